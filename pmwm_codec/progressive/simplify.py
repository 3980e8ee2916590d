"""Encoder side: simplify a mesh by batches of independent half-edge collapses.

A half-edge collapse ``u -> v`` deletes vertex ``u`` and the one or two faces on
edge ``uv``; every other face of ``u`` has its ``u`` corner rewritten to ``v``.
``v`` keeps its position, so the inverse operation (a vertex split) only has to
place the new vertex ``u``; no decoded vertex ever moves.

Collapses are chosen in *batches* of independent collapses ``u_i -> v_i``:

* no two removed vertices are adjacent (no face holds two of them, and no removed
  vertex is in another's 1-ring: the paper's "independency");
* no two collapses keep the same vertex (``v_i`` distinct);
* no kept vertex is a neighbour of another collapse's removed vertex
  (``v_i`` not in ``N(u_j)``).

The faces each collapse moves or deletes are then its own, the new edges of two
collapses never meet on one edge or one face (a shared neighbour ``x`` of ``u_1`` and
``u_2`` only sees two independent contractions of its link), so every legality test
made against the pre-batch mesh stays true after the whole batch, and a decoder can
undo the whole batch with array operations.  (An earlier rule asked for disjoint
closed 1-rings, distance >= 3 between removed vertices; this one keeps the same
guarantees and takes about 1.5x as many collapses per batch.)

A collapse is legal when

* ``u`` is a manifold vertex (one disk or half-disk of faces) on no non-manifold
  or inconsistently oriented edge; non-manifold parts simply stay in the base, except
  doubled-face "pillows" (:func:`twin_faces`) glued onto an interior disk along its edges or
  hanging from one of them as a flap: they move with ``u`` (the VRIP dragons carry ~900
  at 23k vertices; their base: 4,027 -> 1,670 vertices at grid 14).  The encoder of payload
  version 2 does not need this: it simplifies without the pillows (:func:`deferred_pillows`)
  and sends them in a face chunk (227 vertices);
* if ``u`` is on a boundary, ``uv`` is a boundary edge (holes are never closed
  and boundaries never pinched);
* the link condition holds: ``u`` and ``v`` share exactly the neighbours opposite
  ``uv`` (no new non-manifold edge, no duplicate face);
* each deleted face's other edge at ``u`` is interior (the split that undoes it
  can name the face it grows from; it also forbids removing "ear" vertices), or an edge a pillow
  is glued on (of the faces that could name it, the first in face-slot order does);
* the two deleted faces have different third vertices: two faces on the same three vertices
  (a doubled face, as scans' reconstructions leave them) would each grow from the other, and
  the split that undoes the collapse could name neither;
* no moved face flips its normal, becomes degenerate or duplicates a face (a face with no area
  on the grid already may stay so, or must face the way ``u``'s faces do, their normals summed).

Seams: vertices that share a position (glTF copies on a UV seam or a hard edge, given as
``weld``) are never removed by an ordinary collapse; both copies go together, as a *seam pair*
of collapses in one batch, chosen before the batch's other collapses (rule in :mod:`.seams`).

Order within a batch follows the quadric error (Garland–Heckbert) of placing
``u`` on ``v``; an independent set is picked by rounds of "lowest cost among its
neighbours wins" (a parallel, Luby-style version of greedy-by-cost).  A local
minimum is not a globally cheap collapse: left alone, a batch would also take the
collapses that are cheapest only among expensive neighbours (creases, tips), long
before a sequential greedy order would.  So a batch only considers candidates no
dearer than the :data:`BATCH_QUANTILE` (the median) of the vertices' cheapest costs
(:func:`_affordable`); the rest wait for a later batch, when the cheap ones are gone.
On fandisk this made the level with 30 % of the vertices 24x closer to the original
(the error of fast-simplification's LOD: 6.1x before, 0.25x after) for ~30 % more
batches (tools/bench_rd.py, BENCHMARKS.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import pcg64, seams, topology
from .livemesh import boundary_half_edges, live_mesh
from .topology import compiled, expand, face_keys, group_order, half_edges, kernel_helper, two_alike

#: A moved face's normal may turn by at most this much (cosine bound).
MIN_NORMAL_COS = 0.0
#: Weight of the boundary-preserving planes relative to face planes.
BOUNDARY_WEIGHT = 10.0
#: How many of each vertex's cheapest collapses are tested for legality per batch.
TRIES = 3
#: Selection rounds per batch (see :func:`_select`).
ROUNDS = 8
#: A batch only takes collapses no dearer than this quantile of the vertices' cheapest
#: candidate costs (see :func:`_affordable`); 1.0 takes every independent winner.
BATCH_QUANTILE = 0.5
#: A batch whose winners are fewer than this fraction of the vertices offering a collapse is
#: chosen again among the legal candidates only (see :func:`_unstalled`).
STALL_FRACTION = 1 / 32
#: The first batches (at most this many) take the vertices that share a grid point with another first
#: (:func:`coincident_vertices`).
SHARED_FIRST_BATCHES = 4


@dataclass
class CollapseBatch:
    """One batch of independent collapses, in *original* vertex and face ids.

    Attributes
    ----------
    u, v : (k,) int64
        Removed vertex and the vertex it collapses into.
    del_left, del_right : (k,) int64
        Deleted face holding directed edge ``u->v`` (resp. ``v->u``); -1 if none.
    wing_left, wing_right : (k,) int64
        Third vertex of ``del_left`` / ``del_right``; -1 if none.
    moved_face : (j,) int64
        Faces whose ``u`` corner became ``v``.
    moved_by : (j,) int64
        Index into this batch's collapses for each moved face.
    cost : (k,) float64
        Quadric error of each collapse (area-weighted squared distances; ranks collapses).
    error : (k,) float64
        Root-mean-square distance of each collapse's quadric planes at the kept
        vertex (``sqrt(cost / plane weight)``), in the units of the positions.
    """

    u: np.ndarray
    v: np.ndarray
    del_left: np.ndarray
    del_right: np.ndarray
    wing_left: np.ndarray
    wing_right: np.ndarray
    moved_face: np.ndarray
    moved_by: np.ndarray
    cost: np.ndarray
    error: np.ndarray


@dataclass
class CollapseLog:
    """Result of :func:`simplify`: the base mesh and the batches (fine to coarse)."""

    vertex_count: int
    face_count: int
    base_vertices: np.ndarray  # (n0,) int64 original ids that survive, ascending
    base_faces: np.ndarray  # (m0,) int64 original face ids that survive, ascending
    base_corners: np.ndarray  # (m0, 3) int64 corners of the base faces (original vertex ids)
    batches: list = field(default_factory=list)  # CollapseBatch, in collapse order (fine -> coarse)


def face_quadrics(pos: np.ndarray, faces: np.ndarray, n: int, boundary: np.ndarray | None = None) -> np.ndarray:
    """Per-vertex quadrics (n, 10) float64: area-weighted face planes plus boundary planes.

    The 10 entries are the upper triangle of the symmetric 4x4 quadric
    ``[a2, ab, ac, ad, b2, bc, bd, c2, cd, d2]`` of planes ``ax + by + cz + d = 0``.
    ``pos`` (N, 3) float64, ``faces`` (m, 3) int64 over ``n`` vertices; ``boundary`` (b,) int64: the
    half-edges of its boundary edges in edge order (:func:`~.livemesh.boundary_half_edges`), when the
    caller has them.  A dot product of three terms is summed ``(x0 + x2) + x1``, as ``np.einsum`` sums
    it here, so the numpy path and the compiled one (:func:`_quadrics_kernel`, no temporaries) give
    the same bits.
    """
    if boundary is None:
        boundary = boundary_half_edges(faces, n)
    kernel = compiled(_quadrics_kernel)
    if kernel is not None:
        return kernel(pos, faces, np.asarray(boundary, np.int64), n, BOUNDARY_WEIGHT)
    p0, p1, p2 = pos[faces[:, 0]], pos[faces[:, 1]], pos[faces[:, 2]]
    nrm = np.cross(p1 - p0, p2 - p0)
    area2 = np.linalg.norm(nrm, axis=1)
    unit = nrm / np.maximum(area2, 1e-300)[:, None]
    planes = np.concatenate([unit, -_dot3(unit, p0)[:, None]], axis=1)
    corner_q = np.repeat(_plane_quadrics(planes, 0.5 * area2), 3, axis=0)
    out = _index_sum(faces.ravel(), corner_q, n)

    # boundary edges: a plane through the edge, perpendicular to its face
    he = boundary
    if len(he):
        src, dst, _ = half_edges(faces)
        a_, b_ = src[he], dst[he]
        e = pos[b_] - pos[a_]
        elen2 = _dot3(e, e)
        pn = np.cross(e, unit[he // 3])
        pn /= np.maximum(np.linalg.norm(pn, axis=1), 1e-300)[:, None]
        pd = -_dot3(pn, pos[a_])
        bq = _plane_quadrics(np.concatenate([pn, pd[:, None]], axis=1), BOUNDARY_WEIGHT * elen2)
        out += _index_sum(np.concatenate([a_, b_]), np.concatenate([bq, bq]), n)
    return out


def _dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(k,) float64 row dot products of a, b (k, 3) float64, summed ``(x0 + x2) + x1``."""
    return (a[:, 0] * b[:, 0] + a[:, 2] * b[:, 2]) + a[:, 1] * b[:, 1]


def _index_sum(idx, q, n):
    """(n, 10) float64: the rows of ``q`` (k, 10) float64 summed by ``idx`` (k,) int64, in ``idx``
    order (``np.bincount`` per column)."""
    return np.stack([np.bincount(idx, weights=q[:, j], minlength=n) for j in range(q.shape[1])], axis=1)


@kernel_helper
def _unit_normal(pos, faces, f):
    """Face ``f``'s unit normal and doubled area, as :func:`face_quadrics` computes them (``np.cross``,
    ``np.linalg.norm``, the division by the norm floored at 1e-300): ``(ux, uy, uz, area2)``."""
    i, j, k = faces[f, 0], faces[f, 1], faces[f, 2]
    a0, a1, a2 = pos[j, 0] - pos[i, 0], pos[j, 1] - pos[i, 1], pos[j, 2] - pos[i, 2]
    b0, b1, b2 = pos[k, 0] - pos[i, 0], pos[k, 1] - pos[i, 1], pos[k, 2] - pos[i, 2]
    nx, ny, nz = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    area2 = np.sqrt((nx * nx + ny * ny) + nz * nz)
    s = area2 if (area2 >= 1e-300 or area2 != area2) else 1e-300  # np.maximum (NaN propagates)
    return nx / s, ny / s, nz / s, area2


@kernel_helper
def _add_plane(out, row, a, b, c, d, w):
    """``out[row] += w * (the plane's quadric)``, entry by entry as :func:`_plane_quadrics` makes it."""
    out[row, 0] += w * (a * a)
    out[row, 1] += w * (a * b)
    out[row, 2] += w * (a * c)
    out[row, 3] += w * (a * d)
    out[row, 4] += w * (b * b)
    out[row, 5] += w * (b * c)
    out[row, 6] += w * (b * d)
    out[row, 7] += w * (c * c)
    out[row, 8] += w * (c * d)
    out[row, 9] += w * (d * d)


def _quadrics_kernel(pos, faces, boundary, n, boundary_weight):
    """Compiled :func:`face_quadrics` (the same bits) without its (m, ...) temporaries: each face's
    plane added at its corners in face order; then every boundary plane summed per vertex (first at
    the edges' first ends, then at their second ends, in edge order, from zero, as ``np.bincount``
    does) and that sum added to the vertex's face quadric."""
    out = np.zeros((n, 10), np.float64)
    for f in range(len(faces)):
        ux, uy, uz, area2 = _unit_normal(pos, faces, f)
        d = -((ux * pos[faces[f, 0], 0] + uz * pos[faces[f, 0], 2]) + uy * pos[faces[f, 0], 1])
        for k in range(3):
            _add_plane(out, faces[f, k], ux, uy, uz, d, 0.5 * area2)
    b = len(boundary)
    if b == 0:
        return out
    planes = np.empty((b, 5), np.float64)  # a, b, c, d, weight of each boundary plane
    ends = np.empty((2, b), np.int64)
    for i in range(b):
        h = boundary[i]
        f, c = h // 3, h % 3
        x, y = faces[f, c], faces[f, (c + 1) % 3]
        ends[0, i], ends[1, i] = x, y
        e0, e1, e2 = pos[y, 0] - pos[x, 0], pos[y, 1] - pos[x, 1], pos[y, 2] - pos[x, 2]
        ux, uy, uz, _ = _unit_normal(pos, faces, f)
        px, py, pz = e1 * uz - e2 * uy, e2 * ux - e0 * uz, e0 * uy - e1 * ux
        norm = np.sqrt((px * px + py * py) + pz * pz)
        s = norm if (norm >= 1e-300 or norm != norm) else 1e-300
        px, py, pz = px / s, py / s, pz / s
        planes[i, 0], planes[i, 1], planes[i, 2] = px, py, pz
        planes[i, 3] = -((px * pos[x, 0] + pz * pos[x, 2]) + py * pos[x, 1])
        planes[i, 4] = boundary_weight * ((e0 * e0 + e2 * e2) + e1 * e1)
    slot = np.full(n, -1, np.int64)  # boundary vertex -> its row of ``acc``
    acc = np.zeros((2 * b, 10), np.float64)
    rows = 0
    for side in range(2):
        for i in range(b):
            x = ends[side, i]
            if slot[x] < 0:
                slot[x] = rows
                rows += 1
            _add_plane(acc, slot[x], planes[i, 0], planes[i, 1], planes[i, 2], planes[i, 3], planes[i, 4])
    for x in range(n):
        if slot[x] >= 0:
            for j in range(10):
                out[x, j] += acc[slot[x], j]
    return out


def _plane_quadrics(planes: np.ndarray, weight: np.ndarray) -> np.ndarray:
    a, b, c, d = planes.T
    return weight[:, None] * np.stack(
        [a * a, a * b, a * c, a * d, b * b, b * c, b * d, c * c, c * d, d * d], axis=1
    )


def _plane_weight(q: np.ndarray) -> np.ndarray:
    """Total weight of the planes in quadrics (k, 10): the trace a2 + b2 + c2 (unit normals)."""
    return q[:, 0] + q[:, 4] + q[:, 7]


def quadric_error(q: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Evaluate quadrics (k, 10) at points (k, 3) float64: returns (k,) float64 >= 0 (clipped).  Compiled:
    row by row (:func:`_quadric_error_kernel`, the same bits, no (k,) temporaries)."""
    kernel = compiled(_quadric_error_kernel)
    if kernel is not None:
        return kernel(q, p)
    x, y, z = p.T
    a2, ab, ac, ad, b2, bc, bd, c2, cd, d2 = q.T
    err = (
        a2 * x * x + 2 * ab * x * y + 2 * ac * x * z + 2 * ad * x
        + b2 * y * y + 2 * bc * y * z + 2 * bd * y
        + c2 * z * z + 2 * cd * z + d2
    )
    return np.maximum(err, 0.0)


def _quadric_error_kernel(q, p):
    """Compiled :func:`quadric_error`: :func:`_quadric_at` row by row."""
    out = np.empty(len(q), np.float64)
    for i in range(len(q)):
        out[i] = _quadric_at(_quadric_row(q, i), p, i)
    return out


@kernel_helper
def _quadric_row(Q, u):
    """Row ``u`` of the quadrics Q (n, 10) float64 as a tuple of ten floats (held in registers while
    one vertex's collapses are costed)."""
    return Q[u, 0], Q[u, 1], Q[u, 2], Q[u, 3], Q[u, 4], Q[u, 5], Q[u, 6], Q[u, 7], Q[u, 8], Q[u, 9]


@kernel_helper
def _quadric_at(q, P, v):
    """Compiled ``quadric_error(q, P[v])`` for one quadric ``q`` (:func:`_quadric_row`) and one point of
    P (n, 3) float64: the same operations in the same order (no contraction) and ``np.maximum``'s
    choice, so the same bits."""
    x, y, z = P[v, 0], P[v, 1], P[v, 2]
    err = (
        q[0] * x * x + 2 * q[1] * x * y + 2 * q[2] * x * z + 2 * q[3] * x
        + q[4] * y * y + 2 * q[5] * y * z + 2 * q[6] * y
        + q[7] * z * z + 2 * q[8] * z + q[9]
    )
    return err if (err >= 0.0 or err != err) else 0.0


def simplify(
    positions: np.ndarray,
    faces: np.ndarray,
    *,
    target_vertices: int = 0,
    max_batches: int = 400,
    locked: np.ndarray | None = None,
    weld: np.ndarray | None = None,
    twin: np.ndarray | None = None,
    points: np.ndarray | None = None,
) -> CollapseLog:
    """Coarsen a mesh by batches of independent half-edge collapses.

    Parameters
    ----------
    positions : (n, 3) int64 or float
        Vertex positions (usually grid integers; used for geometry tests only).
    faces : (m, 3) int64
        Triangles, counter-clockwise.
    target_vertices : int
        Stop once the mesh has at most this many vertices.
    max_batches : int
        Upper bound on the number of batches.
    locked : (n,) bool, optional
        Vertices that must stay in the base mesh.
    weld : (n,) int64, optional
        Seam copies: the smallest vertex id at each vertex's position
        (:func:`~pmwm_codec.progressive.seams.weld_groups`).  Vertices that share a
        position are removed only in seam pairs (:mod:`.seams`); None: no seams.
    twin : (m,) bool, optional
        :func:`twin_faces` of ``faces``, when the caller has it (:func:`deferred_and_twin_faces`).
    points : (n,) int64, optional
        ``weld_groups(positions)`` (:func:`~.seams.weld_groups`: the first vertex on each vertex's point),
        when the caller has it.  Vertices on a point that another vertex (not a seam copy of theirs) shares
        go first (:func:`coincident_vertices`).

    Returns
    -------
    CollapseLog
        Batches in collapse order (the decoder applies them in reverse).
    """
    n = int(positions.shape[0])
    m = int(faces.shape[0])
    pos = np.asarray(positions, np.float64)
    corners = np.array(faces, dtype=np.int64, copy=True)
    face_alive = np.ones(m, dtype=bool)
    vert_alive = np.zeros(n, dtype=bool)
    vert_alive[corners.ravel()] = True
    live = live_mesh(corners, face_alive, vert_alive)
    boundary = live.et.he0[live.et.count == 1]  # the input's boundary half-edges, in edge order (every face is live)
    # positions and quadrics of the live vertices and the quadrics' errors at them, in local ids (:func:`_kept_rows`
    # from batch to batch; :func:`_apply` updates the errors where it merges quadrics)
    P, Q = _local_rows(pos, face_quadrics(pos, corners, n, live.fids[boundary // 3] * 3 + boundary % 3), live.vids)
    own = quadric_error(Q, P)
    frozen_ext = np.zeros(n, bool) if locked is None else np.asarray(locked, bool).copy()
    twin = twin_faces(corners) if twin is None else np.asarray(twin, bool)
    twin = np.flatnonzero(twin) if twin.any() else None  # the doubled faces' ids (a scan's: a few, of ~50k faces)
    log = CollapseLog(n, m, None, None, None, [])

    alive_count = int(vert_alive.sum())
    points = seams.weld_groups(pos) if points is None and alive_count > target_vertices else points
    shared = None if points is None else coincident_vertices(points, vert_alive, weld)
    # vertices on a grid point another vertex shares: no collapse may put two on one face (:func:`_no_new_slivers`)
    on_shared = None if points is None else np.bincount(points, minlength=n)[points] > 1
    on_shared = on_shared if on_shared is not None and on_shared.any() else None
    legal_only = False
    for b in range(max_batches):
        if alive_count <= target_vertices:
            break
        if b:
            ids = live.vids, live.fids, live.loc
            live = None  # the previous batch's edge tables and adjacency freed before the next ones are made
            live = live_mesh(corners, face_alive, vert_alive, ids)
            P, Q, own = _kept_rows(P, Q, own, ids[0], vert_alive)
        first = None
        if shared is not None and len(shared):
            first = np.zeros(n, bool)
            first[shared] = True
        doubled = None if twin is None else live.loc[corners[twin[face_alive[twin]]]]
        batch, stalled = _one_batch(P, Q, own, live, frozen_ext, alive_count - target_vertices, weld, doubled, first,
                                    legal_only, None if on_shared is None else (points, on_shared))
        # once a batch stalls, the illegal offers that held it hold the later ones too (the illegal share of the
        # candidates grows as the mesh coarsens: dragon23k, 14 % at batch 15 of 61, 72 % at batch 53): the
        # batches after it select among the legal candidates from the start
        legal_only = legal_only or stalled
        if batch is None:
            break
        _apply(batch, corners, face_alive, vert_alive, P, Q, own, live.loc)
        alive_count -= len(batch.u)
        log.batches.append(batch)
        if first is not None:
            shared = coincident_vertices(points, vert_alive, weld, shared) if b + 1 < SHARED_FIRST_BATCHES else None

    log.base_vertices = np.flatnonzero(vert_alive)
    log.base_faces = np.flatnonzero(face_alive)
    log.base_corners = corners[log.base_faces]
    return log


def coincident_vertices(points: np.ndarray, alive: np.ndarray, weld: np.ndarray | None = None,
                        among: np.ndarray | None = None) -> np.ndarray:
    """(k,) int64, ascending: the ``alive`` (n,) bool vertices on a point that another alive vertex shares,
    other than their own seam copies.  ``points`` (n,) int64: the first vertex on each vertex's point
    (:func:`~.seams.weld_groups` of the grid positions, one value per point); ``weld`` (n,) int64 or None the
    seam copies (:func:`simplify`'s); ``among`` (j,) int64 or None: look only at these vertices (an earlier
    answer: vertices only leave the mesh, so a point once free of others stays free).

    A base with two such vertices needs the weld attribute to be stored in Draco's own vertex order (a reader
    welds a Draco base's copies by grid point, spec README "Welded base"; the attribute tells them apart), and
    one with a face on two of them cannot be (Draco drops a face with two corners at one position), so the
    base falls back to Draco's sequential coder, about three times the bytes (a scan's base: 3.2 -> 10.4 KB,
    before the weld attribute).  :func:`simplify` offers their collapses first in its first batches, while
    nearly every collapse is legal (at four times the target vertex count, a scan's two such vertices had no
    legal collapse left)."""
    n = len(points)
    if among is None:
        among = np.flatnonzero(np.bincount(points, minlength=n)[points] > 1)  # every vertex on a point of two
    among = among[alive[among]]
    point = points[among]
    seam = among if weld is None else weld[among]
    order = np.lexsort((seam, point))
    p, s = point[order], seam[order]
    second = (p[1:] == p[:-1]) & (s[1:] != s[:-1])  # a point's second (third, ...) seam group
    return among[np.isin(point, p[1:][second])]


def _apply(batch, corners, face_alive, vert_alive, P, Q, own, loc):
    """Apply a :class:`CollapseBatch` to the simplifier's state in place: delete its faces, rewrite
    the moved corners ``u -> v``, retire ``u``, merge its quadric into ``v``'s and evaluate that at ``v``
    (``P`` (n, 3), ``Q`` (n, 10) and ``own`` (n,) float64, the batch's local positions, quadrics and
    ``quadric_error(Q, P)``; ``loc`` (N,) int64 its original -> local ids; the batch's ``u`` and ``v``
    are disjoint, every ``v`` once)."""
    kernel = compiled(_apply_kernel)
    if kernel is not None:
        kernel(batch.u, batch.v, batch.del_left, batch.del_right, batch.moved_face, batch.moved_by,
               corners, face_alive, vert_alive, P, Q, own, loc)
        return
    dead = np.concatenate([batch.del_left[batch.del_left >= 0], batch.del_right[batch.del_right >= 0]])
    face_alive[dead] = False
    mf = batch.moved_face
    sub = corners[mf]
    corners[mf] = np.where(sub == batch.u[batch.moved_by][:, None], batch.v[batch.moved_by][:, None], sub)
    vert_alive[batch.u] = False
    kept = loc[batch.v]
    Q[kept] += Q[loc[batch.u]]
    own[kept] = quadric_error(Q[kept], P[kept])


def _apply_kernel(u, v, del_left, del_right, moved_face, moved_by, corners, face_alive, vert_alive, P, Q, own, loc):
    """Compiled :func:`_apply` (the same state afterwards, the same quadric and error bits)."""
    for i in range(len(u)):
        for f in (del_left[i], del_right[i]):
            if f >= 0:
                face_alive[f] = False
        vert_alive[u[i]] = False
        a, b = loc[u[i]], loc[v[i]]
        for j in range(Q.shape[1]):
            Q[b, j] = Q[b, j] + Q[a, j]
        own[b] = _quadric_at(_quadric_row(Q, b), P, b)
    for k in range(len(moved_face)):
        f, i = moved_face[k], moved_by[k]
        for c in range(3):
            if corners[f, c] == u[i]:
                corners[f, c] = v[i]


def _one_batch(P, Q, own, live, frozen_ext, budget, weld=None, twin=None, first=None, legal_only=False,
               shared=None):
    """Choose and describe one batch of independent legal collapses: ``(CollapseBatch or None, stalled)``.

    ``live`` is the :class:`~.livemesh.LiveMesh` of the simplifier's live faces, P (n, 3) and Q (n, 10)
    float64 its vertices' positions and quadrics (local ids), ``own`` (n,) float64 ``quadric_error(Q, P)``,
    frozen_ext (N,) bool the simplifier's
    frozen vertices (original ids); at most ``budget`` vertices are removed (the cheapest collapses).
    ``weld`` (N,) int64 or None: seam copies (see :func:`simplify`).  The work is done on the live mesh
    renumbered compactly ("local" ids) and returned in original ids.  ``twin`` (t, 3) int64 or None: the
    live doubled faces (:func:`twin_faces`) in local ids, in face order.  ``first`` (N,) bool or None: vertices whose collapses are offered
    first (ranked as costing nothing; the batch records their true costs).  ``legal_only``: select among
    the legal candidates from the start; ``stalled``: this batch did (``legal_only``, or it stalled:
    :func:`_unstalled`).  ``shared``: ``(points, on_shared)`` (N,) int64 and (N,) bool, the first vertex on each
    vertex's grid point and the vertices on a point another shares, or None (none does): no collapse may leave a
    face with two corners on one point (:func:`_no_new_slivers`).
    """
    vids, fids, loc, F, et, vv, vf, fcount = (live.vids, live.fids, live.loc, live.F, live.et, live.vv, live.vf,
                                              live.fcount)
    vv_edge = live.vv_edge
    n = len(vids)
    frozen = frozen_ext[vids]
    g = None if weld is None else seams.local_groups(weld, vids, loc)
    seam = None if g is None else seams.seam_mask(g)
    if seam is not None and not seam.any():
        g = seam = None
    src, opp = F.reshape(-1), live.opp
    dst = None if seam is None else half_edges(F)[1]  # only the seam pairs read dst
    twins = _twin_counts(et, twin, n)
    mesh = (et, F, P, opp, fcount, vv, vf, vv_edge, twins[0])
    ends = live.boundary, live.edge_flags
    cand = _candidates(mesh, ends, Q, src, frozen if seam is None else frozen | seam, twins, own=own)
    if cand is None and seam is None:
        return None, legal_only
    first = None if first is None or cand is None else (first[vids] if seam is None else first[vids] & ~seam)
    hit = None if first is None else first[cand[0]]
    if hit is not None and hit.any():  # their collapses rank as costing nothing (cand's own cost array, fresh)
        cand[3][hit] = 0.0
    pairs = None if seam is None else _seam_pairs(Q, own, src, dst, frozen, seam, g, mesh, ends)
    # the ordinary candidates must be independent of the chosen seam pairs (left out as the affordable ones are
    # picked, one pass over the candidates)
    blocked = None if pairs is None else seams.blocked_by(pairs[0], pairs[1], vv, n)
    for quantile in (BATCH_QUANTILE, 1.0):  # all candidates when no affordable one is legal
        part = None if cand is None else _affordable(*cand, quantile, blocked)
        part = _legal_only(part, mesh) if legal_only else part
        win = _ordinary_winners(part, mesh, n) if part is not None else np.zeros(0, np.int64)
        if len(win) or pairs is not None or quantile >= 1.0:
            break
    cand = part if legal_only else _unstalled(part, win, mesh, n)
    stalled = legal_only or cand is not part
    if cand is not part:
        win = _ordinary_winners(cand, mesh, n)
    if len(win) == 0 and pairs is None:
        return None, stalled
    if pairs is None:
        if len(win) > budget:
            win = win[np.argsort(cand[3][win], kind="stable")[:budget]]
        win = np.sort(win)
        cu, cv, ce, cost = (x[win] for x in cand)
    else:
        cu, cv, ce, cost = _merge_pairs(cand, win, pairs, budget)
        if len(cu) == 0:
            return None, stalled
    moved_face, moved_by = _moved_faces(vf, F, cu, cv)
    if shared is not None and len(moved_face):  # no collapse may put two corners of a face on one grid point
        keep = _no_new_slivers(shared[0][vids], shared[1][vids], F, g, cu, cv, moved_face, moved_by)
        if not keep.all():
            cu, cv, ce, cost = cu[keep], cv[keep], ce[keep], cost[keep]
            if len(cu) == 0:
                return None, stalled
            moved_face, moved_by = _moved_faces(vf, F, cu, cv)
    rows = None if first is None else np.flatnonzero(first[cu])
    if rows is not None and len(rows):  # their true costs (as _candidates computes them, row by row: the same bits)
        cost = cost.copy()
        cost[rows] = quadric_error(np.take(Q, cu[rows], axis=0), np.take(P, cv[rows], axis=0)) + own[cv[rows]]
    u, v, del_left, wing_left, del_right, wing_right, error = _described(et, src, opp, vids, fids, Q, cu, cv, ce, cost)
    return CollapseBatch(u=u, v=v, del_left=del_left, del_right=del_right, wing_left=wing_left, wing_right=wing_right,
                         moved_face=fids[moved_face], moved_by=moved_by, cost=cost, error=error), stalled


def _no_new_slivers(point, on_shared, F, g, cu, cv, moved_face, moved_by):
    """(k,) bool: the collapses ``cu -> cv`` ((k,) int64 local ids) that leave no face with two corners on one grid
    point that had none (``point`` (n,) int64 a point id per live vertex, ``on_shared`` (n,) bool: on a point another
    vertex shares): a *sliver*, which Draco's own order drops from a base (it drops faces whose corners share a
    position), and which no later collapse removes when the two are seam copies (copies move together: ``g`` (n,)
    int64, :func:`~.seams.local_groups`, or None: no copies; a face that gets two copies is refused too).  A seam
    copy's collapse that is refused takes the collapses of its whole seam group with it.  ``F`` (f, 3) the live
    faces, ``moved_face`` / ``moved_by`` (j,) int64 :func:`_moved_faces`'.  Only a face moved onto a vertex that
    shares its point can become one: only those are looked at."""
    rows = np.flatnonzero(on_shared[cv[moved_by]])
    keep = np.ones(len(cu), bool)
    if not len(rows):
        return keep
    by = moved_by[rows]
    tri = F[moved_face[rows]]
    new = np.where(tri == cu[by][:, None], cv[by][:, None], tri)
    made = two_alike(point[new]) & ~two_alike(point[tri])
    if g is not None:  # two copies on a face: no later collapse parts them (a face on one point and another may)
        made |= two_alike(g[new]) & ~two_alike(g[tri])
    keep[by[made]] = False
    if not keep.all() and g is not None:
        keep &= ~(np.isin(g[cu], g[cu[~keep]]) & (np.bincount(g, minlength=len(g))[g[cu]] > 1))
    return keep


def _local_rows(pos, quad, vids):
    """``(pos[vids], quad[vids])``: the rows (n, 3) and (n, 10) float64 of the live vertices ``vids`` (n,)
    int64 (numpy: np.take, which copies row by row, one memcpy each; compiled: one loop)."""
    kernel = compiled(_local_rows_kernel)
    if kernel is None:
        return np.take(pos, vids, axis=0), np.take(quad, vids, axis=0)
    return kernel(pos, quad, vids)


def _local_rows_kernel(pos, quad, vids):
    """Compiled :func:`_local_rows`."""
    P = np.empty((len(vids), pos.shape[1]), np.float64)
    Q = np.empty((len(vids), quad.shape[1]), np.float64)
    for i in range(len(vids)):
        for j in range(pos.shape[1]):
            P[i, j] = pos[vids[i], j]
        for j in range(quad.shape[1]):
            Q[i, j] = quad[vids[i], j]
    return P, Q


def _kept_rows(P, Q, own, vids, vert_alive):
    """The rows of ``P`` (n, 3), ``Q`` (n, 10) and ``own`` (n,) float64 (the live vertices ``vids`` (n,)
    int64 of the batch before, in local ids) whose vertices are still alive (``vert_alive`` (N,) bool):
    the next batch's local rows, in its order.  Compiled: moved down in place (views of P, Q and own;
    the batch before must be done with them), so that every batch reads the rows of the one before,
    not the whole mesh's original arrays."""
    kernel = compiled(_kept_rows_kernel)
    if kernel is None:
        keep = vert_alive[vids]
        return P[keep], Q[keep], own[keep]
    return kernel(P, Q, own, vids, vert_alive)


def _kept_rows_kernel(P, Q, own, vids, vert_alive):
    """Compiled :func:`_kept_rows`: every row moved down to the next free row, kept (the count advanced) or
    not, no branch on the flags (a batch removes about every 7th vertex, scattered)."""
    k = 0
    for i in range(len(vids)):
        for j in range(P.shape[1]):
            P[k, j] = P[i, j]
        for j in range(Q.shape[1]):
            Q[k, j] = Q[i, j]
        own[k] = own[i]
        k += vert_alive[vids[i]]
    return P[:k], Q[:k], own[:k]


def _described(et, src, opp, vids, fids, Q, cu, cv, ce, cost):
    """The chosen collapses ``cu -> cv`` on edges ``ce`` ((k,) int64 local ids, ``cost`` (k,) float64) in
    :class:`CollapseBatch` terms: ``(u, v, del_left, wing_left, del_right, wing_right, error)``, (k,) int64
    original ids (-1: none, :func:`_deleted_faces`) and (k,) float64 errors (Q (n, 10) the local quadrics)."""
    kernel = compiled(_described_kernel)
    if kernel is not None:
        return kernel(et.he0, et.he1, src, opp, vids, fids, Q, cu, cv, ce, cost)
    del_left, wing_left, del_right, wing_right = _deleted_faces(et, src, opp, cu, ce)
    error = np.sqrt(cost / np.maximum(_plane_weight(np.take(Q, cu, axis=0) + np.take(Q, cv, axis=0)), 1e-300))
    return (vids[cu], vids[cv], _to_original(fids, del_left), _to_original(vids, wing_left),
            _to_original(fids, del_right), _to_original(vids, wing_right), error)


def _described_kernel(he0, he1, src, opp, vids, fids, Q, cu, cv, ce, cost):
    """Compiled :func:`_described`: the same arrays, the same error bits (the summed quadrics' plane
    weight ``(q0 + q4) + q7`` as :func:`_plane_weight`, floored at 1e-300 with NaN kept as np.maximum)."""
    k = len(cu)
    out = np.full((6, k), -1, np.int64)  # u, v, del_left, wing_left, del_right, wing_right
    error = np.empty(k, np.float64)
    for i in range(k):
        u, v, e = cu[i], cv[i], ce[i]
        out[0, i], out[1, i] = vids[u], vids[v]
        for h in (he0[e], he1[e]):  # the first face holding u -> v is the left one, v -> u the right one
            if h >= 0:
                side = 2 if src[h] == u else 4
                if out[side, i] < 0:
                    out[side, i], out[side + 1, i] = fids[h // 3], vids[opp[h]]
        w = ((Q[u, 0] + Q[v, 0]) + (Q[u, 4] + Q[v, 4])) + (Q[u, 7] + Q[v, 7])
        w = w if (w >= 1e-300 or w != w) else 1e-300
        error[i] = np.sqrt(cost[i] / w)
    return out[0], out[1], out[2], out[3], out[4], out[5], error


def _unstalled(cand, win, mesh, n):
    """``cand`` itself, or only its legal candidates when the batch stalls: fewer winners ``win``
    than :data:`STALL_FRACTION` of the vertices offering a collapse.

    The selection only tests the legality of each round's local winners, so cheap illegal
    offers (a fold-over, a link condition that fails) can hold the local minima for every round
    while their neighbours' legal collapses never get to win.  Once that leaves a batch almost
    empty, testing every candidate first and selecting among the legal ones lets the mesh
    coarsen on: on the Stanford dragon (437k vertices, grid 16) the base fell from 53k vertices
    to 5.6k (target 4.4k) in 87 batches instead of 220."""
    if cand is None or len(cand[0]) == 0:
        return cand
    offering = len(_group_starts(cand[0]))
    if len(win) >= STALL_FRACTION * offering:
        return cand
    return _legal_only(cand, mesh)


def _legal_only(cand, mesh):
    """The legal candidates of ``cand = (cu, cv, ce, cost)`` (:func:`_legal`), or ``cand`` itself when all or
    none are (``mesh`` as in :func:`_ordinary_winners`)."""
    if cand is None or len(cand[0]) == 0:
        return cand
    ok = _legal(cand[0], cand[1], cand[2], mesh)
    if ok.all() or not ok.any():
        return cand
    return tuple(x[ok] for x in cand)


def _ordinary_winners(cand, mesh, n):
    """Indices (w,) int64 into the candidates ``cand = (cu, cv, ce, cost)`` chosen by :func:`_select`
    (or its compiled twin); ``mesh`` is ``(et, F, P, opp, fcount, vv, vf, vv_edge, twin_edge)`` of the local
    mesh (:class:`~.livemesh.LiveMesh`; ``opp`` (3m,) the half-edges' opposite corners; ``twin_edge`` (e,)
    bool the pillows' edges, :func:`_twin_counts`)."""
    cu, cv, ce, cost = cand
    if len(cu) == 0:
        return np.zeros(0, np.int64)

    def legal(idx):
        return _legal(cu[idx], cv[idx], ce[idx], mesh)

    kernel = compiled(_select_kernel)
    if kernel is None:
        return _select(cu, cv, cost, legal, mesh[5], n, ROUNDS)
    et, F, P, opp, fcount, vv, vf, vv_edge, twin_edge = mesh
    return kernel(cu, cv, ce, _offer_ranks(cu, cost), vv[0], vv[1], n, ROUNDS,
                  (vv_edge, et.count, et.he0, et.he1, F, P, opp, fcount, vf[0], vf[1], _fin_vertices(et, n),
                   twin_edge))


def _fin_vertices(et, n):
    """(n,) bool: the vertices on an edge of ``et`` with more than two faces (compiled: one pass over the edges)."""
    kernel = compiled(_fin_vertices_kernel)
    if kernel is not None:
        return kernel(et.count, et.lo, et.hi, n)
    fin = np.zeros(n, bool)
    many = et.count > 2
    fin[et.lo[many]] = True
    fin[et.hi[many]] = True
    return fin


def _fin_vertices_kernel(count, lo, hi, n):
    """Compiled :func:`_fin_vertices`: the same (n,) bool."""
    fin = np.zeros(n, np.bool_)
    for e in range(len(count)):
        if count[e] > 2:
            fin[lo[e]] = True
            fin[hi[e]] = True
    return fin


def _seam_pairs(Q, own, src, dst, frozen, seam, g, mesh, ends):
    """The seam pairs of this batch (:mod:`.seams`), or None.

    Q (n, 10) quadrics, ``own`` (n,) their errors (:func:`_candidates`), src / dst (3m,) half-edges,
    frozen / seam (n,) bool, g (n,) int64 seam groups, ``mesh`` as in :func:`_ordinary_winners`, ``ends``
    as in :func:`_candidates`.  Returns ``(cu, cv, ce, cost)``, each (2p,) (int64 / float64 half costs):
    first halves, then second halves in the same order (pair ``k`` is rows ``k`` and ``p + k``).
    """
    et, F, P, opp, fcount, vv, vf, _, _ = mesh
    halves = _candidates(mesh, ends, Q, src, frozen | ~seam, rows=np.flatnonzero(seam & ~frozen), own=own)
    if halves is None:
        return None
    hu, hv, he, hcost = halves
    i, j = seams.pair_up(hu, hv, he, g, et, src, dst, opp, vv)
    if len(i) == 0:
        return None
    both = np.concatenate([i, j])
    ok = _legal(hu[both], hv[both], he[both], mesh)
    good = ok[: len(i)] & ok[len(i):]
    i, j = i[good], j[good]
    pick = seams.choose_pairs(hu, hv, i, j, hcost[i] + hcost[j], vv, len(P))
    if len(pick) == 0:
        return None
    rows = np.concatenate([i[pick], j[pick]])
    return hu[rows], hv[rows], he[rows], hcost[rows]


def _merge_pairs(cand, win, pairs, budget):
    """``(cu, cv, ce, cost)`` of a batch: ordinary winners ``win`` (indices into ``cand``) and
    seam ``pairs`` (:func:`_seam_pairs`), cut to ``budget`` removed vertices with pairs whole."""
    p = len(pairs[0]) // 2
    win = np.sort(win)
    single_cost = cand[3][win] if cand is not None else np.zeros(0)
    singles, keep = seams.within_budget(single_cost, pairs[3][:p] + pairs[3][p:], budget)
    rows = np.concatenate([keep, keep + p])
    parts = [(x[win[singles]] for x in cand)] if cand is not None else []
    return tuple(np.concatenate(cols) for cols in zip(*parts, (x[rows] for x in pairs)))


def _affordable(cu, cv, ce, cost, quantile: float, blocked=None):
    """The candidates (grouped by ``cu``, as from :func:`_candidates`) whose cost is at most
    the ``quantile`` of the per-vertex cheapest costs; all of them when ``quantile >= 1``.

    ``blocked``: None, or ``(no_remove, no_keep)`` (n,) bool (:func:`.seams.blocked_by` of the batch's seam
    pairs): the candidates whose removed vertex is in ``no_remove`` or kept vertex in ``no_keep`` are left out
    first, and the quantile is of what is left (None, or no rows, when nothing is: the same to the callers).
    """
    kernel = compiled(_affordable_kernel)
    if blocked is not None and (kernel is None or quantile >= 1.0 or len(cu) == 0):
        keep = ~blocked[0][cu] & ~blocked[1][cv]
        if not keep.any():
            return None
        cu, cv, ce, cost = cu[keep], cv[keep], ce[keep], cost[keep]
        blocked = None
    if quantile >= 1.0 or len(cu) == 0:
        return cu, cv, ce, cost
    if kernel is None:
        keep = cost <= np.quantile(cost[_group_starts(cu)], quantile)
        return cu[keep], cv[keep], ce[keep], cost[keep]
    none = np.zeros(0, np.bool_)
    return kernel(cu, cv, ce, cost, quantile, *((none, none) if blocked is None else blocked))


def _affordable_kernel(cu, cv, ce, cost, quantile, no_remove, no_keep):
    """Compiled :func:`_affordable` (0 <= quantile < 1, c >= 1): the rows (a,) of the four (c,) arrays
    not blocked (``no_remove`` / ``no_keep`` (n,) bool, or both empty: none is) with ``cost`` at most
    :func:`_quantile_kernel` of the groups' first costs (each group's first row not blocked), as views
    of (a + 1,) arrays (rows are written before they are known to be kept: 0.88x the time)."""
    ok = np.ones(len(cu), np.bool_)
    if len(no_remove):
        for i in range(len(cu)):
            ok[i] = not no_remove[cu[i]] and not no_keep[cv[i]]
    firsts = np.empty(len(cu), np.float64)  # cost[_group_starts(cu)] of the rows not blocked
    g = 0
    last = -1
    for i in range(len(cu)):  # every row written, kept (g advanced) or not: no branch on the rows
        firsts[g] = cost[i]
        g += ok[i] and cu[i] != last
        last = cu[i] if ok[i] else last
    if g == 0:
        return np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.int64), np.empty(0, np.float64)
    limit = _quantile_kernel(firsts[:g], quantile)
    k = 0
    for i in range(len(cost)):
        k += ok[i] and cost[i] <= limit
    ou, ov, oe = np.empty(k + 1, np.int64), np.empty(k + 1, np.int64), np.empty(k + 1, np.int64)
    oc = np.empty(k + 1, np.float64)
    j = 0
    for i in range(len(cost)):  # likewise (about half the rows are kept, at random: a branch mispredicted)
        ou[j], ov[j], oe[j], oc[j] = cu[i], cv[i], ce[i], cost[i]
        j += ok[i] and cost[i] <= limit
    return ou[:k], ov[:k], oe[:k], oc[:k]


@kernel_helper(allocates=True)
def _quantile_kernel(x, q):
    """``np.quantile(x, q)`` (method "linear") of ``x`` (g,) float64, g >= 1, 0 <= q < 1, with numpy's
    arithmetic: the order statistics at ``floor((g - 1) q)`` and the next, ``_lerp``'s two formulas, NaN
    when ``x`` holds one (the order statistics are values, the same whichever partition finds them; only
    the sign of a zero could differ, which no ``<=`` test sees)."""
    for i in range(len(x)):
        if x[i] != x[i]:
            return x[i]
    virtual = (len(x) - 1) * q
    lo = int(np.floor(virtual))
    hi = lo + 1
    if virtual >= len(x) - 1:  # numpy takes the last value (index -1) both times
        lo = hi = len(x) - 1
        gamma = virtual + 1.0
    else:
        gamma = virtual - lo
    if hi != lo and len(x) >= _RADIX_FROM:
        part, lo = _radix_bucket(x, lo)  # the rows of the buckets holding both order statistics, and lo among them
    else:
        part = x.copy()
    a = _kth_smallest(part, lo)
    b = a
    if hi != lo:
        b = part[lo + 1]
        for t in range(lo + 2, len(part)):
            b = min(b, part[t])
    diff = b - a
    return b - diff * (1.0 - gamma) if gamma >= 0.5 else a + diff * gamma


#: :func:`_quantile_kernel` narrows larger inputs down by :func:`_radix_bucket` first (below it, the partitions'
#: mispredicted branches cost less than two passes).
_RADIX_FROM = 2048


@kernel_helper(allocates=True)
def _radix_bucket(x, k):
    """``(part, j)``: the values of ``x`` (g,) float64, C-contiguous, no NaN, 0 <= k < g - 1, whose keys share their top
    14 bits with the ``k``-th or ``k + 1``-th smallest's (a float's bits as an unsigned key that orders as the floats do,
    -0.0 just below 0.0), and ``j``, the rank of the ``k``-th smallest among them: ``_kth_smallest(part, j)`` and the
    smallest after it are the order statistics ``k`` and ``k + 1`` of ``x``.  Two passes (a histogram of the top bits,
    then the rows of the one or two buckets copied, each row written and kept by advancing the count or not), no
    branch on the values: a quickselect of all g values mispredicts about one branch a value a partition, and several
    partitions; the buckets hold a few percent of the values (14 bits: the exponent and 3 bits of the mantissa)."""
    bits = x.view(np.uint64)
    top = np.uint64(0x8000000000000000)
    hist = np.zeros(1 << 14, np.int64)
    for i in range(len(x)):
        u = bits[i]
        hist[np.int64(((u ^ ((np.uint64(0) - (u >> np.uint64(63))) | top))) >> np.uint64(50))] += 1
    below = 0
    b0 = 0
    while below + hist[b0] <= k:
        below += hist[b0]
        b0 += 1
    b1 = b0
    if below + hist[b0] <= k + 1:  # the next order statistic is the next bucket's smallest
        b1 = b0 + 1
        while hist[b1] == 0:
            b1 += 1
    size = hist[b0] + (hist[b1] if b1 != b0 else 0)
    part = np.empty(size + 1, np.float64)  # a spare last entry: the rows not kept are written there last
    j = 0
    for i in range(len(x)):
        u = bits[i]
        b = np.int64(((u ^ ((np.uint64(0) - (u >> np.uint64(63))) | top))) >> np.uint64(50))
        part[j] = x[i]
        j += (b == b0) | (b == b1)
    return part[:size], k - below


@kernel_helper
def _kth_smallest(a, k):
    """The ``k``-th smallest of ``a`` (g,) float64 without NaN, 0 <= k < g, by quickselect (Hoare's partition),
    ``a`` reordered in place so that no value after position k is smaller: ``np.partition``'s order statistic
    without numpy's partition, whose compilation took ~1.5 s of a machine's first encode."""
    lo, hi = 0, len(a) - 1
    while lo < hi:
        pivot = a[(lo + hi) >> 1]
        i, j = lo, hi
        while i <= j:
            while a[i] < pivot:
                i += 1
            while a[j] > pivot:
                j -= 1
            if i <= j:
                a[i], a[j] = a[j], a[i]
                i += 1
                j -= 1
        if k <= j:
            hi = j
        elif k >= i:
            lo = i
        else:
            return a[k]
    return a[k]


def _group_starts(cu):
    """(g,) int64: the first index of every run of equal values in ``cu`` (c,) int64, c >= 1."""
    kernel = compiled(_group_starts_kernel)
    if kernel is None:
        return np.flatnonzero(np.r_[True, cu[1:] != cu[:-1]])
    return kernel(cu)


@kernel_helper(allocates=True)
def _group_starts_kernel(cu):
    """Compiled :func:`_group_starts` (every index written, kept by advancing the count or not: no branch
    on the runs, of 1 to TRIES rows)."""
    out = np.empty(len(cu), np.int64)
    k = 0
    for i in range(len(cu)):
        out[k] = i
        k += i == 0 or cu[i] != cu[i - 1]
    return out[:k]



def _to_original(table, local):
    """Local ids (k,) int64 (-1: none) -> original ids through ``table`` (-1 kept)."""
    return np.where(local >= 0, table[np.maximum(local, 0)], -1)


def _candidates(mesh, ends, Q, src, frozen_ext, twins=None, rows=None, own=None):
    """Candidate collapses on the local mesh, grouped by removed vertex, cheapest first.

    ``mesh`` as in :func:`_ordinary_winners`, ``ends`` the live mesh's ``(boundary, edge_flags)``
    (:class:`~.livemesh.LiveMesh`), Q (n, 10) quadrics, ``src`` (3m,) the half-edge sources, frozen_ext
    (n,) bool, ``twins`` the doubled faces' edges and counts (:func:`_twin_counts`; None: none).
    Returns ``(cu, cv, ce, cost)`` ((c,) int64 removed vertex, kept vertex, edge; (c,) float64 quadric
    cost), at most ``TRIES`` per removed vertex, or None when there is none.  ``rows`` (r,) int64,
    ascending: the only vertices ``frozen_ext`` leaves free, when they are few (the compiled kernel then
    visits only them); None: every vertex.  ``own`` (n,) float64: ``quadric_error(Q, P)``, the second
    term of every cost (:func:`simplify` carries it from batch to batch, as it does Q); None: computed.
    """
    et, F, P, _, fcount, vv, _, vv_edge, _ = mesh
    n = len(P)
    if twins is None:
        twins = _twin_counts(et, None, n)
    # (Q_u + Q_v)(p_v) = Q_u(p_v) + Q_v(p_v); the second term is one value per vertex
    own = quadric_error(Q, P) if own is None else own
    kernel = compiled(_candidates_kernel)
    if kernel is not None:
        cu, cv, ce, cost = kernel(vv[0], vv[1], vv_edge, et.count, ends[0], ends[1], fcount, frozen_ext, twins[0],
                                  twins[1], Q, P, own, TRIES, rows)
        return (cu, cv, ce, cost) if len(cu) else None
    cu, cv, ce = _usable(F, et, src, frozen_ext, twins, n)
    if len(cu) == 0:
        return None
    cost = quadric_error(Q[cu], P[cv]) + own[cv]
    # candidates grouped by u, cheapest first; each u offers up to TRIES of them
    # (the same order as argsort(cu * c + rank of cost): cost order, then grouped by u, stably)
    keep = _cheapest_per_group(cu, cost, n)
    return cu[keep], cv[keep], ce[keep], cost[keep]


def _candidates_kernel(vv_start, vv_nbr, vv_edge, count, boundary, edge_flags, fcount, frozen_ext, twin_edge, extra,
                       Q, P, own, tries, rows):
    """Compiled :func:`_candidates` (same arrays, same order), one vertex at a time.

    A vertex's row of the neighbour CSR lists its edges in the order :func:`_usable` meets them
    (edges where it is the low end, then where it is the high end, each in edge order), so the
    usable collapses of ``u`` are its row minus the excluded edges, sorted stably by cost as in
    :func:`_cheapest_per_group` (NaN last), of which the first ``tries`` are kept.  Each of those is the
    cheapest not yet taken, the first of equals (row order), found by a scan of the row's keys with no
    branch on them (a running minimum by selects), then marked taken with a key above every other; the
    keys are the costs' bits as int64: a cost is ``+0.0``, ``-0.0`` (an error rounded to zero) or
    positive, inf or NaN (:func:`_quadric_at` sums), so with the sign bit cleared and every NaN given one
    value above inf's, the bits order the costs as the floats do, NaN last.  (Counting every collapse's
    place, k**2 comparisons, and writing the ones past the first ``tries`` to a spare entry took 1.2x as
    long; a top-3 insertion by selects 1.1x that.)  ``boundary`` / ``edge_flags`` (n,): the live mesh's
    (:class:`~.livemesh.LiveMesh`); a
    vertex on an edge of more than two faces has its row searched for one that is no pillow's.
    ``own`` (n,) float64: the vertices' quadric errors (:func:`_candidates`).  ``rows``: None, every
    vertex, or (r,) int64, ascending, the vertices to visit (a separate compilation).
    """
    n = len(fcount)
    r = n if rows is None else len(rows)
    out_u = np.empty(tries * r, np.int64)
    out_v = np.empty(tries * r, np.int64)
    out_e = np.empty(tries * r, np.int64)
    out_c = np.empty(tries * r, np.float64)
    if rows is None:
        width = 0
        for x in range(n):  # the widest row (a loop: np.diff compiled for ~1 s on a machine's first encode)
            width = max(width, vv_start[x + 1] - vv_start[x])
    else:
        width = 0
        for u in rows:
            width = max(width, vv_start[u + 1] - vv_start[u])
    buf_p = np.empty(width, np.int64)  # row positions of u's usable collapses
    buf_c = np.empty(width, np.float64)  # their costs
    bits = buf_c.view(np.int64)
    buf_k = np.empty(width, np.int64)  # their sort keys: the costs' bits, every NaN one (the largest) value
    k = 0
    for i in range(r):
        u = i if rows is None else rows[i]
        a, b = vv_start[u], vv_start[u + 1]
        if frozen_ext[u] or edge_flags[u] & 1 or (edge_flags[u] & 2 and _on_fin(a, b, vv_edge, count, twin_edge)):
            continue  # a non-manifold (and no pillow's) or inconsistently oriented edge at u
        bu = boundary[u]
        if not ((bu == 0 and b - a == fcount[u] - extra[u]) or (bu == 2 and extra[u] == 0 and b - a == fcount[u] + 1)):
            continue  # not one disk or half-disk of faces
        q = _quadric_row(Q, u)
        m = 0
        some = bu > 0 or edge_flags[u] & 2  # else every edge at u has two faces: none to leave out
        for p in range(a, b):
            if some:
                ce = count[vv_edge[p]]
                if (bu > 0 and ce != 1) or ce > 2:
                    continue
            c = _quadric_at(q, P, vv_nbr[p]) + own[vv_nbr[p]]
            buf_p[m], buf_c[m] = p, c
            buf_k[m] = bits[m] & 0x7FFFFFFFFFFFFFFF if c == c else 0x7FF8000000000000
            m += 1
        for t in range(min(m, tries)):  # the cheapest left, ties in row order (the first): a min scan, no branch
            best = buf_k[0]
            s = 0
            for j in range(1, m):
                lower = buf_k[j] < best
                best = buf_k[j] if lower else best
                s = j if lower else s
            buf_k[s] = 0x7FFFFFFFFFFFFFFF  # taken: above every key
            p = buf_p[s]
            out_u[k + t], out_v[k + t], out_e[k + t], out_c[k + t] = u, vv_nbr[p], vv_edge[p], buf_c[s]
        k += min(m, tries)
    return out_u[:k], out_v[:k], out_e[:k], out_c[:k]


@kernel_helper
def _on_fin(a, b, vv_edge, count, twin_edge):
    """Whether the edges ``vv_edge[a:b]`` (a vertex's row) hold one of more than two faces that is not
    a pillow's (``twin_edge``, :func:`_twin_counts`)."""
    for p in range(a, b):
        e = vv_edge[p]
        if count[e] > 2 and not twin_edge[e]:
            return True
    return False


def _cheapest_per_group(cu, cost, n):
    """Indices (k,) int64 of the ``TRIES`` cheapest candidates of every removed vertex, grouped
    by ``cu`` (c,) int64 in ``[0, n)``, each group by ``cost`` (c,) float64 with ties in
    encounter order (so the same bytes on every CPU)."""
    by_cost = np.argsort(cost, kind="stable")
    order = by_cost[group_order(cu[by_cost], n)]
    grouped = cu[order]
    group_start = np.flatnonzero(np.r_[True, grouped[1:] != grouped[:-1]])
    rank_in_u = np.arange(len(order)) - np.repeat(group_start, np.diff(np.r_[group_start, len(order)]))
    return order[rank_in_u < TRIES]


def twin_faces(faces: np.ndarray) -> np.ndarray:
    """(m,) bool: the faces of ``faces`` (m, 3) int64 that are doubled, a pair of faces on the same three
    vertices with opposite orientations and no third face on them (scans' reconstructions leave
    thousands: the VRIP dragons ~1,300 at 100k vertices).

    A collapse never deletes one (both would share their third vertex), and both move together
    when one of their vertices is removed, so the pairs found on the input stay pairs while alive.
    """
    return _twins(_reverse_pairs(faces))


def _twins(reverse: tuple) -> np.ndarray:
    """:func:`twin_faces` from ``reverse`` = :func:`_reverse_pairs` of the faces."""
    pairs, size = reverse
    return pairs & (size == 2)


def deferred_pillows(faces: np.ndarray, reverse: tuple | None = None) -> np.ndarray:
    """(m,) bool: the pillows of ``faces`` (m, 3) int64 (:func:`reverse_pairs`) that the encoder of payload
    version 2 keeps out of the simplification and sends in a face chunk after every split (spec
    bitstream.md §8.6): every pillow with a vertex that has a face outside the pillows.  Kept, they stay in the
    base with every vertex they touch.  A flap's tip (a vertex with pillow faces only) then has no
    face left: the face chunk brings it.  Only pillows apart from every other face stay: parts of their
    own, kept in the base like any small part (:func:`specks` sends those too small for the grid).
    ``reverse``: :func:`_reverse_pairs` of ``faces``, when the caller has it."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    twin = (_reverse_pairs(faces) if reverse is None else reverse)[0]
    if not twin.any():
        return twin
    return twin & _touch_others(faces, twin, int(faces.max()) + 1)


def _touch_others(faces: np.ndarray, chosen: np.ndarray, n: int) -> np.ndarray:
    """(m,) bool: the faces of ``faces`` (m, 3) int64 over ``n`` vertices with a vertex that some face
    outside ``chosen`` (m,) bool also names (compiled: two passes over the faces, no (m, 3) gather and
    ``any`` along its short axis)."""
    kernel = compiled(_touch_others_kernel)
    if kernel is not None:
        return kernel(np.ascontiguousarray(faces, np.int64), np.ascontiguousarray(chosen, np.bool_), n)
    elsewhere = np.zeros(n, bool)
    elsewhere[faces[~chosen].ravel()] = True
    return elsewhere[faces].any(axis=1)


def _touch_others_kernel(faces, chosen, n):
    """Compiled :func:`_touch_others`: the same (m,) bool."""
    elsewhere = np.zeros(n, np.bool_)
    for f in range(len(faces)):
        if not chosen[f]:
            elsewhere[faces[f, 0]] = True
            elsewhere[faces[f, 1]] = True
            elsewhere[faces[f, 2]] = True
    out = np.empty(len(faces), np.bool_)
    for f in range(len(faces)):
        out[f] = elsewhere[faces[f, 0]] | elsewhere[faces[f, 1]] | elsewhere[faces[f, 2]]
    return out


def specks(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: the faces of ``faces`` (m, 3) int64 on *specks*: parts of the mesh with three vertices
    that the grid ``positions`` (n, 3) int64 puts on one point (a triangle of a scan smaller than a grid
    step, alone or with its reverse or copies).  Kept, a speck is a face Draco's own order drops (its
    corners share one position), and the encoder falls back to Draco's sequential coder (the snowden bust
    at 14 bits: a 12.0 KB base instead of 3.7 KB); a face chunk sends them instead (bitstream.md §8.6: a
    face of new vertices only)."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    point = _point_faces(np.asarray(positions), faces)
    if not point.any():
        return point
    n = len(positions)
    point &= ~_touch_others(faces, point, n)
    # every vertex of a speck is named by faces on one vertex triple only (the faces left are few)
    triple = np.sort(faces[point], axis=1)
    key = np.unique(triple, axis=0, return_inverse=True)[1].reshape(-1)
    pairs = np.unique(np.stack([triple.ravel(), np.repeat(key, 3)], axis=1), axis=0)
    lone = np.bincount(pairs[:, 0], minlength=n) == 1
    point[np.flatnonzero(point)[~lone[triple].all(axis=1)]] = False
    return point


def _point_faces(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: the faces of ``faces`` (m, 3) int64 whose three corners have equal ``positions`` (n, 3)
    (compiled: no (m, 3, 3) gather)."""
    kernel = compiled(_point_faces_kernel)
    if kernel is not None:
        return kernel(positions, faces)
    p = positions[faces]
    return (p[:, 0] == p[:, 1]).all(axis=1) & (p[:, 1] == p[:, 2]).all(axis=1)


def _point_faces_kernel(positions, faces):
    """Compiled :func:`_point_faces`."""
    out = np.empty(len(faces), np.bool_)
    for f in range(len(faces)):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        same = True
        for k in range(3):
            same = same and positions[a, k] == positions[b, k] and positions[b, k] == positions[c, k]
        out[f] = same
    return out


def deferred_faces(positions: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: the faces of ``faces`` (m, 3) int64 that the encoder of payload version 2 keeps out of
    the simplification and sends in a face chunk after every split (spec bitstream.md §8.6):
    :func:`deferred_pillows` and :func:`specks` (``positions`` (n, 3) int64: grid values), unless that
    would be every face (the simplification needs a mesh)."""
    return deferred_and_twin_faces(positions, faces)[0]


def deferred_and_twin_faces(positions: np.ndarray, faces: np.ndarray) -> tuple:
    """``(late, twin)``, each (m,) bool: :func:`deferred_faces` and :func:`twin_faces` of ``faces`` (m, 3)
    int64 from one sort of the faces (:func:`_reverse_pairs`): the twins are what :func:`simplify` takes
    (``twin``) when nothing is deferred (the faces it gets are these)."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    reverse = _reverse_pairs(faces)
    late = deferred_pillows(faces, reverse) | specks(positions, faces)
    return (late if not late.all() else np.zeros(len(late), bool)), _twins(reverse)


def reverse_pairs(faces: np.ndarray) -> np.ndarray:
    """(m,) bool: faces of ``faces`` (m, 3) int64 paired with a face on the same three vertices facing the
    other way, as many pairs per vertex triple as its rarer orientation has faces (a pillow with a
    duplicate face beside it, or two pillows on one triple, as scans leave them: 169 triples of three
    faces on the 23k dragon besides its 868 lone pillows).  :func:`twin_faces` is the case of a triple
    with exactly these two faces."""
    return _reverse_pairs(faces)[0]


def _reverse_pairs(faces: np.ndarray) -> tuple:
    """``(pairs (m,) bool, size (m,) int64)``: :func:`reverse_pairs`, and the number of faces on each
    face's vertex triple.  One sort by (triple, orientation): a single packed int64 key while the
    vertex ids allow it (3x faster than ``lexsort``, which larger meshes use); compiled, one hash table
    of the packed triples instead (:func:`_reverse_pairs_kernel`)."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    m = len(faces)
    pairs, size = np.zeros(m, bool), np.ones(m, np.int64)
    if m < 2:
        return pairs, size
    n = int(faces.max()) + 1
    kernel = compiled(_reverse_pairs_kernel) if n < 1 << 20 else None
    if kernel is not None:
        return kernel(faces, n)
    rot = face_keys(faces)  # rotated to start at the smallest id
    flip = (rot[:, 1] > rot[:, 2]).astype(np.int64)
    lo, hi = np.minimum(rot[:, 1], rot[:, 2]), np.maximum(rot[:, 1], rot[:, 2])
    if n < 1 << 20:  # (triple, orientation) in one int64
        packed = ((rot[:, 0] * n + lo) * n + hi) * 2 + flip
        order = np.argsort(packed, kind="stable")
        triple = packed[order] >> 1
        new_triple = np.r_[True, triple[1:] != triple[:-1]]
    else:
        order = np.lexsort((flip, hi, lo, rot[:, 0]))
        k = np.stack([rot[:, 0], lo, hi], 1)[order]
        new_triple = np.r_[True, np.any(k[1:] != k[:-1], axis=1)]
    f = flip[order]
    new_side = new_triple | np.r_[True, f[1:] != f[:-1]]
    group = np.cumsum(new_triple) - 1
    side_start = np.flatnonzero(new_side)
    rank = np.arange(m) - side_start[np.cumsum(new_side) - 1]  # place within (triple, orientation)
    ones = np.bincount(group, weights=f).astype(np.int64)
    count = np.bincount(group)
    pairs[order[rank < np.minimum(ones, count - ones)[group]]] = True
    size[order] = count[group]
    return pairs, size


def _reverse_pairs_kernel(faces, n):
    """Compiled :func:`_reverse_pairs` for vertex ids below 2^20: each face's triple (rotated to its smallest
    id, as :func:`~.topology.face_keys`; the other two ascending) packed into one int64 and counted in an
    open-addressing table (a power of two, at least twice the faces); a face's place among the faces of its
    triple and orientation is the count of those before it (the sort's order: stable)."""
    m = len(faces)
    bits = 1
    while (1 << bits) < 2 * m:
        bits += 1
    size_t = 1 << bits
    keys = np.empty(size_t, np.int64)
    count = np.zeros(size_t, np.int32)  # faces on the triple (0: an empty slot)
    ones = np.zeros(size_t, np.int32)  # of them, flipped
    slot = np.empty(m, np.int64)
    place = np.empty(m, np.int64)
    flips = np.empty(m, np.bool_)
    shift = np.uint64(64 - bits)
    for f in range(m):
        a, b, c = faces[f, 0], faces[f, 1], faces[f, 2]
        if b < a and b <= c:  # np.argmin: the first smallest
            a, b, c = b, c, a
        elif c < a and c < b:
            a, b, c = c, a, b
        flip = b > c
        key = (a * n + min(b, c)) * n + max(b, c)
        j = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> shift)
        while count[j] > 0 and keys[j] != key:
            j = (j + 1) & (size_t - 1)
        keys[j] = key
        place[f] = ones[j] if flip else count[j] - ones[j]
        count[j] += 1
        ones[j] += flip
        slot[f] = j
        flips[f] = flip
    pairs = np.zeros(m, np.bool_)
    size = np.empty(m, np.int64)
    for f in range(m):
        j = slot[f]
        pairs[f] = place[f] < min(ones[j], count[j] - ones[j])
        size[f] = count[j]
    return pairs, size


def _twin_counts(et, Ft, n):
    """``(twin_edge (e,) bool, extra (n,) int64)`` of the local mesh (edge table ``et``) whose doubled faces
    are ``Ft`` (t, 3) int64 (local ids, in face order; None: none).  A doubled pair is a closed two-face "pillow" on the surface: glued onto it
    along its three edges, or a flap glued along one edge whose third vertex (its tip) has no other
    face.  ``twin_edge`` marks the edges of exactly one pillow whose other faces are two (the
    surface's) or none (a flap's free edges): the edges a pillow makes non-manifold, or adds.
    ``extra`` counts, on each vertex, its pillow faces minus its pillows' free edges: a vertex
    whose other faces are a disk has ``extra`` more faces than edges."""
    twin_edge = np.zeros(len(et.keys), bool)
    if Ft is None or not len(Ft):
        return twin_edge, np.zeros(n, np.int64)
    kernel = compiled(_twin_counts_kernel)
    if kernel is not None:
        return kernel(Ft, et.keys, et.lo, et.hi, et.count, n)
    ids = np.concatenate([et.find(Ft[:, j], Ft[:, (j + 1) % 3]) for j in range(3)])
    on_edge = np.bincount(ids, minlength=len(et.keys))
    free = (on_edge == 2) & (et.count == 2)
    twin_edge = (on_edge == 2) & ((et.count == 4) | free)
    po = np.bincount(np.concatenate([et.lo[free], et.hi[free]]), minlength=n)
    return twin_edge, np.bincount(Ft.ravel(), minlength=n) - po


def _twin_counts_kernel(Ft, keys, lo, hi, count, n):
    """Compiled :func:`_twin_counts` (the same two arrays) in two passes over the doubled faces ``Ft`` (t, 3)
    int64, their edges found by a binary search of the edge table's sorted ``keys`` (e,): the doubled faces on
    each edge (int8, counted up to 3: only two matters; only their edges' entries set) and the corners on each
    vertex, then each edge with two of them once."""
    on_edge = np.empty(len(keys), np.int8)
    for f in range(len(Ft)):
        for j in range(3):
            a, b = Ft[f, j], Ft[f, (j + 1) % 3]
            on_edge[np.searchsorted(keys, min(a, b) * n + max(a, b))] = 0
    extra = np.zeros(n, np.int64)
    for f in range(len(Ft)):
        for j in range(3):
            a, b = Ft[f, j], Ft[f, (j + 1) % 3]
            e = np.searchsorted(keys, min(a, b) * n + max(a, b))
            on_edge[e] = min(on_edge[e] + 1, 3)
            extra[a] += 1
    twin_edge = np.zeros(len(keys), np.bool_)
    for f in range(len(Ft)):
        for j in range(3):
            a, b = Ft[f, j], Ft[f, (j + 1) % 3]
            e = np.searchsorted(keys, min(a, b) * n + max(a, b))
            if on_edge[e] == 2:
                on_edge[e] = -1  # counted once
                twin_edge[e] = count[e] == 4 or count[e] == 2
                if count[e] == 2:  # a flap's free edge
                    extra[lo[e]] -= 1
                    extra[hi[e]] -= 1
    return twin_edge, extra


def _usable(F, et, src, frozen_ext, twins, n):
    """Directed collapses ``u -> v`` worth costing: ``(cu, cv, ce)`` (c,) int64 each.

    Every edge of the edge table ``et`` both ways (all ``lo -> hi`` first, then ``hi -> lo``), minus
    edges that are non-manifold or inconsistently oriented, minus removed vertices that are frozen
    (not one disk or half-disk of faces, on such an edge, or in ``frozen_ext`` (n,) bool), minus
    boundary vertices moving along an interior edge.  An interior vertex whose faces are a disk plus
    the doubled twins of some of them (``twins``, :func:`_twin_counts`) counts as a disk.  F (m, 3)
    int64, src (3m,) int64.
    """
    ne = len(et.keys)
    # orientation: the two half-edges of an interior edge must run opposite ways
    two = et.count == 2
    same_dir = np.zeros(ne, bool)
    same_dir[two] = src[et.he0[two]] == src[et.he1[two]]
    bad_edge = (et.count > 2) | same_dir
    boundary_edge = et.count == 1
    twin_edge, extra = twins

    fcount = np.bincount(F.ravel(), minlength=n)
    ends = np.concatenate([et.lo, et.hi])
    evc = np.bincount(ends, minlength=n)
    bvc = np.bincount(ends, weights=np.tile(boundary_edge, 2), minlength=n).astype(np.int64)
    badv = np.bincount(ends, weights=np.tile(bad_edge & ~twin_edge, 2), minlength=n) > 0
    manifold = (((bvc == 0) & (evc == fcount - extra)) |
                ((bvc == 2) & (extra == 0) & (evc == fcount + 1)))
    frozen = ~manifold | badv | frozen_ext
    on_boundary = bvc > 0

    cu = np.concatenate([et.lo, et.hi])
    cv = np.concatenate([et.hi, et.lo])
    ce = np.concatenate([np.arange(ne), np.arange(ne)])
    keep = np.tile(~bad_edge, 2) & ~frozen[cu] & (~on_boundary[cu] | boundary_edge[ce])
    return cu[keep], cv[keep], ce[keep]


def _deleted_faces(et, src, opp, cu, ce):
    """Faces deleted by collapses ``cu`` on edges ``ce`` and their third vertices (local ids).

    Returns ``(del_left, wing_left, del_right, wing_right)``, each (k,) int64, -1 for none:
    the left face holds the directed edge u->v, the right one v->u.
    """
    def side(he_col):
        he = np.where(he_col >= 0, he_col, 0)
        face = np.where(he_col >= 0, he // 3, -1)
        forward = (src[he] == cu) & (he_col >= 0)
        return face, forward, np.where(he_col >= 0, opp[he], -1)

    f0, fw0, w0 = side(et.he0[ce])
    f1, fw1, w1 = side(et.he1[ce])
    del_left = np.where(fw0, f0, np.where(fw1, f1, -1))
    wing_left = np.where(fw0, w0, np.where(fw1, w1, -1))
    rev0 = (f0 >= 0) & ~fw0
    rev1 = (f1 >= 0) & ~fw1
    del_right = np.where(rev0, f0, np.where(rev1, f1, -1))
    wing_right = np.where(rev0, w0, np.where(rev1, w1, -1))
    return del_left, wing_left, del_right, wing_right


def _moved_faces(vf, F, cu, cv):
    """Faces of each ``cu`` that do not hold its ``cv``: ``(faces (j,) int64, collapse index (j,) int64)``."""
    vf_start, vf_face = vf
    kernel = compiled(_moved_faces_kernel)
    if kernel is not None:
        return kernel(vf_start, vf_face, F, cu, cv)
    owner, p = expand(vf_start, cu)
    face = vf_face[p]
    has_v = (F[face] == cv[owner][:, None]).any(axis=1)
    return face[~has_v], owner[~has_v]


def _moved_faces_kernel(vf_start, vf_face, F, cu, cv):
    """Compiled :func:`_moved_faces`: the same two (j,) int64 arrays (every face written, kept by advancing
    the count or not: which of ``u``'s faces hold ``v`` is no branch to predict)."""
    total = 0
    for i in range(len(cu)):
        total += vf_start[cu[i] + 1] - vf_start[cu[i]]
    face = np.empty(total, np.int64)
    owner = np.empty(total, np.int64)
    k = 0
    for i in range(len(cu)):
        v = cv[i]
        for p in range(vf_start[cu[i]], vf_start[cu[i] + 1]):
            f = vf_face[p]
            face[k] = f
            owner[k] = i
            k += (F[f, 0] != v) & (F[f, 1] != v) & (F[f, 2] != v)
    return face[:k], owner[:k]


def _legal(cu, cv, ce, mesh):
    """Boolean mask (k,) of candidate collapses ``cu -> cv`` on edge ``ce`` that are legal
    (``mesh`` as in :func:`_ordinary_winners`)."""
    et, F, P, opp, fcount, vv, vf, vv_edge, twin_edge = mesh
    kernel = compiled(_legal_kernel)
    if kernel is not None:
        return kernel(cu, cv, ce, vv_edge, et.count, et.he0, et.he1, F, P, opp, fcount, vv[0], vv[1],
                      vf[0], vf[1], _fin_vertices(et, len(P)), twin_edge)
    k = len(cu)
    ok = np.ones(k, dtype=bool)

    # link condition: |N(u) ∩ N(v)| == faces on uv
    vv_start, vv_nbr = vv
    owner, p = expand(vv_start, cu)
    x = vv_nbr[p]
    common = np.bincount(owner, weights=(et.find(cv[owner], x) >= 0), minlength=k)
    ok &= common == et.count[ce]

    # each deleted face's other edge at u must be interior (or a pillow's, glued), its third vertex keep a face
    for he_col in (et.he0[ce], et.he1[ce]):
        has = he_col >= 0
        he = np.where(has, he_col, 0)
        w = opp[he]
        e_uw = et.find(cu, w)
        e_ = np.maximum(e_uw, 0)
        interior = (e_uw >= 0) & ((et.count[e_] == 2) | (twin_edge[e_] & (et.count[e_] == 4)))
        ok &= ~has | (interior & (fcount[w] >= 2))
    ok &= fcount[cu] > et.count[ce]
    two = et.he1[ce] >= 0  # a doubled face on uv: both deleted faces share their third vertex
    ok &= ~two | (opp[et.he0[ce]] != opp[np.maximum(et.he1[ce], 0)])

    # moved faces: no flip, no degenerate result, no duplicate; a face with no area on the grid
    # already may stay so, or must face the way u's faces do (their normals summed)
    vf_start, vf_face = vf
    owner, p = expand(vf_start, cu)
    face = vf_face[p]
    tri = F[face]
    n_all = _normals(P, tri)
    u_o = cu[owner]
    v_o = cv[owner]
    has_v = (tri == v_o[:, None]).any(axis=1)
    sel = ~has_v
    vertex_normal = np.stack([np.bincount(owner, weights=n_all[:, j], minlength=k) for j in range(3)], 1)
    owner, tri, u_o, v_o, n0 = owner[sel], tri[sel], u_o[sel], v_o[sel], n_all[sel]
    new = np.where(tri == u_o[:, None], v_o[:, None], tri)
    n1 = _normals(P, new)
    l1 = np.linalg.norm(n1, axis=1)
    flat = ~(np.linalg.norm(n0, axis=1) > 0)
    n0[flat] = vertex_normal[owner[flat]]
    dot = np.einsum("ij,ij->i", n0, n1)
    l0 = np.linalg.norm(n0, axis=1)
    good = ((l1 > 0) & (dot > MIN_NORMAL_COS * l0 * l1)) | (flat & ~(l1 > 0))
    # duplicate: the edge opposite u in the moved face already has a face with apex v
    col = np.argmax(tri == u_o[:, None], axis=1)
    xa = np.take_along_axis(tri, ((col + 1) % 3)[:, None], 1)[:, 0]
    xb = np.take_along_axis(tri, ((col + 2) % 3)[:, None], 1)[:, 0]
    e = et.find(xa, xb)
    e_ = np.maximum(e, 0)
    o0 = opp[et.he0[e_]]
    o1 = np.where(et.he1[e_] >= 0, opp[np.maximum(et.he1[e_], 0)], -1)
    many = (e >= 0) & (et.count[e_] > 2)  # not all its faces are in the edge table: search xa's faces
    dup = (e >= 0) & ~many & ((o0 == v_o) | (o1 == v_o))
    for r in np.flatnonzero(many):
        faces_a = F[vf_face[vf_start[xa[r]]:vf_start[xa[r] + 1]]]
        dup[r] = bool(np.any((faces_a == xb[r]).any(axis=1) & (faces_a == v_o[r]).any(axis=1)))
    good &= ~dup
    bad_count = np.bincount(owner, weights=~good, minlength=k)
    ok &= bad_count == 0
    return ok


@kernel_helper
def _edge_id(vv_start, vv_nbr, vv_edge, a, b):
    """Edge id of the pair (a, b) (-1: none), found in ``a``'s row of the vertex -> neighbours CSR
    (``vv_edge``: edge id of every entry); for the kernels."""
    for p in range(vv_start[a], vv_start[a + 1]):
        if vv_nbr[p] == b:
            return vv_edge[p]
    return -1


@kernel_helper(allocates=True)
def _legal_kernel(cu, cv, ce, vv_edge, count, he0, he1, F, P, opp, fcount, vv_start, vv_nbr, vf_start, vf_face, fin,
                  twin_edge):
    """Compiled :func:`_legal`: the same (k,) bool mask, test for test (see there); ``fin`` (n,) bool
    marks the vertices on an edge with more than two faces (:func:`_fin_vertices`), ``twin_edge`` (e,)
    bool the pillows' edges (:func:`_twin_counts`)."""
    return _legal_marked(cu, cv, ce, vv_edge, count, he0, he1, F, P, opp, fcount, vv_start, vv_nbr, vf_start, vf_face,
                         fin, twin_edge, np.full(len(fcount), -1, np.int64), np.int64(0))


@kernel_helper(allocates=True)
def _legal_marked(cu, cv, ce, vv_edge, count, he0, he1, F, P, opp, fcount, vv_start, vv_nbr, vf_start, vf_face, fin,
                  twin_edge, mark, token):
    """:func:`_legal_kernel` with its scratch ``mark`` (n,) int64 given: ``mark[x] == token + j`` marks ``x`` a
    neighbour of candidate j's kept vertex, so a caller testing several sets of candidates (a selection's
    rounds) fills it once, each set with ``token`` past the marks of the sets before (all below it)."""
    ok = np.ones(len(cu), np.bool_)
    for j in range(len(cu)):
        i = token + j
        if j % LEGAL_CHUNK == 0 and _touch(cu, cv, ce, j, min(j + LEGAL_CHUNK, len(cu)), count, he0, he1, opp, fcount,
                                           vv_start, vv_nbr, vv_edge, vf_start, vf_face, F, P) < 0:
            ok[j] = not ok[j]  # never (counts and ids are not negative): the loads must not be dropped
        u, v, e = cu[j], cv[j], ce[j]
        for p in range(vv_start[v], vv_start[v + 1]):
            mark[vv_nbr[p]] = i
        common = 0  # link condition
        for p in range(vv_start[u], vv_start[u + 1]):
            if mark[vv_nbr[p]] == i:
                common += 1
        if common != count[e] or fcount[u] <= count[e]:
            ok[j] = False
            continue
        if he1[e] >= 0 and opp[he0[e]] == opp[he1[e]]:  # a doubled face on uv
            ok[j] = False
            continue
        for he in (he0[e], he1[e]):  # deleted faces: other edge at u interior, wing keeps a face
            if he >= 0:
                w = opp[he]
                e_uw = _edge_id(vv_start, vv_nbr, vv_edge, u, w)
                if e_uw < 0 or not (count[e_uw] == 2 or (twin_edge[e_uw] and count[e_uw] == 4)) or fcount[w] < 2:
                    ok[j] = False
        if ok[j]:
            ok[j] = _moved_faces_ok(u, v, (vv_start, vv_nbr, vv_edge), count, he0, he1, F, P, opp, vf_start, vf_face,
                                    mark, i, fin)
    return ok


#: :func:`_legal_kernel` reads the rows of this many candidates ahead (:func:`_touch`).
LEGAL_CHUNK = 16


@kernel_helper
def _touch(cu, cv, ce, i0, i1, count, he0, he1, opp, fcount, vv_start, vv_nbr, vv_edge, vf_start, vf_face, F, P):
    """Read what the legality tests of candidates ``i0 .. i1 - 1`` will read first (their edge, its
    deleted faces' third vertices and their face counts, their vertices' rows, the faces of the removed
    vertex and their corners' positions) in one loop with no branch on the values, so that the cache
    misses of the chunk overlap instead of coming one test at a time (the candidates are scattered over
    the mesh: the winners of a selection round).  Returns a sum of the counts and ids it read (never
    negative), which the caller tests so that the loads stay.  (The second deleted face and the removed
    vertex's neighbours, read here too, made the selection 0.91-0.94x as long.)"""
    acc = 0
    for i in range(i0, i1):
        u, v, e = cu[i], cv[i], ce[i]
        acc += count[e] + fcount[opp[he0[e]]] + fcount[opp[max(he1[e], 0)]] + fcount[u] + vv_nbr[vv_start[v]] \
            + vv_edge[vv_start[u]] + vv_nbr[vv_start[u]]
        for p in range(vf_start[u], vf_start[u + 1]):
            f = vf_face[p]
            acc += (P[F[f, 0], 0] > 0.0) + (P[F[f, 1], 0] > 0.0) + (P[F[f, 2], 0] > 0.0)
    return acc


@kernel_helper
def _moved_faces_ok(u, v, vv, count, he0, he1, F, P, opp, vf_start, vf_face, mark, i, fin):
    """Kernel part of :func:`_legal`: no moved face of ``u -> v`` flips, degenerates or duplicates.

    ``mark[x] == i`` for the neighbours ``x`` of ``v``: a face on the edge ``xa xb`` opposite ``u``
    with apex ``v`` needs both ends next to ``v``, and an edge with more than two faces has its ends
    in ``fin``; other edges are not looked up (the same answer, fewer memory reads)."""
    for p in range(vf_start[u], vf_start[u + 1]):
        f = vf_face[p]
        t0, t1, t2 = F[f, 0], F[f, 1], F[f, 2]
        if t0 == v or t1 == v or t2 == v:
            continue
        col = 0 if t0 == u else (1 if t1 == u else 2)
        xa = F[f, (col + 1) % 3]
        xb = F[f, (col + 2) % 3]
        n0x, n0y, n0z = _face_normal(P, t0, t1, t2)  # before
        n1x, n1y, n1z = _face_normal(P, (v if t0 == u else t0), (v if t1 == u else t1), (v if t2 == u else t2))
        l0 = np.sqrt(n0x * n0x + n0y * n0y + n0z * n0z)
        l1 = np.sqrt(n1x * n1x + n1y * n1y + n1z * n1z)
        flat = not l0 > 0  # no area on the grid already: it may stay so, or face the way u's faces do
        if flat:
            n0x, n0y, n0z = _vertex_normal(u, F, P, vf_start, vf_face)
            l0 = np.sqrt(n0x * n0x + n0y * n0y + n0z * n0z)
        dot = n0x * n1x + n0y * n1y + n0z * n1z
        if not ((l1 > 0 and dot > MIN_NORMAL_COS * l0 * l1) or (flat and not l1 > 0)):
            return False
        if not fin[xa] and (mark[xa] != i or mark[xb] != i):
            continue
        e = _edge_id(vv[0], vv[1], vv[2], xa, xb)  # duplicate: the edge opposite u already has apex v
        if e >= 0:
            if count[e] > 2:  # not all its faces are in the edge table: search xa's faces
                if _has_face(xa, xb, v, F, vf_start, vf_face):
                    return False
            elif opp[he0[e]] == v or (he1[e] >= 0 and opp[he1[e]] == v):
                return False
    return True


@kernel_helper
def _has_face(a, b, c, F, vf_start, vf_face):
    """Whether a face of ``a`` (its row of the vertex -> faces CSR) also holds ``b`` and ``c``."""
    for p in range(vf_start[a], vf_start[a + 1]):
        f = vf_face[p]
        hb = F[f, 0] == b or F[f, 1] == b or F[f, 2] == b
        hc = F[f, 0] == c or F[f, 1] == c or F[f, 2] == c
        if hb and hc:
            return True
    return False


@kernel_helper
def _face_normal(P, x, y, z):
    """The unnormalised normal of the face ``(x, y, z)`` of positions ``P`` (n, 3): ``np.cross(P[y] - P[x],
    P[z] - P[x])``, in np.cross's order of operations (the same bits as :func:`_normals`)."""
    a0, a1, a2 = P[x, 0], P[x, 1], P[x, 2]
    b0, b1, b2 = P[y, 0] - a0, P[y, 1] - a1, P[y, 2] - a2
    c0, c1, c2 = P[z, 0] - a0, P[z, 1] - a1, P[z, 2] - a2
    return b1 * c2 - b2 * c1, b2 * c0 - b0 * c2, b0 * c1 - b1 * c0


@kernel_helper
def _vertex_normal(u, F, P, vf_start, vf_face):
    """Sum of the normals (:func:`_face_normal`) of ``u``'s faces, in face-list order."""
    rx, ry, rz = 0.0, 0.0, 0.0
    for p in range(vf_start[u], vf_start[u + 1]):
        f = vf_face[p]
        nx, ny, nz = _face_normal(P, F[f, 0], F[f, 1], F[f, 2])
        rx += nx
        ry += ny
        rz += nz
    return rx, ry, rz


def _normals(P, tri):
    a, b, c = P[tri[:, 0]], P[tri[:, 1]], P[tri[:, 2]]
    return np.cross(b - a, c - a)


def _select(cu, cv, cost, legal, vv, n, rounds: int = ROUNDS):
    """Indices of a set of legal collapses that a decoder can undo as one batch.

    The rule (see the module docstring): no two removed vertices are adjacent, no
    two collapses share their kept vertex, and no kept vertex is a neighbour of
    another collapse's removed vertex.  ``cu`` (c,) is grouped by vertex, cheapest
    candidate first.  Each round every vertex still in play offers its current
    candidate; an offer wins when its cost rank is the lowest among its neighbours'
    offers.  Winners that break the rule against each other or against collapses
    already chosen give way to the lower rank; only the survivors are tested with
    ``legal`` (the expensive part).  Chosen collapses block their neighbours;
    winners that lost a conflict or are illegal fall back to their next candidate.
    """
    c = len(cu)
    rank = _offer_ranks(cu, cost)
    big = np.int64(c + 1)
    starts = _group_starts(cu)
    ends = np.r_[starts[1:], c]
    front = starts.copy()  # current candidate of every vertex group
    in_play = np.ones(len(starts), dtype=bool)
    vv_start, vv_nbr = vv

    chosen_u = np.zeros(n, dtype=bool)
    chosen_v = np.zeros(n, dtype=bool)
    blocked = np.zeros(n, dtype=bool)
    chosen = []
    for _ in range(rounds):
        groups = np.flatnonzero(in_play)
        if len(groups) == 0:
            break
        offer = front[groups]
        vr = np.full(n, big, dtype=np.int64)
        vr[cu[offer]] = rank[offer]
        won = _neighbour_min(vv, vr, cu[offer], big) > rank[offer]  # no neighbour offers a lower rank
        if not won.any():
            break
        wg, wo = groups[won], offer[won]
        loses = _conflicts(cu[wo], cv[wo], rank[wo], chosen_u, chosen_v, vv, big)
        keep = ~loses
        ok = np.zeros(len(wo), dtype=bool)
        if keep.any():
            ok[keep] = legal(wo[keep])
        good = wo[ok]
        chosen.append(good)
        # illegal or conflicting winners try their next candidate (or leave play)
        bad = wg[~ok]
        front[bad] += 1
        in_play[bad[front[bad] >= ends[bad]]] = False
        # chosen collapses: their removed vertices block their neighbours
        chosen_u[cu[good]] = True
        chosen_v[cv[good]] = True
        _, pos = expand(vv_start, cu[good])
        blocked[vv_nbr[pos]] = True
        blocked[cu[good]] = True
        blocked[cv[good]] = True
        in_play &= ~blocked[cu[starts]]
    return np.concatenate(chosen) if chosen else np.zeros(0, dtype=np.int64)


def _select_kernel(cu, cv, ce, rank, vv_start, vv_nbr, n, rounds, mesh):
    """Compiled :func:`_select`: the same winners in the same order (round by round, group order).

    ``rank`` (c,) int64 is :func:`_offer_ranks`; ``mesh`` the tuple of :func:`_legal_kernel`'s mesh
    arguments.  (``_conflicts``' same-kept-vertex rule is implied by its kept-vertex-next-to-a-
    lower-ranked-removed-vertex rule, since every winner's removed vertex neighbours its kept one.)
    The groups still in play are kept as a list, ascending, compacted after every round (a round
    visits them only, not every group).  That list and the round's winners are written entry by
    entry, each kept by advancing a count or not (no branch on who wins or stays in play: 0.94x the
    time).  Round ``r``'s offers are written as ``rank + (rounds - 1 - r) * big``: an offer left from
    an earlier round is above every limit of a later one, so the offers are never reset (a pass over
    the groups in play per round less).
    """
    vv_edge, count, he0, he1, F, P, opp, fcount, vf_start, vf_face, fin, twin_edge = mesh
    big = len(cu) + 1
    starts = _group_starts_kernel(cu)  # one pass (flatnonzero of a concatenation took three and four arrays)
    ends = np.empty(len(starts), np.int64)
    for g in range(len(starts)):
        ends[g] = starts[g + 1] if g + 1 < len(starts) else len(cu)
    front = starts.copy()
    play = np.arange(len(starts))  # groups in play, ascending: the first ``live`` entries
    live = len(starts)
    flags = np.zeros((3, n), np.bool_)  # chosen removed, chosen kept, blocked
    offer = np.full(n, rounds * big, np.int64)  # each round's offers, never reset (see ``above``)
    scratch = np.full((2, n), big, np.int64)  # winners' ranks at u, at v (reset after use)
    wg = np.empty(len(starts), np.int64)  # this round's winning groups and their offers
    wo = np.empty(len(starts), np.int64)
    mark = np.full(n, -1, np.int64)  # the legality tests' scratch (:func:`_legal_marked`), filled once
    tested = 0
    out = np.empty(len(cu), np.int64)
    n_out = 0
    for r in range(rounds):
        if live == 0:
            break
        above = (rounds - 1 - r) * big  # this round's offers: rank + above, below every earlier round's
        for j in range(live):
            o = front[play[j]]
            offer[cu[o]] = rank[o] + above
        w = 0
        for j in range(live):
            g = play[j]
            o = front[g]
            if j + 16 < live:  # the rows ahead: their starts 16 groups ahead, their first entries 8 ahead
                topology.prefetch(vv_start, cu[starts[play[j + 16]]])
                topology.prefetch(vv_nbr, vv_start[cu[starts[play[j + 8]]]])
            wg[w], wo[w] = g, o
            w += not _nbr_below(vv_start, vv_nbr, offer, cu[o], rank[o] + 1 + above)
        if w == 0:
            break
        wu, wv = cu[wo[:w]], cv[wo[:w]]
        keep = ~_round_conflicts(wu, wv, rank[wo[:w]], flags, scratch, vv_start, vv_nbr, big, n_out > 0)
        ok = np.zeros(w, np.bool_)
        idx = wo[:w][keep]
        ok[keep] = _legal_marked(cu[idx], cv[idx], ce[idx], vv_edge, count, he0, he1, F, P, opp, fcount,
                                 vv_start, vv_nbr, vf_start, vf_face, fin, twin_edge, mark, tested)
        tested += len(idx)
        for j in range(w):
            g, o = wg[j], wo[j]
            if ok[j]:
                out[n_out] = o
                n_out += 1
                flags[0, cu[o]] = flags[1, cv[o]] = True
                for p in range(vv_start[cu[o]], vv_start[cu[o] + 1]):
                    flags[2, vv_nbr[p]] = True
                flags[2, cu[o]] = flags[2, cv[o]] = True
            else:
                front[g] += 1
        kept = 0  # out of play: no candidate left, or the group's vertex blocked
        for j in range(live):
            g = play[j]
            play[kept] = g
            kept += (front[g] < ends[g]) & (not flags[2, cu[starts[g]]])
        live = kept
    return out[:n_out]


@kernel_helper
def _nbr_flagged(vv_start, vv_nbr, flags, row):
    """Whether a neighbour ``x`` of ``row`` has ``flags[x]`` (stops at the first)."""
    for p in range(vv_start[row], vv_start[row + 1]):
        if flags[vv_nbr[p]]:
            return True
    return False


@kernel_helper
def _nbr_below(vv_start, vv_nbr, values, row, limit):
    """Whether a neighbour ``x`` of ``row`` has ``values[x] < limit`` (the smallest of them ``< limit``,
    found without scanning the whole row once one is)."""
    for p in range(vv_start[row], vv_start[row + 1]):
        if values[vv_nbr[p]] < limit:
            return True
    return False


@kernel_helper(allocates=True)
def _round_conflicts(u, v, r, flags, scratch, vv_start, vv_nbr, big, any_chosen=True):
    """Kernel part of :func:`_select_kernel`: :func:`_conflicts` of one round's winners (w,) -> (w,) bool.
    ``any_chosen``: False when no collapse is chosen yet (``flags`` all False), which skips the rows'
    scans against the chosen ones; each scan stops at the first conflict it finds.  ``scratch`` (2, n) int64:
    ``big`` on entry and on return (the winners' ranks at their u, at their v, while the round is tested)."""
    loses = np.zeros(len(u), np.bool_)
    for i in range(len(u)):
        if any_chosen:
            loses[i] = flags[1, v[i]] or flags[0, v[i]] or _nbr_flagged(vv_start, vv_nbr, flags[1], u[i]) \
                or _nbr_flagged(vv_start, vv_nbr, flags[0], v[i])
        scratch[0, u[i]] = r[i]
        scratch[1, v[i]] = min(scratch[1, v[i]], r[i])
    for i in range(len(u)):
        loses[i] = loses[i] or _nbr_below(vv_start, vv_nbr, scratch[0], v[i], r[i]) \
            or _nbr_below(vv_start, vv_nbr, scratch[1], u[i], r[i])
    for i in range(len(u)):
        scratch[0, u[i]] = big
        scratch[1, v[i]] = big
    return loses


#: The cost bucket of a NaN or infinite cost: past every finite one (|2 log2 x| < 2,200 for any finite
#: double above 1e-12).
_LAST_BUCKET = 4096.0


def _offer_ranks(cu, cost):
    """(c,) int64 rank of every candidate: by cost bucket, ties in a fixed pseudo-random order.

    Rank by cost only to within a factor of ~1.4: ties inside a bucket are broken by a
    fixed pseudo-random order (seeded by the candidate count), otherwise smooth cost fields
    (flat CAD regions, all zero) let only a few local minima win each round.
    """
    c = len(cu)
    # the bucket floor(2 log2(cost + 1e-12 + 1e-9 max)); compiled, all but numpy's log2 in two kernels (a pass
    # each, not eight; their arithmetic is numpy's, rounding for rounding), the second drawing the tie order
    # itself (:func:`.pcg64.permutation`, numpy's draws)
    kernel = compiled(_ranks_kernel)
    if kernel is not None:
        y = compiled(_log_argument_kernel)(cost)
        np.log2(y, out=y)
        return kernel(y)
    shuffle = np.random.default_rng(c).permutation(c)
    # in place: the same values without four (c,) temporaries; a cost rounded below zero counts as zero (its log2
    # was NaN, which a cast made x86's smallest integer and the compiled ranking then asked for a counting array
    # of 2**63 entries)
    y = np.maximum(cost, 0.0)
    y += 1e-12
    y += 1e-9 * float(np.max(cost, where=np.isfinite(cost), initial=0.0))  # a NaN or inf cost moves no other
    np.log2(y, out=y)
    y *= 2.0
    np.floor(y, out=y)
    y[~np.isfinite(y)] = _LAST_BUCKET  # a NaN or infinite cost ranks last, alike on every CPU (a cast of NaN is not)
    bucket = y.astype(np.int64)
    bucket -= bucket.min(initial=0)
    # argsort(bucket * c + shuffle) without a sort of c keys: candidates in shuffle order,
    # then grouped by bucket (few distinct values) stably
    by_shuffle = np.empty(c, dtype=np.int64)
    by_shuffle[shuffle] = np.arange(c)
    order = by_shuffle[group_order(bucket[by_shuffle], int(bucket.max(initial=0)) + 1)]
    rank = np.empty(c, dtype=np.int64)
    rank[order] = np.arange(c)
    return rank


def _log_argument_kernel(cost):
    """Compiled start of :func:`_offer_ranks`: (c,) float64 ``np.maximum(cost, 0.0) + 1e-12 + 1e-9 * m``
    of ``cost`` (c,) float64, m the largest finite cost or 0.0, added in that order."""
    top = 0.0
    for i in range(len(cost)):
        x = cost[i]
        if x > top and x - x == 0.0:  # finite
            top = x
    shift = 1e-9 * top
    y = np.empty(len(cost), np.float64)
    for i in range(len(cost)):
        x = cost[i]
        y[i] = ((x if (x >= 0.0 or x != x) else 0.0) + 1e-12) + shift  # np.maximum's choice (NaN kept)
    return y


def _ranks_kernel(y):
    """Compiled end of :func:`_offer_ranks`: the (c,) int64 ranks of the candidates with ``y`` (c,) float64
    the log2 of :func:`_log_argument_kernel` (turned into the cost buckets in place) and the tie order
    ``default_rng(c).permutation(c)`` (:func:`.pcg64.permutation`): one counting pass over the buckets, then
    the candidates ranked in shuffle order within their bucket."""
    c = len(y)
    shuffle = pcg64.permutation(c, c)
    bucket = y.view(np.int64)
    low = 0
    for i in range(c):
        b = np.floor(y[i] * 2.0)
        bucket[i] = np.int64(b) if b - b == 0.0 else np.int64(_LAST_BUCKET)  # NaN or inf: last
        low = min(low, bucket[i])
    high = 0
    for i in range(c):
        bucket[i] -= low
        high = max(high, bucket[i])
    start = np.zeros(high + 2, np.int64)
    for i in range(c):
        start[bucket[i] + 1] += 1
    for b in range(high + 1):
        start[b + 1] += start[b]
    by_shuffle = np.empty(c, np.int64)
    for j in range(c):
        by_shuffle[shuffle[j]] = j
    rank = np.empty(c, np.int64)
    for i in range(c):
        x = by_shuffle[i]
        rank[x] = start[bucket[x]]
        start[bucket[x]] += 1
    return rank


def _neighbour_min(vv, values, rows, big):
    """(len(rows),) the smallest ``values`` among each row's neighbours (``big`` for none)."""
    vv_start, vv_nbr = vv
    kernel = compiled(_neighbour_min_kernel)
    if kernel is not None:
        return kernel(vv_start, vv_nbr, np.asarray(values, np.int64), np.asarray(rows, np.int64), big)
    owner, pos = expand(vv_start, rows)
    out = np.full(len(rows), big, dtype=np.int64)
    if len(pos):
        np.minimum.at(out, owner, values[vv_nbr[pos]])
    return out


def _neighbour_min_kernel(vv_start, vv_nbr, values, rows, big):
    """Compiled :func:`_neighbour_min`: the same (len(rows),) int64 minima."""
    out = np.full(len(rows), big, np.int64)
    for i in range(len(rows)):
        r = rows[i]
        best = big
        for p in range(vv_start[r], vv_start[r + 1]):
            x = values[vv_nbr[p]]
            if x < best:
                best = x
        out[i] = best
    return out


def _neighbour_any(vv, flags, rows):
    """(len(rows),) whether any neighbour of each row is flagged."""
    vv_start, vv_nbr = vv
    kernel = compiled(_neighbour_any_kernel)
    if kernel is not None:
        return kernel(vv_start, vv_nbr, flags, np.asarray(rows, np.int64))
    owner, pos = expand(vv_start, rows)
    return np.bincount(owner, weights=flags[vv_nbr[pos]], minlength=len(rows)) > 0


def _neighbour_any_kernel(vv_start, vv_nbr, flags, rows):
    """Compiled :func:`_neighbour_any`: the same (len(rows),) bool."""
    out = np.zeros(len(rows), np.bool_)
    for i in range(len(rows)):
        r = rows[i]
        for p in range(vv_start[r], vv_start[r + 1]):
            if flags[vv_nbr[p]]:
                out[i] = True
                break
    return out


def _conflicts(u, v, r, chosen_u, chosen_v, vv, big):
    """(w,) bool: which of this round's winners ``u -> v`` (ranks ``r``) must give way.

    chosen_u / chosen_v (n,) bool mark the removed / kept vertices of the collapses
    already chosen; among the winners themselves the lower rank wins.
    """
    n = len(chosen_u)
    # against the collapses already chosen: a chosen kept vertex next to u, a chosen
    # removed vertex next to v, or v already kept by another collapse
    loses = _neighbour_any(vv, chosen_v, u) | _neighbour_any(vv, chosen_u, v) | chosen_v[v] | chosen_u[v]
    # among this round's winners, the lower rank wins: the same kept vertex ...
    order = np.argsort(v, kind="stable")
    same = np.flatnonzero(v[order][1:] == v[order][:-1])
    for a_, b_ in ((order[same], order[same + 1]), (order[same + 1], order[same])):
        loses[a_[r[a_] > r[b_]]] = True
    # ... a kept vertex next to a lower-ranked winner's removed vertex (u itself ranks r) ...
    win_rank = np.full(n, big, dtype=np.int64)
    win_rank[u] = r
    loses |= _neighbour_min(vv, win_rank, v, big) < r
    # ... or a removed vertex next to a lower-ranked winner's kept vertex
    kept_rank = np.full(n, big, dtype=np.int64)
    np.minimum.at(kept_rank, v, r)
    loses |= _neighbour_min(vv, kept_rank, u, big) < r
    return loses
