"""A ``.pmw`` of an asset that also draws points or lines (passed through by the encoder) decoded to an OBJ, PLY,
STL or OFF: those files get the scene's triangles, and the decode says that the points and lines are left out
(they had been dropped without a word, while a ``.glb`` keeps them)."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.cli import main


def _glb(path, mesh) -> None:
    pos = mesh.positions.astype(np.float32)
    idx = mesh.faces.astype(np.uint32).reshape(-1)
    blob = pos.tobytes() + idx.tobytes()
    gltf = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "buffers": [{"byteLength": len(blob)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                        {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                       "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
                      {"bufferView": 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"},
                      {"bufferView": 0, "componentType": 5126, "count": 20, "type": "VEC3",
                       "min": pos[:20].min(0).tolist(), "max": pos[:20].max(0).tolist()}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1},
                                   {"attributes": {"POSITION": 2}, "mode": 0},
                                   {"attributes": {"POSITION": 2}, "mode": 1}]}],
    }
    js = json.dumps(gltf).encode()
    js += b" " * (-len(js) % 4)
    blob += b"\0" * (-len(blob) % 4)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 28 + len(js) + len(blob)) + struct.pack("<I", len(js)) + b"JSON"
                     + js + struct.pack("<I", len(blob)) + b"BIN\0" + blob)


@pytest.mark.parametrize("suffix", [".obj", ".ply", ".stl", ".off"])
def test_points_and_lines_left_out_of_a_mesh_file_are_named(tmp_path, capsys, suffix):
    _glb(tmp_path / "a.glb", shapes.icosphere(2))
    assert main(["encode", str(tmp_path / "a.glb"), "-o", str(tmp_path / "a.pmw"), "-q"]) == 0
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / f"b{suffix}"), "--json"]) == 0
    notices = json.loads(capsys.readouterr().out)["notices"]
    assert any("POINTS" in n and "LINES" in n and "left out" in n for n in notices), notices
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / "b.glb"), "--json"]) == 0
    assert not any("left out" in n for n in json.loads(capsys.readouterr().out)["notices"])
