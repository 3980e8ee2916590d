"""``pmw decode -o X.obj`` / ``X.ply`` of crafted ``.pmw`` files (their GLB JSON edited, a plain primitive's data
overwritten): bad input is one line and exit 2 with no file written, never a bug report or a wrong file; what the
files cannot hold is left out with a notice; and what is written reads back as what the decoded GLB held.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import meshdoc
from pmwm_codec.format.glb import join_glb, split_glb

from test_obj_appearance import _png, _torus_obj


def pmw(*args):
    return subprocess.run([sys.executable, "-m", "pmwm_codec", *map(str, args)], capture_output=True, text=True)


def _textured(folder) -> str:
    path, *_ = _torus_obj(str(folder))
    _png(folder / "skin.png")
    (folder / "t.mtl").write_text("newmtl skin\nKd 0.8 0.5 0.25\nmap_Kd skin.png\n")
    out = folder / "t.pmw"
    pmwm_codec.encode(path, str(out))
    return out


def _edited(src, dst, edit, patch=None):
    """``src`` with its GLB JSON passed through ``edit`` (in place) and ``patch`` ``{accessor: array}`` written
    over the BIN bytes of those (plain) accessors."""
    gltf, binary = split_glb(src.read_bytes())
    binary = bytearray(binary)
    for index, values in (patch or {}).items():
        acc = gltf["accessors"][index]
        start = gltf["bufferViews"][acc["bufferView"]].get("byteOffset", 0) + acc.get("byteOffset", 0)
        raw = np.ascontiguousarray(values).tobytes()
        binary[start:start + len(raw)] = raw
    edit(gltf)
    dst.write_bytes(join_glb(gltf, bytes(binary)))
    return dst


def _with_plain_strip(folder, attributes: dict) -> str:
    """The textured torus and a second mesh the scene shows, a plain (not progressive) quad TRIANGLE_STRIP with
    ``attributes`` ``{semantic: (float32 array (4, k), glTF type)}`` and no material."""
    path, *_ = _torus_obj(str(folder))
    _png(folder / "skin.png")
    (folder / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\n")
    (doc, buffers), _ = meshdoc.read_source(path)
    data = bytearray(buffers[0])
    positions = np.array([[0, 0, 3], [1, 0, 3], [0, 1, 3], [1, 1, 3]], np.float32)
    attrs = {}
    for semantic, (values, kind) in {"POSITION": (positions, "VEC3"), **attributes}.items():
        data += bytes(-len(data) % 4)
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(data), "byteLength": values.nbytes})
        data += values.tobytes()
        acc = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": 5126, "count": 4, "type": kind}
        if semantic == "POSITION":
            acc.update(min=positions.min(0).tolist(), max=positions.max(0).tolist())
        doc["accessors"].append(acc)
        attrs[semantic] = len(doc["accessors"]) - 1
    doc["buffers"][0]["byteLength"] = len(data)
    doc["meshes"].append({"name": "strip", "primitives": [{"attributes": attrs, "mode": 0}]})  # points: passed through
    doc["nodes"].append({"mesh": 1})
    doc["scenes"][0]["nodes"].append(1)
    out = folder / "s.pmw"
    pmwm_codec.encode((doc, [bytes(data)]), str(out))
    gltf, binary = split_glb(out.read_bytes())
    gltf["meshes"][1]["primitives"][0]["mode"] = 5  # drawn as a strip: triangles the stream does not carry
    out.write_bytes(join_glb(gltf, binary))
    return out


def _one_line_no_file(run, folder, kept, *words):
    assert run.returncode == 2, run.stdout + run.stderr
    assert run.stderr.count("\n") == 1 and "Traceback" not in run.stderr and "bug of pmw" not in run.stderr
    assert all(w in run.stderr for w in words), run.stderr
    assert sorted(os.listdir(folder)) == sorted(kept)


def _material(gltf):
    return gltf["materials"][0]


BAD_DOCUMENTS = {
    "material past the materials": (lambda g: g["meshes"][0]["primitives"][0].update(material=9),
                                    "meshes[0].primitives[0].material = 9 names a material that does not exist"),
    "material -1 (would pick the last)": (lambda g: g["meshes"][0]["primitives"][0].update(material=-1),
                                          "meshes[0].primitives[0].material must be a material index", "got -1"),
    "material true": (lambda g: g["meshes"][0]["primitives"][0].update(material=True),
                       "meshes[0].primitives[0].material must be a material index", "got True"),
    "texture past the textures": (lambda g: _material(g)["pbrMetallicRoughness"]["baseColorTexture"].update(index=7),
                                  "baseColorTexture.index = 7 names a texture that does not exist"),
    "image past the images": (lambda g: g["textures"][0].update(source=5),
                              "textures[0].source = 5 names an image that does not exist"),
    "base colour a string": (lambda g: _material(g)["pbrMetallicRoughness"].update(baseColorFactor="red"),
                             "baseColorFactor"),
    "base colour of two numbers": (lambda g: _material(g)["pbrMetallicRoughness"].update(baseColorFactor=[1, 1]),
                                   "baseColorFactor"),
    "roughness a string": (lambda g: _material(g)["pbrMetallicRoughness"].update(roughnessFactor="x"),
                           "roughnessFactor"),
    "metallic null": (lambda g: _material(g)["pbrMetallicRoughness"].update(metallicFactor=None), "metallicFactor"),
    "pbr a list": (lambda g: _material(g).update(pbrMetallicRoughness=[1]), "pbrMetallicRoughness"),
    "texture extensions a list": (lambda g: g["textures"][0].update(extensions=[1]), "extensions"),
    "materials an object": (lambda g: g.update(materials={"0": {}}), "materials"),
    "textures an object": (lambda g: g.update(textures={"0": {}}), "textures"),
    "images an object": (lambda g: g.update(images={"0": {}}), "images"),
    "image bufferView past the views": (lambda g: g["images"][0].update(bufferView=99),
                                        "images[0].bufferView = 99 names a bufferView that does not exist"),
    "image bufferView a string": (lambda g: g["images"][0].update(bufferView="0"),
                                      "images[0].bufferView must be a bufferView index", "got '0'"),
}


@pytest.mark.parametrize("case", sorted(BAD_DOCUMENTS))
@pytest.mark.parametrize("suffix", [".obj", ".ply", ".glb"])
def test_a_malformed_material_texture_or_image_reference_is_one_line_and_no_file(tmp_path, case, suffix):
    """(A ``.glb`` output carried such a document as it was: a file the glTF validator and three.js refuse, with
    exit 0; the document a ``.pmw`` carries is now checked as an input glTF is, whatever the output.)"""
    src = _textured(tmp_path)
    edit, *words = BAD_DOCUMENTS[case]
    bad = _edited(src, tmp_path / "bad.pmw", edit)
    kept = os.listdir(tmp_path)
    _one_line_no_file(pmw("decode", bad, "-o", tmp_path / f"o{suffix}"), tmp_path, kept, *words)


def test_an_image_the_file_names_by_uri_is_left_out_with_a_notice_and_never_read(tmp_path):
    src = _textured(tmp_path)
    bad = _edited(src, tmp_path / "uri.pmw", lambda g: g["images"].__setitem__(0, {"uri": "skin.png"}))
    run = pmw("decode", bad, "-o", tmp_path / "o.obj", "--json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["files"] == [str(tmp_path / "o.obj"), str(tmp_path / "o.mtl")]
    assert any("uri" in n and "left out" in n for n in report["notices"])
    assert "map_Kd" not in (tmp_path / "o.mtl").read_text()


def test_an_image_whose_mime_type_lies_is_written_under_the_suffix_of_its_bytes(tmp_path):
    src = _textured(tmp_path)
    bad = _edited(src, tmp_path / "lie.pmw", lambda g: g["images"][0].update(mimeType="image/jpeg"))
    run = pmw("decode", bad, "-o", tmp_path / "o.obj", "--json")
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["files"][-1] == str(tmp_path / "o_0.png")
    (back, _), notices = meshdoc.read_source(str(tmp_path / "o.obj"))
    assert notices == [] and back["images"][0]["mimeType"] == "image/png"


@pytest.mark.parametrize("name", ["#skin", "default"])
def test_a_material_named_like_a_comment_or_the_default_keeps_its_texture_when_read_back(tmp_path, name):
    src = _textured(tmp_path)
    bad = _edited(src, tmp_path / "n.pmw", lambda g: _material(g).update(name=name))
    run = pmw("decode", bad, "-o", tmp_path / "o.obj")
    assert run.returncode == 0, run.stderr
    (back, _), notices = meshdoc.read_source(str(tmp_path / "o.obj"))
    assert notices == [] and len(back["materials"]) == 1 and len(back["images"]) == 1
    assert "baseColorTexture" in back["materials"][0]["pbrMetallicRoughness"]


def test_a_mesh_without_a_material_after_one_with_does_not_take_its_material_in_the_obj(tmp_path):
    src = _with_plain_strip(tmp_path, {})
    run = pmw("decode", src, "-o", tmp_path / "o.obj")
    assert run.returncode == 0, run.stderr
    (back, buffers), _ = meshdoc.read_source(str(tmp_path / "o.obj"))
    prims = [p for m in back["meshes"] for p in m["primitives"]]
    textured = [p for p in prims if "baseColorTexture" in back["materials"][p["material"]].get("pbrMetallicRoughness", {})
                ] if "materials" in back else []
    faces = sum(back["accessors"][p["indices"]]["count"] // 3 for p in textured)
    assert faces == 576  # the torus's faces alone: the strip's two are not textured by the torus's skin


@pytest.mark.parametrize("semantic, kind, width", [("NORMAL", "VEC3", 3), ("TEXCOORD_0", "VEC2", 2),
                                                   ("COLOR_0", "VEC4", 4)])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
@pytest.mark.parametrize("suffix", [".obj", ".ply"])
def test_a_value_that_is_not_finite_in_a_carried_attribute_is_one_line_and_no_file(tmp_path, semantic, kind,
                                                                                    width, bad, suffix):
    good = np.full((4, width), 0.5, np.float32)
    src = _with_plain_strip(tmp_path, {semantic: (good, kind)})
    gltf, _ = split_glb(src.read_bytes())
    values = good.copy()
    values[1, 0] = bad
    crafted = _edited(src, tmp_path / "bad.pmw", lambda g: None,
                      {gltf["meshes"][1]["primitives"][0]["attributes"][semantic]: values})
    kept = os.listdir(tmp_path)
    run = pmw("decode", crafted, "-o", tmp_path / f"o{suffix}")
    _one_line_no_file(run, tmp_path, kept, semantic, "not finite")


@pytest.mark.parametrize("name", ["x#1.obj", " lead.obj", "tab\tx.obj", "v\x0btab.obj", "line\u2028sep.obj",
                                  "form\x0cfeed.ply", "nel\x85.obj"])
def test_an_output_name_the_records_naming_its_files_cannot_hold_is_one_line_and_no_file(tmp_path, name):
    src = _textured(tmp_path)
    kept = os.listdir(tmp_path)
    _one_line_no_file(pmw("decode", src, "-o", tmp_path / name), tmp_path, kept, "another name")


@pytest.mark.parametrize("name", ["a  b.obj", "m.mtl n.obj", "-s 1 1 1 x.obj", "back\\slash.obj"])
def test_an_obj_output_name_whose_records_read_back_as_another_name_is_one_line_and_no_file(tmp_path, name):
    """``mtllib`` / ``map_Kd`` records naming ``a  b.mtl`` / ``a  b_0.png`` were written, and read back (by ``pmw
    encode``) as ``a b_0.png`` (a run of spaces as one), ``m.mtl`` and ``n.mtl`` (two MTL files), ``x_0.png``
    (``-s 1 1 1`` a map option) or ``back/slash_0.png``: the OBJ lost its texture or materials with a notice."""
    src = _textured(tmp_path)
    kept = os.listdir(tmp_path)
    _one_line_no_file(pmw("decode", src, "-o", tmp_path / name), tmp_path, kept, "another name")


@pytest.mark.parametrize("name", ["my scan.obj", "x#1.ply"])
def test_an_output_name_its_format_records_as_it_is_reads_back_with_its_texture(tmp_path, name):
    """Single spaces in an OBJ's name, a ``#`` in a PLY's (a comment only in an OBJ or MTL)."""
    src = _textured(tmp_path)
    run = pmw("decode", src, "-o", tmp_path / name)
    assert run.returncode == 0, run.stderr
    (back, _), notices = meshdoc.read_source(str(tmp_path / name))
    assert notices == [] and len(back["images"]) == 1


def test_a_texture_beside_the_output_that_cannot_be_written_is_named_alone_not_as_the_inputs_fault(tmp_path):
    """A folder where ``o_0.png`` goes said ``pmw: error: t.pmw: o_0.png: is a directory ...``, blaming the input."""
    src = _textured(tmp_path)
    (tmp_path / "o_0.png").mkdir()
    kept = os.listdir(tmp_path)
    run = pmw("decode", src, "-o", tmp_path / "o.obj")
    _one_line_no_file(run, tmp_path, kept, "is a directory")
    assert run.stderr.startswith(f"pmw: error: {tmp_path / 'o_0.png'}: is a directory"), run.stderr
