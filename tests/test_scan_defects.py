"""Scan-like meshes with the defects reconstructions leave, mixed at random, through the whole encoder.

Each defect has its own path through the encoder of payload version 2: pillows glued on the surface and
flaps with a tip of their own go to the face chunk, fins of two pillows and bubbles on an edge of four
faces stay in the simplification, specks (a triangle smaller than a grid step) come as faces of new
vertices only, doubled faces, copies of a vertex on its grid point and slivers (a vertex a hair from
another) meet the weld and the sliver rules.  Whatever mix a mesh has, at any grid, the file must decode
to every face of the input, on the grid, and every prefix to whole chunks.
"""

from __future__ import annotations

import io

import numpy as np
from hypothesis import given, settings, strategies as st

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.format import read_header
from pmwm_codec.mesh import Mesh

from test_payload_v2 import assert_prefixes_decode_to_whole_chunks, face_set

DEFECTS = ("pillow", "flap", "fin", "bubble", "speck", "doubled", "copy", "sliver")


def scan_like(seed: int, count: int) -> Mesh:
    """One of five generated surfaces with ``count`` defects of :data:`DEFECTS`, each on a random face."""
    rng = np.random.default_rng(seed)
    surface = [shapes.icosphere(3, 1.0, noise=0.02, seed=seed % 5), shapes.torus(24, 12, twist=0.1),
               shapes.grid(12, 10, hole=True), shapes.bowtie(), shapes.kissing()][seed % 5]
    P = surface.positions
    V, F, n = [P], [surface.faces], surface.vertex_count
    for _ in range(count):
        x, y, z = (int(v) for v in surface.faces[int(rng.integers(surface.face_count))])
        kind = DEFECTS[int(rng.integers(len(DEFECTS)))]
        if kind == "pillow":  # on the face's own triple
            new_v, new_f = [], [[x, y, z], [x, z, y]]
        elif kind == "flap":  # a tip of its own off the edge x-y
            new_v, new_f = [(P[x] + P[y]) / 2 + 0.05 * rng.standard_normal(3)], [[x, y, n], [y, x, n]]
        elif kind == "fin":  # a pillow off x, and a second one beyond it (p below q and r)
            new_v = list(P[x] + 0.05 * rng.standard_normal((3, 3)))
            p, q, r = n, n + 1, n + 2
            new_f = [[x, q, r], [x, r, q], [p, q, r], [p, r, q]]
        elif kind == "bubble":  # a tetrahedron on the edge x-y (four faces on it)
            new_v = list((P[x] + P[y]) / 2 + 0.05 * rng.standard_normal((2, 3)))
            new_f = [[x, y, n], [y, x, n + 1], [x, n, n + 1], [y, n + 1, n]]
        elif kind == "speck":
            new_v, new_f = list(P[x] + 1e-9 * np.eye(3)), [[n, n + 1, n + 2]]
        elif kind == "doubled":
            new_v, new_f = [], [[x, y, z]]
        elif kind == "copy":  # a second vertex on x's point, with a face of its own
            new_v, new_f = [P[x].copy()], [[n, y, z]]
        else:  # a sliver: a vertex a hair from x
            new_v, new_f = [P[x] + 1e-9], [[n, y, x]]
        V.append(np.array(new_v).reshape(-1, 3))
        F.append(np.array(new_f, np.int64))
        n += len(new_v)
    return Mesh(np.concatenate(V), np.concatenate(F).astype(np.int64))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(0, 12), bits=st.sampled_from([10, 12, 14, 16]))
def test_any_mix_of_scan_defects_encodes_and_decodes_to_every_face_on_the_grid(seed, count, bits):
    mesh = scan_like(seed, count)
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, measure=False, grid_bits=bits)
    data = buf.getvalue()
    out = pmwm_codec.decode(data)
    assert (out.positions.shape, out.faces.shape) == (mesh.positions.shape, mesh.faces.shape)
    grid = read_header(data).extension["grid"]
    original = np.round((mesh.positions - grid["origin"]) / grid["step"]).astype(np.int64)
    decoded = np.round((out.positions - grid["origin"]) / grid["step"]).astype(np.int64)
    assert face_set(decoded, out.faces) == face_set(original, mesh.faces)
    assert_prefixes_decode_to_whole_chunks(data, range(0, len(data), max(1, len(data) // 23)))
