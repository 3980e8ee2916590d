"""``pmw batch`` and signals: a SIGTERM stops the run as a Ctrl-C does (one line, exit 143); when the run is
killed outright its encoders end at once and quietly (they finished their asset, then printed a BrokenPipeError
traceback, and the resource tracker a "leaked semaphore" warning, after the command had ended); an encoder keeps
an ignored SIGINT ignored (a Ctrl-C aimed elsewhere killed the encoders of a background run)."""

from __future__ import annotations

import json
import os
import pickle
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, read_ledger  # noqa: E402
from pmwm_codec.batch import child as child_module  # noqa: E402
from pmwm_codec.batch import tasks  # noqa: E402

from test_batch_scheduler import _state, _stopped  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
ASSETS = 24


@pytest.fixture(scope="module")
def library(tmp_path_factory):
    from PIL import Image

    root = tmp_path_factory.mktemp("signals")
    (root / "src").mkdir()
    for i in range(ASSETS):
        write_mesh(root / "src" / f"t{i:02d}.obj", shapes.torus(48, 24, twist=0.01 * i))
    Image.fromarray((np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)).save(root / "wm.png")
    return root


def _start(library, out, sigint=signal.SIG_DFL, fault="batch-row-taken@3:STOP"):
    """The batch of ``library`` into ``out`` on two local workers, a session of its own.  ``fault``: its
    ``PMWM_FAULT``; by default it stops itself (SIGSTOP) as it takes its third result, two rows in its ledger:
    :func:`_held` waits for that moment, which the tests signal in (halfway by the order of events, never by a
    sleep, nor by a look at the ledger that a fast run outpaces)."""
    argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(library / "src"), "-o", str(out),
            "--watermark", str(library / "wm.png"), "--workers", "2", "-q"]
    return subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT=fault),
                            start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, sigint))


def _held(proc, out: Path, rows: int = 2) -> None:
    """Wait until the run ``proc`` has stopped itself at its fault point, ``rows`` rows in its ledger (killed, its
    whole session, when not: a run left stopped would hold its workers for ever)."""
    try:
        _stopped(proc)
        assert len(read_ledger(out / LEDGER_NAME)) == rows
    except BaseException:
        os.killpg(proc.pid, signal.SIGKILL)
        raise


def _left(session: int) -> list:
    ps = subprocess.run(["ps", "-o", "pid=,stat=,args=", "-s", str(session)], capture_output=True, text=True).stdout
    return [line for line in ps.splitlines() if not line.split()[1].startswith("Z")]


def _left_after(session: int, seconds: float = 10) -> list:
    """What :func:`_left` gives once the processes of ``session`` have ended, or after ``seconds``: a process has
    closed its pipes (so :func:`_finish` returned) a moment before it ends; that moment is waited for, not slept on."""
    deadline = time.monotonic() + seconds
    while (left := _left(session)) and time.monotonic() < deadline:
        time.sleep(0.02)
    return left


def _finish(proc, seconds=120):
    """Stdout and stderr to their end: until every process holding them (orphaned encoders too) has ended."""
    try:
        return proc.communicate(timeout=seconds)
    finally:
        if _left(proc.pid):
            os.killpg(proc.pid, signal.SIGKILL)


def _consistent(out: Path) -> None:
    assert (out / LEDGER_NAME).read_bytes().endswith(b"\n")
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
    for row in read_ledger(out / LEDGER_NAME):
        assert row["status"] == "ok" and os.path.getsize(row["output"]) == row["bytes"]


def test_sigterm_of_the_batch_stops_it_like_ctrl_c_in_one_line_with_exit_143_and_leaves_no_process(library,
                                                                                                   tmp_path):
    out = tmp_path / "out"
    proc = _start(library, out)
    _held(proc, out)  # as it takes its third result
    os.kill(proc.pid, signal.SIGTERM)  # the command alone, as timeout, systemd or docker stop send it
    proc.send_signal(signal.SIGCONT)
    _, err = _finish(proc)
    assert proc.returncode == 143 and err == "pmw: error: terminated\n", (proc.returncode, err)
    assert not _left_after(proc.pid)
    _consistent(out)
    assert len(read_ledger(out / LEDGER_NAME)) >= 3  # the held row recorded (the stop held back while it is), and
    # those an encoder published before the stop reached it


def test_kill_9_of_the_batch_ends_its_encoders_at_once_without_a_word(library, tmp_path):
    out = tmp_path / "out"
    proc = _start(library, out)
    _held(proc, out)  # as it takes its third result: the workers go on with the others
    os.kill(proc.pid, signal.SIGKILL)  # encoders are running: each must notice its worker is gone
    start = time.monotonic()
    _, err = _finish(proc)
    assert proc.returncode == -9
    assert err == "", err  # no BrokenPipeError traceback of an encoder, no resource-tracker warning
    assert time.monotonic() - start < 30
    assert not _left_after(proc.pid)
    _consistent(out)
    assert len(read_ledger(out / LEDGER_NAME)) == 2  # the held row died with the run; no row came after it


def test_encoders_of_a_run_started_with_sigint_ignored_keep_it_ignored(library, tmp_path):
    """A background job of a script starts with SIGINT ignored; a Ctrl-C of its process group killed in-flight
    encoders (``exit status -2`` rows) while the run went on.  The Ctrl-C comes as the run takes each result (it
    stops itself there, ``batch-row-taken:STOP``; the other worker's encoder runs meanwhile): one for every row."""
    out = tmp_path / "out"
    proc = _start(library, out, sigint=signal.SIG_IGN, fault="batch-row-taken:STOP")
    sent = 0
    deadline = time.monotonic() + 300
    while (state := _state(proc)) != "Z" and time.monotonic() < deadline:
        if state in "tT":
            os.killpg(proc.pid, signal.SIGINT)
            sent += 1
            proc.send_signal(signal.SIGCONT)
        time.sleep(0.01)
    _, err = _finish(proc)
    assert (proc.returncode, err) == (0, "")
    rows = read_ledger(out / LEDGER_NAME)
    assert len(rows) == ASSETS and {r["status"] for r in rows} == {"ok"}
    assert sent == ASSETS


def test_the_interpreter_form_of_the_encoder_prints_nothing_but_its_result(tmp_path):
    """``python -m pmwm_codec.batch.child`` printed runpy's RuntimeWarning on every start, and a dead encoder's
    error quoted that warning as its reason (external ``dask worker``s)."""
    write_mesh(tmp_path / "a.obj", shapes.icosphere(2, noise=0.01))
    payload = {"src": str(tmp_path / "a.obj"), "dst": str(tmp_path / "a.obj.pmw"), "watermark": None, "key": None,
               "options": {}}
    done = subprocess.run([sys.executable, "-c", tasks._CHILD_MAIN], input=pickle.dumps(payload),
                          capture_output=True, env=tasks._child_env(), timeout=120)
    assert done.returncode == 0 and done.stderr == b""
    assert json.loads(done.stdout)["status"] == "ok"
    assert tasks._died(-9) == "encoder process killed by SIGKILL"
    assert tasks._died(3, "MemoryError") == "encoder process died (exit status 3): MemoryError"


def _orphaned_encoder(tmp_path, parent_script: str, fault: str | None = None) -> None:
    """Run ``parent_script`` (it starts the interpreter form of the encoder on a 10k-vertex marked encode, hands
    it the job from its own standard input, prints the encoder's pid and ends; the encoder shares its standard
    output and error); wait until the encoder is gone.
    ``fault``: the encoder's ``PMWM_FAULT``."""
    write_mesh(tmp_path / "big.obj", shapes.icosphere(5, noise=0.01))
    payload = {"src": str(tmp_path / "big.obj"), "dst": str(tmp_path / "big.obj.pmw"),
               "watermark": np.full((8, 8), 255, np.uint8), "key": None, "options": {}}
    env = tasks._child_env()
    if fault is not None:
        env["PMWM_FAULT"] = fault
    with tempfile.TemporaryFile() as job:
        job.write(pickle.dumps(payload))
        job.seek(0)
        parent = subprocess.Popen([sys.executable, "-c", parent_script], stdin=job, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, env=env)
    child = int(parent.stdout.readline())
    assert parent.wait(timeout=120) == 0
    if fault is not None:
        # held by the fault point; it goes on with its parent gone once its watch's next look is due, so that the
        # look comes a GIL switch interval after it goes on, well before the rest of the encode has run
        time.sleep(2 * child_module.PARENT_POLL)
        os.kill(child, signal.SIGCONT)
    try:  # the pipes close when the encoder, which shares them, has ended too
        out, err = parent.communicate(timeout=20)
    except subprocess.TimeoutExpired:
        os.kill(child, signal.SIGKILL)
        pytest.fail("the encoder outlived its parent by 20 s")
    assert (out, err) == (b"", b""), err  # not a word: no result, no traceback


def test_an_encoder_whose_worker_is_gone_stops_and_removes_what_it_was_writing(tmp_path):
    """The interpreter form's parent ends mid-encode: the encoder stops within its grace time, silently, and
    leaves nothing.  The moment is made certain: the encoder stops itself (SIGSTOP) at the ``measured`` fault
    point, after the simplification and the watermark and before its files are written; its parent ends once it
    sees it stopped, and the test continues it.  (Its parent used to sleep a second instead: an encode faster
    than that published its pair, CI on 8c00ab1.)"""
    parent = ("import os, pickle, subprocess, sys\n"
              f"p = subprocess.Popen([sys.executable, '-c', {tasks._CHILD_MAIN!r}], stdin=subprocess.PIPE)\n"
              "job = pickle.loads(sys.stdin.buffer.read())\n"
              "p.stdin.write(pickle.dumps(dict(job, parent=os.getpid()))); p.stdin.close()\n"
              "_, status = os.waitpid(p.pid, os.WUNTRACED)\n"
              "assert os.WIFSTOPPED(status), status\n"
              "print(p.pid, flush=True)\n"
              "os._exit(0)\n")
    _orphaned_encoder(tmp_path, parent, fault="measured:STOP")
    assert sorted(os.listdir(tmp_path)) == ["big.obj"]


def test_an_encoder_whose_worker_ended_before_its_watch_began_stops_too(tmp_path):
    """The encoder's watch took its parent at the moment it began: a worker that had ended before (it hands the
    job over and can die at once) left an encoder that ran to the end and published an output no ledger names.
    The job now names the worker's pid."""
    parent = ("import os, pickle, subprocess, sys\n"
              f"p = subprocess.Popen([sys.executable, '-c', {tasks._CHILD_MAIN!r}], stdin=subprocess.PIPE)\n"
              "job = pickle.loads(sys.stdin.buffer.read())\n"
              "p.stdin.write(pickle.dumps(dict(job, parent=os.getpid()))); p.stdin.close()\n"
              "print(p.pid, flush=True)\n"
              "os._exit(0)\n")
    _orphaned_encoder(tmp_path, parent)
    assert sorted(os.listdir(tmp_path)) == ["big.obj"]


_STOP_WHILE_THE_WATCH_STARTS = """
import multiprocessing, threading, time
from pmwm_codec.batch import child

start = threading.Thread.start
def slow_start(self):  # the main thread still inside Thread.start when the watch's stop arrives
    start(self)
    time.sleep(2)
threading.Thread.start = slow_start
reader, writer = multiprocessing.Pipe(duplex=False)
writer.close()  # the worker is already gone
child.child_main({"restore_sigint": True}, None, reader)
"""


def test_an_encoder_whose_worker_is_gone_as_it_starts_ends_without_a_word():
    """A fresh-clone CI run of ``test_kill_9_of_the_batch_ends_its_encoders_at_once_without_a_word`` printed an
    encoder's ``Stopped`` traceback: its worker was killed as it started, and the stop (SIGTERM from the watch
    thread) came while the main thread was still in ``Thread.start``, before the ``try`` that ends quietly.  The
    same moment, made certain: exit by SIGTERM, nothing on stderr."""
    done = subprocess.run([sys.executable, "-c", _STOP_WHILE_THE_WATCH_STARTS], capture_output=True, text=True,
                          timeout=60, cwd=ROOT)
    assert (done.returncode, done.stderr) == (-signal.SIGTERM, "")


_ORPHANED_REQUEST = """
import multiprocessing, multiprocessing.forkserver as fs, os, socket, sys
multiprocessing.get_context("forkserver").set_forkserver_preload([sys.argv[1]])
fs.ensure_running()
with socket.socket(socket.AF_UNIX) as s:  # a worker that dies before it sends its request's descriptors
    s.connect(fs._forkserver._forkserver_address)
os.waitpid(fs._forkserver._forkserver_pid, 0)  # the forkserver reads the end of the request and ends
"""


@pytest.mark.parametrize("preload, quiet", [("pmwm_codec.batch.warm", True), ("json", False)])
def test_a_forkserver_whose_worker_dies_mid_request_ends_without_a_traceback(preload, quiet):
    """A run killed while a worker asks its forkserver for an encoder left multiprocessing's EOFError traceback on
    the terminal after the command had ended (the test above, once in a full run); the batch's forkserver imports
    ``pmwm_codec.batch.warm``, which ends it quietly.  Without it (``json`` preloaded) the traceback shows."""
    done = subprocess.run([sys.executable, "-c", _ORPHANED_REQUEST, preload], capture_output=True, text=True,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=300)
    assert done.returncode == 0, done.stderr
    assert (done.stderr == "") if quiet else ("EOFError" in done.stderr), done.stderr


_STOPPED_AS_IT_PUBLISHES = """
import json, multiprocessing, sys, types
import numpy as np
from pmwm_codec.batch import tasks

src, dst, form = sys.argv[1:]
if form == "interpreter":  # the encoder of a daemonic worker (``dask worker``): a fresh interpreter
    tasks.multiprocessing = types.SimpleNamespace(current_process=lambda: types.SimpleNamespace(daemon=True))
job = tasks.EncodeJob(input=src, output=dst, key_path=dst + ".key.json", timeout=300.0,
                      watermark=np.full((8, 8), 255, np.uint8))
print(json.dumps(tasks.encode_task(job)))
"""


@pytest.mark.parametrize("form", ["forked", "interpreter"])
def test_an_encoder_stopped_the_moment_it_published_still_gets_its_row(tmp_path, form):
    """A SIGTERM that reaches an encoder while it publishes is held back until the key and the ``.pmw`` are in
    place, and then stops it before it reports: a stopped ``--scheduler`` run left such an output without a ledger
    row (CI, once).  The moment, made certain by the ``published:TERM`` fault point: the task's row is ``ok`` and
    names the output as it is (bytes, digest, vertex count), beside its key."""
    from pmwm_codec.batch.ledger import sha256_file
    from pmwm_codec.format.inspect import inspect

    mesh = shapes.icosphere(3, noise=0.01)
    write_mesh(tmp_path / "a.obj", mesh)
    dst = tmp_path / "out" / "a.obj.pmw"
    done = subprocess.run([sys.executable, "-c", _STOPPED_AS_IT_PUBLISHES, str(tmp_path / "a.obj"), str(dst), form],
                          capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT="published:TERM"))
    assert done.returncode == 0, done.stderr
    row = json.loads(done.stdout.splitlines()[-1])
    assert (row["status"], row["error"]) == ("ok", None), row
    assert row["bytes"] == dst.stat().st_size and row["output_sha256"] == sha256_file(str(dst))
    assert row["vertices"] == inspect(str(dst))["vertices"] == mesh.vertex_count
    assert (dst.parent / "a.obj.pmw.key.json").is_file()
    assert sorted(os.listdir(dst.parent)) == ["a.obj.pmw", "a.obj.pmw.key.json"]


def test_a_sigterm_inside_a_native_callback_is_a_noted_stop_not_an_ignored_exception(tmp_path):
    """CI saw it once: the SIGTERM of a stopped run landed in llvmlite's ctypes callback, where Python cannot
    raise :class:`~pmwm_codec.batch.child.Stopped`, and printed "Exception ignored on calling ctypes callback
    function" with a traceback; the stop is noted (the encoder stops after its encode) and nothing is printed."""

    script = (
        "import ctypes, signal\n"
        "from pmwm_codec.batch import child\n"
        "child._signals(False)\n"
        "ctypes.CFUNCTYPE(None)(lambda: [signal.raise_signal(signal.SIGTERM)] + [i for i in range(9999)])()\n"
        "print(child._state.get('stopping'))\n")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, cwd=tmp_path,
                       env={**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])})
    assert (r.stdout, r.stderr) == ("True\n", "")


def test_a_sigterm_as_a_result_comes_in_still_records_the_row_of_the_output_it_names(library, tmp_path):
    """CI once: a ``--scheduler`` run stopped by SIGTERM the moment an encoder's result reached it lost that row (the
    stop landed after the run had taken the result and before its ledger had it), leaving a published ``.pmw`` the
    ledger does not name.  A result is now taken and recorded with the stop held back; the ``batch-row-taken:TERM``
    fault point puts the SIGTERM in that moment: the row is there, and every output the run leaves has one."""
    out = tmp_path / "out"
    argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(library / "src"), "-o", str(out),
            "--watermark", str(library / "wm.png"), "--workers", "1", "-q"]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT="batch-row-taken:TERM"))
    assert (done.returncode, done.stdout, done.stderr) == (143, "", "pmw: error: terminated\n")
    rows = read_ledger(out / LEDGER_NAME)
    assert 1 <= len(rows) < ASSETS and {row["status"] for row in rows} == {"ok"}
    assert sorted(row["output"] for row in rows) == sorted(str(p) for p in out.rglob("*.pmw"))
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
