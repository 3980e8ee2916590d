"""Slivers: faces with two corners on one grid point that no collapse is sure to remove (two seam copies, or a
boundary ear).  Kept to the base, Draco's own order drops them (their corners share a position) and the base fell
back to Draco's sequential coder (the 437k dragon: 55 KB instead of 15 KB).  The encoder sends them in the face
chunk, and the simplifier makes no new ones."""

from __future__ import annotations

import io
import json
import struct

import numpy as np

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive import simplify as simplify_module
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.progressive.seams import weld_groups
from pmwm_codec.stream import encoder


def _json(data: bytes) -> dict:
    (length,) = struct.unpack_from("<I", data, 12)
    return json.loads(data[20 : 20 + length])


def kissing_with_a_sliver() -> Mesh:
    """:func:`shapes.kissing` with one more face: the first two spheres' own vertices on the shared point and a
    neighbour of the first (a face of no area whose two coincident corners are seam copies)."""
    mesh = shapes.kissing()
    on_point = np.flatnonzero((mesh.positions == 0).all(axis=1))
    a, b = on_point[:2]
    neighbour = next(int(x) for x in mesh.faces[(mesh.faces == a).any(axis=1)].ravel() if x != a)
    return Mesh(mesh.positions, np.vstack([mesh.faces, [[a, neighbour, b]]]))


def _encode(mesh) -> bytes:
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, measure=False)
    return buf.getvalue()


def _canonical(q, faces):
    """Every face as its three grid points, the smallest rotation (orientation kept), sorted."""
    corners = [tuple(tuple(int(x) for x in q[i]) for i in f) for f in faces]
    return sorted(min(c[k:] + c[:k] for k in range(3)) for c in corners)


def test_a_sliver_between_seam_copies_goes_to_the_face_chunk_and_the_base_keeps_dracos_order():
    mesh = kissing_with_a_sliver()
    data = _encode(mesh)
    gltf = _json(data)
    prim = gltf["meshes"][0]["primitives"][0]
    ext = prim["extensions"]["PMWM_progressive_mesh"]
    assert "_PMWM_WELD" in prim["attributes"]  # Draco's own order (its sequential coder needs no weld)
    assert "firstFaceChunk" in ext
    grid = Grid.from_config(ext["grid"])
    out = pmwm_codec.decode(data)
    assert _canonical(grid.quantize(out.positions), out.faces) == _canonical(grid.quantize(mesh.positions), mesh.faces)
    base = pmwm_codec.decode(data, chunks=0)
    q = grid.quantize(base.positions)[base.faces]
    assert not ((q[:, 0] == q[:, 1]).all(1) | (q[:, 1] == q[:, 2]).all(1) | (q[:, 2] == q[:, 0]).all(1)).any()


def test_without_the_deferral_the_sliver_stays_in_the_base_and_draco_falls_back(monkeypatch):
    monkeypatch.setattr(encoder, "_sliver_faces", lambda q, faces, weld: np.zeros(len(faces), bool))
    prim = _json(_encode(kissing_with_a_sliver()))["meshes"][0]["primitives"][0]
    assert "_PMWM_WELD" not in prim["attributes"]  # the sequential coder


def test_sliver_faces_are_copy_pairs_and_boundary_ears_not_interior_pairs_or_flap_tips():
    # 1 and 2 share a point across an interior edge (faces 0, 1); 4 and 5 across a boundary edge (face 3), 5 with a
    # second face (6); 0 and 6 are seam copies across an interior edge (faces 4, 5); 8 shares 7's point and has
    # one face (7): a flap's tip, which 7 collapses into
    q = np.array([[0, 0, 0], [1, 0, 0], [1, 0, 0], [2, 1, 0], [3, 0, 0], [3, 0, 0], [0, 0, 0], [4, 1, 0], [4, 1, 0],
                  [3, 2, 0]], np.int64)
    faces = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4], [6, 0, 3], [0, 6, 1], [3, 9, 5], [7, 8, 9],
                      [3, 7, 9]], np.int64)
    weld = np.array([0, 1, 2, 3, 4, 5, 0, 7, 8, 9], np.int64)
    points = weld_groups(q)
    assert encoder._sliver_faces(points, faces, weld).tolist() == [False, False, False, True, True, True, False,
                                                                   False, False]
    assert encoder._sliver_faces(points, faces, None).tolist() == [False, False, False, True, False, False, False,
                                                                   False, False]


def _filter(point, F, cu, cv, g=None):
    point = np.asarray(point)
    on_shared = np.bincount(point, minlength=len(point))[point] > 1
    moved = np.arange(len(F))  # every face is moved by the collapse of the same row
    return simplify_module._no_new_slivers(point, on_shared, np.asarray(F), g, np.asarray(cu), np.asarray(cv),
                                           moved, moved).tolist()


def test_no_collapse_puts_two_corners_of_a_face_on_one_point():
    # vertices 2 and 3 share a point: collapse 0 -> 3 would make face (0, 1, 2) into (3, 1, 2); 4 -> 5 moves
    # (4, 6, 7) cleanly
    point = [0, 1, 2, 2, 4, 5, 6, 7]
    assert _filter(point, [[0, 1, 2], [4, 6, 7]], [0, 4], [3, 5]) == [False, True]
    # a face that had two corners on one point already may keep them
    assert _filter(point, [[0, 2, 3], [4, 6, 7]], [0, 4], [1, 5]) == [True, True]
    # two seam copies (group 9: vertices 2 and 5, on one point) brought onto one face: refused, and the other
    # collapse of a copy of that group with it
    point = [0, 1, 2, 3, 4, 2, 6, 7]
    g = np.array([0, 1, 9, 3, 4, 9, 6, 7])
    assert _filter(point, [[0, 1, 2], [4, 6, 7]], [0, 4], [5, 3], g) == [False, True]
    # a seam copy's refused collapse (2 -> 8 puts 8 beside 1, on its point) takes its copy's (5 -> 6) with it
    point = [0, 1, 2, 3, 4, 2, 6, 7, 1]
    g = np.array([0, 1, 9, 3, 4, 9, 6, 7, 8])
    assert _filter(point, [[2, 1, 0], [5, 4, 7]], [2, 5], [8, 6], g) == [False, False]
    assert _filter(point, [[2, 1, 0], [5, 4, 7]], [2, 5], [8, 6]) == [False, True]  # no copies: only its own
