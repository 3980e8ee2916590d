"""An OBJ's appearance rides with the splits (pmwm_codec.meshdoc): texture coordinates, vertex colours and MTL
materials with their textures come back from the ``.pmw`` at every level, seams closed; the files an OBJ names
are read only inside its folder; an OBJ of geometry alone is encoded exactly as before.
"""

from __future__ import annotations

import io
import json
import os
import re
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

import pmwm_codec
from pmwm_codec import meshdoc, shapes
from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.mesh import read_mesh

from test_seams import unpartnered_edges


def _torus_obj(folder, name="t.obj", *, mtl: str | None = "t.mtl", colours=False, normals=False, rings=24) -> tuple:
    """Write a UV torus as an OBJ (welded positions, a ``vt`` per glTF vertex, ``f v/t`` corners) into ``folder``;
    returns ``(path, positions (p, 3), uv (n, 2) as OBJ stores them, glTF vertex -> position (n,))``."""
    mesh = shapes.uv_torus(rings, 12)
    pos, vid = np.unique(mesh.positions, axis=0, return_inverse=True)
    vid = vid.reshape(-1)
    uv = mesh.attributes["TEXCOORD_0"]
    lines = [f"mtllib {mtl}", "usemtl skin"] if mtl else []
    rgb = (pos - pos.min(0)) / np.ptp(pos, 0)
    for p, c in zip(pos, rgb):
        lines.append("v %.9f %.9f %.9f" % tuple(p) + (" %.6f %.6f %.6f" % tuple(c) if colours else ""))
    lines += ["vt %.9f %.9f" % tuple(t) for t in uv]
    if normals:
        n = pos / np.linalg.norm(pos, axis=1, keepdims=True)
        lines += ["vn %.6f %.6f %.6f" % tuple(v) for v in n]
        lines += ["f " + " ".join(f"{vid[i] + 1}/{i + 1}/{vid[i] + 1}" for i in f) for f in mesh.faces]
    else:
        lines += ["f " + " ".join(f"{vid[i] + 1}/{i + 1}" for i in f) for f in mesh.faces]
    path = os.path.join(folder, name)
    with open(path, "w") as fh:
        fh.write("\n".join(lines) + "\n")
    return path, pos, uv, vid


def _png(path, size=8, colour=(200, 40, 10)) -> bytes:
    Image.new("RGB", (size, size), colour).save(path)
    with open(path, "rb") as fh:
        return fh.read()


def _decoded(pmw, chunks=None) -> tuple:
    """``(gltf, buffers)`` of the ``.pmw`` at ``pmw`` decoded to a GLB (``chunks``: a level)."""
    glb = pmwm_codec.decode_asset(pmw, chunks=chunks)
    path = pmw + (f".{chunks}" if chunks is not None else "") + ".glb"
    with open(path, "wb") as fh:
        fh.write(glb)
    return load_document(path)


def _assert_same_rows(want: np.ndarray, got: np.ndarray, tolerance: float) -> None:
    """``got`` (n, d) holds the rows of ``want`` (n, d), one for one in some order, each within ``tolerance``."""
    from scipy.spatial import cKDTree

    assert len(got) == len(want)
    distance, index = cKDTree(want).query(got)
    assert distance.max() <= tolerance and len(np.unique(index)) == len(want)


def _attribute(gltf, buffers, semantic, prim=0) -> np.ndarray:
    return read_accessor(gltf, buffers, gltf["meshes"][0]["primitives"][prim]["attributes"][semantic])


def test_a_textured_obj_keeps_its_texture_coordinates_material_and_texture(tmp_path):
    path, pos, uv, vid = _torus_obj(str(tmp_path))
    png = _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nKd 0.6 0.6 0.6\nNs 250\nmap_Kd -s 1 1 1 skin.png\n")
    out = str(tmp_path / "t.pmw")
    report = pmwm_codec.encode(path, out)
    assert report["vertices"] == len(uv) and report["base_vertices"] < len(uv) // 4
    gltf, buffers = _decoded(out)
    prim = gltf["meshes"][0]["primitives"][0]
    got_pos = _attribute(gltf, buffers, "POSITION")
    got_uv = _attribute(gltf, buffers, "TEXCOORD_0")
    _assert_same_rows(np.hstack([pos[vid], np.stack([uv[:, 0], 1 - uv[:, 1]], 1)]), np.hstack([got_pos, got_uv]),
                      tolerance=1e-3)  # every (position, uv) pair of the input, v flipped to glTF's convention
    material = gltf["materials"][prim["material"]]
    assert material["name"] == "skin"
    assert material["pbrMetallicRoughness"]["baseColorFactor"] == [1.0, 1.0, 1.0, 1.0]  # the texture is the colour
    assert material["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert material["pbrMetallicRoughness"]["roughnessFactor"] == pytest.approx(0.5)
    image = gltf["images"][gltf["textures"][material["pbrMetallicRoughness"]["baseColorTexture"]["index"]]["source"]]
    view = gltf["bufferViews"][image["bufferView"]]
    assert image["mimeType"] == "image/png"
    assert bytes(buffers[0][view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]]) == png


def test_every_level_of_a_textured_obj_is_closed_along_its_seams(tmp_path):
    path, pos, uv, vid = _torus_obj(str(tmp_path), mtl=None)
    out = str(tmp_path / "t.pmw")
    report = pmwm_codec.encode(path, out)
    for chunks in range(report["chunks"] + 1):
        gltf, buffers = _decoded(out, chunks)
        faces = read_accessor(gltf, buffers, gltf["meshes"][0]["primitives"][0]["indices"]).reshape(-1, 3)
        assert unpartnered_edges(_attribute(gltf, buffers, "POSITION"), faces.astype(np.int64)) == 0, chunks


def test_vertex_colours_come_back_within_the_colour_grid(tmp_path):
    path, pos, uv, vid = _torus_obj(str(tmp_path), mtl=None, colours=True)
    out = str(tmp_path / "t.pmw")
    pmwm_codec.encode(path, out)
    gltf, buffers = _decoded(out)
    got_pos, got_rgb = _attribute(gltf, buffers, "POSITION"), _attribute(gltf, buffers, "COLOR_0")
    rgb = (pos - pos.min(0)) / np.ptp(pos, 0)
    near = np.argmin(((got_pos[:, None, :] - pos[None]) ** 2).sum(-1), axis=1)
    want = meshdoc.linear_from_srgb(rgb)  # an OBJ's colours are sRGB-encoded, glTF's linear
    assert np.abs(got_rgb - want[near]).max() <= 1 / 4095 + 1e-6  # 12-bit colour grid (README)


def test_a_missing_mtl_is_a_notice_and_the_texture_coordinates_still_ride(tmp_path):
    path, *_ = _torus_obj(str(tmp_path), mtl="gone.mtl")
    report = pmwm_codec.encode(path, str(tmp_path / "t.pmw"))
    assert any("'gone.mtl' is not beside t.obj" in n for n in report["notices"])
    gltf, buffers = _decoded(str(tmp_path / "t.pmw"))
    assert "TEXCOORD_0" in gltf["meshes"][0]["primitives"][0]["attributes"] and "materials" not in gltf


def test_a_texture_pillow_reads_but_gltf_does_not_take_is_rewritten_as_png(tmp_path):
    path, *_ = _torus_obj(str(tmp_path))
    Image.new("RGB", (4, 4), (1, 2, 3)).save(tmp_path / "skin.bmp")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.bmp\n")
    report = pmwm_codec.encode(path, str(tmp_path / "t.pmw"))
    assert any("'skin.bmp' re-written as PNG" in n for n in report["notices"])
    gltf, buffers = _decoded(str(tmp_path / "t.pmw"))
    image = gltf["images"][0]
    view = gltf["bufferViews"][image["bufferView"]]
    blob = bytes(buffers[0][view.get("byteOffset", 0):view.get("byteOffset", 0) + view["byteLength"]])
    assert image["mimeType"] == "image/png" and np.asarray(Image.open(io.BytesIO(blob)))[0, 0].tolist() == [1, 2, 3]


@pytest.mark.parametrize("mtl, statement", [
    ("../outside.mtl", None), ("/etc/passwd", None), ("t.mtl", "map_Kd ../outside.png"),
    ("t.mtl", "map_Kd /etc/hostname"), ("t.mtl", "map_Kd link.png"), ("link.mtl", None),
])
def test_an_obj_never_makes_the_encoder_read_outside_its_folder(tmp_path, mtl, statement):
    """A file an OBJ names outside its folder (a path out, an absolute one, a symlink out) is not read: the OBJ
    encodes without it and a notice names it (obj2gltf's secure mode); the output holds none of its bytes."""
    folder = tmp_path / "asset"
    folder.mkdir()
    (tmp_path / "outside.mtl").write_text("newmtl skin\nKd 1 0 0\n")
    outside = _png(tmp_path / "outside.png", colour=(1, 2, 3))
    os.symlink(tmp_path / "outside.png", folder / "link.png")
    os.symlink(tmp_path / "outside.mtl", folder / "link.mtl")
    path, *_ = _torus_obj(str(folder), mtl=mtl)
    (folder / "t.mtl").write_text("newmtl skin\n" + (statement or "") + "\n")
    out = folder / "t.pmw"
    run = subprocess.run([sys.executable, "-m", "pmwm_codec", "encode", path, "-o", str(out)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    named = (statement or mtl).split()[-1]
    assert re.search(rf"'{re.escape(named)}' not read \((leads outside the asset's folder|is an absolute path)", run.stderr)
    glb = pmwm_codec.decode_asset(str(out))
    assert outside not in glb and b"\"Kd\"" not in glb
    gltf = json.loads(glb[20:20 + int.from_bytes(glb[12:16], "little")])
    assert all(m["pbrMetallicRoughness"]["baseColorFactor"][:3] != [1.0, 0.0, 0.0] for m in gltf.get("materials", []))


def test_an_obj_of_geometry_and_normals_encodes_as_before_and_says_so(tmp_path):
    path, pos, uv, vid = _torus_obj(str(tmp_path), mtl=None, normals=True)
    text = re.sub(r"^vt .*\n", "", open(path).read(), flags=re.M)
    text = re.sub(r"(\d+)/\d+/(\d+)", r"\1//\2", text)
    with open(path, "w") as fh:
        fh.write(text)
    plain, through_file = io.BytesIO(), io.BytesIO()
    pmwm_codec.encode(read_mesh(path), plain)
    report = pmwm_codec.encode(path, through_file)
    assert through_file.getvalue() == plain.getvalue()
    assert any(n.startswith("normals (vn) not carried") for n in report["notices"])


def test_the_encode_command_reports_what_it_carried_in_one_json_object(tmp_path):
    path, *_ = _torus_obj(str(tmp_path), mtl="gone.mtl")
    run = subprocess.run([sys.executable, "-m", "pmwm_codec", "encode", path, "-o", str(tmp_path / "t.pmw"), "--json"],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    doc = json.loads(run.stdout)
    assert doc["vertices"] > doc["base_vertices"] and any("gone.mtl" in n for n in doc["notices"])


corner_forms = st.sampled_from(["v", "v/t", "v//n", "v/t/n"])


@settings(max_examples=40, deadline=None)
@given(form=corner_forms, sizes=st.lists(st.integers(3, 6), min_size=1, max_size=12),
       relative=st.booleans(), materials=st.lists(st.sampled_from(["a", "b", "nope"]), max_size=4),
       seed=st.integers(0, 2**16))
def test_the_column_reader_reads_every_face_as_the_record_reader_does(form, sizes, relative, materials, seed):
    rng = np.random.default_rng(seed)
    kinds, bodies, counts = [], [], {"v": 0, "vt": 0, "vn": 0}

    def record(kind, body):
        kinds.append(kind)
        bodies.append(body)
        if kind in counts:
            counts[kind] += 1

    for _ in range(8):
        record("v", "0 0 0")
        record("vt", "0 0")
        record("vn", "0 0 1")
    for i, k in enumerate(sizes):
        if materials and i % 3 == 0:
            record("usemtl", materials[(i // 3) % len(materials)])
        corners = []
        for _ in range(k):
            ids = {kind: int(rng.integers(1, counts[kind] + 1)) for kind in counts}
            if relative and rng.random() < 0.5:
                ids = {kind: ids[kind] - counts[kind] - 1 for kind in ids}
            corners.append(form.replace("v", str(ids["v"]), 1).replace("t", str(ids["vt"])).replace("n", str(ids["vn"])))
        record("f", " ".join(corners))
        record("v", "1 1 1")
    by_name = {"a": 0, "b": 1}
    fast = meshdoc._obj_faces_columns(kinds, bodies, by_name)
    assert fast is not None
    slow = _record_reader(kinds, bodies, by_name)
    assert np.array_equal(fast[0], slow[0]) and np.array_equal(fast[1], slow[1])


def _record_reader(kinds, bodies, by_name):
    original = meshdoc._obj_faces_columns
    try:
        meshdoc._obj_faces_columns = lambda *a: None
        return meshdoc._obj_faces(kinds, bodies, "x", by_name)
    finally:
        meshdoc._obj_faces_columns = original


@pytest.mark.parametrize("face, message", [
    ("f 1/1 2/2 9/3", "face index 9 names no v record"),
    ("f 1/1 2/2 0/3", "face index 0 names no v record"),
    ("f 1/1 2/2 3/x", "malformed OBJ face corner"),
    ("f 1/1 2/2 -4/3", "face index -4 names no v record"),
])
def test_a_face_naming_nothing_is_one_line_naming_it(tmp_path, face, message):
    path = tmp_path / "bad.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n" + face + "\n")
    with pytest.raises(pmwm_codec.PmwError, match=re.escape(message)):
        pmwm_codec.encode(str(path), str(tmp_path / "bad.pmw"))
    assert not (tmp_path / "bad.pmw").exists()


@pytest.mark.parametrize("target", ["t.mtl", "skin.png"])
def test_the_output_never_replaces_a_file_the_obj_names(tmp_path, target):
    path, *_ = _torus_obj(str(tmp_path))
    _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\n")
    before = (tmp_path / target).read_bytes()
    run = subprocess.run([sys.executable, "-m", "pmwm_codec", "encode", path, "-o", str(tmp_path / target)],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "is also the input" in run.stderr and len(run.stderr.splitlines()) == 1
    assert (tmp_path / target).read_bytes() == before


def test_the_files_an_obj_names_are_its_mtl_and_every_material_texture_inside_its_folder(tmp_path):
    path, *_ = _torus_obj(str(tmp_path))
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\nnewmtl other\nnorm -bm 0.5 bump.png\n"
                                    "newmtl out\nmap_Kd ../x.png\nnewmtl gone\nmap_Kd gone.png\n")
    for name in ("skin.png", "bump.png"):
        _png(tmp_path / name)
    _png(tmp_path.parent / "x.png")
    assert meshdoc.named_files(path) == [os.path.realpath(tmp_path / n) for n in ("t.mtl", "skin.png", "bump.png")]


def test_the_files_a_gltf_names_are_its_external_buffers_and_images_inside_its_folder(tmp_path):
    gltf = {"asset": {"version": "2.0"},
            "buffers": [{"uri": "a.bin", "byteLength": 4}, {"uri": "data:application/octet-stream;base64,AAAA",
                                                            "byteLength": 3}],
            "images": [{"uri": "tex%20x.png"}, {"uri": "../escape.png"}, {"uri": "http://host/x.png"},
                       {"uri": "a.bin"}, {"uri": "missing.png"}]}
    (tmp_path / "s.gltf").write_text(json.dumps(gltf))
    (tmp_path / "a.bin").write_bytes(b"\0" * 4)
    _png(tmp_path / "tex x.png")
    _png(tmp_path.parent / "escape.png")
    assert meshdoc.named_files(str(tmp_path / "s.gltf")) == [os.path.realpath(tmp_path / n) for n in ("a.bin", "tex x.png")]


def test_colours_on_only_some_vertices_are_left_out_with_a_notice(tmp_path):
    path = tmp_path / "c.obj"
    mesh = shapes.icosphere(2)
    rows = [f"v {x} {y} {z}" + (" 1 0 0" if i % 2 else "") for i, (x, y, z) in enumerate(mesh.positions)]
    path.write_text("\n".join(rows + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]) + "\n")
    report = pmwm_codec.encode(str(path), io.BytesIO())
    assert any(n.startswith(f"vertex colours left out: {len(rows) // 2:,} of {len(rows):,}") for n in report["notices"])


def test_a_map_statement_of_options_alone_names_no_texture():
    assert meshdoc._map_file("-s 1 1 1".split()) == ""
    assert meshdoc._map_file("-s 1 1 1 1.png".split()) == "1.png"
    assert meshdoc._map_file("-bm 0.5 my skin.png".split()) == "my skin.png"
    assert meshdoc._map_file("-clamp on textures\\skin.png".split()) == "textures/skin.png"


@pytest.mark.parametrize("end", ["\r", "\r\n", "\n"])
def test_an_obj_of_any_line_end_with_comments_reads_every_record(tmp_path, end):
    mesh = shapes.icosphere(1)
    rows = ["# made by hand"] + [f"v {x} {y} {z} # a vertex" for x, y, z in mesh.positions]
    rows += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    (tmp_path / "m.obj").write_bytes(end.join(rows).encode() + end.encode())
    got = read_mesh(str(tmp_path / "m.obj"))
    assert got.vertex_count == len(mesh.positions) and got.face_count == len(mesh.faces)


def test_an_empty_face_record_beside_relative_indices_reads_as_the_record_reader_does(tmp_path):
    # the column reader counted "f" alone among the faces whose relative indices it resolved: a ValueError
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf \nf 1 2 3 -1\n")
    assert read_mesh(str(tmp_path / "m.obj")).faces.tolist() == [[0, 1, 2], [0, 2, 3]]


def _sphere_obj(path, normals: str) -> None:
    """An icosphere with a vt per position and normals: ``smooth`` (one per position) or ``faceted`` (one per
    face, a CAD part's hard edges everywhere)."""
    mesh = shapes.icosphere(3)
    p, f = mesh.positions, mesh.faces
    lines = ["mtllib m.mtl", "usemtl paint"] + ["v %.9f %.9f %.9f" % tuple(x) for x in p]
    lines += ["vt %.6f %.6f" % (0.5 + x[0] / 2, 0.5 + x[1] / 2) for x in p]
    if normals == "smooth":
        lines += ["vn %.6f %.6f %.6f" % tuple(x / np.linalg.norm(x)) for x in p]
        lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{i + 1}" for i in t) for t in f]
    else:
        n = np.cross(p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]])
        lines += ["vn %.6f %.6f %.6f" % tuple(x / np.linalg.norm(x)) for x in n]
        lines += ["f " + " ".join(f"{i + 1}/{i + 1}/{k + 1}" for i in t) for k, t in enumerate(f)]
    path.write_text("\n".join(lines) + "\n")
    (path.parent / "m.mtl").write_text("newmtl paint\nKd 0.2 0.4 0.8\n")


def test_hard_edged_normals_that_would_keep_the_mesh_in_its_base_are_not_carried_and_smooth_ones_are(tmp_path):
    _sphere_obj(tmp_path / "faceted.obj", "faceted")
    report = pmwm_codec.encode(str(tmp_path / "faceted.obj"), str(tmp_path / "faceted.pmw"))
    assert any(n.startswith("normals not carried in the faces of material 'paint': their hard edges would keep 642 of its 642")
               for n in report["notices"]), report["notices"]
    assert report["vertices"] == 642 and report["base_vertices"] < 100  # it streams
    gltf, _ = _decoded(str(tmp_path / "faceted.pmw"))
    assert "NORMAL" not in gltf["meshes"][0]["primitives"][0]["attributes"]
    _sphere_obj(tmp_path / "smooth.obj", "smooth")
    report = pmwm_codec.encode(str(tmp_path / "smooth.obj"), str(tmp_path / "smooth.pmw"))
    assert not any("normals" in n for n in report["notices"]) and report["base_vertices"] < 100
    gltf, _ = _decoded(str(tmp_path / "smooth.pmw"))
    assert sorted(gltf["meshes"][0]["primitives"][0]["attributes"]) == ["NORMAL", "POSITION", "TEXCOORD_0"]


@pytest.mark.parametrize("statement", ["map_Kd C:\\maps\\skin.png", "map_Kd ../elsewhere/skin.png",
                                       "map_Kd /home/artist/skin.png", 'map_Kd "skin.png"'])
def test_a_texture_named_by_a_path_that_finds_nothing_is_read_by_its_name_beside_the_obj(tmp_path, statement):
    """As obj2gltf and Blender do: a Windows exporter's absolute path, a path out of the folder or one that
    names nothing is looked for by its file name beside the OBJ (never outside it); quotes are not the name."""
    path, *_ = _torus_obj(str(tmp_path))
    blob = _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text(f"newmtl skin\n{statement}\n")
    report = pmwm_codec.encode(path, str(tmp_path / "t.pmw"))
    assert pmwm_codec.decode_asset(str(tmp_path / "t.pmw")).count(blob) == 1
    if '"' not in statement:
        assert any(n.endswith("read as 'skin.png', beside t.obj") for n in report["notices"]), report["notices"]


def test_obj_colours_of_0_to_1_rounded_just_over_1_are_not_taken_for_bytes(tmp_path):
    path = tmp_path / "c.obj"
    mesh = shapes.icosphere(1)
    rows = [f"v {x} {y} {z} 1.0000001 0.5 0.25" for x, y, z in mesh.positions]
    path.write_text("\n".join(rows + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]) + "\n")
    pmwm_codec.encode(str(path), str(tmp_path / "c.pmw"))
    gltf, buffers = _decoded(str(tmp_path / "c.pmw"))
    want = meshdoc.linear_from_srgb(np.array([[1.0, 0.5, 0.25]]))[0]
    assert np.abs(_attribute(gltf, buffers, "COLOR_0") - want).max() < 1e-3


def test_a_texture_found_by_its_name_is_among_the_files_the_obj_names(tmp_path):
    path, *_ = _torus_obj(str(tmp_path))
    _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd C:\\maps\\skin.png\n")
    assert meshdoc.named_files(path) == [os.path.realpath(tmp_path / n) for n in ("t.mtl", "skin.png")]


def test_geometry_only_encodes_a_textured_obj_as_its_positions_and_faces_alone(tmp_path):
    path, *_ = _torus_obj(str(tmp_path))
    _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\n")
    plain, through_file = io.BytesIO(), io.BytesIO()
    pmwm_codec.encode(read_mesh(path), plain)
    report = pmwm_codec.encode(path, through_file, geometry_only=True)
    assert through_file.getvalue() == plain.getvalue() and report["notices"] == []
    run = subprocess.run([sys.executable, "-m", "pmwm_codec", "encode", path, "-o", str(tmp_path / "g.pmw"),
                          "--geometry-only", "--json"], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "g.pmw").read_bytes() == plain.getvalue()
    with pytest.raises(pmwm_codec.PmwError, match="geometry_only takes a mesh file"):
        pmwm_codec.encode(meshdoc.read_appearance(path)[0], io.BytesIO(), geometry_only=True)


def test_a_seventh_number_on_a_coloured_v_record_is_an_alpha_after_the_colour_as_three_js_reads_it(tmp_path):
    path, pos, uv, vid = _torus_obj(str(tmp_path), mtl=None, colours=True)
    text = open(path).read()
    with_alpha = re.sub(r"^(v .*)$", r"\1 0.5", text, flags=re.M)  # v x y z r g b a
    (tmp_path / "a.obj").write_text(with_alpha)
    (doc, buffers), _ = meshdoc.read_source(str(tmp_path / "a.obj"))
    (want, want_buffers), _ = meshdoc.read_source(path)
    assert np.array_equal(_attribute(doc, buffers, "COLOR_0"), _attribute(want, want_buffers, "COLOR_0"))
