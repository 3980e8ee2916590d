"""Crafted and damaged files: only named errors, checked before anything big is allocated."""

import copy
import json

import numpy as np
import pytest
import zstandard

from pmwm_codec import constants
from pmwm_codec.errors import ChecksumError, FormatError, LimitError, PmwError, TruncatedError, UnsupportedVersionError
from pmwm_codec.format import ChunkEvent, iter_events, layout
from samples import sample_pmw
from pmwm_codec.format.extension import digest
from pmwm_codec.format.glb import frame_glb, join_glb

DATA, BASE, PAYLOADS, _ = sample_pmw("plain", chunk_count=3, subdivisions=1, seed=3)
NAME = constants.EXTENSION_NAME


def _split(data):
    json_length = int.from_bytes(data[12:16], "little")
    gltf = json.loads(data[20 : 20 + json_length])
    return gltf, bytearray(data[20 + json_length + 8 :])


def _join(gltf, bin_payload, *, glb_version=2):
    return join_glb(gltf, bin_payload, version=glb_version)


def _mutated(edit):
    gltf, bin_payload = _split(DATA)
    gltf = copy.deepcopy(gltf)
    edit(gltf, gltf["meshes"][0]["primitives"][0]["extensions"][NAME], bin_payload)
    return _join(gltf, bin_payload)


def _events(data):
    return list(iter_events(data))


def test_rebuilding_an_unmodified_file_gives_the_same_bytes():
    assert _mutated(lambda g, e, b: None) == _join(*_split(DATA))
    assert len(_events(_mutated(lambda g, e, b: None))) == 6


@pytest.mark.parametrize("data, error, match", [
    (b"glTX" + DATA[4:], FormatError, "bad magic"),
    (DATA[:4] + (1).to_bytes(4, "little") + DATA[8:], UnsupportedVersionError, "container version 1"),
    (DATA[:16] + b"JSOX" + DATA[20:], FormatError, "first chunk type"),
    (DATA[:12] + (constants.MAX_JSON_BYTES + 4).to_bytes(4, "little") + DATA[16:], LimitError, "JSON chunk"),
    (DATA[:12] + (6).to_bytes(4, "little") + DATA[16:], FormatError, "multiple of 4"),
    (DATA[:8] + (40).to_bytes(4, "little") + DATA[12:], FormatError, "total length"),
    (DATA + b"\0\0\0\0", FormatError, "after the declared file length"),
])
def test_bad_glb_headers_raise_format_errors(data, error, match):
    with pytest.raises(error, match=match):
        _events(data)


def test_bad_magic_is_reported_before_20_bytes_arrive():
    with pytest.raises(FormatError, match="bad magic"):
        _events(b"PK\x03\x04")


def test_json_that_is_not_json_raises_format_error():
    gltf, bin_payload = _split(DATA)
    text = b"{not json" + b" " * 3
    data = b"".join(frame_glb(text, [bin_payload], len(bin_payload)))
    with pytest.raises(FormatError, match="not valid UTF-8 JSON"):
        _events(data)


def test_json_chunk_starting_with_a_byte_order_mark_is_a_format_error():
    gltf, bin_payload = _split(DATA)
    text = b"\xef\xbb\xbf" + json.dumps(gltf).encode()
    data = b"".join(frame_glb(text, [bin_payload], len(bin_payload)))
    with pytest.raises(FormatError, match="not valid UTF-8 JSON"):
        _events(data)


@pytest.mark.parametrize("codec", ["plain", "draco"])
def test_base_indices_of_unsigned_bytes_are_a_format_error(codec):
    data = sample_pmw(codec, chunk_count=1, subdivisions=1, seed=3)[0]
    gltf, bin_payload = _split(data)
    gltf["accessors"][gltf["meshes"][0]["primitives"][0]["indices"]]["componentType"] = 5121  # UNSIGNED_BYTE
    with pytest.raises(FormatError, match="UNSIGNED_SHORT or UNSIGNED_INT"):
        _events(_join(gltf, bin_payload))


def _set(path, value):
    def edit(gltf, ext, bin_payload):
        target = ext
        for key in path[:-1]:
            target = target[key]
        target[path[-1]] = value
    return edit


@pytest.mark.parametrize("edit, error, match", [
    (_set(["version"], constants.FORMAT_VERSION + 1), UnsupportedVersionError, "newer"),
    (_set(["version"], 0), FormatError, "version"),
    (_set(["version"], "1"), FormatError, "version"),
    (_set(["vertexCount"], constants.MAX_VERTICES + 1), LimitError, "vertexCount"),
    (_set(["chunks", 0, "vertexCount"], constants.MAX_VERTICES + 1), LimitError, r"chunks\[0\]"),
    (_set(["chunks", 0, "splits"], constants.MAX_VERTICES + 1), LimitError, r"chunks\[0\]: splits"),
    (_set(["chunks", 0, "splits"], 1e300), LimitError, r"chunks\[0\]: splits"),
    (_set(["chunks", 1, "byteLength"], constants.MAX_CHUNK_BYTES + 1), LimitError, r"chunks\[1\]"),
    (_set(["chunks", 1, "uncompressedLength"], 1 << 40), LimitError, "uncompressedLength"),
    (_set(["chunks", 0, "bufferView"], 99), FormatError, "bufferView 99"),
    (_set(["chunks", 0, "bufferView"], -1), FormatError, "chunks/0/bufferView"),
    (_set(["chunks", 0, "digest"], "zz"), FormatError, "digest"),
    (lambda g, e, b: e["chunks"].reverse(), FormatError, "overlap or out of stream order"),
    (_set(["chunks", 0, "byteLength"], 5), FormatError, "differs from bufferView length"),
    (_set(["grid", "bits"], 64), FormatError, "grid/bits"),
    (lambda g, e, b: e.pop("chunks"), FormatError, "chunks"),
    (lambda g, e, b: g.pop("extensionsUsed"), FormatError, "extensionsUsed"),
    (lambda g, e, b: g["bufferViews"][3].update(byteOffset=-8), FormatError, "byteOffset"),
    (lambda g, e, b: g["bufferViews"][2].update(byteOffset=g["bufferViews"][1]["byteOffset"]), FormatError, "overlap"),
    (lambda g, e, b: g["bufferViews"][4].update(byteOffset=1 << 31), FormatError, "past the buffer"),
    (lambda g, e, b: g["buffers"][0].update(byteLength=1 << 31), FormatError, "byteLength"),
    (lambda g, e, b: g["buffers"][0].update(uri="x.bin"), FormatError, "uri"),
    (lambda g, e, b: g["accessors"][0].update(count=constants.MAX_VERTICES + 1), LimitError, "vertices"),
    (lambda g, e, b: g["accessors"][1].update(count=(constants.MAX_FACES + 1) * 3), LimitError, "faces"),
    (lambda g, e, b: g["meshes"][0]["primitives"].append(copy.deepcopy(g["meshes"][0]["primitives"][0])), FormatError, "overlaps"),
])
def test_crafted_json_raises_only_named_errors(edit, error, match):
    with pytest.raises(error, match=match):
        _events(_mutated(edit))


def test_error_messages_are_one_line():
    for edit in [_set(["chunks", 0, "digest"], 7), _set(["grid"], {"bits": 9})]:
        with pytest.raises(FormatError) as info:
            _events(_mutated(edit))
        assert "\n" not in str(info.value)


@pytest.mark.parametrize("value", [{"bufferView": 1, "count": 15, "packed": "AHB5" * 200}, "x" * 500])
def test_a_schema_error_on_a_long_value_keeps_its_reason_on_the_line(value):
    """jsonschema starts such messages with the value itself; a long one (a chunk table where an array
    belongs) used to fill the 160 characters before the reason."""
    with pytest.raises(FormatError) as info:
        _events(_mutated(_set(["chunks"], value)))
    text = str(info.value)
    assert text.startswith(f"{NAME}: chunks: the value (") and "is not" in text and len(text) < 220, text


def test_lying_digest_raises_checksum_error_for_that_chunk():
    with pytest.raises(ChecksumError) as info:
        _events(_mutated(_set(["chunks", 1, "digest"], "0" * 32)))
    assert info.value.chunk == 2  # the second chunk, numbered from 1 as in the message


def test_a_decode_stopped_before_a_corrupt_chunk_never_opens_it():
    """``decode --chunks N`` applies the base and N chunks: a chunk after them is passed over unread, as a reader
    fetching only the bytes it needs never sees it (the JavaScript decoder, a URL read by ranges), so its bad
    digest does not fail the decode; the whole file still does."""
    import io

    import pmwm_codec
    from pmwm_codec import shapes
    from pmwm_codec.stream import StreamDecoder
    from pmwm_codec.stream.reader import decode_stream

    buf = io.BytesIO()
    pmwm_codec.encode(shapes.icosphere(4, 1.0, noise=0.02), buf, min_chunk_splits=64)
    good = buf.getvalue()
    ends = [e.bytes_read for e in iter_events(good) if isinstance(e, ChunkEvent)]
    assert len(ends) > 4
    bad = bytearray(good)
    bad[ends[2] - 1] ^= 0x55  # the last stored byte of chunk 3 (index 2)
    bad = bytes(bad)
    last, end = decode_stream(bad, chunks=2)
    whole, _ = decode_stream(good, chunks=2)
    assert last.chunk == 2 and end.complete and end.chunks_applied == 2
    assert np.array_equal(last.mesh.positions, whole.mesh.positions)
    with pytest.raises(ChecksumError) as info:
        decode_stream(bad, chunks=3)
    assert info.value.chunk == 3 and str(info.value).startswith("chunk 3:")
    with pytest.raises(ChecksumError):
        decode_stream(bad)
    decoder = StreamDecoder(max_chunks=0)  # the base only: no chunk opened
    decoder.feed(bad)
    assert decoder.close().complete and decoder.chunks_applied == 0


def _replace_chunk(k, stored, uncompressed_length=None):
    """Edit making chunk k (the last one kept) hold ``stored``, with an honest digest:
    the lie, if any, is inside the zstd frame.  Later chunks are dropped."""
    def edit(gltf, ext, bin_payload):
        chunk = ext["chunks"][k]
        view = gltf["bufferViews"][chunk["bufferView"]]
        del bin_payload[view["byteOffset"] :]
        bin_payload += stored + bytes(layout.padded(len(stored)) - len(stored))
        view["byteLength"] = chunk["byteLength"] = len(stored)
        chunk["digest"] = digest(stored)
        if uncompressed_length is not None:
            chunk["uncompressedLength"] = uncompressed_length
        ext["chunks"][k + 1 :] = []
        gltf["buffers"][0]["byteLength"] = len(bin_payload)
    return edit


def _frame_header_claiming(content_size):
    """A zstd frame header (RFC 8878 §3.1.1.1) with an 8-byte content size, single segment,
    content checksum; followed by an empty last raw block and a checksum."""
    descriptor = 0b11100100  # FCS 8 bytes | single segment | checksum
    return layout.ZSTD_MAGIC + bytes([descriptor]) + content_size.to_bytes(8, "little") + b"\x01\x00\x00" + bytes(4)


def test_zstd_frame_claiming_gigabytes_is_refused_before_decompressing():
    # a frame whose header says 4 GiB of content; the JSON says 100 bytes
    cctx = zstandard.ZstdCompressor(write_content_size=True, write_checksum=True)
    honest = cctx.compress(b"a" * 100)
    frame = _frame_header_claiming(4 << 30)
    assert zstandard.get_frame_parameters(frame).content_size == 4 << 30
    with pytest.raises(FormatError, match="content size"):
        _events(_mutated(_replace_chunk(2, frame, uncompressed_length=100)))
    with pytest.raises(LimitError, match="uncompressedLength"):
        _events(_mutated(_replace_chunk(2, honest, uncompressed_length=4 << 30)))


def test_zstd_frame_without_content_size_or_checksum_is_refused():
    no_size = zstandard.ZstdCompressor(write_content_size=False, write_checksum=True).compress(b"abc" * 10)
    no_sum = zstandard.ZstdCompressor(write_content_size=True, write_checksum=False).compress(b"abc" * 10)
    with pytest.raises(FormatError, match="content size"):
        _events(_mutated(_replace_chunk(2, no_size, uncompressed_length=30)))
    with pytest.raises(FormatError, match="checksum"):
        _events(_mutated(_replace_chunk(2, no_sum, uncompressed_length=30)))


def test_chunk_that_is_not_zstd_or_has_trailing_bytes_is_refused():
    good = zstandard.ZstdCompressor(write_content_size=True, write_checksum=True).compress(b"xyz" * 9)
    with pytest.raises(FormatError, match="not a zstd frame"):
        _events(_mutated(_replace_chunk(2, b"\x00" * 12, uncompressed_length=27)))
    with pytest.raises(FormatError, match="chunk 3"):
        _events(_mutated(_replace_chunk(2, good + good, uncompressed_length=27)))


def test_replacing_a_chunk_with_a_good_frame_still_decodes():
    good = zstandard.ZstdCompressor(write_content_size=True, write_checksum=True).compress(b"xyz" * 9)
    chunks = [e for e in _events(_mutated(_replace_chunk(2, good, uncompressed_length=27))) if isinstance(e, ChunkEvent)]
    assert chunks[-1].payload == b"xyz" * 9


@pytest.mark.parametrize("seed", range(40))
def test_random_byte_damage_raises_only_package_errors(seed):
    import random

    rng = random.Random(seed)
    data = bytearray(DATA)
    for _ in range(rng.randint(1, 4)):
        data[rng.randrange(len(data))] = rng.randrange(256)
    try:
        _events(bytes(data[: rng.randint(0, len(data))] if seed % 3 == 0 else data))
    except PmwError:
        pass


def test_truncated_error_is_a_format_error_and_a_pmw_error():
    with pytest.raises(PmwError):
        _events(DATA[:10])
    assert issubclass(TruncatedError, FormatError)


def test_a_payload_error_names_its_chunk_as_the_container_errors_do(monkeypatch):
    """A payload that fails while it is applied (payload version 2: a code out of range, a stream that does not end
    where the payload does) is reported as ``chunk N payload: ...``, N counted from 1 in stream order."""
    import io

    import pmwm_codec
    from pmwm_codec import shapes
    from pmwm_codec.stream import replay
    from pmwm_codec.stream.reader import decode_stream

    buf = io.BytesIO()
    pmwm_codec.encode(shapes.icosphere(3, 1.0, noise=0.02), buf, min_chunk_splits=32)
    calls = []

    def failing(payload, state, models, **options):
        calls.append(1)
        if len(calls) == 3:
            raise FormatError("chunk payload: invalid connectivity code")
        yield from real(payload, state, models, **options)

    real = replay.decode_chunk
    monkeypatch.setattr(replay, "decode_chunk", failing)
    with pytest.raises(FormatError, match=r"^chunk 3 payload: invalid connectivity code$"):
        decode_stream(buf.getvalue())
