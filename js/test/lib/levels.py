"""The Python side of js/test/payload-v2.test.js: encodes generated cases, prints decoded levels.

    python levels.py encode CASE VERSION OUT.pmw
    python levels.py decode FILE.pmw [FILE.pmw ...]

``encode`` writes ``OUT.pmw`` (the case encoded with chunk payload ``VERSION``, 1 or 2) and prints
one JSON object: the reference decoder's level at every chunk boundary, ``{"levels":
[{"bytesRead", "vertexCount", "faceCount", "parts": [[n, m], ...], "sha256"}, ...], "complete"}``;
``sha256`` is tests/test_golden.py's level digest (positions, faces, quantized attributes as <i8)
and js/test/lib/helpers.js::levelDigest.  ``decode`` prints one such object per file, in order,
as a JSON array, with ``"error"`` (the exception's class name) instead when the decoder refuses
the file.  Cases are generated meshes (``pmwm_codec.shapes``) and seeded keys, so the levels do
not depend on the machine.
"""

from __future__ import annotations

import hashlib
import json
import sys

import numpy as np

from pmwm_codec import PmwError, encode, shapes
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream import StreamDecoder
from pmwm_codec.stream.encoder import PrimitiveJob, encode_document
from pmwm_codec.watermark.key import WatermarkKey

OPTIONS = dict(min_chunk_splits=30, measure="none")


def _with_attributes() -> Mesh:
    """icosphere(3) with a NORMAL (n, 3) and a TEXCOORD_0 (n, 2) per vertex: D = 8 values."""
    sphere = shapes.icosphere(3, 1.1, noise=0.03)
    p = sphere.positions
    normals = p / np.linalg.norm(p, axis=1, keepdims=True)
    uv = np.stack([np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5, np.arccos(normals[:, 2]) / np.pi], 1)
    return Mesh(p, sphere.faces, attributes={"NORMAL": normals, "TEXCOORD_0": uv})


def _stripes(size: int = 16) -> np.ndarray:
    y, x = np.mgrid[0:size, 0:size]
    return (((x // 2 + y // 4) % 2) * 180 + 40).astype(np.uint8)


#: name -> (mesh or list of meshes (one primitive each), encoder options)
CASES = {
    "closed-sphere.draco": lambda: (shapes.icosphere(4, 1.0, noise=0.02), dict(base_codec="draco")),
    "boundaries.plain": lambda: (shapes.grid(20, 14, hole=True), dict(base_codec="plain")),
    "attributes.plain": lambda: (_with_attributes(), dict(base_codec="plain")),
    "two-primitives.draco": lambda: ([shapes.grid(18, 16, hole=True), shapes.torus(24, 12, twist=0.1)],
                                     dict(base_codec="draco")),
    "exact-watermark.draco": lambda: (shapes.icosphere(4, 1.2, noise=0.02), dict(
        base_codec="draco", watermark=_stripes(16), key=WatermarkKey.generate(rng=np.random.default_rng(7)))),
}


def _write(case: str, version: int, out: str) -> None:
    mesh, options = CASES[case]()
    if isinstance(mesh, Mesh):
        encode(mesh, out, payload_version=version, **OPTIONS, **options)
        return
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{} for _ in mesh]}]}
    jobs = [PrimitiveJob(m, 0, i) for i, m in enumerate(mesh)]
    encode_document(doc, b"", jobs, out, payload_version=version, **OPTIONS, **options)


def _digest(r) -> str:
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(r.positions_int, dtype="<i8").tobytes())
    h.update(np.ascontiguousarray(r.faces, dtype="<i8").tobytes())
    attributes = np.concatenate([p.attributes_int for p in r.parts])
    if attributes.size:
        h.update(np.ascontiguousarray(attributes, dtype="<i8").tobytes())
    return h.hexdigest()


def _levels(path: str) -> dict:
    """The decoded levels of the file at ``path`` (module docstring), or ``{"error": class name}``."""
    with open(path, "rb") as f:
        data = f.read()
    dec = StreamDecoder()
    try:
        levels = [{"bytesRead": r.bytes_read, "vertexCount": r.vertices, "faceCount": r.faces_count,
                   "parts": [[len(p.positions_int), len(p.faces)] for p in r.parts], "sha256": _digest(r)}
                  for r in dec.feed(data)]
        return {"levels": levels, "complete": dec.close().complete}
    except PmwError as exc:
        return {"error": type(exc).__name__}


def main(command: str, *args: str) -> None:
    if command == "encode":
        case, version, out = args
        _write(case, int(version), out)
        print(json.dumps(_levels(out)))
    else:
        print(json.dumps([_levels(path) for path in args]))


if __name__ == "__main__":
    main(*sys.argv[1:])
