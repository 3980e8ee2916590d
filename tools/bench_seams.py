"""Seam pairs on a textured asset: base size, file size, encode time, and the twins' residuals.

    python -m tools.bench_seams ../shared/corpus/spot.glb [--runs 5]

Encodes the asset with default options (no watermark) ``--runs`` times (median seconds),
then decodes it batch by batch and counts the *twin* splits (a new vertex on the position
of an earlier new vertex of its batch: the second half of a seam pair).  For the v2 coder:
their position residuals are what a "copy of the twin" symbol would save; the estimate is
``sum over the 3 position columns of 1 + 2 * floor(log2(|r| + 1))`` bits (an Elias-gamma
length of the zigzag value), for twins and for all splits.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from pmwm_codec.progressive.seams import twin_rows
from pmwm_codec.stream import StreamDecoder
from pmwm_codec.stream import replay as replay_module
from pmwm_codec.stream.asset import encode_asset


def gamma_bits(residual: np.ndarray) -> np.ndarray:
    """(k,) estimated bits of the position columns of residuals (k, D) int64."""
    r = np.abs(np.asarray(residual, np.int64)[:, :3])
    zig = 2 * r  # zigzag magnitude, sign bit folded in
    return (1 + 2 * np.floor(np.log2(zig + 1))).sum(axis=1)


def twin_stats(data: bytes) -> dict:
    """Decode ``data`` batch by batch; count twins and their position residual bits."""
    twins, splits, twin_bits, all_bits = 0, 0, 0.0, 0.0
    original = replay_module.apply_batch

    def spy(state, batch):
        nonlocal twins, splits, twin_bits, all_bits
        topo = original(state, batch)
        twin = twin_rows(state.positions[topo.u, :3]) != np.arange(len(topo.u))
        bits = gamma_bits(batch.residual)
        twins += int(twin.sum())
        splits += len(twin)
        twin_bits += float(bits[twin].sum())
        all_bits += float(bits.sum())
        return topo

    replay_module.apply_batch = spy
    try:
        dec = StreamDecoder()
        dec.feed(data)
        dec.close()
    finally:
        replay_module.apply_batch = original
    return {"splits": splits, "twin_splits": twins,
            "twin_position_bits_per_twin": round(twin_bits / max(twins, 1), 2),
            "position_bits_per_split": round(all_bits / max(splits, 1), 2),
            "twin_position_bits_total": int(twin_bits)}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("asset")
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "asset.pmw"
        seconds = []
        for _ in range(args.runs):
            t0 = time.perf_counter()
            report = encode_asset(args.asset, out)
            seconds.append(time.perf_counter() - t0)
        data = out.read_bytes()
    print(json.dumps({
        "vertices": report.vertices, "base_vertices": report.base_vertices,
        "base_share": round(report.base_vertices / report.vertices, 4), "bytes": len(data),
        "batches": report.batches, "encode_seconds_median": round(statistics.median(seconds), 3),
        "encode_seconds_all": [round(s, 3) for s in seconds], **twin_stats(data),
    }, indent=1))


if __name__ == "__main__":
    main()
