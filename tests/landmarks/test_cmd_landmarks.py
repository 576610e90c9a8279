"""``facetex landmarks`` CLI."""

from __future__ import annotations

import json

import numpy as np
from PIL import Image

from facetex._resources import sample_path
from facetex.cli import main

SAMPLE = str(sample_path("frl_005_neutral.jpg"))


def test_json_output(capsys):
    assert main(["landmarks", SAMPLE, "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert set(out) == {"image", "faces"} and out["image"] == SAMPLE
    assert len(out["faces"]) == 1
    face = out["faces"][0]
    assert set(face) == {"box", "points68"}
    assert len(face["box"]) == 4 and face["box"][0] < face["box"][2] and face["box"][1] < face["box"][3]
    pts = np.array(face["points68"])
    assert pts.shape == (68, 2)
    assert pts[36, 0] < pts[45, 0]


def test_summary_and_overlay_and_overwrite(tmp_path, capsys):
    out = tmp_path / "overlay.png"
    assert main(["landmarks", SAMPLE, "-o", str(out)]) == 0
    text = capsys.readouterr().out
    assert "1 face" in text and "face 0" in text
    ov = np.asarray(Image.open(out).convert("RGB"))
    src = np.asarray(Image.open(SAMPLE).convert("RGB"))
    assert ov.shape == src.shape
    assert (np.abs(ov.astype(int) - src).sum(-1) > 60).mean() > 0.002  # something was drawn
    assert not list(tmp_path.glob(".*"))  # no temporary file left behind
    before = out.read_bytes()
    assert main(["landmarks", SAMPLE, "-o", str(out)]) != 0
    err = capsys.readouterr().err
    assert "--overwrite" in err and err.count("\n") == 1
    assert out.read_bytes() == before
    assert main(["landmarks", SAMPLE, "-o", str(out), "--overwrite", "--face-index", "0"]) == 0


def test_no_face_and_bad_index(tmp_path, capsys):
    blank = tmp_path / "blank.png"
    Image.fromarray(np.full((160, 160, 3), 200, np.uint8)).save(blank)
    assert main(["landmarks", str(blank)]) != 0
    err = capsys.readouterr().err
    assert str(blank) in err and err.count("\n") == 1
    assert main(["landmarks", SAMPLE, "--face-index", "3"]) != 0
    err = capsys.readouterr().err
    assert "1 face" in err and err.count("\n") == 1
