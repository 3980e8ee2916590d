"""``pmwm_codec.write_mesh`` / ``write_asset``: every format read back, atomic writes, GLB framing."""

from __future__ import annotations

import codecs
import os
import json
import re
import stat

import numpy as np
import pygltflib
import pytest

import pmwm_codec
from pmwm_codec.atomic import current_umask
from pmwm_codec import shapes
from pmwm_codec.format.parser import parse_preamble
from pmwm_codec.meshio import WRITE_SUFFIXES, write_asset, write_mesh


@pytest.fixture(scope="module")
def mesh():
    return shapes.icosphere(2, 1.0, noise=0.02)


def same_triangles(a, b) -> bool:
    """Same triangles (as float32 corner sets), whatever the vertex order and numbering."""
    def key(m):
        tri = np.asarray(m.positions, np.float32)[m.faces].reshape(-1, 9)
        return sorted(map(tuple, np.sort(tri, axis=1).tolist()))
    return key(a) == key(b)


@pytest.mark.parametrize("suffix", WRITE_SUFFIXES)
def test_every_format_reads_back_with_read_mesh(mesh, tmp_path, suffix):
    path = tmp_path / f"m{suffix}"
    write_mesh(path, mesh)
    back = pmwm_codec.read_mesh(path)
    assert (back.vertex_count, back.face_count) == (mesh.vertex_count, mesh.face_count)
    assert same_triangles(back, mesh)
    if suffix != ".stl":  # STL stores corners, not a vertex order
        assert np.array_equal(back.positions.astype(np.float32), mesh.positions.astype(np.float32))  # float32 exact
        assert np.array_equal(back.faces, mesh.faces)
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written == [path.name]  # no temp file left, no second file (a .gltf's buffer is inline)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~current_umask()  # the umask decides


def test_glb_is_framed_by_glb_parts_and_loads_in_pygltflib(mesh, tmp_path):
    path = tmp_path / "m.glb"
    write_mesh(path, mesh)
    data = path.read_bytes()
    total, json_length = parse_preamble(data)
    assert total == len(data) and len(data) % 4 == 0
    gltf = pygltflib.GLTF2.load(str(path))
    prim = gltf.meshes[0].primitives[0]
    assert gltf.accessors[prim.attributes.POSITION].count == mesh.vertex_count
    assert gltf.accessors[prim.indices].count == 3 * mesh.face_count
    assert gltf.accessors[prim.indices].componentType == pygltflib.UNSIGNED_INT


def test_gltf_is_self_contained_and_never_replaces_the_bin_beside_it(mesh, tmp_path):
    """A .gltf's buffer went to ``<stem>.bin``: a file the caller never named was replaced, and its
    name went into the URI unescaped (``x%41.gltf`` read its buffer back from ``xA.bin``)."""
    (tmp_path / "x%41.bin").write_bytes(b"the caller's own data")
    write_mesh(tmp_path / "xA.gltf", shapes.icosphere(2))
    write_mesh(tmp_path / "x%41.gltf", mesh)
    assert (tmp_path / "x%41.bin").read_bytes() == b"the caller's own data"
    doc = json.loads((tmp_path / "x%41.gltf").read_text())
    assert doc["buffers"][0]["uri"].startswith("data:application/octet-stream;base64,")
    assert same_triangles(pmwm_codec.read_mesh(tmp_path / "x%41.gltf"), mesh)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x%41.bin", "x%41.gltf", "xA.gltf"]


def test_stl_is_binary_with_unit_normals(mesh, tmp_path):
    path = tmp_path / "m.stl"
    write_mesh(path, mesh)
    data = path.read_bytes()
    count = int(np.frombuffer(data, "<u4", 1, 80)[0])
    assert count == mesh.face_count and len(data) == 84 + 50 * count
    rec = np.frombuffer(data, [("n", "<f4", (3,)), ("v", "<f4", (3, 3)), ("a", "<u2")], count, 84)
    assert np.allclose(np.linalg.norm(rec["n"], axis=1), 1.0, atol=1e-5)
    corners = mesh.positions.astype(np.float32)[mesh.faces]
    assert np.array_equal(rec["v"], corners)
    assert np.all((rec["n"] * np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])).sum(1) > 0)


def test_a_failed_write_leaves_the_old_file(mesh, tmp_path):
    path = tmp_path / "m.obj"
    path.write_text("old")
    with pytest.raises(ValueError, match="unknown output format"):
        write_mesh(tmp_path / "m.xyz", mesh)
    broken = pmwm_codec.Mesh(mesh.positions, mesh.faces[:, :2])  # not triangles: the writer fails
    with pytest.raises(Exception):
        write_mesh(path, broken)
    assert path.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["m.obj"]


def test_write_asset_writes_glb_and_self_contained_gltf(mesh, tmp_path):
    src = tmp_path / "src.glb"
    write_mesh(src, mesh)
    glb = src.read_bytes()
    write_asset(tmp_path / "copy.glb", glb)
    write_asset(tmp_path / "copy.gltf", glb)
    assert (tmp_path / "copy.glb").read_bytes() == glb
    doc = json.loads((tmp_path / "copy.gltf").read_text())
    assert doc["buffers"][0]["uri"].startswith("data:application/octet-stream;base64,")
    assert same_triangles(pmwm_codec.read_mesh(tmp_path / "copy.gltf"), mesh)
    with pytest.raises(ValueError):
        write_asset(tmp_path / "copy.obj", glb)


# --- OBJ reading: the column-at-a-time reader gives what the record-by-record reader gives ---------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from pmwm_codec import mesh as mesh_mod  # noqa: E402

coordinate = st.one_of(st.floats(-1e6, 1e6, allow_nan=False), st.integers(-1000, 1000))


@st.composite
def obj_documents(draw):
    """``(text, positions, faces)``: OBJ text with uniform or mixed records and the arrays it means.

    One to three objects, each its vertices then its faces (so a negative index counts back from the
    vertices read before its record, not from the end of the file); extra vertex fields, polygons of
    3-5 vertices (fan-triangulated), indices written plain / ``i/t`` / ``i//n`` / ``i/t/n`` (the ``vt`` and ``vn``
    records they name written first), 1-based or
    negative, keywords indented or followed by tabs, comments and blank lines."""
    extra = draw(st.sampled_from([0, 0, 1, 3]))
    fmt = draw(st.sampled_from(["{:.9g}", "{!r}", "{:.3e}", "{}"]))
    sizes = draw(st.sampled_from([[3], [4], [5], [3, 4]]))
    style = draw(st.sampled_from(["{}", "{}/{}", "{}//{}", "{}/{}/{}"]))
    loose = draw(st.booleans())
    lines, positions, faces = [], [], []

    def head(keyword):
        return draw(st.sampled_from([keyword + " ", keyword + "\t", "  " + keyword + " ", "\t" + keyword + "  "])) \
            if loose else keyword + " "

    if "/" in style:  # the texture coordinate and normal the corners name (1): a record of each, before any face
        lines += [head("vt") + "0.5 0.5", head("vn") + "0 0 1"]
    for _ in range(draw(st.integers(1, 3))):
        if lines and draw(st.booleans()):
            lines.append("o part")
        for _ in range(draw(st.integers(5, 9))):
            values = [fmt.format(float(draw(coordinate))) for _ in range(3 + extra)]
            lines.append(head("v") + " ".join(values))
            positions.append([float(x) for x in values[:3]])
        read = len(positions)
        for _ in range(draw(st.integers(1, 6))):
            k = draw(st.sampled_from(sizes))
            ids = draw(st.lists(st.integers(0, read - 1), min_size=k, max_size=k, unique=True))
            written = [i - read if draw(st.booleans()) and draw(st.booleans()) else i + 1 for i in ids]
            lines.append(head("f") + " ".join(style.format(i, 1, 1) for i in written))
            faces.extend((ids[0], ids[j], ids[j + 1]) for j in range(1, k - 1))
    if draw(st.booleans()):
        lines.insert(draw(st.integers(0, len(lines))), draw(st.sampled_from(["# a comment", "", "vn 0 0 1", "o part"])))
    return "\n".join(lines) + "\n", np.array(positions, np.float64), np.array(faces, np.int64)


@st.composite
def obj_files(draw):
    return draw(obj_documents())[0]


def _read_by_records(path):
    saved = mesh_mod._read_obj_columns
    mesh_mod._read_obj_columns = lambda text, lines: None
    try:
        return mesh_mod._read_obj(path, "m.obj")
    finally:
        mesh_mod._read_obj_columns = saved


@settings(max_examples=200, deadline=None)
@given(obj_files())
def test_the_column_reader_gives_the_record_readers_arrays_or_leaves_the_file_to_it(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("obj") / "m.obj"
    path.write_text(text)
    normalized = mesh_mod._obj_normalized(text)
    columns = mesh_mod._read_obj_columns(normalized, normalized.splitlines())
    positions, faces = _read_by_records(str(path))
    if columns is not None:
        assert columns[0].dtype == positions.dtype and columns[1].dtype == faces.dtype
        assert np.array_equal(columns[0], positions) and np.array_equal(columns[1], faces)
    got = mesh_mod._read_obj(str(path), "m.obj")
    assert np.array_equal(got[0], positions) and np.array_equal(got[1], faces)


def test_a_plain_triangle_obj_takes_the_column_reader(mesh, tmp_path):
    path = tmp_path / "m.obj"
    write_mesh(path, mesh)
    text = path.read_text()
    assert mesh_mod._read_obj_columns(text, text.splitlines()) is not None


@settings(max_examples=200, deadline=None)
@given(obj_documents())
def test_obj_records_mean_what_the_obj_format_says(tmp_path_factory, document):
    """Negative indices count back from the vertices read so far (two objects each written with
    ``f -4 -3 -2`` keep their own vertices); indented records and tabs after the keyword are records."""
    text, positions, faces = document
    path = tmp_path_factory.mktemp("obj") / "m.obj"
    path.write_text(text)
    got = mesh_mod._read_obj(str(path), "m.obj")
    assert np.array_equal(got[0], positions) and np.array_equal(got[1], faces)


def test_a_negative_index_before_the_first_vertex_is_named(tmp_path):
    path = tmp_path / "m.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nf -1 -2 -3\nv 0 1 0\n")
    with pytest.raises(mesh_mod.InputFormatError, match="face index -3 counts back past the first vertex"):
        mesh_mod._read_obj(str(path), "m.obj")


def test_an_obj_edge_written_as_a_two_vertex_face_is_dropped_as_degenerate_not_refused(tmp_path):
    """A scene exported with some edges as ``f a b`` records (a 10 MB robotics scene has 201 among its 125k
    faces; Blender reads them as edges) was refused whole ("a face with fewer than 3 vertices"): such a record
    is a degenerate face, dropped and counted as one naming a vertex twice is, and the encode says so."""
    mesh = shapes.icosphere(1)
    text = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in mesh.positions)
    text += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces[:10])
    text += "f 1 2\nf -1\n" + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces[10:])
    (tmp_path / "edges.obj").write_text(text)
    got = pmwm_codec.read_mesh(tmp_path / "edges.obj")
    assert np.array_equal(got.positions, mesh.positions) and np.array_equal(got.faces, mesh.faces)
    assert got.cleanup == {"degenerate_faces": 2}
    report = pmwm_codec.encode(tmp_path / "edges.obj", tmp_path / "edges.pmw", measure="none")
    assert "dropped 2 degenerate faces" in report["notices"]


@pytest.mark.parametrize("quad", [False, True], ids=["triangles", "with-a-quad"])
def test_an_obj_face_record_without_indices_is_skipped_by_either_reader(tmp_path, quad):
    """A blank ``f`` record (``f`` and spaces) was skipped when every other face was a triangle (the column
    reader) and refused the whole file ("a face with no vertices") when one was a quad (the record reader): the
    same record, two answers.  It names nothing: both readers skip it."""
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf  \n" + ("f 2 4 3 1\n" if quad else "f 2 4 3\n")
    (tmp_path / "blank.obj").write_text(text)
    got = pmwm_codec.read_mesh(tmp_path / "blank.obj")
    expected = [[0, 1, 2], [1, 3, 2], [1, 2, 0]] if quad else [[0, 1, 2], [1, 3, 2]]
    assert got.faces.tolist() == expected and got.vertex_count == 4


def _soup_text(mesh, normals: bool) -> str:
    """OBJ of ``mesh`` as a flat-shaded exporter writes it: every face corner its own ``v`` (and ``vn``)."""
    corners = mesh.positions[mesh.faces.reshape(-1)]
    text = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in corners)
    if normals:
        text += "vn 0 0 1\n" + "".join(f"f {i + 1}//1 {i + 2}//1 {i + 3}//1\n" for i in range(0, len(corners), 3))
    else:
        text += "".join(f"f {i + 1} {i + 2} {i + 3}\n" for i in range(0, len(corners), 3))
    return text


@pytest.mark.parametrize("normals", [True, False], ids=["with-vn", "plain"])
def test_a_flat_shaded_obj_soup_is_welded_and_becomes_progressive(tmp_path, normals):
    """An OBJ written as a triangle soup (every face corner its own vertex, as flat-shaded exports with per-face
    normals write robot collision meshes) read as one vertex per corner: every position had a copy per face
    around it, all stayed in the base and the file had no vertex split.  The reader drops the normals, so the
    copies are exact duplicates: they are welded, as STL corners and glTF soups are, and the encode says so."""
    mesh = shapes.icosphere(3, noise=0.01)
    (tmp_path / "soup.obj").write_text(_soup_text(mesh, normals))
    got = pmwm_codec.read_mesh(tmp_path / "soup.obj")
    assert got.vertex_count == mesh.vertex_count and got.face_count == mesh.face_count
    assert np.array_equal(got.positions[got.faces], mesh.positions[mesh.faces])  # the same triangles, corner for corner
    assert got.cleanup == {"duplicate_soup_vertices": 3 * mesh.face_count - mesh.vertex_count}
    report = pmwm_codec.encode(tmp_path / "soup.obj", tmp_path / "soup.pmw", measure="none")
    indexed = pmwm_codec.encode(mesh, tmp_path / "indexed.pmw", measure="none")
    assert report["vsplits"] == indexed["vsplits"] > 0.9 * mesh.vertex_count
    assert f"dropped {3 * mesh.face_count - mesh.vertex_count} duplicate soup vertices" in report["notices"]


def test_an_indexed_obj_keeps_its_duplicate_positions_as_stored(tmp_path):
    """Only a soup is welded: an OBJ whose faces share vertices is indexed by its author, duplicates and all."""
    mesh = shapes.uv_torus(16, 8)  # a seam: positions written twice, faces sharing vertices
    assert len(np.unique(mesh.positions, axis=0)) < mesh.vertex_count
    write_mesh(tmp_path / "seam.obj", mesh)
    got = pmwm_codec.read_mesh(tmp_path / "seam.obj")
    assert got.vertex_count == mesh.vertex_count and got.cleanup == {}


def test_an_obj_saved_with_a_byte_order_mark_reads_its_first_vertex(tmp_path):
    """A UTF-8 byte-order mark (Notepad's "UTF-8 with BOM") hid the first ``v`` record: every face then named
    the vertex after the one meant, and the mesh encoded with exit 0 as the wrong triangles."""
    text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\n"
    (tmp_path / "bom.obj").write_bytes(b"\xef\xbb\xbf" + text.encode())
    (tmp_path / "plain.obj").write_text(text)
    with_bom, plain = pmwm_codec.read_mesh(tmp_path / "bom.obj"), pmwm_codec.read_mesh(tmp_path / "plain.obj")
    assert np.array_equal(with_bom.positions, plain.positions) and np.array_equal(with_bom.faces, plain.faces)
    assert with_bom.positions[with_bom.faces[0]].tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]


@pytest.mark.parametrize("encoding", ["latin-1", "utf-16-be", "utf-16-le", "utf-32"])
def test_an_obj_in_an_eight_bit_code_page_or_marked_utf16_reads_as_its_records(tmp_path, encoding):
    """An OBJ whose material name is in Latin-1 (3ds Max's Max2Obj: ``usemtl Terraind\\xe6k``, assimp's regr01.obj)
    or that an editor saved as UTF-16 with its byte order mark (assimp's box_UTF16BE.obj) was refused whole as "not a
    text OBJ file": its ``v`` / ``f`` records are plain ASCII and read the same."""
    text = "# d\u00e6k\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\ng Terraind\u00e6k\nusemtl Terraind\u00e6k\nf 1 2 3\nf 2 4 3\n"
    mark = {"latin-1": b"", "utf-16-be": codecs.BOM_UTF16_BE, "utf-16-le": codecs.BOM_UTF16_LE, "utf-32": b""}[encoding]
    (tmp_path / "coded.obj").write_bytes(mark + text.encode(encoding))
    (tmp_path / "plain.obj").write_text(text, encoding="utf-8")
    coded, plain = pmwm_codec.read_mesh(tmp_path / "coded.obj"), pmwm_codec.read_mesh(tmp_path / "plain.obj")
    assert np.array_equal(coded.positions, plain.positions) and np.array_equal(coded.faces, plain.faces)
    assert plain.face_count == 2


@pytest.mark.parametrize("data", [b"v 0 0 0\x00\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", b"\xff\xfe\x00\xd8v\x00"])
def test_binary_data_named_obj_is_refused_as_not_text(tmp_path, data):
    """Latin-1 reads any byte: a NUL byte (no OBJ has one) or text its own byte order mark does not describe is
    still refused in one line, not read as records."""
    (tmp_path / "bin.obj").write_bytes(data)
    with pytest.raises(mesh_mod.InputFormatError, match="not a text OBJ file"):
        pmwm_codec.read_mesh(tmp_path / "bin.obj")


def test_an_obj_face_index_0_is_named_as_obj_counting_from_1(tmp_path):
    """``f 0 7 8 5`` (assimp's invalid/malformed.obj) was refused as "cannot name a vertex (at most 4,194,304)",
    a limit it is nowhere near; index 0 is what OBJ's numbering from 1 leaves out."""
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 0 2 3\n")
    with pytest.raises(mesh_mod.InputFormatError, match="face index 0 names no vertex .OBJ counts vertices from 1"):
        pmwm_codec.read_mesh(tmp_path / "m.obj")


@pytest.mark.parametrize("cut", [False, True])
def test_a_ply_point_cloud_is_named_as_one_cut_short_or_not(tmp_path, cut):
    """A PLY that declares vertices and no faces (a scan's point cloud, assimp's pond.0.ply, 69 bytes short) was
    refused as trimesh's "cannot read as PLY: PLY is unexpected length!": the header already says what it is."""
    from pmwm_codec.errors import MeshError

    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              "property float z\nend_header\n").encode()
    body = np.arange(9, dtype="<f4").tobytes()
    (tmp_path / "cloud.ply").write_bytes(header + (body[:-5] if cut else body))
    with pytest.raises(MeshError, match="cloud.ply: the file holds no triangle mesh .its PLY header declares 3 "
                                        "vertices and no faces: a point cloud"):
        pmwm_codec.read_mesh(tmp_path / "cloud.ply")


ASCII_FACET = "facet normal 0 0 1\n outer loop\n  vertex 0 0 0\n  vertex 1 0 0\n  vertex 0 1 0\n endloop\nendfacet\n"


@pytest.mark.parametrize("body, words", [
    (ASCII_FACET + ASCII_FACET.replace("vertex 0 1 0\n", "vertex 0 1 0\n  vertex 1 1 0\n"),
     "malformed ASCII STL: the facet at line 10 has 4 vertex records, not three"),
    (ASCII_FACET.replace("vertex 0 1 0\n", "vertex 0 1 0\n  vertex 1 1 0\n") + ASCII_FACET.replace("  vertex 0 1 0\n", ""),
     "malformed ASCII STL: the facet at line 3 has 4 vertex records, not three"),  # 6 records: read as 2 wrong triangles
    (ASCII_FACET + ASCII_FACET.replace("vertex 1 0 0", "vertex 1 0 blah"), "malformed ASCII STL record (line 12): 'vertex 1 0 blah'"),
    (ASCII_FACET.replace("vertex 0 0 0", "vertex 0 0"), "malformed ASCII STL record (line 4): 'vertex 0 0'"),
])
def test_a_malformed_ascii_stl_is_named_by_its_record(tmp_path, body, words):
    """OpenSCAD's test STLs: a facet of four vertices was refused in numpy's words ("cannot reshape array of size
    40 into shape (3)"), a vertex of text in numpy's ("could not be read to its end due to unmatched data"); a
    facet of four beside a facet of two was read as two wrong triangles, exit 0."""
    (tmp_path / "m.stl").write_text("solid m\n" + body + "endsolid m\n")
    with pytest.raises(mesh_mod.InputFormatError) as exc:
        pmwm_codec.read_mesh(tmp_path / "m.stl")
    assert str(exc.value) == "m.stl: " + words


def test_a_well_formed_ascii_stl_still_reads(tmp_path):
    (tmp_path / "m.stl").write_text("solid m\n" + ASCII_FACET + ASCII_FACET.replace("0 0 0", "1 1 1e+0") + "endsolid m\n")
    assert pmwm_codec.read_mesh(tmp_path / "m.stl").face_count == 2


def test_an_ascii_stl_in_capitals_reads_and_one_cut_before_endsolid_is_named(tmp_path):
    """Some CAD exporters write the keywords in capitals: such a file was taken for a binary STL "declaring
    1,347,374,924 triangles"; a file cut before its ``endsolid`` was "no triangle mesh"."""
    (tmp_path / "up.stl").write_text(("solid m\n" + ASCII_FACET + ASCII_FACET.replace("0 0 0", "1 1 1") +
                                      "endsolid m\n").upper())
    assert pmwm_codec.read_mesh(tmp_path / "up.stl").face_count == 2
    (tmp_path / "cut.stl").write_text("solid m\n" + ASCII_FACET)
    with pytest.raises(mesh_mod.InputFormatError, match=r"^cut.stl: an ASCII STL without its closing 'endsolid' \(cut short\)$"):
        pmwm_codec.read_mesh(tmp_path / "cut.stl")


def _facets(*triangles) -> str:
    return "".join("facet normal 0 0 1\n outer loop\n" + "".join(f"  vertex {x} {y} {z}\n" for x, y, z in t)
                   + " endloop\nendfacet\n" for t in triangles)


SQUARE = ([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [(1, 0, 0), (1, 1, 0), (0, 1, 0)])


def _corners(m) -> list:
    return sorted(tuple(tuple(p) for p in m.positions[f]) for f in m.faces.tolist())


def test_a_vertex_record_of_four_numbers_beside_one_of_two_is_refused_not_read_as_other_corners(tmp_path):
    """``vertex 1 0 0 7`` and ``vertex 0 1`` make up six numbers between them: the three-a-facet count held, and the
    file was read with corners (7, 0, 1) and (0, 1, ...) that it does not hold, exit 0."""
    body = (_facets(SQUARE[0]).replace("vertex 1 0 0\n", "vertex 1 0 0 7\n")
            + _facets(SQUARE[1]).replace("vertex 0 1 0\n", "vertex 0 1\n"))
    (tmp_path / "m.stl").write_text("solid m\n" + body + "endsolid m\n")
    with pytest.raises(mesh_mod.InputFormatError, match=r"^m.stl: malformed ASCII STL record \(line 5\): 'vertex 1 0 0 7'$"):
        pmwm_codec.read_mesh(tmp_path / "m.stl")


@pytest.mark.parametrize("solid", ["vertex_colours", "vertex 5 6 7", "normal"])
def test_an_ascii_stl_whose_solid_is_named_with_a_keyword_reads(tmp_path, solid):
    """A solid named ``vertex_colours`` was refused in numpy's words ("could not be read to its end due to
    unmatched data"), one named ``vertex 5 6 7`` as "cannot reshape array of size 7 into shape (3)": the name was
    read as a vertex record."""
    (tmp_path / "m.stl").write_text(f"solid {solid}\n" + _facets(*SQUARE) + f"endsolid {solid}\n")
    got = pmwm_codec.read_mesh(tmp_path / "m.stl")
    assert _corners(got) == sorted(tuple(map(tuple, np.asarray(t, float))) for t in SQUARE)


@pytest.mark.parametrize("codec", ["utf-8", "latin-1"])
def test_an_ascii_stl_whose_solid_name_is_not_ascii_reads(tmp_path, codec):
    """``solid Würfel`` was taken for a binary STL: "STL declares 1,695,166,496 triangles"."""
    (tmp_path / "m.stl").write_bytes(("solid Würfel\n" + _facets(*SQUARE) + "endsolid Würfel\n").encode(codec))
    assert pmwm_codec.read_mesh(tmp_path / "m.stl").face_count == 2


def test_an_ascii_stl_of_several_solids_and_crlf_reads_every_solid(tmp_path):
    text = "solid a\n" + _facets(SQUARE[0]) + "endsolid a\nsolid b\n" + _facets(SQUARE[1]) + "endsolid b\n"
    (tmp_path / "m.stl").write_bytes(text.replace("\n", "\r\n").encode())
    assert pmwm_codec.read_mesh(tmp_path / "m.stl").face_count == 2


def test_facets_after_the_closing_endsolid_are_refused_not_dropped(tmp_path):
    """A facet after ``endsolid`` and before any ``solid``, or in a second solid cut short, was left out without a
    word."""
    for tail in ("", "solid n\n"):
        (tmp_path / "m.stl").write_text("solid m\n" + _facets(SQUARE[0]) + "endsolid m\n" + tail + _facets(SQUARE[1]))
        with pytest.raises(mesh_mod.InputFormatError, match=r"^m.stl: an ASCII STL with facets after its last "
                                                            r"'endsolid' \(a solid cut short, or facets outside any solid\)$"):
            pmwm_codec.read_mesh(tmp_path / "m.stl")


def test_a_binary_stl_whose_header_reads_as_ascii_keywords_is_read_as_binary(tmp_path):
    """A binary STL is told by its size: a header ``solid part facet`` over triangles whose bytes are all ASCII (zero
    normals, whole coordinates) was taken for an ASCII STL and refused ("without its closing 'endsolid'")."""
    data = b"solid part facet".ljust(80, b" ") + (2).to_bytes(4, "little")
    for t in SQUARE:
        data += np.array([0, 0, 0, *np.asarray(t, float).ravel() * 2], "<f4").tobytes() + b"  "
    assert data[84:].decode("ascii")  # the whole file is ASCII
    (tmp_path / "m.stl").write_bytes(data)
    got = pmwm_codec.read_mesh(tmp_path / "m.stl")
    assert _corners(got) == sorted(tuple(map(tuple, np.asarray(t, float) * 2)) for t in SQUARE)


def test_an_obj_comment_after_a_record_is_a_comment(tmp_path):
    (tmp_path / "c.obj").write_text("# a cube's corner\nv 0 0 0 # origin\nv 1 0 0\nv 0 1 0\nf 1 2 3 # the one face\n")
    mesh = pmwm_codec.read_mesh(tmp_path / "c.obj")
    assert mesh.vertex_count == 3 and mesh.faces.tolist() == [[0, 1, 2]]


@pytest.mark.parametrize("end", ["\n", "\r\n"])
def test_an_obj_record_continued_by_a_backslash_reads_as_one_record(tmp_path, end):
    """The OBJ format joins a line ending in a backslash to the next (trimesh and Blender read so); both OBJ
    readers refused such a file as "malformed OBJ record: 'f 1 2 \\'" (exit 2)."""
    rows = ["v 0 0 \\", "  0", "v 1 0 0", "v 1 1 0", "v 0 1 0", "f 1 2 \\", "3", "f 1\\", "3 4"]
    (tmp_path / "m.obj").write_bytes(end.join(rows).encode() + end.encode())
    mesh = pmwm_codec.read_mesh(tmp_path / "m.obj")
    assert mesh.positions.tolist() == [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]
    assert mesh.faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    from pmwm_codec import meshdoc

    source, _ = meshdoc.read_source(tmp_path / "m.obj")
    assert sorted(map(tuple, source.faces.tolist())) == [(0, 1, 2), (0, 2, 3)]


@pytest.mark.parametrize("suffix, text, record", [
    (".obj", "v 1_0 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n# a comment: the record reader\n", "'v 1_0 0 0'"),
    (".obj", "v \u0661 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n", "'v \u0661 0 0'"),
    (".obj", "v 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3_0\n", "'f 1 2 3_0'"),
    (".off", "OFF\n3 1 0\n1_0 0 0\n0 1 0\n0 0 1\n3 0 1 2\n", "'1_0 0 0'"),
    (".off", "OFF\n3 1 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 \u0662\n", "'3 0 1 \u0662'"),
])
def test_a_number_only_pythons_parsers_take_is_refused_not_read_as_another(tmp_path, suffix, text, record):
    """float('1_0') is 10 and int('\u0662') is 2: a record of them was read as those numbers, exit 0."""
    (tmp_path / ("m" + suffix)).write_text(text, encoding="utf-8")
    with pytest.raises(mesh_mod.InputFormatError, match="malformed") as exc:
        pmwm_codec.read_mesh(tmp_path / ("m" + suffix))
    assert record in str(exc.value)


def test_a_ply_value_past_float32_is_refused_in_one_line_without_a_warning(tmp_path):
    """An ASCII PLY ``property float`` of 1e39 was refused (exit 2) after trimesh's ``RuntimeWarning: overflow
    encountered in cast`` and its source line: three lines on stderr where the rule is one."""
    import warnings

    from pmwm_codec.errors import MeshError

    header = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    header += "element face 1\nproperty list uchar int vertex_indices\nend_header\n"
    (tmp_path / "big.ply").write_text(header + "0 0 0\n1 0 0\n0 1e39 0\n3 0 1 2\n")
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("always")
        with pytest.raises(MeshError, match="infinite"):
            pmwm_codec.read_mesh(tmp_path / "big.ply")
    assert not [w for w in seen if issubclass(w.category, RuntimeWarning)]


_TRIANGLE = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"


@pytest.mark.parametrize("text, words", [
    (_TRIANGLE + "f 1/1/1 2/2/2 3/3/3\n", "face index 1 names no vt record (0 read before the face)"),
    (_TRIANGLE + "vn 0 0 1\nf 1//1 2//2 3//3\n", "face index 2 names no vn record (1 read before the face)"),
    (_TRIANGLE + "vt 0 0\nf 1/1 2/1 3/1\nf 1/1 2/-2 4/1\n", "face index -2 names no vt record (1 read before the face)"),
    (_TRIANGLE + "vt 0 0\nf 1/1 2/1 3/1\nvt 1 1\nf 1/3 2/1 4/1\n", "face index 3 names no vt record (2 read before"),
    (_TRIANGLE + "f 1/1/1/1 2 3\n", "malformed OBJ face corner '1/1/1/1'"),
], ids=["no-vt-no-vn", "too-few-vn", "relative-vt", "vt-after-a-face", "four-numbers"])
def test_an_obj_corner_naming_a_texture_coordinate_or_normal_that_is_not_there_is_refused(capsys, tmp_path, text,
                                                                                         words):
    """``f 1/1/1 2/2/2 3/3/3`` in an OBJ of no ``vt`` or ``vn`` record (or fewer than named) was read without a
    word: the geometry readers took each corner's first number alone, while the same file with one ``vt`` more
    (read as an asset) was refused.  Both now refuse it with the asset reader's line."""
    from test_hostile_inputs import assert_refused, run_encode

    src = tmp_path / "m.obj"
    src.write_text(text)
    with pytest.raises(mesh_mod.InputFormatError, match=f"m.obj: {re.escape(words)}"):
        pmwm_codec.read_mesh(src)
    assert_refused(*run_encode(capsys, tmp_path, src), "m.obj", words)


def test_an_obj_face_naming_a_vertex_written_after_it_is_refused(capsys, tmp_path):
    """``f 1 2 3`` before the ``v`` records it names was read as if they came first (OBJ numbers the vertices read
    so far: Blender skips such a face, three.js reads no position for it), and refused by the asset reader when
    the file also had a ``vt``: both readers now name it."""
    from test_hostile_inputs import assert_refused, run_encode

    src = tmp_path / "m.obj"
    src.write_text("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n")
    words = "face index 3 names no v record (2 read before the face)"
    with pytest.raises(mesh_mod.InputFormatError, match=re.escape(words)):
        pmwm_codec.read_mesh(src)
    assert_refused(*run_encode(capsys, tmp_path, src), "m.obj", words)


@pytest.mark.parametrize("style", ["{0}/{0}/{0}", "{0}//{0}", "{0}/{0}", "{0}/-1/{0}"])
def test_an_obj_whose_corners_name_their_records_reads_as_its_positions(tmp_path, style):
    """Corners that name existing ``vt`` / ``vn`` records (numbered or counted back) read the mesh the plain faces
    give, whether every record comes before the faces (the column check) or an object follows another."""
    mesh = shapes.icosphere(1)
    v = "".join(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in mesh.positions)
    attrs = "".join("vt 0.5 0.5\nvn 0 0 1\n" for _ in mesh.positions)
    faces = ["f " + " ".join(style.format(i + 1) for i in f) + "\n" for f in mesh.faces]
    half = len(faces) // 2
    (tmp_path / "one.obj").write_text(v + attrs + "".join(faces))
    (tmp_path / "two.obj").write_text(v + attrs + "".join(faces[:half]) + "o second\nvn 0 0 1\n" + "".join(faces[half:]))
    for name in ("one.obj", "two.obj"):
        got = pmwm_codec.read_mesh(tmp_path / name)
        assert np.array_equal(got.positions, mesh.positions) and np.array_equal(got.faces, mesh.faces), name


@pytest.mark.parametrize("kind", ["ascii", "binary"])
def test_an_stl_corner_of_nan_is_named_by_its_facet(tmp_path, kind):
    """It was named by a vertex of the weld ("first at vertex 4"), a number the file does not hold."""
    triangles = [SQUARE[0], [(1, 0, 0), (1, float("nan"), 0), (0, 1, 0)], SQUARE[1]]
    if kind == "ascii":
        (tmp_path / "m.stl").write_text("solid m\n" + _facets(*triangles) + "endsolid m\n")
    else:
        data = bytes(80) + (3).to_bytes(4, "little")
        for t in triangles:
            data += np.array([0, 0, 1, *np.asarray(t, float).ravel()], "<f4").tobytes() + bytes(2)
        (tmp_path / "m.stl").write_bytes(data)
    with pytest.raises(mesh_mod.MeshError, match=r"^m.stl: 1 facet has a NaN or infinite coordinate \(first: facet 2, "
                                                 r"counted from 1\)$"):
        pmwm_codec.read_mesh(tmp_path / "m.stl")


def _written_sizes(monkeypatch) -> list:
    """The sizes of the os.write calls the atomic writer makes (a list, filled as files are written)."""
    from pmwm_codec import atomic

    sizes, write = [], os.write

    def recording(fd, data):
        sizes.append(len(data))
        return write(fd, data)

    monkeypatch.setattr(atomic.os, "write", recording)
    return sizes


@pytest.mark.parametrize("suffix", [".obj", ".off"])
def test_an_obj_or_off_is_written_a_block_of_records_at_a_time_never_whole_in_memory(tmp_path, monkeypatch, suffix):
    """``pmw decode -o X.obj`` of a heritage scan built the whole text (a Python string per line, joined, then
    encoded: more memory than the decoded mesh); the records are formatted a block at a time and written as
    they are made, the same bytes as ``np.savetxt`` writes."""
    import io

    from pmwm_codec import meshio

    mesh = shapes.icosphere(4)
    monkeypatch.setattr(meshio, "TEXT_ROWS_BLOCK", 100, raising=False)
    sizes = _written_sizes(monkeypatch)
    write_mesh(tmp_path / f"m{suffix}", mesh)
    data = (tmp_path / f"m{suffix}").read_bytes()
    assert max(sizes) < len(data) / 10, (max(sizes), len(data))
    expected = io.StringIO()
    positions, faces = mesh.positions.astype(np.float32).astype(np.float64), mesh.faces.astype(np.int64)
    if suffix == ".obj":
        expected.write(f"# pmwm_codec (pmw decode): {len(positions)} vertices, {len(faces)} faces\n")
        np.savetxt(expected, positions, fmt="v %.9g %.9g %.9g")
        np.savetxt(expected, faces + 1, fmt="f %d %d %d")
    else:
        expected.write(f"OFF\n{len(positions)} {len(faces)} 0\n")
        np.savetxt(expected, positions, fmt="%.9g %.9g %.9g")
        np.savetxt(expected, faces, fmt="3 %d %d %d")
    assert data == expected.getvalue().encode("ascii")


def test_a_scene_s_obj_with_texture_coordinates_and_normals_is_written_a_block_at_a_time(tmp_path, monkeypatch):
    """The decoded asset's OBJ (``v``, ``vt``, ``vn`` and ``f p/t/n`` records: :mod:`pmwm_codec.meshexport`) is
    formatted a block of records at a time too, and reads back as the scene it was written from."""
    from pmwm_codec import meshio
    from pmwm_codec.meshdoc import Part
    from pmwm_codec.meshexport import Scene, Showing, write_scene

    mesh = shapes.icosphere(4)
    normals = mesh.positions / np.linalg.norm(mesh.positions, axis=1, keepdims=True)
    uv = (mesh.positions[:, :2] + 1.0) / 2.0
    scene = Scene([Showing("ball", [Part(mesh.positions, mesh.faces, {"NORMAL": normals, "TEXCOORD_0": uv})])],
                  [], [], [])
    monkeypatch.setattr(meshio, "TEXT_ROWS_BLOCK", 100, raising=False)
    sizes = _written_sizes(monkeypatch)
    assert write_scene(str(tmp_path / "m.obj"), scene)[:2] == (len(mesh.positions), len(mesh.faces))
    data = (tmp_path / "m.obj").read_bytes()
    assert max(sizes) < len(data) / 10, (max(sizes), len(data))
    records = data.decode().splitlines()
    corners = [c for r in records if r.startswith("f ") for c in r.split()[1:]]
    assert len(corners) == 3 * len(mesh.faces) and all(re.fullmatch(r"\d+/\d+/\d+", c) for c in corners)
    assert sum(r.startswith("vn ") for r in records) == len(np.unique(normals.astype(np.float32), axis=0))
    back = pmwm_codec.read_mesh(tmp_path / "m.obj")
    assert np.array_equal(back.faces, mesh.faces)
    assert np.allclose(back.positions, mesh.positions, atol=1e-6)


def test_reading_an_obj_takes_no_python_object_per_line():
    """Reading an OBJ of ``v``, ``vt`` and ``f v/t`` records peaked at ~8x the text's size (a list of its lines,
    copies of the ``v`` and ``f`` lines, the faces' text twice: 1.9 GB for a 234 MB scan); the common file is
    read from the text's bytes with numpy, to the same arrays."""
    import tracemalloc

    from pmwm_codec.mesh import obj_arrays

    rng = np.random.default_rng(0)
    n = 20_000
    pos = rng.normal(size=(n, 3))
    faces = rng.integers(1, n + 1, size=(2 * n, 3))
    text = "".join(["v %.9g %.9g %.9g\n" % tuple(p) for p in pos] + ["vt %.9g %.9g\n" % tuple(p[:2]) for p in pos]
                   + ["f %d/%d %d/%d %d/%d\n" % (a, a, b, b, c, c) for a, b, c in faces])
    tracemalloc.start()
    try:
        positions, triangles, widest = obj_arrays(text, "m.obj")
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(positions, np.array([[float("%.9g" % x) for x in p] for p in pos]))
    assert np.array_equal(triangles, faces - 1) and widest == 3
    assert peak < 5 * len(text), (peak, len(text))
