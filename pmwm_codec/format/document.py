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
import urllib.parse

import numpy as np

from ..errors import InputFormatError
from .layout import CHUNK_HEADER_SIZE, CHUNK_TYPE_BIN, CHUNK_TYPE_JSON, GLB_HEADER_SIZE, GLB_MAGIC, ChunkHeader, GlbHeader, padded

COMPONENT_DTYPES = {5120: "i1", 5121: "u1", 5122: "<i2", 5123: "<u2", 5125: "<u4", 5126: "<f4"}
TYPE_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_NORMALIZE = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0}


def load_document(path):
    """Read a ``.glb`` or ``.gltf``: returns ``(gltf dict, buffers list[bytes])``.

    External buffers and images are read relative to the file; images with a
    ``uri`` are returned in ``gltf["images"][i]["_bytes"]`` so :func:`repack`
    can embed them.  Raises :class:`InputFormatError` with a one-line message.
    """
    path = os.fspath(path)
    name = os.path.basename(path)
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise InputFormatError(f"{path}: {exc.strerror or exc}") from None
    if data[:4] == GLB_MAGIC:
        gltf, buffers = _parse_glb(data, name)
    else:
        try:
            gltf = json.loads(data.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            raise InputFormatError(f"{name}: neither a GLB nor glTF JSON") from None
        if not isinstance(gltf, dict):
            raise InputFormatError(f"{name}: glTF JSON must be an object")
        buffers = []
    base_dir = os.path.dirname(os.path.abspath(path))
    for i, buf in enumerate(gltf.get("buffers", [])):
        if "uri" in buf:
            raw = _resolve_uri(buf["uri"], base_dir, name)
            if i < len(buffers):
                buffers[i] = raw
            else:
                buffers.extend([b""] * (i - len(buffers)) + [raw])
        elif i >= len(buffers):
            buffers.extend([b""] * (i + 1 - len(buffers)))
    for image in gltf.get("images", []):
        if "uri" in image:
            image["_bytes"] = _resolve_uri(image["uri"], base_dir, name)
    return gltf, buffers


def _parse_glb(data: bytes, name: str):
    if len(data) < GLB_HEADER_SIZE + CHUNK_HEADER_SIZE:
        raise InputFormatError(f"{name}: GLB is cut short")
    try:
        header = GlbHeader.parse(data[:GLB_HEADER_SIZE])
    except Exception:
        raise InputFormatError(f"{name}: not a GLB file") from None
    if header.length > len(data):
        raise InputFormatError(f"{name}: GLB is cut short ({len(data)} of {header.length} bytes)")
    pos = GLB_HEADER_SIZE
    gltf, binary = None, b""
    while pos + CHUNK_HEADER_SIZE <= header.length:
        chunk = ChunkHeader.parse(data[pos : pos + CHUNK_HEADER_SIZE])
        body = data[pos + CHUNK_HEADER_SIZE : pos + CHUNK_HEADER_SIZE + chunk.length]
        if chunk.type == CHUNK_TYPE_JSON and gltf is None:
            try:
                gltf = json.loads(body.decode("utf-8"))
            except (UnicodeDecodeError, ValueError):
                raise InputFormatError(f"{name}: GLB JSON chunk is not valid JSON") from None
        elif chunk.type == CHUNK_TYPE_BIN and not binary:
            binary = bytes(body)
        pos += CHUNK_HEADER_SIZE + chunk.length
    if not isinstance(gltf, dict):
        raise InputFormatError(f"{name}: GLB has no JSON chunk")
    buffers = [binary] if gltf.get("buffers") and "uri" not in gltf["buffers"][0] else []
    return gltf, buffers


def _resolve_uri(uri: str, base_dir: str, name: str) -> bytes:
    if uri.startswith("data:"):
        try:
            header, payload = uri.split(",", 1)
            return base64.b64decode(payload) if header.endswith(";base64") else urllib.parse.unquote_to_bytes(payload)
        except (ValueError, TypeError):
            raise InputFormatError(f"{name}: a data URI does not decode") from None
    target = os.path.join(base_dir, urllib.parse.unquote(uri))
    try:
        with open(target, "rb") as fh:
            return fh.read()
    except OSError:
        raise InputFormatError(f"{name}: cannot read the resource {uri!r} beside it") from None


def read_accessor(gltf: dict, buffers, index: int) -> np.ndarray:
    """Accessor ``index`` as a (count, width) array: float64 for float or normalized data,
    int64 for integer data.  Handles byteStride, missing bufferView (zeros) and sparse."""
    try:
        acc = gltf["accessors"][index]
        ctype = acc["componentType"]
        width = TYPE_WIDTH[acc["type"]]
        count = int(acc["count"])
        dtype = np.dtype(COMPONENT_DTYPES[ctype])
    except (KeyError, IndexError, TypeError):
        raise InputFormatError(f"accessor {index}: malformed") from None
    if "bufferView" in acc:
        raw, stride = _view(gltf, buffers, acc["bufferView"])
        offset = int(acc.get("byteOffset", 0))
        item = dtype.itemsize * width
        stride = stride or item
        need = offset + (count - 1) * stride + item if count else 0
        if need > len(raw):
            raise InputFormatError(f"accessor {index}: reads past its bufferView")
        if stride == item:
            out = np.frombuffer(raw, dtype=dtype, count=count * width, offset=offset).reshape(count, width)
        else:
            rows = np.frombuffer(raw, dtype=np.uint8, count=need - offset, offset=offset)
            idx = (np.arange(count)[:, None] * stride + np.arange(item)[None, :])
            out = rows[idx].copy().view(dtype).reshape(count, width)
    else:
        out = np.zeros((count, width), dtype=dtype)
    out = _normalized(out, ctype, acc.get("normalized", False))
    sparse = acc.get("sparse")
    if sparse:
        out = out.copy()
        n = int(sparse["count"])
        ii = sparse["indices"]
        raw_i, _ = _view(gltf, buffers, ii["bufferView"])
        idx = np.frombuffer(raw_i, dtype=COMPONENT_DTYPES[ii["componentType"]], count=n, offset=int(ii.get("byteOffset", 0)))
        vv = sparse["values"]
        raw_v, _ = _view(gltf, buffers, vv["bufferView"])
        vals = np.frombuffer(raw_v, dtype=dtype, count=n * width, offset=int(vv.get("byteOffset", 0))).reshape(n, width)
        out[idx.astype(np.int64)] = _normalized(vals, ctype, acc.get("normalized", False))
    return out


def _normalized(values, ctype, normalized):
    if ctype == 5126:
        return values.astype(np.float64)
    if normalized:
        return np.maximum(values.astype(np.float64) / _NORMALIZE[ctype], -1.0)
    return values.astype(np.int64)


def _view(gltf, buffers, index):
    try:
        view = gltf["bufferViews"][index]
        buf = buffers[int(view.get("buffer", 0))]
        start = int(view.get("byteOffset", 0))
        length = int(view["byteLength"])
    except (KeyError, IndexError, TypeError, ValueError):
        raise InputFormatError(f"bufferView {index}: malformed or its buffer is missing") from None
    if start + length > len(buf):
        raise InputFormatError(f"bufferView {index}: reaches past the end of its buffer")
    return memoryview(buf)[start : start + length], view.get("byteStride")


def repack(gltf: dict, buffers, drop_accessors=()):
    """Copy of ``gltf`` without ``drop_accessors`` and without bufferViews nothing uses.

    Returns ``(gltf, bin_bytes)``: every kept bufferView now lives in buffer 0 =
    ``bin_bytes`` (4-byte aligned), external images are embedded as bufferViews,
    and accessor / bufferView references are renumbered.  ``buffers`` of the
    result is left for the writer to set.
    """
    doc = copy.deepcopy({k: v for k, v in gltf.items()})
    drop = set(int(i) for i in drop_accessors)
    accessors = doc.get("accessors", [])
    acc_map = {}
    kept_acc = []
    for i, acc in enumerate(accessors):
        if i not in drop:
            acc_map[i] = len(kept_acc)
            kept_acc.append(acc)
    _renumber_accessors(doc, acc_map)
    doc["accessors"] = kept_acc

    views = doc.get("bufferViews", [])
    extra_blobs = []
    for image in doc.get("images", []):
        blob = image.pop("_bytes", None)
        if blob is not None:
            uri = image.pop("uri")
            if "mimeType" not in image:
                image["mimeType"] = _mime(uri, blob)
            image["bufferView"] = len(views) + len(extra_blobs)
            extra_blobs.append(blob)
    used = set()
    for acc in kept_acc:
        if "bufferView" in acc:
            used.add(acc["bufferView"])
        sparse = acc.get("sparse")
        if sparse:
            used.add(sparse["indices"]["bufferView"])
            used.add(sparse["values"]["bufferView"])
    for image in doc.get("images", []):
        if "bufferView" in image:
            used.add(image["bufferView"])
    for prim in _primitives(doc):
        draco = (prim.get("extensions") or {}).get("KHR_draco_mesh_compression")
        if isinstance(draco, dict) and "bufferView" in draco:
            used.add(draco["bufferView"])

    view_map = {}
    new_views = []
    parts = []
    offset = 0
    for i in sorted(used):
        if i < len(views):
            view = dict(views[i])
            raw, _ = _view(gltf, buffers, i)
            raw = bytes(raw)
        else:
            blob = extra_blobs[i - len(views)]
            view, raw = {"byteLength": len(blob)}, blob
        view["buffer"] = 0
        view["byteOffset"] = offset
        view["byteLength"] = len(raw)
        view_map[i] = len(new_views)
        new_views.append(view)
        parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        offset += padded(len(raw))
    for acc in kept_acc:
        if "bufferView" in acc:
            acc["bufferView"] = view_map[acc["bufferView"]]
        sparse = acc.get("sparse")
        if sparse:
            sparse["indices"]["bufferView"] = view_map[sparse["indices"]["bufferView"]]
            sparse["values"]["bufferView"] = view_map[sparse["values"]["bufferView"]]
    for image in doc.get("images", []):
        if "bufferView" in image:
            image["bufferView"] = view_map[image["bufferView"]]
    for prim in _primitives(doc):
        draco = (prim.get("extensions") or {}).get("KHR_draco_mesh_compression")
        if isinstance(draco, dict) and "bufferView" in draco:
            draco["bufferView"] = view_map[draco["bufferView"]]
    doc["bufferViews"] = new_views
    doc.pop("buffers", None)
    return doc, b"".join(parts)


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
    gltf, buffers = _parse_glb(glb, "GLB")
    if buffers and gltf.get("buffers"):
        gltf["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(buffers[0]).decode("ascii")
    return (json.dumps(gltf, indent=1) + "\n").encode("utf-8")
