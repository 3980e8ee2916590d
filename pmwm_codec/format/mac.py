"""Keyed authentication: the ``baseMac`` of a progressive primitive, the ``mac`` of a chunk, the ``sceneMac``.

The public ``digest`` of a chunk catches accidental damage, but anyone can recompute it
after changing the bytes.  A file written with a watermark key also carries MACs that
only the key holder can compute (normative text: ``spec/bitstream.md`` §6.3):

* ``baseMac`` on the extension object: BLAKE2b-128 keyed with the MAC key
  (:meth:`~pmwm_codec.watermark.key.WatermarkKey.mac_key`) over the primitive's ordinal,
  its extension's public fields (everything but ``chunks``, ``vertexCount``,
  ``faceCount`` and ``baseMac``, which a cut changes or which is the MAC itself) and the
  *decoded* base mesh (grid integers, faces, progressive attributes);
* ``mac`` on every chunk entry: BLAKE2b-128 keyed the same way over the primitive's
  ``baseMac``, the primitive ordinal and chunk index, the entry (everything but
  ``bufferView``, which a cut renumbers, and ``mac``; payload version 2: the five values
  its chunk table stores, :data:`CHUNK_MAC_FIELDS_V2`) and the raw (decompressed) payload.
  The entry holds the ``digest`` of the stored bytes, so the stored bytes are covered too.

* ``sceneMac`` on every extension object (one value): BLAKE2b-128 keyed the same way over
  the rest of the document as a reader shows it (:func:`scene_document`: the glTF JSON without
  ``buffers``, with each bufferView reference replaced by the ordinal of a content field holding
  the bytes it reads, each progressive primitive's extension object and Draco object left out,
  its base accessors ``null``) and those content fields.  It is set before ``baseMac``, which
  covers it, so stripping it breaks ``baseMac``.

Every field of the MAC input is framed as ``uint64_le(len) || bytes``; JSON values are
written canonically by :func:`canonical_json`.  Everything a ``pmw cut`` rewrites is left
out, so a cut file keeps valid MACs for the chunks it keeps.
"""

from __future__ import annotations

import hmac
import json

import numpy as np

from ..constants import EXTENSION_NAME, MAX_SCENE_VALUES
from ..errors import FormatError, LimitError
from .extension import base_mesh_fields, framed_blake2b, payload_version
from .gltf import COMPONENT_DTYPES, DRACO_EXTENSION, INDEX_DTYPES, TYPE_WIDTH, element_rows, gc_paused, named
from .parser import BaseEvent, ChunkEvent, HeaderEvent

#: Extension fields left out of ``baseMac``: set per cut (counts, chunk list), the MAC itself, or
#: the keyless ``baseDigest`` of the same base mesh the MAC covers.
BASE_MAC_EXCLUDED = ("chunks", "vertexCount", "faceCount", "baseMac", "baseDigest")
#: Chunk entry fields left out of its ``mac``: renumbered by a cut, or the MAC itself.
CHUNK_MAC_EXCLUDED = ("bufferView", "mac")
#: Chunk entry fields its ``mac`` covers in payload version 2: the chunk table's values for it
#: (not the bufferView and offset a cut or rewrite may move, nor the fields derived from them).
CHUNK_MAC_FIELDS_V2 = ("byteLength", "digest", "faceCount", "geometricError", "vertexCount")
_BASE_LABEL = b"pmwm/base-mac/v1"
_CHUNK_LABEL = b"pmwm/chunk-mac/v1"
_SCENE_LABEL = b"pmwm/scene-mac/v1"
#: The extension field that holds the scene MAC (the same value on every progressive primitive).
SCENE_MAC = "sceneMac"


def canonical_json(value) -> bytes:
    """UTF-8 JSON with sorted keys, no whitespace, ASCII escapes, floats as Python ``repr``.

    Integers are written in decimal; floats as the shortest text that reads back to the
    same double (Python's ``repr``: ``0.1``, ``1.0``, ``1e-05``, ``1.5e+16``).  A reader's extension
    object has its integer members as ints already (:func:`~.extension.integer_members`: ``16.0`` in
    the file is ``16`` here, bitstream.md §6.3).
    """
    return json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=True, allow_nan=False).encode("ascii")


def base_mac(mac_key: bytes, primitive: int, extension: dict, positions_int, faces, attributes_int=None) -> str:
    """32 hex digits: the ``baseMac`` of progressive primitive ``primitive``.

    ``extension`` the extension object (excluded fields are ignored); ``positions_int``
    (n, 3) int64 grid coordinates and ``faces`` (m, 3) int64 of the decoded base;
    ``attributes_int`` (n, a) int64 progressive attributes (None: a = 0).
    """
    public = {k: v for k, v in extension.items() if k not in BASE_MAC_EXCLUDED}
    return framed_blake2b([_BASE_LABEL, int(primitive).to_bytes(4, "little"), canonical_json(public),
                           *base_mesh_fields(positions_int, faces, attributes_int)], key=mac_key)


def chunk_mac(mac_key: bytes, base_mac_hex: str, primitive: int, chunk: int, entry: dict, payload, version: int = 1) -> str:
    """32 hex digits: the ``mac`` of chunk ``chunk`` of primitive ``primitive``.

    ``entry`` its index entry (:func:`~.extension.chunk_entries`; fields outside the MAC are
    ignored); ``payload`` the raw (decompressed) chunk bytes; ``version`` the payload version.
    """
    if version == 2:  # geometricError always as a float: "0" written by a JSON tool MACs as 0.0
        fields = {**{k: entry[k] for k in CHUNK_MAC_FIELDS_V2}, "geometricError": float(entry["geometricError"])}
    else:
        fields = {k: v for k, v in entry.items() if k not in CHUNK_MAC_EXCLUDED}
    place = int(primitive).to_bytes(4, "little") + int(chunk).to_bytes(4, "little")
    return framed_blake2b([_CHUNK_LABEL, bytes.fromhex(base_mac_hex), place, canonical_json(fields),
                           bytes(memoryview(payload).cast("B"))], key=mac_key)


def scene_document(gltf: dict) -> tuple:
    """``(S, sources)``: what ``sceneMac`` covers of the glTF JSON ``gltf`` (not modified), bitstream.md §6.3.

    ``S`` is a copy of ``gltf`` without ``buffers`` and ``bufferViews``, in which

    * every progressive primitive's ``PMWM_progressive_mesh`` object is ``{}`` and its
      ``KHR_draco_mesh_compression`` object is left out (``baseMac`` and the chunk MACs cover them),
      and the accessors its base reads (``POSITION``, ``indices`` and the attributes named in the
      extension's ``attributes``) are ``null`` (``baseMac`` covers the base they decode to, however
      it is encoded);
    * every other bufferView reference (an accessor's, its sparse ``indices`` and ``values``, an
      image's, a Draco object's) keeps its key ``bufferView`` with the *ordinal of its content field*
      as value, and the holder loses its ``byteOffset``;
    * every number with an integral value is an integer (``1.0`` is ``1``): JSON has one number type.

    ``sources`` lists, per content field in ordinal order, ``(view, byteOffset, count, item size,
    strided)``: the ``count`` elements of ``item size`` bytes the reference reads from bufferView
    ``view`` (at ``byteOffset``, every ``byteStride`` bytes when ``strided`` and the view has one).
    Content fields are numbered in document order: accessors (bufferView, then sparse indices, then
    sparse values), images, then the Draco objects of the other primitives in mesh/primitive order.
    Nothing a ``pmw cut`` rewrites is in ``S``: the chunk table, counts, bufferViews and buffers.
    FormatError when a reference's JSON is malformed (the writer never writes such a document).
    """
    doc = _scene_copy({k: v for k, v in gltf.items() if k not in ("buffers", "bufferViews")})
    sources = []
    base = set()
    for mesh in _list(doc.get("meshes")):
        for prim in _list(mesh.get("primitives") if isinstance(mesh, dict) else None):
            exts = prim.get("extensions") if isinstance(prim, dict) else None
            if not isinstance(exts, dict) or EXTENSION_NAME not in exts:
                continue
            ext = exts[EXTENSION_NAME]
            attributes = prim.get("attributes") if isinstance(prim.get("attributes"), dict) else {}
            names = ["POSITION"] + [a.get("semantic") for a in _list(ext.get("attributes") if isinstance(ext, dict) else None)
                                    if isinstance(a, dict)]
            base.update(attributes[n] for n in names if n in attributes)
            if "indices" in prim:
                base.add(prim["indices"])
            exts[EXTENSION_NAME] = {}
            exts.pop(DRACO_EXTENSION, None)
    accessors = _list(doc.get("accessors"))
    for i, acc in enumerate(accessors):
        if i in base:
            accessors[i] = None
            continue
        if not isinstance(acc, dict):
            continue
        width, dtype = named(acc.get("type"), TYPE_WIDTH), named(acc.get("componentType"), COMPONENT_DTYPES)
        if "bufferView" in acc:
            if width is None or dtype is None:
                raise FormatError(f"accessor {i}: unknown type or componentType")
            _reference(acc, sources, _count(acc), np.dtype(dtype).itemsize * width, True)
        sparse = acc.get("sparse")
        if isinstance(sparse, dict):
            n = _count(sparse)
            indices, values = sparse.get("indices"), sparse.get("values")
            if not isinstance(indices, dict) or not isinstance(values, dict) or width is None or dtype is None:
                raise FormatError(f"accessor {i}: malformed sparse")
            index_dtype = named(indices.get("componentType"), INDEX_DTYPES)
            if index_dtype is None:
                raise FormatError(f"accessor {i}: sparse indices componentType is not an index type")
            _reference(indices, sources, n, np.dtype(index_dtype).itemsize, False)
            _reference(values, sources, n, np.dtype(dtype).itemsize * width, False)
    for image in _list(doc.get("images")):
        if isinstance(image, dict) and "bufferView" in image:
            _reference(image, sources, 1, None, False)
    for mesh in _list(doc.get("meshes")):
        for prim in _list(mesh.get("primitives") if isinstance(mesh, dict) else None):
            exts = prim.get("extensions") if isinstance(prim, dict) else None
            draco = exts.get(DRACO_EXTENSION) if isinstance(exts, dict) else None
            if isinstance(draco, dict) and "bufferView" in draco:
                _reference(draco, sources, 1, None, False)
    return doc, sources


def _list(value) -> list:
    return value if isinstance(value, list) else []


def _count(holder: dict) -> int:
    count = holder.get("count")
    if isinstance(count, float) and count.is_integer():
        count = int(count)
    if isinstance(count, bool) or not isinstance(count, int) or count < 0:
        raise FormatError(f"count {count!r} is not a non-negative integer")
    return count


def _reference(holder: dict, sources: list, count: int, item, strided: bool) -> None:
    """Record the content ``holder``'s bufferView reference reads (``item`` None: the whole view) and
    replace the reference by its ordinal (in place)."""
    view = holder["bufferView"]
    offset = holder.pop("byteOffset", 0)
    for value in (view, offset):
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int) or value < 0:
            raise FormatError(f"bufferView reference {value!r} is not a non-negative integer")
    sources.append((int(view), int(offset), count, item, strided))
    holder["bufferView"] = len(sources) - 1


#: JSON scalars :func:`_scene_copy` keeps as they are (exact types: a subclass, or a float, is looked at one by one).
_PLAIN = frozenset((int, str, bool, type(None)))


def _scene_copy(value, limit: int | None = None):
    """A copy of the JSON ``value`` with every float of integral value as an int (``1.0`` -> ``1``, ``-0.0`` ->
    ``0``), walked without recursion; LimitError, before copying a container, when the values counted so far
    pass ``limit`` (default :data:`~pmwm_codec.constants.MAX_SCENE_VALUES`; objects, arrays and scalars,
    ``value`` itself included)."""
    limit = MAX_SCENE_VALUES if limit is None else limit
    top = [value]
    if not isinstance(value, (dict, list)):
        stack, top[0] = [], _integral(value)
    else:
        stack = [(top, 0)]  # (holder, place): a container still to copy, at holder[place]
    count = 1
    while stack:
        holder, place = stack.pop()
        item = holder[place]
        count += len(item)
        if count > limit:
            raise LimitError(f"the scene holds more than {limit:,} JSON values (MAX_SCENE_VALUES, spec/bitstream.md "
                             "§6.3): too many for its sceneMac")
        copied = holder[place] = dict(item) if isinstance(item, dict) else list(item)
        if _PLAIN.issuperset(map(type, copied.values() if isinstance(copied, dict) else copied)):
            continue  # integers, strings, true, false, null: nothing to change, nothing below (one pass in C)
        for key in (copied.keys() if isinstance(copied, dict) else range(len(copied))):
            child = copied[key]
            if isinstance(child, float):
                if child.is_integer():
                    copied[key] = int(child)
            elif isinstance(child, (dict, list)):
                stack.append((copied, key))
    return top[0]


def _integral(value):
    return int(value) if isinstance(value, float) and value.is_integer() else value


class Scene:
    """What ``sceneMac`` covers of the glTF JSON ``gltf`` (not modified), built once (:func:`scene_document`)
    for every question a writer or a verifier asks of it: where the BIN data it reads ends
    (:meth:`data_end`), its MAC (:meth:`mac`), whether the file's MACs are it (:meth:`check`).

    ``doc`` and ``sources`` as :func:`scene_document` returns them; ``error`` the exception it raised
    instead (a :class:`~pmwm_codec.errors.LimitError` over :data:`~pmwm_codec.constants.MAX_SCENE_VALUES`, a
    FormatError for a malformed reference ...): the document has no canonical form, so no sceneMac is its.
    """

    def __init__(self, gltf: dict):
        self.gltf = gltf
        self.doc, self.sources, self.error = None, [], None
        try:
            with gc_paused():  # the copy makes a container per one of the document's
                self.doc, self.sources = scene_document(gltf)
        except (ValueError, TypeError, OverflowError, RecursionError) as exc:  # FormatError and LimitError among them
            self.error = exc

    def data_end(self) -> int:
        """Where the BIN data the scene MAC reads ends (0: none, or no canonical form; references that do not
        read ignored)."""
        views = _list(self.gltf.get("bufferViews"))
        end = 0
        for view, *_ in self.sources:
            if 0 <= view < len(views) and isinstance(views[view], dict):
                try:
                    end = max(end, int(views[view].get("byteOffset", 0)) + int(views[view]["byteLength"]))
                except (KeyError, TypeError, ValueError):
                    pass
        return end

    def mac(self, mac_key: bytes, bin_data) -> str:
        """32 hex digits: the ``sceneMac`` of the document whose BIN chunk starts with ``bin_data`` (at least
        :meth:`data_end` bytes).  Raises :attr:`error` (LimitError, FormatError ...), or FormatError (a
        ValueError for a non-finite number) when the data cannot be read: the document has no canonical form."""
        if self.error is not None:
            raise self.error
        return framed_blake2b(_scene_fields(self.doc, self.sources, self.gltf, bin_data), key=mac_key)

    def check(self, mac_key: bytes, bin_data, found) -> tuple:
        """``(matches, why)``: whether every ``sceneMac`` in ``found`` (the extension objects' values) is the one
        ``mac_key`` gives this document with BIN data ``bin_data`` (at least :meth:`data_end` bytes); ``why``
        None, or, when the document has no canonical form or its data cannot be read (never so from the key
        holder's writer: ``matches`` False), the one line saying why (``the scene holds more than 4,194,304
        JSON values (MAX_SCENE_VALUES ...``)."""
        try:
            expected = self.mac(mac_key, bin_data)
        except (ValueError, TypeError, OverflowError, RecursionError) as exc:
            return False, str(exc) or type(exc).__name__
        return all(same_mac(expected, f) for f in found), None


def scene_data_end(gltf: dict) -> int:
    """:meth:`Scene.data_end` of ``gltf`` (build a :class:`Scene` to ask it more than this)."""
    return Scene(gltf).data_end()


def _contents(gltf: dict, sources, bin_data):
    """Each content field of ``sources`` (:func:`scene_document`) read from ``bin_data`` (buffer 0)."""
    views = _list(gltf.get("bufferViews"))
    data = memoryview(bin_data).cast("B")
    for view_index, offset, count, item, strided in sources:
        if not 0 <= view_index < len(views) or not isinstance(views[view_index], dict):
            raise FormatError(f"bufferView {view_index} does not exist")
        view = views[view_index]
        if view.get("buffer", 0) != 0:
            raise FormatError(f"bufferView {view_index} is not in the GLB BIN buffer")
        start, length = view.get("byteOffset", 0), view.get("byteLength")
        if isinstance(start, bool) or isinstance(length, bool) or not isinstance(start, int) or not isinstance(length, int) \
                or start < 0 or length < 0 or start + length > len(data):
            raise FormatError(f"bufferView {view_index} does not lie in the BIN chunk")
        raw = data[start : start + length]
        if item is None:
            yield raw
            continue
        stride = view.get("byteStride") if strided else None
        stride = item if stride is None else stride
        if isinstance(stride, bool) or not isinstance(stride, int) or stride < item:
            raise FormatError(f"bufferView {view_index}: byteStride {stride!r} is smaller than its {item}-byte elements")
        if count and offset + (count - 1) * stride + item > length:
            raise FormatError(f"bufferView {view_index}: {count} elements at offset {offset} read past its end")
        yield element_rows(raw, np.uint8, count, item, offset, stride).tobytes() if count else b""


def scene_mac(mac_key: bytes, gltf: dict, bin_data) -> str:
    """:meth:`Scene.mac` of ``gltf`` (build a :class:`Scene` to ask it more than this)."""
    return Scene(gltf).mac(mac_key, bin_data)


def _scene_fields(doc, sources, gltf, bin_data):
    yield _SCENE_LABEL
    yield canonical_json(doc)
    yield from _contents(gltf, sources, bin_data)


def same_mac(expected: str, found) -> bool:
    """Constant-time comparison of a computed MAC with the file's (False when the file has none)."""
    return isinstance(found, str) and hmac.compare_digest(expected, found)


def combine(results) -> bool | None:
    """One verdict for several checks: False if any failed, else None if any had no MAC, else True."""
    results = list(results)
    if any(r is False for r in results):
        return False
    return None if any(r is None for r in results) else True


class MacChecker:
    """Checks the MACs of a stream as its container events arrive (see module docstring).

    :meth:`on_event` returns, for the last :class:`~.parser.BaseEvent` of the bases and
    for every :class:`~.parser.ChunkEvent`: True (the MAC matches: written by the key
    holder), False (it does not) or None (the file carries no MAC there); otherwise
    ``NotImplemented`` (nothing to report yet).  The bases are False together when their MACs
    match but their extension objects name different ``fileId``s: every progressive primitive
    of a file shares one (spec README), so these are primitives of several files spliced into one.
    """

    def __init__(self, mac_key: bytes):
        self._key = mac_key
        self._exts = ()
        self._bases = []
        #: what :meth:`tally` has seen: MACs checked, and the chunk numbers (0: the bases) whose MAC
        #: failed or is missing
        self.checked = 0
        self.failed: list = []
        self.missing: list = []

    def tally(self, event):
        """:meth:`on_event`, with its answer recorded in ``checked`` / ``failed`` / ``missing``."""
        authentic = self.on_event(event)
        if authentic is NotImplemented:
            return authentic
        number = event.index + 1 if isinstance(event, ChunkEvent) else 0
        if authentic is None:
            self.missing.append(number)
        else:
            self.checked += 1
            if not authentic:
                self.failed.append(number)
        return authentic

    def on_event(self, event):
        if isinstance(event, HeaderEvent):
            self._exts = event.extensions or (event.extension,)
        elif isinstance(event, BaseEvent):
            ext = self._exts[event.primitive]
            found = ext.get("baseMac")
            self._bases.append(None if found is None else _verified(lambda: same_mac(
                base_mac(self._key, event.primitive, ext, event.positions_int, event.faces, event.attributes_int), found)))
            if len(self._bases) == len(self._exts):
                if len({repr(e.get("fileId")) for e in self._exts}) > 1 and all(self._bases):
                    return False  # each base the key holder's, but of different files: primitives spliced together
                return combine(self._bases)
        elif isinstance(event, ChunkEvent):
            ext = self._exts[event.primitive]
            entry = ext["chunks"][event.chunk]
            if entry.get("mac") is None or ext.get("baseMac") is None:
                return None
            return _verified(lambda: same_mac(
                chunk_mac(self._key, ext["baseMac"], event.primitive, event.chunk, entry, event.payload,
                          payload_version(ext)), entry["mac"]))
        return NotImplemented


def _verified(check) -> bool:
    """``check()``, or False when the MACed fields have no canonical form (a non-finite number,
    a MAC that is not hex): the key holder's writer never produces such fields."""
    try:
        return check()
    except (ValueError, TypeError, OverflowError):
        return False
