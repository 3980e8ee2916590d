"""GLB framing, both ways, and writing a ``.pmw`` file: our own GLB writer (never pygltflib's).

Framing: :func:`glb_parts` (the writer's), :func:`join_glb` (any JSON, for tests and the
fuzzer) and :func:`split_glb` (lenient reader for input assets; the strict streaming
reader of ``.pmw`` files is :mod:`.parser`).

Contract (DESIGN.md §4)
-----------------------
* One JSON chunk, then one BIN chunk = ``[base mesh bufferViews | the document's own
  bufferViews (images, ...) | chunk 0 | chunk 1 | ...]`` (files written before this
  order put the document's own bufferViews first; readers accept both),
  every bufferView starting on a 4-byte boundary, chunks in stream order.
* Payload version 1: every vertex-split chunk is stored as its own zstd frame with the
  content size and the content checksum in its own bufferView; the extension object lists,
  per chunk, its bufferView, stored ``byteLength``, BLAKE2b-128 ``digest`` of the stored
  bytes and ``uncompressedLength``, plus the caller's
  ``splits``/``vertexCount``/``faceCount``/``geometricError``.
* Payload version 2: the chunks (range-coded streams) are stored as they are, back to back
  in ONE bufferView shared by every progressive primitive, and ``chunks`` is the compact
  chunk table of :func:`compact_chunks` (bitstream.md §6.2: the per-chunk values packed in
  one base64 string -- 64-bit digests, MACs, geometric errors rounded up to float32, varints).
* Every extension object gets the keyless ``baseDigest`` of its decoded base mesh
  (:func:`~.extension.base_digest`).  Given a MAC key (a watermarked file), every chunk gets
  its keyed ``mac`` and every extension object the document's ``sceneMac`` (the same value on each)
  and its ``baseMac``, which covers the ``sceneMac`` (:mod:`.mac`; a caller's ``baseMac``,
  ``baseDigest``, ``sceneMac`` or ``mac`` is never copied).
* The extension object sits on the mesh primitive under ``EXTENSION_NAME``, is listed in
  ``extensionsUsed`` and never in ``extensionsRequired``; ``KHR_draco_mesh_compression``
  is in both lists only when the base mesh uses it.
* Because every offset is in the JSON, all chunks are compressed before anything is
  written; a reader learns every byte range from the first 20 bytes plus the JSON.

:func:`build_pmw` returns the file as bytes; :func:`write_pmw` writes it to a path
(atomically, see :mod:`pmwm_codec.atomic`) or to a binary file object.  Both share :func:`_assemble`.
"""

from __future__ import annotations

import copy
import json
import os
from dataclasses import dataclass

import zstandard

from ..atomic import write_atomic, write_stream
from ..constants import EXTENSION_NAME, FORMAT_VERSION, MAX_CHUNK_BYTES, MAX_CHUNKS, MAX_DECOMPRESSED_CHUNK_BYTES
from ..errors import FormatError, InputFormatError, LimitError
from .base import EncodedBase, decode_base_attributes
from .gltf import DRACO_EXTENSION, QUANTIZATION_EXTENSION, forget_extension, uses_quantization, without_defaults
from .extension import (
    CHUNK_META_FIELDS, DERIVED_FIELDS, RESERVED_FIELDS, TABLE_ARRAYS, base_digest, check_extension, digest, float32_up,
    pack_chunk_table, payload_version,
)
from .mac import SCENE_MAC, Scene, base_mac, chunk_mac
from .layout import (
    CHUNK_HEADER_SIZE,
    CHUNK_TYPE_BIN,
    CHUNK_TYPE_JSON,
    GLB_HEADER_SIZE,
    GLB_VERSION,
    ChunkHeader,
    GlbHeader,
    padded,
)

GENERATOR = "pmwm_codec"


def compress_chunk(payload, level: int = 10) -> bytes:
    """One zstd frame with content size and checksum for a raw chunk payload (bytes-like)."""
    cctx = zstandard.ZstdCompressor(level=level, write_content_size=True, write_checksum=True)
    return cctx.compress(bytes(payload))


def _assemble(base: EncodedBase, chunks, chunk_meta, extension: dict, zstd_level: int) -> list:
    """A single progressive primitive in a minimal document (one scene, node, mesh)."""
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [{}]}]}
    prim = ProgressivePrimitive(0, 0, base, list(chunks), list(chunk_meta), extension)
    order = [(0, k) for k in range(len(prim.chunks))]
    return assemble_document(doc, b"", [prim], order, zstd_level)


@dataclass
class ProgressivePrimitive:
    """One progressive primitive to write: where it goes, its base, its raw chunks and their index fields."""

    mesh: int
    primitive: int
    base: EncodedBase
    chunks: list
    chunk_meta: list
    extension: dict


def assemble_document(doc: dict, kept_bin: bytes, prims, order, zstd_level: int = 10, mac_key: bytes | None = None) -> list:
    """The file as a list of bytes-like parts (header, JSON, BIN header, BIN pieces).

    Parameters
    ----------
    doc : dict
        The glTF document to carry: every property is kept; ``accessors`` and
        ``bufferViews`` (if any) must refer to ``kept_bin`` (buffer 0 from offset 0).
        The primitives named in ``prims`` get the base mesh accessors and the extension
        object; their other properties (material, extras, other extensions) are kept.
    kept_bin : bytes
        The document's own data (images, other meshes), 4-byte aligned.  The BIN is laid
        out in the order a viewer needs it: every base mesh first, then ``kept_bin``
        (what the bases reference: textures...), then the chunks in stream order, so the
        first textured picture needs only the bytes up to the end of ``kept_bin``.
    prims : list[ProgressivePrimitive]
    order : list of (primitive index in ``prims``, chunk index)
        The stream order of every chunk (each primitive's chunks in increasing order).
    mac_key : bytes, optional
        The watermark key's :meth:`~pmwm_codec.watermark.key.WatermarkKey.mac_key`: every
        extension object gets the document's ``sceneMac`` and its ``baseMac`` (over the
        ``sceneMac`` too), every chunk entry a ``mac`` (:mod:`.mac`); without it the file
        has no MACs.
    """
    _check_primitives(prims, order)
    checks = _base_checks(prims)
    views = [dict(v) for v in doc.get("bufferViews", [])]
    accessors = copy.deepcopy(doc.get("accessors", []))
    bin_parts = []
    primitives_json, used, required, bases_end = _merge_bases(prims, views, accessors, bin_parts, 0)
    _shift_views(views[: len(doc.get("bufferViews", []))], bases_end)
    if kept_bin:
        bin_parts.append(kept_bin)
    index, offset = _index_chunks(prims, order, views, bin_parts, bases_end + len(kept_bin), zstd_level)
    if mac_key is not None:
        # sceneMac first: it leaves the extension objects out, and baseMac covers it
        draft = _document(doc, _merge_primitives(doc, prims, primitives_json, index, checks), accessors, views, offset,
                          used, required)
        scene = _scene_mac(mac_key, draft, bin_parts)
        for p, prim in enumerate(prims):
            ordinal, fields, attributes = checks[p]
            fields[SCENE_MAC] = scene
            public = {"version": FORMAT_VERSION, **prim.extension, SCENE_MAC: scene}
            fields["baseMac"] = base_mac(mac_key, ordinal, public, prim.base.positions_int, prim.base.faces, attributes)
            for k, entry in enumerate(index[p]):
                entry["mac"] = chunk_mac(mac_key, fields["baseMac"], ordinal, k, entry, prim.chunks[k],
                                         payload_version(prim.extension))
    meshes = _merge_primitives(doc, prims, primitives_json, index, checks)
    gltf = _document(doc, meshes, accessors, views, offset, used, required)
    return glb_parts(gltf, bin_parts, offset)


def _scene_mac(mac_key: bytes, gltf: dict, bin_parts) -> str:
    """The ``sceneMac`` of the document ``gltf`` about to be written with BIN ``bin_parts`` (:mod:`.mac`)."""
    scene = Scene(gltf)  # built once: its data's end, then its MAC
    end, data = scene.data_end(), bytearray()
    for part in bin_parts:  # the document's own data lies before the chunks: join no further than it needs
        if len(data) >= end:
            break
        data += part
    try:
        return scene.mac(mac_key, data)
    except LimitError:  # a document too large to MAC (the input's): refused in one line, nothing written
        raise
    except FormatError as exc:
        raise ValueError(f"write_pmw: the document's data cannot be read for its scene MAC ({exc})") from None


def _base_checks(prims) -> list:
    """Per primitive of ``prims``: ``(ordinal, fields, attributes)``, the ordinal being its rank in
    mesh/primitive order (the reader's numbering), ``fields`` the extension fields that check its
    decoded base (``baseDigest``; the caller adds ``sceneMac`` and ``baseMac`` with a MAC key) and
    ``attributes`` the base's decoded progressive attributes."""
    rank = {place: r for r, place in enumerate(sorted((p.mesh, p.primitive) for p in prims))}
    out = []
    for prim in prims:
        base, ordinal = prim.base, rank[(prim.mesh, prim.primitive)]
        mini = {"accessors": base.accessors, "bufferViews": base.buffer_views}
        primitive = {**base.primitive, "extensions": {**base.primitive.get("extensions", {}), EXTENSION_NAME: prim.extension}}
        attributes = decode_base_attributes(mini, base.data, primitive, prim.extension.get("attributes", ()))
        out.append((ordinal, {"baseDigest": base_digest(base.positions_int, base.faces, attributes)}, attributes))
    return out


def _shift_views(views: list, delta: int) -> None:
    """Move the document's own bufferViews (``views``, in place) ``delta`` bytes later in the BIN."""
    for view in views:
        view["byteOffset"] = view.get("byteOffset", 0) + delta


def _check_primitives(prims, order) -> None:
    """ValueError / TypeError unless ``prims`` and ``order`` can be written."""
    for prim in prims:
        if not isinstance(prim.base, EncodedBase):
            raise TypeError(f"write_pmw: base must be an EncodedBase, got {type(prim.base).__name__}")
        if len(prim.chunks) != len(prim.chunk_meta):
            raise ValueError(f"write_pmw: {len(prim.chunks)} chunks but {len(prim.chunk_meta)} chunk_meta entries")
        if not isinstance(prim.extension, dict):
            raise TypeError("write_pmw: extension must be a dict")
        clash = [key for key in RESERVED_FIELDS if key in prim.extension]
        if clash:
            raise ValueError(f"write_pmw: extension fields {clash} are set by the writer")
    try:
        versions = {payload_version(p.extension) for p in prims}
    except FormatError as exc:
        raise ValueError(f"write_pmw: {exc}") from None
    if len(versions) > 1:
        raise ValueError("write_pmw: every progressive primitive of a file must use the same payload version")
    if sum(len(p.chunks) for p in prims) > MAX_CHUNKS:
        raise ValueError(f"write_pmw: {sum(len(p.chunks) for p in prims)} chunks exceed the limit {MAX_CHUNKS}")
    if sorted(order) != sorted((p, k) for p, prim in enumerate(prims) for k in range(len(prim.chunks))):
        raise ValueError("write_pmw: order must name every chunk of every primitive once")


def _merge_bases(prims, views: list, accessors: list, bin_parts: list, offset: int) -> tuple:
    """Append every base's bufferViews, accessors and bytes (``views``, ``accessors`` and
    ``bin_parts`` grow in place) from BIN offset ``offset``.

    Returns ``(primitives_json, extensions_used, extensions_required, offset)``: each base's
    glTF primitive renumbered into the merged lists, and the BIN offset after the bases.
    """
    primitives_json = []
    used, required = [EXTENSION_NAME], []
    for prim in prims:
        base = prim.base
        view0, acc0 = len(views), len(accessors)
        for v in base.buffer_views:
            views.append({**v, "byteOffset": offset + v["byteOffset"]})
        for a in base.accessors:
            accessors.append({**a, "bufferView": a["bufferView"] + view0} if "bufferView" in a else dict(a))
        bin_parts.append(base.data)
        offset += len(base.data)
        pj = copy.deepcopy(base.primitive)
        pj["attributes"] = {k: v + acc0 for k, v in pj["attributes"].items()}
        if "indices" in pj:
            pj["indices"] += acc0
        draco = (pj.get("extensions") or {}).get(DRACO_EXTENSION)
        if draco is not None:
            draco["bufferView"] += view0
        primitives_json.append(pj)
        used += [e for e in base.extensions_used if e not in used]
        required += [e for e in base.extensions_required if e not in required]
    return primitives_json, used, required, offset


def _index_chunks(prims, order, views: list, bin_parts: list, offset: int, zstd_level: int) -> tuple:
    """Store every chunk in stream order and append it (``views`` and ``bin_parts`` grow).

    Payload version 1: one zstd frame per chunk in its own bufferView, 4-byte aligned.
    Version 2: the range-coded streams as they are, back to back in ONE bufferView shared by
    the primitives (bitstream.md §6.2).  Returns ``(index, offset)``: ``index[p][k]`` the
    entry of primitive p's chunk k (the shape :func:`~.extension.chunk_entries` reads back),
    and the BIN offset after the last chunk.
    """
    index = [[None] * len(prim.chunks) for prim in prims]
    vertices = [len(prim.base.positions_int) for prim in prims]  # before the next chunk (version 2)
    shared = None  # index of the version 2 bufferView
    for p, k in order:
        stored, entry = _stored_chunk(prims[p], k, zstd_level)
        if "byteOffset" not in entry:  # version 1
            views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(stored)})
            entry = {"bufferView": len(views) - 1, **entry}  # key order is part of the bytes
            pad = padded(len(stored)) - len(stored)
        else:
            if shared is None:
                shared = len(views)
                views.append({"buffer": 0, "byteOffset": offset, "byteLength": 0})
            entry["bufferView"], entry["byteOffset"] = shared, offset - views[shared]["byteOffset"]
            views[shared]["byteLength"] += len(stored)
            pad = 0
            if entry["splits"] != entry["vertexCount"] - vertices[p]:
                raise ValueError(f"write_pmw: chunk_meta[{k}] has {entry['splits']} splits but adds "
                                 f"{entry['vertexCount'] - vertices[p]} vertices")
            vertices[p] = entry["vertexCount"]
        index[p][k] = entry
        bin_parts += [stored, bytes(pad)] if pad else [stored]
        offset += len(stored) + pad
    if offset != padded(offset):  # after the version 2 chunks
        bin_parts.append(bytes(padded(offset) - offset))
        offset = padded(offset)
    return index, offset


def _stored_chunk(prim, k: int, zstd_level: int) -> tuple:
    """``(stored bytes, index entry without bufferView)`` of chunk ``k`` of ``prim``: a zstd
    frame (payload version 1) or the payload itself with a ``byteOffset`` to fill (version 2)."""
    payload, meta = prim.chunks[k], prim.chunk_meta[k]
    missing = [key for key in CHUNK_META_FIELDS if key not in meta]
    if missing:
        raise ValueError(f"write_pmw: chunk_meta[{k}] lacks {missing}")
    raw_length = len(memoryview(payload).cast("B"))
    if raw_length > MAX_DECOMPRESSED_CHUNK_BYTES:
        raise ValueError(f"write_pmw: chunk {k} has {raw_length} bytes, over the limit {MAX_DECOMPRESSED_CHUNK_BYTES}")
    if payload_version(prim.extension) == 2:  # a range-coded stream stored as it is (bitstream.md §8)
        stored = bytes(memoryview(payload).cast("B"))
        return stored, {
            "byteOffset": None, "byteLength": len(stored), "digest": digest(stored, 2),
            "vertexCount": meta["vertexCount"], "faceCount": meta["faceCount"],
            "geometricError": float32_up(meta["geometricError"]), "splits": meta["splits"], "uncompressedLength": raw_length,
        }
    stored = compress_chunk(payload, zstd_level)
    if len(stored) > MAX_CHUNK_BYTES:
        raise ValueError(f"write_pmw: chunk {k} compresses to {len(stored)} bytes, over the limit {MAX_CHUNK_BYTES}")
    return stored, {
        "byteLength": len(stored), "digest": digest(stored),
        **{key: meta[key] for key in CHUNK_META_FIELDS},
        **{key: value for key, value in meta.items() if key not in CHUNK_META_FIELDS and key != "mac"},
        "uncompressedLength": raw_length,
    }


def compact_chunks(entries, packed: bool = True) -> dict:
    """The chunk table of payload version 2 (bitstream.md §6.2) for per-chunk ``entries`` (the
    shape :func:`~.extension.chunk_entries` returns, all in one bufferView): its inverse.

    ``packed``: the values as one base64 string (``count`` + ``packed``, what the writer
    writes; every ``geometricError`` must be a float32 value); otherwise the JSON arrays of
    older files (a cut keeps a table in the form it found, so its MACs stay valid).
    ``byteOffsets`` is written only when the chunks are not back to back from offset 0."""
    entries = list(entries)
    table = {"bufferView": entries[0]["bufferView"]} if entries else {}
    offsets = [int(e["byteOffset"]) for e in entries]
    if offsets != [sum(e["byteLength"] for e in entries[:k]) for k in range(len(entries))]:
        table["byteOffsets"] = offsets
    if packed:
        table.update(pack_chunk_table(entries))
        return table
    for name, field in TABLE_ARRAYS:
        table[name] = [e[field] for e in entries]
    table["digests"] = "".join(e["digest"] for e in entries)
    if any("mac" in e for e in entries):
        table["macs"] = "".join(e["mac"] for e in entries)
    return table


def _merge_primitives(doc: dict, prims, primitives_json, index, checks) -> list:
    """The document's ``meshes`` with each progressive primitive replaced by its base
    primitive plus the extension object (other properties and extensions kept)."""
    meshes = copy.deepcopy(doc.get("meshes", []))
    for p, (prim, pj) in enumerate(zip(prims, primitives_json)):
        own = {k: v for k, v in prim.extension.items() if k not in DERIVED_FIELDS and k != SCENE_MAC}
        chunks = compact_chunks(index[p]) if payload_version(prim.extension) == 2 else index[p]
        ext = {"version": FORMAT_VERSION, **own, "chunks": chunks, **checks[p][1]}
        try:
            check_extension(ext)
        except FormatError as exc:
            raise ValueError(f"write_pmw: {exc}") from None
        original = meshes[prim.mesh]["primitives"][prim.primitive]
        merged = {k: v for k, v in original.items() if k not in ("attributes", "indices", "mode")}
        merged.update({k: v for k, v in pj.items() if k != "extensions"})
        merged["extensions"] = {**(original.get("extensions") or {}), **(pj.get("extensions") or {}), EXTENSION_NAME: ext}
        meshes[prim.mesh]["primitives"][prim.primitive] = merged
    return meshes


#: Top-level properties the writer sets itself (the document's own values are replaced).
_WRITER_PROPERTIES = ("asset", "extensionsUsed", "extensionsRequired", "accessors", "bufferViews", "buffers", "meshes")


def _document(doc: dict, meshes, accessors, views, bin_length: int, used, required) -> dict:
    """The output glTF JSON object: the document's properties with the merged lists."""
    gltf = {"asset": doc.get("asset") or {"version": "2.0", "generator": GENERATOR}}
    gltf["extensionsUsed"] = used + [e for e in doc.get("extensionsUsed", []) if e not in used]
    req = required + [e for e in doc.get("extensionsRequired", []) if e not in required]
    if req:
        gltf["extensionsRequired"] = req
    # Key order: asset and the extension lists first, then the document's own properties
    # in its order with ``meshes`` right after ``nodes`` (at the end when there are no
    # nodes), then accessors, bufferViews and buffers.  The order is part of the bytes.
    for key, value in doc.items():
        if key in _WRITER_PROPERTIES:
            continue
        gltf[key] = value
        if key == "nodes":
            gltf["meshes"] = meshes
    if "meshes" not in gltf:
        gltf["meshes"] = meshes
    gltf["accessors"] = accessors
    gltf["bufferViews"] = [without_defaults(view) for view in views]
    gltf["buffers"] = [{"byteLength": bin_length}]
    if not uses_quantization(gltf):  # a quantized input's progressive primitives became FLOAT bases (or Draco)
        forget_extension(gltf, QUANTIZATION_EXTENSION)
    return gltf


def glb_parts(gltf: dict, bin_parts, bin_length: int) -> list:
    """GLB framing around a JSON document and its BIN pieces (4-byte aligned, ``bin_length`` bytes)."""
    text = json.dumps(gltf, separators=(",", ":"), allow_nan=False).encode("utf-8")
    return frame_glb(text, bin_parts, bin_length)


def frame_glb(text: bytes, bin_parts, bin_length: int, version: int = GLB_VERSION) -> list:
    """``[GLB header, JSON chunk header, JSON text (space padded), BIN chunk header, *bin_parts]``.

    ``text`` is the JSON chunk's bytes (not checked: tests frame broken JSON too);
    ``bin_parts`` are bytes-like pieces totalling ``bin_length`` bytes, 4-byte aligned.
    """
    text += b" " * (padded(len(text)) - len(text))
    total = GLB_HEADER_SIZE + CHUNK_HEADER_SIZE + len(text) + CHUNK_HEADER_SIZE + bin_length
    if total >= 1 << 32:
        raise ValueError(f"write_pmw: file would be {total} bytes, over the GLB limit of 4 GiB")
    return [
        GlbHeader.build({"version": version, "length": total}),
        ChunkHeader.build({"length": len(text), "type": CHUNK_TYPE_JSON}),
        text,
        ChunkHeader.build({"length": bin_length, "type": CHUNK_TYPE_BIN}),
        *bin_parts,
    ]


def join_glb(gltf: dict, bin_payload, *, version: int = GLB_VERSION) -> bytes:
    """A GLB of any JSON dict (``json.dumps`` defaults, so NaN passes) and BIN bytes (zero padded).

    For tests and the fuzzer, which re-frame hostile documents; the writer uses :func:`glb_parts`.
    """
    text = json.dumps(gltf).encode("utf-8")
    payload = bytes(bin_payload)
    payload += bytes(padded(len(payload)) - len(payload))
    return b"".join(frame_glb(text, [payload], len(payload), version))


#: What a glTF 1.0 input is told (its GLB framing, its id-keyed collections and its techniques are not glTF 2.0's).
GLTF_1_ADVICE = ("pmw reads glTF 2.0: upgrade it first (glTF-Pipeline, gltf-pipeline -i IN -o OUT, writes glTF 2.0 "
                 "from a 1.0 file)")


def split_glb(data, name: str = "GLB") -> tuple:
    """``(gltf dict, BIN chunk bytes)`` of a GLB, read leniently (for input assets).

    Unknown chunks are skipped; the first JSON and the first BIN chunk count
    (``b""`` without a BIN chunk).  ``name`` starts the one-line
    :class:`~pmwm_codec.errors.InputFormatError` raised for a damaged file.
    The strict streaming reader of ``.pmw`` files is :mod:`.parser`.
    """
    if len(data) < GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:
        raise InputFormatError(f"{name}: GLB is cut short")
    try:
        header = GlbHeader.parse(data[:GLB_HEADER_SIZE])
    except Exception:
        raise InputFormatError(f"{name}: not a GLB file") from None
    if header.version == 1:  # KHR_binary_glTF: a glTF 1.0 document in a differently framed container
        raise InputFormatError(f"{name}: a GLB version 1 (glTF 1.0) file; {GLTF_1_ADVICE}")
    if header.version != GLB_VERSION:
        raise InputFormatError(f"{name}: GLB version {header.version}, not glTF 2.0's {GLB_VERSION}")
    if header.length > len(data):
        raise InputFormatError(f"{name}: GLB is cut short ({len(data)} of {header.length} bytes)")
    pos = GLB_HEADER_SIZE
    gltf, binary = None, b""
    while pos + CHUNK_HEADER_SIZE <= header.length:
        chunk = ChunkHeader.parse(data[pos : pos + CHUNK_HEADER_SIZE])
        body = data[pos + CHUNK_HEADER_SIZE : pos + CHUNK_HEADER_SIZE + chunk.length]
        if chunk.type == CHUNK_TYPE_JSON and gltf is None:
            try:
                gltf = json.loads(bytes(body).decode("utf-8"))
            except (UnicodeDecodeError, ValueError):
                raise InputFormatError(f"{name}: GLB JSON chunk is not valid JSON") from None
        elif chunk.type == CHUNK_TYPE_BIN and not binary:
            binary = bytes(body)
        pos += CHUNK_HEADER_SIZE + chunk.length
    if not isinstance(gltf, dict):
        raise InputFormatError(f"{name}: GLB has no JSON chunk")
    return gltf, binary


def write_parts(dst, parts) -> int:
    """Write assembled parts to a path (atomically, mode ``0666 & ~umask``) or a binary file object
    (every byte, or an error: :func:`~pmwm_codec.atomic.write_stream`); return the byte count.
    See :mod:`pmwm_codec.atomic`."""
    if not isinstance(dst, (str, os.PathLike)):
        return write_stream(dst, parts)
    return write_atomic(dst, parts)


def build_pmw(*, base: EncodedBase, chunks, chunk_meta, extension: dict, zstd_level: int = 10) -> bytes:
    """The ``.pmw`` file as bytes.

    Parameters
    ----------
    base : EncodedBase
        From :func:`~pmwm_codec.format.base.encode_base`.
    chunks : list of bytes-like
        Raw (uncompressed) chunk payloads in stream order; opaque to the container.
    chunk_meta : list of dict
        One per chunk: ``splits``, ``vertexCount``, ``faceCount``, ``geometricError``
        (extra keys are kept).
    extension : dict
        Caller fields of the extension object (``grid``, ``vertexCount``, ``faceCount``,
        ``watermark`` ...); ``version`` and ``chunks`` are set by the writer.
    zstd_level : int

    Raises
    ------
    ValueError, TypeError
        Inconsistent arguments, limits exceeded, or an extension object the schema rejects.
    """
    return b"".join(_assemble(base, chunks, chunk_meta, extension, zstd_level))


def write_pmw(dst, *, base: EncodedBase, chunks, chunk_meta, extension: dict, zstd_level: int = 10) -> int:
    """Write a ``.pmw`` file; return the number of bytes written.

    ``dst`` is a path (``str`` or ``os.PathLike``) or a binary file object.  A path is
    written atomically (:mod:`pmwm_codec.atomic`): on any exception nothing is left
    and an existing file at ``dst`` is untouched; the new file's mode is ``0666 & ~umask``.  Other arguments: see
    :func:`build_pmw`.
    """
    return write_parts(dst, _assemble(base, chunks, chunk_meta, extension, zstd_level))
