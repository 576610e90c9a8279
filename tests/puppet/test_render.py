"""Z-buffered textured mesh rendering."""

import cv2
import numpy as np
import pytest

from facetex.errors import BadInputError
from facetex.geometry._generic_face import canonical_frame, canonical_surface, load_generic_face
from facetex.geometry.frontalize import rotation_from_angles
from facetex.puppet.render import rasterize, render_layers, render_mesh, vertex_normals

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


# ----------------------------------------------------------------------------- render_layers
def _pixel_triangle(tri):
    """Vertices whose render_layers projection (rotation I, translation 0) is ``tri`` in pixels."""
    t = np.asarray(tri, float)
    return np.c_[t, np.zeros(len(t))]


def test_layers_coverage_is_antialiased_and_sums_to_the_area():
    tri = np.array([[6.3, 4.1], [55.7, 12.2], [17.2, 42.9]])
    e1, e2 = tri[1] - tri[0], tri[2] - tri[0]
    area = 0.5 * abs(e1[0] * e2[1] - e1[1] * e2[0])
    tex = _solid([0.2, 0.4, 0.8])
    kw = dict(rotation=np.eye(3), translation=(0, 0, 0), size=(W, H), normals=False, prefilter=False)
    hard = render_layers(_pixel_triangle(tri), [[0, 1, 2]], np.full((3, 2), 0.5), tex, supersample=1, **kw)
    soft = render_layers(_pixel_triangle(tri), [[0, 1, 2]], np.full((3, 2), 0.5), tex, supersample=4, **kw)
    assert set(np.unique(hard.coverage)) <= {0.0, 1.0}
    edge = (soft.coverage > 0) & (soft.coverage < 1)
    assert edge.sum() > 40  # fractional coverage along all three edges instead of stair steps
    assert soft.coverage.sum() == pytest.approx(area, rel=0.02)
    # straight colours where covered, even on the edge pixels
    np.testing.assert_allclose(soft.image[soft.coverage > 0.05], [[0.2, 0.4, 0.8]] * int((soft.coverage > 0.05).sum()),
                               atol=1e-5)
    y0, y1, x0, x1 = soft.box
    assert soft.coverage[:y0].sum() == soft.coverage[y1:].sum() == 0 and x0 <= 6 and x1 >= 56


def test_layers_normals_of_a_tilted_plane():
    corners = np.array([[-0.5, -0.5], [W - 0.5, -0.5], [W - 0.5, H - 0.5], [-0.5, H - 0.5]])
    v = _pixel_triangle(corners)
    v[:, 2] = 0.5 * v[:, 0]  # z grows to the right: the plane faces left-ish, towards the camera
    faces = [[0, 3, 1], [1, 3, 2]]
    lay = render_layers(v, faces, np.zeros((4, 2)), _solid([1, 1, 1]), rotation=np.eye(3), translation=(0, 0, 0),
                        size=(W, H), supersample=2)
    n = lay.normals[10:-10, 10:-10].reshape(-1, 3)
    want = np.array([0.5, 0.0, -1.0]) / np.sqrt(1.25)
    if n[0] @ want < 0:  # the sign follows the faces' winding
        want = -want
    np.testing.assert_allclose(n, np.broadcast_to(want, n.shape), atol=1e-5)
    np.testing.assert_allclose(vertex_normals(v, faces), np.broadcast_to(want, (4, 3)), atol=1e-9)


def test_layers_prefilter_removes_aliasing_of_a_minified_texture():
    # a 1-texel checkerboard shown 4x smaller aliases into a coarse pattern unless low-passed first
    tex = np.indices((128, 128)).sum(axis=0) % 2
    tex = np.repeat(tex[..., None], 3, axis=2).astype(np.float32)
    corners = np.array([[0, 0], [29.3, 0], [29.3, 29.3], [0, 29.3]], float)
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    kw = dict(rotation=np.eye(3), translation=(8, 8, 0), size=(48, 48), supersample=1, normals=False)
    sharp = render_layers(_pixel_triangle(corners), [[0, 3, 1], [1, 3, 2]], uv, tex, prefilter=False, **kw)
    smooth = render_layers(_pixel_triangle(corners), [[0, 3, 1], [1, 3, 2]], uv, tex, prefilter=True, **kw)
    inner = (slice(12, 34), slice(12, 34))
    assert smooth.image[inner].std() < 0.05 < sharp.image[inner].std()
    assert smooth.image[inner].mean() == pytest.approx(0.5, abs=0.03)


def test_rasterize_fast_paths_match_general_path(monkeypatch):
    """Dropped faces (non-finite or behind-camera corners, degenerate, off-screen) leave the
    other faces' raster unchanged, and a run split into many chunks equals the one-chunk run."""
    import facetex.puppet.render as render_mod

    g = load_generic_face()
    size = (96, 120)
    fr = canonical_frame(size)
    kw = dict(rotation=rotation_from_angles(yaw=20), translation=((fr.cx - 47.5) / fr.scale, (fr.cy - 59.5) / fr.scale,
              1000.0), focal=1000 * fr.scale, size=size)
    v, f = np.asarray(g.vertices, float), np.asarray(g.triangles)
    for weak in (True, False):
        ref = rasterize(v, f, weak_perspective=weak, **kw)
        assert ref.mask.sum() > 2000
        # extra vertices: NaN, inf, behind the camera, far off-screen; faces using them, and a degenerate face
        extra = np.array([[np.nan, 0, 0], [np.inf, 0, 0], [0, 0, -5000.0], [1e4, 1e4, 0], [1e4 + 1, 1e4, 0],
                          [1e4, 1e4 + 1, 0]])
        n = len(v)
        f2 = np.vstack([f, [[0, 1, n], [n + 1, 2, 3], [4, n + 2, 5], [n + 3, n + 4, n + 5], [8, 8, 9], [10, 11, 10]]])
        ras = rasterize(np.vstack([v, extra]), f2, weak_perspective=weak, **kw)
        np.testing.assert_array_equal(ras.triangle, ref.triangle)
        np.testing.assert_array_equal(ras.bary, ref.bary)
        np.testing.assert_array_equal(ras.depth, ref.depth)
        monkeypatch.setattr(render_mod, "_CHUNK", 97)  # many chunks, some faces straddling two
        ras = rasterize(np.vstack([v, extra]), f2, weak_perspective=weak, **kw)
        monkeypatch.undo()
        np.testing.assert_array_equal(ras.triangle, ref.triangle)
        np.testing.assert_array_equal(ras.bary, ref.bary)
        np.testing.assert_array_equal(ras.depth, ref.depth)
