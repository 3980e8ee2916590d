"""``pmw batch`` on a full disk: the ledger row that cannot be written is taken back whole (it was left cut), and
the one-line error names the ledger, the asset whose row was lost and how many are left (it said only "No
space left on device")."""

from __future__ import annotations

import errno
import os

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, read_ledger  # noqa: E402
from pmwm_codec.batch.ledger import LedgerWriter  # noqa: E402
from pmwm_codec.cli import main  # noqa: E402

ROW = {"input": "/lib/a.obj", "output": "/out/a.obj.pmw", "status": "ok", "bytes": 10}


def test_a_ledger_on_a_full_device_is_named_with_the_asset_whose_row_was_lost(tmp_path):
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    ledger = tmp_path / LEDGER_NAME
    with LedgerWriter(ledger) as writer, pytest.raises(OSError) as caught:
        full = os.open("/dev/full", os.O_WRONLY)  # the ledger's descriptor now writes to a full device (a
        os.dup2(full, writer._fd)  # ledger that is a symlink is refused, so the device is not linked in)
        os.close(full)
        writer.write(ROW)
    assert caught.value.errno == errno.ENOSPC and caught.value.filename == str(ledger)
    assert "the row of /lib/a.obj was not written" in str(caught.value)


def test_a_row_written_in_part_is_taken_back_so_no_cut_line_is_left(tmp_path, monkeypatch):
    ledger = tmp_path / LEDGER_NAME
    with LedgerWriter(ledger) as writer:
        writer.write(ROW)
        real = os.write

        def full_after_ten_bytes(fd, data):
            if len(data) > 10:
                return real(fd, bytes(data[:10]))
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        monkeypatch.setattr(os, "write", full_after_ten_bytes)
        try:
            with pytest.raises(OSError, match="No space left on device"):
                writer.write(dict(ROW, input="/lib/b.obj"))
        finally:
            monkeypatch.setattr(os, "write", real)
    data = ledger.read_bytes()
    assert data.endswith(b"\n") and data.count(b"\n") == 1
    assert [r["input"] for r in read_ledger(ledger)] == ["/lib/a.obj"]


def test_a_run_whose_ledger_fills_the_disk_stops_in_one_line_naming_the_ledger_and_the_assets_left(tmp_path,
                                                                                                  monkeypatch, capsys):
    src, out = tmp_path / "src", tmp_path / "out"
    src.mkdir()
    for i in range(3):
        write_mesh(src / f"m{i}.obj", shapes.icosphere(2, noise=0.01, seed=i + 1))
    from PIL import Image

    Image.fromarray((np.indices((8, 8)).sum(0) % 2 * 255).astype(np.uint8)).save(tmp_path / "wm.png")
    real, rows = LedgerWriter.write, []

    def full_after_one_row(self, row):
        if rows:
            os_error = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
            raise OSError(errno.ENOSPC, f"{os_error.strerror} (the row of {row['input']} was not written)", self.path)
        rows.append(row)
        real(self, row)

    monkeypatch.setattr(LedgerWriter, "write", full_after_one_row)
    assert main(["batch", "encode", str(src), "-o", str(out), "--watermark", str(tmp_path / "wm.png"),
                 "--workers", "1", "-q"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"pmw: error: {out / LEDGER_NAME}: No space left on device"), err
    assert "the row of " + str(src) in err and "the run stopped with 2 of 3 assets not recorded" in err
    assert len(read_ledger(out / LEDGER_NAME)) == 1
