"""tools/heldout.py: the held-out scans' packages are read back exactly (no registry needed here)."""

from __future__ import annotations

import base64
import gzip
import hashlib
import shutil
import struct
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


def _chunk(cid: int, body: bytes) -> bytes:
    return struct.pack("<HI", cid, 6 + len(body)) + body


def _write_3ds(path, parts) -> None:
    """A 3DS file of ``parts`` (``[(positions, faces)]``), one named object each, as glmark2's ``cat.3ds`` lays it
    out: MAIN > EDIT > OBJECT (name) > TRIMESH > VERTICES, FACES (3 indices and a flags word)."""
    objects = b""
    for i, (positions, faces) in enumerate(parts):
        verts = _chunk(0x4110, struct.pack("<H", len(positions)) + positions.astype("<f4").tobytes())
        quads = np.hstack([faces, np.zeros((len(faces), 1), np.int64)]).astype("<u2")
        tris = _chunk(0x4120, struct.pack("<H", len(faces)) + quads.tobytes())
        objects += _chunk(0x4000, f"part{i}".encode() + b"\0" + _chunk(0x4100, verts + tris))
    path.write_bytes(_chunk(0x4D4D, _chunk(0x0002, struct.pack("<I", 3)) + _chunk(0x3D3D, objects)))


def _triangles(mesh) -> list:
    return sorted(map(tuple, np.round(mesh.positions[mesh.faces].reshape(len(mesh.faces), 9), 6).tolist()))


def test_a_3ds_file_reads_back_every_object_with_its_seam_corners_merged(tmp_path):
    """Two objects; the second repeats its vertices (a texture seam splits them in 3DS): one mesh, welded."""
    a, b = shapes.icosphere(1), shapes.torus(10, 6)
    split = b.positions[b.faces.reshape(-1)]  # every corner its own vertex
    _write_3ds(tmp_path / "m.3ds", [(a.positions, a.faces), (split, np.arange(len(split)).reshape(-1, 3))])
    got = heldout.read_3ds(str(tmp_path / "m.3ds"))
    assert got.vertex_count == a.vertex_count + b.vertex_count and got.face_count == a.face_count + b.face_count
    f32 = [type(m)(m.positions.astype(np.float32).astype(np.float64), m.faces) for m in (a, b)]
    assert _triangles(got) == sorted(_triangles(f32[0]) + _triangles(f32[1]))


@pytest.mark.skipif(shutil.which("dpkg-deb") is None, reason="dpkg-deb builds the package here")
def test_the_stellarium_and_glmark2_layouts_read_back_the_same_meshes(tmp_path):
    """.debs laid out as stellarium-data's (a gzipped OBJ, an OBJ) and glmark2-data's (a 3DS file)."""
    mesh = shapes.icosphere(2)
    built = {}
    for (package, version, _), models in ((heldout.STELLARIUM, heldout.STELLARIUM_MODELS),
                                          (heldout.GLMARK2, heldout.GLMARK2_MODELS)):
        pkg = tmp_path / package
        (pkg / "DEBIAN").mkdir(parents=True)
        (pkg / "DEBIAN" / "control").write_text(f"Package: {package}\nVersion: {version}\nArchitecture: all\n"
                                                "Maintainer: test <t@example.org>\nDescription: test\n")
        for path in models.values():
            target = pkg / path
            target.parent.mkdir(parents=True, exist_ok=True)
            if path.endswith(".3ds"):
                _write_3ds(target, [(mesh.positions, mesh.faces)])
            elif path.endswith(".gz"):
                write_mesh(str(tmp_path / "m.obj"), mesh)
                with open(tmp_path / "m.obj", "rb") as src, gzip.open(target, "wb") as dst:
                    dst.write(src.read())
            else:
                write_mesh(str(target), mesh)
        deb = tmp_path / f"{package}_{version}_all.deb"
        subprocess.run(["dpkg-deb", "--build", "--root-owner-group", str(pkg), str(deb)], check=True,
                       capture_output=True)
        (tmp_path / "work").mkdir(exist_ok=True)
        built.update(heldout.package_meshes(str(deb), str(tmp_path / "work"), models))
    assert sorted(built) == sorted({**heldout.STELLARIUM_MODELS, **heldout.GLMARK2_MODELS})
    for m in built.values():
        assert m.vertex_count == mesh.vertex_count and m.face_count == mesh.face_count
        assert np.allclose(sorted(map(tuple, m.positions)), sorted(map(tuple, mesh.positions)), atol=1e-6)
