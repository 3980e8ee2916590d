"""Attributes predicted on the ring's plane (spec bitstream.md §8.4.3, ``"prediction": "plane"``).

A split's new vertex takes its texture coordinate (colour, normal) from the affine function of the
position fitted by least squares over its ring, where the ring mean had been used: a texture's coordinates
vary about linearly over the surface, so the mean misses by about half an edge and the plane by the
curvature. Payload version 2 only; integer attributes keep the mean.
"""

from __future__ import annotations

import io
import json
import struct

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.errors import FormatError
from pmwm_codec.format import records_v2 as r2
from pmwm_codec.format.extension import check_extension
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.stream import encoder as encoder_module


def _ring(attribute):
    """A kept vertex 0, its six ring corners 1..6 (faces (a, b) = (1, 2) ... (6, 1), all moved) and the new
    vertex 7, on a tilted plane; column 3 is ``attribute(t)`` of each point's plane coordinates ``t``."""
    rng = np.random.default_rng(3)
    t = rng.normal(size=(8, 2)) * 100
    basis = np.linalg.qr(rng.normal(size=(3, 3)))[0][:, :2]
    P = np.zeros((8, 4), np.int64)
    P[:, :3] = np.rint(t @ basis.T).astype(np.int64) + 1000
    P[:, 3] = attribute(t)
    normal = np.cross(basis[:, 0], basis[:, 1])
    dom = int(np.argmax(np.abs(normal)))
    ax0, ax1 = [k for k in range(3) if k != dom]
    a, b = np.arange(1, 7), np.r_[np.arange(2, 7), 1]
    return P, a, b, np.ones(6, np.int64), ax0, ax1


def test_an_attribute_affine_in_the_position_is_predicted_to_within_rounding():
    P, a, b, sym, ax0, ax1 = _ring(lambda t: np.rint(2 * t[:, 0] - 3 * t[:, 1] + 500).astype(np.int64))
    pred, spread = r2._plane_prediction(0, 6, a, b, sym, 0, 7, P, 3, ax0, ax1, -12345)
    assert abs(pred - P[7, 3]) <= 2  # (the positions are rounded to the grid; the attribute is not)
    assert spread == int(np.abs(P[np.r_[a, b], 3] - P[0, 3]).sum())


def test_a_ring_on_one_line_falls_back_to_the_ring_mean():
    P, a, b, sym, ax0, ax1 = _ring(lambda t: np.rint(t[:, 0]).astype(np.int64))
    P[:, [ax0, ax1]] = P[:, [ax0, ax0]]  # every corner on the diagonal of the two axes: singular normal equations
    pred, _ = r2._plane_prediction(0, 6, a, b, sym, 0, 7, P, 3, ax0, ax1, -12345)
    assert pred == -12345


def test_a_fit_far_off_the_ring_is_kept_within_its_range_widened_by_its_span():
    P, a, b, sym, ax0, ax1 = _ring(lambda t: np.rint(2 * t[:, 0] - 3 * t[:, 1] + 500).astype(np.int64))
    P[7, [ax0, ax1]] += 10 ** 6  # the new vertex far outside its ring: the plane would extrapolate by millions
    pred, _ = r2._plane_prediction(0, 6, a, b, sym, 0, 7, P, 3, ax0, ax1, -12345)
    values = P[np.r_[0, a, b], 3]
    span = values.max() - values.min()
    assert values.min() - span <= pred <= values.max() + span


def _encode(mesh, **options) -> bytes:
    buf = io.BytesIO()
    encode_mesh(mesh, buf, measure=False, **options)
    return buf.getvalue()


def _attributes(data: bytes) -> list:
    n = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + n])["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]["attributes"]


def _levels(data: bytes) -> list:
    dec = StreamDecoder()
    out = [(r.positions_int.copy(), r.faces.copy(), np.concatenate([p.attributes_int for p in r.parts]))
           for r in dec.feed(data)]
    assert dec.close().complete
    return out


def test_texture_coordinates_cost_fewer_bytes_on_the_plane_and_decode_to_the_same_mesh(monkeypatch):
    """A planar projection's texture coordinates on an irregularly sampled sphere (the rings of a scan are not
    symmetric, so their mean misses the new vertex's coordinate by a fraction of an edge): measured 0.85 of the
    file with the ring mean (2,562 vertices)."""
    sphere = shapes.icosphere(4, noise=0.05, seed=1)
    uv = sphere.positions[:, :2] * 0.3 + 0.5
    mesh = Mesh(sphere.positions, sphere.faces, attributes={"TEXCOORD_0": uv})
    plane = _encode(mesh)
    assert [a.get("prediction") for a in _attributes(plane)] == ["plane"]
    monkeypatch.setattr(encoder_module, "_with_prediction", lambda spec: spec)
    mean = _encode(mesh)
    assert "prediction" not in _attributes(mean)[0]
    assert len(plane) < 0.9 * len(mean), (len(plane), len(mean))
    for (p1, f1, a1), (p2, f2, a2) in zip(_levels(plane), _levels(mean), strict=True):
        assert np.array_equal(p1, p2) and np.array_equal(f1, f2) and np.array_equal(a1, a2)


def test_integer_attributes_keep_the_ring_mean_and_payload_version_1_has_no_prediction():
    torus = shapes.uv_torus(24, 12)
    ids = np.arange(len(torus.positions), dtype=np.uint16).reshape(-1, 1) % 7
    mesh = Mesh(torus.positions, torus.faces, attributes={**torus.attributes, "_FEATURE_ID_0": ids})
    entries = {a["semantic"]: a.get("prediction") for a in _attributes(_encode(mesh))}
    assert entries == {"TEXCOORD_0": "plane", "_FEATURE_ID_0": None}
    assert all("prediction" not in a for a in _attributes(_encode(mesh, payload_version=1)))


def test_a_reader_refuses_a_prediction_with_payload_version_1_or_of_another_name():
    ext = {"version": 1, "grid": {"bits": 16, "origin": [0, 0, 0], "step": 1.0}, "vertexCount": 4, "faceCount": 2,
           "payload": {"codec": "pmwm-vsplit", "version": 1}, "chunks": [],
           "attributes": [{"semantic": "TEXCOORD_0", "bits": 12, "origin": [0, 0], "step": [1, 1], "prediction": "plane"}]}
    with pytest.raises(FormatError, match="version 2 only"):
        check_extension(ext)
    ext["attributes"][0]["prediction"] = "mean"
    with pytest.raises(FormatError, match="prediction"):
        check_extension(ext)
