"""``facetex batch transfer`` end to end on the bundled faces (size 96, 2 iterations per level):
outputs equal the Python API's, sidecars, resume, one-line errors, SIGTERM."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from _procs import children
from facetex._resources import sample_path
from facetex.cli import main

SMALL = ["--size", "96", "--iters", "2,2,2"]
A, B, C = (str(sample_path(n)) for n in ("frl_004_neutral.jpg", "frl_005_neutral.jpg", "frl_008_neutral.jpg"))


def _csv(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def _manifest(out: Path) -> dict:
    return {r["item"]: r for r in map(json.loads, (out / "manifest.jsonl").read_text().splitlines())}


def _states(out: Path) -> list[str]:
    """The items' states now (the manifest's last line of each; [] before it exists)."""
    from facetex.batch._state import read_manifest

    return [r["state"] for r in read_manifest(out / "manifest.jsonl").values()]


def test_batch_transfer_equals_the_api_and_resumes(tmp_path, capsys, no_leftover_processes):
    import torch

    import facetex

    pairs = _csv(tmp_path / "pairs.csv", f"content,style,seed\n{A},{B},\n{C},{A},3\n")
    out = tmp_path / "out"
    assert main(["batch", "transfer", str(pairs), "--out", str(out), "--jobs", "2", *SMALL]) == 0
    text = capsys.readouterr().out
    first = out / "frl_004_neutral__frl_005_neutral__facetex.png"
    second = out / "frl_008_neutral__frl_004_neutral__facetex__seed3.png"
    assert f"wrote {first}" in text and f"wrote {second}.json" in text and f"wrote {out / 'manifest.jsonl'}" in text
    assert "2 computed, 0 already done" in text
    rec = json.loads(Path(f"{second}.json").read_text())
    assert rec["command"] == "batch transfer" and rec["seed"] == 3 and rec["command_line"].startswith("facetex batch")
    assert rec["inputs"]["content"]["sha256"] and rec["batch"]["item"] == second.stem
    assert rec["params"]["command_line_options"] == {"size": 96, "iters": [2, 2, 2]}
    m = _manifest(out)
    assert {r["state"] for r in m.values()} == {"done"} and all(r["host"] and r["time"] for r in m.values())
    # a worker runs exactly what a user's script runs: the same pixels (one thread, as the workers)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        img = facetex.transfer(C, A, size=96, iters="2,2,2", seed=3)
    finally:
        torch.set_num_threads(threads)
    assert np.array_equal(facetex.read_image(second), np.round(img * 255) / 255) or \
        np.array_equal(np.asarray(facetex.io.read_image_uint8(second)), facetex.io.to_uint8(img))
    # resumed: nothing is computed again
    assert main(["batch", "transfer", str(pairs), "--out", str(out), "--jobs", "2", *SMALL, "--json"]) == 0
    captured = capsys.readouterr()
    s = json.loads(captured.out)
    assert (s["done"], s["skipped_done"], s["failed"]) == (0, 2, 0)
    assert "batch transfer" not in captured.err  # nothing left to do: no empty progress bar
    # other settings into the same folder: refused before any work
    assert main(["batch", "transfer", str(pairs), "--out", str(out), "--size", "128", "--iters", "2,2,2"]) == 2
    assert "made with other settings" in capsys.readouterr().err


def test_batch_transfer_redoes_the_pair_whose_style_was_replaced(tmp_path, capsys, no_leftover_processes):
    """Issue 23: a style replaced under its name (same file name, other bytes) makes the rerun
    compute that pair again and replace its image and sidecar; the other pair stays."""
    import hashlib
    import shutil

    for src, name in ((A, "a.jpg"), (B, "b.jpg"), (C, "c.jpg")):
        shutil.copy(src, tmp_path / name)
    pairs = _csv(tmp_path / "pairs.csv", "content,style\na.jpg,b.jpg\nc.jpg,a.jpg\n")
    out = tmp_path / "out"
    cmd = ["batch", "transfer", str(pairs), "--out", str(out), "--jobs", "1", *SMALL]
    assert main(cmd) == 0
    capsys.readouterr()
    redone, kept = out / "a__b__facetex.png", out / "c__a__facetex.png"
    before = {p: p.read_bytes() for p in (redone, kept, Path(f"{kept}.json"))}
    shutil.copy(C, tmp_path / "b.jpg")
    assert main(cmd) == 0
    assert "1 computed (1 because an input changed), 1 already done" in capsys.readouterr().out
    assert redone.read_bytes() != before[redone] and all(p.read_bytes() == b for p, b in before.items() if p != redone)
    sha = hashlib.sha256(Path(C).read_bytes()).hexdigest()
    rec = json.loads(Path(f"{redone}.json").read_text())
    assert rec["inputs"]["style"]["sha256"] == sha == rec["batch"]["input_digests"][str((tmp_path / "b.jpg").resolve())]
    assert _manifest(out)["a__b__facetex"]["input_digests"] == rec["batch"]["input_digests"]
    assert not [p.name for p in out.iterdir() if p.name.startswith(".a__b")]  # no temporaries or backups left


@pytest.mark.parametrize("csv_text, message", [
    ("content;style\na.jpg;b.jpg\n", "must name the columns"),
    ("content,style,colour\n{A},{B},red\n", "unknown column 'colour'"),
    ("content,style\n{A},missing.jpg\n", "missing.jpg"),
    ("content,style,method\n{A},{B},magic\n", "pairs.csv:2: unknown method 'magic'"),
    ("content,style,seed\n{A},{B},x\n", "pairs.csv:2: seed must be an integer"),
    ("content,style\n", "no pairs"),
])
def test_bad_pairs_csv_is_one_line_before_any_work(tmp_path, capsys, csv_text, message):
    pairs = _csv(tmp_path / "pairs.csv", csv_text.format(A=A, B=B))
    assert main(["batch", "transfer", str(pairs), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("facetex: error:") and message in err and len(err.splitlines()) == 1
    assert not (tmp_path / "out").exists()


def test_bad_batch_options(tmp_path, capsys):
    samples = str(sample_path())
    cases = [
        (["--out", str(tmp_path / "o")], "give PAIRS.csv, or both --contents DIR and --styles DIR"),
        (["--contents", samples, "--styles", samples, "--out", samples], "--out is the input folder"),
        (["--contents", samples, "--styles", samples, "--out", str(tmp_path / "o"), "--address", "auto"],
         "--address needs --engine ray"),
        (["--contents", samples, "--styles", str(tmp_path / "none"), "--out", str(tmp_path / "o")], "none"),
        (["--contents", samples, "--styles", samples, "--pairs", "0", "--out", str(tmp_path / "o")],
         "must be 'all' or at least 1"),
    ]
    for args, message in cases:
        assert main(["batch", "transfer", *args]) == 2, args
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err


def test_pairs_from_folders_are_stable(tmp_path):
    from facetex.batch import pairs_from_folders

    allp = pairs_from_folders(sample_path(), sample_path(), "all")
    assert len(allp) == 6 * 5 and all(p["content"] != p["style"] for p in allp)
    three = pairs_from_folders(sample_path(), sample_path(), 3)
    assert three == pairs_from_folders(sample_path(), sample_path(), 4)[:3]  # a longer run extends a shorter


@pytest.mark.slow  # ~40 s: five transfers in subprocesses (the interrupt path itself: test_run_batch.py)
def test_sigterm_stops_the_batch_without_partial_output_or_orphans(tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "facetex", "batch", "transfer", "--contents", str(sample_path()), "--styles",
           str(sample_path()), "--pairs", "3", "--out", str(out), "--jobs", "2", *SMALL, "-q"]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[2]),
                                                        os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    workers: set[int] = set()
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:  # wait for items to be running in the workers
            workers |= children(proc.pid)
            states = _states(out)
            if states.count("running") == 2 and len(workers) >= 2:
                break
            time.sleep(0.2)
        else:
            pytest.fail("the batch did not start two items within 120 s")
        time.sleep(1.0)
        workers |= children(proc.pid)
        proc.send_signal(signal.SIGTERM)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 143, err
    assert "interrupted by SIGTERM" in err and "resume" in err
    left = sorted(p.name for p in out.iterdir() if p.name.startswith(".") and p.name != ".facetex-batch")
    assert not left, left  # no temporary file
    for p in out.glob("*.png"):  # whatever finished is whole: image and sidecar
        assert Path(f"{p}.json").is_file()
    time.sleep(0.5)
    alive = [pid for pid in workers if os.path.exists(f"/proc/{pid}") and
             open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z"]
    assert not alive, f"worker processes outlived the batch: {alive}"
    m = _manifest(out)
    assert all(r["state"] in ("done", "pending") for r in m.values())
    assert not list((out / ".facetex-batch" / "claims").iterdir())
    # the same command resumes and finishes
    done = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    assert {r["state"] for r in _manifest(out).values()} == {"done"} and len(list(out.glob("*.png"))) == 3


def _start_and_wait_running(cmd, env, out, n_running=1, timeout=180, settle=1.0):
    """Start ``cmd``; return (process, its descendants) ``settle`` s after ``n_running`` items run."""
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    seen: set[int] = set()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        seen |= children(proc.pid)
        states = _states(out)
        if states.count("running") >= n_running and seen:
            time.sleep(settle)
            return proc, seen | children(proc.pid)
        if proc.poll() is not None:
            pytest.fail(f"the batch ended early: {proc.communicate()[1]}")
        time.sleep(0.2)
    proc.kill()
    pytest.fail("no item started in time")


def _alive(pids):
    out = []
    for pid in pids:
        try:
            if open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0] != "Z":
                out.append(pid)
        except OSError:
            pass
    return out


@pytest.mark.slow  # ~40 s
def test_a_killed_batch_leaves_no_worker_and_the_next_run_takes_over_at_once(tmp_path):
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "facetex", "batch", "transfer", "--contents", str(sample_path()), "--styles",
           str(sample_path()), "--pairs", "2", "--out", str(out), "--jobs", "2", "--size", "256", "--iters",
           "100,100,100", "-q", "--claim-timeout", "3600"]  # items of seconds: killed while they run
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).parents[2]),
                                                        os.environ.get("PYTHONPATH", "")]))
    proc, procs = _start_and_wait_running(cmd, env, out, n_running=2, settle=0.0)
    proc.kill()  # SIGKILL: no clean-up in the batch itself
    proc.wait()
    deadline = time.monotonic() + 30
    while _alive(procs - {proc.pid}) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not _alive(procs - {proc.pid}), "workers outlived a killed batch"
    assert list((out / ".facetex-batch" / "claims").iterdir())  # the killed run's claims are still there
    t0 = time.monotonic()
    done = subprocess.run(cmd[:-2] + ["--json"], capture_output=True, text=True, env=env, timeout=600)
    assert done.returncode == 0, done.stderr
    s = json.loads(done.stdout)
    assert s["done"] + s["skipped_done"] == 2 and s["remaining"] == 0  # not waiting an hour for the claims
    assert time.monotonic() - t0 < 300
    assert not [p for p in out.iterdir() if p.name.startswith(".") and p.name != ".facetex-batch"]


@pytest.mark.slow  # a persona build and a puppet render
def test_batch_persona_then_puppet(tmp_path, capsys, no_leftover_processes):
    import cv2
    from _photos import write_jittered_copies

    from facetex.io import read_image, write_video

    people = tmp_path / "people"
    rng = np.random.default_rng(0)
    for person, n in (("alice", 4), ("bob", 1)):
        (people / person).mkdir(parents=True)
        write_jittered_copies(people / person, n, rng)
    (people / "empty").mkdir()
    personas = tmp_path / "personas"
    code = main(["batch", "persona", str(people), "--out", str(personas), "--min-photos", "6", "--jobs", "2"])
    captured = capsys.readouterr()
    assert code == 4, captured.err  # bob has too few photos
    assert "left out 1 subfolder(s) without photos: empty" in captured.err
    assert "facetex: persona item bob failed:" in captured.err
    m = _manifest(personas)
    assert m["alice"]["state"] == "done" and m["bob"]["state"] == "failed" and "photo" in m["bob"]["error"]
    rec = json.loads((personas / "alice.persona.json").read_text())
    assert rec["command"] == "batch persona" and rec["photos_used"] >= 6
    assert not (personas / "bob.persona").exists()

    drivers = tmp_path / "drivers"
    drivers.mkdir()
    img = cv2.resize(read_image(sample_path("frl_005_neutral.jpg")), (200, 200), interpolation=cv2.INTER_AREA)
    write_video(drivers / "talk.mp4", [np.roll(img, (i % 3) - 1, axis=1) for i in range(6)], 10.0)
    videos = tmp_path / "videos"
    assert main(["batch", "puppet", "--drivers", str(drivers), "--puppets", str(personas), "--out", str(videos),
                 "--size", "96", "--side-by-side", "--jobs", "1"]) == 0
    assert f"wrote {videos / 'talk__alice.mp4'}" in capsys.readouterr().out
    rec = json.loads((videos / "talk__alice.mp4.json").read_text())
    assert rec["command"] == "batch puppet" and rec["result"]["frames"] == 6 and rec["params"]["side_by_side"]
    assert rec["result"]["output"] == str(videos / "talk__alice.mp4")
    from facetex.io import video_info

    assert video_info(videos / "talk__alice.mp4")["n_frames"] == 6


def test_same_bytes_with_jobs_1_and_the_default(tmp_path, capsys, no_leftover_processes):
    """Torch's float sums depend on the thread count (1 vs 2 threads: 28 pixels differ at this
    size, 443 at 128 px × 3 × 10 iterations): every item gets one thread, whatever --jobs."""
    pairs = _csv(tmp_path / "pairs.csv", f"content,style\n{A},{B}\n")
    opts = ["--size", "128", "--iters", "4,4,4", "-q"]
    assert main(["batch", "transfer", str(pairs), "--out", str(tmp_path / "one"), "--jobs", "1", *opts]) == 0
    assert main(["batch", "transfer", str(pairs), "--out", str(tmp_path / "default"), *opts]) == 0
    name = "frl_004_neutral__frl_005_neutral__facetex.png"
    assert (tmp_path / "one" / name).read_bytes() == (tmp_path / "default" / name).read_bytes()
    for d in ("one", "default"):
        assert json.loads((tmp_path / d / f"{name}.json").read_text())["threads"] == 1
        assert _manifest(tmp_path / d)[name[:-4]]["threads"] == 1
