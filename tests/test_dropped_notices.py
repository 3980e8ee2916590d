"""What a reader drops from a mesh (vertices no face names, triangles naming a vertex twice) the encoder says, in
every reading: a plain OBJ, PLY or OFF said ``dropped 20 unreferenced vertices``, while a glTF primitive and an OBJ
with texture coordinates or vertex colours (read as an asset) dropped the same without a word."""

from __future__ import annotations

import json
import struct

import numpy as np

import pmwm_codec
from pmwm_codec import shapes


def _glb(path, positions, faces) -> None:
    pos = np.asarray(positions, np.float32)
    idx = np.asarray(faces, np.uint32).reshape(-1)
    blob = pos.tobytes() + idx.tobytes()
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "buffers": [{"byteLength": len(blob)}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes},
                            {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                           "min": pos.min(0).tolist(), "max": pos.max(0).tolist()},
                          {"bufferView": 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}]}
    js = json.dumps(gltf).encode()
    js += b" " * (-len(js) % 4)
    path.write_bytes(b"glTF" + struct.pack("<II", 2, 28 + len(js) + len(blob)) + struct.pack("<I", len(js)) + b"JSON"
                     + js + struct.pack("<I", len(blob)) + b"BIN\0" + blob)


def _mesh():
    mesh = shapes.icosphere(2)
    extra = np.random.default_rng(5).uniform(-0.5, 0.5, (7, 3))
    return mesh, np.vstack([mesh.positions, extra])


def test_a_gltf_primitive_s_unreferenced_vertices_and_degenerate_triangles_are_said(tmp_path):
    mesh, positions = _mesh()
    faces = np.vstack([mesh.faces, [[0, 0, 1], [2, 3, 3]]])
    _glb(tmp_path / "a.glb", positions, faces)
    report = pmwm_codec.encode(str(tmp_path / "a.glb"), str(tmp_path / "a.pmw"))
    assert report["vertices"] == mesh.vertex_count and report["faces"] == mesh.face_count
    assert "mesh 0 primitive 0: dropped 2 degenerate faces and 7 unreferenced vertices" in report["notices"], \
        report["notices"]
    _glb(tmp_path / "b.glb", mesh.positions, mesh.faces)
    assert not any("dropped" in n for n in pmwm_codec.encode(str(tmp_path / "b.glb"),
                                                             str(tmp_path / "b.pmw"))["notices"])


def test_an_obj_read_as_an_asset_says_its_unreferenced_vertices_as_a_plain_one_does(tmp_path):
    mesh, positions = _mesh()
    v = "".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in positions.tolist())
    plain = "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces.tolist())
    textured = "vt 0.5 0.5\n" + "".join(f"f {a + 1}/1 {b + 1}/1 {c + 1}/1\n" for a, b, c in mesh.faces.tolist())
    coloured = "".join(f"v {x!r} {y!r} {z!r} 0.5 0.2 0.1\n" for x, y, z in positions.tolist()) + plain
    for name, text in (("plain.obj", v + plain), ("textured.obj", v + textured), ("coloured.obj", coloured)):
        (tmp_path / name).write_text(text)
        report = pmwm_codec.encode(str(tmp_path / name), str(tmp_path / (name + ".pmw")))
        assert report["vertices"] == mesh.vertex_count
        assert "dropped 7 unreferenced vertices" in report["notices"], (name, report["notices"])


def _obj_with_lines_and_points(tmp_path, appearance: bool):
    mesh = shapes.icosphere(1)
    lines = ["v " + " ".join(map(repr, p)) for p in mesh.positions.tolist()]
    if appearance:
        lines.append("vt 0.5 0.5")
    corner = "{}/1" if appearance else "{}"
    lines += ["f " + " ".join(corner.format(i + 1) for i in f) for f in mesh.faces.tolist()]
    lines += ["l 1 2 3", "p 4", "  l\t5 6", "# l 7 8 (a comment)"]
    src = tmp_path / ("uv.obj" if appearance else "plain.obj")
    src.write_text("\n".join(lines) + "\n")
    return mesh, src


def test_an_obj_s_line_and_point_records_are_said_left_out(tmp_path, capsys):
    """``l`` (polyline) and ``p`` (point) records were dropped without a word by every OBJ reading; now counted as
    OFF's records past its faces are: read_mesh's ``cleanup``, the encoder's note."""
    from pmwm_codec.cli import main

    for appearance in (False, True):
        mesh, src = _obj_with_lines_and_points(tmp_path, appearance)
        got = pmwm_codec.read_mesh(src)
        assert got.face_count == mesh.face_count and got.cleanup == {"line_and_point_records": 3}
        for options in ((), ("--geometry-only",)):
            assert main(["encode", str(src), "-o", str(tmp_path / "out.pmw"), "-q", "--json", *options]) == 0
            notices = json.loads(capsys.readouterr().out)["notices"]
            assert "dropped 3 line and point records" in notices, (appearance, options, notices)


def test_an_obj_of_lines_and_points_alone_is_named_so(tmp_path):
    import pytest

    (tmp_path / "wire.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3 1\np 2\n")
    with pytest.raises(pmwm_codec.PmwError, match=r"^wire.obj: the file holds no triangle mesh \(no face; 2 line "
                                                   r"and point records \(l, p\), not read\)$"):
        pmwm_codec.read_mesh(tmp_path / "wire.obj")
