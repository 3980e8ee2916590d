"""Seams: vertices that share one position collapse in pairs, both sides in one batch.

glTF splits a vertex wherever its attributes jump (UV seams, hard normals): the
copies share a position, and in the index mesh the seam is a cut whose two sides
are boundary edges running opposite ways between the same positions.  Collapsing
one side alone would open a crack.  The simplifier (:mod:`.simplify`) therefore
never removes a seam vertex (a vertex whose position another live vertex of the
primitive shares) by an ordinary collapse; it removes it here, as a *seam pair*.

Positions are grid integers: the encoder finds the copies with :func:`grid_weld` (exact
float copies, and vertices on one grid point on a cut of the index mesh, whose input floats
may differ by rounding noise), after :func:`snap_near_copies` put copies that rounded to
neighbouring grid points on one.

Rule (everything in the pre-batch mesh; ``pos`` is a vertex's position):

* **Seam vertex.**  ``u`` is a seam vertex when another live vertex has its
  position; its *copies* are all live vertices at that position.
* **Pair.**  A seam pair is two collapses ``u1 -> v1`` and ``u2 -> v2`` with
  ``{u1, u2}`` all the copies of ``pos(u1)`` (exactly two), ``pos(v1) == pos(v2)``
  and ``v1 != v2``, each along a boundary edge of the index mesh (the edge of the
  seam on its own side).  Both halves land on the same position, so the seam stays
  closed, and each side keeps its own attribute values.
* **Pure seam vertex.**  Each copy is one half-disk of faces (two boundary edges),
  and every boundary half-edge at either copy has a *partner*: a boundary
  half-edge running the other way between the same two positions.  A vertex where
  a seam meets a true boundary (a hole, a cylinder's rim) is not pure: moving it
  along the seam would pull the boundary inwards.
* **Corners stay.**  A position with three or more copies (seam branch points, a
  cube's corners) is never removed: a seam ray touches only two of its sectors, the
  other copies would be left behind (a T-junction).  A seam *end* inside a surface
  (one copy, a slit) cannot take both halves of its neighbour either: they would
  keep the same vertex (``v1 == v2``), which one batch of splits cannot undo.
* **Each half legal on its own side**: the simplifier's own legality test
  (link condition, no flip, no duplicate face, interior wing edges).
* **Welded link condition.**  With the copies welded, ``u`` and ``v`` share exactly
  two neighbour positions, the two wings (distinct): no collapse pinches the two
  sides of a seam together through a third position.
* **Independent.**  The two halves obey the batch rule against each other
  (``u2`` not next to ``u1``, ``v1`` not next to ``u2`` and vice versa) and, as a
  unit, against every other collapse of the batch (:func:`choose_pairs`,
  :func:`blocked_by`): a decoder undoes the pair as two splits of one batch.

Pairs are chosen before the batch's ordinary collapses, cheapest first (cost =
the sum of both halves' quadric costs, the welded vertex's quadric), and the
ordinary collapses then avoid their neighbourhoods.  In the stream the pair is two
splits of the same batch whose new vertices have the same position: the second
one's position is a copy of its twin's (:func:`twin_rows` finds them).
"""

from __future__ import annotations

import numpy as np

from . import pcg64, topology
from .topology import any_corner, compiled, expand


def weld_groups(positions: np.ndarray) -> np.ndarray | None:
    """(n,) int64: the smallest vertex id with each vertex's exact row; None when all rows differ.

    ``positions`` (n, d) float (or int: grid integers, exact in float64 below 2**53); -0.0 and
    0.0 are the same value.  One sort of a 64-bit hash of the rows finds the candidates; only
    rows whose hash repeats are compared exactly.  (Any ``d``: positions, or positions with
    every attribute, :func:`~pmwm_codec.mesh.weld_soup`'s duplicate weld.)
    """
    pts = np.asarray(positions, np.float64)
    if len(pts) < 2:  # (before the reshape: an empty array has no column count to infer)
        return None
    pts = np.ascontiguousarray(pts.reshape(len(pts), -1) + 0.0)
    n, d = pts.shape
    bits = pts.view(np.uint64).reshape(n, d)
    h = np.zeros(n, np.uint64)
    for k in range(d):
        h ^= bits[:, k] * _HASH_FACTORS[k % len(_HASH_FACTORS)]
        if k >= len(_HASH_FACTORS):  # more columns than factors: mix before reusing one
            h = (h << np.uint64(13)) | (h >> np.uint64(51))
    cand = _repeated_hashes(h)
    cand = cand[~np.isnan(pts[cand]).any(axis=1)] if len(cand) else cand  # a NaN equals nothing: no copies
    if len(cand) == 0:
        return None
    inverse = _row_groups(bits[cand])
    rep = np.full(int(inverse.max()) + 1, n, np.int64)
    np.minimum.at(rep, inverse, cand)
    weld = np.arange(n, dtype=np.int64)
    weld[cand] = rep[inverse]
    return None if np.array_equal(weld, np.arange(n)) else weld


def _row_groups(rows: np.ndarray) -> np.ndarray:
    """(c,) int64: a group number for each row of ``rows`` (c, d) uint64, equal exactly when the rows are
    (numbered in the rows' lexicographic order; one lexsort of the columns, ~5x faster than
    ``np.unique(axis=0)`` on a scan's shared points)."""
    order = np.lexsort(rows.T[::-1])
    s = rows[order]
    new = np.ones(len(s), bool)
    new[1:] = (s[1:] != s[:-1]).any(axis=1)
    inverse = np.empty(len(s), np.int64)
    inverse[order] = np.cumsum(new) - 1
    return inverse


#: Odd 64-bit multipliers of :func:`weld_groups`' row hash, one per column (the first three as they were).
_HASH_FACTORS = tuple(np.uint64(x) for x in (
    0x9E3779B97F4A7C15, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9, 0x27D4EB2F165667C5,
    0x85EBCA77C2B2AE63, 0xFF51AFD7ED558CCD, 0xC4CEB9FE1A85EC53, 0x94D049BB133111EB,
))


def grid_weld(q: np.ndarray, faces: np.ndarray, positions: np.ndarray,
              on_grid: np.ndarray | None | bool = False) -> np.ndarray | None:
    """(n,) int64 seam copies on the position grid, as :func:`weld_groups` gives them (the smallest
    vertex id of each group); None when there are none.

    The stream lives on the grid: two vertices on one grid point ``q`` (n, 3) int64 are one
    point at every level of the decode, even when their input ``positions`` (n, 3) float differ
    by less than a grid step (a trig-built UV sphere's seam columns: ``sin(2 pi)`` is not 0).
    Copies are therefore

    * vertices with exactly equal input positions (:func:`weld_groups`, every one of them, as
      before), and
    * vertices on one grid point that both lie on a *cut* of the index mesh ``faces`` (m, 3):
      an end of a boundary half-edge that has a partner, a boundary half-edge running the other
      way between the same two grid points (module docstring).  That is where a seam's two
      sides are, and the only place two copies moved apart open a crack.

    Vertices that the grid alone puts on one point and that lie inside the surface (a dense
    scan on a coarse grid) are not copies: they cannot crack, and as seam vertices they would
    all stay in the base (several base vertices on one grid point, which the weld of a Draco
    base cannot tell apart).  With no such grid-only copies the result is
    ``weld_groups(positions)`` itself.  ``on_grid``: ``weld_groups(q)`` when the caller has it (None
    included).
    """
    exact = weld_groups(positions)
    on_grid = weld_groups(q) if on_grid is False else on_grid  # the caller's weld_groups(q), None included
    if on_grid is None or (exact is not None and np.array_equal(exact, on_grid)):
        return exact
    n = len(q)
    cut = _cut_vertices(on_grid, np.asarray(faces, np.int64).reshape(-1, 3), n)
    # each copy's links: to its exact group's first vertex, and (on a cut) to the first cut vertex of its grid
    # point; the groups are the connected parts, named by their smallest id
    first_cut = np.full(n, n, np.int64)
    ids = np.arange(n, dtype=np.int64)
    np.minimum.at(first_cut, on_grid[cut], ids[cut])
    link = np.where(cut, first_cut[on_grid], ids)
    exact = ids if exact is None else exact
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    # the graph of the vertices with a link to another (every other vertex is a part of its own: a scan's
    # vertices are nearly all alone, and a graph of all of them took ~20 ms at 437k vertices)
    linked = (exact != ids) | (link != ids)
    member = linked.copy()
    member[exact[linked]] = True
    member[link[linked]] = True
    members = np.flatnonzero(member)
    weld = ids.copy()
    if len(members):
        local = np.searchsorted(members, np.r_[members, members, exact[members], link[members]])
        k = len(members)
        graph = coo_matrix((np.ones(2 * k, np.int8), (local[: 2 * k], local[2 * k:])), shape=(k, k))
        _, part = connected_components(graph, directed=False)
        first = np.full(k, n, np.int64)
        np.minimum.at(first, part, members)
        weld[members] = first[part]
    return None if np.array_equal(weld, ids) else weld


#: Boundary vertices closer than this fraction of a grid step in every coordinate are one point
#: (:func:`snap_near_copies`): seam copies that float rounding put a hair apart.
NEAR_COPY_STEPS = 1.0 / 16.0


def snap_near_copies(q: np.ndarray, positions: np.ndarray, faces: np.ndarray, step: float,
                     locked: np.ndarray | None = None) -> np.ndarray:
    """(n, 3) int64: the grid points ``q`` (n, 3) int64 of ``positions`` (n, 3) float with every group of
    *near copies* on one of them; ``q`` itself when nothing moves.

    Near copies are boundary vertices of the index mesh ``faces`` (m, 3), not joined by an edge,
    whose positions differ by at most ``NEAR_COPY_STEPS * step`` in every coordinate (``step``: the
    grid's).  A seam's copies computed by trigonometry differ by float noise (``sin(2 pi)`` is
    -2.4e-16, not 0), and where the grid's rounding boundary falls between them (0 of a mesh
    spanning ``[-1, 1]`` lands half-way between two grid points) they round to neighbouring grid
    points: the seam would be open by a step at full resolution and could never be coarsened as a
    pair.  Each group takes the grid point of its smallest locked vertex (a border with another
    primitive never moves), or of its smallest vertex; locked vertices elsewhere stay.  A moved
    vertex decodes at most ``(0.5 + NEAR_COPY_STEPS)`` steps from its input in each coordinate.
    Vertices inside the surface are left as they are: they cannot open a crack.
    """
    n = len(q)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    rim = _rim(faces, n)
    if len(rim) < 2:
        return q
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.asarray(positions, np.float64)[rim]).query_pairs(
        NEAR_COPY_STEPS * float(step), p=np.inf, output_type="ndarray")
    if len(pairs) == 0:
        return q
    i, j = rim[pairs[:, 0]], rim[pairs[:, 1]]
    keep = np.any(q[i] != q[j], axis=1)  # pairs on one grid point already are copies there
    if not keep.any():
        return q
    near = faces[np.isin(faces, np.r_[i[keep], j[keep]]).any(axis=1)]  # the faces around the candidates
    a, b = near.reshape(-1), near[:, [1, 2, 0]].reshape(-1)
    edges = np.minimum(a, b) * n + np.maximum(a, b)
    keep &= ~np.isin(np.minimum(i, j) * n + np.maximum(i, j), edges)  # two ends of an edge are not copies
    i, j = i[keep], j[keep]
    if len(i) == 0:
        return q
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    members = np.unique(np.r_[i, j])
    local = np.searchsorted(members, np.r_[i, j])
    k = len(members)
    graph = coo_matrix((np.ones(len(local) // 2, np.int8), (local[: len(i)], local[len(i):])), shape=(k, k))
    _, part = connected_components(graph, directed=False)
    fixed = np.zeros(k, bool) if locked is None else np.asarray(locked, bool)[members]
    rank = np.where(fixed, members, members + n)  # the smallest locked member first, then the smallest one
    lead = np.full(part.max() + 1, 2 * n, np.int64)
    np.minimum.at(lead, part, rank)
    lead = lead % n
    move = ~fixed
    out = q.copy()
    out[members[move]] = q[lead[part[move]]]
    return out


#: The seed of :func:`_rim`'s random vertex weights.
RIM_SEED = 0x5EA3


def _rim(faces: np.ndarray, n: int) -> np.ndarray:
    """The vertices (k,) int64, ascending, of the edges of ``faces`` (m, 3) int64 over ``n`` vertices that
    have one face (boundary edges), without an edge table of the whole mesh (a closed mesh has none).

    Around a vertex inside a surface every neighbour follows it in one face and precedes it in another,
    so the sums over its corners of a random 64-bit weight of the next vertex and of the previous one
    agree modulo 2**64; a boundary edge leaves them apart (but with probability 2**-64).  Those vertices
    are candidates, and the edges between two candidates --
    every face of such an edge holds a candidate, so its count is whole -- are counted exactly.  The weights
    are ``default_rng(RIM_SEED).integers(0, 2**63, n)``, drawn by the compiled kernel itself
    (:func:`.pcg64.integers_63`)."""
    kernel = compiled(_rim_kernel)
    if kernel is not None:
        maybe, touching = kernel(faces, RIM_SEED, n)
    else:  # the same sums modulo 2**64
        weight = np.random.default_rng(RIM_SEED).integers(0, 2**63, n, dtype=np.int64)
        corner = faces.reshape(-1)
        maybe = np.zeros(n, np.uint64)
        with np.errstate(over="ignore"):
            np.add.at(maybe, corner, weight[faces[:, [1, 2, 0]].reshape(-1)].astype(np.uint64))
            np.subtract.at(maybe, corner, weight[faces[:, [2, 0, 1]].reshape(-1)].astype(np.uint64))
        maybe = maybe != 0
        touching = any_corner(maybe, faces)
    if not maybe.any():
        return np.zeros(0, np.int64)
    near = faces[touching]
    a, b = near.reshape(-1), near[:, [1, 2, 0]].reshape(-1)
    both = maybe[a] & maybe[b]
    edges, count = np.unique(np.minimum(a, b)[both] * n + np.maximum(a, b)[both], return_counts=True)
    return np.unique(np.r_[edges[count == 1] // n, edges[count == 1] % n])


def _rim_kernel(faces, seed, n):
    """Compiled first step of :func:`_rim`: ``(maybe (n,) bool, touching (m,) bool)``, the vertices whose
    corners' next and previous vertices weigh differently (sums modulo 2**64; the weights drawn from ``seed``)
    and the faces that hold one."""
    weight = pcg64.integers_63(seed, n)
    total = np.zeros(n, np.uint64)
    for f in range(len(faces)):
        for c in range(3):
            v = faces[f, c]
            total[v] += np.uint64(weight[faces[f, (c + 1) % 3]])
            total[v] -= np.uint64(weight[faces[f, (c + 2) % 3]])
    maybe = total != 0
    touching = np.zeros(len(faces), np.bool_)
    for f in range(len(faces)):
        touching[f] = maybe[faces[f, 0]] or maybe[faces[f, 1]] or maybe[faces[f, 2]]
    return maybe, touching


def _cut_vertices(pid: np.ndarray, faces: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the ends of boundary half-edges of ``faces`` (m, 3) that have a partner, a boundary
    half-edge the other way between the same two points (``pid`` (n,) int64: each vertex's point).

    A partner runs between other vertices than its half-edge (the same two vertices would make one edge of
    two faces), so one end at least is a vertex whose point another vertex has: only the faces holding one
    are read (:func:`~.topology.any_corner`), and every edge with such an end has all its faces among them
    (its count, :func:`~.topology.edge_ids`', is exact)."""
    shared = np.bincount(pid, minlength=n)[pid] > 1
    faces = np.compress(any_corner(shared, faces), faces, axis=0)
    a = faces.reshape(-1)
    b = faces[:, [1, 2, 0]].reshape(-1)
    edge, count = topology.edge_ids(a, b, n)
    boundary = (count[edge] == 1) & (pid[a] != pid[b])
    a, b = a[boundary], b[boundary]
    ids, _ = topology.key_ids(np.r_[pid[a] * n + pid[b], pid[b] * n + pid[a]])  # forward, then reverse
    forward = np.zeros(len(ids), bool)
    forward[ids[: len(a)]] = True
    partnered = forward[ids[len(a):]]  # the reverse pair is some half-edge's forward one
    out = np.zeros(n, bool)
    out[a[partnered]] = True
    out[b[partnered]] = True
    return out


def local_groups(weld: np.ndarray, vids: np.ndarray, loc: np.ndarray) -> np.ndarray:
    """Seam group of each live vertex in local ids: (len(vids),) int64 in ``[0, len(vids))``.

    ``weld`` (N,) int64 from :func:`weld_groups` (original ids), ``vids`` (n,) the live
    vertices, ``loc`` (N,) original -> local id (-1 dead).  A group's representative (its
    smallest id) lives as long as any copy does (seam vertices die in pairs); a dead one
    would only make its copies singletons.
    """
    kernel = compiled(_local_groups_kernel)
    if kernel is not None:
        return kernel(weld, vids, loc)
    g = loc[weld[vids]]
    return np.where(g >= 0, g, np.arange(len(vids)))


def _local_groups_kernel(weld, vids, loc):
    """Compiled :func:`local_groups` (one pass, no (n,) temporaries)."""
    g = np.empty(len(vids), np.int64)
    for i in range(len(vids)):
        x = loc[weld[vids[i]]]
        g[i] = x if x >= 0 else i
    return g


def seam_mask(g: np.ndarray) -> np.ndarray:
    """(n,) bool: live vertices whose position another live vertex shares (``g`` from :func:`local_groups`)."""
    kernel = compiled(_seam_mask_kernel)
    if kernel is not None:
        return kernel(g)
    return np.bincount(g, minlength=len(g))[g] > 1


def _seam_mask_kernel(g):
    """Compiled :func:`seam_mask`: the group sizes counted, then read back."""
    size = np.zeros(len(g), np.int64)
    for x in g:
        size[x] += 1
    out = np.empty(len(g), np.bool_)
    for i in range(len(g)):
        out[i] = size[g[i]] > 1
    return out


def pair_up(hu, hv, he, g, et, src, dst, opp, vv) -> tuple:
    """Seam pairs among the half candidates ``hu -> hv`` on edges ``he`` ((h,) int64, local ids).

    Returns ``(i, j)`` (p,) int64 indices of the two halves of every candidate pair that is
    pure, has two copies, distinct kept vertices, independent halves and passes the welded
    link condition (module docstring).  ``g`` (n,) int64 seam groups, ``et`` the edge
    table, ``src`` / ``dst`` / ``opp`` (3m,) the half-edges, ``vv`` the vertex -> neighbour CSR.
    """
    n = len(g)
    copies = np.bincount(g, minlength=n)
    ok = (copies[g[hu]] == 2) & (et.count[he] == 1) & ~_impure(g, et, src, dst, n)[hu]
    idx = np.flatnonzero(ok)
    key = g[hu[idx]] * n + g[hv[idx]]
    order = idx[np.argsort(key, kind="stable")]
    key = g[hu[order]] * n + g[hv[order]]
    run = np.flatnonzero(key[1:] == key[:-1])
    single = np.ones(len(run), bool)  # runs of exactly two
    if len(run):
        prev = np.r_[False, run[1:] == run[:-1] + 1]
        nxt = np.r_[run[1:] == run[:-1] + 1, False]
        single = ~prev & ~nxt
    i, j = order[run[single]], order[run[single] + 1]
    keep = (hu[i] != hu[j]) & (hv[i] != hv[j])
    keep &= (et.find(hu[i], hu[j]) < 0) & (et.find(hv[i], hu[j]) < 0) & (et.find(hv[j], hu[i]) < 0)
    i, j = i[keep], j[keep]
    wing_i, wing_j = opp[et.he0[he[i]]], opp[et.he0[he[j]]]
    keep = (g[wing_i] != g[wing_j]) & _welded_link(hu[i], hu[j], hv[i], g, vv, copies)
    return i[keep], j[keep]


def _impure(g, et, src, dst, n) -> np.ndarray:
    """(n,) bool: vertices with a boundary half-edge that has no partner (module docstring)."""
    b = np.flatnonzero(et.count == 1)
    he = et.he0[b]
    a, c = g[src[he]], g[dst[he]]
    fwd = np.sort(a * n + c)
    back = c * n + a
    at = np.minimum(np.searchsorted(fwd, back), max(len(fwd) - 1, 0))
    lonely = (fwd[at] != back) if len(fwd) else np.zeros(0, bool)
    out = np.zeros(n, bool)
    out[src[he][lonely]] = True
    out[dst[he][lonely]] = True
    return out


def _welded_link(u1, u2, v1, g, vv, copies) -> np.ndarray:
    """(p,) bool: the welded ``u`` (copies u1, u2) and ``v`` (every copy of ``pos(v1)``)
    share exactly two neighbour positions.  ``copies`` (n,) int64: the size of each group of ``g``."""
    n = len(g)
    vv_start, vv_nbr = vv
    # every copy of pos(v1): the seam vertices of its group (seam vertices sorted by group, searched), or v1 alone
    seam = np.flatnonzero(copies[g] > 1)
    seam = seam[np.argsort(g[seam], kind="stable")]
    keys = g[seam]
    kernel = compiled(_welded_link_kernel)
    if kernel is not None:
        return kernel(u1, u2, v1, g, vv_start, vv_nbr, seam, keys)
    p = np.arange(len(u1), dtype=np.int64)
    own_a, pos_a = expand(vv_start, np.concatenate([u1, u2]))
    side_a = np.unique(np.concatenate([p, p])[own_a] * n + g[vv_nbr[pos_a]])
    bounds = np.empty(2 * len(v1), np.int64)  # each v1's run of ``keys``, as a CSR of 2 entries a row
    bounds[0::2] = np.searchsorted(keys, g[v1], "left")
    bounds[1::2] = np.searchsorted(keys, g[v1], "right")
    alone = np.flatnonzero(bounds[0::2] == bounds[1::2])
    own_m, pos_m = expand(bounds, 2 * p)
    own_m = np.concatenate([own_m, alone])
    own_b, pos_b = expand(vv_start, np.concatenate([seam[pos_m], v1[alone]]))
    side_b = np.unique(own_m[own_b] * n + g[vv_nbr[pos_b]])
    common = np.intersect1d(side_a, side_b, assume_unique=True) // n
    return np.bincount(common, minlength=len(u1)) == 2


def _welded_link_kernel(u1, u2, v1, g, vv_start, vv_nbr, seam, keys):
    """Compiled :func:`_welded_link`, pair by pair: the neighbour positions ``g`` of ``u1`` and ``u2``, and of
    every copy of ``pos(v1)`` (the ``seam`` vertices whose group ``keys`` (ascending) is ``g[v1]``, or ``v1``
    alone when there are none), each sorted, then their distinct common values counted."""
    out = np.zeros(len(u1), np.bool_)
    one = np.empty(1, np.int64)
    for k in range(len(u1)):
        a = np.empty(vv_start[u1[k] + 1] - vv_start[u1[k]] + vv_start[u2[k] + 1] - vv_start[u2[k]], np.int64)
        j = 0
        for u in (u1[k], u2[k]):
            for q in range(vv_start[u], vv_start[u + 1]):
                a[j] = g[vv_nbr[q]]
                j += 1
        lo = np.searchsorted(keys, g[v1[k]], "left")
        hi = np.searchsorted(keys, g[v1[k]], "right")
        one[0] = v1[k]
        copies = seam[lo:hi] if hi > lo else one
        size = 0
        for x in copies:
            size += vv_start[x + 1] - vv_start[x]
        b = np.empty(size, np.int64)
        j = 0
        for x in copies:
            for q in range(vv_start[x], vv_start[x + 1]):
                b[j] = g[vv_nbr[q]]
                j += 1
        a.sort()
        b.sort()
        i = j = common = 0
        while i < len(a) and j < len(b):
            if a[i] < b[j]:
                i += 1
            elif a[i] > b[j]:
                j += 1
            else:
                common += 1
                x = a[i]
                while i < len(a) and a[i] == x:
                    i += 1
                while j < len(b) and b[j] == x:
                    j += 1
        out[k] = common == 2
    return out


def choose_pairs(hu, hv, i, j, cost, vv, n: int, rounds: int = 32) -> np.ndarray:
    """Indices into ``i`` / ``j`` of independent pairs, cheapest first (Luby rounds).

    ``hu`` / ``hv`` (h,) int64 half collapses, ``i`` / ``j`` (p,) their pairs (all legal),
    ``cost`` (p,) float64.  Each round a pair wins when no pair still in play with a lower
    rank conflicts with it (batch rule of :mod:`.simplify`, both halves against both
    halves); pairs that conflict with a winner leave play.
    """
    p = len(i)
    rank = np.empty(p, np.int64)
    rank[np.argsort(cost, kind="stable")] = np.arange(p)
    u = np.concatenate([hu[i], hu[j]])
    v = np.concatenate([hv[i], hv[j]])
    kernel = compiled(_choose_pairs_kernel)
    if kernel is not None:
        return kernel(u, v, rank, vv[0], vv[1], n, rounds)
    half_rank = np.concatenate([rank, rank])
    in_play = np.ones(p, bool)
    chosen = np.zeros(p, bool)
    big = np.int64(p + 1)
    for _ in range(rounds):
        live = np.concatenate([in_play | chosen, in_play | chosen])
        r = np.where(np.concatenate([chosen, chosen]), -1, half_rank)  # chosen pairs block everyone
        removed = np.full(n, big, np.int64)
        kept = np.full(n, big, np.int64)
        np.minimum.at(removed, u[live], r[live])
        np.minimum.at(kept, v[live], r[live])
        lower = np.minimum.reduce([
            removed[u], kept[v], _nbr_min(vv, removed, u, big), _nbr_min(vv, kept, u, big),
            _nbr_min(vv, removed, v, big),
        ])
        lower = np.minimum(lower[:p], lower[p:])
        in_play &= lower >= 0  # in conflict with a chosen pair
        win = in_play & (lower >= rank)
        if not win.any():
            break
        chosen |= win
        in_play &= ~win
    return np.flatnonzero(chosen)


def _choose_pairs_kernel(u, v, rank, vv_start, vv_nbr, n, rounds):
    """Compiled :func:`choose_pairs` (the same pairs): ``u`` / ``v`` (2p,) int64 the halves' removed and
    kept vertices (first halves, then second halves), ``rank`` (p,) int64 the pairs' ranks.  A round marks
    the halves of the pairs in play or chosen at their vertices in two (n,) arrays, made once and reset at
    the entries it marked, and tests the pairs in play only: a round costs the pairs, not the mesh."""
    p = len(rank)
    big = p + 1
    removed = np.full(n, big, np.int64)
    kept = np.full(n, big, np.int64)
    in_play = np.ones(p, np.bool_)
    chosen = np.zeros(p, np.bool_)
    lower = np.empty(p, np.int64)
    for _ in range(rounds):
        for h in range(2 * p):  # the halves of the pairs in play or chosen; a chosen one blocks everyone
            q = h % p
            if in_play[q] or chosen[q]:
                r = -1 if chosen[q] else rank[q]
                removed[u[h]] = min(removed[u[h]], r)
                kept[v[h]] = min(kept[v[h]], r)
        for q in range(p):
            if not in_play[q]:
                continue
            low = big
            for h in (q, q + p):
                low = min(low, removed[u[h]], kept[v[h]])
                for t in range(vv_start[u[h]], vv_start[u[h] + 1]):
                    low = min(low, removed[vv_nbr[t]], kept[vv_nbr[t]])
                for t in range(vv_start[v[h]], vv_start[v[h] + 1]):
                    low = min(low, removed[vv_nbr[t]])
            lower[q] = low
        won = False
        for q in range(p):
            if in_play[q]:
                if lower[q] < 0:  # in conflict with a chosen pair
                    in_play[q] = False
                elif lower[q] >= rank[q]:
                    chosen[q] = True
                    in_play[q] = False
                    won = True
        for h in range(2 * p):
            removed[u[h]] = big
            kept[v[h]] = big
        if not won:
            break
    return np.flatnonzero(chosen)


def _nbr_min(vv, values, rows, big) -> np.ndarray:
    """(len(rows),) int64 smallest ``values`` over each row's neighbours (``big``: none)."""
    vv_start, vv_nbr = vv
    owner, pos = expand(vv_start, rows)
    out = np.full(len(rows), big, np.int64)
    np.minimum.at(out, owner, values[vv_nbr[pos]])
    return out


def blocked_by(u, v, vv, n: int) -> tuple:
    """What chosen collapses ``u -> v`` ((k,) int64) forbid the batch's other collapses.

    Returns ``(no_remove, no_keep)`` (n,) bool: a further collapse ``a -> b`` is
    independent of them iff ``not no_remove[a] and not no_keep[b]`` (removed vertices
    not adjacent, kept vertices distinct, no kept vertex next to a removed one).
    """
    vv_start, vv_nbr = vv
    _, near_u = expand(vv_start, u)
    _, near_v = expand(vv_start, v)
    no_remove = np.zeros(n, bool)
    no_remove[u] = True
    no_remove[vv_nbr[near_u]] = True
    no_remove[vv_nbr[near_v]] = True
    no_keep = np.zeros(n, bool)
    no_keep[vv_nbr[near_u]] = True
    no_keep[u] = True
    no_keep[v] = True
    return no_remove, no_keep


def within_budget(cost_single, cost_pair, budget: int) -> tuple:
    """Cheapest collapses that fit ``budget`` removed vertices, pairs counting two.

    ``cost_single`` (s,) / ``cost_pair`` (p,) float64.  Returns ``(singles, pairs)`` sorted
    index arrays: the longest prefix of all units in cost order (stable, singles first on
    ties) whose vertex count stays within ``budget``.
    """
    if len(cost_single) + 2 * len(cost_pair) <= budget:  # everything fits: no order to find
        return np.arange(len(cost_single)), np.arange(len(cost_pair))
    cost = np.concatenate([cost_single, cost_pair])
    size = np.r_[np.ones(len(cost_single), np.int64), np.full(len(cost_pair), 2, np.int64)]
    order = np.argsort(cost, kind="stable")
    take = order[np.cumsum(size[order]) <= budget]
    s = len(cost_single)
    return np.sort(take[take < s]), np.sort(take[take >= s] - s)


def _repeated_hashes(h: np.ndarray) -> np.ndarray:
    """(c,) int64 ascending: the rows of ``h`` (n,) uint64 whose value some other row also has (one sort,
    or its compiled twin: one hash table, no sort)."""
    kernel = compiled(_repeated_hashes_kernel)
    if kernel is not None:
        return kernel(h)
    order = np.argsort(h, kind="stable")
    same = h[order][1:] == h[order][:-1]
    return np.unique(order[np.r_[same, False] | np.r_[False, same]])


def _repeated_hashes_kernel(h):
    """Compiled :func:`_repeated_hashes`: an open-addressing table (twice the rows, a power of two) slotted
    by the top bits of each hash (their low bits can be all zero: products of round floats' bit patterns)."""
    n = len(h)
    bits = 1
    while (1 << bits) < 2 * n:
        bits += 1
    size = 1 << bits
    keys = np.empty(size, np.uint64)
    count = np.zeros(size, np.int64)  # 0: an empty slot
    slot = np.empty(n, np.int64)
    shift = np.uint64(64 - bits)
    for i in range(n):
        j = np.int64(h[i] >> shift)
        while count[j] > 0 and keys[j] != h[i]:
            j = (j + 1) & (size - 1)
        keys[j] = h[i]
        count[j] += 1
        slot[i] = j
    c = 0
    for i in range(n):
        c += count[slot[i]] > 1
    out = np.empty(c, np.int64)
    c = 0
    for i in range(n):
        if count[slot[i]] > 1:
            out[c] = i
            c += 1
    return out


def twin_rows(points: np.ndarray) -> np.ndarray:
    """(k,) int64: for each row of ``points`` (k, d), the first row with the same values.

    A row whose entry is not itself is a *twin*: the second half of a seam pair (or two
    new vertices that happen to coincide).  NaN rows are never twins.
    """
    pts = np.asarray(points)
    k = len(pts)
    if k == 0:
        return np.zeros(0, np.int64)
    finite = np.isfinite(pts).all(axis=1) if pts.dtype.kind == "f" else np.ones(k, bool)
    rows = np.flatnonzero(finite)
    out = np.arange(k, dtype=np.int64)
    if len(rows) < 2:
        return out
    _, first, inverse = np.unique(pts[rows] + 0, axis=0, return_index=True, return_inverse=True)
    out[rows] = rows[first[inverse.reshape(-1)]]
    return out
