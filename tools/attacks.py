"""Attack suite: what happens to the watermark of a mesh that left the stream.

The attacks follow the mesh-watermarking benchmark (meshben / MEPP; the numpy
ports and grids are those of ``research-notes/watermark-robustness.md`` §1),
plus glTF transport:

* A0 ``reorder``   random vertex permutation, face permutation, per-face corner rotation
* A1 ``similarity`` random rotation (Rodrigues) x uniform scale x translation
* T1 ``float32``   float64 -> float32 -> float64
* A2 ``noise``     uniform noise, amplitude A = 0.05/0.10/0.30/0.50 % of the mean
  vertex-to-centroid distance, per coordinate (MEPP ``NoiseAdditionUniform``)
* A4 ``quantize``  per-axis bbox grid of R = 11..7 bits, MEPP's round-half-down
* A3 ``smooth``    Laplacian (Jacobi, uniform weights), lambda 0.03, N = 5/10/30/50
* A7 ``crop``      drop 10/30/50 % of the vertices by a random half-space
* A6 ``simplify``  quadric edge collapse (``fast-simplification``, optional) to 10..70 % fewer faces
* T4 ``draco``     a real DracoPy encode/decode at 14 and 11 quantization bits
* A5 ``subdivide`` one step of midpoint (flat) or Loop subdivision: every triangle into four

Every attack takes the *full decode* of the marked file (the reference) and
returns a new ``(positions, faces)``; :func:`pmwm_codec.verify.verify_mesh`
then finds the vertex correspondence itself (exact topology match, or
registration when the vertex count changed) and reports verdict, NC, PSNR, BER.

Run from the repository root::

    python tools/attacks.py                      # bunny+camera128, cow+text64; default + strong settings
    python tools/attacks.py --quick              # fewer configurations
    python tools/attacks.py --json out.json      # also dump every row
"""

from __future__ import annotations

import argparse
import io
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]

SHARED = ROOT.parent / "shared"

from pmwm_codec.progressive.topology import unique_edges


# ------------------------------------------------------------------ attacks


def reorder(V, F, rng):
    """A0: random vertex permutation, face permutation and per-face corner rotation."""
    perm = rng.permutation(len(V))
    inv = np.argsort(perm)
    V2 = V[perm]
    F2 = inv[F][rng.permutation(len(F))]
    k = rng.integers(0, 3, len(F2))
    idx = (np.arange(3)[None, :] + k[:, None]) % 3
    return V2, np.take_along_axis(F2, idx, axis=1)


def rodrigues(axis, angle):
    axis = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def similarity(V, F, rng):
    """A1: rotation about a random axis, uniform scale in [0.2, 5], translation of a few radii."""
    R = rodrigues(rng.normal(size=3), rng.uniform(0, 2 * math.pi))
    s = float(np.exp(rng.uniform(math.log(0.2), math.log(5))))
    radius = float(np.linalg.norm(V - V.mean(0), axis=1).mean())
    t = rng.uniform(-5, 5, 3) * radius
    return V @ R.T * s + t, F


def float32(V, F, rng=None):
    """T1: float32 round trip."""
    return V.astype(np.float32).astype(np.float64), F


def noise(V, F, rng, amplitude):
    """A2: MEPP NoiseAdditionUniform, ``amplitude`` as a fraction (0.001 = 0.10 %)."""
    c = V.mean(0)
    d = np.linalg.norm(V - c, axis=1).mean()
    return V + rng.uniform(-1, 1, V.shape) * amplitude * d, F


def quantize(V, F, rng, bits):
    """A4: MEPP CoordinateQuantization, per-axis bbox grid of 2**bits cells."""
    lo, hi = V.min(0), V.max(0)
    step = (hi - lo) / 2**bits
    step = np.where(step > 0, step, 1.0)
    q = np.floor((V - lo) / step) * step + lo
    q = q + step * ((V - q) > 0.5 * step)
    return q, F


def adjacency(F, n):
    e = unique_edges(F)
    A = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n))
    return (A + A.T).tocsr()


def smooth(V, F, rng, iterations, lam=0.03):
    """A3: MEPP LaplacianSmoothing (Jacobi, uniform weights)."""
    A = adjacency(F, len(V))
    deg = np.asarray(A.sum(1)).ravel()
    deg[deg == 0] = 1
    X = V.copy()
    for _ in range(iterations):
        X = X + lam * (A @ X / deg[:, None] - X)
    return X, F


def crop(V, F, rng, fraction):
    """A7: remove ``fraction`` of the vertices by a random half-space; faces re-indexed."""
    n = rng.normal(size=3)
    n /= np.linalg.norm(n)
    h = V @ n
    keep = h > np.quantile(h, fraction)
    idx = np.flatnonzero(keep)
    remap = np.full(len(V), -1, np.int64)
    remap[idx] = np.arange(len(idx))
    F2 = F[keep[F].all(axis=1)]
    used = np.zeros(len(idx), bool)
    used[remap[F2].ravel()] = True  # drop vertices left without a face
    idx2 = idx[used]
    remap2 = np.full(len(V), -1, np.int64)
    remap2[idx2] = np.arange(len(idx2))
    return V[idx2], remap2[F2]


def simplify(V, F, rng, reduction):
    """A6: quadric edge collapse to ``reduction`` fewer faces (needs ``fast-simplification``)."""
    import fast_simplification

    V2, F2 = fast_simplification.simplify(V.astype(np.float32), F.astype(np.int32), target_reduction=reduction)
    return np.asarray(V2, np.float64), np.asarray(F2, np.int64)


def draco(V, F, rng, bits):
    """T4: a real Draco round trip (DracoPy) at ``bits`` position quantization bits."""
    import DracoPy

    blob = DracoPy.encode(V.astype(np.float32), F.astype(np.uint32), quantization_bits=bits, compression_level=7)
    d = DracoPy.decode(blob)
    return np.asarray(d.points, np.float64), np.asarray(d.faces, np.int64).reshape(-1, 3)


def subdivide(V, F, rng, scheme="midpoint"):
    """A5: one step of subdivision, every triangle into four (shared edge points shared).

    ``scheme`` "midpoint": new points at the edge midpoints, old points kept (the surface does
    not move).  "loop": Loop's rules -- an interior edge point 3/8 (a + b) + 1/8 (c + d) from its
    two opposite corners, a boundary (or non-manifold) edge point the midpoint; an interior old
    point (1 - n beta) v + beta * sum of its n neighbours with beta = (5/8 - (3/8 + cos(2 pi / n) / 4)^2) / n,
    a boundary point 3/4 v + 1/8 of its two boundary neighbours, other boundary points kept.
    ``V`` (n, 3) float64, ``F`` (m, 3) int64; returns (n + edges, 3) float64, (4m, 3) int64.
    """
    n, m = len(V), len(F)
    half = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])  # (3m, 2), face f's edge j at j*m + f
    opposite = np.concatenate([F[:, 2], F[:, 0], F[:, 1]])
    lo, hi = half.min(1), half.max(1)
    uniq, inv = np.unique(lo * n + hi, return_inverse=True)
    ulo, uhi = uniq // n, uniq % n
    count = np.bincount(inv, minlength=len(uniq))
    edge_points = 0.5 * (V[ulo] + V[uhi])
    if scheme == "loop":
        opp_sum = np.stack([np.bincount(inv, V[opposite, q], len(uniq)) for q in range(3)], 1)
        two = count == 2
        edge_points[two] = 0.375 * (V[ulo[two]] + V[uhi[two]]) + 0.125 * opp_sum[two]
        old = V.copy()
        valence = np.bincount(np.concatenate([ulo, uhi]), minlength=n)
        nbr_sum = np.stack([np.bincount(np.concatenate([ulo, uhi]), np.concatenate([V[uhi, q], V[ulo, q]]), n)
                            for q in range(3)], 1)
        edge_b = count != 2
        b_ends = np.concatenate([ulo[edge_b], uhi[edge_b]])
        b_count = np.bincount(b_ends, minlength=n)
        b_sum = np.stack([np.bincount(b_ends, np.concatenate([V[uhi[edge_b], q], V[ulo[edge_b], q]]), n)
                          for q in range(3)], 1)
        inner = (b_count == 0) & (valence > 0)
        k = np.maximum(valence[inner], 1).astype(np.float64)
        beta = (0.625 - (0.375 + 0.25 * np.cos(2 * np.pi / k)) ** 2) / k
        old[inner] = (1 - k * beta)[:, None] * V[inner] + beta[:, None] * nbr_sum[inner]
        rim = b_count == 2
        old[rim] = 0.75 * V[rim] + 0.125 * b_sum[rim]
        V = old
    mid = n + inv.reshape(3, m).T  # (m, 3): edge point of edge 01, 12, 20
    a, b, c = F.T
    ab, bc, ca = mid.T
    faces = np.concatenate([np.stack([a, ab, ca], 1), np.stack([b, bc, ab], 1), np.stack([c, ca, bc], 1),
                            np.stack([ab, bc, ca], 1)])
    return np.concatenate([V, edge_points]), faces


def chain(*steps):
    def run(V, F, rng):
        for step in steps:
            V, F = step(V, F, rng)
        return V, F

    return run


def attack_grid(simplification: bool = True):
    """``[(group, name, fn(V, F, rng) -> (V, F))]`` -- the suite in table order."""
    g = [
        ("none", "no attack", lambda V, F, r: (V, F)),
        ("A0", "reorder vertices+faces+corners", reorder),
        ("A1", "similarity (rot+scale+transl)", similarity),
        ("T1", "float32 round trip", float32),
        ("A0+A1+T1", "similarity+reorder+float32", chain(similarity, reorder, float32)),
    ]
    for a in (0.0005, 0.001, 0.003, 0.005):
        g.append(("A2", f"noise {a * 100:.2f}%", lambda V, F, r, a=a: noise(V, F, r, a)))
    for b in (11, 10, 9, 8, 7):
        g.append(("A4", f"quantization {b} bits", lambda V, F, r, b=b: quantize(V, F, r, b)))
    for n in (5, 10, 30, 50):
        g.append(("A3", f"smoothing {n} it. (lambda 0.03)", lambda V, F, r, n=n: smooth(V, F, r, n)))
    for c in (0.1, 0.3, 0.5):
        g.append(("A7", f"crop {int(c * 100)}%", lambda V, F, r, c=c: crop(V, F, r, c)))
    g.append(("A7+A1", "crop 30% + similarity", chain(lambda V, F, r: crop(V, F, r, 0.3), similarity)))
    if simplification:
        for s in (0.1, 0.3, 0.5, 0.7):
            g.append(("A6", f"simplification {int(s * 100)}%", lambda V, F, r, s=s: simplify(V, F, r, s)))
    for b in (14, 11):
        g.append(("T4", f"Draco {b} bits", lambda V, F, r, b=b: draco(V, F, r, b)))
    g.append(("T4+A0", "Draco 14 bits + reorder", chain(lambda V, F, r: draco(V, F, r, 14), reorder)))
    return g


# -------------------------------------------------------------------- bench


def encode_case(mesh_path, wm_path, *, step_units=None, bits=None, wm_size=None, seed=0):
    """Encode ``mesh_path`` with ``wm_path`` in memory: ``(data, key, report, image)``."""
    from PIL import Image

    from pmwm_codec import read_mesh
    from pmwm_codec.stream.encoder import encode_mesh
    from pmwm_codec.watermark.image import load_watermark
    from pmwm_codec.watermark.key import WatermarkKey

    mesh = read_mesh(mesh_path)
    img, _ = load_watermark(wm_path)
    if wm_size is not None and img.shape[0] != wm_size:
        img = np.asarray(Image.fromarray(img).resize((wm_size, wm_size), Image.LANCZOS), np.uint8)
    key = WatermarkKey.generate(rng=np.random.default_rng(seed))
    buf = io.BytesIO()
    report = encode_mesh(mesh, buf, watermark=img, key=key, step_units=step_units, bits=bits)
    return buf.getvalue(), report.key, report, img, mesh


def run_attacks(data, key, *, seed=0, simplification=True, only=None, log=None, original=None):
    """Apply every attack to the full decode of ``data``; one dict per attack.

    ``original``: the unmarked input :class:`~pmwm_codec.mesh.Mesh`; adds a row
    verifying it (same shape, no mark: must not be authentic).
    """
    from pmwm_codec import decode
    from pmwm_codec.errors import PmwError
    from pmwm_codec.verify import verify_mesh

    ref = decode(data)
    V, F = ref.positions, ref.faces
    rows = []
    grid = attack_grid(simplification)
    if original is not None:
        grid.append(("X", "unmarked input mesh (no mark)", lambda V, F, r: (original.positions, original.faces)))
    for i, (group, name, fn) in enumerate(grid):
        if only and group not in only:
            continue
        rng = np.random.default_rng(seed * 1000 + i)
        t0 = time.perf_counter()
        try:
            V2, F2 = fn(V.copy(), F.copy(), rng)
        except ImportError as exc:
            rows.append({"group": group, "attack": name, "skipped": str(exc)})
            continue
        try:
            r = verify_mesh((V2, F2), data, key)
            row = {"group": group, "attack": name, **r.as_json()}
        except PmwError as exc:
            row = {"group": group, "attack": name, "verdict": "error", "error": str(exc)}
        row["attack_vertices"] = int(len(V2))
        row["wall"] = round(time.perf_counter() - t0, 3)
        rows.append(row)
        if log:
            log(row)
    return rows


def _fmt(x, nd=3):
    if x is None:
        return "—"
    if x == "Infinity" or (isinstance(x, float) and math.isinf(x)):
        return "∞"
    return f"{x:.{nd}f}"


def markdown_table(rows) -> str:
    out = ["| attack | vertices | correspondence | carriers read | BER | code match | NC | centred NC | PSNR dB | verdict |",
           "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        if "skipped" in r:
            out.append(f"| {r['group']} {r['attack']} | — | skipped: {r['skipped']} | | | | | | | |")
            continue
        if r.get("verdict") == "error":
            out.append(f"| {r['group']} {r['attack']} | {r['attack_vertices']} | error: {r['error']} | | | | | | | |")
            continue
        read = f"{r['carriers_read']}/{r['carriers_total']}"
        out.append(
            f"| {r['group']} {r['attack']} | {r['attack_vertices']} | {r['correspondence']} | {read} | {_fmt(r['ber'])} | "
            f"{_fmt(r['code_match'])} | {_fmt(r['nc'], 4)} | {_fmt(r['centered_nc'], 4)} | {_fmt(r['psnr_db'], 2)} | **{r['verdict']}** |"
        )
    return "\n".join(out)


CASES = [
    # (label, mesh, watermark, encode options)
    ("bunny / camera128, default (exact, step 2 grid units)", "stanford-bunny.obj", "camera128.png", {}),
    ("bunny / camera128, step_units=16", "stanford-bunny.obj", "camera128.png", {"step_units": 16}),
    ("bunny / camera128 resized to 32x32, bits=1, step_units=16 (copies voted)", "stanford-bunny.obj", "camera128.png",
     {"step_units": 16, "bits": 1, "wm_size": 32}),
    # text64 (32780 message bits) no longer fits the cow's 2735 splits at <= 6 bits per carrier:
    ("cow / text64 resized to 32x32, default (exact, step 2 grid units)", "cow.obj", "text64.png", {"wm_size": 32}),
    ("cow / text64 resized to 16x16, bits=1, step_units=16 (copies voted)", "cow.obj", "text64.png",
     {"step_units": 16, "bits": 1, "wm_size": 16}),
]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="only the default configurations")
    ap.add_argument("--cases", type=str, default=None, help="comma-separated case numbers (0-based)")
    ap.add_argument("--json", type=str, default=None, help="write every row to this JSON file")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-simplify", action="store_true")
    args = ap.parse_args(argv)
    from pmwm_codec.errors import PmwError

    cases = list(enumerate(CASES))
    if args.cases:
        pick = {int(c) for c in args.cases.split(",")}
        cases = [c for c in cases if c[0] in pick]
    elif args.quick:
        cases = [c for c in cases if "default" in c[1][0]]
    dump = []
    for _, (label, mesh_name, wm_name, opts) in cases:
        opts = dict(opts)
        t0 = time.perf_counter()
        try:
            data, key, report, img, mesh = encode_case(SHARED / "corpus" / mesh_name, SHARED / "watermarks" / wm_name,
                                                       seed=args.seed, **opts)
        except PmwError as exc:
            print(f"\n#### {label}\n\ncannot encode: {exc}\n", flush=True)
            dump.append({"case": label, "options": opts, "error": str(exc)})
            continue
        d = report.distortion
        w = report.watermark
        print(f"\n#### {label}\n")
        print(f"{report.vertices} vertices, {w['carriers']} carriers, {w['width']}x{w['height']} watermark, "
              f"mode {w['mode']}, {w['bits']} bits/carrier, {w['codes']} message bits "
              f"({w['bits'] * w['carriers'] / max(w['codes'], 1):.2f} copies); "
              f"embedding distortion: RMS {d['rms']:.3g} ({d['rms'] / d['bbox_diagonal'] * 100:.4f}% of the bbox diagonal), "
              f"mesh PSNR {d['psnr_db']:.2f} dB, Hausdorff {d['hausdorff'] * 100:.4f}% of the diagonal; "
              f"encode {time.perf_counter() - t0:.1f} s.\n", flush=True)
        rows = run_attacks(data, key, seed=args.seed, simplification=not args.no_simplify, original=mesh)
        print(markdown_table(rows), flush=True)
        dump.append({"case": label, "options": opts, "encode": report.as_json(), "rows": rows})
    if args.json:
        Path(args.json).write_text(json.dumps(dump, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
