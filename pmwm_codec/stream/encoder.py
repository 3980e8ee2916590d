"""Encoder pipeline: Mesh -> simplify -> base + split records -> watermark -> ``.pmw``.

:func:`encode_mesh` is the one place the stages meet::

    quantize to the grid -> simplify (batches of collapses) -> encode the base
    (Draco or plain; its decoded vertex order is the order splits refer to)
    -> build split records, embedding the watermark on the grid as we go
    -> group batches into chunks -> write the GLB atomically

It returns an :class:`EncodeReport` holding the ``pmw encode --json`` fields.
"""

from __future__ import annotations

import os
import secrets
import time
from dataclasses import dataclass, field

import numpy as np

from ..constants import DEFAULT_GRID_BITS
from ..errors import PmwError
from ..format import encode_base, write_pmw
from ..format.records import pack_batches
from ..mesh import Mesh
from ..progressive.build import build_progressive
from ..progressive.grid import Grid
from ..progressive.simplify import simplify
from ..watermark import codec as wm
from ..watermark.key import WatermarkKey

#: Payload codec id written in the extension object.
PAYLOAD_CODEC = "pmwm-vsplit"
PAYLOAD_VERSION = 1


@dataclass
class EncodeReport:
    """What an encode did; :meth:`as_json` gives the ``pmw encode --json`` object."""

    vertices: int
    faces: int
    base_vertices: int
    base_faces: int
    vsplits: int
    chunks: int
    bytes: int
    seconds: float
    distortion: dict
    watermark: dict | None
    base_codec: str = "draco"
    notices: list = field(default_factory=list)
    key: WatermarkKey | None = None
    batches: int = 0

    def as_json(self) -> dict:
        return {
            "vertices": self.vertices, "faces": self.faces,
            "base_vertices": self.base_vertices, "base_faces": self.base_faces,
            "vsplits": self.vsplits, "chunks": self.chunks, "bytes": self.bytes,
            "seconds": round(self.seconds, 4), "distortion": self.distortion,
            "watermark": self.watermark,
        }


def default_base_target(n: int) -> int:
    """Default base size: 1% of the vertices, at least 64 (and never more than n)."""
    return min(n, max(n // 100, 64))


def group_batches(sizes, min_splits: int) -> list:
    """Split batch indices into chunks of consecutive batches holding >= ``min_splits`` splits.

    ``sizes`` : (b,) split counts, coarse to fine.  Returns a list of ``range``.
    """
    out, start, acc = [], 0, 0
    for j, k in enumerate(sizes):
        acc += int(k)
        if acc >= min_splits:
            out.append(range(start, j + 1))
            start, acc = j + 1, 0
    if start < len(sizes):
        if out and acc < min_splits // 2:
            last = out.pop()
            out.append(range(last.start, len(sizes)))
        else:
            out.append(range(start, len(sizes)))
    return out


def encode_mesh(
    mesh: Mesh,
    dst,
    *,
    watermark: np.ndarray | None = None,
    key: WatermarkKey | None = None,
    mode: str = "exact",
    bits: int | None = None,
    grid_bits: int | None = None,
    base_codec: str = "draco",
    base_vertices: int | None = None,
    step_units: float | None = None,
    min_chunk_splits: int | None = None,
    zstd_level: int = 10,
    measure: bool = True,
    progress=None,
) -> EncodeReport:
    """Encode a validated :class:`Mesh` into a ``.pmw`` at ``dst`` (path or binary file).

    Parameters
    ----------
    watermark : (s, s) uint8, optional
        A ``2^k`` square grayscale image (see :func:`~pmwm_codec.watermark.load_watermark`).
    key : WatermarkKey, optional
        Generated when a watermark is given and no key is.
    mode : ``"exact"`` | ``"paper"``; bits : bits per carrier (None: automatic / 12).
    grid_bits : grid resolution (default 16; paper mode 22).
    base_codec : ``"draco"`` | ``"plain"``.
    base_vertices : target base size (default :func:`default_base_target`).
    measure : compute the distortion (RMS, PSNR, Hausdorff) of the full decoded mesh.
    progress : optional callable(stage: str, fraction: float).
    """
    t0 = time.perf_counter()
    say = progress or (lambda stage, fraction: None)
    notices = []
    if grid_bits is None:
        grid_bits = wm.DEFAULT_GRID_BITS[mode] if watermark is not None else DEFAULT_GRID_BITS
    grid = Grid.fit(mesh.positions, grid_bits)
    q = grid.quantize(mesh.positions)
    n, m = mesh.vertex_count, mesh.face_count

    say("simplify", 0.0)
    target = default_base_target(n) if base_vertices is None else int(base_vertices)
    log = simplify(q, mesh.faces, target_vertices=target)
    say("simplify", 1.0)

    # the base as the decoder will see it
    base_ids = log.base_vertices
    local = np.full(n, -1, dtype=np.int64)
    local[base_ids] = np.arange(len(base_ids))
    try:
        base = encode_base(q[base_ids], local[log.base_corners], grid.get_config(), codec=base_codec)
    except ValueError as exc:
        raise PmwError(f"cannot store the base mesh: {exc}") from None
    if base.notice:
        notices.append(base.notice)
    base_order = base_ids[np.asarray(base.vertex_map, dtype=np.int64)]

    # watermark plan (needs the carrier count and nbar of the base)
    embedder = None
    params = None
    carriers = n - len(base_ids)
    if watermark is not None:
        if key is None:
            key = WatermarkKey.generate()
        nbar = wm.base_mean_edge(base.positions_int, base.faces)
        params, codes = wm.plan(watermark, key, carriers, mode=mode, bits=bits, nbar=nbar, step_units=step_units)
        embedder = wm.Embedder(params, key, codes, nbar)

    say("records", 0.0)
    pm = build_progressive(log, q, grid, base_vertex_order=base_order, base_faces_decoded=base.faces, embed=embedder)
    say("records", 1.0)

    sizes = [b.size for b in pm.batches]
    if min_chunk_splits is None:
        min_chunk_splits = max(32, pm.split_count // 100)
    groups = group_batches(sizes, min_chunk_splits)
    payloads, meta = [], []
    nv, nf = len(pm.base_positions), len(pm.base_faces)
    for g in groups:
        chunk = [pm.batches[j] for j in g]
        payloads.append(pack_batches(chunk))
        nv += sum(b.size for b in chunk)
        nf += sum(b.new_face_count() for b in chunk)
        nxt = g.stop
        err = float(pm.batch_errors[nxt]) * grid.step if nxt < len(pm.batches) else 0.0
        meta.append({"splits": int(sum(b.size for b in chunk)), "vertexCount": int(nv), "faceCount": int(nf),
                     "geometricError": err, "batches": len(chunk)})

    file_id = secrets.token_hex(8)
    extension = {
        "grid": grid.get_config(),
        "vertexCount": int(n),
        "faceCount": int(m),
        "payload": {"codec": PAYLOAD_CODEC, "version": PAYLOAD_VERSION},
        "fileId": file_id,
    }
    if params is not None:
        extension["watermark"] = params.get_config()
        key.file_id = file_id
        key.params = params.get_config()
        key.reference = np.asarray(watermark, np.uint8)
    say("write", 0.0)
    size = write_pmw(dst, base=base, chunks=payloads, chunk_meta=meta, extension=extension, zstd_level=zstd_level)
    say("write", 1.0)

    distortion = {"rms": None, "psnr_db": None, "hausdorff": None, "bbox_diagonal": mesh.bbox_diagonal()}
    if measure:
        distortion = full_distortion(pm, grid, mesh)
    wm_report = None
    if params is not None:
        wm_report = {
            "width": params.size, "height": params.size, "mode": params.mode, "bits": params.bits,
            "codes": params.codes, "embedded": int(embedder.embedded), "carriers": params.carriers,
            "failed": int(embedder.failed),
        }
    return EncodeReport(
        vertices=n, faces=m, base_vertices=len(pm.base_positions), base_faces=len(pm.base_faces),
        vsplits=pm.split_count, chunks=len(groups), bytes=int(size), seconds=time.perf_counter() - t0,
        distortion=distortion, watermark=wm_report, base_codec=base.codec, notices=notices, key=key,
        batches=len(pm.batches),
    )


def full_distortion(pm, grid: Grid, mesh: Mesh) -> dict:
    """Distortion of the fully decoded mesh against the input ``mesh`` (float positions)."""
    from ..progressive.vsplit import apply_batch
    from ..watermark.metrics import mesh_distortion

    state = pm.new_state()
    for batch in pm.batches:
        apply_batch(state, batch)
    decoded = grid.dequantize(state.current_positions())[pm.vertex_order]
    inverse = np.empty_like(pm.vertex_order)
    inverse[pm.vertex_order] = np.arange(len(inverse))
    faces = mesh.faces  # same connectivity, input numbering
    d = mesh_distortion(Mesh(mesh.positions, faces), Mesh(decoded, faces))
    return {k: (None if v is None else float(v)) for k, v in d.items()}


def default_key_path(dst) -> str | None:
    """Where ``pmw encode`` writes the key when none is named: ``OUT.pmw.key.json``."""
    if isinstance(dst, (str, os.PathLike)):
        return os.fspath(dst) + ".key.json"
    return None
