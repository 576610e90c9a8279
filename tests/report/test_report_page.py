"""The report page as a results section: intervals (bootstrap, inside each metric's range, none
for too few items), paired differences, one method name and order, Markdown tables, the size
of a 10-pair report, and the persona and puppet sections."""

from __future__ import annotations

import json
import math
import re
import shutil

import numpy as np
import pytest

from facetex._methods import METHOD_ORDER, METHOD_TITLES, TRANSFER_METHODS
from facetex._stats import MIN_N_INTERVAL, bootstrap_mean, spread
from facetex.cli import main
from facetex.report import load_runs
from facetex.report.compare import best_counts, method_pairs, paired_differences
from facetex.report.html import _markdown_table, build_report
from facetex.report.metric_info import metric_info


def test_bootstrap_interval_hand_cases():
    # nine zeros and a ten: the mean is 1; a Student-t interval reaches below 0, the bootstrap's stays
    # inside [0, 10] (every resampled mean is a multiple of 1 between 0 and 10)
    vals = [0.0] * 9 + [10.0]
    t = spread(vals)
    assert t["ci95"][0] < 0
    b = bootstrap_mean(vals, bounds=(0, math.inf))
    assert b["mean"] == 1.0 and b["n"] == 10 and 0 <= b["lo"] < 1 < b["hi"] <= 10
    assert b["lo"] in (0.0, 1.0) or float(b["lo"]).is_integer()
    # 1..10: close to the t interval [3.33, 7.67] (a bootstrap is a little narrower at small n)
    b = bootstrap_mean(range(1, 11))
    assert 3.0 < b["lo"] < 4.2 and 6.8 < b["hi"] < 8.0 and b["mean"] == 5.5
    assert bootstrap_mean(range(1, 11)) == b  # seeded: the same values give the same interval
    # equal values: the interval is the point
    b = bootstrap_mean([0.3] * 6, bounds=(-1, 1))
    assert b["lo"] == b["hi"] == b["mean"] == pytest.approx(0.3)


def test_too_few_items_have_no_interval():
    for n in range(1, MIN_N_INTERVAL):
        b = bootstrap_mean([0.1 * k for k in range(n)])
        assert b["n"] == n and math.isfinite(b["mean"]) and math.isnan(b["lo"]) and math.isnan(b["hi"])
    assert bootstrap_mean([])["n"] == 0
    assert math.isfinite(bootstrap_mean([0.1 * k for k in range(MIN_N_INTERVAL)])["lo"])


@pytest.mark.parametrize("metric,lo,hi", [("E_content", 0, math.inf), ("E_style", 0, math.inf),
                                          ("S_style", -1, 1), ("S_content", -1, 1), ("identity_content", 0, math.inf),
                                          ("face_ssim", -1, 1), ("mouth_ssim", -1, 1), ("cheek_de", 0, math.inf),
                                          ("id_closer", 0, 1), ("time_s", 0, math.inf), ("any_ssim", -1, 1)])
def test_intervals_stay_in_each_metrics_range(metric, lo, hi):
    info = metric_info(metric)
    assert info.bounds == (lo, hi)
    rng = np.random.default_rng(1)
    # values piled at the range's edge, where a symmetric interval leaves it
    edge = lo if math.isfinite(lo) else hi
    sign = 1 if edge == lo else -1
    for n in (5, 6, 10):
        vals = edge + sign * np.abs(rng.standard_cauchy(n)) * 0.01
        vals = np.clip(vals, lo, hi)
        b = bootstrap_mean(vals, bounds=info.bounds)
        assert lo <= b["lo"] <= b["mean"] <= b["hi"] <= hi, (metric, n, b)


def _two_run(tmp_path, rows):
    """A bench transfer folder with the given per-pair metrics ({method: [E_content, ...]})."""
    pairs = []
    n = len(next(iter(rows.values())))
    for i in range(n):
        pairs.append({"content": f"{i:03d}", "style": f"{i + 50:03d}", "results": {
            m: {"metrics": {"E_content": v[i], "S_style": 0.5}} for m, v in rows.items()}})
    (tmp_path / "results.json").write_text(json.dumps({"bench": "transfer", "settings": {}, "pairs": pairs}))
    return load_runs([tmp_path], images=False)[0]


def test_paired_differences_and_wins(tmp_path):
    run = _two_run(tmp_path, {"facetex": [1.0, 2.0, 3.0, 4.0, 5.0, 6.0], "mrf": [2.0, 2.0, 5.0, 5.0, 4.0, 9.0],
                              "none": [0.0] * 6})
    r = paired_differences(run, "facetex", "mrf", "E_content")
    assert r["diffs"] == [-1.0, 0.0, -2.0, -1.0, 1.0, -3.0] and r["mean"] == pytest.approx(-1.0)
    assert (r["wins_a"], r["wins_b"], r["ties"]) == (4, 1, 1)  # lower E is better
    assert r["lo"] <= r["mean"] <= r["hi"] and r["hi"] <= 1.0
    assert best_counts(run, "E_content", ["mrf", "facetex"]) == {"mrf": 1, "facetex": 4}
    # every method against no transfer, then later − earlier in the one order
    assert method_pairs(run) == [("mrf", "none"), ("facetex", "none"), ("facetex", "mrf")]
    assert paired_differences(run, "facetex", "mrf", "S_style")["wins_a"] == 0  # all tied
    assert paired_differences(run, "facetex", "mrf", "E_style")["n"] == 0


def test_markdown_separator_is_never_a_data_row():
    md = "# t\n\n|method|E|S|\n|---|---|---:|\n|FaceTex|1.0|a \\| b|\n\n| x | y |\n| :--- | ---: |\n| 1 | 2 |\n"
    page = _markdown_table(md)
    rows = re.findall(r"<tr>(.*?)</tr>", page)
    assert len(rows) == 4  # two headers, two data rows
    assert "---" not in page and "<td>a | b</td>" in page and "<td>FaceTex</td>" in page


def test_one_method_name_and_order_everywhere(runs, frl):
    from facetex.bench import transfer as bench

    assert bench.METHODS == TRANSFER_METHODS and bench.GRID_ORDER == TRANSFER_METHODS
    assert bench.METHOD_TITLES is METHOD_TITLES
    run = load_runs([runs[0]], also=[frl])[0]
    page = build_report([run])
    titles = [METHOD_TITLES[m] for m in METHOD_ORDER]
    # Table 1's header, the paired differences, the per-pair table, the thumbnails and the zooms
    t1 = re.search(r"<table class='t1'>.*?</thead>", page, re.S).group(0)
    assert re.findall(r"class='m'>([^<]+)</th>", t1) == titles
    pair_head = re.search(r"<table class='items sortable'.*?</thead>", page, re.S).group(0)
    shown = re.findall(r"<small>([^<]+)</small>", pair_head)
    assert shown[:3] == titles[1:]
    thumbs = re.findall(r"class='thumb'[^>]*data-label='([^']+)'", page)[:5]
    assert thumbs == ["style", "content", *titles[1:]]
    start = page.index("<div class='zrow'>")
    zoom_row = page[start:page.index("<div class='zrow'>", start + 1)]  # the first region's line
    shown = [t for t in re.findall(r"<figcaption><b>([^<]+)</b>", zoom_row) if t not in ("content", "style, pre-warped")]
    assert shown == titles[1:]
    for raw in ("gatys", "mrf"):  # ids never shown as names
        assert f">{raw}<" not in page


def test_zooms_are_native_resolution_and_at_least_200_px(runs, frl):
    run = load_runs([runs[0]], also=[frl])[0]
    page = build_report([run])
    crops = re.findall(r"<img class='crop' src='[^']+' width='(\d+)' height='(\d+)' data-native='(\d+)x(\d+)' "
                       r"data-scale='(\d+)'", page)
    assert len(crops) == 3 * 6 * 4  # 3 pairs x 6 regions x (content and the three methods)
    for w, h, nw, nh, k in (tuple(map(int, c)) for c in crops):
        assert (w, h) == (nw * k, nh * k) and min(w, h) >= 200 and k >= 1


def test_ten_pairs_fit_in_two_megabytes(run10, tmp_path):
    out, data = run10
    report = tmp_path / "r10.html"
    assert main(["report", str(out), "-o", str(report), "--data", str(data), "-q"]) == 0
    page = report.read_text()
    size = report.stat().st_size
    assert page.count("<tr data-open=") == 10 and page.count("class='crop'") == 10 * 6 * 4
    assert size <= 2_000_000, f"{size / 1e6:.2f} MB for 10 pairs"


def _puppet_folder(folder, sheet_src):
    folder.mkdir()
    shutil.copy(sheet_src, folder / "sheet.jpg")
    rows = [{"run": f"P/clip{i}", "clip": f"clip{i}", "mouth_slope": 1.0 + 0.1 * i, "mouth_r": 0.9, "cheek_de": 3.0 + i,
             "score": [0.0, 1.4, 0.2][i], "failed": [], "media": {"contact_sheet": str(folder / "sheet.jpg")}}
            for i in range(3)]
    (folder / "results.json").write_text(json.dumps({
        "bench": "puppet", "settings": {"targets": {"mouth_slope": [0.8, 1.15], "cheek_de": [None, 8.0]}},
        "rows": rows, "worst_runs": [{"run": "P/clip1", "score": 1.4, "failed": ["mouth_slope"],
                                      "sheet": str(folder / "sheet.jpg")}]}))
    return folder


def test_persona_and_puppet_sections(tmp_path, runs, frl):
    from facetex._resources import sample_path
    from test_report import _persona_folder

    persona = _persona_folder(tmp_path / "persona", "results.json")
    puppet = _puppet_folder(tmp_path / "puppet", sample_path("frl_003_neutral.jpg"))
    out = tmp_path / "r.html"
    assert main(["report", str(runs[0]), str(persona), str(puppet), "-o", str(out), "--data", str(frl), "-q"]) == 0
    page = out.read_text()
    for needed in ("Leave-out (Tom Hanks Fig. 5)", "Puppet runs: targets", "Worst runs&#x27; sheets", "Runs",
                   "Comparison of the runs"):
        assert needed in page, needed
    leave = page[page.index("id='r2-leaveout'"):page.index("id='r2-paired'")]
    assert re.findall(r"<th class='m'>([^<]+)</th>", leave) == ["static", "paper", "ours"]  # Fig. 5 order
    runs_html = page[page.index("id='r3-runs'"):]
    assert "Worst run (highest fail score, the red row): <b>run P/clip1</b>" in runs_html
    assert re.search(r"<tr data-open='r3-1' class='highlight'>", runs_html)
    # targets: mouth slope 0.8-1.15 met by 2 of 3 runs (1.0, 1.1; not 1.2)
    assert re.search(r"mouth slope</th>.*?<td>0.8–1.150?</td><td>2 of 3</td>", page)



def test_same_runs_give_the_same_bytes(tmp_path, runs, frl):
    """The page is a function of the run folders: no random SVG ids, dates or dict orders."""
    pages = []
    for k in range(2):
        out = tmp_path / f"r{k}.html"
        assert main(["report", str(runs[0]), "-o", str(out), "--data", str(frl), "-q"]) == 0
        pages.append(out.read_bytes())
    assert "<svg" in pages[0].decode() or "image/svg+xml" in pages[0].decode()
    assert pages[0] == pages[1]


def test_paper_values_are_shown_as_printed(runs, frl):
    """FaceTex Table 1's numbers appear with the paper's own digits (106.17, not a rounded 106.2)."""
    from facetex.bench.transfer import PAPER_TABLE1

    run = load_runs([runs[0]], also=[frl])[0]
    t1 = re.search(r"<table class='t1'>.*?</table>", build_report([run]), re.S).group(0)
    shown = re.findall(r"<td class='paper'>([^<]+)</td>", t1)
    assert "106.17" in shown and "191.47" in shown
    printed = {format(v, ".10g") for m in PAPER_TABLE1.values() for v in m.values()}
    assert {s for s in shown if s != "–"} <= printed
