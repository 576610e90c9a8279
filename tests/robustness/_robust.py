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

    @property
    def lines(self) -> list[str]:
        """stderr without progress bars, blank lines and ``facetex: warning:`` lines."""
        lines = re.split(r"[\r\n]+", self.err)
        return [l for l in lines if l.strip() and not _PROGRESS.search(l) and not l.startswith("facetex: warning:")]


def run_cli(capsys, *argv) -> Run:
    capsys.readouterr()
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return Run(code, out, err)


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
    return line


