"""The ``pmw`` command end to end: ``pmwm_codec.cli.main(argv)`` on temp dirs, meshes and watermarks made here,
and the library functions behind it (``verify_stream``, ``inspect``) against its ``--json`` output."""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pygltflib
import pytest
import trimesh
from PIL import Image

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.watermark import WatermarkKey
from pmwm_codec.cli import main
from pmwm_codec.cli.common import jsonable
import math
from pmwm_codec.meshio import write_mesh

ENCODE_FIELDS = {"vertices", "faces", "base_vertices", "base_faces", "vsplits", "chunks", "bytes", "seconds",
                 "distortion", "watermark"}
DISTORTION_FIELDS = {"rms", "psnr_db", "hausdorff", "bbox_diagonal"}
WATERMARK_FIELDS = {"width", "height", "mode", "bits", "codes", "embedded"}
VERIFY_FIELDS = {"complete", "truncated", "chunks_total", "chunks", "final", "verdict"}
CHUNK_FIELDS = {"chunk", "bytes_read", "vertices", "faces", "coefficients", "nc", "psnr_db"}
DECODE_FIELDS = {"vertices", "faces", "chunks_applied", "complete"}
ROOT = Path(__file__).resolve().parents[1]


def strict_json(text):
    """Parse exactly one JSON object; NaN/Infinity are not JSON."""
    def refuse(name):
        raise ValueError(f"not JSON: {name}")
    lines = [line for line in text.splitlines() if line.strip()]
    assert len(lines) == 1, text
    return json.loads(lines[0], parse_constant=refuse)


def run(capsys, *argv):
    """``(exit status, stdout, stderr)`` of ``pmw argv``."""
    code = main([os.fspath(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def write_obj(path, mesh):
    write_mesh(path, mesh)
    return path


def pattern(size: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[:size, :size]
    img = 128 + 90 * np.sin(x / 3.0) * np.cos(y / 5.0) + rng.integers(-20, 20, (size, size))
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """An icosphere(5) (10k vertices) as OBJ, a 32x32 watermark, and its encoded .pmw + key."""
    d = tmp_path_factory.mktemp("pmw")
    mesh = write_obj(d / "sphere.obj", shapes.icosphere(5, 1.0, noise=0.01))
    mark = d / "mark.png"
    Image.fromarray(pattern(32)).save(mark)
    other = d / "other.png"
    Image.fromarray(255 - pattern(32, seed=7)).save(other)
    pmw = d / "sphere.pmw"
    assert main(["encode", str(mesh), "-o", str(pmw), "--watermark", str(mark), "--quiet"]) == 0
    return {"dir": d, "mesh": mesh, "mark": mark, "other": other, "pmw": pmw, "key": d / "sphere.pmw.key.json"}


def stdin_bytes(monkeypatch, data: bytes):
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BytesIO(data)))


# -- encode -------------------------------------------------------------------------------

def test_encode_json_has_the_contract_fields(work, tmp_path, capsys):
    out = tmp_path / "a.pmw"
    code, stdout, err = run(capsys, "encode", work["mesh"], "-o", out, "--watermark", work["mark"], "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    assert ENCODE_FIELDS <= doc.keys()
    assert DISTORTION_FIELDS <= doc["distortion"].keys()
    assert WATERMARK_FIELDS <= doc["watermark"].keys()
    assert doc["watermark"]["width"] == 32 and doc["bytes"] == out.stat().st_size
    assert doc["vertices"] == 10242 and doc["vsplits"] == doc["vertices"] - doc["base_vertices"]
    assert (tmp_path / "a.pmw.key.json").exists() and doc["key_path"].endswith("a.pmw.key.json")


def test_encode_prints_a_summary(work, tmp_path, capsys):
    out = tmp_path / "b.pmw"
    key = tmp_path / "my.key"
    code, stdout, _ = run(capsys, "encode", work["mesh"], "-o", out, "--watermark", work["mark"], "--key", key)
    assert code == 0
    assert "vertex splits" in stdout and "32x32" in stdout and str(key) in stdout
    assert key.exists() and not (tmp_path / "b.pmw.key.json").exists()


def test_encode_with_an_existing_key_reuses_it(work, tmp_path, capsys):
    out = tmp_path / "c.pmw"
    code, _, _ = run(capsys, "encode", work["mesh"], "-o", out, "--watermark", work["mark"], "--key", work["key"], "-q")
    assert code == 0
    assert WatermarkKey.load(work["key"]).fingerprint() == json.loads(
        json.dumps(_info(capsys, out)["watermark"]))["keyFingerprint"]


def test_encode_without_watermark_writes_no_key(tmp_path, capsys):
    src = write_obj(tmp_path / "t.obj", shapes.torus(24, 12))
    code, stdout, _ = run(capsys, "encode", src, "-o", tmp_path / "t.pmw", "--json")
    assert code == 0
    doc = strict_json(stdout)
    assert doc["watermark"] is None and not (tmp_path / "t.pmw.key.json").exists()


def test_encode_without_watermark_names_every_image_option_it_ignores(tmp_path, capsys):
    """--bits, --mode paper and --fit shape only the image's mark: without --watermark they change
    nothing in the file, which a note says (as for --embed-from), never silently."""
    src = write_obj(tmp_path / "t.obj", shapes.torus(24, 12))
    code, stdout, err = run(capsys, "encode", src, "-o", tmp_path / "t.pmw", "--bits", "4", "--mode", "paper",
                            "--fit", "--embed-from", "3", "--json")
    assert code == 0, err
    notices = strict_json(stdout)["notices"]
    for name in ("--bits", "--mode paper", "--fit", "--embed-from"):
        assert f"{name} ignored: no --watermark" in notices, notices


def test_encode_options_reach_the_file(work, tmp_path, capsys):
    out = tmp_path / "p.pmw"
    code, stdout, err = run(capsys, "encode", work["mesh"], "-o", out, "--watermark", work["mark"], "--mode", "paper",
                            "--bits", "4", "--grid-bits", "20", "--base-codec", "plain", "--base-vertices", "200",
                            "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    assert doc["watermark"]["mode"] == "paper" and doc["watermark"]["bits"] == 4
    info = _info(capsys, out)
    assert info["base_codec"] == "plain" and info["grid"]["bits"] == 20 and info["watermark"]["mode"] == "paper"


# -- decode -------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".glb", ".gltf", ".obj", ".ply"])
def test_decode_writes_every_format(work, tmp_path, capsys, suffix):
    out = tmp_path / f"level{suffix}"
    code, stdout, err = run(capsys, "decode", work["pmw"], "-o", out, "--chunks", "2", "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    assert DECODE_FIELDS <= doc.keys()
    assert doc["chunks_applied"] == 2 and doc["complete"] is True
    loaded = trimesh.load(out, force="mesh", process=False)
    assert loaded.vertices.shape == (doc["vertices"], 3) and loaded.faces.shape == (doc["faces"], 3)
    assert [p.name for p in tmp_path.iterdir()] == [out.name]  # no temp file left


def test_decode_quiet_prints_nothing_on_success_and_still_writes(work, tmp_path, capsys):
    """``-q`` as encode, cut and verify take it: no summary line on stdout, the file written."""
    out = tmp_path / "level.obj"
    code, stdout, err = run(capsys, "decode", work["pmw"], "-o", out, "--chunks", "1", "-q")
    assert code == 0 and stdout == "" and err == "" and out.stat().st_size > 0


def test_decode_glb_is_plain_gltf(work, tmp_path, capsys):
    out = tmp_path / "full.glb"
    assert run(capsys, "decode", work["pmw"], "-o", out)[0] == 0
    gltf = pygltflib.GLTF2.load(str(out))
    prim = gltf.meshes[0].primitives[0]
    assert gltf.accessors[prim.attributes.POSITION].count == 10242
    assert gltf.accessors[prim.indices].componentType == pygltflib.UNSIGNED_INT
    assert not gltf.extensionsUsed


def test_decode_from_stdin_truncated(work, tmp_path, capsys, monkeypatch):
    data = work["pmw"].read_bytes()
    stdin_bytes(monkeypatch, data[: len(data) // 2])
    code, stdout, err = run(capsys, "decode", "-", "-o", tmp_path / "cut.obj", "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    assert doc["complete"] is False and 0 < doc["vertices"] < 10242


# -- verify -------------------------------------------------------------------------------

def test_verify_json_authentic(work, capsys):
    code, stdout, err = run(capsys, "verify", work["pmw"], "--key", work["key"], "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    assert VERIFY_FIELDS <= doc.keys()
    assert doc["complete"] is True and doc["truncated"] is False and doc["verdict"] == "authentic"
    assert [c["chunk"] for c in doc["chunks"]] == list(range(doc["chunks_total"] + 1))
    assert all(CHUNK_FIELDS <= c.keys() for c in doc["chunks"])
    assert doc["final"] == doc["chunks"][-1]
    assert doc["final"]["nc"] == pytest.approx(1.0) and doc["final"]["psnr_db"] is None  # exact: inf -> null
    reads = [c["bytes_read"] for c in doc["chunks"]]
    assert reads == sorted(reads)


def test_verify_prints_a_table_and_the_verdict(work, capsys):
    code, stdout, _ = run(capsys, "verify", work["pmw"], "--key", work["key"])
    assert code == 0
    lines = stdout.splitlines()
    assert lines[0].split()[:2] == ["chunk", "bytes"] and "PSNR" in lines[0]
    assert any(line.startswith("verdict: authentic") for line in lines)


def test_verify_truncated_file_on_stdin(work, capsys, monkeypatch):
    data = work["pmw"].read_bytes()
    stdin_bytes(monkeypatch, data[: len(data) * 2 // 3])
    code, stdout, err = run(capsys, "verify", "-", "--key", work["key"], "--json")
    assert code in (0, 1), err
    doc = strict_json(stdout)
    assert doc["truncated"] is True and doc["complete"] is False
    assert 1 < len(doc["chunks"]) <= doc["chunks_total"]
    assert doc["final"]["bytes_read"] <= len(data) * 2 // 3
    assert doc["verdict"] in ("authentic", "inconclusive")


def test_verify_with_another_watermark_is_not_authentic(work, capsys):
    code, stdout, _ = run(capsys, "verify", work["pmw"], "--key", work["key"], "--watermark", work["other"], "--json")
    assert code == 1
    # codes of two images agree more often than chance (shared low bits), so the library
    # may call it inconclusive rather than not-authentic; either way it is not authentic
    assert strict_json(stdout)["verdict"] in ("not-authentic", "inconclusive")


def test_verify_with_a_watermark_of_another_size_than_the_keys_is_refused(work, tmp_path, capsys):
    """It was ``not-authentic`` with NC and PSNR None at every row: a key marks with one image, so an image
    of another size cannot be its mark, and is refused (exit 2) as a key of another image is by encode."""
    small = tmp_path / "small.png"
    Image.fromarray(pattern(16)).save(small)
    code, stdout, err = run(capsys, "verify", work["pmw"], "--key", work["key"], "--watermark", small)
    assert code == 2 and stdout == "" and err.count("\n") == 1
    assert f"{small} is 16x16, the key's is 32x32" in err


def test_verify_of_an_unmarked_file_exits_1(work, tmp_path, capsys):
    plain = tmp_path / "plain.pmw"
    assert run(capsys, "encode", work["mesh"], "-o", plain, "-q")[0] == 0
    code, stdout, _ = run(capsys, "verify", plain, "--key", work["key"])
    assert code == 1 and "no watermark" in stdout


def test_verify_frames(work, tmp_path, capsys):
    frames = tmp_path / "frames"
    data = work["pmw"].read_bytes()
    cut = tmp_path / "cut.pmw"
    cut.write_bytes(data[: len(data) // 2])
    code, stdout, err = run(capsys, "verify", cut, "--key", work["key"], "--frames", frames, "--json")
    assert code in (0, 1), err
    doc = strict_json(stdout)
    names = sorted(p.name for p in frames.iterdir())
    written = [n for n in names if n.startswith("frame_")]
    assert written[0] == "frame_000.png" and set(written) <= {f"frame_{i:03d}.png" for i in range(len(doc["chunks"]))}
    assert "overview.png" in names and "metrics.png" in names
    with Image.open(frames / "frame_000.png") as im:
        assert im.size == (128, 128)  # the 32x32 mark scaled up by 4
    with Image.open(frames / "overview.png") as im:
        assert im.width > 600 and im.mode == "RGB"


@pytest.mark.parametrize("case", ["the stream", "the key", "a key it does not use", "the watermark image", "stdin",
                                  "the reference's key"])
def test_verify_frames_never_writes_a_picture_over_an_input_or_a_key(work, tmp_path, capsys, monkeypatch, case):
    """The picture names are known only after the read (a frame where the watermark changed), so every one is
    checked before the first is written: an input, the file standard input reads, or any key file in the
    --frames directory under a picture's name is refused (exit 2, one line) and left as it was."""
    frames = tmp_path / "frames"
    frames.mkdir()
    pmw, key, mark = work["pmw"], work["key"], work["mark"]
    argv = ["verify", pmw, "--key", key, "--frames", frames]
    if case == "the stream":
        pmw = frames / "frame_000.png"
        pmw.write_bytes(work["pmw"].read_bytes())
        argv[1] = pmw
    elif case == "the key":
        key = frames / "overview.png"
        key.write_bytes(work["key"].read_bytes())
        argv[3] = key
    elif case == "a key it does not use":
        (frames / "metrics.png").write_bytes(work["key"].read_bytes())
    elif case == "the watermark image":
        shutil.copy(work["mark"], frames / "frame_000.png")
        argv += ["--watermark", frames / "frame_000.png"]
    elif case == "stdin":
        (frames / "frame_000.png").write_bytes(work["pmw"].read_bytes())
        monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(open(frames / "frame_000.png", "rb")))
        argv[1] = "-"
    else:
        exported = tmp_path / "exported.obj"
        assert run(capsys, "decode", work["pmw"], "-o", exported)[0] == 0
        (frames / "tamper.png").write_bytes(work["key"].read_bytes())
        argv = ["verify", exported, "--reference", work["pmw"], "--key", frames / "tamper.png", "--frames", frames]
    before = {p.name: p.read_bytes() for p in frames.iterdir()}
    code, stdout, err = run(capsys, *argv)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert ("standard input" if case == "stdin" else "key" if "key" in case else "is also the input") in err, err
    assert {p.name: p.read_bytes() for p in frames.iterdir()} == before


def test_verify_frames_to_standard_output_is_refused(work, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = run(capsys, "verify", work["pmw"], "--key", work["key"], "--frames", "-")
    assert code == 2 and "--frames writes pictures into a directory" in err
    assert not (tmp_path / "-").exists()


def test_verify_reference_finds_the_mark_in_an_exported_and_moved_mesh(work, tmp_path, capsys):
    exported = tmp_path / "exported.obj"
    code, _, err = run(capsys, "decode", work["pmw"], "-o", exported)
    assert code == 0, err
    mesh = pmwm_codec.read_mesh(exported)
    angle = 0.7
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0], [0, 0, 1]])
    moved = write_obj(tmp_path / "moved.obj", pmwm_codec.Mesh(2.5 * mesh.positions @ rot.T + 3.0, mesh.faces))
    code, stdout, err = run(capsys, "verify", moved, "--reference", work["pmw"], "--key", work["key"], "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    assert doc["verdict"] == "authentic" and doc["bit_exact"]


def test_verify_reference_of_the_unmarked_original_is_not_authentic(work, capsys):
    code, stdout, err = run(capsys, "verify", work["mesh"], "--reference", work["pmw"], "--key", work["key"], "--json")
    assert code == 1, err
    assert strict_json(stdout)["verdict"] != "authentic"


# -- info ---------------------------------------------------------------------------------

def _info(capsys, path):
    code, stdout, err = run(capsys, "info", path, "--json")
    assert code == 0, err
    return strict_json(stdout)


def test_info_reads_the_structure(work, capsys):
    info = _info(capsys, work["pmw"])
    assert info["complete"] is True and info["vertices"] == 10242
    assert info["chunks_total"] == len(info["chunks"]) == info["chunks_present"]
    assert info["chunks"][-1]["vertices"] == 10242 and info["watermark"]["width"] == 32
    assert info["vsplits"] == 10242 - info["base_vertices"]
    code, stdout, _ = run(capsys, "info", work["pmw"])
    assert code == 0 and "chunk" in stdout and "watermark" in stdout


def test_info_of_a_truncated_file(work, tmp_path, capsys):
    data = work["pmw"].read_bytes()
    cut = tmp_path / "cut.pmw"
    cut.write_bytes(data[: len(data) // 2])
    info = _info(capsys, cut)
    assert info["truncated"] is True and info["chunks_present"] < info["chunks_total"]
    assert "TRUNCATED" in run(capsys, "info", cut)[1]


def test_info_refuses_bytes_after_the_declared_length_as_decode_does(work, tmp_path, capsys):
    """A file longer than its GLB header says is refused by decode and verify; info said "complete"."""
    longer = tmp_path / "longer.pmw"
    longer.write_bytes(work["pmw"].read_bytes() + b"\0" * 100)
    for argv in (("info", longer), ("info", longer, "--json"), ("decode", longer, "-o", tmp_path / "out.obj")):
        code, stdout, err = run(capsys, *argv)
        assert code == 2 and stdout == "", argv
        assert "100 bytes after the declared file length" in err and err.count("\n") == 1, err
    assert not (tmp_path / "out.obj").exists()


def _base_end(data: bytes) -> int:
    """Bytes a reader needs before the base mesh is whole (the parser's own count, from a prefix's refusal)."""
    import re

    from pmwm_codec.errors import TruncatedError
    from pmwm_codec.format.reader import read_header, read_through_base

    with pytest.raises(TruncatedError) as exc:  # the header and the BIN chunk's, no base byte
        read_through_base(data[: read_header(data).bin_offset])
    return int(re.search(r"needs (\d+) bytes", str(exc.value)).group(1))


@pytest.mark.parametrize("damage", ["ends inside the base", "BIN chunk length", "BIN chunk type"])
def test_info_refuses_what_decode_refuses_before_it_shows_a_mesh(work, tmp_path, capsys, damage):
    """A file ending inside its base mesh, or with a wrong BIN chunk header, is exit 2 for decode, cut and
    verify; info said exit 0 ("TRUNCATED, 0 chunks present", or even "complete", with the base listed)."""
    import struct

    data = work["pmw"].read_bytes()
    bin_header = 20 + struct.unpack_from("<I", data, 12)[0]
    if damage == "ends inside the base":
        data = data[: _base_end(data) - 1]
        said = "before the base mesh was complete"
    elif damage == "BIN chunk length":
        data = data[:bin_header] + struct.pack("<I", struct.unpack_from("<I", data, bin_header)[0] + 64) \
            + data[bin_header + 4:]
        said = "BIN chunk of"
    else:
        data = data[: bin_header + 4] + b"XXXX" + data[bin_header + 8:]
        said = "second chunk type"
    bad = tmp_path / "bad.pmw"
    bad.write_bytes(data)
    for argv in (("info", bad), ("info", bad, "--json"), ("decode", bad, "-o", tmp_path / "o.obj")):
        code, stdout, err = run(capsys, *argv)
        assert code == 2 and stdout == "" and said in err and err.count("\n") == 1, (argv, err)


def test_info_of_a_file_ending_right_after_its_base_lists_no_chunk(work, tmp_path, capsys):
    data = work["pmw"].read_bytes()
    cut = tmp_path / "base.pmw"
    cut.write_bytes(data[: _base_end(data)])
    info = _info(capsys, cut)
    assert info["truncated"] is True and info["chunks_present"] == 0


# -- bad input: exit 2, one line, no traceback, nothing left behind -----------------------

def _bad_cases(work, d):
    (d / "notamesh.obj").write_text("this is not a mesh\n")
    (d / "empty.obj").write_text("")
    (d / "nan.obj").write_text("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n")
    (d / "range.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    (d / "mark.png").write_bytes(b"not an image at all")
    (d / "random.pmw").write_bytes(np.random.default_rng(1).bytes(4000))
    (d / "early.pmw").write_bytes(work["pmw"].read_bytes()[:300])
    os.mkfifo(d / "fifo.pmw")
    out = d / "out.pmw"
    mesh, pmw, key = work["mesh"], work["pmw"], work["key"]
    return {
        "missing file": ["encode", d / "nope.obj", "-o", out],
        "not a mesh": ["encode", d / "notamesh.obj", "-o", out],
        "empty mesh": ["encode", d / "empty.obj", "-o", out],
        "NaN coordinates": ["encode", d / "nan.obj", "-o", out],
        "face index out of range": ["encode", d / "range.obj", "-o", out],
        "watermark not an image": ["encode", mesh, "-o", out, "--watermark", d / "mark.png"],
        "unwritable output": ["encode", mesh, "-o", d / "no" / "such" / "dir" / "out.pmw"],
        "output is a directory": ["decode", pmw, "-o", d],
        "missing key": ["verify", pmw, "--key", d / "nope.key.json"],
        "cut before the base mesh": ["verify", d / "early.pmw", "--key", key, "--frames", d / "frames"],
        "random bytes (verify)": ["verify", d / "random.pmw", "--key", key],
        "random bytes (decode)": ["decode", d / "random.pmw", "-o", d / "out.glb"],
        "random bytes (info)": ["info", d / "random.pmw"],
        "a FIFO (info, was a hang)": ["info", d / "fifo.pmw"],
        "cut before the base mesh (decode)": ["decode", d / "early.pmw", "-o", d / "out.obj"],
        "missing .pmw": ["decode", d / "nope.pmw", "-o", d / "out.obj"],
        "unknown output format": ["decode", pmw, "-o", d / "out.xyz"],
        "negative --chunks": ["decode", pmw, "-o", d / "out.obj", "--chunks", "-1"],
        "bad --bits": ["encode", mesh, "-o", out, "--bits", "99"],
        "missing -o": ["encode", mesh],
        "unknown command": ["frobnicate"],
    }


BAD = ["missing file", "not a mesh", "empty mesh", "NaN coordinates", "face index out of range",
       "watermark not an image", "unwritable output", "output is a directory", "missing key",
       "cut before the base mesh", "random bytes (verify)", "random bytes (decode)", "random bytes (info)",
       "a FIFO (info, was a hang)",
       "cut before the base mesh (decode)", "missing .pmw", "unknown output format", "negative --chunks",
       "bad --bits", "missing -o", "unknown command"]


@pytest.mark.parametrize("case", BAD)
def test_bad_input_exits_2_with_one_line(work, tmp_path, capsys, case):
    argv = _bad_cases(work, tmp_path)[case]
    before = set(os.listdir(tmp_path))
    code, stdout, err = run(capsys, *argv)
    assert code == 2
    assert stdout == ""
    assert len(err.strip().splitlines()) == 1, err
    assert err.startswith("pmw: error: ") and "Traceback" not in err
    assert set(os.listdir(tmp_path)) == before  # no output, no temp file, no frames dir


def test_bad_input_on_stdin(work, capsys, monkeypatch):
    stdin_bytes(monkeypatch, work["pmw"].read_bytes()[:100])
    code, _, err = run(capsys, "verify", "-", "--key", work["key"])
    assert code == 2 and err.startswith("pmw: error: stdin: truncated")


def test_help_exits_0(capsys):
    assert main(["--help"]) == 0
    assert "encode" in capsys.readouterr().out


# -- demo ---------------------------------------------------------------------------------

def test_demo_writes_its_pictures(tmp_path, capsys):
    out = tmp_path / "demo"
    code, stdout, err = run(capsys, "demo", "--out", out)
    assert code == 0, err
    for sub in ("cut", "whole"):
        assert (out / sub / "overview.png").exists() and (out / sub / "metrics.png").exists()
        assert (out / sub / "frame_000.png").exists()
    assert (out / "demo.pmw").exists() and (out / "demo-cut.pmw").exists() and (out / "demo.pmw.key.json").exists()
    assert "truncated" in stdout and "authentic" in stdout and str(out / "cut" / "overview.png") in stdout


@pytest.mark.parametrize("blocker", ["folder at demo.pmw", "key of another image"])
def test_demo_that_cannot_write_its_files_leaves_the_users_watermark_png_untouched(tmp_path, capsys, blocker):
    """``pmw demo --out DIR`` wrote ``DIR/watermark.png`` first, over a file of the user's, then stopped at
    ``demo.pmw`` (a folder there, or a key of another image beside it): exit 2 with the file already replaced."""
    (tmp_path / "watermark.png").write_bytes(b"the user's own picture")
    if blocker == "folder at demo.pmw":
        (tmp_path / "demo.pmw").mkdir()
    else:
        pmwm_codec.encode(shapes.icosphere(3), str(tmp_path / "demo.pmw"), watermark=pattern(8))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    code, stdout, err = run(capsys, "demo", "--out", tmp_path)
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err, err
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


@pytest.mark.parametrize("signal_name, status", [("TERM", 143), ("INT", 130)])
def test_demo_stopped_before_it_wrote_a_file_leaves_no_folder_it_made(tmp_path, signal_name, status):
    """``pmw demo --out new/dir`` stopped (SIGTERM, Ctrl-C) while it encodes left ``new/dir``, empty, behind: the
    folders it made for nothing are removed as ``verify --frames`` removes its own (the stop made certain by the
    encoder's ``measured`` fault point)."""
    done = subprocess.run([sys.executable, "-m", "pmwm_codec.cli", "demo", "--out", str(tmp_path / "new" / "dir")],
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT=f"measured:{signal_name}"))
    assert done.returncode == status and done.stderr.count("\n") == 1, done.stderr
    assert os.listdir(tmp_path) == []
    assert str(tmp_path) not in done.stdout, done.stdout  # its first line named watermark.png, never written


@pytest.mark.parametrize("out", ["", "  "])
def test_demo_with_an_empty_out_names_the_option_in_one_line(tmp_path, capsys, monkeypatch, out):
    """``--out ''`` (an unset variable in ``--out $DIR``) said only "pmw: error: No such file or directory"."""
    monkeypatch.chdir(tmp_path)
    code, stdout, err = run(capsys, "demo", "--out", out)
    assert code == 2 and stdout == "" and err.count("\n") == 1, err
    assert err.startswith("pmw: error: argument --out: an empty path") and "'--out $VAR'" in err, err
    assert list(tmp_path.iterdir()) == []


# -- the package entry point and the library behind the command ----------------------------

def test_python_dash_m_pmwm_codec_runs_the_command():
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", "--help"], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("usage: pmw") and "decode" in done.stdout and "verify" in done.stdout


def test_encode_of_a_mesh_beyond_float32_is_one_line_without_a_numpy_warning(tmp_path):
    """A coordinate past float32's range made numpy warn ("overflow encountered in cast", two lines
    with a source path) on stderr before the one-line refusal."""
    src = tmp_path / "far.obj"
    src.write_text("v 1e39 0 0\nv 0 1 0\nv 0 0 1\nv 1 1 1\nf 1 2 3\nf 1 2 4\nf 2 3 4\nf 1 3 4\n")
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", "encode", str(src), "-o", str(tmp_path / "far.pmw")],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("pmw: error: ") and "float32" in done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["far.obj"]


def test_decode_to_stl_round_trips_through_read_mesh(work, tmp_path, capsys):
    out = tmp_path / "level.stl"
    code, stdout, err = run(capsys, "decode", work["pmw"], "-o", out, "--chunks", "3", "--json")
    assert code == 0, err
    doc = strict_json(stdout)
    expected = pmwm_codec.decode(work["pmw"], chunks=3)
    mesh = pmwm_codec.read_mesh(out)
    assert (mesh.vertex_count, mesh.face_count) == (doc["vertices"], doc["faces"])
    # STL has no vertex order: compare the triangles as sets of float32 corners
    def corners(m):
        return sorted(map(tuple, np.sort(m.positions.astype(np.float32)[m.faces].reshape(-1, 9), axis=1).tolist()))
    assert corners(mesh) == corners(expected)
    assert [p.name for p in tmp_path.iterdir()] == [out.name]


def test_verify_stream_as_json_is_the_verify_json_output(work, capsys):
    code, stdout, _ = run(capsys, "verify", work["pmw"], "--key", work["key"], "--json")
    assert code == 0
    printed = strict_json(stdout)
    result = pmwm_codec.verify_stream(str(work["pmw"]), str(work["key"]))
    # the key carries an owner id (a watermark encode marks the owner layer by default): the CLI
    # adds the owner layer read at every chunk boundary and at the end (pmwm_codec.verify.owner)
    assert printed.pop("owner")["verdict"] == "present"
    assert all(chunk.pop("owner")["bits"] == 64 for chunk in printed["chunks"] + [printed["final"]])
    assert result.as_json().keys() == printed.keys()
    assert jsonable(result.as_json()) == printed
    assert result.verdict == "authentic" and result.end.complete and len(result.results) == printed["chunks_total"] + 1


def test_verify_stream_on_a_cut_file_in_memory(work):
    data = work["pmw"].read_bytes()
    result = pmwm_codec.verify_stream(data[: len(data) // 2], WatermarkKey.load(work["key"]))
    doc = result.as_json()
    assert doc["truncated"] is True and doc["final"] == doc["chunks"][-1]
    assert [r.chunk for r in result.results] == list(range(len(result.results)))


def test_verify_reference_json_is_mesh_verification_as_json(work, tmp_path, capsys):
    from pmwm_codec.verify.mesh import verify_mesh
    from pmwm_codec.verify.owner import owner_of_mesh, owner_view

    exported = tmp_path / "exported.obj"
    assert run(capsys, "decode", work["pmw"], "-o", exported)[0] == 0
    code, stdout, _ = run(capsys, "verify", exported, "--reference", work["pmw"], "--key", work["key"], "--json")
    assert code == 0
    printed = strict_json(stdout)
    v = verify_mesh(pmwm_codec.read_mesh(exported), work["pmw"], work["key"])
    key = pmwm_codec.load_key(work["key"])
    owner = None if key.owner_id is None else owner_of_mesh(owner_view(exported), key).as_json()
    expected = {**v.as_json(), "owner": owner}  # the owner layer read blind beside the exact one
    assert printed == expected and printed["psnr_db"] is None and v.psnr_db == math.inf


@pytest.mark.parametrize("cut", [False, True])
def test_inspect_is_the_info_json_output(work, tmp_path, capsys, cut):
    path = work["pmw"]
    if cut:
        path = tmp_path / "cut.pmw"
        path.write_bytes(work["pmw"].read_bytes()[:20000])
    info = pmwm_codec.inspect(str(path))
    assert jsonable(info) == _info(capsys, path)
    assert pmwm_codec.inspect(path.read_bytes()) == {**info, "file": None}


def test_batch_failure_lines_name_each_input_by_its_path_not_its_base_name(tmp_path, monkeypatch):
    """Two ``bad.obj`` in two folders printed as ``failed: bad.obj: ...`` twice: which one failed?"""
    from pmwm_codec.cli.batch import _failure_line

    rows = [{"input": str(tmp_path / d / "bad.obj"), "status": "failed", "error": f"bad.obj: face index {i} out of range"}
            for i, d in enumerate("ab")]
    assert [_failure_line(r, str(tmp_path)) for r in rows] == [
        "a/bad.obj: face index 0 out of range", "b/bad.obj: face index 1 out of range"]
    monkeypatch.chdir(tmp_path)
    assert _failure_line(rows[1], "*/bad.obj") == "b/bad.obj: face index 1 out of range"
    assert _failure_line({"input": str(tmp_path / "c.obj"), "status": "timeout", "error": None}, ".") == "c.obj: timeout"


@pytest.mark.parametrize("command", ["cut", "decode"])
def test_an_output_that_is_the_file_standard_input_reads_is_refused(work, tmp_path, command):
    """``pmw cut - -o x.pmw < x.pmw`` replaced the whole file by its cut (and ``pmw decode - -o x.glb < x.glb``
    a .pmw named .glb by its decode): the output was compared with every input but ``-``."""
    target = tmp_path / ("x.pmw" if command == "cut" else "x.glb")
    target.write_bytes(work["pmw"].read_bytes())
    with open(target, "rb") as stdin:
        proc = subprocess.run([sys.executable, "-m", "pmwm_codec", command, "-", "-o", str(target), "--chunks", "1"],
                              stdin=stdin, capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 2 and proc.stderr.startswith("pmw: error: ") and len(proc.stderr.splitlines()) == 1
    assert "is also the input" in proc.stderr, proc.stderr
    assert target.read_bytes() == work["pmw"].read_bytes()


def test_encode_quiet_prints_no_summary_but_its_notes_on_stderr(tmp_path, capsys):
    """``encode -q`` dropped every note (``--fit`` shrank the image, the owner layer left out ...), while ``decode -q``
    and ``cut -q`` send theirs to stderr: now encode does too, and prints nothing else."""
    mesh = write_obj(tmp_path / "sphere.obj", shapes.icosphere(3, 1.0, noise=0.01))
    Image.fromarray(pattern(64)).save(tmp_path / "big.png")
    code, stdout, err = run(capsys, "encode", mesh, "-o", tmp_path / "s.pmw", "--watermark", tmp_path / "big.png",
                            "--fit", "-q")
    assert code == 0 and stdout == "" and (tmp_path / "s.pmw").stat().st_size > 0
    assert err and all(line.startswith("pmw: note: ") for line in err.splitlines()) and "--fit" in err, err


@pytest.mark.parametrize("output, words", [("dir", "is a directory"), ("-", "not to standard output")])
def test_decode_names_a_folder_or_dash_as_output_for_what_it_is(work, tmp_path, capsys, output, words):
    """``decode -o somedir`` and ``decode -o -`` said "unknown output format '(no suffix)'"."""
    (tmp_path / "dir").mkdir()
    code, stdout, err = run(capsys, "decode", work["pmw"], "-o", tmp_path / output if output != "-" else "-")
    assert code == 2 and stdout == "" and words in err and "unknown output format" not in err, err
