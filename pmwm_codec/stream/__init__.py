"""Streams: the encoder pipeline, the push decoder and its pull wrappers."""

from .decoder import PartialResult, StreamDecoder, StreamEnd
from .encoder import EncodeReport, encode_mesh
from .reader import decode_stream, iter_results

__all__ = ["PartialResult", "StreamDecoder", "StreamEnd", "EncodeReport", "encode_mesh", "decode_stream", "iter_results"]
