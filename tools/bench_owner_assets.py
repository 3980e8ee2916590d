"""The owner layer on multi-primitive glTF assets: one layer across every primitive, read from the ``.pmw``,
a decoded GLB and a decoded OBJ.

Each mesh is cut into ``--parts`` primitives by face-centre x (cut-border vertices duplicated in the
parts that share them, as exporters write them) and made into three GLB assets:

* **one mesh** -- one glTF mesh holding every part as a primitive with its own material, under a root node
  that rotates and scales by 2 (a similarity) and a child that translates;
* **meshes** -- one glTF mesh per part, each on its own node under the same root;
* **meshes apart** -- one glTF mesh per part, each on its own node with a transform of its own
  (:data:`APART`): moved apart and turned, one stretched along z (not a similarity), one mirrored;
* **a part shown twice** -- as "meshes", and the last part's mesh shown again by a second node, moved
  by 0.3 of the mesh's extent: its copies stay unmarked, the other parts carry the layer;
* **every part shown twice** -- as "meshes", the whole group shown again by a second node that moves it
  by 1.5 times the mesh's extent and turns it: no mesh is shown once, so the layer is marked in the
  meshes' stored coordinates (:func:`~pmwm_codec.format.gltf.owner_placements`);
* **GPU-instanced** -- one glTF mesh per part, each on a node drawing it three times by
  ``EXT_mesh_gpu_instancing`` (translations): marked in the stored meshes too.

Each asset is encoded in memory with an owner ID (``encode_asset((gltf, buffers), ..., owner_id=...)``,
grid 16, no watermark), then read blind as ``pmw verify`` reads it: from the ``.pmw`` at every chunk boundary
(the bytes from which every later boundary reads ``present``), from the decoded asset (a GLB read with its
nodes applied) and from the OBJ ``pmw decode`` writes of it (:func:`~pmwm_codec.stream.asset.scene_as_shown`).
The layer's cost: the RMS and the largest distance from each input vertex to the nearest decoded vertex of its
primitive, both placed by the scene's nodes, as a percentage of the scene's bounding-box
diagonal (quantization on the 16-bit grid included).

    python tools/bench_owner_assets.py [--parts 3] [--heldout /tmp/heldout] [--write BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import io
import os
import shlex
import sys
import tempfile
import time

import numpy as np
from scipy.spatial import cKDTree

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from pmwm_codec import read_mesh  # noqa: E402
from pmwm_codec.errors import OwnerLayerError  # noqa: E402
from pmwm_codec.format.document import load_document, read_accessor  # noqa: E402
from pmwm_codec.format.gltf import owner_placements, place  # noqa: E402
from pmwm_codec.format.layout import padded  # noqa: E402
from pmwm_codec.mesh import Mesh  # noqa: E402
from pmwm_codec.meshio import write_mesh  # noqa: E402
from pmwm_codec.stream import StreamDecoder  # noqa: E402
from pmwm_codec.stream.asset import decode_asset, encode_asset, scene_as_shown  # noqa: E402
from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream  # noqa: E402
from pmwm_codec.watermark.key import WatermarkKey  # noqa: E402
from tools.bench import DEFAULT_CORPUS, machine, publish, run_header, table  # noqa: E402

SECTION = "Owner layer on multi-primitive assets"
OWNER_ID = 0x0123456789ABCDEF
#: the root's rotation (45 degrees about y) and scale, and the child's translation
ROOT_NODE = {"rotation": [0.0, 0.38268343, 0.0, 0.92387953], "scale": [2.0, 2.0, 2.0]}
CHILD_SHIFT = [1.0, 2.0, 3.0]
#: "meshes apart": part i's node (cycled), its translation in units of the whole mesh's largest extent
APART = [{"rotation": [0.0, 0.0, 0.38268343, 0.92387953], "translation": [1.5, 0.0, 0.0]},
         {"scale": [1.0, 1.0, 2.0], "translation": [0.0, -1.5, 0.5]},
         {"scale": [-1.0, 1.0, 1.0], "rotation": [0.5, 0.5, 0.5, 0.5], "translation": [0.0, 0.0, 1.5]}]
KINDS = ("one mesh", "meshes", "meshes apart", "a part shown twice", "every part shown twice", "GPU-instanced")


def parts_of(mesh: Mesh, parts: int) -> list:
    """``mesh`` cut into ``parts`` meshes by face-centre x; vertices on a cut belong to both sides."""
    centre = mesh.positions[mesh.faces].mean(1)[:, 0]
    out = []
    for rows in np.array_split(np.argsort(centre, kind="stable"), parts):
        used, inverse = np.unique(mesh.faces[np.sort(rows)], return_inverse=True)
        out.append(Mesh(mesh.positions[used], inverse.reshape(-1, 3)))
    return out


def asset(parts: list, kind: str) -> tuple:
    """``(gltf dict, [buffer bytes])`` of the parts (float32 positions, uint32 indices)."""
    doc = {"asset": {"version": "2.0"}, "accessors": [], "bufferViews": [], "materials": [], "scene": 0}
    blob, prims = [], []

    def view(raw: bytes, target: int) -> int:
        offset = sum(len(b) for b in blob)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": offset, "byteLength": len(raw), "target": target})
        blob.append(raw + bytes(padded(len(raw)) - len(raw)))
        return len(doc["bufferViews"]) - 1

    for i, part in enumerate(parts):
        p = part.positions.astype(np.float32)
        doc["accessors"].append({"bufferView": view(p.tobytes(), 34962), "componentType": 5126, "count": len(p),
                                 "type": "VEC3", "min": p.min(0).tolist(), "max": p.max(0).tolist()})
        f = part.faces.astype(np.uint32).ravel()
        doc["accessors"].append({"bufferView": view(f.tobytes(), 34963), "componentType": 5125, "count": len(f),
                                 "type": "SCALAR"})
        doc["materials"].append({"name": f"part{i}"})
        prims.append({"attributes": {"POSITION": 2 * i}, "indices": 2 * i + 1, "material": i})
    if kind == "one mesh":
        doc["meshes"] = [{"primitives": prims}]
        doc["nodes"] = [{**ROOT_NODE, "children": [1]}, {"mesh": 0, "translation": CHILD_SHIFT}]
    elif kind == "meshes":
        doc["meshes"] = [{"primitives": [p]} for p in prims]
        doc["nodes"] = ([{**ROOT_NODE, "children": [1]}, {"translation": CHILD_SHIFT, "children": list(range(2, 2 + len(parts)))}]
                        + [{"mesh": i} for i in range(len(parts))])
    elif kind == "a part shown twice":  # "meshes", and the last part's mesh shown again by a second node
        size = float(np.ptp(np.concatenate([p.positions for p in parts]), axis=0).max())
        doc["meshes"] = [{"primitives": [p]} for p in prims]
        doc["nodes"] = ([{**ROOT_NODE, "children": [1]},
                         {"translation": CHILD_SHIFT, "children": list(range(2, 3 + len(parts)))}]
                        + [{"mesh": i} for i in range(len(parts))]
                        + [{"mesh": len(parts) - 1, "translation": [0.0, 0.3 * size, 0.0]}])
    elif kind == "every part shown twice":  # "meshes", and the whole group shown again, moved and turned
        size = float(np.ptp(np.concatenate([p.positions for p in parts]), axis=0).max())
        doc["meshes"] = [{"primitives": [p]} for p in prims]
        n = len(parts)
        doc["nodes"] = ([{**ROOT_NODE, "children": [1, 2]},
                         {"translation": CHILD_SHIFT, "children": list(range(3, 3 + n))},
                         {**APART[0], "translation": [1.5 * size, 0.0, 0.0], "children": list(range(3 + n, 3 + 2 * n))}]
                        + [{"mesh": i % n} for i in range(2 * n)])
    elif kind == "GPU-instanced":  # each part drawn three times by EXT_mesh_gpu_instancing
        size = float(np.ptp(np.concatenate([p.positions for p in parts]), axis=0).max())
        doc["meshes"] = [{"primitives": [p]} for p in prims]
        shifts = (size * np.array([[0.0, 0.0, 0.0], [1.5, 0.0, 0.0], [0.0, 1.5, 0.0]])).astype(np.float32)
        doc["accessors"].append({"bufferView": view(shifts.tobytes(), None), "componentType": 5126, "count": 3,
                                 "type": "VEC3"})
        doc["bufferViews"][-1].pop("target")
        inst = {"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": len(doc["accessors"]) - 1}}}
        doc["nodes"] = [{"children": list(range(1, 1 + len(parts)))}] + [
            {"mesh": i, "extensions": inst} for i in range(len(parts))]
        doc["extensionsUsed"] = ["EXT_mesh_gpu_instancing"]
    else:
        size = float(np.ptp(np.concatenate([p.positions for p in parts]), axis=0).max())
        doc["meshes"] = [{"primitives": [p]} for p in prims]
        nodes = [dict(APART[i % len(APART)], mesh=i) for i in range(len(parts))]
        for node in nodes:
            node["translation"] = [size * t for t in node["translation"]]
        doc["nodes"] = [{"children": list(range(1, 1 + len(parts)))}] + nodes
    doc["scenes"] = [{"nodes": [0]}]
    data = b"".join(blob)
    doc["buffers"] = [{"byteLength": len(data)}]
    return doc, [data]


def layer_cost(src_doc, src_buffers, glb: bytes) -> tuple:
    """(RMS %, max %) of the diagonal: each input vertex to the nearest decoded vertex of its primitive,
    both placed as the layer is marked (:func:`~pmwm_codec.format.gltf.owner_placements`: by the scene's
    nodes, once per showing, or where no mesh is shown once, each mesh once as stored)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "out.glb")
        with open(path, "wb") as fh:
            fh.write(glb)
        out, out_buffers = load_document(path)
    before, gaps = [], []
    frames, _ = owner_placements(src_doc, range(len(src_doc["meshes"])))  # where the layer is marked
    for m_in, m_out, showings in zip(src_doc["meshes"], out["meshes"], frames):
        for p_in, p_out in zip(m_in["primitives"], m_out["primitives"]):
            x = read_accessor(src_doc, src_buffers, p_in["attributes"]["POSITION"]).astype(np.float64)
            y = read_accessor(out, out_buffers, p_out["attributes"]["POSITION"]).astype(np.float64)
            for frame in showings:  # every vertex the scene shows
                before.append(place(x, frame))
                gaps.append(cKDTree(place(y, frame)).query(place(x, frame))[0])
    before, gaps = np.concatenate(before), np.concatenate(gaps)
    diagonal = float(np.linalg.norm(before.max(0) - before.min(0)))
    return 100 * float(np.sqrt(np.mean(gaps**2))) / diagonal, 100 * float(gaps.max()) / diagonal


def measure(mesh: Mesh, parts: int, kind: str, seed: int) -> dict:
    doc, buffers = asset(parts_of(mesh, parts), kind)
    key = WatermarkKey.generate(rng=np.random.default_rng(seed))
    buf = io.BytesIO()
    t = time.perf_counter()
    try:
        key = encode_asset((doc, buffers), buf, key=key, owner_id=OWNER_ID, measure=False).key
    except OwnerLayerError as exc:  # the encoder's own read says no: a row that says why
        return {"refused": str(exc)}
    seconds = time.perf_counter() - t
    data = buf.getvalue()
    boundaries = owner_of_stream(data, key, every=True)  # every boundary read (see bench_heldout)
    first = None
    for b in boundaries:
        if b.owner.verdict != "present":
            first = None
        elif first is None:
            first = b
    glb, _, _ = decode_asset(data)
    decoder = StreamDecoder(copy=False)
    last = decoder.feed(data)[-1]
    decoder.close()
    shown, _ = scene_as_shown(decoder.header.gltf_json, last)  # what `pmw decode IN.pmw -o OUT.obj` writes
    with tempfile.TemporaryDirectory() as tmp:
        path, obj = os.path.join(tmp, "decoded.glb"), os.path.join(tmp, "decoded.obj")
        with open(path, "wb") as fh:
            fh.write(glb)
        write_mesh(obj, shown)
        from_glb = owner_of_mesh(path, key)  # as `pmw verify OUT.glb` reads it (owner_view)
        from_obj = owner_of_mesh(obj, key)
    merged = boundaries[-1]
    rms, worst = layer_cost(doc, buffers, glb)
    return {"vertices": int(merged.vertices), "bytes": len(data), "seconds": seconds,
            "pmw": boundaries[-1].owner, "glb": from_glb, "obj": from_obj, "first": first, "rms": rms, "max": worst}


def read_cell(r) -> str:
    return f"{r.verdict} ({r.bit_errors}/64)"


def render(rows, info, command, parts) -> str:
    L = run_header(command, info) + [
         f"Each mesh cut into {parts} primitives by face-centre x (cut-border vertices in both parts). \"one mesh\": "
         "one glTF mesh holding the parts as primitives (a material each), under a root node that rotates by 45 "
         "degrees and scales by 2 and a child that translates; \"meshes\": one glTF mesh per part, each on its own "
         "node under the same root; \"meshes apart\": one glTF mesh per part, each on a node of its own that moves "
         "it apart by 1.5 times the mesh's extent and turns it, one stretched 2x along z (not a similarity), one "
         "mirrored; \"a part shown twice\": as \"meshes\", and the last part's mesh shown again by a second node, "
         "moved by 0.3 of the mesh's extent (its copies are not marked; the cost is over every vertex shown); "
         "\"every part shown twice\": as \"meshes\", the whole group shown again by a second node (moved by 1.5 "
         "extents, turned); \"GPU-instanced\": a mesh per part, each drawn three times by EXT_mesh_gpu_instancing "
         "(no mesh shown once: the layer is marked and read in the stored meshes, each once, and its cost is "
         "measured there). "
         "Encoded with an owner ID (grid 16, no watermark). Read blind: from the `.pmw` (every chunk boundary; "
         "\"present from\": the bytes from which every later boundary reads `present`), from the decoded GLB as "
         "`pmw verify OUT.glb` reads it (its nodes applied, or its stored meshes where no mesh is shown once) and from the OBJ `pmw decode` writes (the scene as "
         "shown, placed by the nodes; read whole and piece by piece, as `pmw verify OUT.obj` reads any mesh file). "
         "Cost: each input vertex against the nearest decoded "
         "vertex of its primitive, both placed by the nodes, % of the scene's diagonal (the 16-bit grid's rounding "
         "included).", ""]
    body = []
    for name, kind, r in rows:
        if "refused" in r:
            body.append([name, kind, "", f"refused: {r['refused']}", "", "", "", "", ""])
            continue
        first = r["first"]
        present_from = (f"{first.bytes_read:,} of {r['bytes']:,} B ({100 * first.bytes_read / r['bytes']:.1f}%)"
                        if first is not None else "never")
        body.append([name, kind, f"{r['vertices']:,}", read_cell(r["pmw"]), read_cell(r["glb"]), read_cell(r["obj"]),
                     present_from,
                     f"{r['rms']:.4f}% / {r['max']:.4f}%", f"{r['seconds']:.1f} s"])
    L.append(table(["mesh", "asset", "vertices", "owner read from the .pmw", "from the decoded GLB (nodes applied)",
                    "from the decoded OBJ", "present from", "layer RMS / max (% diagonal)", "encode"], body))
    return "\n".join(L) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default=DEFAULT_CORPUS)
    ap.add_argument("--heldout", help="directory of tools/heldout.py's meshes (snowden, dragons), optional")
    ap.add_argument("--parts", type=int, default=3)
    ap.add_argument("--write", metavar="MARKDOWN", help=f"replace the '{SECTION}' section of this file")
    args = ap.parse_args(argv)
    command = "python tools/bench_owner_assets.py " + " ".join(
        shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    info = machine()
    sources = [("stanford-bunny", os.path.join(args.corpus, "stanford-bunny.obj")),
               ("fandisk", os.path.join(args.corpus, "fandisk.obj"))]
    if args.heldout:
        sources += [("snowden", os.path.join(args.heldout, "snowden.obj")),
                    ("dragon100k", os.path.join(args.heldout, "dragon100k.obj"))]
    rows = []
    for seed, (name, path) in enumerate(sources):
        if not os.path.exists(path):
            print(f"[{name}] {path} not found: skipped", file=sys.stderr)
            continue
        mesh = read_mesh(path)
        for kind in KINDS:
            print(f"[{name}] {kind}", file=sys.stderr, flush=True)
            rows.append((name, kind, measure(mesh, args.parts, kind, seed)))
    publish(render(rows, info, command.strip(), args.parts), args.write, SECTION,
            lambda s: print(s, file=sys.stderr))


if __name__ == "__main__":
    main()
