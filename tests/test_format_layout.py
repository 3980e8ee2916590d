"""GLB header and chunk header structs: build/parse round trips and pinned bytes."""

import pytest
from construct import ConstError

from pmwm_codec.format import layout


def test_glb_header_round_trips():
    built = layout.GlbHeader.build({"version": 2, "length": 123456})
    parsed = layout.GlbHeader.parse(built)
    assert (parsed.magic, parsed.version, parsed.length) == (b"glTF", 2, 123456)
    assert layout.GlbHeader.build(parsed) == built


def test_glb_header_matches_pinned_bytes():
    # 'glTF', version 2, length 0x00000F2C, little-endian (hand-checked against the glTF spec §4.4.2)
    assert layout.GlbHeader.build({"version": 2, "length": 3884}) == bytes.fromhex("676c5446" "02000000" "2c0f0000")


def test_chunk_header_matches_pinned_bytes_and_round_trips():
    json_header = bytes.fromhex("a0050000" "4a534f4e")  # 1440 bytes, 'JSON'
    bin_header = bytes.fromhex("10000000" "42494e00")  # 16 bytes, 'BIN\0'
    assert layout.ChunkHeader.build({"length": 1440, "type": layout.CHUNK_TYPE_JSON}) == json_header
    assert layout.ChunkHeader.build({"length": 16, "type": layout.CHUNK_TYPE_BIN}) == bin_header
    parsed = layout.ChunkHeader.parse(bin_header)
    assert (parsed.length, parsed.type) == (16, b"BIN\x00")


def test_glb_header_rejects_bad_magic():
    with pytest.raises(ConstError):
        layout.GlbHeader.parse(b"glTX" + bytes(8))


def test_sizes_are_the_glb_sizes():
    assert (layout.GLB_HEADER_SIZE, layout.CHUNK_HEADER_SIZE, layout.PREAMBLE_SIZE) == (12, 8, 20)


@pytest.mark.parametrize("n, expected", [(0, 0), (1, 4), (4, 4), (5, 8), (1023, 1024)])
def test_padded_rounds_up_to_four(n, expected):
    assert layout.padded(n) == expected
