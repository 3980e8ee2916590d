"""Encode one asset in a process of its own: :func:`child_main` (forked) or ``python -m pmwm_codec.batch.child``.

The batch task (:func:`pmwm_codec.batch.tasks.encode_task`) starts this process so that
it can kill it at the per-asset timeout, and so that a crash in a native library takes
down one asset, not the worker.  A forked child gets the job dict as an argument and sends
the result dict through a pipe; the interpreter form reads a pickled job dict on standard input
(``src``, ``dst``, ``watermark`` ((s, s) uint8 array or None), ``key`` (WatermarkKey,
key path or None), ``options`` (the :func:`pmwm_codec.encode` options) — trusted: written by our
own task), one JSON object on standard output::

    {"status": "ok", "bytes": 10724, "vertices": 800, "key_path": "...", "error": null}
    {"status": "failed", "error": "<one line>", ...}

The encode itself is one call of :func:`pmwm_codec.encode`, which writes the ``.pmw``
atomically and, for a key path (or None), the key file.
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

    try:
        report = pmwm_codec.encode(job["src"], job["dst"], watermark=job.get("watermark"), key=job.get("key"),
                                   **job.get("options", {}))
    except Exception as exc:  # the isolation boundary: the reason goes to the ledger
        if isinstance(exc, OSError) and exc.filename is not None:
            return {"status": "failed", "error": f"{exc.filename}: {exc.strerror or exc}"}
        return {"status": "failed", "error": one_line(exc)}
    return {"status": "ok", "error": None, "bytes": report.get("bytes"), "vertices": report.get("vertices"),
            "key_path": report.get("key_path")}


def _default_sigint() -> None:
    """The run's workers ignore SIGINT (:func:`pmwm_codec.batch.run.dask_client`); an encoder does not: a
    Ctrl-C of the run ends it (without a traceback), so it never outlives the run."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_DFL)


def child_main(job: dict, connection) -> None:
    """Entry of a forked child: encode, send the result dict through ``connection``."""
    _default_sigint()
    connection.send(encode_job(job))
    connection.close()


def main() -> int:
    _default_sigint()
    job = pickle.loads(sys.stdin.buffer.read())
    result = encode_job(job)
    sys.stdout.write(json.dumps(result) + "\n")
    sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
