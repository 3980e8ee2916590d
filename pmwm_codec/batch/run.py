"""The client side of ``pmw batch``: expand SRC, submit one Dask task per asset, keep the ledger.

Dask (``dask.distributed``) is the engine: a ``LocalCluster`` of ``workers`` processes by
default, or an existing cluster at ``scheduler`` (``tcp://host:8786``) whose workers have
this package installed and see the same paths (shared filesystem).  The client is the
ledger's only writer: it appends each row as its task finishes, so a killed run loses at
most the rows of the assets then running, and those are redone by the next run.

A collection key is created (or loaded) here, once, saved once the cluster is reached and before any task starts, and
passed to every task as an object: no task writes it, and every output verifies with it.
"""

from __future__ import annotations

import contextlib
import logging
import numbers
import os
import time
import uuid

import numpy as np

from pmwm_codec.atomic import fault_point, signals_deferred
from pmwm_codec.errors import PmwError
from pmwm_codec.watermark.key import same_path

from .ledger import LEDGER_NAME, LedgerWriter, last_rows, read_ledger, settings_sha256
from .sources import KEY_SUFFIX, PMW_SUFFIX, expand_sources
from .tasks import EncodeJob, encode_task, verify_task

__all__ = ["BatchError", "dask_client", "encode_batch", "verify_batch", "collection_key", "check_key_places",
           "DEFAULT_TIMEOUT", "NO_WORKER_TIMEOUT"]

DEFAULT_TIMEOUT = 600.0  # seconds per asset
#: The longest per-asset timeout: a wait the operating system takes (epoll counts int milliseconds: ~24 days);
#: an infinite one made every asset a lost task (OverflowError).
MAX_TIMEOUT = 1e6
#: Seconds a run goes on while its cluster has no worker before it stops (``--no-worker-timeout``): Dask keeps
#: the tasks of a cluster whose every worker died waiting for a new one, and the run waited forever.  Long
#: enough for a worker to be restarted, or an adaptive cluster to start one; a long encode is not cut by it.
NO_WORKER_TIMEOUT = 120.0
#: Seconds between two looks at the cluster's worker count while no result comes.
WORKER_CHECK_INTERVAL = 1.0
#: Seconds between two looks for finished tasks (as :func:`distributed.as_completed` waits).
_POLL = 0.1
#: Seconds the run waits for a finished task's result to reach it; one that does not (its worker died holding it)
#: is waited for again, as the task is computed again on another worker, under the no-worker timeout.
RESULT_WAIT = 5.0
#: Seconds an interrupted run waits for its running encoders to stop (they poll the stop every
#: :data:`~.tasks.STOP_POLL` s and then have :data:`~.child.GRACE` s to end), recording those that published.
STOP_WAIT = 10.0


class BatchError(PmwError, ValueError):
    """A batch that cannot start (bad SRC, key, watermark or scheduler): one line, exit 2."""


#: Our local workers: they may fork the per-asset encoders (not daemonic), and they do not sample
#: their own stacks (Dask's statistical profiler and GIL monitor) while the encoders need the cores.
LOCAL_WORKER_CONFIG = {
    "distributed.worker.daemon": False,
    "distributed.worker.profile.enabled": False,
    "distributed.admin.system-monitor.gil.enabled": False,
}


#: Local worker processes a run may start per CPU: each imports the library (~150 MB) and runs encoders
#: that need a core each; more only queue for the cores and the memory.
MAX_WORKERS_PER_CPU = 4


def local_workers(workers: int | None, tasks: int | None = None) -> int:
    """How many local worker processes to start for ``tasks`` tasks: ``workers`` (default one per CPU),
    no more than there are tasks; BatchError when ``workers`` exceeds :data:`MAX_WORKERS_PER_CPU` per CPU."""
    cpus = os.cpu_count() or 1
    if workers is not None and workers > MAX_WORKERS_PER_CPU * cpus:
        raise BatchError(f"--workers {workers}: more than {MAX_WORKERS_PER_CPU} local processes per CPU "
                         f"({MAX_WORKERS_PER_CPU * cpus} on this machine's {cpus}); use --scheduler for a bigger cluster")
    count = int(workers or cpus)
    return max(1, min(count, tasks) if tasks is not None else count)


@contextlib.contextmanager
def dask_client(workers: int | None = None, scheduler: str | None = None, client=None, tasks: int | None = None):
    """``client`` if given, else a ``distributed.Client`` on ``scheduler`` or on a LocalCluster
    of :func:`local_workers` processes (default one per CPU, no more than ``tasks``)."""
    import dask
    from distributed import Client, LocalCluster

    if client is not None:
        yield client
        return
    if scheduler:
        check_scheduler(scheduler)
        try:
            client = Client(scheduler, timeout=f"{CONNECT_TIMEOUT:g}s")
        except Exception as exc:  # noqa: BLE001 - reached a moment ago: whatever fails now, it is the connection
            raise BatchError(f"{scheduler}: cannot reach the Dask scheduler ({_one_line(exc)})") from None
        with client:
            yield client
        return
    workers = local_workers(workers, tasks)
    _quiet_resource_tracker()
    with dask.config.set(LOCAL_WORKER_CONFIG), _sigint_ignored():
        # logs at CRITICAL: a worker logs an ERROR with a traceback when the scheduler closes under its heartbeat,
        # as it does at the end of every run (a run's own failures are its rows); the scheduler's HTTP server
        # (no dashboard) on a free port of the loopback: on 8787, taken, it warned on stderr
        cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None,
                               silence_logs=logging.CRITICAL, scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    with cluster, Client(cluster) as client:
        yield client


#: Seconds to reach a ``--scheduler`` (its port), and then for its first answer (the Dask handshake).
CONNECT_TIMEOUT = 15.0
HANDSHAKE_TIMEOUT = 5.0


def check_scheduler(address: str, seconds: float | None = None) -> None:
    """BatchError (one line) unless a Dask scheduler answers at ``address``: its port within ``seconds``
    (default :data:`CONNECT_TIMEOUT`), then its handshake within :data:`HANDSHAKE_TIMEOUT` more.

    A malformed address (an unknown scheme, ``tcp://[::1``, ``tls://`` without a TLS configuration)
    is refused as such; a port that takes the connection but is not Dask (an HTTP server) is refused
    when no Dask handshake comes (``distributed.Client``'s own timeout does not cover that wait).
    Runs in a thread of its own, so that a caller with an event loop running can call it too.
    """
    import asyncio
    import threading

    from distributed.comm import connect
    from distributed.security import Security

    seconds = CONNECT_TIMEOUT if seconds is None else seconds
    bound = seconds + HANDSHAKE_TIMEOUT

    async def probe():
        args = Security().get_connection_args("client")
        comm = await asyncio.wait_for(connect(address, timeout=seconds, **args), bound)
        await comm.close()

    failure = []

    def run():
        try:
            asyncio.run(probe())
        except BaseException as exc:  # noqa: BLE001 - reported below, in the caller's thread
            failure.append(exc)

    thread = threading.Thread(target=run, name="pmw-scheduler-check", daemon=True)
    thread.start()
    thread.join(bound + 5)
    if thread.is_alive():
        raise BatchError(f"{address}: no Dask scheduler answered within {bound:g} s")
    if not failure:
        return
    exc = failure[0]
    if isinstance(exc, (ValueError, TypeError)):  # distributed's words for an address it cannot use
        raise BatchError(f"{address}: not a usable Dask scheduler address ({_one_line(exc)})") from None
    if isinstance(exc, asyncio.TimeoutError) and "Timed out trying to connect" not in str(exc):
        raise BatchError(f"{address}: connected, but no Dask scheduler answered within {bound:g} s "
                         "(another service on that port?)") from None
    raise BatchError(f"{address}: cannot reach the Dask scheduler ({_one_line(exc)})") from None


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _quiet_resource_tracker() -> None:
    """Start multiprocessing's resource tracker (if it is not running yet) with its stderr on the null device.

    The local cluster's worker processes are started through queues whose semaphores the tracker of this
    process records; when this process is killed outright (``kill -9``), the tracker removes them and
    warns about each "leaked semaphore" on the terminal, after the command has ended.  Its removal is the
    cleanup wanted; its warning is noise.  (fd 2 is pointed elsewhere only while the tracker starts.)"""
    from multiprocessing import resource_tracker

    tracker = getattr(resource_tracker, "_resource_tracker", None)
    if tracker is None or getattr(tracker, "_fd", 0) is not None:
        return  # running already (or an implementation we do not know): left as it is
    import sys

    with contextlib.suppress(Exception):
        sys.stderr.flush()
    try:
        saved = os.dup(2)
    except OSError:  # no standard error to keep quiet
        return
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 2)
            resource_tracker.ensure_running()
        finally:
            os.dup2(saved, 2)
            os.close(devnull)
    finally:
        os.close(saved)


def _restore_sigint(scheduler) -> bool:
    """Whether the encoders take SIGINT back (:class:`~.tasks.EncodeJob`): on our own workers, which ignore it
    for the run's sake (:func:`_sigint_ignored`), unless this process had it ignored itself (a background job
    of a script, ``nohup``: a Ctrl-C aimed elsewhere must not kill the run's encoders either); never on the
    workers of a ``--scheduler``, whose SIGINT is theirs."""
    import signal

    return not scheduler and signal.getsignal(signal.SIGINT) is not signal.SIG_IGN


@contextlib.contextmanager
def _sigint_ignored():
    """SIGINT ignored while the local workers start, so that they inherit that: a Ctrl-C (sent to the whole
    process group) stops the run here, once (``pmw: error: interrupted``, the cluster closed), instead of
    raising KeyboardInterrupt in every worker, each printing its traceback.  The encoders take SIGINT back
    (:mod:`.child`): they die with the run.  Only the main thread may set a handler; elsewhere nothing changes."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def collection_key(key_path, watermark, owner_id=None):
    """``(image, key)`` for a collection: load ``key_path`` or create it (with ``watermark``) and save it.

    image: (s, s) uint8, the watermark every asset carries (the key's reference when no
    ``watermark`` is given; None for an existing key of no image that names an owner ID: the owner
    layer alone).  An existing key whose reference differs from ``watermark``, or whose owner ID is not
    ``owner_id`` (an int; None: the key's own, random for a new key), is refused: every asset must verify
    with the one key.  A new key needs a ``watermark`` or an ``owner_id`` (then it marks the owner layer alone).
    """
    image, key, new, _ = _collection_key(key_path, watermark, owner_id)
    if new:
        key.save(key_path)
    return image, key


def _owner_given(options) -> int | None:
    """The owner ID the run's encode ``options`` set (``--owner-id``), or None (none set, or False: no layer)."""
    owner = (options or {}).get("owner_id")
    return None if owner is None or isinstance(owner, bool) else int(owner)


def _collection_key(key_path, watermark, owner_id=None):
    """``(image, key, new, given)``: :func:`collection_key` without saving a new key (``new``: True for one made
    here; ``given``: the watermark's (width, height) as given, None without one)."""
    from pmwm_codec.watermark.image import load_watermark_given
    from pmwm_codec.watermark.key import WatermarkKey

    image, _, given = (None, None, None) if watermark is None else load_watermark_given(watermark)
    if os.path.exists(key_path):
        key = WatermarkKey.load(key_path)
        if image is None:
            if key.reference is None and key.owner_id is None:
                raise BatchError(f"{key_path}: the key holds no watermark image and names no owner id; give "
                                 "--watermark")
            image = key.reference  # None: the key's owner ID alone marks every asset (the owner layer)
        elif key.reference is None:  # as pmw encode refuses it: the files would not verify with the key alone
            raise BatchError(f"{key_path}: the key holds no watermark image (the owner layer alone), so it cannot "
                             f"mark with {watermark}; name a new --key, or leave --watermark out")
        elif not np.array_equal(key.reference, image):
            raise BatchError(f"{key_path}: the key was made for another watermark image than {watermark}")
        if owner_id is not None and key.owner_id != owner_id:
            raise BatchError(f"{key_path}: the key names " + ("no owner id" if key.owner_id is None else
                             f"owner id {key.owner_hex}") + f", not {owner_id:016x} (name a new --key)")
        return image, key, False, given
    if image is None and owner_id is None:
        raise BatchError(f"{key_path}: no such key; give --watermark or --owner-id to create a collection key")
    return image, WatermarkKey.generate(reference=image, owner_id=owner_id), True, given


def check_key_places(assets, out_dir, key=None, keys_dir=None) -> None:
    """BatchError (one line; called before anything is written) when the collection ``key`` or the
    ``keys_dir`` is where this run reads or writes something else: an input of ``assets`` (links
    resolved), an output or a place inside one (an output is a file), the ledger; or when ``keys_dir``
    is, or lies below, an existing file that is not a folder (it could never be made)."""
    if key is None and keys_dir is None:
        return
    ledger = os.path.join(out_dir, LEDGER_NAME)
    written = {os.path.realpath(a.output): f"the output {a.output} (of {a.input})" for a in assets}
    written[os.path.realpath(ledger)] = f"the run's ledger {ledger}"

    def clash(path: str, what: str) -> str | None:
        source = next((a.input for a in assets if same_path(a.input, path)), None)  # links of both kinds
        if source is not None:
            return f"{path}: is also the input {source}; give the {what} another name (an input is never replaced)"
        real = os.path.realpath(path)
        if real in written:
            return f"{path}: is {written[real]}; give the {what} another name"
        here = real
        while os.path.dirname(here) != here:
            here = os.path.dirname(here)
            if here in written:
                return f"{path}: lies inside {written[here]}, a file, not a folder; give the {what} another name"
        return None

    if key is not None:
        key = os.fspath(key)
        why = clash(key, "collection key")
        if why:
            raise BatchError(why)
    if keys_dir is not None:
        keys_dir = os.fspath(keys_dir)
        existing = os.path.abspath(keys_dir)
        while not os.path.lexists(existing):
            existing = os.path.dirname(existing)
        if not os.path.isdir(existing):
            if existing == os.path.abspath(keys_dir):
                raise BatchError(f"{keys_dir}: exists and is not a folder; --keys-dir names the folder "
                                 "each asset's key goes in")
            raise BatchError(f"{keys_dir}: cannot be made: {existing} is not a folder")
        why = clash(keys_dir, "keys folder")
        if why:
            raise BatchError(why)


def _jobs(assets, out_dir, image, key, keys_dir, timeout, force, options=None, restore_sigint=True,
          given=None) -> list[EncodeJob]:
    """One EncodeJob per asset, with the ledger's verdict on what was done before (with the same settings);
    ``given``: the watermark's (width, height) as the user gave it (:attr:`EncodeJob.watermark_given`)."""
    rows = read_ledger(os.path.join(out_dir, LEDGER_NAME))
    previous = last_rows(rows)
    written = last_rows(r for r in rows if r["status"] == "ok")  # what each output was when it was written
    mode = "collection" if key is not None else "keys-dir" if keys_dir is not None else "beside"
    hashed = dict(options or {})
    if key is not None and _owner_given(hashed) is not None and _owner_given(hashed) == key.owner_id:
        del hashed["owner_id"]  # the collection key names that ID itself: --owner-id repeating it changes nothing
    settings = settings_sha256(image, mode, None if key is None else key.fingerprint(), hashed)
    jobs = []
    marked = image is not None or _owner_given(options) is not None  # a mark needs a key per asset
    for asset in assets:
        if not marked or key is not None:
            job_key, key_path = key, None
        elif keys_dir is not None:
            job_key = key_path = os.path.join(os.path.abspath(keys_dir), asset.relative + PMW_SUFFIX + KEY_SUFFIX)
        else:
            job_key, key_path = None, asset.output + KEY_SUFFIX  # pmwm_codec.encode's default key path
        prior = previous.get(asset.input) or {}
        done = prior.get("status") in ("ok", "skipped") and prior.get("output") == asset.output \
            and prior.get("settings_sha256") == settings
        # the output's size and digest: those of the row that wrote it (a skipped row of an older run recorded
        # the size it found, which may be that of a damaged file)
        made = written.get(asset.input) or {}
        if not all(made.get(f) == prior.get(f) for f in ("output", "settings_sha256", "input_sha256")):
            made = prior
        jobs.append(EncodeJob(asset.input, asset.output, job_key, key_path, image, timeout, force,
                              prior.get("input_sha256") if done else None, prior.get("vertices") if done else None,
                              settings, dict(options or {}), asset.root,
                              made.get("bytes") if done else None, made.get("output_sha256") if done else None,
                              restore_sigint, given, asset.clash))
    return jobs


def encode_batch(src, out_dir, *, watermark=None, key=None, keys_dir=None, workers=None, scheduler=None,
                 timeout=DEFAULT_TIMEOUT, force=False, progress=None, client=None, options=None,
                 no_worker_timeout=NO_WORKER_TIMEOUT) -> dict:
    """Encode every asset of ``src`` into ``out_dir``; returns the run's summary.

    ``options``: :func:`pmwm_codec.encode` options for every asset (``mode``, ``grid_bits``,
    ``payload_version``, ...; JSON-able values), part of the settings the ledger compares.

    ``key``: a collection key path (loaded, or created and saved, here); ``keys_dir``: where
    per-asset keys go (default: beside each output).  ``client``: a ``distributed.Client`` to
    use instead of starting one (``workers`` and ``scheduler`` are then ignored).  ``progress(counts)`` is called after
    every finished asset with ``done total ok skipped failed timeout running rate``.
    ``no_worker_timeout``: seconds the run goes on while the cluster has no worker before it stops
    (BatchError; the ledger whole, a re-run does the rest).
    Summary: ``assets ok skipped failed timeout seconds ledger failures`` (failures: rows).
    """
    if key is not None and keys_dir is not None:
        raise BatchError("give --key (one collection key) or --keys-dir (a key per asset), not both")
    _check_seconds(timeout, "--timeout")
    _check_seconds(no_worker_timeout, "--no-worker-timeout")
    if client is None and not scheduler:
        local_workers(workers)  # refused before anything is read or made
    _check_out_dir(out_dir)
    out_dir = os.path.abspath(os.fspath(out_dir))
    try:
        assets = expand_sources(src, out_dir)
    except (ValueError, OSError) as exc:
        raise BatchError(str(exc)) from None
    check_key_places(assets, out_dir, key, keys_dir)  # before anything is made: no key, no OUT_DIR
    image, key_obj, new_key, given = None, None, False, None
    if key is not None:
        image, key_obj, new_key, given = _collection_key(key, watermark, _owner_given(options))
        folder = os.path.dirname(os.path.abspath(key))
        if new_key and not os.path.isdir(folder) and folder != out_dir:
            raise BatchError(f"{key}: cannot make the collection key there: no folder {folder}")
        if image is None and (options or {}).get("owner_id") is False:
            raise BatchError(f"{key}: the key holds no watermark image, so --no-owner would leave every asset "
                             "unmarked")
    elif watermark is not None:
        from pmwm_codec.watermark.image import load_watermark_given

        image, _, given = load_watermark_given(watermark)
    jobs = _jobs(assets, out_dir, image, key_obj, keys_dir, timeout, force, options, _restore_sigint(scheduler), given)
    folders = _missing_folders(jobs, out_dir)  # the tasks make them; those a finished run leaves empty go again
    # Everything refused so far (a watermark, a key or its folder) made nothing.  The cluster comes next (a
    # --scheduler must answer), and only then OUT_DIR and a new collection key; a run that fails before its
    # first task removes exactly what it made.
    created_dir, made_key, started = False, None, False
    try:
        with dask_client(workers, scheduler, client, len(jobs)) as client:
            created_dir = not os.path.isdir(out_dir)
            os.makedirs(out_dir, exist_ok=True)  # before the key: a new collection key may go inside it
            if new_key:
                key_obj.save(key)
                made_key = key
            with LedgerWriter(os.path.join(out_dir, LEDGER_NAME)) as ledger:
                started = True
                start = time.monotonic()
                counts = dict.fromkeys(("ok", "skipped", "failed", "timeout"), 0)
                failures = []

                def record(row):
                    if row["status"] not in counts:  # ``stopped``: the run's own stop, nothing published
                        return
                    try:
                        ledger.write(row)
                    except OSError as exc:  # a full disk: the run cannot record, so it stops, and says what is left
                        left = len(jobs) - sum(counts.values())
                        raise OSError(exc.errno, f"{exc.strerror}; the run stopped with {left} of {len(jobs)} assets "
                                      "not recorded (a re-run does them)", exc.filename) from None
                    counts[row["status"]] += 1
                    if row["status"] in ("failed", "timeout"):
                        failures.append(row)

                def each(row):
                    record(row)
                    if progress is not None:
                        progress(_progress_counts(counts, len(jobs), client, start))

                submitted = _Submitted(client, encode_task, jobs, stoppable=True)
                try:
                    submitted.run(each, no_worker_timeout)
                except BaseException:
                    # interrupted, or stopped: the running encoders stop too; one that published first is
                    # recorded (a row for every output there), the others end without a row (a re-run does them)
                    with contextlib.suppress(Exception):
                        submitted.stop(lambda row: record(row) if row.get("status") in ("ok", "skipped") else None)
                    raise
    except BaseException:
        if not started:  # refused (a scheduler, the key's place, OUT_DIR itself) or interrupted before any work
            if made_key is not None:
                with contextlib.suppress(OSError):
                    os.unlink(made_key)
            if created_dir:
                with contextlib.suppress(OSError):
                    os.rmdir(out_dir)  # only when still empty
        raise
    _remove_empty(folders)  # every task has ended: no output is on its way into them
    return {"assets": len(jobs), **counts, "seconds": round(time.monotonic() - start, 3),
            "ledger": os.path.join(out_dir, LEDGER_NAME), "failures": failures}


def _missing_folders(jobs, out_dir: str) -> set:
    """The folders an output or a key of ``jobs`` goes in that do not exist yet (below ``out_dir``; for a key under
    ``--keys-dir``, up to the first that exists): the tasks make them as they go."""
    missing, seen = set(), set()
    for job in jobs:
        for path in (job.output, job.key_path):
            here = None if path is None else os.path.dirname(path)
            while here is not None and here not in seen and here != out_dir and os.path.dirname(here) != here:
                seen.add(here)
                if os.path.lexists(here):
                    break
                missing.add(here)
                here = os.path.dirname(here)
    return missing


def _remove_empty(folders) -> None:
    """Remove those of ``folders`` that are empty, the deepest first: a failed asset's output folder (``out/sub``
    for ``lib/sub/broken.obj``) was left behind, empty."""
    for folder in sorted(folders, key=lambda f: f.count(os.sep), reverse=True):
        with contextlib.suppress(OSError):
            os.rmdir(folder)


def _check_out_dir(out_dir) -> None:
    """BatchError (one line, before anything is read or made) when OUT_DIR is, or lies below, something that is
    not a folder (a mesh, ``/dev/null``): it was reported as its ledger's path, ``out/pmw-batch.jsonl: Not a
    directory``."""
    shown = os.fspath(out_dir)
    existing = os.path.abspath(shown)
    while not os.path.lexists(existing) and os.path.dirname(existing) != existing:
        existing = os.path.dirname(existing)
    if os.path.isdir(existing):
        return
    if existing == os.path.abspath(shown):
        raise BatchError(f"{shown}: exists and is not a folder; -o names the folder the outputs go in")
    raise BatchError(f"{shown}: cannot be made: {existing} is not a folder")


def _check_seconds(value, option: str) -> None:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not 0 < value <= MAX_TIMEOUT:
        raise BatchError(f"{option} must be a number of seconds in (0, {MAX_TIMEOUT:g}], got {value!r} "
                         "(a longer wait cannot be asked of the operating system)")


def _progress_counts(counts, total, client, start) -> dict:
    done = sum(counts.values())
    elapsed = max(time.monotonic() - start, 1e-9)
    slots = sum(client.nthreads().values()) or 1
    return {"done": done, "total": total, **counts, "running": min(slots, total - done), "rate": done / elapsed}


class _Submitted:
    """``function(job)`` submitted per job on ``client``.  ``stoppable``: each call also gets ``stop=NAME``, the
    name of a Dask Event that :meth:`stop` sets, which a running task polls (a cancel reaches only tasks that have
    not started: Dask cannot stop a running one)."""

    def __init__(self, client, function, jobs, stoppable: bool = False):
        token = uuid.uuid4().hex[:8]
        self.client, self.jobs, self.event = client, jobs, None
        extra = {}
        if stoppable:
            from distributed import Event

            self.event = Event(f"pmw-stop-{token}", client=client)
            extra["stop"] = self.event.name
        self.futures = {client.submit(function, job, pure=False, key=f"pmw-{function.__name__}-{token}-{i}",
                                      **extra): job
                        for i, job in enumerate(jobs)}

    def run(self, each, no_worker_timeout=NO_WORKER_TIMEOUT, what="assets") -> None:
        """``each(result)`` for every result as it finishes (a lost task: a failed row), until all have come.

        BatchError (one line: how many of the ``what`` got no result) when the cluster has had no worker for
        ``no_worker_timeout`` seconds while tasks wait (its workers all died, or none ever joined); the tasks
        left are cancelled, and the results handled before stand (a re-run of an encode does the rest)."""
        from distributed import as_completed

        pending = as_completed(self.futures)
        watch = _WorkerWatch(self.client, no_worker_timeout)
        while not pending.is_empty():
            finished = pending.next_batch(block=False)
            if finished and self._take(finished, each, again=pending.add):
                continue
            # nothing came, or nothing of what came could be had (a result lost with its worker: a future the
            # scheduler may still call finished comes straight back, and the watch must be looked at all the same)
            if watch.gone():
                left = len(self.futures)
                with contextlib.suppress(Exception):  # a cluster that cannot take the cancel lets them go
                    self.client.cancel(list(self.futures))
                raise BatchError(f"the Dask cluster has had no worker for {no_worker_timeout:g} s (all gone?); "
                                 f"the run stopped with {left} of {len(self.jobs)} {what} not done (a re-run "
                                 "does them)")
            if not finished:
                time.sleep(_POLL)

    def _take(self, finished, each, again=lambda future: None) -> int:
        """``each(result)`` for each of the ``finished`` futures still ours; returns how many were taken.  A future is ours until ``each`` has
        done with its result (a row recorded), which runs with SIGINT / SIGTERM held back: a stop that lands as a
        result comes in finds it either still here (:meth:`stop` takes it) or recorded, never lost between the two
        (its output would be left without a ledger row).  A result that died with its worker before it reached the
        run (the future ``lost``, or its result not had within :data:`RESULT_WAIT` s) is not waited for here, which
        waited until a worker computed it again, for ever when none came (the no-worker timeout never looked at):
        the future is given to ``again`` (:meth:`run`'s ``as_completed``), which has it when it finishes again."""
        from distributed import TimeoutError as DaskTimeoutError

        taken = 0
        for future in finished:
            job = self.futures.get(future)
            if job is None:
                continue
            try:
                if future.status == "finished":
                    row = future.result(timeout=RESULT_WAIT)
                elif future.status in ("error", "cancelled"):  # the worker died under the task (KilledWorker) or
                    row = _lost(job, future.exception(timeout=RESULT_WAIT))  # the task raised
                else:  # lost with its worker, or pending again: computed again when a worker comes
                    again(future)
                    continue
            except (DaskTimeoutError, TimeoutError):
                again(future)
                continue
            with signals_deferred():
                del self.futures[future]
                fault_point("batch-row-taken")
                each(row)
            future.release()
            taken += 1
        return taken

    def stop(self, each, seconds: float = STOP_WAIT) -> None:
        """Stop the run: the tasks not started are cancelled, the running ones told to stop (the Event);
        ``each(result)`` for those that end within ``seconds`` (an encoder that published its output before the
        stop reached it has an ``ok`` row: recording it leaves no output the ledger does not name).  Never
        raises."""
        try:
            if self.event is not None:
                self.event.set()
            queued = self._not_started()
            self.client.cancel(queued)
            for future in queued:
                self.futures.pop(future, None)
            deadline = time.monotonic() + seconds
            while self.futures and time.monotonic() < deadline:
                # (a future lost with its worker is computed again only when a worker comes: not waited for here)
                finished = [f for f in self.futures if f.status in ("finished", "error", "cancelled")]
                if finished:
                    self._take(finished, each)
                else:
                    time.sleep(_POLL)
            if not self.futures and self.event is not None:
                self.event.clear()  # every task has seen the stop or ended: the scheduler forgets the Event
        except Exception:  # noqa: BLE001 - a cluster gone or not answering: nothing more comes back from it
            return


    def _not_started(self) -> list:
        """The futures whose tasks no worker has been given yet, which :meth:`stop` cancels (started after the stop,
        they would only see it and end).  Asked of the scheduler in one call: a task that has just finished, its
        result not yet taken, must not be among them (cancelled, its row was lost, and its output was left without
        one).  A task given to a worker after this answer sees the stop before it encodes anything.  A scheduler
        that refuses the call (``distributed.scheduler.pickle`` off): those neither processing nor finished as far
        as the client knows."""
        def states(dask_scheduler, keys):  # run on the scheduler (pickled by value: it needs no import of ours)
            tasks = dask_scheduler.tasks
            return [key for key in keys if key in tasks and tasks[key].state in ("released", "waiting", "queued",
                                                                                 "no-worker")]
        try:
            waiting = set(self.client.run_on_scheduler(states, keys=[f.key for f in self.futures]))
            return [f for f in self.futures if f.key in waiting]
        except Exception:  # noqa: BLE001
            running = set()
            for keys in self.client.processing().values():
                running.update(keys)
            return [f for f in self.futures if f.key not in running and f.status == "pending"]


class _WorkerWatch:
    """How long the cluster of ``client`` has had no worker (looked at every :data:`WORKER_CHECK_INTERVAL` s;
    a scheduler that does not answer counts as one without workers)."""

    def __init__(self, client, timeout: float):
        self.client, self.timeout = client, timeout
        self.checked = self.since = None
        self.verdict = False

    def gone(self) -> bool:
        """Whether there has been no worker for ``timeout`` seconds, as the looks tell it: a look that saw none,
        and a later one, asked ``timeout`` s or more after the first had its answer, that saw none either (and
        none between that saw one).  Between two looks, the verdict of the last: a worker is never judged gone
        on the clock alone (a ``timeout`` shorter than the interval stopped the run one look after it saw no
        worker, one having come since), nor on one slow answer (an answer of no worker that took ``timeout`` s
        counted the whole wait as time without one)."""
        asked = time.monotonic()
        if self.checked is not None and asked - self.checked < WORKER_CHECK_INTERVAL:
            return self.verdict
        try:
            workers = len(self.client.nthreads())
        except Exception:  # noqa: BLE001 - the scheduler is gone or not answering: no worker either
            workers = 0
        self.checked = time.monotonic()
        if workers:
            self.since = None
        elif self.since is None:
            self.since = self.checked  # seen without one by then at the latest
        self.verdict = self.since is not None and asked - self.since >= self.timeout
        return self.verdict


def _lost(job, exc) -> dict:
    text = " ".join(f"{type(exc).__name__}: {exc}".split())
    if isinstance(job, EncodeJob):
        return {"input": job.input, "input_sha256": None, "output": job.output, "status": "failed",
                "error": f"{job.input}: task lost ({text})", "seconds": None, "bytes": None, "vertices": None,
                "settings_sha256": job.settings}
    return {"file": job[0], "verdict": "error", "error": f"task lost ({text})"}


def _not_a_folder(path) -> str:
    """What is wrong with ``path`` where a folder is wanted (it is none): ``is not a folder`` or ``no such folder``."""
    return "is not a folder" if os.path.exists(path) else "no such folder"


def verify_batch(out_dir, *, key=None, keys_dir=None, watermark=None, workers=None, scheduler=None,
                 progress=None, client=None, no_worker_timeout=NO_WORKER_TIMEOUT) -> dict:
    """Verify every ``.pmw`` under ``out_dir``: with the collection ``key``, with per-asset keys
    under ``keys_dir``, or (default) with the key beside each file.

    Returns ``{"files", "authentic", "present", "results": [{file, verdict, error}, ...]}`` (sorted by file;
    ``present``: the files of the owner layer alone, their key holding no image, whose layer reads ``present``:
    :func:`~.tasks.verify_task`).
    Symlinked folders are not entered, and a file or key whose real path leaves its folder
    (``out_dir``, or ``keys_dir`` for the keys there) is not read: an ``error`` result saying so.
    ``no_worker_timeout``: as :func:`encode_batch`'s (BatchError when the cluster has no worker that long).
    """
    if key is not None and keys_dir is not None:
        raise BatchError("give --key (one collection key) or --keys-dir (a key per asset), not both")
    _check_seconds(no_worker_timeout, "--no-worker-timeout")
    if client is None and not scheduler:
        local_workers(workers)
    out_dir = os.path.abspath(os.fspath(out_dir))
    if not os.path.isdir(out_dir):
        raise BatchError(f"{out_dir}: {_not_a_folder(out_dir)}")
    files = sorted(os.path.join(here, f) for here, _, names in os.walk(out_dir) for f in names
                   if f.endswith(PMW_SUFFIX) and not f.startswith("."))
    if not files:
        raise BatchError(f"{out_dir}: no .pmw files found")
    if keys_dir is not None and not os.path.isdir(keys_dir):  # bad usage, not one error result per file
        raise BatchError(f"{keys_dir}: {_not_a_folder(keys_dir)}; --keys-dir names the folder of the per-asset keys")
    if watermark is not None and isinstance(watermark, (str, os.PathLike)):
        from pmwm_codec.watermark.image import load_watermark

        load_watermark(watermark)  # an image that does not read is bad usage (as pmw verify), checked once, here
    if key is not None:
        from pmwm_codec.watermark.key import WatermarkKey

        key = WatermarkKey.load(key)
    # the folders named bound what is read: a .pmw (or a key beside it, or under --keys-dir) whose real path
    # leaves its folder is an error result, never read; a --key names one file, taken as named
    key_root = None if key is not None else out_dir if keys_dir is None else os.path.abspath(keys_dir)
    jobs = [(path, key if key is not None else _beside_key(path, out_dir, keys_dir), watermark, out_dir, key_root)
            for path in files]
    results = []

    def each(result):
        results.append(result)
        if progress is not None:
            progress({"done": len(results), "total": len(jobs), "rate": None})

    with dask_client(workers, scheduler, client, len(jobs)) as client:
        _Submitted(client, _verify_job, jobs).run(each, no_worker_timeout, "files")
    results.sort(key=lambda r: r["file"])
    return {"files": len(results), "authentic": sum(r["verdict"] == "authentic" for r in results),
            "present": sum(r["verdict"] == "present" for r in results), "results": results}


def _verify_job(job) -> dict:
    return verify_task(*job)


def _beside_key(path, out_dir, keys_dir) -> str:
    if keys_dir is None:
        return path + KEY_SUFFIX
    return os.path.join(os.path.abspath(keys_dir), os.path.relpath(path, out_dir) + KEY_SUFFIX)
