"""The encoder's chunking policy: which batches each chunk holds (stream/chunking.py).

Not part of the format (a reader takes whatever grouping the index declares), but it decides
what a prefix of the stream holds: by default the first chunks are small and double, so that
a prefix a little longer than the base already refines it (rate-distortion at low rates).
"""

from __future__ import annotations

import io

from hypothesis import given, settings
from hypothesis import strategies as st

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.format import read_header
from pmwm_codec.stream.chunking import FIRST_CHUNK_SPLITS, default_min_chunk_splits, group_batches

batch_sizes = st.lists(st.integers(1, 400), max_size=60)


def _check_partition(chunks, n: int) -> None:
    """Every batch in exactly one chunk, in order, no chunk empty."""
    assert [j for chunk in chunks for j in chunk] == list(range(n))
    assert all(len(chunk) for chunk in chunks)


@settings(max_examples=300, deadline=None)
@given(batch_sizes, st.integers(1, 500))
def test_every_chunk_but_the_last_holds_the_smallest_chunk(sizes, smallest):
    chunks = group_batches(sizes, smallest)
    _check_partition(chunks, len(sizes))
    held = [sum(sizes[j] for j in chunk) for chunk in chunks]
    assert all(h >= smallest for h in held[:-1])
    if len(held) > 1:  # a short tail joins the chunk before it
        assert held[-1] >= smallest // 2


@settings(max_examples=300, deadline=None)
@given(batch_sizes, st.integers(1, 500), st.integers(1, 64))
def test_with_a_first_chunk_the_chunks_start_small_and_double_up_to_the_smallest(sizes, smallest, first):
    chunks = group_batches(sizes, smallest, first)
    _check_partition(chunks, len(sizes))
    held = [sum(sizes[j] for j in chunk) for chunk in chunks]
    need = [min(smallest, first << j) for j in range(len(chunks))]
    assert all(h >= w for h, w in zip(held[:-1], need))
    for j, chunk in enumerate(chunks[:-1]):  # a chunk closes at the first batch that reaches its need
        assert sum(sizes[i] for i in chunk[:-1]) < need[j]
    if len(held) > 1:
        assert held[-1] >= need[-1] // 2
    if first >= smallest:  # nothing to start small: the plain rule
        assert chunks == group_batches(sizes, smallest)


def test_the_default_encode_starts_with_small_chunks_and_reaches_the_default_smallest():
    mesh = shapes.icosphere(5, noise=0.01)  # 10,242 vertices: the default smallest chunk is 100 splits
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, measure="none")
    entries = read_header(buf.getvalue()).extension["chunks"]
    splits = [e["splits"] for e in entries]
    smallest = default_min_chunk_splits(sum(splits))
    assert splits[0] >= FIRST_CHUNK_SPLITS and splits[0] < smallest
    assert max(splits[:-1]) >= smallest  # later chunks are as large as before
    # the stream does not pay for it in bytes: within 1% of the same stream in 1%-of-the-splits chunks
    plain = io.BytesIO()
    pmwm_codec.encode(mesh, plain, measure="none", min_chunk_splits=smallest)
    assert len(read_header(plain.getvalue()).extension["chunks"]) < len(entries)
    assert len(buf.getvalue()) < 1.01 * len(plain.getvalue())
