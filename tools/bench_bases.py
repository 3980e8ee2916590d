"""Base-mesh sizes and batch yields for every corpus mesh: ``python tools/bench_bases.py [--write BENCHMARKS.md]``.

For each mesh of ../shared/corpus: the base size with the default target (1% of the vertices,
at least 64) and when simplifying as far as the legality rules allow (target 0), the number of
batches, and the fraction of the current vertices each batch removes (median over batches, and
the first batch).  Closed manifold meshes must reach max(2% of the vertices, 200).
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

from pmwm_codec.mesh import read_mesh
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.progressive.simplify import simplify
from pmwm_codec.progressive.topology import edge_table
from pmwm_codec.stream.chunking import default_base_target

from bench import publish

SECTION = "Base meshes"
CORPUS = os.path.join(os.path.dirname(HERE), "..", "shared", "corpus")


def closed_manifold(mesh) -> bool:
    et = edge_table(mesh.faces, mesh.vertex_count)
    return bool(np.all(et.count == 2))


def row(name):
    mesh = read_mesh(os.path.join(CORPUS, name))
    q = Grid.fit(mesh.positions, 16).quantize(mesh.positions)
    n = mesh.vertex_count
    out = {"mesh": name, "vertices": n, "closed": closed_manifold(mesh)}
    for label, target in (("default", default_base_target(n)), ("min", 0)):
        log = simplify(q, mesh.faces, target_vertices=target)
        sizes, cur = [], n
        for b in log.batches:
            sizes.append(len(b.u) / cur)
            cur -= len(b.u)
        out[label] = {"base": len(log.base_vertices), "batches": len(log.batches),
                      "yield_median": float(np.median(sizes)) if sizes else 0.0,
                      "yield_first": sizes[0] if sizes else 0.0}
    return out


def render(rows, command):
    lines = [f"Command: `{command}` (grid 16 bits).", "",
             "| mesh | vertices | closed manifold | base (default target) | batches | base (as far as legal) | batches | "
             "limit max(2%, 200) | yield per batch: median (first) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        d, m = r["default"], r["min"]
        limit = max(0.02 * r["vertices"], 200)
        ok = "met" if m["base"] <= limit else "not met"
        lines.append(f"| {r['mesh']} | {r['vertices']:,} | {'yes' if r['closed'] else 'no'} | {d['base']:,} | "
                     f"{d['batches']} | {m['base']:,} | {m['batches']} | {int(limit):,} ({ok if r['closed'] else 'n/a'}) | "
                     f"{100 * d['yield_median']:.1f}% ({100 * d['yield_first']:.1f}%) |")
    lines.append("")
    lines.append("A batch removes only pairwise non-adjacent vertices whose kept vertices are distinct and not "
                 "next to another removed vertex (see pmwm_codec/progressive/simplify.py), which caps a batch "
                 "below 1/3 of the vertices on a regular triangulation; the selection reaches the yields above. "
                 "Open, multi-part and non-manifold meshes keep boundary corners, non-manifold vertices and the "
                 "ends of tiny parts in the base.")
    return "\n".join(lines) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--write", metavar="MARKDOWN")
    args = ap.parse_args(argv)
    names = sorted(f for f in os.listdir(CORPUS) if f.endswith(".obj"))
    rows = [row(name) for name in names]
    publish(render(rows, "python tools/bench_bases.py --write BENCHMARKS.md"), args.write, SECTION,
            lambda s: print(s, file=sys.stderr))


if __name__ == "__main__":
    main()
