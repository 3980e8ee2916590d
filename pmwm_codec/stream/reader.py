"""Pull wrappers over :class:`~.decoder.StreamDecoder`: paths, bytes, files, stdin, block iterables.

Each is a few lines: read blocks, feed them, yield what comes out, close.
"""

from __future__ import annotations

from ..sources import DEFAULT_BLOCK_SIZE, iter_blocks
from .decoder import StreamDecoder


def iter_results(source, decoder: StreamDecoder, block_size: int = DEFAULT_BLOCK_SIZE):
    """Yield every :class:`PartialResult` of ``source``; returns the :class:`StreamEnd`.

    ``source``: a path, ``"-"`` (standard input), bytes-like, a binary file object,
    or an iterable of byte blocks.
    """
    for block in iter_blocks(source, block_size):
        yield from decoder.feed(block)
    return decoder.close()


def decode_stream(source, *, chunks=None, key=None, reference=None, copy=True, decoder=None):
    """Decode ``source`` fully (or up to ``chunks`` chunks): returns ``(last PartialResult, StreamEnd)``.
    ``decoder``: a :class:`StreamDecoder` to feed (the caller keeps it, e.g. for its header) instead
    of one made from the other arguments."""
    if decoder is None:
        decoder = StreamDecoder(key, reference, copy=copy, max_chunks=chunks)
    last = None
    gen = iter_results(source, decoder)
    while True:
        try:
            last = next(gen)
        except StopIteration as stop:
            return last, stop.value
