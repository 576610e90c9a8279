"""Pieces of ``facetex bench persona``: region masks and scores, zoom sheets, the teeth score."""

import cv2
import numpy as np
import pytest

from facetex.bench.persona import evaluation_masks, region_scores, teeth_score, write_zoom_sheets, zoom_boxes
from facetex.geometry.frontalize import canonical_points68
from facetex.io import read_image

W, H = 192, 240
P68 = canonical_points68((W, H))


def test_evaluation_masks_and_region_scores():
    vis = np.ones((H, W), np.float32)
    vis[:, : W // 2] = 0  # only the right half seen: the scores ignore the rest
    m = evaluation_masks(P68, vis)
    assert set(m) == {"face", "mouth", "eyes"}
    assert not (m["mouth"] & m["eyes"]).any() and (m["mouth"] <= m["face"]).all() and (m["eyes"] <= m["face"]).all()
    assert m["mouth"].sum() > 200 and m["eyes"].sum() > 200 and not m["face"][:, : W // 2].any()
    rng = np.random.default_rng(0)
    ref = rng.random((H, W, 3)).astype(np.float32)
    same = region_scores(ref, ref, m)
    assert all(abs(same[r]["ssim"] - 1) < 1e-6 and same[r]["colour_diff"] < 1e-4 for r in m)
    # damage only the mouth: the mouth score drops, the eyes' does not
    bad = ref.copy()
    bad[m["mouth"]] = 0.5
    s = region_scores(bad, ref, m)
    assert s["mouth"]["ssim"] < 0.5 and s["eyes"]["ssim"] > 0.99 and s["face"]["ssim"] < 0.99
    # an unseen region (too few pixels) gives NaN, not an error
    assert np.isnan(region_scores(ref, ref, {"none": np.zeros((H, W), bool)})["none"]["ssim"])


def test_teeth_score():
    img = np.full((H, W, 3), 150, np.uint8)
    closed = teeth_score(img, P68)
    opened = P68.copy()
    opened[[65, 66, 67], 1] += 10  # lower inner lip down: the lips apart
    mouth = np.zeros((H, W), np.uint8)
    cv2.fillPoly(mouth, [np.round(opened[60:68]).astype(np.int32)], 1)
    teeth = img.copy()
    teeth[mouth > 0] = (235, 235, 225)  # bright, unsaturated
    dark = img.copy()
    dark[mouth > 0] = (60, 20, 25)
    assert closed == 0.0 and teeth_score(teeth, opened) > 0.9 and teeth_score(dark, opened) < 0.05


def test_zoom_sheets(tmp_path):
    boxes = zoom_boxes(P68)
    assert set(boxes) == {"mouth", "eyes", "brow", "chin", "boundary"}
    for x, y, w, h in boxes.values():
        assert 0 <= x and x + w <= W and 0 <= y and y + h <= H and w > 10 and h > 10
    rng = np.random.default_rng(1)
    imgs = {c: rng.random((H, W, 3)).astype(np.float32) for c in ("reference", "static", "paper", "ours")}
    files = write_zoom_sheets(tmp_path, [{"points68": P68, "images": imgs}] * 2)
    assert sorted(files) == sorted(f"zoom_{r}.png" for r in boxes)
    sheet = read_image(tmp_path / "zoom_mouth.png")
    x, y, w, h = boxes["mouth"]
    assert sheet.shape[0] == 28 + 2 * (3 * h + 4) and sheet.shape[1] == 4 * 3 * w + 3 * 4


def test_k_fold_leave_out_scores_every_photo_once_with_a_persona_without_it(tmp_path):
    import json

    import pytest
    from _photos import write_jittered_copies

    from facetex.bench.persona import run_bench_persona
    from facetex.errors import BadInputError
    from facetex.persona import load_persona

    photos = tmp_path / "photos"
    photos.mkdir()
    write_jittered_copies(photos, 10, np.random.default_rng(2))  # 20 photos: two folds of 10
    with pytest.raises(BadInputError, match="--folds"):
        run_bench_persona(photos, folds=1, out=tmp_path / "bad")
    res = run_bench_persona(photos, folds=2, out=tmp_path / "out", jobs=1, grid_rows=1)
    files = sorted(t["file"] for t in res["targets"])
    assert files == sorted(p.name for p in photos.iterdir())  # every photo a target, once
    for k in (0, 1):
        persona = load_persona(tmp_path / "out" / f"photos_fold{k}of2_seed0.persona")
        held = {t["file"] for t in res["targets"] if t["fold"] == k}
        assert len(held) == 10 and not held & set(persona.photos) and len(persona) == 10
    summary = json.loads((tmp_path / "out" / "results.json").read_text())
    assert summary["folds"] == 2 and summary["holdout"] is None and summary["persona_photos"] == [10, 10]
    assert [r["n"] for r in res["rows"]] == [20] * len(res["rows"])
    assert "2 folds (seed 0): every usable photo (20)" in res["table"]


def test_gain_by_expression_groups_targets_by_mouth_distance():
    from facetex.bench.persona import gain_by_expression

    # distances 0..5 (given shuffled), gains: the three nearest gain nothing, the farthest the most
    d = [5, 0, 3, 1, 4, 2]
    gain = {0: 0.0, 1: 0.0, 2: 0.01, 3: 0.03, 4: 0.05, 5: 0.09}
    recs = [{"mouth_expression": float(x), "ours_mouth_ssim": 0.5 + gain[x], "static_mouth_ssim": 0.5} for x in d]
    assert gain_by_expression(recs) == pytest.approx([0.0, 0.02, 0.07])
    assert gain_by_expression(recs, parts=2) == pytest.approx([0.01 / 3, 0.17 / 3])


def test_mouth_expression_is_one_for_the_typical_photo_and_grows_with_an_open_mouth(tmp_path):
    from _photos import build_tiny_persona

    from facetex.bench.persona import mouth_expression
    from facetex.persona import load_persona

    persona = load_persona(build_tiny_persona(tmp_path / "p.persona"))
    own = [mouth_expression(persona, f) for f in persona.fiducials]
    assert np.median(own) == pytest.approx(1.0)
    wide = persona.fiducials.mean(axis=0).copy()
    wide[[38, 39, 40, 41, 42, 46, 47, 48], 1] += 0.5 * (wide[25, 0] - wide[19, 0])  # lower lip (iBUG 55-59, 65-67) down
    assert mouth_expression(persona, wide) > 3 * max(own)
