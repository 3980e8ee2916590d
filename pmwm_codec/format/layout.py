"""Byte layout of the ``.pmw`` container: the only place byte offsets and magics live.

A ``.pmw`` file is a GLB (glTF 2.0 binary container, glTF spec §4.4):

    GlbHeader                         12 bytes
    ChunkHeader (type = 'JSON')        8 bytes
    JSON text, space-padded to 4
    ChunkHeader (type = 'BIN\\0')       8 bytes
    BIN payload, zero-padded to 4:    [base mesh bufferViews | other bufferViews | chunk 0 | chunk 1 | ...]

Every vertex-split chunk inside the BIN payload is one self-contained zstd frame
(RFC 8878) with the content size and the content checksum present.

The construct ``Struct`` field names below are the names used in the tables of
``spec/bitstream.md``; ``tests/test_spec_sync.py`` keeps them identical.
All integers are little-endian.
"""

from __future__ import annotations

from construct import Bytes, Const, Int8ul, Int32ul, Struct

#: GLB magic, the ASCII bytes ``glTF``.
GLB_MAGIC = b"glTF"
#: GLB container version this package reads and writes.
GLB_VERSION = 2
#: GLB chunk types.
CHUNK_TYPE_JSON = b"JSON"
CHUNK_TYPE_BIN = b"BIN\x00"
#: Every GLB chunk, every bufferView we write, starts on this alignment.
ALIGNMENT = 4
#: Magic number that opens every zstd frame (RFC 8878 §3.1.1), as stored.
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"
#: Bytes of the BLAKE2b digest stored per chunk (hex in the JSON: twice as many characters).
DIGEST_SIZE = 16

GlbHeader = Struct(
    "magic" / Const(GLB_MAGIC),
    "version" / Int32ul,
    "length" / Int32ul,
)
"""GLB file header: magic, container version (2), total file length in bytes."""

ChunkHeader = Struct(
    "length" / Int32ul,
    "type" / Bytes(4),
)
"""GLB chunk header: payload length in bytes (a multiple of 4), chunk type."""

GLB_HEADER_SIZE = GlbHeader.sizeof()  # 12
CHUNK_HEADER_SIZE = ChunkHeader.sizeof()  # 8
#: A reader knows the JSON length after this many bytes (header + JSON chunk header).
PREAMBLE_SIZE = GLB_HEADER_SIZE + CHUNK_HEADER_SIZE  # 20

# --- chunk payload (the decompressed content of one chunk; see format/records.py) -------

RecordsHeader = Struct(
    "batch_count" / Int32ul,
)
"""Chunk payload header: number of split batches in the chunk."""

BatchEntry = Struct(
    "split_count" / Int32ul,
    "incidence_count" / Int32ul,
)
"""One row of the batch table that follows the records header (``batch_count`` rows)."""

ColumnHeader = Struct(
    "width" / Int8ul,
)
"""Opens every payload column: bytes per value (1, 2, 4 or 8); byte planes follow."""

#: Every Struct the spec documents, by the name its table is tagged with.
STRUCTS = {
    "GlbHeader": GlbHeader,
    "ChunkHeader": ChunkHeader,
    "RecordsHeader": RecordsHeader,
    "BatchEntry": BatchEntry,
    "ColumnHeader": ColumnHeader,
}


def padded(length: int, alignment: int = ALIGNMENT) -> int:
    """Smallest multiple of ``alignment`` that is >= ``length``."""
    return (length + alignment - 1) // alignment * alignment
