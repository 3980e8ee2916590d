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

The reference is parsed once.  Its full decode (every progressive primitive,
concatenated in stream order, as :attr:`PartialResult.mesh` gives it) is the
target of :func:`.correspond.correspond` (exact topological match first,
similarity registration + nearest neighbours otherwise).  The mesh's positions,
put in the reference's vertex order, are then replayed through the split
connectivity of the reference (:class:`~pmwm_codec.stream.replay.Replay` with
given positions) and every carrier's code is read as a decoder reads it, so the
codes are invariant to rotation, uniform scale and translation (``nbar`` is
measured on the mesh's own base vertices).  Carriers whose vertex or ring has
no counterpart stay unread.  The scores and the verdict are the stream
verifier's (:class:`~pmwm_codec.watermark.verify.Verifier`); vertices of the mesh that
no reference vertex explains (a graft) make it ``tampered``, and the carriers whose
code no longer reads are mapped back to the mesh's vertices (``tamper``).

``MeshVerification.as_json()`` is the ``pmw verify MESH --reference ... --json``
object.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from ..errors import FormatError, MeshError, PmwError, WatermarkKeyError
from ..format import EndEvent, HeaderEvent, iter_events
from ..mesh import Mesh, checked_mesh, read_mesh
from ..progressive.topology import unique_edges
from ..sources import read_all
from ..stream.replay import Replay
from ..watermark import codec as wm
from ..watermark.key import as_key
from ..watermark.verify import Verifier
from .correspond import Correspondence, correspond

__all__ = ["MeshVerification", "verify_mesh"]


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
    vertices of the checked mesh whose carrier code no longer reads (the tamper map);
    ``foreign`` the mesh holds vertices no reference vertex explains (registration only:
    farther than the tolerance from every reference vertex); ``binding`` the file's
    (``""``: a legacy mark, never ``authentic``).
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
        }


def _as_mesh(mesh) -> Mesh:
    if isinstance(mesh, Mesh):
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
    """

    events: list
    params: wm.WatermarkParams
    parts: list
    positions: np.ndarray
    faces: np.ndarray

    def split(self, positions: np.ndarray) -> list:
        """(n, 3) positions in the reference's order -> one (n_p, 3) view per primitive."""
        if len(positions) != len(self.positions):
            raise MeshError(f"{len(positions)} positions for the reference's {len(self.positions)} vertices")
        ends = np.cumsum([len(pos) for pos, _ in self.parts])
        return np.split(positions, ends[:-1])

    @classmethod
    def read(cls, source) -> "Reference":
        try:
            data = read_all(source)
        except OSError as exc:
            raise PmwError(f"cannot read the reference file: {exc}") from None
        events = list(iter_events(data))
        header = events[0]
        assert isinstance(header, HeaderEvent)
        cfg = header.extension.get("watermark")
        if cfg is None:
            raise PmwError("the reference file carries no watermark")
        end = events[-1]
        if isinstance(end, EndEvent) and not end.complete:
            raise FormatError("the reference file is cut short: verify against the complete original")
        replay = Replay()
        for event in events:
            replay.on_event(event)
        parts, faces, offset = [], [], 0
        for p, grid in enumerate(replay.grids):
            values, fac = replay.current(p)
            parts.append((grid.dequantize(values[:, :3]), replay.base_faces[p]))
            faces.append(fac + offset)
            offset += len(values)
        positions = np.concatenate([pos for pos, _ in parts])
        return cls(events, wm.WatermarkParams.from_config(cfg), parts, positions, np.concatenate(faces))


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

    corr = correspondence or correspond(m.positions, m.faces, ref.positions, ref.faces, tolerance=tolerance)
    pts = np.full((len(ref.positions), 3), np.nan)
    pts[corr.valid] = np.asarray(m.positions, np.float64)[corr.index[corr.valid]]
    nbars = None if corr.valid.all() else _partial_nbars(ref, ref.split(pts), corr)
    verifier = read_given(ref, pts, key, ref_image, nbars=nbars)
    verifier.foreign = _foreign_vertices(m, ref, corr, tolerance) > 0
    est = verifier.estimate()
    starts = np.cumsum([0] + [len(pos) for pos, _ in ref.parts])
    flagged = np.unique(corr.index[verifier.tamper(starts)])
    owns = key.owns(ref.params.fingerprint)
    return MeshVerification(
        verdict=est.verdict if owns else "not-authentic", key_matches=owns, nc=est.nc, psnr_db=est.psnr_db, centered_nc=est.centered_nc, ber=est.ber,
        code_match=est.code_match, carriers_read=est.carriers_read, carriers_total=ref.params.carriers,
        correspondence=corr.method, coverage=corr.coverage, registration_rms=corr.rms,
        vertices=m.vertex_count, faces=m.face_count, reference_vertices=len(ref.positions),
        coefficients=est.coefficients, seconds=time.perf_counter() - t0, watermark=est.watermark,
        bit_exact=est.bit_exact, flagged=flagged, foreign=bool(verifier.foreign), binding=ref.params.binding,
    )


def _foreign_vertices(mesh: Mesh, ref: Reference, corr: Correspondence, tolerance: float) -> int:
    """How many vertices of ``mesh`` lie farther than ``tolerance`` reference mean edges from every
    reference vertex once registered (a graft); 0 for the topological correspondences (bijections)."""
    if corr.method != "registration":
        return 0
    from scipy.spatial import cKDTree

    from ..progressive.topology import mean_edge_length

    unit = tolerance * mean_edge_length(ref.positions, ref.faces)
    dist, _ = cKDTree(ref.positions).query(corr.transform(np.asarray(mesh.positions, np.float64)))
    return int(np.count_nonzero(dist > unit))


def read_given(ref: Reference, positions: np.ndarray, key, reference_image=None, *, nbars=None) -> Verifier:
    """Read every carrier of ``ref`` from ``positions`` (n_ref, 3) float in the reference's vertex order.

    NaN rows are vertices without a counterpart (their carriers stay unread);
    ``reference_image`` (s, s) uint8 defaults to the key's; ``nbars`` per-primitive reference lengths (default: measured on the given
    base vertices).  Returns the filled :class:`~pmwm_codec.watermark.verify.Verifier`.
    """
    if reference_image is None:
        reference_image = key.reference
    verifier = Verifier(ref.params, key, None, reference_image)
    replay = Replay(ref.split(np.asarray(positions, np.float64)), nbars=nbars)
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
