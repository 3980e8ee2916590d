"""The push decoder: bytes in, one :class:`PartialResult` per chunk boundary out.

Contract
--------
``StreamDecoder.feed(data)`` accepts any number of bytes and returns the results
that became available: first the base mesh (``chunk == 0``), then one result per
complete vertex-split chunk, in order.  ``close()`` ends the stream and returns
a :class:`StreamEnd` saying whether it was complete or cut short.  A cut stream
is progress, not corruption: every complete chunk has been delivered; only a
stream that ends before its base mesh is complete raises
:class:`~pmwm_codec.errors.TruncatedError`.  A chunk whose digest fails raises
:class:`~pmwm_codec.errors.ChecksumError` naming it; bytes after the GLB header's ``length`` raise
:class:`~pmwm_codec.errors.FormatError` naming how many, once every level the bytes before it complete is
delivered (spec README, *Partial files*): an error found in a ``feed`` that first completed levels (a chunk's
digest, a chunk that fails as it is applied, bytes after the length) is raised by the next ``feed`` or ``close``,
after they are returned, so the levels delivered never depend on how the bytes were split.  The decoder is single-use: a second
``close()`` returns the same :class:`StreamEnd`, after an error every later call raises that
error again, and ``feed`` after ``close`` is a ValueError.  Data that is not bytes-like (a ``str``)
is an :class:`~pmwm_codec.errors.OptionError`.

The container layer (:class:`~pmwm_codec.format.ContainerParser`) does the byte
work (GLB framing, limits, digests, zstd); this layer turns its events into
meshes through the one replay loop (:class:`.replay.Replay`: split records
applied a batch at a time into arrays that grow with the decoded mesh, up to the
declared full-resolution counts) and, given a key, feeds every batch's carriers to a
:class:`~pmwm_codec.watermark.verify.Verifier` and puts its estimate of the
partial watermark into each result.  Given a key, it also checks the keyed MACs of
the base and of every chunk as they arrive (:class:`~pmwm_codec.format.mac.MacChecker`)
and puts the answer in each result's ``authentic_bytes``: True written by the key
holder, False not (MAC mismatch), None no MAC in the file (or no key).  A failed MAC
does not stop decoding; ``mac_failed`` lists the chunks (0: the base).  Pull wrappers
live in :mod:`.reader`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import MAX_VERTICES
from ..errors import FormatError, LimitError, OptionError, PmwError, WatermarkKeyError
from ..format import BaseEvent, ChunkEvent, ContainerParser, EndEvent, HeaderEvent
from ..format.mac import MacChecker
from ..mesh import Mesh
from ..progressive.grid import AttributeGrid, Grid
from ..progressive.topology import job_vertices
from ..sources import byte_view
from ..watermark import codec as wm
from ..watermark.verify import Verifier
from .replay import Replay


@dataclass
class Part:
    """One progressive primitive at a chunk boundary.

    ``positions_int`` (n, 3) int64 grid coordinates, ``faces`` (m, 3) int64 and
    ``attributes_int`` (n, a) int64 quantized attributes (see the extension's
    ``attributes``); copies, or views when the decoder was made with ``copy=False``.
    """

    positions_int: np.ndarray
    faces: np.ndarray
    attributes_int: np.ndarray
    grid: Grid
    attributes: tuple = ()

    @property
    def positions(self) -> np.ndarray:
        return self.grid.dequantize(self.positions_int)

    def attribute_values(self) -> dict:
        """``{semantic: (n, k) float32}`` dequantized attributes."""
        out, col = {}, 0
        for spec in self.attributes:
            width = len(spec["origin"])
            out[spec["semantic"]] = AttributeGrid.from_config(spec).to_float32(self.attributes_int[:, col : col + width])
            col += width
        return out


@dataclass
class PartialResult:
    """The mesh (and watermark) at one chunk boundary.

    ``parts`` holds every progressive primitive (one for a mesh file);
    ``positions_int`` / ``faces`` / ``mesh`` are the first part's for a single
    primitive and all parts concatenated otherwise.
    """

    chunk: int
    chunks_total: int
    bytes_read: int
    vertices: int
    faces_count: int
    grid: Grid
    parts: list
    watermark: np.ndarray | None = None
    coefficients: int = 0
    nc: float | None = None
    psnr_db: float | None = None
    centered_nc: float | None = None
    code_match: float | None = None
    carriers_read: int = 0
    #: the watermark as read at this boundary (None without a key or a mark)
    estimate: object = None
    #: this chunk's (for chunk 0: the bases') MAC matched; None without a key or a MAC
    authentic_bytes: bool | None = None

    @property
    def positions_int(self) -> np.ndarray:
        if len(self.parts) == 1:
            return self.parts[0].positions_int
        return np.concatenate([p.positions_int for p in self.parts])

    @property
    def faces(self) -> np.ndarray:
        if len(self.parts) == 1:
            return self.parts[0].faces
        offsets = np.cumsum([0] + [len(p.positions_int) for p in self.parts])
        return np.concatenate([p.faces + o for p, o in zip(self.parts, offsets)])

    @property
    def mesh(self) -> Mesh:
        """The mesh at this level (all parts), positions dequantized to float64."""
        if len(self.parts) == 1:
            return Mesh(self.grid.dequantize(self.positions_int), self.faces)
        return Mesh(np.concatenate([p.positions for p in self.parts]), self.faces)

    def as_json(self) -> dict:
        return {
            "chunk": self.chunk, "bytes_read": self.bytes_read, "vertices": self.vertices,
            "faces": self.faces_count, "coefficients": self.coefficients,
            "nc": self.nc, "psnr_db": self.psnr_db,
        }


@dataclass
class StreamEnd:
    complete: bool
    bytes_read: int
    total_length: int
    chunks_applied: int
    chunks_total: int

    @property
    def truncated(self) -> bool:
        return not self.complete


class StreamDecoder:
    """Push decoder (see module docstring).

    Parameters
    ----------
    key : WatermarkKey or a key file path, optional
        Needed to read the watermark.  A key whose fingerprint differs from the
        file's raises :class:`WatermarkKeyError` as soon as the header is in.
    reference : (s, s) uint8, or an image as ``iter_decode``'s ``watermark`` takes it, optional
        The original watermark, for NC/PSNR; defaults to the one in the key.
    copy : bool
        Copy the mesh arrays into every result (default) or hand out views.
    max_chunks : int, optional
        Stop applying chunks after this many (``decode --chunks N``).
    check_key : bool
        Refuse keys of other files (default).  Off only to measure false positives.
    """

    def __init__(self, key=None, reference=None, *, copy: bool = True, max_chunks: int | None = None,
                 check_key: bool = True):
        from ..options import checked_chunks
        from ..watermark.image import load_watermark_given
        from ..watermark.key import as_key

        key, max_chunks = as_key(key), checked_chunks(max_chunks)  # a key file path too
        if reference is not None:  # a path or an array, checked now (it was read, or failed, at the first level)
            reference = load_watermark_given(reference)[0]
        self._parser = ContainerParser(max_chunks=max_chunks)  # the chunks after them are not even opened
        self._replay = Replay(max_chunks=max_chunks, carriers=key is not None)  # only a key reads them
        self.key = key
        self.reference = reference if reference is not None else getattr(key, "reference", None)
        self.copy = copy
        self.check_key = check_key
        self.header: HeaderEvent | None = None
        self.chunks_total = 0
        self.watermark_params: wm.WatermarkParams | None = None
        self.verifier: Verifier | None = None
        self._closed = False
        self._end: StreamEnd | None = None  # close()'s answer, returned again by a second close()
        self._error: PmwError | None = None  # the error that broke the stream, raised again by later calls
        self.last: PartialResult | None = None
        #: what a user should know about this decode (one line each), e.g. parts of a cut file left out
        self.notices: list = []
        self._macs = MacChecker(key.mac_key()) if key is not None else None
        #: chunk numbers (0: the base meshes) whose MAC failed / that carry no MAC (with a key: the checker's lists)
        self.mac_failed: list = [] if self._macs is None else self._macs.failed
        self.mac_missing: list = [] if self._macs is None else self._macs.missing
        self.mac_checked = 0

    def vertex_counts(self) -> list:
        """Vertices of each progressive primitive now, in stream order."""
        return [st.n for st in self._replay.states]

    @property
    def chunks_applied(self) -> int:
        return self._replay.chunks_applied

    def feed(self, data) -> list:
        """Consume bytes; return the :class:`PartialResult` objects that became available."""
        if self._closed:
            raise OptionError("StreamDecoder is single-use: it was already closed")
        data = byte_view(data, "StreamDecoder.feed()")  # a str is refused before anything is read
        if self._error is not None:  # the stream broke: every later call says why
            raise self._error
        out = []
        try:
            for event in self._parser.feed(data):
                result = self._on_event(event)
                if result is not None:
                    out.append(result)
        except PmwError as exc:  # a chunk that fails as it is applied: the levels before it first, as the parser's
            self._error = exc
            if not out:
                raise
        return out

    def close(self) -> StreamEnd:
        """End the stream: complete or truncated.  Raises TruncatedError before the base is in.

        Closing again is harmless: it returns the same :class:`StreamEnd`, or raises the error that broke
        the stream again."""
        if not self._closed:
            self._closed = True
            try:
                if self._error is None:
                    end: EndEvent = self._parser.close()
                    self._end = StreamEnd(end.complete, end.bytes_read, end.total_length, self.chunks_applied,
                                          end.chunk_count)
            except PmwError as exc:
                self._error = exc
        if self._error is not None:
            raise self._error
        return self._end

    def _on_event(self, event):
        applied_before = self._replay.chunks_applied
        carriers = self._replay.on_event(event)
        authentic = self._check_mac(event)
        if isinstance(event, HeaderEvent):
            self._on_header(event)
        elif isinstance(event, BaseEvent) and self._replay.ready:
            self._start_verifier()
            return self._result(0, event.bytes_read, authentic)
        elif isinstance(event, ChunkEvent) and self._replay.chunks_applied > applied_before:
            if self.verifier is not None:
                for c in carriers:
                    self.verifier.add_carriers(c)
            return self._result(event.index + 1, event.bytes_read, authentic)
        return None

    def _check_mac(self, event):
        """The MAC answer for ``event`` (True/False/None), recorded in ``mac_*``; None without a key."""
        if self._macs is None:
            return None
        authentic = self._macs.tally(event)
        self.mac_checked = self._macs.checked
        return None if authentic is NotImplemented else authentic

    def _on_header(self, event: HeaderEvent):
        self.header = event
        self.chunks_total = event.chunk_count
        job_vertices(sum(int(e.get("vertexCount", 0)) for e in event.extensions))  # counts checked by the parser
        # one watermark covers every progressive primitive, each repeating its public parameters (spec README,
        # "Watermark over several primitives"): the first that carries one gives them (one whose object was
        # stripped carries no carriers, and its base MAC says it was changed)
        cfg = next((e["watermark"] for e in event.extensions if "watermark" in e), None)
        if cfg is None:
            return  # an unmarked file: nothing to read, the verdict will say so
        # A file cut by `pmw cut` holds fewer vertices than the stream the mark was spread
        # over, so the carrier count is bounded by the vertex limit, not by this file's count
        # (the schema's form of the field: every reader checks it, as the JavaScript reader does).
        carriers = cfg.get("carriers")
        if isinstance(carriers, int) and carriers > MAX_VERTICES:
            raise LimitError(f"watermark carrier count {carriers} exceeds the limit {MAX_VERTICES}")
        if self.key is None:
            return  # a decode without a key reads the mesh only: the parameters' meaning is ignored (spec/watermark.md)
        self.watermark_params = wm.WatermarkParams.from_config(cfg)
        if self.check_key:
            check_fingerprint(self.key, self.watermark_params)

    def _start_verifier(self):
        if self.watermark_params is None:
            return
        nbars = [nb for nb, ext in zip(self._replay.nbars, self._replay.exts) if "watermark" in ext]
        if not all(np.isfinite(nb) and nb > 0 for nb in nbars):
            raise FormatError("base mesh: every edge has zero length, the watermark has no reference length")
        if self.key is not None:
            self.verifier = Verifier(self.watermark_params, self.key, nbars[0], self.reference)

    def _result(self, chunk: int, bytes_read: int, authentic_bytes: bool | None = None) -> PartialResult:
        replay = self._replay
        parts = []
        for p, (grid, ext) in enumerate(zip(replay.grids, replay.exts)):
            values, fac = replay.current(p)
            pos, attrs = values[:, :3], values[:, 3:]
            if self.copy:
                pos, fac, attrs = pos.copy(), fac.copy(), attrs.copy()
            parts.append(Part(pos, fac, attrs, grid, tuple(ext.get("attributes", ()))))
        r = PartialResult(chunk, self.chunks_total, bytes_read, sum(st.n for st in replay.states),
                          sum(st.m for st in replay.states), replay.grids[0], parts, authentic_bytes=authentic_bytes)
        if self.verifier is not None:
            r.estimate = est = self.verifier.estimate()
            r.watermark, r.coefficients, r.carriers_read = est.watermark, est.coefficients, est.carriers_read
            r.nc, r.psnr_db, r.centered_nc, r.code_match = est.nc, est.psnr_db, est.centered_nc, est.code_match
        self.last = r
        return r


def check_fingerprint(key, params) -> None:
    """Refuse a key whose fingerprint differs from the file's public one."""
    if params.fingerprint and key.fingerprint() != params.fingerprint:
        raise WatermarkKeyError("the key belongs to another file (its fingerprint differs from the file's)")
