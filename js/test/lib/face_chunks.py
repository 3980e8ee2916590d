"""The Python side of js/test/face-chunk.test.js: face chunks (spec/bitstream.md §8.6) written by the
reference encoder (pmwm_codec.format.records_v2), printed as JSON.

    python face_chunks.py tetrahedron
        {"chunk": hex}: pack_face_chunk of the spec's example (the tetrahedron, (0,1,3) and (0,3,1))
    python face_chunks.py sequence
        {D, capN, capM, base: {values, faces}, chunks: [{chunk (hex), splits, faceCount, values, faces}]}:
        one primitive's chunks in order -- splits, two face chunks, two batches of splits, a face chunk --
        each with the mesh after it as the reference decoder gives it

The sequence puts face chunks between chunks that split (the reference encoder only sends them
last), so that a decoder must read the splits after them against the mesh the face chunks left.
"""

import json
import sys

import numpy as np

from pmwm_codec.format.records_v2 import (
    ChunkDecoder, FaceChunk, decode_chunk, decode_face_chunk, pack_chunks, pack_face_chunk,
)
from pmwm_codec.progressive.vsplit import MeshState, SplitBatch, apply_batch, find_incidences

SIDE = 6
TETRAHEDRON = [(0, 1, 2), (0, 2, 3), (0, 3, 1), (1, 3, 2)]


def grid():
    """A SIDE x SIDE grid of vertices on z = x * y (int64 (n, 3)), two triangles per cell (int64 (m, 3))."""
    values = np.array([(4 * x, 4 * y, x * y) for y in range(SIDE) for x in range(SIDE)], np.int64)
    faces = []
    for y in range(SIDE - 1):
        for x in range(SIDE - 1):
            p = y * SIDE + x
            faces += [(p, p + 1, p + SIDE + 1), (p, p + SIDE + 1, p + SIDE)]
    return values, np.array(faces, np.int64)


def batch(state, v):
    """Splits of the vertices v (ascending), each moving its first incidence with both new faces."""
    inc, owner = find_incidences(state, np.asarray(v, np.int64))
    symbols = np.zeros(len(inc), np.uint8)
    for i in range(len(v)):
        symbols[np.flatnonzero(np.asarray(owner) == i)[0]] = 4
    residual = np.arange(3 * len(v), dtype=np.int64).reshape(len(v), 3) % 5 - 2
    return SplitBatch(np.asarray(v, np.int64), symbols, residual)


def new_faces(state, seed):
    """Faces to append to ``state``: pillows (x, y, z) + (x, z, y) on paths x-y-z of mesh edges, the
    reverse of an existing face alone, and a lone face between vertices far apart (coded raw)."""
    rng = np.random.default_rng(seed)
    faces = state.faces[: state.m]
    ring = [set() for _ in range(state.n)]
    for a, b, c in faces.tolist():
        ring[a] |= {b, c}
        ring[b] |= {a, c}
        ring[c] |= {a, b}
    out = []
    for y in rng.choice(state.n, 4, replace=False).tolist():
        x = int(rng.choice(sorted(ring[y])))
        far = sorted(ring[y] - ring[x] - {x})
        if far:
            z = int(rng.choice(far))
            out += [(x, y, z), (x, z, y)]
    a, b, c = faces[int(rng.integers(state.m))].tolist()
    out.append((a, c, b))
    out.append((state.n - 1, 1, state.n // 2))
    return np.array(out, np.int64)


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

    def face_chunk(seed):  # the probe gets the faces in the order the decoder appends them
        f = new_faces(probe, seed)
        decode_face_chunk(pack_face_chunk(probe.faces[: probe.m], probe.n, f), probe, ChunkDecoder(), len(f))
        plan.append(FaceChunk(f))

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
        if isinstance(step, FaceChunk):
            decode_face_chunk(payload, ref, model, len(step.faces))
        else:
            for _ in decode_chunk(payload, ref, model):
                pass
        chunks.append({"chunk": bytes(payload).hex(), "splits": ref.n - n0, "faceCount": ref.m,
                       "values": ref.positions[: ref.n].reshape(-1).tolist(),
                       "faces": ref.faces[: ref.m].reshape(-1).tolist()})
    assert ref.n == probe.n and (ref.faces[: ref.m] == probe.faces[: probe.m]).all()
    return {"D": 3, "capN": cap_n, "capM": cap_m,
            "base": {"values": values.reshape(-1).tolist(), "faces": faces.reshape(-1).tolist()}, "chunks": chunks}


def main(command):
    if command == "tetrahedron":
        out = {"chunk": pack_face_chunk(np.array(TETRAHEDRON, np.int64), 4, np.array([(0, 1, 3), (0, 3, 1)], np.int64)).hex()}
    else:
        out = sequence()
    print(json.dumps(out))


if __name__ == "__main__":
    main(*sys.argv[1:])
