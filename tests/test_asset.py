"""glTF assets: materials, textures, nodes and odd primitives survive; seams never crack."""

from __future__ import annotations

import json
import shutil
import subprocess

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.format.document import load_document, read_accessor, sniff_json
from pmwm_codec.format.glb import glb_parts
from pmwm_codec.format.layout import padded
from pmwm_codec.stream.asset import decode_asset, encode_asset
from pmwm_codec.stream.decoder import StreamDecoder
from pmwm_codec.watermark.key import WatermarkKey

from conftest import ROOT, corpus_path

CHECKER = ROOT / "tools" / "js" / "check_gltf.mjs"


def check(path):
    """Khronos validator + three.js on a file (skips when the npm checkers are not installed)."""
    if shutil.which("node") is None or not (ROOT / "tools" / "js" / "node_modules").exists():
        pytest.skip("npm checkers not installed (npm ci --prefix tools/js)")
    out = subprocess.run(["node", str(CHECKER), str(path)], capture_output=True, text=True, check=True)
    return json.loads(out.stdout.splitlines()[0])


class DocBuilder:
    """Builds a GLB from numpy arrays, for test assets."""

    def __init__(self):
        self.doc = {"asset": {"version": "2.0"}, "accessors": [], "bufferViews": []}
        self.parts, self.offset = [], 0

    def accessor(self, array, component, type_, target=None, minmax=False):
        raw = np.ascontiguousarray(array).tobytes()
        view = {"buffer": 0, "byteOffset": self.offset, "byteLength": len(raw)}
        if target:
            view["target"] = target
        self.doc["bufferViews"].append(view)
        self.parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        self.offset += padded(len(raw))
        acc = {"bufferView": len(self.doc["bufferViews"]) - 1, "componentType": component, "count": len(array), "type": type_}
        if minmax:
            acc["min"] = [float(x) for x in array.min(0)]
            acc["max"] = [float(x) for x in array.max(0)]
        self.doc["accessors"].append(acc)
        return len(self.doc["accessors"]) - 1

    def triangles(self, mesh, uv=True):
        attrs = {"POSITION": self.accessor(mesh.positions.astype(np.float32), 5126, "VEC3", 34962, True)}
        if uv:
            p = mesh.positions
            uvs = np.stack([np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5, p[:, 2] / 4 + 0.5], 1)
            attrs["TEXCOORD_0"] = self.accessor(uvs.astype(np.float32), 5126, "VEC2", 34962)
            n = p / np.linalg.norm(p, axis=1, keepdims=True)
            attrs["NORMAL"] = self.accessor(n.astype(np.float32), 5126, "VEC3", 34962)
        return {"attributes": attrs, "indices": self.accessor(mesh.faces.astype(np.uint32).ravel(), 5125, "SCALAR", 34963)}

    def glb(self) -> bytes:
        self.doc["buffers"] = [{"byteLength": self.offset}]
        return b"".join(glb_parts(self.doc, self.parts, self.offset))


def two_mesh_asset(tmp_path):
    """Two meshes, two materials, a node tree with rotation/translation, a line strip and points."""
    b = DocBuilder()
    sphere = shapes.icosphere(4, 1.0, noise=0.02)
    torus = shapes.torus(60, 30, twist=0.1)
    line = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 1]], np.float32)
    cloud = np.random.default_rng(1).uniform(-1, 1, (50, 3)).astype(np.float32)
    prim_sphere = {**b.triangles(sphere), "material": 0, "extras": {"tag": "sphere"}}
    prim_torus = {**b.triangles(torus), "material": 1}
    prim_line = {"attributes": {"POSITION": b.accessor(line, 5126, "VEC3", 34962, True)}, "mode": 3}
    prim_points = {"attributes": {"POSITION": b.accessor(cloud, 5126, "VEC3", 34962, True)}, "mode": 0}
    b.doc.update({
        "scene": 0,
        "scenes": [{"nodes": [0], "name": "world"}],
        "nodes": [
            {"name": "root", "children": [1, 2], "translation": [0.0, 1.0, 0.0]},
            {"name": "ball", "mesh": 0, "rotation": [0.0, 0.38268343, 0.0, 0.92387953], "translation": [2.0, 0.0, 0.0]},
            {"name": "ring", "mesh": 1, "scale": [1.5, 1.5, 1.5], "extras": {"note": "kept"}},
        ],
        "meshes": [{"name": "ball", "primitives": [prim_sphere, prim_line]}, {"name": "ring", "primitives": [prim_torus, prim_points]}],
        "materials": [
            {"name": "red", "pbrMetallicRoughness": {"baseColorFactor": [1, 0, 0, 1]}},
            {"name": "blue", "pbrMetallicRoughness": {"baseColorFactor": [0, 0, 1, 1], "metallicFactor": 0.5}},
        ],
    })
    path = tmp_path / "scene.glb"
    path.write_bytes(b.glb())
    return path


def test_an_asset_keeps_nodes_materials_and_meshes_and_verifies_as_one(tmp_path):
    src = two_mesh_asset(tmp_path)
    key = WatermarkKey.generate(rng=np.random.default_rng(5))
    mark = (np.indices((16, 16)).sum(0) % 2 * 200 + 30).astype(np.uint8)
    report = encode_asset(src, tmp_path / "scene.pmw", watermark=mark, key=key, measure=False)
    assert any("mode 3" in n for n in report.notices) and any("mode 0" in n for n in report.notices)
    glb, end, _ = decode_asset(tmp_path / "scene.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    original, _ = load_document(src)
    for path in (tmp_path / "scene.pmw", tmp_path / "out.glb"):
        doc, _ = load_document(path)
        assert doc["nodes"] == original["nodes"]
        assert doc["materials"] == original["materials"]
        assert doc["scenes"] == original["scenes"]
        assert len(doc["meshes"]) == 2
        assert [m["name"] for m in doc["meshes"]] == ["ball", "ring"]
        assert doc["meshes"][0]["primitives"][0]["material"] == 0
        assert doc["meshes"][0]["primitives"][0]["extras"] == {"tag": "sphere"}
    # the watermark is spread over both meshes and reads back whole
    dec = StreamDecoder(report.key)  # the key of the file (the caller's key is not modified)
    results = dec.feed((tmp_path / "scene.pmw").read_bytes())
    dec.close()
    assert len(results[-1].parts) == 2
    assert dec.verifier.verdict() == "authentic"
    assert np.array_equal(results[-1].watermark, mark)
    for path in (tmp_path / "scene.pmw", tmp_path / "out.glb"):
        result = check(path)
        assert result["validator"]["errors"] == 0 and result["validator"]["warnings"] == 0
        assert set(result["validator"]["codes"]) <= {"UNSUPPORTED_EXTENSION", "UNUSED_OBJECT"}
        assert result["three"]["ok"]


def test_lines_and_points_pass_through_unchanged(tmp_path):
    src = two_mesh_asset(tmp_path)
    encode_asset(src, tmp_path / "scene.pmw", measure=False)
    glb, _, _ = decode_asset(tmp_path / "scene.pmw", chunks=2)
    (tmp_path / "mid.glb").write_bytes(glb)
    before, bb = load_document(src)
    for path in (tmp_path / "scene.pmw", tmp_path / "mid.glb"):
        after, ab = load_document(path)
        for mi, pi in ((0, 1), (1, 1)):
            p0, p1 = before["meshes"][mi]["primitives"][pi], after["meshes"][mi]["primitives"][pi]
            assert p1["mode"] == p0["mode"]
            assert np.array_equal(read_accessor(after, ab, p1["attributes"]["POSITION"]),
                                  read_accessor(before, bb, p0["attributes"]["POSITION"]))


@pytest.mark.parametrize("problem", ["index", "nan"])
def test_a_primitive_with_invalid_data_is_refused_not_passed_through(tmp_path, problem):
    """The library refuses (MeshError naming the primitive once) instead of passing it through."""
    from pmwm_codec.errors import MeshError

    src = two_mesh_asset(tmp_path)
    gltf, buffers = load_document(src)
    b = DocBuilder()
    bad = shapes.icosphere(1)
    faces, positions = bad.faces.copy(), bad.positions.copy()
    if problem == "index":
        faces[0, 0] = 1_000_000
    else:
        positions[7] = np.nan
    prim = b.triangles(type(bad)(positions, faces), uv=False)
    for acc in b.doc["accessors"]:  # bounds JSON can hold (a NaN there is refused first, as in a file)
        acc.update({k: np.nan_to_num(v).tolist() for k, v in acc.items() if k in ("min", "max")})
    offset = len(gltf["accessors"])
    gltf["accessors"] += b.doc["accessors"]
    for acc in b.doc["accessors"]:
        acc["bufferView"] += len(gltf["bufferViews"])
    gltf["bufferViews"] += [{**v, "buffer": 1} for v in b.doc["bufferViews"]]
    gltf["buffers"].append({"byteLength": b.offset})
    gltf["meshes"][1]["primitives"].append({"attributes": {"POSITION": prim["attributes"]["POSITION"] + offset},
                                            "indices": prim["indices"] + offset})
    words = "face index 1000000 out of range for 42 vertices" if problem == "index" else "1 vertex has NaN"
    with pytest.raises(MeshError, match=rf"^mesh 1 \(ring\) primitive 2: {words}"):
        encode_asset((gltf, buffers + [b"".join(b.parts)]), tmp_path / "scene.pmw", measure=False)
    assert not (tmp_path / "scene.pmw").exists()


def test_an_in_memory_document_sharing_one_extension_dict_between_nodes_keeps_every_reference(tmp_path):
    """Three nodes holding one ``EXT_mesh_gpu_instancing`` dict (Python objects a caller shares; parsed JSON
    never does): the renumbering of accessors reached it three times and wrote ``TRANSLATION: null`` into
    the ``.pmw``, an invalid file. Copied as JSON first, each node's reference is renumbered once."""
    from pmwm_codec.errors import InputFormatError

    b = DocBuilder()
    prims = [b.triangles(shapes.icosphere(2, 1.0, noise=0.02, seed=k), uv=False) for k in range(3)]
    shifts = b.accessor(np.array([[0, 0, 0], [3, 0, 0]], np.float32), 5126, "VEC3")
    shared = {"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": shifts}}}
    b.doc.update(scene=0, scenes=[{"nodes": [0, 1, 2]}], extensionsUsed=["EXT_mesh_gpu_instancing"],
                 meshes=[{"primitives": [p]} for p in prims],
                 nodes=[{"mesh": k, "extensions": shared} for k in range(3)], buffers=[{"byteLength": b.offset}])
    encode_asset((b.doc, [b"".join(b.parts)]), tmp_path / "shared.pmw", measure=False)
    (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "shared.pmw")[0])
    doc, buffers = load_document(tmp_path / "out.glb")
    refs = [n["extensions"]["EXT_mesh_gpu_instancing"]["attributes"]["TRANSLATION"] for n in doc["nodes"]]
    assert len(set(refs)) == 1 and isinstance(refs[0], int)
    assert np.array_equal(read_accessor(doc, buffers, refs[0]), [[0, 0, 0], [3, 0, 0]])
    with pytest.raises(InputFormatError, match="not JSON"):
        encode_asset(({**b.doc, "extras": np.zeros(2)}, [b"".join(b.parts)]), tmp_path / "x.pmw", measure=False)
    assert not (tmp_path / "x.pmw").exists()


def test_full_level_positions_and_uvs_match_the_input_within_a_grid_step(tmp_path):
    src = two_mesh_asset(tmp_path)
    encode_asset(src, tmp_path / "scene.pmw", measure=False)
    glb, _, _ = decode_asset(tmp_path / "scene.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    _assert_same_geometry(src, tmp_path / "out.glb", [(0, 0), (1, 0)])


def _assert_same_geometry(src, out, prims):
    """Every input vertex (position and attributes) has a decoded vertex within half a grid step per component."""
    from scipy.spatial import cKDTree

    before, bb = load_document(src)
    after, ab = load_document(out)
    for mi, pi in prims:
        p0, p1 = before["meshes"][mi]["primitives"][pi], after["meshes"][mi]["primitives"][pi]
        assert set(p0["attributes"]) == set(p1["attributes"])
        cols_in, cols_out = [], []
        for semantic in sorted(p0["attributes"]):
            a = read_accessor(before, bb, p0["attributes"][semantic])
            b = read_accessor(after, ab, p1["attributes"][semantic])
            bits = 16 if semantic == "POSITION" else 14
            if semantic == "POSITION":
                step = np.ptp(a, axis=0).max() / (2**bits - 1)
            else:
                step = np.where(np.ptp(a, axis=0) > 0, np.ptp(a, axis=0), 1.0) / (2**bits - 1)
            if semantic == "NORMAL":
                step = step * 4  # decoded normals are renormalized after dequantization
            cols_in.append(a / step)
            cols_out.append(b / step)
        x_in, x_out = np.concatenate(cols_in, 1), np.concatenate(cols_out, 1)
        assert len(x_in) == len(x_out)
        dist, _ = cKDTree(x_out).query(x_in)
        assert dist.max() <= 0.5 * np.sqrt(x_in.shape[1]) + 1e-3


def _seam_cracks(doc, buffers, mi, pi):
    """Boundary edges of a primitive whose positions are on a seam but whose twin edge is missing."""
    prim = doc["meshes"][mi]["primitives"][pi]
    pos = np.round(read_accessor(doc, buffers, prim["attributes"]["POSITION"]), 6)
    faces = read_accessor(doc, buffers, prim["indices"]).reshape(-1, 3)
    _, key = np.unique(pos, axis=0, return_inverse=True)
    key = key.reshape(-1)
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    lo, hi = e.min(1), e.max(1)
    pair, count = np.unique(lo * len(pos) + hi, return_counts=True)
    boundary = pair[count == 1]
    b_lo, b_hi = boundary // len(pos), boundary % len(pos)
    # a seam edge: both ends' positions are shared with other vertices
    shared = np.bincount(key, minlength=key.max() + 1)[key] > 1
    seam = shared[b_lo] & shared[b_hi]
    pk = np.minimum(key[b_lo], key[b_hi]) * len(pos) + np.maximum(key[b_lo], key[b_hi])
    twins = np.unique(pk[seam], return_counts=True)
    return int(np.sum(twins[1] < 2))


@pytest.mark.corpus
def test_spot_keeps_its_texture_uvs_and_is_validator_clean_with_no_seam_cracks(tmp_path):
    src = corpus_path("spot.glb")
    out = tmp_path / "spot.pmw"
    encode_asset(src, out, strip_image_profiles=True, measure=False)
    n_chunks = StreamDecoder().feed(out.read_bytes())[-1].chunks_total
    full, _, _ = decode_asset(out)
    half, _, _ = decode_asset(out, chunks=n_chunks // 2)
    (tmp_path / "full.glb").write_bytes(full)
    (tmp_path / "half.glb").write_bytes(half)
    for path in (out, tmp_path / "full.glb", tmp_path / "half.glb"):
        doc, buffers = load_document(path)
        prim = doc["meshes"][0]["primitives"][0]
        assert "TEXCOORD_0" in prim["attributes"] and prim["material"] == 0
        assert doc["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]["index"] == 0
        assert doc["images"][0]["mimeType"] == "image/png"
        assert _seam_cracks(doc, buffers, 0, 0) == _seam_cracks(*load_document(src), 0, 0)
        result = check(path)
        assert result["validator"]["errors"] == 0 and result["validator"]["warnings"] == 0
        assert result["three"]["ok"] and result["three"]["mapped"] == 1
    _assert_same_geometry(src, tmp_path / "full.glb", [(0, 0)])


def test_pmw_decode_of_an_asset_writes_a_glb_with_its_materials(tmp_path):
    from pmwm_codec.cli import main

    src = two_mesh_asset(tmp_path)
    assert main(["encode", str(src), "-o", str(tmp_path / "s.pmw"), "--quiet"]) == 0
    assert main(["decode", str(tmp_path / "s.pmw"), "-o", str(tmp_path / "s.glb"), "--chunks", "1"]) == 0
    doc, _ = load_document(tmp_path / "s.glb")
    assert [m["name"] for m in doc["materials"]] == ["red", "blue"]
    assert len(doc["meshes"]) == 2


def test_info_lists_every_progressive_primitive_and_the_stream_order(tmp_path):
    from pmwm_codec import inspect as describe

    src = two_mesh_asset(tmp_path)
    encode_asset(src, tmp_path / "scene.pmw", measure=False)
    info = describe(str(tmp_path / "scene.pmw"))
    assert [(q["mesh"], q["primitive"]) for q in info["primitives"]] == [(0, 0), (1, 0)]
    assert info["vertices"] == sum(q["vertices"] for q in info["primitives"])
    assert {c["primitive"] for c in info["chunks"]} == {0, 1}
    assert len(info["chunks"]) == info["chunks_total"]


def test_a_draco_compressed_input_asset_is_decoded_and_made_progressive(tmp_path):
    """Most published GLBs are Draco-compressed: their primitives are decoded, then re-encoded."""
    from pmwm_codec.format.base import encode_base

    mesh = shapes.torus(50, 24, twist=0.1)
    grid = {"bits": 16, "origin": [-2.0, -2.0, -2.0], "step": 4.0 / 65535}
    q = np.rint((mesh.positions - np.array(grid["origin"])) / grid["step"]).astype(np.int64)
    base = encode_base(q, mesh.faces, grid, codec="draco")
    assert base.codec == "draco"
    doc = {
        "asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0, "name": "torus"}], "meshes": [{"primitives": [base.primitive]}],
        "accessors": base.accessors, "bufferViews": base.buffer_views,
        "buffers": [{"byteLength": len(base.data)}],
        "extensionsUsed": list(base.extensions_used), "extensionsRequired": list(base.extensions_required),
    }
    src = tmp_path / "draco.glb"
    src.write_bytes(b"".join(glb_parts(doc, [base.data], len(base.data))))
    report = encode_asset(src, tmp_path / "draco.pmw", measure=False)
    assert report.vertices == mesh.vertex_count
    glb, _, _ = decode_asset(tmp_path / "draco.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    out, buffers = load_document(tmp_path / "out.glb")
    prim = out["meshes"][0]["primitives"][0]
    assert "extensions" not in prim and "KHR_draco_mesh_compression" not in out.get("extensionsUsed", [])
    positions = read_accessor(out, buffers, prim["attributes"]["POSITION"])
    assert len(positions) == mesh.vertex_count
    assert np.abs(np.sort(positions, axis=0) - np.sort(mesh.positions, axis=0)).max() < 1e-3


@pytest.mark.parametrize("nodes, placed", [
    ([{"mesh": 0}], False),
    ([{"mesh": 0, "translation": [0, 0, 0], "scale": [1, 1, 1]}], False),
    ([{"mesh": 0, "translation": [10, 0, 0]}], True),
    ([{"children": [1], "rotation": [0, 0, 0.7071068, 0.7071068]}, {"mesh": 0}], True),  # a parent moves it
    ([{"mesh": 0}, {"mesh": 0}], True),  # one mesh shown twice
    ([{"mesh": 0}, {"mesh": 1}], False),
    ([{"children": [0], "mesh": 0}], False),  # a cycle (invalid glTF): walked once, no hang
    ([{"mesh": 0, "extensions": {"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": 0}}}}], True),
])
def test_placed_by_nodes_tells_transforms_and_instances_apart(nodes, placed):
    from pmwm_codec.format.gltf import placed_by_nodes

    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": nodes}
    if len(nodes) == 2 and "children" not in nodes[0]:
        doc["scenes"][0]["nodes"] = [0, 1]
    assert placed_by_nodes(doc) is placed


@pytest.mark.parametrize("noisy", [False, True], ids=["equal-copies", "copies-a-float32-step-apart"])
@pytest.mark.parametrize("one_mesh", [True, False], ids=["one-mesh", "one-mesh-each"])
def test_primitives_that_share_positions_share_one_grid_and_decode_without_a_crack(tmp_path, one_mesh, noisy):
    """A surface cut into primitives (its cut borders in both) decodes watertight: the parts share one grid,
    so a border position is one grid point in each and comes back as one float32 (on grids of their own,
    the copies came back up to a grid step apart: a crack along every cut).  A primitive sharing no
    position keeps a grid of its own bounding box.  ``noisy``: the middle part's copy of every position is
    written one float32 step away, as an exporter's float noise leaves a border: the parts still share one
    grid and each border position still decodes to one float32 (the parts used to get grids of their own,
    and all 94 copies of the first border decoded apart, up to about a grid step)."""
    from pmwm_codec.constants import EXTENSION_NAME
    from pmwm_codec.format.reader import read_header

    blob = shapes.icosphere(4, 1.0, noise=0.03, seed=3)
    blob = shapes.Mesh(blob.positions.astype(np.float32).astype(np.float64), blob.faces)
    x = blob.positions[blob.faces].mean(1)[:, 0]
    b = DocBuilder()
    prims = []
    for k, rows in enumerate((x < -0.2, (x >= -0.2) & (x < 0.5), x >= 0.5)):
        used, inverse = np.unique(blob.faces[rows], return_inverse=True)
        stored = blob.positions[used]
        if noisy and k == 1:
            stored = np.nextafter(stored.astype(np.float32), np.float32(np.inf)).astype(np.float64)
        prims.append(b.triangles(shapes.Mesh(stored, inverse.reshape(-1, 3)), uv=False))
    apart = shapes.torus(24, 12)
    prims.append(b.triangles(shapes.Mesh(apart.positions * 0.1 + 5.0, apart.faces), uv=False))
    if one_mesh:
        b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}], meshes=[{"primitives": prims}])
    else:
        b.doc.update(scene=0, scenes=[{"nodes": list(range(4))}], nodes=[{"mesh": i} for i in range(4)],
                     meshes=[{"primitives": [p]} for p in prims])
    (tmp_path / "cut.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "cut.glb", tmp_path / "cut.pmw", measure=False)
    header = read_header((tmp_path / "cut.pmw").read_bytes())
    grids = [prim["extensions"][EXTENSION_NAME]["grid"] for mesh in header.gltf_json["meshes"]
             for prim in mesh["primitives"]]
    assert grids[0] == grids[1] == grids[2] != grids[3]
    assert grids[3]["step"] < grids[0]["step"] / 5  # the small torus (a tenth of the surface) on its own bounding box
    def level(chunks):
        glb, end, _ = decode_asset(tmp_path / "cut.pmw", chunks=chunks)
        (tmp_path / "out.glb").write_bytes(glb)
        doc, buffers = load_document(tmp_path / "out.glb")
        return end, [read_accessor(doc, buffers, p["attributes"]["POSITION"]) for m in doc["meshes"] for p in m["primitives"]]

    end, decoded = level(None)
    surface = np.concatenate(decoded[:3])
    assert len(np.unique(surface, axis=0)) == blob.vertex_count  # every border position decoded once
    # the borders stay in the base, in one glTF mesh or across meshes shown in the same place: no level cracks
    rows = [{tuple(x) for x in d} for d in decoded[:3]]
    borders = [rows[i] & rows[j] for i, j in ((0, 1), (1, 2))]
    assert all(borders)
    for chunks in range(end.chunks_total):
        rows = [{tuple(x) for x in d} for d in level(chunks)[1][:3]]
        assert borders[0] <= rows[0] & rows[1] and borders[1] <= rows[1] & rows[2], chunks


def test_meshes_whose_nodes_place_them_to_meet_keep_their_border_at_every_level(tmp_path):
    """Two halves of a surface, the second stored turned and moved away and put back by its node: their border
    coincides in the scene only, so it is found there and stays in the base; at every level each border vertex
    of one half still has its counterpart in the other within the grids' rounding (on a grid of its own each,
    a few grid steps at most), where coarse levels used to open gaps of tenths of a percent of the diagonal."""
    from scipy.spatial import cKDTree

    from pmwm_codec.format.gltf import place, world_placements

    blob = shapes.icosphere(4, 1.0, noise=0.03, seed=3)
    x = blob.positions[blob.faces].mean(1)[:, 0]
    turn = np.array([[0.0, 0.0, 1.0, 2.0], [0.0, 1.0, 0.0, -1.0], [-1.0, 0.0, 0.0, 0.5], [0.0, 0.0, 0.0, 1.0]])
    b = DocBuilder()
    halves, prims = [], []
    for k, rows in enumerate((x < 0.1, x >= 0.1)):
        used, inverse = np.unique(blob.faces[rows], return_inverse=True)
        halves.append(blob.positions[used])
        stored = blob.positions[used] if k == 0 else place(blob.positions[used], np.linalg.inv(turn))
        prims.append(b.triangles(shapes.Mesh(stored, inverse.reshape(-1, 3)), uv=False))
    b.doc.update(scene=0, scenes=[{"nodes": [0, 1]}], meshes=[{"primitives": [p]} for p in prims],
                 nodes=[{"mesh": 0}, {"mesh": 1, "matrix": turn.T.ravel().tolist()}])
    (tmp_path / "halves.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "halves.glb", tmp_path / "halves.pmw", measure=False)
    border = halves[0][cKDTree(halves[1]).query(halves[0])[0] < 1e-9]
    assert len(border) > 20
    diagonal = np.linalg.norm(blob.positions.max(0) - blob.positions.min(0))
    total = decode_asset(tmp_path / "halves.pmw")[1].chunks_total
    for chunks in range(total + 1):
        (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "halves.pmw", chunks=chunks)[0])
        doc, buffers = load_document(tmp_path / "out.glb")
        frames, _ = world_placements(doc, [0, 1])
        parts = [place(read_accessor(doc, buffers, m["primitives"][0]["attributes"]["POSITION"]).astype(np.float64), f)
                 for m, (f,) in zip(doc["meshes"], frames)]
        for k in range(2):
            gap = cKDTree(parts[1 - k]).query(cKDTree(parts[k]).data[cKDTree(parts[k]).query(border)[1]])[0]
            assert gap.max() < 2e-4 * diagonal, (chunks, k, gap.max() / diagonal)


def test_mesh_placements_compose_each_path_of_node_transforms_as_trimesh_does():
    """World matrix of every showing of a mesh: parent @ child, each node ``matrix`` (column-major) or T R S;
    checked against trimesh's scene graph on the same GLB."""
    import trimesh

    from pmwm_codec.format.document import load_document
    from pmwm_codec.format.gltf import mesh_placements

    b = DocBuilder()
    prim = b.triangles(shapes.icosphere(1), uv=False)
    b.doc.update(scene=0, scenes=[{"nodes": [0, 3]}], meshes=[{"name": "a", "primitives": [prim]}, {"name": "b", "primitives": [dict(prim)]}],
                 nodes=[
                     {"children": [1], "rotation": [0.0, 0.38268343, 0.0, 0.92387953], "translation": [1.0, 2.0, 3.0]},
                     {"children": [2], "scale": [2.0, 2.0, 2.0]},
                     {"mesh": 0, "translation": [0.0, 0.0, 5.0]},
                     {"mesh": 1, "matrix": [1, 0, 0, 0, 0, 0, 3, 0, 0, -1, 0, 0, 4, 5, 6, 1]},
                 ])
    path = b.glb()
    doc = json.loads(json.dumps(b.doc))
    shown = mesh_placements(doc)
    assert [m for m, _ in shown] == [0, 1]
    scene = trimesh.load(trimesh.util.wrap_as_stream(path), file_type="glb")
    expected = {}
    for name in scene.graph.nodes_geometry:
        matrix, geometry = scene.graph[name]
        expected[geometry] = matrix
    assert sorted(expected) and len(expected) == 2
    for (mesh, matrix), name in zip(shown, ("a", "b")):
        assert np.allclose(matrix, expected[name], rtol=0, atol=1e-12), mesh
    assert mesh_placements({"nodes": [{"mesh": 0, "scale": "big"}]}) == [(0, None)]  # malformed: placed, unknown


def test_decoding_an_asset_to_obj_writes_the_scene_as_shown(tmp_path, capsys):
    """OBJ / PLY / STL carry no nodes: a decoded asset is written as its scene shows it, every primitive
    placed by its world matrices (a mesh shown twice is written twice, a mirrored showing keeps its faces
    facing out), the same surface a glTF converter (trimesh) makes of the decoded GLB; the owner layer,
    marked into that scene, reads from the OBJ."""
    import trimesh
    from scipy.spatial import cKDTree

    from pmwm_codec import read_mesh
    from pmwm_codec.cli import main
    from pmwm_codec.verify.owner import owner_of_mesh

    b = DocBuilder()
    sphere, torus = shapes.icosphere(4, noise=0.05, seed=2), shapes.torus(32, 16)
    b.doc.update(scene=0, scenes=[{"nodes": [0, 1, 2]}],
                 nodes=[{"mesh": 0, "scale": [-1.0, 2.0, 1.0], "translation": [0.0, 4.0, 0.0]},  # mirrored, stretched
                        {"mesh": 1, "translation": [3.0, 0.0, 0.0]},
                        {"mesh": 1, "rotation": [0.0, 0.38268343, 0.0, 0.92387953]}],
                 meshes=[{"primitives": [b.triangles(sphere, uv=False)]},
                         {"primitives": [b.triangles(torus, uv=False)]}])
    (tmp_path / "a.glb").write_bytes(b.glb())
    key = WatermarkKey.generate(owner_id=0x0123456789ABCDEF, rng=np.random.default_rng(5))
    key.save(tmp_path / "k.json")
    assert main(["encode", str(tmp_path / "a.glb"), "-o", str(tmp_path / "a.pmw"), "--key", str(tmp_path / "k.json"),
                 "--owner-id", "0123456789abcdef", "-q"]) == 0
    capsys.readouterr()
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / "a.obj"), "--json"]) == 0
    out = capsys.readouterr()
    assert out.err == ""  # placed: nothing to warn about
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / "d.glb"), "-q"]) == 0
    obj = read_mesh(tmp_path / "a.obj")
    scene = trimesh.load(tmp_path / "d.glb", file_type="glb").to_geometry()
    assert obj.vertex_count == len(scene.vertices) and obj.face_count == len(scene.faces)
    report = json.loads(out.out)  # the counts of the file written: the torus twice
    assert (report["vertices"], report["faces"]) == (obj.vertex_count, obj.face_count)
    assert report["vertices"] == sphere.vertex_count + 2 * torus.vertex_count
    for a, b in ((obj.positions, scene.vertices), (scene.vertices, obj.positions)):  # the same points, within float32
        assert cKDTree(a).query(b)[0].max() < 1e-5
    tri = obj.positions[obj.faces]  # every showing is a closed surface facing out: its signed volume is positive
    signed = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    showing = np.repeat(np.arange(3), [sphere.face_count, torus.face_count, torus.face_count])
    assert np.all(np.bincount(showing, weights=signed) > 0)
    assert owner_of_mesh(tmp_path / "a.obj", key).verdict == "present"


@pytest.mark.parametrize("mode", [4, 5, 6])
def test_decoding_to_obj_keeps_the_triangles_the_scene_shows_that_are_not_progressive(tmp_path, capsys, monkeypatch,
                                                                                       mode):
    """A triangle primitive the encoder passes through (here a strip or fan, or plain triangles added to a
    ``.pmw``'s scene) is part of the scene as shown: the OBJ / PLY / STL holds it, placed by its node, as
    the GLB does (it was dropped, so an OBJ of a file with a graft read as the marked mesh alone: outside
    probe).  Standard input too."""
    import io as _io

    from pmwm_codec import read_mesh
    from pmwm_codec.cli import main
    from pmwm_codec.format.glb import split_glb

    b = DocBuilder()
    sphere = shapes.icosphere(3, noise=0.05, seed=2)
    ring = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [0, 2, 0], [1, 2, 0]], np.float32)
    order = {4: [0, 1, 2, 2, 1, 3, 2, 3, 4, 4, 3, 5], 5: [0, 1, 2, 3, 4, 5], 6: [2, 0, 1, 3, 5, 4]}[mode]
    plain = {"attributes": {"POSITION": b.accessor(ring, 5126, "VEC3", 34962, True)},
             "indices": b.accessor(np.array(order, np.uint16), 5123, "SCALAR", 34963), "mode": mode,
             "targets": [{"POSITION": b.accessor(np.zeros_like(ring), 5126, "VEC3", 34962, True)}]}  # passed through
    b.doc.update(scene=0, scenes=[{"nodes": [0, 1]}],
                 nodes=[{"mesh": 0, "translation": [0.0, 3.0, 0.0]}, {"mesh": 1, "translation": [5.0, 0.0, 0.0]}],
                 meshes=[{"primitives": [b.triangles(sphere, uv=False)]}, {"primitives": [plain]}])
    (tmp_path / "a.glb").write_bytes(b.glb())
    assert main(["encode", str(tmp_path / "a.glb"), "-o", str(tmp_path / "a.pmw"), "-q"]) == 0
    gltf, _ = split_glb((tmp_path / "a.pmw").read_bytes(), "a.pmw")
    assert "extensions" not in gltf["meshes"][1]["primitives"][0]  # not progressive
    capsys.readouterr()
    faces = {4: 4, 5: 4, 6: 4}[mode]
    for out in ("a.obj", "a.ply", "a.stl"):
        assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / out), "--json"]) == 0
        report = json.loads(capsys.readouterr().out)
        assert (report["vertices"], report["faces"]) == (sphere.vertex_count + 6, sphere.face_count + faces), out
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / "a2.glb"), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)  # what the GLB stores: every triangle primitive, once
    assert (report["vertices"], report["faces"]) == (sphere.vertex_count + 6, sphere.face_count + faces)
    obj = read_mesh(tmp_path / "a.obj")
    assert np.allclose(obj.positions[sphere.vertex_count:], ring + [5.0, 0.0, 0.0], atol=1e-6)
    tri = obj.positions[obj.faces[sphere.face_count:]]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    assert np.all(normals[:, 2] * np.sign(normals[0, 2]) > 0)  # one winding throughout, as a renderer draws it
    assert np.allclose(obj.positions[: sphere.vertex_count].mean(0), sphere.positions.mean(0) + [0, 3, 0], atol=1e-4)
    monkeypatch.setattr("sys.stdin", _io.TextIOWrapper(_io.BytesIO((tmp_path / "a.pmw").read_bytes())))
    assert main(["decode", "-", "-o", str(tmp_path / "s.obj"), "-q"]) == 0
    assert (tmp_path / "s.obj").read_bytes() == (tmp_path / "a.obj").read_bytes()


def test_decoding_an_asset_whose_placements_do_not_read_to_obj_says_so(tmp_path, capsys):
    """GPU instancing draws a mesh where its accessors say, which the OBJ cannot follow: each primitive
    is written once as stored, and a notice names why."""
    from pmwm_codec import read_mesh
    from pmwm_codec.cli import main

    b = DocBuilder()
    sphere = shapes.icosphere(2)
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], meshes=[{"primitives": [b.triangles(sphere, uv=False)]}],
                 nodes=[{"mesh": 0, "translation": [10.0, 0.0, 0.0], "extensions": {"EXT_mesh_gpu_instancing": {
                     "attributes": {"TRANSLATION": b.accessor(np.zeros((2, 3), np.float32), 5126, "VEC3")}}}}],
                 extensionsUsed=["EXT_mesh_gpu_instancing"])
    (tmp_path / "a.glb").write_bytes(b.glb())
    assert main(["encode", str(tmp_path / "a.glb"), "-o", str(tmp_path / "a.pmw"), "-q"]) == 0
    capsys.readouterr()
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / "a.obj")]) == 0
    err = capsys.readouterr().err
    assert "GPU instancing" in err and "once, as stored" in err
    assert read_mesh(tmp_path / "a.obj").vertex_count == sphere.vertex_count
    assert main(["decode", str(tmp_path / "a.pmw"), "-o", str(tmp_path / "a.glb2.glb")]) == 0
    assert "as stored" not in capsys.readouterr().err  # the GLB keeps the scene


def test_an_asset_cut_before_its_other_meshes_data_is_truncated_as_pmw_cut_says(tmp_path, capsys):
    """A prefix holding the progressive bases but not the data of the document's other meshes (a line strip,
    points) decoded to OBJ, while ``decode_asset`` (``pmw decode -o x.glb``) failed with
    ``glTF: bufferView 0 ends at ..., past the buffer's ... bytes``, as if the file were corrupt."""
    import pmwm_codec
    from pmwm_codec.cli import main
    from pmwm_codec.errors import TruncatedError

    encode_asset(two_mesh_asset(tmp_path), tmp_path / "s.pmw", measure="none")
    data = (tmp_path / "s.pmw").read_bytes()
    lo, hi = 0, len(data)  # the shortest prefix that decodes: the bases are in, the other data is not yet
    while lo < hi:
        mid = (lo + hi) // 2
        try:
            pmwm_codec.decode(data[:mid])
            hi = mid
        except TruncatedError:
            lo = mid + 1
    prefix = data[:lo]
    for read in (pmwm_codec.decode_asset, pmwm_codec.cut):
        with pytest.raises(TruncatedError, match="has not arrived"):
            read(prefix)
    (tmp_path / "p.pmw").write_bytes(prefix)
    assert main(["decode", str(tmp_path / "p.pmw"), "-o", str(tmp_path / "p.glb")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: ") and "has not arrived" in err and len(err.splitlines()) == 1
    assert not (tmp_path / "p.glb").exists()


def test_a_gltf_read_by_load_document_encodes_from_memory_with_its_external_images(tmp_path):
    """README's round trip, ``encode((load_document(path)), ...)``, on a .gltf whose texture is a file beside
    it: the image bytes load_document read from the asset's folder are embedded (they were the JSON copy's
    undoing: "the asset's glTF document is not JSON"); its uri is never opened, and a uri without bytes
    is still refused."""
    from PIL import Image as PILImage

    from pmwm_codec.errors import InputFormatError

    b = DocBuilder()
    prim = {**b.triangles(shapes.icosphere(3, 1.0, noise=0.02)), "material": 0}
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}], meshes=[{"primitives": [prim]}],
                 materials=[{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
                 textures=[{"source": 0}], images=[{"uri": "stripes.png"}],
                 buffers=[{"uri": "scene.bin", "byteLength": b.offset}])
    PILImage.fromarray((np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)).save(tmp_path / "stripes.png")
    (tmp_path / "scene.bin").write_bytes(b"".join(b.parts))
    (tmp_path / "scene.gltf").write_text(json.dumps(b.doc))
    gltf, buffers = load_document(tmp_path / "scene.gltf")
    encode_asset((gltf, buffers), tmp_path / "scene.pmw", measure=False)
    (tmp_path / "stripes.png").unlink()  # the .pmw holds the image: nothing refers to the file any more
    (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "scene.pmw")[0])
    doc, _ = load_document(tmp_path / "out.glb")
    image = doc["images"][0]
    assert "uri" not in image and image["mimeType"] == "image/png"
    del gltf["images"][0]["_bytes"]
    with pytest.raises(InputFormatError, match=r"images\[0\]\.uri 'stripes.png' names a file"):
        encode_asset((gltf, buffers), tmp_path / "again.pmw", measure=False)
    assert not (tmp_path / "again.pmw").exists()


@pytest.mark.parametrize("stripped", [0, 1])
def test_a_primitive_whose_watermark_object_was_stripped_makes_the_file_not_authentic(tmp_path, capsys, stripped):
    """One watermark covers every progressive primitive, each repeating its public parameters (spec README,
    "Watermark over several primitives"): with one primitive's object stripped the others are still read
    (verify refused the file with "every edge has zero length" when the second lost it, and said the file
    carried no watermark when the first did), and the changed primitive fails its base MAC."""
    from pmwm_codec.cli import main
    from pmwm_codec.constants import EXTENSION_NAME
    from pmwm_codec.format.glb import split_glb

    src = two_mesh_asset(tmp_path)
    key = WatermarkKey.generate(rng=np.random.default_rng(5))
    mark = (np.indices((16, 16)).sum(0) % 2 * 200 + 30).astype(np.uint8)
    encode_asset(src, tmp_path / "scene.pmw", watermark=mark, key=key, measure=False).key.save(tmp_path / "scene.pmw.key.json")
    gltf, binary = split_glb((tmp_path / "scene.pmw").read_bytes())
    exts = [p["extensions"][EXTENSION_NAME] for m in gltf["meshes"] for p in m["primitives"] if "extensions" in p]
    assert len(exts) == 2 and all("watermark" in e for e in exts)
    exts[stripped].pop("watermark")
    (tmp_path / "stripped.pmw").write_bytes(b"".join(glb_parts(gltf, [binary], len(binary))))
    capsys.readouterr()
    for name, verdict, status in (("scene.pmw", "authentic", 0), ("stripped.pmw", "not-authentic", 1)):
        assert main(["verify", str(tmp_path / name), "--key", str(tmp_path / "scene.pmw.key.json"), "--json"]) == status
        out = json.loads(capsys.readouterr().out)
        assert out["verdict"] == verdict and out["key_matches"] is True
        assert out["codes_read"] > 0  # the primitive that kept its object is read
        assert len(out["mac"]["failed"]) == (name == "stripped.pmw")  # the stripped primitive's base
    assert main(["decode", str(tmp_path / "stripped.pmw"), "-o", str(tmp_path / "stripped.glb")]) == 0


def _quantized_asset(path, with_line: bool):
    """A sphere whose POSITION is a normalized SHORT VEC3 (KHR_mesh_quantization, required; a node scale places
    it), and with ``with_line`` a LINES primitive on the same quantized positions, which passes through."""
    b = DocBuilder()
    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    q = np.round(mesh.positions / np.abs(mesh.positions).max() * 32767).astype(np.int16)
    acc = b.accessor(np.concatenate([q, np.zeros((len(q), 1), np.int16)], 1), 5122, "VEC3", 34962)
    b.doc["accessors"][acc].update(normalized=True, min=[int(x) for x in q.min(0)], max=[int(x) for x in q.max(0)])
    b.doc["bufferViews"][b.doc["accessors"][acc]["bufferView"]]["byteStride"] = 8
    prims = [{"attributes": {"POSITION": acc},
              "indices": b.accessor(mesh.faces.astype(np.uint32).ravel(), 5125, "SCALAR", 34963)}]
    if with_line:
        prims.append({"attributes": {"POSITION": acc}, "mode": 1,
                      "indices": b.accessor(np.arange(8, dtype=np.uint16), 5123, "SCALAR", 34963)})
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0, "scale": [2.0, 2.0, 2.0]}],
                 meshes=[{"primitives": prims}], extensionsUsed=["KHR_mesh_quantization"],
                 extensionsRequired=["KHR_mesh_quantization"])
    path.write_bytes(b.glb())


@pytest.mark.parametrize("with_line", [False, True])
def test_a_decoded_level_requires_mesh_quantization_only_where_an_accessor_still_needs_it(tmp_path, with_line):
    """A decoded level writes progressive primitives as FLOAT: a quantized input's level required
    KHR_mesh_quantization all the same, so a viewer without it refused a file that needs nothing of it. A
    primitive passed through as stored (a LINES one on the quantized positions) still needs it."""
    _quantized_asset(tmp_path / "q.glb", with_line)
    encode_asset(tmp_path / "q.glb", tmp_path / "q.pmw", measure=False)
    pmw = sniff_json(tmp_path / "q.pmw")  # the .pmw's base too: written FLOAT (or Draco), it needs nothing of it
    for key in ("extensionsUsed", "extensionsRequired"):
        assert ("KHR_mesh_quantization" in pmw.get(key, [])) == with_line
    for chunks in (0, None):
        (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "q.pmw", chunks=chunks)[0])
        doc, _ = load_document(tmp_path / "out.glb")
        for key in ("extensionsUsed", "extensionsRequired"):
            assert ("KHR_mesh_quantization" in doc.get(key, [])) == with_line
        result = check(tmp_path / "out.glb")
        assert result["validator"]["errors"] == 0 and result["three"]["ok"]
