"""Face chunks of payload version 2 (spec/bitstream.md §8.6): faces added between existing vertices.

The encoder keeps glued pillows (two faces on one vertex triple, facing opposite ways, whose
vertices all have other faces) out of the simplification and sends them in one face chunk after
every split.  These tests prove the codec round-trips any faces, that the spec's example and
constants are the code's, that hostile face chunks are one-line format errors, and that a pillowed
mesh streams exactly: a smaller base, no pillow before the last chunk, the input at the end.
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
from pmwm_codec.progressive.simplify import glued_pillows, twin_faces
from pmwm_codec.progressive.topology import face_keys
from pmwm_codec.progressive.vsplit import MeshState
from pmwm_codec.stream import StreamDecoder

from test_payload_v2 import _chunk_entries, _encode, _stored, _with_chunk, assert_prefixes_decode_to_whole_chunks
from test_pillows import _pillowed

TETRAHEDRON = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [1, 3, 2]], np.int64)


def _decode(payload, faces_before, n, face_step):
    """Faces (m + appended, 3) after decoding ``payload`` onto the mesh ``faces_before`` over ``n``."""
    before = np.asarray(faces_before, np.int64).reshape(-1, 3)
    state = MeshState(np.zeros((n, 3), np.int64), before, n, len(before) + face_step)
    r2.decode_face_chunk(payload, state, r2.ChunkDecoder(), face_step)
    return state.faces[: state.m]


def _face_multiset(faces) -> list:
    return sorted(map(tuple, face_keys(np.asarray(faces, np.int64).reshape(-1, 3))))


def _spec() -> str:
    text = (Path(__file__).resolve().parents[1] / "spec" / "bitstream.md").read_text()
    return text[text.index("### 8.6 Face chunks"):]


# ---------------------------------------------------------------- the codec


def test_spec_example_is_what_the_encoder_writes_and_decodes_to_the_spec_s_faces():
    block = re.search(r"<!-- face-chunk-example -->\n```\n(.*?)```", _spec(), re.S).group(1)
    stored = bytes.fromhex(block.replace(" ", "").replace("\n", ""))
    assert r2.pack_face_chunk(TETRAHEDRON, 4, [[0, 1, 3], [0, 3, 1]]) == stored
    faces = _decode(stored, TETRAHEDRON, 4, 2)
    assert faces[4:].tolist() == [[0, 1, 3], [0, 3, 1]]


def test_spec_constants_of_face_chunks_match_the_code():
    text = " ".join(_spec().split())
    assert f"`FACE_PROBS = 32 + 5·256 = {r2.FACE_PROBS}`" in text
    assert (r2.F_NEAR_B, r2.F_NEAR_C, r2.F_TWIN) == (0, 1, 2)
    for name, block in (("COUNT", 0), ("GAP", 1), ("RANK_B", 2), ("RANK_C", 3), ("RAW", 4)):
        assert getattr(r2, "FB_" + name) == block
    assert "UInt(block 0) + 1" in text and "a + UInt(block 1)" in text and "Up(a)[UInt(block 2)]" in text
    assert "Near(a, b)[UInt(block 3)]" in text and "a + 1 + UInt(block 4)" in text


def _random_case(draw_seed: int):
    rng = np.random.default_rng(draw_seed)
    n = int(rng.integers(3, 40))
    m = int(rng.integers(0, 60))
    before = np.array([rng.choice(n, 3, replace=False) for _ in range(m)], np.int64).reshape(-1, 3)
    if rng.random() < 0.5 and m:  # faces along the mesh's edges, as pillows are
        picks = before[rng.integers(m, size=int(rng.integers(1, 8)))]
        new = np.stack([picks[:, 0], picks[:, 1], np.roll(picks[:, 2], 1)], 1)
        new = new[(new[:, 0] != new[:, 2]) & (new[:, 1] != new[:, 2])]
    else:
        new = np.zeros((0, 3), np.int64)
    extra = np.array([rng.choice(n, 3, replace=False) for _ in range(int(rng.integers(1, 12)))], np.int64)
    new = np.concatenate([new, extra])
    twins = rng.random(len(new)) < 0.5
    new = np.concatenate([new, new[twins][:, [0, 2, 1]], new[rng.random(len(new)) < 0.1]])  # reverses, repeats
    return before, n, rng.permutation(new)


@settings(max_examples=200, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_any_faces_over_any_mesh_round_trip_as_a_multiset(seed):
    before, n, new = _random_case(seed)
    stored = r2.pack_face_chunk(before, n, new)
    faces = _decode(stored, before, n, len(new))
    assert np.array_equal(faces[: len(before)], before)
    assert _face_multiset(faces[len(before):]) == _face_multiset(new)


def test_a_face_and_its_reverse_cost_one_coded_face_and_neighbours_cost_few_bits():
    """Pillows along mesh edges: both faces of each in one coded row, b and c ranked among
    neighbours; far cheaper than three vertex ids (15 bits each here)."""
    from pmwm_codec import shapes

    sphere = shapes.icosphere(5, 1.0)  # 10,242 vertices
    F = sphere.faces
    rows = F[::37]
    pillows = np.concatenate([rows, rows[:, [0, 2, 1]]])
    stored = r2.pack_face_chunk(F, sphere.vertex_count, pillows)
    assert len(r2.coded_faces(pillows)) == len(rows)
    assert 8 * len(stored) / len(rows) < 16


def _crafted(*items) -> bytes:
    """A face chunk stream of ``(kind, context, value)`` items (kinds of :func:`rc.encode_array`;
    an integer's context is its block number)."""
    kind = [k for k, _, _ in items]
    ctx = [c if k == 0 else 32 + 256 * c for k, c, _ in items]
    return rc.encode_array(np.array(kind), np.array(ctx), np.array([v for _, _, v in items]), r2.FACE_PROBS)


BIT, UINT = 0, 2
HOSTILE = {
    "a rank beyond Up(a)": (_crafted((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 1), (UINT, 2, 3)), 1, "beyond its list"),
    "a vertex beyond the mesh": (_crafted((UINT, 0, 0), (UINT, 1, 9)), 1, "beyond the mesh"),
    "a raw vertex beyond the mesh": (_crafted((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 0), (UINT, 4, 3)), 1,
                                     "beyond the mesh"),
    "b equal to c": (_crafted((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 1), (UINT, 2, 0), (BIT, 1, 0), (UINT, 4, 0)),
                     1, "repeated vertex"),
    "more faces than the entry adds": (_crafted((UINT, 0, 2)), 2, "more faces"),
    "a twin past the entry's faces": (_crafted((UINT, 0, 0), (UINT, 1, 0), (BIT, 0, 1), (UINT, 2, 0), (BIT, 1, 1),
                                               (UINT, 3, 1), (BIT, 2, 1)), 1, "more faces"),
}


@pytest.mark.parametrize("name", sorted(HOSTILE))
def test_a_hostile_face_chunk_is_a_one_line_format_error(name):
    stored, step, words = HOSTILE[name]
    with pytest.raises(FormatError, match=words):
        _decode(stored, TETRAHEDRON, 4, step)


def test_a_face_chunk_cut_short_or_with_trailing_bytes_is_a_format_error():
    from pmwm_codec import shapes

    sphere = shapes.icosphere(3, 1.0)
    new = np.concatenate([sphere.faces[::9], sphere.faces[::9, [0, 2, 1]]])
    stored = r2.pack_face_chunk(sphere.faces, sphere.vertex_count, new)
    for cut in range(len(stored)):
        with pytest.raises(FormatError):
            _decode(stored[:cut], sphere.faces, sphere.vertex_count, len(new))
    with pytest.raises(FormatError, match="does not end"):
        _decode(stored + b"\0", sphere.faces, sphere.vertex_count, len(new))


# ---------------------------------------------------------------- pillowed meshes through the encoder


@pytest.fixture(scope="module")
def pillowed():
    """A sphere with glued pillows and flaps, encoded with payload 2 and 1: (mesh, v2 bytes, v1 bytes)."""
    mesh = _pillowed(5, 40, False)
    assert glued_pillows(mesh.faces).sum() >= 8 and (twin_faces(mesh.faces) & ~glued_pillows(mesh.faces)).any()
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


def test_glued_pillows_arrive_in_one_face_chunk_after_every_split(pillowed):
    mesh, v2, _ = pillowed
    glued = glued_pillows(mesh.faces)
    entries = read_header(v2).extension["chunks"]
    assert [e["splits"] == 0 for e in entries] == [False] * (len(entries) - 1) + [True]
    assert entries[-1]["faceCount"] - entries[-2]["faceCount"] == glued.sum()
    levels = _levels(v2)
    flaps = int((twin_faces(mesh.faces) & ~glued).sum())
    for level in levels[:-1]:  # flaps' pillows travel with their tips; glued ones only at the end
        assert twin_faces(level.faces).sum() <= flaps
    final = levels[-1]
    assert final.vertices == mesh.vertex_count and final.faces_count == mesh.face_count
    decoded = pmwm_codec.decode(v2)
    grid = read_header(v2).extension["grid"]
    assert _position_faces(decoded.positions, decoded.faces, grid) == _position_faces(mesh.positions, mesh.faces, grid)


def _position_faces(P, F, grid) -> list:
    """Faces as rotation-normalised triples of grid points (independent of vertex numbering)."""
    q = np.round((np.asarray(P) - grid["origin"]) / grid["step"]).astype(np.int64)
    out = []
    for f in F:
        t = [tuple(q[i]) for i in f]
        out.append(min(t[r:] + t[:r] for r in range(3)))
    return sorted(out)


def test_the_base_holds_no_glued_pillow_where_version_1_keeps_them_all(pillowed):
    """Version 1 cannot send a face chunk: a split never makes a face on three existing vertices,
    so its base keeps every pillow of the input (and the simplifier works around them)."""
    mesh, v2, v1 = pillowed
    base2, base1 = _levels(v2)[0], _levels(v1)[0]
    assert twin_faces(base1.faces).sum() == twin_faces(mesh.faces).sum()
    assert twin_faces(base2.faces).sum() == (twin_faces(mesh.faces) & ~glued_pillows(mesh.faces)).sum()


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
    from pmwm_codec.verify import verify_stream
    from pmwm_codec.watermark.key import WatermarkKey

    mesh = pillowed[0]
    image = (np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)
    data, key = _encode(mesh, 2, watermark=image, key=WatermarkKey.generate(rng=np.random.default_rng(4)))
    assert verify_stream(io.BytesIO(data), key).verdict == "authentic"
    gltf, binary, _, entries = _chunk_entries(data)
    k = len(entries) - 1
    assert entries[k]["splits"] == 0
    stored = bytearray(_stored(gltf, binary, entries[k]))
    stored[-1] ^= 1
    try:
        verdict = verify_stream(io.BytesIO(_with_chunk(data, k, bytes(stored))), key).verdict
    except PmwError:
        return
    assert verdict != "authentic"


def test_two_pillowed_primitives_send_their_face_chunks_after_every_split_of_both():
    meshes = [_pillowed(8, 30, False), _pillowed(9, 30, False)]
    data, _ = _encode(meshes, 2)
    levels = _levels(data)
    adds_no_vertex = [i for i in range(1, len(levels)) if levels[i].vertices == levels[i - 1].vertices]
    assert adds_no_vertex == [len(levels) - 2, len(levels) - 1]
    final = levels[-1]
    assert final.vertices == sum(m.vertex_count for m in meshes)
    assert final.faces_count == sum(m.face_count for m in meshes)
