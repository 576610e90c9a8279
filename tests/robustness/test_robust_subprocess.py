"""End to end: real ``python -m facetex.cli`` processes and their exit codes (run concurrently)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from _robust import Run, assert_one_error, snapshot

CASES = {
    "debug-bomb": (["--debug", "landmarks", "%bomb.png"], 2),
    "transfer-missing-folder": (["transfer", "%face.jpg", "%other.jpg", "-o", "@missing/t.png",
                                 "--size", "64", "--iters", "2"], 2),
    "landmarks-ok": (["landmarks", "%cmyk.jpg", "--json", "-o", "@overlay.png"], 0),
}


@pytest.fixture(scope="module")
def runs(bad, tmp_path_factory):
    out = tmp_path_factory.mktemp("sub_out")
    procs = {}
    for name, (argv, _) in CASES.items():
        args = [str(bad[a[1:]]) if a.startswith("%") else str(out / a[1:]) if a.startswith("@") else a for a in argv]
        procs[name] = subprocess.Popen([sys.executable, "-m", "facetex.cli", *args], stdout=subprocess.PIPE,
                                       stderr=subprocess.PIPE, text=True)
    res = {n: Run(p.wait(timeout=300), p.stdout.read(), p.stderr.read()) for n, p in procs.items()}
    return res, out


def test_exit_codes(runs):
    res, _ = runs
    assert {n: r.code for n, r in res.items()} == {n: c for n, (_, c) in CASES.items()}


def test_one_line_errors(runs):
    res, out = runs
    assert_one_error(res["transfer-missing-folder"], names=["t.png"], cause="does not exist")
    assert set(snapshot(out)) == {"overlay.png", "overlay.png.json"}  # only the successful overlay (+ its sidecar)


def test_debug_traceback_in_subprocess(runs):
    r = runs[0]["debug-bomb"]
    assert "Traceback (most recent call last)" in r.err
    assert r.err.strip().splitlines()[-1].startswith("facetex: error:") and "bomb.png" in r.err


def test_success_prints_json(runs):
    r = runs[0]["landmarks-ok"]
    assert r.lines == [] and len(json.loads(r.out)["faces"]) == 1

