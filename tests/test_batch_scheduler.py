"""``pmw batch --scheduler ADDRESS``: a malformed address is bad usage (not "a bug of pmw"), a port that is not
Dask is refused within the connection timeout (it hung), and a run that cannot reach its scheduler leaves
nothing behind: no OUT_DIR, no new collection key."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

pytest.importorskip("distributed")

from pmwm_codec.batch import run  # noqa: E402
from pmwm_codec.cli import main  # noqa: E402

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


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


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
    address = f"tcp://127.0.0.1:{_free_port()}"
    out, key = lib / "out", lib / "c.key.json"
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
