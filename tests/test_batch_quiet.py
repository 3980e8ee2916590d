"""``pmw batch`` says nothing on stderr for a run that went well: the local workers' logs are silenced at CRITICAL
(a worker's heartbeat ERROR with its traceback, when the scheduler closes at the end of a run, reached the
terminal after 2 of 8 successful ``batch verify`` runs), and the scheduler's HTTP server no longer warns that
port 8787 is taken (another cluster, another run)."""

from __future__ import annotations

import logging
import socket
import warnings

import pytest

pytest.importorskip("distributed")

from pmwm_codec.batch.run import dask_client  # noqa: E402


def _handler_levels():
    return sorted({h.level for h in logging.getLogger("distributed").handlers if isinstance(h, logging.StreamHandler)})


def test_local_workers_print_no_log_below_critical_and_no_port_warning():
    held = socket.socket()
    try:
        held.bind(("127.0.0.1", 8787))  # taken, by us or by another cluster
        held.listen()
    except OSError:
        pass
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            with dask_client(workers=1) as client:
                levels = client.run(_handler_levels)
    finally:
        held.close()
    assert levels and all(lv and min(lv) >= logging.CRITICAL for lv in levels.values()), levels
    assert not [w for w in caught if "already in use" in str(w.message)]
