"""pmwm_codec: progressive, watermarked 3D meshes in glTF (``.pmw``).

The public API (DESIGN.md §5)::

    mesh   = pmwm_codec.read_mesh(path)
    report = pmwm_codec.encode(src, dst, watermark=None, key=None, **options)
    mesh   = pmwm_codec.decode(src, chunks=None)
    for step in pmwm_codec.iter_decode(src, key=None, watermark=None): ...
"""

from .errors import PmwError
from .mesh import Mesh, read_mesh

__all__ = ["Mesh", "PmwError", "read_mesh"]
__version__ = "0.1.0"
