"""The owner layer: a 64-bit owner ID in the distribution of vertex norms, read blind.

Method (after Cho, Prost & Jung 2007, "mean shifting of the vertex-norm histogram"):

1. **Frame.**  ``c`` = the vertex mean; ``rho`` = |v - c| per vertex, every vertex weighing
   the same (area weights were measured and rejected: the embedding's own steps at shell
   edges change the triangle areas, and the feedback below no longer converges).  All of
   it is invariant to rotation, translation, uniform scale and re-ordering.
2. **Shells.**  The range between the ``QUANTILE`` and ``1 - QUANTILE`` quantiles of
   ``rho`` is cut into 66 equal shells: a guard shell each side that is never moved (so
   the quantiles do not move with the mark) and 64 shells, one per bit.  Quantiles, not
   the extreme norms, so that one vertex removed or moved does not shift every shell.  In
   a shell, ``t`` = the position of a vertex between the inner (0) and outer (1) radius.
3. **Keyed code.**  With the key's SHAKE-256 mappings (stream id :data:`STREAM_ID`):
   ``coded = owner_bits XOR key.bits(STREAM_ID, 64)``; shell ``b`` carries coded bit
   ``key.permutation(STREAM_ID, 64)[b]``.
4. **Embed.**  Each shell's mean ``t`` is pushed to at least ``1/2 + strength`` (bit 1)
   or at most ``1/2 - strength`` (bit 0) by one common radial shift of its vertices,
   clipped inside the shell; shells already beyond their target are left alone.  A
   feedback loop re-measures the marked mesh exactly as :func:`detect` does (its own
   centroid and quantiles) and adds shift where a shell is still short.
5. **Detect (blind).**  Soft value per coded bit = mean ``t`` of its shell - 1/2; the bit
   is its sign (an empty shell is an erased bit, counted as an error); XOR the whitening
   bits gives the ID read.

**False alarm.**  For a mesh not marked with this key (unmarked, or marked with another
key) the whitening bits are independent fair coins, so every read bit matches the key's
ID with probability 1/2 independently, and the chance of ``e`` or fewer errors among 64
is ``P(e) = sum_{i<=e} C(64, i) / 2^64`` (exact, computed with integers).  The verdict
is ``present`` when ``P(bit_errors) < 1e-9`` (at most 8 errors: 2.8e-10), ``absent``
when ``P >= 1e-3`` (14 errors or more), ``inconclusive`` in between or when fewer than
``MIN_BITS_READ`` bits could be read at all.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["OwnerResult", "embed", "detect", "false_alarm_probability", "OWNER_BITS", "DEFAULT_STRENGTH"]

OWNER_BITS = 64
#: Radial shells, one bit each.
BINS = OWNER_BITS
#: Weighted quantile of the norms that bounds the shells (each side).
QUANTILE = 0.01
#: Default margin of a shell's mean position away from 1/2.
DEFAULT_STRENGTH = 0.03
#: Keyed-mapping stream id of the owner layer (the ASCII of "owner"; the exact layer uses
#: chunk numbers, far below it).
STREAM_ID = int.from_bytes(b"owner", "big")
PRESENT_BELOW = 1e-9
ABSENT_FROM = 1e-3
#: Fewer readable bits than this: inconclusive (the mesh is too small to say).
MIN_BITS_READ = 48
_FIXED_POINT_ROUNDS = 24
#: Each feedback round asks for a little more than the gap (faces across shell edges and
#: clipping at the edges give less than was asked).
_OVERSHOOT = 1.3
_EDGE = 1e-6


@dataclass
class OwnerResult:
    """What :func:`detect` read.

    ``id``: the 64 bits read, as 16 hex digits (most significant bit first);
    ``bit_errors``: bits that differ from the key's owner ID (erased bits included);
    ``erased``: bits no vertex voted for; ``false_alarm_probability``: P(this few errors
    | a mesh not marked with this key); ``verdict``: present | absent | inconclusive.
    """

    id: str
    bit_errors: int
    erased: int
    false_alarm_probability: float
    verdict: str
    bits: int = OWNER_BITS

    def as_json(self) -> dict:
        """The ``owner`` object of ``pmw verify --json``."""
        return {"id": self.id, "bits": self.bits, "bit_errors": int(self.bit_errors),
                "false_alarm_probability": float(self.false_alarm_probability), "verdict": self.verdict}


def false_alarm_probability(bit_errors: int, bits: int = OWNER_BITS) -> float:
    """P(at most ``bit_errors`` mismatches among ``bits`` fair independent coins), exactly."""
    e = max(0, min(int(bit_errors), bits))
    return math.fsum(math.comb(bits, i) for i in range(e + 1)) / 2.0**bits


def id_to_bits(owner_id: int) -> np.ndarray:
    """64-bit integer -> (64,) uint8, most significant bit first."""
    owner_id = int(owner_id)
    if not 0 <= owner_id < 1 << OWNER_BITS:
        raise ValueError(f"owner id must fit in {OWNER_BITS} bits")
    return np.unpackbits(np.frombuffer(owner_id.to_bytes(8, "big"), np.uint8))


def bits_to_hex(bits: np.ndarray) -> str:
    return np.packbits(np.asarray(bits, np.uint8)).tobytes().hex()


def _vertex_frame(positions: np.ndarray, faces: np.ndarray) -> tuple:
    """``(centroid (3,), weights (n,))`` float64: the vertex mean and equal weights summing to 1.

    ``faces`` is unused today (the statistics are per vertex); it is part of the signature
    so that a surface-based frame can replace this one without touching the callers.
    """
    n = len(positions)
    return positions.mean(0), np.full(n, 1.0 / max(n, 1))


def _weighted_quantiles(values: np.ndarray, weights: np.ndarray, qs) -> np.ndarray:
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    cum /= cum[-1]
    idx = np.minimum(np.searchsorted(cum, qs), len(values) - 1)
    return values[order][idx]


def _shells(rho: np.ndarray, lo: float, width: float) -> tuple:
    """``(shell (n,) int64, -1 outside; t (n,) float64 in [0, 1))`` of norms ``rho``."""
    u = (rho - lo) / width
    shell = np.floor(u).astype(np.int64)
    shell[(shell < 0) | (shell >= BINS)] = -1
    return shell, u - np.floor(u)


def _layout(key) -> tuple:
    """``(bit of each shell (BINS,) int64, whitening (64,) uint8)`` from the key."""
    return key.permutation(STREAM_ID, BINS), key.bits(STREAM_ID, OWNER_BITS)


def _shell_means(b: np.ndarray, t: np.ndarray, w: np.ndarray) -> tuple:
    """``(weighted mean of t per shell (BINS,), weight per shell (BINS,))``."""
    inside = b >= 0
    mass = np.bincount(b[inside], weights=w[inside], minlength=BINS)
    tot = np.bincount(b[inside], weights=(w * t)[inside], minlength=BINS)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(mass > 0, tot / np.where(mass > 0, mass, 1), 0.5), mass


def _stats(positions: np.ndarray, faces: np.ndarray) -> tuple:
    """``(frame (centroid (3,), lo, width), weights (n,), shell means (BINS,), shell mass (BINS,))``."""
    centroid, weights = _vertex_frame(positions, faces)
    rho = np.linalg.norm(positions - centroid, axis=1)
    lo, hi = _weighted_quantiles(rho, weights, [QUANTILE, 1.0 - QUANTILE])
    width = float(hi - lo) / (BINS + 2)
    lo = float(lo) + width  # a guard shell each side: the vertices at the quantiles never move
    if not width > 0:
        return (centroid, lo, 0.0), weights, np.full(BINS, 0.5), np.zeros(BINS)
    shell, t = _shells(rho, lo, width)
    mean, mass = _shell_means(shell, t, weights)
    return (centroid, float(lo), width), weights, mean, mass


def _move(pos0: np.ndarray, frame: tuple, shift: np.ndarray) -> np.ndarray:
    """Vertices of ``pos0`` (n, 3) moved radially: each shell's ``t`` + its ``shift``, clipped in."""
    centroid, lo, width = frame
    d = pos0 - centroid
    rho = np.linalg.norm(d, axis=1)
    shell, t = _shells(rho, lo, width)
    si = np.where(shell >= 0, shell, 0)
    moved = (shell >= 0) & (shift[si] != 0)
    new_rho = np.where(moved, lo + (si + np.clip(t + shift[si], _EDGE, 1 - _EDGE)) * width, rho)
    scale = np.divide(new_rho, rho, out=np.ones_like(rho), where=rho > 0)
    return centroid + d * scale[:, None]


def embed(positions, faces, key, owner_id: int | None = None, strength: float = DEFAULT_STRENGTH) -> np.ndarray:
    """Mark ``owner_id`` (default ``key.owner_id``) into the distribution of surface norms.

    positions : (n, 3) float; faces : (m, 3) int (may be empty: vertex mean, equal weights);
    key : :class:`~pmwm_codec.watermark.key.WatermarkKey`; strength : margin of each
    shell's mean position from 1/2 (in shell widths).  Returns new (n, 3) float64
    positions: each vertex moved along the ray from the centroid, never out of its shell.

    A feedback loop: the marked mesh is measured exactly as :func:`detect` measures it and
    each shell still short of its target gets more shift, for a few rounds.
    """
    pos0 = np.asarray(positions, np.float64)
    owner_id = key.owner_id if owner_id is None else owner_id
    if owner_id is None:
        raise ValueError("the key carries no owner id")
    shell_bit, whiten = _layout(key)
    coded = id_to_bits(owner_id) ^ whiten
    sides = np.where(coded[shell_bit] == 1, 1.0, -1.0)
    targets = 0.5 + sides * float(strength)
    shift = np.zeros(BINS)
    marked = pos0
    for _ in range(_FIXED_POINT_ROUNDS):
        frame, _, mean, mass = _stats(marked, faces)
        if frame[2] == 0:
            return pos0.copy()
        short = (sides * (mean - targets) < 0) & (mass > 0)
        if not short.any():
            break
        shift = shift + np.where(short, (targets - mean) * _OVERSHOOT, 0.0)
        marked = _move(pos0, frame, shift)
    return marked


def read_soft(positions, faces, key) -> np.ndarray:
    """Soft coded values (64,) float64: > 0 reads 1, < 0 reads 0, 0 is erased."""
    frame, _, mean, mass = _stats(np.asarray(positions, np.float64), faces)
    if frame[2] == 0:
        return np.zeros(OWNER_BITS)
    shell_bit, _ = _layout(key)
    votes = np.where(mass > 0, mean - 0.5, 0.0)
    return np.bincount(shell_bit, weights=votes, minlength=OWNER_BITS)


def detect(positions, faces, key) -> OwnerResult:
    """Read the owner ID blind from any mesh: positions (n, 3) float, faces (m, 3) int.

    ``key`` must carry ``owner_id`` (the ID expected); the ID read is reported either way.
    """
    soft = read_soft(positions, faces, key)
    _, whiten = _layout(key)
    read = (soft > 0).astype(np.uint8) ^ whiten
    erased = int(np.count_nonzero(soft == 0))
    if key.owner_id is None:
        return OwnerResult(bits_to_hex(read), OWNER_BITS, erased, 1.0, "inconclusive")
    errors = int(np.count_nonzero((read != id_to_bits(key.owner_id)) | (soft == 0)))
    p = false_alarm_probability(errors)
    if OWNER_BITS - erased < MIN_BITS_READ:
        verdict = "inconclusive"
    elif p < PRESENT_BELOW:
        verdict = "present"
    elif p >= ABSENT_FROM:
        verdict = "absent"
    else:
        verdict = "inconclusive"
    return OwnerResult(bits_to_hex(read), errors, erased, p, verdict)
