"""Shared pieces of the ``pmw`` subcommands: exit codes, one-line errors, JSON, progress.

Every subcommand module exposes ``add_parser(subparsers)`` and ``run(args) -> int``;
:mod:`pmwm_codec.cli` wires them together and maps errors to exit status 2.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import math
import os
import sys
import threading
import time

EXIT_OK = 0
EXIT_NOT_AUTHENTIC = 1  # verify ran; the mark is absent, wrong or too weak to decide
EXIT_BAD_INPUT = 2  # bad input or usage (argparse uses 2 too)
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT, as a shell reports it)
EXIT_TERMINATED = 143  # SIGTERM (128 + 15): ``timeout``, systemd, ``docker stop``, a CI cancel

PROG = "pmw"


class UsageError(Exception):
    """A bad combination of arguments found after parsing: exit 2, one line."""


class ArgumentParser(argparse.ArgumentParser):
    """argparse with one-line errors (``pmw: error: ...``) and exit status 2."""

    def error(self, message):
        self.exit(EXIT_BAD_INPUT, f"{PROG}: error: {message} (see '{self.prog} --help')\n")


def error_line(message) -> str:
    """The one line printed for a failed command (newlines folded)."""
    text = " ".join(str(message).split()) or "unknown error"
    return f"{PROG}: error: {text}"


class Terminated(KeyboardInterrupt):
    """A SIGTERM (``timeout``, systemd, ``docker stop``, a CI cancel), raised in the main thread while a command
    runs (:func:`sigterm_stops`): it takes the path a Ctrl-C takes (what was being written discarded, a batch's
    cluster closed and its ledger whole), and ends as ``terminated``, exit :data:`EXIT_TERMINATED`."""


@contextlib.contextmanager
def sigterm_stops():
    """SIGTERM raises :class:`Terminated` inside the block (once: the cleanup that follows is not cut short by
    another); only the main thread may set a handler, elsewhere nothing changes."""
    import signal

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def stop(signum, frame):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        raise Terminated()

    previous = signal.signal(signal.SIGTERM, stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def interrupted(exc: BaseException | None = None) -> int:
    """Say that the command was stopped (one line on stderr): ``terminated`` and :data:`EXIT_TERMINATED` when
    ``exc`` stands for a SIGTERM (:func:`raised_by_interrupt`), else ``interrupted`` and :data:`EXIT_INTERRUPTED`."""
    if isinstance(raised_by_interrupt(exc) if exc is not None else None, Terminated):
        sys.stderr.write(error_line("terminated") + "\n")
        return EXIT_TERMINATED
    sys.stderr.write(error_line("interrupted") + "\n")
    return EXIT_INTERRUPTED


def raised_by_interrupt(exc: BaseException) -> KeyboardInterrupt | None:
    """The KeyboardInterrupt (a Ctrl-C, or a :class:`Terminated` SIGTERM) that ``exc`` stands for: ``exc`` itself,
    or the one it was raised because of (a KeyboardInterrupt raised inside a compiled call, a numba kernel's,
    comes back as a SystemError "returned a result with an exception set" whose cause is the KeyboardInterrupt);
    None when it stands for neither."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return exc
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return None


def os_error_message(exc: OSError) -> str:
    name = exc.filename if exc.filename is not None else ""
    why = exc.strerror or str(exc)
    return f"{name}: {why}" if name else why


def nonblank_path(option: str, what: str = "file"):
    """An argparse ``type`` for a path option: refuses an empty or white-space name up front (an unset
    variable in ``--key $KEY`` would otherwise be carried to the step that writes or reads it)."""
    def parse(text):
        if not text.strip():
            raise argparse.ArgumentTypeError(f"an empty path ({text!r}) names no {what} (an unset variable in "
                                             f"'{option} $VAR'?)")
        return text
    return parse


def jsonable(value):
    """Copy of ``value`` where non-finite floats become None (``Infinity`` is not JSON)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [jsonable(v) for v in value]
    if hasattr(value, "item") and callable(value.item):  # numpy scalar
        return jsonable(value.item())
    return value


def print_json(obj) -> None:
    """Exactly one JSON object on stdout."""
    sys.stdout.write(json.dumps(jsonable(obj), allow_nan=False) + "\n")
    sys.stdout.flush()


def notice(text: str) -> None:
    """One ``pmw: note: ...`` line on stderr: something the user asked for was adjusted."""
    sys.stderr.write(f"{PROG}: note: {text}\n")


def fmt_float(value, digits: int = 2, unit: str = "") -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and math.isinf(value):
        return "inf"
    return f"{value:.{digits}f}{unit}"


class Progress:
    """A one-line progress bar on stderr, shown only when stderr is a terminal.

    ``Progress(enabled)(label, fraction)`` redraws; :meth:`done` clears the line.  The
    line ends with the seconds elapsed, redrawn every ``tick`` seconds by a daemon thread,
    so a long stage that reports no progress of its own still shows that it is alive.
    """

    def __init__(self, enabled: bool = True, width: int = 28, tick: float = 1.0):
        self.enabled = bool(enabled) and _isatty(sys.stderr)
        self.width = width
        self.tick = tick
        self._shown = False
        self._last = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = None
        self._t0 = time.monotonic()

    def __call__(self, label: str, fraction: float) -> None:
        if not self.enabled:
            return
        with self._lock:
            self._last = (label, min(max(float(fraction), 0.0), 1.0))
            self._draw()
        if self._thread is None and self.tick:
            self._thread = threading.Thread(target=self._heartbeat, daemon=True)
            self._thread.start()

    def _draw(self) -> None:
        label, f = self._last
        full = int(round(f * self.width))
        bar = "#" * full + "-" * (self.width - full)
        sys.stderr.write(f"\r{label[:24]:<24} [{bar}] {100 * f:3.0f}% {time.monotonic() - self._t0:5.0f}s")
        sys.stderr.flush()
        self._shown = True

    def _heartbeat(self) -> None:
        while not self._stop.wait(self.tick):
            with self._lock:
                if self._last is not None and self._shown:
                    self._draw()

    def done(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with self._lock:
            if self._shown:
                sys.stderr.write("\r" + " " * (self.width + 40) + "\r")
                sys.stderr.flush()
                self._shown = False


#: Labels of the encoder stages on the progress bar.
STAGES = {"simplify": "simplifying", "records": "building splits", "write": "writing",
          "measure": "measuring distortion"}
#: Share of the whole encode each stage spans, in the order they run: the distortion is
#: measured (from vertex displacements by default: cheap) before anything is written.
STAGE_SPANS = {"simplify": (0.0, 0.75), "records": (0.75, 0.9), "measure": (0.9, 0.95), "write": (0.95, 1.0)}


def stage_progress(progress):
    """Adapt the library's ``progress(stage, fraction)`` to one bar over the whole encode
    that only moves forward (an unknown stage or a fraction going back never lowers it)."""
    high = [0.0]

    def report(stage, fraction):
        lo, hi = STAGE_SPANS.get(stage, (high[0], high[0]))
        high[0] = max(high[0], lo + (hi - lo) * min(max(float(fraction), 0.0), 1.0))
        progress(STAGES.get(stage, stage), high[0])
    return report


def _isatty(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


@contextlib.contextmanager
def naming(path):
    """Prefix library errors raised inside the block with the input's name (``stdin`` for ``-``)."""
    from pmwm_codec.errors import PmwError

    name = "stdin" if path == "-" else os.fspath(path)
    try:
        yield
    except PmwError as exc:
        text = str(exc)
        if name in text or os.path.basename(name) in text:
            raise
        raise UsageError(f"{name}: {text}") from None


def check_output_path(path, what: str = "output", inputs=(), key: bool = False) -> None:
    """Fail early (UsageError) where the library would refuse to publish ``path`` before any work
    (:func:`pmwm_codec.options.check_output_path`, the one home of those rules: ``-``, a directory,
    a device, FIFO or socket, a missing or read-only directory, one of the ``inputs`` files, a
    watermark key file unless the output is itself a ``key``), and when standard input (an input
    ``-``) is read from ``path``."""
    from pmwm_codec.errors import OptionError, WatermarkKeyError
    from pmwm_codec.options import check_output_path as checked_output_path

    path = os.fspath(path)
    if path != "-" and "-" in inputs and _stdin_is(path):
        raise UsageError(f"{path}: is also the input (standard input is read from it); give the {what} another "
                         "name (writing it would replace the input)")
    try:
        checked_output_path(path, what, inputs=[s for s in inputs if s is not None and s != "-"], key=key)
    except (OptionError, WatermarkKeyError) as exc:
        raise UsageError(str(exc)) from None


def _stdin_is(path) -> bool:
    """Whether standard input is read from the existing file ``path`` (``pmw cut - -o x.pmw < x.pmw``)."""
    try:
        return os.path.samestat(os.fstat(sys.stdin.fileno()), os.stat(path))
    except (OSError, ValueError, AttributeError, io.UnsupportedOperation):  # no such file, stdin without a descriptor
        return False


def check_pmw_output(path, inputs=()) -> None:
    """:func:`check_output_path` for a ``.pmw``, which is a GLB: not named as another mesh format
    (``.obj``, ``.ply``, ``.stl``, ``.gltf``: a mesh of that name would be replaced by a GLB)."""
    from pmwm_codec.errors import OptionError
    from pmwm_codec.options import refuse_mesh_suffix

    check_output_path(path, ".pmw", inputs=inputs)
    try:
        refuse_mesh_suffix(path)
    except OptionError as exc:
        raise UsageError(str(exc)) from None


def check_input_file(path, what: str = "file", stdin: bool = False) -> None:
    """Fail (UsageError) unless ``path`` is an existing file, or ``-`` where ``stdin`` says standard input is read
    (a ``.pmw``; a mesh, key or image is read from a file: ``-`` was "-: no such file")."""
    if path == "-":
        if stdin:
            return
        raise UsageError(f"-: give the {what} by its name (standard input is read only for a .pmw)")
    if not path.strip():  # an unset variable: "pmw: error: : no such file" named nothing
        raise UsageError(f"an empty path ({path!r}) names no {what} (an unset variable?)")
    from pmwm_codec.sources import shown_path  # as the library names it: a key's JSON given as a path never echoed

    if not os.path.exists(path):
        raise UsageError(f"{shown_path(path)}: no such {what}")
    if os.path.isdir(path):
        raise UsageError(f"{shown_path(path)}: is a directory, not a {what}")


def run_command(args) -> int:
    """Run ``args.run(args)`` behind the safety net; returns the exit status.

    Named errors (PmwError, UsageError, OSError) keep their one-line messages; a
    MemoryError, a RecursionError or any other exception also ends as one line
    and exit 2 (never 1: that is ``verify``'s "not authentic"), without a traceback.
    A Ctrl-C is ``interrupted`` and exit 130, a SIGTERM ``terminated`` and exit 143 (:func:`sigterm_stops`),
    also when it surfaces wrapped in another exception (:func:`raised_by_interrupt`).
    Files are not cleaned up here: every output is published whole or not at all by
    the library (:func:`pmwm_codec.format.glb.write_parts`, :mod:`pmwm_codec.atomic`),
    so a failure leaves the old files or the new ones, never a part of one.
    """
    return _run_mapped(args)


def _run_mapped(args) -> int:
    from pmwm_codec.errors import PmwError

    try:
        with sigterm_stops():
            return int(args.run(args))
    except BrokenPipeError:  # `pmw info x.pmw | head`: the reader left; not an error of ours
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_OK
    except (PmwError, UsageError) as exc:
        message = str(exc)
    except OSError as exc:
        message = os_error_message(exc)
    except KeyboardInterrupt as exc:
        return interrupted(exc)
    except MemoryError:
        message = "out of memory: the input is too large for this machine"
    except RecursionError:
        message = "the input is nested too deeply"
    except Exception as exc:  # the last net: one line, exit 2, never a traceback
        if raised_by_interrupt(exc) is not None:
            return interrupted(exc)
        message = f"unexpected {type(exc).__name__}: {exc} (a bug of pmw: please report it with the input)"
    sys.stderr.write(error_line(message) + "\n")
    return EXIT_BAD_INPUT
