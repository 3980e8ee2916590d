"""Shared topology helpers: unique edges, mean edge length, canonical faces."""

from __future__ import annotations

import warnings

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.progressive.topology import canonical_faces, mean_edge_length, same_face_set, unique_edges

SQUARE = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
TWO_TRIANGLES = np.array([[0, 1, 2], [0, 2, 3]])


def test_unique_edges_lists_each_undirected_edge_once_sorted():
    edges = unique_edges(TWO_TRIANGLES)
    assert edges.dtype == np.int64 and edges.shape == (5, 2)
    assert edges.tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]


def test_unique_edges_of_no_faces_is_empty():
    edges = unique_edges(np.zeros((0, 3), np.int64))
    assert edges.shape == (0, 2) and edges.dtype == np.int64


def test_mean_edge_length_counts_shared_edges_once():
    expected = (4 * 1.0 + np.sqrt(2.0)) / 5
    assert mean_edge_length(SQUARE, TWO_TRIANGLES) == expected


def test_mean_edge_length_without_faces_is_zero_and_silent():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert mean_edge_length(SQUARE, np.zeros((0, 3), np.int64)) == 0.0


def test_mean_edge_length_of_a_sphere_matches_a_direct_sum():
    mesh = shapes.icosphere(2, 1.0)
    e = np.concatenate([mesh.faces[:, [0, 1]], mesh.faces[:, [1, 2]], mesh.faces[:, [2, 0]]])
    e = {tuple(sorted(map(int, pair))) for pair in e}
    direct = np.mean([np.linalg.norm(mesh.positions[a] - mesh.positions[b]) for a, b in e])
    assert np.isclose(mean_edge_length(mesh.positions, mesh.faces), direct)


def test_canonical_faces_rotates_keeps_orientation_and_sorts():
    faces = np.array([[5, 3, 4], [2, 0, 1]])
    out = canonical_faces(faces)
    assert out.dtype == np.int64
    assert out.tolist() == [[0, 1, 2], [3, 4, 5]]


def test_same_face_set_ignores_order_and_rotation_not_orientation():
    faces = np.array([[0, 1, 2], [2, 3, 0], [1, 3, 2]])
    shuffled = np.array([[3, 2, 1], [1, 2, 0], [0, 2, 3]])
    assert same_face_set(faces, shuffled)
    flipped = faces.copy()
    flipped[0] = [0, 2, 1]
    assert not same_face_set(faces, flipped)
    assert not same_face_set(faces, faces[:2])


def test_same_face_set_is_a_multiset_comparison():
    a = np.array([[0, 1, 2], [0, 1, 2], [1, 2, 3]])
    b = np.array([[0, 1, 2], [1, 2, 3], [1, 2, 3]])
    assert not same_face_set(a, b)
