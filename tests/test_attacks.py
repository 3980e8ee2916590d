"""The attack suite on a small mesh: what must survive, and what must never be called authentic."""

from __future__ import annotations

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.verify import verify_mesh
from tools import attacks

from conftest import marked_sphere


@pytest.fixture(scope="module")
def marked():
    data, key, img = marked_sphere(11)
    ref = pmwm_codec.decode(data)
    return data, key, img, ref


LOSSLESS = {
    "reorder": attacks.reorder,
    "similarity": attacks.similarity,
    "float32": attacks.float32,
    "all three": attacks.chain(attacks.similarity, attacks.reorder, attacks.float32),
}


@pytest.mark.parametrize("name", sorted(LOSSLESS))
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_similarity_reorder_float32_keep_the_mark_bit_exactly(marked, name, seed):
    data, key, img, ref = marked
    V, F = LOSSLESS[name](ref.positions.copy(), ref.faces.copy(), np.random.default_rng(seed))
    r = verify_mesh((V, F), data, key)
    assert r.verdict == "authentic"
    assert r.bit_exact and np.array_equal(r.watermark, img)
    assert r.ber == 0.0 and r.carriers_read == r.carriers_total


@pytest.mark.parametrize("amplitude", [0.003, 0.005])
def test_heavy_noise_is_never_authentic(marked, amplitude):
    data, key, img, ref = marked
    for seed in range(3):
        V, F = attacks.noise(ref.positions, ref.faces, np.random.default_rng(seed), amplitude)
        r = verify_mesh((V, F), data, key)
        assert r.verdict in ("not-authentic", "inconclusive"), r.as_json()
        assert r.ber > 0.3


def test_no_attack_of_the_suite_gives_a_false_authentic(marked):
    """Whatever the attack does, ``authentic`` only ever comes with codes that really match."""
    data, key, img, ref = marked
    rows = attacks.run_attacks(data, key, simplification=False,
                               original=shapes.icosphere(3))
    by_name = {r["attack"]: r for r in rows}
    for r in rows:
        if r.get("verdict") == "authentic":
            assert r["ber"] is not None and r["ber"] < 0.05, r
            assert r["carriers_read"] >= 32, r
    for name in ("noise 0.30%", "noise 0.50%", "quantization 8 bits", "quantization 7 bits",
                 "smoothing 50 it. (lambda 0.03)", "Draco 11 bits", "unmarked input mesh (no mark)"):
        assert by_name[name]["verdict"] != "authentic", by_name[name]


def test_attack_functions_keep_shapes():
    m = shapes.icosphere(2)
    rng = np.random.default_rng(0)
    V, F = attacks.crop(m.positions, m.faces, rng, 0.3)
    assert 0.6 * len(m.positions) < len(V) < 0.75 * len(m.positions)
    assert F.max() < len(V) and F.min() >= 0
    Q, _ = attacks.quantize(m.positions, m.faces, rng, 3)
    assert len(np.unique(Q[:, 0])) <= 9
    S, _ = attacks.smooth(m.positions, m.faces, rng, 10)
    assert np.linalg.norm(S, axis=1).mean() < 1.0  # smoothing shrinks a sphere
    R = attacks.rodrigues([0, 0, 1], np.pi / 2)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("scheme", ["midpoint", "loop"])
def test_subdivision_splits_every_triangle_into_four_sharing_edge_points(scheme):
    mesh = shapes.icosphere(2)
    V, F = attacks.subdivide(mesh.positions, mesh.faces, None, scheme)
    edges = len(np.unique(np.sort(np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]],
                                                  mesh.faces[:, [2, 0]]]), 1), axis=0))
    assert F.shape == (4 * len(mesh.faces), 3) and len(V) == len(mesh.positions) + edges
    assert len(np.unique(np.sort(F, 1), axis=0)) == len(F)  # no face twice
    assert np.all(np.diff(np.sort(F, 1), axis=1) > 0)  # no degenerate face


def test_midpoint_subdivision_keeps_the_old_points_and_puts_the_new_ones_on_the_edges():
    mesh = shapes.icosphere(2)
    V, F = attacks.subdivide(mesh.positions, mesh.faces, None, "midpoint")
    n = len(mesh.positions)
    assert np.array_equal(V[:n], mesh.positions)
    corner, new = F[: len(mesh.faces), 0], F[: len(mesh.faces), 1]  # face (a, ab, ca): ab is a's edge to b
    assert np.allclose(V[new], 0.5 * (mesh.positions[corner] + mesh.positions[mesh.faces[:, 1]]))


def test_loop_subdivision_is_affine_invariant_and_moves_a_sphere_inward():
    """Loop's weights sum to one (a translated mesh subdivides to the translated result), and on a
    convex closed mesh every rule averages points of the hull: nothing moves outside the sphere."""
    mesh = shapes.icosphere(2)
    shift = np.array([3.0, -1.0, 2.0])
    V, F = attacks.subdivide(mesh.positions, mesh.faces, None, "loop")
    V2, F2 = attacks.subdivide(mesh.positions + shift, mesh.faces, None, "loop")
    assert np.array_equal(F, F2) and np.allclose(V2, V + shift)
    r = np.linalg.norm(V, axis=1)
    assert r.max() <= 1.0 + 1e-12 and r.min() < 0.99  # smoothed inward, not a midpoint copy


def test_loop_subdivision_keeps_a_flat_open_grid_flat_and_a_straight_boundary_straight():
    xs, ys = np.meshgrid(np.arange(6.0), np.arange(6.0), indexing="ij")
    P = np.stack([xs.ravel(), ys.ravel(), np.zeros(36)], 1)  # point (i, j) at index 6 i + j
    idx = np.arange(36).reshape(6, 6)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    V, F = attacks.subdivide(P, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)]), None, "loop")
    assert np.allclose(V[:, 2], 0.0)
    side = idx[1:-1, 0]  # the side j = 0 without its corners: boundary points with two boundary neighbours
    assert np.allclose(V[side], P[side])  # 3/4 v + 1/8 (v - e) + 1/8 (v + e) on a straight boundary
    interior = idx[1:-1, 1:-1].ravel()
    assert np.allclose(V[interior], P[interior])  # a regular flat interior point is a fixed point of Loop's rule
