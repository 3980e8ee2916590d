"""Keyed chunk authentication (spec/bitstream.md §6.3): whoever lacks the key cannot re-write a chunk
or the base of a marked file, even after recomputing the public digests, without the verifier naming it."""

from __future__ import annotations

import base64
import hashlib
import io
import itertools
import json
import struct
from pathlib import Path

import numpy as np
import zstandard

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.constants import EXTENSION_NAME
from pmwm_codec.format import read_header
from pmwm_codec.format.base import decode_base, decode_base_attributes
from pmwm_codec.format.extension import base_digest
from pmwm_codec.format.glb import glb_parts, split_glb
from pmwm_codec.format.records import pack_batches, unpack_batches
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.stream.cut import cut
from pmwm_codec.verify import verify_stream
from pmwm_codec.watermark.key import WatermarkKey

from conftest import marked_sphere
from samples import edit_chunk_table, rewrite_chunk
import pytest

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"


def _ext(gltf: dict) -> dict:
    return gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]


def _move_first_split(payload: bytes) -> bytes:
    """The first split vertex of the chunk moved by one grid step along x."""
    batches = unpack_batches(payload)
    batches[0].residual[0, 0] += 1
    return pack_batches(batches)


def _rewrite_json(data: bytes, change) -> bytes:
    """The file with ``change(gltf, binary)`` applied to its JSON (and BIN, in place)."""
    gltf, binary = split_glb(data)
    binary = bytearray(binary)
    change(gltf, binary)
    return b"".join(glb_parts(gltf, [bytes(binary)], len(binary)))


def _restamp_base_digest(gltf, binary) -> None:
    """Set the first primitive's ``baseDigest`` to the digest of the base its bytes now decode to."""
    prim = gltf["meshes"][0]["primitives"][0]
    ext = prim["extensions"][EXTENSION_NAME]
    positions, faces = decode_base(gltf, bytes(binary), Grid.from_config(ext["grid"]), prim)
    attributes = decode_base_attributes(gltf, bytes(binary), prim, ext.get("attributes", ()))
    ext["baseDigest"] = base_digest(positions, faces, attributes)


def _decode(data: bytes, key):
    decoder = StreamDecoder(key)
    results = decoder.feed(data)
    decoder.close()
    return results, decoder


def test_untouched_file_passes_every_mac_and_stays_authentic():
    data, key, _ = marked_sphere(7)
    results, decoder = _decode(data, key)
    assert [r.authentic_bytes for r in results] == [True] * len(results)
    assert decoder.mac_checked == len(results) and not decoder.mac_failed and not decoder.mac_missing
    outcome = verify_stream(data, key)
    assert outcome.verdict == "authentic"
    assert outcome.mac == {"checked": len(results), "failed": [], "missing": [], "scene": True, "scene_error": None}
    assert all(row["authentic_bytes"] is True for row in outcome.as_json()["chunks"])


def test_chunk_changed_and_redigested_without_the_key_is_named_at_that_chunk(tmp_path, capsys):
    data, key, _ = marked_sphere(7, payload_version=1)  # rewrites a version 1 (zstd) chunk
    forged = rewrite_chunk(data, 3, _move_first_split)
    results, _ = _decode(forged, None)  # the public digests agree: a keyless reader decodes it
    assert results[-1].chunk == read_header(forged).chunk_count
    outcome = verify_stream(forged, key)
    assert outcome.mac["failed"] == [4]  # chunk rows count from 1 (row 0 is the base)
    assert [row["authentic_bytes"] for row in outcome.as_json()["chunks"]] == [True] * 4 + [False] + [True] * (
        len(results) - 5)
    assert outcome.verdict == "not-authentic"

    path, key_path = tmp_path / "forged.pmw", tmp_path / "key.json"
    path.write_bytes(forged)
    key.save(key_path)
    assert main(["verify", str(path), "--key", str(key_path)]) == 1
    assert "chunk 4: not written by the key holder (MAC mismatch)" in capsys.readouterr().out.splitlines()
    assert main(["verify", str(path), "--key", str(key_path), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "not-authentic" and doc["mac"]["failed"] == [4]
    assert doc["chunks"][4]["authentic_bytes"] is False


def test_macs_copied_from_another_file_of_the_same_key_fail():
    data, key, _ = marked_sphere(7, payload_version=1)  # per-chunk entries to copy MACs between
    buf = io.BytesIO()  # another mesh and watermark, marked with the same secret
    encode_mesh(shapes.icosphere(3, noise=0.02), buf, watermark=np.full((16, 16), 200, np.uint8), key=key,
                payload_version=1)
    other = buf.getvalue()

    def transplant(gltf, binary):
        source = _ext(split_glb(other)[0])
        _ext(gltf)["baseMac"] = source["baseMac"]
        for entry, theirs in zip(_ext(gltf)["chunks"], source["chunks"]):
            entry["mac"] = theirs["mac"]

    outcome = verify_stream(_rewrite_json(data, transplant), key)
    assert outcome.mac["failed"] == list(range(len(outcome.results)))
    assert outcome.verdict == "not-authentic"


def test_a_changed_base_or_public_field_fails_the_base_mac():
    # version 1: its chunks still decode on a moved base vertex (version 2 predicts from the mesh)
    data, key, _ = marked_sphere(7, base_codec="plain", payload_version=1)

    def move_base_vertex(gltf, binary):
        prim = gltf["meshes"][0]["primitives"][0]
        view = gltf["bufferViews"][gltf["accessors"][prim["attributes"]["POSITION"]]["bufferView"]]
        start = view.get("byteOffset", 0)
        positions = np.frombuffer(binary, "<f4", view["byteLength"] // 4, start).reshape(-1, 3).copy()
        positions[0] = positions[1]  # on the grid and inside the accessor bounds
        binary[start : start + positions.nbytes] = positions.tobytes()
        _restamp_base_digest(gltf, binary)  # as a forger would: anyone can compute the keyless digest

    def change_file_id(gltf, binary):
        _ext(gltf)["fileId"] = "0" * 16

    for change in (move_base_vertex, change_file_id):
        results, decoder = _decode(_rewrite_json(data, change), key)
        assert results[0].authentic_bytes is False and decoder.mac_failed == [0], change.__name__
        outcome = verify_stream(_rewrite_json(data, change), key)
        assert outcome.verdict == "not-authentic"
        assert "base mesh: not written by the key holder (MAC mismatch)" in outcome.mac_notes()


def test_cut_files_keep_valid_macs_for_the_chunks_they_keep():
    data, key, _ = marked_sphere(7)
    for chunks in (0, 3, None):
        outcome = verify_stream(cut(data, chunks), key)
        assert outcome.mac["failed"] == [] and outcome.mac["missing"] == []
        assert outcome.mac["checked"] == len(outcome.results) == 1 + len(outcome.results[1:])
        assert all(row["authentic_bytes"] for row in outcome.as_json()["chunks"])


@pytest.mark.parametrize("version", [1, 2])
def test_stripped_macs_make_a_marked_file_not_authentic(version):
    data, key, _ = marked_sphere(7, payload_version=version)

    def strip(gltf, binary):
        del _ext(gltf)["baseMac"]
        chunks = _ext(gltf)["chunks"]
        for entry in chunks if version == 1 else []:
            del entry["mac"]
        if version == 2:
            edit_chunk_table(_ext(gltf), lambda entries: [entry.pop("mac") for entry in entries])

    outcome = verify_stream(_rewrite_json(data, strip), key)
    assert outcome.mac["checked"] == 0 and len(outcome.mac["missing"]) == len(outcome.results)
    assert outcome.verdict == "not-authentic"
    assert any(note.startswith("the file: no MAC") for note in outcome.mac_notes())


def test_golden_files_without_macs_still_decode_and_unmarked_files_get_none():
    name = "sphere.exact-watermark-from-quarter.v1"
    key = WatermarkKey.load(CONFORMANCE / f"{name}.key.json")
    data = (CONFORMANCE / f"{name}.pmw").read_bytes()
    results, decoder = _decode(data, key)
    assert results[-1].chunk == read_header(data).chunk_count
    assert np.array_equal(results[-1].watermark, key.reference)
    assert all(r.authentic_bytes is None for r in results) and decoder.mac_checked == 0
    unmarked = (CONFORMANCE / "grid-hole.plain.v1.pmw").read_bytes()
    ext = read_header(unmarked).extension
    assert "baseMac" not in ext and not any("mac" in c for c in ext["chunks"])


def test_chunk_mac_recomputed_from_the_spec_text_matches_the_file():
    """A second implementation, from bitstream.md §6.3 alone, agrees with the writer for chunk 2."""
    data, key, _ = marked_sphere(7, payload_version=1)
    gltf, binary = split_glb(data)
    ext, k = _ext(gltf), 2
    entry = ext["chunks"][k]
    view = gltf["bufferViews"][entry["bufferView"]]
    payload = zstandard.ZstdDecompressor().decompress(binary[view["byteOffset"] : view["byteOffset"] + view["byteLength"]])
    mac_key = hashlib.shake_256(b"pmwm/mac/v1\0" + key.secret + bytes(8)).digest(32)
    fields = {name: value for name, value in entry.items() if name not in ("bufferView", "mac")}
    parts = [b"pmwm/chunk-mac/v1", bytes.fromhex(ext["baseMac"]), (0).to_bytes(4, "little") + k.to_bytes(4, "little"),
             json.dumps(fields, sort_keys=True, separators=(",", ":")).encode(), payload]
    h = hashlib.blake2b(key=mac_key, digest_size=16)
    for part in parts:
        h.update(len(part).to_bytes(8, "little") + part)
    assert h.hexdigest() == entry["mac"]
    assert mac_key == key.mac_key()


def test_an_index_entry_without_a_canonical_form_fails_its_mac_instead_of_crashing():
    """A crafted entry holding a non-finite number, or a base MAC that is not hex, is not the key holder's."""
    from pmwm_codec.format import ChunkEvent, iter_events
    from pmwm_codec.format.mac import MacChecker

    data, key, _ = marked_sphere(4)

    def answers(edit):
        events = list(iter_events(data))
        edit(events[0].extension)
        checker = MacChecker(key.mac_key())
        return [answer for e in events if (answer := checker.on_event(e)) is not NotImplemented
                and isinstance(e, ChunkEvent)]

    assert all(a is True for a in answers(lambda ext: None))
    infinite = answers(lambda ext: ext["chunks"][0].update(geometricError=float("inf")))
    assert infinite[0] is False and all(a is True for a in infinite[1:])
    assert all(a is False for a in answers(lambda ext: ext.update(baseMac="not hex")))


def _unpack_from_spec_text(table: dict) -> dict:
    """The packed chunk table (bitstream.md §6.2) read byte by byte as the spec words it, without
    the reader's code: ``{"byteLengths", "vertexCounts", "faceCounts", "geometricErrors", "digests", "macs"}``."""
    data, count = base64.b64decode(table["packed"]), table["count"]
    assert data[0] in (0, 1)
    at, out = 1, {}
    out["digests"] = [data[at + 8 * k : at + 8 * k + 8].hex() for k in range(count)]
    at += 8 * count
    out["macs"] = [data[at + 16 * k : at + 16 * k + 16].hex() for k in range(count)] if data[0] else None
    at += 16 * count if data[0] else 0
    out["geometricErrors"] = list(struct.unpack_from(f"<{count}f", data, at))
    at += 4 * count
    values = []
    while at < len(data):
        value = shift = 0
        while True:
            value |= (data[at] & 0x7F) << shift
            shift, at = shift + 7, at + 1
            if data[at - 1] < 0x80:
                break
        values.append(value)
    assert len(values) == 3 * count
    out["byteLengths"] = values[:count]
    out["vertexCounts"] = list(itertools.accumulate(values[count : 2 * count]))
    out["faceCounts"] = list(itertools.accumulate(values[2 * count :]))
    return out


def test_a_v2_chunk_mac_recomputed_from_the_spec_text_matches_the_file():
    """Payload version 2 (bitstream.md §6.2, §6.3): the MAC of chunk k covers the five values its
    packed chunk table stores for it (the geometric error as the float32 widened to a double) and the
    stored stream; table and MAC recomputed independently for chunk 2."""
    data, key, _ = marked_sphere(7)
    gltf, binary = split_glb(data)
    ext, k = _ext(gltf), 2
    table = _unpack_from_spec_text(ext["chunks"])
    start = gltf["bufferViews"][ext["chunks"]["bufferView"]]["byteOffset"] + sum(table["byteLengths"][:k])
    payload = binary[start : start + table["byteLengths"][k]]
    assert hashlib.blake2b(payload, digest_size=16).hexdigest()[:16] == table["digests"][k]
    fields = {"byteLength": table["byteLengths"][k], "digest": table["digests"][k],
              "faceCount": table["faceCounts"][k], "geometricError": table["geometricErrors"][k],
              "vertexCount": table["vertexCounts"][k]}
    parts = [b"pmwm/chunk-mac/v1", bytes.fromhex(ext["baseMac"]), (0).to_bytes(4, "little") + k.to_bytes(4, "little"),
             json.dumps(fields, sort_keys=True, separators=(",", ":")).encode(), payload]
    h = hashlib.blake2b(key=key.mac_key(), digest_size=16)
    for part in parts:
        h.update(len(part).to_bytes(8, "little") + part)
    assert h.hexdigest() == table["macs"][k]


def test_a_changed_v2_chunk_table_value_fails_that_chunk_s_mac():
    """A geometric error the key holder did not write (counts and digests are checked by any reader)."""
    data, key, _ = marked_sphere(7)

    def change(gltf, binary):
        edit_chunk_table(_ext(gltf), lambda entries: entries[1].update(geometricError=2 * entries[1]["geometricError"]))

    outcome = verify_stream(_rewrite_json(data, change), key)
    assert 2 in outcome.mac["failed"]  # chunk rows count from 1 (row 0 is the base)
    assert outcome.verdict == "not-authentic"


@pytest.mark.parametrize("same_file", [True, False])
def test_bases_of_different_files_spliced_into_one_fail_though_each_mac_matches(same_file):
    """Every progressive primitive of a file carries its ``fileId`` (spec README); a file whose primitives
    come from two files marked with one key has valid MACs everywhere -- each base and chunk is the key
    holder's -- but was never written so.  The bases then fail together (outside probe 1)."""
    from pmwm_codec.format.mac import MacChecker, base_mac
    from pmwm_codec.format.parser import BaseEvent, HeaderEvent

    data, key, _ = marked_sphere(7)
    header = read_header(data)
    gltf, binary = split_glb(data)
    prim = gltf["meshes"][0]["primitives"][0]
    ext0 = header.extension
    positions, faces = decode_base(gltf, binary, Grid.from_config(ext0["grid"]), prim)
    attributes = decode_base_attributes(gltf, binary, prim, ext0.get("attributes", ()))
    ext1 = {**ext0, "fileId": ext0["fileId"] if same_file else "0123456789abcdef"}
    ext1["baseMac"] = base_mac(key.mac_key(), 1, ext1, positions, faces, attributes)
    checker = MacChecker(key.mac_key())
    checker.on_event(HeaderEvent(gltf, ext0, header.total_length, 0, (ext0, ext1), header.bin_offset))
    assert checker.on_event(BaseEvent(positions, faces, 0, 0, attributes)) is NotImplemented
    assert checker.on_event(BaseEvent(positions, faces, 0, 1, attributes)) is same_file
