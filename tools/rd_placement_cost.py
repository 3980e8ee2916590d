"""Would splits that also move the kept vertex pay?  An estimate of their bits against their gain in error.

Our splits never move the vertex ``v`` a collapse kept (half-edge collapses), and ``tools/bench_rd.py``'s
placement table shows that this, not the choice of collapses, is why a scan's levels (snowden's) are farther
from the original than fast-simplification's at the same vertex count.  A format whose splits also move ``v``
would send, per split, where ``v`` goes.  For our level at each Draco LOD's vertex count (10% and 30%) this
prints:

* the displacement of every vertex that absorbed others from its position to the minimum of its cluster's
  summed quadrics (``bench_rd.placed_level``: where a full-edge collapse puts it), in grid steps, split into
  the level's vertex normal and the tangent plane;
* the empirical entropy of the rounded components (a static model of the whole set: bits a coder would
  need per moved vertex, whole displacement and normal component alone), spread over the splits that lead
  to the level, beside what a split costs in the stream today;
* the level's error (symmetric RMS surface distance) over the LOD's, with ``v`` where it is (the stream),
  at the quadric minimum, and moved along the normal only.

    python tools/rd_placement_cost.py MESH.obj [--bits 16] [--samples 20000]

Equal bytes then follow: the moves' bits are that many more bytes per split, fewer splits in a prefix, and
(the error of a scan's level falling about as 1 / vertices) that much more error.
"""

from __future__ import annotations

import argparse
import os
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))
sys.path.insert(0, HERE)

import pmwm_codec  # noqa: E402
from pmwm_codec.distortion import rms_surface_distance  # noqa: E402
from pmwm_codec.progressive.grid import Grid  # noqa: E402

import bench_rd as R  # noqa: E402


def entropy(values: np.ndarray) -> float:
    """Bits per value of the empirical distribution of ``values`` (n,) (any hashable dtype)."""
    _, counts = np.unique(values, return_counts=True)
    p = counts / counts.sum()
    return float(-(p * np.log2(p)).sum())


def vertex_normals(points: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(n, 3) float64 unit area-weighted normals of ``points`` (n, 3) over ``faces`` (m, 3) (zero where none)."""
    tri = points[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    vn = np.stack([np.bincount(faces.ravel(), weights=np.repeat(fn[:, q], 3), minlength=len(points)) for q in range(3)], 1)
    return vn / np.maximum(np.linalg.norm(vn, axis=1), 1e-300)[:, None]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mesh")
    ap.add_argument("--bits", type=int, default=16)
    ap.add_argument("--samples", type=int, default=20000)
    args = ap.parse_args(argv)
    mesh = pmwm_codec.read_mesh(args.mesh)
    _, levels, clog = R.our_stream(mesh, args.bits)
    step = Grid.fit(mesh.positions, args.bits).step
    diag = float(np.linalg.norm(np.ptp(mesh.positions, axis=0)))
    base_bytes, base_vertices = levels[0][0], levels[0][1]
    print(f"{os.path.basename(args.mesh)}, grid {args.bits} (step {step:.3g}); base {base_vertices:,} V in {base_bytes:,} B")
    for lod in R.lod_chain(mesh, args.bits)[1:]:
        k = lod["raw"].vertex_count
        core, faces, rep = R.level_clusters(mesh, clog, k, args.bits)
        points = np.asarray(core.positions, np.float64)
        used = np.unique(faces)
        placed = points.copy()
        placed[used] = R.placed_level(core, faces, rep).positions  # compact() keeps the used vertices in order
        movers = used[np.bincount(rep, minlength=len(points))[used] > 1]
        d = (placed[movers] - points[movers]) / step
        n = vertex_normals(points, faces)[movers]
        dn = np.einsum("ij,ij->i", d, n)
        normal_only = points.copy()
        normal_only[movers] += (dn * step)[:, None] * n
        splits = k - base_vertices
        reached = [b for b, nv, _ in levels if nv <= k][-1]
        whole, along = sum(entropy(np.round(d[:, j])) for j in range(3)), entropy(np.round(dn))
        per_split = 8 * (reached - base_bytes) / max(splits, 1)

        def err(points_):
            return rms_surface_distance(mesh, R.compact(points_, faces), args.samples) / diag

        lod_error = rms_surface_distance(mesh, lod["raw"], args.samples) / diag
        print(f"  LOD {lod['fraction']:.0%} ({k:,} V, Draco {lod['bytes']:,} B): our prefix to {k:,} V "
              f"~{reached:,} B, {per_split:.1f} bits per split after the base")
        print(f"    {len(movers):,} moved vertices: |d| median {np.median(np.linalg.norm(d, axis=1)):.1f} steps, "
              f"normal component median {np.median(np.abs(dn)):.1f}")
        print(f"    bits per split for the moves: whole {whole * len(movers) / max(splits, 1):.1f}, "
              f"normal only {along * len(movers) / max(splits, 1):.1f}")
        print(f"    error / the LOD's at {k:,} V: v kept {err(points) / lod_error:.2f}x, at the quadric minimum "
              f"{err(placed) / lod_error:.2f}x, moved along the normal only {err(normal_only) / lod_error:.2f}x")


if __name__ == "__main__":
    main()
