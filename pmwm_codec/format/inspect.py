"""The structure of a ``.pmw`` from its header and glTF JSON (no chunk decoded).

Contract
--------
:func:`inspect` ``(source) -> dict`` reads the 20-byte preamble and the JSON chunk
(:func:`~pmwm_codec.format.parser.read_header`) -- of a file or bytes, whose size is known, also
the BIN chunk header and the base meshes (:func:`~.reader.read_through_base`), so that it refuses
what every reader refuses before it shows a mesh: bytes after the declared length, a bad BIN chunk
header, a file ending before its base meshes -- and returns the ``pmw info --json``
object: counts (totals over every progressive primitive), base codec, grid, payload
codec, public watermark parameters, one row per primitive, and the chunk table in
stream order (the order the bytes arrive) with each chunk's byte count and whether
its last byte is inside the file.  ``bytes``, ``complete``, ``truncated``,
``chunks_present`` and each chunk's ``present`` are None when the size of the source
is unknown (standard input, a file object).
"""

from __future__ import annotations

import os
from typing import Any

from ..constants import EXTENSION_NAME
from .base import base_counts, base_vertex_count
from .extension import chunk_start, is_face_chunk
from .gltf import DRACO_EXTENSION, find_extension_primitives
from .parser import trailing_bytes
from .reader import read_header, read_through_base
from ..sources import Source, source_size

__all__ = ["inspect"]

#: The public watermark parameters ``inspect`` reports (never the key).
WATERMARK_FIELDS = ("mode", "bits", "width", "height", "levels", "codes", "carriers", "keyFingerprint")


def inspect(source: Source) -> dict[str, Any]:
    """The ``pmw info --json`` object of ``source``: a path, ``"-"`` (standard input), bytes or an http(s) URL.

    Raises the parser's named errors (FormatError, LimitError, TruncatedError when the
    JSON chunk is incomplete).
    """
    from ..http import as_source

    source = as_source(source, 0)  # a URL: the header only is fetched
    header = read_header(source)
    gltf = header.gltf_json
    size = source_size(source)
    if size is not None and size > header.total_length:
        raise trailing_bytes(size, header.total_length)  # as decode and verify refuse it
    if size is not None:  # what decode refuses before it shows a mesh: a bad BIN chunk header, no whole base
        read_through_base(source)
    prims, rows = _primitives(gltf, header.extensions or (header.extension,), header.bin_offset, size)
    chunks = [dict(chunk=i + 1, **row) for i, (_, row) in enumerate(sorted(rows, key=lambda r: r[0]))]
    complete = None if size is None else size >= header.total_length
    ext = header.extension
    wm = ext.get("watermark")
    watermark = {k: wm.get(k) for k in WATERMARK_FIELDS} if wm else None
    return {
        "file": _name(source), "bytes": size, "total_length": header.total_length, "complete": complete,
        "truncated": None if complete is None else not complete,
        "chunks_present": sum(1 for c in chunks if c["present"]) if size is not None else None,
        "vertices": sum(q["vertices"] for q in prims), "faces": sum(q["faces"] for q in prims),
        "base_vertices": sum(q["base_vertices"] for q in prims), "base_faces": sum(q["base_faces"] for q in prims),
        "base_codec": prims[0]["base_codec"],
        # a face chunk's new vertices (flap tips, bitstream.md §8.6) come with faces, not by splits
        "vsplits": sum(c["splits"] for c in chunks if not c["face_chunk"]), "chunks_total": header.chunk_count,
        "grid": ext.get("grid"), "payload": ext.get("payload"), "watermark": watermark, "chunks": chunks,
        "primitives": prims,
        "extension": EXTENSION_NAME, "generator": gltf.get("asset", {}).get("generator"),
    }


def _primitives(gltf: dict, exts, bin_offset: int, size):
    """``(primitive rows, [(BIN offset, chunk row), ...])`` of every progressive primitive
    (``exts`` their extension objects as the parser gives them: per-chunk entries).

    A chunk row's ``present`` says whether its last byte is within ``size`` (None if unknown).
    """
    views = gltf.get("bufferViews", [])
    prims, rows = [], []
    for p, ((mi, pi, prim), ext) in enumerate(zip(find_extension_primitives(gltf, EXTENSION_NAME), exts)):
        base_vertices, base_faces = base_vertex_count(gltf, prim), base_counts(gltf, prim)[1]
        prims.append({
            "mesh": mi, "primitive": pi, "name": gltf["meshes"][mi].get("name"),
            "vertices": ext["vertexCount"], "faces": ext["faceCount"],
            "base_vertices": base_vertices, "base_faces": base_faces,
            "base_codec": "draco" if DRACO_EXTENSION in prim.get("extensions", {}) else "plain",
            "attributes": [a["semantic"] for a in ext.get("attributes", [])], "grid": ext.get("grid"),
            "chunks": len(ext["chunks"]),
        })
        for c in ext["chunks"]:
            start = chunk_start(views, c)
            end = bin_offset + start + c["byteLength"]
            rows.append((start, {
                "primitive": p, "splits": c["splits"], "face_chunk": is_face_chunk(ext, c),
                "vertices": c["vertexCount"], "faces": c["faceCount"],
                "bytes": c["byteLength"], "geometric_error": c.get("geometricError"),
                "present": None if size is None else end <= size}))
    return prims, rows


def _name(source):
    if isinstance(source, (str, os.PathLike)):
        return os.fspath(source)
    return getattr(source, "url", None)  # a UrlSource
