"""Issue 23: ``facetex batch`` never deletes or replaces a file it did not make, and a run whose
settings differ from its output folder's is refused (one line, before any work)."""

from __future__ import annotations

import json
import os
import shutil

import pytest

from _robust import FACE, OTHER, assert_one_error, run_cli, snapshot

T = ["--size", "64", "--iters", "2", "--jobs", "1"]  # one worker: about 4 s per item
KEY = "frl_004_neutral__frl_005_neutral__facetex"


@pytest.fixture
def pairs(tmp_path):
    """A pairs CSV of one pair (FACE, OTHER), and the folder it goes to."""
    csv = tmp_path / "pairs.csv"
    csv.write_text(f"content,style\n{FACE},{OTHER}\n")
    return csv


def _put(path, kind: str) -> None:
    if kind == "file":
        path.write_bytes(b"MINE\n")
    elif kind == "symlink":
        (path.parent / "elsewhere.txt").write_bytes(b"MINE\n")
        path.symlink_to(path.parent / "elsewhere.txt")
    elif kind == "fifo":
        os.mkfifo(path)
    elif kind == "json":
        path.write_text('{"mine": true}\n')


@pytest.mark.parametrize("name, kind, cause", [
    (f"{KEY}.png", "file", "exists without its sidecar"),
    (f"{KEY}.png", "symlink", "exists without its sidecar"),
    (f"{KEY}.png", "fifo", "exists without its sidecar"),
    (f"{KEY}.png.json", "json", "not that batch item's sidecar"),
    (f"{KEY}.png.json", "fifo", "not that batch item's sidecar"),  # not opened: no hang
])
def test_a_file_with_an_outputs_name_is_refused_not_replaced(tmp_path, capsys, pairs, name, kind, cause):
    out = tmp_path / "o"
    out.mkdir()
    _put(out / name, kind)
    before = snapshot(out) if kind != "fifo" else sorted(os.listdir(out))
    r = run_cli(capsys, "batch", "transfer", pairs, "--out", out, *T)
    assert_one_error(r, names=[name], cause=cause)
    assert (snapshot(out) if kind != "fifo" else sorted(os.listdir(out))) == before  # nothing replaced or added


def test_out_dot_where_an_input_is_another_rows_output_is_refused(tmp_path, capsys, monkeypatch):
    for src, name in ((FACE, "a.jpg"), (OTHER, "b.jpg"), (FACE, "a__b__facetex.png")):
        shutil.copy(src, tmp_path / name)
    (tmp_path / "pairs.csv").write_text("content,style\na.jpg,b.jpg\na__b__facetex.png,b.jpg\n")
    before = snapshot(tmp_path)
    monkeypatch.chdir(tmp_path)
    r = run_cli(capsys, "batch", "transfer", "pairs.csv", "--out", ".", *T)
    assert_one_error(r, names=["a__b__facetex.png", "pairs.csv"], cause="also the output of item a__b__facetex")
    assert snapshot(tmp_path) == before


def test_hidden_files_that_look_like_temporaries_are_kept(tmp_path, capsys, pairs):
    out = tmp_path / "o"
    out.mkdir()
    mine = [out / f".{KEY}.png.notes", out / f".{KEY}.abcd1234.png", out / f".{KEY}.png.x1y2z3.json"]
    for p in mine:
        p.write_text("a user's hidden file\n")
    r = run_cli(capsys, "batch", "transfer", pairs, "--out", out, *T)
    assert r.code == 0, r.err
    assert all(p.read_text() == "a user's hidden file\n" for p in mine)
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".") and p not in mine) == [".facetex-batch"]


# ------------------------------------------------------------------------------ concurrency
def test_a_run_with_other_settings_than_the_folders_is_refused(tmp_path, capsys, pairs):
    out = tmp_path / "o"
    assert run_cli(capsys, "batch", "transfer", pairs, "--out", out, *T).code == 0
    other = tmp_path / "other.csv"  # another pair: no finished item clashes, the folder's settings do
    other.write_text(f"content,style\n{OTHER},{FACE}\n")
    before = snapshot(out)
    r = run_cli(capsys, "batch", "transfer", other, "--out", out, "--size", "96", "--iters", "2", "--jobs", "1")
    assert_one_error(r, names=[out], cause=r"other settings: size 64 \(this run: 96\)")
    assert snapshot(out) == before


def test_two_runs_at_once_with_other_settings_second_is_refused(tmp_path, capsys, pairs):
    import subprocess
    import sys
    import time

    out = tmp_path / "o"
    first = subprocess.Popen([sys.executable, "-m", "facetex", "batch", "transfer", str(pairs), "--out", str(out),
                              "-q", *T], stderr=subprocess.PIPE, text=True)
    try:
        record = out / ".facetex-batch" / "claims" / f"{KEY}.0"  # the first run holds its item
        deadline = time.monotonic() + 120
        while not record.exists() and first.poll() is None and time.monotonic() < deadline:
            time.sleep(0.05)  # the first run is computing its item
        r = run_cli(capsys, "batch", "transfer", pairs, "--out", out, "--size", "96", "--iters", "2", "--jobs", "1")
        assert_one_error(r, names=[out], cause=r"other settings: size 64 \(this run: 96\)")
    finally:
        _, err = first.communicate(timeout=180)
    assert first.returncode == 0, err
    from PIL import Image

    assert Image.open(out / f"{KEY}.png").size is not None
    assert sorted(p.name for p in out.iterdir()) == [".facetex-batch", f"{KEY}.png", f"{KEY}.png.json",
                                                     "manifest.jsonl"]


def test_another_runs_failure_is_not_reported_as_this_runs(tmp_path, capsys, pairs):
    import socket
    import threading

    from facetex.batch._claims import _proc_start
    from facetex.batch._state import BatchState

    out = tmp_path / "o"
    state = BatchState(out)
    state.create()
    state.put(KEY, {"kind": "transfer", "state": "running", "run": "other-run"})
    claim = state.claims / f"{KEY}.0"  # held by a live process (this one) of another run
    claim.write_text(json.dumps({"run": "other-run", "host": socket.gethostname(), "pid": os.getpid(),
                                 "pid_start": _proc_start(os.getpid())}))

    def the_other_run_fails():
        state.put(KEY, {"kind": "transfer", "state": "failed", "run": "other-run", "error": "boom"})
        claim.unlink()

    timer = threading.Timer(1.0, the_other_run_fails)
    timer.start()
    try:
        r = run_cli(capsys, "batch", "transfer", pairs, "--out", out, *T)
    finally:
        timer.join()
    assert r.code == 4, r.err
    assert f"item {KEY} failed in another run (other-run): boom" in r.err and f"{KEY} failed: boom" not in r.err
    assert "0 failed, 1 failed in another run" in r.out


# ------------------------------------------------------------------------------ pairs CSV
def test_a_quoted_line_break_in_a_csv_field_is_part_of_the_field(tmp_path, capsys):
    from facetex.batch import read_pairs_csv

    shutil.copy(FACE, tmp_path / "two\nlines.jpg")
    csv = tmp_path / "pairs.csv"
    csv.write_text(f'content,style\n"two\nlines.jpg",{OTHER}\n{OTHER},"two\nlines.jpg"\n')
    rows = read_pairs_csv(csv)
    assert [(os.path.basename(r["content"]), os.path.basename(r["style"])) for r in rows] == \
        [("two\nlines.jpg", OTHER.name), (OTHER.name, "two\nlines.jpg")]
    csv.write_text(f'content,style\n\n{FACE},{OTHER}\n"gone\nfile.jpg",{OTHER}\n')
    r = run_cli(capsys, "batch", "transfer", csv, "--out", tmp_path / "o", *T)
    assert_one_error(r, names=["pairs.csv"], cause=r"gone\\nfile\.jpg: content image not found.*pairs\.csv:4\)")
    assert not (tmp_path / "o").exists()


def test_an_input_replaced_under_its_name_is_computed_again_not_already_done(tmp_path, capsys):
    """Issue 23: items are keyed by their inputs' content. A rerun after the style was replaced
    under the same name computes the pair again (it used to say "already done"); a rerun with
    nothing changed computes nothing and leaves the outputs and the manifest byte-identical (each
    run adds only its own record under .facetex-batch/runs)."""
    content, style = tmp_path / "c.jpg", tmp_path / "s.jpg"
    shutil.copy(FACE, content)
    shutil.copy(OTHER, style)
    csv = tmp_path / "pairs.csv"
    csv.write_text(f"content,style\n{content},{style}\n")
    out = tmp_path / "o"
    assert run_cli(capsys, "batch", "transfer", csv, "--out", out, *T).code == 0
    def outputs():
        return {k: v for k, v in snapshot(out).items() if not k.startswith(".facetex-batch/runs")}

    same = outputs()
    r = run_cli(capsys, "batch", "transfer", csv, "--out", out, *T)
    assert r.code == 0 and "already done" in r.out and outputs() == same
    shutil.copy(FACE, style)  # other bytes, same name
    r = run_cli(capsys, "batch", "transfer", csv, "--out", out, *T)
    assert r.code == 0 and "because an input changed" in r.out, r.out
    after = outputs()
    png = "c__s__facetex.png"
    assert after[png] != same[png] and sorted(after) == sorted(same)  # replaced in place, nothing left over
