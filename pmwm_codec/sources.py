"""Byte sources: the one place that knows paths, ``"-"`` (standard input), bytes, files and iterables.

Every reader of the package takes a *source*:

* a path (``str`` or ``os.PathLike``);
* ``"-"`` or ``sys.stdin``: standard input, read as bytes;
* bytes-like: anything with the buffer protocol (``bytes``, ``bytearray``, ``memoryview`` of any
  shape or stride, ``array.array``, a numpy array), read as its bytes in C order;
* a binary file object (anything with ``read``; ``read1`` is preferred), open, readable and blocking;
* an iterable of bytes-like blocks (not a dict or a set: its order is none the caller chose).

:func:`checked_source` is the one gate: every reader (:func:`iter_blocks`, :func:`read_all`,
:func:`source_size`, :func:`pmwm_codec.format.reader.read_header`) takes its source through it, so
each accepts the same sources and refuses the rest with the same
:class:`~pmwm_codec.errors.OptionError` (an int, ``None``, a file opened in text mode, a closed
file, a non-blocking file, blocks that are not bytes).
"""

from __future__ import annotations

import codecs
import io
import os
import sys
from collections.abc import Iterable, Mapping, Set
from typing import BinaryIO, Union

#: Byte order marks and the codecs they name, longest first (UTF-32 LE's starts with UTF-16 LE's).
BYTE_ORDER_MARKS = ((codecs.BOM_UTF32_LE, "utf-32"), (codecs.BOM_UTF32_BE, "utf-32"), (codecs.BOM_UTF8, "utf-8-sig"),
                    (codecs.BOM_UTF16_LE, "utf-16"), (codecs.BOM_UTF16_BE, "utf-16"))


def bom_codec(head: bytes) -> str | None:
    """The codec whose byte order mark ``head`` (a text file's first bytes) starts with: ``"utf-8-sig"``,
    ``"utf-16"`` or ``"utf-32"`` (each drops its mark when decoding), or None when it starts with none."""
    for bom, codec in BYTE_ORDER_MARKS:
        if head.startswith(bom):
            return codec
    return None


#: What every ``.pmw`` reader takes (the list above); the readers of the public API also take an
#: ``http://`` or ``https://`` URL (a ``str``, :mod:`pmwm_codec.http`).
Source = Union[str, "os.PathLike[str]", bytes, bytearray, memoryview, BinaryIO, Iterable[bytes]]

#: Block size of the pull readers (64 KiB).
DEFAULT_BLOCK_SIZE = 1 << 16


def resolve_stdin(source):
    """``sys.stdin.buffer`` for ``"-"`` or ``sys.stdin``; any other source unchanged.  OptionError for ``"-"``
    when the process has no standard input (started with it closed, ``<&-``: ``sys.stdin`` is None)."""
    if isinstance(source, str) and source == "-" or (source is not None and source is sys.stdin):
        buffer = getattr(sys.stdin, "buffer", None)
        if buffer is None:
            from .errors import OptionError

            raise OptionError("standard input is closed (or not a binary stream): nothing to read from '-'")
        return buffer
    return source


def checked_source(source):
    """``source`` in the form the readers take it; :class:`~pmwm_codec.errors.OptionError` naming it when
    it is none of the sources listed in the module docstring.

    Returns a path (``str`` / ``os.PathLike``, unchanged), a flat byte memoryview (format ``"B"``,
    C-contiguous; a strided buffer is copied: :func:`byte_view`), a file object known to be open,
    binary, readable and blocking (:func:`check_file_object`; ``"-"`` and ``sys.stdin`` are
    ``sys.stdin.buffer``), or an iterable, whose blocks :func:`iter_blocks` checks as they come.
    """
    source = resolve_stdin(source)
    if isinstance(source, (str, os.PathLike)):
        return source
    if _has_buffer(source):
        view = byte_view(source, "the source")
        if _looks_like_a_name(view):
            from .errors import FormatError

            raise FormatError(f"the source is {len(view)} bytes of text that look like a file name, not a .pmw: a "
                              "reader takes bytes as the file's content; give a name as a str or os.PathLike "
                              "(os.fsdecode(name))")
        return view
    if hasattr(source, "read"):
        check_file_object(source, "the source", "read")
        return source
    if not hasattr(source, "__iter__") or isinstance(source, (Mapping, Set)):  # a dict, a set: no blocks in order
        from .errors import OptionError

        raise OptionError(f"the source must be a path, '-', bytes, a binary file object or an iterable of byte "
                          f"blocks, got {type(source).__name__}")
    return source


def _looks_like_a_name(view: memoryview) -> bool:
    """Whether the bytes ``view`` are a file name given where a ``.pmw``'s bytes belong (``decode(b"x.pmw")``): short
    text, one line, with a folder separator or a ``.pmw`` / ``.glb`` ending, that no ``.pmw`` can be (no GLB
    magic).  Read for the message alone: nothing is looked up on disk, and the text is not repeated."""
    if not 0 < len(view) <= 4096:
        return False
    data = bytes(view)
    if data.startswith(b"glTF") or any(c < 0x20 for c in data):
        return False
    try:
        data.decode("utf-8")
    except UnicodeDecodeError:
        return False
    return b"/" in data or b"\\" in data or data.lower().endswith((b".pmw", b".glb"))


def iter_blocks(source, block_size: int = DEFAULT_BLOCK_SIZE):
    """Yield the bytes of ``source`` (:func:`checked_source`) as flat bytes-like blocks of at most
    ``block_size`` bytes.

    A bytes-like source comes out whole, as one block; an iterable's blocks come out as they
    are (as byte memoryviews).  A path is opened and closed here; a file object is not closed.
    """
    source = checked_source(source)
    if isinstance(source, memoryview):
        yield source
        return
    if isinstance(source, (str, os.PathLike)):
        with open_regular_file(source) as fh:
            yield from iter_blocks(fh, block_size)
        return
    if hasattr(source, "read"):
        read = getattr(source, "read1", None) or source.read
        while True:
            block = read_block(read, block_size)
            if not block:
                return
            yield block
        return
    for block in source:
        yield byte_view(block, "a block of the source")


def read_block(read, size: int) -> memoryview:
    """``read(size)`` of a source's file object as a flat byte memoryview (empty at the end);
    OptionError when it gives None (a non-blocking file with no data ready: the end of the
    data would be taken for the end of the file) or anything but bytes."""
    block = read(size)
    if block is None:
        from .errors import OptionError

        raise OptionError("the source: the file object's read() gave None (a non-blocking file with no data ready); "
                          "give a blocking file")
    return byte_view(block, "the file object's read()")


def check_file_object(fileobj, what: str, use: str) -> None:
    """OptionError naming ``what`` unless the file object ``fileobj`` can ``use`` (``"read"`` or
    ``"write"``) bytes whole: open, binary (not a ``TextIOBase``, no text ``mode``), readable /
    writable, and blocking (a non-blocking file reads or writes nothing when it is not ready: a
    ``.pmw`` would be cut short, and the end of the data taken for the end of the file)."""
    from .errors import OptionError

    kind = type(fileobj).__name__
    if getattr(fileobj, "closed", False) is True:
        raise OptionError(f"{what}: the file object ({kind}) is closed")
    mode = getattr(fileobj, "mode", None)  # of a file-like of no io class: "w" is text (a zip member's "r" is not)
    binary = isinstance(fileobj, (io.BufferedIOBase, io.RawIOBase))
    if isinstance(fileobj, io.TextIOBase) or (not binary and isinstance(mode, str) and "b" not in mode):
        raise OptionError(f"{what}: a file object in text mode ({kind}, its {use}() "
                          f"{'gives' if use == 'read' else 'takes'} str): open the file in binary mode ('{use[0]}b')")
    able_name, doing = {"read": ("readable", "reading"), "write": ("writable", "writing")}[use]
    able = getattr(fileobj, able_name, None)
    try:
        usable = able() if callable(able) else True
    except (OSError, ValueError):
        usable = True  # no answer: its read() / write() will say
    if usable is False:
        raise OptionError(f"{what}: the file object ({kind}) is not open for {doing}")
    try:
        blocking = os.get_blocking(fileobj.fileno())
    except (AttributeError, OSError, ValueError, TypeError):  # no descriptor (BytesIO): never waits
        blocking = True
    if not blocking:
        raise OptionError(f"{what}: the file object ({kind}) is in non-blocking mode, where a {use} that would wait "
                          f"does nothing; give a blocking file (os.set_blocking(fd, True))")


def _has_buffer(obj) -> bool:
    """Whether ``obj`` has the buffer protocol (bytes, bytearray, memoryview, array.array, numpy arrays)."""
    if isinstance(obj, (bytes, bytearray, memoryview)):
        return True
    try:
        memoryview(obj)
    except TypeError:
        return False
    return True


def byte_view(data, what: str) -> memoryview:
    """``data`` as a flat, C-contiguous byte memoryview (a strided buffer, such as ``memoryview(a)[::2]``
    or a transposed array, is copied in C order); :class:`~pmwm_codec.errors.OptionError` naming
    ``what`` when it has no buffer (a ``str`` from a file opened in text mode, say)."""
    try:
        view = memoryview(data)
    except TypeError:
        from .errors import OptionError

        hint = ": open the file in binary mode ('rb')" if isinstance(data, str) else ""
        raise OptionError(f"{what}: bytes-like data expected (bytes, bytearray, memoryview, a numpy array), got "
                          f"{type(data).__name__}{hint}") from None
    if not view.c_contiguous:
        view = memoryview(view.tobytes())
    return view.cast("B")


def read_all(source) -> bytes:
    """All bytes of ``source`` (:func:`checked_source`) as one ``bytes`` object."""
    source = checked_source(source)
    if isinstance(source, memoryview):
        return source.tobytes()
    return b"".join(iter_blocks(source, 1 << 20))


def source_size(source) -> int | None:
    """The byte size of ``source`` (:func:`checked_source`): a bytes-like source's, a path's (a regular
    file's size on disk), or None when it cannot be known without reading it all (a file object, an
    iterable, standard input)."""
    source = checked_source(source)
    if isinstance(source, memoryview):
        return source.nbytes
    if isinstance(source, (str, os.PathLike)):
        return os.path.getsize(source)
    return None


#: Control characters as :func:`shown_path` writes them (``\\n``, ``\\t``, ``\\x1b`` ...): a message stays one line.
_ESCAPED = {c: repr(chr(c))[1:-1] for c in (*range(32), 127)}


def shown_path(path) -> str:
    """``path`` as an error message names it: as it is (control characters escaped, ``a\\nb.obj``), unless it
    cannot be a file name a person typed (a NUL, over 512 characters, or a line break or a leading ``{`` in a name
    no file has): a file's content passed where its path belongs, which must not be copied into a message or a
    log (a key's JSON: its secret).  An existing file named with a line break is shown, escaped."""
    text = os.fspath(path)
    text = text if isinstance(text, str) else os.fsdecode(text)
    if len(text) > 512 or "\0" in text or (("\n" in text or "\r" in text or text.lstrip().startswith("{"))
                                            and not os.path.lexists(text)):
        return f"<a string of {len(text):,} characters, not a file name (a file's content given as its path?)>"
    return text.translate(_ESCAPED)


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


def path_argument(path, what: str) -> str:
    """``path`` (``str``, ``bytes`` or ``os.PathLike``) as a ``str`` file name;
    :class:`~pmwm_codec.errors.OptionError` naming ``what`` for anything else (a file object, an int,
    None: a function that takes a file by its name)."""
    try:
        if isinstance(path, (str, bytes, os.PathLike)):
            return os.fsdecode(os.fspath(path))
    except TypeError:  # an os.PathLike whose __fspath__ gives neither str nor bytes
        pass
    from .errors import OptionError

    raise OptionError(f"{what} must be a file name (str, bytes or os.PathLike), got {type(path).__name__}")


def check_input_path(path, what: str) -> str:
    """The file name of ``path`` once it is known to name an existing regular file.

    Raises :class:`~pmwm_codec.errors.InputFormatError` naming the path otherwise
    (missing, a directory, a device or FIFO); ``what`` says what was expected ("a mesh file").
    """
    from .errors import InputFormatError

    path = path_argument(path, f"the path of {what}")  # bytes too, as a str
    shown = shown_path(path)
    if "\0" in path or not os.path.exists(path):
        raise InputFormatError(f"{shown}: no such file")
    if os.path.isdir(path):
        raise InputFormatError(f"{shown}: is a directory, not {what}")
    if not os.path.isfile(path):
        raise InputFormatError(f"{shown}: not a regular file")
    return os.path.basename(path) or path
