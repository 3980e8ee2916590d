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
import re
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from .constants import MAX_ENCODE_FACES, MAX_ENCODE_VERTICES, MAX_GRID_BITS, MAX_INPUT_FILE_BYTES
from .errors import DegenerateMeshError, InputFormatError, MeshError
from .progressive.topology import SMALL_JOB_VERTICES, compiled, two_alike
from .sources import bom_codec, check_input_path, path_argument, read_regular_file

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


@dataclass
class Mesh:
    """A triangle mesh: ``positions`` (n, 3) and ``faces`` (m, 3), float64 and int64 as the readers and
    :func:`checked_mesh` make them (a Mesh built by hand keeps the arrays it is given, float32 / int32 too)."""

    positions: np.ndarray
    faces: np.ndarray
    attributes: dict = field(default_factory=dict)
    #: What :func:`checked_mesh` dropped: ``{"degenerate_faces": k, "unreferenced_vertices": j}``, and what the
    #: file reader left out (``duplicate_soup_vertices``, a glTF's ``primitives_of_points_or_lines`` and
    #: ``gpu_instanced_meshes``, an OBJ's ``line_and_point_records``) or placed otherwise than a viewer draws it (a
    #: glTF's ``skinned_meshes_moved_by_their_nodes``): counts, each said by the encoder.
    cleanup: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        """A Mesh made of lists (any array_like) holds them as arrays, as its fields say (its counts, its repr and
        its comparison read ``.shape``); MeshError when they are no arrays (ragged rows).  Arrays are kept as given:
        :func:`checked_mesh` checks their shapes and values."""
        if not isinstance(self.positions, np.ndarray) or not isinstance(self.faces, np.ndarray):
            try:
                self.positions, self.faces = np.asarray(self.positions), np.asarray(self.faces)
            except (TypeError, ValueError) as exc:
                raise MeshError(f"mesh: vertex or face data is not numeric ({exc})") from None

    @property
    def vertex_count(self) -> int:
        return int(self.positions.shape[0]) if self.positions.ndim else 0

    @property
    def face_count(self) -> int:
        return int(self.faces.shape[0]) if self.faces.ndim else 0

    def bbox_diagonal(self) -> float:
        """Length of the axis-aligned bounding box diagonal (float)."""
        if self.vertex_count == 0:
            return 0.0
        lo, hi = bounds(self.positions)
        return float(np.linalg.norm(hi - lo))

    def __repr__(self) -> str:
        return f"Mesh({self.vertex_count} vertices, {self.face_count} faces)"

    def __eq__(self, other) -> bool:
        """The same positions, faces and attributes, array for array (``cleanup``, a note on how the
        mesh was read, is not compared); the generated comparison raised on numpy arrays."""
        if not isinstance(other, Mesh):
            return NotImplemented
        same = lambda a, b: np.shape(a) == np.shape(b) and bool(np.array_equal(a, b))  # noqa: E731
        return (same(self.positions, other.positions) and same(self.faces, other.faces)
                and self.attributes.keys() == other.attributes.keys()
                and all(same(v, other.attributes[k]) for k, v in self.attributes.items()))

    __hash__ = None  # mutable arrays: not hashable (as the dataclass had it)


def vertex_components(faces: np.ndarray, n: int) -> tuple:
    """``(count, label (n,) int32)``: the connected parts of a mesh of ``n`` vertices whose ``faces`` (m, 3) int join
    the vertices they name (scipy's labels: a vertex no face names is a part of its own)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    graph = coo_matrix((np.ones(len(edges), np.int8), (edges[:, 0], edges[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)


def bounds(points: np.ndarray) -> tuple:
    """``(lo, hi)``, each (d,) of the dtype of ``points`` (n, d), n >= 1: its columns' minima and maxima,
    ``points.min(0)`` and ``points.max(0)``.  Column by column: numpy reduces a narrow array over its
    first axis about 20x slower (37 ms for 556k positions)."""
    lo = np.array([points[:, k].min() for k in range(points.shape[1])], dtype=points.dtype)
    hi = np.array([points[:, k].max() for k in range(points.shape[1])], dtype=points.dtype)
    return lo, hi


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
        Empty mesh, wrong shapes, NaN/inf coordinates, face index out of range, more
        than the encoder's limits (``MAX_ENCODE_VERTICES`` / ``MAX_ENCODE_FACES``), or a
        far-out vertex that would collapse the mesh on any position grid;
        :class:`~pmwm_codec.errors.DegenerateMeshError` (a MeshError) when the data is
        well formed but every triangle is degenerate.
    """
    pos, tri = mesh_arrays(positions, faces, name)
    n = pos.shape[0]

    attrs = {}
    if attributes is not None and not isinstance(attributes, Mapping):
        raise MeshError(f"{name}: attributes must be a dict of (n, k) arrays, one row per vertex, "
                        f"got {type(attributes).__name__}")
    for key, value in (attributes or {}).items():
        arr = np.asarray(value)
        if arr.ndim == 0 or arr.shape[0] != n:
            rows = "no rows (a scalar)" if arr.ndim == 0 else f"{arr.shape[0]} rows"
            raise MeshError(f"{name}: attribute {key} has {rows} for {n} vertices")
        attrs[key] = arr

    degenerate = two_alike(tri)  # faces repeating a vertex
    tri = np.compress(~degenerate, tri, axis=0)  # tri[~degenerate], a copy, in a quarter of the time
    if tri.shape[0] == 0:
        raise DegenerateMeshError(f"{name}: every triangle is degenerate")
    used = np.zeros(n, dtype=bool)
    used[tri.ravel()] = True
    unreferenced = int(n - used.sum())
    if unreferenced:
        remap = np.cumsum(used) - 1
        tri = remap[tri]
        pos = pos[used]
        attrs = {k: v[used] for k, v in attrs.items()}
    if len(tri) > MAX_ENCODE_FACES or len(pos) > MAX_ENCODE_VERTICES:
        raise MeshError(f"{name}: {len(pos):,} vertices and {len(tri):,} faces; the encoder takes at most "
                        f"{MAX_ENCODE_VERTICES:,} vertices and {MAX_ENCODE_FACES:,} faces")
    _check_extent(pos, tri, name)
    cleanup = {}
    if degenerate.any():
        cleanup["degenerate_faces"] = int(degenerate.sum())
    if unreferenced:
        cleanup["unreferenced_vertices"] = unreferenced
    return Mesh(np.ascontiguousarray(pos), np.ascontiguousarray(tri), attrs, cleanup)


def mesh_arrays(positions, faces, name: str = "mesh") -> tuple:
    """``(positions (n, 3) float64, faces (m, 3) int64)`` of raw arrays once they are known to be a triangle
    mesh: numeric, of those shapes, not empty, finite, every face index naming a vertex (the faces
    may be degenerate, the vertices unreferenced; :func:`checked_mesh` goes on to drop them).

    Raises MeshError naming ``name`` otherwise.
    """
    try:
        pos = np.asarray(positions)
        real = pos.dtype.kind not in "bc"  # float64 would take True as 1 and drop an imaginary part (a warning)
        pos = pos.astype(np.float64, copy=False) if real else pos
        tri = np.asarray(faces)
    except (TypeError, ValueError) as exc:
        raise MeshError(f"{name}: vertex or face data is not numeric ({exc})") from None
    if not real:
        raise MeshError(f"{name}: positions must be real numbers, got dtype {pos.dtype}")
    if pos.size and (pos.ndim != 2 or pos.shape[1] != 3):
        raise MeshError(f"{name}: positions must be (n, 3), got shape {pos.shape}")
    if pos.ndim != 2 or pos.shape[0] == 0:
        raise MeshError(f"{name}: the mesh has no vertices")
    if tri.size == 0:
        raise MeshError(f"{name}: the mesh has no triangles")
    if tri.ndim != 2 or tri.shape[1] != 3:
        raise MeshError(f"{name}: faces must be triangles, got shape {tri.shape}")
    if tri.dtype.kind not in "iuf":  # a bool is no index (True would name vertex 1)
        raise MeshError(f"{name}: face indices are not numbers (dtype {tri.dtype})")
    if not np.issubdtype(tri.dtype, np.integer):
        if not np.all(np.equal(np.mod(tri, 1), 0)):
            raise MeshError(f"{name}: face indices are not integers")
    finite = np.isfinite(pos)
    if not finite.all():
        bad = ~finite.all(axis=1)
        count = int(bad.sum())
        raise MeshError(
            f"{name}: {count} {'vertex has' if count == 1 else 'vertices have'} NaN or infinite coordinates "
            f"(first at vertex {int(np.argmax(bad))})"
        )
    n = pos.shape[0]
    lo, hi = tri.min(), tri.max()  # in the caller's dtype: a uint64 past int64's range would wrap to a negative
    if lo < 0 or hi >= n:
        worst = int(hi) if hi >= n else int(lo)
        numbering = (f"; {worst + 1} in an OBJ file, whose numbering starts at 1"
                     if worst >= n and str(name).lower().endswith(".obj") else "")  # OFF, PLY, glTF count from 0
        raise MeshError(f"{name}: face index {worst} out of range for {n} vertices (counted from 0{numbering})")
    return pos, tri.astype(np.int64, copy=False)  # (checked_mesh's face filter copies: never the caller's array)


#: PLY property types that are integers (face indices must be one of them).
_PLY_INTEGER_TYPES = {"char", "uchar", "short", "ushort", "int", "uint",
                      "int8", "uint8", "int16", "uint16", "int32", "uint32"}


def _check_ply_header(path, name) -> None:
    """Refuse a PLY whose header declares more vertices / faces than the encoder takes,
    or face indices that are not integers, before anything is allocated (:func:`~pmwm_codec.ply.read_ply` reads it;
    a face's other lists, MeshLab's ``texcoord`` floats, are not indices)."""
    from .ply import FACE_LISTS

    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    end = head.find(b"end_header")
    if not head.startswith(b"ply") or end < 0:
        raise InputFormatError(f"{name}: not a PLY file (no 'ply' ... 'end_header' header in its first 64 KiB)")
    element = None
    limits = {"vertex": MAX_ENCODE_VERTICES, "face": MAX_ENCODE_FACES}
    declared = {}
    for line in head[:end].decode("ascii", "replace").splitlines():
        words = line.split()
        if words[:1] == ["element"] and len(words) == 3:
            element = words[1]
            count = int(words[2]) if words[2].isdigit() else -1
            if count < 0:
                raise InputFormatError(f"{name}: PLY declares {words[2]!r} {element} elements (not a count)")
            if count > limits.get(element, count):
                raise InputFormatError(f"{name}: PLY declares {count:,} {element} elements "
                                       f"(the encoder takes at most {limits[element]:,})")
            declared[element] = count
        elif words[:2] == ["property", "list"] and element == "face" and len(words) == 5 and words[4] in FACE_LISTS:
            if words[2] not in _PLY_INTEGER_TYPES or words[3] not in _PLY_INTEGER_TYPES:
                raise InputFormatError(f"{name}: PLY face indices are of type {words[2]}/{words[3]}, not integers")
    if not declared.get("face") and not declared.get("tristrips"):  # a scan's point cloud: said before its data is
        raise MeshError(f"{name}: the file holds no triangle mesh (its PLY header declares "  # read (cut short or not)
                        f"{declared.get('vertex', 0):,} vertices and no faces: a point cloud)")


def _read_stl(path, name) -> Mesh:
    """The mesh of the STL at ``path``: binary (an 80-byte header, a triangle count, 50 bytes a triangle) or
    ASCII (``solid`` ... ``facet`` ... ``endsolid``), its corners welded where they are the same point.  Each
    facet's normal is not read: its winding is its vertices' order, as other readers take it.  InputFormatError
    (:func:`_check_stl_header`, :func:`_read_ascii_stl`) for a file that is neither, cut short, or malformed."""
    size = os.stat(path).st_size
    if _check_stl_header(path, name) == "ascii":
        positions = _read_ascii_stl(path, name)
    else:
        data = read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError, name)
        if len(data) != size:  # (changed while read)
            raise InputFormatError(f"{name}: the file changed while it was read")
        positions = np.frombuffer(data, _STL_RECORD, offset=84)["corners"].reshape(-1, 3).astype(np.float64)
    if not len(positions):
        raise MeshError(f"{name}: the file holds no triangle mesh")
    bad = ~np.isfinite(positions).all(axis=1)
    if bad.any():  # named by facet, as the file counts them (checked_mesh would name a vertex of the weld)
        facets = np.unique(np.flatnonzero(bad) // 3)
        raise MeshError(f"{name}: {len(facets):,} facet{'s have' if len(facets) > 1 else ' has'} a NaN or infinite "
                        f"coordinate (first: facet {int(facets[0]) + 1}, counted from 1)")
    positions, inverse = np.unique(positions, axis=0, return_inverse=True)
    return checked_mesh(positions, inverse.reshape(-1, 3), name=name)


#: A binary STL's triangle record: a normal, three corners (float32, little-endian) and two attribute bytes.
_STL_RECORD = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attributes", "<u2")])


def _check_stl_header(path, name) -> str:
    """``"binary"`` or ``"ascii"``: what the STL at ``path`` is, or InputFormatError for a binary STL that declares
    more triangles than the encoder takes, or whose size is not what its triangle count says (cut short, or
    trailing bytes).  A file whose size is what its count says is binary, whatever its header (exporters start
    it with ``solid`` too, and may name ``facet`` in it); otherwise it is ASCII when it starts with ``solid``,
    its first KiB holds no NUL byte and names ``facet`` or ``endsolid``, in any case (some CAD exporters write
    the keywords in capitals; the solid's name may be UTF-8 or Latin-1)."""
    size = os.stat(path).st_size
    with open(path, "rb") as fh:
        head = fh.read(1024)
    count = int.from_bytes(head[80:84], "little") if len(head) >= 84 else -1
    if 0 <= count <= MAX_ENCODE_FACES and size == 84 + 50 * count:
        return "binary"
    low = head.lstrip().lower()
    if low.startswith(b"solid") and b"\0" not in head and (b"facet" in low or b"endsolid" in low):
        return "ascii"  # (checked as it is read: _read_ascii_stl)
    if len(head) < 84:
        raise InputFormatError(f"{name}: not an STL file (a binary STL has an 84-byte header; the file has {size} bytes)")
    if count > MAX_ENCODE_FACES:
        raise InputFormatError(f"{name}: STL declares {count:,} triangles (the encoder takes {MAX_ENCODE_FACES:,})")
    why = "cut short" if size < 84 + 50 * count else "bytes after its last triangle"
    raise InputFormatError(f"{name}: binary STL declares {count:,} triangles ({84 + 50 * count:,} bytes) "
                           f"but the file has {size:,} bytes ({why})")


#: An ASCII STL ``vertex`` record that is not the keyword and three numbers (a regular expression over the file's
#: bytes: the structure is checked at C speed before the reader parses it).
_STL_BAD_VERTEX = re.compile(rb"^[ \t]*vertex(?![ \t]+[-+.0-9eEinfINFaA]+[ \t]+[-+.0-9eEinfINFaA]+[ \t]+"
                             rb"[-+.0-9eEinfINFaA]+[ \t]*\r?$).*$", re.M)
_STL_FACET, _STL_VERTEX = re.compile(rb"^[ \t]*facet\b", re.M), re.compile(rb"^[ \t]*vertex\b", re.M)
#: A facet's loop of exactly three ``vertex`` records (the screen), and any loop (the diagnosis).
_STL_LOOP3 = re.compile(rb"loop[ \t]*\r?\n(?:[ \t]*vertex[^\n]*\n){3}[ \t]*endloop")
_STL_LOOP = re.compile(rb"\bouter[ \t]+loop\b(.*?)\bendloop\b", re.S)
#: The three numbers of an ASCII STL ``vertex`` record (one checked by :data:`_STL_BAD_VERTEX`).
_STL_CORNER = re.compile(rb"^[ \t]*vertex[ \t]+([^\r\n]*)", re.M)


def _stl_text(path, name) -> bytes:
    """The ASCII STL at ``path``, lower-cased (its keywords are read in any case)."""
    return read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError, name).lower()


def _check_ascii_stl(path, name, data: bytes | None = None) -> None:
    """Refuse an ASCII STL whose facets do not each hold three ``vertex`` records, naming the facet (the
    reader's own words were numpy's: "cannot reshape array of size 40 into shape (3)", OpenSCAD's
    toomanyvertices.stl; a facet of four beside one of two was read as wrong triangles, exit 0), a ``vertex``
    record that is not the keyword and three numbers (``vertex 1 0 0 7`` beside ``vertex 0 1`` made up the count
    and was read as other corners), a facet after the closing ``endsolid``, or a file without one.  A count of
    the loops of three screens the file; the diagnosis (:func:`ascii_stl_problem`) runs only when it differs
    from the facets'."""
    data = _stl_text(path, name) if data is None else data
    bad = _STL_BAD_VERTEX.search(data)
    if bad is not None or len(_STL_LOOP3.findall(data)) != data.count(b"endfacet"):
        problem = ascii_stl_problem(data)
        if problem:
            raise InputFormatError(f"{name}: {problem}")
    end = data.rfind(b"endsolid")
    if end < 0:
        raise InputFormatError(f"{name}: an ASCII STL without its closing 'endsolid' (cut short)")
    if _STL_FACET.search(data, end) is not None:
        raise InputFormatError(f"{name}: an ASCII STL with facets after its last 'endsolid' (a solid cut short, or "
                               "facets outside any solid)")


def _read_ascii_stl(path, name) -> np.ndarray:
    """(3m, 3) float64: the corners of the m facets of the ASCII STL at ``path`` (checked by
    :func:`_check_ascii_stl`), in file order, every solid of the file one after the other."""
    data = _stl_text(path, name)
    _check_ascii_stl(path, name, data)
    records = _STL_CORNER.findall(data)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # numpy's parser stops at a malformed number
        corners = np.fromstring(b" ".join(records), dtype=np.float64, sep=" ")
    if len(corners) != 3 * len(records):  # a number the screen let by ("1e", "1.2.3"): named record by record
        for i, record in enumerate(records):
            try:
                [float(x) for x in record.split()]
            except ValueError:
                raise InputFormatError(f"{name}: malformed ASCII STL record (vertex record {i + 1}): "
                                       f"{record.strip()[:60].decode('ascii', 'replace')!r}") from None
        raise InputFormatError(f"{name}: malformed ASCII STL vertex records")
    return corners.reshape(-1, 3)


def ascii_stl_problem(data: bytes):
    """What is malformed in the ASCII STL ``data`` (one phrase: a ``vertex`` record that is not the keyword
    and three numbers, with its line, or facets and vertex records that do not come three to one), else None."""
    bad = _STL_BAD_VERTEX.search(data)
    if bad is not None:
        line = data.count(b"\n", 0, bad.start()) + 1
        return f"malformed ASCII STL record (line {line}): {bad.group().strip()[:60].decode('ascii', 'replace')!r}"
    for loop in _STL_LOOP.finditer(data):
        corners = len(_STL_VERTEX.findall(loop.group(1)))
        if corners != 3:
            line = data.count(b"\n", 0, loop.start()) + 1
            return f"malformed ASCII STL: the facet at line {line} has {corners} vertex records, not three"
    facets, vertices = len(_STL_FACET.findall(data)), len(_STL_VERTEX.findall(data))
    if vertices != 3 * facets:
        return f"ASCII STL with {facets:,} facets and {vertices:,} vertex records (a facet has three vertices)"
    return None


def _check_extent(pos: np.ndarray, tri: np.ndarray, name: str) -> None:
    """Refuse a mesh that no position grid can hold: when its typical edge (median of the
    non-zero first-edge lengths, max-norm) is smaller than one cell of the finest grid
    (the bbox extent over 2^MAX_GRID_BITS), a far-out vertex would collapse the rest of
    the mesh onto a single cell.  ``pos`` (n, 3) float64, ``tri`` (m, 3) int64."""
    lo, hi = bounds(pos)
    extent = float((hi - lo).max())
    edges = _first_edges(pos, tri, max(1, len(tri) // (1 << 20)))
    if extent == 0.0 or edges.size == 0:
        return
    typical = _median(edges)
    if typical * float((1 << MAX_GRID_BITS) - 1) < extent:
        far = int(np.argmax(np.abs(pos - np.median(pos, axis=0)).max(axis=1)))
        where = ", ".join(f"{x:.3g}" for x in pos[far])
        raise MeshError(f"{name}: vertex {far} at ({where}) spans {extent / typical:.3g} typical edge lengths; "
                        f"the mesh would collapse onto one cell of any position grid (at most {MAX_GRID_BITS} bits)")


def _first_edges(pos: np.ndarray, tri: np.ndarray, stride: int) -> np.ndarray:
    """(k,) float64 the non-zero max-norm lengths of the first edges (corners 0 -> 1) of every ``stride``-th face
    of ``tri`` (m, 3) int64 over ``pos`` (n, 3) float64 (finite), in face order; compiled, one pass (the numpy
    path's five temporaries of (m / stride, 3) took ~1 ms of a 100k-vertex encode), for a mesh of
    :data:`~.progressive.topology.SMALL_JOB_VERTICES` or more (a one-shot process decides whether a job
    loads numba after reading its mesh: reading a small one must not load it)."""
    kernel = compiled(_first_edges_kernel) if len(pos) >= SMALL_JOB_VERTICES else None
    if kernel is not None:
        return kernel(np.ascontiguousarray(pos), np.ascontiguousarray(tri), stride)
    sample = tri[::stride]
    step = np.abs(np.take(pos, sample[:, 1], axis=0) - np.take(pos, sample[:, 0], axis=0))
    edges = np.maximum(np.maximum(step[:, 0], step[:, 1]), step[:, 2])  # max(axis=1), without numpy's slow 3-wide reduce
    return edges[edges > 0]


def _first_edges_kernel(pos, tri, stride):
    """Compiled :func:`_first_edges` (the same values: ``abs`` of the differences, their maximum; positions
    are finite, so no NaN to carry)."""
    out = np.empty((len(tri) + stride - 1) // stride, np.float64)
    k = 0
    for f in range(0, len(tri), stride):
        a, b = tri[f, 0], tri[f, 1]
        x = max(max(abs(pos[b, 0] - pos[a, 0]), abs(pos[b, 1] - pos[a, 1])), abs(pos[b, 2] - pos[a, 2]))
        out[k] = x
        k += x > 0
    return out[:k]


def _median(x: np.ndarray) -> float:
    """``float(np.median(x))`` of ``x`` (k,) float64, k >= 1, without NaN: the middle order statistic, or
    the mean of the two, from one partition (np.median's partition, which also looks for a NaN, took
    7x as long: 1.2 ms of a 35k-vertex encode)."""
    k = len(x) // 2
    part = np.partition(x, k)
    if len(x) % 2:
        return float(part[k])
    return float((part[:k].max() + part[k]) / 2)


def _oversized_message(path: str, name: str, size: int, suffix: str) -> str:
    """The one line refusing the mesh file at ``path`` (shown as ``name``) of ``size`` bytes over
    :data:`MAX_INPUT_FILE_BYTES`: the limit with its unit and why it is there, and for a text format (OBJ, OFF,
    STL, ASCII PLY) the way out: a binary PLY, which holds the same mesh (its colours and normals too) in a
    fraction of the bytes."""
    line = (f"{name}: {size:,} bytes, more than the {MAX_INPUT_FILE_BYTES:,} bytes "
            f"({MAX_INPUT_FILE_BYTES / (1 << 30):g} GiB) a mesh file may hold (it is read whole into memory)")
    if suffix in (".obj", ".off", ".stl") or (suffix == ".ply" and _ascii_ply(path, name)):
        line += "; saved as a binary PLY the same mesh takes a fraction of the bytes"
    return line


def _ascii_ply(path: str, name: str) -> bool:
    """Whether the PLY at ``path`` is an ASCII one (its header in its first 64 KiB); False when it cannot be read."""
    from .ply import header_format

    try:
        with open(path, "rb") as fh:
            return header_format(fh.read(1 << 16), name) == "ascii"
    except (OSError, InputFormatError):
        return False


def read_mesh(path: str | bytes | os.PathLike[str]) -> Mesh:
    """Read a triangle mesh from OBJ, PLY, STL, OFF, glTF or GLB at ``path`` (a file name: ``str``, ``bytes``
    or ``os.PathLike``).

    Polygons are fan-triangulated; STL triangle soups have identical corners
    merged, and so do OBJ and PLY soups (every face corner its own vertex:
    :func:`_soup_welded`).  For glTF/GLB the triangles the default scene shows
    (triangle lists, strips and fans) are merged into one mesh with node transforms
    applied (:func:`_read_gltf`; the asset pipeline keeps the document structure;
    this function only wants geometry).

    Raises
    ------
    OptionError
        ``path`` is not a file name (a file object, None, an int).
    InputFormatError
        Missing file, unknown suffix, or a file that does not parse as a mesh.
    MeshError
        See :func:`checked_mesh`.
    """
    path = path_argument(path, "the mesh path")
    name = check_input_path(path, "a mesh file")
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in MESH_SUFFIXES:
        raise InputFormatError(
            f"{name}: unknown mesh format {suffix or '(no suffix)'!r}; expected one of "
            + ", ".join(MESH_SUFFIXES)
        )
    size = os.stat(path).st_size
    if size > MAX_INPUT_FILE_BYTES:
        raise InputFormatError(_oversized_message(path, name, size, suffix))
    if suffix == ".obj":
        return obj_mesh(obj_text(path, name), name)
    if suffix == ".off":
        return _soup_welded(*_read_off(path, name), name)
    if suffix == ".ply":
        _check_ply_header(path, name)
        from .ply import read_ply

        data = read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError, name)
        return _soup_welded(*read_ply(data, name, MAX_ENCODE_FACES), name)
    if suffix == ".stl":
        return _read_stl(path, name)
    from .format.document import is_progressive, progressive_refusal, sniff_json

    gltf = sniff_json(path)
    if gltf is not None and is_progressive(gltf):
        raise InputFormatError(progressive_refusal(name))
    return _read_gltf(path, name)


def _read_gltf(path, name) -> Mesh:
    """The triangles the default scene of the glTF / GLB at ``path`` shows, as one mesh: every primitive of mode
    TRIANGLES, TRIANGLE_STRIP or TRIANGLE_FAN (a strip's and a fan's triangles as glTF 2.0 3.7.2.1 winds them, a
    strip's restarts dropped, as the asset encoder reads them) of each mesh the scene shows, placed by each node
    that shows it (:func:`~pmwm_codec.format.gltf.mesh_placements`: without a default scene, every root node;
    without nodes, each mesh once as stored), a mirrored showing with its winding reversed so that its faces
    keep facing out; positions as their accessors declare them (``normalized`` integers, KHR_mesh_quantization,
    mapped to -1..1 or 0..1; sparse accessors applied; Draco and meshopt data decoded).  The document is read as
    :func:`~pmwm_codec.format.document.load_document` reads it for an encode (every ``uri`` a regular file
    inside the asset's folder or a ``data:`` URI; sizes, indices and the node tree checked).

    Primitives of points and lines in a shown mesh are left out and counted in ``cleanup``
    (``primitives_of_points_or_lines``).  Morph targets are applied by the default weights (a node's
    ``weights``, else its mesh's: the rest pose a viewer draws;
    :func:`~pmwm_codec.format.document.rest_weights`); skins are not (the
    stored, bind-pose positions), and a skinned mesh is placed by its nodes as any mesh is (the frame its owner
    layer is read in), which a glTF viewer ignores: counted in ``cleanup``
    (``skinned_meshes_moved_by_their_nodes``) where that moves it.  MeshError (named by primitive) for a
    TRIANGLES index count that is not a multiple of 3, as the asset encoder says it, and for a scene that shows no
    triangle.  A scene that draws a mesh by
    ``EXT_mesh_gpu_instancing`` (whose instances are not placed here; the asset encoder keeps them) is read as
    decode writes it to OBJ: each shown mesh once, as stored, counted in ``cleanup`` (``gpu_instanced_meshes``)."""
    from .format.document import load_document, primitive_triangles, rest_weights
    from .format.gltf import DRACO_EXTENSION, TRIANGLE_MODES, TRIANGLES, placements_by_mesh, scene_mesh, skinned_meshes

    gltf, buffers = load_document(path)
    meshes = gltf.get("meshes", [])
    if gltf.get("nodes"):
        shown = placements_by_mesh(gltf)
    else:  # no node: each mesh once, where it is stored (as the encoder and decode read such a document)
        shown = {mi: [np.eye(4)] for mi in range(len(meshes))}
    instanced = sum(any(m is None for m in matrices) for matrices in shown.values())  # (transforms are checked)
    if instanced:  # as decode writes such a scene to OBJ (stream.asset.scene_as_shown): each mesh once, as stored
        shown = {mi: [np.eye(4)] for mi in shown}
    parts, frames, placed, lines = [], [], [], 0
    for mi in sorted(shown):
        matrices = shown[mi]
        for pi, prim in enumerate(meshes[mi].get("primitives", [])):
            where = f"{name}: mesh {mi} primitive {pi}"
            mode = prim.get("mode", TRIANGLES)
            if mode not in TRIANGLE_MODES:
                lines += 1
                continue
            if "POSITION" not in prim.get("attributes", {}):
                continue  # (nothing to draw: glTF lets a client skip it)
            draco = (prim.get("extensions") or {}).get(DRACO_EXTENSION)
            if draco is not None:
                from .stream.asset import _draco_arrays, _PassThrough

                try:
                    positions, faces, _ = _draco_arrays(gltf, buffers, prim, draco)
                except (_PassThrough, InputFormatError) as exc:
                    raise InputFormatError(f"{where}: {exc}") from None
                if mode != TRIANGLES:
                    raise InputFormatError(f"{where}: a Draco-compressed strip or fan (mode {mode}) is not read")
            else:
                try:
                    weights = rest_weights(gltf, mi, len(prim.get("targets", [])))
                except MeshError as exc:
                    raise MeshError(f"{name}: {exc}") from None
                positions, faces = primitive_triangles(gltf, buffers, prim, where, weights, MeshError, bounds=False)
            if len(faces) and (faces.min() < 0 or faces.max() >= len(positions)):
                raise MeshError(f"{where}: face index {int(faces.max())} out of range for {len(positions)} vertices "
                                "(counted from 0)")  # (as the asset encoder says it: checked_mesh's words)
            parts.append((np.asarray(positions, np.float64), np.asarray(faces, np.int64)))
            frames.append(matrices)
            placed.append(mi)
    if not any(len(f) and len(m) for (_, f), m in zip(parts, frames)):
        why = ("it has no mesh" if not meshes else "no node of its scene shows a mesh" if not shown
               else "its scene shows points and lines alone" if lines and not parts
               else "its primitives hold no triangle")
        raise MeshError(f"{name}: the file holds no triangle mesh ({why})")
    positions, faces, _ = scene_mesh([p for p, _ in parts], [f for _, f in parts], frames, oriented=True)
    mesh = checked_mesh(positions, faces, name=name)
    if lines:
        mesh.cleanup["primitives_of_points_or_lines"] = lines
    if instanced:
        mesh.cleanup["gpu_instanced_meshes"] = instanced
    skinned = skinned_meshes(gltf)
    moved = sum(mi in skinned and any(not np.array_equal(m, np.eye(4)) for m in shown[mi]) for mi in set(placed))
    if moved:  # where the owner layer is marked and read (format.gltf.owner_placements), not where viewers draw it
        mesh.cleanup["skinned_meshes_moved_by_their_nodes"] = moved
    return mesh


#: What ends a line besides a line feed for :meth:`str.splitlines` (a classic Mac OS file's CR; NEL, byte 0x85,
#: in a Latin-1 text; form feed; U+2028 ...).
_LINE_BREAKS = re.compile(r"[\r\x0b\x0c\x1c-\x1e\x85\u2028\u2029]")


def one_line_end(text: str) -> str:
    """``text`` with every line ended by a line feed, so that a comment (``#`` to the end of its line) and a record
    end where :meth:`str.splitlines` ends lines: its lines are those of ``text.splitlines()`` (an OBJ or OFF of CR
    line ends with a comment lost every record after it)."""
    if "\r\n" in text:
        text = text.replace("\r\n", "\n")
    return _LINE_BREAKS.sub("\n", text)


def _read_obj(path, name):
    """Parse ``v`` and ``f`` records of a Wavefront OBJ; returns float64 and int64 arrays.

    Counts are checked while reading, before they are stored: at most
    :data:`MAX_ENCODE_VERTICES` vertices and :data:`MAX_ENCODE_FACES` triangles (a
    face line's triangles are counted from its spaces before it is split), and
    every face index must name an existing vertex.
    """
    return obj_arrays(obj_text(path, name), name)[:2]


def obj_text(path, name) -> str:
    """The text of the OBJ at ``path`` as its readers take it: decoded (:func:`_mesh_text`), every line ended by a
    line feed (:func:`one_line_end`), comments cut (a comment runs to the end of its line, after a record too:
    ``f 1 2 3 # the lid``), a line that ends in a backslash joined to the next by a blank (the format's line
    continuation: ``f 1 2 \\`` then ``3`` is ``f 1 2 3``).  Read once for both readers: :func:`obj_arrays` and
    :func:`pmwm_codec.meshdoc.obj_document`."""
    text = one_line_end(_mesh_text(read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError, name), name, "OBJ"))
    if "#" in text:
        text = re.sub(r"#[^\n]*", "", text)
    return text.replace("\\\n", " ") if "\\\n" in text else text


def obj_mesh(text: str, name: str) -> Mesh:
    """The checked :class:`Mesh` of an OBJ's :func:`obj_text`, as :func:`read_mesh` reads the file (its ``l`` and
    ``p`` records, lines and points, left out and counted: :func:`with_obj_left_out`)."""
    return with_obj_left_out(_soup_welded(*obj_arrays(text, name)[:2], name), text)


#: An OBJ ``l`` or ``p`` record (a polyline, points) after a line feed: not read (the mesh is its triangles).
_OBJ_LINES_POINTS = re.compile(r"\n[ \t]*[lp][ \t]+[^ \t\n]")


def obj_lines_points(text: str) -> int:
    """How many ``l`` (line) and ``p`` (point) records the OBJ :func:`obj_text` ``text`` holds (a regular expression
    over the text, ~6 ms a MB)."""
    return len(_OBJ_LINES_POINTS.findall(text if text.startswith("\n") else "\n" + text))


def with_obj_left_out(mesh: Mesh, text: str) -> Mesh:
    """``mesh``, read from the OBJ :func:`obj_text` ``text``, with the ``l`` and ``p`` records it leaves out counted
    in its ``cleanup`` (``line_and_point_records``: the encoder says "dropped k line and point records"; they
    went without a word)."""
    left = obj_lines_points(text)
    if left:
        mesh.cleanup = {**mesh.cleanup, "line_and_point_records": left}
    return mesh


def obj_arrays(text: str, name: str) -> tuple:
    """:func:`_read_obj`'s arrays of an OBJ's :func:`obj_text`, and the most numbers a ``v`` record holds
    (``(positions (n, 3) float64, faces (m, 3) int64, widest int)``: six or more, vertex colours, which
    :func:`pmwm_codec.meshdoc.read_source` then reads as an asset, learnt from the one parse).

    Every index of a face corner must name a record read before its face (a position, and the texture
    coordinate and normal of ``v/t``, ``v//n``, ``v/t/n``), as the OBJ asset reader
    (:func:`pmwm_codec.meshdoc.obj_document`) requires, in its words: ``f 1/1/1 2/2/2 3/3/3`` in a file of no
    ``vt`` or ``vn``, or ``f 1 2 3`` before its vertices, was read without a word (the mesh an OBJ viewer shows is
    not that one: Blender skips such a face, three.js reads no position for it)."""
    text = _obj_normalized(text)
    fast = _read_obj_bytes(text)
    if fast is not None:
        return fast
    lines = text.splitlines()
    fast = _read_obj_columns(text, lines)
    if fast is not None:
        return fast
    from .meshdoc import _corner

    verts, tris, widest = [], [], 3
    counts = {"v": 0, "vt": 0, "vn": 0}  # records read so far, which a face corner may name
    line = ""
    try:
        for line in lines:
            if line.startswith("v "):
                if len(verts) >= MAX_ENCODE_VERTICES:
                    raise InputFormatError(f"{name}: more than {MAX_ENCODE_VERTICES:,} vertices (the encoder's limit)")
                parts = line.split(None, 4)
                verts.append((_number(parts[1]), _number(parts[2]), _number(parts[3])))
                counts["v"] += 1
                if len(parts) == 5 and widest < 6:
                    widest = max(widest, 3 + len(parts[4].split()))
            elif line.startswith("f "):
                if len(tris) + max(1, line.count(" ") - 2) > MAX_ENCODE_FACES:
                    raise InputFormatError(f"{name}: more than {MAX_ENCODE_FACES:,} triangles (the encoder's limit)")
                _add_polygon(line, tris, name, counts, _corner)
            elif line.startswith(("vt ", "vn ")):
                counts[line[:2]] += 1
    except InputFormatError:
        raise
    except (ValueError, IndexError):
        raise InputFormatError(f"{name}: malformed OBJ record: {line.strip()[:60]!r}") from None
    if not verts or not tris:
        left = obj_lines_points(text) if verts else 0
        raise MeshError(f"{name}: the file holds no triangle mesh (no face; {left:,} line and point records (l, p), "
                        "not read)" if left
                        else f"{name}: the mesh has no vertices or no faces")
    return np.array(verts, dtype=np.float64), np.array(tris, dtype=np.int64), widest


def _mesh_text(data: bytes, name: str, kind: str) -> str:
    """The text of a ``kind`` (OBJ, OFF) file's bytes ``data``: UTF-8, or what its byte order mark names (a Windows
    editor's UTF-8, UTF-16 or UTF-32 mark, dropped), else Latin-1 (older exporters write their object and material
    names in the system's 8-bit code page, ``usemtl Terraind\\xe6k``: every record read is ASCII, the same in
    both, and the names are not read).  InputFormatError for binary data: a NUL byte outside a marked UTF-16 /
    UTF-32 text, or text its mark's codec cannot decode."""
    codec = bom_codec(data[:4])
    try:
        if codec is not None:
            return data.decode(codec)
        if b"\0" in data:
            raise UnicodeDecodeError("utf-8", data, 0, 1, "a NUL byte")
        try:
            return data.decode("utf-8")
        except UnicodeDecodeError:
            return data.decode("latin-1")
    except UnicodeDecodeError:
        raise InputFormatError(f"{name}: not a text {kind} file (binary data" +
                               (f", or not the {codec.upper().removesuffix('-SIG')} its byte order mark names)"
                                if codec else ")")) from None


#: An OFF header keyword (Geomview's ``[ST][C][N][4][n]OFF``) and what follows it on its line.
_OFF_HEADER = re.compile(r"((?:ST)?C?N?(4)?(n)?OFF)(.*)")


def _read_off(path, name, appearance: bool = False, header_out: list | None = None) -> tuple:
    """Parse an OFF file (Object File Format: Geomview's, CGAL's, the Princeton Shape Benchmark's and ModelNet's):
    ``(positions (n, 3) float64, faces (m, 3) int64)``, polygons fan-triangulated as an OBJ's are; with
    ``appearance``, ``(positions, faces, colours, face colours)``: ``colours`` (n, 3) float64 the red, green and
    blue a ``C``-keyword file (``COFF``, ``CNOFF`` ...) gives each vertex after its position (and its normal, in an
    ``N`` one), as written (0..1 floats or 0..255 integers), None without ``C``; ``face colours`` whether a face
    record has numbers after its indices (a colour: not read).

    The header keyword (``OFF``, ``COFF``, ``NOFF``, ``STOFF``, ...; ModelNet writes the counts on its line,
    ``OFF490 1010 0``), then the vertex and face counts, then one vertex a line (its first three numbers: the
    position; then, as the keyword says, ``N`` a normal, ``C`` a colour (3 or 4 numbers), ``ST`` texture
    coordinates: only the colour is read) and one face a line (its corner count k, k indices counted from 0, then
    an optional colour).  ``header_out``, a list, gets the file's header keyword appended (``NOFF`` ...: whether its
    vertices carry normals, which are not read), then the number of records after the faces its header declares
    (not read: readers stop at the declared count).  ``#`` starts a comment.  Counts are checked
    against the encoder's limits before anything is stored.  InputFormatError, naming the line, for a binary
    or 4D / nD OFF, a missing or malformed record, a face index past the vertices; MeshError for a file of no
    faces (a point cloud).  A face of one or two corners is a degenerate triangle, dropped and counted by
    :func:`checked_mesh` as an OBJ's is."""
    text = one_line_end(_mesh_text(read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError, name), name, "OFF"))
    if "#" in text:
        text = re.sub(r"#[^\n]*", "", text)
    lines = [line for line in text.splitlines() if line.strip()]
    head = _OFF_HEADER.fullmatch(lines[0].strip()) if lines else None
    if head is None:
        raise InputFormatError(f"{name}: not an OFF file (its first record is not an OFF keyword such as OFF or COFF)")
    if head.group(2) or head.group(3):
        raise InputFormatError(f"{name}: a {head.group(1)} file holds vertices of another dimension than 3")
    rest = head.group(4).split()
    if rest[:1] == ["BINARY"]:
        raise InputFormatError(f"{name}: a binary OFF file; pmw reads OFF as text")
    at = 1
    if not rest:
        rest, at = (lines[1].split() if len(lines) > 1 else []), 2
    try:
        n_vertices, n_faces = int(rest[0]), int(rest[1])
    except (IndexError, ValueError):
        raise InputFormatError(f"{name}: malformed OFF counts: {' '.join(rest)[:60]!r} (vertices, faces, edges)") from None
    if not 0 <= n_vertices <= MAX_ENCODE_VERTICES or not 0 <= n_faces <= MAX_ENCODE_FACES:
        raise InputFormatError(f"{name}: OFF declares {n_vertices:,} vertices and {n_faces:,} faces (the encoder takes "
                               f"0..{MAX_ENCODE_VERTICES:,} and 0..{MAX_ENCODE_FACES:,})")
    if n_faces == 0:
        raise MeshError(f"{name}: the file holds no triangle mesh (its OFF header declares {n_vertices:,} vertices and "
                        "no faces: a point cloud)")
    if len(lines) < at + n_vertices + n_faces:
        raise InputFormatError(f"{name}: OFF declares {n_vertices:,} vertices and {n_faces:,} faces but holds "
                               f"{max(len(lines) - at, 0):,} records (cut short)")
    keyword = head.group(1)
    if header_out is not None:
        header_out += [keyword, len(lines) - (at + n_vertices + n_faces)]
    coloured = appearance and "C" in keyword.replace("OFF", "")
    first = 6 if "N" in keyword.replace("OFF", "") else 3  # where a colour starts: after a normal
    rows = _off_rows(lines[at: at + n_vertices], first + 3 if coloured else 3, name, at, "vertex")
    polygons = lines[at + n_vertices: at + n_vertices + n_faces]
    faces, face_colours = _off_faces(polygons, name, at + n_vertices)
    if not appearance:
        return rows, faces
    return rows[:, :3], faces, (rows[:, first: first + 3] if coloured else None), face_colours


def _off_rows(records: list, width: int, name: str, first: int, what: str) -> np.ndarray:
    """The first ``width`` numbers of each of ``records`` (OFF lines, the first of them record ``first`` of the
    file counting from 0) as an (n, width) float64 array; the records all of one length are parsed at once."""
    fields = records[0].split()
    if all(len(r.split()) == len(fields) for r in records) and len(fields) >= width and _plain(records):
        try:
            return np.array(" ".join(records).split(), np.float64).reshape(len(records), -1)[:, :width]
        except ValueError:
            pass  # the record that does not parse is named below
    out = np.empty((len(records), width), np.float64)
    for i, record in enumerate(records):
        values = record.split()[:width]
        try:
            if len(values) < width:
                raise ValueError(record)
            out[i] = [_number(x) for x in values]
        except ValueError:
            raise InputFormatError(f"{name}: malformed OFF {what} record (record {first + i + 1}): "
                                   f"{record.strip()[:60]!r}") from None
    return out


def _off_faces(records: list, name: str, first: int) -> tuple:
    """``(triangles (m, 3) int64, whether a record has numbers after its indices: a face colour)`` of OFF face
    ``records`` (``k i_1 .. i_k [colour]`` each), fan-triangulated; the common file of one corner count
    throughout at once, the rest record by record."""
    fields = [r.split() for r in records]
    k0 = fields[0][0]
    if k0.isdigit() and int(k0) >= 3 and all(f[0] == k0 and len(f) == len(fields[0]) for f in fields) \
            and _plain(records):
        k = int(k0)
        if len(fields[0]) > k:
            try:
                idx = np.array([f[1: k + 1] for f in fields], np.int64)
            except ValueError:
                idx = None  # named record by record below
            if idx is not None:
                if len(idx) * (k - 2) > MAX_ENCODE_FACES:
                    raise InputFormatError(f"{name}: more than {MAX_ENCODE_FACES:,} triangles (the encoder's limit)")
                tris = np.stack([np.repeat(idx[:, 0], k - 2), idx[:, 1:-1].reshape(-1), idx[:, 2:].reshape(-1)], 1)
                return tris, len(fields[0]) > k + 1
    tris, coloured = [], False
    for i, f in enumerate(fields):
        try:
            k = _integer(f[0])
            idx = [_integer(x) for x in f[1: k + 1]]
            if k < 1 or len(idx) < k:
                raise ValueError
        except ValueError:
            raise InputFormatError(f"{name}: malformed OFF face record (record {first + i + 1}): "
                                   f"{records[i].strip()[:60]!r}") from None
        if len(tris) + max(k - 2, 1) > MAX_ENCODE_FACES:
            raise InputFormatError(f"{name}: more than {MAX_ENCODE_FACES:,} triangles (the encoder's limit)")
        coloured = coloured or len(f) > k + 1
        idx += idx[-1:] * (3 - len(idx))  # a face of one or two corners: a degenerate triangle, dropped and counted
        tris.extend((idx[0], idx[j], idx[j + 1]) for j in range(1, len(idx) - 1))
    return np.array(tris, np.int64).reshape(-1, 3), coloured


#: A number as OBJ and OFF write them: ASCII digits (Python's float() and int() also take ``1_0`` as 10 and
#: other scripts' digits, which no exporter writes: refused, not read as another number).
_NUMBER = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][-+]?[0-9]+)?|[-+]?(?:inf|infinity|nan)", re.I)
_INTEGER = re.compile(r"[-+]?[0-9]+")


def _plain(records: list) -> bool:
    """Whether ``records`` (text lines) hold only ASCII letters, digits, signs, points and blanks (numpy's
    parsers, like :func:`float`, read ``1_0`` and other scripts' digits: such records go record by record)."""
    return _NOT_PLAIN.search("\n".join(records)) is None


_NOT_PLAIN = re.compile(r"[^0-9A-Za-z+\-.\s]|[^\x00-\x7f]")


def _number(token: str) -> float:
    """``float(token)`` of a number as files write it (:data:`_NUMBER`); ValueError for anything else."""
    if _NUMBER.fullmatch(token) is None:
        raise ValueError(token)
    return float(token)


def _integer(token: str) -> int:
    """``int(token)`` of ASCII digits with an optional sign; ValueError for anything else."""
    if _INTEGER.fullmatch(token) is None:
        raise ValueError(token)
    return int(token)


def _obj_normalized(text: str) -> str:
    """An OBJ text with each ``v`` / ``vt`` / ``vn`` / ``f`` record starting with its keyword and one space (the
    form the readers match): records indented, or with a tab after the keyword, are valid OBJ."""
    loose = _LOOSE_HEAD.match(text) or _LOOSE_RECORD.search(text)
    return _RECORD_HEAD.sub(r"\1 ", text) if loose else text


#: A record that is not in that form at the start of a line: the text's first (``_LOOSE_HEAD``), or after a line feed
#: (a literal first, which the engine scans for: ``^`` with re.M tried every position, 1.9 s on a 211 MB OBJ, 0.7 now).
_LOOSE_HEAD = re.compile(r"[ \t]+(?:v[tn]?|f)[ \t]|(?:v[tn]?|f)(?:\t| [ \t])")
_LOOSE_RECORD = re.compile(r"\n(?:" + _LOOSE_HEAD.pattern + ")")
_RECORD_HEAD = re.compile(r"^[ \t]*(v[tn]?|f)[ \t]+", re.M)
#: A ``v`` / ``vt`` / ``vn`` record after the first face (a ``"\n"`` before the text): faces read by what precedes them.
_LATER_RECORD = re.compile(r"\nv[tn]? ")


_FACE_INDICES = re.compile(r"[0-9 \t\n-]*")
#: Longest ``v`` / ``f`` record the column reader takes (a few coordinates or indices each).
_COLUMN_RECORD = 256


def _read_obj_columns(text: str, lines: list):
    """:func:`_read_obj`'s result for the common OBJ whose ``v`` records all have the same number of
    fields and whose ``f`` records all name the same number of vertices, every corner in one form (plain,
    ``v/t``, ``v//n`` or ``v/t/n``), parsed a column at a time (numpy's text reader: ~5x faster than the loop
    on the 100k-vertex dragon, the same float64 and int64 values); None for anything else, which the
    record-by-record reader then reads or rejects with its message (limits, bad indices, an index naming no
    record read before its face, mixed polygons or corner forms, a malformed record).  ``text``: the
    normalized OBJ text (:func:`_obj_normalized`), ``lines`` its lines."""
    from .meshdoc import _CORNER_FORMS, _every_corner_has

    verts = [line[2:] for line in lines if line.startswith("v ")]
    polys = [line[2:] for line in lines if line.startswith("f ") and line[2:].strip()]  # "f" alone names nothing
    if not verts or not polys or len(verts) > MAX_ENCODE_VERTICES:
        return None
    if max(map(len, verts)) > _COLUMN_RECORD or max(map(len, polys)) > _COLUMN_RECORD:
        return None  # a huge record is checked against the limits before it is split, record by record
    joined = "\n".join(polys)
    first = polys[0].split(None, 1)[0]
    slashes, double = first.count("/"), "//" in first
    form = _CORNER_FORMS.get((slashes, int(double)))  # the record kinds a corner names: 0 v, 1 vt, 2 vn
    numbers = joined.replace("//", "/").replace("/", " ") if slashes else joined
    if form is None or _FACE_INDICES.fullmatch(numbers) is None:
        return None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # an empty row or a changed column count: the general reader
            positions = np.loadtxt(verts, dtype=np.float64, comments=None, ndmin=2)
            values = np.loadtxt(numbers.splitlines(), dtype=np.int64, comments=None, ndmin=2)
    except (ValueError, Warning):
        return None
    if values.shape[1] % len(form):
        return None
    k = values.shape[1] // len(form)  # corners a face
    corners = values.reshape(len(values), k, len(form))
    n = corners.shape[0] * k
    if slashes and (joined.count("/") != n * slashes or joined.count("//") != n * double
                    or not _every_corner_has(joined, n, slashes)):
        return None  # corners of mixed forms whose numbers make up the same count
    if positions.shape[1] < 3 or k < 3 or len(corners) * (k - 2) > MAX_ENCODE_FACES:
        return None
    before = _records_before_faces(text, lines, form, len(verts), len(corners))
    per_face = np.full(len(corners), k, np.int64)
    ids = None if before is None else obj_corner_ids(values.reshape(-1), form, per_face, before, (0,))
    if ids is None:
        return None
    return np.ascontiguousarray(positions[:, :3]), fan_triangles(ids.reshape(-1), per_face), positions.shape[1]


#: The bytes of the common OBJ's ``v`` records (digits, signs, points, exponents, blanks) and ``f`` records.
_PLAIN_FLOAT = np.zeros(256, bool)
_PLAIN_FLOAT[list(b"0123456789+-.eE \t\n")] = True
_PLAIN_FACE = np.zeros(256, bool)
_PLAIN_FACE[list(b"0123456789-/ \t\n")] = True


class ObjLines:
    """The lines of an ASCII OBJ text as numpy sees them, for readers that parse a kind of record at once:
    ``data`` (bytes,) uint8 the text's bytes; ``starts``, ``ends`` (lines,) int64 where each line starts and
    where its line feed is (or the end of the text); ``kinds`` four (lines,) bool masks: ``v``, ``vt``, ``vn``
    and ``f`` records (the keyword and one space: the normalized text, :func:`_obj_normalized`).  Both fast OBJ
    readers (:func:`_read_obj_bytes`, :func:`pmwm_codec.meshdoc._obj_records_fast`) read their numbers
    (:meth:`numbers`) and faces (:meth:`face_corners`) through it."""

    def __init__(self, data: np.ndarray):
        self.data = data
        ends = np.flatnonzero(data == 10)
        if data[-1] != 10:
            ends = np.append(ends, len(data))
        self.ends, self.starts = ends, np.concatenate([[0], ends[:-1] + 1])
        b0, b1, b2 = (self._bytes_at(self.starts + k) for k in range(3))
        space, v = ord(" "), b0 == ord("v")
        self.kinds = [v & (b1 == space), v & (b1 == ord("t")) & (b2 == space), v & (b1 == ord("n")) & (b2 == space),
                      (b0 == ord("f")) & (b1 == space)]

    def _bytes_at(self, at: np.ndarray) -> np.ndarray:
        """(len(at),) uint8: the bytes at offsets ``at``, 0 past the end (no padded copy of the text)."""
        out = self.data[np.minimum(at, len(self.data) - 1)]
        out[at >= len(self.data)] = 0
        return out

    def records(self, k: int, plain: np.ndarray):
        """(bytes,) uint8: the records of kind ``k`` (0 ``v``, 1 ``vt``, 2 ``vn``, 3 ``f``), each line with its line
        feed, its keyword blanked; None when one holds a byte not ``plain`` ((256,) bool).  Copied a run of
        records at a time (the common file's records of a kind are a few runs), else through a mask of the text."""
        kind, size = self.kinds[k], self.ends - self.starts + 1
        edges = np.flatnonzero(np.diff(kind.view(np.int8), prepend=0, append=0))  # runs: [edges[2i], edges[2i+1])
        if not len(edges):
            return np.zeros(0, np.uint8)
        if len(edges) <= 2 * _RECORD_RUNS:
            body = np.concatenate([self.data[self.starts[a]: self.ends[b - 1] + 1]
                                   for a, b in zip(edges[0::2].tolist(), edges[1::2].tolist())])
        else:
            keep = np.repeat(kind, size)[: len(self.data)]
            body = self.data[keep]
            del keep
        first = np.cumsum(np.concatenate([[0], size[kind][:-1]]))  # each record's first byte
        for at in range((1, 2, 2, 1)[k]):
            body[first + at] = ord(" ")  # the keyword
        block = 1 << 24
        return body if all(plain[body[i: i + block]].all() for i in range(0, len(body), block)) else None

    def numbers(self, k: int) -> tuple | None:
        """``(values (count,) float64, widths (records,) int64)``: the numbers of the records of kind ``k`` (0 ``v``,
        1 ``vt``, 2 ``vn``), record after record, and how many each record holds; None when a record holds a byte
        no plain decimal has (:data:`_PLAIN_FLOAT`: no ``nan`` / ``inf``), no number, or a token that is not one
        number (:func:`~pmwm_codec.ply.parsed_numbers`).  The records' text is not held after the parse."""
        from .ply import _tokens_per_line, parsed_numbers

        body = self.records(k, _PLAIN_FLOAT)
        if body is None:
            return None
        widths = _tokens_per_line(body)[0]
        if len(widths) != np.count_nonzero(self.kinds[k]):
            return None  # (a record of no number)
        values = parsed_numbers(body, np.float64)
        return None if values is None or values.size != widths.sum() else (values, widths)

    def face_corners(self, kinds: tuple) -> tuple | None:
        """``(ids (c, len(kinds)) int64, per_face (f,) int64)`` of the ``f`` records, read a column at a time: for
        each of the c corners, face after face, the 0-based index of the record of each kind of ``kinds`` (0 ``v``,
        1 ``vt``, 2 ``vn``) it names (:func:`obj_corner_ids`: relative indices resolved, -1 for a kind its form
        names none of), and how many corners each face has (:func:`fan_triangles` makes its triangles).  None
        unless every ``f`` record holds three or more corners, all of one form (``v``, ``v/t``, ``v//n`` or
        ``v/t/n``, plain digits), each index naming a record of its kind read before its face, and the faces make
        at most :data:`MAX_ENCODE_FACES` triangles: the readers of lines then read the file or name what is wrong.

        The lines' last reading: their bytes and offsets (``data``, ``starts``, ``ends``: the text's size, and 16
        bytes a line) are let go once the face records are copied out, not held while the corners are parsed."""
        from .meshdoc import _CORNER_FORMS, _every_corner_has
        from .ply import _tokens_per_line, parsed_numbers

        polys = self.records(3, _PLAIN_FACE)
        self.data = self.starts = self.ends = None
        if polys is None:
            return None
        face_lines = self.kinds[3]
        per_face = _tokens_per_line(polys)[0]
        if not len(per_face) or len(per_face) != np.count_nonzero(face_lines) or (per_face < 3).any() \
                or int((per_face - 2).sum()) > MAX_ENCODE_FACES:
            return None  # (a blank f record, a point or an edge: the record readers skip or drop it)
        n = int(per_face.sum())
        slash = polys == ord("/")
        slashes, odd = divmod(np.count_nonzero(slash), n)
        double, odd_double = divmod(np.count_nonzero(slash[1:] & slash[:-1]), n)
        del slash
        form = _CORNER_FORMS.get((slashes, double))  # the record kinds a corner names: 0 v, 1 vt, 2 vn
        if form is None or odd or odd_double or not _every_corner_has(polys, n, slashes):
            return None  # corners of mixed forms (each corner: its form's slashes)
        polys[polys == ord("/")] = ord(" ")
        values = parsed_numbers(polys, np.int64)
        del polys
        if values is None or len(values) != n * len(form):
            return None
        before = [np.cumsum(self.kinds[k])[face_lines] if k in form else None for k in range(3)]
        ids = obj_corner_ids(values, form, per_face, before, kinds)
        return None if ids is None else (ids, per_face)


def obj_corner_ids(values: np.ndarray, form: tuple, per_face: np.ndarray, before: list, kinds: tuple = (0, 1, 2)):
    """(c, len(kinds)) int64: for each OBJ face corner, the 0-based index of the record of each kind of ``kinds``
    (0 ``v``, 1 ``vt``, 2 ``vn``) it names, -1 for a kind ``form`` does not name; None where an index is 0 or names
    no record read before its face (the record readers name it).  ``values``: the corners' numbers (int64,
    ``len(form)`` a corner, face after face, of the kinds ``form`` names), ``per_face`` (f,) int64 corners each,
    ``before[kind]`` (f,) int64 the records of that kind read before each face (for each kind of ``form``).  OBJ
    indices count from 1, or back from -1 for the last record read before the face."""
    n = len(values) // len(form)
    values = values.reshape(n, len(form))
    k = int(per_face[0]) if len(per_face) and (per_face == per_face[0]).all() else 0  # one polygon size: broadcast
    ids = np.full((n, len(kinds)), -1, np.int64)
    for column, kind in enumerate(form):  # a column at a time: no (c, 3) temporaries
        index = values[:, column]
        read = before[kind]
        if k:
            index, read = index.reshape(-1, k), read[:, None]
        else:
            read = np.repeat(read, per_face)
        if ((index == 0) | (index > read) | (index < -read)).any():  # an index 0, or one naming no record
            return None
        if kind in kinds:
            resolved = np.where(index > 0, index - 1, read + index) if (index < 0).any() else index - 1
            ids[:, kinds.index(kind)] = resolved.reshape(-1)
    return ids


def fan_triangles(ids: np.ndarray, per_face: np.ndarray) -> np.ndarray:
    """(t, 3, ...) of the corners ``ids`` ((c, ...), face after face; ``per_face`` (f,) int64 corners each, three
    or more): each face fan-triangulated, corner 0 with each pair of consecutive others, ``t = sum(per_face - 2)``,
    triangles in face order.  Triangles alone are ``ids`` itself, reshaped (no copy)."""
    tail = ids.shape[1:]
    k = int(per_face[0]) if (per_face == per_face[0]).all() else 0
    if k == 3:
        return ids.reshape(-1, 3, *tail)
    if k:  # one polygon size: a column of each face's corners at a time
        corners = ids.reshape(-1, k, *tail)
        return np.stack([np.repeat(corners[:, 0], k - 2, axis=0), corners[:, 1:-1].reshape(-1, *tail),
                         corners[:, 2:].reshape(-1, *tail)], axis=1)
    starts = np.concatenate([[0], np.cumsum(per_face)[:-1]])
    tri_face = np.repeat(np.arange(len(per_face)), per_face - 2)
    j = np.arange(len(tri_face)) - np.repeat(np.cumsum(per_face - 2) - (per_face - 2), per_face - 2) + 1
    first = starts[tri_face]
    del tri_face
    return np.stack([ids[first], ids[first + j], ids[first + j + 1]], axis=1)


#: Most runs of consecutive records of a kind :meth:`ObjLines.records` copies one by one.
_RECORD_RUNS = 4096


def obj_lines(text: str) -> ObjLines | None:
    """:class:`ObjLines` of the normalized OBJ ``text`` (:func:`_obj_normalized`), or None when it is empty or
    not ASCII (its readers of lines then read it)."""
    if not text or not text.isascii():
        return None
    return ObjLines(np.frombuffer(text.encode("ascii"), np.uint8))


def _read_obj_bytes(text: str):
    """:func:`_read_obj_columns`' result, read from the text's bytes by numpy without a Python object per line
    or token (the list of lines and its copies took ~8x the file's size: 1.9 GB for a 234 MB OBJ), for the
    common ASCII OBJ whose ``v`` records hold the same count (three or more) of plain decimals (no ``nan`` /
    ``inf``) and whose faces :meth:`ObjLines.face_corners` reads (polygons of any sizes, fan-triangulated:
    :func:`fan_triangles`); None for anything else, which the readers of lines then read or refuse (the same
    values: the records of every kind are found, counted and checked as the record reader finds, counts and
    checks them).  ``text``: the normalized OBJ text (:func:`_obj_normalized`)."""
    lines = obj_lines(text)
    if lines is None or (lines.ends - lines.starts).max() > _COLUMN_RECORD + 2:
        return None  # a huge record is checked against the limits before it is split, record by record
    n_vertices = int(np.count_nonzero(lines.kinds[0]))
    if not n_vertices or n_vertices > MAX_ENCODE_VERTICES:
        return None
    numbers = lines.numbers(0)
    if numbers is None or (numbers[1] != numbers[1][0]).any() or numbers[1][0] < 3:
        return None  # (v records of another count of numbers, or fewer than three)
    positions = numbers[0].reshape(n_vertices, int(numbers[1][0]))
    del numbers
    corners = lines.face_corners((0,))
    if corners is None:
        return None
    return np.ascontiguousarray(positions[:, :3]), fan_triangles(corners[0].reshape(-1), corners[1]), positions.shape[1]


def _records_before_faces(text: str, lines: list, form: tuple, vertices: int, faces: int) -> list | None:
    """``before[kind]`` (faces,) int64, for each kind of ``form`` (0 ``v``, 1 ``vt``, 2 ``vn``): how many records of
    that kind the normalized OBJ ``text`` (``lines``: its lines; ``vertices``: its ``v`` records) holds before each
    of its ``faces`` ``f`` records (:func:`obj_corner_ids` checks and resolves indices against them).  Records all
    before the first face (the common file): each kind's count; records after a face (objects one after another):
    :func:`_records_before`.  None where that finds another count of faces (faces of blanks alone among the
    records: the record reader counts)."""
    first_face = 0 if text.startswith("f ") else text.find("\nf ") + 1
    if _LATER_RECORD.search(text, first_face) is not None:
        before = [_records_before(text, lines, kind, faces) if kind in form else None for kind in range(3)]
        return None if any(before[kind] is None for kind in form) else before
    counts = [vertices] + [text.count(("\nvt ", "\nvn ")[kind - 1]) + text.startswith(("vt ", "vn ")[kind - 1])
                           for kind in (1, 2)]
    return [np.full(faces, counts[kind], np.int64) if kind in form else None for kind in range(3)]


def _records_before(text: str, lines: list, kind: int, faces: int) -> np.ndarray | None:
    """(faces,) int64: how many records of ``kind`` (0 ``v``, 1 ``vt``, 2 ``vn``) come before each ``f`` record of
    the normalized OBJ ``text`` (:func:`_obj_normalized`; ``lines``: its lines), numpy over the bytes that start its
    lines; None unless there are ``faces`` such records (an ``f`` of blanks alone is none of the column reader's)."""
    raw = np.frombuffer(text.encode("utf-8", "surrogatepass"), np.uint8)
    starts = np.concatenate([[0], np.flatnonzero(raw == 10) + 1])
    starts = starts[starts < len(raw)]  # (the line feed that ends the text starts no line)
    if len(starts) != len(lines):
        return None
    head = np.concatenate([raw, np.zeros(3, np.uint8)])[starts[:, None] + np.arange(3)]  # each line's first bytes
    is_f = (head[:, 0] == ord("f")) & (head[:, 1] == ord(" "))
    record = (head[:, 0] == ord("v")) & ((head[:, 1] == ord(" ")) if kind == 0 else
                                          (head[:, 1] == ord("tn"[kind - 1])) & (head[:, 2] == ord(" ")))
    before = np.cumsum(record)[is_f]
    return before if len(before) == faces else None


def _add_polygon(line: str, tris: list, name: str, counts: dict, corner) -> None:
    """Fan-triangulate the ``f`` record ``line`` into ``tris`` as 0-based vertex ids: OBJ indices are
    1-based, or negative counting back from the ``counts["v"]`` vertices before the record (``-1``: the
    last of them).  A record without indices (``f`` and blanks) names nothing and adds nothing, as in the
    column reader (:func:`_read_obj_columns`, which skips it).  InputFormatError for an index 0, beyond the
    limit or before the first vertex, and for a corner (``corner``: :func:`pmwm_codec.meshdoc._corner`) that is
    malformed or names a record (``v``, ``vt``, ``vn``: ``counts``) not read before the face.  A record of one or
    two vertices (exporters write an edge so: Blender reads it as one) is a degenerate face, one triangle
    repeating a corner, which :func:`checked_mesh` drops and counts (``degenerate_faces``) as it does a triangle
    naming a vertex twice."""
    tokens = line.split()[1:]
    idx = [_integer(tok.split("/", 1)[0]) for tok in tokens]
    if not idx:
        return
    read = counts["v"]
    for i in idx:
        if i == 0:
            raise InputFormatError(f"{name}: face index 0 names no vertex (OBJ counts vertices from 1, or back "
                                   "from -1 for the last one read)")
        if abs(i) > MAX_ENCODE_VERTICES:
            raise InputFormatError(f"{name}: face index {i} cannot name a vertex (at most {MAX_ENCODE_VERTICES:,}, "
                                   "the encoder's limit)")
        if i < -read:
            raise InputFormatError(f"{name}: face index {i} counts back past the first vertex ({read} read before it)")
    for tok in tokens:
        corner(tok, counts, name)  # the texture coordinate and normal, and a vertex not yet read
    idx += idx[-1:] * (3 - len(idx))
    idx = [i - 1 if i > 0 else read + i for i in idx]
    tris.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))


def _soup_welded(positions: np.ndarray, faces: np.ndarray, name: str) -> Mesh:
    """:func:`checked_mesh` of an OBJ's, OFF's or PLY's arrays, a triangle soup's exact duplicates welded first
    (:func:`weld_soup`: only positions are read, so that is every attribute the mesh has).

    Unwelded, each position had a copy per face around it and stayed in the base (no vertex split).  The
    vertices removed are counted in ``cleanup["duplicate_soup_vertices"]``; a mesh whose faces share a
    vertex is indexed by its author and kept as stored."""
    welded = weld_soup(positions, faces, name=name)
    if welded is None:
        return checked_mesh(positions, faces, name=name)  # (checked_mesh names what is wrong)
    mesh, removed = welded
    mesh.cleanup = {**mesh.cleanup, "duplicate_soup_vertices": removed}
    return mesh


def weld_soup(positions, faces, attributes=None, *, name="mesh") -> tuple | None:
    """``(mesh, removed)``: a triangle soup as the indexed mesh it is, or None when it is no soup or has no
    duplicates (the caller keeps what it has).

    A soup has faces naming every vertex at most once: every corner its own vertex, as flat-shaded OBJ
    exports, three.js non-indexed geometry and STL converters write it.  Vertices with the same position
    and the same value of every attribute (``attributes``, {name: (n, ...) array}) are one vertex, the
    first of them; vertices keep their order.  ``mesh`` is :func:`checked_mesh`'s (faces the weld makes
    degenerate dropped and counted in its ``cleanup``), ``removed`` how many vertices the weld removed.
    Faces that are not an index array of ``positions``, and positions that are not finite, are no soup:
    :func:`checked_mesh` of the caller's arrays names what is wrong.  Serves the mesh file readers
    (:func:`_soup_welded`) and the glTF primitives (:func:`pmwm_codec.stream.asset._welded`)."""
    positions, tri = np.asarray(positions), np.asarray(faces)
    n = len(positions)
    if tri.ndim != 2 or tri.size == 0 or tri.min() < 0 or tri.max() >= n \
            or np.bincount(tri.reshape(-1), minlength=n).max() > 1 or not np.isfinite(positions).all():
        return None
    return weld_duplicates(positions, tri, attributes, name=name)


def weld_duplicates(positions, faces, attributes=None, *, name="mesh") -> tuple | None:
    """:func:`weld_soup`'s weld for any mesh whose ``faces`` (m, 3) index ``positions`` (n, 3) (soup or
    not): ``(mesh, removed)``, or None when no two vertices have the same position and the same value of
    every attribute.  The first of each group is kept, vertices keep their order."""
    attributes = attributes or {}
    positions, tri = np.asarray(positions), np.asarray(faces)
    n = len(positions)
    from .progressive.seams import weld_groups

    rows = [np.asarray(positions, np.float64)] + [np.asarray(v, np.float64).reshape(n, -1)
                                                  for _, v in sorted(attributes.items())]
    weld = weld_groups(np.concatenate(rows, axis=1))
    if weld is None:
        return None
    keep = weld == np.arange(n)
    mesh = checked_mesh(positions[keep], (np.cumsum(keep) - 1)[weld[tri]],
                        {k: v[keep] for k, v in attributes.items()}, name=name)
    return mesh, int(n - keep.sum())
