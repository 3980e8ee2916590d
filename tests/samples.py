"""Small generated inputs for the tests and the spec's worked example (a test fixture).

Nothing here reads files: an icosphere (deliberately not a unit sphere and
off-centre, so a swapped Draco attribute or a lost origin shows in the bounding
radius) and a ``.pmw`` built from it with random opaque chunk payloads; and a closed
file object, a source or destination every reader and writer must refuse by name.
"""

from __future__ import annotations

import hashlib

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.format.base import encode_base
from pmwm_codec.format.glb import build_pmw
from pmwm_codec.progressive.vsplit import SplitBatch

ICOSPHERE_RADIUS = 2.5
ICOSPHERE_CENTRE = (0.75, -1.25, 3.0)


def icosphere(subdivisions: int = 2, radius: float = ICOSPHERE_RADIUS, centre=ICOSPHERE_CENTRE):
    """:func:`pmwm_codec.shapes.icosphere` moved to ``centre``: ``(positions (n, 3) float64, faces (m, 3) int64)``.

    ``n = 10 * 4**s + 2``, ``m = 20 * 4**s``, counter-clockwise seen from outside.  For
    ``subdivisions <= 1`` the positions are bit for bit those of the generator the spec's worked
    example was made with (it normalised once, at the end); from 2 on they differ (shapes
    re-projects after every subdivision), which no pinned file depends on.
    """
    mesh = shapes.icosphere(subdivisions, radius)
    return mesh.positions + np.asarray(centre, np.float64), mesh.faces


def to_grid(positions, bits: int = 14):
    """Quantize (n, 3) float positions onto a ``bits`` grid: ((n, 3) int64, grid dict)."""
    lo = positions.min(0)
    step = float((positions.max(0) - lo).max() / ((1 << bits) - 1))
    ints = np.rint((positions - lo) / step).astype(np.int64)
    return ints, {"bits": bits, "origin": [float(x) for x in lo], "step": step}


def sample_pmw(codec: str = "plain", chunk_count: int = 3, subdivisions: int = 1, seed: int = 0,
               chunk_sizes=None):
    """A small ``.pmw`` with random opaque payloads.

    Returns ``(data: bytes, base: EncodedBase, payloads: list[bytes], extension: dict)``.
    """
    rng = np.random.default_rng(seed)
    positions, faces = icosphere(subdivisions)
    ints, grid = to_grid(positions)
    base = encode_base(ints, faces, grid, codec=codec)
    sizes = chunk_sizes or [int(s) for s in rng.integers(1, 400, chunk_count)]
    # half random (incompressible), half repetitive, so stored sizes vary
    payloads = [bytes(rng.integers(0, 256, s // 2, dtype=np.uint8)) + bytes(s - s // 2) for s in sizes]
    meta = [{"splits": 10 * (k + 1), "vertexCount": base.vertex_count + 10 * (k + 1),
             "faceCount": base.face_count + 20 * (k + 1), "geometricError": 0.5 / (k + 1)}
            for k in range(len(payloads))]
    extension = {"grid": grid, "vertexCount": base.vertex_count + 10 * len(payloads),
                 "faceCount": base.face_count + 20 * len(payloads),
                 "watermark": {"mode": "exact", "bits": 2, "scale": 10.0, "width": 16, "height": 16,
                               "levels": 4, "codes": 40, "carriers": 30}}
    data = build_pmw(base=base, chunks=payloads, chunk_meta=meta, extension=extension)
    return data, base, payloads, extension


#: The two-batch, D = 4 chunk of spec/bitstream.md §6 (*Example*); its bytes are pinned in
#: tests/test_records.py and quoted in the spec.
PAYLOAD_EXAMPLE = [
    SplitBatch(np.array([2, 5]), np.array([1, 2, 0, 4], np.uint8), np.array([[1, -1, 0, 5], [3, 0, -2, -1]])),
    SplitBatch(np.array([0]), np.array([3], np.uint8), np.array([[-300, 2, 0, 0]])),
]


def edit_chunk_table(ext: dict, edit) -> None:
    """Rewrite the packed chunk table of extension object ``ext`` (in place): ``edit(entries)``
    changes the per-chunk entries the reader expands (``chunk_entries``) and the table is packed
    again from them -- a table a writer with other values would have written."""
    from pmwm_codec.format.extension import chunk_entries
    from pmwm_codec.format.glb import compact_chunks

    entries = chunk_entries(ext, 0)
    edit(entries)
    ext["chunks"] = compact_chunks(entries)


def rewrite_chunk(data: bytes, k: int, edit) -> bytes:
    """The ``.pmw`` ``data`` (one primitive, payload version 1: a bufferView per chunk) with chunk ``k``'s payload
    replaced by ``edit(payload)``, recompressed, re-digested and re-laid out, as a forger without the key would do
    it (the MACs are left as they were): a hostile payload behind a valid digest."""
    import zstandard

    from pmwm_codec.constants import EXTENSION_NAME
    from pmwm_codec.format.extension import digest
    from pmwm_codec.format.glb import compress_chunk, glb_parts, split_glb
    from pmwm_codec.format.layout import padded

    gltf, binary = split_glb(data)
    views, entries = gltf["bufferViews"], gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["chunks"]
    out = bytearray(binary[: views[entries[k]["bufferView"]]["byteOffset"]])
    for j in range(k, len(entries)):
        view = views[entries[j]["bufferView"]]
        stored = binary[view["byteOffset"] : view["byteOffset"] + view["byteLength"]]
        if j == k:
            payload = edit(zstandard.ZstdDecompressor().decompress(stored))
            stored = compress_chunk(payload)
            entries[j].update(byteLength=len(stored), digest=digest(stored), uncompressedLength=len(payload))
        view["byteOffset"], view["byteLength"] = len(out), len(stored)
        out += stored + bytes(padded(len(stored)) - len(stored))
    gltf["buffers"][0]["byteLength"] = len(out)
    return b"".join(glb_parts(gltf, [bytes(out)], len(out)))


def level_digest(r) -> str:
    """The conformance files' ``level_sha256`` of a decoded level ``r`` (spec/conformance/README.md): SHA-256 of
    its positions, faces and quantized attributes as little-endian int64, each part's (n_p, a_p) attributes
    row-major one part after another (parts may carry different attributes; one without adds nothing).
    js/test/lib/helpers.js ``levelDigest`` computes the same."""
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(r.positions_int, dtype="<i8").tobytes())
    h.update(np.ascontiguousarray(r.faces, dtype="<i8").tobytes())
    for p in r.parts:
        h.update(np.ascontiguousarray(p.attributes_int, dtype="<i8").tobytes())
    return h.hexdigest()


def closed_file(path, mode: str = "rb"):
    """A file object of ``path`` opened in ``mode`` ("wb" creates the file) and closed."""
    fh = open(path, mode)
    fh.close()
    return fh
