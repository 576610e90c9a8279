"""Pieces of ``facetex bench puppet``: the per-run measures against hand-computed cases, the worst-run
selection and the CLI over several puppets (the puppetry itself replaced by a stand-in)."""

import argparse
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from facetex.bench import puppet as bench
from facetex.bench import puppet_measures as measures
from facetex.errors import BadInputError
from facetex.geometry.frontalize import canonical_points68
from facetex.io import read_image, write_image

W, H = 192, 240
P68 = canonical_points68((W, H))


def _eye(x0, half_height):
    """p1..p6 of an eye 6 px wide: corners at x0 and x0 + 6, lids at x0 + 2 and x0 + 4."""
    return np.array([[x0, 0], [x0 + 2, -half_height], [x0 + 4, -half_height], [x0 + 6, 0], [x0 + 4, half_height],
                     [x0 + 2, half_height]], float)


def test_eye_aspect_ratio_of_known_points():
    p = np.zeros((68, 2))
    p[36:42] = _eye(0, 1)  # (2 + 2) / (2 * 6) = 1/3
    p[42:48] = _eye(20, 2)  # (4 + 4) / 12 = 2/3
    assert bench.eye_aspect_ratio(p) == pytest.approx(0.5)
    assert bench.eye_aspect_ratio(np.stack([p, p])).shape == (2,)


def test_eye_openness_ratio_ignores_the_drivers_blinks():
    drv = np.full(20, 0.3)
    drv[[5, 6, 12]] = 0.05  # blinks: not "open"
    pup = drv * 0.5
    pup[[5, 6, 12]] = 0.3  # what the puppet does there does not count
    pup[3] = np.nan  # a frame without a puppet face is left out
    assert bench.eye_openness_ratio(drv, pup) == pytest.approx(0.5)
    assert np.isnan(bench.eye_openness_ratio(np.full(5, np.nan), pup[:5]))


def test_rest_lift_difference_on_the_drivers_closed_frames():
    """Eye centres 10 apart; the puppet's corners 1 px above the driver's (lift + 0.1) on the closed
    frames, 3 px on the open ones (not counted); a frame without a puppet face is left out."""
    base = np.zeros((68, 2))
    base[36:42], base[42:48] = [0.0, 0.0], [10.0, 0.0]
    base[62], base[66] = [5.0, 20.0], [5.0, 20.0]
    base[48], base[54] = [0.0, 20.0], [10.0, 20.0]
    drv = np.stack([base] * 6)
    pup = drv.copy()
    opening = np.array([0.0, 0.0, 0.0, 0.5, 0.5, 0.5])
    pup[:3, [48, 54], 1] -= 1.0
    pup[3:, [48, 54], 1] -= 3.0
    assert bench.rest_lift_difference(drv, pup, opening, closed=40) == pytest.approx(0.1)
    pup[0] = np.nan
    assert bench.rest_lift_difference(drv, pup, opening, closed=40) == pytest.approx(0.1)
    assert np.isnan(bench.rest_lift_difference(drv[:1], pup[:1], opening[:1]))


def test_blink_correlation_only_when_the_driver_blinks():
    drv = np.full(20, 0.3) + 0.001 * np.arange(20)
    pup = drv.copy()
    assert np.isnan(bench.blink_correlation(drv, pup))  # eyes always open: no blink to follow
    drv[[5, 6]] = 0.05
    assert np.isnan(bench.blink_correlation(drv, np.full(20, 0.25)))  # the puppet does not move: undefined
    follows = drv * 0.8
    stares = 0.3 + 0.001 * np.random.default_rng(0).standard_normal(20)  # eyes open throughout
    assert bench.blink_correlation(drv, follows) == pytest.approx(1.0)
    assert bench.blink_correlation(drv, stares) < 0.5
    row = measures._series_measures({"driver_ear": list(drv), "puppet_ear": [None if i == 3 else v for i, v in
                                                                          enumerate(follows)],
                                  "driver_opening": list(np.linspace(0, 1, 20)),
                                  "puppet_opening": list(np.linspace(0, 0.5, 20))})
    assert row["eye_ratio"] == pytest.approx(0.8) and row["driver_blink_frames"] == 2
    assert row["mouth_slope"] == pytest.approx(0.5) and row["mouth_r"] == pytest.approx(1.0)
    assert row["failed"] == ["mouth_slope", "cheek_de", "sharp", "id_closer"]


def test_cheek_delta_e_of_known_colours():
    black, white = np.zeros((10, 10, 3), np.float32), np.ones((10, 10, 3), np.float32)
    m = np.ones((10, 10), bool)
    assert bench.cheek_delta_e(white, black, m) == pytest.approx(100.0, abs=0.05)  # L* 100 vs 0
    # sRGB 0.5 grey: linear ((0.5 + 0.055) / 1.055) ** 2.4 = 0.2140, L* = 116 * 0.2140 ** (1/3) − 16 = 53.39
    assert bench.cheek_delta_e(black + 0.5, black, m) == pytest.approx(53.39, abs=0.1)
    # only the masked pixels count; too few pixels give NaN
    half = white.copy()
    half[:, 5:] = 0.5
    m2 = np.zeros((10, 10), bool)
    m2[:, :5] = True
    assert bench.cheek_delta_e(half, white, m2) == pytest.approx(0.0, abs=1e-4)
    assert np.isnan(bench.cheek_delta_e(white, black, np.zeros((10, 10), bool)))


def test_under_eye_lightness_difference_by_hand():
    """Grey 0.5 (L* 53.39) against white (100) on the mask: -46.61; the masks sit below the lower lids."""
    black, white = np.zeros((10, 10, 3), np.float32), np.ones((10, 10, 3), np.float32)
    m = np.zeros((10, 10), bool)
    m[2:6, 2:6] = True
    assert bench.lightness_difference(black + 0.5, white, m) == pytest.approx(53.39 - 100.0, abs=0.1)
    assert bench.lightness_difference(white, black + 0.5, m) == pytest.approx(100.0 - 53.39, abs=0.1)
    assert np.isnan(bench.lightness_difference(white, black, np.zeros((10, 10), bool)))
    m = bench.under_eye_mask(P68, (H, W))
    ys, xs = np.nonzero(m)
    d = np.linalg.norm(P68[36] - P68[45])
    assert ys.min() > P68[[40, 41, 46, 47], 1].max()  # below the lower lids
    assert ys.max() < P68[31:36, 1].min()  # above the nostrils
    assert m[:, : W // 2].sum() == pytest.approx(m[:, W // 2:].sum(), rel=0.2)  # both eyes
    assert m.sum() == pytest.approx(2 * np.pi * (0.06 * d) ** 2, rel=0.3)
    assert measures._worst_value("under_eye_dl", [-3.0, 5.0, -12.0, np.nan]) == -12.0  # farthest from 0


def test_sharpness_ratio_on_synthetic_images():
    rng = np.random.default_rng(0)
    img = (0.5 + 0.1 * rng.standard_normal((64, 64))).astype(np.float32)
    rgb = np.repeat(img[..., None], 3, axis=2)
    m = np.zeros((64, 64), bool)
    m[8:56, 8:56] = True
    assert bench.sharpness_ratio(rgb, rgb, m) == pytest.approx(1.0)
    # the Laplacian is linear: twice the contrast, four times its variance; an offset changes nothing
    assert bench.sharpness_ratio(0.5 + 2 * (rgb - 0.5), rgb, m) == pytest.approx(4.0, rel=1e-4)
    assert bench.sharpness_ratio(rgb + 0.2, rgb, m) == pytest.approx(1.0, rel=1e-4)
    blurred = cv2.GaussianBlur(rgb, (0, 0), 1.5)
    assert bench.sharpness_ratio(blurred, rgb, m) < 0.1
    assert np.isnan(bench.sharpness_ratio(rgb, np.full_like(rgb, 0.5), m))  # a flat reference
    assert np.isnan(bench.sharpness_ratio(rgb, rgb, np.zeros_like(m)))


def test_sharpness_ratio_at_half_size_sees_past_a_pixel_grain():
    """A puppet whose only detail is a pixel checkerboard, as strong at full size as the frame's
    2-4 px structure, is flat at half size (every 2 x 2 block averages to its mean): ratio 0 there."""
    rng = np.random.default_rng(1)
    ref = cv2.GaussianBlur(rng.standard_normal((64, 64)).astype(np.float32), (0, 0), 1.5)
    ref = np.repeat((0.5 + 0.5 * ref / ref.std() * 0.1)[..., None], 3, axis=2)
    yy, xx = np.mgrid[0:64, 0:64]
    check = np.repeat((0.5 + 0.05 * np.where((yy + xx) % 2 == 0, 1.0, -1.0)).astype(np.float32)[..., None], 3, axis=2)
    m = np.zeros((64, 64), bool)
    m[8:56, 8:56] = True
    assert bench.sharpness_ratio(check, ref, m) > 0.5
    assert bench.sharpness_ratio(check, ref, m, scale=0.5) == pytest.approx(0.0, abs=1e-9)
    assert bench.sharpness_ratio(ref, ref, m, scale=0.5) == pytest.approx(1.0)


def test_face_masks_at_canonical_landmarks():
    cheeks, skin, eyes = bench.cheek_mask(P68, (H, W)), bench.face_skin_mask(P68, (H, W)), bench.eye_mask(P68, (H, W))
    iod = np.linalg.norm(P68[36] - P68[45])
    r = measures.CHEEK_RADIUS * iod
    assert cheeks.sum() == pytest.approx(2 * np.pi * r * r, rel=0.15)  # two discs
    assert (cheeks[:, : W // 2].sum() > 0) and (cheeks[:, W // 2:].sum() > 0)
    assert (cheeks & skin).sum() >= 0.95 * cheeks.sum()  # on the skin, below the eyes
    assert (cheeks & eyes).sum() < 0.02 * cheeks.sum() and not (skin & eyes).any()  # at most touching the eyes
    lips = np.zeros((H, W), np.uint8)
    cv2.fillPoly(lips, [np.round(P68[48:60]).astype(np.int32)], 1)
    assert not (skin & (lips > 0)).any()
    assert skin.sum() > 10 * cheeks.sum()
    ys = np.flatnonzero(skin.any(axis=1))
    assert ys.min() >= P68[17:27, 1].min() - 1 and ys.max() <= P68[8, 1]  # between the brows and the chin


def test_run_score_and_the_worst_runs():
    good = {"mouth_slope": 1.0, "mouth_r": 0.9, "cheek_de": 5.0, "eye_ratio": 0.9, "sharp": 0.8, "id_closer": 1.0}
    assert bench.run_score(good) == 0 and bench.failed_targets(good) == []
    slow_mouth = {**good, "mouth_slope": 0.4}  # (0.8 − 0.4) / 0.8 = 0.5 short: 1 + 0.5
    assert bench.run_score(slow_mouth) == pytest.approx(1.5)
    wide_mouth = {**good, "mouth_slope": 1.95}  # (1.95 − 1.3) / 1.3 = 0.5 over
    assert bench.run_score(wide_mouth) == pytest.approx(1.5)
    bruised = {**good, "cheek_de": 16.0, "eye_ratio": 0.4}  # (1 + 1) + (1 + 0.5)
    assert bench.run_score(bruised) == pytest.approx(3.5)
    assert bench.failed_targets(bruised) == ["cheek_de", "eye_ratio"]
    missing = {**good, "sharp": float("nan"), "id_closer": None}  # not measured: failed, shortfall 1
    assert bench.run_score(missing) == pytest.approx(4.0)
    rows = [good, slow_mouth, bruised, wide_mouth, missing]
    assert bench.worst_runs(rows) == [4, 2, 1]  # ties (1 and 3) in row order
    # fewer than 3 failing: the passing runs closest to a target follow (smallest margin first)
    near = {**good, "mouth_slope": 1.28}  # (1.3 − 1.28) / 1.3 = 1.5 % from the upper bound
    assert measures.headroom(near) == (pytest.approx(0.02 / 1.3), "mouth_slope")
    assert measures.headroom(good) == (pytest.approx(0.05 / 0.85), "mouth_r")  # 0.9 vs 0.85: 5.9 %, sharp 6.7 %
    assert measures.headroom(slow_mouth) == (float("-inf"), None)
    assert bench.worst_runs([good, slow_mouth, near, good]) == [1, 2, 0]
    assert measures._worst_value("mouth_slope", [1.0, 0.7, 1.5, None]) == 1.5  # (1.5-1.3)/1.3 > (0.8-0.7)/0.8
    assert measures._worst_value("cheek_de", [3.0, float("nan"), 9.0]) == 9.0
    assert measures._worst_value("sharp", [0.9, 0.6]) == 0.6


def test_sheet_frames_most_closed_widest_and_middle():
    o = np.array([0.1, 0.05, np.nan, 0.3, 0.5, 0.26, 0.2])
    assert bench.sheet_frames(o) == [1, 4, 5]  # middle: nearest (0.05 + 0.5) / 2 = 0.275
    assert bench.sheet_frames(np.full(5, np.nan)) == [0, 4, 2]


@pytest.fixture()
def fake_runs(tmp_path, monkeypatch):
    """Two fake persona files and two fake clips; the puppetry and the identity reference stubbed."""
    personas = []
    for name in ("Anna", "Bert"):
        f = tmp_path / f"{name}.persona"
        f.write_bytes(b"x")
        personas.append(f)
    clips = tmp_path / "clips"
    clips.mkdir()
    for c in ("c1", "c2"):
        (clips / f"{c}.mp4").write_bytes(b"x")
    calls = []
    values = {("Anna", "c1"): 1.0, ("Anna", "c2"): 0.5, ("Bert", "c1"): 0.9, ("Bert", "c2"): 0.2}

    def evaluate(clip, persona, ref, out, *, name, **kw):
        calls.append((name, clip.stem, kw["size"]))
        out.mkdir(parents=True, exist_ok=True)
        sheet = out / f"{clip.stem}_sheet3_100.png"
        write_image(sheet, np.full((30, 45, 3), values.get((name, clip.stem), 0.95), np.float32))
        row = {"run": f"{name}/{clip.stem}", "persona": name, "clip": clip.stem, "frames": 5, "lost": 0,
               "mouth_slope": values.get((name, clip.stem), 0.95), "mouth_r": 0.9, "cheek_de": 4.0, "eye_ratio": 0.9,
               "sharp": 0.8, "id_closer": 1.0, "media": {"sheet3_100": str(sheet)}, "sheet_frames": [0, 4, 2]}
        row["score"], row["failed"] = bench.run_score(row), bench.failed_targets(row)
        return row

    monkeypatch.setattr(bench, "_persona_file", lambda p, out, progress: str(p))
    monkeypatch.setattr(bench, "_collection_descriptor", lambda f: calls.append(("reference", Path(f).stem))
                        or np.zeros(128))
    monkeypatch.setattr(bench, "_evaluate_clip", evaluate)
    monkeypatch.setattr("facetex.persona.load_persona", lambda f: Path(f).stem)
    return personas, clips, calls


def test_cli_runs_every_puppet_on_every_clip(fake_runs, tmp_path, capsys):
    personas, clips, calls = fake_runs
    parser = argparse.ArgumentParser()
    bench.register_bench(parser.add_subparsers())
    out = tmp_path / "o"
    args = parser.parse_args(["puppet", "--drivers", str(clips), "--puppets", *map(str, personas), "--out", str(out),
                              "--no-partial", "--size", "64", "--json", "--jobs", "1"])
    assert args.func(args) == 0
    assert calls == [("reference", "Anna"), ("reference", "Bert"), ("Anna", "c1", 64), ("Anna", "c2", 64),
                     ("Bert", "c1", 64), ("Bert", "c2", 64)]
    printed = json.loads(capsys.readouterr().out)
    worst = printed["summary"]["worst_runs"]
    assert [w["run"] for w in worst[:2]] == ["Bert/c2", "Anna/c2"]  # slope 0.2, 0.5
    assert len(worst) == 3 and worst[2]["score"] == 0  # then the passing run closest to a target
    res = json.loads((out / "results.json").read_text())
    assert [r["run"] for r in res["rows"]] == ["Anna/c1", "Anna/c2", "Bert/c1", "Bert/c2"]
    assert res["worst"]["mouth_slope"] == 0.2 and res["worst"]["runs"]["mouth_slope"] == "Bert/c2"
    assert res["targets_met"]["mouth_slope"] is False and res["targets_met"]["cheek_de"] is True
    md = (out / "table.md").read_text()
    assert "## Worst run per measure" in md and "| mouth slope | 0.8–1.3 | 0.20 | Bert/c2 | 2/4 |" in md
    assert "| worst |" in md and "| mean |" in md
    worst1 = read_image(out / "worst1_Bert__c2.png")
    assert worst1.shape[1] == 45 and worst1.shape[0] > 30 and (out / "worst2_Anna__c2.png").is_file()
    assert (out / "worst3_Anna__c1.png").is_file()  # then the passing run closest to a target
    assert len(list((out / "runs").glob("*.json"))) == 4
    # --puppet is the same option; --resume reuses the stored runs (and the identity references)
    calls.clear()
    args = parser.parse_args(["puppet", "--drivers", str(clips), "--puppet", str(personas[1]), "--out", str(out),
                              "--no-partial", "--size", "64", "--resume", "-q", "--jobs", "1"])
    assert args.func(args) == 0
    assert calls == []
    assert [r["run"] for r in json.loads((out / "results.json").read_text())["rows"]] == ["Bert/c1", "Bert/c2"]
    # the earlier table's worst sheets are gone: only this table's runs
    assert sorted(p.name for p in out.glob("worst*.png")) == ["worst1_Bert__c2.png", "worst2_Bert__c1.png"]


def test_default_puppets_are_every_collection(tmp_path):
    (tmp_path / "grid").mkdir()
    for p in ("B", "A"):
        (tmp_path / "lfw" / p).mkdir(parents=True)
    drivers, puppets = bench._data_paths(tmp_path, None, None)
    assert drivers == tmp_path / "grid" and puppets == [tmp_path / "lfw" / "A", tmp_path / "lfw" / "B"]
    assert bench._data_paths(tmp_path, None, "x.persona")[1] == [Path("x.persona")]
    with pytest.raises(BadInputError, match="--puppets"):
        bench._data_paths(None, None, None)
    assert bench._persona_names(["a/P.persona", "b/P.persona", "c/Q.persona"]) == ["P-0", "P-1", "Q"]


def test_cli_stress_adds_the_harder_copies_as_runs(fake_runs, tmp_path, monkeypatch):
    personas, clips, calls = fake_runs

    def copies(files, out, *, max_frames=None):
        assert [f.stem for f in files] == ["c1", "c2"] and max_frames is None
        (out / "stress").mkdir(exist_ok=True)
        made = [out / "stress" / "c1_dim.mp4"]
        made[0].write_bytes(b"x")
        return made

    monkeypatch.setattr(bench, "stress_clips", copies)
    monkeypatch.setattr("facetex.io.video_info", lambda c: {"n_frames": 5})
    parser = argparse.ArgumentParser()
    bench.register_bench(parser.add_subparsers())
    args = parser.parse_args(["puppet", "--drivers", str(clips), "--puppets", str(personas[0]), "--out",
                              str(tmp_path / "o"), "--no-partial", "--size", "64", "--stress", "-q", "--jobs", "1"])
    assert args.func(args) == 0
    assert [c for c in calls if c[0] == "Anna"] == [("Anna", "c1", 64), ("Anna", "c2", 64), ("Anna", "c1_dim", 64)]
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert [r["run"] for r in res["rows"]] == ["Anna/c1", "Anna/c2", "Anna/c1_dim"]
    assert res["rows"][2]["mouth_slope"] == 0.95  # evaluated like the others
