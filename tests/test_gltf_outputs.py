"""What we write, read by real tools: decoded levels (``.glb`` and self-contained ``.gltf``) of generated
assets are Khronos-validator clean and three.js's GLTFLoader sees the vertices, triangles and attributes
``decode_asset`` says it wrote (outside probe h93).

The checks run ``node tools/js/check_gltf.mjs``; they skip with the reason when Node or
``npm ci --prefix tools/js`` is missing.  Python-only checks of the same outputs run everywhere.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.stream.asset import decode_asset, encode_asset

from conftest import ROOT
from test_integer_attributes import UNSIGNED_INT, _asset

JS = ROOT / "tools" / "js"
FLOAT = 5126


def _check(paths):
    if shutil.which("node") is None:
        pytest.skip("node is not on PATH")
    if not (JS / "node_modules").is_dir():
        pytest.skip("tools/js/node_modules is absent: run `npm ci --prefix tools/js`")
    proc = subprocess.run(["node", str(JS / "check_gltf.mjs"), *map(str, paths)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    return [json.loads(line) for line in proc.stdout.splitlines()]


@pytest.fixture(scope="module")
def u32_ids(tmp_path_factory):
    """A sphere whose ``_FEATURE_ID_0`` is (invalidly) UNSIGNED_INT, encoded; its ids and input positions."""
    tmp = tmp_path_factory.mktemp("u32")
    ids = (np.arange(642) * 97) % 70000
    mesh = _asset(tmp / "ids.glb", ids, UNSIGNED_INT)
    encode_asset(tmp / "ids.glb", tmp / "ids.pmw", measure=False)
    return tmp, ids, mesh


def test_an_unsigned_int_feature_id_is_written_back_as_exact_floats_not_as_unsigned_int(u32_ids):
    """glTF allows UNSIGNED_INT for indices only: a decoded level wrote the input's UNSIGNED_INT vertex
    attribute as it came (validator error MESH_PRIMITIVE_ATTRIBUTES_ACCESSOR_UNSIGNED_INT at every level);
    now it is FLOAT, each value the exact integer."""
    from scipy.spatial import cKDTree

    tmp, ids, mesh = u32_ids
    for chunks in (0, None):
        glb, _, _ = decode_asset(tmp / "ids.pmw", chunks)
        (tmp / "out.glb").write_bytes(glb)
        doc, buffers = load_document(tmp / "out.glb")
        prim = doc["meshes"][0]["primitives"][0]
        acc = doc["accessors"][prim["attributes"]["_FEATURE_ID_0"]]
        assert acc["componentType"] == FLOAT and not acc.get("normalized", False), acc
        values = read_accessor(doc, buffers, prim["attributes"]["_FEATURE_ID_0"])[:, 0]
        _, vertex = cKDTree(mesh.positions).query(read_accessor(doc, buffers, prim["attributes"]["POSITION"]))
        assert np.array_equal(values, ids[vertex]), chunks


def test_decoded_levels_of_an_unsigned_int_feature_id_input_are_validator_clean(u32_ids):
    tmp, _, _ = u32_ids
    paths = []
    for chunks in (0, 1, None):
        glb, _, _ = decode_asset(tmp / "ids.pmw", chunks)
        paths.append(tmp / f"level{chunks}.glb")
        paths[-1].write_bytes(glb)
    for result in _check(paths):
        report = result["validator"]
        assert (report["errors"], report["warnings"]) == (0, 0), (result["file"], report["messages"])
        assert result["three"]["ok"], result["three"]["error"]
        (prim,) = result["three"]["primitives"]
        assert prim["attributes"]["_feature_id_0"] == [1, False, "Float32Array"]


def _mixed_asset(path):
    """A skinned sphere (JOINTS_0 / WEIGHTS_0, made progressive), a torus with normalized UNSIGNED_BYTE colours
    and UNSIGNED_SHORT feature ids (made progressive) and a torus with a morph target (passed through)."""
    from pmwm_codec import shapes
    from test_asset import DocBuilder

    b = DocBuilder()
    sphere, torus = shapes.icosphere(3, 1.0, noise=0.02), shapes.torus(40, 20)
    n, m = sphere.vertex_count, torus.vertex_count
    t = ((sphere.positions[:, 2] + 1) / 2).clip(0, 1)
    joints = np.zeros((n, 4), np.uint8)
    joints[t > 0, 1] = 1
    weights = np.zeros((n, 4), np.float32)
    weights[:, 0], weights[:, 1] = 1 - t, t
    skinned = b.triangles(sphere)
    skinned["attributes"].update(JOINTS_0=b.accessor(joints, 5121, "VEC4", 34962),
                                 WEIGHTS_0=b.accessor(weights, 5126, "VEC4", 34962))
    ibm = b.accessor(np.tile(np.eye(4, dtype=np.float32).ravel(), (2, 1)), 5126, "MAT4")
    coloured = b.triangles(torus)
    rng = np.random.default_rng(5)
    coloured["attributes"]["COLOR_0"] = b.accessor(rng.integers(0, 256, (m, 4)).astype(np.uint8), 5121, "VEC4", 34962)
    b.doc["accessors"][-1]["normalized"] = True
    ids = np.zeros((m, 2), np.uint16)
    ids[:, 0] = np.arange(m) % 300
    coloured["attributes"]["_FEATURE_ID_0"] = b.accessor(ids, 5123, "VEC2", 34962)
    b.doc["accessors"][-1]["type"] = "SCALAR"
    b.doc["bufferViews"][-1]["byteStride"] = 4
    morphed = {**b.triangles(torus), "targets": [{"POSITION": b.accessor(
        (torus.positions * 0.2).astype(np.float32), 5126, "VEC3", 34962, True)}]}
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0, 1, 3, 4]}],
        "nodes": [{"mesh": 0, "skin": 0}, {"name": "j0", "children": [2]}, {"name": "j1", "translation": [0, 0, 1.0]},
                  {"mesh": 1, "translation": [3.0, 0, 0]}, {"mesh": 2, "translation": [-3.0, 0, 0]}],
        "skins": [{"joints": [1, 2], "inverseBindMatrices": ibm}],
        "meshes": [{"primitives": [skinned]}, {"primitives": [coloured]}, {"primitives": [morphed], "weights": [0.5]}],
    })
    path.write_bytes(b.glb())


def test_decoded_glb_and_gltf_levels_are_validator_clean_and_three_js_sees_what_decode_wrote(tmp_path, capsys):
    """Each level as .glb and as self-contained .gltf (data: URIs, which the checker could not load in Node
    before it had a ProgressEvent): no validator error or warning, and three.js counts the vertices and
    triangles ``decode --json`` reports, keeps the skin and the morph target, and reads every attribute of
    the input with its itemSize (normalized colours come back as FLOATs in [0, 1], feature ids as their
    UNSIGNED_SHORTs)."""
    from pmwm_codec.cli import main

    _mixed_asset(tmp_path / "in.glb")
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    paths, said = [], []
    for chunks in ("0", "1", "99"):
        for suffix in (".glb", ".gltf"):
            paths.append(tmp_path / f"level{chunks}{suffix}")
            capsys.readouterr()
            argv = ["decode", str(tmp_path / "in.pmw"), "-o", str(paths[-1]), "--chunks", chunks, "--json"]
            assert main(argv) in (0, None)
            said.append(json.loads(capsys.readouterr().out))
    results = _check([tmp_path / "in.glb", *paths])
    source = results[0]["three"]
    for path, result, decoded in zip(paths, results[1:], said):
        report, three = result["validator"], result["three"]
        assert (report["errors"], report["warnings"]) == (0, 0), (path.name, report["messages"])
        assert three["ok"] and not three["warnings"], (path.name, three)
        assert (three["vertices"], three["triangles"]) == (decoded["vertices"], decoded["faces"]), path.name
        assert [p["mode"] for p in three["primitives"]] == ["SkinnedMesh", "Mesh", "Mesh"]
        assert [p["morphTargets"] for p in three["primitives"]] == [0, 0, 1]
        for got, want in zip(three["primitives"], source["primitives"]):
            assert {k: v[0] for k, v in got["attributes"].items()} == {k: v[0] for k, v in want["attributes"].items()}
        coloured = three["primitives"][1]["attributes"]
        assert coloured["color"] == [4, False, "Float32Array"]
        assert coloured["_feature_id_0"] == [1, False, "Uint16Array"]
    full = results[-1]["three"]
    assert (full["vertices"], full["triangles"]) == (source["vertices"], source["triangles"])
    for got, want in zip(results[-1]["three"]["primitives"], source["primitives"]):
        assert np.allclose(got["box"], want["box"], atol=1e-4)


@pytest.mark.parametrize("source", ["draco", "meshopt"])
def test_three_js_reads_compressed_inputs_and_their_decoded_level_has_the_same_geometry(tmp_path, source):
    """The checker reads a Draco input with a normalized UNSIGNED_BYTE colour and UNSIGNED_SHORT feature ids
    (its Draco stand-in handled Float32Array only) and a meshopt-compressed one (no MeshoptDecoder was set),
    so the full level can be compared with the input as three.js shows both: same vertex and triangle
    counts, same bounding box, same attributes and sizes."""
    if source == "draco":
        import DracoPy
        from pmwm_codec import shapes
        from pmwm_codec.format.glb import glb_parts
        from pmwm_codec.format.layout import padded

        mesh = shapes.icosphere(3, 1.0, noise=0.02)
        n = mesh.vertex_count
        colour = np.random.default_rng(1).integers(0, 256, (n, 3)).astype(np.uint8)
        ids = (np.arange(n) % 7).astype(np.uint16).reshape(-1, 1)
        data = DracoPy.encode(mesh.positions.astype(np.float32), mesh.faces.astype(np.uint32), quantization_bits=16,
                              colors=colour, generic_attributes={1: ids}, preserve_order=True)
        unique = {a["attribute_type"]: a["unique_id"] for a in DracoPy.decode(data).attributes}
        data += bytes(padded(len(data)) - len(data))
        doc = {
            "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "extensionsUsed": ["KHR_draco_mesh_compression"], "extensionsRequired": ["KHR_draco_mesh_compression"],
            "meshes": [{"primitives": [{
                "attributes": {"POSITION": 0, "COLOR_0": 1, "_FEATURE_ID_0": 2}, "indices": 3,
                "extensions": {"KHR_draco_mesh_compression": {"bufferView": 0, "attributes": {
                    "POSITION": unique[0], "COLOR_0": unique[2], "_FEATURE_ID_0": unique[4]}}}}]}],
            "accessors": [
                {"componentType": FLOAT, "count": n, "type": "VEC3", "min": mesh.positions.min(0).tolist(),
                 "max": mesh.positions.max(0).tolist()},
                {"componentType": 5121, "normalized": True, "count": n, "type": "VEC3"},
                {"componentType": 5123, "count": n, "type": "SCALAR"},
                {"componentType": UNSIGNED_INT, "count": mesh.faces.size, "type": "SCALAR"}],
            "bufferViews": [{"buffer": 0, "byteLength": len(data)}], "buffers": [{"byteLength": len(data)}],
        }
        src = tmp_path / "in.glb"
        src.write_bytes(b"".join(glb_parts(doc, [data], len(data))))
    else:
        src = ROOT / "tests" / "data" / "meshopt" / "torus_c.glb"
    encode_asset(src, tmp_path / "in.pmw", measure=False)
    glb, _, _ = decode_asset(tmp_path / "in.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    before, after = _check([src, tmp_path / "out.glb"])
    assert before["three"]["ok"], before["three"]["error"]
    assert before["three"]["draco"] == (source == "draco")
    assert (after["validator"]["errors"], after["validator"]["warnings"]) == (0, 0), after["validator"]["messages"]
    assert (after["three"]["vertices"], after["three"]["triangles"]) == (before["three"]["vertices"],
                                                                         before["three"]["triangles"])
    (want,), (got,) = before["three"]["primitives"], after["three"]["primitives"]
    assert {k: v[0] for k, v in got["attributes"].items()} == {k: v[0] for k, v in want["attributes"].items()}
    assert np.allclose(got["box"], want["box"], atol=2e-3 * np.ptp(want["box"], axis=0).max())


def test_write_mesh_glb_and_self_contained_gltf_are_validator_clean_with_the_mesh_s_counts_and_bounds(tmp_path):
    from pmwm_codec import Mesh, shapes, write_mesh

    mesh = shapes.torus(20, 10)
    for suffix in (".glb", ".gltf"):
        write_mesh(tmp_path / f"t{suffix}", Mesh(mesh.positions, mesh.faces))
    for result in _check([tmp_path / "t.glb", tmp_path / "t.gltf"]):
        report, three = result["validator"], result["three"]
        assert (report["errors"], report["warnings"], report["infos"]) == (0, 0, 0), report["messages"]
        assert three["ok"] and (three["vertices"], three["triangles"]) == (mesh.vertex_count, len(mesh.faces))
        (prim,) = three["primitives"]
        assert prim["attributes"] == {"position": [3, False, "Float32Array"]}
        assert np.allclose(prim["box"], [mesh.positions.min(0), mesh.positions.max(0)], atol=1e-6)


def test_the_checker_reports_bytes_that_are_not_gltf_as_one_error_and_checks_the_next_file(tmp_path):
    """The validator throws on bytes it cannot read as glTF at all; the checker died there, losing the
    lines of the files after it, where it promises a line per file whatever the file holds."""
    from pmwm_codec import Mesh, shapes, write_mesh

    (tmp_path / "junk.glb").write_bytes(b"hello")
    mesh = shapes.torus(20, 10)
    write_mesh(tmp_path / "t.glb", Mesh(mesh.positions, mesh.faces))
    junk, good = _check([tmp_path / "junk.glb", tmp_path / "t.glb"])
    assert junk["validator"]["codes"] == {"NOT_GLTF": 1} and not junk["three"]["ok"]
    assert good["validator"]["errors"] == 0 and good["three"]["ok"]
