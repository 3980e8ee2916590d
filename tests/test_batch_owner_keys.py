"""``pmw batch`` with a key of the owner layer alone: every asset marked with its owner ID, verified by it.

A model store marks its catalogue with its owner ID (the layer that survives re-compression and
simplification); ``pmw batch encode --key OWNER.key.json`` refused such a key ("the key holds no
watermark image"), and ``pmw batch verify`` called every file of the owner layer alone not-authentic.
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
from pmwm_codec.mesh import Mesh
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

ROOT = Path(__file__).resolve().parents[1]


def pmw(*args):
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    return subprocess.run([sys.executable, "-m", "pmwm_codec", *map(str, args)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=600)


def _turned(mesh: Mesh, seed: int) -> Mesh:
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return Mesh(mesh.positions @ q.T * rng.uniform(0.5, 3.0) + rng.normal(size=3), mesh.faces)


@pytest.fixture(scope="module")
def catalogue(tmp_path_factory):
    root = tmp_path_factory.mktemp("owner-batch")
    (root / "src").mkdir()
    mesh = shapes.demo_mesh(60)
    for i in range(2):
        write_mesh(root / "src" / f"m{i}.ply", _turned(mesh, i))
    for name, owner in (("owner.key.json", 0xABC), ("other.key.json", 0xDEF)):  # owner-only keys
        pmwm_codec.encode(mesh, root / f"{name}.pmw", owner_id=owner, key=root / name, measure="none")
    return root


@pytest.fixture(scope="module")
def marked(catalogue):
    """``catalogue/out``: the catalogue encoded with the owner-only key, and that key's bytes before."""
    key = catalogue / "owner.key.json"
    before = key.read_bytes()
    r = pmw("batch", "encode", catalogue / "src", "-o", catalogue / "out", "--key", key, "--workers", "1", "-q")
    assert r.returncode == 0, r.stderr
    return catalogue / "out", before


def test_an_owner_key_marks_every_asset_and_batch_verify_reads_them_present(catalogue, marked):
    key = catalogue / "owner.key.json"
    assert key.read_bytes() == marked[1]  # the collection key is never rewritten
    outputs = sorted(marked[0].glob("*.pmw"))
    assert len(outputs) == 2
    one = json.loads(pmw("verify", outputs[0], "--key", key, "--json").stdout)
    assert one["owner"]["verdict"] == "present" and one["owner"]["id"] == "0000000000000abc"
    r = pmw("batch", "verify", catalogue / "out", "--key", key, "--workers", "1", "--json")
    doc = json.loads(r.stdout)
    assert r.returncode == 0 and (doc["files"], doc["authentic"], doc["present"]) == (2, 0, 2)
    assert {x["verdict"] for x in doc["results"]} == {"present"}
    text = pmw("batch", "verify", catalogue / "out", "--key", key, "--workers", "1")
    assert text.returncode == 0 and "2 of 2 files verified (2 of the owner layer alone: present)" in text.stdout


def test_another_owner_key_reads_them_absent_and_exits_1(catalogue, marked):
    r = pmw("batch", "verify", catalogue / "out", "--key", catalogue / "other.key.json", "--workers", "1", "--json")
    doc = json.loads(r.stdout)
    assert r.returncode == 1 and doc["present"] == 0
    assert all(x["verdict"] in ("absent", "inconclusive") and "bits wrong" in x["error"] for x in doc["results"])


def test_a_cut_owner_only_file_is_not_counted_present(catalogue, marked, tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    data = (catalogue / "out" / "m0.ply.pmw").read_bytes()
    (out / "cut.pmw").write_bytes(data[: len(data) * 3 // 4])
    r = pmw("batch", "verify", out, "--key", catalogue / "owner.key.json", "--workers", "1", "--json")
    doc = json.loads(r.stdout)
    assert r.returncode == 1 and doc["present"] == 0
    assert doc["results"][0]["verdict"] == "truncated"  # was the prefix's absent or inconclusive: no verdict on the file
    assert "ends at" in doc["results"][0]["error"] and "the owner layer of the part there reads" in doc["results"][0]["error"]


def test_no_owner_with_an_owner_only_key_is_refused_before_anything_is_made(catalogue, tmp_path):
    r = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "none", "--key", catalogue / "owner.key.json",
            "--no-owner", "--workers", "1")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--no-owner would leave every asset unmarked" in r.stderr
    assert not (tmp_path / "none").exists()


def test_an_owner_only_key_with_a_watermark_is_refused_as_pmw_encode_refuses_it(catalogue, tmp_path):
    """The outputs would carry an image their key does not hold: nothing could verify them with it alone."""
    from PIL import Image

    Image.fromarray(np.random.default_rng(3).integers(0, 256, (16, 16)).astype(np.uint8)).save(tmp_path / "w.png")
    r = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "none", "--key", catalogue / "owner.key.json",
            "--watermark", tmp_path / "w.png", "--workers", "1")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "holds no watermark image" in r.stderr
    assert not (tmp_path / "none").exists()


def test_owner_id_marks_each_asset_with_a_key_of_its_own_and_a_rerun_skips_them(catalogue, tmp_path):
    out = tmp_path / "out"
    r = pmw("batch", "encode", catalogue / "src", "-o", out, "--owner-id", "0x77", "--workers", "1", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["ok"] == 2
    keys = sorted(out.glob("*.pmw.key.json"))
    assert len(keys) == 2 and all(json.loads(k.read_text())["owner_id"] == "0000000000000077" for k in keys)
    r = pmw("batch", "verify", out, "--workers", "1", "--json")  # each with the key beside it
    assert r.returncode == 0 and json.loads(r.stdout)["present"] == 2
    again = pmw("batch", "encode", catalogue / "src", "-o", out, "--owner-id", "0x77", "--workers", "1", "--json")
    assert again.returncode == 0 and json.loads(again.stdout)["skipped"] == 2


def test_owner_id_with_a_new_collection_key_makes_it_and_an_existing_key_must_name_it(catalogue, tmp_path):
    key = tmp_path / "store.key.json"
    r = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "out", "--owner-id", "0x78", "--key", key,
            "--workers", "1", "-q")
    assert r.returncode == 0 and json.loads(key.read_text())["owner_id"] == "0000000000000078"
    assert pmw("batch", "verify", tmp_path / "out", "--key", key, "--workers", "1").returncode == 0
    r = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "other", "--owner-id", "0x79", "--key", key,
            "--workers", "1")
    assert r.returncode == 2 and "names owner id 0000000000000078, not 0000000000000079" in r.stderr
    assert not (tmp_path / "other").exists()


def test_a_rerun_with_the_collection_key_alone_skips_what_owner_id_and_that_key_made(catalogue, tmp_path):
    """``--owner-id 0x7a --key K`` then ``--key K`` (the key names 0x7a; the same outputs) re-encoded every asset:
    the repeated ID was hashed into the settings as an option of its own, so neither run took the other's for done."""
    key = tmp_path / "store.key.json"
    first = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "out", "--owner-id", "0x7a", "--key", key,
                "--workers", "1", "--json")
    assert first.returncode == 0 and json.loads(first.stdout)["ok"] == 2, first.stderr
    again = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "out", "--key", key, "--workers", "1", "--json")
    assert again.returncode == 0 and json.loads(again.stdout)["skipped"] == 2, again.stdout
    back = pmw("batch", "encode", catalogue / "src", "-o", tmp_path / "out", "--owner-id", "0x7a", "--key", key,
               "--workers", "1", "--json")
    assert back.returncode == 0 and json.loads(back.stdout)["skipped"] == 2, back.stdout
