"""Face chunks of payload version 2 (spec/bitstream.md §8.6): faces, and the vertices only they name.

The encoder keeps pillows (two faces on one vertex triple, facing opposite ways) out of the
simplification, with the flaps' tips (vertices with pillow faces only), and sends them in one face
chunk after every split.  These tests prove the codec round-trips any faces and new vertices, that
the spec's examples and constants are the code's, that hostile face chunks are one-line format
errors, and that a pillowed mesh streams exactly: no pillow before the last chunk, the input at the end.
"""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import pmwm_codec
from pmwm_codec.errors import FormatError, PmwError
from pmwm_codec.format import rangecoder as rc
from pmwm_codec.format import read_header
from pmwm_codec.format import records_v2 as r2
from pmwm_codec import shapes
from pmwm_codec.format.glb import split_glb
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.progressive.simplify import deferred_pillows, specks, twin_faces
from pmwm_codec.progressive.topology import face_keys
from pmwm_codec.progressive.vsplit import MeshState
from pmwm_codec.stream import StreamDecoder

from test_payload_v2 import (_chunk_entries, _encode, _stored, _with_chunk, assert_prefixes_decode_to_whole_chunks,
                             face_set)
from test_pillows import _pillowed

TETRAHEDRON = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int64)
TETRA_VALUES = np.arange(12, dtype=np.int64).reshape(4, 3) * 10


def _decode(payload, values_before, faces_before, vertex_step, face_step):
    """``(values, faces)`` after decoding ``payload`` onto the mesh of ``values_before`` (n, D) and
    ``faces_before`` (m, 3)."""
    values = np.asarray(values_before, np.int64)
    before = np.asarray(faces_before, np.int64).reshape(-1, 3)
    n, D = values.shape
    state = MeshState(np.concatenate([values, np.zeros((vertex_step, D), np.int64)]), before, n + vertex_step,
                      len(before) + face_step)
    state.n = n
    r2.decode_face_chunk(payload, state, r2.ChunkDecoder(), vertex_step, face_step)
    return state.positions[: state.n], state.faces[: state.m]


def _face_multiset(faces) -> list:
    return sorted(map(tuple, face_keys(np.asarray(faces, np.int64).reshape(-1, 3))))


def _spec() -> str:
    text = (Path(__file__).resolve().parents[1] / "spec" / "bitstream.md").read_text()
    return text[text.index("### 8.6 Face chunks"):]


# ---------------------------------------------------------------- the codec


def _spec_bytes(name: str) -> bytes:
    block = re.search(rf"<!-- {name} -->\n```\n(.*?)```", _spec(), re.S).group(1)
    return bytes.fromhex(block.replace(" ", "").replace("\n", ""))


def test_spec_example_is_what_the_encoder_writes_and_decodes_to_the_spec_s_faces():
    stored = _spec_bytes("face-chunk-example")
    assert r2.pack_face_chunk(TETRA_VALUES, TETRAHEDRON, [[0, 1, 3], [0, 3, 1]])[0] == stored
    values, faces = _decode(stored, TETRA_VALUES, TETRAHEDRON, 0, 2)
    assert faces[4:].tolist() == [[0, 1, 3], [0, 3, 1]] and np.array_equal(values, TETRA_VALUES)


def test_spec_flap_example_is_what_the_encoder_writes_and_decodes_to_the_spec_s_vertex():
    stored = _spec_bytes("face-chunk-flap-example")
    assert r2.pack_face_chunk(TETRA_VALUES, TETRAHEDRON, [[0, 1, 4], [1, 0, 4]], [[7, 9, 11]])[0] == stored
    values, faces = _decode(stored, TETRA_VALUES, TETRAHEDRON, 1, 2)
    assert faces[4:].tolist() == [[0, 1, 4], [0, 4, 1]] and values[4].tolist() == [7, 9, 11]


def test_spec_speck_example_is_what_the_encoder_writes_and_decodes_to_the_spec_s_vertices():
    stored = _spec_bytes("face-chunk-speck-example")
    new_values = [[91, 101, 111], [91, 101, 111], [92, 101, 111]]
    assert r2.pack_face_chunk(TETRA_VALUES, TETRAHEDRON, [[4, 5, 6]], new_values)[0] == stored
    values, faces = _decode(stored, TETRA_VALUES, TETRAHEDRON, 3, 1)
    assert faces[4:].tolist() == [[4, 5, 6]] and values[4:].tolist() == new_values


def test_spec_constants_of_face_chunks_match_the_code():
    text = " ".join(_spec().split())
    assert f"`FACE_PROBS = 32 + 9·256 = {r2.FACE_PROBS}`" in text
    assert (r2.F_NEAR_B, r2.F_NEAR_C, r2.F_TWIN, r2.F_FRESH) == (0, 1, 2, 3)
    for name, block in (("COUNT", 0), ("GAP", 1), ("RANK_B", 2), ("RANK_C", 3), ("RAW", 4), ("VALUE", 5)):
        assert getattr(r2, "FB_" + name) == block
    assert "UInt(block 0) + 1" in text and "a + UInt(block 1)" in text and "Vertex(0, Up(a), 2)" in text
    assert "Vertex(1, Near(a, b), 3)" in text and "a + 1 + UInt(block 4)" in text
    assert "DecodeBit(3)" in text and "SInt(block 5 + min(q, 3))" in text


def _random_case(seed: int):
    """``(values (n, D), faces (m, 3), new faces, new values)``: a random mesh and random faces to add,
    some along its edges (as pillows are), some reversed or repeated, some naming new vertices (one
    or two to a face beside an existing vertex; three that other faces name too: fins and bubbles
    beyond the mesh; or three of their own: specks, parts of new vertices only)."""
    rng = np.random.default_rng(seed)
    n, D = int(rng.integers(3, 40)), int(rng.integers(3, 6))
    values = rng.integers(0, 1 << 16, (n, D))
    m = int(rng.integers(0, 60))
    before = np.array([rng.choice(n, 3, replace=False) for _ in range(m)], np.int64).reshape(-1, 3)
    new = [rng.choice(n, 3, replace=False) for _ in range(int(rng.integers(0, 10)))]
    if m:  # along the mesh's edges
        for f in before[rng.integers(m, size=int(rng.integers(0, 6)))]:
            if f[0] != f[1]:
                new.append([f[0], f[1], before[rng.integers(m), 2]])
    t = int(rng.integers(0, 7))
    for j in range(t):  # a new vertex off an existing pair, sometimes a second one beside it
        x = rng.choice(n, 2, replace=False)
        new.append([x[0], x[1], n + j])
        if j and rng.random() < 0.5:
            new.append([x[0], n + j - 1, n + j])
    for j in range(2, t):  # faces of new vertices only that others name too (a fin, a bubble), any corner first
        if rng.random() < 0.4:
            new.append(list(n + rng.permutation([j, j - 1, int(rng.integers(0, j - 1))])))
    new = np.array([f for f in new if len(set(int(v) for v in f)) == 3] or [[0, 1, 2]], np.int64)
    twins = rng.random(len(new)) < 0.5
    new = np.concatenate([new, new[twins][:, [0, 2, 1]], new[rng.random(len(new)) < 0.1]])
    specks = int(rng.integers(0, 3))
    for j in range(specks):  # a triangle of three new vertices, sometimes with its reverse or a copy
        x = n + t + 3 * j + rng.permutation(3)
        extra = [x[[0, 2, 1]]] if rng.random() < 0.5 else [x] * int(rng.random() < 0.3)
        new = np.concatenate([new, np.array([x, *extra], np.int64)])
    t += 3 * specks
    used = np.unique(new[new >= n]) - n
    keep = np.full(max(t, 1), -1)
    keep[used] = np.arange(len(used))  # renumber the new vertices some face names
    new = np.where(new >= n, n + keep[np.clip(new - n, 0, len(keep) - 1)], new)
    return values, before, rng.permutation(new), rng.integers(0, 1 << 16, (len(used), D))


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_any_faces_and_new_vertices_over_any_mesh_round_trip(seed):
    values, before, new, new_values = _random_case(seed)
    n, t = len(values), len(new_values)
    stored, order = r2.pack_face_chunk(values, before, new, new_values)
    got_values, faces = _decode(stored, values, before, t, len(new))
    final = np.arange(n + t)
    final[n + order] = n + np.arange(t)  # the caller's new vertex -> the id it decodes as
    assert np.array_equal(faces[: len(before)], before)
    assert _face_multiset(faces[len(before):]) == _face_multiset(final[new])
    assert np.array_equal(got_values[:n], values) and np.array_equal(got_values[n:], new_values[order])


def test_a_face_and_its_reverse_cost_one_coded_face_and_neighbours_cost_few_bits():
    """Pillows along mesh edges: both faces of each in one coded row, b and c ranked among
    neighbours; far cheaper than three vertex ids (15 bits each here)."""
    from pmwm_codec import shapes

    sphere = shapes.icosphere(5, 1.0)  # 10,242 vertices
    F = sphere.faces
    rows = F[::37]
    pillows = np.concatenate([rows, rows[:, [0, 2, 1]]])
    stored, _ = r2.pack_face_chunk(sphere.positions.astype(np.int64), F, pillows)
    assert len(r2.coded_faces(pillows)) == len(rows)
    assert 8 * len(stored) / len(rows) < 16


def _crafted(*items) -> bytes:
    """A face chunk stream of ``(kind, context, value)`` items (kinds of :func:`rc.encode_array`;
    an integer's context is its block number)."""
    kind = [k for k, _, _ in items]
    ctx = [c if k == 0 else 32 + 256 * c for k, c, _ in items]
    return rc.encode_array(np.array(kind), np.array(ctx), np.array([v for _, _, v in items]), r2.FACE_PROBS)


BIT, UINT, SINT = 0, 2, 3
_FACE = ((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 1), (UINT, 2, 0))  # one face, a = 0, b = Up(0)[0] = 1
HOSTILE = {  # (stored, vertex step, face step, words of the error)
    "a rank beyond Up(a)": (_crafted((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 1), (UINT, 2, 3)), 0, 1, "beyond its list"),
    "a vertex beyond the mesh": (_crafted((UINT, 0, 0), (UINT, 1, 9)), 0, 1, "beyond the mesh"),
    "a raw vertex beyond the mesh": (_crafted(*_FACE, (BIT, 1, 0), (BIT, 3, 0), (UINT, 4, 3)), 0, 1,
                                     "beyond the mesh"),
    "b equal to c": (_crafted((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 0), (BIT, 3, 0), (UINT, 4, 0), (BIT, 1, 0),
                              (BIT, 3, 0), (UINT, 4, 0)), 0, 1, "repeated vertex"),
    "more faces than the entry adds": (_crafted((UINT, 0, 2)), 0, 2, "more faces"),
    "a twin past the entry's faces": (_crafted(*_FACE, (BIT, 1, 1), (UINT, 3, 1), (BIT, 2, 1)), 0, 1, "more faces"),
    "a fresh vertex the entry does not add": (_crafted(*_FACE, (BIT, 1, 0), (BIT, 3, 1)), 0, 1, "more new vertices"),
    "a new vertex never named": (_crafted(*_FACE, (BIT, 1, 1), (UINT, 3, 1), (BIT, 2, 0)), 1, 1, "fewer new"),
    "a raw id of a new vertex not yet named": (_crafted(*_FACE, (BIT, 1, 0), (BIT, 3, 0), (UINT, 4, 3)), 1, 1,
                                               "beyond the mesh"),
    "a first vertex past the next new one": (_crafted((UINT, 0, 0), (UINT, 1, 5)), 3, 1, "beyond the mesh"),
    "a first new vertex the entry does not add": (_crafted((UINT, 0, 0), (UINT, 1, 4)), 0, 1, "more new vertices"),
    "a new value out of range": (_crafted(*_FACE, (BIT, 1, 0), (BIT, 3, 1), (BIT, 2, 0), (SINT, 5, 1 << 31),
                                          (SINT, 6, 0), (SINT, 7, 0)), 1, 1, "value out of range"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_a_hostile_face_chunk_is_a_one_line_format_error(name):
    stored, vertex_step, face_step, words = HOSTILE[name]
    with pytest.raises(FormatError, match=words):
        _decode(stored, TETRA_VALUES, TETRAHEDRON, vertex_step, face_step)


def test_a_face_chunk_cut_short_or_with_trailing_bytes_is_a_format_error():
    from pmwm_codec import shapes

    sphere = shapes.icosphere(3, 1.0)
    values = np.round(sphere.positions * 1000).astype(np.int64) + 1000
    n = len(values)
    new = np.concatenate([sphere.faces[::9], sphere.faces[::9, [0, 2, 1]], [[0, 1, n], [1, 0, n]]])
    stored, _ = r2.pack_face_chunk(values, sphere.faces, new, [[5, 6, 7]])
    for cut in range(len(stored)):
        with pytest.raises(FormatError):
            _decode(stored[:cut], values, sphere.faces, 1, len(new))
    with pytest.raises(FormatError, match="does not end"):
        _decode(stored + b"\0", values, sphere.faces, 1, len(new))


# ---------------------------------------------------------------- pillowed meshes through the encoder


@pytest.fixture(scope="module")
def pillowed():
    """A sphere with glued pillows and flaps, encoded with payload 2 and 1: (mesh, v2 bytes, v1 bytes)."""
    mesh = _pillowed(5, 40, False)
    tips = np.setdiff1d(np.arange(mesh.vertex_count), mesh.faces[~twin_faces(mesh.faces)])
    assert deferred_pillows(mesh.faces).sum() >= 16 and len(tips) >= 4
    out = []
    for version in (2, 1):
        buf = io.BytesIO()
        pmwm_codec.encode(mesh, buf, measure=False, payload_version=version)
        out.append(buf.getvalue())
    return (mesh, *out)


def _levels(data):
    dec = StreamDecoder()
    levels = dec.feed(data)
    dec.close()
    return levels


def test_pillows_and_flap_tips_arrive_in_one_face_chunk_after_every_split(pillowed):
    mesh, v2, _ = pillowed
    late = deferred_pillows(mesh.faces)
    tips = np.setdiff1d(np.arange(mesh.vertex_count), mesh.faces[~late])
    header = read_header(v2)
    entries = header.extension["chunks"]
    assert header.extension["firstFaceChunk"] == len(entries) - 1
    assert [e.get("faces", False) for e in entries] == [False] * (len(entries) - 1) + [True]
    assert entries[-1]["faceCount"] - entries[-2]["faceCount"] == late.sum()
    assert entries[-1]["vertexCount"] - entries[-2]["vertexCount"] == len(tips)
    levels = _levels(v2)
    for level in levels[:-1]:
        assert twin_faces(level.faces).sum() == 0
    final = levels[-1]
    assert final.vertices == mesh.vertex_count and final.faces_count == mesh.face_count
    grid = read_header(v2).extension["grid"]
    original = np.round((mesh.positions - grid["origin"]) / grid["step"]).astype(np.int64)
    assert face_set(final.positions_int, final.faces) == face_set(original, mesh.faces)


def test_info_counts_the_splits_encode_counts_not_a_face_chunks_tips(pillowed):
    """``pmw info``'s ``vsplits`` is the number of vertex splits, as ``pmw encode`` reports it: a face chunk's
    new vertices (flap tips) arrive with its faces, not by splits (info used to add them)."""
    from pmwm_codec.format.inspect import inspect

    mesh, v2, _ = pillowed
    tips = np.setdiff1d(np.arange(mesh.vertex_count), mesh.faces[~deferred_pillows(mesh.faces)])
    report = pmwm_codec.encode(mesh, io.BytesIO(), measure=False)
    info = inspect(v2)
    assert info["vsplits"] == report["vsplits"] == info["vertices"] - info["base_vertices"] - len(tips)


def test_the_base_holds_no_pillow_where_version_1_keeps_them_all(pillowed):
    """Version 1 cannot send a face chunk: a split never makes a face on three existing vertices,
    so its base keeps every pillow of the input, and every flap's tip."""
    mesh, v2, v1 = pillowed
    base2, base1 = _levels(v2)[0], _levels(v1)[0]
    assert twin_faces(base1.faces).sum() == twin_faces(mesh.faces).sum()
    assert twin_faces(base2.faces).sum() == 0


def test_every_prefix_of_a_file_with_a_face_chunk_decodes_to_whole_chunks_only(pillowed):
    _, v2, _ = pillowed
    last_start = _levels(v2)[-2].bytes_read
    assert_prefixes_decode_to_whole_chunks(v2, list(range(0, last_start, 97)) + list(range(last_start, len(v2) + 1)))


def test_flipped_bits_in_a_face_chunk_give_a_format_error_or_a_valid_mesh(pillowed):
    _, v2, _ = pillowed
    gltf, binary, _, entries = _chunk_entries(v2)
    k = len(entries) - 1
    rng = np.random.default_rng(3)
    errors = 0
    for _ in range(40):
        stored = bytearray(_stored(gltf, binary, entries[k]))
        bit = int(rng.integers(8 * len(stored)))
        stored[bit // 8] ^= 1 << (bit % 8)
        try:
            mesh = pmwm_codec.decode(_with_chunk(v2, k, bytes(stored)))
        except PmwError:
            errors += 1
            continue
        assert (mesh.faces < len(mesh.positions)).all()
        assert (mesh.faces[:, 0] != mesh.faces[:, 1]).all() and (mesh.faces[:, 1] != mesh.faces[:, 2]).all()
    assert errors > 25


def test_a_watermarked_pillowed_file_verifies_authentic_and_its_face_chunk_is_covered_by_a_mac(pillowed):
    """The face chunk carries no watermark slot, but its MAC binds it: change it and the verdict falls."""
    from pmwm_codec.verify import verify_mesh, verify_stream
    from pmwm_codec.watermark.key import WatermarkKey

    mesh = pillowed[0]
    image = (np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)
    data, key = _encode(mesh, 2, watermark=image, key=WatermarkKey.generate(rng=np.random.default_rng(4)))
    assert verify_stream(io.BytesIO(data), key).verdict == "authentic"
    final = pmwm_codec.decode(data)  # the decoded mesh read back against the file: the tips come from it
    assert verify_mesh((final.positions, final.faces), data, key).verdict == "authentic"
    gltf, binary, _, entries = _chunk_entries(data)
    k = len(entries) - 1
    assert entries[k]["faces"]
    stored = bytearray(_stored(gltf, binary, entries[k]))
    stored[-1] ^= 1
    try:
        verdict = verify_stream(io.BytesIO(_with_chunk(data, k, bytes(stored))), key).verdict
    except PmwError:
        return
    assert verdict != "authentic"


def test_two_pillowed_primitives_send_their_face_chunks_after_every_split_of_both():
    from pmwm_codec.format.inspect import inspect

    meshes = [_pillowed(8, 30, False), _pillowed(9, 30, False)]
    data, _ = _encode(meshes, 2)
    rows = inspect(data)["chunks"]  # in stream order
    assert [r["face_chunk"] for r in rows] == [False] * (len(rows) - 2) + [True, True]
    assert {r["primitive"] for r in rows[-2:]} == {0, 1}
    final = _levels(data)[-1]
    assert final.vertices == sum(m.vertex_count for m in meshes)
    assert final.faces_count == sum(m.face_count for m in meshes)


def _with_first_face_chunk(data: bytes, value) -> bytes:
    """The file with its extension's ``firstFaceChunk`` set to ``value`` (None: removed)."""
    from pmwm_codec.format.extension import EXTENSION_NAME
    from pmwm_codec.format.glb import glb_parts, split_glb

    gltf, binary = split_glb(data)
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
    ext.pop("firstFaceChunk", None)
    if value is not None:
        ext["firstFaceChunk"] = value
    return b"".join(glb_parts(gltf, [bytes(binary)], len(binary)))


@pytest.mark.parametrize("shift, words", [(-10**6, "firstFaceChunk"), (10**6, "firstFaceChunk"), ("1", "firstFaceChunk"),
                                          (None, None), (-1, None), (1, None)])
def test_a_wrong_first_face_chunk_is_a_one_line_format_error(pillowed, shift, words):
    """Out of range, not an integer, or the wrong chunks taken for face chunks (or none): refused,
    never a mesh."""
    _, v2, _ = pillowed
    first = read_header(v2).extension["firstFaceChunk"]
    value = shift if shift is None or isinstance(shift, str) else max(first + shift, -1) if abs(shift) < 10 else shift
    with pytest.raises(PmwError, match=words):
        pmwm_codec.decode(_with_first_face_chunk(v2, value))


def test_face_chunks_need_payload_version_2(pillowed):
    _, _, v1 = pillowed
    with pytest.raises(PmwError, match="firstFaceChunk needs chunk payload version 2"):
        pmwm_codec.decode(_with_first_face_chunk(v1, 1))


def test_the_report_measures_the_flaps_tips_where_the_face_chunk_puts_them():
    """The report's distortion compares every input vertex with its decoded place, tips included:
    a tip put anywhere but on its own grid point would cost far more than grid 16's rounding."""
    mesh = _pillowed(5, 40, False)
    report = pmwm_codec.encode(mesh, io.BytesIO())
    assert report["vertices"] == mesh.vertex_count and report["distortion"]["psnr_db"] > 95


def test_a_cut_before_or_after_the_face_chunk_decodes_to_that_level_and_keeps_its_macs():
    """A cut keeps ``firstFaceChunk`` as it is (the kept chunks keep their kind), so ``baseMac``,
    which covers it, still verifies."""
    from pmwm_codec.verify import verify_stream
    from pmwm_codec.watermark.key import WatermarkKey

    image = (np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)
    data, key = _encode(_pillowed(6, 40, False), 2, watermark=image,
                        key=WatermarkKey.generate(rng=np.random.default_rng(5)))
    levels = _levels(data)
    for keep in (len(levels) - 2, len(levels) - 1):
        cut = pmwm_codec.cut(data, keep)
        assert read_header(cut).extension["firstFaceChunk"] == read_header(data).extension["firstFaceChunk"]
        got = _levels(cut)[-1]
        assert np.array_equal(got.positions_int, levels[keep].positions_int)
        assert np.array_equal(got.faces, levels[keep].faces)
        report = verify_stream(io.BytesIO(cut), key)
        assert report.mac["failed"] == [] and report.mac["checked"] == keep + 1


def test_reverse_pairs_pair_each_triple_s_rarer_orientation():
    from pmwm_codec.progressive.simplify import reverse_pairs

    faces = np.array([[0, 1, 2], [0, 2, 1], [1, 2, 0],  # a pillow and a duplicate: one pair
                      [3, 4, 5], [3, 5, 4], [4, 3, 5], [3, 4, 5],  # two pillows on one triple
                      [6, 7, 8], [7, 8, 6],  # a face twice, the same way: no pair
                      [0, 1, 3]])
    assert reverse_pairs(faces).tolist() == [True, True, False, True, True, True, True, False, False, False]
    assert np.array_equal(reverse_pairs(faces[:2]), twin_faces(faces[:2]))


def test_pillows_laid_on_surface_faces_leave_the_surface_whole_in_every_level():
    """A pillow on a triple that is also a surface face (three faces there: the scans' "pillow plus
    duplicate") makes three non-manifold edges; deferring the pair leaves the surface face, so no
    level before the face chunk has an edge of more than two faces, and the last is the input."""
    from pmwm_codec import shapes
    from pmwm_codec.progressive.topology import edge_table

    sphere = shapes.icosphere(3, 1.0, noise=0.02)
    picked = sphere.faces[::23]
    mesh = pmwm_codec.mesh.Mesh(sphere.positions, np.concatenate([sphere.faces, picked[:, [0, 2, 1]], picked]))
    data, _ = _encode(mesh, 2)
    levels = _levels(data)
    for level in levels[:-1]:
        assert edge_table(level.faces, level.vertices).count.max() <= 2
    grid = read_header(data).extension["grid"]
    original = np.round((mesh.positions - grid["origin"]) / grid["step"]).astype(np.int64)
    assert face_set(levels[-1].positions_int, levels[-1].faces) == face_set(original, mesh.faces)
    assert levels[0].vertices <= 64


# --- specks: parts of three vertices on one grid point, sent as faces of new vertices only ---------


def _draco_method(data: bytes) -> int:
    """The Draco base's encoding method byte (0 sequential, 1 edgebreaker)."""
    gltf, binary = split_glb(data)
    view = gltf["bufferViews"][gltf["meshes"][0]["primitives"][0]["extensions"]["KHR_draco_mesh_compression"]
                               ["bufferView"]]
    blob = binary[view.get("byteOffset", 0):][: view["byteLength"]]
    assert blob[:5] == b"DRACO"
    return blob[8]


def test_specks_arrive_in_the_face_chunk_and_the_draco_base_keeps_edgebreaker():
    mesh = shapes.specks()  # two specks: a face alone, a face with its reverse
    grid = Grid.fit(mesh.positions, 14)
    late = specks(grid.quantize(mesh.positions), mesh.faces)
    assert late.sum() == 3 and late[-3:].all()
    out = {}
    for version in (2, 1):
        buf = io.BytesIO()
        pmwm_codec.encode(mesh, buf, measure=False, grid_bits=14, payload_version=version, base_codec="draco")
        out[version] = buf.getvalue()
    assert _draco_method(out[2]) == 1  # edgebreaker: the base's grid positions are distinct
    assert _draco_method(out[1]) == 0  # version 1 keeps the specks in the base: sequential coding
    entries = read_header(out[2]).extension["chunks"]
    assert entries[-1].get("faces") and entries[-1]["vertexCount"] - entries[-2]["vertexCount"] == 6
    for version in (2, 1):  # both exact on the grid
        got = pmwm_codec.decode(out[version])
        assert face_set(grid.quantize(got.positions), got.faces) == face_set(grid.quantize(mesh.positions), mesh.faces)
    base = _levels(out[2])[0]
    from pmwm_codec.stream.chunking import default_base_target

    assert len(base.positions_int) == default_base_target(mesh.vertex_count - 6)  # the sphere's own base
    assert len(np.unique(base.positions_int, axis=0)) == len(base.positions_int)  # no speck vertex in it


def test_specks_need_three_vertices_of_their_own_on_one_grid_point():
    P = np.array([[0, 0, 0]] * 3 + [[5, 5, 5]] * 4 + [[1, 2, 3], [4, 5, 6], [7, 8, 9], [9, 9, 9]], np.int64)
    F = np.array([[0, 1, 2], [0, 2, 1],            # a speck and its reverse: deferred
                  [3, 4, 5], [4, 5, 6],            # four vertices on one point: not a speck of three
                  [7, 8, 9], [7, 9, 10],           # a real surface
                  [7, 8, 1]], np.int64)            # ... naming a vertex of the first point: not deferred
    assert specks(P, F).tolist() == [False] * 7
    assert specks(P, F[[0, 1, 2, 3, 4, 5]]).tolist() == [True, True, False, False, False, False]


def test_faces_of_new_vertices_that_other_faces_name_are_coded_in_an_order_the_decoder_can_follow():
    # (4,6,7) names 4, 6, 7 as 4, 5, 6; (5,6,8) in that order would start at the next new vertex, 7, and
    # name 6 (numbered 5) after it: a raw id coded after a face's first vertex.  The encoder takes the faces
    # of new vertices only by their first named vertex instead: (6,8,5) rotated, from 5 (6's number) on.
    for new in ([[4, 6, 7], [5, 6, 8]], [[4, 5, 8], [5, 6, 7]], [[0, 1, 6], [4, 5, 6], [5, 6, 7], [4, 7, 8]]):
        new = np.array(new, np.int64)
        values = np.arange(15, dtype=np.int64).reshape(5, 3) * 7
        stored, order = r2.pack_face_chunk(TETRA_VALUES, TETRAHEDRON, new, values)
        got, faces = _decode(stored, TETRA_VALUES, TETRAHEDRON, 5, len(new))
        final = np.arange(9)
        final[4 + order] = 4 + np.arange(5)  # the caller's new vertex -> the id it decodes as
        assert _face_multiset(faces[4:]) == _face_multiset(final[new])
        assert np.array_equal(got[4:], values[order])


@pytest.mark.parametrize("vertex_step, face_step", [(20_000_000, 2), (0, 50_000_000)])
def test_a_face_chunk_claiming_more_than_its_bytes_can_code_is_refused_before_any_room_is_made(vertex_step,
                                                                                                 face_step):
    """Every new value and face costs a coded decision, and a byte pays for at most
    :data:`~pmwm_codec.format.rangecoder.MAX_DECISIONS_PER_BYTE` of them: an index entry claiming millions
    for a few bytes is refused by name, on a state that grows only as it is decoded (no room made first)."""
    import tracemalloc

    stored = _spec_bytes("face-chunk-example")
    state = MeshState(TETRA_VALUES, TETRAHEDRON, 4 + vertex_step, 4 + face_step, grow=True)
    tracemalloc.start()
    try:
        with pytest.raises(FormatError, match=f"adds more than its {len(stored)} bytes can code"):
            r2.decode_face_chunk(stored, state, r2.ChunkDecoder(), vertex_step, face_step)
        assert tracemalloc.get_traced_memory()[1] < 1 << 20
    finally:
        tracemalloc.stop()
    values, faces = _decode(stored, TETRA_VALUES, TETRAHEDRON, 0, 2)  # the honest entry still decodes
    assert faces[4:].tolist() == [[0, 1, 3], [0, 3, 1]]
