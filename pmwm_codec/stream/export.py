"""A ``.pmw`` decoded to an ordinary mesh file: what ``pmw decode`` does, as one library call (:func:`decode_to`).

glTF outputs keep the whole document (materials, textures, nodes) through :func:`~pmwm_codec.stream.asset.decode_asset`.
OBJ, PLY and OFF outputs of an asset with texture coordinates, normals, colours or materials keep them (an OBJ
its MTL and textures beside it: :mod:`pmwm_codec.meshexport`, the files a set), unless ``geometry_only``; the
other outputs get the geometry through :func:`~pmwm_codec.stream.reader.decode_stream`, placed as the scene shows
them (:func:`~pmwm_codec.stream.asset.scene_as_shown`: each progressive primitive placed by its nodes, once per
node that shows it, as glTF converters flatten a scene; as stored, with a notice, when the placements do not
read), and :func:`pmwm_codec.meshio.write_mesh`.  Every output is written atomically.
"""

from __future__ import annotations

import os

from ..errors import OptionError
from ..format.glb import split_glb
from ..format.gltf import POINT_AND_LINE_MODES, TRIANGLE_MODES, TRIANGLES
from ..format.reader import read_header
from ..http import as_source, is_url, stream_end
from ..meshexport import progressive_meshes, scene_parts, shows_appearance, sidecar_paths, write_scene
from ..meshio import WRITE_SUFFIXES, write_asset, write_mesh
from ..options import check_output_path, checked_chunks
from .asset import decode_asset, plain_triangle_primitives, posed_notes, scene_as_shown
from .decoder import StreamDecoder
from .reader import decode_stream

__all__ = ["decode_to"]


def decode_to(src, dst, chunks: int | None = None, geometry_only: bool = False) -> dict:
    """Decode the ``.pmw`` ``src`` (a path, ``-`` for standard input, an http(s) URL, bytes or a binary file;
    whole or cut) to the mesh file ``dst`` (its suffix one of :data:`~pmwm_codec.meshio.WRITE_SUFFIXES`) after
    the base and ``chunks`` chunks (default: all that arrived); ``geometry_only``: an OBJ, PLY or OFF of
    positions and faces alone.

    Returns ``pmw decode --json``'s object: ``vertices`` and ``faces`` (what the output holds), ``chunks_applied``,
    ``chunks_total``, ``complete`` and ``truncated`` (of the *input*), ``output``, ``files`` (every file written,
    the output first: an OBJ's MTL and textures follow it) and ``notices``.  OptionError for an output that cannot
    be written (nothing is); the errors of the readers for an input that does not read."""
    chunks = checked_chunks(chunks)
    local = isinstance(src, (str, os.PathLike)) and not is_url(src)
    inputs = (src,) if local and os.fspath(src) != "-" else ()
    dst = check_output_path(dst, "mesh", inputs=inputs)  # a str, or OptionError for what names no file
    suffix = os.path.splitext(dst)[1].lower()
    if suffix not in WRITE_SUFFIXES:
        raise OptionError(f"{dst}: unknown output format {suffix or '(no suffix)'!r}; use one of {', '.join(WRITE_SUFFIXES)}")
    notices, written, why = [], [dst], None
    styled = suffix in (".obj", ".ply", ".off") and not geometry_only  # may keep the appearance (OFF: colours)
    # an OBJ / PLY / STL / OFF of a scene that also shows plain triangles, or a styled one of an asset with
    # texture coordinates, normals, colours or materials, needs the whole document: that data, the images, may
    # follow the chunks (a URL's header is known only once it is read, see below)
    plain = suffix not in (".glb", ".gltf") and not is_url(src) and _needs_document(src, styled)
    source = as_source(src, chunks, whole_document=plain or suffix in (".glb", ".gltf"))
    if suffix in (".glb", ".gltf"):  # the whole document: its images may follow the chunks
        glb, end, decoder = decode_asset(source, chunks=chunks)
        notices = list(decoder.notices)
        write_asset(dst, glb)
        counts = _stored_triangles(split_glb(glb, "the decoded asset")[0])  # each stored once
    else:
        if not plain:  # a URL read by ranges fetches nothing after chunk N
            decoder = StreamDecoder(copy=False, max_chunks=chunks)
            last, end = decode_stream(source, decoder=decoder)
            header = decoder.header.gltf_json if decoder.header is not None else None
            if is_url(src) and (plain_triangle_primitives(header) or (styled and shows_appearance(header))):
                plain, source = True, as_source(src, chunks, whole_document=True)  # read again, whole
            else:
                mesh, why = scene_as_shown(header, last)
                notices += posed_notes(header)  # a progressive skinned mesh
                shown = header
        scene = None
        if plain:
            glb, end, decoder = decode_asset(source, chunks=chunks)
            header = shown = decoder.header.gltf_json
            notices += decoder.notices + posed_notes(header)
            keeps_appearance = styled and shows_appearance(header)
            last = None if keeps_appearance else decoder.last
            # the decoder is let go: its replay's state of the level (about 4x the GLB's bytes) is in the GLB
            # now, and an OBJ / PLY of the scene would otherwise be written with both held
            del decoder
            doc, bin_chunk = split_glb(glb, "the decoded asset")
            del glb  # (bin_chunk is a copy of its BIN chunk)
            if keeps_appearance:
                scene = scene_parts(doc, [bin_chunk], also=progressive_meshes(header))
                del doc, bin_chunk  # the scene holds its arrays
            else:
                mesh, why = scene_as_shown(header, last, plain=(doc, [bin_chunk]))
        if scene is not None:
            mtl, images = sidecar_paths(dst, scene)
            beside = ([mtl] if mtl else []) + images
            for path in beside:
                check_output_path(path, "mesh", inputs=inputs)
            vertices, faces, more = write_scene(dst, scene)
            written += beside
            counts = (vertices, faces)
            notices += scene.notices + more
        else:
            write_mesh(dst, mesh)
            counts = (mesh.vertex_count, mesh.face_count)  # what the file holds: a mesh shown twice, twice
            if suffix == ".stl" and shows_appearance(header):
                notices.append("an STL file holds geometry alone: the asset's texture coordinates, normals, "
                               "colours and materials are left out (decode to .obj, .ply or .glb to keep them)")
        if why is not None:
            notices.append(f"{why}: the {suffix[1:].upper()} file holds each primitive once, as stored, not "
                           "placed by the scene's nodes; decode to .glb to keep the scene")
        notices += _points_and_lines_left_out(shown, suffix)
    end = stream_end(source, end)  # a URL read up to chunk N: the file on the server may be whole
    return {"vertices": int(counts[0]), "faces": int(counts[1]), "chunks_applied": int(end.chunks_applied),
            "complete": bool(end.complete), "chunks_total": int(end.chunks_total), "truncated": bool(end.truncated),
            "output": dst, "files": written, "notices": _chunk_notices(chunks, end) + notices,
            "bytes_read": int(end.bytes_read)}


def _points_and_lines_left_out(gltf, suffix: str) -> list:
    """A notice naming the primitives of the document ``gltf`` that draw points or lines (which the ``.pmw``
    passes through, and a ``.glb`` / ``.gltf`` output keeps): an OBJ, PLY, STL or OFF output holds the scene's
    triangles, so they are left out, and the decode says so rather than drop them without a word."""
    named = []
    for mi, mesh in enumerate((gltf or {}).get("meshes", []) if isinstance(gltf, dict) else []):
        for pi, prim in enumerate(mesh.get("primitives", []) if isinstance(mesh, dict) else []):
            mode = prim.get("mode", TRIANGLES) if isinstance(prim, dict) else TRIANGLES
            if mode in POINT_AND_LINE_MODES:
                named.append(f"mesh {mi} primitive {pi} ({POINT_AND_LINE_MODES[mode]})")
    if not named:
        return []
    shown = ", ".join(named[:3]) + (f" and {len(named) - 3} more" if len(named) > 3 else "")
    return [f"{shown}: points and lines are left out; the {suffix[1:].upper()} file holds the scene's triangles "
            "(decode to .glb to keep them)"]


def _stored_triangles(doc: dict) -> tuple:
    """``(vertices, triangles)`` of the triangle primitives a decoded glTF document stores (each primitive
    once, as the file holds it; strips and fans counted as the triangles they draw), from its JSON."""
    accessors, vertices, faces = doc.get("accessors", []), 0, 0
    for mesh in doc.get("meshes", []):
        for prim in mesh.get("primitives", []):
            mode = prim.get("mode", TRIANGLES)
            if mode not in TRIANGLE_MODES or "POSITION" not in prim.get("attributes", {}):
                continue
            n = accessors[prim["attributes"]["POSITION"]]["count"]
            corners = accessors[prim["indices"]]["count"] if "indices" in prim else n
            vertices += n
            faces += corners // 3 if mode == TRIANGLES else max(0, corners - 2)
    return vertices, faces


def _needs_document(src, styled: bool) -> bool:
    """Whether an OBJ / PLY / STL / OFF of the ``.pmw`` ``src`` needs the whole decoded document (a path or bytes:
    its header alone is read): its scene shows triangles that are not progressive
    (:func:`~pmwm_codec.stream.asset.plain_triangle_primitives`), or, ``styled`` (an output that keeps the
    appearance), texture coordinates, normals, colours or materials
    (:func:`~pmwm_codec.meshexport.shows_appearance`).  Standard input and a file object, which cannot be read
    twice, are read whole in any case (True)."""
    if not isinstance(src, (str, os.PathLike, bytes, bytearray, memoryview)) or src == "-":
        return True
    gltf = read_header(src).gltf_json
    return bool(plain_triangle_primitives(gltf)) or (styled and shows_appearance(gltf))


def _chunk_notices(asked, end) -> list:
    """Say so when ``chunks`` asked for more chunks than the file holds (or than arrived)."""
    if asked is None or asked <= end.chunks_applied:
        return []
    if end.complete:
        return [f"--chunks {asked}: the file has {end.chunks_total} chunks; decoded all of them (full resolution)"]
    return [f"--chunks {asked}: only {end.chunks_applied} of {end.chunks_total} chunks arrived whole; decoded those"]
