"""Bytes the JavaScript reader (js/src) and this one read differently, found by a differential run of both
over mutated files (helper-126): each case here was accepted by one reader and refused by the other, or
refused by this one with an exception that is no :class:`~pmwm_codec.errors.PmwError`.  The JavaScript
side's cases are in ``js/test/reader-differentials.test.js``.  The sources are conformance files."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pmwm_codec.errors import FormatError, LimitError
from pmwm_codec.format.glb import glb_parts, split_glb
from pmwm_codec.stream import StreamDecoder

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"
DRACO = "uv-torus-attributes.welded-draco.v1.pmw"  # Draco base, welded, COLOR_0 / TEXCOORD_0 / _FEATURE_ID_0
PLAIN = "sphere-attributes.plain.v1.pmw"  # plain base, NORMAL / TEXCOORD_0


def _decode(data: bytes) -> None:
    dec = StreamDecoder()
    dec.feed(data)
    dec.close()


def _rewrite(name: str, change) -> bytes:
    gltf, binary = split_glb((CONFORMANCE / name).read_bytes())
    change(gltf)
    return b"".join(glb_parts(gltf, [binary], len(binary)))


def _prim(gltf) -> dict:
    return gltf["meshes"][0]["primitives"][0]


@pytest.mark.parametrize("name", [DRACO, PLAIN])
def test_the_sources_decode(name):
    _decode((CONFORMANCE / name).read_bytes())
    _decode(_rewrite(name, lambda gltf: None))


@pytest.mark.parametrize("extra", [1, 2, 3])
def test_a_bin_chunk_whose_length_is_no_multiple_of_4_is_a_format_error(extra):
    """bitstream.md §3: a chunk's length is a multiple of 4. The JavaScript reader refused such a BIN chunk,
    this one decoded the file (bytes appended to the BIN, the GLB and BIN lengths raised to match)."""
    data = bytearray((CONFORMANCE / PLAIN).read_bytes() + bytes(extra))
    json_length = struct.unpack_from("<I", data, 12)[0]
    struct.pack_into("<I", data, 8, len(data))
    bin_length = struct.unpack_from("<I", data, 20 + json_length)[0]
    struct.pack_into("<I", data, 20 + json_length, bin_length + extra)
    with pytest.raises(FormatError, match="not a multiple of 4"):
        _decode(bytes(data))


def test_a_progressive_attribute_a_draco_base_primitive_lacks_is_a_format_error():
    """An extension attribute whose semantic is not in the primitive's attributes: a KeyError here on a
    Draco base (a plain base already refused it), a FormatError in JavaScript."""
    def change(gltf):
        _prim(gltf)["extensions"]["PMWM_progressive_mesh"]["attributes"][1]["semantic"] = "TEXCOORD_7"

    with pytest.raises(FormatError, match="'TEXCOORD_7' is not an attribute of the primitive"):
        _decode(_rewrite(DRACO, change))


@pytest.mark.parametrize("name, semantic", [(DRACO, "TEXCOORD_0"), (DRACO, "_PMWM_WELD"), (PLAIN, "NORMAL")])
@pytest.mark.parametrize("field, wrap", [("componentType", lambda v: [v]), ("componentType", lambda v: {str(v): 1}),
                                         ("type", lambda v: [v]), ("type", lambda v: {v: 1})])
def test_an_attribute_accessor_type_that_is_no_json_scalar_is_a_format_error(name, semantic, field, wrap):
    """``componentType: [5126]`` or ``type: ["VEC2"]`` on a progressive attribute's (or the weld's) accessor:
    a TypeError here (unhashable), a FormatError in JavaScript."""
    def change(gltf):
        acc = gltf["accessors"][_prim(gltf)["attributes"][semantic]]
        acc[field] = wrap(acc[field])

    with pytest.raises(FormatError):
        _decode(_rewrite(name, change))


@pytest.mark.parametrize("value", [True, False, -1, 65536, "1", None])
def test_a_draco_attribute_id_that_is_no_integer_of_its_range_is_a_format_error(value):
    """``KHR_draco_mesh_compression.attributes.COLOR_0: true``: this reader took it for unique id 1 (COLOR_0's
    own id in this file, so the file decoded); JavaScript refuses an id that is not an integer 0..65535."""
    def change(gltf):
        _prim(gltf)["extensions"]["KHR_draco_mesh_compression"]["attributes"]["COLOR_0"] = value

    with pytest.raises(FormatError):
        _decode(_rewrite(DRACO, change))


@pytest.mark.parametrize("name, which, count", [
    (PLAIN, "indices", 2**31), (PLAIN, "indices", 3 * 134217728 + 1), (DRACO, "indices", 2**32),
    (PLAIN, "TEXCOORD_0", 67108865), (PLAIN, "NORMAL", 2**32), (DRACO, "TEXCOORD_0", 2**64), (DRACO, "_PMWM_WELD", 2**31)])
def test_a_base_accessor_count_over_its_limit_is_a_limit_error(name, which, count):
    """spec README, Kinds of refusal: an accessor's count over a limit is a LimitError. This reader named an
    index count over ``3 * MAX_FACES`` that is no multiple of 3, and an attribute accessor's count over
    ``MAX_VERTICES`` (unequal to the POSITION count), format errors; JavaScript checks the limit first."""
    def change(gltf):
        prim = _prim(gltf)
        gltf["accessors"][prim["indices"] if which == "indices" else prim["attributes"][which]]["count"] = count

    with pytest.raises(LimitError):
        _decode(_rewrite(name, change))


@pytest.mark.parametrize("k", [0, 1, 2])
@pytest.mark.parametrize("count", [2**31, 67108865])
def test_a_chunk_table_vertex_count_over_the_limit_is_a_limit_error_before_the_next_counts_order(k, count):
    """A version 2 chunk table (array form) whose ``vertexCounts[k]`` is over ``MAX_VERTICES`` (2^31: its splits
    too): a LimitError in JavaScript, which checks chunk by chunk; this reader first saw ``vertexCounts[k + 1]``
    smaller than it and said FormatError."""
    def change(gltf):
        _prim(gltf)["extensions"]["PMWM_progressive_mesh"]["chunks"]["vertexCounts"][k] = count

    with pytest.raises(LimitError, match="exceeds the limit"):
        _decode(_rewrite("sphere-attributes.plain.v2.pmw", change))
