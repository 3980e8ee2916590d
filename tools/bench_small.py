"""Small meshes on the command line: ``pmw encode`` / ``pmw decode`` in a fresh process, with and without numba.

A one-shot ``pmw`` process runs a job below ``SMALL_JOB_VERTICES`` vertices on the numpy / Python
twins of the kernels (:func:`pmwm_codec.progressive.topology.job_vertices`): numba's start-up in a
fresh process (its import, its target context, loading the cached kernels) costs more than its
kernels save on a small mesh.  This tool measures that trade on each mesh, in fresh processes as a
user runs them (imports, reading, writing included), the two ways interleaved run by run:

* **as shipped** -- ``pmw encode MESH -o X.pmw -q`` then ``pmw decode X.pmw -o X.obj``;
* **numba always** -- the same commands with ``SMALL_JOB_VERTICES`` set to 0 in the process
  (every job on numba, from its on-disk cache: warmed before the runs).

It checks that both ways write the same bytes, and reports medians, the ratio and the peak RSS
(``ru_maxrss`` of the child).  Meshes: the corpus meshes under ``--max-vertices`` (default 8,000;
``../shared/corpus``, skipped when absent) and generated icospheres of 642 / 2,562 / 10,242 vertices.

    python tools/bench_small.py [--repeats 5] [--write BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from pmwm_codec import read_mesh, shapes, write_mesh  # noqa: E402
from pmwm_codec.progressive.topology import SMALL_JOB_VERTICES  # noqa: E402
from tools.bench import DEFAULT_CORPUS, machine, publish, run_header, table  # noqa: E402

SECTION = "Small meshes on the command line"
#: ``pmw`` as the console script runs it, with the policy's threshold set first (argv[1]).
RUNNER = ("import sys; import pmwm_codec.progressive.topology as t; t.SMALL_JOB_VERTICES = int(sys.argv.pop(1)); "
          "from pmwm_codec.cli import main; sys.exit(main())")


def child(threshold, *args) -> float:
    """Run ``pmw ARGS`` in a fresh process with the policy's threshold; its wall time in seconds."""
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", RUNNER, str(threshold), *map(str, args)], check=True,
                   stdout=subprocess.DEVNULL, cwd=ROOT)
    return time.perf_counter() - t


def meshes(corpus: str, max_vertices: int, tmp: str) -> list:
    out = []
    if os.path.isdir(corpus):
        for name in sorted(os.listdir(corpus)):
            if name.endswith(".obj"):
                mesh = read_mesh(os.path.join(corpus, name))
                if mesh.vertex_count <= max_vertices:
                    out.append((name[:-4], os.path.join(corpus, name), mesh.vertex_count))
    for level in (3, 4, 5):
        mesh = shapes.icosphere(level, 1.0, noise=0.01)
        path = os.path.join(tmp, f"icosphere{level}.obj")
        write_mesh(path, mesh)
        out.append((f"generated icosphere({level})", path, mesh.vertex_count))
    return sorted(out, key=lambda m: m[2])


def measure(path: str, repeats: int, tmp: str) -> dict:
    ways = {"shipped": SMALL_JOB_VERTICES, "numba": 0}
    runs = {w: {"encode": [], "decode": []} for w in ways}
    rss = {w: 0.0 for w in ways}
    for w, th in ways.items():  # warm the numba cache and the OS file cache once each way
        child(th, "encode", path, "-o", os.path.join(tmp, f"{w}.pmw"), "-q")
    for _ in range(repeats):
        for w, th in ways.items():
            pmw, obj = os.path.join(tmp, f"{w}.pmw"), os.path.join(tmp, f"{w}.obj")
            for step, args in (("encode", ("encode", path, "-o", pmw, "-q")), ("decode", ("decode", pmw, "-o", obj))):
                runs[w][step].append(child(th, *args))
    for w, th in ways.items():  # peak RSS: one more encode each way, in a parent of its own (ru_maxrss of children)
        code = (f"import resource, subprocess, sys; subprocess.run([sys.executable, '-c', {RUNNER!r}, '{th}', 'encode', "
                f"{path!r}, '-o', {os.path.join(tmp, 'rss.pmw')!r}, '-q'], check=True); "
                "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
        rss[w] = int(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                                    cwd=ROOT).stdout.strip()) / 1024
    same = all(open(os.path.join(tmp, f"shipped.{ext}"), "rb").read() == open(os.path.join(tmp, f"numba.{ext}"), "rb").read()
               for ext in ("pmw", "obj"))
    return {"runs": runs, "rss": rss, "same": same,
            "median": {w: {s: statistics.median(v) for s, v in r.items()} for w, r in runs.items()}}


def render(results, info, command, repeats) -> str:
    L = run_header(command, info) + [
         "Each cell: a fresh `pmw` process as a user runs it (imports, reading, writing), median of "
         f"{repeats}, the two ways interleaved run by run. As shipped, a job under {SMALL_JOB_VERTICES:,} vertices "
         "runs the kernels' numpy twins (numba's start-up is not paid); \"numba always\" sets that threshold to 0 "
         "(kernels from the warm on-disk cache). Same bytes: the `.pmw` and the decoded OBJ of both ways compared "
         "byte for byte. Peak RSS: one more encode each way.", ""]
    rows = []
    for name, v, r in results:
        m = r["median"]
        rows.append([name, f"{v:,}", "plain" if v < SMALL_JOB_VERTICES else "numba",
                     f"{m['shipped']['encode']:.2f} s", f"{m['numba']['encode']:.2f} s",
                     f"{m['shipped']['encode'] / m['numba']['encode']:.2f}x",
                     f"{m['shipped']['decode']:.2f} s", f"{m['numba']['decode']:.2f} s",
                     f"{m['shipped']['decode'] / m['numba']['decode']:.2f}x",
                     f"{r['rss']['shipped']:.0f} / {r['rss']['numba']:.0f} MB", "yes" if r["same"] else "**NO**"])
    L.append(table(["mesh", "vertices", "kernels as shipped", "encode as shipped", "encode, numba always", "ratio",
                    "decode as shipped", "decode, numba always", "ratio", "encode peak RSS (shipped / numba)",
                    "same bytes"], rows))
    L += ["", "All runs (seconds, encode then decode, as shipped | numba always): " + "; ".join(
        f"{name}: {[round(x, 2) for x in r['runs']['shipped']['encode']]} {[round(x, 2) for x in r['runs']['shipped']['decode']]}"
        f" | {[round(x, 2) for x in r['runs']['numba']['encode']]} {[round(x, 2) for x in r['runs']['numba']['decode']]}"
        for name, _, r in results)]
    return "\n".join(L) + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--corpus", default=DEFAULT_CORPUS)
    ap.add_argument("--max-vertices", type=int, default=8000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--write", metavar="MARKDOWN", help=f"replace the '{SECTION}' section of this file")
    args = ap.parse_args(argv)
    command = "python tools/bench_small.py " + " ".join(shlex.quote(a) for a in (argv if argv is not None else sys.argv[1:]))
    info = machine()
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, path, v in meshes(args.corpus, args.max_vertices, tmp):
            print(f"[{name}] {v:,} vertices", file=sys.stderr, flush=True)
            results.append((name, v, measure(path, args.repeats, tmp)))
    publish(render(results, info, command.strip(), args.repeats), args.write, SECTION,
            lambda s: print(s, file=sys.stderr))


if __name__ == "__main__":
    main()
