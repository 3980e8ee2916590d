"""glTF documents in and out: loading assets, reading accessors, repacking what is kept.

The asset pipeline keeps everything of a document (materials, textures, images,
samplers, nodes with names and transforms, scenes, cameras, ``extras``, unknown
extensions) and replaces only the geometry of the triangle primitives it makes
progressive.  This module does the document bookkeeping:

* :func:`load_document` reads a ``.glb`` or a ``.gltf`` (external and data-URI
  buffers and images) into ``(json dict, buffers: list[bytes])``;
* :func:`read_accessor` decodes an accessor to a numpy array (strides,
  normalized integers and sparse accessors included);
* :func:`repack` drops accessors the caller no longer needs, drops the
  bufferViews nothing references any more, embeds external images, renumbers
  every reference it knows and packs the kept bytes into one BIN blob.

Known reference sites renumbered: primitive ``attributes``/``indices``/``targets``,
``skins[].inverseBindMatrices``, ``animations[].samplers[].input/output``,
``EXT_mesh_gpu_instancing`` attributes (accessors); ``accessors[].bufferView``,
sparse ``indices``/``values``, ``images[].bufferView`` and
``KHR_draco_mesh_compression.bufferView`` (bufferViews).  Objects of other
extensions are carried unchanged.
"""

from __future__ import annotations

import base64
import copy
import json
import os
import re
import struct
import urllib.parse

import numpy as np

from ..constants import (
    EXTENSION_NAME,
    MAX_ENCODE_FACES,
    MAX_ENCODE_VERTICES,
    MAX_INPUT_FILE_BYTES,
    MAX_JSON_BYTES,
    MAX_JSON_DEPTH,
    MAX_RESOURCE_BYTES,
)
from ..errors import InputFormatError
from ..sources import read_regular_file
from .glb import split_glb
from .gltf import (COMPONENT_DTYPES, DRACO_EXTENSION, FLOAT, INDEX_DTYPES, NORMALIZE_DIVISORS, TYPE_WIDTH,
                   check_finite_numbers, element_rows, uint, view_bytes)
from .layout import CHUNK_HEADER_SIZE, CHUNK_TYPE_JSON, GLB_HEADER_SIZE, GLB_MAGIC, padded
from .meshopt import EXTENSIONS as MESHOPT_EXTENSIONS
from .meshopt import decompress as decompress_meshopt

#: Most elements one accessor may declare: three indices per face of the largest mesh encoded.
MAX_ACCESSOR_COUNT = 3 * MAX_ENCODE_FACES


def load_document(path):
    """Read a ``.glb`` or ``.gltf``: returns ``(gltf dict, buffers list[bytes])``.

    External buffers and images are read relative to the file, and only from
    inside its folder (see :func:`_resolve_uri`); images with a ``uri`` are
    returned in ``gltf["images"][i]["_bytes"]`` so :func:`repack` can embed them.
    Buffer views compressed with EXT_ / KHR_meshopt_compression come back decoded
    (:func:`~pmwm_codec.format.meshopt.decompress`: gltfpack ``-c`` / ``-cc`` output reads as
    any other).  The JSON is checked first (:func:`check_document`: shapes, references, nesting
    depth, declared sizes against the encoder's limits).  Raises
    :class:`InputFormatError` with a one-line message.
    """
    path = os.fspath(path)
    name = os.path.basename(path)
    data = read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError)
    try:
        if data[:4] == GLB_MAGIC:
            gltf, buffers = _glb_document(data, name)
        else:
            gltf, buffers = _json_document(data, name), []
    except RecursionError:
        raise InputFormatError(f"{name}: glTF JSON nested too deeply") from None
    check_document(gltf, name)
    base_dir = os.path.dirname(os.path.abspath(path))
    budget = [MAX_RESOURCE_BYTES]
    for i, buf in enumerate(gltf.get("buffers", [])):
        if "uri" in buf:
            raw = _resolve_uri(buf["uri"], base_dir, name, budget)
            if i < len(buffers):
                buffers[i] = raw
            else:
                buffers.extend([b""] * (i - len(buffers)) + [raw])
        elif i >= len(buffers):
            buffers.extend([b""] * (i + 1 - len(buffers)))
    for image in gltf.get("images", []):
        if "uri" in image:
            image["_bytes"] = _resolve_uri(image["uri"], base_dir, name, budget)
    return decompress_meshopt(gltf, buffers, name)


def is_progressive(gltf: dict) -> bool:
    """Whether a glTF JSON is a progressive stream (a ``.pmw``, whatever the file is called): it lists
    :data:`~pmwm_codec.constants.EXTENSION_NAME` in ``extensionsUsed``."""
    used = gltf.get("extensionsUsed")
    return isinstance(used, list) and EXTENSION_NAME in used


def progressive_refusal(name: str) -> str:
    """The one line that refuses to read a progressive stream as a plain mesh: a glTF reader sees its base only."""
    return (f"{name}: a progressive .pmw stream ({EXTENSION_NAME}), whose glTF shows only its base mesh; "
            f"decode it first (pmw decode {name} -o full.glb)")


def is_progressive_file(path) -> bool:
    """Whether the glTF at ``path`` (:func:`sniff_json`) is a progressive stream (:func:`is_progressive`)."""
    gltf = sniff_json(path)
    return gltf is not None and is_progressive(gltf)


def sniff_json(path) -> dict | None:
    """The glTF JSON of the GLB (its JSON chunk: the header and that chunk are all that is read) or ``.gltf``
    at ``path``, or None for anything else (no error: the caller's reader names what is wrong).  Only a
    regular file is opened: a FIFO or a device named ``x.glb`` is left to the reader, which refuses it."""
    try:
        if not os.path.isfile(path):
            return None
        with open(path, "rb") as f:
            head = f.read(GLB_HEADER_SIZE + CHUNK_HEADER_SIZE)
            if head[:4] == GLB_MAGIC:
                if len(head) < GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:
                    return None
                (length,) = struct.unpack_from("<I", head, GLB_HEADER_SIZE)
                if head[GLB_HEADER_SIZE + 4 :] != CHUNK_TYPE_JSON or length > MAX_JSON_BYTES:
                    return None
                text = f.read(length)
            else:
                text = head + f.read(MAX_JSON_BYTES + 1 - len(head))
                if len(text) > MAX_JSON_BYTES:
                    return None
        gltf = json.loads(text.decode("utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return None
    return gltf if isinstance(gltf, dict) else None


def uses_meshopt(gltf: dict) -> bool:
    """Whether a glTF JSON lists EXT_ / KHR_meshopt_compression in ``extensionsUsed`` (:mod:`.meshopt`)."""
    used = gltf.get("extensionsUsed")
    return isinstance(used, list) and any(e in used for e in MESHOPT_EXTENSIONS)


def _json_document(data: bytes, name: str) -> dict:
    try:
        gltf = json.loads(data.decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        raise InputFormatError(f"{name}: neither a GLB nor glTF JSON") from None
    if not isinstance(gltf, dict):
        raise InputFormatError(f"{name}: glTF JSON must be an object")
    return gltf


def _glb_document(data: bytes, name: str):
    """``(gltf, buffers)`` of a GLB: the BIN chunk is buffer 0 unless buffers[0] has a uri."""
    gltf, binary = split_glb(data, name)
    first = gltf.get("buffers")
    first = first[0] if isinstance(first, list) and first else None
    buffers = [binary] if isinstance(first, dict) and "uri" not in first else []
    return gltf, buffers


#: A uri with a scheme (``file:``, ``http:`` ...): never fetched.
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


def _resolve_uri(uri, base_dir: str, name: str, budget: list) -> bytes:
    """The bytes a buffer / image ``uri`` names: a ``data:`` URI, or a regular file inside ``base_dir``.

    The uri is percent-decoded, joined onto ``base_dir`` and resolved with
    ``realpath`` (``..`` and symlinks included); it must stay inside the folder
    (resolved too).  Absolute paths and other schemes are refused.  Each resource
    is charged to ``budget[0]`` (bytes left of :data:`MAX_RESOURCE_BYTES`), and a
    file is never read past it.  InputFormatError naming the uri otherwise.
    """
    if not isinstance(uri, str):
        raise InputFormatError(f"{name}: a uri must be a string, got {type(uri).__name__}")
    shown = repr(uri if len(uri) <= 80 else uri[:77] + "...")
    if uri.startswith("data:"):
        blob = _data_uri(uri, name, shown, budget[0])
    else:
        path = urllib.parse.unquote(uri)
        if _SCHEME.match(uri) or _SCHEME.match(path):
            raise InputFormatError(f"{name}: the uri {shown} is not a relative path (only files beside the asset are read)")
        if "\0" in path or os.path.isabs(path) or path.startswith(("\\", "/")):
            raise InputFormatError(f"{name}: the uri {shown} is an absolute path; only files inside the asset's folder are read")
        root = os.path.realpath(base_dir)
        target = os.path.realpath(os.path.join(root, path))
        if os.path.commonpath([root, target]) != root or target == root:
            raise InputFormatError(f"{name}: the uri {shown} leads outside the asset's folder")
        blob = read_regular_file(target, budget[0], InputFormatError, f"{name}: the uri {shown}", follow_symlinks=False)
    budget[0] -= len(blob)
    return blob


def _data_uri(uri: str, name: str, shown: str, limit: int) -> bytes:
    header, sep, payload = uri.partition(",")
    if not sep:
        raise InputFormatError(f"{name}: the data URI {shown} has no ',' before its payload")
    base64_coded = header.endswith(";base64")
    if base64_coded and len(payload) // 4 * 3 > limit:  # decoded size known before decoding
        raise InputFormatError(f"{name}: the data URI {shown} holds more than the limit of {limit:,} bytes")
    try:
        blob = base64.b64decode(payload) if base64_coded else urllib.parse.unquote_to_bytes(payload)
    except (ValueError, TypeError):
        raise InputFormatError(f"{name}: the data URI {shown} does not decode") from None
    if len(blob) > limit:
        raise InputFormatError(f"{name}: the data URI {shown} holds more than the limit of {limit:,} bytes")
    return blob


#: Top-level glTF arrays whose items must be objects.
_ARRAYS = ("accessors", "animations", "buffers", "bufferViews", "cameras", "images", "materials",
           "meshes", "nodes", "samplers", "scenes", "skins", "textures")


def check_document(gltf: dict, name: str) -> None:
    """Refuse (InputFormatError) a glTF JSON the document code cannot walk safely.

    Checks the nesting depth (:data:`MAX_JSON_DEPTH`), that no number is NaN or
    infinite (Python's JSON reader takes ``NaN``, ``Infinity`` and ``1e999``; JSON, and
    so the output, does not), that every array and object
    this module reads has the right JSON type, that every accessor / bufferView
    reference it renumbers is an index in range, and that the triangle primitives
    declare no more vertices and faces in total than the encoder takes
    (:data:`MAX_ENCODE_VERTICES`, :data:`MAX_ENCODE_FACES`) — all before any
    buffer is read or any array allocated.
    """
    check_json_depth(gltf, name)
    check_finite_numbers(gltf, name, InputFormatError)
    for key in _ARRAYS:
        _objects(gltf, key, key, name)
    for key in ("extensionsUsed", "extensionsRequired"):
        if not all(isinstance(e, str) for e in _list(gltf, key, key, name)):
            raise InputFormatError(f"{name}: {key} must be an array of strings")
    n_acc, n_views = len(gltf.get("accessors", [])), len(gltf.get("bufferViews", []))
    for i, view in enumerate(gltf.get("bufferViews", [])):
        _check_view(view, f"bufferViews[{i}]", len(gltf.get("buffers", [])), name)
    for i, acc in enumerate(gltf.get("accessors", [])):
        _check_accessor(acc, f"accessors[{i}]", n_views, name)
    for kind in ("images", "buffers"):
        for i, entry in enumerate(gltf.get(kind, [])):
            if "uri" in entry and not isinstance(entry["uri"], str):
                raise InputFormatError(f"{name}: {kind}[{i}].uri must be a string")
    for i, image in enumerate(gltf.get("images", [])):
        _ref(image, "bufferView", n_views, f"images[{i}]", name)
    for i, skin in enumerate(gltf.get("skins", [])):
        _ref(skin, "inverseBindMatrices", n_acc, f"skins[{i}]", name)
    for i, anim in enumerate(gltf.get("animations", [])):
        for j, sampler in enumerate(_objects(anim, "samplers", f"animations[{i}].samplers", name)):
            for key in ("input", "output"):
                _ref(sampler, key, n_acc, f"animations[{i}].samplers[{j}]", name, required=True)
    for i, node in enumerate(gltf.get("nodes", [])):
        _check_extensions(node, f"nodes[{i}]", n_acc, name, "EXT_mesh_gpu_instancing")
        _ref(node, "mesh", len(gltf.get("meshes", [])), f"nodes[{i}]", name)
    _check_node_trees(gltf.get("nodes", []), name)
    _check_meshes(gltf, n_acc, n_views, name)


def _check_node_trees(nodes: list, name: str) -> None:
    """Refuse a node hierarchy that is not disjoint strict trees (glTF 2.0, 3.5.1): a child index out of
    range, a node with two parents (its meshes would be shown twice, or once, as readers differ), a node
    that is its own ancestor."""
    parent = {}
    for i, node in enumerate(nodes):
        for child in _list(node, "children", f"nodes[{i}].children", name):
            if not isinstance(child, int) or isinstance(child, bool) or not 0 <= child < len(nodes):
                raise InputFormatError(f"{name}: nodes[{i}].children holds {child!r}, not a node index")
            if child == i:
                raise InputFormatError(f"{name}: nodes[{i}] is its own child; glTF nodes form disjoint trees")
            if child in parent:
                raise InputFormatError(f"{name}: nodes[{child}] is a child of nodes[{parent[child]}] and of "
                                       f"nodes[{i}]; glTF nodes form disjoint trees")
            parent[child] = i
    state = {}  # node -> the walk that reached it; each node is walked up once
    for start in range(len(nodes)):
        x = start
        while x in parent and x not in state:
            state[x] = start
            x = parent[x]
        if state.get(x) == start and x in parent:
            raise InputFormatError(f"{name}: nodes[{x}] is its own ancestor; glTF nodes form disjoint trees")


def _check_view(view: dict, where: str, n_buffers: int, name: str) -> None:
    """A bufferView's numbers: ``buffer`` in range, ``byteOffset`` / ``byteLength``
    non-negative integers, ``byteStride`` (if any) a multiple of 4 in 4..252."""
    _ref(view, "buffer", n_buffers, where, name, required=True)
    uint(view, "byteOffset", f"{name}: {where}", 0, error=InputFormatError)
    uint(view, "byteLength", f"{name}: {where}", error=InputFormatError)
    if "byteStride" in view:
        stride = uint(view, "byteStride", f"{name}: {where}", error=InputFormatError)
        if not 4 <= stride <= 252 or stride % 4:
            raise InputFormatError(f"{name}: {where}.byteStride {stride} is not a multiple of 4 in 4..252")


def _check_accessor(acc: dict, where: str, n_views: int, name: str) -> None:
    """An accessor's numbers: known ``componentType`` / ``type``, ``count`` in
    1..:data:`MAX_ACCESSOR_COUNT`, ``byteOffset`` non-negative, bufferView references in
    range, a sparse ``count`` no larger than the accessor's."""
    if acc.get("componentType") not in COMPONENT_DTYPES or acc.get("type") not in TYPE_WIDTH:
        raise InputFormatError(f"{name}: {where} has an unknown componentType or type")
    count = _bounded_count(acc, "count", f"{name}: {where}")
    if count < 1:
        raise InputFormatError(f"{name}: {where}.count must be at least 1")
    uint(acc, "byteOffset", f"{name}: {where}", 0, error=InputFormatError)
    _ref(acc, "bufferView", n_views, where, name)
    if "sparse" in acc:
        sparse = _object(acc["sparse"], f"{where}.sparse", name)
        if _bounded_count(sparse, "count", f"{name}: {where}.sparse") > count:
            raise InputFormatError(f"{name}: {where}.sparse.count is larger than the accessor's count {count}")
        for part in ("indices", "values"):
            _ref(_object(sparse.get(part), f"{where}.sparse.{part}", name), "bufferView", n_views,
                 f"{where}.sparse.{part}", name, required=True)


def _check_meshes(gltf: dict, n_acc: int, n_views: int, name: str) -> None:
    vertices = faces = 0
    accessors = gltf.get("accessors", [])
    for mi, mesh in enumerate(gltf.get("meshes", [])):
        for pi, prim in enumerate(_objects(mesh, "primitives", f"meshes[{mi}].primitives", name)):
            where = f"meshes[{mi}].primitives[{pi}]"
            attrs = _object(prim.get("attributes", {}), f"{where}.attributes", name)
            for semantic in attrs:
                _ref(attrs, semantic, n_acc, f"{where}.attributes", name)
            for ti, target in enumerate(_objects(prim, "targets", f"{where}.targets", name)):
                for semantic in target:
                    _ref(target, semantic, n_acc, f"{where}.targets[{ti}]", name)
            _ref(prim, "indices", n_acc, where, name)
            uint(prim, "mode", f"{name}: {where}", 4, error=InputFormatError)
            draco = _check_extensions(prim, where, n_acc, name, DRACO_EXTENSION)
            if draco is not None:
                _ref(draco, "bufferView", n_views, f"{where} Draco", name, required=True)
            if prim.get("mode", 4) == 4 and "POSITION" in attrs:
                vertices += _count(accessors[attrs["POSITION"]])
                faces += _count(accessors[prim["indices"]]) // 3 if "indices" in prim else 0
    if vertices > MAX_ENCODE_VERTICES or faces > MAX_ENCODE_FACES:
        raise InputFormatError(
            f"{name}: {vertices:,} vertices and {faces:,} faces in its triangle primitives; the encoder's limit is "
            f"{MAX_ENCODE_VERTICES:,} vertices and {MAX_ENCODE_FACES:,} faces")


def _check_extensions(holder: dict, where: str, n_acc: int, name: str, known: str):
    """Check ``holder["extensions"]`` is an object and its ``known`` entry (if any) is one
    whose ``attributes`` are accessor indices; returns that entry or None."""
    exts = _object(holder.get("extensions", {}), f"{where}.extensions", name)
    if known not in exts:
        return None
    entry = _object(exts[known], f"{where}.extensions.{known}", name)
    attrs = _object(entry.get("attributes", {}), f"{where}.extensions.{known}.attributes", name)
    if known != DRACO_EXTENSION:  # Draco attributes are ids in the Draco stream, not accessors
        for semantic in attrs:
            _ref(attrs, semantic, n_acc, f"{where}.extensions.{known}.attributes", name)
    return entry


def _count(acc: dict) -> int:
    value = acc.get("count")
    return value if isinstance(value, int) and not isinstance(value, bool) and value > 0 else 0


def _object(value, where: str, name: str) -> dict:
    if not isinstance(value, dict):
        raise InputFormatError(f"{name}: {where} must be an object, got {type(value).__name__}")
    return value


def _list(holder: dict, key: str, where: str, name: str) -> list:
    value = holder.get(key, [])
    if not isinstance(value, list):
        raise InputFormatError(f"{name}: {where} must be an array, got {type(value).__name__}")
    return value


def _objects(holder: dict, key: str, where: str, name: str) -> list:
    """``holder[key]`` (default []) checked to be an array of objects."""
    items = _list(holder, key, where, name)
    for i, value in enumerate(items):
        _object(value, f"{where}[{i}]", name)
    return items


def _ref(holder: dict, key: str, bound: int, where: str, name: str, required: bool = False) -> None:
    """``holder[key]``, when present (or ``required``), must be an integer index below ``bound``."""
    if key not in holder and not required:
        return
    index = uint(holder, key, f"{name}: {where}", error=InputFormatError)
    if index >= bound:
        raise InputFormatError(f"{name}: {where}.{key} = {index} refers past the {bound} items it indexes")


def check_json_depth(doc, name: str, limit: int = MAX_JSON_DEPTH, error=InputFormatError) -> None:
    """Refuse (``error``) JSON nested deeper than ``limit`` arrays/objects (walked without recursion)."""
    stack = [(doc, 1)]
    while stack:
        value, depth = stack.pop()
        children = value.values() if isinstance(value, dict) else value if isinstance(value, list) else None
        if children is None:
            continue
        if depth > limit:
            raise error(f"{name}: JSON nested more than {limit} levels deep")
        stack.extend((child, depth + 1) for child in children if isinstance(child, (dict, list)))


def read_accessor(gltf: dict, buffers, index: int) -> np.ndarray:
    """Accessor ``index`` as a (count, width) array: float64 for float or normalized data,
    int64 for integer data.  Handles byteStride, missing bufferView (zeros) and sparse.

    Every number of the JSON is checked before anything is allocated: ``count`` is a
    non-negative integer of at most :data:`MAX_ACCESSOR_COUNT`, ``byteOffset``
    non-negative, ``byteStride`` a multiple of 4 in 4..252 no smaller than one
    element, and sparse indices lie inside the accessor (InputFormatError otherwise).
    """
    what = f"accessor {index}"
    try:
        acc = gltf["accessors"][index]
        ctype = acc["componentType"]
        width = TYPE_WIDTH[acc["type"]]
        dtype = np.dtype(COMPONENT_DTYPES[ctype])
    except (KeyError, IndexError, TypeError):
        raise InputFormatError(f"{what}: malformed") from None
    count = _bounded_count(acc, "count", what)
    if "bufferView" in acc:
        raw, stride = _view(gltf, buffers, acc["bufferView"])
        offset = uint(acc, "byteOffset", what, 0, error=InputFormatError)
        item = dtype.itemsize * width
        if stride is not None and (isinstance(stride, bool) or not isinstance(stride, int)
                                   or not 4 <= stride <= 252 or stride % 4 or stride < item):
            raise InputFormatError(f"{what}: byteStride {stride!r} is not a multiple of 4 in {max(4, item)}..252")
        stride = stride or item
        need = offset + (count - 1) * stride + item if count else 0
        if need > len(raw):
            raise InputFormatError(f"{what}: reads past its bufferView")
        out = element_rows(raw, dtype, count, width, offset, stride)
    else:
        out = np.zeros((count, width), dtype=dtype)
    out = _normalized(out, ctype, acc.get("normalized", False))
    if acc.get("sparse"):
        out = _apply_sparse(gltf, buffers, acc, out, what)
    return out


def _bounded_count(holder: dict, key: str, what: str) -> int:
    count = uint(holder, key, what, error=InputFormatError)
    if count > MAX_ACCESSOR_COUNT:
        raise InputFormatError(f"{what}: {key} {count:,} is more than the limit of {MAX_ACCESSOR_COUNT:,}")
    return count


def _apply_sparse(gltf, buffers, acc, out, what):
    """``out`` (count, width) with the sparse substitution of ``acc`` applied (a copy)."""
    sparse, (count, width) = acc["sparse"], out.shape
    n = _bounded_count(sparse, "count", f"{what} sparse")
    ii, vv = sparse["indices"], sparse["values"]
    idx = _sparse_part(gltf, buffers, ii, INDEX_DTYPES.get(ii.get("componentType")), n, 1, f"{what} sparse indices")
    vals = _sparse_part(gltf, buffers, vv, COMPONENT_DTYPES[acc["componentType"]], n, width, f"{what} sparse values")
    if n and int(idx.max()) >= count:
        raise InputFormatError(f"{what}: sparse index {int(idx.max())} is past its {count} elements")
    out = out.copy()
    out[idx.reshape(-1).astype(np.int64)] = _normalized(vals, acc["componentType"], acc.get("normalized", False))
    return out


def _sparse_part(gltf, buffers, part, dtype, n, width, what):
    """(n, width) array of ``dtype`` read tightly packed from ``part``'s bufferView, bounds checked."""
    if dtype is None:
        raise InputFormatError(f"{what}: componentType is not an index type")
    raw, _ = _view(gltf, buffers, part.get("bufferView"))
    offset = uint(part, "byteOffset", what, 0, error=InputFormatError)
    if offset + n * width * np.dtype(dtype).itemsize > len(raw):
        raise InputFormatError(f"{what}: reads past its bufferView")
    return np.frombuffer(raw, dtype=dtype, count=n * width, offset=offset).reshape(n, width)


def _normalized(values, ctype, normalized):
    if ctype == FLOAT:
        return values.astype(np.float64)
    if normalized:
        return np.maximum(values.astype(np.float64) / NORMALIZE_DIVISORS[ctype], -1.0)
    return values.astype(np.int64)


def _view(gltf, buffers, index):
    """``(memoryview of bufferView index, its byteStride or None)``; InputFormatError if malformed."""
    view, raw = view_bytes(gltf, buffers, index, "glTF", error=InputFormatError)
    return raw, view.get("byteStride")


def repack(gltf: dict, buffers, drop_accessors=()):
    """Copy of ``gltf`` without ``drop_accessors`` and without bufferViews nothing uses.

    Returns ``(gltf, bin_bytes)``: every kept bufferView now lives in buffer 0 =
    ``bin_bytes`` (4-byte aligned), external images are embedded as bufferViews,
    and accessor / bufferView references are renumbered.  ``buffers`` of the
    result is left for the writer to set.
    """
    doc = copy.deepcopy({k: v for k, v in gltf.items()})
    _drop_accessors(doc, set(int(i) for i in drop_accessors))
    views = doc.get("bufferViews", [])
    blobs = _embed_images(doc, len(views))
    sites = list(view_sites(doc))
    used = sorted({holder[key] for holder, key in sites})
    view_map, new_views, parts = {}, [], []
    offset = 0
    for i in used:
        if i < len(views):
            view, raw = dict(views[i]), bytes(_view(gltf, buffers, i)[0])
        else:
            view, raw = {"byteLength": len(blobs[i - len(views)])}, blobs[i - len(views)]
        view.update(buffer=0, byteOffset=offset, byteLength=len(raw))
        view_map[i] = len(new_views)
        new_views.append(view)
        parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        offset += padded(len(raw))
    for holder, key in sites:
        holder[key] = view_map[holder[key]]
    doc["bufferViews"] = new_views
    doc.pop("buffers", None)
    return doc, b"".join(parts)


def _drop_accessors(doc: dict, drop: set) -> None:
    """Remove accessors ``drop`` from ``doc`` (in place) and renumber every reference to the rest."""
    acc_map, kept = {}, []
    for i, acc in enumerate(doc.get("accessors", [])):
        if i not in drop:
            acc_map[i] = len(kept)
            kept.append(acc)
    _renumber_accessors(doc, acc_map)
    doc["accessors"] = kept


def _embed_images(doc: dict, first_view: int) -> list:
    """Give every image loaded from a uri (``_bytes``) a new bufferView index from ``first_view`` on.

    Returns the blobs in index order; the views themselves are made by :func:`repack`.
    """
    blobs = []
    for image in doc.get("images", []):
        blob = image.pop("_bytes", None)
        if blob is not None:
            uri = image.pop("uri")
            if "mimeType" not in image:
                image["mimeType"] = _mime(uri, blob)
            image["bufferView"] = first_view + len(blobs)
            blobs.append(blob)
    return blobs


def view_sites(doc: dict):
    """Yield ``(holder, key)`` for every bufferView reference ``holder[key]`` that :func:`repack` knows."""
    for acc in doc.get("accessors", []):
        if "bufferView" in acc:
            yield acc, "bufferView"
        sparse = acc.get("sparse")
        if sparse:
            yield sparse["indices"], "bufferView"
            yield sparse["values"], "bufferView"
    for image in doc.get("images", []):
        if "bufferView" in image:
            yield image, "bufferView"
    for prim in _primitives(doc):
        draco = (prim.get("extensions") or {}).get(DRACO_EXTENSION)
        if isinstance(draco, dict) and "bufferView" in draco:
            yield draco, "bufferView"


def _primitives(doc):
    for mesh in doc.get("meshes", []):
        yield from mesh.get("primitives", [])


def _renumber_accessors(doc, acc_map):
    def m(i):
        return acc_map.get(i)

    for prim in _primitives(doc):
        prim["attributes"] = {k: m(v) for k, v in prim.get("attributes", {}).items() if m(v) is not None}
        if "indices" in prim:
            if m(prim["indices"]) is None:
                del prim["indices"]
            else:
                prim["indices"] = m(prim["indices"])
        if "targets" in prim:
            prim["targets"] = [{k: m(v) for k, v in t.items() if m(v) is not None} for t in prim["targets"]]
    for skin in doc.get("skins", []):
        if "inverseBindMatrices" in skin:
            skin["inverseBindMatrices"] = m(skin["inverseBindMatrices"])
    for anim in doc.get("animations", []):
        for sampler in anim.get("samplers", []):
            sampler["input"] = m(sampler["input"])
            sampler["output"] = m(sampler["output"])
    for node in doc.get("nodes", []):
        inst = (node.get("extensions") or {}).get("EXT_mesh_gpu_instancing")
        if isinstance(inst, dict) and isinstance(inst.get("attributes"), dict):
            inst["attributes"] = {k: m(v) for k, v in inst["attributes"].items()}


def _mime(uri: str, blob: bytes) -> str:
    if blob[:8] == b"\x89PNG\r\n\x1a\n":
        return "image/png"
    if blob[:3] == b"\xff\xd8\xff":
        return "image/jpeg"
    if blob[:4] == b"RIFF" and blob[8:12] == b"WEBP":
        return "image/webp"
    return "image/png" if uri.lower().endswith(".png") else "image/jpeg"


#: PNG chunks that carry colour-space or pixel-aspect metadata (the Khronos validator
#: warns IMAGE_FEATURES_UNSUPPORTED on them); pixels do not depend on them.
PNG_PROFILE_CHUNKS = (b"iCCP", b"cHRM", b"gAMA", b"sRGB", b"pHYs")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def strip_png_profile(blob: bytes) -> bytes:
    """A PNG without its colour-space / pixel-aspect chunks (same pixels); other data unchanged."""
    if blob[:8] != PNG_SIGNATURE:
        return blob
    out, pos = [blob[:8]], 8
    while pos + 12 <= len(blob):
        length = int.from_bytes(blob[pos : pos + 4], "big")
        end = pos + 12 + length
        if end > len(blob):
            return blob  # damaged: leave it alone
        if blob[pos + 4 : pos + 8] not in PNG_PROFILE_CHUNKS:
            out.append(blob[pos:end])
        pos = end
    return b"".join(out)


def strip_image_profiles(gltf: dict, buffers) -> int:
    """Apply :func:`strip_png_profile` to every PNG image of a loaded document, in place.

    Images stored in bufferViews get their own new buffer; returns how many changed.
    """
    changed = 0
    for image in gltf.get("images", []):
        if "_bytes" in image:
            new = strip_png_profile(image["_bytes"])
            if new != image["_bytes"]:
                image["_bytes"], changed = new, changed + 1
        elif "bufferView" in image:
            raw, _ = _view(gltf, buffers, image["bufferView"])
            new = strip_png_profile(bytes(raw))
            if new != bytes(raw):
                # embed as an external-style blob: repack turns it into a fresh bufferView
                image["_bytes"] = new
                image["uri"] = "stripped.png"
                del image["bufferView"]
                changed += 1
    return changed


def glb_to_gltf(glb: bytes) -> bytes:
    """A GLB as a self-contained ``.gltf`` (JSON text with the BIN chunk as a base64 data URI)."""
    gltf, buffers = _glb_document(glb, "GLB")
    if buffers and gltf.get("buffers"):
        gltf["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(buffers[0]).decode("ascii")
    return (json.dumps(gltf, indent=1) + "\n").encode("utf-8")
