"""glTF 2.0 vocabulary: enums, type widths, and checked access to bufferViews and accessors.

The one place that knows the numbers of the glTF specification (component types,
bufferView targets, primitive modes), the accessor ``type`` widths both ways, the
name of the Draco extension, how to find the primitives carrying an extension,
and how to read a bufferView or a tightly packed accessor without trusting the
JSON: every index, offset and length is checked before anything is sliced.

Errors are :class:`~pmwm_codec.errors.FormatError` unless the caller passes
another class (``error=InputFormatError`` for input assets).
"""

from __future__ import annotations

import contextlib
import functools
import gc

import math

import numpy as np

from ..constants import MAX_JSON_DEPTH
from ..errors import FormatError, LimitError
from .layout import padded

# accessor componentType
BYTE = 5120
UNSIGNED_BYTE = 5121
SHORT = 5122
UNSIGNED_SHORT = 5123
UNSIGNED_INT = 5125
FLOAT = 5126

# bufferView target
ARRAY_BUFFER = 34962
ELEMENT_ARRAY_BUFFER = 34963

# primitive mode
TRIANGLES = 4
#: primitive modes also drawn as triangles (glTF 2.0, 3.7.2.1), and the three together.
TRIANGLE_STRIP, TRIANGLE_FAN = 5, 6
TRIANGLE_MODES = (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN)
#: glTF 2.0's primitive modes that draw points and lines (3.7.2.1), by name.
POINT_AND_LINE_MODES = {0: "POINTS", 1: "LINES", 2: "LINE_LOOP", 3: "LINE_STRIP"}

DRACO_EXTENSION = "KHR_draco_mesh_compression"


def triangle_list(order: np.ndarray, mode: int) -> np.ndarray:
    """The triangles (m, 3) int64 that a primitive of ``mode`` (one of :data:`TRIANGLE_MODES`) draws from its
    vertex ``order`` (k,) (its indices, or 0..n-1 without), each wound as glTF 2.0 3.7.2.1 says: a strip's
    triangle i is (v_i, v_i+1, v_i+2) for even i and (v_i+1, v_i, v_i+2) for odd i, a fan's (v_0, v_i+1, v_i+2).
    Fewer than three vertices draw nothing; TRIANGLES drops a last incomplete triple (its readers refuse one
    first, where that matters).  Degenerate triangles (a strip's restarts) are kept."""
    order = np.asarray(order, np.int64).reshape(-1)
    if mode == TRIANGLES or len(order) < 3:
        return order[: len(order) // 3 * 3].reshape(-1, 3)
    i = np.arange(len(order) - 2)
    if mode == TRIANGLE_STRIP:
        odd = i % 2 == 1
        return np.stack([np.where(odd, order[i + 1], order[i]), np.where(odd, order[i], order[i + 1]), order[i + 2]], 1)
    if mode == TRIANGLE_FAN:
        return np.stack([np.full(len(i), order[0]), order[i + 1], order[i + 2]], 1)
    raise ValueError(f"mode {mode} does not draw triangles")

#: JSON names of the Python types a parsed JSON value can have (for messages).
JSON_KINDS = {dict: "an object", list: "an array", str: "a string", bool: "a boolean", int: "an integer",
              float: "a number", type(None): "null"}
#: Longest ``repr`` of a value a message quotes; a longer one is named by its JSON kind.
SHOWN_LIMIT = 40


def json_kind(value) -> str:
    """``value``'s JSON kind for a message: "an object", "an array", "a string" ..."""
    return JSON_KINDS.get(type(value), type(value).__name__)


def shown_value(value) -> str:
    """``value`` for a one-line message: its ``repr`` when short, else its JSON kind (a long string, a table;
    "a 301-digit integer")."""
    text = repr(value)
    if len(text) <= SHOWN_LIMIT:
        return text
    return f"a {len(text)}-digit integer" if json_kind(value) == "an integer" else json_kind(value)


#: componentType -> little-endian numpy dtype string.
COMPONENT_DTYPES = {BYTE: "i1", UNSIGNED_BYTE: "u1", SHORT: "<i2", UNSIGNED_SHORT: "<u2", UNSIGNED_INT: "<u4", FLOAT: "<f4"}
#: componentType -> its name in the glTF specification (for messages).
COMPONENT_NAMES = {BYTE: "BYTE", UNSIGNED_BYTE: "UNSIGNED_BYTE", SHORT: "SHORT", UNSIGNED_SHORT: "UNSIGNED_SHORT",
                   UNSIGNED_INT: "UNSIGNED_INT", FLOAT: "FLOAT"}
#: componentType of the three index types -> dtype.
INDEX_DTYPES = {UNSIGNED_BYTE: "<u1", UNSIGNED_SHORT: "<u2", UNSIGNED_INT: "<u4"}
#: Divisor that maps a normalized integer componentType to [-1, 1] / [0, 1].
NORMALIZE_DIVISORS = {BYTE: 127.0, UNSIGNED_BYTE: 255.0, SHORT: 32767.0, UNSIGNED_SHORT: 65535.0}
#: accessor type -> number of components.
TYPE_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: number of components -> accessor type (vectors only).
WIDTH_TYPE = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}
#: vector accessor type -> number of components (no matrices).
VECTOR_WIDTH = {name: width for width, name in WIDTH_TYPE.items()}

_REQUIRED = object()


def named(value, table: dict):
    """``table[value]`` for a JSON ``value`` that names one of ``table``'s entries (a ``componentType`` in
    :data:`COMPONENT_DTYPES`, a ``type`` in :data:`TYPE_WIDTH` ...), else None: a list or an object names none
    (as a key it raised TypeError, a crash where a one-line refusal was due), nor does a bool."""
    if isinstance(value, (bool, list, dict)):
        return None
    return table.get(value)


def json_integer(value):
    """``value`` as an ``int`` when it is a JSON integer, else None.

    A JSON integer is a number with an integral value: ``16``, ``16.0`` and ``1.6e1`` are one value
    (JSON does not tell them apart and JavaScript cannot; spec README, *JSON numbers*); a bool is none.
    """
    if isinstance(value, bool):
        return None
    if isinstance(value, int):
        return value
    if isinstance(value, float) and value.is_integer():
        return int(value)
    return None


_INTEGER = {"type": "integer"}


def _array_of(properties: dict) -> dict:
    return {"items": {"properties": properties}}


def _integers(*names) -> dict:
    return {name: _INTEGER for name in names}


_TEXTURE_INFO = {"properties": _integers("index", "texCoord")}


def document_integers(primitive_extensions: dict) -> dict:
    """The members a glTF 2.0 document types ``integer`` (the glTF 2.0 JSON schema's, and
    ``KHR_draco_mesh_compression``'s), as a JSON schema of the document for :func:`integer_shape`,
    with ``primitive_extensions`` (``{name: schema}``) the schemas of other extension objects of a
    mesh primitive.  Members of other extensions are not listed."""
    draco = {"properties": {"bufferView": _INTEGER, "attributes": {"additionalProperties": _INTEGER}}}
    primitive = {
        **_integers("indices", "material", "mode"),
        "attributes": {"additionalProperties": _INTEGER}, "targets": {"items": {"additionalProperties": _INTEGER}},
        "extensions": {"properties": {DRACO_EXTENSION: draco, **primitive_extensions}},
    }
    sparse = {"properties": {"count": _INTEGER, "indices": {"properties": _integers("bufferView", "byteOffset", "componentType")},
                             "values": {"properties": _integers("bufferView", "byteOffset")}}}
    return {"properties": {
        "scene": _INTEGER,
        "scenes": _array_of({"nodes": {"items": _INTEGER}}),
        "nodes": _array_of({**_integers("camera", "skin", "mesh"), "children": {"items": _INTEGER}}),
        "meshes": _array_of({"primitives": _array_of(primitive)}),
        "accessors": _array_of({**_integers("bufferView", "byteOffset", "componentType", "count"), "sparse": sparse}),
        "bufferViews": _array_of(_integers("buffer", "byteOffset", "byteLength", "byteStride", "target")),
        "buffers": _array_of(_integers("byteLength")),
        "images": _array_of(_integers("bufferView")),
        "textures": _array_of(_integers("sampler", "source")),
        "samplers": _array_of(_integers("magFilter", "minFilter", "wrapS", "wrapT")),
        "skins": _array_of({**_integers("inverseBindMatrices", "skeleton"), "joints": {"items": _INTEGER}}),
        "animations": _array_of({
            "channels": _array_of({"sampler": _INTEGER, "target": {"properties": _integers("node")}}),
            "samplers": _array_of(_integers("input", "output"))}),
        "materials": _array_of({
            "pbrMetallicRoughness": {"properties": {"baseColorTexture": _TEXTURE_INFO, "metallicRoughnessTexture": _TEXTURE_INFO}},
            "normalTexture": _TEXTURE_INFO, "occlusionTexture": _TEXTURE_INFO, "emissiveTexture": _TEXTURE_INFO}),
    }}


def integer_shape(schema, schemas=None):
    """Where a JSON schema types a value ``integer``: a tree of dicts (``integer``: bool, ``properties``:
    {name: tree}, ``additional``: tree, ``items``: tree) for :func:`with_integers`, or None when nothing
    in it is.  Follows ``$ref`` (a name in ``schemas``), ``properties``, ``additionalProperties``,
    ``items`` and every branch of ``allOf`` / ``anyOf`` / ``oneOf`` / ``then`` / ``else`` (merged: a
    member typed ``integer`` in one branch is an integer wherever it occurs)."""
    if not isinstance(schema, dict):
        return None
    parts = [schema] + ([schemas[schema["$ref"]]] if "$ref" in schema else [])
    parts += [branch for key in ("allOf", "anyOf", "oneOf") for branch in schema.get(key, ())]
    parts += [schema[key] for key in ("then", "else") if key in schema]
    tree = {"integer": False, "properties": {}, "additional": None, "items": None}
    for part in parts:
        if part is schema:
            tree["integer"] |= part.get("type") == "integer"
            for name, sub in part.get("properties", {}).items():
                tree["properties"][name] = _merged(tree["properties"].get(name), integer_shape(sub, schemas))
            tree["additional"] = _merged(tree["additional"], integer_shape(part.get("additionalProperties"), schemas))
            tree["items"] = _merged(tree["items"], integer_shape(part.get("items"), schemas))
        else:
            tree = _merged(tree, integer_shape(part, schemas))
    tree["properties"] = {name: sub for name, sub in tree["properties"].items() if sub is not None}
    if not (tree["integer"] or tree["properties"] or tree["additional"] or tree["items"]):
        return None
    return tree


@functools.lru_cache(maxsize=None)
def _gltf_integers() -> dict:
    return integer_shape(document_integers({}))


def gltf_integers(gltf: dict) -> dict:
    """A parsed glTF 2.0 document (in place) with every member glTF's schema types ``integer`` that holds an
    integral float made an ``int`` (``"count": 3.0`` -> ``3``; :func:`with_integers`): the encoder takes
    an input document's integers as the readers take a ``.pmw``'s (spec README, *JSON numbers*) and writes
    them as integers.  Members of extensions other than Draco's are left as they are."""
    return with_integers(gltf, _gltf_integers())


def _merged(a, b):
    """Two :func:`integer_shape` trees as one (either may be None)."""
    if a is None or b is None:
        return a if b is None else b
    names = set(a["properties"]) | set(b["properties"])
    return {"integer": a["integer"] or b["integer"],
            "properties": {n: _merged(a["properties"].get(n), b["properties"].get(n)) for n in names},
            "additional": _merged(a["additional"], b["additional"]), "items": _merged(a["items"], b["items"])}


def with_integers(value, shape):
    """``value`` (parsed JSON) with every member :func:`integer_shape` tree ``shape`` types integer that
    holds a number of integral value made an ``int`` (:func:`json_integer`; ``16.0`` -> ``16``), in place;
    returns the value.  Other numbers stay as they are (a ``1.0`` typed ``number`` stays a float); a
    member of another JSON type is left for the checks that read it.  Recursion follows ``shape``, never
    deeper than the schema."""
    if shape is None:
        return value
    if shape["integer"] and isinstance(value, float) and json_integer(value) is not None:
        return json_integer(value)
    if isinstance(value, dict):
        for name, member in value.items():
            sub = shape["properties"].get(name, shape["additional"])
            if sub is not None:
                value[name] = with_integers(member, sub)
    elif isinstance(value, list) and shape["items"] is not None:
        for i, member in enumerate(value):
            value[i] = with_integers(member, shape["items"])
    return value


def float32_numbers(values) -> list:
    """float32 ``values`` (any shape, flattened) as the floats whose JSON text is the shortest
    decimal reading back to the same float32 (``0.1``, not ``0.10000000149011612``): glTF stores
    accessor ``min``/``max`` of FLOAT components as single precision values."""
    return [float(str(x)) for x in np.asarray(values, dtype=np.float32).ravel()]


def without_defaults(view: dict) -> dict:
    """A bufferView without a ``byteOffset`` of 0 (the glTF default)."""
    return {k: v for k, v in view.items() if not (k == "byteOffset" and v == 0)}


def find_extension_primitive(gltf: dict, name: str):
    """``(mesh_index, primitive_index, primitive)`` of the one primitive carrying ``name``.

    Raises FormatError when no primitive, or more than one, carries it.
    """
    hits = find_extension_primitives(gltf, name)
    if len(hits) != 1:
        raise FormatError(f"glTF JSON: expected one mesh primitive with {name}, found {len(hits)}")
    return hits[0]


def find_extension_primitives(gltf: dict, name: str):
    """``[(mesh_index, primitive_index, primitive), ...]`` of every primitive carrying ``name``.

    Mesh/primitive order, which is the order progressive primitives are numbered in.
    Raises FormatError when none carries it.
    """
    hits = []
    meshes = gltf.get("meshes", [])
    if not isinstance(meshes, list):
        raise FormatError("glTF JSON: meshes must be an array")
    for mi, mesh in enumerate(meshes):
        prims = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for pi, prim in enumerate(prims if isinstance(prims, list) else []):
            ext = prim.get("extensions") if isinstance(prim, dict) else None
            if isinstance(ext, dict) and name in ext:
                hits.append((mi, pi, prim))
    if not hits:
        raise FormatError(f"glTF JSON: no mesh primitive carries {name}")
    return hits


def uses_extension(gltf: dict, name: str) -> bool:
    """True when some mesh primitive of ``gltf`` has ``name`` in its ``extensions``."""
    return any(name in (prim.get("extensions") or {})
               for mesh in gltf.get("meshes", []) for prim in mesh.get("primitives", []))


#: Integer and normalized vertex attributes beyond glTF 2.0's own (:func:`uses_quantization`).
QUANTIZATION_EXTENSION = "KHR_mesh_quantization"

#: The (componentType, normalized) pairs glTF 2.0 itself (3.7.2.1, 3.7.2.2) allows a vertex attribute of each
#: semantic; others (a SHORT POSITION, a BYTE NORMAL ...) need KHR_mesh_quantization (:func:`uses_quantization`).
_NORMALIZED_8_16 = ((FLOAT, False), (UNSIGNED_BYTE, True), (UNSIGNED_SHORT, True))
CORE_COMPONENTS = {"POSITION": ((FLOAT, False),), "NORMAL": ((FLOAT, False),), "TANGENT": ((FLOAT, False),),
                   "TEXCOORD": _NORMALIZED_8_16, "COLOR": _NORMALIZED_8_16, "WEIGHTS": _NORMALIZED_8_16,
                   "JOINTS": ((UNSIGNED_BYTE, False), (UNSIGNED_SHORT, False))}


def uses_quantization(gltf: dict) -> bool:
    """Whether an accessor of a (checked) ``gltf`` needs KHR_mesh_quantization: a vertex attribute of a componentType
    glTF 2.0 does not allow its semantic (:data:`CORE_COMPONENTS`; a morph target's: FLOAT alone), or an
    EXT_mesh_gpu_instancing attribute that is not FLOAT.  Application-specific ``_NAME`` attributes need nothing."""
    accessors = gltf.get("accessors", [])

    def form(index):
        acc = accessors[index]
        return acc["componentType"], bool(acc.get("normalized", False))

    for mesh in gltf.get("meshes", []):
        for prim in mesh.get("primitives", []):
            sets = [(prim.get("attributes", {}), False)] + [(t, True) for t in prim.get("targets", [])]
            for attributes, target in sets:
                for semantic, index in attributes.items():
                    allowed = ((FLOAT, False),) if target else CORE_COMPONENTS.get(semantic.split("_")[0])
                    if semantic[:1] != "_" and allowed is not None and form(index) not in allowed:
                        return True
    for node in gltf.get("nodes", []):
        instancing = (node.get("extensions") or {}).get("EXT_mesh_gpu_instancing") or {}
        if any(form(index)[0] != FLOAT for index in (instancing.get("attributes") or {}).values()):
            return True
    return False


def forget_extension(gltf: dict, name: str, keys=("extensionsUsed", "extensionsRequired")) -> None:
    """Remove ``name`` from the lists ``keys`` of ``gltf`` (in place), and each list that
    becomes empty; call it once no primitive uses the extension any more."""
    for key in keys:
        if key in gltf:
            gltf[key] = [e for e in gltf[key] if e != name]
            if not gltf[key]:
                del gltf[key]


def uint(obj, key: str, what: str, default=_REQUIRED, *, error=FormatError) -> int:
    """``obj[key]`` when it is a non-negative integer (not a bool); else ``error``.

    ``default`` is used when the key is absent (no default: the key is required).
    """
    value = obj.get(key, None if default is _REQUIRED else default) if isinstance(obj, dict) else None
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise error(f"{what}: {key} must be a non-negative integer, got {value!r}")
    return value


def item(seq, index, what: str, *, error=FormatError) -> dict:
    """``seq[index]`` of a glTF array (``what`` names it, e.g. ``"accessor"``), checked to be an object."""
    if isinstance(index, bool) or not isinstance(index, int) or not isinstance(seq, list) or not 0 <= index < len(seq):
        raise error(f"{what} {index!r} does not exist")
    value = seq[index]
    if not isinstance(value, dict):
        raise error(f"{what} {index} is not an object")
    return value


def view_range(views, index, buffer_length: int, what: str, *, error=FormatError) -> tuple[int, int]:
    """``(start, end)`` of bufferView ``index`` in the GLB BIN buffer (buffer 0) of ``buffer_length`` bytes.

    Checks that the view exists, lives in buffer 0, has non-negative integer
    ``byteOffset`` / ``byteLength``, ends inside the buffer and, where it has a ``byteStride``,
    that it is a multiple of 4 in 4..252 (the glTF schema's).
    """
    view = item(views, index, f"{what}: bufferView", error=error)
    if uint(view, "buffer", f"{what}: bufferView {index}", 0, error=error) != 0:  # not False, which == 0
        raise error(f"{what}: bufferView {index} is not in the GLB BIN buffer")
    return _range(view, index, buffer_length, what, error)


def _range(view: dict, index, buffer_length: int, what: str, error) -> tuple[int, int]:
    start = uint(view, "byteOffset", f"{what}: bufferView {index}", 0, error=error)
    length = uint(view, "byteLength", f"{what}: bufferView {index}", error=error)
    if "byteStride" in view:
        stride = view["byteStride"]
        if not isinstance(stride, int) or isinstance(stride, bool) or stride % 4 or not 4 <= stride <= 252:
            raise error(f"{what}: bufferView {index} has an invalid byteStride {stride!r} (a multiple of 4 in 4..252)")
    if start + length > buffer_length:
        raise error(f"{what}: bufferView {index} ends at {start + length}, past the buffer's {buffer_length} bytes")
    return start, start + length


def view_bytes(gltf: dict, buffers, index, what: str, *, error=FormatError):
    """``(view dict, memoryview of its bytes)`` of bufferView ``index``.

    ``buffers`` is the list of the document's buffers as bytes-like (for a GLB,
    ``[bin_chunk]``); the view's ``buffer`` must name one of them.
    """
    view = item(gltf.get("bufferViews"), index, f"{what}: bufferView", error=error)
    buffer = uint(view, "buffer", f"{what}: bufferView {index}", 0, error=error)
    if buffer >= len(buffers):
        raise error(f"{what}: bufferView {index} is in buffer {buffer}, which is not loaded")
    start, end = _range(view, index, len(buffers[buffer]), what, error)
    return view, memoryview(buffers[buffer])[start:end]


def accessor_array(gltf: dict, acc: dict, bin_data, dtype, count: int, width: int, what: str, *,
                   vertex_attribute: bool = True) -> np.ndarray:
    """An accessor of the GLB BIN buffer as a (count, width) array of ``dtype``.

    ``acc`` is the accessor object; ``count`` / ``width`` are what the caller has
    already checked against its limits.  A vertex attribute's bufferView may interleave
    (a ``byteStride`` of at least one element, a multiple of the component size, glTF 2.0
    3.6.2.4); indices (``vertex_attribute`` False) are tightly packed.  The array is a
    read-only view of ``bin_data`` when tightly packed, else a copy (:func:`element_rows`).
    """
    view = item(gltf.get("bufferViews"), acc.get("bufferView"), f"{what}: bufferView")
    start, end = view_range(gltf.get("bufferViews"), acc["bufferView"], len(bin_data), what)
    raw = memoryview(bin_data)[start:end]
    component = np.dtype(dtype).itemsize
    size = component * width
    stride = view.get("byteStride", size)
    if stride != size and (not vertex_attribute or stride < size or stride % component):
        raise FormatError(f"{what}: byteStride {stride!r} for {size}-byte elements"
                          + ("" if vertex_attribute else " (indices are tightly packed)"))
    offset = uint(acc, "byteOffset", f"{what} accessor", 0)
    need = offset + (count - 1) * stride + size if count else offset
    if offset % component or need > len(raw):
        raise FormatError(f"{what}: accessor needs {need} bytes at offset {offset}, bufferView has {len(raw)}")
    return element_rows(raw, dtype, count, width, offset, stride)


def element_rows(raw, dtype, count: int, width: int, offset: int, stride: int) -> np.ndarray:
    """(count, width) array of ``dtype`` whose rows start every ``stride`` bytes from ``offset`` in ``raw`` (the
    bytes of a bufferView, already checked to hold them): a read-only view of ``raw`` when the rows are
    tightly packed, else a contiguous copy (an interleaved view's other attributes left out)."""
    dtype = np.dtype(dtype)
    if count == 0 or stride == dtype.itemsize * width:
        return np.frombuffer(raw, dtype=dtype, count=count * width, offset=offset).reshape(count, width)
    return np.ndarray((count, width), dtype, buffer=raw, offset=offset, strides=(stride, dtype.itemsize)).copy()


class BufferBuilder:
    """Buffer 0 of a document being written: appends 4-byte aligned bufferViews and accessors.

    ``views`` and ``accessors`` are the document's lists, extended in place;
    ``parts`` collects the bytes (each view zero-padded to 4 bytes) and ``length``
    is their total, which is where the next view starts.
    """

    def __init__(self, views: list, accessors: list, parts=(), length: int = 0):
        self.views = views
        self.accessors = accessors
        self.parts = list(parts)
        self.length = length

    def add_view(self, raw: bytes, target: int | None = None) -> int:
        """Append ``raw`` as a new bufferView (with ``target`` when given); returns its index."""
        view = {"buffer": 0, "byteOffset": self.length, "byteLength": len(raw)}
        if target:
            view["target"] = target
        self.views.append(view)
        self.parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        self.length += padded(len(raw))
        return len(self.views) - 1

    def add_accessor(self, array: np.ndarray, component_type: int, target: int | None = None, *, minmax: bool = False) -> int:
        """Append ``array`` ((n,) SCALAR or (n, k) VECk, already of ``component_type``'s dtype)
        as a bufferView plus an accessor; ``minmax`` adds per-component ``min``/``max``.
        Returns the accessor index."""
        array = np.ascontiguousarray(array)
        type_ = "SCALAR" if array.ndim == 1 else WIDTH_TYPE[array.shape[1]]
        view = self.add_view(array.tobytes(), target)
        acc = {"bufferView": view, "componentType": component_type, "count": int(len(array)), "type": type_}
        if minmax:
            acc["min"] = [float(x) for x in array.min(0)]
            acc["max"] = [float(x) for x in array.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1

    def add_vertex_integers(self, values: np.ndarray, component_type: int, target: int | None = None) -> int:
        """Append integer vertex values ((n, k) holding whole numbers, any dtype) as an accessor of
        ``component_type`` (not normalized), each element padded to 4 bytes (glTF 2.0 3.6.2.4: a vertex
        attribute's elements start on 4-byte boundaries) with the view's ``byteStride``.  Returns its index."""
        dtype = np.dtype(COMPONENT_DTYPES[component_type])
        ints = np.rint(np.asarray(values, np.float64)).astype(dtype).reshape(len(values), -1)
        item = ints.shape[1] * dtype.itemsize
        stride = padded(item)
        rows = np.zeros((len(ints), stride), np.uint8)
        rows[:, :item] = ints.view(np.uint8).reshape(len(ints), item)
        view = self.add_view(rows.tobytes(), target)
        if stride != item:
            self.views[view]["byteStride"] = stride
        self.accessors.append({"bufferView": view, "componentType": component_type, "count": len(ints),
                               "type": "SCALAR" if ints.shape[1] == 1 else f"VEC{ints.shape[1]}"})
        return len(self.accessors) - 1


#: The least integer whose conversion to a double overflows (2^1024 rounded half to even): 309 digits.
_INT_PAST_DOUBLE = 2**1024 - 2**970
_INT_DIGITS_PAST_DOUBLE = 309


def check_finite_numbers(gltf: dict, name: str, error) -> None:
    """Refuse (``error`` naming the member, e.g. ``accessors[3].min[0]``) a NaN or infinite number
    anywhere in a parsed JSON document: Python's reader takes ``NaN``, ``Infinity`` and ``1e999``, JSON
    does not, and writing one back fails (walked without recursion; paths built only for the culprit); nor an
    integer literal past a double's range (a reader of doubles, as JavaScript's, takes it as Infinity; Python's
    keeps an int that no float conversion takes)."""
    def refuse(value, path):
        shown = ("an integer past a double's range (Infinity)" if isinstance(value, int) else
                 "NaN" if math.isnan(value) else "Infinity" if value > 0 else "-Infinity")
        raise error(f"{name}: {_json_path(path)} is {shown}, which JSON does not allow")

    if isinstance(gltf, float) and not math.isfinite(gltf):
        refuse(gltf, None)
    stack = [(gltf, None)] if isinstance(gltf, (dict, list)) else []  # (container, path as a (parent path, key) chain)
    while stack:  # the scalars of a container are checked in place: only containers go on the stack
        value, path = stack.pop()
        for key, child in (value.items() if isinstance(value, dict) else enumerate(value)):
            if isinstance(child, float):
                if not math.isfinite(child):
                    refuse(child, (path, key))
            elif type(child) is int:
                if not -_INT_PAST_DOUBLE < child < _INT_PAST_DOUBLE:
                    refuse(child, (path, key))
            elif isinstance(child, (dict, list)):
                stack.append((child, (path, key)))


@contextlib.contextmanager
def gc_paused():
    """Python's cyclic garbage collector held off while a JSON document is built or copied: each of the
    millions of containers a large one holds counts toward a collection, and each collection walks all those
    made so far again (a 64 MiB text of 16M empty arrays: 5.5 s to parse, 0.8 s so); JSON values make no cycle."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def loads_finite(text: str, name: str, error):
    """``json.loads(text)``, refusing as :func:`check_finite_numbers` does (``error`` naming the member) a NaN or
    infinite number, without walking the document when it holds none: the parser reports every ``NaN`` /
    ``Infinity`` / ``-Infinity`` literal and every number it reads as a float (``1e999`` is infinite), so the
    check rides on its own pass, and every integer literal of 309 digits or more (the shortest past a double's
    range: ~1.2x the parse of a document of 400,000 small integers); only a document holding one is walked, to
    name the member.
    ``ValueError`` (``json.JSONDecodeError``) for text that is not JSON."""
    import json

    found = []

    def constant(word):
        found.append(word)
        return float(word)

    def number(literal, finite=math.isfinite):
        value = float(literal)
        if not finite(value):
            found.append(literal)
        return value

    def whole(literal):
        if len(literal) >= _INT_DIGITS_PAST_DOUBLE:
            found.append(literal)
        return int(literal)

    with gc_paused():
        doc = json.loads(text, parse_constant=constant, parse_float=number, parse_int=whole)
    if found:
        check_finite_numbers(doc, name, error)
    return doc


#: Bytes of JSON text :func:`check_json_text_depth` looks at in one numpy pass.
_SCAN_BLOCK = 1 << 20
#: Depth step of each byte outside a string: ``[`` and ``{`` open (+1), ``]`` and ``}`` close (-1).
_DEPTH_STEP = np.zeros(256, np.int64)
_DEPTH_STEP[[ord("["), ord("{")]] = 1
_DEPTH_STEP[[ord("]"), ord("}")]] = -1
_QUOTE, _BACKSLASH = ord('"'), ord("\\")


def check_json_text_depth(text, name: str, limit: int = MAX_JSON_DEPTH, error=LimitError) -> None:
    """Refuse (``error`` naming :data:`~pmwm_codec.constants.MAX_JSON_DEPTH`) JSON text nested more than
    ``limit`` arrays and objects deep (the outermost value is level 1), found in the bytes before they
    are parsed: Python's JSON reader recurses once per level (a deep enough text raises RecursionError,
    at a depth that depends on the stack).

    The scan (spec README, Conformance): a ``"`` preceded by an even run of backslashes (none included)
    toggles "inside a string"; outside a string ``[`` / ``{`` open a level and ``]`` / ``}`` close one;
    nothing else counts.  On valid JSON this is its nesting depth; on any text it is what the JavaScript
    decoder's scan (``jsonTooDeep`` in js/src/header.js) finds, so both refuse the same texts.  Linear,
    in blocks of :data:`_SCAN_BLOCK` bytes, without recursion.
    """
    data = np.frombuffer(text, np.uint8)
    depth, inside, odd = 0, False, False  # before the block: levels open, in a string, after an odd backslash run
    for start in range(0, len(data), _SCAN_BLOCK):
        block = data[start : start + _SCAN_BLOCK]
        plain = np.flatnonzero(block != _BACKSLASH)
        quotes = np.flatnonzero(block == _QUOTE)
        at = np.searchsorted(plain, quotes)  # each quote's place among the bytes that are no backslash
        run = np.where(at > 0, quotes - plain[np.maximum(at - 1, 0)] - 1, quotes + odd)  # backslashes before it
        toggles = quotes[run % 2 == 0]
        brackets = np.flatnonzero(_DEPTH_STEP[block])
        outside = (np.searchsorted(toggles, brackets) % 2 == 1) == inside  # toggles before it, from the state before
        running = depth + np.cumsum(np.where(outside, _DEPTH_STEP[block[brackets]], 0))
        if running.size and running.max() > limit:
            raise error(f"{name}: JSON nested more than {limit} levels deep (MAX_JSON_DEPTH)")
        depth = int(running[-1]) if running.size else depth
        inside ^= bool(len(toggles) % 2)
        trailing = len(block) - 1 - int(plain[-1]) if plain.size else len(block) + odd
        odd = bool(trailing % 2)
    return None


def check_json_depth(doc, name: str, limit: int = MAX_JSON_DEPTH, error=FormatError) -> None:
    """Refuse (``error``) a parsed JSON value nested deeper than ``limit`` arrays/objects, the outermost
    being level 1 (walked without recursion): :func:`check_json_text_depth` for a value already in memory."""
    stack = [(doc, 1)]
    while stack:
        value, depth = stack.pop()
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else None
        if children is None:
            continue
        if depth > limit:
            raise error(f"{name}: JSON nested more than {limit} levels deep")
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))


def _json_path(path) -> str:
    """``accessors[3].min[0]`` of a ``(parent, key)`` chain from :func:`check_finite_numbers`."""
    keys = []
    while path is not None:
        path, key = path
        keys.append(key)
    text = ""
    for key in reversed(keys):
        text += f"[{key}]" if isinstance(key, int) else f".{key}" if text else str(key)
    return text or "the document"


def _node_matrix(node: dict):
    """A node's local transform (4, 4) float64 (``matrix``, column-major, or ``T R S``), or None when
    a member is malformed (the reader checks what it uses; here it only makes the mesh count as placed)."""
    try:
        if "matrix" in node:
            m = np.asarray(node["matrix"], np.float64)
            return m.reshape(4, 4).T if m.shape == (16,) and np.isfinite(m).all() else None
        t = np.asarray(node.get("translation", [0.0, 0.0, 0.0]), np.float64)
        x, y, z, w = np.asarray(node.get("rotation", [0.0, 0.0, 0.0, 1.0]), np.float64)
        s = np.asarray(node.get("scale", [1.0, 1.0, 1.0]), np.float64)
    except (TypeError, ValueError):
        return None
    if t.shape != (3,) or s.shape != (3,) or not (np.isfinite(t).all() and np.isfinite(s).all()):
        return None
    norm = math.sqrt(x * x + y * y + z * z + w * w)
    if not norm > 0.0 or not math.isfinite(norm):
        return None
    x, y, z, w = x / norm, y / norm, z / norm, w / norm  # written with a few digits: unit as readers take it
    rot = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                    [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                    [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    m = np.eye(4)
    m[:3, :3] = rot * s[None, :]
    m[:3, 3] = t
    return m


def mesh_placements(gltf: dict) -> list:
    """Every showing of a mesh in the default scene (or, without one, under every node that is no
    node's child): ``[(mesh index, world matrix (4, 4) float64 or None)]`` in walk order, None where a
    node on the path has a malformed transform; a node with ``EXT_mesh_gpu_instancing`` adds a second
    showing with None (its instances are drawn where the extension's accessors say).  Reads the JSON
    leniently: a malformed node or child index is skipped, a node met twice (glTF nodes form disjoint
    trees) is walked once."""
    nodes = gltf.get("nodes")
    if not isinstance(nodes, list):
        return []
    scenes, scene = gltf.get("scenes"), gltf.get("scene", 0)
    roots = None
    if isinstance(scenes, list) and isinstance(scene, int) and 0 <= scene < len(scenes) and isinstance(scenes[scene], dict):
        roots = scenes[scene].get("nodes")
    if not isinstance(roots, list):
        children = {c for n in nodes if isinstance(n, dict) and isinstance(n.get("children"), list)
                    for c in n["children"] if isinstance(c, int)}
        roots = [i for i in range(len(nodes)) if i not in children]
    shown, seen = [], set()
    stack = [(r, np.eye(4)) for r in reversed(roots)]
    while stack:
        i, parent = stack.pop()
        if not isinstance(i, int) or not 0 <= i < len(nodes) or not isinstance(nodes[i], dict) or i in seen:
            continue
        seen.add(i)
        node = nodes[i]
        local = _node_matrix(node)
        world = None if parent is None or local is None else parent @ local
        if "mesh" in node:
            shown.append((node["mesh"], world))
            exts = node.get("extensions")
            if isinstance(exts, dict) and "EXT_mesh_gpu_instancing" in exts:  # drawn once per instance
                shown.append((node["mesh"], None))
        children = node.get("children")
        if isinstance(children, list):
            stack.extend((c, world) for c in reversed(children))
    return shown


def placements_by_mesh(gltf: dict) -> dict:
    """``{mesh index: [world matrix (4, 4) or None, ...]}``: :func:`mesh_placements` grouped by mesh."""
    out = {}
    for mesh, matrix in mesh_placements(gltf):
        if isinstance(mesh, int):
            out.setdefault(mesh, []).append(matrix)
    return out


def skinned_meshes(gltf: dict) -> set:
    """The indices of the meshes a node with a ``skin`` shows (read leniently: whatever the nodes' ``mesh`` hold)."""
    return {node.get("mesh") for node in gltf.get("nodes", []) if isinstance(node, dict) and "skin" in node}


def placed_by_nodes(gltf: dict) -> bool:
    """Whether the default scene (or, without one, every root node) moves a mesh away from its stored
    coordinates (a node transform on its path) or shows a mesh more than once (instances).  Reads the
    JSON leniently: a malformed transform counts as moving its meshes (:func:`mesh_placements`)."""
    shown = mesh_placements(gltf)
    meshes = [repr(mesh) for mesh, _ in shown]
    return len(set(meshes)) < len(meshes) or any(m is None or not np.array_equal(m, np.eye(4)) for _, m in shown)


def world_placements(gltf: dict, mesh_indices) -> tuple:
    """Every world matrix of each mesh of ``mesh_indices`` (a list of mesh indices, repeats allowed):
    ``(placements, None)``, for each mesh the list of (4, 4) float64 matrices of its showings (one per
    node that shows it, in walk order), or ``(None, why)`` (a phrase) when some mesh has no placement
    that reads: not shown by the default scene, under a malformed transform or drawn by
    ``EXT_mesh_gpu_instancing``, or flattened (a scale of zero).  A document without nodes shows
    every mesh once, as stored (the identity)."""
    if not gltf.get("nodes"):
        return [[np.eye(4)] for _ in mesh_indices], None
    shown = placements_by_mesh(gltf)
    out = []
    for mi in mesh_indices:
        mine = shown.get(mi, [])
        if not mine:
            return None, f"mesh {mi} is not shown in the scene, where a decoded asset's read looks for it"
        if any(m is None for m in mine):
            return None, (f"mesh {mi} is placed by a node transform that does not read, or drawn by GPU "
                          "instancing, whose instances the reads do not place")
        if any(not abs(np.linalg.det(m[:3, :3])) > 0.0 for m in mine):
            return None, f"mesh {mi} is flattened by its node transform (a scale of zero)"
        out.append(mine)
    return out, None


def owner_placements(gltf: dict, mesh_indices) -> tuple:
    """Where the owner layer of the meshes ``mesh_indices`` (a list of mesh indices, repeats allowed) of a
    document is marked and read: ``(placements, in_scene)``, ``placements`` as :func:`world_placements`'
    (for each mesh a list of (4, 4) float64 matrices).

    The scene as shown (``in_scene`` True: every showing of each mesh placed by its world matrix) when
    every placement reads and some mesh is shown once: that mesh carries the layer where the scene shows
    it.  Otherwise each mesh once, where it is stored (the identity; ``in_scene`` False): a scene whose
    every mesh is shown several times (instances) or drawn by ``EXT_mesh_gpu_instancing``, or whose
    placements do not read (a mesh not shown, a malformed transform, a scale of zero), carries the layer
    in its meshes' own coordinates, where one move of the stored positions marks every showing alike.
    The rule reads the JSON alone, so the encoder and every reader of the file or of its decoded asset
    take the same view."""
    frames, _ = world_placements(gltf, mesh_indices)
    if frames is not None and any(len(mine) == 1 for mine in frames):
        return frames, True
    return [[np.eye(4)] for _ in mesh_indices], False


def place(positions: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """(n, 3) float64: ``positions`` (n, 3) moved by the affine map ``matrix`` (4, 4) (the same array
    when it is the identity)."""
    if np.array_equal(matrix, np.eye(4)):
        return positions
    return positions @ matrix[:3, :3].T + matrix[:3, 3]


def progressive_placements(gltf: dict, name: str) -> tuple:
    """:func:`world_placements` of the meshes of every primitive carrying the extension ``name``, in
    the order the primitives are numbered (:func:`find_extension_primitives`): ``(placements, None)``
    or ``(None, why)``."""
    return world_placements(gltf, [mi for mi, _, _ in find_extension_primitives(gltf, name)])


def scene_mesh(positions: list, faces: list, placements: list, oriented: bool = False) -> tuple:
    """Meshes as a scene shows them, taken as one mesh: each of ``positions`` (a list of (n_i, 3)) with its
    ``faces`` (a list of (m_i, 3) int) placed once per matrix of its entry in ``placements`` (a list of
    lists of (4, 4), :func:`world_placements`).  ``oriented``: a showing under a matrix that mirrors
    (negative determinant) gets its faces' winding reversed, as a renderer draws it (glTF 2.0, 3.7.4),
    so that its faces keep facing out.  Returns ``(positions (N, 3) float64, faces (M, 3) int64,
    spans)``, ``spans[i]`` the ``(start, stop)`` vertex ranges of mesh i's showings, in order."""
    points, tris, spans, offset = [], [], [], 0
    for p, f, matrices in zip(positions, faces, placements):
        mine = []
        for matrix in matrices:
            tri = np.asarray(f, np.int64).reshape(-1, 3)
            if oriented and np.linalg.det(np.asarray(matrix)[:3, :3]) < 0:
                tri = tri[:, [0, 2, 1]]
            points.append(place(np.asarray(p, np.float64), matrix))
            tris.append(tri + offset)
            mine.append((offset, offset + len(p)))
            offset += len(p)
        spans.append(mine)
    if not points:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), spans
    return np.concatenate(points), np.concatenate(tris), spans


def named_view_sites(doc: dict):
    """Yield ``(where, holder, key)`` for every bufferView reference ``holder[key]`` of ``doc``: an accessor's,
    its sparse ``indices``' and ``values``', an image's, a ``KHR_draco_mesh_compression`` object's; ``where``
    names it (``"accessors[3].sparse.indices"``).  Members of the wrong JSON type are passed over (an unchecked
    document's too: the value of ``holder[key]`` is the caller's to check)."""
    for i, acc in enumerate(_dicts(doc.get("accessors"))):
        if "bufferView" in acc:
            yield f"accessors[{i}]", acc, "bufferView"
        sparse = acc.get("sparse")
        for part in ("indices", "values"):
            holder = sparse.get(part) if isinstance(sparse, dict) else None
            if isinstance(holder, dict) and "bufferView" in holder:
                yield f"accessors[{i}].sparse.{part}", holder, "bufferView"
    for i, image in enumerate(_dicts(doc.get("images"))):
        if "bufferView" in image:
            yield f"images[{i}]", image, "bufferView"
    for mi, mesh in enumerate(_dicts(doc.get("meshes"))):
        for pi, prim in enumerate(_dicts(mesh.get("primitives"))):
            extensions = prim.get("extensions")
            draco = extensions.get(DRACO_EXTENSION) if isinstance(extensions, dict) else None
            if isinstance(draco, dict) and "bufferView" in draco:
                yield f"meshes[{mi}].primitives[{pi}].extensions.{DRACO_EXTENSION}", draco, "bufferView"


def _dicts(value) -> list:
    """The objects of a JSON array ``value`` (positions kept: a member that is no object is ``{}``), [] if no array."""
    return [v if isinstance(v, dict) else {} for v in value] if isinstance(value, list) else []
