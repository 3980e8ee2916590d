"""A chunk payload version 2 whose first batch splits two adjacent vertices, each moving a face
that holds the other (a batch an encoder never writes, which a decoder applies all the same),
then three batches of many splits whose selection masks read the valences the first left: prints JSON {D, capN, capM, base: {values, faces}, chunk (hex), final:
{values, faces}}, the final mesh as the reference decoder gives it (pmwm_codec.format.records_v2).

    python dependent_batches.py
"""

import json

import numpy as np

from pmwm_codec.format.records_v2 import ChunkDecoder, decode_chunk, pack_chunks
from pmwm_codec.progressive.vsplit import MeshState, SplitBatch, apply_batch, find_incidences

SIDE = 5


def grid(side: int = SIDE, extra: bool = False):
    """A side x side grid of vertices on z = x * y (int64 (n, 3); with ``extra`` two more columns
    x + 3y and -7x), two triangles per cell (int64 (m, 3))."""
    values = np.array([(4 * x, 4 * y, x * y) + ((x + 3 * y, -7 * x) if extra else ())
                       for y in range(side) for x in range(side)], np.int64)
    faces = []
    for y in range(side - 1):
        for x in range(side - 1):
            p = y * side + x
            faces += [(p, p + 1, p + side + 1), (p, p + side + 1, p + side)]
    return values, np.array(faces, np.int64)


def batch(state, v, moved):
    """Splits of the vertices v (ascending), split i moving its incidence moved[i] with both new faces."""
    inc, owner = find_incidences(state, np.asarray(v, np.int64))
    symbols = np.zeros(len(inc), np.uint8)
    for i, j in enumerate(moved):
        symbols[np.flatnonzero(np.asarray(owner) == i)[j]] = 4
    residual = np.arange(3 * len(v), dtype=np.int64).reshape(len(v), 3) % 3 - 1
    return SplitBatch(np.asarray(v, np.int64), symbols, residual)


def main():
    values, faces = grid()
    cap_n, cap_m = 4 * len(values), 8 * len(faces)
    state = MeshState(values, faces, cap_n, cap_m)
    # 6 moves its 5th face (6, 7, 12), 12 its 2nd (6, 12, 11): each moved face holds the other split vertex
    first = batch(state, [6, 12], [4, 1])
    probe = MeshState(values, faces, cap_n, cap_m)
    batches = [first]
    apply_batch(probe, first)
    for r in range(3):  # then every third vertex, each moving its first face
        later = batch(probe, list(range(r, probe.n, 3)), [0] * len(range(r, probe.n, 3)))
        batches.append(later)
        apply_batch(probe, later)
    chunk = pack_chunks(MeshState(values, faces, cap_n, cap_m), [batches])[0]
    ref = MeshState(values, faces, cap_n, cap_m)
    for _ in decode_chunk(chunk, ref, ChunkDecoder()):
        pass
    print(json.dumps({
        "D": 3, "capN": cap_n, "capM": cap_m,
        "base": {"values": values.reshape(-1).tolist(), "faces": faces.reshape(-1).tolist()},
        "chunk": bytes(chunk).hex(),
        "final": {"values": ref.positions[: ref.n].reshape(-1).tolist(), "faces": ref.faces[: ref.m].reshape(-1).tolist()},
    }))


if __name__ == "__main__":
    main()
