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
from .glb import split_glb
from .gltf import COMPONENT_DTYPES, DRACO_EXTENSION, FLOAT, NORMALIZE_DIVISORS, TYPE_WIDTH, view_bytes
from .layout import GLB_MAGIC, padded


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
        gltf, buffers = _glb_document(data, name)
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


def _glb_document(data: bytes, name: str):
    """``(gltf, buffers)`` of a GLB: the BIN chunk is buffer 0 unless buffers[0] has a uri."""
    gltf, binary = split_glb(data, name)
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
    sites = list(_view_sites(doc))
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


def _view_sites(doc: dict):
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
