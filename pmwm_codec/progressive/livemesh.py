"""The simplifier's view of the live mesh at the start of a batch, built in one pass.

Each batch of :func:`~pmwm_codec.progressive.simplify.simplify` works on the live mesh
renumbered compactly ("local" ids, in the order of the original ids) and needs its edge
table, its vertex -> neighbours and vertex -> faces adjacencies and the face count of every
vertex.  :func:`live_mesh` builds all of them: with numba, in one compiled kernel (a counting
sort of the half-edges by their low end, then a small stable sort by the high end inside each
bucket, instead of two counting sorts and a dozen numpy passes); without numba, with the
functions of :mod:`.topology`.  Both paths return the same arrays, entry for entry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .topology import EdgeTable, compiled, csr, edge_table, kernel_helper


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


def live_mesh(corners: np.ndarray, face_alive: np.ndarray, vert_alive: np.ndarray) -> LiveMesh:
    """:class:`LiveMesh` of the faces ``corners`` (M, 3) int64 with ``face_alive`` (M,) bool over the
    vertices with ``vert_alive`` (N,) bool (every corner of a live face is a live vertex)."""
    kernel = compiled(_live_mesh_kernel)
    if kernel is not None:
        vids, fids, loc, F, edges, vv_start, vv_nbr, vv_edge, vf_start, vf_face, fcount = \
            kernel(corners, face_alive, vert_alive)
        et = EdgeTable(len(vids), *edges)
        return LiveMesh(vids, fids, loc, F, et, (vv_start, vv_nbr), vv_edge, (vf_start, vf_face), fcount)
    fids = np.flatnonzero(face_alive)
    vids = np.flatnonzero(vert_alive)
    loc = np.full(len(vert_alive), -1, dtype=np.int64)
    loc[vids] = np.arange(len(vids))
    F = loc[corners[fids]]
    n, m = len(vids), len(fids)
    et = edge_table(F, n)
    ends = np.concatenate([et.lo, et.hi])
    vv = csr(ends, np.concatenate([et.hi, et.lo]), n)
    ids = np.arange(len(et.lo))
    _, vv_edge = csr(ends, np.concatenate([ids, ids]), n)
    vf = csr(F.ravel(), np.repeat(np.arange(m), 3), n)
    return LiveMesh(vids, fids, loc, F, et, vv, vv_edge, vf, np.bincount(F.ravel(), minlength=n))


@kernel_helper
def _compact_kernel(corners, face_alive, vert_alive):
    """Kernel part of :func:`_live_mesh_kernel`: ``(vids, fids, loc, F)`` as in :class:`LiveMesh`."""
    loc = np.full(len(vert_alive), -1, np.int64)
    n = 0
    for x in range(len(vert_alive)):
        if vert_alive[x]:
            loc[x] = n
            n += 1
    vids = np.flatnonzero(vert_alive).astype(np.int64)
    fids = np.flatnonzero(face_alive).astype(np.int64)
    F = np.empty((len(fids), 3), np.int64)
    for i in range(len(fids)):
        for c in range(3):
            F[i, c] = loc[corners[fids[i], c]]
    return vids, fids, loc, F


@kernel_helper
def _sorted_half_edges(F, n):
    """Half-edges ``3 f + c`` of ``F`` (m, 3) sorted by (low end, high end), ties by half-edge:
    ``(order (3m,), lo (3m,), hi (3m,))`` with ``lo`` / ``hi`` per half-edge (not sorted)."""
    h = 3 * len(F)
    lo = np.empty(h, np.int64)
    hi = np.empty(h, np.int64)
    start = np.zeros(n + 1, np.int64)
    for f in range(len(F)):
        for c in range(3):
            a, b = F[f, c], F[f, (c + 1) % 3]
            lo[3 * f + c], hi[3 * f + c] = min(a, b), max(a, b)
            start[min(a, b) + 1] += 1
    for x in range(n):
        start[x + 1] += start[x]
    fill = start[:-1].copy()
    order = np.empty(h, np.int64)
    for j in range(h):  # bucket by the low end, half-edges ascending inside a bucket
        order[fill[lo[j]]] = j
        fill[lo[j]] += 1
    for x in range(n):  # stable sort of each bucket by the high end
        a, b = start[x], start[x + 1]
        if b - a > 32:
            seg = order[a:b].copy()
            order[a:b] = seg[np.argsort(hi[seg], kind="mergesort")]
            continue
        for j in range(a + 1, b):
            item = order[j]
            t = j
            while t > a and hi[order[t - 1]] > hi[item]:
                order[t] = order[t - 1]
                t -= 1
            order[t] = item
    return order, lo, hi


def _live_mesh_kernel(corners, face_alive, vert_alive):
    """Compiled :func:`live_mesh`: the same arrays (see there), as a flat tuple."""
    vids, fids, loc, F = _compact_kernel(corners, face_alive, vert_alive)
    n = len(vids)
    order, hlo, hhi = _sorted_half_edges(F, n)
    h = len(order)
    he_edge = np.empty(h, np.int64)
    first = np.empty(h, np.int64)  # sorted position of each edge's first half-edge
    e = -1
    for i in range(h):
        if i == 0 or hlo[order[i]] != hlo[order[i - 1]] or hhi[order[i]] != hhi[order[i - 1]]:
            e += 1
            first[e] = i
        he_edge[order[i]] = e
    ne = e + 1
    keys, lo, hi = np.empty(ne, np.int64), np.empty(ne, np.int64), np.empty(ne, np.int64)
    count, he0, he1 = np.empty(ne, np.int64), np.empty(ne, np.int64), np.empty(ne, np.int64)
    for e in range(ne):
        s = first[e]
        count[e] = (first[e + 1] if e + 1 < ne else h) - s
        he0[e] = order[s]
        he1[e] = order[s + 1] if count[e] >= 2 else -1
        lo[e], hi[e] = hlo[order[s]], hhi[order[s]]
        keys[e] = lo[e] * n + hi[e]
    vv_start = np.zeros(n + 1, np.int64)
    for e in range(ne):
        vv_start[lo[e] + 1] += 1
        vv_start[hi[e] + 1] += 1
    for x in range(n):
        vv_start[x + 1] += vv_start[x]
    fill = vv_start[:-1].copy()
    vv_nbr = np.empty(2 * ne, np.int64)
    vv_edge = np.empty(2 * ne, np.int64)
    for e in range(ne):
        vv_nbr[fill[lo[e]]] = hi[e]
        vv_edge[fill[lo[e]]] = e
        fill[lo[e]] += 1
    for e in range(ne):
        vv_nbr[fill[hi[e]]] = lo[e]
        vv_edge[fill[hi[e]]] = e
        fill[hi[e]] += 1
    fcount = np.zeros(n, np.int64)
    for f in range(len(F)):
        for c in range(3):
            fcount[F[f, c]] += 1
    vf_start = np.zeros(n + 1, np.int64)
    vf_start[1:] = np.cumsum(fcount)
    fill = vf_start[:-1].copy()
    vf_face = np.empty(3 * len(F), np.int64)
    for f in range(len(F)):
        for c in range(3):
            vf_face[fill[F[f, c]]] = f
            fill[F[f, c]] += 1
    edges = (keys, lo, hi, count, he0, he1, he_edge)
    return vids, fids, loc, F, edges, vv_start, vv_nbr, vv_edge, vf_start, vf_face, fcount
