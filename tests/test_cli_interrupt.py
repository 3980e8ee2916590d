"""Ctrl-C at any moment of a ``pmw`` command: one line, ``pmw: error: interrupted``, exit 130, no traceback.

A signal is timing-dependent, so the tests place it: an import hook sends the process a real SIGINT
when a chosen module starts loading (start-up), and a KeyboardInterrupt raised inside a compiled
call is reproduced by the exception it comes back as (a SystemError caused by it).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh

ROOT = Path(__file__).resolve().parents[1]

#: Run ``pmw`` as the console script does, after installing a hook that sends this process SIGINT
#: when the module ``sys.argv[1]`` starts loading; the command is ``sys.argv[2:]``.
_SIGINT_ON_IMPORT = """
import os, signal, sys

class SigintOnImport:
    def __init__(self, name):
        self.name = name

    def find_spec(self, name, path=None, target=None):
        if name == self.name:
            sys.meta_path.remove(self)
            os.kill(os.getpid(), signal.SIGINT)
        return None

sys.meta_path.insert(0, SigintOnImport(sys.argv[1]))
sys.argv[1:] = sys.argv[2:]
from pmwm_codec.cli import main
sys.exit(main())
"""


def _default_sigint():
    # a shell's background job starts with SIGINT ignored; the command must see it as a terminal would
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@pytest.mark.parametrize("module", ["pmwm_codec.cli.common", "pmwm_codec.cli.encode", "PIL"])
@pytest.mark.parametrize("command", [["info", "x.pmw"], ["encode", "x.obj", "-o", "y.pmw"]], ids=["info", "encode"])
def test_sigint_while_the_command_loads_its_modules_is_one_line_and_exit_130(tmp_path, module, command):
    r = subprocess.run([sys.executable, "-c", _SIGINT_ON_IMPORT, module, *command], cwd=tmp_path,
                       env={**os.environ, "PYTHONPATH": str(ROOT)}, capture_output=True, text=True, timeout=120,
                       preexec_fn=_default_sigint)
    assert (r.returncode, r.stderr) == (130, "pmw: error: interrupted\n")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def small_mesh(tmp_path):
    path = tmp_path / "m.ply"
    write_mesh(path, shapes.icosphere(2, noise=0.01))
    return path


def _raise_from(cause):
    def encode(*args, **kwargs):
        try:
            raise cause
        except BaseException as exc:  # as CPython wraps an exception set under a returned result
            raise SystemError("CPUDispatcher(<function _live_mesh_kernel>) returned a result with an exception "
                              "set") from exc
    return encode


def test_an_interrupt_inside_a_compiled_kernel_is_interrupted_not_a_bug(monkeypatch, capsys, small_mesh, tmp_path):
    monkeypatch.setattr(pmwm_codec, "encode", _raise_from(KeyboardInterrupt()))
    assert main(["encode", str(small_mesh), "-o", str(tmp_path / "o.pmw"), "-q"]) == 130
    assert capsys.readouterr().err == "pmw: error: interrupted\n"


def test_a_system_error_without_an_interrupt_is_still_reported_as_a_bug(monkeypatch, capsys, small_mesh, tmp_path):
    monkeypatch.setattr(pmwm_codec, "encode", _raise_from(ValueError("inside")))
    assert main(["encode", str(small_mesh), "-o", str(tmp_path / "o.pmw"), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: unexpected SystemError:") and "a bug of pmw" in err and err.count("\n") == 1
