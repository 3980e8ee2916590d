"""The triangle mesh every part of the package exchanges, and reading it from disk.

A :class:`Mesh` is a plain container of numpy arrays with no I/O methods:

``positions`` : (n, 3) float64
    Vertex coordinates.
``faces`` : (m, 3) int64
    Counter-clockwise vertex indices into ``positions``.
``attributes`` : dict[str, (n, k) array]
    Optional per-vertex attributes (glTF semantic names: ``NORMAL``,
    ``TEXCOORD_0`` ...), one row per vertex.

:func:`checked_mesh` is the single gate through which outside data enters:
NaN/inf coordinates, out-of-range indices and empty meshes are named errors
(:class:`~pmwm_codec.errors.MeshError`); degenerate faces and unreferenced
vertices are dropped and counted in :attr:`Mesh.cleanup`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .errors import InputFormatError, MeshError

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")


@dataclass
class Mesh:
    """A triangle mesh: ``positions`` (n, 3) float64, ``faces`` (m, 3) int64."""

    positions: np.ndarray
    faces: np.ndarray
    attributes: dict = field(default_factory=dict)
    #: What :func:`checked_mesh` dropped: ``{"degenerate_faces": k, "unreferenced_vertices": j}``.
    cleanup: dict = field(default_factory=dict)

    @property
    def vertex_count(self) -> int:
        return int(self.positions.shape[0])

    @property
    def face_count(self) -> int:
        return int(self.faces.shape[0])

    def bbox_diagonal(self) -> float:
        """Length of the axis-aligned bounding box diagonal (float)."""
        if self.vertex_count == 0:
            return 0.0
        return float(np.linalg.norm(self.positions.max(0) - self.positions.min(0)))

    def __repr__(self) -> str:
        return f"Mesh({self.vertex_count} vertices, {self.face_count} faces)"


def checked_mesh(positions, faces, attributes=None, *, name="mesh") -> Mesh:
    """Validate raw arrays and return a clean :class:`Mesh`.

    Parameters
    ----------
    positions : (n, 3) array_like of float
    faces : (m, 3) array_like of int
    attributes : dict of (n, k) arrays, optional
    name : str
        Used in error messages (usually the file name).

    Raises
    ------
    MeshError
        Empty mesh, wrong shapes, NaN/inf coordinates, face index out of range.
    """
    try:
        pos = np.asarray(positions, dtype=np.float64)
        tri = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"{name}: vertex or face data is not numeric ({exc})") from None
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0:
        raise MeshError(f"{name}: the mesh has no vertices")
    if tri.size == 0:
        raise MeshError(f"{name}: the mesh has no triangles")
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise MeshError(f"{name}: faces must be triangles, got shape {tri.shape}")
    if not np.issubdtype(tri.dtype, np.integer):
        if not np.all(np.equal(np.mod(tri, 1), 0)):
            raise MeshError(f"{name}: face indices are not integers")
    tri = tri.astype(np.int64)
    bad = ~np.isfinite(pos).all(axis=1)
    if bad.any():
        raise MeshError(
            f"{name}: {int(bad.sum())} vertices have NaN or infinite coordinates "
            f"(first at vertex {int(np.argmax(bad))})"
        )
    n = pos.shape[0]
    if tri.min() < 0 or tri.max() >= n:
        worst = int(tri.max()) if tri.max() >= n else int(tri.min())
        raise MeshError(f"{name}: face index {worst} out of range for {n} vertices")

    attrs = {}
    for key, value in (attributes or {}).items():
        arr = np.asarray(value)
        if arr.shape[0] != n:
            raise MeshError(f"{name}: attribute {key} has {arr.shape[0]} rows for {n} vertices")
        attrs[key] = arr

    degenerate = (tri[:, 0] == tri[:, 1]) | (tri[:, 1] == tri[:, 2]) | (tri[:, 0] == tri[:, 2])
    tri = tri[~degenerate]
    if tri.shape[0] == 0:
        raise MeshError(f"{name}: every triangle is degenerate")
    used = np.zeros(n, dtype=bool)
    used[tri.ravel()] = True
    unreferenced = int(n - used.sum())
    if unreferenced:
        remap = np.cumsum(used) - 1
        tri = remap[tri]
        pos = pos[used]
        attrs = {k: v[used] for k, v in attrs.items()}
    cleanup = {}
    if degenerate.any():
        cleanup["degenerate_faces"] = int(degenerate.sum())
    if unreferenced:
        cleanup["unreferenced_vertices"] = unreferenced
    return Mesh(np.ascontiguousarray(pos), np.ascontiguousarray(tri), attrs, cleanup)


def read_mesh(path) -> Mesh:
    """Read a triangle mesh from OBJ, PLY, STL, glTF or GLB.

    Polygons are fan-triangulated; STL triangle soups have identical corners
    merged.  For glTF/GLB the triangle primitives of the default scene are merged
    into one mesh with node transforms applied (the asset pipeline keeps the
    document structure; this function only wants geometry).

    Raises
    ------
    InputFormatError
        Missing file, unknown suffix, or a file that does not parse as a mesh.
    MeshError
        See :func:`checked_mesh`.
    """
    path = os.fspath(path)
    name = os.path.basename(path)
    if not os.path.exists(path):
        raise InputFormatError(f"{path}: no such file")
    if os.path.isdir(path):
        raise InputFormatError(f"{path}: is a directory, not a mesh file")
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in MESH_SUFFIXES:
        raise InputFormatError(
            f"{name}: unknown mesh format {suffix or '(no suffix)'!r}; expected one of "
            + ", ".join(MESH_SUFFIXES)
        )
    if suffix == ".obj":
        positions, faces = _read_obj(path, name)
        return checked_mesh(positions, faces, name=name)
    return _read_with_trimesh(path, name, suffix)


def _read_obj(path, name):
    """Parse ``v`` and ``f`` records of a Wavefront OBJ; returns float64 and int64 arrays."""
    verts = []
    polys = []
    try:
        with open(path, "rb") as fh:
            data = fh.read()
        text = data.decode("utf-8", errors="strict")
    except UnicodeDecodeError:
        raise InputFormatError(f"{name}: not a text OBJ file") from None
    try:
        for line in text.splitlines():
            if line.startswith("v "):
                parts = line.split()
                verts.append((float(parts[1]), float(parts[2]), float(parts[3])))
            elif line.startswith("f "):
                idx = [int(tok.split("/", 1)[0]) for tok in line.split()[1:]]
                polys.append(idx)
    except (ValueError, IndexError):
        raise InputFormatError(f"{name}: malformed OBJ record: {line.strip()[:60]!r}") from None
    if not verts or not polys:
        raise MeshError(f"{name}: the mesh has no vertices or no faces")
    n = len(verts)
    tris = []
    for idx in polys:
        if len(idx) < 3:
            raise InputFormatError(f"{name}: a face with fewer than 3 vertices")
        fixed = [i - 1 if i > 0 else n + i for i in idx]
        for k in range(1, len(fixed) - 1):
            tris.append((fixed[0], fixed[k], fixed[k + 1]))
    return np.array(verts, dtype=np.float64), np.array(tris, dtype=np.int64)


def _read_with_trimesh(path, name, suffix):
    import trimesh

    try:
        loaded = trimesh.load(path, process=False, force=None)
    except Exception as exc:  # trimesh raises many types on garbage
        raise InputFormatError(f"{name}: cannot read as {suffix[1:].upper()}: {exc}".splitlines()[0]) from None
    if isinstance(loaded, trimesh.Scene):
        geoms = [g for g in loaded.dump(concatenate=False) if isinstance(g, trimesh.Trimesh)]
        if not geoms:
            raise MeshError(f"{name}: the file holds no triangle mesh")
        loaded = trimesh.util.concatenate(geoms) if len(geoms) > 1 else geoms[0]
    if not isinstance(loaded, trimesh.Trimesh):
        raise MeshError(f"{name}: the file holds no triangle mesh")
    positions = np.asarray(loaded.vertices, dtype=np.float64)
    faces = np.asarray(loaded.faces, dtype=np.int64)
    if suffix == ".stl" and faces.size:
        positions, inverse = np.unique(positions, axis=0, return_inverse=True)
        faces = inverse.reshape(-1)[faces]
    return checked_mesh(positions, faces, name=name)
