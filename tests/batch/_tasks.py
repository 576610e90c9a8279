"""Cheap, picklable item functions for the engine and scheduler tests (module-level, so local
and Ray workers import them by reference; the tests put this folder on the workers' path)."""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path


def square(p):
    return {"value": p["x"] * p["x"], "pid": os.getpid(), "threads": os.environ.get("OMP_NUM_THREADS")}


def fail(p):
    from facetex.errors import BadInputError

    raise BadInputError("this item is bad\nsecond line", path=p.get("path", "in.jpg"))


def crash(p):
    raise ZeroDivisionError("division by zero in the item")


def die_once(p):
    """Killed (SIGKILL, as the OOM killer does) on its first attempt, succeeds on the next."""
    marker = Path(p["marker"])
    if not marker.exists():
        marker.write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    return {"value": "second time lucky", "pid": os.getpid()}


def always_die(p):
    os.kill(os.getpid(), signal.SIGKILL)


def write_item(p):
    """An item like the real ones: sleeps (the work), then commits its output and sidecar together."""
    from facetex.io import write_files

    time.sleep(float(p.get("sleep", 0.0)))
    if p.get("die_marker") and not Path(p["die_marker"]).exists():
        Path(p["die_marker"]).write_text(str(os.getpid()))
        os.kill(os.getpid(), signal.SIGKILL)
    src = Path(p["src"]).read_text() if p.get("src") else ""
    if p.get("fail") or src.startswith("bad"):
        raise ValueError(f"item {p['name']} cannot be done")
    log = p.get("log")
    if log:  # every computation leaves a line: the tests count them
        with open(log, "a") as fh:
            fh.write(f"{p['name']} {os.getpid()}\n")
    out = p["output"]
    batch = p.get("batch") or {}
    # as the real items: the sidecar keeps "batch" (the input digests), and replaces (output first) when asked
    text = f"{p['name']} {p.get('value', 0)}\n{src}"
    write_files({out: text, f"{out}.json": json.dumps({"sidecar": True, "batch": batch}) + "\n"},
                overwrite=bool(batch.get("replace")), reverse_commit=not batch.get("replace"))
    return {"outputs": [out, f"{out}.json"]}


def photo_item(p):
    """A persona item's stand-in: its output lists the photo folder's files and their bytes."""
    folder = Path(p["photo_dir"])
    text = "".join(f"{f.name} {f.read_bytes().hex()}\n" for f in sorted(folder.iterdir()) if f.is_file())
    return write_item(dict(p, name=folder.name, value=text))


def pair_item(p):
    """A transfer item's stand-in: its output holds the content's and the style's bytes."""
    text = Path(p["content"]).read_text() + Path(p["style"]).read_text()
    return write_item(dict(p, name=Path(p["output"]).stem, value=text))


def slow_write(p):
    """Writes a temporary file beside its output, then sleeps inside the atomic writer: an interrupt
    must remove the temporary file."""
    from facetex.io import write_files

    def content(tmp):
        Path(tmp).write_text("partial")
        Path(p["started"]).write_text(str(os.getpid()))
        time.sleep(float(p.get("sleep", 60)))
        Path(tmp).write_text("complete")

    write_files({p["output"]: content, f"{p['output']}.json": "{}"})
    return {"outputs": [p["output"]]}


def thread_pools(p):
    """The thread pools an item of this worker gets: OpenCV's (imported by the item, as a transfer
    does, and already imported, as for the next item), torch's, and OpenMP's wait policy."""
    import cv2
    import torch

    return {"cv2": cv2.getNumThreads(), "torch": torch.get_num_threads(),
            "wait_policy": os.environ.get("OMP_WAIT_POLICY"), "pid": os.getpid()}
