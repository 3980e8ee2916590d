"""``pmw decode IN.pmw|- -o OUT.(glb|gltf|obj|ply) [--chunks N]``: a level of detail as a plain mesh.

The writers here are deliberately minimal and dependency-free: float32 POSITION and
uint32 indices (glTF/GLB, one buffer; the .gltf embeds it as a data URI), ASCII OBJ,
binary little-endian PLY.  Every output is written atomically.
"""

from __future__ import annotations

import base64
import io
import json
import os
import struct

import numpy as np

from pmwm_codec.format.document import glb_to_gltf
from pmwm_codec.stream import StreamDecoder, iter_results
from pmwm_codec.stream.asset import decode_asset

from .common import UsageError, atomic_output, naming, check_input_file, check_output_path, print_json

FORMATS = (".glb", ".gltf", ".obj", ".ply")
GENERATOR = "pmwm_codec (pmw decode)"


def add_parser(sub):
    p = sub.add_parser(
        "decode", help=".pmw (whole, cut or on stdin) -> GLB/glTF/OBJ/PLY",
        description="Decode a .pmw (whole, truncated, or '-' for standard input) to an ordinary mesh file "
                    "at full resolution or after --chunks N vertex-split chunks.")
    p.add_argument("input", metavar="IN.pmw", help="the .pmw, or - for standard input")
    p.add_argument("-o", "--output", required=True, metavar="OUT", help="output mesh: .glb, .gltf, .obj or .ply")
    p.add_argument("--chunks", type=int, metavar="N", help="stop after the base mesh and N chunks")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(run=run)


def run(args) -> int:
    suffix = os.path.splitext(args.output)[1].lower()
    if suffix not in FORMATS:
        raise UsageError(f"{args.output}: unknown output format {suffix or '(no suffix)'!r}; use one of {', '.join(FORMATS)}")
    if args.chunks is not None and args.chunks < 0:
        raise UsageError(f"--chunks must be >= 0, got {args.chunks}")
    check_input_file(args.input, ".pmw file")
    check_output_path(args.output, "mesh")
    if suffix in (".glb", ".gltf"):
        # the whole glTF document at that level: materials, textures, nodes kept
        with naming(args.input):
            glb, end, decoder = decode_asset(args.input, chunks=args.chunks)
        last = decoder.last
        with atomic_output(args.output) as fh:
            fh.write(glb if suffix == ".glb" else glb_to_gltf(glb))
    else:
        decoder = StreamDecoder(copy=False, max_chunks=args.chunks)
        gen = iter_results(args.input, decoder)
        last = None
        with naming(args.input):
            while True:
                try:
                    last = next(gen)
                except StopIteration as stop:
                    end = stop.value
                    break
        positions = last.mesh.positions.astype(np.float32)
        faces = np.asarray(last.faces, dtype=np.uint32)
        write_mesh(args.output, positions, faces)
    out = {"vertices": int(last.vertices), "faces": int(last.faces_count), "chunks_applied": int(decoder.chunks_applied),
           "complete": bool(end.complete), "chunks_total": int(end.chunks_total), "truncated": bool(end.truncated),
           "output": args.output}
    if args.json:
        print_json(out)
    else:
        state = "complete file" if end.complete else f"truncated file, {end.bytes_read:,} bytes"
        print(f"{args.output}: {out['vertices']:,} vertices, {out['faces']:,} faces "
              f"(base + {out['chunks_applied']} of {out['chunks_total']} chunks; {state})")
    return 0


# -- writers --------------------------------------------------------------------------------

def write_mesh(path, positions, faces) -> None:
    """Write (n, 3) float32 positions and (m, 3) uint32 faces, format by suffix, atomically."""
    suffix = os.path.splitext(path)[1].lower()
    if suffix == ".glb":
        data = glb_bytes(positions, faces)
    elif suffix == ".gltf":
        data = gltf_bytes(positions, faces)
    elif suffix == ".obj":
        data = obj_bytes(positions, faces)
    elif suffix == ".ply":
        data = ply_bytes(positions, faces)
    else:
        raise UsageError(f"{path}: unknown output format {suffix!r}")
    with atomic_output(path) as fh:
        fh.write(data)


def _gltf_document(positions, faces):
    pos = np.ascontiguousarray(positions, dtype="<f4")
    idx = np.ascontiguousarray(faces, dtype="<u4").reshape(-1)
    binary = pos.tobytes() + idx.tobytes()  # 12 n bytes: already 4-aligned
    doc = {
        "asset": {"version": "2.0", "generator": GENERATOR},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": 4}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": int(len(pos)), "type": "VEC3",
             "min": [float(v) for v in pos.min(0)], "max": [float(v) for v in pos.max(0)]},
            {"bufferView": 1, "componentType": 5125, "count": int(len(idx)), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": pos.nbytes, "target": 34962},
            {"buffer": 0, "byteOffset": pos.nbytes, "byteLength": idx.nbytes, "target": 34963},
        ],
        "buffers": [{"byteLength": len(binary)}],
    }
    return doc, binary


def glb_bytes(positions, faces) -> bytes:
    doc, binary = _gltf_document(positions, faces)
    text = json.dumps(doc, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return b"".join([struct.pack("<4sII", b"glTF", 2, total), struct.pack("<I4s", len(text), b"JSON"), text,
                     struct.pack("<I4s", len(binary), b"BIN\0"), binary])


def gltf_bytes(positions, faces) -> bytes:
    doc, binary = _gltf_document(positions, faces)
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(binary).decode("ascii")
    return (json.dumps(doc, indent=1) + "\n").encode("utf-8")


def obj_bytes(positions, faces) -> bytes:
    buf = io.StringIO()
    buf.write(f"# {GENERATOR}: {len(positions)} vertices, {len(faces)} faces\n")
    np.savetxt(buf, np.asarray(positions, np.float64), fmt="v %.9g %.9g %.9g")
    np.savetxt(buf, np.asarray(faces, np.int64) + 1, fmt="f %d %d %d")
    return buf.getvalue().encode("ascii")


def ply_bytes(positions, faces) -> bytes:
    pos = np.ascontiguousarray(positions, dtype="<f4")
    rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<u4", (3,))])
    rec["n"] = 3
    rec["i"] = faces
    header = (f"ply\nformat binary_little_endian 1.0\ncomment {GENERATOR}\n"
              f"element vertex {len(pos)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar uint vertex_indices\nend_header\n")
    return header.encode("ascii") + pos.tobytes() + rec.tobytes()
