"""Bit layout, packing, symbols, repetition and voting."""

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from pmwm_codec.watermark import haar
from pmwm_codec.watermark.payload import (
    BitLayout,
    bits_from_symbols,
    pack,
    repeat_to_capacity,
    symbols,
    unpack,
    vote,
)


@st.composite
def streams(draw):
    """A coefficient stream cut into bands of random sizes and value ranges."""
    sizes = draw(st.lists(st.integers(0, 12), min_size=1, max_size=6))
    parts, bands, start = [], [], 0
    for n in sizes:
        lo = draw(st.integers(-(2**20), 2**20))
        span = draw(st.integers(0, 2**draw(st.integers(0, 20))))
        parts.append(draw(hnp.arrays(np.int64, n, elements=st.integers(lo, lo + span))))
        bands.append((start, start + n))
        start += n
    return np.concatenate(parts), bands


def reference_pack(stream, layout):
    """A slow per-coefficient packer, straight from the docstring."""
    out = []
    lows = np.repeat(layout.lows, layout.stops - layout.starts)
    for v, w, lo in zip(stream, layout.widths, lows):
        code = int(v) - int(lo)
        out += [(code >> (w - 1 - j)) & 1 for j in range(w)]
    return np.array(out, dtype=np.uint8)


@settings(max_examples=100, deadline=None)
@given(streams())
def test_pack_unpack_round_trip(case):
    stream, bands = case
    layout = BitLayout.for_coefficients(stream, bands)
    bits = pack(stream, layout)
    assert bits.dtype == np.uint8 and bits.shape == (layout.total_bits,)
    assert np.array_equal(bits, reference_pack(stream, layout))
    values, count = unpack(bits, layout)
    assert count == stream.size and values.dtype == np.int64
    assert np.array_equal(values, stream)


@settings(max_examples=40, deadline=None)
@given(streams())
def test_every_bit_prefix_decodes_a_coefficient_prefix(case):
    stream, bands = case
    layout = BitLayout.for_coefficients(stream, bands)
    bits = pack(stream, layout)
    last = 0
    for n in range(bits.size + 1):
        values, count = unpack(bits[:n], layout)
        assert values.shape == (count,) and count >= last
        assert np.array_equal(values, stream[:count])
        assert layout.offsets[count] <= n  # complete ...
        assert count == stream.size or layout.offsets[count + 1] > n  # ... and all of them
        last = count


def test_widths_follow_the_band_ranges():
    stream = np.array([0, 255, 7, -1, 0, 0, 0, 0, -4, 3, 5, 6])
    layout = BitLayout.for_coefficients(stream, [(0, 3), (3, 4), (4, 8), (8, 10), (10, 12)])
    assert layout.band_widths.tolist() == [8, 1, 0, 3, 3]
    assert layout.signed.tolist() == [0, 1, 0, 1, 0]
    assert layout.lows.tolist() == [0, -1, 0, -4, 0]
    assert layout.total_bits == 3 * 8 + 1 + 0 + 2 * 3 + 2 * 3


def test_an_all_zero_stream_still_packs_one_bit_per_first_band_coefficient():
    """An all-black image's coefficients are all 0: its layout must not be empty (a reader
    refuses a message of 0 bits), so the first band gets width 1."""
    img = np.zeros((16, 16), np.uint8)
    stream = haar.to_stream(haar.forward_int(img, 4), 4)
    layout = BitLayout.for_coefficients(stream, haar.bands(16, 4))
    assert layout.band_widths.tolist()[0] == 1 and not any(layout.band_widths.tolist()[1:])
    assert layout.total_bits == 1
    coefficients, count = unpack(pack(stream, layout), layout)
    assert count == 256 and not coefficients.any()


def test_layout_does_not_publish_coefficients():
    """A 1x1 band must still travel in the bits, not in the public config."""
    img = np.full((8, 8), 200, np.uint8)
    stream = haar.to_stream(haar.forward_int(img, 3), 3)
    layout = BitLayout.for_coefficients(stream, haar.bands(8, 3))
    assert layout.band_widths[0] == 8
    assert 200 not in np.ravel(layout.get_config()["bands"])


def test_config_round_trip_is_json():
    img = np.random.default_rng(0).integers(0, 256, (16, 16)).astype(np.uint8)
    stream = haar.to_stream(haar.forward_int(img, 4), 4)
    layout = BitLayout.for_coefficients(stream, haar.bands(16, 4))
    config = json.loads(json.dumps(layout.get_config()))
    back = BitLayout.from_config(config)
    assert back == layout and back.total_bits == layout.total_bits
    assert np.array_equal(unpack(pack(stream, layout), back)[0], stream)
    with pytest.raises(ValueError):
        BitLayout.from_config({"id": "other"})
    with pytest.raises(ValueError):
        BitLayout.from_config({"id": "pmwm-bits", "version": 1, "bands": [[1, 2, 0, 3]]})


def test_pack_rejects_values_outside_the_layout():
    layout = BitLayout([(0, 2, 0, 4)])
    with pytest.raises(ValueError, match="coefficient 1"):
        pack(np.array([3, 16]), layout)
    with pytest.raises(ValueError):
        pack(np.array([3, -1]), layout)
    with pytest.raises(ValueError):
        unpack(np.zeros(9, np.uint8), layout)


@settings(max_examples=100, deadline=None)
@given(hnp.arrays(np.uint8, st.integers(0, 200), elements=st.integers(0, 1)), st.integers(1, 24))
def test_symbols_round_trip(bits, b):
    s = symbols(bits, b)
    assert s.dtype == np.int64 and s.shape == (-(-bits.size // b),)
    assert s.min(initial=0) >= 0 and s.max(initial=0) < 2**b
    assert np.array_equal(bits_from_symbols(s, b, bits.size), bits)


def test_symbols_are_msb_first():
    assert symbols([1, 0, 1, 1, 0, 1], 4).tolist() == [11, 4]  # 1011, 01|00
    assert bits_from_symbols([11, 4], 4, 6).tolist() == [1, 0, 1, 1, 0, 1]
    assert bits_from_symbols([11], 4, 6).tolist() == [1, 0, 1, 1]  # prefix only


def test_repeat_to_capacity():
    assert repeat_to_capacity([1, 0, 1], 8).tolist() == [1, 0, 1, 1, 0, 1, 1, 0]
    assert repeat_to_capacity([1, 0, 1], 2).tolist() == [1, 0]
    assert repeat_to_capacity([], 3).tolist() == [0, 0, 0]


def test_vote_recovers_from_a_minority_of_flips():
    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2, 500).astype(np.uint8)
    copies = repeat_to_capacity(bits, 5 * 500 + 123)
    received = copies.copy()
    pos = np.arange(copies.size) % 500
    for i in range(500):  # flip 2 of the 5 (or 6) copies of every bit
        where = np.flatnonzero(pos == i)
        received[rng.choice(where, 2, replace=False)] ^= 1
    out, known = vote(received, np.ones(received.size, bool), 500)
    assert known.all() and np.array_equal(out, bits)


def test_vote_ties_and_missing_are_unknown():
    received = np.array([1, 0, 1, 0, 1, 1])  # total 3: bit0 gets 1 (0 erased); bit1 0,1; bit2 1,1
    mask = np.array([True, True, True, False, True, True])
    out, known = vote(received, mask, 3)
    assert known.tolist() == [True, False, True]
    assert out.tolist() == [1, 0, 1]
    out, known = vote([1, 1], [True, True], 4)
    assert known.tolist() == [True, True, False, False]
    with pytest.raises(ValueError):
        vote([1, 0], [True], 2)


def test_full_watermark_pipeline():
    """image -> Haar -> bits -> 12-bit symbols -> back, on a real-sized watermark."""
    img = np.random.default_rng(2).integers(0, 256, (128, 128)).astype(np.uint8)
    stream = haar.to_stream(haar.forward_int(img, 7), 7)
    layout = BitLayout.for_coefficients(stream, haar.bands(128, 7))
    bits = pack(stream, layout)
    s = symbols(bits, 12)
    back, count = unpack(bits_from_symbols(s, 12, layout.total_bits), layout)
    assert count == stream.size
    assert np.array_equal(haar.reconstruct_prefix(back, 128, 7), img)
