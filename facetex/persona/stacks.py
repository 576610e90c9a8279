"""The persona's precomputed texture stacks (the fast path of :mod:`facetex.persona.texture`): every
photo aligned to the neutral frame, its pyramid and Laplacian responses, blended per target by sparse
products; their 8-bit storage in the .persona file."""

from __future__ import annotations

import math
import zlib
from concurrent.futures import ThreadPoolExecutor
from typing import TYPE_CHECKING, Callable

import cv2
import numpy as np

from .._parallel import available_cpus
from ..errors import BadInputError, BadPersonaError
from ..geometry.gaze import gaze_asymmetry
from ..geometry.glasses import glasses_bridge_score
from ._occlusion import occlude_aligned
from ._packed import Packed
from ._photo_quality import _PhotoQuality
from ._stack_parts import (
    ROBUST_FINEST,
    ROBUST_UNIFORM,
    _confidence,
    _csr,
    _float16_to_32,
    _photo_rows_rgbc,
    _robust_product,
    _Segment,
    _single_stack,
    _small_page_arrays,
    _unpremultiply,
)
from ._stack_store import (
    store_photo_scores,
    stored_photo_scores,
    STACKS_VERSION,
    _aligned_lut,
    _conf_range,
    _dequantize_aligned,
    _lsb_bytes,
    _lsb_lut,
    _quantize_aligned,
    _stored_key,
    warn_stale_stacks,
)
from .align import (
    compose_map_flow,
    face_region,
    remap_stack,
    tps_maps,
)
from .params import TextureParams
from .pyramid import (
    OUTSIDE_SMOOTH_LEVELS,
    SPARSE_MASS,
    _cut_small,
    _uniform_term,
    collapse_pyramid,
    laplacian_pyramid,
    pyramid_levels,
)

if TYPE_CHECKING:
    from .collection import Persona

__all__ = [
    "prepare_persona",
    "stored_stacks",
    "STACKS_VERSION",
]


class _Prepared(_PhotoQuality):
    """Target-independent data of a persona for :func:`synthesize_texture` (see module doc).

    Per pyramid level, the pixels inside the face support are grouped into segments by the
    weight regions whose (feathered) masks reach them; outside the face support (hair,
    background, neck) the texture is the expression-independent average (its stack sum is
    kept), so nothing is stored there."""

    #: photos per work unit of the precomputation (bounds the per-chunk maps to ~24 MB)
    CHUNK = 32
    #: region masks below this are cut (the rest renormalised), so segments stay few
    MASK_CUT = 0.01

    def __init__(self, persona: Persona, tp: TextureParams, progress: Callable | None = None,
                 stored: dict | None = None, cache=None):
        """``stored``: the persona's stored stacks (:func:`stored_stacks`); used when they were
        made with ``tp``'s stack key and this layout, else the stacks are computed. ``cache``: a
        folder of :mod:`facetex.persona._stack_cache` the stacks rebuilt from ``stored`` are read
        from (memory-mapped) or, when it does not hold them, written to."""
        self._cache_folder = cache
        W, H = persona.size
        n = len(persona)
        self.n = n
        self.shape = (H, W)
        self.tp = tp
        self.levels = pyramid_levels(self.shape, tp.min_level_side)
        self.M = persona.mean_fiducials
        self.points68 = persona.points68.mean(axis=0)
        self.region = face_region(self.points68, self.shape)
        self.level_shapes = [p.shape[:2] for p in laplacian_pyramid(np.zeros((H, W, 3), np.float32), self.levels)]
        self._layout(tp.regions)
        self.static = [np.zeros(h * w * 4, np.float64) for h, w in self.level_shapes]
        built = persona._cache.pop("tps_maps", None)  # left by build_persona; dropped after use
        if built is not None and built.shape[0] != n:
            built = None
        self._persona_ref = persona  # for the lazily computed stages and full-frame stacks
        self._full: dict = {}
        self._bounds = [(i, min(i + self.CHUNK, n)) for i in range(0, n, self.CHUNK)]
        self._stage = {}
        self._single = {}
        self._outside_cache = {}
        self._packed: Packed | None = None  # the stored aligned photos (version-4 file)
        self._aligned_q: np.ndarray | None = None  # the same, unpacked (computed here)
        self._aligned_lsb: np.ndarray | None = None  # their images' 9th bits (computed or stored)
        self._gaze = np.full(n, np.nan)  # each aligned photo's gaze asymmetry (made with the stacks)
        self._gaze_stored = False  # read from the file (version-4 stacks saved since stop 46)
        # each photo's eyeglasses bridge score (made with the stacks from the photos, stored with them:
        # a load then need not unpack every photo for it, ~0.4 s of a 519-photo puppet's start)
        self._glasses: np.ndarray | None = None
        if not self._load(stored):
            self._compute(persona, built)
        if progress:
            progress(n=1, stage="precompute")

    def _compute(self, persona: Persona, built: np.ndarray | None) -> None:
        """The stacks and static sums from the photos (alignment, 8-bit quantization, pyramids,
        segment gather)."""
        self._fill(persona, built, None)

    def _fill(self, persona: Persona, built: np.ndarray | None, packed: Packed | None,
              static: list[np.ndarray] | None = None) -> None:
        """The stacks and static sums from the photos aligned now (``packed`` None) or from the
        8-bit aligned photos a .persona stored (``packed``, with their ``static`` sums): the same
        pyramids of the same values."""
        n, tp = self.n, self.tp
        luts = _aligned_lut(tp), _lsb_lut()
        if packed is None:  # what a .persona stores
            self._aligned_q = np.empty((n,) + self.shape + (4,), np.uint8)
            self._aligned_lsb = np.empty((n, _lsb_bytes(self.shape)), np.uint8)
            self._glasses = np.full(n, np.nan)

        gaze_stored = packed is not None and self._gaze_stored
        # with the occluders' factors every photo is aligned first (they judge each photo against
        # the others), then the rows are made from the aligned codes as from a file's
        occluded = packed is None and tp.occlusion > 0

        def align(i0: int, i1: int):
            maps, conf = self._align_maps(i0, i1, None if built is None else built[i0:i1])
            P = self._persona_ref
            for i in range(i0, i1):
                self._aligned_photo(i, maps[i - i0], conf[i - i0], self._aligned_q[i], self._aligned_lsb[i])
                self._glasses[i] = glasses_bridge_score(P.images[i], P.points68[i])

        def chunk(i0: int, i1: int):
            # the chunk's photos aligned, then one photo at a time through pyramid, segment gather and
            # the static sums: its rows (~1 MB) stay in cache (a whole chunk's full-frame rows, ~30 MB, did not)
            work = {"q": np.empty(self.shape + (4,), np.uint8)}
            if packed is None and not occluded:
                align(i0, i1)
            sums = [np.zeros(h * w * 4, np.float64) for h, w in self.level_shapes] if static is None else None
            for i in range(i0, i1):
                if packed is None:
                    q = self._aligned_q[i]
                else:
                    q = packed.photo(i, work["q"])
                # stored or computed, the stacks are made from the same quantized aligned photo
                ic = _dequantize_aligned(q, self._aligned_lsb[i], luts, work)
                if not gaze_stored:
                    self._gaze[i] = gaze_asymmetry(ic[..., :3], self.points68)
                for k, row in enumerate(_photo_rows_rgbc(ic, self.levels, tp, work)):
                    if sums is not None:  # the same sequential float64 sum as rows.sum(axis=0) over the chunk
                        sums[k] += row
                    r4 = row.reshape(-1, 4)
                    for seg in self.segments[k]:  # gathered straight into the segment's rows
                        np.take(r4, seg.pixels, axis=0, out=seg.stack[i].reshape(-1, 4))
            return sums

        # photos are independent: chunks run on a thread pool (OpenCV, zlib and numpy release the
        # GIL); results do not depend on the thread count (partial sums are added in order)
        with ThreadPoolExecutor(max(1, min(len(self._bounds), available_cpus()))) as pool:
            if occluded:
                list(pool.map(lambda b: align(*b), self._bounds))
                self._occlude(luts)
            results = list(pool.map(lambda b: chunk(*b), self._bounds))
        if static is not None:  # stored with the aligned photos (adding every photo's rows cost ~15 % of a load)
            self.static = [np.array(x, np.float32) for x in static]
            return
        for sums in results:
            for k in range(self.levels):
                self.static[k] += sums[k]
        self.static = [(x / max(n, 1)).astype(np.float32) for x in self.static]  # uniform weights

    def _occlude(self, luts: tuple) -> None:
        """The aligned photos' confidences times their occluders' factors (:func:`occlude_aligned`)."""
        P, tp = self._persona_ref, self.tp
        self._stage["occlusion"] = occlude_aligned(self._aligned_q, self._aligned_lsb, luts, P.fiducials, self.points68,
                                                   _conf_range(tp), tp.occlusion)

    def stored(self) -> dict:
        """What a .persona file stores of the stacks (:func:`stored_stacks`): the photos aligned to
        the neutral frame with their confidences, 8-bit and packed (the stacks are rebuilt from them
        at load); computed now when the stacks came from a version-3 file."""
        # stacks read from a version-3 file (float16) are not those a load rebuilds: what is made from
        # them (the gaze, the band energy) is then left to the load
        rebuilt_alike = self._packed is not None or self._aligned_q is not None
        if self._packed is None:
            if self._aligned_q is None:  # stacks read from a version-3 file: align the photos again
                self._aligned_q, self._aligned_lsb = self._aligned_quantized()
                if self.tp.occlusion > 0:
                    self._occlude((_aligned_lut(self.tp), _lsb_lut()))
            self._packed = Packed.pack(self._aligned_q, workers=available_cpus())
            self._aligned_q = None  # packed: ~1/3 of the memory
        lo, hi = _conf_range(self.tp)
        arrays = {"texture_aligned": self._packed, "texture_aligned_lsb": self._aligned_lsb}
        arrays.update({f"texture_static_{k}": np.asarray(x, np.float32) for k, x in enumerate(self.static)})
        meta = {"key": _stored_key(self.tp), "aligned": {"conf_range": [lo, hi]}, "static": [x.size for x in self.static]}
        scores = self._glasses_scores()
        # NaN (no score: eyes off the photo) stored as -1: scores are >= 0, stored arrays finite
        arrays["texture_glasses_scores"] = np.where(np.isfinite(scores), scores, -1.0)
        meta["glasses"] = True
        if rebuilt_alike:  # what a load would compute from every photo's rebuilt stacks
            store_photo_scores(arrays, meta, self._gaze, self.band_energy())
        return {"meta": meta, "arrays": arrays}

    def _aligned_photo(self, i: int, m: np.ndarray, conf: np.ndarray, out: np.ndarray,
                       lsb: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Photo i and its frontal-frame confidence ``conf`` warped by its sampling map ``m`` to the
        neutral frame through one 4-channel remap (per channel the same values), quantized into
        ``out`` and ``lsb`` (:func:`_quantize_aligned`)."""
        ic = np.empty(self.shape + (4,), np.float32)
        np.multiply(self._persona_ref.images[i], np.float32(1 / 255.0), out=ic[..., :3], casting="unsafe")
        ic[..., 3] = conf
        ic = cv2.remap(ic, m[..., 0], m[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return _quantize_aligned(ic, self.tp, out, lsb)

    def _aligned_quantized(self) -> tuple[np.ndarray, np.ndarray]:
        """(n, H, W, 4) uint8 photos aligned to the neutral frame with their confidences and (n, m)
        uint8 their images' 9th bits (:func:`_quantize_aligned`)."""
        out = np.empty((self.n,) + self.shape + (4,), np.uint8)
        lsb = np.empty((self.n, _lsb_bytes(self.shape)), np.uint8)
        for i0, i1 in self._bounds:
            align, conf = self._align_maps(i0, i1)
            for i in range(i0, i1):
                self._aligned_photo(i, align[i - i0], conf[i - i0], out[i], lsb[i])
        return out, lsb

    def _load(self, stored: dict | None) -> bool:
        """Fill the stacks from ``stored`` (a version-4 file's packed aligned photos, or a version-3
        file's float16 stacks); False (nothing changed) when they do not fit."""
        if not stored or stored["meta"].get("key") != _stored_key(self.tp):
            return False
        arrays = stored["arrays"]
        if "aligned" in stored["meta"]:
            packed, lsb = arrays.get("texture_aligned"), arrays.get("texture_aligned_lsb")
            static = [arrays.get(f"texture_static_{k}") for k in range(self.levels)]
            if (not isinstance(packed, Packed) or packed.shape != (self.n,) + self.shape + (4,)
                    or lsb is None or lsb.shape != (self.n, _lsb_bytes(self.shape))
                    or stored["meta"]["aligned"].get("conf_range") != list(_conf_range(self.tp))
                    or [None if x is None else x.shape for x in static] != [(x.size,) for x in self.static]):
                return False
            self._aligned_lsb = lsb
            g = arrays.get("texture_glasses_scores") if stored["meta"].get("glasses") else None
            if g is not None and g.shape == (self.n,):
                self._glasses = np.where(g >= 0, g, np.nan).astype(np.float64)
            gaze, energy = stored_photo_scores(stored, (self.levels, len(self.regions), self.n))
            if gaze is not None:
                self._gaze, self._gaze_stored = gaze, True
            if energy is not None:
                self._stage["band_energy"] = energy
            from ._stack_cache import read_stack_cache, write_stack_cache

            try:
                if self._cache_folder is None or not read_stack_cache(self, self._cache_folder):
                    self._fill(self._persona_ref, None, packed, static)
                    if self._cache_folder is not None:
                        write_stack_cache(self, self._cache_folder, stored.get("path"))
                else:
                    self.static = [np.array(x, np.float32) for x in static]
            except (ValueError, zlib.error) as e:  # a stream whose CRC-32 passed but does not unpack
                raise BadPersonaError(f"corrupt persona file (texture_aligned: {type(e).__name__}: {e}): rebuild it "
                                      "with `facetex persona build`", path=stored.get("path")) from None
            self._packed = packed
            return True
        want = [sum(seg.stack.shape[1] for seg in segs) for segs in self.segments]
        if stored["meta"].get("columns") != want:
            return False
        for k in range(self.levels):
            st, sa = arrays.get(f"texture_stack_{k}"), arrays.get(f"texture_static_{k}")
            if (st is None or sa is None or st.shape != (self.n, want[k])
                    or sa.shape != (self.static[k].size,)):
                return False
        for k, segs in enumerate(self.segments):
            st, c = arrays[f"texture_stack_{k}"], 0
            for seg in segs:
                w = seg.stack.shape[1]
                _float16_to_32(st[:, c:c + w], seg.stack)
                c += w
            self.static[k] = np.array(arrays[f"texture_static_{k}"], np.float32)
        return True

    def _align_maps(self, i0: int, i1: int, maps: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Photos i0..i1's sampling maps into the neutral frame (TPS composed with the collection
        flow) and their frontal-frame confidences."""
        persona = self._persona_ref
        if maps is None:
            maps = tps_maps(persona.fiducials[i0:i1], self.M, self.shape, persona.params.tps_smoothing)
        return compose_map_flow(maps, persona.flows[i0:i1]), _confidence(persona, self.tp, slice(i0, i1))

    def _aligned_stacks(self) -> tuple[np.ndarray, np.ndarray]:
        if "aligned" not in self._full:
            persona = self._persona_ref
            H, W = self.shape
            aligned = np.empty((self.n, H, W, 3), np.float32)
            conf = np.empty((self.n, H, W), np.float32)
            for i0, i1 in self._bounds:
                align, c = self._align_maps(i0, i1)
                aligned[i0:i1] = remap_stack(persona.images[i0:i1], align)
                conf[i0:i1] = remap_stack(c, align)
            self._full["aligned"], self._full["conf_aligned"] = aligned, conf
        return self._full["aligned"], self._full["conf_aligned"]

    @property
    def aligned(self) -> np.ndarray:
        """(n, H, W, 3) float32 photos aligned to the neutral frame (computed on first use)."""
        return self._aligned_stacks()[0]

    @property
    def conf_aligned(self) -> np.ndarray:
        """(n, H, W) float32 their confidences (computed on first use)."""
        return self._aligned_stacks()[1]

    @property
    def conf_frontal(self) -> np.ndarray:
        """(n, H, W) float32 confidences of the frontal photos (computed on first use)."""
        if "conf_frontal" not in self._full:
            self._full["conf_frontal"] = _confidence(self._persona_ref, self.tp)
        return self._full["conf_frontal"]

    def stage_b(self) -> np.ndarray:
        """Fig. 6 b: the mean of the photos TPS-warped to the mean fiducials (the TPS alone),
        computed on first use (the TPS maps are recomputed; chunk sums added in order)."""
        if "b" not in self._stage:
            persona = self._persona_ref
            sums = []
            for i0, i1 in self._bounds:
                maps = tps_maps(persona.fiducials[i0:i1], self.M, self.shape, persona.params.tps_smoothing)
                sums.append(remap_stack(persona.images[i0:i1], maps).sum(axis=0, dtype=np.float64))
            self._stage["b"] = np.clip(np.sum(sums, axis=0) / max(self.n, 1), 0, 1).astype(np.float32)
        return self._stage["b"]

    def _layout(self, regions) -> None:
        """Region masks per level (the face support's complement = the static average) and the
        pixel segments (see :class:`_Segment`)."""
        from .weights import face_support, region_masks

        H, W = self.shape
        base = region_masks(self.points68, (H, W), regions)
        sup = face_support(self.points68, (H, W))
        full = np.concatenate([base * sup[None], (1.0 - sup)[None]])  # last: outside (static)
        self.regions = tuple(regions)
        self.masks, self.segments = [], []
        for k in range(self.levels):
            if k > 0:
                full = np.stack([cv2.pyrDown(x) for x in full])
            m = np.where(full < self.MASK_CUT, 0.0, full).astype(np.float32)
            m /= np.maximum(m.sum(axis=0, keepdims=True), 1e-12)
            self.masks.append(m)
            R = len(regions)
            flat = m[:R].reshape(R, -1) > 0
            code = (flat * (1 << np.arange(R))[:, None]).sum(axis=0)
            segs = []
            for c in np.unique(code[code > 0]):
                pix = np.nonzero(code == c)[0]
                regs = tuple(j for j in range(R) if c >> j & 1)
                segs.append((pix, regs, m[list(regs)].reshape(len(regs), -1)[:, pix].copy()))
            self.segments.append(segs)
        # all segments' stacks in one memory map with small pages (_small_page_arrays)
        shapes = [(self.n, len(pix) * 4) for segs in self.segments for pix, _, _ in segs]
        stacks = _small_page_arrays(shapes)
        stacks = iter(stacks)
        self.segments = [[_Segment(pix, regs, self.n, masks, next(stacks)) for pix, regs, masks in segs]
                         for segs in self.segments]

    def single(self, which: str, persona: Persona) -> np.ndarray:
        if which not in self._single:
            if which == "aligned":
                self._single[which] = _single_stack(self.aligned, self.conf_aligned, self.tp)
            else:
                front = persona.images.astype(np.float32) / 255.0
                self._single[which] = _single_stack(front, self.conf_frontal, self.tp)
        return self._single[which]

    def blend_ours(self, similarity: np.ndarray) -> np.ndarray:
        return self.blend_many(np.asarray(similarity)[None])[0]

    def blend_ours_many(self, similarities: np.ndarray) -> np.ndarray:
        """(B, H, W, 3) blends for B targets' global similarities (B, n) (Eq. 3)."""
        return self.blend_many(np.atleast_2d(similarities))

    def level_masks(self) -> list[np.ndarray]:
        """Per pyramid level (finest first), the (R + 1, h_k, w_k) masks of the weight regions
        and, last, of the outside (static average), summing to 1."""
        return [m.reshape((-1,) + tuple(sh)) for m, sh in zip(self.masks, self.level_shapes)]

    def _outside(self, k: int) -> np.ndarray:
        """Level k's static rows times the outside mask (its finest bands left out: no fine detail
        off the face, where the frontalization paints streaks), cached."""
        if k not in self._outside_cache:
            h, w = self.level_shapes[k]
            outside = self.masks[k][-1].repeat(4)
            if k < OUTSIDE_SMOOTH_LEVELS:
                outside = outside * np.tile(np.array([0, 0, 0, 1], np.float32), h * w)
            self._outside_cache[k] = (self.static[k] * outside).astype(np.float32)
        return self._outside_cache[k]

    def blend_many(self, weights: np.ndarray) -> np.ndarray:
        """(B, H, W, 3) blends for B targets. ``weights``: (B, n) global similarities (the same for
        every region) or (B, R, n) per-region similarities (mixed per pixel by the region masks,
        see :mod:`facetex.persona.weights`).

        Per level and region the Eq. 3 factor (s_i + u_l) is normalised to sum 1 over the photos
        and split as u_l * (sum of all photos' rows, precomputed) + sum_i s_i * row_i; the second
        sum leaves out the photos with the smallest similarities that together hold less than
        1 - :data:`SPARSE_MASS` of a target's total (a sparse product then reads only the
        remaining photos' rows). Each region's product covers only its own pixels."""
        p = self.levels
        S = np.asarray(weights, np.float64)
        if S.ndim == 1:
            S = S[None]
        regional = S.ndim == 3
        if not regional:
            S = np.repeat(S[:, None], len(self.regions), axis=1)
        B, R, n = S.shape
        if R != len(self.regions):
            raise BadInputError(f"{R} region weights for the {len(self.regions)} regions {self.regions}")
        if regional and self.tp.glasses > 0:
            # photos with eyeglasses lose their weight round the eyes: their rims lie in the eyes'
            # and the rest of the face's regions (the eyes' detail weights alone left faint rings)
            S = S.copy()
            for j, g in self.glasses_factors().items():
                S[:, j] *= g
        # per region: the similarities, small ones cut; sparse products when that pays off
        Wn = [_cut_small(S[:, j], SPARSE_MASS, self.tp.max_photos if regional else None)
              for j in range(R if regional else 1)]
        sums = [w.sum(axis=-1) for w in Wn]  # the kept weights sum to 1 (with the uniform term)
        # one (sparse when that pays off) matrix per region; each level only rescales its rows
        def matrix(w):
            return _csr(w.astype(np.float32)) if np.count_nonzero(w) < 0.5 * w.size else w.astype(np.float32)

        mats = [matrix(w) for w in Wn]
        # the finest levels of a region take its detail weights (same totals, so the same scale)
        fine = [(0, mats[j]) for j in range(len(Wn))]
        if regional:
            from .weights import detail_weights

            for j, name in enumerate(self.regions):
                power, nlev = self.tp.detail_of(name)
                q = self.eye_quality() if name == "eyes" and self.tp.eye_quality > 0 else None
                if nlev > 0 and (power != 1 or q is not None):
                    # raised to a power, most of the kept photos' weights all but vanish: the same cut
                    # of the smallest 0.5 % of the mass (519-photo persona, GRID clip: eyes ~49 -> ~22
                    # photos, face 54 -> 39; the blend -25 % CPU; textures 0.013/255 apart)
                    fine[j] = (nlev, matrix(_cut_small(detail_weights(Wn[j], power, q), SPARSE_MASS)))
        robust = dict(self.tp.robust) if regional else {}
        bands = []
        for k in range(p):
            lvl = p - 1 - k  # paper's l
            h, w = self.level_shapes[k]
            u = _uniform_term(lvl, self.tp.tau, self.tp.beta)
            static = self.static[k]
            if math.isinf(u):
                out = np.broadcast_to(static, (B, h * w * 4))
            else:
                out = np.repeat(self._outside(k)[None], B, axis=0)
                scale = [(1.0 / (sums[j] + n * u)).astype(np.float32)[:, None] for j in range(len(Wn))]
                ucoef = [(n * u / (sums[j] + n * u)).astype(np.float32)[:, None] for j in range(len(Wn))]
                for seg in self.segments[k]:
                    st = static[seg.cols][None] if u > 0 else None
                    if not regional:  # one product, the regions' masks summed
                        acc = mats[0] @ seg.stack
                        acc *= scale[0]
                        if u > 0:
                            acc += ucoef[0] * st
                        acc *= seg.masks.sum(axis=0)[None]
                    else:
                        acc = np.zeros((B, seg.stack.shape[1]), np.float32)
                        for mj, j in zip(seg.masks, seg.regions):
                            wm = fine[j][1] if k < fine[j][0] else mats[j]
                            kappa = robust.get(self.regions[j]) if u <= ROBUST_UNIFORM and k >= ROBUST_FINEST else None
                            num = wm @ seg.stack if kappa is None else _robust_product(wm, seg.stack, kappa)
                            num *= scale[j]
                            if u > 0:
                                num += ucoef[j] * st
                            num *= mj
                            acc += num
                    for ob, ab in zip(out, acc):  # row by row: the 2-D fancy scatter is ~2.5x slower
                        t = ob.take(seg.cols)
                        t += ab
                        ob[seg.cols] = t
            bands.append(_unpremultiply(out.reshape(B, h, w, 4)))
        if regional:
            self._restore_detail(bands, fine, mats)
        return np.stack([collapse_pyramid([b[j] for b in bands]) for j in range(B)])

    def _restore_detail(self, bands: list[np.ndarray], fine: list, mats: list) -> None:
        """Detail restoration (``tp.restore``; in place on the (B, h, w, 3) ``bands``, finest first;
        ``fine``: per region (levels, weights) of the detail weights, ``mats`` the other levels').

        Averaging photos whose fine detail (pores, creases, lashes) is not aligned to the pixel
        cancels most of it: the blend's band energy is a fraction of what each photo has. Per
        target, level and region, the band is scaled by sqrt(E_photos / E_blend), E_photos the
        photos' own mean band energy there weighted as in the blend (:meth:`band_energy`), E_blend
        the blended band's, the gain clipped to [1, ``tp.restore_gain``] and mixed per pixel by
        the region masks (1 outside the face): the persona's own amount of detail, as Shih et al.
        2014 match local band energies, with the blend's own structure (no photo's noise)."""
        levels = dict(self.tp.restore)
        if not levels:
            return
        E = self.band_energy()
        for k in range(min(self.levels, max(levels.values()))):
            if _uniform_term(self.levels - 1 - k, self.tp.tau, self.tp.beta) > 1e-3:
                continue  # the lighting levels: shared by all photos, nothing cancelled
            b = bands[k]
            B, h, w, _ = b.shape
            m = self.masks[k].reshape(len(self.regions) + 1, -1)  # (R + 1, h * w), last the outside
            gain = np.zeros((B, h * w), np.float32)
            gain += m[-1][None]  # outside the face: unchanged
            bb = b.reshape(B, -1, 3)
            e2 = bb[..., 0] * bb[..., 0] + bb[..., 1] * bb[..., 1] + bb[..., 2] * bb[..., 2]  # (B, h * w)
            for j, name in enumerate(self.regions):
                mj = m[j]
                if k >= levels.get(name, 0):
                    gain += mj[None]
                    continue
                Wj = fine[j][1] if k < fine[j][0] else mats[j]
                Wj = Wj.toarray() if hasattr(Wj, "toarray") else np.asarray(Wj)
                tot = Wj.sum(axis=1)
                e_photos = (Wj @ E[k, j]) / np.maximum(tot, 1e-30)
                e_blend = (e2 @ mj).astype(np.float64) / max(float(mj.sum()), 1e-12)
                g = np.sqrt(e_photos / np.maximum(e_blend, 1e-12))
                g = np.clip(np.where(np.isfinite(g) & (tot > 0), g, 1.0), 1.0, self.tp.restore_gain)
                gain += g.astype(np.float32)[:, None] * mj[None]
            for c in range(3):  # per channel: numpy broadcasts over a length-3 axis slowly
                b[..., c] *= gain.reshape(B, h, w)

    @property
    def pyr(self) -> list[np.ndarray]:
        """Per level (finest first) the (n, h * w * 4) full-frame stack rows assembled from the
        segments (zero outside the face support): for inspection and tests, not used by the blend."""
        out = []
        for k, (h, w) in enumerate(self.level_shapes):
            a = np.zeros((self.n, h * w * 4), np.float32)
            for seg in self.segments[k]:
                a[:, seg.cols] = seg.stack
            out.append(a)
        return out

    def nbytes(self) -> int:
        arrs = [*self._full.values(), *self.static, *([] if self._aligned_q is None else [self._aligned_q]),
                *([] if self._aligned_lsb is None else [self._aligned_lsb]),
                *([] if self._packed is None else [self._packed.blob]),
                *(seg.stack for segs in self.segments for seg in segs), *self._single.values()]
        return int(sum(a.nbytes for a in arrs))


def stored_stacks(persona: Persona) -> dict:
    """{"meta", "arrays"} of the default parameters' texture stacks for a .persona file (computed,
    or taken from the persona's cache): the photos aligned to the neutral frame and their
    confidences, 8-bit and packed (~60 kB per photo); the stacks are rebuilt from them at load,
    which spares the puppet's setup the alignment of every photo (~10 ms per photo and core)."""
    return prepare_persona(persona).stored()


def prepare_persona(persona: Persona, params: TextureParams | None = None, *, progress=None,
                    cache=None) -> _Prepared:
    """Precompute (once, cached on the persona) the target-independent synthesis data: from
    the stacks stored in its file when they were made with ``params``' stack key. ``cache``: a
    folder (:func:`facetex.persona._stack_cache.stack_cache_folder`) the stacks rebuilt from the
    file are memory-mapped from, or written to when it does not hold them yet."""
    tp = params or TextureParams()
    key = ("prepared", tp.stack_key())
    if key not in persona._cache:
        stored = persona.texture_stacks
        warn_stale_stacks(stored, tp)
        persona._cache[key] = _Prepared(persona, tp, progress, stored, cache)
        if stored is not None and stored["meta"].get("key") == _stored_key(tp):
            persona.texture_stacks = None  # now held by the cache (exported from there by save)
    prep = persona._cache[key]
    if prep.tp != tp:  # same stacks, other weights: a view with these parameters
        import copy

        prep = copy.copy(prep)
        prep.tp = tp
    return prep
