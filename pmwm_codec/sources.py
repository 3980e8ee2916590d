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
        with open(source, "rb") as fh:
            yield from iter_blocks(fh, block_size)
        return
    if hasattr(source, "read"):
        read = getattr(source, "read1", None) or source.read
        while True:
            block = read(block_size)
            if not block:
                return
            yield block
        return
    yield from source


def read_all(source) -> bytes:
    """All bytes of ``source`` as one ``bytes`` object."""
    if isinstance(source, (bytes, bytearray, memoryview)):
        return bytes(source)
    return b"".join(bytes(b) for b in iter_blocks(source, 1 << 20))
