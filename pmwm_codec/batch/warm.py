"""Imported by each worker's encoder forkserver: compiles the encoder's kernels once, and keeps the
forkserver quiet when its worker dies in the middle of a request.

The per-asset encoders are forked from a forkserver (:func:`pmwm_codec.batch.tasks._run_forked`)
that imports the modules in ``_PRELOAD``.  Importing modules is not enough: numba compiles
(or loads from its disk cache) each kernel on its first call, about half a second per
process, which every forked child would pay again.  Importing this module encodes and
decodes one small watermarked mesh in memory, so that every kernel is compiled in the
forkserver and inherited, ready, by each child.

When the run is killed outright (``kill -9``) while a worker is asking its forkserver for a new
encoder, the forkserver reads the end of the connection where it expected the request's file
descriptors; multiprocessing's loop lets that ``EOFError`` end the forkserver with a traceback on
the terminal the run was started from, after the command has ended (tests/test_batch_signals.py
caught it once in a full run).  :func:`quiet_when_orphaned` ends it without one.
"""

from __future__ import annotations

import io
import sys


def quiet_when_orphaned(kind, value, tb) -> None:
    """``sys.excepthook`` of the forkserver: an uncaught ``EOFError`` or ``ConnectionError`` (a client, its
    worker, gone mid-request) ends the process without a word; anything else is reported as before."""
    if issubclass(kind, (EOFError, ConnectionError)):
        return
    _REPORT(kind, value, tb)


_REPORT = sys.excepthook
sys.excepthook = quiet_when_orphaned


def warm() -> bool:
    """Encode and decode a small watermarked icosphere in memory; True when it worked.

    Never raises: a failure here only costs the children their warm start.
    """
    try:
        import numpy as np

        from pmwm_codec import shapes
        from pmwm_codec.stream import decode_stream, encode_mesh
        from pmwm_codec.watermark.key import WatermarkKey

        image = (np.indices((8, 8)).sum(0) % 2 * 255).astype(np.uint8)
        out = io.BytesIO()
        key = WatermarkKey.generate(rng=np.random.default_rng(0))
        encode_mesh(shapes.icosphere(3, noise=0.01, seed=1), out, watermark=image, key=key, measure="none")
        decode_stream(io.BytesIO(out.getvalue()), key=key)
        return True
    except Exception:  # noqa: BLE001 - warming is an optimisation, never a failure
        return False


WARM = warm()
