"""An OBJ / PLY of an asset says where it differs from what a glTF viewer shows: a skinned mesh's joints and
weights left out (an OBJ holds none), a skinned mesh moved by its node's transform (which a viewer ignores,
glTF 2.0 3.7.3.3), a mesh its node draws with morph weights (a node's weights override its mesh's) posed by
them."""

from __future__ import annotations

import json

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.stream.asset import encode_asset

from test_asset import DocBuilder
from test_skinned import _skinned_asset


def _notices(capsys, *args) -> list:
    capsys.readouterr()
    assert main([*map(str, args), "--json"]) in (0, None)
    return json.loads(capsys.readouterr().out)["notices"]


def _with_node(path, **node):
    """Rewrite the GLB at ``path`` with its node 0 updated by ``node`` (JSON only)."""
    from pmwm_codec.format.glb import glb_parts
    from pmwm_codec.format.document import load_document

    doc, buffers = load_document(path)
    doc["nodes"][0].update(node)
    path.write_bytes(b"".join(glb_parts(doc, [buffers[0]], len(buffers[0]))))


def test_an_obj_of_a_skinned_mesh_says_its_joints_and_weights_are_left_out_not_that_it_holds_one_set(tmp_path, capsys):
    _skinned_asset(tmp_path / "in.glb")
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    notices = _notices(capsys, "decode", tmp_path / "in.pmw", "-o", tmp_path / "out.obj")
    assert "skin joints and weights (JOINTS_n, WEIGHTS_n) are left out: an OBJ or PLY holds none" in notices
    assert not any("one set" in n for n in notices)


def test_an_obj_of_a_skinned_mesh_its_node_moves_says_a_viewer_would_not_move_it(tmp_path, capsys):
    positions, _, _ = _skinned_asset(tmp_path / "in.glb")
    _with_node(tmp_path / "in.glb", translation=[3.0, 0.0, 0.0], scale=[1.0, 2.0, 1.0])
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    notices = _notices(capsys, "decode", tmp_path / "in.pmw", "-o", tmp_path / "out.obj")
    assert ("mesh 0 is skinned: the file holds it in its stored pose, not posed by its joints, moved by its node's "
            "transform, which a glTF viewer ignores for a skinned mesh") in notices
    obj = np.array([ln.split()[1:4] for ln in (tmp_path / "out.obj").read_text().splitlines() if ln.startswith("v ")],
                   float)
    assert obj[:, 0].min() > positions[:, 0].min() + 2  # (the note is true: the OBJ places it by the node)
    _skinned_asset(tmp_path / "still.glb")  # a skinned mesh no node moves: the plain note
    encode_asset(tmp_path / "still.glb", tmp_path / "still.pmw", measure=False)
    notices = _notices(capsys, "decode", tmp_path / "still.pmw", "-o", tmp_path / "still.obj")
    assert "mesh 0 is skinned: the file holds it in its stored pose, not posed by its joints" in notices


def test_an_obj_of_a_mesh_its_node_draws_morphed_holds_it_morphed_and_says_so(tmp_path, capsys):
    """The mesh's own weights are zero, its node's are not: a viewer draws it morphed (so does read_mesh)."""
    b = DocBuilder()
    sphere = shapes.icosphere(2, 1.0)
    prim = b.triangles(sphere, uv=False)
    prim["targets"] = [{"POSITION": b.accessor((sphere.positions * 0.5).astype(np.float32), 5126, "VEC3", 34962, True)}]
    ball = b.triangles(shapes.icosphere(3, 1.0, noise=0.02), uv=False)  # (an asset needs a progressive mesh)
    b.doc.update({"scene": 0, "scenes": [{"nodes": [0, 1]}],
                  "nodes": [{"mesh": 0, "weights": [0.5]}, {"mesh": 1, "translation": [3.0, 0.0, 0.0]}],
                  "meshes": [{"primitives": [prim], "weights": [0.0]}, {"primitives": [ball]}]})
    (tmp_path / "in.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    for out in ("out.obj", "out.ply"):
        notices = _notices(capsys, "decode", tmp_path / "in.pmw", "-o", tmp_path / out)
        assert ("mesh 0's morph targets are left out: the file holds it posed at the weights it is drawn with at rest "
                "(decode to .glb to keep them)") in notices, out
    obj = (tmp_path / "out.obj").read_text().splitlines()
    radii = np.linalg.norm(np.array([ln.split()[1:4] for ln in obj if ln.startswith("v ")], float), axis=1)
    assert np.isclose(radii.min(), 1.25, atol=1e-3)  # the unit sphere morphed by 0.5 x its half: at the node's weight


def test_geometry_only_of_a_skinned_mesh_its_node_moves_says_a_viewer_would_not_move_it(tmp_path, capsys):
    """read_mesh places it by its node (the owner layer's frame) and counts it in ``cleanup``; the encoder says so."""
    import pmwm_codec

    _skinned_asset(tmp_path / "in.glb")
    _with_node(tmp_path / "in.glb", translation=[3.0, 0.0, 0.0])
    assert pmwm_codec.read_mesh(tmp_path / "in.glb").cleanup == {"skinned_meshes_moved_by_their_nodes": 1}
    notices = _notices(capsys, "encode", tmp_path / "in.glb", "-o", tmp_path / "in.pmw", "--geometry-only")
    assert ("1 skinned mesh(es) read in their stored pose placed by their node's transform, which a glTF viewer "
            "ignores for a skinned mesh (glTF 2.0 3.7.3.3)") in notices
    _skinned_asset(tmp_path / "still.glb")
    assert not pmwm_codec.read_mesh(tmp_path / "still.glb").cleanup


def test_an_obj_of_a_morphed_mesh_holds_its_texture_coordinates_and_colours_morphed_too(tmp_path, capsys):
    """glTF morph targets may move TEXCOORD_n and COLOR_n as well as positions and normals (glTF 2.0 3.7.2.2): the
    OBJ / PLY of a mesh drawn morphed held its positions posed and its texture coordinates and colours as stored.
    The PLY's values are the decoded GLB's plus half the targets' (colours clamped to 1, as a viewer shows them)."""
    from pmwm_codec import meshdoc, ply
    from pmwm_codec.format.document import load_document, read_accessor

    b = DocBuilder()
    sphere = shapes.icosphere(2, 1.0)
    n = sphere.vertex_count
    prim = b.triangles(sphere)
    prim["attributes"]["COLOR_0"] = b.accessor(np.tile(np.float32([0.2, 0.4, 0.6]), (n, 1)), 5126, "VEC3", 34962)
    prim["targets"] = [{"POSITION": b.accessor(np.zeros((n, 3), np.float32), 5126, "VEC3", 34962, True),
                        "TEXCOORD_0": b.accessor(np.tile(np.float32([0.25, -0.5]), (n, 1)), 5126, "VEC2", 34962),
                        "COLOR_0": b.accessor(np.tile(np.float32([0.5, 0.5, 0.9]), (n, 1)), 5126, "VEC3", 34962)}]
    ball = b.triangles(shapes.icosphere(3, 1.0, noise=0.02), uv=False)
    b.doc.update({"scene": 0, "scenes": [{"nodes": [0, 1]}],
                  "nodes": [{"mesh": 0}, {"mesh": 1, "translation": [3.0, 0.0, 0.0]}],
                  "meshes": [{"primitives": [prim], "weights": [0.5]}, {"primitives": [ball]}]})
    (tmp_path / "in.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", measure=False)
    _notices(capsys, "decode", tmp_path / "in.pmw", "-o", tmp_path / "out.glb")
    _notices(capsys, "decode", tmp_path / "in.pmw", "-o", tmp_path / "out.ply")
    gltf, buffers = load_document(tmp_path / "out.glb")
    attrs = gltf["meshes"][0]["primitives"][0]["attributes"]
    m = len(read_accessor(gltf, buffers, attrs["POSITION"]))
    got = ply.read_appearance((tmp_path / "out.ply").read_bytes(), "out.ply", 10 ** 7)
    uv = read_accessor(gltf, buffers, attrs["TEXCOORD_0"]) + [0.125, -0.25]
    assert np.abs(got.uv[:m] - np.stack([uv[:, 0], 1 - uv[:, 1]], 1)).max() <= 2e-7
    rgb = meshdoc.srgb_from_linear(np.clip(read_accessor(gltf, buffers, attrs["COLOR_0"])[:, :3] + 0.5 * np.float32(
        [0.5, 0.5, 0.9]), 0, 1))
    assert np.abs(got.colours[:m, :3] - rgb).max() <= 0.5 / 255 + 1e-9
