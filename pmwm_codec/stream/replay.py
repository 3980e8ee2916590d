"""The one replay loop: container events in, split batches applied, watermark carriers out.

Contract
--------
:class:`Replay` consumes the events of :class:`~pmwm_codec.format.ContainerParser`
one at a time (:meth:`Replay.on_event`) and keeps one
:class:`~pmwm_codec.progressive.vsplit.MeshState` per progressive primitive.  For
every vertex-split batch it applies, it returns a :class:`Carriers`: the
positions of the batch's new vertices and the means of their rings, which is
everything the watermark reader needs.  Every consumer of a stream goes through
it: the push decoder (:mod:`.decoder`), verifying a mesh that left the stream
(:mod:`pmwm_codec.verify.mesh`) and the benchmarks.

Positions come from one of two places:

* **decoded** (``given=None``): residuals of the stream, on the primitive's
  integer grid, attributes included (``D = 3 + attribute components`` columns);
* **given** (``given=[(n_p, 3) float64 per primitive]``): the positions of a
  mesh outside the stream, in the stream's vertex order; only the connectivity
  of the splits is replayed and the residuals are skipped.  NaN rows mark
  vertices with no counterpart: carriers whose vertex or ring touches one are
  returned with ``known`` False.

Several primitives share one stream order; ``Carriers.batch`` numbers batches
over all of them, as the watermark's carrier slots do.  ``nbar`` (the base mean
edge of the carrier's primitive, in the units of its positions) and ``scale``
(the primitive's public watermark scale) travel with each batch, so a reader
needs no per-primitive bookkeeping of its own.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..errors import ChecksumError, FormatError, MeshError, TruncatedError
from ..format import BaseEvent, ChunkEvent, HeaderEvent
from ..format.extension import is_face_chunk, payload_version
from ..format.records import unpack_batches
from ..format.records_v2 import ChunkDecoder, decode_chunk, decode_face_chunk, plane_columns
from ..progressive.grid import SRGB8, AttributeGrid, Grid
from ..progressive.seams import twin_rows
from ..progressive.topology import mean_edge_length
from ..progressive.vsplit import MeshState, apply_batch, split_topology


@dataclass(frozen=True)
class Carriers:
    """The watermark carriers of one applied batch.

    ``points`` (k, 3) float64 positions of the new vertices, ``centroid`` (k, 3)
    float64 their ring means, ``known`` (k,) bool (False: not readable, a
    vertex without counterpart); ``batch`` the stream-wide batch index,
    ``primitive`` its primitive, ``nbar`` / ``scale`` that primitive's;
    ``vertices`` (k,) int64 the new vertices' ids in the primitive; ``positions``
    (n, >=3) the primitive's positions (the rings' rows are final) and ``topology``
    the batch's :class:`~pmwm_codec.progressive.vsplit.SplitTopology`, from which
    :attr:`descriptor` describes the rings; :attr:`twin` (k,) bool the seam twins as the
    stream decodes them (a new vertex on the position of an earlier one of its batch:
    it carries no code, spec/watermark.md "Repeated points"), also for given positions,
    found from ``decoded`` (k, 3) the new vertices' decoded positions when first asked.
    """

    primitive: int
    batch: int
    points: np.ndarray
    centroid: np.ndarray
    known: np.ndarray
    nbar: float
    scale: float | None
    vertices: np.ndarray | None = None
    positions: np.ndarray | None = None
    topology: object = None
    decoded: np.ndarray | None = None

    @cached_property
    def twin(self) -> np.ndarray | None:
        """(k,) bool the seam twins (class docstring); None without ``decoded``."""
        if self.decoded is None:
            return None
        return twin_rows(self.decoded) != np.arange(len(self.decoded))

    @cached_property
    def descriptor(self):
        """The batch's :class:`~pmwm_codec.watermark.codec.RingDescriptor` (the rings never move later; computed once)."""
        from ..watermark.codec import ring_descriptor

        return ring_descriptor(self.positions, self.topology, self.nbar)


def value_width(ext: dict) -> int:
    """``D``: residual columns of a primitive's splits (3 + attribute components)."""
    return 3 + sum(len(spec["origin"]) for spec in ext.get("attributes", ()))


def srgb8_columns(ext: dict) -> list:
    """``[(column, AttributeGrid, semantic)]``: a primitive's ``srgb8`` attributes, each with its first column in the
    (n, D) values (positions' 3 first)."""
    out, col = [], 3
    for spec in ext.get("attributes", ()):
        grid = AttributeGrid.from_config(spec)
        if grid.transfer == SRGB8:
            out.append((col, grid, spec["semantic"]))
        col += grid.width
    return out


def check_payload_codec(ext: dict) -> None:
    """Refuse a chunk payload codec this reader does not know (:func:`~pmwm_codec.format.extension.payload_version`)."""
    payload_version(ext)


def _base_values(event: BaseEvent, ext: dict) -> np.ndarray:
    """(n0, D) int64: a base mesh's grid positions, then its quantized attributes."""
    attrs = event.attributes_int
    if attrs is None:
        attrs = np.zeros((len(event.positions_int), 0), np.int64)
    if attrs.shape[1] != value_width(ext) - 3:
        raise FormatError("base mesh: attribute columns differ from the extension's attributes")
    return np.concatenate([event.positions_int, attrs], axis=1)


class Replay:
    """Per-primitive mesh states driven by container events (module docstring).

    ``given``: None to decode positions from the stream, or one (n_p, 3) float64
    array per progressive primitive (its full-resolution positions in the
    stream's vertex order, NaN where unknown).  ``nbars``: per-primitive
    reference lengths to use instead of the base mean edge (given positions of
    a partial mesh measure it themselves).  ``max_chunks``: apply no chunk after
    this many.  ``carriers``: False when nobody reads them (a decode without a key):
    with decoded positions, :meth:`on_event` then returns none and the batches are applied
    without the work of listing their new vertices and ring means.
    """

    def __init__(self, given: list | None = None, *, nbars: list | None = None, max_chunks: int | None = None,
                 carriers: bool = True):
        self.given = given
        self.carriers = carriers
        self._nbar_override = nbars
        self.max_chunks = max_chunks
        self.header: HeaderEvent | None = None
        self.exts: tuple = ()
        self.grids: list = []
        self.states: list = []
        self.nbars: list = []
        #: per primitive, its base mesh's faces (f_p, 3) int64
        self.base_faces: list = []
        #: given positions: per primitive, the stream's own decoded integer state, which a version 2
        #: payload decodes against and the seam twins come from (never read as codes); None otherwise
        self.shadows: list = []
        #: per primitive, the version 2 :class:`~pmwm_codec.format.records_v2.ChunkDecoder` the next chunk continues
        #: (None for version 1)
        self.models: list = []
        #: per primitive, its ``srgb8`` attributes (:func:`srgb8_columns`), whose bytes every chunk's new vertices
        #: must keep in 0..255
        self.srgb8: list = []
        self.chunks_applied = 0
        self.batches_applied = 0

    @property
    def ready(self) -> bool:
        """True once every base mesh is in."""
        return bool(self.exts) and len(self.states) == len(self.exts)

    def on_event(self, event) -> list:
        """Consume one event; return the :class:`Carriers` of the batches it applied."""
        if isinstance(event, HeaderEvent):
            self._on_header(event)
        elif isinstance(event, BaseEvent):
            self._on_base(event)
        elif isinstance(event, ChunkEvent):
            try:
                return self._on_chunk(event)
            except FormatError as exc:  # the payload's own errors name the chunk, as the container's do
                if re.match(r"chunk \d", str(exc)) or type(exc) in (ChecksumError, TruncatedError):
                    raise
                text, n = str(exc), event.index + 1
                named = f"chunk {n} {text[len('chunk '):]}" if text.startswith("chunk payload") else f"chunk {n}: {text}"
                raise type(exc)(named) from None
        return []

    def _on_header(self, event: HeaderEvent) -> None:
        self.header = event
        self.exts = tuple(event.extensions or (event.extension,))
        for ext in self.exts:
            check_payload_codec(ext)
        self.grids = [Grid.from_config(e["grid"]) for e in self.exts]
        if self.given is not None:
            if len(self.given) != len(self.exts):
                raise MeshError(f"{len(self.given)} position sets for {len(self.exts)} progressive primitives")
            for p, (pts, ext) in enumerate(zip(self.given, self.exts)):
                if np.shape(pts) != (int(ext["vertexCount"]), 3):
                    raise MeshError(f"primitive {p}: {len(pts)} positions for {ext['vertexCount']} vertices")

    def _on_base(self, event: BaseEvent) -> None:
        p = event.primitive
        ext = self.exts[p]
        n, m = int(ext["vertexCount"]), int(ext["faceCount"])
        n0 = len(event.positions_int)
        decoded = MeshState(_base_values(event, ext), event.faces, n, m, grow=True)  # memory follows the chunks
        shadow = None
        if self.given is None:
            self.states.append(decoded)
            base = event.positions_int
        else:
            base = self.given[p][:n0]
            self.states.append(MeshState(base, event.faces, n, m, dtype=np.float64, grow=True))
            shadow = decoded
        self.shadows.append(shadow)
        self.models.append(ChunkDecoder(plane_columns(ext.get("attributes"))) if payload_version(ext) == 2 else None)
        self.base_faces.append(np.asarray(event.faces, np.int64))
        self.srgb8.append(srgb8_columns(ext))  # the base read them: their grids are valid
        if self._nbar_override is not None:
            self.nbars.append(float(self._nbar_override[p]))
        elif "watermark" in ext:
            self.nbars.append(mean_edge_length(base, event.faces))
        else:  # only the watermark reads the reference length: a plain stream skips the edge scan
            self.nbars.append(float("nan"))

    def _on_chunk(self, event: ChunkEvent) -> list:
        if self.max_chunks is not None and self.chunks_applied >= self.max_chunks:
            return []
        p = event.primitive
        state, ext = self.states[p], self.exts[p]
        scale = ext["watermark"]["scale"] if "watermark" in ext else None
        meta = ext["chunks"][event.chunk]
        own = state if self.given is None else self.shadows[p]  # the stream's own integers
        n_before = own.n
        out = []
        face_chunk = is_face_chunk(ext, meta)
        if face_chunk:
            self._faces(p, event, meta)
        for batch, own_topo in () if face_chunk else self._batches(p, event):
            self.batches_applied += 1
            if self.given is None and (not self.carriers or scale is None):
                continue
            if self.given is None:
                topo = own_topo
                points = state.positions[topo.u, :3].astype(np.float64)
                centroid = topo.centroid()[:, :3]
                known = np.ones(len(points), bool)
                decoded = points
            else:
                topo = split_topology(state, batch.v, batch.symbols)
                points = self.given[p][topo.u]
                state.positions[topo.u] = points
                centroid = topo.centroid()
                known = np.isfinite(points).all(axis=1) & np.isfinite(centroid).all(axis=1)
                decoded = self.shadows[p].positions[own_topo.u, :3]
            if scale is None:
                continue  # a primitive without a watermark object carries none
            out.append(Carriers(p, self.batches_applied - 1, points, centroid, known, self.nbars[p], scale,
                                topo.u, state.positions, topo, decoded))
        self.chunks_applied += 1
        if state.n != meta["vertexCount"] or state.m != meta["faceCount"]:
            raise FormatError(f"chunk {event.index + 1}: vertex/face counts differ from its index entry")
        for col, grid, semantic in self.srgb8[p]:  # a colour byte outside 0..255 refuses the chunk (spec/README.md)
            grid.srgb8_bytes(own.positions[n_before : own.n, col : col + grid.width], semantic)
        return out

    def _faces(self, p: int, event: ChunkEvent, meta: dict) -> None:
        """Apply a face chunk (bitstream.md §8.6) to the primitive's state (and its shadow)."""
        own = self.states[p] if self.given is None else self.shadows[p]
        n = own.n
        got = decode_face_chunk(event.payload, own, self.models[p], meta["vertexCount"] - n, meta["faceCount"] - own.m)
        if own is not self.states[p]:  # the given mesh: its own values for the new vertices
            state = self.states[p]
            state.reserve(own.n, state.m + got)
            state.faces[state.m : state.m + got] = own.faces[own.m - got : own.m]
            state.positions[n : own.n] = self.given[p][n : own.n]
            state.n, state.m = own.n, state.m + got

    def _batches(self, p: int, event: ChunkEvent):
        """Yield ``(SplitBatch, SplitTopology)`` per batch of the chunk, the batch applied (topology and
        values) to the stream's own integer state: the primitive's state with decoded positions, its
        shadow with given positions (the caller then replays the topology over the given ones).  Version 2
        batches nobody reads (decoded positions, no carriers) are applied and not listed: ``(None, None)``."""
        own = self.states[p] if self.given is None else self.shadows[p]
        ext = self.exts[p]
        if payload_version(ext) == 2:
            yield from decode_chunk(event.payload, own, self.models[p], listed=self.carriers or self.given is not None)
            return
        for batch in unpack_batches(event.payload, max_splits=own.vertex_limit, width=value_width(ext)):
            yield batch, apply_batch(own, batch)

    def current(self, p: int) -> tuple[np.ndarray, np.ndarray]:
        """Primitive ``p`` now: values (n, D) (views) and faces (m, 3) int64 (views)."""
        st = self.states[p]
        return st.positions[: st.n], st.faces[: st.m]
