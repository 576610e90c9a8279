"""facetex.io: image modes, failures, atomic writes, PyAV video."""

from __future__ import annotations

import json
import os
import struct
import time
import zlib

import av
import cv2
import numpy as np
import pytest
from PIL import Image, ImageOps

from facetex import io as fio
from facetex._resources import sample_path
from facetex.errors import BadImageError, BadInputError, BadVideoError, OutputError

SAMPLE = sample_path("frl_004_neutral.jpg")


# ------------------------------------------------------------------ reading: modes
def test_sample_jpeg_matches_pillow():
    img = fio.read_image(SAMPLE)
    assert img.dtype == np.float32 and img.shape == (400, 400, 3)
    ref = np.asarray(Image.open(SAMPLE).convert("RGB"), np.float32) / 255
    np.testing.assert_allclose(img, ref, atol=1e-6)
    u = fio.read_image_uint8(SAMPLE)
    assert u.dtype == np.uint8 and np.array_equal(u, np.asarray(Image.open(SAMPLE).convert("RGB")))


def test_gray_png_gives_equal_channels(tmp_path):
    Image.new("L", (20, 18), 77).save(tmp_path / "g.png")
    img = fio.read_image(tmp_path / "g.png")
    assert img.shape == (18, 20, 3)
    np.testing.assert_allclose(img, 77 / 255, atol=1e-6)


@pytest.mark.parametrize("background,bg", [("white", 1.0), ("black", 0.0)])
def test_rgba_composited_on_background(tmp_path, background, bg):
    a = np.zeros((16, 24, 4), np.uint8)
    a[..., :3] = (200, 40, 10)
    a[:, :8, 3] = 0      # transparent
    a[:, 8:16, 3] = 255  # opaque
    a[:, 16:, 3] = 128   # half
    Image.fromarray(a, "RGBA").save(tmp_path / "a.png")
    img = fio.read_image(tmp_path / "a.png", background=background)
    np.testing.assert_allclose(img[0, 0], [bg] * 3, atol=1e-6)
    np.testing.assert_allclose(img[0, 10], np.array([200, 40, 10]) / 255, atol=1e-6)
    half = 128 / 255
    np.testing.assert_allclose(img[0, 20], np.array([200, 40, 10]) / 255 * half + bg * (1 - half), atol=1e-6)


def test_gray_alpha_png(tmp_path):
    la = np.zeros((16, 16, 2), np.uint8)
    la[..., 0] = 100
    la[:8, :, 1] = 255
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    img = fio.read_image(tmp_path / "la.png", background="black")
    np.testing.assert_allclose(img[0, 0], [100 / 255] * 3, atol=1e-6)
    np.testing.assert_allclose(img[12, 0], [0, 0, 0], atol=1e-6)


def test_palette_with_transparency(tmp_path):
    im = Image.new("P", (16, 16), 1)
    im.putpalette([0, 0, 0, 10, 200, 30] + [0] * 762)
    im.paste(0, (0, 0, 8, 16))
    im.save(tmp_path / "p.png", transparency=0)
    img = fio.read_image(tmp_path / "p.png", background="white")
    np.testing.assert_allclose(img[0, 0], [1, 1, 1], atol=1e-6)  # index 0 is transparent
    np.testing.assert_allclose(img[0, 12], np.array([10, 200, 30]) / 255, atol=1e-6)


@pytest.mark.parametrize("name", ["rgb16.png", "rgb16.tif", "gray16.png", "gray16.tif"])
def test_16bit_keeps_precision(tmp_path, name):
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 65536, (20, 24, 3), dtype=np.uint16)
    rgb[0, 0] = (1000, 1100, 1200)  # 100/65535 apart: finer than 1/255
    arr = rgb[..., 0] if name.startswith("gray") else rgb[..., ::-1]  # OpenCV writes BGR
    assert cv2.imwrite(str(tmp_path / name), arr)
    img = fio.read_image(tmp_path / name)
    want = (rgb[..., :1].repeat(3, 2) if name.startswith("gray") else rgb) / 65535
    np.testing.assert_allclose(img, want, atol=1e-6)
    assert np.unique(np.round(img * 255)).size <= 256 < np.unique(img).size


def test_16bit_rgba_png_composited(tmp_path):
    bgra = np.zeros((16, 16, 4), np.uint16)
    bgra[..., :3] = (300, 200, 100)
    bgra[:, 8:, 3] = 65535
    cv2.imwrite(str(tmp_path / "a16.png"), bgra)
    img = fio.read_image(tmp_path / "a16.png", background="white")
    np.testing.assert_allclose(img[0, 0], [1, 1, 1], atol=1e-6)
    np.testing.assert_allclose(img[0, 12], np.array([100, 200, 300]) / 65535, atol=1e-6)


def test_cmyk_jpeg_red_patch_reads_red(tmp_path):
    Image.new("CMYK", (32, 32), (0, 255, 255, 0)).save(tmp_path / "c.jpg", quality=95)
    assert Image.open(tmp_path / "c.jpg").mode == "CMYK"
    px = fio.read_image(tmp_path / "c.jpg")[16, 16]
    assert px[0] > 0.9 and px[1] < 0.1 and px[2] < 0.1


@pytest.mark.parametrize("icc", [b"garbage", "srgb"])
def test_cmyk_jpeg_with_unusable_profile_falls_back(tmp_path, icc):
    from PIL import ImageCms
    if icc == "srgb":  # a valid profile of the wrong colour space
        icc = ImageCms.ImageCmsProfile(ImageCms.createProfile("sRGB")).tobytes()
    Image.new("CMYK", (32, 32), (0, 255, 255, 0)).save(tmp_path / "c.jpg", icc_profile=icc)
    px = fio.read_image(tmp_path / "c.jpg")[16, 16]
    assert px[0] > 0.9 and px[1] < 0.1 and px[2] < 0.1


def test_cmyk_jpeg_of_sample_not_inverted(tmp_path):
    Image.open(SAMPLE).convert("CMYK").save(tmp_path / "c.jpg", quality=95)
    diff = np.abs(fio.read_image(tmp_path / "c.jpg") - fio.read_image(SAMPLE)).mean()
    assert diff < 0.05


def test_exif_orientation_6_rotates(tmp_path):
    a = np.zeros((20, 40, 3), np.uint8)  # 40 wide, 20 high
    a[:6, :6] = (255, 0, 0)  # stored top-left
    exif = Image.Exif()
    exif[0x0112] = 6  # display = stored rotated 90 degrees clockwise
    Image.fromarray(a).save(tmp_path / "o.jpg", exif=exif, quality=98)
    img = fio.read_image(tmp_path / "o.jpg")
    assert img.shape == (40, 20, 3)
    assert img[1, -2, 0] > 0.8 and img[1, -2, 1] < 0.2  # now top-right
    assert img[1, 1, 0] < 0.2


def _png16_with_orientation(path, gray16, orientation):
    assert cv2.imwrite(str(path), gray16)
    exif = Image.Exif()
    exif[0x0112] = orientation
    raw = path.read_bytes()  # insert an eXIf chunk right after IHDR
    tiff = exif.tobytes().removeprefix(b"Exif\x00\x00")  # PNG's eXIf holds bare TIFF data
    path.write_bytes(raw[:33] + _png_chunk(b"eXIf", tiff) + raw[33:])


@pytest.mark.parametrize("ext", [".png", ".tif"])
def test_16bit_with_orientation_6_and_unicode_name(tmp_path, ext):
    a = np.full((20, 40), 1000, np.uint16)  # 40 wide, 20 high
    a[0, 0] = 1100
    path = tmp_path / f"gr\u00fc\u00df16{ext}"
    if ext == ".tif":
        Image.fromarray(a).save(path, tiffinfo={274: 6})
    else:
        _png16_with_orientation(path, a, 6)
    img = fio.read_image(path)  # 16-bit OpenCV path
    assert img.shape == (40, 20, 3)
    np.testing.assert_allclose(img[0, -1], [1100 / 65535] * 3, atol=1e-7)  # top-left -> top-right
    np.testing.assert_allclose(img[5, 5], [1000 / 65535] * 3, atol=1e-7)


@pytest.mark.parametrize("orientation", range(1, 9))
def test_numpy_orientation_matches_pillow(orientation):
    # the 16-bit OpenCV path re-implements exif_transpose on arrays
    a = np.arange(5 * 7 * 3, dtype=np.uint8).reshape(5, 7, 3)
    im = Image.fromarray(a)
    exif = im.getexif()
    exif[0x0112] = orientation
    im.info["exif"] = exif.tobytes()
    ref = np.asarray(ImageOps.exif_transpose(im))
    assert np.array_equal(fio._read._apply_orientation(a, orientation), ref)


@pytest.mark.parametrize("ext", [".tif", ".webp", ".png", ".jpg"])
def test_write_read_roundtrip_formats(tmp_path, ext):
    img = fio.read_image(SAMPLE)[:64, :48]
    fio.write_image(tmp_path / f"x{ext}", img, quality=100)
    back = fio.read_image(tmp_path / f"x{ext}")
    assert back.shape == img.shape
    tol = 1e-6 if ext in (".tif", ".png") else 0.02
    assert np.abs(back - fio.to_float32(fio.to_uint8(img))).mean() <= tol


def test_write_16bit_png_roundtrip(tmp_path):
    img = np.linspace(0, 1, 32 * 32 * 3, dtype=np.float32).reshape(32, 32, 3)
    fio.write_image(tmp_path / "h.png", img, bit_depth=16)
    assert cv2.imread(str(tmp_path / "h.png"), cv2.IMREAD_UNCHANGED).dtype == np.uint16
    np.testing.assert_allclose(fio.read_image(tmp_path / "h.png"), img, atol=1 / 65535)


def test_write_gray_2d(tmp_path):
    fio.write_image(tmp_path / "g.png", np.full((20, 16), 0.25, np.float32))
    np.testing.assert_allclose(fio.read_image(tmp_path / "g.png"), 64 / 255, atol=1e-6)


def test_write_image_bad_requests(tmp_path):
    img = np.zeros((16, 16, 3), np.float32)
    with pytest.raises(BadInputError):
        fio.write_image(tmp_path / "x.jpg", img, bit_depth=16)
    with pytest.raises(OutputError, match="extension"):
        fio.write_image(tmp_path / "x.bmpx", img)
    fio.write_image(tmp_path / "x.png", img)
    with pytest.raises(OutputError, match="--overwrite"):
        fio.write_image(tmp_path / "x.png", img, overwrite=False)


def test_uint8_float_helpers():
    assert fio.to_uint8(np.array([0.0, 0.5, 1.2, -0.1, 1 / 255])).tolist() == [0, 128, 255, 0, 1]
    assert fio.to_uint8(np.array([65535, 257, 128], np.uint16)).tolist() == [255, 1, 0]
    np.testing.assert_allclose(fio.to_float32(np.array([0, 51, 255], np.uint8)), [0, 0.2, 1])
    assert fio.to_float32(np.array([65535], np.uint16)).tolist() == [1.0]


# ---------------------------------------------------------------- reading: failures
def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _bad_files(tmp_path):
    good = SAMPLE.read_bytes()
    (tmp_path / "zero.jpg").write_bytes(b"")
    (tmp_path / "trunc.jpg").write_bytes(good[: len(good) // 2])
    png = tmp_path / "ok.png"
    Image.fromarray(np.random.default_rng(1).integers(0, 255, (64, 64, 3), dtype=np.uint8)).save(png)
    raw = bytearray(png.read_bytes())
    raw[100:140] = b"\x00" * 40  # corrupt the IDAT stream
    (tmp_path / "corrupt.png").write_bytes(bytes(raw))
    (tmp_path / "text.jpg").write_text("this is not an image\n" * 20)
    (tmp_path / "random.png").write_bytes(np.random.default_rng(2).bytes(4096))
    (tmp_path / "adir.png").mkdir()
    Image.new("RGB", (10, 12)).save(tmp_path / "tiny.png")
    return {
        "missing.jpg": "not found", "zero.jpg": "empty", "trunc.jpg": "truncated",
        "corrupt.png": "corrupt", "text.jpg": "not an image", "random.png": "not an image",
        "adir.png": "directory", "tiny.png": "10x12",
    }


def test_bad_images_raise_with_name(tmp_path):
    for name, cause in _bad_files(tmp_path).items():
        with pytest.raises(BadImageError) as e:
            fio.read_image(tmp_path / name)
        msg = str(e.value)
        assert name in msg and cause in msg and "\n" not in msg, msg
        assert e.value.path == str(tmp_path / name)


def test_min_size_is_configurable(tmp_path):
    Image.new("RGB", (10, 12)).save(tmp_path / "tiny.png")
    assert fio.read_image(tmp_path / "tiny.png", min_size=8).shape == (12, 10, 3)


def test_decompression_bomb_fails_fast(tmp_path):
    ihdr = struct.pack(">IIBBBBB", 20000, 20000, 8, 2, 0, 0, 0)
    data = (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
            + _png_chunk(b"IDAT", zlib.compress(b"\0" * 1000)) + _png_chunk(b"IEND", b""))
    (tmp_path / "bomb.png").write_bytes(data)
    t = time.perf_counter()
    with pytest.raises(BadImageError) as e:
        fio.read_image(tmp_path / "bomb.png")
    assert time.perf_counter() - t < 1.0
    assert "bomb.png" in str(e.value) and "20000x20000" in str(e.value) and str(fio.MAX_IMAGE_PIXELS) in str(e.value)


def test_bad_background_value():
    with pytest.raises(BadInputError):
        fio.read_image(SAMPLE, background="grey")


# ------------------------------------------------------------------------- writing
def test_atomic_path_success_and_mode(tmp_path):
    target = tmp_path / "out.txt"
    with fio.atomic_path(target) as tmp:
        assert tmp.parent == tmp_path and tmp.suffix == ".txt" and not target.exists()
        tmp.write_text("new")
    assert target.read_text() == "new" and os.listdir(tmp_path) == ["out.txt"]
    assert target.stat().st_mode & 0o044  # not left at mkstemp's 0600


@pytest.mark.parametrize("exc", [RuntimeError, KeyboardInterrupt])
def test_atomic_path_exception_leaves_nothing(tmp_path, exc):
    with pytest.raises(exc):
        with fio.atomic_path(tmp_path / "out.png") as tmp:
            tmp.write_bytes(b"partial")
            raise exc()
    assert os.listdir(tmp_path) == []
    (tmp_path / "old.png").write_bytes(b"old")
    with pytest.raises(exc):
        with fio.atomic_path(tmp_path / "old.png") as tmp:
            tmp.write_bytes(b"partial")
            raise exc()
    assert os.listdir(tmp_path) == ["old.png"] and (tmp_path / "old.png").read_bytes() == b"old"


def test_check_output_path(tmp_path):
    with pytest.raises(OutputError, match="does not exist") as e:
        fio.check_output_path(tmp_path / "nope" / "x.png")
    assert e.value.path == str(tmp_path / "nope" / "x.png")
    (tmp_path / "x.png").write_bytes(b"x")
    with pytest.raises(OutputError, match="--overwrite"):
        fio.check_output_path(tmp_path / "x.png")
    assert fio.check_output_path(tmp_path / "x.png", overwrite=True) == tmp_path / "x.png"
    assert fio.check_output_path(tmp_path / "y.png") == tmp_path / "y.png"
    with pytest.raises(OutputError, match="directory"):
        fio.check_output_path(tmp_path, overwrite=True)


@pytest.mark.skipif(os.name != "posix" or os.geteuid() == 0, reason="root ignores permissions")
def test_check_output_path_read_only(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        with pytest.raises(OutputError, match="not writable"):
            fio.check_output_path(ro / "x.png")
    finally:
        ro.chmod(0o755)


def test_write_json_converts_numpy(tmp_path):
    obj = {"a": np.float32(1.5), "b": np.arange(3), "c": np.int64(7), "p": tmp_path, "t": (1, 2)}
    fio.write_json(tmp_path / "s.json", obj)
    assert json.loads((tmp_path / "s.json").read_text()) == {
        "a": 1.5, "b": [0, 1, 2], "c": 7, "p": str(tmp_path), "t": [1, 2]}
    with pytest.raises(OutputError):
        fio.write_json(tmp_path / "s.json", {}, overwrite=False)


# --------------------------------------------------------------------------- video
def _pattern(n, h=48, w=64):
    yy, xx = np.mgrid[0:h, 0:w]
    for i in range(n):  # a generator: write_video must stream it
        yield (0.5 + 0.35 * np.sin(np.stack([xx / 9 + i * 0.4, yy / 8 - i * 0.3, (xx + yy) / 13 + i * 0.2],
                                            -1))).astype(np.float32)


def _make_clip(path, audio_codec="aac", seconds=2.0, video=True, rate=22050):
    with av.open(str(path), "w") as c:  # all streams must exist before the first mux
        v = c.add_stream("libx264", rate=25) if video else None
        a = c.add_stream(audio_codec, rate=rate)
        a.layout = "mono"
        if v is not None:
            v.width, v.height, v.pix_fmt = 64, 48, "yuv420p"
            for i in range(int(seconds * 25)):
                f = av.VideoFrame.from_ndarray(np.full((48, 64, 3), i * 4, np.uint8), format="rgb24")
                f.pts = i
                c.mux(v.encode(f))
            c.mux(v.encode(None))
        for t0 in range(0, int(seconds * rate), 1024):
            s = np.sin(2 * np.pi * 440 * np.arange(t0, t0 + 1024) / rate).astype(np.float32)[None]
            af = av.AudioFrame.from_ndarray(s, format="fltp", layout="mono")
            af.sample_rate, af.pts = rate, t0
            c.mux(a.encode(af))
        c.mux(a.encode(None))
    return path


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    path = tmp_path_factory.mktemp("video") / "v.mp4"
    fio.write_video(path, _pattern(10), 25)
    return path


_SAME_VIDEO = """
import hashlib, sys
import numpy as np
import facetex.io as fio
rng = np.random.default_rng(0)
yy, xx = np.mgrid[0:144, 0:180]
frames = [np.clip(0.5 + 0.4 * np.sin(np.stack([xx / 7 + t / 3, yy / 5 - t / 4, (xx + yy) / 9 + t / 5], -1))
                  + rng.normal(0, 0.05, (144, 180, 3)), 0, 1) for t in range(40)]
for k in range(5):
    opts = {"x264-params": "keyint=50"} if k >= 3 else None
    out = fio.write_video(f"{sys.argv[1]}/d{k}.mp4", frames, 25, encoder_options=opts)
    print(hashlib.sha256(out.read_bytes()).hexdigest())
"""


def test_write_video_is_deterministic(tmp_path):
    """The same frames give the same file every time, also with the caller's own x264-params:
    libx264's MB-tree made them differ run to run (decoded frames up to 45/255 apart at 180 x 144;
    in a fresh process, as a user's runs are)."""
    import subprocess
    import sys

    res = subprocess.run([sys.executable, "-c", _SAME_VIDEO, str(tmp_path)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr
    digests = res.stdout.split()
    assert len(digests) == 5 and len(set(digests[:3])) == 1 and len(set(digests[3:])) == 1, digests


def test_video_roundtrip(clip):
    info = fio.video_info(clip)
    assert info == dict(info, fps=25.0, n_frames=10, width=64, height=48, has_audio=False)
    assert info["duration"] == pytest.approx(0.4, abs=0.05)
    calls = []
    frames, fps = fio.read_video(clip, progress=lambda n=1, **kw: calls.append(n))
    assert len(calls) == 10
    assert fps == 25.0 and len(frames) == 10
    assert all(f.shape == (48, 64, 3) and f.dtype == np.float32 for f in frames)
    err = max(np.abs(a - b).mean() for a, b in zip(frames, _pattern(10)))
    assert err < 0.03
    assert len(fio.read_video(clip, max_frames=3)[0]) == 3


def _stored_turned(path, frames, rotation):
    """A clip as a phone writes one: each frame stored turned by -rotation degrees, with a display
    matrix that turns it back by ``rotation`` (counter-clockwise) to show it."""
    k = -(rotation // 90)
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=25)
        h, w = np.rot90(frames[0], k).shape[:2]
        s.width, s.height, s.pix_fmt = w, h, "yuv420p"
        s.set_display_rotation(rotation)
        for f in frames:
            c.mux(s.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(np.rot90(f, k)), format="rgb24")))
        c.mux(s.encode(None))
    return path


@pytest.mark.parametrize("rotation", [-90, 90, 180])
def test_frames_come_upright_as_their_display_matrix_says(tmp_path, rotation):
    """A phone's portrait clip is stored landscape with a display rotation (-90 on iPhones): read as
    stored, every face was on its side and the puppet found none. Frames and video_info are as shown."""
    up = [(f * 255).astype(np.uint8) for f in _pattern(4, 48, 64)]
    up = [np.ascontiguousarray(np.pad(f, ((0, 0), (0, 16), (0, 0)))) for f in up]  # 48 x 80: a turn shows
    path = _stored_turned(tmp_path / "p.mp4", up, rotation)
    with av.open(str(path)) as c:  # stored turned (the test's premise)
        assert next(c.decode(video=0)).to_ndarray(format="rgb24").shape[:2] == ((80, 48) if rotation % 180 else (48, 80))
    back = list(fio.iter_video_frames(path, uint8=True))
    assert len(back) == 4 and all(b.shape == (48, 80, 3) and b.flags.c_contiguous for b in back)
    err = np.mean([np.abs(b.astype(float) - u).mean() for b, u in zip(back, up)])
    wrong = np.mean([np.abs(b.astype(float) - u[::-1, ::-1]).mean() for b, u in zip(back, up)])
    assert err < 6 and wrong > 5 * err, (err, wrong)
    small = next(fio.iter_video_frames(path, uint8=True, max_side=40))  # scaled down while converted
    assert small.shape == (24, 40, 3)
    info = fio.video_info(path)
    assert (info["width"], info["height"], info["rotation"], info["n_frames"]) == (80, 48, rotation % 360, 4)
    assert fio.display_turns(-90) == 3 and fio.display_turns(89.0) == 1 and fio.display_turns(None) == 0


def test_uint8_frames_are_the_decoded_values(clip):
    u8 = list(fio.iter_video_frames(clip, max_frames=4, uint8=True))
    f32 = list(fio.iter_video_frames(clip, max_frames=4))
    assert len(u8) == 4 and all(u.dtype == np.uint8 and u.shape == (48, 64, 3) for u in u8)
    assert all(np.array_equal(u.astype(np.float32) / 255.0, f) for u, f in zip(u8, f32))


def test_odd_size_is_padded(tmp_path):
    frames = [np.full((47, 63, 3), 0.5, np.float32)] * 3
    frames = [f.copy() for f in frames]
    for f in frames:
        f[:, -1] = 0.9  # last column is repeated into the padding
    fio.write_video(tmp_path / "o.mp4", frames, 25)
    back, _ = fio.read_video(tmp_path / "o.mp4")
    assert back[0].shape == (48, 64, 3)
    assert abs(back[0][20, -1, 0] - 0.9) < 0.05 and abs(back[0][20, 30, 0] - 0.5) < 0.05


def test_audio_passthrough_aac_remux(tmp_path):
    src = _make_clip(tmp_path / "src.mp4", "aac")
    out = fio.write_video(tmp_path / "o.mp4", _pattern(10), 25, audio_from=src)
    assert fio.video_info(out)["has_audio"]
    with av.open(str(out)) as c:
        a = c.streams.audio[0]
        assert a.codec_context.name == "aac"
        assert float(a.duration * a.time_base) < 0.4 + 0.1  # trimmed from 2 s to the video


def test_audio_reencoded_from_pcm(tmp_path):
    src = _make_clip(tmp_path / "src.mkv", "pcm_s16le")
    out = fio.write_video(tmp_path / "o.mp4", _pattern(10), 25, audio_from=src)
    with av.open(str(out)) as c:
        a = c.streams.audio[0]
        assert a.codec_context.name == "aac" and a.rate == 22050
        assert 0.2 < float(a.duration * a.time_base) < 0.5
        samples = np.concatenate([f.to_ndarray().ravel() for f in c.decode(a)])
    assert np.abs(samples).max() > 0.5  # the sine survived


def test_transcoded_audio_remuxes_into_the_output(tmp_path, clip):
    src = _make_clip(tmp_path / "src.mkv", "pcm_s16le")
    m4a = fio.transcode_audio(src, tmp_path / "a.m4a")
    with av.open(str(m4a)) as c:
        assert [s.codec_context.name for s in c.streams] == ["aac"]
        assert float(c.streams.audio[0].duration * c.streams.audio[0].time_base) == pytest.approx(2.0, abs=0.1)
    out = fio.write_video(tmp_path / "o.mp4", _pattern(10), 25, audio_from=m4a)
    with av.open(str(out)) as c:
        samples = np.concatenate([f.to_ndarray().ravel() for f in c.decode(c.streams.audio[0])])
    assert np.abs(samples).max() > 0.5
    # no audio, or no readable file: None and nothing written
    assert fio.transcode_audio(clip, tmp_path / "b.m4a") is None
    (tmp_path / "junk.mp4").write_bytes(b"not a video" * 10)
    assert fio.transcode_audio(tmp_path / "junk.mp4", tmp_path / "c.m4a") is None
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.m4a", "junk.mp4", "o.mp4", "src.mkv"]
    assert m4a not in fio.committed_outputs()  # a scratch file, not an output


def test_audio_from_silent_video_adds_no_audio(tmp_path, clip):
    out = fio.write_video(tmp_path / "o.mp4", _pattern(3), 25, audio_from=clip)
    assert not fio.video_info(out)["has_audio"]


def test_bad_videos_raise_with_name(tmp_path):
    (tmp_path / "zero.mp4").write_bytes(b"")
    (tmp_path / "text.mp4").write_text("hello, not a video\n" * 50)
    _make_clip(tmp_path / "audio.mka", "aac", video=False)
    for name in ["zero.mp4", "text.mp4", "missing.mp4", "audio.mka"]:
        for call in (fio.video_info, lambda p: list(fio.iter_video_frames(p))):
            with pytest.raises(BadVideoError) as e:
                call(tmp_path / name)
            assert name in str(e.value) and "\n" not in str(e.value)


def test_truncated_mp4(tmp_path, clip):
    data = clip.read_bytes()
    with av.open(str(clip)) as c:  # byte offsets of the coded frames (moov is up front: faststart)
        packets = [(p.pos, p.size) for p in c.demux(c.streams.video[0]) if p.size]
    (tmp_path / "head.mp4").write_bytes(data[: packets[0][0] // 2])  # cut inside the header
    with pytest.raises(BadVideoError):
        list(fio.iter_video_frames(tmp_path / "head.mp4"))
    pos, size = packets[5]
    (tmp_path / "mid.mp4").write_bytes(data[: pos + size // 2])  # cut inside the 6th frame
    with pytest.warns(UserWarning, match="damaged"):
        n = len(list(fio.iter_video_frames(tmp_path / "mid.mp4")))
    assert 1 <= n < 10  # implemented: the decodable frames are yielded, then iteration stops


def test_write_video_bad_frames_leave_nothing(tmp_path):
    with pytest.raises(BadInputError):
        fio.write_video(tmp_path / "e.mp4", [], 25)
    frames = [np.zeros((48, 64, 3), np.float32), np.zeros((40, 64, 3), np.float32)]
    with pytest.raises(BadInputError):
        fio.write_video(tmp_path / "m.mp4", frames, 25)
    assert os.listdir(tmp_path) == []


# ------------------------------------------------------------ issue 13: reduced reading, commits
@pytest.mark.parametrize("ext, mode", [(".jpg", "RGB"), (".png", "RGB"), (".png", "RGBA"), (".png", "P"),
                                       (".tif", "RGB16")])
def test_read_image_reduced_matches_a_resize(tmp_path, ext, mode):
    base = cv2.resize(fio.read_image(SAMPLE), (1200, 900), interpolation=cv2.INTER_CUBIC)
    path = tmp_path / f"big{ext}"
    if mode == "RGB16":
        cv2.imwrite(str(path), (np.clip(base, 0, 1) * 65535).astype(np.uint16)[..., ::-1])
    else:
        im = Image.fromarray(fio.to_uint8(base))
        im = im.convert(mode) if mode != "P" else im.convert("P", palette=Image.Palette.ADAPTIVE)
        im.save(path, quality=95)
    img, (sx, sy) = fio.read_image_reduced(path, 200_000)
    h, w = img.shape[:2]
    assert h * w <= 200_000 and abs(w / h - 4 / 3) < 0.02
    assert abs(sx - w / 1200) < 1e-9 and abs(sy - h / 900) < 1e-9
    ref = cv2.resize(base, (w, h), interpolation=cv2.INTER_AREA)
    assert np.abs(img - ref).mean() < 0.03  # the same picture, smaller
    full = fio.read_image(path)
    assert full.shape == (900, 1200, 3)  # without reduce_to: full resolution


def test_read_image_reduced_exif_rotation_scale(tmp_path):
    base = Image.open(SAMPLE).convert("RGB").resize((800, 600))
    exif = Image.Exif()
    exif[0x0112] = 6  # stored turned to 600 x 800; displayed 800 x 600 again
    base.transpose(Image.Transpose.ROTATE_90).save(tmp_path / "r.jpg", exif=exif.tobytes(), quality=95)
    img, (sx, sy) = fio.read_image_reduced(tmp_path / "r.jpg", 60_000)
    h, w = img.shape[:2]
    assert w > h  # displayed orientation, not the stored one
    assert abs(sx - w / 800) < 1e-9 and abs(sy - h / 600) < 1e-9
    ref = cv2.resize(np.asarray(base, np.float32) / 255, (w, h), interpolation=cv2.INTER_AREA)
    assert np.abs(img - ref).mean() < 0.03


def test_small_image_not_reduced(tmp_path):
    img, scale = fio.read_image_reduced(SAMPLE, fio.DETECT_MAX_PIXELS)
    assert img.shape == (400, 400, 3) and scale == (1.0, 1.0)


def test_memory_budget_refuses_from_header(tmp_path):
    ihdr = struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0)
    (tmp_path / "b.png").write_bytes(b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", ihdr)
                                     + _png_chunk(b"IDAT", zlib.compress(b"\0" * 10)) + _png_chunk(b"IEND", b""))
    with pytest.raises(BadImageError, match=r"30000x30000.*GiB to decode.*limit"):
        fio.read_image(tmp_path / "b.png", reduce_to=1_000_000)


def test_check_input_file_kinds(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    (tmp_path / "dangling").symlink_to(tmp_path / "nothing")
    (tmp_path / "zero").symlink_to("/dev/zero")
    for name, cause in {"fifo": "FIFO", "loop": "symlink loop", "dangling": "broken symlink",
                        "zero": "character device", "missing": "not found"}.items():
        with pytest.raises(BadInputError, match=cause) as e:
            fio.check_input_file(tmp_path / name)
        assert e.value.path == str(tmp_path / name)


def test_write_files_exclusive_and_rollback(tmp_path):
    a, b = tmp_path / "a.png", tmp_path / "a.png.json"
    fio.write_files({a: b"one", b: "two"}, overwrite=False)
    assert a.read_bytes() == b"one" and b.read_text() == "two"
    with pytest.raises(OutputError, match="exists"):
        fio.write_files({a: b"x", b: "y"}, overwrite=False)
    fio.write_files({a: b"three", b: "four"}, overwrite=True)
    assert a.read_bytes() == b"three" and b.read_text() == "four"
    # a failure while committing the second file restores the first (overwrite: from its backup)
    real = fio._atomic._link_new
    b.unlink()
    fio._atomic._link_new = lambda tmp, final: (_ for _ in ()).throw(OSError(28, "No space left on device"))
    try:
        with pytest.raises(OutputError, match="disk full"):
            fio.write_files({tmp_path / "new.png": b"n"}, overwrite=False)
    finally:
        fio._atomic._link_new = real
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png"]


def test_output_checks_whatever_overwrite(tmp_path):
    src = tmp_path / "in.png"
    src.write_bytes(b"input")
    os.mkfifo(tmp_path / "f.png")
    with pytest.raises(OutputError, match="same file as the input"):
        fio.check_output_path(src, overwrite=True, inputs=[src])
    with pytest.raises(OutputError, match="FIFO"):
        fio.check_output_path(tmp_path / "f.png", overwrite=True)
    with pytest.raises(OutputError, match="same file as the input"):
        fio.write_image(src, np.zeros((20, 20, 3)), overwrite=True, inputs=[src])
    assert src.read_bytes() == b"input"
    with pytest.raises(OutputError, match=r"extension '\.xyz'"):
        fio.write_image(tmp_path / "o.xyz", np.zeros((20, 20, 3)))


def test_npz_members_reads_headers_only(tmp_path):
    np.savez_compressed(tmp_path / "a.npz", x=np.zeros((3, 4), np.float32), y=np.arange(5))
    m = fio.npz_members(tmp_path / "a.npz")
    assert m["x"]["shape"] == (3, 4) and m["x"]["dtype"] == np.float32 and m["y"]["shape"] == (5,)
    np.save(tmp_path / "o.npy", np.array([object()], dtype=object), allow_pickle=True)
    import zipfile

    with zipfile.ZipFile(tmp_path / "b.npz", "w") as z:
        z.write(tmp_path / "o.npy", "o.npy")
    with pytest.raises(BadInputError, match="Python objects"):
        fio.npz_members(tmp_path / "b.npz")
