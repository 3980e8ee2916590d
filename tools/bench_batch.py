"""Batch benchmark: assets per second of ``pmw batch encode`` with 1 and 2 local Dask workers.

A folder of ``--assets`` equal-size generated meshes (``shapes.icosphere(--level)`` with a
different noise seed each, OBJ) is encoded with a ``--watermark-size`` checkerboard watermark
(a key beside each output) through :func:`pmwm_codec.batch.encode_batch` on a LocalCluster of
1, then 2, worker processes.  Per worker count: the cluster is started (time recorded), one
warm-up batch of one asset per worker starts each worker's encoder forkserver, then
``--repeats`` timed runs with ``force=True`` encode the whole folder; the table holds the
median assets per second and the scaling ratio (2 workers / 1 worker).  A baseline row
encodes the same folder with :func:`pmwm_codec.encode` in a loop in this process (no Dask,
no child processes): the price of the batch machinery on one worker.

Run from the repository root::

    python tools/bench_batch.py                        # print the Markdown section
    python tools/bench_batch.py --write BENCHMARKS.md  # also replace its "Batch" section
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

from bench import machine, publish, table  # noqa: E402

from pmwm_codec import shapes  # noqa: E402
from pmwm_codec.batch import encode_batch  # noqa: E402
from pmwm_codec.batch.run import dask_client  # noqa: E402
from pmwm_codec.meshio import write_mesh  # noqa: E402

SECTION = "Batch"


def make_library(folder: str, count: int, level: int) -> int:
    """``count`` OBJ icospheres of one size under ``folder``; returns the vertex count of each."""
    vertices = 0
    for i in range(count):
        mesh = shapes.icosphere(level, noise=0.01, seed=i + 1)
        write_mesh(os.path.join(folder, f"m{i:03d}.obj"), mesh)
        vertices = len(mesh.positions)
    return vertices


def run_workers(src: str, out: str, image, workers: int, repeats: int, log) -> dict:
    """Start a LocalCluster of ``workers``, warm it up, time ``repeats`` forced runs over ``src``."""
    t = time.perf_counter()
    with dask_client(workers=workers) as client:
        startup = time.perf_counter() - t
        warm = tempfile.mkdtemp(dir=os.path.dirname(out))
        for name in sorted(os.listdir(src))[:workers]:
            os.link(os.path.join(src, name), os.path.join(warm, name))
        encode_batch(warm, out + "-warm", watermark=image, client=client)
        rates = []
        for r in range(repeats):
            summary = encode_batch(src, out, watermark=image, client=client, force=True)
            if summary["ok"] != summary["assets"]:
                raise SystemExit(f"bench: {summary['assets'] - summary['ok']} assets failed: {summary['failures'][:1]}")
            rates.append(summary["assets"] / summary["seconds"])
            log(f"  {workers} worker(s), run {r + 1}: {rates[-1]:.2f} assets/s")
    return {"workers": workers, "startup": startup, "rates": rates, "median": statistics.median(rates)}


def run_in_process(src: str, out: str, image, repeats: int, log) -> dict:
    """The baseline without Dask or child processes: :func:`pmwm_codec.encode` in a loop, here."""
    import pmwm_codec

    os.makedirs(out, exist_ok=True)
    names = sorted(os.listdir(src))
    rates = []
    for r in range(repeats):
        t = time.perf_counter()
        for name in names:
            pmwm_codec.encode(os.path.join(src, name), os.path.join(out, name + ".pmw"), watermark=image)
        rates.append(len(names) / (time.perf_counter() - t))
        log(f"  in process, run {r + 1}: {rates[-1]:.2f} assets/s")
    return {"workers": "0 (pmwm_codec.encode in a loop)", "startup": 0.0, "rates": rates,
            "median": statistics.median(rates)}


def render(results, info, args, vertices, command, load_before, load_after) -> str:
    one = next(r for r in results if r["workers"] == 1)
    rows = [[r["workers"], f"{r['median']:.2f}", ", ".join(f"{x:.2f}" for x in r["rates"]),
             f"{r['median'] / one['median']:.2f}x", f"{r['startup']:.1f} s"] for r in results]
    return "\n".join([
        f"Command: `{command}` (commit {info['git']})",
        "",
        f"Machine: {info['cpu']}, {info['cores']} cores, Python {info['python']}, numpy {info['numpy']}; "
        f"load average {load_before[0]:.2f} before, {load_after[0]:.2f} after (1 min).",
        "",
        f"Job: {args.assets} OBJ icospheres of {vertices:,} vertices each, {args.watermark_size}x"
        f"{args.watermark_size} watermark, a key beside each output; {args.repeats} timed runs per worker "
        "count after a warm-up, `force=True` (every asset encoded; the cluster already up).",
        "",
        table(["workers", "median assets/s", "runs (assets/s)", "scaling vs 1 worker", "cluster start"], rows),
        "",
        "The load averages above say how busy the shared machine was: with other work on the 2 cores the "
        "2-worker figure and the ratio are noisy and understate the scaling of an idle machine. Row 0 is "
        "the same encodes in one process without Dask or a child process per asset: the gap to 1 worker "
        "is the price of isolation, a killable child forked per asset from a forkserver that has the "
        "encoder imported and its kernels compiled (`pmwm_codec/batch/warm.py`), plus Dask's per-task "
        "round trip and the ledger. Most of it is the encode itself running slower in a fresh child "
        "than in a long-lived process: every array faults in fresh memory pages, which a process that "
        "has encoded before reuses (a persistent encoder per worker would close it, at the price of "
        "isolation between assets). "
        "The client (scheduler, ledger) shares the 2 cores with the workers' encoders.",
    ])


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--assets", type=int, default=16)
    ap.add_argument("--level", type=int, default=4, help="icosphere subdivision level (4: 2,562 vertices)")
    ap.add_argument("--watermark-size", type=int, default=16)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--write", metavar="BENCHMARKS.md")
    args = ap.parse_args(argv)
    command = "python tools/bench_batch.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    info = machine()
    load_before = os.getloadavg()
    image = (np.indices((args.watermark_size,) * 2).sum(0) % 2 * 255).astype(np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        src = os.path.join(tmp, "src")
        os.makedirs(src)
        vertices = make_library(src, args.assets, args.level)
        results = [run_in_process(src, os.path.join(tmp, "out0"), image, args.repeats, log)]
        results += [run_workers(src, os.path.join(tmp, f"out{w}"), image, w, args.repeats, log) for w in (1, 2)]
    publish(render(results, info, args, vertices, command.strip(), load_before, os.getloadavg()),
            args.write, SECTION, log)


if __name__ == "__main__":
    main()
