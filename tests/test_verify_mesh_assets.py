"""A mesh that left the stream verifies for every kind of file ``encode`` writes.

Plain meshes, assets whose primitives carry NORMAL / TEXCOORD_0 columns with the
splits, assets with two progressive primitives -- decoded, exported as an
ordinary GLB, flattened into one mesh (node transforms applied), rotated,
scaled, translated and re-ordered.
"""

from __future__ import annotations

import numpy as np
import pytest

from pmwm_codec.mesh import read_mesh
from pmwm_codec.stream.asset import decode_asset, encode_asset
from pmwm_codec.verify import verify_mesh
from pmwm_codec.watermark.key import WatermarkKey

from conftest import corpus_path
from test_asset import DocBuilder, two_mesh_asset


def _mark(size=16):
    return (np.indices((size, size)).sum(0) * 37 % 251).astype(np.uint8)


def _moved_and_reordered(positions, faces, seed):
    """A similarity transform (rotation, scale 2.5, translation) and a random vertex and face order."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = 2.5 * positions @ q.T + np.array([3.0, -1.0, 7.0])
    perm = rng.permutation(len(moved))
    inv = np.argsort(perm)
    return moved[perm], inv[faces][rng.permutation(len(faces))]


def _one_textured_primitive(tmp_path):
    from pmwm_codec import shapes

    b = DocBuilder()
    prim = b.triangles(shapes.icosphere(4, 1.0, noise=0.02))
    b.doc.update({"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [prim]}]})
    path = tmp_path / "textured.glb"
    path.write_bytes(b.glb())
    return path


def _encode_decode_flatten(src, tmp_path, seed=3):
    key = WatermarkKey.generate(rng=np.random.default_rng(seed))
    pmw = tmp_path / "asset.pmw"
    report = encode_asset(src, pmw, watermark=_mark(), key=key, measure=False)
    glb, end, _ = decode_asset(pmw)
    assert end.complete
    out = tmp_path / "decoded.glb"
    out.write_bytes(glb)
    return pmw, report.key, read_mesh(out)  # node transforms applied, primitives concatenated


@pytest.mark.parametrize("make", [_one_textured_primitive, two_mesh_asset], ids=["attributes", "two-primitives"])
def test_a_decoded_asset_verifies_authentic_bit_exactly(make, tmp_path):
    pmw, key, flat = _encode_decode_flatten(make(tmp_path), tmp_path)
    v = verify_mesh(flat, pmw, key)
    assert v.verdict == "authentic" and v.bit_exact and v.ber == 0.0
    assert v.carriers_read == v.carriers_total


@pytest.mark.parametrize("make", [_one_textured_primitive, two_mesh_asset], ids=["attributes", "two-primitives"])
def test_a_flattened_moved_reordered_asset_still_verifies(make, tmp_path):
    pmw, key, flat = _encode_decode_flatten(make(tmp_path), tmp_path)
    positions, faces = _moved_and_reordered(flat.positions, flat.faces, seed=11)
    v = verify_mesh((positions.astype(np.float32).astype(np.float64), faces), pmw, key)
    assert v.correspondence == "permutation"
    assert v.verdict == "authentic" and v.bit_exact


def test_another_asset_is_not_authentic(tmp_path):
    pmw, key, _ = _encode_decode_flatten(two_mesh_asset(tmp_path), tmp_path)
    other_dir = tmp_path / "other"
    other_dir.mkdir()
    _, _, other = _encode_decode_flatten(_one_textured_primitive(other_dir), other_dir, seed=4)
    assert verify_mesh(other, pmw, key).verdict != "authentic"


@pytest.mark.corpus
def test_spot_decoded_and_moved_verifies(tmp_path):
    pmw, key, flat = _encode_decode_flatten(corpus_path("spot.glb"), tmp_path)
    positions, faces = _moved_and_reordered(flat.positions, flat.faces, seed=5)
    v = verify_mesh((positions, faces), pmw, key)
    assert v.verdict == "authentic" and v.bit_exact


def test_decode_dequantizes_every_primitive_on_its_own_grid(tmp_path):
    import pmwm_codec
    from pmwm_codec.verify.mesh import Reference

    pmw, _, _ = _encode_decode_flatten(two_mesh_asset(tmp_path), tmp_path)
    assert np.array_equal(pmwm_codec.decode(pmw).positions, Reference.read(pmw).positions)


@pytest.mark.parametrize("make", [_one_textured_primitive, two_mesh_asset], ids=["attributes", "two-primitives"])
def test_pmw_verify_reference_on_an_exported_asset_says_authentic(make, tmp_path, capsys):
    """The command line end to end: encode an asset, decode it, flatten + move + re-order it, verify."""
    import json

    from PIL import Image

    from pmwm_codec.cli import main
    from pmwm_codec.meshio import write_mesh
    from pmwm_codec.mesh import Mesh

    src = make(tmp_path)
    Image.fromarray(_mark()).save(tmp_path / "mark.png")
    pmw, key, decoded = tmp_path / "a.pmw", tmp_path / "a.key.json", tmp_path / "decoded.glb"
    assert main(["encode", str(src), "-o", str(pmw), "--watermark", str(tmp_path / "mark.png"), "--key", str(key),
                 "--quiet"]) == 0
    assert main(["decode", str(pmw), "-o", str(decoded)]) == 0
    flat = read_mesh(decoded)
    positions, faces = _moved_and_reordered(flat.positions, flat.faces, seed=2)
    exported = tmp_path / "exported.obj"
    write_mesh(exported, Mesh(positions, faces))
    capsys.readouterr()
    code = main(["verify", str(exported), "--reference", str(pmw), "--key", str(key), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert code == 0 and doc["verdict"] == "authentic" and doc["bit_exact"]


def _placed_asset(tmp_path):
    """Two meshes placed apart by their nodes: one mirrored and stretched, the other shown twice (turned)."""
    from pmwm_codec import shapes

    b = DocBuilder()
    b.doc.update(scene=0, scenes=[{"nodes": [0, 1, 2]}],
                 nodes=[{"mesh": 0, "scale": [-1.0, 2.0, 1.0], "translation": [0.0, 4.0, 0.0]},
                        {"mesh": 1, "translation": [3.0, 0.0, 0.0]},
                        {"mesh": 1, "rotation": [0.0, 0.38268343, 0.0, 0.92387953], "translation": [-3.0, 0.0, 0.0]}],
                 meshes=[{"primitives": [b.triangles(shapes.icosphere(4, noise=0.02, seed=1), uv=False)]},
                         {"primitives": [b.triangles(shapes.icosphere(3, noise=0.02, seed=2), uv=False)]}])
    path = tmp_path / "placed.glb"
    path.write_bytes(b.glb())
    return path


@pytest.mark.parametrize("suffix", [".glb", ".obj"])
def test_a_scene_placed_by_any_matrices_verifies_from_its_flattened_decode(suffix, tmp_path):
    """``pmw decode`` writes the scene as shown (GLB: by its nodes; OBJ: placed): checked against the
    .pmw, each showing is taken back to its primitive's stored coordinates, so mirrored, stretched and
    repeated meshes read bit-exactly, moved, re-ordered and saved as float32."""
    from pmwm_codec.cli import main

    pmw, key, _ = _encode_decode_flatten(_placed_asset(tmp_path), tmp_path)
    out = tmp_path / f"decoded{suffix}"
    assert main(["decode", str(pmw), "-o", str(out), "-q"]) == 0
    flat = read_mesh(out)
    v = verify_mesh(flat, pmw, key)
    assert v.verdict == "authentic" and v.bit_exact and v.carriers_read == v.carriers_total
    positions, faces = _moved_and_reordered(flat.positions, flat.faces, seed=7)
    v = verify_mesh((positions.astype(np.float32).astype(np.float64), faces), pmw, key)
    assert v.verdict == "authentic" and v.bit_exact and v.correspondence == "permutation"
    stretched = flat.positions * np.array([1.0, 1.2, 1.0])  # not a similarity: the codes break
    assert verify_mesh((stretched, flat.faces), pmw, key).verdict == "not-authentic"


def test_an_edit_of_a_copy_the_codes_do_not_read_is_tampered(tmp_path):
    """A mesh the scene shows twice is read from its first showing; the second must agree with it, so an
    edit there is caught and only the edited vertices are flagged."""
    from pmwm_codec.cli import main
    from pmwm_codec.verify.mesh import Reference

    pmw, key, _ = _encode_decode_flatten(_placed_asset(tmp_path), tmp_path)
    assert main(["decode", str(pmw), "-o", str(tmp_path / "decoded.obj"), "-q"]) == 0
    flat = read_mesh(tmp_path / "decoded.obj")  # the scene in the reference's order
    ref = Reference.read(pmw)
    assert np.allclose(flat.positions, ref.scene_positions, rtol=0, atol=1e-5)
    second = ref.spans[1][1]
    edited = flat.positions.copy()
    rows = np.arange(second[0] + 40, second[0] + 52)
    edited[rows] += 0.01
    v = verify_mesh((edited, flat.faces), pmw, key)
    assert v.verdict == "tampered" and np.array_equal(v.flagged, rows)
    assert verify_mesh(flat, pmw, key).verdict == "authentic"
