"""``pmw decode IN.pmw|URL|- -o OUT.(glb|gltf|obj|ply|stl|off) [--chunks N] [--geometry-only]``: a level of detail
as an ordinary mesh file, by :func:`pmwm_codec.stream.export.decode_to` (the library call, which says what each
format keeps); this module checks the arguments and prints its result.
"""

from __future__ import annotations

import os

from pmwm_codec.errors import OptionError
from pmwm_codec.http import is_url
from pmwm_codec.meshio import WRITE_SUFFIXES
from pmwm_codec.sources import shown_path
from pmwm_codec.stream.export import decode_to

from .common import UsageError, check_input_file, check_output_path, naming, notice, print_json


def add_parser(sub):
    p = sub.add_parser(
        "decode", help=".pmw (whole, cut or on stdin) -> GLB/glTF/OBJ/PLY/STL/OFF",
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
    if args.chunks is not None and args.chunks < 0:
        raise UsageError(f"--chunks must be >= 0, got {args.chunks}")
    url = is_url(args.input)
    if not url:
        check_input_file(args.input, ".pmw file", stdin=True)
    check_output_path(args.output, "mesh", inputs=() if url else (args.input,))  # '-', a folder: named as such
    suffix = os.path.splitext(args.output)[1].lower()
    if suffix not in WRITE_SUFFIXES:
        raise UsageError(f"{shown_path(args.output)}: unknown output format {suffix or '(no suffix)'!r}; "
                         f"use one of {', '.join(WRITE_SUFFIXES)}")
    with naming(args.input):
        try:
            out = decode_to(args.input, args.output, chunks=args.chunks, geometry_only=args.geometry_only)
        except OptionError as exc:  # an output (an OBJ's MTL, a texture beside it) that cannot be written,
            raise UsageError(str(exc)) from None  # named alone: the input is not what is wrong
    bytes_read = out.pop("bytes_read")
    if args.json:
        print_json(out)
    else:
        for note in out["notices"]:
            notice(note)
        if args.quiet:
            return 0
        state = "complete file" if out["complete"] else f"truncated file, {bytes_read:,} bytes"
        written = out["files"]
        beside = f" (with {', '.join(written[1:])})" if len(written) > 1 else ""
        print(f"{shown_path(args.output)}{beside}: {out['vertices']:,} vertices, {out['faces']:,} faces "
              f"(base + {out['chunks_applied']} of {out['chunks_total']} chunks; {state})")
    return 0
