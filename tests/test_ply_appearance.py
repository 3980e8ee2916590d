"""A PLY's appearance (pmwm_codec.ply.read_appearance, pmwm_codec.meshdoc.ply_document): vertex colours, texture
coordinates per vertex or per face corner, MeshLab's TextureFile textures ride with the splits; a PLY of geometry
alone is read as before (the same bytes)."""

from __future__ import annotations

import io
import os

import numpy as np
import pygltflib
import pytest
from hypothesis import given, settings, strategies as st
from PIL import Image
from scipy.spatial import cKDTree

import pmwm_codec
from pmwm_codec import ply, shapes
from pmwm_codec.cli import main
from pmwm_codec.errors import InputFormatError
from pmwm_codec.format.document import load_document
from pmwm_codec.mesh import read_mesh
from pmwm_codec.meshdoc import linear_from_srgb, srgb_from_linear

from samples import icosphere
from test_asset import _seam_cracks
from test_ply import mutations

FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")
SCALAR = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4", "uint": "u4",
          "float": "f4", "double": "f8"}


def ply_bytes(fmt: str, vertex: list, face: list, comments=()) -> bytes:
    """A PLY file: ``vertex`` and ``face`` [(name, type, values)] -- a scalar's values (count,), a list's
    ``type`` ``"list uchar int"`` and its values (count, k)."""
    head = ["ply", f"format {fmt} 1.0", *[f"comment {c}" for c in comments]]
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    out = []
    for element, props in (("vertex", vertex), ("face", face)):
        head.append(f"element {element} {len(props[0][2])}")
        fields, columns = [], []
        for name, kind, values in props:
            head.append(f"property {kind} {name}")
            words = kind.split()
            values = np.asarray(values)
            if words[0] == "list":
                fields += [(f"n_{name}", SCALAR[words[1]]), (name, SCALAR[words[2]], values.shape[1:])]
                columns += [np.full(len(values), values.shape[1]), values]
            else:
                fields.append((name, SCALAR[kind]))
                columns.append(values)
        if order is None:
            rows = [" ".join(_text(c, f[1]) for c, f in zip(cols, fields)) for cols in zip(*columns)]
            out.append(("\n".join(rows) + "\n").encode())
        else:
            records = np.zeros(len(columns[0]), [(f[0], order + f[1], *f[2:]) for f in fields])
            for f, c in zip(fields, columns):
                records[f[0]] = c
            out.append(records.tobytes())
    return ("\n".join(head) + "\nend_header\n").encode() + b"".join(out)


def _text(value, kind: str) -> str:
    values = np.atleast_1d(value)
    if kind[0] == "f":
        digits = 9 if kind == "f4" else 17
        return " ".join(f"{float(v):.{digits}g}" for v in values)
    return " ".join(str(int(v)) for v in values)


def xyz(positions) -> list:
    return [(axis, "float", positions[:, i]) for i, axis in enumerate("xyz")]


def corners(faces) -> list:
    return [("vertex_indices", "list uchar int", faces)]


def sphere():
    positions, faces = icosphere(2)
    return positions.astype(np.float32).astype(np.float64), faces


def encoded(path, **options) -> tuple:
    """``(.pmw bytes, report)`` of ``pmwm_codec.encode(path)``."""
    out = io.BytesIO()
    report = pmwm_codec.encode(path, out, measure="none", **options)
    return out.getvalue(), report


def primitives(pmw: bytes, chunks=None) -> list:
    """The decoded GLB's primitives as ``(attributes {semantic: array}, faces (m, 3), gltf material or None)``,
    read back with pygltflib."""
    gltf = pygltflib.GLTF2.load_from_bytes(pmwm_codec.decode_asset(pmw, chunks))
    blob = gltf.binary_blob()

    def array(index):
        acc = gltf.accessors[index]
        view = gltf.bufferViews[acc.bufferView]
        kind = {5126: np.float32, 5125: np.uint32, 5123: np.uint16, 5121: np.uint8}[acc.componentType]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[acc.type]
        start = (view.byteOffset or 0) + (acc.byteOffset or 0)
        return np.frombuffer(blob, kind, acc.count * width, start).reshape(acc.count, width)

    out = []
    for prim in gltf.meshes[0].primitives:
        attrs = {k: array(v) for k, v in vars(prim.attributes).items() if isinstance(v, int)}
        material = None if prim.material is None else gltf.materials[prim.material]
        out.append((attrs, array(prim.indices).reshape(-1, 3).astype(np.int64), material, gltf))
    return out


def assert_same_vertices(expected: dict, decoded: dict, tolerance: dict):
    """Every expected vertex (a row of ``expected``'s arrays) has a decoded one and every decoded vertex an
    expected one, each column within its semantic's ``tolerance`` (Chebyshev), as many of each."""
    assert set(decoded) == set(expected)
    names = sorted(expected)
    a = np.concatenate([np.asarray(expected[k], np.float64) / tolerance[k] for k in names], axis=1)
    b = np.concatenate([np.asarray(decoded[k], np.float64) / tolerance[k] for k in names], axis=1)
    assert len(np.unique(a, axis=0)) == len(b)
    for x, y in ((a, b), (b, a)):
        dist, _ = cKDTree(y).query(x, p=np.inf)
        assert dist.max() <= 1.0, dist.max()


def position_step(positions) -> float:
    return float(np.ptp(positions, axis=0).max() / (2 ** 16 - 1))


#: TEXCOORD_0's error: under half its step of at most 2^-13, plus float32's rounding near 1.
UV_TOLERANCE = 2.0 ** -14 + 2e-7
#: COLOR_0's: half a step of 12 bits over [0, 1].
COLOUR_TOLERANCE = 0.5 / 4095 + 1e-6

COLOUR_TYPES = {"uchar": 255, "ushort": 65535, "float": None, "double": None}


@settings(max_examples=15, deadline=None)
@given(fmt=st.sampled_from(FORMATS), kind=st.sampled_from(sorted(COLOUR_TYPES)), spelling=st.integers(0, 2),
       alpha=st.booleans(), uv_spelling=st.integers(0, 3), uv_kind=st.sampled_from(["float", "double"]),
       normals=st.booleans(), seed=st.integers(0, 99))
def test_vertex_colours_and_texture_coordinates_round_trip_in_every_format_and_type(
        tmp_path_factory, fmt, kind, spelling, alpha, uv_spelling, uv_kind, normals, seed):
    from pmwm_codec.ply import COLOUR_NAMES, NORMAL_NAMES, UV_NAMES

    rng = np.random.default_rng(seed)
    positions, faces = sphere()
    n = len(positions)
    channels = 4 if alpha else 3
    scale = COLOUR_TYPES[kind]
    if scale is None:
        raw = rng.uniform(-0.25, 1.25, (n, channels))  # clamped to [0, 1]
        raw = raw.astype(np.float32).astype(np.float64) if kind == "float" else raw
        colours = np.clip(raw, 0.0, 1.0)
    else:
        raw = rng.integers(0, scale + 1, (n, channels))
        colours = raw / scale
    uv = rng.uniform(-0.5, 1.5, (n, 2))
    uv = uv.astype(np.float32).astype(np.float64) if uv_kind == "float" else uv
    vertex = xyz(positions)
    vertex += [(name, kind, raw[:, i]) for i, name in enumerate(COLOUR_NAMES[spelling][:channels])]
    vertex += [(name, uv_kind, uv[:, i]) for i, name in enumerate(UV_NAMES[uv_spelling])]
    if normals:
        unit = positions - positions.mean(axis=0)
        vertex += [(name, "float", (unit / np.linalg.norm(unit, axis=1, keepdims=True))[:, i])
                   for i, name in enumerate(NORMAL_NAMES)]
    path = tmp_path_factory.mktemp("ply") / "m.ply"
    path.write_bytes(ply_bytes(fmt, vertex, corners(faces)))
    pmw, report = encoded(path)
    [(attrs, tris, material, _)] = primitives(pmw)
    assert material is None and ("NORMAL" in attrs) == normals and len(tris) == len(faces)
    attrs.pop("NORMAL", None)
    expected = {"POSITION": positions, "COLOR_0": linear_from_srgb(colours),  # a PLY's colours are sRGB-encoded
                "TEXCOORD_0": np.stack([uv[:, 0], 1 - uv[:, 1]], 1)}
    assert_same_vertices(expected, attrs, {"POSITION": position_step(positions), "COLOR_0": COLOUR_TOLERANCE,
                                           "TEXCOORD_0": UV_TOLERANCE})
    if kind == "uchar":  # 8-bit colours come back exact, sRGB-encoded again
        tree = cKDTree(positions)
        _, nearest = tree.query(attrs["POSITION"])
        assert np.array_equal(np.rint(srgb_from_linear(attrs["COLOR_0"].astype(np.float64)) * 255), raw[nearest])


def seamed_sphere():
    """A sphere whose texture coordinates (longitude, latitude) are per face corner, with a seam where the
    longitude wraps: ``(positions, faces, (m, 3, 2) uv)``."""
    positions, faces = sphere()
    centred = positions - positions.mean(axis=0)
    u = np.arctan2(centred[:, 1], centred[:, 0]) / (2 * np.pi) + 0.5
    v = np.arccos(np.clip(centred[:, 2] / np.linalg.norm(centred, axis=1), -1, 1)) / np.pi
    uv = np.stack([u[faces], v[faces]], axis=2)
    wraps = uv[:, :, 0].max(axis=1) - uv[:, :, 0].min(axis=1) > 0.5
    uv[:, :, 0] += wraps[:, None] & (uv[:, :, 0] < 0.5)
    return positions, faces, uv


@pytest.mark.parametrize("fmt", FORMATS)
def test_per_corner_texture_coordinates_make_seams_that_never_crack(tmp_path, fmt):
    positions, faces, uv = seamed_sphere()
    path = tmp_path / "m.ply"
    path.write_bytes(ply_bytes(fmt, xyz(positions), corners(faces) + [("texcoord", "list uchar float",
                                                                       uv.reshape(len(faces), 6))]))
    pmw, report = encoded(path)
    chunks = pmwm_codec.inspect(pmw)["chunks"]
    [(attrs, tris, _, _)] = primitives(pmw)
    pairs = np.concatenate([positions[faces].reshape(-1, 3), uv.reshape(-1, 2)], axis=1)
    distinct = np.unique(pairs.astype(np.float32), axis=0).astype(np.float64)
    assert len(distinct) > len(positions)  # the seam's vertices, one a side
    expected = {"POSITION": distinct[:, :3], "TEXCOORD_0": np.stack([distinct[:, 3], 1 - distinct[:, 4]], 1)}
    assert_same_vertices(expected, attrs, {"POSITION": position_step(positions), "TEXCOORD_0": UV_TOLERANCE})
    for level in sorted({0, 1, len(chunks) // 2, len(chunks)}):
        (tmp_path / "x.glb").write_bytes(pmwm_codec.decode_asset(pmw, level))
        assert _seam_cracks(*load_document(tmp_path / "x.glb"), 0, 0) == 0


def test_meshlab_textures_one_primitive_each_by_texnumber_png_kept_bmp_rewritten(tmp_path):
    positions, faces, uv = seamed_sphere()
    Image.new("RGB", (8, 8), (200, 10, 10)).save(tmp_path / "red.png")
    Image.new("RGB", (4, 4), (10, 10, 200)).save(tmp_path / "blue.bmp")
    texnumber = (positions[faces[:, 0], 2] > positions[:, 2].mean()).astype(np.int64)
    data = ply_bytes("binary_little_endian", xyz(positions), corners(faces) + [
        ("texcoord", "list uchar float", uv.reshape(len(faces), 6)), ("texnumber", "int", texnumber)],
        comments=["VCGLIB generated", "TextureFile red.png", "TextureFile blue.bmp"])
    (tmp_path / "m.ply").write_bytes(data)
    pmw, report = encoded(tmp_path / "m.ply")
    assert any("'blue.bmp' re-written as PNG" in n for n in report["notices"])
    prims = primitives(pmw)
    assert sorted(len(p[1]) for p in prims) == sorted(np.bincount(texnumber).tolist())
    gltf = prims[0][3]
    blob = gltf.binary_blob()
    images = [blob[gltf.bufferViews[im.bufferView].byteOffset or 0:][:gltf.bufferViews[im.bufferView].byteLength]
              for im in gltf.images]
    assert images[0] == (tmp_path / "red.png").read_bytes() and images[1][:8] == b"\x89PNG\r\n\x1a\n"
    assert [im.mimeType for im in gltf.images] == ["image/png", "image/png"]
    for attrs, tris, material, _ in prims:
        assert "TEXCOORD_0" in attrs and material.pbrMetallicRoughness.baseColorTexture is not None
        texture = gltf.textures[material.pbrMetallicRoughness.baseColorTexture.index].source
        assert material.name == ("red", "blue")[texture]


@pytest.mark.parametrize("ref", ["../x.png", "/abs/x.png", "link.png"], ids=["dot-dot", "absolute", "symlink"])
def test_a_texture_outside_the_folder_is_never_read_and_left_out_with_a_notice(tmp_path, capsys, ref):
    inside = tmp_path / "in"
    inside.mkdir()
    Image.new("RGB", (2, 2)).save(tmp_path / "x.png")
    os.symlink(tmp_path / "x.png", inside / "link.png")
    ref = ref.replace("/abs", str(tmp_path))
    positions, faces, uv = seamed_sphere()
    (inside / "m.ply").write_bytes(ply_bytes("ascii", xyz(positions), corners(faces) + [
        ("texcoord", "list uchar float", uv.reshape(len(faces), 6))], comments=[f"TextureFile {ref}"]))
    code = main(["encode", str(inside / "m.ply"), "-o", str(inside / "m.pmw")])
    out, err = capsys.readouterr()
    assert code == 0 and "note:" not in out, out  # the notes go to stderr, the summary to stdout
    reason = "is an absolute path" if ref.startswith("/") else "leads outside the asset's folder"
    assert f"pmw: note: the texture {ref!r} not read ({reason}" in err and "left out" in err, err
    glb = pmwm_codec.decode_asset(str(inside / "m.pmw"))
    assert (tmp_path / "x.png").read_bytes() not in glb  # never read, never embedded


def test_a_missing_texture_is_left_out_with_a_notice_and_the_texture_coordinates_kept(tmp_path):
    positions, faces = sphere()
    uv = np.random.default_rng(3).random((len(positions), 2))
    (tmp_path / "m.ply").write_bytes(ply_bytes("binary_big_endian", xyz(positions) + [
        ("texture_u", "float", uv[:, 0]), ("texture_v", "float", uv[:, 1])], corners(faces),
        comments=["TextureFile gone.png"]))
    pmw, report = encoded(tmp_path / "m.ply")
    assert "the texture 'gone.png' is not beside m.ply: left out" in report["notices"]
    [(attrs, _, material, _)] = primitives(pmw)
    assert "TEXCOORD_0" in attrs and material.pbrMetallicRoughness.baseColorTexture is None


def test_a_texture_without_texture_coordinates_leaves_the_ply_plain_and_says_so(tmp_path):
    positions, faces = sphere()
    Image.new("RGB", (2, 2)).save(tmp_path / "t.png")
    (tmp_path / "m.ply").write_bytes(ply_bytes("ascii", xyz(positions), corners(faces), ["TextureFile t.png"]))
    pmw, report = encoded(tmp_path / "m.ply")
    assert "the texture 't.png' not carried: the PLY has no texture coordinates" in report["notices"]
    assert pmw == encoded_plain(tmp_path / "m.ply")


def encoded_plain(path) -> bytes:
    out = io.BytesIO()
    pmwm_codec.encode(read_mesh(path), out, measure="none")
    return out.getvalue()


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("extra", ["none", "normals", "red-only"])
def test_a_ply_of_geometry_alone_gives_the_same_bytes_as_before_read_once(tmp_path, monkeypatch, fmt, extra):
    from pmwm_codec import ply

    positions, faces = sphere()
    vertex = xyz(positions)
    if extra == "normals":
        vertex += [(name, "float", positions[:, i]) for i, name in enumerate(("nx", "ny", "nz"))]
    elif extra == "red-only":
        vertex += [("red", "uchar", np.full(len(positions), 7))]
    (tmp_path / "m.ply").write_bytes(ply_bytes(fmt, vertex, corners(faces)))
    reads = []
    parse = ply._parsed_file
    monkeypatch.setattr(ply, "_parsed_file", lambda *a: reads.append(1) or parse(*a))
    pmw, report = encoded(tmp_path / "m.ply")
    assert len(reads) == 1
    assert pmw == encoded_plain(tmp_path / "m.ply")
    said = "normals (nx, ny, nz) not carried: the .pmw holds positions, and viewers shade it from them"
    assert (said in report["notices"]) == (extra == "normals")


def test_an_appearance_ply_is_read_once_too(tmp_path, monkeypatch):
    from pmwm_codec import ply

    positions, faces = sphere()
    (tmp_path / "m.ply").write_bytes(ply_bytes("ascii", xyz(positions) + [
        (c, "uchar", np.arange(len(positions)) % 256) for c in ("r", "g", "b")], corners(faces)))
    reads = []
    parse = ply._parsed_file
    monkeypatch.setattr(ply, "_parsed_file", lambda *a: reads.append(1) or parse(*a))
    encoded(tmp_path / "m.ply")
    assert len(reads) == 1


def test_strips_and_polygons_with_corner_texture_coordinates(tmp_path):
    """MeshLab's quads (a texcoord list of eight values) fan as their corners do; a strip's triangles, which
    carry none, are given (0, 0) and the encoder says so."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0]], np.float64)
    header = ("ply\nformat ascii 1.0\nelement vertex 6\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nproperty list uchar float texcoord\n"
              "element tristrips 1\nproperty list int int vertex_indices\nend_header\n")
    body = "".join(f"{x:g} {y:g} {z:g}\n" for x, y, z in positions)
    body += "4 0 1 2 3 8 0 0 0.5 0 0.5 0.5 0 0.5\n4 1 4 2 5\n"
    (tmp_path / "m.ply").write_bytes((header + body).encode())
    from pmwm_codec.meshdoc import ply_document

    (gltf, buffers), notices = ply_document(tmp_path / "m.ply", (tmp_path / "m.ply").read_bytes())
    assert "6 corners of the faces of no material name no texture coordinate: given (0, 0)" in notices
    from pmwm_codec.format.document import read_accessor

    prim = gltf["meshes"][0]["primitives"][0]
    pos = read_accessor(gltf, buffers, prim["attributes"]["POSITION"])
    uv = read_accessor(gltf, buffers, prim["attributes"]["TEXCOORD_0"])
    tris = read_accessor(gltf, buffers, prim["indices"]).reshape(-1, 3)
    assert len(tris) == 4
    quad = [[(tuple(pos[i]), tuple(uv[i])) for i in t] for t in tris[:2]]
    assert quad[0] == [((0, 0, 0), (0, 1)), ((1, 0, 0), (0.5, 1)), ((1, 1, 0), (0.5, 0.5))]
    assert quad[1] == [((0, 0, 0), (0, 1)), ((1, 1, 0), (0.5, 0.5)), ((0, 1, 0), (0, 0.5))]


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_texcoord_list_not_two_values_a_corner_is_refused_in_one_line(tmp_path, fmt):
    from pmwm_codec.ply import read_appearance

    positions, faces = sphere()
    data = ply_bytes(fmt, xyz(positions), corners(faces) + [
        ("texcoord", "list uchar float", np.zeros((len(faces), 4)))])
    with pytest.raises(InputFormatError) as err:
        read_appearance(data, "bad.ply", 10 ** 6)
    assert str(err.value) == "bad.ply: PLY face 0 has 4 texcoord values for its 3 corners (two a corner)"


def test_a_coloured_point_cloud_is_named_as_before(tmp_path):
    from pmwm_codec.errors import MeshError

    positions, _ = sphere()
    data = ply_bytes("ascii", xyz(positions) + [(c, "uchar", np.zeros(len(positions))) for c in ("red", "green", "blue")],
                     [("vertex_indices", "list uchar int", np.zeros((0, 3)))])
    (tmp_path / "p.ply").write_bytes(data)
    with pytest.raises(MeshError, match="a point cloud"):
        encoded(tmp_path / "p.ply")


def test_a_large_coloured_textured_ply_reads_into_one_vertex_per_ply_vertex():
    """A 40,962-vertex coloured mesh with a texture coordinate per vertex: one glTF vertex each, its colour and
    coordinate its own (how fast it reads is the README's measure, not a test's)."""
    from pmwm_codec.format.document import read_accessor
    from pmwm_codec.meshdoc import ply_document

    mesh = shapes.icosphere(6, 1.0)
    n = len(mesh.positions)
    rng = np.random.default_rng(0)
    rng_values = {c: rng.integers(0, 256, n) for c in ("red", "green", "blue")}
    rng_values.update(s=rng.random(n).astype(np.float32), t=rng.random(n).astype(np.float32))
    data = ply_bytes("binary_little_endian", xyz(mesh.positions) + [
        (c, "uchar", rng_values[c]) for c in ("red", "green", "blue")] + [
        ("s", "float", rng_values["s"]), ("t", "float", rng_values["t"])], corners(mesh.faces))
    (gltf, buffers), notices = ply_document("m.ply", data)
    assert notices == [] and gltf["accessors"][0]["count"] == n
    attrs = gltf["meshes"][0]["primitives"][0]["attributes"]
    pos, rgb, uv = (read_accessor(gltf, buffers, attrs[k]) for k in ("POSITION", "COLOR_0", "TEXCOORD_0"))
    order = np.lexsort(mesh.positions.astype(np.float32).T[::-1])
    got = np.lexsort(pos.T[::-1])
    assert np.array_equal(pos[got], mesh.positions.astype(np.float32)[order])
    want_rgb = linear_from_srgb(np.stack([rng_values[c] for c in ("red", "green", "blue")], axis=1) / 255.0)
    assert np.abs(rgb[got] - want_rgb[order]).max() < 1e-6
    assert np.abs(uv[got] - np.stack([rng_values["s"], 1 - rng_values["t"]], axis=1)[order]).max() < 1e-6


@settings(max_examples=200, deadline=None)
@given(rows=st.integers(1, 300), high=st.sampled_from([2, 40, 10 ** 6, 2 ** 20]),
       same=st.sampled_from([(), (1,), (2,), (1, 2)]), none=st.sampled_from([(), (1,), (2,)]),
       seed=st.integers(0, 2 ** 32 - 1))
def test_corners_made_unique_by_keys_as_numpy_makes_them_by_row(rows, high, same, none, seed):
    """meshdoc._unique_corners (a PLY's texture coordinates and normals often the vertex's own index) is
    np.unique(axis=0)."""
    from pmwm_codec.meshdoc import _unique_corners

    c = np.random.default_rng(seed).integers(-1, high, (rows, 3))
    c[:, 0] = np.abs(c[:, 0])
    c[:, list(same)] = c[:, :1]
    c[:, list(none)] = -1
    unique, inverse = np.unique(c, axis=0, return_inverse=True)
    mine = _unique_corners(c)
    assert np.array_equal(mine[0], unique) and np.array_equal(mine[1], inverse.reshape(-1))


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("what, says", [
    ("colour", "PLY vertex 5 has a colour float32 cannot carry"),
    ("uv", "PLY vertex 5 has a texture coordinate float32 cannot carry"),
    ("texcoord", "PLY face 3 has a texcoord value float32 cannot carry"),
])
@pytest.mark.parametrize("bad", [np.nan, np.inf, -1e300])
def test_an_attribute_float32_cannot_carry_is_refused_in_one_line_naming_its_record(tmp_path, fmt, what, says, bad):
    positions, faces = sphere()
    n = len(positions)
    values = np.where(np.arange(n) == 5, bad, 0.5)
    vertex, face = xyz(positions), corners(faces)
    if what == "colour":
        vertex += [(c, "double", values) for c in ("red", "green", "blue")]
    elif what == "uv":
        vertex += [("u", "double", values), ("v", "double", np.full(n, 0.5))]
    else:
        wedge = np.full((len(faces), 6), 0.5)
        wedge[3, 4] = bad
        face += [("texcoord", "list uchar double", wedge)]
    (tmp_path / "m.ply").write_bytes(ply_bytes(fmt, vertex, face))
    with pytest.raises(InputFormatError) as err:
        encoded(tmp_path / "m.ply")
    assert str(err.value).startswith(f"m.ply: {says} (NaN, infinite") and "\n" not in str(err.value)


@pytest.mark.parametrize("target", ["red.png", "m.ply"])
def test_the_output_never_replaces_the_texture_a_ply_names(tmp_path, capsys, target):
    from pmwm_codec.meshdoc import named_files

    positions, faces, uv = seamed_sphere()
    Image.new("RGB", (4, 4), (200, 10, 10)).save(tmp_path / "red.png")
    Image.new("RGB", (4, 4)).save(tmp_path.parent / "out.png")
    (tmp_path / "m.ply").write_bytes(ply_bytes("ascii", xyz(positions), corners(faces) + [
        ("texcoord", "list uchar float", uv.reshape(len(faces), 6))],
        comments=["TextureFile red.png", "TextureFile ../out.png", "TextureFile gone.png"]))
    assert named_files(tmp_path / "m.ply") == [os.path.realpath(tmp_path / "red.png")]
    before = (tmp_path / target).read_bytes()
    assert main(["encode", str(tmp_path / "m.ply"), "-o", str(tmp_path / target)]) == 2
    err = capsys.readouterr().err
    assert "is also the input" in err and len(err.splitlines()) == 1
    assert (tmp_path / target).read_bytes() == before


def test_a_ply_without_texture_coordinates_names_no_texture(tmp_path):
    from pmwm_codec.meshdoc import named_files

    positions, faces = sphere()
    Image.new("RGB", (2, 2)).save(tmp_path / "t.png")
    (tmp_path / "m.ply").write_bytes(ply_bytes("binary_little_endian", xyz(positions) + [
        (c, "uchar", np.zeros(len(positions))) for c in "rgb"], corners(faces), ["TextureFile t.png"]))
    assert named_files(tmp_path / "m.ply") == []


def test_mutated_appearance_files_are_read_or_refused_by_name_never_another_error():
    """800 copies of coloured, textured PLY files with bytes changed, cut out, put in or the end cut off: each
    reads (pmwm_codec.ply.read_appearance, then meshdoc.ply_document) or is refused with a PmwError (20,000
    such calls run once by hand found a header naming a property twice, which read_ply's binary records
    failed on, and a signalling NaN's numpy warning: test_ply)."""
    from pmwm_codec.errors import PmwError
    from pmwm_codec.meshdoc import ply_document

    positions = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    vertex = xyz(positions) + [(c, "uchar", [10, 20, 30, 40]) for c in ("red", "green", "blue")] + [
        ("u", "float", [0, 1, 1, 0]), ("v", "float", [0, 0, 1, 1])]
    face = corners(faces) + [("texcoord", "list uchar float", np.arange(12).reshape(2, 6) / 12),
                             ("texnumber", "int", [0, 1])]
    seeds = [ply_bytes(fmt, vertex, face, ["TextureFile a.png", "TextureFile b.png"]) for fmt in FORMATS]
    for data in mutations(seeds, 800, seed=7):
        try:
            ply_document("/nonexistent-folder/f.ply", data)
        except PmwError:
            pass


@pytest.mark.parametrize("vertex_colours", [False, True])
def test_face_colours_are_not_carried_and_the_encoder_says_so(tmp_path, vertex_colours):
    positions, faces = sphere()
    vertex = xyz(positions) + ([(c, "uchar", np.full(len(positions), 9)) for c in "rgb"] if vertex_colours else [])
    face = corners(faces) + [(c, "uchar", np.full(len(faces), 200)) for c in ("red", "green", "blue")]
    (tmp_path / "m.ply").write_bytes(ply_bytes("binary_little_endian", vertex, face))
    pmw, report = encoded(tmp_path / "m.ply")
    assert "the faces' colours not carried (a PLY's vertex colours are)" in report["notices"]
    [(attrs, _, _, _)] = primitives(pmw)
    assert ("COLOR_0" in attrs) == vertex_colours
    if vertex_colours:
        assert np.array_equal(np.rint(srgb_from_linear(attrs["COLOR_0"]) * 255), np.full((len(positions), 3), 9))
    else:
        assert pmw == encoded_plain(tmp_path / "m.ply")


@pytest.mark.parametrize("kind", ["float", "double"])
def test_float_colours_written_in_0_to_255_are_read_over_255_as_an_objs_are(kind):
    positions, faces = sphere()
    rgb = np.random.default_rng(3).integers(0, 256, (len(positions), 3)).astype(np.float64)
    rgb[0] = 255.0  # some channel reaches 2: the file's colours are 0..255
    data = ply_bytes("ascii", xyz(positions) + [(c, kind, rgb[:, i]) for i, c in enumerate(("red", "green", "blue"))],
                     corners(faces))
    got = ply.read_appearance(data, "f.ply", 10 ** 6)
    assert np.abs(got.colours - rgb / 255.0).max() <= 1e-7
    unit = rgb / 255.0 * 0.999 + 0.0005  # 0..1 colours stay as they are
    data = ply_bytes("ascii", xyz(positions) + [(c, kind, unit[:, i]) for i, c in enumerate(("red", "green", "blue"))],
                     corners(faces))
    assert np.abs(ply.read_appearance(data, "f.ply", 10 ** 6).colours - unit).max() <= 1e-7
