"""Whole libraries of assets: ``pmw batch encode`` / ``pmw batch verify`` on Dask.

* :mod:`.sources` — SRC (folder, glob, manifest) to assets and mirrored output paths;
* :mod:`.ledger` — ``OUT_DIR/pmw-batch.jsonl``, one JSON line per asset and attempt;
* :mod:`.tasks` — what runs on a worker: hash, skip or encode in a killable child;
* :mod:`.child` — the child process: one :func:`pmwm_codec.encode` call;
* :mod:`.run` — the client: Dask cluster, submission, ledger, summary.

Needs the optional ``batch`` extra (``pip install "pmwm_codec[batch]"``: ``dask[distributed]``);
importing :mod:`.run` imports Dask only when a batch starts.
"""

from .ledger import FIELDS, LEDGER_NAME, read_ledger
from .run import DEFAULT_TIMEOUT, NO_WORKER_TIMEOUT, BatchError, encode_batch, verify_batch
from .sources import Asset, expand_sources

__all__ = ["Asset", "BatchError", "DEFAULT_TIMEOUT", "FIELDS", "LEDGER_NAME", "NO_WORKER_TIMEOUT", "encode_batch",
           "expand_sources", "read_ledger", "verify_batch"]
