"""Reading the watermark of a mesh that left the stream, against the original ``.pmw``.

A decoded mesh that was exported, moved, scaled or saved as float32 keeps the
connectivity and vertex order of the stream's full decode.  The reference file
supplies the connectivity of every level; the mesh supplies the positions.  The
split topology is replayed over the mesh's own positions (no residuals), and at
every batch the codes are read exactly as a decoder reads them, so codes are
invariant to rotation, uniform scale and translation (``nbar`` is measured on
the mesh's own base vertices).
"""

from __future__ import annotations

import numpy as np

from ..errors import MeshError, PmwError
from ..format import BaseEvent, ChunkEvent, HeaderEvent, iter_events
from ..format.records import unpack_batches
from ..progressive.vsplit import MeshState, split_topology
from ..watermark import codec as wm
from ..watermark.verify import Verifier


def verify_positions(positions: np.ndarray, reference_source, key, reference_image=None) -> Verifier:
    """Read the watermark of ``positions`` (n, 3) float, in the reference's decoded vertex order.

    ``reference_source``: the original ``.pmw`` (path, bytes, file).  Returns the
    filled :class:`~pmwm_codec.watermark.verify.Verifier` (``.verdict()``,
    ``.extractor.image()``, ``.matches()``).
    """
    pts = np.asarray(positions, np.float64)
    verifier = None
    state = None
    header = None
    batch_index = 0
    for event in iter_events(reference_source):
        if isinstance(event, HeaderEvent):
            header = event
            ext = event.extension
            if "watermark" not in ext:
                raise PmwError("the reference file carries no watermark")
            params = wm.WatermarkParams.from_config(ext["watermark"])
            if pts.shape != (int(ext["vertexCount"]), 3):
                raise MeshError(
                    f"the mesh has {len(pts)} vertices, the reference stream {ext['vertexCount']}: "
                    "it must be the full decode of the reference, in its vertex order"
                )
            if not np.isfinite(pts).all():
                raise MeshError("the mesh has NaN or infinite coordinates")
        elif isinstance(event, BaseEvent):
            n0 = len(event.positions_int)
            state = MeshState(pts[:n0], event.faces, len(pts), int(header.extension["faceCount"]), dtype=np.float64)
            nbar = wm.base_mean_edge(pts[:n0], event.faces)
            ref = reference_image if reference_image is not None else getattr(key, "reference", None)
            verifier = Verifier(params, key, nbar, ref)
        elif isinstance(event, ChunkEvent):
            for batch in unpack_batches(event.payload, max_splits=len(pts)):
                topo = split_topology(state, batch.v, batch.symbols)
                state.positions[topo.u] = pts[topo.u]
                verifier.add(batch_index, pts[topo.u], topo.centroid())
                batch_index += 1
    return verifier
