"""The integer grid every progressive stream lives on.

Positions are stored as integers ``q`` on a uniform cubic grid:
``position = origin + q * step`` with ``0 <= q < 2**bits`` on the largest bbox
axis.  The split stream is lossless on this grid, the watermark is embedded on
it, and a decoder recovers the integers exactly from float32 glTF accessors by
rounding, so the grid is the one coordinate system encoder and decoder share.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import DEFAULT_GRID_BITS, MAX_GRID_BITS, MIN_GRID_BITS
from ..errors import FormatError


@dataclass(frozen=True)
class Grid:
    """A uniform grid: ``origin`` (3,) float64, ``step`` float, ``bits`` int."""

    bits: int
    origin: tuple
    step: float

    @classmethod
    def fit(cls, positions: np.ndarray, bits: int = DEFAULT_GRID_BITS) -> "Grid":
        """The grid of ``bits`` bits spanning the bbox of ``positions`` (n, 3) float."""
        if not MIN_GRID_BITS <= bits <= MAX_GRID_BITS:
            raise ValueError(f"grid bits must be in [{MIN_GRID_BITS}, {MAX_GRID_BITS}], got {bits}")
        lo = positions.min(axis=0)
        extent = float((positions.max(axis=0) - lo).max())
        if extent <= 0.0:
            extent = 1.0
        # float32 must be able to carry every grid point exactly enough to round back:
        step = extent / float((1 << bits) - 1)
        return cls(int(bits), tuple(float(x) for x in lo), float(step))

    def quantize(self, positions: np.ndarray) -> np.ndarray:
        """(n, 3) float -> (n, 3) int64 grid coordinates (rounded)."""
        q = np.rint((np.asarray(positions, np.float64) - np.asarray(self.origin)) / self.step)
        return q.astype(np.int64)

    def dequantize(self, q: np.ndarray) -> np.ndarray:
        """(n, 3) int grid coordinates -> (n, 3) float64 positions."""
        return np.asarray(self.origin) + np.asarray(q, np.float64) * self.step

    def get_config(self) -> dict:
        return {"bits": self.bits, "origin": list(self.origin), "step": self.step}

    @classmethod
    def from_config(cls, config: dict) -> "Grid":
        try:
            bits = int(config["bits"])
            origin = tuple(float(x) for x in config["origin"])
            step = float(config["step"])
        except (KeyError, TypeError, ValueError):
            raise FormatError("grid: expected {bits, origin[3], step}") from None
        if len(origin) != 3 or not np.isfinite(origin).all() or not (np.isfinite(step) and step > 0):
            raise FormatError("grid: origin must be 3 finite numbers and step a positive number")
        if not MIN_GRID_BITS <= bits <= MAX_GRID_BITS:
            raise FormatError(f"grid: bits {bits} outside [{MIN_GRID_BITS}, {MAX_GRID_BITS}]")
        return cls(bits, origin, step)
