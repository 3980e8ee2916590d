"""Chunk payload version 2 (spec/bitstream.md §8): the range coder, and v2 files against v1 files.

A v2 file codes the same batches as a v1 file of the same input and options, so both decode to the
same mesh at every chunk; the watermark rides in the values and reads the same; hostile payloads
give a FormatError (never a crash or a hang).
"""

from __future__ import annotations

import base64
import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmwm_codec import shapes
from pmwm_codec.errors import FormatError, PmwError
from pmwm_codec.format import rangecoder as rc
from pmwm_codec.format import records_v2
from pmwm_codec.format import read_header
from pmwm_codec.format.extension import EXTENSION_NAME, chunk_start, digest
from pmwm_codec.format.glb import glb_parts, split_glb
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive import topology
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.stream.encoder import PrimitiveJob, encode_document
from pmwm_codec.verify import verify_mesh, verify_stream
from pmwm_codec.watermark.key import WatermarkKey

from conftest import GENERATED, corpus_path
from samples import edit_chunk_table
from test_pillows import _pillowed
from test_golden import _sphere_with_attributes


def _encode(mesh, version, **options) -> tuple:
    """(bytes, key) of ``mesh`` (a Mesh or a list: one primitive each) at payload ``version``."""
    buf = io.BytesIO()
    options = dict(min_chunk_splits=30, measure=False, payload_version=version, **options)
    if isinstance(mesh, Mesh):
        report = encode_mesh(mesh, buf, **options)
    else:
        doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
               "meshes": [{"primitives": [{} for _ in mesh]}]}
        report = encode_document(doc, b"", [PrimitiveJob(m, 0, i) for i, m in enumerate(mesh)], buf, **options)
    return buf.getvalue(), report.key


def _levels(data, key=None) -> list:
    dec = StreamDecoder(key)
    results = dec.feed(data)
    assert dec.close().complete
    return results


def _assert_same_levels(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert (x.vertices, x.faces_count) == (y.vertices, y.faces_count)
        assert np.array_equal(x.positions_int, y.positions_int)
        assert np.array_equal(x.faces, y.faces)
        for p, q in zip(x.parts, y.parts):
            assert np.array_equal(p.attributes_int, q.attributes_int)
        if x.watermark is not None or y.watermark is not None:
            assert np.array_equal(x.watermark, y.watermark)


# ---------------------------------------------------------------- range coder


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), st.integers(0, 5), st.integers(-(2**32) + 1, 2**32 - 1)), max_size=200))
def test_range_coder_round_trips_any_bits_and_integers_under_any_contexts(items):
    kind = np.array([k for k, _, _ in items], np.int64)
    ctx = np.array([c if k < 2 else 16 + c * rc.INT_BLOCK for k, c, _ in items], np.int64)
    values = np.array([(x & 1) if k < 2 else (abs(x) if k == 2 else x) for k, _, x in items], np.int64)
    n_probs = 16 + 6 * rc.INT_BLOCK
    coded = rc.encode_array(kind, ctx, values, n_probs)
    assert np.array_equal(rc.decode_array(coded, kind, ctx, n_probs), values)


def test_range_coder_refuses_a_stream_cut_short_or_with_trailing_bytes():
    rng = np.random.default_rng(3)
    kind = np.zeros(500, np.int64)
    ctx = rng.integers(0, 4, 500)
    values = (rng.random(500) < 0.3).astype(np.int64)
    coded = rc.encode_array(kind, ctx, values, 4)
    with pytest.raises(FormatError):
        rc.decode_array(coded[:-1], kind, ctx, 4)
    with pytest.raises(FormatError):
        rc.decode_array(coded + b"\x00", kind, ctx, 4)


def test_skewed_bits_cost_far_less_than_a_bit_each():
    values = np.zeros(4000, np.int64)
    values[::100] = 1
    coded = rc.encode_array(np.zeros(4000, np.int64), np.zeros(4000, np.int64), values, 1)
    assert 8 * len(coded) < 4000 * 0.2


def test_plain_python_kernels_code_the_same_bytes_as_the_compiled_ones(monkeypatch):
    mesh = shapes.grid(8, 7, hole=True)
    compiled, _ = _encode(mesh, 2, base_codec="plain")
    monkeypatch.setattr(topology, "USE_NUMBA", False)
    plain, _ = _encode(mesh, 2, base_codec="plain")
    assert plain == compiled
    _assert_same_levels(_levels(plain), _levels(compiled))


# ---------------------------------------------------------------- v2 files against v1 files


def face_set(positions_int, faces) -> list:
    """The faces of a mesh as rotation-normalised triples of grid points, sorted (any vertex numbering)."""
    corners = [tuple(map(tuple, positions_int[f])) for f in np.asarray(faces)]
    return sorted(min(t[r:] + t[:r] for r in range(3)) for t in corners)


@pytest.mark.parametrize("name", sorted(GENERATED))
def test_v2_decodes_to_the_same_mesh_as_v1_at_every_chunk(name):
    """Version 2 codes the batches of version 1 -- except on meshes with pillows, which it simplifies
    without and sends in a face chunk (bitstream.md §8.6): then only the full meshes agree."""
    from pmwm_codec.progressive.simplify import deferred_pillows

    mesh = GENERATED[name]()
    v1, _ = _encode(mesh, 1)
    v2, _ = _encode(mesh, 2)
    if deferred_pillows(mesh.faces).any():
        a, b = _levels(v1)[-1], _levels(v2)[-1]
        assert face_set(a.positions_int, a.faces) == face_set(b.positions_int, b.faces)
    else:
        _assert_same_levels(_levels(v1), _levels(v2))
    assert len(v2) < len(v1)


def test_v2_keeps_attributes_and_two_primitives_exact():
    for mesh in (_sphere_with_attributes(), [shapes.grid(18, 16, hole=True), shapes.torus(24, 12, twist=0.1)]):
        v1, _ = _encode(mesh, 1, base_codec="plain")
        v2, _ = _encode(mesh, 2, base_codec="plain")
        _assert_same_levels(_levels(v1), _levels(v2))


@pytest.mark.parametrize("mode", ["exact", "paper"])
def test_v2_watermark_reads_as_in_v1_and_verifies_authentic(mode):
    mesh = shapes.icosphere(4, 1.2, noise=0.02)
    img = (np.indices((16, 16)).sum(0) % 3 * 100).astype(np.uint8)
    key = WatermarkKey.generate(rng=np.random.default_rng(7))
    v1, _ = _encode(mesh, 1, watermark=img, key=key, mode=mode)
    v2, key2 = _encode(mesh, 2, watermark=img, key=key, mode=mode)
    levels = _levels(v2, key2)
    _assert_same_levels(_levels(v1, key2), levels)
    if mode == "exact":
        assert np.array_equal(levels[-1].watermark, img)
    report = verify_stream(io.BytesIO(v2), key2)
    assert report.verdict == "authentic", report.as_json()
    final = levels[-1]
    as_mesh = verify_mesh((final.mesh.positions, final.mesh.faces), v2, key2)
    assert as_mesh.verdict == "authentic", as_mesh.as_json()


# ---------------------------------------------------------------- the decoder's incremental adjacency


def _corner_sets_and_valences(lists, n: int) -> tuple:
    """Every vertex's corners (walking the lists, which must be ascending) and its valence."""
    corners = []
    for w in range(n):
        c, got = int(lists.head[w]), []
        while c >= 0:
            got.append(c)
            c = int(lists.nxt[c])
        assert got == sorted(got)
        corners.append(got)
    return corners, lists.valence[:n].tolist()


def _assert_lists_match_a_rebuild(lists, state) -> None:
    fresh = records_v2.CornerLists(len(state.positions), len(state.faces))
    fresh.sync(state)
    assert (lists.n, lists.m) == (state.n, state.m)
    assert _corner_sets_and_valences(lists, state.n) == _corner_sets_and_valences(fresh, state.n)


def test_v2_decoder_corner_lists_and_valences_equal_a_rebuild_after_every_chunk():
    from pmwm_codec.stream.replay import Replay
    from pmwm_codec.format import ChunkEvent, ContainerParser

    data, _ = _encode(shapes.grid(14, 11, hole=True), 2, base_codec="plain")
    parser, replay = ContainerParser(), Replay()
    chunks = 0
    for event in parser.feed(data):
        replay.on_event(event)
        if isinstance(event, ChunkEvent):
            _assert_lists_match_a_rebuild(replay.models[0].lists, replay.states[0])
            chunks += 1
    assert chunks >= 2 and replay.batches_applied > chunks


def test_a_batch_whose_splits_share_faces_decodes_as_version_1_applies_it():
    """Splits that are not independent (an encoder MUST NOT batch them; a hostile file may): the
    decoder's topology, values and adjacency still follow spec §6.1 exactly."""
    from pmwm_codec.progressive.vsplit import MeshState, SplitBatch, find_incidences

    mesh = shapes.grid(6, 5, hole=False)
    values = np.rint(mesh.positions * 1000).astype(np.int64)
    faces = np.asarray(mesh.faces, np.int64)
    n, m = len(values), len(faces)
    x, y = sorted(int(c) for c in faces[7, :2])  # both move their corners in face 7; y also in
    both = np.flatnonzero((faces == x).any(axis=1) & (faces == y).any(axis=1))  # the other face of edge xy
    v = np.array([x, y], np.int64)
    encoder_state = MeshState(values, faces, n + 2, m + 4)
    inc, owner = find_incidences(encoder_state, v)
    symbols = ((inc // 3 == 7) | ((owner == 1) & np.isin(inc // 3, both))).astype(np.uint8)
    for i in range(2):  # each split also names one new face on its first incidence
        symbols[np.flatnonzero(owner == i)[0]] = 2
    batch = SplitBatch(v, symbols, np.array([[3, -2, 1], [0, 5, -4]]))
    payload = records_v2.pack_chunks(encoder_state, [[batch]])[0]

    state, model = MeshState(values, faces, n + 2, m + 4), records_v2.ChunkDecoder()
    (decoded, _), = list(records_v2.decode_chunk(payload, state, model))
    assert np.array_equal(decoded.symbols, symbols) and np.array_equal(decoded.residual, batch.residual)
    assert np.array_equal(state.current_faces(), encoder_state.current_faces())
    assert np.array_equal(state.current_positions(), encoder_state.current_positions())
    _assert_lists_match_a_rebuild(model.lists, state)


def test_the_encoder_packs_on_the_decoders_incremental_path_and_leaves_version_1_s_mesh(monkeypatch):
    """pack_chunks keeps its corner lists from batch to batch (no rebuild): the state it leaves is
    the one version 1's apply_batch leaves, and its lists equal a rebuild after every chunk."""
    from pmwm_codec.progressive.vsplit import apply_batch
    from test_kernels import _progressive

    pm = _progressive(shapes.torus(30, 14, twist=0.1))
    chunks = [pm.batches[i:i + 3] for i in range(0, len(pm.batches), 3)]
    reference = pm.new_state()
    for b in pm.batches:
        apply_batch(reference, b)
    seen = []
    sync = records_v2.CornerLists.sync

    def watched(lists, state):  # the base only: every later mesh comes from the incremental update
        seen.append((state.n, state.m))
        sync(lists, state)

    monkeypatch.setattr(records_v2.CornerLists, "sync", watched)
    state = pm.new_state()
    payloads = records_v2.pack_chunks(state, chunks)
    assert seen == [(len(pm.base_positions), len(pm.base_faces))] and len(payloads) == len(chunks) > 2
    assert (state.n, state.m) == (reference.n, reference.m)
    assert np.array_equal(state.current_faces(), reference.current_faces())
    assert np.array_equal(state.current_positions(), reference.current_positions())
    decoded, model = pm.new_state(), records_v2.ChunkDecoder()
    for payload in payloads:
        for _ in records_v2.decode_chunk(payload, decoded, model):
            pass
        _assert_lists_match_a_rebuild(model.lists, decoded)
    assert np.array_equal(decoded.current_faces(), reference.current_faces())


def test_decoded_batches_list_the_topology_version_1_applies_even_when_read_after_the_stream():
    """What a decoded batch lists only when asked (its symbols, incidences, owners, ring, residuals)
    equals version 1's apply_batch of the same batch, also when asked after every later batch was
    decoded (the decoder reuses its mask outputs only once no batch holds them)."""
    from pmwm_codec.progressive.vsplit import apply_batch
    from test_kernels import _progressive

    pm = _progressive(shapes.torus(30, 14, twist=0.1))
    payloads = records_v2.pack_chunks(pm.new_state(), [pm.batches[i:i + 3] for i in range(0, len(pm.batches), 3)])
    state, model, reference = pm.new_state(), records_v2.ChunkDecoder(), pm.new_state()
    decoded = [got for payload in payloads for got in records_v2.decode_chunk(payload, state, model)]
    assert len(decoded) == len(pm.batches) and len(payloads) > 2
    for (batch, topo), original in zip(decoded, pm.batches):
        want = apply_batch(reference, original)
        assert np.array_equal(batch.v, original.v) and np.array_equal(batch.symbols, original.symbols)
        assert np.array_equal(batch.residual, original.residual)
        for name in ("incidences", "owner", "ring_owner", "ring_a", "ring_b", "u", "ring_count"):
            assert np.array_equal(getattr(topo, name), getattr(want, name)), name
        assert np.array_equal(topo.ring_sum, want.ring_sum)


def test_the_decoder_reuses_its_mask_outputs_once_no_batch_holds_them():
    from test_kernels import _progressive

    pm = _progressive(shapes.torus(30, 14, twist=0.1))
    payloads = records_v2.pack_chunks(pm.new_state(), [pm.batches[i:i + 3] for i in range(0, len(pm.batches), 3)])
    state, model = pm.new_state(), records_v2.ChunkDecoder()
    used = set()
    for payload in payloads:
        batches = records_v2.decode_chunk(payload, state, model)
        for got in iter(lambda: next(batches, None), None):
            used.add(id(model.mask_out[0]))
            del got  # dropped before the next batch is decoded: its mask outputs are free again
    assert len(used) == 1 and len(pm.batches) > 3
    state, model, used = pm.new_state(), records_v2.ChunkDecoder(), set()
    for payload in payloads:  # a plain loop holds the last batch while the next is decoded: two sets in turn
        for got in records_v2.decode_chunk(payload, state, model):
            used.add(id(model.mask_out[0]))
    assert len(used) == 2
    state, model, held = pm.new_state(), records_v2.ChunkDecoder(), []
    for payload in payloads:  # every batch held: each one's outputs are new
        held += [(got, model.mask_out) for got in records_v2.decode_chunk(payload, state, model)]
    assert len({id(outputs[0]) for _, outputs in held}) == len(held) == len(pm.batches)
    state, model, kept = pm.new_state(), records_v2.ChunkDecoder(), []
    for payload in payloads:  # only each batch's split vertices kept (a view of the outputs): new ones too
        for got, _ in records_v2.decode_chunk(payload, state, model):
            kept.append((got.v, got.v.copy()))
    assert all(np.array_equal(view, copy) for view, copy in kept)
    assert len({view.base.ctypes.data for view, _ in kept}) == len(pm.batches)


@pytest.mark.parametrize("use_numba", [True, False], ids=["compiled", "numpy"])
@pytest.mark.parametrize("make", [lambda: shapes.torus(30, 14, twist=0.1), lambda: _pillowed(5, 40, False)],
                         ids=["torus", "pillows"])
def test_the_builders_own_payloads_are_pack_chunks_of_its_batches(monkeypatch, use_numba, make):
    """Without an embedder the record builder codes the payloads on its replay (the packer's path): the
    same bytes as packing its batches afterwards, the same batches, ids and values as a build that
    does not pack (a face chunk included)."""
    from pmwm_codec.progressive import build
    from pmwm_codec.stream import encoder
    from test_kernels import NUMBA

    if use_numba and not NUMBA:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(topology, "USE_NUMBA", use_numba)
    calls, orig = [], encoder.build_progressive
    monkeypatch.setattr(encoder, "build_progressive", lambda *a, **k: calls.append((a, k)) or orig(*a, **k))
    _encode(make(), 2)
    (args, kwargs), = calls
    packed, plain = orig(*args, **kwargs), orig(*args, **dict(kwargs, chunks=None))
    assert plain.payloads is None and len(packed.payloads) == len(kwargs["chunks"]) > 2
    chunks = [[plain.batches[j] for j in grp] if len(grp) else records_v2.FaceChunk(plain.late_faces, plain.late_values)
              for grp in kwargs["chunks"]]
    assert records_v2.pack_chunks(plain.new_state(), chunks) == packed.payloads
    for mine, theirs in zip(packed.batches, plain.batches, strict=True):
        assert np.array_equal(mine.v, theirs.v) and np.array_equal(mine.symbols, theirs.symbols)
        assert np.array_equal(mine.residual, theirs.residual) and mine.new_face_count() == theirs.new_face_count()
    for name in ("vertex_order", "face_order", "full_values", "late_faces", "base_faces"):
        assert np.array_equal(getattr(packed, name), getattr(plain, name)), name
    with pytest.raises(ValueError, match="consecutive"):
        build.build_progressive(*args, **dict(kwargs, chunks=[range(1, len(plain.batches))]))


def test_the_encoder_refuses_a_batch_that_does_not_fit_the_mesh():
    from test_kernels import _progressive

    pm = _progressive(shapes.grid(10, 9, hole=True))
    first = pm.batches[0]
    bad = [records_v2.SplitBatch(first.v[::-1].copy(), first.symbols, first.residual),
           records_v2.SplitBatch(first.v, first.symbols[:-1], first.residual),
           records_v2.SplitBatch(first.v, first.symbols, first.residual[:, :2])]
    for batch in bad:
        with pytest.raises(ValueError, match="payload v2"):
            records_v2.pack_chunks(pm.new_state(), [[batch]])


# ---------------------------------------------------------------- hostile and truncated input


@pytest.fixture(scope="module")
def v2_file():
    return _encode(shapes.grid(12, 10, hole=True), 2, base_codec="plain")[0]


def assert_prefixes_decode_to_whole_chunks(data: bytes, cuts) -> None:
    """Each prefix ``data[:cut]`` is refused (PmwError) or decodes to the first levels of ``data``."""
    full = _levels(data)
    for cut in cuts:
        try:
            got = StreamDecoder().feed(data[:cut])
        except PmwError:
            continue
        assert len(got) <= len(full)
        for x, y in zip(got, full):
            assert np.array_equal(x.positions_int, y.positions_int) and np.array_equal(x.faces, y.faces)


def test_every_prefix_of_a_v2_file_decodes_to_whole_chunks_only(v2_file):
    assert_prefixes_decode_to_whole_chunks(v2_file, range(0, len(v2_file), 7))


def _chunk_entries(data):
    """``(gltf, BIN bytearray, chunk table as stored, per-chunk entries as the reader expands them)``."""
    gltf, binary = split_glb(data)
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
    return gltf, bytearray(binary), ext["chunks"], read_header(data).extension["chunks"]


def _stored(gltf, binary, entry) -> bytes:
    start = chunk_start(gltf["bufferViews"], entry)
    return bytes(binary[start : start + entry["byteLength"]])


def _with_chunk(data, k, stored: bytes) -> bytes:
    """Chunk k's stored bytes replaced (same length), digest recomputed."""
    gltf, binary, table, entries = _chunk_entries(data)
    start = chunk_start(gltf["bufferViews"], entries[k])
    assert len(stored) == entries[k]["byteLength"]
    binary[start : start + len(stored)] = stored
    edit_chunk_table(gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME],
                     lambda entries: entries[k].update(digest=digest(stored, 2)))
    return b"".join(glb_parts(gltf, [bytes(binary)], len(binary)))


def _decode_all(data):
    dec = StreamDecoder()
    dec.feed(data)
    dec.close()


def test_flipped_bits_with_a_recomputed_digest_give_a_format_error_or_a_valid_mesh(v2_file):
    gltf, binary, _, entries = _chunk_entries(v2_file)
    rng = np.random.default_rng(11)
    errors = 0
    for trial in range(60):
        k = int(rng.integers(len(entries)))
        stored = bytearray(_stored(gltf, binary, entries[k]))
        bit = int(rng.integers(8 * len(stored)))
        stored[bit // 8] ^= 1 << (bit % 8)
        try:
            _decode_all(_with_chunk(v2_file, k, bytes(stored)))
        except PmwError:
            errors += 1
    assert errors > 40


def test_random_payload_bytes_give_a_format_error(v2_file):
    gltf, binary, _, entries = _chunk_entries(v2_file)
    rng = np.random.default_rng(12)
    for trial in range(30):
        k = int(rng.integers(len(entries)))
        size = entries[k]["byteLength"]
        with pytest.raises(PmwError):
            _decode_all(_with_chunk(v2_file, k, rng.integers(0, 256, size, dtype=np.uint8).tobytes()))


LEGACY_V2 = Path(__file__).resolve().parents[1] / "spec" / "conformance" / "grid-hole.plain.v2.pmw"


@pytest.mark.parametrize("field", ["vertexCounts", "faceCounts", "geometricErrors", "byteLengths", "digests"])
def test_a_v2_chunk_table_whose_json_arrays_disagree_is_refused(field):
    gltf, binary = split_glb(LEGACY_V2.read_bytes())  # a file written before the packed form
    table = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["chunks"]
    table[field] = table[field][:-1]
    with pytest.raises(FormatError):
        _decode_all(b"".join(glb_parts(gltf, [bytes(binary)], len(binary))))


def _repacked(table: dict, change) -> dict:
    """``table`` with its packed bytes passed through ``change(bytearray) -> bytes`` (count kept)."""
    return {**table, "packed": base64.b64encode(change(bytearray(base64.b64decode(table["packed"])))).decode()}


MALFORMED_PACKED = {
    "count one more": lambda t: {**t, "count": t["count"] + 1},
    "count one less": lambda t: {**t, "count": t["count"] - 1},
    "count past the limit": lambda t: {**t, "count": 1 << 20},
    "a byte missing": lambda t: _repacked(t, lambda b: b[:-1]),
    "a byte too many": lambda t: _repacked(t, lambda b: b + b"\x00"),
    "a reserved flag bit": lambda t: _repacked(t, lambda b: bytes([b[0] | 2]) + b[1:]),
    "an overlong varint": lambda t: _repacked(t, lambda b: b[:-1] + b"\x80\x80\x80\x80\x80\x00"),
    "a NaN geometric error": lambda t: _repacked(t, lambda b: b[: 1 + 8 * t["count"]] + b"\x00\x00\xc0\x7f"
                                                 + b[1 + 8 * t["count"] + 4 :]),
    "not base64": lambda t: {**t, "packed": t["packed"][:-4] + "!!!="},
    "a JSON array beside it": lambda t: {**t, "byteLengths": [1]},
}


@pytest.mark.parametrize("damage", sorted(MALFORMED_PACKED))
def test_a_malformed_packed_chunk_table_is_a_one_line_format_error(v2_file, damage):
    gltf, binary, table, _ = _chunk_entries(v2_file)
    assert "packed" in table
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
    ext["chunks"] = MALFORMED_PACKED[damage](table)
    with pytest.raises(FormatError) as info:
        _decode_all(b"".join(glb_parts(gltf, [bytes(binary)], len(binary))))
    assert "\n" not in str(info.value)


def test_a_v2_chunk_past_the_end_of_its_bufferview_is_refused(v2_file):
    gltf, binary, table, _ = _chunk_entries(v2_file)
    gltf["bufferViews"][table["bufferView"]]["byteLength"] -= 1
    with pytest.raises(FormatError, match="past the end"):
        _decode_all(b"".join(glb_parts(gltf, [bytes(binary)], len(binary))))


def test_an_unknown_payload_version_is_refused(v2_file):
    gltf, binary, *_ = _chunk_entries(v2_file)
    gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["payload"]["version"] = 3
    with pytest.raises(FormatError):
        _decode_all(b"".join(glb_parts(gltf, [bytes(binary)], len(binary))))


# ---------------------------------------------------------------- the arc model


def _chunk_bytes(data) -> int:
    return sum(entry["byteLength"] for entry in _chunk_entries(data)[3])


def test_a_real_scan_s_v2_chunks_take_under_two_thirds_of_v1_s_bytes():
    """On the cow the models (arcs, mask, frame) pay: v2's chunks are far smaller than v1's."""
    from pmwm_codec.mesh import read_mesh

    mesh = read_mesh(str(corpus_path("cow.obj")))
    v1, _ = _encode(mesh, 1, grid_bits=14)
    v2, _ = _encode(mesh, 2, grid_bits=14)
    _assert_same_levels(_levels(v1), _levels(v2))
    assert _chunk_bytes(v2) < 2 / 3 * _chunk_bytes(v1)



# ---------------------------------------------------------------- spec/bitstream.md §8 and the code


def _spec_v2() -> str:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[1] / "spec" / "bitstream.md").read_text()
    return text[text.index("## 8. Chunk payload version 2"):]


def test_spec_coder_example_is_what_the_coder_writes():
    import re

    block = re.search(r"<!-- coder-example -->\n```\n(.*?)```", _spec_v2(), re.S).group(1)
    kind, ctx, values = [0, 0, 0, 1, 2, 3], [0, 0, 0, 0, 16, 16], [0, 1, 1, 1, 5, -3]
    coded = rc.encode_array(np.array(kind), np.array(ctx), np.array(values), 16 + rc.INT_BLOCK)
    assert bytes.fromhex(block.replace(" ", "").replace("\n", "")) == coded
    assert f"the {len(coded)} bytes" in _spec_v2()


def test_spec_constants_of_the_coder_and_the_models_match_the_code():
    text = " ".join(_spec_v2().split())
    assert f"prob[i] = {rc.PROB_INIT}" in text and f"bound = (range >> {rc.PROB_BITS}) * prob[i]" in text
    assert f"prob[i] += ({rc.PROB_ONE} - prob[i]) >> {rc.ADAPT_SHIFT}" in text
    assert f"prob[i] -= prob[i] >> {rc.ADAPT_SHIFT}" in text
    assert f"range < 2^{rc.TOP.bit_length() - 1}" in text
    assert f"`b = Tree(base, {rc.BUCKET_BITS})`; `b > {rc.MAX_BUCKET}` is a format error" in text
    assert f"base + {rc.INT_MANTISSA} + 3·b + t" in text and f"`base + {rc.INT_SIGN} + b` the sign" in text
    r2 = records_v2
    assert f"`N_PROBS = {r2.P_INT} + {r2.INT_BLOCKS}·{rc.INT_BLOCK} = {r2.N_PROBS}`" in text
    assert f"| `{r2.P_ESCAPE}` | escape flag" in text and f"| `{r2.P_WING}`, `{r2.P_WING + 1}` | left / right wing" in text
    assert f"`{r2.P_SYMBOL} … {r2.P_SYMBOL + 7}` | escaped symbol, `Tree({r2.P_SYMBOL}, 3)`" in text
    assert f"`{r2.B_GEOMETRY} + 3·cls + role` | position residual" in text
    assert f"`{r2.B_ATTRIBUTE} + min(j, {r2.ATTRIBUTE_CONTEXTS - 1})` | residual of value column `3 + j`" in text
    assert (f"`{r2.B_PLANE} + {r2.PLANE_CLASSES}·min(j, {r2.ATTRIBUTE_CONTEXTS - 1}) + acls` | residual of value column "
            f"`3 + j` (as above) predicted on the ring's plane") in text
    assert f"`acls` 0 … {r2.PLANE_CLASSES - 1} the ring's spread class" in text
    assert f"`{r2.B_LENGTH} + min(d, 16) − 1`" in text and f"`{r2.B_RANK} + min(c, 16) − 1`" in text
    assert f"`1 <= d <= {r2.MAX_ARC_FAN}`" in text
    assert f"`|x| < 2^{r2.MAX_VALUE.bit_length() - 1}`" in text
    assert f"1 … {r2.MAX_BATCHES_PER_CHUNK}, else a format error" in text
