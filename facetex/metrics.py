"""FaceTex evaluation metrics (§3.1 of Kaur, Zhang & Dana 2017), numpy in, floats out.

- :func:`landmark_error` — E(a, b), "mean square error of the landmarks" on the 66
  FaceTex landmarks, at the paper's 1000 px working size.
- :func:`texture_similarity` — S(a, b), Eq. 8 averaged over three skin patches.
- :func:`identity_distance` — beyond the paper: distance of face-recognition
  descriptors (dlib convention: < 0.6 means the same person).

Beyond the paper, to see whether texture really moved and nothing else did:

- :func:`skin_detail` — std (0–255) of a σ = 2 px high-pass of the luminance in the same
  three skin patches, at the image's native resolution (pores, fine wrinkles, stubble);
- :func:`protected_change` — mean |Δ| (0–255) over eyes, brows and lips;
- :func:`background_change` — mean |Δ| (0–255) outside the face;
- :func:`lowfreq_skin_delta_e` — ΔE (CIELAB, L 0..100) of the skin's colour and shading,
  both images blurred at 0.1 × the eye distance over the skin only (issue 22: detail, not
  lighting);
- :func:`hair_leakage` — structure-tensor coherence of the change image on the forehead
  (hair strands are oriented, pores are not);
- :func:`dark_speck_density` on :func:`stubble_regions` — dark specks per 1000 px on the
  upper lip and chin (stubble);
- :func:`skin_coverage` — fraction of the content's skin that changed;
- :func:`mark_survival` — the content's marks (moles, spots) kept and the style's arrived;
- in :func:`transfer_metrics`: ``S_style_gain`` = S(xt, xs) − S(xc, xs) (the move towards
  the style compared with doing nothing) and ``detail_ratio`` = detail(output) / detail(the
  style aligned onto the content), ``detail_moved`` = (detail(output) − detail(content)) /
  (detail(style) − detail(content)) per patch (the fraction of the way from the content's
  fine-detail level to the style's own), ``stubble_moved`` likewise for dark specks.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .errors import BadInputError
from .io import ImageLike, image_args

WORKING_SIZE = 1000  # px, long edge at which the paper measures E and S
#: ``facetex metrics`` reads larger images reduced on load to this many pixels (2000 x 2000):
#: the paper's measures are taken at 1000 px, and a 36 MP photo at full resolution takes
#: minutes and several GB (issue 23). The functions here take any size.
METRICS_MAX_PIXELS = 4_000_000
PATCH_SIZE = 100  # px at WORKING_SIZE (§3.1: 100 × 100 skin patches)
SKIN_PATCHES = ("forehead", "left_cheek", "right_cheek")


@dataclass(frozen=True)
class LandmarkError:
    """``mse_px2``: mean over the 66 points of the squared distance (px², the paper's E);
    ``rms_px``: its square root (px), easier to read."""

    mse_px2: float
    rms_px: float


def _as_points(p, name: str) -> np.ndarray:
    p = np.asarray(p, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise BadInputError(f"{name} must be an (N, 2) array of points, got shape {p.shape}")
    return p


def landmark_error_points(points_a, points_b, *, scale_a: float = 1.0, scale_b: float = 1.0) -> LandmarkError:
    """E between two point sets: (1/N) Σ_k ‖s_a·a_k − s_b·b_k‖² in px² (and the RMS in px).

    ``scale_*`` bring each set to the working size (WORKING_SIZE / long edge)."""
    a = _as_points(points_a, "points_a") * scale_a
    b = _as_points(points_b, "points_b") * scale_b
    if a.shape != b.shape:
        raise BadInputError(f"point sets differ in shape: {a.shape} vs {b.shape}")
    mse = float(np.mean(np.sum((a - b) ** 2, axis=1)))  # FaceTex §3.1 landmark error
    return LandmarkError(mse, float(np.sqrt(mse)))


def working_scale(image_or_shape) -> float:
    """Factor from an image's pixels to the 1000 px long-edge working size."""
    shape = getattr(image_or_shape, "shape", image_or_shape)
    return WORKING_SIZE / float(max(shape[0], shape[1]))


def _points68(image, points68, source):
    if points68 is not None:
        return _as_points(points68, "points68")
    from .landmarks import detect_face

    return detect_face(image, source=source).points68


@image_args("image_a", "image_b", sources={"image_a": "source_a", "image_b": "source_b"})
def landmark_error(image_a: ImageLike, image_b: ImageLike, *, points_a: np.ndarray | None = None,
                   points_b: np.ndarray | None = None, source_a: str | None = None,
                   source_b: str | None = None) -> LandmarkError:
    """E(a, b) on the 66 FaceTex landmarks, each image's points scaled to a 1000 px long edge.

    Parameters
    ----------
    image_a, image_b : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays.
    points_a, points_b : numpy.ndarray, optional
        Their (68, 2) landmarks; detected (largest face) when not given.
    source_a, source_b : str, optional
        The files to name in errors (the paths themselves when the images are paths).

    Returns
    -------
    LandmarkError
        ``mse_px2`` (E, px²) and ``rms_px``.

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    from .landmarks import points66

    pa = points66(_points68(image_a, points_a, source_a))
    pb = points66(_points68(image_b, points_b, source_b))
    return landmark_error_points(pa, pb, scale_a=working_scale(image_a), scale_b=working_scale(image_b))


def normalized_correlation(p, q) -> float:
    """Eq. 8 (FaceTex): normalized correlation coefficient of two equally sized patches."""
    p = np.asarray(p, dtype=np.float64).ravel()
    q = np.asarray(q, dtype=np.float64).ravel()
    if p.shape != q.shape:
        raise BadInputError(f"patches differ in size: {p.size} vs {q.size}")
    p = p - p.mean()
    q = q - q.mean()
    denom = np.sqrt(np.sum(p * p) * np.sum(q * q))
    return float(np.sum(p * q) / denom) if denom > 0 else 0.0


def skin_patch_frames(points68, image_shape) -> dict[str, np.ndarray]:
    """2 × 3 affine maps (image → patch) of the forehead and cheek patches.

    Positions are landmark-relative, so the same facial spot is sampled in both images:
    the frame's x axis follows the eye line; with ``d`` the distance between the eye
    centres, the forehead patch's lower edge lies 0.08·d above the brow arches
    (points 19 and 24), each cheek patch at the centroid of the jaw point 2 (or 14), the
    nostril point 31 (35), the lower eyelid 41 (46) and the mouth corner 48 (54).
    The patch side is 100 px at the 1000 px working size, scaled with the image."""
    p = _as_points(points68, "points68")
    if p.shape[0] != 68:
        raise BadInputError(f"need 68 landmarks, got {p.shape[0]}")
    left_eye, right_eye = p[36:42].mean(0), p[42:48].mean(0)
    ex = right_eye - left_eye
    d = float(np.hypot(*ex))
    ex /= d
    ey = np.array([-ex[1], ex[0]])  # image "down" direction for an upright face
    side = PATCH_SIZE / working_scale(image_shape)
    centres = {
        # just above the brow arches: foreheads are short, hair starts soon above
        "forehead": p[[19, 24]].mean(0) - (side / 2 + 0.08 * d) * ey,
        "left_cheek": p[[2, 31, 41, 48]].mean(0),
        "right_cheek": p[[14, 35, 46, 54]].mean(0),
    }
    frames = {}
    for name, c in centres.items():
        # patch pixel (u, v) samples image point c + (u - side/2)·ex + (v - side/2)·ey
        origin = c - side / 2 * (ex + ey)
        to_image = np.column_stack([ex, ey, origin])
        frames[name] = cv2.invertAffineTransform(to_image)
    return frames


def _luminance(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float32)
    if image.ndim == 2:
        return image
    return image[..., :3] @ np.array([0.299, 0.587, 0.114], dtype=np.float32)  # ITU-R BT.601 luma


def skin_patches(image, points68, *, gray: bool = True) -> dict[str, np.ndarray]:
    """The three skin patches (forehead, left cheek, right cheek) of an image."""
    img = _luminance(image) if gray else np.asarray(image, dtype=np.float32)
    side = int(round(PATCH_SIZE / working_scale(img.shape)))
    return {
        name: cv2.warpAffine(img, m, (side, side), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
        for name, m in skin_patch_frames(points68, img.shape).items()
    }


@image_args("image_a", "image_b", sources={"image_a": "source_a", "image_b": "source_b"})
def texture_similarity(image_a: ImageLike, image_b: ImageLike, *, points_a: np.ndarray | None = None,
                       points_b: np.ndarray | None = None, source_a: str | None = None,
                       source_b: str | None = None, gray: bool = True, per_patch: bool = False) -> float | dict:
    """S(a, b): Eq. 8 on the forehead and both cheek patches, averaged over the three.

    Patches of both images are resampled to the same size (100 px at the 1000 px scale of
    ``image_a``).

    Parameters
    ----------
    image_a, image_b : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays.
    points_a, points_b : numpy.ndarray, optional
        Their (68, 2) landmarks; detected (largest face) when not given.
    source_a, source_b : str, optional
        The files to name in errors (the paths themselves when the images are paths).
    gray : bool
        Correlate BT.601 luminance (texture is mostly luminance detail); False: the RGB
        values of a patch together.
    per_patch : bool
        Also return the three patches' values.

    Returns
    -------
    float or tuple
        S in [-1, 1]; with ``per_patch`` ``(S, {patch: S})``.

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    pa = _points68(image_a, points_a, source_a)
    pb = _points68(image_b, points_b, source_b)
    patches_a = skin_patches(image_a, pa, gray=gray)
    patches_b = skin_patches(image_b, pb, gray=gray)
    values = {}
    for name in SKIN_PATCHES:
        qa, qb = patches_a[name], patches_b[name]
        if qb.shape != qa.shape:
            qb = cv2.resize(qb, qa.shape[1::-1], interpolation=cv2.INTER_AREA)
        values[name] = normalized_correlation(qa, qb)
    mean = float(np.mean(list(values.values())))
    return (mean, values) if per_patch else mean


DETAIL_SIGMA = 2.0  # px, native: the high-pass is luminance minus its Gaussian blur of this sigma


MIN_SKIN_FRACTION = 0.2  # of a patch: with less skin than this a skin-only detail is NaN


def skin_detail(image, points68=None, *, sigma: float = DETAIL_SIGMA, source=None, per_patch: bool = False,
                mask=None):
    """Fine skin detail: std (0–255 scale) of ``L − G_sigma * L`` over the forehead and both
    cheek patches of :func:`skin_patch_frames`, at the image's own resolution (the patch
    pixels are sampled with nearest-neighbour, so no interpolation smooths them).
    ``mask`` (H, W) in [0, 1]: only the patch pixels where it is > 0.5 count (NaN for a patch
    with less than :data:`MIN_SKIN_FRACTION` of them)."""
    img = np.asarray(image, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] < 3:
        raise BadInputError(f"expected an (H, W, 3) image, got shape {img.shape}")
    if img.max() > 1.5:
        img = img / 255.0
    p = _points68(img, points68, source)
    lum = _luminance(img) * 255.0
    hp = lum - cv2.GaussianBlur(lum, (0, 0), sigma, borderType=cv2.BORDER_REFLECT)
    side = int(round(PATCH_SIZE / working_scale(img.shape)))
    if mask is not None:
        mask = np.asarray(mask, np.float32)
        if mask.shape != img.shape[:2]:
            raise BadInputError(f"mask has shape {mask.shape}, the image {img.shape[:2]}")
    values = {}
    for name, m in skin_patch_frames(p, img.shape).items():
        patch = cv2.warpAffine(hp, m, (side, side), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_REFLECT)
        if mask is None:
            values[name] = float(patch.std())
            continue
        keep = cv2.warpAffine(mask, m, (side, side), flags=cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT) > 0.5
        values[name] = float(patch[keep].std()) if keep.mean() >= MIN_SKIN_FRACTION else float("nan")
    mean = float(np.nanmean(list(values.values()))) if mask is not None else float(np.mean(list(values.values())))
    return (mean, values) if per_patch else mean


def _abs_change(a, b) -> np.ndarray:
    a = np.asarray(a, np.float32)
    b = np.asarray(b, np.float32)
    if a.shape != b.shape:
        raise BadInputError(f"images differ in shape: {a.shape} vs {b.shape}")
    if max(float(a.max()), float(b.max())) > 1.5:
        a, b = a / 255.0, b / 255.0
    d = np.abs(a - b) * 255.0
    return d.mean(axis=2) if d.ndim == 3 else d


def protected_change(output, content, *, points=None, source=None) -> float:
    """Mean |output − content| (0–255, averaged over channels) over the eyes, brows and lips
    of the content (:func:`facetex.geometry.skin.protected_mask`)."""
    from .geometry.skin import protected_mask

    p = _points68(content, points, source)
    m = protected_mask(p, np.asarray(content).shape[:2])
    return float(_abs_change(output, content)[m].mean()) if m.any() else 0.0


def face_area_mask(image, points68, *, mesh=None, margin: float = 0.03) -> np.ndarray:
    """bool (H, W): the face (jaw + forehead outline, united with the mesh's face oval when
    ``mesh`` is given, and with the head region where the transfer may find skin: up to the
    hairline, the temples and the jaw edge) grown by ``margin`` × face width. Its complement
    is the background."""
    from .geometry.masks import face_outline, face_width
    from .geometry.segment import head_region_mask
    from .geometry.skin import FACE_OVAL_468

    p = _as_points(points68, "points68")
    h, w = np.asarray(image).shape[:2]
    m = np.zeros((h, w), np.uint8)
    cv2.fillPoly(m, [np.round(face_outline(p) * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    if mesh is not None:
        oval = np.asarray(mesh)[list(FACE_OVAL_468), :2]
        cv2.fillPoly(m, [np.round(oval * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    m |= head_region_mask(p, (h, w), mesh=mesh).astype(np.uint8)
    r = max(1, int(round(margin * face_width(p))))
    m = cv2.dilate(m, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1)))
    return m.astype(bool)


def background_change(output, content, *, points=None, mesh=None, source=None) -> float:
    """Mean |output − content| (0–255) outside :func:`face_area_mask` of the content."""
    p = _points68(content, points, source)
    bg = ~face_area_mask(content, p, mesh=mesh)
    return float(_abs_change(output, content)[bg].mean()) if bg.any() else 0.0


@image_args("image_a", "image_b", sources={"image_a": "source_a", "image_b": "source_b"})
def identity_distance(image_a: ImageLike, image_b: ImageLike, *, points_a: np.ndarray | None = None,
                      points_b: np.ndarray | None = None, source_a: str | None = None,
                      source_b: str | None = None) -> float:
    """Euclidean distance of the FaceRecognitionNet (dlib ResNet) descriptors of two faces.

    Parameters
    ----------
    image_a, image_b : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays.
    points_a, points_b : numpy.ndarray, optional
        Their (68, 2) landmarks; detected (largest face) when not given.
    source_a, source_b : str, optional
        The files to name in errors (the paths themselves when the images are paths).

    Returns
    -------
    float
        The distance; < 0.6 means the same person by dlib's convention.

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    from .nets.dlib_resnet import face_descriptor

    da = face_descriptor(image_a, _points68(image_a, points_a, source_a))
    db = face_descriptor(image_b, _points68(image_b, points_b, source_b))
    return float(np.linalg.norm(da - db))


@image_args("output", "content", "style", "aligned_style")
def transfer_metrics(output: ImageLike, content: ImageLike, style: ImageLike, *, points=None,
                     sources=(None, None, None), aligned_style: ImageLike | None = None,
                     content_mesh=None) -> dict:
    """All FaceTex metrics of a transfer output against its content and style images.

    Parameters
    ----------
    output, content, style : str, os.PathLike, PIL.Image.Image or numpy.ndarray
        Files, PIL images or (H, W, 3) uint8 / uint16 / float [0, 1] arrays (any mix).
    points : sequence of numpy.ndarray, optional
        The (68, 2) landmarks of (output, content, style), to skip detection.
    sources : tuple of str
        The files of (output, content, style) to name in errors.
    aligned_style : image, optional
        The style warped onto the content geometry (as the transfer's pre-warp makes it;
        default: :func:`facetex.geometry.align_style_to_content` on the full images, Lanczos
        resampling), for ``detail_ratio`` and the detail measures.
    content_mesh : numpy.ndarray, optional
        The content's 468-point face mesh for ``background_change`` (default: computed).

    Returns
    -------
    dict
        Metric name -> value (E, S, identity, detail, protected and background change,
        low-frequency ΔE, stubble, marks, detail moved; see ``facetex metrics --help``).

    Raises
    ------
    facetex.NoFaceError
        No face in an image whose points were not given."""
    images = (output, content, style)
    pts = list(points) if points is not None else [None, None, None]
    pts = [_points68(im, p, s) for im, p, s in zip(images, pts, sources)]
    e_c = landmark_error(output, content, points_a=pts[0], points_b=pts[1])
    e_s = landmark_error(output, style, points_a=pts[0], points_b=pts[2])
    s_style = texture_similarity(output, style, points_a=pts[0], points_b=pts[2])
    s_none = texture_similarity(content, style, points_a=pts[1], points_b=pts[2])
    if aligned_style is None:
        from .geometry.style_align import align_style_to_content

        aligned_style = align_style_to_content(np.asarray(style, np.float32), np.asarray(content, np.float32),
                                               style_points=pts[2], content_points=pts[1], refine=None,
                                               interpolation="lanczos").image
    d_out = skin_detail(output, pts[0])
    d_con = skin_detail(content, pts[1])
    d_sty = skin_detail(aligned_style, pts[1])
    skin = _content_skin(_rgb01(content), pts[1], None)
    lf = lowfreq_skin_delta_e(output, content, pts[1], skin=skin)
    stub = stubble_leakage(output, content, aligned_style, pts[1])
    marks = mark_survival(output, content, aligned_style, pts[1], skin=skin)
    from .geometry.segment import skin_mask

    style_skin = skin_mask(_rgb01(style), pts[2], source=True)  # its bare skin: no beard, hair or shine
    moved = detail_moved(output, content, style, pts[0], pts[1], pts[2], skins=(skin, style_skin))
    return {
        "E_content": e_c.mse_px2,
        "E_style": e_s.mse_px2,
        "E_content_rms_px": e_c.rms_px,
        "E_style_rms_px": e_s.rms_px,
        "S_content": texture_similarity(output, content, points_a=pts[0], points_b=pts[1]),
        "S_style": s_style,
        "S_style_none": s_none,
        "S_style_gain": s_style - s_none,
        "identity_content": identity_distance(output, content, points_a=pts[0], points_b=pts[1]),
        "identity_style": identity_distance(output, style, points_a=pts[0], points_b=pts[2]),
        "detail_output": d_out,
        "detail_content": d_con,
        "detail_style": d_sty,
        "detail_style_own": skin_detail(style, pts[2]),
        "detail_ratio": d_out / max(d_sty, 1e-9),
        "protected_change": protected_change(output, content, points=pts[1]),
        "background_change": background_change(output, content, points=pts[1], mesh=content_mesh),
        "lowfreq_dE": lf["mean"],
        "lowfreq_dE_max_region": lf["max_region"],
        "hair_leakage": hair_leakage(output, content, pts[1], skin=skin),
        "hair_leakage_style": hair_leakage(aligned_style, content, pts[1], skin=skin),
        "stubble_output": stub["output"],
        "stubble_content": stub["content"],
        "stubble_style": stub["style"],
        "stubble_moved": stub["moved"],
        "coverage": skin_coverage(output, content, pts[1], skin=skin),
        "detail_moved": moved["mean"],
        "detail_moved_cheeks": moved["cheeks_rougher"],
        "detail_moved_cheeks_skin": moved["cheeks_rougher_skin"],
        "marks_content": marks["content"],
        "marks_kept": marks["kept"],
        "marks_style": marks["style"],
        "marks_arrived": marks["arrived"],
    }


# ---------------------------------------------------------------- issue 22: detail, not lighting
LOWFREQ_SIGMA = 0.1  # × the eye distance (eye centres): the blur of the low-frequency ΔE
CHANGED_LEVEL = 1.0  # 0–255: a skin pixel "changed" when its |Δ| blurred at σ = 2 px exceeds this
SPECK_SIGMA = 3.0  # px at 1000 px: a speck is darker than the luminance blurred at this σ …
SPECK_DEPTH = 0.04  # … by more than this (luminance 0..1)
SPECK_AREA = (2, 60)  # px at 1000 px: a speck's area (larger dark pieces are shadows or lips)
COHERENCE_RHO = 4.0  # px at 1000 px: integration σ of the structure tensor


def _content_skin(image, points68, skin):
    if skin is not None:
        m = np.asarray(skin, np.float32)
        if m.shape != np.asarray(image).shape[:2]:
            raise BadInputError(f"skin mask has shape {m.shape}, the image {np.asarray(image).shape[:2]}")
        return m
    from .geometry.segment import skin_mask

    return skin_mask(np.asarray(image, np.float32), points68)


def _rgb01(image) -> np.ndarray:
    a = np.asarray(image, np.float32)
    if a.ndim != 3 or a.shape[2] < 3:
        raise BadInputError(f"expected an (H, W, 3) image, got shape {a.shape}")
    return a[..., :3] / 255.0 if a.max() > 1.5 else a[..., :3]


def lowfreq_skin_delta_e(output, content, points68, *, skin=None, sigma: float = LOWFREQ_SIGMA) -> dict:
    """ΔE76 (CIELAB, L 0..100) between ``output`` and ``content``, both low-passed at ``sigma`` ×
    the eye distance over the content's skin only (normalised convolution, so eyes, brows and
    hair never blur into it): ``mean`` over the skin (mask ≥ 0.5) and over each skin patch of
    :func:`skin_patch_frames` (``forehead``, ``left_cheek``, ``right_cheek``, and ``max_region``).
    ``skin``: the content's skin mask (default :func:`facetex.geometry.segment.skin_mask`)."""
    from .geometry.filters import masked_lowpass
    from .transfer.colour import eye_distance

    out, con = _rgb01(output), _rgb01(content)
    if out.shape != con.shape:
        raise BadInputError(f"images differ in shape: {out.shape} vs {con.shape}")
    p = _as_points(points68, "points68")
    m = _content_skin(con, p, skin)
    s = sigma * eye_distance(p)
    lab = [cv2.cvtColor(np.clip(masked_lowpass(x, m, s), 0, 1), cv2.COLOR_RGB2LAB) for x in (out, con)]
    de = np.sqrt(np.sum((lab[0] - lab[1]) ** 2, axis=2))
    inside = m >= 0.5
    res = {"mean": float(de[inside].mean()) if inside.any() else float("nan")}
    side = int(round(PATCH_SIZE / working_scale(con.shape)))
    for name, a in skin_patch_frames(p, con.shape).items():
        dp = cv2.warpAffine(de, a, (side, side), flags=cv2.INTER_NEAREST, borderValue=np.nan)
        mp = cv2.warpAffine(inside.astype(np.uint8), a, (side, side), flags=cv2.INTER_NEAREST) > 0
        res[name] = float(np.nanmean(dp[mp])) if mp.any() else float("nan")
    regions = [res[k] for k in SKIN_PATCHES if np.isfinite(res[k])]
    res["max_region"] = max(regions) if regions else float("nan")
    return res


def forehead_mask(points68, shape) -> np.ndarray:
    """bool (H, W): between the brows (points 17–26) and the forehead arc of
    :func:`facetex.geometry.masks.forehead_points`."""
    from .geometry.masks import forehead_points

    p = _as_points(points68, "points68")
    poly = np.vstack([p[17:27], forehead_points(p)])
    m = np.zeros(shape[:2], np.uint8)
    cv2.fillPoly(m, [np.round(poly * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
    return m.astype(bool)


def structure_coherence(image, mask=None, *, rho: float = COHERENCE_RHO) -> float:
    """Energy-weighted mean coherence (λ1 − λ2) / (λ1 + λ2) of the structure tensor of a
    grey image (gradient σ 1 px, integration σ ``rho`` px) over ``mask``: 1 for parallel
    strands (hair), lower for isotropic texture (pores)."""
    from skimage.feature import structure_tensor, structure_tensor_eigenvalues

    img = np.asarray(image, np.float64)
    m = np.ones(img.shape, bool) if mask is None else np.asarray(mask, bool)
    if mask is not None and m.any():  # only the mask's box and the filters' reach: the same values, less memory
        pad = int(np.ceil(4 * float(rho))) + 4  # scipy's Gaussian reaches 4 sigma; np.gradient 1 px
        ys, xs = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
        y0, y1 = max(0, ys[0] - pad), min(img.shape[0], ys[-1] + 1 + pad)
        x0, x1 = max(0, xs[0] - pad), min(img.shape[1], xs[-1] + 1 + pad)
        img, m = img[y0:y1, x0:x1], m[y0:y1, x0:x1]
    a = structure_tensor(img, sigma=float(rho), order="rc", mode="reflect")
    l1, l2 = structure_tensor_eigenvalues(a)
    energy = l1 + l2
    coh = np.where(energy > 0, (l1 - l2) / np.where(energy > 0, energy, 1.0), 0.0)
    wsum = float(energy[m].sum())
    return float((coh[m] * energy[m]).sum() / wsum) if wsum > 0 else 0.0


def hair_leakage(output, content, points68, *, skin=None, rho: float = COHERENCE_RHO) -> float:
    """Structure-tensor coherence (:func:`structure_coherence`) of the luminance change
    ``output − content`` on the content's forehead skin: strands of the style's fringe make
    the change oriented (findings: 0.29 against 0.21–0.23 for pores alone)."""
    out, con = _rgb01(output), _rgb01(content)
    p = _as_points(points68, "points68")
    m = forehead_mask(p, con.shape) & (_content_skin(con, p, skin) >= 0.5)
    if not m.any():
        return float("nan")
    d = (_luminance(out) - _luminance(con)) * 255.0
    return structure_coherence(d, m, rho=rho / working_scale(con.shape))


def stubble_regions(points68, shape) -> dict[str, np.ndarray]:
    """bool (H, W) masks of the ``upper_lip`` (nostrils 31–35 down to the upper lip's edge
    48–54) and the ``chin`` (the lower lip's edge 54–59 down to the jaw 6–10, drawn 15 % of
    the way back towards the mouth so it stays off the chin's edge), minus the lips."""
    from .geometry.skin import protected_mask

    p = _as_points(points68, "points68")
    h, w = shape[:2]
    mouth = p[48:60].mean(0)
    jaw = p[[6, 7, 8, 9, 10]]
    jaw = jaw + 0.15 * (mouth - jaw)
    polys = {"upper_lip": np.vstack([p[31:36], p[[54, 53, 52, 51, 50, 49, 48]]]),
             "chin": np.vstack([p[[54, 55, 56, 57, 58, 59, 48]], jaw])}
    lips = protected_mask(p, (h, w))
    r = max(1, int(round(0.01 * float(np.linalg.norm(p[16] - p[0])))))
    lips = cv2.dilate(lips.astype(np.uint8), cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1,) * 2)) > 0
    out = {}
    for k, poly in polys.items():
        m = np.zeros((h, w), np.uint8)
        cv2.fillPoly(m, [np.round(poly * 16).astype(np.int32)], 1, cv2.LINE_8, 4)
        out[k] = (m > 0) & ~lips
    return out


def dark_speck_density(image, mask) -> float:
    """Dark specks per 1000 px of ``mask``: connected pieces (8-connected) at least
    ``SPECK_DEPTH`` darker than the luminance blurred at ``SPECK_SIGMA`` px, of
    ``SPECK_AREA`` px (lengths at 1000 px, scaled with the image) — stubble, stray hairs."""
    img = _rgb01(image)
    m = np.asarray(mask, bool)
    if m.shape != img.shape[:2]:
        raise BadInputError(f"mask has shape {m.shape}, the image {img.shape[:2]}")
    area = int(m.sum())
    if area == 0:
        return float("nan")
    k = 1.0 / working_scale(img.shape)
    lum = _luminance(img)
    dark = (cv2.GaussianBlur(lum, (0, 0), SPECK_SIGMA * k, borderType=cv2.BORDER_REFLECT) - lum > SPECK_DEPTH) & m
    n, lab, stats, _ = cv2.connectedComponentsWithStats(dark.astype(np.uint8), connectivity=8)
    a = stats[1:, cv2.CC_STAT_AREA]
    lo, hi = SPECK_AREA[0] * k * k, SPECK_AREA[1] * k * k
    return float(np.count_nonzero((a >= lo) & (a <= hi)) * 1000.0 / area)


def stubble_leakage(output, content, aligned_style, points68) -> dict:
    """Dark-speck density (:func:`dark_speck_density`) on the content's upper lip and chin
    (both together) of the ``output``, the ``content`` and the ``aligned_style`` (the style
    warped onto the content), and ``moved`` = (output − content) / (style − content): the
    fraction of the way to the style's stubble (NaN when the style has no more than the content)."""
    p = _as_points(points68, "points68")
    regions = stubble_regions(p, np.asarray(content).shape)
    m = regions["upper_lip"] | regions["chin"]
    d = {k: dark_speck_density(im, m) for k, im in (("output", output), ("content", content), ("style", aligned_style))}
    gap = d["style"] - d["content"]
    d["moved"] = (d["output"] - d["content"]) / gap if gap > 0.5 else float("nan")
    return d


def skin_coverage(output, content, points68, *, skin=None, level: float = CHANGED_LEVEL) -> float:
    """Fraction of the content's skin (mask ≥ 0.5) that changed: |output − content| (0–255,
    mean of the channels) blurred at σ = 2 px (at 1000 px) above ``level``."""
    p = _as_points(points68, "points68")
    m = _content_skin(_rgb01(content), p, skin) >= 0.5
    if not m.any():
        return float("nan")
    d = _abs_change(output, content)
    d = cv2.GaussianBlur(d, (0, 0), 2.0 / working_scale(d.shape), borderType=cv2.BORDER_REFLECT)
    return float(np.mean(d[m] > level))


def mark_survival(output, content, aligned_style, points68, *, skin=None, style_skin=None) -> dict:
    """The content's marks that survive in the output and the style's that arrive
    (:func:`facetex.geometry.marks.detect_marks`, dark blobs on the skin): counts
    ``content`` / ``style`` (the style's marks in the content frame, on the aligned style's own
    skin, that the content does not have there) and fractions ``kept`` / ``arrived``."""
    from .geometry.marks import detect_marks, match_marks
    from .geometry.masks import face_width
    from .geometry.segment import skin_mask

    out, con, sty = _rgb01(output), _rgb01(content), _rgb01(aligned_style)
    p = _as_points(points68, "points68")
    mc = _content_skin(con, p, skin)
    ms = (skin_mask(sty, p) if style_skin is None else np.asarray(style_skin, np.float32)) * (mc > 0.05)
    fw = face_width(p)
    mk_c = detect_marks(con, mc, face_width=fw)
    mk_s = detect_marks(sty, ms, face_width=fw)
    mk_s = mk_s[~match_marks(mk_s, mk_c)]
    mk_o = detect_marks(out, mc, face_width=fw)
    kept = match_marks(mk_c, mk_o)
    arrived = match_marks(mk_s, mk_o)
    return {"content": int(len(mk_c)), "style": int(len(mk_s)),
            "kept": float(kept.mean()) if len(mk_c) else float("nan"),
            "arrived": float(arrived.mean()) if len(mk_s) else float("nan")}


def detail_moved(output, content, style, points_output, points_content, points_style, *, skins=None) -> dict:
    """Fraction of the way the fine skin detail (:func:`skin_detail`, per patch) moved from
    the content's level to the style's own: (d_out − d_con) / (d_sty − d_con), NaN where the two
    differ by < 0.1 (0–255). ``mean`` over the patches; ``cheeks_rougher`` over the cheeks
    where the style is rougher than the content (NaN when none is).

    ``skins`` = (content skin, style skin), (H, W) masks of the content and the style image:
    ``cheeks_rougher_skin`` is the same measure over the skin pixels of the patches only — the
    output and the content on the content's skin, the style on its source skin (no moustache,
    stubble, hair or highlights). The whole cheek patch reaches the nostril and the moustache's
    corner, so on a bearded style ``cheeks_rougher`` also measures the beard, which the
    transfer must not copy (issue 22)."""
    _, do = skin_detail(output, points_output, per_patch=True)
    _, dc = skin_detail(content, points_content, per_patch=True)
    _, ds = skin_detail(style, points_style, per_patch=True)
    res = {}
    for k in SKIN_PATCHES:
        gap = ds[k] - dc[k]
        res[k] = (do[k] - dc[k]) / gap if abs(gap) >= 0.1 else float("nan")
    vals = [res[k] for k in SKIN_PATCHES if np.isfinite(res[k])]
    res["mean"] = float(np.mean(vals)) if vals else float("nan")
    res["cheeks_rougher"] = _rougher_cheeks(do, dc, ds)
    if skins is not None:
        _, do_s = skin_detail(output, points_content, per_patch=True, mask=skins[0])
        _, dc_s = skin_detail(content, points_content, per_patch=True, mask=skins[0])
        _, ds_s = skin_detail(style, points_style, per_patch=True, mask=skins[1])
        res["cheeks_rougher_skin"] = _rougher_cheeks(do_s, dc_s, ds_s)
    return res


def _rougher_cheeks(do, dc, ds) -> float:
    """Mean fraction moved over the cheeks where the style is rougher by > 0.1 (NaN: none)."""
    rough = [(do[k] - dc[k]) / (ds[k] - dc[k]) for k in ("left_cheek", "right_cheek")
             if np.isfinite(ds[k]) and np.isfinite(dc[k]) and np.isfinite(do[k]) and ds[k] > dc[k] + 0.1]
    return float(np.mean(rough)) if rough else float("nan")
