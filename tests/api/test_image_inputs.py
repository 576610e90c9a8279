"""Every public function that takes an image takes the same things (issue 24): a path, a PIL
image, a uint8, uint16 or float [0, 1] array, and refuses a 0..255 float array with the same
one-line hint; a mixed uint8 / float call gives the float call's numbers."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

import facetex
from facetex._resources import sample_path

FACE, OTHER = sample_path("frl_004_neutral.jpg"), sample_path("frl_005_neutral.jpg")
FLOAT = {p: facetex.read_image(p) for p in (FACE, OTHER)}

FORMS = {
    "path": lambda p: p,
    "pathlib": lambda p: __import__("pathlib").Path(p),
    "PIL": lambda p: Image.open(p),
    "uint8": lambda p: (FLOAT[p] * 255).round().astype(np.uint8),
    "uint16": lambda p: (FLOAT[p] * 65535).round().astype(np.uint16),
    "float": lambda p: FLOAT[p],
}

# name -> (call with two images a, b; a number or array to compare across the forms)
CALLS = {
    "detect_face": lambda a, b: facetex.detect_face(a).points68,
    "detect_faces": lambda a, b: facetex.detect_faces(a)[0].points68,
    "face_mesh468": lambda a, b: facetex.face_mesh468(a),
    "landmark_error": lambda a, b: facetex.landmark_error(a, b).mse_px2,
    "texture_similarity": lambda a, b: facetex.texture_similarity(a, b),
    "identity_distance": lambda a, b: facetex.identity_distance(a, b),
    "as_image": lambda a, b: facetex.as_image(a),
    # the transfer and its metrics: a small, short run (the numbers of every form must agree)
    "transfer": lambda a, b: facetex.transfer(a, b, size=96, iters="2,2", seed=0),
    "transfer_metrics": lambda a, b: [facetex.transfer_metrics(a, a, b)[k] for k in
                                      ("protected_change", "background_change", "identity_content")],
}


@pytest.fixture(scope="module")
def reference():
    return {name: call(FLOAT[FACE], FLOAT[OTHER]) for name, call in CALLS.items()}


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("name", CALLS)
def test_every_image_function_takes_every_image_form(name, form, reference):
    got = CALLS[name](FORMS[form](FACE), FORMS[form](OTHER))
    # uint16 rounds differently from uint8 at the 8-bit JPEG's levels: a hair's difference
    np.testing.assert_allclose(np.asarray(got, np.float64), np.asarray(reference[name], np.float64),
                               rtol=1e-5, atol=0.02 if form == "uint16" else 1e-6)


@pytest.mark.parametrize("name", CALLS)
def test_every_image_function_refuses_0_255_floats_with_the_same_hint(name):
    with pytest.raises(facetex.BadImageError, match="divide by 255") as e:
        CALLS[name](FLOAT[FACE] * 255, FLOAT[OTHER])
    assert "\n" not in str(e.value)


def test_a_missing_file_is_named():
    with pytest.raises(facetex.BadImageError, match="nope.png"):
        facetex.identity_distance("nope.png", FACE)


def test_transfer_metrics_mixed_uint8_and_float_give_the_float_numbers():
    """The reported case: output float, content and style uint8 gave protected_change 104.6 and
    background_change 198.6 (0..255 compared with 0..1) where all-float inputs give 0.0."""
    c, s = FLOAT[FACE], FLOAT[OTHER]
    u8 = lambda x: (x * 255).round().astype(np.uint8)  # noqa: E731
    pts = [facetex.detect_face(c).points68, facetex.detect_face(c).points68, facetex.detect_face(s).points68]
    ref = facetex.transfer_metrics(c, c, s, points=pts)
    mixed = facetex.transfer_metrics(c, u8(c), u8(s), points=pts)
    assert ref["protected_change"] == 0.0 and ref["background_change"] == 0.0
    for k in ("protected_change", "background_change", "S_style", "identity_content", "lowfreq_dE"):
        assert mixed[k] == pytest.approx(ref[k], abs=1e-4), k
