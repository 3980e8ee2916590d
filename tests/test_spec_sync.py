"""spec/ and the code say the same thing: byte tables, limits, schemas, examples."""

import base64
import json
import re
from pathlib import Path

import jsonschema
import numpy as np
import pytest
from referencing import Registry, Resource

from pmwm_codec import constants
from pmwm_codec.format import layout, read_header, records
from pmwm_codec.format.extension import SCHEMA_DIR
from pmwm_codec.format.glb import split_glb
from pmwm_codec.progressive.vsplit import SYMBOL_COUNT
from samples import PAYLOAD_EXAMPLE, sample_pmw

SPEC = Path(__file__).resolve().parents[1] / "spec"
NAME = constants.EXTENSION_NAME
TYPE_SIZES = {"uint8": 1, "uint32": 4, "char[4]": 4}


def _tagged_tables(text):
    """{struct name: [(field, type, size), ...]} from tables preceded by ``<!-- layout: Name -->``."""
    tables = {}
    for match in re.finditer(r"<!-- layout: (\w+) -->\n((?:\|.*\n)+)", text):
        rows = [line.strip().strip("|").split("|") for line in match.group(2).splitlines()[2:]]
        tables[match.group(1)] = [(c[0].strip().strip("`"), c[1].strip().strip("`"), int(c[2])) for c in rows]
    return tables


def _schemas():
    return {p.name: json.loads(p.read_text()) for p in (SPEC / "schema").glob("*.schema.json")}


def _validator():
    schemas = _schemas()
    registry = Registry().with_resources((n, Resource.from_contents(s)) for n, s in schemas.items())
    schema = schemas[f"mesh.primitive.{NAME}.schema.json"]
    return jsonschema.Draft202012Validator(schema, registry=registry)


def test_bitstream_tables_match_layout_structs():
    tables = _tagged_tables((SPEC / "bitstream.md").read_text())
    assert set(tables) == set(layout.STRUCTS)
    for name, struct in layout.STRUCTS.items():
        code = [(sub.name, sub.sizeof()) for sub in struct.subcons]
        spec = [(field, size) for field, _, size in tables[name]]
        assert spec == code, name
        for field, type_, size in tables[name]:
            assert TYPE_SIZES[type_] == size, (name, field)


def _payload_section():
    text = (SPEC / "bitstream.md").read_text()
    return text[text.index("## 6. Chunk payload") : text.index("### 6.1")]


def test_bitstream_payload_columns_are_the_columns_the_code_writes():
    table = re.search(r"<!-- columns -->\n((?:\|.*\n)+)", _payload_section()).group(1)
    rows = [re.findall(r"`(\w+|attribute_\{D−4\})`", line.split("|")[1]) for line in table.splitlines()[2:]]
    assert [r[0] for r in rows[:-1]] == list(records.COLUMNS)
    # last row: the D - 3 attribute columns, attribute_0 ... attribute_{D-4}
    assert rows[-1] == [records.ATTRIBUTE_COLUMN.format(0), records.ATTRIBUTE_COLUMN.format("{D−4}")]
    for d in (3, 4, 7):
        names = records.column_names(d)
        assert len(names) == d + 2  # "Then come D + 2 columns"
        assert names[2:5] == ("residual_x", "residual_y", "residual_z")
        assert names[5:] == tuple(records.ATTRIBUTE_COLUMN.format(j) for j in range(d - 3))
    assert "Then come `D + 2` *columns*" in _payload_section().replace("\n", " ")


def test_bitstream_payload_example_is_what_pack_writes():
    section = _payload_section()
    block = re.search(r"<!-- payload-example -->\n```\n(.*?)```", section, re.S).group(1)
    hex_text = "".join(re.split(r" {2,}", line)[0].replace(" ", "") for line in block.splitlines())
    packed = records.pack_batches(PAYLOAD_EXAMPLE)
    assert bytes.fromhex(hex_text) == packed
    assert f"Its payload is {len(packed)} bytes" in section
    back = records.unpack_batches(packed, width=4)
    assert [b.v.tolist() for b in back] == [[2, 5], [0]]


def test_bitstream_packed_chunk_table_example_is_what_the_writer_packs_and_the_reader_expands():
    from pmwm_codec.format.extension import chunk_entries, float32_up
    from pmwm_codec.format.glb import compact_chunks

    text = (SPEC / "bitstream.md").read_text()
    section = text[text.index("*Worked example* (two chunks, no MACs") :]
    block = re.search(r"```\n(.*?)```", section, re.S).group(1)
    hex_text = "".join(re.match(r"(?:[0-9a-f]{2}\s+)*", line + " ").group(0) for line in block.splitlines())
    table = json.loads(re.search(r'the table is `(\{.*?\})`', section).group(1).replace("…", "3"))
    entries = [{"bufferView": 3, "byteOffset": 0, "byteLength": 300, "vertexCount": 120, "faceCount": 236,
                "geometricError": float32_up(0.0125), "digest": "0123456789abcdef", "splits": 120, "uncompressedLength": 300},
               {"bufferView": 3, "byteOffset": 300, "byteLength": 129, "vertexCount": 250, "faceCount": 496,
                "geometricError": 0.0, "digest": "fedcba9876543210", "splits": 130, "uncompressedLength": 129}]
    assert compact_chunks(entries) == table
    assert base64.b64decode(table["packed"]) == bytes.fromhex(hex_text.replace(" ", ""))
    assert f"{len(bytes.fromhex(hex_text))} bytes; the table is" in section
    assert chunk_entries({"payload": {"codec": "pmwm-vsplit", "version": 2}, "chunks": table}, 0) == entries
    assert repr(entries[0]["geometricError"]) in section


def test_bitstream_payload_limits_match_records():
    section = " ".join(_payload_section().split())
    assert f"batches in the chunk, 1 … {records.MAX_BATCHES_PER_CHUNK} |" in section
    assert f"reader MUST reject a stored residual above `2^{records.MAX_RESIDUAL_ZIGZAG.bit_length() - 1}`" in section
    assert records.MAX_RESIDUAL_ZIGZAG == 1 << (records.MAX_RESIDUAL_ZIGZAG.bit_length() - 1)
    assert "Bytes per value: " + ", ".join(map(str, records._WIDTHS[:-1])) + f" or {records._WIDTHS[-1]}" in section
    assert f"A packed value MUST be `< {SYMBOL_COUNT ** 3}` (every symbol `< {SYMBOL_COUNT}`)" in section
    assert f"`s_{{3t}} + {SYMBOL_COUNT}·s_{{3t+1}} + {SYMBOL_COUNT ** 2}·s_{{3t+2}}`" in section
    assert f"header (`batch_count` 1 … {records.MAX_BATCHES_PER_CHUNK})" in section


def test_readme_limits_table_matches_constants():
    text = (SPEC / "README.md").read_text()
    rows = dict(re.findall(r"^\| `(MAX_\w+)` \| (\d+) \|$", text, re.M))
    names = [n for n in dir(constants) if n.startswith("MAX_") and n != "MAX_GRID_BITS"]
    assert {n: int(rows[n]) for n in names} == {n: getattr(constants, n) for n in names}


def test_readme_names_the_extension_and_version():
    text = (SPEC / "README.md").read_text()
    assert text.startswith(f"# {NAME}\n")
    assert f"format version {constants.FORMAT_VERSION}" in text


def test_packaged_schemas_are_identical_to_spec_schemas():
    spec = {p.name: p.read_bytes() for p in (SPEC / "schema").glob("*.json")}
    packaged = {p.name: p.read_bytes() for p in SCHEMA_DIR.glob("*.json")}
    assert spec == packaged, "copy spec/schema/*.json to pmwm_codec/format/schema/"


@pytest.mark.parametrize("name", sorted(_schemas()))
def test_schema_is_valid_and_every_property_has_a_description(name):
    schema = _schemas()[name]
    jsonschema.Draft202012Validator.check_schema(schema)
    assert schema["$id"] == name and "description" in schema

    def walk(node, path):
        for key, prop in node.get("properties", {}).items():
            assert "description" in prop, f"{name}: {path}{key} has no description"
            walk(prop, f"{path}{key}.")
        if isinstance(node.get("items"), dict):
            walk(node["items"], path)

    walk(schema, "")


def test_schema_limits_match_constants():
    schemas = _schemas()
    grid = schemas[f"{NAME}.grid.schema.json"]["properties"]["bits"]
    assert (grid["minimum"], grid["maximum"]) == (constants.MIN_GRID_BITS, constants.MAX_GRID_BITS)
    chunks = schemas[f"mesh.primitive.{NAME}.schema.json"]["properties"]["chunks"]
    assert chunks["maxItems"] == constants.MAX_CHUNKS


def test_readme_property_tables_list_the_schema_properties():
    text = (SPEC / "README.md").read_text()
    documented = set(re.findall(r"^\| `(\w+)` \| `[^`]+` \|", text, re.M))
    schemas = _schemas()
    for name in (f"mesh.primitive.{NAME}.schema.json", f"{NAME}.chunk.schema.json", f"{NAME}.chunkTable.schema.json",
                 f"{NAME}.grid.schema.json"):
        props = set(schemas[name]["properties"]) - {"extensions", "extras"}
        assert props <= documented, (name, props - documented)


@pytest.mark.parametrize("codec", ["plain", "draco"])
def test_writer_output_validates_against_the_spec_schemas(codec):
    data, *_ = sample_pmw(codec, chunk_count=3)
    ext = read_header(data).extension
    _validator().validate(ext)


def test_a_payload_v2_file_s_chunk_table_validates_and_an_array_there_does_not():
    gltf, _ = split_glb((SPEC / "conformance" / "sphere.exact-watermark.v2.pmw").read_bytes())
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][NAME]
    _validator().validate(ext)
    assert isinstance(ext["chunks"], dict) and len(ext["chunks"]["macs"]) == 32 * len(ext["chunks"]["byteLengths"])
    with pytest.raises(jsonschema.ValidationError):
        _validator().validate({**ext, "chunks": read_header(
            (SPEC / "conformance" / "sphere.exact-watermark.v2.pmw").read_bytes()).extension["chunks"]})


def test_worked_example_is_valid_and_its_ranges_are_consistent():
    gltf = json.loads((SPEC / "examples" / "icosphere-plain.gltf.json").read_text())
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][NAME]
    _validator().validate(ext)
    views = gltf["bufferViews"]
    ends = [views[c["bufferView"]]["byteOffset"] + c["byteLength"] for c in ext["chunks"]]
    assert ends[-1] <= gltf["buffers"][0]["byteLength"]
    assert all(views[c["bufferView"]]["byteLength"] == c["byteLength"] for c in ext["chunks"])
    text = (SPEC / "README.md").read_text()
    for chunk in ext["chunks"]:
        assert chunk["digest"] in text  # the README quotes the example's real numbers


def _worked_example():
    """The README's worked example file: (pmw bytes, its glTF JSON as a dict)."""
    data, *_ = sample_pmw("plain", chunk_count=2, subdivisions=1, seed=5, chunk_sizes=[96, 200])
    return data, read_header(data).gltf_json


def test_worked_example_is_what_the_writer_produces_today(update_golden):
    data, gltf = _worked_example()
    path = SPEC / "examples" / "icosphere-plain.gltf.json"
    if update_golden:
        path.write_text(json.dumps(gltf, indent=2) + "\n")
    if gltf != json.loads(path.read_text()):
        pytest.fail(
            f"{path.name} is not what the writer produces today (zstd build or writer changed). If the change is "
            "deliberate, regenerate with: python -m pytest tests/test_spec_sync.py --update-golden, then update "
            "the byte table and digests of spec/README.md, Worked example"
        )
    assert len(data) == 2520
    text = (SPEC / "README.md").read_text()
    section = text[text.index("## Worked example") : text.index("## Implementation notes")]
    ext = gltf["meshes"][0]["primitives"][0]["extensions"][NAME]
    assert f"{len(data)}-byte file" in section and f"the `baseDigest` `{ext['baseDigest']}`" in section


def test_bitstream_base_digest_examples_are_what_the_reader_computes():
    from pmwm_codec.format.extension import BASE_DIGEST_LABEL, base_digest

    text = (SPEC / "bitstream.md").read_text()
    section = text[text.index("### 6.4 Base digest") : text.index("## 7. Watermark")]
    triangle = ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    assert f"`baseDigest` = `{base_digest(*triangle)}`" in section
    assert f"values `7, 8, 9`: `{base_digest(*triangle, [[7], [8], [9]])}`" in section
    assert f'b"{BASE_DIGEST_LABEL.decode()}"' in section and f"the {len(BASE_DIGEST_LABEL)}-byte label" in section


def test_bitstream_mac_examples_are_what_the_verifier_computes():
    """spec/bitstream.md §6.3, the *Example* of ``baseMac`` and a chunk's ``mac`` (version 1 entry)."""
    from pmwm_codec.format.mac import base_mac, canonical_json, chunk_mac

    text = (SPEC / "bitstream.md").read_text()
    section = text[text.index("### 6.3 Keyed MACs") : text.index("**`sceneMac`**")]
    key = bytes(range(32))
    ext = {"version": 1, "grid": {"bits": 8, "origin": [0.0, 0.0, 0.0], "step": 0.5}, "vertexCount": 4,
           "faceCount": 3, "chunks": []}
    public = canonical_json({"grid": ext["grid"], "version": 1})
    base = base_mac(key, 0, ext, [[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
    entry = {"bufferView": 1, "byteLength": 20, "digest": "0" * 32, "splits": 1, "vertexCount": 4,
             "faceCount": 3, "geometricError": 0.0, "uncompressedLength": 5}
    assert f"the {len(public)} bytes `{public.decode()}`" in section
    assert f"`baseMac = {base}`" in section
    assert f"`mac_0 = {chunk_mac(key, base, 0, 0, entry, b'hello')}`" in section


def test_readme_srgb8_table_is_the_one_the_readers_use():
    """spec/README.md's SRGB8_TO_LINEAR (float32 bit patterns) is the table of the Python reader and of the
    JavaScript one (js/src/constants.js), bit for bit."""
    import re

    from pmwm_codec.progressive.grid import SRGB8_TO_LINEAR

    readme = (SPEC / "README.md").read_text()
    block = readme[readme.index("`SRGB8_TO_LINEAR[b]`, `b` = 0…255"):]
    block = block[block.index("```") + 3:]
    words = block[:block.index("```")].split()
    assert [int(w, 16) for w in words] == SRGB8_TO_LINEAR.view(np.uint32).tolist()
    js = (SPEC.parent / "js" / "src" / "constants.js").read_text()
    js = js[js.index("export const SRGB8_TO_LINEAR"):]
    assert [int(w, 16) for w in re.findall(r"0x([0-9a-f]{8})", js[:js.index("]).buffer")])] == \
        SRGB8_TO_LINEAR.view(np.uint32).tolist()
