"""`facetex report` / `facetex compare` on real bench run folders, and the figure helpers."""

from __future__ import annotations

import base64
import json
import re

import numpy as np
import pytest

from facetex.cli import main
from facetex.errors import BadInputError
from facetex.report import compare_rows, load_run, metrics_figure, zoom_panel


def test_load_bench_transfer_run(runs, frl):
    from facetex.report import load_runs

    alone = load_run(runs[0])  # the content and style images are outside the run folder: skipped
    assert "style" not in alone.items[0].images and any(str(frl) in p for p in alone.skipped)
    run, = load_runs([runs[0]], also=[frl])
    assert run.kind == "bench transfer" and len(run.items) == 3 and not run.skipped
    assert run.methods == ["none", "gatys", "mrf", "facetex"]  # "none": the content, a baseline
    it = run.items[0]
    assert list(it.images)[:2] == ["style", "content"] and set(it.images) >= {"gatys", "mrf", "facetex"}
    assert {"E_content", "S_style", "time_s"} <= set(run.metric_names)
    assert run.paper["facetex"]["E_content"] == 37.93  # Table 1 as a reference
    assert run.provenance["command"] == "bench transfer"


def _persona_folder(folder, json_name, bench_key=True):
    """A bench persona run folder in the layout run_bench_persona writes (per-target columns
    <row>_<region>_<metric>, px_<region> mask sizes)."""
    folder.mkdir()
    rec = {"rows": [], "data": "lfw/x", "holdout": 2, "teeth": [], "held_out": ["a.jpg", "b.jpg"]}
    (folder / json_name).write_text(json.dumps({**({"bench": "persona"} if bench_key else {}), **rec}))
    cols = ["file", "yaw", "px_face", "px_mouth"] + [f"{r}_{g}_ssim" for r in ("static", "paper", "ours")
                                                     for g in ("face", "mouth")] + ["ours_time_s"]
    lines = [",".join(cols)] + [",".join(["a.jpg", "1.0", "900", "80", "0.5", "0.4", "0.52", "0.43", "0.55",
                                          "0.47", "0.01"]),
                                ",".join(["b.jpg", "-2.0", "950", "85", "0.6", "0.5", "0.61", "0.52", "0.63",
                                          "0.55", "0.02"])]
    (folder / "per_target.csv").write_text("\n".join(lines) + "\n")
    (folder / "table.md").write_text("| method |\n|---|\n| ours |\n")
    return folder


def test_load_bench_persona_and_puppet_runs(tmp_path):
    for name, json_name, key in (("new", "results.json", True), ("old", "summary.json", False)):
        run = load_run(_persona_folder(tmp_path / name, json_name, key))
        assert run.kind == "bench persona" and len(run.items) == 2, name
        assert run.methods == ["static", "paper", "ours"] and "px" not in run.methods  # Tom Hanks Fig. 5 order
        assert {"face_ssim", "mouth_ssim"} <= set(run.metric_names)
        assert run.values("ours", "mouth_ssim") == [0.47, 0.55]
        assert "bench" not in run.settings and run.settings["holdout"] == 2
    pup = tmp_path / "puppet"
    pup.mkdir()
    (pup / "results.json").write_text(json.dumps({"bench": "puppet", "settings": {"size": 256},
                                                  "rows": [{"clip": "c1", "mouth_slope": 0.9, "mouth_r": 0.9}]}))
    run = load_run(pup)  # recognised by its bench key, with or without a table
    assert run.kind == "bench puppet" and run.values("puppet", "mouth_slope") == [0.9]


def test_bench_json_holds_no_image_data(runs):
    for p in (runs[0] / "images").glob("*.json"):
        text = p.read_text()
        assert len(text) < 20_000 and '"images"' not in text, p


def _decodes(uri: str) -> bool:
    head, b64 = uri.split(",", 1)
    data = base64.b64decode(b64)
    return data[:4] == b"RIFF" and data[8:12] == b"WEBP" or data[:8] == b"\x89PNG\r\n\x1a\n" or b"<svg" in data[:400]


def test_report_is_self_contained_and_complete(runs, frl, tmp_path, capsys):
    out = tmp_path / "report.html"
    # the bench's content and style images are in its --data folder: read only when given
    assert main(["report", str(runs[0]), str(runs[1]), "-o", str(out), "--data", str(frl)]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [f"wrote {out}", f"wrote {out}.json"] and "skipped" not in captured.err
    page = out.read_text()
    # nothing outside the file: every src is a data URI, and each decodes
    srcs = re.findall(r"src='([^']*)'", page)
    assert srcs and all(s.startswith("data:image/") for s in srcs)
    assert "http://" not in page and "https://" not in page
    assert all(_decodes(s) for s in srcs)
    for needed in ("Comparison of the runs", "Table 1: the paper beside ours", "Paired differences", "Figures",
                   "Pairs", "Settings and provenance", "Non-default settings", "bootstrap 95 %", "Native-resolution zooms",
                   "run.json", "Sidecar parameters", "table.md", "id='toc'"):
        assert needed in page, needed
    nd = re.search(r"<b>Non-default settings:</b> ([^<]*)</p>", page).group(1)
    assert "pairs = 3" in nd and "preset" not in nd  # from run.json against the command's own defaults
    assert page.count("class='thumb'") == 2 * 3 * 5  # 2 runs x 3 pairs x (style, content, 3 methods)
    # the Table 1 comparison comes before the figures, the per-pair table and the settings
    order = [page.index(f"id='r1-{k}'") for k in ("table1", "paired", "figures", "pairs", "settings")]
    assert order == sorted(order)
    # every anchor of the table of contents exists
    toc = re.search(r"<nav id='toc'.*?</nav>", page, re.S).group(0)
    anchors = re.findall(r"href='#([^']+)'", toc)
    assert len(anchors) >= 12 and all(f"id='{a}'" in page for a in anchors)
    side = json.loads((tmp_path / "report.html.json").read_text())
    assert side["command"] == "report" and len(side["inputs"]["run1"]["sha256"]) == 64
    # exclusive create: no silent replacement
    assert main(["report", str(runs[0]), "-o", str(out)]) == 2
    assert "exists" in capsys.readouterr().err


def test_compare_prints_the_same_numbers(runs, capsys):
    assert main(["compare", str(runs[0]), str(runs[1])]) == 0
    text = capsys.readouterr().out
    assert "[1] run_a" in text and "[2] run_b" in text and "Δ [2]-[1]" in text
    rows = compare_rows([load_run(runs[0]), load_run(runs[1])])
    row = next(r for r in rows if r["method"] == "mrf" and r["metric"] == "S_style")
    a, b = row["runs"]
    assert a["n"] == b["n"] == 3 and b["mean"] > a["mean"]  # run b blends in twice the style
    assert abs(row["delta"][1] - (b["mean"] - a["mean"])) < 1e-12
    assert f"{a['mean']:.4g}"[:4] in text
    assert main(["compare", str(runs[0]), str(runs[1]), "--json"]) == 0
    js = json.loads(capsys.readouterr().out)
    assert len(js["rows"]) == len(rows)
    assert main(["compare", str(runs[0])]) == 2


def test_report_errors_are_one_line(tmp_path, capsys):
    assert main(["report", str(tmp_path / "missing"), "-o", str(tmp_path / "r.html")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "not found" in err
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(BadInputError, match="nothing to report"):
        load_run(empty)
    assert not (tmp_path / "r.html").exists()


def test_report_of_a_folder_of_single_runs(tmp_path, capsys):
    """A folder of `facetex transfer` outputs with sidecars (made here without running a transfer)."""
    from facetex._provenance import provenance
    from facetex._resources import sample_path
    from facetex.io import read_image, write_image, write_json

    c, s = sample_path("frl_004_neutral.jpg"), sample_path("frl_005_neutral.jpg")
    img = 0.8 * read_image(c) + 0.2 * read_image(s)
    write_image(tmp_path / "a.png", img)
    write_json(tmp_path / "a.png.json", provenance(command="transfer", inputs={"content": c, "style": s},
                                                   params={"method": "facetex"}, result={"timings": {"total_s": 3.0}}))
    run = load_run(tmp_path)
    assert run.kind == "outputs" and list(run.items[0].images) == ["style", "content", "facetex"]
    assert run.items[0].metrics["facetex"]["time_s"] == 3.0
    assert main(["report", str(tmp_path), "-o", str(tmp_path / "r.html")]) == 0


def test_zoom_panel_is_native_resolution():
    a = np.zeros((100, 120, 3), np.float32)
    a[20:30, 40:50] = 1.0
    b = np.full((80, 80, 3), 0.5, np.float32)
    p = zoom_panel([("a", a, (40, 20, 60, 40)), ("b", b, (0, 0, 30, 10))], gap=4, label_height=10)
    assert p.shape == (10 + 20, 20 + 4 + 30, 3)
    assert (p[10:20, 0:10] == 255).all() and (p[20:30, 10:20] == 0).all()  # pixels copied, not resampled
    assert (p[10:20, 24:54] == 128).all()
    with pytest.raises(BadInputError, match="outside"):
        zoom_panel([("a", a, (200, 200, 220, 220))])


def test_metrics_figure_marks_the_paper_values(tmp_path):
    from facetex.bench._common import write_figure_formats

    fig = metrics_figure({"FaceTex": {"E_content": [1.0, 2.0, 3.0]}, "MRF-CNN": {"E_content": [4.0, 5.0]}},
                         ["E_content"], paper={"FaceTex": {"E_content": 37.9}}, title="t")
    ax = fig.axes[0]
    texts = [t.get_text() for t in ax.texts]
    assert texts == ["paper"]
    legend = [t.get_text() for t in fig.legends[0].get_texts()]
    assert any("paper (other data)" in t for t in legend)
    paths = write_figure_formats(tmp_path / "fig", fig)
    assert [p.suffix for p in paths] == [".png", ".svg", ".pdf"]
    assert paths[0].read_bytes()[:4] == b"\x89PNG" and b"<svg" in paths[1].read_bytes()[:500]
    assert paths[2].read_bytes()[:5] == b"%PDF-"
