"""Verification: a stream as it arrives, or a mesh that left the stream, against the key.

* :mod:`.stream` -- :func:`verify_stream`: a ``.pmw`` (whole, cut or arriving) chunk by chunk;
* :mod:`.mesh` -- :func:`verify_mesh`: a mesh file (exported, moved, re-ordered,
  flattened, attacked) against its original ``.pmw``;
* :mod:`.correspond` -- finding the reference's vertex order in such a mesh.

Only :mod:`.stream` is imported eagerly: the mesh wing needs scipy.
"""

from .stream import StreamVerification, verify_stream


def __getattr__(name):
    if name in ("verify_mesh", "MeshVerification"):
        from . import mesh

        return getattr(mesh, name)
    if name in ("correspond", "Correspondence"):
        from . import correspond

        return getattr(correspond, name)
    raise AttributeError(name)


__all__ = ["StreamVerification", "verify_stream", "MeshVerification", "verify_mesh", "Correspondence", "correspond"]
