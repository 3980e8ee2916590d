"""The ``PMWM_progressive_mesh`` extension object: schema check, digests and the chunk index.

The normative schemas live in ``spec/schema/``; this package ships byte-identical
copies in ``pmwm_codec/format/schema/`` (``tests/test_spec_sync.py`` keeps them
equal) so an installed package can validate without the source tree.

:func:`check_extension` is the gate every extension object passes before a reader
uses it: an unknown newer ``version`` is :class:`UnsupportedVersionError`, anything
the schema rejects is a one-line :class:`FormatError`.

:func:`chunk_entries` is the one place a reader turns the compact chunk table of payload
version 2 (bitstream.md §6.2) into the per-chunk entries of version 1, so everything
after the parser (replay, MACs, cut, inspect) reads one shape; the writer's side is
:func:`pmwm_codec.format.glb.compact_chunks`.
"""

from __future__ import annotations

import base64
import binascii
import functools
import hashlib
import json
from pathlib import Path

import numpy as np

from ..constants import EXTENSION_NAME, FORMAT_VERSION, MAX_CHUNKS, MAX_VERTICES
from ..errors import FormatError, LimitError, UnsupportedVersionError
from .gltf import SHOWN_LIMIT, document_integers, integer_shape, json_integer, json_kind, shown_value, with_integers
from .layout import DIGEST_SIZE

SCHEMA_DIR = Path(__file__).with_name("schema")
#: Schema of the object on the mesh primitive.
PRIMITIVE_SCHEMA = f"mesh.primitive.{EXTENSION_NAME}.schema.json"
#: Extension fields the writer sets itself; callers must not pass them.
RESERVED_FIELDS = ("version", "chunks")
#: Extension fields the writer derives and drops from the caller's (a copied ``baseMac`` or
#: ``baseDigest`` would not match).
DERIVED_FIELDS = ("baseMac", "baseDigest")
#: Per-chunk fields the caller supplies (``chunk_meta``).
CHUNK_META_FIELDS = ("splits", "vertexCount", "faceCount", "geometricError")
#: Chunk payload codec id and the versions this reader knows (bitstream.md §6 and §8).
PAYLOAD_CODEC = "pmwm-vsplit"
PAYLOAD_VERSIONS = (1, 2)
#: Version written unless the caller asks for another.
DEFAULT_PAYLOAD_VERSION = 2
#: Hex digits of a chunk ``digest`` per payload version: BLAKE2b-128 (v1), its first 64 bits (v2).
DIGEST_HEX = {1: 32, 2: 16}
#: Hex digits of one MAC (BLAKE2b-128, both versions).
MAC_HEX = 32
#: Compact chunk table (payload version 2): its per-chunk arrays and the entry field each one fills.
TABLE_ARRAYS = (("byteLengths", "byteLength"), ("vertexCounts", "vertexCount"), ("faceCounts", "faceCount"),
                ("geometricErrors", "geometricError"))
#: Packed chunk table (bitstream.md §6.2): bit 0 of its first byte says it holds MACs; the other bits are 0.
PACKED_MACS_FLAG = 1
#: Bytes of one digest / one MAC / one geometric error in the packed table; a varint has at most 5 bytes.
PACKED_DIGEST, PACKED_MAC, PACKED_ERROR, VARINT_MAX = 8, 16, 4, 5


def digest(data, version: int = 1) -> str:
    """The chunk ``digest`` of stored bytes ``data`` for payload ``version``: BLAKE2b-128 as 32
    lowercase hex digits (version 1), or its first 16 (version 2)."""
    return hashlib.blake2b(data, digest_size=DIGEST_SIZE).hexdigest()[: DIGEST_HEX[version]]


def framed_blake2b(fields, key: bytes = b"") -> str:
    """BLAKE2b-128 (keyed with ``key``, unkeyed when empty) over ``uint64_le(len(f)) || f`` for
    each bytes-like ``f`` of ``fields`` in turn, as 32 lowercase hex digits (bitstream.md §6.3)."""
    h = hashlib.blake2b(key=key, digest_size=DIGEST_SIZE)
    for data in fields:
        data = memoryview(data).cast("B")
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)
    return h.hexdigest()


def base_mesh_fields(positions_int, faces, attributes_int=None) -> list:
    """The decoded base mesh as the framed fields its ``baseMac`` and ``baseDigest`` cover
    (bitstream.md §6.3): counts ``uint64_le(n) || uint64_le(m) || uint64_le(a)``, then
    positions, faces and attributes as little-endian int64, row-major.

    ``positions_int`` (n, 3) int64 grid coordinates, ``faces`` (m, 3) int64, ``attributes_int``
    (n, a) int64 progressive attributes in the extension's order (None: a = 0).
    """
    positions = np.asarray(positions_int, dtype=np.int64).reshape(-1, 3)
    triangles = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    attributes = np.zeros((len(positions), 0), np.int64) if attributes_int is None else np.asarray(attributes_int, np.int64)
    width = attributes.shape[1] if attributes.ndim == 2 else 0
    counts = np.array([len(positions), len(triangles), width], dtype="<u8").tobytes()
    as_bytes = [np.ascontiguousarray(a, dtype="<i8").tobytes() for a in (positions, triangles)]
    return [counts, *as_bytes, np.ascontiguousarray(attributes.reshape(len(positions), width), dtype="<i8").tobytes()]


#: Label of the ``baseDigest`` input (bitstream.md §6.4).
BASE_DIGEST_LABEL = b"pmwm/base-digest/v1"
#: Hex digits of a ``baseDigest``: the first 64 bits of its BLAKE2b-128, as a version 2 chunk digest.
BASE_DIGEST_HEX = 16


def base_digest(positions_int, faces, attributes_int=None) -> str:
    """The keyless ``baseDigest`` of a decoded base mesh (bitstream.md §6.4): 16 lowercase hex
    digits, the first 64 bits of the unkeyed BLAKE2b-128 of the label and
    :func:`base_mesh_fields`.  Catches accidental damage to the base (a flipped bit inside a
    Draco stream that still decodes); anyone can recompute it, so it proves nothing about who
    wrote the file (that is ``baseMac``'s job)."""
    return framed_blake2b([BASE_DIGEST_LABEL, *base_mesh_fields(positions_int, faces, attributes_int)])[:BASE_DIGEST_HEX]


def chunk_entries(ext: dict, base_vertices: int) -> list:
    """The per-chunk index entries of a checked extension object ``ext``: its ``chunks`` array
    (payload version 1, the same dicts) or its chunk table expanded (version 2), whether the
    table holds JSON arrays or the packed binary form (``count`` + ``packed``).

    An expanded entry holds ``bufferView``, ``byteOffset`` (inside that bufferView),
    ``byteLength``, ``digest``, ``vertexCount``, ``faceCount``, ``geometricError``, ``mac`` when
    the table has MACs, and the derived ``splits`` (vertices added: one per split, the
    first chunk counted from the base's ``base_vertices``), ``uncompressedLength``
    (= ``byteLength``), and ``faces`` True on a face chunk (from ``firstFaceChunk`` on, bitstream.md §8.6;
    ask :func:`is_face_chunk`, as a version 1 entry is the file's own object).
    FormatError when the table's arrays disagree or the packed bytes are malformed.
    """
    table = ext["chunks"]
    first_face = ext.get("firstFaceChunk")  # an integer >= 0 (schema), or absent: no face chunk
    if payload_version(ext) != 2:
        if not isinstance(table, list):
            raise FormatError(f"{EXTENSION_NAME}: chunks must be an array for payload version 1")
        if first_face is not None:
            raise FormatError(f"{EXTENSION_NAME}: firstFaceChunk needs chunk payload version 2")
        return table
    if not isinstance(table, dict):
        raise FormatError(f"{EXTENSION_NAME}: chunks must be a chunk table object for payload version 2")
    columns = unpack_chunk_table(table["count"], table["packed"]) if "packed" in table else _json_columns(table)
    count = len(columns["byteLength"])
    offsets = table.get("byteOffsets")
    if offsets is None:  # back to back from the start of the bufferView
        offsets = [0] * count
        for k in range(1, count):
            offsets[k] = offsets[k - 1] + columns["byteLength"][k - 1]
    if len(offsets) != count or (count and "bufferView" not in table):
        raise FormatError(f"{EXTENSION_NAME}: chunks: the table's arrays do not all describe {count} chunks")
    entries, previous = [], base_vertices
    for k in range(count):
        entry = {"bufferView": table.get("bufferView"), "byteOffset": offsets[k],
                 **{field: columns[field][k] for _, field in TABLE_ARRAYS}, "digest": columns["digest"][k]}
        if "mac" in columns:
            entry["mac"] = columns["mac"][k]
        entry["splits"], previous = entry["vertexCount"] - previous, entry["vertexCount"]
        if entry["splits"] < 0:
            over = next((e for e in entries if max(e["splits"], e["vertexCount"]) > MAX_VERTICES), None)
            if over is not None:  # an earlier chunk's count over the limit: that refusal first (chunk by chunk, as JS)
                raise LimitError(f"{EXTENSION_NAME}: chunks: a chunk's vertexCount {over['vertexCount']} (splits "
                                 f"{over['splits']}) exceeds the limit {MAX_VERTICES}")
            raise FormatError(f"{EXTENSION_NAME}: chunks: vertexCounts[{k}] is smaller than the count before it")
        entry["uncompressedLength"] = entry["byteLength"]
        if first_face is not None and k >= first_face:
            entry["faces"] = True
        entries.append(entry)
    return entries


def is_face_chunk(ext: dict, entry: dict) -> bool:
    """Whether ``entry`` (one of :func:`chunk_entries`' for ``ext``) is a face chunk (bitstream.md §8.6).
    Only payload version 2 has face chunks, marked by :func:`chunk_entries` from ``firstFaceChunk``: a
    member ``faces`` that a version 1 entry carries in the file is one the schema does not know, which
    means nothing (the JavaScript decoder's ``checkChunk`` reads it the same way)."""
    return payload_version(ext) == 2 and entry.get("faces") is True


def _json_columns(table: dict) -> dict:
    """The per-chunk values of a chunk table in JSON-array form, by entry field (lists of length K)."""
    count = len(table["byteLengths"])
    columns = {field: table[name] for name, field in TABLE_ARRAYS}
    digests, macs = table["digests"], table.get("macs")
    if any(len(values) != count for values in columns.values()) or len(digests) != count * DIGEST_HEX[2] or \
            (macs is not None and len(macs) != count * MAC_HEX):
        raise FormatError(f"{EXTENSION_NAME}: chunks: the table's arrays do not all describe {count} chunks")
    columns["digest"] = [digests[k * DIGEST_HEX[2] : (k + 1) * DIGEST_HEX[2]] for k in range(count)]
    if macs is not None:
        columns["mac"] = [macs[k * MAC_HEX : (k + 1) * MAC_HEX] for k in range(count)]
    return columns


def pack_chunk_table(entries) -> dict:
    """``{"count": K, "packed": base64}``: the packed chunk table (bitstream.md §6.2) of per-chunk
    ``entries`` (``byteLength``, ``vertexCount``, ``faceCount``, ``geometricError`` (a float32
    value: :func:`float32_up`), ``digest`` (16 hex digits), ``mac`` on every entry or on none).

    ValueError when a value does not fit (counts decreasing, a length over 32 bits, an error
    that is not a float32) -- the inverse :func:`unpack_chunk_table` must give the same values back.
    """
    entries = list(entries)
    macs = [e["mac"] for e in entries if "mac" in e]
    if macs and len(macs) != len(entries):
        raise ValueError("chunk table: a MAC on some chunks but not on all")
    errors = np.array([e["geometricError"] for e in entries], dtype=np.float64)
    if not np.array_equal(errors.astype(np.float32).astype(np.float64), errors):
        raise ValueError("chunk table: a geometric error is not a float32 value")
    varints = [np.array([e["byteLength"] for e in entries], dtype=np.int64)]
    for field in ("vertexCount", "faceCount"):
        varints.append(np.diff(np.array([e[field] for e in entries], dtype=np.int64), prepend=0))
    varints = np.concatenate(varints)
    if varints.size and (varints.min() < 0 or varints.max() >= 1 << 32):
        raise ValueError("chunk table: counts must not decrease and every value must fit in 32 bits")
    data = b"".join([bytes([PACKED_MACS_FLAG if macs else 0]), bytes.fromhex("".join(e["digest"] for e in entries)),
                     bytes.fromhex("".join(macs)), errors.astype("<f4").tobytes(), _leb128(varints)])
    return {"count": len(entries), "packed": base64.b64encode(data).decode("ascii")}


def _leb128(values: np.ndarray) -> bytes:
    """Unsigned LEB128 of (n,) int64 ``values`` in [0, 2**32): 7 bits a byte, low first, bit 7 = more follow."""
    values = values.astype(np.uint64)
    sizes = 1 + sum((values >> np.uint64(7 * j) > 0).astype(np.int64) for j in range(1, VARINT_MAX))
    out = np.zeros(int(sizes.sum()), np.uint8)
    starts = np.cumsum(sizes) - sizes
    for j in range(VARINT_MAX):
        live = sizes > j
        more = (sizes > j + 1)[live].astype(np.uint8) << 7
        out[starts[live] + j] = ((values[live] >> np.uint64(7 * j)) & np.uint64(0x7F)).astype(np.uint8) | more
    return out.tobytes()


def unpack_chunk_table(count, packed) -> dict:
    """The per-chunk values of a packed chunk table, by entry field: ``byteLength``,
    ``vertexCount``, ``faceCount`` (lists of int), ``geometricError`` (float: the float32
    widened), ``digest`` and ``mac`` (lists of hex strings; ``mac`` only when the table has MACs).

    ``count`` (K) and the base64 text's length are checked before anything is decoded or
    allocated; FormatError (one line) for malformed base64, a wrong length, reserved flag bits,
    a varint over 5 bytes or 32 bits, or a negative or non-finite geometric error.
    """
    def bad(why):
        return FormatError(f"{EXTENSION_NAME}: chunks: packed table: {why}")

    if not isinstance(count, int) or isinstance(count, bool) or not 0 <= count <= MAX_CHUNKS:
        raise bad(f"count must be an integer in [0, {MAX_CHUNKS}]")
    longest = 1 + count * (PACKED_DIGEST + PACKED_MAC + PACKED_ERROR + 3 * VARINT_MAX)
    if not isinstance(packed, str) or len(packed) > 4 * -(-longest // 3):
        raise bad(f"longer than {count} chunks can need")
    try:
        data = np.frombuffer(base64.b64decode(packed, validate=True), np.uint8)
    except (binascii.Error, ValueError):
        raise bad("not valid base64") from None
    if not len(data) or int(data[0]) & ~PACKED_MACS_FLAG:
        raise bad("missing or reserved flag bits")
    fixed = PACKED_DIGEST + PACKED_ERROR + (PACKED_MAC if data[0] else 0)
    at = 1 + count * fixed
    if len(data) < at + 3 * count:
        raise bad(f"{len(data)} bytes are too few for {count} chunks")
    digests = data[1 : 1 + count * PACKED_DIGEST].reshape(count, PACKED_DIGEST)
    columns = {"digest": [bytes(row).hex() for row in digests]}
    if data[0]:
        macs = data[1 + count * PACKED_DIGEST : 1 + count * (PACKED_DIGEST + PACKED_MAC)].reshape(count, PACKED_MAC)
        columns["mac"] = [bytes(row).hex() for row in macs]
    errors = data[at - count * PACKED_ERROR : at].view("<f4").astype(np.float64)
    if not (np.isfinite(errors).all() and (errors >= 0).all()):
        raise bad("a geometric error is negative or not finite")
    varints = _read_leb128(data[at:], 3 * count, bad)
    columns["byteLength"] = varints[:count].tolist()
    columns["vertexCount"] = np.cumsum(varints[count : 2 * count]).tolist()
    columns["faceCount"] = np.cumsum(varints[2 * count :]).tolist()
    columns["geometricError"] = errors.tolist()
    if count and min(columns["byteLength"]) < 1:
        raise bad("a chunk has byteLength 0")
    return columns


def _read_leb128(data: np.ndarray, n: int, bad) -> np.ndarray:
    """Exactly ``n`` unsigned LEB128 values filling uint8 ``data`` (m,), as (n,) int64; ``bad(why)`` the error."""
    ends = np.flatnonzero(data < 0x80)
    if len(ends) != n or (n and ends[-1] != len(data) - 1) or (not n and len(data)):
        raise bad(f"the varints are not exactly {n} values")
    sizes = np.diff(ends, prepend=-1)
    if n and sizes.max() > VARINT_MAX:
        raise bad(f"a varint longer than {VARINT_MAX} bytes")
    values = np.zeros(n, np.int64)
    starts = ends - sizes + 1
    for j in range(VARINT_MAX):
        live = sizes > j
        values[live] |= (data[starts[live] + j].astype(np.int64) & 0x7F) << (7 * j)
    if n and values.max() >= 1 << 32:
        raise bad("a varint over 32 bits")
    return values


def float32_up(value: float) -> float:
    """The smallest float32 value >= ``value`` (a finite, non-negative geometric error), as a
    float: stored in a packed chunk table it stays an upper bound and reads back exactly."""
    low = np.float32(value)
    if float(low) < value:
        low = np.nextafter(low, np.float32(np.inf))
    return float(low)


def chunk_start(views: list, entry: dict) -> int:
    """BIN offset of the first byte of a chunk, from its entry (:func:`chunk_entries`) and the
    document's ``bufferViews`` (already checked)."""
    return int(views[entry["bufferView"]].get("byteOffset", 0)) + int(entry.get("byteOffset", 0))


def payload_version(ext: dict) -> int:
    """The chunk payload version of an extension object (1 when it names none).  The one place readers
    dispatch on it.  A ``payload`` that is not an object with a string ``codec`` and an integer ``version``
    is a FormatError; a well-formed one this reader does not know (another codec, version 3) is an
    :class:`UnsupportedVersionError`, as a newer extension ``version`` is (spec README, *Properties*)."""
    payload = ext.get("payload", {"codec": PAYLOAD_CODEC, "version": 1})
    version = json_integer(payload.get("version")) if isinstance(payload, dict) else None
    if version is None or not isinstance(payload.get("codec"), str):
        raise FormatError(f"{EXTENSION_NAME}: payload must be an object with a string codec and an integer version, "
                          f"got {shown_value(payload)}")
    if payload["codec"] != PAYLOAD_CODEC or version not in PAYLOAD_VERSIONS:
        raise UnsupportedVersionError(
            f"{EXTENSION_NAME}: chunk payload {shown_value(payload['codec'])} version {shown_value(version)} is not "
            f"supported (this reader knows {PAYLOAD_CODEC} versions {', '.join(map(str, PAYLOAD_VERSIONS))})")
    return version


def chunk_count(ext: dict):
    """The number of chunks an extension object declares (its ``chunks`` array's length, a packed table's
    ``count``, an array table's ``byteLengths`` length), or None when it has no such number."""
    chunks = ext.get("chunks")
    if isinstance(chunks, list):
        return len(chunks)
    if isinstance(chunks, dict):
        count = json_integer(chunks.get("count"))
        return count if count is not None else len(chunks["byteLengths"]) if isinstance(chunks.get("byteLengths"), list) else None
    return None


@functools.lru_cache(maxsize=None)
def _schemas() -> dict:
    """The extension's JSON schemas by file name (``$id``)."""
    return {p.name: json.loads(p.read_text()) for p in SCHEMA_DIR.glob("*.schema.json")}


@functools.lru_cache(maxsize=None)
def _document_integers() -> dict:
    """Where a ``.pmw`` document holds integers: glTF's integer members and the extension's, as its schemas type them."""
    return integer_shape(document_integers({EXTENSION_NAME: {"$ref": PRIMITIVE_SCHEMA}}), _schemas())


def integer_members(gltf: dict) -> dict:
    """A parsed ``.pmw`` document (in place) with every member glTF 2.0 or the extension's schemas type
    ``integer`` that holds an integral float made an ``int`` (``16.0`` -> ``16``: one value in JSON;
    spec README, *JSON numbers*), so every reader of the document sees ints; returns it.  Members typed
    ``number`` keep their floats (``0.0`` stays ``0.0``: the MACs' canonical JSON writes it so)."""
    return with_integers(gltf, _document_integers())


@functools.lru_cache(maxsize=None)
def _validator():
    import jsonschema
    from referencing import Registry, Resource

    schemas = _schemas()
    registry = Registry().with_resources((name, Resource.from_contents(s)) for name, s in schemas.items())
    schema = schemas[PRIMITIVE_SCHEMA]
    cls = jsonschema.validators.validator_for(schema)
    return cls(schema, registry=registry)


def _schema_message(error) -> str:
    """A schema error's message on one line of at most 160 characters that keeps its reason: jsonschema
    starts many messages with the offending value itself (``{...} is not of type 'array'``), which for
    a chunk table or a long string would fill the line before the reason; such a value is named by
    its JSON kind instead."""
    message = error.message.replace("\n", " ")
    text = repr(error.instance)
    if len(text) > SHOWN_LIMIT and message.startswith(text):
        message = f"the value ({json_kind(error.instance)})" + message[len(text):]
    return message if len(message) <= 160 else message[:157] + "..."


def check_extension(ext) -> dict:
    """Check an extension object; return it unchanged.

    Raises
    ------
    UnsupportedVersionError
        ``version`` is an integer newer than :data:`FORMAT_VERSION`, or the ``payload`` one this reader
        does not know (:func:`payload_version`).
    LimitError
        More chunks than :data:`~pmwm_codec.constants.MAX_CHUNKS`.
    FormatError
        Not an object, or the schema rejects it (message names the JSON path).
    """
    if not isinstance(ext, dict):
        raise FormatError(f"{EXTENSION_NAME}: extension must be a JSON object")
    version = json_integer(ext.get("version"))
    if version is not None and version > FORMAT_VERSION:
        raise UnsupportedVersionError(
            f"{EXTENSION_NAME}: version {shown_value(version)} is newer than this reader (version {FORMAT_VERSION})"
        )
    payload_version(ext)  # an unknown payload is named as such, before the schema finds its chunks of another form
    count = chunk_count(ext)
    if count is not None and count > MAX_CHUNKS:  # a limit of spec README, Limits (the schema repeats it)
        raise LimitError(f"{EXTENSION_NAME}: chunks: {shown_value(count)} exceeds the limit of {MAX_CHUNKS} chunks")
    import jsonschema

    # best_match descends into anyOf (chunks: an array of entries, or the version 2 table)
    error = jsonschema.exceptions.best_match(sorted(_validator().iter_errors(ext), key=lambda e: list(e.absolute_path)))
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path) or "(root)"
        raise FormatError(f"{EXTENSION_NAME}: {where}: {_schema_message(error)}")
    if version != FORMAT_VERSION:
        raise UnsupportedVersionError(f"{EXTENSION_NAME}: version {version} is not supported (this reader knows {FORMAT_VERSION})")
    if payload_version(ext) != 2 and any("prediction" in a for a in ext.get("attributes", ())):
        raise FormatError(f"{EXTENSION_NAME}: an attribute's prediction with chunk payload version {payload_version(ext)} "
                          "(version 2 only)")
    return ext
