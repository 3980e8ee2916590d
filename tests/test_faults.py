"""Faults: an encode killed at any moment, and a file read while it is still being written."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.stream import StreamDecoder
from pmwm_codec.stream.encoder import encode_mesh
from pmwm_codec.watermark.key import WatermarkKey

from conftest import marked_sphere

ROOT = Path(__file__).resolve().parents[1]

CHILD = r"""
import os, sys, numpy as np
from pmwm_codec import shapes
from pmwm_codec.stream.encoder import encode_mesh
from pmwm_codec.watermark.key import WatermarkKey
if {hang_at_replace}:
    real = os.replace
    def replace(a, b):
        if os.fspath(b) == {dst!r}:  # the output's rename, not another (numba's cache writes rename too)
            print("READY", flush=True)
            import time; time.sleep(60)
        real(a, b)
    os.replace = replace
print("START", flush=True)
rng = np.random.default_rng(1)
img = rng.integers(0, 256, ({size}, {size})).astype(np.uint8)
encode_mesh(shapes.icosphere({sub}, noise=0.01, seed=2), {dst!r}, watermark=img,
            key=WatermarkKey.generate(rng=rng))
print("DONE", flush=True)
"""


def _child(dst, *, sub=5, hang_at_replace=False):
    code = CHILD.format(dst=str(dst), sub=sub, hang_at_replace=hang_at_replace,
                        size=32 if sub >= 5 else 16)
    return subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)


@pytest.fixture
def old_file(tmp_path):
    dst = tmp_path / "out.pmw"
    rng = np.random.default_rng(0)
    encode_mesh(shapes.icosphere(2), dst, watermark=rng.integers(0, 256, (8, 8)).astype(np.uint8),
                key=WatermarkKey.generate(rng=rng))
    return dst, dst.read_bytes()


def _strays(dst):
    return sorted(p.name for p in dst.parent.iterdir() if p.name != dst.name)


def test_encode_killed_at_random_moments_leaves_the_old_file_intact(old_file):
    """After a SIGKILL the output is either the old file, byte for byte, or the complete new one."""
    dst, before = old_file
    rng = np.random.default_rng()
    outcomes = []
    for delay in [0.0, 0.05, *rng.uniform(0.0, 1.5, 4)]:
        proc = _child(dst)
        assert proc.stdout.readline().strip() == "START"  # imports done; the encode runs
        time.sleep(float(delay))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        now = dst.read_bytes()
        if now == before:
            outcomes.append("old")
        else:  # the kill came after os.replace: the new file must be whole
            assert pmwm_codec.decode(now).positions.shape[0] == 10242
            outcomes.append("new")
            before = now
        assert pmwm_codec.decode(str(dst)).positions.shape[0] > 0
        # a kill -9 cannot run cleanup: a hidden ".out.pmw.*.tmp" may stay, never a damaged output
        assert all(s.startswith(".out.pmw.") and s.endswith(".tmp") for s in _strays(dst))
    assert outcomes[0] == "old"  # killed right after the imports: nothing written yet


def test_kill_between_write_and_rename_then_a_later_encode(old_file):
    """The worst moment: the temp file is complete and fsynced, the rename has not happened."""
    dst, before = old_file
    proc = _child(dst, sub=3, hang_at_replace=True)
    lines = [proc.stdout.readline().strip() for _ in range(2)]
    assert lines == ["START", "READY"]
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert dst.read_bytes() == before
    strays = _strays(dst)
    assert len(strays) == 1 and strays[0].startswith(".out.pmw.") and strays[0].endswith(".tmp")
    # the stray is a complete file (it was fsynced), but it is not the output
    assert pmwm_codec.decode(str(dst.parent / strays[0])).positions.shape[0] > 0
    # a later encode ignores the stray: it writes its own temp file and replaces the output
    proc = _child(dst, sub=3)
    out, _ = proc.communicate(timeout=120)
    assert proc.returncode == 0 and "DONE" in out
    assert dst.read_bytes() != before
    assert pmwm_codec.decode(str(dst)).positions.shape[0] == 642
    assert _strays(dst) == strays  # left as it was (not cleaned up, not reused)


@pytest.fixture(scope="module")
def marked():
    return marked_sphere(5, min_chunk_splits=32)


def test_reading_a_file_while_it_is_being_written(tmp_path, marked):
    data, key, img = marked
    path = tmp_path / "growing.pmw"
    path.write_bytes(b"")
    written = [0]
    done = threading.Event()

    def writer():
        with open(path, "ab") as fh:
            for i in range(0, len(data), 701):
                # counted before the write: the reader can see the bytes the moment they are written, before this
                # thread runs again (counted after, a reader that had caught up failed whenever it was preempted there)
                written[0] = min(len(data), i + 701)
                fh.write(data[i: i + 701])
                fh.flush()
                time.sleep(0.002)
        done.set()

    t = threading.Thread(target=writer)
    t.start()
    dec = StreamDecoder(key)
    seen = []
    with open(path, "rb") as fh:
        while True:
            block = fh.read(4096)
            if block:
                for r in dec.feed(block):
                    assert r.bytes_read <= written[0]  # never ahead of what has arrived
                    seen.append((r.chunk, r.bytes_read, r.carriers_read))
            elif done.is_set() and fh.tell() == len(data):
                break
            else:
                time.sleep(0.001)
    t.join()
    end = dec.close()
    assert end.complete
    chunks = [c for c, _, _ in seen]
    assert chunks == list(range(len(chunks))) and chunks[-1] == end.chunks_total
    reads = [n for _, _, n in seen]
    assert reads == sorted(reads) and reads[0] == 0
    assert np.array_equal(dec.last.watermark, img) and dec.verifier.verdict() == "authentic"


def test_a_snapshot_of_a_growing_file_reports_what_has_arrived(marked):
    data, key, img = marked
    results = list(pmwm_codec.iter_decode(data, key=key))
    cut_after = results[len(results) // 2].bytes_read
    partial = list(pmwm_codec.iter_decode(data[: cut_after + 10], key=key))
    assert [r.chunk for r in partial] == [r.chunk for r in results[: len(partial)]]
    assert partial[-1].bytes_read == cut_after
    assert 0 < partial[-1].carriers_read < results[-1].carriers_read
    dec = StreamDecoder(key)
    dec.feed(data[: cut_after + 10])
    end = dec.close()
    assert end.truncated and end.chunks_applied == partial[-1].chunk


@pytest.mark.parametrize("order", [("m.obj", "m_0.png", "m.mtl"), ("m.obj", "m.mtl", "m_0.png")])
def test_a_set_whose_rename_fails_part_way_leaves_the_old_set_as_it_was(tmp_path, monkeypatch, order):
    """``write_set`` (an OBJ with its MTL and textures, ``--frames`` pictures) over an older set: a rename that
    failed part-way removed the files it had published, and the older files they had replaced were gone with
    them.  What the set replaced is now put back, what it added removed (here the new texture's rename fails)."""
    import errno
    import os

    from pmwm_codec import atomic

    old = {"m.obj": b"old obj", "m.mtl": b"old mtl"}
    for name, data in old.items():
        (tmp_path / name).write_bytes(data)
    real = os.replace

    def replace(src, dst):
        if str(dst).endswith("m_0.png"):
            raise OSError(errno.ENOSPC, "No space left on device", str(dst))
        real(src, dst)

    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError, match="No space left"):
        atomic.write_set({str(tmp_path / name): [b"new " + name.encode()] for name in order})
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == old
