"""Verification: a stream as it arrives, or a mesh that left the stream, against the key.

* :mod:`.mesh` -- :func:`verify_mesh`: a mesh file (exported, moved, re-ordered,
  flattened, attacked) against its original ``.pmw``;
* :mod:`.correspond` -- finding the reference's vertex order in such a mesh.
"""

from .correspond import Correspondence, correspond
from .mesh import MeshVerification, verify_mesh

__all__ = ["Correspondence", "correspond", "MeshVerification", "verify_mesh"]
