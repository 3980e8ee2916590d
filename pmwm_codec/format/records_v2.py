"""Chunk payload version 2: split batches <-> one range-coded stream (spec/bitstream.md §8).

Version 2 codes the SAME batches as version 1 (:mod:`.records`: split vertices, incidence
symbols, final integer values) with models that need the mesh the chunk applies to:

* selection: a mask bit per existing vertex, context (marked lower-id neighbours, valence);
* connectivity: the moved faces of a split as an arc of the split vertex's fan, its start ranked
  by a decoder-side score; fans that are not simple (or larger than :data:`MAX_ARC_FAN`) and
  splits the arc cannot express are coded symbol by symbol (escape);
* geometry: positions predicted in the ring's frame (ring mean moved to ``v``'s height along the
  ring normal), two non-dominant grid axes against the prediction, the dominant axis against the
  ring plane; attributes against the floored ring mean as in version 1.

So encoding and decoding both walk the batches on a :class:`~pmwm_codec.progressive.vsplit.MeshState`:
:func:`pack_chunks` takes the base state and every chunk's batches, :func:`decode_chunk` applies
one chunk's batches to a state as it decodes them.  The coder is :mod:`.rangecoder`; the model
kernels here are numba-compiled (plain Python without numba) and loop per vertex / split, around
numpy over whole batches (incidences, topology: :mod:`..progressive.vsplit`).
"""

from __future__ import annotations

import numpy as np

from ..errors import FormatError, LimitError
from ..progressive.topology import group_order, kernel_helper
from ..progressive.vsplit import SplitBatch, apply_batch, find_incidences, split_topology
from . import rangecoder as rc
from .rangecoder import INT_BLOCK, INT_DECISIONS

PAYLOAD_VERSION = 2
MAX_BATCHES_PER_CHUNK = 4096
#: Fans with more faces than this are coded symbol by symbol (bounds the O(d^2) rank work).
MAX_ARC_FAN = 32
#: Decoded values must stay within ``|x| < 2**31`` (every valid grid is at most 30 bits).
MAX_VALUE = 1 << 31
VALENCE_CLASSES = 7  # valence 3 .. 9+ (<= 3 is class 0)
# probability table layout (spec §8.3)
P_MASK = 0  # 3 neighbour classes x 7 valence classes
P_ESCAPE = 21
P_WING = 22  # + 0 left, + 1 right
P_SYMBOL = 24  # 3-bit tree, nodes 1..7
P_INT = 32
B_BATCHES = 0
B_LENGTH = 1  # + min(d, 16) - 1
B_RANK = 17  # + min(candidates, 16) - 1
B_GEOMETRY = 33  # + class * 3 + role, class 0..31, role 0..2
GEOMETRY_CLASSES = 32
B_ATTRIBUTE = B_GEOMETRY + 3 * GEOMETRY_CLASSES  # + min(component, 7)
ATTRIBUTE_CONTEXTS = 8
INT_BLOCKS = B_ATTRIBUTE + ATTRIBUTE_CONTEXTS
N_PROBS = P_INT + INT_BLOCKS * INT_BLOCK


@kernel_helper
def _block(b):
    """Offset of integer context block ``b`` in the probability table."""
    return P_INT + b * INT_BLOCK


# ---------------------------------------------------------------- selection mask


def _mask_kernel(flat, n, sel, stamp, es, out, ds, buf, probs, decode):
    """Code (``decode`` 0) or decode (1) the mask ``sel`` (n,) int64 of the mesh whose face slots
    are ``flat`` (3m,) int64.

    ``stamp`` (>= n,) int64 scratch.  Context of vertex w: 7 * min(2, marked distinct neighbours
    below w) + clamp(distinct neighbours, 3, 9) - 3.  Returns the number of marked vertices.
    """
    start = np.zeros(n + 1, np.int64)
    for c in range(len(flat)):
        start[flat[c] + 1] += 1
    for w in range(n):
        start[w + 1] += start[w]
    fill = start[:n].copy()
    vf = np.empty(len(flat), np.int64)  # per vertex, the first slot of each of its faces
    for f3 in range(0, len(flat), 3):
        for j in range(3):
            w = flat[f3 + j]
            vf[fill[w]] = f3
            fill[w] += 1
    for w in range(n):
        stamp[w] = -1
    count = 0
    for w in range(n):
        valence = 0
        below = 0
        for t in range(start[w], start[w + 1]):
            f3 = vf[t]
            for j in range(3):
                x = flat[f3 + j]
                if x != w and stamp[x] != w:
                    stamp[x] = w
                    valence += 1
                    if x < w and sel[x] != 0:
                        below += 1
        vclass = min(max(valence, 3), 9) - 3
        ctx = P_MASK + 7 * min(below, 2) + vclass
        if decode:
            sel[w] = rc.dec_bit(ds, buf, probs, ctx)
        else:
            rc.enc_bit(es, out, probs, ctx, sel[w])
        count += sel[w]
    return count


# ---------------------------------------------------------------- connectivity: fans and arcs


@kernel_helper
def _fan(J, a, b, posA, posB, fan):
    """Order the incidences ``J`` (d,) of one split vertex into ``fan`` (d,) (spec §8.5).

    ``posA`` / ``posB`` (>= n,) int64 scratch, all -1 on entry and on return.  Returns 1 closed
    fan, 2 open fan, 0 not simple (then ``fan`` is undefined).
    """
    d = len(J)
    simple = 1
    for t in range(d):
        j = J[t]
        if posA[a[j]] >= 0 or posB[b[j]] >= 0:
            simple = 0
        posA[a[j]] = t
        posB[b[j]] = t
    kind = 0
    if simple:
        first = -1
        starts = 0
        for t in range(d):
            if posB[a[J[t]]] < 0:
                starts += 1
                if first < 0:
                    first = t
        if starts == 0:
            kind, first = 1, 0
        elif starts == 1:
            kind = 2
        if kind != 0:
            t = first
            for s in range(d):
                fan[s] = J[t]
                nxt = posA[b[J[t]]]
                if s < d - 1:
                    if nxt < 0 or nxt == first:
                        kind = 0
                        break
                    t = nxt
                elif kind == 1 and nxt != first:
                    kind = 0
                elif kind == 2 and nxt >= 0:
                    kind = 0
    for t in range(d):
        posA[a[J[t]]] = -1
        posB[b[J[t]]] = -1
    return kind


@kernel_helper
def _arc_rank(fan, d, closed, L, s, a, vv, P, lens, scores, choose):
    """Rank of start ``s`` among the arc's candidate starts (``choose`` < 0), or the start of
    rank ``choose``.  Score of start c: sum over j = 1 .. L-1 of |P[a of fan[(c + j) mod d]] - P[v]|
    (float64, in that order); higher scores first, ties by lower c."""
    for t in range(d):
        x = P[a[fan[t]], 0] - P[vv, 0]
        y = P[a[fan[t]], 1] - P[vv, 1]
        z = P[a[fan[t]], 2] - P[vv, 2]
        fx, fy, fz = np.float64(x), np.float64(y), np.float64(z)
        lens[t] = np.sqrt((fx * fx + fy * fy) + fz * fz)
    ncand = d if closed else d - L + 1
    for c in range(ncand):
        sc = 0.0
        for j in range(1, L):
            sc += lens[(c + j) % d]
        scores[c] = sc
    if choose < 0:
        r = 0
        for c in range(ncand):
            if scores[c] > scores[s] or (scores[c] == scores[s] and c < s):
                r += 1
        return r
    for c in range(ncand):
        r = 0
        for c2 in range(ncand):
            if scores[c2] > scores[c] or (scores[c2] == scores[c] and c2 < c):
                r += 1
        if r == choose:
            return c
    return -1


@kernel_helper
def _arc_symbol(t, L, left, right):
    """Symbol of the t-th moved face of an arc of L faces with the given wings."""
    return 1 + (1 if (t == 0 and left) else 0) + (2 if (t == L - 1 and right) else 0)


@kernel_helper
def _arc_of(fan, d, kind, sym):
    """The arc (s, L, left, right) the symbols of a fan form, or s = -1 when they form none."""
    L = 0
    for t in range(d):
        if sym[fan[t]] != 0:
            L += 1
    s = -1
    if L == 0:
        return -1, 0, 0, 0
    if L == d and kind == 1:
        for t in range(d):
            if sym[fan[t]] == 2 or sym[fan[t]] == 4:
                s = t
                break
    else:
        for t in range(d):
            prev_moved = sym[fan[(t + d - 1) % d]] != 0 if (t > 0 or kind == 1) else False
            if sym[fan[t]] != 0 and not prev_moved:
                if s >= 0:
                    return -1, 0, 0, 0
                s = t
    if s < 0:
        return -1, 0, 0, 0
    left = 1 if (sym[fan[s]] == 2 or sym[fan[s]] == 4) else 0
    last = fan[(s + L - 1) % d]
    right = 1 if (sym[last] == 3 or sym[last] == 4) else 0
    if kind == 1 and (left == 0 or right == 0):
        return -1, 0, 0, 0
    if kind == 2 and ((s > 0 and left == 0) or (s + L < d and right == 0)):
        return -1, 0, 0, 0
    for t in range(d):  # the arc must rebuild every symbol
        inside = (t - s) % d
        want = _arc_symbol(inside, L, left, right) if inside < L else 0
        if sym[fan[t]] != want:
            return -1, 0, 0, 0
    return s, L, left, right


def _connectivity_kernel(gstart, gidx, a, b, v, P, sym, posA, posB, es, out, ds, buf, probs, decode):
    """Code or decode the incidence symbols ``sym`` (I,) uint8 of a batch, split by split.

    ``gidx[gstart[i]:gstart[i+1]]``: split i's incidences in face-slot order; ``a`` / ``b`` (I,)
    the corners after / before the split vertex.  Returns 0, or (decode) -1 on an invalid code.
    """
    k = len(v)
    fan = np.empty(MAX_ARC_FAN, np.int64)
    lens = np.empty(MAX_ARC_FAN, np.float64)
    scores = np.empty(MAX_ARC_FAN, np.float64)
    for i in range(k):
        J = gidx[gstart[i]:gstart[i + 1]]
        d = len(J)
        kind = _fan(J, a, b, posA, posB, fan) if 0 < d <= MAX_ARC_FAN else 0
        s, L, left, right = -1, 0, 0, 0
        if kind != 0:
            if decode:
                escape = rc.dec_bit(ds, buf, probs, P_ESCAPE)
            else:
                s, L, left, right = _arc_of(fan, d, kind, sym)
                escape = 1 if s < 0 else 0
                rc.enc_bit(es, out, probs, P_ESCAPE, escape)
        else:
            escape = 1
        if escape:
            for t in range(d):
                if decode:
                    x = rc.dec_tree(ds, buf, probs, P_SYMBOL, 3)
                    if x >= 5:
                        return -1
                    sym[J[t]] = x
                else:
                    rc.enc_tree(es, out, probs, P_SYMBOL, 3, sym[J[t]])
            continue
        len_ctx = _block(B_LENGTH + min(d, 16) - 1)
        if decode:
            L = rc.dec_uint(ds, buf, probs, len_ctx) + 1
            if L < 1 or L > d:
                return -1
        else:
            rc.enc_uint(es, out, probs, len_ctx, L - 1)
        ncand = d if kind == 1 else d - L + 1
        rank_ctx = _block(B_RANK + min(ncand, 16) - 1)
        if decode:
            r = rc.dec_uint(ds, buf, probs, rank_ctx)
            if r < 0 or r >= ncand:
                return -1
            s = _arc_rank(fan, d, kind == 1, L, 0, a, v[i], P, lens, scores, r)
        else:
            rc.enc_uint(es, out, probs, rank_ctx, _arc_rank(fan, d, kind == 1, L, s, a, v[i], P, lens, scores, -1))
        if kind == 1:
            left, right = 1, 1
        else:
            if s == 0:
                if decode:
                    left = rc.dec_bit(ds, buf, probs, P_WING)
                else:
                    rc.enc_bit(es, out, probs, P_WING, left)
            else:
                left = 1
            if s + L == d:
                if decode:
                    right = rc.dec_bit(ds, buf, probs, P_WING + 1)
                else:
                    rc.enc_bit(es, out, probs, P_WING + 1, right)
            else:
                right = 1
        if decode:
            for t in range(d):
                inside = (t - s) % d
                sym[fan[t]] = _arc_symbol(inside, L, left, right) if inside < L else 0
    return 0


# ---------------------------------------------------------------- geometry


@kernel_helper
def _floor_half(x):
    """floor(x + 0.5) as int64."""
    return np.int64(np.floor(x + 0.5))


def _geometry_kernel(gstart, gidx, a, b, v, sym, P, n0, es, out, ds, buf, probs, decode):
    """Code (from ``P[n0 + i]``) or decode (into it) the values of the new vertices, split by split.

    Returns 0, or (decode) -1 on an invalid code / a value outside ``|x| < 2**31``.
    """
    k = len(v)
    D = P.shape[1]
    S = np.zeros(D, np.int64)
    frame = np.empty((3, 3), np.float64)  # scratch rows: ring mean m, normal n, prediction ph
    for i in range(k):
        vv = v[i]
        S[:] = 0
        c = 0
        ell = 0
        nx, ny, nz = 0.0, 0.0, 0.0
        for t in range(gstart[i], gstart[i + 1]):
            j = gidx[t]
            s = sym[j]
            if s == 0:
                continue
            aj, bj = a[j], b[j]
            for q in range(D):
                S[q] += P[aj, q] + P[bj, q]
            c += 1
            ell += abs(P[aj, 0] - P[bj, 0]) + abs(P[aj, 1] - P[bj, 1]) + abs(P[aj, 2] - P[bj, 2])
            e1x, e1y, e1z = np.float64(P[aj, 0] - P[vv, 0]), np.float64(P[aj, 1] - P[vv, 1]), np.float64(P[aj, 2] - P[vv, 2])
            e2x, e2y, e2z = np.float64(P[bj, 0] - P[vv, 0]), np.float64(P[bj, 1] - P[vv, 1]), np.float64(P[bj, 2] - P[vv, 2])
            nx += e1y * e2z - e1z * e2y
            ny += e1z * e2x - e1x * e2z
            nz += e1x * e2y - e1y * e2x
            for w in range(2):
                if (w == 0 and (s == 2 or s == 4)) or (w == 1 and (s == 3 or s == 4)):
                    o = aj if w == 0 else bj
                    for q in range(D):
                        S[q] += P[vv, q] + P[o, q]
                    c += 1
                    ell += abs(P[vv, 0] - P[o, 0]) + abs(P[vv, 1] - P[o, 1]) + abs(P[vv, 2] - P[o, 2])
        if c == 0:
            return -1
        status = _split_values(S, c, ell, nx, ny, nz, vv, n0 + i, P, frame, es, out, ds, buf, probs, decode)
        if status != 0:
            return status
    return 0


@kernel_helper
def _split_values(S, c, ell, nx, ny, nz, vv, u, P, frame, es, out, ds, buf, probs, decode):
    """One new vertex ``u``: frame prediction, then its D values coded / decoded in order
    (``frame`` (3, 3) float64 scratch)."""
    D = P.shape[1]
    cls = min(rc.bit_length(ell // c), GEOMETRY_CLASSES - 1)
    two_c = np.float64(2 * c)
    m, nv, ph = frame[0], frame[1], frame[2]
    for q in range(3):
        m[q] = np.float64(S[q]) / two_c
    nv[0], nv[1], nv[2] = nx, ny, nz
    nn = (nx * nx + ny * ny) + nz * nz
    dom, ax0, ax1 = 2, 0, 1
    if nn > 0.0:
        h = (((np.float64(P[vv, 0]) - m[0]) * nx + (np.float64(P[vv, 1]) - m[1]) * ny)
             + (np.float64(P[vv, 2]) - m[2]) * nz) / nn
        for q in range(3):
            ph[q] = m[q] + h * nv[q]
        if abs(nx) >= abs(ny) and abs(nx) >= abs(nz):
            dom, ax0, ax1 = 0, 1, 2
        elif abs(ny) >= abs(nz):
            dom, ax0, ax1 = 1, 0, 2
    else:
        for q in range(3):
            ph[q] = m[q]
    base = _block(B_GEOMETRY + 3 * cls)
    for role in range(3):
        q = ax0 if role == 0 else (ax1 if role == 1 else dom)
        if role < 2 or nn == 0.0:
            pred = _floor_half(ph[q])
        else:
            x0 = np.float64(P[u, ax0]) - ph[ax0]
            x1 = np.float64(P[u, ax1]) - ph[ax1]
            pred = _floor_half(ph[q] - (x0 * nv[ax0] + x1 * nv[ax1]) / nv[q])
        if _value(pred, base + role * INT_BLOCK, q, u, P, es, out, ds, buf, probs, decode) != 0:
            return -1
    for q in range(3, D):
        pred = S[q] // (2 * c)
        ctx = _block(B_ATTRIBUTE + min(q - 3, ATTRIBUTE_CONTEXTS - 1))
        if _value(pred, ctx, q, u, P, es, out, ds, buf, probs, decode) != 0:
            return -1
    return 0


@kernel_helper
def _value(pred, ctx, q, u, P, es, out, ds, buf, probs, decode):
    """Value ``q`` of vertex ``u``: residual against ``pred`` coded from / decoded into ``P[u, q]``."""
    if decode:
        r, ok = rc.dec_sint(ds, buf, probs, ctx)
        x = pred + r
        if ok == 0 or x >= MAX_VALUE or x <= -MAX_VALUE:
            return -1
        P[u, q] = x
    else:
        rc.enc_sint(es, out, probs, ctx, P[u, q] - pred)
    return 0


# ---------------------------------------------------------------- chunks


def _grouped(state, v):
    """Incidences of the split vertices ``v`` in the mesh before the batch, grouped by split.

    Returns ``(inc (I,), owner (I,), gstart (k+1,), gidx (I,), a (I,), b (I,))`` int64: the
    incidences in face-slot order and their owners (:func:`find_incidences`), split i's
    incidences ``gidx[gstart[i]:gstart[i+1]]`` in face-slot order, and every incidence's corners
    after / before its vertex.
    """
    inc, owner = find_incidences(state, v)
    owner = np.asarray(owner, np.int64)
    flat = state.faces[: state.m].reshape(-1)
    base = inc - inc % 3
    a = flat[base + (inc + 1) % 3]
    b = flat[base + (inc + 2) % 3]
    gidx = group_order(owner, len(v))
    gstart = np.zeros(len(v) + 1, np.int64)
    np.cumsum(np.bincount(owner, minlength=len(v)), out=gstart[1:])
    return inc, owner, gstart, gidx, a, b


def _connectivity_decisions(incidences: int, splits: int) -> int:
    return 3 * incidences + splits * (3 + 2 * INT_DECISIONS)


_NO_BYTES = np.zeros(0, np.uint8)
_NO_STATE = np.zeros(6, np.int64)


def _encode_batch(enc, state, batch, scratch) -> None:
    """Code one batch into ``enc`` and apply it to ``state`` (version 1 semantics)."""
    n, k = state.n, batch.size
    sel = np.zeros(n, np.int64)
    sel[batch.v] = 1
    enc.reserve(n)
    rc._kernel(_mask_kernel)(state.faces[: state.m].reshape(-1), n, sel, scratch, enc.es, enc.out, _NO_STATE, _NO_BYTES,
                             enc.probs, 0)
    inc, owner, gstart, gidx, a, b = _grouped(state, batch.v)
    sym = np.asarray(batch.symbols, np.uint8)
    posA, posB = np.full(n, -1, np.int64), np.full(n, -1, np.int64)
    enc.reserve(_connectivity_decisions(len(inc), k))
    rc._kernel(_connectivity_kernel)(gstart, gidx, a, b, np.asarray(batch.v, np.int64), state.positions, sym,
                                     posA, posB, enc.es, enc.out, _NO_STATE, _NO_BYTES, enc.probs, 0)
    n0 = state.n
    topo = apply_batch(state, batch)
    if not np.array_equal(topo.incidences, inc):
        raise AssertionError("payload v2: incidences changed under the encoder")
    enc.reserve(k * state.positions.shape[1] * INT_DECISIONS)
    rc._kernel(_geometry_kernel)(gstart, gidx, a, b, np.asarray(batch.v, np.int64), sym, state.positions, n0,
                                 enc.es, enc.out, _NO_STATE, _NO_BYTES, enc.probs, 0)


def pack_chunks(state, chunks) -> list:
    """Encode every chunk of one primitive.

    ``state``: the primitive's :class:`~pmwm_codec.progressive.vsplit.MeshState` at the base
    (int64 values, D columns), advanced through every batch; ``chunks``: list of lists of
    :class:`SplitBatch`, coarse to fine.  Returns one ``bytes`` payload per chunk.
    """
    out = []
    probs = new_model()
    for batches in chunks:
        if not 1 <= len(batches) <= MAX_BATCHES_PER_CHUNK:
            raise ValueError(f"payload v2: {len(batches)} batches in a chunk, outside 1..{MAX_BATCHES_PER_CHUNK}")
        enc = rc.Encoder(probs)
        enc.reserve(INT_DECISIONS)
        rc._kernel(rc._enc_array_kernel)(enc.es, enc.out, enc.probs, np.array([2]), np.array([_block(B_BATCHES)]),
                                         np.array([len(batches) - 1]))
        scratch = np.empty(state.n + sum(b.size for b in batches), np.int64)
        for batch in batches:
            _encode_batch(enc, state, batch, scratch)
        out.append(enc.finish())
    return out


def new_model() -> np.ndarray:
    """The probability table of a primitive's first chunk: (N_PROBS,) int64, every entry 1024.
    Each chunk continues the table the chunk before it (of the same primitive) left."""
    return rc.new_probs(N_PROBS)


def decode_chunk(payload, state, probs):
    """Decode one chunk against ``state`` (int64 values), applying each batch as it is decoded;
    ``probs`` is the primitive's probability table (:func:`new_model`, updated in place).

    Yields ``(SplitBatch, SplitTopology)`` per batch: the batch in version 1 terms (split
    vertices, incidence symbols, residuals against the version 1 prediction) and what
    :func:`~pmwm_codec.progressive.vsplit.split_topology` did.  FormatError / LimitError on any
    invalid code, count or termination.
    """
    dec = rc.Decoder(payload, probs)
    count = np.zeros(1, np.int64)
    if rc._kernel(rc._dec_array_kernel)(dec.ds, dec.buf, dec.probs, np.array([2]), np.array([_block(B_BATCHES)]), count):
        raise FormatError("chunk payload: invalid batch count")
    batches = int(count[0]) + 1
    if batches > MAX_BATCHES_PER_CHUNK:
        raise LimitError(f"chunk payload: batch count {batches} outside 1..{MAX_BATCHES_PER_CHUNK}")
    for _ in range(batches):
        yield _decode_batch(dec, state)
    dec.finish()


def _decode_batch(dec, state):
    n = state.n
    sel = np.zeros(n, np.int64)
    k = rc._kernel(_mask_kernel)(state.faces[: state.m].reshape(-1), n, sel, np.empty(n, np.int64), _NO_STATE, _NO_BYTES,
                                 dec.ds, dec.buf, dec.probs, 1)
    if k == 0:
        raise FormatError("chunk payload: a batch marks no split vertex")
    if n + k > len(state.positions):
        raise FormatError("splits exceed the declared vertex count")
    v = np.flatnonzero(sel).astype(np.int64)
    inc, owner, gstart, gidx, a, b = _grouped(state, v)
    sym = np.zeros(len(inc), np.uint8)
    posA, posB = np.full(n, -1, np.int64), np.full(n, -1, np.int64)
    if rc._kernel(_connectivity_kernel)(gstart, gidx, a, b, v, state.positions, sym, posA, posB, _NO_STATE,
                                        _NO_BYTES, dec.ds, dec.buf, dec.probs, 1):
        raise FormatError("chunk payload: invalid connectivity code")
    n0 = state.n
    topo = split_topology(state, v, sym, incidences=(inc, owner))
    if rc._kernel(_geometry_kernel)(gstart, gidx, a, b, v, sym, state.positions, n0, _NO_STATE, _NO_BYTES,
                                    dec.ds, dec.buf, dec.probs, 1):
        raise FormatError("chunk payload: invalid value code or a value out of range")
    values = state.positions[topo.u]
    return SplitBatch(v, sym, values - topo.prediction()), topo
