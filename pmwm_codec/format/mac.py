"""Keyed chunk authentication: the ``baseMac`` of a progressive primitive and the ``mac`` of a chunk.

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

Every field of the MAC input is framed as ``uint64_le(len) || bytes``; JSON values are
written canonically by :func:`canonical_json`.  Everything a ``pmw cut`` rewrites is left
out, so a cut file keeps valid MACs for the chunks it keeps.
"""

from __future__ import annotations

import hmac
import json

from .extension import base_mesh_fields, framed_blake2b, payload_version
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
    ``NotImplemented`` (nothing to report yet).
    """

    def __init__(self, mac_key: bytes):
        self._key = mac_key
        self._exts = ()
        self._bases = []

    def on_event(self, event):
        if isinstance(event, HeaderEvent):
            self._exts = event.extensions or (event.extension,)
        elif isinstance(event, BaseEvent):
            ext = self._exts[event.primitive]
            found = ext.get("baseMac")
            self._bases.append(None if found is None else _verified(lambda: same_mac(
                base_mac(self._key, event.primitive, ext, event.positions_int, event.faces, event.attributes_int), found)))
            if len(self._bases) == len(self._exts):
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
