"""Streams: the encoder pipeline, the push decoder and its pull wrappers, glTF assets.

``encoder``    Mesh / document -> .pmw (simplify, base, records, watermark, write)
``chunking``   the encoder's chunking policy: base size, chunks, stream order, chunk index fields
``decoder``    :class:`StreamDecoder`: bytes in, one result per chunk boundary out
``reader``     pull wrappers (paths, bytes, files, stdin, block iterables)
``asset``      glTF assets in and out (every triangle primitive progressive, the rest kept)
``reference``  re-reading the watermark of a mesh that left the stream
"""

from .decoder import PartialResult, StreamDecoder, StreamEnd
from .encoder import EncodeReport, encode_mesh
from .reader import decode_stream, iter_results

__all__ = ["PartialResult", "StreamDecoder", "StreamEnd", "EncodeReport", "encode_mesh", "decode_stream", "iter_results"]
