"""The simplifier's view of the live mesh at the start of a batch, built in one pass.

Each batch of :func:`~pmwm_codec.progressive.simplify.simplify` works on the live mesh
renumbered compactly ("local" ids, in the order of the original ids) and needs its edge
table, its vertex -> neighbours and vertex -> faces adjacencies and the face count of every
vertex.  :func:`live_mesh` builds all of them: with numba, in one compiled kernel (the vertex ->
faces table and every vertex's half-edges to and from higher vertices by one counting sort, then
every vertex's edges to higher vertices from its own half-edges, in edge order, so the half-edges
are never sorted as a whole); without numba, with the functions of :mod:`.topology`.  Both paths
return the same arrays, entry for entry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .topology import EdgeTable, compiled, csr, edge_table, half_edges, kernel_helper


@dataclass
class LiveMesh:
    """The live mesh in local ids.

    Attributes
    ----------
    vids : (n,) int64
        Original id of each local vertex, ascending.
    fids : (m,) int64
        Original id of each local face, ascending.
    loc : (N,) int64
        Original vertex id -> local id (-1: dead).
    F : (m, 3) int64
        Faces in local vertex ids.
    et : EdgeTable
        :func:`~.topology.edge_table` of ``F``.
    vv : tuple of (n + 1,) int64 and (2e,) int64
        Vertex -> neighbours CSR: each row lists the edges where the vertex is the low end
        (in edge order), then those where it is the high end.
    vv_edge : (2e,) int64
        Edge id of every entry of ``vv`` (the compiled kernels find an edge by a row scan).
    vf : tuple of (n + 1,) int64 and (3m,) int64
        Vertex -> faces CSR, faces ascending (one entry per corner).
    fcount : (n,) int64
        Faces on each vertex.
    boundary : (n,) int64
        Boundary edges (one face) at each vertex (a self-loop counts at both ends).
    edge_flags : (n,) uint8
        What edges each vertex is on: bit 1, an edge of two faces whose half-edges run the same way
        (inconsistently oriented); bit 2, an edge of more than two faces.
    opp : (3m,) int64
        The corner opposite every half-edge (``opposite`` of :func:`~.topology.half_edges` of ``F``).
    """

    vids: np.ndarray
    fids: np.ndarray
    loc: np.ndarray
    F: np.ndarray
    et: EdgeTable
    vv: tuple
    vv_edge: np.ndarray
    vf: tuple
    fcount: np.ndarray
    boundary: np.ndarray
    edge_flags: np.ndarray
    opp: np.ndarray


def live_mesh(corners: np.ndarray, face_alive: np.ndarray, vert_alive: np.ndarray,
              prev: tuple | None = None) -> LiveMesh:
    """:class:`LiveMesh` of the faces ``corners`` (M, 3) int64 with ``face_alive`` (M,) bool over the
    vertices with ``vert_alive`` (N,) bool (every corner of a live face is a live vertex).

    ``prev``: ``(vids, fids, loc)`` of the :class:`LiveMesh` of an earlier state of the same mesh (the
    previous batch's: every live vertex and face now was live then), only those, so that the rest of
    that mesh can be freed before this one is built.  ``vids`` and ``fids`` are filtered instead of every
    vertex and face being scanned, and ``loc`` is updated in place and shared: the earlier mesh must not
    be used afterwards.  The same arrays either way.
    """
    if prev is None:
        vids0, fids0 = np.arange(len(vert_alive)), np.arange(len(face_alive))
        loc = np.full(len(vert_alive), -1, dtype=np.int64)
    else:
        vids0, fids0, loc = prev
    kernel = compiled(_live_mesh_kernel)
    if kernel is not None:
        vids, fids, loc, F, opp, edges, vv_start, vv_nbr, vv_edge, vf_start, vf_face, fcount, boundary, flags = \
            kernel(corners, face_alive, vert_alive, vids0, fids0, loc)
        et = EdgeTable(len(vids), *edges)
        return LiveMesh(vids, fids, loc, F, et, (vv_start, vv_nbr), vv_edge, (vf_start, vf_face), fcount, boundary,
                        flags, opp)
    fids = fids0[face_alive[fids0]]
    vids = vids0[vert_alive[vids0]]
    loc[vids0] = -1
    loc[vids] = np.arange(len(vids))
    F = loc[corners[fids]]
    n, m = len(vids), len(fids)
    et = edge_table(F, n)
    ends = np.concatenate([et.lo, et.hi])
    vv = csr(ends, np.concatenate([et.hi, et.lo]), n)
    ids = np.arange(len(et.lo))
    _, vv_edge = csr(ends, np.concatenate([ids, ids]), n)
    vf = csr(F.ravel(), np.repeat(np.arange(m), 3), n)
    boundary = np.bincount(ends, weights=np.tile(et.count == 1, 2), minlength=n).astype(np.int64)
    two = np.flatnonzero(et.count == 2)
    same = two[F.ravel()[et.he0[two]] == F.ravel()[et.he1[two]]]  # both half-edges leave the same end
    flags = np.zeros(n, np.uint8)
    for bit, e in ((1, same), (2, np.flatnonzero(et.count > 2))):
        flags[et.lo[e]] |= bit
        flags[et.hi[e]] |= bit
    return LiveMesh(vids, fids, loc, F, et, vv, vv_edge, vf, np.bincount(F.ravel(), minlength=n), boundary, flags,
                    half_edges(F, with_dst=False)[2])


def boundary_half_edges(faces: np.ndarray, n: int) -> np.ndarray:
    """The half-edges (b,) int64 of the boundary edges (one face) of ``faces`` (m, 3) int64 over ``n``
    vertices, in edge order (``he0`` of :func:`~.topology.edge_table` where ``count == 1``)."""
    kernel = compiled(_boundary_kernel)
    if kernel is None:
        et = edge_table(faces, n)
        return et.he0[et.count == 1]
    return kernel(faces, n)


def _boundary_kernel(faces, n):
    """Compiled :func:`boundary_half_edges` (the edge pass of :func:`_live_mesh_kernel`)."""
    vf_start, _, _, key_start, keys = _vertex_faces(faces, n)
    _, _, count, he0, _, _, _, _, _, _ = _edges_by_vertex(faces, n, vf_start, key_start, keys)
    return he0[count == 1]


@kernel_helper(allocates=True)
def _compact_kernel(corners, face_alive, vert_alive, vids0, fids0, loc):
    """Kernel part of :func:`_live_mesh_kernel`: ``(vids, fids, loc, F, opp)`` as in :class:`LiveMesh`, from
    ``vids0`` / ``fids0`` (ascending int64: every live vertex / face and maybe dead ones) and ``loc`` (N,)
    int64, -1 except at ``vids0``, filled in place."""
    vids = np.empty(len(vids0), np.int64)
    n = 0
    for x in vids0:  # no branch on the flags (a batch removes about every 7th vertex and face, scattered)
        alive = vert_alive[x]
        loc[x] = n if alive else -1
        vids[n] = x
        n += alive
    fids = np.empty(len(fids0), np.int64)
    m = 0
    for f in fids0:
        fids[m] = f
        m += face_alive[f]
    F = np.empty((m, 3), np.int64)
    opp = np.empty(3 * m, np.int64)
    for i in range(m):  # the face's corners read into locals first (a store to F could alias them: reloads)
        f = fids[i]
        a, b, c = loc[corners[f, 0]], loc[corners[f, 1]], loc[corners[f, 2]]
        F[i, 0], F[i, 1], F[i, 2] = a, b, c
        opp[3 * i], opp[3 * i + 1], opp[3 * i + 2] = c, a, b
    return vids[:n], fids[:m], loc, F, opp


@kernel_helper(allocates=True)
def _vertex_faces(F, n):
    """Kernel part of :func:`_live_mesh_kernel`: the vertex -> faces CSR of ``F`` (m, 3) int64 (one entry per
    corner, faces ascending in every row) and every vertex's edge keys (:func:`_vertex_edges`) in a CSR of their
    own, both by one counting sort: ``(vf_start (n + 1,), vf_face (3m,), fcount (n,), key_start (n + 1,), keys
    (3m + 1,))``, all int64.

    A corner ``3 f + c`` at ``x`` gives two keys: its half-edge ``x -> y`` (the next corner's vertex) as
    ``(y << shift | 3 f + c) << 1``, kept when ``y >= x``, and the previous corner's half-edge ``z -> x`` as
    ``(z << shift | that corner) << 1 | 1``, kept when ``z > x`` (``shift`` the bits of 3m); ``x``'s row holds the
    kept ones (the half-edges to and from its higher neighbours, and its own outgoing self-loops), in no order.
    The counts are made with the face counts; each key is written where it goes if kept, at the spare last entry
    if not (no branch on the vertex order, which is random: a branch per key mispredicted about half the time)."""
    h = 3 * len(F)
    shift = 1
    while (1 << shift) < h:  # half-edge ids are below 3m, the corner count
        shift += 1
    fcount = np.zeros(n, np.int64)
    kcount = np.zeros(n, np.int64)
    for f in range(len(F)):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        fcount[a] += 1
        kcount[a] += (b >= a) + (c > a)
        fcount[b] += 1
        kcount[b] += (c >= b) + (a > b)
        fcount[c] += 1
        kcount[c] += (a >= c) + (b > c)
    vf_start = np.zeros(n + 1, np.int64)
    key_start = np.zeros(n + 1, np.int64)
    for x in range(n):
        vf_start[x + 1] = vf_start[x] + fcount[x]
        key_start[x + 1] = key_start[x] + kcount[x]
    fill = vf_start[:-1].copy()
    kfill = key_start[:-1].copy()
    vf_face = np.empty(h, np.int64)
    keys = np.empty(key_start[n] + 1, np.int64)
    spare = key_start[n]
    for f in range(len(F)):  # the corners held in locals (a store could alias F or the fills: reloads)
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        h0, h1, h2 = 3 * f, 3 * f + 1, 3 * f + 2  # a -> b, b -> c, c -> a
        # a degenerate face repeats a vertex: its next corner goes to the next place (the fills are read again)
        _corner_keys(a, b, c, h0, h2, f, shift, fill, vf_face, kfill, keys, spare)
        _corner_keys(b, c, a, h1, h0, f, shift, fill, vf_face, kfill, keys, spare)
        _corner_keys(c, a, b, h2, h1, f, shift, fill, vf_face, kfill, keys, spare)
    return vf_start, vf_face, fcount, key_start, keys


@kernel_helper(inline=True)
def _corner_keys(x, y, z, out, into, f, shift, fill, vf_face, kfill, keys, spare):
    """:func:`_vertex_faces`' step for the corner of face ``f`` at ``x``, whose next vertex is ``y`` (half-edge
    ``out``: x -> y) and previous ``z`` (half-edge ``into``: z -> x): ``f`` into ``x``'s faces row, and both
    half-edge keys written, kept (``x``'s key row advanced) only when the other end is higher (``y`` may equal
    ``x``: an outgoing self-loop), else at the ``spare`` last entry."""
    s = fill[x]
    vf_face[s] = f
    fill[x] = s + 1
    t = kfill[x]
    keys[t if y >= x else spare] = ((y << shift) | out) << 1
    t += y >= x
    keys[t if z > x else spare] = (((z << shift) | into) << 1) | 1
    t += z > x
    kfill[x] = t


@kernel_helper(allocates=True)
def _edges_by_vertex(F, n, vf_start, key_start, keys):
    """Kernel part of :func:`_live_mesh_kernel`: the edge table of ``F`` built vertex by vertex
    (:func:`_vertex_edges`, from :func:`_vertex_faces`' key rows), with the vertex -> neighbours CSR of
    :class:`LiveMesh`.

    Returns ``(lo, hi, count, he0, he1)`` (e,) int64 as in :class:`~.topology.EdgeTable`, ``vv_start``
    (n + 1,), ``vv_nbr`` and ``vv_edge`` (2e,) int64 and :class:`LiveMesh`'s ``boundary`` and
    ``edge_flags``.  The edge and neighbour arrays are views of arrays sized
    for a closed mesh's edges and a little more (grown by half when short), not for every half-edge
    (about twice the edges), which views would keep alive with the live mesh (+137 MB peak on a
    1.1M-vertex encode); nor copies (5-8 % of the live mesh's time).  The neighbour rows' first parts
    (each vertex's edges as the low end) are written as the vertices' edges are made, their second
    parts in one pass over the edges after.
    """
    h = 3 * len(F)
    cap = min(h, h // 2 + h // 32 + 16)
    lo, hi, count = np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(cap, np.int64)
    he0, he1 = np.empty(cap, np.int64), np.empty(cap, np.int64)
    vv_nbr, vv_edge = np.empty(2 * cap, np.int64), np.empty(2 * cap, np.int64)
    vv_start = np.zeros(n + 1, np.int64)
    fill = np.empty(n, np.int64)  # each row's second part: where its next entry goes
    down = np.zeros(n, np.int64)
    boundary, flags = np.zeros(n, np.int64), np.zeros(n, np.uint8)
    kmax = 0
    for x in range(n):
        kmax = max(kmax, key_start[x + 1] - key_start[x])
    buf = np.empty(2 * max(kmax, 8) + 2, np.int64)  # a vertex's keys, then sorted (:func:`_vertex_edges`)
    shift = 1
    while (1 << shift) < h:  # as :func:`_vertex_faces`
        shift += 1
    zero = np.int64(0)  # not a literal (see :func:`~.topology.kernel_helper`)
    x, ne = _vertex_edges(zero, zero, n, shift, key_start, keys, buf, lo, hi, count, he0, he1, down, boundary, flags,
                          vv_start, vv_nbr, vv_edge, fill)
    while x < n:  # more boundary or non-manifold edges than that: grow (outside the vertex loop, which stays fast)
        cap = min(h, max(cap + cap // 2, ne + kmax))
        lo, hi, count = _grown(lo, cap, ne), _grown(hi, cap, ne), _grown(count, cap, ne)
        he0, he1 = _grown(he0, cap, ne), _grown(he1, cap, ne)
        vv_nbr, vv_edge = _grown(vv_nbr, 2 * cap, vv_start[x]), _grown(vv_edge, 2 * cap, vv_start[x])
        x, ne = _vertex_edges(x, ne, n, shift, key_start, keys, buf, lo, hi, count, he0, he1, down, boundary, flags,
                              vv_start, vv_nbr, vv_edge, fill)
    for e in range(ne):  # each row's second part: the edges where its vertex is the high end, in edge order
        y = hi[e]
        p = fill[y]
        vv_nbr[p] = lo[e]
        vv_edge[p] = e
        fill[y] = p + 1
    return lo[:ne], hi[:ne], count[:ne], he0[:ne], he1[:ne], vv_start, vv_nbr[:2 * ne], vv_edge[:2 * ne], boundary, flags


@kernel_helper(allocates=True)
def _grown(a, cap, k):
    """A (cap,) array holding ``a``'s first ``k`` entries (the rest uninitialised)."""
    out = np.empty(cap, a.dtype)
    for i in range(k):  # a loop, not a slice copy: that compiles numba's shape-mismatch error path (~0.5 s)
        out[i] = a[i]
    return out


@kernel_helper(inline=True)
def _network8(buf, k, half):
    """Sort the keys ``buf[:k]`` (k <= 8, int64, below the largest int64) into ``buf[half:half + k]``,
    ``half >= 8``, by a sorting network of 19 comparators (each a min and a max, no branch; it sorts
    every 0-1 input of 8, hence every input) on the keys padded to 8 with the largest int64
    (``buf[k:8]`` and ``buf[half + k:half + 8]`` overwritten)."""
    for i in range(k, 8):
        buf[i] = 0x7FFFFFFFFFFFFFFF
    x0, x1, x2, x3, x4, x5, x6, x7 = buf[0], buf[1], buf[2], buf[3], buf[4], buf[5], buf[6], buf[7]
    x0, x1 = min(x0, x1), max(x0, x1)
    x2, x3 = min(x2, x3), max(x2, x3)
    x4, x5 = min(x4, x5), max(x4, x5)
    x6, x7 = min(x6, x7), max(x6, x7)
    x0, x2 = min(x0, x2), max(x0, x2)
    x1, x3 = min(x1, x3), max(x1, x3)
    x4, x6 = min(x4, x6), max(x4, x6)
    x5, x7 = min(x5, x7), max(x5, x7)
    x1, x2 = min(x1, x2), max(x1, x2)
    x5, x6 = min(x5, x6), max(x5, x6)
    x0, x4 = min(x0, x4), max(x0, x4)
    x3, x7 = min(x3, x7), max(x3, x7)
    x1, x5 = min(x1, x5), max(x1, x5)
    x2, x6 = min(x2, x6), max(x2, x6)
    x1, x4 = min(x1, x4), max(x1, x4)
    x3, x6 = min(x3, x6), max(x3, x6)
    x2, x4 = min(x2, x4), max(x2, x4)
    x3, x5 = min(x3, x5), max(x3, x5)
    x3, x4 = min(x3, x4), max(x3, x4)
    buf[half], buf[half + 1], buf[half + 2], buf[half + 3] = x0, x1, x2, x3
    buf[half + 4], buf[half + 5], buf[half + 6], buf[half + 7] = x4, x5, x6, x7


@kernel_helper
def _vertex_edges(x0, ne, n, shift, key_start, keys, buf, lo, hi, count, he0, he1, down, boundary, flags, vv_start,
                  vv_nbr, vv_edge, fill):
    """Kernel part of :func:`_edges_by_vertex`: the edges of the vertices from ``x0`` on, written from
    entry ``ne`` on of ``lo`` / ``hi`` / ``count`` / ``he0`` / ``he1`` (each (cap,) int64; ``down``,
    ``boundary`` and ``flags`` (n,) counted and marked as in :class:`LiveMesh`), until the next vertex's
    would not fit: returns ``(x, ne)``, the first vertex not written (``n``: none left) and the edges
    written.  Each vertex's row of the neighbour CSR is placed as it is reached (``vv_start`` (n + 1,)
    int64: the edges where a vertex is the high end are all made by then, ``down``) and its first part
    written (``vv_nbr`` / ``vv_edge`` (2 cap,) int64), ``fill`` (n,) int64 set to where its second part
    starts.

    Every vertex ``x`` in turn takes its row of packed keys ``(y << shift | half-edge) << 1 | into x``
    (:func:`_vertex_faces`: the half-edges to and from its higher neighbours ``y``; the direction bit below the
    half-edge, which no two keys share) into the first half of ``buf`` (scratch, (2 max(k, 8) + 2,) int64 for the
    longest row k) and sorts them into the second half (from ``len(buf) // 2`` on): its edges as the low end, in
    edge order.  Up to 8 keys (k ~ 6) go through a sorting network (:func:`_network8`), more each to its place,
    the number of keys below it (k**2 comparisons).  An insertion sort, whose steps mispredict, made the live
    mesh 1.05-1.15x as long."""
    low = (1 << shift) - 1
    half = len(buf) // 2
    for x in range(x0, n):
        a, b = key_start[x], key_start[x + 1]
        k = b - a
        if ne + k > len(lo):  # no more edges than keys
            return x, ne
        for i in range(k):
            buf[i] = keys[a + i]
        if k <= 8:
            _network8(buf, k, half)
        else:
            for i in range(k):  # each key to its place, ascending: the keys before it, counted
                key = buf[i]
                t = half
                for j in range(k):
                    t += buf[j] < key
                buf[t] = key
        row = vv_start[x]
        j = half
        while j < half + k:
            s = j
            y = buf[s] >> (shift + 1)
            while j < half + k and buf[j] >> (shift + 1) == y:
                j += 1
            c = j - s
            lo[ne], hi[ne], count[ne] = x, y, c
            he0[ne] = (buf[s] >> 1) & low
            he1[ne] = (buf[s + 1] >> 1) & low if c >= 2 else -1
            vv_nbr[row], vv_edge[row] = y, ne
            row += 1
            down[y] += 1
            if c == 1:
                boundary[x] += 1
                boundary[y] += 1
            elif c == 2 and (buf[s] & 1) == (buf[s + 1] & 1):
                flags[x] |= 1
                flags[y] |= 1
            elif c > 2:
                flags[x] |= 2
                flags[y] |= 2
            ne += 1
        fill[x] = row
        vv_start[x + 1] = row + down[x]  # every edge with x as its high end is made (a self-loop just now)
    return n, ne


def _live_mesh_kernel(corners, face_alive, vert_alive, vids0, fids0, loc):
    """Compiled :func:`live_mesh`: the same arrays (see there), as a flat tuple; ``vids0``, ``fids0`` and
    ``loc`` as in :func:`_compact_kernel`."""
    vids, fids, loc, F, opp = _compact_kernel(corners, face_alive, vert_alive, vids0, fids0, loc)
    n = len(vids)
    vf_start, vf_face, fcount, key_start, keys = _vertex_faces(F, n)
    lo, hi, count, he0, he1, vv_start, vv_nbr, vv_edge, boundary, flags = _edges_by_vertex(F, n, vf_start, key_start,
                                                                                            keys)
    edges = (lo * n + hi, lo, hi, count, he0, he1)
    return vids, fids, loc, F, opp, edges, vv_start, vv_nbr, vv_edge, vf_start, vf_face, fcount, boundary, flags
