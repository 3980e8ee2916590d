"""Seams collapse in pairs: textured and multi-attribute meshes coarsen, and never crack.

The crack check is defined from the decoded geometry alone (no encoder knowledge):

    a *boundary half-edge* a -> b of a level is a face edge that no other face of the
    level holds; it is *partnered* when the level has a boundary half-edge c -> d with
    position(c) == position(b) and position(d) == position(a) (exact grid values).

The generated meshes and spot are closed once welded by position, so at every level every
boundary half-edge must be partnered: a seam moved on one side only, or a T-junction, leaves
an edge without its twin.
"""

from __future__ import annotations

import io

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive.grid import AttributeGrid, Grid
from pmwm_codec.progressive.seams import twin_rows, weld_groups
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.stream import replay as replay_module
from pmwm_codec.watermark.key import WatermarkKey

from conftest import corpus_path

SEAMED = {
    "uv-torus": lambda: shapes.uv_torus(32, 16),
    "faceted-cube": lambda: shapes.faceted_cube(9, bump=0.15),
}


def unpartnered_edges(positions: np.ndarray, faces: np.ndarray, among=None) -> int:
    """Boundary half-edges of (positions (n, 3), faces (m, 3)) without a partner (module docstring).

    ``among`` (s, 3), optional: count only half-edges whose two end positions are among these
    (the seams of an open surface, whose true boundary has no partners).
    """
    pts = np.asarray(positions)[:, :3]
    _, pid = np.unique(pts, axis=0, return_inverse=True)
    pid = pid.reshape(-1)
    a = faces.reshape(-1)
    b = faces[:, [1, 2, 0]].reshape(-1)
    n = len(pts)
    edge, count = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True, return_counts=True)[1:]
    boundary = count[edge.reshape(-1)] == 1
    if among is not None:
        on_seam = (pts[:, None, :] == np.asarray(among)[None]).all(axis=2).any(axis=1)
        boundary &= on_seam[a] & on_seam[b]
    fwd = pid[a[boundary]] * n + pid[b[boundary]]
    back = pid[b[boundary]] * n + pid[a[boundary]]
    return int(np.count_nonzero(~np.isin(back, fwd)))


def seam_vertex_count(mesh: Mesh) -> int:
    """Vertices whose position another vertex shares."""
    _, inverse, count = np.unique(mesh.positions, axis=0, return_inverse=True, return_counts=True)
    return int(np.count_nonzero(count[inverse.reshape(-1)] > 1))


def _encode(mesh: Mesh, **options) -> tuple:
    buf = io.BytesIO()
    # payload version 1: the batch-by-batch observer hooks replay's apply_batch, which v1 chunks go through
    report = encode_mesh(mesh, buf, measure=False, **{"payload_version": 1, **options})
    return buf.getvalue(), report


def _levels_batch_by_batch(data: bytes, monkeypatch, key=None) -> tuple:
    """Decode ``data`` recording the crack count after every batch; returns
    ``(cracks per batch, twin splits per batch, results, decoder)``."""
    cracks, twins = [], []
    original = replay_module.apply_batch

    def checked(state, batch):
        topo = original(state, batch)
        cracks.append(unpartnered_edges(state.positions[: state.n, :3], state.faces[: state.m]))
        twins.append(int(np.count_nonzero(twin_rows(state.positions[topo.u, :3]) != np.arange(len(topo.u)))))
        return topo

    monkeypatch.setattr(replay_module, "apply_batch", checked)
    dec = StreamDecoder(key)
    results = dec.feed(data)
    dec.close()
    return cracks, twins, results, dec


def _quantized_rows(mesh: Mesh, part) -> np.ndarray:
    """(n, D) int64: the input's vertices on the file's grids (positions, then attributes by semantic)."""
    cols = [part.grid.quantize(mesh.positions)]
    for spec in part.attributes:
        cols.append(AttributeGrid.from_config(spec).from_float32(mesh.attributes[spec["semantic"]], spec["semantic"]))
    return np.concatenate(cols, axis=1)


def _assert_exact_round_trip(mesh: Mesh, part) -> None:
    """The decoded vertices are the input's grid values, one for one, and the faces the same triangles."""
    assert_same_vertices_and_triangles(_quantized_rows(mesh, part), mesh.faces, part)


def assert_same_vertices_and_triangles(want: np.ndarray, faces: np.ndarray, part) -> None:
    """``part``'s decoded vertices (grid positions, then attributes) are the rows ``want`` (n, D) int64, one
    for one in some order, and its faces the triangles ``faces`` (m, 3) of those rows."""
    got = np.concatenate([part.positions_int, part.attributes_int], axis=1)
    assert len(np.unique(want, axis=0)) == len(want) == len(got)  # each row names one vertex
    order_w = np.lexsort(want.T[::-1])
    order_g = np.lexsort(got.T[::-1])
    assert np.array_equal(want[order_w], got[order_g])
    to_input = np.empty(len(got), np.int64)
    to_input[order_g] = order_w
    assert np.array_equal(_rotate(to_input[part.faces]), _rotate(faces))


def _rotate(faces: np.ndarray) -> np.ndarray:
    """Faces rotated to start at their smallest id (orientation kept), rows sorted."""
    k = np.argmin(faces, axis=1)
    rot = np.take_along_axis(faces, (k[:, None] + np.arange(3)) % 3, axis=1)
    return rot[np.lexsort(rot.T[::-1])]


def test_the_crack_check_sees_a_seam_opened_on_one_side():
    mesh = shapes.uv_torus(16, 8)
    assert unpartnered_edges(mesh.positions, mesh.faces) == 0
    weld = weld_groups(mesh.positions)
    copy = np.flatnonzero(weld != np.arange(mesh.vertex_count))[3]  # a seam vertex's second copy
    moved = mesh.positions.copy()
    moved[copy] += 1e-3
    assert unpartnered_edges(moved, mesh.faces) > 0


def test_weld_groups_name_the_smallest_copy_and_treat_signed_zeros_alike():
    p = np.array([[0.0, 1, 2], [5, 5, 5], [-0.0, 1, 2], [0.0, 1, 2]])
    assert weld_groups(p).tolist() == [0, 1, 0, 0]
    assert weld_groups(np.eye(3)) is None


def test_weld_groups_match_a_row_by_row_comparison_and_never_weld_a_nan():
    rng = np.random.default_rng(7)
    for d in (3, 5):
        rows = rng.integers(-3, 4, (400, d)).astype(np.float64)  # many repeats, negative values among them
        rows[rng.random(400) < 0.1] *= -0.0  # signed zeros
        rows[rng.integers(0, 400, 12), rng.integers(0, d, 12)] = np.nan
        expect = np.arange(400)
        for i in range(400):  # the smallest row equal to row i (NaN equals nothing, itself included)
            same = np.flatnonzero((rows == rows[i]).all(axis=1))
            expect[i] = same[0] if len(same) else i
        weld = weld_groups(rows)
        assert weld is not None and weld.tolist() == expect.tolist()
        assert (weld[np.isnan(rows).any(axis=1)] == np.flatnonzero(np.isnan(rows).any(axis=1))).all()


@pytest.mark.parametrize("name", sorted(SEAMED))
def test_seams_never_crack_at_any_batch_and_collapse_in_twin_pairs(name, monkeypatch):
    mesh = SEAMED[name]()
    seam_vertices = seam_vertex_count(mesh)
    data, report = _encode(mesh)
    cracks, twins, results, _ = _levels_batch_by_batch(data, monkeypatch)
    assert len(cracks) == report.batches > 1
    assert cracks == [0] * len(cracks)
    for r in results:  # and at every chunk boundary, as a player shows it
        assert unpartnered_edges(r.parts[0].positions_int, r.parts[0].faces) == 0
    assert sum(twins) > 0  # seam vertices were removed in pairs, not kept in the base
    assert report.base_vertices < seam_vertices


@pytest.mark.parametrize("name", sorted(SEAMED))
def test_seamed_meshes_round_trip_exactly_on_the_grid(name):
    mesh = SEAMED[name]()
    data, _ = _encode(mesh, base_codec="plain")
    dec = StreamDecoder()
    results = dec.feed(data)
    assert dec.close().complete
    _assert_exact_round_trip(mesh, results[-1].parts[0])


def test_cube_corners_with_three_copies_stay_in_the_base():
    mesh = shapes.faceted_cube(7)
    data, _ = _encode(mesh)
    base = StreamDecoder().feed(data)[0].parts[0]
    corners = Grid.from_config(base.grid.get_config()).quantize(np.array(
        [[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-1.0, 1.0)]))
    kept = {tuple(p) for p in base.positions_int.tolist()}
    assert all(tuple(c) in kept for c in corners.tolist())
    copies = np.count_nonzero((base.positions_int[:, None, :] == corners[None]).all(axis=2))
    assert copies == 24  # every corner with its three normals


def open_uv_cylinder() -> Mesh:
    """:func:`shapes.uv_torus` without its last band of faces: an open tube whose seam meets both rims."""
    t = shapes.uv_torus(24, 12)
    band = np.arange(t.face_count // 2).reshape(24, 12)[:, :-1].reshape(-1)
    faces = np.concatenate([t.faces[band], t.faces[band + t.face_count // 2]])
    used = np.unique(faces)
    remap = np.full(t.vertex_count, -1)
    remap[used] = np.arange(len(used))
    return Mesh(t.positions[used], remap[faces], attributes={"TEXCOORD_0": t.attributes["TEXCOORD_0"][used]})


def test_a_seam_meeting_an_open_rim_keeps_its_rim_points_and_never_cracks(monkeypatch):
    mesh = open_uv_cylinder()
    data, _ = _encode(mesh)
    grid = StreamDecoder().feed(data)[0].parts[0].grid
    # the input's seam positions, and those of them on the rims (a welded edge with one face)
    weld = weld_groups(mesh.positions)
    seam = np.bincount(weld, minlength=mesh.vertex_count)[weld] > 1
    q = grid.quantize(mesh.positions[seam])
    w = weld[mesh.faces]
    a, b = w.reshape(-1), w[:, [1, 2, 0]].reshape(-1)
    key, count = np.unique(np.minimum(a, b) * len(weld) + np.maximum(a, b), return_counts=True)
    rim = np.zeros(len(weld), bool)
    rim[np.r_[key[count == 1] // len(weld), key[count == 1] % len(weld)]] = True
    rim_seam = grid.quantize(mesh.positions[seam & rim[weld]])
    assert len(rim_seam) == 4  # two rim points, two copies each

    cracks = []
    original = replay_module.apply_batch

    def checked(state, batch):
        topo = original(state, batch)
        cracks.append(unpartnered_edges(state.positions[: state.n, :3], state.faces[: state.m], among=q))
        return topo

    monkeypatch.setattr(replay_module, "apply_batch", checked)
    results = StreamDecoder().feed(data)
    assert len(cracks) > 1 and cracks == [0] * len(cracks)
    base = results[0].parts[0].positions_int
    assert all((base == p).all(axis=1).any() for p in rim_seam)
    seam_left = np.count_nonzero((base[:, None, :] == q[None]).all(axis=2).any(axis=1))
    assert seam_left < len(q)  # the seam itself did coarsen


@pytest.mark.parametrize("embed_from", [0, 0.3])
def test_a_watermarked_textured_mesh_verifies_authentic_with_its_seams_closed(monkeypatch, embed_from):
    mesh = shapes.uv_torus(48, 24)
    rng = np.random.default_rng(7)
    mark = rng.integers(0, 256, (16, 16) if embed_from == 0 else (8, 8)).astype(np.uint8)
    data, report = _encode(mesh, watermark=mark, key=WatermarkKey.generate(rng=rng), mode="exact",
                           embed_from=embed_from)
    cracks, twins, results, dec = _levels_batch_by_batch(data, monkeypatch, key=report.key)
    assert sum(twins) > 0 and cracks == [0] * len(cracks)
    assert dec.verifier.verdict() == "authentic"
    assert np.array_equal(results[-1].watermark, mark)
    # a twin carries nothing and takes no code slot: the carriers are the other splits
    if embed_from == 0:
        assert report.watermark["carriers"] == report.vsplits - sum(twins)
    assert report.watermark["embedded"] == report.watermark["carriers"]


@pytest.mark.corpus
def test_spot_streams_with_a_small_base_exact_attributes_and_no_crack_at_any_batch(monkeypatch, tmp_path):
    from pmwm_codec.format.document import load_document
    from pmwm_codec.stream.asset import encode_asset, plan_asset

    src = corpus_path("spot.glb")
    report = encode_asset(src, tmp_path / "spot.pmw", measure=False, payload_version=1)  # observed through v1 apply_batch
    assert report.base_vertices <= 0.05 * report.vertices
    cracks, twins, results, _ = _levels_batch_by_batch((tmp_path / "spot.pmw").read_bytes(), monkeypatch)
    assert sum(twins) > 0 and cracks == [0] * len(cracks)
    jobs, _, _ = plan_asset(*load_document(src))
    _assert_exact_round_trip(jobs[0].mesh, results[-1].parts[0])


def test_a_decoded_textured_mesh_verifies_through_the_given_positions_path_even_welded():
    """verify_mesh replays the stream's own twins: a reordered copy verifies bit-exactly, and so does
    one whose seam copies were merged into one vertex (as an OBJ export does)."""
    import pmwm_codec
    from pmwm_codec.verify import verify_mesh

    rng = np.random.default_rng(3)
    mark = rng.integers(0, 256, (16, 16)).astype(np.uint8)
    data, report = _encode(shapes.uv_torus(48, 24), watermark=mark, key=WatermarkKey.generate(rng=rng))
    ref = pmwm_codec.decode(data)
    perm = rng.permutation(len(ref.positions))
    inverse = np.argsort(perm)
    r = verify_mesh((ref.positions[perm], inverse[ref.faces]), data, report.key)
    assert r.verdict == "authentic" and r.bit_exact and r.carriers_read == r.carriers_total
    weld = weld_groups(ref.positions)
    used, welded = np.unique(weld, return_inverse=True)
    r = verify_mesh((ref.positions[used], welded[ref.faces]), data, report.key)
    assert r.verdict == "authentic" and r.bit_exact
