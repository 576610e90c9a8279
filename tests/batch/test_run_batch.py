"""run_batch: resuming, failures, worker deaths, settings clashes, interrupts and concurrent runs on
one folder, with cheap items on the local engine (the real workloads: test_cli_batch.py)."""

from __future__ import annotations

import json
import multiprocessing
import time
from pathlib import Path

import pytest

import _tasks
from facetex.batch import Item, LocalEngine, run_batch
from facetex.errors import OutputError


def _items(out: Path, n: int = 4, log: Path | None = None, **extra) -> list[Item]:
    items = []
    for i in range(n):
        key = f"item{i}"
        payload = {"name": key, "output": str(out / f"{key}.txt"), "log": str(log) if log else None, **extra}
        if isinstance(extra.get("fail"), set):
            payload["fail"] = key in extra["fail"]
        items.append(Item(key, "test", _tasks.write_item, payload, (payload["output"], payload["output"] + ".json"),
                          {"name": key, "value": extra.get("value", 0)}))
    return items


def _manifest(out: Path) -> dict:
    return {r["item"]: r for r in map(json.loads, (out / "manifest.jsonl").read_text().splitlines())}


def _computed(log: Path) -> list[str]:
    return sorted(line.split()[0] for line in log.read_text().splitlines()) if log.exists() else []


def test_resume_skips_finished_items(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    with LocalEngine(2, threads=1) as eng:
        s = run_batch(_items(out, log=log), out, eng)
    assert (s.done, s.failed, s.remaining, s.skipped_done) == (4, 0, 0, 0) and s.ok
    assert sorted(s.computed) == [f"item{i}" for i in range(4)]
    m = _manifest(out)
    assert sorted(m) == [f"item{i}" for i in range(4)]
    assert all(r["state"] == "done" and r["host"] and r["time"] and r["error"] is None and r["attempts"] == 1
               for r in m.values())
    assert (out / "item0.txt").read_text() == "item0 0\n" and (out / "item0.txt.json").exists()
    assert not list((out / ".facetex-batch" / "claims").iterdir())  # every claim released
    with LocalEngine(2, threads=1) as eng:
        s2 = run_batch(_items(out, log=log), out, eng)
    assert (s2.done, s2.skipped_done) == (0, 4) and s2.ok
    assert _computed(log) == [f"item{i}" for i in range(4)]  # nothing computed twice
    runs = list((out / ".facetex-batch" / "runs").glob("*.json"))
    assert len(runs) == 2 and all(json.loads(r.read_text())["summary"]["total"] == 4 for r in runs)


def test_failed_items_are_recorded_and_retried_on_request(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    with LocalEngine(2, threads=1) as eng:
        s = run_batch(_items(out, log=log, fail={"item1"}), out, eng)
        assert (s.done, s.failed) == (3, 1) and not s.ok
        assert s.failures == [("item1", "ValueError: item item1 cannot be done")]
        m = _manifest(out)
        assert m["item1"]["state"] == "failed" and m["item1"]["error"] == "ValueError: item item1 cannot be done"
        assert not (out / "item1.txt").exists() and not [p for p in out.iterdir() if p.name.startswith(".item")]
        s = run_batch(_items(out, log=log), out, eng)  # the cause is fixed, but failed items stay failed ...
        assert (s.done, s.skipped_done, s.skipped_failed) == (0, 3, 1)
        s = run_batch(_items(out, log=log), out, eng, retry_failed=True)  # ... until asked
        assert (s.done, s.skipped_done, s.failed) == (1, 3, 0) and s.ok
    assert _manifest(out)["item1"]["state"] == "done"
    assert _computed(log) == [f"item{i}" for i in range(4)]


def test_a_killed_worker_fails_only_its_item_which_is_retried(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    items = _items(out, log=log, sleep=0.2)
    items[2].payload["die_marker"] = str(tmp_path / "died")
    with LocalEngine(2, threads=1) as eng:
        s = run_batch(items, out, eng, max_retries=2)
    assert (s.done, s.failed, s.retried) == (4, 0, 1)
    assert (tmp_path / "died").exists() and _computed(log) == [f"item{i}" for i in range(4)]
    assert _manifest(out)["item2"]["attempts"] == 2


def test_retries_are_bounded(tmp_path, no_leftover_processes):
    out = tmp_path / "out"
    out.mkdir()
    it = Item("doomed", "test", _tasks.always_die, {}, (str(out / "doomed.txt"),), {"x": 1})
    with LocalEngine(1, threads=1) as eng:
        s = run_batch([it], out, eng, max_retries=1)
    assert (s.done, s.failed, s.retried) == (0, 1, 1)
    err = _manifest(out)["doomed"]["error"]
    assert "killed by SIGKILL" in err and "attempt 2 of 2" in err


def test_finished_items_of_other_settings_are_refused_before_any_work(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    with LocalEngine(1, threads=1) as eng:
        run_batch(_items(out, n=2, log=log), out, eng)
        with pytest.raises(OutputError, match=r"holds 2 item\(s\) made with other settings .*value: 0 -> 1"):
            run_batch(_items(out, n=2, log=log, value=1), out, eng)
    assert _computed(log) == ["item0", "item1"]


def test_half_committed_item_and_stale_temporaries_are_redone(tmp_path, no_leftover_processes):
    from facetex.batch import run_tag
    from facetex.batch._state import BatchState

    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    # a commit killed between its renames leaves the sidecar (committed first), which names its item
    (out / "item0.txt.json").write_text('{"batch": {"run": "killed-run", "item": "item0"}}')
    state = BatchState(out)
    state.create()
    state.put("item0", {"kind": "test", "state": "running", "run": "killed-run"})
    stale = out / f".item0.txt.{run_tag('killed-run')}.abcd1234.json"
    stale.write_text("the killed run's temporary file")
    (out / ".item0.txt.abcd1234.json").write_text("untagged: not a temporary of a batch run")
    (out / ".item10.txt.keep").write_text("another item's name: not touched")
    with LocalEngine(1, threads=1) as eng:
        s = run_batch(_items(out, n=1, log=log), out, eng)
    assert s.done == 1 and (out / "item0.txt").read_text() == "item0 0\n"
    assert not stale.exists() and (out / ".item0.txt.abcd1234.json").exists() and (out / ".item10.txt.keep").exists()


def test_an_output_without_its_sidecar_is_refused_not_replaced(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    (out / "item1.txt").write_text("MINE")
    with LocalEngine(1, threads=1) as eng:
        with pytest.raises(OutputError, match=r"item1.txt: exists without its sidecar item1.txt.json"):
            run_batch(_items(out, n=2, log=log), out, eng)
    assert (out / "item1.txt").read_text() == "MINE" and not log.exists()


def test_interrupt_cancels_running_items_and_leaves_them_pending(tmp_path, no_leftover_processes):
    out = tmp_path / "out"
    out.mkdir()
    items = [Item(f"slow{k}", "test", _tasks.slow_write,
                  {"output": str(out / f"slow{k}.txt"), "started": str(tmp_path / f"started{k}")},
                  (str(out / f"slow{k}.txt"), str(out / f"slow{k}.txt.json")), {"k": k}) for k in range(3)]

    def progress(**counts):
        if counts["running"] == 2 and all((tmp_path / f"started{k}").exists() for k in range(2)):
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        with LocalEngine(2, threads=1) as eng:
            deadline = time.monotonic() + 60

            def progress_or_timeout(**counts):
                assert time.monotonic() < deadline
                progress(**counts)

            run_batch(items, out, eng, progress=progress_or_timeout, poll=0.2)
    assert sorted(p.name for p in out.iterdir()) == [".facetex-batch", "manifest.jsonl"]  # no partial output
    m = _manifest(out)
    assert m["slow0"]["state"] == "pending" and m["slow0"]["error"] == "interrupted"
    assert m["slow2"]["state"] == "pending"
    assert not list((out / ".facetex-batch" / "claims").iterdir())


def _run_in_process(out, log, result):
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    import _tasks as tasks  # noqa: F401 - the workers import it by name

    with LocalEngine(1, threads=1) as eng:
        s = run_batch(_items(Path(out), n=10, log=Path(log), sleep=0.3), out, eng, poll=0.2)
    Path(result).write_text(json.dumps({"computed": s.computed, "done": s.done, "elsewhere": s.done_elsewhere,
                                        "remaining": s.remaining, "failed": s.failed}))


def test_two_concurrent_runs_compute_each_item_once(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    ctx = multiprocessing.get_context("spawn")
    procs = [ctx.Process(target=_run_in_process, args=(str(out), str(log), str(tmp_path / f"r{i}"))) for i in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(180)
        assert p.exitcode == 0
    r = [json.loads((tmp_path / f"r{i}").read_text()) for i in range(2)]
    assert _computed(log) == sorted(f"item{i}" for i in range(10))  # each computed exactly once
    assert not set(r[0]["computed"]) & set(r[1]["computed"])
    assert r[0]["done"] + r[1]["done"] == 10 and r[0]["done"] and r[1]["done"]  # both did work
    assert all(x["remaining"] == 0 and x["failed"] == 0 and x["done"] + x["elsewhere"] == 10 for x in r)
    assert all(rec["state"] == "done" for rec in _manifest(out).values())


def test_manifest_is_appended_with_relative_paths_and_records_only_failures(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    with LocalEngine(2, threads=1) as eng:
        run_batch(_items(out, log=log, fail={"item1"}), out, eng)
        first = (out / "manifest.jsonl").read_bytes()
        lines = [json.loads(x) for x in first.splitlines()]
        assert [x["state"] for x in lines if x["item"] == "item0"] == ["pending", "running", "done"]
        assert _manifest(out)["item0"]["outputs"] == ["item0.txt", "item0.txt.json"]  # relative to the folder
        # a record only where one is needed: the failed item
        assert sorted(p.name for p in (out / ".facetex-batch" / "items").iterdir()) == ["item1.json"]
        run_batch(_items(out, log=log), out, eng, retry_failed=True)
    second = (out / "manifest.jsonl").read_bytes()
    assert second.startswith(first) and len(second) > len(first)  # appended to, never rewritten
    assert not list((out / ".facetex-batch" / "items").iterdir())  # done now: its record is gone
    assert _manifest(out)["item1"]["state"] == "done"


def test_a_moved_folder_resumes(tmp_path, no_leftover_processes):
    out, log = tmp_path / "out", tmp_path / "log"
    out.mkdir()
    with LocalEngine(2, threads=1) as eng:
        s = run_batch(_items(out, log=log, fail={"item2"}), out, eng)
    assert s.done == 3
    moved = tmp_path / "elsewhere" / "moved"
    moved.parent.mkdir()
    out.rename(moved)
    with LocalEngine(2, threads=1) as eng:
        s = run_batch(_items(moved, log=log), moved, eng, retry_failed=True)
    assert (s.done, s.skipped_done, s.failed) == (1, 3, 0) and s.computed == ["item2"]
    assert _computed(log) == [f"item{i}" for i in range(4)]  # nothing computed twice
    m = _manifest(moved)
    assert all(r["state"] == "done" for r in m.values()) and m["item2"]["outputs"] == ["item2.txt", "item2.txt.json"]
    assert not any(str(tmp_path / "out") in line for line in (moved / "manifest.jsonl").read_text().splitlines()
                   if '"item2"' in line)


def test_status_counts_groups_failures_and_lists_the_slowest(tmp_path, capsys, no_leftover_processes):
    from facetex.batch._status import batch_status
    from facetex.cli import main

    out = tmp_path / "out"
    out.mkdir()
    items = _items(out, n=5, fail={"item1", "item3"})
    items[4].payload["sleep"] = 1.0
    with LocalEngine(2, threads=1) as eng:
        run_batch(items, out, eng)
    s = batch_status(out, slowest=2)
    assert s["total"] == 5 and s["counts"] == {"pending": 0, "running": 0, "done": 3, "failed": 2}
    # one cause on two items: one group
    assert s["failures"] == [{"error": "ValueError: item item1 cannot be done", "count": 2,
                              "items": ["item1", "item3"]}]
    assert s["slowest"][0]["item"] == "item4" and s["slowest"][0]["seconds"] >= 1.0 and len(s["slowest"]) == 2
    assert s["throughput"]["done"] == 3 and len(s["runs"]) == 1 and s["runs"][0]["done"] == 3
    assert main(["batch", "status", str(out), "-o", str(tmp_path / "status.json")]) == 0
    text = capsys.readouterr().out
    assert "5 items: 3 done, 2 failed, 0 running, 0 pending" in text and "2 × ValueError" in text
    assert json.loads((tmp_path / "status.json").read_text())["counts"]["failed"] == 2
    assert main(["batch", "status", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "not a batch folder (no manifest.jsonl)" in err and len(err.strip().splitlines()) == 1
