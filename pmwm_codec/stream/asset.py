"""glTF assets in and out: every triangle primitive progressive, everything else kept.

:func:`encode_asset` reads a ``.glb`` / ``.gltf`` (or an in-memory ``(gltf, buffers)``),
makes every *eligible* triangle primitive progressive, and carries the rest of the
document over unchanged: materials, textures, images (external ones embedded),
samplers, the node tree with names and transforms, scenes, cameras, skins,
animations, ``extras`` and extensions it does not know.

Eligible: ``mode`` TRIANGLES, a POSITION, no morph ``targets``, no ``JOINTS_n`` /
``WEIGHTS_n`` (skinned).  Draco-compressed input primitives are decoded first
(attributes looked up by their Draco unique ids).  Any other primitive
(points, lines, strips, morphs, skins) passes through untouched, with a notice.
Every other vertex attribute (NORMAL, TANGENT, TEXCOORD_n, COLOR_n, custom)
rides with the splits on its own integer grid.

Seams.  glTF vertices are already split where UVs or normals jump; the copies
share a position.  Every vertex whose position is shared with another vertex of
the same glTF mesh (a seam, or a border between two primitives of one mesh) is
locked: it stays in the base mesh, so both sides of every seam have identical
positions at every level of detail (no cracks).  Collapses elsewhere may still
land *on* seam vertices (the kept vertex never moves).

:func:`decode_asset` turns a ``.pmw`` (whole or cut) back into an ordinary GLB
at any level: the same document with each progressive primitive's geometry
replaced by plain accessors for that level and the extension removed.
"""

from __future__ import annotations

import copy
import os

import numpy as np

from ..constants import EXTENSION_NAME
from ..errors import InputFormatError, MeshError, PmwError
from ..format.base import DRACO_EXTENSION
from ..format.document import load_document, read_accessor, repack
from ..format.document import strip_image_profiles as _strip_profiles
from ..format.glb import glb_parts
from ..format.parser import _blocks, parse_preamble
from ..format.layout import CHUNK_HEADER_SIZE, PREAMBLE_SIZE, padded
from ..mesh import Mesh, checked_mesh
from .decoder import StreamDecoder
from .encoder import EncodeReport, PrimitiveJob, encode_document

TRIANGLES = 4
ASSET_SUFFIXES = (".glb", ".gltf")


def is_asset_path(path) -> bool:
    return isinstance(path, (str, os.PathLike)) and os.fspath(path).lower().endswith(ASSET_SUFFIXES)


def plan_asset(gltf: dict, buffers) -> tuple:
    """Split a document's primitives into progressive jobs and pass-throughs.

    Returns ``(jobs: list[PrimitiveJob], drop_accessors: set, notices: list[str])``.
    """
    jobs, notices = [], []
    users = {}  # accessor -> number of pass-through users
    candidates = []
    for mi, mesh in enumerate(gltf.get("meshes", [])):
        for pi, prim in enumerate(mesh.get("primitives", [])):
            attrs = prim.get("attributes", {})
            why = _why_not(prim)
            where = f"mesh {mi}" + (f" ({mesh['name']})" if mesh.get("name") else "") + f" primitive {pi}"
            if why is None:
                candidates.append((mi, pi, prim, where))
                continue
            notices.append(f"{where}: {why}; passed through unchanged")
            for idx in list(attrs.values()) + ([prim["indices"]] if "indices" in prim else []):
                users[idx] = users.get(idx, 0) + 1
            for target in prim.get("targets", []):
                for idx in target.values():
                    users[idx] = users.get(idx, 0) + 1

    by_mesh = {}
    for mi, pi, prim, where in candidates:
        try:
            mesh = _primitive_mesh(gltf, buffers, prim, where)
        except (MeshError, InputFormatError) as exc:
            notices.append(f"{where}: {exc}; passed through unchanged")
            for idx in list(prim.get("attributes", {}).values()) + ([prim["indices"]] if "indices" in prim else []):
                users[idx] = users.get(idx, 0) + 1
            continue
        job = PrimitiveJob(mesh, mi, pi)
        jobs.append(job)
        by_mesh.setdefault(mi, []).append(job)
    for mi, group in by_mesh.items():
        _lock_shared_positions(group)

    drop = set()
    for job in jobs:
        prim = gltf["meshes"][job.mesh_index]["primitives"][job.primitive_index]
        for idx in list(prim.get("attributes", {}).values()) + ([prim["indices"]] if "indices" in prim else []):
            if users.get(idx, 0) == 0:
                drop.add(idx)
    return jobs, drop, notices


def _why_not(prim: dict):
    if prim.get("mode", TRIANGLES) != TRIANGLES:
        return f"mode {prim.get('mode')} is not TRIANGLES"
    attrs = prim.get("attributes", {})
    if "POSITION" not in attrs:
        return "no POSITION"
    if prim.get("targets"):
        return "morph targets are not made progressive"
    if any(k.startswith(("JOINTS_", "WEIGHTS_")) for k in attrs):
        return "skinned primitives are not made progressive"
    return None


def _primitive_mesh(gltf, buffers, prim, where) -> Mesh:
    """The primitive's geometry and attributes as a checked :class:`Mesh` (Draco input decoded)."""
    draco = (prim.get("extensions") or {}).get(DRACO_EXTENSION)
    if draco is not None:
        return _draco_mesh(gltf, buffers, prim, draco, where)
    attrs = prim["attributes"]
    positions = read_accessor(gltf, buffers, attrs["POSITION"]).astype(np.float64)
    n = len(positions)
    if "indices" in prim:
        faces = read_accessor(gltf, buffers, prim["indices"]).reshape(-1)
    else:
        faces = np.arange(n)
    if len(faces) % 3:
        raise MeshError("index count is not a multiple of 3")
    faces = faces.reshape(-1, 3)
    extra = {}
    for semantic, idx in attrs.items():
        if semantic == "POSITION":
            continue
        values = read_accessor(gltf, buffers, idx)
        extra[semantic] = values.astype(np.float64)
    return checked_mesh(positions, faces, extra, name=where)


def _draco_mesh(gltf, buffers, prim, draco, where) -> Mesh:
    """A ``KHR_draco_mesh_compression`` input primitive, decoded with DracoPy.

    Attributes are looked up by the unique ids the extension names (never by
    position in the Draco stream); the decoded values replace the accessors.
    """
    import DracoPy

    from ..format.document import _view

    try:
        raw, _ = _view(gltf, buffers, draco["bufferView"])
        decoded = DracoPy.decode(bytes(raw))
    except (KeyError, TypeError, InputFormatError):
        raise InputFormatError("its Draco data is missing") from None
    except Exception as exc:  # DracoPy raises its own exception types
        raise InputFormatError(f"its Draco data does not decode ({str(exc).splitlines()[0]})") from None
    ids = draco.get("attributes", {})
    values = {}
    for semantic in prim.get("attributes", {}):
        if semantic not in ids:
            raise InputFormatError(f"Draco attributes lack {semantic}")
        attribute = decoded.get_attribute_by_unique_id(ids[semantic])
        if attribute is None:
            raise InputFormatError(f"Draco data has no attribute {ids[semantic]} for {semantic}")
        data = np.asarray(attribute["data"], dtype=np.float64)
        values[semantic] = data.reshape(len(data), -1)
    faces = np.asarray(decoded.faces, dtype=np.int64).reshape(-1, 3)
    positions = values.pop("POSITION")
    return checked_mesh(positions, faces, values, name=where)


def _lock_shared_positions(jobs) -> None:
    """Lock every vertex whose position also belongs to another vertex of the same glTF mesh."""
    points = np.concatenate([j.mesh.positions for j in jobs])
    _, inverse, counts = np.unique(points, axis=0, return_inverse=True, return_counts=True)
    shared = counts[inverse.reshape(-1)] > 1
    start = 0
    for job in jobs:
        n = job.mesh.vertex_count
        job.locked = shared[start : start + n]
        start += n


def encode_asset(src, dst, *, strip_image_profiles: bool = False, **options) -> EncodeReport:
    """Encode a glTF asset (path, or ``(gltf dict, buffers)``) into a ``.pmw`` at ``dst``.

    Options as :func:`~pmwm_codec.stream.encoder.encode_document`, plus
    ``strip_image_profiles``: drop colour-profile / pixel-aspect chunks from PNG
    textures (same pixels; the glTF validator warns on them).  Images are otherwise
    carried byte for byte.  The report's ``notices`` say which primitives passed
    through and why.
    """
    if isinstance(src, tuple):
        gltf, buffers = copy.deepcopy(src[0]), list(src[1])
    else:
        gltf, buffers = load_document(src)
    notices = []
    if strip_image_profiles:
        count = _strip_profiles(gltf, buffers)
        if count:
            notices.append(f"removed colour-profile metadata from {count} PNG image(s)")
    jobs, drop, planned = plan_asset(gltf, buffers)
    notices += planned
    _forget_input_draco(gltf, jobs)
    if not jobs:
        raise PmwError("the asset has no triangle primitive that can be made progressive")
    doc, kept_bin = repack(gltf, buffers, drop)
    report = encode_document(doc, kept_bin, jobs, dst, **options)
    report.notices = notices + report.notices
    return report


def _forget_input_draco(gltf: dict, jobs) -> None:
    """Drop the input's Draco extension from primitives that become progressive (their
    geometry is re-encoded), and from the extension lists if nothing else uses it."""
    for job in jobs:
        prim = gltf["meshes"][job.mesh_index]["primitives"][job.primitive_index]
        exts = prim.get("extensions")
        if isinstance(exts, dict) and exts.pop(DRACO_EXTENSION, None) is not None and not exts:
            del prim["extensions"]
    still = any(DRACO_EXTENSION in (p.get("extensions") or {}) for m in gltf.get("meshes", [])
                for p in m.get("primitives", []))
    if not still:
        for key in ("extensionsUsed", "extensionsRequired"):
            if key in gltf:
                gltf[key] = [e for e in gltf[key] if e != DRACO_EXTENSION]
                if not gltf[key]:
                    del gltf[key]


def _read_all(src) -> bytes:
    if isinstance(src, (bytes, bytearray, memoryview)):
        return bytes(src)
    return b"".join(bytes(b) for b in _blocks(src, 1 << 20))


def decode_asset(src, chunks=None):
    """A ``.pmw`` (path, bytes, file; whole or cut) as an ordinary GLB at a level of detail.

    Returns ``(glb bytes, StreamEnd, decoder)``: the document with every progressive
    primitive's geometry replaced by plain accessors for the level reached
    (base + ``chunks`` chunks, or as many as arrived) and the extension removed.
    """
    data = _read_all(src)
    decoder = StreamDecoder(copy=False, max_chunks=chunks)
    results = decoder.feed(data)
    end = decoder.close()
    last = results[-1]
    gltf = decoder.header.gltf_json
    _, json_length = parse_preamble(data[:PREAMBLE_SIZE])
    bin_start = PREAMBLE_SIZE + json_length + CHUNK_HEADER_SIZE
    from ..format.base import find_extension_primitives

    found = find_extension_primitives(gltf, EXTENSION_NAME)
    doc = copy.deepcopy(gltf)
    drop = set()
    for mi, pi, prim in found:
        p = doc["meshes"][mi]["primitives"][pi]
        drop.update(p.get("attributes", {}).values())
        if "indices" in p:
            drop.add(p["indices"])
        exts = p.get("extensions", {})
        exts.pop(EXTENSION_NAME, None)
        exts.pop(DRACO_EXTENSION, None)
        if not exts:
            p.pop("extensions", None)
    buffers = [data[bin_start:]]
    kept, kept_bin = repack(doc, buffers, drop)
    bin_parts = [kept_bin]
    offset = len(kept_bin)
    views, accessors = kept["bufferViews"], kept["accessors"]

    def add(array, component, type_, target=None, minmax=False):
        nonlocal offset
        raw = np.ascontiguousarray(array).tobytes()
        views.append({"buffer": 0, "byteOffset": offset, "byteLength": len(raw), **({"target": target} if target else {})})
        bin_parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        offset += padded(len(raw))
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": int(len(array)), "type": type_}
        if minmax:
            acc["min"] = [float(x) for x in array.min(0)]
            acc["max"] = [float(x) for x in array.max(0)]
        accessors.append(acc)
        return len(accessors) - 1

    for (mi, pi, _), part in zip(found, last.parts):
        p = kept["meshes"][mi]["primitives"][pi]
        pos = part.positions.astype(np.float32)
        attributes = {"POSITION": add(pos, 5126, "VEC3", 34962, minmax=True)}
        for semantic, values in part.attribute_values().items():
            values = values.astype(np.float32)
            if semantic.startswith(("NORMAL", "TANGENT")):
                values = _renormalized(values)
            type_ = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}[values.shape[1]]
            attributes[semantic] = add(values, 5126, type_, 34962)
        p["attributes"] = attributes
        p["indices"] = add(np.asarray(part.faces, np.uint32).reshape(-1), 5125, "SCALAR", 34963)
        p["mode"] = TRIANGLES
    used = [e for e in kept.get("extensionsUsed", []) if e not in (EXTENSION_NAME,)]
    if not any(DRACO_EXTENSION in (pr.get("extensions") or {}) for m in kept.get("meshes", []) for pr in m.get("primitives", [])):
        used = [e for e in used if e != DRACO_EXTENSION]
        if "extensionsRequired" in kept:
            kept["extensionsRequired"] = [e for e in kept["extensionsRequired"] if e != DRACO_EXTENSION]
            if not kept["extensionsRequired"]:
                del kept["extensionsRequired"]
    if used:
        kept["extensionsUsed"] = used
    else:
        kept.pop("extensionsUsed", None)
    kept["buffers"] = [{"byteLength": offset}]
    return b"".join(glb_parts(kept, bin_parts, offset)), end, decoder


def _renormalized(values: np.ndarray) -> np.ndarray:
    """Unit-length xyz for NORMAL / TANGENT (w of a tangent kept)."""
    out = values.copy()
    length = np.linalg.norm(out[:, :3], axis=1, keepdims=True)
    out[:, :3] = np.where(length > 0, out[:, :3] / np.maximum(length, 1e-30), out[:, :3])
    return out
