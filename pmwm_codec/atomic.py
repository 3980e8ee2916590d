"""Writing files so that a failure at any moment leaves the old file or the new one, whole.

Contract
--------
* :func:`stage` writes the bytes of a file-to-be beside its target and fsyncs them; where
  the platform allows (Linux ``O_TMPFILE``) the staged file has **no name** until
  :func:`publish`, so a process killed while writing (SIGKILL, the OOM killer) leaves
  nothing behind; elsewhere it is a hidden ``.NAME.XXXX.tmp`` that :func:`discard` removes.
* :func:`publish` moves a staged file over its target with one ``rename`` (a symlink at
  the target is replaced, never followed) and fsyncs the directory.  A target that exists and
  is neither a regular file nor a symlink (a device such as ``/dev/null``, a FIFO, a socket, a
  directory) is never replaced: :func:`stage` and :func:`publish` refuse it
  (:func:`check_replaceable`).
* Modes: ``mode=None`` gives ``0666 & ~umask`` (as ``open`` would); a given mode (keys:
  0600) is set with ``fchmod`` whatever the umask.
* Errors name the file asked for (an ``OSError`` whose ``filename`` is the target: "File too
  large", "No space left on device"), never a temporary name; temporary names are cut to fit the
  file system's 255-byte limit on a name.
* :func:`write_stream` writes to a caller's binary file object, which cannot be atomic: every byte
  is written (a raw file's short writes are written again) or an error says how many were.
* :func:`write_atomic` = stage + publish; :func:`write_set` writes several files whole or not at
  all (every one staged, then all published with signals held back); :func:`directory_lock` serialises writers of
  the same directories (``flock`` on the directories themselves: nothing is left on
  disk, and the lock dies with its process); :func:`signals_deferred` holds SIGINT,
  SIGTERM and SIGHUP back while a pair of files is published.

Test hook: :func:`fault_point` (``PMWM_FAULT=<point>:<SIGNAL>`` in the environment) sends
the process that signal when it reaches the named point; ``PMWM_FAULT=<point>@<N>:<SIGNAL>`` only the N-th time
it reaches it (``batch-row-taken@3:STOP``: the batch run stops itself as it takes its third result); it does
nothing otherwise.  Points: ``stage-written`` (here), ``measured``, ``staged``, ``key-published``, ``published``
(:mod:`pmwm_codec.stream.encoder`), ``batch-row-taken`` (:mod:`pmwm_codec.batch.run`: a result taken, its ledger
row not yet written).
"""

from __future__ import annotations

import contextlib
import errno
import os
import secrets
import signal
import stat
import tempfile
from dataclasses import dataclass

__all__ = ["Staged", "stage", "publish", "discard", "write_atomic", "write_set", "write_stream", "directory_lock",
           "signals_deferred", "fault_point", "current_umask", "check_replaceable"]

_DEFERRED_SIGNALS = {signal.SIGINT, signal.SIGTERM, signal.SIGHUP}


@dataclass
class Staged:
    """A written, fsynced file waiting for :func:`publish`: ``fd`` open (or -1 once closed),
    ``temp`` its visible temporary name (None while it has none), ``path`` the target."""

    fd: int
    temp: str | None
    path: str

    @property
    def directory(self) -> str:
        return os.path.dirname(os.path.abspath(self.path))


def current_umask() -> int:
    """The process umask (read from /proc where possible, so nothing is changed)."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("Umask:"):
                    return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


#: The longest file name (bytes) most file systems take (NAME_MAX); a temporary name is kept within it.
NAME_MAX = 255


def _temp_stem(path: str) -> str:
    """The start of ``path``'s temporary names: ``.NAME`` with NAME cut so that ``.NAME.<12 hex>.tmp`` (or
    mkstemp's ``.NAME.<8 chars>.tmp``) fits :data:`NAME_MAX` bytes (a 250-byte name is valid; its
    temporary name must be too)."""
    base = os.path.basename(os.path.abspath(path))
    while len(os.fsencode(base)) > NAME_MAX - 19:
        base = base[:-1]
    return "." + base


def _temp_name(path: str) -> str:
    directory = os.path.dirname(os.path.abspath(path))
    return os.path.join(directory, f"{_temp_stem(path)}.{secrets.token_hex(6)}.tmp")


@contextlib.contextmanager
def _naming(path: str):
    """An OSError raised inside the block names ``path``, the file asked for (a write that fails with
    "File too large" names no file; a rename names the temporary file first)."""
    try:
        yield
    except OSError as exc:
        if exc.filename == path and exc.filename2 is None:
            raise
        raise OSError(exc.errno, exc.strerror or str(exc), path) from None


def check_replaceable(path) -> None:
    """OSError unless ``path`` is free, a regular file or a symlink: a rename over a device, a FIFO
    or a socket would put a regular file in its place (``-o /dev/null`` run as root)."""
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not (stat.S_ISREG(st.st_mode) or stat.S_ISLNK(st.st_mode)):
        kind = "a directory" if stat.S_ISDIR(st.st_mode) else "not a regular file (a device, FIFO or socket)"
        raise OSError(errno.EEXIST, f"{os.fspath(path)}: is {kind}; refusing to replace it: give a file name")


def _open_staged(path: str, mode: int | None) -> Staged:
    """An empty file in ``path``'s directory: nameless (O_TMPFILE) if possible."""
    check_replaceable(path)
    directory = os.path.dirname(os.path.abspath(path))
    flags = os.O_WRONLY | getattr(os, "O_CLOEXEC", 0)
    if hasattr(os, "O_TMPFILE") and os.path.isdir("/proc/self/fd"):
        try:
            fd = os.open(directory, flags | os.O_TMPFILE, 0o666 if mode is None else mode)
            if mode is not None:
                os.fchmod(fd, mode)
            return Staged(fd, None, path)
        except OSError:
            pass  # the file system has no O_TMPFILE: a named temporary file
    try:
        fd, temp = tempfile.mkstemp(dir=directory, prefix=_temp_stem(path) + ".", suffix=".tmp")
    except OSError as exc:  # name the file asked for, not the temporary one
        raise OSError(exc.errno, f"cannot write a file in {directory} ({exc.strerror})", path) from None
    try:
        os.fchmod(fd, (0o666 & ~current_umask()) if mode is None else mode)
    except BaseException:
        os.close(fd)
        os.unlink(temp)
        raise
    return Staged(fd, temp, path)


def stage(path, parts, mode: int | None = None) -> Staged:
    """Write the bytes-like ``parts`` to a staged file for ``path`` and fsync it.

    On any exception nothing is left behind and the exception propagates.
    """
    staged = _open_staged(os.fspath(path), mode)
    try:
        with _naming(staged.path):
            view_parts = (memoryview(p).cast("B") for p in parts)
            for part in view_parts:
                while part:
                    part = part[os.write(staged.fd, part):]
            fault_point("stage-written")
            os.fsync(staged.fd)
    except BaseException:
        discard(staged)
        raise
    return staged


def publish(staged: Staged) -> None:
    """Move the staged file over its target (one rename) and make it durable."""
    check_replaceable(staged.path)  # before the staged file gets a name: nothing to clean up
    with _naming(staged.path):
        if staged.temp is None:
            temp = _temp_name(staged.path)
            proc = os.open("/proc/self/fd", os.O_RDONLY)
            try:  # linkat(proc, "fd", AT_FDCWD, temp, AT_SYMLINK_FOLLOW): name the nameless file
                os.link(str(staged.fd), temp, src_dir_fd=proc, follow_symlinks=True)
            finally:
                os.close(proc)
            staged.temp = temp
        os.close(staged.fd)
        staged.fd = -1
        os.replace(staged.temp, staged.path)
    staged.temp = None
    _fsync_directory(staged.directory)


def discard(staged: Staged | None) -> None:
    """Forget a staged file (close it, remove its temporary name); never raises."""
    if staged is None:
        return
    if staged.fd >= 0:
        with contextlib.suppress(OSError):
            os.close(staged.fd)
        staged.fd = -1
    if staged.temp is not None:
        with contextlib.suppress(OSError):
            os.unlink(staged.temp)
        staged.temp = None


def write_atomic(path, parts, mode: int | None = None) -> int:
    """Write ``parts`` to ``path`` atomically (old file or new file, whole); returns the byte count."""
    sizes = []  # parts may be a generator (text written a block at a time): counted as they are written
    staged = stage(path, (_counted(p, sizes) for p in parts), mode)
    try:
        publish(staged)
    except BaseException:
        discard(staged)
        raise
    return sum(sizes)


def _counted(part, sizes: list):
    view = memoryview(part).cast("B")
    sizes.append(len(view))
    return view


def write_set(files: dict) -> None:
    """Write ``files`` (``{path: bytes-like parts}``) as one set: every file is staged (:func:`stage`), and
    only when all are staged are they published, one rename each, with SIGINT / SIGTERM / SIGHUP held back
    (:func:`signals_deferred`).  A failure or an interrupt before that leaves none of them; a rename failing
    part-way puts back what the set had already replaced (each file it replaced is kept under a temporary
    name, a hard link, until the whole set is in place) and removes what it had added, then the exception
    propagates: the old set, as it was."""
    staged, kept = [], {}
    try:
        for path, parts in files.items():
            staged.append(stage(path, parts))
        with signals_deferred():
            done = []
            try:
                for item in staged:
                    kept[item.path] = _keep(item.path)
                    try:
                        publish(item)
                    finally:
                        if item.fd < 0 and item.temp is None:  # renamed into place (its directory's fsync may fail)
                            done.append(item.path)
            except BaseException:
                for path in done:
                    with contextlib.suppress(OSError):
                        if kept.get(path) is None:
                            os.unlink(path)
                        else:
                            os.replace(kept.pop(path), path)
                raise
    finally:
        for item in staged:
            discard(item)  # a published one is closed and nameless already: nothing to do
        for old in kept.values():
            if old is not None:
                with contextlib.suppress(OSError):
                    os.unlink(old)


def _keep(path: str) -> str | None:
    """A temporary second name (a hard link) of the regular file at ``path``, which :func:`write_set` puts back if
    the set fails after replacing it; None when there is none (no file there, or one the file system cannot link:
    it is then lost with the set, as before)."""
    if not os.path.isfile(path) or os.path.islink(path):
        return None
    temp = _temp_name(path)
    try:
        os.link(path, temp, follow_symlinks=False)
    except OSError:
        return None
    return temp


def write_stream(stream, parts, what: str = "dst") -> int:
    """Write every byte of the bytes-like ``parts`` to the caller's binary file object ``stream``, then
    flush it; returns the byte count.

    A raw file's ``write()`` may take less than it is given and return the count (a pipe, a
    socket): the rest is written again until all is.  A count of 0, None from an
    :class:`io.RawIOBase` (a non-blocking file that is not ready) or a ``write()`` that refuses
    bytes (a text stream) is an :class:`~pmwm_codec.errors.OptionError` naming ``what`` and how
    many bytes went out; a ``write()`` of any other object that returns None (a file-like object
    without a return value) is taken to have written everything.  A caller's stream cannot be
    written atomically: after an error the bytes already written stay in it.
    """
    import io
    import numbers

    from .errors import OptionError

    parts = list(parts)  # an iterable is read once: a generator of text blocks (write_atomic takes one too)
    total = sum(len(memoryview(p).cast("B")) for p in parts)
    done = 0
    for part in parts:
        view = memoryview(part).cast("B")
        given = part  # the part itself first (file-likes that want bytes), what is left of it after a short write
        while view:
            try:
                count = stream.write(given)
            except TypeError as exc:  # a text stream: str only
                raise OptionError(f"{what}: the file object's write() refused bytes ({exc}): open the file in "
                                  "binary mode ('wb')") from None
            if count is None and not isinstance(stream, io.RawIOBase):
                count = len(view)
            if isinstance(count, bool) or not isinstance(count, numbers.Integral) or not 0 < count <= len(view):
                why = ("gave None (a non-blocking file that is not ready)" if count is None else
                       "wrote nothing" if count == 0 else
                       f"returned {count} for {len(view):,} bytes" if isinstance(count, numbers.Integral) else
                       f"returned a {type(count).__name__}, not a byte count")
                raise OptionError(f"{what}: the file object's write() {why} after {done:,} of {total:,} bytes: "
                                  "the output is incomplete")
            done += count
            view = given = view[count:]
    flush = getattr(stream, "flush", None)
    if callable(flush):
        flush()
    return total


def missing_directories(directory) -> list:
    """The directories :func:`os.makedirs` would create for ``directory``, deepest first (absolute paths)."""
    missing = []
    path = os.path.abspath(os.fspath(directory))
    while not os.path.exists(path):
        missing.append(path)
        parent = os.path.dirname(path)
        if parent == path:
            break
        path = parent
    return missing


@contextlib.contextmanager
def directory_made(directory):
    """Make ``directory`` (and its missing parents) for the block; if the block fails (an error, a Ctrl-C, a
    SIGTERM), remove the ones this made, deepest first, that are still empty: a command that wrote nothing leaves
    no folder behind, and one holding a file something put there (a whole output of the block) stays."""
    made = missing_directories(directory)
    try:
        os.makedirs(directory, exist_ok=True)
        yield
    except BaseException:
        for folder in made:
            with contextlib.suppress(OSError):
                os.rmdir(folder)
        raise


@contextlib.contextmanager
def directory_lock(paths):
    """Hold an exclusive ``flock`` on the directory of every path (sorted, so two writers never deadlock)."""
    try:
        import fcntl
    except ImportError:  # no flock on this platform: writers are not serialised
        yield
        return
    directories = sorted({os.path.realpath(os.path.dirname(os.path.abspath(os.fspath(p)))) for p in paths})
    fds = []
    try:
        for directory in directories:
            fd = os.open(directory, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
            fds.append(fd)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        for fd in reversed(fds):
            os.close(fd)  # closing releases the lock


@contextlib.contextmanager
def signals_deferred():
    """Hold SIGINT, SIGTERM and SIGHUP back; they take effect (as they would have) when the block ends.

    In the main thread the handlers are swapped for a recorder (a signal may reach any of
    the process's threads, e.g. numpy's, and Python runs handlers in the main thread) and the
    recorded signals are re-sent afterwards; in other threads Python handlers never
    interrupt this code, so nothing is needed.
    """
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught, old, state = [], {}, {"holding": True}

    def record(signum, frame):
        if state["holding"]:
            caught.append(signum)
        else:  # the block has ended and this recorder is still installed (a signal stopped the restore): the
            _forward(old[signum], signum, frame)  # signal's own handler takes it

    try:  # a signal that comes between two swaps (its handler raising) leaves no recorder behind
        for sig in _DEFERRED_SIGNALS:
            old[sig] = signal.getsignal(sig)  # first: a handler may raise the moment the swap returns
            signal.signal(sig, record)
        yield
    finally:
        state["holding"] = False
        for sig, handler in old.items():
            signal.signal(sig, signal.SIG_DFL if handler is None else handler)
        for sig in dict.fromkeys(caught):
            os.kill(os.getpid(), sig)


def _forward(handler, signum: int, frame) -> None:
    """Deliver signal ``signum`` as ``handler`` (what :func:`signal.signal` returned for it) would have."""
    if callable(handler):
        handler(signum, frame)
    elif handler != signal.SIG_IGN:  # the default action (None: a handler not installed from Python)
        signal.signal(signum, signal.SIG_DFL)
        os.kill(os.getpid(), signum)


def fault_point(name: str) -> None:
    """Test hook: with ``PMWM_FAULT=name:SIGNAL`` (e.g. ``key-published:KILL``), send that signal to this process
    each time it reaches the point ``name``; with ``PMWM_FAULT=name@N:SIGNAL`` (e.g. ``batch-row-taken@3:STOP``),
    only the ``N``-th time this process reaches it (counted from 1).  Nothing (one lookup) when unset."""
    spec = os.environ.get("PMWM_FAULT")
    if not spec:
        return
    point, _, sig = spec.partition(":")
    point, at, nth = point.partition("@")
    if point != name:
        return
    if at:
        _fault_counts[name] = reached = _fault_counts.get(name, 0) + 1
        if reached != int(nth):
            return
    os.kill(os.getpid(), getattr(signal, "SIG" + (sig or "KILL")))


#: How many times this process has reached each fault point named with a count (``name@N``).
_fault_counts: dict[str, int] = {}


def _fsync_directory(directory: str) -> None:
    """Make a rename durable where the platform allows it (best effort)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)
