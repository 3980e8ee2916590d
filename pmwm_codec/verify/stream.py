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
reads, and :meth:`StreamVerification.mac_notes` names every such chunk.
:meth:`StreamVerification.as_json` is the ``pmw verify --json`` object
(non-finite floats such as the PSNR of a bit-exact watermark stay ``inf``; the command
prints them as ``null``).
"""

from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..stream import StreamDecoder, iter_results
from ..stream.decoder import StreamEnd
from ..watermark import load_watermark
from ..sources import Source
from ..watermark.key import WatermarkKey, as_key

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
    ``mac``: ``{"checked": n, "failed": [chunk numbers], "missing": [chunk numbers]}`` (chunk 0
    is the base meshes) -- the keyed MACs checked, failed and absent.
    ``flagged`` (f,) int64 the tamper map (vertex ids of the last level's decoded mesh);
    ``binding`` the mark's keyed binding (``""``: a legacy mark).
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

    def tamper(self) -> dict:
        """``{"flagged": [vertex ids of the decoded mesh whose carrier code no longer reads], "fraction"}``."""
        vertices = self.results[-1].vertices if self.results else 0
        return {"flagged": [int(i) for i in self.flagged], "fraction": len(self.flagged) / max(1, vertices)}

    def mac_notes(self) -> list:
        """One line per chunk whose bytes are not the key holder's (MAC failed, or absent)."""
        if not self.mac:
            return []
        notes = [f"{_chunk_name(c)}: not written by the key holder (MAC mismatch)" for c in self.mac["failed"]]
        missing = self.mac["missing"]
        if missing and self.marked:
            where = "the file" if len(missing) == len(self.results) else ", ".join(_chunk_name(c) for c in missing)
            notes.append(f"{where}: no MAC, the bytes cannot be attributed to the key holder "
                         "(written before keyed chunk authentication, or stripped)")
        return notes

    def as_json(self) -> dict:
        """The ``pmw verify --json`` object (without ``pictures``, which only the command writes)."""
        chunks = [{**r.as_json(), "authentic_bytes": r.authentic_bytes} for r in self.results]
        return {"complete": bool(self.end.complete), "truncated": bool(self.end.truncated),
                "chunks_total": int(self.end.chunks_total), "chunks": chunks, "final": chunks[-1],
                "verdict": self.verdict, "bytes_read": int(self.end.bytes_read),
                "total_length": int(self.total_length), "codes_matched": self.codes_matched,
                "codes_read": self.codes_read, "key_matches": self.key_matches, "mac": self.mac,
                "tamper": self.tamper(), "binding": self.binding or None}


def _chunk_name(number: int) -> str:
    """``chunk N`` for a chunk row, ``base mesh`` for row 0."""
    return f"chunk {number}" if number else "base mesh"


def verify_stream(source: Source, key: WatermarkKey | str | os.PathLike[str], watermark: np.ndarray | str | None = None, *,
                  keep_meshes: bool = False, progress: Callable[[str, float], None] | None = None) -> StreamVerification:
    """Decode ``source`` with ``key`` and score the watermark at every chunk boundary.

    ``keep_meshes``: keep a copy of every level's mesh in the results (for pictures);
    otherwise the results hold only the numbers and the partial watermark.
    ``progress``: optional ``progress(label, fraction)`` called after every boundary.
    Raises the decoder's named errors (:class:`~pmwm_codec.errors.PmwError`), e.g.
    TruncatedError when the file ends before its base mesh.  ``source`` may be an http(s) URL.
    """
    from ..http import as_source

    source = as_source(source)
    reference = None
    if watermark is not None:
        reference, _ = load_watermark(watermark)
    key = as_key(key)
    if key is not None:  # before anything is read
        key.check_reference(reference, watermark)
    decoder = StreamDecoder(key, reference, copy=keep_meshes, check_key=False)
    gen = iter_results(source, decoder)
    results = []
    while True:
        try:
            r = next(gen)
        except StopIteration as stop:
            end = stop.value
            break
        if not keep_meshes:  # views into the decoder: drop them, keep the numbers
            r.parts = []
        results.append(r)
        if progress is not None:
            progress(f"chunk {r.chunk}/{r.chunks_total}", r.chunk / max(1, r.chunks_total))
    v = decoder.verifier
    owns = decoder.watermark_params is None or key is None or key.owns(decoder.watermark_params.fingerprint)
    mac = {"checked": decoder.mac_checked, "failed": decoder.mac_failed, "missing": decoder.mac_missing}
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
        if mac["failed"] or mac["missing"]:
            out.verdict = "not-authentic"  # bytes the key holder did not write (or cannot be shown to have)
    return out
