"""tools/owner_sweep.py sorts what `pmw encode --owner-id` did with a mesh and reads the ID after each transport."""

from __future__ import annotations

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.mesh import Mesh
from tools import owner_sweep


def _obj(path, mesh):
    with open(path, "w") as fh:
        fh.writelines(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in mesh.positions)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces)


def test_a_mesh_the_layer_survives_on_is_clean_and_reads_present_after_every_transport(tmp_path):
    m = shapes.icosphere(4, 1.0, noise=0.03, seed=5)
    _obj(tmp_path / "blob.obj", Mesh(m.positions * np.array([1.0, 0.8, 0.6]), m.faces))
    row = owner_sweep.probe(str(tmp_path / "blob.obj"), str(tmp_path))
    assert row["outcome"] == "clean" and row["notice"] is None
    assert [name for name, _ in owner_sweep.TRANSPORTS] == list(row["reads"])
    assert all(verdict == "present" for _, verdict in row["reads"].values()), row["reads"]
    table = owner_sweep.summary([dict(row, file="blob.obj")], 1.0)
    assert "| clean | 1 | 1 of 1 |" in table and "| refused (nothing written) | 0 |" in table


def test_a_sphere_is_refused_before_anything_is_written(tmp_path):
    m = shapes.icosphere(4, 1.0)  # every vertex norm the same: no shell can be told from another
    _obj(tmp_path / "sphere.obj", m)
    row = owner_sweep.probe(str(tmp_path / "sphere.obj"), str(tmp_path))
    assert row["outcome"] == "refused" and "cannot be read back" in row["why"]
    assert not (tmp_path / "out.pmw").exists()


def test_a_glb_asset_is_encoded_as_an_asset_and_read_from_the_glb_decode_writes(tmp_path):
    import pmwm_codec
    from pmwm_codec.stream.asset import decode_asset

    m = shapes.icosphere(4, 1.0, noise=0.03, seed=6)
    pmwm_codec.encode(Mesh(m.positions * np.array([1.0, 0.8, 0.6]), m.faces), tmp_path / "blob.pmw", measure="none")
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "blob.glb").write_bytes(decode_asset(str(tmp_path / "blob.pmw"))[0])
    row = owner_sweep.probe(str(tmp_path / "in" / "blob.glb"), str(tmp_path))
    assert row["outcome"] == "clean" and row["vertices"] == len(m.positions)
    assert all(verdict == "present" for _, verdict in row["reads"].values()), row["reads"]
    assert (tmp_path / "out.glb").exists()  # the decoded asset the reads were made on
