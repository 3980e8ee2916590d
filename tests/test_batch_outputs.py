"""``pmw batch``: an output damaged after its run (truncated by a partial copy or sync, or altered) is never taken
for done by a re-run, and ``pmw batch verify`` never counts a file that is not whole as authentic."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, encode_batch, read_ledger, verify_batch  # noqa: E402
from pmwm_codec.verify import verify_stream  # noqa: E402

from test_batch_refusals import IMAGE, client  # noqa: E402,F401 (a fixture)

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def encoded(tmp_path, client):
    """Three assets encoded into ``tmp/out`` (a key beside each output); returns (src, out)."""
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    for i in range(3):
        write_mesh(src / f"m{i}.obj", shapes.icosphere(3, noise=0.01, seed=i + 1))
    assert encode_batch(src, out, watermark=IMAGE, client=client)["ok"] == 3
    return src, out


def _truncate(path: Path, size: int) -> None:
    path.write_bytes(path.read_bytes()[:size])


def _statuses(out: Path, count: int) -> dict:
    return {Path(r["input"]).name: r["status"] for r in read_ledger(out / LEDGER_NAME)[-count:]}


def test_a_rerun_redoes_an_output_truncated_or_altered_since_its_ledger_row(encoded, client):
    src, out = encoded
    rows = read_ledger(out / LEDGER_NAME)
    assert all(r["output_sha256"] and r["bytes"] == os.path.getsize(r["output"]) for r in rows)
    whole = (out / "m0.obj.pmw").read_bytes()
    _truncate(out / "m0.obj.pmw", 3000)  # a partial copy: the size differs
    data = bytearray((out / "m1.obj.pmw").read_bytes())
    data[-10] ^= 0xFF  # the same size, another byte: the digest differs
    (out / "m1.obj.pmw").write_bytes(bytes(data))
    summary = encode_batch(src, out, watermark=IMAGE, client=client)
    assert (summary["ok"], summary["skipped"]) == (2, 1)
    assert _statuses(out, 3) == {"m0.obj": "ok", "m1.obj": "ok", "m2.obj": "skipped"}
    assert (out / "m0.obj.pmw").read_bytes() == whole  # redone with its key: the same bytes
    for i in range(3):
        pmw = out / f"m{i}.obj.pmw"
        outcome = verify_stream(pmw, f"{pmw}.key.json")
        assert outcome.verdict == "authentic" and outcome.end.complete
    assert encode_batch(src, out, watermark=IMAGE, client=client)["skipped"] == 3  # and then done


def test_a_ledger_of_an_older_run_without_digests_still_redoes_a_truncated_output(encoded, client):
    """Rows of an older run hold no output digest, and its skipped rows recorded the size they found (that of
    a damaged file): the size the output was written with counts."""
    src, out = encoded
    ledger = out / LEDGER_NAME
    rows = [{k: v for k, v in r.items() if k != "output_sha256"} for r in read_ledger(ledger)]
    _truncate(out / "m0.obj.pmw", 3000)
    skipped = dict(rows[[Path(r["input"]).name for r in rows].index("m0.obj")], status="skipped", bytes=3000)
    ledger.write_text("".join(json.dumps(r) + "\n" for r in [*rows, skipped]))
    summary = encode_batch(src, out, watermark=IMAGE, client=client)
    assert (summary["ok"], summary["skipped"]) == (1, 2)
    assert _statuses(out, 3)["m0.obj"] == "ok"
    assert verify_stream(out / "m0.obj.pmw", out / "m0.obj.pmw.key.json").end.complete


def test_batch_verify_reports_a_truncated_file_as_truncated_and_exits_1(encoded, client):
    _, out = encoded
    _truncate(out / "m1.obj.pmw", 3000)
    doc = verify_batch(out, client=client)
    assert (doc["files"], doc["authentic"]) == (3, 2)
    bad = [r for r in doc["results"] if r["verdict"] != "authentic"]
    assert [(Path(r["file"]).name, r["verdict"]) for r in bad] == [("m1.obj.pmw", "truncated")]
    assert "ends at 3,000 of its" in bad[0]["error"]
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", "batch", "verify", str(out), "--workers", "1"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 1, done.stderr
    assert f"  truncated: {out / 'm1.obj.pmw'} (the file ends at 3,000 of its" in done.stdout
    assert done.stdout.rstrip().endswith("2 of 3 files authentic")


def test_batch_verify_reports_a_file_cut_before_its_base_mesh_as_truncated_not_as_an_error(encoded, client):
    _, out = encoded
    _truncate(out / "m2.obj.pmw", 100)
    bad = [r for r in verify_batch(out, client=client)["results"] if r["verdict"] != "authentic"]
    assert [(Path(r["file"]).name, r["verdict"]) for r in bad] == [("m2.obj.pmw", "truncated")]  # was "error"
    assert "before the base mesh was complete" in bad[0]["error"]


# --- hard links: outputs shared with a snapshot of OUT_DIR, with each other, with an input -----------------


def _tree_bytes(root: Path) -> dict:
    return {p.relative_to(root): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_a_forced_rerun_never_changes_a_hard_linked_snapshot_of_the_output_folder_ledger_included(encoded, client,
                                                                                                   tmp_path):
    """``cp -al out snap`` (or an ``rsync --link-dest`` backup) shares every file of OUT_DIR.  The outputs and keys
    are published by a rename, which leaves the snapshot's names alone, but the ledger was appended in place: the
    snapshot's ledger got the new run's rows, naming outputs it does not hold."""
    src, out = encoded
    snap = tmp_path / "snap"
    subprocess.run(["cp", "-al", str(out), str(snap)], check=True)
    before = _tree_bytes(snap)
    doc = encode_batch(src, out, watermark=IMAGE, client=client, force=True)
    assert doc["ok"] == 3
    assert _tree_bytes(snap) == before
    assert os.stat(out / LEDGER_NAME).st_nlink == 1 and len(read_ledger(out / LEDGER_NAME)) == 6
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    assert encode_batch(src, out, watermark=IMAGE, client=client)["skipped"] == 3


def test_batch_verify_verifies_each_name_of_a_hard_linked_pmw_with_its_own_key(encoded, client):
    src, out = encoded
    os.link(out / "m0.obj.pmw", out / "copy.pmw")
    os.link(out / "m1.obj.pmw.key.json", out / "copy.pmw.key.json")  # another asset's key: not this file's
    doc = verify_batch(out, client=client)
    verdicts = {Path(r["file"]).name: r["verdict"] for r in doc["results"]}
    assert verdicts == {"copy.pmw": "not-authentic", "m0.obj.pmw": "authentic", "m1.obj.pmw": "authentic",
                        "m2.obj.pmw": "authentic"}
    os.replace(out / "m0.obj.pmw.key.json", out / "copy.pmw.key.json")
    os.link(out / "copy.pmw.key.json", out / "m0.obj.pmw.key.json")
    assert verify_batch(out, client=client)["authentic"] == 4


def test_an_output_that_is_a_hard_link_of_its_input_is_a_failed_asset_and_the_input_is_kept(tmp_path, client):
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    write_mesh(src / "m.obj", shapes.icosphere(2, noise=0.01, seed=1))
    kept = (src / "m.obj").read_bytes()
    os.link(src / "m.obj", out / "m.obj.pmw")
    doc = encode_batch(src, out, watermark=IMAGE, client=client)
    assert (doc["ok"], doc["failed"]) == (0, 1)
    assert "is also the input" in doc["failures"][0]["error"]
    assert (src / "m.obj").read_bytes() == kept and (out / "m.obj.pmw").read_bytes() == kept


def test_a_ledger_that_is_a_symlink_is_refused_and_the_file_it_names_is_never_appended_to(tmp_path, client):
    """The ledger is appended in place: a ``pmw-batch.jsonl`` planted in OUT_DIR as a link to another file (a
    shell profile, another tree's ledger) made the run append its rows there."""
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    write_mesh(src / "m.obj", shapes.icosphere(2, noise=0.01, seed=1))
    victim = tmp_path / "profile"
    victim.write_text("precious\n")
    (out / LEDGER_NAME).symlink_to(victim)
    with pytest.raises(OSError, match="is a symbolic link: the ledger is appended in place"):
        encode_batch(src, out, watermark=IMAGE, client=client)
    assert victim.read_text() == "precious\n"
    assert sorted(p.name for p in out.iterdir()) == [LEDGER_NAME]  # nothing made: no output, no key


def test_a_failed_asset_leaves_no_empty_folder_behind(tmp_path, client):
    """A failed asset's output folder (``out/bad/deeper`` for ``src/bad/deeper/broken.obj``) was made for it and
    left behind, empty; one an output went into stays, and so does a folder that was there before the run."""
    src, out = tmp_path / "src", tmp_path / "out"
    (src / "bad" / "deeper").mkdir(parents=True)
    (src / "bad" / "deeper" / "broken.obj").write_bytes(b"v 1 2\nf 1 2 9\n")
    (src / "good").mkdir()
    write_mesh(src / "good" / "m.obj", shapes.icosphere(2, noise=0.01, seed=1))
    (src / "mine").mkdir()
    (src / "mine" / "broken.obj").write_bytes(b"")
    (out / "mine").mkdir(parents=True)  # the user's own folder
    keys = tmp_path / "keys"
    summary = encode_batch(src, out, watermark=IMAGE, keys_dir=keys, client=client)
    assert (summary["ok"], summary["failed"]) == (1, 2)
    assert sorted(p.relative_to(out).as_posix() for p in out.rglob("*")) == [
        "good", "good/m.obj.pmw", "mine", LEDGER_NAME]
    assert sorted(p.relative_to(keys).as_posix() for p in keys.rglob("*")) == ["good", "good/m.obj.pmw.key.json"]


@pytest.mark.parametrize("collection", [False, True], ids=["key-beside", "collection-key"])
def test_a_watermark_too_large_for_an_asset_is_named_as_the_user_gave_it(tmp_path, client, collection):
    """A batch's failed row named the padded square (``a 256x256 watermark needs ...``) where ``pmw encode`` names
    the image as given: the run loads the image once and sends the square, so its size as given goes with it."""
    from PIL import Image
    import numpy as np

    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    write_mesh(src / "t.obj", shapes.torus(24, 12))
    pixels = np.random.default_rng(0).integers(0, 256, (200, 300)).astype(np.uint8)
    Image.fromarray(pixels).save(tmp_path / "w.png")
    key = str(tmp_path / "c.key.json") if collection else None
    assert encode_batch(src, out, watermark=tmp_path / "w.png", key=key, client=client)["failed"] == 1
    (row,) = read_ledger(out / LEDGER_NAME)
    assert ": the 300x200 watermark (carried as a 256x256 square) needs " in row["error"], row["error"]
