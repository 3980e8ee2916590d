"""pmwm_codec: progressive, watermarked 3D meshes in glTF (``.pmw``).

The public API (DESIGN.md §5)::

    mesh   = pmwm_codec.read_mesh(path)                       # OBJ, PLY, STL, OFF, glTF/GLB -> Mesh
    report = pmwm_codec.encode(src, dst, watermark=None, key=None, **options)
    mesh   = pmwm_codec.decode(src, chunks=None)              # path, bytes, binary file or http(s) URL
    data   = pmwm_codec.cut(src, chunks=None)                 # a valid, smaller .pmw (bytes)
    for step in pmwm_codec.iter_decode(src, key=None, watermark=None):
        step.mesh, step.watermark, step.chunk, step.bytes_read
"""

from __future__ import annotations

import os

from .errors import PmwError

# Nothing else at module level (numpy, the mesh module, even typing: ``_LAZY`` and :func:`_type_aliases`
# below): the ``pmw`` console script imports this package before :func:`pmwm_codec.cli.main` can answer a
# Ctrl-C with its one line, so whatever loads here is a window in which a Ctrl-C prints a traceback.
TYPE_CHECKING = False

if TYPE_CHECKING:  # for type checkers only: importing these here would make ``import pmwm_codec`` heavy
    from collections.abc import Iterator
    from typing import Any, BinaryIO, Union

    import numpy as np

    from .sources import Source

    MeshSource = Union[str, bytes, "os.PathLike[str]", "Mesh", tuple]
    Destination = Union[str, bytes, "os.PathLike[str]", BinaryIO]
    WatermarkImage = Union[str, bytes, "os.PathLike[str]", "np.ndarray", None]
    KeyLike = Union["WatermarkKey", str, bytes, "os.PathLike[str]", None]

    from .mesh import Mesh, checked_mesh, read_mesh

    from .format.inspect import inspect
    from .meshio import write_mesh
    from .stream.decoder import PartialResult
    from .verify.stream import verify_stream
    from .watermark.key import WatermarkKey

__all__ = ["Mesh", "PmwError", "read_mesh", "encode", "decode", "decode_asset", "cut", "iter_decode", "load_key",
           "Source", "MeshSource", "Destination", "WatermarkImage", "KeyLike"]
__version__ = "0.1.0"


def _as_mesh(src: MeshSource) -> Mesh:
    from .mesh import Mesh, checked_mesh, read_mesh

    if isinstance(src, Mesh):
        return checked_mesh(src.positions, src.faces, src.attributes)
    return read_mesh(src)


def _as_watermark(watermark) -> tuple:
    """``(image (s, s) uint8, notices, (width, height) as given)`` of a watermark image argument
    (:func:`~pmwm_codec.watermark.image.load_watermark`); ``(None, [], None)`` for None."""
    if watermark is None:
        return None, [], None
    from .watermark.image import load_watermark_given

    return load_watermark_given(watermark)


def load_key(key: KeyLike) -> WatermarkKey | None:
    """A :class:`~pmwm_codec.watermark.key.WatermarkKey` from a key object or a key file path (None for None)."""
    from .watermark.key import as_key

    return as_key(key)


def encode(src: MeshSource, dst: Destination, watermark: WatermarkImage = None, key: KeyLike = None,
           **options: Any) -> dict[str, Any]:
    """Encode ``src`` into a ``.pmw`` at ``dst`` (path or binary file).

    ``src``: a mesh file or :class:`Mesh`, or a glTF asset (``.glb`` / ``.gltf`` path, or an
    in-memory ``(gltf dict, buffers)``) whose triangle primitives all become progressive
    while materials, textures and nodes are kept (see :mod:`pmwm_codec.stream.asset`).  An OBJ or PLY
    file that carries appearance (texture coordinates, vertex colours, MTL materials and their textures)
    is encoded as the glTF asset it describes (:mod:`pmwm_codec.meshdoc`); one of geometry alone as a mesh.
    The files a mesh file names (an MTL, a texture, a ``.gltf``'s buffers) are never replaced by ``dst``.

    A path (``src``, ``dst``, ``watermark``, ``key``) may be a ``str``, ``bytes`` or ``os.PathLike``.

    ``dst``: a path, checked before any work (:func:`~pmwm_codec.options.check_destination`), or a
    binary file object, open, writable and blocking, that gets every byte
    (:func:`~pmwm_codec.atomic.write_stream`; a new key file is not kept when it does not).

    ``watermark``: image path or array ((h, w) gray, or (h, w, 3 | 4) colour, made gray; floats scaled, values out
    of 0..255 clipped, a side not a power of two padded: each said in a notice); ``key``: a WatermarkKey (never modified, not
    saved), a key file path, or None (the key file ``dst + ".key.json"`` when ``dst`` is a
    path).  A key file path follows :class:`~pmwm_codec.watermark.key.KeySlot`: an existing
    key file is reused untouched when it holds this watermark, refused
    (WatermarkKeyError, nothing written) otherwise or when it is a symbolic link; a new one
    is written (0600) just before the ``.pmw``, so a failure at any moment leaves the old
    pair or the new one.  Without a ``watermark``, a ``key`` given here marks with what it holds: its own
    reference image (as if given as ``watermark``, so one key marks every asset alike; the owner layer under it
    as with any watermark), or, holding no image, its owner ID alone (as ``owner_id``); a key file that does
    not exist is refused then (WatermarkKeyError, before any work) unless an ``owner_id`` makes it, and so is
    a key holding neither, or no image with ``owner_id=False`` (nothing would be marked).  Options: ``mode``, ``bits``, ``grid_bits``, ``base_codec``,
    ``base_vertices``, ``embed_from`` (first split carrying a code: index or fraction), ``owner_id`` (the owner layer: a 64-bit int, alone or under the watermark; default
    with a watermark: the key's owner ID, random for a new key, none for a key written
    before the owner layer; False: no owner layer; a layer that would not read back from the
    file is refused when asked for by its ID (OwnerLayerError, nothing written) and left out
    with a notice when on by default), ``zstd_level``, ``measure`` (``"vertices"`` | ``"sampled"`` |
    ``"none"``), ``payload_version`` (2, the default: range-coded chunks and the compact chunk
    table; 1: the zstd payload and per-chunk index of files written before),
    ``strip_image_profiles`` and ``keep_flat_normals`` (assets: a flat-shaded primitive keeps its NORMAL,
    and stays in the base), ``geometry_only`` (the positions and faces alone, as :func:`read_mesh` reads them:
    an OBJ's or PLY's appearance, a glTF asset's document not carried).  Without a ``watermark``, ``mode``, ``bits``, ``embed_from`` and
    ``step_units`` change nothing in the file: each one given says so in a notice
    (:func:`~pmwm_codec.options.ignored_without_image`, ``"bits ignored: no watermark"``), and so does
    ``owner_strength`` without an ``owner_id`` or a watermark (no owner layer).  ``progress``: a callable
    ``progress(stage, fraction)``, called as each stage (``simplify``, ``records``, ``measure``, ``write``) starts
    (0.0) and ends (1.0); ``min_chunk_splits``: the smallest chunk, in vertex splits (default 1% of a
    primitive's splits, at least 32; the first chunks grow to it from 32, so the first levels come early).
    Returns the report dict (the ``pmw encode --json`` fields, plus ``notices``, ``key_path`` (None for a key
    object or when nothing is marked) and ``owner_id`` (16 hex digits; absent without an owner layer)).
    """
    from dataclasses import replace

    from .stream.asset import encode_asset, is_asset_path
    from .options import check_destination, check_source, checked_options, ignored_without_image, image_options_given
    from .stream.encoder import encode_mesh
    from .watermark.codec import MAX_EXACT_BITS, CapacityError

    src, dst, key, watermark = (os.fsdecode(x) if isinstance(x, bytes) else x for x in (src, dst, key, watermark))
    check_source(src)
    named = ()  # the files a mesh file names (its MTL, textures, .gltf buffers): never replaced by the output
    if isinstance(src, (str, os.PathLike)) and isinstance(dst, (str, bytes, os.PathLike)) and os.path.exists(dst):
        from .meshdoc import named_files

        named = tuple(named_files(src))
    check_destination(dst, inputs=(src, watermark, *named))
    options = checked_options(options)
    geometry_only = options.pop("geometry_only", False)
    if geometry_only and isinstance(src, tuple):
        from .errors import OptionError

        raise OptionError("geometry_only takes a mesh file or a Mesh, not an in-memory glTF document")
    image, notices, given = _as_watermark(watermark)
    from_key = None  # the key whose own image is the watermark (no watermark given)
    if image is None and key is not None:
        image, from_key = _key_watermark(key, options.get("owner_id"))
    if image is None:
        notices += ignored_without_image(image_options_given(options))
    elif options.get("mode") in (None, "exact") and (options.get("bits") or 0) > MAX_EXACT_BITS:
        notices.append(f"{options['bits']} bits per code: past the {MAX_EXACT_BITS} exact mode is made for (about 70 dB "
                       "mesh PSNR), each bit more doubles how far a code may move its vertex: expect the mesh visibly "
                       "changed (fewer bits, or a finer mesh, keep it close)")
    asked = options.get("owner_id")
    if image is None and (asked is False or (asked is None and key is None)) and options.get("owner_strength") is not None:
        notices.append("owner_strength ignored: no owner layer (an owner_id, or a watermark, makes one)")
    key_obj, key_slot, options["owner_id"] = _key_for(key, image, dst, asked, inputs=(src, watermark))
    asset = not geometry_only and (is_asset_path(src) or isinstance(src, tuple))
    label = None  # a mesh file read as an asset (its appearance: pmwm_codec.meshdoc) is named as the file
    mesh = None
    if not asset and not geometry_only and isinstance(src, (str, os.PathLike)) and os.path.exists(src):
        from .meshdoc import read_source

        source, read_notices = read_source(src)  # the document its appearance describes, or its Mesh
        notices += read_notices
        if isinstance(source, tuple):
            src, asset, label = source, True, os.path.basename(os.fspath(src))
        else:
            mesh = source
    if mesh is None and not asset:
        mesh = _as_mesh(src)
    if asset and not isinstance(src, tuple) and not os.path.exists(src):
        from .errors import InputFormatError
        from .sources import shown_path

        raise InputFormatError(f"{shown_path(src)}: no such file")
    options["key_slot"] = key_slot
    if image is not None and asked is None and options["owner_id"] is None:
        notices.append("the key names no owner id (written before the owner layer, or without it): no owner layer written")
    # the owner layer on by default (under a watermark) is left out, with a notice, where it could not be
    # read back; one asked for by its ID is refused there (OwnerLayerError, nothing written)
    options["owner_fallback"] = image is not None and asked is None
    try:
        if asset:
            report = encode_asset(src, dst, watermark=image, key=key_obj, label=label, **options)
        else:
            options.pop("strip_image_profiles", None)
            options.pop("keep_flat_normals", None)
            report = encode_mesh(mesh, dst, watermark=image, key=key_obj, **options)
    except CapacityError as exc:  # named as the caller gave it, not as the square it was made
        if from_key is not None:  # never shrunk (--fit): the key marks with this image only
            raise exc.of_key(from_key) from None
        raise exc.as_given(*given) from None
    key_path = None if key_slot is None else key_slot.path
    cleanup = {} if mesh is None else mesh.cleanup
    dropped = [_CLEANUP_SAID[k].format(v) if k in _CLEANUP_SAID else f"dropped {v} {k.replace('_', ' ')}"
               for k, v in cleanup.items()]
    doc = replace(report, notices=notices + report.notices + dropped, key_path=key_path).as_json()
    if options.get("owner_id") is not None and report.key is not None and report.key.owner_id is not None:
        doc["owner_id"] = report.key.owner_hex  # the owner layer is in the file
    return doc


#: How the encoder says a :attr:`Mesh.cleanup` count that is no "dropped k <what>".
_CLEANUP_SAID = {"gpu_instanced_meshes": "{} mesh(es) drawn by GPU instancing (EXT_mesh_gpu_instancing), whose "
                                         "instances the geometry reader does not place: every mesh read once, as stored",
                "skinned_meshes_moved_by_their_nodes": "{} skinned mesh(es) read in their stored pose placed by their "
                                                       "node's transform, which a glTF viewer ignores for a skinned "
                                                       "mesh (glTF 2.0 3.7.3.3)"}


def _key_watermark(key, owner_id=None) -> tuple:
    """``(image (s, s) uint8 or None, the key's name or None)``: what an encode given no watermark marks
    with when it names a ``key`` (a WatermarkKey, or a key file path): the key's own reference image, so that
    one key marks every asset alike (as ``pmw batch encode --key`` does); None for a key that holds none (its
    owner ID alone is marked: :func:`_key_for`).  WatermarkKeyError (before any work) for a key file that does
    not exist unless an ``owner_id`` (an int) makes it (a key named to mark with is never made up: a mistyped path
    would leave the file unmarked, or marked under a new random key), and for a key that would mark nothing: one
    holding neither an image nor an owner ID, or no image with ``owner_id`` False (no owner layer); an image key
    with ``owner_id`` False marks the image alone, as with a watermark."""
    from .errors import WatermarkKeyError
    from .watermark.key import WatermarkKey

    name = "the key object"
    if isinstance(key, (str, os.PathLike)):
        name = os.fspath(key)
        if not os.path.lexists(key):
            if owner_id is None or owner_id is False:
                raise WatermarkKeyError(f"{name}: no such key file: an encode with no watermark image and no owner "
                                        "ID marks with an existing key (--watermark or --owner-id make a new one)")
            return None, None
        key = WatermarkKey.load(key)
    if not isinstance(key, WatermarkKey):
        return None, None  # _key_for names what is wrong with it
    if key.reference is not None:
        return key.reference, name
    if owner_id is False:
        raise WatermarkKeyError(f"{name}: the key holds no watermark image, so without the owner layer (--no-owner) "
                                "nothing would be marked")
    if key.owner_id is None and owner_id is None:
        raise WatermarkKeyError(f"{name}: the key holds no watermark image and names no "
                                "owner ID: nothing to mark with (give a watermark image or an owner ID)")
    return None, None


def _key_for(key, image, dst, owner_id=None, inputs=()) -> tuple:
    """``(key object or None, KeySlot or None, owner ID or None)`` for an encode of ``image``
    (and/or the owner layer) to ``dst``; ``owner_id`` as :func:`encode` takes it, resolved.

    Checked before any work (before the mesh is read): a refused key file costs nothing.  An encode
    that writes no mark to a path beside a key file (``OUT.pmw.key.json``), or marks it with another key,
    is refused (:func:`~pmwm_codec.watermark.key.refuse_orphaned_beside`).  A key
    path that names no file yet must be one a new key can be published at
    (:func:`~pmwm_codec.options.check_output_path`: not empty, no directory, not one of ``inputs``).
    """
    from .stream.encoder import default_key_path
    from .errors import OptionError, WatermarkKeyError
    from .options import check_output_path
    from .watermark.key import FROM_KEY, KeySlot, WatermarkKey, check_key_object, refuse_orphaned_beside, same_path

    if owner_id is False or (owner_id is None and image is None and key is None):
        owner_id = None
    elif owner_id is None:
        owner_id = FROM_KEY
    if image is None and owner_id is None:  # no mark: never written beside a key it would leave verifying nothing
        if isinstance(dst, (str, os.PathLike)):
            refuse_orphaned_beside(default_key_path(dst), dst, marked=False)
        return None, None, None
    if key is not None and not isinstance(key, (str, os.PathLike)):
        if not isinstance(key, WatermarkKey):
            raise OptionError(f"key must be a WatermarkKey, a key file path or None, got {type(key).__name__}")
        resolved = key.owner_id if owner_id == FROM_KEY else owner_id
        check_key_object(key, image, resolved)
        refuse_orphaned_beside(default_key_path(dst), dst, marked=True, key=key)
        return key, None, resolved
    path = default_key_path(dst) if key is None else key
    if path is None:
        raise OptionError("a mark written to a file object needs key= (a WatermarkKey kept by the caller, or a key "
                          "file path): the key made here would be lost, and nothing could verify the file")
    if not os.path.lexists(path):  # an existing key file (or what stands there) is KeySlot's to judge
        path = check_output_path(path, "key", inputs=inputs, key=True)
    if isinstance(dst, (str, os.PathLike)) and same_path(path, dst):
        raise WatermarkKeyError(f"{os.fspath(path)}: the key file would be the .pmw itself (the .pmw would "
                                "replace the key just written): give the key another name")
    slot = KeySlot.open(path, image, owner_id)
    beside = default_key_path(dst)
    if beside is not None and not same_path(path, beside):
        refuse_orphaned_beside(beside, dst, marked=True, key=slot.existing)
    return slot.existing, slot, slot.owner_id


def decode(src: Source, chunks: int | None = None) -> Mesh:
    """Decode a whole or cut ``.pmw`` (path, bytes or binary file) to a :class:`Mesh`.

    ``chunks``: stop after the base mesh and this many vertex-split chunks.  ``src`` may be
    an ``http://`` or ``https://`` URL (:mod:`pmwm_codec.http`): read by Range requests when
    the server honours them, fetching nothing after the last chunk asked for.  The geometry
    only (positions and faces, every primitive placed as stored); :func:`decode_asset` keeps
    the document: attributes (texture coordinates, normals ...), materials and nodes.
    """
    from .http import as_source
    from .mesh import Mesh
    from .options import checked_chunks
    from .stream.reader import decode_stream

    chunks = checked_chunks(chunks)

    last, _ = decode_stream(as_source(src, chunks), chunks=chunks, copy=False)
    mesh = last.mesh  # every primitive dequantized on its own grid
    faces = mesh.faces
    # nothing uses the decoder's arrays after this: a view of one is copied only to free what it does not cover
    if faces.base is not None and faces.base.nbytes != faces.nbytes:
        faces = faces.copy()
    return Mesh(mesh.positions, faces)


def iter_decode(src: Source, key: KeyLike = None, watermark: WatermarkImage = None) -> Iterator[PartialResult]:
    """Yield a :class:`~pmwm_codec.stream.PartialResult` per chunk boundary, base mesh first.

    Each has ``mesh``, ``watermark`` (the partial image, with a key), ``chunk`` and
    ``bytes_read``, plus ``nc`` and ``psnr_db`` when a reference watermark is known.
    ``src`` may be an ``http://`` or ``https://`` URL, fetched as the results are pulled.

    The arguments are checked by the call itself, before anything is read: a key or watermark that cannot
    be used, or a source of a kind no reader takes, raises here, not at the first ``next()``; the bytes
    (a path's file, a URL's answer, a file object's or an iterable's blocks) are read as results are pulled.
    """
    from .errors import OptionError
    from .http import UrlSource, as_source
    from .sources import checked_source
    from .stream.decoder import StreamDecoder
    from .stream.reader import iter_results

    reference = None
    if watermark is not None:
        reference, _, _ = _as_watermark(watermark)  # an image that cannot be read is named first
        if key is None:  # the partial image is read with the key alone: without one it would go unused in silence
            raise OptionError("iter_decode: watermark needs a key (the watermark is read with the key; give key=)")
    decoder = StreamDecoder(load_key(key), reference)
    source = as_source(src)
    return iter_results(source if isinstance(source, UrlSource) else checked_source(source), decoder)


def decode_asset(src: Source, chunks: int | None = None) -> bytes:
    """A ``.pmw`` (whole or cut; a path, bytes, a binary file or an http(s) URL) as an ordinary GLB (bytes)
    at a level of detail.

    The same glTF document (materials, textures, nodes ...) with every progressive
    primitive's geometry at the base mesh plus ``chunks`` chunks (default: all that arrived).
    """
    from .http import as_source
    from .options import checked_chunks
    from .stream.asset import decode_asset as _decode_asset

    chunks = checked_chunks(chunks)
    glb, _, _ = _decode_asset(as_source(src, chunks, whole_document=True), chunks=chunks)
    return glb


def decode_to(src: Source, dst, chunks: int | None = None, geometry_only: bool = False) -> dict:
    """Decode a ``.pmw`` (a path, ``-``, an http(s) URL, bytes or a binary file; whole or cut) to the mesh file
    ``dst`` (``.glb``, ``.gltf``, ``.obj``, ``.ply``, ``.stl`` or ``.off``) after ``chunks`` chunks, as ``pmw
    decode`` does: an asset's OBJ, PLY or OFF keeps its texture coordinates, normals, colours and materials (an
    OBJ its MTL and textures beside it) unless ``geometry_only``.  Returns ``pmw decode --json``'s object (and
    ``bytes_read``); see :func:`pmwm_codec.stream.export.decode_to`."""
    from .stream.export import decode_to as _decode_to

    return _decode_to(src, dst, chunks=chunks, geometry_only=geometry_only)


def cut(src: Source, chunks: int | None = None) -> bytes:
    """A valid, smaller ``.pmw`` (bytes) from any ``.pmw`` or prefix of one (an http(s) URL too): the base and the
    first ``chunks`` chunks (default: all that arrived whole).  See :mod:`pmwm_codec.stream.cut`."""
    from .http import as_source
    from .options import checked_chunks
    from .stream.cut import cut as _cut

    chunks = checked_chunks(chunks)
    return _cut(as_source(src, chunks, whole_document=True), chunks)


#: Functions of heavier modules, imported on first use so that ``import pmwm_codec`` stays light.
_LAZY = {"inspect": ".format.inspect", "verify_stream": ".verify.stream", "write_mesh": ".meshio",
         "Mesh": ".mesh", "read_mesh": ".mesh", "checked_mesh": ".mesh"}
__all__ += ["inspect", "verify_stream", "write_mesh", "decode_to"]  # Mesh, read_mesh: listed above


def _type_aliases() -> dict:
    """The public type aliases (built on first use: importing typing is a cost ``import pmwm_codec`` avoids)."""
    from typing import BinaryIO, Union

    from .sources import Source

    return {
        # what every reader takes: a path, bytes, a binary file, an iterable of blocks (or an http(s) URL)
        "Source": Source,
        # what encode reads: a mesh file (OBJ, PLY, STL, OFF, glTF/GLB) or glTF asset path, a Mesh,
        # or an in-memory glTF asset (gltf dict, list of buffers)
        "MeshSource": Union[str, bytes, "os.PathLike[str]", "Mesh", tuple],
        # where encode writes: a path or a binary file object
        "Destination": Union[str, bytes, "os.PathLike[str]", BinaryIO],
        # a watermark image: a path (PNG ...) or a square (s, s) array
        "WatermarkImage": Union[str, bytes, "os.PathLike[str]", "np.ndarray", None],
        # a key: a WatermarkKey, a key file path, or None
        "KeyLike": Union["WatermarkKey", str, bytes, "os.PathLike[str]", None],
    }


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        from importlib import import_module

        return getattr(import_module(_LAZY[name], __name__), name)
    if name in ("Source", "MeshSource", "Destination", "WatermarkImage", "KeyLike"):
        aliases = _type_aliases()
        globals().update(aliases)
        return aliases[name]
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
