"""Persona puppetry end to end on a tiny synthetic driver video and a tiny persona."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.errors import BadInputError, NoFaceError
from facetex.io import read_image, video_info, write_video

N_MORPH = 8  # neutral -> smiling frames
N_BLANK = 2  # frames without a face
N_HOLD = 2  # smiling frames after the gap
SIDE = 288


def _landmarks(img):
    from facetex.landmarks import detect_face

    return detect_face(img).points68


def morph_frames(n_morph: int = N_MORPH, n_blank: int = N_BLANK, n_hold: int = N_HOLD, side: int = SIDE):
    """Frames morphing frl_004 neutral -> smiling (piecewise-affine warp + cross-fade),
    then ``n_blank`` grey frames (face lost), then ``n_hold`` smiling frames."""
    from facetex.geometry.morph import piecewise_affine_map, remap

    a = cv2.resize(read_image(sample_path("frl_004_neutral.jpg")), (side, side), interpolation=cv2.INTER_AREA)
    b = cv2.resize(read_image(sample_path("frl_004_smiling.jpg")), (side, side), interpolation=cv2.INTER_AREA)
    pa, pb = _landmarks(a), _landmarks(b)
    ident = np.stack(np.meshgrid(np.arange(side), np.arange(side)), axis=-1).astype(np.float32)
    # displacement fields of the full morphs, scaled by t for the in-between frames
    da = piecewise_affine_map(pa, pb, a.shape[:2]) - ident
    db = piecewise_affine_map(pb, pa, b.shape[:2]) - ident
    frames = []
    for t in np.linspace(0, 1, n_morph):
        wa = remap(a, ident + t * da)
        wb = remap(b, ident + (1 - t) * db)
        frames.append(np.clip((1 - t) * wa + t * wb, 0, 1).astype(np.float32))
    frames += [np.full_like(a, 0.45)] * n_blank + [b] * n_hold
    return frames


@pytest.fixture(scope="module")
def driver_video(tmp_path_factory):
    path = tmp_path_factory.mktemp("driver") / "driver.mp4"
    write_video(path, morph_frames(), fps=10)
    return path


@pytest.fixture(scope="module")
def tiny_persona(tmp_path_factory):
    """8 jittered, differently lit copies of frl_004 neutral/smiling (min_photos lowered to 6)."""
    from facetex.io import write_image
    from facetex.persona import PersonaParams, build_persona

    folder = tmp_path_factory.mktemp("photos")
    rng = np.random.default_rng(0)
    for name in ("frl_004_neutral.jpg", "frl_004_smiling.jpg"):
        img = read_image(sample_path(name))
        h, w = img.shape[:2]
        for k in range(4):
            m = cv2.getRotationMatrix2D((w / 2, h / 2), rng.uniform(-6, 6), rng.uniform(0.92, 1.05))
            m[:, 2] += rng.uniform(-10, 10, 2)
            j = cv2.warpAffine(img, m, (w, h), borderMode=cv2.BORDER_REPLICATE)
            ramp = np.linspace(-1, 1, w, dtype=np.float32)[None, :, None] * rng.uniform(-0.25, 0.25)
            vramp = np.linspace(-1, 1, h, dtype=np.float32)[:, None, None] * rng.uniform(-0.2, 0.2)
            j = np.clip(j * rng.uniform(0.8, 1.1) * (1 + ramp + vramp), 0, 1)
            write_image(folder / f"{name[:-4]}_{k}.png", j)
    # a half-size canonical frame keeps the test fast; the puppet works in the persona's frame
    return build_persona(folder, jobs=1, params=PersonaParams(min_photos=6, size=(96, 120)))


@pytest.fixture(scope="module")
def puppet_run(driver_video, tiny_persona, tmp_path_factory):
    from facetex.puppet.puppetry import puppeteer

    out = tmp_path_factory.mktemp("out") / "puppet.mp4"
    records = []
    report = puppeteer(driver_video, tiny_persona, out, size=160, side_by_side=True,
                       on_frame=lambda r: records.append({k: r[k] for k in ("index", "driver", "puppet", "alpha",
                                                                            "lost")}))
    return out, report, records


def test_output_video_frames_and_size(puppet_run):
    out, report, records = puppet_run
    info = video_info(out)
    n = N_MORPH + N_BLANK + N_HOLD
    assert info["n_frames"] == n == report["frames"] == len(records)
    assert (info["width"], info["height"]) == (2 * 160, 160)  # side by side, square driver


def test_lost_frames_counted_and_show_the_driver(puppet_run):
    _, report, records = puppet_run
    assert report["lost_frames"] == N_BLANK
    assert report["lost_indices"] == list(range(N_MORPH, N_MORPH + N_BLANK))
    assert report["lost_causes"] == {"no face": N_BLANK}
    for r in records:
        if r["lost"]:  # the driver's own frame, no puppet
            assert r["alpha"].max() == 0.0
            np.testing.assert_array_equal(r["puppet"], r["driver"])
        else:
            assert r["alpha"].max() > 0.9, r["index"]


def test_puppet_face_is_rendered_over_the_driver(puppet_run):
    _, _, records = puppet_run
    alpha = records[0]["alpha"]
    ys, xs = np.nonzero(alpha > 0.5)
    # the face covers a plausible part of the 160 px panel around its centre
    assert 0.05 < (alpha > 0.5).mean() < 0.6
    assert 40 < xs.mean() < 120 and 40 < ys.mean() < 130


@pytest.fixture(scope="module")
def session(driver_video, tiny_persona):
    from facetex.puppet.puppetry import prepare_puppetry

    return prepare_puppetry(driver_video, tiny_persona)


def test_composite_never_leaves_the_drivers_face_outline(session):
    """No halo: the puppet is drawn only inside the driver's own face outline."""
    from facetex.geometry.masks import polygon_mask
    from facetex.puppet.composite import FACE_OVAL
    from facetex.puppet.puppetry import render_frames

    scale = 160 / session.track.frame_size[0]
    for r in render_frames(session, size=160, max_frames=N_MORPH):
        i = r["index"]
        if r["lost"]:
            continue
        oval = (session.track.mesh[i][list(FACE_OVAL), :2] + 0.5) * scale - 0.5
        outline = polygon_mask(oval, r["alpha"].shape) > 0
        assert r["alpha"][~outline].max() == 0.0, i
        np.testing.assert_array_equal(r["puppet"][~outline], r["driver"][~outline])


def test_open_mouth_shows_the_drivers_mouth_interior(session):
    from dataclasses import replace

    from facetex.geometry.masks import polygon_mask
    from facetex.puppet.composite import INNER_LIPS
    from facetex.puppet.puppetry import render_frames

    recs = {r["index"]: r for r in render_frames(session, size=160, keep=True)}
    pup = session.puppeteer
    scale = 160 / session.track.frame_size[0]
    i = N_MORPH - 1  # smiling, lips apart
    r = recs[i]
    lips = pup.points(i, r["grid"], scale)[list(INNER_LIPS)]
    inside = polygon_mask(lips, r["alpha"].shape) > 0.5
    assert inside.sum() > 5  # the puppet's lips are open
    saved = pup.params
    try:
        pup.params = replace(saved, composite=replace(saved.composite, mouth=False))
        without = pup.render(i, r["grid"], r["texture"], r["driver"], scale)[0]
    finally:
        pup.params = saved
    diff = np.abs(r["puppet"] - without).max(axis=2)
    # the interior replaced the stretched lip texture: 0.0265 alone and after every earlier test
    # folder (bisected on 9d40b33); the 0.0199 once seen was on the unmerged live branch
    assert diff[inside].mean() > 0.02, diff[inside].mean()
    ring = (polygon_mask(lips * 1.0, r["alpha"].shape, samples=1) == 0)
    assert diff[ring].mean() < 0.1 * diff[inside].mean()  # and nothing else


def test_face_mode_draws_the_puppet_alone(session):
    from facetex.puppet.puppetry import render_frames

    plain = np.asarray(session.puppeteer.params.plain, np.float32)
    for r in render_frames(session, size=160, mode="face", max_frames=3):
        bg = r["alpha"] == 0
        assert 0.05 < (~bg).mean() < 0.6
        np.testing.assert_allclose(r["puppet"][bg], np.broadcast_to(plain, r["puppet"][bg].shape))
        edge = (r["alpha"] > 0) & (r["alpha"] < 1)
        assert edge.sum() > 20  # anti-aliased silhouette


def test_no_face_video_raises_and_writes_nothing(tmp_path, tiny_persona):
    from facetex.puppet.puppetry import puppeteer

    blank = tmp_path / "blank.mp4"
    write_video(blank, [np.full((96, 96, 3), 0.3, np.float32)] * 3, fps=10)
    out = tmp_path / "out.mp4"
    with pytest.raises(NoFaceError) as e:
        puppeteer(blank, tiny_persona, out)
    assert e.value.path == str(blank)
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == ["blank.mp4"]


def test_neutral_texture_weights_follow_expression(tiny_persona):
    import dataclasses

    from facetex.persona import TextureParams, blend_textures
    from facetex.puppet import PuppetParams, neutral_texture

    p = tiny_persona
    smiling = np.array(["smiling" in f for f in p.photos])
    neu, smi = p.fiducials[~smiling].mean(axis=0), p.fiducials[smiling].mean(axis=0)
    paper = PuppetParams(weights="global", sigma=4.0).texture_params()
    assert paper.weights == "global" and paper.sigma == 4.0 and paper.alpha_ == 1.0
    # the persona texture's regional weights, with the mouth's detail restored too (the persona
    # texture leaves it out: closer to held-out photos in SSIM; the puppet's lips need it)
    from facetex.persona.params import RENDER_RESTORE

    assert PuppetParams().texture_params() == dataclasses.replace(TextureParams(), restore=RENDER_RESTORE)
    assert "mouth" not in dict(TextureParams().restore) and "mouth" in dict(RENDER_RESTORE)
    for tp in (TextureParams(), paper):
        t_neu = neutral_texture(p, neu, params=tp)
        t_smi = neutral_texture(p, smi, params=tp)
        static = neutral_texture(p, p.fiducials[0], method="static", params=tp)
        assert t_neu.shape == t_smi.shape == static.shape == (120, 96, 3)
        # different target expressions blend different photos (the static texture does not change)
        assert np.abs(t_neu - t_smi).mean() > 1e-3, tp.weights
        np.testing.assert_array_equal(static, neutral_texture(p, p.fiducials[-1], method="static", params=tp))
    # the regional texture is the persona texture's blend in the neutral frame
    np.testing.assert_allclose(neutral_texture(p, smi), blend_textures(p, smi)[0], atol=1e-6)
    np.testing.assert_allclose(neutral_texture(p, smi, params=TextureParams.paper(), sigma=4.0),
                               neutral_texture(p, smi, params=paper), atol=1e-6)
    with pytest.raises(ValueError, match="unknown puppet texture weights"):
        PuppetParams(weights="local").texture_params()
    with pytest.raises(ValueError, match="weight smoothing must be >= 0"):
        PuppetParams(weight_smoothing=-0.1).texture_params()


def test_cli_puppet(tmp_path, driver_video, tiny_persona, capsys):
    from facetex.cli import main

    persona_file = tiny_persona.save(tmp_path / "tiny.persona")
    out = tmp_path / "cli.mp4"
    code = main(["puppet", "--driver", str(driver_video), "--puppet", str(persona_file), "-o", str(out),
                 "--max-frames", "3", "--size", "96", "--mode", "face", "--json"])
    assert code == 0 and out.is_file()
    assert video_info(out)["n_frames"] == 3
    assert '"lost_frames": 0' in capsys.readouterr().out
    sh = tmp_path / "sh.mp4"  # composite with the spherical-harmonics lighting, the paper's global weights
    assert main(["puppet", "--driver", str(driver_video), "--puppet", str(persona_file), "-o", str(sh),
                 "--max-frames", "2", "--size", "96", "--lighting", "sh", "--weights", "global", "--grain", "0.5",
                 "--nose-sharpen", "1", "--occlusion", "off", "--persona-hair", "off"]) == 0
    assert video_info(sh)["n_frames"] == 2
    side = json.loads((tmp_path / "sh.mp4.json").read_text())
    assert side["params"]["weights"] == "global" and side["params"]["puppet_params"]["weights"] == "global"
    assert side["params"]["grain"] == 0.5 and side["params"]["puppet_params"]["composite"]["grain"] == 0.5
    assert side["params"]["puppet_params"]["composite"]["nose_sharpen"] == 1.0
    assert side["params"]["occlusion"] == "off" and side["params"]["puppet_params"]["composite"]["occlusion"] is False
    assert side["params"]["persona_hair"] == "off"
    assert side["params"]["puppet_params"]["composite"]["persona_hair"] is False
    assert side["result"]["driver_glasses"] is False  # a bare face
    # existing output without --overwrite, and a video without faces: one-line errors, non-zero exit
    assert main(["puppet", "--driver", str(driver_video), "--puppet", str(persona_file), "-o", str(out)]) != 0
    blank = tmp_path / "blank.mp4"
    write_video(blank, [np.full((64, 64, 3), 0.5, np.float32)] * 2, fps=5)
    assert main(["puppet", "--driver", str(blank), "--puppet", str(persona_file), "-o", str(tmp_path / "x.mp4")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert "blank.mp4" in err[-1] and "no face" in err[-1]
    assert not (tmp_path / "x.mp4").exists()


def test_batched_textures_match_per_frame(tiny_persona):
    from facetex.puppet import neutral_texture, neutral_textures

    p = tiny_persona
    targets = [p.fiducials[0], p.fiducials[5], p.mean_fiducials]
    from facetex.persona import TextureParams

    for tp in (TextureParams(), TextureParams.paper(sigma=4.0)):
        batch = neutral_textures(p, targets, params=tp)
        for t, b in zip(targets, batch):
            np.testing.assert_allclose(b, neutral_texture(p, t, params=tp), atol=1e-5)
        assert np.abs(batch[0] - batch[1]).mean() > 1e-3  # different expressions, different blends


def test_render_frames_do_not_depend_on_the_batch_size(driver_video, tiny_persona, monkeypatch):
    import facetex.puppet.puppetry as pp

    session = pp.prepare_puppetry(driver_video, tiny_persona)
    ref = [r["puppet"] for r in pp.render_frames(session, size=96)]
    monkeypatch.setattr(pp, "TEXTURE_BATCH", 5)  # 12 frames: batches 5 + 5 + 2
    small = [r["puppet"] for r in pp.render_frames(session, size=96)]
    assert len(ref) == len(small) == session.track.n_frames
    for a, b in zip(ref, small):
        np.testing.assert_allclose(a, b, atol=1e-4)


def test_render_frames_in_a_forked_child_are_the_same_frames(session, monkeypatch):
    """With ``fork`` the odd frames are rendered in a child process: the same records, in order
    (textures blended in other batches: within float rounding); a child's error reaches the caller."""
    import facetex.puppet.puppetry as pp

    ref = list(pp.render_frames(session, size=96, keep=True, fork=False))
    forked = list(pp.render_frames(session, size=96, keep=True, fork=True))
    assert [r["index"] for r in forked] == list(range(session.track.n_frames))
    assert any(r["lost"] for r in forked) and any(not r["lost"] for r in forked[1::2])
    for a, b in zip(ref, forked):
        assert a["lost"] == b["lost"]
        for key in ("puppet", "alpha", "texture", "driver"):
            np.testing.assert_allclose(a[key], b[key], atol=1e-5)
        np.testing.assert_array_equal(a["grid"], b["grid"])
    kw = dict(size=96, mode="face", side_by_side=True, uint8_frame=True, max_frames=9)
    ref = list(pp.render_frames(session, fork=False, **kw))
    forked = list(pp.render_frames(session, fork=True, **kw))
    assert len(ref) == len(forked) == 9
    for a, b in zip(ref, forked):
        assert a["frame"].dtype == np.uint8 and a["frame"].shape == b["frame"].shape
        assert np.abs(a["frame"].astype(int) - b["frame"]).max() <= 1
    pup = session.puppeteer
    render = pup.render

    def failing(i, *args, **kwargs):
        if i % 2:
            raise BadInputError("broken frame", path="clip.mp4")
        return render(i, *args, **kwargs)

    monkeypatch.setattr(pup, "render", failing)  # the child is forked with it
    with pytest.raises(BadInputError, match="broken frame"):
        list(pp.render_frames(session, size=96, fork=True))


def test_render_frames_equal_frames_rendered_alone_in_order(session):
    """Frames are rendered on a thread pool: each equals its own render, in the video's order."""
    import facetex.puppet.puppetry as pp

    recs = list(pp.render_frames(session, size=96, keep=True))
    assert [r["index"] for r in recs] == list(range(session.track.n_frames))
    pup = session.puppeteer
    for r in recs:
        if r["lost"]:
            np.testing.assert_array_equal(r["puppet"], r["driver"])
            continue
        assert np.array_equal(r["grid"], pup.grid(r["index"]), equal_nan=True)
        img, alpha = pup.render(r["index"], r["grid"], r["texture"], r["driver"], 96 / max(session.track.frame_size))
        np.testing.assert_array_equal(r["puppet"], img)
        np.testing.assert_array_equal(r["alpha"], alpha)


def test_texture_precomputation_does_not_depend_on_threads(tiny_persona, monkeypatch):
    import dataclasses

    import facetex.persona.stacks as stacks
    import facetex.persona.texture as tx

    results = []
    for threads in (1, 2):
        p = dataclasses.replace(tiny_persona, _cache={})
        monkeypatch.setattr(stacks, "available_cpus", lambda t=threads: t)
        monkeypatch.setattr(stacks._Prepared, "CHUNK", 3)  # 8 photos: chunks 3 + 3 + 2
        prep = tx.prepare_persona(p)
        results.append((prep.aligned, prep.pyr[0], prep.pyr[-1], prep.stage_b()))
    for a, b in zip(*results):
        np.testing.assert_array_equal(a, b)


def test_puppet_lips_open_and_close_with_the_drivers(driver_video, tiny_persona):
    """The puppet's inner-lip gap (its mesh, canonical px) follows the driver's landmark gap scaled
    by the ratio of eye distances, around the same mean (rest motion): slope ~1, not ~0.4.
    (The half-size test persona's lips are ~2 px apart: a 1 px grid resolves them as the default
    2 px grid resolves a full-size persona's.)"""
    from facetex.puppet.driver import DriverParams
    from facetex.puppet.puppetry import PuppetParams, prepare_puppetry

    session = prepare_puppetry(driver_video, tiny_persona, params=PuppetParams(driver=DriverParams(grid_step=1)))
    pup, m = session.puppeteer, session.motion
    k = pup.lip_scale
    pairs = ((61, 67), (62, 66), (63, 65))

    def gap(points):
        return np.mean([np.linalg.norm(points[b] - points[a]) for a, b in pairs])

    frames = np.flatnonzero(m.found)
    drv = np.array([k * gap(m.fiducials68[i]) for i in frames])
    pp = np.array([gap(pup._sample_grid(pup.grid(i), pup.mean68)[:, :2]) for i in frames])
    assert drv.std() > 0.5  # the driver does open its mouth
    assert np.polyfit(drv, pp, 1)[0] == pytest.approx(1.0, abs=0.1)
    assert pp.mean() == pytest.approx(drv.mean(), abs=0.15 * drv.std() + 0.3)


def test_landmark_correspondence_is_exact_at_the_landmarks_and_does_not_fold(tiny_persona):
    from facetex.puppet import landmark_correspondence

    P = tiny_persona.points68.mean(axis=0)
    c0 = P.mean(axis=0)
    D = c0 + (P - c0) * [1.04, 0.96]  # another person's mean landmarks: a wider, shorter face
    D[48:68, 1] += 1.5  # with a lower mouth
    W, H = tiny_persona.size
    c = landmark_correspondence(D, P, (H, W), smoothing=0.0)
    at = np.stack([cv2.remap(c[..., k], D[:, :1].T.astype(np.float32), D[:, 1:].T.astype(np.float32),
                             cv2.INTER_LINEAR)[0] for k in range(2)], -1)
    assert np.abs(at - P).max() < 0.3
    jy, jx = np.gradient(c, axis=(0, 1))
    det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
    face = np.zeros((H, W), np.uint8)
    cv2.fillConvexPoly(face, cv2.convexHull(P.astype(np.int32)), 1)
    assert det[face > 0].min() > 0.2
    with pytest.raises(Exception, match="68, 2"):
        landmark_correspondence(D[:49], P, (H, W))


def test_stage_b_is_the_tps_alone_computed_on_first_use(tiny_persona):
    import dataclasses

    import facetex.persona.texture as tx
    from facetex.persona.align import remap_stack, tps_maps

    p = dataclasses.replace(tiny_persona, _cache={})
    prep = tx.prepare_persona(p)
    assert "b" not in prep._stage  # not computed by the precomputation
    W, H = p.size
    maps = tps_maps(p.fiducials, p.mean_fiducials, (H, W), p.params.tps_smoothing)
    want = np.clip(remap_stack(p.images, maps).mean(axis=0), 0, 1)
    np.testing.assert_allclose(tx.average_face(p, "b"), want, atol=1e-6)


def test_sequence_weights_blend_like_per_frame_textures_and_keep_totals(tiny_persona):
    from facetex.persona import TextureParams
    from facetex.persona.texture import blend_textures, blend_weights, sequence_weights, target_weights

    p, tp = tiny_persona, TextureParams()
    f = np.stack([p.fiducials[i] for i in (0, 0, 1, 5, 5, 6)])
    raw = sequence_weights(p, f, tp)
    smooth = sequence_weights(p, f, tp, sigma_frames=1.0)
    assert raw.shape == smooth.shape == target_weights(p, f, tp).shape
    np.testing.assert_allclose(smooth.sum(axis=-1), raw.sum(axis=-1), rtol=1e-9)
    # unsmoothed: the same textures as blend_textures (up to the second 0.5 % mass cut)
    np.testing.assert_allclose(blend_weights(p, raw, params=tp), blend_textures(p, f, params=tp), atol=2e-3)
    assert np.abs(smooth - raw).max() > 1e-3  # frames 1 -> 5 change expression: smoothing acts


def test_puppeteer_weight_smoothing_zero_is_per_frame(driver_video, tiny_persona):
    import dataclasses

    import facetex.puppet as pp
    from facetex.puppet.mouth import fill_mouth_interior, mouth_closure

    session = pp.prepare_puppetry(driver_video, tiny_persona, params=pp.PuppetParams(weight_smoothing=0.0))
    pup = session.puppeteer
    frames = [0, 3, 7]
    per_frame = pp.neutral_textures(tiny_persona, [pup.target(i) for i in frames],  # with the eyes' rest motion
                                    params=pup.params.texture_params())
    for a, b in zip(pup.textures(frames), per_frame):  # the driver's interior is drawn: all filled
        np.testing.assert_array_equal(a, fill_mouth_interior(b, pup.mean68[60:68], 1.0))
    pup.params = dataclasses.replace(pup.params, composite=dataclasses.replace(pup.params.composite, mouth=False))
    closure = [mouth_closure(pup.motion.fiducials68[i][60:68]) for i in frames]
    for a, b, c in zip(pup.textures(frames), per_frame, closure):  # the interior filled as the lips close
        np.testing.assert_array_equal(a, fill_mouth_interior(b, pup.mean68[60:68], c))
    pup.params = dataclasses.replace(pup.params, close_mouth=False)
    for a, b in zip(pup.textures(frames), per_frame):
        np.testing.assert_array_equal(a, b)
    pup.params = dataclasses.replace(pup.params, weight_smoothing=0.3)
    W = pup.sequence_weights()
    assert W.shape[0] == len(pup.motion)
    smoothed = pup.textures(frames)
    assert all(np.isfinite(t).all() and t.shape == per_frame[0].shape for t in smoothed)


def test_brow_rest_gives_the_puppets_mean_brows_the_drivers_tilt_and_height():
    """A frowning persona (inner brow ends pulled down) driven by a driver with level brows: the
    rest motion levels the puppet's brow lines and matches their height; the brow's own curve stays."""
    from types import SimpleNamespace

    from facetex.geometry._generic_face import load_generic_face
    from facetex.puppet.motion import brow_heights
    from facetex.puppet.puppetry import Puppeteer

    g = load_generic_face().points68[:, :2]
    g = g / np.linalg.norm(g[36] - g[45])
    drv, pup = g * 100.0 + 200.0, g * 80.0 + 150.0
    pup[17:22, 1] += np.linspace(-4.0, 6.0, 5)  # right brow: inner end (21) down
    pup[22:27, 1] += np.linspace(6.0, -4.0, 5)  # left brow: inner end (22) down
    pup[19, 1] -= 2.0  # a peaked brow
    motion = SimpleNamespace(fiducials68=np.stack([drv, drv]), found=np.array([True, True]))
    stub = SimpleNamespace(motion=motion, mean68=pup)
    moved = pup + Puppeteer._brow_rest_motion(stub)
    hd, hp = brow_heights(drv), brow_heights(moved)
    for side in (slice(0, 5), slice(5, 10)):
        x = np.arange(5.0)
        fit_d, fit_p = np.polyfit(x, hd[side], 1), np.polyfit(x, hp[side], 1)
        assert fit_p[0] == pytest.approx(fit_d[0], abs=0.01)  # tilt
        assert hp[side].mean() == pytest.approx(hd[side].mean(), abs=0.01)  # height
    # the peak is kept: the puppet's middle point stays above its neighbours' line
    assert hp[2] - (hp[1] + hp[3]) / 2 > 0.02
    assert np.all(moved[:17] == pup[:17]) and np.all(moved[27:] == pup[27:])


def _smiling(g, lift_px):
    """Landmarks ``g`` with the mouth corners (and the outer corners' neighbours) raised by ``lift_px``
    and the mouth widened by half of it on each side: a smile."""
    p = g.copy()
    for corner, side in ((48, -1), (54, 1), (60, -1), (64, 1)):
        p[corner] += [side * lift_px / 2, -lift_px]
    for near in (49, 53, 59, 55):
        p[near, 1] -= lift_px / 2
    return p


def test_mouth_lift_hand_computed():
    from facetex.puppet.motion import mouth_lift

    p = np.zeros((68, 2))
    p[36:42] = [0.0, 0.0]
    p[42:48] = [10.0, 0.0]  # eye centres 10 apart
    p[62], p[66] = [5.0, 20.0], [5.0, 22.0]  # inner-lip middle at y 21
    p[48], p[54] = [0.0, 20.0], [10.0, 19.0]  # corners at mean y 19.5: 1.5 above
    assert mouth_lift(p) == pytest.approx(0.15)
    p[48, 1] = p[54, 1] = 23.0  # corners down
    assert mouth_lift(np.stack([p, p])) == pytest.approx([-0.2, -0.2])


def test_lips_at_lift_follows_the_collections_smile_line_within_its_range():
    """A collection whose mouths are the same face at smiles 0..4 px: the lips at a lift are that
    photo's lips; beyond the photos' lifts the clamp holds them at the 10th / 90th percentile's."""
    from facetex.errors import BadInputError
    from facetex.geometry._generic_face import load_generic_face
    from facetex.puppet.motion import lips_at_lift, mouth_lift

    g = load_generic_face().points68[:, :2]
    g = (g - g.mean(axis=0)) / np.linalg.norm(g[36] - g[45]) * 60.0 + 100.0
    photos = np.stack([_smiling(g, s) for s in np.linspace(0.0, 4.0, 41)])
    lifts = mouth_lift(photos)
    mean = photos.mean(axis=0)
    target = 10  # the photo smiling 1 px
    move = lips_at_lift(photos, float(lifts[target]))
    np.testing.assert_allclose((mean + move)[48:68], photos[target, 48:68], atol=1e-6)
    assert np.all(move[:48] == 0)
    assert mouth_lift(mean + move) == pytest.approx(lifts[target], abs=1e-9)
    # a driver who frowns: the persona's least-smiling photos (its 10th percentile), not beyond
    low = lips_at_lift(photos, float(lifts.min()) - 1.0)
    assert mouth_lift(mean + low) == pytest.approx(np.percentile(lifts, 10), abs=1e-9)
    # lower_only: a lift above the photos' mean moves nothing, one below it moves as before
    assert np.all(lips_at_lift(photos, float(lifts[30]), lower_only=True) == 0)
    np.testing.assert_array_equal(lips_at_lift(photos, float(lifts[target]), lower_only=True), move)
    # all photos alike: nothing to learn, no motion
    assert np.all(lips_at_lift(np.stack([g] * 5), 0.3) == 0)
    with pytest.raises(BadInputError, match="68, 2"):
        lips_at_lift(g, 0.0)


def test_smile_rest_lowers_a_smiling_personas_corners_to_the_drivers_and_keeps_the_gap_rest(monkeypatch):
    """A persona whose photos mostly smile, a driver who does not: the puppet's rest mouth is the
    persona's at the driver's lift (within its photos' range; never raised to a broader smile); the
    mouth rest then sets the lip gap to the driver's as before; the texture's target fiducials carry
    the same corners."""
    from types import SimpleNamespace

    from facetex.geometry._generic_face import load_generic_face
    from facetex.landmarks import POINTS49_INDEX
    from facetex.puppet.motion import mouth_lift
    from facetex.puppet.puppetry import Puppeteer

    g = load_generic_face().points68[:, :2]
    g = (g - g.mean(axis=0)) / np.linalg.norm(g[36] - g[45]) * 60.0 + 100.0
    photos = np.stack([_smiling(g, s) for s in np.r_[np.linspace(0.0, 1.0, 5), np.full(15, 4.0)]])
    drv = _smiling(g, 0.5)
    drv[66, 1] += 3.0  # the driver's lips part 3 px at rest
    motion = SimpleNamespace(fiducials68=np.stack([drv, drv]), found=np.array([True, True]))
    pup = photos.mean(axis=0)
    stub = SimpleNamespace(motion=motion, mean68=pup, persona=SimpleNamespace(points68=photos), lip_scale=1.0,
                           params=SimpleNamespace(mouth_rest=False))
    stub.smile_move = Puppeteer._smile_rest_motion(stub)
    assert mouth_lift(pup) > mouth_lift(drv) + 0.02
    assert mouth_lift(pup + stub.smile_move) == pytest.approx(mouth_lift(drv), abs=1e-6)
    assert np.all(Puppeteer._rest_motion(stub) == stub.smile_move)  # smile rest alone
    # only downwards: a driver who smiles more than the persona's mean leaves its mouth as it is
    broad = SimpleNamespace(fiducials68=np.stack([_smiling(g, 5.0)] * 2), found=np.array([True, True]))
    assert np.all(Puppeteer._smile_rest_motion(SimpleNamespace(**(vars(stub) | {"motion": broad}))) == 0)
    stub.params = SimpleNamespace(mouth_rest=True)
    rest = pup + Puppeteer._rest_motion(stub)
    gap = lambda p: (p[[67, 66, 65], 1] - p[[61, 62, 63], 1]).mean()  # noqa: E731
    assert gap(rest) == pytest.approx(gap(drv), abs=1e-6)
    stub.smile_move = None  # without the smile rest: the gap rest as it was
    rest0 = pup + Puppeteer._rest_motion(stub)
    assert gap(rest0) == pytest.approx(gap(drv), abs=1e-6) and mouth_lift(rest0) == pytest.approx(mouth_lift(pup))
    # the texture's target: the driver's expression offset (none here) plus the rest motions
    stub.smile_move = Puppeteer._smile_rest_motion(stub)
    stub.eye_move = None
    monkeypatch.setattr("facetex.puppet.puppeteer.target_fiducials", lambda persona, m, i: pup[POINTS49_INDEX])
    t = Puppeteer.target(stub, 0)
    np.testing.assert_allclose(t, (pup + stub.smile_move)[POINTS49_INDEX])


def test_puppet_lids_follow_the_drivers_and_narrow_eyes_open(driver_video, tiny_persona):
    """The puppet's eyelid gaps (its mesh, canonical px) follow the driver's scaled by the ratio of
    eye distances (slope ~1), and are at least the driver's mean gap (eye rest); without lid sync
    and eye rest they do not follow."""
    from facetex.puppet.driver import DriverParams
    from facetex.puppet.motion import _LOWER_LIDS, _UPPER_LIDS
    from facetex.puppet.puppetry import PuppetParams, prepare_puppetry

    def gaps(params):
        session = prepare_puppetry(driver_video, tiny_persona, params=params)
        pup, m = session.puppeteer, session.motion
        frames = np.flatnonzero(m.found)
        k = pup.lid_scale if pup.lid_fields is not None else pup.lip_scale

        def gap(points):
            return np.mean([points[b, 1] - points[a, 1] for a, b in zip(_UPPER_LIDS, _LOWER_LIDS)])

        drv = np.array([k * gap(m.fiducials68[i]) for i in frames])
        pp = np.array([gap(pup._sample_grid(pup.grid(i), pup.mean68)[:, :2]) for i in frames])
        return drv, pp, gap(pup.mean68)

    grid1 = DriverParams(grid_step=1)
    drv, pp, rest = gaps(PuppetParams(driver=grid1))
    assert drv.std() > 0.2  # the driver's eyes narrow in its smile
    assert np.polyfit(drv, pp, 1)[0] == pytest.approx(1.0, abs=0.15)
    assert pp.mean() >= min(drv.mean(), rest) - 0.1
    _, off, _ = gaps(PuppetParams(driver=grid1, lid_sync=False, eye_rest=False))
    assert np.polyfit(drv, off, 1)[0] < 0.9 or off.std() < 0.8 * drv.std()


def test_eye_quality_ranks_a_photo_with_flat_eyes_last_and_detail_weights_are_optional(tiny_persona):
    import dataclasses

    from facetex.persona import texture as tx

    tp = tx.TextureParams()
    prep = tx.prepare_persona(tiny_persona, tp)
    q = prep.eye_quality()
    assert q.shape == (len(tiny_persona),) and np.all((q > 0) & (q <= 4.0))
    import copy

    from facetex.geometry.gaze import gaze_weights

    # each photo's gaze is measured with the stacks; one looking far sideways loses its eye weight
    assert np.isfinite(prep._gaze).all()
    prep3 = copy.copy(prep)
    prep3._stage, prep3._gaze = {}, prep._gaze.copy()
    prep3._gaze[1] = np.median(prep._gaze) + 0.9
    q3 = prep3.eye_quality()
    assert q3[1] == pytest.approx(q[1] / gaze_weights(prep._gaze, tp.gaze)[1] * gaze_weights(prep3._gaze, tp.gaze)[1])
    assert q3[1] < 0.01 * q[1] / gaze_weights(prep._gaze, tp.gaze)[1]

    prep2 = copy.copy(prep)
    prep2._stage = {}
    prep2.segments = [[copy.copy(seg) for seg in segs] for segs in prep.segments]
    for k in prep.QUALITY_LEVELS:  # photo 0's eye bands flattened to 10 %
        for seg in prep2.segments[k]:
            seg.stack = seg.stack.copy()
            r = seg.stack[0].reshape(-1, 4)
            r[:, :3] *= 0.1
    q2 = prep2.eye_quality()
    assert np.argmin(q2) == 0 and q2[0] < q[0]
    # detail off: the blend is the plain regional blend; on: it differs only where the eyes and face are
    f = tiny_persona.fiducials[:2]
    plain = tx.blend_textures(tiny_persona, f, params=dataclasses.replace(tp, detail=(), eye_quality=0))
    sharp = tx.blend_textures(tiny_persona, f, params=tp)
    assert np.abs(plain - sharp).max() > 1e-3
    off = tx.blend_textures(tiny_persona, f, params=dataclasses.replace(tp, detail=(("eyes", 1.0, 5),),
                                                                         eye_quality=0, glasses=0, restore=()))
    plain = tx.blend_textures(tiny_persona, f, params=dataclasses.replace(tp, detail=(), eye_quality=0, glasses=0, restore=()))
    np.testing.assert_allclose(off, plain, atol=1e-6)


def test_photos_with_glasses_lose_their_weight_round_the_eyes(tiny_persona):
    import copy

    from facetex.persona import texture as tx
    from facetex.persona.params import GLASSES_LEVELS

    tp = tx.TextureParams()
    prep = copy.copy(tx.prepare_persona(tiny_persona, tp))
    prep._stage, prep._glasses = {}, None  # the scores are recomputed from the changed photos
    persona = copy.copy(tiny_persona)
    images = np.array(tiny_persona.images, copy=True)
    p = tiny_persona.points68[0]
    iod = float(np.linalg.norm(p[36:42].mean(0) - p[42:48].mean(0)))
    y = int(round((p[39, 1] + p[42, 1]) / 2 - 0.1 * iod))
    dark = 30 if images.dtype == np.uint8 else 30 / 255
    cv2.line(images[0], (int(p[39, 0]) - 2, y), (int(p[42, 0]) + 2, y), (dark,) * 3, 2)  # photo 0's bridge
    persona.images = images
    prep._persona_ref = persona
    g = prep.glasses_free(GLASSES_LEVELS["eyes"])
    assert g.shape == (len(tiny_persona),) and np.all((g > 0) & (g <= 1))
    assert np.argmin(g) == 0 and g[0] < 0.5 and np.median(g) == 1.0
    # in the blend: the eyes' and the face's weights are scaled (each from its own level), the mouth's are not
    import dataclasses

    S = np.full((1, len(prep.regions), len(tiny_persona)), 1.0)
    seen = {}

    def spy(w, mass, cap):
        seen.setdefault(len(seen), np.array(w, copy=True))
        return w

    import facetex.persona.stacks as txm

    orig = txm._cut_small
    txm._cut_small = spy
    try:
        prep.tp = dataclasses.replace(tp, detail=(), restore=())
        prep.blend_many(S)
    finally:
        txm._cut_small = orig
    for j, name in enumerate(prep.regions):
        want = prep.glasses_free(GLASSES_LEVELS[name]) if name in GLASSES_LEVELS else np.ones_like(g)
        np.testing.assert_allclose(seen[j][0], want)


def test_detail_restoration_gives_the_blend_its_photos_band_energy(tiny_persona):
    """The blend of 8 photos has less fine-band energy in the face than its photos; restoration
    scales the band back to the photos' weighted mean energy (gain <= restore_gain), face and
    eyes only; a single photo's "blend" is (nearly) left alone (gain ~1)."""
    import copy
    import dataclasses

    from facetex.persona import texture as tx

    base = dataclasses.replace(tx.TextureParams(), detail=(), eye_quality=0, glasses=0, restore=())
    prep = copy.copy(tx.prepare_persona(tiny_persona, base))  # its tp is changed below
    S = tx.target_weights(tiny_persona, tiny_persona.fiducials[:1], base)
    S = np.full_like(S, 1.0)  # every photo alike: the widest average
    k, j = 0, list(prep.regions).index("face")
    m = prep.masks[k][j] > 0.99

    def band0(tp):
        prep.tp = tp
        t = prep.blend_many(S)[0]
        return t - cv2.pyrUp(cv2.pyrDown(t), dstsize=t.shape[1::-1])

    e_plain = (band0(base) ** 2).sum(-1)[m].mean()
    e_rest = (band0(dataclasses.replace(base, restore=(("face", 1),), restore_gain=100.0)) ** 2).sum(-1)[m].mean()
    want = prep.band_energy()[k, j].mean()  # uniform weights: the photos' mean energy
    assert e_plain < 0.95 * want  # the photos' detail partly cancels in their average
    # restored (measured on the collapsed, clipped texture: the soft masks and the collapse mix a little)
    assert e_rest > e_plain and e_rest == pytest.approx(want, rel=0.25)
    capped = (band0(dataclasses.replace(base, restore=(("face", 1),), restore_gain=1.1)) ** 2).sum(-1)[m].mean()
    assert capped <= 1.1**2 * e_plain * 1.05
    one = np.zeros_like(S)
    one[..., 3] = 1.0  # a single photo: nothing cancelled, gain 1
    prep.tp = base
    a = prep.blend_many(one)
    prep.tp = dataclasses.replace(base, restore=(("face", 3), ("eyes", 3)))
    d = np.abs(prep.blend_many(one) - a)
    assert d.max() < 0.03 and d.mean() < 1e-3  # nearly: its confidence-weighted energy vs the plain mean


def test_a_persona_loaded_beforehand_gives_the_same_frames(driver_video, tiny_persona, session):
    """What the CLI does: load_puppet on a thread, handed to prepare_puppetry(loading=...)."""
    import dataclasses
    from concurrent.futures import ThreadPoolExecutor

    import facetex.puppet.puppetry as pp

    fresh = dataclasses.replace(tiny_persona, _cache={})
    with ThreadPoolExecutor(1) as pool:
        early = pp.prepare_puppetry(driver_video, fresh, loading=pool.submit(pp.load_puppet, fresh, pp.PuppetParams()))
    assert ("landmark_field", "lips", 2) in fresh._cache  # made by load_puppet, before the driver's motion
    assert early.timings["persona_prepare_s"] >= 0
    for a, b in zip(pp.render_frames(early, size=96), pp.render_frames(session, size=96)):
        np.testing.assert_array_equal(a["puppet"], b["puppet"])


def test_glasses_scores_are_stored_with_the_stacks(tiny_persona, tmp_path):
    """The eyeglasses scores are made with the texture stacks and stored in the .persona: a loaded
    persona's blend reads them instead of unpacking every photo (~0.4 s of a 519-photo puppet's
    start); they equal the scores computed from the photos."""
    from facetex.geometry.glasses import glasses_bridge_score
    from facetex.persona import load_persona
    from facetex.persona import texture as tx
    from facetex.persona.params import GLASSES_LEVELS

    direct = np.array([glasses_bridge_score(im, p) for im, p in zip(tiny_persona.images, tiny_persona.points68)])
    path = tiny_persona.save(tmp_path / "g.persona")
    q = load_persona(path)
    stored = q.texture_stacks["arrays"]["texture_glasses_scores"]
    assert q.texture_stacks["meta"]["glasses"] is True and stored.shape == (len(q),)
    prep = tx.prepare_persona(q, tx.TextureParams())
    np.testing.assert_allclose(prep._glasses, direct, rtol=1e-6)
    q.images = None  # the blend's glasses weights must not need the photos
    prep._stage = {}
    g = prep.glasses_free(GLASSES_LEVELS["eyes"])
    assert g.shape == (len(q),) and np.all((g > 0) & (g <= 1))


def test_gaze_and_band_energy_are_stored_with_the_stacks(tiny_persona, tmp_path):
    """The photos' gaze scores and band energies are stored in the .persona (~0.45 s of CPU of a
    519-photo puppet's start): a loaded persona does not compute them again, and they equal what
    the rebuilt stacks give."""
    import dataclasses

    from facetex.persona import load_persona
    from facetex.persona import texture as tx

    path = tiny_persona.save(tmp_path / "g.persona")
    q = load_persona(path)
    meta, arrays = q.texture_stacks["meta"], q.texture_stacks["arrays"]
    assert meta["gaze"] is True and arrays["texture_gaze"].shape == (len(q),)
    prep = tx.prepare_persona(q, tx.TextureParams())
    assert prep._gaze_stored and "band_energy" in prep._stage
    fresh = tx.prepare_persona(dataclasses.replace(tiny_persona, _cache={}), tx.TextureParams())
    np.testing.assert_array_equal(prep._gaze, fresh._gaze)
    np.testing.assert_allclose(prep.band_energy(), fresh.band_energy(), rtol=1e-12)
    stored, prep._stage = prep.band_energy(), {}
    np.testing.assert_allclose(prep.band_energy(), stored, rtol=1e-12)  # and what its own stacks give


def test_face_mode_lifts_the_inner_lips_relative_to_the_lips_and_white_balances_the_interior(session, monkeypatch):
    """Face mode (the persona's own colour): the open mouth's inner lip band is lifted relative to
    each face's lips (CompositeParams.lip_band; none at 0) and the driver's interior takes the
    puppet's white balance."""
    import importlib
    from dataclasses import replace

    from facetex.puppet.composite import CompositeParams
    from facetex.puppet.puppetry import render_frames

    pt = importlib.import_module("facetex.puppet.puppeteer")
    calls = []

    def lift(image, frame, d68, p68, *, band, relative):
        calls.append(("lift", band, relative))
        return image

    def balance(interior, frame, d68, image, p68):
        calls.append(("balance", np.shape(interior) == np.shape(image)))
        return interior

    monkeypatch.setattr(pt, "lift_inner_lips", lift)
    monkeypatch.setattr(pt, "interior_white_balance", balance)
    list(render_frames(session, size=160, mode="face", max_frames=2))
    assert ("lift", CompositeParams().lip_band, True) in calls and ("balance", True) in calls
    calls.clear()
    pup, saved = session.puppeteer, session.puppeteer.params
    try:
        pup.params = replace(saved, composite=replace(saved.composite, lip_band=0.0))
        list(render_frames(session, size=160, mode="face", max_frames=2))
    finally:
        pup.params = saved
    assert calls and all(c[0] == "balance" for c in calls)


def test_open_eyes_show_the_drivers_eyeballs_only_inside_the_puppets_lids(session):
    """eyes="driver" (the default) changes the composite inside the puppet's eye contours and
    nowhere else (against the persona's own eyes), beyond float rounding."""
    from dataclasses import replace

    from facetex.geometry.masks import polygon_mask
    from facetex.puppet.puppetry import render_frames

    recs = {r["index"]: r for r in render_frames(session, size=160, keep=True, max_frames=N_MORPH)}
    pup = session.puppeteer
    scale = 160 / session.track.frame_size[0]
    i = N_MORPH // 2
    r = recs[i]
    pts = pup.points(i, r["grid"], scale)
    shape = r["alpha"].shape
    inside = (polygon_mask(pts[36:42], shape) > 0.5) | (polygon_mask(pts[42:48], shape) > 0.5)
    assert inside.sum() > 4  # the puppet's eyes are open
    saved = pup.params
    try:  # (without the driver's lash lines, whose amount follows the lids' statistics)
        pup.params = replace(saved, composite=replace(saved.composite, lid_detail=0.0))
        theirs = pup.render(i, r["grid"], r["texture"], r["driver"], scale)[0]
        pup.params = replace(saved, composite=replace(saved.composite, eyes="persona", lid_detail=0.0))
        own = pup.render(i, r["grid"], r["texture"], r["driver"], scale)[0]
    finally:
        pup.params = saved
    diff = np.abs(theirs - own).max(axis=2)
    assert diff[inside].mean() > 0.03, diff[inside].mean()  # 0.081 when written
    near = np.zeros(shape, bool)
    for eye in (pts[36:42], pts[42:48]):
        c = eye.mean(axis=0)
        near |= polygon_mask(c + 1.6 * (eye - c), shape, samples=1) > 0
    # (float32 rounding only: with the driver's eyeballs the persona's own keep their lightness from
    # a little inside the lids, which moves the sharpening's statistics by ~1e-7)
    assert diff[~near].max() < 1e-5


def test_lip_motion_lands_the_remainder_where_the_grid_is_sampled(session):
    """The lip field of :meth:`Puppeteer._lip_motion_for`'s motion moves the lip points by the
    remainder asked for, on a grid whose cells hold both inner lips (the half-size test persona,
    2 px grid): the plain field of the remainder parts them short."""
    pup = session.puppeteer
    lips = np.arange(48, 68)
    r = np.zeros((68, 2))
    r[[61, 62, 63], 1] = -1.0  # part the inner lips by 2 px
    r[[65, 66, 67], 1] = 1.0
    r[[56, 57, 58], 1] = 0.5

    def landed(motion):
        g = np.zeros(pup.puppet_mask.shape + (3,), np.float32)
        g[..., :2] = pup.lip_fields(motion) * pup.puppet_mask[..., None]
        return pup._sample_grid(g, pup.mean68[lips])[:, :2]

    plain = np.abs(landed(r) - r[lips]).max()
    solved = pup._lip_motion_for(r)
    assert plain > 0.2
    assert np.abs(landed(solved) - r[lips]).max() < 0.25 * plain
    np.testing.assert_array_equal(solved[:48], r[:48])  # only the lips' motion is solved for
