"""Persona puppetry: drive one person's 3D face with another person's video (Tom Hanks §4, §6).

Per driver video (see :mod:`facetex.puppet.driver` for the motion):

1. **Average shapes.** Puppet: photometric stereo on the persona's aligned photos
   (:func:`facetex.puppet.shape.reconstruct_average_shape`, computed when the persona is
   built and stored in the ``.persona``; checked against the generic face by
   :func:`facetex.puppet.shape.checked_depth`). Driver: from
   ``driver_photos`` the same way; from the video alone the tracked mean mesh is used
   instead (a video has one lighting, so photometric stereo on its frames is degenerate).
2. **Correspondence** (§4, §6): for every driver pixel of the canonical frame, its puppet
   pixel. The paper (``correspondence="flow"``): the puppet's 2D average is projected onto the
   driver's rank-4 appearance subspace and the optical flow (α, ratio, minWidth, outer, inner,
   SOR) = (0.02, 0.85, 20, 4, 1, 40) from the projection to the puppet's average. Ours (default,
   ``"landmarks"``): the thin-plate spline (Eq. 1, λ = 10) from the driver's mean frontal
   landmarks to the puppet's. Measured on the GRID clips with the LFW Bush and Blair personas:
   the projection of the puppet onto a video's subspace is the driver's own face (one lighting,
   one identity), and the flow between two people's faces at α = 0.02 tears: it misses the
   landmarks by 3-12 px median (the identity map by 1-4 px, the spline by < 0.5 px), folds over
   on 10-13 % of the grid, and the deformation transfer's tangent maps turn its tears into 5-18x
   magnified motions (puppet vertices jumping 10-15 px for a 1 px driver motion) and its folds
   into a broken inverse (vertices that never move: the notch in Blair's lower lip).
3. **Deformation transfer** per frame with magnitude adjustment and Huber-ROF
   (:class:`facetex.puppet.deform.DeformationTransfer`) on a depth-map grid of 2 px.
4. **Texture** per frame (§6, Figs. 8-9): synthesized *in the neutral frame* of the
   average model — the mesh carries the expression — with the blending weights of the
   target fiducials F^T = M_P + k (F_D^i − M̄_D) (k: ratio of the eye distances): the
   persona's regional expression weights by default (:mod:`facetex.persona.weights`, the
   same blend as ``facetex persona texture``), or the paper's global Eq. 2/3 weights
   (``weights="global"``: sigma, Laplacian exponent 1). Beyond the paper, the regional weights of
   the whole clip are made temporally coherent before blending: each frame's photo weights are
   averaged with those of the frames within ~0.1 s that show the same expression (a bilateral
   filter, :func:`facetex.persona.weights.temporal_weights`). Per frame, the few nearest photos
   swap with the landmarks' jitter and a still face shimmered (bench flicker 1.3-1.7 against
   1.2 with the global weights; 1.0-1.4 with the filter on 11 Bush/Blair x GRID runs); the filter
   leaves a mouth opening alone (its frames are far apart in the mouth region's coordinates).
5. **Rendering** with the driver's head pose (orthographic, z-buffered, 2x supersampled).
   ``mode="composite"``: put into the driver's frame (:mod:`facetex.puppet.composite`:
   the driver's face outline as mask, SH lighting and colour transfer, the driver's mouth
   interior); ``mode="face"``: the puppet alone on a plain background, as in
   the paper's figures. Frames where the driver's face is lost, partly outside the frame or
   implausible (:func:`facetex.puppet.driver.track_driver`) show the driver's own frame
   (a plain frame in face mode) and are reported.

Beyond the paper, the puppet's lips start closed when the driver's are: the persona's average
texture often has parted lips (its photos talk and smile), so a constant lip motion sets the
puppet's mean lip gap to the driver's mean gap (scaled by the eye distances); the per-frame
motion then opens and closes it like the driver's. Its corners likewise start where the driver's
do when the persona's mean mouth smiles more (``smile_rest``): a persona whose photos mostly smile
(Serena Williams: mouth-corner lift +0.06 eye distances on average, GRID speakers -0.035 to +0.038)
smiled on a neutral driver, so the rest mouth is the persona's own at the driver's mean corner lift
(its photos' lips regressed on their lift, :func:`facetex.puppet.motion.lips_at_lift`, within the
lifts they show), and the texture's weights see that mouth too.

Eyes likewise (``eye_rest``, ``lid_sync``): the eyelid landmarks follow the driver's
(:class:`facetex.puppet.motion.LidFields`; the deformation transfer's smoothing all but removed a
blink), and a persona whose mean eyes are narrower than the driver's (LFW collections: eye aspect
ratio 0.21-0.29 against 0.31-0.34 of the GRID speakers; the puppet's eyes read as half shut) has
them opened to the driver's mean lid gap; the texture's eye-region weights see the opened lids
(:meth:`Puppeteer.target`), so photos with open eyes are blended there.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from ..errors import BadInputError
from ._output import (  # noqa: F401 - the limits are also read from here
    MAX_FACE_PANEL_PIXELS,
    MAX_FRAME_PIXELS,
    MAX_OUTPUT_SIDE,
    check_output_frame,
    output_size,
)
from .correspondence import DriverCollection, driver_collection, puppet_average_shape
from .driver import DriverTrack
from .motion import DriverMotion, driver_motion
from .params import MODES, TEXTURES, PuppetParams
from .puppeteer import Puppeteer, _landmark_fields_used, landmark_field

__all__ = [
    "PuppetSession",
    "load_puppet",
    "prepare_puppetry",
    "render_frames",
    "puppeteer",
]


@dataclass(eq=False)
class PuppetSession:
    """Everything prepared for rendering a driver video with a puppet."""

    track: DriverTrack
    motion: DriverMotion
    collection: DriverCollection
    puppeteer: Puppeteer
    timings: dict


def _load(persona):
    from ..persona.collection import Persona, load_persona

    return persona if isinstance(persona, Persona) else load_persona(persona)


def _persona_size(persona) -> tuple[int, int]:
    """Canonical frame (W, H) of a Persona or a .persona path (read from its header only)."""
    from ..persona.collection import Persona, read_persona_header

    if isinstance(persona, Persona):
        return persona.size
    return tuple(read_persona_header(persona)["size"])


def _load_puppet(persona, timings: dict):
    t0 = time.perf_counter()
    persona = _load(persona)
    timings["persona_load_s"] = time.perf_counter() - t0
    return persona


def _prepare_puppet_texture(loaded, params: PuppetParams, timings: dict) -> None:
    """The texture synthesis precomputation (and, for the flow correspondence or the static
    texture, the average face), cached on the persona."""
    from ..persona.stacks import prepare_persona
    from ..persona.texture import average_face

    persona = loaded.result()
    tp = params.texture_params()
    t0 = time.perf_counter()
    prep = prepare_persona(persona, tp)
    if params.texture == "ours" and tp.weights == "regional":  # what the first blend would compute
        if tp.restore:
            prep.band_energy()
        if tp.eye_quality > 0:
            prep.eye_quality()
        if tp.glasses > 0:
            prep.glasses_factors()
        from ..persona.texture import expression_model

        expression_model(persona, tp)  # the regional weights' model (~70 ms for 519 photos)
    t1 = time.perf_counter()
    if params.needs_average_face:
        average_face(persona, "d", params=tp)
    timings.update(persona_prepare_s=t1 - t0, puppet_average_s=time.perf_counter() - t1)


def _loaded_early(loading, timings: dict):
    """The Persona of a :func:`load_puppet` future (its timings copied into ``timings``)."""
    persona, early = loading.result()
    timings.update(early)
    return persona


def _puppet_shape(loaded, params: PuppetParams, timings: dict) -> None:
    """The puppet's average shape and its landmark fields (cached on the persona)."""
    t0 = time.perf_counter()
    persona = loaded.result()
    puppet_average_shape(persona, params)
    for kind in _landmark_fields_used(params):
        landmark_field(persona, kind, params.driver.grid_step)
    timings["puppet_shape_s"] = time.perf_counter() - t0


class _Done:
    """A finished future's stand-in (its ``result``)."""

    def __init__(self, value):
        self.value = value

    def result(self):
        return self.value


def load_puppet(persona, params: PuppetParams = PuppetParams()) -> tuple:
    """(Persona, timings): a Persona or .persona path (loaded) with everything the puppetry
    computes from the persona alone made and cached on it: its average shape, landmark fields and
    texture stacks (with the blend's band energy, eye quality and glasses factors). :func:`prepare_puppetry` does
    this beside the driver's tracking; the CLI starts it on a thread before its own imports and
    hands it over (``loading``)."""
    import threading

    timings: dict = {}
    loaded = _Done(_load_puppet(persona, timings))
    # the texture stacks on a second thread beside the shape: both release the GIL in most of their
    # work (zlib, OpenCV, numpy), and neither needs the other
    # (a daemon thread, not an executor's: the CLI loads on a daemon thread, and a command ending
    # on an argument error must not wait at exit for the stacks)
    failed: list = []

    def texture():
        try:
            _prepare_puppet_texture(loaded, params, timings)
        except BaseException as e:  # noqa: BLE001 - re-raised on this thread
            failed.append(e)

    t = threading.Thread(target=texture, name="facetex-puppet-texture", daemon=True)
    t.start()
    try:
        _puppet_shape(loaded, params, timings)
    finally:
        t.join()
    if failed:
        raise failed[0]
    return loaded.value, timings


def prepare_puppetry(driver, persona, *, driver_photos=None, max_frames: int | None = None,
                     params: PuppetParams = PuppetParams(), progress: Callable | None = None,
                     tracking="process", loading=None) -> PuppetSession:
    """Track the driver video and set up the puppet (everything before the per-frame rendering).

    ``persona``: a Persona or a .persona path. The driver is tracked in a child process
    (``tracking="process"``; ``"thread"``: in this one; or a :class:`DriverTracking` already
    started with the same arguments) while a second thread loads the persona and precomputes
    its texture stacks: neither needs the other, and dlib holds the GIL. ``loading``: a future of
    :func:`load_puppet` of the same persona and ``params`` started earlier (by the CLI), used
    instead of loading the persona here."""
    from concurrent.futures import ThreadPoolExecutor

    from ._tracking import DriverTracking

    if params.texture not in TEXTURES:
        raise BadInputError(f"unknown puppet texture {params.texture!r}: use one of {', '.join(TEXTURES)}")
    params.texture_params()  # checks the weights before any work
    size = _persona_size(persona)
    if tuple(params.driver.size) != size:  # work in the persona's canonical frame
        params = replace(params, driver=replace(params.driver, size=size))
    timings, puppet_timings = {}, {}
    t0 = time.perf_counter()
    # the frontalized frames feed only the flow correspondence's appearance subspace
    job = dict(max_frames=max_frames, params=params.driver,
               frontal_images=driver_photos is None and params.correspondence == "flow")
    if isinstance(tracking, DriverTracking):  # started earlier by the caller (the CLI, before its imports)
        if (Path(tracking.path), tracking.kwargs) != (Path(driver), job):
            tracking.cancel()
            raise BadInputError(f"the driver tracking was started for {tracking.path} with {tracking.kwargs}, "
                                f"but this puppetry needs {driver} with {job}")
        tracker = tracking
    elif tracking in ("process", "thread"):
        tracker = DriverTracking(driver, process=tracking == "process", **job)
    else:
        raise BadInputError(f"unknown tracking {tracking!r}: use 'process', 'thread' or a DriverTracking")
    # one worker thread: the persona load, then the texture precomputation (cached on the persona)
    from .._parallel import serialize_ast_parse

    serialize_ast_parse()  # numpy's .npy headers and inspect parse Python on both threads
    with ThreadPoolExecutor(1, thread_name_prefix="facetex-puppet") as pool:
        if loading is not None:  # loaded and prepared by the caller's thread
            loaded = shaped = prepared = pool.submit(_loaded_early, loading, puppet_timings)
        else:
            loaded = pool.submit(_load_puppet, persona, puppet_timings)
            shaped = pool.submit(_puppet_shape, loaded, params, puppet_timings)
            prepared = pool.submit(_prepare_puppet_texture, loaded, params, puppet_timings)
        try:
            track = tracker.result(progress)
            timings["track_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            coll = driver_collection(track, driver_photos=driver_photos, params=params)
            motion = driver_motion(track, params.driver)
            timings["motion_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            persona = loaded.result()
            shaped.result()
            wait = time.perf_counter() - t0
            if params.needs_average_face:  # the puppeteer needs it: wait for the precomputation
                t0 = time.perf_counter()
                prepared.result()
                wait += time.perf_counter() - t0
            # the correspondence and deformation transfer, and the clip's expression weights, while
            # the texture precomputation runs on the other thread
            pup = Puppeteer(persona, motion, coll, params, track)
            if pup.uses_sequence_weights():
                t0 = time.perf_counter()
                pup.sequence_weights()
                timings["sequence_weights_s"] = time.perf_counter() - t0
            t0 = time.perf_counter()
            prepared.result()
            timings["puppet_wait_s"] = wait + time.perf_counter() - t0
        except BaseException:
            tracker.cancel()
            for fut in (loaded, shaped, prepared):
                fut.cancel()
            raise
    timings.update(puppet_timings)
    timings.update({k: v for k, v in pup.timings.items() if k not in timings})  # not the cached look-ups
    return PuppetSession(track, motion, coll, pup, timings)


#: bytes the frames rendered ahead may hold (driver and puppet panels, alpha, as float32)
IN_FLIGHT_BYTES = 192 * 2**20
#: panels over this many pixels are rendered one at a time (each render's temporaries are
#: several times the panel's float image)
ONE_RENDER_PIXELS = 2_100_000


#: frames whose textures are blended together (a batch reads the precomputed stack once)
TEXTURE_BATCH = 32
#: frames of the first batch (rendering waits for it)
FIRST_BATCH = 8
#: frames rendered ahead of the one being written
IN_FLIGHT = 4
#: ... and when a forked child renders every other frame (its frames come a batch at a time)
FORKED_IN_FLIGHT = 16


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise BadInputError(f"unknown puppet mode {mode!r}: use one of {', '.join(MODES)}")


def render_frames(session: PuppetSession, *, size: int | None = None, mode: str = "composite",
                  side_by_side: bool = False, texture: str | None = None, max_frames: int | None = None,
                  keep: bool = False, progress: Callable | None = None, uint8_frame: bool = False,
                  fork: bool | None = None) -> Iterator[dict]:
    """Yield per frame {"index", "driver" (panel), "puppet" (panel), "frame" (output), "alpha",
    "lost"} (with ``keep`` also "grid" and "texture", the frame's mesh and texture): the second
    pass over the driver video. Lost frames show the driver's panel (a plain panel in face
    mode) and alpha 0. Per-stage times accumulate in ``session.timings`` (mesh_s, texture_s,
    render_s; mesh and texture overlap rendering). ``uint8_frame``: "frame" is the output frame
    as uint8 (what :func:`facetex.io.write_video` encodes; made panel by panel, without a float
    copy of the frame). Output frames over :data:`MAX_FRAME_PIXELS` are refused (BadInputError);
    large panels are rendered one at a time with fewer frames ahead (the same frames).
    ``fork``: render every other frame in a forked child process (:mod:`facetex.puppet._forked`;
    the same frames within float rounding: its textures are blended in other batches); None: when
    it can (Linux, the main thread, 2+ CPUs, panels up to ~0.4 MP, 16+ frames)."""
    from concurrent.futures import ThreadPoolExecutor

    from ..io import iter_video_frames
    from .driver import DRIVER_MAX_SIDE

    _check_mode(mode)
    pup = session.puppeteer
    W, H, scale = check_output_frame(session.track.frame_size, size, side_by_side=side_by_side, mode=mode,
                                     path=session.track.path)
    # frames ahead of the one yielded: at most IN_FLIGHT, and at most IN_FLIGHT_BYTES of panels
    # (a 4096 x 2304 panel's record is 0.26 GB as float32); large panels render on one thread
    by_bytes = IN_FLIGHT_BYTES // (W * H * (12 + 12 + 4))
    in_flight = min(IN_FLIGHT, by_bytes)  # 0: one frame at a time
    workers = 1 if W * H > ONE_RENDER_PIXELS else 2
    n = session.track.n_frames if max_frames is None else min(session.track.n_frames, max(0, int(max_frames)))
    if fork is None:
        from .._parallel import available_cpus
        from ._forked import fork_available

        fork = (workers == 2 and by_bytes >= FORKED_IN_FLIGHT and n >= 2 * FIRST_BATCH and available_cpus() >= 2
                and fork_available())
    if fork:
        # one render thread here: two contend for the GIL (75 frames at 256 px: 2.16 s -> 2.05 s); the
        # child's frames come in bursts (a batch's textures first): a longer queue
        workers = 1
        in_flight = max(in_flight, min(FORKED_IN_FLIGHT, by_bytes))
    tm = session.timings
    for key in ("mesh_s", "texture_s", "render_s"):
        tm.setdefault(key, 0.0)

    lock = threading.Lock()

    def add_time(key: str, dt: float) -> None:
        with lock:
            tm[key] += dt

    def meshes_and_textures(frames: list, add=add_time) -> list:
        t0 = time.perf_counter()
        verts = [pup.grid(i) for i in frames]
        t1 = time.perf_counter()
        tex = pup.textures(frames, texture)
        add("mesh_s", t1 - t0)
        add("texture_s", time.perf_counter() - t1)
        return list(zip(verts, tex))

    def render_one(i: int, grid, tex, drv, add=add_time):
        t0 = time.perf_counter()
        out = pup.render(i, grid, tex, drv, scale, mode)
        add("render_s", time.perf_counter() - t0)
        return out

    def panel(frame):
        return cv2.resize(frame, (W, H), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)

    def batches(frames: list) -> list:
        """Frames whose meshes and textures are computed together (a short first batch: rendering
        starts early)."""
        starts = [0] + list(range(min(FIRST_BATCH, len(frames)), len(frames), TEXTURE_BATCH)) if frames else []
        return [frames[a:b] for a, b in zip(starts, starts[1:] + [len(frames)])]

    # the odd frames go to the forked child: it computes their meshes and textures, receives their
    # driver panels and sends each frame's record back (its panels, with ``keep`` its mesh and texture)
    theirs = list(range(1, n, 2)) if fork else []
    own = list(range(0, n, 2)) if fork else list(range(n))

    def child_frames(receive):
        times = dict.fromkeys(("mesh_s", "texture_s", "render_s"), 0.0)

        def add(key, dt):
            times[key] += dt

        for fr in batches(theirs):
            for i, (grid, tex) in zip(fr, meshes_and_textures(fr, add)):
                out = {"grid": grid, "texture": tex} if keep else {}
                if session.track.found[i]:
                    try:
                        j, drv = receive()
                    except EOFError:  # the parent ended early (a video shorter than its header said)
                        return times
                    if j != i:
                        raise RuntimeError(f"render child: frame {j} received for frame {i}")
                    out["puppet"], out["alpha"] = render_one(i, grid, tex, drv, add)
                yield i, out
        return times

    # this process's frames are rendered on a pool of ``workers`` threads, each batch's textures
    # computed there ahead of its frames (OpenCV and numpy release the GIL); frames come out in
    # order, each the same as rendered alone
    groups = batches(own)
    where = {i: (b, p) for b, fr in enumerate(groups) for p, i in enumerate(fr)}
    child = None
    if theirs:
        from ._forked import ForkedResults

        child = ForkedResults(child_frames, theirs, ahead=in_flight)  # before this process's threads start
    pool = ThreadPoolExecutor(workers, thread_name_prefix="facetex-puppet-frame")
    try:
        ahead = {b: pool.submit(meshes_and_textures, groups[b]) for b in range(min(2, len(groups)))}
        pending: deque = deque()
        batch, b = [], -1

        def finished(rec_fut):
            rec, fut = rec_fut
            if fut is not None:
                res = fut.result()
                if isinstance(res, dict):  # the child's
                    rec.update(res)
                    child.taken(rec["index"])
                else:
                    rec.update(puppet=res[0], alpha=res[1])
            drv, img = rec["driver"], rec["puppet"]
            if uint8_frame:  # the same values as to_uint8 of the float frame
                from ..io import to_uint8

                if side_by_side:
                    rec["frame"] = np.empty((H, 2 * W, 3), np.uint8)
                    rec["frame"][:, :W], rec["frame"][:, W:] = to_uint8(drv), to_uint8(img)
                else:
                    rec["frame"] = to_uint8(img)
            else:
                rec["frame"] = np.concatenate([drv, img], axis=1) if side_by_side else img
            if progress:
                progress(n=1, stage="render", lost=session.track.n_lost)
            return rec

        for i, frame in enumerate(iter_video_frames(session.track.path, max_frames=n, max_side=DRIVER_MAX_SIDE)):
            if i >= n:
                break
            drv = panel(frame)
            lost = not bool(session.track.found[i])
            rec = {"index": i, "driver": drv, "lost": lost}
            fut = None
            if lost:  # no puppet where the driver's face is not seen whole
                rec["puppet"] = drv.copy() if mode == "composite" else np.broadcast_to(
                    np.asarray(pup.params.plain, np.float32), drv.shape).copy()
                rec["alpha"] = np.zeros((H, W), np.float32)
            if i in where:
                if where[i][0] != b:
                    b = where[i][0]
                    batch = ahead.pop(b).result()
                    if b + 2 < len(groups):
                        ahead[b + 2] = pool.submit(meshes_and_textures, groups[b + 2])
                grid, tex = batch[where[i][1]]
                if keep:
                    rec.update(grid=grid, texture=tex)
                if not lost:
                    fut = pool.submit(render_one, i, grid, tex, drv)
            else:  # the child's
                fut = child.future(i)
                if not lost:
                    child.send((i, drv))
            pending.append((rec, fut))
            while pending and (len(pending) > in_flight or pending[0][1] is None or pending[0][1].done()):
                yield finished(pending.popleft())
        if child is not None:
            child.done_sending()
        while pending:
            yield finished(pending.popleft())
        if child is not None:
            for key, dt in child.result().items():
                add_time(key, dt)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        if child is not None:
            child.close()


def puppeteer(driver, persona, output, *, driver_photos=None, side_by_side: bool = False, size: int | None = None,
              mode: str = "composite", overwrite: bool = False, max_frames: int | None = None,
              params: PuppetParams = PuppetParams(), progress: Callable | None = None,
              on_frame: Callable | None = None, tracking="process", loading=None) -> dict:
    """Render ``driver`` (a video) performed by ``persona`` (a Persona or .persona path) to
    ``output`` (H.264 MP4, written atomically, the driver's audio passed through).

    Frames where the driver's face is lost (not found, partly outside the frame, implausible)
    show the driver's frame and are counted and reported with their causes; a video without
    any face raises NoFaceError naming it (nothing is written).
    ``on_frame(record)`` receives each frame record of :func:`render_frames` (its "frame" is the
    uint8 frame written); ``tracking`` and ``loading``: see :func:`prepare_puppetry`. An output
    frame over :data:`MAX_FRAME_PIXELS` is refused before any work (BadInputError naming the
    driver and the largest ``size`` that fits).
    Returns a report dict (frames, lost frames, timings, shape/collection sources)."""
    import tempfile
    from concurrent.futures import ThreadPoolExecutor

    from ..io import check_output_path, transcode_audio

    _check_mode(mode)
    inputs = [driver] + ([] if hasattr(persona, "images") else [persona])
    out = check_output_path(output, overwrite=overwrite, inputs=inputs)
    output_size((1, 1), size)  # a bad size fails before the work
    if size is not None:  # an output frame too large to render and encode within the memory budget
        from ..io import video_info

        try:
            info = video_info(driver)
            check_output_frame((info["width"], info["height"]), size, side_by_side=side_by_side, mode=mode,
                               path=driver)
        except BaseException:
            if hasattr(tracking, "cancel"):  # started by the caller (the CLI)
                tracking.cancel()
            raise
    t_start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="facetex-puppet-") as tmp, ThreadPoolExecutor(1) as audio_pool:
        # the driver's audio is encoded during the setup, not beside the rendering
        audio = audio_pool.submit(transcode_audio, driver, Path(tmp) / "audio.m4a")
        session = prepare_puppetry(driver, persona, driver_photos=driver_photos, max_frames=max_frames,
                                   params=params, progress=progress, tracking=tracking, loading=loading)
        return _render_video(session, out, audio, driver=driver, inputs=inputs, size=size, mode=mode,
                             side_by_side=side_by_side, overwrite=overwrite, progress=progress, on_frame=on_frame,
                             t_start=t_start)


def _render_video(session: PuppetSession, out, audio, *, driver, inputs, size, mode, side_by_side, overwrite,
                  progress, on_frame, t_start: float) -> dict:
    """The second pass of :func:`puppeteer`: frames rendered and encoded (``audio``: the future
    of the driver's transcoded audio file, or of None), and the report."""
    from ..io import video_info, write_video

    def frames():
        for rec in render_frames(session, size=size, mode=mode, side_by_side=side_by_side,
                                 progress=progress, uint8_frame=True):
            if on_frame:
                on_frame(rec)
            yield rec["frame"]

    t0 = time.perf_counter()
    audio_from = (audio.result() or driver) if session.track.has_audio else None
    write_video(out, frames(), session.track.fps, audio_from=audio_from, overwrite=overwrite, inputs=inputs)
    tm = session.timings
    tm["render_pass_s"] = time.perf_counter() - t0
    tm["total_s"] = time.perf_counter() - t_start
    tr = session.track
    return {
        "output": str(out),
        "frames": tr.n_frames,
        "lost_frames": tr.n_lost,
        "lost_indices": [int(i) for i in np.flatnonzero(~tr.found)],
        "lost_causes": tr.lost_causes,
        "fps": tr.fps,
        "audio": tr.has_audio and video_info(out)["has_audio"],  # False when the driver's audio was damaged
        "puppet_shape": session.puppeteer.shape_source,
        "driver_collection": session.collection.source,
        # its glasses' rims were kept in front of the puppet (with the default occlusion)
        "driver_glasses": session.puppeteer.glasses,
        "timings": {k: round(v, 3) for k, v in tm.items()},
    }
