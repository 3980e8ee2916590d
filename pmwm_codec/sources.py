"""Byte sources: the one place that knows paths, ``"-"`` (standard input), bytes, files and iterables.

Every reader of the package takes a *source*:

* a path (``str`` or ``os.PathLike``);
* ``"-"`` or ``sys.stdin``: standard input, read as bytes;
* bytes-like (``bytes``, ``bytearray``, ``memoryview``);
* a binary file object (anything with ``read``; ``read1`` is preferred);
* an iterable of bytes-like blocks.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable
from typing import BinaryIO, Union

#: What every ``.pmw`` reader takes (the list above); the readers of the public API also take an
#: ``http://`` or ``https://`` URL (a ``str``, :mod:`pmwm_codec.http`).
Source = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview, BinaryIO, Iterable[bytes]]

#: Block size of the pull readers (64 KiB).
DEFAULT_BLOCK_SIZE = 1 << 16


def resolve_stdin(source):
    """``sys.stdin.buffer`` for ``"-"`` or ``sys.stdin``; any other source unchanged."""
    if isinstance(source, str) and source == "-" or source is sys.stdin:
        return sys.stdin.buffer
    return source


def iter_blocks(source, block_size: int = DEFAULT_BLOCK_SIZE):
    """Yield the bytes of ``source`` as bytes-like blocks of at most ``block_size`` bytes.

    Bytes-like sources come out whole, as one block; an iterable's blocks come out
    as they are.  A path is opened and closed here; a file object is not closed.
    """
    if isinstance(source, (bytes, bytearray, memoryview)):
        yield source
        return
    source = resolve_stdin(source)
    if isinstance(source, (str, os.PathLike)):
        with open_regular_file(source) as fh:
            yield from iter_blocks(fh, block_size)
        return
    if hasattr(source, "read"):
        read = getattr(source, "read1", None) or source.read
        while True:
            block = read(block_size)
            if not block:
                return
            byte_view(block, "the file object's read()")
            yield block
        return
    if not hasattr(source, "__iter__"):
        from .errors import OptionError

        raise OptionError(f"the source must be a path, '-', bytes, a binary file object or an iterable of byte "
                          f"blocks, got {type(source).__name__}")
    for block in source:
        byte_view(block, "a block of the source")
        yield block


def byte_view(data, what: str) -> memoryview:
    """``data`` as a flat byte memoryview; :class:`~pmwm_codec.errors.OptionError` naming ``what`` when it
    is not bytes-like (a ``str`` from a file opened in text mode, say)."""
    try:
        return memoryview(data).cast("B")
    except TypeError:
        from .errors import OptionError

        hint = ": open the file in binary mode ('rb')" if isinstance(data, str) else ""
        raise OptionError(f"{what}: bytes-like data expected (bytes, bytearray, memoryview), got "
                          f"{type(data).__name__}{hint}") from None


def read_all(source) -> bytes:
    """All bytes of ``source`` as one ``bytes`` object."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        return bytes(source)
    return b"".join(bytes(b) for b in iter_blocks(source, 1 << 20))


def shown_path(path) -> str:
    """``path`` as an error message names it: as it is, unless it cannot be a file name a person typed
    (a line break, a NUL, or over 512 characters: a file's content passed where its path belongs,
    which must not be copied into a message or a log -- a key file's secret, say)."""
    text = os.fspath(path)
    text = text if isinstance(text, str) else os.fsdecode(text)
    if len(text) > 512 or "\n" in text or "\0" in text:
        return f"<a string of {len(text):,} characters, not a file name (a file's content given as its path?)>"
    return text


def open_regular_file(path):
    """``path`` opened for reading bytes once it is known to be an existing regular file (opened
    without blocking and checked with ``fstat``: a FIFO never blocks);
    :class:`~pmwm_codec.errors.InputFormatError` naming it otherwise."""
    import stat

    from .errors import InputFormatError

    label = shown_path(path)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError) as exc:
        why = "no such file" if isinstance(exc, FileNotFoundError) else (
            "is a directory" if isinstance(exc, IsADirectoryError) else f"cannot read ({getattr(exc, 'strerror', None) or exc})")
        raise InputFormatError(f"{label}: {why}") from None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            raise InputFormatError(f"{label}: {'is a directory' if stat.S_ISDIR(mode) else 'not a regular file'}")
        os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


def read_regular_file(path, limit: int, error, label=None, *, follow_symlinks: bool = True) -> bytes:
    """All bytes of the regular file ``path``, refusing anything else before reading.

    Devices (``/dev/zero``), FIFOs, sockets and directories are refused without
    being read (the file is opened with ``O_NONBLOCK``, so a FIFO never blocks, and
    checked with ``fstat``); a file of more than ``limit`` bytes is refused, and no
    more than ``limit`` bytes are ever read.  ``follow_symlinks=False`` refuses a
    symlink as the last component (``O_NOFOLLOW``).  Errors are ``error(message)``,
    one line starting with ``label`` (default: the path).
    """
    import stat

    path = os.fspath(path)
    label = shown_path(path) if label is None else label
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0)
    if not follow_symlinks:
        flags |= getattr(os, "O_NOFOLLOW", 0)
    try:
        if not stat.S_ISREG(os.stat(path, follow_symlinks=follow_symlinks).st_mode):
            raise error(f"{label}: not a regular file")
        fd = os.open(path, flags)
    except OSError as exc:
        raise error(f"{label}: cannot read ({exc.strerror or exc})") from None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            raise error(f"{label}: not a regular file")
        if info.st_size > limit:
            raise error(f"{label}: {info.st_size:,} bytes, more than the limit of {limit:,}")
        os.set_blocking(fd, True)
        chunks, size = [], 0
        while size <= limit:
            block = os.read(fd, min(1 << 24, limit + 1 - size))
            if not block:
                break
            chunks.append(block)
            size += len(block)
    except OSError as exc:
        raise error(f"{label}: cannot read ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if size > limit:
        raise error(f"{label}: more than the limit of {limit:,} bytes")
    return b"".join(chunks)


def check_input_path(path, what: str) -> str:
    """The file name of ``path`` once it is known to name an existing regular file.

    Raises :class:`~pmwm_codec.errors.InputFormatError` naming the path otherwise
    (missing, a directory, a device or FIFO); ``what`` says what was expected ("a mesh file").
    """
    from .errors import InputFormatError

    path = os.fspath(path)
    shown = shown_path(path)
    if shown != path or not os.path.exists(path):
        raise InputFormatError(f"{shown}: no such file")
    if os.path.isdir(path):
        raise InputFormatError(f"{path}: is a directory, not {what}")
    if not os.path.isfile(path):
        raise InputFormatError(f"{path}: not a regular file")
    return os.path.basename(path) or path
