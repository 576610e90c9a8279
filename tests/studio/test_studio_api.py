"""The studio's HTTP API with Starlette's TestClient: pages, uploads and their one-line errors,
limits, path traversal attempts, the job queue's order and its full-queue refusal."""

from __future__ import annotations

import io
import json
import sys
import time
import zipfile

import numpy as np
import pytest

from facetex._resources import sample_path

pytest.importorskip("fastapi", reason="the studio extra is not installed (pip install -e '.[studio]')")


@pytest.fixture()
def app(tmp_path):
    from facetex.studio import create_app

    app = create_app(tmp_path / "work", max_upload_mb=1)
    yield app
    app.state.jobs.close()


@pytest.fixture()
def client(app):
    from fastapi.testclient import TestClient

    with TestClient(app) as c:
        yield c


def jpeg(name: str = "frl_004_neutral.jpg") -> bytes:
    return sample_path(name).read_bytes()


def wait(client, job_id: str, timeout: float = 120) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/api/jobs/{job_id}").json()
        if job["state"] in ("done", "failed"):
            return job
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} did not finish: {job}")


def one_line_error(r, status: int) -> str:
    assert r.status_code == status, r.text
    msg = r.json()["error"]
    assert isinstance(msg, str) and msg and "\n" not in msg and "Traceback" not in msg
    return msg


def test_pages_static_files_and_info(client):
    for url in ("/", "/transfer", "/persona", "/puppet", "/live"):
        r = client.get(url)
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
        assert "/static/studio.js" in r.text and "http://" not in r.text and "https://" not in r.text  # offline
    assert client.get("/static/studio.css").status_code == 200
    info = client.get("/api/info").json()
    assert "preview" in info["presets"] and "facetex" in info["methods"]
    assert "frl_004_neutral.jpg" in info["samples"] and info["max_upload_mb"] == 1
    assert client.get("/api/samples/frl_004_neutral.jpg").content == jpeg()


def test_bad_uploads_get_one_line_errors(client, tmp_path):
    r = client.post("/api/transfer", files={"content": ("face.jpg", b"not an image")},
                    data={"style_sample": "frl_005_neutral.jpg"})
    assert one_line_error(r, 400).startswith("face.jpg: not an image")
    r = client.post("/api/transfer", files={"content": ("face.gif", b"GIF89a")}, data={"style_sample": "frl_005_neutral.jpg"})
    assert ".jpg" in one_line_error(r, 400)
    r = client.post("/api/transfer", files={"content": ("face.png", b"")}, data={"style_sample": "frl_005_neutral.jpg"})
    assert "empty" in one_line_error(r, 400)
    assert "no style image" in one_line_error(client.post("/api/transfer", data={"content_sample": "frl_004_neutral.jpg"}), 400)
    r = client.post("/api/transfer", data={"content_sample": "frl_004_neutral.jpg", "style_sample": "x.jpg"})
    assert "no bundled sample" in one_line_error(r, 400)
    r = client.post("/api/transfer", data={"content_sample": "frl_004_neutral.jpg", "style_sample": "frl_005_neutral.jpg",
                                           "method": "magic"})
    assert "unknown method" in one_line_error(r, 400)
    r = client.post("/api/transfer", data={"content_sample": "frl_004_neutral.jpg", "style_sample": "frl_005_neutral.jpg",
                                           "size": "huge"})
    assert one_line_error(r, 400).startswith("size:")
    r = client.post("/api/persona", files=[("photos", ("a.jpg", jpeg()))], data={"min_photos": "3"})
    assert "1 photo(s) uploaded, fewer than the 3" in one_line_error(r, 400)
    r = client.post("/api/personas", files={"persona": ("bob.persona", b"garbage" * 100)})
    assert one_line_error(r, 400).startswith("bob.persona: ")
    r = client.post("/api/puppet", files={"driver": ("clip.mp4", b"x")}, data={"persona": "job-0000000000000000"})
    assert "no persona" in one_line_error(r, 400)
    # nothing of the refused jobs is left behind
    assert not any((tmp_path / "work" / "jobs").iterdir())


def test_upload_size_limit(client):
    big = b"\xff\xd8" + b"\0" * (2 * 2**20)
    r = client.post("/api/transfer", files={"content": ("big.jpg", big)}, data={"style_sample": "frl_005_neutral.jpg"})
    assert "upload limit of 1 MB" in one_line_error(r, 413)


def test_a_zip_over_the_limit_uncompressed_is_refused(client):
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("bomb.jpg", b"\0" * (3 * 2**20))  # 3 MB of zeros: a few kB compressed
    r = client.post("/api/persona", files=[("photos", ("photos.zip", buf.getvalue()))], data={"min_photos": "3"})
    assert "uncompressed" in one_line_error(r, 413)


def test_no_request_string_reaches_a_path(client, app, tmp_path):
    work = tmp_path / "work"
    for url in ("/api/jobs/..%2F..%2Fetc/files/passwd", "/api/jobs/0123456789abcdef/files/..%2F..%2Fetc%2Fpasswd",
                "/static/..%2Fapp.py", "/static/../app.py", "/api/samples/..%2F..%2F__init__.py",
                "/api/samples/%2Fetc%2Fpasswd", "/api/jobs/..", "/api/jobs/%2e%2e%2f%2e%2e/events"):
        r = client.get(url)
        assert r.status_code == 404, (url, r.status_code)
        assert b"root:" not in r.content and b"import" not in r.content
    # an upload's name picks only the extension: saved as content.jpg inside its job
    r = client.post("/api/transfer", files={"content": ("../../../evil.jpg", jpeg()),
                                            "style": ("..\\..\\evil2.jpg", jpeg("frl_005_neutral.jpg"))},
                    data={"preset": "preview"})
    assert r.status_code == 200, r.text
    job = r.json()
    assert job["info"]["content"] == "evil.jpg" and job["info"]["style"] == "evil2.jpg"
    folder = work / "jobs" / job["id"]
    assert (folder / "content.jpg").is_file() and (folder / "style.jpg").is_file()
    assert not list(tmp_path.rglob("evil*"))
    # a zip's member names too: photo_000.jpg ... inside the job's photos/
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        for k in range(3):
            z.writestr(f"../../../zip_evil_{k}.jpg", jpeg())
        z.writestr("/abs_evil.png", jpeg())
        z.writestr("notes.txt", b"skipped")
    r = client.post("/api/persona", files=[("photos", ("x.zip", buf.getvalue()))], data={"min_photos": "3"})
    assert r.status_code == 200, r.text
    photos = sorted(p.name for p in (work / "jobs" / r.json()["id"] / "photos").iterdir())
    assert photos == ["photo_000.jpg", "photo_001.jpg", "photo_002.jpg", "photo_003.png"]
    assert not list(tmp_path.rglob("*evil*"))
    # a job's files are served by their names in the job's table only
    assert client.get(f"/api/jobs/{job['id']}/files/content").content == jpeg()
    assert client.get(f"/api/jobs/{job['id']}/files/content.jpg").status_code == 404
    r = client.post("/api/puppet", files={"driver": ("clip.mp4", b"x")}, data={"persona": f"../{job['id']}"})
    assert "no persona" in one_line_error(r, 400)


def test_failed_job_shows_the_cli_line_without_server_paths(client, tmp_path):
    from facetex.io import encode_image

    grey = encode_image("grey.png", np.full((200, 160, 3), 0.5, np.float32))
    r = client.post("/api/transfer", files={"content": ("wall.png", grey)},
                    data={"style_sample": "frl_005_neutral.jpg", "preset": "preview"})
    job = wait(client, r.json()["id"])
    assert job["state"] == "failed"
    assert job["error"].startswith("content.png: ") and "face" in job["error"], job["error"]
    assert str(tmp_path) not in job["error"] and "\n" not in job["error"]


def _sleeper(seconds: float, mark: str) -> list[str]:
    """A step that records when it starts and ends (the queue runs any command line)."""
    code = (f"import time, pathlib; p = pathlib.Path('order.txt'); p.write_text('start {mark} ' + repr(time.time()));"
            f"time.sleep({seconds}); print('{{\"mark\": \"{mark}\"}}')")
    return [sys.executable, "-c", code]


def test_jobs_run_one_at_a_time_in_order_and_a_full_queue_refuses(tmp_path):
    from facetex.studio.jobs import JobQueue, QueueFullError, Step

    q = JobQueue(tmp_path, workers=1, max_queued=2)
    try:
        ids = []
        for k in range(3):
            job_id, folder = q.new_folder()
            q.submit(job_id, folder, "test", [Step("sleep", _sleeper(0.5, str(k)))], outputs={})
            ids.append(job_id)
            if k == 0:
                deadline = time.monotonic() + 10
                while q.get(job_id).state == "queued" and time.monotonic() < deadline:
                    time.sleep(0.02)
        assert [q.position(i) for i in ids] == [None, 0, 1]  # the first runs, two wait in order
        job_id, folder = q.new_folder()
        with pytest.raises(QueueFullError, match="queue is full"):
            q.submit(job_id, folder, "test", [Step("sleep", _sleeper(0, "x"))], outputs={})
        deadline = time.monotonic() + 30
        while any(q.get(i).state != "done" for i in ids) and time.monotonic() < deadline:
            time.sleep(0.05)
        jobs = [q.get(i) for i in ids]
        assert [j.state for j in jobs] == ["done"] * 3
        assert [j.result["sleep"]["mark"] for j in jobs] == ["0", "1", "2"]
        for a, b in zip(jobs, jobs[1:]):  # never two at once: each starts after the one before ended
            assert b.started >= a.finished - 0.01
    finally:
        q.close()


def test_progress_and_error_are_read_from_the_command(tmp_path):
    from facetex.studio.jobs import JobQueue, Step

    q = JobQueue(tmp_path)
    code = ("import sys, time\n"
            "for n in range(1, 5):\n"
            "    sys.stderr.write(f'\\rpersona:  {25*n}%|##   | {n}/4 [00:01<00:01, 1.0step/s, stage=frontalize]')\n"
            "    sys.stderr.flush(); time.sleep(0.15)\n"
            "sys.stderr.write('\\nfacetex: error: ' + sys.argv[1] + '/photos/a.jpg: no face found\\n'); sys.exit(2)\n")
    try:
        job_id, folder = q.new_folder()
        q.submit(job_id, folder, "test", [Step("build", [sys.executable, "-c", code, str(folder)])], outputs={})
        seen = set()
        deadline = time.monotonic() + 30
        while q.get(job_id).state != "failed" and time.monotonic() < deadline:
            j = q.get(job_id)
            seen.add((j.stage, round(j.progress, 2)))
            time.sleep(0.03)
        job = q.get(job_id)
        assert job.error == "photos/a.jpg: no face found"
        assert ("build: frontalize", 0.5) in seen or ("build: frontalize", 0.75) in seen, seen
        assert json.dumps(job.public())  # the page's JSON
    finally:
        q.close()


def test_a_full_queue_is_a_503_with_one_line(tmp_path):
    from fastapi.testclient import TestClient

    from facetex.studio import create_app

    app = create_app(tmp_path / "work", max_queued=1, workers=1)
    app.state.jobs.close()  # no worker: the jobs stay queued
    with TestClient(app) as c:
        data = {"content_sample": "frl_004_neutral.jpg", "style_sample": "frl_005_neutral.jpg"}
        assert c.post("/api/transfer", data=data).status_code == 200
        assert "queue is full" in one_line_error(c.post("/api/transfer", data=data), 503)
        jobs = c.get("/api/jobs").json()
        assert [j["state"] for j in jobs] == ["queued"] and jobs[0]["position"] == 0


def test_live_socket_refuses_an_unknown_persona(client):
    with client.websocket_connect("/api/live?persona=../../etc/passwd") as ws:
        msg = ws.receive_json()
    assert "no persona" in msg["error"]
