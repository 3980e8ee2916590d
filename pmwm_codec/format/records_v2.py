"""Chunk payload version 2: split batches <-> one range-coded stream (spec/bitstream.md §8).

Version 2 codes the SAME batches as version 1 (:mod:`.records`: split vertices, incidence
symbols, final integer values) with models that need the mesh the chunk applies to:

* selection: a mask bit per existing vertex, context (marked lower-id neighbours, valence);
* connectivity: the moved faces of a split as an arc of the split vertex's fan, its start ranked
  by a decoder-side score; fans that are not simple (or larger than :data:`MAX_ARC_FAN`) and
  splits the arc cannot express are coded symbol by symbol (escape);
* geometry: positions predicted in the ring's frame (ring mean moved to ``v``'s height along the
  ring normal), two non-dominant grid axes against the prediction, the dominant axis against the
  ring plane; attributes against the floored ring mean as in version 1, or (``"prediction":
  "plane"``) against the affine function of the position fitted over the ring
  (:func:`_plane_prediction`), in contexts of the ring's spread.

So encoding and decoding both walk the batches on a :class:`~pmwm_codec.progressive.vsplit.MeshState`:
:func:`pack_chunks` takes the base state and every chunk's batches, :func:`decode_chunk` applies
one chunk's batches to a state as it decodes them.  The coder is :mod:`.rangecoder`; the model
kernels here are numba-compiled (plain Python without numba, same results, slow) and loop per
vertex / split.  Both sides read the mesh through :class:`CornerLists` (every vertex's corners,
its valence).  The decoder (:class:`ChunkDecoder`, one per primitive) keeps them from chunk to
chunk and updates them with each batch, so a batch costs two kernel calls and work in proportion
to its splits plus one mask bit per vertex: :func:`_mask_kernel` (marks, gathering the marked
vertices' incidences on the way) and :func:`_batch_kernel` (arcs, topology, values, valences).
The encoder (:class:`ChunkPacker`) walks the same two kernels in encode mode on lists it keeps
from batch to batch (made once for the base), so it leaves the mesh the decoder builds; the record
builder (:func:`~pmwm_codec.progressive.build.build_progressive` with ``chunks``) replays the
simplifier's log through it, so an encode walks the mesh once.
"""

from __future__ import annotations

import sys
from functools import cached_property

import numpy as np

from ..errors import FormatError, LimitError
from ..progressive import topology
from ..progressive.topology import compiled, face_keys, kernel_helper
from ..progressive.vsplit import SplitBatch, SplitTopology, _ring_lists
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
#: Attributes predicted on the ring's plane (an extension ``attributes`` entry with ``"prediction":
#: "plane"``, spec §8.4.3): + min(component, 7) * PLANE_CLASSES + the ring's spread class 0 .. 15.
B_PLANE = B_ATTRIBUTE + ATTRIBUTE_CONTEXTS
PLANE_CLASSES = 16
#: Below this fraction of the product of its diagonal, the plane fit's determinant counts as singular
#: (spec §8.4.3): the ring mean predicts instead.
PLANE_SINGULAR = 2.0 ** -20
INT_BLOCKS = B_PLANE + ATTRIBUTE_CONTEXTS * PLANE_CLASSES
N_PROBS = P_INT + INT_BLOCKS * INT_BLOCK


@kernel_helper
def _block(b):
    """Offset of integer context block ``b`` in the probability table."""
    return P_INT + b * INT_BLOCK


# ---------------------------------------------------------------- corner lists and the selection mask


class CornerLists:
    """Every vertex's corners (the face slots holding it) as ascending linked lists in arrays with room
    to spare, with every vertex's valence (spec §8.4.1): the adjacency the models read.

    ``head`` / ``tail`` (N,) int32 first / last corner of a vertex (-1: none), ``nxt`` (3M,) int32
    the next corner of the same vertex (-1: the last); ``valence`` (N,) int64 the number of
    distinct other vertices sharing a face with each vertex; scratch: ``below`` (N,) int64 zeros
    (:data:`BELOW_BITS`), ``stamp`` / ``tag`` (N,) int64 with their token counter ``ctr`` (1,)
    int64, ``split`` (N,) uint8 zeros, ``created`` ((3M + 31) // 32,) int64 zeros (a bitmap over
    the corners, 32 bits a word) and ``creator`` (3M,) int32 (:func:`_link_splits`).  N / M: the
    capacity of the primitive's :class:`~pmwm_codec.progressive.vsplit.MeshState` (:meth:`grow`
    follows it).  ``n`` / ``m``: the mesh they describe; :meth:`sync` rebuilds them (O(m)) for a mesh
    that changed elsewhere, the decoder updates them batch by batch (O(batch)).
    """

    def __init__(self, vertex_capacity: int, face_capacity: int):
        N, M = int(vertex_capacity), int(face_capacity)
        self.head, self.tail = np.full(N, -1, np.int32), np.full(N, -1, np.int32)
        self.nxt = np.full(3 * M, -1, np.int32)  # corners < 3 * MAX_FACES < 2**31
        self.valence, self.tag, self.split = np.zeros(N, np.int64), np.zeros(N, np.int64), np.zeros(N, np.uint8)
        self.below, self.stamp, self.ctr = np.zeros(N, np.int64), np.zeros(N, np.int64), np.zeros(1, np.int64)
        self.created, self.creator = np.zeros((3 * M + 31) // 32, np.int64), np.empty(3 * M, np.int32)
        self.n = self.m = -1

    def fits(self, state) -> bool:
        return len(self.head) == len(state.positions) and len(self.nxt) == 3 * len(state.faces)

    def grow(self, state) -> None:
        """Room for ``state``'s arrays after they grew (:meth:`~pmwm_codec.progressive.vsplit.MeshState.reserve`):
        every array copied into a longer one, its new part as a new one's (-1 / zeros); ``creator`` (scratch) is
        not carried over."""
        N, M = len(state.positions), len(state.faces)
        for name in ("head", "tail", "valence", "tag", "split", "below", "stamp"):
            setattr(self, name, _longer(getattr(self, name), N, -1 if name in ("head", "tail") else 0))
        self.nxt = _longer(self.nxt, 3 * M, -1)
        if len(self.creator) < 3 * M:  # scratch read only where a batch wrote it: nothing to carry over
            self.creator = np.empty(3 * M, np.int32)
        self.created = _longer(self.created, (3 * M + 31) // 32, 0)

    def sync(self, state) -> None:
        """Describe ``state``'s current mesh (rebuilt unless it is the mesh they already describe)."""
        if (self.n, self.m) != (state.n, state.m):
            rc._kernel(_corner_lists_kernel)(state.faces[: state.m].reshape(-1), state.n, self.head, self.tail,
                                             self.nxt, self.valence, self.stamp, self.ctr)
            self.n, self.m = state.n, state.m


def _longer(values: np.ndarray, size: int, fill) -> np.ndarray:
    """(size,) ``values`` then ``fill`` (``values`` itself when it is that long already)."""
    if len(values) >= size:
        return values
    if fill == 0:  # zeroed pages from the allocator: those never written are never touched
        out = np.zeros(size, values.dtype)
    else:
        out = np.empty(size, values.dtype)
        out[len(values) :] = fill
    out[: len(values)] = values
    return out


def _corner_lists_kernel(flat, n, head, tail, nxt, valence, stamp, ctr):
    """Build the lists of :class:`CornerLists` for the faces ``flat`` (3m,) over ``n`` vertices."""
    for w in range(n):
        head[w] = -1
        tail[w] = -1
    for c in range(len(flat)):
        _append_corner(flat[c], c, head, tail, nxt)
    for w in range(n):
        valence[w] = _valence(w, flat, head, nxt, stamp, ctr)
    return 0


@kernel_helper
def _append_corner(w, c, head, tail, nxt):
    """Put corner ``c`` (larger than every corner of ``w``'s list) at the end of ``w``'s list."""
    nxt[c] = -1
    if head[w] < 0:
        head[w] = c
    else:
        nxt[tail[w]] = c
    tail[w] = c


@kernel_helper
def _valence(w, flat, head, nxt, stamp, ctr):
    """|N(w)|: the distinct vertices other than ``w`` sharing a face with it."""
    token = ctr[0] + 1
    ctr[0] = token
    valence = 0
    c = head[w]
    while c >= 0:
        f3 = c - c % 3
        for j in range(3):
            x = flat[f3 + j]
            if x != w and stamp[x] != token:
                stamp[x] = token
                valence += 1
        c = nxt[c]
    return valence


#: ``below[x]`` (:func:`_mask_kernel`): the marked distinct neighbours below x, counted up to 2, in
#: its low bits; above them the last marked vertex w that counted x, as w + 1 (tells its corners apart).
BELOW_BITS = 2
#: How many vertices ahead :func:`_mask_kernel` asks for a vertex's first corner, and half as far its second
#: (:data:`PREFETCH_VERTICES`).
MASK_AHEAD = 16


@kernel_helper
def _mark_above(w, t, flat, head, nxt, below, inc, a, b):
    """List ``w``'s corners from ``t`` on as its split's incidences (:func:`_batch_kernel`) and
    count ``w`` in ``below`` (:data:`BELOW_BITS`) once for each distinct neighbour ``x > w``;
    returns the next ``t``."""
    start = t
    c = head[w]
    while c >= 0:  # no branch on what the faces hold: the face loads of the corners overlap
        f3 = c - c % 3
        inc[t], a[t], b[t] = c, flat[f3 + (c + 1) % 3], flat[f3 + (c + 2) % 3]
        t += 1
        c = nxt[c]
    mark = (w + 1) << BELOW_BITS
    for s in range(start, t):
        for z in (a[s], b[s]):
            if z > w and below[z] & -(1 << BELOW_BITS) != mark:
                below[z] = mark | min((below[z] & ((1 << BELOW_BITS) - 1)) + 1, 2)
    return t


@kernel_helper
def _mask_kernel(flat, n, head, nxt, valence, below, sel, marked, gstart, inc, a, b, es, out, ds, buf, probs, decode):
    """Code (``decode`` 0, the bits ``sel`` (n,) int64) or decode (1) a batch's selection mask over the
    mesh of the corner lists (:class:`CornerLists` arrays, ``flat`` (3M,) int64 its face slots).

    Context of vertex w: 7 * min(2, marked distinct neighbours below w) + clamp(valence, 3, 9) - 3; the
    marks push to the neighbours above them as they are coded (``below``, zeros on entry and on
    return).  ``marked`` (cap,) int64 receives the marked vertices, ascending, and ``gstart``
    (cap + 1,) / ``inc`` / ``a`` / ``b`` (3m,) int64 their incidences as
    :func:`_batch_kernel` takes them (gathered on the way).  Returns ``(k, incidences)``; k = -1
    when more than ``cap`` vertices are marked.
    """
    k = 0
    corners = 0
    ahead = len(head) >= PREFETCH_VERTICES
    rng, code, pos = (ds[0], ds[1], ds[2]) if decode else (0, 0, 0)  # the coder state in registers
    for w in range(n):
        if ahead and w + MASK_AHEAD < n:  # later vertices' first corners and their faces, in case they are marked
            _prefetch_corner(head[w + MASK_AHEAD], flat, nxt)
            c = head[w + MASK_AHEAD // 2]  # a nearer one's second corner (its first asked for above, earlier)
            if c >= 0:
                _prefetch_corner(nxt[c], flat, nxt)
        ctx = P_MASK + 7 * (below[w] & ((1 << BELOW_BITS) - 1)) + min(max(valence[w], 3), 9) - 3
        below[w] = 0
        if decode:
            bit, rng, code, pos = rc._bit(rng, code, pos, ds, buf, probs, ctx)
        else:
            bit = sel[w]
            rc.enc_bit(es, out, probs, ctx, bit)
        if bit == 0:
            continue
        if k == len(marked):
            for x in range(n):
                below[x] = 0
            k = -1
            break
        marked[k] = w
        gstart[k] = corners
        corners = _mark_above(w, corners, flat, head, nxt, below, inc, a, b)
        k += 1
    if decode:
        ds[0], ds[1], ds[2] = rng, code, pos
    if k >= 0:
        gstart[k] = corners
    return k, corners


@kernel_helper(inline=True)
def _prefetch_corner(c, flat, nxt):
    """:func:`~pmwm_codec.progressive.topology.prefetch` of corner ``c``'s successor and face (nothing for ``c`` < 0)."""
    if c >= 0:
        topology.prefetch(nxt, c)
        topology.prefetch(flat, c - c % 3)


#: Meshes with room for at least this many vertices (the length of the decoder's arrays, which grow with
#: the decoded mesh) outgrow the processor's caches: the kernels then ask for the next split's scattered
#: rows while they work on a split (:func:`_prefetch_rows`).  Below it the rows are mostly cached and the
#: requests only cost time.
PREFETCH_VERTICES = 1 << 16


@kernel_helper(inline=True)
def _prefetch_rows(array, index, lo, hi):
    """:func:`~pmwm_codec.progressive.topology.prefetch` of ``array[index[t]]`` for ``t`` in ``lo .. hi - 1``."""
    for t in range(lo, hi):
        topology.prefetch(array, index[t])


# ---------------------------------------------------------------- connectivity: fans and arcs


#: The hash of a fan's corners ``a`` (:func:`_fan`): 2**FAN_BITS slots, at most half full.
FAN_BITS = 6
FAN_SLOTS = 1 << FAN_BITS
#: Layout of :func:`_fan`'s scratch ``work`` (int64): successors, predecessor flags, then the
#: slots' keys, incidences and epochs.
W_SUCC, W_PRED = 0, MAX_ARC_FAN
W_KEY, W_INDEX, W_EPOCH = 2 * MAX_ARC_FAN, 2 * MAX_ARC_FAN + FAN_SLOTS, 2 * MAX_ARC_FAN + 2 * FAN_SLOTS
FAN_WORK = 2 * MAX_ARC_FAN + 3 * FAN_SLOTS


@kernel_helper
def _fan_slot(x):
    """The first slot of corner ``x`` in :func:`_fan`'s hash (multiplicative hashing)."""
    return ((x * 0x9E3779B1) & 0xFFFFFFFF) >> (32 - FAN_BITS)


@kernel_helper
def _fan(lo, d, a, b, fan, work, epoch):
    """Order the ``d <= MAX_ARC_FAN`` incidences ``lo .. lo + d - 1`` of one split vertex into
    ``fan`` (d,) int64 (spec §8.4.2).  ``work`` (FAN_WORK,) int64 scratch, zeros when first used;
    ``epoch`` > 0 marks the hash slots of this call (a value no earlier call on ``work`` used).

    The corners ``a`` are hashed: a repeated ``a`` fails at once, and the successor of t is the
    incidence whose ``a`` is ``b[t]``.  With distinct ``a``, a successor named twice means two equal
    ``b``; any other repeated ``b`` (with no successor) leaves two ends to the walk, which then
    fails: so the spec's conditions hold exactly when these checks and the walk pass.
    Returns 1 closed fan, 2 open fan, 0 not simple (then ``fan`` is undefined).
    """
    for t in range(d):
        x = a[lo + t]
        h = _fan_slot(x)
        while work[W_EPOCH + h] == epoch:
            if work[W_KEY + h] == x:
                return 0  # corners after the vertex repeat
            h = (h + 1) & (FAN_SLOTS - 1)
        work[W_EPOCH + h], work[W_KEY + h], work[W_INDEX + h] = epoch, x, t
        work[W_PRED + t] = 0
    for t in range(d):
        y = b[lo + t]
        nx = -1
        h = _fan_slot(y)
        while work[W_EPOCH + h] == epoch:
            if work[W_KEY + h] == y:
                nx = work[W_INDEX + h]
                if work[W_PRED + nx] != 0:
                    return 0  # corners before the vertex repeat
                work[W_PRED + nx] = 1
                break
            h = (h + 1) & (FAN_SLOTS - 1)
        work[W_SUCC + t] = nx
    first = -1
    starts = 0
    for t in range(d):  # t starts the walk when no b equals its a
        if work[W_PRED + t] == 0:
            starts += 1
            if first < 0:
                first = t
    if starts > 1:
        return 0
    kind = 2 if starts == 1 else 1
    if kind == 1:
        first = 0
    t = first
    for s in range(d):
        fan[s] = lo + t
        nx = work[W_SUCC + t]
        if s < d - 1:
            if nx < 0 or nx == first:
                return 0
            t = nx
        elif (kind == 1 and nx != first) or (kind == 2 and nx >= 0):
            return 0
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
    best, best_score = 0, -1.0  # the start of rank 0 (the first of highest score), found on the way
    for c in range(ncand):
        sc = 0.0
        t = c
        for _ in range(1, L):
            t = t + 1 if t + 1 < d else 0  # (c + j) mod d
            sc += lens[t]
        scores[c] = sc
        if sc > best_score:
            best, best_score = c, sc
    if choose < 0:
        r = 0
        for c in range(ncand):
            if scores[c] > scores[s] or (scores[c] == scores[s] and c < s):
                r += 1
        return r
    # the start of rank `choose` in choose more passes (mostly none or one): each takes the first start
    # of highest score among those after the previous pass's in rank order (scores are finite and >= 0)
    for _ in range(choose):
        prev, prev_score = best, best_score
        best = -1
        for c in range(ncand):
            sc = scores[c]
            if (sc < prev_score or (sc == prev_score and c > prev)) and (best < 0 or sc > best_score):
                best, best_score = c, sc
        if best < 0:
            return -1
    return best


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


@kernel_helper
def _connectivity_kernel(gstart, a, b, v, P, sym, S, ring, nrm, arc, fan, work, lens, scores, es, out, ds, buf, probs,
                         decode):
    """Code or decode the incidence symbols ``sym`` (I,) uint8 of a batch, split by split, and
    take each split's ring statistics (:func:`_ring_stats`) while its rows are at hand.

    ``gstart[i] .. gstart[i+1] - 1``: split i's incidences in face-slot order; ``a`` / ``b`` (I,)
    the corners after / before the split vertex.  Fills ``S`` (k, D) int64, ``ring`` (k, 2) int64,
    ``nrm`` (k, 3) float64 and ``arc`` (k, 3) int64 (:func:`_split_symbols`).  Scratch: ``fan`` (MAX_ARC_FAN,)
    int64, ``work`` (FAN_WORK,) int64 zeros (:func:`_fan`), ``lens`` / ``scores`` (MAX_ARC_FAN,) float64
    (:func:`_arc_rank`).  Returns 0, or (decode) -1 on an invalid code.
    """
    ahead = len(P) >= PREFETCH_VERTICES
    for i in range(len(v)):
        lo, hi = gstart[i], gstart[i + 1]
        if ahead and i + 1 < len(v):  # the next split's ring values, loaded while this split is worked on
            _prefetch_rows(P, a, hi, gstart[i + 2])
        if _split_symbols(lo, hi, v[i], a, b, P, sym, fan, work, i + 1, lens, scores, arc[i], es, out, ds, buf,
                          probs, decode) != 0:
            return -1
        _ring_stats(lo, hi, a, b, v[i], sym, P, S, ring, nrm, i)
    return 0


@kernel_helper(inline=True)
def _split_symbols(lo, hi, vv, a, b, P, sym, fan, work, epoch, lens, scores, arc, es, out, ds, buf, probs, decode):
    """Code or decode the symbols of one split's incidences ``lo .. hi - 1`` (spec §8.4.2); 0, or -1 on an
    invalid code.  ``fan`` / ``work`` / ``epoch``: :func:`_fan`'s.  ``arc`` (3,) int64: when the
    symbols are the arc of a closed fan, the incidence of its first moved face, that of the first
    face after it (-1 when every face moves) and its length (:func:`_arc_valences`); else -1."""
    arc[0] = -1
    d = hi - lo
    kind = _fan(lo, d, a, b, fan, work, epoch) if 0 < d <= MAX_ARC_FAN else 0
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
        for t in range(lo, hi):
            if decode:
                x = rc.dec_tree(ds, buf, probs, P_SYMBOL, 3)
                if x >= 5:
                    return -1
                sym[t] = x
            else:
                rc.enc_tree(es, out, probs, P_SYMBOL, 3, sym[t])
        return 0
    ncand = 0
    for step in range(2):  # the arc's length, then its start's rank: one inlined call site of the integer coder
        if step == 0:
            ctx, value = _block(B_LENGTH + min(d, 16) - 1), L - 1
        else:
            ncand = d if kind == 1 else d - L + 1
            ctx = _block(B_RANK + min(ncand, 16) - 1)
            if not decode:
                value = _arc_rank(fan, d, kind == 1, L, s, a, vv, P, lens, scores, np.int64(-1))
        if not decode:
            rc.enc_uint(es, out, probs, ctx, value)
            continue
        value = rc.dec_uint(ds, buf, probs, ctx)
        if step == 0:
            L = value + 1
            if L < 1 or L > d:
                return -1
        else:
            if value < 0 or value >= ncand:
                return -1
            s = _arc_rank(fan, d, kind == 1, L, np.int64(0), a, vv, P, lens, scores, value)
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
            inside = t - s if t >= s else t - s + d
            sym[fan[t]] = _arc_symbol(inside, L, left, right) if inside < L else 0
    if kind == 1:
        arc[0], arc[1], arc[2] = fan[s], fan[s + L - d if s + L >= d else s + L] if L < d else -1, L
    return 0


# ---------------------------------------------------------------- geometry


@kernel_helper
def _floor_half(x):
    """floor(x + 0.5) as int64."""
    return np.int64(np.floor(x + 0.5))


@kernel_helper(inline=True)
def _ring_stats(lo, hi, a, b, vv, sym, P, S, ring, nrm, i):
    """Split ``i``'s ring over the faces of its new vertex (spec §8.4.3), from its incidences
    ``lo .. hi - 1`` and their symbols, into row ``i`` of: ``S`` (k, D) int64 the sums of the faces'
    other corners' values, ``ring`` (k, 2) int64 the face count ``c`` and the summed L1 edge ``E``,
    ``nrm`` (k, 3) float64 the normal."""
    D = P.shape[1]
    vx, vy, vz = P[vv, 0], P[vv, 1], P[vv, 2]
    sx, sy, sz, c, ell = 0, 0, 0, 0, 0
    nx, ny, nz = 0.0, 0.0, 0.0
    for j in range(lo, hi):
        s = sym[j]
        if s == 0:
            continue
        ax, ay, az = P[a[j], 0], P[a[j], 1], P[a[j], 2]
        bx, by, bz = P[b[j], 0], P[b[j], 1], P[b[j], 2]
        sx, sy, sz = sx + ax + bx, sy + ay + by, sz + az + bz
        c += 1
        ell += abs(ax - bx) + abs(ay - by) + abs(az - bz)
        e1x, e1y, e1z = np.float64(ax - vx), np.float64(ay - vy), np.float64(az - vz)
        e2x, e2y, e2z = np.float64(bx - vx), np.float64(by - vy), np.float64(bz - vz)
        nx += e1y * e2z - e1z * e2y
        ny += e1z * e2x - e1x * e2z
        nz += e1x * e2y - e1y * e2x
        if s >= 2:  # the new faces: (u, v, a) left for symbols 2 and 4, (v, u, b) right for 3 and 4
            left, right = (0 if s == 3 else 1), (0 if s == 2 else 1)
            sx += (left + right) * vx + left * ax + right * bx
            sy += (left + right) * vy + left * ay + right * by
            sz += (left + right) * vz + left * az + right * bz
            c += left + right
            ell += (left * (abs(vx - ax) + abs(vy - ay) + abs(vz - az))
                    + right * (abs(vx - bx) + abs(vy - by) + abs(vz - bz)))
    S[i, 0], S[i, 1], S[i, 2] = sx, sy, sz
    for q in range(3, D):  # the attributes: the same faces' sums
        sq = 0
        for j in range(lo, hi):
            s = sym[j]
            if s == 0:
                continue
            sq += P[a[j], q] + P[b[j], q]
            if s >= 2:
                sq += (2 if s == 4 else 1) * P[vv, q] + (0 if s == 3 else P[a[j], q]) + (0 if s == 2 else P[b[j], q])
        S[i, q] = sq
    ring[i, 0], ring[i, 1] = c, ell
    nrm[i, 0], nrm[i, 1], nrm[i, 2] = nx, ny, nz


@kernel_helper
def _values_kernel(v, P, n0, S, ring, nrm, gstart, a, b, sym, plane, es, out, ds, buf, probs, decode, rsum, rcount):
    """Code (from ``P[n0 + i]``) or decode (into it) the values of the new vertices, split by split,
    given their rings (``S``, ``ring``, ``nrm`` of :func:`_connectivity_kernel`; ``gstart``, ``a``, ``b``, ``sym``
    the incidences it took them from, which the plane prediction walks again).  ``plane`` (D,) int64: 1 for
    the value columns predicted on the ring's plane (:func:`plane_columns`), else 0.

    Also fills ``rsum`` (k, D) float64 / ``rcount`` (k,) int64, each split's ring sum and twice
    its face count (:class:`~pmwm_codec.progressive.vsplit.SplitTopology`'s ``ring_sum`` /
    ``ring_count``).  Returns 0, or (decode) -1 on an invalid code / a value outside ``|x| < 2**31``.
    """
    D = P.shape[1]
    for i in range(len(v)):
        c = ring[i, 0]
        if c == 0:
            return -1
        for q in range(D):
            rsum[i, q] = np.float64(S[i, q])
        rcount[i] = 2 * c
        status = _split_values(S, i, v[i], n0 + i, P, ring, nrm, gstart[i], gstart[i + 1], a, b, sym, plane, es, out,
                               ds, buf, probs, decode)
        if status != 0:
            return status
    return 0


@kernel_helper
def _axis(q, x0, x1, x2):
    """Component ``q`` (0, 1, 2) of the vector ``(x0, x1, x2)``."""
    return x0 if q == 0 else (x1 if q == 1 else x2)


@kernel_helper
def _plane_prediction(lo, hi, a, b, sym, vv, u, P, q, ax0, ax1, mean):
    """``(prediction, spread)`` of value ``q`` of the new vertex ``u`` of a split of ``vv`` (spec §8.4.3): the
    affine function of the two non-dominant position axes ``ax0`` / ``ax1`` fitted by least squares to the
    ring's corners (the faces' other corners, as the ring sums ``S`` count them: incidences ``lo .. hi - 1``),
    at ``u``'s position, rounded and kept within the range of the corners' and ``vv``'s values widened by its
    span; ``mean`` (the floored ring mean) when the fit is singular.  ``spread`` = the sum over the corners of ``|value - value of vv|``."""
    vq, v0, v1 = P[vv, q], P[vv, ax0], P[vv, ax1]
    a00, a01, a11, a0, a1, nn = 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    b0, b1, bw = 0.0, 0.0, 0.0
    spread, lo_q, hi_q = 0, vq, vq
    for j in range(lo, hi):
        s = sym[j]
        if s == 0:
            continue
        for t in range(6):  # a, b; then v, a for a left face (symbol 2 or 4); then v, b for a right face (3 or 4)
            if (t == 2 or t == 3) and s != 2 and s != 4 or t >= 4 and s != 3 and s != 4:
                continue
            k = a[j] if t == 0 or t == 3 else (b[j] if t == 1 or t == 5 else vv)
            d0, d1 = np.float64(P[k, ax0] - v0), np.float64(P[k, ax1] - v1)
            wq = P[k, q] - vq
            w = np.float64(wq)
            a00 += d0 * d0
            a01 += d0 * d1
            a11 += d1 * d1
            a0 += d0
            a1 += d1
            nn += 1.0
            b0 += d0 * w
            b1 += d1 * w
            bw += w
            spread += abs(wq)
            lo_q = min(lo_q, P[k, q])
            hi_q = max(hi_q, P[k, q])
    m00, m01, m02 = a11 * nn - a1 * a1, a01 * nn - a1 * a0, a01 * a1 - a11 * a0
    det = (a00 * m00 - a01 * m01) + a0 * m02
    if not det > PLANE_SINGULAR * ((a00 * a11) * nn):
        return mean, spread
    alpha = ((b0 * m00 - a01 * (b1 * nn - a1 * bw)) + a0 * (b1 * a1 - a11 * bw)) / det
    beta = ((a00 * (b1 * nn - a1 * bw) - b0 * m01) + a0 * (a01 * bw - b1 * a0)) / det
    gamma = ((a00 * (a11 * bw - a1 * b1) - a01 * (a01 * bw - b1 * a0)) + b0 * m02) / det
    t0, t1 = np.float64(P[u, ax0] - v0), np.float64(P[u, ax1] - v1)
    span = hi_q - lo_q  # the fit kept within the range widened by its span, before rounding (integer bounds)
    fit = min(max((alpha * t0 + beta * t1) + gamma, np.float64(lo_q - span - vq)), np.float64(hi_q + span - vq))
    return vq + _floor_half(fit), spread


@kernel_helper(inline=True)
def _split_values(S, i, vv, u, P, ring, nrm, lo, hi, a, b, sym, plane, es, out, ds, buf, probs, decode):
    """Split ``i``'s new vertex ``u``: frame prediction from row ``i`` of ``S`` / ``ring`` / ``nrm``,
    then its D values coded / decoded in order (the ``plane`` columns by :func:`_plane_prediction` over the
    incidences ``lo .. hi - 1``)."""
    D = P.shape[1]
    c, ell = ring[i, 0], ring[i, 1]
    nx, ny, nz = nrm[i, 0], nrm[i, 1], nrm[i, 2]
    cls = min(rc.bit_length(ell // c), GEOMETRY_CLASSES - 1)
    two_c = np.float64(2 * c)
    m0, m1, m2 = np.float64(S[i, 0]) / two_c, np.float64(S[i, 1]) / two_c, np.float64(S[i, 2]) / two_c
    nn = (nx * nx + ny * ny) + nz * nz
    dom, ax0, ax1 = 2, 0, 1
    ph0, ph1, ph2 = m0, m1, m2
    if nn > 0.0:
        h = (((np.float64(P[vv, 0]) - m0) * nx + (np.float64(P[vv, 1]) - m1) * ny)
             + (np.float64(P[vv, 2]) - m2) * nz) / nn
        ph0, ph1, ph2 = m0 + h * nx, m1 + h * ny, m2 + h * nz
        if abs(nx) >= abs(ny) and abs(nx) >= abs(nz):
            dom, ax0, ax1 = 0, 1, 2
        elif abs(ny) >= abs(nz):
            dom, ax0, ax1 = 1, 0, 2
    base = _block(B_GEOMETRY + 3 * cls)
    for role in range(D):  # the three position roles, then the attributes; one call site of :func:`_value`
        if role >= 3:  # (each inlined call site compiles the range coder's integer once more)
            q = role
            if plane[q] != 0:
                pred, spread = _plane_prediction(lo, hi, a, b, sym, vv, u, P, q, ax0, ax1, S[i, q] // (2 * c))
                ctx = _block(B_PLANE + min(q - 3, ATTRIBUTE_CONTEXTS - 1) * PLANE_CLASSES
                             + min(rc.bit_length(spread // (2 * c)), PLANE_CLASSES - 1))
            else:
                pred = S[i, q] // (2 * c)
                ctx = _block(B_ATTRIBUTE + min(q - 3, ATTRIBUTE_CONTEXTS - 1))
        else:
            q = ax0 if role == 0 else (ax1 if role == 1 else dom)
            ctx = base + role * INT_BLOCK
            if role < 2 or nn == 0.0:
                pred = _floor_half(_axis(q, ph0, ph1, ph2))
            else:
                x0 = np.float64(P[u, ax0]) - _axis(ax0, ph0, ph1, ph2)
                x1 = np.float64(P[u, ax1]) - _axis(ax1, ph0, ph1, ph2)
                pred = _floor_half(_axis(q, ph0, ph1, ph2) - (x0 * _axis(ax0, nx, ny, nz) + x1 * _axis(ax1, nx, ny, nz))
                                   / _axis(q, nx, ny, nz))
        if _value(pred, ctx, q, u, P, es, out, ds, buf, probs, decode) != 0:
            return -1
    return 0


@kernel_helper(inline=True)
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


def _batch_decisions(n: int, incidences: int, splits: int, columns: int) -> int:
    """A bound on the coded decisions of one batch: its mask, connectivity and values."""
    return n + 3 * incidences + splits * (3 + 2 * INT_DECISIONS) + splits * columns * INT_DECISIONS


_NO_BYTES = np.zeros(0, np.uint8)
_NO_STATE = np.zeros(6, np.int64)
_NO_SEL = np.zeros(0, np.int64)
_NO_RES = np.zeros((0, 0), np.int64)


#: Digit width of :func:`_grouped_symbols_kernel`'s radix sort.
RADIX_BITS = 11


def _grouped_symbols(inc: np.ndarray, symbols: np.ndarray) -> np.ndarray:
    """(I,) uint8: the ``symbols`` (I,) of the incidences in face-slot order (ascending corner) moved to the
    order of ``inc`` (I,) int64, their distinct corners grouped by split (``sym[argsort(inc)] = symbols``)."""
    kernel = compiled(_grouped_symbols_kernel)
    if kernel is not None:
        return kernel(inc, np.asarray(symbols, np.uint8))
    sym = np.empty(len(inc), np.uint8)
    sym[np.argsort(inc)] = symbols
    return sym


def _grouped_symbols_kernel(inc, symbols):
    """Compiled :func:`_grouped_symbols`: the order of the corners ``inc`` (distinct, so any sort gives the
    same one) by a least-significant-digit radix sort, :data:`RADIX_BITS` bits a pass, O(I) each."""
    k = len(inc)
    top = 0
    for t in range(k):
        top = max(top, inc[t])
    key = inc.copy()
    order = np.arange(k)
    key2, order2 = np.empty(k, np.int64), np.empty(k, np.int64)
    size = 1 << RADIX_BITS
    start = np.empty(size + 1, np.int64)
    shift = 0
    while shift == 0 or (top >> shift) > 0:
        start[:] = 0
        for t in range(k):
            start[((key[t] >> shift) & (size - 1)) + 1] += 1
        for d in range(size):
            start[d + 1] += start[d]
        for t in range(k):
            d = (key[t] >> shift) & (size - 1)
            key2[start[d]], order2[start[d]] = key[t], order[t]
            start[d] += 1
        key, key2 = key2, key
        order, order2 = order2, order
        shift += RADIX_BITS
    sym = np.empty(k, np.uint8)
    for j in range(k):
        sym[order[j]] = symbols[j]
    return sym


def pack_chunks(state, chunks, plane=None) -> list:
    """Encode every chunk of one primitive.  ``plane``: the columns predicted on the ring's plane
    (:func:`plane_columns`), or None.

    ``state``: the primitive's :class:`~pmwm_codec.progressive.vsplit.MeshState` at the base
    (int64 values, D columns), advanced through every chunk; ``chunks``: list of lists of
    :class:`SplitBatch`, coarse to fine, or :class:`FaceChunk` (spec §8.6).  Returns one ``bytes``
    payload per chunk.
    """
    packer = ChunkPacker(state, plane)
    for batches in chunks:
        if isinstance(batches, FaceChunk):
            packer.face_chunk(batches)
            continue
        packer.begin(len(batches))
        for batch in batches:
            packer.batch(batch)
        packer.end()
    return packer.payloads


class ChunkPacker:
    """Codes one primitive's chunks (one payload each, :attr:`payloads`) while it applies their batches
    to ``state`` (a :class:`~pmwm_codec.progressive.vsplit.MeshState` at the base, int64 values) by
    the decoder's path, so it leaves the mesh the decoder builds: per batch :func:`_mask_kernel`
    then :func:`_batch_kernel`, both in encode mode, on :class:`CornerLists` made once for the base
    and updated batch by batch.  A chunk of splits is :meth:`begin`, then :meth:`batch` (a whole
    :class:`SplitBatch`) or :meth:`mask` and :meth:`split` (a batch whose symbols the caller derives
    from the incidences the mask gathers: the record builder), then :meth:`end`;
    :meth:`face_chunk` codes a face chunk.  ValueError for a batch the format cannot carry (no
    simplifier makes one)."""

    def __init__(self, state, plane=None):
        self.state = state
        self.plane = plane  # (D,) int64 the columns predicted on the ring's plane (plane_columns), or None
        self.probs = new_model()  # each chunk continues the table the chunk before it left
        self.lists = CornerLists(len(state.positions), len(state.faces))
        self.lists.sync(state)
        self.payloads = []
        self.enc = None
        self.buffers = None  # the mask's outputs, reused from batch to batch (:func:`_mask_buffers`)
        self.sel = None  # (N,) int64 the mask's input bits, zeros between batches

    def begin(self, batches: int) -> None:
        """Start a chunk of ``batches`` batches: its batch count."""
        if not 1 <= batches <= MAX_BATCHES_PER_CHUNK:
            raise ValueError(f"payload v2: {batches} batches in a chunk, outside 1..{MAX_BATCHES_PER_CHUNK}")
        if self.lists.n < 0:  # after a face chunk
            self.lists.sync(self.state)
        self.enc = enc = rc.Encoder(self.probs)
        enc.reserve(INT_DECISIONS)
        rc.encode_uint(enc, _block(B_BATCHES), batches - 1)

    def end(self) -> None:
        """Close the chunk: its payload is appended to :attr:`payloads`."""
        self.payloads.append(self.enc.finish())
        self.enc = None

    def batch(self, batch: SplitBatch) -> None:
        """Code ``batch`` (symbols in face-slot order, residuals against the version 1 prediction) and
        apply it."""
        k, D = batch.size, self.state.positions.shape[1]
        res = np.asarray(batch.residual, np.int64)
        if res.shape != (k, D):
            raise ValueError("payload v2: residual array does not match the split count")
        v = np.asarray(batch.v, np.int64)
        gstart, inc, a, b = self.mask(v)
        symbols = np.asarray(batch.symbols)
        if len(inc) != len(symbols) or (len(inc) and int(symbols.max()) >= 5):
            raise ValueError("payload v2: the batch's symbols do not match the mesh's incidences")
        self.split(v, gstart, inc, a, b, _grouped_symbols(inc, symbols), res)

    def mask(self, v: np.ndarray) -> tuple:
        """Code the selection of the split vertices ``v`` (k,) int64 (strictly increasing, existing).
        Returns their incidences as :func:`_batch_kernel` takes them, grouped by split: ``(gstart
        (k + 1,), inc, a, b (I,))`` int64 (:func:`_mask_kernel`), views of buffers the next batch reuses."""
        state = self.state
        n, m, k = state.n, state.m, len(v)
        if k == 0 or v[0] < 0 or v[-1] >= n or not (v[1:] > v[:-1]).all() or n + k > len(state.positions):
            raise ValueError("payload v2: split vertices empty, out of range or not increasing")
        if self.sel is None or len(self.sel) < n:
            self.sel = np.zeros(len(state.positions), np.int64)
        sel = self.sel
        sel[v] = 1
        self.enc.reserve(n)
        enc, lists = self.enc, self.lists
        if self.buffers is None:
            self.buffers = _mask_buffers(len(state.faces), len(state.positions))
        marked, gstart, inc, a, b = self.buffers
        _, corners = rc._kernel(_mask_kernel)(state.faces.reshape(-1), n, lists.head, lists.nxt, lists.valence,
                                              lists.below, sel, marked[:k], gstart[: k + 1], inc, a, b, enc.es,
                                              enc.out, _NO_STATE, _NO_BYTES, enc.probs, 0)
        sel[v] = 0
        return gstart[: k + 1], inc[:corners], a[:corners], b[:corners]

    def split(self, v, gstart, inc, a, b, sym, res=None):
        """Code the connectivity and values of the batch of ``v`` (k,) whose selection :meth:`mask`
        coded (``gstart``, ``inc``, ``a``, ``b``: what it returned; ``sym`` (I,) uint8 their symbols,
        in that order) and apply it.  ``res`` (k, D) int64: the new values' residuals against the
        version 1 prediction; None: the caller has put the new values in ``state.positions[n:n + k]``.
        Returns the batch in version 1 terms (:func:`_packed_batch`)."""
        state, enc, lists = self.state, self.enc, self.lists
        n, m, k, D = state.n, state.m, len(v), state.positions.shape[1]
        enc.reserve(_batch_decisions(0, len(inc), k, D))
        rsum, rcount = np.empty((k, D)), np.empty(k, np.int64)
        new_faces = rc._kernel(_batch_kernel)(state.faces.reshape(-1), m, n, state.positions, v, lists.head,
                                              lists.tail, lists.nxt, lists.valence, lists.stamp, lists.tag,
                                              lists.split, lists.created, lists.creator, lists.ctr, inc, a, b, sym,
                                              gstart, rsum, rcount, _NO_RES if res is None else res,
                                              _columns(self.plane, D), enc.es, enc.out, _NO_STATE, _NO_BYTES, enc.probs, 0)
        if new_faces < 0:
            raise ValueError(f"payload v2: {_BATCH_ERRORS[new_faces]}")
        state.n, state.m = n + k, m + new_faces
        lists.n, lists.m = state.n, state.m
        return _packed_batch(v, n, state.positions, inc, sym, rsum, rcount, new_faces)

    def face_chunk(self, chunk: FaceChunk) -> np.ndarray:
        """Code the face chunk ``chunk`` and apply it (:func:`_pack_face_chunk`); returns its ``order``."""
        if self.lists.n < 0:
            self.lists.sync(self.state)
        payload, order = _pack_face_chunk(self.state, self.lists, chunk)
        self.payloads.append(payload)
        return order


def plane_columns(attributes) -> np.ndarray | None:
    """(D,) int64: 1 for each value column of an extension ``attributes`` list (spec README, attributes) whose
    entry says ``"prediction": "plane"`` (spec §8.4.3), 0 for the positions and the other columns; None when
    no entry does."""
    flags = [0, 0, 0]
    for spec in attributes or ():
        flags += [1 if spec.get("prediction") == PLANE_PREDICTION else 0] * len(spec["origin"])
    return np.array(flags, np.int64) if any(flags) else None


#: The extension ``attributes`` entry's ``prediction`` value of an attribute predicted on the ring's plane.
PLANE_PREDICTION = "plane"


def _columns(plane, d: int) -> np.ndarray:
    """``plane`` (D,) int64, or zeros of ``d`` columns when None."""
    if plane is None:
        return np.zeros(d, np.int64)
    if len(plane) != d:
        raise FormatError(f"payload v2: {len(plane)} prediction flags for {d} value columns")
    return plane


def new_model() -> np.ndarray:
    """The probability table of a primitive's first chunk: (N_PROBS,) int64, every entry 1024.
    Each chunk continues the table the chunk before it (of the same primitive) left."""
    return rc.new_probs(N_PROBS)


class ChunkDecoder:
    """What decoding a primitive's chunks carries from one chunk to the next: the probability
    table (:func:`new_model`) and the :class:`CornerLists` of its mesh (made on the first chunk,
    then updated batch by batch).  One per primitive; :func:`decode_chunk` advances it."""

    def __init__(self, plane=None):
        self.probs = new_model()
        self.plane = plane  # (D,) int64 the columns predicted on the ring's plane (plane_columns), or None
        self.lists: CornerLists | None = None
        self.mask_out: tuple | None = None  # the last batch's mask outputs (mask_buffers)
        self.mask_spare: tuple | None = None  # the outputs of the batch before it

    def lists_for(self, state) -> CornerLists:
        if self.lists is None or not self.lists.fits(state):
            self.lists = CornerLists(len(state.positions), len(state.faces))
        self.lists.sync(state)
        return self.lists

    def mask_buffers(self, state) -> tuple:
        """:func:`_mask_buffers` at the primitive's capacity (N marks, 3M corners) for the next batch
        on ``state``: the last batch's when nothing else holds them any more, else new ones.  A
        decoded batch lists its split vertices and incidences as views of them, read when first
        asked (the watermark reads them after the chunk): while any view lives, CPython counts a
        reference to the array it views (:func:`_unreferenced`).  Reuse spares a batch the system
        calls and page faults of new arrays.  The outputs of the batch before the last are tried
        too: a consumer's ``for`` loop still holds the last batch while it asks for the next one."""
        for bufs in (self.mask_out, self.mask_spare):
            if (bufs is not None and len(bufs[0]) == len(state.positions) and len(bufs[2]) == 3 * len(state.faces)
                    and _unreferenced(bufs)):
                break
        else:
            if self.mask_out is not None and len(self.mask_out[0]) != len(state.positions):
                self.mask_out = self.mask_spare = None  # the mesh grew: the old sizes are never used again
            bufs = _mask_buffers(len(state.faces), len(state.positions))
        if bufs is not self.mask_out:
            self.mask_out, self.mask_spare = bufs, self.mask_out
        return bufs


def _references(items: tuple) -> list:
    """CPython's reference count of each of ``items``, as counted from here."""
    return [sys.getrefcount(x) for x in items]


def _unreferenced(items: tuple) -> bool:
    """Whether nothing but the tuple ``items`` holds any of its items (no view of an array, no
    decoded batch).  The counts are compared with those of a fresh object held by a tuple alone and
    counted by the same code, not with a constant: how many references the counting itself takes
    differs between CPython versions (3.14 borrows some).  False outside CPython (its counts are
    meaningless there): new buffers every batch, as before reuse."""
    if sys.implementation.name != "cpython":
        return False
    alone = _references((object(),))[0]
    return all(r <= alone for r in _references(items))


def decode_chunk(payload, state, model: ChunkDecoder, listed: bool = True):
    """Decode one chunk against ``state`` (int64 values), applying each batch as it is decoded;
    ``model`` is the primitive's :class:`ChunkDecoder` (updated in place).

    Yields ``(SplitBatch, SplitTopology)`` per batch: the batch in version 1 terms (split
    vertices, incidence symbols, residuals against the version 1 prediction; listed when first
    read) and what :func:`~pmwm_codec.progressive.vsplit.split_topology` would have done;
    ``(None, None)`` when not ``listed`` (a caller that reads neither: the batch is applied all the same).
    FormatError / LimitError on any invalid code, count or termination.
    """
    dec = rc.Decoder(payload, model.probs)
    count = rc.decode_uint(dec, _block(B_BATCHES))
    if count < 0:
        raise FormatError("chunk payload: invalid batch count")
    batches = count + 1
    if batches > MAX_BATCHES_PER_CHUNK:
        raise LimitError(f"chunk payload: batch count {batches} outside 1..{MAX_BATCHES_PER_CHUNK}")
    lists = model.lists_for(state)
    for _ in range(batches):
        try:
            yield _decode_batch(dec, state, lists, model.mask_buffers(state), listed, model.plane)
        except FormatError:
            lists.n = -1  # the lists may be half updated: rebuilt if anyone decodes on
            raise
    dec.finish()


_BATCH_ERRORS = {
    -1: "chunk payload: invalid connectivity code",
    -2: "a split names no new face or more than two",
    -3: "splits exceed the declared face count",
    -4: "chunk payload: invalid value code or a value out of range",
}


def _mask_buffers(m: int, cap: int) -> tuple:
    """Outputs of :func:`_mask_kernel` for a mesh of ``m`` faces and up to ``cap`` marks:
    ``(marked (cap,), gstart (cap + 1,), inc, a, b (3m,))`` int64, uninitialised (their
    pages are only taken as the kernel writes them)."""
    return (np.empty(cap, np.int64), np.empty(cap + 1, np.int64)) + tuple(np.empty(3 * m, np.int64) for _ in range(3))


def _decode_batch(dec, state, lists, buffers, listed, plane=None):
    """One batch: mask, then connectivity, topology and values in one kernel (:func:`_batch_kernel`).
    ``buffers``: the mask's outputs (:meth:`ChunkDecoder.mask_buffers`).  Returns what
    :func:`decode_chunk` yields (``listed``: whether the batch is listed)."""
    n, m = state.n, state.m
    flat = state.faces.reshape(-1)
    marked, gstart, inc, a, b = buffers
    cap = min(state.vertex_limit, 2 * n) - n  # the marks the primitive has room for (one a vertex at most)
    k, corners = rc._kernel(_mask_kernel)(flat, n, lists.head, lists.nxt, lists.valence, lists.below, _NO_SEL,
                                          marked[:cap], gstart[: cap + 1], inc, a, b, _NO_STATE, _NO_BYTES, dec.ds,
                                          dec.buf, dec.probs, 1)
    if k < 0:
        raise FormatError("splits exceed the declared vertex count")
    if k == 0:
        raise FormatError("chunk payload: a batch marks no split vertex")
    dec.check_overrun()
    v, gstart = marked[:k], gstart[: k + 1]
    inc, a, b = inc[:corners], a[:corners], b[:corners]
    if state.reserve(n + k, min(m + 2 * k, state.face_limit)):  # two new faces a split at most
        lists.grow(state)
        flat = state.faces.reshape(-1)
    D = state.positions.shape[1]
    sym = np.zeros(corners, np.uint8)
    rsum, rcount = np.empty((k, D)), np.empty(k, np.int64)
    new_faces = rc._kernel(_batch_kernel)(flat, m, n, state.positions, v, lists.head, lists.tail, lists.nxt,
                                          lists.valence, lists.stamp, lists.tag, lists.split, lists.created,
                                          lists.creator, lists.ctr, inc, a, b, sym, gstart, rsum, rcount, _NO_RES,
                                          _columns(plane, state.positions.shape[1]), _NO_STATE, _NO_BYTES, dec.ds,
                                          dec.buf, dec.probs, 1)
    if new_faces < 0:
        raise FormatError(_BATCH_ERRORS[new_faces])
    state.n, state.m = n + k, m + new_faces
    lists.n, lists.m = state.n, state.m
    if not listed:
        return None, None
    return _listed_batch(v, n, state.positions, gstart, inc, a, b, sym, rsum, rcount, new_faces)


def _listed_batch(v, n0, positions, gstart, inc, a, b, sym, rsum, rcount, new_faces) -> tuple:
    """``(DecodedBatch, SplitTopology)`` of a batch :func:`_batch_kernel` applied: ``v`` (k,) int64 its split
    vertices, ``n0`` the vertex count before it, ``positions`` (N, D) the values it wrote, ``gstart`` /
    ``inc`` / ``a`` / ``b`` / ``sym`` its incidences grouped by split (:func:`_mask_kernel`), ``rsum`` /
    ``rcount`` its ring sums, ``new_faces`` the faces it appended; what version 1 terms need of them is
    listed when first asked."""
    k = len(v)
    u = n0 + np.arange(k)

    def face_slot_order():
        order = np.argsort(inc, kind="stable")
        own = np.repeat(np.arange(k), np.diff(gstart))  # the split of each incidence
        return inc[order], own[order], order

    def incidence_lists():
        return face_slot_order()[:2]

    def ring():
        _, own, order = face_slot_order()
        return _ring_lists(v, sym[order], own, a[order], b[order])

    topo = SplitTopology(u, rsum, rcount, incidence_lists, ring)
    return DecodedBatch(v, positions, topo, lambda: sym[face_slot_order()[2]], sym, new_faces), topo


def _packed_batch(v, n0, positions, inc, sym, rsum, rcount, new_faces) -> DecodedBatch:
    """A batch :meth:`ChunkPacker.split` applied, in version 1 terms (as :func:`_listed_batch`), holding
    only what its symbols in face-slot order and its residuals are listed from when first read: ``sym``
    (I,) uint8 grouped by split, a copy of their corners ``inc`` (I,) in int32 (corners < 2**31; the
    mask's buffers are reused), the ring sums ``rsum`` (k, D) / ``rcount`` (k,) and ``positions``
    (N, D), which hold the new values at ``n0 ..``; ``new_faces`` the faces it appended."""
    corners = inc.astype(np.int32)
    topo = SplitTopology(n0 + np.arange(len(v)), rsum, rcount, None)
    return DecodedBatch(v, positions, topo, lambda: sym[np.argsort(corners, kind="stable")], sym, new_faces)


class DecodedBatch(SplitBatch):
    """A decoded batch in version 1 terms (:class:`~pmwm_codec.progressive.vsplit.SplitBatch`):
    its symbols in face-slot order and its residuals, listed only when first read (a plain
    decode reads neither), and the count of faces it appended (:func:`_batch_kernel`'s, the
    count :func:`~pmwm_codec.progressive.vsplit.new_face_count` makes of its symbols)."""

    def __init__(self, v, positions, topo, symbols, grouped, new_faces):
        self.v = v
        self._positions, self._topo, self._symbols, self._grouped = positions, topo, symbols, grouped
        self._new_faces = int(new_faces)

    def new_face_count(self) -> int:
        return self._new_faces

    @cached_property
    def symbols(self) -> np.ndarray:
        return self._symbols()

    @cached_property
    def residual(self) -> np.ndarray:
        return self._positions[self._topo.u] - self._topo.prediction()


def _batch_kernel(flat, m0, n0, P, v, head, tail, nxt, valence, stamp, tag, split, created, creator, ctr, inc, a, b,
                  sym, gstart, rsum, rcount, res, plane, es, out, ds, buf, probs, decode):
    """Code (``decode`` 0) or decode (1) the connectivity and values of one batch whose split
    vertices ``v`` (k,) and incidences are known (:func:`_mask_kernel`), applying it to the face
    slots ``flat`` (3M,) int64, the values ``P`` (N, D) and the corner lists (:class:`CornerLists`
    arrays).  Encoding and decoding walk the same steps, so both leave the same mesh.

    The incidences are grouped by split (split i's: ``[gstart[i], gstart[i+1])``, face-slot
    order within it): ``inc`` corner, ``a`` / ``b`` corners after / before the
    split vertex (all (I,) int64).  ``sym`` (I,) uint8: the symbols (encode: given, decode:
    filled).  ``res`` (k, D) int64 (encode): the new values' residuals against the version 1
    prediction, written to ``P`` before they are coded; empty (encode): ``P[n0:n0 + k]`` already holds
    the new values.  ``plane`` (D,) int64: the columns predicted on the ring's plane.  Fills ``rsum`` / ``rcount`` (see
    :func:`_values_kernel`).  Returns the number of new faces, or a negative code (:data:`_BATCH_ERRORS`).
    """
    k, D = len(v), P.shape[1]
    # every array the steps use is made here: the steps are compiled without reference counting (each
    # array's count taken with an atomic instruction), which their loops would otherwise do per split
    S, ring, nrm = np.empty((k, D), np.int64), np.empty((k, 2), np.int64), np.empty((k, 3))
    arc = np.empty((k, 3), np.int64)
    fan, work = np.empty(MAX_ARC_FAN, np.int64), np.zeros(FAN_WORK, np.int64)
    lens, scores = np.empty(MAX_ARC_FAN, np.float64), np.empty(MAX_ARC_FAN, np.float64)
    if _connectivity_kernel(gstart, a, b, v, P, sym, S, ring, nrm, arc, fan, work, lens, scores, es, out, ds, buf,
                            probs, decode) != 0:
        return -1
    named = np.empty((2 * k, 4), np.int64)  # two new faces a split at most (more: refused before any is named)
    new_faces, rewritten = _link_splits(flat, m0, n0, v, inc, a, b, sym, gstart, head, tail, nxt, split, created,
                                        creator, named)
    if new_faces < 0:
        return new_faces
    if not decode and len(res) != 0:
        for i in range(k):
            if ring[i, 0] == 0:
                return -4
            for q in range(D):
                P[n0 + i, q] = S[i, q] // (2 * ring[i, 0]) + res[i, q]
    if _values_kernel(v, P, n0, S, ring, nrm, gstart, a, b, sym, plane, es, out, ds, buf, probs, decode, rsum,
                      rcount) != 0:
        return -4
    own, near, flags = np.empty((k, 2), np.int64), np.empty(2 * MAX_ARC_FAN, np.int64), np.empty(2 * MAX_ARC_FAN, np.int64)
    _update_valences(n0, v, a, b, sym, gstart, arc, flat, head, nxt, valence, stamp, tag, ctr, rewritten, own, near,
                     flags)
    return new_faces


@kernel_helper
def _update_valences(n0, v, a, b, sym, gstart, arc, flat, head, nxt, valence, stamp, tag, ctr, rewritten, own, near,
                     flags):
    """The valences a batch changed, after its topology.  A ring vertex ``x`` of split i gains ``u``
    when a face of ``u`` holds it and loses ``v`` when no face of ``v`` holds it any more; ``v`` and
    ``u`` count the distinct ring vertices of their faces, plus each other (in O(1) for the arc of
    a closed fan, ``arc`` (k, 3) of :func:`_split_symbols`: :func:`_arc_valences`).  That holds when
    no face held a moved corner and another split vertex (``rewritten`` False: every valid batch);
    else every ring, split and new vertex is recounted from its faces.  Scratch: ``own`` (k, 2) int64,
    ``near`` / ``flags`` (2 * MAX_ARC_FAN,) int64."""
    k = len(v)
    if rewritten:
        for i in range(k):
            for t in range(gstart[i], gstart[i + 1]):
                valence[a[t]] = _valence(a[t], flat, head, nxt, stamp, ctr)
                valence[b[t]] = _valence(b[t], flat, head, nxt, stamp, ctr)
        for i in range(k):
            valence[v[i]] = _valence(v[i], flat, head, nxt, stamp, ctr)
            valence[n0 + i] = _valence(n0 + i, flat, head, nxt, stamp, ctr)
        return
    for i in range(k):  # own: the valences of u and v after the split
        own[i, 0], own[i, 1] = 1, 1
    for i in range(k):
        lo, hi = gstart[i], gstart[i + 1]
        if arc[i, 0] >= 0 and _arc_valences(lo, hi, a, v[i], arc[i], valence, own[i]):
            continue
        if hi - lo <= MAX_ARC_FAN:  # a small ring: its distinct vertices told apart in near / flags
            count = 0
            for t in range(lo, hi):
                s = sym[t]
                count = _note(a[t], (1 if s != 0 else 2) | (2 if s == 2 or s == 4 else 0), near, flags, count)
                count = _note(b[t], (1 if s != 0 else 2) | (2 if s == 3 or s == 4 else 0), near, flags, count)
            for q in range(count):
                _ring_vertex_moved(near[q], flags[q], v[i], valence, own[i])
            continue
        ctr[0] += 1
        token = 8 * ctr[0]  # tag bits: 1 in a face of u, 2 in a face of v, 4 counted
        for t in range(lo, hi):
            s = sym[t]
            _tag(a[t], token, (1 if s != 0 else 2) | (2 if s == 2 or s == 4 else 0), tag)
            _tag(b[t], token, (1 if s != 0 else 2) | (2 if s == 3 or s == 4 else 0), tag)
        for t in range(lo, hi):
            for x in (a[t], b[t]):
                if tag[x] & 4 == 0:
                    _ring_vertex_moved(x, tag[x], v[i], valence, own[i])
                    tag[x] |= 4
    for i in range(k):  # last: a split vertex may be in another split's ring
        valence[n0 + i], valence[v[i]] = own[i, 0], own[i, 1]


@kernel_helper
def _arc_valences(lo, hi, a, vv, arc, valence, own):
    """:func:`_update_valences` for a split of ``vv`` whose symbols are the arc of a closed fan of
    d = hi - lo faces (``arc`` (3,): :func:`_split_symbols`), its moved faces holding no other split
    vertex: the ring vertices r_t (``a`` of the fan's t-th incidence, all distinct) from r_s (the
    arc's first) to r_(s+L) (``a`` of ``arc[1]``) gain u (r_s and r_(s+L)) or swap v for u (those
    between, no change); u has them (L + 1, or d when L = d) and v; v keeps r_(s+L) .. r_s (d - L + 1,
    or r_s alone when L = d) and has u.  False (nothing changed) when a ring vertex is ``vv``
    itself: the caller then counts."""
    for t in range(lo, hi):
        if a[t] == vv:
            return False
    L, d = arc[2], hi - lo
    valence[a[arc[0]]] += 1
    if arc[1] >= 0:
        valence[a[arc[1]]] += 1
    own[0] = L + 2 if L < d else d + 1
    own[1] = d - L + 2 if L < d else 2
    return True


@kernel_helper
def _ring_vertex_moved(x, bits, vv, valence, own):
    """Ring vertex ``x`` of a split of ``vv``, in a face of u (bits & 1) / of v (bits & 2) after it:
    its valence gains u, loses v unless still beside it; ``own`` (2,) counts it for u and v."""
    if x != vv:
        valence[x] += (bits & 1) - 1 + ((bits >> 1) & 1)
        own[0] += bits & 1
        own[1] += (bits >> 1) & 1


@kernel_helper
def _note(x, bits, near, flags, count):
    """Or ``bits`` into the flags of ``x`` among ``near[:count]`` (appended when new); returns the count."""
    for q in range(count):
        if near[q] == x:
            flags[q] |= bits
            return count
    near[count], flags[count] = x, bits
    return count + 1


@kernel_helper
def _tag(x, token, bits, tag):
    """``tag[x]``: ``token`` with ``bits`` or-ed into those ``x`` already has under it."""
    tag[x] = (tag[x] | bits) if tag[x] & ~7 == token else (token | bits)


#: Bit j of a word -> j, by the de Bruijn sequence 0x077CB531 (:func:`_link_splits`'s bitmap).
_DE_BRUIJN = np.array([0, 1, 28, 2, 29, 14, 24, 3, 30, 22, 20, 15, 25, 17, 4, 8, 31, 27, 13, 23, 21, 19, 16, 7, 26, 12,
                       18, 6, 11, 5, 10, 9], np.int64)


@kernel_helper
def _link_splits(flat, m0, n0, v, inc, a, b, sym, gstart, head, tail, nxt, split, created, creator, named):
    """Spec §6.1 steps 1-3 on the face slots and the corner lists: the moved corners become
    ``u`` (and its list), the new faces are appended in face-slot order of the incidences naming
    them.  Returns ``(new faces, rewritten)``: new faces -2 when a split names none or more than
    two, -3 when they exceed the face capacity (nothing written then); rewritten True when a
    face held a moved corner and another corner of a split vertex (:func:`_update_valences`).
    Scratch: ``split`` (N,) uint8 and ``created`` (bitmap over the corners, 32 bits in each int64
    word), zeros on entry and on return; ``creator`` (3M,) int32, at a corner naming new faces
    (read only where ``created`` has the corner's bit) the row of ``named`` that holds them, made
    as the corners move: (u, v, a of the left face or -1, b of the right face or -1), so that
    the faces are written from one row each, not from the batch's arrays at scattered places: ``named``
    (at least new faces, 4) int64 scratch, its rows in the order the corners move."""
    k = len(v)
    new_faces = 0
    for i in range(k):
        wings = 0
        for t in range(gstart[i], gstart[i + 1]):
            if sym[t] >= 2:
                wings += 1 if sym[t] < 4 else 2
        if wings == 0 or wings > 2:
            return -2, False
        new_faces += wings
    if 3 * (m0 + new_faces) > len(flat):
        return -3, False
    for i in range(k):
        split[v[i]] = 1
    rewritten = False
    ahead = len(head) >= PREFETCH_VERTICES
    lo_word, hi_word = len(created), 0
    j = 0
    for i in range(k):  # split i's corners, ascending: the moved ones to u, the others stay with v
        u = n0 + i
        if ahead and i + 1 < k:  # the next split's corners, loaded while this split is worked on
            _prefetch_rows(flat, inc, gstart[i + 1], gstart[i + 2])
            _prefetch_rows(nxt, inc, gstart[i + 1], gstart[i + 2])
        last_u, last_v = -1, -1  # the two lists rebuilt in locals: each corner's successor written once
        for t in range(gstart[i], gstart[i + 1]):
            c = inc[t]
            if sym[t] != 0:  # its face's other corners as they were before the batch: a[t], b[t]
                rewritten = rewritten or split[a[t]] != 0 or split[b[t]] != 0
                flat[c] = u
                if sym[t] >= 2:  # names a new face: its corner goes into the bitmap
                    named[j, 0], named[j, 1] = u, v[i]
                    named[j, 2] = a[t] if sym[t] != 3 else -1
                    named[j, 3] = b[t] if sym[t] != 2 else -1
                    creator[c] = j
                    j += 1
                    created[c >> 5] |= 1 << (c & 31)
                    lo_word, hi_word = min(lo_word, c >> 5), max(hi_word, (c >> 5) + 1)
                if last_u < 0:
                    head[u] = c
                else:
                    nxt[last_u] = c
                last_u = c
            else:
                if last_v < 0:
                    head[v[i]] = c
                else:
                    nxt[last_v] = c
                last_v = c
        _end_list(u, last_u, head, tail, nxt)
        _end_list(v[i], last_v, head, tail, nxt)
    slot = 3 * m0
    word, bits = lo_word - 1, 0  # the naming corners in ascending order (a cursor over the bitmap)
    # on large meshes two cursors run ahead: one asks for the creator entries LINK_AHEAD corners on, one
    # for the rows of named half as far on (their creator entries asked for by then)
    wa, ba, wb, bb = word, bits, word, bits
    if ahead:
        for _ in range(LINK_AHEAD):
            c, wa, ba = _next_created(created, wa, ba, hi_word)
            if c >= 0:
                topology.prefetch(creator, c)
        for _ in range(LINK_AHEAD // 2):
            c, wb, bb = _next_created(created, wb, bb, hi_word)
            if c >= 0:
                topology.prefetch(named, creator[c])
    while True:
        c, word, bits = _next_created(created, word, bits, hi_word)
        if c < 0:
            break
        if ahead:
            x, wa, ba = _next_created(created, wa, ba, hi_word)
            if x >= 0:
                topology.prefetch(creator, x)
            x, wb, bb = _next_created(created, wb, bb, hi_word)
            if x >= 0:
                topology.prefetch(named, creator[x])
        row = creator[c]
        u, vv, left, right = named[row, 0], named[row, 1], named[row, 2], named[row, 3]
        if left >= 0:  # left new face (u, v, a)
            slot = _new_face(slot, u, vv, left, flat, head, tail, nxt)
        if right >= 0:  # right new face (v, u, b)
            slot = _new_face(slot, vv, u, right, flat, head, tail, nxt)
    for word in range(lo_word, hi_word):  # the bitmap cleared
        created[word] = 0
    for i in range(k):
        split[v[i]] = 0
    return new_faces, rewritten


#: How many naming corners ahead :func:`_link_splits` asks for their ``creator`` entries on large meshes.
LINK_AHEAD = 16


@kernel_helper(inline=True)
def _next_created(created, word, bits, hi_word):
    """Advance a cursor over the bitmap ``created`` (:func:`_link_splits`): ``bits`` the part of word ``word``
    not visited yet.  Returns ``(corner, word, bits)``: the next set corner, or -1 past word ``hi_word - 1``."""
    while bits == 0:
        word += 1
        if word >= hi_word:
            return -1, word, bits
        bits = created[word]
    low = bits & -bits
    return 32 * word + _DE_BRUIJN[((low * 0x077CB531) & 0xFFFFFFFF) >> 27], word, bits ^ low


@kernel_helper
def _end_list(w, last, head, tail, nxt):
    """Close ``w``'s list at its last corner ``last`` (-1: the list is empty)."""
    if last < 0:
        head[w] = -1
    else:
        nxt[last] = -1
    tail[w] = last


@kernel_helper
def _new_face(slot, x, y, z, flat, head, tail, nxt):
    """Write face (x, y, z) at face slot ``slot`` and list its corners; returns the next slot."""
    flat[slot], flat[slot + 1], flat[slot + 2] = x, y, z
    _append_corner(x, slot, head, tail, nxt)
    _append_corner(y, slot + 1, head, tail, nxt)
    _append_corner(z, slot + 2, head, tail, nxt)
    return slot + 3


# ---------------------------------------------------------------- face chunks (spec §8.6)

#: A face chunk's own probability table: singles 0 (b near), 1 (c near), 2 (twin), 3 (fresh vertex);
#: integer blocks at 32 + 256 * B.
FACE_PROBS = 32 + 9 * INT_BLOCK
F_NEAR_B, F_NEAR_C, F_TWIN, F_FRESH = 0, 1, 2, 3
FB_COUNT, FB_GAP, FB_RANK_B, FB_RANK_C, FB_RAW, FB_VALUE = range(6)  # values: FB_VALUE + min(q, 3)
_FACE_ERRORS = {
    -1: "face chunk: invalid integer code",
    -2: "face chunk: a neighbour rank beyond its list",
    -3: "face chunk: a vertex id beyond the mesh",
    -4: "face chunk: a face with a repeated vertex",
    -5: "face chunk: more faces than its index entry adds",
    -6: "face chunk: more new vertices than its index entry adds",
    -7: "face chunk: fewer new vertices named than its index entry adds",
    -8: "face chunk: a value out of range",
    -9: "face chunk: faces not in ascending order of their first vertex",
    -10: "face chunk: a face names a new vertex numbered before its first vertex",
}


@kernel_helper
def _face_block(b):
    """Offset of integer block ``b`` in a face chunk's table."""
    return 32 + b * INT_BLOCK


@kernel_helper
def _neighbours_above(w, above, flat, head, nxt, stamp, ctr, out):
    """The distinct vertices ``x > above``, ``x != w``, sharing a face with ``w``, written ascending to
    ``out`` (scratch, at least ``|N(w)|`` long); returns their number.  ``w`` and every vertex
    sharing a face with it get ``stamp`` = the new token ``ctr[0]``."""
    token = ctr[0] + 1
    ctr[0] = token
    stamp[w] = token
    k = 0
    c = head[w]
    while c >= 0:
        f3 = c - c % 3
        for j in range(3):
            x = flat[f3 + j]
            if stamp[x] != token:
                stamp[x] = token
                if x > above:
                    t = k  # insertion: lists are short
                    while t > 0 and out[t - 1] > x:
                        out[t] = out[t - 1]
                        t -= 1
                    out[t] = x
                    k += 1
        c = nxt[c]
    return k


@kernel_helper
def _up_list(a, flat, head, nxt, stamp, ctr, up):
    """``Up(a)`` (spec §8.6) into ``up``: the distinct vertices ``x > a`` sharing a face with ``a``,
    ascending; returns their number."""
    return _neighbours_above(a, a, flat, head, nxt, stamp, ctr, up)


@kernel_helper
def _near_list(a, b, n, up, k, flat, head, nxt, tag, ctr, near):
    """``Near(a, b)`` (spec §8.6) into ``near``: the vertices ``x > a``, ``x != b`` sharing a face with
    ``b``, ascending, then those of ``up[:k]`` (``Up(a)``) other than ``b`` sharing none; returns
    their number.  A new vertex ``b >= n`` has no face yet: ``Near(a, b)`` is ``Up(a)``."""
    if b >= n:
        for t in range(k):
            near[t] = up[t]
        return k
    count = _neighbours_above(b, a, flat, head, nxt, tag, ctr, near)
    token = ctr[0]
    for t in range(k):
        if tag[up[t]] != token:
            near[count] = up[t]
            count += 1
    return count


@kernel_helper
def _position(x, items, count):
    """Index of ``x`` in ``items[:count]``, or -1."""
    for t in range(count):
        if items[t] == x:
            return t
    return -1


@kernel_helper
def _fit(a, b, c, n, up, near, flat, head, nxt, stamp, tag, ctr):
    """How well the coded face ``(a, b, c)`` fits the neighbour lists: 2 if ``b`` is in ``Up(a)``,
    plus 1 if ``c`` is in ``Near(a, b)``."""
    k = _up_list(a, flat, head, nxt, stamp, ctr, up) if a < n else 0
    count = _near_list(a, b, n, up, k, flat, head, nxt, tag, ctr, near)
    return 2 * (_position(b, up, k) >= 0) + (_position(c, near, count) >= 0)


@kernel_helper
def _face_vertex(near, x, a, items, count, n, t, fresh, rename, es, out, ds, buf, probs, decode):
    """Code or decode one of the two later vertices of a face (spec §8.6, ``Vertex``): its rank in
    ``items[:count]`` after the bit ``near`` = 1; else the next new vertex after the fresh bit; else
    ``a + 1 + UInt`` (an existing vertex, or a new one already named).  ``fresh`` (1,) int64 counts
    the new vertices named so far.  Encode: ``x`` is the vertex (ids ``>= n``: the caller's new
    vertices, given their final ids in ``rename`` (t,) int64 as they are first named); returns its
    final id.  Decode: returns the vertex, or a negative code of :data:`_FACE_ERRORS`."""
    if not decode:
        found = _position(x, items, count)
        rc.enc_bit(es, out, probs, near, 1 if found >= 0 else 0)
        if found >= 0:
            rc.enc_uint(es, out, probs, _face_block(FB_RANK_B + near), found)
            return x
        if x >= n and rename[x - n] < 0:
            rc.enc_bit(es, out, probs, F_FRESH, 1)
            rename[x - n] = n + fresh[0]
            fresh[0] += 1
            return rename[x - n]
        rc.enc_bit(es, out, probs, F_FRESH, 0)
        if x >= n:
            x = rename[x - n]
        if x <= a:  # a raw id is coded after a: a new vertex named before the face's first one
            return -10
        rc.enc_uint(es, out, probs, _face_block(FB_RAW), x - a - 1)
        return x
    if rc.dec_bit(ds, buf, probs, near):
        r = rc.dec_uint(ds, buf, probs, _face_block(FB_RANK_B + near))
        if r < 0:
            return -1
        if r >= count:
            return -2
        return items[r]
    if rc.dec_bit(ds, buf, probs, F_FRESH):
        if fresh[0] >= t:
            return -6
        fresh[0] += 1
        return n + fresh[0] - 1
    r = rc.dec_uint(ds, buf, probs, _face_block(FB_RAW))
    if r < 0:
        return -1
    if a + 1 + r >= n + fresh[0]:
        return -3
    return a + 1 + r


def _face_kernel(flat, m, n, t, P, head, nxt, stamp, tag, ctr, coded, rename, up, near, es, out, ds, buf, probs,
                 decode):
    """Code (``decode`` 0) or decode (1) a face chunk over the mesh of the corner lists (``flat`` (3M,)
    int64 face slots, ``m`` faces, ``n`` vertices; ``P`` (N, D) int64 values) adding ``t`` vertices.

    Encode: ``coded`` (G, 4) int64 rows ``(a, b, c, twin)``, ``a`` the smallest of the three, ids ``>= n``
    naming the caller's new vertices, whose values are in ``P[n:n + t]`` in the caller's order; rows
    whose ``a`` is new (faces of new vertices only) after the others, which the kernel takes in the order
    of :func:`_next_new_row` (spec §8.6, the reference encoder), each rotated to start at the vertex
    it is taken for, so that its other new vertices are named after it; the kernel turns a twin row to
    ``(a, c, b)`` when that fits the neighbour lists better (:func:`_fit`), writes final ids into
    ``coded``, fills ``rename`` (t,) (caller's new vertex -> final id) and codes the values; the
    caller then reorders ``P[n:n + t]``.  Decode:
    appends the faces to ``flat`` from slot ``3m`` on and the values to ``P[n:n + t]``.  ``up`` /
    ``near`` (scratch) hold twice the largest valence.  Returns the number of faces (decode:
    appended), or a negative code of :data:`_FACE_ERRORS`."""
    room = len(flat) // 3 - m
    fresh = np.zeros(1, np.int64)
    if decode:
        g = rc.dec_uint(ds, buf, probs, _face_block(FB_COUNT))
        if g < 0:
            return -1
        g += 1
        if g > room:
            return -5
    else:
        g = len(coded)
        rc.enc_uint(es, out, probs, _face_block(FB_COUNT), g - 1)
    a = 0
    added = 0
    # encode: the rows of faces of new vertices only (from g0 on) are taken in the order
    # :func:`_next_new_row` gives (each rotated to the vertex it is taken for)
    g0 = g
    if not decode:
        for i in range(g):
            if coded[i, 0] >= n:
                g0 = i
                break
    tips = 0 if decode else t  # (the decoder needs none of this)
    pool = coded[g0:].copy()
    done = np.zeros(len(pool), np.bool_)
    tip_start, tip_rows = _rows_by_new_vertex(pool, n, tips)
    named = np.full(tips, -1, np.int64)  # final id - n -> the caller's id of that new vertex
    walk = np.zeros(3, np.int64)  # the final id visited, a cursor into its rows, the first pool row maybe unused
    pre0 = pre1 = pre2 = np.int64(0)  # the caller's ids of a face of new vertices only
    for i in range(g):
        if decode:
            gap = rc.dec_uint(ds, buf, probs, _face_block(FB_GAP))
            if gap < 0:
                return -1
            a += gap
        else:
            if i >= g0:
                if i == g0:  # the new vertices the faces with an old vertex named, by final id
                    for j in range(t):
                        if rename[j] >= 0:
                            named[rename[j] - n] = n + j
                    walk[0] = n
                    if fresh[0] > 0:
                        walk[1] = tip_start[named[0] - n]
                r, first = _next_new_row(pool, done, tip_start, tip_rows, named, walk, n, fresh[0])
                for q in range(3):  # rotated to start at ``first`` (the orientation kept)
                    coded[i, q] = pool[r, (q + (1 if pool[r, 1] == first else 2 if pool[r, 2] == first else 0)) % 3]
                coded[i, 3] = pool[r, 3]
                pre0, pre1, pre2 = coded[i, 0], coded[i, 1], coded[i, 2]
            x = coded[i, 0]
            if x >= n:  # a new vertex: already named, or named here (the next one)
                if rename[x - n] < 0:
                    rename[x - n] = n + fresh[0]
                x = rename[x - n]
            if x < a:
                return -9
            rc.enc_uint(es, out, probs, _face_block(FB_GAP), x - a)
            a = x
        if a > n + fresh[0]:
            return -3
        if a == n + fresh[0]:  # the next new vertex: the first of a face of new vertices only
            if fresh[0] >= t:
                return -6
            fresh[0] += 1
        if not decode:
            coded[i, 0] = a
            if coded[i, 3] == 1:
                b, c = coded[i, 1], coded[i, 2]
                if _fit(a, c, b, n, up, near, flat, head, nxt, stamp, tag, ctr) > _fit(a, b, c, n, up, near, flat,
                                                                                        head, nxt, stamp, tag, ctr):
                    coded[i, 1], coded[i, 2] = c, b
        k = _up_list(a, flat, head, nxt, stamp, ctr, up) if a < n else 0  # a new vertex has no neighbour yet
        b = _face_vertex(F_NEAR_B, coded[i, 1] if not decode else 0, a, up, k, n, t, fresh, rename, es, out, ds, buf,
                         probs, decode)
        if b < 0:
            return b
        count = _near_list(a, b, n, up, k, flat, head, nxt, tag, ctr, near)
        c = _face_vertex(F_NEAR_C, coded[i, 2] if not decode else 0, a, near, count, n, t, fresh, rename, es, out,
                         ds, buf, probs, decode)
        if c < 0:
            return c
        if b == c:
            return -4
        if decode:
            twin = rc.dec_bit(ds, buf, probs, F_TWIN)
        else:
            if i >= g0:  # its new vertices, named now if not before
                for y in (pre0, pre1, pre2):
                    named[rename[y - n] - n] = y
            coded[i, 1], coded[i, 2] = b, c
            twin = coded[i, 3]
            rc.enc_bit(es, out, probs, F_TWIN, twin)
        if added + 1 + twin > room:
            return -5
        s = 3 * (m + added)
        flat[s], flat[s + 1], flat[s + 2] = a, b, c
        if twin:
            flat[s + 3], flat[s + 4], flat[s + 5] = a, c, b
        added += 1 + twin
    if fresh[0] != t:
        return -7
    if not decode and t:  # the caller's values to final ids
        given = P[n : n + t].copy()
        for j in range(t):
            P[rename[j]] = given[j]
    if _face_values(flat, m, added, n, t, P, es, out, ds, buf, probs, decode) != 0:
        return -8
    return added


@kernel_helper(allocates=True)
def _rows_by_new_vertex(rows, n, t):
    """``(start (t + 1,), rows_of (3G,))`` int64: the rows of ``rows`` (G, 4) int64 that name each new vertex
    ``n + j`` (ids ``>= n``), ascending, as rows ``start[j] .. start[j + 1] - 1`` of ``rows_of`` (CSR)."""
    start = np.zeros(t + 1, np.int64)
    for r in range(len(rows)):
        for q in range(3):
            if rows[r, q] >= n:
                start[rows[r, q] - n + 1] += 1
    for j in range(t):
        start[j + 1] += start[j]
    fill = start[:t].copy()
    rows_of = np.empty(max(start[t], 1), np.int64)
    for r in range(len(rows)):
        for q in range(3):
            if rows[r, q] >= n:
                rows_of[fill[rows[r, q] - n]] = r
                fill[rows[r, q] - n] += 1
    return start, rows_of


@kernel_helper
def _next_new_row(pool, done, tip_start, tip_rows, named, walk, n, fresh):
    """The next face of new vertices only a face chunk codes (encode, spec §8.6 *reference encoder*):
    ``(row of pool, the caller's id of the vertex it starts at)``.  ``pool`` (G, 4) int64: those rows
    (caller's ids, each starting at its smallest), ``done`` (G,) bool the ones taken; ``tip_start`` /
    ``tip_rows`` (:func:`_rows_by_new_vertex`); ``named`` (t,) int64 the caller's id of each final id
    ``n ..  n + fresh - 1``; ``walk`` (3,) int64: the final id being visited, a cursor into its rows, the
    first pool row maybe not taken.

    The named new vertices are visited in the order of their final ids, each taking the rows not
    taken yet that name it (it is their smallest named vertex: its rows come when their first vertex
    is, ascending); when every named one is visited, the first row not taken starts at its first
    vertex, the next new vertex.  So every face's first vertex is named before or as it is coded,
    its later ones after it, and the first vertices never go down."""
    while walk[0] < n + fresh:
        x = named[walk[0] - n] - n
        while walk[1] < tip_start[x + 1]:
            r = tip_rows[walk[1]]
            walk[1] += 1
            if not done[r]:
                done[r] = True
                return r, x + n
        walk[0] += 1
        if walk[0] < n + fresh:
            walk[1] = tip_start[named[walk[0] - n] - n]
    while done[walk[2]]:
        walk[2] += 1
    r = walk[2]
    done[r] = True
    walk[1] = tip_start[pool[r, 0] - n]  # it is named next, as final id walk[0]
    return r, pool[r, 0]


@kernel_helper(allocates=True)
def _face_values(flat, m, added, n, t, P, es, out, ds, buf, probs, decode):
    """The new vertices' values (spec §8.6, *Values*): vertex ``u`` predicted by the floored mean of
    the other corners ``p < u`` of the chunk's faces naming it, one residual per column.  Returns 0,
    or -1 on an invalid code or a value out of range."""
    D = P.shape[1]
    if t == 0:
        return 0
    start = np.zeros(t + 1, np.int64)  # the corners naming each new vertex, grouped (CSR)
    for f in range(m, m + added):
        for j in range(3):
            if flat[3 * f + j] >= n:
                start[flat[3 * f + j] - n + 1] += 2
    for u in range(t):
        start[u + 1] += start[u]
    other = np.empty(start[t], np.int64)
    fill = start[:t].copy()
    for f in range(m, m + added):
        for j in range(3):
            x = flat[3 * f + j]
            if x >= n:
                other[fill[x - n]] = flat[3 * f + (j + 1) % 3]
                other[fill[x - n] + 1] = flat[3 * f + (j + 2) % 3]
                fill[x - n] += 2
    S = np.zeros(D, np.int64)
    for u in range(t):
        c = 0
        for q in range(D):
            S[q] = 0
        for e in range(start[u], start[u + 1]):
            p = other[e]
            if p < n + u:
                c += 1
                for q in range(D):
                    S[q] += P[p, q]
        if c == 0:  # the first vertex of a face of new vertices only: predicted by the vertex before it
            c = 1
            for q in range(D):
                S[q] = P[n + u - 1, q]
        for q in range(D):
            ctx = _face_block(FB_VALUE + min(q, 3))
            pred = S[q] // c
            if decode:
                r, ok = rc.dec_sint(ds, buf, probs, ctx)
                if ok == 0:
                    return -1
                x = pred + r
                if x >= MAX_VALUE or x <= -MAX_VALUE:
                    return -1
                P[n + u, q] = x
            else:
                rc.enc_sint(es, out, probs, ctx, P[n + u, q] - pred)
    return 0


def coded_faces(faces: np.ndarray) -> np.ndarray:
    """The rows ``(a, b, c, twin)`` (G, 4) int64 a face chunk codes for ``faces`` (L, 3) int64: each
    face rotated to start at its smallest vertex (orientation kept), a face and its reverse paired
    into one row with ``twin`` 1, rows sorted by ``(a, b, c)`` (spec §8.6, the reference encoder)."""
    f = face_keys(np.asarray(faces, np.int64).reshape(-1, 3))
    lo, hi = np.minimum(f[:, 1], f[:, 2]), np.maximum(f[:, 1], f[:, 2])
    order = np.lexsort((f[:, 1], hi, lo, f[:, 0]))  # a face and its reverse side by side, (a,lo,hi) first
    f, lo, hi = f[order], lo[order], hi[order]
    # Within one vertex triple the rows (a, lo, hi) come before (a, hi, lo): a face meets its reverse
    # only where the orientation changes, so each such place is one pair (the first row codes it).
    turn = np.zeros(len(f), bool)
    turn[1:] = (f[1:, 0] == f[:-1, 0]) & (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1]) & (f[1:, 1] != f[:-1, 1])
    twin = np.r_[turn[1:], False]
    rows = np.concatenate([f, twin[:, None].astype(np.int64)], axis=1)[~turn]
    return rows[np.lexsort((rows[:, 2], rows[:, 1], rows[:, 0]))]


class FaceChunk:
    """A face chunk to pack (:func:`pack_chunks`): ``faces`` (L, 3) int64 in ids of the mesh it
    follows, ids ``>= n`` naming new vertices whose values are ``values`` (t, D) int64 (row ``i``:
    id ``n + i``); the packer renumbers them in the order the faces first name them."""

    def __init__(self, faces, values=None):
        self.faces = np.asarray(faces, np.int64).reshape(-1, 3)
        self.values = None if values is None else np.asarray(values, np.int64)


def _face_scratch(state) -> tuple:
    """Scratch for ``Up`` / ``Near`` over ``state``'s mesh: (s,) int64 twice.  A vertex in ``c`` faces
    has at most ``2c`` neighbours, and ``Near(a, b)`` at most those of both; sized from the faces
    themselves, so no count kept elsewhere can make a kernel write past the end."""
    corners = np.bincount(state.faces[: state.m].ravel(), minlength=state.n)
    size = 4 * int(corners.max()) + 1 if len(corners) else 1
    return np.empty(size, np.int64), np.empty(size, np.int64)


def _pack_face_chunk(state, lists, chunk: FaceChunk) -> tuple:
    """Code ``chunk`` onto ``state`` (described by ``lists``) and apply it as the decoder will (new
    vertices' values in their final order, faces as decoded).  Returns ``(bytes, order)``:
    ``order[i]`` the index in ``chunk.values`` of the vertex that decodes as ``n + i``."""
    rows = coded_faces(chunk.faces)
    n, m = state.n, state.m
    D = state.positions.shape[1]
    values = np.zeros((0, D), np.int64) if chunk.values is None else chunk.values.reshape(-1, D)
    t = len(values)
    if not len(rows):
        raise ValueError("payload v2: a face chunk needs at least one face")
    if rows[:, :3].max() >= n + t or (rows[:, 1] == rows[:, 2]).any() or (rows[:, 0] == rows[:, 1]).any():
        raise ValueError("payload v2: a face chunk's faces must name three distinct vertices of the mesh or new ones")
    if m + len(chunk.faces) > len(state.faces) or n + t > len(state.positions):
        raise ValueError("payload v2: the face chunk exceeds the primitive's counts")
    enc = rc.Encoder(rc.new_probs(FACE_PROBS))
    enc.reserve((4 * INT_DECISIONS + 5) * len(rows) + INT_DECISIONS * (1 + D * t))
    up, near = _face_scratch(state)
    rename = np.full(t, -1, np.int64)
    state.positions[n : n + t] = values
    got = rc._kernel(_face_kernel)(state.faces.reshape(-1), m, n, t, state.positions, lists.head, lists.nxt,
                                   lists.stamp, lists.tag, lists.ctr, rows, rename, up, near, enc.es, enc.out,
                                   _NO_STATE, _NO_BYTES, enc.probs, 0)
    if got < 0:
        raise ValueError(f"payload v2: {_FACE_ERRORS[got]}")
    state.n, state.m = n + t, m + got
    lists.n = -1  # the corner lists no longer describe the mesh: rebuilt if a chunk that splits follows
    order = np.empty(t, np.int64)
    order[rename - n] = np.arange(t)
    return enc.finish(), order


def expand_rows(rows: np.ndarray) -> np.ndarray:
    """The faces (L, 3) int64 a face chunk's rows ``(a, b, c, twin)`` append, in order."""
    rows = np.asarray(rows, np.int64)
    pairs = np.stack([rows[:, :3], rows[:, [0, 2, 1]]], axis=1)  # (G, 2, 3)
    keep = np.stack([np.ones(len(rows), bool), rows[:, 3] == 1], axis=1)
    return pairs[keep]


def pack_face_chunk(values_before, faces_before, new_faces, new_values=None) -> tuple:
    """``(stored bytes, order)`` of a face chunk adding ``new_faces`` (L, 3) int64 to the mesh of
    ``values_before`` (n, D) int64 and ``faces_before`` (m, 3) int64; ids ``>= n`` in ``new_faces``
    name new vertices with ``new_values`` (t, D) int64 (row ``i``: id ``n + i``).  ``order[i]``: the
    row of ``new_values`` that decodes as vertex ``n + i`` (spec §8.6; for tests and other decoders)."""
    from ..progressive.vsplit import MeshState

    before = np.asarray(values_before, np.int64)
    n, D = before.shape
    faces = np.asarray(faces_before, np.int64).reshape(-1, 3)
    new = np.asarray(new_faces, np.int64).reshape(-1, 3)
    values = np.zeros((0, D), np.int64) if new_values is None else np.asarray(new_values, np.int64).reshape(-1, D)
    N, M = n + len(values), len(faces) + len(new)
    state = MeshState(np.concatenate([before, np.zeros((len(values), D), np.int64)]), faces, N, M)
    state.n = n
    lists = CornerLists(N, M)
    lists.sync(state)
    return _pack_face_chunk(state, lists, FaceChunk(new, values))


def decode_face_chunk(payload, state, model: ChunkDecoder, vertex_step: int, face_step: int) -> int:
    """Decode a face chunk (spec §8.6) onto ``state`` (int64 values): ``vertex_step`` / ``face_step``
    the vertices / faces its index entry adds.  Returns the number of faces appended.  FormatError
    on any invalid code, count or termination; ``model``'s split table is untouched."""
    lists = model.lists_for(state)
    n, m = state.n, state.m
    t = int(vertex_step)
    if t < 0 or n + t > state.vertex_limit:
        raise FormatError("face chunk: its index entry adds more vertices than the primitive declares")
    room = min(int(face_step), state.face_limit - m)
    if room < 1:
        raise FormatError("face chunk: its index entry adds no face")
    if t * state.positions.shape[1] + room > rc.MAX_DECISIONS_PER_BYTE * (len(payload) + 4):
        raise FormatError(f"face chunk: its index entry adds more than its {len(payload)} bytes can code")
    if state.reserve(n + t, m + room):
        lists.grow(state)
    dec = rc.Decoder(payload, rc.new_probs(FACE_PROBS))
    flat = state.faces[: m + room].reshape(-1)
    up, near = _face_scratch(state)
    got = rc._kernel(_face_kernel)(flat, m, n, t, state.positions, lists.head, lists.nxt, lists.stamp, lists.tag,
                                   lists.ctr, _NO_ROWS, _NO_RENAME, up, near, _NO_STATE, _NO_BYTES, dec.ds, dec.buf,
                                   dec.probs, 1)
    if got < 0:
        raise FormatError(_FACE_ERRORS[got])
    dec.finish("face chunk")
    state.n, state.m = n + t, m + got
    lists.n = -1  # rebuilt if a chunk that splits follows
    return got


_NO_ROWS = np.zeros((0, 4), np.int64)
_NO_RENAME = np.zeros(0, np.int64)
