"""Vertex correspondence between a mesh that left the stream and its reference.

The watermark of a ``.pmw`` is read per vertex split, in the vertex order of the
stream's full decode (the *reference*).  A mesh that was exported, moved,
re-saved or attacked has lost that order; this module finds it again.

Contract
--------
:func:`correspond` ``(positions, faces, ref_positions, ref_faces) -> Correspondence``
maps every reference vertex ``i`` to a mesh vertex ``index[i]`` (``valid[i]``
False where the mesh has no counterpart).  Methods, tried in this order:

``identity``
    Same vertex count and the same face array: nothing moved in the index space.
``faces-reordered``
    Same vertex count and the same set of oriented triangles, faces permuted
    and/or their corners rotated, or every face's winding reversed: vertex ids still agree.
``permutation``
    Same connectivity up to a vertex permutation (the faces wound as they are, or all reversed).  Found *topologically*: one
    seed triangle pair (chosen by similarity-invariant edge-length descriptors)
    is propagated across shared edges (breadth first, one half-edge lookup per
    step), and the result must map the face set onto the mesh's exactly.  Exact
    and independent of the geometry, so it also holds after noise, smoothing or
    quantization of a re-ordered mesh.
``registration``
    Anything else (cropped, simplified, re-meshed, another mesh).  The mesh is
    brought into the reference frame by a similarity ``x_ref = s R x + t``:
    hypotheses are the identity, principal axes (centroid, RMS radius, the 8
    sign choices of the axes, reflections included) and single-triangle matches
    of scale-free face shapes (RANSAC-style, for crops of a moved mesh), scored
    by the fraction of mesh vertices near a reference vertex; the best is
    refined by trimmed ICP with Umeyama's closed form.  Each reference vertex then takes its nearest mesh
    vertex; it is ``valid`` when that vertex lies within ``tolerance`` times the
    reference's mean edge length.

Everything is numpy / :class:`scipy.spatial.cKDTree`; the only Python loop is
the topological propagation (one step per face).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ..progressive.topology import mean_edge_length, same_face_set

__all__ = [
    "Correspondence",
    "correspond",
    "exact_correspondence",
    "match_topology",
    "register",
    "umeyama",
]

METHODS = ("identity", "faces-reordered", "permutation", "registration")


@dataclass
class Correspondence:
    """Reference vertex -> mesh vertex.

    ``index`` (n_ref,) int64 mesh vertex of every reference vertex (-1: none);
    ``valid`` (n_ref,) bool; ``method`` one of :data:`METHODS`; ``scale``,
    ``rotation`` (3, 3), ``translation`` (3,) the similarity mesh -> reference
    frame (identity for the topological methods); ``rms`` the RMS distance of
    the valid pairs in the reference frame, in reference units (None for the
    topological methods); ``distance`` (n_ref,) per-vertex nearest distance
    (registration only).
    """

    method: str
    index: np.ndarray
    valid: np.ndarray
    scale: float = 1.0
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rms: float | None = None
    distance: np.ndarray | None = None

    @property
    def coverage(self) -> float:
        """Fraction of reference vertices with a counterpart."""
        return float(self.valid.mean()) if len(self.valid) else 0.0

    def transform(self, positions: np.ndarray) -> np.ndarray:
        """Mesh positions (k, 3) in the reference frame."""
        return self.scale * np.asarray(positions, np.float64) @ self.rotation.T + self.translation


# ------------------------------------------------------------------ face sets


# ------------------------------------------------------------- topology match


def _face_descriptors(positions, faces):
    """(m, 3) edge lengths in corner order (|p0p1|, |p1p2|, |p2p0|) over the face's perimeter.

    Scale-free per face, so parts of a flattened asset that were scaled by
    different node transforms still find their counterparts.
    """
    p = np.asarray(positions, np.float64)[faces]
    d = np.stack([p[:, 1] - p[:, 0], p[:, 2] - p[:, 1], p[:, 0] - p[:, 2]], axis=1)
    lengths = np.linalg.norm(d, axis=2)
    perimeter = lengths.sum(axis=1, keepdims=True)
    return lengths / np.where(perimeter > 0, perimeter, 1.0)


def _halfedges(faces):
    """dict (a, b) -> (face, opposite corner c) for every directed edge a->b of face (a, b, c)."""
    f = faces.tolist()
    out = {}
    for i, (a, b, c) in enumerate(f):
        out.setdefault((a, b), (i, c))
        out.setdefault((b, c), (i, a))
        out.setdefault((c, a), (i, b))
    return out


def _propagate(ref_faces_list, ref_he, mesh_he, n_ref, n_mesh, seed_face, seed_image, vmap, used, visited):  # noqa: ARG001
    """Grow ``vmap`` (ref -> mesh) from one seed face pair over shared edges.  False on any conflict."""
    def bind(r, m) -> bool:
        """Map reference vertex r to mesh vertex m; False if either is already bound elsewhere."""
        if vmap[r] == -1:
            if used[m]:
                return False
            vmap[r] = m
            used[m] = True
            return True
        return vmap[r] == m

    a, b, c = ref_faces_list[seed_face]
    if not all(bind(r, m) for r, m in zip((a, b, c), seed_image)):
        return False
    if (seed_image[0], seed_image[1]) not in mesh_he:
        return False
    visited[seed_face] = True
    queue = deque([seed_face])
    while queue:
        f = queue.popleft()
        x, y, z = ref_faces_list[f]
        for p, q in ((x, y), (y, z), (z, x)):
            twin = ref_he.get((q, p))
            if twin is None:
                continue  # boundary edge
            g, d = twin
            hit = mesh_he.get((vmap[q], vmap[p]))
            if hit is None:
                return False
            if not bind(d, hit[1]):
                return False
            if not visited[g]:
                visited[g] = True
                queue.append(g)
    return True


#: a component whose propagated map fits a similarity within this fraction of its size is taken at once
EXACT_FIT = 1e-5
#: the best fit found must be within this fraction of the component's size (noise, smoothing) to be taken at all
LOOSE_FIT = 0.2


def _fit_error(ref_positions, positions, r_idx, m_idx) -> float:
    """RMS residual of the best similarity ``positions[m_idx] ~ s R ref_positions[r_idx] + t``.

    In units of the reference points' RMS spread (scale-free); mirror images allowed.
    """
    src, dst = ref_positions[r_idx], positions[m_idx]
    if len(r_idx) < 3:
        return 0.0
    spread = np.sqrt(((src - src.mean(0)) ** 2).sum(1).mean()) or 1.0
    best = np.inf
    for mirrored in (False, True):  # a mirrored copy keeps the connectivity, so both are candidates
        s, R, t = umeyama(src, dst, reflection=mirrored)
        if s > 0:
            resid = np.linalg.norm(dst - (s * src @ R.T + t), axis=1)
            best = min(best, float(np.sqrt((resid**2).mean()) / s / spread))
    return best


def match_topology(positions, faces, ref_positions, ref_faces, *, seeds: int = 6, candidates: int = 24):
    """Vertex permutation ``index`` (n_ref,) with ``faces`` == ``index[ref_faces]`` as face sets, or None.

    Works component by component: for an unmapped reference face, the mesh faces
    (in each of their 3 corner rotations) whose scale-free edge-length
    descriptors are nearest are tried as its image.  A seed that propagates
    without conflict is still only one automorphism of the connectivity (a
    regular torus has hundreds), so the component's map must also be a
    similarity of the geometry: the first map whose fit error is below
    :data:`EXACT_FIT` is taken, otherwise the best one below :data:`LOOSE_FIT`.
    The final face sets must agree exactly.
    """
    faces = np.asarray(faces, np.int64)
    ref_faces = np.asarray(ref_faces, np.int64)
    positions = np.asarray(positions, np.float64)
    ref_positions = np.asarray(ref_positions, np.float64)
    n_ref, n_mesh = len(ref_positions), len(positions)
    if n_ref != n_mesh or faces.shape != ref_faces.shape or len(faces) == 0:
        return None
    dref = _face_descriptors(ref_positions, ref_faces)
    dm = _face_descriptors(positions, faces)
    rot = np.concatenate([dm, np.roll(dm, -1, axis=1), np.roll(dm, -2, axis=1)])  # rotation r: corner r first
    tree = cKDTree(rot)
    rot_faces = np.concatenate([faces, np.roll(faces, -1, axis=1), np.roll(faces, -2, axis=1)])
    ref_list = ref_faces.tolist()
    ref_he, mesh_he = _halfedges(ref_faces), _halfedges(faces)
    # plain Python lists for the hot loop
    state = ([-1] * n_ref, [False] * n_mesh, [False] * len(faces))
    rng = np.random.default_rng(0)
    while True:
        todo = np.flatnonzero(~np.asarray(state[2], bool))
        if len(todo) == 0:
            break
        tried = np.r_[todo[:1], rng.choice(todo, size=min(seeds, len(todo)), replace=False)]
        best = (np.inf, None)
        for f in tried:
            _, hits = tree.query(dref[f], k=min(candidates, len(rot)))
            for h in np.atleast_1d(hits):
                trial = (list(state[0]), list(state[1]), list(state[2]))
                if not _propagate(ref_list, ref_he, mesh_he, n_ref, n_mesh, int(f), rot_faces[h].tolist(), *trial):
                    continue
                new = np.flatnonzero((np.asarray(trial[0]) >= 0) & (np.asarray(state[0]) < 0))
                err = _fit_error(ref_positions, positions, new, np.asarray(trial[0])[new])
                if err < best[0]:
                    best = (err, trial)
                if err < EXACT_FIT:
                    break
            if best[0] < EXACT_FIT:
                break
        if best[1] is None or not best[0] < LOOSE_FIT:
            return None
        state = best[1]
    vmap = np.asarray(state[0], dtype=np.int64)
    if np.any(vmap < 0):
        return None
    if not same_face_set(vmap[ref_faces], faces):
        return None
    return vmap


def _permutation(pos, fac, ref, rfac):
    """:func:`match_topology` of the faces as they are wound, or reversed (an exporter that flips every face):
    a map the geometry does not fit exactly is only one automorphism of the connectivity (an orientation
    reversing one, on a mesh whose faces were flipped: a near-symmetric sphere's mirror fit ``LOOSE_FIT``), so the
    other winding is tried too and the better fit kept.  ``(n_ref,)`` int64 or None."""
    every = np.arange(len(ref))
    best, best_error = None, np.inf
    for wound in (fac, fac[:, ::-1]):
        vmap = match_topology(pos, wound, ref, rfac)
        if vmap is not None:
            error = _fit_error(ref, pos, every, vmap)
            if error < best_error:
                best, best_error = vmap, error
            if error < EXACT_FIT:
                break
    return best


# --------------------------------------------------------------- registration


def umeyama(src: np.ndarray, dst: np.ndarray, *, reflection: bool = False):
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991): returns ``(s, R, t)``.

    ``reflection``: allow det R = -1 (a mirrored copy).
    """
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var = (xs * xs).sum() / len(src)
    if var <= 0:
        return 1.0, np.eye(3), mu_d - mu_s
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.ones(3)
    want = -1.0 if reflection else 1.0
    if np.linalg.det(U) * np.linalg.det(Vt) * want < 0:
        S[2] = -1.0
    R = U @ np.diag(S) @ Vt
    s = float((D * S).sum() / var)
    t = mu_d - s * R @ mu_s
    return s, R, t


def _pca(points):
    c = points.mean(0)
    x = points - c
    radius = float(np.sqrt((x * x).sum(1).mean()))
    w, v = np.linalg.eigh(x.T @ x / len(x))
    return c, radius, v[:, ::-1]  # columns by decreasing variance


def _hypotheses(positions, ref_positions):
    """Candidate similarities (s, R, t) mapping the mesh into the reference frame."""
    out = [(1.0, np.eye(3), np.zeros(3))]
    cm, rm, vm = _pca(positions)
    cr, rr, vr = _pca(ref_positions)
    s = rr / rm if rm > 0 else 1.0
    for signs in np.array(np.meshgrid([1, -1], [1, -1], [1, -1])).reshape(3, -1).T:
        R = vr @ np.diag(signs) @ vm.T
        out.append((s, R, cr - s * R @ cm))
    return out


def _triangle_hypotheses(positions, faces, ref_positions, ref_faces, *, count: int, seed: int):
    """Similarities from single triangle pairs with matching scale-free shapes (RANSAC seeds).

    Descriptor of a face in corner order: (|e1|, |e2|) / |e0|.  A few random mesh
    faces (in their 3 corner rotations) are looked up among the reference faces;
    each nearest pair gives a similarity from its three corners (and the normal).
    """
    if faces is None or ref_faces is None or len(faces) == 0 or len(ref_faces) == 0:
        return []
    pos = np.asarray(positions, np.float64)
    ref = np.asarray(ref_positions, np.float64)
    dr = _face_descriptors(ref, ref_faces)
    ok = dr[:, 0] > 0
    rf = np.asarray(ref_faces, np.int64)[ok]
    key_r = dr[ok][:, 1:] / dr[ok][:, :1]
    if len(rf) == 0:
        return []
    tree = cKDTree(key_r)
    rng = np.random.default_rng(seed)
    f = np.asarray(faces, np.int64)
    pick = f[rng.choice(len(f), size=min(count, len(f)), replace=False)]
    out = []
    for r in range(3):
        g = np.roll(pick, -r, axis=1)
        dm = _face_descriptors(pos, g)
        good = dm[:, 0] > 0
        if not good.any():
            continue
        g, dm = g[good], dm[good]
        _, j = tree.query(dm[:, 1:] / dm[:, :1])
        for a, b in zip(g, rf[j]):
            pa, pb = pos[a], ref[b]
            na = np.cross(pa[1] - pa[0], pa[2] - pa[0])
            nb = np.cross(pb[1] - pb[0], pb[2] - pb[0])
            la, lb = np.linalg.norm(na), np.linalg.norm(nb)
            if la <= 0 or lb <= 0:
                continue
            ea = np.linalg.norm(pa[1] - pa[0])
            eb = np.linalg.norm(pb[1] - pb[0])
            src = np.vstack([pa, pa.mean(0) + na / la * ea])
            dst = np.vstack([pb, pb.mean(0) + nb / lb * eb])
            out.append(umeyama(src, dst))
    return out


def register(positions, ref_positions, *, unit: float, faces=None, ref_faces=None, iterations: int = 40,
             sample: int = 4000, triangles: int = 40, seed: int = 0):
    """Similarity ``(s, R, t, score)`` mapping ``positions`` onto ``ref_positions``.

    Hypotheses: identity, principal axes (8 sign choices), and -- given the faces
    -- single-triangle matches (a crop of a moved mesh, where principal axes
    fail).  Each is scored by the fraction of sampled mesh vertices within
    ``unit / 4`` of a reference vertex (ties: median distance); the best is
    refined by trimmed ICP.  ``unit`` is a reference length (its mean edge);
    ``score`` is the final median mesh->reference distance / unit.
    """
    pos = np.asarray(positions, np.float64)
    ref = np.asarray(ref_positions, np.float64)
    tree = cKDTree(ref)
    rng = np.random.default_rng(seed)
    pick = pos if len(pos) <= sample else pos[rng.choice(len(pos), sample, replace=False)]
    small = pick if len(pick) <= 500 else pick[rng.choice(len(pick), 500, replace=False)]
    hyps = _hypotheses(pos, ref) + _triangle_hypotheses(pos, faces, ref, ref_faces, count=triangles, seed=seed)
    best = None
    for s, R, t in hyps:
        if not (np.isfinite(s) and s > 0 and np.isfinite(R).all() and np.isfinite(t).all()):
            continue
        d, _ = tree.query(s * small @ R.T + t)
        score = (-float(np.mean(d <= 0.25 * unit)), float(np.median(d)))
        if best is None or score < best[3]:
            best = (s, R, t, score)
    s, R, t, _ = best
    reflect = bool(np.linalg.det(R) < 0)
    for _ in range(iterations):
        moved = s * pick @ R.T + t
        d, j = tree.query(moved)
        cut = max(3.0 * float(np.median(d)), 1e-12 * unit)
        keep = d <= cut
        if keep.sum() < 4:
            break
        s2, R2, t2 = umeyama(pick[keep], ref[j[keep]], reflection=reflect)
        change = float(np.abs(s2 * pick[keep] @ R2.T + t2 - moved[keep]).max())
        s, R, t = s2, R2, t2
        if change <= 1e-9 * unit:
            break
    d, _ = tree.query(s * pick @ R.T + t)
    return s, R, t, float(np.median(d)) / unit


# ---------------------------------------------------------------------- entry


def exact_correspondence(positions, faces, ref_positions, ref_faces) -> Correspondence | None:
    """:func:`correspond`'s topological methods alone (``identity``, ``faces-reordered``, ``permutation``):
    the bijection they find, or None when the mesh is not the reference's connectivity (arguments as there)."""
    pos = np.asarray(positions, np.float64)
    fac = np.asarray(faces, np.int64)
    ref = np.asarray(ref_positions, np.float64)
    rfac = np.asarray(ref_faces, np.int64)
    n_ref = len(ref)
    if len(pos) != n_ref or fac.shape != rfac.shape:
        return None
    ident = np.arange(n_ref, dtype=np.int64)
    if np.array_equal(fac, rfac):
        return Correspondence("identity", ident, np.ones(n_ref, bool))
    if same_face_set(fac, rfac) or same_face_set(fac[:, ::-1], rfac):
        return Correspondence("faces-reordered", ident, np.ones(n_ref, bool))
    vmap = _permutation(pos, fac, ref, rfac)
    return None if vmap is None else Correspondence("permutation", vmap, np.ones(n_ref, bool))


def correspond(positions, faces, ref_positions, ref_faces, *, tolerance: float = 0.5,
               topology: bool = True) -> Correspondence:
    """Map every reference vertex to a mesh vertex (see the module docstring).

    Parameters
    ----------
    positions, faces : the mesh (n, 3) float, (m, 3) int
    ref_positions, ref_faces : the reference full decode
    tolerance : registration only: a pair is valid within ``tolerance`` x the
        reference's mean edge length
    topology : try the exact (topological) methods first
    """
    pos = np.asarray(positions, np.float64)
    fac = np.asarray(faces, np.int64)
    ref = np.asarray(ref_positions, np.float64)
    rfac = np.asarray(ref_faces, np.int64)
    if topology:
        exact = exact_correspondence(pos, fac, ref, rfac)
        if exact is not None:
            return exact
    unit = mean_edge_length(ref, rfac) or 1.0
    s, R, t, _ = register(pos, ref, unit=unit, faces=fac, ref_faces=rfac)
    moved = s * pos @ R.T + t
    d, j = cKDTree(moved).query(ref)
    valid = d <= tolerance * unit
    rms = float(np.sqrt(np.mean(d[valid] ** 2))) if valid.any() else None
    index = np.where(valid, j, -1).astype(np.int64)
    return Correspondence("registration", index, valid, float(s), R, t, rms, d)
