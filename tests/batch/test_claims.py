"""Claims on items: exclusive across processes, expired after a timeout or when the holder is gone."""

from __future__ import annotations

import json
import multiprocessing
import os
import time

import pytest

from facetex.batch._claims import Claims


def test_one_claimer_wins_and_release_frees(tmp_path):
    a, b = Claims(tmp_path, timeout=60), Claims(tmp_path, timeout=60)
    ca = a.acquire("item1")
    assert ca is not None and ca.path.exists()
    assert a.acquire("item1") is ca  # held already
    assert b.acquire("item1") is None
    info = b.holder("item1")
    assert info["run"] == a.run and info["pid"] == os.getpid() and not info["expired"]
    a.release("item1")
    assert b.holder("item1") is None and not list(tmp_path.iterdir())
    assert b.acquire("item1") is not None


def test_expired_claim_is_taken_by_the_next_generation(tmp_path):
    a, b = Claims(tmp_path, timeout=5), Claims(tmp_path, timeout=5)
    ca = a.acquire("k")
    old = time.time() - 60
    os.utime(ca.path, (old, old))  # its run stopped refreshing it a minute ago
    a.held.clear()  # (that run is gone)
    cb = b.acquire("k")
    assert cb is not None and cb.generation == ca.generation + 1
    assert Claims(tmp_path, timeout=5).acquire("k") is None  # the new claim is live
    b.release("k")
    assert not list(tmp_path.iterdir())  # the holder removes the expired generation too


def test_heartbeat_keeps_a_claim_alive(tmp_path):
    a = Claims(tmp_path, timeout=5)
    c = a.acquire("k")
    old = time.time() - 60
    os.utime(c.path, (old, old))
    a.heartbeat()
    assert not Claims(tmp_path, timeout=5).holder("k")["expired"]


def test_claim_of_a_dead_process_on_this_host_expires_at_once(tmp_path):
    p = multiprocessing.get_context("spawn").Process(target=_claim_and_exit, args=(str(tmp_path),))
    p.start()
    p.join(60)
    assert p.exitcode == 0
    info = Claims(tmp_path, timeout=3600).holder("k")
    assert info is not None and info["pid"] == p.pid and info["expired"]
    assert Claims(tmp_path, timeout=3600).acquire("k") is not None


def _claim_and_exit(folder):
    Claims(folder, timeout=3600).acquire("k")  # and never release


def test_claim_of_another_host_waits_for_the_timeout(tmp_path):
    (tmp_path / "k.0").write_text(json.dumps({"run": "r", "host": "elsewhere", "pid": 1}))
    assert Claims(tmp_path, timeout=30).acquire("k") is None  # fresh: that host is working on it
    old = time.time() - 31
    os.utime(tmp_path / "k.0", (old, old))
    assert Claims(tmp_path, timeout=30).acquire("k") is not None


def _race(folder, keys, out, barrier):
    c = Claims(folder, timeout=3600)
    barrier.wait()
    won = [k for k in keys if c.acquire(k) is not None]
    with open(out, "w") as fh:
        fh.write("\n".join(won))
    # stay alive until every racer is done: a claim of a process of this host that has exited
    # has expired (by design), so a slower racer would rightly take it over
    barrier.wait()


@pytest.mark.parametrize("stale", [False, True])
def test_concurrent_claimers_one_winner_per_item(tmp_path, stale):
    keys = [f"item{i}" for i in range(40)]
    folder = tmp_path / "claims"
    folder.mkdir()
    if stale:  # every item has an expired claim of another host: all racers try to take it over
        for k in keys:
            (folder / f"{k}.0").write_text(json.dumps({"host": "gone", "pid": 1}))
            os.utime(folder / f"{k}.0", (1, 1))
    ctx = multiprocessing.get_context("spawn")
    barrier = ctx.Barrier(4)
    procs = [ctx.Process(target=_race, args=(str(folder), keys, str(tmp_path / f"won{i}"), barrier))
             for i in range(4)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(120)
    won = [k for i in range(4) for k in (tmp_path / f"won{i}").read_text().split()]
    assert sorted(won) == sorted(keys)  # every item claimed, and by exactly one racer
