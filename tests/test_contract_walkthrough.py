"""Command-line behaviours a contract walkthrough (README, DESIGN.md §5) found apart from the README.

* ``pmw demo --out -`` made a folder named ``-`` in the current one and wrote the demo there, exit 0; the
  README's outputs are "never ``-`` (no output goes to standard output; nor is ``--frames -``)", and
  ``verify --frames -`` is refused.  It is now refused the same way: exit 2, one line, nothing made.
"""

from __future__ import annotations

import os

from pmwm_codec.cli import main


def test_demo_refuses_out_dash_and_makes_no_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", "-"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: -: ") and "standard output" in err and err.count("\n") == 1
    assert os.listdir(tmp_path) == []
