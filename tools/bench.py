"""Engine benchmark: our encode / decode / size against the compiled peers, on the same mesh.

One run measures, per mesh:

* **encode** -- ``pmwm_codec.encode(mesh, BytesIO, measure=False)`` (no watermark, no
  distortion measurement, grid 14 bits) against ``fast_simplification.simplify(...,
  return_collapses=True)`` down to the same base face count;
* **default encode** -- ``pmwm_codec.encode(mesh, BytesIO)`` with no options at all, against the same
  fast-simplification runs; **peak memory** of each task in a fresh subprocess (``ru_maxrss`` growth,
  ``tracemalloc`` peak); **cold start** of ``pmw encode`` with and without the numba cache;
* **decode** -- ``pmwm_codec.decode(bytes)`` of the whole file in memory (Draco base + zstd +
  every split) against ``DracoPy.decode`` of the full mesh encoded at q14 / compression level 7;
* **size** -- total ``.pmw`` bits per vertex (grid 14 and 16) against that Draco file, plus a
  breakdown of our bytes (GLB/JSON, base, per payload column) and the encode profile
  (simplify / build records / base / pack / write) from timers wrapped around the stages of
  :func:`pmwm_codec.stream.encoder.encode_mesh` (in this process only; no library file changes).

Meshes: ``stanford-bunny.obj`` from ``../shared/corpus`` and the bunny midpoint-subdivided twice
(flat subdivision, built in memory: good for time scaling, unrealistic for size); with ``--huge``
also two copies of that side by side (1.11M vertices, the issue's ~1M-vertex mesh).

Run from the repository root::

    python tools/bench.py                       # print the Markdown report
    python tools/bench.py --write BENCHMARKS.md # also replace its "Engine" section

Times are medians of ``--repeats`` runs (``--big-repeats`` on the meshes of 200k vertices and more), ours and the
peer's interleaved run by run, after one warm-up encode.  The
machines these run on are shared; compare ratios within one table, not absolute times.
"""

from __future__ import annotations

import argparse
import io
import os
import platform
import shlex
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
if ROOT not in sys.path:  # run as `python tools/bench.py` from a checkout
    sys.path.insert(0, ROOT)

import pmwm_codec
from pmwm_codec.format import records
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream import encoder as enc_mod

DEFAULT_CORPUS = os.path.normpath(os.path.join(ROOT, "..", "shared", "corpus"))
SECTION = "Engine"

# targets (performance.md / the issue)
ENCODE_TARGET = 3.0  # x fast-simplification
DECODE_TARGET = 3.0  # x Draco q14 cl7 decode
SIZE_TARGET = 1.5  # x Draco q14 cl7 bytes


# ----------------------------------------------------------------------------- helpers
def machine() -> dict:
    cpu = "unknown"
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    try:
        load = os.getloadavg()
    except OSError:
        load = (float("nan"),) * 3
    import zstandard

    from importlib.metadata import version

    def ver(name):
        try:
            return version(name)
        except Exception:  # noqa: BLE001
            return "?"

    return {
        "git": git_state(),
        "cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "numpy": np.__version__,
        "DracoPy": ver("DracoPy"),
        "fast_simplification": ver("fast-simplification"),
        "zstandard": zstandard.__version__, "load": load,
    }


def git_state() -> str:
    """Commit and the library files that differ from it (others edit the tree concurrently)."""
    import subprocess

    try:
        head = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "--", "pmwm_codec"],
                               capture_output=True, text=True).stdout.split("\n")
        dirty = [line[3:] for line in dirty if line.strip()]
    except OSError:
        return "unknown"
    return head + (f" with uncommitted changes in {', '.join(dirty)}" if dirty else " (clean library tree)")


def interleaved(fns: dict, repeats: int) -> dict:
    """Run every function of ``fns`` once per round, ``repeats`` rounds: ``{name: (median s, all s, last result)}``."""
    times = {k: [] for k in fns}
    last = {}
    for _ in range(repeats):
        for name, fn in fns.items():
            t = time.perf_counter()
            last[name] = fn()
            times[name].append(time.perf_counter() - t)
    return {k: (statistics.median(v), v, last[k]) for k, v in times.items()}


def replace_section(path: str, title: str, body: str) -> None:
    """Replace (or append) the ``## title`` section of a Markdown file, up to the next ``## ``."""
    text = open(path).read() if os.path.exists(path) else "# Benchmarks\n"
    lines = text.splitlines(keepends=True)
    head = f"## {title}"
    start = next((i for i, l in enumerate(lines) if l.rstrip() == head), None)
    block = head + "\n\n" + body.rstrip() + "\n\n"
    if start is None:
        if not text.endswith("\n\n"):
            text = text.rstrip("\n") + "\n\n"
        text += block
    else:
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        text = "".join(lines[:start]) + block + "".join(lines[end:])
    with open(path, "w") as fh:
        fh.write(text.rstrip("\n") + "\n")


def run_header(command: str, info: dict) -> list:
    """The opening lines of a section: the command, then the machine, its load and the code measured."""
    load = ", ".join(f"{x:.2f}" for x in info["load"])
    return [f"Command (from the repository root): `{command}`", "",
            f"Machine: {info['cpu']} ({info['cores']} cores), load average {load} at the start; Python {info['python']}; "
            f"code {info['git']}.", ""]


def table(header, rows) -> str:
    out = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    out += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(out)


def ms(s: float) -> str:
    return f"{s * 1e3:,.1f} ms" if s < 10 else f"{s:,.2f} s"


# ----------------------------------------------------------------------------- meshes
def load_meshes(corpus: str, big: bool, huge: bool = False):
    """``[(name, Mesh)]``: the bunny; with ``big`` (or ``huge``) the bunny midpoint-subdivided twice (556k
    vertices); with ``huge`` also two copies of that side by side (1.11M vertices)."""
    bunny = pmwm_codec.read_mesh(os.path.join(corpus, "stanford-bunny.obj"))
    out = [("stanford-bunny", bunny)]
    if big or huge:
        from pmwm_codec.shapes import _midpoint_subdivide

        v, f = bunny.positions, bunny.faces
        for _ in range(2):
            v, f = _midpoint_subdivide(v, f)
        out.append(("bunny-sub2 (midpoint x2)", Mesh(v, f)))
    if huge:
        out.append(("bunny-sub2 x2 (side by side)", side_by_side(out[-1][1])))
    return out


def side_by_side(mesh):
    """Two copies of ``mesh`` one bounding box width (x 1.1) apart along x: one mesh of twice the size."""
    width = float(np.ptp(mesh.positions[:, 0])) * 1.1
    shifted = mesh.positions + np.array([width, 0.0, 0.0])
    return Mesh(np.concatenate([mesh.positions, shifted]), np.concatenate([mesh.faces, mesh.faces + mesh.vertex_count]))


# ----------------------------------------------------------------------------- profiled encode
class StageTimers:
    """Wrap the stage functions encode_mesh looks up in its module; collect times and outputs."""

    STAGES = ("simplify", "encode_base", "build_progressive", "pack_batches", "pack_chunks", "write_parts",
              "assemble_document")

    def __init__(self):
        self.times = {}
        self.captured = {}
        self.packed_chunks = []
        self._orig = {}

    def __enter__(self):
        for name in self.STAGES:
            orig = getattr(enc_mod, name)
            self._orig[name] = orig

            def wrapper(*a, _name=name, _orig=orig, **k):
                t = time.perf_counter()
                out = _orig(*a, **k)
                self.times[_name] = self.times.get(_name, 0.0) + time.perf_counter() - t
                if _name == "pack_batches":
                    self.packed_chunks.append(list(a[0]))
                else:
                    self.captured[_name] = out
                return out

            setattr(enc_mod, name, wrapper)
        return self

    def __exit__(self, *exc):
        for name, orig in self._orig.items():
            setattr(enc_mod, name, orig)


def column_breakdown(chunks, level: int) -> dict:
    """Bytes per payload column: every chunk's column compressed alone at ``level``, summed.

    Mirrors :func:`pmwm_codec.format.records.pack_batches` column by column.  Also returns the
    raw header + batch-table bytes (compressed alone too).
    """
    import zstandard

    cctx = zstandard.ZstdCompressor(level=level)
    out = {"header+table": 0, "gaps": 0, "symbols": 0, "residual_x": 0, "residual_y": 0, "residual_z": 0}
    raw = dict.fromkeys(out, 0)
    for batches in chunks:
        table_ = np.array([(b.size, len(b.symbols)) for b in batches], dtype=records.BATCH_TABLE_DTYPE)
        gaps = np.concatenate([np.diff(b.v, prepend=-1) - 1 for b in batches])
        symbols = np.concatenate([b.symbols for b in batches]).astype(np.uint8)
        residual = np.concatenate([b.residual for b in batches]).astype(np.int64)
        cols = {
            "header+table": records.RecordsHeader.build({"batch_count": len(batches)}) + table_.tobytes(),
            "gaps": records._pack_column(gaps),
            "symbols": records._pack_column(records._pack_symbols(symbols)),
        }
        for axis, name in enumerate(("residual_x", "residual_y", "residual_z")):
            cols[name] = records._pack_column(records.zigzag(residual[:, axis]))
        if sum(len(d) for d in cols.values()) != len(records.pack_batches(batches)):
            raise RuntimeError("column_breakdown no longer mirrors records.pack_batches: update the bench")
        for name, data in cols.items():
            raw[name] += len(data)
            out[name] += len(cctx.compress(data))
    return {"compressed": out, "raw": raw}


def residual_stats(chunks) -> dict:
    res = np.concatenate([np.concatenate([b.residual for b in bs]) for bs in chunks]).astype(np.int64)
    sym = np.concatenate([np.concatenate([b.symbols for b in bs]) for bs in chunks])
    a = np.abs(res)
    # empirical entropy of each residual axis (bits/value): a floor for an order-0 coder
    ent = []
    for axis in range(3):
        _, c = np.unique(res[:, axis], return_counts=True)
        p = c / c.sum()
        ent.append(float(-(p * np.log2(p)).sum()))
    _, c = np.unique(sym, return_counts=True)
    p = c / c.sum()
    return {"median_abs": float(np.median(a)), "p90_abs": float(np.percentile(a, 90)),
            "max_abs": int(a.max()), "entropy_bits": ent, "symbols_per_split": len(sym) / len(res),
            "symbol_entropy": float(-(p * np.log2(p)).sum())}


def glb_parts(data: bytes) -> dict:
    """Split a .pmw into GLB overhead, JSON, base and chunk bytes (from its own index)."""
    import json
    import struct

    from pmwm_codec.format import read_header

    json_len = struct.unpack_from("<I", data, 12)[0]
    gltf = json.loads(data[20 : 20 + json_len])
    ext = read_header(data).extension  # per-chunk entries (a version 2 chunk table expanded)
    bin_len = struct.unpack_from("<I", data, 20 + json_len)[0]
    chunk_views = {c["bufferView"] for c in ext["chunks"]}
    chunk_bytes = sum(c["byteLength"] for c in ext["chunks"])
    chunk_padded = sum(v["byteLength"] + (-v["byteLength"]) % 4 for i, v in enumerate(gltf["bufferViews"]) if i in chunk_views)
    base_bytes = bin_len - chunk_padded
    return {"glb_headers": 28, "json": json_len, "base": base_bytes, "chunks": chunk_bytes,
            "chunk_padding": chunk_padded - chunk_bytes, "total": len(data)}


# ----------------------------------------------------------------------------- one mesh
def bench_mesh(name, mesh, repeats, zstd_level, log):
    import DracoPy
    import fast_simplification

    n, m = mesh.vertex_count, mesh.face_count
    log(f"[{name}] {n} vertices, {m} faces, {repeats} repeats")
    res = {"name": name, "vertices": n, "faces": m, "repeats": repeats}

    # ours, encode at 14 bits (timed), no watermark, no measurement
    data = {}

    def ours_encode(bits=14):
        buf = io.BytesIO()
        rep = pmwm_codec.encode(mesh, buf, measure=False, grid_bits=bits, zstd_level=zstd_level,
                                payload_version=PAYLOAD_VERSION[0])
        data[bits] = buf.getvalue()
        return rep

    rep14 = ours_encode()  # warm-up (first calls load the compiled kernels; cold start is timed apart)
    rep16 = ours_encode(16)
    res["report14"], res["report16"] = rep14, rep16

    # fast-simplification to the same base face count, with the collapse record
    pts = np.ascontiguousarray(mesh.positions, np.float64)
    tri = np.ascontiguousarray(mesh.faces, np.int32)
    target_faces = int(rep14["base_faces"])

    def fs_run():
        return fast_simplification.simplify(pts, tri, target_count=target_faces, return_collapses=True)

    def ours_default():  # the user's default options: pmwm_codec.encode(mesh, dst), nothing else
        return pmwm_codec.encode(mesh, io.BytesIO())

    # the runs interleave (ours, peer, ours, peer, ...): on a shared machine both see the same load
    encodes = {"ours": ours_encode, "fs": fs_run, "ours16": lambda: ours_encode(16)}
    if n < 200_000:
        encodes["default"] = ours_default
    timed = interleaved(encodes, repeats)
    if n >= 200_000:  # the default report is costly on big meshes: one run, right after the others
        timed.update(interleaved({"default": ours_default}, 1))
    log(f"  encode runs: { {k: v[1] for k, v in timed.items()} }")
    fs_pts, fs_tri, fs_coll = timed["fs"][2]
    res.update(ours_encode=timed["ours"][0], ours_encode_all=timed["ours"][1], ours_encode16=timed["ours16"][0],
               fs=timed["fs"][0], fs_all=timed["fs"][1], fs_vertices=len(fs_pts), fs_faces=len(fs_tri),
               fs_collapses=len(fs_coll), target_faces=target_faces,
               ours_default=timed["default"][0], ours_default_all=timed["default"][1])

    # decode: ours (bytes in memory) vs DracoPy q14 cl7 of the full mesh
    blob = data[14]
    draco = DracoPy.encode(pts, tri, quantization_bits=14, compression_level=7)
    decodes = {"ours": lambda: pmwm_codec.decode(blob), "draco": lambda: DracoPy.decode(draco),
               "draco_encode": lambda: DracoPy.encode(pts, tri, quantization_bits=14, compression_level=7)}
    if PAYLOAD_VERSION[0] != 1:  # the same mesh at payload version 1, decoded in the same runs
        v1 = io.BytesIO()
        pmwm_codec.encode(mesh, v1, measure=False, grid_bits=14, zstd_level=zstd_level, payload_version=1)
        decodes["ours_v1"] = lambda: pmwm_codec.decode(v1.getvalue())
    for warm in decodes.values():  # first calls load the decoders' compiled kernels (as the encode warm-up above)
        warm()
    timed = interleaved(decodes, max(repeats, 5))
    if "ours_v1" in timed:
        res.update(ours_decode_v1=timed["ours_v1"][0], ours_decode_v1_all=timed["ours_v1"][1])
        log(f"  decode runs, payload v1: {timed['ours_v1'][1]}")
    dm, dmesh = timed["ours"][2], timed["draco"][2]
    assert dm.vertex_count == n and dm.face_count == m, (dm.vertex_count, dm.face_count)
    log(f"  decode runs: ours {timed['ours'][1]} draco {timed['draco'][1]}")
    res.update(ours_decode=timed["ours"][0], ours_decode_all=timed["ours"][1], draco_encode=timed["draco_encode"][0],
               draco_decode=timed["draco"][0], draco_decode_all=timed["draco"][1], draco_bytes=len(draco),
               draco_vertices=len(dmesh.points))
    res["peak"] = peak_memory(mesh, blob, draco, target_faces, log)

    # size and breakdown (grid 14 and 16)
    for bits in (14, 16):
        res[f"parts{bits}"] = glb_parts(data[bits])

    # profile: one more q14 encode with stage timers; the column breakdown needs the version 1 records
    # (version 2 is one range-coded stream, no columns), so with version 2 a version 1 encode of the same
    # batches is captured after the timed one
    with StageTimers() as st:
        t = time.perf_counter()
        pmwm_codec.encode(mesh, io.BytesIO(), measure=False, grid_bits=14, zstd_level=zstd_level,
                          payload_version=PAYLOAD_VERSION[0])
        total = time.perf_counter() - t
    if not st.packed_chunks:
        with StageTimers() as v1:
            pmwm_codec.encode(mesh, io.BytesIO(), measure=False, grid_bits=14, zstd_level=zstd_level,
                              payload_version=1)
        st.packed_chunks = v1.packed_chunks
    stages = dict(st.times)
    # pack_batches runs inside encode_document before assemble_document, which does the zstd compression
    res["profile"] = {"total": total, **stages}
    res["columns"] = column_breakdown(st.packed_chunks, zstd_level)
    res["residuals"] = residual_stats(st.packed_chunks)
    res["splits"] = sum(b.size for bs in st.packed_chunks for b in bs)
    res["batches"] = sum(len(bs) for bs in st.packed_chunks)
    batch_sizes = [b.size for bs in st.packed_chunks for b in bs]
    res["batch_sizes"] = batch_sizes

    # inside simplify: cProfile of one more encode, for the mesh's functions (small meshes only)
    if n < 200_000:
        res["simplify_profile"] = simplify_profile(mesh, zstd_level)

    # decode profile: parse/zstd vs apply (one run, manual loop over the decoder's stages)
    res["decode_profile"] = decode_profile(blob)
    return res


# ----------------------------------------------------------------------------- peak memory, cold start
PEAK_TASKS = ("ours encode", "ours decode", "fast-simplification", "Draco decode")


def peak_memory(mesh, blob: bytes, draco: bytes, target_faces: int, log) -> dict:
    """Peak memory of each task, each in a fresh subprocess: ``{task: (rss MB, traced MB or None)}``.

    RSS: the process's resident high-water mark (``VmHWM``, reset through ``/proc/self/clear_refs``
    just before the call) minus the resident size then (inputs and imports loaded), i.e. how far
    the call pushed the process above where it started (Linux).  Traced: ``tracemalloc`` peak during the call (numpy
    reports its buffers to tracemalloc; C libraries' own allocations are not seen), ours only.
    """
    import json
    import subprocess
    import tempfile

    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        np.savez(os.path.join(tmp, "mesh.npz"), v=mesh.positions, f=mesh.faces)
        for name, data in (("blob.pmw", blob), ("mesh.drc", draco)):
            with open(os.path.join(tmp, name), "wb") as fh:
                fh.write(data)
        for task in PEAK_TASKS:
            for traced in ((False, True) if task.startswith("ours") else (False,)):
                cmd = [sys.executable, os.path.abspath(__file__), "--peak-child", task, tmp, str(target_faces),
                       "--payload-version", str(PAYLOAD_VERSION[0])]
                run = subprocess.run(cmd + (["--traced"] if traced else []), capture_output=True, text=True,
                                     cwd=ROOT, env={**os.environ, "PYTHONPATH": ROOT})
                if run.returncode != 0:
                    raise RuntimeError(f"peak-memory child failed: {run.stderr.strip()[-500:]}")
                got = json.loads(run.stdout.strip().splitlines()[-1])
                rss, tr = out.get(task, (None, None))
                out[task] = (got["mb"], tr) if not traced else (rss, got["mb"])
    log(f"  peak memory (MB, rss / traced): {out}")
    return out


def peak_child(task: str, tmp: str, target_faces: int, traced: bool) -> None:
    """Run one :data:`PEAK_TASKS` task on the inputs in ``tmp``; print its peak memory as JSON.

    Ours runs once on a tiny mesh first (imports, numba's cached kernels), then the high-water
    mark is reset: the figure is the call's own working memory.
    """
    import json
    import tracemalloc

    d = np.load(os.path.join(tmp, "mesh.npz"))
    mesh = Mesh(d["v"], d["f"])
    blob = open(os.path.join(tmp, "blob.pmw"), "rb").read()
    draco = open(os.path.join(tmp, "mesh.drc"), "rb").read()
    pts, tri = np.ascontiguousarray(mesh.positions, np.float64), np.ascontiguousarray(mesh.faces, np.int32)
    import DracoPy
    import fast_simplification

    run = {
        "ours encode": lambda: pmwm_codec.encode(mesh, io.BytesIO()),
        "ours decode": lambda: pmwm_codec.decode(blob),
        "fast-simplification": lambda: fast_simplification.simplify(pts, tri, target_count=target_faces,
                                                                      return_collapses=True),
        "Draco decode": lambda: DracoPy.decode(draco),
    }[task]
    if task.startswith("ours"):  # imports and compiled kernels loaded on a tiny mesh, not measured
        from pmwm_codec.shapes import icosphere

        buf = io.BytesIO()
        pmwm_codec.encode(icosphere(2, 1.0), buf, payload_version=PAYLOAD_VERSION[0])
        pmwm_codec.decode(buf.getvalue())

    if traced:
        tracemalloc.start()
        run()
        mb = tracemalloc.get_traced_memory()[1] / 2**20
    else:
        # ru_maxrss survives exec (it holds the parent's peak): use this process's VmHWM, reset first
        with open("/proc/self/clear_refs", "w") as fh:
            fh.write("5")
        now = _proc_status_kb("VmRSS")
        run()
        mb = (_proc_status_kb("VmHWM") - now) / 1024
    print(json.dumps({"mb": mb}))


def _proc_status_kb(field: str) -> int:
    """A size field of /proc/self/status (Linux), in KB."""
    with open("/proc/self/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith(field + ":"))


def cold_start(corpus: str, log) -> dict:
    """Fresh-process ``pmw encode`` of the bunny (imports, numba kernels, encode, write), timed from outside.

    ``compile``: an empty numba cache (``NUMBA_CACHE_DIR`` a new directory), so every kernel compiles;
    ``cached``: the same directory again, kernels loaded from the cache.  Default options.
    """
    import subprocess
    import tempfile

    src = os.path.join(corpus, "stanford-bunny.obj")
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "PYTHONPATH": ROOT, "NUMBA_CACHE_DIR": os.path.join(tmp, "numba-cache")}
        for label in ("compile", "cached", "cached "):
            dst = os.path.join(tmp, "bunny.pmw")
            if os.path.exists(dst):
                os.remove(dst)
            t = time.perf_counter()
            run = subprocess.run([sys.executable, "-m", "pmwm_codec.cli", "encode", src, "-o", dst], env=env, cwd=ROOT,
                                 capture_output=True, text=True)
            dt = time.perf_counter() - t
            if run.returncode != 0:
                raise RuntimeError(f"pmw encode failed: {run.stderr.strip()[-500:]}")
            out.setdefault(label.strip(), []).append(dt)
    res = {"compile": out["compile"][0], "cached": statistics.median(out["cached"])}
    log(f"  cold start pmw encode: {res}")
    return res


def simplify_profile(mesh, zstd_level) -> list:
    """cProfile one q14 encode; (function, calls, cumulative s, own s) for simplify's parts."""
    import cProfile
    import pstats

    pr = cProfile.Profile()
    pr.enable()
    pmwm_codec.encode(mesh, io.BytesIO(), measure=False, grid_bits=14, zstd_level=zstd_level)
    pr.disable()
    st = pstats.Stats(pr).stats
    rows = []
    for (file, _, func), (cc, nc, tt, ct, _) in st.items():
        if file.endswith(("progressive/simplify.py", "progressive/topology.py", "progressive/livemesh.py")) or func in ("<method 'argsort' of 'numpy.ndarray' objects>", "<method 'reduceat' of 'numpy.ufunc' objects>"):
            rows.append((f"{os.path.basename(file)}:{func}" if file != "~" else func, nc, ct, tt))
    rows.sort(key=lambda r: -r[2])
    return rows[:10]


def decode_profile(blob: bytes) -> dict:
    """Time the decoder's parts on one full decode: container (digest + zstd), unpack, apply
    (payload version 2: unpacking is decoding against the mesh, counted in apply).  Positions only: a
    file whose primitive carries attributes is refused (its values and their prediction are not set up)."""
    from pmwm_codec.format import BaseEvent, ChunkEvent, ContainerParser, records_v2
    from pmwm_codec.format.extension import payload_version
    from pmwm_codec.progressive.vsplit import MeshState, apply_batch

    t0 = time.perf_counter()
    parser = ContainerParser()
    events = list(parser.feed(blob))
    parser.close()
    t_container = time.perf_counter() - t0
    header = events[0]
    ext = header.extension
    if ext.get("attributes"):
        raise ValueError("decode_profile: the stage breakdown is of meshes without attributes")
    t_unpack = t_apply = 0.0
    t = time.perf_counter()
    base = next(e for e in events if isinstance(e, BaseEvent))
    state = MeshState(base.positions_int, base.faces, int(ext["vertexCount"]), int(ext["faceCount"]))
    t_state = time.perf_counter() - t
    model = records_v2.ChunkDecoder() if payload_version(ext) == 2 else None
    for e in events:
        if isinstance(e, ChunkEvent) and model is not None:  # v2 decodes as it applies: all under "apply"
            t = time.perf_counter()
            for _ in records_v2.decode_chunk(e.payload, state, model):
                pass
            t_apply += time.perf_counter() - t
        elif isinstance(e, ChunkEvent):
            t = time.perf_counter()
            batches = records.unpack_batches(e.payload, max_splits=len(state.positions))
            t_unpack += time.perf_counter() - t
            t = time.perf_counter()
            for b in batches:
                apply_batch(state, b)
            t_apply += time.perf_counter() - t
    return {"container (GLB parse, Draco base, digests, zstd)": t_container, "state alloc": t_state,
            "unpack records": t_unpack, "apply splits": t_apply}


# ----------------------------------------------------------------------------- report
def render(results, info, command) -> str:
    L = []
    L.append(f"Command (from the repository root): `{command}`")
    L.append("")
    L.append(
        f"Machine: {info['cpu']}, {info['cores']} cores, Python {info['python']}, numpy {info['numpy']}, "
        f"DracoPy {info['DracoPy']}, fast-simplification {info['fast_simplification']}, "
        f"zstandard {info['zstandard']}; load average at start {info['load'][0]:.2f}. "
        f"Library: commit {info['git']}."
    )
    L.append("")
    L.append(
        "These machines are shared and noisy (the load average above says how busy this one was); "
        "ours and the peer alternate run by run, so each ratio compares "
        "runs made under the same load. Compare the ratios within one table, not absolute times. Times are medians "
        "(repeat counts in the table). `OPENBLAS_CORETYPE` is not set: nothing here goes through BLAS "
        "in a way that matters (the work is sorts, gathers, bincounts and zstd)."
    )
    L.append("")
    L.append("What is timed:")
    L.append("* ours encode: `pmwm_codec.encode(mesh, BytesIO(), measure=False, grid_bits=14)` on the mesh "
             "already in memory, no watermark (quantize, simplify, Draco base, split records, zstd, GLB);")
    L.append("* fast-simplification: `simplify(points, triangles, target_count=<our base face count>, "
             "return_collapses=True)`;")
    L.append("* ours decode: `pmwm_codec.decode(bytes)` of the whole q14 file in memory (GLB parse, Draco base, "
             f"digests, zstd, every split), chunk payload version {PAYLOAD_VERSION[0]};")
    L.append("* Draco: `DracoPy.decode` of `DracoPy.encode(points, faces, quantization_bits=14, "
             "compression_level=7)` of the full mesh.")
    L.append("")

    rows = []
    for r in results:
        enc_ratio = r["ours_encode"] / r["fs"]
        dec_ratio = r["ours_decode"] / r["draco_decode"]
        rows.append([
            r["name"], f"{r['vertices']:,}", r["repeats"],
            ms(r["ours_encode"]), f"{ms(r['fs'])} (to {r['fs_vertices']:,} V / {r['fs_faces']:,} F)",
            f"**{enc_ratio:.1f}x**" + (" (miss)" if enc_ratio > ENCODE_TARGET else " (ok)"),
            ms(r["ours_decode"]), ms(r["draco_decode"]),
            f"**{dec_ratio:.1f}x**" + (" (miss)" if dec_ratio > DECODE_TARGET else " (ok)"),
        ])
    L.append("### Time")
    L.append("")
    L.append(table(["mesh", "vertices", "repeats", "ours encode", "fast-simplification (collapses)",
                    f"encode ratio (target <= {ENCODE_TARGET:g}x)", "ours full decode", "Draco q14 cl7 decode",
                    f"decode ratio (target <= {DECODE_TARGET:g}x)"], rows))
    for r in results:
        if "ours_decode_v1" in r:
            L.append(f"* {r['name']}: chunk payload version {PAYLOAD_VERSION[0]} above; the same mesh at payload "
                     f"version 1, decoded in the same runs: {ms(r['ours_decode_v1'])}, "
                     f"{r['ours_decode_v1'] / r['draco_decode']:.1f}x Draco.")
    L.append("")
    rows = []
    for r in results:
        n = r["vertices"]
        rows.append([
            r["name"], f"{1e6 * r['ours_encode'] / n:.2f}", f"{1e6 * r['fs'] / n:.2f}",
            f"{1e6 * r['ours_decode'] / n:.3f}", f"{1e6 * r['draco_decode'] / n:.3f}",
            ms(r["draco_encode"]), ms(r["ours_encode16"]),
        ])
    L.append(table(["mesh", "ours encode µs/V", "fast-simpl. µs/V", "ours decode µs/V", "Draco decode µs/V",
                    "Draco q14 cl7 encode", "ours encode at grid 16"], rows))
    L.append("")
    rows = []
    for r in results:
        ratio = r["ours_default"] / r["fs"]
        rows.append([r["name"], len(r["ours_default_all"]), ms(r["ours_default"]), ms(r["fs"]),
                     f"**{ratio:.1f}x**" + (" (miss)" if ratio > ENCODE_TARGET else " (ok)")])
    L.append("Encode with the user's default options, `pmwm_codec.encode(mesh, dst)` (grid 16 and the default "
             "distortion report), against the same fast-simplification runs:")
    L.append("")
    L.append(table(["mesh", "runs", "ours encode, default options", "fast-simplification (collapses)",
                    f"ratio (target <= {ENCODE_TARGET:g}x)"], rows))
    L.append("")
    rows = []
    for r in results:
        for task in PEAK_TASKS:
            rss, traced = r["peak"][task]
            rows.append([r["name"], task, f"{rss:,.0f}", "" if traced is None else f"{traced:,.0f}"])
    L.append("Peak memory, each task alone in a fresh process (inputs loaded first; ours encode with default "
             "options): RSS = the resident high-water mark of the call (`VmHWM`, reset just before it) minus the resident size before it; traced = `tracemalloc` peak of the "
             "call (numpy buffers; ours only, the C peers allocate outside it). Imports and compiled kernels were "
             "loaded on a tiny mesh first:")
    L.append("")
    L.append(table(["mesh", "task", "peak RSS growth (MB)", "traced peak (MB)"], rows))
    L.append("")
    cold = info.get("cold")
    if cold:
        L.append(f"Fresh process, `python -m pmwm_codec.cli encode stanford-bunny.obj -o out.pmw` (default options, "
                 f"imports included): {cold['compile']:.2f} s with an empty numba cache (every kernel compiles), "
                 f"{cold['cached']:.2f} s with the kernels cached (median of 2).")
        L.append("")
    L.append("All runs (seconds): " + "; ".join(
        f"{r['name']}: encode {[round(x, 3) for x in r['ours_encode_all']]}, fast-simpl. "
        f"{[round(x, 3) for x in r['fs_all']]}, decode {[round(x, 4) for x in r['ours_decode_all']]}, "
        f"Draco decode {[round(x, 4) for x in r['draco_decode_all']]}" for r in results))
    L.append("")

    L.append("### Size")
    L.append("")
    rows = []
    for r in results:
        n = r["vertices"]
        d_bpv = 8 * r["draco_bytes"] / n
        for bits in (14, 16):
            b = r[f"report{bits}"]["bytes"]
            ratio = b / r["draco_bytes"]
            mark = ""
            if bits == 14:
                mark = " (miss)" if ratio > SIZE_TARGET else " (ok)"
            rows.append([r["name"], bits, f"{b:,}", f"{8 * b / n:.1f}", f"{r['draco_bytes']:,}", f"{d_bpv:.1f}",
                         f"**{ratio:.2f}x**{mark}"])
    L.append(table(["mesh", "grid bits", "ours bytes", "ours bpv", "Draco q14 cl7 bytes", "Draco bpv",
                    f"ratio (target <= {SIZE_TARGET:g}x at 14 bits)"], rows))
    L.append("")
    v2_note = ("" if PAYLOAD_VERSION[0] == 1 else
               " The file is payload version 2 (one range-coded stream per chunk, no columns); the column rows "
               "show the same batches coded as payload version 1, for reference (their shares and bits/vertex are "
               "against this file's size, so they add up to more than its chunk bytes).")
    L.append("Where our bytes go (grid 14). File parts come from the file's own index; payload columns are "
             "each column of every chunk compressed alone with the same zstd level (level "
             f"{ZSTD_LEVEL_USED[0]}), so their sum differs slightly from the stored chunks. "
             "Bits per split = column bits / splits." + v2_note)
    L.append("")
    for r in results:
        p = r["parts14"]
        n, k = r["vertices"], r["splits"]
        c = r["columns"]["compressed"]
        raw = r["columns"]["raw"]
        total = p["total"]
        rows = [
            ["GLB headers + JSON", f"{p['glb_headers'] + p['json']:,}", f"{100 * (p['glb_headers'] + p['json']) / total:.1f}%",
             f"{8 * (p['glb_headers'] + p['json']) / n:.2f}", "", ""],
            [f"base mesh (Draco, {r['report14']['base_vertices']:,} V)", f"{p['base']:,}",
             f"{100 * p['base'] / total:.1f}%", f"{8 * p['base'] / n:.2f}", "", ""],
            [f"split chunks as stored ({r['report14']['chunks']} chunks, payload v{PAYLOAD_VERSION[0]})", f"{p['chunks'] + p['chunk_padding']:,}",
             f"{100 * (p['chunks'] + p['chunk_padding']) / total:.1f}%", f"{8 * (p['chunks'] + p['chunk_padding']) / n:.2f}",
             f"{8 * p['chunks'] / k:.1f}", ""],
        ]
        for col in ("header+table", "gaps", "symbols", "residual_x", "residual_y", "residual_z"):
            label = f"&nbsp;&nbsp;column {col}" + ("" if PAYLOAD_VERSION[0] == 1 else " (as v1)")
            rows.append([label, f"{c[col]:,}", f"{100 * c[col] / total:.1f}%",
                         f"{8 * c[col] / n:.2f}", f"{8 * c[col] / k:.2f}", f"{8 * raw[col] / k:.1f}"])
        rows.append(["total file", f"{total:,}", "100%", f"{8 * total / n:.2f}", f"{8 * total / k:.1f}", ""])
        L.append(f"**{r['name']}** ({n:,} V, {k:,} splits in {r['batches']} batches):")
        L.append("")
        L.append(table(["part", "bytes", "share", "bits/vertex", "bits/split", "raw bits/split (before zstd)"], rows))
        s = r["residuals"]
        L.append("")
        L.append(
            f"Residuals (grid units): median |r| {s['median_abs']:.0f}, 90th percentile {s['p90_abs']:.0f}, max "
            f"{s['max_abs']}; order-0 entropy per axis {', '.join(f'{e:.2f}' for e in s['entropy_bits'])} bits "
            f"(sum {sum(s['entropy_bits']):.1f} bits/split). Symbols: {s['symbols_per_split']:.2f} per split, "
            f"order-0 entropy {s['symbol_entropy']:.2f} bits each "
            f"({s['symbols_per_split'] * s['symbol_entropy']:.1f} bits/split)."
        )
        L.append("")

    L.append("### Where the encode time goes (grid 14, one run with timers around the stages)")
    L.append("")
    rows = []
    for r in results:
        p = dict(r["profile"])
        p["pack_batches"] = p.get("pack_batches", 0.0) + p.pop("pack_chunks", 0.0)  # v1 or v2 payloads
        named = {"simplify": "simplify", "encode_base": "base (Draco encode + check)",
                 "build_progressive": "build records", "pack_batches": "pack payloads",
                 "assemble_document": "zstd + GLB assembly", "write_parts": "write"}
        other = p["total"] - sum(p.get(k, 0.0) for k in named)
        rows.append([r["name"], ms(p["total"])] + [f"{ms(p.get(k, 0.0))} ({100 * p.get(k, 0.0) / p['total']:.0f}%)" for k in named]
                    + [f"{ms(other)} ({100 * other / p['total']:.0f}%)"])
    L.append(table(["mesh", "total", "simplify", "base (Draco encode + check)", "build records", "pack payloads",
                    "zstd + GLB assembly", "write", "other (validate, quantize, grouping)"], rows))
    L.append("")
    for r in results:
        bs = r["batch_sizes"]
        n = r["vertices"]
        L.append(f"{r['name']}: {len(bs)} batches; batch yields (splits per batch, coarse to fine): "
                 f"{', '.join(str(x) for x in bs)}.")
        L.append("")
    for r in results:
        if r.get("simplify_profile"):
            L.append(f"Inside simplify, {r['name']} (cProfile of one more encode; cumulative time includes callees, "
                     "profiler overhead inflates the many small calls):")
            L.append("")
            L.append(table(["function", "calls", "cumulative", "own"],
                           [[f"`{f}`", c, ms(ct), ms(tt)] for f, c, ct, tt in r["simplify_profile"]]))
            L.append("")
    L.append("### Where the decode time goes (one run, same stages as the decoder)")
    L.append("")
    rows = []
    for r in results:
        d = r["decode_profile"]
        rows.append([r["name"]] + [ms(v) for v in d.values()])
    L.append(table(["mesh"] + list(results[0]["decode_profile"].keys()), rows))
    L.append("")
    return "\n".join(L)


ZSTD_LEVEL_USED = [10]
PAYLOAD_VERSION = [1]  # chunk payload version of our encodes (--payload-version)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default=DEFAULT_CORPUS)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--big-repeats", type=int, default=3)
    ap.add_argument("--no-big", action="store_true", help="skip the subdivided (~0.56M vertex) mesh")
    ap.add_argument("--huge", action="store_true",
                    help="also two copies of the subdivided bunny side by side (1.11M vertices: the ~1M-vertex mesh)")
    ap.add_argument("--zstd-level", type=int, default=10)
    ap.add_argument("--payload-version", type=int, choices=(1, 2), default=1,
                    help="chunk payload version of our timed encodes and decodes (2: also decode v1 in the same runs)")
    ap.add_argument("--write", metavar="MARKDOWN", help="replace the 'Engine' section of this file")
    ap.add_argument("--peak-child", nargs=3, metavar=("TASK", "DIR", "TARGET_FACES"), help=argparse.SUPPRESS)
    ap.add_argument("--traced", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    PAYLOAD_VERSION[0] = args.payload_version
    if args.peak_child:
        task, tmp, target = args.peak_child
        peak_child(task, tmp, int(target), args.traced)
        return
    ZSTD_LEVEL_USED[0] = args.zstd_level
    command = "python tools/bench.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    log = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    info = machine()
    log(f"machine: {info}")
    results = []
    for name, mesh in load_meshes(args.corpus, not args.no_big, args.huge):
        reps = args.repeats if mesh.vertex_count < 200_000 else args.big_repeats
        results.append(bench_mesh(name, mesh, reps, args.zstd_level, log))
    info["cold"] = cold_start(args.corpus, log)
    publish(render(results, info, command.strip()), args.write, SECTION, log)


def publish(md: str, path, section: str, log) -> None:
    """Print a rendered section and, with ``--write PATH``, replace that section of the Markdown file."""
    print(md)
    if path:
        replace_section(path, section, md)
        log(f"wrote section '{section}' of {path}")


if __name__ == "__main__":
    main()
