"""Writing meshes to disk: the mirror of :func:`pmwm_codec.mesh.read_mesh`.

Contract
--------
:func:`write_mesh` ``(path, mesh)`` writes a :class:`~pmwm_codec.mesh.Mesh`
(``positions`` (n, 3) float, ``faces`` (m, 3) int) in the format named by the
suffix of ``path``:

``.obj``   ASCII Wavefront OBJ (``v`` and ``f`` records, 1-based, 9 significant digits)
``.ply``   binary little-endian PLY (float x, y, z; ``uchar uint`` face lists)
``.stl``   binary STL (one float32 normal and three float32 corners per face)
``.off``   ASCII OFF (``OFF``, the counts, a vertex a line, ``3 i j k`` a face, 0-based, 9 significant digits)
``.glb``   a minimal glTF binary: one node, one mesh, float32 POSITION, uint32 indices
``.gltf``  the same document as JSON, self-contained: its buffer a base64 ``data:`` URI, as
           :func:`write_asset` and ``pmw decode -o X.gltf`` write it (no second file: a ``.bin``
           beside it would replace a file the caller never named, and a name such as ``50%41.gltf``
           is no safe URI)

Positions are stored as float32 in every format (the precision of glTF; 9 significant
digits round-trip a float32 exactly) and indices as uint32.  Attributes are not written here: an asset's
scene with its texture coordinates, normals, colours and materials goes to OBJ or PLY through
:mod:`pmwm_codec.meshexport`.
:func:`write_asset` writes the bytes of an ordinary GLB document (for instance from
:func:`pmwm_codec.decode_asset`) as ``.glb``, or as a self-contained ``.gltf`` with the
buffer as a base64 data URI.

Every file is written atomically through :func:`pmwm_codec.format.glb.write_parts`
(:mod:`pmwm_codec.atomic`): an existing file is either replaced whole or left
untouched, and a new file gets the mode ``0666 & ~umask``.  GLB framing is
:func:`pmwm_codec.format.glb.glb_parts`, the one the ``.pmw`` writer uses.
"""

from __future__ import annotations

import os
from itertools import chain

import numpy as np

from .errors import MeshError, OptionError
from .format.document import glb_to_gltf
from .format.glb import glb_parts, write_parts
from .mesh import Mesh, mesh_arrays
from .options import check_output_path
from .sources import shown_path

__all__ = ["WRITE_SUFFIXES", "write_mesh", "write_asset", "text_rows"]

WRITE_SUFFIXES = (".glb", ".gltf", ".obj", ".ply", ".stl", ".off")
GENERATOR = "pmwm_codec (pmw decode)"

_FLOAT, _UINT = 5126, 5125  # glTF componentType
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963  # glTF bufferView target
_TRIANGLES = 4


def write_mesh(path: str | bytes | os.PathLike[str], mesh: Mesh) -> None:
    """Write ``mesh`` to ``path`` (a file name: str, bytes or os.PathLike), format by suffix (see the module
    docstring).

    ``mesh.positions`` (n, 3) float is stored as float32, ``mesh.faces`` (m, 3) int as uint32.  The path is
    checked before anything is written, as ``pmw decode -o`` checks it
    (:func:`~pmwm_codec.options.check_output_path`); it is the only file written.

    Raises
    ------
    OptionError
        ``path`` is not a file name, is ``-``, a directory, a device, in a missing directory, or has a suffix
        not in :data:`WRITE_SUFFIXES`; ``mesh`` is not a :class:`~pmwm_codec.mesh.Mesh`.
    WatermarkKeyError
        ``path`` names a watermark key file: a key is never replaced.
    MeshError
        The mesh's arrays are not a triangle mesh (:func:`~pmwm_codec.mesh.mesh_arrays`), or a coordinate
        overflows float32 (it would be written as infinite).
    """
    path, suffix = _checked_output(path, WRITE_SUFFIXES)
    if not isinstance(mesh, Mesh):
        raise OptionError(f"write_mesh: mesh must be a Mesh, got {type(mesh).__name__}")
    pos, tri = mesh_arrays(mesh.positions, mesh.faces, "write_mesh: mesh")
    with np.errstate(over="ignore"):
        positions = np.ascontiguousarray(pos, dtype="<f4")
    if not np.isfinite(positions).all():
        raise MeshError(f"write_mesh: mesh: a coordinate of {np.abs(pos).max():.6g} overflows the float32 "
                        "every format stores")
    faces = np.ascontiguousarray(tri, dtype="<u4")
    writer = {".glb": _glb_parts, ".gltf": _gltf_parts, ".obj": _obj_parts, ".ply": _ply_parts,
              ".stl": _stl_parts, ".off": _off_parts}[suffix]
    _write(path, writer(positions, faces))


def write_asset(path: str | bytes | os.PathLike[str], glb) -> None:
    """Write the bytes-like ``glb`` of an ordinary GLB document as ``.glb``, or as ``.gltf`` (buffer
    embedded as base64); ``path`` is checked as :func:`write_mesh` checks it."""
    from .sources import byte_view

    path, suffix = _checked_output(path, (".glb", ".gltf"))
    glb = byte_view(glb, "write_asset: glb")
    _write(path, [glb if suffix == ".glb" else glb_to_gltf(glb)])


def _checked_output(path, allowed) -> tuple:
    """``(path as str, its suffix)`` once :func:`~pmwm_codec.options.check_output_path` passed it and the suffix
    is one of ``allowed``; OptionError or WatermarkKeyError otherwise."""
    path = check_output_path(path, "mesh")
    suffix = os.path.splitext(path)[1].lower()
    if suffix not in allowed:
        raise OptionError(
            f"{shown_path(path)}: unknown output format {suffix or '(no suffix)'!r}; use one of {', '.join(allowed)}")
    return path, suffix


def _write(path: str, parts) -> None:
    write_parts(path, parts)  # mode 0666 & ~umask, as any program's new file


def _gltf_document(positions: np.ndarray, faces: np.ndarray):
    """``(glTF dict, [position bytes, index bytes], byte length)`` for (n, 3) <f4 positions, (m, 3) <u4 faces."""
    pos_bytes, idx_bytes = positions.tobytes(), faces.tobytes()  # 12 n and 12 m bytes: 4-aligned
    doc = {
        "asset": {"version": "2.0", "generator": GENERATOR},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "mode": _TRIANGLES}]}],
        "accessors": [
            {"bufferView": 0, "componentType": _FLOAT, "count": int(len(positions)), "type": "VEC3",
             "min": [float(v) for v in positions.min(0)], "max": [float(v) for v in positions.max(0)]},
            {"bufferView": 1, "componentType": _UINT, "count": int(faces.size), "type": "SCALAR"},
        ],
        "bufferViews": [
            {"buffer": 0, "byteOffset": 0, "byteLength": len(pos_bytes), "target": _ARRAY_BUFFER},
            {"buffer": 0, "byteOffset": len(pos_bytes), "byteLength": len(idx_bytes),
             "target": _ELEMENT_ARRAY_BUFFER},
        ],
        "buffers": [{"byteLength": len(pos_bytes) + len(idx_bytes)}],
    }
    return doc, [pos_bytes, idx_bytes], len(pos_bytes) + len(idx_bytes)


def _glb_parts(positions, faces) -> list:
    doc, binary, length = _gltf_document(positions, faces)
    return glb_parts(doc, binary, length)


def _gltf_parts(positions, faces) -> list:
    return [glb_to_gltf(b"".join(_glb_parts(positions, faces)))]  # the .glb's document, buffer inline


def _obj_parts(positions, faces):
    return chain([f"# {GENERATOR}: {len(positions)} vertices, {len(faces)} faces\n".encode("ascii")],
                 text_rows("v %.9g %.9g %.9g", positions), text_rows("f %d %d %d", faces, 1))


def _off_parts(positions, faces):
    """OFF as Geomview defined it: the keyword, the counts, a vertex a line, a triangle a line (no comment: a
    strict reader takes none)."""
    return chain([f"OFF\n{len(positions)} {len(faces)} 0\n".encode("ascii")],
                 text_rows("%.9g %.9g %.9g", positions), text_rows("3 %d %d %d", faces))


#: Rows a block of :func:`text_rows` formats at once (~4 MB of text: bounded, whatever the mesh).
TEXT_ROWS_BLOCK = 1 << 16


def text_rows(fmt: str, rows: np.ndarray, add: int = 0):
    """The bytes of ``np.savetxt(f, rows + add, fmt=fmt)`` (one ``fmt`` line per row of the (n, k) int or float
    array ``rows``, ``fmt`` holding k conversions), a block of :data:`TEXT_ROWS_BLOCK` rows at a time: each
    block one ``%`` over its values (no Python loop per row, and never the whole text in memory: an OBJ of 2M
    faces as a list of lines took more memory than the decoded mesh).  A generator of ASCII bytes, which
    :func:`pmwm_codec.atomic.stage` writes as it goes."""
    line = fmt + "\n"
    for at in range(0, len(rows), TEXT_ROWS_BLOCK):
        block = rows[at: at + TEXT_ROWS_BLOCK]
        if add:
            block = block.astype(np.int64) + add
        yield ((line * len(block)) % tuple(block.reshape(-1).tolist())).encode("ascii")


def _ply_parts(positions, faces) -> list:
    rec = np.empty(len(faces), dtype=[("n", "u1"), ("i", "<u4", (3,))])
    rec["n"] = 3
    rec["i"] = faces
    header = (f"ply\nformat binary_little_endian 1.0\ncomment {GENERATOR}\n"
              f"element vertex {len(positions)}\nproperty float x\nproperty float y\nproperty float z\n"
              f"element face {len(faces)}\nproperty list uchar uint vertex_indices\nend_header\n")
    return [header.encode("ascii"), positions, rec.view(np.uint8)]  # (the arrays' own bytes, not a copy of them)


def _stl_parts(positions, faces) -> list:
    """Binary STL: 80-byte header, uint32 face count, then per face 12 float32 and a uint16 (50 bytes)."""
    corners = positions[faces]  # (m, 3, 3) float32
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]).astype(np.float64)
    length = np.linalg.norm(normal, axis=1, keepdims=True)
    normal = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    rec = np.zeros(len(faces), dtype=[("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attr", "<u2")])
    rec["normal"] = normal
    rec["corners"] = corners
    header = f"binary STL, {GENERATOR}".encode("ascii").ljust(80, b" ")
    return [header, np.uint32(len(faces)).astype("<u4").tobytes(), rec.tobytes()]
