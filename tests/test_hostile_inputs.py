"""Hostile inputs on the encoder side (security audit, probes 1, 3, 11, 12, 14; issue 11 part A).

Every case is a file generated here in ``tmp_path``.  Each must end ``pmw encode`` with
exit 2, exactly one line ``pmw: error: ...`` on stderr (naming the culprit), no
traceback and no output file; a ``.gltf`` may only bring in regular files inside its
own folder.  The largest cases also run in a subprocess under an address-space limit.
"""

from __future__ import annotations

import base64
import json
import os
import resource
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh
from pmwm_codec.constants import MAX_ENCODE_FACES, MAX_ENCODE_VERTICES, MAX_INPUT_FILE_BYTES, MAX_WATERMARK_PIXELS
from pmwm_codec.format.document import load_document

ROOT = Path(__file__).resolve().parents[1]
TINY_PNG = base64.b64decode(
    "iVBORw0KGgoAAAANSUhEUgAAAAEAAAABCAAAAAA6fptVAAAACklEQVR4nGP4DwABAQEAG7buVgAAAABJRU5ErkJggg==")


# --- helpers ---------------------------------------------------------------------------------


def run_encode(capsys, tmp_path, *argv):
    """``pmw encode`` in process: ``(status, stderr lines, out path)``; stdout is not looked at."""
    out = tmp_path / "out.pmw"
    status = main(["encode", *map(str, argv), "-o", str(out), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    return status, err, out


def assert_refused(status, err, out, *words):
    """Exit 2, one ``pmw: error:`` line holding every one of ``words``, no file written."""
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith("pmw: error: "), err
    assert "Traceback" not in err[0]
    for word in words:
        assert word in err[0], err
    assert not out.exists()
    assert not Path(str(out) + ".key.json").exists()


def gltf_doc(mesh, images=(), **extra) -> dict:
    """A ``.gltf`` JSON of ``mesh`` (one data-URI buffer) whose images have the given uris."""
    pos = mesh.positions.astype("<f4").tobytes()
    idx = mesh.faces.astype("<u4").tobytes()
    blob = pos + idx
    doc = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(blob),
                     "uri": "data:application/octet-stream;base64," + base64.b64encode(blob).decode()}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(pos)},
                        {"buffer": 0, "byteOffset": len(pos), "byteLength": len(idx)}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": mesh.vertex_count, "type": "VEC3",
             "min": mesh.positions.min(0).tolist(), "max": mesh.positions.max(0).tolist()},
            {"bufferView": 1, "componentType": 5125, "count": mesh.faces.size, "type": "SCALAR"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}} if images else {}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    if images:
        doc["images"] = [{"uri": uri} for uri in images]
        doc["textures"] = [{"source": 0}]
    doc.update(extra)
    return doc


def write_gltf(folder: Path, doc: dict) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "m.gltf"
    path.write_text(json.dumps(doc))
    return path


@pytest.fixture
def mesh():
    return shapes.icosphere(1)


@pytest.fixture
def secret(tmp_path) -> Path:
    """A file beside (not inside) the asset folder ``tmp_path/asset``."""
    path = tmp_path / "secret.txt"
    path.write_bytes(b"root:*:secret\n")
    return path


# --- 1. local file exfiltration ------------------------------------------------------------


@pytest.mark.parametrize("uri", ["/etc/shadow", "/etc/passwd", "../../../../../../../../etc/passwd",
                                 "%2e%2e/secret.txt", "..%2fsecret.txt", "/proc/self/environ", "/dev/zero",
                                 "SECRET_ABSOLUTE", "sub/../../secret.txt"])
def test_image_uri_outside_the_asset_folder_is_refused_and_named(capsys, tmp_path, mesh, secret, uri):
    uri = str(secret) if uri == "SECRET_ABSOLUTE" else uri
    src = write_gltf(tmp_path / "asset", gltf_doc(mesh, images=[uri]))
    status, err, out = run_encode(capsys, tmp_path, src)
    assert_refused(status, err, out, repr(uri))
    assert "outside the asset's folder" in err[0] or "absolute path" in err[0]


def test_buffer_uri_outside_the_asset_folder_is_refused(capsys, tmp_path, mesh, secret):
    doc = gltf_doc(mesh)
    doc["buffers"].append({"byteLength": 10, "uri": "../secret.txt"})
    status, err, out = run_encode(capsys, tmp_path, write_gltf(tmp_path / "asset", doc))
    assert_refused(status, err, out, "'../secret.txt'", "outside the asset's folder")


def test_symlink_leading_out_of_the_folder_is_refused(capsys, tmp_path, mesh, secret):
    folder = tmp_path / "asset"
    folder.mkdir()
    (folder / "tex.png").symlink_to(secret)
    status, err, out = run_encode(capsys, tmp_path, write_gltf(folder, gltf_doc(mesh, images=["tex.png"])))
    assert_refused(status, err, out, "'tex.png'", "outside the asset's folder")


def test_symlink_to_a_device_inside_the_folder_path_is_refused(capsys, tmp_path, mesh):
    folder = tmp_path / "asset"
    folder.mkdir()
    (folder / "zero.png").symlink_to("/dev/zero")
    status, err, out = run_encode(capsys, tmp_path, write_gltf(folder, gltf_doc(mesh, images=["zero.png"])))
    assert_refused(status, err, out, "'zero.png'")


def test_scheme_uris_are_refused_without_fetching(capsys, tmp_path, mesh, secret):
    for uri in (f"file://{secret}", "http://127.0.0.1:9/x.png"):
        status, err, out = run_encode(capsys, tmp_path, write_gltf(tmp_path / "asset", gltf_doc(mesh, images=[uri])))
        assert_refused(status, err, out, "not a relative path")


def test_fifo_inside_the_folder_is_refused_without_blocking(tmp_path, mesh):
    """Run in a subprocess with a timeout: the old reader blocked forever on the FIFO."""
    folder = tmp_path / "asset"
    folder.mkdir()
    os.mkfifo(folder / "tex.png")
    src = write_gltf(folder, gltf_doc(mesh, images=["tex.png"]))
    proc = run_cli_limited(["encode", str(src), "-o", str(tmp_path / "out.pmw"), "-q"], timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "'tex.png'" in proc.stderr and "not a regular file" in proc.stderr
    assert not (tmp_path / "out.pmw").exists()


def test_resources_inside_the_folder_still_load(tmp_path, mesh):
    """Relative paths, ``..`` that stays inside, percent-encoding, symlinks inside, data URIs."""
    folder = tmp_path / "asset"
    (folder / "sub").mkdir(parents=True)
    (folder / "tex one.png").write_bytes(TINY_PNG)
    (folder / "link.png").symlink_to(folder / "tex one.png")
    data_uri = "data:image/png;base64," + base64.b64encode(TINY_PNG).decode()
    uris = ["tex one.png", "tex%20one.png", "sub/../tex one.png", "link.png", data_uri]
    gltf, _ = load_document(write_gltf(folder, gltf_doc(mesh, images=uris)))
    assert [image["_bytes"] for image in gltf["images"]] == [TINY_PNG] * len(uris)


# --- 2. hostile encoder inputs -------------------------------------------------------------


def obj_text(mesh, face_line=None) -> str:
    lines = [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in mesh.positions]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in mesh.faces]
    if face_line is not None:
        lines.append(face_line)
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("line, word", [("f 1 2 100000000000000000000000", "100000000000000000000000"),
                                        ("f 1 2 -100000000000000000000000", "-100000000000000000000000"),
                                        ("f 0 1 2", "face index 0")])
def test_obj_face_index_that_cannot_name_a_vertex_is_refused(capsys, tmp_path, mesh, line, word):
    src = tmp_path / "m.obj"
    src.write_text(obj_text(mesh, line))
    assert_refused(*run_encode(capsys, tmp_path, src), word)


def test_one_vertex_far_out_is_refused_instead_of_collapsing_the_mesh(capsys, tmp_path, mesh):
    far = mesh.positions.copy()
    far[7] = [1e30, 0.0, 0.0]
    src = tmp_path / "m.obj"
    src.write_text(obj_text(type(mesh)(far, mesh.faces)))
    assert_refused(*run_encode(capsys, tmp_path, src), "vertex 7", "collapse")


def ply_bytes(mesh, index_type="int") -> bytes:
    head = (f"ply\nformat ascii 1.0\nelement vertex {mesh.vertex_count}\nproperty float x\nproperty float y\n"
            f"property float z\nelement face {mesh.face_count}\nproperty list uchar {index_type} vertex_indices\n"
            "end_header\n")
    verts = "".join(f"{x} {y} {z}\n" for x, y, z in mesh.positions)
    faces = "".join(f"3 {a}.0 {b}.0 {c}.0\n" if index_type == "float" else f"3 {a} {b} {c}\n" for a, b, c in mesh.faces)
    return (head + verts + faces).encode()


def test_ply_float_face_indices_are_refused(capsys, tmp_path, mesh):
    src = tmp_path / "m.ply"
    src.write_bytes(ply_bytes(mesh, "float"))
    assert_refused(*run_encode(capsys, tmp_path, src), "not integers")


def test_ply_declaring_more_vertices_than_the_encoder_takes_is_refused(capsys, tmp_path, mesh):
    src = tmp_path / "m.ply"
    src.write_bytes(ply_bytes(mesh).replace(b"element vertex 42", f"element vertex {MAX_ENCODE_VERTICES + 1}".encode()))
    assert_refused(*run_encode(capsys, tmp_path, src), f"{MAX_ENCODE_VERTICES + 1:,} vertex elements")


@pytest.mark.parametrize("suffix, ascii_ply, hint", [(".obj", False, True), (".ply", True, True), (".ply", False, False)])
def test_a_mesh_file_over_the_size_limit_is_refused_naming_the_limit_and_the_way_out(capsys, tmp_path, mesh, suffix,
                                                                                     ascii_ply, hint):
    """A scan of several GB: the line gives the limit in bytes and GiB and, for a text format, says a binary PLY
    holds the same mesh in fewer bytes (never to a binary PLY, which is that already)."""
    src = tmp_path / f"scan{suffix}"
    if suffix == ".obj":
        head = "".join(f"v {x} {y} {z}\n" for x, y, z in mesh.positions).encode()
    else:
        head = ply_bytes(mesh) if ascii_ply else ply_bytes(mesh).replace(b"format ascii", b"format binary_little_endian")
    with open(src, "wb") as fh:  # a sparse file one byte over the limit
        fh.write(head)
        fh.truncate(MAX_INPUT_FILE_BYTES + 1)
    status, err, out = run_encode(capsys, tmp_path, src)
    assert_refused(status, err, out, f"{MAX_INPUT_FILE_BYTES + 1:,} bytes", f"{MAX_INPUT_FILE_BYTES:,} bytes", "2 GiB")
    assert ("binary PLY" in err[0]) == hint, err


def test_binary_stl_declaring_more_triangles_than_the_encoder_takes_is_refused(capsys, tmp_path):
    count = MAX_ENCODE_FACES + 1
    src = tmp_path / "m.stl"
    with open(src, "wb") as fh:  # a sparse file of the declared size
        fh.write(bytes(80) + struct.pack("<I", count))
        fh.truncate(84 + 50 * count)
    assert_refused(*run_encode(capsys, tmp_path, src), f"{count:,}")


WRONG_TYPES = {
    "meshes is an object": lambda d: d.update(meshes={"0": d["meshes"][0]}),
    "primitives is a string": lambda d: d["meshes"][0].update(primitives="x"),
    "attributes is a list": lambda d: d["meshes"][0]["primitives"][0].update(attributes=[0]),
    "POSITION is a string": lambda d: d["meshes"][0]["primitives"][0]["attributes"].update(POSITION="0"),
    "buffers is a number": lambda d: d.update(buffers=5),
    "images hold a number": lambda d: d.update(images=[1]),
    "a uri is a number": lambda d: d.update(images=[{"uri": 7}]),
    "bufferView past the end": lambda d: d["accessors"][0].update(bufferView=9),
    "indices past the end": lambda d: d["meshes"][0]["primitives"][0].update(indices=99),
    "extensions is a list": lambda d: d["meshes"][0]["primitives"][0].update(extensions=[]),
    "animation samplers are strings": lambda d: d.update(animations=[{"samplers": ["a"], "channels": []}]),
    "extensionsUsed holds a number": lambda d: d.update(extensionsUsed=[3]),
    "count is -5": lambda d: d["accessors"][0].update(count=-5),
    "count is 2^36": lambda d: d["accessors"][0].update(count=1 << 36),
    "count is 2^36 without a bufferView": lambda d: d["accessors"][1].pop("bufferView") and
    d["accessors"][1].update(count=3 << 34),
    "count is fractional": lambda d: d["accessors"][0].update(count=42.5),  # 42.0 is the integer 42
    "byteStride is negative": lambda d: d["bufferViews"][0].update(byteStride=-12),
    "byteStride is 2": lambda d: d["bufferViews"][0].update(byteStride=2),
    "byteOffset is negative": lambda d: d["accessors"][0].update(byteOffset=-4),
    "extras 800 deep": lambda d: d.update(extras=json.loads("[" * 800 + "]" * 800)),
    "a node with two parents": lambda d: d.update(nodes=[{"children": [2]}, {"children": [2]}, {"mesh": 0}]),
    "a node its own ancestor": lambda d: d.update(nodes=[{"children": [1]}, {"children": [2]}, {"children": [0], "mesh": 0}]),
    "a node its own child": lambda d: d.update(nodes=[{"children": [0], "mesh": 0}]),
    "a child past the end": lambda d: d.update(nodes=[{"children": [5], "mesh": 0}]),
    "a child index is a string": lambda d: d.update(nodes=[{"children": ["1"]}, {"mesh": 0}]),
    "a node's mesh past the end": lambda d: d.update(nodes=[{"mesh": 3}]),
    "sparse count 2^40": lambda d: d["accessors"][0].update(
        sparse={"count": 1 << 40, "indices": {"bufferView": 1, "componentType": 5125}, "values": {"bufferView": 0}}),
}


@pytest.mark.parametrize("case", sorted(WRONG_TYPES))
def test_malformed_gltf_json_is_one_line_and_no_file(capsys, tmp_path, mesh, case):
    doc = gltf_doc(mesh)
    WRONG_TYPES[case](doc)
    status, err, out = run_encode(capsys, tmp_path, write_gltf(tmp_path / "asset", doc))
    assert_refused(status, err, out, "m.gltf")


def test_sparse_index_past_the_accessor_is_refused(tmp_path, mesh):
    from pmwm_codec.errors import InputFormatError
    from pmwm_codec.format.document import read_accessor

    doc = gltf_doc(mesh)
    doc["bufferViews"].append({"buffer": 0, "byteOffset": 0, "byteLength": 4})  # float 'x' of vertex 0 as an index
    doc["accessors"][0]["sparse"] = {"count": 1, "indices": {"bufferView": 2, "componentType": 5125},
                                     "values": {"bufferView": 0}}
    gltf, buffers = load_document(write_gltf(tmp_path / "asset", doc))
    with pytest.raises(InputFormatError, match="sparse index"):
        read_accessor(gltf, buffers, 0)


def test_glb_with_json_nested_beyond_the_parser_is_refused(capsys, tmp_path):
    body = b"[" * 100_000 + b"]" * 100_000
    body += b" " * (-len(body) % 4)
    glb = struct.pack("<III", 0x46546C67, 2, 12 + 8 + len(body)) + struct.pack("<II", len(body), 0x4E4F534A) + body
    src = tmp_path / "deep.glb"
    src.write_bytes(glb)
    assert_refused(*run_encode(capsys, tmp_path, src), "deep.glb")


def glb_of(primitives, meshes=None) -> bytes:
    """A GLB of one glTF mesh whose primitives are ``(mode, positions (n, 3), faces (m, 3) or None)``.

    Written with ``json.dumps``' defaults, so a NaN in ``positions`` or in a min/max goes in
    as-is (``NaN`` in the JSON); ``meshes`` (the JSON dict) may be edited by the caller first.
    """
    doc = {"asset": {"version": "2.0"}, "accessors": [], "bufferViews": [], "nodes": [{"mesh": 0}],
           "scenes": [{"nodes": [0]}], "scene": 0}
    blob = b""

    def accessor(array, component, type_, minmax=False):
        nonlocal blob
        raw = array.tobytes()
        doc["bufferViews"].append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(raw)})
        blob += raw + bytes(-len(raw) % 4)
        acc = {"bufferView": len(doc["bufferViews"]) - 1, "componentType": component, "count": len(array), "type": type_}
        if minmax:
            acc.update(min=np.nanmin(array, 0).tolist(), max=np.nanmax(array, 0).tolist())
        doc["accessors"].append(acc)
        return len(doc["accessors"]) - 1

    prims = []
    for mode, positions, faces in primitives:
        prim = {"attributes": {"POSITION": accessor(np.asarray(positions, "<f4"), 5126, "VEC3", True)}, "mode": mode}
        if faces is not None:
            prim["indices"] = accessor(np.asarray(faces, "<u4").ravel(), 5125, "SCALAR")
        prims.append(prim)
    doc["meshes"] = [{"primitives": prims}]
    doc["buffers"] = [{"byteLength": len(blob)}]
    if meshes is not None:
        meshes(doc)
    text = json.dumps(doc).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(blob), 0x004E4942) + blob
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


def bad_primitive(mesh, problem):
    """``(mode, positions, faces)`` of ``mesh`` with ``problem``: a face index out of range or a NaN position."""
    positions, faces = mesh.positions.copy(), mesh.faces.copy()
    if problem == "index":
        faces[5, 1] = 1_000_000
    else:
        positions[3, 1] = np.nan
    return 4, positions, faces


PROBLEM_WORDS = {"index": "face index 1000000 out of range for 42 vertices",
                 "nan": "1 vertex has NaN or infinite coordinates (first at vertex 3)"}


@pytest.mark.parametrize("problem", sorted(PROBLEM_WORDS))
@pytest.mark.parametrize("where", ["only", "second"])
def test_gltf_primitive_with_invalid_data_is_refused_and_named(capsys, tmp_path, mesh, problem, where):
    """Invalid data in a triangle primitive refuses the asset (as in an OBJ), whether or not
    another primitive could be made progressive; it is never passed through."""
    good = (4, shapes.icosphere(2).positions, shapes.icosphere(2).faces)
    prims = [bad_primitive(mesh, problem)] if where == "only" else [good, bad_primitive(mesh, problem)]
    src = tmp_path / "m.glb"
    src.write_bytes(glb_of(prims))
    k = len(prims) - 1
    status, err, out = run_encode(capsys, tmp_path, src)
    assert_refused(status, err, out, f"m.glb: mesh 0 primitive {k}: {PROBLEM_WORDS[problem]}")
    assert err[0].count("primitive") == 1


def test_gltf_points_and_degenerate_primitives_still_pass_through(capsys, tmp_path, mesh):
    """Valid primitives that are not made progressive pass through with one notice each, exit 0."""
    cloud = np.random.default_rng(3).uniform(-1, 1, (20, 3))
    flat = mesh.faces.copy()
    flat[:, 2] = flat[:, 1]  # every triangle degenerate
    src = tmp_path / "m.glb"
    src.write_bytes(glb_of([(4, mesh.positions, mesh.faces), (0, cloud, None), (4, mesh.positions, flat)]))
    out = tmp_path / "out.pmw"
    status = main(["encode", str(src), "-o", str(out), "--json"])
    captured = capsys.readouterr()
    assert status == 0, captured.err
    notices = json.loads(captured.out)["notices"]
    assert "mesh 0 primitive 1: mode 0 (POINTS) does not draw triangles; passed through unchanged" in notices
    assert "mesh 0 primitive 2: every triangle is degenerate; passed through unchanged" in notices
    assert out.exists()
    doc, _ = load_document(out)
    assert [p.get("mode", 4) for p in doc["meshes"][0]["primitives"]] == [4, 0, 4]


def test_gltf_with_nothing_to_make_progressive_says_why(capsys, tmp_path):
    cloud = np.random.default_rng(3).uniform(-1, 1, (20, 3))
    src = tmp_path / "m.glb"
    src.write_bytes(glb_of([(0, cloud, None)]))
    assert_refused(*run_encode(capsys, tmp_path, src),
                   "m.glb: the asset has no triangle primitive that can be made progressive (mesh 0 primitive 0: mode 0 "
                   "(POINTS) does not draw triangles)")


def test_gltf_with_no_mesh_at_all_is_named_with_its_file_and_says_so(capsys, tmp_path):
    """assimp's SceneWithoutNodes.gltf (a scene, no node, no mesh) was refused with no file name and no reason."""
    src = tmp_path / "m.gltf"
    src.write_text(json.dumps({"asset": {"version": "2.0"}, "scene": 0, "scenes": [{}]}))
    assert_refused(*run_encode(capsys, tmp_path, src),
                   "m.gltf: the asset has no triangle primitive that can be made progressive (it has no mesh)")


@pytest.mark.parametrize("value, shown", [(float("nan"), "NaN"), (float("inf"), "Infinity"), (float("-inf"), "-Infinity")])
@pytest.mark.parametrize("prim", [0, 1])
def test_gltf_non_finite_accessor_min_max_is_refused_and_named(capsys, tmp_path, mesh, value, shown, prim):
    """JSON has no NaN / Infinity (Python's reader takes them): refused naming the member,
    for the accessor of a passed-through primitive (copied to the output) and of a progressive one."""
    cloud = np.random.default_rng(3).uniform(-1, 1, (20, 3))

    def poison(doc):
        doc["accessors"][doc["meshes"][0]["primitives"][prim]["attributes"]["POSITION"]]["min"][1] = value

    src = tmp_path / "m.glb"
    src.write_bytes(glb_of([(4, mesh.positions, mesh.faces), (0, cloud, None)], poison))
    acc = 0 if prim == 0 else 2
    assert_refused(*run_encode(capsys, tmp_path, src), f"m.glb: accessors[{acc}].min[1] is {shown}, which JSON does not allow")


def test_gltf_text_with_a_nan_literal_is_refused_and_named(capsys, tmp_path, mesh):
    doc = gltf_doc(mesh)
    doc["nodes"][0]["translation"] = [0.0, float("nan"), 0.0]
    status, err, out = run_encode(capsys, tmp_path, write_gltf(tmp_path / "asset", doc))
    assert_refused(status, err, out, "m.gltf: nodes[0].translation[1] is NaN")


def png_header_only(width: int, height: int) -> bytes:
    """A PNG whose IHDR declares ``width`` x ``height`` 8-bit gray, with one tiny IDAT."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 64)) + chunk(b"IEND", b"")


@pytest.mark.parametrize("side", [30000, 5000])
def test_huge_watermark_is_refused_from_its_header(capsys, tmp_path, mesh, side):
    assert side * side > MAX_WATERMARK_PIXELS
    src, wm = tmp_path / "m.obj", tmp_path / "wm.png"
    src.write_text(obj_text(mesh))
    wm.write_bytes(png_header_only(side, side))
    assert_refused(*run_encode(capsys, tmp_path, src, "--watermark", wm), "wm.png", f"limit of {MAX_WATERMARK_PIXELS:,} pixels")


def test_key_file_with_deeply_nested_json_is_one_line(capsys, tmp_path, mesh):
    src, wm, key = tmp_path / "m.obj", tmp_path / "wm.png", tmp_path / "k.json"
    src.write_text(obj_text(mesh))
    wm.write_bytes(TINY_PNG)
    key.write_text("[" * 100_000 + "]" * 100_000)
    status, err, out = run_encode(capsys, tmp_path, src, "--watermark", wm, "--key", key)
    assert_refused(status, err, out, "k.json", "nested too deeply")
    assert key.read_text().startswith("[[[")  # left as it was


def test_key_file_that_is_a_fifo_is_refused(capsys, tmp_path, mesh):
    src, wm, key = tmp_path / "m.obj", tmp_path / "wm.png", tmp_path / "k.json"
    src.write_text(obj_text(mesh))
    wm.write_bytes(TINY_PNG)
    os.mkfifo(key)
    assert_refused(*run_encode(capsys, tmp_path, src, "--watermark", wm, "--key", key), "not a regular file")


# --- 3. the safety net ---------------------------------------------------------------------


@pytest.mark.parametrize("exc", [MemoryError(), RecursionError("maximum recursion depth exceeded"),
                                 KeyError("internal"), ZeroDivisionError("division by zero")])
def test_unexpected_exception_is_one_line_and_exit_2(capsys, tmp_path, mesh, monkeypatch, exc):
    """The last net: no traceback, exit 2 (never 1), nothing written (outputs are published whole by the library)."""
    import pmwm_codec

    src, wm = tmp_path / "m.obj", tmp_path / "wm.png"
    src.write_text(obj_text(mesh))
    wm.write_bytes(TINY_PNG)

    def crash(src, dst, **kwargs):
        raise exc

    monkeypatch.setattr(pmwm_codec, "encode", crash)
    assert_refused(*run_encode(capsys, tmp_path, src, "--watermark", wm))


def test_safety_net_leaves_files_that_existed_before(capsys, tmp_path, mesh, monkeypatch):
    import pmwm_codec

    src, out = tmp_path / "m.obj", tmp_path / "out.pmw"
    src.write_text(obj_text(mesh))
    out.write_bytes(b"an older file")
    monkeypatch.setattr(pmwm_codec, "encode", lambda *a, **k: 1 / 0)
    status, err, _ = run_encode(capsys, tmp_path, src)
    assert status == 2 and len(err) == 1 and "ZeroDivisionError" in err[0]
    assert out.read_bytes() == b"an older file"


# --- 4. memory stays bounded ---------------------------------------------------------------

#: Address space allowed to the subprocess: enough for Python with numpy, trimesh and
#: Pillow imported, far below what the old code allocated on these inputs.
ADDRESS_SPACE = 1536 << 20


def run_cli_limited(argv, timeout=300):
    """``python -m pmwm_codec argv`` under RLIMIT_AS = :data:`ADDRESS_SPACE`."""
    def limit():
        resource.setrlimit(resource.RLIMIT_AS, (ADDRESS_SPACE, ADDRESS_SPACE))
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1",
               PYTHONPATH=str(ROOT))
    return subprocess.run([sys.executable, "-m", "pmwm_codec", *argv], capture_output=True, text=True,
                          timeout=timeout, preexec_fn=limit, env=env, cwd=ROOT)


def test_largest_hostile_inputs_are_refused_under_an_address_space_limit(tmp_path, mesh):
    cases = {}
    face_line = tmp_path / "faceline.obj"  # a 200 MB face line: 7.6 GB with the old reader
    with open(face_line, "w") as fh:
        fh.write(obj_text(mesh) + "f")
        block = " 1" * (1 << 20)
        for _ in range(100):
            fh.write(block)
        fh.write("\n")
    cases["faceline"] = ([str(face_line)], "triangles")
    doc = gltf_doc(mesh)
    doc["accessors"][1].pop("bufferView")
    doc["accessors"][1]["count"] = 3 << 34
    cases["count"] = ([str(write_gltf(tmp_path / "count", doc))], "limit")
    wm = tmp_path / "wm.png"
    wm.write_bytes(png_header_only(30000, 30000))
    obj = tmp_path / "m.obj"
    obj.write_text(obj_text(mesh))
    cases["png"] = ([str(obj), "--watermark", str(wm)], "pixels")
    zero = tmp_path / "zero"
    zero.mkdir()
    (zero / "z.bin").symlink_to("/dev/zero")
    doc = gltf_doc(mesh)
    doc["buffers"].append({"byteLength": 1 << 40, "uri": "z.bin"})
    cases["devzero"] = ([str(write_gltf(zero, doc))], "'z.bin'")
    for name, (argv, word) in cases.items():
        out = tmp_path / f"{name}.pmw"
        proc = run_cli_limited(["encode", *argv, "-o", str(out), "-q"])
        assert proc.returncode == 2, (name, proc.stderr[-2000:])
        assert proc.stderr.count("\n") == 1 and proc.stderr.startswith("pmw: error: "), (name, proc.stderr[-2000:])
        assert word in proc.stderr and "MemoryError" not in proc.stderr and "out of memory" not in proc.stderr, name
        assert not out.exists(), name


@pytest.mark.parametrize("cut", [-7, +9], ids=["cut short", "trailing bytes"])
def test_a_binary_stl_whose_size_disagrees_with_its_count_is_named(capsys, tmp_path, mesh, cut):
    src = tmp_path / "m.stl"
    write_mesh(src, mesh)
    data = src.read_bytes()
    src.write_bytes(data[:cut] if cut < 0 else data + bytes(cut))
    assert_refused(*run_encode(capsys, tmp_path, src), "binary STL declares 80 triangles",
                   "cut short" if cut < 0 else "bytes after its last triangle")


# --- outputs: never the input, never a device, a FIFO or a directory -------------------------------


def test_encoding_onto_its_own_input_is_refused_and_the_input_kept(capsys, tmp_path, mesh):
    src = tmp_path / "m.obj"
    write_mesh(src, mesh)
    before = src.read_bytes()
    status = main(["encode", str(src), "-o", str(src), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "is also the input" in err[0], err
    assert src.read_bytes() == before


def test_a_pmw_named_like_a_text_mesh_is_refused(capsys, tmp_path, mesh):
    src = tmp_path / "m.ply"
    write_mesh(src, mesh)
    status = main(["encode", str(src), "-o", str(tmp_path / "m.obj"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "name it .pmw" in err[0], err
    assert not (tmp_path / "m.obj").exists()


@pytest.mark.parametrize("command", ["encode", "decode", "key"])
def test_a_fifo_in_place_of_an_output_is_refused_and_left_alone(capsys, tmp_path, mesh, command):
    """Publishing renames the new file over the target: a device (``-o /dev/null`` run as root) or a
    FIFO would be replaced by a regular file."""
    src = tmp_path / "m.obj"
    write_mesh(src, mesh)
    fifo = tmp_path / ("f.obj" if command == "decode" else "f.pmw")
    if command == "decode":
        assert main(["encode", str(src), "-o", str(tmp_path / "m.pmw"), "-q"]) == 0
        os.mkfifo(fifo)
        argv = ["decode", str(tmp_path / "m.pmw"), "-o", str(fifo)]
    elif command == "encode":
        os.mkfifo(fifo)
        argv = ["encode", str(src), "-o", str(fifo), "-q"]
    else:  # the default key file beside the output
        os.mkfifo(str(tmp_path / "k.pmw") + ".key.json")
        fifo = Path(str(tmp_path / "k.pmw") + ".key.json")
        argv = ["encode", str(src), "-o", str(tmp_path / "k.pmw"), "--owner-id", "12", "-q"]
    capsys.readouterr()
    status = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "not a regular file" in err[0], err
    assert fifo.is_fifo()
    assert not (tmp_path / "k.pmw").exists()


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_a_fifo_named_as_a_gltf_input_is_refused_without_being_opened(capsys, tmp_path, suffix):
    """Telling a renamed .pmw or a meshopt file from a plain glTF sniffs the JSON: never of a FIFO (opening one
    blocks until a writer comes)."""
    from pmwm_codec.format.document import sniff_json
    from pmwm_codec.watermark.key import WatermarkKey

    fifo = tmp_path / f"f{suffix}"
    os.mkfifo(fifo)
    key = tmp_path / "k.json"
    WatermarkKey.generate(rng=np.random.default_rng(1)).save(key)
    assert sniff_json(fifo) is None
    capsys.readouterr()
    status = main(["verify", str(fifo), "--key", str(key)])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and "not a regular file" in err[0], err


def test_the_atomic_writer_never_replaces_a_device(tmp_path):
    from pmwm_codec.atomic import write_atomic

    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    with pytest.raises(OSError, match="refusing to replace it"):
        write_atomic(fifo, [b"x"])
    assert fifo.is_fifo()


@pytest.mark.parametrize("offset, bits, advice", [(1000.0, 16, "--grid-bits 15"), (1e6, 16, "move the mesh nearer"),
                                                  (0.0, 30, "--grid-bits 25")])
def test_a_grid_float32_cannot_carry_is_refused_before_any_work_with_the_grid_that_can(capsys, tmp_path, offset, bits,
                                                                                         advice):
    src = tmp_path / "m.obj"
    sphere = shapes.icosphere(3, 1.0, noise=0.01)  # 642 vertices: none of them on a float32-friendly point by luck
    write_mesh(src, type(sphere)(sphere.positions + offset, sphere.faces))
    status, err, out = run_encode(capsys, tmp_path, src, "--grid-bits", str(bits))
    assert_refused(status, err, out, f"a {bits}-bit position grid", "float32", advice)
    if "--grid-bits" in advice:  # and the advice holds
        assert run_encode(capsys, tmp_path, src, "--grid-bits", advice.split()[-1])[0] == 0


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "-1e999"])
def test_a_pmw_whose_json_holds_a_non_finite_number_is_a_format_error_naming_it(capsys, tmp_path, mesh, literal):
    """Python's JSON reader takes NaN / Infinity / 1e999; JSON does not, and writing the document back
    (decode to .glb) failed with a message calling it a bug of pmw."""
    import json

    from pmwm_codec.format.glb import frame_glb, split_glb

    src = tmp_path / "m.obj"
    write_mesh(src, mesh)
    assert main(["encode", str(src), "-o", str(tmp_path / "m.pmw"), "-q"]) == 0
    data = (tmp_path / "m.pmw").read_bytes()
    gltf, binary = split_glb(data)
    gltf["nodes"][0]["translation"] = [0.5, 0, 0]
    text = json.dumps(gltf, separators=(",", ":")).replace("[0.5,0,0]", f"[{literal},0,0]").encode()
    bad = tmp_path / "bad.pmw"
    bad.write_bytes(b"".join(frame_glb(text, [binary], len(binary))))
    for argv in (["decode", str(bad), "-o", str(tmp_path / "out.glb")], ["info", str(bad)]):
        capsys.readouterr()
        status = main(argv)
        err = capsys.readouterr().err.strip().splitlines()
        assert status == 2 and len(err) == 1, err
        assert "nodes[0].translation[0]" in err[0] and "bug" not in err[0], err
    assert not (tmp_path / "out.glb").exists()


# --- the blind read of pmw verify goes through the same reader as pmw encode --------------------


def _owner_key(tmp_path) -> Path:
    from pmwm_codec.watermark.key import WatermarkKey

    path = tmp_path / "owner.key.json"
    WatermarkKey.generate(rng=np.random.default_rng(3), owner_id=0x0123456789ABCDEF).save(path)
    return path


def test_verify_of_a_gltf_whose_buffer_is_a_fifo_is_refused_without_blocking(tmp_path, mesh):
    """``pmw verify ASSET.gltf --key K`` read glTF through trimesh, which opened a FIFO named by a
    ``uri`` and blocked forever; it now reads what ``pmw encode`` reads: one line, exit 2."""
    folder = tmp_path / "asset"
    folder.mkdir()
    doc = gltf_doc(mesh)
    doc["buffers"][0]["uri"] = "geo.bin"
    os.mkfifo(folder / "geo.bin")
    src = write_gltf(folder, doc)
    proc = run_cli_limited(["verify", str(src), "--key", str(_owner_key(tmp_path))], timeout=120)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "'geo.bin'" in proc.stderr and "not a regular file" in proc.stderr


@pytest.mark.parametrize("edit, words", [
    (lambda d: d["accessors"][0].update(count=10**6), "reads past its bufferView"),
    (lambda d: d["accessors"][0].update(byteOffset=4), "reads past its bufferView"),
    (lambda d: d["accessors"][0].update(bufferView=99), "bufferView = 99"),
    (lambda d: d["nodes"][0].update(children=[0]), "own child"),
    (lambda d: d["buffers"].append({"byteLength": 10, "uri": "../secret.txt"}), "outside the asset's folder"),
])
def test_verify_names_a_broken_gltf_as_encode_does(capsys, tmp_path, mesh, secret, edit, words):
    doc = gltf_doc(mesh)
    edit(doc)
    src = write_gltf(tmp_path / "asset", doc)
    status = main(["verify", str(src), "--key", str(_owner_key(tmp_path))])
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and err[0].startswith("pmw: error: ") and words in err[0], err
