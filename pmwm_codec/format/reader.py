"""Pull wrappers over the push parser :class:`~.parser.ContainerParser`.

``source`` is anything :mod:`pmwm_codec.sources` reads: a path, ``"-"`` or
``sys.stdin`` (standard input), bytes-like, a binary file object or an iterable
of byte blocks.
"""

from __future__ import annotations

import os

from ..sources import DEFAULT_BLOCK_SIZE, checked_source, iter_blocks, open_regular_file, read_block
from .layout import PREAMBLE_SIZE
from .parser import BaseEvent, ContainerParser, HeaderEvent, truncated_before_base


def iter_events(source, block_size: int = DEFAULT_BLOCK_SIZE):
    """Yield every event of ``source``, ending with the :class:`~.parser.EndEvent`.

    A file object is read in blocks of ``block_size``.  Raises the parser's named
    errors; TruncatedError when the base mesh is incomplete.
    """
    parser = ContainerParser()
    for block in iter_blocks(source, block_size):
        yield from parser.feed(block)
    yield parser.close()


def read_through_base(source, block_size: int = DEFAULT_BLOCK_SIZE) -> None:
    """Parse ``source`` from its start through its base meshes, as every reader does before it shows a
    mesh: the preamble, the JSON, the BIN chunk header and each base mesh (decoded, its ``baseDigest``
    checked); no chunk is read.  Raises the parser's named errors, TruncatedError when ``source`` ends
    before the bases are complete."""
    parser = ContainerParser()
    for block in iter_blocks(source, block_size):
        for start in range(0, len(block), block_size):  # a bytes source comes as one block
            if any(isinstance(e, BaseEvent) for e in parser.feed(block[start:start + block_size])):
                return
    parser.close()


def read_header(source) -> HeaderEvent:
    """The HeaderEvent of ``source``, reading only the 20-byte preamble and the JSON chunk.

    A file object is left just after the JSON chunk.  Raises TruncatedError if the
    JSON is incomplete.
    """
    source = checked_source(source)
    if isinstance(source, (str, os.PathLike)):
        with open_regular_file(source) as fh:  # a FIFO never blocks; a directory is a named error
            return read_header(fh)
    parser = ContainerParser()
    wanted = PREAMBLE_SIZE
    got = 0
    reader = getattr(source, "read", None)
    blocks = None if reader is not None else iter_blocks(source)
    pending = b""
    while True:
        if reader is not None:
            block = read_block(reader, wanted - got)
        else:
            block = pending or next(blocks, b"")
            block, pending = block[: wanted - got], block[wanted - got :]
        if not block:
            raise truncated_before_base(got, parser.bytes_needed, header=True)
        got += len(block)
        for event in parser.feed(block):
            if isinstance(event, HeaderEvent):
                return event
        if got == PREAMBLE_SIZE:
            wanted = PREAMBLE_SIZE + parser.json_length
