import argparse
import csv
import json
import shutil

import numpy as np
import pytest

from facetex._resources import sample_path
from facetex.bench import _common
from facetex.bench import transfer as bench
from facetex.errors import BadInputError, OutputError
from facetex.io import read_image

PEOPLE = ("003", "004", "005", "008")
SUMMARY = ("table.md", "table.csv", "grid.png", "scatter.png", "results.json")


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    d = tmp_path_factory.mktemp("frl")
    for p in PEOPLE:
        shutil.copy(sample_path(f"frl_{p}_neutral.jpg"), d / f"{p}_neutral.jpg")
    shutil.copy(sample_path("frl_004_smiling.jpg"), d / "004_smiling.jpg")  # not a neutral: ignored
    return d


class FakeTransfer:
    """A cheap stand-in: 0.7 content + 0.3 style (the frontal samples are roughly aligned);
    reports 3 inner iterations; raises KeyboardInterrupt on call ``interrupt_at``."""

    def __init__(self, interrupt_at=None):
        self.calls = []
        self.interrupt_at = interrupt_at

    def __call__(self, content, style, *, method, preset, seed, device, progress=None, **options):
        self.calls.append((method, options))
        if len(self.calls) == self.interrupt_at:
            raise KeyboardInterrupt
        for i in range(3):
            if progress:
                progress(n=1, loss=1.0 / (i + 1))
        return 0.7 * content + 0.3 * style, {"timings": {"total_s": 0.01}, "params": {"method": method}}


def quick_metrics(output, content, style, *, points=None):
    """Cheap stand-in for transfer_metrics in the tests of the run logic (resume, interrupt):
    numbers from pixel differences, no landmark detection or face network."""
    dc, ds = float(np.mean((output - content) ** 2)), float(np.mean((output - style) ** 2))
    return {"E_content": dc, "E_style": ds, "E_content_rms_px": dc ** 0.5, "E_style_rms_px": ds ** 0.5,
            "S_content": 1 - dc, "S_style": 1 - ds, "identity_content": dc, "identity_style": ds}


def _run(data, out, fake, **kw):
    kw.setdefault("pairs", 2)
    kw.setdefault("methods", "gatys,facetex")
    kw.setdefault("metrics_fn", quick_metrics)
    return bench.run_bench_transfer(data, out, transfer_fn=fake, **kw)


@pytest.fixture(scope="module")
def done(data, tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    fake = FakeTransfer()
    events = []
    result = _run(data, out, fake, progress=lambda n=1, **pf: events.append((n, pf)))
    return out, fake, result, events


def _files(folder):
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if p.is_file())


def test_outputs_have_table1_structure(done):
    out, fake, result, events = done
    assert len(fake.calls) == 4 and result["n_run"] == 4 and result["n_reused"] == 0
    for name in SUMMARY:
        assert (out / name).is_file()
    rows = list(csv.DictReader((out / "table.csv").open()))
    assert [r["method_id"] for r in rows] == ["none", "gatys", "facetex"]  # "no transfer" first
    assert {"E_content", "E_style", "S_content", "S_style", "identity_content", "identity_style",
            "same_identity", "time_s", "n_pairs", "S_style_gain", "detail_ratio", "protected_change",
            "background_change", "prewarp_folds"} <= set(rows[0])
    assert [r["n_pairs"] for r in rows] == ["2", "2", "2"]
    assert float(rows[0]["E_content"]) == 0.0  # the content scored as its own output
    assert (out / "zoom.png").is_file() and len(list((out / "zoom").glob("*.png"))) == 2
    md = (out / "table.md").read_text()
    for v in ("22.61", "106.17", "37.93", "369.39", "191.47", "295.93", "0.89", "0.68", "0.55"):
        assert v in md
    assert "Neural Style" in md and "FaceTex" in md


def test_pairs_run_one_after_another_each_loaded_once_with_its_zoom_sheet(data, tmp_path, monkeypatch):
    """Sequential run: a pair's images are loaded once for all its methods, and its zoom sheet is
    written before the next pair starts (an intermediate save; memory holds one pair)."""
    loads, zooms_seen = [], []
    real = bench._load_pair
    monkeypatch.setattr(bench, "_load_pair", lambda c, s: loads.append((c, s)) or real(c, s))
    out = tmp_path / "b"
    fake = FakeTransfer()

    def watched(*a, **kw):
        zooms_seen.append(len(list((out / "zoom").glob("*.png"))))
        return fake(*a, **kw)

    result = _run(data, out, watched)
    assert result["n_run"] == 4 and len(loads) == 2 and len(set(loads)) == 2
    assert zooms_seen == [0, 0, 1, 1]
    assert len(list((out / "zoom").glob("*.png"))) == 2 and (out / "zoom.png").is_file()


def test_real_metrics_of_a_content_heavy_blend(data, tmp_path):
    out = tmp_path / "out"
    _run(data, out, FakeTransfer(), pairs=1, methods="facetex", metrics_fn=None)
    none, r = list(csv.DictReader((out / "table.csv").open()))
    # doing nothing: no change anywhere, no move towards the style
    assert float(none["S_style_gain"]) == 0.0 and float(none["protected_change"]) == 0.0
    assert float(none["background_change"]) == 0.0 and float(none["E_content"]) == 0.0
    # the 0.3 blend moves towards the style and changes the features and background too
    assert float(r["S_style_gain"]) > 0.0
    assert float(r["protected_change"]) > 1.0 and float(r["background_change"]) > 1.0
    # the output is mostly content: closer to it in structure, texture and identity
    assert float(r["E_content"]) < float(r["E_style"])
    assert float(r["S_content"]) > float(r["S_style"])
    assert float(r["identity_content"]) < 0.6 < float(r["identity_style"])
    assert r["same_identity"] == "1"
    assert float(r["E_content_rms_px"]) ** 2 == pytest.approx(float(r["E_content"]))


def test_pairs_json_and_images(done, data):
    out, _, result, _ = done
    pj = json.loads((out / "results.json").read_text())
    assert pj["bench"] == "transfer"
    s = pj["settings"]
    assert s["seed"] == 0 and s["preset"] == "default" and s["methods"] == ["gatys", "facetex"]
    assert "facetex" in s["versions"] and s["data"] == str(data.resolve())
    assert len(pj["pairs"]) == 2
    for p in pj["pairs"]:
        assert p["content"] != p["style"]
        assert set(p["results"]) == {"none", "gatys", "facetex"}
        for m, r in p["results"].items():
            assert set(r["metrics"]) == set(bench.METRIC_KEYS)
            if m == "none":
                assert r["image"] is None
                continue
            img = out / r["image"]
            assert img.name == f"{p['content']}__{p['style']}__{m}.png" and img.is_file()
            info = json.loads(img.with_suffix(".json").read_text())
            assert info["method"] == m and info["params"] == {"method": m} and "timings" in info
    assert [(p["content"], p["style"]) for p in pj["pairs"]] == result["pairs"]


def test_grid_and_scatter_images(done):
    out, *_ = done
    grid = read_image(out / "grid.png")
    # 2 rows, 4 columns (style, content, FaceTex, Neural Style) of 256 px cells plus title band
    assert grid.shape[1] == 4 * 256 + 5 * 4
    assert grid.shape[0] == 36 + 2 * 256 + 3 * 4
    assert grid[:30].mean() > 0.9  # white title band with dark text
    assert grid[:30].min() < 0.3
    assert read_image(out / "scatter.png").shape[1] > 600


def test_progress_counts_items_and_shows_inner_iterations(done):
    *_, events = done
    assert sum(n for n, _ in events) == 4
    inner = [pf for n, pf in events if n == 0]
    assert len(inner) == 4 * 3 and inner[2]["it"] == 3 and inner[0]["method"] == "gatys"


def test_pair_selection_different_people_and_deterministic():
    ids = [f"{i:03d}" for i in range(10)]
    a = _common.select_pairs(ids, 5, seed=1)
    assert a == _common.select_pairs(ids, 5, seed=1)
    assert all(c != s for c, s in a)
    assert len({p for pair in a for p in pair}) == 10  # disjoint while possible
    others = [_common.select_pairs(ids, 5, seed=k) for k in range(2, 6)]
    assert any(o != a for o in others)
    assert _common.select_pairs(ids, 3, seed=1) == a[:3]  # a longer run extends a shorter one
    many = _common.select_pairs(ids[:4], 50, seed=0)
    assert len(many) == 12 and len(set(many)) == 12 and all(c != s for c, s in many)
    assert _common.select_pairs(ids[:4], 7, seed=0) == many[:7]


def test_run_pairs_follow_seed(data, tmp_path):
    r1 = _run(data, tmp_path / "a", FakeTransfer(), pairs=1, methods="facetex", seed=3)
    assert r1["pairs"] == _common.select_pairs(PEOPLE, 1, seed=3)
    assert r1["pairs"][0][0] != r1["pairs"][0][1]


def test_resume_skips_done_work(done, data, tmp_path):
    src, _, first, _ = done
    out = tmp_path / "out"
    shutil.copytree(src, out)
    fake = FakeTransfer()
    r = _run(data, out, fake)
    assert fake.calls == [] and r["n_reused"] == 4
    assert [row["E_content"] for row in r["table"]] == pytest.approx([row["E_content"] for row in first["table"]])
    # a lost result is redone, only that one
    c, s = first["pairs"][1]
    (out / "results" / f"{c}__{s}__facetex.json").unlink()
    r = _run(data, out, fake)
    assert [m for m, _ in fake.calls] == ["facetex"] and r["n_run"] == 1 and r["n_reused"] == 3
    # more pairs: only the new pair runs
    fake = FakeTransfer()
    r = _run(data, out, fake, pairs=3)
    assert len(fake.calls) == 2 and r["n_reused"] == 4
    fake = FakeTransfer()
    _run(data, out, fake, overwrite=True)
    assert len(fake.calls) == 4


def test_results_of_other_settings_are_not_mixed(done, data, tmp_path):
    out = tmp_path / "out"
    shutil.copytree(done[0], out)
    with pytest.raises(OutputError, match="--overwrite"):
        _run(data, out, FakeTransfer(), size=128)
    fake = FakeTransfer()
    _run(data, out, fake, size=128, overwrite=True)
    assert fake.calls[0][1] == {"size": 128}


def test_interrupted_run_leaves_no_partial_files_and_resumes(data, tmp_path):
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        _run(data, out, FakeTransfer(interrupt_at=2))
    files = _files(out)
    assert not any(f.split("/")[-1].startswith(".") for f in files)  # no temporary files
    assert not any(name in files for name in SUMMARY)
    assert len([f for f in files if f.startswith("results/") and "__none" not in f]) == 1
    assert len([f for f in files if f.startswith("images/")]) == 2  # one png + its info json
    fake = FakeTransfer()
    r = _run(data, out, fake)
    assert len(fake.calls) == 3 and r["n_reused"] == 1
    assert all((out / name).is_file() for name in SUMMARY)


def test_bad_inputs(data, tmp_path):
    one = tmp_path / "one"
    one.mkdir()
    shutil.copy(data / "003_neutral.jpg", one)
    shutil.copy(sample_path("frl_004_smiling.jpg"), one / "004_smiling.jpg")
    with pytest.raises(BadInputError, match="at least 2") as e:
        _run(one, tmp_path / "o", FakeTransfer())
    assert e.value.path == str(one)
    with pytest.raises(BadInputError) as e:
        _run(tmp_path / "missing", tmp_path / "o", FakeTransfer())
    assert e.value.path == str(tmp_path / "missing")
    with pytest.raises(BadInputError, match="gatys, mrf, facetex"):
        _run(data, tmp_path / "o", FakeTransfer(), methods="facetex,cyclegan")
    with pytest.raises(BadInputError, match="preset"):
        _run(data, tmp_path / "o", FakeTransfer(), preset="fast")


def _fake_bench_parser(monkeypatch):
    """(FakeTransfer, the bench's argument parser) with the fake transfer and quick metrics patched in."""
    fake = FakeTransfer()
    monkeypatch.setattr(bench, "_default_transfer_fn", lambda: fake)
    monkeypatch.setattr("facetex.metrics.transfer_metrics", quick_metrics)
    parser = argparse.ArgumentParser()
    bench.register_bench(parser.add_subparsers())
    return fake, parser


def test_cli_parser_and_run(data, tmp_path, monkeypatch, capsys):
    fake, parser = _fake_bench_parser(monkeypatch)
    args = parser.parse_args(["transfer", "--data", str(data), "--out", str(tmp_path / "o"), "--pairs", "1", "--jobs", "1",
                              "--methods", "mrf", "--seed", "2", "--preset", "paper", "--json"])
    assert args.func(args) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["summary"]["run"] == 1
    assert [r["method_id"] for r in printed["summary"]["table"]] == ["none", "mrf"]
    assert fake.calls == [("mrf", {})]
    assert (tmp_path / "o" / "grid.png").is_file()
    run = json.loads((tmp_path / "o" / "run.json").read_text())
    assert run["command"] == "bench transfer" and run["seed"] == 2 and run["params"]["preset"] == "paper"
    assert run["inputs"]["data"]["files"] >= 2 and len(run["inputs"]["data"]["sha256_of_files"]) == 64
    # --iters reaches the transfer; without --json the table and `wrote` lines are printed
    args = parser.parse_args(["transfer", "--data", str(data), "--out", str(tmp_path / "q"), "--pairs", "1", "--jobs", "1",
                              "--methods", "gatys", "--iters", "2,2"])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "| method |" in text and f"wrote {tmp_path / 'q' / 'run.json'}" in text
    md = (tmp_path / "q" / "table.md").read_text()
    assert "`--pairs 1`" in md and "`--methods gatys`" in md and "`--iters 2,2`" in md and "preset" not in md.split(
        "## Settings of this run")[1].split("## Spread")[0]
    assert "## Spread" in md and "| Neural Style | S_style | 1 |" in md
    assert fake.calls[-1] == ("gatys", {"iters": [2, 2]})


def test_data_folder_comes_from_option_or_environment(data, tmp_path, monkeypatch):
    monkeypatch.delenv(_common.DATA_ENV, raising=False)
    with pytest.raises(BadInputError, match="--data DIR or set FACETEX_DATA"):
        _common.data_root(None)
    monkeypatch.setenv(_common.DATA_ENV, str(tmp_path))
    assert _common.data_root(None) == tmp_path
    assert _common.data_root(data) == data  # the option wins
    (tmp_path / "frl-london").mkdir()
    assert _common.data_folder(tmp_path, "frl-london") == tmp_path / "frl-london"  # the data root
    assert _common.data_folder(data, "frl-london") == data  # the bench's own folder
    with pytest.raises(BadInputError, match="data folder not found"):
        _common.data_root(tmp_path / "nope")


def test_pairs_stay_when_a_portrait_is_added():
    ids = [f"{i:03d}" for i in range(60)]
    changed = [len(set(_common.select_pairs(ids, 5, seed=s)) - set(_common.select_pairs(ids + ["061"], 5, seed=s)))
               for s in range(20)]
    assert sum(changed) <= 10  # random shuffling would change nearly all 100
    assert max(changed) <= 2


def test_spread_and_no_image_data():
    s = _common.spread([1.0, 2.0, 3.0, float("nan"), None])
    assert s["n"] == 3 and s["mean"] == 2.0 and s["std"] == 1.0
    assert abs(s["ci95_half"] - 4.302652729749464 / 3 ** 0.5) < 1e-9  # t(0.975, 2) * std / sqrt(n)
    assert _common.spread_text([1.0, 2.0, 3.0], ".1f") == "2.0 ± 1.0 [-0.5, 4.5]"
    info = {"images": {"x": np.zeros((50, 50, 3))}, "mask": np.ones((64, 64)), "loss": [1.0, 2.0]}
    clean = _common.no_image_data(info)
    assert clean == {"mask": {"array": [64, 64], "dtype": "float64"}, "loss": [1.0, 2.0]}
    assert _common.non_default_settings({"a": 1, "b": 2, "c": 3}, {"a": 1, "b": 5}) == {"b": 2, "c": 3}


def test_markdown_and_csv_tables():
    cols = [_common.Column("name", "Name"), _common.Column("v", "Value", ".2f")]
    rows = [{"name": "a", "v": 1.234}, {"name": "b|c", "v": float("nan")}, {"name": "d,e", "v": 2}]
    md = _common.markdown_table(cols, rows)
    assert md.splitlines() == ["| Name | Value |", "| --- | ---: |", "| a | 1.23 |", "| b\\|c | – |", "| d,e | 2.00 |"]
    assert _common.csv_table(cols, rows).splitlines() == ["name,v", "a,1.234", "b|c,", "\"d,e\",2"]


def test_image_grid_layout():
    img = np.zeros((40, 20, 3), np.float32)
    g = _common.image_grid([[img, None]], col_titles=["x", "y"], cell=64, gap=2, title_height=20)
    assert g.shape == (20 + 64 + 4, 2 * 64 + 6, 3) and g.dtype == np.uint8
    cell0 = g[22:86, 2:66]
    assert cell0[:, 32].min() == 0 and cell0[:, 0].min() == 128  # fitted, centred on grey


@pytest.mark.slow
def test_engine_gives_the_sequential_results(data, tmp_path):
    """Two local workers: the same images and numbers as one after another (one torch thread each)."""
    import torch

    from facetex.batch import LocalEngine

    kw = dict(pairs=2, methods="facetex,mrf", size=96, iters=(2, 2, 2))
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        seq = bench.run_bench_transfer(data, tmp_path / "seq", **kw)
    finally:
        torch.set_num_threads(threads)
    with LocalEngine(2, threads=1) as eng:
        par = bench.run_bench_transfer(data, tmp_path / "par", engine=eng, **kw)
    assert (seq["n_run"], par["n_run"]) == (4, 4)
    for name in sorted(p.name for p in (tmp_path / "seq" / "images").glob("*.png")):
        assert (tmp_path / "seq" / "images" / name).read_bytes() == (tmp_path / "par" / "images" / name).read_bytes()
    for a, b in zip(seq["table"], par["table"]):
        assert {k: v for k, v in a.items() if k not in ("time_s", "cpu_s")} == pytest.approx(
            {k: v for k, v in b.items() if k not in ("time_s", "cpu_s")}, nan_ok=True)
    for name in ("zoom.png", "grid.png"):  # the figures, from the same images
        assert (tmp_path / "seq" / name).read_bytes() == (tmp_path / "par" / name).read_bytes()
    resumed = bench.run_bench_transfer(data, tmp_path / "par", **kw)
    assert (resumed["n_run"], resumed["n_reused"]) == (0, 4)


def test_pair_list_explicit_and_named(data, tmp_path, monkeypatch):
    portraits = {p: None for p in PEOPLE}
    assert bench.resolve_pair_list("003:004,005:008", portraits) == [("003", "004"), ("005", "008")]
    assert bench.resolve_pair_list([("008", "003")], portraits) == [("008", "003")]
    with pytest.raises(BadInputError, match="without an NNN_neutral.jpg portrait: 999"):
        bench.resolve_pair_list("003:999", portraits)
    with pytest.raises(BadInputError, match="neither one of issue22"):
        bench.resolve_pair_list("003-004", portraits)
    with pytest.raises(BadInputError, match="same person"):
        bench.resolve_pair_list("003:003", portraits)
    # the documented issue-22 list: ≥ 20 pairs of different people, no pair twice
    assert len(bench.ISSUE22_PAIRS) >= 20 and len(set(bench.ISSUE22_PAIRS)) == len(bench.ISSUE22_PAIRS)
    assert all(c != s for c, s in bench.ISSUE22_PAIRS)
    # the run takes the list's first --pairs pairs, passes --keep-shading / --marks on, and writes
    # the per-pair table
    fake, parser = _fake_bench_parser(monkeypatch)
    args = parser.parse_args(["transfer", "--data", str(data), "--out", str(tmp_path / "o"), "--pairs", "1", "--jobs", "1",
                              "--methods", "facetex", "--pair-list", "005:003,004:008", "--keep-shading", "off",
                              "--marks", "style", "-q"])
    assert args.func(args) == 0
    assert fake.calls == [("facetex", {"keep_shading": False, "marks": "style"})]
    res = json.loads((tmp_path / "o" / "results.json").read_text())
    assert [(p["content"], p["style"]) for p in res["pairs"]] == [("005", "003")]
    assert "## Per pair, worst low-frequency ΔE first" in (tmp_path / "o" / "table.md").read_text()
