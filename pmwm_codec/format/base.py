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

Progressive attributes (texture coordinates, colours, normals, joints) ride on either codec: plain
accessors, or Draco attributes (``TEXCOORD_0`` as Draco's texture coordinate, quantized finer than the
attribute grid and checked to round back; the others as generic attributes holding what a plain base
stores), welded with the positions.

:func:`decode_base` reads the primitive back from a glTF JSON dict and the BIN
bytes, checking declared counts against :mod:`pmwm_codec.constants` before it
allocates anything; :func:`read_base` with the attributes.
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
import threading
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
    WIDTH_TYPE,
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
_DRACO_TEX_COORD_TYPE = 3
_DRACO_GENERIC_TYPE = 4
#: The DracoPy generic-attribute key (the Draco unique id) of the weld attribute; progressive attributes stored
#: as generic Draco attributes take the keys after it.
_WELD_KEY = 0
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


def encode_base(positions_int, faces, grid: Grid | dict, codec: str = "draco", *, draco_compression_level: int = 7,
                attributes=()) -> EncodedBase:
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
    attributes : list of ``(spec, ints (n, k) int64)``
        Progressive attributes in the input's vertex order (``spec`` an extension ``attributes``
        entry): a Draco base carries them as Draco attributes (:func:`_draco_attribute_plan`), a plain
        one as accessors (:func:`with_attributes`).

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

    attributes = [(spec, np.asarray(ints, np.int64).reshape(n, -1)) for spec, ints in attributes]
    if codec == "plain":
        return with_attributes(_encode_plain(pos, tri, grid), attributes)
    if codec != "draco":
        raise ValueError(f"encode_base: codec must be 'draco' or 'plain', got {codec!r}")
    reason = "it has no faces"
    if m:
        # Draco's own vertex order first, then ours; texture coordinates as Draco's own (quantized and
        # predicted), else as generic floats
        textures = (True, False) if any(spec["semantic"] == "TEXCOORD_0" for spec, _ in attributes) else (False,)
        for preserve_order in (False, True):
            for texture in textures:
                result = _try_draco(pos, tri, grid, preserve_order, draco_compression_level, attributes, texture)
                if isinstance(result, EncodedBase):
                    return result
                reason = result
    base = with_attributes(_encode_plain(pos, tri, grid), attributes)
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


@contextlib.contextmanager
def _draco_messages():
    """Keep Draco's own messages off the process's standard error while the block runs; yields a list that
    receives them (lines of text, after the block).

    Draco's C++ encoder refuses some inputs at some settings (seen: the texture coordinates of parts a tenth
    of a millimetre across, given our grid's quantization range, at compression level 7 and above: "Draco
    encoding error: Failed to encode point attributes.") and writes that to file descriptor 2 beside the
    exception DracoPy raises.  The encoder tries Draco and falls back (:func:`encode_base`), so a refusal is
    an expected outcome, not the user's concern: the lines become part of the fallback's reason.  Lines that
    are not Draco's (another thread's) are written back to standard error after the block.  One block at a
    time in a process (a Dask worker of several threads encodes in each: the descriptor is the process's);
    without a file descriptor 2, nothing is captured.
    """
    with _STDERR_LOCK:
        said: list = []
        try:
            saved = os.dup(2)
        except OSError:
            yield said
            return
        with contextlib.suppress(Exception):
            sys.stderr.flush()
        try:
            with tempfile.TemporaryFile() as capture:
                os.dup2(capture.fileno(), 2)
                try:
                    yield said
                finally:
                    os.dup2(saved, 2)
                    capture.seek(0)
                    others = []
                    for line in capture.read().decode("utf-8", "replace").splitlines():
                        (said if line.startswith("Draco") else others).append(line.strip())
                    if others:
                        with contextlib.suppress(OSError):
                            os.write(2, ("\n".join(others) + "\n").encode())
        finally:
            os.close(saved)


#: :func:`_draco_messages` redirects the process's file descriptor 2: one thread at a time.
_STDERR_LOCK = threading.Lock()


def _position_accessor(stored: np.ndarray, **extra) -> dict:
    """POSITION accessor with exact float32 min/max (the validator compares them as float32),
    each written as the shortest decimal of its float32.  ``stored`` (n, 3) float32."""
    return {
        **extra, "componentType": FLOAT, "count": int(stored.shape[0]), "type": "VEC3",
        "min": float32_numbers(stored.min(0)), "max": float32_numbers(stored.max(0)),
    }


def _try_draco(pos, tri, grid, preserve_order, level, attributes=(), texture=False):
    """EncodedBase for a Draco encoding, or a string saying why it is not exact.  ``attributes``: list of
    ``(spec, ints (n, k) int64)`` in the order of ``pos`` (:func:`encode_base`); ``texture``: ``TEXCOORD_0``
    as Draco's texture coordinate (:func:`_draco_attribute_plan`)."""
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
    plan = _draco_attribute_plan(attributes, texture)
    generic = {} if ordinals is None else {_WELD_KEY: ordinals.astype(COMPONENT_DTYPES[weld_type]).reshape(-1, 1)}
    generic.update({p.key: p.values for p in plan if p.key is not None})
    tex = next((p for p in plan if p.key is None), None)
    extra = {} if tex is None else {"tex_coord": tex.values, "tex_coord_quantization_bits": tex.bits}
    # Draco quantizes q = floor((p - origin) * (2**bits - 1) / range + 0.5) and
    # dequantizes origin + q * range / (2**bits - 1): with the grid's own origin
    # and range = step * (2**bits - 1) its integers are our grid integers.
    said: list = []
    try:
        with _draco_messages() as said:
            encoded = DracoPy.encode(
                stored, tri.astype(np.uint32), quantization_bits=bits, compression_level=level,
                quantization_range=float(grid.step * ((1 << bits) - 1)),
                quantization_origin=list(grid.origin), preserve_order=preserve_order,
                generic_attributes=generic or None, **extra,
            )
        decoded = DracoPy.decode(encoded)
    except Exception as exc:  # DracoPy raises its own exception types
        return f"DracoPy failed ({exc}{': ' + said[0] if said else ''})"
    types = {}  # Draco attribute type -> the unique ids of that type
    for a in decoded.attributes:
        types.setdefault(a["attribute_type"], []).append(int(a["unique_id"]))
    if len(types.get(_DRACO_POSITION_TYPE, ())) != 1 or (tex is not None and len(types.get(_DRACO_TEX_COORD_TYPE, ())) != 1):
        return "no POSITION (or texture coordinate) attribute in the Draco output"
    if not set(generic) <= set(types.get(_DRACO_GENERIC_TYPE, ())):
        return "a generic attribute is missing from the Draco output"
    ids = {p.spec["semantic"]: (types[_DRACO_TEX_COORD_TYPE][0] if p.key is None else p.key) for p in plan}
    if ordinals is not None:
        ids[WELD_ATTRIBUTE] = _WELD_KEY
    ids["POSITION"] = types[_DRACO_POSITION_TYPE][0]
    found = {}
    for name, uid in ids.items():
        attr = decoded.get_attribute_by_unique_id(uid)
        if attr is None:
            return f"no {name} attribute in the Draco output"
        found[name] = np.asarray(attr["data"])
    dpos = found["POSITION"].astype(np.float32).reshape(-1, 3)
    dtri = np.asarray(decoded.faces, dtype=np.int64).reshape(-1, 3)
    if dpos.shape[0] < pos.shape[0] or dtri.shape != tri.shape:
        return f"vertex/face count changed {pos.shape[0]}/{tri.shape[0]} -> {dpos.shape[0]}/{dtri.shape[0]}"
    try:
        dint = grid.from_float32(dpos)
        dattr = [AttributeGrid.from_config(p.spec).from_float32(
            found[p.spec["semantic"]].astype(np.float32).reshape(len(dpos), -1), p.spec["semantic"]) for p in plan]
    except (FormatError, ValueError) as exc:
        return str(exc)
    dclass = None if ordinals is None else found[WELD_ATTRIBUTE].reshape(-1).astype(np.int64)
    welded_count = None
    stored_count = dpos.shape[0]
    if stored_count > pos.shape[0] or dclass is not None:
        # edgebreaker split non-manifold vertices, or distinct vertices share a point: readers weld the copies
        kept, number = weld_kept(dint, dclass)
        if any((d[kept][number] != d).any() for d in dattr):
            return "copies the weld joins carry different attribute values"
        dint, dtri, dattr = dint[kept], number[dtri], [d[kept] for d in dattr]
        kept_class = None if dclass is None else dclass[kept]
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
    if any(not np.array_equal(d, ints[vertex_map]) for d, (_, ints) in zip(dattr, attributes)):
        return "decoded attribute values differ from the input's"
    draco_view = {"buffer": 0, "byteOffset": 0, "byteLength": len(encoded)}
    index_type = UNSIGNED_SHORT if pos.shape[0] <= 0xFFFF else UNSIGNED_INT
    accessors = [
        _position_accessor(dpos),
        {"componentType": index_type, "count": int(dtri.size), "type": "SCALAR"},
    ]
    attribute_ids = {"POSITION": int(ids["POSITION"])}
    primitive_attributes = {"POSITION": 0}
    for p in plan:
        primitive_attributes[p.spec["semantic"]] = len(accessors)
        attribute_ids[p.spec["semantic"]] = int(ids[p.spec["semantic"]])
        accessors.append({"componentType": p.component_type, "count": int(stored_count),
                          "type": WIDTH_TYPE[p.values.shape[1]]})
    if dclass is not None:
        primitive_attributes[WELD_ATTRIBUTE] = len(accessors)
        attribute_ids[WELD_ATTRIBUTE] = _WELD_KEY
        accessors.append({"componentType": weld_type, "count": int(stored_count), "type": "SCALAR"})
    primitive = {
        "attributes": primitive_attributes, "indices": 1,  # mode: TRIANGLES, the glTF default
        "extensions": {DRACO_EXTENSION: {"bufferView": 0, "attributes": attribute_ids}},
    }
    data = bytes(encoded) + bytes(padded(len(encoded)) - len(encoded))
    return EncodedBase(
        codec="draco", grid=grid, data=data, buffer_views=[draco_view], accessors=accessors, primitive=primitive,
        positions_int=dint, faces=dtri, vertex_map=vertex_map,
        extensions_used=(DRACO_EXTENSION,), extensions_required=(DRACO_EXTENSION,),
        draco_attribute_ids=attribute_ids, welded_count=welded_count,
    )


@dataclass(frozen=True)
class _DracoAttribute:
    """How a Draco base stores one progressive attribute: ``key`` its DracoPy generic-attribute key (its
    unique id), or None for Draco's texture coordinate (``TEXCOORD_0``, quantized with ``bits``);
    ``values`` (n, k) the array handed to DracoPy; ``component_type`` the accessor's."""

    spec: dict
    key: int | None
    values: np.ndarray
    component_type: int
    bits: int = 0


def _draco_attribute_plan(attributes, texture: bool = True) -> list:
    """Per progressive attribute ``(spec, ints (n, k) int64)``, a :class:`_DracoAttribute`.

    With ``texture``, ``TEXCOORD_0`` on a linear float grid rides as Draco's texture coordinate, which Draco predicts from the
    positions and quantizes on its own grid (the base's range of values over ``2**bits - 1``): ``bits`` is
    chosen so that Draco's step is at most a quarter of the smallest of ours, so every Draco value rounds back
    to our integer (``_try_draco`` checks it, and falls back when not).  Every other attribute rides as a
    generic attribute holding the values a plain base stores: the exact integers of an unsigned integer
    attribute (``JOINTS_n``: a viewer skins the base with them), else float32 (Draco keeps generic floats
    as they are)."""
    plan, key = [], _WELD_KEY + 1
    for spec, ints in attributes:
        grid = AttributeGrid.from_config(spec)
        stored = grid.to_float32(ints)
        ctype = stored_type(spec)
        if texture and spec["semantic"] == "TEXCOORD_0" and ctype == FLOAT and grid.transfer is None and stored.shape[1] == 2:
            wide = stored.astype(np.float64)
            span = float((wide.max(0) - wide.min(0)).max()) if len(wide) else 0.0
            need = math.ceil(math.log2(4.0 * span / min(grid.step) + 1.0)) if span > 0 else 0
            if 1 <= need <= 30:
                plan.append(_DracoAttribute(spec, None, wide, FLOAT, need))
                continue
        if ctype in (UNSIGNED_BYTE, UNSIGNED_SHORT):
            plan.append(_DracoAttribute(spec, key, np.rint(stored).astype(COMPONENT_DTYPES[ctype]), ctype))
        else:
            plan.append(_DracoAttribute(spec, key, stored.astype(np.float32), FLOAT))
        key += 1
    return plan


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
    kept, number = weld_kept(positions_int, ordinals)
    ordinals = np.zeros(positions_int.shape[0], np.int64) if ordinals is None else np.asarray(ordinals, np.int64).reshape(-1)
    return positions_int[kept], number[faces], ordinals[kept]


def weld_kept(positions_int: np.ndarray, ordinals: np.ndarray | None = None) -> tuple:
    """``(kept (n',) int64, number (n,) int64)``: the stored vertices the weld keeps (ascending) and the
    kept vertex each stored vertex becomes (:func:`weld`).  ``positions_int`` (n, 3) int64, ``ordinals``
    (n,) int64 or None."""
    n = positions_int.shape[0]
    ordinals = np.zeros(n, np.int64) if ordinals is None else np.asarray(ordinals, np.int64).reshape(-1)
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    key = np.column_stack([positions_int, ordinals])
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    rank = np.empty(len(first), np.int64)
    rank[np.argsort(first)] = np.arange(len(first))
    return np.sort(first).astype(np.int64), rank[inverse.reshape(-1)]


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
    _refuse_sparse_base(gltf, primitive, progressive_attributes)
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


def _refuse_sparse_base(gltf: dict, primitive: dict, progressive_attributes=()) -> None:
    """FormatError when an accessor of the base (``POSITION``, ``indices``, a progressive attribute, the weld
    attribute) is sparse (spec README, *Base mesh*): a glTF viewer applies the substitution, the readers of this
    extension decode the stored values, and the MACs cover what they decode (its accessors are ``null`` in the
    ``sceneMac``'s document), so the base a viewer showed would not be the one verified."""
    attributes = primitive.get("attributes")
    accessors = gltf.get("accessors")
    if not isinstance(attributes, dict) or not isinstance(accessors, list):
        return
    names = ["POSITION", WELD_ATTRIBUTE] + [s.get("semantic") for s in progressive_attributes if isinstance(s, dict)]
    indices = [attributes[n] for n in names if n in attributes] + ([primitive["indices"]] if "indices" in primitive else [])
    for index in map(json_integer, indices):
        if index is not None and 0 <= index < len(accessors) and isinstance(accessors[index], dict) \
                and "sparse" in accessors[index]:
            raise FormatError(f"base mesh: accessor {index} is sparse; a base accessor holds its values as stored "
                              "(spec README, Base mesh)")


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
    if count > 3 * MAX_FACES:  # over the limit before its shape (spec README, Kinds of refusal), as JavaScript
        raise LimitError(f"base mesh: {count} indices exceed the limit of {MAX_FACES} faces")
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
    return read_base(gltf, bin_data, grid, primitive)[:2]


def read_base(gltf: dict, bin_data, grid: Grid | dict, primitive: dict | None = None, attributes=()) -> tuple:
    """:func:`decode_base` with the base's progressive ``attributes`` (the extension's ``attributes`` entries):
    ``(positions_int (n, 3) int64, faces (m, 3) int64, values (n, a) int64)``, ``values`` every attribute's grid
    integers side by side in the order of ``attributes`` (a = 0 without any), welded with the positions."""
    from ..constants import EXTENSION_NAME

    if primitive is None:
        primitive = find_extension_primitive(gltf, EXTENSION_NAME)[2]
    base_views(gltf, primitive, attributes)
    n, m, ctype, pos_acc, idx_acc = base_counts(gltf, primitive)
    draco = (primitive.get("extensions") or {}).get(DRACO_EXTENSION)  # shape checked in base_views
    weld_acc = weld_accessor(gltf, primitive, n)
    grids = [AttributeGrid.from_config(spec) for spec in attributes]
    accs = [_attribute_accessor(gltf, primitive, spec, g, n) for spec, g in zip(attributes, grids)]
    semantics = [spec["semantic"] for spec in attributes]
    if draco is not None:
        names = ["POSITION"] + semantics + ([WELD_ATTRIBUTE] if weld_acc is not None else [])
        types = [FLOAT] + [acc["componentType"] for acc in accs] + ([weld_acc["componentType"]] if weld_acc else [])
        stored, faces = _decode_draco(gltf, draco, bin_data, n, m, names, [3] + [g.width for g in grids] + [1], types)
    else:
        stored = {"POSITION": accessor_array(gltf, pos_acc, bin_data, "<f4", n, 3, "base mesh: POSITION")}
        faces = accessor_array(gltf, idx_acc, bin_data, INDEX_DTYPES[ctype], m, 3, "base mesh: indices",
                               vertex_attribute=False).astype(np.int64)
        for semantic, g, acc in zip(semantics, grids, accs):
            stored[semantic] = accessor_array(gltf, acc, bin_data, COMPONENT_DTYPES[acc["componentType"]], n, g.width,
                                              f"base mesh: {semantic}")
        if weld_acc is not None:
            stored[WELD_ATTRIBUTE] = accessor_array(gltf, weld_acc, bin_data, COMPONENT_DTYPES[weld_acc["componentType"]],
                                                    n, 1, f"base mesh: {WELD_ATTRIBUTE}")
    if faces.size and faces.max() >= n:
        raise FormatError(f"base mesh: face index {int(faces.max())} out of range [0, {n})")
    _check_bounds(pos_acc, stored["POSITION"])
    positions = _as_grid(grid).from_float32(stored["POSITION"])
    columns = [g.from_float32(stored[s].astype(np.float32), s) for s, g in zip(semantics, grids)]  # integers: exact
    values = np.concatenate(columns, axis=1) if columns else np.zeros((n, 0), np.int64)
    if welded_vertex_count(primitive) is not None:
        welded = base_vertex_count(gltf, primitive)  # at most the stored count
        ordinals = stored.get(WELD_ATTRIBUTE)
        if ordinals is not None:
            ordinals = ordinals.reshape(-1)
            if not np.issubdtype(ordinals.dtype, np.integer) or (ordinals < 0).any():
                raise FormatError(f"base mesh: the {WELD_ATTRIBUTE} values are not non-negative integers")
        kept, number = weld_kept(positions, ordinals)
        if (values[kept][number] != values).any():
            raise FormatError("base mesh: copies the weld joins carry different attribute values (spec README, Welded base)")
        positions, faces, values = positions[kept], number[faces], values[kept]
        if positions.shape[0] != welded:
            raise FormatError(f"base mesh: welding gives {positions.shape[0]} vertices, baseVertexCount says {welded}")
    if two_alike(faces).any():
        raise FormatError("base mesh: a face repeats a vertex (a valid base has only proper triangles)")
    return positions, faces, values


def _check_bounds(acc: dict, stored: np.ndarray) -> None:
    """FormatError unless the POSITION accessor's ``min`` / ``max``, where given, are the exact float32 bounds of the
    ``stored`` (n, 3) positions (spec README, *Base mesh*): three.js takes a mesh's bounding box and sphere from them
    and culls by them, and they are outside every MAC (the base accessors are ``null`` in the ``sceneMac``'s document)."""
    for name, bound in (("min", np.min), ("max", np.max)):
        if name not in acc:
            continue
        given = acc[name]
        if not isinstance(given, list) or len(given) != 3 or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) for x in given):
            raise FormatError(f"base mesh: POSITION {name} is not three numbers")
        with np.errstate(over="ignore"):  # a number past float32 is no float32 bound: inf, unequal (no warning)
            exact = not stored.shape[0] or np.array_equal(np.asarray(given, np.float64).astype(np.float32),
                                                          bound(stored, axis=0).astype(np.float32))
        if not exact:
            raise FormatError(f"base mesh: POSITION {name} {given} is not the bound of its values "
                              f"{float32_numbers(bound(stored, axis=0))} (spec README, Base mesh)")


def _attribute_accessor(gltf: dict, primitive: dict, spec: dict, grid: AttributeGrid, n: int) -> dict:
    """The base accessor of the progressive attribute ``spec``, checked: FLOAT or the componentType the
    attribute names (:func:`stored_type`), not normalized, ``grid.width`` components, ``n`` values."""
    semantic = spec["semantic"]
    if semantic not in primitive["attributes"]:
        raise FormatError(f"base mesh: progressive attribute {semantic!r} is not an attribute of the primitive")
    acc = item(gltf.get("accessors"), primitive["attributes"][semantic], "base mesh: accessor")
    ctype = acc.get("componentType")
    if json_integer(ctype) is None or ctype not in {FLOAT, stored_type(spec)} or acc.get("normalized") \
            or not isinstance(acc.get("type"), str) or VECTOR_WIDTH.get(acc.get("type")) != grid.width:
        named = "" if stored_type(spec) == FLOAT else f" or a componentType {stored_type(spec)} one"
        raise FormatError(f"base mesh: {semantic} must be a FLOAT accessor{named} with {grid.width} components")
    count = uint(acc, "count", f"base mesh: {semantic} accessor")
    if count > MAX_VERTICES:  # an accessor's count over MAX_VERTICES (spec README, Kinds of refusal)
        raise LimitError(f"base mesh: {semantic} accessor's count {count} exceeds the limit {MAX_VERTICES}")
    if count != n:
        raise FormatError(f"base mesh: {semantic} has {acc.get('count')} values for {n} stored vertices")
    return acc


def weld_accessor(gltf: dict, primitive: dict, n: int) -> dict | None:
    """The accessor of the base's :data:`WELD_ATTRIBUTE`, or None without one; FormatError unless it is an
    UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR (not normalized) of the ``n`` stored vertices on a welded base."""
    attributes = primitive.get("attributes") or {}
    if WELD_ATTRIBUTE not in attributes:
        return None
    if welded_vertex_count(primitive) is None:
        raise FormatError(f"base mesh: {WELD_ATTRIBUTE} without baseVertexCount (it serves the weld only)")
    acc = item(gltf.get("accessors"), attributes[WELD_ATTRIBUTE], "base mesh: accessor")
    if json_integer(acc.get("componentType")) is None or acc.get("componentType") not in WELD_TYPES \
            or acc.get("type") != "SCALAR" or acc.get("normalized"):
        raise FormatError(f"base mesh: {WELD_ATTRIBUTE} must be an UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR accessor")
    count = uint(acc, "count", f"base mesh: {WELD_ATTRIBUTE} accessor")
    if count > MAX_VERTICES:
        raise LimitError(f"base mesh: {WELD_ATTRIBUTE} accessor's count {count} exceeds the limit {MAX_VERTICES}")
    if count != n:
        raise FormatError(f"base mesh: {WELD_ATTRIBUTE} has {acc.get('count')} values for {n} stored vertices")
    return acc


def welded_vertex_count(primitive: dict) -> int | None:
    """The extension's ``baseVertexCount`` (the base's vertex count after the weld) as an int, or
    None when the base is not welded; FormatError unless it is a positive integer."""
    from ..constants import EXTENSION_NAME

    ext = (primitive.get("extensions") or {}).get(EXTENSION_NAME) or {}
    count = ext.get("baseVertexCount")
    if count is None:
        return None
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


#: glTF componentType -> the Draco DataType of data of that type (spec README, *Base mesh*: a Draco attribute's data
#: has the type its accessor names; readers convert nothing, so a normalized Draco attribute reads as its integers).
_DRACO_DATA_TYPES = {5120: 1, 5121: 2, 5122: 3, 5123: 4, 5125: 6, FLOAT: 9}


def _decode_draco(gltf, draco, bin_data, n, m, names, widths, types) -> tuple:
    """``({name: (n, k) array}, faces (m, 3) int64)`` of a Draco base: the Draco attribute of each of ``names``
    (``POSITION``, progressive attributes, :data:`WELD_ATTRIBUTE`) by its unique id in
    ``KHR_draco_mesh_compression.attributes``, checked to have ``n`` values of ``widths`` components, of the data
    type its accessor's componentType (``types``) names."""
    import DracoPy

    _, raw = view_bytes(gltf, [bin_data], draco.get("bufferView"), "base mesh: Draco")
    ids = draco.get("attributes")
    if not isinstance(ids, dict):
        raise FormatError(f"base mesh: {DRACO_EXTENSION}.attributes is not an object")
    for name in names:
        if name not in ids:
            raise FormatError(f"base mesh: {DRACO_EXTENSION}.attributes has no {name} id")
        if json_integer(ids[name]) is None or not 0 <= ids[name] <= 0xFFFF:  # a Draco unique id (true is none)
            raise FormatError(f"base mesh: {DRACO_EXTENSION}.attributes.{name} is not a Draco attribute id, got {ids[name]!r}")
    try:
        mesh = DracoPy.decode(bytes(raw))
        found = {name: mesh.get_attribute_by_unique_id(ids[name]) for name in names}
    except Exception as exc:  # DracoPy raises its own exception types
        raise FormatError(f"base mesh: Draco data does not decode ({exc})") from None
    faces = np.asarray(mesh.faces, dtype=np.int64)
    out = {}
    for name, width, ctype in zip(names, widths, types):
        if found[name] is None:
            raise FormatError(f"base mesh: Draco data has no attribute with unique id {ids[name]!r} ({name})")
        if found[name].get("data_type") != _DRACO_DATA_TYPES.get(ctype):
            kind = next((t for t, d in _DRACO_DATA_TYPES.items() if d == found[name].get("data_type")), None)
            raise FormatError(f"base mesh: the Draco {name} holds data of componentType {kind}, its accessor says {ctype}")
        values = np.asarray(found[name]["data"])
        if values.size != n * width:
            raise FormatError(f"base mesh: Draco decoded {values.size // width} {name} values, accessors declare {n}")
        out[name] = values.reshape(n, width)
    if faces.size != 3 * m:
        raise FormatError(f"base mesh: Draco decoded {faces.size // 3} faces, accessors declare {m}")
    out["POSITION"] = out["POSITION"].astype(np.float32)
    return out, faces.reshape(-1, 3)


# ------------------------------------------------------------------ attributes


def decode_base_attributes(gltf: dict, bin_data, primitive: dict, attributes, grid: Grid | dict | None = None) -> np.ndarray:
    """The base's progressive attributes as (n, a) int64 grid integers (a = 0 without any): :func:`read_base`'s
    ``values``.  ``grid``: the base's position grid (the weld keys on it), default the primitive's extension's."""
    if grid is None:
        from ..constants import EXTENSION_NAME

        grid = ((primitive.get("extensions") or {}).get(EXTENSION_NAME) or {}).get("grid")
        if grid is None:
            raise FormatError("base mesh: no grid to read the attributes with")
    return read_base(gltf, bin_data, grid, primitive, attributes)[2]


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

