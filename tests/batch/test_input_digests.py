"""Issue 23: a rerun after an input was replaced under the same name recomputes that item (and
only it), replacing its outputs; the items are keyed by the sha256 of their inputs, each input
hashed once per run. Cheap stand-ins for the real item functions (``_tasks``)."""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import uuid
from pathlib import Path

import pytest

import _tasks
from facetex.batch import InlineEngine, Item, LocalEngine, persona_items, run_batch, transfer_items
from facetex.errors import OutputError


def _items(out, srcs) -> list[Item]:
    """One item per input file: its output holds the input's text."""
    items = []
    for i, src in enumerate(srcs):
        key = f"item{i}"
        output = f"{out}/{key}.txt"
        payload = {"name": key, "output": output, "src": str(src)}
        items.append(Item(key, "test", _tasks.write_item, payload, (output, output + ".json"), {"name": key},
                          inputs=(str(src),)))
    return items


def _manifest(out: Path) -> dict:
    return {r["item"]: r for r in map(json.loads, (out / "manifest.jsonl").read_text().splitlines())}


def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _replace_keeping_time(path: Path, data: bytes) -> None:
    """New bytes, the same size and modification time: only the content tells."""
    st = path.stat()
    assert len(data) == st.st_size
    path.write_bytes(data)
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))


@pytest.fixture
def inputs(tmp_path):
    d = tmp_path / "in"
    d.mkdir()
    for name in "abc":
        (d / f"{name}.txt").write_text(f"input {name} v1\n")
    return [d / f"{name}.txt" for name in "abc"]


def test_an_input_replaced_under_its_name_recomputes_only_its_item(tmp_path, inputs, no_leftover_processes):
    out = tmp_path / "out"
    out.mkdir()
    with LocalEngine(1, threads=1) as eng:
        s = run_batch(_items(out, inputs), out, eng)
        assert s.done == 3 and s.ok
        assert _manifest(out)["item1"]["input_digests"] == {str(inputs[1]): _sha(b"input b v1\n")}
        sidecar = json.loads((out / "item1.txt.json").read_text())
        assert sidecar["batch"]["input_digests"] == {str(inputs[1]): _sha(b"input b v1\n")}
        before = {p.name: p.read_bytes() for p in out.glob("item*")}
        manifest = (out / "manifest.jsonl").read_bytes()

        s = run_batch(_items(out, inputs), out, eng)  # untouched: nothing computed, nothing written
        assert (s.done, s.skipped_done, s.inputs_changed) == (0, 3, 0)
        assert (out / "manifest.jsonl").read_bytes() == manifest

        _replace_keeping_time(inputs[1], b"input b v2\n")
        s = run_batch(_items(out, inputs), out, eng)
        assert (s.computed, s.skipped_done, s.inputs_changed) == (["item1"], 2, 1) and s.ok
        assert (out / "item1.txt").read_text() == "item1 0\ninput b v2\n" != before["item1.txt"].decode()
        assert all((out / n).read_bytes() == b for n, b in before.items() if not n.startswith("item1"))
        line = _manifest(out)["item1"]
        assert line["state"] == "done" and line["input_digests"] == {str(inputs[1]): _sha(b"input b v2\n")}
        sidecar = json.loads((out / "item1.txt.json").read_text())
        assert sidecar["batch"]["input_digests"] == line["input_digests"] and sidecar["batch"]["replace"]
        assert sorted(p.name for p in out.iterdir() if p.name.startswith(".item")) == []  # no temporaries left

        s = run_batch(_items(out, inputs), out, eng)
        assert (s.done, s.skipped_done, s.inputs_changed) == (0, 3, 0)


def test_a_persona_folder_with_one_photo_changed_is_recomputed(tmp_path):
    from facetex._provenance import _input_record

    people, out = tmp_path / "people", tmp_path / "out"
    for name, photos in (("ann", 2), ("bob", 2)):
        (people / name).mkdir(parents=True)
        for k in range(photos):
            (people / name / f"{k}.jpg").write_bytes(f"{name} photo {k}".encode())
    out.mkdir()

    def items():
        return [dataclasses.replace(it, fn=_tasks.photo_item) for it in persona_items(people, out)[0]]

    s = run_batch(items(), out, InlineEngine())
    assert sorted(s.computed) == ["ann", "bob"]
    recorded = _manifest(out)["ann"]["input_digests"]
    # the folder's digest is the one its sidecar's provenance records
    assert recorded == {str((people / "ann").resolve()): _input_record(people / "ann")["sha256_of_files"]}
    (people / "ann" / "1.jpg").write_bytes(b"ann photo X")
    (people / "bob" / ".DS_Store").write_bytes(b"hidden: not a photo")
    s = run_batch(items(), out, InlineEngine())
    assert (s.computed, s.skipped_done, s.inputs_changed) == (["ann"], 1, 1)
    assert bytes.hex(b"ann photo X") in (out / "ann.persona").read_text()
    assert run_batch(items(), out, InlineEngine()).done == 0


def test_a_shared_style_is_hashed_once_per_run(tmp_path, monkeypatch):
    from facetex.batch import _digests

    faces = tmp_path / "faces"
    faces.mkdir()
    for k in range(6):
        (faces / f"c{k}.jpg").write_text(f"content {k}\n")
    style = faces / "style.jpg"
    style.write_text("style v1\n")
    rows = [{"content": str(faces / f"c{k}.jpg"), "style": str(style)} for k in range(6)]
    out = tmp_path / "out"
    out.mkdir()
    hashed: list[str] = []
    real = _digests.file_sha256

    def counting(path):
        hashed.append(Path(path).name)
        return real(path)

    monkeypatch.setattr(_digests, "file_sha256", counting)

    def run():
        hashed.clear()
        items = [dataclasses.replace(it, fn=_tasks.pair_item) for it in transfer_items(rows, out)]
        return run_batch(items, out, InlineEngine())

    assert run().done == 6
    assert hashed.count("style.jpg") == 1 and len(hashed) == 7  # 6 contents and the style, once each
    s = run()
    assert (s.done, s.skipped_done) == (0, 6) and hashed.count("style.jpg") == 1 and len(hashed) == 7
    style.write_text("style v2\n")
    s = run()
    assert (s.done, s.inputs_changed) == (6, 6) and hashed.count("style.jpg") == 1
    assert all("style v2" in p.read_text() for p in out.glob("*.png"))


def test_records_made_before_digests_stay_done_and_get_them(tmp_path, inputs):
    """An upgrade recomputes nothing: done lines without digests stay done; their current
    digests are recorded, so a later replacement is seen."""
    out = tmp_path / "out"
    out.mkdir()
    run_batch(_items(out, inputs), out, InlineEngine())
    old = []
    for raw in (out / "manifest.jsonl").read_text().splitlines():
        line = json.loads(raw)
        line.pop("input_digests", None)
        old.append(json.dumps(line))
    (out / "manifest.jsonl").write_text("\n".join(old) + "\n")
    for p in out.glob("*.txt.json"):  # and sidecars of before
        p.write_text(json.dumps({"batch": {"item": p.name.split(".")[0]}}))
    inputs[0].write_text("input a v2, replaced before the upgrade\n")
    s = run_batch(_items(out, inputs), out, InlineEngine())
    assert (s.done, s.skipped_done, s.inputs_changed) == (0, 3, 0)
    line = _manifest(out)["item0"]
    assert line["note"] == "input digests recorded" and line["input_digests"] == {str(inputs[0]): _sha(
        inputs[0].read_bytes())}
    inputs[0].write_text("input a v3\n")
    s = run_batch(_items(out, inputs), out, InlineEngine())
    assert (s.computed, s.inputs_changed) == (["item0"], 1)


def test_a_replacement_cut_short_is_redone_and_a_lost_done_line_is_not(tmp_path, inputs):
    """The replacing worker commits the sidecar (the new digests) last: killed before it, the
    item is redone; a replacement whose done line was lost (killed run) is done."""
    out = tmp_path / "out"
    out.mkdir()
    run_batch(_items(out, inputs), out, InlineEngine())
    inputs[1].write_text("input b v2\n")
    (out / "item1.txt").write_text("item1 0\ninput b v2\n")  # the output replaced, not yet the sidecar
    manifest = (out / "manifest.jsonl").read_bytes()
    s = run_batch(_items(out, inputs), out, InlineEngine())
    assert (s.computed, s.inputs_changed) == (["item1"], 1)
    (out / "manifest.jsonl").write_bytes(manifest)  # that run's lines lost
    s = run_batch(_items(out, inputs), out, InlineEngine())
    assert (s.done, s.skipped_done, s.inputs_changed) == (0, 3, 0)
    line = _manifest(out)["item1"]
    assert line["input_digests"] == {str(inputs[1]): _sha(b"input b v2\n")} and line["note"] == \
        "input digests recorded"


def test_a_failed_item_is_tried_again_when_its_input_changed(tmp_path, inputs, no_leftover_processes):
    out = tmp_path / "out"
    out.mkdir()
    inputs[2].write_text("bad input\n")
    with LocalEngine(1, threads=1) as eng:
        s = run_batch(_items(out, inputs), out, eng)
        assert (s.done, s.failed) == (2, 1)
        s = run_batch(_items(out, inputs), out, eng)  # the same bytes: it stays failed
        assert (s.done, s.skipped_failed) == (0, 1)
        inputs[2].write_text("fixed input\n")
        s = run_batch(_items(out, inputs), out, eng)
    assert (s.computed, s.inputs_changed, s.skipped_done) == (["item2"], 1, 2) and s.ok
    assert _manifest(out)["item2"]["state"] == "done"


def test_an_output_whose_sidecar_is_not_the_batchs_is_not_replaced(tmp_path, inputs):
    out = tmp_path / "out"
    out.mkdir()
    run_batch(_items(out, inputs), out, InlineEngine())
    (out / "item1.txt.json").write_text('{"mine": true}\n')
    inputs[1].write_text("input b v2\n")
    with pytest.raises(OutputError, match=r"item1.txt.json: its item's input changed .* will not replace item1.txt"):
        run_batch(_items(out, inputs), out, InlineEngine())
    assert (out / "item1.txt").read_text() == "item1 0\ninput b v1\n"


def test_status_counts_done_items_whose_inputs_changed(tmp_path, inputs, capsys):
    from facetex.batch import batch_status
    from facetex.cli import main

    out = tmp_path / "out"
    out.mkdir()
    run_batch(_items(out, inputs), out, InlineEngine())
    assert batch_status(out)["inputs_changed"] is None  # not asked: only the folder is read
    inputs[1].write_text("input b v2\n")
    s = batch_status(out, check_inputs=True)
    assert s["inputs_changed"] == {"checked": 3, "count": 1, "items": ["item1"]}
    assert s["counts"]["done"] == 3
    assert main(["batch", "status", str(out), "--check-inputs"]) == 0
    assert "inputs changed since: 1 of 3 done items checked (item1); a rerun computes them again" in \
        capsys.readouterr().out


def test_inputs_in_object_storage_are_hashed_and_replaced_objects_recomputed(tmp_path, monkeypatch):
    """An fsspec store (memory://, no ETags): inputs hashed through fsspec, the worker's cached
    copy of a replaced input (same size) fetched again, the output object replaced."""
    import fsspec

    from facetex.batch._digests import InputDigests

    monkeypatch.setenv("FACETEX_CACHE", str(tmp_path / "cache"))
    fs = fsspec.filesystem("memory")
    root = f"memory://digests-{uuid.uuid4().hex[:8]}"
    srcs = [f"{root}/in/{n}.txt" for n in "ab"]
    try:
        for n, u in zip("ab", srcs):
            fs.pipe_file(u, f"input {n} v1\n".encode())
        d = InputDigests()
        assert d(srcs[0]) == _sha(b"input a v1\n")
        (tmp_path / "local").mkdir()
        for n in "ab":
            (tmp_path / "local" / f"{n}.txt").write_bytes(f"input {n} v1\n".encode())
        assert d(f"{root}/in") == InputDigests()(tmp_path / "local")  # a folder: the same digest as a local one

        out = f"{root}/out"
        s = run_batch(_items(out, srcs), out, InlineEngine())
        assert s.done == 2
        fs.pipe_file(srcs[1], b"input b v2\n")
        s = run_batch(_items(out, srcs), out, InlineEngine())
        assert (s.computed, s.skipped_done, s.inputs_changed) == (["item1"], 1, 1)
        assert fs.cat_file(f"{out}/item1.txt") == b"item1 0\ninput b v2\n"
        sidecar = json.loads(fs.cat_file(f"{out}/item1.txt.json"))
        assert sidecar["batch"]["input_digests"] == {srcs[1]: _sha(b"input b v2\n")}
        assert run_batch(_items(out, srcs), out, InlineEngine()).done == 0
    finally:
        fs.rm(root.replace("memory://", "/"), recursive=True)
