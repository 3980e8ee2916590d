"""Third-party checks: the Khronos glTF-Validator and three.js GLTFLoader accept what we write.

Runs ``node tools/js/check_gltf.mjs`` (one JSON line per file).  Needs Node and
``npm ci --prefix tools/js``; skipped with the reason otherwise.
"""

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from samples import ICOSPHERE_CENTRE, ICOSPHERE_RADIUS, sample_pmw

JS = Path(__file__).resolve().parents[1] / "tools" / "js"
ALLOWED_INFOS = {"UNSUPPORTED_EXTENSION", "UNUSED_OBJECT"}

pytestmark = [
    pytest.mark.node,
    pytest.mark.skipif(shutil.which("node") is None, reason="node is not on PATH"),
    pytest.mark.skipif(not (JS / "node_modules").is_dir(),
                       reason="tools/js/node_modules is absent: run `npm ci --prefix tools/js`"),
]


def _check(paths):
    proc = subprocess.run(["node", str(JS / "check_gltf.mjs"), *map(str, paths)],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return [json.loads(line) for line in proc.stdout.splitlines()]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    out = tmp_path_factory.mktemp("pmw")
    files = {}
    for codec in ("plain", "draco"):
        data, base, payloads, _ = sample_pmw(codec, chunk_count=5, subdivisions=2, seed=11)
        assert base.codec == codec
        path = out / f"{codec}.pmw"
        path.write_bytes(data)
        files[codec] = (path, base)
    results = _check([p for p, _ in files.values()])
    return {codec: (result, files[codec][1]) for codec, result in zip(files, results)}


@pytest.mark.parametrize("codec", ["plain", "draco"])
def test_validator_reports_no_errors_no_warnings_and_only_expected_infos(written, codec):
    result, _ = written[codec]
    report = result["validator"]
    assert (report["errors"], report["warnings"]) == (0, 0), report["messages"]
    assert set(report["codes"]) <= ALLOWED_INFOS, report["codes"]
    assert report["codes"]["UNUSED_OBJECT"] >= 5  # one per chunk bufferView


@pytest.mark.parametrize("codec", ["plain", "draco"])
def test_three_js_loads_the_base_mesh_with_its_counts_and_radius(written, codec):
    result, base = written[codec]
    three = result["three"]
    assert three["ok"], three.get("error")
    assert three["draco"] == (codec == "draco")
    assert (three["meshes"], three["vertices"], three["triangles"]) == (1, base.vertex_count, base.face_count)
    # a swapped Draco attribute id or a lost quantization origin would move these
    assert three["radius"] == pytest.approx(ICOSPHERE_RADIUS, abs=1e-3)
    assert np.allclose(three["center"], ICOSPHERE_CENTRE, atol=1e-3)
    assert not three["warnings"]


def test_cut_file_is_flagged_by_the_validator_and_three_js_still_shows_the_base(tmp_path):
    data, base, _, _ = sample_pmw("plain", chunk_count=5, subdivisions=2, seed=12)
    path = tmp_path / "cut.pmw"
    path.write_bytes(data[: len(data) - 100])
    (result,) = _check([path])
    assert "GLB_UNEXPECTED_END_OF_CHUNK_DATA" in result["validator"]["codes"]
    assert result["three"]["ok"] and result["three"]["vertices"] == base.vertex_count


def test_a_draco_base_with_attributes_is_valid_and_three_js_reads_them_from_the_draco_data():
    """The conformance file whose Draco base carries TEXCOORD_0 (Draco's texture coordinate), COLOR_0 and
    _FEATURE_ID_0 (generic attributes) and the weld attribute: no validator error or warning, and three.js's
    DRACOLoader gives every attribute with the type its accessor declares."""
    path = Path(__file__).resolve().parents[1] / "spec" / "conformance" / "uv-torus-attributes.welded-draco.packed.v2.pmw"
    (result,) = _check([path])
    report = result["validator"]
    assert (report["errors"], report["warnings"]) == (0, 0), report["messages"]
    assert set(report["codes"]) <= ALLOWED_INFOS, report["codes"]
    three = result["three"]
    assert three["ok"] and three["draco"], three.get("error")
    attributes = three["primitives"][0]["attributes"]
    assert attributes["uv"] == [2, False, "Float32Array"] and attributes["color"] == [3, False, "Float32Array"]
    assert attributes["_feature_id_0"] == [1, False, "Uint16Array"]
