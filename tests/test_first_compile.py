"""A machine's first runs compile the numba kernels (about a minute for the first encode): the command line
says so once, at a terminal, when a kernel first compiles, and never when the kernels come from the cache."""

from __future__ import annotations

import importlib.util
import io

import pytest

from pmwm_codec import cli
from pmwm_codec.cli import common
from pmwm_codec.progressive import topology

pytestmark = pytest.mark.skipif(importlib.util.find_spec("numba") is None, reason="numba is not installed")


def _fresh_function():
    """A numba function this process has never compiled (a new closure each call: no cache entry)."""
    import numba

    scale = 3

    @numba.njit(cache=False)
    def f(x):
        return x * scale

    return f


def test_the_first_compile_calls_back_once_and_only_on_a_compile(monkeypatch):
    monkeypatch.setattr(topology, "_first_compile", [])
    topology._load_numba()
    calls = []
    topology.on_first_compile(lambda: calls.append(1))
    assert calls == []  # registering compiles nothing
    f = _fresh_function()
    f(2)
    assert calls == [1]
    f(3)  # the same signature: no compile
    _fresh_function()(4)  # another compile: the callback is spent
    assert calls == [1]


@pytest.mark.parametrize("tty", [True, False], ids=["terminal", "pipe"])
def test_the_command_line_explains_the_first_compile_at_a_terminal_only(monkeypatch, tty):
    monkeypatch.setattr(topology, "_first_compile", [])
    err = io.StringIO()
    monkeypatch.setattr("sys.stderr", err)
    monkeypatch.setattr(common, "_isatty", lambda stream: tty)
    cli._explain_first_compile()
    topology._load_numba()
    _fresh_function()(2)
    _fresh_function()(3)
    expected = f"\r{common.PROG}: note: {cli.FIRST_COMPILE}\n" if tty else ""
    assert err.getvalue() == expected
