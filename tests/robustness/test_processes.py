"""Worker processes (issue 23): a long TMPDIR (the forkserver's AF_UNIX socket path), and
workers that die with a SIGKILLed parent instead of running on."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import pytest

from _robust import alive, assert_one_error, descendants, run_cli, snapshot


def _long_tmpdir(tmp_path):
    d = tmp_path / ("t" * 60) / ("m" * 60)  # with pymp-*/listener-*: over the 107 bytes of a socket path
    d.mkdir(parents=True)
    return d


def _env(**extra):
    return {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path), **extra}


def test_persona_build_jobs_2_with_a_long_tmpdir(tmp_path, photo_dir):
    tmp = _long_tmpdir(tmp_path)
    out = tmp_path / "p.persona"
    r = subprocess.run([sys.executable, "-m", "facetex", "persona", "build", str(photo_dir), "-o", str(out),
                        "--jobs", "2", "--min-photos", "3", "--allow-mixed", "-q"],
                       env=_env(TMPDIR=str(tmp)), capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr and out.is_file()
    assert list(tmp.iterdir()) == []  # multiprocessing's folder went elsewhere, and is gone


def test_no_short_temp_folder_is_one_line(capsys, tmp_path, photo_dir, outdir, monkeypatch):
    """No writable short folder either: one line naming TMPDIR and --jobs, before any work."""
    import multiprocessing.util
    import tempfile

    import facetex._parallel as par

    tmp = _long_tmpdir(tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.setattr(par, "_SHORT_TEMP_FOLDERS", ())
    monkeypatch.setattr(multiprocessing.util, "get_temp_dir", lambda: os.path.join(tempfile.gettempdir(), "pymp-x"))
    run = run_cli(capsys, "persona", "build", photo_dir, "-o", outdir / "p.persona", "--jobs", "2", "--min-photos",
                  "3", "--allow-mixed")
    assert_one_error(run, names=[tmp / "pymp-x"], cause=r"too long a path .*socket.*TMPDIR.*--jobs 1")
    assert snapshot(outdir) == {}



def test_sigkill_of_persona_build_leaves_no_process(many_photos, tmp_path):
    """SIGKILL (no cleanup runs) of a real ``persona build --jobs 2`` in the middle: the workers
    notice and end, then the forkserver and the resource tracker (they live as long as the
    workers): nothing runs on after a few seconds (it ran for over a minute)."""
    out = tmp_path / "p.persona"
    p = subprocess.Popen([sys.executable, "-m", "facetex", "persona", "build", str(many_photos), "-o", str(out),
                          "--jobs", "2", "--min-photos", "3", "--allow-mixed"], env=_env(),
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    seen: set[int] = set()
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < 90:  # until the resource tracker, forkserver and two workers run
            seen |= descendants(p.pid)
            if len(seen) >= 4 or p.poll() is not None:
                break
            time.sleep(0.1)
        time.sleep(1.0)  # the workers are busy with photos
        seen |= descendants(p.pid)
        assert p.poll() is None and len(seen) >= 4, seen
        p.kill()
        p.wait()
        t1 = time.monotonic()
        while any(alive(pid) for pid in seen) and time.monotonic() - t1 < 5:
            time.sleep(0.1)
        left = [pid for pid in seen if alive(pid)]
        assert not left, f"processes left running after SIGKILL: {left}"
    finally:
        for pid in seen:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
    assert not out.exists()


_SLEEPER = ("import os, sys, time\nfrom facetex._parallel import die_with\ndie_with(int(sys.argv[1]))\n"
            "print(os.getpid(), flush=True)\ntime.sleep(60)\n")


def test_die_with_a_process_that_is_not_the_parent():
    """The forkserver's case: the watched process is not the parent (a pidfd, no prctl)."""
    watched = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    watcher = subprocess.Popen([sys.executable, "-c", _SLEEPER, str(watched.pid)], env=_env(),
                               stdout=subprocess.PIPE, text=True)
    try:
        assert int(watcher.stdout.readline()) == watcher.pid
        watched.kill()  # a zombie until reaped below: it has ended all the same
        assert watcher.wait(timeout=5) == -signal.SIGTERM
    finally:
        for p in (watched, watcher):
            p.kill()
            p.wait()


def test_die_with_the_parent():
    """A batch worker's case: the parent is SIGKILLed, its child gets SIGTERM (prctl)."""
    middle = subprocess.Popen([sys.executable, "-c", "import os, subprocess, sys, time\n"
                               f"subprocess.Popen([sys.executable, '-c', {_SLEEPER!r}, str(os.getpid())])\n"
                               "time.sleep(60)\n"], env=_env(), stdout=subprocess.PIPE, text=True)
    child = int(middle.stdout.readline())
    try:
        middle.kill()
        middle.wait()
        t0 = time.monotonic()
        while alive(child) and time.monotonic() - t0 < 5:
            time.sleep(0.05)
        assert not alive(child)
    finally:
        if alive(child):
            os.kill(child, signal.SIGKILL)


@pytest.mark.slow
def test_sigkill_of_ray_batch_leaves_no_process_and_rerun_finishes(tmp_path, photo_dir):
    """SIGKILL of ``batch transfer --engine ray`` (a local Ray started by facetex) while an item
    runs: Ray's daemons (GCS, raylet, dashboard and runtime-env agents) and the running task end
    within seconds (the agents ran on; the task could finish and write its output while the
    manifest said running), and a rerun reconciles the dead run's claims and finishes cleanly."""
    pytest.importorskip("ray")
    out = tmp_path / "o"
    args = [sys.executable, "-m", "facetex", "batch", "transfer", "--contents", str(photo_dir), "--styles",
            str(photo_dir), "--pairs", "2", "--size", "128", "--iters", "150,150,150", "--out", str(out),
            "--engine", "ray", "--jobs", "1", "-q"]
    p = subprocess.Popen(args, env=_env(), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                         start_new_session=True)
    seen: set[int] = set()

    def task_running() -> bool:
        for pid in seen:
            try:
                if open(f"/proc/{pid}/cmdline", "rb").read().startswith(b"ray::facetex"):
                    return True
            except OSError:
                pass
        return False

    try:
        t0 = time.monotonic()
        while time.monotonic() - t0 < 120 and p.poll() is None:
            seen |= descendants(p.pid)
            if task_running():
                break
            time.sleep(0.1)
        assert p.poll() is None and task_running(), "no Ray task started"
        time.sleep(0.5)
        seen |= descendants(p.pid)
        p.kill()
        p.wait()
        t1 = time.monotonic()
        while any(alive(pid) for pid in seen) and time.monotonic() - t1 < 10:
            time.sleep(0.2)
        left = {pid: open(f"/proc/{pid}/cmdline", "rb").read()[:40] for pid in seen if alive(pid)}
        assert not left, f"processes left running after SIGKILL: {left}"
    finally:
        for pid in seen:
            if alive(pid):
                os.kill(pid, signal.SIGKILL)
    written = sorted(q.name for q in out.iterdir() if q.suffix == ".png")
    time.sleep(3)
    assert sorted(q.name for q in out.iterdir() if q.suffix == ".png") == written  # nothing written afterwards
    r = subprocess.run(args[:-1] + ["--json"], env=_env(), capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    import json

    summary = json.loads(r.stdout)
    assert summary["failed"] == 0 and summary["done"] + summary["skipped_done"] == 2, summary
    assert len([q for q in out.iterdir() if q.suffix == ".png"]) == 2
    assert [q.name for q in out.iterdir() if q.name.startswith(".")] in ([], [".facetex-batch"]), list(out.iterdir())
