"""Push parser for ``.pmw`` containers: bytes in, events out, as soon as they are complete.

Contract
--------
``ContainerParser.feed(data)`` accepts any slice of the stream and returns the events
that became complete, in stream order:

1. :class:`HeaderEvent` once the 20-byte preamble and the JSON chunk are in.  All byte
   ranges (base mesh, every chunk) are known from here on.
2. :class:`BaseEvent` once the base mesh bufferViews are in.
3. :class:`ChunkEvent` for each vertex-split chunk whose bytes are all in, in order,
   digest-checked and zstd-decompressed.  ``ContainerParser(max_chunks=N)`` opens the first
   ``N`` chunks only: the bytes of the others are passed over unread (no event, no digest,
   as a reader fetching only what it needs never sees them), still counted for ``complete``.

``close()`` ends the stream and returns an :class:`EndEvent`.  A stream cut after the
base mesh is *progress, not corruption*: ``EndEvent.complete`` is False and the chunks
already delivered stay valid.  A stream cut before the base mesh is complete raises
:class:`~pmwm_codec.errors.TruncatedError`.

Every event carries ``bytes_read`` as the absolute stream offset at which it became
complete, so the events do not depend on how the bytes were split into ``feed`` calls.

Corruption is a named error, raised from ``feed`` (or, when the same ``feed`` call
first completed other events, returned after them and raised by the next ``feed``
or ``close`` call, so every good chunk before a bad one is delivered): a bad digest is ``ChecksumError``
(``.chunk`` = its number in stream order, from 1 as in the message; None for a base mesh whose ``baseDigest`` differs); bad magic, JSON, layout or extension fields are ``FormatError``;
a newer extension ``version`` is ``UnsupportedVersionError``; declared sizes or counts
over the limits of :mod:`pmwm_codec.constants` (and JSON nested deeper than ``MAX_JSON_DEPTH``) are ``LimitError``, checked before
anything of that size is allocated or decompressed.  Bytes after the GLB header's ``length`` are a
``FormatError`` raised the same way: the bytes up to that length are read as usual and the events they
complete are returned first (spec README, *Partial files*), however the stream was split into ``feed`` calls.

A parser is single-use: after ``close()`` or after it raised, it refuses more input.
:func:`~.reader.iter_events` and :func:`~.reader.read_header` (in :mod:`.reader`) are thin pull wrappers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import zstandard
from construct import ConstructError

from ..constants import (
    EXTENSION_NAME,
    MAX_CHUNK_BYTES,
    MAX_CHUNKS,
    MAX_DECOMPRESSED_CHUNK_BYTES,
    MAX_FACES,
    MAX_JSON_BYTES,
    MAX_VERTICES,
)
from ..errors import ChecksumError, FormatError, LimitError, TruncatedError, UnsupportedVersionError
from ..progressive.grid import Grid
from ..sources import byte_view
from . import base as _base
from .extension import base_digest, check_extension, chunk_entries, digest, integer_members, payload_version
from .gltf import (check_json_text_depth, find_extension_primitives, loads_finite, named_view_sites, shown_value, uint,
                   view_range)
from .layout import (
    ALIGNMENT,
    CHUNK_HEADER_SIZE,
    CHUNK_TYPE_BIN,
    CHUNK_TYPE_JSON,
    GLB_HEADER_SIZE,
    GLB_MAGIC,
    GLB_VERSION,
    PREAMBLE_SIZE,
    ChunkHeader,
    GlbHeader,
)


# ----------------------------------------------------------------------- events


@dataclass(frozen=True)
class HeaderEvent:
    """The glTF JSON is in: every byte range is known."""

    gltf_json: dict
    extension: dict  # the first progressive primitive's extension object
    total_length: int  # GLB header length: the size of the complete file
    chunk_count: int  # all chunks of all progressive primitives
    extensions: tuple = ()  # every progressive primitive's extension object, in mesh/primitive order
    bin_offset: int | None = None  # absolute offset of the BIN chunk's payload (buffer 0 starts here)


@dataclass(frozen=True, eq=False)
class BaseEvent:
    """A base mesh is in.  ``positions_int`` (n, 3) int64 grid coordinates, ``faces`` (m, 3) int64.

    ``attributes_int`` (n, a) int64 quantized attributes in the order of the extension's
    ``attributes`` list (a = 0 without attributes).  ``primitive`` numbers the progressive
    primitives in mesh/primitive order; all bases arrive together, before any chunk.
    """

    positions_int: np.ndarray
    faces: np.ndarray
    bytes_read: int
    primitive: int = 0
    attributes_int: np.ndarray | None = None

    def __eq__(self, other):
        if not isinstance(other, BaseEvent):
            return NotImplemented
        return (
            self.bytes_read == other.bytes_read
            and np.array_equal(self.positions_int, other.positions_int)
            and np.array_equal(self.faces, other.faces)
        )

    __hash__ = None


@dataclass(frozen=True)
class ChunkEvent:
    """Chunk ``index`` (in stream order over all primitives) is in; ``payload`` is its raw bytes.

    ``primitive`` is the progressive primitive it refines and ``chunk`` its index in that
    primitive's ``chunks`` array.
    """

    index: int
    payload: bytes
    bytes_read: int
    primitive: int = 0
    chunk: int = 0


@dataclass(frozen=True)
class EndEvent:
    """The stream ended (``close()``).  ``complete`` is False for a cut stream."""

    complete: bool
    bytes_read: int
    total_length: int
    chunks_delivered: int
    chunk_count: int

    @property
    def truncated(self) -> bool:
        return not self.complete


# ------------------------------------------------------------------ header sniff


def trailing_bytes(size: int, total: int) -> FormatError:
    """The error of a file of ``size`` bytes longer than the GLB's declared ``total`` length (every reader
    refuses the bytes after it: they are no part of the file, and a reader that took them would disagree
    with one that stopped at the declared length)."""
    return FormatError(f"GLB: {size - total} bytes after the declared file length {total}")


#: What the first bytes of a file that is no GLB say it is (:func:`_what_else`): text formats by their first word, at
#: most 4 bytes of it (a streamed file is refused as soon as its first 4 bytes are in).
_TEXT_KINDS = ((b"{", "a glTF JSON file"), (b"ply", "a PLY mesh"), (b"soli", "an STL mesh"),
               (b"v ", "an OBJ mesh"), (b"OFF", "an OFF mesh"), (b"COFF", "an OFF mesh"),
               (b"#", "a text file, an OBJ mesh perhaps"))


def _what_else(head: bytes) -> str:
    """``" (a glTF JSON file, not a .pmw: pmw encode makes one)"`` when the first bytes ``head`` of a file that is
    no GLB show what it is (:data:`_TEXT_KINDS`), else ``""``."""
    text = head.lstrip(b"\xef\xbb\xbf").lstrip()
    for start, kind in _TEXT_KINDS:
        if text.startswith(start):
            return f" ({kind}, not a .pmw: pmw encode makes one)"
    return ""


def parse_preamble(data) -> tuple[int, int]:
    """``(total_length, json_length)`` from the first 20 bytes, or FormatError/LimitError."""
    head = bytes(data[:PREAMBLE_SIZE])
    if head[:4] != GLB_MAGIC:
        raise FormatError(f"GLB header: bad magic {head[:4]!r}, not a glTF binary{_what_else(head)}")
    try:
        glb = GlbHeader.parse(head[:GLB_HEADER_SIZE])
        chunk = ChunkHeader.parse(head[GLB_HEADER_SIZE:PREAMBLE_SIZE])
    except ConstructError as exc:  # pragma: no cover - magic already checked
        raise FormatError(f"GLB header: {exc}".splitlines()[0]) from None
    if glb.version != GLB_VERSION:  # a container this reader does not implement (spec README, Conformance)
        raise UnsupportedVersionError(f"GLB header: container version {glb.version}, expected {GLB_VERSION}")
    if chunk.type != CHUNK_TYPE_JSON:
        raise FormatError(f"GLB header: first chunk type {chunk.type!r}, expected {CHUNK_TYPE_JSON!r}")
    if chunk.length > MAX_JSON_BYTES:
        raise LimitError(f"GLB header: JSON chunk of {chunk.length} bytes exceeds the limit {MAX_JSON_BYTES}")
    if chunk.length == 0 or chunk.length % ALIGNMENT:
        raise FormatError(f"GLB header: JSON chunk length {chunk.length} is not a positive multiple of {ALIGNMENT}")
    if PREAMBLE_SIZE + chunk.length + CHUNK_HEADER_SIZE > glb.length:
        raise FormatError(f"GLB header: total length {glb.length} cannot hold a {chunk.length}-byte JSON chunk and a BIN chunk")
    return glb.length, chunk.length


@dataclass(frozen=True)
class _Plan:
    """Byte ranges (relative to the BIN payload) derived from the JSON."""

    primitives: tuple  # progressive primitives, mesh/primitive order
    extensions: tuple  # their extension objects
    base_end: int
    chunk_ranges: tuple  # ((start, end, primitive, chunk), ...) in stream order
    buffer_length: int


def _plan(gltf: dict, exts: list, bin_capacity: int) -> _Plan:
    """Check the JSON's structure and limits; compute every byte range."""
    used = gltf.get("extensionsUsed", [])
    if not isinstance(used, list) or EXTENSION_NAME not in used:
        raise FormatError(f"glTF JSON: {EXTENSION_NAME} is not listed in extensionsUsed")
    buffers = gltf.get("buffers")
    if not isinstance(buffers, list) or not buffers or not isinstance(buffers[0], dict):
        raise FormatError("glTF JSON: no buffers[0] for the GLB BIN chunk")
    if "uri" in buffers[0]:
        raise FormatError("glTF JSON: buffers[0] has a uri; a .pmw keeps its data in the GLB BIN chunk")
    views = gltf.get("bufferViews")
    for i, view in enumerate(views if isinstance(views, list) else ()):
        if isinstance(view, dict) and view.get("extensions"):
            names = ", ".join(sorted(map(str, view["extensions"]))) if isinstance(view["extensions"], dict) else "extensions"
            raise FormatError(f"glTF JSON: bufferViews[{i}] carries {names}; a .pmw's bufferViews hold their bytes as "
                              "stored (a viewer would decode other bytes than the ones the digests and MACs cover)")
    buffer_length = uint(buffers[0], "byteLength", "buffers[0]")
    if buffer_length > bin_capacity:
        raise FormatError(f"glTF JSON: buffers[0].byteLength {buffer_length} exceeds the {bin_capacity} bytes the GLB length leaves")
    primitives = [prim for _, _, prim in find_extension_primitives(gltf, EXTENSION_NAME)]
    total_vertices = total_faces = 0
    for ext in exts:
        total_vertices += ext["vertexCount"]
        total_faces += ext["faceCount"]
    if total_vertices > MAX_VERTICES:
        raise LimitError(f"{EXTENSION_NAME}: vertexCount {shown_value(total_vertices)} exceeds the limit {MAX_VERTICES}")
    if total_faces > MAX_FACES:
        raise LimitError(f"{EXTENSION_NAME}: faceCount {shown_value(total_faces)} exceeds the limit {MAX_FACES}")

    views = gltf.get("bufferViews")
    base_end = 0
    bases = []  # each primitive's base (vertices as the chunks see them, faces)
    for primitive, ext in zip(primitives, exts):
        for index in _base.base_views(gltf, primitive, ext.get("attributes", ())):
            start, end = view_range(views, index, buffer_length, "base mesh")
            base_end = max(base_end, end)
        faces0 = _base.base_counts(gltf, primitive)[1]  # base vertex/face counts against the limits
        bases.append((_base.base_vertex_count(gltf, primitive), faces0))

    if sum(len(ext["chunks"]) for ext in exts) > MAX_CHUNKS:
        raise LimitError(f"{EXTENSION_NAME}: {sum(len(e['chunks']) for e in exts)} chunks exceed the limit {MAX_CHUNKS}")
    ranges = []
    for p, ext in enumerate(exts):
        previous_end = base_end
        for k, chunk in enumerate(ext["chunks"]):
            what = f"{EXTENSION_NAME}: " + (f"primitive {p} " if len(exts) > 1 else "") + f"chunks[{k}]"
            start, end = _chunk_range(views, chunk, buffer_length, what, previous_end, payload_version(ext))
            ranges.append((start, end, p, k))
            previous_end = end
    ranges.sort()
    for (s0, e0, *_), (s1, e1, p1, k1) in zip(ranges, ranges[1:]):
        if s1 < e0:
            raise FormatError(f"{EXTENSION_NAME}: chunks[{k1}] of primitive {p1} overlaps the chunk before it")
    _check_chunk_views_unshared(gltf, exts, buffer_length)
    for ext, (vertices0, faces0) in zip(exts, bases):
        _check_final_counts(ext, vertices0, faces0)
    return _Plan(tuple(primitives), tuple(exts), base_end, tuple(ranges), buffer_length)


def _check_chunk_views_unshared(gltf: dict, exts: list, buffer_length: int) -> None:
    """FormatError when a bufferView that holds chunks (a version 1 chunk's, a chunk table's; their ranges checked)
    shares a byte with any other bufferView of the BIN (the base meshes', the document's data), or when an
    accessor, an image or a Draco object reads it (bitstream.md §4): a cut shortens or drops it and zeroes
    the chunks it drops, so whatever else read those bytes would silently change.  The chunk tables of
    several primitives may name one bufferView, and the chunk bufferViews may overlap one another."""
    views = gltf.get("bufferViews")
    chunk_views = sorted({int(c["bufferView"]) for ext in exts for c in ext["chunks"]})
    if not chunk_views:
        return
    chunk_set = set(chunk_views)
    for where, holder, key in named_view_sites(gltf):
        if type(holder[key]) is int and holder[key] in chunk_set:
            raise FormatError(f"{EXTENSION_NAME}: {where} reads bufferView {holder[key]}, which holds chunks "
                              "(a chunk's bytes are no other data's)")
    spans = sorted((*view_range(views, i, buffer_length, EXTENSION_NAME), i) for i in chunk_views)
    starts = np.array([start for start, _, _ in spans], dtype=np.int64)  # (c,) sorted
    ends = np.maximum.accumulate(np.array([end for _, end, _ in spans], dtype=np.int64))  # (c,) furthest end so far
    for i, view in enumerate(views):
        fields = [view.get(key, default) for key, default in (("buffer", 0), ("byteOffset", 0), ("byteLength", None))] \
            if isinstance(view, dict) else None
        if i in chunk_set or fields is None or any(type(x) is not int for x in fields) or fields[0] != 0 \
                or fields[1] < 0 or fields[2] <= 0:
            continue  # a view of another buffer, or one no reader reads bytes through: it shares none
        _, start, length = fields
        before = int(np.searchsorted(starts, start + length))  # the chunk views that start before it ends
        if before and ends[before - 1] > start:
            shared = next(j for s, e, j in spans[:before] if e > start)
            raise FormatError(f"{EXTENSION_NAME}: bufferViews[{i}] shares bytes with bufferView {shared}, which holds "
                              "chunks (a chunk's bytes are no other data's)")


def _check_final_counts(ext: dict, base_vertices: int, base_faces: int) -> None:
    """The extension's ``vertexCount`` / ``faceCount`` are the counts after all chunks of the file (spec
    README): the last chunk's, or the base mesh's when there is none.  FormatError otherwise (a file
    declaring millions it never reaches decoded as complete to fewer).  They bound what a reader holds;
    its arrays grow as the chunks decode (:meth:`~pmwm_codec.progressive.vsplit.MeshState.reserve`)."""
    chunks = ext["chunks"]
    last = (chunks[-1]["vertexCount"], chunks[-1]["faceCount"]) if chunks else (base_vertices, base_faces)
    if (ext["vertexCount"], ext["faceCount"]) != last:
        raise FormatError(f"{EXTENSION_NAME}: vertexCount / faceCount {ext['vertexCount']} / {ext['faceCount']} differ "
                          f"from the {last[0]} / {last[1]} " + ("its last chunk reaches" if chunks else "of its base mesh"))


def _chunk_range(views, chunk, buffer_length, what, previous_end, version=1):
    """Check one chunk entry; return its (start, end) in the BIN payload.  A version 1 chunk
    is its whole bufferView; a version 2 chunk lies at its ``byteOffset`` inside it."""
    if chunk["byteLength"] > MAX_CHUNK_BYTES:
        raise LimitError(f"{what}: byteLength {chunk['byteLength']} exceeds the limit {MAX_CHUNK_BYTES}")
    if chunk["uncompressedLength"] > MAX_DECOMPRESSED_CHUNK_BYTES:
        raise LimitError(f"{what}: uncompressedLength {chunk['uncompressedLength']} exceeds the limit {MAX_DECOMPRESSED_CHUNK_BYTES}")
    if chunk["vertexCount"] > MAX_VERTICES or chunk["faceCount"] > MAX_FACES:
        raise LimitError(f"{what}: {chunk['vertexCount']} vertices / {chunk['faceCount']} faces exceed the limits")
    if chunk["splits"] > MAX_VERTICES:  # each split adds a vertex
        raise LimitError(f"{what}: splits {chunk['splits']} exceeds the limit {MAX_VERTICES}")
    start, end = view_range(views, chunk["bufferView"], buffer_length, what)
    if version == 2:
        start, view_end = start + chunk["byteOffset"], end
        end = start + chunk["byteLength"]
        if end > view_end:
            raise FormatError(f"{what}: ends at {end}, past the end {view_end} of its bufferView")
    elif end - start != chunk["byteLength"]:
        raise FormatError(f"{what}: byteLength {chunk['byteLength']} differs from bufferView length {end - start}")
    if start < previous_end:
        raise FormatError(f"{what}: bufferView starts at {start}, before the end {previous_end} of the data before it (overlap or out of stream order)")
    return start, end


# ----------------------------------------------------------------------- parser

_PREAMBLE, _JSON, _BIN_HEADER, _BASE, _CHUNKS, _TAIL, _CLOSED, _FAILED = range(8)


def truncated_before_base(received: int, needed: int | None, header: bool, bin_header: bool = False) -> TruncatedError:
    """The one refusal of a stream that ends before its base mesh is whole, read by push or by pull alike.

    ``header``: it ended inside the GLB header or JSON; ``bin_header``: inside the BIN chunk's header.  There
    ``needed`` (:attr:`ContainerParser.bytes_needed`) is a lower bound, the end of the BIN chunk's header: "at
    least" (the JavaScript reader parses the JSON once that header is in, so every reader names the same bound).
    """
    where = "inside the GLB header or JSON, " if header else "inside the BIN chunk header, " if bin_header else ""
    need = "" if needed is None else f" (needs {'at least ' if header or bin_header else ''}{needed} bytes)"
    where += "before the base mesh was complete"
    return TruncatedError(f"truncated: stream ended after {received} bytes, {where}{need}", bytes_read=received,
                          bytes_needed=needed)


class ContainerParser:
    """Incremental (push) reader of one ``.pmw`` stream.  Single-use.

    >>> parser = ContainerParser()
    >>> events = parser.feed(first_bytes)      # doctest: +SKIP
    >>> events += parser.feed(more_bytes)      # doctest: +SKIP
    >>> end = parser.close()                   # doctest: +SKIP
    """

    def __init__(self, max_chunks: int | None = None):
        self.max_chunks = max_chunks
        self._buf = bytearray()
        self._buf_start = 0  # absolute offset of _buf[0]
        self._received = 0
        self._state = _PREAMBLE
        self._total = None
        self._json_length = None
        self._bin_data = None  # absolute offset of the BIN payload
        self._gltf = None
        self._ext = None
        self._plan = None
        self._next_chunk = 0
        self._pending_error = None

    @property
    def bytes_read(self) -> int:
        """Bytes fed so far."""
        return self._received

    @property
    def bytes_needed(self):
        """The bytes the stream needs before its base mesh is complete (spec README, *Partial files*): the base
        meshes' end once the JSON is in; before, the lower bound that every reader names, the end of the BIN
        chunk's header (``28 + J``) once the 20-byte preamble gives the JSON's length ``J``, else 20.  None once
        the base mesh is in."""
        return self._needed(self._state)

    @property
    def json_length(self):
        """Length of the JSON chunk once the 20-byte preamble is in, else None."""
        return self._json_length

    def feed(self, data) -> list:
        """Add bytes; return the list of events that became complete (may be empty)."""
        if self._state == _CLOSED:
            raise RuntimeError("ContainerParser: feed() after close(); a parser is single-use")
        self._raise_pending()
        if self._state == _FAILED:
            raise RuntimeError("ContainerParser: feed() after an error; a parser is single-use")
        data = byte_view(data, "ContainerParser.feed()")
        self._received += len(data)
        if self._total is not None and self._received > self._total:  # only the bytes up to the length are read
            data = data[: max(0, len(data) - (self._received - self._total))]
        if self._state != _TAIL:
            self._buf += data
        events = []
        try:
            while True:
                event = self._step()
                if event is None:
                    break
                if isinstance(event, list):
                    events.extend(event)
                elif event is not True:
                    events.append(event)
            if self._total is not None and self._received > self._total:  # after the events the file's bytes made
                raise trailing_bytes(self._received, self._total)
        except Exception as exc:
            self._state = _FAILED
            if not events:
                raise
            self._pending_error = exc  # deliver what completed first; raise on the next call
        return events

    def _raise_pending(self):
        error, self._pending_error = self._pending_error, None
        if error is not None:
            raise error

    def close(self) -> EndEvent:
        """End the stream.  Returns an EndEvent; raises TruncatedError if the base mesh is incomplete."""
        self._raise_pending()
        if self._state in (_CLOSED, _FAILED):
            raise RuntimeError("ContainerParser: close() called twice or after an error; a parser is single-use")
        state = self._state
        self._state = _CLOSED
        self._buf = bytearray()
        if state <= _BASE:
            raise truncated_before_base(self._received, self._needed(state), header=state <= _JSON,
                                        bin_header=state == _BIN_HEADER)
        count = len(self._plan.chunk_ranges)
        return EndEvent(
            complete=self._received == self._total and self._next_chunk == count,
            bytes_read=self._received, total_length=self._total,
            chunks_delivered=self._next_chunk, chunk_count=count,
        )

    # -- internals -------------------------------------------------------------

    def _needed(self, state):
        if state == _PREAMBLE:
            return PREAMBLE_SIZE
        if state in (_JSON, _BIN_HEADER):  # the base lies in the BIN chunk: at least up to its data
            return PREAMBLE_SIZE + self._json_length + CHUNK_HEADER_SIZE
        if state == _BASE:
            return self._bin_data + self._plan.base_end
        return None

    def _take(self, end: int):
        """Bytes from _buf_start to absolute offset ``end``, or None if not all in; drops them."""
        if self._buf_start + len(self._buf) < end:
            return None
        cut = end - self._buf_start
        out = bytes(self._buf[:cut])
        del self._buf[:cut]
        self._buf_start = end
        return out

    def _skip_to(self, offset: int) -> bool:
        """Drop bytes before ``offset``; True if the buffer reaches it."""
        if self._buf_start + len(self._buf) < offset:
            return False
        del self._buf[: offset - self._buf_start]
        self._buf_start = offset
        return True

    def _chunk_done(self) -> None:
        """The next chunk's bytes are consumed: after the last one, only the padding is left."""
        self._next_chunk += 1
        if self._next_chunk == len(self._plan.chunk_ranges):
            self._state = _TAIL
            self._buf = bytearray()

    def _step(self):
        """Advance one state; return an event, True (progress, no event) or None (need bytes)."""
        state = self._state
        if state == _PREAMBLE:
            head = self._take(PREAMBLE_SIZE)
            if head is None:
                if len(self._buf) >= 4 and bytes(self._buf[:4]) != GLB_MAGIC:
                    parse_preamble(bytes(self._buf[:4]) + bytes(PREAMBLE_SIZE))  # bad magic, early
                return None
            self._total, self._json_length = parse_preamble(head)
            if self._received > self._total:  # the bytes after the length are no part of the file: never read
                del self._buf[max(0, self._total - self._buf_start):]
            self._state = _JSON
            return True
        if state == _JSON:
            text = self._take(PREAMBLE_SIZE + self._json_length)
            if text is None:
                return None
            self._gltf, exts = _load_json(text)
            self._ext = exts[0]
            self._bin_data = PREAMBLE_SIZE + self._json_length + CHUNK_HEADER_SIZE
            self._plan = _plan(self._gltf, exts, self._total - self._bin_data)
            self._state = _BIN_HEADER
            return HeaderEvent(self._gltf, self._ext, self._total, len(self._plan.chunk_ranges), tuple(exts),
                               self._bin_data)
        if state == _BIN_HEADER:
            head = self._take(self._bin_data)
            if head is None:
                return None
            chunk = ChunkHeader.parse(head)
            if chunk.type != CHUNK_TYPE_BIN:
                raise FormatError(f"GLB: second chunk type {chunk.type!r}, expected {CHUNK_TYPE_BIN!r}")
            if chunk.length % ALIGNMENT:  # bitstream.md §3: a chunk's length is a multiple of 4
                raise FormatError(f"GLB: BIN chunk length {chunk.length} is not a multiple of {ALIGNMENT}")
            if self._bin_data + chunk.length != self._total:
                raise FormatError(f"GLB: BIN chunk of {chunk.length} bytes does not end at the file length {self._total}")
            if chunk.length < self._plan.buffer_length:
                raise FormatError(f"GLB: BIN chunk of {chunk.length} bytes is shorter than buffers[0].byteLength {self._plan.buffer_length}")
            self._state = _BASE
            return True
        if state == _BASE:
            data = self._take(self._bin_data + self._plan.base_end)
            if data is None:
                return None
            events = []
            for p, (prim, ext) in enumerate(zip(self._plan.primitives, self._plan.extensions)):
                positions, faces, attributes = _base.read_base(self._gltf, data, Grid.from_config(ext["grid"]), prim,
                                                               ext.get("attributes", ()))
                _check_base_digest(ext, positions, faces, attributes, p, len(self._plan.extensions))
                events.append(BaseEvent(positions, faces, self._bin_data + self._plan.base_end, p, attributes))
            self._state = _CHUNKS if self._plan.chunk_ranges else _TAIL
            if self._state == _TAIL:
                self._buf = bytearray()
            return events
        if state == _CHUNKS:
            k = self._next_chunk
            start, end, p, kp = self._plan.chunk_ranges[k]
            if not self._skip_to(self._bin_data + start):
                return None
            if self.max_chunks is not None and k >= self.max_chunks:  # not asked for: pass over it
                if not self._skip_to(self._bin_data + end):
                    return None
                self._chunk_done()
                return True
            stored = self._take(self._bin_data + end)
            if stored is None:
                return None
            payload = _open_chunk(k, stored, self._plan.extensions[p]["chunks"][kp], payload_version(self._plan.extensions[p]))
            self._chunk_done()
            return ChunkEvent(k, payload, self._bin_data + end, p, kp)
        return None  # _TAIL: padding up to the file length


def _load_json(text: bytes):
    try:
        decoded = text.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(f"GLB JSON chunk: not valid UTF-8 JSON ({str(exc).splitlines()[0]})") from None
    check_json_text_depth(text, "GLB JSON chunk")  # before the parser recurses into it (spec README, Conformance)
    try:  # a NaN or infinite number is refused, named, as the parser reads it (spec README, Conformance)
        gltf = loads_finite(decoded, "GLB JSON chunk", FormatError)
    except FormatError:
        raise
    except ValueError as exc:
        raise FormatError(f"GLB JSON chunk: not valid UTF-8 JSON ({str(exc).splitlines()[0]})") from None
    if not isinstance(gltf, dict):
        raise FormatError("GLB JSON chunk: top level is not an object")
    integer_members(gltf)  # 16.0 where an integer belongs is 16 (spec README, JSON numbers)
    exts = []
    for _, _, prim in find_extension_primitives(gltf, EXTENSION_NAME):
        ext = check_extension(prim["extensions"][EXTENSION_NAME])
        if payload_version(ext) == 2:  # the compact table as per-chunk entries (the gltf keeps it as stored)
            ext = {**ext, "chunks": chunk_entries(ext, _base.base_vertex_count(gltf, prim))}
        else:
            chunk_entries(ext, 0)  # a version 1 object must hold an array
        exts.append(ext)
    return gltf, exts


def _check_base_digest(ext: dict, positions, faces, attributes, p: int, count: int) -> None:
    """ChecksumError when primitive ``p``'s decoded base differs from its ``baseDigest``
    (bitstream.md §6.4; files without the field are not checked)."""
    expected = ext.get("baseDigest")
    if expected is not None and base_digest(positions, faces, attributes) != expected:
        which = f" of progressive primitive {p + 1}" if count > 1 else ""
        raise ChecksumError(f"base mesh{which}: baseDigest mismatch, the base mesh decodes to other geometry than was written (corrupt)")


def _open_chunk(k: int, stored: bytes, meta: dict, version: int = 1) -> bytes:
    """Digest-check chunk ``k`` (0-based stream index) and return its raw payload: the zstd frame decompressed
    (payload version 1, bitstream.md §5) or the stored range-coded stream itself (version 2, §8)."""
    if digest(stored, version) != meta["digest"]:
        raise ChecksumError(f"chunk {k + 1}: digest mismatch, the stored bytes are corrupt", chunk=k + 1)
    declared = meta["uncompressedLength"]
    if version == 2:
        if declared != len(stored):
            raise FormatError(f"chunk {k + 1}: uncompressedLength {declared} differs from byteLength {len(stored)} (payload version 2)")
        return bytes(stored)
    try:
        params = zstandard.get_frame_parameters(stored)
    except zstandard.ZstdError as exc:
        raise FormatError(f"chunk {k + 1}: not a zstd frame ({exc})") from None
    if params.content_size == zstandard.CONTENTSIZE_UNKNOWN:
        raise FormatError(f"chunk {k + 1}: zstd frame does not declare its content size")
    if params.content_size != declared:
        raise FormatError(f"chunk {k + 1}: zstd frame content size {params.content_size} differs from uncompressedLength {declared}")
    if not params.has_checksum:
        raise FormatError(f"chunk {k + 1}: zstd frame has no content checksum")
    dobj = zstandard.ZstdDecompressor().decompressobj(write_size=max(1, min(declared, 1 << 20)))
    try:
        payload = dobj.decompress(stored)
    except zstandard.ZstdError as exc:
        raise FormatError(f"chunk {k + 1}: zstd frame does not decompress ({exc})") from None
    if not dobj.eof or dobj.unused_data or len(payload) != declared:
        raise FormatError(f"chunk {k + 1}: zstd frame is incomplete, has trailing bytes, or differs from uncompressedLength {declared}")
    return payload
