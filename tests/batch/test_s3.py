"""``facetex batch transfer`` with inputs and ``--out`` in object storage: a local S3-compatible
server (moto's, started here on a free port), real transfers (size 96, 2 iterations per level),
outputs and manifest in the bucket, a resume that computes nothing, a failure recorded, and
exclusive creates that hold on the server."""

from __future__ import annotations

import json
import socket

import pytest

from facetex._resources import sample_path
from facetex.cli import main

moto_server = pytest.importorskip("moto.server")
s3fs = pytest.importorskip("s3fs")

SMALL = ["--size", "96", "--iters", "2,2,2"]
FACES = ("frl_004_neutral.jpg", "frl_005_neutral.jpg", "frl_008_neutral.jpg")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture
def s3(monkeypatch, tmp_path):
    """A moto S3 server on 127.0.0.1, the environment pointing every client (this process and
    the workers it spawns) at it with dummy credentials; yields an s3fs filesystem."""
    port = _free_port()
    server = moto_server.ThreadedMotoServer(ip_address="127.0.0.1", port=port, verbose=False)
    server.start()
    import urllib.request

    # the server keeps moto's in-process state: start each test with an empty one
    urllib.request.urlopen(urllib.request.Request(f"http://127.0.0.1:{port}/moto-api/reset", method="POST"))
    for k, v in {"AWS_ACCESS_KEY_ID": "testing", "AWS_SECRET_ACCESS_KEY": "testing", "AWS_SESSION_TOKEN": "testing",
                 "AWS_DEFAULT_REGION": "us-east-1", "AWS_ENDPOINT_URL": f"http://127.0.0.1:{port}",
                 "FACETEX_CACHE": str(tmp_path / "cache")}.items():
        monkeypatch.setenv(k, v)
    s3fs.S3FileSystem.clear_instance_cache()
    fs = s3fs.S3FileSystem(use_listings_cache=False)
    fs.mkdir("faces")
    try:
        yield fs
    finally:
        s3fs.S3FileSystem.clear_instance_cache()
        server.stop()


def _manifest(fs, url: str) -> dict:
    return {r["item"]: r for r in map(json.loads, fs.cat_file(url).decode().splitlines())}


def test_batch_transfer_on_s3_resumes_and_records_failures(s3, tmp_path, capsys, no_leftover_processes):
    for name in FACES:
        s3.put_file(str(sample_path(name)), f"faces/in/{name}")
    s3.pipe_file("faces/in/broken.jpg", b"not an image\n")
    s3.pipe_file("faces/pairs.csv", (f"content,style\nin/{FACES[0]},in/{FACES[1]}\ns3://faces/in/{FACES[2]},"
                                     f"in/{FACES[0]}\nin/broken.jpg,in/{FACES[1]}\n").encode())
    out = "s3://faces/runs/aug"
    args = ["batch", "transfer", "s3://faces/pairs.csv", "--out", out, "--jobs", "2", *SMALL]
    assert main(args) == 4  # the broken image failed
    captured = capsys.readouterr()
    assert "facetex: transfer item broken__frl_005_neutral__facetex failed:" in captured.err
    first, second = "frl_004_neutral__frl_005_neutral__facetex", "frl_008_neutral__frl_004_neutral__facetex"
    assert f"wrote {out}/{first}.png" in captured.out and f"wrote {out}/manifest.jsonl" in captured.out
    names = set(s3.ls("faces/runs/aug", detail=False))
    for key in (first, second):
        assert {f"faces/runs/aug/{key}.png", f"faces/runs/aug/{key}.png.json"} <= names
        assert s3.cat_file(f"faces/runs/aug/{key}.png")[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [n for n in names if "broken" in n]  # no partial output of the failed item
    rec = json.loads(s3.cat_file(f"faces/runs/aug/{second}.png.json"))
    assert rec["inputs"]["content"]["path"] == f"s3://faces/in/{FACES[2]}"  # the URLs, not the local copies
    assert rec["outputs"] == [f"{out}/{second}.png"] and rec["threads"] == 1
    m = _manifest(s3, f"{out}/manifest.jsonl")
    assert m[first]["state"] == "done" and m[first]["outputs"] == [f"{first}.png", f"{first}.png.json"]
    bad = m["broken__frl_005_neutral__facetex"]
    assert bad["state"] == "failed" and "broken.jpg" in bad["error"]
    failure = json.loads(s3.cat_file("faces/runs/aug/.facetex-batch/items/broken__frl_005_neutral__facetex.json"))
    assert failure["state"] == "failed" and failure["error"] == bad["error"]
    assert not s3.ls("faces/runs/aug/.facetex-batch/claims") if s3.exists("faces/runs/aug/.facetex-batch/claims") \
        else True  # every claim released
    size = len(s3.cat_file(f"{out}/manifest.jsonl"))

    # resumed: nothing is computed again, the failure stays failed, the manifest only grows
    assert main([*args, "--json"]) == 4
    s = json.loads(capsys.readouterr().out)
    assert (s["done"], s["skipped_done"], s["skipped_failed"], s["failed"]) == (0, 2, 1, 0)
    data = s3.cat_file(f"{out}/manifest.jsonl")
    assert len(data) >= size

    # the status of the folder in the bucket
    assert main(["batch", "status", out, "--json"]) == 0
    st = json.loads(capsys.readouterr().out)
    assert st["counts"]["done"] == 2 and st["counts"]["failed"] == 1 and st["total"] == 3
    assert st["failures"][0]["count"] == 1 and st["failures"][0]["items"] == ["broken__frl_005_neutral__facetex"]


def test_exclusive_creates_hold_on_the_server(s3):
    from facetex.batch._claims import Claims
    from facetex.batch._store import FsspecStore

    store = FsspecStore("s3://faces/state")
    store.create("s3://faces/state/x", b"1")
    with pytest.raises(FileExistsError):
        store.create("s3://faces/state/x", b"2")
    assert store.read("s3://faces/state/x") == b"1"
    a, b = Claims("s3://faces/state/claims", timeout=60), Claims("s3://faces/state/claims", timeout=60)
    assert a.acquire("item") is not None and b.acquire("item") is None  # one winner
    assert b.holder("item")["run"] == a.run and not b.holder("item")["expired"]
    a.release("item")
    assert b.acquire("item") is not None


def test_a_store_without_exclusive_creates_is_refused_before_any_work(monkeypatch, tmp_path):
    """A server that ignores If-None-Match would let two runs replace each other's outputs."""
    import _tasks
    from facetex.batch import InlineEngine, Item, run_batch
    from facetex.batch._store import FsspecStore
    from facetex.errors import OutputError

    out = "memory://bucket/aug"
    it = Item("a", "test", _tasks.write_item, {"name": "a", "output": f"{out}/a.txt", "log": str(tmp_path / "log")},
              (f"{out}/a.txt", f"{out}/a.txt.json"), {"a": 1})
    monkeypatch.setattr(FsspecStore, "create", FsspecStore.put)  # "xb" silently treated as "wb"
    with pytest.raises(OutputError, match="does not honour exclusive creates"):
        run_batch([it], out, InlineEngine(threads=1))
    assert not (tmp_path / "log").exists()  # refused before any work
