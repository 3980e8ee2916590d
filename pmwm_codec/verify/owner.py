"""Reading the owner layer blind: from any mesh, and from a ``.pmw`` at every chunk boundary.

Contract
--------
* :func:`owner_of_mesh` ``(mesh, key) -> OwnerResult``: ``mesh`` a :class:`~pmwm_codec.mesh.Mesh`,
  a mesh file path (OBJ, PLY, STL, glTF/GLB: every triangle primitive, flattened) or a
  ``(positions (n, 3), faces (m, 3))`` pair; no original is needed.
* :func:`owner_of_stream` ``(source, key) -> list[OwnerBoundary]``: a ``.pmw`` (path, bytes,
  binary file; whole or cut) decoded chunk by chunk, the owner read at each boundary,
  base mesh first; its primitives are placed by the scene's nodes, as a decoded asset's are.

``key``: a :class:`~pmwm_codec.watermark.key.WatermarkKey` or key file path carrying
``owner_id``; a key without one raises :class:`~pmwm_codec.errors.WatermarkKeyError`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import WatermarkKeyError
from ..format.extension import EXTENSION_NAME
from ..format.gltf import find_extension_primitives, progressive_placements, scene_mesh
from ..mesh import Mesh, checked_mesh, read_mesh
from ..stream import StreamDecoder, iter_results
from ..watermark.key import as_key
from ..watermark.owner import OwnerResult, detect

__all__ = ["OwnerBoundary", "owner_key", "owner_of_mesh", "owner_of_stream"]


@dataclass
class OwnerBoundary:
    """The owner layer as read after ``chunk`` chunks (``bytes_read`` bytes, ``vertices``)."""

    chunk: int
    bytes_read: int
    vertices: int
    owner: OwnerResult

    def as_json(self) -> dict:
        return {"chunk": self.chunk, "bytes_read": self.bytes_read, "vertices": self.vertices,
                **self.owner.as_json()}


def owner_key(key):
    """The key as a WatermarkKey; WatermarkKeyError when it carries no owner id."""
    key = as_key(key)
    if key is None or key.owner_id is None:
        raise WatermarkKeyError("the key carries no owner id (it was written before the owner layer)")
    return key


def owner_of_mesh(mesh, key) -> OwnerResult:
    """Read the owner layer of one mesh (see the module contract)."""
    key = owner_key(key)
    if isinstance(mesh, tuple):
        mesh = checked_mesh(*mesh)
    elif not isinstance(mesh, Mesh):
        mesh = read_mesh(mesh)
    return detect(mesh.positions, mesh.faces, key)


def owner_of_stream(source, key) -> list:
    """``[OwnerBoundary]`` of a ``.pmw`` (see the module contract), base mesh first."""
    key = owner_key(key)
    out = []
    decoder = StreamDecoder(None, None, copy=True)
    frames = None
    for r in iter_results(source, decoder):
        if frames is None:
            frames = _frames(decoder.header.gltf_json)
        positions, faces, _ = scene_mesh([p.positions for p in r.parts], [p.faces for p in r.parts], frames)
        out.append(OwnerBoundary(r.chunk, int(r.bytes_read), int(r.vertices), detect(positions, faces, key)))
    return out


def _frames(gltf: dict) -> list:
    """The world matrices of every progressive primitive of the document ``gltf`` (a list of lists of
    (4, 4), one per showing of its mesh): where every one of their meshes is placed by nodes that read
    (as the encoder marks the layer, and as a decoded asset is read), else the identity once for all
    (the stored positions taken together, as files marked before the layer was placed were)."""
    frames, why = progressive_placements(gltf, EXTENSION_NAME)
    return frames if why is None else [[np.eye(4)]] * len(find_extension_primitives(gltf, EXTENSION_NAME))
