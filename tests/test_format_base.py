"""Base-mesh codec: plain and Draco primitives give back the exact grid integers."""

import json

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmwm_codec.constants import MAX_VERTICES
from pmwm_codec.errors import FormatError, LimitError
from pmwm_codec.format import base as basecodec
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.progressive.topology import same_face_set
from samples import ICOSPHERE_CENTRE, ICOSPHERE_RADIUS, icosphere, to_grid


def _gltf_of(enc):
    """A minimal glTF dict around an EncodedBase (what decode_base reads)."""
    prim = json.loads(json.dumps(enc.primitive))
    return {"accessors": enc.accessors, "bufferViews": enc.buffer_views, "meshes": [{"primitives": [prim]}]}, prim


@pytest.fixture(scope="module")
def mesh():
    positions, faces = icosphere(2)
    ints, grid = to_grid(positions, bits=14)
    return ints, faces, grid


@pytest.mark.parametrize("codec", ["plain", "draco"])
def test_decoded_base_equals_input_up_to_vertex_map(mesh, codec):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec=codec)
    assert enc.codec == codec and enc.notice is None
    assert np.array_equal(enc.positions_int, ints[enc.vertex_map])
    assert np.array_equal(np.sort(enc.vertex_map), np.arange(len(ints)))
    gltf, prim = _gltf_of(enc)
    pos, tri = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert pos.dtype == np.int64 and tri.dtype == np.int64
    assert np.array_equal(pos, enc.positions_int)
    assert np.array_equal(tri, enc.faces)
    assert same_face_set(enc.vertex_map[tri], faces)


def test_draco_base_keeps_the_bounding_radius(mesh):
    # not a unit sphere and off-centre: a swapped attribute or a lost origin would show here
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    gltf, prim = _gltf_of(enc)
    pos, _ = basecodec.decode_base(gltf, enc.data, grid, prim)
    xyz = Grid.from_config(grid).to_float32(pos).astype(np.float64)
    radius = np.linalg.norm(xyz - np.asarray(ICOSPHERE_CENTRE), axis=1)
    assert np.allclose(radius, ICOSPHERE_RADIUS, atol=2 * grid["step"])


def test_draco_attribute_id_is_read_back_not_assumed(mesh, monkeypatch):
    # With normals DracoPy gives NORMAL id 0 and POSITION id 1: the primitive must say 1.
    import DracoPy

    real_encode = DracoPy.encode
    monkeypatch.setattr(DracoPy, "encode", lambda points, faces, **kw: real_encode(points, faces, normals=np.asarray(points, dtype=np.float64), **kw))
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    assert enc.codec == "draco"
    assert enc.draco_attribute_ids == {"POSITION": 1}
    assert enc.primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"] == {"POSITION": 1}
    gltf, prim = _gltf_of(enc)
    pos, _ = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert np.array_equal(pos, enc.positions_int)


def test_a_base_whose_distinct_vertices_share_a_grid_point_keeps_dracos_order_with_the_weld_attribute(mesh):
    ints, faces, grid = mesh
    dup = np.vstack([ints, ints[:1]])  # two vertices at one grid point: matching them by position is ambiguous
    tri = np.vstack([faces, [[len(ints), faces[0, 1], faces[0, 2]]]])
    enc = basecodec.encode_base(dup, tri, grid, codec="draco")
    # Draco's own order (not its sequential coder), the two told apart by their ordinals on the point
    assert enc.codec == "draco" and enc.notice is None and enc.welded_count == len(dup)
    assert basecodec.WELD_ATTRIBUTE in enc.primitive["attributes"]
    assert np.array_equal(enc.positions_int, dup[enc.vertex_map])
    gltf, prim = _welded_gltf(enc)
    pos, tri_back = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert np.array_equal(pos, enc.positions_int) and same_face_set(enc.vertex_map[tri_back], tri)
    # without the attribute the weld merges the two: the file is refused, not read as another mesh
    del prim["attributes"][basecodec.WELD_ATTRIBUTE]
    with pytest.raises(FormatError, match="welding gives"):
        basecodec.decode_base(gltf, enc.data, grid, prim)


def test_the_sequential_coder_keeps_the_order_of_a_base_whose_vertices_share_a_position(mesh, monkeypatch):
    ints, faces, grid = mesh
    dup = np.vstack([ints, ints[:1]])
    tri = np.vstack([faces, [[len(ints), faces[0, 1], faces[0, 2]]]])
    real = basecodec._try_draco
    monkeypatch.setattr(basecodec, "_try_draco", lambda *a: "refused" if not a[3] else real(*a))  # own order refused
    enc = basecodec.encode_base(dup, tri, grid, codec="draco")
    assert enc.codec == "draco" and enc.notice is None and enc.welded_count is None  # Draco's sequential coding
    assert basecodec.WELD_ATTRIBUTE not in enc.primitive["attributes"]
    assert np.array_equal(enc.vertex_map, np.arange(len(dup))) and np.array_equal(enc.positions_int, dup)
    gltf, prim = _gltf_of(enc)
    pos, tri_back = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert np.array_equal(pos, dup) and same_face_set(tri_back, tri)


def test_draco_falls_back_to_plain_with_a_notice_when_the_base_has_no_faces(mesh):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces[:0], grid, codec="draco")
    assert enc.codec == "plain" and "Draco" in enc.notice and "no faces" in enc.notice
    assert np.array_equal(enc.positions_int, ints)


def _welded_gltf(enc):
    gltf, prim = _gltf_of(enc)
    prim["extensions"]["PMWM_progressive_mesh"] = {"baseVertexCount": enc.welded_count}
    return gltf, prim


@pytest.fixture(scope="module")
def bowtie_base():
    """Two spheres sharing a vertex plus a fin (an edge of three faces): Draco's edgebreaker
    stores the shared vertex and the fin's edge ends as several copies."""
    from pmwm_codec import shapes

    m = shapes.bowtie()
    ints, grid = to_grid(m.positions, bits=14)
    return ints, m.faces, grid


def test_a_non_manifold_base_keeps_edgebreaker_and_is_welded_back_exactly(bowtie_base):
    ints, faces, grid = bowtie_base
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    assert enc.codec == "draco" and enc.notice is None
    assert enc.welded_count == len(ints) < enc.accessors[0]["count"]  # stored copies, welded count declared
    gltf, prim = _welded_gltf(enc)
    pos, tri = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert np.array_equal(pos, enc.positions_int) and np.array_equal(tri, enc.faces)
    assert np.array_equal(pos, ints[enc.vertex_map]) and same_face_set(enc.vertex_map[tri], faces)
    assert basecodec.base_vertex_count(gltf, prim) == len(ints)
    sequential = basecodec._try_draco(ints, faces, Grid.from_config(grid), True, 7)
    assert len(enc.data) < len(sequential.data)  # what the weld is for


def test_a_welded_base_without_its_declaration_decodes_to_the_stored_copies(bowtie_base):
    ints, faces, grid = bowtie_base
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    gltf, prim = _gltf_of(enc)  # no baseVertexCount: what a viewer shows
    pos, _ = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert len(pos) == enc.accessors[0]["count"] > len(ints)


def _count(delta):
    return lambda ext, n: ext.update(baseVertexCount=n + delta)


@pytest.mark.parametrize("edit, message", [
    (_count(1), "baseVertexCount"),  # more than the stored vertices... or than the weld gives
    (_count(-1), "welding"),
    (_count(10**6), "baseVertexCount"),
    (lambda ext, n: ext.update(baseVertexCount=n - 0.5), "not a positive integer"),
    (lambda ext, n: ext.update(baseVertexCount=True), "not a positive integer"),
    (lambda ext, n: ext.update(baseVertexCount=0), "not a positive integer"),
], ids=["one-more", "one-fewer", "beyond-stored", "fraction", "bool", "zero"])
def test_a_wrong_weld_declaration_is_a_format_error(bowtie_base, edit, message):
    ints, faces, grid = bowtie_base
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    gltf, prim = _welded_gltf(enc)
    edit(prim["extensions"]["PMWM_progressive_mesh"], len(ints))
    with pytest.raises(FormatError, match=message):
        basecodec.decode_base(gltf, enc.data, grid, prim)


def test_weld_keeps_the_first_copy_and_numbers_kept_vertices_in_stored_order():
    pos = np.array([[5, 0, 0], [1, 1, 1], [5, 0, 0], [2, 2, 2], [1, 1, 1]], np.int64)
    faces = np.array([[0, 1, 3], [2, 3, 4]], np.int64)
    kept, welded, ordinals = basecodec.weld(pos, faces)
    assert kept.tolist() == [[5, 0, 0], [1, 1, 1], [2, 2, 2]]
    assert welded.tolist() == [[0, 1, 2], [0, 2, 1]]
    assert ordinals.tolist() == [0, 0, 0]


def test_weld_with_ordinals_keeps_distinct_vertices_on_one_point_apart():
    # the spec's example with a weld attribute: stored vertex 2 is another vertex on (5,0,0), 4 a copy of 1
    pos = np.array([[5, 0, 0], [1, 1, 1], [5, 0, 0], [2, 2, 2], [1, 1, 1]], np.int64)
    faces = np.array([[0, 1, 3], [2, 3, 4]], np.int64)
    kept, welded, ordinals = basecodec.weld(pos, faces, np.array([0, 0, 1, 0, 0]))
    assert kept.tolist() == [[5, 0, 0], [1, 1, 1], [5, 0, 0], [2, 2, 2]]
    assert welded.tolist() == [[0, 1, 3], [2, 3, 1]]
    assert ordinals.tolist() == [0, 0, 1, 0]


def test_point_ordinals_number_the_vertices_of_each_point_in_vertex_order():
    pos = np.array([[1, 0, 0], [2, 0, 0], [1, 0, 0], [1, 0, 0], [3, 0, 0], [2, 0, 0]], np.int64)
    assert basecodec.point_ordinals(pos).tolist() == [0, 0, 1, 2, 0, 1]
    assert basecodec.point_ordinals(pos[:0]).tolist() == []


@given(st.lists(st.integers(0, 5), min_size=3, max_size=40), st.integers(0, 2**31))
@settings(max_examples=60, deadline=None)
def test_weld_gives_each_distinct_position_once_and_every_corner_its_position(labels, seed):
    rng = np.random.default_rng(seed)
    pos = np.array([[x, 2 * x, -x] for x in labels], np.int64)
    faces = rng.integers(0, len(pos), size=(7, 3))
    kept, welded, _ = basecodec.weld(pos, faces)
    assert len(np.unique(kept, axis=0)) == len(kept) == len(set(labels))
    assert np.array_equal(kept[welded], pos[faces])
    firsts = sorted({labels.index(x) for x in labels})
    assert np.array_equal(kept, pos[firsts])


def test_plain_indices_use_unsigned_short_for_small_meshes(mesh):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="plain")
    assert enc.accessors[1]["componentType"] == basecodec.UNSIGNED_SHORT
    assert len(enc.data) % 4 == 0


def test_plain_position_accessor_min_max_are_the_exact_float32_bounds(mesh):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="plain")
    stored = np.frombuffer(enc.data, "<f4", count=3 * len(ints)).reshape(-1, 3)
    assert enc.accessors[0]["min"] == [float(x) for x in stored.min(0)]
    assert enc.accessors[0]["max"] == [float(x) for x in stored.max(0)]


@pytest.mark.parametrize("bad", ["negative", "too_big", "float", "face_range"])
def test_encode_base_rejects_bad_input(mesh, bad):
    ints, faces, grid = mesh
    if bad == "negative":
        ints = ints - 1
    elif bad == "too_big":
        ints = ints.copy(); ints[0, 0] = 1 << grid["bits"]
    elif bad == "float":
        ints = ints.astype(float)
    else:
        faces = faces.copy(); faces[0, 0] = len(ints)
    with pytest.raises(ValueError, match="encode_base"):
        basecodec.encode_base(ints, faces, grid, codec="plain")


def test_encode_base_rejects_a_grid_too_fine_for_float32():
    positions, faces = icosphere(0)
    ints, grid = to_grid(positions * 1000 + 1e6, bits=30)
    with pytest.raises(ValueError, match="float32"):
        basecodec.encode_base(ints, faces, grid, codec="plain")


def test_decode_base_checks_vertex_count_before_reading(mesh):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="plain")
    gltf, prim = _gltf_of(enc)
    gltf["accessors"][0]["count"] = MAX_VERTICES + 1
    with pytest.raises(LimitError):
        basecodec.decode_base(gltf, enc.data, grid, prim)


def test_decode_base_rejects_out_of_range_indices(mesh):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="plain")
    gltf, prim = _gltf_of(enc)
    gltf["accessors"][0]["count"] = 3  # fewer vertices than the faces index
    with pytest.raises(FormatError, match="out of range"):
        basecodec.decode_base(gltf, enc.data, grid, prim)


def test_decode_base_rejects_undecodable_draco(mesh):
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    gltf, prim = _gltf_of(enc)
    with pytest.raises(FormatError, match="Draco"):
        basecodec.decode_base(gltf, bytes(len(enc.data)), grid, prim)


def test_decode_base_rejects_a_face_that_repeats_a_vertex(mesh):
    """A split of a vertex held twice by one face has no defined result (bitstream §6.1): refused."""
    ints, faces, grid = mesh
    enc = basecodec.encode_base(ints, faces, grid, codec="plain")
    gltf, prim = _gltf_of(enc)
    acc = gltf["accessors"][prim["indices"]]
    view = gltf["bufferViews"][acc["bufferView"]]
    dtype = {5121: "<u1", 5123: "<u2", 5125: "<u4"}[acc["componentType"]]
    data = bytearray(enc.data)
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    idx = np.frombuffer(data, dtype, acc["count"], start).copy()
    idx[1] = idx[0]  # face 0 becomes (a, a, c)
    data[start:start + idx.nbytes] = idx.tobytes()
    with pytest.raises(FormatError, match="repeats a vertex"):
        basecodec.decode_base(gltf, bytes(data), grid, prim)


@settings(max_examples=300, deadline=None)
@given(st.floats(width=32, allow_nan=False, allow_infinity=False))
def test_float32_min_max_text_is_the_shortest_that_reads_back_to_the_same_float32(x):
    from pmwm_codec.format.gltf import float32_numbers

    (y,) = float32_numbers([x])
    text = json.dumps(y)
    assert np.float32(json.loads(text)) == np.float32(x)
    assert len(text) <= len(repr(float(np.float32(x))))


@pytest.mark.parametrize("codec", ["plain", "draco"])
def test_the_written_base_leaves_out_glTF_defaults_and_long_float_texts(codec):
    from pmwm_codec.format.glb import split_glb
    from samples import sample_pmw

    data, *_ = sample_pmw(codec, chunk_count=2)
    gltf, _ = split_glb(data)
    assert "mode" not in gltf["meshes"][0]["primitives"][0]
    assert all(view.get("byteOffset", 1) != 0 for view in gltf["bufferViews"])
    position = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    for value in position["min"] + position["max"]:
        assert json.dumps(value) == str(np.float32(value))


def test_a_base_whose_triangles_all_fall_onto_grid_points_leaves_draco_unasked_and_stderr_clean(capfd, tmp_path):
    """A strip 1/200,000 as wide as it is long: on the 16-bit grid every triangle has two corners on one
    point.  Draco would refuse it and print that on the process's stderr; the encoder stores the base
    its own way and says nothing."""
    import pmwm_codec
    from pmwm_codec.mesh import Mesh

    n = 200  # columns 1 apart, the two rows 1e-3 apart, a wave of 0.01 in z
    x = np.arange(n, dtype=np.float64)
    z = 0.01 * np.sin(x)
    positions = np.concatenate([np.stack([x, np.zeros(n), z], 1), np.stack([x, np.full(n, 1e-3), z], 1)])
    faces = np.concatenate([np.stack([np.arange(n - 1), np.arange(1, n), n + np.arange(n - 1)], 1),
                            np.stack([np.arange(1, n), n + np.arange(1, n), n + np.arange(n - 1)], 1)])
    capfd.readouterr()
    report = pmwm_codec.encode(Mesh(positions, faces), str(tmp_path / "s.pmw"))
    assert report["base_codec"] != "draco"
    out, err = capfd.readouterr()
    assert err == ""
    assert pmwm_codec.decode(str(tmp_path / "s.pmw")).face_count == report["faces"]


def _fan_of_copies(k: int):
    """``k`` separate triangles whose apexes are ``k`` distinct vertices on one grid point (the other
    corners each on their own point): ordinals 0 .. k - 1 on the apex's point."""
    angle = np.arange(2 * k) * (2 * np.pi / (2 * k))
    rim = np.c_[np.cos(angle), np.sin(angle), np.zeros(2 * k)]
    pos = np.vstack([np.zeros((k, 3)) + [0.0, 0.0, 1.0], rim])
    faces = np.c_[np.arange(k), k + 2 * np.arange(k), k + 2 * np.arange(k) + 1]
    ints, grid = to_grid(pos, bits=16)
    assert len(np.unique(ints[k:], axis=0)) == 2 * k and len(np.unique(ints[:k], axis=0)) == 1
    return ints, faces, grid


def test_more_than_255_vertices_on_one_point_take_an_unsigned_short_weld_attribute():
    ints, faces, grid = _fan_of_copies(300)
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    assert enc.codec == "draco" and enc.welded_count == len(ints)  # Draco's own order, welded back
    weld = enc.accessors[enc.primitive["attributes"][basecodec.WELD_ATTRIBUTE]]
    assert weld["componentType"] == basecodec.UNSIGNED_SHORT
    gltf, prim = _welded_gltf(enc)
    pos, tri = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert np.array_equal(pos, enc.positions_int) and same_face_set(enc.vertex_map[tri], faces)


def test_more_vertices_on_one_point_than_the_weld_attribute_counts_fall_back_to_the_sequential_coder():
    ints, faces, grid = _fan_of_copies(basecodec.WELD_TYPES[basecodec.UNSIGNED_SHORT] + 2)
    why = basecodec._try_draco(ints, faces, Grid.from_config(grid), False, 7)
    assert isinstance(why, str) and "65536" in why.replace(",", "")
    enc = basecodec.encode_base(ints, faces, grid, codec="draco")
    assert enc.codec == "draco" and enc.welded_count is None  # the sequential coder keeps our order: no weld
    assert basecodec.WELD_ATTRIBUTE not in enc.primitive["attributes"]
    gltf, prim = _gltf_of(enc)
    pos, tri = basecodec.decode_base(gltf, enc.data, grid, prim)
    assert np.array_equal(pos, ints) and np.array_equal(tri, faces)
