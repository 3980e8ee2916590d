"""OFF meshes (Geomview's Object File Format: CGAL's data, the Princeton Shape Benchmark, ModelNet) are read.

``pmw encode mesh.off`` was "unknown mesh format '.off'", and trimesh's own OFF reader fails on numpy 2 for a
file that mixes polygon sizes (6 of CGAL's 139 OFF meshes).  Every reader of a mesh file (``read_mesh``,
``pmw encode``, ``pmw verify``, ``pmw batch``) now takes OFF: one vertex a line, one polygon a line (its corner
count, indices from 0, an optional colour), fan-triangulated as an OBJ's polygons are.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.errors import InputFormatError, MeshError


def off_text(mesh, keyword="OFF", header_counts_inline=False, comments=False, colours=False) -> str:
    lines = [keyword + (f" {mesh.vertex_count} {mesh.face_count} 0" if header_counts_inline else "")]
    if comments:
        lines.insert(0, "# made by a test")
        lines.append("")
    if not header_counts_inline:
        lines.append(f"{mesh.vertex_count} {mesh.face_count} 0")
    for p in mesh.positions:
        lines.append(" ".join(repr(float(x)) for x in p) + (" 0.5 0.5 0.5 1" if colours else "")
                     + ("  # a vertex" if comments else ""))
    for f in mesh.faces:
        lines.append("3 " + " ".join(map(str, f)) + (" 255 0 0" if colours else ""))
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("form", [{}, {"keyword": "COFF", "colours": True}, {"header_counts_inline": True},
                                  {"comments": True}])
def test_an_off_mesh_reads_as_its_obj_does(tmp_path, form):
    mesh = shapes.icosphere(3, noise=0.05, seed=4)
    (tmp_path / "m.obj").write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in mesh.positions.tolist())
                                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces.tolist()))
    (tmp_path / "m.off").write_text(off_text(mesh, **form))
    off, obj = pmwm_codec.read_mesh(tmp_path / "m.off"), pmwm_codec.read_mesh(tmp_path / "m.obj")
    assert np.array_equal(off.positions, obj.positions) and np.array_equal(off.faces, obj.faces)
    assert np.array_equal(off.positions, mesh.positions) and np.array_equal(off.faces, mesh.faces)


def test_off_polygons_of_mixed_sizes_are_fan_triangulated_as_obj_polygons(tmp_path):
    """A quad, a pentagon and triangles (the kind trimesh's reader fails on): the same triangles as the OBJ."""
    pts = "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n3 1 0\n2 2 0\n"
    (tmp_path / "m.off").write_text("OFF\n7 3 0\n" + pts + "4 0 1 2 3\n5 1 4 5 6 2\n3 0 2 3\n")
    (tmp_path / "m.obj").write_text("".join(f"v {line}\n" for line in pts.splitlines()) + "f 1 2 3 4\nf 2 5 6 7 3\nf 1 3 4\n")
    off, obj = pmwm_codec.read_mesh(tmp_path / "m.off"), pmwm_codec.read_mesh(tmp_path / "m.obj")
    assert off.face_count == 6 and np.array_equal(off.faces, obj.faces)


@pytest.mark.parametrize("text, error, words", [
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n", InputFormatError, "OFF declares 3 vertices and 1 faces but holds 2 records (cut short)"),
    ("OFF\n3 1 0\n0 0 0\n1 0 x\n0 1 0\n3 0 1 2\n", InputFormatError, "malformed OFF vertex record (record 4): '1 0 x'"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1\n", InputFormatError, "malformed OFF face record (record 6): '3 0 1'"),
    ("OFF\n3 0 0\n0 0 0\n1 0 0\n0 1 0\n", MeshError, "no triangle mesh (its OFF header declares 3 vertices and no faces"),
    ("OFF BINARY\n", InputFormatError, "a binary OFF file"),
    ("4OFF\n1 1 0\n0 0 0 0\n", InputFormatError, "a 4OFF file holds vertices of another dimension than 3"),
    ("OFF\n99999999 1 0\n", InputFormatError, "OFF declares 99,999,999 vertices"),
    ("ply\n", InputFormatError, "not an OFF file"),
    ("OFF\nthree 1 0\n", InputFormatError, "malformed OFF counts: 'three 1 0'"),
    ("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", MeshError, "face index 7 out of range for 3 vertices"),
])
def test_a_malformed_off_is_refused_in_one_line_naming_the_problem(tmp_path, capsys, text, error, words):
    (tmp_path / "m.off").write_text(text)
    with pytest.raises(error) as exc:
        pmwm_codec.read_mesh(tmp_path / "m.off")
    assert words in str(exc.value) and "OBJ" not in str(exc.value)  # an OFF counts from 0: no OBJ numbering hint
    assert main(["encode", str(tmp_path / "m.off"), "-o", str(tmp_path / "m.pmw")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and words in err[0] and not (tmp_path / "m.pmw").exists()


def test_an_off_mesh_encodes_decodes_to_off_verifies_and_batches(tmp_path, capsys):
    mesh = shapes.icosphere(4, noise=0.03, seed=5)
    src = tmp_path / "in" / "m.off"
    src.parent.mkdir()
    src.write_text(off_text(mesh))
    assert main(["encode", str(src), "-o", str(tmp_path / "m.pmw"), "--owner-id", "abc", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["vertices"] == mesh.vertex_count and report["vsplits"] > 0
    assert main(["decode", str(tmp_path / "m.pmw"), "-o", str(tmp_path / "back.off"), "-q"]) == 0
    assert pmwm_codec.read_mesh(tmp_path / "back.off").vertex_count == mesh.vertex_count
    assert main(["verify", str(tmp_path / "back.off"), "--key", str(tmp_path / "m.pmw.key.json"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["owner"]["verdict"] == "present"
    assert main(["batch", "encode", str(tmp_path / "in"), "-o", str(tmp_path / "out"), "-q"]) == 0
    assert (tmp_path / "out" / "m.off.pmw").exists()  # the batch tree keeps the source name (m.obj.pmw beside it)


def test_modelnet_s_counts_glued_to_the_keyword_read(tmp_path):
    """ModelNet's OFF files write ``OFF490 1010 0``: the keyword and the counts on one line, with no space."""
    (tmp_path / "m.off").write_text("OFF4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n")
    assert pmwm_codec.read_mesh(tmp_path / "m.off").faces.tolist() == [[0, 1, 2], [0, 2, 3]]


@pytest.mark.parametrize("keyword, normals, scale, alpha", [("COFF", False, 255, True), ("COFF", False, 1, False),
                                                           ("CNOFF", True, 255, True)])
def test_an_off_s_vertex_colours_ride_as_colour_and_come_back_as_the_same_bytes(tmp_path, keyword, normals, scale,
                                                                                 alpha):
    """A ``C`` OFF's vertex colours (after the position, and after the normal in an ``N`` one; 0..255 integers
    or 0..1 floats, an alpha or not) are sRGB colours, carried as COLOR_0 as a PLY's are: they had been dropped
    without a word.  Decoded to PLY, the same bytes come back."""
    from scipy.spatial import cKDTree

    from pmwm_codec import ply

    mesh = shapes.icosphere(2)
    rgb = np.random.default_rng(3).integers(0, 256, (mesh.vertex_count, 3))
    rgb[0] = 255
    lines = [keyword, f"{mesh.vertex_count} {mesh.face_count} 0"]
    for p, c in zip(mesh.positions, rgb):
        normal = " 0 0 1" if normals else ""
        colour = " ".join(str(int(v)) if scale == 255 else repr(float(v) / 255) for v in c) + (" 255" if alpha else "")
        lines.append(" ".join(repr(float(x)) for x in p) + normal + " " + colour)
    lines += ["3 " + " ".join(map(str, f)) for f in mesh.faces]
    (tmp_path / "c.off").write_text("\n".join(lines) + "\n")
    report = pmwm_codec.encode(str(tmp_path / "c.off"), str(tmp_path / "c.pmw"))
    assert report["vertices"] == mesh.vertex_count and not any("colour" in n for n in report["notices"])
    assert main(["decode", str(tmp_path / "c.pmw"), "-o", str(tmp_path / "back.ply"), "-q"]) == 0
    back = ply.read_appearance((tmp_path / "back.ply").read_bytes(), "back.ply", 10 ** 6)
    _, nearest = cKDTree(mesh.positions).query(back.positions)
    assert np.array_equal(np.rint(back.colours[:, :3] * 255), rgb[nearest])
    assert main(["decode", str(tmp_path / "c.pmw"), "-o", str(tmp_path / "back.off"), "-q"]) == 0  # COFF out
    from pmwm_codec.mesh import _read_off

    positions, _, colours, _ = _read_off(str(tmp_path / "back.off"), "back.off", appearance=True)
    _, nearest = cKDTree(mesh.positions).query(positions)
    assert np.array_equal(np.rint(colours * 255), rgb[nearest])


def test_an_off_s_face_colours_are_not_carried_and_the_encoder_says_so(tmp_path):
    mesh = shapes.icosphere(2)
    (tmp_path / "f.off").write_text(off_text(mesh))
    assert pmwm_codec.encode(str(tmp_path / "f.off"), str(tmp_path / "f.pmw"))["notices"] == []
    lines = off_text(mesh).splitlines()
    faces_from = 2 + mesh.vertex_count
    (tmp_path / "g.off").write_text("\n".join(lines[:faces_from] + [f + " 255 0 0" for f in lines[faces_from:]]) + "\n")
    report = pmwm_codec.encode(str(tmp_path / "g.off"), str(tmp_path / "g.pmw"))
    assert "the faces' colours not carried (an OFF's vertex colours are)" in report["notices"]
    assert (tmp_path / "g.pmw").read_bytes() == (tmp_path / "f.pmw").read_bytes()  # the geometry as before


def test_mutated_coloured_off_files_are_read_or_refused_by_name_never_another_error(tmp_path):
    """600 copies of COFF / CNOFF files with bytes changed, cut out, put in or the end cut off: each reads
    (meshdoc.off_source: the document of its colours, or a mesh) or is refused with a PmwError."""
    from pmwm_codec.errors import PmwError
    from pmwm_codec.meshdoc import off_source

    from test_ply import mutations

    mesh = shapes.icosphere(0)
    rows = [" ".join(repr(float(x)) for x in p) for p in mesh.positions]
    seeds = [("\n".join([k, f"{mesh.vertex_count} {mesh.face_count} 0"]
                        + [r + extra + " 200 100 50 255" for r in rows]
                        + ["3 " + " ".join(map(str, f)) + " 1 0 0" for f in mesh.faces]) + "\n").encode()
             for k, extra in (("COFF", ""), ("CNOFF", " 0 0 1"))]
    path = tmp_path / "m.off"
    for data in mutations(seeds, 600, seed=11):
        path.write_bytes(data)
        try:
            off_source(str(path), "m.off")
        except PmwError:
            pass


@pytest.mark.parametrize("keyword, colours", [("NOFF", False), ("CNOFF", True)])
def test_an_off_s_vertex_normals_are_not_carried_and_the_encoder_says_so(tmp_path, keyword, colours):
    """An ``N`` OFF's vertex normals are not read (README: "its faces' colours and normals not read, with a
    note"), as an OBJ's ``vn`` and a PLY's ``nx ny nz`` are not carried, which the encoder says: a NOFF's had
    been dropped without a word."""
    mesh = shapes.icosphere(2)
    lines = [keyword, f"{mesh.vertex_count} {mesh.face_count} 0"]
    for p in mesh.positions:
        n = p / np.linalg.norm(p)
        lines.append(" ".join(repr(float(x)) for x in (*p, *n)) + (" 0.5 0.5 0.5" if colours else ""))
    lines += ["3 " + " ".join(map(str, f)) for f in mesh.faces]
    (tmp_path / "n.off").write_text("\n".join(lines) + "\n")
    report = pmwm_codec.encode(str(tmp_path / "n.off"), str(tmp_path / "n.pmw"))
    assert report["vertices"] == mesh.vertex_count
    assert any("normals" in n and "not carried" in n for n in report["notices"]), report["notices"]
    (tmp_path / "p.off").write_text(off_text(mesh))
    assert not any("normals" in n for n in pmwm_codec.encode(str(tmp_path / "p.off"), str(tmp_path / "p.pmw"))["notices"])


def test_records_after_the_faces_an_off_declares_are_left_out_and_the_encoder_says_so(tmp_path):
    """Face records past the header's count were ignored without a word (helper-123): the declared count is read,
    as other readers read it, and a note says how many records were left out."""
    mesh = shapes.icosphere(2)
    (tmp_path / "f.off").write_text(off_text(mesh))
    extra = ["3 0 1 2", "3 1 2 3"]
    (tmp_path / "g.off").write_text(off_text(mesh) + "\n".join(extra) + "\n")
    report = pmwm_codec.encode(str(tmp_path / "g.off"), str(tmp_path / "g.pmw"))
    assert "2 records after the faces the OFF header declares left out" in " ".join(report["notices"]), report["notices"]
    assert pmwm_codec.encode(str(tmp_path / "f.off"), str(tmp_path / "f.pmw"))["notices"] == []
    assert (tmp_path / "g.pmw").read_bytes() == (tmp_path / "f.pmw").read_bytes()  # the declared faces alone
