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
