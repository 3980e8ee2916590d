"""Verifying a mesh that left the stream: vertex correspondence and verify_mesh."""

from __future__ import annotations

import io
import math

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.verify import verify_mesh
from pmwm_codec.watermark.verify import code_ber
from pmwm_codec.stream.encoder import encode_mesh
from pmwm_codec.watermark.key import WatermarkKey
from pmwm_codec.progressive.topology import canonical_faces, same_face_set
from pmwm_codec.verify.correspond import correspond, match_topology, umeyama


def _encode(mesh, size=16, seed=0):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (size, size)).astype(np.uint8)
    key = WatermarkKey.generate(rng=rng)
    buf = io.BytesIO()
    key = encode_mesh(mesh, buf, watermark=img, key=key).key  # the key of the file
    return buf.getvalue(), key, img


@pytest.fixture(scope="module")
def marked():
    data, key, img = _encode(shapes.icosphere(3, noise=0.02))
    ref = pmwm_codec.decode(data)
    return data, key, img, ref


def _rotation(rng, reflect=False):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    if (np.linalg.det(q) < 0) != reflect:
        q[:, 0] *= -1
    return q


def _reorder(V, F, rng):
    perm = rng.permutation(len(V))
    inv = np.argsort(perm)
    F2 = inv[F][rng.permutation(len(F))]
    k = rng.integers(0, 3, len(F2))
    return V[perm], np.take_along_axis(F2, (np.arange(3)[None] + k[:, None]) % 3, axis=1)


def test_canonical_faces_keep_orientation():
    f = np.array([[2, 0, 1], [3, 4, 5]])
    assert canonical_faces(f).tolist() == [[0, 1, 2], [3, 4, 5]]
    assert same_face_set(f, np.array([[4, 5, 3], [1, 2, 0]]))
    assert not same_face_set(f, np.array([[0, 2, 1], [3, 4, 5]]))  # flipped orientation


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(50, 3))
    R = _rotation(rng)
    s, R2, t = umeyama(X, 2.5 * X @ R.T + [1, -2, 3])
    assert math.isclose(s, 2.5, rel_tol=1e-12)
    np.testing.assert_allclose(R2, R, atol=1e-12)
    np.testing.assert_allclose(t, [1, -2, 3], atol=1e-12)


@pytest.mark.parametrize("reflect", [False, True])
def test_moved_reordered_float32_mesh_verifies_bit_exactly(marked, reflect):
    data, key, img, ref = marked
    rng = np.random.default_rng(7 + reflect)
    V, F = _reorder(ref.positions, ref.faces, rng)
    V = (3.7 * V @ _rotation(rng, reflect).T + [10.0, -4.0, 2.5]).astype(np.float32)
    r = verify_mesh((V.astype(np.float64), F), data, key)
    assert r.correspondence == "permutation"
    assert r.verdict == "authentic"
    assert r.bit_exact and np.array_equal(r.watermark, img)
    assert r.ber == 0.0 and r.psnr_db == math.inf and r.nc == 1.0
    assert r.carriers_read == r.carriers_total
    assert r.as_json()["psnr_db"] is None  # JSON has no infinity: the contract prints null


def test_saved_as_float32_obj_and_read_back(marked, tmp_path):
    data, key, img, ref = marked
    rng = np.random.default_rng(3)
    V, F = _reorder(ref.positions, ref.faces, rng)
    V = (0.01 * V @ _rotation(rng).T + 0.003).astype(np.float32)  # float32 far from the origin would not do: see BENCHMARKS.md
    path = tmp_path / "exported.obj"
    with open(path, "w") as fh:
        fh.writelines(f"v {x!r} {y!r} {z!r}\n" for x, y, z in V.tolist())
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F.tolist())
    (tmp_path / "ref.pmw").write_bytes(data)
    key.save(tmp_path / "k.json")
    r = verify_mesh(str(path), str(tmp_path / "ref.pmw"), str(tmp_path / "k.json"))
    assert r.verdict == "authentic" and r.bit_exact


def test_faces_reordered_only(marked):
    data, key, img, ref = marked
    rng = np.random.default_rng(4)
    F = np.roll(ref.faces[rng.permutation(len(ref.faces))], 1, axis=1)
    c = correspond(ref.positions, F, ref.positions, ref.faces)
    assert c.method == "faces-reordered"
    assert verify_mesh((ref.positions, F), data, key).bit_exact


def test_identity(marked):
    data, key, img, ref = marked
    r = verify_mesh(ref, data, key)
    assert r.correspondence == "identity" and r.verdict == "authentic" and r.bit_exact


def test_topology_match_survives_noise_on_a_reordered_mesh(marked):
    data, key, img, ref = marked
    rng = np.random.default_rng(5)
    V, F = _reorder(ref.positions, ref.faces, rng)
    V = V + rng.uniform(-1, 1, V.shape) * 0.01
    vmap = match_topology(V, F, ref.positions, ref.faces)
    assert vmap is not None
    assert same_face_set(vmap[ref.faces], F)
    r = verify_mesh((V, F), data, key)
    assert r.correspondence == "permutation"
    assert r.verdict != "authentic"  # 1% noise destroys the fragile mark -- and says so


def test_a_mesh_that_is_not_the_reference_is_not_authentic(marked):
    data, key, img, ref = marked
    # same connectivity (found by the topology match), other geometry; and the unmarked input itself
    for other in (shapes.icosphere(3, noise=0.02, seed=9), shapes.icosphere(3, noise=0.02)):
        r = verify_mesh(other, data, key)
        assert r.verdict == "not-authentic", r.as_json()
        assert r.ber > 0.3
    # another shape: registration finds (almost) no counterparts -- too few codes to decide
    r = verify_mesh(shapes.torus(24, 12), data, key)
    assert r.verdict == "inconclusive" and r.carriers_read < 32


def test_crop_of_a_moved_mesh_goes_through_registration(marked):
    data, key, img, ref = marked
    rng = np.random.default_rng(6)
    V = ref.positions
    keep = V[:, 2] > np.quantile(V[:, 2], 0.3)
    idx = np.flatnonzero(keep)
    remap = np.full(len(V), -1)
    remap[idx] = np.arange(len(idx))
    F = remap[ref.faces[keep[ref.faces].all(axis=1)]]
    V2 = 0.5 * V[idx] @ _rotation(rng).T + 3.0
    r = verify_mesh((V2, F), data, key)
    assert r.correspondence == "registration"
    assert 0.5 < r.coverage < 0.8
    assert r.carriers_read < r.carriers_total
    assert r.ber == 0.0 and r.verdict == "authentic"  # the surviving carriers all hold the key's codes


def test_wrong_key_is_not_authentic(marked):
    data, key, img, ref = marked
    r = verify_mesh(ref, data, WatermarkKey.generate(rng=np.random.default_rng(99), reference=img))
    assert r.verdict == "not-authentic" and r.key_matches is False


def test_code_ber():
    got = np.array([0b101, -1, 0b111, 0b000])
    exp = np.array([0b101, 0b000, 0b110, 0b011])
    assert code_ber(got, exp, 3) == pytest.approx(3 / 9)
    assert code_ber(np.full(3, -1), exp[:3], 3) is None
