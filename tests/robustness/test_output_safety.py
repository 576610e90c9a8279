"""Issue 13, data loss: no output replaces a file the user did not name.

Sidecars and step files are existing files too; a file that appears during the run is
never replaced (exclusive create on the final name); an output that is one of the inputs
is refused whatever the flags; a device or FIFO is never replaced by a regular file; an
image is never left without its sidecar."""

from __future__ import annotations

import errno
import os
import stat
import subprocess
import sys

import pytest

import facetex.io as fio
from facetex.errors import OutputError
import facetex.transfer._pipeline as pipeline
from _robust import assert_one_error, run_cli, sha1s, snapshot
from conftest import has_command

T = ["--size", "64", "--iters", "2"]  # 1 level, 2 loss evaluations (budget 1.25 × 2)


def _optimize_then(monkeypatch, action):
    """Run ``action()`` at the first progress callback of the optimisation (mid-run)."""
    real = pipeline.optimize_image
    done = []

    def patched(*args, progress=None, **kwargs):
        def prog(*a, **k):
            if not done:
                done.append(1)
                action()
            if progress:
                progress(*a, **k)
        return real(*args, progress=prog, **kwargs)

    monkeypatch.setattr(pipeline, "optimize_image", patched)
    return done


# ------------------------------------------------------------ existing files not named
@pytest.mark.parametrize("argv", [
    ["transfer", "%face.jpg", "%other.jpg", "-o", "@o.png", *T],
    ["persona", "texture", "%persona", "--like", "%face_smiling.jpg", "-o", "@o.png"],
    ["persona", "average", "%persona", "-o", "@o.png"],
], ids=["transfer", "persona-texture", "persona-average"])
def test_existing_sidecar_is_not_replaced(capsys, bad, outdir, persona_file, monkeypatch, argv):
    def work(*a, **k):
        raise AssertionError("the work started although the sidecar exists")

    (outdir / "o.png.json").write_text("my notes\n")
    before = snapshot(outdir)
    args = [str(bad[a[1:]]) if a.startswith("%") and a != "%persona" else str(persona_file) if a == "%persona"
            else str(outdir / a[1:]) if a.startswith("@") else a for a in argv]
    for mod in (fio, fio._read):  # facetex.io's callers and as_image, beside read_image
        monkeypatch.setattr(mod, "read_image", work)
    import facetex.persona as persona

    monkeypatch.setattr(persona, "load_persona", work)
    run = run_cli(capsys, *args)
    assert_one_error(run, names=["o.png.json"], cause=r"exists.*--overwrite")
    assert snapshot(outdir) == before


def test_existing_step_files_refused_before_work(capsys, bad, outdir, monkeypatch):
    (outdir / "t_level0_eval0002.png").write_bytes(b"an earlier run's step")
    before = snapshot(outdir)
    for mod in (fio, fio._read):  # facetex.io's callers and as_image, beside read_image
        monkeypatch.setattr(mod, "read_image", lambda *a, **k: pytest.fail("work started"))
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T,
                  "--save-every", "1")
    assert_one_error(run, names=["t_level0_eval0002.png"], cause=r"step file.*earlier run.*--overwrite")
    assert snapshot(outdir) == before


# ------------------------------------------------------------ files appearing mid-run
@pytest.mark.parametrize("which", ["t.png", "t.png.json"])
def test_output_appearing_during_run_is_kept(capsys, bad, outdir, monkeypatch, which):
    intruder = outdir / which
    _optimize_then(monkeypatch, lambda: intruder.write_bytes(b"written by someone else"))
    inputs = sha1s(bad["face.jpg"], bad["other.jpg"])
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T)
    assert_one_error(run, names=[which], cause=r"appeared during the run.*not replaced")
    # the intruder is intact, and no image without its sidecar (nor the reverse), no temp file
    assert snapshot(outdir) == {which: snapshot(outdir)[which]}
    assert intruder.read_bytes() == b"written by someone else"
    assert sha1s(bad["face.jpg"], bad["other.jpg"]) == inputs


def test_overlay_appearing_during_run_is_kept(capsys, bad, outdir, monkeypatch):
    import facetex.landmarks as lm

    real = lm.detect_faces
    out = outdir / "o.png"

    def detect(*a, **k):
        out.write_bytes(b"mine")
        return real(*a, **k)

    monkeypatch.setattr(lm, "detect_faces", detect)
    run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", out)
    assert_one_error(run, names=[out], cause=r"appeared during the run")
    assert out.read_bytes() == b"mine" and snapshot(outdir) == {"o.png": snapshot(outdir)["o.png"]}


def test_persona_appearing_during_build_is_kept(capsys, outdir, photo_dir, persona_file, monkeypatch):
    import facetex.persona as persona

    out = outdir / "p.persona"

    def build(*a, **k):  # the build itself is tested elsewhere: here, only its commit
        out.write_bytes(b"another build")
        return persona.load_persona(persona_file)

    monkeypatch.setattr(persona, "build_persona", build)
    run = run_cli(capsys, "persona", "build", photo_dir, "-o", out, "--jobs", "1", "--min-photos", "3")
    assert_one_error(run, names=[out], cause=r"appeared during the run")
    assert out.read_bytes() == b"another build" and len(snapshot(outdir)) == 1


def test_concurrent_runs_one_wins_nothing_replaced(bad, tmp_path):
    """Two processes writing the same overlay at once: exactly one succeeds, the file is whole."""
    out = tmp_path / "o.png"
    cmd = [sys.executable, "-m", "facetex.cli", "landmarks", str(bad["face.jpg"]), "-o", str(out)]
    procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    res = [(p.wait(timeout=120), p.stderr.read()) for p in procs]
    codes = sorted(c for c, _ in res)
    assert codes == [0, 2], res
    err = next(e for c, e in res if c == 2)
    assert "Traceback" not in err and "o.png" in err and ("exists" in err or "appeared during the run" in err)
    assert fio.read_image(out).shape == (400, 400, 3)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.png", "o.png.json"]  # the winner's image and sidecar


# ------------------------------------------------------------ output == an input
def _same(name, bad, tmp_path):
    """A copy of a bundled input in tmp_path (so a failure cannot damage the package)."""
    p = tmp_path / name
    p.write_bytes(bad[name if name in bad else "face.jpg"].read_bytes())
    return p


@pytest.mark.parametrize("which", ["content", "style", "hardlink"])
def test_transfer_output_is_an_input(capsys, bad, tmp_path, monkeypatch, which):
    content, style = _same("face.jpg", bad, tmp_path), _same("other.jpg", bad, tmp_path)
    target = {"content": content, "style": style, "hardlink": tmp_path / "link.jpg"}[which]
    if which == "hardlink":
        os.link(content, target)
    for mod in (fio, fio._read):  # facetex.io's callers and as_image, beside read_image
        monkeypatch.setattr(mod, "read_image", lambda *a, **k: pytest.fail("work started"))
    before = snapshot(tmp_path)
    run = run_cli(capsys, "transfer", content, style, "-o", target, *T, "--overwrite")
    assert_one_error(run, names=[target], cause=r"same file as the input")
    assert snapshot(tmp_path) == before


def test_landmarks_overlay_is_the_image(capsys, bad, tmp_path):
    img = tmp_path / "face.png"
    fio.write_image(img, fio.read_image(bad["face.jpg"]))
    before = snapshot(tmp_path)
    run = run_cli(capsys, "landmarks", img, "-o", img, "--overwrite")
    assert_one_error(run, names=[img], cause=r"same file as the input")
    assert snapshot(tmp_path) == before


def test_persona_texture_output_is_the_reference(capsys, bad, tmp_path, persona_file):
    ref = tmp_path / "ref.png"
    fio.write_image(ref, fio.read_image(bad["face_smiling.jpg"]))
    before = snapshot(tmp_path) | sha1s(persona_file)
    run = run_cli(capsys, "persona", "texture", persona_file, "--like", ref, "-o", ref, "--overwrite")
    assert_one_error(run, names=[ref], cause=r"same file as the input")
    assert snapshot(tmp_path) | sha1s(persona_file) == before


@pytest.mark.skipif(not has_command("puppet"), reason="no puppet command")
def test_puppet_output_is_the_driver(capsys, videos, tmp_path, persona_file):
    drv = tmp_path / "driver.mp4"
    drv.write_bytes(videos["face.mp4"].read_bytes())
    before = snapshot(tmp_path)
    run = run_cli(capsys, "puppet", "--driver", drv, "--puppet", persona_file, "-o", drv, "--overwrite")
    assert_one_error(run, names=[drv], cause=r"same file as the input")
    assert snapshot(tmp_path) == before


def test_persona_build_output_is_a_photo(capsys, photo_dir, tmp_path):
    d = tmp_path / "photos"
    d.mkdir()
    for p in photo_dir.iterdir():
        (d / p.name).write_bytes(p.read_bytes())
    before = snapshot(d)
    run = run_cli(capsys, "persona", "build", d, "-o", d / "frl_003_neutral.jpg", "--overwrite", "--jobs", "1")
    assert_one_error(run, names=["frl_003_neutral.jpg"], cause=r"same file as the input")
    assert snapshot(d) == before


# ------------------------------------------------------------ devices and FIFOs as -o
@pytest.mark.parametrize("name, kind", [("fifo_out.png", r"FIFO"), ("null.png", r"character device")])
def test_device_or_fifo_output_is_never_replaced(capsys, bad, special, name, kind):
    target = special[name]
    run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", target, "--overwrite")
    assert_one_error(run, names=[target], cause=kind + r".*not a regular file")
    assert os.path.islink(target) or stat.S_ISFIFO(os.lstat(target).st_mode)
    assert not stat.S_ISREG(os.stat(target).st_mode)


# ------------------------------------------------------------ never one file of a set
def _fail_nth_write(monkeypatch, n: int, code=errno.ENOSPC):
    real = fio._atomic._write_bytes
    calls = []

    def write(path, data):
        calls.append(path)
        if len(calls) == n:
            with open(path, "wb") as fh:  # a partial temp file, as a real full disk leaves
                fh.write(data[: len(data) // 3])
            raise OSError(code, os.strerror(code))
        return real(path, data)

    monkeypatch.setattr(fio._atomic, "_write_bytes", write)  # where write_files calls it
    return calls


def test_disk_full_on_sidecar_leaves_no_png(capsys, bad, outdir, monkeypatch):
    calls = _fail_nth_write(monkeypatch, 2)  # the image's temp is written, the sidecar's fails
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T)
    assert len(calls) == 2
    assert_one_error(run, names=["t.png.json"], cause=r"disk full")
    assert snapshot(outdir) == {}


def test_disk_full_on_image_with_overwrite_keeps_old(capsys, bad, outdir, monkeypatch):
    (outdir / "t.png").write_bytes(b"old image")
    (outdir / "t.png.json").write_bytes(b"old sidecar")
    before = snapshot(outdir)
    _fail_nth_write(monkeypatch, 1)
    run = run_cli(capsys, "transfer", bad["face.jpg"], bad["other.jpg"], "-o", outdir / "t.png", *T, "--overwrite")
    assert_one_error(run, names=["t.png"], cause=r"disk full")
    assert snapshot(outdir) == before


def test_mesh_set_all_or_nothing(capsys, outdir, persona_file, monkeypatch):
    calls = _fail_nth_write(monkeypatch, 3)  # png, mtl written; the obj fails
    run = run_cli(capsys, "persona", "mesh", persona_file, "-o", outdir / "face.obj", "--step", "4")
    assert len(calls) == 3
    assert_one_error(run, names=["face.obj"], cause=r"disk full")
    assert snapshot(outdir) == {}


def test_commit_rolls_back_the_first_file(tmp_path):
    """The image is committed, then the sidecar's name turns out taken: the image is removed
    again (API level, no CLI)."""
    (tmp_path / "o.png.json").write_text("taken")
    with pytest.raises(OutputError, match="exists"):
        fio.write_files({tmp_path / "o.png": b"png", tmp_path / "o.png.json": b"{}"})
    real = fio._atomic.check_outputs
    # a sidecar that appears between the checks and the commit
    def late(paths, **kw):
        out = real(paths, **kw)
        (tmp_path / "x.png.json").write_text("late")
        return out
    fio._atomic.check_outputs = late
    try:
        with pytest.raises(OutputError, match="appeared during the run"):
            fio.write_files({tmp_path / "x.png": b"png", tmp_path / "x.png.json": b"{}"})
    finally:
        fio._atomic.check_outputs = real
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.png.json", "x.png.json"]
    assert (tmp_path / "x.png.json").read_text() == "late"


def test_real_full_disk(capsys, bad, tiny_fs):
    """A 64 KiB file system: the overlay does not fit."""
    run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", tiny_fs / "o.png")
    assert_one_error(run, names=["o.png"], cause=r"disk full")
    assert list(tiny_fs.iterdir()) == []
