"""glTF inputs the encoder must refuse by name, or label right (outside probe 2, findings 03-07).

Each bad input ends ``pmw encode`` with exit 2, one ``pmw: error:`` line naming the problem and
no output file, and the library with an :class:`InputFormatError`: an image whose type is not
declared and cannot be told from its bytes (03), an accessor ``normalized`` that is not a JSON
boolean (04) or is true where glTF does not allow it (05), an index reference out of range (06),
an extension required but not supported, or required but not used (07).  Valid assets of the same
kinds (KTX2 textures, required material extensions, animations) still encode, and keep what they say.
"""

from __future__ import annotations

import base64
import json

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.errors import InputFormatError
from pmwm_codec.format.document import load_document, read_accessor, sniff_json
from pmwm_codec.format.glb import split_glb
from pmwm_codec.stream.asset import decode_asset

from test_hostile_inputs import TINY_PNG, assert_refused, gltf_doc, run_encode, write_gltf

#: The 12-byte KTX2 file identifier, then a body (the encoder never decodes textures).
KTX2 = b"\xabKTX 20\xbb\r\n\x1a\n" + bytes(200)
PNG_URI = "data:image/png;base64," + base64.b64encode(TINY_PNG).decode()


@pytest.fixture
def mesh():
    return shapes.icosphere(1)


def refused(capsys, tmp_path, doc, *words, files=()):
    """``doc`` (with ``files``: ``{name: bytes}`` beside it) is refused by the CLI and by the library,
    each naming every one of ``words`` (the library's message is the CLI's line)."""
    folder = tmp_path / "asset"
    folder.mkdir(parents=True, exist_ok=True)
    for file_name, data in dict(files).items():
        (folder / file_name).write_bytes(data)
    src = write_gltf(folder, doc)
    assert_refused(*run_encode(capsys, tmp_path, src), "m.gltf", *words)
    out = tmp_path / "api.pmw"
    with pytest.raises(InputFormatError) as exc:
        pmwm_codec.encode(src, out, measure="none")
    for word in ("m.gltf", *words):
        assert word in str(exc.value)
    assert not out.exists()


def encoded(capsys, tmp_path, doc, files=()) -> dict:
    """The glTF JSON of the ``.pmw`` that ``pmw encode`` writes of ``doc`` (exit 0)."""
    folder = tmp_path / "asset"
    folder.mkdir(parents=True, exist_ok=True)
    for file_name, data in dict(files).items():
        (folder / file_name).write_bytes(data)
    status, err, out = run_encode(capsys, tmp_path, write_gltf(folder, doc))
    assert status == 0, err
    return sniff_json(out)


def basisu_doc(mesh, image: dict) -> dict:
    """A mesh textured by a KHR_texture_basisu texture of ``image`` (no fallback source)."""
    doc = gltf_doc(mesh, images=["x"])
    doc.update(images=[image], textures=[{"extensions": {"KHR_texture_basisu": {"source": 0}}}],
               extensionsUsed=["KHR_texture_basisu"], extensionsRequired=["KHR_texture_basisu"])
    return doc


def append_view(doc: dict, data: bytes) -> int:
    """Extend the data-URI buffer of ``doc`` (from :func:`gltf_doc`) by ``data`` as a new bufferView; its index."""
    blob = base64.b64decode(doc["buffers"][0]["uri"].partition(",")[2])
    blob += bytes(-len(blob) % 4)
    doc["buffers"][0] = {"byteLength": len(blob) + len(data),
                         "uri": "data:application/octet-stream;base64," + base64.b64encode(blob + data).decode()}
    doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data)})
    return len(doc["bufferViews"]) - 1


def with_view_image(doc: dict, data: bytes, **image) -> dict:
    """``doc`` with images[0] the bufferView of ``data`` (and the members ``image``)."""
    doc["images"] = [{"bufferView": append_view(doc, data), **image}]
    return doc


# --- 03: an image's type is declared, read from its data URI or its bytes, never guessed ---------------


@pytest.mark.parametrize("how", ["file", "data URI", "octet-stream data URI", "bufferView"])
def test_a_ktx2_image_without_a_mime_type_is_labelled_ktx2(capsys, tmp_path, mesh, how):
    uri = {"file": "tex.ktx2", "data URI": "data:image/ktx2;base64," + base64.b64encode(KTX2).decode(),
           "octet-stream data URI": "data:application/octet-stream;base64," + base64.b64encode(KTX2).decode()}
    doc = basisu_doc(mesh, {"uri": uri.get(how, "x")})
    if how == "bufferView":
        doc = with_view_image(doc, KTX2)
    gltf = encoded(capsys, tmp_path, doc, files={"tex.ktx2": KTX2})
    assert [image.get("mimeType") for image in gltf["images"]] == ["image/ktx2"]
    assert "KHR_texture_basisu" in gltf["extensionsRequired"]
    assert gltf["textures"] == [{"extensions": {"KHR_texture_basisu": {"source": 0}}}]


def test_a_declared_or_data_uri_image_type_is_kept(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh, images=["tex.bin", "data:image/webp;base64," + base64.b64encode(b"not sniffed").decode()])
    doc["images"][0]["mimeType"] = "image/ktx2"
    gltf = encoded(capsys, tmp_path, doc, files={"tex.bin": b"some bytes the encoder does not read"})
    assert [image["mimeType"] for image in gltf["images"]] == ["image/ktx2", "image/webp"]


def test_png_jpeg_and_webp_images_are_still_told_from_their_bytes(capsys, tmp_path, mesh):
    jpeg, webp = b"\xff\xd8\xff\xe0" + bytes(20), b"RIFF\x10\0\0\0WEBPVP8 " + bytes(8)
    doc = gltf_doc(mesh, images=["a.img", "b.img", "c.img"])
    gltf = encoded(capsys, tmp_path, doc, files={"a.img": TINY_PNG, "b.img": jpeg, "c.img": webp})
    assert [image["mimeType"] for image in gltf["images"]] == ["image/png", "image/jpeg", "image/webp"]


@pytest.mark.parametrize("how", ["file", "octet-stream data URI", "bufferView"])
def test_an_image_whose_type_cannot_be_told_is_refused_not_guessed(capsys, tmp_path, mesh, how):
    data = b"GIF89a" + bytes(30)
    uri = {"file": "tex.png",
           "octet-stream data URI": "data:application/octet-stream;base64," + base64.b64encode(data).decode()}
    doc = gltf_doc(mesh, images=[uri.get(how, "x")])
    if how == "bufferView":
        doc = with_view_image(doc, data)
    refused(capsys, tmp_path, doc, "images[0]", "mimeType", files={"tex.png": data})


def test_a_mime_type_that_is_not_a_string_is_refused(capsys, tmp_path, mesh):
    doc = with_view_image(gltf_doc(mesh, images=["x"]), TINY_PNG, mimeType=7)
    refused(capsys, tmp_path, doc, "images[0].mimeType")


def in_memory(doc: dict) -> tuple:
    """``doc`` (from :func:`gltf_doc`) as the in-memory ``(gltf, buffers)`` the library takes."""
    blob = base64.b64decode(doc["buffers"][0].pop("uri").partition(",")[2])
    return doc, [blob]


@pytest.mark.parametrize("edit, words", [
    (lambda d: with_view_image(d, b"GIF89a" + bytes(30)), "the asset: images[0] has no mimeType"),
    (lambda d: d["meshes"][0]["primitives"][0].update(material=4), "the asset: meshes[0].primitives[0].material = 4"),
    (lambda d: d["accessors"][1].update(normalized=True), "the asset: accessors[1].normalized is true"),
    (lambda d: d.update(extensionsUsed=["EXT_x"], extensionsRequired=["EXT_x"]), "requires the glTF extension EXT_x"),
])
def test_an_in_memory_document_is_refused_as_a_file_is(tmp_path, mesh, edit, words):
    doc = gltf_doc(mesh, images=[PNG_URI])
    edit(doc)
    with pytest.raises(InputFormatError) as exc:
        pmwm_codec.encode(in_memory(doc), tmp_path / "out.pmw", measure="none")
    assert words in str(exc.value) and "\n" not in str(exc.value)
    assert not (tmp_path / "out.pmw").exists()


def test_an_in_memory_bufferview_image_without_a_mime_type_is_labelled(tmp_path, mesh):
    doc = with_view_image(gltf_doc(mesh, images=["x"]), KTX2)
    pmwm_codec.encode(in_memory(doc), tmp_path / "out.pmw", measure="none")
    assert sniff_json(tmp_path / "out.pmw")["images"][0]["mimeType"] == "image/ktx2"


# --- 04, 05: accessor normalized is a boolean, and true only where glTF allows it ---------------------


def quantized_doc(mesh, normalized) -> dict:
    """Positions as UNSIGNED_SHORT 0..100 (KHR_mesh_quantization), with ``normalized`` when not None."""
    q = np.zeros((mesh.vertex_count, 4), "<u2")
    q[:, :3] = np.round((mesh.positions - mesh.positions.min(0)) * 50)
    doc = gltf_doc(mesh)
    view = append_view(doc, q.tobytes())
    doc["bufferViews"][view]["byteStride"] = 8
    doc["accessors"][0].update(bufferView=view, componentType=5123,
                               min=q[:, :3].min(0).tolist(), max=q[:, :3].max(0).tolist())
    if normalized is not None:
        doc["accessors"][0]["normalized"] = normalized
    doc.update(extensionsUsed=["KHR_mesh_quantization"], extensionsRequired=["KHR_mesh_quantization"])
    return doc


@pytest.mark.parametrize("value", ["false", "true", 0, 1, None])
def test_normalized_that_is_not_a_json_boolean_is_refused(capsys, tmp_path, mesh, value):
    doc = quantized_doc(mesh, value)
    if value is None:
        doc["accessors"][0]["normalized"] = None
    refused(capsys, tmp_path, doc, "accessors[0].normalized", repr(value))


@pytest.mark.parametrize("normalized", [False, None])
def test_quantized_positions_still_encode_at_their_scale(tmp_path, mesh, normalized):
    src = write_gltf(tmp_path / "asset", quantized_doc(mesh, normalized))
    pmwm_codec.encode(src, tmp_path / "out.pmw", measure="none")
    glb, _, _ = decode_asset(tmp_path / "out.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    gltf, buffers = load_document(tmp_path / "out.glb")
    positions = read_accessor(gltf, buffers, gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"])
    assert 99 < positions.max() <= 101  # the integers, not divided by 65535


@pytest.mark.parametrize("accessor, component", [(1, 5125), (0, 5126)])
def test_normalized_on_unsigned_int_or_float_is_refused_by_name(capsys, tmp_path, mesh, accessor, component):
    doc = gltf_doc(mesh)
    doc["accessors"][accessor]["normalized"] = True
    refused(capsys, tmp_path, doc, f"accessors[{accessor}].normalized", str(component))


def test_normalized_indices_are_refused(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh)
    doc["accessors"][1].update(bufferView=append_view(doc, mesh.faces.astype("<u2").tobytes()), componentType=5123,
                               normalized=True)
    refused(capsys, tmp_path, doc, "meshes[0].primitives[0].indices", "normalized")


@pytest.mark.parametrize("kind, component, said", [("VEC3", 5125, "a VEC3 of UNSIGNED_INT (5125)"),
                                                    ("SCALAR", 5126, "a SCALAR of FLOAT (5126)"),
                                                    ("SCALAR", 5122, "a SCALAR of SHORT (5122)")])
def test_indices_that_are_not_an_unsigned_integer_scalar_are_refused(capsys, tmp_path, mesh, kind, component, said):
    """glTF 2.0 3.7.2.1: whole numbers stored as FLOAT, or a VEC3 of indices, are not indices (they were
    read as if they were, and the output rewrote them valid: a silent repair of an invalid asset)."""
    doc = gltf_doc(mesh)
    values = mesh.faces.astype("<f4" if component == 5126 else "<i2" if component == 5122 else "<u4")
    count = mesh.faces.size // (3 if kind == "VEC3" else 1)
    doc["accessors"][1].update(bufferView=append_view(doc, values.tobytes()), componentType=component, type=kind,
                               count=count)
    refused(capsys, tmp_path, doc, f"meshes[0].primitives[0].indices: accessor 1 is {said}", "UNSIGNED_INT SCALAR")


@pytest.mark.parametrize("kind, component, said", [("VEC3", 5126, "a VEC3 of FLOAT (5126)"),
                                                    ("SCALAR", 5123, "a SCALAR of UNSIGNED_SHORT (5123)")])
def test_keyframe_times_that_are_not_a_float_scalar_are_refused(capsys, tmp_path, mesh, kind, component, said):
    """glTF 2.0 5.2.3: an animation sampler's ``input`` is a FLOAT SCALAR accessor; another was copied into
    the ``.pmw`` as it was (an invalid output)."""
    doc = gltf_doc(mesh)
    _animated(doc)
    doc["accessors"][2].update(type=kind, componentType=component, min=None, max=None)
    for key in ("min", "max"):
        del doc["accessors"][2][key]
    refused(capsys, tmp_path, doc, f"animations[0].samplers[0].input: accessor 2 is {said}", "FLOAT SCALAR")


# --- 06: every index reference the writer keeps is in range ----------------------------------------------


def _animated(doc, **channel):
    doc["accessors"].append({"bufferView": 0, "componentType": 5126, "count": 2, "type": "SCALAR",
                             "min": [0.0], "max": [1.0]})
    doc["animations"] = [{"channels": [{"sampler": 0, "target": {"node": 0, "path": "translation"}, **channel}],
                          "samplers": [{"input": 2, "output": 0}]}]


def _lit(doc, light):
    """A document light, and node 0 naming light ``light`` (KHR_lights_punctual)."""
    doc.setdefault("extensionsUsed", []).append("KHR_lights_punctual")
    doc["extensions"] = {"KHR_lights_punctual": {"lights": [{"type": "point"}]}}
    doc["nodes"][0]["extensions"] = {"KHR_lights_punctual": {"light": light}}


_MAPPING = "meshes[0].primitives[0].extensions.KHR_materials_variants.mappings[0]"


def _variants(doc, mapping):
    """Two document variants, and primitive 0 mapping ``mapping`` (KHR_materials_variants)."""
    doc.setdefault("extensionsUsed", []).append("KHR_materials_variants")
    doc["extensions"] = {"KHR_materials_variants": {"variants": [{"name": "a"}, {"name": "b"}]}}
    doc["meshes"][0]["primitives"][0]["extensions"] = {"KHR_materials_variants": {"mappings": [mapping]}}


#: An edit of :func:`gltf_doc`'s document (textured) -> what the one line says: ``(path, value)`` of a
#: reference out of range (``path = value names a ... that does not exist``), or the path of a member
#: of the wrong type.
REFERENCES = {
    "scene": (lambda d: d.update(scene=3), ("scene", 3, "scene")),
    "scene root past the end": (lambda d: d.update(scenes=[{"nodes": [0, 7]}]), ("scenes[0].nodes[1]", 7, "node")),
    "scene root negative": (lambda d: d.update(scenes=[{"nodes": [-1]}]), "scenes[0].nodes[0]"),
    "scene root a string": (lambda d: d.update(scenes=[{"nodes": ["0"]}]), "scenes[0].nodes[0]"),
    "scene nodes an object": (lambda d: d.update(scenes=[{"nodes": {"0": 0}}]), "scenes[0].nodes"),
    "primitive material": (lambda d: d["meshes"][0]["primitives"][0].update(material=9),
                           ("meshes[0].primitives[0].material", 9, "material")),
    "node skin": (lambda d: d["nodes"][0].update(skin=2), ("nodes[0].skin", 2, "skin")),
    "node camera": (lambda d: d["nodes"][0].update(camera=1), ("nodes[0].camera", 1, "camera")),
    "skin joint": (lambda d: d.update(skins=[{"joints": [0, 4]}]), ("skins[0].joints[1]", 4, "node")),
    "skin skeleton": (lambda d: d.update(skins=[{"joints": [0], "skeleton": 3}]), ("skins[0].skeleton", 3, "node")),
    "texture source": (lambda d: d["textures"][0].update(source=9), ("textures[0].source", 9, "image")),
    "texture sampler": (lambda d: d["textures"][0].update(sampler=1), ("textures[0].sampler", 1, "sampler")),
    "texture extension source": (lambda d: d["textures"][0].update(extensions={"EXT_texture_webp": {"source": 4}}),
                                 ("textures[0].extensions.EXT_texture_webp.source", 4, "image")),
    "baseColorTexture": (lambda d: d["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"].update(index=9),
                         ("materials[0].pbrMetallicRoughness.baseColorTexture.index", 9, "texture")),
    "normalTexture": (lambda d: d["materials"][0].update(normalTexture={"index": 2}),
                      ("materials[0].normalTexture.index", 2, "texture")),
    "emissiveTexture a string": (lambda d: d["materials"][0].update(emissiveTexture={"index": "0"}),
                                 "materials[0].emissiveTexture.index"),
    "occlusionTexture not an object": (lambda d: d["materials"][0].update(occlusionTexture=0),
                                       "materials[0].occlusionTexture"),
    "texture in a material extension": (
        lambda d: d["materials"][0].update(extensions={"KHR_materials_clearcoat": {"clearcoatTexture": {"index": 5}}}),
        ("materials[0].extensions.KHR_materials_clearcoat.clearcoatTexture.index", 5, "texture")),
    "animation target node": (lambda d: _animated(d, target={"node": 5, "path": "translation"}),
                              ("animations[0].channels[0].target.node", 5, "node")),
    "animation channel sampler": (lambda d: _animated(d, sampler=3), ("animations[0].channels[0].sampler", 3, "sampler")),
    "animation channel without a target": (lambda d: _animated(d, target=None), "animations[0].channels[0].target"),
    "punctual light": (lambda d: _lit(d, 3), ("nodes[0].extensions.KHR_lights_punctual.light", 3, "light")),
    "punctual light a string": (lambda d: _lit(d, "0"), "nodes[0].extensions.KHR_lights_punctual.light"),
    "variant mapping material": (lambda d: _variants(d, {"material": 9, "variants": [0]}),
                                 (_MAPPING + ".material", 9, "material")),
    "variant mapping variant": (lambda d: _variants(d, {"material": 0, "variants": [0, 4]}),
                                (_MAPPING + ".variants[1]", 4, "variant")),
}


@pytest.mark.parametrize("case", sorted(REFERENCES))
def test_a_reference_out_of_range_or_of_the_wrong_type_is_refused_by_its_path(capsys, tmp_path, mesh, case):
    edit, said = REFERENCES[case]
    doc = gltf_doc(mesh, images=[PNG_URI])
    edit(doc)
    if isinstance(said, tuple):
        path, value, kind = said
        said = f"{path} = {value} names a{'n' if kind[0] in 'aeiou' else ''} {kind} that does not exist"
    refused(capsys, tmp_path, doc, said)


def _with_normals(doc, mesh, width):
    """``doc`` with a NORMAL attribute of ``width`` components (VEC3 is glTF's)."""
    normals = np.zeros((mesh.vertex_count, width), "<f4")
    view = append_view(doc, normals.tobytes())
    doc["accessors"].append({"bufferView": view, "componentType": 5126, "count": mesh.vertex_count,
                             "type": {2: "VEC2", 3: "VEC3", 4: "VEC4"}[width]})
    doc["meshes"][0]["primitives"][0]["attributes"]["NORMAL"] = len(doc["accessors"]) - 1


#: Members of the wrong shape that the Khronos validator rejects and the encoder used to copy into the ``.pmw``
#: (outside probe 2, F7): ``(edit, words of the one-line refusal)``.
SHAPES = {
    "a matrix of 15 numbers": (lambda d, m: d["nodes"][0].update(matrix=[1.0] * 15), "nodes[0].matrix must be 16 numbers"),
    "a matrix beside a translation": (lambda d, m: d["nodes"][0].update(matrix=np.eye(4).ravel().tolist(),
                                                                     translation=[1.0, 2.0, 3.0]),
                                      "nodes[0] has a matrix and translation"),
    "a rotation of 3 numbers": (lambda d, m: d["nodes"][0].update(rotation=[0.0, 0.0, 1.0]),
                                "nodes[0].rotation must be 4 numbers"),
    "a scale that is a string": (lambda d, m: d["nodes"][0].update(scale="big"), "nodes[0].scale must be 3 numbers"),
    "a translation holding a string": (lambda d, m: d["nodes"][0].update(translation=[0.0, "1", 0.0]),
                                       "nodes[0].translation must be 3 numbers"),
    "a VEC2 NORMAL": (lambda d, m: _with_normals(d, m, 2), "attributes.NORMAL", "NORMAL is VEC3"),
    "a mesh without primitives": (lambda d, m: d["meshes"].append({"primitives": []}), "meshes[1] has no primitives"),
    "weights for morph targets it has not": (lambda d, m: d["meshes"][0].update(weights=[0.5, 0.5]),
                                             "meshes[0].weights"),
    "indices in a vertex bufferView": (lambda d, m: d["bufferViews"][1].update(target=34962),
                                       "bufferViews[1].target is 34962, but it holds indices"),
    "positions in an index bufferView": (lambda d, m: d["bufferViews"][0].update(target=34963),
                                         "bufferViews[0].target is 34963, but it holds vertex data"),
    # assimp's glTF2/wrongTypes/badString.gltf: its copy in the .pmw failed three.js' GLTFLoader (name.replace)
    "a scene name that is a number": (lambda d, m: d["scenes"][0].update(name=42), "scenes[0].name must be a string"),
    "a node name that is an object": (lambda d, m: d["nodes"][0].update(name={"a": 1}),
                                      "nodes[0].name must be a string"),
    "a material name that is null": (lambda d, m: d["materials"][0].update(name=None),
                                     "materials[0].name must be a string"),
    # material values a .pmw would carry as they are, into a file the glTF validator refuses
    "a base colour that is a word": (lambda d, m: d["materials"][0].update(pbrMetallicRoughness={"baseColorFactor": "red"}),
                                     "materials[0].pbrMetallicRoughness.baseColorFactor must be 4 numbers"),
    "a roughness that is a list": (lambda d, m: d["materials"][0].update(pbrMetallicRoughness={"roughnessFactor": [1]}),
                                   "materials[0].pbrMetallicRoughness.roughnessFactor must be a number"),
    "an alpha mode glTF does not name": (lambda d, m: d["materials"][0].update(alphaMode="SHINY"),
                                         "materials[0].alphaMode must be OPAQUE, MASK or BLEND"),
    "double-sided as a string": (lambda d, m: d["materials"][0].update(doubleSided="yes"),
                                 "materials[0].doubleSided must be true or false"),
    # a list or an object where glTF names an enum value ended in "unexpected TypeError: unhashable type"
    "a componentType that is a list": (lambda d, m: d["accessors"][0].update(componentType=[5126]),
                                       "accessors[0] has an unknown componentType or type"),
    "a componentType that is an object": (lambda d, m: d["accessors"][1].update(componentType={"x": 5125}),
                                          "accessors[1] has an unknown componentType or type"),
    "a type that is a list": (lambda d, m: d["accessors"][0].update(type=["VEC3"]),
                              "accessors[0] has an unknown componentType or type"),
    "a sparse index componentType that is a list": (lambda d, m: d["accessors"][0].update(sparse={
        "count": 1, "indices": {"bufferView": 1, "componentType": [5125]}, "values": {"bufferView": 0}}),
        "accessor 0 sparse indices: componentType is not an index type"),
}


@pytest.mark.parametrize("case", sorted(SHAPES))
def test_members_of_the_wrong_shape_are_refused_by_their_path(capsys, tmp_path, mesh, case):
    edit, *said = SHAPES[case]
    doc = gltf_doc(mesh)
    edit(doc, mesh)
    refused(capsys, tmp_path, doc, *said)


def test_valid_transforms_normals_and_targets_still_encode(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh)
    doc["nodes"] = [{"mesh": 0, "translation": [1, 2, 3], "rotation": [0, 0, 0, 1], "scale": [2, 2, 2]}]
    doc["bufferViews"][0]["target"], doc["bufferViews"][1]["target"] = 34962, 34963
    _with_normals(doc, mesh, 3)
    assert encoded(capsys, tmp_path, doc)["nodes"] == doc["nodes"]


@pytest.mark.parametrize("roots, said", [([0, 0], "scenes[0].nodes[1] names nodes[0] again"),
                                         ([0, 1], "scenes[0].nodes[1] names nodes[1], a child of nodes[0]")])
def test_a_scene_naming_a_root_twice_or_a_child_as_a_root_is_refused(capsys, tmp_path, mesh, roots, said):
    """glTF 2.0 3.5.2: a scene's roots are distinct roots; either way the mesh would be shown twice by some
    readers and once by others."""
    doc = gltf_doc(mesh, images=[PNG_URI])
    doc["nodes"][0]["children"] = [len(doc["nodes"])]
    doc["nodes"].append({"name": "child"})
    doc["scenes"] = [{"nodes": roots}]
    refused(capsys, tmp_path, doc, said)


def test_a_valid_asset_with_materials_textures_skins_and_animations_keeps_its_references(capsys, tmp_path, mesh):
    """Every reference kept as it was: an animation's output sharing the POSITION accessor of a progressive
    primitive (valid, if odd) keeps that accessor (it came out ``null`` when the primitive's was dropped)."""
    doc = gltf_doc(mesh, images=[PNG_URI, PNG_URI])
    doc["textures"] = [{"source": 0, "sampler": 0}, {"source": 1}]
    doc["samplers"] = [{"magFilter": 9729}]
    doc["materials"][0].update(normalTexture={"index": 1}, extensions={
        "KHR_materials_clearcoat": {"clearcoatFactor": 1.0, "clearcoatTexture": {"index": 1}}})
    doc["nodes"] = [{"mesh": 0, "children": [1]}, {"name": "child", "camera": 0}]
    doc["cameras"] = [{"type": "perspective", "perspective": {"yfov": 0.8, "znear": 0.01}}]
    doc["skins"] = [{"joints": [1], "skeleton": 1}]
    times = np.linspace(0, 1, mesh.vertex_count).astype("<f4")
    doc["accessors"].append({"bufferView": append_view(doc, times.tobytes()), "componentType": 5126,
                             "count": mesh.vertex_count, "type": "SCALAR", "min": [0.0], "max": [1.0]})
    doc["animations"] = [{"channels": [{"sampler": 0, "target": {"node": 1, "path": "translation"}}],
                          "samplers": [{"input": 2, "output": 0}]}]
    doc["extensionsUsed"] = ["KHR_materials_clearcoat"]
    before = json.loads(json.dumps(doc))
    gltf = encoded(capsys, tmp_path, doc)
    for key in ("materials", "textures", "samplers", "nodes", "scenes", "scene", "cameras", "skins"):
        assert gltf[key] == before[key], key
    sampler = gltf["animations"][0]["samplers"][0]
    assert isinstance(sampler["input"], int) and isinstance(sampler["output"], int)
    output, times_out = gltf["accessors"][sampler["output"]], gltf["accessors"][sampler["input"]]
    assert (output["type"], output["count"], times_out["count"]) == ("VEC3", mesh.vertex_count, mesh.vertex_count)
    assert gltf["animations"][0]["channels"] == before["animations"][0]["channels"]
    glb, _, _ = decode_asset(tmp_path / "out.pmw")
    decoded, _ = split_glb(glb, "decoded")
    sampler = decoded["animations"][0]["samplers"][0]
    assert decoded["accessors"][sampler["output"]]["type"] == "VEC3"
    assert decoded["accessors"][sampler["input"]]["count"] == mesh.vertex_count
    assert decoded["materials"] == before["materials"] and decoded["textures"] == before["textures"]


def test_a_prefix_without_its_ktx2_image_leaves_out_the_basisu_texture_that_uses_it(tmp_path, mesh):
    """A texture whose image is its KHR_texture_basisu ``source`` (no fallback) went out with that image
    when a cut file's data ended inside it: decode kept the texture, pointing at an image that is gone."""
    doc = basisu_doc(mesh, {"uri": "tex.ktx2"})
    (tmp_path / "asset").mkdir()
    (tmp_path / "asset" / "tex.ktx2").write_bytes(KTX2)
    pmwm_codec.encode(write_gltf(tmp_path / "asset", doc), tmp_path / "out.pmw", measure="none")
    data = (tmp_path / "out.pmw").read_bytes()
    gltf, _ = split_glb(data, "out.pmw")
    view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    bin_start = 12 + 8 + int.from_bytes(data[12:16], "little") + 8
    glb, end, decoder = decode_asset(data[: bin_start + view.get("byteOffset", 0) + view["byteLength"] // 2])
    decoded, _ = split_glb(glb, "decoded")
    assert end.truncated and "images" not in decoded and "textures" not in decoded
    assert decoded["materials"] == [{"pbrMetallicRoughness": {}}]
    assert decoder.notices == ["image 0 has not arrived yet: the level is written without it"]


# --- 07: required extensions are ones the reader supports, and are used -----------------------------------


def test_an_unsupported_required_extension_is_refused_by_name(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh, extensionsUsed=["EXT_bogus_thing"], extensionsRequired=["EXT_bogus_thing"])
    refused(capsys, tmp_path, doc, "EXT_bogus_thing", "requires")


def test_an_extension_required_but_not_used_is_refused(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh, extensionsRequired=["KHR_texture_transform"])
    refused(capsys, tmp_path, doc, "KHR_texture_transform", "extensionsUsed")


def test_an_unknown_extension_used_but_not_required_is_carried(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh, extensionsUsed=["EXT_bogus_thing"])
    doc["nodes"][0]["extensions"] = {"EXT_bogus_thing": {"any": [1, 2]}}
    gltf = encoded(capsys, tmp_path, doc)
    assert "EXT_bogus_thing" in gltf["extensionsUsed"] and "EXT_bogus_thing" not in gltf.get("extensionsRequired", [])
    assert gltf["nodes"][0]["extensions"] == {"EXT_bogus_thing": {"any": [1, 2]}}


def test_required_material_and_texture_extensions_are_carried_still_required(capsys, tmp_path, mesh):
    required = ["KHR_texture_transform", "KHR_materials_unlit"]
    doc = gltf_doc(mesh, images=[PNG_URI], extensionsUsed=list(required), extensionsRequired=list(required))
    doc["materials"][0]["extensions"] = {"KHR_materials_unlit": {}}
    doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["extensions"] = {
        "KHR_texture_transform": {"scale": [2.0, 2.0]}}
    gltf = encoded(capsys, tmp_path, doc)
    assert set(required) <= set(gltf["extensionsRequired"]) <= set(gltf["extensionsUsed"])
    assert gltf["materials"] == doc["materials"]


def test_valid_lights_and_material_variants_are_carried(capsys, tmp_path, mesh):
    """The carried extensions whose indices are now checked still pass through when they are right."""
    doc = gltf_doc(mesh, images=[PNG_URI])
    _lit(doc, 0)
    lights = doc["extensions"]
    _variants(doc, {"material": 0, "variants": [1]})
    doc["extensions"].update(lights)
    out = encoded(capsys, tmp_path, doc)
    assert out["nodes"][0]["extensions"]["KHR_lights_punctual"] == {"light": 0}
    mapping = out["meshes"][0]["primitives"][0]["extensions"]["KHR_materials_variants"]["mappings"][0]
    assert mapping == {"material": 0, "variants": [1]}
    assert len(out["extensions"]["KHR_lights_punctual"]["lights"]) == 1


def _floats_for_integers(value, shape):
    """``value`` with every member the glTF schema types integer written as a float (``3`` -> ``3.0``)."""
    if shape is None:
        return value
    if shape["integer"] and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, dict):
        return {k: _floats_for_integers(v, shape["properties"].get(k, shape["additional"])) for k, v in value.items()}
    if isinstance(value, list) and shape["items"] is not None:
        return [_floats_for_integers(v, shape["items"]) for v in value]
    return value


def test_integers_written_as_integral_floats_encode_as_the_integers_and_come_out_as_ints(capsys, tmp_path, mesh):
    """JSON does not tell ``3`` from ``3.0`` (spec README, *JSON numbers*): a document whose every integer
    member is an integral float (as some writers emit) encodes exactly as the integer document, and the
    ``.pmw`` holds ints (the Khronos validator refuses ``3.0`` where glTF wants an integer).  A fractional
    value is still refused by name."""
    from pmwm_codec.format.gltf import _gltf_integers

    doc = gltf_doc(mesh, images=[PNG_URI])
    doc["samplers"] = [{"magFilter": 9729, "wrapS": 33648}]
    doc["textures"][0]["sampler"] = 0
    floated = _floats_for_integers(json.loads(json.dumps(doc)), _gltf_integers())
    assert floated["accessors"][0]["count"] == float(mesh.vertex_count) and isinstance(floated["scene"], float)
    plain = encoded(capsys, tmp_path / "a", doc)
    gltf = encoded(capsys, tmp_path / "b", floated)
    assert json.dumps(gltf, sort_keys=True) == json.dumps(plain, sort_keys=True)  # ints, not "3.0"
    assert (tmp_path / "a" / "out.pmw").read_bytes() == (tmp_path / "b" / "out.pmw").read_bytes()
    floated["accessors"][0]["count"] = mesh.vertex_count + 0.5
    refused(capsys, tmp_path / "c", floated, "accessors[0]", "count")


@pytest.mark.parametrize("asset", [{"version": "1.0"}, {"version": 1}, None])
def test_a_gltf_1_document_is_named_as_one(capsys, tmp_path, mesh, asset):
    """glTF 1.0 files (assimp's test models, collada2gltf's output: collections keyed by id, the version a string,
    a number, or no ``asset`` at all) were refused as "accessors must be an array, got dict", which names a
    symptom: the line now says the file is glTF 1.0 and how to upgrade it."""
    doc = gltf_doc(mesh)
    doc["accessors"] = {f"accessor_{i}": acc for i, acc in enumerate(doc["accessors"])}
    if asset is None:
        del doc["asset"]
    else:
        doc["asset"] = asset
    refused(capsys, tmp_path, doc, "a glTF 1.0 document", "reads glTF 2.0", "gltf-pipeline")


def test_a_gltf_2_document_with_an_object_for_an_array_is_still_named_by_member(capsys, tmp_path, mesh):
    """A 2.0 document (its ``asset.version`` says so) whose ``accessors`` is an object is malformed, not 1.0."""
    doc = gltf_doc(mesh)
    doc["accessors"] = {"a": doc["accessors"][0]}
    refused(capsys, tmp_path, doc, "accessors must be an array")


@pytest.mark.parametrize("version, words", [(1, ("a GLB version 1 (glTF 1.0) file", "gltf-pipeline")),
                                            (3, ("GLB version 3, not glTF 2.0's 2",))])
def test_a_glb_of_another_container_version_is_named_not_called_cut_short(capsys, tmp_path, mesh, version, words):
    """A glTF 1.0 binary (KHR_binary_glTF: version 1, its second word the length, then a content length and
    format) was read as a 2.0 GLB and refused as "GLB is cut short (17721 of 17754 bytes)"; any other
    version is named as such."""
    from pmwm_codec.format.glb import join_glb

    src = tmp_path / "m.glb"
    src.write_bytes(join_glb({"asset": {"version": "1.0"}}, b"", version=version))
    assert_refused(*run_encode(capsys, tmp_path, src), "m.glb", *words)
    with pytest.raises(InputFormatError, match="m.glb: .*GLB version"):
        pmwm_codec.encode(src, tmp_path / "api.pmw", measure="none")


def _blob_of(doc: dict) -> bytes:
    return base64.b64decode(doc["buffers"][0]["uri"].partition(",")[2])


def _as_source(tmp_path, doc: dict, kind: str, data: bytes, declared: int):
    """``doc``'s buffer 0 holding ``data`` and declaring ``declared`` bytes, written as ``kind``: a data URI, a
    ``.bin`` beside the ``.gltf``, or a GLB's BIN chunk (zero padded to 4 bytes).  The file's path."""
    from pmwm_codec.format.glb import join_glb

    folder = tmp_path / "asset"
    folder.mkdir(parents=True, exist_ok=True)
    doc["buffers"][0] = {"byteLength": declared}
    if kind == "glb":
        src = folder / "m.glb"
        src.write_bytes(join_glb(doc, data))
        return src
    if kind == "bin":
        (folder / "m.bin").write_bytes(data)
        doc["buffers"][0]["uri"] = "m.bin"
    else:
        doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(data).decode()
    return write_gltf(folder, doc)


@pytest.mark.parametrize("kind", ["data", "bin", "glb"])
def test_a_buffer_declaring_more_bytes_than_it_holds_is_refused(capsys, tmp_path, mesh, kind):
    """A buffer whose ``byteLength`` says more than its data URI, ``.bin`` or BIN chunk holds (the validator's
    BUFFER_*_BYTELENGTH_MISMATCH) was read without a word: cut short, or the wrong length declared."""
    doc = gltf_doc(mesh)
    blob = _blob_of(doc)
    src = _as_source(tmp_path, doc, kind, blob, len(blob) + 64)
    assert_refused(*run_encode(capsys, tmp_path, src), src.name, "buffers[0] declares byteLength",
                   f"{len(blob):,} bytes")
    with pytest.raises(InputFormatError, match="buffers\\[0\\] declares byteLength"):
        pmwm_codec.read_mesh(src)


@pytest.mark.parametrize("kind", ["data", "bin", "glb"])
def test_a_buffer_view_past_the_declared_byte_length_is_refused(capsys, tmp_path, mesh, kind):
    """A bufferView that ends past its buffer's declared ``byteLength`` (BUFFER_VIEW_TOO_LONG) read bytes the
    document says do not exist (a declared length 16 short of the data was read to its end, exit 0)."""
    doc = gltf_doc(mesh)
    blob = _blob_of(doc)
    src = _as_source(tmp_path, doc, kind, blob, len(blob) - 16)
    assert_refused(*run_encode(capsys, tmp_path, src), src.name, "bufferViews[1] ends at byte",
                   f"past the byteLength {len(blob) - 16:,} buffers[0] declares")
    with pytest.raises(InputFormatError, match="bufferViews\\[1\\] ends at byte"):
        pmwm_codec.read_mesh(src)


@pytest.mark.parametrize("kind", ["bin", "glb"])
def test_a_buffer_holding_more_than_it_declares_still_reads(tmp_path, mesh, kind):
    """A ``.bin`` that runs on past its declared ``byteLength`` and a GLB whose BIN chunk pads it to 4 bytes are
    valid glTF: the views, inside the declared length, read the mesh as stored."""
    doc = gltf_doc(mesh)
    blob = _blob_of(doc)
    data, declared = (blob + bytes(6), len(blob)) if kind == "bin" else (blob + bytes(2), len(blob) + 2)
    src = _as_source(tmp_path, doc, kind, data, declared)
    if kind == "glb":
        assert len(split_glb(src.read_bytes())[1]) == declared + 2  # padded past the declared length
    assert pmwm_codec.read_mesh(src) == pmwm_codec.read_mesh(write_gltf(tmp_path / "plain", gltf_doc(mesh)))


# --- the geometry reader (read_mesh, encode --geometry-only) reads what the scene draws -------------------


def test_normalized_quantized_positions_are_read_as_their_values_by_the_geometry_reader(capsys, tmp_path, mesh):
    """KHR_mesh_quantization positions (``normalized: true`` UNSIGNED_SHORT) were read as the raw integers
    0..65535 by read_mesh and ``encode --geometry-only``: a mesh 65535 times its size, exit 0."""
    doc = quantized_doc(mesh, True)
    src = write_gltf(tmp_path / "asset", doc)
    q = np.round((mesh.positions - mesh.positions.min(0)) * 50)
    got = pmwm_codec.read_mesh(src)
    np.testing.assert_array_equal(got.positions, q / 65535.0)
    np.testing.assert_array_equal(got.faces, mesh.faces)
    status, err, out = run_encode(capsys, tmp_path, src, "--geometry-only")
    assert status == 0, err
    assert pmwm_codec.decode(out).positions.max() <= 1.0


def test_a_triangle_fan_is_read_as_the_triangles_it_draws_by_the_geometry_reader(tmp_path):
    """A TRIANGLE_FAN primitive was "the file holds no triangle mesh" for read_mesh and --geometry-only (the
    asset encoder read it); a strip reads as the spec's formula winds it, its restarts dropped."""
    from test_gltf_strips import FAN, STRIP, doc_of, dome_fan, oriented, spec_triangles, terrain_strips

    for mode, shape in ((FAN, dome_fan), (STRIP, terrain_strips)):
        positions, order = shape()
        got = pmwm_codec.read_mesh(write_gltf(tmp_path / str(mode), doc_of(positions, order, mode)))
        np.testing.assert_array_equal(got.positions, positions.astype(np.float32))
        assert oriented(got.faces) == oriented(spec_triangles(order.tolist(), mode)) and got.cleanup == {}


def test_an_index_count_not_a_multiple_of_3_or_out_of_range_is_named_alike_by_every_reader(capsys, tmp_path, mesh):
    """read_mesh and --geometry-only said it in numpy's words ("cannot read as GLB: cannot reshape array of size 5
    into shape (3)"), the asset encoder "index count 5 is not a multiple of 3": one message now; a primitive without
    indices is named by its vertex count (it was "index count 41"), an index past the vertices alike too."""
    doc = gltf_doc(mesh)
    doc["accessors"][1]["count"] = 5
    unindexed = gltf_doc(mesh)
    del unindexed["meshes"][0]["primitives"][0]["indices"]
    unindexed["accessors"][0]["count"] = 41
    out_of_range = gltf_doc(mesh)
    out_of_range["accessors"][0]["count"] = 10
    for edited, said in ((doc, "index count 5 is not a multiple of 3"),
                         (unindexed, "vertex count 41 (no indices: every three vertices a triangle) is not a multiple of 3"),
                         (out_of_range, f"face index {mesh.faces.max()} out of range for 10 vertices (counted from 0)")):
        src = write_gltf(tmp_path / "asset", edited)
        said = "m.gltf: mesh 0 primitive 0: " + said
        with pytest.raises(pmwm_codec.PmwError) as exc:
            pmwm_codec.read_mesh(src)
        assert str(exc.value) == said
        for options in ((), ("--geometry-only",)):
            status, err, out = run_encode(capsys, tmp_path, src, *options)
            assert_refused(status, err, out)
            assert err[0] == "pmw: error: " + said


@pytest.mark.parametrize("edit", ["no nodes", "no scenes"])
def test_a_document_without_nodes_or_scenes_reads_as_the_encoder_reads_it(tmp_path, mesh, edit):
    """Meshes without nodes (each shown once, as stored) and nodes without a scene (every root node shown), as
    the asset encoder and decode read them: read_mesh said "the file holds no triangle mesh"."""
    doc = gltf_doc(mesh)
    del doc["scenes"], doc["scene"]
    if edit == "no nodes":
        del doc["nodes"]
    else:
        doc["nodes"][0]["translation"] = [5.0, 0.0, 0.0]
    got = pmwm_codec.read_mesh(write_gltf(tmp_path / "asset", doc))
    shift = [0.0, 0.0, 0.0] if edit == "no nodes" else [5.0, 0.0, 0.0]
    np.testing.assert_array_equal(got.positions, mesh.positions.astype(np.float32).astype(np.float64) + shift)


@pytest.mark.parametrize("edit", ["empty scene", "no node shows it"])
def test_a_scene_that_shows_no_mesh_is_named_so(tmp_path, mesh, edit):
    doc = gltf_doc(mesh)
    if edit == "empty scene":
        doc["scenes"][0]["nodes"] = []
    else:
        del doc["nodes"][0]["mesh"]
    with pytest.raises(pmwm_codec.PmwError, match=r"^m.gltf: the file holds no triangle mesh \(no node of its "
                                                   r"scene shows a mesh\)$"):
        pmwm_codec.read_mesh(write_gltf(tmp_path / "asset", doc))


def test_points_and_lines_beside_triangles_are_left_out_with_a_note(capsys, tmp_path, mesh):
    """A LINES primitive beside the triangles went without a word through --geometry-only."""
    doc = gltf_doc(mesh)
    prim = doc["meshes"][0]["primitives"][0]
    doc["meshes"][0]["primitives"].append({"attributes": {"POSITION": 0}, "indices": 1, "mode": 1})
    src = write_gltf(tmp_path / "asset", doc)
    got = pmwm_codec.read_mesh(src)
    assert got.face_count == mesh.face_count and got.cleanup == {"primitives_of_points_or_lines": 1}
    out = tmp_path / "out.pmw"
    assert pmwm_codec.cli.main(["encode", str(src), "-o", str(out), "--geometry-only", "-q", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert "dropped 1 primitives of points or lines" in report["notices"], report["notices"]
    del prim["indices"]  # only lines and points: named
    doc["meshes"][0]["primitives"][0]["mode"] = 0
    with pytest.raises(pmwm_codec.PmwError, match=r"no triangle mesh \(its scene shows points and lines alone\)"):
        pmwm_codec.read_mesh(write_gltf(tmp_path / "only", doc))


def test_a_mesh_drawn_by_gpu_instancing_is_read_once_as_stored_with_a_note(capsys, tmp_path, mesh):
    """EXT_mesh_gpu_instancing draws the mesh once per instance, which the geometry reader does not place: it was
    read once at its node without a word; it is read as decode writes such a scene to OBJ (each mesh once, as
    stored), and the encoder says so.  The asset encoder keeps the instances."""
    doc = gltf_doc(mesh, extensionsUsed=["EXT_mesh_gpu_instancing"])
    view = append_view(doc, np.array([[0, 0, 0], [3, 0, 0]], "<f4").tobytes())
    doc["accessors"].append({"bufferView": view, "componentType": 5126, "count": 2, "type": "VEC3"})
    doc["nodes"][0].update(translation=[0.0, 5.0, 0.0],
                           extensions={"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": 2}}})
    src = write_gltf(tmp_path / "asset", doc)
    got = pmwm_codec.read_mesh(src)
    np.testing.assert_array_equal(got.positions, mesh.positions.astype(np.float32))
    assert got.cleanup == {"gpu_instanced_meshes": 1}
    out = tmp_path / "out.pmw"
    assert pmwm_codec.cli.main(["encode", str(src), "-o", str(out), "--geometry-only", "-q", "--json"]) == 0
    assert "1 mesh(es) drawn by GPU instancing (EXT_mesh_gpu_instancing), whose instances the geometry reader does " \
           "not place: every mesh read once, as stored" in json.loads(capsys.readouterr().out)["notices"]
    status, err, out = run_encode(capsys, tmp_path, src)
    assert status == 0, err


def _morphed(mesh, mesh_weights, node_weights=None) -> dict:
    """``mesh`` with one morph target moving every vertex by half its position; the weights given."""
    doc = gltf_doc(mesh)
    view = append_view(doc, (mesh.positions * 0.5).astype("<f4").tobytes())
    doc["accessors"].append({"bufferView": view, "componentType": 5126, "count": mesh.vertex_count, "type": "VEC3",
                             "min": (mesh.positions * 0.5).min(0).tolist(), "max": (mesh.positions * 0.5).max(0).tolist()})
    doc["meshes"][0]["primitives"][0]["targets"] = [{"POSITION": 2}]
    doc["meshes"][0]["weights"] = mesh_weights
    if node_weights is not None:
        doc["nodes"] = [{"children": list(range(1, len(node_weights) + 1))}] + [{"mesh": 0, "weights": w}
                                                                              for w in node_weights]
    return doc


@pytest.mark.parametrize("mesh_weights, node_weights, scale", [([0.0], None, 1.0), ([1.0], None, 1.5),
                                                               ([0.0], [[0.5]], 1.25)])
def test_morph_targets_are_applied_by_their_rest_weights_by_the_geometry_reader(tmp_path, mesh, mesh_weights,
                                                                               node_weights, scale):
    """A mesh whose default weights morph it was read at its base positions: not the mesh a viewer draws, exit 0."""
    got = pmwm_codec.read_mesh(write_gltf(tmp_path / "asset", _morphed(mesh, mesh_weights, node_weights)))
    expected = mesh.positions.astype(np.float32).astype(np.float64)
    expected = expected + (scale - 1.0) / 0.5 * (mesh.positions * 0.5).astype(np.float32)
    np.testing.assert_allclose(got.positions, expected, rtol=0, atol=1e-12)


def test_a_mesh_its_nodes_morph_differently_is_refused_by_the_geometry_reader(tmp_path, mesh):
    with pytest.raises(pmwm_codec.PmwError, match=r"^m.gltf: mesh 0 is drawn with different morph weights by its nodes"):
        pmwm_codec.read_mesh(write_gltf(tmp_path / "asset", _morphed(mesh, [0.0], [[0.5], [1.0]])))
