"""Every metric of one transfer output against its content and style."""

from __future__ import annotations

import numpy as np

from ..io import ImageLike, image_args
from ._detail import background_change, protected_change, skin_detail
from ._issue22 import (
    _content_skin,
    _rgb01,
    detail_moved,
    hair_leakage,
    lowfreq_skin_delta_e,
    mark_survival,
    skin_coverage,
    stubble_leakage,
)
from ._paper import _points68, identity_distance, landmark_error, texture_similarity


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
        from ..geometry.style_align import align_style_to_content

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
    from ..geometry.segment import skin_mask

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
