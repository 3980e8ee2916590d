"""Verifying a mesh that left the stream against the original ``.pmw``.

Contract
--------
:func:`verify_mesh` ``(mesh, reference_source, key, watermark=None) -> MeshVerification``

* ``mesh``: a :class:`~pmwm_codec.mesh.Mesh`, a mesh file path, or a
  ``(positions (n, 3), faces (m, 3))`` pair -- exported, moved, scaled,
  re-ordered, re-saved as float32, or attacked;
* ``reference_source``: the original ``.pmw`` (path, bytes, binary file);
* ``key``: a :class:`~pmwm_codec.watermark.key.WatermarkKey` or a key file path
  (a key of another file raises :class:`~pmwm_codec.errors.WatermarkKeyError`);
* ``watermark``: the reference image (path or array); default the key's.

It finds the vertex correspondence with
:func:`pmwm_codec.watermark.registration.correspond` (exact topological match
first, similarity registration + nearest neighbours otherwise), re-reads the
codes of the reference's vertex splits from the mesh's positions (through
:func:`pmwm_codec.stream.reference.verify_positions` when every reference
vertex has a counterpart; carriers whose vertex or ring has none are left
unread otherwise) and scores them.  The verdict is the stream verifier's
(:mod:`pmwm_codec.watermark.verify`): a hypothesis test on the codes read,
so a mesh that is not the reference, or a mark destroyed by an attack, gives
``not-authentic`` or ``inconclusive`` -- never ``authentic`` by chance
(false-positive probability below ``ALPHA`` = 1e-9 per verification).

``MeshVerification.as_json()`` is the ``pmw verify MESH --reference ... --json``
object.
"""

from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass

import numpy as np

from .errors import MeshError, PmwError, WatermarkKeyError
from .mesh import Mesh, checked_mesh, read_mesh
from .watermark import codec as wm
from .watermark.metrics import centered_nc, nc, psnr
from .watermark.registration import Correspondence, correspond

__all__ = ["MeshVerification", "verify_mesh", "code_ber"]


@dataclass
class MeshVerification:
    """The result of :func:`verify_mesh`.

    ``verdict`` authentic | not-authentic | inconclusive; ``nc``, ``psnr_db``
    (inf when bit-exact), ``centered_nc`` of the recovered watermark against the
    reference; ``ber`` bit error rate of the codes read against the codes the
    reference embeds (None without a reference image); ``code_match`` fraction
    of codes read that match; ``carriers_read`` / ``carriers_total``;
    ``correspondence`` how the vertex order was found (``identity``,
    ``faces-reordered``, ``permutation``, ``registration``); ``coverage``
    fraction of reference vertices with a counterpart; ``registration_rms``
    RMS pair distance after registration (reference units, None for exact
    methods); ``watermark`` (s, s) uint8 the recovered image.
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

    def as_json(self) -> dict:
        def num(x):
            if x is None:
                return None
            x = float(x)
            return None if math.isnan(x) else ("Infinity" if math.isinf(x) else x)

        return {
            "verdict": self.verdict, "nc": num(self.nc), "psnr_db": num(self.psnr_db),
            "centered_nc": num(self.centered_nc), "ber": num(self.ber), "code_match": num(self.code_match),
            "carriers_read": self.carriers_read, "carriers_total": self.carriers_total,
            "coefficients": self.coefficients, "bit_exact": self.bit_exact,
            "correspondence": self.correspondence, "coverage": self.coverage,
            "registration_rms": num(self.registration_rms), "vertices": self.vertices, "faces": self.faces,
            "reference_vertices": self.reference_vertices, "seconds": round(self.seconds, 4),
        }


def code_ber(received: np.ndarray, expected: np.ndarray, bits: int) -> float | None:
    """Bit error rate of the codes read (``received >= 0``) against ``expected``; None if none read."""
    got = received >= 0
    if expected is None or not got.any():
        return None
    diff = (received[got] ^ expected[got]).astype(np.uint64)
    errors = sum(int(np.count_nonzero((diff >> np.uint64(b)) & np.uint64(1))) for b in range(bits))
    return errors / (bits * int(got.sum()))


def _as_mesh(mesh) -> Mesh:
    if isinstance(mesh, Mesh):
        return mesh
    if isinstance(mesh, (str, os.PathLike)):
        return read_mesh(mesh)
    if isinstance(mesh, tuple) and len(mesh) == 2:
        return checked_mesh(mesh[0], mesh[1])
    raise MeshError(f"verify_mesh: expected a Mesh, a path or (positions, faces), got {type(mesh).__name__}")


def _as_bytes(source) -> bytes:
    if isinstance(source, (bytes, bytearray, memoryview)):
        return bytes(source)
    if isinstance(source, (str, os.PathLike)):
        try:
            with open(source, "rb") as fh:
                return fh.read()
        except OSError as exc:
            raise PmwError(f"cannot read the reference file: {exc}") from None
    if hasattr(source, "read"):
        return source.read()
    raise PmwError(f"verify_mesh: unsupported reference source {type(source).__name__}")


def verify_mesh(mesh, reference_source, key, watermark=None, *, tolerance: float = 0.5,
                correspondence: Correspondence | None = None) -> MeshVerification:
    """Verify ``mesh`` against the original ``.pmw`` ``reference_source`` with ``key`` (module docstring).

    ``tolerance``: registration only, the largest pair distance in reference mean
    edge lengths; ``correspondence``: skip the search and use this one.
    """
    from . import decode, load_key
    from .format import read_header
    from .stream.reference import verify_positions

    t0 = time.perf_counter()
    m = _as_mesh(mesh)
    data = _as_bytes(reference_source)
    key = load_key(key)
    if key is None:
        raise WatermarkKeyError("verify_mesh needs the key of the reference file")
    header = read_header(data)
    cfg = header.extension.get("watermark")
    if cfg is None:
        raise PmwError("the reference file carries no watermark")
    params = wm.WatermarkParams.from_config(cfg)
    if params.fingerprint and key.fingerprint() != params.fingerprint:
        raise WatermarkKeyError("the key belongs to another file (its fingerprint differs from the reference's)")
    ref_image = None
    if watermark is not None:
        from .watermark.image import load_watermark

        ref_image, _ = load_watermark(watermark)
    elif key.reference is not None:
        ref_image = key.reference

    ref = decode(data)
    corr = correspondence or correspond(m.positions, m.faces, ref.positions, ref.faces, tolerance=tolerance)
    if corr.valid.all():
        verifier = verify_positions(m.positions[corr.index], data, key, ref_image)
    else:
        verifier = _verify_partial(m.positions, corr, data, key, ref_image, ref.positions)

    img, count = verifier.extractor.image()
    m_, n_ = verifier.matches()
    expected = verifier.expected
    out_nc = out_psnr = out_cnc = None
    if verifier.reference is not None and verifier.reference.shape == img.shape:
        r = verifier.reference.astype(np.float64)
        out_nc = float(nc(r, img.astype(np.float64)))
        out_psnr = float(psnr(verifier.reference, img))
        out_cnc = float(centered_nc(r, img.astype(np.float64)))
    ber = code_ber(verifier.extractor.received, expected, params.bits) if expected is not None else None
    return MeshVerification(
        verdict=verifier.verdict(), nc=out_nc, psnr_db=out_psnr, centered_nc=out_cnc, ber=ber,
        code_match=(m_ / n_) if (n_ and expected is not None) else None,
        carriers_read=n_, carriers_total=params.carriers, correspondence=corr.method,
        coverage=corr.coverage, registration_rms=corr.rms, vertices=m.vertex_count, faces=m.face_count,
        reference_vertices=len(ref.positions), coefficients=int(count), seconds=time.perf_counter() - t0,
        watermark=img, bit_exact=bool(verifier.reference is not None and np.array_equal(img, verifier.reference)),
    )


def _verify_partial(positions, corr: Correspondence, data: bytes, key, ref_image, ref_positions):
    """Like :func:`~pmwm_codec.stream.reference.verify_positions` for a partial correspondence.

    Reference vertices without a counterpart are NaN; a carrier whose vertex or
    ring mean is not finite stays unread.  ``nbar`` (a global length) is
    measured on the surviving base edges only, scaled by their ratio to the
    same edges of the reference, so a crop does not change it.
    """
    from .format import BaseEvent, ChunkEvent, HeaderEvent, iter_events
    from .format.records import unpack_batches
    from .progressive.vsplit import MeshState, split_topology
    from .watermark.verify import Verifier

    n = len(ref_positions)
    pts = np.full((n, 3), np.nan)
    pts[corr.valid] = np.asarray(positions, np.float64)[corr.index[corr.valid]]
    verifier = state = header = None
    batch_index = 0
    for event in iter_events(data):
        if isinstance(event, HeaderEvent):
            header = event
            params = wm.WatermarkParams.from_config(event.extension["watermark"])
        elif isinstance(event, BaseEvent):
            n0 = len(event.positions_int)
            f = np.asarray(event.faces, np.int64)
            state = MeshState(pts[:n0], f, n, int(header.extension["faceCount"]), dtype=np.float64)
            e = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
            ok = corr.valid[e[:, 0]] & corr.valid[e[:, 1]]
            ref_len = np.linalg.norm(ref_positions[e[:, 0]] - ref_positions[e[:, 1]], axis=1)
            nbar_ref = float(ref_len.mean())
            if ok.any():
                mesh_len = np.linalg.norm(pts[e[ok, 0]] - pts[e[ok, 1]], axis=1)
                nbar = nbar_ref * float(mesh_len.sum() / ref_len[ok].sum())
            else:
                nbar = nbar_ref / corr.scale  # no base edge survived: trust the registration scale
            verifier = Verifier(params, key, nbar, ref_image)
        elif isinstance(event, ChunkEvent):
            for batch in unpack_batches(event.payload, max_splits=n):
                topo = split_topology(state, batch.v, batch.symbols)
                state.positions[topo.u] = pts[topo.u]
                p = pts[topo.u]
                c = topo.centroid()
                bad = ~(np.isfinite(p).all(axis=1) & np.isfinite(c).all(axis=1))
                offset = verifier.extractor.offset
                verifier.add(batch_index, np.where(bad[:, None], 0.0, p), np.where(bad[:, None], 1.0, c))
                if bad.any():
                    slots = wm.carrier_slots(key, batch_index, offset, len(p))
                    gone = slots[bad]
                    verifier.extractor.received[gone[gone < len(verifier.extractor.received)]] = -1
                batch_index += 1
    return verifier
