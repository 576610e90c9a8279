"""Issue 23: run folders and batch state of the wrong shape (a list where an object belongs, a
string for the settings, a folder for a table, bytes that are not UTF-8, ...) are one error line
naming the file and the wrong field, never an internal error."""

from __future__ import annotations

import json
import os

import pytest

from _robust import FACE, OTHER, assert_one_error, bench_run_folder, run_cli, snapshot

pytestmark = pytest.mark.timeout(120)


def _edit_results(change):
    def edit(run):
        rec = json.loads((run / "results.json").read_text())
        change(rec)
        (run / "results.json").write_text(json.dumps(rec))
    return edit


def _write(rel, data):
    def edit(run):
        (run / rel).write_bytes(data if isinstance(data, bytes) else json.dumps(data).encode())
    return edit


def _pair(**fields):
    return _edit_results(lambda rec: rec["pairs"][0].update(fields))


def _result(**fields):
    return _edit_results(lambda rec: rec["pairs"][0]["results"]["facetex"].update(fields))


REPORT_CASES = {  # name: (edit of a good run folder, file named, cause)
    "results-list": (_write("results.json", [1, 2]), "results.json", "whole file must be a JSON object, not a list"),
    "results-not-json": (_write("results.json", b'{"bench": "transfer", '), "results.json", "unreadable JSON"),
    "results-not-utf8": (_write("results.json", b'{"bench": "\xff\xfe"}'), "results.json", "not a UTF-8 text file"),
    "pairs-object": (_edit_results(lambda r: r.update(pairs={})), "results.json",
                     "pairs must be a list, not a JSON object"),
    "pairs-number": (_edit_results(lambda r: r.update(pairs=[7])), "results.json",
                     r"pairs\[0\] must be a JSON object, not an integer"),
    "pair-no-content": (_edit_results(lambda r: r["pairs"][0].pop("content")), "results.json",
                        "'content' is a required property"),
    "settings-string": (_edit_results(lambda r: r.update(settings="abc")), "results.json",
                        "settings must be a JSON object, not a string"),
    "paper-list": (_edit_results(lambda r: r.update(paper_table1=[1])), "results.json", "paper_table1"),
    "style-path-number": (_pair(style_path=3), "results.json", "style_path must be a string"),
    "results-list-of-methods": (_pair(results=["facetex"]), "results.json", "results must be a JSON object"),
    "image-number": (_result(image=5), "results.json", "image"),
    "metrics-list": (_result(metrics=[1, 2]), "results.json", "metrics"),
    "run-json-list": (_write("run.json", [1]), "run.json", "whole file must be a JSON object, not a list"),
    "run-json-command-number": (_write("run.json", {"command": 3}), "run.json", "command must be a string"),
    "sidecar-list": (_write("images/a__b__facetex.json", []), "a__b__facetex.json", "must be a JSON object"),
    "sidecar-params-string": (_write("images/a__b__facetex.json", {"params": "x"}), "a__b__facetex.json", "params"),
    "table-not-utf8": (_write("table.md", b"| a |\n|---|\n| \xff\xfe |\n"), "table.md", "not a UTF-8 text file"),
}


@pytest.mark.parametrize("command", ["report", "compare"])
@pytest.mark.parametrize("case", sorted(REPORT_CASES))
def test_report_and_compare_of_wrong_shaped_run_folders(tmp_path, capsys, command, case):
    edit, name, cause = REPORT_CASES[case]
    good, run = bench_run_folder(tmp_path / "good"), bench_run_folder(tmp_path / "run")
    edit(run)
    before = snapshot(tmp_path)
    out = tmp_path / "r.html"
    argv = ["report", run, "-o", out] if command == "report" else ["compare", good, run]
    r = run_cli(capsys, *argv)
    assert_one_error(r, names=[name], cause=cause)
    assert snapshot(tmp_path) == before  # nothing written


def test_a_folder_named_like_a_table_is_skipped(tmp_path, capsys):
    run = bench_run_folder(tmp_path / "run")
    (run / "table_x.md").mkdir()
    r = run_cli(capsys, "report", run, "-o", tmp_path / "r.html")
    assert r.code == 0 and not r.lines and "table_x.md" in r.err, r.err


@pytest.mark.parametrize("method", ["$\\foo$", "$x^{$", "a$b"])
def test_method_names_are_not_mathtext(tmp_path, capsys, method):
    run = bench_run_folder(tmp_path / "run")
    _edit_results(lambda r: r["pairs"][0]["results"].update({method: {"metrics": {"E_content": 2.0}}}))(run)
    r = run_cli(capsys, "report", run, "-o", tmp_path / "r.html")
    assert r.code == 0 and not r.lines, r.err
    assert method.replace("$", "") in (tmp_path / "r.html").read_text().replace("$", "")


def test_demo_and_outputs_folders_of_the_wrong_shape(tmp_path, capsys):
    demo = tmp_path / "demo"
    demo.mkdir()
    (demo / "transfer_facetex.png").write_bytes(b"")
    (demo / "summary.json").write_text(json.dumps({"inputs": {"content": 4}, "transfers": {}}))
    assert_one_error(run_cli(capsys, "report", demo, "-o", tmp_path / "r.html"), names=["summary.json"],
                     cause="inputs.content must be a string")
    outs = tmp_path / "outs"
    outs.mkdir()
    (outs / "a.png").write_bytes(b"png")
    (outs / "a.png.json").write_text(json.dumps({"inputs": {"content": "x.jpg"}}))
    assert_one_error(run_cli(capsys, "compare", outs, outs), names=["a.png.json"],
                     cause="inputs.content must be a JSON object or null|inputs.content")


# --------------------------------------------------------------------------------- batch state
KEY = "frl_004_neutral__frl_005_neutral__facetex"
T = ["--size", "64", "--iters", "2", "--jobs", "1"]


def _state_file(rel, data):
    def make(out):
        p = out / ".facetex-batch" / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        if data == "fifo":
            os.mkfifo(p)
        else:
            p.write_bytes(data if isinstance(data, bytes) else json.dumps(data).encode())
        return p.name
    return make


def _internal_is_a_file(out):
    (out / ".facetex-batch").write_text("not a folder\n")
    return ".facetex-batch"


def _manifest(kind):
    def make(out):
        if kind == "folder":
            (out / "manifest.jsonl").mkdir()
        else:
            os.mkfifo(out / "manifest.jsonl")
        return "manifest.jsonl"
    return make


BATCH_CASES = {
    "manifest-folder": (_manifest("folder"), "is a directory"),
    "manifest-fifo": (_manifest("fifo"), "FIFO"),
    "internal-is-a-file": (_internal_is_a_file, "exists and is not a folder"),
    "items-is-a-file": (_state_file("items", b"x"), "exists and is not a folder"),
    "record-list": (_state_file(f"items/{KEY}.json", []), "batch item record: the whole file must be a JSON object"),
    "record-number": (_state_file(f"items/{KEY}.json", 42), "batch item record: the whole file must be a JSON object"),
    "record-not-json": (_state_file(f"items/{KEY}.json", b"{"), "batch item record: unreadable JSON"),
    "record-bad-state": (_state_file(f"items/{KEY}.json", {"state": "maybe"}), "state: 'maybe' is not one of"),
    "record-run-list": (_state_file(f"items/{KEY}.json", {"state": "failed", "run": [1]}), "run must be"),
    "record-fifo": (_state_file(f"items/{KEY}.json", "fifo"), r"not a batch item record \(not a regular file"),
    "claim-list": (_state_file(f"claims/{KEY}.0", [1]), "batch claim: the whole file must be a JSON object"),
    "claim-pid-string": (_state_file(f"claims/{KEY}.0", {"pid": "1"}), "pid must be an integer"),
    "claim-fifo": (_state_file(f"claims/{KEY}.0", "fifo"), r"not a batch claim \(not a regular file"),
    "settings-list": (_state_file("settings.json", [1]), "batch settings record: the whole file must be a JSON object"),
}


@pytest.mark.parametrize("case", sorted(BATCH_CASES))
def test_batch_state_of_the_wrong_shape(tmp_path, capsys, case):
    make, cause = BATCH_CASES[case]
    (tmp_path / "pairs.csv").write_text(f"content,style\n{FACE},{OTHER}\n")
    out = tmp_path / "o"
    out.mkdir()
    name = make(out)
    fifo = "fifo" in case or "manifest" in case
    before = sorted(os.listdir(out)) if fifo else snapshot(out)
    r = run_cli(capsys, "batch", "transfer", tmp_path / "pairs.csv", "--out", out, *T)
    assert_one_error(r, names=[name], cause=cause)
    assert (sorted(os.listdir(out)) if fifo else snapshot(out)) == before  # refused before any work
