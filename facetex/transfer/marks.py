"""Marks: the content's moles, spots and scars kept, or replaced by the style's (issue 22).

Without this step the texture transfer erases the content's marks (they are not in the
style's skin patches, and the detail stage swaps the fine bands) and brings the style's,
which ages or de-ages the person and removes identifying marks. Marks are found on both
faces with :func:`facetex.geometry.marks.detect_marks` (dark blobs, LoG), in the frame of
the content region (the style pre-warped onto it), and at every mark's disc
(:func:`facetex.geometry.marks.marks_mask`) the output's detail finer than ``σ_m`` is
replaced by the wanted face's::

    x_t ← x_t + w ⊙ (H(x_want) − H(x_t)),   H(x) = x − G_σm * x

``mode="content"``: at the content's marks and at the style's (which the content lacks
there) the detail is the content's — its marks are back and the style's are gone;
``mode="style"``: the detail there is the pre-warped style's — the style's marks arrive
and the content's go. The coarser part of the output (its colour and shading) is left to
the shading step. Pure numpy / OpenCV.
"""

from __future__ import annotations

import numpy as np

from ..errors import BadInputError
from ..geometry.filters import gaussian
from ..geometry.marks import REF_FACE_WIDTH, MarkParams, detect_marks, marks_mask

__all__ = ["MARK_MODES", "MARK_DETAIL_SIGMA", "transfer_marks"]

MARK_MODES = ("content", "style")
#: σ (px at a 330 px face width) below which a mark's detail is swapped: twice the largest
#: mark's σ (5 px), so nearly all of a mark is swapped; the face's shading stays the shading step's
MARK_DETAIL_SIGMA = 10.0


def transfer_marks(output, content, aligned_style, content_skin, style_skin, *, mode: str = "content",
                   face_width: float = REF_FACE_WIDTH, params: MarkParams = MarkParams(),
                   return_info: bool = False):
    """The output with the content's (``mode="content"``) or the style's (``"style"``) marks
    (module doc). All images (H, W, 3) in [0, 1] in the content region's frame; skins (H, W)
    in [0, 1] (the style's warped into this frame); ``face_width`` of the content face there.
    Returns the new image (and with ``return_info`` the marks found: ``content``, ``style``
    as (N, 3) arrays of x, y, radius)."""
    if mode not in MARK_MODES:
        raise BadInputError(f"marks must be one of {', '.join(MARK_MODES)}, not {mode!r}")
    out = np.asarray(output, np.float32)
    con = np.asarray(content, np.float32)
    sty = np.asarray(aligned_style, np.float32)
    if not out.shape == con.shape == sty.shape or out.ndim != 3:
        raise BadInputError(f"output {out.shape}, content {con.shape} and style {sty.shape} must be the same "
                            "(H, W, 3) shape")
    mc = np.clip(np.asarray(content_skin, np.float32), 0, 1)
    ms = np.clip(np.asarray(style_skin, np.float32), 0, 1) * (mc > 0.05)  # only where the content is skin too
    marks_c = detect_marks(con, mc, face_width=face_width, params=params)
    marks_s = detect_marks(sty, ms, face_width=face_width, params=params)
    w = np.maximum(marks_mask(marks_c, out.shape), marks_mask(marks_s, out.shape)) * mc
    result = out
    if w.any():
        want = con if mode == "content" else sty
        sigma = MARK_DETAIL_SIGMA * face_width / REF_FACE_WIDTH
        detail = (want - gaussian(want, sigma)) - (out - gaussian(out, sigma))
        result = np.clip(out + w[..., None] * detail, 0.0, 1.0)
    if return_info:
        return result, {"content": marks_c, "style": marks_s}
    return result
