"""The JSON chunk as every reader reads it (spec/README.md, Conformance; the JavaScript decoder's twin
tests are js/test/json-fields.test.js): its nesting depth, integer members written as floats, and the
named error of each refusal.  Every file is a conformance file with its JSON edited here."""

from __future__ import annotations

import base64
import json
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import constants, shapes
from pmwm_codec.errors import FormatError, LimitError, PmwError
from pmwm_codec.format import gltf as gltf_module
from pmwm_codec.format.glb import frame_glb
from pmwm_codec.stream import StreamDecoder

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"
NAME = constants.EXTENSION_NAME


def conformance(name: str) -> bytes:
    return (CONFORMANCE / name).read_bytes()


def split(data: bytes) -> tuple:
    """``(gltf dict, BIN payload)`` of a GLB."""
    json_length = int.from_bytes(data[12:16], "little")
    return json.loads(data[20 : 20 + json_length]), data[20 + json_length + 8 :]


def framed(text: bytes, bin_payload: bytes) -> bytes:
    """A GLB of JSON text as it is (space padded) and a BIN payload."""
    return b"".join(frame_glb(text, [bin_payload], len(bin_payload)))


def with_text(data: bytes, edit) -> bytes:
    """``data`` with its JSON text replaced by ``edit(text)`` (the compact JSON of its document)."""
    gltf, bin_payload = split(data)
    return framed(edit(json.dumps(gltf, separators=(",", ":"))).encode(), bin_payload)


def nested(data: bytes, depth: int) -> bytes:
    """``data`` with ``nodes[0].extras`` arrays nested so that the document is ``depth`` levels deep
    (the document 1, ``nodes`` 2, the node 3, its extras 4 ...): written as text, as no JSON writer
    of Python recurses that deep."""
    gltf, bin_payload = split(data)
    gltf["nodes"][0]["extras"] = "@extras@"
    text = json.dumps(gltf, separators=(",", ":")).replace('"@extras@"', "[" * (depth - 3) + "]" * (depth - 3))
    return framed(text.encode(), bin_payload)


def decoded(data: bytes) -> tuple:
    """Every level of ``data`` as the push decoder gives it: ``[(positions_int, faces, attributes_int)]``."""
    decoder = StreamDecoder()
    results = decoder.feed(data)
    decoder.close()
    return [(r.positions_int, r.faces, np.concatenate([p.attributes_int for p in r.parts])) for r in results]


def same_levels(a, b) -> bool:
    return len(a) == len(b) and all(all(np.array_equal(x, y) for x, y in zip(la, lb)) for la, lb in zip(a, b))


# --- nesting depth (MAX_JSON_DEPTH) ---------------------------------------------------------------------


def _decode_with(api: str, data: bytes):
    if api == "decode":
        return pmwm_codec.decode(data)
    if api == "iter_decode":
        return list(pmwm_codec.iter_decode(data))
    return decoded(data)


@pytest.mark.parametrize("api", ["decode", "iter_decode", "StreamDecoder"])
@pytest.mark.parametrize("depth", [constants.MAX_JSON_DEPTH + 1, 1000, 3000, 100_000])
def test_json_nested_deeper_than_the_limit_is_a_limit_error_naming_it(api, depth):
    data = nested(conformance("grid-hole.plain.v2.pmw"), depth)
    with pytest.raises(LimitError, match=f"more than {constants.MAX_JSON_DEPTH} levels deep \\(MAX_JSON_DEPTH\\)"):
        _decode_with(api, data)


def test_json_nested_to_the_limit_decodes_as_without_the_nesting():
    data = conformance("grid-hole.plain.v2.pmw")
    assert same_levels(decoded(nested(data, constants.MAX_JSON_DEPTH)), decoded(data))


OPEN, CLOSE = "[" * constants.MAX_JSON_DEPTH, "]" * constants.MAX_JSON_DEPTH


@pytest.mark.parametrize("text, deep", [
    ('{"a":"' + OPEN + '"}', False),  # brackets in a string do not count
    ('{"a":"\\"' + OPEN + '"}', False),  # nor after an escaped quote
    ('{"a":"\\\\","b":' + OPEN + CLOSE + "}", True),  # an escaped backslash ends its string at the next quote
])
def test_the_depth_scan_skips_strings_as_json_does(text, deep):
    data = with_text(conformance("grid-hole.plain.v2.pmw"), lambda t: t[:-1] + ',"extras":' + text + "}")
    if deep:
        with pytest.raises(LimitError, match="levels deep"):
            decoded(data)
        return
    assert same_levels(decoded(data), decoded(conformance("grid-hole.plain.v2.pmw")))


def _scan_reference(text: bytes, limit: int) -> bool:
    """The spec's depth scan byte by byte (as js/src/header.js jsonTooDeep runs it): True when too deep."""
    depth, inside, odd = 0, False, False
    for b in text:
        if b == ord("\\"):
            odd = not odd
            continue
        if b == ord('"'):
            inside ^= not odd
        elif not inside and b in b"[{":
            depth += 1
            if depth > limit:
                return True
        elif not inside and b in b"]}":
            depth -= 1
        odd = False
    return False


@pytest.mark.parametrize("block", [3, 7, 64, 1 << 20])
def test_the_depth_scan_in_blocks_is_the_byte_by_byte_scan(monkeypatch, block):
    monkeypatch.setattr(gltf_module, "_SCAN_BLOCK", block)
    rng = np.random.default_rng(block)
    alphabet = np.frombuffer(b'[]{}"\\ax', np.uint8)
    for _ in range(2000):
        text = alphabet[rng.integers(0, len(alphabet), rng.integers(0, 60))].tobytes()
        limit = int(rng.integers(0, 6))
        try:
            gltf_module.check_json_text_depth(text, "text", limit)
            deep = False
        except LimitError:
            deep = True
        assert deep == _scan_reference(text, limit), (text, limit)


def test_every_file_the_encoder_writes_is_within_the_readers_depth(tmp_path):
    """The encoder takes input JSON as deep as MAX_JSON_DEPTH and writes a node's extras at the depth they
    had: the output is that deep, and decodes."""
    depth = constants.MAX_JSON_DEPTH
    mesh = shapes.icosphere(2, 1.0)
    pos, idx = mesh.positions.astype("<f4").tobytes(), mesh.faces.astype("<u4").tobytes()
    extras = 0
    for _ in range(depth - 3):  # the document 1, nodes 2, the node 3
        extras = [extras]
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "extras": extras}],
        "buffers": [{"byteLength": len(pos + idx),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(pos + idx).decode()}],
        "bufferViews": [{"buffer": 0, "byteLength": len(pos)}, {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": mesh.vertex_count, "type": "VEC3",
                       "min": mesh.positions.min(0).tolist(), "max": mesh.positions.max(0).tolist()},
                      {"bufferView": 1, "componentType": 5125, "count": mesh.faces.size, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    }
    src = tmp_path / "deep.gltf"
    src.write_text(json.dumps(doc))
    pmwm_codec.encode(src, tmp_path / "deep.pmw")
    data = (tmp_path / "deep.pmw").read_bytes()
    assert split(data)[0]["nodes"][0]["extras"] == extras
    assert len(decoded(data)) > 1
    with pytest.raises(LimitError):  # one level more is refused: the output is exactly at the limit
        decoded(nested(data, depth + 1))
