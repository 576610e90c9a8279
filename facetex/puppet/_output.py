"""The output frame's size: a driver frame scaled to ``--size`` (even sides), and the largest
frame rendered and encoded within the memory budget."""

from __future__ import annotations

import math

from ..errors import BadInputError

__all__ = ["MAX_OUTPUT_SIDE", "MAX_FRAME_PIXELS", "MAX_FACE_PANEL_PIXELS", "output_size", "check_output_frame"]


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


#: most pixels of an output frame (both panels with ``side_by_side``): 6.6 MP (2560 x 2560,
#: 3408 x 1920). Larger frames are refused before any work: every command stays under 1.5 GB
#: (issue 23). Measured peaks (composite, 8-24 frames): 4096 x 4096 took 3.3 GB, side by side
#: (33.5 MP) 4.4 GB, its encoder alone over 1 GB with the fewest reference and look-ahead frames;
#: with frames streamed as below, 4096 x 2304 (9.4 MP) 1.44 GB, 3072 x 3072 (9.4 MP) 1.59 GB.
MAX_FRAME_PIXELS = 2560 * 2560
#: most pixels of a ``mode="face"`` panel: it is rasterized 2 x 2 supersampled (0.7 GB at 16.8 MP)
MAX_FACE_PANEL_PIXELS = 2560 * 1440


def check_output_frame(frame_size, size: int | None, *, side_by_side: bool = False, mode: str = "composite",
                       path=None) -> tuple[int, int, float]:
    """:func:`output_size` of a driver frame (W, H), and BadInputError (naming ``path``, the
    driver) when the output frame is larger than :data:`MAX_FRAME_PIXELS` (or a face-mode panel
    than :data:`MAX_FACE_PANEL_PIXELS`): one line saying the largest ``--size`` that fits."""
    W, H, scale = output_size(frame_size, size)
    panels = 2 if side_by_side else 1
    limit = min(MAX_FRAME_PIXELS // panels, MAX_FACE_PANEL_PIXELS if mode == "face" else MAX_FRAME_PIXELS)
    if W * H > limit:
        w, h = frame_size
        best = max(w, h) * math.sqrt(limit / (w * h))
        fit = max((v for v in range(32, int(best) + 3, 2) if (lambda o: o[0] * o[1])(output_size(frame_size, v)) <= limit),
                  default=None)
        what = f"{panels * W}x{H}" + (" (two panels)" if panels == 2 else "")
        bound = (f"{MAX_FRAME_PIXELS / 1e6:.1f} MP a frame (2560x2560, 3408x1920)"
                 + (f", {MAX_FACE_PANEL_PIXELS / 1e6:.1f} MP a face-mode panel" if mode == "face" else ""))
        raise BadInputError(f"--size {size} makes {what} output frames of {W * H * panels / 1e6:.1f} MP, over the "
                            f"{bound} that are rendered and encoded within the memory budget"
                            + (f": use --size {fit} or less" if fit else ""), path=path)
    return W, H, scale
