"""Chunk payload: a run of :class:`~pmwm_codec.progressive.vsplit.SplitBatch` <-> bytes.

This is the raw (uncompressed) payload of one chunk; the container wraps it in
its own zstd frame and digest.  Layout (all little-endian; the structs live in
:mod:`.layout`, spec/bitstream.md §6 mirrors them and tests/test_spec_sync.py
compares the two)::

    RecordsHeader       batch_count : uint32
    BatchTable          batch_count x BatchEntry (split_count : uint32, incidence_count : uint32)
    Column "gaps"       split vertex gaps, sum(split_count) values
    Column "symbols"    incidence symbols, three per value (base 5), ceil(sum(incidence_count) / 3) values
    Column "residual_x" \\
    Column "residual_y"  > zigzag-coded position residuals, sum(split_count) values each
    Column "residual_z" /
    Column "attribute_0" ... one more zigzag residual column per attribute component
                         (D - 3 of them, D given by the caller / the extension JSON)

The column order is :func:`column_names` (``COLUMNS`` then ``attribute_{j}``), the one
list :func:`pack_batches`, :func:`unpack_batches` and the spec sync test use.

A column is a ``ColumnHeader`` (``width : uint8``, 1, 2, 4 or 8 bytes per value, the
smallest that holds the largest value) followed by the values split into byte planes
(all low bytes, then the next byte of every value, ...), which lets zstd see the
mostly-zero high bytes as long runs.  An empty column is its header alone, width 1.
Gaps are ``v[0]`` then ``v[i] - v[i-1] - 1`` per batch (v strictly increasing).
Symbols ``s0, s1, s2`` are packed as ``s0 + 5*s1 + 25*s2`` (zero-padded at the
end), so zstd's byte-wise Huffman stage sees 125 joint symbols and gets closer
to their entropy than with one byte per symbol.
"""

from __future__ import annotations

import numpy as np

from ..constants import MAX_VERTICES
from ..errors import FormatError, LimitError
from ..progressive.vsplit import SYMBOL_COUNT, SplitBatch
from .layout import BatchEntry, ColumnHeader, RecordsHeader

#: One row of the batch table, as a numpy dtype mirroring :data:`layout.BatchEntry`
#: (every field a little-endian uint32).
BATCH_TABLE_DTYPE = np.dtype([(sub.name, "<u4") for sub in BatchEntry.subcons])
assert BATCH_TABLE_DTYPE.itemsize == BatchEntry.sizeof()
#: The columns every payload has, in byte order.
COLUMNS = ("gaps", "symbols", "residual_x", "residual_y", "residual_z")
#: Name of the attribute residual column j (they follow the COLUMNS, j = 0 .. D - 4).
ATTRIBUTE_COLUMN = "attribute_{}"
#: Number of position residual columns (the first three residual columns).
POSITION_COMPONENTS = 3
MAX_BATCHES_PER_CHUNK = 4096
#: Largest zigzag residual a valid file can hold.  Positions and attribute values, and hence
#: their predictions (floored ring means), lie on grids of at most ``MAX_GRID_BITS`` (30) bits,
#: so ``|residual| < 2**30``; refused above ``|r| <= 2**31`` (``z <= 2**32``) before any
#: arithmetic.  With at most ``MAX_CHUNKS * MAX_BATCHES_PER_CHUNK = 2**28`` batches, each moving
#: a value by at most ``2**31`` from the range of the values before it, a hostile file's int64
#: values stay below ``2**30 + 2**59 < 2**63``: they never wrap.
#:
#: Float64 exactness (``vsplit.SplitTopology.prediction`` rounds a float64 ring sum with
#: ``np.rint``): on a valid file every summed value is < ``2**30``, and a ring of a vertex with
#: ``c`` faces sums ``2c`` of them, so the sum is exact (< ``2**53``) while ``c < 2**22``.  On a
#: hostile file whose values have left the grid the sums may be inexact; the decoded mesh is then
#: wrong (the file is invalid anyway) but no integer array overflows.
MAX_RESIDUAL_ZIGZAG = 1 << 32
_WIDTHS = (1, 2, 4, 8)
#: Byte sizes of the fixed structs, computed once (construct's sizeof/parse cost ~10 us a call).
_COLUMN_HEADER_SIZE = ColumnHeader.sizeof()
_RECORDS_HEADER_SIZE = RecordsHeader.sizeof()
# the column header is its width byte alone: the decoder reads that byte directly
assert _COLUMN_HEADER_SIZE == 1 and ColumnHeader.parse(b"\x08").width == 8


def column_names(width: int = 3) -> tuple:
    """Names of a payload's columns in byte order, for ``D = width`` residual components (D >= 3)."""
    return COLUMNS + tuple(ATTRIBUTE_COLUMN.format(j) for j in range(width - POSITION_COMPONENTS))


def zigzag(x: np.ndarray) -> np.ndarray:
    """int64 -> uint64 mapping 0, -1, 1, -2, ... to 0, 1, 2, 3, ... (any shape)."""
    x = np.asarray(x, np.int64)
    return ((x << 1) ^ (x >> 63)).view(np.uint64)


def unzigzag(z: np.ndarray) -> np.ndarray:
    """uint64 -> int64, the inverse of :func:`zigzag` (any shape)."""
    z = np.asarray(z, np.uint64)
    return ((z >> np.uint64(1)).view(np.int64)) ^ -((z & np.uint64(1)).view(np.int64))


def _pack_column(values: np.ndarray) -> bytes:
    """(k,) non-negative integers < 2**64 -> ``ColumnHeader`` + ``width`` byte planes of k bytes."""
    values = np.asarray(values, np.uint64)
    top = int(values.max()) if len(values) else 0
    width = next(w for w in _WIDTHS if top < (1 << (8 * w)))
    le = values.astype(f"<u{width}").view(np.uint8).reshape(-1, width)
    return ColumnHeader.build({"width": width}) + np.ascontiguousarray(le.T).tobytes()


def _unpack_column(buf: memoryview, offset: int, count: int, name: str):
    """Inverse of :func:`_pack_column`: returns ``(values (count,) uint64, offset after the column)``."""
    start = offset + _COLUMN_HEADER_SIZE
    if start > len(buf):
        raise FormatError(f"chunk payload: column {name} is missing")
    width = buf[offset]
    if width not in _WIDTHS:
        raise FormatError(f"chunk payload: column {name} has invalid width {width}")
    end = start + width * count
    if end > len(buf):
        raise FormatError(f"chunk payload: column {name} is cut short")
    planes = np.frombuffer(buf, dtype=np.uint8, count=width * count, offset=start).reshape(width, count)
    values = np.ascontiguousarray(planes.T).view(f"<u{width}").reshape(count).astype(np.uint64)
    return values, end


def _pack_symbols(symbols: np.ndarray) -> np.ndarray:
    """(I,) symbols < 5 -> (ceil(I/3),) uint8, three per value: ``s0 + 5*s1 + 25*s2``."""
    pad = np.zeros(-(-len(symbols) // 3) * 3, dtype=np.uint8)
    pad[: len(symbols)] = symbols
    t = pad.reshape(-1, 3).astype(np.uint16)
    return (t[:, 0] + SYMBOL_COUNT * t[:, 1] + SYMBOL_COUNT**2 * t[:, 2]).astype(np.uint8)


#: (256, 3) uint8: packed byte -> its three symbols (rows >= 125 are never looked up).
_SYMBOL_TRIPLES = np.stack(
    [np.arange(256) % SYMBOL_COUNT, (np.arange(256) // SYMBOL_COUNT) % SYMBOL_COUNT, np.arange(256) // SYMBOL_COUNT**2],
    axis=1,
).astype(np.uint8)


def _unpack_symbols(packed: np.ndarray, count: int) -> np.ndarray:
    """(ceil(count/3),) packed values < 125 -> (count,) uint8 symbols < 5 (one table gather)."""
    return _SYMBOL_TRIPLES[packed.astype(np.uint8)].reshape(-1)[:count]


def pack_batches(batches) -> bytes:
    """Serialise a list of :class:`SplitBatch` (one chunk) to raw payload bytes.

    Each batch: ``v`` (k,) strictly increasing non-negative ints, ``symbols`` (I,) ints < 5,
    ``residual`` (k, D) int64, the same ``D >= 3`` for every batch.
    """
    table = np.array([(b.size, len(b.symbols)) for b in batches], dtype=BATCH_TABLE_DTYPE)
    residual = np.concatenate([b.residual for b in batches]).astype(np.int64)
    names = column_names(residual.shape[1])
    values = {
        "gaps": np.concatenate([np.diff(b.v, prepend=-1) - 1 for b in batches]),
        "symbols": _pack_symbols(np.concatenate([b.symbols for b in batches]).astype(np.uint8)),
    }
    values.update(zip(names[2:], zigzag(residual).T))
    parts = [RecordsHeader.build({"batch_count": len(batches)}), table.tobytes()]
    parts += [_pack_column(values[name]) for name in names]
    return b"".join(parts)


def _read_batch_table(buf: memoryview, max_splits: int):
    """Records header and batch table -> ``(split counts (B,) int64, incidence counts (B,) int64, offset)``."""
    off = _RECORDS_HEADER_SIZE
    if len(buf) < off:
        raise FormatError("chunk payload: shorter than its header")
    batch_count = RecordsHeader.parse(bytes(buf[:off])).batch_count
    if batch_count == 0 or batch_count > MAX_BATCHES_PER_CHUNK:
        raise LimitError(f"chunk payload: batch count {batch_count} outside 1..{MAX_BATCHES_PER_CHUNK}")
    table_bytes = batch_count * BATCH_TABLE_DTYPE.itemsize
    if off + table_bytes > len(buf):
        raise FormatError("chunk payload: batch table is cut short")
    table = np.frombuffer(buf, dtype=BATCH_TABLE_DTYPE, count=batch_count, offset=off)
    splits = table["split_count"].astype(np.int64)
    incs = table["incidence_count"].astype(np.int64)
    if np.any(splits == 0):
        raise LimitError(f"chunk payload: batch {int(np.argmin(splits))} has no splits")
    if int(splits.sum()) > max_splits:
        raise LimitError(f"chunk payload: {int(splits.sum())} splits, more than the limit {max_splits}")
    # No bound on incidences per split: a split vertex of valence c has c incidences, and valence is
    # not limited.  Each incidence is a distinct corner of the mesh before the batch (the decoder
    # checks the exact count against the mesh), and the size check in unpack_batches bounds
    # sum(incidence_count) by 3 bytes of symbols per payload byte before anything is allocated.
    return splits, incs, off + table_bytes


def _read_columns(buf: memoryview, off: int, names, k_total: int, i_total: int) -> dict:
    """Every column in ``names`` -> ``{name: (count,) uint64}``; the payload must end after the last."""
    columns = {}
    for name in names:
        count = -(-i_total // 3) if name == "symbols" else k_total
        columns[name], off = _unpack_column(buf, off, count, name)
    if off != len(buf):
        raise FormatError(f"chunk payload: {len(buf) - off} trailing bytes")
    return columns


def unpack_batches(payload: bytes, *, max_splits: int = MAX_VERTICES, width: int = 3) -> list:
    """Parse raw payload bytes back into a list of :class:`SplitBatch`.

    ``width`` is ``D``, the number of residual columns (3 + attribute components).  Returns one
    batch per batch-table row: ``v`` (k,) int64, ``symbols`` (I,) uint8, ``residual`` (k, D) int64.

    Counts are checked against ``max_splits`` and the payload length before any
    array is allocated.  Raises :class:`FormatError` / :class:`LimitError`.
    """
    buf = memoryview(payload)
    splits, incs, off = _read_batch_table(buf, max_splits)
    k_total, i_total = int(splits.sum()), int(incs.sum())
    names = column_names(width)
    # every value takes at least one byte: a cheap bound before allocating
    if k_total * (len(names) - 1) + -(-i_total // 3) > len(buf):
        raise FormatError("chunk payload: declared counts exceed the payload size")
    cols = _read_columns(buf, off, names, k_total, i_total)
    if len(cols["symbols"]) and int(cols["symbols"].max()) >= SYMBOL_COUNT**3:
        raise FormatError("chunk payload: unknown incidence symbol")
    if k_total and int(cols["gaps"].max()) > MAX_VERTICES:
        raise FormatError("chunk payload: split vertex gap out of range")
    for name in names[2:]:
        if k_total and int(cols[name].max()) > MAX_RESIDUAL_ZIGZAG:
            raise FormatError(f"chunk payload: {name} out of range")
    symbols = _unpack_symbols(cols["symbols"], i_total)
    residual = np.stack([unzigzag(cols[name]) for name in names[2:]], axis=1)
    gaps = cols["gaps"].astype(np.int64)

    out = []
    k_starts = np.cumsum(splits) - splits
    i_starts = np.cumsum(incs) - incs
    for k0, k, i0, ni in zip(k_starts.tolist(), splits.tolist(), i_starts.tolist(), incs.tolist()):
        v = np.cumsum(gaps[k0 : k0 + k] + 1) - 1
        out.append(SplitBatch(v, symbols[i0 : i0 + ni], residual[k0 : k0 + k]))
    return out
