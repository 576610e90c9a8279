"""Building a persona from a folder of photos (Tom Hanks §5, and §4 for its average 3D face): per
photo, face and landmarks, frontalization and fiducials (in worker processes); then the collection's
alignment to its mean fiducials and the average shape (see :mod:`facetex.persona.collection`)."""

from __future__ import annotations

import multiprocessing
import os
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Callable

import cv2
import numpy as np

from ..errors import BadImageError, BadInputError, FacetexError
from .align import (
    appearance_subspace,
    collection_flow,
    compose_map_flow,
    face_region,
    remap_stack,
    tps_maps,
)
from .collection import IMAGE_EXTENSIONS, SUBSPACE_DTYPE, Persona, PersonaParams

__all__ = [
    "build_persona",
    "process_photo",
    "average_shape",
    "average_depth",
    "shape_split",
    "shape_photo_indices",
    "SHAPE_STEPS",
]


# ------------------------------------------------------------------------- building
def _list_photos(folder: Path) -> list[Path]:
    if not folder.is_dir():
        raise BadInputError("photo folder not found: give a folder of photos of one person", path=folder)
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise BadInputError(
            f"no images ({', '.join(IMAGE_EXTENSIONS)}) in the photo folder: give a folder of photos of one person",
            path=folder)
    return files


def _init_worker(parent: int | None = None) -> None:
    import signal

    from .._parallel import die_with

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the whole group: the parent stops us
    if parent is not None:
        die_with(parent)  # also when the parent is SIGKILLed (it cannot stop us then)
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # torch (identity descriptor) is imported after this
    cv2.setNumThreads(1)


def process_photo(path, params: PersonaParams = PersonaParams()) -> dict:
    """Detect, check and frontalize one photo. Returns {"file", "image", "visibility",
    "fiducials", "points68", "pose"} or {"file", "reason"} when the photo is unusable."""
    from ..geometry.frontalize import frontalize
    from ..io import DETECT_MAX_PIXELS, read_image
    from .._landmark_fit import refine_landmarks
    from ..landmarks import POINTS49_INDEX, detect_faces

    path = Path(path)
    name = path.name
    try:
        img = read_image(path, reduce_to=DETECT_MAX_PIXELS)  # a huge photo costs at most ~1 GB
    except BadImageError as e:
        return {"file": name, "reason": f"unreadable ({e.message})"}
    faces = detect_faces(img, upsample=None)
    if not faces:
        return {"file": name, "reason": "no face found"}
    if len(faces) > 1 and faces[1].area > params.dominant_ratio * faces[0].area:
        return {"file": name, "reason": f"{len(faces)} faces of similar size, none dominant"}
    # upscaled and refitted as the driver's tracker reads a frame (a photo's expression and a
    # driver's are compared); not a dark face's mouth at a normalised exposure: on Williams' photos
    # that cost 0.005 leave-out mouth SSIM
    points = faces[0].points68
    if params.landmark_face_px:
        try:
            points = refine_landmarks(img, faces[0].box, points, face_px=params.landmark_face_px,
                                      refits=params.landmark_refits, exposure=False,
                                      mirror=params.landmark_mirror)
        except FacetexError:  # a box the refit cannot use: the detector's own points stay
            pass
    try:
        fr = frontalize(img, points, size=params.size)
    except FacetexError as e:
        return {"file": name, "reason": f"frontalization failed ({e.message})"}
    pose = (fr.pose.yaw, fr.pose.pitch, fr.pose.roll)
    if abs(pose[0]) > params.max_yaw:
        return {"file": name, "reason": f"extreme pose (yaw {pose[0]:.0f} deg > {params.max_yaw:.0f})"}
    p68 = np.asarray(fr.points68, np.float64)
    from .identity import photo_descriptor

    try:
        descriptor = photo_descriptor(img, faces[0].points68)  # who it is (a collection is one person)
    except FacetexError:
        descriptor = None
    return {
        "file": name,
        "descriptor": descriptor,
        "image": np.clip(np.rint(fr.image * 255), 0, 255).astype(np.uint8),
        "visibility": np.clip(np.rint(fr.visibility * 255), 0, 255).astype(np.uint8),
        "fiducials": p68[POINTS49_INDEX].copy(),
        "points68": p68,
        "pose": pose,
    }


def _process_star(args):
    import warnings

    with warnings.catch_warnings(record=True) as caught:  # re-emitted by the parent (not a worker's stderr)
        warnings.simplefilter("always")
        r = process_photo(*args)
    r["warnings"] = [str(w.message) for w in caught]
    return r


class _Pool:
    """``jobs`` worker processes (forkserver: safe after OpenCV / BLAS threads ran in the
    parent), kept for all passes of a build; jobs <= 1 runs in this process. A worker that
    dies (killed, out of memory) fails the build with an error instead of hanging it
    (concurrent.futures notices dead workers; multiprocessing.Pool waits forever)."""

    def __init__(self, jobs: int):
        self.jobs = max(1, int(jobs))
        self.pool = None

    def __enter__(self):
        if self.jobs > 1:
            from .._parallel import short_socket_folder

            short_socket_folder()  # the forkserver's socket path must fit (a long TMPDIR)
            self.pool = ProcessPoolExecutor(self.jobs, mp_context=multiprocessing.get_context("forkserver"),
                                            initializer=_init_worker, initargs=(os.getpid(),))
        return self

    def __exit__(self, *exc):
        if self.pool is None:
            return
        if exc[0] is None:
            self.pool.shutdown(wait=True)
            return
        # interrupted or failed: stop the workers now, then reap them. CPython 3.11's executor
        # thread may then set an exception on a future that was just cancelled and print an
        # InvalidStateError traceback from its thread (a race fixed in 3.12): not ours to show
        import threading
        from concurrent.futures import InvalidStateError

        from .._parallel import terminate_workers

        previous = threading.excepthook

        def quiet(args):
            if not issubclass(args.exc_type, InvalidStateError):
                previous(args)

        threading.excepthook = quiet
        try:
            terminate_workers(self.pool)
            self.pool.shutdown(wait=True, cancel_futures=True)
        finally:
            threading.excepthook = previous

    def map(self, func, items, *, progress: Callable | None = None, **postfix) -> list:
        """``[func(x) for x in items]`` in order; progress(n=1, **postfix) per item."""
        items = list(items)
        if self.pool is None or len(items) <= 1:
            it = map(func, items)
        else:
            from .._parallel import main_script_hidden

            with main_script_hidden():  # the workers start on submission: a plain script is not re-run
                it = self.pool.map(func, items)
        out = []
        try:
            for r in it:
                out.append(r)
                if progress:
                    progress(n=1, **postfix)
        except BrokenProcessPool:
            raise FacetexError("a worker process died (out of memory or killed): retry with --jobs 1") from None
        return out


def build_persona(photo_dir, *, jobs: int = 2, progress: Callable | None = None,
                  params: PersonaParams | None = None, files=None, allow_mixed: bool = False) -> Persona:
    """Build a :class:`Persona` from a folder of photos of one person.

    Per photo (``jobs`` processes, results in file-name order): detect, frontalize,
    pose-correct the fiducials; unusable photos are skipped and listed with the reason.
    Then align the collection to its mean fiducials (TPS + collection flow).
    Last, the average 3D face (:func:`average_shape`) is stored as ``depth`` when it passed its
    photometric validation (all NaN otherwise), its report as ``shape_report``.
    ``progress(n=1, stage=...)`` is called once per photo for each of the two passes
    (then :data:`SHAPE_STEPS` steps of the average shape, each stage named: :func:`average_shape`).
    ``files`` restricts the build to these paths (e.g. leave-out evaluation).
    Raises BadInputError (naming the folder) when it holds no images or fewer than
    ``params.min_photos`` usable photos. The photos must show one person
    (:mod:`facetex.persona.identity`): photos of other people are left out when the main
    identity holds >= 80 % of them, else MixedCollectionError, unless ``allow_mixed``.
    """
    params = params or PersonaParams()
    folder = Path(photo_dir)
    paths = _list_photos(folder) if files is None else [Path(f) for f in files]
    if not paths:
        raise BadInputError("no photos given", path=folder)
    with _Pool(jobs) as pool:
        persona = _build(folder, paths, params, pool, progress, allow_mixed)
    return persona


def _build(folder: Path, paths: list[Path], params: PersonaParams, pool: _Pool, progress,
           allow_mixed: bool = False) -> Persona:
    import warnings

    from .identity import select_main_identity

    results = pool.map(_process_star, [(p, params) for p in paths], progress=progress, stage="frontalize")
    for r in results:
        for w in r.pop("warnings", ()):
            warnings.warn(w, stacklevel=2)
    good = [r for r in results if "reason" not in r]
    skipped = [r for r in results if "reason" in r]
    good, other_people = select_main_identity(good, allow_mixed=allow_mixed, path=folder)
    skipped += other_people
    if len(good) < params.min_photos:
        reasons = {}
        for r in skipped:
            key = r["reason"].split(" (")[0]
            reasons[key] = reasons.get(key, 0) + 1
        summary = ", ".join(f"{v} {k}" for k, v in reasons.items()) or "none skipped"
        raise BadInputError(
            f"only {len(good)} usable photos of {len(paths)} ({summary}); at least {params.min_photos} "
            "frontal-ish photos of one person are needed: add photos", path=folder)
    images = np.stack([r["image"] for r in good])
    fid = np.stack([r["fiducials"] for r in good])
    p68 = np.stack([r["points68"] for r in good])
    W, H = params.size
    M = fid.mean(axis=0)
    maps = tps_maps(fid, M, (H, W), params.tps_smoothing)
    warped = remap_stack(images, maps)
    region = face_region(p68.mean(axis=0), (H, W))
    subspace, proj = appearance_subspace(warped, region, params.subspace_rank)
    subspace = subspace.astype(SUBSPACE_DTYPE).astype(np.float32)  # the precision a .persona stores
    flows = collection_flow(warped, proj, params, pool=pool, progress=progress)
    persona = Persona(
        images=images,
        visibility=np.stack([r["visibility"] for r in good]),
        fiducials=fid,
        points68=p68,
        poses=np.array([r["pose"] for r in good], np.float64).reshape(-1, 3),
        flows=flows,
        subspace=subspace,
        photos=[r["file"] for r in good],
        skipped=[{"file": r["file"], "reason": r["reason"]} for r in skipped],
        params=params,
        source=str(folder),
    )
    depth, count, report = average_shape(persona, maps=maps, progress=progress)
    persona.shape_report = report
    if report.get("accepted"):
        persona.depth, persona.depth_photos = depth, count
    else:  # rejected: the generic face is used (the report says why)
        persona.depth, persona.depth_photos = np.full(depth.shape, np.nan, np.float32), 0
    persona._cache["tps_maps"] = maps  # reused by the texture precomputation
    return persona


def shape_photo_indices(n: int, shape_photos: int) -> np.ndarray:
    """Indices of the at most ``max(4, shape_photos)`` evenly spaced photos (of n)."""
    step = max(1, -(-int(n) // max(4, int(shape_photos))))
    return np.arange(0, int(n), step)


#: Share of a collection held out to validate its average shape photometrically, and the
#: fewest photos for a validated shape (8 to fit the rank-4 factorization, 3 to validate).
SHAPE_HOLDOUT = 0.2
MIN_SHAPE_PHOTOS = 11
#: At most this many held-out photos are used (the validation's cost grows with them).
MAX_SHAPE_HOLDOUT = 60


def shape_split(n: int, shape_photos: int) -> tuple[np.ndarray, np.ndarray]:
    """(training, held-out) photo indices of the average shape: every 5th photo (at least 3) is
    held out for the photometric validation; the training photos are at most ``shape_photos``
    evenly spaced ones of the rest."""
    n = int(n)
    k = min(MAX_SHAPE_HOLDOUT, max(3, int(round(SHAPE_HOLDOUT * n))))
    held = np.unique(np.linspace(0, n - 1, k).round().astype(int)) if n >= MIN_SHAPE_PHOTOS else np.zeros(0, int)
    rest = np.setdiff1d(np.arange(n), held)
    train = rest[shape_photo_indices(len(rest), shape_photos)]
    return train, held


def _aligned_with_visibility(persona: Persona, idx: np.ndarray, maps: np.ndarray | None):
    W, H = persona.size
    sel = (tps_maps(persona.fiducials[idx], persona.mean_fiducials, (H, W), persona.params.tps_smoothing)
           if maps is None else maps[idx])
    amaps = compose_map_flow(sel, persona.flows[idx])
    return remap_stack(persona.images[idx], amaps), remap_stack(persona.visibility[idx], amaps)


#: progress steps of :func:`average_shape` (the build's bar counts them after its two passes over the photos)
SHAPE_STEPS = 4


def average_shape(persona: Persona, *, maps: np.ndarray | None = None, shape_photos: int | None = None,
                  progress: Callable | None = None) -> tuple[np.ndarray, int, dict]:
    """The persona's average 3D face (Tom Hanks Sec. 4) with its photometric validation:
    (depth (H, W) float32 canonical px, NaN off the face region; training photos; report).

    Robust, visibility-weighted photometric stereo
    (:func:`facetex.puppet.shape.reconstruct_average_shape`) on at most ``shape_photos``
    (default ``persona.params.shape_photos``) photos aligned to the neutral frame (TPS +
    collection flow), with their own visibility (the mirrored fill counts 0); then
    :func:`facetex.puppet.shape.validate_shape` on the held-out photos (:func:`shape_split`).
    The report (JSON-able) holds the validation numbers and the verdict; the depth is the
    reconstruction whether accepted or not (``report["accepted"]`` says which). ``progress(n=,
    stage=)``: :data:`SHAPE_STEPS` steps in all, each stage named before it runs (the whole stage
    takes ~10 s for 500 photos: a bar standing at its end without a word looked stuck)."""
    from ..puppet.shape import reconstruct_average_shape, validate_shape

    done = 0

    def step(stage: str, n: int = 1) -> None:
        nonlocal done
        if progress:
            progress(n=n, stage=stage)
        done += n

    W, H = persona.size
    n = len(persona)
    train, held = shape_split(n, persona.params.shape_photos if shape_photos is None else shape_photos)
    nan = np.full((H, W), np.nan, np.float32)
    base = {"method": "robust visible-half photometric stereo, symmetric, bas-relief fixed by the generic face",
            "train_photos": int(len(train)), "heldout_photos": int(len(held))}
    def finish(*result):
        step("shape done", SHAPE_STEPS - done)  # the bar ends its steps whichever way the stage ends
        return result

    if len(held) < 3 or len(train) < 8:
        return finish(nan, 0, {**base, "accepted": False,
                               "reason": f"too few photos ({n}) to reconstruct and validate a shape: at least "
                                         f"{MIN_SHAPE_PHOTOS} usable photos are needed"})
    region = face_region(persona.points68.mean(axis=0), (H, W))
    step("shape: aligning photos", 0)
    imgs, vis = _aligned_with_visibility(persona, train, maps)
    step("shape: photometric stereo")
    try:
        shape = reconstruct_average_shape(imgs, region, visibility=vis)
    except (BadInputError, np.linalg.LinAlgError) as e:
        return finish(nan, 0, {**base, "accepted": False, "reason": f"reconstruction failed ({e})"})
    if not np.isfinite(shape.depth[region]).any():
        return finish(nan, 0, {**base, "accepted": False, "reason": "reconstruction gave no finite depth"})
    step("shape: aligning held-out photos")
    himgs, hvis = _aligned_with_visibility(persona, held, maps)
    step("shape: validating")
    val = validate_shape(shape.depth, imgs, vis, himgs, hvis, region)
    return finish(shape.depth.astype(np.float32), int(len(train)), {**base, **val.as_dict()})


def average_depth(persona: Persona, *, maps: np.ndarray | None = None,
                  shape_photos: int | None = None) -> tuple[np.ndarray, int]:
    """The persona's validated average 3D face: (depth (H, W) float32 canonical px, NaN off the
    face region, training photos) from :func:`average_shape` when it passed its photometric
    validation; all NaN and 0 otherwise (callers then fall back to the generic face,
    :func:`facetex.puppet.shape.checked_depth`)."""
    depth, count, report = average_shape(persona, maps=maps, shape_photos=shape_photos)
    persona._cache["shape_report"] = report
    if not report.get("accepted"):
        W, H = persona.size
        return np.full((H, W), np.nan, np.float32), 0
    return depth, count
