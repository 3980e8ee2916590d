"""Decoder side: vertex-split records and applying a whole batch with array operations.

A batch of ``k`` independent vertex splits is three arrays (see :class:`SplitBatch`):

``v`` : (k,) int64, strictly increasing
    The vertices that split.  Split ``i`` creates vertex ``u_i = n + i`` where
    ``n`` is the vertex count before the batch.
``symbols`` : (I,) uint8
    One symbol per *incidence*: every face corner that holds a split vertex,
    in face-slot order (face 0 corner 0, face 0 corner 1, ...).  ``0`` the face
    stays with ``v``; ``1`` it moves to ``u``; ``2``/``3``/``4`` it moves and
    also names the left / right / both new faces.  The left new face is
    ``(u, v, a)`` and the right one ``(v, u, b)`` where ``a`` / ``b`` are the
    corners after / before ``v`` in the naming face.  New faces are appended in
    the order of their naming incidences, left before right.
``residual`` : (k, D) int64
    ``values(u) - floor(ring mean)``, where the ring mean is the face-weighted
    mean of ``u``'s neighbours after the split (for an interior vertex exactly
    the 1-ring mean): each face of ``u`` contributes its two other corners.
    A vertex's *values* are its grid position (3 columns) followed by its
    quantized attributes (texture coordinates, normals ..., ``D - 3`` columns);
    all of them are predicted the same way.

Because the encoder only puts independent collapses in one batch (removed
vertices pairwise non-adjacent, kept vertices distinct and not next to another
removed vertex; see :mod:`.simplify`), every incidence belongs to exactly one
split, a face moves for at most one split, and the ring of a new vertex holds no
other new vertex of its batch, so the whole batch is a handful of gathers, one
scatter and one append -- no per-split Python loop and no sort.  :func:`split_topology` is shared by the decoder and the encoder's
record builder, so both sides compute the same incidence order by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import FormatError
from .topology import compiled

#: Incidence symbols.
STAY, MOVE, MOVE_LEFT, MOVE_RIGHT, MOVE_BOTH = range(5)
SYMBOL_COUNT = 5


@dataclass
class SplitBatch:
    """One batch of vertex splits (see module docstring for the fields)."""

    v: np.ndarray
    symbols: np.ndarray
    residual: np.ndarray

    @property
    def size(self) -> int:
        return int(len(self.v))

    def new_face_count(self) -> int:
        return new_face_count(self.symbols)


def new_face_count(symbols: np.ndarray) -> int:
    """The faces the incidence symbols ``symbols`` (I,) uint8 (any order) append."""
    s = symbols
    return int(np.count_nonzero((s == MOVE_LEFT) | (s == MOVE_RIGHT)) + 2 * np.count_nonzero(s == MOVE_BOTH))


class MeshState:
    """A mesh growing in arrays with room to spare.

    Attributes
    ----------
    positions : (N, D) int64
        Vertex values: grid positions (columns 0-2) then quantized attributes;
        rows ``[:n]`` are valid.  (float64 when the state only replays
        connectivity over positions taken from elsewhere.)
    faces : (M, 3) int64
        Triangles; rows ``[:m]`` are valid (int64: numpy indexes with intp, int32 would be cast on every use).
    vertex_limit, face_limit : int
        The counts the mesh may reach (a stream's declared counts): :meth:`reserve` refuses more.

    ``N`` / ``M`` are the limits when the state is made with ``grow=False`` (an encoder, which knows
    its counts).  A decoder makes it with ``grow=True``: the arrays start at the base's size and
    :meth:`reserve` grows them (at least doubling, never past the limits) as splits are actually
    decoded, so memory follows what a stream holds, not what its header claims.  Growing replaces
    the arrays: read ``positions`` / ``faces`` again after a :meth:`reserve` (views taken before keep
    the rows they had).
    """

    def __init__(self, base_positions, base_faces, vertex_capacity, face_capacity, dtype=np.int64, *,
                 grow: bool = False):
        n0 = len(base_positions)
        m0 = len(base_faces)
        if vertex_capacity < n0 or face_capacity < m0:
            raise FormatError("declared full-resolution counts are smaller than the base mesh")
        self.vertex_limit, self.face_limit = int(vertex_capacity), int(face_capacity)
        base_positions = np.asarray(base_positions)
        N = min(self.vertex_limit, 2 * n0 + GROW_START) if grow else self.vertex_limit
        M = min(self.face_limit, 2 * m0 + 2 * GROW_START) if grow else self.face_limit
        self.positions = np.empty((N, base_positions.shape[1]), dtype=dtype)
        self.faces = np.empty((M, 3), dtype=np.int64)
        self.positions[:n0] = base_positions
        self.faces[:m0] = base_faces
        self.n = n0
        self.m = m0
        self._sid = np.full(max(n0, 1), -1, dtype=np.int32)  # grown as the mesh grows (not from declared sizes)

    def reserve(self, vertices: int, faces: int) -> bool:
        """Room for ``vertices`` vertices and ``faces`` faces in all; True when an array was replaced.
        FormatError when either exceeds the declared limits (the stream holds more than it says)."""
        if vertices > self.vertex_limit:
            raise FormatError("splits exceed the declared vertex count")
        if faces > self.face_limit:
            raise FormatError("splits exceed the declared face count")
        grown = False
        if vertices > len(self.positions):
            self.positions = _grown(self.positions, self.n, vertices, self.vertex_limit)
            grown = True
        if faces > len(self.faces):
            self.faces = _grown(self.faces, self.m, faces, self.face_limit)
            grown = True
        return grown

    def current_positions(self) -> np.ndarray:
        return self.positions[: self.n]

    def current_faces(self) -> np.ndarray:
        return self.faces[: self.m]


#: Rows a growing :class:`MeshState` starts with beyond twice its base.
GROW_START = 64
#: A growing :class:`MeshState` takes its whole declared room once it needs this fraction of it: the
#: last copy then moves a quarter of the arrays at most, not half (a valid stream reaches its counts),
#: and a claim is trusted only up to this many times what was decoded.
GROW_TO_LIMIT = 8


def _grown(rows: np.ndarray, valid: int, need: int, limit: int) -> np.ndarray:
    """A copy of ``rows`` (R, ...) with room for ``need`` rows: at least twice R, at most ``limit``
    (all of it from ``limit / GROW_TO_LIMIT`` on); its first ``valid`` rows copied, the others uninitialised."""
    size = limit if need * GROW_TO_LIMIT >= limit else min(limit, max(need, 2 * len(rows)))
    out = np.empty((size,) + rows.shape[1:], rows.dtype)
    out[:valid] = rows[:valid]
    return out


@dataclass
class SplitTopology:
    """What :func:`split_topology` did, for the geometry step and the watermark.

    ``u`` : (k,) int64 new vertex ids; ``ring_sum`` : (k, D) float64 sum of the
    neighbour corners of u's faces; ``ring_count`` : (k,) int64 twice the number
    of u's faces; ``incidences`` : (I,) int64 flat corner ids in face-slot order; ``owner`` : (I,)
    split index of each incidence (both held in ``incidence_lists``, a pair or a function that
    lists them when first asked).  The ring itself, as it is summed: ``ring_owner``
    (R,) int64 split index of each face of a new vertex and ``ring_a`` / ``ring_b``
    (R,) int64 its two other corners (moved faces in incidence order, then the
    left new faces, then the right ones), for the watermark's ring binding.
    """

    u: np.ndarray
    ring_sum: np.ndarray
    ring_count: np.ndarray
    #: ``(incidences, owner)``, or a function that lists them when first asked
    incidence_lists: object = field(repr=False)
    #: ``(ring_owner, ring_a, ring_b)``, or a function that lists them when first asked
    #: (a plain decode never asks: only the watermark's ring binding reads the ring)
    ring: object = field(default=None, repr=False)

    def _listed(self, name: str) -> tuple:
        """Field ``name`` (a tuple of arrays), listed now if it still holds the function that lists it."""
        value = getattr(self, name)
        if callable(value):
            value = value()
            setattr(self, name, value)
        return value

    incidences = property(lambda self: self._listed("incidence_lists")[0])
    owner = property(lambda self: self._listed("incidence_lists")[1])
    ring_owner = property(lambda self: self._listed("ring")[0])
    ring_a = property(lambda self: self._listed("ring")[1])
    ring_b = property(lambda self: self._listed("ring")[2])

    def prediction(self) -> np.ndarray:
        """(k, D) int64 ``floor(ring mean)``, the predictor of the new vertices' values."""
        total = np.rint(self.ring_sum).astype(np.int64)
        return np.floor_divide(total, self.ring_count[:, None])

    def centroid(self) -> np.ndarray:
        """(k, D) float64 exact ring mean (columns 0-2: the watermark's ring centroid)."""
        return self.ring_sum / self.ring_count[:, None]


def find_incidences(state: MeshState, v: np.ndarray):
    """Face corners holding one of the split vertices ``v`` (k,), in face-slot order.

    Returns ``(incidences (I,) int64 flat corner ids, owner (I,) int64 split index)``.
    """
    k = len(v)
    if len(state._sid) < state.n:
        state._sid = np.full(min(len(state.positions), max(state.n, 2 * len(state._sid))), -1, dtype=np.int32)
    sid = state._sid
    kernel = compiled(_incidences_kernel)
    if kernel is not None:
        return kernel(state.faces[: state.m].reshape(-1), np.asarray(v, np.int64), sid)
    sid[v] = np.arange(k, dtype=np.int32)
    flat = state.faces[: state.m].reshape(-1)
    s = sid[flat]
    inc = np.flatnonzero(s >= 0)
    sid[v] = -1
    return inc, s[inc]


def _incidences_kernel(flat, v, sid):
    """Compiled :func:`find_incidences` over face slots ``flat`` (3m,) int64; ``sid`` (>= n,) int32
    scratch, all -1 on entry and on return.  Returns ``(inc (I,) int64, owner (I,) int32)``."""
    for i in range(len(v)):
        sid[v[i]] = i
    count = 0
    for x in flat:
        if sid[x] >= 0:
            count += 1
    inc = np.empty(count, np.int64)
    owner = np.empty(count, np.int32)
    j = 0
    for c in range(len(flat)):
        s = sid[flat[c]]
        if s >= 0:
            inc[j] = c
            owner[j] = s
            j += 1
    for i in range(len(v)):
        sid[v[i]] = -1
    return inc, owner


def split_topology(state: MeshState, v: np.ndarray, symbols: np.ndarray, *, incidences=None) -> SplitTopology:
    """Apply the connectivity of a batch of splits; positions of the new vertices are left unset.

    Parameters
    ----------
    state : MeshState, advanced in place (``n += k``, ``m += new faces``)
    v : (k,) int64 strictly increasing split vertices, all ``< state.n``
    symbols : (I,) uint8 incidence symbols (see module docstring)
    incidences : optional precomputed ``find_incidences(state, v)``

    Raises
    ------
    FormatError
        Records that do not fit the current mesh (corrupt or hostile input).
    """
    k = len(v)
    n0, m0 = state.n, state.m
    if k == 0:
        raise FormatError("a split batch is empty")
    if v[0] < 0 or v[-1] >= n0 or (k > 1 and np.any(np.diff(v) <= 0)):
        raise FormatError("split vertex ids out of range or not increasing")
    if n0 + k > state.vertex_limit:
        raise FormatError("splits exceed the declared vertex count")
    inc, owner = incidences if incidences is not None else find_incidences(state, v)
    if len(inc) != len(symbols):
        raise FormatError(f"batch has {len(symbols)} incidence symbols, the mesh has {len(inc)} incidences")
    sym = np.asarray(symbols)
    if len(sym) and int(sym.max()) >= SYMBOL_COUNT:
        raise FormatError("unknown incidence symbol")
    state.reserve(n0 + k, min(m0 + new_face_count(sym), state.face_limit))  # more faces: refused below

    kernel = compiled(_split_kernel)
    if kernel is not None:
        return _split_compiled(kernel, state, v, sym, inc, owner)
    flat = state.faces.reshape(-1)
    u_of = n0 + np.arange(k)

    moved = sym != STAY
    mi = inc[moved]
    ms = owner[moved]
    msym = sym[moved]
    base = mi - mi % 3
    a = flat[base + (mi + 1) % 3]  # corner after v
    b = flat[base + (mi + 2) % 3]  # corner before v

    # the incidences that name new faces, and which ones
    wing = np.flatnonzero(msym >= MOVE_LEFT)
    ws, wms, wa, wb = msym[wing], ms[wing], a[wing], b[wing]
    left = (ws == MOVE_LEFT) | (ws == MOVE_BOTH)
    right = (ws == MOVE_RIGHT) | (ws == MOVE_BOTH)
    per = left.astype(np.int64) + right
    n_new = int(per.sum())
    if m0 + n_new > len(state.faces):
        raise FormatError("splits exceed the declared face count")
    # every split must own one or two new faces
    wings_per_split = np.bincount(wms, weights=per, minlength=k)
    if np.any(wings_per_split == 0) or np.any(wings_per_split > 2):
        raise FormatError("a split names no new face or more than two")
    start = np.cumsum(per) - per
    lm, rm = wms[left], wms[right]
    lv, rv = v[lm], v[rm]
    new = np.empty((n_new, 3), dtype=np.int64)
    new[start[left]] = np.stack([u_of[lm], lv, wa[left]], axis=1)  # (u, v, a)
    new[start[right] + left[right]] = np.stack([rv, u_of[rm], wb[right]], axis=1)  # (v, u, b)

    flat[mi] = u_of[ms]
    state.faces[m0 : m0 + n_new] = new

    # ring of u: two other corners of each moved face, and (v, wing) of each new face
    P = state.positions
    own = np.concatenate([ms, lm, rm])
    ra = np.concatenate([a, lv, rv])
    rb = np.concatenate([b, wa[left], wb[right]])
    pts = P[ra] + P[rb]
    d = P.shape[1]
    ring_sum = np.bincount(
        (own[:, None] * d + np.arange(d)).ravel(), weights=pts.ravel(), minlength=k * d
    ).reshape(k, d)
    ring_count = 2 * np.bincount(own, minlength=k)
    state.n = n0 + k
    state.m = m0 + n_new
    return SplitTopology(u_of, ring_sum, ring_count, (inc, owner), (own, ra, rb))


def _split_compiled(kernel, state, v, sym, inc, owner) -> SplitTopology:
    """:func:`split_topology`'s work after the argument checks, by :func:`_split_kernel`.

    Same faces, same face order and bit-identical ring sums as the numpy path.
    """
    k, n0, m0 = len(v), state.n, state.m
    d = state.positions.shape[1]
    v, sym, owner = np.asarray(v, np.int64), np.asarray(sym, np.uint8), np.asarray(owner, np.int64)
    ring_sum = np.zeros((k, d), dtype=np.float64)
    ring_count = np.zeros(k, dtype=np.int64)
    a, b = np.empty(len(inc), np.int64), np.empty(len(inc), np.int64)
    n_new = kernel(state.faces.reshape(-1), m0, len(state.faces), n0, v, sym, inc, owner, state.positions,
                   ring_sum, ring_count, a, b)
    if n_new == -1:
        raise FormatError("a split names no new face or more than two")
    if n_new == -2:
        raise FormatError("splits exceed the declared face count")
    state.n = n0 + k
    state.m = m0 + n_new
    return SplitTopology(n0 + np.arange(k), ring_sum, ring_count, (inc, owner),
                         lambda: _ring_lists(v, sym, owner, a, b))


def _ring_lists(v, sym, owner, a, b) -> tuple:
    """``(ring_owner, ring_a, ring_b)`` (R,) int64 of a batch, as the numpy path of
    :func:`split_topology` lists them: the two other corners of each moved face, then
    ``(v, a)`` of every left new face, then ``(v, b)`` of every right one.  ``a`` / ``b``
    (I,) int64: the corners after / before the split vertex of every incidence, as they
    were before the batch rewrote the faces."""
    moved = sym != STAY
    left = (sym == MOVE_LEFT) | (sym == MOVE_BOTH)
    right = (sym == MOVE_RIGHT) | (sym == MOVE_BOTH)
    own = np.concatenate([owner[moved], owner[left], owner[right]])
    return own, np.concatenate([a[moved], v[owner[left]], v[owner[right]]]), np.concatenate([b[moved], a[left], b[right]])


def _split_kernel(flat, m0, face_capacity, n0, v, sym, inc, owner, P, ring_sum, ring_count, a, b):
    """Compiled twin of the numpy body of :func:`split_topology` (see there for the rules).

    flat (3M,) int64 face slots, v (k,) int64, sym (I,) uint8, inc / owner (I,) int64,
    P (N, D) values; fills ring_sum (k, D) float64, ring_count (k,) int64 and a / b (I,) int64
    (each incidence's corners after / before its vertex, read before any face is rewritten)
    and writes the faces.  Returns the number of new faces, -1 when a split names 0 or > 2 new faces, -2
    when they exceed ``face_capacity``; nothing is written in those cases.  Ring sums add in
    the numpy path's order (moved faces, then left, then right new faces): same float bits.
    """
    k = len(v)
    n_inc = len(inc)
    wings = np.zeros(k, np.int64)
    n_new = 0
    for j in range(n_inc):
        s = sym[j]
        if s >= 2:
            w = 1 if s < 4 else 2
            wings[owner[j]] += w
            n_new += w
    for i in range(k):
        if wings[i] == 0 or wings[i] > 2:
            return -1
    if m0 + n_new > face_capacity:
        return -2
    for j in range(n_inc):  # read every corner before any is rewritten
        c = inc[j]
        base = c - c % 3
        a[j] = flat[base + (c + 1) % 3]
        b[j] = flat[base + (c + 2) % 3]
    d = P.shape[1]
    slot = 3 * m0
    for j in range(n_inc):
        s = sym[j]
        if s == 0:
            continue
        i = owner[j]
        for t in range(d):
            ring_sum[i, t] += P[a[j], t] + P[b[j], t]
        ring_count[i] += 2
        if s == 2 or s == 4:  # left new face (u, v, a)
            flat[slot] = n0 + i
            flat[slot + 1] = v[i]
            flat[slot + 2] = a[j]
            slot += 3
        if s == 3 or s == 4:  # right new face (v, u, b)
            flat[slot] = v[i]
            flat[slot + 1] = n0 + i
            flat[slot + 2] = b[j]
            slot += 3
    for j in range(n_inc):
        if sym[j] != 0:
            flat[inc[j]] = n0 + owner[j]
    for side in (2, 3):  # the new faces' (v, wing) pairs, all left ones before all right ones
        for j in range(n_inc):
            s = sym[j]
            if s == side or s == 4:
                i = owner[j]
                w = a[j] if side == 2 else b[j]
                for t in range(d):
                    ring_sum[i, t] += P[v[i], t] + P[w, t]
                ring_count[i] += 2
    return n_new


def apply_batch(state: MeshState, batch: SplitBatch) -> SplitTopology:
    """Apply a whole :class:`SplitBatch`: connectivity, then positions ``prediction + residual``."""
    topo = split_topology(state, batch.v, batch.symbols)
    res = np.asarray(batch.residual, dtype=np.int64)
    if res.shape != (len(batch.v), state.positions.shape[1]):
        raise FormatError("residual array does not match the split count")
    state.positions[topo.u] = topo.prediction() + res
    return topo
