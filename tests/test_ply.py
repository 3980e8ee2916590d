"""PLY reading (pmwm_codec.ply): ASCII and binary read alike, every malformed record refused in one line."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from pmwm_codec.errors import InputFormatError
from pmwm_codec.mesh import read_mesh
from pmwm_codec.ply import read_ply

POSITIONS = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [2, 0, 0], [2, 1, 0.5], [0.5, 2, 0.25]], np.float64)
#: A triangle, a quad and a pentagon (MeshLab writes such mixes), fan-triangulated in order as an OBJ's are.
POLYGONS = [[0, 1, 2], [1, 4, 5, 2], [3, 2, 5, 6, 0]]
TRIANGLES = [[0, 1, 2], [1, 4, 5], [1, 5, 2], [3, 2, 5], [3, 5, 6], [3, 6, 0]]

HEADER = ("ply\nformat {fmt} 1.0\ncomment made by a test\nelement vertex {n}\nproperty float x\nproperty float y\n"
          "property float z\nproperty uchar red\nelement face {m}\nproperty list uchar int vertex_indices\n"
          "property uchar flags\nend_header\n")


def _ascii(polygons=POLYGONS, positions=POSITIONS, tail="") -> bytes:
    rows = [f"{x:g} {y:g} {z:g} 200" for x, y, z in positions]
    rows += [f"{len(p)} " + " ".join(map(str, p)) + " 1" for p in polygons]
    return (HEADER.format(fmt="ascii", n=len(positions), m=len(polygons)) + "\n".join(rows) + "\n" + tail).encode()


def _binary(order: str, polygons=POLYGONS, positions=POSITIONS) -> bytes:
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    out = bytearray(HEADER.format(fmt=fmt, n=len(positions), m=len(polygons)).encode())
    for p in positions:
        out += np.asarray(p, order + "f4").tobytes() + bytes([200])
    for p in polygons:
        out += bytes([len(p)]) + np.asarray(p, order + "i4").tobytes() + bytes([1])
    return bytes(out)


@pytest.mark.parametrize("data", [_ascii(), _binary("<"), _binary(">")], ids=["ascii", "little", "big"])
def test_ascii_and_binary_read_the_same_mesh_mixed_polygons_fanned_in_order(data):
    positions, faces = read_ply(data, "m.ply", 100)
    assert np.array_equal(positions, POSITIONS.astype(np.float32)) and faces.tolist() == TRIANGLES


def test_records_of_one_shape_read_at_once_equal_those_read_one_by_one():
    square = [[0, 1, 2], [0, 2, 3], [1, 4, 5], [2, 5, 6]]
    for data in (_ascii(square), _binary("<", square)):
        assert read_ply(data, "m.ply", 100)[1].tolist() == square


def test_a_mesh_file_reads_through_read_mesh_and_welds_like_an_obj(tmp_path):
    (tmp_path / "m.ply").write_bytes(_binary("<"))
    mesh = read_mesh(tmp_path / "m.ply")
    assert mesh.vertex_count == 7 and mesh.face_count == 6


def test_triangle_strips_read_with_restarts_and_alternating_turns():
    data = ("ply\nformat ascii 1.0\nelement vertex 5\nproperty float x\nproperty float y\nproperty float z\n"
            "element tristrips 1\nproperty list int int vertex_indices\nend_header\n"
            "0 0 0\n1 0 0\n0 1 0\n1 1 0\n2 1 0\n6 0 1 2 3 -1 4\n").encode()
    assert read_ply(data, "s.ply", 10)[1].tolist() == [[0, 1, 2], [2, 1, 3]]


@pytest.mark.parametrize("data, says", [
    (_ascii(POLYGONS[:2]).replace(b"4 1 4 5 2 1\n", b""), "declares 2 face records but holds 1 lines"),
    (_ascii().replace(b"4 1 4 5 2 1", b"4 1 4 5 1"), "malformed PLY face record (line 9 after the header): '4 1 4 5 1'"),
    (_ascii().replace(b"3 0 1 2 1", b"3 0 1 2.7 1"), "malformed PLY face record"),
    (_ascii().replace(b"1 0 0 200", b"1 0 0 200 7"), "malformed PLY vertex record (line 2 after the header)"),
    (_ascii().replace(b"3 0 1 2 1\n4 1 4 5 2 1", b"3 0 1 2 1 4 1 4 5 2 1"), "not one record a line"),
    (_ascii(tail="3 0 1 2 1\n"), "data after the last PLY element"),
    (_ascii().replace(b"0 0 0 200", b"0 0 0_0 200"), "byte b'_' in the records"),
    (_ascii().replace(b"0 0 0 200", "0 0 \u0661 200".encode()), "in the records of an ASCII PLY"),
    (_ascii().replace(b"3 0 1 2 1", b"3 0 1 9999999999 1"), "malformed PLY face record"),
    (_ascii().replace(b"property float z\n", b"property float w\n"), "has no x, y and z"),
    (_ascii().replace(b"vertex_indices", b"corners"), "has no vertex_indices list"),
    (_binary("<")[:-3], "ends before them (cut short)"),
    (_binary("<") + b"\0\0", "2 bytes after the last PLY element"),
    (_ascii().replace(b"format ascii", b"format text"), "malformed PLY header line 'format text 1.0'"),
    (_ascii().replace(b"3 0 1 2 1", b"0 1"), "a PLY face of no corners"),
], ids=["cut-short", "count-lies", "float-index", "extra-value", "two-on-a-line", "trailing", "underscore",
        "arabic-digit", "index-past-int32", "no-z", "no-corner-list", "binary-cut", "binary-trailing", "format",
        "no-corners"])
def test_a_malformed_ply_is_refused_in_one_line_naming_the_problem(data, says):
    with pytest.raises(InputFormatError) as err:
        read_ply(data, "bad.ply", 100)
    assert says in str(err.value) and "\n" not in str(err.value) and str(err.value).startswith("bad.ply: ")


def test_more_triangles_than_the_limit_are_refused_before_any_is_made():
    with pytest.raises(InputFormatError, match="more than 5 triangles"):
        read_ply(_binary("<"), "m.ply", 5)


def test_mutated_files_are_read_or_refused_by_name_never_another_error():
    """1,500 copies of the files above with bytes changed, cut out, put in or the end cut off: each reads or is
    refused with a PmwError (30,000 such read_ply calls and 6,000 read_mesh calls were run once by hand: none
    raised anything else)."""
    from pmwm_codec.errors import PmwError

    for data in mutations([_ascii(), _binary("<"), _binary(">"), _ascii([[0, 1, 2], [0, 2, 3]])], 1500, seed=5):
        try:
            read_ply(data, "f.ply", 1000)
        except PmwError:
            pass


def mutations(seeds: list, count: int, seed: int):
    """``count`` copies (bytes) of files picked from ``seeds``, each with one to four bytes changed, runs cut out
    or put in, or its end cut off."""
    import random

    rng = random.Random(seed)
    for _ in range(count):
        data = bytearray(rng.choice(seeds))
        for _ in range(rng.randint(1, 4)):
            if not data:
                break
            j, op = rng.randrange(len(data)), rng.random()
            if op < 0.4:
                data[j] = rng.randrange(256)
            elif op < 0.6:
                del data[j: j + rng.randint(1, 8)]
            elif op < 0.8:
                data[j:j] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 4)))
            else:
                del data[j:]
        yield bytes(data)


def test_an_element_of_no_properties_holds_no_data():
    for data in (_ascii(), _binary("<")):
        extra = data.replace(b"end_header", b"element note 3\nend_header")
        assert read_ply(extra, "m.ply", 100)[1].tolist() == TRIANGLES


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_binary_records_of_mixed_shapes_read_as_written(data):
    """Faces of 1-7 corners in any mix, with scalars before and after the corner list and a second list, every
    count and item type and both byte orders: each property reads back as written (the mixed-shape reader walks
    the records' counts, then gathers each property at once)."""
    order = data.draw(st.sampled_from("<>"))
    count_type = data.draw(st.sampled_from([("uchar", "u1"), ("ushort", "u2"), ("int", "i4"), ("uint", "u4")]))
    item_type = data.draw(st.sampled_from([("int", "i4"), ("uint", "u4"), ("ushort", "u2")]))
    polygons = data.draw(st.lists(st.lists(st.integers(0, 6), min_size=1, max_size=7), min_size=1, max_size=40))
    if all(len(p) == len(polygons[0]) for p in polygons):
        polygons.append([0] * (len(polygons[0]) % 7 + 1))  # at least two shapes
    tags = data.draw(st.lists(st.integers(0, 255), min_size=len(polygons), max_size=len(polygons)))
    fmt = "binary_little_endian" if order == "<" else "binary_big_endian"
    header = (f"ply\nformat {fmt} 1.0\nelement vertex 7\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(polygons)}\nproperty uchar tag\nproperty list {count_type[0]} {item_type[0]} "
              f"vertex_indices\nproperty short weight\nproperty list uchar float uv\nend_header\n")
    out = bytearray(header.encode()) + POSITIONS.astype(order + "f4").tobytes()
    for p, tag in zip(polygons, tags):
        out += bytes([tag]) + np.array(len(p), order + count_type[1]).tobytes()
        out += np.array(p, order + item_type[1]).tobytes() + np.array(-tag, order + "i2").tobytes()
        out += bytes([len(p) % 3]) + np.arange(len(p) % 3, dtype=order + "f4").tobytes()
    from pmwm_codec.ply import _binary_elements, _header

    body = bytes(out)
    start = body.index(b"end_header\n") + len(b"end_header\n")
    _, elements = _header(body[: body.index(b"end_header")].decode(), "m.ply")
    _, face = _binary_elements(body[start:], elements, order, "m.ply")
    assert face["tag"].tolist() == tags and face["weight"].tolist() == [-t for t in tags]
    lengths, items = face["vertex_indices"]
    assert lengths.tolist() == [len(p) for p in polygons] and items.tolist() == [i for p in polygons for i in p]
    uv_lengths, uv = face["uv"]
    assert uv_lengths.tolist() == [len(p) % 3 for p in polygons]
    assert uv.tolist() == [float(j) for p in polygons for j in range(len(p) % 3)]
    assert read_ply(body, "m.ply", 1000)[1].shape == (sum(max(len(p) - 2, 1) for p in polygons), 3)


def test_a_negative_list_count_in_mixed_binary_records_is_refused():
    header = ("ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              "property float z\nelement face 2\nproperty list char int vertex_indices\nend_header\n").encode()
    body = np.zeros(9, "<f4").tobytes() + bytes([3]) + np.arange(3, dtype="<i4").tobytes() + bytes([0xFF])
    with pytest.raises(InputFormatError, match="list of negative length"):
        read_ply(header + body, "m.ply", 10)


@pytest.mark.parametrize("order", ["<", ">"])
def test_a_binary_header_naming_a_property_twice_reads_the_last_as_an_ascii_one_does(order):
    """(A ValueError from numpy's record type before: 'field y occurs more than once'.)"""
    for data in (_ascii(), _binary(order)):
        twice = data.replace(b"property uchar red\n", b"property uchar z\n")
        positions, faces = read_ply(twice, "m.ply", 100)
        assert faces.tolist() == TRIANGLES and (positions[:, 2] == 200).all()


def test_a_signalling_nan_in_a_binary_file_is_read_without_a_numpy_warning():
    import warnings

    body = np.zeros((len(POSITIONS), 3), "<u4")
    body[1, 1] = 0x7FA00000  # a signalling NaN: numpy's cast to float64 raised 'invalid value encountered'
    data = _binary("<").replace(np.asarray(POSITIONS[1], "<f4").tobytes(), body[1].tobytes(), 1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        positions, _ = read_ply(data, "m.ply", 100)
    assert np.isnan(positions[1, 1])


def test_counting_an_ascii_ply_s_tokens_per_line_takes_less_than_an_int64_a_byte():
    """A scan's ASCII PLY is read whole; counting its tokens line by line must not add 8 bytes per byte of the file
    (a count over every byte in int64: 3.3 GB for a 417 MB file).  The counts are those of splitting each line."""
    import tracemalloc

    from pmwm_codec.ply import _tokens_per_line

    rng = np.random.default_rng(5)
    lines = [" ".join(f"{x:.7g}" for x in row) + (" 200 10 3" if i % 3 else "") for i, row in
             enumerate(rng.normal(size=(40_000, 6)))]
    body = ("\n".join(lines) + "\n\n  \t\n").encode()
    tracemalloc.start()
    try:
        counts, ends = _tokens_per_line(body)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert counts.tolist() == [len(line.split()) for line in lines]
    assert [body[e: e + 1] for e in ends.tolist()] == [b"\n"] * len(lines)  # where each line ends
    assert peak < 4 * len(body), (peak, len(body))


def test_a_ply_declaring_more_vertices_than_the_encoder_takes_is_refused_with_readable_counts(tmp_path):
    """The refusal printed the declared count as written, ``PLY declares 7814907 vertex elements (the encoder
    takes 0..4,194,304)``: a heritage scan's 7.8M vertices without separators beside a limit with them (outside
    probe of big inputs).  Both are written alike now, and a count that is no number is said to be none."""
    from pmwm_codec.errors import InputFormatError
    from pmwm_codec.mesh import read_mesh

    path = tmp_path / "big.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 7814907\nproperty float x\n"
                     b"property float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\n"
                     b"end_header\n")
    with pytest.raises(InputFormatError, match=r"declares 7,814,907 vertex elements \(the encoder takes at most 4,"):
        read_mesh(path)
    path.write_bytes(path.read_bytes().replace(b"vertex 7814907", b"vertex 12x"))
    with pytest.raises(InputFormatError, match=r"declares '12x' vertex elements \(not a count\)"):
        read_mesh(path)


def test_reading_an_ascii_ply_takes_no_python_object_per_token():
    """Reading an ASCII PLY split its records into a list of tokens (a bytes object each: ~10x the file's size,
    1.3 GB for a 144 MB scan); records of one shape are parsed from their text by numpy, to the same arrays --
    floats and integers of one element together (a colour's uchar beside float coordinates) too."""
    import tracemalloc

    rng = np.random.default_rng(6)
    n = 20_000
    pos = rng.normal(size=(n, 3))
    colour = rng.integers(0, 256, size=(n, 3))
    faces = rng.integers(0, n, size=(2 * n, 3))
    head = (f"ply\nformat ascii 1.0\nelement vertex {n}\nproperty float x\nproperty float y\nproperty float z\n"
            "property uchar red\nproperty uchar green\nproperty uchar blue\n"
            f"element face {2 * n}\nproperty list uchar int vertex_indices\nend_header\n")
    body = "".join(["%.9g %.9g %.9g %d %d %d\n" % (*p, *c) for p, c in zip(pos, colour)]
                   + ["3 %d %d %d\n" % tuple(f) for f in faces])
    data = (head + body).encode()
    tracemalloc.start()
    try:
        positions, triangles = read_ply(data, "m.ply", 10 * n)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert np.array_equal(positions, np.array([[float(np.float32(float("%.9g" % x))) for x in p] for p in pos]))
    assert np.array_equal(triangles, faces)
    assert peak < 6 * len(data), (peak, len(data))


@pytest.mark.parametrize("token", ["2.0", "2e0", "nan", "+"])
def test_an_ascii_ply_integer_written_as_no_integer_is_refused_beside_floats_too(token):
    """A uchar colour written ``2.0`` (or ``nan``, or a sign alone) beside float coordinates is refused naming its
    record, as it was when every token was parsed on its own (numpy would read ``2.0`` and ``nan`` as floats,
    and a sign alone as 0)."""
    head = ("ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
            "property uchar red\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
    data = (head + f"0 0 0 1\n1 0 0 {token}\n0 1 0 3\n3 0 1 2\n").encode()
    with pytest.raises(InputFormatError, match=r"malformed PLY vertex record \(line 2 after the header\)"):
        read_ply(data, "m.ply", 10)
