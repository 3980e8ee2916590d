"""Coefficient stream <-> bit stream <-> b-bit symbols, with repetition and voting.

**Bit layout.**  A :class:`BitLayout` gives every band of the coefficient stream (a
contiguous run ``[start, stop)``, e.g. :func:`pmwm_codec.watermark.haar.bands`) a width
chosen from the band's actual values, and an *offset-binary* code ``code = value - low``:

* an **unsigned** band (no negative value: the low band B) has ``low = 0`` and
  ``width = bit_length(max)``;
* a **signed** band has ``low = -2^(width-1)`` and the smallest ``width`` with
  ``-2^(width-1) <= min`` and ``max < 2^(width-1)`` (two's complement with its top bit
  flipped); a band of zeros has width 0 and costs no bits (its values are 0), except that
  a stream of zeros gives its first band width 1, so no message is empty.

``low`` follows from ``(signed, width)``, so the public layout reveals each band's order of
magnitude but no coefficient value (a per-band minimum would give away 1x1 bands
outright).  It travels in the file's JSON through :meth:`BitLayout.get_config` /
:meth:`BitLayout.from_config`::

    {"id": "pmwm-bits", "version": 1, "bands": [[start, stop, signed (0|1), width], ...]}

**Packing.**  :func:`pack` writes the coefficients in stream order, each most significant
bit first; so any *prefix* of the bits holds a prefix of the coefficients, and
:func:`unpack` decodes every coefficient whose bits are complete.

**Symbols.**  :func:`symbols` cuts the bits into b-bit integers (MSB first, the last one
zero-padded), one per carrier vertex; :func:`bits_from_symbols` undoes it.

**Repetition.**  When the carriers hold more bits than the stream, :func:`repeat_to_capacity`
cycles the stream; :func:`vote` takes a majority over the copies (position ``i`` of the
received bits is stream bit ``i mod total_bits``); ties and never-received bits are unknown.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "BitLayout",
    "pack",
    "unpack",
    "symbols",
    "bits_from_symbols",
    "repeat_to_capacity",
    "vote",
]

MAX_WIDTH = 62


class BitLayout:
    """Per-band offset-binary widths for a coefficient stream of ``count`` values.

    Attributes (all numpy int64): ``starts``, ``stops``, ``signed`` (0|1), ``band_widths``,
    ``lows`` per band (k,); ``widths`` per coefficient (count,); ``offsets`` (count + 1,)
    bit offset of each coefficient in the packed stream; ``count``; ``total_bits``.
    """

    CODEC_ID = "pmwm-bits"
    VERSION = 1

    def __init__(self, bands):
        """bands : iterable of (start, stop, signed, width), contiguous from 0, in order."""
        rows = np.array([[int(x) for x in b] for b in bands], dtype=np.int64).reshape(-1, 4)
        if rows.shape[0] == 0:
            raise ValueError("a bit layout needs at least one band")
        self.starts, self.stops, self.signed, self.band_widths = rows.T.copy()
        if self.starts[0] != 0 or np.any(self.starts[1:] != self.stops[:-1]):
            raise ValueError("bands must be contiguous, in order, starting at 0")
        if np.any(self.stops < self.starts):
            raise ValueError("a band ends before it starts")
        if np.any((self.band_widths < 0) | (self.band_widths > MAX_WIDTH)):
            raise ValueError(f"band widths must be in 0..{MAX_WIDTH}")
        if np.any((self.signed != 0) & (self.signed != 1)):
            raise ValueError("band 'signed' flags must be 0 or 1")
        half = np.left_shift(1, np.maximum(self.band_widths - 1, 0))
        self.lows = np.where((self.signed == 1) & (self.band_widths > 0), -half, 0)
        sizes = self.stops - self.starts
        self.count = int(self.stops[-1])
        self.widths = np.repeat(self.band_widths, sizes)
        self._lows = np.repeat(self.lows, sizes)
        self.offsets = np.concatenate([[0], np.cumsum(self.widths)]).astype(np.int64)
        self.total_bits = int(self.offsets[-1])

    @classmethod
    def for_coefficients(cls, stream, bands) -> "BitLayout":
        """The tightest layout for ``stream`` (n,) int.

        bands : Band descriptors (with ``start``/``stop``) or (start, stop) pairs tiling
        ``[0, n)`` in order.
        """
        v = np.asarray(stream)
        if v.ndim != 1 or (v.size and not np.issubdtype(v.dtype, np.integer)):
            raise ValueError("the coefficient stream must be a 1-D integer array")
        v = v.astype(np.int64)
        rows = []
        for b in bands:
            start, stop = (b.start, b.stop) if hasattr(b, "start") else b
            part = v[start:stop]
            lo, hi = (int(part.min()), int(part.max())) if part.size else (0, 0)
            if lo >= 0:
                rows.append((start, stop, 0, hi.bit_length()))
            else:  # need -2^(w-1) <= lo and hi <= 2^(w-1) - 1
                w = 1 + max((-lo - 1).bit_length(), max(hi, 0).bit_length())
                rows.append((start, stop, 1, w))
        if rows and not any(r[3] and r[1] > r[0] for r in rows):
            # a stream of zeros (an all-black image) would pack to no bits, a message no reader
            # takes (spec/watermark.md §3: `codes` > 0): its first band gets one bit
            rows[0] = (rows[0][0], rows[0][1], 0, 1)
        layout = cls(rows)
        if layout.count != v.size:
            raise ValueError(f"bands cover {layout.count} coefficients, stream has {v.size}")
        return layout

    def get_config(self) -> dict:
        """JSON-able description (public; goes into the file)."""
        bands = np.stack([self.starts, self.stops, self.signed, self.band_widths], axis=1)
        return {"id": self.CODEC_ID, "version": self.VERSION, "bands": bands.tolist()}

    @classmethod
    def from_config(cls, config: dict) -> "BitLayout":
        if not isinstance(config, dict) or config.get("id") != cls.CODEC_ID:
            raise ValueError(f'bit layout config must have "id": "{cls.CODEC_ID}"')
        if config.get("version") != cls.VERSION:
            raise ValueError(f"unsupported bit layout version {config.get('version')!r}")
        bands = config.get("bands")
        if not isinstance(bands, list) or len(bands) > 1024:
            raise ValueError("bad bit layout config: bands must be a list of at most 1024 entries")
        for band in bands:
            if (not isinstance(band, (list, tuple)) or len(band) != 4
                    or not all(isinstance(x, int) and not isinstance(x, bool) for x in band)
                    or not (0 <= band[0] <= band[1] <= 1 << 24 and band[2] in (0, 1) and 0 <= band[3] <= MAX_WIDTH)):
                raise ValueError(f"bad bit layout config: band {band!r}")
        try:
            return cls(bands)
        except (KeyError, TypeError, OverflowError) as exc:
            raise ValueError(f"bad bit layout config: {exc}") from None

    def coefficients_in(self, nbits: int) -> int:
        """How many coefficients are complete in the first ``nbits`` bits."""
        return int(np.searchsorted(self.offsets[1:], int(nbits), side="right"))

    def __eq__(self, other):
        return isinstance(other, BitLayout) and self.get_config() == other.get_config()

    def __repr__(self) -> str:
        k, n, nbits = len(self.starts), self.count, self.total_bits
        return f"BitLayout({k} bands, {n} coefficients, {nbits} bits)"


def pack(stream, layout: BitLayout) -> np.ndarray:
    """Coefficients (count,) int -> bits (layout.total_bits,) uint8, MSB first per value."""
    v = np.asarray(stream)
    if v.shape != (layout.count,):
        raise ValueError(f"expected {layout.count} coefficients, got shape {v.shape}")
    code = v.astype(np.int64) - layout._lows
    if np.any(code < 0) or np.any(code >> layout.widths != 0):
        bad = int(np.flatnonzero((code < 0) | (code >> layout.widths != 0))[0])
        raise ValueError(f"coefficient {bad} = {int(v[bad])} does not fit its band's bit width")
    owner = np.repeat(np.arange(layout.count), layout.widths)  # coefficient of each bit
    shift = layout.offsets[owner + 1] - 1 - np.arange(layout.total_bits)
    return ((code[owner] >> shift) & 1).astype(np.uint8)


def unpack(bits_prefix, layout: BitLayout) -> tuple[np.ndarray, int]:
    """A bit prefix (n,) -> (coefficients (c,) int64, c): every coefficient complete in it."""
    bits = np.asarray(bits_prefix).ravel()
    if bits.size > layout.total_bits:
        raise ValueError(f"{bits.size} bits given, the layout holds {layout.total_bits}")
    c = layout.coefficients_in(bits.size)
    b = (bits != 0).astype(np.int64)
    width, start = layout.widths[:c], layout.offsets[:c]
    code = np.zeros(c, dtype=np.int64)
    for j in range(int(width.max()) if c else 0):  # one pass per bit position, not per value
        sel = width > j
        code[sel] = (code[sel] << 1) | b[start[sel] + j]
    return code + layout._lows[:c], c


def _check_b(b: int) -> int:
    b = int(b)
    if not 1 <= b <= MAX_WIDTH:
        raise ValueError(f"bits per symbol must be in 1..{MAX_WIDTH}, got {b}")
    return b


def symbols(bits, b: int) -> np.ndarray:
    """Bits (N,) -> (ceil(N / b),) int64 symbols of b bits, MSB first, last one zero-padded."""
    b = _check_b(b)
    x = (np.asarray(bits).ravel() != 0).astype(np.int64)
    n = -(-x.size // b)
    x = np.concatenate([x, np.zeros(n * b - x.size, dtype=np.int64)]).reshape(n, b)
    return x @ (np.int64(1) << np.arange(b - 1, -1, -1, dtype=np.int64))


def bits_from_symbols(symbols_, b: int, total_bits: int) -> np.ndarray:
    """Symbols (n,) -> bits (min(total_bits, n*b),) uint8, inverse of :func:`symbols`."""
    b = _check_b(b)
    s = np.asarray(symbols_, dtype=np.int64).ravel()
    bits = (s[:, None] >> np.arange(b - 1, -1, -1, dtype=np.int64)) & 1
    return bits.ravel()[: int(total_bits)].astype(np.uint8)


def repeat_to_capacity(bits, capacity_bits: int) -> np.ndarray:
    """Cycle bits (N,) to exactly capacity_bits: (capacity_bits,) uint8 (a prefix if shorter)."""
    x = np.asarray(bits, dtype=np.uint8).ravel()
    capacity_bits = int(capacity_bits)
    if capacity_bits < 0:
        raise ValueError("capacity must be >= 0")
    if x.size == 0:
        return np.zeros(capacity_bits, dtype=np.uint8)
    return x[np.arange(capacity_bits) % x.size]


def vote(received_bits, known_mask, total_bits: int) -> tuple[np.ndarray, np.ndarray]:
    """Majority vote over cycled copies.

    received_bits : (n,) 0/1, position i carries stream bit ``i mod total_bits``
    known_mask : (n,) bool, False where a bit was not received (or is erased)
    Returns ``bits`` (total_bits,) uint8 (0 where unknown) and ``known`` (total_bits,) bool,
    False where no copy arrived or the copies tie.
    """
    r = np.asarray(received_bits).ravel() != 0
    k = np.asarray(known_mask, dtype=bool).ravel()
    if r.shape != k.shape:
        raise ValueError(f"received bits {r.shape} and mask {k.shape} differ in shape")
    total_bits = int(total_bits)
    if total_bits <= 0:
        return np.zeros(0, dtype=np.uint8), np.zeros(0, dtype=bool)
    pos = np.arange(r.size) % total_bits
    ones = np.bincount(pos[k & r], minlength=total_bits)
    zeros = np.bincount(pos[k & ~r], minlength=total_bits)
    return (ones > zeros).astype(np.uint8), ones != zeros
