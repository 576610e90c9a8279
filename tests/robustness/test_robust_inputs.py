"""Bad and unusual inputs to ``landmarks``, ``identity``, ``metrics`` and ``transfer``:
one clear stderr line naming the file, the right exit code, nothing written."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest

from _robust import assert_one_error, run_cli, snapshot

T = ["--size", "64", "--iters", "2"]  # fast transfer options

# (id, argv, files the line must name, cause regex). "%key" = generated input, "@name" = output folder entry.
ERRORS = [
    ("landmarks-zero-byte", ["landmarks", "%empty.jpg"], ["%empty.jpg"], r"empty|0 bytes"),
    ("landmarks-truncated-jpeg", ["landmarks", "%truncated.jpg"], ["%truncated.jpg"], r"truncated|corrupt"),
    ("landmarks-random-bytes", ["landmarks", "%random.jpg"], ["%random.jpg"], r"not an image"),
    ("landmarks-text-file", ["landmarks", "%text.png"], ["%text.png"], r"not an image"),
    ("landmarks-directory", ["landmarks", "%folder.jpg"], ["%folder.jpg"], r"directory"),
    ("landmarks-missing", ["landmarks", "%missing.jpg"], ["%missing.jpg"], r"not found"),
    ("landmarks-1x1", ["landmarks", "%tiny.png"], ["%tiny.png"], r"1x1"),
    ("landmarks-bomb", ["landmarks", "%bomb.png"], ["%bomb.png"], r"20000x20000.*(bomb|limit)"),
    ("landmarks-no-face", ["landmarks", "%noface.png"], ["%noface.png"], r"no face"),
    ("landmarks-face-index", ["landmarks", "%face.jpg", "--face-index", "5"], ["%face.jpg"], r"out of range"),
    ("landmarks-out-missing-folder", ["landmarks", "%face.jpg", "-o", "@missing/o.png"], ["@missing/o.png"],
     r"does not exist"),
    ("landmarks-out-under-file", ["landmarks", "%face.jpg", "-o", "@afile/o.png"], ["@afile/o.png"],
     r"not a folder|not a directory"),
    ("landmarks-out-exists", ["landmarks", "%face.jpg", "-o", "@exists.png"], ["@exists.png"], r"exists.*--overwrite"),
    ("landmarks-out-is-dir", ["landmarks", "%face.jpg", "-o", "@sub"], ["@sub"], r"directory"),
    ("landmarks-out-bad-ext", ["landmarks", "%face.jpg", "-o", "@o.xyz"], ["@o.xyz"], r"extension"),
    ("identity-zero-byte-a", ["identity", "%empty.jpg", "%face.jpg"], ["%empty.jpg"], r"empty"),
    ("identity-no-face-b", ["identity", "%face.jpg", "%noface.png"], ["%noface.png"], r"no face"),
    ("identity-bomb-b", ["identity", "%face.jpg", "%bomb.png"], ["%bomb.png"], r"bomb|limit"),
    ("identity-truncated-a", ["identity", "%truncated.jpg", "%face.jpg"], ["%truncated.jpg"], r"truncated"),
    ("metrics-text-style", ["metrics", "%face.jpg", "%face.jpg", "%text.png"], ["%text.png"], r"not an image"),
    ("metrics-1x1-output", ["metrics", "%tiny.png", "%face.jpg", "%face.jpg"], ["%tiny.png"], r"1x1"),
    ("metrics-no-face-content", ["metrics", "%face.jpg", "%noface.png", "%face.jpg"], ["%noface.png"], r"no face"),
    ("metrics-directory-style", ["metrics", "%face.jpg", "%face.jpg", "%folder.jpg"], ["%folder.jpg"], r"directory"),
    ("transfer-zero-byte-content", ["transfer", "%empty.jpg", "%face.jpg", "-o", "@t.png", *T], ["%empty.jpg"],
     r"empty"),
    ("transfer-random-content", ["transfer", "%random.jpg", "%face.jpg", "-o", "@t.png", *T], ["%random.jpg"],
     r"not an image"),
    ("transfer-truncated-style", ["transfer", "%face.jpg", "%truncated.jpg", "-o", "@t.png", *T],
     ["%truncated.jpg"], r"truncated"),
    ("transfer-no-face-style", ["transfer", "%face.jpg", "%noface.png", "-o", "@t.png", *T], ["%noface.png"],
     r"no face"),
    ("transfer-bomb-content", ["transfer", "%bomb.png", "%face.jpg", "-o", "@t.png", *T], ["%bomb.png"],
     r"bomb|limit"),
    ("transfer-out-missing-folder", ["transfer", "%face.jpg", "%other.jpg", "-o", "@missing/t.png", *T],
     ["@missing/t.png"], r"does not exist"),
    ("transfer-out-exists", ["transfer", "%face.jpg", "%other.jpg", "-o", "@exists.png", *T], ["@exists.png"],
     r"exists.*--overwrite"),
    ("transfer-out-under-file", ["transfer", "%face.jpg", "%other.jpg", "-o", "@afile/t.png", *T],
     ["@afile/t.png"], r"not a folder|not a directory"),
]


def _args(argv, bad, outdir):
    def one(a):
        if a.startswith("%"):
            return str(bad[a[1:]])
        if a.startswith("@"):
            return str(outdir / a[1:])
        return a
    return [one(a) for a in argv]


def _prepare(outdir):
    (outdir / "exists.png").write_bytes(b"old output")
    (outdir / "afile").write_bytes(b"a file, not a folder")
    (outdir / "sub").mkdir()


@pytest.mark.parametrize("argv, names, cause", [c[1:] for c in ERRORS], ids=[c[0] for c in ERRORS])
def test_bad_input_one_line_no_output(capsys, bad, outdir, argv, names, cause):
    _prepare(outdir)
    before = snapshot(outdir)
    run = run_cli(capsys, *_args(argv, bad, outdir))
    assert_one_error(run, names=_args(names, bad, outdir), cause=cause)
    assert snapshot(outdir) == before  # nothing written, replaced or left behind (temp files included)
    assert run.out == ""


@pytest.mark.skipif(not hasattr(os, "geteuid") or os.geteuid() == 0, reason="root ignores folder permissions")
def test_read_only_output_folder(capsys, bad, outdir):
    ro = outdir / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", ro / "o.png")
        assert_one_error(run, names=[ro / "o.png"], cause="not writable")
        assert list(ro.iterdir()) == []
    finally:
        ro.chmod(0o700)


@pytest.mark.parametrize("where", ["before", "after"])
def test_debug_shows_traceback(capsys, bad, where):
    argv = ["landmarks", str(bad["empty.jpg"])]
    argv = ["--debug", *argv] if where == "before" else [*argv, "--debug"]
    run = run_cli(capsys, *argv)
    assert run.code == 2
    assert "Traceback (most recent call last)" in run.err
    assert run.err.strip().splitlines()[-1].startswith("facetex: error:")
    assert "empty.jpg" in run.err.strip().splitlines()[-1]


def _points(capsys, path):
    run = run_cli(capsys, "landmarks", path, "--json")
    assert run.code == 0, run.err
    assert "Traceback" not in run.err and run.lines == [], run.lines
    return json.loads(run.out)["faces"]


@pytest.fixture(scope="module")
def reference_points(bad):
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    return detect_faces(read_image(bad["face.jpg"]), upsample=None)[0].points68


@pytest.mark.parametrize("name", ["gray.jpg", "gray_alpha.png", "rgba.png", "palette.png", "cmyk.jpg", "rgb16.png"])
def test_unusual_encodings_work(capsys, bad, reference_points, name):
    faces = _points(capsys, bad[name])
    assert len(faces) == 1
    p = np.asarray(faces[0]["points68"])
    # same face, same geometry: the landmarks agree with the plain RGB JPEG's
    assert np.abs(p - reference_points).mean() < 2.0


def test_exif_rotation_gives_displayed_orientation(capsys, bad, tmp_path, reference_points):
    from PIL import Image

    path = bad["exif_rot6.jpg"]
    with Image.open(path) as im:
        stored = np.asarray(im.convert("RGB"))  # raw decode: orientation not applied
    assert stored.shape[:2] == (400, 400)
    displayed = np.rot90(stored, -1)  # orientation 6 = turn 90° clockwise to display
    Image.fromarray(np.ascontiguousarray(displayed)).save(tmp_path / "displayed.png")
    Image.fromarray(stored).save(tmp_path / "stored.png")
    got = np.asarray(_points(capsys, path)[0]["points68"])
    want = np.asarray(_points(capsys, tmp_path / "displayed.png")[0]["points68"])
    np.testing.assert_allclose(got, want, atol=0.02)
    # and not the stored orientation: eyes side by side (x differs), not one above the other
    assert abs(got[45, 0] - got[36, 0]) > 3 * abs(got[45, 1] - got[36, 1])
    assert np.abs(got - reference_points).mean() < 2.0
    stored_faces = run_cli(capsys, "landmarks", tmp_path / "stored.png", "--json")
    if stored_faces.code == 0 and json.loads(stored_faces.out)["faces"]:  # HOG may find the sideways face: it differs
        p = np.asarray(json.loads(stored_faces.out)["faces"][0]["points68"])
        assert np.abs(p - got).mean() > 20


def test_several_faces_largest_first(capsys, bad):
    faces = _points(capsys, bad["twofaces.png"])
    assert len(faces) == 2
    boxes = np.asarray([f["box"] for f in faces])
    areas = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    assert areas[0] > areas[1]
    assert boxes[0, 2] <= 400  # the large face is the left one (the 400 px sample)


@pytest.mark.parametrize("image, same", [("twofaces.png", True), ("twofaces_swapped.png", False)])
def test_identity_uses_largest_face(capsys, bad, image, same):
    run = run_cli(capsys, "identity", bad[image], bad["face_smiling.jpg"], "--json")
    assert run.code == 0, run.err
    assert json.loads(run.out)["same_person"] is same


def test_metrics_accepts_unusual_encodings(capsys, bad):
    run = run_cli(capsys, "metrics", bad["rgb16.png"], bad["cmyk.jpg"], bad["palette.png"], "--json")
    assert run.code == 0, run.err
    assert run.lines == []
    res = json.loads(run.out)
    # the same face, re-encoded: ~1 px apart (E is px² at 1000 px), same identity
    assert res["E_content"] < 20 and res["identity_content"] < 0.3


def test_overwrite_replaces_only_with_flag(capsys, bad, outdir):
    out = outdir / "o.png"
    out.write_bytes(b"old output")
    run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", out)
    assert run.code == 2 and out.read_bytes() == b"old output"
    run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", out, "--overwrite")
    assert run.code == 0, run.err
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert sorted(p.name for p in outdir.iterdir()) == ["o.png", "o.png.json"]  # no temp file left
    assert oct(out.stat().st_mode & 0o777) != oct(0o600)  # not mkstemp's private mode
