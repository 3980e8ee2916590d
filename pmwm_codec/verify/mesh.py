"""Verifying a mesh that left the stream against the original ``.pmw``.

Contract
--------
:func:`verify_mesh` ``(mesh, reference_source, key, watermark=None) -> MeshVerification``

* ``mesh``: a :class:`~pmwm_codec.mesh.Mesh`, a mesh file path, or a
  ``(positions (n, 3), faces (m, 3))`` pair -- exported, moved, scaled,
  re-ordered, re-saved as float32, flattened from a glTF asset into one mesh,
  or attacked;
* ``reference_source``: the original ``.pmw`` (path, bytes, binary file),
  complete;
* ``key``: a :class:`~pmwm_codec.watermark.key.WatermarkKey` or a key file path
  (a key whose fingerprint differs from the reference's: verdict ``not-authentic``);
* ``watermark``: the reference image (path or array); default the key's.

The reference is parsed once.  Its full decode as the asset's scene shows it (every
progressive primitive placed by its nodes' world matrices, once per showing, as a decoded
GLB is flattened and as ``pmw decode`` writes OBJ / PLY / STL; the primitives concatenated
in stream order, as stored, when the scene shows each once where it is stored or its
placements do not read) is the target of :func:`.correspond.correspond` (exact topological
match first, similarity registration + nearest neighbours otherwise).  A mesh with fewer vertices
that is exactly, by topology, the decode after fewer chunks (a level a decoder shows, exported) is
checked against that level instead, its codes those of the chunks up to it, as ``verify`` reads the
``cut`` file of that level (``level`` in the result).  A placed mesh is
taken back into each primitive's stored coordinates (the similarity that best maps the
scene onto the mesh undone, then each showing's matrix; a vertex shown several times is
read from its first showing that has a counterpart), so that a scene placed by any
invertible matrices reads as its stored primitives do.  The mesh's positions, put in the
reference's vertex order, are then replayed through the split
connectivity of the reference (:class:`~pmwm_codec.stream.replay.Replay` with
given positions) and every carrier's code is read as a decoder reads it, so the
codes are invariant to rotation, uniform scale and translation (``nbar`` is
measured on the mesh's own base vertices).  Carriers whose vertex or ring has
no counterpart stay unread.  The scores and the verdict are the stream
verifier's (:class:`~pmwm_codec.watermark.verify.Verifier`); vertices of the mesh that
no reference vertex explains (a graft), and faces that differ from the reference's among the
vertices it has where the reference has them (rewired, added or removed; compared as sets of
corners, so winding and order are free), and vertices that are not where the reference has them
(:func:`_moved_rows`), make it ``tampered``; the carriers whose code no longer reads, a graft's
vertices, a changed face's corners and the moved vertices are the mesh's vertices ``tamper`` names.

``MeshVerification.as_json()`` is the ``pmw verify MESH --reference ... --json``
object.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from ..errors import FormatError, InputFormatError, MeshError, WatermarkKeyError
from ..format import BaseEvent, ChunkEvent, EndEvent, HeaderEvent, iter_events
from ..format.extension import EXTENSION_NAME
from ..format.gltf import placed_by_nodes, progressive_placements, scene_mesh
from ..format.mac import SCENE_MAC, MacChecker, Scene
from ..mesh import Mesh, checked_mesh, read_mesh
from ..meshexport import _unique_rows
from ..progressive.topology import unique_edges
from ..sources import read_all
from ..stream.replay import Replay
from ..watermark import codec as wm
from ..watermark.key import as_key
from ..watermark.verify import Verifier, image_note
from .correspond import Correspondence, correspond, exact_correspondence, umeyama

__all__ = ["MeshVerification", "verify_mesh"]

#: Copies of one stored vertex (a primitive the scene shows several times) read from a placed mesh
#: agree when they lie within this fraction of the scene's size of each other once taken back to the
#: stored coordinates (float32 output and the transforms round them ~1e-7 apart).
COPY_TOLERANCE = 1e-5
#: A registered vertex lies where the reference has it (and its faces are compared, :func:`_changed_faces`)
#: within this many reference mean edge lengths: float32 storage and a similarity move it ~1e-5 of an edge.
FACE_PAIR_TOLERANCE = 1e-3


@dataclass
class MeshVerification:
    """The result of :func:`verify_mesh`.

    ``verdict`` authentic | tampered | not-authentic | inconclusive; ``nc``, ``psnr_db``
    (inf when bit-exact), ``centered_nc`` of the recovered watermark against the
    reference; ``ber`` bit error rate of the codes read against the codes the
    reference embeds (None without a reference image); ``code_match`` fraction
    of codes read that match; ``carriers_read`` / ``carriers_total``;
    ``correspondence`` how the vertex order was found (``identity``,
    ``faces-reordered``, ``permutation``, ``registration``); ``coverage``
    fraction of reference vertices with a counterpart; ``registration_rms``
    RMS pair distance after registration (reference units, None for exact
    methods); ``watermark`` (s, s) uint8 the recovered image; ``key_matches`` False
    when the reference's public key fingerprint is another key's (then ``not-authentic``);
    ``flagged`` (f,) int64
    vertices of the checked mesh whose carrier code no longer reads, and the grafted ones (``foreign``; the tamper map);
    ``foreign`` the mesh holds vertices no reference vertex explains (registration only:
    farther than the tolerance from every reference vertex); ``binding`` the file's
    (``""``: a legacy mark, never ``authentic``); ``reference_mac`` the key holder's MACs over the
    reference file (:meth:`Reference.authenticate`): a reference whose base, chunks or scene fail them is
    not the key holder's file, so nothing checked against it is ``authentic``; ``image_note`` the line
    saying that a bit-exact ``watermark`` beside another verdict than ``authentic`` is no match the verdict
    makes (:func:`~pmwm_codec.watermark.verify.image_note`), else None; ``level`` the number of chunks of the
    reference's stream the mesh was found to be the decode after (a level short of the whole stream, which
    ``reference_vertices``, ``coverage`` and the codes are then that level's), None for the whole stream;
    ``chunks_total`` the stream's chunks.
    """

    verdict: str
    nc: float | None
    psnr_db: float | None
    centered_nc: float | None
    ber: float | None
    code_match: float | None
    carriers_read: int
    carriers_total: int
    correspondence: str
    coverage: float
    registration_rms: float | None
    vertices: int
    faces: int
    reference_vertices: int
    coefficients: int
    seconds: float
    watermark: np.ndarray | None = None
    bit_exact: bool = False
    key_matches: bool = True
    flagged: np.ndarray | None = None
    foreign: bool = False
    binding: str = ""
    reference_mac: dict | None = None
    image_note: str | None = None
    level: int | None = None
    chunks_total: int = 0

    def tamper(self) -> dict:
        """``{"flagged": [mesh vertex ids whose carrier code no longer reads], "fraction": of the mesh's vertices}``."""
        flagged = [] if self.flagged is None else [int(i) for i in self.flagged]
        return {"flagged": flagged, "fraction": len(flagged) / max(1, self.vertices)}

    def as_json(self) -> dict:
        """The ``pmw verify MESH --reference --json`` object (non-finite numbers are ``null``)."""

        def num(x):
            return None if x is None or not math.isfinite(float(x)) else float(x)

        return {
            "verdict": self.verdict, "nc": num(self.nc), "psnr_db": num(self.psnr_db),
            "centered_nc": num(self.centered_nc), "ber": num(self.ber), "code_match": num(self.code_match),
            "carriers_read": self.carriers_read, "carriers_total": self.carriers_total,
            "coefficients": self.coefficients, "bit_exact": self.bit_exact,
            "correspondence": self.correspondence, "coverage": self.coverage,
            "registration_rms": num(self.registration_rms), "vertices": self.vertices, "faces": self.faces,
            "reference_vertices": self.reference_vertices, "key_matches": self.key_matches,
            "tamper": self.tamper(), "foreign": self.foreign, "binding": self.binding or None,
            "reference_mac": self.reference_mac, "image_note": self.image_note,
            "level": None if self.level is None else {"chunks": self.level, "chunks_total": self.chunks_total},
        }

    def reference_note(self) -> str | None:
        """A line saying why the reference is not the key holder's file as written (None when it is, or
        when it carries no MAC to tell)."""
        macs = self.reference_mac or {}
        parts = [f"{'chunk ' + str(c) if c else 'its base mesh'}" for c in macs.get("failed", [])]
        if macs.get("scene") is False:
            why = macs.get("scene_error")
            parts.append("its scene (nodes, materials, other meshes" + (f"; {why}" if why else "") + ")")
        if not parts:
            return None
        return "the reference is not the key holder's file as written (MAC mismatch: " + ", ".join(parts) + ")"


def _as_mesh(mesh) -> Mesh:
    if isinstance(mesh, Mesh):
        if mesh.vertex_count == 0 or mesh.face_count == 0:  # the registration's eigen-solver failed on it
            raise MeshError("verify_mesh: the mesh has no vertices or no faces")
        return mesh
    if isinstance(mesh, (str, os.PathLike)):
        return read_mesh(mesh)
    if isinstance(mesh, tuple) and len(mesh) == 2:
        return checked_mesh(mesh[0], mesh[1])
    raise MeshError(f"verify_mesh: expected a Mesh, a path or (positions, faces), got {type(mesh).__name__}")


@dataclass
class Reference:
    """The original ``.pmw``, parsed once.

    ``events`` every container event; ``params`` its public watermark parameters;
    ``parts`` per progressive primitive ``(positions (n_p, 3) float64, base
    faces (f_p, 3) int64)`` of the full decode; ``positions`` (n, 3) float64 and
    ``faces`` (m, 3) int64 all primitives concatenated in stream order.
    ``placements``: per primitive the (4, 4) world matrices of its showings, or None when the
    scene shows each primitive once where it is stored (or its placements do not read);
    ``scene_positions`` (N, 3) / ``scene_faces`` (M, 3) the mesh a check is matched against
    (:func:`~pmwm_codec.format.gltf.scene_mesh` of the parts, or ``positions`` / ``faces``);
    ``spans`` per primitive the ``(start, stop)`` rows of its showings in it; ``part_faces`` per
    primitive its full-resolution faces (m_p, 3) int64 in its own vertex ids.  ``chunks``: None for the full
    decode; a level of the stream otherwise (:meth:`at_level`): the decode after that many chunks, whose
    ``parts``, ``positions``, ``faces`` and scene are that level's (its codes are read by replaying those chunks).
    ``bins``: per primitive the length one step of its codes stands for in its stored coordinates (its reference
    length over its ``scale``: a move smaller than half of it may leave a code as it was, by design), NaN for a
    primitive without a watermark.
    """

    events: list
    params: wm.WatermarkParams
    parts: list
    positions: np.ndarray
    faces: np.ndarray
    placements: list | None = None
    scene_positions: np.ndarray | None = None
    scene_faces: np.ndarray | None = None
    spans: list | None = None
    part_faces: list | None = None
    data: bytes = b""
    chunks: int | None = None
    bins: list | None = None

    def __post_init__(self):
        #: (P + 1,) int64: where each primitive's rows start in ``positions``.
        self.starts = np.cumsum([0] + [len(pos) for pos, _ in self.parts])
        if self.placements is None:
            self.scene_positions, self.scene_faces = self.positions, self.faces
            self.spans = [[(int(a), int(b))] for a, b in zip(self.starts[:-1], self.starts[1:])]
        else:
            self.scene_positions, self.scene_faces, self.spans = scene_mesh(
                [pos for pos, _ in self.parts], self.part_faces, self.placements, oriented=True)

    def stored(self, scene_points: np.ndarray) -> tuple:
        """(N, 3) points in the order of ``scene_positions`` (NaN: no counterpart), in any similar frame ->
        ``(points (n, 3) in the reference's stored order and coordinates, apart (k,) int64)`` (see the module
        docstring).  ``apart``: the rows of ``scene_points`` that a later showing of a primitive puts
        elsewhere than its first showing with a counterpart does (copies of one stored vertex must agree,
        to :data:`COPY_TOLERANCE` of the scene's size: an edit of a copy that is not read)."""
        if self.placements is None:
            return scene_points, np.zeros(0, np.int64)
        ok = np.isfinite(scene_points).all(axis=1)
        out = np.full((len(self.positions), 3), np.nan)
        if not ok.any():
            return out, np.zeros(0, np.int64)
        frame = _robust_similarity(scene_points, self.scene_positions, ok)
        size = float(np.ptp(self.scene_positions, axis=0).max())
        apart = []
        for start, matrices, spans in zip(self.starts, self.placements, self.spans):
            for matrix, (a, b) in zip(matrices, spans):
                rows = out[start : start + b - a]
                local = (frame[a:b] - matrix[:3, 3]) @ np.linalg.inv(matrix[:3, :3]).T
                world = np.linalg.norm(((local - rows) @ matrix[:3, :3].T), axis=1)  # NaN where either is missing
                apart.append(a + np.flatnonzero(world > COPY_TOLERANCE * size))
                fill = ~np.isfinite(rows).all(axis=1) & ok[a:b]
                rows[fill] = local[fill]
        return out, np.concatenate(apart)

    def showing_order(self, scene_points: np.ndarray) -> np.ndarray:
        """(N,) int64: the order of the rows of ``scene_points`` (as :meth:`stored` takes them) that puts the
        copies of a primitive shown several times at the showings where they lie.  A topological match maps
        each connected copy on its own, and congruent copies alike, so it may give one copy's vertices to
        another's showing: each copy goes to the showing whose reference positions it lies nearest (an
        assignment per primitive) once the scene's similarity is undone.  That similarity is fitted on the
        primitives shown once, or, when every primitive is shown several times, on the first one's first
        copy taken as each of its showings in turn (the hypothesis whose assignment fits best is kept).
        The identity where every primitive is shown once."""
        order = np.arange(len(scene_points))
        ok = np.isfinite(scene_points).all(axis=1)
        if self.placements is None or all(len(spans) < 2 for spans in self.spans) or not ok.any():
            return order
        once = np.zeros(len(ok), bool)
        for spans in self.spans:
            if len(spans) == 1:
                once[spans[0][0] : spans[0][1]] = True
        if np.count_nonzero(once & ok) >= 3:
            frames = [_robust_similarity(scene_points, self.scene_positions, once & ok)]
        else:
            spans = next(spans for spans in self.spans if len(spans) > 1)
            a, b = spans[0]
            frames = []
            for c, d in spans:
                pairs = np.flatnonzero(ok[a:b])
                if len(pairs) >= 3:
                    sc, R, t = umeyama(scene_points[a:b][pairs], self.scene_positions[c:d][pairs])
                    frames.append(sc * scene_points @ R.T + t)
        best = (np.inf, order)
        for frame in frames:
            total, trial = self._assign(frame)
            if total < best[0]:
                best = (total, trial)
        return best[1]

    def _assign(self, frame: np.ndarray) -> tuple:
        """``(total cost, order)``: :meth:`showing_order`'s assignment of copies to showings for the scene points
        ``frame`` (N, 3) already in the reference's frame; a copy's cost at a showing is its mean distance to it."""
        from scipy.optimize import linear_sum_assignment

        order = np.arange(len(frame))
        total = 0.0
        for spans in self.spans:
            if len(spans) < 2:
                continue
            cost = np.zeros((len(spans), len(spans)))
            for i, (a, b) in enumerate(spans):
                for j, (c, d) in enumerate(spans):
                    gap = np.linalg.norm(frame[a:b] - self.scene_positions[c:d], axis=1)
                    cost[i, j] = np.mean(gap[np.isfinite(gap)]) if np.isfinite(gap).any() else 0.0
            rows, cols = linear_sum_assignment(cost)
            total += float(cost[rows, cols].sum())
            for i, j in zip(rows, cols):
                order[spans[j][0] : spans[j][1]] = np.arange(*spans[i])
        return total, order

    def scene_rows(self, stored: np.ndarray) -> np.ndarray:
        """The rows of ``scene_positions`` of the stored vertices ``stored`` (k,) int64 (every showing of each)."""
        part = np.searchsorted(self.starts, stored, side="right") - 1
        rows = [a + stored[part == i] - self.starts[i] for i, spans in enumerate(self.spans) for a, _ in spans]
        return np.concatenate(rows) if rows else np.zeros(0, np.int64)

    def split(self, positions: np.ndarray) -> list:
        """(n, 3) positions in the reference's order -> one (n_p, 3) view per primitive."""
        if len(positions) != len(self.positions):
            raise MeshError(f"{len(positions)} positions for the reference's {len(self.positions)} vertices")
        return np.split(positions, self.starts[1:-1])

    @classmethod
    def read(cls, source) -> "Reference":
        try:
            data = read_all(source)
        except OSError as exc:
            raise InputFormatError(f"cannot read the reference file: {exc}") from None
        events = list(iter_events(data))
        header = events[0]
        assert isinstance(header, HeaderEvent)
        cfg = header.extension.get("watermark")
        if cfg is None:
            raise InputFormatError("the reference file carries no watermark")
        end = events[-1]
        if isinstance(end, EndEvent) and not end.complete:
            raise FormatError("the reference file is cut short: verify against the complete original")
        return cls._replayed(events, wm.WatermarkParams.from_config(cfg), bytes(data))

    @classmethod
    def _replayed(cls, events: list, params: wm.WatermarkParams, data: bytes, chunks: int | None = None) -> "Reference":
        """The reference decoded from its ``events`` (after ``chunks`` chunks; all when None)."""
        replay = Replay(max_chunks=chunks)
        for event in events:
            replay.on_event(event)
        parts, faces = [], []
        for p, grid in enumerate(replay.grids):
            values, fac = replay.current(p)
            parts.append((grid.dequantize(values[:, :3]), replay.base_faces[p]))
            faces.append(np.array(fac))
        starts = np.cumsum([0] + [len(pos) for pos, _ in parts])
        positions = np.concatenate([pos for pos, _ in parts])
        header = events[0]
        placements = None
        if placed_by_nodes(header.gltf_json):
            placements = progressive_placements(header.gltf_json, EXTENSION_NAME)[0]
        bins = [nbar / ext["watermark"]["scale"] * grid.step if "watermark" in ext else float("nan")
                for nbar, ext, grid in zip(replay.nbars, replay.exts, replay.grids)]  # nbar: in grid units
        return cls(events, params, parts, positions, np.concatenate([f + a for f, a in zip(faces, starts)]),
                   placements, part_faces=faces, data=data, chunks=chunks, bins=bins)

    def scene_bins(self) -> np.ndarray:
        """(N,) float64: per row of ``scene_positions``, its primitive's code step (``bins``) as its showing
        scales it (the largest stretch of the showing's matrix), 0 for a primitive without a watermark."""
        out = np.zeros(len(self.scene_positions))
        for p, spans in enumerate(self.spans):
            size = self.bins[p] if np.isfinite(self.bins[p]) else 0.0
            stretch = [1.0] * len(spans) if self.placements is None else \
                [float(np.linalg.norm(matrix[:3, :3], 2)) for matrix in self.placements[p]]
            for (a, b), factor in zip(spans, stretch):
                out[a:b] = size * factor
        return out

    @property
    def unit(self) -> float:
        """The scene's mean edge length (1.0 for a scene whose edges all have none): the length the tolerances
        of a check are in."""
        if not hasattr(self, "_unit"):
            from ..progressive.topology import mean_edge_length

            self._unit = mean_edge_length(self.scene_positions, self.scene_faces) or 1.0
        return self._unit

    @property
    def chunks_total(self) -> int:
        """The number of chunks of the stream (every primitive's)."""
        return int(self.events[0].chunk_count)

    def level_counts(self) -> list:
        """``[(chunks, vertices, faces)]``: the scene's vertex and face counts (every showing of a primitive
        counted) after each number of chunks short of the whole stream, the base meshes first (0), from the
        chunk index alone."""
        header = self.events[0]
        exts = header.extensions or (header.extension,)
        showings = np.array([len(spans) for spans in self.spans], np.int64)
        counts = np.zeros((len(exts), 2), np.int64)
        out = []
        for event in self.events:
            if isinstance(event, BaseEvent):
                counts[event.primitive] = len(event.positions_int), len(event.faces)
            elif isinstance(event, ChunkEvent):
                if event.index == 0:
                    out.append((0, *map(int, showings @ counts)))
                meta = exts[event.primitive]["chunks"][event.chunk]
                counts[event.primitive] = meta["vertexCount"], meta["faceCount"]
                if event.index + 1 < self.chunks_total:
                    out.append((event.index + 1, *map(int, showings @ counts)))
        return out

    def at_level(self, chunks: int) -> "Reference":
        """This reference as its stream stands after ``chunks`` chunks (a level a decoder shows)."""
        return self._replayed(self.events, self.params, self.data, chunks)

    def given(self, positions: np.ndarray) -> list:
        """(n, 3) positions in this reference's order -> one (N_p, 3) array per primitive of its full vertex
        count (the rows past this level's vertices NaN), as :class:`~pmwm_codec.stream.replay.Replay` takes them."""
        header = self.events[0]
        exts = header.extensions or (header.extension,)
        out = []
        for part, ext in zip(self.split(positions), exts):
            full = np.full((int(ext["vertexCount"]), 3), np.nan)
            full[: len(part)] = part
            out.append(full)
        return out

    def authenticate(self, key) -> dict:
        """The key holder's MACs over this file, as ``pmw verify FILE.pmw`` checks them (bitstream.md §6.3):
        ``{"checked": n, "failed": [chunk numbers, 0 the bases], "missing": [...], "scene": True | False |
        None, "scene_error": why}`` (``scene`` None: the file carries no ``sceneMac``; ``scene_error`` the line
        saying why a scene that has no canonical form is not the key holder's, e.g. one over
        ``MAX_SCENE_VALUES``: :meth:`~pmwm_codec.format.mac.Scene.check`)."""
        checker = MacChecker(key.mac_key())
        for event in self.events:
            checker.tally(event)
        header = self.events[0]
        found = [ext.get(SCENE_MAC) for ext in header.extensions or (header.extension,)]
        scene, why = (None, None) if all(f is None for f in found) else \
            Scene(header.gltf_json).check(key.mac_key(), self.data[header.bin_offset:], found)
        return {"checked": checker.checked, "failed": checker.failed, "missing": checker.missing, "scene": scene,
                "scene_error": why}


def verify_mesh(mesh, reference_source, key, watermark=None, *, tolerance: float = 0.5,
                correspondence: Correspondence | None = None) -> MeshVerification:
    """Verify ``mesh`` against the original ``.pmw`` ``reference_source`` with ``key`` (module docstring).

    ``tolerance``: registration only, the largest pair distance in reference mean
    edge lengths; ``correspondence``: skip the search and use this one.
    """
    t0 = time.perf_counter()
    m = _as_mesh(mesh)
    key = as_key(key)
    if key is None:
        raise WatermarkKeyError("verify_mesh needs the key of the reference file")
    ref = Reference.read(reference_source)
    ref_image = None
    if watermark is not None:
        from ..watermark.image import load_watermark

        ref_image, _ = load_watermark(watermark)
        key.check_reference(ref_image, watermark)  # before the correspondence search

    corr = correspondence
    if corr is None:
        ref, corr = _level_of(m, ref)
    if corr is None:
        corr = correspond(m.positions, m.faces, ref.scene_positions, ref.scene_faces, tolerance=tolerance)
    pts = np.full((len(ref.scene_positions), 3), np.nan)
    pts[corr.valid] = np.asarray(m.positions, np.float64)[corr.index[corr.valid]]
    order = ref.showing_order(pts)
    moved = _moved_rows(pts[order], ref, mutual=corr.method == "registration")
    pts, apart = ref.stored(pts[order])
    pts = _float32_storage_undone(pts, ref.positions)
    index = corr.index[order]
    nbars = None if corr.valid.all() else _partial_nbars(ref, ref.split(pts), corr)
    verifier = read_given(ref, pts, key, ref_image, nbars=nbars)
    grafted = _foreign_vertices(m, ref, corr, tolerance)
    refaced = _changed_faces(m, ref, corr)
    verifier.foreign = len(grafted) > 0 or len(apart) > 0 or len(refaced) > 0 or len(moved) > 0
    est = verifier.estimate()
    flagged = index[np.concatenate([ref.scene_rows(verifier.tamper(ref.starts)), apart, moved])]
    flagged = np.unique(np.concatenate([flagged[flagged >= 0], grafted, refaced]))  # a graft's, a changed face's too
    owns = key.owns(ref.params.fingerprint)
    macs = ref.authenticate(key) if owns else None
    written = macs is None or (not macs["failed"] and macs["scene"] is not False)  # the reference as the key holder wrote it
    verdict = est.verdict if owns and written else "not-authentic"
    why = ([] if written else ["the reference is not the key holder's file as written"]) + \
        (["vertices the reference does not explain"] if len(grafted) or len(apart) else []) + \
        (["faces the reference does not have"] if len(refaced) else []) + \
        (["vertices moved from where the reference has them"] if len(moved) else [])
    return MeshVerification(
        image_note=image_note(verdict, est.bit_exact, est.inconsistent, "; ".join(why)),
        verdict=verdict, key_matches=owns, reference_mac=macs, nc=est.nc, psnr_db=est.psnr_db, centered_nc=est.centered_nc, ber=est.ber,
        code_match=est.code_match, carriers_read=est.carriers_read, carriers_total=ref.params.carriers,
        correspondence=corr.method, coverage=corr.coverage, registration_rms=corr.rms,
        vertices=m.vertex_count, faces=m.face_count, reference_vertices=len(ref.scene_positions),
        coefficients=est.coefficients, seconds=time.perf_counter() - t0, watermark=est.watermark,
        bit_exact=est.bit_exact, flagged=flagged, foreign=bool(len(grafted) or len(apart)), binding=ref.params.binding,
        level=ref.chunks, chunks_total=ref.chunks_total,
    )


def _level_of(mesh: Mesh, ref: Reference) -> tuple:
    """``(reference, correspondence)``: ``ref`` at the level of its stream that ``mesh`` is (a decode after fewer
    chunks, exported: ``pmw decode --chunks N``, a viewer's level) with the correspondence found, or ``(ref,
    None)``.  A level is taken only when the mesh has its vertex count and matches it exactly, by topology (up to
    order, a similarity and float32 storage); a level of the mesh's face count is tried first.  So is, after
    them, a level of the mesh's face count and more vertices, welded as an OBJ's or OFF's ``v`` records weld it
    (one per distinct float32 position, as an STL's corners read: an asset's vertices split at its texture seams are
    one there), the
    correspondence then naming each level vertex the welded one.  Anything else is checked against the whole
    stream, as before."""
    n, m = mesh.vertex_count, mesh.face_count
    if n >= len(ref.scene_positions):
        return ref, None
    counts = ref.level_counts()
    levels = [(faces != m, chunks) for chunks, vertices, faces in counts if vertices == n]
    for _, chunks in sorted(levels):
        level = ref.at_level(chunks)
        corr = exact_correspondence(mesh.positions, mesh.faces, level.scene_positions, level.scene_faces)
        if corr is not None:
            return level, corr
    for chunks in [chunks for chunks, vertices, faces in counts if faces == m and vertices > n]:
        level = ref.at_level(chunks)
        welded, row = _unique_rows(np.asarray(level.scene_positions, np.float32))
        if len(welded) != n:
            continue
        corr = exact_correspondence(mesh.positions, mesh.faces, welded, row[np.asarray(level.scene_faces, np.int64)])
        if corr is not None:
            return level, Correspondence(corr.method, corr.index[row], corr.valid[row])
    return ref, None


def _robust_similarity(points: np.ndarray, target: np.ndarray, ok: np.ndarray, rounds: int = 4, *,
                       reflection: bool = False) -> np.ndarray:
    """``points`` (N, 3) moved by the similarity that best maps its rows ``ok`` (N,) bool onto the same rows of
    ``target`` (N, 3), refitted on the pairs within 3x the median residual (at least 1e-9 of the target's size):
    the untouched vertices of an edited mesh fix it to rounding, which a showing's matrix, undone after it,
    would otherwise spread over its primitive (a non-uniform matrix turns a small similarity into a distortion).
    ``reflection``: fit a mirrored similarity (det R = -1) instead."""
    use = ok.copy()
    floor = 1e-9 * float(np.ptp(target[ok], axis=0).max()) if ok.any() else 0.0
    for _ in range(rounds):
        s, R, t = umeyama(points[use], target[use], reflection=reflection)
        moved = s * points @ R.T + t
        residual = np.linalg.norm(moved[ok] - target[ok], axis=1)
        keep = ok.copy()
        keep[ok] = residual <= max(3.0 * float(np.median(residual)), floor)
        if np.array_equal(keep, use) or keep.sum() < 3:
            break
        use = keep
    return moved


def _moved_rows(points: np.ndarray, ref: Reference, *, mutual: bool = False) -> np.ndarray:
    """The rows (k,) int64 of ``points`` (N, 3), the mesh's vertices in the order of ``ref.scene_positions`` (NaN:
    no counterpart), that lie farther from their counterpart than :data:`FACE_PAIR_TOLERANCE` reference mean edges,
    than float32 storage moves them (8 units in the last place of the largest coordinate) and than half a step of
    their codes (:meth:`Reference.scene_bins`: what the mark is made to tolerate, e.g. a Draco transport with a
    coarse ``step_units``), once the similarity that best maps the mesh onto the reference is undone.  The codes
    are read from positions, and a code of one bit reads the same after a larger move with even odds (a vertex
    moved by half an edge read ``authentic`` in about one check of five): a vertex the check has a counterpart
    for must be where the reference has it.  ``mutual`` (a registration's pairs, nearest neighbours within half
    an edge): only rows whose mesh vertex has them as its nearest reference vertex are judged (at a crop's edge a
    reference vertex that is gone pairs with a kept neighbour, which is where its own counterpart has it)."""
    ok = np.isfinite(points).all(axis=1)
    if np.count_nonzero(ok) < 3:
        return np.zeros(0, np.int64)
    target = ref.scene_positions

    def fit(reflection: bool) -> tuple:
        moved = _robust_similarity(points, target, ok, reflection=reflection)
        return float(np.median(np.linalg.norm(moved[ok] - target[ok], axis=1))), moved

    fitted = min(fit(False), fit(True), key=lambda f: f[0])[1]  # a mirrored copy's codes read as they were
    spread = float(np.linalg.norm(points[ok] - points[ok].mean(axis=0), axis=1).mean())
    scale = float(np.linalg.norm(fitted[ok] - fitted[ok].mean(axis=0), axis=1).mean()) / spread if spread > 0 else 1.0
    rounding = 8 * 2.0**-24 * max(float(np.abs(points[ok]).max()) * scale, float(np.abs(target).max()))
    gap = np.linalg.norm(fitted - target, axis=1)
    allowed = np.maximum(max(FACE_PAIR_TOLERANCE * ref.unit, rounding), 0.5 * ref.scene_bins())
    far = ok & (gap > allowed)
    if mutual and far.any():
        from scipy.spatial import cKDTree

        rows = np.flatnonzero(far)
        far[rows] = cKDTree(target).query(fitted[rows])[1] == rows
    return np.flatnonzero(far).astype(np.int64)


def _float32_storage_undone(points: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """``points`` (n, 3) float64 (NaN: no counterpart) with every row that is, in float32, exactly its
    counterpart's stored position in ``stored`` (n, 3) float64 replaced by that position: float32 storage
    (glTF's) is no edit, and far from the origin its rounding, a good part of a grid step, would otherwise
    move the rings the codes are bound to."""
    same = np.all(points.astype(np.float32) == stored.astype(np.float32), axis=1)
    if not same.any():
        return points
    out = points.copy()
    out[same] = stored[same]
    return out


def _foreign_vertices(mesh: Mesh, ref: Reference, corr: Correspondence, tolerance: float) -> np.ndarray:
    """The vertices (k,) int64 of ``mesh`` that lie farther than ``tolerance`` reference mean edges from every
    reference vertex once registered (a graft); none for the topological correspondences (bijections)."""
    if corr.method != "registration":
        return np.zeros(0, np.int64)
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(ref.scene_positions).query(corr.transform(np.asarray(mesh.positions, np.float64)))
    return np.flatnonzero(dist > tolerance * ref.unit).astype(np.int64)


def _changed_faces(mesh: Mesh, ref: Reference, corr: Correspondence) -> np.ndarray:
    """The vertices (k,) int64 of ``mesh`` on a face that differs from the reference's (the codes are read from
    positions alone, so a mesh of the reference's vertices with its faces rewired read ``authentic``).

    Only vertices where the reference has them are compared (a topological counterpart, or a registered one
    within :data:`FACE_PAIR_TOLERANCE` reference mean edges; a moved vertex is :func:`_moved_rows`' to judge): a face of
    the mesh whose corners are all such vertices and onto which no reference face maps, and the corners of a
    reference face whose corners all have such counterparts but which the mesh lacks.  Faces are compared as
    sets of corners (counted: a face the mesh has more often than the reference is added), each corner by its
    position in the mesh (coincident vertices, a seam's or a weld's, are one
    corner; winding and face order are not compared); a face two of whose corners coincide there is left out on
    both sides (an exporter drops those)."""
    faces = np.asarray(mesh.faces, np.int64).reshape(-1, 3)
    if faces.size == 0:
        return np.zeros(0, np.int64)
    paired = corr.valid.copy()
    if corr.distance is not None:
        paired &= corr.distance <= FACE_PAIR_TOLERANCE * ref.unit
    corner = np.unique(np.asarray(mesh.positions, np.float64), axis=0, return_inverse=True)[1].ravel()
    seen = np.zeros(len(corner), bool)  # by corner: a vertex that coincides with a paired one (an unwelded
    seen[corner[corr.index[paired]]] = True  # copy, the correspondence names one of them) is where the reference has it
    rf = np.asarray(ref.scene_faces, np.int64)
    ours = corr.index[rf[paired[rf].all(axis=1)]]  # (k, 3) mesh vertices of the reference faces compared
    faces = faces[seen[corner[faces]].all(axis=1)]

    def keys(f: np.ndarray) -> tuple:
        c = np.sort(corner[f], axis=1)
        keep = (c[:, 0] != c[:, 1]) & (c[:, 1] != c[:, 2])
        return np.ascontiguousarray(c[keep]).view(np.dtype((np.void, 24))).ravel(), f[keep]

    mine, faces = keys(faces)
    want, ours = keys(ours)
    # counted, not only matched: a face the reference has once and the mesh twice (a copy, either winding) is added
    labels = np.unique(np.concatenate([mine, want]), return_inverse=True)[1].ravel()
    lm, lw = labels[: len(mine)], labels[len(mine):]
    size = int(labels.max()) + 1 if len(labels) else 0
    have, need = np.bincount(lm, minlength=size), np.bincount(lw, minlength=size)
    extra, missing = faces[have[lm] > need[lm]], ours[need[lw] > have[lw]]
    return np.unique(np.concatenate([extra.ravel(), missing.ravel()]))


def read_given(ref: Reference, positions: np.ndarray, key, reference_image=None, *, nbars=None) -> Verifier:
    """Read every carrier of ``ref`` from ``positions`` (n_ref, 3) float in the reference's vertex order.

    NaN rows are vertices without a counterpart (their carriers stay unread);
    ``reference_image`` (s, s) uint8 defaults to the key's; ``nbars`` per-primitive reference lengths (default: measured on the given
    base vertices).  Returns the filled :class:`~pmwm_codec.watermark.verify.Verifier`.
    """
    if reference_image is None:
        reference_image = key.reference
    verifier = Verifier(ref.params, key, None, reference_image)
    replay = Replay(ref.given(np.asarray(positions, np.float64)), nbars=nbars, max_chunks=ref.chunks)
    for event in ref.events:
        for carriers in replay.on_event(event):
            verifier.add_carriers(carriers)
    return verifier


def _partial_nbars(ref: Reference, given: list, corr: Correspondence) -> list:
    """Per-primitive reference lengths for a mesh that covers only part of the reference.

    ``nbar`` (a global length) is measured on the surviving base edges only,
    scaled by their ratio to the same edges of the reference, so a crop does not
    change it; with no base edge left, the registration's scale stands in.
    """
    nbars = []
    for (ref_pos, base_faces), pts in zip(ref.parts, given):
        e = unique_edges(base_faces)
        ref_len = np.linalg.norm(ref_pos[e[:, 0]] - ref_pos[e[:, 1]], axis=1)
        nbar_ref = float(ref_len.mean())
        ok = np.isfinite(pts[e[:, 0]]).all(axis=1) & np.isfinite(pts[e[:, 1]]).all(axis=1)
        if ok.any():
            mesh_len = np.linalg.norm(pts[e[ok, 0]] - pts[e[ok, 1]], axis=1)
            nbars.append(nbar_ref * float(mesh_len.sum() / ref_len[ok].sum()))
        else:
            nbars.append(nbar_ref / corr.scale)
    return nbars
