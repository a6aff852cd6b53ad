"""Quadric decimation: fewer triangles, an honest error in world units, bad input refused."""

import numpy as np
import pytest

from service.base.errors import HoloError
from service.primitives import sphere
from service.simplify.distance import points_to_mesh, surface_distance
from service.simplify.errors import SimplifyError
from service.simplify.quadric import decimate


def _grid(n: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """A flat n x n square of 2 n^2 triangles in z = 0."""
    xs, ys = np.meshgrid(np.linspace(0, 1, n + 1), np.linspace(0, 1, n + 1), indexing="ij")
    v = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3),
                        np.stack([a, c, d], -1).reshape(-1, 3)])
    return v, f


def _sphere() -> tuple[np.ndarray, np.ndarray]:
    m = sphere(0.5, 24, 48)
    return m.vertices, m.triangles


def test_decimate_reaches_the_target_and_reports_world_error():
    v, f = _sphere()
    vs, fs, err = decimate(v, f, 0.1)
    assert fs.shape[0] <= 0.15 * f.shape[0]
    assert 0.0 < err < 0.05  # a 0.5-radius sphere, 10 % of its triangles
    # the error bounds every original vertex's distance to the simplified surface
    assert points_to_mesh(v, vs, fs).max() <= err + 1e-12


def test_error_grows_as_triangles_go():
    v, f = _sphere()
    errs = [decimate(v, f, fr)[2] for fr in (0.5, 0.2, 0.05)]
    assert errs[0] < errs[1] < errs[2]


def test_flat_mesh_stays_flat_and_the_error_sees_its_border_shrink():
    v, f = _grid()
    vs, fs, err = decimate(v, f, 0.1)
    assert fs.shape[0] < f.shape[0] // 4
    assert np.abs(vs[:, 2]).max() < 1e-12  # no vertex leaves the plane...
    # ...but an open border is collapsed too (quadrics have no border term); the
    # measured error is the distance the border moved, not zero
    moved = points_to_mesh(v, vs, fs).max()
    assert moved > 0.01 and err >= moved - 1e-12


def test_fraction_one_is_the_mesh_itself():
    v, f = _sphere()
    vs, fs, err = decimate(v, f, 1.0)
    assert err == 0.0 and np.array_equal(fs, f) and np.array_equal(vs, v)


def test_distance_matches_brute_force():
    rng = np.random.default_rng(3)
    v, f = _sphere()
    pts = rng.normal(size=(200, 3)) * 0.4
    corners = v[f]
    # brute force: closest point by dense barycentric sampling bounds it from above
    got = points_to_mesh(pts, v, f)
    s = np.linspace(0, 1, 9)
    uu, ww = np.meshgrid(s, s)
    keep = (uu + ww) <= 1
    bary = np.stack([1 - uu[keep] - ww[keep], uu[keep], ww[keep]], 1)  # (B, 3)
    samples = np.einsum("bk,tkd->tbd", bary, corners).reshape(-1, 3)
    upper = np.sqrt(((pts[:, None, :] - samples[None]) ** 2).sum(-1)).min(1)
    assert np.all(got <= upper + 1e-12)
    assert np.all(upper - got < 0.02)  # sampling step on these small triangles


def test_symmetric_distance_of_a_mesh_to_itself_is_zero():
    v, f = _sphere()
    assert surface_distance(v, f, v, f).max < 1e-12


@pytest.mark.parametrize("frac", [0.0, -0.5, 1.5, float("nan")])
def test_bad_fraction_is_refused(frac):
    v, f = _sphere()
    with pytest.raises(SimplifyError, match="fraction"):
        decimate(v, f, frac)


def test_mesh_with_no_faces_is_refused():
    with pytest.raises(SimplifyError, match="no triangles"):
        decimate(np.zeros((3, 3)), np.zeros((0, 3), dtype=np.int64), 0.5)
    assert issubclass(SimplifyError, HoloError)


def test_bad_index_is_refused():
    with pytest.raises(SimplifyError, match="out of range"):
        decimate(np.zeros((3, 3)), np.array([[0, 1, 3]]), 0.5)
