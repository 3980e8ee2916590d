"""A machine's first runs: the helper process that compiles the kernels a command needs later
(:mod:`pmwm_codec.compile_ahead`) never outlives the command, prints nothing, writes only numba's cache,
compiles the very signatures the command asks for, and starts only where it can help."""

from __future__ import annotations

import importlib.util
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from pmwm_codec import cli, compile_ahead
from pmwm_codec.progressive import topology

ROOT = Path(__file__).resolve().parents[1]
NUMBA = importlib.util.find_spec("numba") is not None
needs_numba = pytest.mark.skipif(not NUMBA, reason="numba is not installed")

#: A command's process reduced to its helper: starts it (plan "decode"), prints its pid and, half a second later,
#: whether it is still at work, then ends as told (or waits to be killed).
_COMMAND = """
import os, signal, sys, time
from pmwm_codec import compile_ahead
helper = compile_ahead.start(("decode",))
print(helper.proc.pid, flush=True)
time.sleep(0.5)  # the helper at work (loading, noting the kernels' arguments, or compiling)
print("working" if helper.proc.poll() is None else "ended", flush=True)
how = sys.argv[1]
if how == "error":
    raise RuntimeError("the command failed")
if how == "exit":
    sys.exit(0)
time.sleep(60)  # until killed
"""


def _ended(pid: int) -> bool:
    """The process ``pid`` is gone or a zombie (ended, not reaped: its parent, killed, was not there to)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] == "Z"
    except FileNotFoundError:
        return True


def _default_sigint():
    signal.signal(signal.SIGINT, signal.SIG_DFL)  # a background job starts with SIGINT ignored; a terminal's has it


@needs_numba
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
@pytest.mark.parametrize("how", ["exit", "error", "ctrl-c", "sigterm", "sigkill"])
def test_the_helper_ends_with_the_command_however_the_command_ends(tmp_path, how):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NUMBA_CACHE_DIR": str(tmp_path / "cache")}  # cold: it compiles
    command = subprocess.Popen([sys.executable, "-c", _COMMAND, how], cwd=tmp_path, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, start_new_session=True, preexec_fn=_default_sigint)
    pid = None
    try:
        pid = int(command.stdout.readline())
        assert command.stdout.readline() == b"working\n"
        if how == "ctrl-c":  # to the command's process group, as a terminal sends it: the helper is in it too
            os.killpg(command.pid, signal.SIGINT)
        elif how in ("sigterm", "sigkill"):
            command.send_signal(signal.SIGTERM if how == "sigterm" else signal.SIGKILL)
        command.wait(timeout=60)
        deadline = time.monotonic() + 5
        while not _ended(pid) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert _ended(pid)
        out, err = command.communicate()
    finally:  # a failed test leaves nothing running
        if command.poll() is None:
            os.killpg(command.pid, signal.SIGKILL)
        if pid is not None and not _ended(pid):
            os.kill(pid, signal.SIGKILL)
    assert out == b""  # past the pid line: nothing from the helper
    expected = {"error": b"RuntimeError: the command failed", "ctrl-c": b"KeyboardInterrupt"}.get(how)
    if expected is None:
        assert err == b""
    else:
        assert expected in err and b"compile_ahead" not in err
    leftovers = [p for p in tmp_path.rglob("*") if p.is_file() and not p.name.endswith((".nbi", ".nbc"))]
    assert leftovers == []


@needs_numba
def test_the_helper_alone_says_nothing_writes_only_numbas_cache_and_exits(tmp_path):
    """Its job done (here on the suite's cache, warm or not), the helper ends by itself; its only output is the
    ``+kernel`` / ``-kernel`` lines to the command (none when every kernel loads from the cache)."""
    boot = [sys.executable, "-c", compile_ahead._BOOT, str(ROOT), "decode"]
    done = subprocess.run(boot, cwd=tmp_path, stdin=subprocess.PIPE, capture_output=True, timeout=600)
    assert done.returncode == 0 and done.stderr == b""
    assert all(line[:1] in (b"+", b"-") for line in done.stdout.splitlines())
    assert list(tmp_path.iterdir()) == []


@needs_numba
def test_the_helper_compiles_the_signatures_the_command_asks_for():
    """Each kernel (and helper a kernel calls) the helper compiles, it compiles for the argument types the
    compiled code path gives it (dtypes, writable or readonly arrays, no literal constants): an entry for other
    types would never be loaded."""
    import numba
    from numba.core import compiler, typed_passes

    calls = compile_ahead.capture(("encode", "decode"))
    assert {fn.__name__ for fn, _ in calls} >= {"_batch_kernel", "_mask_kernel", "_connectivity_kernel",
                                                 "_values_kernel", "dec_uint"}
    topology._load_numba()
    compile_ahead.small_job()  # the compiled path: its kernels get the signatures it calls them with
    dispatchers = {fn: topology.compiled(fn) for fn, _ in calls}
    for fn, dispatcher in list(dispatchers.items()):  # type the kernels called so: the helpers they call get theirs
        for sig in list(dispatcher.signatures):
            dispatcher.targetctx.refresh()
            typed_passes.type_inference_stage(dispatcher.typingctx, dispatcher.targetctx, compiler.run_frontend(fn),
                                              sig, None)
    for fn, args in calls:
        assert tuple(numba.typeof(a) for a in args) in [tuple(s) for s in dispatchers[fn].signatures], fn.__name__


@needs_numba
def test_no_helper_once_the_batch_kernel_is_in_the_cache(monkeypatch):
    """What is left to compile then (a decoder's ``dec_uint``, the owner layer's readers) is smaller than a
    helper's start."""
    from pmwm_codec.format import records_v2

    topology._load_numba()
    compile_ahead.small_job()  # the batch kernel compiled, or loaded: in the cache either way
    if not compile_ahead._batch_kernel_cached():
        pytest.skip(f"no numba cache here: {topology.compiled(records_v2._batch_kernel)._cache!r}")
    monkeypatch.setattr(compile_ahead, "_helper", None)
    assert compile_ahead.start(("decode",)) is None


@needs_numba
def test_a_numba_whose_cache_internals_moved_gets_no_hooks_and_no_helper(monkeypatch):
    """The hooks read numba's private cache attributes; where one is missing, the command compiles alone as it
    did before the helper, and numba's own cache methods stay in place (no hook to fail inside every compile)."""
    from numba.core.caching import Cache

    from pmwm_codec.format import records_v2

    topology._load_numba()
    cache = topology.compiled(records_v2._batch_kernel)._cache
    monkeypatch.delattr(cache, "_cache_path")
    monkeypatch.setattr(compile_ahead, "_helper", None)
    monkeypatch.setattr(compile_ahead, "_batch_kernel_cached", lambda: False)
    load, save = Cache.load_overload, Cache.save_overload
    assert compile_ahead.start(("decode",)) is None
    assert (Cache.load_overload, Cache.save_overload) == (load, save)


def test_the_capture_leaves_the_kernels_as_they_were():
    before = {(id(g), name): g[name] for g, name, fn, flags in topology._HELPERS}
    compile_ahead.capture(("decode",))
    assert topology._capture is None
    assert {(id(g), name): g[name] for g, name, fn, flags in topology._HELPERS} == before


def test_no_helper_where_it_cannot_help(monkeypatch):
    monkeypatch.delenv(compile_ahead.ENV, raising=False)
    monkeypatch.setattr(topology, "USE_NUMBA", True)
    monkeypatch.setattr(compile_ahead, "cpus", lambda: 2)
    assert compile_ahead.wanted()
    for off in ("0", "off", "no", "false", " OFF "):
        monkeypatch.setenv(compile_ahead.ENV, off)
        assert not compile_ahead.wanted()
    monkeypatch.setenv(compile_ahead.ENV, "1")
    assert compile_ahead.wanted()
    monkeypatch.setattr(compile_ahead, "cpus", lambda: 1)  # one CPU: the two processes would share it
    assert not compile_ahead.wanted()
    monkeypatch.setattr(compile_ahead, "cpus", lambda: 2)
    monkeypatch.setattr(topology, "USE_NUMBA", False)  # the numpy twins: nothing compiles
    assert not compile_ahead.wanted()


@pytest.mark.parametrize("argv, plan", [
    (["encode", "m.obj", "-o", "m.pmw"], ("encode",)),
    (["encode", "m.obj", "-o", "m.pmw", "--payload-version", "1"], ()),  # zstd columns: no payload kernel
    (["demo"], ("encode", "decode")),
    (["decode", "m.pmw", "-o", "m.obj"], ("decode",)),
    (["cut", "m.pmw", "-o", "c.pmw", "--chunks", "2"], ("decode",)),
    (["verify", "m.pmw", "--key", "k.json"], ("decode",)),
    (["verify", "m.obj", "--key", "k.json"], ()),  # the owner layer of a mesh: no decoder
    (["verify", "m.obj", "--reference", "m.pmw", "--key", "k.json"], ("decode",)),
    (["info", "m.pmw"], ()),
], ids=lambda v: " ".join(v) if isinstance(v, list) else None)
def test_a_helper_is_planned_only_for_the_payload_kernels_a_command_will_run(argv, plan):
    assert cli.ahead_plan(cli.build_parser().parse_args(argv)) == plan


def test_a_command_run_in_process_arms_no_helper(monkeypatch, tmp_path):
    """``main(argv)`` (the tests, a program calling pmw's main) is not a process of its own: no helper, as for the
    library, ``pmw batch`` and ``pmw serve``."""
    armed = []
    monkeypatch.setattr(compile_ahead, "arm", armed.append)
    assert cli.main(["decode", str(tmp_path / "none.pmw"), "-o", str(tmp_path / "x.obj")]) == 2
    assert armed == []


def test_the_command_waits_for_a_kernel_the_helper_is_compiling():
    """Told by the order of events, not by a clock: the save of ``m.k`` is held until the command's wait for another
    kernel has returned, so that wait cannot have waited for it; the wait for ``m.k`` must then see it saved.  (The
    test timed it from after the saving thread had started, whose 0.2 s sleep had then already begun: under load the
    wait ended 0.2 s after the sleep began and less than 0.2 s after the clock was read, 8 runs in 300.)"""
    helper = object.__new__(compile_ahead.Helper)
    helper.busy, helper.alive, helper.cond = {"m.k": 1}, True, threading.Condition()
    other_done = threading.Event()

    def saved():
        other_done.wait(10)  # (a wait_for("m.other") that waited for m.k ends when m.k is saved, after 10 s)
        time.sleep(0.2)  # the command has begun its wait for m.k (a wait_for that does not wait ends meanwhile)
        with helper.cond:
            helper.busy["m.k"] -= 1
            helper.cond.notify_all()

    saver = threading.Thread(target=saved)
    saver.start()
    helper.wait_for("m.other")  # not the helper's: no wait
    assert helper.busy["m.k"] == 1  # returned while m.k was still being compiled
    other_done.set()
    helper.wait_for("m.k")
    assert helper.busy["m.k"] == 0  # returned once m.k was saved, not before
    saver.join()
    helper.busy["m.k"] = 1
    helper.alive = False  # the helper ended (saved or not): nothing to wait for
    helper.wait_for("m.k")
