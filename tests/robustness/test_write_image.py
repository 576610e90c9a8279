"""``write_image`` refuses pixels it would turn into garbage (issue 23): NaN, 0..255 floats."""

from __future__ import annotations

import numpy as np
import pytest

from _robust import snapshot


@pytest.mark.parametrize("image, cause", [
    (np.full((16, 16, 3), np.nan, np.float32), r"only NaN or infinite values"),
    (np.where(np.eye(16, dtype=bool)[..., None], np.nan, 0.5).repeat(3, 2), r"NaN or infinite values"),
    (np.full((16, 16, 3), np.inf, np.float64), r"infinite"),
    (np.linspace(0, 255, 16 * 16 * 3, dtype=np.float32).reshape(16, 16, 3), r"values up to 255.*divide by 255"),
    (np.full((16, 16), 3000.0), r"values up to 3000, not in \[0, 1\]"),
    (np.full((16, 16, 3), -1.0, np.float32), r"negative values"),
])
@pytest.mark.parametrize("ext", [".png", ".jpg"])
def test_write_image_refuses(outdir, image, cause, ext):
    from facetex import BadImageError, write_image

    with pytest.raises(BadImageError, match=cause) as e:
        write_image(outdir / f"o{ext}", image)
    assert f"o{ext}" in str(e.value) and "\n" not in str(e.value)
    assert snapshot(outdir) == {}


@pytest.mark.parametrize("image", [
    np.full((16, 16, 3), 1.2, np.float32),  # a processing overshoot: clipped, as before
    np.full((16, 16, 3), -0.1, np.float64),
    np.full((16, 16, 3), 255, np.uint8),
    np.full((16, 16, 3), 65535, np.uint16),
])
def test_write_image_clips_small_overshoots(outdir, image):
    from facetex import read_image, write_image

    write_image(outdir / "o.png", image)
    assert read_image(outdir / "o.png").shape == (16, 16, 3)
