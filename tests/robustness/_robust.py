"""Helpers of the robustness tests: run the CLI in-process, check its one-line errors."""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass
from pathlib import Path


from facetex._resources import sample_path
from facetex.cli import main

FACE = sample_path("frl_004_neutral.jpg")
FACE_SMILING = sample_path("frl_004_smiling.jpg")
OTHER = sample_path("frl_005_neutral.jpg")

# tqdm bars always show the elapsed time "[00:01" (also with an unknown total)
_PROGRESS = re.compile(r"\[\d+:\d\d")


@dataclass
class Run:
    code: int
    out: str
    err: str
    argv: tuple = ()

    @property
    def lines(self) -> list[str]:
        """stderr without progress bars, blank lines and ``facetex: warning:`` lines."""
        lines = re.split(r"[\r\n]+", self.err)
        return [l for l in lines if l.strip() and not _PROGRESS.search(l) and not l.startswith("facetex: warning:")]


def run_cli(capsys, *argv) -> Run:
    capsys.readouterr()
    argv = [str(a) for a in argv]
    code = main(argv)
    out, err = capsys.readouterr()
    return Run(code, out, err, tuple(argv))


def command_options(argv) -> set[str] | None:
    """Option strings (``--size`` …) of the (sub)command that ``argv`` runs, or None if unknown."""
    import argparse

    from facetex.cli import build_parser

    parser = build_parser()
    opts = set()
    for a in argv:
        opts |= {s for act in parser._actions for s in act.option_strings}
        subs = [act for act in parser._actions if isinstance(act, argparse._SubParsersAction)]
        if not subs or a not in subs[0].choices:
            if a.startswith("-"):
                continue
            if subs:
                break
            continue
        parser = subs[0].choices[a]
    opts |= {s for act in parser._actions for s in act.option_strings}
    return opts


def snapshot(folder: Path) -> dict[str, str]:
    """name -> sha1 of every entry below ``folder`` (hidden temp files included)."""
    if not folder.exists():
        return {}
    return {str(p.relative_to(folder)): (hashlib.sha1(p.read_bytes()).hexdigest() if p.is_file() else "dir")
            for p in sorted(folder.rglob("*"))}


def assert_one_error(run: Run, *, names=(), cause: str = "", code: int = 2, prefix: str = "facetex: error:"):
    """Exit ``code``; exactly one stderr line, naming every file in ``names`` and matching ``cause``."""
    assert run.code == code, (run.code, run.err)
    assert "Traceback" not in run.err, run.err
    assert len(run.lines) == 1, run.lines
    line = run.lines[0]
    assert line.startswith(prefix), line
    for n in names:
        assert Path(n).name in line, (n, line)
    assert re.search(cause, line, re.I), (cause, line)
    if run.argv:  # advice names only options this command has
        opts = command_options(run.argv)
        named = set(re.findall(r"(?<![\w/.-])--[a-z][a-z0-9-]*", line))
        typed = {a.split("=")[0] for a in run.argv if a.startswith("--")}  # echoed back: fine
        assert named <= opts | typed, (sorted(named - opts - typed), line)
    return line


def sha1s(*paths) -> dict[str, str]:
    """path -> sha1 of the given files (for "inputs byte-identical")."""
    return {str(p): hashlib.sha1(Path(p).read_bytes()).hexdigest() for p in paths}


def child_pids(pid: int | None = None) -> set[int]:
    """Live (not zombie) direct children of ``pid`` (default: this process), from /proc."""
    import os

    pid = os.getpid() if pid is None else pid
    out = set()
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            stat = (d / "stat").read_text()
        except OSError:
            continue
        fields = stat[stat.rindex(")") + 2:].split()
        if int(fields[1]) == pid and fields[0] != "Z":
            out.add(int(d.name))
    return out


def descendants(pid: int) -> set[int]:
    out, todo = set(), [pid]
    while todo:
        kids = child_pids(todo.pop())
        out |= kids
        todo.extend(kids)
    return out


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2:].split()[0] != "Z"


def helper_daemon(pid: int) -> bool:
    """multiprocessing's forkserver / resource tracker: one per process, they end with it."""
    try:
        cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return True
    return b"forkserver" in cmd or b"resource_tracker" in cmd




def tiny_png(path: Path, value: int = 128) -> Path:
    """A 48 x 48 grey PNG (its folders made)."""
    import numpy as np
    from PIL import Image

    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.full((48, 48, 3), value, np.uint8)).save(path)
    return path


def bench_run_folder(folder: Path, *, image: str = "images/a__b__facetex.png", style_path=None) -> Path:
    """A minimal `facetex bench transfer` run folder: results.json naming one output image, a
    table.md, run.json and the image's sidecar (a report of it takes well under a second)."""
    import json

    folder.mkdir()
    tiny_png(folder / "images" / "a__b__facetex.png")
    (folder / "images" / "a__b__facetex.json").write_text(json.dumps({"params": {"method": "facetex"}}))
    pair = {"content": "a", "style": "b", "results": {"facetex": {"image": image, "metrics": {"E_content": 1.0}}}}
    if style_path is not None:
        pair["style_path"] = str(style_path)
    (folder / "results.json").write_text(json.dumps({"bench": "transfer", "settings": {"size": 64}, "pairs": [pair]}))
    (folder / "table.md").write_text("| method | E |\n|---|---|\n| facetex | 1.0 |\n")
    (folder / "run.json").write_text(json.dumps({"command": "bench transfer", "command_line": "facetex bench"}))
    return folder
