"""Chunk payload: a run of :class:`~pmwm_codec.progressive.vsplit.SplitBatch` <-> bytes.

This is the raw (uncompressed) payload of one chunk; the container wraps it in
its own zstd frame and digest.  Layout (all little-endian; the structs live in
:mod:`.layout`, spec/bitstream.md §6 mirrors them and a test compares the two)::

    RecordsHeader       batch_count : uint32
    BatchTable          batch_count x (split_count : uint32, incidence_count : uint32)
    Column "gaps"       split vertex gaps, sum(split_count) values
    Column "symbols"    incidence symbols, three per value (base 5), ceil(sum(incidence_count) / 3) values
    Column "residual_x" \\
    Column "residual_y"  > zigzag-coded position residuals, sum(split_count) values each
    Column "residual_z" /
    Column "attribute_0" ... one more residual column per attribute component
                         (D - 3 of them, D given by the caller / the extension JSON)

A column is a ``ColumnHeader`` (``width : uint8``, 1, 2, 4 or 8 bytes per value) followed by the
values split into byte planes (all low bytes, then the next byte of every
value, ...), which lets zstd see the mostly-zero high bytes as long runs.
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

#: One row of the batch table, as a numpy dtype mirroring :data:`layout.BatchEntry`.
BATCH_TABLE_DTYPE = np.dtype([(sub.name, "<u4") for sub in BatchEntry.subcons])
COLUMNS = ("gaps", "symbols", "residual_x", "residual_y", "residual_z")
#: Name of the attribute residual column j (after the COLUMNS).
ATTRIBUTE_COLUMN = "attribute_{}"
MAX_BATCHES_PER_CHUNK = 4096
#: Largest position residual magnitude a valid file can hold: positions and predictions both lie on
#: a grid of at most ``MAX_GRID_BITS`` (30) bits, so ``|residual| < 2**30``.  Checked on the
#: zigzag value (``|r| <= 2**31`` <=> ``z <= 2**32``) before any arithmetic, so hostile
#: residuals cannot overflow the int64 positions or the float64 ring sums downstream.
MAX_RESIDUAL_ZIGZAG = 1 << 32
_WIDTHS = (1, 2, 4, 8)


def zigzag(x: np.ndarray) -> np.ndarray:
    """int64 -> uint64 mapping 0, -1, 1, -2, ... to 0, 1, 2, 3, ..."""
    x = np.asarray(x, np.int64)
    return ((x << 1) ^ (x >> 63)).view(np.uint64)


def unzigzag(z: np.ndarray) -> np.ndarray:
    z = np.asarray(z, np.uint64)
    return ((z >> np.uint64(1)).view(np.int64)) ^ -((z & np.uint64(1)).view(np.int64))


def _pack_column(values: np.ndarray) -> bytes:
    """(k,) non-negative integers -> width byte + byte planes."""
    values = np.asarray(values, np.uint64)
    top = int(values.max()) if len(values) else 0
    width = next(w for w in _WIDTHS if top < (1 << (8 * w)))
    le = values.astype(f"<u{width}").view(np.uint8).reshape(-1, width)
    return ColumnHeader.build({"width": width}) + np.ascontiguousarray(le.T).tobytes()


def _unpack_column(buf: memoryview, offset: int, count: int, name: str):
    """Inverse of :func:`_pack_column`: returns ``(values (count,) uint64, new offset)``."""
    if offset >= len(buf):
        raise FormatError(f"chunk payload: column {name} is missing")
    width = buf[offset]
    if width not in _WIDTHS:
        raise FormatError(f"chunk payload: column {name} has invalid width {width}")
    end = offset + 1 + width * count
    if end > len(buf):
        raise FormatError(f"chunk payload: column {name} is cut short")
    planes = np.frombuffer(buf, dtype=np.uint8, count=width * count, offset=offset + 1).reshape(width, count)
    values = np.ascontiguousarray(planes.T).view(f"<u{width}").reshape(count).astype(np.uint64)
    return values, end


def _pack_symbols(symbols: np.ndarray) -> np.ndarray:
    """(I,) symbols < 5 -> (ceil(I/3),) uint8, three per value."""
    pad = np.zeros(-(-len(symbols) // 3) * 3, dtype=np.uint8)
    pad[: len(symbols)] = symbols
    t = pad.reshape(-1, 3).astype(np.uint16)
    return (t[:, 0] + SYMBOL_COUNT * t[:, 1] + SYMBOL_COUNT**2 * t[:, 2]).astype(np.uint8)


def _unpack_symbols(packed: np.ndarray, count: int) -> np.ndarray:
    p = packed.astype(np.int64)
    t = np.stack([p % SYMBOL_COUNT, (p // SYMBOL_COUNT) % SYMBOL_COUNT, p // SYMBOL_COUNT**2], axis=1)
    return t.reshape(-1)[:count].astype(np.uint8)


def pack_batches(batches) -> bytes:
    """Serialise a list of :class:`SplitBatch` (one chunk) to raw payload bytes."""
    table = np.array([(b.size, len(b.symbols)) for b in batches], dtype=BATCH_TABLE_DTYPE)
    gaps = np.concatenate([np.diff(b.v, prepend=-1) - 1 for b in batches])
    symbols = np.concatenate([b.symbols for b in batches]).astype(np.uint8)
    residual = np.concatenate([b.residual for b in batches]).astype(np.int64)
    parts = [RecordsHeader.build({"batch_count": len(batches)}), table.tobytes()]
    parts.append(_pack_column(gaps))
    parts.append(_pack_column(_pack_symbols(symbols)))
    for axis in range(residual.shape[1]):
        parts.append(_pack_column(zigzag(residual[:, axis])))
    return b"".join(parts)


def unpack_batches(payload: bytes, *, max_splits: int = MAX_VERTICES, width: int = 3) -> list:
    """Parse raw payload bytes back into a list of :class:`SplitBatch`.

    ``width`` is ``D``, the number of residual columns (3 + attribute components).

    Counts are checked against ``max_splits`` and the payload length before any
    array is allocated.  Raises :class:`FormatError` / :class:`LimitError`.
    """
    buf = memoryview(payload)
    if len(buf) < RecordsHeader.sizeof():
        raise FormatError("chunk payload: shorter than its header")
    batch_count = RecordsHeader.parse(bytes(buf[:4])).batch_count
    if batch_count == 0 or batch_count > MAX_BATCHES_PER_CHUNK:
        raise LimitError(f"chunk payload: batch count {batch_count} outside 1..{MAX_BATCHES_PER_CHUNK}")
    off = 4
    table_bytes = batch_count * BATCH_TABLE_DTYPE.itemsize
    if off + table_bytes > len(buf):
        raise FormatError("chunk payload: batch table is cut short")
    table = np.frombuffer(buf, dtype=BATCH_TABLE_DTYPE, count=batch_count, offset=off)
    off += table_bytes
    splits = table["split_count"].astype(np.int64)
    incs = table["incidence_count"].astype(np.int64)
    k_total, i_total = int(splits.sum()), int(incs.sum())
    if np.any(splits == 0) or k_total > max_splits or i_total > 64 * max(k_total, 1):
        raise LimitError("chunk payload: split or incidence counts out of bounds")
    # every value takes at least one byte: a cheap bound before allocating
    if k_total * (1 + width) + -(-i_total // 3) > len(buf):
        raise FormatError("chunk payload: declared counts exceed the payload size")

    gaps, off = _unpack_column(buf, off, k_total, "gaps")
    packed, off = _unpack_column(buf, off, -(-i_total // 3), "symbols")
    if len(packed) and int(packed.max()) >= SYMBOL_COUNT**3:
        raise FormatError("chunk payload: unknown incidence symbol")
    symbols = _unpack_symbols(packed, i_total)
    res = []
    names = list(COLUMNS[2:]) + [ATTRIBUTE_COLUMN.format(j) for j in range(width - 3)]
    for c, name in enumerate(names):
        col, off = _unpack_column(buf, off, k_total, name)
        if c < 3 and len(col) and int(col.max()) > MAX_RESIDUAL_ZIGZAG:
            raise FormatError(f"chunk payload: {name} out of range")
        res.append(unzigzag(col))
    if off != len(buf):
        raise FormatError(f"chunk payload: {len(buf) - off} trailing bytes")
    if len(symbols) and int(symbols.max()) >= SYMBOL_COUNT:
        raise FormatError("chunk payload: unknown incidence symbol")
    if len(gaps) and int(gaps.max()) > MAX_VERTICES:
        raise FormatError("chunk payload: split vertex gap out of range")
    residual = np.stack(res, axis=1)

    out = []
    ks = np.cumsum(splits) - splits
    is_ = np.cumsum(incs) - incs
    sym8 = symbols.astype(np.uint8)
    gaps = gaps.astype(np.int64)
    for j in range(batch_count):
        k0, k = int(ks[j]), int(splits[j])
        i0, ni = int(is_[j]), int(incs[j])
        v = np.cumsum(gaps[k0 : k0 + k] + 1) - 1
        out.append(SplitBatch(v, sym8[i0 : i0 + ni], residual[k0 : k0 + k]))
    return out
