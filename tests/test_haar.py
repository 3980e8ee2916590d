"""Haar transforms, band stream order and prefix reconstruction."""

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pmwm_codec.watermark import haar
from pmwm_codec.watermark.metrics import psnr

SHARED = Path(__file__).resolve().parents[2] / "shared"


@st.composite
def images(draw, max_k=7):
    k = draw(st.integers(1, max_k))
    img = draw(hnp.arrays(np.uint8, (1 << k, 1 << k), elements=st.integers(0, 255)))
    return img, draw(st.integers(0, k))


def natural_image(size=64):
    """A smooth gradient with a disc, a bar and a little texture."""
    y, x = np.mgrid[0:size, 0:size] / size
    img = 60 + 120 * x + 40 * np.sin(6 * y)
    img[(x - 0.6) ** 2 + (y - 0.4) ** 2 < 0.05] = 230
    img[int(0.7 * size) : int(0.8 * size), size // 8 : size // 2] = 20
    img += np.random.default_rng(0).normal(0, 3, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


@settings(max_examples=60, deadline=None)
@given(images())
def test_integer_round_trip_is_exact(case):
    img, levels = case
    coeffs = haar.forward_int(img, levels)
    assert coeffs.dtype == np.int64
    assert np.array_equal(haar.inverse_int(coeffs, levels), img)


@settings(max_examples=40, deadline=None)
@given(images())
def test_integer_coefficient_ranges(case):
    img, levels = case
    coeffs = haar.forward_int(img, levels)
    stream = haar.to_stream(coeffs, levels)
    low = haar.bands(img.shape[0], levels)[0]
    assert stream[low.stream_slice].min() >= 0 and stream[low.stream_slice].max() <= 255
    assert np.abs(stream).max() <= 510


@settings(max_examples=40, deadline=None)
@given(images())
def test_float_round_trip(case):
    img, levels = case
    coeffs = haar.forward_float(img, levels)
    assert np.allclose(haar.inverse_float(coeffs, levels), img)


@settings(max_examples=40, deadline=None)
@given(images())
def test_stream_inverse(case):
    img, levels = case
    coeffs = haar.forward_int(img, levels)
    stream = haar.to_stream(coeffs, levels)
    assert stream.shape == (img.size,)
    assert np.array_equal(haar.from_stream(stream, img.shape[0], levels), coeffs)


def test_bands_tile_the_stream_in_order():
    b = haar.bands(16, 3)
    assert [x.label for x in b] == haar.band_order(16, 3) == [
        "B3", "V3", "H3", "D3", "V2", "H2", "D2", "V1", "H1", "D1",
    ]
    assert b[0].start == 0 and b[-1].stop == 256
    assert all(p.stop == q.start for p, q in zip(b, b[1:]))
    cover = np.zeros((16, 16), int)
    for x in b:
        cover[x.rows, x.cols] += 1
        assert x.size == (x.rows.stop - x.rows.start) * (x.cols.stop - x.cols.start)
    assert (cover == 1).all()
    idx = haar.stream_index(16, 3)
    assert np.array_equal(np.sort(idx), np.arange(256))


def test_quadrant_naming():
    """V answers vertical edges (top-right), H horizontal edges (bottom-left)."""
    vertical = np.zeros((8, 8), np.uint8)
    vertical[:, 3:] = 200  # an edge between columns 2 and 3, inside a pair
    c = haar.forward_int(vertical, 1)
    v, h, d = (c[b.rows, b.cols] for b in haar.bands(8, 1)[1:])
    assert np.any(v) and not np.any(h) and not np.any(d)
    c = haar.forward_int(vertical.T.copy(), 1)
    v, h, d = (c[b.rows, b.cols] for b in haar.bands(8, 1)[1:])
    assert np.any(h) and not np.any(v) and not np.any(d)


@pytest.mark.parametrize("integer", [True, False])
def test_every_prefix_reconstructs(integer):
    img = natural_image(16)
    coeffs = haar.forward_int(img, 4) if integer else haar.forward_float(img, 4)
    stream = haar.to_stream(coeffs, 4)
    for n in range(stream.size + 1):
        out = haar.reconstruct_prefix(stream[:n], 16, 4, integer=integer)
        assert out.shape == (16, 16) and out.dtype == np.uint8
    assert np.array_equal(out, img)


def test_low_band_prefix_is_the_blurred_image():
    img = natural_image(32)
    stream = haar.to_stream(haar.forward_int(img, 2), 2)
    low = haar.reconstruct_prefix(stream[:64], 32, 2)
    blocks = img.reshape(8, 4, 8, 4).astype(float).mean(axis=(1, 3))
    # nested floor-averages: each of the 2 x 2 lifting steps rounds down by < 1/2
    assert np.all(low[::4, ::4] <= blocks) and np.all(blocks - low[::4, ::4] < 2.0)
    assert (low.reshape(8, 4, 8, 4) == low[::4, ::4][:, None, :, None]).all()


def _band_psnrs(img, levels, integer):
    size = img.shape[0]
    fwd = haar.forward_int if integer else haar.forward_float
    stream = haar.to_stream(fwd(img, levels), levels)
    return [
        psnr(img, haar.reconstruct_prefix(stream[: b.stop], size, levels, integer=integer))
        for b in haar.bands(size, levels)
    ]


def _natural_image(name):
    if name == "synthetic":
        return natural_image(64)
    path = SHARED / "watermarks" / f"{name}.png"
    if not path.exists():
        pytest.skip(f"{path} absent")
    from pmwm_codec.watermark.image import load_watermark

    return load_watermark(path)[0]


@pytest.mark.parametrize("integer", [True, False])
@pytest.mark.parametrize("name", ["synthetic", "camera128"])
def test_psnr_never_drops_as_bands_arrive(name, integer):
    img = _natural_image(name)
    k = img.shape[0].bit_length() - 1
    for levels in range(1, k + 1):
        values = _band_psnrs(img, levels, integer)
        assert all(b >= a for a, b in zip(values, values[1:])), (levels, values)
        assert values[-1] == float("inf")


def test_bad_sizes():
    with pytest.raises(ValueError):
        haar.forward_int(np.zeros((6, 6), np.uint8), 1)
    with pytest.raises(ValueError):
        haar.forward_int(np.zeros((8, 4), np.uint8), 1)
    with pytest.raises(ValueError):
        haar.bands(8, 4)
    with pytest.raises(TypeError):
        haar.forward_int(np.zeros((8, 8)), 1)
    with pytest.raises(ValueError):
        haar.from_stream(np.zeros(65, np.int64), 8, 2)


def test_zero_levels_is_identity():
    img = natural_image(8)
    assert np.array_equal(haar.forward_int(img, 0), img)
    assert np.array_equal(haar.to_stream(img, 0), img.ravel())
