"""The Python side of js/test/payload-v2.test.js: encodes generated cases, prints decoded levels.

    python levels.py encode CASE VERSION OUT.pmw
    python levels.py decode FILE.pmw [FILE.pmw ...]

``encode`` writes ``OUT.pmw`` (the case encoded with chunk payload ``VERSION``, 1 or 2) and prints
one JSON object: the reference decoder's level at every chunk boundary, ``{"levels":
[{"bytesRead", "vertexCount", "faceCount", "parts": [[n, m], ...], "sha256"}, ...], "complete"}``;
``sha256`` is tests/samples.py's level digest (positions, faces, quantized attributes as <i8)
and js/test/lib/helpers.js::levelDigest.  ``decode`` prints one such object per file, in order,
as a JSON array, with ``"error"`` (the exception's class name) and ``"message"`` instead of ``"complete"``
(and ``"bytesNeeded"`` for a ``TruncatedError``) when the decoder refuses the file (``"levels"`` then those it delivered before refusing).  Cases are generated meshes (``pmwm_codec.shapes``) and seeded keys, so the levels do
not depend on the machine.
"""

from __future__ import annotations

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

import pmwm_codec
from pmwm_codec import PmwError, encode, shapes
from pmwm_codec.errors import TruncatedError
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream import StreamDecoder
from pmwm_codec.stream.encoder import PrimitiveJob, encode_document
from pmwm_codec.watermark.key import WatermarkKey

OPTIONS = dict(min_chunk_splits=30, measure="none")


def _load_golden():
    """tests/test_golden.py of the tree this pmwm_codec comes from: the home of the attribute sphere and
    watermark image used here (its folder on the path: the level digest is tests/samples.py's)."""
    tests = Path(pmwm_codec.__file__).resolve().parents[1] / "tests"
    if str(tests) not in sys.path:
        sys.path.insert(0, str(tests))
    path = tests / "test_golden.py"
    spec = importlib.util.spec_from_file_location("_pmw_test_golden", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


golden = _load_golden()


def _glued_pillows(count: int, seed: int, share: bool, flaps: int = 0, attributes: bool = False) -> Mesh:
    """An icosphere with up to ``count`` glued pillows: the faces (x, y, z) and (x, z, y) on a path
    x-y-z of surface edges (x, z not adjacent), so that all three vertices have other faces and the
    encoder sends the pair in a face chunk (spec/bitstream.md §8.6).  Unless ``share``, no two
    pillows touch each other's vertices or neighbours; with it they may share vertices.

    ``flaps``: as many flaps, pillows (x, y, tip) + (y, x, tip) on a surface edge x-y whose tip is a
    vertex of their own just off the surface (named by no other face: the face chunk adds it); with
    ``share``, also a tip named by two flaps and a pillow with two tips (x, t, w) + (x, w, t).
    ``attributes``: a TEXCOORD_0 and a NORMAL per vertex, tips included (D = 8)."""
    rng = np.random.default_rng(seed)
    sphere = shapes.icosphere(3, 1.0, noise=0.02, seed=seed)
    ring = shapes._rings(sphere.faces, sphere.vertex_count)
    extra, used = [], set()
    for y in rng.permutation(sphere.vertex_count).tolist():
        x = int(rng.choice(sorted(ring[y])))
        far = sorted(ring[y] - ring[x] - {x})
        if len(extra) >= 2 * count or not far:
            continue
        z = int(rng.choice(far))
        if not share and ({x, y, z} | ring[x] | ring[y] | ring[z]) & used:
            continue
        extra += [(x, y, z), (x, z, y)]
        used |= {x, y, z} | ring[x] | ring[y] | ring[z]
    V = [p for p in sphere.positions]
    tips = 0
    for f in rng.permutation(len(sphere.faces)).tolist():
        if tips >= flaps:
            break
        x, y, z = sphere.faces[f].tolist()
        if not share and ({x, y} | ring[x] | ring[y]) & used:
            continue
        t = len(V)
        V.append(0.54 * (V[x] + V[y]) + 0.01 * rng.standard_normal(3))
        extra += [(x, y, t), (y, x, t)]
        used |= {x, y} | ring[x] | ring[y]
        tips += 1
        if share and tips == 2:  # the tip named by a second flap on edge y-z, and a pillow with two tips
            extra += [(y, z, t), (z, y, t)]
            w1, w2 = len(V), len(V) + 1
            V += [0.5 * (V[x] + V[z]) + 0.02, 0.5 * (V[x] + V[z]) - 0.02]
            extra += [(x, w1, w2), (x, w2, w1)]
    P = np.array(V)
    faces = np.concatenate([sphere.faces, np.array(extra, np.int64).reshape(-1, 3)])
    if not attributes:
        return Mesh(P, faces)
    normals = P / np.linalg.norm(P, axis=1, keepdims=True)
    uv = np.stack([0.5 + np.arctan2(P[:, 1], P[:, 0]) / (2 * np.pi), 0.5 + 0.5 * P[:, 2]], 1)
    return Mesh(P, faces, attributes={"TEXCOORD_0": uv, "NORMAL": normals})


#: name -> (mesh or list of meshes (one primitive each), encoder options)
CASES = {
    "closed-sphere.draco": lambda: (shapes.icosphere(4, 1.0, noise=0.02), dict(base_codec="draco")),
    "boundaries.plain": lambda: (shapes.grid(20, 14, hole=True), dict(base_codec="plain")),
    "attributes.plain": lambda: (golden._sphere_with_attributes(), dict(base_codec="plain")),  # D = 8
    "two-primitives.draco": lambda: ([shapes.grid(18, 16, hole=True), shapes.torus(24, 12, twist=0.1)],
                                     dict(base_codec="draco")),
    "exact-watermark.draco": lambda: (shapes.icosphere(4, 1.2, noise=0.02), dict(
        base_codec="draco", watermark=golden._stripes(16), key=WatermarkKey.generate(rng=np.random.default_rng(7)))),
    "pillows.plain": lambda: (_glued_pillows(12, 3, False), dict(base_codec="plain")),
    "pillows-shared.draco": lambda: (_glued_pillows(40, 11, True), dict(base_codec="draco")),
    "flaps.plain": lambda: (_glued_pillows(6, 5, False, flaps=6), dict(base_codec="plain")),
    "flaps-shared.draco": lambda: (_glued_pillows(30, 13, True, flaps=12), dict(base_codec="draco")),
    "flaps-attributes.plain": lambda: (_glued_pillows(8, 17, False, flaps=5, attributes=True), dict(base_codec="plain")),
    "specks.draco": lambda: (shapes.specks(shapes.icosphere(4, 1.0, noise=0.02), 3, seed=5),
                             dict(base_codec="draco", grid_bits=14)),
    # a base Draco stores with copies of its non-manifold vertices, welded back by readers
    "welded.draco": lambda: (shapes.bowtie(), dict(base_codec="draco")),
    # a stream of many chunks (68, in 12 primitives), as a scene of many parts has
    "many-primitives.plain": lambda: ([shapes.torus(24, 12, twist=0.1 * k) for k in range(12)],
                                      dict(base_codec="plain")),
}


#: name -> (meshes (one mesh of one primitive each), the nodes of the scene (node i shows mesh i), encoder
#: options): documents of one primitive per mesh, some of which the scene may leave out
SCENES = {
    "unseen-first-mesh.plain": lambda: ([shapes.grid(18, 16, hole=True), shapes.torus(24, 12, twist=0.1)], [1],
                                        dict(base_codec="plain")),
    "two-meshes.plain": lambda: ([shapes.grid(18, 16, hole=True), shapes.torus(24, 12, twist=0.1)], [0, 1],
                                 dict(base_codec="plain")),
}


def _skinned_sphere() -> Mesh:
    """A noisy sphere bent by two joints along z: JOINTS_0 UNSIGNED_BYTE (0 and 1), WEIGHTS_0 (1 - t, t)."""
    sphere = shapes.icosphere(3, 1.0, noise=0.02, seed=4)
    t = ((sphere.positions[:, 2] + 1) / 2).clip(0, 1)
    joints = np.zeros((sphere.vertex_count, 4), np.uint8)
    joints[:, 1] = 1
    weights = np.zeros((sphere.vertex_count, 4), np.float32)
    weights[:, 1] = t
    weights[:, 0] = 1 - weights[:, 1].astype(np.float64)
    return Mesh(sphere.positions, sphere.faces, {"JOINTS_0": joints, "WEIGHTS_0": weights.astype(np.float64)})


#: name -> (mesh, options): a skinned primitive, in a document whose first node skins it with two joints
SKINNED = {"skinned.plain": lambda: (_skinned_sphere(), dict(base_codec="plain"))}


def _flat_document() -> tuple:
    """``(gltf, [buffer])``: a noisy sphere written flat shaded, as exporters write it: each face its own three
    vertices (indexed) with its face's normal as NORMAL (float32)."""
    sphere = shapes.icosphere(3, 1.0, noise=0.02, seed=4)
    corners = sphere.positions[sphere.faces].reshape(-1, 3).astype(np.float32)
    p = corners.astype(np.float64).reshape(-1, 3, 3)
    normal = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    normal = np.repeat(normal / np.linalg.norm(normal, axis=1, keepdims=True), 3, axis=0).astype(np.float32)
    index = np.arange(len(corners), dtype=np.uint32)
    parts = [corners.tobytes(), normal.tobytes(), index.tobytes()]
    offsets = np.cumsum([0] + [len(b) for b in parts])
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}, "indices": 2}]}],
           "buffers": [{"byteLength": int(offsets[-1])}],
           "bufferViews": [{"buffer": 0, "byteOffset": int(offsets[i]), "byteLength": len(b)} for i, b in enumerate(parts)],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(corners), "type": "VEC3",
                          "min": corners.min(0).tolist(), "max": corners.max(0).tolist()},
                         {"bufferView": 1, "componentType": 5126, "count": len(corners), "type": "VEC3"},
                         {"bufferView": 2, "componentType": 5125, "count": len(index), "type": "SCALAR"}]}
    return doc, [b"".join(parts)]


#: name -> (document, options): assets encoded as `pmw encode` reads a glTF file (pmwm_codec.encode of the document)
ASSETS = {"flat.plain": lambda: (_flat_document(), dict(base_codec="plain"))}


def _write(case: str, version: int, out: str) -> None:
    if case in ASSETS:
        document, options = ASSETS[case]()
        encode(document, out, payload_version=version, **OPTIONS, **options)
        return
    if case in SKINNED:
        mesh, options = SKINNED[case]()
        doc = {"scene": 0, "scenes": [{"nodes": [0, 1]}], "skins": [{"joints": [1, 2]}],
               "nodes": [{"mesh": 0, "skin": 0}, {"name": "j0", "children": [2]}, {"name": "j1", "translation": [0, 0, 1.0]}],
               "meshes": [{"primitives": [{}]}]}
        encode_document(doc, b"", [PrimitiveJob(mesh, 0, 0)], out, payload_version=version, **OPTIONS, **options)
        return
    if case in SCENES:
        meshes, shown, options = SCENES[case]()
        doc = {"scene": 0, "scenes": [{"nodes": shown}], "nodes": [{"mesh": i} for i in range(len(meshes))],
               "meshes": [{"primitives": [{}]} for _ in meshes]}
        jobs = [PrimitiveJob(m, i, 0) for i, m in enumerate(meshes)]
        encode_document(doc, b"", jobs, out, payload_version=version, **OPTIONS, **options)
        return
    mesh, options = CASES[case]()
    if isinstance(mesh, Mesh):
        encode(mesh, out, payload_version=version, **OPTIONS, **options)
        return
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{} for _ in mesh]}]}
    jobs = [PrimitiveJob(m, 0, i) for i, m in enumerate(mesh)]
    encode_document(doc, b"", jobs, out, payload_version=version, **OPTIONS, **options)


def _levels(path: str) -> dict:
    """The decoded levels of the file at ``path`` (module docstring), or ``{"error": class name}``."""
    with open(path, "rb") as f:
        data = f.read()
    dec, levels = StreamDecoder(), []
    try:
        levels += [{"bytesRead": r.bytes_read, "vertexCount": r.vertices, "faceCount": r.faces_count,
                    "parts": [[len(p.positions_int), len(p.faces)] for p in r.parts], "sha256": golden.level_digest(r)}
                   for r in dec.feed(data)]
        return {"levels": levels, "complete": dec.close().complete}
    except PmwError as exc:
        needed = {"bytesNeeded": exc.bytes_needed} if isinstance(exc, TruncatedError) else {}
        return {"levels": levels, "error": type(exc).__name__, "message": str(exc), **needed}


def main(command: str, *args: str) -> None:
    if command == "encode":
        case, version, out = args
        _write(case, int(version), out)
        print(json.dumps(_levels(out)))
    else:
        print(json.dumps([_levels(path) for path in args]))


if __name__ == "__main__":
    main(*sys.argv[1:])
