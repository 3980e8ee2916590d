"""Mesh files that carry more than geometry, read as in-memory glTF documents.

A Wavefront OBJ with texture coordinates (``vt``), vertex colours (``v x y z r g b``) or materials (``mtllib``
/ ``usemtl``, and the textures an MTL file names), and a PLY with vertex colours, texture coordinates or a
texture (see :mod:`pmwm_codec.ply`), are encoded as a glTF asset is (:func:`~pmwm_codec.stream.asset.encode_asset`):
their appearance rides with the splits, seams coarsen in pairs, the materials and images are kept.  A file with
nothing but positions and faces (and normals, which alone do not make it an asset: :func:`obj_document`) is read
by :func:`~pmwm_codec.mesh.read_mesh` as before.

The pieces a reader hands over:

``Part``
    one triangle primitive: ``positions`` (n, 3) float, ``indices`` (m, 3) int into them,
    ``attributes`` {glTF semantic: (n, k) float} (stored as float32 / uint16 or uint32 by
    :func:`build_document`) (``NORMAL`` unit vectors, ``TEXCOORD_0`` in glTF's
    convention -- v grows downwards, so an OBJ's or PLY's ``v`` becomes ``1 - v`` --, ``COLOR_0`` in [0, 1], linear
    as glTF's colours are: a mesh file's sRGB-encoded colours decoded, :func:`linear_from_srgb`),
    and the index of its :class:`Material` or None;
``Material``
    a name, a base colour (r, g, b, a) in [0, 1], a metal-free roughness, and the index of its base colour
    and normal textures in the image list, or None;
images
    ``(bytes, media type, file name)`` -- PNG or JPEG, as glTF 2.0 core takes them (:func:`texture_image`).

Every file a mesh file names besides itself (an MTL, a texture) is read under the rule a ``.gltf``'s files are
(:func:`~pmwm_codec.format.document.beside`): a relative path inside the mesh file's folder, a regular file, no
symlink as its last component, all resources together at most :data:`~pmwm_codec.constants.MAX_RESOURCE_BYTES`.
A file that breaks the rule is never read (an input file never makes the encoder read outside what the user
named) and, as one that is missing, left out with a notice, the rest encoded (:class:`Resources`; obj2gltf's
secure mode): an MTL and its textures are appearance the geometry does not need, where a ``.gltf``'s buffers,
its geometry, are refused instead.  A texture path that finds nothing inside the folder is looked for by its
file name beside the mesh file (:meth:`Resources._by_name`).
"""

from __future__ import annotations

import io
import os
import re
import warnings
import zlib
from dataclasses import dataclass, field

import numpy as np

from .constants import MAX_ENCODE_FACES, MAX_ENCODE_VERTICES, MAX_INPUT_FILE_BYTES, MAX_RESOURCE_BYTES
from .errors import DegenerateMeshError, InputFormatError, MeshError


@dataclass
class Part:
    """One triangle primitive (see the module docstring for the arrays' shapes and dtypes)."""

    positions: np.ndarray
    indices: np.ndarray
    attributes: dict = field(default_factory=dict)
    material: int | None = None


#: The glTF extension of an emission brighter than an ``emissiveFactor`` of 1 (an MTL's ``Ke 4 4 4``).
EMISSIVE_STRENGTH = "KHR_materials_emissive_strength"


@dataclass
class Material:
    """A glTF metallic-roughness material as a mesh file's material maps onto one (metallic 0)."""

    name: str
    color: tuple = (1.0, 1.0, 1.0, 1.0)
    roughness: float = 1.0
    texture: int | None = None
    normal_texture: int | None = None
    #: glTF's metallicFactor: 0 for a mesh file's material; a decoded asset's own (:mod:`pmwm_codec.meshexport`).
    metallic: float = 0.0
    #: glTF's emissiveFactor times KHR_materials_emissive_strength's emissiveStrength (linear RGB, each >= 0) and
    #: the index of its emissiveTexture: an MTL's ``Ke`` / ``map_Ke`` (:func:`_parse_mtl`), a decoded asset's own
    #: (:mod:`pmwm_codec.meshexport`).
    emissive: tuple = (0.0, 0.0, 0.0)
    emissive_texture: int | None = None
    #: The file names an MTL gives for the three textures (:data:`TEXTURE_FILES`), read (into ``texture`` /
    #: ``normal_texture`` / ``emissive_texture``) only for the materials some face uses.
    texture_file: str | None = None
    normal_file: str | None = None
    emissive_file: str | None = None


#: A :class:`Material`'s texture file fields and the texture index each is read into.
TEXTURE_FILES = {"texture_file": "texture", "normal_file": "normal_texture", "emissive_file": "emissive_texture"}


def build_document(parts: list, materials: list, images: list, name: str) -> tuple:
    """``(gltf dict, [bin bytes])``: one mesh of ``parts`` (one primitive each) under one node named ``name``,
    ``materials`` and ``images`` (``(bytes, media type, file name)``; held as ``_bytes``, which
    :func:`~pmwm_codec.format.document.repack` embeds) -- the in-memory document
    :func:`~pmwm_codec.stream.asset.encode_asset` takes."""
    blob = bytearray()
    views, accessors, primitives = [], [], []

    def add(array: np.ndarray, kind: str, ctype: int, target: int, bounds: bool = False) -> int:
        data = np.ascontiguousarray(array).tobytes()
        blob.extend(bytes(-len(blob) % 4))
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data), "target": target})
        blob.extend(data)
        acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": int(len(array)), "type": kind}
        if bounds:
            acc["min"] = [float(v) for v in array.min(axis=0)]
            acc["max"] = [float(v) for v in array.max(axis=0)]
        accessors.append(acc)
        return len(accessors) - 1

    for part in parts:
        attrs = {"POSITION": add(part.positions.astype(np.float32), "VEC3", 5126, 34962, bounds=True)}
        for semantic, values in part.attributes.items():
            attrs[semantic] = add(values.astype(np.float32), f"VEC{values.shape[1]}", 5126, 34962)
        wide = len(part.positions) > 65535
        indices = part.indices.astype(np.uint32 if wide else np.uint16).reshape(-1)
        prim = {"attributes": attrs, "indices": add(indices, "SCALAR", 5125 if wide else 5123, 34963), "mode": 4}
        if part.material is not None:
            prim["material"] = part.material
        primitives.append(prim)
    gltf = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
            "nodes": [{"mesh": 0, "name": name}], "meshes": [{"name": name, "primitives": primitives}],
            "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(blob)}]}
    if materials:
        gltf["materials"] = [_material(m) for m in materials]
        if any(EMISSIVE_STRENGTH in m.get("extensions", {}) for m in gltf["materials"]):
            gltf["extensionsUsed"] = [EMISSIVE_STRENGTH]
    if images:
        gltf["images"] = [{"name": file_name, "uri": file_name, "mimeType": kind, "_bytes": data}
                          for data, kind, file_name in images]
        gltf["textures"] = [{"source": i} for i in range(len(images))]
    return gltf, [bytes(blob)]


def _material(m: Material) -> dict:
    pbr = {"baseColorFactor": [float(c) for c in m.color], "metallicFactor": float(m.metallic), "roughnessFactor": float(m.roughness)}
    if m.texture is not None:
        pbr["baseColorTexture"] = {"index": m.texture}
    out = {"name": m.name, "pbrMetallicRoughness": pbr}
    if m.normal_texture is not None:
        out["normalTexture"] = {"index": m.normal_texture}
    if m.color[3] < 1.0:
        out["alphaMode"] = "BLEND"
    strength = max(m.emissive)  # glTF's emissiveFactor stops at 1: a brighter light is its emissive strength
    if strength > 0.0:
        out["emissiveFactor"] = [float(c / strength) if strength > 1.0 else float(c) for c in m.emissive]
        if strength > 1.0:
            out["extensions"] = {EMISSIVE_STRENGTH: {"emissiveStrength": float(strength)}}
    if m.emissive_texture is not None:
        out["emissiveTexture"] = {"index": m.emissive_texture}
    return out


class Resources:
    """The files a mesh file at ``path`` names besides itself, read under one budget (module docstring);
    :meth:`image` keeps each texture once, however many materials name it."""

    def __init__(self, path: str, notices: list):
        self.base_dir = os.path.dirname(os.path.abspath(path))
        self.name = os.path.basename(path)
        self.notices = notices
        self.budget = [MAX_RESOURCE_BYTES]
        self.images: list = []
        self._image_ids: dict = {}
        #: The real paths of the files read, in order (:func:`named_files`).
        self.files: list = []

    def read(self, ref: str, what: str) -> bytes | None:
        """The bytes of the file ``ref`` names (``what``: how the notice names it, ``"the MTL file"``), or None
        with a notice when it is missing or cannot be read under the folder rule -- a path that leads outside
        the mesh file's folder or is absolute, a symbolic link out of it, anything but a regular file (a FIFO
        is never opened for reading), more bytes than the budget left: never read, the rest encoded (as
        obj2gltf's secure mode does; an MTL and its textures are appearance, the geometry does not need them)."""
        from .format.document import read_beside

        target = self._target(ref, what)
        if target is None:
            return None
        if not os.path.lexists(target):
            self.notices.append(f"{what} {_shown(ref)} is not beside {self.name}: left out")
            return None
        label = f"{self.name}: {what} {_shown(ref)}"
        try:
            blob = read_beside(ref, self.base_dir, label, self.budget)
        except InputFormatError as exc:
            self.notices.append(f"{what} {_shown(ref)} not read ({_reason(exc, label)}): left out")
            return None
        self.budget[0] -= len(blob)
        self.files.append(target)
        return blob

    def _target(self, ref: str, what: str) -> str | None:
        """The real path ``ref`` names inside the folder (:func:`~pmwm_codec.format.document.beside`), or None
        with a notice when it leads outside it or is absolute."""
        from .format.document import beside

        label = f"{self.name}: {what} {_shown(ref)}"
        try:
            return beside(ref, self.base_dir, label)
        except InputFormatError as exc:
            self.notices.append(f"{what} {_shown(ref)} not read ({_reason(exc, label)}): left out")
            return None

    def image(self, ref: str) -> int | None:
        """The index of the texture ``ref`` names in :attr:`images`, read and made PNG or JPEG
        (:func:`texture_image`) the first time; None (with a notice) where it cannot be."""
        ref, key = self.locate(ref)
        if key is None:
            return None
        if key not in self._image_ids:
            blob = self.read(ref, "the texture")
            made = None if blob is None else texture_image(blob, ref, self.notices)
            self._image_ids[key] = None
            if made is not None:
                self.images.append((*made, os.path.basename(ref.replace("\\", "/"))))
                self._image_ids[key] = len(self.images) - 1
        return self._image_ids[key]

    def locate(self, ref: str) -> tuple:
        """``(the name the texture ``ref`` is read by (:meth:`_by_name`), its real path inside the folder or None
        with a notice (:meth:`_target`))``; nothing is read."""
        ref = self._by_name(ref)
        return ref, self._target(ref, "the texture")

    def _by_name(self, ref: str) -> str:
        """``ref``, or its last component where ``ref`` names no file inside the folder -- a path out of it, an
        absolute one (a Windows exporter's ``C:/maps/skin.jpg``), one that names nothing -- and a file of that
        name lies beside the mesh file, where obj2gltf and Blender look for it then (a notice says so)."""
        from .format.document import beside

        name = ref.rsplit("/", 1)[-1]
        if not name or name == ref:
            return ref
        for candidate in (ref, name):
            try:
                if os.path.lexists(beside(candidate, self.base_dir, candidate)):
                    if candidate is name:
                        self.notices.append(f"the texture {_shown(ref)} read as {_shown(name)}, beside {self.name}")
                    return candidate
            except InputFormatError:
                continue
        return ref


def _reason(exc: Exception, label: str) -> str:
    """What an InputFormatError whose message starts with ``label`` says after it ("leads outside the asset's
    folder", "is not a regular file" ...)."""
    message = str(exc)
    return (message[len(label):] if message.startswith(label) else message).strip(" :;")


def _shown(ref: str) -> str:
    return repr(ref if len(ref) <= 80 else ref[:77] + "...")


def texture_image(blob: bytes, ref: str, notices: list) -> tuple | None:
    """``(bytes, media type)`` of a texture file's bytes as glTF 2.0 core takes them: a PNG (whole:
    :func:`_png_damage`) or JPEG byte for byte; another format Pillow reads (TGA, BMP, TIFF, ...) re-written
    as a PNG of the same pixels, with a notice; None, with a notice, for bytes no image format reads, a damaged
    PNG, and an image of more pixels than Pillow decodes without calling it a decompression bomb
    (``Image.MAX_IMAGE_PIXELS``; a BMP header of 54 bytes may declare 10^8 pixels), never decoded."""
    from .format.document import sniff_image

    kind = sniff_image(blob)
    damage = _png_damage(blob) if kind == "image/png" else None
    if damage is not None:
        notices.append(f"the texture {_shown(ref)} is a damaged PNG ({damage}): left out")
        return None
    if kind in ("image/png", "image/jpeg"):
        return blob, kind
    from PIL import Image, UnidentifiedImageError

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)  # open() warns, and load() would decode
            with Image.open(io.BytesIO(blob)) as img:
                img.load()
                if img.mode not in ("RGB", "RGBA", "L", "LA"):
                    img = img.convert("RGBA" if "A" in img.getbands() or "transparency" in img.info else "RGB")
                out = io.BytesIO()
                img.save(out, format="PNG")
    except (Image.DecompressionBombError, Image.DecompressionBombWarning):
        notices.append(f"the texture {_shown(ref)} declares more pixels than the limit of {Image.MAX_IMAGE_PIXELS:,} "
                       "(a decompression bomb?): left out")
        return None
    except (UnidentifiedImageError, OSError, ValueError) as exc:
        notices.append(f"the texture {_shown(ref)} is not an image Pillow reads ({str(exc)[:60]}): left out")
        return None
    notices.append(f"the texture {_shown(ref)} re-written as PNG (glTF takes PNG or JPEG)")
    return out.getvalue(), "image/png"


def _png_damage(blob: bytes) -> str | None:
    """What is wrong with the chunks of a PNG's bytes (``blob``, the signature checked), or None: an ``IHDR``
    first, every chunk whole with its CRC, an ``IEND`` last.  No pixel is decoded (a PNG is embedded byte for
    byte, and a viewer decodes it: a truncated or corrupt one would be a texture no viewer shows)."""
    from .format.document import png_chunks

    for i, (kind, start, end) in enumerate(png_chunks(blob)):
        if i == 0 and kind != b"IHDR":
            return "no IHDR chunk first"
        if end > len(blob):
            return f"truncated in its {kind.decode('latin-1')!r} chunk"
        if zlib.crc32(blob[start + 4:end - 4]) != int.from_bytes(blob[end - 4:end], "big"):
            return f"the CRC of its {kind.decode('latin-1')!r} chunk does not match"
        if kind == b"IEND":
            return None
    return "truncated: no IEND chunk"


# -- Wavefront OBJ ------------------------------------------------------------------------------------------

#: Options of an MTL map statement and how many values each takes (``-o``, ``-s``, ``-t``: one to three).
_MAP_OPTIONS = {"-blendu": 1, "-blendv": 1, "-boost": 1, "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1,
                "-clamp": 1, "-bm": 1, "-imfchan": 1, "-type": 1, "-cc": 1}
_APPEARANCE = re.compile(r"^[ \t]*(?:vt[ \t]|mtllib[ \t]|usemtl[ \t])", re.M)
#: The records that may make an OBJ an asset, and its normals, found after a line feed (the text given one first):
#: a literal start the regular expression engine scans for fast, where ``^`` with re.M tries every position.
_APPEARANCE_WORDS = re.compile(r"\n[ \t]*(?:vt|mtllib|usemtl)[ \t]")
_NORMALS_WORD = re.compile(r"\n[ \t]*vn[ \t]")
_COLOURED = re.compile(r"^[ \t]*v(?:[ \t]+[^ \t\n]+){6}", re.M)
#: What the encoder says of a mesh file's normals when nothing else makes it an asset, and of a PLY's face colours.
_NORMALS_LEFT = "normals ({}) not carried: the .pmw holds positions, and viewers shade it from them"
_FACE_COLOURS_LEFT = "the faces' colours not carried (a PLY's vertex colours are)"
_RECORD = re.compile(r"^[ \t]*(v|vt|vn|f|usemtl|mtllib)[ \t]+([^\n]*)", re.M)


def read_appearance(path) -> tuple:
    """``((gltf, buffers) or None, notices)`` of the mesh file at ``path``: the in-memory document of an OBJ
    or a PLY that carries appearance (:func:`obj_document`, :func:`ply_document`), else None -- geometry
    alone, which :func:`~pmwm_codec.mesh.read_mesh` reads -- with what the encoder should say of what it
    leaves out.  See :func:`read_source`, which reads such a file once for either."""
    source, notices = read_source(path)
    return (source if isinstance(source, tuple) else None), notices


def read_source(path) -> tuple:
    """``(source, notices)`` of the mesh file at ``path`` for the encoder: ``source`` the in-memory document of
    an OBJ or a PLY that carries appearance (:func:`obj_document`, :func:`ply_document`), else the
    :class:`~pmwm_codec.mesh.Mesh` :func:`~pmwm_codec.mesh.read_mesh` reads -- an OBJ's text read once for both
    (a plain OBJ's second reading had cost 1.4 s on the 437k-vertex dragon, read in 1.6); ``notices`` what the
    encoder should say of what it leaves out (normals, face colours)."""
    from .mesh import _soup_welded, obj_arrays, obj_lines_points, obj_mesh, obj_text, read_mesh, with_obj_left_out
    from .sources import check_input_path

    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in (".obj", ".ply", ".off") or os.stat(path).st_size > MAX_INPUT_FILE_BYTES:
        return read_mesh(path), []  # read_mesh names what is wrong
    name = check_input_path(path, "a mesh file")
    if suffix == ".off":
        return off_source(path, name)
    if suffix == ".ply":
        doc, notices = _ply_appearance(path, name)
        return (doc if doc is not None else read_mesh(path)), notices
    text = obj_text(path, name)
    lead = "\n" + text  # every record after a line feed (_APPEARANCE_WORDS)
    normals = [_NORMALS_LEFT.format("vn")] if _NORMALS_WORD.search(lead) else []
    if _APPEARANCE_WORDS.search(lead) is None:  # no vt, mtllib, usemtl (~0.07 s on 30 MB; ^ with re.M: 0.2)
        positions, faces, widest = obj_arrays(text, name)
        if widest < 6:  # no v record of colours either: the one parse is the mesh
            return with_obj_left_out(_soup_welded(positions, faces, name), lead), normals
    del lead  # a second copy of the text, not kept while the document is made (790 MB on a 790 MB OBJ)
    doc, notices = obj_document(path, text)
    if doc is not None:
        left = obj_lines_points(text)
        if left:  # as the geometry reader counts them (Mesh.cleanup)
            notices.append(f"dropped {left:,} line and point records")
        return doc, notices
    return obj_mesh(text, name), notices + normals


def off_source(path: str, name: str) -> tuple:
    """``(source, notices)`` of an OFF file, read once: the in-memory document of a ``C`` one (``COFF``: its
    vertex colours as COLOR_0, 0..255 where a value reaches 2, else 0..1, as an OBJ's), else its
    :class:`~pmwm_codec.mesh.Mesh`; a note when faces carry colours (not read) or vertices normals (not
    carried)."""
    from .mesh import _read_off, _soup_welded, mesh_arrays

    header: list = []
    positions, faces, colours, face_colours = _read_off(path, name, appearance=True, header_out=header)
    keyword, past = header
    notices = ["the faces' colours not carried (an OFF's vertex colours are)"] if face_colours else []
    if "N" in keyword.replace("OFF", ""):  # NOFF, CNOFF ...: a normal after each position, not read
        notices.append(_NORMALS_LEFT.format(f"of the {keyword} vertices"))
    if past:  # as other readers, the declared count is what is read
        notices.append(f"{past:,} record{'s' if past != 1 else ''} after the faces the OFF header declares left out "
                       "(its face count ends the mesh, as other readers read it)")
    if colours is None:
        return _soup_welded(positions, faces, name), notices
    if not np.isfinite(colours).all():
        raise InputFormatError(f"{name}: an OFF vertex colour is not a finite number")
    colours = np.clip(colours / (255.0 if colours.max(initial=0.0) >= 2.0 else 1.0), 0.0, 1.0)
    positions, faces = mesh_arrays(positions, faces, name)
    vertex = faces.reshape(-1)
    none = np.full(len(vertex), -1, np.int64)
    parts = _obj_parts(positions, np.zeros((0, 2)), np.zeros((0, 3)), colours, np.stack([vertex, none, none], 1),
                       np.full(len(faces), -1, np.int64), notices, [])
    if not parts:
        raise DegenerateMeshError(f"{name}: every triangle is degenerate")
    return _document(parts, [], Resources(path, notices), name), notices


def named_files(path) -> list:
    """The real paths of the files the mesh file at ``path`` names besides itself and the encoder would read: a
    ``.gltf``'s / GLB's buffers and images (:func:`~pmwm_codec.format.document.named_files`), an OBJ's MTL files
    and the textures they name (every material's), a PLY's ``TextureFile`` textures (where it has texture
    coordinates to map them: :func:`ply_document`); each once, inside the file's folder, existing (what
    cannot be read is left out: the encode names it).  An output must not replace one of them (``pmw encode
    scan.obj -o skin.png``), and ``pmw batch``'s ledger covers them (a changed texture redoes its asset)."""
    from .format.document import named_files as gltf_named_files
    from .mesh import obj_text

    path = os.fspath(path)
    suffix = os.path.splitext(path)[1].lower()
    if suffix in (".gltf", ".glb"):
        return gltf_named_files(path)
    if suffix not in (".obj", ".ply"):
        return []
    resources = Resources(path, [])  # the encoder's own rules; what a listing leaves out it does not say
    if suffix == ".ply":
        refs = _ply_texture_files(path)
    else:
        try:
            text = obj_text(path, resources.name)
        except (InputFormatError, OSError):
            return []
        materials, _ = _obj_materials(re.findall(r"^[ \t]*mtllib[ \t]+([^\n]*)", text, re.M), resources)
        refs = [ref for m in materials for ref in (getattr(m, f) for f in TEXTURE_FILES) if ref]
    out = list(resources.files)
    for ref in refs:
        target = resources.locate(ref)[1]
        if target is not None and os.path.isfile(target) and target not in out:
            out.append(target)
    return out


def obj_document(path, text: str) -> tuple:
    """``((gltf, buffers) or None, notices)`` of the OBJ at ``path`` (its ``text``, comments removed): the
    document when the OBJ carries appearance -- texture coordinates, vertex colours on every ``v`` record, or
    materials that resolve to something -- else None (geometry alone).

    A glTF vertex is each distinct (position, texture coordinate, normal) triple a face corner names, per
    material; faces are fan-triangulated (a record of fewer than three corners draws nothing); a face's
    material is the last ``usemtl`` before it (faces before any, or naming a material no MTL defines, have
    none).  InputFormatError (one line) for an index that names nothing, a malformed record, or the
    encoder's limits; MeshError for an OBJ with no faces."""
    name = os.path.basename(path)
    has_colours = False
    if _APPEARANCE.search(text) is None:
        if _COLOURED.search(text) is None:
            return None, []  # no vt, no material, no v record of six numbers or more: geometry only
        has_colours = True
    fast = _obj_records_fast(text)  # the common OBJ, parsed a kind of record at once from its bytes
    if fast is not None:
        v, vt, vn, mtllibs, faces = fast
    else:
        v, vt, vn, mtllibs, faces = _obj_records(text, name)
    if len(v) > MAX_ENCODE_VERTICES:
        raise InputFormatError(f"{name}: more than {MAX_ENCODE_VERTICES:,} vertices (the encoder's limit)")
    colours, notices = None, []
    if v.shape[1] >= 6 and not np.isnan(v[:, 3:6]).any():
        colours = v[:, 3:6]  # x y z r g b, or x y z r g b a (its alpha not carried), as three.js and Blender read them
        # 0..255 where a value reaches 2 (a 0..1 colour a rounding over 1 is not one), else 0..1
        colours = np.clip(colours / (255.0 if colours.max() >= 2.0 else 1.0), 0.0, 1.0)
    elif has_colours or v.shape[1] >= 6:
        notices = [f"vertex colours left out: {int(np.isnan(v[:, 3:6]).any(axis=1).sum()):,} of {len(v):,} v records "
                   "have none"]
        if has_colours:
            return None, notices
    positions = v[:, :3]
    resources = Resources(path, notices)
    materials, by_name = _obj_materials(mtllibs, resources)
    corners, face_material = faces(by_name)
    if len(vt) == 0 and colours is None and (face_material < 0).all():
        return None, notices  # materials that did not resolve, no vt, no colours: geometry only
    parts = _obj_parts(positions, vt, vn, colours, corners, face_material, notices, materials)
    if not parts:  # faces were read (else MeshError before), and every one was dropped
        raise DegenerateMeshError(f"{name}: every triangle is degenerate")
    return _document(parts, materials, resources, name), notices


def _obj_records(text: str, name: str) -> tuple:
    """``(v, vt, vn, mtllibs, faces)`` of an OBJ's text, read record by record (any OBJ): ``v`` (p, 3|4|6|7),
    ``vt`` (t, 1..3), ``vn`` (n, 3) float64 (:func:`_rows`: narrower records padded with NaN), ``mtllibs`` the text
    of each ``mtllib`` record, ``faces`` a function of the materials' ``{name: index}`` giving
    :func:`_obj_faces`' ``(corners, face_material)``.  InputFormatError (one line) for a malformed record."""
    kinds, bodies = [], []
    for m in _RECORD.finditer(text):
        kinds.append(m.group(1))
        bodies.append(m.group(2))
    try:
        v = _rows([b for k, b in zip(kinds, bodies) if k == "v"], (3, 4, 6, 7), "v", name, finite=True)
        vt = _rows([b for k, b in zip(kinds, bodies) if k == "vt"], (1, 2, 3), "vt", name, finite=True)
        vn = _rows([b for k, b in zip(kinds, bodies) if k == "vn"], (3,), "vn", name)
    except InputFormatError:
        raise
    except ValueError as exc:
        raise InputFormatError(f"{name}: malformed OBJ record: {_printable(str(exc))[:60]}") from None
    mtllibs = [b for k, b in zip(kinds, bodies) if k == "mtllib"]
    return v, vt, vn, mtllibs, lambda by_name: _obj_faces(kinds, bodies, name, by_name)


#: An OBJ's ``usemtl`` or ``mtllib`` record from the start of its line (as :data:`_RECORD` reads it).
_MATERIAL_RECORD = re.compile(r"[ \t]*(usemtl|mtllib)[ \t]+([^\n]*)")
#: The widths :func:`_rows` takes of each kind of vertex record, and whether its numbers must fit float32.
_ROW_WIDTHS = (((3, 4, 6, 7), True), ((1, 2, 3), True), ((3,), False))


def _obj_records_fast(text: str):
    """:func:`_obj_records`' result, the same arrays, read from the text's bytes by numpy (no Python object per
    record or token: those lists took ~8x the text at the peak), for the common ASCII OBJ whose ``v`` / ``vt`` / ``vn``
    records hold plain decimals of the widths :func:`_rows` takes, each a float32 carries, and whose faces are
    read a column at a time (:meth:`~pmwm_codec.mesh.ObjLines.face_corners`: every corner of one form, naming a
    record read before its face, three or more corners a face); None for anything else, which :func:`_obj_records`
    reads or names what is wrong in (its words, since it reads it).  The records are read by
    :class:`~pmwm_codec.mesh.ObjLines` (:meth:`~pmwm_codec.mesh.ObjLines.numbers`, ``face_corners``), as
    :func:`~pmwm_codec.mesh.read_mesh` reads an OBJ."""
    from .mesh import _obj_normalized, fan_triangles, obj_lines

    text = _obj_normalized(text)
    lines = obj_lines(text)
    if lines is None:
        return None
    kinds = lines.kinds
    arrays = []
    for k, (kind, (widths, finite)) in enumerate(zip(kinds, _ROW_WIDTHS)):
        if not kind.any():
            arrays.append(np.zeros((0, min(widths))))
            continue
        numbers = lines.numbers(k)
        if numbers is None or not np.isin(numbers[1], widths).all():
            return None  # (a record of a width not taken)
        if finite and not _float32_carries(numbers[0]):
            return None
        arrays.append(_padded_rows(*numbers))
        del numbers
    face_lines = np.flatnonzero(kinds[3])
    uses, mtllibs = [], []
    heads = lines.data[lines.starts]
    for line in np.flatnonzero(np.isin(heads, np.frombuffer(b"um \t", np.uint8))).tolist():
        m = _MATERIAL_RECORD.match(text, int(lines.starts[line]))
        if m is not None and m.group(1) == "mtllib":
            mtllibs.append(m.group(2))
        elif m is not None:
            uses.append((line, m.group(2)))
    use_lines = np.array([line for line, _ in uses], np.int64)
    face_use = np.searchsorted(use_lines, face_lines) - 1  # each face's material: the last usemtl before it
    del kinds, text, heads  # (the text: the caller keeps it)
    corners = lines.face_corners((0, 1, 2))  # (the lines' bytes let go as the faces are copied out)
    if corners is None:
        return None
    ids, per_face = corners
    corners = fan_triangles(ids, per_face).reshape(-1, 3)
    tri_use = np.repeat(face_use, per_face - 2)

    def faces_of(by_name: dict) -> tuple:
        material = np.array([by_name.get(body.strip(), -1) for _, body in uses] + [-1], np.int64)
        return corners, material[tri_use]  # (a face of no usemtl before it: -1, the last)

    return (*arrays, mtllibs, faces_of)


def _document(parts: list, materials: list, resources: Resources, name: str) -> tuple:
    """:func:`build_document` of a mesh file's ``parts``: the materials some part uses, renumbered, with
    their textures (each read once, through ``resources``)."""
    used = sorted({p.material for p in parts if p.material is not None})
    renumber = {old: new for new, old in enumerate(used)}
    for p in parts:
        p.material = None if p.material is None else renumber[p.material]
    kept = [materials[i] for i in used]
    for m in kept:  # the textures of the materials faces use, each read once
        for file_field, index_field in TEXTURE_FILES.items():
            ref = getattr(m, file_field)
            setattr(m, index_field, None if ref is None else resources.image(ref))
        if m.texture is not None:  # the texture is the colour (as Blender imports it); its alpha stays
            m.color = (1.0, 1.0, 1.0, m.color[3])
    return build_document(parts, kept, resources.images, os.path.splitext(name)[0])


def _rows(records: list, widths: tuple, kind: str, name: str, finite: bool = False) -> np.ndarray:
    """(n, w) float64 of ``records`` (the text after each keyword); w the widest record, narrower ones padded
    with NaN; ValueError (the record) for a record of a width not in ``widths`` or a token that is no number;
    ``finite``: InputFormatError naming the first record holding a number float32 does not carry (NaN,
    infinite, beyond its range: positions and texture coordinates, which a NaN would otherwise reach as the
    padding's 0 or as an encoder's failure; a normal that is not finite is left out with a notice instead)."""
    if not records:
        return np.zeros((0, min(widths)))
    counts = np.fromiter((len(r.split()) for r in records), np.int64, len(records))
    for w in np.unique(counts).tolist():
        if w not in widths:
            raise ValueError(f"{kind} {records[int(np.flatnonzero(counts == w)[0])].strip()}")
    flat = " ".join(records).split()
    try:
        values = np.array(flat, dtype=np.float64)
    except ValueError:
        bad = next(t for t in flat if not _is_number(t))
        raise ValueError(f"{kind} ... {bad}") from None
    if finite and not _float32_carries(values):
        row = int(np.searchsorted(np.cumsum(counts), np.argmin(np.abs(values) <= np.finfo(np.float32).max), "right"))
        raise InputFormatError(f"{name}: {kind} record {row + 1:,} holds a number float32 cannot carry (NaN, infinite "
                               f"or beyond 3.4e38): {_printable(kind + ' ' + records[row])[:60]}")
    return _padded_rows(values, counts)


def _float32_carries(values: np.ndarray) -> bool:
    """Whether float32 carries every value of ``values`` (float64): none NaN, infinite or beyond its range."""
    return bool((np.abs(values) <= np.finfo(np.float32).max).all())


def _padded_rows(values: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(len(counts), w) float64 of the records' ``values`` (float64, record after record; ``counts`` (r,) int64
    values each), w the widest record, narrower ones padded with NaN."""
    width = int(counts.max())
    if (counts == width).all():
        return values.reshape(-1, width)
    out = np.full((len(counts), width), np.nan)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    for w in np.unique(counts).tolist():
        rows = np.flatnonzero(counts == w)
        out[rows, :w] = values[starts[rows, None] + np.arange(w)]
    return out


def _printable(text: str) -> str:
    """``text`` as a message quotes it: its whitespace runs one space, any other character that does not print
    (a terminal's escape sequence) escaped."""
    text = " ".join(text.split())
    return text if text.isprintable() else "".join(c if c.isprintable() else repr(c)[1:-1] for c in text)


def _is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _obj_materials(mtllibs: list, resources: Resources) -> tuple:
    """``(materials, {name: index})`` of every MTL file the ``mtllib`` records name (a record may name several;
    a name repeated is read once; a material defined twice keeps its first definition)."""
    materials, by_name, seen = [], {}, set()
    for record in mtllibs:
        for ref in _mtllib_names(record):
            if ref in seen:
                continue
            seen.add(ref)
            blob = resources.read(ref, "the MTL file")
            if blob is None:
                continue
            from .mesh import _mesh_text

            parsed = _parse_mtl(_mesh_text(blob, f"{resources.name}: {ref}", "MTL"))
            for m in _near_mtl(parsed, ref, resources.base_dir):
                if m.name not in by_name:
                    by_name[m.name] = len(materials)
                    materials.append(m)
    return materials, by_name


def _near_mtl(materials: list, mtl_ref: str, base_dir: str) -> list:
    """``materials`` (of the MTL file ``mtl_ref`` names, relative to the OBJ's folder ``base_dir``) with each
    relative texture name made relative to the MTL's own folder where that is a subfolder and the texture is
    there (``mtllib mats/a.mtl`` naming ``map_Kd skin.png``: ``mats/skin.png``, where Blender and three.js read
    it), under the folder rule still; else as the MTL wrote it (beside the OBJ)."""
    from .format.document import beside

    folder = os.path.dirname(mtl_ref)
    for m in materials if folder else []:
        for attr in TEXTURE_FILES:
            ref = getattr(m, attr)
            if not ref or ref.startswith("/") or os.path.isabs(ref):
                continue
            near = f"{folder}/{ref}"
            try:
                if os.path.lexists(beside(near, base_dir, near)):
                    setattr(m, attr, near)
            except InputFormatError:
                continue
    return materials


def _mtllib_names(record: str) -> list:
    """The file names of an ``mtllib`` record: one name when the record is a single file name with spaces that
    ends in ``.mtl`` (as some exporters write), else each word."""
    record = record.strip().replace("\\", "/")
    words = record.split()
    if len(words) > 1 and record.lower().endswith(".mtl") and sum(w.lower().endswith(".mtl") for w in words) == 1:
        return [record]
    return words


def _parse_mtl(text: str) -> list:
    """The :class:`Material` of each ``newmtl`` of an MTL text: ``Kd`` and ``d`` (or, without a ``d``, ``Tr``, its
    complement -- but ``Tr 1``, which MeshLab writes on every material as its opacity, is opaque) make the base
    colour (white where the ``map_Kd`` texture is read, as Blender imports it: the texture is the colour), ``Ns``
    the roughness (``1 - sqrt(Ns / 1000)``), ``map_Kd`` the base colour texture, ``map_Bump`` / ``bump`` /
    ``norm`` the normal texture, ``Ke`` the emission (linear RGB, negatives as 0) and ``map_Ke`` the emissive
    texture (under a ``map_Ke`` without a ``Ke``, an emission of 1, as Blender imports it: the texture is the
    light); other statements are not carried."""
    out, current, kd, alpha, tr, ke = [], None, None, None, None, None

    def close():
        if current is not None:
            current.color = (*(kd or (1.0, 1.0, 1.0)), alpha if alpha is not None else tr if tr is not None else 1.0)
            current.emissive = ke or ((1.0, 1.0, 1.0) if current.emissive_file else (0.0, 0.0, 0.0))
            out.append(current)

    for raw in text.splitlines():
        words = raw.split("#", 1)[0].split()
        if not words:
            continue
        key = words[0].lower()
        if key == "newmtl":
            close()
            current, kd, alpha, tr, ke = Material(" ".join(words[1:]) or "material"), None, None, None, None
        elif current is None:
            continue
        elif key == "kd" and len(words) >= 4:
            kd = tuple(min(max(_number_or(w, 1.0), 0.0), 1.0) for w in words[1:4])
        elif key == "ke" and len(words) >= 4:
            ke = tuple(max(_number_or(w, 0.0), 0.0) for w in words[1:4])
        elif key == "d" and len(words) >= 2:
            alpha = min(max(_number_or(words[-1], 1.0), 0.0), 1.0)
        elif key == "tr" and len(words) >= 2:  # 1 - d; but MeshLab writes its opacity, "Tr 1.000000", as Tr
            tr = 1.0 - min(max(_number_or(words[-1], 0.0), 0.0), 1.0)
            tr = 1.0 if tr == 0.0 else tr
        elif key == "ns" and len(words) >= 2:
            current.roughness = float(1.0 - min(max(_number_or(words[1], 0.0), 0.0) / 1000.0, 1.0) ** 0.5)
        elif key in _MAP_FIELDS and len(words) >= 2:
            ref = _map_file(words[1:])
            if ref:
                setattr(current, _MAP_FIELDS[key], ref)
    close()
    return out


#: The MTL map statements read (lower case) and the :class:`Material` file field each names.
_MAP_FIELDS = {"map_kd": "texture_file", "map_bump": "normal_file", "bump": "normal_file", "norm": "normal_file",
               "map_ke": "emissive_file"}


def _number_or(token: str, default: float) -> float:
    try:
        value = float(token)
    except ValueError:
        return default
    return value if np.isfinite(value) else default


def _map_file(words: list) -> str:
    """The file name of an MTL map statement's arguments: its options (``-s 1 1 1``, ``-bm 0.5``, ...)
    skipped, the rest joined (a file name may hold spaces), backslashes read as slashes."""
    i = 0
    while i < len(words) and words[i].lower() in _MAP_OPTIONS:
        n = _MAP_OPTIONS[words[i].lower()]
        i += 1
        taken = 0
        while taken < n and i < len(words) and (_is_number(words[i]) or words[i] in ("on", "off")):
            i += 1
            taken += 1
    name = " ".join(words[i:]).replace("\\", "/")  # "" for options alone (map_Kd -s 1 1 1): no file
    return name[1:-1] if len(name) > 1 and name[0] == name[-1] == '"' else name  # map_Kd "my skin.png"


def _obj_faces(kinds: list, bodies: list, name: str, by_name: dict) -> tuple:
    """``(corners (c, 3) int64, material per triangle (c / 3,) int64, -1 for none)``: each triangle's three corners as 0-based
    (position, texture coordinate, normal) indices, -1 where a corner names none; relative (negative) indices
    resolved against the records read before the face.  InputFormatError for an index 0, out of range, or a
    corner that is not ``v``, ``v/t``, ``v//n`` or ``v/t/n``.  Read a column at a time when every corner has
    one form (:func:`_obj_faces_columns`), else record by record (which names what is wrong)."""
    fast = _obj_faces_columns(kinds, bodies, by_name)
    if fast is not None:
        return fast
    counts = {"v": 0, "vt": 0, "vn": 0}
    rows, mats, material = [], [], -1
    for kind, body in zip(kinds, bodies):
        if kind == "f":
            corners = body.split()
            if len(corners) < 3:
                continue  # a point or an edge: draws no triangle
            if len(rows) + 3 * (len(corners) - 2) > 3 * MAX_ENCODE_FACES:
                raise InputFormatError(f"{name}: more than {MAX_ENCODE_FACES:,} triangles (the encoder's limit)")
            ids = [_corner(c, counts, name) for c in corners]
            for k in range(1, len(ids) - 1):
                rows.extend((ids[0], ids[k], ids[k + 1]))
                mats.append(material)
        elif kind == "usemtl":
            material = by_name.get(body.strip(), -1)
        elif kind in counts:
            counts[kind] += 1
    if not rows:
        raise MeshError(f"{name}: the mesh has no vertices or no faces")
    return np.array(rows, dtype=np.int64), np.array(mats, dtype=np.int64)


#: The corner forms of :func:`_obj_faces_columns`: (slashes per corner, "//" per corner) -> the columns the
#: corner's numbers fill (position, texture coordinate, normal).
_CORNER_FORMS = {(0, 0): (0,), (1, 0): (0, 1), (2, 1): (0, 2), (2, 0): (0, 1, 2)}


def _obj_faces_columns(kinds: list, bodies: list, by_name: dict):
    """:func:`_obj_faces`'s result read a column at a time (numpy over every corner: ~8x the record loop on the
    437k-vertex dragon) when every corner of every face has one form and every index names a record; None for
    anything else (the record loop then reads it or names what is wrong)."""
    kind = np.array([{"v": 0, "vt": 1, "vn": 2, "f": 3, "usemtl": 4}.get(k, 5) for k in kinds], np.int8)
    face_rows = np.flatnonzero(kind == 3)
    faces = [bodies[i] for i in face_rows.tolist()]
    if not faces:
        return None
    per_face = np.fromiter((len(b.split()) for b in faces), np.int64, len(faces))
    if (per_face < 3).any() or int((per_face - 2).sum()) > MAX_ENCODE_FACES:
        return None
    text = " ".join(faces)
    n = int(per_face.sum())
    form = _CORNER_FORMS.get((text.count("/") // n, text.count("//") // n))
    if form is None or text.count("/") % n or text.count("//") % n:
        return None
    if not _every_corner_has(text, n, 2 if 2 in form else len(form) - 1):
        return None  # forms mixed so that the slashes average one form (f 1/4/1 2/5/1 3/6/1 and f 4 5 6)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a token that is not an integer stops the reader: the record loop names it
        try:
            values = np.fromstring(text.replace("/", " "), dtype=np.int64, sep=" ")
        except (ValueError, DeprecationWarning):
            return None
    del text  # the faces' text (~60 bytes a face) is not held while the corners are made: in place from here
    if len(values) != n * len(form):
        return None
    before = [np.cumsum(kind == k)[face_rows] for k in range(3)]  # records of each kind read before each face
    use = np.flatnonzero(kind == 4)  # each face's material: the last usemtl before it
    material = np.full(len(kinds), -1, np.int64)
    material[use] = [by_name.get(bodies[i].strip(), -1) for i in use.tolist()]
    last = np.maximum.accumulate(np.where(kind == 4, np.arange(len(kinds)), -1))[face_rows]
    return _face_corners(values, form, per_face, before, np.where(last >= 0, material[np.maximum(last, 0)], -1))


def _face_corners(values: np.ndarray, form: tuple, per_face: np.ndarray, before: list, face_material):
    """:func:`_obj_faces`' ``(corners (c, 3) int64, material per triangle (c / 3,) int64)`` of the faces' corner
    numbers ``values`` (int64, ``len(form)`` a corner, the kinds ``form`` names: 0 ``v``, 1 ``vt``, 2 ``vn``),
    ``per_face`` (f,) int64 corners each (three or more), ``before[kind]`` (f,) int64 the records of each kind read
    before each face, ``face_material`` (f,) int64 each face's (-1 none); None where an index is 0 or names no
    record (the record loop names it).  The arithmetic of :meth:`~pmwm_codec.mesh.ObjLines.face_corners`:
    :func:`~pmwm_codec.mesh.obj_corner_ids`, :func:`~pmwm_codec.mesh.fan_triangles`."""
    from .mesh import fan_triangles, obj_corner_ids

    ids = obj_corner_ids(values, form, per_face, before)
    if ids is None:
        return None
    return fan_triangles(ids, per_face).reshape(-1, 3), np.repeat(np.asarray(face_material), per_face - 2)


#: The bytes :meth:`str.split` splits on that a face record may hold (its line breaks are gone: ``one_line_end``).
_SPLITS = np.zeros(256, bool)
_SPLITS[[9, 10, 11, 12, 13, 28, 29, 30, 31, 32]] = True


def _every_corner_has(text, n: int, slashes: int) -> bool:
    """Whether each of the ``n`` corners of the face records ``text`` (str, or its bytes: bytes-like; joined by
    white space; ``n * slashes`` slashes in
    all) holds ``slashes`` slashes: numpy over its bytes, two slashes in one corner when no separator lies between
    them.  False for a separator :meth:`str.split` knows and this does not (the record loop reads it)."""
    if not slashes:
        return True  # no slash at all (counted by the caller)
    raw = np.frombuffer(text.encode("utf-8", "replace") if isinstance(text, str) else text, np.uint8)
    before = np.searchsorted(np.flatnonzero(_SPLITS[raw]), np.flatnonzero(raw == 47)).reshape(n, slashes)
    return bool((before[:, 0] == before[:, -1]).all() and (before[1:, 0] > before[:-1, -1]).all())


def _corner(token: str, counts: dict, name: str) -> tuple:
    parts = token.split("/")
    if len(parts) > 3 or not parts[0]:
        raise InputFormatError(f"{name}: malformed OBJ face corner {token[:40]!r}")
    out = []
    for value, kind in zip(parts + [""] * (3 - len(parts)), ("v", "vt", "vn")):
        if not value:
            out.append(-1)
            continue
        try:
            i = int(value)
        except ValueError:
            raise InputFormatError(f"{name}: malformed OBJ face corner {token[:40]!r}") from None
        n = counts[kind]
        if i == 0 or i > n or i < -n:
            raise InputFormatError(f"{name}: face index {value} names no {kind} record ({n:,} read before the face)")
        out.append(i - 1 if i > 0 else n + i)
    return tuple(out)


def linear_from_srgb(colours: np.ndarray) -> np.ndarray:
    """(n, 3 | 4) float64: colours in [0, 1] as a mesh file holds them, sRGB-encoded (as three.js's OBJ and PLY
    loaders and Blender take them), in the linear values glTF's COLOR_0 holds (glTF 2.0, 3.7.2.1); alpha as it
    is.  The inverse of :func:`srgb_from_linear`."""
    out = np.array(colours, np.float64)
    c = out[:, :3]
    out[:, :3] = np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return out


def srgb_from_linear(colours: np.ndarray) -> np.ndarray:
    """(n, 3 | 4) float64: glTF's linear COLOR_0 values (in [0, 1]) sRGB-encoded, as a mesh file holds its colours;
    alpha as it is.  The inverse of :func:`linear_from_srgb`."""
    out = np.clip(np.array(colours, np.float64), 0.0, 1.0)
    c = out[:, :3]
    out[:, :3] = np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)
    return out


def _obj_parts(positions, vt, vn, colours, corners, face_material, notices, materials) -> list:
    """One :class:`Part` per material (faces of no material last): a glTF vertex per distinct corner triple.
    ``positions`` (p, 3), ``vt`` (t, 1..3), ``vn`` (n, 3) float64, ``colours`` (p, 3|4) in [0, 1] or None (sRGB:
    COLOR_0 gets them linear, :func:`linear_from_srgb`);
    ``corners`` (3m, 3) int64 (position, texture coordinate, normal; -1 none); ``face_material`` (m,) int64
    indices into ``materials`` (the notices name them), -1 none."""
    parts = []

    def _part_name(key: int) -> str:
        return "the faces of no material" if key < 0 else f"the faces of material {materials[key].name!r}"

    keys = np.unique(face_material).tolist()
    used = np.zeros(len(positions), bool)  # the positions some kept face names
    for key in keys[1:] + keys[:1] if keys[0] < 0 else keys:
        tri = np.flatnonzero(face_material == key)
        c = corners.reshape(-1, 3, 3)[tri].reshape(-1, 3)
        degenerate = ((c[0::3, 0] == c[1::3, 0]) | (c[1::3, 0] == c[2::3, 0]) | (c[0::3, 0] == c[2::3, 0]))
        if degenerate.any():
            notices.append(f"dropped {int(degenerate.sum())} degenerate faces")
            c = c.reshape(-1, 3, 3)[~degenerate].reshape(-1, 3)
        if not len(c):
            continue
        used[c[:, 0]] = True
        attrs = {}
        has_uv = bool(len(vt)) and (c[:, 1] >= 0).any()
        has_normal = bool(len(vn)) and (c[:, 2] >= 0).any()
        if has_normal and (c[:, 2] < 0).any():
            notices.append(f"normals left out of {_part_name(key)}: {int((c[:, 2] < 0).sum()):,} corners name none")
            has_normal = False
        if has_uv and (c[:, 1] < 0).any():
            notices.append(f"{int((c[:, 1] < 0).sum()):,} corners of {_part_name(key)} name no texture "
                           "coordinate: given (0, 0)")
        c = np.where(np.array([True, has_uv, has_normal])[None, :], c, -1)
        unique, inverse = _unique_corners(c)
        if has_normal:
            locked, count = _seam_corners(unique)
            if locked > HARD_NORMALS_SHARE * count:  # hard edges everywhere: carried, nothing would stream
                plain = np.where(np.array([True, True, False])[None, :], c, -1)
                unique_plain, inverse_plain = _unique_corners(plain)
                if _seam_corners(unique_plain)[0] < locked:
                    notices.append(f"normals not carried in {_part_name(key)}: their hard edges would keep {locked:,} "
                                   f"of its {count:,} positions in the base (seam corners); viewers shade it "
                                   "from its positions, flat")
                    c, unique, inverse, has_normal = plain, unique_plain, inverse_plain, False
        if has_uv:
            uv = np.where(unique[:, 1:2] >= 0, vt[np.maximum(unique[:, 1], 0), :2], 0.0)
            if vt.shape[1] == 1 or np.isnan(uv).any():  # a vt of one value: v is 0
                uv = np.nan_to_num(uv, nan=0.0)
            attrs["TEXCOORD_0"] = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1)
        if has_normal:
            n = vn[unique[:, 2]]
            length = np.linalg.norm(n, axis=1, keepdims=True)
            if (length < 1e-12).any() or not np.isfinite(length).all():
                notices.append(f"normals left out of {_part_name(key)}: some are zero or not finite")
            else:
                attrs["NORMAL"] = n / length
        if colours is not None:
            attrs["COLOR_0"] = linear_from_srgb(colours[unique[:, 0]])
        parts.append(Part(positions[unique[:, 0]], inverse.reshape(-1, 3), attrs, None if key < 0 else key))
    if parts and not used.all():  # as the geometry reader says it (checked_mesh's cleanup)
        notices.append(f"dropped {int((~used).sum())} unreferenced vertices")
    return parts


#: Normals that leave more than this share of a primitive's positions as seam corners (three or more glTF
#: vertices at one position, which stay in the base: a CAD part's hard edges, a normal per face around each
#: corner) are not carried, with a notice: the primitive would not stream (pybullet's a1 thigh.obj: 1,931 of
#: 1,954 positions).  Smooth normals, and a few creases, ride (a scan's: none; a soccer ball's: 1.3%).
HARD_NORMALS_SHARE = 0.25


def _seam_corners(unique: np.ndarray) -> tuple:
    """``(positions carrying three or more of the glTF vertices unique (u, 3), positions)``."""
    _, copies = np.unique(unique[:, 0], return_counts=True)
    return int((copies >= 3).sum()), len(copies)


def _unique_corners(c: np.ndarray) -> tuple:
    """``(unique (u, 3) int64, inverse (c,) int64)`` of the corner triples ``c`` (c, 3) int64 (-1 for none), as
    ``np.unique(c, axis=0, return_inverse=True)`` gives them, through two 1-D uniques of int64 keys (~4x faster
    than sorting rows).  A column equal to the position's (a PLY's texture coordinates and normals, which are
    its vertices') is left out of the keys, and keys of a small range are made unique through a table
    (:func:`_unique_keys`): a 1M-vertex coloured PLY's corners in 0.1 s instead of 1.4."""
    same = [j for j in (1, 2) if np.array_equal(c[:, j], c[:, 0])]
    t, n = (np.full(len(c), -1, np.int64) if j in same else c[:, j] for j in (1, 2))
    t_span, n_span = int(t.max()) + 2, int(n.max()) + 2
    pairs, first = _unique_keys(c[:, 0] * t_span + (t + 1))
    keys, inverse = _unique_keys(first * n_span + (n + 1))
    pair = pairs[keys // n_span]
    unique = np.stack([pair // t_span, pair % t_span - 1, keys % n_span - 1], axis=1)
    unique[:, same] = unique[:, :1]
    return unique, inverse


def _unique_keys(keys: np.ndarray) -> tuple:
    """``np.unique(keys, return_inverse=True)`` (the inverse flat) of non-negative int64 ``keys``: through a
    table of their range where it is at most four times their count (no sort), else numpy's."""
    top = int(keys.max())
    if top < 4 * len(keys) + 1024:
        seen = np.zeros(top + 1, bool)
        seen[keys] = True
        return np.flatnonzero(seen), (np.cumsum(seen) - 1)[keys]
    values, inverse = np.unique(keys, return_inverse=True)
    return values, inverse.reshape(-1)


# -- PLY ----------------------------------------------------------------------------------------------------


def _ply_appearance(path: str, name: str) -> tuple:
    """:func:`read_appearance` of a PLY: its header decides (:func:`~pmwm_codec.ply.header_look`), so a PLY
    of geometry alone is read once, by :func:`~pmwm_codec.mesh.read_mesh`; a header that does not parse is
    left to it to name."""
    from .mesh import _check_ply_header
    from .ply import header_look
    from .sources import read_regular_file

    with open(path, "rb") as fh:
        head = fh.read(1 << 16)
    try:
        look = header_look(head, name)
    except InputFormatError:
        return None, []
    if not look.appearance:
        notices = [_NORMALS_LEFT.format("nx, ny, nz")] if look.normal else []
        notices += [_FACE_COLOURS_LEFT] if look.face_colour else []
        notices += [f"the texture {_shown(t)} not carried: the PLY has no texture coordinates" for t in look.textures]
        return None, notices
    _check_ply_header(path, name)
    return ply_document(path, read_regular_file(path, MAX_INPUT_FILE_BYTES, InputFormatError, name))


def _ply_texture_files(path: str) -> list:
    """The texture file names in the header of the PLY at ``path`` when it has texture coordinates to map
    them, else none (nor for a header that does not parse)."""
    from .ply import header_look

    try:
        with open(path, "rb") as fh:
            look = header_look(fh.read(1 << 16), path)
    except (InputFormatError, OSError):
        return []
    return look.textures if look.uv or look.wedge else []


def ply_document(path, data: bytes) -> tuple:
    """``((gltf, buffers), notices)`` of the PLY file ``data`` (at ``path``) that carries appearance
    (:func:`pmwm_codec.ply.read_appearance`): vertex colours as COLOR_0, texture coordinates -- per vertex,
    or per face corner (a face's ``texcoord`` list, each distinct (vertex, coordinate) pair a glTF vertex, as
    an OBJ's corners are) -- as TEXCOORD_0, normals as NORMAL (here only: alone they do not make the PLY an
    asset).  The textures ``comment TextureFile`` lines name become one material each, read through
    :class:`Resources`; a face's ``texnumber`` picks its material (one primitive each; out of range: none),
    else every face has the first.  InputFormatError or MeshError (one line) as
    :func:`~pmwm_codec.mesh.read_mesh` refuses the file."""
    from .mesh import mesh_arrays
    from .ply import read_appearance as read_ply_appearance

    name = os.path.basename(path)
    ply = read_ply_appearance(data, name, MAX_ENCODE_FACES)
    positions, faces = mesh_arrays(ply.positions, ply.faces, name)
    notices: list = [_FACE_COLOURS_LEFT] if ply.face_colour else []
    vertex = faces.reshape(-1)
    vt, uv_ids = np.zeros((0, 2)), np.full(len(vertex), -1, np.int64)
    if ply.wedge is not None:
        if ply.uv is not None:
            notices.append("the vertices' texture coordinates left out: the faces' texcoord lists are read")
        pairs = ply.wedge.reshape(-1, 2)
        none = np.isnan(pairs).any(axis=1)
        pairs = np.where(none[:, None], 0.0, pairs) + 0.0  # (+ 0.0: -0.0 is 0.0)
        vt, first, uv_ids = np.unique(np.ascontiguousarray(pairs).view(np.complex128).reshape(-1),
                                      return_index=True, return_inverse=True)
        vt, uv_ids = pairs[first], np.where(none, -1, uv_ids.reshape(-1))
    elif ply.uv is not None:
        vt, uv_ids = ply.uv, vertex
    normal_ids = vertex if ply.normals is not None else np.full(len(vertex), -1, np.int64)
    materials, face_material = [], np.full(len(faces), -1, np.int64)
    if ply.textures and not len(vt):
        notices += [f"the texture {_shown(t)} not carried: the PLY has no texture coordinates" for t in ply.textures]
    elif ply.textures:
        materials = [Material(os.path.splitext(os.path.basename(t))[0] or f"texture {i}",
                              texture_file=t) for i, t in enumerate(ply.textures)]
        if ply.texnumber is None:
            face_material[:] = 0
            notices += [f"the texture {_shown(t)} not carried: no face names it (no texnumber)"
                        for t in ply.textures[1:]]
        else:
            named = (ply.texnumber >= 0) & (ply.texnumber < len(materials))
            face_material = np.where(named, ply.texnumber, -1)
            if not named.all():
                notices.append(f"{int((~named).sum()):,} triangles name no texture of the "
                               f"{len(materials)} the header names: left without one")
    corners = np.stack([vertex, uv_ids, normal_ids], axis=1)
    parts = _obj_parts(positions, vt, ply.normals if ply.normals is not None else np.zeros((0, 3)), ply.colours,
                       corners, face_material, notices, materials)
    if not parts:  # faces were read (else MeshError before), and every one was dropped
        raise DegenerateMeshError(f"{name}: every triangle is degenerate")
    return _document(parts, materials, Resources(path, notices), name), notices
