"""Ctrl-C at any moment of a ``pmw`` command: one line, ``pmw: error: interrupted``, exit 130, no traceback.

A signal is timing-dependent, so the tests place it: an import hook sends the process a real SIGINT
when a chosen module starts loading (start-up), and a KeyboardInterrupt raised inside a compiled
call is reproduced by the exception it comes back as (a SystemError caused by it).
"""

from __future__ import annotations

import ast
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
#: when the module ``sys.argv[1]`` starts loading; the command is ``sys.argv[2:]``.  A module named
#: ``callback:NAME`` gets it while a weakref callback runs (as importlib's module locks run theirs), where
#: Python cannot raise a KeyboardInterrupt: it prints "Exception ignored in ..." and goes on.
_SIGINT_ON_IMPORT = """
import os, signal, sys, weakref

class SigintOnImport:
    def __init__(self, name):
        self.in_callback = name.startswith("callback:")
        self.name = name.removeprefix("callback:")

    def find_spec(self, name, path=None, target=None):
        if name == self.name:
            sys.meta_path.remove(self)
            if not self.in_callback:
                os.kill(os.getpid(), signal.SIGINT)
                return None
            gone = type("Gone", (), {})()
            self.ref = weakref.ref(gone, lambda _: [signal.raise_signal(signal.SIGINT)] + [i for i in range(9999)])
            del gone
        return None

sys.meta_path.insert(0, SigintOnImport(sys.argv[1]))
sys.argv[1:] = sys.argv[2:]
from pmwm_codec.cli import main
sys.exit(main())
"""


def _default_sigint():
    # a shell's background job starts with SIGINT ignored; the command must see it as a terminal would
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _run(tmp_path, argv, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", *argv], cwd=tmp_path, env={**os.environ, "PYTHONPATH": str(ROOT)},
                          capture_output=True, text=True, timeout=120, preexec_fn=_default_sigint, **kwargs)


def _interrupted_on_import(tmp_path, module, command) -> None:
    r = _run(tmp_path, [_SIGINT_ON_IMPORT, module, *command])
    assert (r.returncode, r.stderr) == (130, "pmw: error: interrupted\n")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("module", ["pmwm_codec.cli.common", "pmwm_codec.cli.encode", "PIL"])
@pytest.mark.parametrize("command", [["info", "x.pmw"], ["encode", "x.obj", "-o", "y.pmw"]], ids=["info", "encode"])
def test_sigint_while_the_command_loads_its_modules_is_one_line_and_exit_130(tmp_path, module, command):
    _interrupted_on_import(tmp_path, module, command)


@pytest.mark.parametrize("module", ["numpy", "pmwm_codec.mesh", "datetime"])
def test_sigint_while_the_console_script_imports_the_package_is_one_line_not_a_traceback(tmp_path, module):
    """``import pmwm_codec`` (the console script's first import, before :func:`main` runs) loaded numpy and the
    mesh module: a Ctrl-C in those ~0.1 s was a traceback.  They now load inside main's guard; and a Ctrl-C that
    numpy's compiled loading turns into an ImportError (its import of ``datetime`` interrupted) is still one
    ``interrupted`` line, not numpy's "Importing the numpy C-extensions failed"."""
    _interrupted_on_import(tmp_path, module, ["info", "x.pmw"])


def test_sigint_in_a_weakref_callback_while_modules_load_is_one_line_not_an_ignored_exception(tmp_path):
    """CI saw it at a real Ctrl-C 0.2 s into ``pmw info``: "Exception ignored in: <function
    _get_module_lock.<locals>.cb>", a traceback through pmw's own SIGINT handler, before the ``interrupted`` line."""
    _interrupted_on_import(tmp_path, "callback:pmwm_codec.cli.common", ["info", "x.pmw"])


def test_the_console_script_loads_nothing_but_the_package_and_its_errors_before_main():
    """What loads before :func:`main` runs is the window in which a Ctrl-C cannot be answered in one line."""
    code = "import sys; before = set(sys.modules); import pmwm_codec.cli; print(sorted(set(sys.modules) - before))"
    r = subprocess.run([sys.executable, "-c", code], env={**os.environ, "PYTHONPATH": str(ROOT)},
                       capture_output=True, text=True, timeout=60, check=True)
    loaded = set(ast.literal_eval(r.stdout.strip()))
    # ``__future__`` (a few lines: the package's ``from __future__ import annotations``) loads unless the
    # interpreter's start-up loaded it already (an editable install's .pth does)
    assert loaded - {"__future__"} == {"pmwm_codec", "pmwm_codec.cli", "pmwm_codec.errors"}


#: The console script as pip writes it (``[project.scripts] pmw = "pmwm_codec.cli:main"``).
_CONSOLE_SCRIPT = "import re, sys\nfrom pmwm_codec.cli import main\nsys.exit(main())"
#: Modules of the package the console script imports before :func:`main` runs (a few ms out of pmw's reach).
_BEFORE_MAIN = ("pmwm_codec/__init__.py", "pmwm_codec/errors.py", "pmwm_codec/cli/__init__.py")


@pytest.mark.parametrize("delay", [0, 0.01, 0.02, 0.03, 0.05, 0.08, 0.12, 0.2])
def test_a_ctrl_c_at_any_early_moment_is_never_a_traceback_from_pmw_or_what_it_loads(tmp_path, delay):
    """SIGINT sent at fixed moments of a start: the command ends killed by it before Python takes it (nothing
    said), with the one ``interrupted`` line and 130, or with its own answer when it ended first.  A traceback
    is CPython's own, from its start-up or the script's import line, before any of pmw runs: never in numpy,
    Pillow, or a module of the package past the few that the console script itself imports."""
    import re
    import time

    proc = subprocess.Popen([sys.executable, "-c", _CONSOLE_SCRIPT, "info", "x.pmw"], cwd=tmp_path,
                            env={**os.environ, "PYTHONPATH": str(ROOT)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, preexec_fn=_default_sigint)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    frames = re.findall(r'File "([^"]+)", line \d+, in (\S+)', err)
    # the package's own modules only: CI's virtual environment lies inside the checkout (.venv), and a Ctrl-C in
    # its site-packages' start-up hooks (setuptools' _distutils_hack) is CPython's start-up, not pmw
    package = os.path.join(str(ROOT), "pmwm_codec") + os.sep
    late = [(f, fn) for f, fn in frames if f.startswith(package) and not (f.endswith(_BEFORE_MAIN) and fn == "<module>")]
    assert not late and not [f for f, _ in frames if "/numpy/" in f or "/PIL/" in f], err
    if "Traceback" not in err:
        answer = "pmw: error: x.pmw: no such .pmw file\n"
        # the answer given, then killed by the signal on the way out (the default handler is back by then: seen
        # once under load, 0.2 s in)
        assert (proc.returncode, err) in ((-signal.SIGINT, ""), (130, "pmw: error: interrupted\n"), (2, answer),
                                          (-signal.SIGINT, answer)), err


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
