"""The ``.pmw`` container: a valid GLB whose progressive mesh primitives hold base meshes and
whose BIN chunk carries one zstd-framed bufferView per vertex-split chunk.

The container layer treats chunk payloads as opaque bytes; ``records`` is the one
module that knows their layout.  Modules:

``layout``     construct Structs: GLB header, chunk header, chunk payload headers (the only byte offsets)
``base``       base mesh <-> glTF primitive (plain accessors or KHR_draco_mesh_compression), attributes
``extension``  the PMWM_progressive_mesh object: JSON-schema check, digests
``gltf``       glTF vocabulary: enums, type widths, Draco name, checked bufferView/accessor reads
``glb``        GLB framing both ways (:func:`glb_parts`, :func:`split_glb`) and the writer:
               :func:`assemble_document`, :func:`build_pmw`, :func:`write_pmw` (atomic)
``parser``     push parser :class:`ContainerParser` and its events
``reader``     pull wrappers :func:`iter_events`, :func:`read_header`
``inspect``    :func:`~.inspect.inspect`: the structure of a file from its header alone (``pmw info``)
``records``    chunk payload: split batches <-> bytes (numpy columns)
``document``   glTF documents in and out: loading assets, reading accessors, repacking
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
)
from .reader import iter_events, read_header

__all__ = [
    "EncodedBase", "encode_base", "decode_base", "check_extension", "digest",
    "build_pmw", "write_pmw", "ContainerParser", "HeaderEvent", "BaseEvent",
    "ChunkEvent", "EndEvent", "iter_events", "read_header",
]
