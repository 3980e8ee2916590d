"""The JavaScript decoder (js/) reproduces the Python decoder exactly on every corpus mesh.

Each corpus mesh is encoded with Python into a temporary .pmw (Draco base; one plain base too),
then ``node js/tools/dump.mjs`` prints the JS decode at every chunk boundary (counts, bytes read and
a SHA-256 of the level's positions, faces and quantized attributes) and the Python decoder's
levels must match line for line.  The conformance files are compared by the Node tests themselves
(``npm test --prefix js``).  Skips when node or js/node_modules is absent, or ../shared is.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec.meshdoc import srgb_from_linear
from pmwm_codec.stream import StreamDecoder

from conftest import CORPUS_MESHES, corpus_path
from samples import level_digest

ROOT = Path(__file__).resolve().parents[1]
DUMP = ROOT / "js" / "tools" / "dump.mjs"


def _node() -> str:
    node = shutil.which("node")
    if node is None or not (ROOT / "js" / "node_modules" / "zstddec").exists():
        pytest.skip("node or js/node_modules absent (npm ci --prefix js)")
    return node


def _python_levels(data: bytes) -> list:
    dec = StreamDecoder()
    results = dec.feed(data)
    assert dec.close().complete
    return [
        {"chunk": r.chunk, "bytesRead": r.bytes_read, "vertexCount": r.vertices, "faceCount": r.faces_count,
         "parts": [[len(p.positions_int), len(p.faces)] for p in r.parts], "sha256": level_digest(r)}
        for r in results
    ]


def _js_levels(node: str, path: Path) -> tuple[list, dict]:
    out = subprocess.run([node, str(DUMP), str(path)], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    lines = [json.loads(line) for line in out.stdout.splitlines()]
    return lines[:-1], lines[-1]["end"]


def _corpus_file(name: str) -> Path:
    """The corpus asset of `name`: its .glb when there is one (attributes, textures), else its .obj."""
    for suffix in (".glb", ".obj"):
        path = corpus_path("") / f"{name}{suffix}"
        if path.exists():
            return path
    return corpus_path(f"{name}.obj")


@pytest.mark.parametrize("name", CORPUS_MESHES)
def test_js_decoder_matches_python_at_every_chunk_boundary(name, tmp_path):
    node = _node()
    src = _corpus_file(name)
    dst = tmp_path / f"{name}.pmw"
    pmwm_codec.encode(str(src), str(dst), measure=False)
    js, end = _js_levels(node, dst)
    assert end["complete"]
    assert js == _python_levels(dst.read_bytes())


def test_js_decoder_matches_python_on_a_plain_base_with_a_watermark(tmp_path):
    node = _node()
    dst = tmp_path / "cow.pmw"
    stripes = (np.indices((16, 16)).sum(0) % 2 * 200 + 20).astype(np.uint8)
    pmwm_codec.encode(str(corpus_path("cow.obj")), str(dst), watermark=stripes, base_codec="plain", measure=False)
    js, end = _js_levels(node, dst)
    assert end["complete"] and end["chunksApplied"] == end["chunkCount"]
    assert js == _python_levels(dst.read_bytes())


def test_js_decoder_matches_python_on_an_asset_whose_primitives_carry_different_attributes(tmp_path):
    """Real assets mix primitives with and without NORMAL / TEXCOORD_0 (4 of the 82 webxr-input-profiles
    controllers): the two decoders agree on those too (this comparison could not digest such a level before:
    it stacked the parts' attribute rows, of different widths)."""
    from test_asset import DocBuilder

    from pmwm_codec import shapes

    node = _node()
    b = DocBuilder()
    textured, plain = shapes.icosphere(3, noise=0.05, seed=1), shapes.icosphere(3, noise=0.05, seed=2)
    b.doc.update(scene=0, scenes=[{"nodes": [0, 1]}], nodes=[{"mesh": 0}, {"mesh": 1, "translation": [3.0, 0.0, 0.0]}],
                 meshes=[{"primitives": [b.triangles(textured)]}, {"primitives": [b.triangles(plain, uv=False)]}])
    (tmp_path / "mixed.glb").write_bytes(b.glb())
    dst = tmp_path / "mixed.pmw"
    pmwm_codec.encode(str(tmp_path / "mixed.glb"), str(dst), measure=False)
    python = _python_levels(dst.read_bytes())
    assert len(python) > 2 and len(python[-1]["parts"]) == 2
    js, end = _js_levels(node, dst)
    assert end["complete"] and js == python


def test_js_decoder_matches_python_on_a_textured_coloured_obj_of_two_materials(tmp_path):
    """An OBJ's appearance (pmwm_codec.meshdoc) streams as an asset: per-material primitives with TEXCOORD_0 and
    COLOR_0; the JavaScript decoder reads every level of it as the Python one does."""
    from test_obj_appearance import _torus_obj

    node = _node()
    path, *_ = _torus_obj(str(tmp_path), "t.obj", mtl="t.mtl", colours=True)
    lines = open(path).read().splitlines()
    faces = sorted((line for line in lines if line.startswith("f ")),
                   key=lambda f: min(int(c.split("/")[0]) for c in f.split()[1:]))  # by ring: positions are
    half = len(faces) // 2
    lines = [line for line in lines if not line.startswith("f ")] + faces[:half] + ["usemtl bark"] + faces[half:]
    (tmp_path / "t.obj").write_text("\n".join(lines) + "\n")  # the torus's second half another material
    (tmp_path / "t.mtl").write_text("newmtl skin\nKd 0.8 0.5 0.4\nnewmtl bark\nKd 0.3 0.2 0.1\n")
    dst = tmp_path / "t.pmw"
    pmwm_codec.encode(path, str(dst), measure=False)
    python = _python_levels(dst.read_bytes())
    assert len(python) > 2 and len(python[-1]["parts"]) == 2
    js, end = _js_levels(node, dst)
    assert end["complete"] and js == python


def test_js_decoder_matches_python_on_a_ply_of_8_bit_srgb_colours_on_their_byte_grid(tmp_path):
    """A PLY's uchar colours (and alpha) are sRGB bytes, carried exact on their ``srgb8`` byte grid (spec/README.md,
    attributes: transfer); the JavaScript decoder writes each byte's float32 as the Python one does, the base's
    values mapped back to bytes (base.js srgb8Into) and every level's values (decoder.js dequantizeSrgb8)."""
    from test_ply_appearance import corners, ply_bytes, xyz

    from pmwm_codec import shapes

    node = _node()
    mesh = shapes.icosphere(4, noise=0.01, seed=4)
    rgba = np.random.default_rng(7).integers(0, 256, (len(mesh.positions), 4)).astype(np.uint8)
    colours = [(c, "uchar", rgba[:, i]) for i, c in enumerate(("red", "green", "blue", "alpha"))]
    (tmp_path / "c.ply").write_bytes(ply_bytes("binary_little_endian", xyz(mesh.positions) + colours,
                                               corners(mesh.faces)))
    dst = tmp_path / "c.pmw"
    pmwm_codec.encode(str(tmp_path / "c.ply"), str(dst), measure=False)
    data = dst.read_bytes()
    ext = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])["meshes"][0]["primitives"][0]
    (colour,) = [a for a in ext["extensions"]["PMWM_progressive_mesh"]["attributes"] if a["semantic"] == "COLOR_0"]
    assert colour["transfer"] == "srgb8" and colour["bits"] == 8 and colour["step"] == [1, 1, 1, 1]
    python = _python_levels(data)
    assert len(python) > 2
    js, end = _js_levels(node, dst)
    assert end["complete"] and js == python
    script = ("import { readFileSync } from 'node:fs'; import { PmwDecoder } from './src/index.js';"
              "const d = new PmwDecoder(); await d.feed(new Uint8Array(readFileSync(process.argv[1]))); await d.close();"
              "const c = d.snapshot().parts[0].attributes.COLOR_0;"
              "process.stdout.write(Buffer.from(c.buffer, c.byteOffset, c.byteLength).toString('hex'));")
    out = subprocess.run([node, "--input-type=module", "-e", script, str(dst)], capture_output=True, text=True,
                         cwd=ROOT / "js", timeout=120)
    assert out.returncode == 0, out.stderr
    dec = StreamDecoder()
    last = dec.feed(data)[-1]
    want = last.parts[0].attribute_values()["COLOR_0"]
    assert bytes.fromhex(out.stdout) == np.ascontiguousarray(want, "<f4").tobytes()  # every float32, bit for bit
    assert np.array_equal(np.rint(srgb_from_linear(want) * 255), _in_decoded_order(last, mesh.positions, rgba))


def _in_decoded_order(level, positions: np.ndarray, values: np.ndarray) -> np.ndarray:
    """``values`` (one row per input vertex at ``positions``) in the order of the decoded ``level``'s vertices."""
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(positions).query(level.parts[0].positions)
    return values[nearest]


def test_js_decoder_matches_python_on_8_bit_colours_on_their_own_lattice(tmp_path):
    """An asset's COLOR_0 of 8-bit values (k / 255, as a normalized UNSIGNED_BYTE accessor holds them) rides on
    the 8-bit lattice (step 1/255, exact: encoder._colour_lattice); the JavaScript decoder reads that grid's
    levels as the Python one does."""
    from pmwm_codec import shapes
    from pmwm_codec.meshdoc import Part, build_document

    node = _node()
    mesh = shapes.icosphere(4, noise=0.01, seed=4)
    rgb = (np.clip((mesh.positions + 1) / 2, 0, 1) * 255).astype(np.uint8)
    document = build_document([Part(mesh.positions, mesh.faces, {"COLOR_0": rgb / 255.0})], [], [], "c")
    dst = tmp_path / "c.pmw"
    pmwm_codec.encode(document, str(dst), measure=False)
    data = dst.read_bytes()
    ext = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])["meshes"][0]["primitives"][0]
    (colour,) = [a for a in ext["extensions"]["PMWM_progressive_mesh"]["attributes"] if a["semantic"] == "COLOR_0"]
    assert colour["bits"] == 8 and colour["step"] == [1 / 255] * 3
    python = _python_levels(data)
    assert len(python) > 2
    js, end = _js_levels(node, dst)
    assert end["complete"] and js == python


@pytest.mark.parametrize("change, words", [
    ({"transfer": "gamma"}, "srgb8"),
    ({"origin": [300, 0, 0, 0]}, "origins in 0..255"),
    ({"step": [2, 1, 1, 1]}, "steps of 1"),
    ({"semantic": "NORMAL"}, None),  # then the base has no NORMAL: refused either way
    ({"origin": [1, 1, 1, 1]}, None),  # a base byte below the origin, or other bytes than the digest's
])
def test_both_decoders_refuse_an_srgb8_grid_that_is_malformed_or_off_its_base(tmp_path, change, words):
    """A crafted ``transfer`` / origin / step of an ``srgb8`` COLOR_0 is a format error in Python (one line, no
    traceback, exit 2) and in JavaScript (a FormatError), never wrong colours."""
    from test_chunk_mac import _rewrite_json
    from test_ply_appearance import corners, ply_bytes, xyz

    from pmwm_codec import shapes

    node = _node()
    mesh = shapes.icosphere(2)
    rgba = np.random.default_rng(9).integers(20, 250, (len(mesh.positions), 4)).astype(np.uint8)
    colours = [(c, "uchar", rgba[:, i]) for i, c in enumerate(("red", "green", "blue", "alpha"))]
    (tmp_path / "c.ply").write_bytes(ply_bytes("binary_little_endian", xyz(mesh.positions) + colours,
                                               corners(mesh.faces)))
    pmwm_codec.encode(str(tmp_path / "c.ply"), str(tmp_path / "c.pmw"), measure=False)

    def edit(gltf, binary):
        (colour,) = gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]["attributes"]
        assert colour["transfer"] == "srgb8"
        colour.update(change)

    bad = tmp_path / "bad.pmw"
    bad.write_bytes(_rewrite_json((tmp_path / "c.pmw").read_bytes(), edit))
    run = subprocess.run([sys.executable, "-m", "pmwm_codec", "decode", str(bad), "-o", str(tmp_path / "o.glb")],
                         capture_output=True, text=True)
    assert run.returncode == 2 and "Traceback" not in run.stderr and run.stderr.count("\n") == 1, run.stderr
    assert words is None or words in run.stderr
    out = subprocess.run([node, str(DUMP), str(bad)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 2 and ("FormatError" in out.stderr or "CorruptChunkError" in out.stderr), out.stderr
    assert words is None or words in out.stderr
