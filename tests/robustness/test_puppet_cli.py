"""``facetex puppet`` with bad driver videos, bad personas and bad outputs.

Skipped while the puppet command is not registered."""

from __future__ import annotations

import numpy as np
import pytest

from _robust import assert_one_error, run_cli, snapshot
from conftest import has_command

pytestmark = pytest.mark.skipif(not has_command("puppet"), reason="`facetex puppet` not registered yet")


@pytest.mark.parametrize("video, cause", [
    ("noface.mp4", r"no face"),
    ("truncated.mp4", r"not a readable video|truncated|corrupt"),
    ("cut_first.mp4", r"no decodable frame|truncated|corrupt"),
    ("empty.mp4", r"empty"),
    ("text.mp4", r"not a readable video"),
    ("missing.mp4", r"not found"),
])
def test_bad_driver(capsys, videos, outdir, persona_file, video, cause):
    path = videos.get(video, videos["face.mp4"].parent / video)
    run = run_cli(capsys, "puppet", "--driver", path, "--puppet", persona_file, "-o", outdir / "o.mp4",
                  "--size", "96")
    assert_one_error(run, names=[path], cause=cause)
    assert snapshot(outdir) == {}


@pytest.fixture(scope="module")
def bad_personas(tmp_path_factory, persona_file):
    import json

    d = tmp_path_factory.mktemp("puppet_personas")
    (d / "random.persona").write_bytes(np.random.default_rng(2).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    raw = persona_file.read_bytes()
    (d / "truncated.persona").write_bytes(raw[: len(raw) // 3])
    head = {"format": "facetex-persona", "version": 7}
    with open(d / "future.persona", "wb") as fh:
        np.savez(fh, header=np.frombuffer(json.dumps(head).encode(), np.uint8))
    return d


@pytest.mark.parametrize("name, cause", [("random.persona", r"corrupt|not a persona"),
                                         ("truncated.persona", r"corrupt"),
                                         ("future.persona", r"version 7"),
                                         ("missing.persona", r"not found")])
def test_bad_persona(capsys, videos, outdir, bad_personas, name, cause):
    path = bad_personas / name
    run = run_cli(capsys, "puppet", "--driver", videos["face.mp4"], "--puppet", path, "-o", outdir / "o.mp4")
    assert_one_error(run, names=[path], cause=cause)
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("target, cause", [("missing/o.mp4", r"does not exist"), ("o.mp4", r"exists.*--overwrite"),
                                           ("afile/o.mp4", r"not a folder")])
def test_bad_output(capsys, videos, outdir, persona_file, target, cause):
    (outdir / "o.mp4").write_bytes(b"old")
    (outdir / "afile").write_bytes(b"a file")
    before = snapshot(outdir)
    run = run_cli(capsys, "puppet", "--driver", videos["face.mp4"], "--puppet", persona_file,
                  "-o", outdir / target)
    assert_one_error(run, names=[outdir / target], cause=cause)
    assert snapshot(outdir) == before


def test_partly_decodable_driver_warns_and_works(capsys, videos, outdir, persona_file):
    """A video cut after two whole frames: those two are used, with one warning line naming it."""
    from facetex.io import video_info

    path = videos["cut_mid.mp4"]
    run = run_cli(capsys, "puppet", "--driver", path, "--puppet", persona_file, "-o", outdir / "o.mp4",
                  "--size", "96")
    assert run.code == 0, run.err
    assert "Traceback" not in run.err and run.lines == [], run.lines
    warnings = [l for l in run.err.replace("\r", "\n").splitlines() if l.startswith("facetex: warning:")]
    assert warnings and all(path.name in w and "damaged" in w for w in warnings)
    assert sorted(p.name for p in outdir.iterdir()) == ["o.mp4", "o.mp4.json"]  # no temp file; the sidecar
    assert video_info(outdir / "o.mp4")["n_frames"] == 2


@pytest.fixture(scope="module")
def sliding(tmp_path_factory):
    """Driver videos whose face is half outside the frame: always, and in the last frames only."""
    import cv2

    from _robust import FACE

    from facetex.io import read_image, write_video

    img = cv2.resize(read_image(FACE), (240, 240), interpolation=cv2.INTER_AREA)

    def shifted(dx):
        return cv2.warpAffine(img, np.float32([[1, 0, dx], [0, 1, 0]]), (240, 240), borderMode=cv2.BORDER_REPLICATE)

    d = tmp_path_factory.mktemp("sliding")
    write_video(d / "half_out.mp4", [shifted(-120)] * 4, 10)
    write_video(d / "leaves.mp4", [img] * 4 + [shifted(-120)] * 3, 10)
    return d


def test_face_always_half_outside_the_frame(capsys, sliding, outdir, persona_file):
    path = sliding / "half_out.mp4"
    run = run_cli(capsys, "puppet", "--driver", path, "--puppet", persona_file, "-o", outdir / "o.mp4", "--size", "96")
    assert_one_error(run, names=[path], cause=r"no usable face|no face")
    assert snapshot(outdir) == {}


def test_face_leaving_the_frame_is_reported_lost(capsys, sliding, outdir, persona_file):
    import json

    path = sliding / "leaves.mp4"
    run = run_cli(capsys, "puppet", "--driver", path, "--puppet", persona_file, "-o", outdir / "o.mp4", "--size", "96",
                  "--json")
    assert run.code == 0, run.err
    report = json.loads(run.out)
    assert report["lost_indices"] == [4, 5, 6]
    assert sum(report["lost_causes"].values()) == 3
    assert any("lost in 3 of 7 frames" in l and path.name in l for l in run.lines), run.lines
    assert sorted(p.name for p in outdir.iterdir()) == ["o.mp4", "o.mp4.json"]


def test_phone_portrait_driver_is_read_upright(capsys, tmp_path, outdir, persona_file):
    """A phone's portrait clip: frames stored landscape with a display rotation of -90 degrees. Read as
    stored, the face lay on its side and the puppet found none in any frame."""
    import json

    import av

    from _robust import FACE

    from facetex.io import read_image_uint8, video_info

    face = read_image_uint8(FACE)
    h, w = face.shape[:2]
    face = np.ascontiguousarray(face[: h // 2 * 2, w // 10: w // 10 + w * 4 // 5 // 2 * 2])  # taller than wide
    stored = np.ascontiguousarray(np.rot90(face, 1))  # turned +90: shown by turning it -90 (ccw)
    path = tmp_path / "portrait.mp4"
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=10)
        s.width, s.height, s.pix_fmt = stored.shape[1], stored.shape[0], "yuv420p"
        s.set_display_rotation(-90)
        for _ in range(4):
            c.mux(s.encode(av.VideoFrame.from_ndarray(stored, format="rgb24")))
        c.mux(s.encode(None))
    run = run_cli(capsys, "puppet", "--driver", path, "--puppet", persona_file, "-o", outdir / "o.mp4",
                  "--size", "96", "--json")
    assert run.code == 0, run.err
    assert json.loads(run.out)["lost_indices"] == []
    out = video_info(outdir / "o.mp4")
    assert out["width"] < out["height"] and out["rotation"] == 0  # upright: portrait, as shown
