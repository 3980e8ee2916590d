"""The scene MAC (spec/bitstream.md §6.3, ``sceneMac``): ``pmw verify`` with the key says ``authentic``
only for the document the key holder wrote around the marked meshes -- nodes and their transforms,
scenes, other meshes, materials, images, animations, the asset -- and still for a ``pmw cut`` of it,
which it reports as a prefix of the key holder's stream (``whole_stream`` false)."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.constants import EXTENSION_NAME, MAX_JSON_DEPTH, MAX_SCENE_VALUES
from pmwm_codec.errors import LimitError
from pmwm_codec.format import mac, read_header
from pmwm_codec.format.glb import frame_glb, glb_parts, split_glb
from pmwm_codec.format.gltf import find_extension_primitives
from pmwm_codec.format.layout import padded
from pmwm_codec.format.mac import canonical_json, scene_data_end, scene_document, scene_mac
from pmwm_codec.stream.asset import encode_asset
from pmwm_codec.stream.cut import cut
from pmwm_codec.verify import verify_stream
from pmwm_codec.watermark.key import WatermarkKey

from conftest import marked_sphere
from test_asset import DocBuilder
from test_hostile_inputs import TINY_PNG

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"


# --- files ----------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def sphere():
    """A marked icosphere written by ``encode_mesh``: ``(pmw bytes, key)``."""
    data, key, _ = marked_sphere(11)
    return data, key


def _textured_asset() -> tuple:
    """``(gltf, buffers)``: one mesh of two textured primitives (a sphere and a torus, two materials, a PNG
    image in a bufferView), a second mesh (a grid) under a translated, rotated node, and an animation
    whose keyframes (times and translations) are accessors of the document."""
    b = DocBuilder()
    sphere, torus, grid = shapes.icosphere(3, 1.0, noise=0.02), shapes.torus(30, 15), shapes.grid(12, 12, hole=False)
    image = TINY_PNG + bytes(padded(len(TINY_PNG)) - len(TINY_PNG))
    b.doc["bufferViews"].append({"buffer": 0, "byteOffset": b.offset, "byteLength": len(TINY_PNG)})
    b.parts.append(image)
    b.offset += len(image)
    times = b.accessor(np.array([[0.0], [1.0]], np.float32), 5126, "SCALAR", minmax=True)
    moves = b.accessor(np.array([[3.0, 0, 0], [3.0, 1.0, 0]], np.float32), 5126, "VEC3")
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0, 1], "name": "world"}],
        "nodes": [{"mesh": 0, "name": "pair"},
                  {"mesh": 1, "translation": [3.0, 0.0, 0.0], "rotation": [0.0, 0.38268343, 0.0, 0.92387953]}],
        "meshes": [{"primitives": [{**b.triangles(sphere), "material": 0}, {**b.triangles(torus), "material": 1}]},
                   {"primitives": [{**b.triangles(grid), "material": 1}]}],
        "materials": [{"name": "skin", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}},
                      {"name": "blue", "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 1, 1]}}],
        "textures": [{"source": 0, "sampler": 0}], "samplers": [{"magFilter": 9729}],
        "images": [{"bufferView": 0, "mimeType": "image/png"}],
        "animations": [{"channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}],
                        "samplers": [{"input": times, "output": moves}]}],
    })
    b.doc["buffers"] = [{"byteLength": b.offset}]
    return b.doc, [b"".join(b.parts)]


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    """The textured asset encoded with a watermark key: ``(pmw bytes, key)``."""
    path = tmp_path_factory.mktemp("asset") / "scene.pmw"
    key = WatermarkKey.generate(rng=np.random.default_rng(21))
    mark = (np.indices((16, 16)).sum(0) % 2 * 200 + 30).astype(np.uint8)
    report = encode_asset(_textured_asset(), path, watermark=mark, key=key, measure=False)
    return path.read_bytes(), report.key


def _rewrite(data: bytes, change) -> bytes:
    """The file with ``change(gltf, bin bytearray)`` applied, re-framed (what anyone can do without the key)."""
    gltf, binary = split_glb(data)
    binary = bytearray(binary)
    out = change(gltf, binary)
    if out is not None:
        binary = out
    gltf["buffers"][0]["byteLength"] = len(binary)
    return b"".join(glb_parts(gltf, [bytes(binary)], len(binary)))


def _verify(capsys, tmp_path, data: bytes, key, *options) -> tuple:
    """``pmw verify FILE --key KEY [options]`` in process: ``(exit status, stdout)``."""
    path, key_path = tmp_path / "x.pmw", tmp_path / "x.key.json"
    path.write_bytes(data)
    if not key_path.exists():
        key.save(key_path)
    capsys.readouterr()
    status = main(["verify", str(path), "--key", str(key_path), *options])
    return status, capsys.readouterr().out


def _verify_json(capsys, tmp_path, data: bytes, key) -> tuple:
    status, out = _verify(capsys, tmp_path, data, key, "--json")
    return status, json.loads(out)


def _accessor_bytes(gltf: dict, index: int) -> tuple:
    """``(start, end)`` in the BIN of accessor ``index``'s first element."""
    acc = gltf["accessors"][index]
    view = gltf["bufferViews"][acc["bufferView"]]
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    return start, start + 4


# --- the key holder's files verify -----------------------------------------------------------------


def test_an_unedited_file_is_authentic_with_its_scene_covered_and_whole(capsys, tmp_path, sphere):
    data, key = sphere
    assert read_header(data).extension["sceneMac"]
    status, doc = _verify_json(capsys, tmp_path, data, key)
    assert (status, doc["verdict"], doc["mac"]["scene"], doc["whole_stream"]) == (0, "authentic", True, True)
    assert doc["codes_read"] == doc["carriers_total"] == read_header(data).extension["watermark"]["carriers"]


def test_a_multi_primitive_textured_animated_asset_verifies_authentic(capsys, tmp_path, asset):
    data, key = asset
    gltf, _ = split_glb(data)
    prims = find_extension_primitives(gltf, EXTENSION_NAME)
    assert len(prims) == 3 and gltf["images"] and gltf["animations"]
    macs = {prim["extensions"][EXTENSION_NAME]["sceneMac"] for _, _, prim in prims}
    assert len(macs) == 1  # one value, on every progressive primitive
    status, doc = _verify_json(capsys, tmp_path, data, key)
    assert (status, doc["verdict"], doc["mac"]["scene"], doc["mac"]["failed"]) == (0, "authentic", True, [])


@pytest.mark.parametrize("chunks", [0, 3])
def test_a_pmw_cut_file_keeps_its_scene_mac_and_says_it_is_a_prefix(capsys, tmp_path, asset, chunks):
    """A cut drops chunk bufferViews, renumbers the rest (the image's too), rewrites counts, the chunk table and
    the buffer length: none of that is in the scene MAC."""
    data, key = asset
    small = cut(data, chunks)
    assert split_glb(small)[0]["bufferViews"] != split_glb(data)[0]["bufferViews"]
    outcome = verify_stream(small, key)
    assert outcome.mac["scene"] is True and outcome.scene == "match" and not outcome.mac["failed"]
    assert outcome.whole_stream is False and outcome.codes_read < outcome.carriers_total
    status, out = _verify(capsys, tmp_path, small, key)
    assert f"a prefix of the key holder's stream: {outcome.codes_read:,} of {outcome.carriers_total:,} carriers read" in out


def test_a_cut_sphere_is_authentic_complete_and_not_whole(capsys, tmp_path, sphere):
    data, key = sphere
    status, doc = _verify_json(capsys, tmp_path, cut(data, 4), key)
    assert (status, doc["verdict"], doc["complete"], doc["mac"]["scene"]) == (0, "authentic", True, True)
    assert doc["whole_stream"] is False and doc["codes_read"] < doc["carriers_total"]


def test_a_json_rewrite_that_changes_only_layout_keeps_the_scene_mac(asset):
    """Key order, whitespace and an integral number written without its ``.0`` (as JavaScript tools write
    ``3.0``) are the same document."""
    data, key = asset
    gltf, binary = split_glb(data)
    assert gltf["nodes"][1]["translation"] == [3.0, 0.0, 0.0]
    gltf["nodes"][1]["translation"] = [3, 0, 0]
    text = json.dumps({k: gltf[k] for k in reversed(list(gltf))}, indent=2).encode()
    text += b" " * (padded(len(text)) - len(text))
    chunk = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    rewritten = struct.pack("<4sII", b"glTF", 2, 12 + len(chunk)) + chunk
    outcome = verify_stream(rewritten, key)
    assert (outcome.verdict, outcome.mac["scene"]) == ("authentic", True)


# --- edits of what the file shows are tampered ---------------------------------------------------------


def _shear(gltf, binary):
    gltf["nodes"][0]["matrix"] = [3, 0, 0, 0, 0, 0.3, 0, 0, 1.5, 0, 1, 0, 0, 0, 0, 1]


def _extra_mesh(gltf, binary):
    triangle = struct.pack("<9f", 0, 0, 0, 50, 0, 0, 0, 50, 0)
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(triangle)})
    gltf["accessors"].append({"bufferView": len(gltf["bufferViews"]) - 1, "componentType": 5126, "count": 3,
                              "type": "VEC3", "min": [0, 0, 0], "max": [50, 50, 0]})
    gltf["meshes"].append({"primitives": [{"attributes": {"POSITION": len(gltf["accessors"]) - 1}}]})
    gltf["nodes"].append({"mesh": len(gltf["meshes"]) - 1})
    gltf["scenes"][0]["nodes"].append(len(gltf["nodes"]) - 1)
    return binary + triangle


def _shown_twice(gltf, binary):
    gltf["nodes"].append({"mesh": 0, "scale": [-1, 1, 1], "translation": [12, 0, 0]})
    gltf["scenes"][0]["nodes"].append(len(gltf["nodes"]) - 1)


def _material(gltf, binary):
    gltf.setdefault("materials", []).append({"pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]}})
    gltf["meshes"][0]["primitives"][0]["material"] = len(gltf["materials"]) - 1


EDITS = {
    "node matrix shear": _shear,
    "node translation far away": lambda g, b: g["nodes"][0].update(translation=[1e6, 0, 0]),
    "node rotation": lambda g, b: g["nodes"][0].update(rotation=[0, 0, 1, 0]),
    "node scale": lambda g, b: g["nodes"][0].update(scale=[3, 0.3, 1]),
    "extra mesh in the scene": _extra_mesh,
    "mesh shown twice, mirrored": _shown_twice,
    "emptied scene": lambda g, b: g["scenes"][0].update(nodes=[]),
    "material": _material,
    "asset copyright": lambda g, b: g["asset"].update(copyright="Mallory 2026"),
    "asset extras": lambda g, b: g["asset"].update(extras={"owner": "mallory"}),
    "extensionsRequired emptied": lambda g, b: g.update(extensionsRequired=[]),
}


@pytest.mark.parametrize("edit", sorted(EDITS))
def test_an_edit_of_the_scene_around_a_marked_mesh_is_tampered(capsys, tmp_path, sphere, edit):
    data, key = sphere
    if edit == "extensionsRequired emptied" and "extensionsRequired" not in split_glb(data)[0]:
        pytest.skip("a plain base lists no required extension")
    edited = _rewrite(data, EDITS[edit])
    status, doc = _verify_json(capsys, tmp_path, edited, key)
    assert (status, doc["verdict"], doc["mac"]["scene"]) == (1, "tampered", False), edit
    assert doc["mac"]["failed"] == [] and doc["codes_matched"] == doc["codes_read"]  # the mark itself is intact
    status, out = _verify(capsys, tmp_path, edited, key)
    assert "the scene (nodes, materials, other meshes) differs from what the key holder wrote (sceneMac mismatch)" in out
    assert "verdict: tampered" in out and status == 1


def _image_byte(gltf, binary):
    view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    binary[view.get("byteOffset", 0) + 20] ^= 0x01


def _keyframe(gltf, binary):
    start, end = _accessor_bytes(gltf, gltf["animations"][0]["samplers"][0]["output"])
    binary[start:end] = struct.pack("<f", 40.0)


def _keyframe_time(gltf, binary):
    acc = gltf["animations"][0]["samplers"][0]["input"]
    start, end = _accessor_bytes(gltf, acc)
    binary[start + 4 : end + 4] = struct.pack("<f", 9.0)  # the second key time
    gltf["accessors"][acc]["max"] = [9.0]


def _other_mesh_vertex(gltf, binary):
    start, end = _accessor_bytes(gltf, gltf["meshes"][1]["primitives"][0]["attributes"]["POSITION"])
    binary[start:end] = struct.pack("<f", 5.0)


def _texture_sampler(gltf, binary):
    gltf["samplers"][0]["magFilter"] = 9728


ASSET_EDITS = {
    "image bytes": _image_byte,
    "animation keyframe value": _keyframe,
    "animation keyframe time": _keyframe_time,
    "texture sampler": _texture_sampler,
    "node of the second mesh": lambda g, b: g["nodes"][1].update(translation=[30.0, 0.0, 0.0]),
}


@pytest.mark.parametrize("edit", sorted(ASSET_EDITS))
def test_an_edit_of_an_assets_images_animations_or_nodes_is_tampered(capsys, tmp_path, asset, edit):
    data, key = asset
    status, doc = _verify_json(capsys, tmp_path, _rewrite(data, ASSET_EDITS[edit]), key)
    assert (status, doc["verdict"], doc["mac"]["scene"], doc["mac"]["failed"]) == (1, "tampered", False, []), edit


def test_the_vertices_of_a_mesh_that_is_not_progressive_are_covered(tmp_path):
    """A primitive passed through unchanged (points here) is the document's too: its bytes are covered."""
    b = DocBuilder()
    cloud = np.random.default_rng(2).uniform(-1, 1, (40, 3)).astype(np.float32)
    b.doc.update({"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
                  "meshes": [{"primitives": [b.triangles(shapes.icosphere(3, 1.0, noise=0.02)),
                                             {"attributes": {"POSITION": b.accessor(cloud, 5126, "VEC3", 34962, True)},
                                              "mode": 0}]}]})
    key = WatermarkKey.generate(rng=np.random.default_rng(4))
    mark = np.random.default_rng(4).integers(0, 256, (16, 16)).astype(np.uint8)
    b.doc["buffers"] = [{"byteLength": b.offset}]
    report = encode_asset((b.doc, [b"".join(b.parts)]), tmp_path / "p.pmw", watermark=mark, key=key, measure=False)
    data = (tmp_path / "p.pmw").read_bytes()
    assert verify_stream(data, report.key).mac["scene"] is True

    def move_point(gltf, binary):
        start, end = _accessor_bytes(gltf, gltf["meshes"][0]["primitives"][1]["attributes"]["POSITION"])
        binary[start:end] = struct.pack("<f", 7.0)

    outcome = verify_stream(_rewrite(data, move_point), report.key)
    assert (outcome.verdict, outcome.mac["scene"]) == ("tampered", False)


# --- sceneMac itself --------------------------------------------------------------------------------


def test_a_stripped_scene_mac_breaks_the_base_mac(capsys, tmp_path, sphere):
    data, key = sphere

    def strip(gltf, binary):
        del gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["sceneMac"]

    status, doc = _verify_json(capsys, tmp_path, _rewrite(data, strip), key)
    assert (status, doc["verdict"], doc["mac"]["failed"], doc["mac"]["scene"]) == (1, "not-authentic", [0], None)


def test_a_scene_mac_recomputed_without_the_key_breaks_the_base_mac(capsys, tmp_path, sphere):
    """Whoever edits the scene and puts a scene MAC of their own key on it fails ``baseMac``, which covers it."""
    data, key = sphere
    other = WatermarkKey.generate(rng=np.random.default_rng(99))

    def forge(gltf, binary):
        gltf["nodes"][0]["translation"] = [5.0, 0.0, 0.0]
        gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]["sceneMac"] = \
            scene_mac(other.mac_key(), gltf, bytes(binary))

    status, doc = _verify_json(capsys, tmp_path, _rewrite(data, forge), key)
    assert (status, doc["verdict"], doc["mac"]["failed"], doc["mac"]["scene"]) == (1, "not-authentic", [0], False)


def test_a_reference_the_scene_mac_cannot_read_is_a_mismatch_not_unchecked(asset):
    data, key = asset

    def past_the_end(gltf, binary):
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary) + 64, "byteLength": 68})
        gltf["images"][0]["bufferView"] = len(gltf["bufferViews"]) - 1

    outcome = verify_stream(_rewrite(data, past_the_end), key)
    assert (outcome.verdict, outcome.mac["scene"], outcome.scene) == ("tampered", False, "mismatch")


def test_a_stream_cut_before_the_scene_data_leaves_the_scene_unchecked_and_says_so(asset):
    data, key = asset
    header = read_header(data)
    end = header.bin_offset + scene_data_end(header.gltf_json)
    outcome = verify_stream(data[: end - 1], key)
    assert not outcome.end.complete and outcome.mac["scene"] is None and outcome.scene == "not arrived"
    assert "the scene (nodes, materials, other meshes): not checked, the data it covers has not arrived" \
        in outcome.mac_notes()
    assert verify_stream(data[:end], key).mac["scene"] is True  # the scene is checked as soon as its data is in


@pytest.mark.parametrize("name", ["sphere.exact-watermark.packed.v2", "sphere.paper-watermark.v2"])
def test_a_file_written_before_the_scene_mac_verifies_as_before_with_a_note(capsys, tmp_path, name):
    data = (CONFORMANCE / f"{name}.pmw").read_bytes()
    assert "sceneMac" not in read_header(data).extension and "baseMac" in read_header(data).extension
    key = WatermarkKey.load(CONFORMANCE / f"{name}.key.json")
    status, doc = _verify_json(capsys, tmp_path, data, key)
    assert (status, doc["verdict"], doc["mac"]["scene"], doc["mac"]["failed"]) == (0, "authentic", None, [])
    (tmp_path / "x.key.json").unlink()
    status, out = _verify(capsys, tmp_path, data, key)
    assert status == 0 and "the scene (nodes, materials, other meshes): not covered, the file has no sceneMac" in out


def test_the_scene_document_leaves_out_what_the_other_macs_cover_and_what_a_cut_rewrites(asset):
    data, _ = asset
    gltf, _ = split_glb(data)
    doc, sources = scene_document(gltf)
    assert "buffers" not in doc and "bufferViews" not in doc
    for _, _, prim in find_extension_primitives(doc, EXTENSION_NAME):
        assert prim["extensions"] == {EXTENSION_NAME: {}}
        assert all(doc["accessors"][i] is None for i in [*prim["attributes"].values(), prim["indices"]])
    assert doc["images"][0]["bufferView"] == len(sources) - 1  # the image's content field comes after the accessors'
    assert all(a is None or "byteOffset" not in a for a in doc["accessors"])
    assert gltf == split_glb(data)[0]  # the file's JSON is not modified


def test_the_worked_example_of_the_spec():
    """spec/bitstream.md §6.3, *Example* (sceneMac)."""
    doc, key = _example()
    s, sources = scene_document(doc)
    assert canonical_json(s) == EXAMPLE_S
    assert sources == [(1, 0, 2, 6, True), (2, 0, 1, None, False)]
    assert scene_mac(key, doc, EXAMPLE_BIN) == EXAMPLE_MAC


def _example() -> tuple:
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "translation": [1.0, 0.0, 0.5]}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "material": 0,
                                    "extensions": {EXTENSION_NAME: {"version": 1}}},
                                   {"attributes": {"POSITION": 1}, "mode": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0}], "images": [{"bufferView": 2, "mimeType": "image/png"}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                      {"bufferView": 1, "byteOffset": 0, "componentType": 5123, "count": 2, "type": "VEC3"}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}, {"buffer": 0, "byteOffset": 36, "byteLength": 16, "byteStride": 8},
                        {"buffer": 0, "byteOffset": 52, "byteLength": 4}],
        "buffers": [{"byteLength": 56}],
        "extensionsUsed": [EXTENSION_NAME],
    }
    return doc, bytes(range(32))


EXAMPLE_BIN = bytes(36) + struct.pack("<3H2x3H2x", 1, 2, 3, 4, 5, 6) + b"\x89PNG"
EXAMPLE_S = (
    b'{"accessors":[null,{"bufferView":0,"componentType":5123,"count":2,"type":"VEC3"}],"asset":{"version"'
    b':"2.0"},"extensionsUsed":["PMWM_progressive_mesh"],"images":[{"bufferView":1,"mimeType":"image/png"}'
    b'],"materials":[{"pbrMetallicRoughness":{"baseColorTexture":{"index":0}}}],"meshes":[{"primitives":[{'
    b'"attributes":{"POSITION":0},"extensions":{"PMWM_progressive_mesh":{}},"material":0},{"attributes":{"'
    b'POSITION":1},"mode":0}]}],"nodes":[{"mesh":0,"translation":[1,0,0.5]}],"scene":0,"scenes":[{"nodes":'
    b'[0]}],"textures":[{"source":0}]}'
)
EXAMPLE_MAC = "7bf93886522788412dcefd8fddd2a768"


# --- verify --reference: the reference must be the key holder's file as written ------------------------


@pytest.mark.parametrize("edit", ["node matrix shear", "node scale", "extra mesh in the scene"])
def test_a_mesh_checked_against_an_edited_reference_is_not_authentic(capsys, tmp_path, sphere, edit):
    """The decoded mesh of an edited file, checked against that same edited file as its reference, matched
    code for code and read ``authentic``: nothing checked the reference's MACs (an attacker hands in both).
    Against the key holder's file as written the same mesh was already refused; now the reference's MACs are
    checked as ``pmw verify FILE.pmw`` checks them."""
    import pmwm_codec

    data, key = sphere
    edited = _rewrite(data, EDITS[edit])
    (tmp_path / "ref.pmw").write_bytes(edited)
    key.save(tmp_path / "k.json")
    assert main(["decode", str(tmp_path / "ref.pmw"), "-o", str(tmp_path / "shown.obj"), "-q"]) == 0
    capsys.readouterr()
    status = main(["verify", str(tmp_path / "shown.obj"), "--reference", str(tmp_path / "ref.pmw"), "--key",
                   str(tmp_path / "k.json"), "--json"])
    doc = json.loads(capsys.readouterr().out)
    assert (status, doc["verdict"], doc["reference_mac"]["scene"]) == (1, "not-authentic", False)
    status = main(["verify", str(tmp_path / "shown.obj"), "--reference", str(tmp_path / "ref.pmw"), "--key",
                   str(tmp_path / "k.json")])
    assert status == 1 and "the reference is not the key holder's file as written" in capsys.readouterr().out
    untouched = pmwm_codec.decode(data)  # the key holder's own file as reference: authentic, its scene covered
    from pmwm_codec.verify import verify_mesh

    ok = verify_mesh((untouched.positions, untouched.faces), data, key)
    assert ok.verdict == "authentic" and ok.reference_mac["scene"] is True and ok.reference_mac["failed"] == []


# --- the work the scene MAC does is bounded (MAX_JSON_DEPTH, MAX_SCENE_VALUES) ---------------------


def _with_node_extras(data: bytes, text: str) -> bytes:
    """The file with its first node's ``extras`` the JSON ``text`` (framed by hand: json.dumps would recurse)."""
    gltf, binary = split_glb(data)
    gltf["nodes"][0]["extras"] = "@extras@"
    doc = json.dumps(gltf, separators=(",", ":")).replace('"@extras@"', text)
    return b"".join(frame_glb(doc.encode(), [bytes(binary)], len(binary)))


def test_extras_nested_100k_deep_are_refused_by_the_reader_in_one_line_before_the_scene_mac(capsys, tmp_path, sphere):
    """Deep nesting never reaches the scene MAC's walk (nor Python's recursion limit): the reader refuses JSON
    nested more than MAX_JSON_DEPTH levels from its text, before parsing it."""
    data, key = sphere
    path, key_path = tmp_path / "x.pmw", tmp_path / "x.key.json"
    path.write_bytes(_with_node_extras(data, "[" * 100_000 + "]" * 100_000))
    key.save(key_path)
    assert main(["verify", str(path), "--key", str(key_path)]) == 2
    assert capsys.readouterr() == ("", f"pmw: error: {path}: GLB JSON chunk: JSON nested more than {MAX_JSON_DEPTH} "
                                       "levels deep (MAX_JSON_DEPTH)\n")


def test_a_scene_of_more_than_max_scene_values_is_a_mismatch_found_without_copying_it(capsys, tmp_path, sphere):
    """A legal but wide document (a node's extras of 2 x MAX_SCENE_VALUES numbers, 16 MiB of JSON) was copied and
    hashed whole, twice: 30M values cost a verify 280 s and 5 GB.  The scene MAC now stops at MAX_SCENE_VALUES:
    no writer writes such a scene, so it is a mismatch (tampered), found in the time of reading the JSON."""
    import time

    data, key = sphere
    wide = _with_node_extras(data, "[" + ",".join(["1"] * (2 * MAX_SCENE_VALUES)) + "]")
    with pytest.raises(LimitError, match="more than 4,194,304 JSON values"):
        scene_document(split_glb(wide)[0])
    start = time.monotonic()
    status, doc = _verify_json(capsys, tmp_path, wide, key)
    assert time.monotonic() - start < 30
    assert (status, doc["verdict"], doc["mac"]["scene"]) == (1, "tampered", False)


def test_a_document_of_more_than_max_scene_values_is_refused_by_the_writer_with_nothing_written(capsys, tmp_path,
                                                                                                monkeypatch):
    """A key holder's file must verify: a marked file whose scene is over MAX_SCENE_VALUES is never written."""
    monkeypatch.setattr(mac, "MAX_SCENE_VALUES", 60)
    gltf, buffers = _textured_asset()
    src, out = tmp_path / "scene.glb", tmp_path / "scene.pmw"
    src.write_bytes(b"".join(frame_glb(json.dumps(gltf).encode(), buffers, len(buffers[0]))))
    Image.fromarray((np.indices((16, 16)).sum(0) % 2 * 200 + 30).astype(np.uint8)).save(tmp_path / "wm.png")
    assert main(["encode", str(src), "-o", str(out), "--watermark", str(tmp_path / "wm.png"), "-q"]) == 2
    assert capsys.readouterr().err == ("pmw: error: the scene holds more than 60 JSON values (MAX_SCENE_VALUES, "
                                       "spec/bitstream.md §6.3): too many for its sceneMac\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.glb", "wm.png"]
    assert main(["encode", str(src), "-o", str(out), "-q"]) == 0  # no key, no scene MAC: no limit
