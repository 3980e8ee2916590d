"""Reading the owner layer blind: from any mesh, and from a ``.pmw`` at every chunk boundary.

Contract
--------
* :func:`owner_of_mesh` ``(mesh, key) -> OwnerResult``: ``mesh`` a :class:`~pmwm_codec.mesh.Mesh`,
  a mesh file path (OBJ, PLY, STL, glTF/GLB: :func:`owner_view`) or a
  ``(positions (n, 3), faces (m, 3))`` pair; no original is needed.
* :func:`owner_view` ``(path) -> Mesh``: the one mesh a mesh file's layer is read from: an OBJ, PLY
  or STL as it is; a glTF/GLB's triangle primitives in the view
  :func:`~pmwm_codec.format.gltf.owner_placements` gives (the scene as shown, flattened, or, when no
  mesh is shown once or the placements do not read, each mesh once where it is stored).
* :func:`owner_of_stream` ``(source, key) -> list[OwnerBoundary]``: a ``.pmw`` (path, bytes,
  binary file; whole or cut) decoded chunk by chunk, the owner read at each boundary,
  base mesh first; its primitives are placed in the same view, as a decoded asset's are.

``key``: a :class:`~pmwm_codec.watermark.key.WatermarkKey` or key file path carrying
``owner_id``; a key without one raises :class:`~pmwm_codec.errors.WatermarkKeyError`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from ..errors import WatermarkKeyError
from ..format.extension import EXTENSION_NAME
from ..format.document import sniff_json
from ..format.gltf import find_extension_primitives, owner_placements, scene_mesh
from ..mesh import Mesh, checked_mesh, read_mesh
from ..stream import StreamDecoder, iter_results
from ..watermark.key import as_key
from ..watermark.owner import OwnerResult, detect

__all__ = ["OwnerBoundary", "owner_key", "owner_of_mesh", "owner_of_stream", "owner_view"]


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
        mesh = owner_view(mesh)
    return detect(mesh.positions, mesh.faces, key)


def owner_view(path) -> Mesh:
    """The mesh the owner layer of the mesh file at ``path`` is read from (see the module contract).

    A glTF/GLB whose view is the scene is read as :func:`~pmwm_codec.mesh.read_mesh` reads it (every
    triangle primitive placed by its nodes); one whose view is the stored meshes takes each primitive
    that :func:`~pmwm_codec.stream.asset.plan_asset` makes progressive once, as stored.  Errors are
    :func:`~pmwm_codec.mesh.read_mesh`'s and :func:`~pmwm_codec.stream.asset.plan_asset`'s."""
    from ..format.document import is_progressive, load_document
    from ..stream.asset import is_asset_path, plan_asset

    gltf = sniff_json(path) if is_asset_path(path) else None
    if gltf is None or is_progressive(gltf) or owner_placements(gltf, _triangle_meshes(gltf))[1]:
        return read_mesh(path)
    name = os.path.basename(os.fspath(path))
    document, buffers = load_document(path)
    jobs = plan_asset(document, buffers, name)[0]
    frames, in_scene = owner_placements(document, [job.mesh_index for job in jobs])
    if in_scene:  # a mesh of triangles that are all degenerate was shown twice: the scene after all
        return read_mesh(path)
    positions, faces, _ = scene_mesh([job.mesh.positions for job in jobs], [job.mesh.faces for job in jobs], frames)
    return checked_mesh(positions, faces, name=name)


def _triangle_meshes(gltf: dict) -> list:
    """Indices of the meshes of ``gltf`` with a primitive of triangles (``mode`` 4, the default)."""
    meshes = gltf.get("meshes")
    return [i for i, m in enumerate(meshes if isinstance(meshes, list) else [])
            if isinstance(m, dict) and isinstance(m.get("primitives"), list)
            and any(isinstance(p, dict) and p.get("mode", 4) == 4 for p in m["primitives"])]


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
    """The matrices every progressive primitive of the document ``gltf`` is placed by for the read (a list
    of lists of (4, 4)): :func:`~pmwm_codec.format.gltf.owner_placements` of their meshes, as the
    encoder marks the layer and as a decoded asset is read."""
    return owner_placements(gltf, [mi for mi, _, _ in find_extension_primitives(gltf, EXTENSION_NAME)])[0]
