"""Integer vertex attributes (outside probe 2, F3): a non-normalized integer accessor (EXT_mesh_features
``_FEATURE_ID_0``, ``_BATCHID``) rides with the splits exactly, on a grid of step 1, and a decoded level
writes it back with its own componentType; integers float32 cannot hold pass the primitive through."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pmwm_codec import shapes
from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.format.glb import glb_parts
from pmwm_codec.format.layout import padded
from pmwm_codec.stream.asset import decode_asset, encode_asset

UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT, FLOAT = 5121, 5123, 5125, 5126
DTYPES = {UNSIGNED_BYTE: np.uint8, UNSIGNED_SHORT: np.uint16, UNSIGNED_INT: np.uint32}


def _asset(path, ids: np.ndarray, component: int):
    """A sphere whose vertices carry ``ids`` as ``_FEATURE_ID_0`` (``component``, each element padded to
    4 bytes as glTF wants a vertex attribute), with EXT_mesh_features pointing at it."""
    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    views, accessors, parts = [], [], []

    def add(raw: bytes, target: int, stride=None) -> int:
        offset = sum(len(p) for p in parts)
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(raw), "target": target,
                      **({"byteStride": stride} if stride else {})})
        parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        return len(views) - 1

    pos = mesh.positions.astype(np.float32)
    accessors.append({"bufferView": add(pos.tobytes(), 34962), "componentType": FLOAT, "count": len(pos),
                      "type": "VEC3", "min": pos.min(0).tolist(), "max": pos.max(0).tolist()})
    rows = np.zeros((len(ids), 4), np.uint8)
    raw = ids.astype(DTYPES[component])
    rows[:, : raw.itemsize] = raw.view(np.uint8).reshape(len(ids), -1)
    accessors.append({"bufferView": add(rows.tobytes(), 34962, 4), "componentType": component, "count": len(ids),
                      "type": "SCALAR", "name": "feature ids"})
    accessors.append({"bufferView": add(mesh.faces.astype(np.uint32).tobytes(), 34963), "componentType": UNSIGNED_INT,
                      "count": mesh.faces.size, "type": "SCALAR"})
    doc = {
        "asset": {"version": "2.0"}, "extensionsUsed": ["EXT_mesh_features"], "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}], "accessors": accessors, "bufferViews": views,
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "_FEATURE_ID_0": 1}, "indices": 2, "extensions": {
            "EXT_mesh_features": {"featureIds": [{"featureCount": int(ids.max()) + 1, "attribute": 0}]}}}]}],
    }
    length = sum(len(p) for p in parts)
    doc["buffers"] = [{"byteLength": length}]
    path.write_bytes(b"".join(glb_parts(doc, parts, length)))
    return mesh


def _level(tmp_path, pmw, chunks=None):
    glb, _, _ = decode_asset(pmw, chunks)
    out = tmp_path / f"level{chunks}.glb"
    out.write_bytes(glb)
    doc, buffers = load_document(out)
    prim = doc["meshes"][0]["primitives"][0]
    index = prim["attributes"]["_FEATURE_ID_0"]
    return doc["accessors"][index], read_accessor(doc, buffers, index)[:, 0], read_accessor(
        doc, buffers, prim["attributes"]["POSITION"])


@pytest.mark.parametrize("component, count", [(UNSIGNED_BYTE, 10), (UNSIGNED_SHORT, 40000)])
def test_feature_ids_come_back_exact_with_their_component_type_at_every_level(tmp_path, component, count):
    n = 642
    ids = (np.arange(n) * 97) % count  # u16: 40,000 features, beyond what a 14-bit grid over the span keeps
    mesh = _asset(tmp_path / "ids.glb", ids, component)
    encode_asset(tmp_path / "ids.glb", tmp_path / "ids.pmw", measure=False)
    nearest = cKDTree(mesh.positions)
    for chunks in (0, 1, None):
        acc, values, positions = _level(tmp_path, tmp_path / "ids.pmw", chunks)
        assert acc["componentType"] == component and not acc.get("normalized", False), acc
        assert values.dtype.kind in "iu"  # read as the integers they are
        _, vertex = nearest.query(positions)  # splits never move a vertex: each is an input vertex
        assert np.array_equal(values, ids[vertex]), chunks
    assert len(values) == n  # full resolution: every vertex, each with its own id


def test_integers_float32_cannot_hold_are_not_made_progressive_the_encoder_says_why(tmp_path):
    ids = np.arange(642, dtype=np.int64) + (1 << 24) + 7  # above 2^24: float32 would merge neighbours
    _asset(tmp_path / "big.glb", ids, UNSIGNED_INT)
    with pytest.raises(Exception, match="no triangle primitive.*_FEATURE_ID_0 holds integers beyond 16,777,216"):
        encode_asset(tmp_path / "big.glb", tmp_path / "big.pmw", measure=False)


def test_a_draco_input_keeps_its_integer_and_normalized_attributes_as_its_accessors_declare(tmp_path):
    """Draco stores an integer attribute's raw integers: a normalized UNSIGNED_BYTE colour came back as FLOAT
    values up to 255 (a viewer clamps them: white) and feature ids as FLOATs like 4.9998; now the colour is
    mapped to [0, 1] as its accessor says, and the ids stay exact integers of their componentType."""
    import DracoPy

    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    n = mesh.vertex_count
    ids = (np.arange(n) % 7).astype(np.uint16)
    colour = np.random.default_rng(1).integers(0, 256, (n, 3)).astype(np.uint8)
    data = DracoPy.encode(mesh.positions.astype(np.float32), mesh.faces.astype(np.uint32), quantization_bits=16,
                          colors=colour, generic_attributes={1: ids.reshape(-1, 1)}, preserve_order=True)
    unique = {a["attribute_type"]: a["unique_id"] for a in DracoPy.decode(data).attributes}  # 0 position, 2 colour, 4 generic
    data += bytes(padded(len(data)) - len(data))
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "COLOR_0": 1, "_FEATURE_ID_0": 2}, "indices": 3,
                                    "extensions": {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {
                                        "POSITION": unique[0], "COLOR_0": unique[2], "_FEATURE_ID_0": unique[4]}}}}]}],
        "accessors": [
            {"componentType": FLOAT, "count": n, "type": "VEC3", "min": mesh.positions.min(0).tolist(),
             "max": mesh.positions.max(0).tolist()},
            {"componentType": UNSIGNED_BYTE, "normalized": True, "count": n, "type": "VEC3"},
            {"componentType": UNSIGNED_SHORT, "count": n, "type": "SCALAR"},
            {"componentType": UNSIGNED_INT, "count": mesh.faces.size, "type": "SCALAR"}],
        "bufferViews": [{"buffer": 0, "byteLength": len(data)}], "buffers": [{"byteLength": len(data)}],
    }
    (tmp_path / "draco.glb").write_bytes(b"".join(glb_parts(doc, [data], len(data))))
    encode_asset(tmp_path / "draco.glb", tmp_path / "draco.pmw", measure=False)
    glb, _, _ = decode_asset(tmp_path / "draco.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    out, buffers = load_document(tmp_path / "out.glb")
    prim = out["meshes"][0]["primitives"][0]
    _, vertex = cKDTree(mesh.positions).query(read_accessor(out, buffers, prim["attributes"]["POSITION"]))
    acc = out["accessors"][prim["attributes"]["_FEATURE_ID_0"]]
    assert acc["componentType"] == UNSIGNED_SHORT
    assert np.array_equal(read_accessor(out, buffers, prim["attributes"]["_FEATURE_ID_0"])[:, 0], ids[vertex])
    got = read_accessor(out, buffers, prim["attributes"]["COLOR_0"])
    assert np.abs(got - colour[vertex] / 255.0).max() < 1e-3
