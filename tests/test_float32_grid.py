"""The position grid against float32 (outside probe 2, F2): a grid on which the watermark or the owner layer
moves vertices must carry *every* grid point of the mesh's box through the float32 a file stores, not only
the input's own points (which always come back from float32 input)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.errors import PmwError
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive.grid import Grid, float32_spacing
from pmwm_codec.stream.decoder import StreamDecoder
from pmwm_codec.stream.encoder import _moved_reach, encode_mesh
from pmwm_codec.watermark.key import WatermarkKey

IMAGE = np.random.default_rng(0).integers(0, 256, (8, 8)).astype(np.uint8)


def _every_point_comes_back(grid: Grid, lo, hi) -> bool:
    """Exhaustively, axis by axis (the map is per axis): every grid point inside [lo, hi] comes back."""
    origin = np.asarray(grid.origin)
    for axis in range(3):
        first = int(np.ceil((lo[axis] - origin[axis]) / grid.step))
        last = int(np.floor((hi[axis] - origin[axis]) / grid.step))
        q = np.zeros((last - first + 1, 3), np.int64)
        q[:, axis] = np.arange(first, last + 1)
        stored = grid.to_float32(q).astype(np.float64)
        back = np.rint((stored - origin) / grid.step).astype(np.int64)
        if not np.array_equal(back[:, axis], q[:, axis]):
            return False
    return True


def test_carries_float32_is_exact_against_every_grid_point():
    rng = np.random.default_rng(7)
    seen = {True: 0, False: 0}
    for _ in range(300):
        bits = int(rng.integers(8, 17))
        extent = 10.0 ** rng.uniform(-3, 3)
        offset = rng.choice([-1, 1]) * 10.0 ** rng.uniform(-3, 6)
        lo = np.array([offset, -extent / 3, 0.0])
        hi = lo + extent * np.array([1.0, 0.5, 0.25])
        grid = Grid.fit(np.stack([lo, hi]), bits)
        verdict = grid.carries_float32(lo, hi)
        ratio = float(float32_spacing(np.abs(np.stack([lo, hi])).max(0)).max()) / grid.step
        if verdict:
            assert _every_point_comes_back(grid, lo, hi), (bits, extent, offset)
        elif ratio > 1.01:  # the spacing clearly over the step: some float32 cell holds two grid points
            assert not _every_point_comes_back(grid, lo, hi), (bits, extent, offset, ratio)
        seen[verdict] += 1
    assert min(seen.values()) > 30, seen


def _sphere(offset: float) -> Mesh:
    """A radius-1 sphere ``offset`` from the origin, float32 as a glTF stores it (the probe's case)."""
    m = shapes.icosphere(3, 1.0, noise=0.01)
    return Mesh((m.positions + [offset, 0.0, 0.0]).astype(np.float32).astype(np.float64), m.faces)


def _decoded_ints(data: bytes):
    decoder = StreamDecoder()
    result = decoder.feed(data)
    decoder.close()
    part = result[-1].parts[0]
    return part.grid, part.positions_int


@pytest.mark.parametrize("offset, advice", [(10000.0, 11), (1000.0, 15)])
def test_a_watermarked_float32_mesh_far_out_is_refused_with_the_grid_that_carries_it(offset, advice):
    mesh = _sphere(offset)
    key = WatermarkKey.generate(rng=np.random.default_rng(1))
    assert encode_mesh(mesh, io.BytesIO()).vertices == mesh.vertex_count  # nobody moves a vertex: exact as it is
    with pytest.raises(PmwError, match=rf"a 16-bit position grid .*float32.*--grid-bits {advice}\b"):
        encode_mesh(mesh, io.BytesIO(), watermark=IMAGE, key=key)
    with pytest.raises(PmwError, match=rf"--grid-bits {advice}\b"):  # the owner layer moves vertices too
        encode_mesh(mesh, io.BytesIO(), key=key, owner_id=0x1234)
    out = io.BytesIO()
    encode_mesh(mesh, out, watermark=IMAGE, key=key, grid_bits=advice)  # the advice holds
    grid, q = _decoded_ints(out.getvalue())
    stored = grid.to_float32(q).astype(np.float64)  # what a decoded .glb holds
    assert np.array_equal(np.rint((stored - np.asarray(grid.origin)) / grid.step).astype(np.int64), q)


@pytest.mark.parametrize("mode, bits", [("exact", None), ("exact", 3), ("paper", 6)])
def test_the_watermark_moves_no_vertex_farther_than_the_reach_the_grid_check_allows(mode, bits):
    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    plain = io.BytesIO()
    encode_mesh(mesh, plain)
    _, before = _decoded_ints(plain.getvalue())
    steps, _ = _moved_reach(True, mode, bits, None, False)
    for seed in range(2):
        marked = io.BytesIO()
        encode_mesh(mesh, marked, watermark=IMAGE, key=WatermarkKey.generate(rng=np.random.default_rng(seed)),
                    mode=mode, bits=bits, grid_bits=16)
        _, after = _decoded_ints(marked.getvalue())
        moved = np.abs(after - before).max()
        assert 0 < moved <= steps, (moved, steps)


@pytest.mark.parametrize("offset, bits", [(1000.0, 15), (10000.0, 11)])
def test_the_float32_decode_of_a_marked_mesh_far_out_verifies_authentic_against_its_pmw(offset, bits):
    """Far from the origin float32's rounding is a good part of a grid step: a decoded mesh stored as
    float32 (a GLB) read ``tampered`` against its own ``.pmw`` (outside probe 2, F2). A vertex that is in
    float32 exactly its counterpart's stored position is that position: float32 storage is no edit."""
    import pmwm_codec
    from pmwm_codec.verify import verify_mesh

    m = shapes.icosphere(4, noise=0.02, seed=1)
    rng = np.random.default_rng(3)
    buf = io.BytesIO()
    key = encode_mesh(Mesh(m.positions + offset, m.faces), buf, watermark=rng.integers(0, 256, (16, 16)).astype(np.uint8),
                      key=WatermarkKey.generate(rng=rng), grid_bits=bits).key
    decoded = pmwm_codec.decode(buf.getvalue())
    stored = decoded.positions.astype(np.float32).astype(np.float64)
    assert verify_mesh((stored, decoded.faces), buf.getvalue(), key).verdict == "authentic"
    moved = stored.copy()
    moved[:40] += 3 * (float(np.ptp(m.positions)) / 2**bits)  # three grid steps: an edit, not storage
    assert verify_mesh((moved, decoded.faces), buf.getvalue(), key).verdict != "authentic"


def test_a_mesh_past_float32s_range_is_told_to_scale_not_to_move():
    """Coordinates of 1e39 were told to "move the mesh nearer the origin": no place or grid can store them."""
    import pmwm_codec

    sphere = shapes.icosphere(2)
    with pytest.raises(PmwError, match="beyond float32's range .* cannot be stored at all: scale the mesh down$"):
        pmwm_codec.encode(Mesh(sphere.positions * 1e39, sphere.faces), io.BytesIO(), measure=False)
