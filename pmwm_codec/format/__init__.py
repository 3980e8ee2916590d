"""The ``.pmw`` container: a valid GLB whose mesh primitive holds a base mesh and whose
BIN chunk carries one zstd-framed bufferView per vertex-split chunk.

This layer knows nothing about how vertex splits are encoded: chunk payloads are
opaque bytes.  Modules:

``layout``     construct Structs of the GLB header and chunk header (the only byte offsets)
``base``       base mesh <-> glTF primitive (plain accessors or KHR_draco_mesh_compression)
``extension``  the PMWM_progressive_mesh object: JSON-schema check, digests
``glb``        writer: :func:`build_pmw`, :func:`write_pmw` (atomic)
``parser``     push parser :class:`ContainerParser` and pull wrappers
"""

from .base import EncodedBase, decode_base, encode_base
from .extension import check_extension, digest
from .glb import build_pmw, write_pmw
from .parser import (
    BaseEvent,
    ChunkEvent,
    ContainerParser,
    EndEvent,
    HeaderEvent,
    iter_events,
    read_header,
)

__all__ = [
    "EncodedBase", "encode_base", "decode_base", "check_extension", "digest",
    "build_pmw", "write_pmw", "ContainerParser", "HeaderEvent", "BaseEvent",
    "ChunkEvent", "EndEvent", "iter_events", "read_header",
]
