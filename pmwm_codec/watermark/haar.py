"""Multi-level 2-D Haar transform of a ``2^k x 2^k`` watermark and its low-to-high stream.

Two transforms share one coefficient layout (Mallat's pyramid, in place):

* **Integer lifting (S-transform)** — :func:`forward_int` / :func:`inverse_int`.  For a
  pair ``(a, b)`` of neighbouring samples ``d = a - b`` and ``s = floor((a + b) / 2)``
  (computed as ``b + (d >> 1)``); the inverse is ``b = s - (d >> 1)``, ``a = b + d``.
  Integer in, integer out, bit-exact round trip.  From a uint8 image the low band stays in
  ``[0, 255]`` and every detail band lies in ``[-510, 510]``.
* **Float sum/difference (the paper's A/G filters)** — :func:`forward_float` /
  :func:`inverse_float`: ``s = (a + b) / 2``, ``d = (a - b) / 2``; inverse ``a = s + d``,
  ``b = s - d``.  The basis is orthogonal (not normalised), so dropping coefficients never
  increases the error when others are added.

One level works on the top-left ``s x s`` block: first along rows (x: left half low, right
half high), then along columns (y: top half low, bottom half high).  Quadrants, as in the
paper's ``W I W^T = [[B, V], [H, D]]``::

    +-----+-----+      B  low x, low y    (the blurred image)
    |  B  |  V  |      V  high x, low y   (responds to vertical edges)
    +-----+-----+      H  low x, high y   (responds to horizontal edges)
    |  H  |  D  |      D  high x, high y  (diagonal detail)
    +-----+-----+

Level 1 is the finest (quadrants of the whole image), level ``L`` the coarsest.

**Stream order** (low to high frequency), each band row-major::

    B_L, V_L, H_L, D_L, V_{L-1}, H_{L-1}, D_{L-1}, ..., V_1, H_1, D_1

:func:`bands` describes each band (name, level, place in the image, slice of the stream);
:func:`to_stream` / :func:`from_stream` convert; any prefix of the stream decodes, missing
coefficients taken as ``fill`` (0), and :func:`reconstruct_prefix` turns a prefix into a
(blurred) uint8 image.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = [
    "Band",
    "bands",
    "band_order",
    "check_size",
    "forward_int",
    "inverse_int",
    "forward_float",
    "inverse_float",
    "stream_index",
    "to_stream",
    "from_stream",
    "reconstruct_prefix",
]


@dataclass(frozen=True)
class Band:
    """One sub-band of the pyramid.

    ``name`` is ``"B"``, ``"V"``, ``"H"`` or ``"D"``; ``level`` 1 (finest) .. L (coarsest);
    ``rows``/``cols`` locate it in the coefficient image; ``start``/``stop`` in the stream.
    """

    name: str
    level: int
    rows: slice
    cols: slice
    start: int
    stop: int

    @property
    def label(self) -> str:
        """Short label such as ``"B3"`` or ``"V1"``."""
        return f"{self.name}{self.level}"

    @property
    def size(self) -> int:
        return self.stop - self.start

    @property
    def stream_slice(self) -> slice:
        return slice(self.start, self.stop)


def check_size(size: int, levels: int) -> int:
    """Validate ``size = 2^k`` and ``0 <= levels <= k``; return ``k``."""
    size, levels = int(size), int(levels)
    if size < 1 or size & (size - 1):
        raise ValueError(f"watermark size must be a power of two, got {size}")
    k = size.bit_length() - 1
    if not 0 <= levels <= k:
        raise ValueError(f"levels must be in 0..{k} for size {size}, got {levels}")
    return k


def _check_image(image: np.ndarray, levels: int) -> None:
    if image.ndim != 2 or image.shape[0] != image.shape[1]:
        raise ValueError(f"expected a square 2-D array, got shape {image.shape}")
    check_size(image.shape[0], levels)


@lru_cache(maxsize=64)
def bands(size: int, levels: int) -> tuple[Band, ...]:
    """Band descriptors in stream order: ``B_L, (V,H,D)_L, ..., (V,H,D)_1``."""
    check_size(size, levels)
    out, start = [], 0
    s = size >> levels
    out.append(Band("B", levels, slice(0, s), slice(0, s), 0, s * s))
    start = s * s
    for level in range(levels, 0, -1):
        h = size >> level  # side of each band at this level
        for name, rows, cols in (
            ("V", slice(0, h), slice(h, 2 * h)),
            ("H", slice(h, 2 * h), slice(0, h)),
            ("D", slice(h, 2 * h), slice(h, 2 * h)),
        ):
            out.append(Band(name, level, rows, cols, start, start + h * h))
            start += h * h
    return tuple(out)


def band_order(size: int, levels: int) -> list[str]:
    """Band labels in stream order, e.g. ``["B2", "V2", "H2", "D2", "V1", "H1", "D1"]``."""
    return [b.label for b in bands(size, levels)]


@lru_cache(maxsize=64)
def _stream_index(size: int, levels: int) -> np.ndarray:
    flat = np.arange(size * size, dtype=np.int64).reshape(size, size)
    idx = np.concatenate([flat[b.rows, b.cols].ravel() for b in bands(size, levels)])
    idx.setflags(write=False)
    return idx


def stream_index(size: int, levels: int) -> np.ndarray:
    """(size*size,) int64: flat index in the coefficient image of each stream position."""
    return _stream_index(int(size), int(levels))


# --- one-dimensional steps along an axis (pairs = even/odd samples) ------------------


def _lift_fwd(x: np.ndarray, axis: int) -> np.ndarray:
    a = x.take(np.arange(0, x.shape[axis], 2), axis)
    b = x.take(np.arange(1, x.shape[axis], 2), axis)
    d = a - b
    return np.concatenate([b + (d >> 1), d], axis=axis)


def _lift_inv(y: np.ndarray, axis: int) -> np.ndarray:
    half = y.shape[axis] // 2
    s, d = np.split(y, [half], axis=axis)
    b = s - (d >> 1)
    a = b + d
    return np.stack([a, b], axis=axis + 1).reshape(y.shape)


def _avg_fwd(x: np.ndarray, axis: int) -> np.ndarray:
    a = x.take(np.arange(0, x.shape[axis], 2), axis)
    b = x.take(np.arange(1, x.shape[axis], 2), axis)
    return np.concatenate([(a + b) / 2, (a - b) / 2], axis=axis)


def _avg_inv(y: np.ndarray, axis: int) -> np.ndarray:
    s, d = np.split(y, [y.shape[axis] // 2], axis=axis)
    return np.stack([s + d, s - d], axis=axis + 1).reshape(y.shape)


def _forward(x: np.ndarray, levels: int, step) -> np.ndarray:
    s = x.shape[0]
    for _ in range(levels):
        x[:s, :s] = step(step(x[:s, :s], 1), 0)  # rows (x) first, then columns (y)
        s //= 2
    return x


def _inverse(c: np.ndarray, levels: int, step) -> np.ndarray:
    s = c.shape[0] >> (levels - 1) if levels else c.shape[0]
    for _ in range(levels):
        c[:s, :s] = step(step(c[:s, :s], 0), 1)
        s *= 2
    return c


def forward_int(image, levels: int) -> np.ndarray:
    """Integer lifting Haar.  image: (s, s) integer array -> (s, s) int64 coefficients."""
    x = np.array(image, dtype=np.int64)
    if not np.issubdtype(np.asarray(image).dtype, np.integer):
        raise TypeError("forward_int needs an integer array")
    _check_image(x, levels)
    return _forward(x, levels, _lift_fwd)


def inverse_int(coeffs, levels: int) -> np.ndarray:
    """Exact inverse of :func:`forward_int`: (s, s) integer -> (s, s) int64."""
    c = np.array(coeffs, dtype=np.int64)
    _check_image(c, levels)
    return _inverse(c, levels, _lift_inv)


def forward_float(image, levels: int) -> np.ndarray:
    """The paper's averaging/half-difference Haar: (s, s) -> (s, s) float64."""
    x = np.array(image, dtype=np.float64)
    _check_image(x, levels)
    return _forward(x, levels, _avg_fwd)


def inverse_float(coeffs, levels: int) -> np.ndarray:
    """Inverse of :func:`forward_float`: (s, s) -> (s, s) float64."""
    c = np.array(coeffs, dtype=np.float64)
    _check_image(c, levels)
    return _inverse(c, levels, _avg_inv)


def to_stream(coeff_image, levels: int) -> np.ndarray:
    """(s, s) coefficient image -> (s*s,) stream in band order (same dtype)."""
    c = np.asarray(coeff_image)
    _check_image(c, levels)
    return c.ravel()[stream_index(c.shape[0], levels)]


def from_stream(stream_prefix, size: int, levels: int, fill=0) -> np.ndarray:
    """A prefix (n,) of the stream, n <= size*size -> (size, size) coefficient image.

    Positions the prefix does not reach are ``fill``.  The dtype is the prefix's (int64
    for an empty integer prefix).
    """
    p = np.asarray(stream_prefix)
    idx = stream_index(size, levels)
    if p.ndim != 1 or p.shape[0] > idx.shape[0]:
        raise ValueError(f"stream prefix of shape {p.shape} does not fit a {size}x{size} image")
    dtype = p.dtype if p.size else np.result_type(p.dtype, np.int64)
    out = np.full(size * size, fill, dtype=dtype)
    out[idx[: p.shape[0]]] = p
    return out.reshape(size, size)


def reconstruct_prefix(stream_prefix, size: int, levels: int, integer: bool = True) -> np.ndarray:
    """Image from a stream prefix, missing coefficients zero: (size, size) uint8 (clipped).

    ``integer=True`` inverts the lifting transform (the prefix must be integers);
    ``integer=False`` inverts the float transform and rounds.
    """
    if integer:
        p = np.asarray(stream_prefix)
        if p.size and not np.issubdtype(p.dtype, np.integer):
            raise TypeError("integer reconstruction needs integer coefficients")
        img = inverse_int(from_stream(p.astype(np.int64), size, levels), levels)
    else:
        c = from_stream(np.asarray(stream_prefix, dtype=np.float64), size, levels)
        img = np.rint(inverse_float(c, levels))
    return np.clip(img, 0, 255).astype(np.uint8)
