"""What users trip over: clamped --chunks, internal notes, black or repeated frames, a watermark
that does not fit, a progress bar that jumps back."""

from __future__ import annotations

import hashlib
import io
import json
import re

import numpy as np
import pytest
from PIL import Image

from pmwm_codec import shapes
from pmwm_codec.cli import common, main
from pmwm_codec.format import base as base_module
from pmwm_codec.format import read_header
from pmwm_codec.format.base import encode_base
from pmwm_codec.meshio import write_mesh
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.image import save_png
from pmwm_codec.watermark.key import WatermarkKey

from conftest import marked_sphere


def _checker(size: int) -> np.ndarray:
    return (np.indices((size, size)).sum(0) % 2 * 200 + 30).astype(np.uint8)


def test_decode_says_when_chunks_asks_for_more_than_the_file_holds(tmp_path, capsys):
    data, _, _ = marked_sphere(1)
    src = tmp_path / "m.pmw"
    src.write_bytes(data)
    total = read_header(data).chunk_count
    assert main(["decode", str(src), "--chunks", str(total + 6), "-o", str(tmp_path / "m.obj")]) == 0
    err = capsys.readouterr().err
    assert f"--chunks {total + 6}" in err and f"{total} chunks" in err
    assert main(["decode", str(src), "--chunks", str(total + 6), "-o", str(tmp_path / "m.obj"), "--json"]) == 0
    assert len(json.loads(capsys.readouterr().out)["notices"]) == 1
    assert main(["decode", str(src), "--chunks", str(total), "-o", str(tmp_path / "m.obj")]) == 0
    assert capsys.readouterr().err == ""


def test_the_draco_fallback_note_speaks_to_users_not_of_internal_flags(monkeypatch):
    monkeypatch.setattr(base_module, "_try_draco", lambda *a: "decoded faces differ from the input faces")
    mesh = shapes.icosphere(1, 1.0)
    grid = Grid.fit(mesh.positions, 16)
    base = encode_base(grid.quantize(mesh.positions), mesh.faces, grid, codec="draco")
    assert base.codec == "plain"
    assert "preserve_order" not in base.notice and "plain accessors" in base.notice


def test_verify_frames_start_grey_not_black_and_never_repeat(tmp_path, capsys):
    data, key, img = marked_sphere(2)
    src, key_path = tmp_path / "m.pmw", tmp_path / "m.key.json"
    src.write_bytes(data)
    key.save(key_path)
    assert main(["verify", str(src), "--key", str(key_path), "--frames", str(tmp_path / "f")]) == 0
    frames = sorted((tmp_path / "f").glob("frame_*.png"))
    first = np.asarray(Image.open(frames[0]).convert("L"))
    assert frames[0].name == "frame_000.png" and first.mean() > 200  # the grey "no coefficients yet" tile
    digests = [hashlib.sha256(p.read_bytes()).hexdigest() for p in frames]
    assert len(set(digests)) == len(digests)
    last = np.asarray(Image.open(frames[-1]).convert("L"))
    factor = last.shape[0] // img.shape[0]
    assert np.array_equal(last[::factor, ::factor], img)  # the finished mark, scaled up by a whole factor


def test_a_watermark_that_does_not_fit_names_the_largest_size_that_does():
    key = WatermarkKey.generate(rng=np.random.default_rng(3))
    image = _checker(64)
    carriers = 700
    with pytest.raises(wm.CapacityError) as info:
        wm.plan(image, key, carriers)
    size = info.value.largest_size
    assert size and f"{size}x{size}" in str(info.value)
    wm.plan(wm.shrink_watermark(image, size), key, carriers)  # fits
    with pytest.raises(wm.CapacityError):
        wm.plan(wm.shrink_watermark(image, size * 2), key, carriers)


def test_encode_fit_shrinks_the_watermark_to_fit_and_says_so(tmp_path, capsys):
    mesh, mark = tmp_path / "t.ply", tmp_path / "mark.png"
    write_mesh(mesh, shapes.torus(24, 12))
    save_png(mark, _checker(128))
    out = tmp_path / "t.pmw"
    assert main(["encode", str(mesh), "-o", str(out), "--watermark", str(mark), "-q"]) == 2
    err = capsys.readouterr().err
    size = int(re.search(r"largest that fits is (\d+)x", err).group(1))
    assert not out.exists()
    assert main(["encode", str(mesh), "-o", str(out), "--watermark", str(mark), "--fit", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["watermark"]["width"] == size and any("--fit" in n for n in report["notices"])
    assert main(["verify", str(out), "--key", str(out) + ".key.json", "-q"]) == 0


class _Terminal(io.StringIO):
    def isatty(self):
        return True


def test_the_encode_progress_bar_only_moves_forward(monkeypatch):
    term = _Terminal()
    monkeypatch.setattr("sys.stderr", term)
    bar = common.Progress(True, tick=0)
    report = common.stage_progress(bar)
    for stage, fraction in [("simplify", 0), ("simplify", 1), ("records", 0), ("records", 1), ("write", 0),
                            ("write", 1), ("measure", 0), ("something new", 0.2), ("measure", 1)]:
        report(stage, fraction)
    bar.done()
    shown = [int(p) for p in re.findall(r"\]\s+(\d+)%", term.getvalue())]
    assert shown == sorted(shown) and shown[0] == 0 and shown[-1] == 100
    assert "measuring distortion" in term.getvalue()


def test_an_obj_face_past_the_last_vertex_is_named_in_the_files_own_numbering_too(tmp_path, capsys):
    """``f 1 2 9`` over three vertices said "face index 8": the reader's count from 0, a number the file never holds."""
    (tmp_path / "b9.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n")
    assert main(["encode", str(tmp_path / "b9.obj"), "-o", str(tmp_path / "bad.pmw")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.endswith("b9.obj: face index 9 names no v record (3 read before the face)") and "\n" not in err
    assert not (tmp_path / "bad.pmw").exists()


@pytest.mark.parametrize("argv", [["info", ""], ["cut", " ", "-o", "x.pmw"], ["decode", "", "-o", "x.obj"]])
def test_an_empty_input_path_is_named_as_empty(tmp_path, capsys, monkeypatch, argv):
    """``pmw info $UNSET`` said ``pmw: error: : no such .pmw file``: a message that names nothing."""
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and err.startswith("pmw: error: an empty path ("), err
    assert "names no .pmw file (an unset variable?)" in err and list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("name, text, kind", [
    ("scene.gltf", b'{\n  "asset": {"version": "2.0"}}', "a glTF JSON file"),
    ("mesh.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "an OBJ mesh"),
    ("mesh.ply", b"ply\nformat ascii 1.0\nend_header\n", "a PLY mesh"),
    ("mesh.stl", b"solid x\nendsolid x\n", "an STL mesh"),
    ("mesh.off", b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "an OFF mesh"),
    ("noise.pmw", bytes(range(7, 107)), None),
])
def test_a_file_that_is_no_pmw_is_named_for_what_it_is(tmp_path, capsys, name, text, kind):
    """``pmw info`` / ``decode`` of a mesh or a glTF JSON said only ``bad magic b'{\\n "'``: the line now says what
    the file looks like and what makes a .pmw of it; bytes that look like nothing known keep the plain line."""
    path = tmp_path / name
    path.write_bytes(text)
    for argv in (["info", str(path)], ["decode", str(path), "-o", str(tmp_path / "out.obj")]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "bad magic" in err[0], err
        if kind is None:
            assert err[0].endswith("not a glTF binary"), err
        else:
            assert f"({kind}, not a .pmw: pmw encode makes one)" in err[0], err
    assert not (tmp_path / "out.obj").exists()
