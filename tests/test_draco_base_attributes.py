"""A Draco base carries the progressive attributes (texture coordinates, colours, joints, normals) exactly.

Before, a primitive with attributes always got a plain base (float32 accessors): for a textured scan whose
seam corners hold a fifth of its vertices in the base, 44% of the file. The Draco base stores TEXCOORD_0 as
Draco's texture coordinate (quantized finer than our grid, rounded back) and every other attribute as a
generic Draco attribute; the readers weld its seam copies by the weld attribute, attribute values and all
(spec README, *Base mesh* and *Welded base*).
"""

from __future__ import annotations

import io

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.errors import FormatError
from pmwm_codec.format import base as basecodec
from pmwm_codec.format.gltf import BufferBuilder
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive.grid import SRGB8_TO_LINEAR, AttributeGrid, Grid
from pmwm_codec.stream import StreamDecoder, encode_mesh


def _textured(rings=24, sides=12, seed=7) -> Mesh:
    """A UV torus (seams: copies of one position) with sRGB colours, byte joints and normals per vertex."""
    torus = shapes.uv_torus(rings, sides)
    n = len(torus.positions)
    rng = np.random.default_rng(seed)
    normals = torus.positions - torus.positions.mean(0)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return Mesh(torus.positions, torus.faces, attributes={
        **torus.attributes, "COLOR_0": SRGB8_TO_LINEAR[rng.integers(0, 256, (n, 3))].astype(np.float64),
        "JOINTS_0": rng.integers(0, 6, (n, 4)).astype(np.uint8), "NORMAL": normals})


def _encode(mesh, **options) -> bytes:
    buf = io.BytesIO()
    encode_mesh(mesh, buf, measure=False, **options)
    return buf.getvalue()


def _levels(data: bytes) -> list:
    """Every level as a sorted list of its corners (each corner: grid position and attribute integers), so
    that two files whose vertices come in another order compare equal when they hold the same mesh."""
    dec = StreamDecoder()
    results = dec.feed(data)
    assert dec.close().complete
    out = []
    for r in results:
        rows = np.concatenate([np.column_stack([p.positions_int, p.attributes_int]) for p in r.parts])
        corners = rows[np.asarray(r.faces)]  # (m, 3, d)
        faces = sorted(min(tuple(map(tuple, np.roll(f, -k, axis=0))) for k in range(3)) for f in corners)
        out.append(faces)
    return out


def _glb_json(data: bytes) -> dict:
    import json
    import struct

    n = struct.unpack("<I", data[12:16])[0]
    return json.loads(data[20:20 + n])


def test_every_kind_of_attribute_rides_on_a_draco_base_and_reads_back_exactly():
    mesh = _textured()
    grid = Grid.fit(mesh.positions, 14)
    pos = grid.quantize(mesh.positions)
    attributes = []
    for semantic, bits, values in (("TEXCOORD_0", 14, mesh.attributes["TEXCOORD_0"]),
                                   ("NORMAL", 12, mesh.attributes["NORMAL"])):
        g = AttributeGrid.fit(values, bits)
        ints = np.rint((values - np.asarray(g.origin)) / np.asarray(g.step)).astype(np.int64)
        attributes.append(({"semantic": semantic, **g.get_config()}, ints))
    joints = mesh.attributes["JOINTS_0"].astype(np.int64)
    attributes.append(({"semantic": "JOINTS_0", "bits": 8, "origin": [0.0] * 4, "step": [1.0] * 4,
                        "componentType": 5121}, joints))
    enc = basecodec.encode_base(pos, mesh.faces, grid, codec="draco", attributes=attributes)
    assert enc.codec == "draco" and enc.notice is None
    ids = enc.primitive["extensions"]["KHR_draco_mesh_compression"]["attributes"]
    assert {"POSITION", "TEXCOORD_0", "NORMAL", "JOINTS_0"} <= set(ids)
    gltf = {"accessors": enc.accessors, "bufferViews": enc.buffer_views}
    prim = {**enc.primitive, "extensions": {**enc.primitive["extensions"], "PMWM_progressive_mesh": {
        "grid": grid.get_config(), **({} if enc.welded_count is None else {"baseVertexCount": enc.welded_count})}}}
    specs = [spec for spec, _ in attributes]
    positions, faces, values = basecodec.read_base(gltf, enc.data, grid, prim, specs)
    assert np.array_equal(positions, pos[enc.vertex_map])
    assert np.array_equal(values, np.concatenate([ints for _, ints in attributes], axis=1)[enc.vertex_map])
    assert len(faces) == len(mesh.faces)
    assert enc.accessors[prim["attributes"]["JOINTS_0"]]["componentType"] == 5121  # a viewer skins the base


def test_a_textured_mesh_streams_the_same_levels_from_a_draco_base_as_from_a_plain_one():
    mesh = _textured(32, 16)
    draco, plain = _encode(mesh, base_codec="draco"), _encode(mesh, base_codec="plain")
    prim = _glb_json(draco)["meshes"][0]["primitives"][0]
    assert "KHR_draco_mesh_compression" in prim.get("extensions", {})
    assert _levels(draco) == _levels(plain)


def test_a_draco_base_makes_a_textured_file_smaller_and_its_first_level_come_sooner():
    mesh = shapes.uv_torus(96, 48)
    draco, plain = _encode(mesh, base_codec="draco"), _encode(mesh, base_codec="plain")
    # the base's own bytes: what the first level needs past the GLB header, the JSON and the BIN header
    base = [StreamDecoder().feed(d)[0].bytes_read - 28 - int.from_bytes(d[12:16], "little") for d in (draco, plain)]
    assert len(draco) < len(plain) and base[0] < base[1] / 2, (len(draco), len(plain), base)


def test_copies_the_weld_joins_must_carry_the_same_attribute_values():
    """A plain welded base (the reader's other path): a copy of vertex 0 that carries vertex 0's texture
    coordinate welds; one that carries another is refused, not silently given vertex 0's."""
    grid = Grid(10, (0.0, 0.0, 0.0), 1.0)
    pos = np.array([[0, 0, 0], [9, 0, 0], [0, 9, 0], [0, 0, 9], [0, 0, 0]], np.int64)
    faces = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [4, 3, 2]], np.int64)
    uv_grid = AttributeGrid(8, (0.0, 0.0), (1.0 / 255, 1.0 / 255))
    spec = {"semantic": "TEXCOORD_0", **uv_grid.get_config()}

    def read(copy_uv):
        uv = np.array([[0, 0], [255, 0], [0, 255], [128, 128], copy_uv], np.int64)
        enc = basecodec.encode_base(pos, faces, grid, codec="plain", attributes=[(spec, uv)])
        out = BufferBuilder(list(enc.buffer_views), list(enc.accessors), [enc.data], len(enc.data))
        weld = out.add_vertex_integers(np.zeros((5, 1)), 5121, 34962)
        prim = {**enc.primitive, "attributes": {**enc.primitive["attributes"], "_PMWM_WELD": weld},
                "extensions": {"PMWM_progressive_mesh": {"grid": grid.get_config(), "baseVertexCount": 4}}}
        gltf = {"accessors": out.accessors, "bufferViews": out.views}
        return basecodec.read_base(gltf, b"".join(out.parts), grid, prim, [spec])

    positions, welded, values = read([0, 0])
    assert len(positions) == 4 and welded[3].tolist() == [0, 3, 2] and values[0].tolist() == [0, 0]
    with pytest.raises(FormatError, match="copies the weld joins carry different attribute values"):
        read([3, 0])


def test_texture_coordinates_draco_cannot_quantize_exactly_ride_as_generic_floats(monkeypatch):
    """Where Draco's quantized texture coordinate would not round back to the grid (here: forced to 2 bits),
    the base stays a Draco base with TEXCOORD_0 as a generic float attribute, not a plain base."""
    plan = basecodec._draco_attribute_plan

    def too_coarse(attributes, texture=True):
        return [p if p.key is not None else basecodec._DracoAttribute(p.spec, None, p.values, p.component_type, 2)
                for p in plan(attributes, texture)]

    monkeypatch.setattr(basecodec, "_draco_attribute_plan", too_coarse)
    mesh = shapes.uv_torus(24, 12)
    grid = Grid.fit(mesh.positions, 14)
    uv = mesh.attributes["TEXCOORD_0"]
    g = AttributeGrid.fit(uv, 14)
    ints = np.rint((uv - np.asarray(g.origin)) / np.asarray(g.step)).astype(np.int64)
    spec = {"semantic": "TEXCOORD_0", **g.get_config()}
    enc = basecodec.encode_base(grid.quantize(mesh.positions), mesh.faces, grid, codec="draco", attributes=[(spec, ints)])
    assert enc.codec == "draco" and enc.notice is None
    gltf = {"accessors": enc.accessors, "bufferViews": enc.buffer_views}
    prim = {**enc.primitive, "extensions": {**enc.primitive["extensions"], "PMWM_progressive_mesh": {
        "grid": grid.get_config(), **({} if enc.welded_count is None else {"baseVertexCount": enc.welded_count})}}}
    assert np.array_equal(basecodec.read_base(gltf, enc.data, grid, prim, [spec])[2], ints[enc.vertex_map])
    import DracoPy

    stored = DracoPy.decode(enc.data[: enc.buffer_views[0]["byteLength"]])
    assert 3 not in {a["attribute_type"] for a in stored.attributes}  # no Draco texture coordinate: a generic one


# A triangle a tenth of a millimetre across with texture coordinates: Draco's encoder refuses its texture
# coordinate at compression level 7 with our grid's range ("Failed to encode point attributes"), and says
# so on the process's file descriptor 2; the encoder falls back to a generic attribute.
_REFUSED_TRIANGLE_OBJ = """v 2.4e-05 -5e-07 -1.284e-04
v -3.5e-06 -1.74e-05 -1.311e-04
v -3.5e-06 -6e-07 -1.306e-04
vt 0.89 0.98
vt 0.92 0.99
vt 0.91 0.98
f 1/1 2/2 3/3
"""


def _run(tmp_path, code: str):
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=tmp_path, timeout=120)


def test_draco_refusing_a_base_leaves_no_message_on_the_users_terminal(tmp_path):
    (tmp_path / "tri.obj").write_text(_REFUSED_TRIANGLE_OBJ)
    done = _run(tmp_path, "import sys; from pmwm_codec.cli import main; sys.exit(main(['encode', 'tri.obj', '-o', 'tri.pmw']))")
    assert done.returncode == 0, done.stderr
    assert "Draco" not in done.stderr, done.stderr
    back = _run(tmp_path, "import sys; from pmwm_codec.cli import main; sys.exit(main(['decode', 'tri.pmw', '-o', 'back.obj']))")
    assert back.returncode == 0 and "Draco" not in back.stderr, back.stderr
    lines = (tmp_path / "back.obj").read_text().splitlines()
    uv = sorted(tuple(float(x) for x in line.split()[1:3]) for line in lines if line.startswith("vt "))
    assert np.allclose(uv, [(0.89, 0.98), (0.91, 0.98), (0.92, 0.99)], atol=1e-4)  # the texture coordinates kept


def test_draco_messages_are_caught_and_other_output_on_stderr_is_passed_on(tmp_path):
    done = _run(tmp_path, "\n".join([
        "import os",
        "from pmwm_codec.format.base import _draco_messages",
        "with _draco_messages() as said:",
        "    os.write(2, b'Draco encoding error: Failed to encode point attributes.\\n')",
        "    os.write(2, b'another thread wrote this\\n')",
        "print(said)",
    ]))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "['Draco encoding error: Failed to encode point attributes.']"
    assert done.stderr == "another thread wrote this\n"


def test_threads_catching_draco_messages_at_once_each_get_their_own_and_leave_stderr_as_it_was(tmp_path):
    done = _run(tmp_path, "\n".join([
        "import os, threading, time",
        "from pmwm_codec.format.base import _draco_messages",
        "got = {}",
        "def work(k):",
        "    for i in range(50):",
        "        with _draco_messages() as said:",
        "            time.sleep(0.0005)",  # another thread runs meanwhile
        "            os.write(2, f'Draco {k} {i}\\n'.encode())",
        "        got.setdefault(k, []).extend(said)",
        "threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]",
        "[t.start() for t in threads]; [t.join() for t in threads]",
        "os.write(2, b'after\\n')",
        "print(all(got[k] == [f'Draco {k} {i}' for i in range(50)] for k in range(4)))",
    ]))
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "True" and done.stderr == "after\n"
