"""The forked child whose results the puppet's second pass takes as futures."""

import os
import sys

import pytest

from facetex.errors import BadInputError
from facetex.puppet._forked import ForkedResults, fork_available

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="fork: Linux only")


def test_values_arrive_by_key_and_the_final_value_at_the_end():
    parent = os.getpid()

    def produce(receive):
        for k in (3, 1, 2):
            yield k, (k * k, os.getpid())
        return {"done": True}

    child = ForkedResults(produce, [1, 2, 3])
    try:
        got = {k: child.future(k).result(timeout=30) for k in (1, 2, 3)}
        assert {k: v[0] for k, v in got.items()} == {1: 1, 2: 4, 3: 9}
        assert all(v[1] != parent for v in got.values())  # computed in another process
        assert child.result() == {"done": True}
    finally:
        child.close()


def test_a_childs_facetex_error_keeps_its_class_message_and_file():
    def produce(receive):
        yield 0, "first"
        raise BadInputError("no face in this frame", path="/tmp/clip.mp4")

    child = ForkedResults(produce, [0, 1])
    try:
        assert child.future(0).result(timeout=30) == "first"
        with pytest.raises(BadInputError) as e:
            child.future(1).result(timeout=30)
        assert e.value.path == "/tmp/clip.mp4" and "no face in this frame" in str(e.value)
        with pytest.raises(BadInputError):
            child.result()
    finally:
        child.close()


def test_a_child_that_dies_fails_the_pending_futures():
    def produce(receive):
        yield 0, 1
        os._exit(3)  # killed, say: no message

    child = ForkedResults(produce, [0, 1])
    try:
        assert child.future(0).result(timeout=30) == 1
        with pytest.raises(RuntimeError, match="ended unexpectedly"):
            child.future(1).result(timeout=30)
    finally:
        child.close()


def test_close_stops_a_child_that_has_not_finished():
    import time

    def produce(receive):
        yield 0, 0
        time.sleep(60)
        yield 1, 1

    child = ForkedResults(produce, [0, 1])
    t = time.perf_counter()
    assert child.future(0).result(timeout=30) == 0
    child.close()
    assert time.perf_counter() - t < 20 and not child._proc.is_alive()


def test_fork_is_only_offered_on_the_main_thread():
    import threading

    seen = []
    th = threading.Thread(target=lambda: seen.append(fork_available()))
    th.start()
    th.join()
    assert seen == [False]
    assert fork_available() is True  # pytest runs tests on the main thread, on Linux


def test_the_child_waits_while_ahead_values_are_not_taken():
    import time

    def produce(receive):
        for k in range(6):
            yield k, time.perf_counter()

    child = ForkedResults(produce, range(6), ahead=2)
    try:
        assert child.future(1).result(timeout=30) > 0
        time.sleep(0.5)
        assert not child.future(2).done()  # two sent, none taken: the child waits
        child.taken(0)
        assert 0 not in child._futures  # let go: a long video's frames are not all kept
        assert child.future(2).result(timeout=30) > 0  # sent after the credit
        time.sleep(0.3)
        assert not child.future(3).done()
        for k in range(1, 6):  # each taken once it has come, as the puppet does
            assert child.future(k).result(timeout=30) > 0
            child.taken(k)
        assert child._futures == {}
    finally:
        child.close()


def test_a_child_waiting_for_credit_ends_with_its_killed_parent(tmp_path):
    """A parent killed outright (SIGKILL, no cleanup) must not leave its child waiting forever."""
    import signal
    import subprocess
    import textwrap
    import time

    script = tmp_path / "parent.py"
    script.write_text(textwrap.dedent('''
        import os, sys, time
        from facetex.puppet._forked import ForkedResults
        def produce(receive):
            for k in range(5):
                yield k, k
        child = ForkedResults(produce, range(5), ahead=1)
        child.future(0).result(timeout=30)
        print(child._proc.pid, flush=True)
        time.sleep(60)
    '''))
    parent = subprocess.Popen([sys.executable, str(script)], stdout=subprocess.PIPE, text=True)
    try:
        pid = int(parent.stdout.readline())
        os.kill(parent.pid, signal.SIGKILL)
        parent.wait(timeout=30)
        deadline = time.time() + 20
        while time.time() < deadline and os.path.exists(f"/proc/{pid}") and "Z" not in _state(pid):
            time.sleep(0.1)
        assert not os.path.exists(f"/proc/{pid}") or "Z" in _state(pid)
    finally:
        parent.kill()


def _state(pid: int) -> str:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "Z"


def test_the_parent_sends_objects_the_child_receives_in_order_until_done():
    import numpy as np

    def produce(receive):
        n = 0
        while True:
            try:
                k, a = receive()
            except EOFError:
                return n
            n += 1
            yield k, float(a.sum())

    child = ForkedResults(produce, range(3))
    try:
        for k in range(3):
            child.send((k, np.full((300, 400, 3), k, np.float32)))  # larger than a pipe's buffer
        child.done_sending()
        assert [child.future(k).result(timeout=30) for k in range(3)] == [0.0, 360000.0, 720000.0]
        assert child.result() == 3
    finally:
        child.close()
