"""``facetex persona build`` / ``persona texture`` with bad inputs, crafted files and determinism.

Skipped while the persona commands are not registered."""

from __future__ import annotations

import json

import numpy as np
import pytest

from _robust import assert_one_error, run_cli, snapshot
from conftest import BUILD_OPTS, has_command

pytestmark = pytest.mark.skipif(not has_command("persona", "build") or not has_command("persona", "texture"),
                                reason="`facetex persona build/texture` not registered yet")


class _Payload:
    """Unpickling it creates ``marker`` (stands for arbitrary code run by np.load(allow_pickle=True))."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (open, (self.marker, "w"))


def _npz(path, head: dict | None, **arrays):
    if head is not None:
        arrays["header"] = np.frombuffer(json.dumps(head).encode(), np.uint8)
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)
    return path


_KEYS = ("images", "visibility", "fiducials", "points68", "poses", "flows", "subspace")
_HEAD = {"format": "facetex-persona", "version": 1, "parameters": {}, "photos": []}


@pytest.fixture(scope="module")
def personas(tmp_path_factory, persona_file):
    """Bad .persona files: name -> (path, cause regex)."""
    d = tmp_path_factory.mktemp("bad_personas")
    f = {}
    raw = persona_file.read_bytes()
    (d / "random.persona").write_bytes(np.random.default_rng(0).integers(0, 256, 5000, dtype=np.uint8).tobytes())
    f["random"] = (d / "random.persona", r"corrupt|not a persona")
    (d / "truncated.persona").write_bytes(raw[: len(raw) // 2])
    f["truncated"] = (d / "truncated.persona", r"corrupt|truncated")
    (d / "empty.persona").write_bytes(b"")
    f["empty"] = (d / "empty.persona", r"corrupt|empty")
    (d / "text.persona").write_text("name: Tom\n")
    f["text"] = (d / "text.persona", r"corrupt|not a persona")
    f["future"] = (_npz(d / "future.persona", {**_HEAD, "version": 99}), r"version 99")
    f["other-format"] = (_npz(d / "other.persona", {"format": "something-else", "version": 1}), r"not a persona")
    f["no-header"] = (_npz(d / "noheader.persona", None, images=np.zeros((1, 2, 2, 3), np.uint8)), r"header")
    f["missing"] = (d / "missing.persona", r"not found")
    (d / "folder.persona").mkdir()
    f["directory"] = (d / "folder.persona", r"not found|directory")
    return f


@pytest.mark.parametrize("name", ["random", "truncated", "empty", "text", "future", "other-format", "no-header",
                                  "missing", "directory"])
def test_texture_bad_persona(capsys, bad, outdir, personas, name):
    path, cause = personas[name]
    run = run_cli(capsys, "persona", "texture", path, "--like", bad["face_smiling.jpg"], "-o", outdir / "t.png")
    assert_one_error(run, names=[path], cause=cause)
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("where", ["arrays", "header"])
def test_texture_pickle_never_runs(capsys, bad, outdir, tmp_path, where):
    marker = tmp_path / "pwned"
    obj = np.empty(1, dtype=object)
    obj[0] = _Payload(marker)
    if where == "arrays":
        path = _npz(tmp_path / "evil.persona", _HEAD, **{k: obj for k in _KEYS})
    else:
        path = _npz(tmp_path / "evil.persona", None, header=obj, **{k: obj for k in _KEYS})
    # the payload works when unpickled (so the test would notice a pickle load)
    with np.load(path, allow_pickle=True) as z:
        z["images"]
    assert marker.exists()
    marker.unlink()
    run = run_cli(capsys, "persona", "texture", path, "--like", bad["face_smiling.jpg"], "-o", outdir / "t.png")
    assert not marker.exists()
    assert_one_error(run, names=[path], cause=r"corrupt|pickle|object")
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("ref, cause", [("noface.png", r"no face"), ("empty.jpg", r"empty"),
                                        ("truncated.jpg", r"truncated"), ("bomb.png", r"bomb|limit"),
                                        ("folder.jpg", r"directory")])
def test_texture_bad_reference(capsys, bad, outdir, persona_file, ref, cause):
    run = run_cli(capsys, "persona", "texture", persona_file, "--like", bad[ref], "-o", outdir / "t.png")
    assert_one_error(run, names=[bad[ref]], cause=cause)
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("content, cause", [("{not json", r"json"), ("[[1, 2], [3, 4]]", r"49"),
                                            ('{"fiducials": "many"}', r"49")])
def test_texture_bad_fiducials(capsys, outdir, tmp_path, persona_file, content, cause):
    fid = tmp_path / "points.json"
    fid.write_text(content)
    run = run_cli(capsys, "persona", "texture", persona_file, "--fiducials", fid, "-o", outdir / "t.png")
    assert_one_error(run, names=[fid], cause=cause)
    assert snapshot(outdir) == {}


def test_texture_existing_output(capsys, bad, outdir, persona_file):
    out = outdir / "t.png"
    out.write_bytes(b"old")
    run = run_cli(capsys, "persona", "texture", persona_file, "--like", bad["face_smiling.jpg"], "-o", out)
    assert_one_error(run, names=[out], cause=r"exists.*--overwrite")
    assert out.read_bytes() == b"old" and sorted(p.name for p in outdir.iterdir()) == ["t.png"]


@pytest.mark.parametrize("ref", ["cmyk.jpg", "gray_alpha.png"])
def test_texture_unusual_reference_works(capsys, bad, outdir, persona_file, ref):
    run = run_cli(capsys, "persona", "texture", persona_file, "--like", bad[ref], "-o", outdir / "t.png")
    assert run.code == 0, run.err
    assert "Traceback" not in run.err and run.lines == [], run.lines
    assert sorted(p.name for p in outdir.iterdir()) == ["t.png", "t.png.json"]


# ------------------------------------------------------------------------------ build
def _folder(tmp_path, bad, kind):
    d = tmp_path / kind
    if kind == "missing":
        return d
    if kind == "a-file":
        d.write_text("not a folder")
        return d
    d.mkdir()
    if kind == "non-images":
        (d / "notes.txt").write_text("hello")
        (d / "data.csv").write_text("1,2,3")
    elif kind == "junk-images":
        for n in ("empty.jpg", "random.jpg", "text.png", "truncated.jpg", "noface.png", "tiny.png"):
            (d / n).write_bytes(bad[n].read_bytes())
    return d


@pytest.mark.parametrize("kind, cause", [("empty", r"no images"), ("non-images", r"no images"),
                                         ("junk-images", r"only 0 usable"), ("missing", r"not found"),
                                         ("a-file", r"not found|not a folder")])
def test_build_bad_folder(capsys, bad, outdir, tmp_path, kind, cause):
    folder = _folder(tmp_path, bad, kind)
    run = run_cli(capsys, "persona", "build", folder, "-o", outdir / "p.persona", *BUILD_OPTS)
    assert_one_error(run, names=[folder], cause=cause)
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("target, cause", [("missing/p.persona", r"does not exist"), ("p.persona", r"exists")])
def test_build_bad_output(capsys, outdir, photo_dir, target, cause):
    (outdir / "p.persona").write_bytes(b"old")
    before = snapshot(outdir)
    run = run_cli(capsys, "persona", "build", photo_dir, "-o", outdir / target, *BUILD_OPTS)
    assert_one_error(run, names=[outdir / target], cause=cause)
    assert snapshot(outdir) == before


def test_build_and_texture_deterministic(capsys, bad, outdir, photo_dir, persona_file):
    from facetex.persona import load_persona

    run = run_cli(capsys, "persona", "build", photo_dir, "-o", outdir / "again.persona", *BUILD_OPTS)
    assert run.code == 0, run.err
    a, b = load_persona(persona_file), load_persona(outdir / "again.persona")
    for k in _KEYS:
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k), err_msg=k)
    assert (a.photos, a.skipped, a.params) == (b.photos, b.skipped, b.params)
    for name in ("t1.png", "t2.png"):
        run = run_cli(capsys, "persona", "texture", persona_file, "--like", bad["face_smiling.jpg"], "-o",
                      outdir / name)
        assert run.code == 0, run.err
    assert (outdir / "t1.png").read_bytes() == (outdir / "t2.png").read_bytes()
