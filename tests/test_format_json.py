"""The JSON chunk as every reader reads it (spec/README.md, Conformance; the JavaScript decoder's twin
tests are js/test/json-fields.test.js): its nesting depth, integer members written as floats, and the
named error of each refusal.  Every file is a conformance file with its JSON edited here."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import constants, shapes
from pmwm_codec.errors import FormatError, LimitError, PmwError, UnsupportedVersionError
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


# --- integer members written as floats (spec README, JSON numbers) ----------------------------------------


def _edit(data: bytes, change) -> bytes:
    """``data`` with ``change(gltf, primitive, extension)`` applied to its JSON (the BIN kept)."""
    gltf, bin_payload = split(data)
    prim = gltf["meshes"][0]["primitives"][0]
    change(gltf, prim, prim["extensions"][NAME])
    return framed(json.dumps(gltf).encode(), bin_payload)


def _floats(path):
    """A change making the integer member at ``path`` (keys from the primitive's extension object, or
    from the document after a leading ``"/"``) a float of the same value."""
    def change(gltf, prim, ext):
        target = gltf if path[0] == "/" else ext
        keys = path[1:] if path[0] == "/" else path
        for key in keys[:-1]:
            target = target[key] if not callable(key) else key(gltf, prim, ext)
        last = keys[-1]
        target[last] = [float(x) for x in target[last]] if isinstance(target[last], list) else float(target[last])
    return change


def _view_of_chunks(gltf, prim, ext):
    return gltf["bufferViews"][ext["chunks"]["bufferView"]]


def _byte_offsets_as_floats(gltf, prim, ext):
    table = ext["chunks"]
    offsets = [0.0]
    for length in table["byteLengths"][:-1]:
        offsets.append(offsets[-1] + length)
    table["byteOffsets"] = offsets


INTEGRAL_FLOATS = {  # the probe's cases (grid bits, accessor count, bufferView offset, ...) and the rest of the kinds
    "grid bits": ("grid-hole.plain.v2.pmw", _floats(["grid", "bits"])),
    "version": ("grid-hole.plain.v2.pmw", _floats(["version"])),
    "payload version": ("grid-hole.plain.v2.pmw", _floats(["payload", "version"])),
    "vertexCount, faceCount": ("grid-hole.plain.v2.pmw",
                               lambda g, p, e: (_floats(["vertexCount"])(g, p, e), _floats(["faceCount"])(g, p, e))),
    "chunk table arrays": ("grid-hole.plain.v2.pmw", lambda g, p, e: [_floats(["chunks", k])(g, p, e) for k in
                                                                      ("bufferView", "byteLengths", "vertexCounts", "faceCounts")]),
    "chunk table byteOffsets": ("grid-hole.plain.v2.pmw", _byte_offsets_as_floats),
    "packed table count": ("sphere-pillows.draco.packed.v2.pmw", _floats(["chunks", "count"])),
    "firstFaceChunk": ("sphere-pillows.draco.packed.v2.pmw", _floats(["firstFaceChunk"])),
    "Draco attribute id and bufferView": ("sphere-pillows.draco.packed.v2.pmw", lambda g, p, e: (
        p["extensions"]["KHR_draco_mesh_compression"]["attributes"].update(
            POSITION=float(p["extensions"]["KHR_draco_mesh_compression"]["attributes"]["POSITION"])),
        p["extensions"]["KHR_draco_mesh_compression"].update(
            bufferView=float(p["extensions"]["KHR_draco_mesh_compression"]["bufferView"])))),
    "baseVertexCount": ("bowtie.welded-draco.v1.pmw", _floats(["baseVertexCount"])),
    "v1 chunk entries": ("bowtie.welded-draco.v1.pmw", lambda g, p, e: [
        _floats(["chunks", k, key])(g, p, e) for k in range(len(e["chunks"]))
        for key in ("bufferView", "byteLength", "uncompressedLength", "splits", "vertexCount", "faceCount")]),
    "attribute bits": ("sphere-attributes.plain.v2.pmw", lambda g, p, e: [a.update(bits=float(a["bits"])) for a in e["attributes"]]),
    "primitive POSITION, indices, mode": ("sphere-attributes.plain.v2.pmw", lambda g, p, e: (
        p["attributes"].update({s: float(i) for s, i in p["attributes"].items()}),
        p.update(indices=float(p["indices"]), mode=float(p["mode"])))),
    "accessors": ("sphere-attributes.plain.v2.pmw", lambda g, p, e: [
        a.update({k: float(a[k]) for k in ("bufferView", "byteOffset", "componentType", "count") if k in a})
        for a in g["accessors"]]),
    "bufferViews and the buffer": ("sphere-attributes.plain.v2.pmw", lambda g, p, e: (
        [v.update({k: float(v[k]) for k in ("buffer", "byteOffset", "byteLength", "target") if k in v}) for v in g["bufferViews"]],
        g["buffers"][0].update(byteLength=float(g["buffers"][0]["byteLength"])))),
    "scene and nodes": ("grid-hole.plain.v2.pmw", lambda g, p, e: (
        g.update(scene=float(g.get("scene", 0))), [n.update(mesh=float(n["mesh"])) for n in g["nodes"] if "mesh" in n])),
}


@pytest.mark.parametrize("case", sorted(INTEGRAL_FLOATS))
def test_integer_members_written_as_integral_floats_decode_as_the_integers(case):
    name, change = INTEGRAL_FLOATS[case]
    data = conformance(name)
    edited = _edit(data, change)
    assert b".0" in edited[: 20 + int.from_bytes(edited[12:16], "little")]
    assert same_levels(decoded(edited), decoded(data))


def test_integers_written_with_an_exponent_decode_as_the_integers():
    data = conformance("grid-hole.plain.v2.pmw")
    edited = with_text(data, lambda t: t.replace('"bits":16,', '"bits":1.6e1,').replace('"version":1,', '"version":1e0,', 1))
    assert b"1.6e1" in edited and b"1e0" in edited
    assert same_levels(decoded(edited), decoded(data))


@pytest.mark.parametrize("change, match", [
    (lambda g, p, e: e["grid"].update(bits=16.5), "grid/bits"),
    (lambda g, p, e: e["chunks"].update(count=e["chunks"]["count"] + 0.5), "count"),
    (lambda g, p, e: g["accessors"][p["attributes"]["POSITION"]].update(count=648.5), "count"),
    (lambda g, p, e: p.update(indices=p["indices"] + 0.5), "accessor"),
])
def test_an_integer_member_with_a_fraction_is_still_a_format_error(change, match):
    with pytest.raises(FormatError, match=match):
        decoded(_edit(conformance("sphere-pillows.draco.packed.v2.pmw"), change))


@pytest.mark.parametrize("payload_version", [1, 2])
def test_integral_floats_keep_a_marked_file_s_macs(payload_version):
    """The MACs' canonical JSON writes an integer member as an integer however the file writes it
    (bitstream.md 6.3): a JSON tool rewriting 16 as 16.0 keeps every MAC; ``0.0`` of a number member stays."""
    from conftest import marked_sphere

    data, key, _ = marked_sphere(5, payload_version=payload_version)

    def change(gltf, prim, ext):
        for member in ("version", "vertexCount", "faceCount"):
            ext[member] = float(ext[member])
        ext["grid"]["bits"] = float(ext["grid"]["bits"])
        ext["payload"]["version"] = float(ext["payload"]["version"])
        for member in ("bits", "width", "height", "levels", "codes", "carriers"):
            ext["watermark"][member] = float(ext["watermark"][member])
        if payload_version == 1:
            for entry in ext["chunks"]:
                for member in ("byteLength", "uncompressedLength", "splits", "vertexCount", "faceCount", "batches"):
                    entry[member] = float(entry[member])
        else:
            ext["chunks"]["count"] = float(ext["chunks"]["count"])

    edited = _edit(data, change)
    decoder = StreamDecoder(key)
    results = decoder.feed(edited)
    decoder.close()
    assert decoder.mac_checked == len(results) > 1 and not decoder.mac_failed and not decoder.mac_missing
    assert same_levels(decoded(edited), decoded(data))


# --- members that mean nothing -------------------------------------------------------------------------


def test_a_faces_member_on_a_version_1_chunk_entry_means_nothing():
    """Face chunks exist in payload version 2 only (bitstream.md 8.6): ``"faces": true`` on a version 1
    entry is a member the schema does not know (Python took it for a face chunk: AttributeError)."""
    data = conformance("grid-hole.plain.v1.pmw")
    edited = _edit(data, lambda g, p, e: [entry.update(faces=True) for entry in e["chunks"]])
    assert same_levels(decoded(edited), decoded(data))
    info = pmwm_codec.inspect(edited)
    assert not any(chunk["face_chunk"] for chunk in info["chunks"])


# --- attribute names -----------------------------------------------------------------------------------


def _glb_attribute(glb: bytes, semantic: str) -> np.ndarray:
    """The float32 values of the first primitive's ``semantic`` accessor in a GLB (tightly packed)."""
    gltf, bin_payload = split(glb)
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"][semantic]]
    view = gltf["bufferViews"][acc["bufferView"]]
    width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc["type"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return np.frombuffer(bin_payload, "<f4", acc["count"] * width, start).reshape(-1, width)


def test_a_decoded_level_renormalizes_normal_and_tangent_only_not_names_starting_so():
    """spec README, Seams and attributes: NORMAL and TANGENT are written at unit length; a custom
    ``NORMAL_1`` keeps its decoded values, as the JavaScript decoder gives them."""
    data = conformance("sphere-attributes.plain.v2.pmw")

    def rename(gltf, prim, ext):
        prim["attributes"]["NORMAL_1"] = prim["attributes"].pop("NORMAL")
        next(a for a in ext["attributes"] if a["semantic"] == "NORMAL")["semantic"] = "NORMAL_1"

    renamed = _edit(data, rename)
    raw = StreamDecoder().feed(renamed)[0].parts[0].attribute_values()["NORMAL_1"]
    written = _glb_attribute(pmwm_codec.decode_asset(renamed, chunks=0), "NORMAL_1")
    assert np.array_equal(written, raw)
    normal = _glb_attribute(pmwm_codec.decode_asset(data, chunks=0), "NORMAL")
    assert np.array_equal(normal, raw) is False
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0, atol=1e-6)


# --- the kind of each refusal (spec README, Kinds of refusal) --------------------------------------------


def _glb_version(version: int):
    def change(data: bytes) -> bytes:
        return data[:4] + version.to_bytes(4, "little") + data[8:]
    return change


def _member(path, value):
    """A change setting the member at ``path`` of the extension object (``"/"`` first: of the document)."""
    def change(gltf, prim, ext):
        target = gltf if path[0] == "/" else ext
        keys = path[1:] if path[0] == "/" else path
        for key in keys[:-1]:
            target = target[key]
        target[keys[-1]] = value
    return change


def _position_count(value):
    return lambda g, p, e: g["accessors"][p["attributes"]["POSITION"]].update(count=value)


V1, V2, PACKED, MARKED = "grid-hole.plain.v1.pmw", "grid-hole.plain.v2.pmw", "grid-hole.plain.packed.v2.pmw", "sphere.exact-watermark.v1.pmw"
REFUSALS = [  # (file, change of the JSON or of the bytes, kind, what the message names)
    (V2, _member(["vertexCount"], None), FormatError, "vertexCount"),
    (V2, _member(["vertexCount"], True), FormatError, "vertexCount"),
    (V2, _member(["vertexCount"], "1"), FormatError, "vertexCount"),
    (V2, _member(["vertexCount"], 1.5), FormatError, "vertexCount"),
    (V2, _member(["faceCount"], -1), FormatError, "faceCount"),
    (V2, _member(["vertexCount"], 1 << 27), LimitError, "vertexCount"),
    (V2, _member(["vertexCount"], 1e300), LimitError, "vertexCount"),
    (V2, _member(["version"], 1 << 60), UnsupportedVersionError, "version 1152921504606846976 is newer"),
    (V2, _member(["version"], 1e300), UnsupportedVersionError, "version a 301-digit integer is newer"),
    (V2, _member(["payload", "codec"], "pmwm-vsplitx"), UnsupportedVersionError, "payload 'pmwm-vsplitx' version 2"),
    (V2, _member(["payload", "version"], 3), UnsupportedVersionError, "payload 'pmwm-vsplit' version 3"),
    (V1, _member(["payload"], {"codec": "pmwm-vsplit", "version": 3}), UnsupportedVersionError, "version 3"),
    (V2, _member(["payload"], None), FormatError, "payload must be an object"),
    (V2, _member(["payload"], {}), FormatError, "payload must be an object"),
    (V2, _member(["payload", "version"], "2"), FormatError, "payload must be an object"),
    (V2, _glb_version(514), UnsupportedVersionError, "container version 514"),
    (V2, _glb_version(1), UnsupportedVersionError, "container version 1"),
    (MARKED, _member(["watermark", "carriers"], 1 << 27), LimitError, "carrier count"),
    (MARKED, _member(["watermark", "carriers"], -1), FormatError, "carriers"),
    (V2, lambda g, p, e: e["chunks"]["byteLengths"].__setitem__(0, 0), FormatError, "byteLengths/0"),
    (V1, _member(["chunks", 0, "byteLength"], 0), FormatError, "byteLength"),
    (V1, _member(["chunks", 0, "byteLength"], None), FormatError, "byteLength"),
    (V1, _member(["chunks", 0, "uncompressedLength"], -1), FormatError, "uncompressedLength"),
    (V1, _member(["chunks", 0, "vertexCount"], 1 << 27), LimitError, "vertices"),
    (PACKED, _member(["chunks", "count"], constants.MAX_CHUNKS + 1), LimitError, "exceeds the limit of 65536 chunks"),
    (PACKED, _member(["chunks", "count"], 1e300), LimitError, "exceeds the limit of 65536 chunks"),
    (V1, _position_count(-1), FormatError, "count"),
    (V1, _position_count(1 << 27), LimitError, "vertices exceed"),
]


@pytest.mark.parametrize("name, change, kind, named", REFUSALS, ids=[f"{i}-{r[3]}" for i, r in enumerate(REFUSALS)])
def test_each_refusal_has_its_kind_before_any_level(name, change, kind, named):
    data = conformance(name)
    edited = change(data) if change.__code__.co_argcount == 1 else _edit(data, change)
    decoder = StreamDecoder()
    with pytest.raises(kind, match=re.escape(named)) as info:
        decoder.feed(edited)  # the header's refusals come before the base mesh: no level is shown
    if kind is FormatError:
        assert not isinstance(info.value, (LimitError, UnsupportedVersionError)), info.value
    assert "\n" not in str(info.value) and len(str(info.value)) < 240
