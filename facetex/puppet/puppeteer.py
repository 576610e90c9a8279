"""The per-frame puppet (Tom Hanks §6; step 3-5 of :mod:`facetex.puppet.puppetry`): target
fiducials, the neutral-frame textures, the deformed mesh and its rendering."""

from __future__ import annotations

import time

import cv2
import numpy as np

from ..errors import BadInputError
from ..geometry.glasses import rim_mask, rims_present
from ..landmarks import eye_centres
from .composite import FACE_OVAL, INNER_LIPS, composite_face
from .correspondence import DriverCollection, collection_correspondence, landmark_correspondence, puppet_average_shape
from .deform import DeformationTransfer
from .driver import DriverTrack
from .motion import DriverMotion, unfold_columns
from .mouth import interior_white_balance, lift_inner_lips, mouth_interior
from .params import CORRESPONDENCES, TEXTURES, PuppetParams

__all__ = [
    "Puppeteer",
    "target_fiducials",
    "neutral_texture",
    "neutral_textures",
    "grid_normals",
    "landmark_field",
]


# ----------------------------------------------------------------------------- texture
def target_fiducials(persona, motion: DriverMotion, i: int) -> np.ndarray:
    """F^T (49, 2) for frame i: the puppet's mean fiducials plus the driver's expression
    offset, scaled by the ratio of eye-centre distances."""
    from .motion import _iod49

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

    from ..persona.params import TextureParams
    from ..persona.texture import average_face, blend_textures

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
    """The persona's :class:`~facetex.puppet.motion.LipFields` ("lips"), ``BrowFields`` ("brows")
    or ``LidFields`` ("lids") at its mean landmarks on its depth-map grid of ``step`` px, cached on
    the persona: they depend on the persona alone, so the puppet's setup makes them beside the
    driver's tracking (:func:`prepare_puppetry`)."""
    key = ("landmark_field", kind, int(step))
    if key not in persona._cache:
        from .motion import BrowFields, LidFields, LipFields

        W, H = persona.size
        gy, gx = np.mgrid[0:H:step, 0:W:step].astype(np.float64)
        cls = {"lips": LipFields, "brows": BrowFields, "lids": LidFields}[kind]
        persona._cache[key] = cls(persona.points68.mean(axis=0), np.stack([gx, gy], axis=-1))
    return persona._cache[key]


def _landmark_fields_used(params: PuppetParams) -> tuple[str, ...]:
    """The kinds of :func:`landmark_field` a puppet with ``params`` moves its grid by."""
    return tuple(k for k, on in (("lips", params.mouth_rest or params.lip_sync or params.smile_rest),
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
        self._iris = False  # the persona's iris colour, measured on first use (None: not measurable)
        #: whether the driver wears glasses (its clip's :func:`~facetex.geometry.glasses.rims_present`), once
        self.glasses = track is not None and rims_present(track.rims)
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
        self.lip_fields = self.smile_move = self.rest_move = self._lip_response = None
        if self.motion.fiducials68 is not None and (params.mouth_rest or params.lip_sync or params.smile_rest):
            from .motion import _iod49

            self.lip_fields = landmark_field(persona, "lips", st)
            self.lip_scale = _iod49(persona.mean_fiducials) / max(motion.iod, 1e-9)
            if params.smile_rest:
                self.smile_move = self._smile_rest_motion()
            if params.mouth_rest or params.smile_rest:
                self.rest_move = self._rest_motion()
        self.brow_fields = self.brow_rest = None
        if self.motion.fiducials68 is not None and (params.brow_rest or params.brow_sync):
            from .motion import _iod49

            self.brow_fields = landmark_field(persona, "brows", st)
            self.brow_scale = _iod49(persona.mean_fiducials) / max(motion.iod, 1e-9)
            if params.brow_rest:
                self.brow_rest = self._brow_rest_motion()
        self.lid_fields, self.eye_move = None, None
        if self.motion.fiducials68 is not None and (params.eye_rest or params.lid_sync):
            from .motion import _iod49

            self.lid_fields = landmark_field(persona, "lids", st)
            self.lid_scale = _iod49(persona.mean_fiducials) / max(motion.iod, 1e-9)
            if params.eye_rest:
                self.eye_move = self._eye_rest_motion()

    @property
    def puppet_average(self) -> np.ndarray:
        """The persona's average face (Fig. 6 d; cached on the persona): computed when first
        needed (the flow correspondence, the static texture), not for every puppet."""
        from ..persona.texture import average_face

        return average_face(self.persona, "d", params=self.params.texture_params())

    def _smile_rest_motion(self) -> np.ndarray:
        """(68, 2) constant motion of the puppet's lip landmarks from the persona's mean mouth to its
        mouth at the driver's mean mouth-corner lift where that is lower than the persona's mean
        (:func:`facetex.puppet.motion.lips_at_lift`); none where it is higher.
        Why: a collection's mean mouth is its habitual expression, and photos smile: Serena Williams'
        LFW photos (mean lift +0.06 eye distances, median +0.09; GRID speakers -0.035 to +0.038), and
        her puppet kept that smile on a driver's neutral, talking mouth. Only downwards: a mean mouth
        whose corners sit lower than a driver's is the persona's own (Bush -0.033); raised to the
        driver's it smiled on a neutral driver (GRID sbwe5n: mouth-opening slope 1.16 -> 1.25)."""
        from .motion import lips_at_lift, mouth_lift

        m = self.motion
        return lips_at_lift(self.persona.points68, float(mouth_lift(m.fiducials68[m.found]).mean()), lower_only=True)

    def _rest_motion(self) -> np.ndarray:
        """(68, 2) constant motion of the puppet's lip landmarks: the smile rest
        (:meth:`_smile_rest_motion`, ``smile_rest``), then (``mouth_rest``) the motion that makes
        its mean inner-lip gap the driver's mean gap (scaled by the ratio of eye distances)."""
        m = self.motion
        smile = np.zeros((68, 2)) if self.smile_move is None else self.smile_move
        if not self.params.mouth_rest:
            return smile.copy()
        P = self.mean68 + smile
        D = m.fiducials68[m.found].mean(axis=0)
        k = self.lip_scale
        gap = np.zeros((68, 2))
        for up, lo in ((61, 67), (62, 66), (63, 65)):
            change = k * (D[lo] - D[up]) - (P[lo] - P[up])  # > 0: open the puppet's lips
            gap[up] -= change / 2
            gap[lo] += change / 2
        upper, lower = gap[[61, 62, 63]].mean(axis=0), gap[[65, 66, 67]].mean(axis=0)
        gap[[49, 50, 51, 52, 53]] = upper
        gap[[55, 56, 57, 58, 59, 7, 8, 9]] = lower
        gap[[5, 6, 10, 11]] = lower / 2
        return smile + gap

    def _brow_rest_motion(self) -> np.ndarray:
        """(68, 2) constant motion of the puppet's brows (17-26) that gives each of its mean brows
        the tilt and mean height above the eye line (over the eye distance) of the driver's mean
        brow: the difference of the two least-squares lines (height on position along the eye
        line), moved along the eye line's normal. The brow's own curve stays the puppet's."""
        from .motion import brow_heights

        m = self.motion
        P, D = self.mean68, m.fiducials68[m.found].mean(axis=0)

        def along(F):  # brow points' positions along the eye line, over the eye distance
            a, b = eye_centres(F)
            e = b - a
            return (F[17:27] - (a + b) / 2) @ e / float(e @ e)

        left, right = eye_centres(P)
        e = right - left
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
        from .motion import _LOWER_LIDS, _UPPER_LIDS

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
        eyelids' and the smile's rest motions (:meth:`_eye_rest_motion`, :meth:`_smile_rest_motion`),
        so the photos are chosen with the eyes as open and the mouth corners as high as the mesh
        shows them."""
        from ..landmarks import POINTS49_INDEX

        f = target_fiducials(self.persona, self.motion, i)
        for move in (self.eye_move, self.smile_move):
            if move is not None:
                f = f + move[POINTS49_INDEX]
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
        (scaled by the ratio of eye distances; :class:`facetex.puppet.motion.LipFields`), on top of
        the constant rest motion (:mod:`facetex.puppet.puppetry` doc): the deformation transfer's magnitude adjustment and
        Huber-ROF smoothing shrink the thin, fast lip motion by 10-25 % on GRID clips. Lips that
        close further than the puppet's mouth band is tall meet instead of folding the grid over
        (:func:`facetex.puppet.motion.unfold_columns`). The brows likewise follow the driver's
        brow landmarks relative to the eye corners (:class:`facetex.puppet.motion.BrowFields`; the
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
            # short of their targets (lips opened 0.81-0.85 as far as the driver's on GRID, 0.64 on
            # a puppet with tight lips): one more pass with the lip motion that lands the remainder
            want = have + move
            got = self._sample_grid(g - self.puppet_grid, self.mean68)[:, :2]
            lf = self.lip_fields(self._lip_motion_for(want - got))
            for c in range(2):
                g[..., c] += lf[..., c] * self.puppet_mask
        # lips that meet (or whose landmarks cross) must not fold the grid over: stair steps
        return unfold_columns(g, self.puppet_mask)

    def _lip_motion_for(self, remainder: np.ndarray, ridge: float = 0.01) -> np.ndarray:
        """The landmark motion (68, 2) whose lip field moves the lips' points 48-67 by
        ``remainder`` (68, 2) where the grid is sampled at them: the field is linear in the motion,
        so its response at the points (20 x 20, the same for x and y, computed once) is inverted,
        ridge-regularized towards ``remainder`` itself. Repeating the plain pass converged ~6 %
        short: a puppet whose average mouth is nearly shut (Koizumi's: 0.024 eye distances) has
        its inner lips within a grid cell of each other, and each pass parted them a little less
        (a 1000 px smile 0.140 wanted: 0.119 after one pass, 0.131 after twelve, 0.136 solved)."""
        lips = np.arange(48, 68)
        if self._lip_response is None:
            A = np.zeros((len(lips), len(lips)))
            unit = np.zeros((self.puppet_mask.shape + (3,)), np.float32)
            for k, j in enumerate(lips):
                e = np.zeros((68, 2))
                e[j] = 1.0
                unit[..., 0] = self.lip_fields(e)[..., 0] * self.puppet_mask
                A[:, k] = self._sample_grid(unit, self.mean68[lips])[:, 0]
            self._lip_response = A
        A = self._lip_response
        out = np.array(remainder, np.float64)
        r = out[lips]
        out[lips] = np.linalg.solve(A.T @ A + ridge * np.eye(len(lips)), A.T @ r + ridge * r)
        return out

    def _lids(self, i: int, g: np.ndarray) -> np.ndarray:
        """The grid ``g`` with the puppet's eyelid landmarks moved as the driver's (scaled by the
        ratio of eye distances) on top of the eyes' rest motion (:class:`facetex.puppet.motion.LidFields`):
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
            from ..persona.texture import blend_weights

            tex = list(blend_weights(self.persona, self.sequence_weights()[frames], params=tp))
        else:
            tex = neutral_textures(self.persona, [self.target(i) for i in frames], method=method, params=tp)
        return self._close_interiors(frames, tex)

    def _close_interiors(self, frames: list, tex: list) -> list:
        """The textures with their mouth interior filled from the lips
        (:func:`facetex.puppet.mouth.fill_mouth_interior`; ``params.close_mouth``): all of it when
        the driver's interior is drawn, else as the driver's mouth closes."""
        from .mouth import fill_mouth_interior, mouth_closure

        m = self.motion
        if not self.params.close_mouth or m.fiducials68 is None:
            return list(tex)
        lips = self.mean68[60:68]
        if self.params.composite.mouth:  # the opening is the driver's interior on the cavity's shadow
            return [fill_mouth_interior(t, lips, 1.0) for t in tex]
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
            from ..persona.texture import sequence_weights

            fps = float(self.track.fps) if self.track is not None and self.track.fps else 25.0
            f = np.stack([self.target(i) for i in range(len(self.motion))])
            self._sequence_weights = sequence_weights(self.persona, f, self.params.texture_params(),
                                                      sigma_frames=self.params.weight_smoothing * fps,
                                                      range_scale=self.params.weight_range,
                                                      segments=self.motion.shots)
        return self._sequence_weights

    def pose(self, i: int, scale: float) -> tuple[np.ndarray, np.ndarray]:
        """(A, b): output-panel pixel = A X + b of a canonical point X in frame i (driver pixels
        scaled by ``scale``, pixel centres at integers)."""
        A = self.motion.pose_A[i] * scale
        b = self.motion.pose_b[i] * scale
        b[:2] += 0.5 * scale - 0.5
        return A, b

    def points(self, i: int, grid: np.ndarray, scale: float) -> np.ndarray:
        """The puppet's 68 landmarks (68, 2) in output-panel px for frame i: its texture-frame
        landmarks carried by the deformed ``grid`` and projected."""
        X = self._sample_grid(grid, self.mean68)
        A, b = self.pose(i, scale)
        return X @ A[:2].T + b[:2]

    def layers(self, i: int, grid: np.ndarray, texture: np.ndarray, size, scale: float, supersample: int = 1,
               normals: bool = True):
        """:class:`facetex.puppet.render.Layers` of the puppet in frame i (output panel ``size`` (W, H))."""
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
        pts = self.points(i, grid, scale)
        lips = pts[list(INNER_LIPS)]
        drv68 = (tr.points68[i] + 0.5) * scale - 0.5
        if mode == "face":
            bg = np.broadcast_to(np.asarray(self.params.plain, np.float32), (h, w, 3))
            cov = lay.coverage[..., None]
            img = cov * lay.image + (1 - cov) * bg
            if self.params.composite.mouth and np.isfinite(drv68).all():
                if self.params.composite.lip_band > 0:  # the persona's colour: relative to each face's lips
                    img = lift_inner_lips(img, frame, drv68, pts, band=self.params.composite.lip_band, relative=True)
                mi, ma = mouth_interior(frame, drv68[list(INNER_LIPS)], lips, (h, w))
                mi = interior_white_balance(mi, frame, drv68, img, pts)
                ma = (ma * lay.coverage)[..., None]
                img = ma * mi + (1 - ma) * img
            return img.astype(np.float32), lay.coverage
        oval = (tr.mesh[i][list(FACE_OVAL), :2] + 0.5) * scale - 0.5
        rims = rim_mask(frame, drv68, tr.rims) if self.params.composite.occlusion and self.glasses else None
        return composite_face(frame, lay.image, lay.coverage, lay.normals, driver_oval=oval, driver_points68=drv68,
                              rims=rims, puppet_points68=pts, driver_normals=self.driver_normals(i, (w, h), scale) if sh else None,
                              iris=self.iris() if self.params.composite.eyes == "driver" else None,
                              params=self.params.composite)

    def iris(self) -> np.ndarray | None:
        """The persona's iris-to-skin colour ratio (:func:`~facetex.puppet.eyes.persona_iris`), once."""
        # a render kit without its persona (facetex.live) carries the value measured before
        if self._iris is False and self.persona is not None:
            from .eyes import persona_iris

            self._iris = persona_iris(self.persona.image, self.persona.points68)
        return None if self._iris is False else self._iris

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


