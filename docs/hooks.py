"""MkDocs hook: the command-line page is made from the CLI's own parser (every command's --help),
so it cannot drift from the code."""

from __future__ import annotations


def cli_reference() -> str:
    from facetex.cli import iter_commands

    out = []
    for name, p in iter_commands():
        p.prog = f"facetex {name}"
        text = p.format_help().replace("```", "'''")
        out.append(f"## `facetex {name}`\n\n```text\n{text.rstrip()}\n```\n")
    return "\n".join(out)


def on_page_markdown(markdown: str, page, config, files):  # noqa: ARG001 - MkDocs' hook signature
    if "<!-- CLI REFERENCE -->" in markdown:
        return markdown.replace("<!-- CLI REFERENCE -->", cli_reference())
    return markdown
