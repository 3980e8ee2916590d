"""glTF assets in and out: every triangle primitive progressive, everything else kept.

:func:`encode_asset` reads a ``.glb`` / ``.gltf`` (or an in-memory ``(gltf, buffers)``),
makes every *eligible* triangle primitive progressive, and carries the rest of the
document over unchanged: materials, textures, images (external ones embedded),
samplers, the node tree with names and transforms, scenes, cameras, skins,
animations, ``extras`` and extensions it does not know.

Eligible: ``mode`` TRIANGLES, TRIANGLE_STRIP or TRIANGLE_FAN (a strip or fan becomes the list of
triangles it draws, :func:`~pmwm_codec.format.gltf.triangle_list`, its restarts dropped; the ``.pmw``
stores TRIANGLES), a POSITION, no morph ``targets``.  Draco-compressed input primitives are decoded first
(attributes looked up by their Draco unique ids).  Any other primitive
(points, lines, morphs; triangles that are all degenerate) passes
through untouched, with a notice.  A skinned primitive is made progressive like any other: its
``JOINTS_n`` ride as exact integers (written back with their componentType, in the base too) and its
``WEIGHTS_n`` on the grid of step 2^-24 from 0, so that every level's weights still sum to 1
(:func:`~pmwm_codec.stream.encoder._attribute_grid`).  Invalid data is never passed through: an
eligible primitive goes through :func:`~pmwm_codec.mesh.checked_mesh` as a mesh
file does, and a face index out of range or a NaN position refuses the asset
with an error naming the primitive.
Every other vertex attribute (NORMAL, TANGENT, TEXCOORD_n, COLOR_n, custom)
rides with the splits on its own integer grid.

Triangle soups.  A primitive whose every face corner is its own vertex (non-indexed,
or indices naming each vertex once) has its exact duplicate vertices (the same
position and the same value of every attribute) welded first (:func:`_welded`),
keeping the first of each and the vertex order; the decoded primitive has the welded
vertices (indexed), and a notice says how many were welded.  Indexed primitives are
kept as stored.

Flat shading.  A primitive whose NORMAL is every face's own normal (and that has no TANGENT)
has it dropped and its copies welded (:func:`flat_normals`): glTF viewers compute flat normals
for a primitive without NORMAL, so it looks the same, and it streams (with a copy of each
position per face around it, it stayed whole in the base).

Seams.  glTF vertices are already split where UVs or normals jump; the copies
share a position.  Inside one primitive the simplifier collapses both sides of a
seam together, in the same batch (:mod:`~pmwm_codec.progressive.seams`), so both
sides have identical positions at every level of detail (no cracks).  Copies are
found on the position grid (:func:`~pmwm_codec.progressive.seams.grid_weld`): a
seam whose sides differ by float noise is one seam.  A vertex
that coincides in the scene with a vertex of another *primitive* (a border between
primitives: of one glTF mesh, or of meshes whose nodes place them to meet) is locked: it
stays in the base mesh.  Collapses elsewhere may still land *on* seam or border vertices (the kept vertex
never moves).

:func:`decode_asset` turns a ``.pmw`` (whole or cut) back into an ordinary GLB
at any level: the same document with each progressive primitive's geometry
replaced by plain accessors for that level and the extension removed;
:func:`scene_as_shown` gives a level as one mesh placed as the scene shows it
(for OBJ, PLY and STL, which carry no nodes).
"""

from __future__ import annotations

import copy
import json
import os

import numpy as np

from ..constants import EXTENSION_NAME
from ..errors import DegenerateMeshError, FormatError, InputFormatError, MeshError
from ..format.document import (as_declared, primitive_triangles, renormalized, shown_weights, triangle_faces,
                               view_sites)
from ..format.document import (check_document, check_rig_data, is_progressive, label_images, load_document,
                               progressive_refusal, read_accessor, repack, texture_scales)
from ..format.document import strip_image_profiles as _strip_profiles
from ..format.glb import glb_parts
from ..format.meshopt import decompress as decompress_meshopt
from ..format.gltf import (
    ARRAY_BUFFER,
    DRACO_EXTENSION,
    ELEMENT_ARRAY_BUFFER,
    FLOAT,
    POINT_AND_LINE_MODES,
    QUANTIZATION_EXTENSION,
    TRIANGLE_MODES,
    TRIANGLES,
    UNSIGNED_INT,
    BufferBuilder,
    find_extension_primitives,
    item as gltf_item,
    forget_extension,
    place,
    placed_by_nodes,
    placements_by_mesh,
    scene_mesh,
    skinned_meshes,
    uses_extension,
    uses_quantization,
    world_placements,
    view_bytes,
)
from ..mesh import Mesh, checked_mesh, weld_duplicates, weld_soup
from ..http import read_declared
from .cut import data_not_arrived
from .decoder import StreamDecoder
from .encoder import EncodeReport, PrimitiveJob, encode_document
from .encoder import FLOAT32_EXACT_INTEGERS, SCENE_TOLERANCE
from ..format.gltf import COMPONENT_DTYPES

ASSET_SUFFIXES = (".glb", ".gltf")


def is_asset_path(path) -> bool:
    return isinstance(path, (str, os.PathLike)) and os.fspath(path).lower().endswith(ASSET_SUFFIXES)


#: How many pass-through reasons the "no triangle primitive" error quotes.
_REASONS_QUOTED = 3


class _PassThrough(Exception):
    """A valid primitive that is not made progressive; the message names it and says why."""


def plan_asset(gltf: dict, buffers, name: str | None = None, *, keep_flat_normals: bool = False) -> tuple:
    """Split a document's primitives into progressive jobs and pass-throughs.

    Returns ``(jobs: list[PrimitiveJob], drop_accessors: set, notices: list[str])``.

    A primitive that is valid but not made progressive (points, lines, strips,
    morphs, triangles that are all degenerate, Draco data with attributes
    outside the Draco stream) passes through with a notice.  A triangle primitive
    whose data is invalid (face index out of range, NaN/inf positions, an index
    count that is not a multiple of 3, an accessor that cannot be read, Draco data
    that does not decode ...: what :func:`~pmwm_codec.mesh.checked_mesh` refuses in
    a mesh file) is refused: :class:`MeshError` / :class:`InputFormatError` naming
    the primitive (after ``name``, the file's, when given).  So is an asset with no
    primitive to make progressive (:class:`MeshError` quoting why).  ``keep_flat_normals``: a flat-shaded
    primitive keeps its NORMAL (:func:`_welded`), and its copies, in the base.
    """
    jobs, notices, reasons = [], [], []
    users = {i: 1 for i in _accessors_outside_meshes(gltf)}  # accessor -> number of users kept as they are
    candidates = []

    def pass_through(prim, reason):
        reasons.append(reason)
        notices.append(f"{reason}; passed through unchanged")
        for idx in list(prim.get("attributes", {}).values()) + ([prim["indices"]] if "indices" in prim else []):
            users[idx] = users.get(idx, 0) + 1
        for target in prim.get("targets", []):
            for idx in target.values():
                users[idx] = users.get(idx, 0) + 1

    for mi, mesh in enumerate(gltf.get("meshes", [])):
        for pi, prim in enumerate(mesh.get("primitives", [])):
            why = _why_not(prim)
            where = f"mesh {mi}" + (f" ({mesh['name']})" if mesh.get("name") else "") + f" primitive {pi}"
            if why is None:
                candidates.append((mi, pi, prim, where))
            else:
                pass_through(prim, f"{where}: {why}")

    by_mesh = {}
    for mi, pi, prim, where in candidates:
        try:
            mesh, welded, flat = _primitive_mesh(gltf, buffers, prim, where, keep_flat_normals)
        except _PassThrough as exc:
            pass_through(prim, str(exc))
            continue
        except (MeshError, InputFormatError) as exc:
            if name:
                raise type(exc)(f"{name}: {exc}") from None
            raise
        if flat:
            notices.append(f"{where}: flat shaded (every NORMAL is its face's normal): NORMAL dropped, so that "
                           f"glTF viewers compute the same flat normals at every level, and {welded} copies welded; "
                           f"it decodes with {mesh.vertex_count} vertices, without NORMAL")
        elif welded:
            notices.append(f"{where}: {welded} duplicate vertices (same position and attributes) welded; it decodes "
                           f"with {mesh.vertex_count} vertices")
        dropped = [f"{v:,} {k.replace('_', ' ')}" for k, v in mesh.cleanup.items() if v]
        if dropped:  # as a mesh file's reader says it (pmwm_codec.encode): they had gone without a word
            notices.append(f"{where}: dropped " + " and ".join(dropped))
        job = PrimitiveJob(mesh, mi, pi, texture_scales=texture_scales(gltf, prim))
        jobs.append(job)
        by_mesh.setdefault(mi, []).append(job)
    if not jobs:
        why = "; ".join(reasons[:_REASONS_QUOTED])
        if len(reasons) > _REASONS_QUOTED:
            why += f"; {len(reasons) - _REASONS_QUOTED} more"
        if not why:  # nothing passed through: say what the document holds instead
            why = "it has no mesh" if not gltf.get("meshes") else "its meshes have no primitive"
        raise MeshError(f"{name + ': ' if name else ''}the asset has no triangle primitive that can be made "
                        f"progressive ({why})")
    _lock_shared_positions(gltf, jobs)

    drop = set()
    for job in jobs:
        prim = gltf["meshes"][job.mesh_index]["primitives"][job.primitive_index]
        for idx in list(prim.get("attributes", {}).values()) + ([prim["indices"]] if "indices" in prim else []):
            if users.get(idx, 0) == 0:
                drop.add(idx)
    return jobs, drop, notices


def _accessors_outside_meshes(gltf: dict) -> set:
    """The accessors that skins (``inverseBindMatrices``), animation samplers (``input`` / ``output``) and
    ``EXT_mesh_gpu_instancing`` refer to: never dropped with a progressive primitive that shares one (its
    reference came out ``null``)."""
    used = {skin["inverseBindMatrices"] for skin in gltf.get("skins", []) if "inverseBindMatrices" in skin}
    used.update(sampler[key] for anim in gltf.get("animations", []) for sampler in anim.get("samplers", [])
                for key in ("input", "output"))
    for node in gltf.get("nodes", []):
        inst = (node.get("extensions") or {}).get("EXT_mesh_gpu_instancing")
        if isinstance(inst, dict):
            used.update((inst.get("attributes") or {}).values())
    return used


def _why_not(prim: dict):
    if prim.get("mode", TRIANGLES) not in TRIANGLE_MODES:
        shown = POINT_AND_LINE_MODES.get(prim.get("mode"))
        return f"mode {prim.get('mode')}{f' ({shown})' if shown else ''} does not draw triangles"
    if prim.get("mode", TRIANGLES) != TRIANGLES and DRACO_EXTENSION in (prim.get("extensions") or {}):
        return f"a Draco-compressed strip or fan (mode {prim['mode']}) is not made progressive"  # which order its
        # decoded indices take is the extension's to say, not ours to guess
    attrs = prim.get("attributes", {})
    if "POSITION" not in attrs:
        return "no POSITION"
    if prim.get("targets"):
        return "morph targets are not made progressive"
    return None


def _primitive_mesh(gltf, buffers, prim, where, keep_flat_normals: bool = False) -> tuple:
    """``(mesh, welded, flat)``: the primitive's geometry and attributes as a checked :class:`Mesh` (Draco input
    decoded), a triangle soup's exact duplicates welded, or a flat-shaded primitive's after its NORMAL is dropped
    (:func:`_welded`: the glTF vertices of the decoded primitive are the welded ones), how many vertices that
    weld removed and whether NORMAL was dropped.

    Validation is :func:`~pmwm_codec.mesh.checked_mesh`'s, as for a mesh file.  Raises
    :class:`_PassThrough` for a valid primitive that is not made progressive, and
    MeshError / InputFormatError for invalid data; every message starts with ``where``.
    """
    draco = (prim.get("extensions") or {}).get(DRACO_EXTENSION)
    try:
        if draco is not None:
            positions, faces, extra = _draco_arrays(gltf, buffers, prim, draco)
        else:
            positions, faces, extra = _accessor_arrays(gltf, buffers, prim)
    except (_PassThrough, MeshError, InputFormatError) as exc:
        raise type(exc)(f"{where}: {exc}") from None
    try:
        return _welded(checked_mesh(positions, faces, extra, name=where), where, keep_flat_normals)
    except DegenerateMeshError as exc:  # well formed, nothing to make progressive
        raise _PassThrough(str(exc)) from None


def _welded(mesh: Mesh, where: str, keep_flat_normals: bool = False) -> tuple:
    """``(mesh, how many vertices the weld removed, flat)``: a checked primitive with its exact duplicates
    welded when it is a triangle soup (:func:`~pmwm_codec.mesh.weld_soup`: the same position and the same
    value of every attribute), or when its normals are flat (``flat`` True: :func:`flat_normals`, its NORMAL
    dropped first, every duplicate welded, soup or not), its ``cleanup`` counts and the weld's added up.

    A soup (a non-indexed primitive, or indices naming every vertex once) becomes the indexed mesh it is,
    whose seams the simplifier can collapse; as a soup each position had about six copies and stayed in the
    base.  A primitive whose vertices the faces share is indexed by its author and kept as stored,
    duplicates and all (gltfpack keeps a few where its compressed attributes differ in a bit and its plain
    ones do not: one weld would make the two encodes of one file differ); it comes back as it is, with 0.

    A flat-shaded primitive has a copy of each position per normal around it, three or more, which keep it
    whole in the base (seam corners).  When its NORMAL is what a glTF viewer computes without one (glTF 2.0,
    3.7.2.1: flat normals) it is dropped: the primitive looks the same at every level, and its copies weld
    into the surface they are, which streams; unless ``keep_flat_normals`` (for a viewer or a tool that
    reads NORMAL)."""
    flat = not keep_flat_normals and flat_normals(mesh)
    if flat:
        mesh = Mesh(mesh.positions, mesh.faces, {k: v for k, v in mesh.attributes.items() if k != "NORMAL"},
                    cleanup=mesh.cleanup)
        welded = weld_duplicates(mesh.positions, mesh.faces, mesh.attributes, name=where)
    else:
        welded = weld_soup(mesh.positions, mesh.faces, mesh.attributes, name=where)
    if welded is None:
        return mesh, 0, flat
    out, removed = welded
    out.cleanup = {k: out.cleanup.get(k, 0) + mesh.cleanup.get(k, 0) for k in sorted({*out.cleanup, *mesh.cleanup})}
    return out, removed, flat


#: A normal is its face's (:func:`flat_normals`) within this angle: well below what shading shows, well above
#: float32's rounding of a unit vector and of the positions an exporter computed it from.
FLAT_NORMAL_DEGREES = 0.25


def flat_normals(mesh: Mesh) -> bool:
    """True when ``mesh`` has a NORMAL (n, 3) and no TANGENT, and every corner of every face with an area
    has its face's unit normal (by its winding: ``(b - a) x (c - a)``) for NORMAL, within
    :data:`FLAT_NORMAL_DEGREES`: what a glTF viewer computes for a primitive without NORMAL (glTF 2.0,
    3.7.2.1, "client implementations MUST calculate flat normals").  Not with TANGENT, which a viewer
    ignores once NORMAL is gone; not when no face has an area."""
    normal = mesh.attributes.get("NORMAL")
    if normal is None or "TANGENT" in mesh.attributes or mesh.face_count == 0:
        return False
    p = np.asarray(mesh.positions, np.float64)[mesh.faces]  # (m, 3 corners, 3)
    cross = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    area = np.linalg.norm(cross, axis=1)
    scale = float(np.ptp(mesh.positions, axis=0).max()) if mesh.vertex_count else 0.0
    drawn = area > (scale * scale) * 1e-12  # a face with no area shows nothing: its corners' normals say nothing
    if not drawn.any():
        return False
    unit = cross[drawn] / area[drawn, None]
    given = np.asarray(normal, np.float64).reshape(mesh.vertex_count, -1)[:, :3][mesh.faces[drawn]]  # (k, 3, 3)
    length = np.linalg.norm(given, axis=2)
    if not (length > 0).all():
        return False
    cos = np.einsum("kcj,kj->kc", given, unit) / length
    return bool((cos >= np.cos(np.radians(FLAT_NORMAL_DEGREES))).all())


def _accessor_arrays(gltf, buffers, prim) -> tuple:
    """``(positions, faces (m, 3), {semantic: values})`` of a plain primitive, unchecked."""
    attrs = prim["attributes"]
    positions = read_accessor(gltf, buffers, attrs["POSITION"]).astype(np.float64)
    faces = triangle_faces(gltf, buffers, prim, len(positions))
    extra = {}
    for semantic, idx in attrs.items():
        if semantic == "POSITION":
            continue
        values = read_accessor(gltf, buffers, idx)
        if np.issubdtype(values.dtype, np.integer):  # a non-normalized integer accessor: exact integers
            extra[semantic] = _integer_values(gltf, idx, values, semantic)
        else:
            extra[semantic] = values.astype(np.float64)
    return positions, faces, extra


def _integer_values(gltf, index: int, values: np.ndarray, semantic: str) -> np.ndarray:
    """An integer attribute's ``values`` (n, k) int64 as its accessor's own component dtype, which
    tells the encoder to carry them exactly (step 1) and a decoded level to write them with that
    componentType (:func:`~pmwm_codec.stream.encoder._attribute_grid`).  :class:`_PassThrough` when
    float32, which the base stores them in, cannot hold them all exactly."""
    if values.size and int(np.abs(values).max()) > FLOAT32_EXACT_INTEGERS:
        raise _PassThrough(f"{semantic} holds integers beyond {FLOAT32_EXACT_INTEGERS:,}, which the progressive "
                           "stream cannot carry exactly")
    return values.astype(COMPONENT_DTYPES[gltf["accessors"][index]["componentType"]])


def _draco_arrays(gltf, buffers, prim, draco) -> tuple:
    """``(positions, faces, {semantic: values})`` of a ``KHR_draco_mesh_compression`` input
    primitive, decoded with DracoPy, unchecked.

    Attributes are looked up by the unique ids the extension names (never by
    position in the Draco stream); the decoded values replace the accessors.
    """
    import DracoPy

    try:
        _, raw = view_bytes(gltf, buffers, draco["bufferView"], "Draco", error=InputFormatError)
        decoded = DracoPy.decode(bytes(raw))
    except (KeyError, TypeError, InputFormatError):
        raise InputFormatError("its Draco data is missing") from None
    except Exception as exc:  # DracoPy raises its own exception types
        raise InputFormatError(f"its Draco data does not decode ({str(exc).splitlines()[0]})") from None
    ids = draco.get("attributes", {})
    values = {}
    for semantic in prim.get("attributes", {}):
        if semantic not in ids:  # allowed by the extension (read from the accessor); not supported here
            raise _PassThrough(f"Draco attributes lack {semantic}")
        attribute = decoded.get_attribute_by_unique_id(ids[semantic])
        if attribute is None:
            raise InputFormatError(f"Draco data has no attribute {ids[semantic]} for {semantic}")
        data = np.asarray(attribute["data"])
        data = data.reshape(len(data), -1)
        if semantic != "POSITION" and np.issubdtype(data.dtype, np.integer):
            # Draco keeps an integer attribute's raw integers: normalized ones (colours as UNSIGNED_BYTE) are
            # mapped as the accessor says, and exact integers (feature ids) stay integers
            data = as_declared(gltf, prim["attributes"][semantic], data)
        if np.issubdtype(data.dtype, np.integer):
            values[semantic] = _integer_values(gltf, prim["attributes"][semantic], data, semantic)
        else:
            values[semantic] = data.astype(np.float64)
    faces = np.asarray(decoded.faces, dtype=np.int64).reshape(-1, 3)
    positions = values.pop("POSITION")
    return positions, faces, values


def _lock_shared_positions(gltf: dict, jobs) -> None:
    """Lock every vertex that coincides in the scene with a vertex of another primitive: a border between
    two primitives, of one glTF mesh or of meshes whose nodes place them to meet, stays in the base and
    never cracks.

    A mesh the scene shows once (or every mesh of a document without nodes) is taken at its world
    positions, where two vertices coincide within :data:`SCENE_TOLERANCE` of the coordinates' size (the
    float32 rounding of stored coordinates, carried through different matrices, keeps a border's copies
    that far apart); a mesh shown several times (or not, or under a malformed node) at its stored
    positions, coinciding exactly with those of meshes shown at the same world matrices.

    Once the grids are fitted, the encoder locks every other vertex of the primitive on the grid point of a
    locked one too (:func:`~pmwm_codec.stream.encoder._locked_with_grid_copies`): copies that land on one
    grid point are one position in the stream."""
    shown = placements_by_mesh(gltf) if gltf.get("nodes") else {}
    counts = [job.mesh.vertex_count for job in jobs]
    owner = np.repeat(np.arange(len(jobs)), counts)
    shared = np.zeros(len(owner), bool)
    world, size, rows, groups = [], 0.0, [], {}
    for k, job in enumerate(jobs):
        places = shown.get(job.mesh_index, []) if gltf.get("nodes") else [np.eye(4)]
        if len(places) == 1 and places[0] is not None:
            world.append((k, place(job.mesh.positions, places[0])))
            scale = float(np.linalg.norm(places[0][:3, :3], 2)) * float(np.abs(job.mesh.positions).max(initial=0.0))
            size = max(size, scale, float(np.abs(world[-1][1]).max(initial=0.0)))
            continue
        key = tuple(sorted(b"" if m is None else np.round(m, 12).tobytes() for m in places))
        tag = groups.setdefault(key, len(groups))
        bits = np.ascontiguousarray(job.mesh.positions + 0.0, np.float64).view(np.int64)  # -0.0 as 0.0
        rows.append(np.column_stack([np.full(len(bits), tag, np.int64), bits, np.full(len(bits), k)]))
    starts = np.cumsum([0] + counts)
    if len(world) > 1:
        from scipy.spatial import cKDTree

        points = np.concatenate([w for _, w in world])
        index = np.concatenate([np.arange(starts[k], starts[k + 1]) for k, _ in world])
        pairs = cKDTree(points).query_pairs(SCENE_TOLERANCE * size, output_type="ndarray")
        i, j = index[pairs[:, 0]], index[pairs[:, 1]]
        apart = owner[i] != owner[j]
        shared[i[apart]] = shared[j[apart]] = True
    if len(rows) > 1:
        table = np.concatenate(rows)
        _, inverse = np.unique(table[:, :4], axis=0, return_inverse=True)
        inverse = inverse.reshape(-1)
        pairs = np.unique(np.stack([inverse, table[:, 4]], 1), axis=0)  # distinct (position, primitive)
        border = np.bincount(pairs[:, 0], minlength=int(inverse.max(initial=-1)) + 1)[inverse] > 1
        index = np.concatenate([np.arange(starts[r[0, 4]], starts[r[0, 4] + 1]) for r in rows])
        shared[index[border]] = True
    for k, job in enumerate(jobs):
        job.locked = shared[starts[k] : starts[k + 1]]


def _refuse_external_uris(gltf: dict) -> None:
    """InputFormatError for an image ``uri`` of an in-memory document that is not a ``data:`` URI: such a
    document has no folder its files could be inside, and the ``.pmw`` would carry a reference out of
    it (``/etc/hostname``, ``../x.png``, ``http://...``) that a file on disk is refused for.  An image
    whose bytes the document holds (``_bytes``, as :func:`load_document` leaves an image it read from
    the asset's folder) is embedded from them: its ``uri`` is never opened."""
    images = gltf.get("images") if isinstance(gltf, dict) else None
    for i, image in enumerate(images if isinstance(images, list) else []):
        uri = image.get("uri") if isinstance(image, dict) else None
        if uri is not None and not (isinstance(uri, str) and uri.startswith("data:")) and "_bytes" not in image:
            shown = repr(uri if not isinstance(uri, str) or len(uri) <= 80 else uri[:77] + "...")
            raise InputFormatError(f"the asset: images[{i}].uri {shown} names a file; an in-memory document "
                                   "holds its images (a bufferView or a data: URI)")


def encode_asset(src, dst, *, strip_image_profiles: bool = False, keep_flat_normals: bool = False,
                 label: str | None = None, **options) -> EncodeReport:
    """Encode a glTF asset (path, or ``(gltf dict, buffers)``) into a ``.pmw`` at ``dst``.

    Options as :func:`~pmwm_codec.stream.encoder.encode_document`, plus
    ``strip_image_profiles``: drop colour-profile / pixel-aspect chunks from PNG
    textures (same pixels; the glTF validator warns on them).  Images are otherwise
    carried byte for byte.  ``keep_flat_normals``: a flat-shaded primitive keeps its NORMAL (and stays in
    the base; :func:`plan_asset`).  ``label``: how messages name an in-memory document (default "the asset";
    the mesh file it was read from: :mod:`pmwm_codec.meshdoc`).  The report's ``notices`` say which primitives passed
    through and why; a primitive with invalid data is refused (see :func:`plan_asset`).
    """
    if isinstance(src, tuple):  # checked as a file's document is (load_document), but it has no folder
        label = label or "the asset"
        gltf, buffers = _json_copy(src[0]), list(src[1])
        check_document(gltf, label)
        _refuse_external_uris(gltf)
        gltf, buffers = decompress_meshopt(gltf, buffers, label)
        label_images(gltf, buffers, label)
        check_rig_data(gltf, buffers, label)
    else:
        gltf, buffers = load_document(src)
    if is_progressive(gltf):  # a .pmw by another name: its glTF is the base mesh alone
        raise InputFormatError(progressive_refusal(label if isinstance(src, tuple) else os.path.basename(src)))
    notices = []
    if strip_image_profiles:
        count = _strip_profiles(gltf, buffers)
        if count:
            notices.append(f"removed colour-profile metadata from {count} PNG image(s)")
    name = (None if label == "the asset" else label) if isinstance(src, tuple) else os.path.basename(os.fspath(src))
    jobs, drop, planned = plan_asset(gltf, buffers, name, keep_flat_normals=keep_flat_normals)
    notices += planned
    for job in jobs:  # the accessors' names, which the base's accessors keep
        job.names = _accessor_names(gltf, gltf["meshes"][job.mesh_index]["primitives"][job.primitive_index])
    _forget_input_draco(gltf, jobs)
    doc, kept_bin = repack(gltf, buffers, drop)
    report = encode_document(doc, kept_bin, jobs, dst, **options)
    report.notices = notices + report.notices
    return report


def _json_copy(gltf) -> dict:
    """An in-memory document copied as its JSON text would be parsed: objects the caller's dict shares (one
    ``extensions`` dict on several nodes, say) become separate, so renumbering an index in one place does
    not renumber it again through another (a shared instancing dict came out with ``TRANSLATION: null``);
    an image's ``_bytes`` (:func:`load_document`'s) are kept as bytes.
    InputFormatError when the document is not JSON (a numpy array, a cycle; a NaN is let through to the
    checks that name where it is)."""
    images = gltf.get("images") if isinstance(gltf, dict) else None
    held = {i: image["_bytes"] for i, image in enumerate(images if isinstance(images, list) else [])
            if isinstance(image, dict) and "_bytes" in image}
    if held:  # the image bytes load_document holds beside the JSON, copied as bytes
        gltf = {**gltf, "images": [{k: v for k, v in image.items() if k != "_bytes"} if i in held else image
                                   for i, image in enumerate(images)]}
    try:
        gltf = json.loads(json.dumps(gltf))
    except (TypeError, ValueError, RecursionError) as exc:
        raise InputFormatError(f"the asset's glTF document is not JSON ({str(exc)[:80]})") from None
    if not isinstance(gltf, dict):
        raise InputFormatError("the asset's glTF document is not a JSON object")
    for i, blob in held.items():
        if not isinstance(blob, (bytes, bytearray, memoryview)):
            raise InputFormatError(f"the asset: images[{i}]._bytes is {type(blob).__name__}, not bytes")
        gltf["images"][i]["_bytes"] = bytes(blob)
    return gltf


def _forget_input_draco(gltf: dict, jobs) -> None:
    """Drop the input's Draco extension from primitives that become progressive (their
    geometry is re-encoded), and from the extension lists if nothing else uses it."""
    for job in jobs:
        prim = gltf["meshes"][job.mesh_index]["primitives"][job.primitive_index]
        exts = prim.get("extensions")
        if isinstance(exts, dict) and exts.pop(DRACO_EXTENSION, None) is not None and not exts:
            del prim["extensions"]
    if not uses_extension(gltf, DRACO_EXTENSION):
        forget_extension(gltf, DRACO_EXTENSION)


def decode_asset(src, chunks=None):
    """A ``.pmw`` (path, bytes, file; whole or cut) as an ordinary GLB at a level of detail.

    Returns ``(glb bytes, StreamEnd, decoder)``: the document with every progressive
    primitive's geometry replaced by plain accessors for the level reached
    (base + ``chunks`` chunks, or as many as arrived) and the extension removed.
    Images whose bytes have not all arrived (a cut file: the document's data
    follows the base meshes) are left out with the textures that use them; the
    decoder's ``notices`` say which.
    """
    data = read_declared(src)  # a stream: no further than the GLB header declares
    decoder = StreamDecoder(copy=False, max_chunks=chunks)
    results = decoder.feed(data)
    end = decoder.close()
    gltf = decoder.header.gltf_json
    try:  # the document a .pmw carries is written out as it is: never one the glTF readers (ours too) refuse
        check_document(gltf, "its glTF document")
    except InputFormatError as exc:
        raise FormatError(str(exc)) from None
    bin_start = decoder.header.bin_offset
    found = find_extension_primitives(gltf, EXTENSION_NAME)
    doc, drop = _without_progressive_geometry(gltf, found)
    missing = _drop_images_not_arrived(doc, len(data) - bin_start)
    decoder.notices += [f"image {i} has not arrived yet: the level is written without it" for i in missing]
    needed = _data_end(doc)
    if not end.complete and needed > len(data) - bin_start:  # other meshes' data, cut before it: as pmw cut says
        raise data_not_arrived(len(data), bin_start + needed)
    names = [_accessor_names(gltf, gltf["meshes"][mi]["primitives"][pi]) for mi, pi, _ in found]
    kept, kept_bin = repack(doc, [data[bin_start:]], drop)
    out = BufferBuilder(kept["bufferViews"], kept["accessors"], [kept_bin], len(kept_bin))
    for (mi, pi, _), part, named in zip(found, results[-1].parts, names):
        _write_level(kept["meshes"][mi]["primitives"][pi], part, out, named)
    forget_extension(kept, EXTENSION_NAME, keys=("extensionsUsed",))
    if not uses_extension(kept, DRACO_EXTENSION):
        forget_extension(kept, DRACO_EXTENSION)
    if not uses_quantization(kept):  # the level's accessors are FLOAT: a quantized input's need may be gone
        forget_extension(kept, QUANTIZATION_EXTENSION)
    kept["buffers"] = [{"byteLength": out.length}]
    parts = out.parts
    if kept.get("skins") or kept.get("animations"):  # their data as it came (a skin's joints from the stream)
        parts = [b"".join(parts)]
        try:
            check_rig_data(kept, parts, "its glTF document")
        except InputFormatError as exc:
            raise FormatError(str(exc)) from None
    return b"".join(glb_parts(kept, parts, out.length)), end, decoder


def plain_triangle_primitives(gltf: dict | None) -> list:
    """``[(mesh index, primitive index)]`` of the primitives of ``gltf`` (a ``.pmw``'s document) that are
    drawn as triangles (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN) but not progressive: geometry the asset
    shows that the stream does not carry (the encoder passes such primitives through: morphs,
    strips, or any added later).  Only meshes the scene shows count (every mesh without nodes)."""
    if not gltf:
        return []
    progressive = {(mi, pi) for mi, pi, _ in find_extension_primitives(gltf, EXTENSION_NAME)}
    shown = set(placements_by_mesh(gltf)) if gltf.get("nodes") else None
    out = []
    for mi, mesh in enumerate(gltf.get("meshes", [])):
        if shown is not None and mi not in shown:
            continue
        for pi, prim in enumerate(mesh.get("primitives", [])):
            if (mi, pi) not in progressive and prim.get("mode", TRIANGLES) in TRIANGLE_MODES \
                    and "POSITION" in prim.get("attributes", {}):
                out.append((mi, pi))
    return out


def posed_notes(gltf: dict | None) -> list:
    """Notes for an OBJ / PLY / STL / OFF of the scene: the triangle meshes it shows skinned (progressive or not),
    which such a file holds in their stored pose (the bind pose), placed by their nodes, while a glTF viewer poses
    them by their joints; and those with morph targets (non-progressive, :func:`plain_triangle_primitives`),
    which it holds posed at the weights a viewer draws them with at rest
    (:func:`~pmwm_codec.format.document.shown_weights`), the targets themselves left out -- or as stored, when
    their nodes draw them with different weights.  A skinned mesh its nodes
    move is said to be moved: a glTF viewer ignores a skinned mesh node's transform (glTF 2.0 3.7.3.3), while the file
    places it by its nodes as :func:`scene_as_shown` does (the frame :func:`~pmwm_codec.format.gltf.owner_placements`
    marks its owner layer in)."""
    if not gltf:
        return []
    skinned = skinned_meshes(gltf)
    shown = set(placements_by_mesh(gltf)) if gltf.get("nodes") else None
    progressive = {mi for mi, _, _ in find_extension_primitives(gltf, EXTENSION_NAME) if shown is None or mi in shown}
    plain = plain_triangle_primitives(gltf)
    meshes = sorted({mi for mi, _ in plain} | progressive)
    moved = {mi for mi, matrices in zip(meshes, world_placements(gltf, meshes)[0] or [])
             if any(not np.array_equal(m, np.eye(4)) for m in matrices)}
    notes = []
    for mi in meshes:
        if mi in skinned:
            notes.append(f"mesh {mi} is skinned: the file holds it in its stored pose, not posed by its joints"
                         + (", moved by its node's transform, which a glTF viewer ignores for a skinned mesh"
                            if mi in moved else ""))
        morphs = [gltf["meshes"][mi]["primitives"][pi] for m, pi in plain if m == mi]
        morphs = [prim for prim in morphs if prim.get("targets")]
        if not morphs:
            continue
        if shown_weights(gltf, mi, morphs[0]) is None:
            notes.append(f"mesh {mi} is drawn with different morph weights by its nodes: the file holds its stored "
                         "positions, not morphed (decode to .glb to keep its morph targets)")
        else:
            notes.append(f"mesh {mi}'s morph targets are left out: the file holds it posed at the weights it is "
                         "drawn with at rest (decode to .glb to keep them)")
    return notes


def _plain_triangles(doc: dict, buffers, mi: int, pi: int) -> tuple:
    """``(positions (n, 3) float64, faces (m, 3) int64)`` of primitive ``pi`` of mesh ``mi`` of a plain
    document (:func:`~pmwm_codec.format.document.primitive_triangles`: strips and fans as triangles, glTF 2.0
    3.7.2.1, a strip's restarts dropped; morphed as a viewer draws it at rest, :func:`posed_notes`)."""
    prim = doc["meshes"][mi]["primitives"][pi]
    return primitive_triangles(doc, buffers, prim, f"mesh {mi} primitive {pi}", shown_weights(doc, mi, prim) or [])


def scene_as_shown(gltf: dict | None, result, plain=None) -> tuple:
    """A level as the asset's scene shows it, for formats without nodes (OBJ, PLY, STL).

    ``gltf`` the ``.pmw``'s document (None: a mesh file's), ``result`` a
    :class:`~pmwm_codec.stream.decoder.PartialResult`, ``plain`` ``(document, [BIN bytes])`` of the
    asset decoded (:func:`decode_asset`) when the scene shows triangles that are not progressive
    (:func:`plain_triangle_primitives`; None: it shows none).  Returns ``(Mesh, None)``: every
    progressive primitive placed by its nodes' world matrices, once per node that shows it, a mirrored
    showing with its winding reversed (:func:`~pmwm_codec.format.gltf.scene_mesh`, oriented), as glTF
    converters flatten a scene, then the other triangle primitives the same way; the parts as stored
    when the scene shows each once where it is stored.  ``(the parts as stored, why)`` when the
    placements do not read (GPU instancing, a mesh the scene does not show, a scale of zero; ``why`` a
    phrase).
    """
    others = [] if plain is None else plain_triangle_primitives(gltf)
    parts = [(p.positions, p.faces) for p in result.parts]
    parts += [_plain_triangles(plain[0], plain[1], mi, pi) for mi, pi in others]
    stored = [[np.eye(4)] for _ in parts]  # each part once, where it is stored
    if gltf is None or not placed_by_nodes(gltf):
        if not others:
            return result.mesh, None
        frames, why = stored, None
    else:
        meshes = [mi for mi, _, _ in find_extension_primitives(gltf, EXTENSION_NAME)] + [mi for mi, _ in others]
        frames, why = world_placements(gltf, meshes)
        if frames is None:
            if not others:
                return result.mesh, why
            frames = stored
    positions, faces, _ = scene_mesh([p for p, _ in parts], [f for _, f in parts], frames, oriented=True)
    return Mesh(positions, faces), why


def _data_end(doc: dict) -> int:
    """Where the BIN data the document references ends (its bufferViews in buffer 0 that something uses)."""
    views = doc.get("bufferViews", [])
    used = {holder[key] for holder, key in view_sites(doc)}
    return max((int(views[i].get("byteOffset", 0)) + int(views[i]["byteLength"]) for i in used
                if i < len(views) and views[i].get("buffer", 0) == 0), default=0)


def _drop_images_not_arrived(doc: dict, available: int) -> list:
    """Remove (in place) the images of ``doc`` whose bufferView ends past ``available`` BIN bytes.

    Textures using them go too (as their ``source`` or the ``source`` of an extension object:
    KHR_texture_basisu, EXT_texture_webp ...), and every ``{"index": t}`` texture reference to
    those textures (in materials and their extensions); the remaining textures
    and images are renumbered.  Returns the original indices of the removed images.
    """
    views = doc.get("bufferViews", [])

    def arrived(i: int, image) -> bool:
        if not isinstance(image, dict):
            raise InputFormatError(f"images[{i}] is not an object")
        if "bufferView" not in image:
            return True
        view = gltf_item(views, image["bufferView"], f"images[{i}]: bufferView", error=InputFormatError)
        start, length = view.get("byteOffset", 0), view.get("byteLength")
        if any(isinstance(v, bool) or not isinstance(v, int) or v < 0 for v in (start, length)):
            raise InputFormatError(f"images[{i}]: bufferView {image['bufferView']} has no byte range")
        return start + length <= available

    images = doc.get("images", [])
    if not isinstance(images, list):
        raise InputFormatError("the document's images is not an array")
    missing = [i for i, image in enumerate(images) if not arrived(i, image)]
    if not missing:
        return []
    image_map = {i: n for n, i in enumerate(i for i in range(len(images)) if i not in missing)}
    textures = doc.get("textures", [])
    gone = {t for t, tex in enumerate(textures) if any(holder["source"] in missing for holder in _sources(tex))}
    texture_map = {t: n for n, t in enumerate(t for t in range(len(textures)) if t not in gone)}
    doc["images"] = [img for i, img in enumerate(images) if i in image_map]
    doc["textures"] = [tex for t, tex in enumerate(textures) if t in texture_map]
    for tex in doc["textures"]:
        for holder in _sources(tex):
            holder["source"] = image_map[holder["source"]]
    for material in doc.get("materials", []):
        _renumber_texture_refs(material, texture_map)
    for key in ("images", "textures"):
        if not doc[key]:
            del doc[key]
    return missing


def _sources(texture: dict) -> list:
    """The objects holding an image ``source`` of a texture: itself, and its extension objects that have one
    (KHR_texture_basisu, EXT_texture_webp, EXT_texture_avif, MSFT_texture_dds)."""
    exts = texture.get("extensions")
    holders = [texture] + [e for e in (exts.values() if isinstance(exts, dict) else ()) if isinstance(e, dict)]
    return [h for h in holders if isinstance(h.get("source"), int)]


def _renumber_texture_refs(node, texture_map: dict) -> None:
    """Renumber texture references (``{"index": t, ...}`` under a key ending in "Texture") in place; drop lost ones."""
    if isinstance(node, dict):
        for key in list(node):
            value = node[key]
            if key.endswith("Texture") and isinstance(value, dict) and isinstance(value.get("index"), int):
                if value["index"] in texture_map:
                    value["index"] = texture_map[value["index"]]
                else:
                    del node[key]
            else:
                _renumber_texture_refs(value, texture_map)
    elif isinstance(node, list):
        for item in node:
            _renumber_texture_refs(item, texture_map)


def _without_progressive_geometry(gltf: dict, found) -> tuple:
    """Copy of ``gltf`` whose progressive primitives lost the PMWM and Draco extensions.

    Returns ``(doc, accessors to drop)``: the accessors those primitives used.
    """
    doc = copy.deepcopy(gltf)
    drop = set()
    for mi, pi, _ in found:
        p = doc["meshes"][mi]["primitives"][pi]
        drop.update(p.get("attributes", {}).values())
        if "indices" in p:
            drop.add(p["indices"])
        exts = p.get("extensions", {})
        exts.pop(EXTENSION_NAME, None)
        exts.pop(DRACO_EXTENSION, None)
        if not exts:
            p.pop("extensions", None)
    return doc, drop


#: The attributes a decoded level writes at unit length (spec README, *Seams and attributes*): these glTF
#: semantics exactly, not every name that starts like them (``NORMAL_1`` is a custom attribute, kept as decoded).
RENORMALIZED = ("NORMAL", "TANGENT")


def _accessor_names(gltf: dict, prim: dict) -> dict:
    """``{semantic or "indices": name}`` of the accessors of ``prim`` that have a string ``name``."""
    accessors = gltf.get("accessors", [])
    used = {**prim.get("attributes", {}), **({"indices": prim["indices"]} if "indices" in prim else {})}
    return {what: accessors[i]["name"] for what, i in used.items()
            if isinstance(i, int) and 0 <= i < len(accessors) and isinstance(accessors[i].get("name"), str)}


def _write_level(prim: dict, part, out: BufferBuilder, names: dict | None = None) -> None:
    """Give ``prim`` plain accessors (in ``out``) for the decoded ``part``: positions (n, 3)
    float32 with min/max, its attributes (NORMAL / TANGENT renormalized; an attribute whose grid names
    a ``componentType``, an integer one, as those integers, but UNSIGNED_INT as FLOAT), uint32 indices;
    each named as ``names`` (``{semantic or "indices": name}``: the stored accessors') has it."""
    attributes = {"POSITION": out.add_accessor(part.positions.astype(np.float32), FLOAT, ARRAY_BUFFER, minmax=True)}
    # UNSIGNED_INT is glTF's for indices only (validator: MESH_PRIMITIVE_ATTRIBUTES_ACCESSOR_UNSIGNED_INT; an
    # input that used it was invalid): its integers, at most 2^24, are written as the exact FLOATs they are
    types = {spec["semantic"]: spec.get("componentType") for spec in part.attributes
             if spec.get("componentType") != UNSIGNED_INT}
    for semantic, values in part.attribute_values().items():
        values = values.astype(np.float32)
        if types.get(semantic) is not None:
            attributes[semantic] = out.add_vertex_integers(values, types[semantic], ARRAY_BUFFER)
            continue
        if semantic in RENORMALIZED:
            values = renormalized(values)
        attributes[semantic] = out.add_accessor(values, FLOAT, ARRAY_BUFFER)
    prim["attributes"] = attributes
    prim["indices"] = out.add_accessor(np.asarray(part.faces, np.uint32).reshape(-1), UNSIGNED_INT, ELEMENT_ARRAY_BUFFER)
    prim["mode"] = TRIANGLES
    for what, name in (names or {}).items():
        index = prim["indices"] if what == "indices" else attributes.get(what)
        if index is not None:
            out.accessors[index]["name"] = name


