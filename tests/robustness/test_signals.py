"""Issue 13, signals: SIGTERM is handled like SIGINT everywhere (exit 143 / 130), nothing
partial is left, every child process is reaped, and an interrupted run says which files
it kept (step files) instead of claiming "no partial output"."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

import facetex.transfer._pipeline as pipeline
from _robust import assert_one_error, descendants, alive, run_cli, sha1s, snapshot
from conftest import has_command

T = ["--size", "64", "--iters", "3"]  # 1 level, 4 loss evaluations (budget 1.25 × 3)


def _interrupt_at(monkeypatch, n: int, action):
    """Call ``action()`` at the n-th progress callback of the optimisation."""
    real = pipeline.optimize_image
    calls = []

    def patched(*args, progress=None, **kwargs):
        def prog(*a, **k):
            calls.append(1)
            if len(calls) == n:
                action()
            if progress:
                progress(*a, **k)
        return real(*args, progress=prog, **kwargs)

    monkeypatch.setattr(pipeline, "optimize_image", patched)
    return calls


def test_sigterm_transfer_in_process(capsys, bad, outdir, monkeypatch):
    calls = _interrupt_at(monkeypatch, 2, lambda: os.kill(os.getpid(), signal.SIGTERM))
    inputs = sha1s(bad["face.jpg"], bad["other.jpg"])
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T)
    assert len(calls) == 2
    assert_one_error(run, code=143, prefix="facetex:", cause=r"interrupted by SIGTERM; no partial output")
    assert snapshot(outdir) == {}
    assert sha1s(bad["face.jpg"], bad["other.jpg"]) == inputs
    assert signal.getsignal(signal.SIGTERM) in (signal.SIG_DFL, None) or callable(signal.getsignal(signal.SIGTERM))


@pytest.mark.parametrize("how, code, name", [("sigint", 130, ""), ("sigterm", 143, " by SIGTERM")])
def test_interrupted_save_every_keeps_and_names_step_files(capsys, bad, outdir, monkeypatch, how, code, name):
    def stop():
        if how == "sigint":
            raise KeyboardInterrupt
        os.kill(os.getpid(), signal.SIGTERM)

    _interrupt_at(monkeypatch, 3, stop)
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T,
                  "--save-every", "1")
    files = sorted(snapshot(outdir))
    assert files and all(f.startswith("t_level0_eval") and f.endswith(".png") for f in files), files
    line = assert_one_error(run, code=code, prefix="facetex:",
                            cause=rf"interrupted{name}; the run did not finish; kept {len(files)} file")
    assert "no partial output" not in line
    assert files[0] in line


@pytest.mark.skipif(not has_command("puppet"), reason="no puppet command")
def test_sigterm_puppet_in_process(capsys, videos, outdir, persona_file, monkeypatch):
    """SIGTERM while the driver is tracked (in its child process): no output, the child stopped."""
    from facetex.puppet._tracking import DriverTracking

    real = DriverTracking.result
    children = []

    def result(self, progress=None):
        children.append(self._proc)
        calls = []

        def tick(**k):  # the second frame's progress message from the child
            calls.append(1)
            if len(calls) == 2:
                os.kill(os.getpid(), signal.SIGTERM)
            if progress:
                progress(**k)

        return real(self, tick)

    monkeypatch.setattr(DriverTracking, "result", result)
    run = run_cli(capsys, "puppet", "--driver", videos["face.mp4"], "--puppet", persona_file, "-o",
                  outdir / "o.mp4", "--size", "64")
    assert_one_error(run, code=143, prefix="facetex:", cause=r"interrupted by SIGTERM; no partial output")
    assert snapshot(outdir) == {}
    assert children and children[0] is not None and children[0].poll() is not None
    time.sleep(0.2)
    assert not [t for t in threading.enumerate() if t.name.startswith("facetex-puppet")]



@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_to_persona_build_reaps_every_child(many_photos, tmp_path, sig, code):
    """A real ``facetex persona build --jobs 2``: forkserver, two workers and the resource tracker
    are all gone when it exits (nobody reading its pipes is kept waiting); SIGINT goes to the
    whole process group, as Ctrl-C does."""
    out = tmp_path / "p.persona"
    p = subprocess.Popen([sys.executable, "-m", "facetex.cli", "persona", "build", str(many_photos), "-o", str(out),
                          "--jobs", "2", "--min-photos", "3", "--allow-mixed"],
                         stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                         # a shell's background job inherits SIGINT ignored (Python then installs no
                         # KeyboardInterrupt handler); the target of a terminal's Ctrl-C has it default
                         preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    seen: set[int] = set()
    t0 = time.monotonic()
    while time.monotonic() - t0 < 90:  # until the two workers run
        kids = descendants(p.pid)
        seen |= kids
        if len(kids) >= 4 or p.poll() is not None:  # resource tracker, forkserver, two workers
            break
        time.sleep(0.1)
    assert p.poll() is None, p.stderr.read()
    time.sleep(1.0)
    seen |= descendants(p.pid)
    if sig == signal.SIGINT:
        os.killpg(p.pid, sig)
    else:
        p.send_signal(sig)
    try:
        out_text, err = p.communicate(timeout=30)  # returns only when every holder of the pipes is gone
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        pytest.fail(f"persona build did not stop within 30 s of {sig.name}")
    assert p.returncode == code, err
    lines = [l for l in err.replace("\r", "\n").splitlines() if l.strip() and "[" not in l and "photo" not in l]
    assert "Traceback" not in err, err
    assert len(lines) == 1 and lines[0].startswith("facetex: interrupted") and "no partial output" in lines[0], lines
    assert len(seen) >= 4, seen
    t1 = time.monotonic()
    while any(alive(pid) for pid in seen) and time.monotonic() - t1 < 5:
        time.sleep(0.1)
    assert not [pid for pid in seen if alive(pid)], "child processes left running"
    assert sorted(x.name for x in tmp_path.iterdir()) == []  # no persona, no temp file
