"""OBJ and PLY files with appearance (texture coordinates, vertex colours, materials: pmwm_codec.meshdoc).

For each mesh file given (an OBJ with ``vt`` / colours / an MTL, a PLY with colours / texture coordinates):

* **size** -- ``pmwm_codec.encode(path, BytesIO())`` (default options, no watermark) without the bytes of
  its embedded images, against ``DracoPy.encode`` (compression level 7) of the same glTF vertices, their
  positions at 16 bits (the default grid) and the attributes the file carries: texture coordinates at 14
  bits, colours at 8 (Draco's defaults for glTF pipelines are 12 and 8); and the Draco file of the
  positions alone;
* **base** -- the base mesh's vertices against the glTF vertices, and how many positions carry three or
  more glTF vertices (seam corners, which stay in the base);
* **read** -- ``meshdoc.read_appearance`` (the whole document) against ``read_mesh`` (positions and faces
  alone), medians of ``--repeats`` interleaved rounds.

Usage::

    python tools/bench_appearance.py --meshes a.obj b.ply ... [--repeats 5] [--write BENCHMARKS.md]

``--generated`` adds two meshes made here (a UV torus as a textured OBJ, a coloured icosphere as a binary
PLY), so the section has rows without any file from outside.
"""

from __future__ import annotations

import argparse
import io
import os
import shlex
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for p in (ROOT, HERE):
    if p not in sys.path:
        sys.path.insert(0, p)

import pmwm_codec  # noqa: E402
from pmwm_codec import shapes  # noqa: E402
from pmwm_codec.format.document import read_accessor  # noqa: E402
from pmwm_codec.mesh import read_mesh  # noqa: E402
from pmwm_codec.meshdoc import read_appearance  # noqa: E402

from bench import interleaved, machine, publish, run_header, table  # noqa: E402

SECTION = "OBJ and PLY appearance"


def _document_arrays(gltf, buffers) -> tuple:
    """``(positions (n, 3) f32, faces (m, 3) u32, {semantic: (n, k) f32})`` of every primitive stacked."""
    pos, faces, attrs, offset = [], [], {}, 0
    prims = gltf["meshes"][0]["primitives"]
    semantics = sorted({k for p in prims for k in p["attributes"]} - {"POSITION"})
    for prim in prims:
        p = read_accessor(gltf, buffers, prim["attributes"]["POSITION"])
        pos.append(p)
        faces.append(read_accessor(gltf, buffers, prim["indices"]).reshape(-1, 3).astype(np.int64) + offset)
        for k in semantics:
            a = prim["attributes"].get(k)
            attrs.setdefault(k, []).append(read_accessor(gltf, buffers, a) if a is not None else
                                           np.zeros((len(p), 2 if k.startswith("TEXCOORD") else 3), np.float32))
        offset += len(p)
    return (np.concatenate(pos), np.concatenate(faces).astype(np.uint32),
            {k: np.concatenate(v) for k, v in attrs.items()})


def measure(path: str, repeats: int) -> dict:
    import DracoPy

    (gltf, buffers), notices = read_appearance(path)
    if gltf is None:
        raise SystemExit(f"{path}: carries no appearance (read as geometry alone)")
    pos, faces, attrs = _document_arrays(gltf, buffers)
    images = sum(len(im["_bytes"]) for im in gltf.get("images", []))
    buf = io.BytesIO()
    report = pmwm_codec.encode(path, buf)
    extra = {}
    if "TEXCOORD_0" in attrs:
        extra.update(tex_coord=attrs["TEXCOORD_0"].astype(np.float64), tex_coord_quantization_bits=14)
    if "COLOR_0" in attrs:
        extra.update(colors=np.round(attrs["COLOR_0"][:, :3] * 255).astype(np.uint8))
    draco = DracoPy.encode(pos, faces, quantization_bits=16, compression_level=7, **extra)
    draco_positions = DracoPy.encode(pos, faces, quantization_bits=16, compression_level=7)
    _, copies = np.unique(pos, axis=0, return_counts=True)
    timed = interleaved({"document": lambda: read_appearance(path), "positions": lambda: read_mesh(path)}, repeats)
    return {"name": os.path.basename(path), "vertices": len(pos), "faces": len(faces),
            "attributes": ", ".join(sorted(attrs)), "materials": len(gltf.get("materials", [])),
            "ours": len(buf.getvalue()) - images, "images": images, "draco": len(draco),
            "draco_positions": len(draco_positions), "base": report["base_vertices"],
            "corners": int((copies >= 3).sum()), "positions": len(copies),
            "read_doc": timed["document"][0], "read_pos": timed["positions"][0]}


def generated(folder: str) -> list:
    """A UV torus as a textured OBJ (an MTL, a PNG), and a coloured icosphere as a binary PLY."""
    from PIL import Image


    torus = shapes.uv_torus(96, 48)
    pos, vid = np.unique(torus.positions, axis=0, return_inverse=True)
    vid = vid.reshape(-1)
    uv = torus.attributes["TEXCOORD_0"]
    lines = ["mtllib t.mtl", "usemtl skin"] + ["v %.9f %.9f %.9f" % tuple(p) for p in pos]
    lines += ["vt %.9f %.9f" % tuple(t) for t in uv]
    lines += ["f " + " ".join(f"{vid[i] + 1}/{i + 1}" for i in f) for f in torus.faces]
    with open(os.path.join(folder, "uv-torus.obj"), "w") as fh:
        fh.write("\n".join(lines) + "\n")
    with open(os.path.join(folder, "t.mtl"), "w") as fh:
        fh.write("newmtl skin\nmap_Kd skin.png\n")
    Image.new("RGB", (64, 64), (180, 90, 40)).save(os.path.join(folder, "skin.png"))
    sphere = shapes.icosphere(5, noise=0.002, seed=3)
    rgb = (np.clip((sphere.positions + 1) / 2, 0, 1) * 255).astype(np.uint8)
    vertex = np.empty(len(sphere.positions), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                              ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, c in enumerate("xyz"):
        vertex[c] = sphere.positions[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        vertex[c] = rgb[:, i]
    face = np.empty(len(sphere.faces), [("n", "u1"), ("i", "<i4", (3,))])
    face["n"], face["i"] = 3, sphere.faces
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(vertex)}\nproperty float x\n"
            "property float y\nproperty float z\nproperty uchar red\nproperty uchar green\nproperty uchar blue\n"
            f"element face {len(face)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    with open(os.path.join(folder, "coloured-sphere.ply"), "wb") as fh:
        fh.write(head + vertex.tobytes() + face.tobytes())
    return [os.path.join(folder, "uv-torus.obj"), os.path.join(folder, "coloured-sphere.ply")]


def render(rows: list, info: dict, command: str) -> str:
    L = run_header(command, info)
    L.append("Our `.pmw` with default options and no watermark (its embedded images left out of its bytes) against "
             "Draco (cl7) of the same glTF vertices: positions at 16 bits, texture coordinates at 14, colours at 8; "
             "`positions alone` is Draco's file without the attributes. Base: the base mesh's glTF vertices; "
             "`seam corners`: positions carrying three or more glTF vertices (they stay in the base). Read: "
             "`meshdoc.read_appearance` (the whole document) against `read_mesh` (positions and faces), medians.")
    L.append("")
    head = ["file", "glTF vertices / faces", "carries", "ours (images)", "Draco with them / positions alone",
            "ratio", "base (seam corners)", "read: document / positions"]
    body = [(r["name"], f"{r['vertices']:,} / {r['faces']:,}",
             r["attributes"] + (f"; {r['materials']} material(s)" if r["materials"] else ""),
             f"{r['ours']:,} B ({r['images']:,} B)", f"{r['draco']:,} / {r['draco_positions']:,} B",
             f"**{r['ours'] / r['draco']:.2f}x**",
             f"{r['base']:,} ({100 * r['base'] / r['vertices']:.1f}%; {r['corners']:,} of {r['positions']:,} positions)",
             f"{r['read_doc']:.3f} / {r['read_pos']:.3f} s") for r in rows]
    L.append(table(head, body))
    return "\n".join(L)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", nargs="*", default=[], help="OBJ / PLY files with appearance")
    ap.add_argument("--generated", action="store_true", help="add two meshes made here (module docstring)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--write", metavar="MARKDOWN", help=f"replace the '{SECTION}' section of this file")
    args = ap.parse_args(argv)
    info = machine()
    command = "python tools/bench_appearance.py " + shlex.join(sys.argv[1:] if argv is None else argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    with tempfile.TemporaryDirectory() as tmp:
        paths = (generated(tmp) if args.generated else []) + list(args.meshes)
        if not paths:
            ap.error("give --meshes FILES or --generated")
        rows = []
        for path in paths:
            log(f"{path} ...")
            rows.append(measure(path, args.repeats))
    publish(render(rows, info, command.strip()), args.write, SECTION, log)
    return 0


if __name__ == "__main__":
    sys.exit(main())
