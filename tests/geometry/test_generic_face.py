"""The generic face on canonical frames: the piecewise-planar depth interpolation."""

from __future__ import annotations

import numpy as np
import pytest

from facetex.geometry._generic_face import (
    canonical_depth_from_mesh,
    canonical_frame,
    load_generic_face,
    planar_interpolation,
)


def test_planar_interpolation_of_a_plane_is_exact_inside_the_square():
    # two triangles over the square [1, 4] x [1, 3] carrying z = 2x + 3y + 1
    xy = np.array([[1.0, 1.0], [4.0, 1.0], [4.0, 3.0], [1.0, 3.0]])
    z = 2 * xy[:, 0] + 3 * xy[:, 1] + 1
    vals, mask = planar_interpolation(xy, z, [[0, 1, 2], [0, 2, 3]], (6, 5))
    expect = np.zeros((5, 6), bool)
    expect[1:4, 1:5] = True  # pixel centres on the edges count as inside
    np.testing.assert_array_equal(mask, expect)
    yy, xx = np.mgrid[0:5, 0:6]
    np.testing.assert_allclose(vals[mask], (2 * xx + 3 * yy + 1)[mask], atol=1e-12)
    assert np.isnan(vals[~mask]).all()


def test_planar_interpolation_follows_each_triangles_own_plane():
    # a tent: the ridge vertex is raised, so the two triangles' planes differ
    xy = np.array([[0.0, 0.0], [4.0, 0.0], [2.0, 4.0], [2.0, -4.0]])
    z = np.array([0.0, 0.0, 8.0, 4.0])
    vals, mask = planar_interpolation(xy, z, [[0, 1, 2], [0, 3, 1]], (5, 5))
    assert vals[2, 2] == pytest.approx(4.0)  # (2, 2) is half way up to the apex of the upper triangle
    assert vals[0, 2] == pytest.approx(0.0) and mask[0, 2]
    assert not mask[4, 0] and not mask[3, 3]


def test_generic_depth_matches_matplotlib_triinterpolation():
    tri = pytest.importorskip("matplotlib.tri")
    g = load_generic_face()
    frame = canonical_frame((192, 240))
    z, mask = canonical_depth_from_mesh(g.vertices, g.triangles, frame)
    uv = frame.project(np.asarray(g.vertices, np.float64))
    interp = tri.LinearTriInterpolator(tri.Triangulation(uv[:, 0], uv[:, 1], np.asarray(g.triangles)),
                                       np.asarray(g.vertices, np.float64)[:, 2])
    uu, vv = np.meshgrid(np.arange(192.0), np.arange(240.0))
    ref = interp(uu, vv)
    np.testing.assert_array_equal(mask, ~np.ma.getmaskarray(ref))
    np.testing.assert_allclose(z[mask], np.ma.filled(ref, np.nan)[mask], rtol=0, atol=1e-9)
