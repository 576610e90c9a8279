"""Expression weights of the persona texture blend (Tom Hanks Sec. 5, Eqs. 2-3): global and regional.

**Global (the paper, ``weights="global"``).** One similarity per photo,
exp(-||F^T - F^i||^2 / 2 sigma^2), on the 98-vector of pose-corrected fiducials (Eq. 2),
sigma = 10 in pixels of a frame whose eye centres are 69.12 px apart
(:func:`global_similarity`), with the Laplacian factor L^alpha, alpha = 1 (Eq. 3).

**Regional (ours, the default).** On the LFW Bush (499 photos) and Blair (124) collections the
paper's distance hardly discriminates: a photo's nearest neighbour is 0.20 IOD away, the
median photo 0.45 (98 dimensions of landmark noise swamp the few that carry expression);
the weights spread over 40-160 photos (effective number) and the blend is nearly the static
average. What we do instead (measured with ``facetex bench persona``, leave-out SSIM over
20 held-out photos, two held-out draws, both collections):

1. Normalised space: each photo's fiducials are similarity-aligned (Procrustes: shift,
   rotation, scale) to the collection's mean M on the rigid points (eye corners, nose), which
   removes what the pose correction left of head pose and face size, and are measured in
   units of M's eye-centre distance (IOD).
2. Regions: the mouth (18 lip points) and the eyes with the brows (22 points) get their own
   distances, each region centred on its own centroid (its position is the TPS warp's
   business, its shape the expression); the rest of the face uses all 49 points. Regional
   weights beat the same machinery with one region for the whole face (face-only,
   K = 5: SSIM gain over static +0.028 / +0.026 face, +0.025 / +0.016 eyes on Bush / Blair,
   against +0.032 / +0.028 and +0.033 / +0.019 regional).
3. sigma by measurement, per target: sigma_r(T) = (distance of the target to its K-th
   nearest photo in region r) / 2 (:func:`adaptive_sigma`), K = ``neighbours`` = 3. A fixed
   sigma would give a target in a dense part of the collection (neutral faces) hundreds of
   photos and a rare expression (a broad smile) a single one; tying sigma to the target's
   own neighbour distances keeps the effective number of photos similar (median 29 / 59 / 44
   for mouth / eyes / face on Bush, 11 / 25 / 22 on Blair: in 36-98 dimensions the K-th and
   the 10K-th neighbours are nearly as far, so the count is well above K). K = 2...32 and
   fractions of the collection were measured; smaller K was better down to K = 2-3 on both
   collections (Bush mouth gain +0.047 at K = 3 against +0.042 at K = 20 and +0.036 with
   the paper's sigma). The paper's sigma "can vary around 6-12 for different sizes and
   qualities of the photo collections" (Sec. 6-7): this is that adaptation, made explicit.
4. At most ``max_photos`` = 32 photos per region and target (the rest of the Gaussian tail
   is cut): measured +0.001-0.003 SSIM, and a target reads only those photos' rows.
5. Spatial blending: soft masks (mouth, eyes + brows + forehead, rest) summing to 1 at every
   pixel, Gaussian-feathered over 0.12 IOD (no seam; :func:`region_masks`). A pixel's weight
   for photo i is sum_r m_r(x) W_r^i, W_r^i the region's Eq. 3 factor (similarity + uniform
   term) normalised over the photos, so a smile does not have to wait for the eyes to match.
   Outside the face (grown by 0.3 IOD, :func:`face_support`: hair, background, neck) the
   texture is the expression-independent average.
6. The mouth's weights mix the regions' (:func:`mix_similarities`, ``TextureParams.mouth_mix``:
   mouth 0.4, face 0.4, eyes 0.2, each normalised): leave-out mouth SSIM +0.004-0.008 on all six
   collections (figures in :class:`facetex.persona.TextureParams`).

Tried and dropped (measured worse): truncating each region to its principal components by
the broken-stick rule (the "noise" dimensions carry lip and lid shape: -0.004 to -0.013
mouth SSIM), not centring the regions, and a global sigma from the collection's median
K-th-neighbour distance (weights too flat for common expressions).

Tried for the mouth's leave-out gain over static (5 folds; the default +0.026 on Koizumi, 47
photos per persona, +0.030 on Arroyo, 35) and dropped, none moved it by more than its standard
error (0.005-0.007): a mouth metric learned from the collection (ridge regression, GCV, of each
photo's aligned mouth luminance, 10 principal components, on its mouth coordinates; distances
mapped through it: +0.028 / +0.027; to the photos' actual appearance: +0.024 / +0.032); photo
quality factors (how typical a photo's mouth is, how well its fiducials predict it: 0 to -0.005);
local-linear weights (the weighted mean expression moved onto the target's, against the average's
pull to common mouths: -0.003 to -0.04, worst on open mouths); a pose kernel (yaw, pitch; sigma
8-30 deg: -0.005 to 0); the mouth's blend region grown from 0.35 to 0.5 / 0.7 IOD (+0.001 / 0);
detail weights for the mouth (its finest 2-4 levels from fewer photos, power 2-8, with K 3-8:
-0.004 to -0.015; from more, power 0.3-0.5: -0.002 to -0.005); a global ridge regression of the
texture on the mouth coordinates (-0.004 to -0.035; added to ours: +0.001).
Nor did more photos: each fold's persona built with every photo's mirror image too (94 photos,
fiducials mirrored) scored ours 0.8056 against 0.8058 on Koizumi (its static average 0.004 worse).
Blending via the neutral frame is not the loss either: each photo warped straight to the target in
one resampling scores the same (0.8047 vs 0.8049 single-scale, open mouths included).
With the mix, on Koizumi (+0.0294) and Arroyo (+0.0357), none of these moved it by more than 0.001:
``max_photos`` 16 / 64, K 2 / 5, weights spread over an appearance graph of the collection's mouths
(high-pass correlation, 3 or 8 neighbours: -0.004 to +0.0007). Before it (the mouth's own weights,
Koizumi): a 7-number mouth descriptor (inner and outer opening, width, corner lift, lip
thicknesses; z-scored) -0.010 to -0.016; MediaPipe's lip contours on the frontal photos -0.005 to
-0.013; the weights squared -0.007 (to the 4th: -0.025; square root -0.003); each photo reweighted
by its agreement with the blend's own mouth (fiducials only) -0.0003 to -0.017; the top photos
flowed onto the blend's mouth per target (the paper's dense step at the target) -0.004 to 0; a
stronger collection flow (alpha 0.08 / 0.02: -0.001 / -0.012; at 0.3 the flow is < 0.32 px) and
none (+0.0002). An oracle shows the room: the 4 photos whose mouths best match the held-out
photo's, blended, +0.059 (chosen on its high-pass structure alone, lighting left out: +0.051); the
fiducials' ranking correlates 0.39 with it.
What did move it: less noisy fiducials. The photos' landmarks fitted on a 2x upscale of the face and
refitted once, as the driver's tracker fits a frame's (:class:`facetex.persona.PersonaParams`
``landmark_face_px``, ``landmark_refits``): Koizumi +0.0294 -> +0.0334, Arroyo +0.0357 -> +0.0363
(upscaled to 300 px, refitted twice, or the fits at 200, 300 and 400 px averaged: +0.035 on Koizumi).
The fit repeated on the mirror image and the two averaged (``landmark_mirror``,
:func:`facetex._landmark_fit.refine_landmarks`): mouth +0.0001 / +0.0016 on Koizumi / Arroyo, +0.0023
on Blair (face +0.002-0.004 on the three); the last fit alone mirrored, -0.001 to -0.002 on Williams
and Chavez; with the box also shifted four ways (ten fits averaged) +0.0348 / +0.0375 on Koizumi /
Arroyo: dlib's own scatter is averaged away, its bias and the 68 points' coarseness stay.
Then dropped (Koizumi): the jaw's points (iBUG 4-12 or 6-10) added to the mouth's distance, -0.003;
each aligned photo's lighting taken out before the blend (its coefficients on the collection's 4
appearance components fitted outside the mouth, subtracted at 0.5 / 1: -0.0035 / -0.013); Eq. 3's
beta 10 / 5 / 2 (0 / -0.001 / -0.017; beta 2 raises the eyes' gain by 0.012: the eyes' and the
mouth's bands want different breadths); tau 1e-3 (+0.0003). With these landmarks the mouth's K 2 / 4,
the mix's shares (0.5 / 0.3 / 0.2, 0.3 / 0.5 / 0.2, 0.4 / 0.6 / 0) and ``max_photos`` 16 stay within
0.001 on Koizumi and Arroyo.
Nor did (Koizumi): each lip point moved halfway to its projection on MediaPipe's lip contour of the
same frontal image (photos and target, the weights only; two detectors' noise averaged), +0.0008
(s.e. 0.0016), all the way -0.0026; a diagonal metric on the mouth coordinates learned across the
other five collections (non-negative least squares of pairwise aligned-mouth SSIM, per-photo
offsets): rank correlation with the true similarity 0.40 -> 0.42, but its 4 nearest photos matched
no better (mean aligned-mouth SSIM 0.719 against 0.717 Euclidean on Koizumi, 0.002-0.011 lower on
the other five collections; the oracle's 0.795). Nor 10 folds instead of 5 (more photos per persona): Koizumi +0.0358, Arroyo
+0.0362.
Nor a stronger lip detector: MediaPipe's attention mesh (``face_landmark_with_attention``, its lips
refined by their own sub-model; it ships in mediapipe 0.10.14's wheel, which needs numpy < 2, and uses
custom TFLite ops, so it was run in a separate environment on the frontal photos): the mouth's
distance on its 40 or 80 lip points, on dlib's 18 and its 40, or dlib's points moved onto its
contours, Koizumi -0.0010 to +0.0003, Arroyo -0.0007 to +0.0004 (s.e. 0.001-0.002); its whole mesh, or
the points below the nose, -0.0016 to -0.0031. Nor the photos' lip points moved by their collection flow
there (what the flow found the fiducials missed): the flow is under 0.2 px, Koizumi within 0.0001.
Nor can any shrinkage towards the static average: static + lambda (ours - static) scores best at
lambda = 1 on both collections, and even lambda chosen per target by the held-out photo itself (an
oracle) reaches only +0.0384 on Koizumi and +0.0431 on Arroyo (5 folds).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from ..errors import BadInputError
from ..geometry.masks import disc
from ..landmarks import eye_distance

__all__ = [
    "REGIONS",
    "RIGID49",
    "ExpressionModel",
    "fit_expression_model",
    "mix_similarities",
    "normalised_fiducials",
    "region_masks",
    "global_similarity",
    "face_support",
    "iod49",
    "temporal_weights",
    "detail_weights",
]

#: 49-point indices (Tom Hanks / SDM layout: iBUG 17..67 without 60, 64) of each region.
REGIONS: dict[str, np.ndarray] = {
    "mouth": np.arange(31, 49),  # iBUG 48..59 outer lip, 61..63, 65..67 inner lip
    "eyes": np.r_[0:10, 19:31],  # iBUG 17..26 brows, 36..47 eyes
    "face": np.arange(49),  # everything else: all fiducials
}
#: Points the normalisation aligns on (they move least with expression): eye corners, nose.
RIGID49 = np.r_[10:19, 19, 22, 25, 28]


def iod49(f49) -> float:
    """Distance between the eye centres of 49 fiducials (iBUG 36..41 and 42..47)."""
    f = np.asarray(f49, np.float64)
    return float(np.linalg.norm(f[..., 19:25, :].mean(axis=-2) - f[..., 25:31, :].mean(axis=-2)))


def _procrustes(f: np.ndarray, ref: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(..., 49, 2) fiducials mapped by the similarity that best maps f[idx] onto ref[idx]."""
    a = f[..., idx, :]
    mu_a = a.mean(axis=-2, keepdims=True)
    mu_r = ref[idx].mean(axis=0)
    a0 = a - mu_a
    r0 = ref[idx] - mu_r
    # complex-number form of the 2-D similarity: z' = c z, c = sum conj(a) r / sum |a|^2
    za = a0[..., 0] + 1j * a0[..., 1]
    zr = r0[:, 0] + 1j * r0[:, 1]
    c = (np.conj(za) * zr).sum(axis=-1) / np.maximum((np.abs(za) ** 2).sum(axis=-1), 1e-12)
    zf = (f[..., 0] - mu_a[..., 0]) + 1j * (f[..., 1] - mu_a[..., 1])
    out = c[..., None] * zf
    return np.stack([out.real + mu_r[0], out.imag + mu_r[1]], axis=-1)


def normalised_fiducials(fiducials, mean) -> np.ndarray:
    """(..., 49, 2) fiducials similarity-aligned to ``mean`` on :data:`RIGID49`, in units of
    ``mean``'s eye-centre distance (origin at ``mean``'s rigid-point centroid)."""
    f = np.asarray(fiducials, np.float64)
    m = np.asarray(mean, np.float64)
    a = _procrustes(f, m, RIGID49)
    return (a - m[RIGID49].mean(axis=0)) / iod49(m)


@dataclass(frozen=True, eq=False)
class _Region:
    name: str
    index: np.ndarray  # 49-point indices
    centre: bool  # subtract the region's own centroid
    coords: np.ndarray  # (n, 2 x points) the collection's normalised coordinates
    kth: float  # the collection's median distance to the k-th neighbour (IOD units)
    k: int  # neighbours of the adaptive sigma


@dataclass(frozen=True, eq=False)
class ExpressionModel:
    """Per-region expression subspaces and sigmas of a collection (see the module docstring)."""

    mean_fiducials: np.ndarray
    regions: tuple[_Region, ...]
    #: ((region, ((source region, share), ...)), ...): :func:`mix_similarities`
    mix: tuple = ()

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.regions)

    def coordinates(self, fiducials) -> list[np.ndarray]:
        """Per region, (..., 2 x points) normalised coordinates of (..., 49, 2) fiducials."""
        z = normalised_fiducials(fiducials, self.mean_fiducials)
        return [_region_coords(z, r.index, r.centre) for r in self.regions]

    def similarities(self, targets) -> np.ndarray:
        """exp(-d_r^2 / 2 sigma_r(T)^2) of every photo to every target, (B, R, n) for (B, 49, 2)
        targets ((R, n) for one (49, 2) target); sigma_r(T) = the target's distance to its
        ``neighbours``-th nearest photo / :data:`SIGMA_DIVISOR` (:func:`adaptive_sigma`)."""
        t = np.asarray(targets, np.float64)
        one = t.ndim == 2
        s = self.evaluate(t[None] if one else t)[2]
        return s[0] if one else s

    def evaluate(self, targets) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
        """(:meth:`coordinates`, :meth:`sigmas`, :meth:`similarities`) of (B, 49, 2) targets at once
        (each computed once)."""
        coords = self.coordinates(np.asarray(targets, np.float64))
        sig, out = [], []
        for r, c in zip(self.regions, coords):
            d2 = _squared_distances(c, r.coords)
            sig.append(adaptive_sigma(np.sqrt(d2), r.k, floor=1e-3 * r.kth))
            out.append(np.exp(-d2 / (2.0 * sig[-1][:, None] ** 2)))
        S = mix_similarities(np.stack(out, axis=1), self.names, self.mix)
        return coords, np.stack(sig, axis=1), S

    def sigmas(self, targets) -> np.ndarray:
        """(B, R) adaptive sigmas (IOD units) of (B, 49, 2) targets."""
        t = np.asarray(targets, np.float64).reshape(-1, 49, 2)
        out = []
        for r, c in zip(self.regions, self.coordinates(t)):
            d = np.sqrt(_squared_distances(c, r.coords))
            out.append(adaptive_sigma(d, r.k, floor=1e-3 * r.kth))
        return np.stack(out, axis=1)

    def summary(self) -> dict:
        return {r.name: {"points": len(r.index), "neighbours": r.k, "median_kth_distance_iod": round(r.kth, 4)}
                for r in self.regions}


#: targets whose distances to the photos are computed at once: the (targets, photos, coordinates)
#: differences of a 1200-frame clip and 519 photos took ~0.45 GB at once (growing with the clip)
DISTANCE_BLOCK = 64


def _squared_distances(c: np.ndarray, photos: np.ndarray) -> np.ndarray:
    """(B, n) squared distances of (B, D) target coordinates to (n, D) photo coordinates, in blocks
    of :data:`DISTANCE_BLOCK` targets: the same values as all at once (scipy's ``cdist`` sums the
    coordinates in another order, so its weights would differ in the last bits)."""
    out = np.empty((len(c), len(photos)))
    for i in range(0, len(c), DISTANCE_BLOCK):
        out[i:i + DISTANCE_BLOCK] = ((c[i:i + DISTANCE_BLOCK, None, :] - photos[None]) ** 2).sum(-1)
    return out


#: sigma_r(T) = (distance to the K-th nearest photo) / SIGMA_DIVISOR: the K-th neighbour gets
#: exp(-2) = 0.14 of the nearest's weight, photos 1.5x further 0.011.
SIGMA_DIVISOR = 2.0


def adaptive_sigma(distances, k: int, *, floor: float = 1e-9) -> np.ndarray:
    """Per target (rows of ``distances`` (B, n)): its distance to the k-th nearest photo divided
    by :data:`SIGMA_DIVISOR` (at least ``floor``)."""
    d = np.asarray(distances, np.float64)
    k = int(min(max(1, k), d.shape[-1]))
    kth = np.partition(d, k - 1, axis=-1)[..., k - 1]
    return np.maximum(kth / SIGMA_DIVISOR, floor)


def _region_coords(z: np.ndarray, index: np.ndarray, centre: bool) -> np.ndarray:
    x = z[..., index, :]
    if centre:
        x = x - x.mean(axis=-2, keepdims=True)
    return x.reshape(x.shape[:-2] + (-1,))


def mix_similarities(S, names, mix) -> np.ndarray:
    """(..., R, n) regional similarities with each region of ``mix`` ((region, ((source, share),
    ...)), ...) replaced by the shares' sum of its sources' similarities, each normalised over the
    photos, times the region's own total (its balance with Eq. 3's uniform term kept). Regions not
    in ``names`` are an error."""
    S = np.asarray(S, np.float64)
    if not mix:
        return S
    names = list(names)
    out = S.copy()
    norm = S / np.maximum(S.sum(axis=-1, keepdims=True), 1e-300)
    for region, sources in mix:
        for name in (region, *(src for src, _ in sources)):
            if name not in names:
                raise BadInputError(f"weight mix names region {name!r}, not one of the regions {tuple(names)}")
        j = names.index(region)
        mixed = sum(float(share) * norm[..., names.index(src), :] for src, share in sources)
        out[..., j, :] = mixed * S[..., j, :].sum(axis=-1, keepdims=True)
    return out


def fit_expression_model(fiducials, *, neighbours=3, regions=("mouth", "eyes", "face"), mix=()) -> ExpressionModel:
    """The regional expression model of a collection's (n, 49, 2) pose-corrected fiducials
    (module docstring). ``neighbours``: K of the adaptive sigma, one number or one per region
    (a number in (0, 1) is a fraction of the collection); ``mix``: regions whose weights mix
    other regions' (:func:`mix_similarities`), checked here."""
    from scipy.spatial.distance import cdist

    f = np.asarray(fiducials, np.float64)
    if f.ndim != 3 or f.shape[1:] != (49, 2) or len(f) < 3:
        raise BadInputError(f"need (n >= 3, 49, 2) fiducials to fit the expression weights, got {f.shape}")
    n = len(f)
    ks = [neighbours] * len(regions) if np.isscalar(neighbours) else list(neighbours)
    if len(ks) != len(regions) or any(k <= 0 for k in ks):
        raise BadInputError(f"neighbours must be one positive number or one per region {regions}, got {neighbours!r}")
    M = f.mean(axis=0)
    z = normalised_fiducials(f, M)
    out = []
    for name, k in zip(regions, ks):
        if name not in REGIONS:
            raise BadInputError(f"unknown weight region {name!r}: use {', '.join(REGIONS)}")
        k = int(round(k * n)) if k < 1 else int(k)
        k = int(min(max(1, k), n - 1))
        centre = name != "face"
        coords = _region_coords(z, REGIONS[name], centre)
        # scipy's pairwise distances: the (n, n, D) broadcast difference cost ~0.6 s on 519 photos
        d = cdist(coords, coords)
        np.fill_diagonal(d, np.inf)
        kth = float(max(np.median(np.partition(d, k - 1, axis=1)[:, k - 1]), 1e-6))
        out.append(_Region(name, REGIONS[name], centre, coords, kth, k))
    mix = tuple((region, tuple((src, float(share)) for src, share in sources)) for region, sources in mix)
    for region, sources in mix:
        shares = [share for _, share in sources]
        if not sources or min(shares) < 0 or not math.isclose(sum(shares), 1.0, abs_tol=1e-6):
            raise BadInputError(f"the weight mix of {region!r} needs non-negative shares summing to 1, got {sources!r}")
    mix_similarities(np.ones((len(out), 1)), regions, mix)  # names checked
    return ExpressionModel(M, tuple(out), mix)


def region_masks(points68, shape, regions=("mouth", "eyes", "face"), *, feather_iod: float = 0.12) -> np.ndarray:
    """(R, H, W) float32 soft masks of ``regions`` on a face with 68 landmarks, summing to 1
    at every pixel: mouth (lips dilated by 0.35 IOD: nasolabial folds, chin crease), eyes
    (eyes and brows dilated by 0.25 IOD, up to the forehead), and "face" = the rest.
    Edges are Gaussian-feathered with sigma ``feather_iod`` x IOD."""
    p = np.asarray(points68, np.float64)
    if p.shape != (68, 2):
        raise BadInputError(f"region masks need (68, 2) landmarks, got {p.shape}")
    H, W = int(shape[0]), int(shape[1])
    iod = eye_distance(p)
    sig = max(feather_iod * iod, 0.5)

    def blob(pts: np.ndarray, grow: float) -> np.ndarray:
        hull = cv2.convexHull(pts.astype(np.float32)).reshape(-1, 2)
        m = np.zeros((H, W), np.uint8)
        cv2.fillPoly(m, [np.round(hull).astype(np.int32)], 1)
        r = int(round(grow * iod))
        if r > 0:
            m = cv2.dilate(m, disc(r))
        return cv2.GaussianBlur(m.astype(np.float32), (0, 0), sig)

    brow_top = p[17:27].copy()
    brow_top[:, 1] -= 0.45 * iod  # forehead above the brows (brow raise lines)
    parts = {"mouth": blob(p[48:68], 0.35), "eyes": blob(np.vstack([p[17:27], p[36:48], brow_top]), 0.2)}
    masks = []
    rest = np.ones((H, W), np.float32)
    for name in regions:
        if name == "face":
            masks.append(None)
            continue
        m = np.minimum(parts[name], rest)
        rest = rest - m
        masks.append(m)
    masks = [rest if m is None else m for m in masks]
    return np.stack(masks).astype(np.float32)


def face_support(points68, shape, *, grow_iod: float = 0.3, feather_iod: float = 0.12) -> np.ndarray:
    """(H, W) float32 soft region where the texture depends on the expression: the face (jaw
    line and forehead arc) grown by ``grow_iod`` x IOD, Gaussian-feathered (sigma ``feather_iod``
    x IOD). Outside it (hair, background, neck) the texture is the collection's static average."""
    from ..geometry.masks import face_outline

    p = np.asarray(points68, np.float64)
    H, W = int(shape[0]), int(shape[1])
    iod = eye_distance(p)
    m = np.zeros((H, W), np.uint8)
    cv2.fillPoly(m, [np.round(face_outline(p)).astype(np.int32)], 1)
    r = int(round(grow_iod * iod))
    if r > 0:
        m = cv2.dilate(m, disc(r))
    return np.clip(cv2.GaussianBlur(m.astype(np.float32), (0, 0), max(feather_iod * iod, 0.5)), 0, 1)


def global_similarity(target, fiducials, sigma: float = 10.0, *, scale: float = 1.0) -> np.ndarray:
    """Eq. 2 factor exp(-||F^T - F^i||^2 / 2 sigma^2) per photo (n,) (or (..., n) for (..., 49, 2)
    targets broadcast against (n, 49, 2)); distances are multiplied by ``scale`` first."""
    t = np.asarray(target, np.float64)
    f = np.asarray(fiducials, np.float64)
    d2 = ((f - t) ** 2).sum(axis=(-2, -1)) * scale**2
    return np.exp(-d2 / (2.0 * sigma**2))


def temporal_weights(weights, coordinates, sigmas, *, sigma_frames: float, range_scale: float = 1.0,
                     last: bool = False, segments=None) -> np.ndarray:
    """Expression weights of a frame sequence made temporally coherent (puppetry, beyond the paper).

    ``weights`` (N, R, n): each frame's per-region photo weights as its blend would use them;
    ``coordinates``: per region, (N, D_r) the frames' normalised region coordinates
    (:meth:`ExpressionModel.coordinates`); ``sigmas`` (N, R) their adaptive sigmas. Each frame's
    normalised weights become the average of its neighbours' (N, R, n), weighted by a Gaussian in
    time (``sigma_frames``, cut at 3 sigma) times a Gaussian in expression distance (the region's
    coordinates, scale ``range_scale`` x the frame's own sigma): a bilateral filter. Why: the
    regional weights pick each frame's few nearest photos, and landmark jitter of a still face
    swaps them from frame to frame (the texture shimmers); frames with the same expression now
    share one blend, while frames with another expression (a mouth opening) are not mixed in,
    so the expression stays. Each frame keeps its total weight (the uniform term of Eq. 3 is
    relative to it). Frames are filtered in a band (cost O(N x window x n)). ``last``: only the
    last frame's weights, (1, R, n) (a causal filter's newest frame; the same values as the last
    row of the full result, at 1/N of the cost). ``segments`` (N,): shot ids of an edited clip
    (:func:`facetex.puppet.driver.shot_starts`); frames of different shots are not mixed."""
    W = np.asarray(weights, np.float64)
    if W.ndim != 3:
        raise BadInputError(f"temporal weights need (frames, regions, photos) weights, got {W.shape}")
    N, R, n = W.shape
    sig = np.asarray(sigmas, np.float64).reshape(N, R)
    if len(coordinates) != R:
        raise BadInputError(f"{len(coordinates)} coordinate sets for {R} regions")
    if sigma_frames <= 0 or N < 2:
        return W[-1:].copy() if last else W.copy()
    half = int(math.ceil(3.0 * sigma_frames))
    t0 = N - 1 if last else 0  # the first frame filtered
    seg = None if segments is None else np.asarray(segments).reshape(N)
    out = np.empty((N - t0, R, n))
    for j in range(R):
        tot = W[:, j].sum(axis=-1)
        P = W[:, j] / np.maximum(tot, 1e-300)[:, None]
        c = np.asarray(coordinates[j], np.float64).reshape(N, -1)
        s2 = 2.0 * (range_scale * np.maximum(sig[:, j], 1e-12)) ** 2 if range_scale > 0 else None
        acc = np.zeros((N - t0, n))
        norm = np.zeros(N - t0)
        for o in range(-half, half + 1):
            lo, hi = max(t0, -o), min(N, N - o)  # frames t with t + o inside
            if hi <= lo:
                continue
            k = np.full(hi - lo, math.exp(-(o * o) / (2.0 * sigma_frames**2)))
            if s2 is not None and o:
                d2 = ((c[lo:hi] - c[lo + o:hi + o]) ** 2).sum(axis=-1)
                k *= np.exp(-d2 / s2[lo:hi])
            if seg is not None and o:
                k *= seg[lo:hi] == seg[lo + o:hi + o]
            acc[lo - t0:hi - t0] += k[:, None] * P[lo + o:hi + o]
            norm[lo - t0:hi - t0] += k
        out[:, j] = acc / norm[:, None] * tot[t0:, None]
    return out


def detail_weights(weights, power: float, quality=None) -> np.ndarray:
    """Photo weights of the fine pyramid levels (the detail bands): each target's (B, n) weights
    raised to ``power`` and rescaled to the same total per target.

    Why: w^power = exp(-d^2 / 2 (sigma / sqrt(power))^2) is the same Gaussian with a narrower
    sigma, so the detail bands come from the few photos nearest the target's expression while
    the coarse bands (shading, the shape of the blob) stay a broad, consistent average (Tom Hanks
    Sec. 5: "preserves a uniform illumination ... and enhances details in the higher frequency
    bands"). An average of ~20-60 photos whose irises, lids and creases are not aligned to the
    pixel is a smooth blob (no whites, no iris); raising the weights to the 4th-8th power keeps
    1-5 of them. ``quality`` (n,): each photo's detail confidence in the region (Eq. 2's L^alpha
    as one number per photo and region, :meth:`_Prepared.eye_quality`), multiplied in after the
    power. Zero weights stay zero; power 1 without quality returns the weights unchanged."""
    W = np.asarray(weights, np.float64)
    if not (np.isfinite(power) and power > 0):
        raise BadInputError(f"detail power must be a positive number, got {power!r}")
    if power == 1 and quality is None:
        return W.copy()
    top = W.max(axis=-1, keepdims=True)
    P = (W / np.where(top > 0, top, 1.0)) ** power  # divided by the maximum first: no underflow
    if quality is not None:
        P = P * np.asarray(quality, np.float64)  # Eq. 2 (Tom Hanks): similarity x detail confidence
    tot = P.sum(axis=-1, keepdims=True)
    return P * (W.sum(axis=-1, keepdims=True) / np.where(tot > 0, tot, 1.0))
