"""three.js's own OBJ, MTL and PLY loaders read what ``pmw decode -o X.obj / X.ply`` writes as the decoded GLB
holds it: the same corners, texture coordinates (glTF's ``v`` flipped, as OBJ and PLY have it) and colours (three.js
takes an OBJ's or PLY's colours as sRGB and decodes them to the linear values glTF's COLOR_0 holds: the same
values), the material and its texture file; and the colours it reads from a source PLY are those our ``.pmw`` of it
carries.

Runs ``node tools/js/check_obj.mjs`` (one JSON line per file).  Needs Node and ``npm ci --prefix tools/js``;
skipped with the reason otherwise.
"""

from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.format.document import load_document, read_accessor

from test_decode_appearance import _textured, pmw
from test_ply_appearance import corners, ply_bytes, xyz

JS = Path(__file__).resolve().parents[1] / "tools" / "js"

pytestmark = [
    pytest.mark.node,
    pytest.mark.skipif(shutil.which("node") is None, reason="node is not on PATH"),
    pytest.mark.skipif(not (JS / "node_modules").is_dir(),
                       reason="tools/js/node_modules is absent: run `npm ci --prefix tools/js`"),
]

#: COLOR_0's 12-bit grid (half a step) and float32 on both sides.
COLOUR_TOLERANCE = 0.5 / 4095 + 1e-6


def _three(*paths) -> list:
    proc = subprocess.run(["node", str(JS / "check_obj.mjs"), *map(str, paths)], capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    out = [json.loads(line) for line in proc.stdout.splitlines()]
    assert all(o["ok"] for o in out), out
    return out


def _glb(pmw: Path, tmp_path: Path) -> tuple:
    """``(per corner: positions (3m, 3), uv (3m, 2), colours (3m, 3)) float32`` of the decoded GLB's one primitive."""
    (tmp_path / "ref.glb").write_bytes(pmwm_codec.decode_asset(str(pmw)))
    gltf, buffers = load_document(str(tmp_path / "ref.glb"))
    prim = gltf["meshes"][0]["primitives"][0]
    faces = read_accessor(gltf, buffers, prim["indices"]).reshape(-1)
    attrs = {k: read_accessor(gltf, buffers, v)[faces].astype(np.float32) for k, v in prim["attributes"].items()}
    return attrs["POSITION"], attrs["TEXCOORD_0"], attrs["COLOR_0"][:, :3]


def _by_corner(rows: np.ndarray) -> np.ndarray:
    """``rows`` (3m, d) as triangles (m, 3d), sorted (the order of faces is not part of the claim)."""
    tri = rows.reshape(-1, 3 * rows.shape[1])
    return tri[np.lexsort(tri.T[::-1])]


def test_three_js_reads_the_decoded_obj_and_mtl_as_the_decoded_glb_holds_them(tmp_path):
    src, _, _ = _textured(tmp_path, colours=True)
    out = tmp_path / "back.obj"
    assert pmw("decode", src, "-o", out).returncode == 0
    (obj,) = _three(out)
    (mesh,) = obj["meshes"]
    pos, uv, rgb = _glb(src, tmp_path)
    assert mesh["corners"] == len(pos)
    got = np.hstack([np.reshape(mesh["position"], (-1, 3)), np.reshape(mesh["uv"], (-1, 2)),
                     np.reshape(mesh["color"], (-1, 3))])
    want = np.hstack([pos, np.stack([uv[:, 0], 1 - uv[:, 1]], 1), rgb])
    assert np.abs(_by_corner(got) - _by_corner(want)).max() <= COLOUR_TOLERANCE
    assert np.array_equal(_by_corner(got[:, :3]), _by_corner(want[:, :3]))  # positions exact
    assert [g["material"] for g in mesh["groups"]] == ["skin"]
    assert obj["materials"]["skin"]["map"] == "back_0.png" and obj["materials"]["skin"]["opacity"] == 0.5


def test_three_js_reads_the_decoded_ply_as_the_decoded_glb_holds_it(tmp_path):
    src, _, _ = _textured(tmp_path, colours=True)
    out = tmp_path / "back.ply"
    assert pmw("decode", src, "-o", out).returncode == 0
    (ply,) = _three(out)
    assert set(ply["attributes"]) >= {"position", "uv", "color"}
    (tmp_path / "ref.glb").write_bytes(pmwm_codec.decode_asset(str(src)))
    gltf, buffers = load_document(str(tmp_path / "ref.glb"))
    prim = gltf["meshes"][0]["primitives"][0]
    rgb = read_accessor(gltf, buffers, prim["attributes"]["COLOR_0"])[:, :3]
    uv = read_accessor(gltf, buffers, prim["attributes"]["TEXCOORD_0"])
    assert ply["vertices"] == len(rgb)  # a vertex per glTF vertex, in its order
    # the PLY's sRGB bytes (half a byte each), decoded by three.js to linear bytes (half a byte again)
    assert np.abs(np.reshape(ply["color"], (-1, 3)) - rgb).max() <= (0.5 * 2.28 + 0.5) / 255 + COLOUR_TOLERANCE
    assert np.abs(np.reshape(ply["uv"], (-1, 2)) - np.stack([uv[:, 0], 1 - uv[:, 1]], 1)).max() <= 2e-7


def test_the_colours_of_a_ply_ride_as_three_js_reads_them_from_the_ply_itself(tmp_path):
    mesh = shapes.icosphere(3)
    rgb = np.random.default_rng(5).integers(0, 256, (len(mesh.positions), 3))
    path = tmp_path / "c.ply"
    path.write_bytes(ply_bytes("binary_little_endian",
                               xyz(mesh.positions) + [(c, "uchar", rgb[:, i]) for i, c in enumerate(("red", "green",
                                                                                                    "blue"))],
                               corners(mesh.faces)))
    (source,) = _three(path)
    pmwm_codec.encode(str(path), str(tmp_path / "c.pmw"))
    (tmp_path / "ref.glb").write_bytes(pmwm_codec.decode_asset(str(tmp_path / "c.pmw")))
    gltf, buffers = load_document(str(tmp_path / "ref.glb"))
    prim = gltf["meshes"][0]["primitives"][0]
    pos = read_accessor(gltf, buffers, prim["attributes"]["POSITION"])
    got = read_accessor(gltf, buffers, prim["attributes"]["COLOR_0"])
    three_rgb = np.reshape(source["color"], (-1, 3))  # three.js's linear values, a PLY vertex each, in file order
    _, nearest = cKDTree(mesh.positions).query(pos)
    assert np.abs(got - three_rgb[nearest]).max() <= 0.5 / 255 + COLOUR_TOLERANCE  # three.js keeps linear bytes
