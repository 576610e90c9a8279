"""Bad inputs made on the fly from the bundled samples (fixtures of the robustness tests)."""

from __future__ import annotations

import shutil
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


BUILD_OPTS = ["--jobs", "1", "--min-photos", "3", "--allow-mixed"]  # six people: not one persona


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


# ---------------------------------------------------------------- second wave (issue 13)
def _variants(img: np.ndarray, n: int, seed: int) -> list[np.ndarray]:
    """n distinct photos of one face: small rotations, scales, shifts, gains and light ramps."""
    rng = np.random.default_rng(seed)
    h, w = img.shape[:2]
    out = []
    for k in range(n):
        m = cv2.getRotationMatrix2D((w / 2, h / 2), rng.uniform(-5, 5), rng.uniform(0.93, 1.05))
        m[:, 2] += rng.uniform(-8, 8, 2)
        j = cv2.warpAffine(img, m, (w, h), borderMode=cv2.BORDER_REPLICATE)
        ramp = np.linspace(-1, 1, w, dtype=np.float32)[None, :, None] * rng.uniform(-0.2, 0.2)
        out.append(np.clip(j * rng.uniform(0.85, 1.1) * (1 + ramp), 0, 1))
    return out


def _person(name: str, n: int, seed: int) -> list[np.ndarray]:
    from facetex.io import read_image

    imgs = []
    for k, expr in enumerate(("neutral", "smiling")):
        img = cv2.resize(read_image(FACE.parent / f"{name}_{expr}.jpg"), (240, 240), interpolation=cv2.INTER_AREA)
        imgs += _variants(img, (n + 1 - k) // 2, seed + k)
    return imgs[:n]


@pytest.fixture(scope="session")
def two_people(tmp_path_factory) -> dict[str, Path]:
    """Photo folders: "half" = 5 photos of frl_004 + 5 of frl_005; "mostly" = 8 of frl_004 + 1 of frl_005."""
    from facetex.io import write_image

    a, b = _person("frl_004", 8, 0), _person("frl_005", 5, 10)
    out = {}
    for name, (na, nb) in {"half": (5, 5), "mostly": (8, 1)}.items():
        d = tmp_path_factory.mktemp(name)
        for i in range(na):
            write_image(d / f"a{i}.jpg", a[i])
        for i in range(nb):
            write_image(d / f"b{i}.jpg", b[i])
        out[name] = d
    return out


@pytest.fixture(scope="session")
def special(tmp_path_factory) -> dict[str, Path]:
    """FIFOs, a link to /dev/zero, a symlink loop, a dangling link, animated images."""
    import os

    from PIL import Image

    d = tmp_path_factory.mktemp("special")
    f = {}
    for name in ("fifo.jpg", "fifo.persona", "fifo.json", "fifo.mp4", "fifo_out.png"):
        os.mkfifo(d / name)
        f[name] = d / name
    for name, target in (("zero.jpg", "/dev/zero"), ("zero.persona", "/dev/zero"), ("null.png", "/dev/null"),
                         ("loop.jpg", "loop.jpg"), ("loop.persona", "loop.persona"), ("dangling.jpg", "gone.jpg")):
        (d / name).symlink_to(target)
        f[name] = d / name
    frames = [Image.open(FACE).convert("RGB"), Image.open(FACE_SMILING).convert("RGB"), Image.open(OTHER).convert("RGB")]
    frames[0].save(d / "animated.gif", save_all=True, append_images=frames[1:], duration=100, loop=0)
    frames[0].save(d / "animated.png", save_all=True, append_images=frames[1:], duration=100)  # APNG
    f["animated.gif"], f["animated.png"] = d / "animated.gif", d / "animated.png"
    return f


def _mount_tmpfs(path: Path, options: str) -> bool:
    import os
    import subprocess

    if not hasattr(os, "geteuid") or os.geteuid() != 0:
        return False
    r = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True)
    return r.returncode == 0


@pytest.fixture
def readonly_dir(tmp_path):
    """A folder nobody may write: chmod 0500 (non-root) or a read-only tmpfs (root)."""
    import os
    import subprocess

    d = tmp_path / "ro"
    d.mkdir()
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        d.chmod(0o500)
        yield d
        d.chmod(0o700)
        return
    if not _mount_tmpfs(d, "ro,size=64k"):
        pytest.skip("root cannot make a read-only folder here (no tmpfs mount)")
    try:
        yield d
    finally:
        subprocess.run(["umount", str(d)], capture_output=True)


@pytest.fixture
def tiny_fs(tmp_path):
    """A 64 KiB tmpfs (a full disk after 64 KiB); root only."""
    import subprocess

    d = tmp_path / "tiny"
    d.mkdir()
    if not _mount_tmpfs(d, "size=64k"):
        pytest.skip("needs root and tmpfs to make a tiny file system")
    try:
        yield d
    finally:
        subprocess.run(["umount", str(d)], capture_output=True)


def _video_with_audio(path: Path, frames, fps: int = 10) -> Path:
    """H.264 + AAC (a 440 Hz tone) MP4."""
    import av

    with av.open(str(path), "w") as out:
        vs = out.add_stream("libx264" if "libx264" in av.codecs_available else "h264", rate=fps)
        h, w = frames[0].shape[:2]
        vs.width, vs.height, vs.pix_fmt = w, h, "yuv420p"
        a = out.add_stream("aac", rate=16000)
        a.layout = "mono"
        for i, fr in enumerate(frames):
            vf = av.VideoFrame.from_ndarray((np.clip(fr, 0, 1) * 255).astype(np.uint8), format="rgb24")
            vf.pts = i
            out.mux(vs.encode(vf))
        out.mux(vs.encode(None))
        n = int(16000 * len(frames) / fps)
        pcm = (0.3 * np.sin(2 * np.pi * 440 * np.arange(n) / 16000)).astype(np.float32)
        for k in range(0, n, 1024):
            af = av.AudioFrame.from_ndarray(np.ascontiguousarray(pcm[None, k:k + 1024]), format="flt", layout="mono")
            af.sample_rate, af.pts = 16000, k
            out.mux(a.encode(af))
        out.mux(a.encode(None))
    return path


@pytest.fixture(scope="session")
def audio_videos(tmp_path_factory) -> dict[str, Path]:
    """A talking-face stand-in with good AAC audio, and the same with every audio packet scrambled."""
    import av

    from facetex.io import read_image

    d = tmp_path_factory.mktemp("audio")
    a = cv2.resize(read_image(FACE), (200, 200), interpolation=cv2.INTER_AREA)
    b = cv2.resize(read_image(FACE_SMILING), (200, 200), interpolation=cv2.INTER_AREA)
    good = _video_with_audio(d / "good_audio.mp4", [a if i % 4 < 2 else b for i in range(6)])
    raw = bytearray(good.read_bytes())
    with av.open(str(good)) as c:
        packets = [(p.pos, p.size) for p in c.demux(c.streams.audio[0]) if p.size]
    rng = np.random.default_rng(3)
    for pos, size in packets:
        raw[pos:pos + size] = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
    (d / "bad_audio.mp4").write_bytes(bytes(raw))
    return {"good_audio.mp4": good, "bad_audio.mp4": d / "bad_audio.mp4"}


def big_png(path: Path, side: int, face_side: int) -> Path:
    """A side x side RGB PNG (grey, the sample face of face_side px in the middle), streamed row
    by row: a few MB on disk, side² x 3 bytes once decoded."""
    import struct
    import zlib

    from facetex.io import read_image_uint8

    face = cv2.resize(read_image_uint8(FACE), (face_side, face_side), interpolation=cv2.INTER_LINEAR)
    comp = zlib.compressobj(1)
    row = np.full((side, 3), 200, np.uint8)
    plain = b"\x00" + row.tobytes()
    y0 = (side - face_side) // 2
    parts = []
    for y in range(side):
        if y0 <= y < y0 + face_side:
            row[y0:y0 + face_side] = face[y - y0]
            parts.append(comp.compress(b"\x00" + row.tobytes()))
            row[y0:y0 + face_side] = 200
        else:
            parts.append(comp.compress(plain))
    parts.append(comp.flush())
    chunk = lambda t, d: struct.pack(">I", len(d)) + t + d + struct.pack(">I", zlib.crc32(t + d))  # noqa: E731
    with open(path, "wb") as fh:
        fh.write(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", side, side, 8, 2, 0, 0, 0))
                 + chunk(b"IDAT", b"".join(parts)) + chunk(b"IEND", b""))
    return path


@pytest.fixture(autouse=True)
def _no_orphans_inputs_intact(request):
    """Around every robustness test: the shared inputs stay byte-identical and no process or
    facetex thread it started is left running (multiprocessing's forkserver / resource tracker,
    which live as long as the test process, excepted)."""
    import threading
    import time

    from _robust import alive, child_pids, helper_daemon, sha1s

    files = []
    for name in ("bad", "videos", "special", "audio_videos"):
        if name in request.fixturenames:
            files += [p for p in request.getfixturevalue(name).values()
                      if p.is_file() and not p.is_symlink() and p.stat().st_size < 50 * 2**20
                      and __import__("stat").S_ISREG(p.stat().st_mode)]
    before = sha1s(*files)
    kids = child_pids()
    yield
    assert sha1s(*files) == before, "an input file was modified"
    deadline = time.monotonic() + 5
    while True:
        new = [p for p in child_pids() - kids if alive(p) and not helper_daemon(p)]
        threads = [t.name for t in threading.enumerate() if t.name.startswith("facetex")]
        if not new and not threads or time.monotonic() > deadline:
            break
        time.sleep(0.1)
    assert not new, f"child processes left running: {new}"
    assert not threads, f"threads left running: {threads}"


@pytest.fixture(scope="module")
def many_photos(tmp_path_factory, photo_dir):
    """24 photos (the bundled faces four times): a build long enough to interrupt or kill."""
    d = tmp_path_factory.mktemp("many")
    for k in range(4):
        for p in sorted(photo_dir.iterdir()):
            shutil.copy(p, d / f"{k}_{p.name}")
    return d
