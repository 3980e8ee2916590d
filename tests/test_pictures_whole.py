"""``pmw verify --frames DIR`` writes its pictures as a set: all of them, or (a failure, a Ctrl-C) none.

A run that failed or was interrupted used to leave 16-18 of a set of 19 pictures behind.
"""

from __future__ import annotations

import errno
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from pmwm_codec import atomic, figures
from pmwm_codec.cli import main

from conftest import marked_sphere

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def marked(tmp_path_factory):
    from pmwm_codec.watermark.image import save_png

    d = tmp_path_factory.mktemp("marked")
    data, key, image = marked_sphere(4)
    (d / "m.pmw").write_bytes(data)
    key.save(d / "m.key.json")
    save_png(d / "mark.png", image)
    return d / "m.pmw", d / "m.key.json"


def _verify(marked, frames, *extra) -> int:
    pmw, key = marked
    return main(["verify", str(pmw), "--key", str(key), "--frames", str(frames), "-q", *extra])


def _failing_on_call(function, n: int, exc: BaseException):
    """``function`` that raises ``exc`` on its ``n``-th call (counting from 1)."""
    calls = [0]

    def wrapper(*args, **kwargs):
        calls[0] += 1
        if calls[0] == n:
            raise exc
        return function(*args, **kwargs)
    return wrapper


def test_a_whole_run_writes_the_whole_set(marked, tmp_path):
    assert _verify(marked, tmp_path / "f") == 0
    names = sorted(p.name for p in (tmp_path / "f").iterdir())
    assert {"overview.png", "metrics.png", "tamper.png", "frame_000.png"} <= set(names) and len(names) > 5


@pytest.mark.parametrize("where, patch", [
    ("a Ctrl-C while the third picture is written", lambda m: m.setattr(
        atomic, "stage", _failing_on_call(atomic.stage, 3, KeyboardInterrupt()))),
    ("a Ctrl-C while the overview is drawn", lambda m: m.setattr(
        figures, "overview", _failing_on_call(figures.overview, 1, KeyboardInterrupt()))),
], ids=["staging", "drawing"])
def test_an_interrupted_run_leaves_no_picture(marked, tmp_path, monkeypatch, capsys, where, patch):
    patch(monkeypatch)
    assert _verify(marked, tmp_path / "f") == 130, where
    assert capsys.readouterr().err == "pmw: error: interrupted\n"
    assert list(tmp_path.iterdir()) == []  # not even the directory the run made


@pytest.mark.parametrize("call", [1, 3])
def test_a_rename_failing_part_way_takes_back_the_pictures_already_published(marked, tmp_path, monkeypatch, capsys,
                                                                             call):
    (tmp_path / "f").mkdir()
    (tmp_path / "f" / "notes.txt").write_text("mine")
    monkeypatch.setattr(atomic, "publish", _failing_on_call(atomic.publish, call, OSError(errno.EIO, "I/O error")))
    assert _verify(marked, tmp_path / "f") == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: ") and "cannot write pictures" in err and err.count("\n") == 1
    assert [p.name for p in (tmp_path / "f").iterdir()] == ["notes.txt"]  # a directory it did not make stays


def test_a_full_disk_leaves_no_picture(marked, tmp_path):
    """The probe's case: ``ulimit -f`` lets the frames through and stops the larger overview."""
    pmw, key = marked

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (8_000, 8_000))

    r = subprocess.run([sys.executable, "-m", "pmwm_codec", "verify", str(pmw), "--key", str(key), "--frames",
                        str(tmp_path / "f"), "-q"], cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                       capture_output=True, text=True, timeout=300, preexec_fn=small_files)
    assert r.returncode == 2 and "File too large" in r.stderr and r.stderr.count("\n") == 1, r.stderr
    assert list(tmp_path.iterdir()) == []


def test_verify_of_a_mesh_writes_its_two_pictures_together(marked, tmp_path, monkeypatch, capsys):
    import pmwm_codec
    from pmwm_codec.meshio import write_mesh

    pmw, key = marked
    mesh = tmp_path / "m.ply"
    write_mesh(mesh, pmwm_codec.decode(pmw))
    argv = ["verify", str(mesh), "--reference", str(pmw), "--key", str(key), "--frames", str(tmp_path / "f"), "-q"]
    assert main(argv) == 0
    assert sorted(p.name for p in (tmp_path / "f").iterdir()) == ["tamper.png", "watermark.png"]
    monkeypatch.setattr(atomic, "stage", _failing_on_call(atomic.stage, 2, KeyboardInterrupt()))
    argv[-2] = str(tmp_path / "g")
    assert main(argv) == 130 and capsys.readouterr().err == "pmw: error: interrupted\n"
    assert not (tmp_path / "g").exists()


def test_a_second_run_into_the_folder_leaves_only_its_own_pictures(marked, tmp_path):
    """A folder verified into twice showed a mix: the second file's frames beside the first's later ones (and
    its metrics.png or tamper.png when the second run draws none).  Stale pictures of the set are removed once
    the new set is published; anything else in the folder, links, and the command's own inputs stay."""
    pmw, key = marked
    frames = tmp_path / "f"
    assert _verify(marked, frames) == 0
    first = {p.name for p in frames.iterdir()}
    cut = tmp_path / "cut.pmw"
    data = pmw.read_bytes()
    cut.write_bytes(data[: 2 * len(data) // 3])
    (frames / "notes.txt").write_text("mine")
    (frames / "frame_999.png").symlink_to(tmp_path / "elsewhere.png")
    reference = frames / "frame_998.png"  # the expected image kept under a frame's name: an input of the run
    reference.write_bytes((pmw.parent / "mark.png").read_bytes())
    code = main(["verify", str(cut), "--key", str(key), "--frames", str(frames), "--watermark", str(reference), "-q",
                 "--json"])
    assert code in (0, 1)
    second = {p.name for p in frames.iterdir()} - {"notes.txt", "frame_999.png", "frame_998.png"}
    drawn = {n for n in first if n.startswith("frame_")}
    assert second < first and {n for n in second if n.startswith("frame_")} < drawn  # fewer chunks: fewer frames
    assert (frames / "notes.txt").read_text() == "mine" and (frames / "frame_999.png").is_symlink()
    assert reference.exists()


def test_a_mesh_verified_into_a_folder_used_before_leaves_only_its_two_pictures(marked, tmp_path):
    """``pmw verify MESH --reference REF --frames DIR`` wrote its ``watermark.png`` and ``tamper.png`` beside the
    frames, ``overview.png`` and ``metrics.png`` an earlier ``pmw verify FILE.pmw --frames DIR`` had left: the
    folder showed two runs' pictures.  They are removed as the stream form removes them once the two are
    published; anything else, a link of a set's name (and what it points to), and the command's inputs stay."""
    import pmwm_codec
    from pmwm_codec.meshio import write_mesh

    pmw, key = marked
    frames = tmp_path / "f"
    assert _verify(marked, frames) == 0
    first = {p.name for p in frames.iterdir()}
    assert {"overview.png", "metrics.png", "tamper.png", "frame_000.png"} <= first and len(first) > 5
    (frames / "notes.txt").write_text("mine")
    (tmp_path / "elsewhere.png").write_bytes(b"not a picture of this run")
    for link in ("frame_999.png", "metrics.png"):
        (frames / link).unlink(missing_ok=True)
        (frames / link).symlink_to(tmp_path / "elsewhere.png")
    expected = frames / "frame_998.png"  # the expected image kept under a frame's name: an input of the run
    expected.write_bytes((pmw.parent / "mark.png").read_bytes())
    mesh = tmp_path / "m.ply"
    write_mesh(mesh, pmwm_codec.decode(pmw))
    assert main(["verify", str(mesh), "--reference", str(pmw), "--key", str(key), "--frames", str(frames),
                 "--watermark", str(expected), "-q"]) == 0
    assert sorted(p.name for p in frames.iterdir()) == ["frame_998.png", "frame_999.png", "metrics.png", "notes.txt",
                                                        "tamper.png", "watermark.png"]
    assert (frames / "frame_999.png").is_symlink() and (frames / "metrics.png").is_symlink()
    assert (tmp_path / "elsewhere.png").read_bytes() == b"not a picture of this run"
    assert (frames / "notes.txt").read_text() == "mine" and expected.read_bytes() == (pmw.parent / "mark.png").read_bytes()


def test_remove_stale_touches_only_the_sets_names(tmp_path):
    for name in ("frame_001.png", "frame_002.png", "frame_0123.png", "overview.png", "metrics.png", "tamper.png",
                 "frame_1.png", "frame_001.png.bak", "other.png"):
        (tmp_path / name).write_bytes(b"x")
    removed = figures.remove_stale(str(tmp_path), {"frame_001.png", "overview.png"})
    assert sorted(os.path.basename(p) for p in removed) == ["frame_002.png", "frame_0123.png", "metrics.png", "tamper.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frame_001.png", "frame_001.png.bak", "frame_1.png",
                                                          "other.png", "overview.png"]
