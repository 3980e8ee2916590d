"""The integer grids every progressive stream lives on: :class:`Grid` (positions) and
:class:`AttributeGrid` (other vertex attributes).

Positions are stored as integers ``q`` on a uniform cubic grid:
``position = origin + q * step`` with ``0 <= q < 2**bits`` on the largest bbox
axis.  The split stream is lossless on this grid, the watermark is embedded on
it, and a decoder recovers the integers exactly from float32 glTF accessors by
rounding, so the grid is the one coordinate system encoder and decoder share.
Every other vertex attribute has its own per-component grid of the same kind.

Both convert to the float32 values a file stores (``to_float32``) and back, checked
(``from_float32``).  Their dict form exists only at the extension JSON boundary
(``get_config`` / ``from_config``), and ``from_config`` is the one validator.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass

import numpy as np

from ..constants import DEFAULT_GRID_BITS, MAX_GRID_BITS, MIN_GRID_BITS
from ..errors import FormatError
from ..mesh import bounds


#: :meth:`Grid.carries_float32`: the float32 spacing must be below ``step * FLOAT32_SLACK``.  A
#: stored value is within half a spacing of ``origin + q * step``; the float64 arithmetic of the
#: writer (``origin + q * step``) and the reader (``(p - origin) / step``) adds under ``2**-26``
#: spacings, so this keeps ``|(p - origin) / step - q|`` strictly below one half.
FLOAT32_SLACK = 1.0 - 2.0**-20


def float32_spacing(magnitude) -> np.ndarray:
    """The float32 spacing (float64) at each of ``magnitude`` (>= 0, any shape): the gap above the
    float32 nearest to it (the larger gap when that float32 is a power of two); inf where float32
    overflows."""
    with np.errstate(over="ignore", invalid="ignore"):
        f = np.asarray(magnitude, np.float64).astype(np.float32)
        gap = np.spacing(f).astype(np.float64)
    return np.where(np.isfinite(f), gap, np.inf)


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
        lo, hi = bounds(positions)
        extent = float((hi - lo).max())
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
        """(n, 3) int grid coordinates -> (n, 3) float64 positions (``origin + q * step``, in one
        new array: no temporaries)."""
        out = np.array(q, np.float64)
        out *= self.step
        out += np.asarray(self.origin)
        return out

    def to_float32(self, q: np.ndarray) -> np.ndarray:
        """(n, 3) int grid coordinates -> the float32 positions a file stores (``origin + q * step``);
        a coordinate beyond float32's range is infinite, without a warning (:meth:`from_float32` refuses
        it: the encoder's check that the grid survives float32 names the mesh instead)."""
        with np.errstate(over="ignore"):
            return self.dequantize(q).astype(np.float32)

    def from_float32(self, positions: np.ndarray, what: str = "base mesh") -> np.ndarray:
        """Stored positions (n, 3) float -> grid integers (n, 3) int64 (``round((p - origin) / step)``).

        Raises FormatError (message starting with ``what``) when a coordinate is not
        finite or falls outside ``[0, 2**bits)``.
        """
        return _checked_grid_ints(positions, np.asarray(self.origin), self.step, self.bits, f"{what}: positions")

    def carries_float32(self, lo, hi) -> bool:
        """Whether *every* grid point inside the box ``[lo, hi]`` ((3,) float positions) comes back
        from the float32 a file stores (``from_float32(to_float32(q)) == q``), whichever points
        those are: on each axis the float32 spacing at the coordinate of largest magnitude must be
        below ``step`` (by :data:`FLOAT32_SLACK`, which covers the float64 arithmetic of both
        sides).  A float32 value is then at most half a spacing, under half a step, from its grid
        point, so it rounds back; where the spacing exceeds the step, some float32 cell holds two
        grid points and they cannot both come back (a property of the grid, not of given points)."""
        lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        return bool(np.all(float32_spacing(np.maximum(np.abs(lo), np.abs(hi))) < self.step * FLOAT32_SLACK))

    def get_config(self) -> dict:
        """The extension JSON form ``{"bits": int, "origin": [x, y, z], "step": float}``."""
        return {"bits": self.bits, "origin": list(self.origin), "step": self.step}

    @classmethod
    def from_config(cls, config: dict) -> "Grid":
        """The grid of an extension JSON object; FormatError unless ``bits`` is an integer in
        range, ``origin`` three finite numbers and ``step`` a positive finite number."""
        bits, origin, step = _check_config(config, "grid", scalar_step=True)
        if len(origin) != 3:
            raise FormatError(f"grid: origin must be 3 finite numbers, got {config['origin']!r}")
        return cls(bits, origin, step)


def _srgb8_to_linear() -> np.ndarray:
    """(256,) float32: the linear value of each 8-bit sRGB-encoded value ``b`` (IEC 61966-2-1: ``s = b / 255``,
    ``s / 12.92`` up to 0.04045, else ``((s + 0.055) / 1.055) ** 2.4``), computed in float64 and rounded to the
    nearest float32; strictly increasing.  spec/README.md lists these 256 values (``tests/test_spec_sync.py``)."""
    s = np.arange(256, dtype=np.float64) / 255.0
    return np.where(s <= 0.04045, s / 12.92, ((s + 0.055) / 1.055) ** 2.4).astype(np.float32)


#: :data:`SRGB8_TO_LINEAR` ``[b]``: what an ``srgb8`` :class:`AttributeGrid` writes for the byte ``b`` of a colour
#: channel.
SRGB8_TO_LINEAR = _srgb8_to_linear()
#: The one ``transfer`` an :class:`AttributeGrid` may name (the extension's ``attributes[].transfer``).
SRGB8 = "srgb8"


@dataclass(frozen=True)
class AttributeGrid:
    """A per-component grid for a vertex attribute of ``k`` components.

    ``bits`` int; ``origin`` and ``step`` tuples of ``k`` floats: value ``j`` of a
    vertex is ``origin[j] + q[j] * step[j]`` with ``0 <= q[j] < 2**bits``.

    ``transfer`` ``"srgb8"`` (a COLOR_n of 8-bit sRGB-encoded colours decoded to linear, as a PLY's or an OBJ's
    come: exact on 8 bits where a linear grid needs 12 and is not): every component is a byte ``b = origin[j] +
    q[j]`` (``origin`` whole numbers, ``step`` 1), 0..255, the value :data:`SRGB8_TO_LINEAR` ``[b]`` for the
    first three (red, green, blue) and ``b / 255`` for a fourth (alpha, linear) -- each rounded to float32.
    """

    bits: int
    origin: tuple
    step: tuple
    transfer: str | None = None

    @classmethod
    def fit(cls, values: np.ndarray, bits: int) -> "AttributeGrid":
        """The grid of ``bits`` bits spanning each column of ``values`` (n, k) float
        (a constant column gets step 1.0)."""
        lo, hi = bounds(values)
        lo = lo.astype(np.float64)
        span = hi.astype(np.float64) - lo
        step = np.where(span > 0, span / float((1 << bits) - 1), 1.0)
        return cls(int(bits), tuple(float(x) for x in lo), tuple(float(x) for x in step))

    @property
    def width(self) -> int:
        """Number of components ``k``."""
        return len(self.origin)

    def to_float32(self, q: np.ndarray) -> np.ndarray:
        """(n, k) int grid values -> the float32 values a file stores (beyond float32: infinite, as
        :meth:`Grid.to_float32`); an ``srgb8`` grid's (class docstring): FormatError for a byte outside 0..255."""
        if self.transfer == SRGB8:
            return self.to_float32_bytes(self.srgb8_bytes(q))
        with np.errstate(over="ignore"):
            return (np.asarray(self.origin) + q.astype(np.float64) * np.asarray(self.step)).astype(np.float32)

    def srgb8_bytes(self, q: np.ndarray, what: str = "a colour") -> np.ndarray:
        """(n, k) int grid values of an ``srgb8`` grid -> (n, k) int64 bytes ``origin + q``; FormatError (naming
        ``what``, e.g. the attribute) when one lies outside 0..255.  A reader checks a chunk's new vertices as it
        applies the chunk (:class:`~pmwm_codec.stream.replay.Replay`), so a level never holds such a byte."""
        b = np.asarray(self.origin, np.int64) + np.asarray(q).astype(np.int64)
        bad = (b < 0) | (b > 255)
        if bad.any():
            raise FormatError(f"{what}: sRGB byte {int(b[bad][0])} lies outside 0..255")
        return b

    def from_float32(self, values: np.ndarray, what: str) -> np.ndarray:
        """Stored values (n, k) float -> grid integers (n, k) int64; FormatError (naming
        ``what``) when a value is not finite or off the grid (of an ``srgb8`` grid: not one of the float32
        values it writes)."""
        if self.transfer == SRGB8:
            return self._srgb8_ints(np.asarray(values, np.float64), f"base mesh: {what} values")
        return _checked_grid_ints(values, np.asarray(self.origin, np.float64), np.asarray(self.step, np.float64),
                                  self.bits, f"base mesh: {what} values", "their ")

    def _srgb8_ints(self, values: np.ndarray, what: str) -> np.ndarray:
        with np.errstate(invalid="ignore", over="ignore"):
            stored = values.astype(np.float32)
            b = np.rint(np.nan_to_num(values, nan=-1.0, posinf=-1.0, neginf=-1.0) * 255.0)
        b = np.clip(b, 0, 255).astype(np.int64)
        b[:, :3] = np.clip(np.searchsorted(SRGB8_TO_LINEAR, stored[:, :3]), 0, 255)
        if not np.array_equal(self.to_float32_bytes(b), stored):  # float64 values: those that round to them
            raise FormatError(f"{what} are not the 8-bit sRGB colours of their grid")
        q = b - np.asarray(self.origin, np.int64)
        if q.size and (q.min() < 0 or q.max() >= (1 << self.bits)):
            raise FormatError(f"{what} lie outside their {self.bits}-bit grid")
        return q

    @staticmethod
    def to_float32_bytes(b: np.ndarray) -> np.ndarray:
        """(n, k) bytes 0..255 of an ``srgb8`` grid -> the float32 values it writes (class docstring)."""
        out = (b / 255.0).astype(np.float32)
        out[:, :3] = SRGB8_TO_LINEAR[b[:, :3]]
        return out

    def get_config(self) -> dict:
        """The extension JSON form ``{"bits": int, "origin": [k floats], "step": [k floats]}`` (and
        ``"transfer": "srgb8"`` for such a grid)."""
        out = {"bits": self.bits, "origin": list(self.origin), "step": list(self.step)}
        if self.transfer is not None:
            out["transfer"] = self.transfer
        return out

    @classmethod
    def from_config(cls, config: dict) -> "AttributeGrid":
        """The grid of an extension ``attributes`` entry (other keys, e.g. ``semantic``, ignored);
        FormatError unless ``bits`` is in range and ``origin``/``step`` are equally long lists of
        finite numbers, every step positive."""
        what = f"{config.get('semantic', 'attribute')} grid"
        bits, origin, step = _check_config(config, what, scalar_step=False)
        if len(origin) != len(step):
            raise FormatError(f"base mesh: {config.get('semantic')} grid has {len(origin)} origins and {len(step)} steps")
        transfer = config.get("transfer")
        if transfer is not None:
            if transfer != SRGB8:
                raise FormatError(f"{what}: transfer must be {SRGB8!r}, got {transfer!r}")
            semantic = config.get("semantic")
            if not (isinstance(semantic, str) and semantic.startswith("COLOR_")) or len(origin) not in (3, 4):
                raise FormatError(f"{what}: transfer {SRGB8!r} is for a COLOR_n of 3 or 4 components")
            if any(x != 1.0 for x in step) or any(not (0 <= x <= 255 and x == int(x)) for x in origin):
                raise FormatError(f"{what}: transfer {SRGB8!r} needs whole-number origins in 0..255 and steps of 1")
        return cls(bits, origin, step, transfer)


def _number(x) -> bool:
    return isinstance(x, numbers.Real) and not isinstance(x, bool)


def _finite(x) -> bool:
    """A real number (not a bool) that is finite as a float64; JSON integers too large for a
    float (``1e400`` written out as digits) are not."""
    if not _number(x):
        return False
    try:
        return math.isfinite(float(x))
    except OverflowError:
        return False


def _check_config(config, what: str, *, scalar_step: bool):
    """``(bits, origin tuple, step)`` of a grid config dict, or FormatError (the one validator)."""
    try:
        bits, origin, step = config["bits"], config["origin"], config["step"]
    except (KeyError, TypeError) as exc:
        raise FormatError(f"{what}: needs bits, origin and step ({exc!r})") from None
    if not _number(bits) or not isinstance(bits, numbers.Integral) or not MIN_GRID_BITS <= bits <= MAX_GRID_BITS:
        raise FormatError(f"{what}: bits must be an integer in [{MIN_GRID_BITS}, {MAX_GRID_BITS}], got {bits!r}")
    if not isinstance(origin, (list, tuple, np.ndarray)) or not all(_finite(x) for x in origin):
        raise FormatError(f"{what}: origin must be finite numbers, got {origin!r}")
    steps = [step] if scalar_step else step
    if not isinstance(steps, (list, tuple, np.ndarray)) or not all(_finite(x) and x > 0 for x in steps):
        raise FormatError(f"{what}: step must be positive finite numbers, got {step!r}")
    origin = tuple(float(x) for x in origin)
    step = float(step) if scalar_step else tuple(float(x) for x in step)
    return int(bits), origin, step


def _checked_grid_ints(values, origin, step, bits: int, what: str, whose: str = "the ") -> np.ndarray:
    """``rint((values - origin) / step)`` as int64, or FormatError when not finite or outside ``[0, 2**bits)``."""
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        scaled = (np.asarray(values, np.float64) - origin) / step
    if not np.isfinite(scaled).all():
        raise FormatError(f"{what} are not finite")
    rounded = np.rint(scaled)
    if rounded.size and (rounded.min() < 0 or rounded.max() >= (1 << bits)):
        raise FormatError(f"{what} lie outside {whose}{bits}-bit grid")
    return rounded.astype(np.int64)
