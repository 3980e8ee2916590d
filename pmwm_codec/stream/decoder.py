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
:class:`~pmwm_codec.errors.ChecksumError` naming it.  The decoder is single-use.

The container layer (:class:`~pmwm_codec.format.ContainerParser`) does the byte
work (GLB framing, limits, digests, zstd); this layer turns its events into
meshes: it parses split records, applies them a batch at a time with
:func:`~pmwm_codec.progressive.vsplit.apply_batch` into arrays preallocated for
the full-resolution counts, and, given a key, reads the watermark codes of
every batch and rebuilds the partial watermark.  Pull wrappers live in
:mod:`.reader`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..constants import EXTENSION_NAME
from ..errors import FormatError, WatermarkKeyError
from ..format import BaseEvent, ChunkEvent, ContainerParser, EndEvent, HeaderEvent
from ..format.records import unpack_batches
from ..mesh import Mesh
from ..progressive.grid import Grid
from ..progressive.vsplit import MeshState, apply_batch
from ..watermark import codec as wm
from ..watermark.verify import Verifier


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
        from ..format.base import attribute_to_float

        out, col = {}, 0
        for spec in self.attributes:
            width = len(spec["origin"])
            out[spec["semantic"]] = attribute_to_float(self.attributes_int[:, col : col + width], spec)
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
    key : WatermarkKey, optional
        Needed to read the watermark.  A key whose fingerprint differs from the
        file's raises :class:`WatermarkKeyError` as soon as the header is in.
    reference : (s, s) uint8, optional
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
        self._parser = ContainerParser()
        self.key = key
        self.reference = reference if reference is not None else getattr(key, "reference", None)
        self.copy = copy
        self.max_chunks = max_chunks
        self.check_key = check_key
        self.header: HeaderEvent | None = None
        self.grid: Grid | None = None
        self.exts: tuple = ()
        self.grids: list = []
        self.states: list = []
        self.nbars: list = []
        self.chunks_applied = 0
        self.chunks_total = 0
        self.watermark_params: wm.WatermarkParams | None = None
        self.verifier: Verifier | None = None
        self._batch_index = 0
        self._closed = False
        self.last: PartialResult | None = None

    # -- push interface -------------------------------------------------------------
    def feed(self, data) -> list:
        """Consume bytes; return the :class:`PartialResult` objects that became available."""
        if self._closed:
            raise ValueError("StreamDecoder is single-use: it was already closed")
        out = []
        for event in self._parser.feed(data):
            result = self._on_event(event)
            if result is not None:
                out.append(result)
        return out

    def close(self) -> StreamEnd:
        """End the stream: complete or truncated.  Raises TruncatedError before the base is in."""
        self._closed = True
        end: EndEvent = self._parser.close()
        return StreamEnd(end.complete, end.bytes_read, end.total_length, self.chunks_applied, end.chunk_count)

    # -- events -----------------------------------------------------------------------
    def _on_event(self, event):
        if isinstance(event, HeaderEvent):
            self._on_header(event)
            return None
        if isinstance(event, BaseEvent):
            ext = self.exts[event.primitive]
            attrs = event.attributes_int if event.attributes_int is not None else np.zeros((len(event.positions_int), 0), np.int64)
            width = 3 + sum(len(sp["origin"]) for sp in ext.get("attributes", ()))
            if attrs.shape[1] != width - 3:
                raise FormatError("base mesh: attribute columns differ from the extension's attributes")
            values = np.concatenate([event.positions_int, attrs], axis=1)
            self.states.append(MeshState(values, event.faces, int(ext["vertexCount"]), int(ext["faceCount"])))
            nbar = wm.base_mean_edge(event.positions_int, event.faces) if self.watermark_params else 0.0
            if self.watermark_params is not None and not (np.isfinite(nbar) and nbar > 0):
                raise FormatError("base mesh: every edge has zero length, the watermark has no reference length")
            self.nbars.append(nbar)
            if len(self.states) < len(self.exts):
                return None
            if self.watermark_params is not None and self.key is not None:
                self.verifier = Verifier(self.watermark_params, self.key, self.nbars[0], self.reference)
            return self._result(0, event.bytes_read)
        if isinstance(event, ChunkEvent):
            if self.max_chunks is not None and self.chunks_applied >= self.max_chunks:
                return None
            p = event.primitive
            state, ext = self.states[p], self.exts[p]
            width = state.positions.shape[1]
            scale = ext["watermark"]["scale"] if "watermark" in ext else None
            for batch in unpack_batches(event.payload, max_splits=len(state.positions), width=width):
                topo = apply_batch(state, batch)
                if self.verifier is not None:
                    self.verifier.add(self._batch_index, state.positions[topo.u, :3], topo.centroid()[:, :3],
                                      self.nbars[p], scale)
                self._batch_index += 1
            self.chunks_applied += 1
            meta = ext["chunks"][event.chunk]
            if state.n != meta["vertexCount"] or state.m != meta["faceCount"]:
                raise FormatError(f"chunk {event.index + 1}: vertex/face counts differ from its index entry")
            return self._result(event.index + 1, event.bytes_read)
        return None

    def _on_header(self, event: HeaderEvent):
        self.header = event
        self.exts = event.extensions or (event.extension,)
        ext = event.extension
        self.grids = [Grid.from_config(e["grid"]) for e in self.exts]
        self.grid = self.grids[0]
        self.chunks_total = event.chunk_count
        for e in self.exts:
            payload = e.get("payload", {"codec": "pmwm-vsplit", "version": 1})
            if not isinstance(payload, dict) or payload.get("codec") != "pmwm-vsplit" or payload.get("version") != 1:
                raise FormatError(f"{EXTENSION_NAME}: unknown chunk payload codec {str(payload)[:60]}")
        if "watermark" in ext:
            self.watermark_params = wm.WatermarkParams.from_config(ext["watermark"])
            if self.watermark_params.carriers > sum(int(e["vertexCount"]) for e in self.exts):
                raise FormatError("watermark carrier count exceeds the vertices of the stream")
            if self.key is not None and self.check_key:
                fp = self.watermark_params.fingerprint
                if fp and self.key.fingerprint() != fp:
                    raise WatermarkKeyError("the key belongs to another file (its fingerprint differs from the file's)")
        elif self.key is not None and self.check_key:
            # an unmarked file: nothing to read, the verdict will say so
            pass

    @property
    def state(self) -> MeshState | None:
        """The first primitive's state (the only one for a mesh file)."""
        return self.states[0] if self.states else None

    def _result(self, chunk: int, bytes_read: int) -> PartialResult:
        parts = []
        for st, grid, ext in zip(self.states, self.grids, self.exts):
            values = st.positions[: st.n]
            fac = st.faces[: st.m]
            pos, attrs = values[:, :3], values[:, 3:]
            if self.copy:
                pos, fac, attrs = pos.copy(), fac.copy(), attrs.copy()
            parts.append(Part(pos, fac, attrs, grid, tuple(ext.get("attributes", ()))))
        r = PartialResult(chunk, self.chunks_total, bytes_read, sum(st.n for st in self.states),
                          sum(st.m for st in self.states), self.grid, parts)
        if self.verifier is not None:
            self.verifier.fill(r)
        self.last = r
        return r
