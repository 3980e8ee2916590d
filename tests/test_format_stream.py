"""Streaming: every prefix, every way of splitting the bytes, every corrupted chunk."""

import io
import sys

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmwm_codec.errors import ChecksumError, TruncatedError
from pmwm_codec.format import BaseEvent, ChunkEvent, ContainerParser, EndEvent, HeaderEvent, iter_events, read_header
from samples import sample_pmw

DATA, BASE, PAYLOADS, _ = sample_pmw("plain", chunk_count=3, subdivisions=0, seed=7, chunk_sizes=[40, 1, 90])
DRACO_DATA, *_ = sample_pmw("draco", chunk_count=2, subdivisions=1, seed=8)
REFERENCE = list(iter_events(DATA))


def _feed_all(data, sizes):
    parser = ContainerParser()
    events, pos = [], 0
    for size in sizes:
        events += parser.feed(data[pos : pos + size])
        pos += size
    events += parser.feed(data[pos:])
    return events + [parser.close()]


def _chunk_ends(data):
    return [e.bytes_read for e in iter_events(data) if isinstance(e, ChunkEvent)]


@pytest.mark.parametrize("data", [DATA, DRACO_DATA], ids=["plain", "draco"])
def test_every_prefix_yields_exactly_the_chunks_inside_it_or_truncated_error(data):
    full = list(iter_events(data))
    base_end = next(e.bytes_read for e in full if isinstance(e, BaseEvent))
    ends = _chunk_ends(data)
    for cut in range(len(data) + 1):
        prefix = data[:cut]
        if cut < base_end:
            with pytest.raises(TruncatedError) as info:
                list(iter_events(prefix))
            assert info.value.bytes_read == cut
            continue
        events = list(iter_events(prefix))
        chunks = [e for e in events if isinstance(e, ChunkEvent)]
        expected = sum(end <= cut for end in ends)
        assert [c.index for c in chunks] == list(range(expected)), cut
        assert chunks == [e for e in full if isinstance(e, ChunkEvent)][:expected]
        end = events[-1]
        assert isinstance(end, EndEvent)
        assert end.complete == (cut == len(data)) and end.truncated == (cut < len(data))
        assert (end.bytes_read, end.chunks_delivered) == (cut, expected)


def test_truncated_error_names_bytes_arrived_and_needed():
    with pytest.raises(TruncatedError, match=r"after 25 bytes, inside the GLB header or JSON.*needs at least \d+ bytes") as info:
        list(iter_events(DATA[:25]))
    assert info.value.bytes_read == 25


def _stream_closed(prefix):
    parser = ContainerParser()
    parser.feed(prefix)
    parser.close()


@pytest.mark.parametrize("data", [DATA, DRACO_DATA], ids=["plain", "draco"])
def test_a_stream_cut_before_its_base_names_the_bytes_needed_the_javascript_reader_names(data):
    """Cut inside the JSON, this reader named the JSON's end (``20 + J``) where the JavaScript reader names
    ``28 + J``, where the BIN chunk's data (and the base mesh in it) starts: both lower bounds, two numbers.  Every
    reader now names 20 in the preamble, ``28 + J`` up to the BIN data, then the base meshes' end (spec README,
    *Partial files*; ``js/test/reader-differentials.test.js`` compares the two readers prefix by prefix)."""
    json_length = int.from_bytes(data[12:16], "little")
    base_end = next(e.bytes_read for e in iter_events(data) if isinstance(e, BaseEvent))
    bin_data = 28 + json_length
    for cut, needed in [(0, 20), (10, 20), (19, 20), (20, bin_data), (21, bin_data), (20 + json_length - 1, bin_data),
                        (20 + json_length, bin_data), (bin_data - 1, bin_data), (bin_data, base_end),
                        (base_end - 1, base_end)]:
        readers = [lambda p: list(iter_events(p)), _stream_closed]
        if cut < 20 + json_length:
            readers.append(lambda p: read_header(io.BytesIO(p)))
        for read in readers:
            with pytest.raises(TruncatedError) as info:
                read(data[:cut])
            assert (info.value.bytes_read, info.value.bytes_needed) == (cut, needed), (cut, read)
            assert f"{needed} bytes)" in str(info.value)
            assert ("at least" in str(info.value)) == (cut < bin_data), str(info.value)


def test_feeding_one_byte_at_a_time_gives_the_same_events():
    assert _feed_all(DATA, [1] * len(DATA)) == REFERENCE


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(min_value=0, max_value=300), max_size=40))
def test_any_split_into_blocks_gives_the_same_events(sizes):
    assert _feed_all(DATA, sizes) == REFERENCE


def test_events_arrive_as_soon_as_their_bytes_are_in():
    parser = ContainerParser()
    seen = []
    for i in range(len(DATA)):
        for event in parser.feed(DATA[i : i + 1]):
            seen.append((type(event).__name__, i + 1))
    for (name, at), event in zip(seen, REFERENCE):
        if not isinstance(event, HeaderEvent):
            assert at == event.bytes_read, name


@pytest.mark.parametrize("data", [DATA, DRACO_DATA], ids=["plain", "draco"])
def test_a_flipped_bit_inside_a_chunk_raises_checksum_error_naming_it(data):
    header = read_header(data)
    json_length = int.from_bytes(data[12:16], "little")
    bin_start = 20 + json_length + 8
    views = header.gltf_json["bufferViews"]
    for k, chunk in enumerate(header.extension["chunks"]):
        view = views[chunk["bufferView"]]
        for offset in range(0, view["byteLength"], max(1, view["byteLength"] // 7)):
            for bit in (0, 7):
                corrupt = bytearray(data)
                corrupt[bin_start + view["byteOffset"] + offset] ^= 1 << bit
                with pytest.raises(ChecksumError) as info:
                    list(iter_events(bytes(corrupt)))
                assert info.value.chunk == k + 1
                assert f"chunk {k + 1}" in str(info.value)


def test_chunks_before_the_corrupt_one_are_still_delivered():
    header = read_header(DATA)
    json_length = int.from_bytes(DATA[12:16], "little")
    view = header.gltf_json["bufferViews"][header.extension["chunks"][2]["bufferView"]]
    corrupt = bytearray(DATA)
    corrupt[20 + json_length + 8 + view["byteOffset"]] ^= 0xFF
    got = []
    with pytest.raises(ChecksumError):
        for event in iter_events(bytes(corrupt)):
            got.append(event)
    assert [e.index for e in got if isinstance(e, ChunkEvent)] == [0, 1]


def test_sources_path_file_object_iterable_and_stdin_give_the_same_events(tmp_path, monkeypatch):
    path = tmp_path / "s.pmw"
    path.write_bytes(DATA)
    assert list(iter_events(path)) == REFERENCE
    assert list(iter_events(str(path), block_size=7)) == REFERENCE
    assert list(iter_events(io.BytesIO(DATA), block_size=3)) == REFERENCE
    assert list(iter_events(iter([DATA[:50], DATA[50:51], DATA[51:]]))) == REFERENCE
    assert list(iter_events(memoryview(DATA))) == REFERENCE

    class FakeStdin:
        buffer = io.BytesIO(DATA)

    monkeypatch.setattr(sys, "stdin", FakeStdin)
    assert list(iter_events("-")) == REFERENCE


def test_read_header_reads_only_the_preamble_and_json():
    stream = io.BytesIO(DATA)
    header = read_header(stream)
    json_length = int.from_bytes(DATA[12:16], "little")
    assert stream.tell() == 20 + json_length
    assert header == REFERENCE[0]


def test_read_header_on_a_cut_json_raises_truncated_error():
    with pytest.raises(TruncatedError):
        read_header(DATA[:30])


def test_parser_is_single_use():
    parser = ContainerParser()
    parser.feed(DATA)
    parser.close()
    with pytest.raises(RuntimeError, match="single-use"):
        parser.feed(b"x")
    with pytest.raises(RuntimeError, match="single-use"):
        parser.close()
