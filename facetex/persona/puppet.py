"""Persona puppetry: drive one person's 3D face with another person's video (Tom Hanks §4, §6).

Per driver video (see :mod:`facetex.persona.driver` for the motion):

1. **Average shapes.** Puppet: photometric stereo on the persona's aligned photos
   (:func:`facetex.persona.shape.reconstruct_average_shape`, computed when the persona is
   built and stored in the ``.persona``; checked against the generic face by
   :func:`facetex.persona.shape.checked_depth`). Driver: from
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
   (:class:`facetex.persona.deform.DeformationTransfer`) on a depth-map grid of 2 px.
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
   ``mode="composite"``: put into the driver's frame (:mod:`facetex.persona.composite`:
   the driver's face outline as mask, SH lighting and colour transfer, Poisson blending, the
   driver's mouth interior); ``mode="face"``: the puppet alone on a plain background, as in
   the paper's figures. Frames where the driver's face is lost, partly outside the frame or
   implausible (:func:`facetex.persona.driver.track_driver`) show the driver's own frame
   (a plain frame in face mode) and are reported.

Beyond the paper, the puppet's lips start closed when the driver's are: the persona's average
texture often has parted lips (its photos talk and smile), so a constant lip motion sets the
puppet's mean lip gap to the driver's mean gap (scaled by the eye distances); the per-frame
motion then opens and closes it like the driver's.

Eyes likewise (``eye_rest``, ``lid_sync``): the eyelid landmarks follow the driver's
(:class:`facetex.persona.driver.LidFields`; the deformation transfer's smoothing all but removed a
blink), and a persona whose mean eyes are narrower than the driver's (LFW collections: eye aspect
ratio 0.21-0.29 against 0.31-0.34 of the GRID speakers; the puppet's eyes read as half shut) has
them opened to the driver's mean lid gap; the texture's eye-region weights see the opened lids
(:meth:`Puppeteer.target`), so photos with open eyes are blended there.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Callable, Iterator

import cv2
import numpy as np

from ..errors import BadInputError
from .composite import FACE_OVAL, INNER_LIPS, CompositeParams, composite_face, mouth_interior
from .deform import DeformationTransfer, DeformParams
from .driver import DriverMotion, DriverParams, DriverTrack, driver_motion, unfold_columns

__all__ = [
    "PuppetParams",
    "Puppeteer",
    "PuppetSession",
    "puppet_average_shape",
    "driver_collection",
    "collection_correspondence",
    "landmark_correspondence",
    "CORRESPONDENCES",
    "target_fiducials",
    "neutral_texture",
    "neutral_textures",
    "prepare_puppetry",
    "render_frames",
    "puppeteer",
    "MODES",
    "TEXTURES",
]

MODES = ("composite", "face")
TEXTURES = ("ours", "static")
CORRESPONDENCES = ("landmarks", "flow")


@dataclass(frozen=True)
class PuppetParams:
    """Driver-puppet correspondence: "landmarks" (ours, the default: a thin-plate spline between
    the two mean landmark sets) or "flow" (the paper's collection flow, Tom Hanks §6, with alpha,
    ratio, minWidth, outer, inner, SOR iterations; module doc, 2);
    texture "ours" (expression-dependent) or "static" (the average texture); weights of the
    expression-dependent texture: "regional" (ours, ``neighbours`` K of the per-region
    adaptive sigma) or "global" (the paper's Eq. 2/3 with ``sigma`` and alpha 1), see
    :meth:`texture_params`; weight_smoothing: the regional weights are made temporally coherent by a
    bilateral filter over frames (Gaussian of this many seconds) and expression distance
    (``weight_range`` x each frame's adaptive sigma), 0 = per frame
    (:func:`facetex.persona.weights.temporal_weights`; module doc, 4);
    plain: background colour of ``mode="face"``; composite: how the puppet is put into the
    driver's frame; supersample / supersample_composite: rasterization samples per pixel and
    axis in face / composite mode (anti-aliased silhouette; in composite mode the feathered
    driver outline is the edge, and the texture is low-passed to the pixel spacing either way);
    mouth_rest: the puppet's mean lip gap set to the driver's (module doc); lip_sync: the
    puppet's lip and jaw landmarks follow the driver's (:meth:`Puppeteer.grid`); eye_rest: eyes
    narrower than the driver's are opened to the driver's mean lid gap (scaled), lid_sync: the
    puppet's eyelids follow the driver's (blinks; :meth:`Puppeteer.grid`); close_mouth: the
    texture's mouth interior is filled from its lips as the driver's lips close
    (:func:`facetex.persona.composite.fill_mouth_interior`: no teeth sliver between closed lips);
    max_depth_error: a reconstructed average depth whose RMS
    difference to the generic face exceeds this fraction of the frame width is replaced by
    the generic depth (too few or too uniformly lit photos); shape "generic" skips the
    photometric-stereo reconstruction of the puppet and uses the generic face's depth;
    shape_photos: at most this many (evenly spaced) photos feed the photometric stereo (its SVD
    grows with the square of the count; a few dozen lightings determine the rank-4 factorization)."""

    flow_alpha: float = 0.02
    flow_ratio: float = 0.85
    flow_min_width: int = 20
    flow_outer: int = 4
    flow_inner: int = 1
    flow_sor: int = 40
    correspondence: str = "landmarks"
    sigma: float = 10.0
    texture: str = "ours"
    weights: str = "regional"
    neighbours: int = 3
    weight_smoothing: float = 0.12
    weight_range: float = 1.0
    plain: tuple[float, float, float] = (0.5, 0.5, 0.5)
    composite: CompositeParams = field(default_factory=CompositeParams)
    supersample: int = 2
    supersample_composite: int = 1
    mouth_rest: bool = True
    lip_sync: bool = True
    brow_rest: bool = True
    brow_sync: bool = True
    eye_rest: bool = True
    lid_sync: bool = True
    close_mouth: bool = True
    max_depth_error: float = 0.08
    shape: str = "collection"
    shape_photos: int = 128
    deform: DeformParams = field(default_factory=DeformParams)
    driver: DriverParams = field(default_factory=DriverParams)

    @property
    def needs_average_face(self) -> bool:
        """Whether the puppet needs the persona's average face (Fig. 6 d): the flow
        correspondence projects it, the static texture is it."""
        return self.texture == "static" or self.correspondence == "flow"

    def texture_params(self):
        """The :class:`facetex.persona.TextureParams` of the puppet's textures: the persona
        texture's defaults with the regional weights, :meth:`TextureParams.paper` with the
        global ones (both the static average and the blends use them, so one precomputation
        serves all)."""
        from .texture import WEIGHTS, TextureParams

        if self.weights not in WEIGHTS:
            raise BadInputError(f"unknown puppet texture weights {self.weights!r}: use one of {', '.join(WEIGHTS)}")
        if not self.weight_smoothing >= 0:
            raise BadInputError(f"weight smoothing must be >= 0 seconds, got {self.weight_smoothing}")
        if self.weights == "global":
            return TextureParams.paper(sigma=self.sigma)
        return TextureParams(neighbours=self.neighbours)


# ----------------------------------------------------------------------------- shapes
def puppet_average_shape(persona, params: PuppetParams = PuppetParams()) -> tuple[np.ndarray, np.ndarray, str]:
    """(depth (H, W) canonical px, mask (H, W) bool, source "collection" | "generic") of the
    persona's average 3D face (Tom Hanks §4): the one stored in the .persona (computed at
    build time), else computed now (version-1 files); cached on the persona object."""
    from .align import face_region
    from .collection import average_depth
    from .shape import checked_depth

    key = ("puppet_shape", params.max_depth_error, params.shape, params.shape_photos)
    if key not in persona._cache:
        W, H = persona.size
        region = face_region(persona.points68.mean(axis=0), (H, W))
        depth = None
        if params.shape == "collection":
            stored = persona.depth is not None and params.shape_photos == persona.params.shape_photos
            depth = persona.depth if stored else average_depth(persona, shape_photos=params.shape_photos)[0]
        depth, src = checked_depth(depth, region, persona.size, params.max_depth_error)
        persona._cache[key] = (depth, region, src)
    return persona._cache[key]


@dataclass(eq=False)
class DriverCollection:
    """The driver's canonical-frame collection data: subspace (1 + rank, H, W, 3) (mean first),
    region (H, W) bool, depth (H, W) or None (use the tracked mean mesh), source text."""

    subspace: np.ndarray | None  # None: tracked without frontal images (landmark correspondence)
    region: np.ndarray
    depth: np.ndarray | None
    source: str


def driver_collection(track: DriverTrack, *, driver_photos=None, params: PuppetParams = PuppetParams(),
                      progress: Callable | None = None) -> DriverCollection:
    """The driver's 2D average, appearance subspace and (with photos) average shape.

    From ``driver_photos`` (a folder): a persona build of it (fewest photos 4). Otherwise the
    frontalized video frames kept by :func:`~facetex.persona.driver.track_driver`, TPS-aligned to
    their mean fiducials."""
    from ..landmarks import POINTS49_INDEX
    from .align import appearance_subspace, face_region, remap_stack, tps_maps
    from .collection import PersonaParams, build_persona
    from .shape import checked_depth

    W, H = params.driver.size
    if driver_photos is not None:
        dp = build_persona(driver_photos, jobs=1, progress=progress,
                           params=PersonaParams(size=(W, H), min_photos=4, shape_photos=params.shape_photos))
        region = face_region(dp.points68.mean(axis=0), (H, W))
        depth, src = checked_depth(dp.depth, region, (W, H), params.max_depth_error)
        return DriverCollection(dp.subspace, region, depth, f"photos ({len(dp)}, shape: {src})")
    if len(track.frontal) == 0:  # tracked for the landmark correspondence: no appearance subspace
        region = face_region(track.frontal_points68.mean(axis=0), (H, W))
        return DriverCollection(None, region, None, f"video frames ({len(track.frontal_points68)} landmark sets, "
                                                    "shape: tracked mean mesh)")
    fid = track.frontal_points68[:, POINTS49_INDEX]
    M = fid.mean(axis=0)
    maps = tps_maps(fid, M, (H, W), 10.0)
    warped = remap_stack(track.frontal, maps)
    region = face_region(track.frontal_points68.mean(axis=0), (H, W))
    sub, _ = appearance_subspace(warped, region, 4)
    return DriverCollection(sub, region, None, f"video frames ({len(warped)}, shape: tracked mean mesh)")


def collection_correspondence(driver_subspace: np.ndarray, driver_region: np.ndarray, puppet_average: np.ndarray,
                              params: PuppetParams = PuppetParams()) -> np.ndarray:
    """(H, W, 2) puppet-frame (x, y) of every driver-frame pixel (Tom Hanks §4, §6): the flow
    from the projection of the puppet's average onto the driver's appearance subspace to the
    puppet's average (illumination-matched pair; collection flow)."""
    from ..geometry.flow import map_from_flow, optical_flow
    from .align import project_onto_subspace

    proj = np.clip(project_onto_subspace(puppet_average, driver_subspace, driver_region), 0, 1)
    flow = optical_flow(proj, puppet_average, alpha=params.flow_alpha, ratio=params.flow_ratio,
                        min_width=params.flow_min_width, outer_iters=params.flow_outer,
                        inner_iters=params.flow_inner, sor_iters=params.flow_sor)
    return map_from_flow(flow)


def landmark_correspondence(driver_points68, puppet_points68, shape, smoothing: float = 10.0) -> np.ndarray:
    """(H, W, 2) puppet-frame (x, y) of every driver-frame pixel: the thin-plate spline (Eq. 1,
    ``smoothing`` λ) that maps the driver's mean landmarks (68, 2) onto the puppet's (both in the
    canonical frame). Smooth and fold-free, exact at the landmarks (module doc, 2)."""
    from .align import tps_map

    d = np.asarray(driver_points68, np.float64)
    p = np.asarray(puppet_points68, np.float64)
    if d.shape != (68, 2) or p.shape != (68, 2) or not (np.isfinite(d).all() and np.isfinite(p).all()):
        raise BadInputError(f"landmark correspondence needs two finite (68, 2) landmark sets, got {d.shape}, {p.shape}")
    return tps_map(d, p, shape, smoothing)


# ----------------------------------------------------------------------------- texture
def target_fiducials(persona, motion: DriverMotion, i: int) -> np.ndarray:
    """F^T (49, 2) for frame i: the puppet's mean fiducials plus the driver's expression
    offset, scaled by the ratio of eye-centre distances."""
    from .driver import _iod49

    M = persona.mean_fiducials
    k = _iod49(M) / max(motion.iod, 1e-9)
    return M + k * (motion.fiducials[i] - motion.mean_fiducials)


def neutral_texture(persona, fiducials, *, method: str = "ours", params=None, sigma: float | None = None
                    ) -> np.ndarray:
    """Texture (H, W, 3) in the persona's neutral frame (its mean fiducials) with the expression
    weights of the target ``fiducials`` (Tom Hanks §6: "we only synthesize textures in their
    neutral expressions for the average models but use the target expressions to calculate
    the blending weights"). ``params``: :class:`facetex.persona.TextureParams` (default: the
    regional weights); ``sigma``: the global weights' sigma. ``method`` "static": the
    expression-independent average (the stage-d average face)."""
    return neutral_textures(persona, [fiducials], method=method, params=params, sigma=sigma)[0]


def neutral_textures(persona, fiducials, *, method: str = "ours", params=None, sigma: float | None = None
                     ) -> list[np.ndarray]:
    """:func:`neutral_texture` for a sequence of target fiducials (B, 49, 2), blended together
    (:func:`facetex.persona.blend_textures`: one sparse product per region and pyramid level
    for the batch)."""
    import dataclasses

    from .texture import TextureParams, average_face, blend_textures

    if method not in TEXTURES:
        raise BadInputError(f"unknown puppet texture {method!r}: use one of {', '.join(TEXTURES)}")
    tp = params or TextureParams()
    if method == "static":
        key = ("puppet_static", tp.stack_key(), tp.sigma)
        if key not in persona._cache:
            persona._cache[key] = average_face(persona, "d", params=tp)
        return [persona._cache[key]] * len(fiducials)
    if sigma is not None and tp.weights == "global":
        tp, sigma = dataclasses.replace(tp, sigma=float(sigma)), None
    return list(blend_textures(persona, np.asarray(fiducials, np.float64), params=tp, sigma=sigma))


# ----------------------------------------------------------------------------- puppeteer
def grid_normals(grid: np.ndarray) -> np.ndarray:
    """Unit normals (h, w, 3) of a depth-map grid mesh (h, w, 3): cross product of its
    row and column tangents (central differences; NaN vertices give NaN neighbours' normals)."""
    g = np.asarray(grid, np.float64)
    dy, dx = np.gradient(g, axis=(0, 1))
    n = np.cross(dx, dy)
    nn = np.linalg.norm(n, axis=2, keepdims=True)
    return np.divide(n, nn, out=np.zeros_like(n), where=nn > 1e-12)


def landmark_field(persona, kind: str, step: int):
    """The persona's :class:`~facetex.persona.driver.LipFields` ("lips"), ``BrowFields`` ("brows")
    or ``LidFields`` ("lids") at its mean landmarks on its depth-map grid of ``step`` px, cached on
    the persona: they depend on the persona alone, so the puppet's setup makes them beside the
    driver's tracking (:func:`prepare_puppetry`)."""
    key = ("landmark_field", kind, int(step))
    if key not in persona._cache:
        from .driver import BrowFields, LidFields, LipFields

        W, H = persona.size
        gy, gx = np.mgrid[0:H:step, 0:W:step].astype(np.float64)
        cls = {"lips": LipFields, "brows": BrowFields, "lids": LidFields}[kind]
        persona._cache[key] = cls(persona.points68.mean(axis=0), np.stack([gx, gy], axis=-1))
    return persona._cache[key]


def _landmark_fields_used(params: PuppetParams) -> tuple[str, ...]:
    """The kinds of :func:`landmark_field` a puppet with ``params`` moves its grid by."""
    return tuple(k for k, on in (("lips", params.mouth_rest or params.lip_sync),
                                 ("brows", params.brow_rest or params.brow_sync),
                                 ("lids", params.eye_rest or params.lid_sync)) if on)


class Puppeteer:
    """Puppet mesh, texture and rendering for each frame of a driver motion.

    Precomputes (once): the puppet's and the driver's average meshes on the depth-map grid,
    their correspondence and the :class:`DeformationTransfer`, the puppet's triangulation."""

    def __init__(self, persona, motion: DriverMotion, collection: DriverCollection,
                 params: PuppetParams = PuppetParams(), track: DriverTrack | None = None):
        from .mesh_io import depth_to_mesh

        self.persona, self.motion, self.params, self.track = persona, motion, params, track
        self._sequence_weights = None
        st = motion.grid_step
        W, H = persona.size
        if (W, H) != tuple(params.driver.size):
            raise BadInputError(f"the persona's canonical frame {W}x{H} differs from the driver's "
                                f"{params.driver.size}: rebuild the persona at {params.driver.size}")
        self.timings: dict[str, float] = {}
        t0 = time.perf_counter()
        depth, region, self.shape_source = puppet_average_shape(persona, params)
        gy, gx = np.mgrid[0:H:st, 0:W:st].astype(np.float64)
        pmask = region[::st, ::st] & np.isfinite(depth[::st, ::st])
        self.puppet_grid = np.stack([gx, gy, depth[::st, ::st]], axis=-1)
        self.puppet_mask = pmask
        self.timings["puppet_shape_s"] = time.perf_counter() - t0
        # driver mesh on the grid: photo-collection depth if given, else the tracked mean mesh
        dmesh = motion.grid_mesh.copy()
        dmask = motion.grid.mask.copy()
        if collection.depth is not None:
            dmesh[..., 2] = collection.depth[::st, ::st]
            dmask &= collection.region[::st, ::st]
        t0 = time.perf_counter()
        if params.correspondence not in CORRESPONDENCES:
            raise BadInputError(f"unknown puppet correspondence {params.correspondence!r}: use one of "
                                f"{', '.join(CORRESPONDENCES)}")
        if params.correspondence == "flow" or motion.frontal_mean68 is None:
            if collection.subspace is None:
                raise BadInputError("the flow correspondence needs the driver's frontalized frames: track the driver "
                                    "with frontal_images=True")
            corr = collection_correspondence(collection.subspace, collection.region, self.puppet_average, params)
        else:  # the mesh's canonical frame is fitted to the driver's mean frontal landmarks
            corr = landmark_correspondence(motion.frontal_mean68, persona.points68.mean(axis=0),
                                           (H, W), persona.params.tps_smoothing)
        self.correspondence = corr
        corr_grid = (corr[::st, ::st] / st).astype(np.float32)
        self.timings["correspondence_s"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        self.transfer = DeformationTransfer(dmesh, self.puppet_grid, corr_grid, driver_mask=dmask,
                                            puppet_mask=pmask, params=params.deform)
        self.timings["transfer_setup_s"] = time.perf_counter() - t0
        depth_for_mesh = np.where(pmask, self.puppet_grid[..., 2], np.nan)
        _, self.faces, self.uv = depth_to_mesh(depth_for_mesh, pmask)
        # lighting sees the average shape's normals: the expression's folds at the lips and the
        # grid's creases would print as shading artifacts, and low-frequency lighting hardly changes
        self.rest_normals = grid_normals(self.puppet_grid)[pmask]
        self.mean68 = persona.points68.mean(axis=0)  # the texture's frame (its 49 points: the mean fiducials)
        self.lip_fields = None
        if self.motion.fiducials68 is not None and (params.mouth_rest or params.lip_sync):
            from .driver import _iod49

            self.lip_fields = landmark_field(persona, "lips", st)
            self.lip_scale = _iod49(persona.mean_fiducials) / max(motion.iod, 1e-9)
        self.rest_move = self._rest_motion() if params.mouth_rest and self.lip_fields is not None else None
        self.brow_fields = self.brow_rest = None
        if self.motion.fiducials68 is not None and (params.brow_rest or params.brow_sync):
            from .driver import _iod49

            self.brow_fields = landmark_field(persona, "brows", st)
            self.brow_scale = _iod49(persona.mean_fiducials) / max(motion.iod, 1e-9)
            if params.brow_rest:
                self.brow_rest = self._brow_rest_motion()
        self.lid_fields, self.eye_move = None, None
        if self.motion.fiducials68 is not None and (params.eye_rest or params.lid_sync):
            from .driver import _iod49

            self.lid_fields = landmark_field(persona, "lids", st)
            self.lid_scale = _iod49(persona.mean_fiducials) / max(motion.iod, 1e-9)
            if params.eye_rest:
                self.eye_move = self._eye_rest_motion()

    @property
    def puppet_average(self) -> np.ndarray:
        """The persona's average face (Fig. 6 d; cached on the persona): computed when first
        needed (the flow correspondence, the static texture), not for every puppet."""
        from .texture import average_face

        return average_face(self.persona, "d", params=self.params.texture_params())

    def _rest_motion(self) -> np.ndarray:
        """(68, 2) constant motion of the puppet's lip landmarks that makes its mean inner-lip gap
        the driver's mean gap (scaled by the ratio of eye distances)."""
        m = self.motion
        P = self.mean68
        D = m.fiducials68[m.found].mean(axis=0)
        k = self.lip_scale
        move = np.zeros((68, 2))
        for up, lo in ((61, 67), (62, 66), (63, 65)):
            change = k * (D[lo] - D[up]) - (P[lo] - P[up])  # > 0: open the puppet's lips
            move[up] -= change / 2
            move[lo] += change / 2
        upper, lower = move[[61, 62, 63]].mean(axis=0), move[[65, 66, 67]].mean(axis=0)
        move[[49, 50, 51, 52, 53]] = upper
        move[[55, 56, 57, 58, 59, 7, 8, 9]] = lower
        move[[5, 6, 10, 11]] = lower / 2
        return move

    def _brow_rest_motion(self) -> np.ndarray:
        """(68, 2) constant motion of the puppet's brows (17-26) that gives each of its mean brows
        the tilt and mean height above the eye line (over the eye distance) of the driver's mean
        brow: the difference of the two least-squares lines (height on position along the eye
        line), moved along the eye line's normal. The brow's own curve stays the puppet's."""
        from .driver import brow_heights

        m = self.motion
        P, D = self.mean68, m.fiducials68[m.found].mean(axis=0)

        def along(F):  # brow points' positions along the eye line, over the eye distance
            a, b = F[36:42].mean(axis=0), F[42:48].mean(axis=0)
            e = b - a
            return (F[17:27] - (a + b) / 2) @ e / float(e @ e)

        e = P[42:48].mean(axis=0) - P[36:42].mean(axis=0)
        up = np.array([e[1], -e[0]])  # eye-distance long, upwards
        xp, xd, hp, hd = along(P), along(D), brow_heights(P), brow_heights(D)
        move = np.zeros((68, 2))
        for side in (slice(0, 5), slice(5, 10)):
            lp, ld = np.polyfit(xp[side], hp[side], 1), np.polyfit(xd[side], hd[side], 1)
            move[17:27][side] = (np.polyval(ld, xp[side]) - np.polyval(lp, xp[side]))[:, None] * up
        return move

    def _eye_rest_motion(self) -> np.ndarray:
        """(68, 2) constant motion of the puppet's eyelid landmarks that opens each lid pair whose
        mean gap is smaller than the driver's mean gap (scaled by the ratio of eye distances) to
        that gap, 70 % by the upper lid. Why: LFW collections' mean eyes are narrow (news photos:
        squints, smiles, flash; eye aspect ratio 0.21-0.29 against 0.31-0.34 of GRID speakers), and
        a puppet whose eyes are a third narrower than the driver's reads as half shut."""
        from .driver import _LOWER_LIDS, _UPPER_LIDS

        m = self.motion
        P = self.mean68
        D = m.fiducials68[m.found].mean(axis=0)
        move = np.zeros((68, 2))
        for up, lo in zip(_UPPER_LIDS, _LOWER_LIDS):
            change = max(0.0, self.lid_scale * (D[lo, 1] - D[up, 1]) - (P[lo, 1] - P[up, 1]))
            move[up, 1] -= 0.7 * change
            move[lo, 1] += 0.3 * change
        return move

    def target(self, i: int) -> np.ndarray:
        """F^T (49, 2) of frame i for the texture weights: :func:`target_fiducials` with the
        eyelids' rest motion (:meth:`_eye_rest_motion`), so the eye region's photos are chosen
        with the eyes as open as the mesh shows them."""
        f = target_fiducials(self.persona, self.motion, i)
        if self.eye_move is not None:
            from ..landmarks import POINTS49_INDEX

            f = f + self.eye_move[POINTS49_INDEX]
        return f

    def _sample_grid(self, grid: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Bilinear samples (P, 3) of a (h, w, 3) grid at canonical (x, y) ``points`` (P, 2)."""
        st = self.motion.grid_step
        q = np.asarray(points, np.float32) / st
        g = np.nan_to_num(grid).astype(np.float32)
        return cv2.remap(g, q[:, 0][None], q[:, 1][None], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)[0].astype(np.float64)

    def grid(self, i: int) -> np.ndarray:
        """Puppet mesh (h, w, 3) on its depth-map grid for frame i (M_P^i, Tom Hanks §4).

        Beyond the paper: its lip and jaw landmarks then move exactly as the driver's
        (scaled by the ratio of eye distances; :class:`facetex.persona.driver.LipFields`), on top of
        the constant rest motion (module doc): the deformation transfer's magnitude adjustment and
        Huber-ROF smoothing shrink the thin, fast lip motion by 10-25 % on GRID clips. Lips that
        close further than the puppet's mouth band is tall meet instead of folding the grid over
        (:func:`facetex.persona.driver.unfold_columns`). The brows likewise follow the driver's
        brow landmarks relative to the eye corners (:class:`facetex.persona.driver.BrowFields`; the
        face mesh moved them 0.2-0.4x as far), from the brow rest (:meth:`_brow_rest_motion`)."""
        g = self.transfer(self.motion.delta_field(i))
        g = self._lids(i, g)
        if self.lip_fields is None and self.brow_fields is None:
            return g
        m = self.motion
        have = None
        if ((self.params.lip_sync and self.lip_fields is not None)
                or (self.params.brow_sync and self.brow_fields is not None)):
            have = self._sample_grid(g - self.puppet_grid, self.mean68)[:, :2]
        g = g.copy()
        if self.brow_fields is not None:
            bmove = np.zeros((68, 2))
            if self.params.brow_sync:
                # each brow moves as the driver's relative to its eye corners (the lids' blinks and
                # squints are not the brow's), from where the puppet's corners are now: the deformation
                # transfer moves the eyes by the face mesh, not by the landmarks' motion
                d = m.fiducials68[i] - m.fiducials68[m.found].mean(axis=0)
                for brow, eye in ((slice(17, 22), [36, 39]), (slice(22, 27), [42, 45])):
                    bmove[brow] = (self.brow_scale * (d[brow] - d[eye].mean(axis=0)) + have[eye].mean(axis=0)
                                   - have[brow])
            if self.brow_rest is not None:
                bmove += self.brow_rest
            bf = self.brow_fields(bmove)
            for c in range(2):
                g[..., c] += bf[..., c] * self.puppet_mask
        if self.lip_fields is None:
            return unfold_columns(g, self.puppet_mask)
        move = np.zeros((68, 2))
        if self.params.lip_sync:
            move += self.lip_scale * (m.fiducials68[i] - m.fiducials68[m.found].mean(axis=0)) - have
        if self.rest_move is not None:
            move += self.rest_move
        lf = self.lip_fields(move)
        for c in range(2):  # per column: numpy broadcasts over a length-2 axis slowly
            g[..., c] += lf[..., c] * self.puppet_mask
        if self.params.lip_sync:
            # the smoothed splines (and the grid's bilinear sampling) move the landmarks ~6-20 %
            # short of their targets: one more pass with the remainder (lips opened 0.81-0.85 as
            # far as the driver's on GRID, 0.64 on a puppet with tight lips)
            want = have + move
            got = self._sample_grid(g - self.puppet_grid, self.mean68)[:, :2]
            lf = self.lip_fields(want - got)
            for c in range(2):
                g[..., c] += lf[..., c] * self.puppet_mask
        # lips that meet (or whose landmarks cross) must not fold the grid over: stair steps
        return unfold_columns(g, self.puppet_mask)

    def _lids(self, i: int, g: np.ndarray) -> np.ndarray:
        """The grid ``g`` with the puppet's eyelid landmarks moved as the driver's (scaled by the
        ratio of eye distances) on top of the eyes' rest motion (:class:`facetex.persona.driver.LidFields`):
        the deformation transfer's smoothing all but removes a blink's 2-4 px lid motion."""
        if self.lid_fields is None:
            return g
        move = np.zeros((68, 2))
        if self.params.lid_sync:
            m = self.motion
            want = self.lid_scale * (m.fiducials68[i] - m.fiducials68[m.found].mean(axis=0))
            have = self._sample_grid(g - self.puppet_grid, self.mean68)[:, :2]
            move += want - have
        if self.eye_move is not None:
            move += self.eye_move
        g = g.copy()
        lf = self.lid_fields(move)
        for c in range(2):
            g[..., c] += lf[..., c] * self.puppet_mask
        return g

    def mesh(self, i: int) -> np.ndarray:
        """Puppet vertices (V, 3) in its canonical frame for frame i (the grid's mask vertices)."""
        return self.grid(i)[self.puppet_mask]

    def texture(self, i: int, method: str | None = None) -> np.ndarray:
        """Texture (H, W, 3) of frame i in the puppet's neutral frame."""
        return self.textures([i], method)[0]

    def textures(self, frames, method: str | None = None) -> list[np.ndarray]:
        """Textures of several frames, blended as one batch (faster per frame)."""
        method = method or self.params.texture
        frames = list(frames)
        tp = self.params.texture_params()
        if self.uses_sequence_weights(method):
            from .texture import blend_weights

            tex = list(blend_weights(self.persona, self.sequence_weights()[frames], params=tp))
        else:
            tex = neutral_textures(self.persona, [self.target(i) for i in frames], method=method, params=tp)
        return self._close_interiors(frames, tex)

    def _close_interiors(self, frames: list, tex: list) -> list:
        """The textures with their mouth interior filled from the lips as the driver's mouth
        closes (:func:`facetex.persona.composite.fill_mouth_interior`; ``params.close_mouth``)."""
        from .composite import fill_mouth_interior, mouth_closure

        m = self.motion
        if not self.params.close_mouth or m.fiducials68 is None:
            return list(tex)
        lips = self.mean68[60:68]
        return [fill_mouth_interior(t, lips, mouth_closure(m.fiducials68[i][60:68])) for i, t in zip(frames, tex)]

    def uses_sequence_weights(self, method: str | None = None) -> bool:
        """Whether ``method``'s textures (default: the puppet's) blend the clip's temporally
        smoothed regional weights (:meth:`sequence_weights`)."""
        return ((method or self.params.texture) == "ours" and self.params.texture_params().weights == "regional"
                and self.params.weight_smoothing > 0)

    def sequence_weights(self) -> np.ndarray:
        """(N, R, n) temporally coherent regional weights of every frame of the clip (computed once;
        :func:`facetex.persona.texture.sequence_weights`)."""
        if self._sequence_weights is None:
            from .texture import sequence_weights

            fps = float(self.track.fps) if self.track is not None and self.track.fps else 25.0
            f = np.stack([self.target(i) for i in range(len(self.motion))])
            self._sequence_weights = sequence_weights(self.persona, f, self.params.texture_params(),
                                                      sigma_frames=self.params.weight_smoothing * fps,
                                                      range_scale=self.params.weight_range)
        return self._sequence_weights

    def pose(self, i: int, scale: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, b): output-panel pixel = A X + b of a canonical point X in frame i (driver pixels
        scaled by ``scale``, pixel centres at integers)."""
        A = self.motion.pose_A[i] * scale
        b = self.motion.pose_b[i] * scale
        b[:2] += 0.5 * scale - 0.5
        return A, b

    def lips(self, i: int, grid: np.ndarray, scale: float) -> np.ndarray:
        """The puppet's inner lips (8, 2) (iBUG 60-67) in output-panel px for frame i: its
        texture-frame inner lips carried by the deformed ``grid`` and projected."""
        X = self._sample_grid(grid, self.mean68[list(INNER_LIPS)])
        A, b = self.pose(i, scale)
        return X @ A[:2].T + b[:2]

    def layers(self, i: int, grid: np.ndarray, texture: np.ndarray, size, scale: float, supersample: int = 1,
               normals: bool = True):
        """:class:`facetex.persona.render.Layers` of the puppet in frame i (output panel ``size`` (W, H))."""
        from .render import render_layers

        A, b = self.pose(i, scale)
        return render_layers(grid[self.puppet_mask], self.faces, self.uv, texture, rotation=A, translation=b,
                             size=size, supersample=supersample, normals=self.rest_normals if normals else False)

    def render(self, i: int, grid: np.ndarray, texture: np.ndarray, frame: np.ndarray, scale: float,
               mode: str = "composite") -> tuple[np.ndarray, np.ndarray]:
        """(image, alpha) of the puppet in frame i: composited into ``frame`` (the driver's
        frame as an output panel (H, W, 3), ``scale`` panel px per driver px) or, with
        ``mode="face"``, alone on the plain background."""
        h, w = frame.shape[:2]
        ss = self.params.supersample if mode == "face" else self.params.supersample_composite
        sh = mode == "composite" and self.params.composite.lighting == "sh"
        lay = self.layers(i, grid, texture, (w, h), scale, ss, normals=sh)
        tr = self.track
        lips = self.lips(i, grid, scale)
        drv68 = (tr.points68[i] + 0.5) * scale - 0.5
        if mode == "face":
            bg = np.broadcast_to(np.asarray(self.params.plain, np.float32), (h, w, 3))
            cov = lay.coverage[..., None]
            img = cov * lay.image + (1 - cov) * bg
            if self.params.composite.mouth and np.isfinite(drv68).all():
                mi, ma = mouth_interior(frame, drv68[list(INNER_LIPS)], lips, (h, w))
                ma = (ma * lay.coverage)[..., None]
                img = ma * mi + (1 - ma) * img
            return img.astype(np.float32), lay.coverage
        oval = (tr.mesh[i][list(FACE_OVAL), :2] + 0.5) * scale - 0.5
        return composite_face(frame, lay.image, lay.coverage, lay.normals, driver_oval=oval, driver_points68=drv68,
                              puppet_lips=lips, driver_normals=self.driver_normals(i, (w, h), scale) if sh else None,
                              params=self.params.composite)

    def driver_normals(self, i: int, size, scale: float) -> np.ndarray | None:
        """(H, W, 3) unit normals of the driver's own tracked face mesh in frame i (output panel
        px), for estimating the lighting of the driver's frame with the driver's shape."""
        from .render import render_layers

        tri = self.motion.triangles
        mesh = self.track.mesh[i]
        if tri is None or not np.isfinite(mesh).all():
            return None
        v = mesh.copy()
        v[:, :2] = (v[:, :2] + 0.5) * scale - 0.5
        v[:, 2] *= scale
        lay = render_layers(v, tri, np.zeros((len(v), 2)), np.ones((1, 1, 3), np.float32), rotation=np.eye(3),
                            translation=np.zeros(3), size=size, supersample=1, prefilter=False)
        return lay.normals


@dataclass(eq=False)
class PuppetSession:
    """Everything prepared for rendering a driver video with a puppet."""

    track: DriverTrack
    motion: DriverMotion
    collection: DriverCollection
    puppeteer: Puppeteer
    timings: dict


def _load(persona):
    from .collection import Persona, load_persona

    return persona if isinstance(persona, Persona) else load_persona(persona)


def _persona_size(persona) -> tuple[int, int]:
    """Canonical frame (W, H) of a Persona or a .persona path (read from its header only)."""
    from .collection import Persona, read_persona_header

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
    from .texture import average_face, prepare_persona

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


#: longest side of an output panel (a 4K frame); larger sizes are refused before any work
MAX_OUTPUT_SIDE = 4096


def _even(v: float) -> int:
    return max(2, int(round(v / 2.0)) * 2)


def output_size(frame_size, size: int | None) -> tuple[int, int, float]:
    """(W, H, scale) of one output panel: the driver frame with its longer side ``size`` (even sides)."""
    w, h = frame_size
    if size is None:
        return _even(w), _even(h), 1.0
    if not 32 <= int(size) <= MAX_OUTPUT_SIDE:
        raise BadInputError(f"--size must be 32..{MAX_OUTPUT_SIDE} px, got {size}")
    s = float(size) / max(w, h)
    return _even(w * s), _even(h * s), s


#: frames whose textures are blended together (a batch reads the precomputed stack once)
TEXTURE_BATCH = 32
#: frames of the first batch (rendering waits for it)
FIRST_BATCH = 8
#: frames rendered ahead of the one being written
IN_FLIGHT = 4


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise BadInputError(f"unknown puppet mode {mode!r}: use one of {', '.join(MODES)}")


def render_frames(session: PuppetSession, *, size: int | None = None, mode: str = "composite",
                  side_by_side: bool = False, texture: str | None = None, max_frames: int | None = None,
                  keep: bool = False, progress: Callable | None = None) -> Iterator[dict]:
    """Yield per frame {"index", "driver" (panel), "puppet" (panel), "frame" (output), "alpha",
    "lost"} (with ``keep`` also "grid" and "texture", the frame's mesh and texture): the second
    pass over the driver video. Lost frames show the driver's panel (a plain panel in face
    mode) and alpha 0. Per-stage times accumulate in ``session.timings`` (mesh_s, texture_s,
    render_s; mesh and texture overlap rendering)."""
    from concurrent.futures import ThreadPoolExecutor

    from ..io import iter_video_frames

    _check_mode(mode)
    pup = session.puppeteer
    W, H, scale = output_size(session.track.frame_size, size)
    n = session.track.n_frames if max_frames is None else min(session.track.n_frames, max(0, int(max_frames)))
    tm = session.timings
    for key in ("mesh_s", "texture_s", "render_s"):
        tm.setdefault(key, 0.0)

    lock = threading.Lock()

    def add_time(key: str, dt: float) -> None:
        with lock:
            tm[key] += dt

    def meshes_and_textures(i0: int, i1: int) -> list:
        frames = range(i0, i1)
        t0 = time.perf_counter()
        verts = [pup.grid(i) for i in frames]
        t1 = time.perf_counter()
        tex = pup.textures(frames, texture)
        add_time("mesh_s", t1 - t0)
        add_time("texture_s", time.perf_counter() - t1)
        return list(zip(verts, tex))

    def render_one(i: int, grid, tex, drv):
        t0 = time.perf_counter()
        out = pup.render(i, grid, tex, drv, scale, mode)
        add_time("render_s", time.perf_counter() - t0)
        return out

    # batches of frames whose meshes and textures are computed together (a short first batch:
    # rendering starts early); frames are rendered on a 2-thread pool, each batch's textures
    # computed there ahead of its frames (OpenCV and numpy release the GIL); frames come out in
    # order, each the same as rendered alone
    starts = [0] + list(range(min(FIRST_BATCH, n), n, TEXTURE_BATCH)) if n else []
    bounds = list(zip(starts, starts[1:] + [n]))
    pool = ThreadPoolExecutor(2, thread_name_prefix="facetex-puppet-frame")
    try:
        ahead = {b: pool.submit(meshes_and_textures, *bounds[b]) for b in range(min(2, len(bounds)))}
        pending: deque = deque()
        batch, b = [], -1

        def finished(rec_fut):
            rec, fut = rec_fut
            if fut is not None:
                img, alpha = fut.result()
                rec.update(puppet=img, alpha=alpha)
            drv, img = rec["driver"], rec["puppet"]
            rec["frame"] = np.concatenate([drv, img], axis=1) if side_by_side else img
            if progress:
                progress(n=1, stage="render", lost=session.track.n_lost)
            return rec

        for i, frame in enumerate(iter_video_frames(session.track.path, max_frames=n)):
            if i >= n:
                break
            drv = cv2.resize(frame, (W, H), interpolation=cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR)
            if b + 1 < len(bounds) and i == bounds[b + 1][0]:
                b += 1
                batch = ahead.pop(b).result()
                if b + 2 < len(bounds):
                    ahead[b + 2] = pool.submit(meshes_and_textures, *bounds[b + 2])
            grid, tex = batch[i - bounds[b][0]]
            lost = not bool(session.track.found[i])
            rec = {"index": i, "driver": drv, "lost": lost}
            if keep:
                rec.update(grid=grid, texture=tex)
            fut = None
            if lost:  # no puppet where the driver's face is not seen whole
                rec["puppet"] = drv.copy() if mode == "composite" else np.broadcast_to(
                    np.asarray(pup.params.plain, np.float32), drv.shape).copy()
                rec["alpha"] = np.zeros((H, W), np.float32)
            else:
                fut = pool.submit(render_one, i, grid, tex, drv)
            pending.append((rec, fut))
            while pending and (len(pending) > IN_FLIGHT or pending[0][1] is None or pending[0][1].done()):
                yield finished(pending.popleft())
        while pending:
            yield finished(pending.popleft())
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def puppeteer(driver, persona, output, *, driver_photos=None, side_by_side: bool = False, size: int | None = None,
              mode: str = "composite", overwrite: bool = False, max_frames: int | None = None,
              params: PuppetParams = PuppetParams(), progress: Callable | None = None,
              on_frame: Callable | None = None, tracking="process", loading=None) -> dict:
    """Render ``driver`` (a video) performed by ``persona`` (a Persona or .persona path) to
    ``output`` (H.264 MP4, written atomically, the driver's audio passed through).

    Frames where the driver's face is lost (not found, partly outside the frame, implausible)
    show the driver's frame and are counted and reported with their causes; a video without
    any face raises NoFaceError naming it (nothing is written).
    ``on_frame(record)`` receives each frame record of :func:`render_frames`; ``tracking`` and
    ``loading``: see :func:`prepare_puppetry`.
    Returns a report dict (frames, lost frames, timings, shape/collection sources)."""
    import tempfile
    from concurrent.futures import ThreadPoolExecutor

    from ..io import check_output_path, transcode_audio

    _check_mode(mode)
    inputs = [driver] + ([] if hasattr(persona, "images") else [persona])
    out = check_output_path(output, overwrite=overwrite, inputs=inputs)
    output_size((1, 1), size)  # a bad size fails before the work
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
                                 progress=progress):
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
        "timings": {k: round(v, 3) for k, v in tm.items()},
    }
