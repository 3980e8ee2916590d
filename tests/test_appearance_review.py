"""Review of the OBJ / PLY appearance path (pmwm_codec.meshdoc): cases where it read a file otherwise than the
plain reader (:func:`pmwm_codec.mesh.read_mesh`) does, or named the wrong problem."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import pmwm_codec
from pmwm_codec import meshdoc
from pmwm_codec.format.document import read_accessor
from pmwm_codec.mesh import read_mesh


def _triangles(gltf, buffers) -> set:
    """Every triangle of a document as a frozenset of its corners' positions (rounded to 1e-6)."""
    out = set()
    for prim in gltf["meshes"][0]["primitives"]:
        pos = read_accessor(gltf, buffers, prim["attributes"]["POSITION"])
        tri = read_accessor(gltf, buffers, prim["indices"]).reshape(-1, 3)
        out |= {frozenset(tuple(np.round(p, 6)) for p in pos[t]) for t in tri}
    return out


def _plain_triangles(path) -> set:
    mesh = read_mesh(str(path))
    return {frozenset(tuple(np.round(p, 6)) for p in mesh.positions[t]) for t in mesh.faces}


def _document(path):
    text = path.read_text()
    return meshdoc.obj_document(str(path), text)


_GRID = "".join(f"v {x} {y} {(x * y) % 3}\n" for y in range(4) for x in range(4))
_UVS = "".join(f"vt {x / 3} {y / 3}\n" for y in range(4) for x in range(4))


def test_faces_of_different_corner_forms_whose_slashes_average_one_form_draw_the_triangles_they_name(tmp_path):
    # f 1/4/1 2/5/1 3/6/1 then f 4 5 6: six slashes over six corners, read a column at a time as six v/t corners
    # (1/4 1/2 5/1 | 3/6 1/4 5/6): a wrong triangle and a dropped one, silently
    path = tmp_path / "m.obj"
    path.write_text(_GRID + _UVS + "vn 0 0 1\nf 1/4/1 2/5/1 3/6/1\nf 4 5 6\n")
    (gltf, buffers), _ = _document(path)
    assert _triangles(gltf, buffers) == _plain_triangles(path)


@settings(max_examples=60, deadline=None)
@given(forms=st.lists(st.sampled_from(["v", "v/t", "v//n", "v/t/n"]), min_size=3, max_size=12),
       seed=st.integers(0, 2**16))
@example(forms=["v/t/n"] * 3 + ["v"] * 3, seed=0)
@example(forms=["v/t", "v/t/n", "v"], seed=1)
def test_corners_of_mixed_forms_read_as_the_record_reader_reads_them(forms, seed):
    rng = np.random.default_rng(seed)
    kinds = ["v"] * 16 + ["vt"] * 16 + ["vn"] * 16
    bodies = [f"{i} {i * i} 0" for i in range(16)] + ["0 0"] * 16 + ["0 0 1"] * 16
    for start in range(0, len(forms) - 2, 3):
        corners = []
        for form in forms[start:start + 3]:
            v, t, n = (int(x) for x in rng.integers(1, 17, 3))
            corners.append(form.replace("v", str(v), 1).replace("t", str(t)).replace("n", str(n)))
        kinds.append("f")
        bodies.append(" ".join(corners))
    fast = meshdoc._obj_faces_columns(kinds, bodies, {})
    if fast is None:
        return  # the record reader reads it
    original = meshdoc._obj_faces_columns
    try:
        meshdoc._obj_faces_columns = lambda *a: None
        slow = meshdoc._obj_faces(kinds, bodies, "x", {})
    finally:
        meshdoc._obj_faces_columns = original
    assert np.array_equal(fast[0], slow[0]) and np.array_equal(fast[1], slow[1])


def _jpeg() -> bytes:
    import io

    from PIL import Image

    out = io.BytesIO()
    Image.new("RGB", (8, 8), (200, 10, 10)).save(out, "JPEG")
    return out.getvalue()


_QUAD = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nusemtl m\nf 1/1 2/2 3/3 4/4\n"


@pytest.mark.parametrize("texture", ["a.jpg", "../textures/a.jpg"])
def test_a_texture_named_beside_an_mtl_in_a_subfolder_is_embedded_and_named(tmp_path, texture):
    # mtllib mats/scan.mtl, whose map_Kd a.jpg is mats/a.jpg (Blender and three.js read it there): it was looked
    # for beside the OBJ only, and left out
    (tmp_path / "mats").mkdir()
    (tmp_path / "textures").mkdir()
    at = tmp_path / ("mats/a.jpg" if texture == "a.jpg" else "textures/a.jpg")
    at.write_bytes(_jpeg())
    (tmp_path / "mats" / "scan.mtl").write_text(f"newmtl m\nmap_Kd {texture}\n")
    path = tmp_path / "scan.obj"
    path.write_text("mtllib mats/scan.mtl\n" + _QUAD)
    report = pmwm_codec.encode(str(path), str(tmp_path / "scan.pmw"))
    assert not any("not beside" in n for n in report["notices"]), report["notices"]
    assert _jpeg() in pmwm_codec.decode_asset(str(tmp_path / "scan.pmw"))
    assert str(at) in meshdoc.named_files(str(path))


def test_a_texture_beside_the_obj_is_still_read_when_the_mtl_is_in_a_subfolder(tmp_path):
    (tmp_path / "mats").mkdir()
    (tmp_path / "a.jpg").write_bytes(_jpeg())
    (tmp_path / "mats" / "scan.mtl").write_text("newmtl m\nmap_Kd a.jpg\n")
    path = tmp_path / "scan.obj"
    path.write_text("mtllib mats/scan.mtl\n" + _QUAD)
    pmwm_codec.encode(str(path), str(tmp_path / "scan.pmw"))
    assert _jpeg() in pmwm_codec.decode_asset(str(tmp_path / "scan.pmw"))
    assert str(tmp_path / "a.jpg") in meshdoc.named_files(str(path))


@pytest.mark.parametrize("suffix, text", [
    (".obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 1/1 2/1\n"),
    (".ply", "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
             "property uchar red\nproperty uchar green\nproperty uchar blue\nelement face 1\n"
             "property list uchar int vertex_indices\nend_header\n0 0 0 1 2 3\n1 0 0 1 2 3\n0 1 0 1 2 3\n3 0 0 1\n"),
])
def test_a_file_whose_every_triangle_is_degenerate_says_so_as_the_plain_reader_does(tmp_path, suffix, text):
    # the appearance path said 'the mesh has no vertices or no faces' of a file that has both
    path = tmp_path / ("m" + suffix)
    path.write_text(text)
    with pytest.raises(pmwm_codec.errors.DegenerateMeshError, match="every triangle is degenerate"):
        pmwm_codec.encode(str(path), str(tmp_path / "m.pmw"))
    assert not (tmp_path / "m.pmw").exists()


@pytest.mark.parametrize("statements, alpha", [
    ("Tr 1.000000\n", 1.0),  # MeshLab's (vcglib's) MTL: Tr is its opacity, 1 on every material it writes
    ("d 1\nTr 1\n", 1.0),  # d is the dissolve: it wins over Tr whichever comes first
    ("Tr 1\nd 1\n", 1.0),
    ("Tr 0.25\nd 0.5\n", 0.5),
    ("Tr 0.25\n", 0.75),
    ("d 0.4\n", 0.4),
])
def test_an_mtl_transparency_reads_as_the_alpha_its_writer_meant(statements, alpha):
    # a MeshLab-exported textured OBJ came out with baseColorFactor alpha 0 and alphaMode BLEND: invisible
    (material,) = meshdoc._parse_mtl("newmtl m\nKd 1 1 1\n" + statements + "map_Kd t.png\n")
    assert material.color[3] == pytest.approx(alpha)


def test_a_meshlab_textured_obj_encodes_an_opaque_material(tmp_path):
    (tmp_path / "a.jpg").write_bytes(_jpeg())
    (tmp_path / "scan.obj.mtl").write_text("newmtl material_0\nKa 0.200000 0.200000 0.200000\nKd 1.000000 1.000000 "
                                           "1.000000\nKs 1.000000 1.000000 1.000000\nTr 1.000000\nillum 2\n"
                                           "Ns 0.000000\nmap_Kd a.jpg\n")
    path = tmp_path / "scan.obj"
    path.write_text("mtllib ./scan.obj.mtl\n" + _QUAD.replace("usemtl m", "usemtl material_0"))
    (gltf, _), _ = meshdoc.read_appearance(str(path))
    (material,) = gltf["materials"]
    assert material["pbrMetallicRoughness"]["baseColorFactor"][3] == 1.0 and "alphaMode" not in material
