"""``pmw info IN.pmw``: the structure of a ``.pmw`` from its header and JSON alone (no decoding)."""

from __future__ import annotations

import os

from pmwm_codec.constants import EXTENSION_NAME
from pmwm_codec.format import read_header
from pmwm_codec.format.base import find_extension_primitives
from pmwm_codec.format.layout import CHUNK_HEADER_SIZE, PREAMBLE_SIZE
from pmwm_codec.format.parser import parse_preamble

from .common import check_input_file, naming, print_json


def add_parser(sub):
    p = sub.add_parser("info", help="structure of a .pmw from its header (no decoding)",
                       description="Show the structure of a .pmw from its header and glTF JSON alone: counts, base "
                                   "codec, grid, chunk table, public watermark parameters, complete or truncated.")
    p.add_argument("input", metavar="IN.pmw", help="the .pmw")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run)


def describe(path) -> dict:
    """The ``pmw info --json`` object of the .pmw at ``path`` (from the header and JSON alone).

    Counts are totals over every progressive primitive; ``primitives`` lists each one; the
    chunk table is in stream order (the order the bytes arrive), ``primitive`` saying which
    primitive a chunk refines.
    """
    header = read_header(path)
    gltf = header.gltf_json
    size = os.path.getsize(path) if path != "-" else None
    accessors = gltf.get("accessors", [])
    json_length = header_json_length(gltf, path)
    bin_start = PREAMBLE_SIZE + json_length + CHUNK_HEADER_SIZE if json_length is not None else None
    views = gltf.get("bufferViews", [])
    prims, rows = [], []
    for p, (mi, pi, prim) in enumerate(find_extension_primitives(gltf, EXTENSION_NAME)):
        ext = prim["extensions"][EXTENSION_NAME]
        base_vertices = accessors[prim["attributes"]["POSITION"]]["count"]
        base_faces = accessors[prim["indices"]]["count"] // 3 if "indices" in prim else base_vertices // 3
        prims.append({
            "mesh": mi, "primitive": pi, "name": gltf["meshes"][mi].get("name"),
            "vertices": ext["vertexCount"], "faces": ext["faceCount"],
            "base_vertices": base_vertices, "base_faces": base_faces,
            "base_codec": "draco" if "KHR_draco_mesh_compression" in prim.get("extensions", {}) else "plain",
            "attributes": [a["semantic"] for a in ext.get("attributes", [])], "grid": ext.get("grid"),
            "chunks": len(ext["chunks"]),
        })
        for k, c in enumerate(ext["chunks"]):
            view = views[c["bufferView"]]
            end = None if bin_start is None else bin_start + view.get("byteOffset", 0) + view["byteLength"]
            rows.append((view.get("byteOffset", 0), {
                "primitive": p, "splits": c["splits"], "vertices": c["vertexCount"], "faces": c["faceCount"],
                "bytes": view["byteLength"], "geometric_error": c.get("geometricError"),
                "present": None if (end is None or size is None) else end <= size}))
    chunks = [dict(chunk=i + 1, **row) for i, (_, row) in enumerate(sorted(rows, key=lambda r: r[0]))]
    complete = None if size is None else size >= header.total_length
    ext = header.extension
    wm = ext.get("watermark")
    watermark = None
    if wm:
        watermark = {k: wm.get(k) for k in ("mode", "bits", "width", "height", "levels", "codes", "carriers",
                                            "keyFingerprint")}
    return {
        "file": path, "bytes": size, "total_length": header.total_length, "complete": complete,
        "truncated": None if complete is None else not complete,
        "chunks_present": sum(1 for c in chunks if c["present"]) if size is not None else None,
        "vertices": sum(q["vertices"] for q in prims), "faces": sum(q["faces"] for q in prims),
        "base_vertices": sum(q["base_vertices"] for q in prims), "base_faces": sum(q["base_faces"] for q in prims),
        "base_codec": prims[0]["base_codec"],
        "vsplits": sum(c["splits"] for c in chunks), "chunks_total": header.chunk_count,
        "grid": ext.get("grid"), "payload": ext.get("payload"), "watermark": watermark, "chunks": chunks,
        "primitives": prims,
        "extension": EXTENSION_NAME, "generator": gltf.get("asset", {}).get("generator"),
    }


def header_json_length(gltf, path):
    """Length of the JSON chunk payload, read from the file's preamble (None for stdin)."""
    if path == "-":
        return None
    with open(path, "rb") as fh:
        pre = fh.read(PREAMBLE_SIZE)
    return parse_preamble(pre)[1] if len(pre) == PREAMBLE_SIZE else None


def run(args) -> int:
    check_input_file(args.input, ".pmw file")
    with naming(args.input):
        info = describe(args.input)
    if args.json:
        print_json(info)
        return 0
    print(text(info))
    return 0


def text(i) -> str:
    state = ("complete" if i["complete"] else f"TRUNCATED: {i['chunks_present']} of {i['chunks_total']} chunks present") \
        if i["complete"] is not None else "size unknown (stdin)"
    size = f"{i['bytes']:,} of {i['total_length']:,} bytes" if i["bytes"] is not None else f"{i['total_length']:,} bytes"
    g = i["grid"] or {}
    lines = [f"{i['file']}: {size}, {state}",
             f"  full mesh   {i['vertices']:,} vertices, {i['faces']:,} faces",
             f"  base mesh   {i['base_vertices']:,} vertices, {i['base_faces']:,} faces ({i['base_codec']})",
             f"  stream      {i['vsplits']:,} vertex splits in {i['chunks_total']} chunks",
             f"  grid        {g.get('bits')} bits, step {g.get('step', 0):.4g}"]
    if len(i["primitives"]) > 1:
        lines.append(f"  primitives  {len(i['primitives'])} progressive (one stream, one watermark):")
        for n, q in enumerate(i["primitives"]):
            name = f" {q['name']}" if q.get("name") else ""
            attrs = ", ".join(q["attributes"]) or "positions only"
            lines.append(f"    [{n}] mesh {q['mesh']}{name} primitive {q['primitive']}: {q['vertices']:,} vertices, "
                         f"base {q['base_vertices']:,}, {q['chunks']} chunks; {attrs}")
    w = i["watermark"]
    if w:
        lines.append(f"  watermark   {w['width']}x{w['height']}, {w['levels']} Haar levels, {w['mode']} mode, "
                     f"{w['bits']} bits per code, {w['codes']:,} codes on {w['carriers']:,} carriers "
                     f"(key fingerprint {w['keyFingerprint']})")
    else:
        lines.append("  watermark   none")
    multi = len(i["primitives"]) > 1
    lines.append(f"  {'chunk':>5}" + (f" {'prim':>4}" if multi else "")
                 + f" {'splits':>8} {'vertices':>9} {'faces':>9} {'bytes':>9} {'geom. error':>12}")
    for c in i["chunks"]:
        mark = "" if c["present"] in (True, None) else "  (missing)"
        err = "-" if c["geometric_error"] is None else f"{c['geometric_error']:.4g}"
        lines.append(f"  {c['chunk']:>5}" + (f" {c['primitive']:>4}" if multi else "")
                     + f" {c['splits']:>8,} {c['vertices']:>9,} {c['faces']:>9,} {c['bytes']:>9,} {err:>12}{mark}")
    return "\n".join(lines)
