"""The persona's load for a live session, in two steps, so the first puppet frame need not wait
for the texture stacks.

:func:`facetex.puppet.load_puppet` makes everything the puppet needs from the persona: its shape
and landmark fields (~0.5 s) and its texture stacks, rebuilt from the aligned photos the file
stores (~2.2 s of a 519-photo persona on 2 threads, more while frames are processed beside it).
Here the puppet starts as soon as the shape is made, with the persona's expression-independent
texture (the uniform blend of all photos, whose pyramid sums the file stores next to the photos:
collapsed in a few ms, the same image the stacks blend with equal weights), and switches to the
expression-dependent texture when the stacks are ready (``stage="textures"``). Measured with the
519-photo persona: the static and expression textures differ by ~1.5/255 on average (findings),
a change one does not see as a jump.

The stacks themselves are memory-mapped from facetex's cache folder when an earlier session of the
same ``.persona`` file wrote them there (:mod:`facetex.persona._stack_cache`, ~1 MB per photo): then
they are ready at once instead of after seconds of CPU beside the stream."""

from __future__ import annotations

import threading
import time

import numpy as np

__all__ = ["StagedPuppet", "stored_static_texture"]


def stored_static_texture(persona, tp) -> np.ndarray | None:
    """(H, W, 3) float32: the uniform blend of the persona's photos from the static pyramid sums its
    file stores with the texture stacks (made with ``tp``'s stack key), or None when it has none."""
    from ..persona._stack_parts import _unpremultiply
    from ..persona._stack_store import _stored_key
    from ..persona.pyramid import collapse_pyramid, laplacian_pyramid, pyramid_levels

    stored = persona.texture_stacks
    if not stored or stored.get("meta", {}).get("key") != _stored_key(tp):
        return None
    W, H = persona.size
    levels = pyramid_levels((H, W), tp.min_level_side)
    shapes = [p.shape[:2] for p in laplacian_pyramid(np.zeros((H, W, 3), np.float32), levels)]
    static = [stored["arrays"].get(f"texture_static_{k}") for k in range(levels)]
    if any(s is None or s.size != h * w * 4 for s, (h, w) in zip(static, shapes)):
        return None
    bands = [_unpremultiply(np.asarray(s, np.float32).reshape(h, w, 4)) for s, (h, w) in zip(static, shapes)]
    return np.clip(collapse_pyramid(bands), 0, 1).astype(np.float32)


def _cache_folder(persona, tp):
    """The stack cache folder (:mod:`facetex.persona._stack_cache`) of a .persona path, or None (a
    Persona object, no writable cache folder)."""
    import os

    from .._resources import writable_cache_dir
    from ..persona._stack_cache import stack_cache_folder

    if not isinstance(persona, (str, os.PathLike)):
        return None
    root = writable_cache_dir()
    try:
        return None if root is None else stack_cache_folder(root, persona, tp)
    except OSError:
        return None


def _read_ahead(persona, tp) -> None:
    """The cached stack files of a .persona path read ahead
    (:func:`facetex.persona._stack_cache.read_ahead`): from a cold page cache the first blends
    otherwise fault their rows in a few pages at a time (measured with the 519-photo persona's
    ~500 MB evicted: the set-up before the first frame took 2.3 s instead of 0.3-0.5 s)."""
    from ..persona._stack_cache import read_ahead

    folder = _cache_folder(persona, tp)
    if folder is not None:
        read_ahead(folder)


#: modules the puppet's set-up and first frame import (scipy.interpolate alone ~0.35 s): imported on a
#: thread while the persona file is read
_PREIMPORT = ("scipy.interpolate", "scipy.spatial", "scipy.sparse", "scipy.fft", "facetex.puppet.puppeteer",
              "facetex.puppet.motion", "facetex.puppet.correspondence", "facetex.puppet.shape",
              "facetex.puppet.composite", "facetex.puppet.render", "facetex.puppet.deform",
              "facetex.geometry.frontalize", "facetex.persona.texture", "facetex.persona.weights")


def _preimport() -> None:
    import importlib

    for name in _PREIMPORT:
        try:
            importlib.import_module(name)
        except ImportError:  # reported where it is used
            pass


class StagedPuppet:
    """The persona loaded on a thread in two stages: ``shaped`` (loaded, shape and landmark fields
    made; ``static`` holds the stored static texture or None) and ``textured`` (texture stacks
    ready). ``error``: the load's exception (both events are set then)."""

    def __init__(self, persona, params, timings: dict, *, static: bool = True, cache: bool = True):
        self.use_static, self.cache = static, cache
        self.persona = None
        self.static: np.ndarray | None = None
        self.error: BaseException | None = None
        self.shaped, self.textured = threading.Event(), threading.Event()
        self.timings = timings
        self._thread = threading.Thread(target=self._run, args=(persona, params), name="facetex-live-load",
                                         daemon=True)
        self._thread.start()

    def _run(self, persona, params) -> None:
        from ..puppet.puppetry import _Done, _load_puppet, _prepare_puppet_texture, _puppet_shape

        t0 = time.perf_counter()
        if self.cache:  # the cached stacks read ahead from now on, beside the persona's own load
            threading.Thread(target=_read_ahead, args=(persona, params.texture_params()), daemon=True,
                             name="facetex-live-readahead").start()
        pre = threading.Thread(target=_preimport, name="facetex-live-imports", daemon=True)
        pre.start()
        try:
            loaded = _Done(_load_puppet(persona, self.timings))
            pre.join()
            if self.use_static:
                self.static = stored_static_texture(loaded.value, params.texture_params())
            failed: list = []

            def texture():
                try:
                    t1 = time.perf_counter()
                    folder = _cache_folder(persona, params.texture_params()) if self.cache else None
                    if folder is not None:  # the stacks memory-mapped from the cache, or written to it
                        from ..persona.stacks import prepare_persona

                        self.timings["stack_cache"] = "hit" if (folder / "meta.json").is_file() else "written"
                        prepare_persona(loaded.value, params.texture_params(), cache=folder)
                        self.timings["stack_cache_s"] = time.perf_counter() - t1
                    _prepare_puppet_texture(loaded, params, self.timings)
                except BaseException as e:  # noqa: BLE001 - re-raised below
                    failed.append(e)
                finally:
                    self.timings["textures_ready_s"] = time.perf_counter() - t0

            th = threading.Thread(target=texture, name="facetex-live-texture", daemon=True)
            th.start()
            _puppet_shape(loaded, params, self.timings)
            self.persona = loaded.value
            self.timings["shape_ready_s"] = time.perf_counter() - t0
            self.shaped.set()
            th.join()
            if failed:
                raise failed[0]
        except BaseException as e:  # noqa: BLE001 - re-raised by the session's thread
            self.error = e
        finally:
            self.shaped.set()
            self.textured.set()
