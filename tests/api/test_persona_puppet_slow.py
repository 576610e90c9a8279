"""The persona and puppet commands and API of the README, end to end on a small collection made
from the bundled photos, with their sidecars (slow: builds a persona and renders a video)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

import facetex
from facetex._resources import sample_path
from facetex.cli import main
from facetex.io import read_image, write_image, write_video
from facetex.persona import load_persona

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def photos(tmp_path_factory):
    d = tmp_path_factory.mktemp("photos")
    for name in ("frl_004_neutral", "frl_004_smiling"):
        img = cv2.resize(read_image(sample_path(f"{name}.jpg")), (240, 240), interpolation=cv2.INTER_AREA)
        for k, (gain, angle) in enumerate([(1.0, 0), (0.8, 0), (1.15, 3), (0.9, -3)]):
            m = cv2.getRotationMatrix2D((120, 120), angle, 1.0)
            write_image(d / f"{name}_{k}.jpg", np.clip(cv2.warpAffine(img, m, (240, 240)) * gain, 0, 1))
    return d


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    img = cv2.resize(read_image(sample_path("frl_005_neutral.jpg")), (200, 200), interpolation=cv2.INTER_AREA)
    frames = [np.roll(img, (k % 3) - 1, axis=1) for k in range(10)]
    path = tmp_path_factory.mktemp("driver") / "driver.mp4"
    write_video(path, frames, 10.0)
    return path


def _sidecar(path):
    rec = json.loads(open(f"{path}.json").read())
    assert rec["schema"] == "facetex.provenance/1" and rec["versions"]["facetex"] == facetex.__version__
    assert rec["created_utc"] and rec["command_line"].startswith("facetex")
    return rec


def test_persona_and_puppet_commands(photos, driver, tmp_path, capsys):
    p = tmp_path / "person.persona"
    assert main(["persona", "build", str(photos), "-o", str(p), "--min-photos", "6", "--jobs", "1", "-q"]) == 0
    rec = _sidecar(p)
    assert rec["command"] == "persona build" and rec["inputs"]["photo_dir"]["files"] == 8 and rec["photos_used"] >= 6
    assert rec["params"]["texture_stacks"] is True and load_persona(p).texture_stacks is not None
    small = tmp_path / "small.persona"
    assert main(["persona", "build", str(photos), "-o", str(small), "--min-photos", "6", "--jobs", "1", "-q",
                 "--no-texture-stacks"]) == 0
    assert load_persona(small).texture_stacks is None and small.stat().st_size < p.stat().st_size
    capsys.readouterr()
    out = tmp_path / "tex.png"
    assert main(["persona", "texture", str(p), "--like", str(sample_path("frl_004_smiling.jpg")), "-o", str(out)]) == 0
    assert capsys.readouterr().out.splitlines() == [f"wrote {out}", f"wrote {out}.json"]
    assert _sidecar(out)["inputs"]["persona"]["sha256"]
    assert main(["persona", "average", str(p), "-o", str(tmp_path / "avg.png"), "--stage", "c"]) == 0
    assert _sidecar(tmp_path / "avg.png")["params"]["stage"] == "c"
    assert main(["persona", "mesh", str(p), "-o", str(tmp_path / "face.obj"), "--step", "2"]) == 0
    assert _sidecar(tmp_path / "face.obj")["params"]["step"] == 2
    capsys.readouterr()
    mp4 = tmp_path / "puppet.mp4"
    assert main(["puppet", "--driver", str(driver), "--puppet", str(p), "-o", str(mp4), "--size", "96",
                 "--side-by-side"]) == 0
    text = capsys.readouterr().out
    assert text.splitlines()[-2:] == [f"wrote {mp4}", f"wrote {mp4}.json"] and "{" not in text  # JSON only with --json
    rec = _sidecar(mp4)
    assert rec["result"]["frames"] == 10 and rec["params"]["side_by_side"] is True


def test_persona_and_puppet_api(photos, driver, tmp_path, capsys):
    persona = facetex.build_persona(photos, jobs=1, min_photos=6, progress=True)
    assert "100%" in capsys.readouterr().err
    persona.save(tmp_path / "p.persona")
    tex = facetex.persona_texture(tmp_path / "p.persona", like=sample_path("frl_004_smiling.jpg"))
    assert tex.dtype == np.float32 and tex.shape[2] == 3
    with pytest.raises(ValueError, match="exactly one"):
        facetex.persona_texture(persona)
    avg = facetex.persona_average(persona, stage="d")
    assert avg.shape == tex.shape
    mesh = facetex.persona_mesh(persona, step=2)
    assert mesh.vertices.shape[1] == 3 and len(mesh.faces) > 0
    assert mesh.save(tmp_path / "face.obj").is_file() and (tmp_path / "face.png").is_file()
    report = facetex.puppeteer(driver, persona, tmp_path / "o.mp4", size=96, texture="static")
    assert report["frames"] == 10 and (tmp_path / "o.mp4").is_file()
    with pytest.raises(FileNotFoundError):
        facetex.persona_average(tmp_path / "missing.persona")
