"""A non-indexed triangle primitive (a triangle soup: every corner its own glTF vertex, as three.js
non-indexed geometry and STL-to-glTF converters write it) is welded before it is simplified, and a
triangle primitive that still gets no vertex split says so, and why.

As a soup every position had about six copies (three or more copies stay in the base), so the
primitive came out with 0 splits and 0 chunks, and no notice.  Welding exact duplicates (the same
position and the same value of every attribute) gives back the indexed mesh; vertices that differ
in any attribute (a UV seam, a hard normal) stay separate.
"""

from __future__ import annotations

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream.asset import decode_asset, encode_asset, plan_asset

_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}


def gltf_of(mesh: Mesh, indexed: bool = True) -> tuple:
    """``(gltf, buffers)``: one triangle primitive with the mesh's float32 attributes, indexed, or as a soup
    (``indexed=False``: every face corner its own vertex, no ``indices``)."""
    faces = mesh.faces.astype(np.uint32)
    arrays = {"POSITION": mesh.positions, **mesh.attributes}
    if not indexed:
        arrays = {k: np.asarray(v)[faces.reshape(-1)] for k, v in arrays.items()}
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "accessors": [], "bufferViews": [], "meshes": [{"primitives": [{"attributes": {}}]}]}
    prim = gltf["meshes"][0]["primitives"][0]
    blob = b""

    def add(data, component) -> int:
        nonlocal blob
        raw = data.tobytes()
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw)})
        acc = {"bufferView": len(gltf["bufferViews"]) - 1, "componentType": component, "count": len(data),
               "type": _TYPES[data.shape[1] if data.ndim == 2 else 1]}
        gltf["accessors"].append(acc)
        blob += raw + b"\0" * (-len(raw) % 4)
        return len(gltf["accessors"]) - 1

    for semantic, values in arrays.items():
        data = np.asarray(values, np.float32).reshape(len(values), -1)
        prim["attributes"][semantic] = add(data, 5126)
        if semantic == "POSITION":
            gltf["accessors"][-1].update(min=data.min(0).tolist(), max=data.max(0).tolist())
    if indexed:
        prim["indices"] = add(faces.reshape(-1), 5125)
    gltf["buffers"] = [{"byteLength": len(blob)}]
    return gltf, [blob]


def test_a_soup_glb_becomes_progressive_with_about_as_many_splits_as_the_indexed_mesh(tmp_path):
    mesh = shapes.icosphere(4, 1.0, noise=0.03)  # 2,562 vertices, 5,120 faces
    indexed = encode_asset(gltf_of(mesh), tmp_path / "indexed.pmw", measure=False)
    soup = encode_asset(gltf_of(mesh, indexed=False), tmp_path / "soup.pmw", measure=False)
    assert indexed.vsplits > 1000
    assert soup.vertices == indexed.vertices == mesh.vertex_count  # (it was 15,360: every corner)
    assert abs(soup.vsplits - indexed.vsplits) <= 0.05 * indexed.vsplits  # (it was 0)
    assert soup.base_vertices <= 0.05 * soup.vertices and soup.chunks > 1
    welded = [n for n in soup.notices if "duplicate vertices" in n]
    assert welded == [f"mesh 0 primitive 0: {3 * mesh.face_count - mesh.vertex_count} duplicate vertices (same "
                      f"position and attributes) welded; it decodes with {mesh.vertex_count} vertices"]
    assert not any("duplicate" in n for n in indexed.notices)


def test_a_textured_soup_welds_only_exact_duplicates_and_decodes_the_same_triangles(tmp_path):
    """A UV torus as a soup: the seam's copies (one position, two UVs) stay two vertices, so the weld gives the
    indexed mesh's vertices exactly, and the full decode draws the soup's triangles with their UVs."""
    mesh = shapes.uv_torus(32, 16)
    src = gltf_of(mesh, indexed=False)
    jobs, _, notices = plan_asset(*src)
    assert jobs[0].mesh.vertex_count == mesh.vertex_count  # seam copies kept apart by their UVs
    report = encode_asset(src, tmp_path / "soup.pmw", measure=False)
    assert report.vsplits > 0.9 * (mesh.vertex_count - report.base_vertices) and report.chunks > 1
    full, _, _ = decode_asset(tmp_path / "soup.pmw")
    (tmp_path / "full.glb").write_bytes(full)
    doc, buffers = load_document(tmp_path / "full.glb")
    prim = doc["meshes"][0]["primitives"][0]
    pos = read_accessor(doc, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
    uv = read_accessor(doc, buffers, prim["attributes"]["TEXCOORD_0"]).astype(np.float64)
    faces = read_accessor(doc, buffers, prim["indices"]).reshape(-1, 3).astype(np.int64)
    assert len(pos) == mesh.vertex_count  # the welded vertices are the decoded glTF vertices
    # each decoded vertex is one input vertex (position within a grid step, the same UV), one for one, and
    # the decoded triangles are the soup's
    from scipy.spatial import cKDTree

    span = np.ptp(mesh.positions, axis=0).max()
    _, match = cKDTree(np.c_[mesh.positions, mesh.attributes["TEXCOORD_0"] * span]).query(np.c_[pos, uv * span])
    assert len(np.unique(match)) == len(match)
    assert np.abs(pos - mesh.positions[match]).max() <= span / 65535  # a grid step
    assert np.abs(uv - mesh.attributes["TEXCOORD_0"][match]).max() <= 1 / 16383  # a step of the UV grid
    assert np.array_equal(_rotated(match[faces]), _rotated(mesh.faces))


def _rotated(faces: np.ndarray) -> np.ndarray:
    """Faces rotated to start at their smallest id (orientation kept), rows sorted."""
    k = np.argmin(faces, axis=1)
    rot = np.take_along_axis(faces, (k[:, None] + np.arange(3)) % 3, axis=1)
    return rot[np.lexsort(rot.T[::-1])]


def test_one_weld_serves_an_obj_soup_and_a_gltf_soup(tmp_path):
    """The mesh readers and the glTF primitives weld a soup through one function (there were two copies of
    the logic): the same soup read as an OBJ and planned as a non-indexed primitive is the mesh
    :func:`~pmwm_codec.mesh.weld_soup` gives, the OBJ counting the weld in its cleanup, the primitive in its
    notice; vertices that differ in an attribute stay apart, and a mesh whose faces share vertices is none
    of its business."""
    from pmwm_codec.mesh import read_mesh, weld_soup

    mesh = shapes.icosphere(2, 1.0, noise=0.02)
    corners = mesh.positions.astype(np.float32).astype(np.float64)[mesh.faces.reshape(-1)]  # exact in both files
    soup = np.arange(len(corners)).reshape(-1, 3)
    welded, removed = weld_soup(corners, soup, name="soup")
    assert welded.vertex_count == mesh.vertex_count and removed == len(corners) - mesh.vertex_count
    (tmp_path / "soup.obj").write_text("".join(f"v {x!r} {y!r} {z!r}\n" for x, y, z in corners.tolist())
                                       + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in soup.tolist()))
    obj = read_mesh(tmp_path / "soup.obj")
    jobs, _, notices = plan_asset(*gltf_of(Mesh(corners, soup, {}, {}), indexed=False))
    for got in (obj, jobs[0].mesh):
        assert np.array_equal(got.positions, welded.positions) and np.array_equal(got.faces, welded.faces)
    assert obj.cleanup == {"duplicate_soup_vertices": removed} and jobs[0].mesh.cleanup == {}
    assert notices == [f"mesh 0 primitive 0: {removed} duplicate vertices (same position and attributes) welded; "
                       f"it decodes with {mesh.vertex_count} vertices"]
    uv = np.zeros((len(corners), 2))
    uv[0] = 0.5  # the first corner differs from its copies in its UV: it stays its own vertex
    apart, fewer = weld_soup(corners, soup, {"TEXCOORD_0": uv}, name="soup")
    assert apart.vertex_count == mesh.vertex_count + 1 and fewer == removed - 1
    assert weld_soup(mesh.positions, mesh.faces) is None  # indexed by its author: kept as stored


def test_a_flat_shaded_primitive_with_no_split_says_why(tmp_path):
    """Per-face normals it must keep (beside a TANGENT, which a viewer ignores without NORMAL: test_flat_shading):
    every position has a copy per face around it (three or more), all stay in the base.  The encoder says the
    primitive got no split and why (it said nothing)."""
    ico = shapes.icosphere(3)
    p = ico.positions[ico.faces]  # (m, 3, 3): each face its own three vertices
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    flat = Mesh(p.reshape(-1, 3), np.arange(3 * ico.face_count).reshape(-1, 3),
                {"NORMAL": np.repeat(normal, 3, axis=0), "TANGENT": np.tile([1.0, 0.0, 0.0, 1.0], (3 * ico.face_count, 1))})
    report = encode_asset(gltf_of(flat), tmp_path / "flat.pmw", measure=False)
    assert report.vsplits == 0 and report.base_vertices == report.vertices
    said = [n for n in report.notices if "not made progressive" in n]
    assert len(said) == 1 and said[0].startswith("mesh 0 primitive 0: not made progressive (0 vertex splits")
    assert f"of its {flat.vertex_count} vertices, {flat.vertex_count} share their position" in said[0]
    assert "flat shading" in said[0]


def test_small_primitives_with_no_split_are_named_in_one_notice(tmp_path):
    gltf, buffers = gltf_of(shapes.icosphere(1))  # 42 vertices: no more than a base keeps
    report = encode_asset((gltf, buffers), tmp_path / "small.pmw", measure=False)
    assert report.vsplits == 0
    assert [n for n in report.notices if "not made progressive" in n] == [
        "mesh 0 primitive 0: not made progressive (0 vertex splits): it has 42 vertices, no more than a base keeps "
        "(at least 64), so the base is all of it"]
    gltf["meshes"][0]["primitives"] *= 5
    gltf["meshes"][0]["name"] = "pebbles"
    report = encode_asset((gltf, buffers), tmp_path / "five.pmw", measure=False)
    said = [n for n in report.notices if "not made progressive" in n]
    assert said == ["mesh 0 (pebbles) primitive 0, mesh 0 (pebbles) primitive 1, mesh 0 (pebbles) primitive 2 and "
                    "2 more: not made progressive (0 vertex splits): each has no more vertices than a base keeps "
                    "(at least 64), so the base is all of it"]


def test_an_indexed_primitive_without_duplicates_is_planned_as_stored():
    mesh = shapes.uv_torus(16, 8)
    jobs, _, notices = plan_asset(*gltf_of(mesh))
    got = jobs[0].mesh
    assert np.array_equal(got.positions, mesh.positions.astype(np.float32))
    assert np.array_equal(got.faces, mesh.faces) and not any("duplicate" in n for n in notices)


def test_an_indexed_primitive_keeps_its_duplicate_vertices():
    """Only a soup (every face corner its own vertex) is welded: an indexed primitive's vertices are its
    author's, duplicates and all (gltfpack writes a few), and decode as stored."""
    mesh = shapes.uv_torus(16, 8)
    faces = mesh.faces.copy()
    faces[0, 0] = mesh.vertex_count  # a duplicate of vertex faces[0, 0], named by one corner
    dup = Mesh(np.r_[mesh.positions, mesh.positions[mesh.faces[0, :1]]], faces,
               {"TEXCOORD_0": np.r_[mesh.attributes["TEXCOORD_0"], mesh.attributes["TEXCOORD_0"][mesh.faces[0, :1]]]})
    jobs, _, notices = plan_asset(*gltf_of(dup))
    assert jobs[0].mesh.vertex_count == dup.vertex_count and not any("duplicate" in n for n in notices)


def test_a_mesh_whose_faces_disagree_on_orientation_says_why_it_stays_in_the_base():
    """CGAL's blobby-shuffled.off (blobby.off with faces flipped at random) kept 1,952 of its 2,027 vertices in
    the base (blobby.off: 64) and the encoder said nothing; a collapse never crosses an edge two faces run the
    same way.  The notice names those edges and what to do."""
    import io

    import pmwm_codec

    ico = shapes.icosphere(4)
    faces = ico.faces.copy()
    flip = np.random.default_rng(5).random(len(faces)) < 0.5
    faces[flip] = faces[flip][:, ::-1]
    consistent = pmwm_codec.encode(ico, io.BytesIO(), measure=False)
    shuffled = pmwm_codec.encode(Mesh(ico.positions, faces), io.BytesIO(), measure=False)
    assert not [n for n in consistent["notices"] if "stay in the base" in n]
    assert shuffled["base_vertices"] > ico.vertex_count // 4 > consistent["base_vertices"]
    said = [n for n in shuffled["notices"] if "stay in the base" in n]
    assert len(said) == 1 and said[0].startswith(f"the mesh: {shuffled['base_vertices']:,} of its {ico.vertex_count:,} "
                                                 "vertices stay in the base (target 64): ")
    assert "edges run the same way in two faces" in said[0] and "orient the faces consistently" in said[0]


def test_a_positions_only_mesh_with_duplicate_points_names_them_as_duplicates_not_flat_shading(tmp_path):
    """CGAL's boeing.off: faces that share points through separate vertices (no attribute at all) were described as
    "per-face normals or UVs, as flat shading has"; a mesh file's copies are one point written several times."""
    import io

    import pmwm_codec

    ico = shapes.icosphere(3)
    p = ico.positions[ico.faces]
    keep = np.arange(ico.face_count) % 7 == 0  # a seventh of the faces share their corners; the rest stand apart
    positions = np.concatenate([ico.positions, p[~keep].reshape(-1, 3)])
    faces = np.concatenate([ico.faces[keep], ico.vertex_count + np.arange(3 * (~keep).sum()).reshape(-1, 3)])
    report = pmwm_codec.encode(Mesh(positions, faces), io.BytesIO(), measure=False)
    said = [n for n in report["notices"] if "base" in n and "share their position" in n]
    assert said and "one point written as separate vertices" in said[0] and "flat shading" not in said[0]


def test_a_scene_of_many_small_parts_says_the_parts_keep_the_base_large():
    """pybullet's samurai_monastry.obj (4,863 separate boxes and panels) kept 22,151 of its 85,982 vertices in the
    base, and the notice named only 330 point copies and 1,814 seam copies: a half-edge collapse never joins two
    parts, so each keeps three vertices or more.  The notice now counts the parts and that floor."""
    import io

    import pmwm_codec

    part = shapes.icosphere(0)  # 12 vertices, closed: coarsens to four or so
    scene = shapes.components(*([part] * 600), spacing=2.5)
    out = pmwm_codec.encode(scene, io.BytesIO(), measure=False)
    said = [n for n in out["notices"] if "stay in the base" in n]
    assert len(said) == 1, out["notices"]
    assert "the surface is 600 separate parts, which no collapse joins, each keeping at least three vertices " \
           "(1,800 in all)" in said[0]
    assert out["base_vertices"] >= 1800
    one = pmwm_codec.encode(shapes.icosphere(4), io.BytesIO(), measure=False)  # one part: nothing said
    assert not [n for n in one["notices"] if "separate parts" in n]
