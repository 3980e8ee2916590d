"""``pmw batch --scheduler ADDRESS``: a malformed address is bad usage (not "a bug of pmw"), a port that is not
Dask is refused within the connection timeout (it hung), and a run that cannot reach its scheduler leaves
nothing behind: no OUT_DIR, no new collection key."""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("distributed")

from pmwm_codec.batch import run  # noqa: E402
from pmwm_codec.cli import main  # noqa: E402

from conftest import refusing_port  # noqa: E402
from test_batch_refusals import lib  # noqa: E402,F401 (a fixture: tmp/lib/a.obj and tmp/wm.png)

ROOT = Path(__file__).resolve().parents[1]


def _one_line(capsys, *words) -> str:
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and err.startswith("pmw: error:") and "bug of pmw" not in err, err
    for word in words:
        assert word in err, err
    assert out == ""
    return err


@pytest.fixture
def silent_port():
    """A TCP port that takes connections and reads, but never answers (as an HTTP server waits for a line)."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen()
    held, stop = [], threading.Event()

    def serve():
        server.settimeout(0.2)
        while not stop.is_set():
            try:
                held.append(server.accept()[0])
            except OSError:
                continue

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    yield server.getsockname()[1]
    stop.set()
    thread.join()
    for conn in held:
        conn.close()
    server.close()


@pytest.mark.parametrize("address, words", [
    ("foo://x:1", ["unknown address scheme 'foo'"]),
    ("tcp://[::1", ["invalid address"]),
    ("tls://127.0.0.1:1", ["TLS"]),
    ("tcp://", ["missing port"]),
])
@pytest.mark.parametrize("command", ["encode", "verify"])
def test_a_malformed_scheduler_address_is_bad_usage_and_leaves_no_output_folder_nor_key(lib, capsys, address, words,
                                                                                     command):
    out = lib / "out"
    if command == "encode":
        argv = ["batch", "encode", str(lib / "lib"), "-o", str(out), "--watermark", str(lib / "wm.png"),
                "--key", str(out / "c.key.json"), "--scheduler", address]
    else:
        out.mkdir()
        (out / "x.pmw").write_bytes(b"")
        argv = ["batch", "verify", str(out), "--scheduler", address]
    assert main(argv) == 2
    _one_line(capsys, address, "not a usable Dask scheduler address", *words)
    assert not out.exists() if command == "encode" else sorted(os.listdir(out)) == ["x.pmw"]


def test_an_unreachable_scheduler_leaves_no_new_collection_key_and_no_output_folder(lib, capsys, monkeypatch):
    monkeypatch.setattr(run, "CONNECT_TIMEOUT", 1.0)
    out, key = lib / "out", lib / "c.key.json"
    with refusing_port() as port:
        address = f"tcp://127.0.0.1:{port}"
        assert main(["batch", "encode", str(lib / "lib"), "-o", str(out), "--watermark", str(lib / "wm.png"),
                     "--key", str(key), "--scheduler", address]) == 2
    _one_line(capsys, address, "cannot reach the Dask scheduler")
    assert not out.exists() and not key.exists()


def test_a_port_that_is_not_a_dask_scheduler_is_refused_in_one_line_within_the_timeout_not_a_hang(lib, silent_port):
    """A port that takes the connection (an HTTP server) left the run waiting for a Dask handshake forever."""
    address = f"tcp://127.0.0.1:{silent_port}"
    out = lib / "out"
    start = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", "batch", "encode", str(lib / "lib"), "-o", str(out),
                           "--watermark", str(lib / "wm.png"), "--scheduler", address],
                          env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True, timeout=90)
    seconds = time.monotonic() - start
    assert done.returncode == 2 and done.stdout == ""
    assert done.stderr == (f"pmw: error: {address}: connected, but no Dask scheduler answered within "
                           f"{run.CONNECT_TIMEOUT + run.HANDSHAKE_TIMEOUT:g} s (another service on that port?)\n")
    assert seconds < run.CONNECT_TIMEOUT + run.HANDSHAKE_TIMEOUT + 30
    assert not out.exists()


def test_check_scheduler_bounds_the_handshake_wait(silent_port, monkeypatch):
    monkeypatch.setattr(run, "HANDSHAKE_TIMEOUT", 1.0)
    start = time.monotonic()
    with pytest.raises(run.BatchError, match="no Dask scheduler answered within 2 s"):
        run.check_scheduler(f"tcp://127.0.0.1:{silent_port}", seconds=1.0)
    assert time.monotonic() - start < 10


@contextlib.contextmanager
def dask_cluster(workers: int = 1, env: dict | None = None):
    """A ``dask scheduler`` on a port of the loopback it binds itself and ``workers`` ``dask worker`` processes (one
    thread each), every one a session of its own: ``(address, procs)``, procs[0] the scheduler; all ended after.
    ``env``: more environment for the workers (and so their encoders)."""
    dask = shutil.which("dask", path=os.path.dirname(sys.executable)) or shutil.which("dask")
    if dask is None:
        pytest.skip("the dask command is not installed")
    with tempfile.TemporaryDirectory() as tmp:  # the scheduler names the port it took in a file there
        info = os.path.join(tmp, "scheduler.json")
        procs = [_session([dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                           "--scheduler-file", info])]
        try:
            address = _scheduler_address(procs[0], info)
            for _ in range(workers):
                procs.append(start_worker(address, env))
            wait_for_workers(address, workers)
            yield address, procs
        finally:
            for proc in reversed(procs):
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGTERM)
            for proc in reversed(procs):
                try:
                    proc.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    os.killpg(proc.pid, signal.SIGKILL)
                    proc.wait()


def _scheduler_address(scheduler, info: str, seconds: float = 120) -> str:
    """The address the ``dask scheduler`` process ``scheduler`` wrote to its ``--scheduler-file`` ``info`` (written
    once it listens; read whole: the file is written in place)."""
    deadline = time.monotonic() + seconds
    while scheduler.poll() is None and time.monotonic() < deadline:
        with contextlib.suppress(OSError, ValueError):
            with open(info) as f:
                return json.load(f)["address"]
        time.sleep(0.05)
    raise AssertionError(f"the dask scheduler wrote no address in {seconds:g} s (exit status {scheduler.poll()})")


def _session(argv, env: dict | None = None):
    return subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT), **(env or {})), stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)


def start_worker(address: str, env: dict | None = None):
    """A ``dask worker`` of one thread for the scheduler at ``address`` (a session of its own; ``env``: more
    environment for it)."""
    dask = shutil.which("dask", path=os.path.dirname(sys.executable)) or shutil.which("dask")
    return _session([dask, "worker", address, "--host", "127.0.0.1", "--nthreads", "1", "--no-dashboard"], env)


def wait_for_workers(address: str, count: int, timeout: float = 120) -> None:
    from distributed import Client

    with Client(address, timeout="60s") as client:
        client.wait_for_workers(count, timeout=timeout)


def _finish(run_, seconds: float = 90):
    """``(stdout, stderr)`` of the run ``run_`` once it has ended (killed after ``seconds``)."""
    try:
        return run_.communicate(timeout=seconds)
    finally:
        if run_.poll() is None:
            run_.kill()
            run_.communicate()


def _state(proc) -> str:
    """The state letter of ``proc`` in ``/proc`` (``T``: stopped, ``Z``: ended, not yet reaped)."""
    with open(f"/proc/{proc.pid}/stat") as f:
        return f.read().rpartition(")")[2].split()[0]


def _stopped(proc, seconds: float = 240) -> None:
    """Wait (up to ``seconds``) until ``proc`` is stopped (a SIGSTOP of its fault point), read off ``/proc`` (not
    ``waitpid``: the process is not reaped)."""
    deadline = time.monotonic() + seconds
    while (state := _state(proc)) not in "tT":
        assert state != "Z", f"the run ended before its fault point (exit status {proc.poll()})"
        assert time.monotonic() < deadline, f"the run did not reach its fault point in {seconds:g} s"
        time.sleep(0.05)


def _continued(proc, seconds: float = 90):
    """``(stdout, stderr)`` of ``proc`` once it has ended, continued (SIGCONT) each time its fault point stops it
    (each result it takes); killed after ``seconds``."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and _state(proc) != "Z":
        if _state(proc) in "tT":
            proc.send_signal(signal.SIGCONT)
        time.sleep(0.05)
    return _finish(proc, max(1.0, deadline - time.monotonic()))


def _results_on_workers(address: str, count: int, seconds: float = 240) -> None:
    """Wait (up to ``seconds``) until the scheduler at ``address`` has ``count`` results in memory (kept on the
    workers until their client has them)."""
    from distributed import Client

    def held(dask_scheduler):  # run on the scheduler
        return sum(task.state == "memory" for task in dask_scheduler.tasks.values())

    deadline = time.monotonic() + seconds
    with Client(address, timeout="60s") as client:
        while client.run_on_scheduler(held) < count:
            assert time.monotonic() < deadline, f"fewer than {count} results in {seconds:g} s"
            time.sleep(0.05)


def test_a_run_whose_every_worker_dies_stops_in_one_line_after_the_no_worker_timeout_and_a_rerun_resumes(tmp_path):
    """Every worker of a --scheduler cluster killed mid-run: the run waited forever (Dask keeps the tasks for a
    worker that never comes).  It stops once the cluster has had no worker for --no-worker-timeout seconds: one
    line, exit 2, the ledger whole (a row per asset done), and the next run, on a new worker, does the rest.

    The run is held (SIGSTOP, its ``batch-row-taken`` fault point) as it takes its first result, and the worker
    killed once it holds another result the run has not taken: mid-run by the order of events, not by a guess that
    the worker cannot finish the rest first.  A result that died with its worker is the run's to wait for again,
    not a wait for ever: asking for it (``Future.result``) waited for a worker to compute it again, and the
    no-worker timeout was never looked at (the run hung; 1 run in 30 of the earlier form on a loaded machine)."""
    from PIL import Image

    from pmwm_codec import shapes
    from pmwm_codec.batch import LEDGER_NAME, read_ledger
    from pmwm_codec.meshio import write_mesh

    assets = 6
    (tmp_path / "lib").mkdir()
    for i in range(assets):
        write_mesh(tmp_path / "lib" / f"m{i}.obj", shapes.icosphere(2, noise=0.01, seed=i))
    Image.fromarray(np.full((8, 8), 255, np.uint8)).save(tmp_path / "wm.png")
    out = tmp_path / "out"
    with dask_cluster() as (address, procs):
        argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(tmp_path / "lib"), "-o", str(out),
                "--watermark", str(tmp_path / "wm.png"), "--scheduler", address, "--json"]
        run_ = subprocess.Popen([*argv, "--no-worker-timeout", "3"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT="batch-row-taken:STOP"),
                                text=True)
        try:
            _stopped(run_)  # the run holds its first result, not yet in its ledger
            _results_on_workers(address, 2)  # and the worker another one, done while the run was held
            os.killpg(procs[1].pid, signal.SIGKILL)  # the one worker (and its encoder) gone mid-run
            killed = time.monotonic()
        finally:
            stdout, stderr = _continued(run_)
        waited = time.monotonic() - killed
        done = read_ledger(out / LEDGER_NAME)
        assert (run_.returncode, stdout) == (2, ""), stderr
        assert stderr.count("\n") == 1 and stderr.startswith(
            "pmw: error: the Dask cluster has had no worker for 3 s (all gone?); the run stopped with "), stderr
        assert f" of {assets} assets not done (a re-run does them)" in stderr and "Traceback" not in stderr
        assert 3 <= waited  # the run was held while the worker was killed: its no-worker time begins after
        assert 1 <= len(done) < assets
        assert (out / LEDGER_NAME).read_bytes().endswith(b"\n")
        assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]
        for row in done:
            assert row["status"] == "ok" and os.path.getsize(row["output"]) == row["bytes"]
        procs.append(start_worker(address))
        wait_for_workers(address, 1)
        again = subprocess.run(argv, env=dict(os.environ, PYTHONPATH=str(ROOT)), capture_output=True, text=True,
                               timeout=300)
    assert again.returncode == 0, again.stderr
    summary = json.loads(again.stdout)
    assert (summary["skipped"], summary["ok"]) == (len(done), assets - len(done))


class _Clock:
    """A ``time`` for :mod:`pmwm_codec.batch.run` whose ``monotonic()`` moves only when the test moves it."""

    def __init__(self):
        self.now = 1000.0

    def monotonic(self) -> float:
        return self.now


class _Cluster:
    """A client whose scheduler answers each look (``nthreads``) with ``workers()`` workers, the answer taking
    ``delay`` seconds of ``clock``."""

    def __init__(self, clock, workers, delay: float = 0.0):
        self.clock, self.workers, self.delay, self.looks = clock, workers, delay, 0

    def nthreads(self) -> dict:
        self.clock.now += self.delay
        self.looks += 1
        return {f"tcp://w{i}": 1 for i in range(self.workers())}


def test_the_worker_watch_never_judges_a_worker_gone_without_a_look_that_saw_none_for_the_whole_timeout(
        monkeypatch):
    """A --no-worker-timeout shorter than the watch's interval (1 s) stopped the run on the clock alone: one look saw
    no worker (one restarting), a worker came, and the next call, within the interval, said "gone" with no look.
    A timeout that ends between two looks is decided at the next look."""
    clock = _Clock()
    monkeypatch.setattr(run, "time", clock)
    present = {"workers": 0}
    cluster = _Cluster(clock, lambda: present["workers"])
    watch = run._WorkerWatch(cluster, 0.5)
    assert not watch.gone()  # the first look: none yet
    clock.now += 0.3
    present["workers"] = 1  # a worker comes
    clock.now += 0.3
    assert not watch.gone() and cluster.looks == 1  # 0.6 s after a look that saw none, and no look since
    clock.now += run.WORKER_CHECK_INTERVAL
    assert not watch.gone() and cluster.looks == 2  # the next look sees the worker
    present["workers"] = 0  # gone again: gone once two looks that saw none are the timeout apart
    clock.now += run.WORKER_CHECK_INTERVAL
    assert not watch.gone()
    clock.now += run.WORKER_CHECK_INTERVAL
    assert watch.gone() and cluster.looks == 4


def test_the_worker_watch_does_not_count_a_slow_answer_as_time_without_a_worker(monkeypatch):
    """A look whose answer (no worker) took the whole --no-worker-timeout counted the wait as time without one: the
    run stopped after one look, which may have begun while workers were there."""
    clock = _Clock()
    monkeypatch.setattr(run, "time", clock)
    cluster = _Cluster(clock, lambda: 0, delay=3.0)
    watch = run._WorkerWatch(cluster, 3.0)
    assert not watch.gone() and cluster.looks == 1
    clock.now += run.WORKER_CHECK_INTERVAL
    assert not watch.gone() and cluster.looks == 2  # asked 1 s after the first answer
    clock.now += 2.0
    assert watch.gone() and cluster.looks == 3  # asked 3 s or more after it: gone


class _LostResult:
    """A future the scheduler still calls finished whose result cannot be had (its worker died holding it): each ask
    waits :data:`~pmwm_codec.batch.run.RESULT_WAIT` seconds of ``clock`` and times out."""

    status = "finished"

    def __init__(self, clock):
        self.clock = clock

    def result(self, timeout=None):
        from distributed import TimeoutError as DaskTimeoutError

        self.clock.now += timeout
        raise DaskTimeoutError("no result")


class _Again:
    """``as_completed`` over one future that comes straight back each time it is handed back (at most ``most``
    times: a run that never looks at its workers would go round for ever)."""

    def __init__(self, futures, most: int = 100):
        self.futures, self.most = list(futures), most

    def is_empty(self) -> bool:
        return False

    def next_batch(self, block=False) -> list:
        self.most -= 1
        assert self.most >= 0, "the run went round and round without looking at its workers"
        return list(self.futures)

    def add(self, future) -> None:
        pass


def test_a_result_that_keeps_coming_back_unobtainable_does_not_keep_the_run_from_its_no_worker_timeout(monkeypatch):
    """The run looked at its workers only when no future came: a result lost with its worker that the scheduler
    still called finished came straight back after each wait for it, and the run went round for ever, its
    no-worker timeout never looked at.  It stops now, in one line, once the cluster has had no worker that long."""
    import distributed

    clock = _Clock()
    monkeypatch.setattr(run, "time", clock)
    monkeypatch.setattr(distributed, "as_completed", _Again)
    cluster = _Cluster(clock, lambda: 0)
    cluster.cancel = lambda futures: None
    submitted = object.__new__(run._Submitted)
    submitted.client, submitted.jobs, submitted.event = cluster, ["a.obj"], None
    submitted.futures = {_LostResult(clock): "a.obj"}
    with pytest.raises(run.BatchError, match=r"no worker for 12 s .* 1 of 1 assets not done"):
        submitted.run(lambda row: pytest.fail("no result was had"), no_worker_timeout=12)


def _encoders(procs) -> list:
    """The encoder processes (``pmwm_codec.batch.child``) still alive in the sessions of ``procs`` (``ps -ww``: without
    it ps cuts each line at 80 columns, before the module's name under a long interpreter path)."""
    found = []
    for proc in procs:
        ps = subprocess.run(["ps", "-ww", "-o", "pid=,stat=,args=", "-s", str(proc.pid)], capture_output=True,
                            text=True).stdout
        found += [line for line in ps.splitlines() if "batch.child" in line and not line.split()[1].startswith("Z")]
    return found


def test_a_stopped_scheduler_run_leaves_no_output_its_ledger_does_not_name(tmp_path):
    """A --scheduler run stopped by SIGTERM while encoders ran on the workers: Dask's cancel cannot reach a running
    task, so those encoders went on and published their ``.pmw`` seconds after the command had ended, with no
    ledger row.  The run's stop now reaches them (a Dask Event their tasks poll): each stops and removes what it
    was writing, or, when it had already published, the run records its row before it exits."""
    from PIL import Image

    from pmwm_codec import shapes
    from pmwm_codec.batch import LEDGER_NAME, read_ledger
    from pmwm_codec.meshio import write_mesh

    assets = 8
    (tmp_path / "lib").mkdir()
    for i in range(assets):
        write_mesh(tmp_path / "lib" / f"m{i}.obj", shapes.torus(96, 48, twist=0.01 * i))
    Image.fromarray((np.indices((16, 16)).sum(0) % 2 * 255).astype(np.uint8)).save(tmp_path / "wm.png")
    out = tmp_path / "out"
    with dask_cluster(workers=2) as (address, procs):
        argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(tmp_path / "lib"), "-o", str(out),
                "--watermark", str(tmp_path / "wm.png"), "--scheduler", address, "-q"]
        run_ = subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT), PMWM_FAULT="batch-row-taken@1:STOP"),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            _stopped(run_)  # held as it takes its first result: the workers go on with the next tasks
            deadline = time.monotonic() + 60  # until they have started an encoder (the run cannot end meanwhile)
            while not _encoders(procs[1:]) and time.monotonic() < deadline:
                time.sleep(0.05)
            assert _encoders(procs[1:]), "no encoder was running when the run was stopped"
            run_.send_signal(signal.SIGTERM)
        finally:
            run_.send_signal(signal.SIGCONT)
            _, stderr = _finish(run_)
        assert (run_.returncode, stderr) == (143, "pmw: error: terminated\n")
        deadline = time.monotonic() + 120  # until every encoder the run started has ended, one way or the other
        while _encoders(procs[1:]) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert not _encoders(procs[1:])
        rows = read_ledger(out / LEDGER_NAME)
        assert 1 <= len(rows) < assets  # the held row recorded (the stop held back while it is)
        assert {row["status"] for row in rows} == {"ok"}
        assert sorted(row["output"] for row in rows) == sorted(str(p) for p in out.rglob("*.pmw"))
        for row in rows:
            assert os.path.getsize(row["output"]) == row["bytes"]
        assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]


def test_a_stop_reaches_the_encoders_running_on_the_workers_and_none_of_them_publishes(tmp_path):
    """Dask cannot cancel a running task: the run's stop reaches its encoders through a Dask Event their tasks poll.
    Without it they published their outputs after the command had ended, with no ledger row (the stopped run above
    does not show it when they finish within the run's STOP_WAIT, whose rows it records).  The moment is made
    certain: every encoder stops itself (``measured:STOP``, its mesh measured, nothing written) and the run is
    stopped (SIGTERM) while they are held; those still there once the run has ended, its stop set long before, are
    continued: they end without publishing (without the Event they were still held, and published)."""
    from PIL import Image

    from pmwm_codec import shapes
    from pmwm_codec.batch import LEDGER_NAME, read_ledger
    from pmwm_codec.meshio import write_mesh

    assets, workers = 4, 2
    (tmp_path / "lib").mkdir()
    for i in range(assets):
        write_mesh(tmp_path / "lib" / f"m{i}.obj", shapes.icosphere(2, noise=0.01, seed=i))
    Image.fromarray(np.full((8, 8), 255, np.uint8)).save(tmp_path / "wm.png")
    out = tmp_path / "out"
    with dask_cluster(workers, env={"PMWM_FAULT": "measured:STOP"}) as (address, procs):
        argv = [sys.executable, "-m", "pmwm_codec", "batch", "encode", str(tmp_path / "lib"), "-o", str(out),
                "--watermark", str(tmp_path / "wm.png"), "--scheduler", address, "-q"]
        run_ = subprocess.Popen(argv, env=dict(os.environ, PYTHONPATH=str(ROOT)), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        held = []
        try:
            deadline = time.monotonic() + 240
            while len(held := [e for e in _encoders(procs[1:]) if e.split()[1].startswith("T")]) < workers:
                assert run_.poll() is None and time.monotonic() < deadline, "the encoders did not reach their point"
                time.sleep(0.05)
            run_.send_signal(signal.SIGTERM)
            _, stderr = _finish(run_)
        finally:
            for line in held:  # (those the stop has not killed already: a held encoder cannot end on SIGTERM)
                with contextlib.suppress(ProcessLookupError):
                    os.kill(int(line.split()[0]), signal.SIGCONT)
        assert (run_.returncode, stderr) == (143, "pmw: error: terminated\n")
        deadline = time.monotonic() + 120
        while _encoders(procs[1:]) and time.monotonic() < deadline:
            time.sleep(0.1)
        assert not _encoders(procs[1:])
        assert read_ledger(out / LEDGER_NAME) == []
        assert not list(out.rglob("*.pmw")) and not list(out.rglob("*.key.json"))
        assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")]


def _at_once_or_slow(job):
    if job:
        time.sleep(1.0)
    return job


def test_a_stop_keeps_the_result_of_a_task_that_had_just_finished_unread():
    """The stop cancels the tasks no worker has started; it took that set as "all but those processing", so a task
    that had just finished, its result not yet read by the run, was cancelled with them: its row lost, its output
    left without one (the stopped-run test above, 1 run in 6).  Now the scheduler says which tasks are not started."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        submitted = run._Submitted(client, _at_once_or_slow, list(range(8)))
        first = next(f for f, job in submitted.futures.items() if job == 0)
        deadline = time.monotonic() + 30
        def state(dask_scheduler, key):
            return getattr(dask_scheduler.tasks.get(key), "state", None)
        while time.monotonic() < deadline and client.run_on_scheduler(state, key=first.key) != "memory":
            time.sleep(0.01)
        results = []
        submitted.stop(results.append, seconds=10)
    assert 0 in results
    assert len(results) < 8  # the tasks not started were cancelled
