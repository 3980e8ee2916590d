"""Flat-shaded primitives stream: a NORMAL that is every face's own normal is what a glTF viewer computes for a
primitive without one (glTF 2.0, 3.7.2.1), so it is dropped and the copies it made (one per face around each
position, which kept the whole primitive in the base) are welded into the surface they are."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest
from scipy.spatial import cKDTree

from pmwm_codec import shapes
from pmwm_codec.format.document import read_accessor
from pmwm_codec.stream.asset import FLAT_NORMAL_DEGREES, decode_asset, encode_asset

from test_asset import DocBuilder


def _face_normals(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    p = positions[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    return n / np.linalg.norm(n, axis=1, keepdims=True)


def _corners(sphere) -> np.ndarray:
    """(3m, 3) float32 the corners of ``sphere``'s faces, as :func:`_flat_asset` writes them."""
    return sphere.positions[sphere.faces].reshape(-1, 3).astype(np.float32)


def _corner_uvs(sphere) -> np.ndarray:
    """(3m, 2) float32: the spherical UV of every corner, a face across the wrap taking u past 1 (a seam)."""
    p = _corners(sphere).astype(np.float64)
    u = (np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5).reshape(-1, 3)
    u[(u.max(axis=1) - u.min(axis=1) > 0.5)[:, None] & (u < 0.5)] += 1.0
    return np.stack([u.reshape(-1), p[:, 2] / 4 + 0.5], 1).astype(np.float32)


def _flat_asset(path, *, indexed=True, uv=False, tangent=False, tilt_degrees=0.0, subdivisions=4):
    """A noisy sphere written flat shaded: each face its own three vertices with its face's normal (float32),
    indexed or not; with ``uv`` a spherical TEXCOORD_0 per position (a seam where it wraps), with ``tangent`` a
    TANGENT, with ``tilt_degrees`` the first corner's normal turned by that much.  Returns the sphere."""
    sphere = shapes.icosphere(subdivisions, 1.0, noise=0.01, seed=3)
    corners = _corners(sphere)
    normal = np.repeat(_face_normals(corners.astype(np.float64), np.arange(len(corners)).reshape(-1, 3)), 3, axis=0)
    if tilt_degrees:
        t = np.radians(tilt_degrees)
        side = np.cross(normal[0], [0.0, 0.0, 1.0] if abs(normal[0, 2]) < 0.9 else [1.0, 0.0, 0.0])
        normal[0] = np.cos(t) * normal[0] + np.sin(t) * side / np.linalg.norm(side)
    b = DocBuilder()
    attrs = {"POSITION": b.accessor(corners, 5126, "VEC3", 34962, True),
             "NORMAL": b.accessor(normal.astype(np.float32), 5126, "VEC3", 34962)}
    if uv:
        attrs["TEXCOORD_0"] = b.accessor(_corner_uvs(sphere), 5126, "VEC2", 34962)
    if tangent:
        attrs["TANGENT"] = b.accessor(np.tile(np.float32([1, 0, 0, 1]), (len(corners), 1)), 5126, "VEC4", 34962)
    prim = {"attributes": attrs}
    if indexed:
        prim["indices"] = b.accessor(np.arange(len(corners), dtype=np.uint32), 5125, "SCALAR", 34963)
    b.doc.update({"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [prim]}]})
    path.write_bytes(b.glb())
    return sphere


def _level(glb: bytes) -> tuple:
    """``(attributes {semantic: values}, faces (m, 3))`` of the one primitive of a decoded level."""
    length = struct.unpack("<I", glb[12:16])[0]
    doc, buffers = json.loads(glb[20:20 + length]), [glb[20 + length + 8:]]
    (prim,) = doc["meshes"][0]["primitives"]
    attrs = {k: read_accessor(doc, buffers, i) for k, i in prim["attributes"].items()}
    return attrs, read_accessor(doc, buffers, prim["indices"]).reshape(-1, 3).astype(np.int64)


@pytest.mark.parametrize("indexed", [True, False])
def test_a_flat_shaded_primitive_drops_its_normals_welds_and_streams_looking_the_same(tmp_path, indexed):
    """Before, every position had six copies (three or more: seam corners) and the whole primitive stayed in the
    base.  Now the full level is the welded sphere (its vertex count), every level has no NORMAL, and the faces
    a viewer shades flat from the decoded positions face as the input's normals did."""
    sphere = _flat_asset(tmp_path / "flat.glb", indexed=indexed)
    report = encode_asset(tmp_path / "flat.glb", tmp_path / "flat.pmw", measure=False)
    assert report.vertices == sphere.vertex_count and report.vsplits > 0
    assert report.base_vertices <= 0.05 * sphere.vertex_count
    assert report.notices == [
        f"mesh 0 primitive 0: flat shaded (every NORMAL is its face's normal): NORMAL dropped, so that glTF viewers "
        f"compute the same flat normals at every level, and {3 * sphere.face_count - sphere.vertex_count} copies "
        f"welded; it decodes with {sphere.vertex_count} vertices, without NORMAL"]
    counts = []
    for chunks in (0, 2, None):
        glb, _, _ = decode_asset(tmp_path / "flat.pmw", chunks)
        attrs, faces = _level(glb)
        assert set(attrs) == {"POSITION"}, chunks
        counts.append(len(attrs["POSITION"]))
    assert counts[0] < counts[1] < counts[2] == sphere.vertex_count
    full = attrs["POSITION"].astype(np.float64)
    given = sphere.positions.astype(np.float32).astype(np.float64)
    dist, _ = cKDTree(given).query(full)
    assert dist.max() < 1e-4  # on the grid (16 bits over a sphere of diameter ~2)
    mine = _face_normals(full, faces)
    _, face = cKDTree(given[sphere.faces].mean(axis=1)).query(full[faces].mean(axis=1))
    assert np.array_equal(np.sort(face), np.arange(sphere.face_count))  # every input face, once
    assert (np.einsum("ij,ij->i", mine, _face_normals(given, sphere.faces)[face]) > np.cos(np.radians(0.5))).all()


@pytest.mark.parametrize("case", ["tangent", "tilted", "smooth"])
def test_normals_that_are_not_exactly_flat_are_kept(tmp_path, case):
    """Only a NORMAL a viewer would compute the same goes: not beside a TANGENT (which a viewer ignores without
    NORMAL), not when one corner's normal is turned by more than the tolerance, never a smooth one."""
    if case == "smooth":
        b = DocBuilder()
        prim = b.triangles(shapes.icosphere(4, 1.0, noise=0.01, seed=3))  # NORMAL = the radial direction
        b.doc.update({"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
                      "meshes": [{"primitives": [prim]}]})
        (tmp_path / "in.glb").write_bytes(b.glb())
    else:
        _flat_asset(tmp_path / "in.glb", tangent=case == "tangent",
                    tilt_degrees=4 * FLAT_NORMAL_DEGREES if case == "tilted" else 0.0, subdivisions=3)
    report = encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    assert not any("flat shaded" in n for n in report.notices)
    glb, _, _ = decode_asset(tmp_path / "in.pmw", None)
    assert "NORMAL" in _level(glb)[0]
    if case != "smooth":  # still every position's copies: no split, and the notice says why
        assert report.vsplits == 0 and any("flat shading" in n for n in report.notices)


def test_a_flat_shaded_textured_primitive_keeps_its_uv_seam_and_streams(tmp_path):
    """With TEXCOORD_0 the weld joins the copies of a position that agree in their UV: the seam where the UV wraps
    keeps a copy a side (collapsed in pairs), and every UV comes back on its grid."""
    sphere = _flat_asset(tmp_path / "flat.glb", uv=True)
    report = encode_asset(tmp_path / "flat.glb", tmp_path / "flat.pmw", measure=False)
    assert report.vertices > sphere.vertex_count and report.vsplits > 0  # the seam's copies
    assert report.base_vertices <= 0.05 * report.vertices
    glb, _, _ = decode_asset(tmp_path / "flat.pmw", None)
    attrs, _ = _level(glb)
    assert set(attrs) == {"POSITION", "TEXCOORD_0"}
    given = np.concatenate([_corners(sphere), _corner_uvs(sphere)], axis=1)  # (3m, 5): every input corner
    dist, _ = cKDTree(given).query(np.concatenate([attrs["POSITION"], attrs["TEXCOORD_0"]], axis=1))
    assert dist.max() < 2e-4  # each vertex one of the input's (position, UV) pairs, on the grids
    assert (attrs["TEXCOORD_0"][:, 0] > 1).any()  # the seam's far side came back


def test_a_flat_shaded_pmw_and_its_levels_are_validator_clean_and_three_js_shades_them_flat(tmp_path):
    """The .pmw and a level: no validator error, no issue the input does not have; three.js GLTFLoader gives each a
    material with flatShading (what it does for a primitive without NORMAL) and no normal attribute."""
    from test_gltf_checkers import ALLOWED_INFOS
    from test_gltf_outputs import _check

    _flat_asset(tmp_path / "in.glb")
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    glb, _, _ = decode_asset(tmp_path / "in.pmw", chunks=2)
    (tmp_path / "level2.glb").write_bytes(glb)
    source, *results = _check([tmp_path / "in.glb", tmp_path / "in.pmw", tmp_path / "level2.glb"])
    assert not source["three"]["primitives"][0]["flatShading"]  # the input has its NORMAL
    for result in results:
        report = result["validator"]
        new = set(report["codes"]) - set(source["validator"]["codes"]) - ALLOWED_INFOS  # the .pmw's own
        assert report["errors"] == report["warnings"] == 0 and not new, report
        (prim,) = result["three"]["primitives"]
        assert prim["flatShading"] and "normal" not in prim["attributes"], prim


def test_keep_flat_normals_keeps_them_on_the_command_line_and_in_the_api(tmp_path, capsys):
    """``pmw encode --keep-flat-normals`` (``keep_flat_normals=True``) is for a viewer or a tool that reads NORMAL:
    the primitive keeps it, with every copy, and stays in the base (the notice says why); the option is a flag,
    refused as any other with a value that is not one, and ignored for a mesh file, which has no NORMAL."""
    import pmwm_codec
    from pmwm_codec.cli import main
    from pmwm_codec.errors import OptionError

    sphere = _flat_asset(tmp_path / "flat.glb", subdivisions=3)
    assert main(["encode", str(tmp_path / "flat.glb"), "-o", str(tmp_path / "kept.pmw"), "--keep-flat-normals",
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["vertices"] == 3 * sphere.face_count and report["vsplits"] == 0
    assert any("flat shading" in n for n in report["notices"])
    glb, _, _ = decode_asset(tmp_path / "kept.pmw", None)
    assert "NORMAL" in _level(glb)[0]
    report = pmwm_codec.encode(str(tmp_path / "flat.glb"), str(tmp_path / "api.pmw"), keep_flat_normals=True,
                               measure="none")
    assert report["vsplits"] == 0
    assert pmwm_codec.encode(str(tmp_path / "flat.glb"), str(tmp_path / "dropped.pmw"), measure="none")["vsplits"] > 0
    with pytest.raises(OptionError, match="keep_flat_normals"):
        pmwm_codec.encode(str(tmp_path / "flat.glb"), str(tmp_path / "bad.pmw"), keep_flat_normals="yes")
    assert not (tmp_path / "bad.pmw").exists()
    mesh_file = tmp_path / "sphere.obj"
    pmwm_codec.write_mesh(mesh_file, sphere)
    assert pmwm_codec.encode(str(mesh_file), str(tmp_path / "obj.pmw"), keep_flat_normals=True,
                             measure="none")["vsplits"] > 0
