"""``facetex completion bash|zsh|tcsh`` — a shell completion script for every command and option."""

from __future__ import annotations


def register(sub) -> None:
    p = sub.add_parser("completion", help="print a shell completion script (bash, zsh or tcsh)",
                       description="Print the completion script of the whole CLI for a shell (made by shtab from "
                                   "the parser itself). bash: `facetex completion bash > "
                                   "~/.local/share/bash-completion/completions/facetex`; zsh: `facetex completion "
                                   "zsh > ~/.zfunc/_facetex` (with ~/.zfunc on $fpath).")
    p.add_argument("shell", choices=("bash", "zsh", "tcsh"), help="the shell")
    p.set_defaults(func=run)


def run(args) -> int:
    import shtab

    from . import build_parser

    print(shtab.complete(build_parser(), shell=args.shell))
    return 0
