"""One live puppet stream: :class:`LiveSession` turns driver frames into puppet frames one at a time.

The offline puppetry (:mod:`facetex.puppet.puppetry`) sees the whole driver video before it renders
a frame; a live session sees each frame once, as it arrives. What changes (the rest is the offline
code, :class:`facetex.puppet.Puppeteer` per frame):

* the driver is tracked frame by frame, seeded by the previous frame (:class:`~facetex.live.motion.CausalTracker`);
* the clip-wide reference (mean mesh, canonical frame, mean landmarks) comes from the first tracked
  frames, those seen while the persona loads (:func:`~facetex.live.motion.reference_motion`): until
  it is made, :meth:`LiveSession.process` returns None;
* the motion is smoothed causally (One-Euro, :class:`~facetex.live.motion.LiveMotion`);
* the expression texture's regional weights are made temporally coherent by the offline bilateral
  filter (frames of the same expression share a blend) over the past frames only
  (``LiveParams.weight_smoothing``; offline it also looks 0.36 s ahead). A cache of textures keyed by
  the quantised target fiducials was measured and dropped: on GRID clips with the 519-photo persona
  not one of 68 frames hit it at steps of 0.5-3 canonical px (49 points x 2 coordinates: some always
  move a step), while the steps changed the texture by 0.5-3/255;
* a frame without a usable face (not found, partly outside the frame, landmarks and mesh
  disagreeing, an implausible shape) shows the driver's own frame (a plain panel in face mode), as
  offline; with ``LiveParams(lost_output="last")`` the last puppet frame instead. The filters restart
  when the face comes back.

The puppet's per-frame state lives in a few slots appended to the reference's arrays, so up to
:data:`SLOTS` frames may be between :meth:`LiveSession.prepare` and :meth:`LiveSession.finish` (a
pipelined runner tracks frame t+1 while frame t renders)."""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import replace

import cv2
import numpy as np

from ..errors import BadInputError, NoFaceError
from ..geometry.glasses import rim_response, rim_template
from ..puppet.params import MODES, PuppetParams
from .motion import CausalTracker, LiveMotion, reference_motion, shape_residual
from .params import LiveParams
from .stats import LiveStats

__all__ = ["LiveSession", "SLOTS"]


def _load_models() -> None:
    from .motion import load_tracking_models

    load_tracking_models()

#: frames that may be between prepare() and finish() at once
SLOTS = 8


def _uint8_rgb(frame) -> np.ndarray:
    a = np.asarray(frame)
    if a.ndim != 3 or a.shape[2] != 3 or a.dtype != np.uint8 or min(a.shape[:2]) < 16:
        raise BadInputError(f"a live frame must be an (H, W, 3) uint8 RGB array of at least 16 px, "
                            f"got {a.dtype} {a.shape}")
    return np.ascontiguousarray(a)


class LiveSession:
    """A persona puppet driven by frames as they arrive (module doc).

    Parameters
    ----------
    persona : str, os.PathLike or Persona
        The puppet (a ``.persona`` file or a loaded :class:`facetex.persona.Persona`).
    size : int or None
        Longer side of the output frame in px (32..4096; None: the tracked frame's size).
    mode : {"composite", "face"}
        The puppet put into the driver's frame, or alone on a plain panel.
    params : PuppetParams, optional
        The puppet's settings (default :class:`facetex.puppet.PuppetParams`); ``weight_smoothing``
        is set to 0 (the offline filter looks ahead).
    live : LiveParams, optional
        The live settings (warm-up, filters, texture cache; :class:`facetex.live.LiveParams`).
    background : bool
        Load the persona on a thread (default): frames given meanwhile are tracked for the
        reference and give None. False: the constructor returns once the persona is loaded.

    Raises
    ------
    facetex.BadInputError
        A bad mode, size or setting.
    FileNotFoundError, facetex.BadPersonaError
        A missing file or not a persona (its header is read here); a persona whose arrays turn out
        damaged: here with ``background=False``, else from :meth:`wait_loaded` or :meth:`process`.

    Examples
    --------
    >>> s = LiveSession("george.persona", size=256)            # doctest: +SKIP
    >>> out = s.process(frame)   # (H, W, 3) uint8 RGB -> uint8 RGB, or None while warming up  # doctest: +SKIP
    >>> s.stats()["latency_ms_p95"]                             # doctest: +SKIP
    """

    def __init__(self, persona, *, size: int | None = 256, mode: str = "composite",
                 params: PuppetParams | None = None, live: LiveParams | None = None, background: bool = True):
        from ..puppet.puppetry import output_size

        if mode not in MODES:
            raise BadInputError(f"unknown puppet mode {mode!r}: use one of {', '.join(MODES)}")
        output_size((1, 1), size)  # a bad size fails here
        self.size, self.mode = size, mode
        self.live = (live or LiveParams()).check()
        params = params or PuppetParams()
        params.texture_params()  # checks the texture weights
        self.params = replace(params, weight_smoothing=0.0)
        self.stats_ = LiveStats()
        params = self._puppet_params(persona)  # reads the persona's header: a missing file fails here
        if self.live.tracking == "process":
            from ._tracking import ProcessTracker

            self.tracker = ProcessTracker(self.params.driver)
        else:
            self.tracker = CausalTracker(self.params.driver)
        self._warm: deque = deque(maxlen=self.live.max_warmup)
        self._index = 0
        self._last_out: np.ndarray | None = None
        self._geometry = None  # (tracked W, H, output W, H, output px per tracked px) of the first frame
        self.puppeteer = self.motion = None
        self._persona = None
        self.timings: dict = {}
        self._fade = 0
        self._last_tex: np.ndarray | None = None  # the last blend (before its mouth fill), for reuse
        self._reused = False
        self.texture_reused = 0
        self._weights: deque = deque(maxlen=64)  # the last frames' texture weights (the causal filter's window)
        self._renderer = None
        if self.live.render == "process":
            from ._render import ProcessRenderer

            try:
                self._renderer = ProcessRenderer()
            except OSError:  # no child process here: rendered in this one
                self._renderer = None
        if isinstance(self.tracker, CausalTracker):  # the tracking process loads its own models
            threading.Thread(target=_load_models, name="facetex-live-models", daemon=True).start()
        from ._loading import StagedPuppet

        self._loading = StagedPuppet(persona, params, self.timings,
                                     static=self.live.static_start, cache=self.live.stack_cache)
        if not background:
            self.wait_loaded(textures=True)

    # ------------------------------------------------------------------ set-up
    def close(self) -> None:
        """Stop the tracking and rendering processes (if any); the session cannot process frames after."""
        for part in (self.tracker, self._renderer):
            close = getattr(part, "close", None)
            if close is not None:
                close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _puppet_params(self, persona) -> PuppetParams:
        from ..puppet.puppetry import _persona_size

        size = _persona_size(persona)
        p = self.params
        if tuple(p.driver.size) != tuple(size):  # the puppet works in the persona's canonical frame
            p = replace(p, driver=replace(p.driver, size=tuple(size)))
        self.params = p
        return p

    def wait_loaded(self, timeout: float | None = None, *, textures: bool = False) -> bool:
        """Wait until puppet frames can be made (the persona loaded, its shape made, the tracker's
        models loaded; with ``textures`` also the expression textures' stacks); True when they can.
        The load's error (missing file, not a persona, ...) is raised here."""
        ld = self._loading
        done = ld.shaped.wait(timeout)
        if done and (textures or ld.static is None):  # no stored static texture: the stacks are needed
            done = ld.textured.wait(timeout)
        if ld.error is not None:
            raise ld.error
        if done and hasattr(self.tracker, "wait_ready"):
            self.tracker.wait_ready()
        if done and self._renderer is not None:
            self._renderer.wait_ready()
        return done

    def _can_build(self) -> bool:
        ld = self._loading
        if ld.error is not None:
            raise ld.error
        return ld.shaped.is_set() and (ld.static is not None or ld.textured.is_set())

    @property
    def ready(self) -> bool:
        """Whether puppet frames come out (the persona is loaded and the reference made)."""
        return self.puppeteer is not None

    def _build(self, fps: float) -> None:
        """The reference from the warm-up frames, the puppet and the per-frame motion."""
        from ..puppet.correspondence import driver_collection
        from ..puppet.puppeteer import Puppeteer

        t0 = time.perf_counter()
        p68, mesh, score = (np.array([w[k] for w in self._warm]) for k in range(3))
        tw, th = self._geometry[:2]
        track, motion = reference_motion(p68, mesh, score, (tw, th), fps=fps, params=self.params.driver,
                                         rims=rim_template([w[3] for w in self._warm]))
        coll = driver_collection(track, params=self.params)
        mean68 = p68.mean(axis=0)
        res = [shape_residual(q, mean68) for q in p68]
        self._shape = (mean68, max(self.live.shape_floor, self.live.shape_factor * float(np.median(res))))
        k, S = len(p68), SLOTS

        def ext(a, fill=0.0):
            return np.concatenate([a, np.full((S,) + a.shape[1:], fill, a.dtype)])

        found = np.r_[np.ones(k, bool), np.zeros(S, bool)]  # the reference's means: its own frames only
        motion = replace(motion, pose_A=ext(motion.pose_A), pose_b=ext(motion.pose_b), deltas=ext(motion.deltas),
                         fiducials=ext(motion.fiducials), fiducials68=ext(motion.fiducials68), found=found,
                         opening=ext(motion.opening), points68=ext(motion.points68))
        track = replace(track, points68=ext(track.points68), mesh=ext(track.mesh), found=found.copy(),
                        score=ext(track.score), lost_reason=track.lost_reason + [""] * S)
        self._k = k
        if self._loading.textured.is_set():  # the expression textures from the first frame: no fade
            self._fade = self.live.fade_frames
        pup = Puppeteer(self._persona, motion, coll, self.params, track)
        self.motion = LiveMotion(motion, self.live)
        # one frame of the reference through every stage: their first calls' set-up (lazy imports,
        # caches) is not paid by the first live frame
        tw, th, W, H, scale = self._geometry
        tex = pup.textures([k - 1])[0] if self._loading.textured.is_set() else self._loading.static
        grid = pup.grid(k - 1)
        if self._renderer is not None:
            from ._render import render_kit

            self._renderer.set_kit(render_kit(pup), self._slot_frame(pup, k - 1), grid, tex,
                                   np.zeros((H, W, 3), np.uint8), scale, self.mode)
        else:
            pup.render(k - 1, grid, tex, np.zeros((H, W, 3), np.float32), scale, self.mode)
        self.puppeteer = pup
        self.timings["reference_frames"] = k
        self.timings["build_s"] = time.perf_counter() - t0

    @staticmethod
    def _slot_frame(pup, i: int) -> dict:
        """What the renderer reads of frame slot ``i`` (pose, tracked landmarks and mesh)."""
        return {"A": pup.motion.pose_A[i], "b": pup.motion.pose_b[i], "points68": pup.track.points68[i],
                "mesh": pup.track.mesh[i]}

    # ------------------------------------------------------------------ per frame
    def _frame_geometry(self, frame: np.ndarray):
        from ..puppet.puppetry import check_output_frame

        h, w = frame.shape[:2]
        k = min(1.0, self.live.track_side / max(w, h))
        tw, th = (w, h) if k >= 1 else (max(16, int(round(w * k))), max(16, int(round(h * k))))
        W, H, scale = check_output_frame((tw, th), self.size, mode=self.mode)
        return tw, th, W, H, scale

    def prepare(self, frame, *, arrival: float | None = None, t: float | None = None, fps: float = 25.0,
                index: int | None = None) -> dict:
        """The first half of :meth:`process` (tracking, motion, mesh, texture): a work record for
        :meth:`finish`. Call it from one thread, frames in order; ``arrival``: the frame's arrival
        (``time.perf_counter()``, default now: its latency is measured from it); ``t``: its time in
        the stream (seconds; default its arrival), which the filters use; ``fps``: the stream's
        nominal rate (the reference's); ``index``: the frame's number in the source (default: the
        count of frames prepared; a runner that drops frames gives the source's), the records' "index"."""
        now = time.perf_counter()
        arrival = now if arrival is None else arrival
        late = now - arrival > 0.5 / max(fps, 1.0)  # it waited for this call: the stages are behind
        t = arrival if t is None else t
        frame = _uint8_rgb(frame)
        if self._loading.error is not None:
            raise self._loading.error
        if self._geometry is None:
            self._geometry = self._frame_geometry(frame)
        elif frame.shape[1::-1] != self._geometry_src:
            raise BadInputError(f"live frames changed size from {self._geometry_src} to {frame.shape[1::-1]}")
        self._geometry_src = frame.shape[1::-1]
        tw, th = self._geometry[:2]
        t0 = time.perf_counter()
        small = frame if (tw, th) == frame.shape[1::-1] else cv2.resize(frame, (tw, th), interpolation=cv2.INTER_AREA)
        p68, mesh, score, why = self.tracker(small)
        if not why and self.puppeteer is not None and shape_residual(p68, self._shape[0]) > self._shape[1]:
            why = "implausible shape"
            self.tracker.lose()
        t1 = time.perf_counter()
        self.stats_.stage_time("track", t1 - t0)
        count, self._index = self._index, self._index + 1
        index = count if index is None else int(index)
        work = {"index": index, "arrival": arrival, "frame": frame, "lost": bool(why), "why": why, "warmup": False}
        if self.puppeteer is None:
            if not why:  # with the frame's thin lines: the driver's glasses, averaged over the warm-up
                self._warm.append((p68, mesh, score, rim_response(small, p68)))
            if len(self._warm) >= self.live.warmup and self._can_build():
                self._persona = self._loading.persona
                self._build(fps)
                self.stats_.stage_time("build", time.perf_counter() - t1)
                t1 = time.perf_counter()
            else:
                work["warmup"] = True
                return work
        if why:
            self.motion.reset()
            self._weights.clear()
            self._last_tex = None
            return work
        slot = self._k + count % SLOTS  # frames in flight have consecutive counts: distinct slots
        m = self.motion(p68, mesh, t)
        pup = self.puppeteer
        pup.motion.pose_A[slot], pup.motion.pose_b[slot] = m["A"], m["b"]
        pup.motion.deltas[slot] = m["deltas"]
        pup.motion.fiducials68[slot] = m["fiducials68"]
        from ..landmarks import POINTS49_INDEX

        pup.motion.fiducials[slot] = m["fiducials68"][POINTS49_INDEX]
        pup.track.points68[slot], pup.track.mesh[slot] = p68, mesh
        t2 = time.perf_counter()
        work["grid"] = pup.grid(slot)
        t3 = time.perf_counter()
        if late and self.live.reuse_texture and self._last_tex is not None and not self._reused:
            # the previous frame's blend with this frame's mouth (its weights still enter the filter)
            self._push_weights(slot)
            work["texture"] = self.puppeteer._close_interiors([slot], [self._last_tex])[0]
            self._reused = True
            self.texture_reused += 1
        else:
            work["texture"] = self._texture(slot, fps)
            self._reused = False
        t4 = time.perf_counter()
        work["slot"] = slot
        st = self.stats_
        st.stage_time("motion", t2 - t1)
        st.stage_time("mesh", t3 - t2)
        st.stage_time("texture", t4 - t3)
        return work

    def _texture(self, slot: int, fps: float) -> np.ndarray:
        """The expression texture of a slot's frame: its regional weights (as the offline blend's)
        averaged with those of the previous frames of the same expression (a one-sided bilateral
        filter: :func:`facetex.persona.weights.temporal_weights` over the frames up to this one,
        ``LiveParams.weight_smoothing`` seconds), then blended; the static texture or the global
        weights as offline."""
        pup = self.puppeteer
        static = self._loading.static
        if not self._loading.textured.is_set():  # the stacks are still being made: the stored static texture
            return pup._close_interiors([slot], [static])[0]
        if self._loading.error is not None:
            raise self._loading.error
        tex = self._expression_texture(slot, fps)
        if static is not None and self._fade < self.live.fade_frames:  # from the static texture, gradually
            self._fade += 1
            a = np.float32(self._fade / (self.live.fade_frames + 1))
            tex = a * tex + (1 - a) * static
        self._last_tex = tex
        return pup._close_interiors([slot], [tex])[0]

    def _expression_texture(self, slot: int, fps: float) -> np.ndarray:
        sigma = self.live.weight_smoothing * fps
        tp = self.params.texture_params()
        if self.params.texture != "ours" or tp.weights != "regional" or sigma <= 0:
            return self._plain_texture(slot)
        from ..persona.texture import blend_weights
        from ..persona.weights import temporal_weights

        self._push_weights(slot)
        win = list(self._weights)[-(int(np.ceil(3 * sigma)) + 1):]
        Ws = np.stack([w[0] for w in win])
        coords = [np.stack([w[1][j] for w in win]) for j in range(Ws.shape[1])]
        smooth = temporal_weights(Ws, coords, np.stack([w[2] for w in win]), sigma_frames=sigma,
                                  range_scale=self.params.weight_range, last=True)[-1]
        return blend_weights(self._persona, smooth[None], params=tp)[0]

    def _push_weights(self, slot: int) -> None:
        """This frame's regional texture weights (as the offline blend's) into the filter's window."""
        from ..persona.texture import _fiducials49, cut_region_weights, expression_model

        tp = self.params.texture_params()
        if self.params.texture != "ours" or tp.weights != "regional" or not self._loading.textured.is_set():
            return
        f = _fiducials49(self.puppeteer.target(slot))[None]
        coords, sigmas, S = expression_model(self._persona, tp).evaluate(f)
        W = cut_region_weights(S, tp)[0]  # (R, n): this frame's weights, cut as offline
        self._weights.append((W, [c[0] for c in coords], sigmas[0]))

    def _plain_texture(self, slot: int) -> np.ndarray:
        """The texture of the puppet's own method (static, global weights, or per-frame regional
        weights) before the mouth-interior fill."""
        from ..puppet.puppeteer import neutral_textures

        return neutral_textures(self._persona, [self.puppeteer.target(slot)], method=self.params.texture,
                                params=self.params.texture_params())[0]

    def finish(self, work: dict) -> dict:
        """The second half of :meth:`process`: the record of a :meth:`prepare` work record with its
        output frame ("output": uint8 RGB (H, W, 3), None in the warm-up) and "kind" ("puppet",
        "lost" or "warmup"). Call it from one thread, records in the order prepared."""
        t0 = time.perf_counter()
        rec = {k: work[k] for k in ("index", "arrival", "lost", "why", "warmup")}
        if work["warmup"]:
            rec.update(output=None, kind="warmup")
            self.stats_.output(work["arrival"], "warmup")
            return rec
        from ..io import to_uint8

        tw, th, W, H, scale = self._geometry
        frame = work["frame"]
        drv = cv2.resize(frame, (W, H), interpolation=cv2.INTER_AREA if W < frame.shape[1] else cv2.INTER_LINEAR)
        if work["lost"]:
            if self.live.lost_output == "last" and self._last_out is not None:
                out = self._last_out
            elif self.mode == "composite":
                out = drv
            else:
                out = np.empty_like(drv)
                out[:] = to_uint8(np.asarray(self.params.plain, np.float32))
            rec.update(output=out, kind="lost")
        elif self._renderer is not None:  # in the rendering process, beside this one's next frame
            out = self._renderer(self._slot_frame(self.puppeteer, work["slot"]), work["grid"], work["texture"], drv,
                                 scale, self.mode)
            self._last_out = out
            rec.update(output=out, kind="puppet")
        else:
            img, alpha = self.puppeteer.render(work["slot"], work["grid"], work["texture"],
                                               drv.astype(np.float32) * np.float32(1 / 255), scale, self.mode)
            out = to_uint8(img)
            self._last_out = out
            rec.update(output=out, kind="puppet", alpha=alpha)
        now = time.perf_counter()
        self.stats_.stage_time("render", now - t0)
        self.stats_.output(work["arrival"], rec["kind"], now)
        rec["latency"] = now - work["arrival"]
        return rec

    def process(self, frame, *, arrival: float | None = None, t: float | None = None) -> np.ndarray | None:
        """The output frame (uint8 RGB (H, W, 3) at ``size``) of one driver frame (uint8 RGB (H, W, 3)),
        or None while the persona loads and the reference is made (module doc).

        Raises
        ------
        facetex.BadInputError
            Not an (H, W, 3) uint8 frame, or a frame of another size than the first.
        """
        self.stats_.arrived()
        return self.finish(self.prepare(frame, arrival=arrival, t=t))["output"]

    def stats(self) -> dict:
        """{"frames_in", "frames_out", "puppet_frames", "lost_frames", "warmup_frames", "dropped",
        "dropped_pct", "fps", "sustained_fps", "latency_ms_p50", "latency_ms_p95", "latency_ms_max",
        "first_puppet_s" (from the session's start), "first_puppet_unix", "stage_ms" (median per stage),
        "detections" (runs of the face detector), "texture_reused" (frames that took the previous frame's
        blend, ``LiveParams.reuse_texture``), "timings" (set-up)}: see :class:`facetex.live.stats.LiveStats`."""
        d = self.stats_.summary()
        d.update(detections=self.tracker.detections, texture_reused=self.texture_reused,
                 timings={k: round(v, 3) if isinstance(v, float) else v for k, v in self.timings.items()})
        return d

    def require_face(self, source=None) -> None:
        """NoFaceError naming ``source`` when no puppet frame came out (no usable face in the stream)."""
        if self.stats_.puppet == 0:
            why = "not enough frames with a usable face for the reference" if self._warm else "no usable face"
            raise NoFaceError(f"{why} in the driver stream ({self.stats_.frames_in} frames): use a video showing "
                              "one face frontally, at least ~80 px wide", path=source)
