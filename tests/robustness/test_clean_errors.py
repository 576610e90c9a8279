"""Issue 13: one clean line (exit 2, the file named) instead of "internal error", a hang or a
wrong cause: corrupt .persona members, nested JSON, read-only and deleted folders, damaged
audio, FIFOs, devices, symlink loops, animated images."""

from __future__ import annotations

import json
import zipfile

import numpy as np
import pytest

from _robust import assert_one_error, run_cli, sha1s, snapshot
from conftest import has_command


# ------------------------------------------------------------ corrupt .persona members
def _member_data(path, name: str) -> tuple[int, int, int]:
    """(offset of the member's data in the file, its compressed size, compress type)."""
    with zipfile.ZipFile(path) as z:
        info = z.getinfo(name)
    with open(path, "rb") as fh:
        fh.seek(info.header_offset + 26)
        n, m = np.frombuffer(fh.read(4), "<u2")
    return info.header_offset + 30 + int(n) + int(m), info.compress_size, info.compress_type


def _flip(src, dst, offset: int):
    raw = bytearray(src.read_bytes())
    raw[offset] ^= 0x5A
    dst.write_bytes(bytes(raw))
    return dst


@pytest.fixture(scope="module")
def flipped(tmp_path_factory, persona_file):
    d = tmp_path_factory.mktemp("flipped")
    out = {}
    for member in ("subspace.npy", "points68.npy", "header.npy"):  # deflated: a zlib error
        off, size, kind = _member_data(persona_file, member)
        assert kind == zipfile.ZIP_DEFLATED
        out[member] = _flip(persona_file, d / f"{member[:-4]}.persona", off + size // 2)
    off, _, kind = _member_data(persona_file, "images.npy")  # stored: a flip in its .npy header text
    assert kind == zipfile.ZIP_STORED
    out["images-npy-header"] = _flip(persona_file, d / "npyheader.persona", off + 20)
    return out


@pytest.mark.parametrize("member", ["subspace.npy", "points68.npy", "header.npy", "images-npy-header"])
@pytest.mark.parametrize("command", ["average", "mesh", "texture", "puppet"])
def test_flipped_byte_is_a_corrupt_persona(capsys, flipped, outdir, bad, videos, command, member):
    if command == "puppet" and not has_command("puppet"):
        pytest.skip("no puppet command")
    path = flipped[member]
    argv = {"average": ["persona", "average", path, "-o", outdir / "o.png"],
            "mesh": ["persona", "mesh", path, "-o", outdir / "o.obj", "--step", "4"],
            "texture": ["persona", "texture", path, "--like", bad["face_smiling.jpg"], "-o", outdir / "o.png"],
            "puppet": ["puppet", "--driver", videos["face.mp4"], "--puppet", path, "-o", outdir / "o.mp4",
                       "--size", "64"]}[command]
    run = run_cli(capsys, *argv)
    assert_one_error(run, names=[path], cause=r"corrupt persona")
    assert snapshot(outdir) == {}


def test_every_single_byte_flip_loads_or_fails_cleanly(tmp_path, persona_file):
    """60 flips spread over the whole file (headers, directory, data): the loader returns the
    same persona or raises BadPersonaError, never anything else."""
    from facetex.errors import BadPersonaError
    from facetex.persona import load_persona

    ref = load_persona(persona_file)
    size = persona_file.stat().st_size
    offsets = sorted(set(np.linspace(0, size - 1, 45).astype(int)) | set(range(size - 300, size, 20)))
    outcomes = {"same": 0, "refused": 0}
    for off in offsets:
        p = _flip(persona_file, tmp_path / "f.persona", int(off))
        try:
            got = load_persona(p)
        except BadPersonaError as e:
            assert "f.persona" in str(e) and "\n" not in str(e)
            outcomes["refused"] += 1
            continue
        for k in ("images", "visibility", "fiducials", "points68", "poses", "flows", "subspace"):
            np.testing.assert_array_equal(getattr(got, k), getattr(ref, k), err_msg=f"flip at {off}: {k}")
        outcomes["same"] += 1
    assert outcomes["refused"] >= len(offsets) // 2, outcomes


# ------------------------------------------------------------ nested JSON
def test_deeply_nested_fiducials(capsys, tmp_path, outdir, persona_file):
    path = tmp_path / "deep.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    run = run_cli(capsys, "persona", "texture", persona_file, "--fiducials", path, "-o", outdir / "t.png")
    assert_one_error(run, names=[path], cause=r"nested too deeply")
    assert snapshot(outdir) == {}


def test_deeply_nested_persona_header(capsys, tmp_path, outdir):
    path = tmp_path / "deep.persona"
    text = '{"format": "facetex-persona", "version": 2, "x": ' + "[" * 100_000 + "]" * 100_000 + "}"
    with open(path, "wb") as fh:
        np.savez(fh, header=np.frombuffer(text.encode(), np.uint8))
    run = run_cli(capsys, "persona", "average", path, "-o", outdir / "a.png")
    assert_one_error(run, names=[path], cause=r"corrupt persona header.*nested too deeply")
    assert snapshot(outdir) == {}


# ------------------------------------------------------------ read-only and deleted folders
def test_demo_in_read_only_folder(capsys, readonly_dir, monkeypatch):
    import facetex.transfer._pipeline as pipeline

    monkeypatch.setattr(pipeline, "optimize_image", lambda *a, **k: pytest.fail("the demo started working"))
    monkeypatch.chdir(readonly_dir)
    run = run_cli(capsys, "demo")
    assert_one_error(run, names=["demo_out"], cause=r"cannot create the output folder \((Read-only file system|"
                                                      r"Permission denied)\)")
    assert list(readonly_dir.iterdir()) == []


def test_read_only_output_folder_any_user(capsys, bad, readonly_dir):
    run = run_cli(capsys, "landmarks", bad["face.jpg"], "-o", readonly_dir / "o.png")
    assert_one_error(run, names=["o.png"], cause=r"not writable")
    assert list(readonly_dir.iterdir()) == []


@pytest.mark.parametrize("argv, cause", [
    (["landmarks", "%face.jpg", "-o", "o.png"], r"\(the current folder\) was deleted"),
    (["transfer", "%face.jpg", "%other.jpg", "-o", "t.png", "--size", "64", "--iters", "1"],
     r"\(the current folder\) was deleted"),
    (["landmarks", "face.jpg"], r"not found"),
])
def test_deleted_working_folder(capsys, bad, tmp_path, monkeypatch, argv, cause):
    wd = tmp_path / "wd"
    wd.mkdir()
    monkeypatch.chdir(wd)
    wd.rmdir()
    args = [str(bad[a[1:]]) if a.startswith("%") else a for a in argv]
    run = run_cli(capsys, *args)
    named = [a for a in argv if not a.startswith("%") and "." in a][-1:]
    assert_one_error(run, names=named, cause=cause)
    assert not wd.exists()


# ------------------------------------------------------------ damaged audio in the driver
@pytest.mark.skipif(not has_command("puppet"), reason="no puppet command")
@pytest.mark.parametrize("video, audio", [("bad_audio.mp4", False), ("good_audio.mp4", True)])
def test_driver_audio(capsys, audio_videos, outdir, persona_file, video, audio):
    from facetex.io import video_info

    path = audio_videos[video]
    before = sha1s(path)
    run = run_cli(capsys, "puppet", "--driver", path, "--puppet", persona_file, "-o", outdir / "o.mp4",
                  "--size", "96")
    assert run.code == 0, run.err
    assert "Traceback" not in run.err and run.lines == [], run.lines
    warnings = [l for l in run.err.replace("\r", "\n").splitlines() if l.startswith("facetex: warning:")]
    if audio:
        assert not any("audio" in w for w in warnings), warnings
    else:
        assert any(path.name in w and "audio cannot be decoded" in w and "no audio" in w for w in warnings), warnings
    assert video_info(outdir / "o.mp4")["has_audio"] is audio
    assert sorted(p.name for p in outdir.iterdir()) == ["o.mp4", "o.mp4.json"]  # the video and its sidecar
    assert sha1s(path) == before


def test_write_video_names_the_damaged_source(tmp_path, audio_videos):
    """API level: the encoder never reports a source's damage as its own."""
    from facetex.io import write_video

    frames = [np.full((64, 64, 3), 0.5, np.float32)] * 4
    with pytest.warns(UserWarning, match="bad_audio.mp4.*audio cannot be decoded"):
        write_video(tmp_path / "o.mp4", frames, 10, audio_from=audio_videos["bad_audio.mp4"])
    assert (tmp_path / "o.mp4").is_file()


# ------------------------------------------------------------ special files
SPECIAL = [
    ("landmarks-fifo", ["landmarks", "$fifo.jpg"], "$fifo.jpg", r"not a regular file \(a FIFO"),
    ("landmarks-dev-zero", ["landmarks", "$zero.jpg"], "$zero.jpg", r"not a regular file \(a character device"),
    ("landmarks-symlink-loop", ["landmarks", "$loop.jpg"], "$loop.jpg", r"symlink loop"),
    ("landmarks-dangling-link", ["landmarks", "$dangling.jpg"], "$dangling.jpg", r"broken symlink"),
    ("transfer-style-fifo", ["transfer", "%face.jpg", "$fifo.jpg", "-o", "@t.png"], "$fifo.jpg", r"not a regular"),
    ("identity-dev-zero", ["identity", "%face.jpg", "$zero.jpg"], "$zero.jpg", r"not a regular file"),
    ("texture-persona-fifo", ["persona", "texture", "$fifo.persona", "--like", "%face.jpg", "-o", "@t.png"],
     "$fifo.persona", r"not a regular file \(a FIFO"),
    ("average-persona-dev-zero", ["persona", "average", "$zero.persona", "-o", "@a.png"], "$zero.persona",
     r"not a regular file"),
    ("average-persona-loop", ["persona", "average", "$loop.persona", "-o", "@a.png"], "$loop.persona",
     r"symlink loop"),
    ("texture-fiducials-fifo", ["persona", "texture", "%persona", "--fiducials", "$fifo.json", "-o", "@t.png"],
     "$fifo.json", r"not a regular file"),
    ("texture-like-fifo", ["persona", "texture", "%persona", "--like", "$fifo.jpg", "-o", "@t.png"], "$fifo.jpg",
     r"not a regular file"),
    ("puppet-driver-fifo", ["puppet", "--driver", "$fifo.mp4", "--puppet", "%persona", "-o", "@o.mp4"],
     "$fifo.mp4", r"not a regular file"),
    ("build-folder-loop", ["persona", "build", "$loop.jpg", "-o", "@p.persona"], "$loop.jpg", r"symlink loop"),
]


@pytest.mark.timeout(60)  # a FIFO that is opened would block forever
@pytest.mark.parametrize("argv, name, cause", [c[1:] for c in SPECIAL], ids=[c[0] for c in SPECIAL])
def test_special_files(capsys, bad, special, outdir, persona_file, argv, name, cause):
    if argv[0] == "puppet" and not has_command("puppet"):
        pytest.skip("no puppet command")

    def one(a):
        if a == "%persona":
            return str(persona_file)
        return str(bad[a[1:]]) if a[0] == "%" else str(special[a[1:]]) if a[0] == "$" else \
            str(outdir / a[1:]) if a[0] == "@" else a

    run = run_cli(capsys, *[one(a) for a in argv])
    assert_one_error(run, names=[one(name)], cause=cause)
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("name", ["animated.gif", "animated.png"])
def test_animated_image_says_first_frame(capsys, special, reference_points_first, name):
    run = run_cli(capsys, "landmarks", special[name], "--json")
    assert run.code == 0, run.err
    assert run.lines == [], run.lines
    warnings = [l for l in run.err.splitlines() if l.startswith("facetex: warning:")]
    assert any(name in w and "3 frames" in w and "first frame is used" in w for w in warnings), warnings
    p = np.asarray(json.loads(run.out)["faces"][0]["points68"])
    assert np.abs(p - reference_points_first).mean() < 3.0  # the first frame's face (neutral), not another


@pytest.fixture(scope="module")
def reference_points_first(bad):
    from facetex.io import read_image
    from facetex.landmarks import detect_faces

    return detect_faces(read_image(bad["face.jpg"]), upsample=None)[0].points68
