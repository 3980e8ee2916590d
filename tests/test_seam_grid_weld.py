"""Seam copies are found on the position grid the stream lives on, not by float equality.

A UV sphere built with trigonometry (three.js ``SphereGeometry``, most generators) stores its
u = 0 and u = 1 seam columns a few 1e-17 apart (``sin(2 pi)`` is not 0) and its bottom pole's
copies 1e-16 apart: different floats, one grid point.  Found by float equality they were not
seams, each side coarsened on its own and the seam cracked at every coarse level.

The crack check is the one of ``test_seams.py``, from the decoded geometry alone: every boundary
half-edge of a level must have a partner (a boundary half-edge the other way between the same
two positions); the sphere is closed once welded by position.
"""

from __future__ import annotations

import io

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.mesh import Mesh, checked_mesh
from pmwm_codec.progressive.grid import AttributeGrid, Grid
from pmwm_codec.progressive.seams import grid_weld, snap_near_copies, weld_groups
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.stream import replay as replay_module
from pmwm_codec.stream.asset import decode_asset, encode_asset
from pmwm_codec.stream.encoder import _locked_with_grid_copies

from test_seams import assert_same_vertices_and_triangles, unpartnered_edges


def trig_sphere(width: int = 24, height: int = 16) -> Mesh:
    """A bumpy UV sphere as three.js ``SphereGeometry`` builds it (poles included), float32 as glTF
    stores it, with NORMAL and TEXCOORD_0: seam and pole copies differ below any grid step."""
    u = np.arange(width + 1) / width
    v = np.arange(height + 1) / height
    phi, theta = np.meshgrid(u * 2 * np.pi, v * np.pi)
    n = np.stack([-np.cos(phi) * np.sin(theta), np.cos(theta), np.sin(phi) * np.sin(theta)], -1).reshape(-1, 3)
    r = 1 + 0.1 * (np.sin(5 * phi) * np.sin(3 * theta)).reshape(-1, 1)
    positions = (n * r).astype(np.float32).astype(np.float64)
    uv = np.stack(np.meshgrid(u, 1 - v), -1).reshape(-1, 2)
    grid = np.arange((width + 1) * (height + 1)).reshape(height + 1, width + 1)
    faces = []
    for iy in range(height):
        for ix in range(width):
            a, b = grid[iy, ix + 1], grid[iy, ix]
            c, d = grid[iy + 1, ix], grid[iy + 1, ix + 1]
            if iy != 0:
                faces.append((a, b, d))
            if iy != height - 1:
                faces.append((b, c, d))
    attrs = {"NORMAL": n.astype(np.float32).astype(np.float64), "TEXCOORD_0": uv.astype(np.float32).astype(np.float64)}
    return checked_mesh(positions, np.array(faces), attrs)  # the top pole's last copy is on no face


def test_the_trig_spheres_copies_differ_as_floats_and_some_round_to_neighbouring_grid_points():
    """Found by float equality the seam is open; on the default grid some copies round apart (the grid's
    rounding boundary falls on 0 of a mesh spanning [-1, 1]); snapped, every copy pair is one point."""
    mesh = trig_sphere()
    assert unpartnered_edges(mesh.positions, mesh.faces) > 0
    grid = Grid.fit(mesh.positions, 16)
    q = grid.quantize(mesh.positions)
    assert unpartnered_edges(q, mesh.faces) > 0
    snapped = snap_near_copies(q, mesh.positions, mesh.faces, grid.step)
    assert unpartnered_edges(snapped, mesh.faces) == 0
    moved = np.any(snapped != q, axis=1)
    assert 0 < moved.sum() < 30 and np.abs(snapped - q).max() == 1


def test_near_copies_snap_to_a_locked_vertex_and_only_on_the_boundary():
    # 0 and 1 straddle the rounding boundary at x = 0.5 steps (step 1) on two triangles' rims; 2 and 3 likewise
    pos = np.array([[0.5, 0, 0], [0.5 + 1e-9, 0, 0], [0, 5, 0], [5, 5, 0], [0.5 - 1e-9, 9, 0], [0.5 + 1e-9, 9, 0]])
    faces = np.array([[0, 2, 4], [1, 5, 3]])
    q = np.rint(pos).astype(np.int64)
    assert q[0, 0] != q[1, 0] and q[4, 0] != q[5, 0]
    out = snap_near_copies(q, pos, faces, 1.0)
    assert out[1, 0] == out[0, 0] == q[0, 0] and out[5, 0] == q[4, 0]  # the smallest id leads
    out = snap_near_copies(q, pos, faces, 1.0, locked=np.array([False, True, False, False, False, False]))
    assert out[0, 0] == q[1, 0] and out[1, 0] == q[1, 0]  # a locked vertex never moves
    apart = pos + [[0, 0, 0], [0.2, 0, 0], [0, 0, 0], [0, 0, 0], [0, 0, 0], [0.2, 0, 0]]
    assert snap_near_copies(q, apart, faces, 1.0) is q  # farther than 1/16 step: not copies
    inside = np.array([[0, 1, 2], [1, 3, 2], [3, 0, 2], [0, 3, 1]])  # a closed tetrahedron: no rim
    assert snap_near_copies(np.rint(pos[:4]).astype(np.int64), pos[:4], inside, 1.0).tolist() == \
        np.rint(pos[:4]).astype(np.int64).tolist()


def test_a_trig_sphere_with_a_near_identical_seam_has_no_open_edge_at_any_batch(monkeypatch):
    mesh = trig_sphere()
    buf = io.BytesIO()
    # payload version 1: the batch-by-batch observer hooks replay's apply_batch, which v1 chunks go through
    report = encode_mesh(mesh, buf, measure=False, payload_version=1)
    cracks, twins = [], []
    original = replay_module.apply_batch

    def checked(state, batch):
        topo = original(state, batch)
        cracks.append(unpartnered_edges(state.positions[: state.n, :3], state.faces[: state.m]))
        pts = state.positions[topo.u, :3]
        twins.append(len(pts) - len(np.unique(pts, axis=0)))
        return topo

    monkeypatch.setattr(replay_module, "apply_batch", checked)
    dec = StreamDecoder()
    results = dec.feed(buf.getvalue())
    assert dec.close().complete
    assert len(cracks) == report.batches > 1
    assert cracks == [0] * len(cracks)
    assert unpartnered_edges(results[0].parts[0].positions_int, results[0].parts[0].faces) == 0  # the base
    assert sum(twins) > 0  # the seam coarsened in pairs (it was not kept whole in the base)
    # the full decode is the input on its grids, vertex for vertex (the copies stay separate vertices), the
    # copies that rounded to neighbouring grid points on one of them
    full = results[-1].parts[0]
    q = full.grid.quantize(mesh.positions)
    snapped = snap_near_copies(q, mesh.positions, mesh.faces, full.grid.step)
    assert np.abs(snapped - q).max() == 1
    want = [snapped]
    for spec in full.attributes:
        grid = AttributeGrid.from_config(spec)
        want.append(grid.from_float32(mesh.attributes[spec["semantic"]], spec["semantic"]))
    assert_same_vertices_and_triangles(np.concatenate(want, axis=1), mesh.faces, full)


def _glb(mesh: Mesh) -> tuple:
    """``(gltf, buffers)`` of one indexed primitive with the mesh's float32 attributes."""
    arrays = [("POSITION", mesh.positions.astype(np.float32), "VEC3")]
    arrays += [(k, v.astype(np.float32), {2: "VEC2", 3: "VEC3", 4: "VEC4"}[v.shape[1]]) for k, v in mesh.attributes.items()]
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
            "accessors": [], "bufferViews": [], "meshes": [{"primitives": [{"attributes": {}}]}]}
    blob = b""
    prim = gltf["meshes"][0]["primitives"][0]
    for name, data, kind in arrays + [("indices", mesh.faces.astype(np.uint32).reshape(-1), "SCALAR")]:
        raw = data.tobytes()
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw)})
        acc = {"bufferView": len(gltf["bufferViews"]) - 1, "componentType": 5125 if name == "indices" else 5126,
               "count": len(data), "type": kind}
        if name == "POSITION":
            acc["min"], acc["max"] = data.min(0).tolist(), data.max(0).tolist()
        gltf["accessors"].append(acc)
        if name == "indices":
            prim["indices"] = len(gltf["accessors"]) - 1
        else:
            prim["attributes"][name] = len(gltf["accessors"]) - 1
        blob += raw + b"\0" * (-len(raw) % 4)
    gltf["buffers"] = [{"byteLength": len(blob)}]
    return gltf, [blob]


def test_a_trig_sphere_glb_decodes_without_a_seam_crack_at_every_chunk_count(tmp_path):
    """The outside probe's case end to end: the decoded GLB at every level, float32 positions as a viewer
    reads them (open edges that are not open at full resolution were 12 to 14 at every coarse level)."""
    out = tmp_path / "sphere.pmw"
    encode_asset(_glb(trig_sphere()), out, measure=False)
    total = StreamDecoder().feed(out.read_bytes())[-1].chunks_total
    assert total >= 2
    for chunks in range(total + 1):
        glb, _, _ = decode_asset(out, chunks=chunks)
        path = tmp_path / f"level{chunks}.glb"
        path.write_bytes(glb)
        doc, buffers = load_document(path)
        prim = doc["meshes"][0]["primitives"][0]
        pos = read_accessor(doc, buffers, prim["attributes"]["POSITION"])
        faces = read_accessor(doc, buffers, prim["indices"]).reshape(-1, 3).astype(np.int64)
        assert unpartnered_edges(pos, faces) == 0, f"--chunks {chunks}"


def test_grid_only_copies_inside_the_surface_are_not_seams():
    """Two vertices on one grid point in the middle of a surface (a dense scan on a coarse grid) stay
    separate vertices (they cannot crack, and as seams they would all stay in the base); points on one
    grid point on a cut (each side's boundary edges partnered on the grid) are one seam; exact copies
    always are."""
    # a square fanned around two interior points 4 and 5 (one grid point), and a strip whose edge 7 -> 6
    # runs back along the square's rim edge 1 -> 2, its copies a float hair off 1 and 2
    pos = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0.5, 0.5, 0], [0.5 + 1e-9, 0.5, 0],
                    [1 + 1e-12, 0, 0], [1, 1 - 1e-12, 0], [2, 0, 0], [2, 1, 0]], np.float64)
    faces = np.array([[0, 1, 4], [1, 5, 4], [1, 2, 5], [2, 3, 5], [3, 4, 5], [3, 0, 4], [6, 8, 9], [6, 9, 7]])
    q = np.rint(pos * 1000).astype(np.int64)
    weld = grid_weld(q, faces, pos)
    assert weld.tolist() == [0, 1, 2, 3, 4, 5, 1, 2, 8, 9]
    exact = pos.copy()
    exact[5] = exact[4]
    assert grid_weld(q, faces, exact).tolist() == [0, 1, 2, 3, 4, 4, 1, 2, 8, 9]  # an exact copy always is one
    assert grid_weld(np.arange(30).reshape(10, 3), faces, pos) is None
    assert weld_groups(pos) is None


def test_a_lock_reaches_every_copy_on_its_grid_point():
    q = np.array([[0, 0, 0], [5, 5, 5], [0, 0, 0], [1, 1, 1]])
    locked = np.array([False, False, True, False])
    assert _locked_with_grid_copies(q, locked).tolist() == [True, False, True, False]
    assert _locked_with_grid_copies(q, np.zeros(4, bool)).tolist() == [False] * 4


@pytest.mark.parametrize("numba", [True, False])
def test_the_rim_is_the_ends_of_the_edges_of_one_face(monkeypatch, numba):
    """:func:`seams._rim` (no edge table of the whole mesh) against the edge table's definition, compiled and
    not, on a mesh with holes, a flipped face and a fin (an edge of three faces)."""
    from pmwm_codec.progressive import seams, topology

    monkeypatch.setattr(topology, "USE_NUMBA", numba and topology.USE_NUMBA)
    mesh = shapes.icosphere(3, noise=0.01, seed=4)
    faces = np.asarray(mesh.faces, np.int64)
    rng = np.random.default_rng(5)
    faces = faces[rng.random(len(faces)) > 0.05]  # holes
    faces[3] = faces[3, [0, 2, 1]]  # a face the other way round
    faces = np.concatenate([faces, [[faces[10, 0], faces[10, 1], faces[40, 2]]]])  # a fin
    n = mesh.vertex_count
    a, b = faces.reshape(-1), faces[:, [1, 2, 0]].reshape(-1)
    edges, count = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_counts=True)
    expected = np.unique(np.r_[edges[count == 1] // n, edges[count == 1] % n])
    assert len(expected) > 10
    np.testing.assert_array_equal(seams._rim(faces, n), expected)
    assert len(seams._rim(np.asarray(mesh.faces, np.int64), n)) == 0  # a closed surface has none


def _grid_weld_whole_graph(q, faces, positions):
    """grid_weld as it was first written: the connected parts of a graph of every vertex (a self loop on
    each vertex without a copy), the reference of the graph of the linked vertices only."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from pmwm_codec.progressive.seams import _cut_vertices

    exact, on_grid = weld_groups(positions), weld_groups(q)
    if on_grid is None or (exact is not None and np.array_equal(exact, on_grid)):
        return exact
    n = len(q)
    cut = _cut_vertices(on_grid, np.asarray(faces, np.int64).reshape(-1, 3), n)
    ids = np.arange(n, dtype=np.int64)
    first_cut = np.full(n, n, np.int64)
    np.minimum.at(first_cut, on_grid[cut], ids[cut])
    link = np.where(cut, first_cut[on_grid], ids)
    exact = ids if exact is None else exact
    graph = coo_matrix((np.ones(2 * n, np.int8), (np.r_[ids, ids], np.r_[exact, link])), shape=(n, n))
    _, part = connected_components(graph, directed=False)
    first = np.full(n, n, np.int64)
    np.minimum.at(first, part, ids)
    weld = first[part]
    return None if np.array_equal(weld, ids) else weld


@pytest.mark.parametrize("seed", range(6))
def test_the_cut_vertices_and_the_grid_weld_are_the_same_on_both_paths(monkeypatch, seed):
    """_cut_vertices (its edge and point-pair numbers compiled: a hash table; numpy: sorts) and grid_weld (its graph of the linked vertices
    only) against the whole-graph reference, on a trig sphere's seams and poles with random copies: exact
    ones, grid-only ones inside the surface, and faces cut loose along random edges (boundary half-edges,
    partnered or not)."""
    from pmwm_codec.progressive import seams, topology

    rng = np.random.default_rng(seed)
    mesh = trig_sphere(12 + seed, 9)
    pos = np.asarray(mesh.positions, np.float64).copy()
    faces = np.asarray(mesh.faces, np.int64).copy()
    n = len(pos)
    dup = rng.choice(n, 6, replace=False)  # exact copies of some vertices, and near ones (one grid point)
    pos[dup[:3]] = pos[rng.choice(n, 3)]
    pos[dup[3:]] = pos[rng.choice(n, 3)] + 1e-9
    cut = rng.choice(len(faces), len(faces) // 4, replace=False)  # faces on copies of their corners
    extra = faces[cut].reshape(-1)
    faces[cut] = (n + np.arange(len(extra))).reshape(-1, 3)
    pos = np.concatenate([pos, pos[extra]])
    q = np.rint(pos * 200).astype(np.int64)
    pid = weld_groups(q)
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append((seams._cut_vertices(pid, faces, len(q)), grid_weld(q, faces, pos)))
        assert np.array_equal(out[-1][1], _grid_weld_whole_graph(q, faces, pos))
    assert out[0][0].any() and np.array_equal(out[0][0], out[1][0])
    assert np.array_equal(out[0][1], out[1][1])
