"""numpy's seeded random streams, ``np.random.default_rng(seed)``, drawn inside compiled kernels.

The encoder's bytes depend on such streams: the tie order of the simplifier's offers
(:func:`~.simplify._offer_ranks`: ``default_rng(c).permutation(c)`` for ``c`` candidates, a batch) and the
vertex weights that find a mesh's rim (:func:`~.seams._rim`: ``integers(0, 2**63, n)``).  Their numpy paths
draw them from numpy; their compiled kernels draw the same values here, without a ``Generator`` built per
call (its seeding alone took ~6.5 us) and without numpy's shuffle, which calls the bit generator through a
function pointer for every draw (~8 ns a value; here ~3).

What numpy does, step by step (numpy 1.17 and later; the stream is frozen by numpy's compatibility
policy for the bit generator, and ``permutation`` / ``shuffle`` have drawn the same way since):

* ``SeedSequence(seed)``: the seed's 32-bit words (low first) hashed into a pool of four words
  (:func:`_pool`), then ``generate_state(4, np.uint64)``: eight 32-bit words drawn from the pool, paired
  little-endian into four 64-bit words;
* ``PCG64``: a 128-bit LCG (multiplier :data:`_MUL_HI`, :data:`_MUL_LO`; increment ``(w2:w3 << 1) | 1``)
  started at zero, stepped, given ``w0:w1``, stepped again; each 64-bit output is the state after a step,
  ``(hi ^ lo)`` rotated right by ``hi >> 58`` (XSL-RR); a 32-bit draw takes an output's low half and keeps
  its high half for the next 32-bit draw;
* ``Generator.permutation(c)``: ``arange(c)`` shuffled by Fisher-Yates from the top, position ``i``
  swapped with ``j`` drawn in ``[0, i]`` by masked rejection (32-bit draws masked to the bits of ``i``,
  redrawn while above it);
* ``Generator.integers(0, 2**63, n, dtype=np.int64)``: Lemire's bounded draws (:func:`integers_63`).

:func:`tests.test_kernels` compares these with numpy's own draws.
"""

from __future__ import annotations

import numpy as np

from .topology import kernel_helper

#: PCG64's 128-bit multiplier (PCG_DEFAULT_MULTIPLIER_128), high and low 64-bit halves.
_MUL_HI = 2549297995355413924
_MUL_LO = 4865540595714422341


@kernel_helper(inline=True)
def _mul_hi64(a, b):
    """The high 64 bits of the 128-bit product of ``a`` and ``b`` (np.uint64), by 32-bit halves."""
    m, s = np.uint64(0xFFFFFFFF), np.uint64(32)
    a0, a1, b0, b1 = a & m, a >> s, b & m, b >> s
    mid = ((a0 * b0) >> s) + ((a0 * b1) & m) + ((a1 * b0) & m)
    return a1 * b1 + ((a0 * b1) >> s) + ((a1 * b0) >> s) + (mid >> s)


@kernel_helper(inline=True)
def _step(hi, lo, inc_hi, inc_lo):
    """The LCG state ``(hi, lo)`` (np.uint64 halves) after one step: ``state * multiplier + inc`` modulo 2**128."""
    mul_hi, mul_lo = np.uint64(_MUL_HI), np.uint64(_MUL_LO)
    low = lo * mul_lo
    high = _mul_hi64(lo, mul_lo) + lo * mul_hi + hi * mul_lo
    new_lo = low + inc_lo
    return high + inc_hi + np.uint64(new_lo < low), new_lo


@kernel_helper(inline=True)
def _output(hi, lo):
    """PCG64's 64-bit output (np.uint64) of the state ``(hi, lo)``: ``hi ^ lo`` rotated right by ``hi >> 58``."""
    rot = hi >> np.uint64(58)
    x = hi ^ lo
    return (x >> rot) | (x << ((np.uint64(64) - rot) & np.uint64(63)))


@kernel_helper(inline=True)
def _hashmix(value, h):
    """SeedSequence's ``hashmix`` of a 32-bit ``value`` with the running constant ``h`` (both np.uint64 below
    2**32): ``(hashed value, next h)``."""
    m = np.uint64(0xFFFFFFFF)
    value ^= h
    h = (h * np.uint64(0x931E8875)) & m
    value = (value * h) & m
    return value ^ (value >> np.uint64(16)), h


@kernel_helper(allocates=True)
def _pool(seed):
    """SeedSequence's pool, (4,) np.uint64 words below 2**32, of the entropy ``seed`` (0 <= seed < 2**63): its
    32-bit words, low first (one word for a seed below 2**32, zero included), hashed into the pool, every
    pool word then mixed into every other."""
    m = np.uint64(0xFFFFFFFF)
    s = np.uint64(seed)
    words = (s & m, s >> np.uint64(32))
    count = 1 if s >> np.uint64(32) == np.uint64(0) else 2
    pool = np.empty(4, np.uint64)
    h = np.uint64(0x43B0D7E5)
    for i in range(4):
        pool[i], h = _hashmix(words[i] if i < count else np.uint64(0), h)
    for src in range(4):
        for dst in range(4):
            if src != dst:
                y, h = _hashmix(pool[src], h)
                x = ((np.uint64(0xCA01F9DD) * pool[dst]) - (np.uint64(0x4973F715) * y)) & m
                pool[dst] = x ^ (x >> np.uint64(16))
    return pool


@kernel_helper(allocates=True)
def seeded(seed):
    """PCG64's state as ``default_rng(seed)`` starts it (0 <= seed < 2**63): ``(hi, lo, inc_hi, inc_lo)``,
    np.uint64, the LCG state and its increment."""
    pool = _pool(seed)
    m = np.uint64(0xFFFFFFFF)
    h = np.uint64(0x8B51F9DD)
    w = np.empty(8, np.uint64)  # generate_state(8 words), SeedSequence's second hash
    for i in range(8):
        x = pool[i % 4] ^ h
        h = (h * np.uint64(0x58F38DED)) & m
        x = (x * h) & m
        w[i] = x ^ (x >> np.uint64(16))
    s = np.uint64(32)
    state_hi, state_lo = w[0] | (w[1] << s), w[2] | (w[3] << s)
    seq_hi, seq_lo = w[4] | (w[5] << s), w[6] | (w[7] << s)
    inc_hi = (seq_hi << np.uint64(1)) | (seq_lo >> np.uint64(63))
    inc_lo = (seq_lo << np.uint64(1)) | np.uint64(1)
    hi, lo = _step(np.uint64(0), np.uint64(0), inc_hi, inc_lo)
    lo2 = lo + state_lo
    hi, lo = _step(hi + state_hi + np.uint64(lo2 < lo), lo2, inc_hi, inc_lo)
    return hi, lo, inc_hi, inc_lo


@kernel_helper(allocates=True)
def permutation(seed, c):
    """``np.random.default_rng(seed).permutation(c)``: (c,) int64 (c >= 0, 0 <= seed < 2**63)."""
    hi, lo, inc_hi, inc_lo = seeded(seed)
    out = np.arange(c)
    spare = np.uint64(0)  # the high half of the last output, when ``held``
    held = False
    for i in range(c - 1, 0, -1):
        top = np.uint64(i)
        mask = top
        for b in (1, 2, 4, 8, 16, 32):
            mask |= mask >> np.uint64(b)
        while True:
            if held:
                r = spare
            else:
                hi, lo = _step(hi, lo, inc_hi, inc_lo)
                x = _output(hi, lo)
                r = x & np.uint64(0xFFFFFFFF)
                spare = x >> np.uint64(32)
            held = not held
            if r & mask <= top:
                break
        j = np.int64(r & mask)
        out[i], out[j] = out[j], out[i]
    return out


@kernel_helper(allocates=True)
def integers_63(seed, n):
    """``np.random.default_rng(seed).integers(0, 2**63, n, dtype=np.int64)``: (n,) int64 (n >= 0, 0 <= seed <
    2**63).  numpy draws a bound of 2**63 by Lemire's method over 64-bit outputs: the high half of
    ``output * 2**63`` is ``output >> 1``, and the low half, ``(output & 1) << 63``, is never below the
    rejection threshold (``2**64 % 2**63 = 0``): one output per value, its top 63 bits."""
    hi, lo, inc_hi, inc_lo = seeded(seed)
    out = np.empty(n, np.int64)
    for i in range(n):
        hi, lo = _step(hi, lo, inc_hi, inc_lo)
        out[i] = np.int64(_output(hi, lo) >> np.uint64(1))
    return out
