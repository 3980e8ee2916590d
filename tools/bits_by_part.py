"""Where a payload-version-2 stream's bits go: the cost of every coded decision, by part of the model.

Encodes a mesh with the library's default payload (no watermark, no report) with numba off (the payload
coder's kernels then run as their plain-Python twins, the same bytes) and adds up ``-log2 p`` of every
adaptive decision the range coder takes (``rangecoder._ebit``) and one bit for every direct one
(``rangecoder._edirect``: the raw low mantissa bits of large integers), grouped by the probability
block the decision uses (``format/records_v2.py``: the selection mask, the arc's escape / wing / symbol
bits, its length and rank, the three geometry roles (two tangents and the normal height of a new vertex in
its ring's frame), attributes).  The sum is the coded payload within the range coder's few bytes of flush
per chunk; the file adds the GLB, its JSON and the Draco base.

    python tools/bits_by_part.py MESH [MESH ...] [--bits 14]

Prints bits per input vertex for each part.  Slow on big meshes (plain Python): meant for 2k-50k vertices.
"""

from __future__ import annotations

import argparse
import collections
import io
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import pmwm_codec  # noqa: E402
from pmwm_codec.format import rangecoder as rc  # noqa: E402
from pmwm_codec.format import records_v2 as R  # noqa: E402
from pmwm_codec.mesh import read_mesh  # noqa: E402
from pmwm_codec.progressive import topology  # noqa: E402


def part(i: int) -> str:
    """The part of the model probability ``i`` belongs to: ``"group:detail"``."""
    if i < R.P_ESCAPE:
        return "mask:selection"
    if i < R.P_WING:
        return "arc:escape"
    if i < R.P_SYMBOL:
        return "arc:wing"
    if i < R.P_INT:
        return "arc:symbol"
    block, off = divmod(i - R.P_INT, rc.INT_BLOCK)
    piece = "bucket" if off < rc.INT_MANTISSA else ("mantissa" if off < rc.INT_SIGN else "sign")
    if block == R.B_BATCHES:
        return f"batches:{piece}"
    if block < R.B_RANK:
        return f"arc-length:{piece}"
    if block < R.B_GEOMETRY:
        return f"arc-rank:{piece}"
    if block < R.B_ATTRIBUTE:
        role = (block - R.B_GEOMETRY) % 3
        return f"{('tangent-1', 'tangent-2', 'normal')[role]}:{piece}"
    return f"attribute:{piece}"


def costs(mesh, bits: int) -> tuple:
    """``(Counter part -> bits, file bytes)`` of one encode of ``mesh`` at ``bits`` grid bits."""
    cost = collections.Counter()

    def counted_bit(low, rng, es, out, probs, i, bit):
        p = probs[i] / rc.PROB_ONE
        cost[part(i)] += -math.log2(p if bit == 0 else 1.0 - p)
        return ebit(low, rng, es, out, probs, i, bit)

    def counted_direct(low, rng, es, out, bit):
        cost["direct:raw mantissa"] += 1.0
        return edirect(low, rng, es, out, bit)

    use = topology.USE_NUMBA
    # the plain-Python twins look the coder's helpers up in its module: where numba is loaded already (a big
    # mesh read through a kernel), its helpers' module names hold their dispatchers, put back after the count
    swapped = [(g, name, g[name]) for g, name, fn, _ in topology._HELPERS if g.get(name) is not fn]
    topology.USE_NUMBA = False
    for g, name, fn, _ in topology._HELPERS:
        g[name] = fn
    ebit, edirect = rc._ebit, rc._edirect
    rc._ebit, rc._edirect = counted_bit, counted_direct
    try:
        buf = io.BytesIO()
        pmwm_codec.encode(mesh, buf, measure=False, grid_bits=bits)
    finally:
        rc._ebit, rc._edirect = ebit, edirect
        for g, name, held in swapped:
            g[name] = held
        topology.USE_NUMBA = use
    return cost, len(buf.getvalue())


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("meshes", nargs="+")
    ap.add_argument("--bits", type=int, default=14, help="position grid bits (default 14)")
    args = ap.parse_args(argv)
    for path in args.meshes:
        mesh = read_mesh(path)
        cost, size = costs(mesh, args.bits)
        n = mesh.vertex_count
        groups = collections.Counter()
        for name, value in cost.items():
            groups[name.split(":")[0]] += value
        print(f"{os.path.basename(path)}: {n:,} vertices, grid {args.bits}: file {size:,} B "
              f"({8 * size / n:.1f} bits a vertex), coded decisions {sum(cost.values()) / 8:,.0f} B")
        for name, value in sorted(groups.items(), key=lambda x: -x[1]):
            detail = ", ".join(f"{k.split(':')[1]} {v / n:.2f}" for k, v in sorted(cost.items())
                               if k.split(":")[0] == name)
            print(f"  {name:12s} {value / n:6.2f} bits a vertex  ({detail})")


if __name__ == "__main__":
    main()
