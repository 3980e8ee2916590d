"""Encoder side: turn a :class:`CollapseLog` into split records a decoder can replay.

The builder replays the stream exactly as a decoder will, coarse to fine, on a
:class:`~pmwm_codec.progressive.vsplit.MeshState`, and at every batch derives the
symbols from what the simplifier recorded (which faces moved, which were
deleted).  Running the decoder's own :func:`split_topology` guarantees that the
encoder's idea of incidence order, new vertex ids and new face slots is the
decoder's.  The geometry step is where the watermark hooks in: the caller may
move each new vertex (``embed``) after seeing its ring, before the residual is
taken, so the watermark sits on the grid exactly as the decoder will see it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import numpy as np

from .grid import Grid
from .simplify import CollapseLog
from .topology import compiled, face_keys
from .vsplit import MOVE, MOVE_LEFT, MOVE_RIGHT, MeshState, SplitBatch, SplitTopology, find_incidences, split_topology

#: embed(batch_index, topology, values (k, D) int64, state) -> (k, D) int64 (moves columns 0-2)
EmbedHook = Callable[[int, SplitTopology, np.ndarray, MeshState], np.ndarray]


@dataclass
class ProgressiveMesh:
    """A base mesh plus batches of vertex splits, all on one :class:`Grid`.

    Attributes
    ----------
    grid : Grid
    base_positions : (n0, 3) int64 grid coordinates
    base_faces : (m0, 3) int64
    batches : list[SplitBatch], coarse to fine
    vertex_count, face_count : int, at full resolution
    batch_errors : (len(batches),) float64
        Geometric error (grid units) of the level *before* each batch is applied.
    vertex_order : (n,) int64
        Input vertex id -> id in the decoded mesh.
    face_order : (m - L,) int64
        Decoded face id -> input face id (of the faces the splits make).
    late_faces : (L, 3) int64
        Faces that no split makes, appended after every batch by a face chunk (bitstream.md
        §8.6), in decoded ids; ids ``n + j`` (``n``: the vertices the splits reach) name the
        vertex of ``late_values[j]``.  ``vertex_count`` and ``face_count`` count them.
    late_values : (t, D) int64
        Values of the vertices only the late faces name.
    full_values : (n, D) int64 or None
        Values of the full decode (of the vertices the splits reach), in decoded ids: where the
        builder's replay, the decoder's own (:func:`split_topology`, residuals against its
        predictions), ends; :func:`~pmwm_codec.distortion.decoded_positions` reads them instead
        of replaying the batches again.  None: not known (replay the batches).
    payloads : list[bytes] or None
        The chunk payloads (version 2) when the builder coded them on its replay
        (:func:`build_progressive`'s ``chunks``), else None.
    """

    grid: Grid
    base_positions: np.ndarray
    base_faces: np.ndarray
    batches: list
    vertex_count: int
    face_count: int
    batch_errors: np.ndarray = field(default_factory=lambda: np.zeros(0))
    vertex_order: Optional[np.ndarray] = None
    face_order: Optional[np.ndarray] = None
    late_faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    late_values: Optional[np.ndarray] = None
    full_values: Optional[np.ndarray] = field(default=None, repr=False)
    payloads: Optional[list] = field(default=None, repr=False)

    @property
    def split_count(self) -> int:
        return sum(b.size for b in self.batches)

    def new_state(self) -> MeshState:
        return MeshState(self.base_positions, self.base_faces, self.vertex_count, self.face_count)


def build_progressive(
    log: CollapseLog,
    positions: np.ndarray,
    grid: Grid,
    *,
    base_vertex_order: Optional[np.ndarray] = None,
    base_faces_decoded: Optional[np.ndarray] = None,
    embed: Optional[EmbedHook] = None,
    late_faces: Optional[np.ndarray] = None,
    late_values: Optional[np.ndarray] = None,
    chunks: Optional[list] = None,
    plane: Optional[np.ndarray] = None,
) -> ProgressiveMesh:
    """Replay ``log`` coarse to fine and emit :class:`SplitBatch` records.

    Parameters
    ----------
    log : CollapseLog from :func:`~pmwm_codec.progressive.simplify.simplify`
    positions : (n, D) int64 grid coordinates of the input mesh, then quantized
        attributes (columns 3 and up ride along; only columns 0-2 shape the mesh)
    grid : Grid the positions live on
    base_vertex_order : (n0,) int64, optional
        Input ids of the base vertices in the order the decoder will see them
        (e.g. after a Draco round trip).  Default: ascending input ids.
    base_faces_decoded : (m0, 3) int64, optional
        Base faces as the decoder will see them, in *decoded* vertex ids (any
        face order and rotation).  Default: the simplifier's order.
    embed : EmbedHook, optional
        Moves the new vertices of each batch (watermark).
    late_faces : (L, 3) int64, optional
        Faces the log left out (the simplifier never saw them), sent after every batch; ids ``n + j``
        name vertices the log does not have, whose values are ``late_values`` (t, D) int64.
    chunks : list[range], optional
        The chunks of payload version 2 (consecutive batch indices, coarse to fine, covering every
        batch; an empty range, last, is the face chunk of the late faces): without ``embed``, the
        replay is the packer's own (:class:`~pmwm_codec.format.records_v2.ChunkPacker`), which codes
        each batch as it applies it (``payloads``); with ``embed`` they are ignored (the caller packs).
    plane : (D,) int64, optional
        The packer's value columns predicted on the ring's plane
        (:func:`~pmwm_codec.format.records_v2.plane_columns`).
    """
    n, m = log.vertex_count, log.face_count
    order0, vid, base_faces, base_face_ids = _base_ids(log, base_vertex_order, base_faces_decoded)
    t = 0 if late_values is None else len(late_values)
    n_late = 0 if late_faces is None else len(np.asarray(late_faces).reshape(-1, 3))
    packer = None
    if chunks is not None and embed is None:
        from ..format.records_v2 import ChunkPacker

        _check_chunks(chunks, len(log.batches))
        starts = {grp.start: len(grp) for grp in chunks if len(grp)}
        stops = {grp.stop for grp in chunks if len(grp)}
        state = MeshState(positions[order0], base_faces, n + t, m + n_late)  # room for the face chunk
        packer = ChunkPacker(state, plane)
    else:
        state = MeshState(positions[order0], base_faces, n, m)
    face_src = np.full(m, -1, dtype=np.int64)  # decoded face id -> input face id
    face_src[: len(base_faces)] = base_face_ids
    moved_by = np.full(m, -1, dtype=np.int64)  # scratch over input (replay) or decoded (packer) face ids
    if packer is not None:  # input face id -> decoded face id (-1: not made yet), face_src's inverse
        face_dst = np.full(m, -1, dtype=np.int64)
        face_dst[base_face_ids] = np.arange(len(base_faces))

    batches = []
    errors = []
    for j, cb in enumerate(reversed(log.batches)):
        if packer is None:
            batches.append(_replay_batch(j, cb, state, positions, vid, face_src, moved_by, embed))
        else:
            if j in starts:
                packer.begin(starts[j])
            batches.append(_replay_packed(cb, state, positions, vid, face_src, face_dst, moved_by, packer))
            if j + 1 in stops:
                packer.end()
        errors.append(float(np.maximum.reduce(cb.error)) if len(cb.u) else 0.0)  # cb.error.max()

    if state.n != n or state.m != m or np.any(face_src < 0):
        raise AssertionError("progressive build did not reach the full mesh")  # a bug, not bad input
    full_values = state.current_positions()
    named = np.concatenate([vid, n + np.arange(t)])  # the late vertices keep their order (the packer renumbers)
    late = np.zeros((0, 3), np.int64) if late_faces is None else named[np.asarray(late_faces, np.int64).reshape(-1, 3)]
    if packer is not None and len(chunks) and not len(chunks[-1]):
        from ..format.records_v2 import FaceChunk

        packer.face_chunk(FaceChunk(late, late_values))  # writes past full_values' rows only
    return ProgressiveMesh(
        grid=grid,
        base_positions=positions[order0].astype(np.int64),
        base_faces=base_faces,
        batches=batches,
        vertex_count=n + t,
        face_count=m + len(late),
        batch_errors=np.array(errors, dtype=np.float64),
        vertex_order=vid,
        face_order=face_src,
        late_faces=late,
        late_values=None if late_values is None else np.asarray(late_values, np.int64),
        full_values=full_values,
        payloads=None if packer is None else packer.payloads,
    )


def _check_chunks(chunks: list, count: int) -> None:
    """ValueError unless ``chunks`` (list of range) are consecutive ranges over ``count`` batches, in
    order, with at most one empty range, last (the face chunk)."""
    spans = [grp for grp in chunks if len(grp)]
    stops = [0] + [grp.stop for grp in spans]
    if ([grp.start for grp in spans] != stops[:-1] or stops[-1] != count or any(grp.step != 1 for grp in spans)
            or len(chunks) - len(spans) > 1 or (len(spans) < len(chunks) and len(chunks[-1]))):
        raise ValueError("chunks must be consecutive batch ranges covering every batch, a face chunk last")


def _base_ids(log: CollapseLog, base_vertex_order, base_faces_decoded) -> tuple:
    """The base as the decoder sees it.

    Returns ``(order0 (n0,) int64 input ids of the decoded base vertices, vid (n,) int64
    input id -> decoded id (-1 until the vertex exists), base faces (m0, 3) int64 in
    decoded ids, base face ids (m0,) int64 input face id of each)``.
    """
    order0 = log.base_vertices if base_vertex_order is None else np.asarray(base_vertex_order, np.int64)
    n0 = len(order0)
    vid = np.full(log.vertex_count, -1, dtype=np.int64)
    vid[order0] = np.arange(n0)
    base_corners = vid[log.base_corners]
    if base_faces_decoded is None:
        return order0, vid, base_corners, log.base_faces
    base_faces = np.asarray(base_faces_decoded, np.int64)
    return order0, vid, base_faces, _match_faces(base_faces, base_corners, log.base_faces, n0)


def _replay_batch(j, cb, state, positions, vid, face_src, moved_by, embed) -> SplitBatch:
    """Undo collapse batch ``cb`` (stream batch ``j``) on ``state``; return its split record.

    Updates ``state``, ``vid`` (new vertices get their decoded ids) and ``face_src`` (the
    appended faces get their input face ids) in place; ``moved_by`` is scratch.
    """
    order, rank, v_sorted = _split_order(vid[cb.v], state.n)

    inc, owner = find_incidences(state, v_sorted)
    symbols = _symbols(state, inc, owner, vid, face_src, moved_by, cb, order, rank)
    topo = split_topology(state, v_sorted, symbols, incidences=(inc, owner))

    u_in = cb.u[order]
    vid[u_in] = topo.u
    target = np.take(positions, u_in, axis=0).astype(np.int64)
    if embed is not None:
        target = np.asarray(embed(j, topo, target, state), dtype=np.int64)
    residual = target - topo.prediction()
    state.positions[topo.u] = target
    return SplitBatch(v_sorted, symbols, residual)


def _split_order(vf: np.ndarray, n: int) -> tuple:
    """The splits of a batch sorted by their decoded kept vertex ``vf`` (k,) int64 (distinct, in ``[0, n)``: a
    batch keeps each vertex once): ``(order, rank, v_sorted)`` (k,) int64, ``rank`` the inverse of ``order``.
    Distinct keys have one sorted order: numpy's default sort finds it (~4x faster than its stable one, a
    timsort here); compiled, a bitmap of the n vertices read word by word (:func:`_split_order_kernel`)."""
    kernel = compiled(_split_order_kernel)
    if kernel is not None:
        return kernel(vf, n)
    order = np.argsort(vf)
    rank = np.empty(len(vf), dtype=np.int64)
    rank[order] = np.arange(len(vf))
    return order, rank, vf[order]


#: De Bruijn table: the bit index of a 64-bit word with one bit set, at ``(word * _DE_BRUIJN) >> 58``.
_DE_BRUIJN = 0x03F79D71B4CA8B09
_BIT_OF = np.zeros(64, np.int64)
_BIT_OF[[((1 << b) * _DE_BRUIJN & (2**64 - 1)) >> 58 for b in range(64)]] = np.arange(64)


def _split_order_kernel(vf, n):
    """Compiled :func:`_split_order`: each key's bit set in an (n / 64,) bitmap and its row kept in an (n,)
    array (only the keys' entries written), then the words read in order, their set bits lowest first."""
    k = len(vf)
    bits = np.zeros(n // 64 + 1, np.uint64)
    row = np.empty(n, np.int64)
    lo, hi = n, -1
    for i in range(k):
        d = vf[i]
        row[d] = i
        bits[d >> 6] |= np.uint64(1) << np.uint64(d & 63)
        lo, hi = min(lo, d >> 6), max(hi, d >> 6)
    order, rank, v_sorted = np.empty(k, np.int64), np.empty(k, np.int64), np.empty(k, np.int64)
    s = 0
    for w in range(lo, hi + 1):
        word = bits[w]
        while word:
            low = word & (np.uint64(0) - word)
            d = (w << 6) + _BIT_OF[np.int64((low * np.uint64(_DE_BRUIJN)) >> np.uint64(58))]
            order[s], rank[row[d]], v_sorted[s] = row[d], s, d
            s += 1
            word ^= low
    return order, rank, v_sorted


def _replay_packed(cb, state, positions, vid, face_src, face_dst, moved_by, packer) -> SplitBatch:
    """:func:`_replay_batch` without an embedder, by the packer's path: ``packer``
    (:class:`~pmwm_codec.format.records_v2.ChunkPacker` over ``state``, in a chunk) codes the batch's
    selection, the symbols are derived from the incidences it gathers (:func:`_packed_symbols`), and it
    codes the connectivity and the values as it applies them.  ``face_dst`` (M,) int64: ``face_src``'s
    inverse (input face id -> decoded id), updated with it; ``moved_by`` (M,) int64: scratch, -1.  Returns
    the batch in version 1 terms (its symbols and residuals listed when first read)."""
    k = len(cb.u)
    n0, m0 = state.n, state.m
    order, rank, v_sorted = _split_order(vid[cb.v], n0)
    gstart, inc, a, b = packer.mask(v_sorted)
    sym = _packed_symbols(gstart, inc, a, b, vid, face_dst, moved_by, cb, order, rank)
    u_in = cb.u[order]
    vid[u_in] = n0 + np.arange(k)
    np.take(positions, u_in, axis=0, out=state.positions[n0 : n0 + k])
    batch = packer.split(v_sorted, gstart, inc, a, b, sym)
    _name_appended_faces(face_src, face_dst, state.faces[m0 : state.m], m0, n0, cb, order)
    return batch


def _packed_symbols(gstart, inc, a, b, vid, face_dst, moved_by, cb, order, rank) -> np.ndarray:
    """The symbols (I,) uint8 of collapse batch ``cb`` undone, for its incidences grouped by split
    (:meth:`~pmwm_codec.format.records_v2.ChunkPacker.mask`: split ``s`` has ``gstart[s] ..
    gstart[s + 1] - 1``, ascending corners ``inc``, the corners after / before its vertex ``a`` / ``b``,
    all (I,) int64); splits in ``order``, ``rank`` its inverse; ``face_dst`` (M,) int64 the decoded id
    of each input face.  An incidence moves when its face is one of its split's moved faces (a face
    moves for one split at most: the batch's removed vertices share no face), marked in ``moved_by``
    (M,) int64 over decoded face ids (scratch, -1 on entry and on return) with the split's rank."""
    kernel = compiled(_packed_symbols_kernel)
    if kernel is not None:
        return kernel(gstart, inc, a, b, vid, face_dst, moved_by, cb.moved_face, cb.moved_by, rank, order,
                      cb.wing_left, cb.wing_right)
    owner = np.repeat(np.arange(len(order)), np.diff(gstart))
    mover = face_dst[cb.moved_face]
    moved_by[mover] = rank[cb.moved_by]
    moved = moved_by[inc // 3] == owner
    moved_by[mover] = -1
    left, right = _wing_incidences(a, b, owner, vid, cb, order, moved)
    return (moved * MOVE + left * (MOVE_LEFT - MOVE) + right * (MOVE_RIGHT - MOVE)).astype(np.uint8)


def _packed_symbols_kernel(gstart, inc, a, b, vid, face_dst, moved_by, moved_face, moved_of, rank, order, wing_left,
                           wing_right):
    """Compiled :func:`_packed_symbols` (``moved_face`` / ``moved_of`` / ``wing_*``: the batch's arrays,
    input ids, collapse order): the moved faces marked with their split's rank, then one pass over the
    incidences, split by split."""
    for j in range(len(moved_face)):
        moved_by[face_dst[moved_face[j]]] = rank[moved_of[j]]
    symbols = np.zeros(len(inc), np.uint8)
    for s in range(len(order)):
        i = order[s]
        wl = vid[wing_left[i]] if wing_left[i] >= 0 else -1  # the wings' decoded ids (-1: none)
        wr = vid[wing_right[i]] if wing_right[i] >= 0 else -1
        named_left = named_right = False  # the split has named its left / right new face
        for t in range(gstart[s], gstart[s + 1]):
            if moved_by[inc[t] // 3] != s:
                continue
            left = wl >= 0 and a[t] == wl and not named_left
            right = wr >= 0 and b[t] == wr and not named_right
            named_left |= left
            named_right |= right
            symbols[t] = MOVE + left * (MOVE_LEFT - MOVE) + right * (MOVE_RIGHT - MOVE)
    for j in range(len(moved_face)):
        moved_by[face_dst[moved_face[j]]] = -1
    return symbols


def _name_appended_faces(face_src, face_dst, new, m0, n0, cb, order) -> None:
    """Record the input face id of each face (rows ``new`` (f, 3) int64, from face ``m0`` on) that the
    splits of collapse batch ``cb`` (in ``order``, new vertices ``n0 + s``) appended, in ``face_src`` and
    its inverse ``face_dst``: a left new face is ``(u, v, a)``, a right one ``(v, u, b)``, so the first
    corner tells them apart (``u >= n0``)."""
    kernel = compiled(_name_appended_faces_kernel)
    if kernel is not None:
        kernel(face_src, face_dst, new, m0, n0, cb.del_left, cb.del_right, order)
        return
    left = new[:, 0] >= n0
    i = order[np.where(left, new[:, 0], new[:, 1]) - n0]
    face_src[m0 : m0 + len(new)] = np.where(left, cb.del_left[i], cb.del_right[i])
    face_dst[face_src[m0 : m0 + len(new)]] = np.arange(m0, m0 + len(new))


def _name_appended_faces_kernel(face_src, face_dst, new, m0, n0, del_left, del_right, order):
    """Compiled :func:`_name_appended_faces`."""
    for j in range(len(new)):
        if new[j, 0] >= n0:
            f = del_left[order[new[j, 0] - n0]]
        else:
            f = del_right[order[new[j, 1] - n0]]
        face_src[m0 + j] = f
        face_dst[f] = m0 + j
    return 0


def _symbols(state, inc, owner, vid, face_src, moved_by, cb, order, rank) -> np.ndarray:
    """The symbols (I,) uint8 of the incidences ``inc`` / ``owner`` (:func:`find_incidences`) of collapse batch
    ``cb`` undone on ``state`` (splits in ``order``, ``rank`` its inverse); ``face_src`` gets the input face
    ids of the faces the batch will append (:func:`_name_new_faces`), ``moved_by`` is scratch (-1 after)."""
    kernel = compiled(_symbols_kernel)
    if kernel is not None:
        return kernel(state.faces.reshape(-1), inc, owner, vid, face_src, moved_by, cb.moved_face, cb.moved_by, rank,
                      order, cb.wing_left, cb.wing_right, cb.del_left, cb.del_right, state.m)
    moved_by[cb.moved_face] = rank[cb.moved_by]
    moved = moved_by[face_src[inc // 3]] == owner
    moved_by[cb.moved_face] = -1
    flat = state.faces.reshape(-1)
    first = inc - inc % 3
    left, right = _wing_incidences(flat[first + (inc + 1) % 3], flat[first + (inc + 2) % 3], owner, vid, cb, order,
                                   moved)
    # STAY, MOVE, MOVE_LEFT, MOVE_RIGHT, MOVE_BOTH: a moved incidence is MOVE plus one per
    # left face it names plus two per right face (MOVE_BOTH = MOVE + 1 + 2)
    symbols = (moved * MOVE + left * (MOVE_LEFT - MOVE) + right * (MOVE_RIGHT - MOVE)).astype(np.uint8)
    _name_new_faces(face_src, state.m, symbols, owner, left, right, cb, order)
    return symbols


def _symbols_kernel(flat, inc, owner, vid, face_src, moved_by, moved_face, moved_of, rank, order, wing_left, wing_right,
                    del_left, del_right, m_before):
    """Compiled :func:`_symbols` (:func:`_wing_incidences`, :func:`_first_per_split` and :func:`_name_new_faces` in one
    pass over the incidences): ``flat`` (3M,) int64 the face slots, ``moved_face`` / ``moved_of`` /
    ``wing_*`` / ``del_*`` the batch's arrays (input ids, collapse order)."""
    for j in range(len(moved_face)):
        moved_by[moved_face[j]] = rank[moved_of[j]]
    symbols = np.zeros(len(inc), np.uint8)
    named = np.zeros((2, len(order)), np.bool_)  # the split has named its left / right new face
    face = m_before  # the next appended face
    for t in range(len(inc)):
        s = owner[t]
        if moved_by[face_src[inc[t] // 3]] != s:
            continue
        i = order[s]
        c = inc[t]
        first = c - c % 3
        wl = vid[wing_left[i]] if wing_left[i] >= 0 else -1  # the wings' decoded ids (-1: none)
        wr = vid[wing_right[i]] if wing_right[i] >= 0 else -1
        left = wl >= 0 and flat[first + (c + 1) % 3] == wl and not named[0, s]
        right = wr >= 0 and flat[first + (c + 2) % 3] == wr and not named[1, s]
        named[0, s] |= left
        named[1, s] |= right
        symbols[t] = MOVE + left * (MOVE_LEFT - MOVE) + right * (MOVE_RIGHT - MOVE)
        if left:
            face_src[face] = del_left[i]
            face += 1
        if right:
            face_src[face] = del_right[i]
            face += 1
    for j in range(len(moved_face)):
        moved_by[moved_face[j]] = -1
    return symbols


def _wing_incidences(a, b, owner, vid, cb, order, moved) -> tuple:
    """Which moved incidences name the left / right new face: two (I,) bool arrays.

    The left new face is ``(u, v, a)`` and the right one ``(v, u, b)``, ``a`` / ``b`` (I,) int64 the
    corners after / before ``v`` in the incidence's face; the face names it when that corner
    is the collapse's recorded wing vertex.  Within a split the incidences are in face-slot order.
    """
    wing_left = _lookup(vid, cb.wing_left[order])[owner]
    wing_right = _lookup(vid, cb.wing_right[order])[owner]
    left = _first_per_split(moved & (wing_left >= 0) & (a == wing_left), owner, len(order))
    right = _first_per_split(moved & (wing_right >= 0) & (b == wing_right), owner, len(order))
    return left, right


def _first_per_split(mask: np.ndarray, owner: np.ndarray, k: int) -> np.ndarray:
    """``mask`` (I,) bool kept at the first incidence of each split only (incidences in face-slot order,
    ``owner`` (I,) int64 their splits, of ``k``): when a pillow is glued on the edge a new face grows
    from, several moved faces could name it, and a split names each new face once."""
    kernel = compiled(_first_per_split_kernel)
    if kernel is not None:
        return kernel(mask, owner, k)
    hit = np.flatnonzero(mask)
    first = hit[np.unique(owner[hit], return_index=True)[1]]
    out = np.zeros_like(mask)
    out[first] = True
    return out


def _first_per_split_kernel(mask, owner, k):
    """Compiled :func:`_first_per_split` (one pass, no sort)."""
    seen = np.zeros(k, np.bool_)
    out = np.zeros(len(mask), np.bool_)
    for i in range(len(mask)):
        if mask[i] and not seen[owner[i]]:
            seen[owner[i]] = True
            out[i] = True
    return out


def _name_new_faces(face_src, m_before, symbols, owner, left, right, cb, order) -> None:
    """Record the input face id of each face :func:`split_topology` appended.

    New faces are appended in the order of their naming incidences, left before right, so
    an incidence naming both has its left face at ``start`` and its right one at ``start + 1``.
    """
    naming = symbols >= MOVE_LEFT
    split = owner[naming]
    names_left = left[naming]
    names_right = right[naming]
    per = names_left.astype(np.int64) + names_right
    start = m_before + np.cumsum(per) - per
    face_src[start[names_left]] = cb.del_left[order][split[names_left]]
    face_src[start[names_right] + names_left[names_right]] = cb.del_right[order][split[names_right]]


def _lookup(table, ids):
    return np.where(ids >= 0, table[np.maximum(ids, 0)], -1)


def _match_faces(decoded, corners, face_ids, n0):
    """Input face ids of ``decoded`` faces (m0, 3), matched by oriented vertex triple."""
    kd = face_keys(decoded)
    kc = face_keys(corners)
    key_d = (kd[:, 0] * n0 + kd[:, 1]) * n0 + kd[:, 2]
    key_c = (kc[:, 0] * n0 + kc[:, 1]) * n0 + kc[:, 2]
    oc = np.argsort(key_c)
    pos = np.searchsorted(key_c[oc], key_d)
    pos = np.minimum(pos, len(oc) - 1)
    if not np.array_equal(key_c[oc][pos], key_d):
        raise ValueError("decoded base faces do not match the simplified base mesh")
    return face_ids[oc[pos]]
