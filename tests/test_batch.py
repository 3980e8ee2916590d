"""``pmw batch``: a folder of generated meshes through Dask, the ledger, resumption, a real cluster."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, encode_batch, expand_sources, read_ledger, verify_batch  # noqa: E402
from pmwm_codec.batch.run import dask_client  # noqa: E402
from pmwm_codec.batch.ledger import LedgerWriter  # noqa: E402
from pmwm_codec.batch.tasks import EncodeJob, encode_task  # noqa: E402
from pmwm_codec.cli import main  # noqa: E402
from pmwm_codec.verify import verify_stream  # noqa: E402

from test_batch_scheduler import _stopped, dask_cluster  # noqa: E402
from test_batch_signals import _left_after  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
GOOD = {
    "a.obj": lambda: shapes.icosphere(3, noise=0.01, seed=1),
    "b.ply": lambda: shapes.icosphere(3, noise=0.02, seed=2),
    "sub/c.stl": lambda: shapes.torus(30, 16),
    "sub/d.glb": lambda: shapes.torus(32, 16, twist=0.2),
    "sub/deep/e.obj": lambda: shapes.grid(24, 24),
    "sub/deep/f.gltf": lambda: shapes.icosphere(3, noise=0.03, seed=3),
}
BROKEN = {"broken.obj": b"v 1 2\nf 1 2 9\n", "sub/empty.ply": b""}


def _library(root: Path) -> Path:
    src = root / "src"
    for name, make in GOOD.items():
        (src / name).parent.mkdir(parents=True, exist_ok=True)
        write_mesh(src / name, make())
    for name, data in BROKEN.items():
        (src / name).write_bytes(data)
    (src / "notes.txt").write_text("not a mesh\n")
    return src


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    root = tmp_path_factory.mktemp("batch")
    src = _library(root)
    image = (np.indices((8, 8)).sum(0) % 2 * 255).astype(np.uint8)
    from PIL import Image

    Image.fromarray(image).save(root / "wm.png")
    return root, src


@pytest.fixture(scope="module")
def client():
    """One local Dask cluster (two worker processes) for the in-process runs of this module."""
    with dask_client(workers=2) as c:
        yield c


@pytest.fixture(scope="module")
def first_run(library):
    root, src = library
    out = root / "out"
    status, doc = _run_json(["batch", "encode", str(src), "-o", str(out), "--watermark", str(root / "wm.png"),
                             "--workers", "2"])
    return out, status, doc


def _run_json(argv):
    """``pmw argv --json`` in a subprocess: (exit status, the JSON object)."""
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", *argv, "--json"], capture_output=True, env=env,
                          timeout=300)
    return done.returncode, json.loads(done.stdout) if done.stdout.strip() else done.stderr.decode()


def _last_statuses(out: Path) -> dict:
    return {Path(r["input"]).name: r["status"] for r in read_ledger(out / LEDGER_NAME)}


def test_batch_encode_writes_outputs_that_decode_and_verify_and_a_ledger_row_per_asset(first_run, library):
    out, status, doc = first_run
    root, src = library
    assert status == 1 and doc["ok"] == len(GOOD) and doc["failed"] == len(BROKEN)
    for name, make in GOOD.items():
        pmw = out / (name + ".pmw")
        assert pmwm_codec.decode(pmw).positions.shape == make().positions.shape
        assert verify_stream(pmw, str(pmw) + ".key.json").verdict == "authentic"
    rows = read_ledger(out / LEDGER_NAME)
    assert sorted(Path(r["input"]).relative_to(src).as_posix() for r in rows) == sorted([*GOOD, *BROKEN])
    for r in rows:
        if r["status"] == "ok":
            assert r["bytes"] == os.path.getsize(r["output"]) and r["vertices"] > 0 and r["error"] is None
        else:
            assert r["status"] == "failed" and not os.path.exists(r["output"])
    errors = {Path(r["input"]).name: r["error"] for r in rows if r["status"] == "failed"}
    assert "malformed OBJ" in errors["broken.obj"] and "empty.ply" in errors["empty.ply"]
    assert not list(out.rglob("*.tmp")) and not (out / "notes.txt.pmw").exists()


def test_second_run_skips_done_assets_and_retries_failed_ones(first_run, library, client):
    out, _, _ = first_run
    root, src = library
    before = {p: p.read_bytes() for p in out.rglob("*.pmw")}
    doc = encode_batch(src, out, watermark=root / "wm.png", client=client)
    assert doc["skipped"] == len(GOOD) and doc["failed"] == len(BROKEN) and doc["ok"] == 0
    assert len(read_ledger(out / LEDGER_NAME)) == 2 * (len(GOOD) + len(BROKEN))
    assert {p: p.read_bytes() for p in out.rglob("*.pmw")} == before


def test_changed_input_or_missing_key_is_redone_and_the_rest_skipped(tmp_path, client):
    src = tmp_path / "src"
    src.mkdir()
    write_mesh(src / "a.obj", shapes.icosphere(3, noise=0.01, seed=1))
    write_mesh(src / "b.obj", shapes.icosphere(3, noise=0.01, seed=2))
    image = np.full((4, 4), 255, np.uint8)
    image[::2] = 0
    out = tmp_path / "out"
    assert encode_batch(src, out, watermark=image, client=client)["ok"] == 2
    write_mesh(src / "a.obj", shapes.icosphere(3, noise=0.01, seed=7))
    os.unlink(out / "b.obj.pmw.key.json")
    summary = encode_batch(src, out, watermark=image, client=client)
    assert (summary["ok"], summary["skipped"]) == (2, 0)
    assert verify_batch(out, client=client)["authentic"] == 2
    assert encode_batch(src, out, watermark=image, client=client, force=True)["ok"] == 2


def test_a_rerun_with_another_watermark_or_key_is_never_skipped_as_done(tmp_path, client):
    src = tmp_path / "src"
    src.mkdir()
    for i in range(2):
        write_mesh(src / f"m{i}.obj", shapes.icosphere(3, noise=0.01, seed=i + 1))
    first, second = np.full((4, 4), 255, np.uint8), np.full((4, 4), 255, np.uint8)
    first[::2], second[:, ::2] = 0, 0
    out = tmp_path / "out"
    assert encode_batch(src, out, watermark=first, client=client)["ok"] == 2
    assert encode_batch(src, out, watermark=first, client=client)["skipped"] == 2
    before = {p: p.read_bytes() for p in out.glob("*.pmw*")}
    redo = encode_batch(src, out, watermark=second, client=client)  # never skipped as if done
    assert redo["failed"] == 2 and all("key holds another watermark" in r["error"] for r in redo["failures"])
    assert {p: p.read_bytes() for p in out.glob("*.pmw*")} == before  # the keys' own outputs untouched
    # under other keys, the keys beside the outputs (what ``verify_batch(out)`` reads) would no longer verify them
    redo = encode_batch(src, out, watermark=second, keys_dir=tmp_path / "keys2", client=client)
    assert redo["failed"] == 2 and all("marks it with another key" in r["error"] for r in redo["failures"])
    assert {p: p.read_bytes() for p in out.glob("*.pmw*")} == before
    for old_key in out.glob("*.pmw.key.json"):  # moved away, as the message says
        old_key.rename(tmp_path / old_key.name)
    assert encode_batch(src, out, watermark=second, keys_dir=tmp_path / "keys2", client=client)["ok"] == 2
    for i in range(2):
        pmw = out / f"m{i}.obj.pmw"
        assert verify_stream(pmw, tmp_path / "keys2" / f"m{i}.obj.pmw.key.json", second).verdict == "authentic"
    collection = tmp_path / "collection.key.json"
    assert encode_batch(src, out, watermark=second, key=collection, client=client)["ok"] == 2
    assert encode_batch(src, out, watermark=second, key=collection, client=client)["skipped"] == 2
    assert verify_batch(out, key=collection, client=client)["authentic"] == 2


def test_sigkill_of_the_process_group_halfway_then_rerun_finishes_consistently(library, tmp_path, client):
    """Killed halfway by the order of events: the run stops itself (``batch-row-taken@4:STOP``) as it takes its fourth
    result, three rows in its ledger (one at least ``ok``: two assets are broken), and the whole process group is
    killed there.  The ledger keeps exactly those three rows (each flushed as written), and the re-run skips exactly
    the outputs they name and does the rest."""
    root, src = library
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(src), "-o", str(out),
            "--watermark", str(root / "wm.png"), "--workers", "1", "-q"]
    proc = subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT="batch-row-taken@4:STOP"),
                            start_new_session=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        _stopped(proc)  # holding its fourth result, its row not yet written
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    before = read_ledger(out / LEDGER_NAME)
    assert len(before) == 3
    done = sum(row["status"] == "ok" for row in before)
    doc = encode_batch(src, out, watermark=root / "wm.png", client=client)
    assert (doc["skipped"], doc["ok"], doc["failed"]) == (done, len(GOOD) - done, len(BROKEN))
    last = _last_statuses(out)
    assert {n: last[Path(n).name] for n in BROKEN} == dict.fromkeys(BROKEN, "failed")
    assert {last[Path(n).name] for n in GOOD} <= {"ok", "skipped"}
    for name in GOOD:
        pmw = out / (name + ".pmw")
        assert verify_stream(pmw, str(pmw) + ".key.json").verdict == "authentic"
    assert sorted(p.name for p in out.rglob("*.pmw")) == sorted(Path(n).name + ".pmw" for n in GOOD)
    assert not list(out.rglob("*.tmp"))


def test_ctrl_c_halfway_is_one_line_and_exit_130_and_leaves_no_process_behind(library, tmp_path):
    """A Ctrl-C (SIGINT to the process group) raised KeyboardInterrupt in every Dask worker too, each printing
    its traceback on stderr under ``pmw: error: interrupted``.  Halfway by the order of events: the run stops itself
    (``batch-row-taken@2:STOP``) as it takes its second result, the Ctrl-C reaches the group there, and the run is
    continued: it records that row (the stop is held back while it does) and stops."""
    root, src = library
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(src), "-o", str(out),
            "--watermark", str(root / "wm.png"), "--workers", "1", "-q"]
    # started with SIGINT at its default, as a terminal's command is: a suite run as a background job (``cmd &``,
    # nohup) has it ignored, and the run rightly kept it ignored: it went on to its end (exit 1, not a word)
    proc = subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT="batch-row-taken@2:STOP"),
                            start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    try:
        _stopped(proc)
        os.killpg(proc.pid, signal.SIGINT)
        proc.send_signal(signal.SIGCONT)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
    assert proc.returncode == 130, err
    assert "Traceback" not in err and err.strip().splitlines()[-1] == "pmw: error: interrupted", err
    left = _left_after(proc.pid)  # (the run's own session: its process group)
    assert not left, left  # no worker, forkserver or encoder outlives the run
    rows = read_ledger(out / LEDGER_NAME)
    assert 2 <= len(rows) < len(GOOD) + len(BROKEN)  # the held row, and those an encoder published before the stop
    assert sorted(r["output"] for r in rows if r["status"] == "ok") == sorted(map(str, out.rglob("*.pmw")))
    assert not list(out.rglob("*.tmp"))


def test_a_timed_out_asset_is_killed_and_leaves_nothing(tmp_path):
    src = tmp_path / "big.obj"
    write_mesh(src, shapes.icosphere(5, noise=0.01))
    out = tmp_path / "out" / "big.obj.pmw"
    row = encode_task(EncodeJob(str(src), str(out), key_path=str(out) + ".key.json",
                                watermark=np.full((8, 8), 255, np.uint8), timeout=0.05))
    assert row["status"] == "timeout" and "killed" in row["error"]
    assert sorted(os.listdir(out.parent)) == []


def test_a_dask_scheduler_and_two_workers_give_the_same_bytes_as_the_local_run(library, tmp_path, client):
    root, src = library
    key = tmp_path / "collection.key.json"
    local, remote = tmp_path / "local", tmp_path / "remote"
    common = ["--watermark", str(root / "wm.png"), "--key", str(key)]
    doc = encode_batch(src, local, watermark=root / "wm.png", key=key, client=client)
    assert doc["ok"] == len(GOOD)
    with dask_cluster(2) as (address, _):
        status, doc = _run_json(["batch", "encode", str(src), "-o", str(remote), *common, "--scheduler", address])
        assert status == 1 and doc["ok"] == len(GOOD) and doc["failed"] == len(BROKEN)
        status, doc = _run_json(["batch", "verify", str(remote), "--key", str(key), "--scheduler", address])
        assert status == 0 and doc["authentic"] == doc["files"] == len(GOOD)
    for name in GOOD:
        assert (remote / (name + ".pmw")).read_bytes() == (local / (name + ".pmw")).read_bytes()
    assert not list(remote.rglob("*.key.json")) and not list(local.rglob("*.key.json"))


def test_batch_verify_reports_a_file_verified_with_another_key_as_not_authentic(first_run, tmp_path, client):
    out, _, _ = first_run
    tree = tmp_path / "tree"
    shutil.copytree(out, tree)
    keys = sorted(tree.rglob("*.pmw.key.json"))
    shutil.copy(keys[0], keys[1])
    doc = verify_batch(tree, client=client)
    assert doc["authentic"] == len(GOOD) - 1
    bad = [r for r in doc["results"] if r["verdict"] != "authentic"]
    assert [r["file"] for r in bad] == [str(keys[1])[: -len(".key.json")]]


def test_sources_mirror_the_tree_from_a_folder_a_glob_and_a_manifest(library, tmp_path):
    root, src = library
    by_folder = expand_sources(src, src / "out")
    assert sorted(a.relative for a in by_folder) == sorted([*GOOD, *BROKEN])
    assert all(a.output == str(src / "out" / a.relative) + ".pmw" for a in by_folder)
    by_glob = expand_sources(str(src / "sub" / "**" / "*.obj"), tmp_path)
    assert [a.relative for a in by_glob] == ["deep/e.obj"]
    manifest = tmp_path / "list.txt"
    manifest.write_text(f"# meshes\n{src / 'a.obj'}\n\n{src / 'sub' / 'c.stl'}\n{src / 'a.obj'}\n")
    assert [a.relative for a in expand_sources(manifest, tmp_path / "o")] == ["a.obj", "sub/c.stl"]


def test_outputs_that_differ_only_in_letter_case_encode_the_first_and_refuse_the_other(tmp_path, client):
    """``A.OBJ`` and ``a.obj`` (or ``Chairs/oak.obj`` and ``chairs/oak.obj``) in a library made on Linux write one
    output on a case-insensitive file system (macOS, Windows): both were encoded, and there one asset's ``.pmw``
    and key silently replaced the other's.  The outputs are compared case-folded: the first is encoded, the
    other is a failed row that names it, read by no one and written nowhere."""
    lib = tmp_path / "lib"
    for name in ("A.OBJ", "a.obj", "Chairs/oak.obj", "b.obj", "chairs/oak.obj"):
        (lib / name).parent.mkdir(parents=True, exist_ok=True)
        write_mesh(lib / name, shapes.icosphere(1, noise=0.01, seed=len(name)))
    summary = encode_batch(lib, tmp_path / "out", client=client)
    assert (summary["ok"], summary["failed"]) == (3, 2), summary
    errors = {Path(r["input"]).relative_to(lib).as_posix(): r["error"] for r in summary["failures"]}
    assert errors == {
        "a.obj": f"{lib / 'a.obj'}: its output a.obj.pmw is A.OBJ.pmw (of {lib / 'A.OBJ'}) but for letter case, one "
                 "file on a case-insensitive file system (macOS, Windows); not encoded (rename one of the two to "
                 "encode both)",
        "chairs/oak.obj": f"{lib / 'chairs' / 'oak.obj'}: its output chairs/oak.obj.pmw is Chairs/oak.obj.pmw (of "
                          f"{lib / 'Chairs' / 'oak.obj'}) but for letter case, one file on a case-insensitive file "
                          "system (macOS, Windows); not encoded (rename one of the two to encode both)"}
    assert all(r["input_sha256"] is None for r in summary["failures"])  # never read
    written = sorted(p.relative_to(tmp_path / "out").as_posix() for p in (tmp_path / "out").rglob("*.pmw"))
    assert written == ["A.OBJ.pmw", "Chairs/oak.obj.pmw", "b.obj.pmw"]
    assert not (tmp_path / "out" / "chairs").exists()  # the refused asset's folder is never made
    assets = expand_sources(lib, tmp_path / "out")
    assert [(a.relative, a.clash is not None) for a in assets] == [
        ("A.OBJ", False), ("Chairs/oak.obj", False), ("a.obj", True), ("b.obj", False), ("chairs/oak.obj", True)]


def test_a_glob_enters_no_symlinked_folder_and_takes_nothing_under_the_output_folder(tmp_path):
    """``**`` followed symlinked folders, which a folder SRC never enters: a link to a folder above
    (``lib/a/loop -> ..``) made one file some forty assets, each encoded to its own deeper output."""
    lib = tmp_path / "lib"
    (lib / "a").mkdir(parents=True)
    write_mesh(lib / "a" / "x.obj", shapes.icosphere(1))
    (lib / "a" / "loop").symlink_to("..")
    (lib / "out").mkdir()
    write_mesh(lib / "out" / "decoded.obj", shapes.icosphere(1))
    assert [a.relative for a in expand_sources(str(lib / "**" / "*.obj"), lib / "out")] == ["a/x.obj"]
    assert [a.relative for a in expand_sources(str(lib / "*" / "*.obj"), tmp_path / "o")] == ["a/x.obj", "out/decoded.obj"]
    (tmp_path / "named").symlink_to(lib)  # a link the user names is followed, as a folder SRC's is
    assert [a.relative for a in expand_sources(str(tmp_path / "named" / "**" / "x.obj"), tmp_path / "o")] == ["a/x.obj"]


def test_a_glob_over_two_symlink_loops_ends_at_once(tmp_path):
    """With a second link (``lib/b -> a`` beside ``lib/a/loop -> ..``) the expansion of ``lib/**/*.obj`` never
    ended (the paths through the links grow exponentially): the run hung before it made anything."""
    lib = tmp_path / "lib"
    (lib / "a").mkdir(parents=True)
    write_mesh(lib / "a" / "x.obj", shapes.icosphere(1))
    (lib / "a" / "loop").symlink_to("..")
    (lib / "b").symlink_to("a")
    code = ("import sys; from pmwm_codec.batch import expand_sources; "
            "print(*[a.relative for a in expand_sources(sys.argv[1], sys.argv[2])])")
    try:
        done = subprocess.run([sys.executable, "-c", code, str(lib / "**" / "*.obj"), str(tmp_path / "out")],
                              capture_output=True, text=True, timeout=60, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    except subprocess.TimeoutExpired:
        pytest.fail("the glob did not end within 60 s")
    assert done.returncode == 0 and done.stdout.split() == ["a/x.obj"], done.stderr


def test_a_manifest_written_with_a_byte_order_mark_and_crlf_names_its_first_file(library, tmp_path):
    """A manifest saved by a Windows editor starts with a UTF-8 byte order mark: it was taken into the first path,
    which then named no file (a failed asset)."""
    root, src = library
    manifest = tmp_path / "list.txt"
    manifest.write_bytes(b"\xef\xbb\xbf" + f"{src / 'a.obj'}\r\n{src / 'b.ply'}\r\n".encode())
    assets = expand_sources(manifest, tmp_path / "o")
    assert [a.input for a in assets] == [str(src / "a.obj"), str(src / "b.ply")]


def test_a_manifest_longer_than_the_limit_is_refused_never_cut(library, tmp_path, monkeypatch):
    """A manifest past the characters read used to be cut there silently: the paths after it, and one cut in
    two, left out of the run (exit 0)."""
    from pmwm_codec.batch import sources

    root, src = library
    manifest = tmp_path / "list.txt"
    manifest.write_text(f"{src / 'a.obj'}\n{src / 'sub' / 'c.stl'}\n")
    monkeypatch.setattr(sources, "MAX_MANIFEST_CHARS", len(manifest.read_text()))
    assert [a.relative for a in expand_sources(manifest, tmp_path / "o")] == ["a.obj", "sub/c.stl"]
    monkeypatch.setattr(sources, "MAX_MANIFEST_CHARS", len(manifest.read_text()) - 3)
    with pytest.raises(ValueError, match="a manifest of more than"):
        expand_sources(manifest, tmp_path / "o")


def test_a_folder_holding_the_output_folder_does_not_take_outputs_as_inputs(tmp_path):
    write_mesh(tmp_path / "a.obj", shapes.icosphere(1))
    (tmp_path / "out").mkdir()
    write_mesh(tmp_path / "out" / "decoded.obj", shapes.icosphere(1))
    assert [a.relative for a in expand_sources(tmp_path, tmp_path / "out")] == ["a.obj"]


def test_an_output_folder_that_is_the_source_or_holds_it_leaves_no_subfolder_out(tmp_path):
    """``pmw batch encode lib -o lib`` (or ``-o .`` from lib's parent) took every subfolder of lib for a part of
    OUT_DIR and encoded the top-level meshes only, exit 0."""
    lib = tmp_path / "lib"
    (lib / "sub").mkdir(parents=True)
    write_mesh(lib / "a.obj", shapes.icosphere(1))
    write_mesh(lib / "sub" / "b.ply", shapes.icosphere(1))
    for out in (lib, tmp_path):
        assert sorted(a.relative for a in expand_sources(lib, out)) == ["a.obj", "sub/b.ply"]


def test_the_ledger_reader_drops_a_line_cut_by_a_kill_and_the_writer_starts_a_new_line(tmp_path):
    path = tmp_path / LEDGER_NAME
    row = {"input": "/x.obj", "input_sha256": "0" * 64, "output": "/o/x.obj.pmw", "status": "ok", "error": None,
           "seconds": 1.0, "bytes": 10, "vertices": 4}
    path.write_text(json.dumps(row) + "\n" + json.dumps(row)[:30])
    assert read_ledger(path) == [row]
    with LedgerWriter(path) as ledger:
        ledger.write({**row, "status": "skipped"})
    assert [r["status"] for r in read_ledger(path)] == ["ok", "skipped"]


@pytest.mark.parametrize("argv, words", [
    (["batch", "encode", "/nonexistent/src", "-o", "OUT"], "no such folder"),
    (["batch", "encode", "SRC", "-o", "OUT", "--key", "k", "--keys-dir", "d"], "not allowed with"),
    (["batch", "encode", "SRC", "-o", "OUT", "--workers", "0"], "--workers must be > 0"),
    (["batch", "verify", "/nonexistent/out"], "no such folder"),
    (["batch", "encode", "SRC", "-o", "OUT", "--grid-bits", "40"], "--grid-bits must be"),
    (["batch", "encode", "SRC", "-o", "OUT", "--payload-version", "3"], "invalid choice"),
    (["batch", "encode", "SRC", "-o", "OUT", "--no-owner"], "--no-owner needs --watermark"),
])
def test_bad_batch_usage_exits_2_with_one_line(argv, words, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pmw: error:") and words in err


def test_batch_verify_of_a_file_names_it_as_not_a_folder(tmp_path, capsys):
    """A file given as OUT_DIR exists: the line says it is not a folder (it said "no such folder")."""
    path = tmp_path / "demo.obj"
    path.write_text("v 0 0 0\n")
    assert main(["batch", "verify", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "is not a folder" in err and "no such" not in err


def test_more_local_workers_than_four_per_cpu_are_refused_before_anything_is_made(library, tmp_path, capsys):
    """A thousand worker processes (each imports the library) would take the machine down: refused in one line,
    no output folder made, nothing started."""
    _, src = library
    out = tmp_path / "never"
    for argv in (["batch", "encode", str(src), "-o", str(out)], ["batch", "verify", str(src)]):
        assert main([*argv, "--workers", str(4 * (os.cpu_count() or 1) + 1)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "local processes per CPU" in err and "--scheduler" in err
    assert not out.exists()


def test_a_local_run_starts_no_more_workers_than_it_has_assets(monkeypatch):
    """``--workers 4`` over one asset starts one process; the default is one per CPU, and the same bound holds."""
    from pmwm_codec.batch import run

    monkeypatch.setattr(run.os, "cpu_count", lambda: 2)
    assert run.local_workers(4, tasks=1) == 1
    assert run.local_workers(None, tasks=1) == 1
    assert run.local_workers(None, tasks=10) == 2
    assert run.local_workers(8, tasks=10) == 8
    assert run.local_workers(3) == 3
    with pytest.raises(run.BatchError, match="--workers 9"):
        run.local_workers(9, tasks=100)


def test_batch_without_dask_installed_tells_how_to_install_it(monkeypatch, capsys, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)
    assert main(["batch", "encode", str(tmp_path), "-o", str(tmp_path / "o")]) == 2
    assert capsys.readouterr().err == 'pmw: error: pmw batch needs Dask: pip install "pmwm_codec[batch]"\n'


def test_a_collection_key_made_for_another_watermark_is_refused(library, tmp_path, capsys):
    root, src = library
    key = tmp_path / "k.json"
    other = tmp_path / "other.png"
    from PIL import Image

    Image.fromarray(np.zeros((8, 8), np.uint8)).save(other)
    from pmwm_codec.batch.run import collection_key

    collection_key(str(key), str(root / "wm.png"))
    assert main(["batch", "encode", str(src), "-o", str(tmp_path / "o"), "--key", str(key),
                 "--watermark", str(other)]) == 2
    assert "another watermark image" in capsys.readouterr().err


def test_keys_dir_holds_each_assets_key_and_batch_verify_finds_them_there(tmp_path, client):
    src = tmp_path / "src"
    (src / "x").mkdir(parents=True)
    write_mesh(src / "x" / "a.obj", shapes.icosphere(3, noise=0.01, seed=4))
    image = np.zeros((4, 4), np.uint8)
    image[:, ::2] = 255
    out, keys = tmp_path / "out", tmp_path / "keys"
    assert encode_batch(src, out, watermark=image, keys_dir=keys, client=client)["ok"] == 1
    assert (keys / "x" / "a.obj.pmw.key.json").is_file() and not list(out.rglob("*.key.json"))
    assert verify_batch(out, keys_dir=keys, client=client)["authentic"] == 1
    assert verify_batch(out, client=client)["results"][0]["verdict"] == "error"  # no key beside the file


def test_the_encoder_forkserver_warm_up_runs_a_real_encode_and_decode():
    from pmwm_codec.batch import tasks, warm

    assert "pmwm_codec.batch.warm" in tasks._PRELOAD  # imported by each worker's forkserver
    assert warm.warm() is True  # False would mean every forked encoder compiles its kernels again


def _extension(path) -> dict:
    import struct

    data = Path(path).read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    gltf = json.loads(data[20 : 20 + length])
    return gltf, gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]


def test_batch_encode_takes_the_stream_options_of_pmw_encode_and_redoes_assets_when_they_change(tmp_path, client, capsys):
    src = tmp_path / "src"
    src.mkdir()
    write_mesh(src / "a.obj", shapes.icosphere(3, noise=0.01, seed=1))
    out = tmp_path / "out"
    argv = ["batch", "encode", str(src), "-o", str(out), "--grid-bits", "12", "--payload-version", "1",
            "--base-codec", "plain", "--base-vertices", "80", "--workers", "1", "--json"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["ok"] == 1
    gltf, ext = _extension(out / "a.obj.pmw")
    assert ext["grid"]["bits"] == 12 and "payload" in ext and ext["payload"]["version"] == 1
    assert "KHR_draco_mesh_compression" not in json.dumps(gltf["meshes"]) and isinstance(ext["chunks"], list)
    assert gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]["count"] <= 80
    # the same options: skipped; other options (or none): redone, with what they ask
    assert main(argv) == 0 and json.loads(capsys.readouterr().out)["skipped"] == 1
    assert encode_batch(src, out, client=client, options={"grid_bits": 14})["ok"] == 1
    assert _extension(out / "a.obj.pmw")[1]["grid"]["bits"] == 14
    assert encode_batch(src, out, client=client)["ok"] == 1
    gltf, ext = _extension(out / "a.obj.pmw")
    assert ext["grid"]["bits"] == 16 and ext["payload"]["version"] == 2 and "KHR_draco_mesh_compression" in gltf["extensionsUsed"]
    assert encode_batch(src, out, client=client)["skipped"] == 1


def test_batch_no_owner_writes_the_exact_layer_only(tmp_path, client, capsys):
    src = tmp_path / "src"
    src.mkdir()
    write_mesh(src / "a.obj", shapes.icosphere(3, noise=0.01, seed=1))
    image = np.full((4, 4), 255, np.uint8)
    image[::2] = 0
    owners = []
    for out, options in ((tmp_path / "o1", None), (tmp_path / "o2", {"owner_id": False})):
        assert encode_batch(src, out, watermark=image, client=client, options=options)["ok"] == 1
        pmw = out / "a.obj.pmw"
        main(["verify", str(pmw), "--key", str(pmw) + ".key.json", "--json"])
        doc = json.loads(capsys.readouterr().out)
        assert doc["verdict"] == "authentic"
        owners.append(doc.get("owner"))
    assert owners[0]["verdict"] == "present" and owners[1] is None


@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_an_input_that_is_a_fifo_or_a_device_is_a_failed_asset_never_a_hang(tmp_path, kind):
    """Hashing the input opened it as it was: a FIFO in the library (or ``/dev/zero`` in a manifest) blocked or
    read forever, before the encoder and its timeout ever started."""
    if kind == "fifo":
        path = tmp_path / "f.obj"
        os.mkfifo(path)
    else:
        path = Path("/dev/zero")
    row = encode_task(EncodeJob(str(path), str(tmp_path / "out" / "f.obj.pmw"), timeout=30))
    assert row["status"] == "failed" and "not a regular file" in row["error"] and str(path) in row["error"]
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("named", ["folder", "glob"])
def test_a_symlink_out_of_the_named_folder_is_a_refused_asset_never_read(tmp_path, named):
    """A folder or glob run followed symlinked files: ``lib/x.obj -> ~/private/x.obj`` made the run read (and embed
    in a .pmw) a file outside what the user named.  Now such an asset is a failed row naming the link; a link that
    stays inside the folder is encoded, and a manifest that names the outside file encodes it."""
    outside = tmp_path / "private"
    outside.mkdir()
    write_mesh(outside / "secret.obj", shapes.icosphere(1))
    lib = tmp_path / "lib"
    (lib / "sub").mkdir(parents=True)
    write_mesh(lib / "a.obj", shapes.icosphere(1))
    (lib / "x.obj").symlink_to(outside / "secret.obj")
    (lib / "sub" / "alias.obj").symlink_to(lib / "a.obj")
    src = lib if named == "folder" else str(lib / "**" / "*.obj")
    assets = {a.relative: a for a in expand_sources(src, tmp_path / "out")}
    assert sorted(assets) == ["a.obj", "sub/alias.obj", "x.obj"]
    refused = encode_task(EncodeJob(assets["x.obj"].input, assets["x.obj"].output, timeout=60, root=assets["x.obj"].root))
    assert refused["status"] == "failed" and refused["input_sha256"] is None
    assert "symlink" in refused["error"] and str(outside / "secret.obj") in refused["error"]
    assert not (tmp_path / "out").exists()
    inside = assets["sub/alias.obj"]
    assert encode_task(EncodeJob(inside.input, inside.output, timeout=60, root=inside.root))["status"] == "ok"
    manifest = tmp_path / "list.txt"
    manifest.write_text(f"{lib / 'x.obj'}\n")
    (listed,) = expand_sources(manifest, tmp_path / "out2")
    assert listed.root is None
    assert encode_task(EncodeJob(listed.input, listed.output, timeout=60, root=listed.root))["status"] == "ok"


class _HeldEncoder:
    """A watermark that holds the encoder that unpickles it for ever (a ``select`` on nothing), before it has read
    anything: its task's timeout is certain to come first, however fast the machine (a small encode given 10 ms
    could finish in them)."""

    def __reduce__(self):
        import select

        return select.select, ([], [], [])


@pytest.mark.parametrize("ending", ["timeout", "failed"])
def test_a_rerun_that_fails_leaves_the_output_of_the_run_before_as_it_was(tmp_path, ending):
    """A re-run with other settings (``--keys-dir``, so the key it wants is not there yet) deleted each old output
    before encoding: when the encode then failed or timed out, the good output of the run before was lost and its
    key left alone beside nothing.  (``failed``: the input changed since into one that does not read.)"""
    if ending == "failed":
        (tmp_path / "a.obj").write_bytes(BROKEN["broken.obj"])
    else:
        write_mesh(tmp_path / "a.obj", shapes.icosphere(2))
    old = tmp_path / "out" / "a.obj.pmw"
    old.parent.mkdir()
    old.write_bytes(b"the output of the run before")
    watermark = _HeldEncoder() if ending == "timeout" else np.full((4, 4), 255, np.uint8)
    job = EncodeJob(str(tmp_path / "a.obj"), str(old), key=str(tmp_path / "keys" / "a.obj.pmw.key.json"),
                    key_path=str(tmp_path / "keys" / "a.obj.pmw.key.json"), watermark=watermark,
                    timeout=0.01 if ending == "timeout" else 120)
    row = encode_task(job)
    assert row["status"] == ending and old.read_bytes() == b"the output of the run before", row
    assert not list(old.parent.glob(".*.tmp"))


@pytest.mark.parametrize("refused", ["watermark", "key"])
def test_a_run_refused_before_any_work_leaves_no_output_folder(library, tmp_path, refused):
    """A missing watermark or a key that is not a key left an empty OUT_DIR behind."""
    root, src = library
    (tmp_path / "k.json").write_text("not a key")
    out = tmp_path / "out"
    kwargs = {"watermark": tmp_path / "nope.png"} if refused == "watermark" else {"key": tmp_path / "k.json"}
    with pytest.raises(pmwm_codec.PmwError):
        encode_batch(src, out, **kwargs)
    assert not out.exists()


def test_an_output_folder_that_cannot_be_made_is_a_failed_row_not_a_lost_task(tmp_path):
    """A file where an output's folder goes raised FileExistsError out of the task (the ledger said ``task
    lost``), though a task never raises for a bad asset."""
    write_mesh(tmp_path / "a.obj", shapes.icosphere(2))
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "sub").write_text("a file where a folder goes")
    row = encode_task(EncodeJob(str(tmp_path / "a.obj"), str(tmp_path / "out" / "sub" / "a.obj.pmw"), timeout=30))
    assert row["status"] == "failed" and "File exists" in row["error"] and str(tmp_path / "out" / "sub") in row["error"]


@pytest.mark.parametrize("timeout", [float("inf"), 1e308, 0, -1, float("nan"), "600"])
def test_a_timeout_the_operating_system_cannot_wait_is_refused_before_any_work(library, tmp_path, capsys, timeout):
    """``--timeout inf`` (or 1e308) passed the command's check: every asset then failed as ``task lost
    (OverflowError: cannot convert float infinity to integer)``, with tracebacks of the workers on stderr."""
    root, src = library
    with pytest.raises(pmwm_codec.PmwError, match="--timeout must be"):
        encode_batch(src, tmp_path / "out", timeout=timeout)
    assert not (tmp_path / "out").exists()
    if timeout == float("inf"):
        assert main(["batch", "encode", str(src), "-o", str(tmp_path / "out"), "--timeout", "inf"]) == 2
        err = capsys.readouterr().err
        assert err.startswith("pmw: error: --timeout must be") and len(err.splitlines()) == 1, err


def test_a_changed_texture_or_mtl_redoes_its_asset_and_nothing_else(tmp_path, client):
    from PIL import Image

    from test_obj_appearance import _torus_obj

    src = tmp_path / "src"
    src.mkdir()
    _torus_obj(str(src), "t.obj", mtl="t.mtl")
    (src / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\n")
    Image.new("RGB", (4, 4), (10, 20, 30)).save(src / "skin.png")
    write_mesh(src / "plain.obj", shapes.icosphere(2, noise=0.01, seed=1))
    out = tmp_path / "out"
    assert encode_batch(src, out, client=client)["ok"] == 2
    assert encode_batch(src, out, client=client)["skipped"] == 2
    Image.new("RGB", (4, 4), (30, 20, 10)).save(src / "skin.png")  # the OBJ's own bytes unchanged
    summary = encode_batch(src, out, client=client)
    assert (summary["ok"], summary["skipped"]) == (1, 1)
    glb = pmwm_codec.decode_asset(str(out / "t.obj.pmw"))
    assert glb.find(open(src / "skin.png", "rb").read()) > 0  # the new texture is in the output
    (src / "t.mtl").write_text("newmtl skin\nKd 1 0 0\nmap_Kd skin.png\n")
    assert encode_batch(src, out, client=client)["ok"] == 1
