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
    MAX_RESOURCE_BYTES,
)
from ..errors import InputFormatError, MeshError
from ..sources import read_regular_file
from .glb import GLTF_1_ADVICE, split_glb
from .gltf import (COMPONENT_DTYPES, COMPONENT_NAMES, DRACO_EXTENSION, FLOAT, INDEX_DTYPES, NORMALIZE_DIVISORS,
                   QUANTIZATION_EXTENSION, TRIANGLE_MODES, TRIANGLE_STRIP, TRIANGLES, TYPE_WIDTH, check_finite_numbers,
                   check_json_depth, element_rows, gltf_integers, named, named_view_sites, shown_value, triangle_list,
                   uint, view_bytes)
from .layout import CHUNK_HEADER_SIZE, CHUNK_TYPE_JSON, GLB_HEADER_SIZE, GLB_MAGIC, padded
from .meshopt import EXTENSIONS as MESHOPT_EXTENSIONS
from .meshopt import decompress as decompress_meshopt

#: Most elements one accessor may declare: three indices per face of the largest mesh encoded.
MAX_ACCESSOR_COUNT = 3 * MAX_ENCODE_FACES


def load_document(path):
    """Read a ``.glb`` or ``.gltf``: returns ``(gltf dict, buffers list[bytes])``.

    External buffers and images are read relative to the file, and only from
    inside its folder (see :func:`_resolve_uri`); images with a ``uri`` are
    returned in ``gltf["images"][i]["_bytes"]`` so :func:`repack` can embed them, and every image
    embedded or in a bufferView gets its ``mimeType`` (:func:`label_images`).
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
    _check_buffer_lengths(gltf, buffers, data[:4] == GLB_MAGIC, name)
    for image in gltf.get("images", []):
        if "uri" in image:
            image["_bytes"] = _resolve_uri(image["uri"], base_dir, name, budget)
    gltf, buffers = decompress_meshopt(gltf, buffers, name)
    label_images(gltf, buffers, name)
    check_rig_data(gltf, buffers, name)
    return gltf, buffers


def _check_buffer_lengths(gltf: dict, buffers: list, glb: bool, name: str) -> None:
    """Refuse a buffer that holds fewer bytes than its ``byteLength`` declares, and a bufferView that ends past
    its buffer's declared ``byteLength`` (the glTF validator's BUFFER_*_BYTELENGTH_MISMATCH and
    BUFFER_VIEW_TOO_LONG): either way the document and its data disagree on what the buffer is, and the
    bytes a view read were never declared (a declared 40 over a 60-byte BIN chunk was read to its end
    without a word).  A buffer may hold more than it declares (a GLB's BIN chunk pads to 4 bytes, a
    ``.bin`` file may run on): the views, inside the declared length, read the same bytes.  A
    meshopt fallback buffer holds no bytes by design (its views are decoded from another buffer)."""
    from .meshopt import _fallback_ext

    declared = []
    for i, buf in enumerate(gltf.get("buffers", [])):
        length = uint(buf, "byteLength", f"{name}: buffers[{i}]", error=InputFormatError)
        declared.append(length)
        if _fallback_ext(buf):
            continue
        if "uri" in buf:
            source = "its uri holds"
        elif i == 0 and glb:
            source = "the GLB's BIN chunk holds"
        else:
            continue  # no data of its own: a view that reads it is refused by its reader
        have = len(buffers[i]) if i < len(buffers) else 0
        if have < length:
            raise InputFormatError(f"{name}: buffers[{i}] declares byteLength {length:,} but {source} "
                                   f"{have:,} bytes (cut short, or the wrong length declared)")
    for i, view in enumerate(gltf.get("bufferViews", [])):
        end = view.get("byteOffset", 0) + view["byteLength"]  # (check_document: integers, a buffer in range)
        if end > declared[view["buffer"]]:
            raise InputFormatError(f"{name}: bufferViews[{i}] ends at byte {end:,}, past the byteLength "
                                   f"{declared[view['buffer']]:,} buffers[{view['buffer']}] declares")


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


def named_files(path) -> list:
    """The real paths of the files the ``.gltf`` / GLB at ``path`` names besides itself -- buffers and images by a
    ``uri`` that is not a ``data:`` URI -- that are regular files inside its folder (:func:`beside`), each once,
    in the order named; a uri the encoder would refuse, or whose file is missing, is left out (the encode names
    it).  What a record of the input must cover besides the file (``pmw batch``'s ledger)."""
    gltf = sniff_json(path)
    out = []
    base_dir = os.path.dirname(os.path.abspath(path))
    for key in ("buffers", "images"):
        items = gltf.get(key) if gltf is not None else None
        for item in items if isinstance(items, list) else []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if not isinstance(uri, str) or uri.startswith("data:") or _SCHEME.match(uri):
                continue
            try:
                target = beside(urllib.parse.unquote(uri), base_dir, uri)
            except InputFormatError:
                continue
            if os.path.isfile(target) and target not in out:
                out.append(target)
    return out


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
#: ASCII white space, which a base64 data URI may hold between its characters.
_NO_WHITE_SPACE = re.compile(r"[ \t\r\n\f\v]+")


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
        blob = read_beside(path, base_dir, f"{name}: the uri {shown}", budget)
    if not blob:  # glTF: a buffer's and a bufferView's byteLength are at least 1; an empty image is none
        raise InputFormatError(f"{name}: the uri {shown} holds no bytes")
    budget[0] -= len(blob)
    return blob


def beside(path: str, base_dir: str, label: str) -> str:
    """The real path of the file ``path`` names relative to ``base_dir``, which must stay inside that folder
    (resolved too: ``..`` and symlinks included) -- the rule for every file an input names besides itself (a
    ``.gltf``'s buffers and images, an OBJ's MTL files and their textures).  InputFormatError starting with
    ``label`` for an absolute path, a NUL, or a path that leads outside the folder (or is the folder)."""
    if "\0" in path or os.path.isabs(path) or path.startswith(("\\", "/")):
        raise InputFormatError(f"{label} is an absolute path; only files inside the asset's folder are read")
    root = os.path.realpath(base_dir)
    target = os.path.realpath(os.path.join(root, path))
    if os.path.commonpath([root, target]) != root or target == root:
        raise InputFormatError(f"{label} leads outside the asset's folder")
    return target


def read_beside(path: str, base_dir: str, label: str, budget: list) -> bytes:
    """The bytes of the regular file :func:`beside` finds, never read past ``budget[0]`` bytes (the caller
    charges them) and not through a symlink as its last component; InputFormatError starting with ``label``,
    also for a watermark key file (by name or content: :func:`~pmwm_codec.watermark.key.is_key_file`), whose
    secret would otherwise ride in the output as a buffer's or an image's bytes."""
    from ..watermark.key import is_key_file

    target = beside(path, base_dir, label)
    if is_key_file(target):
        raise InputFormatError(f"{label} names a watermark key file, never read into an asset: its secret "
                               "would be in the output")
    return read_regular_file(target, budget[0], InputFormatError, label, follow_symlinks=False)


def _data_uri(uri: str, name: str, shown: str, limit: int) -> bytes:
    header, sep, payload = uri.partition(",")
    if not sep:
        raise InputFormatError(f"{name}: the data URI {shown} has no ',' before its payload")
    base64_coded = header.endswith(";base64")
    if base64_coded and len(payload) // 4 * 3 > limit:  # decoded size known before decoding
        raise InputFormatError(f"{name}: the data URI {shown} holds more than the limit of {limit:,} bytes")
    try:
        # strict: a character outside the alphabet is an error, not dropped (``@@@@`` decoded to no bytes);
        # ASCII white space (base64 broken over lines) is not part of the data
        blob = base64.b64decode(_NO_WHITE_SPACE.sub("", payload), validate=True) if base64_coded else \
            urllib.parse.unquote_to_bytes(payload)
    except (ValueError, TypeError):
        raise InputFormatError(f"{name}: the data URI {shown} does not decode") from None
    if len(blob) > limit:
        raise InputFormatError(f"{name}: the data URI {shown} holds more than the limit of {limit:,} bytes")
    return blob


#: Top-level glTF arrays whose items must be objects.
_ARRAYS = ("accessors", "animations", "buffers", "bufferViews", "cameras", "images", "materials",
           "meshes", "nodes", "samplers", "scenes", "skins", "textures")

#: Extensions an input may list in ``extensionsRequired``: what the reader implements -- Draco and
#: meshopt data are decoded, quantized accessors read (KHR_mesh_quantization: any componentType,
#: ``normalized``), GPU instancing placed and renumbered -- and this package's own (a ``.pmw``, refused
#: by name as an input).
READ_EXTENSIONS = (DRACO_EXTENSION, *MESHOPT_EXTENSIONS, QUANTIZATION_EXTENSION, "EXT_mesh_gpu_instancing",
                   EXTENSION_NAME)
#: Required extensions carried to the output still required: they say only how materials, textures,
#: images and lights look, which the encoder copies unchanged (it reads no pixel, and a texture
#: transform applies to the TEXCOORD values the splits carry), so the output asks a viewer for them
#: as the input did.  Any other required extension may change what the geometry means (how an
#: accessor, a buffer or a primitive reads): refused, never guessed.
CARRIED_EXTENSIONS = (
    "KHR_texture_basisu", "EXT_texture_webp", "EXT_texture_avif", "MSFT_texture_dds", "KHR_texture_transform",
    "KHR_materials_anisotropy", "KHR_materials_clearcoat", "KHR_materials_diffuse_transmission",
    "KHR_materials_dispersion", "KHR_materials_emissive_strength", "KHR_materials_ior", "KHR_materials_iridescence",
    "KHR_materials_pbrSpecularGlossiness", "KHR_materials_sheen", "KHR_materials_specular",
    "KHR_materials_transmission", "KHR_materials_unlit", "KHR_materials_variants", "KHR_materials_volume",
    "KHR_lights_punctual",
)


def _refuse_gltf_1(gltf: dict, name: str) -> None:
    """InputFormatError naming a glTF 1.0 document as one (its ``asset.version`` says 1.x, or, as 1.0 files
    written without ``asset`` have it, its collections are objects keyed by id), not by the first member
    whose glTF 2.0 type it lacks ("accessors must be an array, got dict")."""
    asset = gltf.get("asset")
    version = asset.get("version") if isinstance(asset, dict) else None
    keyed = next((key for key in _ARRAYS if isinstance(gltf.get(key), dict)), None)
    major = str(version).split(".")[0] if isinstance(version, (str, int, float)) and version is not True else None
    if major == "1" or (version is None and keyed):  # 1.0 files wrote the version as a string or a number
        why = f"asset.version {version!r}" if major == "1" else f"its {keyed} keyed by id"
        raise InputFormatError(f"{name}: a glTF 1.0 document ({why}); {GLTF_1_ADVICE}")


def check_document(gltf: dict, name: str) -> None:
    """Refuse (InputFormatError) a glTF JSON the document code cannot walk safely.

    Checks the nesting depth (:data:`~pmwm_codec.constants.MAX_JSON_DEPTH`), that no number is NaN or
    infinite (Python's JSON reader takes ``NaN``, ``Infinity`` and ``1e999``; JSON, and
    so the output, does not), that every array and object
    this module reads has the right JSON type (and every ``name`` of theirs a string), that every index reference the
    output keeps (scene, scene and child nodes, a node's mesh / skin / camera, a
    primitive's accessors and material, textures' images and samplers, materials'
    textures, skins' joints, animations' samplers, accessors and target nodes,
    bufferViews) is an index in range, that an accessor's ``normalized`` is a
    boolean, true only where glTF allows it (never on indices), that a primitive's
    indices are an unsigned integer SCALAR accessor and an animation's keyframe times a
    FLOAT SCALAR one, that skins and animations are what glTF allows (:func:`_check_skins`,
    :func:`_check_channels`: what the Khronos validator calls errors, from the JSON alone), that every required
    extension is used and supported (:data:`READ_EXTENSIONS`,
    :data:`CARRIED_EXTENSIONS`), and that the triangle primitives
    declare no more vertices and faces in total than the encoder takes
    (:data:`MAX_ENCODE_VERTICES`, :data:`MAX_ENCODE_FACES`) — all before any
    buffer is read or any array allocated.  Members glTF types ``integer`` that hold an integral
    float are made ints first, in place (:func:`~.gltf.gltf_integers`).
    """
    check_json_depth(gltf, name, error=InputFormatError)
    _refuse_gltf_1(gltf, name)
    check_finite_numbers(gltf, name, InputFormatError)
    gltf_integers(gltf)  # "count": 3.0 is the integer 3 (JSON does not tell them apart), in place
    for key in _ARRAYS:
        for i, item in enumerate(_objects(gltf, key, key, name)):
            # copied into the output: a name three.js' GLTFLoader cannot sanitize (name.replace) fails its load
            if "name" in item and not isinstance(item["name"], str):
                raise InputFormatError(f"{name}: {key}[{i}].name must be a string, got {shown_value(item['name'])}")
    for key in ("extensionsUsed", "extensionsRequired"):
        if not all(isinstance(e, str) for e in _list(gltf, key, key, name)):
            raise InputFormatError(f"{name}: {key} must be an array of strings")
    _check_required_extensions(gltf, name)
    n_acc, n_views = len(gltf.get("accessors", [])), len(gltf.get("bufferViews", []))
    for i, view in enumerate(gltf.get("bufferViews", [])):
        _check_view(view, f"bufferViews[{i}]", len(gltf.get("buffers", [])), name)
    for i, acc in enumerate(gltf.get("accessors", [])):
        _check_accessor(acc, f"accessors[{i}]", n_views, name)
    for kind in ("images", "buffers"):
        for i, entry in enumerate(gltf.get(kind, [])):
            if "uri" in entry and not isinstance(entry["uri"], str):
                raise InputFormatError(f"{name}: {kind}[{i}].uri must be a string")
    count = {key: len(gltf.get(key, [])) for key in _ARRAYS}
    for i, image in enumerate(gltf.get("images", [])):
        _ref(image, "bufferView", n_views, f"images[{i}]", name, "bufferView")
        if "mimeType" in image and not isinstance(image["mimeType"], str):
            raise InputFormatError(f"{name}: images[{i}].mimeType must be a string, got {shown_value(image['mimeType'])}")
    for i, texture in enumerate(gltf.get("textures", [])):
        _check_texture(texture, f"textures[{i}]", count, name)
    for i, material in enumerate(gltf.get("materials", [])):
        _check_material(material, f"materials[{i}]", count["textures"], name)
    for i, skin in enumerate(gltf.get("skins", [])):
        _ref(skin, "inverseBindMatrices", n_acc, f"skins[{i}]", name, "accessor")
        _refs(skin, "joints", count["nodes"], f"skins[{i}]", name, "node")
        _ref(skin, "skeleton", count["nodes"], f"skins[{i}]", name, "node")
    for i, anim in enumerate(gltf.get("animations", [])):
        _check_animation(anim, f"animations[{i}]", gltf.get("accessors", []), count["nodes"], name)
    for i, node in enumerate(gltf.get("nodes", [])):
        _check_node_transform(node, f"nodes[{i}]", name)
        _check_extensions(node, f"nodes[{i}]", n_acc, name, "EXT_mesh_gpu_instancing")
        for key, kind in (("mesh", "meshes"), ("skin", "skins"), ("camera", "cameras")):
            _ref(node, key, count[kind], f"nodes[{i}]", name, key)
    parent = _check_node_trees(gltf.get("nodes", []), name)
    _ref(gltf, "scene", count["scenes"], "", name, "scene")
    for i, scene in enumerate(gltf.get("scenes", [])):
        _refs(scene, "nodes", count["nodes"], f"scenes[{i}]", name, "node")
        _check_scene_roots(scene.get("nodes", []), parent, f"scenes[{i}].nodes", name)
    _check_meshes(gltf, n_acc, n_views, name)
    _check_carried_refs(gltf, count["materials"], name)
    _check_skins(gltf, parent, name)
    for i, anim in enumerate(gltf.get("animations", [])):
        _check_channels(gltf, anim, f"animations[{i}]", name)


def _check_carried_refs(gltf: dict, n_materials: int, name: str) -> None:
    """The indices of carried extensions the output keeps as they are: a node's ``KHR_lights_punctual``
    light (into the document's ``lights``) and a primitive's ``KHR_materials_variants`` mappings (a
    material, and variants of the document's ``variants``)."""
    root = _object(gltf.get("extensions", {}), "extensions", name)
    lights = _objects(_object(root.get("KHR_lights_punctual", {}), "extensions.KHR_lights_punctual", name),
                      "lights", "extensions.KHR_lights_punctual.lights", name)
    variants = _objects(_object(root.get("KHR_materials_variants", {}), "extensions.KHR_materials_variants", name),
                        "variants", "extensions.KHR_materials_variants.variants", name)
    for i, node in enumerate(gltf.get("nodes", [])):
        punctual = _object(node.get("extensions", {}), f"nodes[{i}].extensions", name).get("KHR_lights_punctual")
        if punctual is not None:
            at = f"nodes[{i}].extensions.KHR_lights_punctual"
            _ref(_object(punctual, at, name), "light", len(lights), at, name, "light", required=True)
    for mi, mesh in enumerate(gltf.get("meshes", [])):
        for pi, prim in enumerate(mesh.get("primitives", [])):
            where = f"meshes[{mi}].primitives[{pi}].extensions"
            entry = _object(prim.get("extensions", {}), where, name).get("KHR_materials_variants")
            if entry is None:
                continue
            at = f"{where}.KHR_materials_variants"
            for j, mapping in enumerate(_objects(_object(entry, at, name), "mappings", f"{at}.mappings", name)):
                _ref(mapping, "material", n_materials, f"{at}.mappings[{j}]", name, "material", required=True)
                _refs(mapping, "variants", len(variants), f"{at}.mappings[{j}]", name, "variant")


def _check_required_extensions(gltf: dict, name: str) -> None:
    """Refuse an extension in ``extensionsRequired`` that ``extensionsUsed`` does not list (invalid glTF,
    and an output that would say so), or that the reader neither implements nor carries unchanged
    (:data:`READ_EXTENSIONS`, :data:`CARRIED_EXTENSIONS`): what it changes would be read wrong."""
    used = gltf.get("extensionsUsed", [])
    for ext in gltf.get("extensionsRequired", []):
        if ext not in used:
            raise InputFormatError(f"{name}: extensionsRequired lists {ext}, which extensionsUsed does not "
                                   "(glTF lists every required extension as used)")
        if ext not in READ_EXTENSIONS and ext not in CARRIED_EXTENSIONS:
            raise InputFormatError(f"{name}: the asset requires the glTF extension {ext}, which pmw does not "
                                   "support")


def _check_texture(texture: dict, where: str, count: dict, name: str) -> None:
    """A texture's ``source`` (also the ``source`` of an extension object: KHR_texture_basisu,
    EXT_texture_webp, EXT_texture_avif, MSFT_texture_dds) and ``sampler`` in range."""
    _ref(texture, "source", count["images"], where, name, "image")
    _ref(texture, "sampler", count["samplers"], where, name, "sampler")
    for ext, entry in _object(texture.get("extensions", {}), f"{where}.extensions", name).items():
        if isinstance(entry, dict) and "source" in entry:
            _ref(entry, "source", count["images"], f"{where}.extensions.{ext}", name, "image")


#: The textureInfo members of a material: ``(member holding them or None for the material, names)``.
_MATERIAL_TEXTURES = (("pbrMetallicRoughness", ("baseColorTexture", "metallicRoughnessTexture")),
                      (None, ("normalTexture", "occlusionTexture", "emissiveTexture")))


def _check_material(material: dict, where: str, n_textures: int, name: str) -> None:
    """A material's textureInfo objects (:func:`texture_infos`), each with a texture ``index`` in range."""
    _check_material_values(material, where, name)
    for path, info in texture_infos(material, where, name):
        _ref(info, "index", n_textures, path, name, "texture", required=True)


def texture_infos(material: dict, where: str = "material", name: str = "glTF"):
    """``(JSON path, textureInfo dict)`` of each texture a material reads: the core ones, and in its extensions
    every object with an ``index`` under a member whose name ends in ``Texture`` (``clearcoatTexture``,
    ``sheenColorTexture`` ...: the rule decode renumbers them by); InputFormatError for a member that is not an
    object."""
    for member, keys in _MATERIAL_TEXTURES:
        at = f"{where}.{member}" if member else where
        holder = _object(material.get(member, {}), at, name) if member else material
        for key in keys:
            if key in holder:
                yield f"{at}.{key}", _object(holder[key], f"{at}.{key}", name)
    stack = [(_object(material.get("extensions", {}), f"{where}.extensions", name), f"{where}.extensions")]
    while stack:  # the JSON depth is bounded already
        value, at = stack.pop()
        children = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
        for key, child in children:
            path = f"{at}[{key}]" if isinstance(key, int) else f"{at}.{key}"
            if isinstance(key, str) and key.endswith("Texture") and isinstance(child, dict) and "index" in child:
                yield path, child
            if key != "extras":
                stack.append((child, path))


def texture_scales(gltf: dict, prim: dict) -> dict:
    """``{"TEXCOORD_n": s}``: how many times over (s > 1) a texture the primitive's materials (its ``material``
    and those its KHR_materials_variants mappings name) read with TEXCOORD_n repeats per unit of those
    coordinates, by a KHR_texture_transform ``scale`` (the largest component's size; the transform's own
    ``texCoord`` picks the set, as the extension says). A texture coordinate's error shows that many times
    larger in the texture. Coordinate sets no transform scales up are left out (1). The document is checked."""
    materials = [prim["material"]] if "material" in prim else []
    variants = (prim.get("extensions") or {}).get("KHR_materials_variants") or {}
    materials += [m["material"] for m in variants.get("mappings", []) if "material" in m]
    scales = {}
    for index in materials:
        for _, info in texture_infos(gltf["materials"][index]):
            transform = (info.get("extensions") or {}).get("KHR_texture_transform")
            if not isinstance(transform, dict):
                continue
            given = transform.get("scale")
            scale = max((abs(float(x)) for x in (given if isinstance(given, list) else ())
                         if isinstance(x, (int, float)) and np.isfinite(x)), default=1.0)
            semantic = f"TEXCOORD_{transform.get('texCoord', info.get('texCoord', 0))}"
            if scale > scales.get(semantic, 1.0):
                scales[semantic] = scale
    return scales


def _check_animation(anim: dict, where: str, accessors: list, n_nodes: int, name: str) -> None:
    """An animation's samplers (``input`` / ``output`` accessors; an ``input``, the keyframe times, a
    FLOAT SCALAR accessor) and channels (a ``sampler`` of this animation, a ``target`` object whose
    ``node``, if any, exists)."""
    samplers = _objects(anim, "samplers", f"{where}.samplers", name)
    for j, sampler in enumerate(samplers):
        for key in ("input", "output"):
            _ref(sampler, key, len(accessors), f"{where}.samplers[{j}]", name, "accessor", required=True)
        times = accessors[sampler["input"]]
        if (times["type"], times["componentType"]) != ("SCALAR", FLOAT):
            raise InputFormatError(f"{name}: {where}.samplers[{j}].input: accessor {sampler['input']} is {_kind(times)}; "
                                   "keyframe times are a FLOAT SCALAR")
    for j, channel in enumerate(_objects(anim, "channels", f"{where}.channels", name)):
        at = f"{where}.channels[{j}]"
        _ref(channel, "sampler", len(samplers), at, name, "sampler", required=True)
        _ref(_object(channel.get("target"), f"{at}.target", name), "node", n_nodes, f"{at}.target", name, "node")


#: The accessor formats glTF 2.0 (5.6 animation sampler) allows an animation's output for each target path:
#: ``path -> (type, FLOAT or the integer componentTypes allowed normalized)``.
_OUTPUT_TYPES = {"translation": ("VEC3", ()), "scale": ("VEC3", ()), "rotation": ("VEC4", tuple(NORMALIZE_DIVISORS)),
                 "weights": ("SCALAR", tuple(NORMALIZE_DIVISORS))}


def _check_channels(gltf: dict, anim: dict, where: str, name: str) -> None:
    """What an animation's channels ask of their samplers and target nodes (glTF 2.0, 3.11 and 5.5-5.6; the
    Khronos validator's errors): keyframe times with ``min`` / ``max``; an output of the format its path takes
    (:data:`_OUTPUT_TYPES`) holding one value per keyframe -- three (in-tangent, value, out-tangent) for
    CUBICSPLINE, which needs two keyframes, times the morph targets for ``weights``; no ``byteStride`` on their
    bufferViews; a ``weights`` target whose mesh has morph targets, a TRS target without a ``matrix``, and no
    two channels of the animation on one target; at least one channel and one sampler.  Indices and types are checked already
    (:func:`_check_animation`, :func:`_check_meshes`)."""
    accessors, nodes, meshes = gltf.get("accessors", []), gltf.get("nodes", []), gltf.get("meshes", [])
    samplers, seen = anim.get("samplers", []), {}
    for key in ("samplers", "channels"):
        if not anim.get(key):
            raise InputFormatError(f"{name}: {where}.{key} is empty; a glTF animation has at least one")
    for j, sampler in enumerate(samplers):
        at = f"{where}.samplers[{j}]"
        times = accessors[sampler["input"]]
        if "min" not in times or "max" not in times:
            raise InputFormatError(f"{name}: {at}.input: accessor {sampler['input']} has no min / max; glTF "
                                   "declares the bounds of keyframe times")
        if sampler.get("interpolation") == "CUBICSPLINE" and times["count"] < 2:
            raise InputFormatError(f"{name}: {at}: a CUBICSPLINE sampler with {times['count']} keyframe; it "
                                   "needs at least 2")
        for key in ("input", "output"):
            if _view_stride(gltf, accessors[sampler[key]]) is not None:
                raise InputFormatError(f"{name}: {at}.{key}: accessor {sampler[key]}'s bufferView has a "
                                       "byteStride; glTF animation data is tightly packed")
    for j, channel in enumerate(anim.get("channels", [])):
        at, target = f"{where}.channels[{j}]", channel["target"]
        path, node = target.get("path"), target.get("node")
        if node is None or not isinstance(path, str) or path not in _OUTPUT_TYPES:  # another path: a warning
            continue
        if (node, path) in seen:
            raise InputFormatError(f"{name}: {at} animates the {path} of nodes[{node}], as {where}.channels"
                                   f"[{seen[node, path]}] does; glTF gives each target one channel")
        seen[node, path] = j
        sampler = samplers[channel["sampler"]]
        if path == "weights":
            mesh = meshes[nodes[node]["mesh"]] if "mesh" in nodes[node] else None
            targets = len(mesh["primitives"][0].get("targets", [])) if mesh else 0
            if not targets:
                raise InputFormatError(f"{name}: {at} animates the morph weights of nodes[{node}], which draws "
                                       "no mesh with morph targets")
        elif "matrix" in nodes[node]:
            raise InputFormatError(f"{name}: {at} animates the {path} of nodes[{node}], which has a matrix; "
                                   "glTF animates only translation / rotation / scale nodes")
        out = accessors[sampler["output"]]
        kind, integers = _OUTPUT_TYPES[path]
        if out["type"] != kind or (out["componentType"] != FLOAT and (out["componentType"] not in integers
                                                                       or out.get("normalized") is not True)):
            allowed = f"a FLOAT {kind}" + (" or a normalized integer one" if integers else "")
            raise InputFormatError(f"{name}: {at}: its sampler's output, accessor {sampler['output']}, is "
                                   f"{_kind(out)}{' (normalized)' if out.get('normalized') else ''}; "
                                   f"glTF's {path} is {allowed}")
        per_key = (3 if sampler.get("interpolation") == "CUBICSPLINE" else 1) * (targets if path == "weights" else 1)
        keys = accessors[sampler["input"]]["count"]
        if out["count"] != keys * per_key:
            each = f" x {per_key} values" if per_key > 1 else ""
            raise InputFormatError(f"{name}: {at}: its sampler's output, accessor {sampler['output']}, holds "
                                   f"{out['count']} values for {keys} keyframes{each}; glTF needs "
                                   f"{keys * per_key}")


#: How far from 1 the length of a rotation keyframe's quaternion may be (the Khronos validator's bound for
#: ACCESSOR_ANIMATION_SAMPLER_OUTPUT_NON_NORMALIZED_QUATERNION).
QUATERNION_LENGTH_TOLERANCE = 0.00769


def check_animation_data(gltf: dict, buffers, name: str) -> None:
    """Refuse (InputFormatError naming the sampler) animation data the Khronos validator calls errors (glTF
    2.0, 5.6): keyframe times that are negative or do not strictly increase (ACCESSOR_ANIMATION_INPUT_NEGATIVE /
    _NON_INCREASING), and a rotation keyframe whose quaternion is not of unit length within
    :data:`QUATERNION_LENGTH_TOLERANCE` (a CUBICSPLINE's values; its tangents are free).  Reads the data of a
    loaded document (buffers read, meshopt decoded), each accessor once (:func:`read_accessor`: (count, 1)
    float64 times, (count, 4) float64 quaternions, normalized integers mapped to [-1, 1]).  The rest of an
    animation is checked from the JSON (:func:`_check_channels`)."""
    seen = set()
    for i, anim in enumerate(gltf.get("animations", [])):
        samplers = anim.get("samplers", [])
        for j, sampler in enumerate(samplers):
            index = sampler["input"]
            if index in seen:
                continue
            seen.add(index)
            times = read_accessor(gltf, buffers, index)[:, 0]
            at = f"{name}: animations[{i}].samplers[{j}].input (accessor {index})"
            if len(times) and times.min() < 0:
                k = int(np.argmax(times < 0))
                raise InputFormatError(f"{at}: keyframe {k} is at {times[k]:g} s; glTF keyframe times are not "
                                       "negative")
            later = np.diff(times) <= 0
            if later.any():
                k = int(np.argmax(later)) + 1
                raise InputFormatError(f"{at}: keyframe {k} at {times[k]:g} s is not after keyframe {k - 1} at "
                                       f"{times[k - 1]:g} s; glTF keyframe times strictly increase")
        for channel in anim.get("channels", []):
            j = channel["sampler"]
            if channel["target"].get("path") != "rotation" or ("rotation", i, j) in seen:
                continue
            seen.add(("rotation", i, j))
            quats = read_accessor(gltf, buffers, samplers[j]["output"])
            if samplers[j].get("interpolation") == "CUBICSPLINE":
                quats = quats[1::3]  # in-tangent, value, out-tangent per keyframe
            off = np.abs(np.linalg.norm(quats, axis=1) - 1) > QUATERNION_LENGTH_TOLERANCE
            if off.any():
                k = int(np.argmax(off))
                raise InputFormatError(f"{name}: animations[{i}].samplers[{j}].output (accessor "
                                       f"{samplers[j]['output']}): the rotation of keyframe {k} is of length "
                                       f"{np.linalg.norm(quats[k]):.4g}; glTF rotations are unit quaternions")


def check_rig_data(gltf: dict, buffers, name: str) -> None:
    """Refuse animation and skin data the Khronos validator calls errors (:func:`check_animation_data`,
    :func:`check_skin_weights`): what :func:`check_document` cannot see in the JSON, read from the buffers."""
    check_animation_data(gltf, buffers, name)
    check_skin_weights(gltf, buffers, name)


def check_skin_weights(gltf: dict, buffers, name: str) -> None:
    """Refuse (InputFormatError naming the primitive, the attribute and the vertex) skin data the Khronos validator
    calls errors (glTF 2.0, 3.7.3.3), in each primitive a skinned node draws: a joint index past the skin's joints
    (ACCESSOR_JOINTS_INDEX_OOB; three.js fails to load such an asset), a joint named twice with non-zero weights
    (_DUPLICATE), a negative weight (ACCESSOR_WEIGHTS_NEGATIVE), and a vertex whose weights over all its sets do
    not sum to 1 (_NON_NORMALIZED: the validator's sum, float32 in its order, within 2e-7 a non-zero weight).
    Reads the JOINTS_n / WEIGHTS_n accessors of a loaded document (:func:`read_accessor`: int64 joints, float64
    weights, normalized integers mapped to [0, 1]); their types and pairing are checked already
    (:func:`check_document`).  A mesh two skins draw is held to the one of fewer joints."""
    nodes, skins, meshes = gltf.get("nodes", []), gltf.get("skins", []), gltf.get("meshes", [])
    skinned = {}  # mesh -> (joint count, the node whose skin has it)
    for i, node in enumerate(nodes):
        if "skin" in node and "mesh" in node:
            count = len(skins[node["skin"]].get("joints", []))
            if node["mesh"] not in skinned or count < skinned[node["mesh"]][0]:
                skinned[node["mesh"]] = (count, i)
    for mi, (count, ni) in sorted(skinned.items()):
        for pi, prim in enumerate(meshes[mi]["primitives"]):
            attrs = prim.get("attributes", {})
            sets = 0
            while f"JOINTS_{sets}" in attrs and f"WEIGHTS_{sets}" in attrs:
                sets += 1
            if not sets:
                continue
            # the validator's order: a vertex's component 0 of every set, then component 1 ...
            order = np.arange(4 * sets).reshape(sets, 4).T.ravel()
            joints = np.hstack([read_accessor(gltf, buffers, attrs[f"JOINTS_{k}"]) for k in range(sets)])[:, order]
            weights = np.hstack([read_accessor(gltf, buffers, attrs[f"WEIGHTS_{k}"]) for k in range(sets)])[:, order]
            at = f"{name}: meshes[{mi}].primitives[{pi}]"

            def attribute(column):  # the attribute of a column of ``order``
                return f"{at}.attributes.%s_{order[column] // 4}"

            bad = joints >= count
            if bad.any():
                v, c = np.argwhere(bad)[0]
                raise InputFormatError(f"{attribute(c) % 'JOINTS'}: vertex {v} names joint {joints[v, c]}, but the skin "
                                       f"of nodes[{ni}] has {count} joints (0..{count - 1})")
            bad = weights < 0
            if bad.any():
                v, c = np.argwhere(bad)[0]
                raise InputFormatError(f"{attribute(c) % 'WEIGHTS'}: vertex {v} has weight {weights[v, c]:.6g}; glTF "
                                       "skin weights are not negative")
            used = weights != 0
            keyed = np.where(used, joints, -1 - np.arange(4 * sets))  # unused slots never match
            ranked = np.sort(keyed, axis=1)
            bad = (ranked[:, 1:] == ranked[:, :-1]).any(axis=1)
            if bad.any():
                v = int(np.argmax(bad))
                twice = ranked[v, 1:][ranked[v, 1:] == ranked[v, :-1]][0]
                raise InputFormatError(f"{at}: vertex {v} names joint {twice} twice with non-zero weights; glTF "
                                       "gives a vertex each joint once")
            total = np.zeros(len(weights), np.float32)
            for c in range(4 * sets):
                total = (total.astype(np.float64) + weights[:, c]).astype(np.float32)
            bad = np.abs(total.astype(np.float64) - 1) > 2e-7 * used.sum(axis=1)
            if bad.any():
                v = int(np.argmax(bad))
                raise InputFormatError(f"{at}: the skin weights of vertex {v} sum to {total[v]:.7g}; glTF skin "
                                       "weights sum to 1")


def _view_stride(gltf: dict, acc: dict):
    """The ``byteStride`` of accessor ``acc``'s bufferView (checked), or None."""
    return gltf["bufferViews"][acc["bufferView"]].get("byteStride") if "bufferView" in acc else None


def _check_skins(gltf: dict, parent: dict, name: str) -> None:
    """What skins and skinned nodes ask of each other (glTF 2.0, 3.8 and 5.23; the Khronos validator's errors):
    a skin's joints are nodes, each once, at least one, under one common root, which its ``skeleton`` (if any)
    is or is above; its ``inverseBindMatrices`` a FLOAT MAT4 accessor, tightly packed, with a matrix per joint;
    a node with a skin draws a mesh, skinned (a primitive with JOINTS_0 and WEIGHTS_0), and every primitive has
    as many JOINTS_n as WEIGHTS_n.  ``parent``: :func:`_check_node_trees`' parent of every child node."""
    def above(x):  # x and its ancestors, its tree's root last
        out = [x]
        while out[-1] in parent:
            out.append(parent[out[-1]])
        return out

    def root(x):
        return above(x)[-1]

    accessors, nodes, meshes = gltf.get("accessors", []), gltf.get("nodes", []), gltf.get("meshes", [])
    for i, skin in enumerate(gltf.get("skins", [])):
        where, joints = f"skins[{i}]", skin.get("joints", [])
        if not joints:
            raise InputFormatError(f"{name}: {where}.joints is empty; a glTF skin has at least one joint")
        if len(set(joints)) != len(joints):
            twice = next(j for k, j in enumerate(joints) if j in joints[:k])
            raise InputFormatError(f"{name}: {where}.joints names nodes[{twice}] twice")
        common = set(above(joints[0]))
        for j in joints[1:]:
            common &= set(above(j))
        if not common:
            raise InputFormatError(f"{name}: {where}.joints have no common root (nodes[{joints[0]}] and "
                                   f"nodes[{next(j for j in joints if root(j) != root(joints[0]))}] are in "
                                   "different trees)")
        if "skeleton" in skin and skin["skeleton"] not in common:
            raise InputFormatError(f"{name}: {where}.skeleton = {skin['skeleton']} is not a common root of its "
                                   "joints (an ancestor of each, or the joint itself)")
        if "inverseBindMatrices" in skin:
            index = skin["inverseBindMatrices"]
            ibm = accessors[index]
            at = f"{where}.inverseBindMatrices"
            if (ibm["type"], ibm["componentType"]) != ("MAT4", FLOAT):
                raise InputFormatError(f"{name}: {at}: accessor {index} is {_kind(ibm)}; glTF's inverse bind "
                                       "matrices are a FLOAT MAT4")
            if ibm["count"] < len(joints):
                raise InputFormatError(f"{name}: {at}: accessor {index} holds {ibm['count']} matrices for "
                                       f"{len(joints)} joints; glTF gives each joint one")
            if _view_stride(gltf, ibm) is not None:
                raise InputFormatError(f"{name}: {at}: accessor {index}'s bufferView has a byteStride; glTF "
                                       "inverse bind matrices are tightly packed")
    scene_roots = [set(scene.get("nodes", [])) for scene in gltf.get("scenes", [])]
    for i, node in enumerate(nodes):
        if "skin" not in node:
            continue
        if "mesh" not in node:
            raise InputFormatError(f"{name}: nodes[{i}] has a skin but no mesh to skin")
        prims = meshes[node["mesh"]]["primitives"]
        if not any("JOINTS_0" in p.get("attributes", {}) and "WEIGHTS_0" in p.get("attributes", {}) for p in prims):
            raise InputFormatError(f"{name}: nodes[{i}] has a skin but its mesh {node['mesh']} has no JOINTS_0 and "
                                   "WEIGHTS_0 to skin it by")
        joint_root = root(gltf["skins"][node["skin"]]["joints"][0])
        for s, roots in enumerate(scene_roots):
            if root(i) in roots and joint_root not in roots:
                raise InputFormatError(f"{name}: scenes[{s}] shows nodes[{i}], skinned, but not the joints of its "
                                       f"skin {node['skin']}")
    for mi, mesh in enumerate(meshes):
        for pi, prim in enumerate(mesh["primitives"]):
            sets = {kind: sum(1 for k in prim.get("attributes", {}) if re.fullmatch(kind + r"_\d+", k))
                    for kind in ("JOINTS", "WEIGHTS")}
            if sets["JOINTS"] != sets["WEIGHTS"]:
                raise InputFormatError(f"{name}: meshes[{mi}].primitives[{pi}] has {sets['JOINTS']} JOINTS_n and "
                                       f"{sets['WEIGHTS']} WEIGHTS_n attributes; glTF pairs them")


def _check_scene_roots(roots: list, parent: dict, where: str, name: str) -> None:
    """Refuse a scene whose root nodes repeat or include a node's child (glTF 2.0, 3.5.2: each root is
    named once and is the root of its tree): its meshes would be shown twice, or once, as readers differ."""
    seen = set()
    for j, node in enumerate(roots):
        if node in seen:
            raise InputFormatError(f"{name}: {where}[{j}] names nodes[{node}] again; a scene names each root once")
        if node in parent:
            raise InputFormatError(f"{name}: {where}[{j}] names nodes[{node}], a child of nodes[{parent[node]}]; "
                                   "a scene names only root nodes")
        seen.add(node)


def _check_node_trees(nodes: list, name: str) -> dict:
    """Refuse a node hierarchy that is not disjoint strict trees (glTF 2.0, 3.5.1): a child index out of
    range, a node with two parents (its meshes would be shown twice, or once, as readers differ), a node
    that is its own ancestor.  Returns the parent of every child node."""
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
    return parent


def _check_view(view: dict, where: str, n_buffers: int, name: str) -> None:
    """A bufferView's numbers: ``buffer`` in range, ``byteOffset`` / ``byteLength``
    non-negative integers, ``byteStride`` (if any) a multiple of 4 in 4..252."""
    _ref(view, "buffer", n_buffers, where, name, "buffer", required=True)
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
    if named(acc.get("componentType"), COMPONENT_DTYPES) is None or named(acc.get("type"), TYPE_WIDTH) is None:
        raise InputFormatError(f"{name}: {where} has an unknown componentType or type")
    count = _bounded_count(acc, "count", f"{name}: {where}")
    if count < 1:
        raise InputFormatError(f"{name}: {where}.count must be at least 1")
    uint(acc, "byteOffset", f"{name}: {where}", 0, error=InputFormatError)
    _ref(acc, "bufferView", n_views, where, name, "bufferView")
    _normalized_flag(acc, f"{name}: {where}")
    if "sparse" in acc:
        sparse = _object(acc["sparse"], f"{where}.sparse", name)
        if _bounded_count(sparse, "count", f"{name}: {where}.sparse") > count:
            raise InputFormatError(f"{name}: {where}.sparse.count is larger than the accessor's count {count}")
        for part in ("indices", "values"):
            _ref(_object(sparse.get(part), f"{where}.sparse.{part}", name), "bufferView", n_views,
                 f"{where}.sparse.{part}", name, "bufferView", required=True)


def _check_indices_accessor(acc: dict, where: str, index: int, name: str) -> None:
    """A primitive's ``indices`` accessor ``acc`` (accessor ``index``): an UNSIGNED_BYTE, UNSIGNED_SHORT or
    UNSIGNED_INT SCALAR, never normalized (glTF 2.0, 3.7.2.1)."""
    if acc.get("normalized") is True:
        raise InputFormatError(f"{name}: {where}: accessor {index} is normalized; glTF indices never are")
    if acc["type"] != "SCALAR" or acc["componentType"] not in INDEX_DTYPES:
        raise InputFormatError(f"{name}: {where}: accessor {index} is {_kind(acc)}; glTF indices are an UNSIGNED_BYTE, "
                               "UNSIGNED_SHORT or UNSIGNED_INT SCALAR")


def _kind(acc: dict) -> str:
    """An accessor's element kind for a message, e.g. ``"a VEC3 of FLOAT (5126)"`` (its type and
    componentType known: :func:`_check_accessor`)."""
    ctype = acc["componentType"]
    return f"a {acc['type']} of {COMPONENT_NAMES[ctype]} ({ctype})"


#: The accessor types glTF 2.0 (3.7.2.1) allows a vertex attribute of each semantic (the name without
#: its ``_n`` set index), and in a morph target (3.7.2.2).
ATTRIBUTE_TYPES = {"POSITION": ("VEC3",), "NORMAL": ("VEC3",), "TANGENT": ("VEC4",), "TEXCOORD": ("VEC2",),
                   "COLOR": ("VEC3", "VEC4"), "JOINTS": ("VEC4",), "WEIGHTS": ("VEC4",)}
TARGET_TYPES = {"POSITION": ("VEC3",), "NORMAL": ("VEC3",), "TANGENT": ("VEC3",), "TEXCOORD": ("VEC2",),
                "COLOR": ("VEC3", "VEC4")}
#: bufferView targets (glTF 2.0, 5.11): vertex data, indices.
ARRAY_BUFFER_TARGET, ELEMENT_ARRAY_BUFFER = 34962, 34963


def _check_attribute(acc: dict, semantic: str, target: bool, where: str, views: list, name: str) -> None:
    """A vertex attribute's accessor ``acc``: of the type glTF gives its semantic (``NORMAL`` a VEC3 ...;
    custom ``_NAME`` semantics any), in a bufferView not marked as holding indices."""
    base = semantic.split("_")[0] if semantic[:1] != "_" else ""
    allowed = (TARGET_TYPES if target else ATTRIBUTE_TYPES).get(base if base in ("TEXCOORD", "COLOR", "JOINTS", "WEIGHTS")
                                                                 else semantic)
    if allowed is not None and acc["type"] not in allowed:
        raise InputFormatError(f"{name}: {where}: accessor is {_kind(acc)}; glTF's {semantic} is "
                               + " or ".join(allowed))
    _check_view_target(acc, ARRAY_BUFFER_TARGET, where, views, name)


def _check_view_target(acc: dict, expected: int, where: str, views: list, name: str) -> None:
    """Refuse an accessor whose bufferView declares the other ``target`` (vertex data in a view marked for
    indices, or indices in one marked for vertex data): the output would say the same, invalid glTF."""
    view = acc.get("bufferView")
    target = views[view].get("target") if isinstance(view, int) and 0 <= view < len(views) else None
    if target is not None and target != expected:
        what = "indices" if expected == ELEMENT_ARRAY_BUFFER else "vertex data"
        raise InputFormatError(f"{name}: {where}: bufferViews[{view}].target is {target}, but it holds {what} "
                               f"({expected})")


def _check_node_transform(node: dict, where: str, name: str) -> None:
    """A node's transform: ``matrix`` 16 numbers, or any of ``translation`` (3), ``rotation`` (4, a
    quaternion), ``scale`` (3) -- not both (glTF 2.0, 5.25)."""
    for key, size in (("matrix", 16), ("translation", 3), ("rotation", 4), ("scale", 3)):
        _numbers(node, key, size, where, name)
    if "matrix" in node and any(key in node for key in ("translation", "rotation", "scale")):
        raise InputFormatError(f"{name}: {where} has a matrix and translation / rotation / scale; glTF allows one "
                               "or the other")


def _numbers(holder: dict, key: str, size: int | None, where: str, name: str) -> None:
    """Refuse ``holder[key]`` (when there) unless it is ``size`` numbers, or one number for ``size`` None."""
    if key not in holder:
        return
    value = holder[key]
    values = value if size is not None and isinstance(value, list) else [value] if size is None else None
    if values is None or len(values) != (size or 1) \
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in values):
        what = "a number" if size is None else f"{size} numbers"
        raise InputFormatError(f"{name}: {where}.{key} must be {what}, got {shown_value(value)}")


def _check_material_values(material: dict, where: str, name: str) -> None:
    """A material's factors and flags of the types glTF 2.0 (5.19) gives them (``baseColorFactor`` 4 numbers,
    ``alphaMode`` one of its three names ...): a ``.pmw`` carries the material as it is, and one a viewer cannot
    take (``"baseColorFactor": "red"``) made a file the glTF validator refuses, read by three.js as NaN colours."""
    pbr = material.get("pbrMetallicRoughness", {})
    if isinstance(pbr, dict):
        _numbers(pbr, "baseColorFactor", 4, f"{where}.pbrMetallicRoughness", name)
        for key in ("metallicFactor", "roughnessFactor"):
            _numbers(pbr, key, None, f"{where}.pbrMetallicRoughness", name)
    _numbers(material, "emissiveFactor", 3, where, name)
    _numbers(material, "alphaCutoff", None, where, name)
    for key, factor in (("normalTexture", "scale"), ("occlusionTexture", "strength")):
        if isinstance(material.get(key), dict):
            _numbers(material[key], factor, None, f"{where}.{key}", name)
    if "alphaMode" in material and material["alphaMode"] not in ("OPAQUE", "MASK", "BLEND"):
        raise InputFormatError(f"{name}: {where}.alphaMode must be OPAQUE, MASK or BLEND, got "
                               f"{shown_value(material['alphaMode'])}")
    if "doubleSided" in material and not isinstance(material["doubleSided"], bool):
        raise InputFormatError(f"{name}: {where}.doubleSided must be true or false, got "
                               f"{shown_value(material['doubleSided'])}")


def _check_meshes(gltf: dict, n_acc: int, n_views: int, name: str) -> None:
    vertices = faces = 0
    accessors, n_materials = gltf.get("accessors", []), len(gltf.get("materials", []))
    views = gltf.get("bufferViews", [])
    for mi, mesh in enumerate(gltf.get("meshes", [])):
        primitives = _objects(mesh, "primitives", f"meshes[{mi}].primitives", name)
        if not primitives:
            raise InputFormatError(f"{name}: meshes[{mi}] has no primitives (glTF: at least one)")
        for pi, prim in enumerate(primitives):
            where = f"meshes[{mi}].primitives[{pi}]"
            attrs = _object(prim.get("attributes", {}), f"{where}.attributes", name)
            for semantic in attrs:
                _ref(attrs, semantic, n_acc, f"{where}.attributes", name, "accessor")
                _check_attribute(accessors[attrs[semantic]], semantic, False, f"{where}.attributes.{semantic}",
                                 views, name)
            targets = _objects(prim, "targets", f"{where}.targets", name)
            for ti, target in enumerate(targets):
                for semantic in target:
                    _ref(target, semantic, n_acc, f"{where}.targets[{ti}]", name, "accessor")
                    _check_attribute(accessors[target[semantic]], semantic, True,
                                     f"{where}.targets[{ti}].{semantic}", views, name)
            weights = mesh.get("weights")
            if weights is not None and (not isinstance(weights, list) or len(weights) != len(targets)):
                raise InputFormatError(f"{name}: meshes[{mi}].weights must hold one number per morph target of "
                                       f"its primitives ({len(targets)}), got {shown_value(weights)}")
            _ref(prim, "indices", n_acc, where, name, "accessor")
            if "indices" in prim:
                _check_indices_accessor(accessors[prim["indices"]], f"{where}.indices", prim["indices"], name)
                _check_view_target(accessors[prim["indices"]], ELEMENT_ARRAY_BUFFER, f"{where}.indices", views, name)
            _ref(prim, "material", n_materials, where, name, "material")
            uint(prim, "mode", f"{name}: {where}", 4, error=InputFormatError)
            draco = _check_extensions(prim, where, n_acc, name, DRACO_EXTENSION)
            if draco is not None:
                _ref(draco, "bufferView", n_views, f"{where}.extensions.{DRACO_EXTENSION}", name, "bufferView",
                     required=True)
            mode = prim.get("mode", TRIANGLES)
            if mode in TRIANGLE_MODES and "POSITION" in attrs:
                corners = _count(accessors[prim["indices"] if "indices" in prim else attrs["POSITION"]])
                vertices += _count(accessors[attrs["POSITION"]])
                faces += corners // 3 if mode == TRIANGLES else max(corners - 2, 0)
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
            _ref(attrs, semantic, n_acc, f"{where}.extensions.{known}.attributes", name, "accessor")
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


def _ref(holder: dict, key: str, bound: int, where: str, name: str, kind: str, required: bool = False) -> None:
    """``holder[key]``, when present (or ``required``), must be the index of one of the ``bound`` items
    it refers to, each a ``kind`` ("accessor", "node" ...); ``where`` is the JSON path of ``holder``
    ("" for the document), which the error names with the member:
    ``scenes[0].nodes[1] = 7 names a node that does not exist``."""
    if key in holder or required:
        _index(holder.get(key), bound, f"{where}.{key}" if where else key, name, kind)


def _refs(holder: dict, key: str, bound: int, where: str, name: str, kind: str) -> None:
    """``holder[key]`` (default []) must be an array of indices of ``kind`` items, as :func:`_ref`."""
    for j, value in enumerate(_list(holder, key, f"{where}.{key}", name)):
        _index(value, bound, f"{where}.{key}[{j}]", name, kind)


def _index(value, bound: int, path: str, name: str, kind: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise InputFormatError(f"{name}: {path} must be {_a(kind)} index (a non-negative integer), got {shown_value(value)}")
    if value >= bound:
        raise InputFormatError(f"{name}: {path} = {value} names {_a(kind)} that does not exist "
                               f"(the document has {bound or 'none'})")


def _a(word: str) -> str:
    return ("an " if word[0] in "aeiou" else "a ") + word


def _normalized_flag(acc: dict, where: str) -> bool:
    """An accessor's ``normalized`` (default false): a JSON boolean, true only on the componentTypes glTF
    normalizes (BYTE, UNSIGNED_BYTE, SHORT, UNSIGNED_SHORT); ``where`` names the accessor."""
    value = acc.get("normalized", False)
    if not isinstance(value, bool):
        raise InputFormatError(f"{where}.normalized must be true or false, got {shown_value(value)}")
    ctype = acc.get("componentType")
    if value and ctype not in NORMALIZE_DIVISORS:
        raise InputFormatError(f"{where}.normalized is true on componentType {ctype!r} "
                               f"({COMPONENT_NAMES.get(ctype, 'unknown')}); glTF normalizes only BYTE, "
                               "UNSIGNED_BYTE, SHORT and UNSIGNED_SHORT")
    return value


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
    normalized = _normalized_flag(acc, f"accessors[{index}]")
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
    out = _normalized(out, ctype, normalized)
    if acc.get("sparse"):
        out = _apply_sparse(gltf, buffers, acc, out, what, normalized)
    return out


def rest_weights(gltf: dict, mi: int, targets: int) -> list:
    """The ``targets`` morph weights (floats) mesh ``mi`` of ``gltf`` is drawn with at rest, as a viewer draws it:
    its nodes' ``weights`` (each node's, else the mesh's; zeros without either); MeshError (naming the mesh) when
    its nodes give it different weights (one pose cannot stand for them: decode holds such a mesh as stored) or a list of another length than its
    targets."""
    if not targets:
        return []
    mesh = gltf["meshes"][mi]
    own = mesh.get("weights") or [0.0] * targets
    found = {tuple(node.get("weights", own)) for node in gltf.get("nodes", [])
             if isinstance(node, dict) and node.get("mesh") == mi} or {tuple(own)}
    if len(found) > 1:
        raise MeshError(f"mesh {mi} is drawn with different morph weights by its nodes, which the geometry "
                        "reader does not pose node by node")
    weights = list(found.pop())
    if len(weights) != targets or not all(isinstance(w, (int, float)) and not isinstance(w, bool) for w in weights):
        raise MeshError(f"mesh {mi}'s morph weights {weights!r:.60} are not one number per target ({targets})")
    return [float(w) for w in weights]


def shown_weights(gltf: dict, mi: int, prim: dict) -> list | None:
    """The weights a decoded OBJ / PLY / STL / OFF poses the primitive ``prim`` of mesh ``mi`` of a checked
    document with: :func:`rest_weights` of its targets ([] without any), None when the mesh's nodes draw it with
    different weights (it is held as stored then)."""
    try:
        return rest_weights(gltf, mi, len(prim.get("targets", [])))
    except MeshError:
        return None


def morphed(gltf: dict, buffers, prim: dict, semantic: str, values: np.ndarray, weights) -> np.ndarray:
    """(n, k) float64: ``values`` (n, k), the primitive ``prim``'s ``semantic`` attribute, plus each morph
    target's displacement of it times its weight (glTF 2.0 3.7.2.2; ``weights`` one per target, as
    :func:`rest_weights` gives them; a zero weight reads nothing)."""
    values = np.asarray(values, np.float64)
    for w, target in zip(weights, prim.get("targets", [])):
        if w != 0.0 and semantic in target:
            values = values + w * read_accessor(gltf, buffers, target[semantic])[:, :values.shape[1]]
    return values


def renormalized(values: np.ndarray) -> np.ndarray:
    """``values`` (n, 3 or 4), NORMAL or TANGENT values, with unit-length xyz (a tangent's w kept; a zero vector
    stays zero): a copy, of the dtype given."""
    out = values.copy()
    length = np.linalg.norm(out[:, :3], axis=1, keepdims=True)
    out[:, :3] = np.where(length > 0, out[:, :3] / np.maximum(length, 1e-30), out[:, :3])
    return out


def primitive_triangles(gltf: dict, buffers, prim: dict, what: str, weights=(), error=InputFormatError,
                        bounds: bool = True) -> tuple:
    """``(positions (n, 3) float64, faces (m, 3) int64)`` of a triangle primitive ``prim`` of a loaded document:
    its positions morphed by ``weights`` (:func:`morphed`; none: as stored), its triangles as
    :func:`triangle_faces` reads them for the encoders (strips and fans as glTF 2.0 3.7.2.1 winds them, a strip's
    restarts dropped; no indices: the vertices in order); ``error`` naming ``what`` for a TRIANGLES count that is
    not a multiple of 3 (:func:`triangle_faces`' words), InputFormatError for an index past the vertices (unless
    not ``bounds``: the caller's)."""
    positions = morphed(gltf, buffers, prim, "POSITION",
                        read_accessor(gltf, buffers, prim["attributes"]["POSITION"])[:, :3], weights)
    try:
        faces = triangle_faces(gltf, buffers, prim, len(positions))
    except MeshError as exc:
        raise error(f"{what}: {exc}") from None
    if bounds and len(faces) and (faces.min() < 0 or faces.max() >= len(positions)):
        raise InputFormatError(f"{what}: an index past its {len(positions)} vertices")
    return np.asarray(positions, np.float64), np.asarray(faces, np.int64)


def triangle_faces(gltf: dict, buffers, prim: dict, n: int) -> np.ndarray:
    """(m, 3) int64: the triangles the primitive ``prim`` of ``n`` vertices draws, as the encoders read it (its
    ``indices``, or the vertices in order; strips and fans as glTF 2.0 3.7.2.1 winds them, a strip's restarts --
    an index repeated to join two strips -- dropped: they draw nothing); MeshError for a TRIANGLES primitive
    whose index (or vertex) count is not a multiple of 3.  Indices past the vertices are the caller's."""
    from ..progressive.topology import two_alike

    order = read_accessor(gltf, buffers, prim["indices"]).reshape(-1) if "indices" in prim else np.arange(n)
    mode = prim.get("mode", TRIANGLES)
    if mode == TRIANGLES and len(order) % 3:
        raise MeshError(f"index count {len(order)} is not a multiple of 3" if "indices" in prim else
                        f"vertex count {len(order)} (no indices: every three vertices a triangle) is not a "
                        "multiple of 3")
    faces = triangle_list(order, mode)
    if mode == TRIANGLE_STRIP:
        faces = faces[~two_alike(faces)]
    return np.asarray(faces, np.int64)


def _bounded_count(holder: dict, key: str, what: str) -> int:
    count = uint(holder, key, what, error=InputFormatError)
    if count > MAX_ACCESSOR_COUNT:
        raise InputFormatError(f"{what}: {key} {count:,} is more than the limit of {MAX_ACCESSOR_COUNT:,}")
    return count


def _apply_sparse(gltf, buffers, acc, out, what, normalized):
    """``out`` (count, width) with the sparse substitution of ``acc`` applied (a copy)."""
    sparse, (count, width) = acc["sparse"], out.shape
    n = _bounded_count(sparse, "count", f"{what} sparse")
    ii, vv = sparse["indices"], sparse["values"]
    idx = _sparse_part(gltf, buffers, ii, named(ii.get("componentType"), INDEX_DTYPES), n, 1, f"{what} sparse indices")
    vals = _sparse_part(gltf, buffers, vv, COMPONENT_DTYPES[acc["componentType"]], n, width, f"{what} sparse values")
    if n and int(idx.max()) >= count:
        raise InputFormatError(f"{what}: sparse index {int(idx.max())} is past its {count} elements")
    out = out.copy()
    out[idx.reshape(-1).astype(np.int64)] = _normalized(vals, acc["componentType"], normalized)
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


def as_declared(gltf: dict, index: int, values: np.ndarray) -> np.ndarray:
    """Integer ``values`` (count, width) of accessor ``index`` decoded elsewhere (a Draco attribute's raw
    integers) as :func:`read_accessor` gives that accessor: float64 for FLOAT or normalized data (mapped to
    [0, 1] / [-1, 1] as the glTF specification says), int64 for integer data."""
    try:
        acc = gltf["accessors"][index]
        ctype = acc["componentType"]
    except (KeyError, IndexError, TypeError):
        ctype = None
    if ctype not in COMPONENT_DTYPES:
        raise InputFormatError(f"accessor {index}: malformed")
    return _normalized(values, ctype, _normalized_flag(acc, f"accessors[{index}]"))


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
            if "mimeType" not in image:  # labelled when loaded (label_images); a caller's _bytes too
                image["mimeType"] = _image_type(uri, blob, "an image")
            image["bufferView"] = first_view + len(blobs)
            blobs.append(blob)
    return blobs


def view_sites(doc: dict):
    """Yield ``(holder, key)`` for every bufferView reference ``holder[key]`` that :func:`repack` knows."""
    for _, holder, key in named_view_sites(doc):
        yield holder, key


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


#: The image formats glTF carries (PNG, JPEG) and its texture extensions' (KHR_texture_basisu: KTX2,
#: EXT_texture_webp, EXT_texture_avif, MSFT_texture_dds) as ``(offset, signature, media type)``.
IMAGE_SIGNATURES = ((0, b"\x89PNG\r\n\x1a\n", "image/png"), (0, b"\xff\xd8\xff", "image/jpeg"),
                    (0, b"\xabKTX 20\xbb\r\n\x1a\n", "image/ktx2"), (8, b"WEBP", "image/webp"),
                    (4, b"ftypavif", "image/avif"), (4, b"ftypavis", "image/avif"), (0, b"DDS ", "image/vnd-ms.dds"))


def sniff_image(blob) -> str | None:
    """The media type of an image's bytes by its signature (:data:`IMAGE_SIGNATURES`), or None."""
    head = bytes(blob[:16])
    for offset, signature, kind in IMAGE_SIGNATURES:
        if head[offset : offset + len(signature)] == signature and (kind != "image/webp" or head[:4] == b"RIFF"):
            return kind
    return None


def _image_type(uri, blob, where: str) -> str:
    """The ``mimeType`` of an image without one: the media type of its ``data:`` URI when that is an
    ``image/`` type, else its bytes' (:func:`sniff_image`); never guessed (a bufferView image must have
    one, and the wrong one makes a viewer fail): InputFormatError naming ``where`` when neither tells."""
    if isinstance(uri, str) and uri.startswith("data:"):
        declared = uri[5:].partition(",")[0].split(";")[0].strip().lower()
        if declared.startswith("image/"):
            return declared
    kind = sniff_image(blob)
    if kind is None:
        raise InputFormatError(f"{where} has no mimeType and its bytes are none of PNG, JPEG, WebP, KTX2, AVIF "
                               "or DDS; give it its mimeType")
    return kind


def label_images(gltf: dict, buffers, name: str) -> None:
    """Give a ``mimeType`` (in place) to every image of a loaded document that lacks one and that the output
    holds in a bufferView: one loaded from a ``uri`` (``_bytes``, which :func:`repack` embeds) and one in
    a bufferView already (where glTF requires it).  See :func:`_image_type`; a declared ``mimeType`` is
    kept as it is.  An in-memory document's ``data:`` URI image stays a URI, whose type is optional."""
    for i, image in enumerate(gltf.get("images", [])):
        where = f"{name}: images[{i}]"
        if "mimeType" in image:
            continue
        if "_bytes" in image:
            image["mimeType"] = _image_type(image.get("uri"), image["_bytes"], where)
        elif "bufferView" in image:
            _, raw = view_bytes(gltf, buffers, image["bufferView"], where, error=InputFormatError)
            image["mimeType"] = _image_type(None, raw, where)


#: PNG chunks that carry colour-space or pixel-aspect metadata (the Khronos validator
#: warns IMAGE_FEATURES_UNSUPPORTED on them); pixels do not depend on them.
PNG_PROFILE_CHUNKS = (b"iCCP", b"cHRM", b"gAMA", b"sRGB", b"pHYs")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def png_chunks(blob: bytes):
    """Yield ``(type, start, end)`` of each chunk of a PNG's bytes after its signature: ``start`` at its length
    field, ``end`` after its CRC -- beyond ``len(blob)`` for a chunk cut short, the last one yielded then."""
    pos = 8
    while pos + 12 <= len(blob):
        end = pos + 12 + int.from_bytes(blob[pos : pos + 4], "big")
        yield blob[pos + 4 : pos + 8], pos, end
        if end > len(blob):
            return
        pos = end


def strip_png_profile(blob: bytes) -> bytes:
    """A PNG without its colour-space / pixel-aspect chunks (same pixels); other data unchanged."""
    if blob[:8] != PNG_SIGNATURE:
        return blob
    out = [blob[:8]]
    for kind, start, end in png_chunks(blob):
        if end > len(blob):
            return blob  # damaged: leave it alone
        if kind not in PNG_PROFILE_CHUNKS:
            out.append(blob[start:end])
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
