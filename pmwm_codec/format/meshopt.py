"""Decoder of glTF buffer views compressed with EXT_meshopt_compression / KHR_meshopt_compression.

Written from the two extension specifications (KhronosGroup/glTF, ``extensions/2.0/Vendor/
EXT_meshopt_compression/README.md`` and ``extensions/2.0/Khronos/KHR_meshopt_compression/
README.md``); the sections implemented are:

* "Specifying compressed views" / "JSON schema updates": the bufferView extension object and its
  validity rules (:func:`decompress`);
* "Fallback buffers": buffers tagged ``"fallback": true`` (:func:`decompress`);
* Appendix A "Bitstream":
  - "Mode 0: attributes", version 0 (header ``0xa0``, both extensions) and version 1 (header
    ``0xa1``, KHR only) with its per-byte control modes 0-3 and per-channel modes 0 (byte deltas),
    1 (2-byte deltas) and 2 (4-byte XOR deltas with rotation);
  - "Mode 1: triangles" (header ``0xe1``: the index buffer codec);
  - "Mode 2: indices" (header ``0xd1``: the index sequence codec);
* Appendix B "Filters": 1 OCTAHEDRAL, 2 QUATERNION, 3 EXPONENTIAL and (KHR only) 4 COLOR.

Every malformed or truncated stream raises :class:`~pmwm_codec.errors.InputFormatError` with one
line naming the problem; the decoders never read past the bytes they are given, and a view's
declared size (``count * byteStride``) is checked against :data:`MAX_DECODED_VIEW_BYTES` and
against the least compressed size that could hold it before anything is allocated.

The attribute, triangle and index sequence codecs are sequential by nature (a group's bytes start
where the previous group's end); they run as numba kernels where numba is available
(:func:`pmwm_codec.progressive.topology.compiled`), and otherwise the attribute and triangle
kernels as the same functions in plain Python and the index sequence on whole numpy arrays (same
bytes).  The delta chains, the channel transforms and the filters are numpy.
"""

from __future__ import annotations

import copy

import numpy as np

from ..constants import MAX_INPUT_FILE_BYTES, MAX_RESOURCE_BYTES
from ..errors import InputFormatError
from ..progressive.topology import compiled, kernel_helper

EXT = "EXT_meshopt_compression"
KHR = "KHR_meshopt_compression"
EXTENSIONS = (EXT, KHR)
MODES = ("ATTRIBUTES", "TRIANGLES", "INDICES")
FILTERS = ("NONE", "OCTAHEDRAL", "QUATERNION", "EXPONENTIAL", "COLOR")

#: Largest decoded buffer view (``count * byteStride``), checked before allocating: a glTF
#: resource is never larger (:data:`~pmwm_codec.constants.MAX_RESOURCE_BYTES`).
MAX_DECODED_VIEW_BYTES = MAX_RESOURCE_BYTES
#: Largest total of the decoded views of one document.
MAX_DECODED_TOTAL_BYTES = MAX_INPUT_FILE_BYTES

# kernel status codes (negative returns)
_TRUNCATED = -1
_BAD_FIFO = -2
_BAD_VARINT = -3


def _kernel(fn):
    """``fn`` compiled when numba is available (and wanted), else the plain function."""
    jit = compiled(fn)
    return jit if jit is not None else fn


# --------------------------------------------------------------------------------------------
# Mode 0: attributes


def _max_block_elements(stride: int) -> int:
    return min((8192 // stride) & ~15, 256)


def _vertex_deltas_kernel(src, limit, count, stride, version, deltas):
    """Parse the attribute blocks of a mode-0 stream into per-element byte deltas.

    ``src`` (n,) uint8 is the whole stream (header byte at 0); ``limit`` is where the tail
    padding begins (nothing at or past it may be read); ``deltas`` (count, stride) uint8,
    zero-filled, receives the still zigzag-/channel-encoded delta byte of every element and byte
    position.  Returns the offset just past the last attribute block, or -1 when a block would
    need bytes at or past ``limit``.
    """
    max_block = min((8192 // stride) & ~15, 256)
    pos = 1
    base = 0
    while base < count:
        n = min(count - base, max_block)
        groups = (n + 15) >> 4
        header_bytes = (groups + 3) >> 2
        control_pos = pos
        if version == 1:
            pos += stride >> 2
            if pos > limit:
                return -1
        for k in range(stride):
            control = 0
            if version == 1:
                control = (np.int64(src[control_pos + (k >> 2)]) >> ((k & 3) << 1)) & 3
            if control == 2:  # all deltas zero, nothing stored
                continue
            if control == 3:  # literal deltas, no header bits
                if pos + n > limit:
                    return -1
                for e in range(n):
                    deltas[base + e, k] = src[pos + e]
                pos += n
                continue
            header_pos = pos
            pos += header_bytes
            if pos > limit:
                return -1
            for g in range(groups):
                m = (np.int64(src[header_pos + (g >> 2)]) >> ((g & 3) << 1)) & 3
                if version == 0:
                    bits = 0 if m == 0 else 1 << m  # 0, 2, 4, 8
                elif control == 0:
                    bits = 0 if m == 0 else 1 << (m - 1)  # 0, 1, 2, 4
                else:
                    bits = 1 << m  # 1, 2, 4, 8
                e0 = base + (g << 4)
                ne = min(16, n - (g << 4))
                if bits == 0:
                    continue
                if bits == 8:
                    if pos + 16 > limit:
                        return -1
                    for j in range(ne):
                        deltas[e0 + j, k] = src[pos + j]
                    pos += 16
                    continue
                packed = bits << 1  # bytes holding 16 deltas of `bits` bits
                if pos + packed > limit:
                    return -1
                sentinel = (1 << bits) - 1
                extra = pos + packed
                for j in range(16):
                    if bits == 1:
                        v = (np.int64(src[pos + (j >> 3)]) >> (j & 7)) & 1
                    elif bits == 2:
                        v = (np.int64(src[pos + (j >> 2)]) >> (6 - ((j & 3) << 1))) & 3
                    else:
                        v = (np.int64(src[pos + (j >> 1)]) >> (4 - ((j & 1) << 2))) & 15
                    if v == sentinel:
                        if extra >= limit:
                            return -1
                        v = np.int64(src[extra])
                        extra += 1
                    if j < ne:
                        deltas[e0 + j, k] = v
                pos = extra
        base += n
    return pos


def _min_attribute_bytes(count: int, stride: int, version: int) -> int:
    """Fewest bytes a mode-0 stream of ``count`` elements can have (header, blocks, tail)."""
    tail = stride if version == 0 else stride + stride // 4
    size = 1 + max(tail, 32 if version == 0 else 24)
    mb = _max_block_elements(stride)
    full, rest = divmod(count, mb)
    if version == 1:  # control bytes only (control mode 2 everywhere)
        return size + (full + (rest > 0)) * (stride // 4)
    per_block = lambda n: stride * ((((n + 15) >> 4) + 3) >> 2)  # header bits only
    return size + full * per_block(mb) + (per_block(rest) if rest else 0)


def _dezigzag(v: np.ndarray) -> np.ndarray:
    """Zigzag decode in ``v``'s unsigned dtype: ``(v >> 1) ^ -(v & 1)`` with wraparound."""
    one = v.dtype.type(1)
    return (v >> one) ^ np.negative(v & one)


def _decode_attributes(data: np.ndarray, count: int, stride: int, khr: bool, fail) -> np.ndarray:
    """Mode 0: ``data`` (n,) uint8 -> (count, stride) uint8."""
    if stride % 4 or not 4 <= stride <= 256:
        fail(f"byteStride {stride} is not a multiple of 4 in 4..256")
    header = int(data[0])
    if header == 0xA0:
        version = 0
    elif header == 0xA1:
        if not khr:
            fail("attribute stream version 1 (header 0xa1) is not allowed in EXT_meshopt_compression")
        version = 1
    else:
        fail(f"the attribute stream starts with 0x{header:02x}, not 0xa0 or 0xa1")
    tail = stride if version == 0 else stride + stride // 4
    tail_padded = max(tail, 32 if version == 0 else 24)
    least = _min_attribute_bytes(count, stride, version)
    if len(data) < least:
        fail(f"{len(data):,} bytes cannot hold {count:,} elements of {stride} bytes "
             f"(at least {least:,} needed)")
    limit = len(data) - tail_padded
    baseline = data[len(data) - tail:len(data) - tail + stride]
    channels = data[len(data) - tail + stride:] if version == 1 else np.zeros(stride // 4, np.uint8)
    for c, mode in enumerate(channels.tolist()):
        if (mode & 15) > 2 or ((mode & 15) < 2 and mode >> 4):
            fail(f"channel {c} has an invalid channel mode byte 0x{mode:02x}")

    deltas = np.zeros((count, stride), np.uint8)
    end = _kernel(_vertex_deltas_kernel)(data, limit, count, stride, version, deltas)
    if end < 0:
        fail(f"the attribute blocks run past the data's {limit:,} bytes before the tail "
             f"(truncated or corrupt stream)")
    if end != limit:
        fail(f"{limit - end:,} unused bytes between the attribute blocks and the tail")

    out = np.empty((count, stride), np.uint8)
    modes = (channels & 15).astype(np.int64)
    for c in range(stride // 4):
        cols = slice(4 * c, 4 * c + 4)
        d = np.ascontiguousarray(deltas[:, cols])
        b = np.ascontiguousarray(baseline[cols])
        if modes[c] == 0:  # byte deltas
            acc = np.cumsum(_dezigzag(d), axis=0, dtype=np.uint8)
            out[:, cols] = acc + b
        elif modes[c] == 1:  # 2-byte deltas
            acc = np.cumsum(_dezigzag(d.view("<u2")), axis=0, dtype=np.uint16)
            out[:, cols] = (acc + b.view("<u2")).astype("<u2").view(np.uint8)
        else:  # 4-byte XOR deltas, rotated by the high nibble
            r = np.uint32(int(channels[c]) >> 4)
            v = d.view("<u4").astype(np.uint32)
            if r:
                v = (v >> r) | (v << np.uint32(32 - int(r)))
            acc = np.bitwise_xor.accumulate(v, axis=0)
            out[:, cols] = (acc ^ b.view("<u4")).astype("<u4").view(np.uint8)
    return out


# --------------------------------------------------------------------------------------------
# Mode 1: triangles


@kernel_helper
def _read_varint(src, dp, limit):
    """A varint-7 (unsigned LEB128, 1-5 bytes, bits past 32 dropped) at ``src[dp]``, reading
    nothing at or past ``limit``.  Returns ``(value, offset past it)``; the offset is -1 when the
    varint runs into ``limit``, -3 when it is longer than 5 bytes."""
    v = 0
    shift = 0
    while True:
        if dp >= limit:
            return 0, -1
        byte = np.int64(src[dp])
        dp += 1
        v |= (byte & 127) << shift
        if byte < 128:
            return v & 0xFFFFFFFF, dp
        shift += 7
        if shift >= 35:
            return 0, -3


@kernel_helper
def _read_index(src, dp, limit, last):
    """``decodeIndex`` of mode 1: a varint at ``src[dp]`` (:func:`_read_varint`), zigzag-decoded
    and added to ``last`` (32-bit wraparound).  Returns ``(new last, offset past the varint)``
    (a negative offset as :func:`_read_varint`'s)."""
    v, dp = _read_varint(src, dp, limit)
    delta = (v >> 1) ^ (0xFFFFFFFF if v & 1 else 0)
    return (last + delta) & 0xFFFFFFFF, dp


@kernel_helper
def _push_vertex(verts, fifo, v):
    """Push ``v`` on the vertex FIFO ``verts`` (16,) int64; ``fifo`` (4,) int64 holds the edge
    FIFO's next slot and fill, then the vertex FIFO's."""
    verts[fifo[2]] = v
    fifo[2] = (fifo[2] + 1) & 15
    fifo[3] = min(fifo[3] + 1, 16)


@kernel_helper
def _push_edge(edge_a, edge_b, fifo, a, b):
    """Push the edge ``(a, b)`` on the edge FIFO ``edge_a`` / ``edge_b`` (16,) int64."""
    edge_a[fifo[0]] = a
    edge_b[fifo[0]] = b
    fifo[0] = (fifo[0] + 1) & 15
    fifo[1] = min(fifo[1] + 1, 16)


def _triangles_kernel(src, limit, tri_count, out):
    """Decode ``tri_count`` triangles of a mode-1 stream into ``out`` (3 * tri_count,) int64.

    ``src`` (n,) uint8 is the whole stream; the 16-byte ``codeaux`` table is ``src[limit:limit+16]``
    (``limit = n - 16``); codes are ``src[1:1+tri_count]``, extra data follows them and may not
    reach ``limit``.  Indices are unsigned 32-bit.  Returns the offset just past the extra data,
    -1 when it would run into the table, -2 when a FIFO entry that was never written is read,
    -3 on a varint longer than 5 bytes.
    """
    mask = 0xFFFFFFFF
    edge_a = np.zeros(16, np.int64)
    edge_b = np.zeros(16, np.int64)
    verts = np.zeros(16, np.int64)
    fifo = np.zeros(4, np.int64)  # edge FIFO next slot, fill; vertex FIFO next slot, fill
    nxt = 0
    last = 0
    dp = 1 + tri_count
    for t in range(tri_count):
        code = np.int64(src[1 + t])
        hi = code >> 4
        lo = code & 15
        if hi < 15:  # an edge from the FIFO and a third vertex
            if hi >= fifo[1]:
                return -2
            slot = (fifo[0] - 1 - hi) & 15
            a = edge_a[slot]
            b = edge_b[slot]
            if 0 < lo < 13:
                if lo >= fifo[3]:
                    return -2
                c = verts[(fifo[2] - 1 - lo) & 15]
            else:
                if lo == 0:
                    c = nxt
                    nxt = (nxt + 1) & mask
                elif lo < 15:
                    c = (last - 1) & mask if lo == 13 else (last + 1) & mask
                    last = c
                else:
                    last, dp = _read_index(src, dp, limit, last)
                    if dp < 0:
                        return dp
                    c = last
                _push_vertex(verts, fifo, c)
            _push_edge(edge_a, edge_b, fifo, c, b)
            _push_edge(edge_a, edge_b, fifo, a, c)
        else:  # three vertices: codeaux table (0xf0..0xfd) or an explicit byte (0xfe, 0xff)
            explicit = lo >= 14
            if not explicit:
                aux = np.int64(src[limit + lo])
            else:
                if dp >= limit:
                    return -1
                aux = np.int64(src[dp])
                dp += 1
                if aux == 0:
                    nxt = 0
            if lo == 15:
                last, dp = _read_index(src, dp, limit, last)
                if dp < 0:
                    return dp
                a = last
            else:
                a = nxt
                nxt = (nxt + 1) & mask
            # b then c, from the nibbles z, w: 0 -> next, 15 (explicit only) -> varint,
            # else vertex FIFO entry z - 1
            b = 0
            c = 0
            for which in range(2):
                sel = aux >> 4 if which == 0 else aux & 15
                if sel == 0:
                    val = nxt
                    nxt = (nxt + 1) & mask
                elif sel == 15 and explicit:
                    last, dp = _read_index(src, dp, limit, last)
                    if dp < 0:
                        return dp
                    val = last
                else:
                    if sel - 1 >= fifo[3]:
                        return -2
                    val = verts[(fifo[2] - sel) & 15]
                if which == 0:
                    b = val
                else:
                    c = val
            _push_vertex(verts, fifo, a)
            if (aux >> 4) == 0 or (aux >> 4) == 15:
                _push_vertex(verts, fifo, b)
            if (aux & 15) == 0 or (aux & 15) == 15:
                _push_vertex(verts, fifo, c)
            _push_edge(edge_a, edge_b, fifo, b, a)
            _push_edge(edge_a, edge_b, fifo, c, b)
            _push_edge(edge_a, edge_b, fifo, a, c)
        out[3 * t] = a
        out[3 * t + 1] = b
        out[3 * t + 2] = c
    return dp


def _decode_triangles(data: np.ndarray, count: int, stride: int, fail) -> np.ndarray:
    """Mode 1: ``data`` (n,) uint8 -> (count,) uint16 or uint32 (``stride`` 2 or 4)."""
    if count % 3:
        fail(f"count {count:,} is not a multiple of 3")
    if data[0] != 0xE1:
        fail(f"the triangle stream starts with 0x{int(data[0]):02x}, not 0xe1")
    tri = count // 3
    if len(data) < 1 + tri + 16:
        fail(f"{len(data):,} bytes cannot hold {tri:,} triangle codes and the 16-byte table "
             f"(at least {1 + tri + 16:,} needed)")
    limit = len(data) - 16
    aux = data[limit:].tolist()
    if aux[14] or aux[15] or any((x >> 4) == 15 or (x & 15) == 15 for x in aux):
        fail("invalid codeaux table (its last two bytes must be 0 and no nibble may be 0xf)")
    out = np.empty(count, np.int64)
    end = _kernel(_triangles_kernel)(data, limit, tri, out)
    if end == _TRUNCATED:
        fail("the triangle data runs into the 16-byte table (truncated or corrupt stream)")
    if end == _BAD_FIFO:
        fail("a triangle code reads an edge or vertex FIFO entry that was never written")
    if end == _BAD_VARINT:
        fail("an index varint is longer than 5 bytes")
    if end != limit:
        fail(f"{limit - end:,} unused bytes between the triangle data and the table")
    return out.astype(np.uint32 if stride == 4 else np.uint16)  # 16-bit: wraparound


# --------------------------------------------------------------------------------------------
# Mode 2: indices


def _index_sequence_kernel(src, limit, count, out):
    """Decode ``count`` index deltas of a mode-2 stream (``src`` (n,) uint8, deltas from offset 1
    up to ``limit = n - 4``) into ``out`` (count,) int64 (unsigned 32-bit values).  Returns the
    offset past the last delta, or -1 / -3 as :func:`_read_varint`."""
    last = np.zeros(2, np.int64)
    dp = 1
    for i in range(count):
        v, dp = _read_varint(src, dp, limit)
        if dp < 0:
            return dp
        which = v & 1
        delta = (v >> 2) ^ (0xFFFFFFFF if v & 2 else 0)
        last[which] = (last[which] + delta) & 0xFFFFFFFF
        out[i] = last[which]
    return dp


def _decode_indices(data: np.ndarray, count: int, stride: int, fail) -> np.ndarray:
    """Mode 2: ``data`` (n,) uint8 -> (count,) uint16 or uint32: :func:`_index_sequence_kernel`
    under numba, else numpy on whole arrays (no per-index loop)."""
    if data[0] != 0xD1:
        fail(f"the index stream starts with 0x{int(data[0]):02x}, not 0xd1")
    if len(data) < 1 + count + 4:
        fail(f"{len(data):,} bytes cannot hold {count:,} index deltas and the 4-byte tail "
             f"(at least {1 + count + 4:,} needed)")
    kernel = compiled(_index_sequence_kernel)
    if kernel is not None:
        out = np.empty(count, np.int64)
        end = kernel(data, len(data) - 4, count, out)
        if end == _TRUNCATED:
            fail("the index data runs into the 4-byte tail (truncated or corrupt stream)")
        if end == _BAD_VARINT:
            fail("an index varint is longer than 5 bytes")
        if end != len(data) - 4:
            fail(f"{len(data) - 4 - end:,} unused bytes between the index data and the tail")
        return out.astype(np.uint32 if stride == 4 else np.uint16)
    # the same on whole arrays
    body = data[1:len(data) - 4]
    ends = np.flatnonzero(body < 0x80)  # last byte of every varint
    if len(ends) < count:
        fail(f"the index data holds {len(ends):,} complete deltas, {count:,} declared "
             f"(truncated or corrupt stream)")
    used = int(ends[count - 1]) + 1 if count else 0
    if used != len(body):
        fail(f"{len(body) - used:,} unused bytes between the index data and the tail")
    ends = ends[:count]
    starts = np.empty(count, np.int64)
    starts[:1] = 0
    starts[1:] = ends[:-1] + 1
    lengths = ends - starts + 1
    if count and int(lengths.max()) > 5:
        fail(f"an index varint is {int(lengths.max())} bytes long (at most 5)")
    # value = sum over bytes of (b & 0x7f) << (7 * position in its varint), then 32-bit wrap
    pos_in = np.arange(len(body), dtype=np.int64) - np.repeat(starts, lengths)
    parts = (body.astype(np.uint64) & np.uint64(0x7F)) << (7 * pos_in).astype(np.uint64)
    values = np.add.reduceat(parts, starts) if count else np.zeros(0, np.uint64)
    v = (values & np.uint64(0xFFFFFFFF)).astype(np.uint32)
    which = (v & np.uint32(1)).astype(bool)
    delta = _dezigzag(v >> np.uint32(1))
    out = np.empty(count, np.uint32)
    for sel in (False, True):
        m = which == sel
        out[m] = np.cumsum(delta[m], dtype=np.uint32)
    return out.astype(np.uint32 if stride == 4 else np.uint16)


# --------------------------------------------------------------------------------------------
# Appendix B: filters, on the decoded (count, stride) uint8 rows.  The spec writes them in
# float32 and specifies their results to one unit in the last place (the exponential filter
# exactly); OCTAHEDRAL, QUATERNION and COLOR run in float64 here: nearer the exact values, and
# nearer meshoptimizer's decoder (200k random vectors per filter and precision: 0-0.07% of the
# OCTAHEDRAL / QUATERNION components one unit off, against 0-0.12% in float32; 12-bit COLOR
# 0.18% either way; none more than one unit).


def _round_away(x: np.ndarray) -> np.ndarray:
    """Round half away from zero (float64 in, float64 out)."""
    return np.trunc(x + np.copysign(0.5, x))


def _to_int(x: np.ndarray, lo: int, hi: int, dtype) -> np.ndarray:
    """float -> ``dtype`` with NaN -> 0 and clamping (results of invalid inputs stay defined)."""
    return np.clip(np.nan_to_num(x, nan=0.0, posinf=hi, neginf=lo), lo, hi).astype(dtype)


def _filter_octahedral(raw: np.ndarray, stride: int) -> np.ndarray:
    """(count, 4|8) uint8 of four int8/int16 components -> same shape, filtered."""
    dt, imax = (np.int8, 127) if stride == 4 else ("<i2", 32767)
    v = raw.view(dt).astype(np.float64)
    with np.errstate(all="ignore"):
        one = v[:, 2]
        x = v[:, 0] / one
        y = v[:, 1] / one
        z = 1 - np.abs(x) - np.abs(y)
        t = np.minimum(z, 0)
        x = x - np.copysign(t, x)
        y = y - np.copysign(t, y)
        length = np.sqrt(x * x + y * y + z * z)
        res = np.stack([x / length, y / length, z / length], axis=1) * imax
        ints = _to_int(_round_away(res), -imax, imax, dt)
    out = raw.view(dt).copy()
    out[:, :3] = ints
    return out.view(np.uint8)


def _filter_quaternion(raw: np.ndarray) -> np.ndarray:
    """(count, 8) uint8 of four int16 components -> four int16 quaternion components."""
    q = raw.view("<i2")
    with np.errstate(all="ignore"):
        scale = np.float64(1.0 / np.sqrt(2.0)) / (q[:, 3] | 3).astype(np.float64)
        xyz = q[:, :3].astype(np.float64) * scale[:, None]
        x, y, z = xyz.T
        w = np.sqrt(np.maximum(0, 1 - x * x - y * y - z * z))
        comps = _to_int(_round_away(np.concatenate([w[:, None], xyz], axis=1) * 32767),
                        -32768, 32767, "<i2")
    maxcomp = (q[:, 3] & 3).astype(np.int64)
    out = np.empty_like(q)
    rows = np.arange(len(q))
    for j in range(4):  # comps[:, j] goes to (maxcomp + j) % 4: w, x, y, z
        out[rows, (maxcomp + j) % 4] = comps[:, j]
    return out.view(np.uint8)


def _filter_exponential(raw: np.ndarray) -> np.ndarray:
    """(count, stride) uint8 of int32 ``e:8 | m:24`` -> float32 ``2**e * m`` (exact for |e| <= 100)."""
    v = raw.view("<i4").astype(np.int32)
    e = v >> np.int32(24)
    m = ((v << np.int32(8)) >> np.int32(8)).astype(np.float32)
    scale = ((e + np.int32(127)).astype(np.uint32) << np.uint32(23)).view(np.float32)
    with np.errstate(all="ignore"):
        return (scale * m).astype("<f4").view(np.uint8)


def _filter_color(raw: np.ndarray, stride: int) -> np.ndarray:
    """(count, 4|8) uint8 of YCoCg+alpha K-bit components -> RGBA unorm8 / unorm16."""
    udt, sdt, umax = (np.uint8, np.int8, 255) if stride == 4 else ("<u2", "<i2", 65535)
    u = raw.view(udt).astype(np.int64)
    s = raw.view(sdt).astype(np.int64)
    alpha = u[:, 3]
    msb = np.zeros(len(alpha), np.int64)
    for bit in range(16):
        msb[alpha >= (1 << bit)] = bit
    scale_as = np.where(alpha > 0, (np.int64(1) << (msb + 1)) - 1, 0)
    y, co, cg = u[:, 0], s[:, 1], s[:, 2]
    a = alpha & (scale_as >> 1)
    a = (a << 1) | (a & 1)
    rgba = np.stack([y + co - cg, y + cg, y - co - cg, a], axis=1).astype(np.float64)
    with np.errstate(all="ignore"):
        ss = umax / scale_as.astype(np.float64)
        res = _round_away(rgba * ss[:, None])
        return _to_int(res, 0, umax, udt).view(np.uint8)


# --------------------------------------------------------------------------------------------
# public API


def decode_view(data: bytes, count: int, stride: int, mode: str, filter: str = "NONE", *,
                khr: bool = False, where: str = "compressed bufferView") -> bytes:
    """Decode one compressed buffer view.

    ``data`` is the extension's byte range (bytes-like); ``count`` elements of ``stride`` bytes
    come out: ``count * stride`` bytes, little-endian as glTF stores them -- for ATTRIBUTES the
    (count, stride) uint8 element rows after ``filter``; for TRIANGLES / INDICES (count,) uint16
    (stride 2, wrapped) or uint32 (stride 4).  ``khr`` allows what only KHR_meshopt_compression
    has (attribute stream version 1, the COLOR filter).  ``where`` starts every error message.

    Raises InputFormatError (one line) on any malformed, truncated or oversized input.
    """

    def fail(msg):
        raise InputFormatError(f"{where}: {msg}")

    for key, value in (("count", count), ("byteStride", stride)):
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            fail(f"{key} must be a non-negative integer, got {value!r}")
    if mode not in MODES:
        fail(f"unknown mode {mode!r} (one of {', '.join(MODES)})")
    if filter not in FILTERS or (filter == "COLOR" and not khr):
        allowed = FILTERS if khr else FILTERS[:4]
        fail(f"unknown filter {filter!r} (one of {', '.join(allowed)})")
    if mode != "ATTRIBUTES" and filter != "NONE":
        fail(f"filter {filter} is only allowed with mode ATTRIBUTES")
    if mode != "ATTRIBUTES" and stride not in (2, 4):
        fail(f"byteStride {stride} of an index stream must be 2 or 4")
    need = {"OCTAHEDRAL": (4, 8), "QUATERNION": (8,), "COLOR": (4, 8)}.get(filter)
    if need and stride not in need:
        fail(f"filter {filter} needs byteStride {' or '.join(map(str, need))}, not {stride}")
    if count * stride > MAX_DECODED_VIEW_BYTES:
        fail(f"{count:,} elements of {stride} bytes exceed the {MAX_DECODED_VIEW_BYTES:,}-byte limit")
    buf = np.frombuffer(memoryview(data).cast("B"), np.uint8) if len(data) else np.zeros(0, np.uint8)
    if len(buf) == 0:
        fail("no compressed data")
    buf.setflags(write=False)  # one array type for the kernels (bytes and bytearray alike): one compile

    if mode == "ATTRIBUTES":
        rows = _decode_attributes(buf, count, stride, khr, fail)
        if filter == "OCTAHEDRAL":
            rows = _filter_octahedral(rows, stride)
        elif filter == "QUATERNION":
            rows = _filter_quaternion(rows)
        elif filter == "EXPONENTIAL":  # any stride of ATTRIBUTES (a multiple of 4)
            rows = _filter_exponential(rows)
        elif filter == "COLOR":
            rows = _filter_color(rows, stride)
        return rows.tobytes()
    if mode == "TRIANGLES":
        return _decode_triangles(buf, count, stride, fail).astype(f"<u{stride}").tobytes()
    return _decode_indices(buf, count, stride, fail).astype(f"<u{stride}").tobytes()


def _int(obj: dict, key: str, fail, default=None) -> int:
    value = obj.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        fail(f"{key} must be a non-negative integer, got {value!r}")
    return value


def _fallback_ext(buffer) -> str | None:
    """The meshopt extension that marks ``buffer`` as a fallback buffer, or None."""
    exts = buffer.get("extensions") if isinstance(buffer, dict) else None
    if isinstance(exts, dict):
        for ext in EXTENSIONS:
            if isinstance(exts.get(ext), dict) and exts[ext].get("fallback") is True:
                return ext
    return None


def decompress(gltf: dict, buffers: list, name: str, *, into_buffer: int | None = None) -> tuple[dict, list]:
    """Decode every bufferView of ``gltf`` compressed with EXT_/KHR_meshopt_compression.

    ``buffers`` holds the bytes of ``gltf["buffers"]`` in order (a GLB: ``[bin_chunk, ...]``; a
    fallback buffer's entry may be empty or None).  Returns ``(document, buffers)``: a deep copy of the
    document whose compressed views point at their decoded bytes, and the list of buffers those
    live in.  The decoded views are appended, 4-byte aligned, to a new last buffer (no ``uri``),
    or with ``into_buffer=i`` to the end of buffer ``i`` (e.g. 0, a GLB's BIN chunk; its
    ``byteLength`` is updated).  The extension objects are removed from the views and the
    buffers, and the names from ``extensionsUsed`` / ``extensionsRequired``.  Fallback buffers
    keep their place (indices do not move; their bytes may be empty or None, and are returned as
    given or ``b""``) and lose their marker; no view points at them any more (an uncompressed view
    pointing at one, which the spec forbids, is an error when that buffer has no data).

    A document without either extension comes back as it came (the same objects).
    ``name`` starts every error message, which also names the bufferView.
    """
    views = gltf.get("bufferViews")
    used = set(gltf.get("extensionsUsed") or []) | set(gltf.get("extensionsRequired") or [])
    has_ext = isinstance(views, list) and any(
        isinstance(v, dict) and isinstance(v.get("extensions"), dict)
        and any(e in v["extensions"] for e in EXTENSIONS) for v in views)
    marked = any(_fallback_ext(b) for b in gltf.get("buffers") or [] if isinstance(b, dict))
    if not has_ext and not marked and not used & set(EXTENSIONS):
        return gltf, buffers

    doc = copy.deepcopy(gltf)
    json_buffers = doc.get("buffers")
    if not isinstance(json_buffers, list):
        raise InputFormatError(f"{name}: the document has compressed bufferViews but no buffers array")
    out_buffers = [b"" if b is None else b if isinstance(b, (bytes, bytearray)) else bytes(b) for b in buffers]
    fallback = {i for i, b in enumerate(json_buffers) if _fallback_ext(b)}
    decoded: list[tuple[int, bytes]] = []
    total = 0
    for i, view in enumerate(doc.get("bufferViews") or []):
        exts = view.get("extensions") if isinstance(view, dict) else None
        if not isinstance(exts, dict):
            continue
        present = [e for e in EXTENSIONS if e in exts]
        if not present:
            continue
        if len(present) == 2:
            raise InputFormatError(f"{name}: bufferView {i} carries both {EXT} and {KHR}")
        ext_name = present[0]
        obj = exts[ext_name]
        where = [f"{name}: bufferView {i} ({ext_name}"]  # mode and filter join once known

        def fail(msg, where=where):
            raise InputFormatError(f"{where[0]}): {msg}")

        if not isinstance(obj, dict):
            fail("the extension is not an object")
        mode = obj.get("mode")
        if mode not in MODES:
            fail(f"unknown mode {mode!r} (one of {', '.join(MODES)})")
        filt = obj.get("filter", "NONE")
        where[0] += f", {mode}" + (f", {filt}" if filt != "NONE" else "")
        src = _int(obj, "buffer", fail)
        offset = _int(obj, "byteOffset", fail, 0)
        length = _int(obj, "byteLength", fail)
        stride = _int(obj, "byteStride", fail)
        count = _int(obj, "count", fail)
        if src >= len(json_buffers) or src >= len(out_buffers):
            fail(f"buffer {src} does not exist")
        if src in fallback:
            fail(f"its compressed data is in buffer {src}, a fallback buffer")
        parent_length = view.get("byteLength")
        if parent_length != count * stride:
            fail(f"the bufferView's byteLength {parent_length!r} is not count * byteStride = "
                 f"{count:,} * {stride} = {count * stride:,}")
        if ext_name == EXT and "byteStride" in view and view["byteStride"] != stride:
            fail(f"the bufferView's byteStride {view['byteStride']!r} differs from the extension's {stride}")
        have = len(out_buffers[src])
        if offset + length > have:
            fail(f"data ends after {max(0, have - offset):,} of {length:,} bytes "
                 f"(buffer {src} has {have:,})")
        total += count * stride
        if total > MAX_DECODED_TOTAL_BYTES:
            fail(f"the decoded views exceed the {MAX_DECODED_TOTAL_BYTES:,}-byte limit")
        data = memoryview(out_buffers[src])[offset:offset + length]
        decoded.append((i, decode_view(data, count, stride, mode, filt, khr=ext_name == KHR,
                                       where=where[0] + ")")))
        del exts[ext_name]
        if not exts:
            del view["extensions"]

    if decoded:
        if into_buffer is None:
            target = len(json_buffers)
            json_buffers.append({"byteLength": 0})
            out_buffers.append(b"")
        else:
            target = into_buffer
            if not 0 <= target < min(len(json_buffers), len(out_buffers)) or not isinstance(json_buffers[target], dict):
                raise InputFormatError(f"{name}: buffer {target} does not exist")
            if target in fallback:
                raise InputFormatError(f"{name}: buffer {target} is a fallback buffer")
        blob = bytearray(out_buffers[target])
        for i, raw in decoded:
            blob.extend(b"\0" * (-len(blob) % 4))
            view = doc["bufferViews"][i]
            view["buffer"] = target
            view["byteOffset"] = len(blob)
            view["byteLength"] = len(raw)
            blob.extend(raw)
        blob.extend(b"\0" * (-len(blob) % 4))
        out_buffers[target] = bytes(blob)
        json_buffers[target]["byteLength"] = len(blob)

    for i in fallback:  # the spec lets only compressed views point at a fallback buffer
        for j, view in enumerate(doc.get("bufferViews") or []):
            if isinstance(view, dict) and view.get("buffer", None) == i and i < len(out_buffers) \
                    and not out_buffers[i]:
                raise InputFormatError(f"{name}: bufferView {j} has no compression extension but "
                                       f"points at fallback buffer {i}, which has no data")
    for b in json_buffers:
        exts = b.get("extensions") if isinstance(b, dict) else None
        if isinstance(exts, dict):
            for ext in EXTENSIONS:
                exts.pop(ext, None)
            if not exts:
                del b["extensions"]
    for key in ("extensionsUsed", "extensionsRequired"):
        if key in doc:
            doc[key] = [e for e in doc[key] if e not in EXTENSIONS]
            if not doc[key]:
                del doc[key]
    return doc, out_buffers
