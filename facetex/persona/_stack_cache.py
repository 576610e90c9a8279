"""An on-disk cache of a persona's rebuilt texture stacks (what :func:`facetex.persona.prepare_persona`
makes from the aligned photos a ``.persona`` stores): float32 ``.npy`` files memory-mapped at the next
load instead of rebuilt (~2.2 s of a 519-photo persona on 2 threads, and the CPU a live stream needs
beside it). The blends read only the rows of the photos they weight, so a mapped cache pages in what
is used. ~1 MB per photo (a 519-photo persona: ~0.5 GB); used by ``facetex live`` (issue 26).

A cache folder holds one persona's stacks for one stack key: ``meta.json`` (format, photo count, the
segments' shapes), ``s<level>_<segment>.npy``, ``gaze.npy`` (each photo's gaze asymmetry, made with
the stacks) and ``band_energy.npy``. The folder's name (:func:`stack_cache_folder`) is a digest of the
persona file's path, size and modification time and the stack key, so a rebuilt persona gets a new
folder. A folder that does not match is ignored (and rebuilt); writing goes to a temporary folder
renamed at the end; failures to write are silent (it is a cache)."""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

__all__ = ["stack_cache_folder", "read_stack_cache", "write_stack_cache", "read_ahead"]

FORMAT = 1


def stack_cache_folder(root, persona_path, tp) -> Path:
    """The cache folder under ``root`` of the persona file ``persona_path``'s stacks for TextureParams ``tp``."""
    from ._stack_store import _stored_key

    p = Path(persona_path).resolve()
    st = p.stat()
    key = json.dumps([FORMAT, str(p), st.st_size, st.st_mtime_ns, _stored_key(tp)])
    return Path(root) / "stacks" / hashlib.sha256(key.encode()).hexdigest()[:32]


def _remove_stale(root: Path, persona: str) -> None:
    """Remove the cache folders under ``root`` made for the persona file ``persona`` (its older versions)."""
    try:
        for d in root.iterdir():
            try:
                if json.loads((d / "meta.json").read_text()).get("persona") == persona:
                    shutil.rmtree(d, ignore_errors=True)
            except (OSError, ValueError, AttributeError):
                continue
    except OSError:
        pass


def _shapes(prep) -> list:
    return [[list(seg.stack.shape) for seg in segs] for segs in prep.segments]


def read_stack_cache(prep, folder) -> bool:
    """Fill ``prep``'s stacks (memory-mapped, read-only) and gaze scores from ``folder``; False
    (nothing changed) when it is missing or does not match ``prep``'s layout."""
    folder = Path(folder)
    try:
        meta = json.loads((folder / "meta.json").read_text())
        if meta.get("format") != FORMAT or meta.get("n") != prep.n or meta.get("shapes") != _shapes(prep):
            return False
        stacks = [[np.load(folder / f"s{k}_{j}.npy", mmap_mode="r") for j in range(len(segs))]
                  for k, segs in enumerate(prep.segments)]
        gaze = np.load(folder / "gaze.npy")
        energy = np.load(folder / "band_energy.npy")
    except (OSError, ValueError, KeyError):
        return False
    if any(a.shape != seg.stack.shape or a.dtype != np.float32 for segs, arrs in zip(prep.segments, stacks)
           for seg, a in zip(segs, arrs)) or gaze.shape != (prep.n,):
        return False
    for segs, arrs in zip(prep.segments, stacks):
        for seg, a in zip(segs, arrs):
            seg.stack = a
    prep._gaze = gaze.astype(np.float64)
    prep._stage["band_energy"] = energy
    _prefetch([a for arrs in stacks for a in arrs])
    return True


def _willneed(arrays) -> None:
    import mmap

    for a in arrays:
        m = getattr(a, "_mmap", None)
        if m is not None:
            try:
                m.madvise(mmap.MADV_WILLNEED)
            except (OSError, ValueError):
                pass


def _prefetch(arrays) -> None:
    """Ask the kernel to read the mapped files into the page cache, on a thread (the reads are
    asynchronous; the call may still wait for the disk's queue). Why: a blend reads ~80 of the
    photos' rows, scattered over the files; from a cold page cache the first blends fault them
    in a few pages at a time (the first live frame's set-up took 2.3 s instead of 0.5 s)."""
    import mmap
    import threading

    if hasattr(mmap, "MADV_WILLNEED"):
        threading.Thread(target=_willneed, args=(arrays,), name="facetex-stack-prefetch", daemon=True).start()


def read_ahead(folder) -> None:
    """Ask the kernel to read ``folder``'s stack files into the page cache, the small levels first
    (posix_fadvise WILLNEED: asynchronous reads; nothing where the call does not exist), before they
    are mapped: the live session starts it beside the persona's own load, ~1 s before
    :func:`read_stack_cache` maps the files (whose :func:`_prefetch` covers systems without it)."""
    if not hasattr(os, "posix_fadvise"):
        return
    try:
        for f in sorted(Path(folder).glob("s*_*.npy"), key=lambda f: f.stat().st_size):
            fd = os.open(f, os.O_RDONLY)
            try:
                os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_WILLNEED)
            finally:
                os.close(fd)
    except OSError:
        pass


def write_stack_cache(prep, folder, persona_path=None) -> None:
    """Write ``prep``'s stacks, gaze scores and band energy to ``folder`` (temporary folder, renamed);
    other folders of the same ``persona_path`` (an older version of the file) are removed."""
    folder = Path(folder)
    if folder.exists():
        return
    if persona_path is not None:
        _remove_stale(folder.parent, str(Path(persona_path).resolve()))
    tmp = None
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=".tmp-", dir=folder.parent))
        for k, segs in enumerate(prep.segments):
            for j, seg in enumerate(segs):
                np.save(tmp / f"s{k}_{j}.npy", np.ascontiguousarray(seg.stack, np.float32))
        np.save(tmp / "gaze.npy", np.asarray(prep._gaze, np.float64))
        np.save(tmp / "band_energy.npy", np.asarray(prep.band_energy()))
        (tmp / "meta.json").write_text(json.dumps({"format": FORMAT, "n": prep.n, "shapes": _shapes(prep),
                                                   "persona": None if persona_path is None
                                                   else str(Path(persona_path).resolve())}))
        os.replace(tmp, folder)
        tmp = None
    except OSError:
        pass
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
