"""Z-buffered textured mesh rendering."""

import cv2
import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.geometry._generic_face import canonical_frame, canonical_surface, load_generic_face
from facetex.geometry.frontalize import rotation_from_angles
from facetex.persona.render import rasterize, render_mesh

W, H = 64, 48
CX, CY = (W - 1) / 2, (H - 1) / 2


def _flat(points_px, z=10.0):
    """Vertices whose weak-perspective projection (focal = t_z = z) is ``points_px``."""
    p = np.asarray(points_px, float)
    return np.column_stack([p[:, 0] - CX, p[:, 1] - CY, np.zeros(len(p))])


def _solid(colour):
    return np.broadcast_to(np.asarray(colour, np.float32), (4, 4, 3)).copy()


def test_single_triangle_pixels_and_colour():
    tri = np.array([[10.0, 5.0], [50.0, 12.0], [20.0, 40.0]])
    img, mask = render_mesh(_flat(tri), [[0, 1, 2]], np.full((3, 2), 0.5), _solid([0.2, 0.4, 0.8]),
                            translation=(0, 0, 10), focal=10, size=(W, H), weak_perspective=True,
                            background=(1.0, 1.0, 1.0))
    yy, xx = np.mgrid[0:H, 0:W]
    ref = np.ones((H, W), bool)
    for a, b in ((0, 1), (1, 2), (2, 0)):  # inside: left of each edge (triangle is clockwise in y-down)
        e = tri[b] - tri[a]
        ref &= (e[0] * (yy - tri[a, 1]) - e[1] * (xx - tri[a, 0])) >= 0
    np.testing.assert_array_equal(mask, ref)
    np.testing.assert_allclose(img[mask], [[0.2, 0.4, 0.8]] * int(mask.sum()), atol=1e-6)
    np.testing.assert_array_equal(img[~mask], 1.0)


def test_nearer_triangle_wins():
    a = _flat([[5, 5], [40, 5], [5, 40]])
    b = _flat([[20, 10], [60, 10], [20, 45]])
    a[:, 2], b[:, 2] = -1.0, 1.0  # a is nearer the camera
    v = np.vstack([a, b])
    uv = np.array([[0.25, 0.5]] * 3 + [[0.75, 0.5]] * 3)  # left half red, right half blue
    tex = np.zeros((4, 4, 3), np.float32)
    tex[:, :2, 0] = 1.0
    tex[:, 2:, 2] = 1.0
    kw = dict(translation=(0, 0, 100), focal=100, size=(W, H))
    img, _ = render_mesh(v, [[0, 1, 2], [3, 4, 5]], uv, tex, **kw)
    np.testing.assert_allclose(img[15, 22], [1, 0, 0], atol=1e-3)  # in both: a
    np.testing.assert_allclose(img[12, 50], [0, 0, 1], atol=1e-3)  # only b
    v[:3, 2] = 2.0  # now b is nearer
    img, _ = render_mesh(v, [[0, 1, 2], [3, 4, 5]], uv, tex, **kw)
    np.testing.assert_allclose(img[15, 22], [0, 0, 1], atol=1e-3)
    ras = rasterize(v, [[0, 1, 2], [3, 4, 5]], **kw)
    assert ras.triangle[15, 22] == 1 and ras.triangle[0, 63] == -1
    assert ras.depth[15, 22] == pytest.approx(101.0)


def test_textured_quad_maps_the_texture():
    tex = np.random.default_rng(0).random((H, W, 3)).astype(np.float32)
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    faces = [[0, 3, 1], [1, 3, 2]]
    img, mask = render_mesh(_flat(corners), faces, uv, tex, translation=(0, 0, 10), focal=10, size=(W, H),
                            weak_perspective=True)
    assert mask.all()
    np.testing.assert_allclose(img, tex, atol=2e-3)  # cv2.remap's 1/32 px sampling
    # perspective camera, quad tilted in depth: texture stays perspective-correct (no affine swim)
    v = _flat(corners)
    v[:, 2] = np.array([0, 0, 30, 30])  # the bottom edge is further away
    img, mask = render_mesh(v, faces, uv, tex, translation=(0, 0, 60), focal=60, size=(W, H))
    ras = rasterize(v, faces, translation=(0, 0, 60), focal=60, size=(W, H))
    y, x = 20, 31
    t = ras.triangle[y, x]
    model = ras.bary[y, x] @ v[np.array(faces)[t]]
    want = (model[:2] + [CX, CY] + 0.5) / [W, H]  # uv is affine in model x, y on this quad
    got = ras.bary[y, x] @ uv[np.array(faces)[t]]
    np.testing.assert_allclose(got, want, atol=1e-6)


def test_generic_face_renders_face_shaped_mask():
    size = (96, 120)
    g, fr = load_generic_face(), canonical_frame(size)
    t = ((fr.cx - (size[0] - 1) / 2) / fr.scale, (fr.cy - (size[1] - 1) / 2) / fr.scale, 1000.0)
    tex = np.ones((8, 8, 3), np.float32)
    _, mask = render_mesh(g.vertices, g.triangles, np.full((len(g.vertices), 2), 0.5), tex, translation=t,
                          focal=1000 * fr.scale, size=size, weak_perspective=True)
    ref = canonical_surface(size).on_mesh
    iou = (mask & ref).sum() / (mask | ref).sum()
    assert iou > 0.97
    # turned 30 degrees, the outline narrows and stays one blob
    _, turned = render_mesh(g.vertices, g.triangles, np.full((len(g.vertices), 2), 0.5), tex,
                            rotation=rotation_from_angles(yaw=30), translation=t, focal=1000 * fr.scale, size=size,
                            weak_perspective=True)
    assert 0.7 * mask.sum() < turned.sum() < mask.sum()
    assert cv2.connectedComponents(turned.astype(np.uint8))[0] == 2


def test_rejects_bad_input():
    with pytest.raises(BadInputError):
        render_mesh(np.zeros((3, 3)), [[0, 1, 5]], np.zeros((3, 2)), _solid([1, 1, 1]), focal=1, size=(8, 8),
                    translation=(0, 0, 1))
    with pytest.raises(BadInputError):
        render_mesh(np.zeros((3, 3)), [[0, 1, 2]], np.zeros((2, 2)), _solid([1, 1, 1]), focal=1, size=(8, 8))
