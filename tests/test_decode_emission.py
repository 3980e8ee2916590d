"""A decoded asset's emissive material reaches the OBJ's MTL: ``Ke`` (glTF's linear ``emissiveFactor`` times
``KHR_materials_emissive_strength``, as ``Kd`` holds the base colour) and ``map_Ke`` (its ``emissiveTexture``,
the image byte for byte), which Blender and three.js read; they had been dropped (the texture with a note, the
factor without a word).  What an MTL cannot say (``doubleSided``) and what a PLY cannot hold (the emission) is
said in a note rather than lost without a word.
"""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes

from conftest import ROOT
from test_asset import DocBuilder
from test_obj_appearance import _png


def _emissive_asset(tmp_path, **material) -> tuple:
    """``(.pmw path, PNG bytes)``: a textured sphere whose one material is ``material`` (over a base colour), the
    PNG the image its textures may name (``{"index": 0}``)."""
    b = DocBuilder()
    png = _png(tmp_path / "glow.png", colour=(10, 220, 40))
    image_view = len(b.doc["bufferViews"])
    b.accessor(np.frombuffer(png, np.uint8), 5121, "SCALAR")  # (a bufferView holding the PNG)
    b.doc["accessors"].pop()
    prim = {**b.triangles(shapes.icosphere(3, 1.0)), "material": 0}
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [prim]}],
        "images": [{"bufferView": image_view, "mimeType": "image/png"}], "textures": [{"source": 0}],
        "materials": [{"name": "lamp", "pbrMetallicRoughness": {"baseColorFactor": [0.5, 0.5, 0.5, 1.0]},
                       **material}],
    })
    if "KHR_materials_emissive_strength" in str(material):
        b.doc["extensionsUsed"] = ["KHR_materials_emissive_strength"]
    (tmp_path / "in.glb").write_bytes(b.glb())
    pmwm_codec.encode(str(tmp_path / "in.glb"), str(tmp_path / "in.pmw"))
    return tmp_path / "in.pmw", png


def _mtl(path) -> dict:
    """``{keyword: [its words]}`` of the one material the MTL at ``path`` defines."""
    records = [line.split() for line in path.read_text().splitlines() if line and not line.startswith("#")]
    return {words[0]: words[1:] for words in records if words[0] != "newmtl"}


def test_an_emissive_material_s_factor_and_texture_are_the_mtl_s_ke_and_map_ke(tmp_path):
    src, png = _emissive_asset(tmp_path, emissiveFactor=[0.25, 0.5, 0.125], emissiveTexture={"index": 0},
                               extensions={"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}})
    result = pmwm_codec.decode_to(str(src), str(tmp_path / "out.obj"))
    mtl = _mtl(tmp_path / "out.mtl")
    assert [float(v) for v in mtl["Ke"]] == [1.0, 2.0, 0.5]  # linear, times the strength: as Kd is written
    assert [float(v) for v in mtl["Kd"]] == [0.5, 0.5, 0.5]
    (texture,) = mtl["map_Ke"]
    assert (tmp_path / texture).read_bytes() == png and texture in [p.split("/")[-1] for p in result["files"]]
    assert not any("emissive" in n for n in result["notices"]), result["notices"]


def test_a_material_that_emits_nothing_has_no_ke(tmp_path):
    src, _ = _emissive_asset(tmp_path)
    pmwm_codec.decode_to(str(src), str(tmp_path / "out.obj"))
    mtl = _mtl(tmp_path / "out.mtl")
    assert "Ke" not in mtl and "map_Ke" not in mtl


def test_a_double_sided_material_and_a_ply_s_lost_emission_are_said(tmp_path):
    src, _ = _emissive_asset(tmp_path, emissiveFactor=[0.25, 0.5, 0.125], doubleSided=True)
    obj = pmwm_codec.decode_to(str(src), str(tmp_path / "out.obj"))["notices"]
    assert sum("doubleSided" in n for n in obj) == 1, obj
    ply = pmwm_codec.decode_to(str(src), str(tmp_path / "out.ply"))["notices"]
    assert any("emission (emissiveFactor, emissiveTexture) is left out" in n for n in ply), ply
    (tmp_path / "single").mkdir()
    single, _ = _emissive_asset(tmp_path / "single")
    assert not any("doubleSided" in n for n in pmwm_codec.decode_to(str(single), str(tmp_path / "s.obj"))["notices"])


@pytest.mark.node
@pytest.mark.skipif(shutil.which("node") is None, reason="node is not on PATH")
@pytest.mark.skipif(not (ROOT / "tools" / "js" / "node_modules").is_dir(),
                    reason="tools/js/node_modules is absent: run `npm ci --prefix tools/js`")
def test_three_js_reads_the_emission_the_mtl_holds(tmp_path):
    src, _ = _emissive_asset(tmp_path, emissiveFactor=[0.25, 0.5, 0.125], emissiveTexture={"index": 0})
    pmwm_codec.decode_to(str(src), str(tmp_path / "out.obj"))
    proc = subprocess.run(["node", str(ROOT / "tools" / "js" / "check_obj.mjs"), str(tmp_path / "out.obj")],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    (material,) = json.loads(proc.stdout)["materials"].values()
    assert [float(v) for v in material["emissive"]] == [0.25, 0.5, 0.125]
    assert material["emissiveMap"] == _mtl(tmp_path / "out.mtl")["map_Ke"][0]


def _materials_of(pmw) -> list:
    """The glTF materials a ``.pmw`` at ``pmw`` carries (its decoded GLB's document)."""
    glb = pmwm_codec.decode_asset(str(pmw))
    (length,) = np.frombuffer(glb[12:16], np.uint32)
    return json.loads(glb[20:20 + int(length)])["materials"]


def test_the_emission_an_obj_decoded_with_comes_back_when_it_is_encoded_again(tmp_path):
    src, png = _emissive_asset(tmp_path, emissiveFactor=[0.25, 0.5, 0.125], emissiveTexture={"index": 0},
                               extensions={"KHR_materials_emissive_strength": {"emissiveStrength": 4.0}})
    pmwm_codec.decode_to(str(src), str(tmp_path / "out.obj"))
    pmwm_codec.encode(str(tmp_path / "out.obj"), str(tmp_path / "again.pmw"))
    (material,) = _materials_of(tmp_path / "again.pmw")
    strength = material["extensions"]["KHR_materials_emissive_strength"]["emissiveStrength"]
    assert strength * np.array(material["emissiveFactor"]) == pytest.approx([1.0, 2.0, 0.5])
    assert max(material["emissiveFactor"]) == 1.0  # glTF's factor stops at 1: the rest is the strength
    assert "emissiveTexture" in material


def test_an_mtl_s_ke_and_map_ke_are_the_material_s_emission(tmp_path):
    """Read as Blender reads them: ``Ke`` the emission, ``map_Ke`` its texture (an emission of 1 under a texture
    with no ``Ke``); ``Ke 0 0 0``, which Blender's exporter writes on every material, emits nothing."""
    _png(tmp_path / "glow.png", colour=(10, 220, 40))
    (tmp_path / "m.mtl").write_text("newmtl dark\nKd 0.5 0.5 0.5\nKe 0 0 0\n\nnewmtl lit\nKd 1 1 1\nKe 0.2 0.4 0.1\n"
                                    "\nnewmtl glow\nmap_Ke glow.png\n")
    (tmp_path / "m.obj").write_text("mtllib m.mtl\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\n"
                                    "usemtl dark\nf 1 2 3\nusemtl lit\nf 1 2 4\nusemtl glow\nf 2 3 5\n")
    pmwm_codec.encode(str(tmp_path / "m.obj"), str(tmp_path / "m.pmw"))
    by_name = {m["name"]: m for m in _materials_of(tmp_path / "m.pmw")}
    assert "emissiveFactor" not in by_name["dark"] and "emissiveTexture" not in by_name["dark"]
    assert by_name["lit"]["emissiveFactor"] == pytest.approx([0.2, 0.4, 0.1])
    assert by_name["glow"]["emissiveFactor"] == [1.0, 1.0, 1.0] and "emissiveTexture" in by_name["glow"]
