"""The functions Dask runs on the workers: one asset per call, a ledger row back, never a hang.

:func:`encode_task` hashes the input, skips it when the ledger says it is done, and
otherwise encodes it in a child process (:mod:`pmwm_codec.batch.child`) that it kills at
the timeout; :func:`verify_task` verifies one ``.pmw``.  Both return plain dicts and
never raise for a bad asset.
"""

from __future__ import annotations

import glob
import json
import multiprocessing
import os
import pickle
import subprocess
import sys
import time
from dataclasses import dataclass

from pmwm_codec.errors import PmwError

from .child import GRACE, child_main
from .ledger import input_sha256, sha256_file
from .sources import outside_root

__all__ = ["EncodeJob", "encode_task", "verify_task"]

#: Imported once by each worker's forkserver, so that a forked encoder starts warm
#: (``warm`` also compiles the numba kernels: a child would otherwise pay ~0.5 s for them).
_PRELOAD = ["pmwm_codec.batch.child", "pmwm_codec.stream.asset", "pmwm_codec.stream.encoder", "pmwm_codec.meshio",
            "DracoPy", "jsonschema", "PIL.PngImagePlugin", "pmwm_codec.batch.warm"]


@dataclass(frozen=True)
class EncodeJob:
    """Everything a worker needs for one asset.

    ``key``: what :func:`pmwm_codec.encode` gets (a collection WatermarkKey, a per-asset key
    path under ``--keys-dir``, or None: a new key beside the output); ``key_path``: the
    per-asset key file that must exist beside a done output (None for a collection key or
    no watermark).  ``watermark``: (s, s) uint8 array or None.  ``prior_sha256`` /
    ``prior_vertices``: the ledger's last ok/skipped row for this input, if any, made with
    the same ``settings`` (:func:`pmwm_codec.batch.ledger.settings_sha256`), and ``prior_bytes`` /
    ``prior_output_sha256``: the size and digest its output had then (the digest None for a row of an
    older run: the size alone is compared).  ``options``: the
    :func:`pmwm_codec.encode` options of every asset of the run.  ``root``: the folder a
    folder or glob SRC names, which the input's real path must not leave (None: no bound).
    ``restore_sigint``: whether the encoder takes SIGINT back to its default (the run's local workers
    ignore it for the run's sake); False leaves it as the worker has it (an ignored SIGINT stays ignored).
    ``watermark_given``: the watermark's (width, height) as the user gave it, before it was made the square
    ``watermark`` (a capacity error names it so), or None.  ``clash``: why the asset is refused before it is
    read (its output is another asset's but for letter case: :attr:`pmwm_codec.batch.sources.Asset.clash`).
    """

    input: str
    output: str
    key: object = None
    key_path: str | None = None
    watermark: object = None
    timeout: float | None = None
    force: bool = False
    prior_sha256: str | None = None
    prior_vertices: int | None = None
    settings: str | None = None
    options: dict | None = None
    root: str | None = None
    prior_bytes: int | None = None
    prior_output_sha256: str | None = None
    restore_sigint: bool = True
    watermark_given: tuple | None = None
    clash: str | None = None


#: Seconds between two looks of a running encode's task at the run's stop (:func:`encode_task`).
STOP_POLL = 0.5


def encode_task(job: EncodeJob, stop: str | None = None) -> dict:
    """Encode (or skip) one asset; returns its ledger row.

    ``stop``: the name of the run's stop Event (a Dask Event on the cluster the task runs on), looked at every
    :data:`STOP_POLL` s while the encoder runs: once it is set (the run was interrupted), the encoder is stopped
    (SIGTERM: what it was writing removed) and the row's status is ``stopped``, which is never recorded; an
    encoder that published its output before the stop reached it keeps its ``ok`` row."""
    start = time.monotonic()
    stopped = _stop_flag(stop)
    row = {"input": job.input, "input_sha256": None, "output": job.output, "status": "failed", "error": None,
           "bytes": None, "vertices": None, "settings_sha256": job.settings, "output_sha256": None}
    # never read: an asset whose output another's is but for letter case, a symlink out of SRC's folder
    row["error"] = job.clash or outside_root(job.input, job.root)
    if row["error"] is None:
        try:
            row["input_sha256"] = input_sha256(job.input)
        except OSError as exc:
            row["error"] = f"{job.input}: {exc.strerror or exc}"
        except PmwError as exc:  # not a regular file: never read
            row["error"] = str(exc)
        else:
            done = _done_before(job, row["input_sha256"])
            if done is not None:
                row.update(status="skipped", bytes=done[0], output_sha256=done[1], vertices=job.prior_vertices)
            else:
                try:
                    row.update(_encode_in_child(job, stopped))
                except OSError as exc:  # its output's folder cannot be made (a file in its place ...)
                    row["error"] = f"{exc.filename or job.output}: {exc.strerror or exc}"
                if row["status"] == "ok":
                    row["output_sha256"] = _output_sha256(job.output)
    row["seconds"] = round(time.monotonic() - start, 3)
    return row


def _done_before(job: EncodeJob, sha: str) -> tuple[int, str] | None:
    """``(bytes, sha256)`` of the output when the ledger says this asset is done and the output (and its key)
    is still what the ledger recorded; None when it must be (re)done: an output truncated or altered since
    its row (a partial copy or sync) is redone, never skipped as done."""
    if job.force or job.prior_sha256 != sha or not os.path.isfile(job.output):
        return None
    if job.key_path is not None and not os.path.isfile(job.key_path):
        return None
    try:
        size = os.path.getsize(job.output)
    except OSError:
        return None
    if job.prior_bytes is None or size != job.prior_bytes:
        return None
    digest = _output_sha256(job.output)
    if digest is None or (job.prior_output_sha256 is not None and digest != job.prior_output_sha256):
        return None
    return size, digest


def _output_sha256(path: str) -> str | None:
    try:
        return sha256_file(path)
    except (OSError, PmwError):
        return None


def _child_env() -> dict:
    """The worker's environment, with this package importable and one thread per asset."""
    import pmwm_codec

    env = dict(os.environ)
    home = os.path.dirname(os.path.dirname(os.path.abspath(pmwm_codec.__file__)))
    env["PYTHONPATH"] = os.pathsep.join(p for p in (home, env.get("PYTHONPATH")) if p)
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(name, "1")
    return env


def _stop_flag(name: str | None):
    """A callable telling whether the run's stop Event ``name`` is set (never True without a name, or off a
    Dask worker; a scheduler that does not answer is no stop: its workers end with it)."""
    if name is None:
        return lambda: False
    try:
        from distributed import Event, get_client

        event = Event(name, client=get_client())
    except Exception:  # noqa: BLE001 - not on a worker (a direct call): nothing can set it
        return lambda: False

    def stopped() -> bool:
        try:
            return bool(event.is_set())
        except Exception:  # noqa: BLE001
            return False
    return stopped


def _encode_in_child(job: EncodeJob, stopped=lambda: False) -> dict:
    """Encode in a child process killed at ``job.timeout`` seconds; a status dict back (``stopped``: the run's
    stop, looked at every :data:`STOP_POLL` s; once True, the encoder is stopped and the status is ``stopped``).

    The child is forked from a forkserver that has the encoder imported (fast); a daemonic
    worker (``dask worker`` by default) may not have children of its own, so there the
    child is a fresh interpreter running :mod:`pmwm_codec.batch.child` (slower start).
    """
    for path in (job.output, job.key_path):
        if path is not None:
            os.makedirs(os.path.dirname(path), exist_ok=True)
    _remove_leftovers(job)  # of a run killed before (one run per OUT_DIR at a time)
    payload = {"src": job.input, "dst": job.output, "watermark": job.watermark, "key": job.key,
               "options": job.options or {}, "restore_sigint": job.restore_sigint, "watermark_given": job.watermark_given}
    if stopped():  # the run stopped while this task waited to start
        return {"status": "stopped", "error": "the run was stopped", "bytes": None, "vertices": None}
    before = _identity(job.output)
    if multiprocessing.current_process().daemon:
        result = _run_interpreter(payload, job.timeout, stopped)
    else:
        result = _run_forked(payload, job.timeout, stopped)
    if result["status"] != "ok":
        result = _published_anyway(job, before) or result
    if result["status"] == "timeout":
        result["error"] = f"{job.input}: no result within {job.timeout:g} s; encoder killed"
    elif result["status"] == "stopped":
        result["error"] = f"{job.input}: the run was stopped; encoder stopped"
    elif result["status"] == "failed" and job.input not in result["error"] \
            and os.path.basename(job.input) not in result["error"]:
        result["error"] = f"{job.input}: {result['error']}"
    if result["status"] != "ok":
        _remove_leftovers(job)
    return {k: result.get(k) for k in ("status", "error", "bytes", "vertices")}


def _identity(path: str):
    """``(device, inode, mtime_ns, size)`` of the file at ``path``, or None: what tells a file published since."""
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size


def _published_anyway(job: EncodeJob, before) -> dict | None:
    """The ``ok`` result of an encoder that ended without reporting ``ok`` after it had published its output:
    stopped, killed at the timeout or by a signal of its own in the moment between the two (a SIGTERM held
    back while the key and the ``.pmw`` were renamed into place takes effect the moment the pair is published).
    The output is replaced whole (one rename, its key before it; one run per OUT_DIR), so a file there other
    than the one the encoder started beside is its own, and it gets its row: an output the ledger does not
    name is the fault a stop must never leave.  None when the output is the one there before."""
    now = _identity(job.output)
    if now is None or now == before or (job.key_path is not None and not os.path.isfile(job.key_path)):
        return None
    from pmwm_codec.format.inspect import inspect

    try:
        vertices = inspect(job.output)["vertices"]
    except (PmwError, OSError, ValueError, KeyError, TypeError):  # its row all the same: `batch verify` reads it
        vertices = None
    return {"status": "ok", "error": None, "bytes": now[3], "vertices": vertices}


def _waits(timeout, stopped):
    """Slices of at most :data:`STOP_POLL` s up to ``timeout`` s: yields each slice's length, and ends with
    ``"timeout"`` or ``"stopped"`` (the caller stops waiting at a slice that brought the result)."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            yield "timeout"
            return
        if stopped():
            yield "stopped"
            return
        yield min(left, STOP_POLL)


def _run_forked(payload: dict, timeout, stopped=lambda: False) -> dict:
    ctx = multiprocessing.get_context("forkserver")
    ctx.set_forkserver_preload(_PRELOAD)
    receive, send = ctx.Pipe(duplex=False)
    # the child's lifeline: this process keeps the writing end open (never writes) until the child has ended;
    # when this process ends first (the run killed), the child reads the end of the pipe and stops quietly
    lifeline, alive = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=child_main, args=(payload, send, lifeline), name="pmw-encode")
    try:
        proc.start()
    finally:
        send.close()
        lifeline.close()
    try:
        for wait in _waits(timeout, stopped):
            if wait == "timeout":
                proc.kill()
                return {"status": "timeout"}
            if wait == "stopped":
                # SIGTERM: the encoder removes what it was writing; one already reporting sends its result
                proc.terminate()
                proc.join(GRACE + 1)
                if proc.is_alive():
                    proc.kill()
                return _received(receive) or {"status": "stopped"}
            if receive.poll(wait):
                break
        try:
            return receive.recv()
        except EOFError:
            proc.join()
            return {"status": "failed", "error": _died(proc.exitcode)}
    finally:
        receive.close()
        proc.join()
        alive.close()


def _received(receive) -> dict | None:
    """The result an encoder sent before it ended, or None."""
    try:
        return receive.recv() if receive.poll(0) else None
    except (EOFError, OSError):
        return None


def _died(status: int | None, why: str = "") -> str:
    """The error of an encoder that ended without a result: its signal by name, or its exit status."""
    import signal

    if status is not None and status < 0:
        try:
            name = signal.Signals(-status).name
        except ValueError:
            name = f"signal {-status}"
        text = f"encoder process killed by {name}"
    else:
        text = f"encoder process died (exit status {status})"
    return f"{text}: {why}" if why else text


def _run_interpreter(payload: dict, timeout, stopped=lambda: False) -> dict:
    # not ``-m pmwm_codec.batch.child``: the package imports that module first, and runpy's RuntimeWarning
    # about it was the last line of every such child's stderr, taken for the reason it died
    proc = subprocess.Popen([sys.executable, "-c", _CHILD_MAIN], stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=_child_env())
    given = pickle.dumps(dict(payload, parent=os.getpid()))  # a worker gone before the encoder's watch starts
    for wait in _waits(timeout, stopped):
        if wait == "timeout":
            proc.kill()
            proc.communicate()
            return {"status": "timeout"}
        if wait == "stopped":
            proc.terminate()  # as in _run_forked: stopped quietly, or its result already on its way
            try:
                out, err = proc.communicate(timeout=GRACE + 1)
            except subprocess.TimeoutExpired:
                proc.kill()
                out, err = proc.communicate()
            return _last_json(out) or {"status": "stopped"}
        try:
            out, err = proc.communicate(given, timeout=wait)
            break
        except subprocess.TimeoutExpired:
            given = None  # sent: a retried communicate() must not send it again
    result = _last_json(out)
    if result is not None:
        return result
    why = (err.decode("utf-8", "replace").strip().splitlines() or [""])[-1] if proc.returncode >= 0 else ""
    return {"status": "failed", "error": _died(proc.returncode, why.strip())}


def _last_json(out: bytes) -> dict | None:
    """The JSON result on the last line of an encoder's standard output, or None."""
    lines = out.decode("utf-8", "replace").strip().splitlines()
    try:
        result = json.loads(lines[-1])
    except (IndexError, ValueError):
        return None
    return result if isinstance(result, dict) else None


_CHILD_MAIN = "import sys; from pmwm_codec.batch.child import main; sys.exit(main())"


def _remove_leftovers(job: EncodeJob) -> None:
    """After a killed encoder: its temporary files.  An output already there is left as it is: the encoder
    publishes a key before its ``.pmw`` (never a new ``.pmw`` without its key), and an old output (of other
    settings, its key elsewhere) is replaced only by a new one that was written whole."""
    for path in (job.output, job.key_path):
        if path is None:
            continue
        pattern = os.path.join(glob.escape(os.path.dirname(path)), "." + glob.escape(os.path.basename(path)) + ".*.tmp")
        for tmp in glob.glob(pattern):
            _unlink(tmp)


def _unlink(path: str) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


#: What an ``outside_root`` refusal of ``pmw batch verify`` suggests: naming the file (and its key) itself.
VERIFY_REMEDY = "name the file and its key to verify it: pmw verify FILE --key KEY"


def verify_task(path: str, key, watermark=None, root: str | None = None, key_root: str | None = None) -> dict:
    """Verify one ``.pmw`` with ``key`` (WatermarkKey or key path): ``{file, verdict, error}``.

    ``verdict``: :func:`pmwm_codec.verify.verify_stream`'s, or ``truncated`` for a file that ends before
    its declared length (a cut file is not a whole output, whatever the part there reads; one that ends
    before its base mesh too), or ``error``; ``error`` says why (for an incomplete file: how much of it is
    there and what that part reads).  A file of the owner
    layer alone (its key holds no image and names an owner ID) has the owner layer's verdict, read from the
    whole file: ``present``, ``absent`` or ``inconclusive``.

    ``root``: the folder the run names (OUT_DIR), which the real path of ``path`` must not
    leave; ``key_root``: the folder a key path must not leave (OUT_DIR for the key beside the
    file, ``--keys-dir``), None for a key named as is.  A file (or key) that leaves its folder
    is never read: an ``error`` result that says so (:func:`~pmwm_codec.batch.sources.outside_root`).
    """
    from pmwm_codec import load_key
    from pmwm_codec.errors import PmwError, TruncatedError
    from pmwm_codec.verify import verify_stream
    from pmwm_codec.verify.owner import OwnerReader

    from .child import one_line

    key_path = os.fspath(key) if isinstance(key, (str, os.PathLike)) else None
    for file, folder in ((path, root), (key_path, key_root)):
        why = None if file is None else outside_root(file, folder, VERIFY_REMEDY)
        if why is not None:
            return {"file": path, "verdict": "error", "error": why}
    try:
        key = load_key(key)
        # a key of no image marks the owner layer alone: the layer read from the whole file is the verdict
        reader = OwnerReader(key, last_only=True) if key.reference is None and key.owner_id is not None else None
        outcome = verify_stream(path, key, watermark, each=None if reader is None else reader.add)
        owner = None if reader is None or outcome.marked or not reader.boundaries else reader.boundaries[-1].owner
    except TruncatedError as exc:  # it ends before its base mesh: a cut file as any other
        return {"file": path, "verdict": "truncated", "error": one_line(exc)}
    except (PmwError, OSError, ValueError) as exc:
        return {"file": path, "verdict": "error", "error": one_line(exc)}
    end = outcome.end
    if end.complete and owner is not None:
        why = None if owner.verdict == "present" else (f"the owner layer reads {owner.bit_errors} of {owner.bits} "
                                                        "bits wrong")
        return {"file": path, "verdict": owner.verdict, "error": why}
    if end.complete:
        return {"file": path, "verdict": outcome.verdict, "error": None}
    # a file cut short (a partial copy or sync) is not a whole output, whatever its prefix verifies as
    applied = outcome.results[-1].chunk if outcome.results else 0
    what = (f"the file ends at {end.bytes_read:,} of its {outcome.total_length:,} bytes, base + {applied} of "
            f"{end.chunks_total} chunks")
    # (an owner ID read absent from a prefix too short to carry it is no answer on the whole file: README, "never
    # authentic" nor any other verdict of a whole file)
    part = (f"the owner layer of the part there reads {owner.verdict}" if owner is not None else
            f"the part there verifies {outcome.verdict}")
    return {"file": path, "verdict": "truncated", "error": f"{what}; {part}"}
