"""``pmw batch encode`` and what lies at its ledger's place: a FIFO or a link to a device is refused
in one line before anything is read or made (a FIFO hung the run for ever, a link to ``/dev/zero`` was read until
memory ran out), a row edited by hand into something the run cannot write back (``NaN``) is left out and its asset
redone (the run stopped with "unexpected ValueError")."""

from __future__ import annotations

import json
import os
import threading
from pathlib import Path

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, read_ledger  # noqa: E402
from pmwm_codec.cli import main  # noqa: E402


def _library(tmp_path: Path, count: int = 2) -> tuple[Path, Path]:
    src = tmp_path / "src"
    src.mkdir()
    for i in range(count):
        write_mesh(src / f"m{i}.obj", shapes.icosphere(2, noise=0.01, seed=i + 1))
    from PIL import Image

    wm = tmp_path / "wm.png"
    Image.fromarray((np.indices((8, 8)).sum(0) % 2 * 255).astype(np.uint8)).save(wm)
    return src, wm


class _Unblock:
    """Opens the FIFO ``path`` (read and write) every second after ``delay`` seconds and closes it again: a reader
    or a writer blocked in ``open()`` (the code before the fix, at both) goes on and fails instead of hanging the
    test for ever."""

    def __init__(self, path: Path, delay: float = 5.0):
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, args=(path, delay), daemon=True)

    def _run(self, path, delay):
        wait = delay
        while not self.stop.wait(wait):
            wait = 1.0
            try:
                os.close(os.open(path, os.O_RDWR | os.O_NONBLOCK))
            except OSError:  # gone
                return

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.thread.join()


def test_a_ledger_that_is_a_fifo_is_refused_in_one_line_and_nothing_is_made(tmp_path, capsys):
    src, wm = _library(tmp_path, 1)
    out = tmp_path / "out"
    out.mkdir()
    fifo = out / LEDGER_NAME
    os.mkfifo(fifo)
    with _Unblock(fifo):
        status = main(["batch", "encode", str(src), "-o", str(out), "--watermark", str(wm), "--workers", "1", "-q"])
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1, err
    assert err.startswith(f"pmw: error: {fifo}: is not a regular file"), err
    assert sorted(p.name for p in out.iterdir()) == [LEDGER_NAME]


def test_a_ledger_that_links_elsewhere_is_never_read(tmp_path):
    target = tmp_path / "elsewhere.jsonl"
    target.write_text(json.dumps({"input": "/lib/a.obj", "status": "ok"}) + "\n")
    link = tmp_path / LEDGER_NAME
    link.symlink_to(target)
    with pytest.raises(OSError, match="is a symbolic link"):
        read_ledger(link)


def test_a_ledger_linked_to_a_device_is_refused_before_a_byte_is_read(tmp_path, capsys, monkeypatch):
    if not os.path.exists("/dev/zero"):
        pytest.skip("no /dev/zero")
    src, wm = _library(tmp_path, 1)
    out = tmp_path / "out"
    out.mkdir()
    (out / LEDGER_NAME).symlink_to("/dev/zero")
    import builtins

    real_open, ledger = builtins.open, str(out / LEDGER_NAME)

    def guarded_open(file, *args, **kwargs):  # the code before read /dev/zero through the link until memory ran out
        if isinstance(file, (str, os.PathLike)) and os.fspath(file) == ledger:
            raise AssertionError("the ledger was opened through its link")
        return real_open(file, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded_open)
    status = main(["batch", "encode", str(src), "-o", str(out), "--watermark", str(wm), "--workers", "1", "-q"])
    monkeypatch.undo()
    err = capsys.readouterr().err
    assert status == 2 and err.count("\n") == 1 and "is a symbolic link" in err, err
    assert sorted(p.name for p in out.iterdir()) == [LEDGER_NAME]


def test_a_row_edited_to_hold_nan_is_left_out_and_its_asset_redone(tmp_path, capsys):
    src, wm = _library(tmp_path, 2)
    out = tmp_path / "out"
    argv = ["batch", "encode", str(src), "-o", str(out), "--watermark", str(wm), "--workers", "1", "--json"]
    assert main(argv) == 0
    capsys.readouterr()
    ledger = out / LEDGER_NAME
    lines = ledger.read_text().splitlines()
    edited = [line.replace('"vertices": 162', '"vertices": NaN') if "m0.obj" in line else line for line in lines]
    assert edited != lines
    ledger.write_text("\n".join(edited) + "\n")
    assert [Path(r["input"]).name for r in read_ledger(ledger)] == ["m1.obj"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    doc = json.loads(captured.out)
    assert (doc["ok"], doc["skipped"], doc["failed"]) == (1, 1, 0) and captured.err == ""
    last = {Path(r["input"]).name: r["status"] for r in read_ledger(ledger)[-2:]}
    assert last == {"m0.obj": "ok", "m1.obj": "skipped"}


@pytest.mark.parametrize("text", ['"vertices": "many"', '"bytes": true', '"input_sha256": 5'])
def test_a_row_whose_fields_have_other_types_is_left_out(tmp_path, text):
    ledger = tmp_path / LEDGER_NAME
    good = {"input": "/lib/a.obj", "input_sha256": "0" * 64, "output": "/out/a.obj.pmw", "status": "ok",
            "bytes": 10, "vertices": 4}
    bad = json.dumps(dict(good, input="/lib/b.obj"))
    field = text.split(":")[0].strip('"')
    bad = bad.replace(f'"{field}": {json.dumps(good[field])}', text)
    assert text in bad
    ledger.write_text(json.dumps(good) + "\n" + bad + "\n")
    assert [r["input"] for r in read_ledger(ledger)] == ["/lib/a.obj"]
