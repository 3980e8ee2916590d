"""The ``pmw`` command against its written contract (DESIGN.md §5, README "The pmw command"), as seen from outside;
each test says what an audit found apart from it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh


def _image(size: int) -> np.ndarray:
    y, x = np.mgrid[:size, :size]
    return (((x // 4 + y // 4) % 2) * 200 + 20 + (x * 3 + y) % 30).astype(np.uint8)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A mesh file, a watermark image, and a .pmw marked with that image but no owner layer, with its key."""
    d = tmp_path_factory.mktemp("contract")
    mesh = shapes.demo_mesh(40)
    write_mesh(d / "m.obj", mesh)
    Image.fromarray(_image(16)).save(d / "logo.png")
    pmwm_codec.encode(mesh, d / "m.pmw", watermark=d / "logo.png", key=d / "m.key.json", owner_id=False,
                      measure="none")
    return d


def test_verify_json_has_owner_null_when_the_key_names_no_owner_id(files, capsys):
    """``verify --json`` lists ``owner`` among its fields; with a key that names no owner ID (``--no-owner``, or a
    key written before the owner layer) the field was missing altogether, from the object and from every chunk
    row, so a script reading ``doc["owner"]`` failed on such files.  It is ``null`` there."""
    assert pmwm_codec.load_key(files / "m.key.json").owner_id is None  # the case: nothing to read the layer by
    assert main(["verify", str(files / "m.pmw"), "--key", str(files / "m.key.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "authentic"
    assert "owner" in doc and doc["owner"] is None, sorted(doc)
    assert all("owner" in row and row["owner"] is None for row in doc["chunks"]), doc["chunks"][0]
    assert doc["final"]["owner"] is None


def test_encode_notes_go_to_stderr_and_the_summary_alone_to_stdout(files, tmp_path, capsys):
    """``encode`` printed its notes (``--bits ignored: no --watermark``, ``dropped 1113 unreferenced vertices`` ...)
    inside its summary on stdout, where ``decode``, ``cut`` and ``encode -q`` print them on stderr as
    ``pmw: note: ...``.  They go to stderr, the summary alone to stdout."""
    out = tmp_path / "plain.pmw"
    assert main(["encode", str(files / "m.obj"), "-o", str(out), "--bits", "3", "--measure", "none"]) == 0
    stdout, stderr = capsys.readouterr()
    assert "pmw: note: --bits ignored: no --watermark" in stderr.splitlines(), stderr
    assert "note:" not in stdout and "ignored" not in stdout, stdout
    assert "plain.pmw" in stdout and "vertex splits" in stdout  # the summary is still there


@pytest.mark.parametrize("argv, what", [
    (["encode", "-", "-o", "{d}/x.pmw"], "mesh file"),
    (["encode", "{d}/m.obj", "-o", "{d}/x.pmw", "--watermark", "-"], "watermark image"),
    (["verify", "{d}/m.pmw", "--key", "-"], "key file"),
    (["verify", "{d}/m.pmw", "--key", "{d}/m.key.json", "--watermark", "-"], "watermark image"),
    (["verify", "{d}/m.obj", "--key", "-"], "key file"),
])
def test_a_dash_where_only_a_file_is_read_is_named_so_not_as_a_missing_file(files, capsys, argv, what):
    """``-`` given for a mesh, a key or a watermark image (read only from files) was refused as ``-: no such
    file`` (``pmw: error: x.pmw: -: no such key file``), as if ``-`` were a missing file; it says that standard
    input is read only for a ``.pmw``."""
    assert main([a.format(d=files) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err == f"pmw: error: -: give the {what} by its name (standard input is read only for a .pmw)\n", err
    assert not (files / "x.pmw").exists()


def test_a_file_cut_inside_its_json_is_named_alike_by_every_command(files, tmp_path, capsys):
    """Cut inside the JSON, the same file was "inside the GLB header or JSON (needs 2544)" for info and decode but
    "before the base mesh was complete (needs 2544 bytes)" for verify and cut -- a count that read as the base's
    end, which lies further on.  Every command now says where it ended and that the count is a least one."""
    data = (files / "m.pmw").read_bytes()
    cut = tmp_path / "early.pmw"
    cut.write_bytes(data[:100])
    key = str(files / "m.key.json")
    said = set()
    for argv in (["info", str(cut)], ["decode", str(cut), "-o", str(tmp_path / "o.obj")],
                 ["verify", str(cut), "--key", key], ["cut", str(cut), "-o", str(tmp_path / "c.pmw")]):
        assert main(argv) == 2, argv
        said.add(capsys.readouterr().err)
    assert len(said) == 1, said
    line = said.pop()
    assert "stream ended after 100 bytes, inside the GLB header or JSON, before the base mesh was complete " \
           "(needs at least " in line, line
    assert not list(tmp_path.glob("o.*")) and not (tmp_path / "c.pmw").exists()


def test_verify_mesh_against_its_reference_also_reads_the_owner_layer(tmp_path, capsys):
    """``verify MESH --reference ORIGINAL.pmw --key KEY`` read only the exact layer, which any noise breaks by
    design: a re-saved copy read ``not-authentic`` and nothing said whose it was, though the key's owner layer
    was there to read (``verify MESH --key KEY`` without ``--reference`` found it).  It now reports ``owner``
    too (null where the key names none), read as the blind form reads it; the verdict stays the image's."""
    mesh = shapes.icosphere(4, noise=0.05, seed=2)
    write_mesh(tmp_path / "m.obj", mesh)
    Image.fromarray(_image(16)).save(tmp_path / "logo.png")
    key = tmp_path / "m.key.json"
    assert main(["encode", str(tmp_path / "m.obj"), "-o", str(tmp_path / "m.pmw"), "--watermark",
                 str(tmp_path / "logo.png"), "--key", str(key), "-q"]) == 0
    assert pmwm_codec.load_key(key).owner_id is not None
    assert main(["decode", str(tmp_path / "m.pmw"), "-o", str(tmp_path / "d.obj"), "-q"]) == 0
    copy = pmwm_codec.read_mesh(tmp_path / "d.obj")
    diagonal = float(np.linalg.norm(np.ptp(copy.positions, axis=0)))
    noisy = copy.positions + np.random.default_rng(3).normal(0.0, 2e-5 * diagonal, copy.positions.shape)
    write_mesh(tmp_path / "noisy.obj", type(copy)(noisy, copy.faces))
    capsys.readouterr()
    assert main(["verify", str(tmp_path / "noisy.obj"), "--key", str(key), "--reference", str(tmp_path / "m.pmw"),
                 "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] != "authentic"
    assert doc["owner"]["verdict"] == "present" and doc["owner"]["id"] == pmwm_codec.load_key(key).owner_hex
    assert main(["verify", str(tmp_path / "noisy.obj"), "--key", str(key), "--reference", str(tmp_path / "m.pmw")]) == 1
    assert f"owner {pmwm_codec.load_key(key).owner_hex}: present" in capsys.readouterr().out


def test_verify_mesh_against_its_reference_says_owner_null_without_an_owner_id(files, tmp_path, capsys):
    assert main(["decode", str(files / "m.pmw"), "-o", str(tmp_path / "d.obj"), "-q"]) == 0
    assert main(["verify", str(tmp_path / "d.obj"), "--key", str(files / "m.key.json"), "--reference",
                 str(files / "m.pmw"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "authentic" and "owner" in doc and doc["owner"] is None
