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

import functools
import hashlib
import json
from pathlib import Path

from ..constants import EXTENSION_NAME, FORMAT_VERSION
from ..errors import FormatError, UnsupportedVersionError
from .layout import DIGEST_SIZE

SCHEMA_DIR = Path(__file__).with_name("schema")
#: Schema of the object on the mesh primitive.
PRIMITIVE_SCHEMA = f"mesh.primitive.{EXTENSION_NAME}.schema.json"
#: Extension fields the writer sets itself; callers must not pass them.
RESERVED_FIELDS = ("version", "chunks")
#: Extension fields the writer derives and drops from the caller's (a copied ``baseMac`` would not match).
DERIVED_FIELDS = ("baseMac",)
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


def digest(data, version: int = 1) -> str:
    """The chunk ``digest`` of stored bytes ``data`` for payload ``version``: BLAKE2b-128 as 32
    lowercase hex digits (version 1), or its first 16 (version 2)."""
    return hashlib.blake2b(data, digest_size=DIGEST_SIZE).hexdigest()[: DIGEST_HEX[version]]


def chunk_entries(ext: dict, base_vertices: int) -> list:
    """The per-chunk index entries of a checked extension object ``ext``: its ``chunks`` array
    (payload version 1, the same dicts) or its compact table expanded (version 2).

    An expanded entry holds ``bufferView``, ``byteOffset`` (inside that bufferView),
    ``byteLength``, ``digest``, ``vertexCount``, ``faceCount``, ``geometricError``, ``mac`` when
    the table has ``macs``, and the derived ``splits`` (vertices added: one per split, the
    first chunk counted from the base's ``base_vertices``) and ``uncompressedLength``
    (= ``byteLength``).  FormatError when the table's arrays disagree.
    """
    table = ext["chunks"]
    if payload_version(ext) != 2:
        if not isinstance(table, list):
            raise FormatError(f"{EXTENSION_NAME}: chunks must be an array for payload version 1")
        return table
    if not isinstance(table, dict):
        raise FormatError(f"{EXTENSION_NAME}: chunks must be a chunk table object for payload version 2")
    count = len(table["byteLengths"])
    columns = [(field, table[name]) for name, field in TABLE_ARRAYS]
    digests, macs = table["digests"], table.get("macs")
    offsets = table.get("byteOffsets")
    if offsets is None:  # back to back from the start of the bufferView
        offsets = [0] * count
        for k in range(1, count):
            offsets[k] = offsets[k - 1] + table["byteLengths"][k - 1]
    if any(len(values) != count for _, values in columns) or len(offsets) != count or \
            len(digests) != count * DIGEST_HEX[2] or (macs is not None and len(macs) != count * MAC_HEX) or \
            (count and "bufferView" not in table):
        raise FormatError(f"{EXTENSION_NAME}: chunks: the table's arrays do not all describe {count} chunks")
    entries, previous = [], base_vertices
    for k in range(count):
        entry = {"bufferView": table.get("bufferView"), "byteOffset": offsets[k], **{f: v[k] for f, v in columns},
                 "digest": digests[k * DIGEST_HEX[2] : (k + 1) * DIGEST_HEX[2]]}
        if macs is not None:
            entry["mac"] = macs[k * MAC_HEX : (k + 1) * MAC_HEX]
        entry["splits"], previous = entry["vertexCount"] - previous, entry["vertexCount"]
        if entry["splits"] < 0:
            raise FormatError(f"{EXTENSION_NAME}: chunks: vertexCounts[{k}] is smaller than the count before it")
        entry["uncompressedLength"] = entry["byteLength"]
        entries.append(entry)
    return entries


def chunk_start(views: list, entry: dict) -> int:
    """BIN offset of the first byte of a chunk, from its entry (:func:`chunk_entries`) and the
    document's ``bufferViews`` (already checked)."""
    return int(views[entry["bufferView"]].get("byteOffset", 0)) + int(entry.get("byteOffset", 0))


def payload_version(ext: dict) -> int:
    """The chunk payload version of an extension object (1 when it names none); FormatError for
    a codec or version this reader does not know.  The one place readers dispatch on it."""
    payload = ext.get("payload", {"codec": PAYLOAD_CODEC, "version": 1})
    if not isinstance(payload, dict) or payload.get("codec") != PAYLOAD_CODEC or payload.get("version") not in PAYLOAD_VERSIONS \
            or isinstance(payload.get("version"), bool):
        raise FormatError(f"unknown chunk payload codec {str(payload)[:60]}")
    return payload["version"]


@functools.lru_cache(maxsize=None)
def _validator():
    import jsonschema
    from referencing import Registry, Resource

    schemas = {p.name: json.loads(p.read_text()) for p in SCHEMA_DIR.glob("*.schema.json")}
    registry = Registry().with_resources((name, Resource.from_contents(s)) for name, s in schemas.items())
    schema = schemas[PRIMITIVE_SCHEMA]
    cls = jsonschema.validators.validator_for(schema)
    return cls(schema, registry=registry)


def check_extension(ext) -> dict:
    """Check an extension object; return it unchanged.

    Raises
    ------
    UnsupportedVersionError
        ``version`` is an integer newer than :data:`FORMAT_VERSION`.
    FormatError
        Not an object, or the schema rejects it (message names the JSON path).
    """
    if not isinstance(ext, dict):
        raise FormatError(f"{EXTENSION_NAME}: extension must be a JSON object")
    version = ext.get("version")
    if isinstance(version, int) and not isinstance(version, bool) and version > FORMAT_VERSION:
        raise UnsupportedVersionError(
            f"{EXTENSION_NAME}: version {version} is newer than this reader (version {FORMAT_VERSION})"
        )
    import jsonschema

    # best_match descends into anyOf (chunks: an array of entries, or the version 2 table)
    error = jsonschema.exceptions.best_match(sorted(_validator().iter_errors(ext), key=lambda e: list(e.absolute_path)))
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path) or "(root)"
        message = error.message.replace("\n", " ")
        if len(message) > 160:
            message = message[:157] + "..."
        raise FormatError(f"{EXTENSION_NAME}: {where}: {message}")
    if version != FORMAT_VERSION:
        raise UnsupportedVersionError(f"{EXTENSION_NAME}: version {version} is not supported (this reader knows {FORMAT_VERSION})")
    return ext
