"""Base-mesh codec: the ordinary glTF primitive every viewer shows.

Contract
--------
The base mesh arrives as integer grid coordinates on a
:class:`~pmwm_codec.progressive.grid.Grid`: grid integer ``i`` stands for the
position ``origin + i * step``, and every coordinate lies in ``[0, 2**bits)``.
(:func:`encode_base` and :func:`decode_base` also take the grid's extension JSON
form ``{"bits": q, "origin": [x, y, z], "step": s}`` and check it.)

:func:`encode_base` stores the mesh either as plain accessors (``codec="plain"``:
float32 POSITION, UNSIGNED_SHORT/UNSIGNED_INT indices) or as a
``KHR_draco_mesh_compression`` primitive (``codec="draco"``).  Whatever the codec,
reading the positions back and mapping each one with ``round((p - origin) / step)``
gives the input integers *exactly*; the encoder checks this by decoding what it
wrote, and raises (plain) or falls back (Draco) when it does not hold.

A decoder sees vertices in the *decoded* order.  Draco may reorder vertices and
faces, so :class:`EncodedBase` carries ``vertex_map``: decoded vertex ``i`` is
input vertex ``vertex_map[i]``.  Everything downstream (vertex-split indices)
must refer to the decoded order.

Draco's edgebreaker also splits a vertex on a non-manifold edge or at a non-manifold
point into copies at one position.  Rather than falling back to Draco's sequential
coding (about 3x the bytes on scans), the encoder then writes the base's true vertex
count as the extension's ``baseVertexCount`` and every reader *welds* the decoded
copies (:func:`weld`, spec README "Welded base").  A base whose distinct vertices share a grid point
(pieces that touch, seam copies held in the base) carries, in the Draco data, the attribute
:data:`WELD_ATTRIBUTE`: each stored vertex's ordinal among the base's vertices on its point, which the
weld keys on beside the grid integers, so the weld is exact either way.

:func:`decode_base` reads the primitive back from a glTF JSON dict and the BIN
bytes, checking declared counts against :mod:`pmwm_codec.constants` before it
allocates anything.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..constants import MAX_FACES, MAX_VERTICES
from ..errors import FormatError, LimitError
from ..progressive.grid import AttributeGrid, Grid
from ..progressive.seams import weld_groups
from ..progressive.topology import same_face_set, two_alike
from .gltf import (
    ARRAY_BUFFER,
    COMPONENT_DTYPES,
    DRACO_EXTENSION,
    BufferBuilder,
    ELEMENT_ARRAY_BUFFER,
    FLOAT,
    INDEX_DTYPES,
    TRIANGLES,
    UNSIGNED_BYTE,
    UNSIGNED_INT,
    UNSIGNED_SHORT,
    VECTOR_WIDTH,
    accessor_array,
    find_extension_primitive,
    float32_numbers,
    item,
    json_integer,
    uint,
    view_bytes,
)
from .layout import padded

#: Draco GeometryAttribute::Type of POSITION and of a generic attribute.
_DRACO_POSITION_TYPE = 0
_DRACO_GENERIC_TYPE = 4
#: The base primitive's attribute that tells apart a welded base's distinct vertices on one grid point
#: (spec README, "Welded base"): an UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR, one value per stored vertex.
WELD_ATTRIBUTE = "_PMWM_WELD"
#: The weld attribute's componentTypes and the largest ordinal each holds.
WELD_TYPES = {UNSIGNED_BYTE: 0xFF, UNSIGNED_SHORT: 0xFFFF}


@dataclass(frozen=True, eq=False)
class EncodedBase:
    """A base mesh ready to be placed at the start of the BIN chunk.

    ``data`` : bytes
        The base region of the BIN chunk; ``len(data)`` is a multiple of 4.
    ``buffer_views`` : list[dict]
        glTF bufferViews; ``byteOffset`` is relative to the start of ``data``
        (which the writer places at BIN offset 0), ``buffer`` is 0.
    ``accessors`` : list[dict]
        glTF accessors; their ``bufferView`` indices point into ``buffer_views``.
    ``primitive`` : dict
        The glTF primitive (``attributes``, ``indices``, ``mode``, and for Draco
        ``extensions.KHR_draco_mesh_compression``), indices into ``accessors``.
    ``positions_int`` : (n, 3) int64
        Grid coordinates in decoded order (``input[vertex_map]``).
    ``faces`` : (m, 3) int64
        Faces in decoded order, indexing decoded vertices.
    ``vertex_map`` : (n,) int64
        Decoded vertex ``i`` is input vertex ``vertex_map[i]``.
    ``notice`` : str or None
        Set when the encoder did not use what was asked (e.g. Draco fell back
        to plain); tools print it.
    """

    codec: str
    grid: Grid
    data: bytes
    buffer_views: list
    accessors: list
    primitive: dict
    positions_int: np.ndarray
    faces: np.ndarray
    vertex_map: np.ndarray
    extensions_used: tuple = ()
    extensions_required: tuple = ()
    draco_attribute_ids: dict = field(default_factory=dict)
    notice: str | None = None
    #: The vertex count after the weld (``baseVertexCount``), when the stored base has copies.
    welded_count: int | None = None

    @property
    def vertex_count(self) -> int:
        return int(self.positions_int.shape[0])

    @property
    def face_count(self) -> int:
        return int(self.faces.shape[0])


# ------------------------------------------------------------------------ encoding


def _as_grid(grid) -> Grid:
    """``grid`` itself, or the :class:`Grid` of a config dict (FormatError if invalid)."""
    return grid if isinstance(grid, Grid) else Grid.from_config(grid)


def encode_base(positions_int, faces, grid: Grid | dict, codec: str = "draco", *, draco_compression_level: int = 7) -> EncodedBase:
    """Encode a base mesh as a glTF primitive.

    Parameters
    ----------
    positions_int : (n, 3) int64
        Grid coordinates, each in ``[0, 2**grid.bits)``.
    faces : (m, 3) int64
        Triangles indexing ``positions_int``; every vertex should be referenced
        (Draco drops unreferenced vertices; the encoder then falls back to plain).
    grid : Grid
        (or its config dict ``{"bits": q, "origin": [x, y, z], "step": s}``, checked).
    codec : "draco" or "plain"

    Returns
    -------
    EncodedBase
        Positions and faces in decoded order, with ``vertex_map``.  A Draco
        request may come back as ``codec == "plain"`` with ``notice`` set.

    Raises
    ------
    ValueError
        Bad shapes, indices out of range, coordinates off the grid, too many
        vertices/faces, or a grid too fine for float32 positions.
    """
    pos = np.asarray(positions_int)
    tri = np.asarray(faces)
    if pos.ndim != 2 or pos.shape[1] != 3 or pos.shape[0] == 0 or not np.issubdtype(pos.dtype, np.integer):
        raise ValueError(f"encode_base: positions_int must be a non-empty (n, 3) integer array, got {pos.shape} {pos.dtype}")
    if tri.ndim != 2 or tri.shape[1] != 3 or not np.issubdtype(tri.dtype, np.integer):
        raise ValueError(f"encode_base: faces must be an (m, 3) integer array, got {tri.shape} {tri.dtype}")
    pos = pos.astype(np.int64)
    tri = tri.astype(np.int64)
    n, m = pos.shape[0], tri.shape[0]
    if n > MAX_VERTICES or m > MAX_FACES:
        raise ValueError(f"encode_base: {n} vertices / {m} faces exceed the limits {MAX_VERTICES} / {MAX_FACES}")
    if m and (tri.min() < 0 or tri.max() >= n):
        raise ValueError(f"encode_base: face index out of range [0, {n})")
    try:
        grid = _as_grid(grid)
    except FormatError as exc:
        raise ValueError(f"encode_base: {exc}") from None
    if pos.min() < 0 or pos.max() >= (1 << grid.bits):
        raise ValueError(f"encode_base: grid coordinates outside [0, 2**{grid.bits})")

    if codec == "plain":
        return _encode_plain(pos, tri, grid)
    if codec != "draco":
        raise ValueError(f"encode_base: codec must be 'draco' or 'plain', got {codec!r}")
    reason = "it has no faces"
    if m:
        for preserve_order in (False, True):  # Draco's own vertex order first, then ours
            result = _try_draco(pos, tri, grid, preserve_order, draco_compression_level)
            if isinstance(result, EncodedBase):
                return result
            reason = result
    base = _encode_plain(pos, tri, grid)
    notice = f"a base mesh is stored as plain accessors (same geometry, larger): Draco could not store it exactly ({reason})"
    return replace(base, notice=notice)


def _check_float32_exact(pos: np.ndarray, grid: Grid) -> np.ndarray:
    """float32 positions of ``pos`` (n, 3) int64; ValueError when they do not map back exactly."""
    stored = grid.to_float32(pos)
    try:
        back = grid.from_float32(stored)
    except FormatError:
        back = None
    if back is None or not np.array_equal(back, pos):
        raise ValueError(f"encode_base: a {grid.bits}-bit grid at this origin/step does not survive float32 positions")
    return stored


def _encode_plain(pos: np.ndarray, tri: np.ndarray, grid: Grid) -> EncodedBase:
    n = pos.shape[0]
    stored = _check_float32_exact(pos, grid)
    index_type = UNSIGNED_SHORT if n <= 0xFFFF else UNSIGNED_INT
    position_bytes = stored.astype("<f4").tobytes()
    index_bytes = tri.astype(INDEX_DTYPES[index_type]).tobytes()
    index_offset = padded(len(position_bytes))
    data = bytearray(padded(index_offset + len(index_bytes)))
    data[: len(position_bytes)] = position_bytes
    data[index_offset : index_offset + len(index_bytes)] = index_bytes
    buffer_views = [
        {"buffer": 0, "byteOffset": 0, "byteLength": len(position_bytes), "target": ARRAY_BUFFER},
        {"buffer": 0, "byteOffset": index_offset, "byteLength": len(index_bytes), "target": ELEMENT_ARRAY_BUFFER},
    ]
    accessors = [
        _position_accessor(stored, bufferView=0),
        {"bufferView": 1, "componentType": index_type, "count": int(tri.size), "type": "SCALAR"},
    ]
    primitive = {"attributes": {"POSITION": 0}, "indices": 1}  # mode: TRIANGLES, the glTF default
    return EncodedBase(
        codec="plain", grid=grid, data=bytes(data), buffer_views=buffer_views, accessors=accessors,
        primitive=primitive, positions_int=pos.copy(), faces=tri.copy(), vertex_map=np.arange(n, dtype=np.int64),
    )


def _position_accessor(stored: np.ndarray, **extra) -> dict:
    """POSITION accessor with exact float32 min/max (the validator compares them as float32),
    each written as the shortest decimal of its float32.  ``stored`` (n, 3) float32."""
    return {
        **extra, "componentType": FLOAT, "count": int(stored.shape[0]), "type": "VEC3",
        "min": float32_numbers(stored.min(0)), "max": float32_numbers(stored.max(0)),
    }


def _try_draco(pos, tri, grid, preserve_order, level):
    """EncodedBase for a Draco encoding, or a string saying why it is not exact."""
    import DracoPy

    bits = grid.bits
    stored = _check_float32_exact(pos, grid)
    corners = pos[tri]  # (m, 3, 3) grid positions
    if not (np.any(corners[:, 0] != corners[:, 1], axis=1) & np.any(corners[:, 1] != corners[:, 2], axis=1)
            & np.any(corners[:, 2] != corners[:, 0], axis=1)).any():
        # Draco refuses such a mesh, and says so on the process's stderr (C++): not asked at all
        return "every triangle has two corners on one grid point (Draco keeps none of them)"
    # distinct vertices on one grid point: Draco's own order needs the weld attribute to tell them apart
    # (the sequential coder keeps our order: no weld, no attribute)
    ordinals = None if preserve_order else point_ordinals(pos)
    if ordinals is not None and not ordinals.any():
        ordinals = None
    if ordinals is not None and ordinals.max() > WELD_TYPES[UNSIGNED_SHORT]:
        return f"{int(ordinals.max()) + 1} vertices on one grid point (the weld attribute holds {WELD_TYPES[UNSIGNED_SHORT] + 1})"
    # the smallest component type that holds the largest ordinal
    weld_type = None if ordinals is None else min(
        (top, t) for t, top in WELD_TYPES.items() if ordinals.max() <= top)[1]
    # Draco quantizes q = floor((p - origin) * (2**bits - 1) / range + 0.5) and
    # dequantizes origin + q * range / (2**bits - 1): with the grid's own origin
    # and range = step * (2**bits - 1) its integers are our grid integers.
    try:
        encoded = DracoPy.encode(
            stored, tri.astype(np.uint32), quantization_bits=bits, compression_level=level,
            quantization_range=float(grid.step * ((1 << bits) - 1)),
            quantization_origin=list(grid.origin), preserve_order=preserve_order,
            generic_attributes=None if ordinals is None else {
                0: ordinals.astype(COMPONENT_DTYPES[weld_type]).reshape(-1, 1)},
        )
        decoded = DracoPy.decode(encoded)
    except Exception as exc:  # DracoPy raises its own exception types
        return f"DracoPy failed ({exc})"
    ids = {a["attribute_type"]: a["unique_id"] for a in decoded.attributes}
    if _DRACO_POSITION_TYPE not in ids:
        return "no POSITION attribute in the Draco output"
    dpos = np.asarray(decoded.get_attribute_by_unique_id(ids[_DRACO_POSITION_TYPE])["data"], dtype=np.float32)
    dtri = np.asarray(decoded.faces, dtype=np.int64).reshape(-1, 3)
    if dpos.shape[0] < pos.shape[0] or dtri.shape != tri.shape:
        return f"vertex/face count changed {pos.shape[0]}/{tri.shape[0]} -> {dpos.shape[0]}/{dtri.shape[0]}"
    try:
        dint = grid.from_float32(dpos)
    except FormatError as exc:
        return str(exc)
    dclass = None
    if ordinals is not None:
        if _DRACO_GENERIC_TYPE not in ids:
            return "no weld attribute in the Draco output"
        dclass = np.asarray(decoded.get_attribute_by_unique_id(ids[_DRACO_GENERIC_TYPE])["data"]).reshape(-1).astype(np.int64)
    welded_count = None
    if dpos.shape[0] > pos.shape[0] or dclass is not None:
        # edgebreaker split non-manifold vertices, or distinct vertices share a point: readers weld the copies
        dint, dtri, kept_class = weld(dint, dtri, dclass)
        welded_count = pos.shape[0]
        if dint.shape[0] != welded_count:
            return f"welding the decoded copies gives {dint.shape[0]} vertices, not {welded_count}"
    if np.array_equal(dint, pos):  # the order kept (sequential coding): no matching needed, copies or not
        vertex_map = np.arange(pos.shape[0], dtype=np.int64)
    elif dclass is None:
        vertex_map = _match_vertices(dint, pos)
    else:  # a vertex is its grid point and its ordinal there
        vertex_map = _match_vertices(np.column_stack([dint, kept_class]), np.column_stack([pos, ordinals]))
    if vertex_map is None:
        return "decoded positions are not a permutation of the grid positions"
    if not same_face_set(vertex_map[dtri], tri):
        return "decoded faces differ from the input faces"
    draco_view = {"buffer": 0, "byteOffset": 0, "byteLength": len(encoded)}
    index_type = UNSIGNED_SHORT if pos.shape[0] <= 0xFFFF else UNSIGNED_INT
    accessors = [
        _position_accessor(dpos),
        {"componentType": index_type, "count": int(dtri.size), "type": "SCALAR"},
    ]
    attribute_ids = {"POSITION": int(ids[_DRACO_POSITION_TYPE])}
    attributes = {"POSITION": 0}
    if dclass is not None:
        accessors.append({"componentType": weld_type, "count": int(dpos.shape[0]), "type": "SCALAR"})
        attribute_ids[WELD_ATTRIBUTE] = int(ids[_DRACO_GENERIC_TYPE])
        attributes[WELD_ATTRIBUTE] = 2
    primitive = {
        "attributes": attributes, "indices": 1,  # mode: TRIANGLES, the glTF default
        "extensions": {DRACO_EXTENSION: {"bufferView": 0, "attributes": attribute_ids}},
    }
    data = bytes(encoded) + bytes(padded(len(encoded)) - len(encoded))
    return EncodedBase(
        codec="draco", grid=grid, data=data, buffer_views=[draco_view], accessors=accessors, primitive=primitive,
        positions_int=dint, faces=dtri, vertex_map=vertex_map,
        extensions_used=(DRACO_EXTENSION,), extensions_required=(DRACO_EXTENSION,),
        draco_attribute_ids=attribute_ids, welded_count=welded_count,
    )


def point_ordinals(positions_int: np.ndarray) -> np.ndarray:
    """(n,) int64: each vertex's ordinal among the vertices on its grid point, in vertex order (0 for the
    first, and for every vertex alone on its point).  ``positions_int`` (n, 3) int64.  These are the values of
    a welded base's :data:`WELD_ATTRIBUTE` (spec README, "Welded base")."""
    n = positions_int.shape[0]
    groups = weld_groups(positions_int)  # the first vertex on each vertex's point
    if groups is None:
        return np.zeros(n, np.int64)
    order = np.argsort(groups, kind="stable")  # by point, vertex order within one
    sorted_group = groups[order]
    starts = np.flatnonzero(np.r_[True, sorted_group[1:] != sorted_group[:-1]])
    out = np.empty(n, np.int64)
    out[order] = np.arange(n) - np.repeat(starts, np.diff(np.r_[starts, n]))
    return out


def weld(positions_int: np.ndarray, faces: np.ndarray, ordinals: np.ndarray | None = None) -> tuple:
    """Weld a stored base's copies (spec README, "Welded base"): vertices with equal grid
    positions (and equal ``ordinals``, the :data:`WELD_ATTRIBUTE` values, when given) are one vertex,
    the first of them in stored order; the kept vertices are numbered in stored order and every face
    corner names its kept vertex.

    ``positions_int`` (n, 3) int64, ``faces`` (m, 3) int64 indexing it, ``ordinals`` (n,) int64 or None;
    returns the kept positions (n', 3) int64, the faces (m, 3) int64 on them and the kept vertices'
    ordinals (n',) int64 (zeros without ``ordinals``)."""
    n = positions_int.shape[0]
    ordinals = np.zeros(n, np.int64) if ordinals is None else np.asarray(ordinals, np.int64).reshape(-1)
    if n == 0:
        return positions_int, faces, ordinals
    key = np.column_stack([positions_int, ordinals])
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    kept = np.sort(first)
    return positions_int[kept], rank[inverse.reshape(-1)][faces], ordinals[kept]


def _match_vertices(decoded: np.ndarray, original: np.ndarray):
    """(n,) int64 map with ``original[map] == decoded``, or None if the rows are not a permutation.

    Both arrays are (n, 3) int64 grid coordinates; rows of ``original`` must be unique.
    """
    n = original.shape[0]
    uniq, first = np.unique(original, axis=0, return_index=True)
    if uniq.shape[0] != n:
        return None  # duplicate positions: order is ambiguous
    found, where = np.unique(decoded, axis=0, return_inverse=True)
    if found.shape[0] != n or not np.array_equal(found, uniq):
        return None
    return first[where.reshape(-1)].astype(np.int64)


# ------------------------------------------------------------------------ decoding


def base_views(gltf: dict, primitive: dict, progressive_attributes=()) -> list[int]:
    """Indices of the bufferViews the base mesh reads (Draco: one; plain: POSITION, indices,
    and the accessors of the extension's ``attributes`` entries)."""
    attributes = primitive.get("attributes")
    if not isinstance(attributes, dict) or "POSITION" not in attributes:
        raise FormatError("base mesh: primitive has no POSITION attribute")
    extensions = primitive.get("extensions") or {}
    draco = extensions.get(DRACO_EXTENSION) if isinstance(extensions, dict) else None
    if draco is not None:
        if not isinstance(draco, dict):
            raise FormatError(f"base mesh: {DRACO_EXTENSION} must be an object")
        item(gltf.get("bufferViews"), draco.get("bufferView"), "base mesh: bufferView")
        return [draco["bufferView"]]
    accessors = gltf.get("accessors")
    views = []
    extra = []
    for spec in progressive_attributes:
        semantic = spec.get("semantic") if isinstance(spec, dict) else None
        if semantic not in attributes:
            raise FormatError(f"base mesh: progressive attribute {semantic!r} is not an attribute of the primitive")
        extra.append(primitive["attributes"][semantic])
    if WELD_ATTRIBUTE in attributes:
        extra.append(attributes[WELD_ATTRIBUTE])
    for index in [attributes["POSITION"]] + ([primitive["indices"]] if "indices" in primitive else []) + extra:
        acc = item(accessors, index, "base mesh: accessor")
        if "bufferView" not in acc:
            raise FormatError(f"base mesh: accessor {index} has no bufferView")
        item(gltf.get("bufferViews"), acc["bufferView"], "base mesh: bufferView")
        views.append(acc["bufferView"])
    return views


def base_counts(gltf: dict, primitive: dict):
    """Declared sizes of a base primitive, limit-checked before anything is allocated.

    Returns ``(n, m, index componentType, POSITION accessor, indices accessor)``;
    raises FormatError (bad mode or accessors) or LimitError (counts over the limits).
    """
    mode = primitive.get("mode", TRIANGLES)
    if mode != TRIANGLES:
        raise FormatError(f"base mesh: primitive mode must be TRIANGLES (4), got {mode!r}")
    attributes = primitive.get("attributes")
    if not isinstance(attributes, dict) or "POSITION" not in attributes:
        raise FormatError("base mesh: primitive has no POSITION attribute")
    accessors = gltf.get("accessors")
    pos_acc = item(accessors, attributes["POSITION"], "base mesh: accessor")
    if pos_acc.get("componentType") != FLOAT or pos_acc.get("type") != "VEC3":
        raise FormatError("base mesh: POSITION must be a FLOAT VEC3 accessor")
    n = uint(pos_acc, "count", "base mesh: POSITION accessor")
    if n > MAX_VERTICES:
        raise LimitError(f"base mesh: {n} vertices exceed the limit {MAX_VERTICES}")
    if "indices" not in primitive:
        raise FormatError("base mesh: primitive has no indices")
    idx_acc = item(accessors, primitive["indices"], "base mesh: accessor")
    ctype = idx_acc.get("componentType")
    if not isinstance(ctype, int) or ctype not in (UNSIGNED_SHORT, UNSIGNED_INT) or idx_acc.get("type") != "SCALAR":
        raise FormatError(f"base mesh: indices must be an UNSIGNED_SHORT or UNSIGNED_INT SCALAR accessor (spec README, Base mesh), got componentType {ctype!r}")
    count = uint(idx_acc, "count", "base mesh: indices accessor")
    if count % 3:
        raise FormatError(f"base mesh: index count {count} is not a multiple of 3")
    m = count // 3
    if m > MAX_FACES:
        raise LimitError(f"base mesh: {m} faces exceed the limit {MAX_FACES}")
    return n, m, ctype, pos_acc, idx_acc


def decode_base(gltf: dict, bin_data, grid: Grid | dict, primitive: dict | None = None):
    """Read the base mesh back.

    Parameters
    ----------
    gltf : dict
        The parsed glTF JSON.
    bin_data : bytes-like
        The BIN chunk payload from offset 0, at least up to the end of the base
        mesh bufferViews.
    grid : Grid
        The extension's grid (or its config dict ``{"bits", "origin", "step"}``, checked).
    primitive : dict, optional
        The primitive to read; default: the one carrying the PMWM extension.

    Returns
    -------
    positions_int : (n, 3) int64
    faces : (m, 3) int64

    Raises
    ------
    FormatError, LimitError
        Bad accessors, counts over the limits (checked before allocating), index
        out of range, positions off the grid, undecodable Draco data.
    """
    from ..constants import EXTENSION_NAME

    if primitive is None:
        primitive = find_extension_primitive(gltf, EXTENSION_NAME)[2]
    base_views(gltf, primitive)
    n, m, ctype, pos_acc, idx_acc = base_counts(gltf, primitive)
    draco = (primitive.get("extensions") or {}).get(DRACO_EXTENSION)  # shape checked in base_views
    weld_acc = weld_accessor(gltf, primitive, n)
    ordinals = None
    if draco is not None:
        positions, faces, ordinals = _decode_draco(gltf, draco, bin_data, n, m, weld_acc is not None)
    else:
        positions = accessor_array(gltf, pos_acc, bin_data, "<f4", n, 3, "base mesh: POSITION")
        faces = accessor_array(gltf, idx_acc, bin_data, INDEX_DTYPES[ctype], m, 3, "base mesh: indices",
                               vertex_attribute=False).astype(np.int64)
        if weld_acc is not None:
            ordinals = accessor_array(gltf, weld_acc, bin_data, COMPONENT_DTYPES[weld_acc["componentType"]], n, 1,
                                      f"base mesh: {WELD_ATTRIBUTE}").reshape(-1).astype(np.int64)
    if faces.size and faces.max() >= n:
        raise FormatError(f"base mesh: face index {int(faces.max())} out of range [0, {n})")
    positions = _as_grid(grid).from_float32(positions)
    if welded_vertex_count(primitive) is not None:
        welded = base_vertex_count(gltf, primitive)  # at most the stored count
        positions, faces, _ = weld(positions, faces, ordinals)
        if positions.shape[0] != welded:
            raise FormatError(f"base mesh: welding gives {positions.shape[0]} vertices, baseVertexCount says {welded}")
    if two_alike(faces).any():
        raise FormatError("base mesh: a face repeats a vertex (a valid base has only proper triangles)")
    return positions, faces


def weld_accessor(gltf: dict, primitive: dict, n: int) -> dict | None:
    """The accessor of the base's :data:`WELD_ATTRIBUTE`, or None without one; FormatError unless it is an
    UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR (not normalized) of the ``n`` stored vertices on a welded base."""
    attributes = primitive.get("attributes") or {}
    if WELD_ATTRIBUTE not in attributes:
        return None
    if welded_vertex_count(primitive) is None:
        raise FormatError(f"base mesh: {WELD_ATTRIBUTE} without baseVertexCount (it serves the weld only)")
    acc = item(gltf.get("accessors"), attributes[WELD_ATTRIBUTE], "base mesh: accessor")
    if acc.get("componentType") not in WELD_TYPES or acc.get("type") != "SCALAR" or acc.get("normalized"):
        raise FormatError(f"base mesh: {WELD_ATTRIBUTE} must be an UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR accessor")
    if uint(acc, "count", f"base mesh: {WELD_ATTRIBUTE} accessor") != n:
        raise FormatError(f"base mesh: {WELD_ATTRIBUTE} has {acc.get('count')} values for {n} stored vertices")
    return acc


def welded_vertex_count(primitive: dict) -> int | None:
    """The extension's ``baseVertexCount`` (the base's vertex count after the weld) as an int, or
    None when the base is not welded; FormatError unless it is a positive integer without
    progressive attributes (a weld by position would merge their seams)."""
    from ..constants import EXTENSION_NAME

    ext = (primitive.get("extensions") or {}).get(EXTENSION_NAME) or {}
    count = ext.get("baseVertexCount")
    if count is None:
        return None
    if ext.get("attributes"):
        raise FormatError("base mesh: baseVertexCount (a welded base) with progressive attributes")
    if json_integer(count) is None or count < 1:
        raise FormatError(f"base mesh: baseVertexCount {count!r} is not a positive integer")
    return json_integer(count)


def base_vertex_count(gltf: dict, primitive: dict) -> int:
    """The base's vertex count as the chunks see it: ``baseVertexCount`` for a welded base,
    else the POSITION accessor's count (limit-checked)."""
    n = base_counts(gltf, primitive)[0]
    welded = welded_vertex_count(primitive)
    if welded is not None and welded > n:
        raise FormatError(f"base mesh: baseVertexCount {welded} exceeds the {n} stored vertices")
    return n if welded is None else welded


def _decode_draco(gltf, draco, bin_data, n, m, welds=False):
    """Positions (n, 3) float32, faces (m, 3) int64 and, when ``welds``, the :data:`WELD_ATTRIBUTE`
    values (n,) int64 (else None) of a Draco base."""
    import DracoPy

    _, raw = view_bytes(gltf, [bin_data], draco.get("bufferView"), "base mesh: Draco")
    ids = draco.get("attributes")
    if not isinstance(ids, dict) or "POSITION" not in ids:
        raise FormatError(f"base mesh: {DRACO_EXTENSION}.attributes has no POSITION id")
    if welds and WELD_ATTRIBUTE not in ids:
        raise FormatError(f"base mesh: {DRACO_EXTENSION}.attributes has no {WELD_ATTRIBUTE} id")
    try:
        mesh = DracoPy.decode(bytes(raw))
        attribute = mesh.get_attribute_by_unique_id(ids["POSITION"])
        welding = mesh.get_attribute_by_unique_id(ids[WELD_ATTRIBUTE]) if welds else None
    except Exception as exc:  # DracoPy raises its own exception types
        raise FormatError(f"base mesh: Draco data does not decode ({exc})") from None
    for name, found in (("POSITION", attribute), (WELD_ATTRIBUTE, welding if welds else True)):
        if found is None:
            raise FormatError(f"base mesh: Draco data has no attribute with unique id {ids[name]!r} ({name})")
    positions = np.asarray(attribute["data"], dtype=np.float32)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    if positions.shape != (n, 3) or faces.reshape(-1, 3).shape != (m, 3):
        raise FormatError(f"base mesh: Draco decoded {positions.shape[0]} vertices / {faces.size // 3} faces, accessors declare {n} / {m}")
    ordinals = None
    if welds:
        values = np.asarray(welding["data"])
        if values.size != n or not np.issubdtype(values.dtype, np.integer) or (values < 0).any():
            raise FormatError(f"base mesh: the Draco {WELD_ATTRIBUTE} is not one non-negative integer per vertex")
        ordinals = values.reshape(-1).astype(np.int64)
    return positions, faces.reshape(-1, 3), ordinals


# ------------------------------------------------------------------ attributes


def decode_base_attributes(gltf: dict, bin_data, primitive: dict, attributes) -> np.ndarray:
    """The base's progressive attributes as (n, a) int64 grid integers (a = 0 without any)."""
    n = base_vertex_count(gltf, primitive)
    columns = []
    for spec in attributes:
        semantic = spec["semantic"]
        grid = AttributeGrid.from_config(spec)
        acc = item(gltf.get("accessors"), primitive["attributes"][semantic], "base mesh: accessor")
        width = VECTOR_WIDTH.get(acc.get("type"))
        ctype = acc.get("componentType")
        if ctype not in {FLOAT, stored_type(spec)} or acc.get("normalized") or width is None or width != grid.width:
            named = "" if stored_type(spec) == FLOAT else f" or a componentType {stored_type(spec)} one"
            raise FormatError(f"base mesh: {semantic} must be a FLOAT accessor{named} with {grid.width} components")
        if uint(acc, "count", f"base mesh: {semantic} accessor") != n:
            raise FormatError(f"base mesh: {semantic} has {acc.get('count')} values for {n} vertices")
        values = accessor_array(gltf, acc, bin_data, COMPONENT_DTYPES[ctype], n, width, f"base mesh: {semantic}")
        columns.append(grid.from_float32(values.astype(np.float32), semantic))  # integers: below 2^24, exact
    if not columns:
        return np.zeros((n, 0), dtype=np.int64)
    return np.concatenate(columns, axis=1)


def stored_type(spec: dict) -> int:
    """The componentType a plain base stores the progressive attribute ``spec`` (an extension ``attributes``
    entry) with: the integer componentType it names (its exact integers: ``JOINTS_n`` must be UNSIGNED_BYTE or
    UNSIGNED_SHORT for a viewer to skin with the base), FLOAT for UNSIGNED_INT (which glTF allows for indices
    only) and for every other attribute.  A reader takes FLOAT too (files written before integer bases)."""
    ctype = spec.get("componentType")
    return FLOAT if ctype is None or ctype == UNSIGNED_INT else int(ctype)


def with_attributes(base: EncodedBase, attributes) -> EncodedBase:
    """Append plain float32 accessors for progressive attributes to a *plain* base.

    ``attributes`` : list of ``(spec, ints (n, k) int64 in the base's decoded order)``
    where ``spec`` is an extension ``attributes`` entry: ``semantic`` plus the
    :class:`AttributeGrid` config (``bits``, ``origin``, ``step``).
    """
    if base.codec != "plain":
        raise ValueError("with_attributes: attributes ride only on a plain base")
    views = [dict(v) for v in base.buffer_views]
    accessors = [dict(a) for a in base.accessors]
    primitive = {**base.primitive, "attributes": dict(base.primitive["attributes"])}
    out = BufferBuilder(views, accessors, [base.data], len(base.data))
    for spec, ints in attributes:
        stored = AttributeGrid.from_config(spec).to_float32(ints).astype("<f4")
        ctype = stored_type(spec)
        primitive["attributes"][spec["semantic"]] = (out.add_accessor(stored, FLOAT, ARRAY_BUFFER) if ctype == FLOAT
                                                     else out.add_vertex_integers(stored, ctype, ARRAY_BUFFER))
    return replace(base, data=b"".join(out.parts), buffer_views=views, accessors=accessors, primitive=primitive)

