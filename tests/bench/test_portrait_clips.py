"""``facetex bench puppet --portraits``: still-pair driver clips of studio portraits, chosen by skin
lightness among the pairs whose smile opens the mouth (on the bundled FRL samples)."""

import argparse
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from facetex.bench import _portrait_clips as pc
from facetex.bench import puppet as bench
from facetex.errors import BadInputError
from facetex.io import iter_video_frames, read_image

SAMPLES = Path(__file__).resolve().parents[2] / "facetex" / "data" / "samples"


def test_choose_portraits_spaced_in_lightness_not_rank():
    light = {"a": 30.0, "b": 60.0, "c": 61.0, "d": 62.0, "e": 63.0, "f": 80.0, "x": float("nan")}
    # targets 30, 55, 80: nearest a, b (60), f; by rank the middle one would be c
    assert pc.choose_portraits(light, 3) == ["a", "b", "f"]
    assert pc.choose_portraits(light, 2) == ["a", "f"]
    assert pc.choose_portraits(light, 9) == ["a", "b", "c", "d", "e", "f"]  # all but the unmeasured
    assert pc.choose_portraits({"a": 50.0, "b": 50.0}, 2) == ["a", "b"]  # each taken once
    assert pc.choose_portraits({}, 2) == []


def test_opens_with_smile():
    assert pc.opens_with_smile({"neutral_open": 0.01, "smiling_open": 0.09})
    assert not pc.opens_with_smile({"neutral_open": 0.01, "smiling_open": 0.04})  # a closed-lip smile
    assert not pc.opens_with_smile({"neutral_open": 0.12, "smiling_open": 0.2})  # neutral read open
    assert not pc.opens_with_smile({"neutral_open": float("nan"), "smiling_open": 0.2})


def test_portrait_pairs_and_bad_folders(tmp_path):
    with pytest.raises(BadInputError, match="not found"):
        pc.portrait_pairs(tmp_path / "missing")
    (tmp_path / "001_neutral.jpg").write_bytes(b"x")  # no smiling partner
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(BadInputError, match="no portrait pairs"):
        pc.portrait_pairs(tmp_path)
    (tmp_path / "001_smiling.png").write_bytes(b"x")
    assert pc.portrait_pairs(tmp_path) == {"001": (tmp_path / "001_neutral.jpg", tmp_path / "001_smiling.png")}


@pytest.fixture(scope="module")
def portraits(tmp_path_factory):
    folder = tmp_path_factory.mktemp("frl")
    for k in ("004", "005"):
        for kind in ("neutral", "smiling"):
            shutil.copy(SAMPLES / f"frl_{k}_{kind}.jpg", folder / f"{k}_{kind}.jpg")
    return folder


def test_portrait_clips_on_real_faces(portraits, tmp_path):
    stats = {k: pc.portrait_stats(*p) for k, p in pc.portrait_pairs(portraits).items()}
    assert all(20 < s["lightness"] < 95 for s in stats.values())
    assert pc.opens_with_smile(stats["004"])  # a smile with teeth
    assert not pc.opens_with_smile(stats["005"])  # a closed-lip smile
    clips = pc.portrait_clips(portraits, tmp_path, 2)
    assert [c.name for c in clips] == ["portrait_004.mp4"]
    frames = list(iter_video_frames(clips[0]))
    assert len(frames) == 2 * pc.HOLD and frames[0].shape == read_image(portraits / "004_neutral.jpg").shape
    assert np.abs(frames[0] - read_image(portraits / "004_neutral.jpg")).mean() < 0.02
    assert np.abs(frames[-1] - read_image(portraits / "004_smiling.jpg")).mean() < 0.02
    cached = json.loads((tmp_path / "portraits" / "portraits.json").read_text())
    assert set(cached) == {"004", "005"}
    mtime = clips[0].stat().st_mtime_ns
    assert pc.portrait_clips(portraits, tmp_path, 2)[0].stat().st_mtime_ns == mtime  # reused
    for f in portraits.glob("004_*"):
        f.unlink()
    with pytest.raises(BadInputError, match="open smile"):
        pc.portrait_clips(portraits, tmp_path / "other", 1)


def test_cli_portraits_run_at_their_own_size_and_length(tmp_path, monkeypatch):

    personas, clips, calls = _fake(tmp_path, monkeypatch)
    made = tmp_path / "o" / "portraits" / "portrait_007.mp4"

    def make(folder, out, n, **kw):
        assert Path(folder) == tmp_path / "frl" and n == 1
        made.parent.mkdir(parents=True, exist_ok=True)
        made.write_bytes(b"x")
        return [made]

    monkeypatch.setattr(bench, "portrait_clips", make)
    monkeypatch.setattr("facetex.io.video_info", lambda c: {"n_frames": 5})
    parser = argparse.ArgumentParser()
    bench.register_bench(parser.add_subparsers())
    args = parser.parse_args(["puppet", "--drivers", str(clips), "--puppets", str(personas[0]), "--out",
                              str(tmp_path / "o"), "--no-partial", "--size", "64", "--max-frames", "3",
                              "--portraits", "1", "--portrait-folder", str(tmp_path / "frl"), "-q", "--jobs", "1"])
    assert args.func(args) == 0
    assert calls == [("Anna", "c1", 64, 3), ("Anna", "c2", 64, 3), ("Anna", "portrait_007", None, None)]
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert res["settings"]["portraits"] == [str(made)] and res["rows"][2]["settings"]["size"] is None
    assert "portrait pairs" in (tmp_path / "o" / "table.md").read_text()
    # without a portrait folder or data root: one clear error
    with pytest.raises(BadInputError, match="--portraits"):
        bench.run_bench_puppet(clips, puppets=[personas[0]], out=tmp_path / "o2", portraits=1, partial=False)


def _fake(tmp_path, monkeypatch):
    """One fake persona, two fake clips; the run records (persona, clip, size, max_frames)."""
    f = tmp_path / "Anna.persona"
    f.write_bytes(b"x")
    clips = tmp_path / "clips"
    clips.mkdir()
    for c in ("c1", "c2"):
        (clips / f"{c}.mp4").write_bytes(b"x")
    calls = []

    def evaluate(clip, persona, ref, out, *, name, **kw):
        calls.append((name, clip.stem, kw["size"], kw["max_frames"]))
        row = {"run": f"{name}/{clip.stem}", "persona": name, "clip": clip.stem, "frames": 5, "lost": 0,
               "mouth_slope": 1.0, "mouth_r": 0.9, "cheek_de": 4.0, "eye_ratio": 0.9, "sharp": 0.8, "id_closer": 1.0}
        row["score"], row["failed"] = bench.run_score(row), bench.failed_targets(row)
        return row

    monkeypatch.setattr(bench, "_persona_file", lambda p, out, progress: str(p))
    monkeypatch.setattr(bench, "_collection_descriptor", lambda f: np.zeros(128))
    monkeypatch.setattr(bench, "_evaluate_clip", evaluate)
    monkeypatch.setattr("facetex.persona.load_persona", lambda f: Path(f).stem)
    return [f], clips, calls
