"""``pmw info IN.pmw``: the structure of a ``.pmw`` from its header and JSON (no chunk decoded)."""

from __future__ import annotations

from pmwm_codec.format.inspect import inspect
from pmwm_codec.http import is_url

from .common import check_input_file, naming, print_json


def add_parser(sub):
    p = sub.add_parser("info", help="structure of a .pmw from its header (no chunk decoded)",
                       description="Show the structure of a .pmw from its header and glTF JSON (no chunk decoded): counts, base "
                                   "codec, grid, chunk table, public watermark parameters, complete or truncated.")
    p.add_argument("input", metavar="IN.pmw|URL", help="the .pmw, or an http(s):// URL of one (its header is fetched)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run)


def run(args) -> int:
    url = is_url(args.input)
    if not url:
        check_input_file(args.input, ".pmw file", stdin=True)
    with naming(args.input):
        info = inspect(args.input)  # a URL: the header only
    if args.json:
        print_json(info)
        return 0
    print(text(info))
    return 0


def text(i) -> str:
    state = ("complete" if i["complete"] else f"TRUNCATED: {i['chunks_present']} of {i['chunks_total']} chunks present") \
        if i["complete"] is not None else "size unknown (standard input or a URL: the header only was read)"
    size = f"{i['bytes']:,} of {i['total_length']:,} bytes" if i["bytes"] is not None else f"{i['total_length']:,} bytes"
    g = i["grid"] or {}
    lines = [f"{i['file']}: {size}, {state}",
             f"  full mesh   {i['vertices']:,} vertices, {i['faces']:,} faces",
             f"  base mesh   {i['base_vertices']:,} vertices, {i['base_faces']:,} faces ({i['base_codec']})",
             f"  stream      {i['vsplits']:,} vertex splits in {i['chunks_total']} chunks",
             f"  grid        {g.get('bits')} bits, step {g.get('step', 0):.4g}"]
    if len(i["primitives"]) == 1:  # what rides with the splits besides positions (several: per primitive below)
        lines.append(f"  carries     {', '.join(i['primitives'][0]['attributes']) or 'positions only'}")
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
