"""Small generated inputs for tests, the spec's worked example and demos (not public API).

Nothing here reads files: an icosphere-like mesh (deliberately not a unit sphere and
off-centre, so a swapped Draco attribute or a lost origin shows in the bounding
radius) and a ``.pmw`` built from it with random opaque chunk payloads.
"""

from __future__ import annotations

import numpy as np

from .base import encode_base
from .glb import build_pmw

ICOSPHERE_RADIUS = 2.5
ICOSPHERE_CENTRE = (0.75, -1.25, 3.0)


def icosphere(subdivisions: int = 2, radius: float = ICOSPHERE_RADIUS, centre=ICOSPHERE_CENTRE):
    """An icosahedron subdivided ``subdivisions`` times, projected on a sphere.

    Returns positions (n, 3) float64 and faces (m, 3) int64 with
    ``n = 10 * 4**s + 2`` and ``m = 20 * 4**s``, counter-clockwise seen from outside.
    """
    t = (1 + 5 ** 0.5) / 2
    v = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
                  [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float)
    f = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
                  [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
                  [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]], np.int64)
    for _ in range(subdivisions):
        edges = np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1)
        unique, inverse = np.unique(edges, axis=0, return_inverse=True)
        mid = inverse.reshape(3, -1).T + len(v)  # (m, 3): midpoints of edges 01, 12, 20
        v = np.vstack([v, (v[unique[:, 0]] + v[unique[:, 1]]) / 2])
        a, b, c = f.T
        ab, bc, ca = mid.T
        f = np.concatenate([np.c_[a, ab, ca], np.c_[b, bc, ab], np.c_[c, ca, bc], np.c_[ab, bc, ca]])
    v = v / np.linalg.norm(v, axis=1, keepdims=True) * radius + np.asarray(centre)
    return v, f


def to_grid(positions, bits: int = 14):
    """Quantize (n, 3) float positions onto a ``bits`` grid: ((n, 3) int64, grid dict)."""
    lo = positions.min(0)
    step = float((positions.max(0) - lo).max() / ((1 << bits) - 1))
    ints = np.rint((positions - lo) / step).astype(np.int64)
    return ints, {"bits": bits, "origin": [float(x) for x in lo], "step": step}


def sample_pmw(codec: str = "plain", chunk_count: int = 3, subdivisions: int = 1, seed: int = 0,
               chunk_sizes=None):
    """A small ``.pmw`` with random opaque payloads.

    Returns ``(data: bytes, base: EncodedBase, payloads: list[bytes], extension: dict)``.
    """
    rng = np.random.default_rng(seed)
    positions, faces = icosphere(subdivisions)
    ints, grid = to_grid(positions)
    base = encode_base(ints, faces, grid, codec=codec)
    sizes = chunk_sizes or [int(s) for s in rng.integers(1, 400, chunk_count)]
    # half random (incompressible), half repetitive, so stored sizes vary
    payloads = [bytes(rng.integers(0, 256, s // 2, dtype=np.uint8)) + bytes(s - s // 2) for s in sizes]
    meta = [{"splits": 10 * (k + 1), "vertexCount": base.vertex_count + 10 * (k + 1),
             "faceCount": base.face_count + 20 * (k + 1), "geometricError": 0.5 / (k + 1)}
            for k in range(len(payloads))]
    extension = {"grid": grid, "vertexCount": base.vertex_count + 10 * len(payloads),
                 "faceCount": base.face_count + 20 * len(payloads),
                 "watermark": {"mode": "exact", "bits": 2, "scale": 10.0, "width": 16, "height": 16,
                               "levels": 4, "codes": 40, "carriers": 30}}
    data = build_pmw(base=base, chunks=payloads, chunk_meta=meta, extension=extension)
    return data, base, payloads, extension
