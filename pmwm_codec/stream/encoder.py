"""Encoder pipeline: Mesh -> simplify -> base + split records -> watermark -> ``.pmw``.

:func:`encode_document` runs the stages, each a function over a list of
:class:`PrimitiveWork` records (one per primitive)::

    _mark_owner             (with ``owner_id``) the owner layer on the full-resolution mesh, read
                            back from the grid positions the decoder will see (:func:`_owner_check`)
    _quantize_and_simplify  grid, quantized values, collapse log
    _encode_bases           base mesh (Draco or plain; its decoded vertex order is the
                            order splits refer to)
    _plan_chunks            batches -> chunks, one stream order, carrier slots (chunking.py)
    _plan_watermark         watermark parameters and one embedder per primitive
    _build_records          split records, the watermark embedded on the grid as we go
    _owner_check            (owner layer and watermark) the owner layer read back from the full
                            decode; unreadable: refused, or the stages again without it
    _report                 the :class:`EncodeReport` with the distortion (measured before
                            anything is written, bounded in memory)
    _write                  payloads, index entries, extension objects; then the key file
                            (if new) and the GLB are published together (:func:`_publish`)

The stages never modify the caller's objects (the key given is returned as a new key
in the report) and the output depends only on the input, the key and the options:
the ``fileId`` written is a digest of the content and of the key's fingerprint.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import time
from dataclasses import dataclass, field

import numpy as np

from ..constants import DEFAULT_GRID_BITS, MAX_GRID_BITS, MIN_GRID_BITS
from ..distortion import combine_meshes, decoded_positions, full_distortion, measure_method
from ..errors import FormatError, MeshError, OwnerLayerError, PmwError
from ..format import encode_base
from ..format.base import EncodedBase
from ..atomic import directory_lock, discard, fault_point, publish, signals_deferred, stage
from ..format.glb import ProgressivePrimitive, assemble_document, write_parts
from ..format.gltf import owner_placements, scene_mesh
from ..format.gltf import COMPONENT_DTYPES, FLOAT
from ..format.extension import DEFAULT_PAYLOAD_VERSION, PAYLOAD_CODEC, PAYLOAD_VERSIONS
from ..format.records import pack_batches
from ..format.records_v2 import PLANE_PREDICTION, FaceChunk, pack_chunks, plane_columns
from ..mesh import Mesh, bounds, vertex_components
from ..progressive.build import ProgressiveMesh, build_progressive
from ..progressive.grid import SRGB8, AttributeGrid, Grid, float32_spacing
from ..progressive.seams import twin_rows, weld_groups
from ..progressive.simplify import CollapseLog, deferred_and_twin_faces, simplify
from ..progressive.topology import any_corner, edge_ids, job_vertices, mean_edge_length, two_alike_at
from ..progressive.seams import grid_weld, snap_near_copies  # (the seam copies of stage 1)
from ..watermark import codec as wm
from ..watermark.key import KEY_FILE_MODE, KEY_SUFFIX, KeySlot, WatermarkKey
from ..watermark.verify import MIN_CARRIERS
from .chunking import (
    FIRST_CHUNK_SPLITS,
    carrier_slots,
    chunk_meta,
    default_base_target,
    default_min_chunk_splits,
    group_batches,
    stream_order,
)


@dataclass
class EncodeReport:
    """What an encode did; :meth:`as_json` gives the ``pmw encode --json`` object.

    ``key`` is the key the file is marked with (a new object: the caller's key is never
    modified), holding the parameters, the reference watermark and the file id; None
    without a watermark unless one was given.  ``key_path`` is where
    :func:`pmwm_codec.encode` saved it.
    """

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
    key_path: str | None = None

    def as_json(self) -> dict:
        """Every field but ``key``, as plain JSON values."""
        return {
            "vertices": self.vertices, "faces": self.faces,
            "base_vertices": self.base_vertices, "base_faces": self.base_faces,
            "vsplits": self.vsplits, "chunks": self.chunks, "bytes": self.bytes,
            "seconds": round(self.seconds, 4), "distortion": self.distortion,
            "watermark": self.watermark, "notices": list(self.notices), "key_path": self.key_path,
            "base_codec": self.base_codec, "batches": self.batches,
        }


@dataclass
class PrimitiveJob:
    """One triangle primitive to make progressive.

    ``mesh`` carries positions, faces and per-vertex ``attributes`` (glTF semantic ->
    (n, k) float); ``locked`` (n,) bool marks vertices that must stay in the base
    (borders shared with other primitives; vertices sharing a position inside the
    primitive are seams, collapsed in pairs: :mod:`~pmwm_codec.progressive.seams`); ``mesh_index`` and
    ``primitive_index`` say where it sits in the document; ``names`` the names of its input accessors
    (``{semantic or "indices": name}``), which the base's accessors keep (a decoded level's then do);
    ``texture_scales`` how many times over its materials' textures repeat per unit of a TEXCOORD_n
    (``{"TEXCOORD_n": s}``, KHR_texture_transform: :func:`~pmwm_codec.format.document.texture_scales`), which
    its grid keeps that much finer.
    """

    mesh: Mesh
    mesh_index: int = 0
    primitive_index: int = 0
    locked: np.ndarray | None = None
    names: dict | None = None
    texture_scales: dict | None = None


@dataclass(frozen=True)
class PrimitiveWork:
    """One primitive on its way through the stages; each stage fills more fields.

    Attributes
    ----------
    job : PrimitiveJob
    grid : Grid
        The position grid.
    values : (n, D) int64
        Grid positions (columns 0-2), then each attribute's quantized columns.
    attribute_grids : list[dict]
        Per attribute (sorted by semantic): ``{"semantic", "bits", "origin", "step"}``.
    log : CollapseLog
        The simplifier's batches (fine to coarse) and base.
    base : EncodedBase
        The base mesh as the decoder will see it (with its attribute accessors).
    base_order : (n0,) int64
        Input vertex id of each decoded base vertex.
    sizes : list[int]
        Splits per batch, coarse to fine.
    groups : list[range]
        The chunks: consecutive batch indices.
    params : WatermarkParams or None
        The watermark parameters with this primitive's ``scale``.
    embedder : Embedder or None
    pm : ProgressiveMesh
        Base plus split records.
    core : (n_core,) int64 or None
        Input id of each vertex the simplifier saw (``values``, the log and ``late`` use their
        order): every vertex but those only the late faces name (None: every vertex).
    tips : (t,) int64
        Input ids of the others, ascending: ``late_values`` are theirs.
    late : (L, 3) int64
        Faces kept out of the simplification (pillows, payload version 2 only), sent in a face chunk
        after every split (bitstream.md §8.6); ids ``n_core + j`` name ``late_values[j]``.
    late_values : (t, D) int64
        Values of the vertices only the late faces name (flaps' tips), in input order.
    """

    job: PrimitiveJob
    grid: Grid
    values: np.ndarray
    attribute_grids: list
    log: CollapseLog
    base: EncodedBase | None = None
    base_order: np.ndarray | None = None
    sizes: list | None = None
    groups: list | None = None
    params: wm.WatermarkParams | None = None
    embedder: wm.Embedder | None = None
    pm: ProgressiveMesh | None = None
    core: np.ndarray | None = None
    tips: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros(0, np.int64))
    late: np.ndarray = dataclasses.field(default_factory=lambda: np.zeros((0, 3), np.int64))
    late_values: np.ndarray | None = None


#: Rounds of sliver deferral (:func:`_sliver_faces`): deferring slivers opens new boundary ears beside them.
SLIVER_ROUNDS = 4
#: Grid bits of progressive attributes, by semantic prefix (others: 14).
ATTRIBUTE_BITS = {"NORMAL": 14, "TANGENT": 14, "TEXCOORD": 14, "COLOR": 12}
#: WEIGHTS_n (skin weights, in [0, 1]): the grid of step 2^-WEIGHTS_BITS from 0 (one bit more, to hold 1), so
#: that each weight is within 2^-25 of the input's (those from 1/2 to 1 exact) and a vertex's four sum to 1 as
#: closely as the input's did, to float32's precision (the glTF validator's ACCESSOR_WEIGHTS_NON_NORMALIZED:
#: webxr's generic hand on a 14-bit grid of the weights' range summed 4e-5 off at 995 of 1,360 vertices,
#: on 20 bits at 36, on 22 bits at none).
WEIGHTS_BITS = 24
#: An integer attribute (a non-normalized integer accessor: feature IDs, ``_BATCHID``) is carried
#: exactly, on a grid of step 1; float32 (the base's accessors) holds every integer up to this.
FLOAT32_EXACT_INTEGERS = 1 << 24
#: numpy dtype -> glTF componentType of the integer attributes.
_INTEGER_TYPES = {np.dtype(dtype): ctype for ctype, dtype in COMPONENT_DTYPES.items() if ctype != FLOAT}


#: TEXCOORD_n: a grid step of at most ``2**-TEXCOORD_STEP_BITS`` units of texture space (one unit: the
#: texture's width), whatever the coordinates' range, so the error stays within half of it, 1/16384
#: of the texture (a quarter of a texel at 4096², 1/16 at 1024²): the 14 bits of
#: :data:`ATTRIBUTE_BITS` cover a span up to 2 (the usual 0..1, and a little over), a wider one (tiled
#: UVs, an outlier, a texture a KHR_texture_transform ``scale`` repeats s times per unit: a span s times
#: as wide) gets more bits, up to 30 and as many as float32 carries at the coordinates' size.
TEXCOORD_STEP_BITS = 13


def _attribute_bits(semantic: str, values: np.ndarray | None = None, texture_scale: float = 1.0) -> int:
    """Grid bits of a float attribute: :data:`ATTRIBUTE_BITS` by semantic prefix (others 14); TEXCOORD_n
    as many more as its ``values`` (n, k) span, in textures (``texture_scale`` textures per unit: a
    KHR_texture_transform's), needs (:data:`TEXCOORD_STEP_BITS`); values that are not all finite have no span
    (the grid names them: "TEXCOORD_0 values are not finite")."""
    prefix = semantic.split("_")[0]
    bits = ATTRIBUTE_BITS.get(prefix, 14)
    if prefix == "TEXCOORD" and values is not None and values.size and np.isfinite(values).all():
        span = float(np.ptp(values, axis=0).max()) * max(1.0, texture_scale)
        need = int(np.ceil(np.log2(span * float(1 << TEXCOORD_STEP_BITS) + 1.0)))
        bits = min(MAX_GRID_BITS, max(bits, need))
    return bits


def _carries(grid: AttributeGrid, values: np.ndarray, semantic: str) -> bool:
    """Whether ``values`` (n, k) float64 on ``grid`` come back from the float32 the base stores."""
    try:
        ints = grid.from_float32(values, semantic)
        return bool(np.array_equal(grid.from_float32(grid.to_float32(ints), semantic), ints))
    except PmwError:  # FormatError: a stored value off the grid
        return False


#: A COLOR_n whose every component is an 8-bit colour (k / 255: a normalized UNSIGNED_BYTE accessor, a PLY's
#: or an OBJ's 0..255 colours) is carried on that lattice, exactly and in 8 bits rather than 12
#: (:func:`_colour_lattice`); a value counts as one within this fraction of a lattice step (float32's rounding of
#: k / 255 is 1.5e-5 of a step).
COLOUR_LATTICE_TOLERANCE = 1e-3


def _colour_lattice(values: np.ndarray) -> AttributeGrid | None:
    """An exact 8-bit grid for ``values`` (n, k) float64 of a COLOR_n, as many bits as the widest span of bytes
    needs (8 at most), from each component's least byte: the grid of step 1/255 when every value is an 8-bit
    colour k / 255 (within :data:`COLOUR_LATTICE_TOLERANCE` of a step: a normalized UNSIGNED_BYTE accessor); the
    ``srgb8`` grid (:class:`~pmwm_codec.progressive.grid.AttributeGrid`) when the red, green and blue values are
    8-bit sRGB colours decoded to linear (as float32: a PLY's or an OBJ's colours) and an alpha is k / 255; else
    None (the 12-bit grid of :data:`ATTRIBUTE_BITS`)."""
    if not values.size or not np.isfinite(values).all() or values.min() < 0.0 or values.max() > 1.0:
        return None
    k = np.rint(values * 255.0)
    if np.abs(values * 255.0 - k).max() <= COLOUR_LATTICE_TOLERANCE:
        lo = k.min(axis=0)
        bits = max(MIN_GRID_BITS, int((k.max(axis=0) - lo).max()).bit_length())
        return AttributeGrid(bits, tuple(float(x) / 255.0 for x in lo), (1.0 / 255.0,) * values.shape[1])
    if values.shape[1] in (3, 4):
        try:
            b = AttributeGrid(MIN_GRID_BITS, (0.0,) * values.shape[1], (1.0,) * values.shape[1],
                              SRGB8).from_float32(values, "COLOR")
        except FormatError:
            return None
        lo = b.min(axis=0)
        bits = max(MIN_GRID_BITS, int((b.max(axis=0) - lo).max()).bit_length())
        return AttributeGrid(bits, tuple(float(x) for x in lo), (1.0,) * values.shape[1], SRGB8)
    return None


def _attribute_grid(semantic: str, values: np.ndarray, texture_scale: float = 1.0) -> tuple:
    """``(AttributeGrid, extra spec members)`` of one attribute's ``values`` (n, k).

    Float values: :func:`_attribute_bits` over each component's range (TEXCOORD_n: ``texture_scale`` textures
    a unit, fewer bits where float32
    cannot carry that many at the values' size, never under :data:`ATTRIBUTE_BITS`); skin weights in [0, 1]
    (WEIGHTS_n) on the grid of step 2^-:data:`WEIGHTS_BITS` from 0.  Integer values (an integer
    dtype: a non-normalized integer accessor): step 1 from each component's minimum, as many bits as
    the widest span needs (at least 8), so every vertex keeps its exact integer; an application-specific
    attribute (``_FEATURE_ID_0``) and JOINTS_n also name their componentType, which a decoded level and the
    base write them with (the other standard semantics, integers only under KHR_mesh_quantization, are
    written as FLOAT)."""
    if not np.issubdtype(values.dtype, np.integer):
        values = np.asarray(values, np.float64)
        if semantic.startswith("WEIGHTS_") and values.size and values.min() >= 0.0 and values.max() <= 1.0:
            k = values.shape[1]  # skin weights: multiples of 2^-24 from 0, each float32 in [1/2, 1] exactly
            return AttributeGrid(WEIGHTS_BITS + 1, (0.0,) * k, (2.0**-WEIGHTS_BITS,) * k), {}
        lattice = _colour_lattice(values) if semantic.startswith("COLOR_") else None
        if lattice is not None:
            return lattice, {}
        bits, floor = _attribute_bits(semantic, values, texture_scale), _attribute_bits(semantic)
        grid = AttributeGrid.fit(values, bits)
        while grid.bits > floor and not _carries(grid, values, semantic):  # finer than float32 holds them
            grid = AttributeGrid.fit(values, grid.bits - 1)
        return grid, {}
    if values.size and int(np.abs(values.astype(np.int64)).max()) > FLOAT32_EXACT_INTEGERS:
        raise MeshError(f"{semantic}: integers beyond {FLOAT32_EXACT_INTEGERS:,}, which float32 cannot hold exactly")
    lo = values.min(axis=0).astype(np.int64)
    span = int((values.max(axis=0).astype(np.int64) - lo).max())
    grid = AttributeGrid(max(MIN_GRID_BITS, span.bit_length()), tuple(float(x) for x in lo), (1.0,) * len(lo))
    ctype = _INTEGER_TYPES.get(values.dtype)
    named = semantic.startswith(("_", "JOINTS_"))  # integers in glTF itself: JOINTS_n, UNSIGNED_BYTE / SHORT
    return grid, ({"componentType": ctype} if named and ctype is not None else {})


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
    embed_from: int | float = 0,
    owner_id: int | None = None,
    owner_strength: float | None = None,
    owner_fallback: bool = False,
    min_chunk_splits: int | None = None,
    zstd_level: int = 10,
    payload_version: int = DEFAULT_PAYLOAD_VERSION,
    measure="vertices",
    key_slot: KeySlot | None = None,
    progress=None,
) -> EncodeReport:
    """Make the primitives of ``jobs`` progressive inside ``doc`` and write the ``.pmw``.

    Parameters
    ----------
    doc, kept_bin : the document to carry and its data (see
        :func:`~pmwm_codec.format.glb.assemble_document`); not modified.
    jobs : list[PrimitiveJob]
    watermark : (s, s) uint8, optional
        A ``2^k`` square grayscale image (see :func:`~pmwm_codec.watermark.load_watermark`);
        one watermark for the whole document, its slots spread over every primitive's
        splits in stream order.
    key : WatermarkKey, optional
        Generated when a watermark is given and no key is.  Never modified: the report's
        ``key`` is a copy holding the parameters, the reference watermark and the file id.
    mode : ``"exact"`` | ``"paper"``; bits : bits per carrier (None: automatic / 12).
    grid_bits : position grid resolution (default 16; paper mode 22).
    base_codec : ``"draco"`` | ``"plain"`` (primitives with attributes use plain).
    base_vertices : target base size per primitive (default
        :func:`~pmwm_codec.stream.chunking.default_base_target`).
    embed_from : first vertex split (stream order, over every primitive) that carries a
        code: an int index or a float fraction in [0, 1) of the splits; stored in the file.
    owner_id : 64-bit owner ID: mark the owner layer (:mod:`~pmwm_codec.watermark.owner`)
        into the primitives' full-resolution positions first, taken as one mesh (when the
        scene shows it: :func:`_mark_owner`);
        the key (generated when
        none is given) is returned carrying it.  ``owner_strength``: its margin.  The layer
        must read back ``present`` (:func:`~pmwm_codec.watermark.owner.detect`, as ``pmw
        verify`` reads it) from the full decode; when it cannot (a mesh whose vertex norms span
        too narrow a range or take too few values: :func:`_owner_check`) the encode raises
        OwnerLayerError and writes nothing, or with ``owner_fallback`` (the layer on by
        default under a watermark) writes the file without it, the returned key naming no
        owner ID (a key file reused as it is stays as it is), and says why in the report's
        ``notices``.
    min_chunk_splits : smallest chunk, in splits, for every chunk of every primitive (default:
        :func:`~pmwm_codec.stream.chunking.default_min_chunk_splits`, reached by chunks that start
        at :data:`~pmwm_codec.stream.chunking.FIRST_CHUNK_SPLITS` and double).
    measure : how to measure the distortion of the full decoded mesh (see
        :func:`~pmwm_codec.distortion.full_distortion`): ``"vertices"`` (default, exact RMS
        and PSNR, Hausdorff bounded by the largest vertex displacement), ``"sampled"``
        (Metro-style sampled surface Hausdorff) or ``"none"``; True / False stand for
        ``"vertices"`` / ``"none"``.
    key_slot : :class:`~pmwm_codec.watermark.key.KeySlot`, optional
        The key file to create or reuse (its existing key should be ``key``); the key file
        (if new) is published just before the ``.pmw``, under one directory lock, so a
        failure at any moment leaves the old pair or the new one (:func:`_publish`).
    payload_version : chunk payload format, 2 (the default: one range-coded stream per chunk,
        bitstream.md §8, indexed by a compact chunk table, §6.2) or 1 (zstd columns, §6, one
        index entry per chunk).
    progress : optional callable(stage: str, fraction: float).

    The same arguments give the same bytes.
    """
    t0 = time.perf_counter()
    say = progress or (lambda stage, fraction: None)
    measure = measure_method(measure)  # a bad value fails before any work
    job_vertices(sum(job.mesh.vertex_count for job in jobs))
    if payload_version not in PAYLOAD_VERSIONS or isinstance(payload_version, bool):
        raise ValueError(f"payload_version must be one of {PAYLOAD_VERSIONS}, not {payload_version!r}")
    if grid_bits is None:
        grid_bits = wm.DEFAULT_GRID_BITS[mode] if watermark is not None else DEFAULT_GRID_BITS
    _check_moved_grids(jobs, grid_bits,
                       _moved_reach(watermark is not None, mode, bits, step_units, owner_id is not None))
    owner_notices = []
    # a key that already names the owner ID: a key file reused as it is, or a key given (a collection's)
    kept_owner = key_slot.existing if key_slot is not None else key
    kept_owner = None if kept_owner is None else kept_owner.owner_id

    def drop_owner(why: str) -> None:
        """The owner layer cannot be read back: refuse, or go on without it (``owner_fallback``)."""
        _owner_unreadable(why, owner_fallback, owner_notices, watermark is not None, kept_owner is not None)

    marked = None
    if owner_id is not None:
        key = dataclasses.replace(key if key is not None else WatermarkKey.generate(), owner_id=int(owner_id))
        marked, why = _mark_owner(jobs, key, owner_strength, grid_bits, doc, owner_notices)
        if why is not None:
            drop_owner(why)
            owner_id, marked = None, None
            key = key if watermark is not None else None  # no mark at all: no key
    if watermark is not None:
        key = key if key is not None else WatermarkKey.generate()

    def stages(jobs):
        """Stages 1-5 over ``jobs``: ``(work, notices, order, carriers, params)``."""
        work = _quantize_and_simplify(jobs, grid_bits, base_vertices, say, defer_faces=payload_version == 2)
        unrefined = _unrefined_notices(work, base_vertices, doc)
        work, notices = _encode_bases(work, base_codec)
        notices = unrefined + notices
        work, order, slots, carriers = _plan_chunks(work, min_chunk_splits)
        params = None
        if watermark is not None:
            params, work = _plan_watermark(work, watermark, key, carriers, slots, mode, bits, step_units,
                                           embed_from)
        return _build_records(work, say, payload_version), notices, order, carriers, params

    work, notices, order, carriers, params = stages(jobs if marked is None else marked)
    decoded = None
    if owner_id is not None and params is not None:  # the watermark moved vertices: read the full decode
        decoded = [_decoded_input_positions(w) for w in work]
        frames = owner_placements(doc, [w.job.mesh_index for w in work])[0]  # placed as _mark_owner placed them
        owner_notices[:] = [n for n in owner_notices if not n.startswith(_WEAK_NOTICE)]  # read again: the decode's
        why = _owner_check(decoded, [w.job.mesh.faces for w in work], key, frames, owner_notices)
        if why is not None:
            owner_notices[:] = [n for n in owner_notices if not n.startswith((_TRANSPORT_NOTICE, _WEAK_NOTICE))]  # moot
            drop_owner(why)
            owner_id, decoded = None, None
            work, notices, order, carriers, params = stages(jobs)
    notices = owner_notices + notices
    stated = None
    if owner_id is not None:  # the frame the layer reads in at full resolution, for the stream's readers
        stated = _stated_owner_frame(decoded if decoded is not None else [_decoded_input_positions(w) for w in work],
                                     [w.job.mesh.faces for w in work], key,
                                     owner_placements(doc, [w.job.mesh_index for w in work])[0])
    report = _report(work, params, measure, say, decoded)
    fault_point("measured")
    prims, file_id = _primitives(doc, kept_bin, work, order, params, key, payload_version, stated)
    if params is not None:
        key = dataclasses.replace(
            key, file_id=file_id, params=params.get_config(), reference=np.asarray(watermark, np.uint8)
        )
    if key is not None and owner_id is None and key.owner_id is not None:
        key = dataclasses.replace(key, owner_id=None)  # the key names an owner id only if the layer is there
    say("write", 0.0)
    mac_key = key.mac_key() if params is not None else None  # marked files carry keyed MACs
    published = key  # a key file reused as it is still names its owner ID (KeySlot.pending compares)
    if owner_notices and key_slot is not None and key_slot.existing is not None and kept_owner is not None:
        published = dataclasses.replace(key, owner_id=kept_owner)
    size = _publish(dst, assemble_document(doc, kept_bin, prims, order, zstd_level, mac_key), published, key_slot)
    say("write", 1.0)
    return dataclasses.replace(
        report, vsplits=carriers, chunks=len(order), bytes=int(size), seconds=time.perf_counter() - t0,
        base_codec=work[0].base.codec if work else base_codec, notices=notices, key=key,
    )


def _mark_owner(jobs, key: WatermarkKey, strength, grid_bits: int, doc: dict, notices: list) -> tuple:
    """Stage 0: the owner layer on the primitives' full-resolution positions, taken as one mesh where
    the scene shows them, or where they are stored.

    ``pmw verify`` reads the layer from every primitive of a file at once, in the view
    :func:`~pmwm_codec.format.gltf.owner_placements` gives: a ``.pmw``'s parts
    (:func:`~pmwm_codec.verify.owner.owner_of_stream`) as a decoded asset's triangle primitives
    (:func:`~pmwm_codec.verify.owner.owner_view`).  So the layer is marked into that one mesh (every
    primitive placed once per matrix of its mesh, :func:`~pmwm_codec.format.gltf.scene_mesh`) and each
    vertex's move is taken back into its own primitive's stored coordinates (the inverse of its
    matrix's linear part).  In the scene, the copies of a mesh shown several times (nodes that share
    it) stay where they are (one move cannot mark them alike) and count in the statistics; the meshes
    shown once carry the layer.  A scene with no mesh shown once (instances only, GPU instancing) or
    whose placements do not read is marked in its meshes' stored coordinates, each mesh once.

    Returns ``(new jobs, None)``, or ``(None, why)`` (a phrase) when the layer cannot be read
    back from the positions as stored: first a cheap test on the coarsest grid
    (:func:`~pmwm_codec.watermark.owner.unreadable`: shells under half a grid step wide, or
    too many of them empty; the embedding's feedback rounds cannot succeed there), then, once
    marked, a blind read (:func:`_owner_check`) of the positions on the grids stage 1 will fit
    them to: without a watermark those are exactly the positions of the full decode.  A layer that
    reads back but not after the re-compression :func:`_transport_check` simulates gets a notice in
    ``notices``, and so does one that reads back ``present`` with a bit wrong or erased (:func:`_weak_notice`).
    """
    from ..watermark import owner

    frames, _ = owner_placements(doc, [job.mesh_index for job in jobs])
    strength = owner.DEFAULT_STRENGTH if strength is None else float(strength)
    grids = position_grids(jobs, grid_bits)
    # several primitives: marked as the read will see them, on their grids (copies of a position that
    # grids of their own round apart, where meshes placed by different transforms meet, are two
    # positions there too), so the layer's frame is the read's; one primitive: its own positions
    base = [job.mesh.positions if len(jobs) == 1 else grid.dequantize(grid.quantize(job.mesh.positions))
            for job, grid in zip(jobs, grids)]
    points, faces, spans = scene_mesh(base, [job.mesh.faces for job in jobs], frames)
    step = max(grid.step * np.linalg.norm(m[:3, :3], 2) for grid, ms in zip(grids, frames) for m in ms)
    why = owner.unreadable(points, faces, step)  # (``step``: the coarsest grid step, in the scene)
    if why is not None:
        return None, why
    fixed = None  # the copies of a mesh shown several times stay; they count in the statistics
    if any(len(m) > 1 for m in frames):
        fixed = np.zeros(len(points), bool)
        for mine in spans:
            for start, stop in mine if len(mine) > 1 else ():
                fixed[start:stop] = True
    moved = owner.embed(points, faces, key, strength=strength, fixed=fixed)  # coincident vertices stay so
    marked = []
    for job, p, ms, mine in zip(jobs, base, frames, spans):
        if len(ms) > 1:
            marked.append(job)
            continue
        (start, stop), m = mine[0], ms[0]
        shift = moved[start:stop] - points[start:stop]
        if not np.array_equal(m, np.eye(4)):
            shift = np.linalg.solve(m[:3, :3], shift.T).T
        marked.append(dataclasses.replace(job, mesh=dataclasses.replace(job.mesh, positions=p + shift)))
    grids = position_grids(marked, grid_bits)  # as stage 1 fits them
    stored = [grid.dequantize(grid.quantize(job.mesh.positions)) for job, grid in zip(marked, grids)]
    why = _owner_check(stored, [job.mesh.faces for job in marked], key, frames, notices)
    if why is not None:
        return None, why
    points, tris, _ = scene_mesh(stored, [job.mesh.faces for job in marked], frames)
    said = _transport_check(points, tris, key)
    if said is not None:
        _notice(notices, said)
    return marked, None


#: :func:`_transport_check`'s grids: Draco's own default (``draco_encoder -qp 11``) and glTF-Transform's and
#: gltfpack's (14 bits).
TRANSPORT_CHECK_BITS = (11, 14)


def _transport_check(points: np.ndarray, faces: np.ndarray, key: WatermarkKey) -> str | None:
    """What to tell the user when the owner layer of the marked mesh ``points`` (n, 3) / ``faces`` (m, 3) would
    not read ``present`` after re-compression, else None.

    Simulated as Draco, glTF-Transform and gltfpack quantize: one cubic grid over the largest extent from
    the bounding box's corner, :data:`TRANSPORT_CHECK_BITS` bits, each position rounded to its nearest
    point; positions that land on one point become one (the read counts each position once).  The
    embedding's own feedback measures its margins after such a quantization but with the mesh's own
    vertices; where separate pieces of a mesh have vertices closer than a step, the re-compressed file
    joins them and the layer's frame, an area centroid, may move by a shell: pybullet's procedurally built
    meshes read 20-31 errors of 64 after 14-bit quantization with every margin met.
    """
    from ..verify.owner import owner_of_mesh
    from ..watermark.owner import on_storage_grid

    if not float((points.max(0) - points.min(0)).max()) > 0:
        return None
    wrong = []
    for bits in TRANSPORT_CHECK_BITS:
        read = owner_of_mesh(Mesh(on_storage_grid(points, bits), faces), key)
        if read.verdict != "present":
            wrong.append(f"{read.bit_errors} of its {read.bits} bits wrong after {bits}-bit quantization ({read.verdict})")
    if not wrong:
        return None
    return (f"{_TRANSPORT_NOTICE}: pmw verify would read {' and '.join(wrong)}, as Draco, glTF-Transform and "
            "gltfpack store positions; lossless copies keep it")


_TRANSPORT_NOTICE = "the owner layer may not survive re-compression of this mesh"
_WEAK_NOTICE = "the owner layer has less margin than usual on this mesh"


def _weak_notice(read) -> str | None:
    """What to tell the user when the owner layer reads ``present`` from the file as written (``read``, an
    :class:`~pmwm_codec.watermark.owner.OwnerResult`) with a bit wrong or erased, else None: every bit an
    attack may still cost is one fewer (a 505-vertex mesh leaves shells with no vertex; CGAL's 17.5k-vertex man
    read a bit wrong for half of all keys before the coding was chosen again)."""
    if read.verdict != "present" or not read.bit_errors:
        return None
    erased = f", {read.erased} of them in shells no vertex falls in" if read.erased else ""
    return (f"{_WEAK_NOTICE}: pmw verify reads {read.bit_errors} of its {read.bits} bits wrong from the file as "
            f"written{erased}, where a mark reads none: it reads present, with fewer bits to spare against noise, "
            "smoothing, simplification or re-compression")


def _owner_check(positions: list, faces: list, key: WatermarkKey, frames: list,
                 notices: list | None = None) -> str | None:
    """Why the owner layer does not read back ``present`` from the primitives' stored positions (a list
    of (n_i, 3)) and faces (a list of (m_i, 3)), each placed once per world matrix of its mesh
    (``frames``, :func:`~pmwm_codec.format.gltf.owner_placements`) and taken as one mesh, as ``pmw
    verify`` reads the mesh file of a decoded stream (:func:`~pmwm_codec.verify.owner.owner_of_mesh`: whole and
    piece by piece, the false-alarm bound over every read: a mesh of two large pieces reads ``present`` with
    one error less than one piece does), or None when it does, and does also with the scene's positions
    rounded to float32: a decoded GLB places float32 positions by its nodes, and a copy is re-saved in
    float32, a few float32 steps from the stream's own scene (pico-neo2's 717-vertex controller read 7 bits
    wrong from its ``.pmw``, 5 erased, ``present``; 20 from its decoded GLB, the positions within 4e-9).
    ``notices``: where it reads ``present`` with a bit wrong or erased from the file, :func:`_weak_notice`
    goes there."""
    from ..verify.owner import owner_of_mesh

    points, tris, _ = scene_mesh(positions, faces, frames)
    read = owner_of_mesh(Mesh(points, tris), key)
    where = "from the file"
    if read.verdict == "present":
        written = read
        read = owner_of_mesh(Mesh(points.astype(np.float32).astype(np.float64), tris), key)
        where = "from the file's positions rounded to float32, as a decoded or re-saved copy holds them"
        if read.verdict == "present":
            if notices is not None:
                _notice(notices, _weak_notice(written))
            return None
    erased = f", {read.erased} of them in shells no vertex falls in" if read.erased else ""
    return f"pmw verify would read {read.bit_errors} of its {read.bits} bits wrong {where}{erased}: {read.verdict}"


def _stated_owner_frame(positions: list, faces: list, key: WatermarkKey, frames: list) -> dict | None:
    """The ``ownerFrame`` object (spec README) of a file whose primitives decode in full to ``positions`` (a
    list of (n_i, 3)) with ``faces`` (a list of (m_i, 3)), placed by ``frames`` as :func:`_owner_check` and
    ``pmw verify`` place them: the frame the layer marked with ``key`` reads in
    (:func:`~pmwm_codec.watermark.owner.stated_frame`), which the stream's readers take at every chunk
    boundary in place of the level's own estimate; None for a degenerate frame (no layer reads there)."""
    from ..watermark import owner

    points, tris, _ = scene_mesh(positions, faces, frames)
    frame = owner.stated_frame(points, tris, key)
    return owner.frame_json(frame) if frame[2] > 0 else None


def _owner_unreadable(why: str, fallback: bool, notices: list, watermark: bool, reused: bool) -> None:
    """The owner layer cannot be read back (``why``): raise OwnerLayerError (nothing is written), or
    with ``fallback`` add the notice that the file carries none.  ``reused``: the key already names
    the owner ID (a key file reused as it is, or a collection's key): it still does, for the files
    that carry the layer, and the returned key of this file names none."""
    what = f"the owner layer cannot be read back from this mesh ({why})"
    if not fallback:
        raise OwnerLayerError(f"{what}; encode without --owner-id")
    if not watermark:
        _notice(notices, f"{what}: the file carries no mark")
    elif reused:
        _notice(notices, f"{what}: the file carries the image watermark only; the key, reused as it is, names an "
                         "owner id this file does not carry")
    else:
        _notice(notices, f"{what}: the file carries the image watermark only, and its key names no owner id")


#: Two vertices of different primitives coincide within this fraction of the coordinates' size (16 float32
#: rounding steps: the copies of a border stored in different frames and put back by their nodes' matrices
#: land that close, and so do copies written with float noise; distinct vertices of a mesh are much farther
#: apart): in the scene (:func:`~pmwm_codec.stream.asset._lock_shared_positions`), and between the borders
#: the asset locked, as stored (:func:`border_pairs`).
SCENE_TOLERANCE = 2.0**-20


def position_grids(jobs: list, grid_bits: int) -> list:
    """The position grid (:class:`~pmwm_codec.progressive.grid.Grid`) of each of ``jobs`` (a list of
    :class:`PrimitiveJob`): primitives that share a position (a surface cut into primitives, its cut border in
    each: equal positions, or locked border vertices within :data:`SCENE_TOLERANCE` of each other, which float
    noise leaves apart: :func:`border_pairs`) share one grid, spanning all of them, so a shared position is one
    grid point in every one (:func:`borders_on_one_point` puts the noisy copies there) and decodes to the same
    float32 in each: no crack opens between them, and the owner layer, whose statistics count a position once
    (:mod:`~pmwm_codec.watermark.owner`), reads them as one surface.  Every other primitive's grid spans its
    own bounding box."""
    meshes = [job.mesh for job in jobs]
    boxes = [np.stack(bounds(m.positions)) for m in meshes]
    label = _sharing_groups([m.positions for m in meshes], _owners(jobs)[border_pairs(jobs)])
    grids = {}
    for g in np.unique(label):
        members = np.flatnonzero(label == g)
        span = np.concatenate([boxes[i] for i in members])
        grids[int(g)] = Grid.fit(span, grid_bits)
    return [grids[int(g)] for g in label]


def _owners(jobs: list) -> np.ndarray:
    """(N,) int64: the job of every vertex of ``jobs``' meshes taken one after the other."""
    return np.repeat(np.arange(len(jobs)), [job.mesh.vertex_count for job in jobs])


def border_pairs(jobs: list) -> np.ndarray:
    """(p, 2) int64: pairs of vertices of different primitives of ``jobs`` (indices into their meshes' vertices
    taken one after the other), both locked (:attr:`PrimitiveJob.locked`: a border with another primitive in the
    scene), whose stored positions differ by at most :data:`SCENE_TOLERANCE` of the coordinates' size in every
    coordinate: a border's two copies, equal or a few float32 rounding steps apart."""
    if len(jobs) < 2 or all(job.locked is None or not job.locked.any() for job in jobs):
        return np.zeros((0, 2), np.int64)
    from scipy.spatial import cKDTree

    starts = np.cumsum([0] + [job.mesh.vertex_count for job in jobs])
    index = np.concatenate([starts[k] + np.flatnonzero(job.locked) for k, job in enumerate(jobs)
                            if job.locked is not None])
    points = np.concatenate([np.asarray(job.mesh.positions, np.float64)[job.locked] for job in jobs
                             if job.locked is not None])
    size = float(np.abs(points).max(initial=0.0))
    pairs = cKDTree(points).query_pairs(SCENE_TOLERANCE * size, p=np.inf, output_type="ndarray")
    pairs = index[pairs.reshape(-1, 2)]
    owner = _owners(jobs)
    return pairs[owner[pairs[:, 0]] != owner[pairs[:, 1]]]


def borders_on_one_point(values: list, jobs: list) -> list:
    """``values`` (a list of (n_i, D) int64 grid values, positions first, one per job of ``jobs``, on the grids
    of :func:`position_grids`) with every group of a border's copies in different primitives
    (:func:`border_pairs`, joined through shared members) on the grid point of its first copy (the first
    primitive's, its smallest vertex): copies a float noise apart can fall on either side of a rounding
    boundary and would decode a grid step apart, a crack along the border at every level.  The arrays that
    change are copies; the others are returned as they are."""
    pairs = border_pairs(jobs)
    if len(pairs) == 0:
        return values
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    members, local = np.unique(pairs, return_inverse=True)
    local = local.reshape(-1, 2)
    k = len(members)
    graph = coo_matrix((np.ones(len(local), np.int8), (local[:, 0], local[:, 1])), shape=(k, k))
    _, part = connected_components(graph, directed=False)
    lead = np.full(part.max() + 1, members.max() + 1, np.int64)
    np.minimum.at(lead, part, members)  # members ascending: the first copy of each group
    q = np.concatenate([v[:, :3] for v in values])
    target = q[lead[part]]
    moves = np.any(q[members] != target, axis=1)
    if not moves.any():
        return values
    q[members[moves]] = target[moves]
    starts = np.cumsum([0] + [len(v) for v in values])
    out = []
    for k, v in enumerate(values):
        rows = q[starts[k] : starts[k + 1]]
        out.append(v if np.array_equal(rows, v[:, :3]) else np.concatenate([rows, v[:, 3:]], axis=1))
    return out


def _sharing_groups(positions: list, near: np.ndarray | None = None) -> np.ndarray:
    """(k,) int64: a group label for each of ``positions`` (a list of (n_i, 3) float arrays), the smallest
    index of the arrays it shares an exactly equal position with, directly or through others; ``near``
    (p, 2) int64: pairs of arrays that share a position within a tolerance too (:func:`border_pairs`'
    owners)."""
    label = np.arange(len(positions))
    if len(positions) < 2:
        return label
    points = np.concatenate(positions)
    owner = np.repeat(label, [len(p) for p in positions])
    order = np.lexsort((owner, *points.T[::-1]))
    p, o = points[order], owner[order]
    same = np.all(p[1:] == p[:-1], axis=1) & (o[1:] != o[:-1])
    pairs = np.stack([o[:-1][same], o[1:][same]], 1)
    if near is not None and len(near):
        pairs = np.concatenate([pairs, near])
    pairs = np.unique(pairs, axis=0)
    for _ in range(len(positions)):  # relax to the smallest label of each connected group
        before = label.copy()
        for a, b in pairs:
            label[a] = label[b] = min(label[a], label[b])
        if np.array_equal(before, label):
            break
    return label


def _quantize(job: PrimitiveJob, grid: Grid) -> tuple:
    """``(grid, values (n, D) int64, attribute grids)`` of one job's mesh on its position ``grid``
    (:func:`position_grids`): positions, then attributes (TEXCOORD_n as finely as its ``texture_scales``).

    Raises MeshError when the positions or an attribute's grid values do not survive a float32 round trip.
    """
    mesh, scales = job.mesh, job.texture_scales or {}
    q = grid.quantize(mesh.positions)
    if not _survives_float32(grid, q):
        raise MeshError(_float32_refusal(mesh.positions, grid))
    specs, columns = [], [q]
    for semantic in sorted(mesh.attributes):
        values = np.asarray(mesh.attributes[semantic]).reshape(mesh.vertex_count, -1)
        agrid, extra = _attribute_grid(semantic, values, scales.get(semantic, 1.0))
        ints = agrid.from_float32(values.astype(np.float64), semantic)
        if not np.array_equal(agrid.from_float32(agrid.to_float32(ints), semantic), ints):
            raise MeshError(f"{semantic}: values too large for float32 at {agrid.bits} bits")
        specs.append({"semantic": semantic, **agrid.get_config(), **extra})
        columns.append(ints)
    return grid, np.concatenate(columns, axis=1), specs


def _survives_float32(grid: Grid, q: np.ndarray, reach: tuple | None = None) -> bool:
    """Whether the grid points ``q`` (n, 3) int64 come back from the float32 positions glTF stores; with
    ``reach`` (:func:`_moved_reach`: vertices will move to grid points the input does not hold), whether
    every grid point of their box widened by ``reach`` does (:meth:`Grid.carries_float32`)."""
    if reach is not None:
        lo, hi = bounds(grid.dequantize(q))
        with np.errstate(over="ignore"):  # a diagonal past float64 (extents ~1e154 and up) is inf: no float32 holds it
            far = reach[0] * grid.step + reach[1] * float(np.linalg.norm(hi - lo))
        return grid.carries_float32(lo - far, hi + far)
    try:
        return bool(np.array_equal(grid.from_float32(grid.to_float32(q)), q))
    except PmwError:  # FormatError: a stored coordinate off the grid
        return False


#: Bits per code of a paper-mode watermark when none are asked for (:func:`~pmwm_codec.watermark.codec.plan`).
_PAPER_BITS = 12
#: How far the owner layer may move a vertex, as a fraction of the bounding-box diagonal: it moves
#: vertices along rays from the area centroid, never out of their shell (64 shells between two
#: quantiles of the vertex norms, so a shell is under 1/64 of the diagonal wide).
_OWNER_REACH = 0.02


def _moved_reach(watermark: bool, mode: str, bits, step_units, owner: bool) -> tuple | None:
    """``(grid steps, fraction of the bbox diagonal)``: how far from the input the watermark and the
    owner layer may put a vertex, or None when neither moves any.

    A watermark code moves its vertex along the ray from its ring's centroid into the nearest bin of
    its code: at most one period, ``2**bits`` codes of ``step_units`` grid steps each
    (:func:`~pmwm_codec.watermark.codec.place_codes`), plus the neighbouring lattice point it picks
    (one step per axis) and the retries that move a clashing carrier (up to three per axis)."""
    if not watermark and not owner:
        return None
    steps = 0.0
    if watermark:
        b = bits if bits is not None else (wm.MAX_EXACT_BITS if mode == "exact" else _PAPER_BITS)
        unit = wm.DEFAULT_STEP_UNITS.get(mode, 2.0) if step_units is None else float(step_units)
        steps = float(1 << int(b)) * unit + 4.0
    return steps, (_OWNER_REACH if owner else 0.0)


def _check_moved_grids(jobs: list, grid_bits: int, reach: tuple | None) -> None:
    """Refuse (MeshError, :func:`_float32_refusal`) before any work a grid of ``grid_bits`` bits on which
    the watermark or the owner layer (``reach``: :func:`_moved_reach`) would move vertices of the meshes of
    ``jobs`` to points float32 cannot carry: every point of its box, widened by the reach, must
    come back.  The input's own points are checked in :func:`_quantize` (a mesh nobody moves, float32
    input far from the origin, stays exact on any grid: only its own points are stored)."""
    if reach is None:
        return
    for job, grid in zip(jobs, position_grids(jobs, grid_bits)):
        mesh = job.mesh
        if not _survives_float32(grid, grid.quantize(mesh.positions), reach):
            raise MeshError(_float32_refusal(mesh.positions, grid, reach))


def _float32_refusal(positions: np.ndarray, grid: Grid, reach: tuple | None = None) -> str:
    """Why ``grid`` cannot carry ``positions`` (n, 3) float through float32 (with ``reach``, the grid
    points of their box the watermark / owner layer may move vertices to: :func:`_survives_float32`),
    and the finest grid that can."""
    extreme = float(np.abs(positions).max())
    extent = grid.step * ((1 << grid.bits) - 1)
    why = (f"a {grid.bits}-bit position grid (step {grid.step:.3g}) does not survive the float32 positions glTF "
           f"stores: the mesh spans {extent:.6g} but lies up to {extreme:.6g} from the origin, where float32 steps "
           f"are {float(float32_spacing(extreme)):.3g}")
    if reach is not None:
        why += (" (the watermark and the owner layer move vertices to grid points the input does not hold: every "
                "grid point of its box must survive)")
    if not np.isfinite(float32_spacing(extreme)):  # past float32's range: no place or grid helps, only a scale
        return (f"{why}; coordinates beyond float32's range ({float(np.finfo(np.float32).max):.3g}) cannot be "
                "stored at all: scale the mesh down")
    for bits in range(grid.bits - 1, MIN_GRID_BITS - 1, -1):
        coarse = Grid.fit(positions, bits)
        if _survives_float32(coarse, coarse.quantize(positions), reach):
            return f"{why}; the finest grid that does is --grid-bits {bits} (or move the mesh nearer the origin)"
    return f"{why}; no grid of {MIN_GRID_BITS} bits or more does: move the mesh nearer the origin"


def _quantize_and_simplify(jobs, grid_bits: int, base_vertices, say, defer_faces: bool = True) -> list:
    """Stage 1: one :class:`PrimitiveWork` per job with its grid, values and collapse log.

    ``defer_faces``: simplify without the :func:`~pmwm_codec.progressive.simplify.deferred_faces`
    (pillows, specks) and the vertices only they name, which a face chunk sends at the end
    (payload version 2 only).
    """
    work = []
    say("simplify", 0.0)
    quantized = [_quantize(job, grid) for job, grid in zip(jobs, position_grids(jobs, grid_bits))]
    on_one_point = borders_on_one_point([values for _, values, _ in quantized], jobs)
    for i, job in enumerate(jobs):
        grid, values, specs = quantized[i][0], on_one_point[i], quantized[i][2]
        faces, positions, locked = job.mesh.faces, job.mesh.positions, job.locked
        # a seam's copies a hair apart (float noise) on one grid point, even where the grid rounds between them
        q = values[:, :3]
        snapped = snap_near_copies(q, positions, faces, grid.step, locked)
        if snapped is not q:
            values = np.concatenate([snapped, values[:, 3:]], axis=1)
        if locked is not None:
            locked = _locked_with_grid_copies(values[:, :3], locked)
        late, twin = (deferred_and_twin_faces(values[:, :3], faces) if defer_faces
                      else (np.zeros(len(faces), bool), None))
        values, positions, faces, locked, twin, extra, points, weld = _core_and_copies(
            job.mesh.vertex_count, values, positions, faces, locked, twin, late, defer_faces)
        target = default_base_target(len(values)) if base_vertices is None else int(base_vertices)
        log = simplify(values[:, :3], faces, target_vertices=target, locked=locked, weld=weld, twin=twin,
                       points=np.arange(len(values)) if points is None else points)
        work.append(PrimitiveWork(job, grid, values, specs, log, **extra))
        say("simplify", (i + 1) / len(jobs))
    return work


def _unrefined_notices(work, base_vertices, doc: dict) -> list:
    """Notices for the primitives of ``work`` (stage 1's) that got no vertex split: their base is the whole
    primitive.  One notice for those too small to refine (no more vertices than their base target,
    ``base_vertices`` or :func:`~pmwm_codec.stream.chunking.default_base_target`), and one per other
    primitive saying which of its vertices had to stay (seam corners, borders with other primitives).
    ``doc``: the document (an asset's has an ``asset`` member; a mesh file's is "the mesh")."""
    small, notices = [], []
    for w in work:
        where = _primitive_name(doc, w.job, len(work))
        n = len(w.values)
        target = default_base_target(n) if base_vertices is None else int(base_vertices)
        removed = sum(len(b.u) for b in w.log.batches)
        if removed:
            if n - removed > max(4 * target, n // 4):  # refined, but far from its base target
                notices.append(f"{where}: {n - removed:,} of its {n:,} vertices stay in the base (target {target:,}): "
                               + _why_unrefined(w, refined=True))
            continue
        if n <= target:
            small.append((where, n))
            continue
        notices.append(f"{where}: not made progressive (0 vertex splits: the base is the whole primitive): "
                       + _why_unrefined(w))
    if small:
        names = ", ".join(w for w, _ in small[:_NAMES_QUOTED])
        names += f" and {len(small) - _NAMES_QUOTED} more" if len(small) > _NAMES_QUOTED else ""
        bound = f"--base-vertices {int(base_vertices)}" if base_vertices is not None else "a base keeps (at least 64)"
        size = (f"it has {small[0][1]} vertices, no more than" if len(small) == 1
                else "each has no more vertices than")
        notices.insert(0, f"{names}: not made progressive (0 vertex splits): {size} {bound}, so the base is all of it")
    return notices


#: How many primitives a notice names before "and k more".
_NAMES_QUOTED = 3


def _primitive_name(doc: dict, job: PrimitiveJob, count: int) -> str:
    """How notices name a primitive: ``mesh i (name) primitive j`` in an asset, "the mesh" for a mesh file."""
    if "asset" not in doc and count == 1:
        return "the mesh"
    meshes = doc.get("meshes")
    mesh = meshes[job.mesh_index] if isinstance(meshes, list) and job.mesh_index < len(meshes) else {}
    name = mesh.get("name") if isinstance(mesh, dict) else None
    return f"mesh {job.mesh_index}" + (f" ({name})" if isinstance(name, str) and name else "") + \
        f" primitive {job.primitive_index}"


def _why_unrefined(w: PrimitiveWork, refined: bool = False) -> str:
    """Why the simplifier removed no vertex of ``w`` (``refined``: so few) although it has more than its base
    target: how many separate parts it is, when three vertices a part are a tenth of what stayed or more (a
    scene of thousands of boxes); how many of its vertices are seam corners (three or more copies of a position
    on the grid), on borders with other primitives (locked), seam copies (two), and the rest; and how many of
    its edges run the same way in two faces (faces oriented against their neighbours, which no collapse
    crosses)."""
    job = w.job
    faces, positions, locked = job.mesh.faces, job.mesh.positions, job.locked
    if w.core is not None:  # the vertices the simplifier saw, and the faces among them
        local = np.full(job.mesh.vertex_count, -1, np.int64)
        local[w.core] = np.arange(len(w.core))
        faces = local[faces][(local[faces] >= 0).all(axis=1)]
        positions = positions[w.core]
        locked = None if locked is None else locked[w.core]
    q, n = w.values[:, :3], len(w.values)
    weld = grid_weld(q, faces, positions)
    size = np.ones(n, np.int64) if weld is None else np.bincount(weld, minlength=n)[weld]
    corner = size >= 3
    border = np.zeros(n, bool) if locked is None else _locked_with_grid_copies(q, locked) & ~corner
    seam = (size == 2) & ~border
    why = []
    if corner.any():
        why.append(f"{int(corner.sum())} share their position with two or more other vertices " + (
            "(seam corners, kept in the base: per-face normals or UVs, as flat shading has at every vertex)"
            if job.mesh.attributes else "(one point written as separate vertices, kept in the base: weld them to "
                                         "stream it)"))
    if border.any():
        why.append(f"{int(border.sum())} lie on borders with other primitives (kept in the base)")
    if seam.any():
        why.append(f"{int(seam.sum())} are seam copies (removed only in pairs, along a seam between two copies)")
    rest = n - int(corner.sum() + border.sum() + seam.sum())
    against = _edges_run_twice(faces)
    parts, floor = _separate_parts(faces if weld is None else weld[faces], n)
    kept = n - sum(len(b.u) for b in w.log.batches)
    lead = [f"the surface is {parts:,} separate parts, which no collapse joins, each keeping at least three "
            f"vertices ({floor:,} in all)"] if parts > 1 and floor * 10 >= kept else []
    if refined:
        why = ([] if not why else ["of them, " + "; ".join(why)]) + lead
        if against:
            why.append(f"{against:,} edges run the same way in two faces (faces oriented against their "
                       "neighbours, which no collapse crosses: orient the faces consistently to stream them)")
        return "; ".join(why) or "no other collapse keeps the surface valid"
    if rest:
        why.append(f"no collapse of the other {rest} keeps the surface valid"
                   + (f" ({against:,} edges run the same way in two faces: faces oriented against their "
                      "neighbours, which no collapse crosses)" if against else ""))
    return "; ".join([f"of its {n} vertices, " + "; ".join(why)] + lead)


def _separate_parts(faces: np.ndarray, n: int) -> tuple:
    """``(parts, floor)``: how many connected parts the faces (m, 3) int of a mesh of ``n`` vertices make (through
    shared vertices; pass faces through the grid weld so that seam copies join their parts), and the fewest
    vertices they can be coarsened to, three a part (or all of a smaller one's): a half-edge collapse moves a
    vertex onto a neighbour, so it never joins two parts nor leaves a part without a face."""
    if not len(faces):
        return 0, 0
    _, label = vertex_components(faces, n)
    used = np.zeros(n, bool)
    used[faces.ravel()] = True
    size = np.bincount(label[used])
    size = size[size > 0]
    return len(size), int(np.minimum(size, 3).sum())


def _edges_run_twice(faces: np.ndarray) -> int:
    """How many directed edges of ``faces`` (m, 3) int two or more faces share (an edge two faces run the same
    way: one of them is oriented against the other)."""
    if not len(faces):
        return 0
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]).astype(np.int64)
    key = edges[:, 0] * (int(edges.max()) + 1) + edges[:, 1]
    _, counts = np.unique(key, return_counts=True)
    return int((counts > 1).sum())


def _locked_with_grid_copies(q: np.ndarray, locked: np.ndarray) -> np.ndarray:
    """(n,) bool: ``locked`` (n,) bool (:func:`~pmwm_codec.stream.asset._lock_shared_positions`: a border with
    another primitive) with every vertex on the grid point ``q`` (n, 3) int64 of a locked one: copies that
    land on one grid point are one position in the stream, and stay in the base together."""
    same = weld_groups(q)
    if same is None or not locked.any():
        return locked
    hit = np.zeros(len(q), bool)
    hit[same[locked]] = True
    return hit[same]


def _naming_locked_tips(faces: np.ndarray, late: np.ndarray, locked: np.ndarray) -> np.ndarray:
    """(m,) bool: the faces of ``late`` (m,) bool (of ``faces`` (m, 3)) that name a vertex locked in the
    base (``locked`` (n,) bool: a border with another primitive) that only late faces name: deferred,
    it would leave every level but the last without that vertex (a flap's tip on a border cracks)."""
    return late & (_named_only_by(faces, late, len(locked)) & locked)[faces].any(axis=1)


def _named_only_by(faces: np.ndarray, late: np.ndarray, n: int) -> np.ndarray:
    """(n,) bool: the vertices of a mesh of ``n`` vertices that faces of ``late`` (m,) bool name and no
    other face of ``faces`` (m, 3) does (the tips a face chunk brings)."""
    only_late = np.zeros(n, bool)
    only_late[np.compress(late, faces, axis=0).ravel()] = True  # faces[late], a copy in a quarter of the time
    only_late[np.compress(~late, faces, axis=0).ravel()] = False
    return only_late


def _core_and_copies(n: int, values, positions, faces, locked, twin, late, defer_slivers: bool) -> tuple:
    """The mesh the simplifier sees: ``(values, positions, faces, locked, twin, extra, points, weld)``.

    ``n`` vertices with ``values`` (n, D) int64 (grid positions first), ``positions`` (n, 3) float, ``faces``
    (m, 3) int64, ``locked`` (n,) bool or None, ``twin`` (m,) bool or None and ``late`` (m,) bool, the faces a face
    chunk sends (:func:`~pmwm_codec.progressive.simplify.deferred_and_twin_faces`).  Returned: the *core*, the
    vertices some face outside the final ``late`` names, renumbered (their values, positions, faces, locked and twin
    rows), ``extra`` (the :class:`PrimitiveWork` fields of the deferred faces: none when nothing is),
    ``points`` (:func:`weld_groups` of the core's grid positions: None when all are distinct) and ``weld`` (its seam
    copies, :func:`grid_weld`).  With ``defer_slivers``, the core's slivers (:func:`_sliver_faces`) are deferred
    too, in up to :data:`SLIVER_ROUNDS` rounds (deferring them opens new boundary ears beside them)."""
    out = None
    for attempt in range(SLIVER_ROUNDS + 1):
        if late.any() and locked is not None:  # a locked vertex stays in the base: its faces are not deferred
            late &= ~_naming_locked_tips(faces, late, locked)
        c_values, c_positions, c_faces, c_locked, c_twin, extra = values, positions, faces, locked, twin, {}
        if late.any():  # the core mesh, renumbered (no copies when nothing is deferred)
            core, tips, local = _core_vertices(n, faces, late)
            # (np.take and np.compress: the same rows as fancy and boolean indexing, in a quarter of the time)
            extra = dict(core=core, tips=tips, late=np.take(local, np.compress(late, faces, axis=0)),
                         late_values=values[tips])
            c_values, c_positions = np.take(values, core, axis=0), np.take(positions, core, axis=0)
            c_faces = np.take(local, np.compress(~late, faces, axis=0))
            c_locked = None if locked is None else locked[core]
            # the core's own doubled faces: ``late`` takes every face of a vertex triple or none (pillows and
            # specks are told by their vertices), so a triple keeps its face count in the core
            c_twin = twin[~late]
        # seam copies on the grid the stream lives on (copies a grid step apart or less are one point there)
        points = weld_groups(c_values[:, :3])
        weld = grid_weld(c_values[:, :3], c_faces, c_positions, points)
        out = c_values, c_positions, c_faces, c_locked, c_twin, extra, points, weld
        if not defer_slivers or points is None or attempt == SLIVER_ROUNDS:  # no two vertices on one point: none
            break
        slivers = _sliver_faces(points, c_faces, weld)
        if not slivers.any() or slivers.all():  # a core of slivers only: the base keeps them (as it keeps specks)
            break
        late = late.copy()
        late[np.flatnonzero(~late)[slivers]] = True
    return out


def _sliver_faces(points: np.ndarray, faces: np.ndarray, weld: np.ndarray | None) -> np.ndarray:
    """(m,) bool: the *slivers* of ``faces`` (m, 3) int64: faces with two corners on one grid point (``points``
    (n,) int64, :func:`weld_groups` of the grid positions) that no collapse is sure to remove: one of the two is a
    seam copy (``weld`` (n,) int64, :func:`~pmwm_codec.progressive.seams.grid_weld`'s, or None: no copies; copies
    move together), or the edge between them has no other face (a boundary ear; not when one of the two has no
    other face: a flap's tip, which the other collapses into), counting the slivers found as gone (taking one
    away can leave an ear beside it).  Kept to the base, a sliver is a face Draco's own order drops (its corners
    share a position), and the base falls back to Draco's sequential coder (dragon437k: 55 KB instead of 15 KB);
    a face chunk sends them instead (bitstream.md §8.6)."""
    m, n = len(faces), len(points)
    on_point = np.flatnonzero(two_alike_at(points, faces))
    out = np.zeros(m, bool)
    if not len(on_point):
        return out
    p = points[faces[on_point]]
    pair = np.stack([p[:, 0] == p[:, 1], p[:, 1] == p[:, 2], p[:, 2] == p[:, 0]], axis=1)
    copy = None if weld is None else np.bincount(weld, minlength=n)[weld] > 1
    # the faces of the vertices of those faces: every face on such an edge is among them
    mark = np.zeros(n, bool)
    mark[faces[on_point].ravel()] = True
    near = np.flatnonzero(any_corner(mark, faces))
    spot = np.full(m, -1, np.int64)
    spot[near] = np.arange(len(near))
    tri = faces[near]
    nxt = tri[:, [1, 2, 0]]  # each near face's edges (0 1), (1 2), (2 0)
    edge, counts = edge_ids(tri.reshape(-1), nxt.reshape(-1), n)
    edge = edge.reshape(-1, 3)  # each near face's edges, as indices into counts
    faces_at = np.bincount(tri.ravel(), minlength=n)  # a vertex's faces (complete for the marked ones)
    first = [pair[:, k] for k in range(3)]
    slot = spot[on_point]
    while True:
        # a flap's tip (a vertex of one face) is no obstacle: the other corner collapses into it, taking the face
        tip = faces_at == 1
        found = np.zeros(len(on_point), bool)
        for k, (i, j) in enumerate(((0, 1), (1, 2), (2, 0))):
            a, b = faces[on_point, i], faces[on_point, j]
            ear = first[k] & (counts[edge[slot, k]] == 1) & ~tip[a] & ~tip[b]
            found |= ear if copy is None else ear | (first[k] & (copy[a] | copy[b]))
        new = found & ~out[on_point]
        if not new.any():
            return out
        out[on_point[new]] = True
        np.subtract.at(counts, edge[slot[new]].ravel(), 1)  # the faces found are gone: their edges and corners
        np.subtract.at(faces_at, faces[on_point[new]].ravel(), 1)


def _core_vertices(n: int, faces: np.ndarray, late: np.ndarray) -> tuple:
    """``(core (n_core,), tips (t,), local (n,))`` int64: the vertices of a mesh of ``n`` vertices and
    ``faces`` (m, 3) that some face outside ``late`` (m,) bool names, or no face at all, ascending;
    the others (named by late faces only), ascending; ``local`` numbers the core ``0 … n_core - 1``
    and the tips after them, in input order."""
    only_late = _named_only_by(faces, late, n)
    core, tips = np.flatnonzero(~only_late), np.flatnonzero(only_late)
    local = np.empty(n, np.int64)
    local[core] = np.arange(len(core))
    local[tips] = len(core) + np.arange(len(tips))
    return core, tips, local


def _encode_bases(work, base_codec: str) -> tuple:
    """Stage 2: each primitive's base as the decoder will see it.

    Returns ``(work, notices)``.
    """
    out, notices = [], []
    for w in work:
        base, base_order = _encode_base(w, base_codec)
        _notice(notices, base.notice)
        out.append(dataclasses.replace(w, base=base, base_order=base_order))
    return out, notices


def _notice(notices: list, note) -> None:
    if note and note not in notices:
        notices.append(note)


def _encode_base(w: PrimitiveWork, codec: str) -> tuple:
    """``(EncodedBase, base_order (n0,) int64)`` of one primitive, attributes included."""
    log, q = w.log, w.values[:, :3]
    base_ids = log.base_vertices
    local = np.full(len(q), -1, dtype=np.int64)
    local[base_ids] = np.arange(len(base_ids))
    offsets = np.cumsum([3] + [len(spec["origin"]) for spec in w.attribute_grids])
    attributes = [(spec, w.values[base_ids, offsets[j] : offsets[j + 1]]) for j, spec in enumerate(w.attribute_grids)]
    try:
        base = encode_base(q[base_ids], local[log.base_corners], w.grid, codec=codec, attributes=attributes)
    except ValueError as exc:
        raise MeshError(f"cannot store the base mesh: {exc}") from None
    return base, base_ids[np.asarray(base.vertex_map, dtype=np.int64)]


def _plan_chunks(work, min_chunk_splits) -> tuple:
    """Stage 3: chunks per primitive, then one stream order over all of them.

    Returns ``(work, order, slots, carriers)`` (see
    :func:`~pmwm_codec.stream.chunking.stream_order` and
    :func:`~pmwm_codec.stream.chunking.carrier_slots`).
    """
    out = []
    for w in work:
        sizes = [len(batch.u) for batch in reversed(w.log.batches)]
        if min_chunk_splits is None:  # the default: small first chunks, doubling
            groups = group_batches(sizes, default_min_chunk_splits(sum(sizes)), FIRST_CHUNK_SPLITS)
        else:
            groups = group_batches(sizes, min_chunk_splits)
        if len(w.late):  # the face chunk: no batch
            groups.append(range(len(sizes), len(sizes)))
        out.append(dataclasses.replace(w, sizes=sizes, groups=groups))
    sizes, groups = [w.sizes for w in out], [w.groups for w in out]
    order = stream_order(sizes, groups)
    slots, carriers = carrier_slots(order, sizes, groups)
    return out, order, slots, carriers


def _plan_watermark(work, watermark, key, carriers: int, slots, mode, bits, step_units, embed_from=0) -> tuple:
    """Stage 4: watermark plan over the carriers of the document from ``embed_from`` on.

    Returns ``(params, work)``: the document's :class:`WatermarkParams` and the work with
    each primitive's ``params`` (its own ``scale``: mean base edge / step) and embedder.
    Raises CapacityError when the splits from the start on cannot hold the watermark.
    """
    start = wm.start_index(embed_from, carriers)
    if start:
        need = wm.splits_needed(watermark, mode, bits)
        if carriers - start < need:
            fit = wm.largest_fitting_size(watermark, carriers - start, bits=bits, mode=mode)
            hint = "; " + wm.fit_hint(" from there") if fit else ""
            raise wm.CapacityError(
                f"embedding from vertex split {start:,} leaves {carriers - start:,} of {carriers:,} splits; "
                f"{{watermark}} needs {need:,} in {mode} mode: start earlier{hint}", fit, int(watermark.shape[0])
            )
    void = _twin_slots(work, key, slots)  # seam twins carry nothing (spec/watermark.md, "Repeated points")
    readable = carriers - start - int(np.count_nonzero(void >= start))
    if readable < MIN_CARRIERS:
        where = f"from vertex split {start:,} on " if start else ""
        raise wm.CapacityError(
            f"the mesh has {max(readable, 0):,} vertex splits {where}that can carry a watermark code; a mark needs "
            f"{MIN_CARRIERS} to verify (with fewer, pmw verify can only call it inconclusive)"
            + ("; start earlier" if start else "; encode without --watermark (--owner-id alone may fit)"))
    params, codes = wm.plan(watermark, key, readable, mode=mode, bits=bits, nbar=1.0, step_units=step_units)
    params.embed_from = start
    step = wm.DEFAULT_STEP_UNITS[mode] if step_units is None else float(step_units)
    out = []
    for w, primitive_slots in zip(work, slots):
        nbar = mean_edge_length(w.base.positions_int, w.base.faces)
        own = dataclasses.replace(params, scale=nbar / step)
        embedder = wm.Embedder(own, key, codes, nbar, slots=primitive_slots, void=void)
        out.append(dataclasses.replace(w, params=own, embedder=embedder))
    return params, out


def _twin_slots(work, key, slots) -> np.ndarray:
    """(v,) int64 sorted stream slots of the seam twins: splits whose new vertex has the
    position of an earlier split of its batch (the watermark reader skips them).

    Replays the decoder's vertex numbering from each primitive's log (splits of a batch in
    the order of their kept vertex's decoded id) without building the records.
    """
    out = []
    for w, primitive_slots in zip(work, slots):
        vid = np.full(w.log.vertex_count, -1, dtype=np.int64)
        vid[w.base_order] = np.arange(len(w.base_order))
        n = len(w.base_order)
        for j, cb in enumerate(reversed(w.log.batches)):
            order = np.argsort(vid[cb.v], kind="stable")
            u = cb.u[order]
            vid[u] = n + np.arange(len(u))
            n += len(u)
            twin = twin_rows(w.values[u, :3]) != np.arange(len(u))
            if twin.any():
                g, offset = primitive_slots[j]
                out.append(wm.carrier_slots(key, g, offset, len(u))[twin])
    return np.sort(np.concatenate(out)) if out else np.zeros(0, np.int64)


def _build_records(work, say, payload_version: int = DEFAULT_PAYLOAD_VERSION) -> list:
    """Stage 5: split records (the embedders, if any, move the new vertices); with payload version 2
    and no embedder, the payloads too (the builder's replay codes them: ``pm.payloads``)."""
    out = []
    say("records", 0.0)
    for p, w in enumerate(work):
        if payload_version == 2:
            w = dataclasses.replace(w, attribute_grids=[_with_prediction(spec) for spec in w.attribute_grids])
        pm = build_progressive(
            w.log, w.values, w.grid, base_vertex_order=w.base_order,
            base_faces_decoded=w.base.faces, embed=w.embedder, late_faces=w.late, late_values=w.late_values,
            chunks=w.groups if payload_version == 2 else None, plane=plane_columns(w.attribute_grids),
        )
        out.append(dataclasses.replace(w, pm=pm))
        say("records", (p + 1) / len(work))
    return out


def _with_prediction(spec: dict) -> dict:
    """An extension ``attributes`` entry of payload version 2 with its prediction: on the ring's plane (spec
    bitstream.md §8.4.3) for an attribute of float values (texture coordinates, colours, normals), which vary
    smoothly over the surface; the ring mean for an integer attribute (joints, feature ids)."""
    return spec if "componentType" in spec else {**spec, "prediction": PLANE_PREDICTION}


def _primitives(doc, kept_bin, work, order, params, key, payload_version: int = DEFAULT_PAYLOAD_VERSION,
                owner_frame: dict | None = None) -> tuple:
    """Stage 6: payloads, index entries, extension objects.  Returns ``(prims, fileId)``.  ``owner_frame``: the
    ``ownerFrame`` object of a file with the owner layer (:func:`_stated_owner_frame`), on its first primitive."""
    prims = []
    for w in work:
        chunks = [[w.pm.batches[j] for j in grp] if len(grp) else FaceChunk(w.pm.late_faces, w.pm.late_values)
                  for grp in w.groups]
        if payload_version == 2:
            payloads = (w.pm.payloads if w.pm.payloads is not None
                        else pack_chunks(w.pm.new_state(), chunks, plane_columns(w.attribute_grids)))
        else:
            payloads = [pack_batches(batches) for batches in chunks]
        extension = {
            "grid": w.grid.get_config(),
            "vertexCount": int(w.pm.vertex_count),
            "faceCount": int(w.pm.face_count),
            "payload": {"codec": PAYLOAD_CODEC, "version": payload_version},
            "fileId": "",  # set below, once the content it digests is known
        }
        if w.attribute_grids:
            extension["attributes"] = w.attribute_grids
        if len(w.late):
            extension["firstFaceChunk"] = len(w.groups) - 1
        if w.base.welded_count is not None:  # readers weld the stored base's copies (spec README, "Welded base")
            extension["baseVertexCount"] = int(w.base.welded_count)
        if params is not None:
            extension["watermark"] = w.params.get_config()
        if owner_frame is not None and not prims:
            extension["ownerFrame"] = owner_frame
        meta = chunk_meta(w.pm, w.groups, w.grid.step)
        job = w.job
        prims.append(ProgressivePrimitive(job.mesh_index, job.primitive_index, _named(w.base, job.names), payloads,
                                          meta, extension))
    file_id = content_file_id(doc, kept_bin, prims, order, key)
    for prim in prims:
        prim.extension["fileId"] = file_id
    return prims, file_id


def _named(base: EncodedBase, names: dict | None) -> EncodedBase:
    """``base`` whose accessors carry ``names`` (``{semantic or "indices": name}``, the input's)."""
    if not names:
        return base
    accessors = [dict(a) for a in base.accessors]
    slots = {**base.primitive.get("attributes", {}), "indices": base.primitive.get("indices")}
    for what, name in names.items():
        if slots.get(what) is not None:
            accessors[slots[what]]["name"] = name
    return dataclasses.replace(base, accessors=accessors)


def _publish(dst, parts, key: WatermarkKey | None, key_slot: KeySlot | None) -> int:
    """Stage 7: write the key file (when new) and the ``.pmw`` so that a failure at any
    moment leaves the old pair or the new pair; returns the ``.pmw``'s byte count.

    Both files are staged (written, fsynced, nameless where the platform allows) while the
    directories are locked (a concurrent encode to the same names waits, then finds the
    key it expected changed and refuses); then the key is renamed into place and the
    ``.pmw`` right after it, with SIGINT/SIGTERM held back.  An error (disk full, file
    size limit, out of memory) before the second rename discards both; SIGKILL between
    the two renames can leave a new key beside the old ``.pmw``, never a marked file
    without its key.
    """
    if key_slot is None or key is None:
        return write_parts(dst, parts)
    to_path = isinstance(dst, (str, os.PathLike))
    with directory_lock([key_slot.path] + ([dst] if to_path else [])), signals_deferred():
        text = key_slot.pending(key)
        staged_key = staged = None
        created = False
        try:
            staged_key = None if text is None else stage(key_slot.path, [text], KEY_FILE_MODE)
            staged = stage(dst, parts) if to_path else None
            fault_point("staged")
            if staged_key is not None:
                publish(staged_key)
                created = True
            fault_point("key-published")
            if to_path:
                publish(staged)
            else:  # a stream: its bytes follow the key
                write_parts(dst, parts)
            fault_point("published")
        except BaseException:
            discard(staged)
            if created:
                os.unlink(key_slot.path)  # ours: created under the lock a moment ago
            raise
        finally:
            discard(staged_key)
    return sum(len(p) for p in parts)


def content_file_id(doc: dict, kept_bin: bytes, prims, order, key: WatermarkKey | None) -> str:
    """16 hex digits: SHA-256 of everything the file will hold, and of the key's fingerprint.

    Covers the carried document and data, and per progressive primitive its place, base
    bytes, extension fields (``fileId`` left out), raw chunk payloads and index fields,
    and the stream order.  The same input, key and options give the same id; the secret
    is not involved beyond the public fingerprint.
    """
    h = hashlib.sha256(b"pmwm/fileId/v1\0")

    def add(data: bytes) -> None:
        h.update(len(data).to_bytes(8, "little"))
        h.update(data)

    def add_json(obj) -> None:
        add(json.dumps(obj, sort_keys=True, separators=(",", ":"), default=_json_default).encode("utf-8"))

    add(b"" if key is None else key.fingerprint().encode("ascii"))
    add_json(doc)
    add(bytes(kept_bin))
    for prim in prims:
        add_json([prim.mesh, prim.primitive, {k: v for k, v in prim.extension.items() if k != "fileId"}])
        add_json([prim.base.buffer_views, prim.base.accessors, prim.base.primitive, prim.chunk_meta])
        add(bytes(prim.base.data))
        for payload in prim.chunks:
            add(bytes(memoryview(payload).cast("B")))
    add_json([list(pk) for pk in order])
    return h.hexdigest()[:16]


def _json_default(obj):
    if isinstance(obj, (np.generic, np.ndarray)):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} is not JSON-serialisable")


def _report(work, params, measure, say, decoded=None) -> EncodeReport:
    """Sizes, distortion and watermark counts (stream fields are set by the caller).

    ``measure``: see :func:`encode_document`; runs before anything is written.  ``decoded``:
    :func:`_decoded_input_positions` of each primitive, when already computed.
    """
    meshes = [w.job.mesh for w in work]
    combined = combine_meshes(meshes)
    method = measure_method(measure)
    distortion = {"rms": None, "psnr_db": None, "hausdorff": None, "bbox_diagonal": combined.bbox_diagonal(),
                  "measure": "none"}
    if method != "none":
        say("measure", 0.0)
        decoded = [_decoded_input_positions(w) for w in work] if decoded is None else decoded
        distortion = full_distortion(combined, combine_meshes([Mesh(d, m.faces) for d, m in zip(decoded, meshes)]),
                                     method)
        say("measure", 1.0)
    wm_report = None
    if params is not None:
        embedders = [w.embedder for w in work]
        wm_report = {
            "width": params.size, "height": params.size, "mode": params.mode, "bits": params.bits,
            "codes": params.codes, "embedded": int(sum(e.embedded for e in embedders)), "carriers": params.carriers,
            "failed": int(sum(e.failed for e in embedders)),
        }
    return EncodeReport(
        vertices=sum(m.vertex_count for m in meshes), faces=sum(m.face_count for m in meshes),
        base_vertices=sum(len(w.pm.base_positions) for w in work),
        base_faces=sum(len(w.pm.base_faces) for w in work),
        vsplits=0, chunks=0, bytes=0, seconds=0.0, distortion=distortion, watermark=wm_report,
        batches=sum(len(w.pm.batches) for w in work),
    )


def _decoded_input_positions(w: PrimitiveWork) -> np.ndarray:
    """(n, 3) float64: the full decode of one primitive's positions in the input's vertex order (the
    vertices the face chunk brings are on the grid, unmoved)."""
    core = decoded_positions(w.pm, w.grid)
    if w.core is None:
        return core
    out = np.empty((w.job.mesh.vertex_count, 3))
    out[w.core] = core
    out[w.tips] = w.grid.dequantize(w.late_values[:, :3])
    return out


def default_key_path(dst) -> str | None:
    """Where ``pmw encode`` writes the key when none is named: ``OUT.pmw.key.json``."""
    if isinstance(dst, (str, os.PathLike)):
        return os.fspath(dst) + KEY_SUFFIX
    return None
