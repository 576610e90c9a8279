"""MkDocs hook: the command-line page is made from the CLI's own parser (every command's --help),
so it cannot drift from the code."""

from __future__ import annotations

import argparse


def _leaves(parser, prefix=()):
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield " ".join(prefix), parser
        return
    for s in subs:
        seen = set()
        for name, p in s.choices.items():
            if id(p) not in seen:
                seen.add(id(p))
                yield from _leaves(p, prefix + (name,))


def cli_reference() -> str:
    from facetex.cli import build_parser

    parser = build_parser()
    out = []
    for name, p in _leaves(parser):
        p.prog = f"facetex {name}"
        text = p.format_help().replace("```", "'''")
        out.append(f"## `facetex {name}`\n\n```text\n{text.rstrip()}\n```\n")
    return "\n".join(out)


def on_page_markdown(markdown: str, page, config, files):  # noqa: ARG001 - MkDocs' hook signature
    if "<!-- CLI REFERENCE -->" in markdown:
        return markdown.replace("<!-- CLI REFERENCE -->", cli_reference())
    return markdown
