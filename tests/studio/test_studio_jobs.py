"""Cancelling jobs and cleaning up job folders, against a real uvicorn server on a free localhost
port: a cancelled job (running or queued) ends "cancelled", its command and the processes it started
are gone, its folder is removed; the clean-up keeps the newest ``--keep-jobs`` finished jobs, removes
those older than ``--job-ttl`` (at start-up and periodically), and never touches anything but job
folders directly under the studio's jobs root (not a running job, not a symbolic link, not another
folder)."""

from __future__ import annotations

import json
import os
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

from _studio import Server

pytest.importorskip("uvicorn", reason="the studio extra is not installed (pip install -e '.[studio]')")


def call(url: str, method: str = "GET", data: bytes | None = None, headers: dict | None = None):
    req = urllib.request.Request(url, data=data, method=method, headers=headers or {})
    try:
        with urllib.request.urlopen(req, timeout=60) as r:
            return r.status, json.loads(r.read())
    except urllib.error.HTTPError as e:
        return e.code, json.loads(e.read())


def alive(pid: int) -> bool:
    """The process exists and is not a zombie."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def children_running(cmd_part: str) -> list[int]:
    """Pids of this process's live children whose command line has ``cmd_part``."""
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            f = stat.read_text().rsplit(")", 1)[1].split()
            cmd = (stat.parent / "cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
        if int(f[1]) == os.getpid() and f[0] != "Z" and cmd_part in cmd:
            out.append(int(stat.parent.name))
    return out


def wait_for(cond, timeout: float = 60, what: str = "a condition"):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def transfer(url: str) -> dict:
    form = urllib.parse.urlencode({"content_sample": "frl_004_neutral.jpg", "style_sample": "frl_005_neutral.jpg",
                                   "preset": "default"}).encode()
    status, job = call(url + "/api/transfer", "POST", form, {"Content-Type": "application/x-www-form-urlencoded"})
    assert status == 200, job
    return job


def test_cancelling_a_running_and_a_queued_job(tmp_path):
    from facetex.studio import create_app

    app = create_app(tmp_path / "work", workers=1)
    root = app.state.jobs.root
    with Server(app) as server:
        url = server.url
        running, queued = transfer(url), transfer(url)
        wait_for(lambda: call(f"{url}/api/jobs/{running['id']}")[1]["state"] == "running", what="the job's start")
        pid = wait_for(lambda: children_running("facetex transfer"), what="the transfer's process")[0]
        assert (root / running["id"]).is_dir() and (root / queued["id"]).is_dir()
        # the queued one first: it leaves the queue, never runs, its folder (its inputs) is gone
        status, job = call(f"{url}/api/jobs/{queued['id']}/cancel", "POST")
        assert status == 200 and job["state"] == "cancelled" and job["position"] is None
        assert not (root / queued["id"]).exists()
        assert alive(pid)  # the running job is not touched by it
        # the running one: its command is stopped, its folder removed, the state says cancelled
        status, job = call(f"{url}/api/jobs/{running['id']}/cancel", "POST")
        assert status == 200 and job["state"] == "cancelled" and job["error"] is None and job["files"] == []
        assert not alive(pid) and not (root / running["id"]).exists()
        # its event stream ends with the cancelled state
        with urllib.request.urlopen(f"{url}/api/jobs/{running['id']}/events", timeout=30) as r:
            events = [json.loads(line[5:]) for line in r.read().decode().splitlines() if line.startswith("data:")]
        assert events[-1]["state"] == "cancelled"
        # cancelling again changes nothing; a finished job cannot be cancelled; an unknown one is a 404
        assert call(f"{url}/api/jobs/{running['id']}/cancel", "POST")[1]["state"] == "cancelled"
        status, err = call(f"{url}/api/jobs/0123456789abcdef/cancel", "POST")
        assert status == 404 and err == {"error": "no such job"}
        assert [j["state"] for j in call(f"{url}/api/jobs")[1]] == ["cancelled", "cancelled"]
        assert not list(root.iterdir())
    app.state.jobs.close()


def test_cancelling_stops_the_whole_process_group(tmp_path):
    """A step that starts a process of its own: both are stopped, even when the step ignores SIGTERM."""
    from facetex.studio import create_app
    from facetex.studio.jobs import Step

    code = ("import signal, subprocess, sys, time, pathlib\n"
            "signal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
            "p = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(120)'])\n"
            "pathlib.Path('pids.txt').write_text(f'{p.pid}')\n"
            "pathlib.Path('partial.out').write_bytes(b'x' * 1000)\n"
            "time.sleep(120)\n")
    app = create_app(tmp_path / "work")
    jobs = app.state.jobs
    with Server(app) as server:
        job_id, folder = jobs.new_folder()
        jobs.submit(job_id, folder, "test", [Step("sleep", [sys.executable, "-c", code]), Step("never", ["false"])],
                    outputs={"partial.out": "partial.out"})
        wait_for(lambda: (folder / "partial.out").is_file(), what="the step's output")
        grandchild = int((folder / "pids.txt").read_text())
        step = children_running("time.sleep(120)")
        assert len(step) == 1 and alive(grandchild)
        t0 = time.monotonic()
        status, job = call(f"{server.url}/api/jobs/{job_id}/cancel", "POST")
        assert status == 200 and job["state"] == "cancelled" and job["step"] == 0  # the second step never ran
        assert time.monotonic() - t0 < 15  # SIGKILL after the grace period
        wait_for(lambda: not alive(grandchild), timeout=10, what="the grandchild's end")
        assert not alive(step[0]) and not folder.exists()
    jobs.close()


def _job_folder(root: Path, name: str, age_s: float, now: float) -> Path:
    d = root / name
    (d / "sub").mkdir(parents=True)
    (d / "sub" / "result.png").write_bytes(b"png")
    os.utime(d, (now - age_s, now - age_s))
    return d


def test_cleanup_at_start_up_keeps_the_newest_job_folders_and_nothing_else(tmp_path):
    """``facetex serve --keep-jobs 2`` on a work folder an earlier server left: the two newest job
    folders stay; older ones go; a folder not named as a job, a file, and a symbolic link named as a
    job (and what it points to, outside the jobs root) stay."""
    from test_studio_server import serve, started

    root = tmp_path / "work" / "jobs"
    root.mkdir(parents=True)
    now = time.time()
    ages = {f"{k:016x}": age for k, age in enumerate([10, 5000, 20, 3000, 40_000])}
    for name, age in ages.items():
        _job_folder(root, name, age, now)
    (root / "my-notes").mkdir()
    (root / "0000000000000fff").write_text("a file named as a job")
    outside = tmp_path / "precious"
    outside.mkdir()
    (outside / "keep.txt").write_text("mine")
    (root / "00000000000000aa").symlink_to(outside, target_is_directory=True)
    os.utime(root / "00000000000000aa", (now - 90_000, now - 90_000), follow_symlinks=False)
    proc = serve("--port", "0", "--json", "--workdir", str(tmp_path / "work"), "--keep-jobs", "2", cwd=tmp_path)
    try:
        started(proc)
        left = sorted(p.name for p in root.iterdir())
        newest = sorted(sorted(ages, key=ages.get)[:2])
        assert left == sorted(newest + ["my-notes", "0000000000000fff", "00000000000000aa"]), left
        assert (outside / "keep.txt").read_text() == "mine" and (root / "00000000000000aa").is_symlink()
    finally:
        proc.terminate()
        proc.wait(30)


def test_cleanup_removes_expired_finished_jobs_periodically_but_not_running_ones(tmp_path, personas_dir):
    from facetex.studio import create_app
    from facetex.studio.jobs import Step

    app = create_app(tmp_path / "work", job_ttl=1.0, cleanup_interval=0.1)
    jobs, root = app.state.jobs, app.state.jobs.root
    persona = next(personas_dir.glob("*.persona")).read_bytes()
    with Server(app) as server:
        url = server.url
        boundary = "facetexboundary"
        body = (f"--{boundary}\r\nContent-Disposition: form-data; name=\"persona\"; filename=\"tiny.persona\"\r\n"
                "Content-Type: application/octet-stream\r\n\r\n").encode() + persona + f"\r\n--{boundary}--\r\n".encode()
        status, uploaded = call(url + "/api/personas", "POST", body,
                                {"Content-Type": f"multipart/form-data; boundary={boundary}"})
        assert status == 200 and uploaded["state"] == "done"
        # a job that runs longer than the time to live, and a folder being uploaded to (not submitted yet)
        job_id, folder = jobs.new_folder()
        jobs.submit(job_id, folder, "test", [Step("sleep", [sys.executable, "-c", "import time; time.sleep(2.5)"])],
                    outputs={})
        pending_id, pending = jobs.new_folder()
        os.utime(pending, (time.time() - 100, time.time() - 100))
        wait_for(lambda: not (root / uploaded["id"]).exists(), timeout=10, what="the expired job's removal")
        assert call(f"{url}/api/jobs/{uploaded['id']}")[0] == 404  # forgotten with its folder
        assert call(f"{url}/api/personas")[1] == []
        assert folder.is_dir() and jobs.get(job_id).state == "running" and pending.is_dir()
        wait_for(lambda: jobs.get(job_id) is None, timeout=15, what="the finished job's removal")
        assert not folder.exists() and pending.is_dir()  # still reserved: its job was not submitted
    jobs.close()
    assert [p.name for p in root.iterdir()] == [pending_id]
