"""Welded bases (spec README, "Welded base"): a non-manifold base keeps Draco's edgebreaker coder,
whose copies of non-manifold vertices every reader welds back, end to end through the file, the
key's MACs, a cut and the viewers' checkers; a base whose distinct vertices share a grid point
keeps it too, its weld attribute (``_PMWM_WELD``) telling them apart."""

from __future__ import annotations

import io
import json
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.format.glb import glb_parts, split_glb

JS = Path(__file__).resolve().parents[1] / "tools" / "js"


def _json(data: bytes) -> dict:
    (length,) = struct.unpack_from("<I", data, 12)
    return json.loads(data[20 : 20 + length])


def _ext(gltf):
    return gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]


def _encoded(mesh):
    """``(mesh, .pmw bytes, report)`` of a default encode."""
    buf = io.BytesIO()
    report = pmwm_codec.encode(mesh, buf)
    return mesh, buf.getvalue(), report


@pytest.fixture(scope="module")
def welded():
    return _encoded(shapes.bowtie())


def test_a_non_manifold_base_is_stored_by_edgebreaker_and_declares_its_welded_count(welded):
    _, data, report = welded
    gltf = _json(data)
    prim = gltf["meshes"][0]["primitives"][0]
    stored = gltf["accessors"][prim["attributes"]["POSITION"]]["count"]
    assert "KHR_draco_mesh_compression" in prim["extensions"] and report["base_codec"] == "draco"
    assert _ext(gltf)["baseVertexCount"] == report["base_vertices"] < stored


def test_a_welded_file_decodes_to_the_input_on_its_grid(welded):
    mesh, data, _ = welded
    grid = Grid.from_config(_ext(_json(data))["grid"])
    out = pmwm_codec.decode(data)
    assert (out.vertex_count, out.face_count) == (mesh.vertex_count, mesh.face_count)
    got = grid.quantize(out.positions)
    want = grid.quantize(mesh.positions)
    assert np.array_equal(np.unique(got, axis=0), np.unique(want, axis=0))
    assert _oriented_triangles(got, out.faces) == _oriented_triangles(want, mesh.faces)


def _oriented_triangles(q, faces):
    """Every face as its three grid positions, rotated to start at the smallest (orientation kept), sorted."""
    out = []
    for f in faces:
        corners = [tuple(int(x) for x in q[i]) for i in f]
        s = corners.index(min(corners))
        out.append(tuple(corners[s:] + corners[:s]))
    return sorted(out)


def test_every_level_of_a_welded_file_reads_from_a_prefix(welded):
    _, data, report = welded
    levels = list(pmwm_codec.iter_decode(data))
    assert levels[0].vertices == report["base_vertices"]
    assert [r.vertices for r in levels][-1] == report["vertices"]


def test_a_welded_file_cut_to_its_base_declares_the_welded_count(welded):
    _, data, report = welded
    cut = pmwm_codec.cut(data, chunks=0)
    assert _ext(_json(cut))["vertexCount"] == report["base_vertices"]
    assert pmwm_codec.decode(cut).vertex_count == report["base_vertices"]


def test_a_marked_welded_file_verifies_authentic_and_a_changed_count_does_not(tmp_path, capsys):
    mesh = shapes.components(shapes.bowtie(), shapes.icosphere(3, 1.0, noise=0.02))
    src, out, key = tmp_path / "m.obj", tmp_path / "m.pmw", tmp_path / "m.key.json"
    from pmwm_codec.meshio import write_mesh

    write_mesh(str(src), mesh)
    image = tmp_path / "w.png"
    from PIL import Image

    Image.fromarray((np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)).save(image)
    assert main(["encode", str(src), "-o", str(out), "--watermark", str(image), "--key", str(key)]) == 0
    assert "baseVertexCount" in _ext(_json(out.read_bytes()))
    capsys.readouterr()
    assert main(["verify", str(out), "--key", str(key), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["verdict"] == "authentic"
    # without its weld the stored base is another mesh: the file is refused, never authentic
    gltf, binary = split_glb(out.read_bytes())
    del _ext(gltf)["baseVertexCount"]
    out.write_bytes(b"".join(glb_parts(gltf, [binary], len(binary))))
    assert main(["verify", str(out), "--key", str(key), "--json"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pmw: error:") and "Traceback" not in err[0]


@pytest.fixture(scope="module")
def kissing():
    return _encoded(shapes.kissing())


def _prim(data):
    return _prim_of(_json(data))


def _grid_points(data):
    """(k, 3) grid integers of the base's vertices, as decoded (welded)."""
    base = pmwm_codec.decode(data, chunks=0)
    return Grid.from_config(_ext(_json(data))["grid"]).quantize(base.positions)


def test_distinct_vertices_on_one_point_keep_edgebreaker_with_the_weld_attribute(kissing):
    mesh, data, report = kissing
    prim = _prim(data)
    points = _grid_points(data)
    # the three spheres' own vertices on the shared point are all in the base, on one grid point
    assert len(points) - len(np.unique(points, axis=0)) >= 2
    assert report["base_codec"] == "draco" and "_PMWM_WELD" in prim["attributes"]
    assert prim["extensions"]["KHR_draco_mesh_compression"]["attributes"].keys() == {"POSITION", "_PMWM_WELD"}
    assert _ext(_json(data))["baseVertexCount"] == report["base_vertices"] == len(points)
    out = pmwm_codec.decode(data)
    grid = Grid.from_config(_ext(_json(data))["grid"])
    assert _oriented_triangles(grid.quantize(out.positions), out.faces) == _oriented_triangles(
        grid.quantize(mesh.positions), mesh.faces)


def test_the_weld_attribute_saves_what_the_sequential_coder_costs(kissing):
    from pmwm_codec.format import base as basecodec

    _, data, _ = kissing
    base = pmwm_codec.decode(data, chunks=0)
    grid = Grid.from_config(_ext(_json(data))["grid"])
    edgebreaker = _json(data)["bufferViews"][0]["byteLength"]
    sequential = basecodec._try_draco(grid.quantize(base.positions), base.faces, grid, True, 7)
    assert edgebreaker < len(sequential.data)


def _edited(data, edit):
    gltf, binary = split_glb(data)
    edit(gltf)
    return b"".join(glb_parts(gltf, [binary], len(binary)))


def _no_weld_count(g):
    del _ext(g)["baseVertexCount"]


def _weld_not_scalar(g):
    g["accessors"][_prim_of(g)["attributes"]["_PMWM_WELD"]]["type"] = "VEC2"


def _weld_float(g):
    g["accessors"][_prim_of(g)["attributes"]["_PMWM_WELD"]]["componentType"] = 5126


def _weld_count_off(g):
    g["accessors"][_prim_of(g)["attributes"]["_PMWM_WELD"]]["count"] += 1


def _weld_dropped(g):
    del _prim_of(g)["attributes"]["_PMWM_WELD"]


def _weld_id_missing(g):
    del _prim_of(g)["extensions"]["KHR_draco_mesh_compression"]["attributes"]["_PMWM_WELD"]


def _prim_of(g):
    return g["meshes"][0]["primitives"][0]


@pytest.mark.parametrize("edit, message", [
    (_no_weld_count, "without baseVertexCount"),
    (_weld_not_scalar, "UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR"),
    (_weld_float, "UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR"),
    (_weld_count_off, "values for"),
    (_weld_dropped, "welding gives"),  # the three vertices on one point weld into one
    (_weld_id_missing, "no _PMWM_WELD id"),
], ids=["no-baseVertexCount", "vec2", "float", "count", "dropped", "no-draco-id"])
def test_a_wrong_weld_attribute_is_refused_with_one_line(kissing, tmp_path, capsys, edit, message):
    _, data, _ = kissing
    path = tmp_path / "edited.pmw"
    path.write_bytes(_edited(data, edit))
    assert main(["decode", str(path), "-o", str(tmp_path / "out.obj")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("pmw: error:") and message in err[0], err
    assert not (tmp_path / "out.obj").exists()


@pytest.mark.node
@pytest.mark.skipif(shutil.which("node") is None, reason="node is not on PATH")
@pytest.mark.skipif(not (JS / "node_modules").is_dir(), reason="tools/js/node_modules is absent: run `npm ci --prefix tools/js`")
@pytest.mark.parametrize("which", ["welded", "kissing"])
def test_validator_and_three_js_take_a_welded_file_as_it_is_stored(which, request, tmp_path):
    _, data, _ = request.getfixturevalue(which)
    path = tmp_path / "welded.pmw"
    path.write_bytes(data)
    proc = subprocess.run(["node", str(JS / "check_gltf.mjs"), str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    (result,) = [json.loads(line) for line in proc.stdout.splitlines()]
    assert (result["validator"]["errors"], result["validator"]["warnings"]) == (0, 0), result["validator"]["messages"]
    gltf = _json(data)
    prim = gltf["meshes"][0]["primitives"][0]
    assert result["three"]["ok"] and result["three"]["vertices"] == gltf["accessors"][prim["attributes"]["POSITION"]]["count"]
