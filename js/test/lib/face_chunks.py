"""The Python side of js/test/face-chunk.test.js: face chunks (spec/bitstream.md §8.6) written by the
reference encoder (pmwm_codec.format.records_v2), printed as JSON.

    python face_chunks.py tetrahedron
        {"chunk": hex, "flap": hex}: pack_face_chunk of the spec's examples (the tetrahedron with
        (0,1,3) and (0,3,1); with values and the flap (0,1,4) + (0,4,1), vertex 4 at (7, 9, 11))
    python face_chunks.py sequence
        {D, capN, capM, base: {values, faces}, chunks: [{chunk (hex), face, splits, vertexCount,
        faceCount, values, faces}]}: one primitive's chunks in order -- splits, two face chunks,
        two batches of splits, a face chunk -- each with the mesh after it as the reference decoder
        gives it (face: a face chunk; splits: the vertices it adds)

The sequence puts face chunks between chunks that split (the reference encoder only sends them
last), so that a decoder must read the splits after them against the mesh the face chunks left,
new vertices included; its values have D = 5 columns (x, y, z and two attribute-like columns), and
its face chunks add vertices: flap tips named by one pillow, pairs of new vertices on one face (the
second predicted from the first), new vertices named again by a later face (a raw id), and faces of new
vertices only that name new vertices other faces name (a bubble beyond the mesh, its faces in any rotation).
"""

import json
import sys

import numpy as np

from pmwm_codec.format.records_v2 import (
    ChunkDecoder, FaceChunk, decode_chunk, decode_face_chunk, pack_chunks, pack_face_chunk,
)
from pmwm_codec.progressive.vsplit import MeshState, SplitBatch, apply_batch, find_incidences

import dependent_batches

SIDE = 6
D = 5
TETRAHEDRON = [(0, 1, 2), (0, 2, 3), (0, 3, 1), (1, 3, 2)]


def grid():
    """A SIDE x SIDE grid of vertices on z = x * y with two more columns (int64 (n, D)), two
    triangles per cell (int64 (m, 3))."""
    return dependent_batches.grid(SIDE, extra=True)


def batch(state, v):
    """Splits of the vertices v (ascending), each moving its first incidence with both new faces."""
    inc, owner = find_incidences(state, np.asarray(v, np.int64))
    symbols = np.zeros(len(inc), np.uint8)
    for i in range(len(v)):
        symbols[np.flatnonzero(np.asarray(owner) == i)[0]] = 4
    residual = np.arange(D * len(v), dtype=np.int64).reshape(len(v), D) % 5 - 2
    return SplitBatch(np.asarray(v, np.int64), symbols, residual)


def new_faces(state, seed):
    """Faces to append to ``state`` and the values of the new vertices they name (ids n, n+1, ...):
    pillows (x, y, z) + (x, z, y) on paths x-y-z of mesh edges, the reverse of an existing face
    alone, a lone face between vertices far apart (coded raw), flaps (x, y, tip) + (y, x, tip) on
    mesh edges, a pillow with two new vertices (x, u, w) + (x, w, u), a face naming a flap's tip
    again, and three faces of new vertices only beyond it, naming three more new vertices and u and w."""
    rng = np.random.default_rng(seed)
    n = state.n
    faces = state.faces[: state.m]
    P = state.positions[:n]
    ring = [set() for _ in range(n)]
    for a, b, c in faces.tolist():
        ring[a] |= {b, c}
        ring[b] |= {a, c}
        ring[c] |= {a, b}
    out = []
    for y in rng.choice(n, 4, replace=False).tolist():
        x = int(rng.choice(sorted(ring[y])))
        far = sorted(ring[y] - ring[x] - {x})
        if far:
            z = int(rng.choice(far))
            out += [(x, y, z), (x, z, y)]
    a, b, c = faces[int(rng.integers(state.m))].tolist()
    out.append((a, c, b))
    out.append((n - 1, 1, n // 2))
    values = []
    for _ in range(3):  # flaps: a new tip off a mesh edge x-y
        x, y = faces[int(rng.integers(state.m))][:2].tolist()
        tip = n + len(values)
        values.append((P[x] + P[y]) // 2 + rng.integers(-3, 4, D))
        out += [(x, y, tip), (y, x, tip)]
    x = int(rng.integers(n))  # two new vertices on one face
    u, w = n + len(values), n + len(values) + 1
    values += [P[x] + rng.integers(-9, 10, D), P[x] + rng.integers(-9, 10, D)]
    out += [(x, u, w), (x, w, u)]
    out.append((int(rng.integers(n)), n, u))  # the first flap's tip and u named again
    # beyond the mesh: p < q, named q first by a face of x, then faces of new vertices only naming them
    # (the first starts at p, numbered after q: the encoder rotates it to start at q) and u and w
    p, q, r = n + len(values), n + len(values) + 1, n + len(values) + 2
    values += [P[x] + rng.integers(-9, 10, D) for _ in range(3)]
    out += [(x, q, p), (p, q, r), (r, w, u), (q, u, r)]
    order = rng.permutation(len(out))
    return np.array(out, np.int64)[order], np.array(values, np.int64)


def sequence():
    values, faces = grid()
    cap_n, cap_m = 4 * len(values), 8 * len(faces)
    probe = MeshState(values, faces, cap_n, cap_m)
    plan = []

    def splits(*vertex_sets):
        batches = []
        for v in vertex_sets:
            b = batch(probe, v)
            apply_batch(probe, b)
            batches.append(b)
        plan.append(batches)

    def face_chunk(seed):  # the probe gets the faces and vertices as the decoder appends them
        f, vals = new_faces(probe, seed)
        stored, _ = pack_face_chunk(probe.positions[: probe.n], probe.faces[: probe.m], f, vals)
        decode_face_chunk(stored, probe, ChunkDecoder(), len(vals), len(f))
        plan.append(FaceChunk(f, vals))

    splits(list(range(0, probe.n, 4)))
    face_chunk(1)
    face_chunk(2)
    splits(list(range(1, probe.n, 5)), list(range(2, probe.n, 7)))
    face_chunk(3)
    payloads = pack_chunks(MeshState(values, faces, cap_n, cap_m), plan)
    ref = MeshState(values, faces, cap_n, cap_m)
    model = ChunkDecoder()
    chunks = []
    for step, payload in zip(plan, payloads):
        n0, m0 = ref.n, ref.m
        face = isinstance(step, FaceChunk)
        if face:
            decode_face_chunk(payload, ref, model, len(step.values), len(step.faces))
        else:
            for _ in decode_chunk(payload, ref, model):
                pass
        chunks.append({"chunk": bytes(payload).hex(), "face": face, "splits": ref.n - n0, "vertexCount": ref.n,
                       "faceCount": ref.m, "values": ref.positions[: ref.n].reshape(-1).tolist(),
                       "faces": ref.faces[: ref.m].reshape(-1).tolist()})
    assert ref.n == probe.n and (ref.faces[: ref.m] == probe.faces[: probe.m]).all()
    assert (ref.positions[: ref.n] == probe.positions[: probe.n]).all()
    return {"D": D, "capN": cap_n, "capM": cap_m,
            "base": {"values": values.reshape(-1).tolist(), "faces": faces.reshape(-1).tolist()}, "chunks": chunks}


def main(command):
    if command == "tetrahedron":
        tetra = np.array(TETRAHEDRON, np.int64)
        values = np.arange(12, dtype=np.int64).reshape(4, 3) * 10
        out = {"chunk": pack_face_chunk(np.zeros((4, 3), np.int64), tetra, np.array([(0, 1, 3), (0, 3, 1)]))[0].hex(),
               "flap": pack_face_chunk(values, tetra, np.array([(0, 1, 4), (1, 0, 4)]), [(7, 9, 11)])[0].hex()}
    else:
        out = sequence()
    print(json.dumps(out))


if __name__ == "__main__":
    main(*sys.argv[1:])
