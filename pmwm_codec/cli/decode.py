"""``pmw decode IN.pmw|URL|- -o OUT.(glb|gltf|obj|ply|stl|off) [--chunks N]``: a level of detail as a plain mesh.

glTF outputs keep the whole document (materials, textures, nodes) through
:func:`pmwm_codec.stream.asset.decode_asset`; the other formats get the geometry through
:func:`pmwm_codec.stream.reader.decode_stream`, placed as the scene shows them
(:func:`pmwm_codec.stream.asset.scene_as_shown`: each progressive primitive placed by its nodes, once
per node that shows it, as glTF converters flatten a scene; as stored, with a notice, when the
placements do not read), and :func:`pmwm_codec.meshio.write_mesh`; an OBJ or PLY of an asset with texture
coordinates, normals, colours or materials (unless ``--geometry-only``) gets them, and an OBJ its MTL and
textures beside it (:mod:`pmwm_codec.meshexport`, the files a set: all or none).
Every output is written atomically.
"""

from __future__ import annotations

import os

from pmwm_codec.http import as_source, is_url, stream_end
from pmwm_codec.meshexport import progressive_meshes, scene_parts, shows_appearance, sidecar_paths, write_scene
from pmwm_codec.meshio import WRITE_SUFFIXES, write_asset, write_mesh
from pmwm_codec.format.glb import split_glb
from pmwm_codec.format.gltf import TRIANGLE_MODES, TRIANGLES
from pmwm_codec.format.reader import read_header
from pmwm_codec.stream.asset import decode_asset, plain_triangle_primitives, posed_notes, scene_as_shown
from pmwm_codec.stream.decoder import StreamDecoder
from pmwm_codec.stream.reader import decode_stream

from .common import UsageError, check_input_file, check_output_path, naming, notice, print_json


def add_parser(sub):
    p = sub.add_parser(
        "decode", help=".pmw (whole, cut or on stdin) -> GLB/glTF/OBJ/PLY/STL",
        description="Decode a .pmw (whole, truncated, or '-' for standard input) to an ordinary mesh file "
                    "at full resolution or after --chunks N vertex-split chunks.")
    p.add_argument("input", metavar="IN.pmw|URL", help="the .pmw, an http(s):// URL of one (read by Range requests "
                                                         "when the server allows), or - for standard input")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output mesh: .glb, .gltf, .obj, .ply, .stl or .off (an asset's OBJ gets its MTL and "
                        "textures beside it, a PLY its textures, named after OUT: X.obj, X.mtl, X_0.png ...)")
    p.add_argument("--chunks", type=int, metavar="N", help="stop after the base mesh and N chunks")
    p.add_argument("--geometry-only", action="store_true",
                   help="an OBJ or PLY gets positions and faces alone (default: an asset's texture coordinates, "
                        "normals, colours and materials too, an OBJ's MTL and textures beside it)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success (notes still go to stderr)")
    p.set_defaults(run=run)


def run(args) -> int:
    suffix = os.path.splitext(args.output)[1].lower()
    if suffix not in WRITE_SUFFIXES:
        raise UsageError(f"{args.output}: unknown output format {suffix or '(no suffix)'!r}; "
                         f"use one of {', '.join(WRITE_SUFFIXES)}")
    if args.chunks is not None and args.chunks < 0:
        raise UsageError(f"--chunks must be >= 0, got {args.chunks}")
    url = is_url(args.input)
    if not url:
        check_input_file(args.input, ".pmw file")
    check_output_path(args.output, "mesh", inputs=() if url else (args.input,))
    notices = []
    styled = suffix in (".obj", ".ply", ".off") and not args.geometry_only  # may keep the appearance (OFF: colours)
    written = [args.output]
    with naming(args.input):
        # an OBJ / PLY / STL of a scene that also shows plain triangles, or an OBJ / PLY of one with texture
        # coordinates, normals, colours or materials, needs the whole document: that data, the images, may
        # follow the chunks (a URL's header is known only once it is read, see below)
        plain = suffix not in (".glb", ".gltf") and not url and _needs_document(args.input, styled)
        source = as_source(args.input, args.chunks, whole_document=plain or suffix in (".glb", ".gltf"))
        if suffix in (".glb", ".gltf"):  # the whole document: its images may follow the chunks
            glb, end, decoder = decode_asset(source, chunks=args.chunks)
            last, notices = decoder.last, decoder.notices
            write_asset(args.output, glb)
            counts = _stored_triangles(split_glb(glb, "the decoded asset")[0])  # each stored once
        else:
            if not plain:  # a URL read by ranges fetches nothing after chunk N
                decoder = StreamDecoder(copy=False, max_chunks=args.chunks)
                last, end = decode_stream(source, decoder=decoder)
                gltf = decoder.header.gltf_json if decoder.header is not None else None
                if url and (plain_triangle_primitives(gltf) or (styled and shows_appearance(gltf))):  # again, whole
                    plain, source = True, as_source(args.input, args.chunks, whole_document=True)
                else:
                    mesh, why = scene_as_shown(gltf, last)
                    notices += posed_notes(gltf)  # a progressive skinned mesh
            scene = None
            if plain:
                glb, end, decoder = decode_asset(source, chunks=args.chunks)
                doc, bin_chunk = split_glb(glb, "the decoded asset")
                notices += decoder.notices + posed_notes(decoder.header.gltf_json)
                if styled and shows_appearance(decoder.header.gltf_json):
                    scene = scene_parts(doc, [bin_chunk], also=progressive_meshes(decoder.header.gltf_json))
                else:
                    mesh, why = scene_as_shown(decoder.header.gltf_json, decoder.last, plain=(doc, [bin_chunk]))
            if scene is not None:
                mtl, images = sidecar_paths(args.output, scene)
                for path in ([mtl] if mtl else []) + images:
                    check_output_path(path, "mesh", inputs=() if url else (args.input,))
                vertices, faces, more = write_scene(args.output, scene)
                written += ([mtl] if mtl else []) + images
                counts, why = (vertices, faces), None
                notices += scene.notices + more
            else:
                write_mesh(args.output, mesh)
                counts = (mesh.vertex_count, mesh.face_count)  # what the file holds: a mesh shown twice, twice
                if suffix == ".stl" and shows_appearance(decoder.header.gltf_json if decoder.header else None):
                    notices.append("an STL file holds geometry alone: the asset's texture "
                                   "coordinates, normals, colours and materials are left out (decode to .obj, "
                                   ".ply or .glb to keep them)")
            if why is not None:
                notices.append(f"{why}: the {suffix[1:].upper()} file holds each primitive once, as "
                               "stored, not placed by the scene's nodes; decode to .glb to keep the scene")
    end = stream_end(source, end)  # a URL read up to chunk N: the file on the server may be whole
    out = {"vertices": int(counts[0]), "faces": int(counts[1]), "chunks_applied": int(end.chunks_applied),
           "complete": bool(end.complete), "chunks_total": int(end.chunks_total), "truncated": bool(end.truncated),
           "output": args.output, "files": written, "notices": _chunk_notices(args.chunks, end) + notices}
    if args.json:
        print_json(out)
    else:
        for note in out["notices"]:
            notice(note)
        if args.quiet:
            return 0
        state = "complete file" if end.complete else f"truncated file, {end.bytes_read:,} bytes"
        beside = f" (with {', '.join(written[1:])})" if len(written) > 1 else ""
        print(f"{args.output}{beside}: {out['vertices']:,} vertices, {out['faces']:,} faces "
              f"(base + {out['chunks_applied']} of {out['chunks_total']} chunks; {state})")
    return 0


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
    """Whether an OBJ / PLY / STL / OFF of the ``.pmw`` at path ``src`` (its header alone is read) needs the
    whole decoded document: its scene shows triangles that are not progressive
    (:func:`~pmwm_codec.stream.asset.plain_triangle_primitives`), or, ``styled`` (an OBJ or PLY that keeps
    the appearance), texture coordinates, normals, colours or materials
    (:func:`~pmwm_codec.meshexport.shows_appearance`).  Standard input, which cannot be read twice, is read
    whole in any case (True)."""
    if src == "-":
        return True
    gltf = read_header(src).gltf_json
    return bool(plain_triangle_primitives(gltf)) or (styled and shows_appearance(gltf))


def _chunk_notices(asked, end) -> list:
    """Say so when ``--chunks`` asked for more chunks than the file holds (or than arrived)."""
    if asked is None or asked <= end.chunks_applied:
        return []
    if end.complete:
        return [f"--chunks {asked}: the file has {end.chunks_total} chunks; decoded all of them (full resolution)"]
    return [f"--chunks {asked}: only {end.chunks_applied} of {end.chunks_total} chunks arrived whole; decoded those"]
