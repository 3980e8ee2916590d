"""The simplifier removes vertices that share a grid point with another (other than seam copies) first, so that
the base keeps none of them where a legal collapse can remove them: Draco's own vertex order stores such a base only
with the weld attribute (its copies are welded by grid point), and not at all with a face on two of them (Draco drops
it), where its sequential coder costs about three times the bytes."""

import io

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive import simplify as simplify_module
from pmwm_codec.progressive.seams import weld_groups
from pmwm_codec.progressive.simplify import coincident_vertices, simplify


def _grid_faces(k: int, flip: bool) -> np.ndarray:
    """(2 (k-1)^2, 3) int64 triangles of a k x k vertex grid, cut along one diagonal or the other."""
    i, j = np.meshgrid(np.arange(k - 1), np.arange(k - 1), indexing="ij")
    a, b, c, d = (i * k + j).ravel(), (i * k + j + 1).ravel(), ((i + 1) * k + j).ravel(), ((i + 1) * k + j + 1).ravel()
    if flip:
        return np.concatenate([np.c_[a, c, b], np.c_[b, c, d]])
    return np.concatenate([np.c_[a, c, d], np.c_[a, d, b]])


def _crossing_sheets(k: int = 24, seed: int = 0) -> tuple:
    """Two bumpy sheets over one k x k grid of (x, y) that touch at ~15 % of their vertices: ``(positions
    (2k^2, 3) int64, faces (m, 3) int64)``; the touching vertices share a point but no edge."""
    rng = np.random.default_rng(seed)
    x, y = np.meshgrid(np.arange(k), np.arange(k), indexing="ij")
    xy = np.stack([x.ravel(), y.ravel()], 1) * 64
    za, zb = rng.integers(0, 48, k * k), rng.integers(0, 48, k * k)
    touch = rng.random(k * k) < 0.15
    zb[touch] = za[touch]
    positions = np.concatenate([np.c_[xy, za], np.c_[xy, zb]]).astype(np.int64)
    faces = np.concatenate([_grid_faces(k, False), _grid_faces(k, True) + k * k])
    return positions, faces


def _base_alive(log, n: int) -> np.ndarray:
    alive = np.zeros(n, bool)
    alive[log.base_vertices] = True
    return alive


def _shared_in(positions: np.ndarray, alive: np.ndarray) -> list:
    return coincident_vertices(weld_groups(positions), alive).tolist()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_base_keeps_no_two_vertices_on_one_grid_point(seed, monkeypatch):
    positions, faces = _crossing_sheets(seed=seed)
    n = len(positions)
    assert len(_shared_in(positions, np.ones(n, bool))) > 0.1 * n
    log = simplify(positions, faces, target_vertices=n // 4)
    assert _shared_in(positions, _base_alive(log, n)) == []
    assert len(log.base_vertices) <= n // 4
    # each batch records the true cost of its collapses (the ones offered first ranked as costing nothing)
    for batch in log.batches[:2]:
        assert np.all(batch.cost > 0) and np.all(batch.error > 0)
    # without them offered first, the same mesh's base keeps some: the check above can fail
    monkeypatch.setattr(simplify_module, "coincident_vertices", lambda *args: np.zeros(0, np.int64))
    unpassed = simplify(positions, faces, target_vertices=n // 4)
    assert _shared_in(positions, _base_alive(unpassed, n)) != []


def test_shared_points_are_those_of_two_vertices_other_than_seam_copies():
    positions = np.array([[0, 0, 0], [0, 0, 0], [5, 0, 0], [0, 5, 0], [9, 9, 9], [9, 9, 9], [9, 9, 9]], np.int64)
    points = weld_groups(positions)
    alive = np.ones(7, bool)
    assert coincident_vertices(points, alive).tolist() == [0, 1, 4, 5, 6]
    weld = np.array([0, 0, 2, 3, 4, 4, 6])  # 0 and 1 are seam copies; 4 and 5 too, 6 is not theirs
    assert coincident_vertices(points, alive, weld).tolist() == [4, 5, 6]
    alive[6] = False
    assert coincident_vertices(points, alive, weld).tolist() == []
    assert coincident_vertices(points, alive, None, np.array([0, 1, 4, 5, 6])).tolist() == [0, 1, 4, 5]
    assert coincident_vertices(np.arange(7), np.ones(7, bool)).tolist() == []


def test_an_encoded_base_has_no_two_vertices_on_one_grid_point():
    # the sheets touch a thousandth of a unit apart: one point on the 12-bit grid (step ~0.36), not exact copies
    # of one another in the input (those would be seam copies, kept together at every level)
    positions, faces = _crossing_sheets(seed=3)
    floats = positions.astype(np.float64)
    k2 = len(positions) // 2
    touching = np.flatnonzero(positions[:k2, 2] == positions[k2:, 2]) + k2
    floats[touching, 2] += 1e-3
    mesh = Mesh(floats, faces)
    out = io.BytesIO()
    report = pmwm_codec.encode(mesh, out, grid_bits=12, base_vertices=len(positions) // 4)
    assert report["base_codec"] == "draco" and report["notices"] == []
    base = pmwm_codec.decode(out.getvalue(), chunks=0)
    assert len(base.positions) <= len(positions) // 4
    assert len(np.unique(base.positions, axis=0)) == len(base.positions)
    decoded = pmwm_codec.decode(out.getvalue())
    assert (decoded.vertex_count, decoded.face_count) == (mesh.vertex_count, mesh.face_count)
