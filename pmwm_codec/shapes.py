"""Meshes the package makes itself: for tests, the demo and benchmarks.

Every function returns a :class:`~pmwm_codec.mesh.Mesh` with float64
positions and int64 counter-clockwise faces (outward normals for closed shapes).
"""

from __future__ import annotations

import numpy as np

from .mesh import Mesh


def icosphere(subdivisions: int = 3, radius: float = 1.0, *, noise: float = 0.0, seed: int = 0) -> Mesh:
    """A closed sphere from a subdivided icosahedron; ``noise`` jitters radii (fraction)."""
    t = (1.0 + 5 ** 0.5) / 2.0
    verts = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )
    faces = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )
    for _ in range(subdivisions):
        verts, faces = _midpoint_subdivide(verts, faces)
        verts /= np.linalg.norm(verts, axis=1)[:, None]
    verts = verts / np.linalg.norm(verts, axis=1)[:, None]
    if noise:
        rng = np.random.default_rng(seed)
        verts *= 1.0 + noise * rng.uniform(-1, 1, (len(verts), 1))
    return Mesh(verts * radius, faces)


def _midpoint_subdivide(verts, faces):
    """Split every triangle into four; shared edge midpoints are shared vertices."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lo, hi = e.min(1), e.max(1)
    key = lo * len(verts) + hi
    uniq, inv = np.unique(key, return_inverse=True)
    mid = len(verts) + inv.reshape(3, -1).T  # (m, 3): midpoint of edge 01, 12, 20
    ulo, uhi = uniq // len(verts), uniq % len(verts)
    new_verts = np.concatenate([verts, 0.5 * (verts[ulo] + verts[uhi])])
    a, b, c = faces.T
    ab, bc, ca = mid.T
    new_faces = np.concatenate(
        [np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1), np.stack([c, ca, bc], 1), np.stack([ab, bc, ca], 1)]
    )
    return new_verts, new_faces


def torus(rings: int = 48, sides: int = 24, major: float = 1.0, minor: float = 0.35, *, twist: float = 0.0) -> Mesh:
    """A closed torus of ``rings * sides`` vertices; ``twist`` adds a ripple to the tube."""
    i, j = np.meshgrid(np.arange(rings), np.arange(sides), indexing="ij")
    th = 2 * np.pi * i / rings
    ph = 2 * np.pi * j / sides
    r = minor * (1.0 + twist * np.sin(5 * th + 3 * ph))
    x = (major + r * np.cos(ph)) * np.cos(th)
    y = (major + r * np.cos(ph)) * np.sin(th)
    z = r * np.sin(ph)
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    i0 = i * sides + j
    i1 = ((i + 1) % rings) * sides + j
    i2 = ((i + 1) % rings) * sides + (j + 1) % sides
    i3 = i * sides + (j + 1) % sides
    faces = np.concatenate([np.stack([i0, i1, i2], -1).reshape(-1, 3), np.stack([i0, i2, i3], -1).reshape(-1, 3)])
    return Mesh(verts, faces.astype(np.int64))


def grid(nx: int = 30, ny: int = 30, *, hole: bool = True, bump: float = 0.2) -> Mesh:
    """An open height-field grid, optionally with a square hole in the middle."""
    x, y = np.meshgrid(np.linspace(-1, 1, nx), np.linspace(-1, 1, ny), indexing="ij")
    z = bump * np.sin(2.5 * x) * np.cos(2.0 * y)
    verts = np.stack([x, y, z], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(nx - 1), np.arange(ny - 1), indexing="ij")
    a = i * ny + j
    b = (i + 1) * ny + j
    c = (i + 1) * ny + j + 1
    d = i * ny + j + 1
    quads = np.stack([a, b, c, d], -1).reshape(-1, 4)
    if hole:
        ci, cj = i.ravel(), j.ravel()
        keep = ~((np.abs(ci - (nx - 2) / 2) < nx / 6) & (np.abs(cj - (ny - 2) / 2) < ny / 6))
        quads = quads[keep]
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    used = np.unique(faces)
    remap = np.full(len(verts), -1)
    remap[used] = np.arange(len(used))
    return Mesh(verts[used], remap[faces].astype(np.int64))


def components(*meshes: Mesh, spacing: float = 3.0) -> Mesh:
    """Several meshes side by side as one mesh of separate components."""
    verts, faces, off = [], [], 0
    for k, mesh in enumerate(meshes):
        verts.append(mesh.positions + np.array([spacing * k, 0.0, 0.0]))
        faces.append(mesh.faces + off)
        off += mesh.vertex_count
    return Mesh(np.concatenate(verts), np.concatenate(faces))


def kissing(count: int = 3, subdivisions: int = 2) -> Mesh:
    """``count`` icospheres around the origin, each touching it with a vertex of its own: distinct vertices on
    one point (not welded, as a scan's touching pieces come), which stay in the base as seam copies do.
    A Draco base tells them apart by its weld attribute (spec README, "Welded base")."""
    parts = []
    for k in range(count):
        sphere = icosphere(subdivisions, 1.0, noise=0.02, seed=k)
        tip = int(np.argmin(sphere.positions[:, 2]))
        angle = 2 * np.pi * k / count
        c, s = np.cos(angle), np.sin(angle)
        turn = np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) if k else np.eye(3)
        pts = (sphere.positions - sphere.positions[tip]) @ turn.T
        pts[tip] = 0.0  # exactly on the shared point
        parts.append(Mesh(pts, sphere.faces))
    verts, faces, off = [], [], 0
    for part in parts:
        verts.append(part.positions)
        faces.append(part.faces + off)
        off += part.vertex_count
    return Mesh(np.concatenate(verts), np.concatenate(faces).astype(np.int64))


def bowtie() -> Mesh:
    """Non-manifold test piece: two fans sharing one vertex, plus a fin (an edge with three faces)."""
    sphere_a = icosphere(2, 1.0)
    sphere_b = icosphere(2, 1.0)
    # place b so that its "south pole" vertex coincides with a's "north pole" vertex
    pa = int(np.argmax(sphere_a.positions[:, 2]))
    pb = int(np.argmin(sphere_b.positions[:, 2]))
    shift = sphere_a.positions[pa] - sphere_b.positions[pb]
    vb = sphere_b.positions + shift
    n_a = sphere_a.vertex_count
    remap = np.arange(sphere_b.vertex_count) + n_a
    remap[pb] = pa
    keep_b = np.ones(sphere_b.vertex_count, bool)
    keep_b[pb] = False
    new_index = np.cumsum(keep_b) - 1 + n_a
    remap[keep_b] = new_index[keep_b]
    verts = np.concatenate([sphere_a.positions, vb[keep_b]])
    faces = np.concatenate([sphere_a.faces, remap[sphere_b.faces]])
    # a fin: a third face on one edge of sphere a
    e0, e1 = sphere_a.faces[0, 0], sphere_a.faces[0, 1]
    tip = len(verts)
    mid = 0.5 * (sphere_a.positions[e0] + sphere_a.positions[e1])
    verts = np.concatenate([verts, (mid * 1.8)[None]])
    faces = np.concatenate([faces, np.array([[e0, e1, tip]])])
    return Mesh(verts, faces.astype(np.int64))


def _rings(faces: np.ndarray, n: int) -> list:
    """Each vertex's neighbours: a list of ``n`` sets of vertex ids, from ``faces`` (m, 3) int."""
    ring = [set() for _ in range(n)]
    for a, b, c in np.asarray(faces).tolist():
        ring[a] |= {b, c}
        ring[b] |= {a, c}
        ring[c] |= {a, b}
    return ring


def doubled_faces(pillows: int = 12) -> Mesh:
    """An icosphere with up to ``pillows`` doubled triangles (two faces on the same three vertices,
    facing opposite ways), as volumetric scan reconstructions leave them.

    Each pillow joins two surface vertices ``u``, ``v`` two edges apart (one common neighbour)
    to a tip of its own; ``u`` sits close to ``v``, so collapsing ``u`` onto ``v`` is cheap and
    passes the counting tests (common neighbours = faces on ``uv``).  Every edge is manifold."""
    sphere = icosphere(3, 1.0, noise=0.02)
    V, F = sphere.positions.copy(), sphere.faces
    ring = _rings(F, len(V))
    taken, pairs = set(), []
    for u in range(0, len(V), 7):
        far = {v for x in ring[u] for v in ring[x]} - ring[u] - {u}
        v = next((v for v in sorted(far) if len(ring[u] & ring[v]) == 1 and not (ring[u] | ring[v] | {u, v}) & taken), None)
        if v is not None and len(pairs) < pillows:
            pairs.append((u, v))
            taken |= ring[u] | ring[v] | {u, v}
    u, v = np.array(pairs, np.int64).T
    V[u] = 0.35 * V[u] + 0.65 * V[v]
    w = len(V) + np.arange(len(pairs))
    doubled = np.concatenate([np.stack([u, v, w], 1), np.stack([v, u, w], 1)])
    return Mesh(np.concatenate([V, 0.505 * (V[u] + V[v])]), np.concatenate([F, doubled]).astype(np.int64))


def flaps(count: int = 12) -> Mesh:
    """An icosphere with up to ``count`` flaps: doubled triangles (two faces on the same three
    vertices, facing opposite ways) glued onto a surface edge ``ab``, with a tip of their own just
    off the surface, as the VRIP dragons carry them by the hundred.  Edge ``ab`` has four faces,
    ``a`` and ``b`` two faces more than their disk; no two flaps share a vertex or a neighbour."""
    sphere = icosphere(3, 1.0, noise=0.02)
    V, F = sphere.positions, sphere.faces
    ring = _rings(F, len(V))
    taken, edges = set(), []
    for a, b, _ in F[::5].tolist():
        if len(edges) < count and not (ring[a] | ring[b]) & taken:
            edges.append((a, b))
            taken |= ring[a] | ring[b] | {a, b}
    a, b = np.array(edges, np.int64).T
    tip = len(V) + np.arange(len(edges))
    mid = 0.5 * (V[a] + V[b])
    out = mid * 1.08  # just outside the unit sphere
    doubled = np.concatenate([np.stack([a, b, tip], 1), np.stack([b, a, tip], 1)])
    return Mesh(np.concatenate([V, out]), np.concatenate([F, doubled]).astype(np.int64))


def pillows(count: int = 12) -> Mesh:
    """An icosphere with up to ``count`` pillows, two faces on one vertex triple facing opposite ways,
    as the VRIP dragons carry them by the hundred: alternately glued along two surface edges ``a-b``
    and ``b-c`` (``a``, ``c`` not adjacent: ``a-c`` is the pillow's own edge) and flaps on a surface
    edge ``a-b`` with a tip of their own just off the surface.  No two pillows share a vertex or a
    neighbour."""
    sphere = icosphere(3, 1.0, noise=0.02)
    V, F = sphere.positions, sphere.faces
    ring = _rings(F, len(V))
    taken, triples, tips = set(), [], []
    for a in range(0, len(V), 5):
        b = min(ring[a])
        far = sorted(ring[b] - ring[a] - {a})
        if len(triples) < count and far and not (ring[a] | ring[b] | ring[far[0]]) & taken:
            if len(triples) % 2:  # a flap: a new tip off edge a-b
                tips.append(0.54 * (V[a] + V[b]))
                triples.append((a, b, len(V) + len(tips) - 1))
            else:
                triples.append((a, b, far[0]))
            taken |= ring[a] | ring[b] | ring[far[0]]
    a, b, c = np.array(triples, np.int64).T
    doubled = np.concatenate([np.stack([a, b, c], 1), np.stack([b, a, c], 1)])
    return Mesh(np.concatenate([V, np.array(tips).reshape(-1, 3)]), np.concatenate([F, doubled]).astype(np.int64))


def specks(mesh: Mesh | None = None, count: int = 2, size: float = 1e-7, seed: int = 0) -> Mesh:
    """``mesh`` (default: an icosphere) with ``count`` *specks*, triangles ``size`` across at random
    points of its bounding box, every second one with its reverse face: the lone specks of a scan,
    smaller than a grid step (each falls on one grid point)."""
    mesh = icosphere(3, 1.0, noise=0.02) if mesh is None else mesh
    rng = np.random.default_rng(seed)
    lo, hi = mesh.positions.min(axis=0), mesh.positions.max(axis=0)
    positions, faces, n = [mesh.positions], [mesh.faces], mesh.vertex_count
    for j in range(count):
        positions.append(lo + (hi - lo) * rng.random(3) + size * np.eye(3))
        faces.append([[n, n + 1, n + 2]] + ([[n, n + 2, n + 1]] if j % 2 else []))
        n += 3
    return Mesh(np.concatenate(positions), np.concatenate(faces).astype(np.int64))


def demo_mesh(resolution: int = 180) -> Mesh:
    """A rippled torus knot-like shape with tens of thousands of vertices, for the demo."""
    rings, sides = resolution * 2, resolution // 2
    t = torus(rings, sides, 1.0, 0.32, twist=0.18)
    p = t.positions.copy()
    ang = np.arctan2(p[:, 1], p[:, 0])
    p[:, 2] += 0.35 * np.sin(3 * ang)
    return Mesh(p, t.faces)


def uv_torus(rings: int = 32, sides: int = 16, *, twist: float = 0.1) -> Mesh:
    """:func:`torus` with a TEXCOORD_0 and its two UV seams, as a glTF exporter splits it.

    The wrap-around row and column are separate vertices (``(rings + 1) * (sides + 1)``)
    at the same positions as the first ones, with u = 1 / v = 1; the two seam loops
    cross at one position with four copies.  The welded surface is closed.
    """
    t = torus(rings, sides, twist=twist)
    a, b = np.meshgrid(np.arange(rings + 1), np.arange(sides + 1), indexing="ij")
    source = (a % rings) * sides + b % sides
    uv = np.stack([a / rings, b / sides], -1).reshape(-1, 2)
    i0 = a[:-1, :-1] * (sides + 1) + b[:-1, :-1]
    i1, i3 = i0 + sides + 1, i0 + 1
    i2 = i1 + 1
    faces = np.concatenate([np.stack([i0, i1, i2], -1).reshape(-1, 3), np.stack([i0, i2, i3], -1).reshape(-1, 3)])
    return Mesh(t.positions[source.reshape(-1)], faces.astype(np.int64), attributes={"TEXCOORD_0": uv})


def faceted_cube(k: int = 9, *, bump: float = 0.0) -> Mesh:
    """A cube of six ``k x k`` vertex grids with a NORMAL per face (hard edges split the vertices).

    Vertices on the cube's edges have two copies, its corners three; the welded surface is
    closed.  ``bump`` pushes each face's interior outwards (a dome; edges stay straight).
    """
    s = np.linspace(-1.0, 1.0, k)
    si, ti = np.meshgrid(s, s, indexing="ij")
    verts, normals, faces = [], [], []
    for axis in range(3):
        for sign in (1.0, -1.0):
            n = np.zeros(3)
            n[axis] = sign
            t1 = np.zeros(3)
            t1[(axis + 1) % 3] = 1.0
            t2 = np.cross(n, t1)
            dome = bump * (1 - si**2) * (1 - ti**2)
            p = (1.0 + dome)[..., None] * n + si[..., None] * t1 + ti[..., None] * t2
            base = len(verts) * k * k
            i0 = base + np.arange(k - 1)[:, None] * k + np.arange(k - 1)[None, :]
            faces.append(np.stack([i0, i0 + k, i0 + k + 1], -1).reshape(-1, 3))
            faces.append(np.stack([i0, i0 + k + 1, i0 + 1], -1).reshape(-1, 3))
            verts.append(p.reshape(-1, 3) + 0.0)
            normals.append(np.tile(n, (k * k, 1)))
    return Mesh(np.concatenate(verts), np.concatenate(faces).astype(np.int64),
                attributes={"NORMAL": np.concatenate(normals)})
