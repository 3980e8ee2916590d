"""Seams: vertices that share one position collapse in pairs, both sides in one batch.

glTF splits a vertex wherever its attributes jump (UV seams, hard normals): the
copies share a position, and in the index mesh the seam is a cut whose two sides
are boundary edges running opposite ways between the same positions.  Collapsing
one side alone would open a crack.  The simplifier (:mod:`.simplify`) therefore
never removes a seam vertex (a vertex whose position another live vertex of the
primitive shares) by an ordinary collapse; it removes it here, as a *seam pair*.

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

from .topology import compiled, csr, expand


def weld_groups(positions: np.ndarray) -> np.ndarray | None:
    """(n,) int64: the smallest vertex id with each vertex's exact position; None when all differ.

    ``positions`` (n, 3) float; -0.0 and 0.0 are the same position.  One sort of a 64-bit
    hash of the rows finds the candidates; only rows whose hash repeats are compared exactly.
    """
    pts = np.ascontiguousarray(np.asarray(positions, np.float64) + 0.0)
    n = len(pts)
    if n < 2:
        return None
    bits = pts.view(np.uint64).reshape(n, 3)
    h = bits[:, 0] * np.uint64(0x9E3779B97F4A7C15)
    h ^= bits[:, 1] * np.uint64(0xC2B2AE3D27D4EB4F)
    h ^= bits[:, 2] * np.uint64(0x165667B19E3779F9)
    cand = _repeated_hashes(h)
    if len(cand) == 0:
        return None
    _, inverse = np.unique(pts[cand], axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    rep = np.full(int(inverse.max()) + 1, n, np.int64)
    np.minimum.at(rep, inverse, cand)
    weld = np.arange(n, dtype=np.int64)
    weld[cand] = rep[inverse]
    return None if np.array_equal(weld, np.arange(n)) else weld


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
    keep = (g[wing_i] != g[wing_j]) & _welded_link(hu[i], hu[j], hv[i], g, vv)
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


def _welded_link(u1, u2, v1, g, vv) -> np.ndarray:
    """(p,) bool: the welded ``u`` (copies u1, u2) and ``v`` (every copy of ``pos(v1)``)
    share exactly two neighbour positions."""
    n = len(g)
    vv_start, vv_nbr = vv
    p = np.arange(len(u1), dtype=np.int64)
    own_a, pos_a = expand(vv_start, np.concatenate([u1, u2]))
    side_a = np.unique(np.concatenate([p, p])[own_a] * n + g[vv_nbr[pos_a]])
    members_start, members = csr(g, np.arange(n), n)
    own_m, pos_m = expand(members_start, g[v1])
    own_b, pos_b = expand(vv_start, members[pos_m])
    side_b = np.unique(own_m[own_b] * n + g[vv_nbr[pos_b]])
    common = np.intersect1d(side_a, side_b, assume_unique=True) // n
    return np.bincount(common, minlength=len(u1)) == 2


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
