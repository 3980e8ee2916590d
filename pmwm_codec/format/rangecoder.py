"""Adaptive binary range coder (LZMA style) and the integer binarisations of payload v2.

spec/bitstream.md §8.1-§8.2 is the normative text; this module is its reference.  Everything is
integer arithmetic on values below 2**40, so a decoder in another language (JavaScript with plain
numbers) reproduces it bit for bit.  That is why the project does not use ``constriction`` here:
its quantized continuous models evaluate floating-point CDFs whose rounding is not specified.

Coder state lives in small numpy arrays so that one chunk is ONE coded stream that several
kernels (mask, connectivity, geometry) continue in turn:

* encoder: ``es`` (6,) int64 ``[low, range, cache, cache_size, out_pos, started]`` and ``out``
  (cap,) uint8, grown by :class:`Encoder` between kernel calls (a kernel never writes past
  ``out_pos + 1 + bytes for its decisions``; see :meth:`Encoder.reserve`);
* decoder: ``ds`` (4,) int64 ``[range, code, in_pos, overrun]`` over ``buf`` (L,) uint8.  Reading
  past the end yields zero bytes and sets ``overrun``; :meth:`Decoder.finish` demands that the
  stream ended exactly at the end of ``buf`` (and no overrun), else FormatError.
* ``probs`` (P,) int64: 11-bit probabilities of a 0 bit, all :data:`PROB_INIT` at a chunk start.

The functions below are plain Python that numba compiles (:func:`~pmwm_codec.progressive.topology.kernel_helper`),
called from the model kernels in :mod:`.records_v2`.
"""

from __future__ import annotations

import numpy as np

from ..errors import FormatError
from ..progressive.topology import compiled, kernel_helper

PROB_BITS = 11
PROB_ONE = 1 << PROB_BITS
PROB_INIT = PROB_ONE // 2
ADAPT_SHIFT = 4
TOP = 1 << 24
MASK32 = 0xFFFFFFFF
#: Integer context block: 64 bucket bit-tree nodes, 3 mantissa nodes per bucket at 64, sign per bucket at 192.
INT_BLOCK = 256
INT_MANTISSA = 64
INT_SIGN = 192
BUCKET_BITS = 6
#: Largest bucket (bit length) of a coded integer magnitude: values below 2**32.
MAX_BUCKET = 32
#: Most bytes one coded decision can add to the output (a bound for buffer sizing).
BYTES_PER_DECISION = 1
#: Decisions of one integer: 6 bucket bits, a sign, up to 31 mantissa bits.
INT_DECISIONS = BUCKET_BITS + 1 + MAX_BUCKET
#: Most decisions a decoder can take per byte it reads: an adaptive probability stays within
#: [2**ADAPT_SHIFT - 1, PROB_ONE - 2**ADAPT_SHIFT + 1] (2033 of 2048 at most), so every decision
#: narrows the range by at least -log2(2033 / 2048) = 0.0106 bits and a byte pays for at most
#: 8 / 0.0106 = 755 of them (a direct bit costs 1 bit).  Rounded up: a bound on what a payload of a
#: given length can hold, so that a reader refuses counts no payload of that length can carry.
MAX_DECISIONS_PER_BYTE = 768


@kernel_helper
def _shift_low(es, out):
    es[0] = _shift(es[0], es, out)


@kernel_helper
def _shift(low, es, out):
    """Shift the top byte out of ``low`` (the encoder's ``es[0]``, held by the caller): the bytes it
    completes go to ``out`` (``es[2:5]``: cache, cache size, position, started).  Returns the new low."""
    if low < 0xFF000000 or low >= 0x100000000:
        carry = low >> 32
        temp = es[2]
        while True:
            if es[5] != 0:
                out[es[4]] = (temp + carry) & 0xFF
                es[4] += 1
            else:  # the very first byte is always 0 and is not stored
                es[5] = 1
            temp = 0xFF
            es[3] -= 1
            if es[3] == 0:
                break
        es[2] = (low >> 24) & 0xFF
    es[3] += 1
    return (low & 0x00FFFFFF) << 8


@kernel_helper(inline=True)
def _ebit(low, rng, es, out, probs, i, bit):
    """:func:`enc_bit` on the state ``low, rng`` (``es[0:2]``) held in locals: ``(low, rng)``.  Inlined,
    as :func:`_bit` is for the decoder: a kernel coding several decisions in a row keeps the state in
    registers, not in ``es`` (which every store to ``probs`` would make the compiler reload)."""
    p = probs[i]
    bound = (rng >> PROB_BITS) * p
    if bit == 0:
        rng = bound
        probs[i] = p + ((PROB_ONE - p) >> ADAPT_SHIFT)
    else:
        low += bound
        rng -= bound
        probs[i] = p - (p >> ADAPT_SHIFT)
    while rng < TOP:
        rng <<= 8
        low = _shift(low, es, out)
    return low, rng


@kernel_helper(inline=True)
def _edirect(low, rng, es, out, bit):
    """:func:`enc_direct` on the state in locals (:func:`_ebit`): ``(low, rng)``."""
    rng >>= 1
    if bit != 0:
        low += rng
    while rng < TOP:
        rng <<= 8
        low = _shift(low, es, out)
    return low, rng


@kernel_helper
def enc_bit(es, out, probs, i, bit):
    """Code ``bit`` (0/1) with adaptive probability ``probs[i]``."""
    es[0], es[1] = _ebit(es[0], es[1], es, out, probs, i, bit)


@kernel_helper
def enc_direct(es, out, bit):
    """Code ``bit`` with probability 1/2, no model."""
    es[0], es[1] = _edirect(es[0], es[1], es, out, bit)


@kernel_helper(inline=True)
def _normalize(rng, code, pos, ds, buf):
    """Shift bytes of ``buf`` into the state in locals (:func:`_bit`) while ``rng`` is below
    :data:`TOP`: ``(rng, code, pos)``.  Past the end of ``buf``: zero bytes, ``ds[3]`` set."""
    while rng < TOP:
        rng <<= 8
        byte = np.int64(0)
        if pos < len(buf):
            byte = np.int64(buf[pos])
        else:
            ds[3] = 1
        pos += 1
        code = ((code << 8) | byte) & MASK32
    return rng, code, pos


@kernel_helper(inline=True)
def _bit(rng, code, pos, ds, buf, probs, i):
    """One adaptive bit (probability ``probs[i]``) decoded from the state ``rng, code, pos``
    (``ds[0:3]``) held in locals: ``(bit, rng, code, pos)``.  Reading past the end of ``buf``
    gives zero bytes and sets ``ds[3]``.  Inlined: a kernel decoding several decisions in a row
    keeps the state in registers, not in ``ds`` (which every store to ``probs`` would make the
    compiler reload, as it cannot tell the two arrays apart)."""
    p = probs[i]
    bound = (rng >> PROB_BITS) * p
    if code < bound:
        rng = bound
        probs[i] = p + ((PROB_ONE - p) >> ADAPT_SHIFT)
        bit = 0
    else:
        code -= bound
        rng -= bound
        probs[i] = p - (p >> ADAPT_SHIFT)
        bit = 1
    rng, code, pos = _normalize(rng, code, pos, ds, buf)
    return bit, rng, code, pos


@kernel_helper(inline=True)
def _direct(rng, code, pos, ds, buf):
    """One equiprobable bit from the state in locals (:func:`_bit`): ``(bit, rng, code, pos)``."""
    rng >>= 1
    bit = 0
    if code >= rng:
        code -= rng
        bit = 1
    rng, code, pos = _normalize(rng, code, pos, ds, buf)
    return bit, rng, code, pos


@kernel_helper(inline=True)
def dec_bit(ds, buf, probs, i):
    """Decode one bit with adaptive probability ``probs[i]``."""
    bit, ds[0], ds[1], ds[2] = _bit(ds[0], ds[1], ds[2], ds, buf, probs, i)
    return bit


@kernel_helper
def dec_direct(ds, buf):
    """Decode one equiprobable bit."""
    bit, ds[0], ds[1], ds[2] = _direct(ds[0], ds[1], ds[2], ds, buf)
    return bit


@kernel_helper
def bit_length(x):
    """Bits of the non-negative int ``x`` (0 for 0)."""
    b = 0
    while x > 0:
        b += 1
        x >>= 1
    return b


@kernel_helper
def enc_tree(es, out, probs, base, nbits, value):
    """``value`` < 2**nbits, MSB first, node ``1 .. 2**nbits - 1`` at ``probs[base + node]``."""
    es[0], es[1] = _etree(es[0], es[1], es, out, probs, base, nbits, value)
    return 0


@kernel_helper(inline=True)
def _etree(low, rng, es, out, probs, base, nbits, value):
    """:func:`enc_tree` on the state in locals (:func:`_ebit`): ``(low, rng)``."""
    node = 1
    for t in range(nbits - 1, -1, -1):
        bit = (value >> t) & 1
        low, rng = _ebit(low, rng, es, out, probs, base + node, bit)
        node = 2 * node + bit
    return low, rng


@kernel_helper(inline=True)
def _tree(rng, code, pos, ds, buf, probs, base, nbits):
    """:func:`dec_tree` on the state in locals (:func:`_bit`): ``(value, rng, code, pos)``."""
    node = 1
    for _ in range(nbits):
        bit, rng, code, pos = _bit(rng, code, pos, ds, buf, probs, base + node)
        node = 2 * node + bit
    return node - (1 << nbits), rng, code, pos


@kernel_helper(inline=True)
def dec_tree(ds, buf, probs, base, nbits):
    value, ds[0], ds[1], ds[2] = _tree(ds[0], ds[1], ds[2], ds, buf, probs, base, nbits)
    return value


@kernel_helper(inline=True)
def _emantissa(low, rng, es, out, probs, base, b, m):
    """The ``b - 1`` bits of ``m`` below a magnitude's leading one, two adaptive, the rest direct, on the
    state in locals (:func:`_ebit`): ``(low, rng)``."""
    nb = b - 1
    first = 0
    for t in range(nb - 1, -1, -1):
        bit = (m >> t) & 1
        pos = nb - 1 - t
        if pos == 0:
            low, rng = _ebit(low, rng, es, out, probs, base + INT_MANTISSA + 3 * b, bit)
            first = bit
        elif pos == 1:
            low, rng = _ebit(low, rng, es, out, probs, base + INT_MANTISSA + 3 * b + 1 + first, bit)
        else:
            low, rng = _edirect(low, rng, es, out, bit)
    return low, rng


@kernel_helper(inline=True)
def _mantissa(rng, code, pos, ds, buf, probs, base, b):
    """The ``b - 1 >= 1`` bits below a magnitude's leading one (:func:`_enc_mantissa`) from the
    state in locals (:func:`_bit`): ``(m, rng, code, pos)``."""
    m, rng, code, pos = _bit(rng, code, pos, ds, buf, probs, base + INT_MANTISSA + 3 * b)
    if b >= 3:
        bit, rng, code, pos = _bit(rng, code, pos, ds, buf, probs, base + INT_MANTISSA + 3 * b + 1 + m)
        m = 2 * m + bit
        for _ in range(b - 3):
            bit, rng, code, pos = _direct(rng, code, pos, ds, buf)
            m = 2 * m + bit
    return m, rng, code, pos


@kernel_helper
def enc_uint(es, out, probs, base, x):
    """Unsigned ``0 <= x < 2**32`` under the integer context block at ``probs[base:]``."""
    b = bit_length(x)
    low, rng = _etree(es[0], es[1], es, out, probs, base, BUCKET_BITS, b)
    if b >= 2:
        low, rng = _emantissa(low, rng, es, out, probs, base, b, x - (np.int64(1) << (b - 1)))
    es[0], es[1] = low, rng
    return 0


@kernel_helper(inline=True)
def dec_uint(ds, buf, probs, base):
    """Inverse of :func:`enc_uint`; -1 for a bucket above :data:`MAX_BUCKET` (invalid)."""
    b, rng, code, pos = _tree(ds[0], ds[1], ds[2], ds, buf, probs, base, BUCKET_BITS)
    x = np.int64(b)
    if b > MAX_BUCKET:
        x = np.int64(-1)
    elif b >= 2:
        m, rng, code, pos = _mantissa(rng, code, pos, ds, buf, probs, base, b)
        x = (np.int64(1) << (b - 1)) + m
    ds[0], ds[1], ds[2] = rng, code, pos
    return x


@kernel_helper
def enc_sint(es, out, probs, base, r):
    """Signed ``|r| < 2**32``: bucket of ``|r|``, sign (context: bucket), mantissa."""
    a = -r if r < 0 else r
    b = bit_length(a)
    low, rng = _etree(es[0], es[1], es, out, probs, base, BUCKET_BITS, b)
    if b >= 1:
        low, rng = _ebit(low, rng, es, out, probs, base + INT_SIGN + b, 1 if r < 0 else 0)
    if b >= 2:
        low, rng = _emantissa(low, rng, es, out, probs, base, b, a - (np.int64(1) << (b - 1)))
    es[0], es[1] = low, rng
    return 0


@kernel_helper(inline=True)
def dec_sint(ds, buf, probs, base):
    """Inverse of :func:`enc_sint`.  Returns ``(value, ok)``; ok 0 for a bucket above :data:`MAX_BUCKET`."""
    b, rng, code, pos = _tree(ds[0], ds[1], ds[2], ds, buf, probs, base, BUCKET_BITS)
    x, ok = np.int64(0), 1
    if b > MAX_BUCKET:
        ok = 0
    elif b >= 1:
        neg, rng, code, pos = _bit(rng, code, pos, ds, buf, probs, base + INT_SIGN + b)
        a = np.int64(1)
        if b >= 2:
            m, rng, code, pos = _mantissa(rng, code, pos, ds, buf, probs, base, b)
            a = (np.int64(1) << (b - 1)) + m
        x = -a if neg else a
    ds[0], ds[1], ds[2] = rng, code, pos
    return x, ok


@kernel_helper
def enc_flush(es, out):
    for _ in range(5):
        _shift_low(es, out)
    return 0


def new_probs(n_probs: int) -> np.ndarray:
    """(n_probs,) int64 probabilities, all :data:`PROB_INIT`."""
    return np.full(n_probs, PROB_INIT, np.int64)


class Encoder:
    """One coded stream: state, output buffer and probability table (module docstring)."""

    def __init__(self, probs: np.ndarray, capacity: int = 256):
        self.es = np.array([0, MASK32, 0, 1, 0, 0], np.int64)
        self.out = np.zeros(max(capacity, 16), np.uint8)
        self.probs = probs

    def reserve(self, decisions: int) -> None:
        """Make room for ``decisions`` more coded decisions (and the flush)."""
        pos = int(self.es[4])
        need = pos + 16 + BYTES_PER_DECISION * int(decisions)
        if need > len(self.out):  # the kernels only write bytes (at es[4] on): the bytes written are all there is
            grown = np.empty(max(need, 2 * len(self.out)), np.uint8)
            grown[:pos] = self.out[:pos]
            self.out = grown

    def finish(self) -> bytes:
        """Flush; the stream's bytes."""
        self.reserve(0)
        _kernel(enc_flush)(self.es, self.out)
        return self.out[: int(self.es[4])].tobytes()


class Decoder:
    """Decoding state over ``payload`` (bytes-like) with the probability table ``probs`` (updated in place)."""

    def __init__(self, payload, probs: np.ndarray):
        # a writable copy (as ``bytes(payload)`` copied before): the compiled kernels that decode take the same
        # array type as the ones that code, so numba compiles each of them once, not once per mode (a readonly
        # array is another type: the first encode and decode on a machine compiled the payload kernels twice)
        self.buf = np.frombuffer(bytearray(payload), np.uint8)
        head = self.buf[:4].tolist() + [0] * max(0, 4 - len(self.buf))
        code = int.from_bytes(bytes(head), "big")
        self.ds = np.array([MASK32, code, 4, 1 if len(self.buf) < 4 else 0], np.int64)
        self.probs = probs

    def finish(self, what: str = "chunk payload") -> None:
        """FormatError unless the stream ended exactly at the end of the bytes."""
        if self.ds[3] or int(self.ds[2]) != len(self.buf):
            self._ended_elsewhere(what)

    def check_overrun(self, what: str = "chunk payload") -> None:
        """:meth:`finish`'s FormatError as soon as the decoder has read past the end of the bytes (zeros
        from there on): a valid stream never does, and decoding on would only spend time and memory."""
        if self.ds[3]:
            self._ended_elsewhere(what)

    def _ended_elsewhere(self, what: str):
        raise FormatError(f"{what}: the coded stream does not end at the end of the payload "
                          f"({int(self.ds[2])} bytes read of {len(self.buf)})")


def _kernel(fn):
    """``fn`` compiled when numba is available, else the plain function."""
    jit = compiled(fn)
    return jit if jit is not None else getattr(fn, "py_func", fn)


def _enc_array_kernel(es, out, probs, kind, ctx, values):
    """Code ``values`` (s,) int64 in order; ``kind`` (s,) int64: 0 adaptive bit at ``probs[ctx]``,
    1 direct bit, 2 unsigned / 3 signed integer under the block at ``probs[ctx]``."""
    for t in range(len(values)):
        k = kind[t]
        if k == 0:
            enc_bit(es, out, probs, ctx[t], values[t])
        elif k == 1:
            enc_direct(es, out, values[t])
        elif k == 2:
            enc_uint(es, out, probs, ctx[t], values[t])
        else:
            enc_sint(es, out, probs, ctx[t], values[t])
    return 0


def _dec_array_kernel(ds, buf, probs, kind, ctx, values):
    """Inverse of :func:`_enc_array_kernel`: fills ``values``; returns 0, or -1 on an invalid integer."""
    for t in range(len(values)):
        k = kind[t]
        if k == 0:
            values[t] = dec_bit(ds, buf, probs, ctx[t])
        elif k == 1:
            values[t] = dec_direct(ds, buf)
        elif k == 2:
            x = dec_uint(ds, buf, probs, ctx[t])
            if x < 0:
                return -1
            values[t] = x
        else:
            x, ok = dec_sint(ds, buf, probs, ctx[t])
            if ok == 0:
                return -1
            values[t] = x
    return 0


def encode_array(kind: np.ndarray, ctx: np.ndarray, values: np.ndarray, n_probs: int) -> bytes:
    """One stream coding ``values`` (s,) int64 as ``kind`` (s,) / ``ctx`` (s,) say (:func:`_enc_array_kernel`)."""
    enc = Encoder(new_probs(n_probs))
    enc.reserve(INT_DECISIONS * len(values))
    _kernel(_enc_array_kernel)(enc.es, enc.out, enc.probs, np.asarray(kind, np.int64), np.asarray(ctx, np.int64),
                               np.asarray(values, np.int64))
    return enc.finish()


def encode_uint(enc: Encoder, base: int, value: int) -> None:
    """Code one unsigned integer (:func:`enc_uint`, the block at ``probs[base]``) on ``enc``'s stream (room made
    with :meth:`Encoder.reserve`)."""
    _kernel(enc_uint)(enc.es, enc.out, enc.probs, np.int64(base), np.int64(value))


def decode_uint(dec: Decoder, base: int) -> int:
    """The next unsigned integer of ``dec``'s stream (:func:`dec_uint`, the block at ``probs[base]``); -1 for an
    invalid one.  (A chunk's batch count: the one integer read outside the payload kernels, by the helper itself
    rather than by :func:`decode_array`, whose four inlined kinds a machine's first decode compiled for ~3 s.)"""
    return int(_kernel(dec_uint)(dec.ds, dec.buf, dec.probs, np.int64(base)))


def decode_array(payload, kind: np.ndarray, ctx: np.ndarray, n_probs: int) -> np.ndarray:
    """Inverse of :func:`encode_array`: (s,) int64.  FormatError on an invalid or mis-terminated stream."""
    dec = Decoder(payload, new_probs(n_probs))
    values = np.zeros(len(kind), np.int64)
    if _kernel(_dec_array_kernel)(dec.ds, dec.buf, dec.probs, np.asarray(kind, np.int64), np.asarray(ctx, np.int64), values):
        raise FormatError("coded stream: integer out of range")
    dec.finish("coded stream")
    return values
