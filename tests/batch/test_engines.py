"""The local engine: worker processes with their own thread budget; a dead worker fails only its
item; cancel and close leave no process."""

from __future__ import annotations

import os

import pytest

import _tasks
from facetex.batch.engines import InlineEngine, LocalEngine, Resources, make_engine


def _drain(engine, n):
    out = []
    while len(out) < n:
        got = engine.wait(timeout=60)
        assert got, "the engine returned nothing within 60 s"
        out += got
    return {o.handle: o for o in out}


def test_local_workers_run_items_with_their_thread_budget(no_leftover_processes):
    with LocalEngine(2, threads=1) as eng:
        hs = [eng.submit(_tasks.square, {"x": x}) for x in range(6)]
        res = _drain(eng, 6)
    assert [res[h].value["value"] for h in hs] == [x * x for x in range(6)]
    assert {res[h].value["threads"] for h in hs} == {"1"}  # OMP_NUM_THREADS = cpus // workers
    assert len({res[h].value["pid"] for h in hs}) == 2 and os.getpid() not in {res[h].value["pid"] for h in hs}
    assert all(res[h].stats["seconds"] >= 0 and res[h].stats["peak_rss_mb"] > 0 for h in hs)


@pytest.mark.parametrize("threads", [1, 2])
def test_every_thread_pool_of_a_worker_follows_the_item_budget(threads, monkeypatch, no_leftover_processes):
    """OpenCV's own pthreads pool (it ignores OMP_NUM_THREADS) gets the item's budget too: with
    one per core in each of 2 one-thread workers, 4 threads ran on 2 cores and a transfer took
    7 % more CPU (same bytes). OpenMP threads sleep when they wait, as under the command line."""
    monkeypatch.delenv("OMP_WAIT_POLICY", raising=False)
    with LocalEngine(1, threads=threads) as eng:
        hs = [eng.submit(_tasks.thread_pools, {}, Resources(cpus=0)) for _ in range(2)]  # 2nd: cv2, torch imported
        res = _drain(eng, 2)
    assert [(res[h].value["cv2"], res[h].value["torch"]) for h in hs] == [(threads, threads)] * 2
    assert {res[h].value["wait_policy"] for h in hs} == {"PASSIVE"}
    assert all(res[h].stats["cpu_s"] >= 0 and res[h].stats["started"] > 0 for h in hs)
    monkeypatch.setenv("OMP_WAIT_POLICY", "ACTIVE")  # the user's choice is kept
    with LocalEngine(1, threads=1) as eng:
        eng.submit(_tasks.thread_pools, {})
        (o,) = _drain(eng, 1).values()
    assert o.value["wait_policy"] == "ACTIVE"


def test_item_errors_are_one_line_and_do_not_stop_the_worker(no_leftover_processes):
    with LocalEngine(1, threads=1) as eng:
        h1, h2, h3 = eng.submit(_tasks.fail, {}), eng.submit(_tasks.crash, {}), eng.submit(_tasks.square, {"x": 3})
        res = _drain(eng, 3)
    assert not res[h1].ok and not res[h1].died and res[h1].error == "in.jpg: this item is bad second line"
    assert res[h1].error_type == "BadInputError"
    assert res[h2].error == "ZeroDivisionError: division by zero in the item"
    assert res[h3].ok and res[h3].value["value"] == 9


def test_a_dead_worker_fails_only_its_item_and_is_replaced(no_leftover_processes):
    with LocalEngine(2, threads=1) as eng:
        hs = [eng.submit(_tasks.square, {"x": 1}), eng.submit(_tasks.always_die, {}),
              eng.submit(_tasks.square, {"x": 2}), eng.submit(_tasks.square, {"x": 3})]
        res = _drain(eng, 4)
    dead = res[hs[1]]
    assert not dead.ok and dead.died and "SIGKILL" in dead.error
    assert [res[h].value["value"] for h in (hs[0], hs[2], hs[3])] == [1, 4, 9]


def test_cancel_stops_running_items_and_removes_their_temporary_files(tmp_path, no_leftover_processes):
    eng = LocalEngine(2, threads=1).start()
    try:
        for k in range(2):
            eng.submit(_tasks.slow_write, {"output": str(tmp_path / f"out{k}.txt"),
                                           "started": str(tmp_path / f"started{k}")})
        import time

        t0 = time.monotonic()
        while not all((tmp_path / f"started{k}").exists() for k in range(2)):
            assert time.monotonic() - t0 < 60
            time.sleep(0.1)
        assert any(p.name.startswith(".out") for p in tmp_path.iterdir())  # the writers' temporary files
        eng.cancel()
    finally:
        eng.close()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["started0", "started1"]


def test_make_engine_choices():
    assert isinstance(make_engine("local", jobs=1, inline_single=True), InlineEngine)
    e = make_engine("local", jobs=2, cpus_per_item=1)
    assert isinstance(e, LocalEngine) and e.slots == 2 and e.threads == 1
    from facetex.errors import BadInputError

    with pytest.raises(BadInputError, match="--address"):
        make_engine("local", address="auto")
    with pytest.raises(BadInputError, match="unknown engine"):
        make_engine("dask")


def test_inline_engine_runs_in_this_process():
    eng = InlineEngine()
    h = eng.submit(_tasks.square, {"x": 4}, Resources())
    (o,) = eng.wait()
    assert o.handle == h and o.value["pid"] == os.getpid() and o.value["value"] == 16


def test_ray_task_options_request_the_measured_memory_and_gpus():
    from facetex.batch import transfer_items
    from facetex.batch.engines import ray_task_options
    from facetex._resources import sample_path

    a, b = str(sample_path("frl_004_neutral.jpg")), str(sample_path("frl_005_neutral.jpg"))
    it, = transfer_items([{"content": a, "style": b}], "/tmp/never-written", size=512, device="cuda")
    assert it.resources.gpus == 1.0 and it.resources.memory_mb == 510 + 512 ** 2 / 1000  # measured: 774 MB
    opts = ray_task_options(it.resources, name="run_transfer_item")
    assert opts["num_gpus"] == 1.0 and opts["num_cpus"] == 1 and opts["memory"] == int(it.resources.memory_mb * 2**20)
    assert opts["max_retries"] == 0 and opts["name"] == "facetex:run_transfer_item"
    # a larger peak measured in the run raises the request; the largest node caps it
    assert ray_task_options(it.resources, observed_mb=1000)["memory"] == int(1250 * 2**20)
    assert ray_task_options(it.resources, observed_mb=1000, node_memory_mb=900)["memory"] == int(900 * 2**20)
    from facetex.batch.engines import Resources

    assert "memory" not in ray_task_options(Resources(cpus=2), cpus_per_item=1)  # nothing known: no request
    assert ray_task_options(Resources(cpus=0), cpus_per_item=3, gpus_per_item=0.5)["num_cpus"] == 3


def test_runtime_env_option(tmp_path, capsys):
    from facetex._resources import sample_path
    from facetex.cli import main
    from facetex.cli._common import runtime_env

    f = tmp_path / "env.json"
    f.write_text('{"pip": ["facetex[s3]"], "env_vars": {"AWS_ENDPOINT_URL": "http://minio:9000"}}')
    assert runtime_env(str(f))["pip"] == ["facetex[s3]"] and runtime_env('{"working_dir": "."}')
    samples = str(sample_path())
    assert main(["batch", "transfer", "--contents", samples, "--styles", samples, "--out", str(tmp_path / "o"),
                 "--runtime-env", '{"pip": []}']) == 2
    assert "--runtime-env is for --engine ray" in capsys.readouterr().err
    assert main(["batch", "transfer", "--contents", samples, "--styles", samples, "--out", str(tmp_path / "o"),
                 "--engine", "ray", "--runtime-env", "[1]"]) == 2
    assert "argument --runtime-env: give a JSON object" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_opencv_thread_count_does_not_change_a_transfer():
    """The workers give OpenCV the item's thread budget (1 by default, was one per core): the
    README says that changes no byte, whatever OpenCV's pool size."""
    import cv2

    import facetex
    from facetex._resources import sample_path

    a, b = (str(sample_path(n)) for n in ("frl_004_neutral.jpg", "frl_005_neutral.jpg"))
    saved = cv2.getNumThreads()
    outs = []
    try:
        for n in (1, 2):
            cv2.setNumThreads(n)
            outs.append(facetex.transfer(a, b, size=96, iters=(2, 2, 2), seed=0))
    finally:
        cv2.setNumThreads(saved)
    assert outs[0].tobytes() == outs[1].tobytes()
