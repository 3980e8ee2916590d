"""Doubled-triangle pillows (scans' reconstructions leave them by the hundred) and the simplifier.

A pillow is two faces on the same three vertices, facing opposite ways.  The simplifier moves a
vertex's pillows with it when its other faces are a disk (``simplify.twin_faces`` /
``_twin_counts``); these properties check, on random pillows glued onto a sphere in every way the
rule admits and in some it refuses, that the stream still round-trips exactly through both
payload versions, that every level stays a valid mesh, and that encoding never refuses the mesh.
"""

from __future__ import annotations

import io

import numpy as np
from hypothesis import given, settings, strategies as st

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive.simplify import twin_faces
from pmwm_codec.progressive.topology import edge_table

from test_progressive import assert_same_mesh, assert_valid_level, decode_levels, duplicate_count, progressive_of


def _pillowed(seed: int, count: int, share: bool) -> Mesh:
    """An icosphere with ``count`` random pillows: flaps on a surface edge (a new tip), pillows glued
    along two surface edges a-b-c (a, c not adjacent: a-c is the pillow's own), and, when ``share``,
    pillows free to share vertices and edges with earlier ones (edges of six faces, vertices with
    several pillows: the rule must refuse what it cannot undo)."""
    rng = np.random.default_rng(seed)
    sphere = shapes.icosphere(3, 1.0, noise=0.02, seed=seed % 7)
    V, F = sphere.positions.copy(), sphere.faces
    ring = shapes._rings(F, len(V))
    extra_v, extra_f, used = [], [], set()
    for _ in range(count):
        a = int(rng.integers(len(V)))
        b = int(rng.choice(sorted(ring[a])))
        if not share and ({a, b} | ring[a] | ring[b]) & used:
            continue
        if rng.random() < 0.5:  # a flap with a tip of its own, just off the surface
            tip = len(V) + len(extra_v)
            extra_v.append(0.54 * (V[a] + V[b]))
            tri = (a, b, tip)
        else:  # glued along a-b and b-c
            far = sorted(ring[b] - ring[a] - {a})
            if not far:
                continue
            tri = (a, b, int(rng.choice(far)))
        extra_f += [tri, (tri[1], tri[0], tri[2])]
        used |= set(tri) | ring[a] | ring[b]
    P = np.concatenate([V, np.array(extra_v).reshape(-1, 3)])
    return Mesh(P, np.concatenate([F, np.array(extra_f, np.int64).reshape(-1, 3)]).astype(np.int64))


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 40), share=st.booleans())
def test_pillowed_meshes_round_trip_and_every_level_is_valid(seed, count, share):
    mesh = _pillowed(seed, count, share)
    had_fin = edge_table(mesh.faces, mesh.vertex_count).count.max() > 2
    pm, q = progressive_of(mesh)
    levels = list(decode_levels(pm))
    for positions, faces in levels:
        assert_valid_level(positions, faces, had_fin, duplicate_count(mesh.faces))
    assert_same_mesh(pm, q, mesh.faces, *levels[-1])


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 40), share=st.booleans())
def test_pillowed_meshes_encode_through_both_payload_versions(seed, count, share):
    """The whole path (Draco base, both chunk payloads): the encoder checks every batch against the
    decoder's own kernels, so an illegal collapse would refuse the mesh here."""
    mesh = _pillowed(seed, count, share)
    for version in (1, 2):
        buf = io.BytesIO()
        pmwm_codec.encode(mesh, buf, measure=False, payload_version=version)
        out = pmwm_codec.decode(buf.getvalue())
        assert (out.positions.shape, out.faces.shape) == (mesh.positions.shape, mesh.faces.shape)
        assert int(twin_faces(out.faces).sum()) == int(twin_faces(mesh.faces).sum())


def test_a_flap_tip_another_primitive_shares_stays_at_every_level(tmp_path):
    """A flap's tip (a vertex only pillow faces name) comes in payload version 2's face chunk, after every
    split; where another primitive holds the same position it is a border, locked in the base: its flap
    stays in the simplification, so every level shows the tip in both (it used to be missing in one until
    the last level, a crack the probe found on a four-part scan)."""
    from test_asset import DocBuilder

    from pmwm_codec.format.document import load_document, read_accessor
    from pmwm_codec.stream.asset import decode_asset, encode_asset

    mesh = _pillowed(3, 30, share=False)
    tips = mesh.positions[shapes.icosphere(3, 1.0, noise=0.02, seed=3 % 7).vertex_count:]
    assert len(tips) >= 3
    # the second primitive: a small triangle at each tip, made of the tip and two points beside it
    side = np.array([[0.05, 0.0, 0.0], [0.0, 0.05, 0.0]])
    points = np.concatenate([np.stack([t, t + side[0], t + side[1]]) for t in tips])
    other = Mesh(points, np.arange(len(points)).reshape(-1, 3))
    b = DocBuilder()
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}],
                 meshes=[{"primitives": [b.triangles(mesh, uv=False), b.triangles(other, uv=False)]}])
    (tmp_path / "flaps.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "flaps.glb", tmp_path / "flaps.pmw", measure=False)
    from scipy.spatial import cKDTree

    total = decode_asset(tmp_path / "flaps.pmw")[1].chunks_total
    for chunks in range(total + 1):
        (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "flaps.pmw", chunks=chunks)[0])
        doc, buffers = load_document(tmp_path / "out.glb")
        first, second = (read_accessor(doc, buffers, p["attributes"]["POSITION"]) for p in doc["meshes"][0]["primitives"])
        shared = second[cKDTree(second).query(tips)[1]]  # the tips as the second primitive decodes them (one grid)
        assert {tuple(x) for x in shared} <= {tuple(x) for x in first}, chunks


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), count=st.integers(1, 40), share=st.booleans(), bits=st.sampled_from([8, 10, 16]))
def test_the_core_s_doubled_faces_are_the_mesh_s_outside_the_deferred_ones(seed, count, share, bits):
    """The encoder hands the simplifier ``twin[~late]`` for the core mesh instead of finding its doubled faces
    again: the same faces, because the deferred faces take every face of a vertex triple or none."""
    from pmwm_codec.progressive.grid import Grid
    from pmwm_codec.progressive.simplify import deferred_and_twin_faces
    from pmwm_codec.stream.encoder import _core_vertices

    mesh = shapes.specks(_pillowed(seed, count, share), count=1 + seed % 3, seed=seed % 5)
    n = mesh.vertex_count
    positions = np.concatenate([mesh.positions, [[3.0, 0, 0], [3.0, 1, 0], [3.0, 0, 1]]])  # a pillow of its own
    faces = np.concatenate([mesh.faces, [[n, n + 1, n + 2], [n, n + 2, n + 1]]]).astype(np.int64)
    extra = faces[np.random.default_rng(seed).integers(0, len(faces), 3)]  # a third face on some pillows' triples
    faces = np.concatenate([faces, extra[:, ::-1]])
    late, twin = deferred_and_twin_faces(Grid.fit(positions, bits).quantize(positions), faces)
    _, _, local = _core_vertices(len(positions), faces, late)
    assert np.array_equal(twin_faces(local[faces[~late]]), twin[~late])
    assert late.any()
