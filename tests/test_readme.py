"""The README keeps its word: every option it shows exists in `--help`, and every command of its
tour runs as written (in a fresh folder, on the bundled samples)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"
CHEAP = ("samples", "landmarks", "identity", "-V", "--version")  # seconds each: also in the fast suite


def _section_blocks(title: str) -> list[str]:
    text = README.read_text(encoding="utf-8")
    start = text.index(f"## {title}")
    end = text.find("\n## ", start + 4)
    section = text[start:end if end > 0 else None]
    return re.findall(r"```[a-z]*\n(.*?)```", section, re.S)


def _reference_lines() -> list[str]:
    """The `facetex ...` synopsis lines of the Command line section (continuations joined)."""
    lines: list[str] = []
    for line in _section_blocks("Command line")[0].splitlines():
        if line.startswith("facetex "):
            lines.append(line.split("#")[0])
        elif line.startswith(" ") and lines:
            lines[-1] += " " + line.strip()
    return lines


def _tour() -> list[str]:
    block = _section_blocks("A tour")[0]
    return [line.split("  #")[0].strip() for line in block.splitlines() if line.strip() and not line.startswith("#")]


def _subparser(words: list[str]):
    from facetex.cli import build_parser

    import argparse

    parser = build_parser()
    for w in words:
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parser = sub.choices[w]
    return parser


def _commands(line: str) -> list[list[str]]:
    words = line.split()[1:]
    path = []
    for w in words:
        if w.startswith(("-", "[", "(")) or w.isupper() or "." in w or "/" in w and "|" not in w:
            break
        path.append(w)
    if path and "|" in path[-1]:  # "bench transfer|persona|puppet"
        return [path[:-1] + [alt] for alt in path[-1].split("|")]
    return [path]


def test_every_option_in_the_readme_exists():
    lines = _reference_lines()
    assert len(lines) >= 15
    checked = 0
    for line in lines:
        options = set(re.findall(r"(?<![\w-])(--?[a-zA-Z][\w-]*)", line))
        for path in _commands(line):
            parser = _subparser(path)
            known = set(parser._option_string_actions)
            missing = sorted(o for o in options if o not in known)
            assert not missing, f"README shows {missing} for `facetex {' '.join(path)}`, which has no such option"
            checked += len(options)
    assert checked > 60


def test_every_command_has_help_with_defaults():
    from facetex.cli import build_parser

    help_text = _subparser(["transfer"]).format_help()
    for needed in ("(default)", "--mrf-weight", "--init", "--print-every", "-q, --quiet", "OUT_level<L>_eval<NNNN>.png",
                   "{cpu,cuda,cuda:N,mps}"):
        assert needed in help_text, needed
    puppet = _subparser(["bench", "puppet"]).format_help()
    assert ".. " not in puppet and "``" not in puppet  # prose, not a reStructuredText dump
    for bench in ("transfer", "persona", "puppet"):
        h = _subparser(["bench", bench]).format_help()
        assert "--data DIR" in h and "FACETEX_DATA" in h and f"bench_out/{bench}" in h and "--json" in h
        assert "/work/" not in h and "shared/data" not in h  # no path of the build machine
    assert "-V, --version" in build_parser().format_help()


def _shims(tmp_path: Path) -> dict:
    """`facetex` and `python` on PATH run this interpreter with this checkout."""
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    for name, cmd in (("facetex", f'exec "{sys.executable}" -m facetex "$@"'), ("python", f'exec "{sys.executable}" "$@"')):
        p = bin_dir / name
        p.write_text(f"#!/bin/sh\n{cmd}\n")
        p.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
               PYTHONPATH=os.pathsep.join([str(README.parent), os.environ.get("PYTHONPATH", "")]).rstrip(os.pathsep),
               OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    env.pop("FACETEX_DATA", None)
    return env


def _run_tour(tmp_path: Path, commands: list[str]) -> list[tuple[str, float]]:
    env = _shims(tmp_path)
    work = tmp_path / "work"
    work.mkdir()
    times = []
    for cmd in commands:
        t0 = time.perf_counter()
        r = subprocess.run(["bash", "-c", cmd], cwd=work, env=env, capture_output=True, text=True, timeout=1800)
        times.append((cmd, time.perf_counter() - t0))
        assert r.returncode == 0, f"`{cmd}` exited {r.returncode}: {r.stderr[-1500:]}"
        for bad in ("Traceback", "internal error", "BrokenPipeError", "facetex: warning"):
            assert bad not in r.stderr, f"`{cmd}` printed {bad!r}: {r.stderr[-1500:]}"
        words = shlex.split(cmd)
        if ("-o" in words or "--out" in words or words[1] == "samples") and "--json" not in words:
            assert "wrote " in r.stdout, f"`{cmd}` wrote files without saying so: {r.stdout[-500:]}"
    return times


def test_readme_tour_cheap_commands(tmp_path):
    tour = _tour()
    assert tour[0].startswith("facetex samples")
    cheap = [c for c in tour if shlex.split(c)[1] in CHEAP or c.startswith("python -m facetex")]
    assert len(cheap) >= 5
    _run_tour(tmp_path, cheap)
    assert (tmp_path / "work" / "overlay.png.json").is_file()


@pytest.mark.slow
def test_readme_tour_every_command(tmp_path):
    times = _run_tour(tmp_path, _tour())
    work = tmp_path / "work"
    for f in ("out.png", "out.png.json", "demo_out/run.json", "bench_out/quick/run.json", "report.html"):
        assert (work / f).is_file(), f
    sys.stderr.write("\n".join(f"{t:7.1f} s  {c}" for c, t in times) + "\n")
