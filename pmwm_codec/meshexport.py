"""A decoded asset's scene written as an OBJ (with its MTL and textures), a PLY or an OFF that keeps its appearance.

The mirror of :mod:`pmwm_codec.meshdoc`, which reads those files as glTF documents: ``pmw decode -o X.obj``
(or ``.ply``) of a ``.pmw`` whose scene has texture coordinates, normals, vertex colours or materials writes
them, where :func:`pmwm_codec.meshio.write_mesh` writes positions and faces alone.

:func:`scene_parts` flattens the document as glTF converters do: every triangle primitive of every mesh the
default scene shows (and of each progressive mesh it does not show: as stored, with a notice), placed once per
node that shows it (positions by the world matrix, normals by its inverse
transpose, the winding reversed under a mirroring one), as :class:`Showing` s of
:class:`~pmwm_codec.meshdoc.Part` s, with the materials mapped onto :class:`~pmwm_codec.meshdoc.Material` (the
base colour, its alpha where ``alphaMode`` blends (where it masks: 1 or 0, as the alpha reaches ``alphaCutoff`` or
not, a mask being opaque where drawn), the roughness, the emission, the base colour, normal and emissive
textures) and the images those use.  What such a file cannot hold (another texture set than the first, a texture
transform, metallic-roughness and occlusion textures, a material's ``doubleSided`` and its extensions:
KHR_materials_clearcoat, _transmission, _pbrSpecularGlossiness ...; in a PLY the materials themselves) is left
out with a notice.

:func:`write_scene` writes the files as one set (:func:`~pmwm_codec.atomic.write_set`: all or none):

``X.obj``
    ``mtllib X.mtl``; one ``o`` group per showing; ``v`` records welded within a showing (one per distinct
    float32 position -- and colour, when the file has colours: ``v x y z r g b``, sRGB-encoded as mesh files hold
    them, the inverse of the reading: :func:`~pmwm_codec.meshdoc.srgb_from_linear`), ``vt`` (``u, 1 - v``: OBJ's
    ``v`` grows upwards, glTF's downwards) and ``vn`` records, each distinct value once, and ``usemtl`` /
    ``f p/t/n`` records per part (``p``, ``p/t``, ``p//n`` as the part has them);
``X.mtl``
    one ``newmtl`` per material used: ``Kd`` (base colour), ``d`` (alpha), ``Ns`` (``1000 (1 - roughness)^2``,
    the inverse of the reader's mapping), ``Pr`` / ``Pm`` (the PBR extension Blender reads), ``map_Kd``,
    ``map_Bump``, and, for a material that emits light, ``Ke`` (``emissiveFactor`` times
    ``KHR_materials_emissive_strength``) and ``map_Ke`` (``emissiveTexture``).  ``Kd`` and ``Ke`` hold glTF's
    linear factors as they are (as Blender's importer takes them, and as :mod:`pmwm_codec.meshdoc` reads them
    back; three.js's MTLLoader takes them as sRGB);
``X.ply``
    binary little-endian, one vertex per glTF vertex (a PLY vertex has one value of each property): ``x y z``,
    then ``nx ny nz`` (when every part has normals), ``s t`` (``u, 1 - v``; 0 where a part has none) and
    ``red green blue alpha`` (uchar, sRGB-encoded; white where a part has none, glTF's default) as the scene has
    them, faces
    ``vertex_indices`` and, when the faces use more than one texture, ``texnumber`` (MeshLab's index into the
    ``comment TextureFile`` lines; -1: none);
``X.off``
    the showings welded as an OBJ's ``v`` records are; ``COFF`` with each vertex's sRGB-encoded colour (``r g b
    a`` in 0..1, six decimals) when the scene has colours, else ``OFF``; no file beside it;
``X_<k>.<ext>``
    image ``k`` of the document, byte for byte (``.png``, ``.jpg``, ``.webp``, ``.ktx2`` ... by its media type).

Every file name derives from the one the caller gave (never from a name inside the input); the caller checks
them (:func:`sidecar_paths`).  Arrays: positions (n, 3) float64 in, float32 out; faces (m, 3) int64.
"""

from __future__ import annotations

import io
import os
import re
from itertools import chain
from dataclasses import dataclass, field

import numpy as np

from .format.document import (morphed, primitive_triangles, read_accessor, renormalized, shown_weights,
                               sniff_image)
from .format.gltf import (
    TRIANGLE_MODES, TRIANGLES, find_extension_primitives, item, placements_by_mesh, view_bytes, world_placements,
)
from .constants import EXTENSION_NAME, MAX_WRITTEN_IMAGES
from .errors import InputFormatError, OptionError
from .meshio import text_rows
from .meshdoc import EMISSIVE_STRENGTH, Material, Part, srgb_from_linear

__all__ = ["Scene", "Showing", "progressive_meshes", "scene_parts", "shows_appearance", "sidecar_paths",
           "write_scene"]

#: The vertex attributes an OBJ or PLY can carry (glTF semantics).
CARRIED = ("NORMAL", "TEXCOORD_0", "COLOR_0")
GENERATOR = "pmwm_codec (pmw decode)"
_EXTENSIONS = {"image/png": ".png", "image/jpeg": ".jpg", "image/webp": ".webp", "image/ktx2": ".ktx2",
               "image/avif": ".avif", "image/vnd-ms.dds": ".dds"}


@dataclass
class Showing:
    """One mesh of the document as one node shows it: ``name`` and its triangle ``parts`` in world coordinates."""

    name: str
    parts: list = field(default_factory=list)


@dataclass
class Scene:
    """:func:`scene_parts`' result: ``showings``, ``materials`` (:class:`~pmwm_codec.meshdoc.Material`, their
    ``texture`` / ``normal_texture`` indices into ``images``), ``images`` (``(bytes, media type)``) and
    ``notices`` (what the files will not hold)."""

    showings: list
    materials: list
    images: list
    notices: list


def shows_appearance(gltf: dict | None) -> bool:
    """Whether a triangle primitive of ``gltf`` (a ``.pmw``'s document, its JSON alone) that an OBJ or PLY of it
    holds (:func:`_written_primitives`, its progressive meshes among them) has a material or an attribute of
    :data:`CARRIED`: what such a file should hold beyond geometry."""
    if not gltf:
        return False
    for _, prim in _written_primitives(gltf, progressive_meshes(gltf)):
        if "material" in prim or any(s in prim.get("attributes", {}) for s in CARRIED):
            return True
    return False


def progressive_meshes(gltf: dict | None) -> list:
    """The indices of the meshes of a ``.pmw``'s document (its JSON) that hold a progressive primitive."""
    return sorted({mi for mi, _, _ in find_extension_primitives(gltf, EXTENSION_NAME)}) if gltf else []


def _written_primitives(gltf: dict, also=()):
    """``(mesh index, primitive)`` of every triangle primitive with a POSITION of the meshes an OBJ or PLY of
    ``gltf`` holds: those the scene shows (every mesh of a document without nodes) and those ``also`` names (a
    ``.pmw``'s progressive meshes, held shown or not, as
    :func:`~pmwm_codec.stream.asset.scene_as_shown` holds them)."""
    meshes = gltf.get("meshes")
    shown = set(placements_by_mesh(gltf)) | set(also) if gltf.get("nodes") else None
    for mi, mesh in enumerate(meshes if isinstance(meshes, list) else []):
        if shown is not None and mi not in shown:
            continue
        prims = mesh.get("primitives") if isinstance(mesh, dict) else None
        for prim in prims if isinstance(prims, list) else []:
            if isinstance(prim, dict) and prim.get("mode", TRIANGLES) in TRIANGLE_MODES \
                    and "POSITION" in prim.get("attributes", {}):
                yield mi, prim


def scene_parts(gltf: dict, buffers, also=()) -> Scene:
    """The scene of a decoded, ordinary glTF document (``gltf`` and its ``buffers``, as
    :func:`~pmwm_codec.stream.asset.decode_asset`'s GLB splits into) flattened (module docstring); ``also``: the
    indices of the meshes held whether the scene shows them or not (the ``.pmw``'s progressive meshes,
    :func:`progressive_meshes` of its JSON).

    A document whose placements do not read (GPU instancing, a mesh of ``also`` the scene does not show, a
    scale of zero) gives each mesh once, as stored, with a notice saying why.  InputFormatError when an
    accessor or image of it does not read."""
    notices = []
    written = list(_written_primitives(gltf, also))
    meshes = sorted({mi for mi, _ in written})
    frames, why = world_placements(gltf, meshes)
    if frames is None:
        frames = [[np.eye(4)] for _ in meshes]
        notices.append(f"{why}: the file holds each mesh once, as stored, not placed by the scene's nodes; "
                       "decode to .glb to keep the scene")
    materials, images, material_map = _materials(gltf, buffers, written, notices)
    showings = []
    for mi, matrices in zip(meshes, frames):
        mesh = gltf["meshes"][mi]
        stored = [_part(gltf, buffers, mi, prim, material_map) for m, prim in written if m == mi]
        name = _safe_name(mesh.get("name"), f"mesh_{mi}")
        for k, matrix in enumerate(matrices):
            shown = name if len(matrices) == 1 else f"{name}_{k}"
            showings.append(Showing(shown, [_placed(part, matrix) for part in stored]))
    for semantic, what in (("TEXCOORD_1", "a second texture set (TEXCOORD_1) is left out: an OBJ or PLY holds one set"),
                           ("COLOR_1", "a second colour set is left out: an OBJ or PLY holds one set"),
                           ("JOINTS_0", "skin joints and weights (JOINTS_n, WEIGHTS_n) are left out: an OBJ or PLY "
                                        "holds none")):
        if any(semantic in prim.get("attributes", {}) for _, prim in written):
            notices.append(what)
    return Scene(showings, materials, images, notices)


def _part(gltf: dict, buffers, mi: int, prim: dict, material_map: dict) -> Part:
    attrs = prim["attributes"]
    weights = shown_weights(gltf, mi, prim) or []  # posed as a viewer draws it at rest (stream.asset.posed_notes)
    positions, faces = primitive_triangles(gltf, buffers, prim, f"mesh {mi}: a primitive", weights)
    carried = {}
    for semantic in CARRIED:
        if semantic in attrs:
            values = read_accessor(gltf, buffers, attrs[semantic]).astype(np.float64)
            if any(weights):  # displaced by the targets as a viewer draws it (glTF 2.0 3.7.2.2)
                values = morphed(gltf, buffers, prim, semantic, values, weights)
                if semantic == "NORMAL":  # of unit length again, as a viewer shades
                    values = renormalized(values)
                elif semantic == "COLOR_0":  # a colour a viewer shows: clamped to [0, 1]
                    values = values.clip(0.0, 1.0)
            if len(values) != len(positions):
                raise InputFormatError(f"mesh {mi}: {semantic} has {len(values)} values for {len(positions)} vertices")
            if not np.isfinite(values).all():  # an OBJ or PLY of it would not read back (nan, inf)
                raise InputFormatError(f"mesh {mi}: a {semantic} value is not finite (NaN or infinite)")
            carried[semantic] = values
    if "COLOR_0" in carried and carried["COLOR_0"].shape[1] == 3:
        carried["COLOR_0"] = np.hstack([carried["COLOR_0"], np.ones((len(positions), 1))])
    return Part(positions, faces, carried, material_map.get(prim.get("material")))


def _placed(part: Part, matrix: np.ndarray) -> Part:
    """``part`` moved by the world ``matrix`` (4, 4): positions by it, normals by its inverse transpose
    (renormalised), the winding reversed where it mirrors."""
    if np.array_equal(matrix, np.eye(4)):
        return part
    linear = matrix[:3, :3]
    attrs = dict(part.attributes)
    if "NORMAL" in attrs:
        n = attrs["NORMAL"] @ np.linalg.inv(linear)  # (inverse transpose) applied to row vectors
        length = np.linalg.norm(n, axis=1, keepdims=True)
        attrs["NORMAL"] = np.divide(n, length, out=np.zeros_like(n), where=length > 0)
    faces = part.indices[:, [0, 2, 1]] if np.linalg.det(linear) < 0 else part.indices
    return Part(part.positions @ linear.T + matrix[:3, 3], faces, attrs, part.material)


def _materials(gltf: dict, buffers, written: list, notices: list) -> tuple:
    """``(materials, images, {glTF material index: index into materials})`` of the materials some primitive
    of ``written`` (``(mesh index, primitive)``) uses, and the images they name (each once)."""
    doc_materials = _array(gltf, "materials")
    used = set()
    for mesh, prim in written:
        if "material" in prim:  # an index past the materials (or -1, which would pick the last) is no material
            item(doc_materials, prim["material"], f"mesh {mesh}: a primitive's material", error=InputFormatError)
            used.add(prim["material"])
    materials, images, image_map, material_map, names = [], [], {}, {}, {"default"}  # default: see _mtl_text
    left = set()

    def image_of(ref, what: str):
        if ref is None:
            return None
        if not isinstance(ref, dict):
            raise InputFormatError(f"{what}: not a texture reference object")
        texture = item(_array(gltf, "textures"), ref.get("index"), f"{what}: texture", error=InputFormatError)
        if ref.get("texCoord", 0) != 0:
            left.add(f"{what} is left out: it reads a second texture set")
            return None
        if "KHR_texture_transform" in _object(ref, "extensions", what):
            left.add(f"{what}'s transform (KHR_texture_transform) is left out: an MTL cannot say it")
        source = _image_source(gltf, texture, what)
        if source is None:
            left.add(f"{what} is left out: its texture names no image")
            return None
        if source not in image_map and len(images) >= MAX_WRITTEN_IMAGES:
            left.add(f"textures past the first {MAX_WRITTEN_IMAGES} are left out (at most that many files are "
                     "written beside the output)")
            return None
        if source not in image_map:
            image = gltf["images"][source]
            if "bufferView" not in image:  # a file it names (uri): an input never makes decode read one
                left.add(f"{what} is left out: its image is not in the file (a uri, which decode does not read)")
                return None
            _, raw = view_bytes(gltf, buffers, image["bufferView"], f"images[{source}]", error=InputFormatError)
            blob = bytes(raw)
            declared = image.get("mimeType") if isinstance(image.get("mimeType"), str) else None
            kind = sniff_image(blob) or declared or "application/octet-stream"  # the bytes name the file's suffix
            image_map[source] = len(images)
            images.append((blob, kind))
        return image_map[source]

    for mi in sorted(used):
        mat = doc_materials[mi]
        where = f"materials[{mi}]"
        pbr = _object(mat, "pbrMetallicRoughness", where)
        where += ".pbrMetallicRoughness"
        color = _factor(pbr, "baseColorFactor", [1.0, 1.0, 1.0, 1.0], where)
        mode = mat.get("alphaMode", "OPAQUE")
        if mode == "OPAQUE":
            color[3] = 1.0
        elif mode == "MASK":  # glTF 3.9.4: drawn opaque where the alpha reaches alphaCutoff, else not drawn at all
            color[3] = 1.0 if color[3] >= _factor(mat, "alphaCutoff", 0.5, f"materials[{mi}]") else 0.0
        name = _safe_name(mat.get("name"), f"material_{mi}")
        while name in names:
            name = f"{name}_{mi}"
        names.add(name)
        if mode == "MASK" and color[3] == 1.0 and "baseColorTexture" in pbr:
            left.add(f"material {name}'s alpha mask (alphaMode MASK) is left out: an MTL has no cutoff, so its "
                     "texture's alpha cuts nothing out")
        out = Material(name, tuple(color), _factor(pbr, "roughnessFactor", 1.0, where),
                       metallic=_factor(pbr, "metallicFactor", 1.0, where))
        out.texture = image_of(pbr.get("baseColorTexture"), f"material {name}'s base colour texture")
        out.normal_texture = image_of(mat.get("normalTexture"), f"material {name}'s normal texture")
        out.emissive = tuple(_emission(mat, f"materials[{mi}]"))
        out.emissive_texture = image_of(mat.get("emissiveTexture"), f"material {name}'s emissive texture")
        for holder, key, what in ((pbr, "metallicRoughnessTexture", "metallic-roughness texture"),
                                  (mat, "occlusionTexture", "occlusion texture")):
            if key in holder:
                left.add(f"material {name}'s {what} is left out: an MTL has no place for it")
        if mat.get("doubleSided") is True:
            left.add(f"material {name} is double-sided (doubleSided): an MTL cannot say so, and a viewer that culls "
                     "back faces (three.js) hides its inside (decode to .glb to keep it)")
        extensions = sorted(set(_object(mat, "extensions", f"materials[{mi}]")) - {EMISSIVE_STRENGTH})  # (in Ke)
        if extensions:  # clearcoat, transmission, unlit ...
            left.add(f"material {name}'s {', '.join(extensions)} "
                     + ("is left out: an MTL cannot say it" if len(extensions) == 1 else
                        "are left out: an MTL cannot say them"))
        material_map[mi] = len(materials)
        materials.append(out)
    notices.extend(sorted(left))
    return materials, images, material_map


def _emission(mat: dict, what: str) -> list:
    """The light a glTF material ``mat`` emits: its ``emissiveFactor`` (linear RGB, default black) times its
    ``KHR_materials_emissive_strength`` ``emissiveStrength`` (default 1), as a viewer draws it."""
    factor = _factor(mat, "emissiveFactor", [0.0, 0.0, 0.0], what)
    strength = _object(_object(mat, "extensions", what), EMISSIVE_STRENGTH, f"{what}.extensions")
    scale = _factor(strength, "emissiveStrength", 1.0, f"{what}.extensions.{EMISSIVE_STRENGTH}")
    return [v * scale for v in factor]


def _image_source(gltf: dict, tex: dict, what: str):
    """The image a texture shows: its core ``source`` (PNG or JPEG), else an extension's (KTX2, WebP ...);
    None when it names none.  InputFormatError when a source it names does not exist."""
    holders = [tex] + [e for e in _object(tex, "extensions", f"{what}: its texture").values() if isinstance(e, dict)]
    for holder in holders:
        if "source" in holder:
            item(_array(gltf, "images"), holder["source"], f"{what}: image", error=InputFormatError)
            return holder["source"]
    return None


def _array(gltf: dict, key: str) -> list:
    """``gltf[key]``, a glTF array ([] when absent); InputFormatError when it is not one."""
    value = gltf.get(key, [])
    if not isinstance(value, list):
        raise InputFormatError(f"the document's {key} is not an array")
    return value


def _object(holder: dict, key: str, what: str) -> dict:
    """``holder[key]``, a JSON object ({} when absent); InputFormatError when it is not one."""
    value = holder.get(key, {})
    if not isinstance(value, dict):
        raise InputFormatError(f"{what}: {key} is not an object")
    return value


def _factor(holder: dict, key: str, default, what: str):
    """A material factor: a number (``default`` a float) or a list of as many numbers (``default`` a list),
    as floats; InputFormatError when it is not."""
    value = holder.get(key, default)
    width = len(default) if isinstance(default, list) else None
    values = value if isinstance(value, list) else [value]
    if (width is None) == isinstance(value, list) or len(values) != (width or 1) \
            or any(isinstance(v, bool) or not isinstance(v, (int, float)) for v in values):
        raise InputFormatError(f"{what}.{key} is {str(value)[:40]!r}, not {f'{width} numbers' if width else 'a number'}")
    out = [float(v) for v in values]
    return out if width else out[0]


def _safe_name(name, fallback: str) -> str:
    """A name an OBJ / MTL record can hold (written as UTF-8, as Blender and three.js read it): each run of
    characters that are white space (a record splits there), not printable, or ``#`` (a comment starts there)
    becomes one ``_``; ``fallback`` for a name left empty or not a string."""
    if not isinstance(name, str):
        return fallback
    kept = "".join(c if c.isprintable() and not c.isspace() and c != "#" else "\0" for c in name)
    name = re.sub("\0+", "_", kept).strip("_")
    return name or fallback


def sidecar_paths(path: str, scene: Scene) -> tuple:
    """``(MTL path or None, [image paths])``: the files besides ``path`` (an ``.obj`` or ``.ply``) that
    :func:`write_scene` writes for ``scene``: the MTL of an OBJ with materials (``X.mtl``), the images
    (``X_<k>.<ext>``, in the order of :func:`_written_images`)."""
    stem, suffix = os.path.splitext(path)
    mtl = stem + ".mtl" if suffix.lower() == ".obj" and _obj_materials(scene) else None
    return mtl, [_image_path(stem, k, kind) for k, (_, kind) in enumerate(_written_images(scene, suffix.lower()))]


def _image_path(stem: str, k: int, kind: str) -> str:
    return f"{stem}_{k}{_EXTENSIONS.get(kind, '.bin')}"


def _obj_materials(scene: Scene) -> bool:
    return any(part.material is not None for s in scene.showings for part in s.parts)


def _written_images(scene: Scene, suffix: str) -> list:
    """The images a file of ``suffix`` holds: every image of an OBJ's materials; a PLY's base colour textures;
    none beside an OFF."""
    if suffix == ".obj":
        return scene.images
    if suffix == ".off":
        return []
    used = sorted({scene.materials[p.material].texture for s in scene.showings for p in s.parts
                   if p.material is not None and scene.materials[p.material].texture is not None})
    return [scene.images[i] for i in used]


def write_scene(path: str, scene: Scene) -> tuple:
    """Write ``scene`` to ``path`` (``.obj``, ``.ply`` or ``.off``) and its :func:`sidecar_paths`, all or none.

    Returns ``(vertices, faces, notices)``: the counts the file holds (an OBJ's or OFF's welded vertices, a
    PLY's vertex elements) and what it leaves out beyond ``scene.notices``."""
    from .atomic import write_set

    suffix = os.path.splitext(path)[1].lower()
    mtl, image_paths = sidecar_paths(path, scene)
    names = [os.path.basename(p) for p in image_paths]
    for named in names + ([os.path.basename(mtl)] if mtl else []):
        why = _unrecordable(named, suffix)
        if why:  # the record naming the file would not name it when read
            raise OptionError(f"{named!r}: the {suffix[1:].upper()} would name this file, and {why} the record "
                              "naming it; give the output another name")
    if suffix == ".obj":
        text, vertices, faces = _obj_text(scene, None if mtl is None else os.path.basename(mtl))
        files, notices = {path: text}, []
        if any("COLOR_0" in p.attributes and (p.attributes["COLOR_0"][:, 3] < 1.0).any()
               for s in scene.showings for p in s.parts):  # a v record's colour is r g b
            notices.append("the vertex colours' alpha is left out: an OBJ's v records hold red, green and blue "
                           "(decode to .ply, .off or .glb to keep it)")
        if mtl is not None:
            files[mtl] = [_mtl_text(scene, names)]
    elif suffix == ".off":
        text, vertices, faces, notices = _off_text(scene)
        files = {path: text}
    elif suffix == ".ply":
        parts, vertices, faces, notices = _ply_parts(scene, names)
        files = {path: parts}
    else:
        raise ValueError(f"write_scene: {suffix!r} is none of .obj, .ply and .off")
    for image_path, (blob, _) in zip(image_paths, _written_images(scene, suffix)):
        files[image_path] = [blob]
    write_set(files)
    return vertices, faces, notices


def _unrecordable(name: str, suffix: str) -> str | None:
    """What keeps a ``mtllib`` / ``map_Kd`` record (``suffix`` .obj) or a PLY's ``comment TextureFile`` line
    from naming the file ``name`` as readers read it, or None: a line break ends the record, another
    character that is not printable (a tab, a vertical tab, U+2028) splits or ends it, white space at either
    end is stripped, in an OBJ or MTL a ``#`` starts a comment, and an OBJ's or MTL's record must read back as
    the name itself (:func:`~pmwm_codec.meshdoc._mtllib_names`, :func:`~pmwm_codec.meshdoc._map_file`: a run of
    spaces is read as one, a backslash as a slash, a first word such as ``-s`` as a map option, a second name
    ending ``.mtl`` as a second MTL file)."""
    if "\n" in name or "\r" in name:
        return "a line break ends"
    if not name.isprintable():
        return "a character that is not printable (a tab, a form feed, a line separator) splits or ends"
    if name != name.strip():
        return "white space at an end of the name is stripped from"
    if suffix == ".obj" and "#" in name:
        return "a # starts a comment in"
    if suffix == ".obj":  # read back as pmw encode reads it: an mtllib record, a map_Kd / map_Bump statement
        from .meshdoc import _map_file, _mtllib_names

        read = _mtllib_names(name) if name.lower().endswith(".mtl") else [_map_file(name.split())]
        if read != [name]:
            return f"it would be read as {' and '.join(map(repr, read))} from"
    return None


def _float32(values: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return np.asarray(values, np.float64).astype(np.float32)


def _unique_rows(rows: np.ndarray) -> tuple:
    """``(unique rows in first-seen order, inverse (n,) int64)`` of a contiguous 2-D array (exact bytes)."""
    rows = np.ascontiguousarray(rows)
    if len(rows) == 0:
        return rows, np.zeros(0, np.int64)
    keys = rows.view(np.dtype((np.void, rows.dtype.itemsize * rows.shape[1]))).ravel()
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    return rows[first[order]], rank[inverse.ravel()].astype(np.int64)


def _welded(showing: Showing, coloured: bool, kind: str, alpha: bool = False) -> tuple:
    """``(rows (v, 3 | 6 | 7) float32, [row of each vertex (n_k,) int64, per part])``: the showing's vertices welded
    (a part's faces into rows: ``maps[k][part.indices]``),
    one row per distinct float32 position (and sRGB-encoded colour, clipped to 0..1, when ``coloured``: white
    for a part without COLOR_0, glTF's default; with its alpha too when ``alpha``: opaque for a VEC3 one), in the
    order first met.  InputFormatError (``kind`` the file) when a coordinate overflows float32."""
    parts = showing.parts
    pos = np.concatenate([_float32(p.positions) for p in parts]) if parts else np.zeros((0, 3), np.float32)
    if not np.isfinite(pos).all():
        raise InputFormatError(f"a coordinate of the decoded mesh overflows the float32 {kind}'s records hold")
    if coloured:
        width = 4 if alpha else 3
        colours = np.concatenate([_float32(srgb_from_linear(p.attributes["COLOR_0"])[:, :width])
                                  if "COLOR_0" in p.attributes else np.ones((len(p.positions), width), np.float32)
                                  for p in parts])
        pos = np.hstack([pos, colours])
    welded, v_of = _unique_rows(pos)
    starts = np.cumsum([0] + [len(p.positions) for p in parts])
    return welded, [v_of[starts[k]:starts[k + 1]] for k in range(len(parts))]


def _off_text(scene: Scene) -> tuple:
    """``(OFF bytes parts (a generator), vertices, faces, notices)``: the scene welded as an OBJ's ``v`` records are (and by alpha),
    ``COFF`` with each vertex's colour (sRGB-encoded, ``r g b a`` in 0..1, six decimals: the same bytes back; ``a``
    COLOR_0's alpha, 1 where it has none) when it has colours; what an OFF cannot hold is left out with a note."""
    coloured = any("COLOR_0" in p.attributes for s in scene.showings for p in s.parts)
    rows, faces, total = [], [], 0
    for showing in scene.showings:
        welded, maps = _welded(showing, coloured, "an OFF", alpha=True)
        faces += [v_of[p.indices] + total for v_of, p in zip(maps, showing.parts)]
        rows.append(welded)
        total += len(welded)
    rows = np.concatenate(rows) if rows else np.zeros((0, 7 if coloured else 3), np.float32)
    faces = np.concatenate(faces) if faces else np.zeros((0, 3), np.int64)
    text = chain([f"{'COFF' if coloured else 'OFF'}\n{len(rows)} {len(faces)} 0\n".encode("ascii")],
                 text_rows("%.9g %.9g %.9g %.6f %.6f %.6f %.6f" if coloured else "%.9g %.9g %.9g", rows),
                 text_rows("3 %d %d %d", faces))
    parts = [p for s in scene.showings for p in s.parts]
    notices = []
    if any(p.material is not None or "TEXCOORD_0" in p.attributes or "NORMAL" in p.attributes for p in parts):
        notices.append("texture coordinates, normals and materials are left out: an OFF holds positions and vertex "
                       "colours (decode to .obj, .ply or .glb to keep them)")
    return text, len(rows), len(faces), notices


def _obj_text(scene: Scene, mtl_name: str | None) -> tuple:
    """``(OBJ bytes parts, v records, f records)`` of ``scene`` (module docstring): the records' arrays are made
    first (the header counts them), their text a block at a time as the file is written
    (:func:`~pmwm_codec.meshio.text_rows`: a generator, never the whole text in memory)."""
    coloured = any("COLOR_0" in p.attributes for s in scene.showings for p in s.parts)
    v_total = vt_total = vn_total = f_total = 0
    body = []  # bytes, or (fmt, rows) of text_rows
    current = None  # the material of the last usemtl: it holds across o records
    for showing in scene.showings:
        body.append(f"o {showing.name}\n".encode("utf-8", "surrogateescape"))
        welded, maps = _welded(showing, coloured, "an OBJ")
        body.append(("v" + " %.9g" * welded.shape[1], welded))
        for part, v_of in zip(showing.parts, maps):
            columns = [(v_of, 1 + v_total)]
            forms = ["%d"]
            if "TEXCOORD_0" in part.attributes:
                uv = _float32(part.attributes["TEXCOORD_0"][:, :2] * [1.0, -1.0] + [0.0, 1.0])
                values, t_of = _unique_rows(uv)
                body.append(("vt %.9g %.9g", values))
                columns.append((t_of, 1 + vt_total))
                vt_total += len(values)
                forms.append("%d")
            if "NORMAL" in part.attributes:
                values, n_of = _unique_rows(_float32(part.attributes["NORMAL"][:, :3]))
                body.append(("vn %.9g %.9g %.9g", values))
                columns.append((n_of, 1 + vn_total))
                vn_total += len(values)
                forms.append("%d" if len(forms) == 2 else "/%d")
            if part.material is not None and part.material != current:
                body.append(f"usemtl {scene.materials[part.material].name}\n".encode("utf-8", "surrogateescape"))
                current = part.material
            elif part.material is None and current is not None:
                body.append(b"usemtl default\n")
                current = None
            corner = "/".join(forms)  # %d, %d/%d, %d//%d or %d/%d/%d
            body.append(("f " + " ".join([corner] * 3), _Corners(part.indices, columns)))
            f_total += len(part.indices)
        v_total += len(welded)
    head = f"# {GENERATOR}: {v_total} vertices, {f_total} faces\n" + (f"mtllib {mtl_name}\n" if mtl_name is not None
                                                                        else "")
    return chain([head.encode("utf-8", "surrogateescape")], *(
        [item] if isinstance(item, bytes) else text_rows(*item) for item in body)), v_total, f_total


class _Corners:
    """The (m, 3 * forms) int64 table of an OBJ part's ``f`` records, corner by corner (position, texture
    coordinate, normal), made a block of rows at a time (:func:`text_rows` slices it) from the part's ``indices``
    ((m, 3) int64, into its vertices) and its ``columns`` (``(record of each vertex (n,) int64, first record's
    number)`` per form): neither the table nor an (m, 3) array per form is held (3 x 48 MB for 2M faces)."""

    def __init__(self, indices: np.ndarray, columns: list):
        self.indices = indices
        self.columns = columns

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, rows: slice) -> np.ndarray:
        corners = self.indices[rows]
        return np.stack([of[corners] + first for of, first in self.columns], axis=2).reshape(-1, 3 * len(self.columns))


def _mtl_text(scene: Scene, image_names: list) -> bytes:
    """The MTL of the materials ``scene``'s parts use (and ``default``, white, when a part has none after one
    that has one), ``image_names[k]`` the file of image ``k``."""
    used = sorted({p.material for s in scene.showings for p in s.parts if p.material is not None})
    out = io.StringIO()
    out.write(f"# {GENERATOR}: {len(used)} materials\n")
    for m in [scene.materials[i] for i in used]:
        r, g, b, a = m.color
        roughness = min(max(m.roughness, 0.0), 1.0)
        out.write(f"\nnewmtl {m.name}\nKa 0 0 0\nKd {r:.6g} {g:.6g} {b:.6g}\nKs 0 0 0\nd {a:.6g}\n"
                  f"Ns {1000.0 * (1.0 - roughness) ** 2:.6g}\nPr {roughness:.6g}\nPm {m.metallic:.6g}\n"
                  "illum 2\n")
        if m.texture is not None:
            out.write(f"map_Kd {image_names[m.texture]}\n")
        if m.normal_texture is not None:
            out.write(f"map_Bump {image_names[m.normal_texture]}\n")
        if any(m.emissive) or m.emissive_texture is not None:  # glTF: the texture times the factor
            out.write("Ke {:.6g} {:.6g} {:.6g}\n".format(*m.emissive))
        if m.emissive_texture is not None:
            out.write(f"map_Ke {image_names[m.emissive_texture]}\n")
    if any(p.material is None for s in scene.showings for p in s.parts):
        out.write("\nnewmtl default\nKd 1 1 1\nd 1\nillum 1\n")
    return out.getvalue().encode("utf-8", "surrogateescape")


def _ply_parts(scene: Scene, image_names: list) -> tuple:
    """``(file parts, vertices, faces, notices)``: the binary PLY of ``scene`` (module docstring)."""
    parts = [p for s in scene.showings for p in s.parts]
    has = {s: any(s in p.attributes for p in parts) for s in CARRIED}
    notices = []
    if has["NORMAL"] and not all("NORMAL" in p.attributes for p in parts):  # a zero normal shades black
        has["NORMAL"] = False
        notices.append("normals are left out: some faces have none, and a PLY vertex has one of each property "
                       "or none (decode to .obj or .glb to keep them)")
    textures = sorted({scene.materials[p.material].texture for p in parts
                       if p.material is not None and scene.materials[p.material].texture is not None})
    texnumber = len(textures) > 1
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    header = ["property float x", "property float y", "property float z"]
    if has["NORMAL"]:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
        header += ["property float nx", "property float ny", "property float nz"]
    if has["TEXCOORD_0"]:
        fields += [("s", "<f4"), ("t", "<f4")]
        header += ["property float s", "property float t"]
    if has["COLOR_0"]:
        fields += [("red", "u1"), ("green", "u1"), ("blue", "u1"), ("alpha", "u1")]
        header += [f"property uchar {c}" for c in ("red", "green", "blue", "alpha")]
    n = sum(len(p.positions) for p in parts)
    m = sum(len(p.indices) for p in parts)
    vert = np.zeros(n, dtype=fields)
    face_fields = [("n", "u1"), ("i", "<u4", (3,))] + ([("tex", "<i4")] if texnumber else [])
    face = np.zeros(m, dtype=face_fields)
    at = fat = 0
    for p in parts:
        k, j = len(p.positions), len(p.indices)
        pos = _float32(p.positions)
        if not np.isfinite(pos).all():
            raise InputFormatError("a coordinate of the decoded mesh overflows the float32 a PLY holds")
        vert["x"][at:at + k], vert["y"][at:at + k], vert["z"][at:at + k] = pos.T
        if has["NORMAL"]:
            for c, col in zip(("nx", "ny", "nz"), p.attributes["NORMAL"][:, :3].T):
                vert[c][at:at + k] = col
        if "TEXCOORD_0" in p.attributes:
            vert["s"][at:at + k] = p.attributes["TEXCOORD_0"][:, 0]
            vert["t"][at:at + k] = 1.0 - p.attributes["TEXCOORD_0"][:, 1]
        if has["COLOR_0"]:
            rgba = srgb_from_linear(p.attributes.get("COLOR_0", np.ones((k, 4))))
            byte = np.rint(rgba * 255.0).astype(np.uint8)
            for c, col in zip(("red", "green", "blue", "alpha"), byte.T):
                vert[c][at:at + k] = col
        face["n"][fat:fat + j] = 3
        face["i"][fat:fat + j] = p.indices + at
        if texnumber:
            tex = scene.materials[p.material].texture if p.material is not None else None
            face["tex"][fat:fat + j] = textures.index(tex) if tex is not None else -1
        at, fat = at + k, fat + j
    lines = ["ply", "format binary_little_endian 1.0", f"comment {GENERATOR}"]
    lines += [f"comment TextureFile {name}" for name in image_names]
    lines += [f"element vertex {n}"] + header + [f"element face {m}", "property list uchar uint vertex_indices"]
    lines += ["property int texnumber"] if texnumber else []
    lines += ["end_header"]
    if any(p.material is not None and (scene.materials[p.material].color != (1.0, 1.0, 1.0, 1.0)
                                       or scene.materials[p.material].normal_texture is not None) for p in parts):
        notices.append("material colours and normal textures are left out: a PLY holds vertex colours and one "
                       "texture per face; decode to .obj or .glb to keep them")
    if any(p.material is not None and (any(scene.materials[p.material].emissive)
                                       or scene.materials[p.material].emissive_texture is not None) for p in parts):
        notices.append("the materials' emission (emissiveFactor, emissiveTexture) is left out: a PLY has no place "
                       "for it; decode to .obj or .glb to keep it")
    return [("\n".join(lines) + "\n").encode("utf-8", "surrogateescape"), vert.view(np.uint8), face.view(np.uint8)], \
        n, m, notices  # (the records' own bytes, not a copy of them)
