"""Embedding a wavelet-transformed watermark in the vertex splits, and reading it back.

Contract
--------
Every vertex split creates a vertex ``u``; it is a *carrier*.  Its code is read
from geometry alone (DESIGN.md §2, after Wagner 2000)::

    d    = position(u) - ring_mean(u)          # ring mean as in progressive/vsplit.py
    l    = scale * |d| / nbar                   # relative scale, nbar = base mean edge
    code = floor(l) mod 2**bits

``nbar`` is the mean edge length of the base mesh, which the watermark never
moves, so codes are invariant to rotation, uniform scale and translation;
``scale`` (the paper's ``c``) and ``bits`` are public and stored in the file.
The encoder moves ``u`` along ``d`` to the *centre* of the nearest bin holding
its code, on the integer grid the decoder sees (a small lattice search keeps
the rounded point inside the bin), so our own file round trip is lossless for
the watermark.  The removed vertices of one batch are pairwise non-adjacent, so
no carrier's ring holds another carrier of its batch (the paper's embedding
dependency).

**Binding** (``binding`` ``ring-v2``, spec/watermark.md §5): the code a carrier holds
is its message symbol plus :func:`binding_offsets` -- SipHash-2-4 (:func:`siphash24`, all the
carriers of a batch at once), keyed from the secret, of its stream slot and of
:func:`ring_descriptor`, the similarity-invariant, quantized shape of its ring at split time -- mod ``2**bits``, so codes read from one mesh are worthless on another
without the key.  Files without ``binding`` are legacy marks (read, never authentic).

Carriers are numbered in stream order: batch 0 (coarsest) first; inside batch
``j`` of ``k`` splits, split ``i`` carries stream slot ``offset_j + perm_j[i]``
with ``perm_j = key.permutation(j, k)`` -- secret, but never mixing batches, so
a cut stream carries a *prefix* of the watermark stream (low frequencies first).

**Start.**  ``embed_from`` (public, ``embedFrom`` in the file, absent = 0) is the
first stream slot that carries a code: slots ``0 .. embed_from - 1`` keep their
vertices where the simplification put them, and slot ``s >= embed_from`` carries
code slot ``s - embed_from``.  ``carriers`` counts the code-carrying slots only.
A batch straddling the start has its keyed permutation decide which of its splits
fall before it.

Modes
-----
``exact`` (default)
    Integer lifting Haar coefficients, packed with per-band bit widths
    (:mod:`.payload`) into a bit stream, cycled to fill every carrier
    (``bits`` bits each) and whitened with ``key.bits``; copies are voted.
    The watermark comes back bit-exactly from the complete file.
``paper``
    One ``bits``-bit code per carrier (the paper's Eq. 4): the float Haar
    coefficient ``w = round(coef * 2**(bits-9)) + 2**(bits-1)``, clipped; codes
    repeat when carriers outnumber them (median of the copies).  Each slot's
    code is stored as ``(w + r) mod 2**bits`` with ``r`` a keyed pseudo-random
    ``bits``-bit value, so without the key codes look uniform (a wrong key
    matches at the chance rate ``2**-bits`` and rebuilds noise, not the image).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..constants import MAX_VERTICES
from ..errors import PmwError
from ..progressive.seams import twin_rows
from ..progressive.topology import compiled, kernel_helper
from . import haar
from .payload import BitLayout, bits_from_symbols, pack, repeat_to_capacity, symbols, unpack, vote

MODES = ("exact", "paper")
#: Default code step (nbar / scale) in grid units, per mode.
DEFAULT_STEP_UNITS = {"exact": 2.0, "paper": 1.5}
DEFAULT_GRID_BITS = {"exact": 16, "paper": 22}
MAX_BITS = 16
#: exact mode: most bits per carrier before the distortion gets out of hand
#: (a code moves its vertex by up to 2**(bits-1) steps; 6 bits ~ 70 dB mesh PSNR).
MAX_EXACT_BITS = 6
#: Largest watermark side a file may declare.
MAX_WATERMARK_SIZE = 4096

_OFFSETS = np.stack(np.meshgrid([0, -1, 1], [0, -1, 1], [0, -1, 1], indexing="ij"), -1).reshape(-1, 3)


class CapacityError(PmwError, ValueError):
    """The mesh has too few vertex splits to carry the watermark.

    ``largest_size``: the side of the largest power-of-two watermark (the image shrunk
    with :func:`shrink_watermark`) that fits, or None when none does; ``size``: the side of the
    square watermark that does not fit; ``given``: ``(width, height)`` of the image as the caller gave
    it, when it was downscaled or padded to that square (None: taken as it is).  ``message`` names the
    watermark and what fits by the fields ``{watermark}`` and ``{fit}``, filled from these
    (:func:`watermark_words`, :func:`fit_words`), so :meth:`as_given` can name them as given.
    """

    def __init__(self, message: str, largest_size: int | None = None, size: int | None = None,
                 given: tuple | None = None):
        self.template, self.largest_size, self.size, self.given = message, largest_size, size, given
        super().__init__(message.format(watermark=watermark_words(size, given),
                                        fit=fit_words(largest_size, size, given)))

    def of_key(self, name: str) -> "CapacityError":
        """This error for the image a key file ``name`` holds (an encode given no watermark marks with it): named
        after the key, and with no pointer to ``--fit``, which never shrinks a key's image (the key marks with that
        image only).  An error that is not about the image's size (too few vertex splits for any) is itself."""
        if "{watermark}" not in self.template:
            return self
        template = self.template
        for where in ("", " from there"):
            template = template.replace(fit_hint(where), KEY_IMAGE_HINT)
        shown = name.replace("{", "{{").replace("}", "}}")  # a file name is no format field
        return CapacityError(f"{shown}: {template}", None, self.size, None)

    def as_given(self, width: int, height: int) -> "CapacityError":
        """This error naming the watermark as given, ``width`` x ``height`` pixels (itself when that is
        the square it carries)."""
        if (width, height) == (self.size, self.size) or self.size is None:
            return self
        return CapacityError(self.template, self.largest_size, self.size, (int(width), int(height)))


def watermark_words(size: int | None, given: tuple | None = None) -> str:
    """How a capacity error names a watermark of side ``size``: ``a 256x256 watermark``, or, ``given`` as
    another ``(width, height)``, ``the 300x200 watermark (carried as a 256x256 square)``."""
    if given is None:
        return f"a {size}x{size} watermark" if size else "the watermark"
    return f"the {given[0]}x{given[1]} watermark (carried as a {size}x{size} square)"


def fit_words(fit: int | None, size: int | None, given: tuple | None = None) -> str:
    """The largest square ``fit`` that fits, ``32x32``; with the image ``given`` as another ``(width,
    height)`` than the ``size`` square, also that image at the scale :func:`shrink_watermark` gives it:
    ``32x32 (this image at 32x21, padded)``."""
    if not fit:
        return ""
    if given is None or given[0] == given[1]:
        return f"{fit}x{fit}"
    scale = fit / max(given)
    return f"{fit}x{fit} (this image at {max(1, round(given[0] * scale))}x{max(1, round(given[1] * scale))}, padded)"


def shrink_watermark(image: np.ndarray, size: int) -> np.ndarray:
    """``image`` (s, s) uint8 resampled (Lanczos) to (size, size) uint8."""
    from PIL import Image

    if size >= image.shape[0]:
        return np.ascontiguousarray(image, np.uint8)
    return np.asarray(Image.fromarray(np.asarray(image, np.uint8)).resize((size, size), Image.LANCZOS), np.uint8)


def _exact_message(image: np.ndarray) -> tuple:
    """``(message bits, BitLayout, levels)`` of ``image`` (s, s) uint8 in exact mode."""
    size = int(image.shape[0])
    levels = haar.check_size(size, size.bit_length() - 1)
    stream = haar.to_stream(haar.forward_int(image, levels), levels)
    layout = BitLayout.for_coefficients(stream, haar.bands(size, levels))
    return pack(stream, layout), layout, levels


def _exact_bits(message_bits: int, carriers: int, bits: int | None) -> int | None:
    """Bits per code for ``message_bits`` on ``carriers`` (``bits`` if given), or None if it does not fit."""
    b = max(1, -(-message_bits // carriers)) if bits is None else int(bits)
    limit = MAX_EXACT_BITS if bits is None else MAX_BITS
    return None if b > limit or b * carriers < message_bits else b


def largest_fitting_size(image: np.ndarray, carriers: int, *, bits: int | None = None,
                         mode: str = "exact") -> int | None:
    """Side of the largest :func:`shrink_watermark` of ``image`` (s, s) smaller than ``image`` that
    ``carriers`` splits carry whole in ``mode`` (paper: one split per coefficient), or None."""
    size = int(image.shape[0]) // 2
    while size >= 1 and carriers > 0:
        if mode == "paper":
            if size * size <= carriers:
                return size
        elif _exact_bits(len(_exact_message(shrink_watermark(image, size))[0]), carriers, bits) is not None:
            return size
        size //= 2
    return None


@dataclass
class WatermarkParams:
    """Public watermark parameters (stored in the file's extension JSON)."""

    mode: str
    bits: int
    scale: float
    size: int
    levels: int
    codes: int  # exact: bits in one copy of the stream; paper: coefficients
    carriers: int
    layout: dict | None = None
    fingerprint: str = ""
    embed_from: int = 0  # first stream slot carrying a code
    binding: str = ""  # keyed binding of codes to their rings ("" legacy: none)

    def code_slots(self, slots: np.ndarray, twin: np.ndarray | None = None, void_before: int = 0) -> tuple:
        """Stream slots (k,) int64 of one batch -> ``(code slots (k,) int64, live (k,) bool)``.

        ``twin`` (k,) bool marks the batch's seam twins (spec/watermark.md, "Repeated
        points"): they carry nothing and the code slots skip them; ``void_before`` counts
        the twins of earlier batches at or after ``embed_from``.
        """
        slots = np.asarray(slots, np.int64)
        code = slots - self.embed_from
        if twin is not None and np.any(twin):
            void = np.sort(slots[twin & (code >= 0)])
            code = code - void_before - np.searchsorted(void, slots)
            return code, (code >= 0) & (code < self.carriers) & (slots >= self.embed_from) & ~twin
        code = code - void_before
        return code, (slots >= self.embed_from) & (code < self.carriers)

    def void_count(self, slots: np.ndarray, twin: np.ndarray | None) -> int:
        """Twins of one batch (stream slots (k,), ``twin`` (k,) bool) that :meth:`code_slots` skips."""
        return 0 if twin is None else int(np.count_nonzero(np.asarray(twin) & (np.asarray(slots) >= self.embed_from)))

    def get_config(self) -> dict:
        cfg = {
            "mode": self.mode, "bits": self.bits, "scale": self.scale, "width": self.size,
            "height": self.size, "levels": self.levels, "codes": self.codes,
            "carriers": self.carriers, "keyFingerprint": self.fingerprint,
        }
        if self.layout is not None:
            cfg["layout"] = self.layout
        if self.embed_from:
            cfg["embedFrom"] = self.embed_from
        if self.binding:
            cfg["binding"] = self.binding
        return cfg

    @classmethod
    def from_config(cls, cfg: dict) -> "WatermarkParams":
        from ..errors import FormatError

        try:
            p = cls(
                mode=str(cfg["mode"]), bits=int(cfg["bits"]), scale=float(cfg["scale"]),
                size=int(cfg["width"]), levels=int(cfg["levels"]), codes=int(cfg["codes"]),
                carriers=int(cfg["carriers"]), layout=cfg.get("layout"),
                fingerprint=str(cfg.get("keyFingerprint", "")), embed_from=int(cfg.get("embedFrom", 0)),
                binding=cfg.get("binding", ""),
            )
            height = int(cfg.get("height", p.size))
        except (KeyError, TypeError, ValueError, OverflowError):
            raise FormatError("watermark parameters in the file are incomplete") from None
        if p.binding not in ("", BINDING):
            raise FormatError(f"unknown watermark binding {str(p.binding)[:40]!r} (this reader knows {BINDING!r})")
        if p.mode not in MODES or not 1 <= p.bits <= MAX_BITS or not (p.scale > 0 and np.isfinite(p.scale)):
            raise FormatError("watermark parameters in the file are out of range")
        if p.size < 1 or p.size > MAX_WATERMARK_SIZE or p.size & (p.size - 1) or height != p.size:
            raise FormatError("watermark size in the file is out of range")
        if not 0 <= p.levels <= p.size.bit_length() - 1:
            raise FormatError("watermark levels in the file do not fit its size")
        if not 0 <= p.carriers <= MAX_VERTICES or not 0 <= p.embed_from <= MAX_VERTICES - p.carriers:
            raise FormatError("watermark carrier count or start in the file is out of range")
        if p.mode == "paper" and p.codes != p.size * p.size:
            raise FormatError("paper-mode code count in the file differs from the image size")
        if p.mode == "exact":
            try:
                layout = BitLayout.from_config(p.layout)
            except (ValueError, TypeError, OverflowError) as exc:
                raise FormatError(f"watermark bit layout in the file is invalid ({exc})") from None
            if layout.count != p.size * p.size or layout.total_bits != p.codes or not 0 < p.codes <= 64 * p.size * p.size:
                raise FormatError("watermark bit layout in the file does not match its size and code count")
        return p


def relative_scale(points: np.ndarray, centroid: np.ndarray, nbar: float, scale: float) -> np.ndarray:
    """(k,) float64 ``l = scale * |points - centroid| / nbar``."""
    d = np.asarray(points, np.float64) - centroid
    return scale * np.sqrt(np.einsum("ij,ij->i", d, d)) / nbar


def read_codes(points, centroid, nbar, scale, bits) -> np.ndarray:
    """(k,) int64 codes carried by vertices ``points`` (k, 3) with ring means ``centroid``."""
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        l = relative_scale(points, centroid, nbar, scale)
        # the modulo in float64 (exact below 2**53) keeps absurd values from overflowing the int cast
        code = np.mod(np.floor(l), float(1 << bits))
    return np.where(np.isfinite(code), code, 0.0).astype(np.int64)


def place_codes(target, centroid, codes, nbar, scale, bits):
    """Grid points (k, 3) int64 near ``target`` whose relative scale carries ``codes``.

    Returns ``(points, ok)``: ``ok`` (k,) bool is False where no point of the
    3x3x3 lattice neighbourhood lands in the code's bin (step below the grid).
    """
    target = np.asarray(target, np.int64)
    d = target - centroid
    length = np.sqrt(np.einsum("ij,ij->i", d, d))
    direction = np.where(length[:, None] > 0, d / np.maximum(length, 1e-300)[:, None], np.array([0.0, 0.0, 1.0]))
    period = float(1 << bits)
    l = scale * length / nbar
    t = np.round((l - codes - 0.5) / period)
    want = period * t + codes + 0.5
    want = np.where(want < 0.5, want + period, want)
    ideal = centroid + direction * (want * nbar / scale)[:, None]
    cand = np.rint(ideal).astype(np.int64)[:, None, :] + _OFFSETS[None]  # (k, 27, 3)
    lc = scale * np.linalg.norm(cand - centroid[:, None, :], axis=2) / nbar
    valid = (np.floor(lc).astype(np.int64) % (1 << bits)) == codes[:, None]
    err = np.abs(lc - want[:, None]) + np.where(valid, 0.0, np.inf)
    best = np.argmin(err, axis=1)
    ok = np.isfinite(err[np.arange(len(best)), best])
    return cand[np.arange(len(best)), best], ok


# --------------------------------------------------------------------------- ring binding

#: The keyed binding of every code to the ring it sits on (public: ``binding`` in the file).
BINDING = "ring-v2"
#: Descriptor bins per unit of normalized ring distance, and per octave of ring size.
RING_STEPS = 32
#: A descriptor value closer than this (in bins) to a bin boundary is read in both bins.
RING_EPS = 1.0 / 128
#: At most this many ambiguous values of one carrier are tried both ways (2**3 alternatives).
MAX_AMBIGUOUS = 3
ALTERNATIVES = 1 << MAX_AMBIGUOUS
BINDING_LABEL = b"ring-binding/v2"


@dataclass(frozen=True)
class RingDescriptor:
    """Quantized, similarity-invariant description of the rings of one batch's k carriers.

    Carrier i owns values ``starts[i]:starts[i + 1]`` of ``q`` (V,) int64: first
    ``floor(RING_STEPS * log2(R / nbar))`` (``R`` the mean distance of the ring's distinct
    vertices to their mean), then ``floor(RING_STEPS * |p - mean| / R)`` for each distinct
    ring vertex ``p`` in ring order (:class:`~pmwm_codec.progressive.vsplit.SplitTopology`).
    ``vertex`` (V,) int64 the ring vertex behind each value (-1 for the size);
    ``near`` (V,) int64 -1 / +1 when the value lies within :data:`RING_EPS` bins of its
    lower / upper boundary (the neighbouring bin is accepted too), else 0; ``closeness``
    (V,) float64 the distance to the nearer boundary, in bins.
    """

    q: np.ndarray
    starts: np.ndarray
    vertex: np.ndarray
    near: np.ndarray
    closeness: np.ndarray

    def ring(self, i: int) -> np.ndarray:
        """(r,) int64 the distinct ring vertices of carrier ``i``."""
        return self.vertex[self.starts[i] + 1 : self.starts[i + 1]]


def ring_descriptor(positions: np.ndarray, topo, nbar: float) -> RingDescriptor:
    """The :class:`RingDescriptor` of the new vertices of ``topo`` over ``positions`` (n, >=3).

    Ring vertices are placed before their carrier and never move again, so the encoder (at
    split time) and every reader (decoded or given positions) describe the same ring.
    """
    k = len(topo.u)
    own = np.repeat(np.asarray(topo.ring_owner, np.int64), 2)
    ids = np.stack([topo.ring_a, topo.ring_b], axis=1).reshape(-1).astype(np.int64)
    order = np.argsort(own, kind="stable")
    own, ids = own[order], ids[order]
    _, first = np.unique(own * (int(ids.max()) + 1) + ids, return_index=True)
    first.sort()  # distinct ring vertices, owner by owner, in order of first appearance
    own, ids = own[first], ids[first]
    count = np.bincount(own, minlength=k)
    pts = np.asarray(positions[ids, :3], np.float64)
    mean = np.stack([np.bincount(own, pts[:, c], k) for c in range(3)], axis=1) / count[:, None]
    dist = np.linalg.norm(pts - mean[own], axis=1)
    radius = np.bincount(own, dist, k) / count
    starts = np.r_[0, np.cumsum(count + 1)].astype(np.int64)
    head = np.zeros(starts[-1], bool)
    head[starts[:-1]] = True
    values = np.empty(starts[-1])
    vertex = np.full(starts[-1], -1, np.int64)
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        values[starts[:-1]] = np.log2(radius / nbar)
        values[~head] = dist / radius[own]
        x = np.clip(np.nan_to_num(values * RING_STEPS, nan=0.0, posinf=0.0, neginf=0.0), -(2.0**40), 2.0**40)
    vertex[~head] = ids
    q = np.floor(x)
    frac = x - q
    near = np.where(frac < RING_EPS, -1, np.where(frac > 1.0 - RING_EPS, 1, 0)).astype(np.int64)
    return RingDescriptor(q.astype(np.int64), starts, vertex, near, np.minimum(frac, 1.0 - frac))


#: SipHash initial state constants ("somepseudorandomlygeneratedbytes"), v0 .. v3.
_SIP_IV = np.array([0x736F6D6570736575, 0x646F72616E646F6D, 0x6C7967656E657261, 0x7465646279746573], np.uint64)
#: Rotations of (v1, v3) in the first and the second half of a SipRound, and their complements.
_ROT_1, _ROT_2 = np.array([[13], [16]], np.uint64), np.array([[17], [21]], np.uint64)
_ROT_1C, _ROT_2C = np.uint64(64) - _ROT_1, np.uint64(64) - _ROT_2
_U32, _U56 = np.uint64(32), np.uint64(56)


def _rotl(x: np.ndarray, r: np.ndarray, rc: np.ndarray, tmp: np.ndarray) -> None:
    """``x <<<= r`` in place (uint64 lanes; ``rc = 64 - r``; ``tmp`` scratch of x's shape)."""
    np.right_shift(x, rc, out=tmp)
    np.left_shift(x, r, out=x)
    np.bitwise_or(x, tmp, out=x)


def _sip_rounds(state: np.ndarray, rounds: int) -> None:
    """``rounds`` SipRounds in place over lanes: ``state`` (4, w) uint64 rows v0, v1, v2, v3."""
    a, b = state[0::2], state[1::2]  # (v0, v2), (v1, v3)
    tmp, tmp1 = np.empty_like(b), np.empty_like(b[0])
    for _ in range(rounds):
        a += b  # v0 += v1; v2 += v3
        _rotl(b, _ROT_1, _ROT_1C, tmp)  # v1 <<<= 13; v3 <<<= 16
        b ^= a  # v1 ^= v0; v3 ^= v2
        _rotl(a[0], _U32, _U32, tmp1)  # v0 <<<= 32
        a += b[::-1]  # v0 += v3; v2 += v1
        _rotl(b, _ROT_2, _ROT_2C, tmp)  # v1 <<<= 17; v3 <<<= 21
        b ^= a[::-1]  # v1 ^= v2; v3 ^= v0
        _rotl(a[1], _U32, _U32, tmp1)  # v2 <<<= 32


def siphash24(key: bytes, message: np.ndarray, nbytes: np.ndarray) -> np.ndarray:
    """SipHash-2-4 (Aumasson & Bernstein 2012) of w byte strings at once.

    ``key`` 16 bytes (``k0``, ``k1`` little-endian); message ``i`` is ``message[i, :nbytes[i]]``
    (``message`` (w, B) uint8, zero beyond each message, ``B >= 8 * (max(nbytes) // 8 + 1)``;
    ``nbytes`` (w,) int64).  Returns (w,) uint64: the standard 8-byte output read little-endian.
    Lanes are sorted longest first, so each 8-byte block compresses a prefix of them.
    """
    nbytes = np.asarray(nbytes, np.int64)
    k0, k1 = np.frombuffer(bytes(key[:16]), "<u8").astype(np.uint64)
    kernel = compiled(_siphash_kernel)
    if kernel is not None:  # lane by lane: a batch of a few carriers costs a few hashes, not ~200 numpy calls
        words = np.ascontiguousarray(np.asarray(message, np.uint8)).view("<u8").astype(np.uint64)
        return kernel(_SIP_IV ^ np.array([k0, k1, k0, k1], np.uint64), words, nbytes)
    order = np.argsort(-nbytes, kind="stable")
    full = nbytes[order] // 8  # whole blocks; then the last block: the tail bytes and the length byte
    words = np.ascontiguousarray(np.asarray(message, np.uint8)[order]).view("<u8").astype(np.uint64)
    state = np.empty((4, len(full)), np.uint64)
    state[:] = (_SIP_IV ^ np.array([k0, k1, k0, k1], np.uint64))[:, None]
    lanes = np.arange(len(full))
    with np.errstate(over="ignore"):
        for j in range(int(full[0]) + 1 if len(full) else 0):
            live = int(np.searchsorted(-full, -j, side="left"))  # lanes with more than j whole blocks
            if j < int(full[0]):
                m = words[:live, j]
            else:
                live, m = len(full), words[lanes, full] | ((nbytes[order].astype(np.uint64) & np.uint64(0xFF)) << _U56)
            state[3, :live] ^= m
            _sip_rounds(state[:, :live], 2)
            state[0, :live] ^= m
        state[2] ^= np.uint64(0xFF)
        _sip_rounds(state, 4)
    out = np.empty(len(full), np.uint64)
    out[order] = state[0] ^ state[1] ^ state[2] ^ state[3]
    return out


def _siphash_kernel(init, words, nbytes):
    """Compiled :func:`siphash24`: ``init`` (4,) uint64 the keyed initial state (v0, v1, v2, v3), ``words``
    (w, W) uint64 each message's zero-padded bytes as little-endian words, ``nbytes`` (w,) int64 their
    lengths; (w,) uint64, one lane after another (every operation on uint64: a mixed int64 one would be a
    float in numba)."""
    out = np.empty(len(nbytes), np.uint64)
    ff, shift = np.uint64(0xFF), np.uint64(56)
    for i in range(len(nbytes)):
        v0, v1, v2, v3 = init[0], init[1], init[2], init[3]
        full = nbytes[i] // 8
        for j in range(full + 1):
            m = words[i, j] if j < full else words[i, full] | ((np.uint64(nbytes[i]) & ff) << shift)
            v3 ^= m
            for _ in range(2):
                v0, v1, v2, v3 = _sip_round(v0, v1, v2, v3)
            v0 ^= m
        v2 ^= ff
        for _ in range(4):
            v0, v1, v2, v3 = _sip_round(v0, v1, v2, v3)
        out[i] = v0 ^ v1 ^ v2 ^ v3
    return out


@kernel_helper(inline=True)
def _sip_round(v0, v1, v2, v3):
    """One SipRound on four uint64 words (:func:`_sip_rounds`, one lane): two halves, the second with v0 and v2
    swapped and its own rotations."""
    v0, v1, v2, v3 = _sip_half(v0, v1, v2, v3, 13, 16)
    v2, v1, v0, v3 = _sip_half(v2, v1, v0, v3, 17, 21)
    return v0, v1, v2, v3


@kernel_helper(inline=True)
def _sip_half(a, b, c, d, rb, rd):
    """Half a SipRound: ``a += b; c += d; b <<<= rb; d <<<= rd; b ^= a; d ^= c; a <<<= 32``."""
    a += b
    c += d
    b = _rotl64(b, rb) ^ a
    d = _rotl64(d, rd) ^ c
    return _rotl64(a, 32), b, c, d


@kernel_helper(inline=True)
def _rotl64(x, r):
    """``x <<< r`` of a uint64 word (0 < r < 64)."""
    return (x << np.uint64(r)) | (x >> np.uint64(64 - r))


def binding_key(key) -> bytes:
    """The 16-byte SipHash key of the ring binding: the first 16 bytes of ``key.derived_key(BINDING_LABEL)``."""
    return key.derived_key(BINDING_LABEL)[:16]


def _ambiguous(desc: RingDescriptor, idx: np.ndarray, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ambiguous values of w carriers whose descriptors sit at ``idx`` (w, L) (``inside``: real values).

    Returns ``(column (w, t), step (w, t), count (w,))``, ``t = min(L, MAX_AMBIGUOUS)``: per carrier the
    positions in its descriptor of its ambiguous values nearest a boundary first (ties: descriptor
    order), the +-1 that moves each into its neighbouring bin, and how many there are (<= t).
    """
    near = np.where(inside, desc.near[idx], 0)
    close = np.where(near != 0, desc.closeness[idx], np.inf)
    column = np.argsort(close, axis=1, kind="stable")[:, :MAX_AMBIGUOUS]
    count = np.isfinite(np.take_along_axis(close, column, 1)).sum(axis=1)
    return column, np.take_along_axis(near, column, 1), count


def binding_offsets(prf_key: bytes, slots: np.ndarray, desc: RingDescriptor, bits: int, which=None, *,
                    alternatives: bool = False) -> np.ndarray:
    """Keyed code offsets of carriers ``which`` (default all) of one batch, all at once.

    ``prf_key`` the 16-byte :func:`binding_key`; ``slots`` (k,) int64 the carriers' stream slots.
    Carrier i's offset is ``siphash24(prf_key, uint64_le(slot_i) || int16_le(D_i)) mod 2**bits``
    with ``D_i`` its descriptor values saturated to int16 (spec/watermark.md §5).  Returns (w, A)
    int64: column 0 the offset of the descriptor as computed; with ``alternatives``
    (A = :data:`ALTERNATIVES`) column ``m`` the reading with the ``t``-th ambiguous value
    (:func:`_ambiguous`) moved to its neighbouring bin for every bit ``t`` set in ``m``, -1 where
    the carrier has fewer.
    """
    which = np.arange(len(slots)) if which is None else np.asarray(which, np.int64)
    out = np.full((len(which), ALTERNATIVES if alternatives else 1), -1, np.int64)
    if not len(which):
        return out
    lo = desc.starts[which]
    n = desc.starts[which + 1] - lo
    col = np.arange(int(n.max()))
    inside = col < n[:, None]
    idx = np.where(inside, lo[:, None] + col, 0)
    values = np.where(inside, desc.q[idx], 0)  # (w, L) int64
    lane = np.arange(len(which))  # one lane per reading: carrier, flip mask
    flips = np.zeros(len(which), np.int64)
    if alternatives:
        column, step, count = _ambiguous(desc, idx, inside)
        lane = np.repeat(lane, 1 << count)
        flips = np.arange(len(lane)) - np.repeat(np.cumsum(1 << count) - (1 << count), 1 << count)
        values = values[lane]
        for t in range(column.shape[1]):
            rows = np.flatnonzero((flips >> t) & 1)
            values[rows, column[lane[rows], t]] += step[lane[rows], t]
    w, width = values.shape
    message = np.zeros((w, 8 * ((8 + 2 * width) // 8 + 1)), np.uint8)  # room for the longest's last block
    message[:, :8] = np.asarray(slots, "<u8")[which][lane].view(np.uint8).reshape(w, 8)
    message[:, 8 : 8 + 2 * width] = np.clip(values, -(1 << 15), (1 << 15) - 1).astype("<i2").view(np.uint8)
    h = siphash24(prf_key, message, 8 + 2 * n[lane])
    out[lane, flips] = (h & np.uint64((1 << bits) - 1)).astype(np.int64)
    return out


def paper_mask(key, carriers: int, bits: int) -> np.ndarray:
    """(carriers,) int64 keyed pseudo-random ``bits``-bit values that whiten paper-mode codes."""
    raw = key.bits(1, carriers * bits).astype(np.int64).reshape(carriers, bits)
    return raw @ (np.int64(1) << np.arange(bits - 1, -1, -1, dtype=np.int64))


def carrier_slots(key, batch_index: int, offset: int, k: int) -> np.ndarray:
    """(k,) int64 stream slots carried by the k splits of one batch."""
    return offset + key.permutation(batch_index, k)


def start_index(embed_from, total: int) -> int:
    """The first code-carrying stream slot for ``embed_from`` over ``total`` splits.

    ``embed_from``: an int index (0 .. total) or a float fraction in [0, 1)
    (``floor(fraction * total)``).  Raises CapacityError for an index past ``total`` (the mark cannot start
    there), ValueError for anything else (:func:`~pmwm_codec.options.checked_options` refuses it first).
    """
    if isinstance(embed_from, (bool, np.bool_)):
        raise ValueError(f"embed_from must be a split index or a fraction, got {embed_from!r}")
    if isinstance(embed_from, (int, np.integer)):
        if not 0 <= embed_from <= total:  # known once the mesh is simplified: a mark that cannot start there
            raise CapacityError(f"embed_from {int(embed_from):,} is outside the stream's {total:,} vertex splits: "
                                "start earlier (a split index within them, or a fraction in [0, 1))")
        return int(embed_from)
    try:
        frac = float(embed_from)
    except (TypeError, ValueError):
        raise ValueError(f"embed_from must be a split index or a fraction, got {embed_from!r}") from None
    if not 0.0 <= frac < 1.0:
        raise ValueError(f"embed_from as a fraction must be in [0, 1), got {frac}")
    return int(np.floor(frac * total))


def splits_needed(image: np.ndarray, mode: str, bits: int | None = None) -> int:
    """Fewest vertex splits that hold ``image`` (s, s) uint8 whole.

    paper: one split per coefficient; exact: the packed bit stream at ``bits`` (None: at
    most :data:`MAX_EXACT_BITS`) bits per split.
    """
    size = int(image.shape[0])
    if mode == "paper":
        return size * size
    levels = haar.check_size(size, size.bit_length() - 1)
    stream = haar.to_stream(haar.forward_int(image, levels), levels)
    message = pack(stream, BitLayout.for_coefficients(stream, haar.bands(size, levels)))
    return -(-len(message) // (MAX_EXACT_BITS if bits is None else int(bits)))


# --------------------------------------------------------------------------- encoder


@dataclass
class Embedder:
    """The encoder's hook for :func:`~pmwm_codec.progressive.build.build_progressive`.

    ``codes`` (carriers,) int64 is the message symbol of every code slot; ``nbar`` the
    base mean edge in grid units.  With ``params.binding`` each carrier gets its symbol
    plus the keyed PRF of its stream slot and ring (:func:`binding_offsets`), mod 2**bits.
    Counts how many carriers got their code.
    """

    params: WatermarkParams
    key: object
    codes: np.ndarray
    nbar: float
    offset: int = 0
    embedded: int = 0
    failed: int = 0
    #: batch j -> (stream batch index, carrier offset) when several primitives share the slots
    slots: dict | None = None
    #: sorted stream slots of every seam twin of the document (None: counted as batches come,
    #: which needs the batches in stream order)
    void: np.ndarray | None = None
    void_seen: int = 0

    def __call__(self, j, topo, target, state):
        k = len(target)
        if self.slots is not None:
            g, offset = self.slots[j]
            slots = carrier_slots(self.key, g, offset, k)
        else:
            offset = self.offset
            slots = carrier_slots(self.key, j, self.offset, k)
            self.offset += k
        first = twin_rows(target[:, :3])
        twin = first != np.arange(k)  # seam twins: they take their first copy's final place
        if self.void is None:
            before = self.void_seen
            self.void_seen += self.params.void_count(slots, twin)
        else:
            before = int(np.searchsorted(self.void, offset) - np.searchsorted(self.void, self.params.embed_from))
            before = max(before, 0)
        code_slots, live = self.params.code_slots(slots, twin, before)
        out = np.array(target, dtype=np.int64, copy=True)
        if live.any():
            codes = self.codes[code_slots[live]]
            if self.params.binding:
                desc = ring_descriptor(state.positions, topo, self.nbar)
                offsets = binding_offsets(binding_key(self.key), slots, desc, self.params.bits, np.flatnonzero(live))[:, 0]
                codes = (codes + offsets) % (1 << self.params.bits)
            ok = _place_apart(out, target, live, twin, topo.centroid()[:, :3], codes, self.nbar, self.params)
            self.embedded += int(ok.sum())
            self.failed += int((~ok).sum())
        out[twin, :3] = out[first[twin], :3]
        return out


def _place_apart(out, target, live, twin, centroid, codes, nbar, params) -> np.ndarray:
    """Place the ``live`` rows' codes into ``out`` (k, D) int64, no two on one point.

    A carrier on the point of another row of its batch would read as a seam twin (and
    shift every later code slot), so a clashing carrier is placed again from a target
    moved by one grid unit (up to 8 times).  ``twin`` rows are left to their first copy.
    Returns ``ok`` (live,) bool: the code is in place and the point is its own.
    """
    rows = np.flatnonzero(live)
    aim = np.asarray(target[rows, :3], np.int64).copy()
    todo = np.ones(len(rows), bool)
    ok = np.zeros(len(rows), bool)
    for attempt in range(9):
        pts, placed = place_codes(aim[todo], centroid[rows[todo]], codes[todo], nbar, params.scale, params.bits)
        out[rows[todo], :3] = pts
        ok[todo] = placed
        clash = (twin_rows(np.where(twin[:, None], -1, out[:, :3])) != np.arange(len(out)))[rows]
        if not clash.any():
            break
        todo = clash
        aim[todo, attempt % 3] += 1
    return ok & ~clash


def plan(image: np.ndarray, key, carriers: int, *, mode: str = "exact", bits: int | None = None,
         nbar: float = 1.0, step_units: float | None = None) -> tuple[WatermarkParams, np.ndarray]:
    """Choose parameters and the per-slot codes for embedding ``image`` (s, s) uint8.

    Returns ``(params, codes (carriers,) int64)``.  Raises :class:`CapacityError`
    when ``exact`` mode would need more than ``MAX_BITS`` bits per carrier.
    """
    if mode not in MODES:
        raise ValueError(f"unknown watermark mode {mode!r}; expected one of {', '.join(MODES)}")
    size = int(image.shape[0])
    levels = haar.check_size(size, size.bit_length() - 1)
    step = DEFAULT_STEP_UNITS[mode] if step_units is None else float(step_units)
    scale = nbar / step
    if carriers <= 0:
        raise CapacityError("the mesh has no vertex splits to carry a watermark")
    if mode == "exact":
        message, layout, _ = _exact_message(image)
        b = _exact_bits(len(message), carriers, bits)
        if b is None:
            raise _capacity_error(image, len(message), carriers, bits)
        cycled = repeat_to_capacity(message, b * carriers) ^ key.bits(0, b * carriers)
        codes = symbols(cycled, b)
        params = WatermarkParams("exact", b, scale, size, levels, len(message), carriers, layout.get_config())
    else:
        b = 12 if bits is None else int(bits)
        if not 2 <= b <= MAX_BITS:
            raise ValueError(f"paper mode needs 2..{MAX_BITS} bits per code, got {b}")
        stream = haar.to_stream(haar.forward_float(image, levels), levels)
        q = np.clip(np.round(stream * 2.0 ** (b - 9)) + 2 ** (b - 1), 0, 2**b - 1).astype(np.int64)
        codes = (q[np.arange(carriers) % len(q)] + paper_mask(key, carriers, b)) % (1 << b)
        params = WatermarkParams("paper", b, scale, size, levels, len(q), carriers, None)
    params.fingerprint = key.fingerprint()
    params.binding = BINDING
    return params, codes


#: What a capacity error of a key's own image says instead of :func:`fit_hint` (:meth:`CapacityError.of_key`).
KEY_IMAGE_HINT = "a key marks with its own image only, never shrunk (--fit shrinks an image given with --watermark)"


def fit_hint(where: str = "") -> str:
    """The capacity errors' pointer to ``--fit``, the largest size that fits left as the field ``{fit}`` of
    :class:`CapacityError` (``where``: from where)."""
    return f"the largest that fits{where} is {{fit}} (pmw encode --fit shrinks it to that)"


def _capacity_error(image: np.ndarray, message_bits: int, carriers: int, bits: int | None) -> CapacityError:
    """The error for a watermark that does not fit, naming the largest size that does."""
    limit = MAX_EXACT_BITS if bits is None else MAX_BITS
    fit = largest_fitting_size(image, carriers, bits=bits)
    hint = fit_hint() if fit else "no smaller image fits either"
    return CapacityError(
        f"{{watermark}} needs {message_bits:,} bits; this mesh has {carriers:,} vertex splits "
        f"(at most {limit} bits each{'' if bits is None else f', {bits} requested'}): {hint}; "
        "or use a finer mesh, or --mode paper", fit, int(image.shape[0]))


# --------------------------------------------------------------------------- decoder


@dataclass
class Extractor:
    """Reads codes batch by batch and rebuilds the partial watermark.

    Call :meth:`add` after each batch is applied (with its split topology and the
    decoder's positions), then :meth:`image` for the watermark so far.
    ``alternates`` (carriers, A) int64: per code slot the message symbols the carrier's
    code reads as, column 0 with its ring descriptor as computed, the others with its
    ambiguous readings (-1: none; A = :data:`ALTERNATIVES`); ``received`` is column 0
    (-1: unread).  ``written``: the code slots :meth:`add` has written since a reader last took them
    (:meth:`take_written`), so that a reader keeping counts updates them for those only.
    """

    params: WatermarkParams
    key: object
    nbar: float
    alternates: np.ndarray = field(default=None)
    offset: int = 0
    void_seen: int = 0  # seam twins so far (at or after embed_from)
    written: list = field(default_factory=list)

    def __post_init__(self):
        self.alternates = np.full((self.params.carriers, ALTERNATIVES), -1, dtype=np.int64)
        self._prf_key = binding_key(self.key) if self.params.binding else None
        self._layout = None

    def take_written(self) -> np.ndarray:
        """The code slots (w,) int64, ascending and distinct, that :meth:`add` wrote since the last call."""
        out = np.unique(np.concatenate(self.written)) if self.written else np.zeros(0, np.int64)
        self.written = []
        return out

    @property
    def layout(self) -> BitLayout:
        """The exact mode's bit layout (parsed once from the parameters)."""
        if self._layout is None:
            self._layout = BitLayout.from_config(self.params.layout)
        return self._layout

    @property
    def received(self) -> np.ndarray:
        """(carriers,) int64 message symbol read per code slot, -1 unread."""
        return self.alternates[:, 0]

    def add(self, j: int, points: np.ndarray, centroid: np.ndarray, nbar: float | None = None,
            scale: float | None = None, known: np.ndarray | None = None, descriptor: RingDescriptor | None = None,
            twin: np.ndarray | None = None):
        """Record the codes of batch ``j`` (stream order): points (k, 3) and ring means (k, 3).

        ``twin`` (k,) bool: the batch's seam twins as the stream decodes them (default: the
        repeated rows of ``points``); they carry nothing and the code slots skip them.

        ``nbar`` / ``scale`` override the defaults for a batch of another primitive;
        ``known`` (k,) bool marks the carriers that can be read (default all): the
        others keep their slots but stay unread; ``descriptor`` the batch's rings (needed
        when the mark is bound).  Returns ``(code slots (r,) int64, batch rows (r,) int64)``
        of the carriers read.
        """
        k = len(points)
        stream = carrier_slots(self.key, j, self.offset, k)
        twin = (twin_rows(points) != np.arange(k)) if twin is None else np.asarray(twin, bool)
        slots, live = self.params.code_slots(stream, twin, self.void_seen)
        self.void_seen += self.params.void_count(stream, twin)
        self.offset += k
        if known is not None:
            live &= np.asarray(known, bool)
        nbar = self.nbar if nbar is None else nbar
        scale = self.params.scale if scale is None else scale
        rows = np.flatnonzero(live)
        codes = read_codes(points[live], centroid[live], nbar, scale, self.params.bits)
        if self._prf_key is None:
            self.alternates[slots[live], 0] = codes
        else:
            if descriptor is None:
                raise ValueError("a bound watermark is read with the ring descriptors of its carriers")
            offsets = binding_offsets(self._prf_key, stream, descriptor, self.params.bits, rows, alternatives=True)
            self.alternates[slots[live]] = np.where(offsets >= 0, (codes[:, None] - offsets) % (1 << self.params.bits), -1)
        self.written.append(slots[live])
        return slots[live], rows

    @property
    def carriers_read(self) -> int:
        return int(np.count_nonzero(self.received >= 0))

    def coefficients(self, received: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """The coefficient stream prefix recovered so far: ``(values, count)``.

        ``received`` (carriers,) int64 replaces :attr:`received` (e.g. each carrier's reading
        that agrees with the expected code, when a ring value lay on a boundary).
        """
        p = self.params
        received = self.received if received is None else received
        got = received >= 0
        if p.mode == "exact":
            b = p.bits
            sym = np.where(got, received, 0)
            raw = bits_from_symbols(sym, b, b * p.carriers) ^ self.key.bits(0, b * p.carriers)
            known = np.repeat(got, b)
            return voted_prefix(*vote(raw, known, p.codes), self.layout)
        q = p.codes
        slot_code = np.arange(p.carriers) % q
        values = np.zeros(q, dtype=np.float64)
        have = np.zeros(q, dtype=bool)
        if got.any():
            # unwhiten, then the median of the copies of each code
            idx = slot_code[got]
            mask = paper_mask(self.key, p.carriers, p.bits)[got]
            vals = ((received[got] - mask) % (1 << p.bits)).astype(np.float64)
            order = np.lexsort((vals, idx))
            idx, vals = idx[order], vals[order]
            starts = np.flatnonzero(np.r_[True, idx[1:] != idx[:-1]])
            counts = np.diff(np.r_[starts, len(idx)])
            med = vals[starts + (counts - 1) // 2]
            values[idx[starts]] = (med - 2 ** (p.bits - 1)) / 2.0 ** (p.bits - 9)
            have[idx[starts]] = True
        prefix = int(np.argmin(have)) if not have.all() else q
        return values[:prefix], prefix

    def image(self, received: np.ndarray | None = None) -> tuple[np.ndarray, int]:
        """(size, size) uint8 partial watermark and the number of coefficients it used (``received``: see
        :meth:`coefficients`)."""
        values, count = self.coefficients(received)
        return self.image_of(values), count

    def image_of(self, values: np.ndarray) -> np.ndarray:
        """(size, size) uint8: the image of the coefficient stream prefix ``values`` (c,) (missing ones zero)."""
        p = self.params
        return haar.reconstruct_prefix(values, p.size, p.levels, integer=(p.mode == "exact"))


def voted_prefix(bits: np.ndarray, known: np.ndarray, layout: BitLayout) -> tuple[np.ndarray, int]:
    """The exact mode's coefficient prefix from the voted message: ``bits`` (codes,) uint8 and ``known``
    (codes,) bool (:func:`~.payload.vote`: False where no copy arrived or the copies tie) ->
    ``(values (c,) int64, c)``, every coefficient complete in the bits before the first unknown one."""
    return unpack(bits[: known_prefix(known)], layout)


def known_prefix(known: np.ndarray) -> int:
    """How many of the voted message's bits (``known`` (codes,) bool) come before the first unknown one."""
    return int(np.argmin(known)) if not known.all() else len(known)
