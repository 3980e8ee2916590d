"""Encode one asset in a process of its own: :func:`child_main` (forked) or :func:`main` (a fresh interpreter).

The batch task (:func:`pmwm_codec.batch.tasks.encode_task`) starts this process so that
it can kill it at the per-asset timeout, and so that a crash in a native library takes
down one asset, not the worker.  A forked child gets the job dict as an argument and sends
the result dict through a pipe, and watches a second pipe that the worker holds open (its end
closes when the worker ends, however); the interpreter form watches its parent process, and reads a
pickled job dict on standard input
(``src``, ``dst``, ``watermark`` ((s, s) uint8 array or None), ``key`` (WatermarkKey,
key path or None), ``options`` (the :func:`pmwm_codec.encode` options), ``restore_sigint``
(:func:`_signals`), ``parent`` (the interpreter form: the pid of the process that started it) — trusted:
written by our own task), one JSON object on standard output::

    {"status": "ok", "bytes": 10724, "vertices": 800, "key_path": "...", "error": null}
    {"status": "failed", "error": "<one line>", ...}

The encode itself is one call of :func:`pmwm_codec.encode`, which writes the ``.pmw``
atomically and, for a key path (or None), the key file.  A SIGTERM, or the end of the worker (the run
killed), stops it quietly: what it was writing is removed, no traceback, no result (:class:`Stopped`).
"""

from __future__ import annotations

import json
import pickle
import sys


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (library errors as they are, others with their type)."""
    from pmwm_codec.errors import PmwError

    text = " ".join(str(exc).split())
    if isinstance(exc, PmwError) and text:
        return text
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def encode_job(job: dict) -> dict:
    """Run one encode; every failure becomes a ``failed`` result (never raises)."""
    import pmwm_codec
    from pmwm_codec.watermark.codec import CapacityError

    try:
        try:
            report = pmwm_codec.encode(job["src"], job["dst"], watermark=job.get("watermark"), key=job.get("key"),
                                       **job.get("options", {}))
        except CapacityError as exc:  # named as the user gave the image, not as the square it was made
            given = job.get("watermark_given")
            raise exc if given is None else exc.as_given(*given) from None
    except Exception as exc:  # the isolation boundary: the reason goes to the ledger
        if isinstance(exc, OSError) and exc.filename is not None:
            return {"status": "failed", "error": f"{exc.filename}: {exc.strerror or exc}"}
        return {"status": "failed", "error": one_line(exc)}
    return {"status": "ok", "error": None, "bytes": report.get("bytes"), "vertices": report.get("vertices"),
            "key_path": report.get("key_path")}


class Stopped(BaseException):
    """Raised in the encoder's main thread by a SIGTERM, or when the worker that started it is gone: the encode
    stops where it is (a file being written is removed, as on any failure) and nothing is reported."""


#: Seconds an encoder has to stop once its worker is gone, before it exits without cleaning up (a native call
#: that does not return); the next run removes what such an exit leaves (:func:`~.tasks._remove_leftovers`).
GRACE = 5.0
#: Seconds between two looks of the interpreter form at its parent (:func:`_wait_reparented`).
PARENT_POLL = 0.25
_state = {"reporting": False}


def _on_sigterm(signum, frame):
    _state["stopping"] = True
    if not _state["reporting"]:
        raise Stopped()


def _signals(restore_sigint: bool) -> None:
    """The encoder's signals.  SIGINT: back to the default when ``restore_sigint`` (the run's local workers
    ignore it only so that a Ctrl-C stops the run once, in the client: :func:`pmwm_codec.batch.run.dask_client`;
    an encoder then dies with the run); left as inherited otherwise, so that an ignored SIGINT (a run started
    as a background job of a script, ``nohup``) stays ignored.  SIGTERM: stop quietly (:class:`Stopped`); where
    Python cannot raise it (a ctypes callback, as llvmlite's cache runs) it prints no "Exception ignored"
    traceback: the stop is noted, and :func:`_encode` stops after the encode."""
    import signal

    hook = sys.unraisablehook

    def unraisable(info):
        if not (_state.get("stopping") and isinstance(info.exc_value, Stopped)):
            hook(info)

    sys.unraisablehook = unraisable
    if restore_sigint:
        signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, _on_sigterm)


def _parent_gone() -> None:
    """The worker is gone (the run was killed): stop the encode in the main thread, then exit in any case."""
    import os
    import signal
    import time

    if _state["reporting"]:
        return
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(GRACE)
    os._exit(1)


def _watch(wait) -> None:
    """Call :func:`_parent_gone` when ``wait()`` returns or raises, from a daemon thread."""
    import threading

    def watch():
        try:
            wait()
        except BaseException:  # noqa: BLE001 - the end of the wait is the news
            pass
        _parent_gone()

    threading.Thread(target=watch, name="pmw-watch-worker", daemon=True).start()


def _wait_pipe_closed(lifeline):
    """Wait until the worker's end of ``lifeline`` closes (it never writes): the worker ended."""
    def wait():
        while True:
            lifeline.recv_bytes()
    return wait


def _wait_reparented(parent: int | None = None):
    """Wait until this process's parent is no longer ``parent`` (the pid of the worker that ran it, given in the
    job: a worker that ended before this watch started is seen too; this process's parent now when None)."""
    import os
    import time

    parent = os.getppid() if parent is None else parent

    def wait():
        while os.getppid() == parent:
            time.sleep(PARENT_POLL)
    return wait


def _stop_quietly() -> None:
    """End after a :class:`Stopped` or a lost worker: by SIGTERM's default action (exit status -15, as an
    encoder killed by it), without a traceback or a result."""
    import os
    import signal

    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    os.kill(os.getpid(), signal.SIGTERM)
    os._exit(1)


def child_main(job: dict, connection, lifeline=None) -> None:
    """Entry of a forked child: encode, send the result dict through ``connection``.  ``lifeline``: a pipe
    end whose other end the worker holds open until this process has ended; when it closes first, the
    worker is gone, and the encode stops (never a traceback of a result sent to no one)."""
    try:  # a stop can come as soon as SIGTERM has its handler: while the watch starts, its news already in
        _signals(job.get("restore_sigint", True))
        if lifeline is not None:
            _watch(_wait_pipe_closed(lifeline))
        result = _encode(job)
        connection.send(result)
        connection.close()
    except (Stopped, OSError, EOFError):  # stopped, or the worker went away while we reported
        _stop_quietly()


def _encode(job: dict) -> dict:
    """:func:`encode_job`, then no more stopping (:class:`Stopped` when a stop came during it: a SIGTERM that
    a compiled call turned into another error is still a stop, not a failed asset)."""
    result = encode_job(job)
    _state["reporting"] = True
    if _state.get("stopping"):
        raise Stopped()
    return result


def main() -> int:
    """Entry of ``python -c 'from pmwm_codec.batch.child import main; ...'`` (a daemonic worker's encoder)."""
    job = pickle.loads(sys.stdin.buffer.read())
    try:  # (as :func:`child_main`: a stop while the watch starts is a stop)
        _signals(job.get("restore_sigint", True))
        _watch(_wait_reparented(job.get("parent")))
        result = _encode(job)
        sys.stdout.write(json.dumps(result) + "\n")
        sys.stdout.flush()
    except (Stopped, OSError, EOFError):
        _stop_quietly()
    return 0


if __name__ == "__main__":
    sys.exit(main())
