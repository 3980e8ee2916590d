"""Reading the owner layer blind: from any mesh, and from a ``.pmw`` at every chunk boundary.

Contract
--------
* :func:`owner_of_mesh` ``(mesh, key) -> OwnerResult``: ``mesh`` a :class:`~pmwm_codec.mesh.Mesh`,
  a mesh file path (OBJ, PLY, STL, OFF, glTF/GLB: :func:`owner_view`) or a
  ``(positions (n, 3), faces (m, 3))`` pair; no original is needed.  A mesh made of separate pieces
  (:func:`pieces`: an OBJ of a scene that shows the marked object twice, a marked object exported
  beside others) is read whole and piece by piece, and the best read counts; its false-alarm
  probability covers every read made (the union bound).
* :func:`owner_view` ``(path) -> Mesh``: the one mesh a mesh file's layer is read from: an OBJ, PLY
  or STL as it is; a glTF/GLB's triangle primitives in the view
  :func:`~pmwm_codec.format.gltf.owner_placements` gives (the scene as shown, flattened, or, when no
  mesh is shown once or the placements do not read, each mesh once where it is stored).
* :func:`owner_of_stream` ``(source, key, every=False) -> list[OwnerBoundary]``: a ``.pmw`` (path, bytes,
  binary file; whole or cut) decoded chunk by chunk, an :class:`OwnerBoundary` at each boundary,
  base mesh first; its primitives are placed in the same view, as a decoded asset's are, and each level is
  read in the frames of the stream's full decode (:func:`full_decode_frames`: its estimate, searched frame and
  two aliases, computed from the decoded mesh, none depending on a key) in place of its own, which lie up to a
  shell width off on a coarse level; a stream that does not decode in full (cut short, or read as it arrives)
  has its levels read in their own frames.  The frame the file states (``ownerFrame``) is never read in:
  anyone who edits a file can set it, and a frame searched for another key brings that key towards
  ``present`` on a mesh never marked with it (a free frame is a view chosen with the key in hand, outside the
  false-alarm bound's views).  The layer is
  read at the base, at the last boundary, and wherever the level has at least :data:`REREAD_GROWTH`
  more vertices than at the last read; a boundary between carries the last read (``read_at``).
  ``every=True`` reads it at every boundary.

``key``: a :class:`~pmwm_codec.watermark.key.WatermarkKey` or key file path carrying
``owner_id``; a key without one raises :class:`~pmwm_codec.errors.WatermarkKeyError`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from ..errors import PmwError, WatermarkKeyError
from ..format.extension import EXTENSION_NAME
from ..format.document import sniff_json
from ..format.gltf import TRIANGLE_MODES, TRIANGLES, find_extension_primitives, owner_placements, scene_mesh
from ..mesh import Mesh, checked_mesh, read_mesh, vertex_components
from ..sources import read_all
from ..stream import StreamDecoder, iter_results
from ..watermark.key import as_key
from ..watermark.owner import OwnerResult, detect, distinct_mesh, full_frames

__all__ = ["OwnerBoundary", "OwnerReader", "owner_key", "owner_of_mesh", "owner_of_stream", "owner_view", "pieces",
           "MAX_PIECES", "MIN_PIECE_VERTICES"]

#: At most this many pieces of a mesh are read besides the whole mesh (the largest distinct ones).
MAX_PIECES = 8
#: A piece with fewer distinct vertices is not read on its own: too few to fill the layer's 64 shells
#: reliably (the encoder refuses meshes whose shells would stay empty, and no marked mesh is this small).
MIN_PIECE_VERTICES = 500
#: A stream's level is read again when it has at least this fraction more vertices than the level last read
#: (and always at the base and at the last boundary).  A multi-primitive asset streams in hundreds of small
#: chunks (2CylinderEngine: 442 for 46k splits), and a read that finds an error searches all its views: read
#: at every boundary, ``pmw verify`` took 190 s there (0.42 s a read); levels this close read the same.
REREAD_GROWTH = 1 / 16
#: Only the largest components this many are grouped by their bounding boxes (a scan's thousands of
#: specks would make the grouping quadratic, and a speck changes no piece's read).
MAX_GROUPED = 256


@dataclass
class OwnerBoundary:
    """The owner layer after ``chunk`` chunks (``bytes_read`` bytes, ``vertices``), as read from the level of
    chunk ``read_at`` (this one, or the last read before it: :data:`REREAD_GROWTH`)."""

    chunk: int
    bytes_read: int
    vertices: int
    owner: OwnerResult | None  # None only until read (OwnerReader.last_only)
    read_at: int = -1

    def __post_init__(self):
        if self.read_at < 0:
            self.read_at = self.chunk

    def as_json(self) -> dict:
        return {"chunk": self.chunk, "bytes_read": self.bytes_read, "vertices": self.vertices,
                **self.owner.as_json(), "read_at_chunk": self.read_at}


def owner_key(key):
    """The key as a WatermarkKey; WatermarkKeyError when it carries no owner id."""
    key = as_key(key)
    if key is None or key.owner_id is None:
        raise WatermarkKeyError("the key carries no owner id: it was written before the owner layer, or the "
                                "encoder left the layer out (a mesh it could not be read back from; the encode said so)")
    return key


def owner_of_mesh(mesh, key) -> OwnerResult:
    """Read the owner layer of one mesh (see the module contract)."""
    key = owner_key(key)
    if isinstance(mesh, tuple):
        mesh = checked_mesh(*mesh)
    elif not isinstance(mesh, Mesh):
        mesh = owner_view(mesh)
    parts = pieces(mesh)
    reads = 1 + len(parts)
    best = detect(mesh.positions, mesh.faces, key, reads=reads)
    for part in parts:
        if best.verdict == "present" and best.bit_errors == 0:
            break  # no read can do better
        result = detect(part.positions, part.faces, key, reads=reads)
        if result.bit_errors < best.bit_errors:
            best = result
    return best


def pieces(mesh: Mesh) -> list:
    """The separate pieces of ``mesh`` worth a read of their own: ``[Mesh]``, largest first, at most
    :data:`MAX_PIECES`, none when the mesh is one piece.

    A piece is a set of faces connected through shared positions (vertices at the same position are
    one: exporters split them at seams and part borders), or a group of such sets whose bounding boxes
    overlap (the parts of one object that do not touch); both kinds are candidates.  Pieces with fewer
    than :data:`MIN_PIECE_VERTICES` distinct positions are left out, and of pieces that are copies of
    one another (a similarity apart: equal counts, equal sorted distances from the centroid relative
    to their mean) one is kept.  Nothing here depends on a key: the reads are chosen before any is
    compared with an ID, as the false-alarm bound requires."""
    points, faces = distinct_mesh(mesh.positions, mesh.faces)
    if len(faces) == 0:
        return []
    n = len(points)
    count, label = vertex_components(faces, n)
    face_label = label[faces[:, 0]]
    used = np.zeros(n, bool)
    used[faces.ravel()] = True
    size = np.bincount(label[used], minlength=count)  # distinct positions of each component
    with_faces = np.flatnonzero(np.bincount(face_label, minlength=count) > 0)
    if len(with_faces) < 2:
        return []
    largest = with_faces[np.argsort(-size[with_faces], kind="stable")][:MAX_GROUPED]
    lo = np.full((count, 3), np.inf)
    hi = np.full((count, 3), -np.inf)
    np.minimum.at(lo, label[used], points[used])
    np.maximum.at(hi, label[used], points[used])
    candidates = [[int(c)] for c in largest] + [g for g in _overlapping(largest, lo, hi) if len(g) > 1]
    candidates = [g for g in candidates if MIN_PIECE_VERTICES <= size[g].sum() < used.sum()]
    by_label = np.argsort(face_label, kind="stable")  # each component's faces a slice, in face order
    start = np.searchsorted(face_label[by_label], np.arange(count + 1))
    out, seen = [], []
    for members in sorted(candidates, key=lambda g: -int(size[g].sum())):
        rows = np.sort(np.concatenate([by_label[start[c]:start[c + 1]] for c in members]))
        part = _compact(points, faces[rows])
        sign = _signature(part)
        if any(_copies(sign, other) for other in seen):
            continue
        seen.append(sign)
        out.append(part)
        if len(out) == MAX_PIECES:
            break
    return out


def _overlapping(components: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> list:
    """The components (indices into ``lo`` / ``hi``, (c, 3) bounding boxes) grouped so that boxes that
    overlap, directly or through others, share a group: a list of lists of component indices."""
    from scipy.sparse.csgraph import connected_components

    a, b = lo[components], hi[components]
    touch = np.all((a[:, None, :] <= b[None, :, :]) & (a[None, :, :] <= b[:, None, :]), axis=2)
    count, group = connected_components(touch, directed=False)
    return [[int(c) for c in components[group == g]] for g in range(count)]


def _compact(points: np.ndarray, faces: np.ndarray) -> Mesh:
    """The mesh of the ``points`` (n, 3) that ``faces`` (m, 3) int64 use, renumbered."""
    used, local = np.unique(faces, return_inverse=True)
    return Mesh(points[used], local.reshape(-1, 3))


def _signature(part: Mesh) -> tuple:
    """``(vertices, faces, sorted distances from the centroid / their mean)``: equal for a piece and a
    copy of it moved, turned, mirrored or scaled."""
    r = np.linalg.norm(part.positions - part.positions.mean(0), axis=1)
    r = np.sort(r)
    return part.vertex_count, part.face_count, r / max(float(r.mean()), 1e-300)


def _copies(a: tuple, b: tuple) -> bool:
    return a[0] == b[0] and a[1] == b[1] and bool(np.allclose(a[2], b[2], rtol=0, atol=1e-5))


def owner_view(path, scene: Mesh | None = None) -> Mesh:
    """The mesh the owner layer of the mesh file at ``path`` is read from (see the module contract); ``scene``:
    what :func:`~pmwm_codec.mesh.read_mesh` made of ``path`` already, taken where the view is that mesh (not read
    again).

    A glTF/GLB whose view is the scene is read as :func:`~pmwm_codec.mesh.read_mesh` reads it (every
    triangle primitive placed by its nodes); one whose view is the stored meshes takes each primitive
    that :func:`~pmwm_codec.stream.asset.plan_asset` makes progressive once, as stored.  Errors are
    :func:`~pmwm_codec.mesh.read_mesh`'s and :func:`~pmwm_codec.stream.asset.plan_asset`'s."""
    from ..format.document import is_progressive, load_document
    from ..stream.asset import is_asset_path, plan_asset

    gltf = sniff_json(path) if is_asset_path(path) else None
    if gltf is None or is_progressive(gltf) or owner_placements(gltf, _triangle_meshes(gltf))[1]:
        return read_mesh(path) if scene is None else scene
    name = os.path.basename(os.fspath(path))
    document, buffers = load_document(path)
    jobs = plan_asset(document, buffers, name)[0]
    frames, in_scene = owner_placements(document, [job.mesh_index for job in jobs])
    if in_scene:  # a mesh of triangles that are all degenerate was shown twice: the scene after all
        return read_mesh(path) if scene is None else scene
    positions, faces, _ = scene_mesh([job.mesh.positions for job in jobs], [job.mesh.faces for job in jobs], frames)
    return checked_mesh(positions, faces, name=name)


def _triangle_meshes(gltf: dict) -> list:
    """Indices of the meshes of ``gltf`` with a primitive drawn as triangles (:data:`TRIANGLE_MODES`: the
    primitives the encoder makes progressive)."""
    meshes = gltf.get("meshes")
    return [i for i, m in enumerate(meshes if isinstance(meshes, list) else [])
            if isinstance(m, dict) and isinstance(m.get("primitives"), list)
            and any(isinstance(p, dict) and p.get("mode", TRIANGLES) in TRIANGLE_MODES for p in m["primitives"])]


def owner_of_stream(source, key, every: bool = False, last_only: bool = False) -> list:
    """``[OwnerBoundary]`` of a ``.pmw`` (see the module contract), base mesh first; ``last_only``: the last
    boundary alone (:class:`OwnerReader`)."""
    source = _read_twice(source)
    reader = OwnerReader(key, every=every, last_only=last_only, frames=None if last_only else full_decode_frames(source))
    decoder = StreamDecoder(None, None, copy=True)
    for r in iter_results(source, decoder):
        reader.add(r, decoder.header.gltf_json)
    return reader.boundaries


def _read_twice(source):
    """``source`` as a source two passes can read (:func:`iter_results`' kinds): a path or bytes as they are;
    standard input (``"-"``), a binary file object or an iterable of blocks read into bytes
    (:func:`~pmwm_codec.sources.read_all`)."""
    if isinstance(source, (bytes, bytearray, memoryview, os.PathLike)) or (isinstance(source, str) and source != "-"):
        return source
    return read_all(source)


def full_decode_frames(source) -> list | None:
    """The frames of the mesh a ``.pmw`` (a path or bytes) decodes to in full, as the owner read places it
    (:func:`~pmwm_codec.watermark.owner.full_frames` of the scene of its progressive primitives), or None
    when the stream does not decode in full (cut short: no full mesh to take them from).  A stream's levels are
    read in them (:class:`OwnerReader`); they depend on the decoded mesh alone, not on anything the file states
    nor on a key.  None too for a stream this pass cannot read (the read of its levels then meets what stops it,
    and says so as it would have)."""
    decoder = StreamDecoder(None, None, copy=False)
    last = None
    try:
        for r in iter_results(source, decoder):
            last = r
    except PmwError:
        return None
    if last is None or last.chunk != last.chunks_total:
        return None
    return full_frames(*_scene(last.parts, _frames(decoder.header.gltf_json)))


class OwnerReader:
    """The owner layer at every chunk boundary of a stream another reader decodes (``pmw verify`` reads the
    image and the owner in one pass): :meth:`add` each result in stream order; :attr:`boundaries` the
    :class:`OwnerBoundary` list :func:`owner_of_stream` returns.  The layer is read at the first boundary, at
    each whose level has :data:`REREAD_GROWTH` more vertices than the last read, and at the last one added
    (read when :attr:`boundaries` is asked for; the boundaries between carry the last read); ``every``:
    at each; ``last_only``: at the last one only (:attr:`boundaries` is then that one boundary: a verdict on
    the whole file, as ``pmw batch verify`` gives).  ``frames``: the frames of the stream's full decode
    (:func:`full_decode_frames`), which every level is read in in place of its own; None: each in its own."""

    def __init__(self, key, every: bool = False, last_only: bool = False, frames: list | None = None):
        self.key = owner_key(key)
        self.given = frames  # the full decode's frames (full_decode_frames), or None: each level in its own
        self.every = every
        self.last_only = last_only
        self._boundaries: list = []
        self._frames = None
        self._read_vertices = None
        self._pending = None  # the last boundary's parts, when it was not read

    @property
    def boundaries(self) -> list:
        """The :class:`OwnerBoundary` of every boundary added, the last one read."""
        if self._pending is not None:
            last = self._boundaries[-1]
            self._boundaries[-1] = OwnerBoundary(last.chunk, last.bytes_read, last.vertices, self._read(self._pending))
            self._read_vertices, self._pending = last.vertices, None
        return self._boundaries

    def add(self, result, gltf: dict) -> None:
        """Take the boundary of ``result`` (a :class:`~pmwm_codec.stream.PartialResult` whose parts hold the
        meshes of its boundary as copies, which the reader may keep until the next :meth:`add`: a decoder made
        with ``copy=True``) of the stream whose glTF JSON is ``gltf``.  The parts' positions are dequantized and
        the scene put together (:func:`~pmwm_codec.format.gltf.scene_mesh`) only for the boundaries read: a
        boundary costs what its chunk brought, not every primitive again."""
        if self._frames is None:
            self._frames = _frames(gltf)
        vertices = int(result.vertices)
        if self.last_only:  # read when asked for (boundaries), and only that one
            self._boundaries = [OwnerBoundary(result.chunk, int(result.bytes_read), vertices, None)]
            self._pending = result.parts
            return
        if self.every or self._read_vertices is None or vertices >= self._read_vertices * (1 + REREAD_GROWTH):
            self._pending = None
            self._read_vertices = vertices
            self._boundaries.append(OwnerBoundary(result.chunk, int(result.bytes_read), vertices,
                                                  self._read(result.parts)))
            return
        read = next(b for b in reversed(self._boundaries) if b.read_at == b.chunk)
        self._boundaries.append(OwnerBoundary(result.chunk, int(result.bytes_read), vertices, read.owner, read.chunk))
        self._pending = result.parts  # the parts' own copies: kept until the next boundary replaces them

    def _read(self, parts: list):
        """The layer read from the scene of ``parts`` (:class:`~pmwm_codec.stream.decoder.Part`)."""
        return detect(*_scene(parts, self._frames), self.key, given=self.given)


def _scene(parts: list, frames: list) -> tuple:
    """``(positions (n, 3), faces (m, 3))`` of the scene the owner read places a boundary's ``parts``
    (:class:`~pmwm_codec.stream.decoder.Part`) in, by ``frames`` (:func:`_frames`)."""
    positions, faces, _ = scene_mesh([p.positions for p in parts], [p.faces for p in parts], frames)
    return positions, faces


def _frames(gltf: dict) -> list:
    """The matrices every progressive primitive of the document ``gltf`` is placed by for the read (a list
    of lists of (4, 4)): :func:`~pmwm_codec.format.gltf.owner_placements` of their meshes, as the
    encoder marks the layer and as a decoded asset is read."""
    return owner_placements(gltf, [mi for mi, _, _ in find_extension_primitives(gltf, EXTENSION_NAME)])[0]
