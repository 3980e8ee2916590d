"""Chunk payload codec (format/records.py): round trips, pinned bytes, named rejections."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmwm_codec.errors import FormatError, LimitError
from pmwm_codec.format.records import (
    ATTRIBUTE_COLUMN,
    COLUMNS,
    MAX_BATCHES_PER_CHUNK,
    MAX_RESIDUAL_ZIGZAG,
    column_names,
    pack_batches,
    unpack_batches,
    unzigzag,
    zigzag,
)
from pmwm_codec.progressive.vsplit import SplitBatch
from samples import PAYLOAD_EXAMPLE

# --- one small two-batch chunk, D = 4 (positions + one attribute component) -------------
PINNED_BATCHES = PAYLOAD_EXAMPLE  # the example of spec/bitstream.md §6
# Checked by hand against spec/bitstream.md §6, field by field:
#   RecordsHeader  batch_count 2                                  -> 02000000
#   BatchEntry 0   split_count 2, incidence_count 4               -> 02000000 04000000
#   BatchEntry 1   split_count 1, incidence_count 1               -> 01000000 01000000
#   gaps           v = [2, 5] | [0]  ->  2, 5-2-1 = 2 | 0, width 1  -> 01 020200
#   symbols        1,2,0 | 4,3,(0)  ->  1+5*2+25*0 = 11, 4+5*3 = 19 -> 01 0b13
#   residual_x     1, 3, -300  ->  zigzag 2, 6, 599 = 0x0257, width 2,
#                  low-byte plane 02 06 57, then high-byte plane 00 00 02 -> 02 020657 000002
#   residual_y     -1, 0, 2  ->  1, 0, 4                          -> 01 010004
#   residual_z     0, -2, 0  ->  0, 3, 0                          -> 01 000300
#   attribute_0    5, -1, 0  ->  10, 1, 0                         -> 01 0a0100
PINNED_BYTES = bytes.fromhex(
    "02000000" "02000000" "04000000" "01000000" "01000000"
    "01" "020200" "01" "0b13" "02" "020657" "000002" "01" "010004" "01" "000300" "01" "0a0100"
)
#: Byte offset of each column's ColumnHeader in PINNED_BYTES (and the payload's end).
PINNED_COLUMN_AT = {"gaps": 20, "symbols": 24, "residual_x": 27, "residual_y": 34, "residual_z": 38,
                    "attribute_0": 42, None: 46}


def assert_same_batches(got, want):
    assert len(got) == len(want)
    for g, w in zip(got, want):
        assert g.v.dtype == np.int64 and g.symbols.dtype == np.uint8 and g.residual.dtype == np.int64
        assert np.array_equal(g.v, w.v)
        assert np.array_equal(g.symbols, w.symbols)
        assert np.array_equal(g.residual, w.residual)


def _with(payload: bytes, at: int, new: bytes) -> bytes:
    return payload[:at] + new + payload[at + len(new):]


# --- round trips -----------------------------------------------------------------------

RESIDUAL = st.integers(-(1 << 31), 1 << 31)  # the full range a reader accepts


@st.composite
def batch_lists(draw):
    """1..4 batches with the same residual width D in 3..8."""
    width = draw(st.integers(3, 8))
    batches = []
    for _ in range(draw(st.integers(1, 4))):
        v = sorted(draw(st.sets(st.integers(0, 1 << 24), min_size=1, max_size=12)))
        symbols = draw(st.lists(st.integers(0, 4), max_size=40))
        residual = draw(st.lists(st.lists(RESIDUAL, min_size=width, max_size=width), min_size=len(v), max_size=len(v)))
        batches.append(SplitBatch(np.array(v, np.int64), np.array(symbols, np.uint8), np.array(residual, np.int64)))
    return batches


@settings(max_examples=150, deadline=None)
@given(batch_lists())
def test_unpack_of_pack_gives_the_batches_back(batches):
    width = batches[0].residual.shape[1]
    assert_same_batches(unpack_batches(pack_batches(batches), width=width), batches)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(-(1 << 63), (1 << 63) - 1), max_size=50))
def test_zigzag_round_trips_and_orders_by_magnitude(values):
    x = np.array(values, np.int64)
    assert np.array_equal(unzigzag(zigzag(x)), x)
    assert np.array_equal(zigzag(np.array([0, -1, 1, -2, 2])), np.arange(5, dtype=np.uint64))


def test_column_names_are_the_fixed_columns_then_one_per_attribute_component():
    assert column_names(3) == COLUMNS
    assert column_names(6) == COLUMNS + tuple(ATTRIBUTE_COLUMN.format(j) for j in range(3))
    assert column_names(6)[-1] == "attribute_2"


# --- pinned bytes ----------------------------------------------------------------------

def test_pack_matches_the_hand_checked_bytes():
    assert pack_batches(PINNED_BATCHES) == PINNED_BYTES


def test_unpack_of_the_hand_checked_bytes():
    assert_same_batches(unpack_batches(PINNED_BYTES, width=4), PINNED_BATCHES)


@pytest.mark.parametrize("top, width", [(0, 1), (255, 1), (256, 2), ((1 << 16) - 1, 2), (1 << 16, 4), (1 << 32, 8)])
def test_a_column_takes_the_smallest_width_that_holds_its_largest_value(top, width):
    r = int(unzigzag(np.array([top], np.uint64))[0])
    payload = pack_batches([SplitBatch(np.array([0]), np.zeros(0, np.uint8), np.array([[r, 0, 0]]))])
    at = 4 + 8 + 2 + 1  # header, one batch entry, gaps column (1 value), empty symbols column
    assert payload[at] == width
    assert len(payload) == at + 1 + width + 2 * 2


# --- accepted edge cases ---------------------------------------------------------------

def test_unpack_accepts_hundreds_of_incidences_for_one_split():
    # a split vertex of valence 565 has 565 incidences: no per-split bound may refuse it
    batch = SplitBatch(np.array([7]), np.full(565, 1, np.uint8), np.array([[0, 1, -1]]))
    assert_same_batches(unpack_batches(pack_batches([batch])), [batch])


def test_a_high_valence_vertex_survives_encode_and_decode():
    # Two rings round a fan centre of valence 1000 (flat): the simplifier collapses inner-ring
    # vertices into the centre, and a chunk holds one split with 565 incidences.  A former
    # bound of 64 incidences per split refused this file.
    from pmwm_codec.mesh import Mesh
    from pmwm_codec.stream import StreamDecoder, encode_mesh

    n = 1000
    th = 2 * np.pi * np.arange(n) / n
    outer = np.c_[np.cos(th), np.sin(th), np.zeros(n)]
    inner = np.c_[0.5 * np.cos(th + 0.01), 0.5 * np.sin(th + 0.01), np.zeros(n)]
    positions = np.vstack([[0, 0, 0.0], [0, 0, -0.2], outer, inner])
    a, b = 2 + np.arange(n), 2 + (np.arange(n) + 1) % n
    c, d = a + n, b + n
    faces = np.concatenate([np.c_[0 * a, c, d], np.c_[c, a, b], np.c_[c, b, d], np.c_[0 * a + 1, b, a]])
    buf = io.BytesIO()
    encode_mesh(Mesh(positions, faces), buf, base_codec="plain", measure=False, base_vertices=10, min_chunk_splits=1)
    dec = StreamDecoder(None)
    results = dec.feed(buf.getvalue())
    assert dec.close().complete
    assert results[-1].vertices == len(positions)


# --- named rejections ------------------------------------------------------------------

def test_unpack_rejects_trailing_bytes():
    with pytest.raises(FormatError, match="chunk payload: 1 trailing bytes"):
        unpack_batches(PINNED_BYTES + b"\x00", width=4)


def test_unpack_rejects_a_missing_attribute_column_as_trailing_bytes_the_other_way():
    # read with D = 3, the attribute column is 4 bytes too many
    with pytest.raises(FormatError, match="chunk payload: 4 trailing bytes"):
        unpack_batches(PINNED_BYTES, width=3)


@pytest.mark.parametrize("packed", [125, 255])
def test_unpack_rejects_unknown_symbol(packed):
    bad = _with(PINNED_BYTES, PINNED_COLUMN_AT["symbols"] + 1, bytes([packed]))
    with pytest.raises(FormatError, match="chunk payload: unknown incidence symbol"):
        unpack_batches(bad, width=4)


def test_unpack_rejects_zero_split_batch():
    bad = _with(PINNED_BYTES, 12, (0).to_bytes(4, "little"))  # batch 1's split_count
    with pytest.raises(LimitError, match="chunk payload: batch 1 has no splits"):
        unpack_batches(bad, width=4)


@pytest.mark.parametrize("count", [0, MAX_BATCHES_PER_CHUNK + 1])
def test_unpack_rejects_batch_count_out_of_range(count):
    with pytest.raises(LimitError, match=f"chunk payload: batch count {count} outside 1..{MAX_BATCHES_PER_CHUNK}"):
        unpack_batches(_with(PINNED_BYTES, 0, count.to_bytes(4, "little")), width=4)


def test_unpack_rejects_a_payload_shorter_than_its_header():
    with pytest.raises(FormatError, match="chunk payload: shorter than its header"):
        unpack_batches(PINNED_BYTES[:3], width=4)


def test_unpack_rejects_truncated_batch_table():
    with pytest.raises(FormatError, match="chunk payload: batch table is cut short"):
        unpack_batches(PINNED_BYTES[:19], width=4)


def test_unpack_rejects_more_splits_than_the_limit():
    with pytest.raises(LimitError, match="chunk payload: 3 splits, more than the limit 2"):
        unpack_batches(PINNED_BYTES, width=4, max_splits=2)


def test_unpack_rejects_declared_counts_larger_than_the_payload():
    bad = _with(PINNED_BYTES, 8, (1000).to_bytes(4, "little"))  # batch 0's incidence_count
    with pytest.raises(FormatError, match="chunk payload: declared counts exceed the payload size"):
        unpack_batches(bad, width=4)


@pytest.mark.parametrize("name", column_names(4))
def test_unpack_rejects_truncated_columns(name):
    at = PINNED_COLUMN_AT[name]
    with pytest.raises(FormatError, match=f"chunk payload: column {name} is missing"):
        unpack_batches(PINNED_BYTES[:at], width=4)
    with pytest.raises(FormatError, match=f"chunk payload: column {name} is cut short"):
        unpack_batches(PINNED_BYTES[: at + 2], width=4)


@pytest.mark.parametrize("name", column_names(4))
@pytest.mark.parametrize("width", [0, 3, 5, 16, 255])
def test_unpack_rejects_bad_column_header(name, width):
    bad = _with(PINNED_BYTES, PINNED_COLUMN_AT[name], bytes([width]))
    with pytest.raises(FormatError, match=f"chunk payload: column {name} has invalid width {width}"):
        unpack_batches(bad, width=4)


def test_unpack_rejects_a_gap_beyond_the_vertex_limit():
    batch = SplitBatch(np.array([1 << 27]), np.zeros(0, np.uint8), np.zeros((1, 3), np.int64))
    with pytest.raises(FormatError, match="chunk payload: split vertex gap out of range"):
        unpack_batches(pack_batches([batch]))


@pytest.mark.parametrize("axis, name", [(0, "residual_x"), (2, "residual_z"), (3, "attribute_0")])
def test_unpack_rejects_residuals_beyond_the_grid_range(axis, name):
    residual = np.zeros((1, 4), np.int64)
    residual[0, axis] = (1 << 31) + 1  # zigzag 2**32 + 2 > MAX_RESIDUAL_ZIGZAG
    payload = pack_batches([SplitBatch(np.array([0]), np.zeros(0, np.uint8), residual)])
    with pytest.raises(FormatError, match=f"chunk payload: {name} out of range"):
        unpack_batches(payload, width=4)
    residual[0, axis] = 1 << 31  # the largest accepted magnitude
    assert int(zigzag(residual[0, axis])) == MAX_RESIDUAL_ZIGZAG
    unpack_batches(pack_batches([SplitBatch(np.array([0]), np.zeros(0, np.uint8), residual)]), width=4)
