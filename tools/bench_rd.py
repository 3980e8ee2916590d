"""Rate-distortion: prefixes of our stream against a Draco-compressed LOD chain (issue 13, done-when 2).

For each mesh and grid resolution (default 16 and 14 bits):

* **ours** -- ``pmwm_codec.encode(mesh, BytesIO, grid_bits=g, measure="none")`` (default options
  otherwise: no watermark), decoded with :func:`pmwm_codec.iter_decode`; every chunk boundary
  gives a point (bytes of the whole file prefix needed -- GLB header + JSON + base + chunks --
  and the error of the mesh decoded from it);
* **LODs** -- ``fast_simplification.simplify`` to 2 %, 10 % and 30 % of the faces, each
  compressed by ``DracoPy.encode(quantization_bits=g, compression_level=7)`` and decoded back;
* **same bytes** -- the longest prefix of ours that fits in each LOD's Draco bytes, its error
  against the LOD's ("nothing fits" when even our base is larger); and, as a diagnostic that
  separates the index from the payload, the same with the GLB JSON (the chunk index lives
  there) not counted;
* **same vertex count** (ordering only, no bits) -- our simplifier's level with exactly the
  LOD's vertex count, on the original float positions (the encoder's own collapse log applied
  fine to coarse; the batch that crosses the count is applied in part, cheapest collapses
  first: collapses of one batch are independent) against the uncompressed fast-simplification LOD;
* **placement against selection** (a diagnostic of that ordering ratio) -- our level with every
  vertex that absorbed others moved to its cluster's quadric minimum (where a full-edge collapse
  would put it: :func:`placed_level`), and the fast-simplification LOD with every vertex snapped
  to the nearest input vertex (:func:`snapped`): which of the two differences, the choice of
  collapses or where the kept vertices sit, makes our levels farther or closer.

Error: symmetric RMS point-to-surface distance to the original
(:func:`pmwm_codec.distortion.rms_surface_distance`: ``--samples`` area-weighted points on
each surface, seed 0), divided by the original's bounding-box diagonal D.

Meshes: every ``*.obj`` of ``../shared/corpus`` (skipped when absent) and a generated one
(``pmwm_codec.shapes.demo_mesh(100)``), so the tool runs anywhere.  Run from the repository root::

    python tools/bench_rd.py                         # print the Markdown report
    python tools/bench_rd.py --write BENCHMARKS.md   # also replace its section, plot in docs/
    python tools/bench_rd.py --corpus /tmp/heldout --mesh dragon437k --same-bytes-only
                                                     # the same-bytes cells only (minutes on a 437k mesh)
"""

from __future__ import annotations

import argparse
import io
import os
import shlex
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for path in (ROOT, HERE):
    if path not in sys.path:
        sys.path.insert(0, path)

import pmwm_codec  # noqa: E402
from pmwm_codec.constants import DEFAULT_GRID_BITS  # noqa: E402
from pmwm_codec.distortion import rms_surface_distance  # noqa: E402
from pmwm_codec.mesh import Mesh  # noqa: E402
from pmwm_codec.progressive.grid import Grid  # noqa: E402
from pmwm_codec.progressive.simplify import deferred_faces, face_quadrics  # noqa: E402
from pmwm_codec.shapes import demo_mesh  # noqa: E402

from bench import DEFAULT_CORPUS, StageTimers, glb_parts, machine, publish, table  # noqa: E402

SECTION = "Rate-distortion against a Draco LOD chain"
FRACTIONS = (0.02, 0.10, 0.30)
PLOT = os.path.join("docs", "rate-distortion.png")


# ----------------------------------------------------------------------------- meshes
def load_meshes(corpus: str, names=None) -> list:
    """``[(name, Mesh)]``: the corpus ``*.obj`` meshes (bunny first; none when absent), then a generated one."""
    out = []
    if os.path.isdir(corpus):
        files = sorted(f for f in os.listdir(corpus) if f.endswith(".obj"))
        files.sort(key=lambda f: f != "stanford-bunny.obj")
        out = [(f[:-4], pmwm_codec.read_mesh(os.path.join(corpus, f))) for f in files]
    out.append(("generated demo_mesh(100)", demo_mesh(100)))
    return [(n, m) for n, m in out if not names or n in names]


def compact(positions: np.ndarray, faces: np.ndarray) -> Mesh:
    """The mesh of the vertices ``faces`` (m, 3) uses, renumbered: positions (k, 3) float64, faces (m, 3) int64."""
    used = np.unique(faces)
    remap = np.full(len(positions), -1, np.int64)
    remap[used] = np.arange(len(used))
    return Mesh(np.asarray(positions, np.float64)[used], remap[faces])


# ----------------------------------------------------------------------------- ours
def our_stream(mesh: Mesh, bits: int) -> tuple:
    """``(blob bytes, boundaries, collapse log)``: boundaries are ``[(bytes_read, vertices, Mesh)]``, base first."""
    buf = io.BytesIO()
    with StageTimers() as timers:
        pmwm_codec.encode(mesh, buf, grid_bits=bits, measure="none")
    blob = buf.getvalue()
    levels = [(r.bytes_read, r.vertices, r.mesh) for r in pmwm_codec.iter_decode(blob)]
    return blob, levels, timers.captured["simplify"]


def level_clusters(mesh: Mesh, log, count: int, bits: int = DEFAULT_GRID_BITS) -> tuple:
    """Our simplifier's level with ``count`` vertices, and where every input vertex went.

    ``log``: the encoder's :class:`~pmwm_codec.progressive.simplify.CollapseLog` for ``mesh`` at a
    ``bits`` grid, whose ids are those of the mesh it simplified: without the faces it defers (pillows,
    flaps' tips, specks), which the stream sends last (a face chunk, bitstream.md §8.6), so no level
    before the last has them.
    Batches are applied fine to coarse; the one that would go below ``count`` is applied in
    part, its cheapest collapses first (the collapses of a batch are independent).  A
    ``count`` below the base size gives the base.

    Returns ``(core, faces, rep)``: ``core`` the simplified mesh (the input without the deferred
    faces, renumbered), ``faces`` (k, 3) int64 the level's faces in ``core``'s ids, ``rep`` (n,) int64
    the level vertex each core vertex collapsed into (itself for a level vertex).
    """
    late = deferred_faces(Grid.fit(mesh.positions, bits).quantize(mesh.positions), mesh.faces)
    core = np.unique(mesh.faces[~late])  # the encoder's core vertices (every vertex is on a face here)
    local = np.full(mesh.vertex_count, -1, np.int64)
    local[core] = np.arange(len(core))
    mesh = Mesh(mesh.positions[core], local[mesh.faces[~late]])
    corners = np.array(mesh.faces, np.int64)
    face_alive = np.ones(len(corners), bool)
    alive = len(np.unique(corners))
    rep = np.arange(mesh.vertex_count)
    for batch in log.batches:
        if alive <= count:
            break
        take = np.arange(len(batch.u))
        if alive - len(take) < count:
            take = np.sort(np.argsort(batch.cost, kind="stable")[: alive - count])
        chosen = np.zeros(len(batch.u), bool)
        chosen[take] = True
        dead = np.concatenate([batch.del_left[take], batch.del_right[take]])
        face_alive[dead[dead >= 0]] = False
        moved = chosen[batch.moved_by]
        mf, by = batch.moved_face[moved], batch.moved_by[moved]
        corners[mf] = np.where(corners[mf] == batch.u[by][:, None], batch.v[by][:, None], corners[mf])
        rep[batch.u[take]] = batch.v[take]
        alive -= len(take)
    while True:  # a kept vertex may be removed by a later batch: follow each chain to its end
        nxt = rep[rep]
        if np.array_equal(nxt, rep):
            break
        rep = nxt
    return mesh, corners[face_alive], rep


def level_at(mesh: Mesh, log, count: int, bits: int = DEFAULT_GRID_BITS) -> Mesh:
    """Our simplifier's level with ``count`` vertices, on ``mesh``'s own (float) positions
    (:func:`level_clusters`): half-edge collapses, so every vertex is an input vertex."""
    core, faces, _ = level_clusters(mesh, log, count, bits)
    return compact(core.positions, faces)


def placed_level(core: Mesh, faces: np.ndarray, rep: np.ndarray) -> Mesh:
    """The level ``faces`` of :func:`level_clusters` with every vertex that absorbed others moved to the
    minimum of the summed quadrics (:func:`~pmwm_codec.progressive.simplify.face_quadrics`, the
    simplifier's own) of the core vertices that collapsed into it: where a full-edge collapse would
    put it.  A diagnostic of placement against selection (the format's splits never move a kept
    vertex); a vertex whose summed quadric is singular, or whose minimum lies farther from its
    cluster's centroid than three times its own distance, stays where it is."""
    P = np.asarray(core.positions, np.float64)
    n = len(P)
    Q = face_quadrics(P, np.asarray(core.faces, np.int64), n)
    size = np.bincount(rep, minlength=n)
    qs = np.stack([np.bincount(rep, weights=Q[:, j], minlength=n) for j in range(10)], axis=1)
    centroid = np.stack([np.bincount(rep, weights=P[:, j], minlength=n) for j in range(3)], axis=1)
    centroid /= np.maximum(size, 1)[:, None]
    out = P.copy()
    movers = np.flatnonzero(size > 1)
    a2, ab, ac, ad, b2, bc, bd, c2, cd, _ = qs[movers].T
    A = np.stack([np.stack([a2, ab, ac], -1), np.stack([ab, b2, bc], -1), np.stack([ac, bc, c2], -1)], 1)
    scale = np.abs(A).reshape(len(movers), -1).max(axis=1)
    ok = np.abs(np.linalg.det(A)) > 1e-12 * np.maximum(scale, 1e-300) ** 3
    x = np.zeros((len(movers), 3))
    if ok.any():
        x[ok] = np.linalg.solve(A[ok], -np.stack([ad, bd, cd], -1)[ok][..., None])[..., 0]
    near = np.linalg.norm(x - centroid[movers], axis=1) < 3 * np.linalg.norm(P[movers] - centroid[movers], axis=1)
    take = ok & near
    out[movers[take]] = x[take]
    return compact(out, faces)


# ----------------------------------------------------------------------------- peers
def lod_chain(mesh: Mesh, bits: int) -> list:
    """One dict per fraction of :data:`FRACTIONS`: ``raw`` (uncompressed fast-simplification LOD),
    ``draco`` (its Draco q``bits`` cl7 decode), ``bytes`` (the Draco file's size)."""
    import DracoPy
    import fast_simplification

    pts = np.ascontiguousarray(mesh.positions, np.float64)
    tri = np.ascontiguousarray(mesh.faces, np.int32)
    out = []
    for frac in FRACTIONS:
        v, f = fast_simplification.simplify(pts, tri, target_reduction=1.0 - frac)
        raw = compact(v, np.asarray(f, np.int64))
        blob = DracoPy.encode(raw.positions, raw.faces.astype(np.uint32), quantization_bits=bits, compression_level=7)
        dec = DracoPy.decode(blob)
        draco = Mesh(np.asarray(dec.points, np.float64), np.asarray(dec.faces, np.int64).reshape(-1, 3))
        out.append({"fraction": frac, "raw": raw, "draco": draco, "bytes": len(blob)})
    return out


def snapped(mesh: Mesh, lod: Mesh) -> Mesh:
    """``lod`` with every vertex moved to the nearest vertex of ``mesh``: a full-edge simplifier's
    selection under half-edge placement (the diagnostic twin of :func:`placed_level`)."""
    from scipy.spatial import cKDTree

    return Mesh(np.asarray(mesh.positions, np.float64)[cKDTree(mesh.positions).query(lod.positions)[1]], lod.faces)


# ----------------------------------------------------------------------------- measure
def measure(name: str, mesh: Mesh, bits: int, samples: int, log, same_bytes_only: bool = False) -> dict:
    """Every boundary's error, the LODs' errors, and the same-bytes / same-vertex comparisons.

    ``same_bytes_only`` measures the base and each LOD's longest fitting prefix only, and skips the
    same-vertex and placement diagnostics (their fields are ``None``): on a mesh of several hundred
    thousand vertices those cost most of the run."""
    t0 = time.perf_counter()
    diag = float(np.linalg.norm(np.ptp(mesh.positions, axis=0)))

    def err(m):
        return rms_surface_distance(mesh, m, samples) / diag

    blob, levels, clog = our_stream(mesh, bits)
    index = glb_parts(blob)["json"]
    lods = lod_chain(mesh, bits)
    wanted = set(range(len(levels)))
    if same_bytes_only:
        wanted = {0} | {i for x in lods for i in (_last_fitting(levels, x["bytes"], 0), _last_fitting(levels, x["bytes"], index))
                        if i is not None}
    curve = [(b, nv, err(m) if i in wanted else None) for i, (b, nv, m) in enumerate(levels)]
    rows = []
    for lod in lods:
        fit, free = _last_fitting(levels, lod["bytes"], 0), _last_fitting(levels, lod["bytes"], index)
        k = lod["raw"].vertex_count
        row = {"fraction": lod["fraction"], "lod_vertices": k, "lod_faces": lod["raw"].face_count,
               "lod_bytes": lod["bytes"], "lod_error": err(lod["draco"]),
               "prefix": None if fit is None else curve[fit], "prefix_chunks": -1 if fit is None else fit,
               "prefix_no_json": None if free is None else curve[free],
               "raw_error": None, "ours_k_vertices": None, "ours_k_error": None, "placed_error": None, "snapped_error": None}
        if not same_bytes_only:
            core, faces, rep = level_clusters(mesh, clog, k, bits)
            ours_k = compact(core.positions, faces)
            row.update(raw_error=err(lod["raw"]), ours_k_vertices=ours_k.vertex_count, ours_k_error=err(ours_k),
                       placed_error=err(placed_level(core, faces, rep)), snapped_error=err(snapped(mesh, lod["raw"])))
        rows.append(row)
    log(f"[{name} grid {bits}] {len(blob):,} B, {len(levels) - 1} chunks, {time.perf_counter() - t0:.1f} s")
    return {"name": name, "bits": bits, "vertices": mesh.vertex_count, "faces": mesh.face_count,
            "bytes": len(blob), "json": index, "curve": curve, "lods": rows}


def _last_fitting(levels: list, budget: int, free: int):
    """Index of the last boundary whose prefix, less ``free`` bytes, fits in ``budget``; ``None`` if none does."""
    fits = [i for i, lv in enumerate(levels) if lv[0] - free <= budget]
    return fits[-1] if fits else None


# ----------------------------------------------------------------------------- report
def fmt_err(e) -> str:
    return "-" if e is None else f"{e:.2e}"


def ratio(a, b) -> str:
    return f"{a / b:.2f}x" if a is not None and b else "-"


def render(results, info, command: str, plot) -> str:
    load = ", ".join(f"{x:.2f}" for x in info["load"])
    L = [f"Command: `{command}`", "",
         f"Machine: {info['cpu']} ({info['cores']} cores), load average {load} at the start; Python "
         f"{info['python']}, numpy {info['numpy']}, DracoPy {info['DracoPy']}, fast-simplification "
         f"{info['fast_simplification']}; code {info['git']}.", "",
         "Error: symmetric RMS point-to-surface distance to the original (sampled both ways, "
         f"{results[0]['samples']:,} points per surface, seed 0) over the original's bounding-box diagonal D. "
         "LOD: fast-simplification to 2/10/30 % of the faces, Draco at the grid's bits, cl7. "
         "Same bytes: the longest prefix of our default-option `.pmw` (no watermark; GLB header, JSON, base "
         "and whole chunks) within the LOD's Draco bytes; \"without the JSON\": the same with the GLB JSON "
         "(it holds the chunk index) not counted, a diagnostic. Same vertices: our simplifier's level with the "
         "LOD's vertex count on the float positions (order only) against the uncompressed LOD.", ""]
    rows = []
    for r in results:
        base = r["curve"][0]
        for x in r["lods"]:
            p = x["prefix"]
            ours = (f"{p[0]:,} B, {p[1]:,} V ({x['prefix_chunks']} chunks): {fmt_err(p[2])}" if p
                    else f"nothing fits (base {base[0]:,} B)")
            q = x["prefix_no_json"]
            free = f"{q[1]:,} V: {ratio(q[2], x['lod_error'])}" if q else "nothing fits"
            rows.append([r["name"], r["bits"], f"{100 * x['fraction']:g}%", f"{x['lod_vertices']:,}",
                         f"{x['lod_bytes']:,}", fmt_err(x["lod_error"]), ours, ratio(p[2], x["lod_error"]) if p else "-", free,
                         fmt_err(x["ours_k_error"]) + ("" if x["ours_k_vertices"] in (None, x["lod_vertices"])
                                                       else f" (base: {x['ours_k_vertices']:,} V)"),
                         fmt_err(x["raw_error"]), ratio(x["ours_k_error"], x["raw_error"])])
    L.append(table(["mesh", "grid", "LOD", "LOD V", "LOD Draco B", "LOD error", "ours in those bytes",
                    "ours / LOD", "without the JSON: ours / LOD", "ours at LOD V", "fast-simpl. LOD", "ordering ratio"], rows))
    if all(x["placed_error"] is None for r in results for x in r["lods"]):
        L += ["", "Same-vertex and placement diagnostics not measured (`--same-bytes-only`)."]
    else:
        L += ["", "Placement against selection (no bits involved): our level at the LOD's vertex count as the stream "
              "has it (every vertex an input vertex: half-edge collapses) and with every vertex that absorbed others "
              "moved to the minimum of the summed quadrics of its cluster (where a full-edge collapse puts it; "
              "`placed_level`); the fast-simplification LOD as it is (full-edge collapses) and with every vertex "
              "snapped to the nearest input vertex (`snapped`). Errors over the LOD's (uncompressed):", ""]
        L.append(table(["mesh", "grid", "LOD", "ours (half-edge)", "ours, quadric placement", "fast-simpl. LOD",
                        "fast-simpl. LOD snapped to input vertices"],
                       [[r["name"], r["bits"], f"{100 * x['fraction']:g}%", ratio(x["ours_k_error"], x["raw_error"]),
                         ratio(x["placed_error"], x["raw_error"]), fmt_err(x["raw_error"]),
                         ratio(x["snapped_error"], x["raw_error"])] for r in results for x in r["lods"]]))
    L += ["", "Our stream (whole file, base mesh = the first renderable one):", ""]
    L.append(table(["mesh", "grid", "file B", "chunks", "JSON B", "base B (all bytes before it)", "base V",
                    "error at base"],
                   [[r["name"], r["bits"], f"{r['bytes']:,}", len(r["curve"]) - 1, f"{r['json']:,}",
                     f"{r['curve'][0][0]:,}", f"{r['curve'][0][1]:,}", fmt_err(r["curve"][0][2])] for r in results]))
    if plot:
        L += ["", f"![error against bytes]({plot}) — ours: one point per chunk boundary; "
              "LODs: the Draco chain (same colour per grid)."]
    return "\n".join(L) + "\n"


def plot(results, path: str) -> None:
    """Log-log error against bytes, one panel per mesh: our curve and the LOD points per grid."""
    from PIL import Image, ImageDraw

    from pmwm_codec.figures import INK, _Panel, font

    names = list(dict.fromkeys(r["name"] for r in results))
    cols, w, h = 2, 520, 330
    img = Image.new("RGB", (cols * w, ((len(names) + cols - 1) // cols) * h), (255, 255, 255))
    d, fnt = ImageDraw.Draw(img), font(12)
    colors = {16: (200, 70, 50), 14: (40, 100, 190)}
    for i, name in enumerate(names):
        mine = [r for r in results if r["name"] == name]
        xs = [np.log10(c[0]) for r in mine for c in r["curve"]] + [np.log10(x["lod_bytes"]) for r in mine for x in r["lods"]]
        ys = [np.log10(max(c[2], 1e-9)) for r in mine for c in r["curve"] if c[2] is not None]
        ys += [np.log10(max(x["lod_error"], 1e-9)) for r in mine for x in r["lods"]]
        ox, oy = (i % cols) * w, (i // cols) * h
        xlim, ylim = (np.floor(min(xs) * 4) / 4, np.ceil(max(xs) * 4) / 4), (np.floor(min(ys) * 2) / 2, np.ceil(max(ys) * 2) / 2)
        panel = _Panel(d, (ox + 62, oy + 28, ox + w - 16, oy + h - 40), xlim, ylim)
        _log_axes(d, panel, fnt)
        d.text((ox + 62, oy + 8), name, font=font(14), fill=INK)
        for r in mine:
            c = colors.get(r["bits"], INK)
            pts = [p for p in r["curve"] if p[2] is not None]
            panel.series([np.log10(p[0]) for p in pts], [np.log10(max(p[2], 1e-9)) for p in pts], c)
            for x in r["lods"]:
                px, py = panel.px(np.log10(x["lod_bytes"]), np.log10(max(x["lod_error"], 1e-9)))
                d.rectangle([px - 6, py - 6, px + 6, py + 6], outline=c, width=2)
            d.text((ox + w - 210, oy + 8 + 14 * (r["bits"] == 14)), f"grid {r['bits']}: ours (line), LOD (square)",
                   font=fnt, fill=c)
    os.makedirs(os.path.dirname(path) or ".", exist_ok=True)
    img.save(path)


def _log_axes(d, panel, fnt) -> None:
    """Frame, grid lines and 10^k labels of a panel whose data are log10 values."""
    from pmwm_codec.figures import GRID, INK

    x0, y0, x1, y1 = panel.box
    for t in np.arange(np.ceil(panel.xlim[0]), panel.xlim[1] + 1e-9):
        px, _ = panel.px(t, panel.ylim[0])
        d.line([px, y0, px, y1], fill=GRID)
        d.text((px - 14, y1 + 6), f"1e{int(t)} B", font=fnt, fill=INK)
    for t in np.arange(np.ceil(panel.ylim[0]), panel.ylim[1] + 1e-9):
        _, py = panel.px(panel.xlim[0], t)
        d.line([x0, py, x1, py], fill=GRID)
        d.text((x0 - 40, py - 7), f"1e{int(t)}", font=fnt, fill=INK)
    d.rectangle([x0, y0, x1, y1], outline=INK)
    d.text((x0 + 4, y1 - 18), "RMS error / D", font=fnt, fill=INK)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default=DEFAULT_CORPUS)
    ap.add_argument("--mesh", action="append", help="only these meshes (corpus names without .obj; repeatable)")
    ap.add_argument("--bits", type=int, nargs="+", default=[16, 14], help="grid bits (default: 16 14)")
    ap.add_argument("--samples", type=int, default=100_000, help="sample points per surface")
    ap.add_argument("--same-bytes-only", action="store_true",
                    help="measure only the base and each LOD's fitting prefix; skip the same-vertex and placement "
                         "diagnostics (minutes instead of tens of minutes on a mesh of ~500k vertices)")
    ap.add_argument("--write", metavar="MARKDOWN", help=f"replace the '{SECTION}' section and write {PLOT}")
    ap.add_argument("--section", default=SECTION, help="section title to replace")
    args = ap.parse_args(argv)
    command = "python tools/bench_rd.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    info = machine()
    results = []
    for name, mesh in load_meshes(args.corpus, args.mesh):
        for bits in args.bits:
            results.append({**measure(name, mesh, bits, args.samples, log, args.same_bytes_only),
                            "samples": args.samples})
    if args.write:
        plot(results, os.path.join(ROOT, PLOT))
    publish(render(results, info, command.strip(), PLOT if args.write else None), args.write, args.section, log)


if __name__ == "__main__":
    main()
