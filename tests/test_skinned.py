"""Skinned primitives stream like any other: their JOINTS_n ride as exact integers, written back (in the
base too) with their componentType, and their WEIGHTS_n on a grid fine enough that every level's weights
still sum to 1 as closely as the input's (the glTF validator's ACCESSOR_WEIGHTS_NON_NORMALIZED)."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pmwm_codec import shapes
from pmwm_codec.format import base as base_format
from pmwm_codec.format.document import read_accessor
from pmwm_codec.stream.asset import decode_asset, encode_asset

from test_asset import DocBuilder
from test_js_decoder import _js_levels, _node, _python_levels


def _skinned_asset(path, joints_type: int = 5121):
    """A noisy sphere bent by two joints along z: JOINTS_0 of ``joints_type``, WEIGHTS_0 float (1 - t, t)."""
    b = DocBuilder()
    sphere = shapes.icosphere(3, 1.0, noise=0.02, seed=4)
    n = sphere.vertex_count
    t = ((sphere.positions[:, 2] + 1) / 2).clip(0, 1)
    joints = np.zeros((n, 4), {5121: np.uint8, 5123: np.uint16}[joints_type])
    joints[:, 0], joints[:, 1] = 0, 1 + (t > 0.5)  # three joints: 0 and 1 or 2
    weights = np.zeros((n, 4), np.float32)
    weights[:, 1] = t.astype(np.float32)
    weights[:, 0] = (1 - weights[:, 1].astype(np.float64)).astype(np.float32)
    prim = b.triangles(sphere)
    prim["attributes"].update(JOINTS_0=b.accessor(joints, joints_type, "VEC4", 34962),
                              WEIGHTS_0=b.accessor(weights, 5126, "VEC4", 34962))
    ibm = b.accessor(np.tile(np.eye(4, dtype=np.float32).ravel(), (3, 1)), 5126, "MAT4")
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0, 1]}],
        "nodes": [{"mesh": 0, "skin": 0}, {"name": "j0", "children": [2, 3]}, {"name": "j1", "translation": [0, 0, 1.0]},
                  {"name": "j2", "translation": [0, 0, -1.0]}],
        "skins": [{"joints": [1, 2, 3], "inverseBindMatrices": ibm}],
        "meshes": [{"primitives": [prim]}],
    })
    path.write_bytes(b.glb())
    return sphere.positions, joints, weights


def _json(data: bytes) -> dict:
    length = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + length])


def _level(glb: bytes) -> dict:
    doc = _json(glb)
    (prim,) = doc["meshes"][0]["primitives"]
    length = struct.unpack("<I", glb[12:16])[0]
    buffers = [glb[20 + length + 8:]]
    types = {k: doc["accessors"][i]["componentType"] for k, i in prim["attributes"].items()}
    return types, {k: read_accessor(doc, buffers, i) for k, i in prim["attributes"].items()}


@pytest.mark.parametrize("joints_type", [5121, 5123], ids=["UNSIGNED_BYTE", "UNSIGNED_SHORT"])
def test_a_skinned_primitive_streams_its_joints_exact_and_its_weights_summing_to_one(tmp_path, joints_type):
    positions, joints, weights = _skinned_asset(tmp_path / "in.glb", joints_type)
    report = encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    assert report.vsplits > 0.8 * len(positions)  # made progressive, not passed through
    data = (tmp_path / "in.pmw").read_bytes()
    doc = _json(data)
    (prim,) = doc["meshes"][0]["primitives"]
    specs = {a["semantic"]: a for a in prim["extensions"]["PMWM_progressive_mesh"]["attributes"]}
    assert specs["JOINTS_0"].get("componentType") == joints_type and "componentType" not in specs["WEIGHTS_0"]
    assert doc["accessors"][prim["attributes"]["JOINTS_0"]]["componentType"] == joints_type  # the base a viewer skins
    assert doc["skins"] and doc["nodes"][0]["skin"] == 0
    tree = cKDTree(positions)
    for chunks in (0, 3, None):
        glb, _, _ = decode_asset(tmp_path / "in.pmw", chunks=chunks)
        types, values = _level(glb)
        assert types["JOINTS_0"] == joints_type and types["WEIGHTS_0"] == 5126
        dist, src = tree.query(values["POSITION"])
        assert dist.max() < 1e-3
        assert np.array_equal(values["JOINTS_0"], joints[src])
        error = np.abs(values["WEIGHTS_0"].astype(np.float64) - weights[src])
        assert error.max() <= 2.0**-25 and not error[weights[src] >= 0.5].any()  # from 1/2 on, exact
        sums = values["WEIGHTS_0"].sum(axis=1, dtype=np.float64)
        assert np.abs(sums - 1.0).max() <= np.abs(weights.sum(axis=1, dtype=np.float64) - 1.0).max() + 2.0**-23


def test_the_javascript_decoder_reads_integer_and_float_base_attributes_as_python_does(tmp_path, monkeypatch):
    """A base storing JOINTS_0 as its UNSIGNED_SHORTs (files from now on) and one storing them as FLOAT
    (files written before integer bases): both decoders read both, level for level."""
    node = _node()
    _skinned_asset(tmp_path / "in.glb", 5123)
    encode_asset(tmp_path / "in.glb", tmp_path / "integer.pmw", measure=False)
    monkeypatch.setattr(base_format, "stored_type", lambda spec: base_format.FLOAT)
    encode_asset(tmp_path / "in.glb", tmp_path / "float.pmw", measure=False)
    monkeypatch.undo()
    integer, floats = (tmp_path / "integer.pmw").read_bytes(), (tmp_path / "float.pmw").read_bytes()
    kinds = []
    for data in (integer, floats):
        doc = _json(data)
        kinds.append(doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"]]["componentType"])
    assert kinds == [5123, base_format.FLOAT]
    python, other = _python_levels(integer), _python_levels(floats)
    unread = lambda levels: [{k: v for k, v in level.items() if k != "bytesRead"} for level in levels]  # noqa: E731
    assert unread(other) == unread(python)  # the same levels: only the base's bytes differ
    shifts = {b["bytesRead"] - a["bytesRead"] for a, b in zip(python[1:], other[1:])}
    assert shifts == {len(floats) - len(integer)}  # (the base's own end moves by its unpadded size)
    for path, data in ((tmp_path / "integer.pmw", integer), (tmp_path / "float.pmw", floats)):
        js, end = _js_levels(node, path)
        assert end["complete"] and js == _python_levels(data)


def test_a_normalized_integer_base_attribute_is_refused(tmp_path):
    _skinned_asset(tmp_path / "in.glb", 5121)
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    data = bytearray((tmp_path / "in.pmw").read_bytes())
    doc = _json(bytes(data))
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"]]
    acc["normalized"] = True
    import pmwm_codec
    from pmwm_codec.errors import FormatError

    text = json.dumps(doc, separators=(",", ":")).encode()
    length = struct.unpack("<I", data[12:16])[0]
    padded = text + b" " * (-len(text) % 4)
    out = data[:12] + struct.pack("<II", len(padded), 0x4E4F534A) + padded + data[20 + length:]
    out[8:12] = struct.pack("<I", len(out))
    with pytest.raises(FormatError, match="JOINTS_0"):
        pmwm_codec.decode(bytes(out))


def test_a_progressive_skinned_mesh_decoded_to_obj_says_it_is_in_its_stored_pose(tmp_path, capsys):
    from pmwm_codec.cli import main

    _skinned_asset(tmp_path / "in.glb")
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    capsys.readouterr()
    assert main(["decode", str(tmp_path / "in.pmw"), "-o", str(tmp_path / "out.obj"), "--json"]) in (0, None)
    notices = json.loads(capsys.readouterr().out)["notices"]
    assert "mesh 0 is skinned: the file holds it in its stored pose, not posed by its joints" in notices


def test_the_pmw_and_its_levels_are_validator_clean_and_three_js_skins_the_base(tmp_path):
    """The .pmw itself (its base stores JOINTS_0 as UNSIGNED_BYTE) and a level as a GLB: no validator error, no
    issue the input does not have, and three.js makes a SkinnedMesh of each with integer skin indices."""
    from test_gltf_outputs import _check

    _skinned_asset(tmp_path / "in.glb")
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    glb, _, _ = decode_asset(tmp_path / "in.pmw", chunks=2)
    (tmp_path / "level2.glb").write_bytes(glb)
    source, *results = _check([tmp_path / "in.glb", tmp_path / "in.pmw", tmp_path / "level2.glb"])
    for result in results:
        report = result["validator"]
        new = set(report["codes"]) - set(source["validator"]["codes"]) - {"UNSUPPORTED_EXTENSION"}  # the .pmw's own
        assert report["errors"] == 0 and not new, report
        (prim,) = result["three"]["primitives"]
        assert prim["mode"] == "SkinnedMesh" and prim["attributes"]["skinIndex"] == [4, False, "Uint8Array"]
