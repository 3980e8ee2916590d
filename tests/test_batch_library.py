"""``pmw batch`` on a library of 40 meshes, from the command line: 38 encode, 2 fail, a re-run skips.

The 38 good meshes are variants (noise, scale, rotation, vertex order, file format) of the
small shared corpus meshes when ``../shared`` is beside the project, of generated shapes
otherwise; two files are broken.  Everything goes through ``python -m pmwm_codec batch``.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.mesh import Mesh, read_mesh
from pmwm_codec.meshio import write_mesh

from conftest import CORPUS

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, read_ledger  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SUFFIXES = [".obj", ".ply", ".stl", ".glb", ".gltf"]
GOOD_COUNT = 38
BROKEN = {"broken/short-vertex.obj": b"v 1 2\nf 1 2 9\n", "broken/not-a-glb.glb": b"glTF\x02\x00\x00\x00garbage"}


def _parents() -> list:
    """Meshes to make variants of: the small corpus meshes when present, else generated shapes."""
    names = ["suzanne.obj", "cow.obj", "beetle.obj", "teapot.obj"]
    if all((CORPUS / n).exists() for n in names):
        return [(Path(n).stem, read_mesh(CORPUS / n)) for n in names]
    return [("sphere", shapes.icosphere(3, noise=0.02, seed=5)), ("torus", shapes.torus(36, 18, twist=0.3)),
            ("sheet", shapes.grid(26, 22)), ("blob", shapes.icosphere(4, noise=0.05, seed=9))]


def _variant(mesh: Mesh, i: int) -> Mesh:
    """Variant ``i`` of ``mesh``: rotated, scaled, moved, jittered, with its vertices renumbered."""
    rng = np.random.default_rng(1000 + i)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    pos = mesh.positions @ q.T * rng.uniform(0.2, 5.0) + rng.normal(size=3) * 10
    pos = pos + rng.normal(scale=1e-3 * mesh.bbox_diagonal(), size=pos.shape)
    order = rng.permutation(len(pos))
    inverse = np.empty_like(order)
    inverse[order] = np.arange(len(order))
    return Mesh(pos[order], inverse[mesh.faces])


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    root = tmp_path_factory.mktemp("library")
    src = root / "src"
    parents = _parents()
    good = []
    for i in range(GOOD_COUNT):
        name, parent = parents[i % len(parents)]
        rel = f"{name}/v{i:02d}{SUFFIXES[i % len(SUFFIXES)]}"
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        write_mesh(src / rel, _variant(parent, i))
        good.append(rel)
    for rel, data in BROKEN.items():
        (src / rel).parent.mkdir(parents=True, exist_ok=True)
        (src / rel).write_bytes(data)
    image = (np.indices((16, 16)).sum(0) // 2 % 2 * 255).astype(np.uint8)
    from PIL import Image

    Image.fromarray(image).save(root / "wm.png")
    return root, src, good


def _pmw(*argv):
    """``python -m pmwm_codec *argv --json``: (exit status, JSON object or stderr)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", *argv, "--json"], capture_output=True, env=env,
                          timeout=600)
    return done.returncode, json.loads(done.stdout) if done.stdout.strip() else done.stderr.decode()


@pytest.fixture(scope="module")
def encoded(library):
    root, src, good = library
    out = root / "out"
    status, doc = _pmw("batch", "encode", str(src), "-o", str(out), "--watermark", str(root / "wm.png"),
                       "--workers", "2")
    return out, status, doc


def test_38_of_40_meshes_encode_and_the_2_broken_ones_are_failed_rows_naming_the_problem(library, encoded):
    root, src, good = library
    out, status, doc = encoded
    assert status == 1, doc  # some failed
    assert (doc["ok"], doc["failed"]) == (GOOD_COUNT, len(BROKEN)), doc
    rows = read_ledger(out / LEDGER_NAME)
    assert len(rows) == GOOD_COUNT + len(BROKEN)
    by_input = {Path(r["input"]).relative_to(src).as_posix(): r for r in rows}
    assert sorted(by_input) == sorted([*good, *BROKEN])
    for rel in good:
        row = by_input[rel]
        assert row["status"] == "ok" and row["error"] is None
        assert row["bytes"] == os.path.getsize(out / (rel + ".pmw")) and row["vertices"] > 0
    for rel in BROKEN:
        row = by_input[rel]
        assert row["status"] == "failed" and Path(rel).name in row["error"] and "\n" not in row["error"]
        assert not (out / (rel + ".pmw")).exists() and not (out / (rel + ".pmw.key.json")).exists()
    assert not list(out.rglob("*.tmp"))


def test_every_output_decodes_to_its_input_vertex_count_and_verifies_authentic_with_its_key(library, encoded):
    root, src, good = library
    out, _, _ = encoded
    for rel in good:
        assert pmwm_codec.decode(out / (rel + ".pmw")).positions.shape == read_mesh(src / rel).positions.shape
    status, doc = _pmw("batch", "verify", str(out), "--workers", "2")
    assert status == 0, doc
    assert doc["files"] == doc["authentic"] == GOOD_COUNT


def test_a_second_run_skips_all_38_and_fails_the_2_again_without_touching_an_output(library, encoded):
    root, src, good = library
    out, _, _ = encoded
    before = {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.rglob("*.pmw*")}
    status, doc = _pmw("batch", "encode", str(src), "-o", str(out), "--watermark", str(root / "wm.png"),
                       "--workers", "2")
    assert status == 1 and (doc["skipped"], doc["failed"], doc["ok"]) == (GOOD_COUNT, len(BROKEN), 0), doc
    assert {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in out.rglob("*.pmw*")} == before
    last = {r["input"]: r["status"] for r in read_ledger(out / LEDGER_NAME)[-(GOOD_COUNT + len(BROKEN)):]}
    assert sorted(last.values()) == sorted(["skipped"] * GOOD_COUNT + ["failed"] * len(BROKEN))
