"""``facetex serve`` as a user starts it: a real uvicorn server on a free localhost port, in a child
process started by the test; the pages and the API answer; Ctrl-C stops it; a port in use is one
error line; a non-local address is warned about."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.parse
import urllib.request

import pytest

pytest.importorskip("uvicorn", reason="the studio extra is not installed (pip install -e '.[studio]')")


def serve(*args: str, cwd) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in [os.getcwd(), os.environ.get("PYTHONPATH", "")] if p))
    return subprocess.Popen([sys.executable, "-m", "facetex", "serve", *args], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def get(url: str) -> bytes:
    with urllib.request.urlopen(url, timeout=30) as r:
        return r.read()


def started(proc: subprocess.Popen) -> dict:
    """The JSON ``--json`` prints once the server listens (several lines, indented)."""
    lines = []
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if not line:
            raise AssertionError(f"serve exited {proc.wait()}: {proc.stderr.read()}")
        lines.append(line)
        if line.rstrip() == "}":
            return json.loads("".join(lines))
    raise AssertionError("serve did not say it listens")


def test_serve_answers_on_a_free_localhost_port_and_stops_on_ctrl_c(tmp_path):
    proc = serve("--port", "0", "--json", "--workdir", str(tmp_path / "work"), "--max-upload-mb", "5", cwd=tmp_path)
    try:
        info = started(proc)
        url = info["url"]
        assert url.startswith("http://127.0.0.1:") and info["workdir"] == str((tmp_path / "work").resolve())
        assert json.loads(get(url + "api/info"))["max_upload_mb"] == 5
        assert "Texture transfer" in get(url + "transfer").decode()
        form = urllib.parse.urlencode({"content_sample": "frl_004_neutral.jpg"}).encode()
        with pytest.raises(urllib.error.HTTPError) as e:
            urllib.request.urlopen(url + "api/transfer", data=form, timeout=30)
        assert e.value.code == 400
        assert json.loads(e.value.read()) == {"error": "no style image: upload one or pick a sample"}
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0
        assert "Traceback" not in proc.stderr.read()
    finally:
        proc.kill()
        proc.wait()


def test_a_port_in_use_is_one_line_and_a_remote_host_is_warned_about(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.2", 0))
        s.listen()
        port = s.getsockname()[1]
        proc = serve("--host", "127.0.0.2", "--port", str(port), "-q", cwd=tmp_path)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 2
    assert "facetex: warning: --host 127.0.0.2: the studio is reachable from other machines" in err
    assert f"facetex: error: cannot listen on 127.0.0.2:{port}" in err
    assert "Traceback" not in err
