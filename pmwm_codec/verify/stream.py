"""Verifying a ``.pmw`` stream: read the watermark at every chunk boundary and decide.

Contract
--------
:func:`verify_stream` ``(source, key, watermark=None) -> StreamVerification``

* ``source``: the ``.pmw`` -- a path, ``"-"`` (standard input), bytes, a binary file or
  an iterable of byte blocks; whole or cut (a cut file is verified as far as it goes);
* ``key``: a :class:`~pmwm_codec.watermark.key.WatermarkKey` or a key file path; a key
  whose fingerprint differs from the file's is read like any other and the verdict is
  ``not-authentic`` (the owner of a key may ask "is my mark in this file?" of any file);
* ``watermark``: the expected image (path or (s, s) array); default the key's own.  One of
  another size than the key's is refused (OptionError) before anything is read: a key marks
  with one image, so it is never the mark.

The verdict is the stream verifier's (:mod:`pmwm_codec.watermark.verify`):
``authentic`` | ``tampered`` | ``not-authentic`` | ``inconclusive``; a file without a
watermark is ``not-authentic``.  ``tamper`` lists the vertices of the decoded mesh whose
carrier code no longer reads (:meth:`~pmwm_codec.watermark.verify.Verifier.tamper`).  Keyed
chunk authentication comes on top: a marked file whose base or any chunk fails its MAC (or
carries none: written before MACs, or stripped) is ``not-authentic`` whatever the watermark
reads, and :meth:`StreamVerification.mac_notes` names every such chunk.  The ``sceneMac`` (bitstream.md
§6.3: the nodes, scenes, materials, images, other meshes, animations ... the file shows around its
progressive meshes) is checked once the data it covers has arrived: a mismatch turns ``authentic``
into ``tampered`` (the mark is there, the document around it was changed); a file written before it
(no ``sceneMac``) is verified as before, with a note that the scene is not covered.
``whole_stream`` says whether every carrier of the key holder's stream was read (a ``pmw cut`` file or
a prefix verifies ``authentic`` too: it is what the key holder wrote, as far as it goes).
:meth:`StreamVerification.as_json` is the ``pmw verify --json`` object
(non-finite floats such as the PSNR of a bit-exact watermark stay ``inf``; the command
prints them as ``null``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..errors import WatermarkKeyError
from ..format.mac import SCENE_MAC, Scene
from ..stream import StreamDecoder, iter_results
from ..stream.decoder import StreamEnd
from ..watermark import load_watermark
from ..sources import Source, iter_blocks
from ..watermark.key import WatermarkKey, as_key
from ..watermark.verify import image_note

__all__ = ["StreamVerification", "verify_stream"]


@dataclass
class StreamVerification:
    """What :func:`verify_stream` found.

    ``results``: one :class:`~pmwm_codec.stream.PartialResult` per chunk boundary, base mesh
    first (``chunk`` 0); ``end``: how the stream ended; ``verdict``; ``codes_matched`` of
    ``codes_read`` codes agree with the expected ones; ``marked``: the file carries a
    watermark; ``total_length``: the size of the complete file in bytes; ``key_matches``:
    False when the file's public key fingerprint is another key's (verdict ``not-authentic``), None
    when the file carries no watermark image (no fingerprint to compare);
    ``mac``: ``{"checked": n, "failed": [chunk numbers], "missing": [chunk numbers], "scene": s, "scene_error":
    why}`` (chunk 0 is the base meshes) -- the keyed MACs checked, failed and absent, and the ``sceneMac``'s
    answer ``s``: True (the document around the progressive meshes is the key holder's), False (it is not),
    None (the file has no ``sceneMac``, or its data has not arrived: ``scene`` says which); ``why`` None, or
    the line saying why a scene is False without a MAC to compare: it has no canonical form (more than
    ``MAX_SCENE_VALUES`` JSON values, a bufferView reference that does not read).
    ``scene``: ``"match"``, ``"mismatch"``, ``"not arrived"``, ``"not covered"`` (a marked file without
    ``sceneMac``) or ``""`` (no key, or no watermark).  ``carriers_total``: the carriers of the key
    holder's whole stream (the MACed ``watermark.carriers``; 0 without a watermark).
    ``flagged`` (f,) int64 the tamper map (vertex ids of the last level's decoded mesh);
    ``binding`` the mark's keyed binding (``""``: a legacy mark).  The NC / PSNR of ``results`` are of the
    image extracted; :meth:`image_note` says when a bit-exact one stands beside another verdict.
    """

    results: list
    end: StreamEnd
    verdict: str
    codes_matched: int
    codes_read: int
    marked: bool
    total_length: int
    key_matches: bool | None = True
    mac: dict | None = None
    flagged: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    binding: str = ""
    scene: str = ""
    carriers_total: int = 0

    @property
    def whole_stream(self) -> bool | None:
        """Every carrier of the key holder's stream was read (None: the file carries no watermark).
        False for a ``pmw cut`` file or a prefix: what the key holder wrote, but not all of it."""
        if not self.marked:
            return None
        return self.codes_read == self.carriers_total

    def tamper(self) -> dict:
        """``{"flagged": [vertex ids of the decoded mesh whose carrier code no longer reads], "fraction"}``."""
        vertices = self.results[-1].vertices if self.results else 0
        return {"flagged": [int(i) for i in self.flagged], "fraction": len(self.flagged) / max(1, vertices)}

    def mac_notes(self) -> list:
        """One line per chunk whose bytes are not the key holder's (MAC failed, or absent), and one for
        the scene when it differs, has not arrived or is not covered."""
        if not self.mac:
            return []
        notes = [f"{_chunk_name(c)}: not written by the key holder (MAC mismatch)" for c in self.mac["failed"]]
        missing = self.mac["missing"]
        if missing and self.marked:
            where = "the file" if len(missing) == len(self.results) else ", ".join(_chunk_name(c) for c in missing)
            notes.append(f"{where}: no MAC, the bytes cannot be attributed to the key holder "
                         "(written before keyed chunk authentication, or stripped)")
        if self.scene == "mismatch" and self.mac.get("scene_error"):  # no canonical form: over MAX_SCENE_VALUES ...
            notes.append(f"{_SCENE} is not the key holder's: {self.mac['scene_error']}")
        elif self.scene in _SCENE_NOTES:
            notes.append(_SCENE_NOTES[self.scene])
        return notes

    def image_note(self) -> str | None:
        """The line saying that a bit-exact image beside another verdict than ``authentic`` is no match the verdict
        makes (:func:`~pmwm_codec.watermark.verify.image_note`), or None."""
        est = self.results[-1].estimate if self.results else None
        if est is None:
            return None
        why = ("the mark is intact, the scene around it is not the key holder's" if self.scene == "mismatch" else
               "bytes not shown to be the key holder's" if self.mac and (self.mac["failed"] or self.mac["missing"])
               else "")
        return image_note(self.verdict, est.bit_exact, est.inconsistent, why)

    def stream_note(self) -> str | None:
        """``a prefix of the key holder's stream: R of T carriers read`` when not every carrier was read."""
        if self.whole_stream is not False:
            return None
        return f"a prefix of the key holder's stream: {self.codes_read:,} of {self.carriers_total:,} carriers read"

    def as_json(self) -> dict:
        """The ``pmw verify --json`` object without ``pictures`` (only the command writes them) and ``owner`` (the
        owner layer, read by :func:`~pmwm_codec.verify.owner.owner_of_stream` in the command's pass)."""
        chunks = [{**r.as_json(), "authentic_bytes": r.authentic_bytes} for r in self.results]
        return {"complete": bool(self.end.complete), "truncated": bool(self.end.truncated),
                "chunks_total": int(self.end.chunks_total), "chunks": chunks, "final": chunks[-1],
                "verdict": self.verdict, "bytes_read": int(self.end.bytes_read),
                "total_length": int(self.total_length), "codes_matched": self.codes_matched,
                "codes_read": self.codes_read, "carriers_total": self.carriers_total,
                "whole_stream": self.whole_stream, "key_matches": self.key_matches, "mac": self.mac,
                "tamper": self.tamper(), "binding": self.binding or None, "image_note": self.image_note()}


_SCENE = "the scene (nodes, materials, other meshes)"
#: The note line of each ``StreamVerification.scene`` answer that needs one.
_SCENE_NOTES = {
    "mismatch": f"{_SCENE} differs from what the key holder wrote (sceneMac mismatch)",
    "not arrived": f"{_SCENE}: not checked, the data it covers has not arrived",
    "not covered": f"{_SCENE}: not covered, the file has no sceneMac (written before it): "
                   "the verdict speaks for the progressive meshes only",
}


def _chunk_name(number: int) -> str:
    """``chunk N`` for a chunk row, ``base mesh`` for row 0."""
    return f"chunk {number}" if number else "base mesh"


class _SceneData:
    """The bytes of a stream the scene MAC needs, kept as the decoder reads it: everything until the
    decoder has the JSON, then the file up to the end of the data its :class:`~..format.mac.Scene` reads
    (nothing more when no extension object carries a ``sceneMac``).  The scene is built once, when the
    JSON is in, and checked with the same copy (its cost grows with the document, up to
    ``MAX_SCENE_VALUES`` values)."""

    def __init__(self, decoder: StreamDecoder):
        self.decoder = decoder
        self.pieces: list = []
        self.length = 0
        self.limit: int | None = None
        self.scene: Scene | None = None

    def _start(self, header) -> None:
        """Build the scene of ``header``'s JSON and set :attr:`limit` (0 when no ``sceneMac`` asks for it)."""
        if any(ext.get(SCENE_MAC) is not None for ext in header.extensions):
            self.scene = Scene(header.gltf_json)
            self.limit = header.bin_offset + self.scene.data_end()
        else:
            self.limit = 0

    def blocks(self, source):
        for block in iter_blocks(source):
            self._keep(block)
            yield block

    def _keep(self, block) -> None:
        header = self.decoder.header
        if self.limit is None and header is not None:
            self._start(header)
            self._trim()
        block = memoryview(block).cast("B")
        room = len(block) if self.limit is None else max(0, self.limit - self.length)
        if room:
            piece = block[:room]
            self.pieces.append(piece if piece.readonly else bytes(piece))  # a caller may reuse a mutable block
            self.length += len(piece)

    def _trim(self) -> None:
        kept, length = [], 0
        for piece in self.pieces:
            if length >= self.limit:
                break
            piece = piece[: self.limit - length]
            kept.append(piece)
            length += len(piece)
        self.pieces, self.length = kept, length

    def check(self, key: WatermarkKey, end: StreamEnd) -> tuple:
        """``(answer, why)``: the scene MAC's answer, True / False, ``"not arrived"`` (a stream cut short
        before the data it covers; a complete file whose data cannot be read is False), or None (no
        ``sceneMac``); ``why`` the line saying why a scene with no canonical form is False (one over
        ``MAX_SCENE_VALUES``: :meth:`~..format.mac.Scene.check`), else None."""
        header = self.decoder.header
        found = [ext.get(SCENE_MAC) for ext in header.extensions]
        if all(f is None for f in found):
            return None, None
        if self.limit is None:  # the JSON came in the last block
            self._start(header)
        self._trim()
        if self.length < self.limit and not end.complete and self.limit - header.bin_offset <= _buffer_length(header):
            return "not arrived", None
        return self.scene.check(key.mac_key(), b"".join(self.pieces)[header.bin_offset:], found)


def verify_stream(source: Source, key: WatermarkKey | str | os.PathLike[str], watermark: np.ndarray | str | None = None, *,
                  keep_meshes: bool = False, progress: Callable[[str, float], None] | None = None,
                  each: Callable[[object, dict], None] | None = None) -> StreamVerification:
    """Decode ``source`` with ``key`` and score the watermark at every chunk boundary.

    ``keep_meshes``: keep a copy of every level's mesh in the results (for pictures);
    otherwise the results hold only the numbers and the partial watermark.
    ``progress``: optional ``progress(label, fraction)`` called after every boundary.
    ``each``: optional ``each(result, gltf)`` called at every boundary with the result, its meshes copied,
    and the stream's glTF JSON (the owner layer read in the same pass: :class:`~.owner.OwnerReader`).
    Raises the decoder's named errors (:class:`~pmwm_codec.errors.PmwError`), e.g.
    TruncatedError when the file ends before its base mesh.  ``source`` may be an http(s) URL.
    """
    from ..http import as_source

    source = as_source(source)
    reference = None
    if watermark is not None:
        reference, _ = load_watermark(watermark)
    key = as_key(key)
    if key is None:  # a verdict needs the key: without one every file read not-authentic, as a forgery does
        raise WatermarkKeyError("verify_stream needs the key of the file (pmw verify --key KEY)")
    key.check_reference(reference, watermark)  # before anything is read
    decoder = StreamDecoder(key, reference, copy=keep_meshes or each is not None, check_key=False)
    scene_data = _SceneData(decoder)
    gen = iter_results(scene_data.blocks(source), decoder)
    results = []
    while True:
        try:
            r = next(gen)
        except StopIteration as stop:
            end = stop.value
            break
        if each is not None:
            each(r, decoder.header.gltf_json)
        if not keep_meshes:  # views into the decoder (or copies only ``each`` needed): drop them, keep the numbers
            r.parts = []
        results.append(r)
        if progress is not None:
            progress(f"chunk {r.chunk}/{r.chunks_total}", r.chunk / max(1, r.chunks_total))
    v = decoder.verifier
    owns = decoder.watermark_params is None or key is None or key.owns(decoder.watermark_params.fingerprint)
    mac = {"checked": decoder.mac_checked, "failed": decoder.mac_failed, "missing": decoder.mac_missing, "scene": None,
           "scene_error": None}
    # key_matches None: the file carries no watermark image, so no key fingerprint to compare (an owner
    # layer alone is answered by ``owner``: one owner's key marks many files)
    out = StreamVerification(results, end, "not-authentic", 0, 0, v is not None, decoder.header.total_length,
                             None if decoder.watermark_params is None else owns, mac)
    if v is not None:  # else the file carries no watermark
        out.verdict = v.verdict() if owns else "not-authentic"
        out.codes_matched, out.codes_read = v.matches()
        # vertex ids of the decoded mesh: the primitives' current meshes, concatenated in stream order
        out.flagged = v.tamper(np.cumsum([0] + decoder.vertex_counts()[:-1]))
        out.binding = v.params.binding
        out.carriers_total = int(v.params.carriers)
        if key is not None:
            _check_scene(out, scene_data.check(key, end), mac)
        if mac["failed"] or mac["missing"]:
            out.verdict = "not-authentic"  # bytes the key holder did not write (or cannot be shown to have)
    return out


def _buffer_length(header) -> int:
    """``buffers[0].byteLength`` of the stream's JSON (the parser checked it)."""
    return int(header.gltf_json["buffers"][0]["byteLength"])


def _check_scene(out: StreamVerification, checked: tuple, mac: dict) -> None:
    """Record the scene MAC's answer and why (:meth:`_SceneData.check`) in ``out`` and ``mac``; a mismatch
    makes an authentic mark ``tampered``: the mark is the key holder's, the document shown around it is not."""
    answer, mac["scene_error"] = checked
    mac["scene"] = answer if isinstance(answer, bool) else None
    if answer is True:
        out.scene = "match"
    elif answer is False:
        out.scene = "mismatch"
        if out.verdict == "authentic":
            out.verdict = "tampered"
    elif answer == "not arrived":
        out.scene = answer
    elif not mac["missing"]:  # MACs but no sceneMac: written before it (a file without MACs is named already)
        out.scene = "not covered"
