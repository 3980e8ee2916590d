"""``pmw decode -o X.obj`` / ``X.ply`` keeps an asset's appearance (pmwm_codec.meshexport): the OBJ holds the
decoded GLB's positions, texture coordinates and normals corner for corner, welded so that its seams are closed,
with an MTL and the textures byte for byte beside it; the PLY its colours and texture coordinates; the files
are written as a set, never over the input, and ``--geometry-only`` writes what it wrote before.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import meshdoc, ply, shapes
from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.meshio import write_mesh

from test_obj_appearance import _png, _torus_obj
from test_seams import unpartnered_edges


def pmw(*args):
    return subprocess.run([sys.executable, "-m", "pmwm_codec", *map(str, args)], capture_output=True, text=True)


def _textured(tmp_path, **options) -> tuple:
    """``(.pmw path, texture bytes, encode report)`` of a UV torus OBJ with an MTL naming a PNG texture."""
    path, *_ = _torus_obj(str(tmp_path), **options)
    png = _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nKd 0.8 0.5 0.25\nd 0.5\nNs 250\nmap_Kd skin.png\n")
    out = tmp_path / "t.pmw"
    report = pmwm_codec.encode(path, str(out))
    return out, png, report


def _corner_rows(gltf, buffers, semantics=("POSITION", "TEXCOORD_0")) -> np.ndarray:
    """(m, 3 * width) float32: each triangle's corners, the named attributes side by side, of every primitive;
    rows sorted (the order of faces is not part of the claim)."""
    rows = []
    for prim in gltf["meshes"][0]["primitives"]:
        faces = read_accessor(gltf, buffers, prim["indices"]).reshape(-1, 3)
        values = np.hstack([read_accessor(gltf, buffers, prim["attributes"][s]) for s in semantics]).astype(np.float32)
        rows.append(values[faces].reshape(len(faces), -1))
    rows = np.concatenate(rows)
    return rows[np.lexsort(rows.T[::-1])]


def _glb_document(pmw_path, tmp_path, chunks=None):
    glb = tmp_path / f"ref{'' if chunks is None else chunks}.glb"
    glb.write_bytes(pmwm_codec.decode_asset(str(pmw_path), chunks=chunks))
    return load_document(str(glb))


def test_an_obj_decoded_from_a_textured_asset_holds_its_corners_material_and_texture(tmp_path):
    src, png, _ = _textured(tmp_path)
    out = tmp_path / "out" / "back.obj"
    out.parent.mkdir()
    run = pmw("decode", src, "-o", out, "--json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["files"] == [str(out), str(out.parent / "back.mtl"), str(out.parent / "back_0.png")]
    gltf, buffers = _glb_document(src, tmp_path)
    (back, back_buffers), notices = meshdoc.read_source(str(out))
    assert notices == []
    want, got = _corner_rows(gltf, buffers), _corner_rows(back, back_buffers)
    assert got.shape == want.shape
    assert np.array_equal(got[:, [0, 1, 2, 5, 6, 7, 10, 11, 12]], want[:, [0, 1, 2, 5, 6, 7, 10, 11, 12]])  # exact
    assert np.abs(got - want).max() <= 2e-7  # texture coordinates: v flipped twice in float32
    assert (out.parent / "back_0.png").read_bytes() == png  # the texture byte for byte
    material = back["materials"][0]
    assert material["name"] == "skin" and material["alphaMode"] == "BLEND"
    assert material["pbrMetallicRoughness"]["baseColorFactor"] == pytest.approx([1.0, 1.0, 1.0, 0.5])
    assert material["pbrMetallicRoughness"]["roughnessFactor"] == pytest.approx(0.5, abs=1e-6)
    positions = read_accessor(gltf, buffers, gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"])
    assert report["vertices"] == len(np.unique(positions.astype(np.float32), axis=0))  # one v a position


def test_every_level_decoded_to_obj_is_welded_and_closed_along_its_seams(tmp_path):
    src, _, encoded = _textured(tmp_path)
    for level in (0, encoded["chunks"] // 2, None):
        out = tmp_path / f"l{level}.obj"
        run = pmw("decode", src, "-o", out, "--json", *(["--chunks", level] if level is not None else []))
        assert run.returncode == 0, run.stderr
        mesh = pmwm_codec.read_mesh(str(out))  # geometry alone: the welded v records
        assert json.loads(run.stdout)["vertices"] == mesh.vertex_count
        assert unpartnered_edges(mesh.positions, mesh.faces) == 0, level
        gltf, buffers = _glb_document(src, tmp_path, level)
        (back, back_buffers), _ = meshdoc.read_source(str(out))
        assert np.array_equal(_corner_rows(back, back_buffers, ("POSITION",)),
                              _corner_rows(gltf, buffers, ("POSITION",)))


def test_a_ply_decoded_from_a_coloured_textured_asset_holds_its_colours_and_texture(tmp_path):
    src, png, _ = _textured(tmp_path, colours=True)
    out = tmp_path / "back.ply"
    run = pmw("decode", src, "-o", out, "--json")
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["files"] == [str(out), str(tmp_path / "back_0.png")]
    assert (tmp_path / "back_0.png").read_bytes() == png
    gltf, buffers = _glb_document(src, tmp_path)
    prim = gltf["meshes"][0]["primitives"][0]
    got = ply.read_appearance(out.read_bytes(), "back.ply", 10 ** 7)
    assert got.textures == ["back_0.png"]
    assert np.array_equal(got.positions.astype(np.float32),
                          read_accessor(gltf, buffers, prim["attributes"]["POSITION"]).astype(np.float32))
    want_rgb = meshdoc.srgb_from_linear(read_accessor(gltf, buffers, prim["attributes"]["COLOR_0"]))[:, :3]
    assert np.abs(got.colours[:, :3] - want_rgb).max() <= 0.5 / 255 + 1e-9  # sRGB-encoded again, 8 bits a channel
    uv = read_accessor(gltf, buffers, prim["attributes"]["TEXCOORD_0"])
    assert np.abs(got.uv - np.stack([uv[:, 0], 1 - uv[:, 1]], 1)).max() <= 2e-7
    assert any("material colours" in n for n in json.loads(run.stdout)["notices"])  # Kd 0.8 0.5 0.25: no place


def test_a_scene_placed_by_a_mirroring_node_is_written_placed_with_its_normals_turned(tmp_path):
    path, *_ = _torus_obj(str(tmp_path), mtl=None, normals=True)
    (doc, buffers), _ = meshdoc.read_source(path)
    matrix = np.diag([-2.0, 1.0, 0.5, 1.0])
    matrix[:3, 3] = [3.0, -1.0, 0.25]
    doc["nodes"][0]["matrix"] = [float(v) for v in matrix.T.reshape(-1)]  # glTF: column-major
    src = tmp_path / "placed.pmw"
    pmwm_codec.encode((doc, buffers), str(src))
    out = tmp_path / "placed.obj"
    run = pmw("decode", src, "-o", out)
    assert run.returncode == 0, run.stderr
    gltf, stored = _glb_document(src, tmp_path)
    (back, back_buffers), _ = meshdoc.read_source(str(out))
    prim, got_prim = gltf["meshes"][0]["primitives"][0], back["meshes"][0]["primitives"][0]
    want_pos = read_accessor(gltf, stored, prim["attributes"]["POSITION"]) @ matrix[:3, :3].T + matrix[:3, 3]
    normals = read_accessor(gltf, stored, prim["attributes"]["NORMAL"]) @ np.linalg.inv(matrix[:3, :3])
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    faces = read_accessor(gltf, stored, prim["indices"]).reshape(-1, 3)[:, [0, 2, 1]]  # mirrored: winding reversed
    want = np.hstack([want_pos, normals]).astype(np.float32)[faces].reshape(len(faces), -1)
    got_faces = read_accessor(back, back_buffers, got_prim["indices"]).reshape(-1, 3)
    got = np.hstack([read_accessor(back, back_buffers, got_prim["attributes"][s]) for s in ("POSITION", "NORMAL")])
    got = got.astype(np.float32)[got_faces].reshape(len(got_faces), -1)
    # row for row, corners in order: each face placed, its normals turned, its winding reversed (a mirror)
    assert np.abs(got[np.lexsort(got.T[::-1])] - want[np.lexsort(want.T[::-1])]).max() <= 1e-6


def test_the_files_beside_an_obj_never_replace_the_input(tmp_path):
    src, _, _ = _textured(tmp_path)
    cunning = tmp_path / "o_0.png"  # the .pmw under the name the texture beside o.obj would get
    cunning.write_bytes(src.read_bytes())
    run = pmw("decode", cunning, "-o", tmp_path / "o.obj")
    assert run.returncode == 2 and "is also the input" in run.stderr and "Traceback" not in run.stderr
    assert cunning.read_bytes() == src.read_bytes() and not (tmp_path / "o.obj").exists()
    assert not (tmp_path / "o.mtl").exists()


def test_a_file_beside_the_obj_that_cannot_be_written_leaves_no_file_at_all(tmp_path):
    src, _, _ = _textured(tmp_path)
    (tmp_path / "o.mtl").mkdir()  # where the MTL would go
    run = pmw("decode", src, "-o", tmp_path / "o.obj")
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "o.mtl" in run.stderr
    assert sorted(os.listdir(tmp_path)) == ["o.mtl", "skin.png", "t.mtl", "t.obj", "t.pmw"]


def test_geometry_only_writes_the_positions_and_faces_it_wrote_before(tmp_path):
    src, _, _ = _textured(tmp_path)
    for suffix in (".obj", ".ply"):
        out = tmp_path / f"g{suffix}"
        run = pmw("decode", src, "-o", out, "--geometry-only", "--json")
        assert run.returncode == 0, run.stderr
        assert json.loads(run.stdout)["files"] == [str(out)]
        write_mesh(tmp_path / f"want{suffix}", pmwm_codec.decode(str(src)))
        assert out.read_bytes() == (tmp_path / f"want{suffix}").read_bytes()


@pytest.mark.parametrize("suffix", [".stl", ".off"])
def test_a_format_of_geometry_alone_says_what_it_leaves_out(tmp_path, suffix):
    src, _, _ = _textured(tmp_path)
    run = pmw("decode", src, "-o", tmp_path / f"g{suffix}", "--json")
    assert run.returncode == 0, run.stderr
    assert any("left out" in n and "texture coordinates" in n for n in json.loads(run.stdout)["notices"])


def test_a_plain_mesh_decodes_to_the_obj_it_always_did(tmp_path):
    mesh = shapes.demo_mesh(12)
    src = tmp_path / "plain.pmw"
    pmwm_codec.encode(mesh, str(src))
    run = pmw("decode", src, "-o", tmp_path / "p.obj", "--json")
    assert run.returncode == 0, run.stderr
    assert json.loads(run.stdout)["files"] == [str(tmp_path / "p.obj")]
    write_mesh(tmp_path / "want.obj", pmwm_codec.decode(str(src)))
    assert (tmp_path / "p.obj").read_bytes() == (tmp_path / "want.obj").read_bytes()


@pytest.mark.parametrize("name", ["ünïcødé скин.obj", "with space.ply"])
def test_files_beside_an_output_of_any_name_are_named_by_it_and_read_back(tmp_path, name):
    src, png, _ = _textured(tmp_path)
    out = tmp_path / name
    run = pmw("decode", src, "-o", out, "--json")
    assert run.returncode == 0, run.stderr
    stem = os.path.splitext(name)[0]
    assert (tmp_path / f"{stem}_0.png").read_bytes() == png
    (back, _), notices = meshdoc.read_source(str(out))
    assert notices == [] and len(back["images"]) == 1


def test_an_output_name_with_a_line_break_is_one_line_and_no_file(tmp_path):
    src, _, _ = _textured(tmp_path)
    out = tmp_path / "two\nlines.obj"
    run = pmw("decode", src, "-o", out)
    assert run.returncode == 2 and "line break" in run.stderr and "Traceback" not in run.stderr
    assert sorted(os.listdir(tmp_path)) == ["skin.png", "t.mtl", "t.obj", "t.pmw"]


def test_an_input_never_makes_decode_write_more_textures_than_the_limit(tmp_path, monkeypatch):
    from pmwm_codec import meshexport

    path, *_ = _torus_obj(str(tmp_path), mtl="t.mtl")
    for k, colour in enumerate([(200, 0, 0), (0, 200, 0), (0, 0, 200)]):
        _png(tmp_path / f"s{k}.png", colour=colour)
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd s0.png\nmap_Bump s1.png\n")
    src = tmp_path / "t.pmw"
    pmwm_codec.encode(path, str(src))
    gltf, buffers = _glb_document(src, tmp_path)
    assert len(meshexport.scene_parts(gltf, buffers).images) == 2
    monkeypatch.setattr(meshexport, "MAX_WRITTEN_IMAGES", 1)
    scene = meshexport.scene_parts(gltf, buffers)
    assert len(scene.images) == 1 and any("past the first 1" in n for n in scene.notices)
    meshexport.write_scene(str(tmp_path / "o.obj"), scene)
    assert sorted(p for p in os.listdir(tmp_path) if p.startswith("o")) == ["o.mtl", "o.obj", "o_0.png"]


def test_a_progressive_mesh_the_scene_does_not_show_is_held_as_stored_as_geometry_alone_is_and_said(tmp_path):
    path, *_ = _torus_obj(str(tmp_path), mtl=None)
    (doc, buffers), _ = meshdoc.read_source(path)
    doc["scenes"][0]["nodes"] = []  # node 0 still shows mesh 0, but no scene has node 0
    src = tmp_path / "hidden.pmw"
    pmwm_codec.encode((doc, buffers), str(src))
    styled, plain = (pmw("decode", src, "-o", tmp_path / f"{name}.obj", "--json", *extra)
                     for name, extra in (("styled", ()), ("plain", ("--geometry-only",))))
    assert styled.returncode == plain.returncode == 0, styled.stderr + plain.stderr
    styled, plain = json.loads(styled.stdout), json.loads(plain.stdout)
    assert styled["faces"] == plain["faces"] > 0
    assert any("mesh 0 is not shown in the scene" in n for n in styled["notices"])
    (back, _), _ = meshdoc.read_source(str(tmp_path / "styled.obj"))
    assert "TEXCOORD_0" in back["meshes"][0]["primitives"][0]["attributes"]


def test_a_material_name_in_any_script_is_kept_and_reads_back(tmp_path):
    path, *_ = _torus_obj(str(tmp_path))
    _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\n")
    (doc, buffers), _ = meshdoc.read_source(path)
    doc["materials"][0]["name"] = "Кожа дракона #2"
    src = tmp_path / "named.pmw"
    pmwm_codec.encode((doc, buffers), str(src))
    assert pmw("decode", src, "-o", tmp_path / "o.obj").returncode == 0
    (back, _), notices = meshdoc.read_source(str(tmp_path / "o.obj"))
    assert back["materials"][0]["name"] == "Кожа_дракона_2" and notices == []


def test_an_off_decoded_from_a_coloured_asset_is_a_coff_whose_colours_read_back_the_same(tmp_path):
    src, _, _ = _textured(tmp_path, colours=True)
    run = pmw("decode", src, "-o", tmp_path / "back.off", "--json")
    assert run.returncode == 0, run.stderr
    report = json.loads(run.stdout)
    assert report["files"] == [str(tmp_path / "back.off")] and (tmp_path / "back.off").read_text().startswith("COFF\n")
    assert any("texture coordinates, normals and materials are left out" in n for n in report["notices"])
    (back, back_buffers), _ = meshdoc.read_source(str(tmp_path / "back.off"))
    gltf, buffers = _glb_document(src, tmp_path)
    want = _corner_rows(gltf, buffers, ("POSITION", "COLOR_0"))
    got = _corner_rows(back, back_buffers, ("POSITION", "COLOR_0"))
    assert np.array_equal(got.reshape(-1, 6)[:, :3], want.reshape(-1, 6)[:, :3])  # positions exact
    assert np.abs(got - want).max() <= 2e-6  # colours written sRGB-encoded with six decimals
    assert report["vertices"] == pmwm_codec.read_mesh(str(tmp_path / "back.off")).vertex_count


def test_the_library_call_writes_what_the_command_writes_and_returns_its_json(tmp_path):
    src, _, _ = _textured(tmp_path)
    run = pmw("decode", src, "-o", tmp_path / "cli.obj", "--json", "--chunks", 2)
    assert run.returncode == 0, run.stderr
    result = pmwm_codec.decode_to(src, tmp_path / "api.obj", chunks=2)
    assert result.pop("bytes_read") == src.stat().st_size
    want = json.loads(run.stdout)
    assert {k: v for k, v in result.items() if k not in ("output", "files")} == \
        {k: v for k, v in want.items() if k not in ("output", "files")}
    assert result["files"] == [str(tmp_path / "api.obj"), str(tmp_path / "api.mtl"), str(tmp_path / "api_0.png")]
    assert (tmp_path / "api.obj").read_bytes().replace(b"api.mtl", b"cli.mtl") == (tmp_path / "cli.obj").read_bytes()
    with pytest.raises(pmwm_codec.PmwError, match="is also the input"):
        pmwm_codec.decode_to(src, src)


def test_an_obj_of_an_asset_says_it_leaves_out_material_extensions(tmp_path):
    """An MTL has no clearcoat, transmission, unlit ...: each material says what it lost (they were dropped without
    a word: a glass material came out as an opaque white one); a PLY says it lost the emission too."""
    from pmwm_codec.stream.asset import encode_asset

    from test_asset import DocBuilder

    b = DocBuilder()
    prims = [{**b.triangles(shapes.icosphere(3, 1.0, noise=0.02)), "material": 0},
             {**b.triangles(shapes.icosphere(3, 0.5, noise=0.02)), "material": 1}]
    b.doc.update({
        "extensionsUsed": ["KHR_materials_transmission", "KHR_materials_volume", "KHR_materials_unlit"],
        "meshes": [{"primitives": prims}],
        "materials": [{"name": "glass", "emissiveFactor": [1.0, 0.5, 0.0],
                       "extensions": {"KHR_materials_transmission": {"transmissionFactor": 0.9},
                                      "KHR_materials_volume": {"thicknessFactor": 0.2}}},
                      {"name": "flat", "extensions": {"KHR_materials_unlit": {}}}],
    })
    (tmp_path / "in.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    for suffix in (".obj", ".ply"):
        out = pmw("decode", tmp_path / "in.pmw", "-o", tmp_path / f"out{suffix}", "--json")
        notices = json.loads(out.stdout)["notices"]
        assert ("material glass's KHR_materials_transmission, KHR_materials_volume are left out: an MTL cannot say "
                "them") in notices, suffix
        assert "material flat's KHR_materials_unlit is left out: an MTL cannot say it" in notices
        emission_lost = any("emission (emissiveFactor, emissiveTexture) is left out" in n for n in notices)
        assert emission_lost == (suffix == ".ply")  # (an MTL holds it: Ke)
