"""Turn any prefix of a ``.pmw`` into a valid, smaller ``.pmw``: the base and the first N chunks.

A byte prefix of a ``.pmw`` (a download that stopped) is usable by our reader and
three.js, but its GLB header still announces the full length, so strict glTF tools
(the Khronos validator, glTF-Transform, Blender) refuse it.  :func:`cut` rewrites
it as a complete file:

* the chunk index of every progressive primitive keeps only the chunks kept (the
  first ``chunks`` of the stream, in stream order, or all that arrived whole); a payload
  version 2 chunk table is rewritten in the form it had (packed or JSON arrays), its shared
  bufferView shortened to the last kept chunk;
* the extension's ``vertexCount`` / ``faceCount`` become the counts of the level
  reached (the counts after its last kept chunk, or of the base);
* the bufferViews of dropped chunks are removed and every bufferView reference is
  renumbered; the BIN ends after the last byte a kept bufferView uses;
* the GLB header, the BIN chunk header and ``buffers[0].byteLength`` agree.

Everything else (watermark parameters, ``fileId``, materials, images, key order of
the JSON) is kept as it is, so the cut file decodes to exactly the mesh the source
gives with the same number of chunks, and verifies with the source's key.  Chunk
bytes are copied, never recompressed; each kept chunk's digest is checked on the way.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

from ..constants import EXTENSION_NAME
from ..errors import TruncatedError
from ..format import BaseEvent, ChunkEvent, ContainerParser, HeaderEvent
from ..format.base import base_counts, base_vertex_count
from ..format.document import view_sites as document_view_sites
from ..format.extension import chunk_start, payload_version
from ..format.glb import compact_chunks, glb_parts
from ..format.gltf import find_extension_primitives
from ..format.layout import padded
from ..format.parser import trailing_bytes
from ..sources import iter_blocks


@dataclass(frozen=True)
class CutResult:
    """The cut file and what it holds.

    ``data`` the new ``.pmw``; ``chunks`` chunks kept; ``chunks_available`` chunks the
    source held whole; ``chunks_total`` chunks of the source's index; ``source_complete``
    whether the source had all its bytes.
    """

    data: bytes
    chunks: int
    chunks_available: int
    chunks_total: int
    source_complete: bool


def cut(source, chunks: int | None = None) -> bytes:
    """A valid ``.pmw`` with the base and the first ``chunks`` chunks (None: all that arrived).

    ``source``: any byte source (:mod:`pmwm_codec.sources`), whole or cut.  Raises
    :class:`~pmwm_codec.errors.TruncatedError` when the base mesh (or data it references)
    has not arrived, and the reader's format errors for a damaged file.
    """
    return cut_file(source, chunks).data


def cut_file(source, chunks: int | None = None) -> CutResult:
    """Like :func:`cut`, with the counts the ``pmw cut`` command reports."""
    if chunks is not None and chunks < 0:
        raise ValueError(f"chunks must be >= 0, got {chunks}")
    header, kept, received, complete = _read_prefix(source, chunks)
    gltf = copy.deepcopy(header.gltf_json)
    found = find_extension_primitives(gltf, EXTENSION_NAME)
    per_primitive = [0] * len(found)
    for event in kept:
        per_primitive[event.primitive] = max(per_primitive[event.primitive], event.chunk + 1)
    dropped, kept_ends, gone = set(), {}, []
    views = gltf.get("bufferViews", [])
    for (_, _, prim), entries, count in zip(found, header.extensions, per_primitive):
        ext = prim["extensions"][EXTENSION_NAME]
        entries = entries["chunks"]  # per-chunk entries, the compact table of payload version 2 expanded
        dropped.update(int(c["bufferView"]) for c in entries[count:])
        gone += [(int(views[c["bufferView"]].get("byteOffset", 0)) + int(c.get("byteOffset", 0)), int(c["byteLength"]))
                 for c in entries[count:]]
        for c in entries[:count]:
            end = int(c.get("byteOffset", 0)) + int(c["byteLength"])
            kept_ends[c["bufferView"]] = max(kept_ends.get(c["bufferView"], 0), end)
        level = entries[count - 1] if count else _base_counts(gltf, prim)
        ext["vertexCount"], ext["faceCount"] = int(level["vertexCount"]), int(level["faceCount"])
        if payload_version(ext) == 2:  # in the form it was found: its values, hence its MACs, unchanged
            ext["chunks"] = compact_chunks(entries[:count], packed="packed" in ext["chunks"])
        else:
            ext["chunks"] = ext["chunks"][:count]
    for view, end in kept_ends.items():  # a shared version 2 bufferView ends after its last kept chunk
        gltf["bufferViews"][view]["byteLength"] = end
    bin_bytes = _blanked(_compact(gltf, dropped - set(kept_ends), received, header.bin_offset), gone)
    data = b"".join(glb_parts(gltf, [bin_bytes], len(bin_bytes)))
    return CutResult(data, len(kept), _available(header, len(received)), header.chunk_count, complete)


def _read_prefix(source, chunks):
    """Read ``source``; the container parser checks it until ``chunks`` chunks are in.

    The remaining bytes are only collected (the data a kept bufferView needs may lie
    past the last kept chunk in files of other writers), never parsed, so damage in a
    dropped chunk does not matter; bytes after the declared length do (FormatError).  Returns ``(HeaderEvent, [ChunkEvent] kept, bytes
    received, whether the source was complete)``.
    """
    parser = ContainerParser()
    header, kept, received, parsing = None, [], bytearray(), True
    for block in iter_blocks(source):
        received += block
        if not parsing:
            continue
        for event in parser.feed(block):
            if isinstance(event, HeaderEvent):
                header = event
            elif isinstance(event, BaseEvent) and chunks == 0:
                parsing = False
            elif isinstance(event, ChunkEvent) and (chunks is None or len(kept) < chunks):
                kept.append(event)
                parsing = chunks is None or len(kept) < chunks
    if parsing:
        parser.close()  # TruncatedError when the base mesh never arrived
    if header is None or header.bin_offset is None:  # pragma: no cover - close() raised already
        raise TruncatedError(f"the file ends after {len(received):,} bytes, before its BIN chunk")
    if len(received) > header.total_length:  # (the parser names them, unless it stopped before they came)
        raise trailing_bytes(len(received), header.total_length)
    return header, kept, bytes(received), len(received) >= header.total_length


def _available(header, received: int) -> int:
    """Chunks of the source whose bytes all arrived (``received`` bytes of the file)."""
    views = header.gltf_json.get("bufferViews", [])
    have = received - header.bin_offset
    return sum(
        1 for ext in header.extensions or (header.extension,) for c in ext["chunks"]
        if chunk_start(views, c) + int(c["byteLength"]) <= have
    )


def data_not_arrived(received: int, needed: int) -> TruncatedError:
    """The error for a prefix that holds the base meshes but not all the document's other data it needs:
    ``received`` bytes of a file whose data ends at ``needed``."""
    return TruncatedError(f"the data the base mesh needs (textures, other meshes) has not arrived: "
                          f"{received:,} of {needed:,} bytes", bytes_read=received, bytes_needed=needed)


def _base_counts(gltf: dict, prim: dict) -> dict:
    """``{"vertexCount", "faceCount"}`` of a base primitive (declared: its accessors' counts, the
    vertices after the weld of a welded base)."""
    n, m = base_vertex_count(gltf, prim), base_counts(gltf, prim)[1]
    return {"vertexCount": n, "faceCount": m}


def _view_sites(gltf: dict):
    """Every bufferView reference ``holder[key]``: the document's (accessors, images, Draco)
    and the chunk entries of every progressive primitive."""
    yield from document_view_sites(gltf)
    for _, _, prim in find_extension_primitives(gltf, EXTENSION_NAME):
        chunks = prim["extensions"][EXTENSION_NAME]["chunks"]
        for holder in chunks if isinstance(chunks, list) else [chunks]:  # entries, or a version 2 table
            if "bufferView" in holder:
                yield holder, "bufferView"


def _blanked(data: bytes, ranges: list) -> bytes:
    """``data`` (the cut's BIN) with the ``(offset, length)`` ``ranges`` of the dropped chunks that lie in it
    zeroed: a gap before document data placed after the chunks (bitstream.md §4) carries nothing of them."""
    inside = [(start, min(length, len(data) - start)) for start, length in ranges if start < len(data)]
    if not inside:
        return data
    out = bytearray(data)
    for start, length in inside:
        out[start : start + length] = bytes(length)
    return bytes(out)


def _compact(gltf: dict, dropped: set, received: bytes, bin_offset: int) -> bytes:
    """Remove bufferViews ``dropped`` from ``gltf`` (in place, references renumbered) and
    return the BIN bytes up to the end of the last kept bufferView, zero padded to 4."""
    views = gltf.get("bufferViews", [])
    view_map, kept = {}, []
    for i, view in enumerate(views):
        if i not in dropped:
            view_map[i] = len(kept)
            kept.append(view)
    for holder, key in _view_sites(gltf):
        holder[key] = view_map[holder[key]]
    gltf["bufferViews"] = kept
    end = max((int(v.get("byteOffset", 0)) + int(v["byteLength"]) for v in kept), default=0)
    if end > len(received) - bin_offset:
        raise data_not_arrived(len(received), bin_offset + end)
    length = padded(end)
    gltf["buffers"][0]["byteLength"] = length
    return received[bin_offset : bin_offset + end] + bytes(length - end)
