"""The compact chunk table of payload version 2 (spec/bitstream.md §6.2) and version 2 as the default.

The writer (``glb.compact_chunks``) and the reader (``extension.chunk_entries``) are each other's
inverse; one bufferView holds every chunk; the index costs a few dozen bytes a chunk; cut and MACs
keep working on it; ``pmwm_codec.encode`` and ``pmw encode`` write it unless asked for version 1.
"""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.constants import EXTENSION_NAME
from pmwm_codec.errors import FormatError
from pmwm_codec.format import read_header
from pmwm_codec.format.extension import chunk_entries, float32_up, pack_chunk_table
from pmwm_codec.format.glb import build_pmw, compact_chunks, split_glb
from pmwm_codec.meshio import write_mesh
from pmwm_codec.stream.cut import cut
from pmwm_codec.stream.encoder import PrimitiveJob, encode_document
from pmwm_codec.verify import verify_stream
from pmwm_codec.watermark.key import WatermarkKey

from samples import sample_pmw


def _entries(lengths, gaps, macs: bool, base: int = 7) -> list:
    """Per-chunk entries as the reader expands them, chunk k after a gap of gaps[k] bytes."""
    out, offset, vertices = [], 0, base
    for k, (length, gap) in enumerate(zip(lengths, gaps)):
        offset += gap
        vertices += k % 3
        entry = {"bufferView": 4, "byteOffset": offset, "byteLength": length, "vertexCount": vertices,
                 "faceCount": 2 * vertices, "geometricError": float32_up(1.0 / (k + 1)), "digest": f"{k:016x}",
                 "splits": k % 3, "uncompressedLength": length}
        if macs:
            entry["mac"] = f"{k:032x}"
        out.append(entry)
        offset += length
    return out


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 5000), st.integers(0, 3)), max_size=40), st.booleans(), st.booleans())
def test_the_chunk_table_reads_back_to_the_entries_it_was_written_from(chunks, macs, packed):
    lengths, gaps = [c[0] for c in chunks], [c[1] for c in chunks]
    entries = _entries(lengths, gaps, macs)
    table = compact_chunks(entries, packed=packed)
    ext = {"payload": {"codec": "pmwm-vsplit", "version": 2}, "chunks": json.loads(json.dumps(table))}
    assert chunk_entries(ext, 7) == entries
    first = 2 * len(entries) // 3  # the chunks from it on read as face chunks (bitstream.md §8.6) when the extension says so
    marked = chunk_entries(dict(ext, firstFaceChunk=first), 7)
    assert [e.pop("faces", False) for e in marked] == [k >= first for k in range(len(entries))]
    assert marked == entries
    assert ("byteOffsets" in table) == any(gaps)  # back to back from 0 needs no offsets
    assert ("packed" in table) == packed and ("macs" in table) == (macs and bool(chunks) and not packed)


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.integers(1, (1 << 32) - 1), st.integers(0, (1 << 32) - 1),
                          st.integers(0, (1 << 32) - 1)), max_size=12))
def test_packed_values_up_to_32_bits_read_back_exactly(values):
    lengths = [v[0] for v in values]
    vertices = sorted(v[1] for v in values)
    faces = sorted(v[2] for v in values)
    entries = [{"bufferView": 0, "byteOffset": sum(lengths[:k]), "byteLength": n, "vertexCount": v, "faceCount": f,
                "geometricError": 0.0, "digest": f"{k:016x}", "splits": v - (vertices[k - 1] if k else 0),
                "uncompressedLength": n} for k, (n, v, f) in enumerate(zip(lengths, vertices, faces))]
    ext = {"payload": {"codec": "pmwm-vsplit", "version": 2}, "chunks": compact_chunks(entries)}
    assert chunk_entries(ext, 0) == entries


@given(st.floats(min_value=0, max_value=1e38, allow_nan=False, allow_infinity=False))
def test_a_geometric_error_rounded_to_float32_stays_the_smallest_float32_bound(value):
    up = float32_up(value)
    assert up >= value and float(np.float32(up)) == up
    assert float(np.nextafter(np.float32(up), np.float32(0))) < value or up == 0


def test_the_packed_writer_refuses_values_it_cannot_give_back():
    entries = _entries([5, 6], [0, 0], False)
    with pytest.raises(ValueError, match="float32"):
        pack_chunk_table([{**entries[0], "geometricError": 0.1}])
    with pytest.raises(ValueError, match="decrease"):
        pack_chunk_table([entries[1], {**entries[0], "faceCount": 0}])
    with pytest.raises(ValueError, match="MAC"):
        pack_chunk_table([{**entries[0], "mac": "00" * 16}, entries[1]])


def test_a_table_whose_vertex_counts_decrease_is_a_format_error():
    table = compact_chunks(_entries([5, 6], [0, 0], False), packed=False)
    table["vertexCounts"] = [9, 8]
    with pytest.raises(FormatError, match="smaller"):
        chunk_entries({"payload": {"codec": "pmwm-vsplit", "version": 2}, "chunks": table}, 7)


def test_the_writer_refuses_to_mix_payload_versions_in_one_file():
    from pmwm_codec.format.glb import ProgressivePrimitive, assemble_document

    _, base, payloads, extension = sample_pmw("plain", chunk_count=1)
    meta = [{"splits": 10, "vertexCount": base.vertex_count + 10, "faceCount": base.face_count + 20, "geometricError": 0.5}]
    v2 = {**extension, "payload": {"codec": "pmwm-vsplit", "version": 2}}
    prims = [ProgressivePrimitive(0, 0, base, payloads, meta, extension), ProgressivePrimitive(0, 1, base, payloads, meta, v2)]
    doc = {"meshes": [{"primitives": [{}, {}]}]}
    with pytest.raises(ValueError, match="same payload version"):
        assemble_document(doc, b"", prims, [(0, 0), (1, 0)])


def test_a_v2_chunk_whose_split_count_is_not_its_vertex_count_step_is_refused_by_the_writer():
    _, base, payloads, extension = sample_pmw("plain", chunk_count=2)
    meta = [{"splits": 10, "vertexCount": base.vertex_count + 10, "faceCount": base.face_count + 20, "geometricError": 0.5},
            {"splits": 20, "vertexCount": base.vertex_count + 20, "faceCount": base.face_count + 40, "geometricError": 0.2}]
    v2 = {**extension, "payload": {"codec": "pmwm-vsplit", "version": 2}}
    with pytest.raises(ValueError, match="splits"):
        build_pmw(base=base, chunks=payloads, chunk_meta=meta, extension=v2)


def _encode(mesh, **options) -> bytes:
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, measure="none", **options)
    return buf.getvalue()


def test_encode_writes_payload_version_2_with_one_chunk_bufferview_by_default():
    data = _encode(shapes.icosphere(3, noise=0.02))
    gltf, _ = split_glb(data)
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
    assert ext["payload"]["version"] == 2 and isinstance(ext["chunks"], dict)
    entries = read_header(data).extension["chunks"]
    assert len(entries) > 1 and {e["bufferView"] for e in entries} == {ext["chunks"]["bufferView"]}
    assert "byteOffsets" not in ext["chunks"]  # one primitive: back to back from the view's start
    view = gltf["bufferViews"][ext["chunks"]["bufferView"]]
    assert view["byteLength"] == sum(e["byteLength"] for e in entries)
    assert "packed" in ext["chunks"] and ext["chunks"]["count"] == len(entries)


def test_the_v2_index_costs_a_fraction_of_the_v1_index_of_the_same_stream():
    mesh = shapes.icosphere(4, noise=0.02)
    sizes = {}
    for version in (1, 2):
        gltf, _ = split_glb(_encode(mesh, payload_version=version))
        ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
        chunk_views = len(ext["chunks"]) if version == 1 else 1
        sizes[version] = len(json.dumps(ext["chunks"], separators=(",", ":"))) + 50 * chunk_views  # + bufferViews
    entries = read_header(_encode(mesh)).extension["chunks"]
    assert sizes[2] * 8 < sizes[1]
    assert sizes[2] < 32 * len(entries) + 100  # base64 of an 8-byte digest, a float32 and three small varints
    arrays = len(json.dumps(compact_chunks(entries, packed=False), separators=(",", ":")))
    assert sizes[2] - 50 < 0.75 * arrays  # the JSON arrays of the same values (files before the packed form)


def test_pmw_encode_defaults_to_version_2_and_still_writes_version_1_on_request(tmp_path, capsys):
    src = tmp_path / "s.obj"
    write_mesh(str(src), shapes.icosphere(3))
    for args, version in (([], 2), (["--payload-version", "1"], 1)):
        out = tmp_path / f"v{version}.pmw"
        assert main(["encode", str(src), "-o", str(out), "-q", "--measure", "none", *args]) == 0
        ext = read_header(out.read_bytes()).extension
        assert ext.get("payload", {}).get("version", 1) == version


def _two_primitive_marked_file() -> tuple:
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [{}, {}]}]}
    meshes = [shapes.icosphere(3, 1.0, noise=0.02), shapes.grid(14, 12, hole=True)]
    key = WatermarkKey.generate(rng=np.random.default_rng(31))
    buf = io.BytesIO()
    report = encode_document(doc, b"", [PrimitiveJob(m, 0, i) for i, m in enumerate(meshes)], buf,
                             watermark=np.random.default_rng(3).integers(0, 256, (16, 16)).astype(np.uint8),
                             key=key, min_chunk_splits=30, measure=False)
    return buf.getvalue(), report.key


def test_two_primitives_share_one_chunk_bufferview_and_every_cut_keeps_its_macs():
    data, key = _two_primitive_marked_file()
    gltf, _ = split_glb(data)
    tables = [p["extensions"][EXTENSION_NAME]["chunks"] for p in gltf["meshes"][0]["primitives"]]
    assert tables[0]["bufferView"] == tables[1]["bufferView"] and all("byteOffsets" in t for t in tables)
    total = read_header(data).chunk_count
    for n in (0, 1, total // 2, total):
        small = cut(data, n)
        assert read_header(small).chunk_count == n
        outcome = verify_stream(small, key)
        assert outcome.mac["failed"] == [] and outcome.mac["missing"] == [] and outcome.mac["checked"] == n + 1
        for prim in split_glb(small)[0]["meshes"][0]["primitives"]:
            assert isinstance(prim["extensions"][EXTENSION_NAME]["chunks"], dict)  # still the compact form


def test_a_v2_mac_survives_a_json_writer_that_prints_a_zero_error_as_an_integer():
    """JavaScript's JSON.stringify writes 0.0 as 0 (the last chunk's geometricError) in a table of
    JSON arrays (files written before the packed form; the same values rewritten in that form here)."""
    data, key = _two_primitive_marked_file()
    gltf, binary = split_glb(data)
    for prim in gltf["meshes"][0]["primitives"]:
        ext = prim["extensions"][EXTENSION_NAME]
        ext["chunks"] = compact_chunks(chunk_entries(ext, 0), packed=False)
        errors = ext["chunks"]["geometricErrors"]
        assert errors[-1] == 0.0
        errors[-1] = 0
    from pmwm_codec.format.glb import glb_parts

    rewritten = b"".join(glb_parts(gltf, [binary], len(binary)))
    assert b'0.0]' not in rewritten[: 20 + int.from_bytes(rewritten[12:16], "little")]
    outcome = verify_stream(rewritten, key)
    assert outcome.mac["failed"] == [] and outcome.verdict == "authentic"
