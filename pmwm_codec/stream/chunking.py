"""Chunking policy of the encoder: base size, batches -> chunks, stream order, chunk index fields.

A primitive's split batches (coarse to fine) are grouped into *chunks* of consecutive
batches (:func:`group_batches`), so that a chunk carries enough splits to be worth a
zstd frame and an index entry.  The chunks of every primitive of a document are then
interleaved into one stream order (:func:`stream_order`) that refines all primitives
at the same pace.  Every split of the stream is a watermark carrier; :func:`carrier_slots`
numbers them in stream order.  None of this is part of the format: a decoder reads
whatever order and grouping the index declares.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "default_base_target",
    "FIRST_CHUNK_SPLITS",
    "default_min_chunk_splits",
    "group_batches",
    "stream_order",
    "carrier_slots",
    "chunk_meta",
]


def default_base_target(n: int) -> int:
    """Default base size: 1% of the vertices, at least 64 (and never more than n)."""
    return min(n, max(n // 100, 64))


#: Smallest first chunk of the default chunking; each next chunk may be twice the one before
#: until :func:`default_min_chunk_splits` (see :func:`group_batches`).
FIRST_CHUNK_SPLITS = 32


def default_min_chunk_splits(total: int) -> int:
    """Default smallest chunk: 1% of the primitive's ``total`` splits, at least 32."""
    return max(32, total // 100)


def group_batches(sizes, min_splits: int, first: int | None = None) -> list:
    """Split batch indices into chunks of consecutive batches holding >= ``min_splits`` splits.

    ``sizes`` : (b,) split counts, coarse to fine.  With ``first``, chunk j needs only
    ``min(min_splits, first * 2**j)`` splits: the stream's first refinements come in small
    steps, so that a prefix a little longer than the base already holds some of them (the
    default: :data:`FIRST_CHUNK_SPLITS`; each chunk costs ~25 bytes of index), then chunks
    double up to ``min_splits``.  Returns a list of ``range``; a last chunk smaller than half
    of what it needs joins the one before it.
    """
    out, start, acc = [], 0, 0
    need = min_splits if first is None else min(min_splits, first)
    for j, k in enumerate(sizes):
        acc += int(k)
        if acc >= need:
            out.append(range(start, j + 1))
            start, acc = j + 1, 0
            need = min(min_splits, 2 * need)
    if start < len(sizes):
        if out and acc < need // 2:
            last = out.pop()
            out.append(range(last.start, len(sizes)))
        else:
            out.append(range(start, len(sizes)))
    return out


def stream_order(sizes, groups) -> list:
    """Every (primitive, chunk) in stream order.

    ``sizes[p]`` : split counts of primitive p's batches; ``groups[p]`` : its chunks (from
    :func:`group_batches`).  Chunks are sorted by the fraction of their primitive's splits
    done once they are applied (ties: primitive, then chunk index), so every primitive
    refines at the same pace; face chunks (an empty group: bitstream.md §8.6) come after every
    chunk that splits.  Returns a list of ``(p, k)``.
    """
    keys = []
    for p, (batch_sizes, chunks) in enumerate(zip(sizes, groups)):
        total = max(1, sum(batch_sizes))
        done = 0
        for k, grp in enumerate(chunks):
            done += sum(batch_sizes[j] for j in grp)
            keys.append((done / total if len(grp) else 2.0, p, k))
    return [(p, k) for _, p, k in sorted(keys)]


def carrier_slots(order, sizes, groups) -> tuple[list, int]:
    """Where each batch's splits sit among the stream's watermark carriers.

    Returns ``(slots, carriers)``: ``slots[p]`` maps primitive p's batch index j to
    ``(stream batch index, offset of its first split among all carriers)``, both counted
    in stream order over every primitive; ``carriers`` is the total number of splits.
    """
    slots, stream_batch, offset = [dict() for _ in sizes], 0, 0
    for p, k in order:
        for j in groups[p][k]:
            slots[p][j] = (stream_batch, offset)
            stream_batch += 1
            offset += sizes[p][j]
    return slots, offset


def chunk_meta(pm, groups, step: float) -> list:
    """Index fields of each chunk of one progressive primitive.

    pm : :class:`~pmwm_codec.progressive.build.ProgressiveMesh`; groups : its chunks (list
    of ``range`` over ``pm.batches``); step : grid step (model units per grid unit).
    Returns one dict per chunk: ``splits``, ``vertexCount`` and ``faceCount`` once it is
    applied, ``geometricError`` (model units) and ``batches``.  An empty group is the face chunk
    of ``pm.late_faces``.
    """
    errors = pm.batch_errors  # (b,) float64: error of the level *before* batch j, grid units
    # The error of the mesh after a chunk is the max over the batches still missing: the
    # per-batch errors are not monotone, and any collapse not yet undone may be the worst.
    remaining = np.maximum.accumulate(errors[::-1])[::-1] if len(errors) else errors
    meta = []
    nv, nf = len(pm.base_positions), len(pm.base_faces)
    for grp in groups:
        chunk = [pm.batches[j] for j in grp]
        added = sum(b.size for b in chunk) if chunk else pm.vertex_count - nv
        nv += added
        nf += sum(b.new_face_count() for b in chunk) if chunk else len(pm.late_faces)
        err = float(remaining[grp.stop]) * step if grp.stop < len(pm.batches) else 0.0
        meta.append({"splits": int(added), "vertexCount": int(nv), "faceCount": int(nf),
                     "geometricError": err, "batches": len(chunk)})
    return meta
