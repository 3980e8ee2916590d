"""Mesh distortion: RMS, PSNR and a sampled, exact-distance Hausdorff distance.

Mesh (:func:`mesh_distortion`, the fields of ``encode --json``'s ``distortion``):

* ``rms`` — RMS distance between corresponding vertices (same vertex count required);
* ``psnr_db`` — ``20 log10(D / rms)``, D the original's bounding-box diagonal (inf if rms 0);
* ``hausdorff`` — symmetric Hausdorff distance between the two *surfaces*, divided by D;
* ``bbox_diagonal`` — D.

:func:`rms_surface_distance` compares surfaces that need not share vertices (a level of
detail against its original): the symmetric RMS point-to-surface distance, sampled both ways.

:func:`mesh_nc` adds the paper's mesh NC (normalized correlation of centred vertex positions).

The Hausdorff distance is estimated Metro-style (:func:`hausdorff_distance`): each surface is
sampled (all its vertices plus area-weighted uniform random points, seeded) and for every
sample the distance to the *other* surface is computed **exactly** — candidate triangles
come from k-d trees over triangle centroids (triangles grouped by size), pruned by the
bound ``distance >= |p - centroid| - radius``, and a sample's search widens (k x 4) until
``best <= (k-th centroid distance) - (group's largest radius)`` proves that no other
triangle can be closer (see :func:`surface_distance`).  The only approximation is the
sampling: the maximum over the samples is a lower bound of the true Hausdorff distance that
converges as ``samples`` grows (default: 10 per face, 20k..100k per surface; vertices, where
a displaced mesh usually errs most, are always included).

Memory is bounded: queries run in blocks of points, and a widening search never holds more
than :data:`PAIR_BUDGET` (point, candidate) pairs at once (a closed cylinder's long thin
triangles made one query of 4k candidates per point, over 10 GB, before).

The encoder's ``distortion`` report (:func:`full_distortion`) compares the input with the
full decode of its progressive primitives (:func:`decoded_positions`, :func:`combine_meshes`),
which has the same connectivity and vertex order.  By default (``measure="vertices"``,
:func:`vertex_distortion`) it is cheap and exact where it can be: RMS and PSNR come from the
vertex displacements, and ``hausdorff`` is the largest vertex displacement over D, an
**upper bound** of the surface Hausdorff distance (a point of a triangle is the same
barycentric mix of its corners in both meshes, so it moves at most as far as the farthest
corner).  ``measure="sampled"`` gives the Metro-style sampled estimate above (a lower bound
that converges with the samples).  The report's ``measure`` field says which.
"""

from __future__ import annotations

import numpy as np

from .errors import MeshError
from .mesh import Mesh, bounds
from .progressive.vsplit import apply_batch

__all__ = [
    "point_triangle_distance",
    "sample_surface",
    "surface_distance",
    "hausdorff_distance",
    "rms_surface_distance",
    "default_samples",
    "mesh_distortion",
    "mesh_nc",
    "full_distortion",
    "decoded_positions",
    "combine_meshes",
    "vertex_distortion",
    "measure_method",
    "MEASURES",
]

#: Ways to measure the encoder's distortion: exact vertex errors with the displacement bound,
#: the sampled surface Hausdorff distance, or nothing.
MEASURES = ("vertices", "sampled", "none")
#: Largest number of (point, candidate triangle) pairs a surface query holds at once.
PAIR_BUDGET = 1 << 20


def _dot(u, v):
    return np.einsum("...i,...i->...", u, v)


class _Triangles:
    """Per-triangle data precomputed once for many point-triangle distance queries."""

    def __init__(self, tri: np.ndarray):
        tri = np.asarray(tri, dtype=np.float64).reshape(-1, 3, 3)
        self.corner = tri  # (m, 3, 3)
        self.edge = np.roll(tri, -1, axis=1) - tri  # (m, 3, 3): b-a, c-b, a-c
        ee = _dot(self.edge, self.edge)
        self.inv_ee = np.divide(1.0, ee, out=np.zeros_like(ee), where=ee > 0)
        n = np.cross(self.edge[:, 0], -self.edge[:, 2])
        nn = np.linalg.norm(n, axis=1)
        self.flat = nn > 0  # False for degenerate (zero-area) triangles
        self.unit_normal = n / np.where(self.flat, nn, 1.0)[:, None]
        # in-plane inward normals of the edges: p is over the triangle iff all three >= 0
        self.inward = np.cross(self.unit_normal[:, None, :], self.edge)

    def distance(self, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """p (n, 3), idx (n,) triangle indices -> (n,) exact distances."""
        rel = p[:, None, :] - self.corner[idx]  # (n, 3, 3): p-a, p-b, p-c
        side = _dot(rel, self.inward[idx])  # (n, 3)
        over = self.flat[idx] & (side >= 0).all(axis=1)
        plane = np.abs(_dot(rel[:, 0], self.unit_normal[idx]))
        edge = self.edge[idx]
        t = np.clip(_dot(rel, edge) * self.inv_ee[idx], 0.0, 1.0)
        off = rel - t[..., None] * edge
        edge_d2 = _dot(off, off).min(axis=1)
        return np.where(over, plane, np.sqrt(edge_d2))


def point_triangle_distance(points, triangles) -> np.ndarray:
    """Exact Euclidean distance from each point to its triangle.

    points : (n, 3) float; triangles : (n, 3, 3) float (corners a, b, c); the two are
    broadcast (a single point or a single triangle is fine).  Returns (n,) float64.
    If the point's projection falls inside the triangle the distance is the plane
    distance, otherwise the smallest distance to the three edges; degenerate (zero-area)
    triangles therefore measure as segments or points.
    """
    p = np.asarray(points, dtype=np.float64)
    t = np.asarray(triangles, dtype=np.float64)
    p, t = np.broadcast_arrays(p[..., None, :], t)
    p = p[..., 0, :]
    shape = p.shape[:-1]
    tris = _Triangles(t.reshape(-1, 3, 3))
    d = tris.distance(p.reshape(-1, 3), np.arange(tris.corner.shape[0]))
    return d.reshape(shape)


def sample_surface(positions, faces, samples: int, seed: int = 0) -> np.ndarray:
    """The vertices plus ``samples`` area-weighted uniform points: (n + samples, 3) float64."""
    v = np.asarray(positions, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    tri = v[f]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    if samples <= 0 or area.sum() <= 0:
        return v.copy()
    rng = np.random.default_rng(seed)
    pick = rng.choice(len(f), size=samples, p=area / area.sum())
    r1, r2 = rng.random(samples), rng.random(samples)
    flip = r1 + r2 > 1.0  # fold the unit square onto the triangle
    r1, r2 = np.where(flip, 1 - r1, r1), np.where(flip, 1 - r2, r2)
    t = tri[pick]
    pts = t[:, 0] + r1[:, None] * (t[:, 1] - t[:, 0]) + r2[:, None] * (t[:, 2] - t[:, 0])
    return np.concatenate([v, pts])


def _buckets(radius: np.ndarray, keep: float = 0.9, small: int = 64) -> list[np.ndarray]:
    """Triangle indices split by radius: the smallest 90 %, then 90 % of the rest, ..."""
    rest, out = np.argsort(radius, kind="stable"), []
    while rest.size > small:
        cut = int(np.ceil(keep * rest.size))
        out.append(rest[:cut])
        rest = rest[cut:]
    return out + ([rest] if rest.size else [])


def surface_distance(points, positions, faces, k: int = 8, block: int = 1 << 15) -> np.ndarray:
    """Exact distance from each point (n, 3) to a triangle surface: (n,) float64.

    Triangles are grouped by radius r (largest centroid-to-corner distance): the smallest
    90 %, 90 % of the rest, and so on, one k-d tree of centroids per group.  In each group
    the k nearest centroids are candidates, evaluated only when ``|p - centroid| - r`` is
    below the best distance so far; a point is done with a group when
    ``best <= (k-th centroid distance) - (group's largest r)``, otherwise it is retried
    with 4k candidates, up to the whole group.  ``block`` points at a time (memory).
    """
    from scipy.spatial import cKDTree  # on first use: the default (vertex) measure needs none

    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    tris = _Triangles(np.asarray(positions, dtype=np.float64)[np.asarray(faces, dtype=np.int64)])
    centroid = tris.corner.mean(axis=1)
    radius = np.linalg.norm(tris.corner - centroid[:, None, :], axis=2).max(axis=1)
    groups = [(cKDTree(centroid[g]), g, radius[g]) for g in _buckets(radius)]
    out = np.empty(len(p))
    for s in range(0, len(p), block):
        q = p[s : s + block]
        best = np.full(len(q), np.inf)
        for tree, g, rad in groups:
            _search_group(q, best, tris, tree, g, rad, k)
        out[s : s + block] = best
    return out


def _search_group(q, best, tris, tree, g, rad, k) -> None:
    """Lower ``best`` (n,) in place to the exact distance to the group's triangles ``g``.

    At most :data:`PAIR_BUDGET` (point, candidate) pairs are held at once: points still
    searching are queried in slices of ``PAIR_BUDGET // k`` as k grows.
    """
    todo, kk, r_max = np.arange(len(q)), min(k, len(g)), float(rad.max())
    while todo.size:
        step = max(1, PAIR_BUDGET // kk)
        keep = [_search_slice(q, best, tris, tree, g, rad, todo[s : s + step], kk, r_max)
                for s in range(0, len(todo), step)]
        if kk == len(g):
            break
        todo = np.concatenate(keep)
        kk = min(4 * kk, len(g))


def _search_slice(q, best, tris, tree, g, rad, todo, kk, r_max) -> np.ndarray:
    """One query of ``kk`` candidates for the points ``todo``; returns those not yet proven done."""
    cdist, cidx = tree.query(q[todo], k=kk, workers=-1)
    cdist, cidx = cdist.reshape(len(todo), kk), cidx.reshape(len(todo), kk)
    first = ~np.isfinite(best[todo])  # no bound yet: take the nearest centroid's triangle
    if first.any():
        best[todo[first]] = tris.distance(q[todo[first]], g[cidx[first, 0]])
    rows, cols = np.nonzero(cdist - rad[cidx] < best[todo][:, None])
    for s in range(0, rows.size, PAIR_BUDGET // 4):  # distance() holds ~40 floats per pair
        r, c = rows[s : s + PAIR_BUDGET // 4], cols[s : s + PAIR_BUDGET // 4]
        d = tris.distance(q[todo[r]], g[cidx[r, c]])
        starts = np.flatnonzero(np.r_[True, r[1:] != r[:-1]])
        hit = todo[r[starts]]
        best[hit] = np.minimum(best[hit], np.minimum.reduceat(d, starts))
    return todo[best[todo] > cdist[:, -1] - r_max]


def default_samples(mesh) -> int:
    """Random samples per surface when none are given: 10 per face (as Metro), 20k..100k."""
    return int(np.clip(10 * len(mesh.faces), 20_000, 100_000))


def hausdorff_distance(mesh_a, mesh_b, samples: int | None = None, seed: int = 0) -> float:
    """Symmetric Hausdorff distance between two surfaces (absolute units), sampled.

    mesh_a, mesh_b : objects with ``positions`` (n, 3) and ``faces`` (m, 3).
    ``samples`` random points per surface in addition to its vertices (default
    :func:`default_samples`); the result is deterministic for a given ``seed``.
    """
    na = default_samples(mesh_a) if samples is None else samples
    nb = default_samples(mesh_b) if samples is None else samples
    pa = sample_surface(mesh_a.positions, mesh_a.faces, na, seed)
    pb = sample_surface(mesh_b.positions, mesh_b.faces, nb, seed + 1)
    ab = surface_distance(pa, mesh_b.positions, mesh_b.faces).max()
    ba = surface_distance(pb, mesh_a.positions, mesh_a.faces).max()
    return float(max(ab, ba))


def rms_surface_distance(mesh_a, mesh_b, samples: int = 100_000, seed: int = 0) -> float:
    """Symmetric RMS point-to-surface distance between two surfaces (absolute units), sampled.

    mesh_a, mesh_b : objects with ``positions`` (n, 3) and ``faces`` (m, 3); their vertex
    counts and connectivity may differ (a level of detail against its original).  Each
    surface gets ``samples`` area-weighted uniform random points (vertices are not added, so
    both directions weigh the same), each point's exact distance to the other surface is
    taken (:func:`surface_distance`), and the result is the RMS over all ``2 * samples``
    distances: ``sqrt((mean d_ab^2 + mean d_ba^2) / 2)``.  Deterministic for a ``seed``;
    a surface of zero area contributes its vertices instead.
    """
    squares = []
    for s, (src, dst) in enumerate(((mesh_a, mesh_b), (mesh_b, mesh_a))):
        n = len(src.positions)
        pts = sample_surface(src.positions, src.faces, samples, seed + s)
        pts = pts[n:] if len(pts) > n else pts
        squares.append(float(np.mean(surface_distance(pts, dst.positions, dst.faces) ** 2)))
    return float(np.sqrt(0.5 * (squares[0] + squares[1])))


def mesh_distortion(original, distorted, samples: int | None = None, seed: int = 0) -> dict:
    """Distortion of ``distorted`` against ``original`` (same vertices, in the same order).

    Returns ``{"rms", "psnr_db", "hausdorff", "bbox_diagonal"}`` (floats): RMS vertex error
    in model units, PSNR ``20 log10(D / rms)`` in dB (inf when rms is 0), Hausdorff distance
    as a fraction of D, and D, the bounding-box diagonal of ``original``.  ``samples``
    and ``seed`` go to :func:`hausdorff_distance`.

    Raises
    ------
    MeshError
        When the vertex counts differ (there is no vertex correspondence).
    """
    a = np.asarray(original.positions, dtype=np.float64)
    b = np.asarray(distorted.positions, dtype=np.float64)
    if a.shape != b.shape:
        raise MeshError(
            f"cannot compare vertex errors: {len(a)} original vs {len(b)} distorted vertices"
        )
    lo, hi = bounds(a)
    diag = float(np.linalg.norm(hi - lo))
    rms = float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))))
    psnr_db = float("inf") if rms == 0.0 else float(20.0 * np.log10(diag / rms))
    if rms == 0.0 and np.array_equal(original.faces, distorted.faces):
        h = 0.0
    else:
        h = hausdorff_distance(original, distorted, samples, seed)
    return {
        "rms": rms,
        "psnr_db": psnr_db,
        "hausdorff": h / diag if diag > 0 else 0.0,
        "bbox_diagonal": diag,
    }


def mesh_nc(original, distorted) -> float:
    """Normalized correlation of two meshes' vertex positions (the paper's Table I "Disguised Mesh (NC)").

    ``original`` / ``distorted``: meshes (or (n, 3) arrays) with the same vertices in the same
    order.  Both position sets are centred on the *original's* centroid ``c`` and correlated
    over all 3n coordinates::

        a = P - c,  b = P' - c,  NC = <a, b> / (|a| |b|)      (float64)

    1 for identical meshes; translation-free, so the value measures the shape change, not
    where the mesh sits.  For a small error ``1 - NC`` is about half the squared ratio of
    the error orthogonal to ``a`` to the RMS radius.  Raises MeshError when the vertex
    counts differ; returns 1.0 for a mesh of one point.
    """
    a = np.asarray(getattr(original, "positions", original), np.float64)
    b = np.asarray(getattr(distorted, "positions", distorted), np.float64)
    if a.shape != b.shape:
        raise MeshError(f"cannot correlate vertices: {len(a)} original vs {len(b)} distorted vertices")
    c = a.mean(axis=0)
    a, b = (a - c).ravel(), (b - c).ravel()
    na, nb = np.linalg.norm(a), np.linalg.norm(b)
    if na == 0.0 or nb == 0.0:
        return 1.0 if na == nb else 0.0
    return float(np.clip(np.dot(a, b) / (na * nb), -1.0, 1.0))


# --- the encoder's report ----------------------------------------------------------------


def combine_meshes(meshes) -> Mesh:
    """One mesh of several (disjoint vertex ranges); the mesh itself when there is one.

    meshes : list of :class:`Mesh` with (n_i, 3) float64 positions and (m_i, 3) int64 faces.
    Returns positions (sum n_i, 3) float64 and faces (sum m_i, 3) int64 (offset per mesh).
    """
    if len(meshes) == 1:
        return meshes[0]
    offsets = np.cumsum([0] + [m.vertex_count for m in meshes])
    return Mesh(
        np.concatenate([m.positions for m in meshes]),
        np.concatenate([m.faces + o for m, o in zip(meshes, offsets)]),
    )


def decoded_positions(pm, grid) -> np.ndarray:
    """(n, 3) float64 positions of the full decode of ``pm``, in the input's vertex order.

    pm : :class:`~pmwm_codec.progressive.build.ProgressiveMesh`; grid : its
    :class:`~pmwm_codec.progressive.grid.Grid`.  The builder's own replay's end (``pm.full_values``)
    when it kept it, else every batch replayed on a fresh state.
    """
    values = pm.full_values
    if values is None:
        state = pm.new_state()
        for batch in pm.batches:
            apply_batch(state, batch)
        values = state.current_positions()
    return grid.dequantize(values[:, :3])[pm.vertex_order]


def measure_method(measure) -> str:
    """``measure`` as one of :data:`MEASURES` (True / None / False: ``"vertices"`` / ``"none"``);
    ValueError otherwise."""
    method = measure if isinstance(measure, str) else ("vertices" if measure else "none")
    if method not in MEASURES:
        raise ValueError(f"measure must be one of {', '.join(MEASURES)}, got {measure!r}")
    return method


def vertex_distortion(original: Mesh, decoded: Mesh) -> dict:
    """Distortion of ``decoded`` against ``original``, same connectivity and vertex order.

    Returns ``{"rms", "psnr_db", "hausdorff", "bbox_diagonal"}``: RMS and PSNR exactly from
    the (n, 3) vertex displacements, ``hausdorff`` the largest vertex displacement over D
    (an upper bound of the surface Hausdorff distance, module docstring).  O(n) time and memory.
    """
    a = np.asarray(original.positions, dtype=np.float64)
    b = np.asarray(decoded.positions, dtype=np.float64)
    if a.shape != b.shape:
        raise MeshError(f"cannot compare vertex errors: {len(a)} original vs {len(b)} decoded vertices")
    lo, hi = bounds(a)
    diag = float(np.linalg.norm(hi - lo))
    d = a - b
    moved = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])  # np.sum(d ** 2, axis=1), not its slow 3-wide reduce
    rms = float(np.sqrt(np.mean(moved**2)))
    psnr_db = float("inf") if rms == 0.0 else float(20.0 * np.log10(diag / rms))
    worst = float(moved.max()) if moved.size else 0.0
    return {"rms": rms, "psnr_db": psnr_db, "hausdorff": worst / diag if diag > 0 else 0.0, "bbox_diagonal": diag}


def full_distortion(original: Mesh, decoded: Mesh, measure="vertices") -> dict:
    """Distortion of ``decoded`` (same connectivity and vertex order) against ``original``.

    ``measure``: ``"vertices"`` (:func:`vertex_distortion`) or ``"sampled"``
    (:func:`mesh_distortion`).  The fields as plain floats, plus ``measure``, the method used.
    """
    method = measure_method(measure)
    if method == "none":
        raise ValueError("full_distortion: nothing to measure with measure='none'")
    d = vertex_distortion(original, decoded) if method == "vertices" else mesh_distortion(original, decoded)
    return {**{k: (None if v is None else float(v)) for k, v in d.items()}, "measure": method}
