"""Watermark similarity and mesh distortion measures."""

import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pmwm_codec.errors import MeshError
from pmwm_codec.mesh import Mesh
from pmwm_codec import distortion
from pmwm_codec.watermark import metrics

SHARED = Path(__file__).resolve().parents[2] / "shared"


def grid(n=20, size=1.0):
    """A flat n x n vertex grid in the z = 0 plane, triangulated."""
    y, x = np.mgrid[0:n, 0:n] * (size / (n - 1))
    pos = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    i = np.arange(n - 1)[:, None] * n + np.arange(n - 1)[None, :]
    i = i.ravel()
    faces = np.concatenate([np.stack([i, i + 1, i + n + 1], 1), np.stack([i, i + n + 1, i + n], 1)])
    return Mesh(pos, faces)


# --- watermark measures -----------------------------------------------------------------


def test_psnr_of_known_mse():
    a = np.zeros((4, 4))
    b = a + 5.0  # MSE 25
    assert metrics.psnr(a, b) == pytest.approx(10 * math.log10(255**2 / 25))
    assert metrics.psnr(a, a) == math.inf
    assert metrics.psnr(a, b, peak=1.0) == pytest.approx(10 * math.log10(1 / 25))


def test_nc_hand_values():
    w = np.array([1.0, 2.0, 3.0])
    assert metrics.nc(w, w) == 1.0
    assert metrics.nc(w, [1, 0, 0]) == pytest.approx(1 / 14)
    assert metrics.nc(w, 2 * w) == pytest.approx(2.0)
    assert metrics.nc([0, 0], [0, 0]) == 1.0 and metrics.nc([0, 0], [1, 0]) == 0.0


def test_centered_nc_hand_values():
    w = np.array([1.0, 2.0, 3.0])
    assert metrics.centered_nc(w, w) == pytest.approx(1.0)
    assert metrics.centered_nc(w, -w) == pytest.approx(-1.0)
    assert metrics.centered_nc(w, 10 * w + 7) == pytest.approx(1.0)
    assert metrics.centered_nc(w, [1, 3, 2]) == pytest.approx(0.5)
    assert metrics.centered_nc(w, [5, 5, 5]) == 0.0
    # two unrelated positive images: raw NC is high, centred NC is not
    rng = np.random.default_rng(0)
    a, b = rng.integers(100, 200, 1000), rng.integers(100, 200, 1000)
    assert metrics.nc(a, b) > 0.95 and abs(metrics.centered_nc(a, b)) < 0.1


def test_ber():
    assert metrics.ber([0, 1, 1, 0], [0, 1, 0, 1]) == 0.5
    assert metrics.ber([], []) == 0.0
    with pytest.raises(ValueError):
        metrics.ber([0, 1], [0])


def test_shape_mismatch():
    with pytest.raises(ValueError):
        metrics.psnr(np.zeros(3), np.zeros(4))


# --- point-triangle distance ------------------------------------------------------------


def brute_distance(p, tri, n=300):
    """Minimum over a dense barycentric grid (an upper bound within tri_size / n)."""
    u, v = np.mgrid[0 : n + 1, 0 : n + 1] / n
    keep = u + v <= 1
    u, v = u[keep], v[keep]
    pts = tri[0] + u[:, None] * (tri[1] - tri[0]) + v[:, None] * (tri[2] - tri[0])
    return np.linalg.norm(pts - p, axis=1).min()


coords = st.floats(-10, 10, allow_nan=False, width=32)


@settings(max_examples=80, deadline=None)
@given(hnp.arrays(np.float64, (4, 3), elements=coords))
def test_point_triangle_distance_matches_brute_force(a):
    p, tri = a[0], a[1:]
    d = distortion.point_triangle_distance(p, tri)
    size = np.ptp(tri, axis=0).max()
    ref = brute_distance(p, tri)
    assert d <= ref + 1e-9 * (1 + size)
    assert ref <= d + 2 * size / 300 + 1e-9


def test_point_triangle_distance_regions_and_degenerate():
    tri = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    pts = np.array([[0.2, 0.2, 3], [-1, -1, 0], [0.5, -2, 0], [2, 2, 0], [0.5, 0.5, 0]])
    want = [3, math.sqrt(2), 2, math.sqrt(4.5), 0]
    assert np.allclose(distortion.point_triangle_distance(pts, tri), want)
    segment = np.array([[0.0, 0, 0], [2, 0, 0], [1, 0, 0]])  # zero area
    assert distortion.point_triangle_distance([1, 1, 0], segment) == pytest.approx(1)
    point = np.zeros((3, 3))
    assert distortion.point_triangle_distance([0, 3, 4], point) == pytest.approx(5)


@pytest.mark.parametrize("k", [1, 2, 8])
def test_surface_distance_equals_brute_force_minimum(k):
    """Random soup of very unequal triangles: several size groups, widening searches."""
    rng = np.random.default_rng(3)
    pos = rng.normal(size=(300, 3)) * rng.choice([0.05, 1.0, 3.0], size=(300, 1))
    faces = rng.integers(0, 300, (700, 3))
    s = np.sort(faces, axis=1)
    faces = faces[(s[:, 0] != s[:, 1]) & (s[:, 1] != s[:, 2])]
    pts = rng.normal(scale=1.5, size=(400, 3))
    got = distortion.surface_distance(pts, pos, faces, k=k, block=128)
    brute = distortion.point_triangle_distance(pts[:, None, :], pos[faces][None]).min(axis=1)
    assert np.allclose(got, brute, rtol=0, atol=1e-12)


# --- mesh distortion --------------------------------------------------------------------


def test_identical_meshes():
    m = grid(10)
    r = distortion.mesh_distortion(m, Mesh(m.positions.copy(), m.faces.copy()))
    assert r == {"rms": 0.0, "psnr_db": math.inf, "hausdorff": 0.0,
                 "bbox_diagonal": pytest.approx(math.sqrt(2))}


def test_grid_shifted_along_its_normal():
    m = grid(20)
    d = 0.01
    shifted = Mesh(m.positions + [0, 0, d], m.faces)
    r = distortion.mesh_distortion(m, shifted, samples=5000)
    diag = math.sqrt(2)
    assert r["bbox_diagonal"] == pytest.approx(diag)
    assert r["rms"] == pytest.approx(d)
    assert r["psnr_db"] == pytest.approx(20 * math.log10(diag / d))
    assert r["hausdorff"] == pytest.approx(d / diag)


def test_hausdorff_sees_surfaces_not_vertices():
    """Moving vertices *within* the plane changes RMS but not the surface distance."""
    m = grid(11)
    pos = m.positions.copy()
    inner = (pos[:, 0] > 0) & (pos[:, 0] < 1) & (pos[:, 1] > 0) & (pos[:, 1] < 1)
    pos[inner, 0] += 0.02
    r = distortion.mesh_distortion(m, Mesh(pos, m.faces), samples=2000)
    assert r["rms"] > 0.01 and r["hausdorff"] < 1e-12


def test_one_vertex_bump():
    m = grid(11)
    pos = m.positions.copy()
    centre = 5 * 11 + 5
    pos[centre, 2] = 0.05
    r = distortion.mesh_distortion(m, Mesh(pos, m.faces), samples=2000)
    assert r["hausdorff"] == pytest.approx(0.05 / math.sqrt(2))  # the vertex is always sampled
    assert r["rms"] == pytest.approx(0.05 / math.sqrt(121))


def test_vertex_count_mismatch_is_a_mesh_error():
    with pytest.raises(MeshError, match="vertices"):
        distortion.mesh_distortion(grid(5), grid(6))


def test_hausdorff_without_correspondence():
    h = distortion.hausdorff_distance(grid(5), Mesh(grid(9).positions + [0, 0, 0.1], grid(9).faces),
                                   samples=1000)
    assert h == pytest.approx(0.1)


@pytest.mark.corpus
def test_bunny_with_tiny_noise_has_a_tiny_distortion():
    path = SHARED / "corpus" / "stanford-bunny.obj"
    if not path.exists():
        pytest.skip("shared corpus absent")
    from pmwm_codec.mesh import read_mesh

    m = read_mesh(path)
    rng = np.random.default_rng(0)
    noisy = Mesh(m.positions + rng.normal(scale=1e-4 * m.bbox_diagonal(), size=m.positions.shape), m.faces)
    r = distortion.mesh_distortion(m, noisy)
    assert 0 < r["hausdorff"] < 0.01 and r["psnr_db"] > 60


def _square(x1: float, z: float = 0.0):
    """Rectangle [0, x1] x [0, 1] at height z, two triangles."""
    from pmwm_codec.mesh import Mesh

    v = np.array([[0, 0, z], [x1, 0, z], [x1, 1, z], [0, 1, z]], dtype=np.float64)
    return Mesh(v, np.array([[0, 1, 2], [0, 2, 3]]))


def test_rms_surface_distance_of_a_parallel_copy_is_its_offset():
    assert distortion.rms_surface_distance(_square(1), _square(1, 0.25), samples=2000) == pytest.approx(0.25)
    assert distortion.rms_surface_distance(_square(1), _square(1), samples=2000) == 0.0


def test_rms_surface_distance_counts_both_directions_equally():
    # [0,1]^2 lies inside [0,2]x[0,1]: 0 one way; the other way half the points sit at x-1,
    # uniform on [0, 1]: mean square 1/6, so the symmetric RMS is sqrt((0 + 1/6) / 2).
    small, wide = _square(1), _square(2)
    d = distortion.rms_surface_distance(small, wide, samples=40_000, seed=3)
    assert d == pytest.approx(math.sqrt(1 / 12), rel=0.02)
    assert distortion.rms_surface_distance(small, wide, samples=40_000, seed=3) == d  # seeded
    assert distortion.rms_surface_distance(wide, small, samples=40_000) == pytest.approx(d, rel=0.02)
