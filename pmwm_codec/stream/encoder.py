"""Encoder pipeline: Mesh -> simplify -> base + split records -> watermark -> ``.pmw``.

:func:`encode_mesh` is the one place the stages meet::

    quantize to the grid -> simplify (batches of collapses) -> encode the base
    (Draco or plain; its decoded vertex order is the order splits refer to)
    -> build split records, embedding the watermark on the grid as we go
    -> group batches into chunks -> write the GLB atomically

It returns an :class:`EncodeReport` holding the ``pmw encode --json`` fields.
"""

from __future__ import annotations

import dataclasses
import os
import secrets
import time
from dataclasses import dataclass, field

import numpy as np

from ..constants import DEFAULT_GRID_BITS
from ..distortion import combine_meshes, decoded_positions, full_distortion
from ..errors import PmwError
from ..format import encode_base
from ..format.base import attribute_grid, attribute_to_float, attribute_to_grid, with_attributes
from ..format.glb import ProgressivePrimitive, assemble_document, write_parts
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


@dataclass
class PrimitiveJob:
    """One triangle primitive to make progressive.

    ``mesh`` carries positions, faces and per-vertex ``attributes`` (glTF semantic ->
    (n, k) float); ``locked`` (n,) bool marks vertices that must stay in the base
    (attribute seams, borders shared with other primitives); ``mesh_index`` and
    ``primitive_index`` say where it sits in the document.
    """

    mesh: Mesh
    mesh_index: int = 0
    primitive_index: int = 0
    locked: np.ndarray | None = None


#: Grid bits of progressive attributes, by semantic prefix (others: 14).
ATTRIBUTE_BITS = {"NORMAL": 14, "TANGENT": 14, "TEXCOORD": 14, "COLOR": 12}


def _attribute_bits(semantic: str) -> int:
    return ATTRIBUTE_BITS.get(semantic.split("_")[0], 14)


def encode_mesh(mesh: Mesh, dst, **options) -> EncodeReport:
    """Encode one validated :class:`Mesh` into a ``.pmw`` at ``dst`` (path or binary file).

    See :func:`encode_document` for the options.
    """
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [{}]}]}
    return encode_document(doc, b"", [PrimitiveJob(mesh)], dst, **options)


def encode_document(
    doc: dict,
    kept_bin: bytes,
    jobs: list,
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
    """Make the primitives of ``jobs`` progressive inside ``doc`` and write the ``.pmw``.

    Parameters
    ----------
    doc, kept_bin : the document to carry and its data (see
        :func:`~pmwm_codec.format.glb.assemble_document`).
    jobs : list[PrimitiveJob]
    watermark : (s, s) uint8, optional
        A ``2^k`` square grayscale image (see :func:`~pmwm_codec.watermark.load_watermark`);
        one watermark for the whole document, its slots spread over every primitive's
        splits in stream order.
    key : WatermarkKey, optional
        Generated when a watermark is given and no key is.
    mode : ``"exact"`` | ``"paper"``; bits : bits per carrier (None: automatic / 12).
    grid_bits : position grid resolution (default 16; paper mode 22).
    base_codec : ``"draco"`` | ``"plain"`` (primitives with attributes use plain).
    base_vertices : target base size per primitive (default :func:`default_base_target`).
    measure : compute the distortion (RMS, PSNR, Hausdorff) of the full decoded mesh.
    progress : optional callable(stage: str, fraction: float).
    """
    t0 = time.perf_counter()
    say = progress or (lambda stage, fraction: None)
    notices = []
    if grid_bits is None:
        grid_bits = wm.DEFAULT_GRID_BITS[mode] if watermark is not None else DEFAULT_GRID_BITS

    # 1. quantize and simplify every primitive
    work = []
    say("simplify", 0.0)
    for i, job in enumerate(jobs):
        mesh = job.mesh
        grid = Grid.fit(mesh.positions, grid_bits)
        q = grid.quantize(mesh.positions)
        specs, columns = [], [q]
        for semantic in sorted(mesh.attributes):
            values = np.asarray(mesh.attributes[semantic], np.float64).reshape(mesh.vertex_count, -1)
            spec = {"semantic": semantic, **attribute_grid(values, _attribute_bits(semantic))}
            ints = attribute_to_grid(values, spec, semantic)
            if not np.array_equal(attribute_to_grid(attribute_to_float(ints, spec), spec, semantic), ints):
                raise PmwError(f"{semantic}: values too large for float32 at {spec['bits']} bits")
            specs.append(spec)
            columns.append(ints)
        values = np.concatenate(columns, axis=1)
        n = mesh.vertex_count
        target = default_base_target(n) if base_vertices is None else int(base_vertices)
        log = simplify(q, mesh.faces, target_vertices=target, locked=job.locked)
        work.append({"job": job, "grid": grid, "values": values, "specs": specs, "log": log})
        say("simplify", (i + 1) / len(jobs))

    # 2. bases as the decoder will see them
    for w in work:
        log, q = w["log"], w["values"][:, :3]
        base_ids = log.base_vertices
        local = np.full(len(q), -1, dtype=np.int64)
        local[base_ids] = np.arange(len(base_ids))
        codec = base_codec
        if w["specs"] and codec == "draco":
            codec = "plain"
            note = "primitives with attributes keep a plain base (Draco carries positions only here)"
            if note not in notices:
                notices.append(note)
        try:
            base = encode_base(q[base_ids], local[log.base_corners], w["grid"].get_config(), codec=codec)
        except ValueError as exc:
            raise PmwError(f"cannot store the base mesh: {exc}") from None
        if base.notice and base.notice not in notices:
            notices.append(base.notice)
        order0 = base_ids[np.asarray(base.vertex_map, dtype=np.int64)]
        if w["specs"]:
            offsets = np.cumsum([3] + [len(sp["origin"]) for sp in w["specs"]])
            base = with_attributes(base, [
                (sp, w["values"][order0, offsets[j] : offsets[j + 1]]) for j, sp in enumerate(w["specs"])
            ])
        w["base"], w["order0"] = base, order0

    # 3. chunks per primitive, then one stream order over all of them
    for w in work:
        sizes = [len(cb.u) for cb in reversed(w["log"].batches)]
        total = sum(sizes)
        mcs = max(32, total // 100) if min_chunk_splits is None else min_chunk_splits
        w["sizes"], w["groups"] = sizes, group_batches(sizes, mcs)
    order = _stream_order(work)
    slots, g, offset = [dict() for _ in work], 0, 0
    for p, k in order:
        for j in work[p]["groups"][k]:
            slots[p][j] = (g, offset)
            g += 1
            offset += work[p]["sizes"][j]
    carriers = offset

    # 4. watermark plan over every carrier of the document
    params = None
    embedders = [None] * len(work)
    if watermark is not None:
        if key is None:
            key = WatermarkKey.generate()
        params, codes = wm.plan(watermark, key, carriers, mode=mode, bits=bits, nbar=1.0, step_units=step_units)
        step = wm.DEFAULT_STEP_UNITS[mode] if step_units is None else float(step_units)
        for p, w in enumerate(work):
            nbar = wm.base_mean_edge(w["base"].positions_int, w["base"].faces)
            w["params"] = dataclasses.replace(params, scale=nbar / step)
            embedders[p] = wm.Embedder(w["params"], key, codes, nbar, slots=slots[p])

    # 5. split records
    say("records", 0.0)
    for p, w in enumerate(work):
        w["pm"] = build_progressive(
            w["log"], w["values"], w["grid"], base_vertex_order=w["order0"],
            base_faces_decoded=w["base"].faces, embed=embedders[p],
        )
        say("records", (p + 1) / len(work))

    # 6. payloads, index entries, extension objects; write
    file_id = secrets.token_hex(8)
    prims = []
    for p, w in enumerate(work):
        pm, grid = w["pm"], w["grid"]
        remaining = np.maximum.accumulate(pm.batch_errors[::-1])[::-1] if len(pm.batch_errors) else pm.batch_errors
        payloads, meta = [], []
        nv, nf = len(pm.base_positions), len(pm.base_faces)
        for grp in w["groups"]:
            chunk = [pm.batches[j] for j in grp]
            payloads.append(pack_batches(chunk))
            nv += sum(b.size for b in chunk)
            nf += sum(b.new_face_count() for b in chunk)
            err = float(remaining[grp.stop]) * grid.step if grp.stop < len(pm.batches) else 0.0
            meta.append({"splits": int(sum(b.size for b in chunk)), "vertexCount": int(nv), "faceCount": int(nf),
                         "geometricError": err, "batches": len(chunk)})
        extension = {
            "grid": grid.get_config(),
            "vertexCount": int(pm.vertex_count),
            "faceCount": int(pm.face_count),
            "payload": {"codec": PAYLOAD_CODEC, "version": PAYLOAD_VERSION},
            "fileId": file_id,
        }
        if w["specs"]:
            extension["attributes"] = w["specs"]
        if params is not None:
            extension["watermark"] = w["params"].get_config()
        job = w["job"]
        prims.append(ProgressivePrimitive(job.mesh_index, job.primitive_index, w["base"], payloads, meta, extension))
    if params is not None:
        key.file_id = file_id
        key.params = params.get_config()
        key.reference = np.asarray(watermark, np.uint8)
    say("write", 0.0)
    size = write_parts(dst, assemble_document(doc, kept_bin, prims, order, zstd_level))
    say("write", 1.0)

    meshes = [w["job"].mesh for w in work]
    combined = combine_meshes(meshes)
    distortion = {"rms": None, "psnr_db": None, "hausdorff": None, "bbox_diagonal": combined.bbox_diagonal()}
    if measure:
        say("measure", 0.0)
        decoded = [decoded_positions(w["pm"], w["grid"]) for w in work]
        distortion = full_distortion(combined, combine_meshes([Mesh(d, m.faces) for d, m in zip(decoded, meshes)]))
        say("measure", 1.0)
    wm_report = None
    if params is not None:
        wm_report = {
            "width": params.size, "height": params.size, "mode": params.mode, "bits": params.bits,
            "codes": params.codes, "embedded": int(sum(e.embedded for e in embedders)), "carriers": params.carriers,
            "failed": int(sum(e.failed for e in embedders)),
        }
    return EncodeReport(
        vertices=sum(m.vertex_count for m in meshes), faces=sum(m.face_count for m in meshes),
        base_vertices=sum(len(w["pm"].base_positions) for w in work),
        base_faces=sum(len(w["pm"].base_faces) for w in work),
        vsplits=carriers, chunks=len(order), bytes=int(size), seconds=time.perf_counter() - t0,
        distortion=distortion, watermark=wm_report, base_codec=work[0]["base"].codec if work else base_codec,
        notices=notices, key=key, batches=sum(len(w["pm"].batches) for w in work),
    )


def _stream_order(work) -> list:
    """Every (primitive, chunk) in stream order: by the fraction of the primitive's splits done after it."""
    keys = []
    for p, w in enumerate(work):
        total = max(1, sum(w["sizes"]))
        done = 0
        for k, grp in enumerate(w["groups"]):
            done += sum(w["sizes"][j] for j in grp)
            keys.append((done / total, p, k))
    return [(p, k) for _, p, k in sorted(keys)]


def default_key_path(dst) -> str | None:
    """Where ``pmw encode`` writes the key when none is named: ``OUT.pmw.key.json``."""
    if isinstance(dst, (str, os.PathLike)):
        return os.fspath(dst) + ".key.json"
    return None
