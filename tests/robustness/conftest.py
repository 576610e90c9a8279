"""Bad inputs made on the fly from the bundled samples (fixtures of the robustness tests)."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from _robust import FACE, FACE_SMILING, OTHER


def _png_with_declared_size(path: Path, w: int, h: int) -> Path:
    """A few-byte PNG whose IHDR declares w x h (a decompression bomb's header)."""
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))  # noqa: E731
    idat = zlib.compress(b"\x00" * 64)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
    return path


def _with_alpha(im: Image.Image) -> Image.Image:
    """Opaque face, transparent 20 px border."""
    a = np.zeros(im.size[::-1], np.uint8)
    a[20:-20, 20:-20] = 255
    out = im.copy()
    out.putalpha(Image.fromarray(a))
    return out


@pytest.fixture(scope="session")
def bad(tmp_path_factory) -> dict[str, Path]:
    """name -> path of every generated test input (read-only use)."""
    d = tmp_path_factory.mktemp("inputs")
    face = Image.open(FACE).convert("RGB")
    raw = FACE.read_bytes()
    f: dict[str, Path] = {}

    def put(name, data: bytes):
        f[name] = d / name
        f[name].write_bytes(data)

    put("empty.jpg", b"")
    put("truncated.jpg", raw[: len(raw) * 2 // 5])
    put("random.jpg", np.random.default_rng(0).integers(0, 256, 4096, dtype=np.uint8).tobytes())
    put("text.png", b"this is not an image\n")
    f["folder.jpg"] = d / "folder.jpg"
    f["folder.jpg"].mkdir()
    f["missing.jpg"] = d / "missing.jpg"
    Image.new("RGB", (1, 1), (128, 128, 128)).save(d / "tiny.png")
    f["tiny.png"] = d / "tiny.png"
    f["bomb.png"] = _png_with_declared_size(d / "bomb.png", 20000, 20000)

    # unusual but valid encodings of the face
    face.convert("L").save(d / "gray.jpg", quality=95)
    _with_alpha(face.convert("L")).save(d / "gray_alpha.png")  # LA
    _with_alpha(face).save(d / "rgba.png")
    face.convert("P", palette=Image.Palette.ADAPTIVE, colors=256).save(d / "palette.png")
    face.convert("CMYK").save(d / "cmyk.jpg", quality=95)
    rgb16 = np.asarray(face, np.uint16) * 257
    cv2.imwrite(str(d / "rgb16.png"), rgb16[..., ::-1])
    # EXIF orientation 6: the stored pixels are turned 90° counter-clockwise, viewers turn them back
    exif = Image.Exif()
    exif[0x0112] = 6
    face.transpose(Image.Transpose.ROTATE_90).save(d / "exif_rot6.jpg", quality=95, exif=exif.tobytes())
    for n in ("gray.jpg", "gray_alpha.png", "rgba.png", "palette.png", "cmyk.jpg", "rgb16.png", "exif_rot6.jpg"):
        f[n] = d / n

    # no face: smooth noise; two faces: the sample beside a smaller other person
    noise = np.random.default_rng(1).random((300, 300, 3)).astype(np.float32)
    Image.fromarray((cv2.GaussianBlur(noise, (0, 0), 8) * 255).clip(0, 255).astype(np.uint8)).save(d / "noface.png")
    small = Image.open(OTHER).convert("RGB").resize((280, 280), Image.Resampling.LANCZOS)
    two = Image.new("RGB", (680, 400), (200, 200, 200))
    two.paste(face, (0, 0))
    two.paste(small, (400, 60))
    two.save(d / "twofaces.png")
    two_swapped = Image.new("RGB", (680, 400), (200, 200, 200))
    two_swapped.paste(face.resize((280, 280), Image.Resampling.LANCZOS), (0, 60))
    two_swapped.paste(Image.open(OTHER).convert("RGB"), (280, 0))
    two_swapped.save(d / "twofaces_swapped.png")
    for n in ("noface.png", "twofaces.png", "twofaces_swapped.png"):
        f[n] = d / n
    f["face.jpg"] = FACE
    f["face_smiling.jpg"] = FACE_SMILING
    f["other.jpg"] = OTHER
    return f


@pytest.fixture
def outdir(tmp_path) -> Path:
    d = tmp_path / "out"
    d.mkdir()
    return d


def has_command(*names) -> bool:
    """Whether ``facetex NAME [SUBNAME]`` is registered (persona/puppet are being written)."""
    import argparse

    from facetex.cli import build_parser

    parser = build_parser()
    for name in names:
        subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
        if not subs or name not in subs[0].choices:
            return False
        parser = subs[0].choices[name]
    return True


@pytest.fixture(scope="session")
def photo_dir(tmp_path_factory) -> Path:
    """The six bundled faces: a stand-in photo collection (six people, but the build does not know)."""
    import shutil

    from facetex._resources import sample_path

    d = tmp_path_factory.mktemp("photos")
    for p in sorted(sample_path().glob("frl_*.jpg")):
        shutil.copy(p, d / p.name)
    return d


BUILD_OPTS = ["--jobs", "1", "--min-photos", "3"]


@pytest.fixture(scope="session")
def persona_file(tmp_path_factory, photo_dir) -> Path:
    """A .persona built once through the CLI (skipped when ``persona build`` is missing or fails)."""
    from facetex.cli import main

    if not has_command("persona", "build"):
        pytest.skip("`facetex persona build` is not registered yet")
    out = tmp_path_factory.mktemp("persona") / "p.persona"
    code = main(["persona", "build", str(photo_dir), "-o", str(out), *BUILD_OPTS])
    if code != 0 or not out.is_file():
        pytest.fail(f"`facetex persona build` of the bundled faces failed (exit {code})")
    return out


@pytest.fixture(scope="session")
def videos(tmp_path_factory) -> dict[str, Path]:
    """Short driver videos: a face, no face, truncated in three places, zero-byte, text."""
    from facetex.io import read_image, write_video

    d = tmp_path_factory.mktemp("videos")
    a, b = read_image(FACE), read_image(FACE_SMILING)
    frames = [a if i % 4 < 2 else b for i in range(8)]
    write_video(d / "face.mp4", frames, 10)
    gray = [np.full((240, 320, 3), 0.4 + 0.02 * i, np.float32) for i in range(8)]
    write_video(d / "noface.mp4", gray, 10)
    raw = (d / "face.mp4").read_bytes()
    (d / "truncated.mp4").write_bytes(raw[:600])  # cut inside the header (faststart: moov first)
    import av

    with av.open(str(d / "face.mp4")) as c:  # byte ranges of the coded frames (moov is up front)
        packets = [(p.pos, p.size) for p in c.demux(c.streams.video[0]) if p.size]
    (d / "cut_first.mp4").write_bytes(raw[: packets[0][0] + packets[0][1] // 2])  # inside the first frame
    (d / "cut_mid.mp4").write_bytes(raw[: packets[2][0] + packets[2][1] // 2])  # two whole frames left
    (d / "empty.mp4").write_bytes(b"")
    (d / "text.mp4").write_text("not a video\n")
    return {p.name: p for p in d.iterdir()}
