"""Attribute precision (outside probe 2, F6): TEXCOORD_n keeps a step of at most 2**-13 of the texture
whatever the coordinates' range (tiled UVs, an outlier), so its error stays under 1/16384 of the texture;
the other semantics keep ATTRIBUTE_BITS over their range; the rule is stated in README and --help."""

from __future__ import annotations

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.cli import build_parser
from pmwm_codec.format.document import load_document, read_accessor
from pmwm_codec.stream.asset import decode_asset, encode_asset
from pmwm_codec.stream.encoder import ATTRIBUTE_BITS, TEXCOORD_STEP_BITS, _attribute_bits, _attribute_grid

from conftest import ROOT
from test_asset import DocBuilder

BOUND = 2.0**-TEXCOORD_STEP_BITS / 2  # 1/16384 of the texture


def _uv_asset(path, uv: np.ndarray, material: dict | None = None):
    """A sphere with ``uv`` (n, 2) float32 as TEXCOORD_0 (n = 642), and ``material`` (a texture at index 0 it
    may name is an image-less one: the encoder reads no pixel)."""
    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    b = DocBuilder()
    attributes = {"POSITION": b.accessor(mesh.positions.astype(np.float32), 5126, "VEC3", 34962, True),
                  "TEXCOORD_0": b.accessor(uv.astype(np.float32), 5126, "VEC2", 34962)}
    indices = b.accessor(mesh.faces.astype(np.uint32).ravel(), 5125, "SCALAR", 34963)
    prim = {"attributes": attributes, "indices": indices}
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}], meshes=[{"primitives": [prim]}])
    if material is not None:
        prim["material"] = 0
        b.doc.update(materials=[material], textures=[{}], extensionsUsed=["KHR_texture_transform"])
    path.write_bytes(b.glb())
    return mesh


def _uv_error(tmp_path, uv, material: dict | None = None) -> tuple:
    """``(largest TEXCOORD_0 error of the full decode, the .pmw's TEXCOORD_0 grid bits)``."""
    mesh = _uv_asset(tmp_path / "uv.glb", uv, material)
    encode_asset(tmp_path / "uv.glb", tmp_path / "uv.pmw", measure=False)
    pmw, _ = load_document(tmp_path / "uv.pmw")
    spec = pmw["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]["attributes"][0]
    glb, _, _ = decode_asset(tmp_path / "uv.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    doc, buffers = load_document(tmp_path / "out.glb")
    prim = doc["meshes"][0]["primitives"][0]
    positions = read_accessor(doc, buffers, prim["attributes"]["POSITION"])
    got = read_accessor(doc, buffers, prim["attributes"]["TEXCOORD_0"])
    from scipy.spatial import cKDTree

    _, vertex = cKDTree(mesh.positions).query(positions)
    return float(np.abs(got - uv.astype(np.float32)[vertex]).max()), spec["bits"]


def test_the_bits_by_semantic_and_range():
    rng = np.random.default_rng(0)
    unit = np.vstack([[0.0, 0.0], [1.0, 1.0], rng.uniform(0, 1, (100, 2))])  # spans exactly 1
    assert _attribute_bits("TEXCOORD_0", unit) == 14  # the usual 0..1: as before
    assert _attribute_bits("TEXCOORD_1", unit * 1.99) == 14  # up to a span of 2
    assert _attribute_bits("TEXCOORD_0", unit * 64) == 20
    assert _attribute_bits("TEXCOORD_0", np.vstack([unit, [[500.0, 500.0]]])) == 22
    assert _attribute_bits("TEXCOORD_0", unit * 1e9) == 30  # capped
    assert _attribute_bits("NORMAL", unit * 64) == 14 and _attribute_bits("COLOR_0", unit) == 12
    assert _attribute_bits("_TEMP", unit * 1e6) == 14
    for span in (0.5, 1.0, 1.99, 64.0, 500.0, 1e4):  # the rule: a step of at most 2**-13
        grid, _ = _attribute_grid("TEXCOORD_0", np.vstack([unit * 0, unit * 0 + span]))
        assert max(grid.step) <= 2.0**-TEXCOORD_STEP_BITS or grid.bits < _attribute_bits("TEXCOORD_0", [[0], [span]])


@pytest.mark.parametrize("scale, outlier", [(64.0, False), (1.0, True)])
def test_tiled_or_outlying_texture_coordinates_keep_a_sixteen_thousandth_of_the_texture(tmp_path, scale, outlier):
    uv = np.random.default_rng(1).uniform(0, 1, (642, 2)) * scale
    if outlier:
        uv[7] = (500.0, 500.0)  # one vertex far out: it coarsened every other vertex's UVs
    error, bits = _uv_error(tmp_path, uv)
    assert error <= BOUND, (error, bits)
    assert bits > 14


@pytest.mark.parametrize("where", ["baseColor", "clearcoat"])
def test_a_texture_a_transform_repeats_keeps_a_sixteen_thousandth_of_the_texture(tmp_path, where):
    """KHR_texture_transform's scale 64 repeats the texture 64 times over UVs of 0..1: the error the texture
    shows is 64 times the coordinates' (on 14 bits it was 2e-3 of the texture, 32 times the bound)."""
    uv = np.random.default_rng(4).uniform(0, 1, (642, 2))
    info = {"index": 0, "extensions": {"KHR_texture_transform": {"scale": [64.0, -64.0], "rotation": 0.5}}}
    material = ({"pbrMetallicRoughness": {"baseColorTexture": info}} if where == "baseColor" else
                {"extensions": {"KHR_materials_clearcoat": {"clearcoatTexture": info}}})
    error, bits = _uv_error(tmp_path, uv, material)
    assert error * 64 <= BOUND, (error, bits)
    assert bits > 14


@pytest.mark.parametrize("scale", [None, "x", [None, "2"], [float("inf"), float("nan")], {"0": 5}])
def test_a_transform_scale_that_is_no_list_of_numbers_widens_nothing_and_breaks_nothing(scale):
    """A malformed ``scale`` (null ended pmw encode in "unexpected TypeError ... a bug of pmw") counts as 1."""
    from pmwm_codec.format.document import texture_scales

    info = {"index": 0, "extensions": {"KHR_texture_transform": {"scale": scale}}}
    gltf = {"materials": [{"pbrMetallicRoughness": {"baseColorTexture": info}}]}
    assert texture_scales(gltf, {"material": 0}) == {}
    info["extensions"]["KHR_texture_transform"]["scale"] = [3, -8.0]
    assert texture_scales(gltf, {"material": 0}) == {"TEXCOORD_0": 8.0}


def test_unit_texture_coordinates_keep_fourteen_bits(tmp_path):
    uv = np.random.default_rng(2).uniform(-0.02, 1.02, (642, 2))  # spot's span: 1.04
    error, bits = _uv_error(tmp_path, uv)
    assert bits == 14 and error <= BOUND


def test_coordinates_float32_cannot_resolve_that_finely_get_the_bits_it_can(tmp_path):
    uv = np.random.default_rng(3).uniform(0, 5000, (642, 2))  # float32 steps of 4.9e-4 near 5000
    grid, _ = _attribute_grid("TEXCOORD_0", uv)  # float64 values: 26 bits (steps of 7.5e-5) would not come back
    assert 14 < grid.bits < 26
    ints = grid.from_float32(uv, "TEXCOORD_0")
    assert np.array_equal(grid.from_float32(grid.to_float32(ints), "TEXCOORD_0"), ints)
    error, bits = _uv_error(tmp_path, uv)  # float32 input: its own values come back (the error is float32's)
    assert error <= BOUND


def test_decoded_normals_stay_within_the_bound_readme_states(tmp_path):
    """NORMAL on the 14-bit grid over [-1, 1] is within half a step (6.1e-5) a component; written back at unit
    length, the renormalization moves a component by up to the error vector's length, sqrt(3) half steps (README:
    "within 1.1e-4"; it said "under 6.2e-5", which decoded normals exceeded: 6.5e-5 on a noisy sphere)."""
    mesh = shapes.icosphere(4, 1.0, noise=0.02)
    b = DocBuilder()
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}], meshes=[{"primitives": [b.triangles(mesh)]}])
    (tmp_path / "n.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "n.glb", tmp_path / "n.pmw", measure=False)
    (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "n.pmw")[0])
    doc, buffers = load_document(tmp_path / "out.glb")
    prim = doc["meshes"][0]["primitives"][0]
    from scipy.spatial import cKDTree

    _, vertex = cKDTree(mesh.positions).query(read_accessor(doc, buffers, prim["attributes"]["POSITION"]))
    want = (mesh.positions / np.linalg.norm(mesh.positions, axis=1, keepdims=True)).astype(np.float32)[vertex]
    error = float(np.abs(read_accessor(doc, buffers, prim["attributes"]["NORMAL"]) - want).max())
    half_step = 2.0 / ((1 << ATTRIBUTE_BITS["NORMAL"]) - 1) / 2
    assert error <= np.sqrt(3) * half_step + 1e-6 < 1.1e-4, error
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert "NORMAL and TANGENT 14 bits (error under 6.2e-5 on the grid; written back at unit length, a component within 1.1e-4" in readme


def test_the_precision_is_stated_in_help_and_readme():
    parser = build_parser()
    encode = parser._subparsers._group_actions[0].choices["encode"]
    text = " ".join(encode.format_help().split())
    assert "TEXCOORD_n a step of at most 1/8192" in text and "COLOR_n 12" in text and "integer attributes" in text
    readme = " ".join((ROOT / "README.md").read_text().split())
    assert "TEXCOORD_n a step of at most 2^-13" in readme and "`ATTRIBUTE_BITS`" in readme


def test_eight_bit_colours_ride_exactly_on_their_own_lattice_and_others_on_twelve_bits(tmp_path):
    """A normalized UNSIGNED_BYTE COLOR_0 (k / 255) gets the 8-bit lattice (step 1/255 from its least value,
    bits for its span) and comes back as the same float32; colours off that lattice keep 12 bits."""
    rng = np.random.default_rng(5)
    k = rng.integers(20, 200, (642, 4))
    byte_colours = (k / np.float32(255)).astype(np.float32).astype(np.float64)
    grid, extra = _attribute_grid("COLOR_0", byte_colours)
    assert extra == {} and grid.bits == 8 and grid.step == (1 / 255,) * 4
    assert grid.origin == tuple(float(x) / 255 for x in k.min(axis=0))
    assert np.array_equal(grid.to_float32(grid.from_float32(byte_colours, "COLOR_0")), byte_colours.astype(np.float32))
    assert _attribute_grid("COLOR_0", rng.random((642, 3)))[0].bits == 12
    assert _attribute_grid("COLOR_0", byte_colours * 0.5 + 1e-4)[0].bits == 12  # near, not on, the lattice

    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    b = DocBuilder()
    attributes = {"POSITION": b.accessor(mesh.positions.astype(np.float32), 5126, "VEC3", 34962, True),
                  "COLOR_0": b.accessor(k.astype(np.uint8), 5121, "VEC4", 34962)}
    b.doc["accessors"][attributes["COLOR_0"]]["normalized"] = True
    indices = b.accessor(mesh.faces.astype(np.uint32).ravel(), 5125, "SCALAR", 34963)
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}],
                 meshes=[{"primitives": [{"attributes": attributes, "indices": indices}]}])
    (tmp_path / "c.glb").write_bytes(b.glb())
    encode_asset(tmp_path / "c.glb", tmp_path / "c.pmw", measure=False)
    (tmp_path / "out.glb").write_bytes(decode_asset(str(tmp_path / "c.pmw"))[0])
    out, buffers = load_document(tmp_path / "out.glb")
    prim = out["meshes"][0]["primitives"][0]["attributes"]
    got = read_accessor(out, buffers, prim["COLOR_0"])
    pos = read_accessor(out, buffers, prim["POSITION"])
    from scipy.spatial import cKDTree

    distance, source = cKDTree(mesh.positions).query(pos)  # each decoded vertex's input vertex (grid: ~2.5e-5)
    assert distance.max() < 1e-3 and len(np.unique(source)) == len(k)
    assert np.array_equal(got, (k[source] / np.float32(255)).astype(np.float32))  # the input's float32, exactly


def test_srgb_colours_decoded_to_linear_ride_exactly_on_their_byte_grid():
    """COLOR_0 values that are 8-bit sRGB colours decoded to linear (a PLY's or an OBJ's, meshdoc.linear_from_srgb)
    get the ``srgb8`` grid: bytes from each component's least, bits for the span, the same float32 back (alpha on
    k / 255); values near but off those float32 keep 12 bits; a stored value off the table, or a byte a split
    would put outside 0..255, is a format error."""
    from pmwm_codec.errors import FormatError
    from pmwm_codec.meshdoc import linear_from_srgb
    from pmwm_codec.progressive.grid import SRGB8_TO_LINEAR, AttributeGrid

    rng = np.random.default_rng(8)
    k = rng.integers(30, 150, (500, 4))
    colours = linear_from_srgb(k / 255.0)
    grid, extra = _attribute_grid("COLOR_0", colours)
    assert extra == {} and grid.transfer == "srgb8" and grid.bits == 8 and grid.step == (1.0,) * 4  # 8 at least
    assert grid.origin == tuple(float(x) for x in k.min(axis=0))
    ints = grid.from_float32(colours, "COLOR_0")
    assert np.array_equal(ints, k - k.min(axis=0))
    assert np.array_equal(grid.to_float32(ints), colours.astype(np.float32))
    assert np.array_equal(grid.to_float32(ints)[:, :3], SRGB8_TO_LINEAR[k[:, :3]])
    assert AttributeGrid.from_config({"semantic": "COLOR_0", **grid.get_config()}) == grid
    assert _attribute_grid("COLOR_0", colours * (1 - 1e-5))[0].transfer is None  # near, not on, the table
    assert _attribute_grid("COLOR_0", colours * (1 - 1e-5))[0].bits == 12
    with pytest.raises(FormatError, match="not the 8-bit sRGB colours"):
        grid.from_float32(colours.astype(np.float32) * np.float32(1.0001), "COLOR_0")
    with pytest.raises(FormatError, match="outside 0..255"):
        grid.to_float32(np.full((1, 4), 255, np.int64))
    for bad in ({"transfer": "gamma"}, {"origin": [0.5, 0, 0, 0]}, {"step": [2, 1, 1, 1]}, {"semantic": "NORMAL"}):
        with pytest.raises(FormatError):
            AttributeGrid.from_config({"semantic": "COLOR_0", **grid.get_config(), **bad})
