"""The triangles of a ``.pmw``'s primitives that are not progressive (morph-targeted ones pass through as stored)
decoded to OBJ / STL as a glTF viewer draws them: a strip's restarts (an index repeated to join two strips, which
draws nothing) dropped, as the encoders and the glTF geometry reader read a strip (the decode had written them as
degenerate faces), a fan's triangles wound as glTF says, and a morphed mesh posed at the weights it is drawn with
at rest -- its node's ``weights``, else its mesh's -- as ``read_mesh`` and viewers pose it, with a note that the
targets themselves are left out (the decode had written the stored, unposed positions).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.format.gltf import triangle_list

from test_asset import DocBuilder
from test_decode_appearance import pmw

#: A ribbon of two quads joined into one strip by a restart (3 and 4 repeated): 8 triangles, 4 of them drawing
#: nothing.
STRIP_POSITIONS = np.array([[0, 0, 0], [0, 1, 0], [1, 0, 0], [1, 1, 0],
                            [3, 0, 0], [3, 1, 0], [4, 0, 0], [4, 1, 0]], np.float32)
STRIP_ORDER = np.array([0, 1, 2, 3, 3, 4, 4, 5, 6, 7], np.uint16)
#: A fan of six triangles about its first vertex (no indices), and its one morph target: every vertex up by 1.
FAN_POSITIONS = np.array([[0, 0, 0]] + [[np.cos(a), np.sin(a), 0] for a in np.linspace(0, 2 * np.pi, 7)],
                         np.float32)
FAN_TARGET = np.tile(np.array([0, 0, 1], np.float32), (len(FAN_POSITIONS), 1))
STRIP_AT, FAN_AT, FAN_WEIGHT = 10.0, 20.0, 0.5


def _asset(tmp_path, fan_node_weights=(FAN_WEIGHT,), second_fan=None, normals=False) -> str:
    """A ``.pmw`` of a progressive sphere at the origin, the strip (with a morph target of no displacement, so
    that it passes through) at x = 10 and the fan (its target weighted ``fan_node_weights`` by its node, 0.25
    by its mesh) at x = 20; and, with ``second_fan`` (weights), the fan again at x = 30, so weighted; with
    ``normals``, the fan's normals +z, its target turning them by +x."""
    b = DocBuilder()
    sphere = b.triangles(shapes.icosphere(3, 1.0), uv=False)
    pos = b.accessor(STRIP_POSITIONS, 5126, "VEC3", 34962, True)
    zero = b.accessor(np.zeros_like(STRIP_POSITIONS), 5126, "VEC3", 34962, True)
    strip = {"attributes": {"POSITION": pos}, "indices": b.accessor(STRIP_ORDER, 5123, "SCALAR", 34963),
             "mode": 5, "targets": [{"POSITION": zero}]}
    fan = {"attributes": {"POSITION": b.accessor(FAN_POSITIONS, 5126, "VEC3", 34962, True)}, "mode": 6,
           "targets": [{"POSITION": b.accessor(FAN_TARGET, 5126, "VEC3", 34962, True)}]}
    if normals:
        up = np.tile(np.array([0, 0, 1], np.float32), (len(FAN_POSITIONS), 1))
        fan["attributes"]["NORMAL"] = b.accessor(up, 5126, "VEC3", 34962)
        fan["targets"][0]["NORMAL"] = b.accessor(up[:, [2, 0, 1]], 5126, "VEC3", 34962)
    fan_node = {"mesh": 2, "translation": [FAN_AT, 0, 0]}
    if fan_node_weights is not None:
        fan_node["weights"] = list(fan_node_weights)
    nodes = [{"mesh": 0}, {"mesh": 1, "translation": [STRIP_AT, 0, 0]}, fan_node]
    if second_fan is not None:
        nodes.append({"mesh": 2, "translation": [FAN_AT + 10, 0, 0], "weights": list(second_fan)})
    b.doc.update({"scene": 0, "scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes,
                  "meshes": [{"primitives": [sphere]}, {"primitives": [strip]},
                             {"primitives": [fan], "weights": [0.25]}]})
    (tmp_path / "in.glb").write_bytes(b.glb())
    pmwm_codec.encode(str(tmp_path / "in.glb"), str(tmp_path / "in.pmw"))
    return str(tmp_path / "in.pmw")


def _obj_triangles(path) -> np.ndarray:
    """(m, 3, 3) float64: each ``f`` record's corner positions of the OBJ at ``path``."""
    v, f = [], []
    for line in open(path, encoding="utf-8"):
        words = line.split()
        if words and words[0] == "v":
            v.append([float(x) for x in words[1:4]])
        elif words and words[0] == "f":
            f.append([int(w.split("/")[0]) - 1 for w in words[1:]])
    return np.array(v)[np.array(f)]


def _near(triangles, x: float) -> np.ndarray:
    """The triangles of ``triangles`` (m, 3, 3) within 5 of x = ``x``, rows sorted."""
    tri = triangles[np.abs(triangles[:, :, 0].mean(1) - x) < 5].reshape(-1, 9)
    return tri[np.lexsort(tri.T[::-1])]


def _expected(positions, order, mode, at, lift=0.0) -> np.ndarray:
    tri = triangle_list(order, mode)
    tri = tri[(tri[:, 0] != tri[:, 1]) & (tri[:, 1] != tri[:, 2]) & (tri[:, 0] != tri[:, 2])]
    out = (positions.astype(np.float64) + [at, 0.0, lift])[tri].reshape(-1, 9)
    return out[np.lexsort(out.T[::-1])]


@pytest.mark.parametrize("options", [(), ("--geometry-only",)], ids=["obj", "geometry-only"])
def test_a_strip_s_restarts_are_dropped_and_a_fan_is_posed_in_the_decoded_obj(tmp_path, options):
    src = _asset(tmp_path)
    out = tmp_path / "out.obj"
    proc = pmw("decode", src, "-o", out, "--json", *options)
    assert proc.returncode == 0, proc.stderr
    triangles = _obj_triangles(out)
    strip = _near(triangles, STRIP_AT + 2)
    assert np.array_equal(strip, _expected(STRIP_POSITIONS, STRIP_ORDER, 5, STRIP_AT))  # 4 triangles, none degenerate
    fan = _near(triangles, FAN_AT)
    lifted = _expected(FAN_POSITIONS, np.arange(len(FAN_POSITIONS)), 6, FAN_AT, lift=FAN_WEIGHT)  # the node's weight
    assert np.allclose(fan, lifted, atol=1e-6)
    notices = json.loads(proc.stdout)["notices"]
    assert any("mesh 2's morph targets are left out: the file holds it posed" in n for n in notices), notices
    assert json.loads(proc.stdout)["faces"] == len(triangles)


@pytest.mark.parametrize("suffix", [".obj", ".stl"])
def test_a_mesh_its_nodes_draw_with_different_weights_is_held_as_stored_and_said(tmp_path, suffix):
    src = _asset(tmp_path, second_fan=[1.0])
    result = pmwm_codec.decode_to(src, str(tmp_path / f"out{suffix}"))
    assert any("mesh 2 is drawn with different morph weights by its nodes: the file holds its stored positions" in n
               for n in result["notices"]), result["notices"]
    if suffix == ".obj":
        triangles = _obj_triangles(tmp_path / "out.obj")
        for at in (FAN_AT, FAN_AT + 10):
            assert np.allclose(_near(triangles, at), _expected(FAN_POSITIONS, np.arange(len(FAN_POSITIONS)), 6, at),
                               atol=1e-6)


def test_the_geometry_reader_and_the_decoded_obj_pose_a_morphed_mesh_alike(tmp_path):
    """``read_mesh`` of the glTF and of the OBJ ``pmw decode`` writes of its ``.pmw``: the same posed fan and strip."""
    src = _asset(tmp_path)
    pmwm_codec.decode_to(src, str(tmp_path / "out.obj"))
    read = pmwm_codec.read_mesh(str(tmp_path / "in.glb"))
    tri = read.positions[read.faces]
    for at in (STRIP_AT + 2, FAN_AT):
        assert np.allclose(_near(tri, at), _near(_obj_triangles(tmp_path / "out.obj"), at), atol=1e-6)


def test_a_morphed_mesh_s_normals_are_posed_with_it_in_the_decoded_obj(tmp_path):
    src = _asset(tmp_path, normals=True)
    pmwm_codec.decode_to(src, str(tmp_path / "out.obj"))
    vn = [line.split()[1:] for line in open(tmp_path / "out.obj") if line.startswith("vn ")]
    want = np.array([FAN_WEIGHT, 0.0, 1.0]) / np.hypot(FAN_WEIGHT, 1.0)  # displaced, of unit length again
    assert len(vn) == 1 and np.allclose(np.array(vn[0], float), want, atol=1e-7), vn
