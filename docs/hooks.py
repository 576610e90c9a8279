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


_ROLE = None


def on_page_content(html: str, page, config, files):  # noqa: ARG001 - MkDocs' hook signature
    """The docstrings' Sphinx roles (``:func:`facetex.io.read_image```) as links where the target is
    documented (mkdocs-autorefs resolves them; ``optional``: plain code otherwise), not as raw text."""
    global _ROLE
    import re

    if _ROLE is None:
        _ROLE = re.compile(r":(?:func|class|mod|meth|data|attr|exc|obj):<code>(~?)([^<]+)</code>")

    def link(m):
        target = m.group(2).lstrip(".")
        shown = target.rsplit(".", 1)[-1] if m.group(1) else m.group(2)
        return f'<autoref identifier="{target}" optional><code>{shown}</code></autoref>'

    return _ROLE.sub(link, html)
