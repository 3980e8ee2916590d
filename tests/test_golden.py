"""Conformance files: small .pmw files written once, committed, and decoded forever.

Each ``spec/conformance/<name>.v<FORMAT_VERSION>.pmw`` has a ``.expected.npz`` beside it with the
mesh at every chunk boundary (and, for marked files, a ``.key.json`` and the watermark).  A
change that alters how these files decode breaks the format: bump FORMAT_VERSION, then
regenerate with ``python -m pytest tests/test_golden.py --update-golden``.

The inputs are generated meshes (``pmwm_codec.shapes``) and seeded keys, so a regenerated file
decodes to the same levels; its bytes still differ today because the encoder draws a random
``fileId``.  To add a case without rewriting the others, select it:
``python -m pytest tests/test_golden.py --update-golden -k <case name>``.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.constants import FORMAT_VERSION
from pmwm_codec.errors import FormatError
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.stream.encoder import PrimitiveJob, encode_document
from pmwm_codec.watermark.key import WatermarkKey

from samples import level_digest

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"


def _stripes(size=16):
    y, x = np.mgrid[0:size, 0:size]
    return (((x // 2 + y // 4) % 2) * 180 + 40).astype(np.uint8)


def _sphere_with_attributes():
    """icosphere(3) with a NORMAL (n, 3) and a TEXCOORD_0 (n, 2) per vertex (float64), no seams."""
    sphere = shapes.icosphere(3, 1.1, noise=0.03)
    p = sphere.positions
    normals = p / np.linalg.norm(p, axis=1, keepdims=True)
    uv = np.stack([np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5, np.arccos(normals[:, 2]) / np.pi], 1)
    return Mesh(p, sphere.faces, attributes={"NORMAL": normals, "TEXCOORD_0": uv})


def _uv_torus_with_attributes():
    """:func:`shapes.uv_torus` (UV seams: copies of one position in the base, which Draco's output welds back)
    with a TEXCOORD_0, a COLOR_0 of 8-bit sRGB colours decoded to linear (the ``srgb8`` grid) and a
    ``_FEATURE_ID_0`` of unsigned shorts: every kind of Draco attribute a base carries (spec README, *Base
    mesh*)."""
    from pmwm_codec.progressive.grid import SRGB8_TO_LINEAR

    torus = shapes.uv_torus(24, 12)
    n = len(torus.positions)
    rng = np.random.default_rng(7)
    colours = SRGB8_TO_LINEAR[rng.integers(0, 256, (n, 3))].astype(np.float64)
    features = rng.integers(0, 300, (n, 1)).astype(np.uint16)
    return Mesh(torus.positions, torus.faces,
                attributes={**torus.attributes, "COLOR_0": colours, "_FEATURE_ID_0": features})


CASES = {
    "grid-hole.plain": lambda: dict(mesh=shapes.grid(12, 10, hole=True), base_codec="plain"),
    "two-parts.draco": lambda: dict(
        mesh=shapes.components(shapes.icosphere(2, 0.8, noise=0.05), shapes.torus(16, 8)), base_codec="draco"
    ),
    "sphere.exact-watermark": lambda: dict(
        mesh=shapes.icosphere(4, 1.2, noise=0.02), base_codec="draco", watermark=_stripes(16),
        key=WatermarkKey.generate(rng=np.random.default_rng(2024)),
    ),
    "sphere-attributes.plain": lambda: dict(mesh=_sphere_with_attributes(), base_codec="plain"),
    "two-primitives.draco": lambda: dict(
        mesh=[shapes.grid(18, 16, hole=True), shapes.torus(24, 12, twist=0.1)], base_codec="draco"
    ),
    "sphere.paper-watermark": lambda: dict(
        mesh=shapes.icosphere(4, 1.2, noise=0.02), base_codec="draco", watermark=_stripes(16), mode="paper",
        key=WatermarkKey.generate(rng=np.random.default_rng(2025)),
    ),
    # a base Draco's edgebreaker stores with copies of its non-manifold vertices, welded back by
    # readers (spec README, "Welded base"; files from after the weld only: no frozen array-form file)
    "bowtie.welded-draco": lambda: dict(mesh=shapes.bowtie(), base_codec="draco"),
    "sphere-pillows.draco": lambda: dict(mesh=shapes.pillows(12), base_codec="draco"),
    # three spheres touching at one point, each with a vertex of its own there: a Draco base whose weld
    # attribute tells the three apart (spec README, "Welded base")
    "kissing.welded-draco": lambda: dict(mesh=shapes.kissing(), base_codec="draco"),
    # specks: triangles a 14-bit grid puts on one point, sent as faces of new vertices only (§8.6)
    "sphere-specks.draco": lambda: dict(mesh=shapes.specks(), base_codec="draco", grid_bits=14),
    # a Draco base carrying attributes (texture coordinates, sRGB colours, feature ids), welded at its seams
    "uv-torus-attributes.welded-draco": lambda: dict(mesh=_uv_torus_with_attributes(), base_codec="draco"),
    # the same with the attributes of float values predicted on the ring's plane (bitstream.md §8.4.3;
    # payload version 2 only: no version 1 file)
    "uv-torus-plane.welded-draco": lambda: dict(mesh=_uv_torus_with_attributes(), base_codec="draco"),
    "sphere.exact-watermark-from-quarter": lambda: dict(
        mesh=shapes.icosphere(4, 1.2, noise=0.02), base_codec="draco", watermark=_stripes(16), embed_from=0.25,
        key=WatermarkKey.generate(rng=np.random.default_rng(2026)),
    ),
}


#: File versions with conformance files: FORMAT_VERSION (payload version 1), and ``2``, the same
#: cases with chunk payload version 2 (bitstream.md §8; the extension object is still version 1).
VERSIONS = (FORMAT_VERSION, 2)
#: The conformance file sets: (version, packed chunk table).  ``<name>.v2`` files hold the chunk
#: table as JSON arrays (written before the packed form, frozen: the writer no longer writes them);
#: ``<name>.packed.v2`` the packed table (bitstream.md §6.2) the writer writes today.
VARIANTS = ((FORMAT_VERSION, False), (2, False), (2, True))
FROZEN = {(2, False)}
#: Cases added after a frozen set was frozen: no file of that set.
NOT_IN_FROZEN = {"bowtie.welded-draco", "sphere-pillows.draco", "sphere-specks.draco", "kissing.welded-draco",
                 "uv-torus-attributes.welded-draco", "uv-torus-plane.welded-draco"}
#: Cases of what payload version 2 alone has: no file of version 1.
V2_ONLY = {"uv-torus-plane.welded-draco"}
CASE_VARIANTS = [
    pytest.param(name, version, packed, id=f"{'packed.' if packed else ''}v{version}-{name}")
    for name in sorted(CASES) for version, packed in VARIANTS
    if not ((version, packed) in FROZEN and name in NOT_IN_FROZEN) and not (version != 2 and name in V2_ONLY)
]


def _path(name, suffix, version=FORMAT_VERSION, packed=False):
    return CONFORMANCE / f"{name}{'.packed' if packed else ''}.v{version}{suffix}"


def _decode(data, key=None):
    dec = StreamDecoder(key)
    results = dec.feed(data)
    end = dec.close()
    return results, end


def _encode(mesh, **options):
    """One mesh, or a list of meshes (one primitive each, in one glTF mesh) -> (.pmw bytes, key or None)."""
    buf = io.BytesIO()
    if isinstance(mesh, Mesh):
        report = encode_mesh(mesh, buf, min_chunk_splits=30, measure=False, **options)
    else:
        doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
               "meshes": [{"primitives": [{} for _ in mesh]}]}
        jobs = [PrimitiveJob(m, 0, i) for i, m in enumerate(mesh)]
        report = encode_document(doc, b"", jobs, buf, min_chunk_splits=30, measure=False, **options)
    return buf.getvalue(), report.key


def _attributes_int(r) -> np.ndarray:
    """(n, a) int64 quantized attributes of every part, stacked (a = 0 without attributes; parts alike)."""
    return np.concatenate([p.attributes_int for p in r.parts])


def _expected_arrays(results):
    """Final mesh in full; every level by counts and a SHA-256 of its arrays; watermarks in full."""
    out = {
        "chunk_bytes": np.array([r.bytes_read for r in results]),
        "counts": np.array([(r.vertices, r.faces_count) for r in results]),
        "level_sha256": np.array([level_digest(r) for r in results]),
        "final_positions": results[-1].positions_int,
        "final_faces": results[-1].faces,
        "final_attributes": _attributes_int(results[-1]),
        "part_counts": np.array([[(len(p.positions_int), len(p.faces)) for p in r.parts] for r in results]),
    }
    for r in results:
        if r.watermark is not None:
            out[f"watermark_{r.chunk}"] = r.watermark
    return out


def _write(name, version, packed=False):
    case = CASES[name]()
    mesh = case.pop("mesh")
    data, key = _encode(mesh, payload_version=1 if version == FORMAT_VERSION else version, **case)
    CONFORMANCE.mkdir(parents=True, exist_ok=True)
    _path(name, ".pmw", version, packed).write_bytes(data)
    if key is not None:
        key.save(_path(name, ".key.json", version, packed))
    results, _ = _decode(data, key)
    np.savez_compressed(_path(name, ".expected.npz", version, packed), **_expected_arrays(results))


@pytest.mark.parametrize("name, version, packed", CASE_VARIANTS)
def test_conformance_file_decodes_to_its_expected_levels(name, version, packed, update_golden):
    if update_golden and (version, packed) not in FROZEN:
        _write(name, version, packed)
    pmw = _path(name, ".pmw", version, packed)
    if not pmw.exists():
        pytest.fail(f"{pmw.name} is missing; generate it with: python -m pytest tests/test_golden.py --update-golden")
    key_path = _path(name, ".key.json", version, packed)
    key = WatermarkKey.load(key_path) if key_path.exists() else None
    results, end = _decode(pmw.read_bytes(), key)
    assert end.complete
    with np.load(_path(name, ".expected.npz", version, packed)) as expected:
        want = dict(expected)
    assert [r.bytes_read for r in results] == want["chunk_bytes"].tolist(), (
        "decoding changed: if the format changed on purpose, bump FORMAT_VERSION and run with --update-golden"
    )
    assert [[r.vertices, r.faces_count] for r in results] == want["counts"].tolist()
    assert np.array_equal(results[-1].positions_int, want["final_positions"])
    assert np.array_equal(results[-1].faces, want["final_faces"])
    if "final_attributes" in want:  # files written before attributes were recorded have none
        assert np.array_equal(_attributes_int(results[-1]), want["final_attributes"])
    if "part_counts" in want:
        assert [[[len(p.positions_int), len(p.faces)] for p in r.parts] for r in results] == want["part_counts"].tolist()
    for r in results:
        assert level_digest(r) == want["level_sha256"][r.chunk]
        if f"watermark_{r.chunk}" in want:
            assert np.array_equal(r.watermark, want[f"watermark_{r.chunk}"])
    if key is not None:
        assert np.array_equal(results[-1].watermark, key.reference)



def _split_glb(data: bytes) -> tuple:
    """``(gltf dict, the bytes after the JSON chunk)`` of a GLB."""
    import json
    import struct

    (json_len,) = struct.unpack("<I", data[12:16])
    return json.loads(data[20:20 + json_len]), data[20 + json_len:]


def _join_glb(gltf: dict, rest: bytes) -> bytes:
    """A GLB of ``gltf`` (padded JSON) followed by ``rest`` (the BIN chunk with its header)."""
    import json
    import struct

    text = json.dumps(gltf, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def _interleaved(data: bytes) -> bytes:
    """``sphere-attributes.plain``'s GLB with the base's NORMAL and TEXCOORD_0 in one interleaved bufferView
    (byteStride 20; glTF 2.0 3.6.2.4 allows it for vertex attributes), every other byte as it was."""
    gltf, rest = _split_glb(data)
    prim = gltf["meshes"][0]["primitives"][0]
    normal, uv = (gltf["accessors"][prim["attributes"][s]] for s in ("NORMAL", "TEXCOORD_0"))
    nv, tv = gltf["bufferViews"][normal["bufferView"]], gltf["bufferViews"][uv["bufferView"]]
    start, n = 8 + nv["byteOffset"], normal["count"]  # in rest: after the BIN chunk's 8-byte header
    assert tv["byteOffset"] == nv["byteOffset"] + 12 * n and "byteOffset" not in normal and "byteOffset" not in uv
    normals = np.frombuffer(rest, "<f4", 3 * n, start).reshape(n, 3)
    uvs = np.frombuffer(rest, "<f4", 2 * n, start + 12 * n).reshape(n, 2)
    blob = bytearray(rest)
    blob[start:start + 20 * n] = np.hstack([normals, uvs]).astype("<f4").tobytes()
    nv.update(byteLength=20 * n, byteStride=20)
    uv.update(bufferView=normal["bufferView"], byteOffset=12)
    return _join_glb(gltf, bytes(blob))


def test_a_base_whose_attributes_interleave_decodes_to_the_same_levels():
    """A writer may interleave a plain base's vertex attributes (glTF-Transform's default layout did): the
    reader used to refuse it ('must be tightly packed'); every level is now the file's own."""
    data = _path("sphere-attributes.plain", ".pmw", 2, packed=True).read_bytes()
    edited = _interleaved(data)
    assert edited != data
    want, _ = _decode(data)
    got, end = _decode(edited)
    assert end.complete and len(got) == len(want)
    assert [level_digest(r) for r in got] == [level_digest(r) for r in want]


def test_interleaved_indices_are_refused_by_name():
    """Indices are tightly packed (glTF 2.0): a byteStride on their view is a format error, never read
    overlapping."""
    gltf, rest = _split_glb(_path("sphere-attributes.plain", ".pmw", 2, packed=True).read_bytes())
    prim = gltf["meshes"][0]["primitives"][0]
    gltf["bufferViews"][gltf["accessors"][prim["indices"]]["bufferView"]]["byteStride"] = 4
    with pytest.raises(FormatError, match="indices are tightly packed"):
        _decode(_join_glb(gltf, rest))


def test_a_decode_without_a_key_ignores_the_watermark_parameters():
    """spec/watermark.md: a reader that only decodes the mesh can ignore the watermark. Out-of-range
    parameters (an image 3 pixels wide) refused the decode (the JavaScript reader decoded it); now only a
    reader with a key, which reads the mark, refuses them."""
    name = "sphere.exact-watermark"
    data = _path(name, ".pmw", 2, packed=True).read_bytes()
    gltf, rest = _split_glb(data)
    gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]["watermark"]["width"] = 3
    edited = _join_glb(gltf, rest)
    want, _ = _decode(data)
    got, end = _decode(edited)
    assert end.complete and [level_digest(r) for r in got] == [level_digest(r) for r in want]
    key = WatermarkKey.load(str(_path(name, ".key.json", 2, packed=True)))
    with pytest.raises(FormatError, match="watermark size"):
        _decode(edited, key)


@pytest.mark.parametrize("field, value", [("vertexCount", 4_000_000), ("faceCount", 8_000_000)])
def test_declared_counts_past_what_the_chunks_reach_are_refused_before_anything_is_allocated(field, value):
    """The extension's counts are what its last chunk reaches (spec README). A 3 KB edit declaring 4M
    vertices took 120+ MB for arrays sized by it, then decoded as complete to the 642 the chunks make."""
    gltf, rest = _split_glb(_path("sphere-attributes.plain", ".pmw", 2, packed=True).read_bytes())
    gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"][field] = value
    with pytest.raises(FormatError, match="its last chunk reaches"):
        _decode(_join_glb(gltf, rest))


def _claiming(data: bytes, vertices: int, faces: int, cut_last_to: int | None = None) -> bytes:
    """``data`` (a one-primitive version 2 file, packed table) with its last chunk's index entry and the
    extension claiming ``vertices`` / ``faces`` (digests kept valid: no key, no MAC); ``cut_last_to``: that
    chunk's payload cut to so many bytes, its length and digest made to match."""
    from pmwm_codec.format.extension import digest, pack_chunk_table, unpack_chunk_table

    gltf, rest = _split_glb(data)
    ext = gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]
    table = ext["chunks"]
    columns = unpack_chunk_table(table["count"], table["packed"])
    fields = ("byteLength", "vertexCount", "faceCount", "geometricError", "digest")
    entries = [dict(zip(fields, row)) for row in zip(*(columns[f] for f in fields))]
    assert "firstFaceChunk" not in ext and "byteOffsets" not in table
    blob = rest[8:]
    view = gltf["bufferViews"][table["bufferView"]]
    start = view.get("byteOffset", 0) + sum(e["byteLength"] for e in entries[:-1])
    last = entries[-1]
    if cut_last_to is not None:
        payload = blob[start : start + cut_last_to]
        blob = blob[:start] + payload + blob[start + last["byteLength"] :]
        view["byteLength"] -= last["byteLength"] - cut_last_to
        gltf["buffers"][0]["byteLength"] = len(blob)
        blob += b"\0" * (-len(blob) % 4)
        last.update(byteLength=cut_last_to, digest=digest(payload, 2))
    last.update(vertexCount=vertices, faceCount=faces)
    ext.update(vertexCount=vertices, faceCount=faces, chunks={**table, **pack_chunk_table(entries)})
    return _join_glb(gltf, len(blob).to_bytes(4, "little") + rest[4:8] + blob)  # the BIN chunk's header, its length new


def _peak_bytes(run) -> tuple:
    """``(most bytes allocated, numpy's arrays included, the error's text)`` of ``run()``, which must raise
    FormatError."""
    import tracemalloc

    tracemalloc.start()
    try:
        with pytest.raises(FormatError) as caught:
            run()
        return tracemalloc.get_traced_memory()[1], str(caught.value)
    finally:
        tracemalloc.stop()


def test_chunks_claiming_sixty_million_vertices_cost_the_memory_of_what_they_hold():
    """An edited index (the last chunk and the extension claiming 60M vertices / 120M faces, digests valid)
    made both decoders size every array by the claim before a chunk was read: 2 GB and 10 s for a 105 KB file
    (a dragon). Memory now follows the splits actually decoded; the claim is refused when it is not reached."""
    data = _path("sphere-attributes.plain", ".pmw", 2, packed=True).read_bytes()
    _decode(data)  # the kernels compiled, outside the measure
    peak, error = _peak_bytes(lambda: _decode(_claiming(data, 60_000_000, 120_000_000)))
    assert "counts differ from its index entry" in error
    assert peak < 16 << 20


def test_a_payload_cut_short_is_refused_at_the_first_batch_past_its_end():
    """The range decoder reads zeros past a payload's end and only said so at the end of the chunk: a few bytes
    claiming millions of splits decoded zeros up to the claim (work and memory with no bytes behind them). The
    first batch that reads past the end is refused now, with the end-of-payload error."""
    data = _path("sphere-attributes.plain", ".pmw", 2, packed=True).read_bytes()
    peak, error = _peak_bytes(lambda: _decode(_claiming(data, 60_000_000, 120_000_000, cut_last_to=3)))
    assert "does not end at the end of the payload" in error
    assert peak < 16 << 20
