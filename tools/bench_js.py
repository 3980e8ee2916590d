"""JavaScript decoder benchmark: js/ full decode in Node vs draco3d's decode of the same full mesh.

For each mesh: encode it with pmwm_codec (grid 14, Draco base, no watermark) and with DracoPy
(quantization 14, compression level 7, the full mesh: the same settings as tools/bench.py's Draco
column), then run ``node js/bench/bench.mjs`` (one warm-up each, then REPEATS alternating runs of
``decodePmw`` and of draco3d ``DecodeBufferToMesh`` + array copies) and report medians; then
``node js/bench/stages.mjs --cpu`` splits the JS decode into its stages (CPU time per stage).

    python tools/bench_js.py [--big | --huge] [--repeats N] [--payload-version {1,2}] [--write BENCHMARKS.md]

``--payload-version`` defaults to 2, what ``pmw encode`` writes; each version's run replaces its own
section of BENCHMARKS.md (``SECTIONS``).

Meshes: ``stanford-bunny.obj`` from ``../shared/corpus`` and, with ``--big``, the bunny
midpoint-subdivided twice (556k vertices), as in tools/bench.py; ``--huge`` adds two copies
of that side by side (1.11M vertices).  Needs node and ``npm ci --prefix js``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

import DracoPy

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import pmwm_codec  # noqa: E402
from tools.bench import load_meshes, ms, publish, table  # noqa: E402

#: The section each chunk payload version's run replaces (version 2 is what ``pmw encode`` writes).
SECTIONS = {1: "JavaScript decoder", 2: "JavaScript decoder: payload version 2 (the default)"}


def run_mesh(name: str, mesh, repeats: int, tmp: Path, payload_version: int = 1) -> dict:
    """Encode ``mesh`` both ways into ``tmp`` (chunk payload ``payload_version``) and time the two
    decoders in Node; the bench.mjs JSON."""
    pmw, drc = tmp / "mesh.pmw", tmp / "mesh.drc"
    pmwm_codec.encode(mesh, str(pmw), measure=False, grid_bits=14, payload_version=payload_version)
    drc.write_bytes(DracoPy.encode(mesh.positions, mesh.faces, quantization_bits=14, compression_level=7))
    out = subprocess.run(["node", str(ROOT / "js" / "bench" / "bench.mjs"), str(pmw), str(drc), str(repeats)],
                         capture_output=True, text=True, check=True)
    result = json.loads(out.stdout)
    stages = subprocess.run(["node", str(ROOT / "js" / "bench" / "stages.mjs"), str(pmw), str(repeats), "--cpu"],
                            capture_output=True, text=True, check=True)
    result.update(name=name, pmw_bytes=pmw.stat().st_size, drc_bytes=drc.stat().st_size,
                  stages=json.loads(stages.stdout))
    return result


#: stages.mjs keys, in decode order, with what each one is (libraries named).
STAGES = [
    ("plan", "GLB preamble + JSON plan"),
    ("base", "Draco base mesh (draco3d) + grid mapping"),
    ("blake2b", "chunk digests, BLAKE2b-128 (hash-wasm)"),
    ("zstd", "zstd frame walk + decompression and XXH64 content checksum (zstddec)"),
    ("unpack", "payload columns -> split vertices, symbols, residuals"),
    ("splits", "vertex splits (incidences, new faces, predicted values)"),
    ("rangecoded", "payload version 2: range-coded chunks decoded into the mesh, splits included"),
    ("decode", "whole PmwDecoder feed + close"),
    ("snapshot", "snapshot(): output arrays"),
]


def render_stages(results: list) -> str:
    """The per-stage CPU-time table of stages.mjs, one column per mesh."""
    rows = [[key, what] + [ms(r["stages"][key]) for r in results] for key, what in STAGES
            if any(key in r["stages"] for r in results)]
    return table(["stage", "what"] + [r["name"] for r in results], rows)


def render(results: list, command: str, load: float, payload_version: int) -> str:
    rows = []
    for r in results:
        ours, draco = statistics.median(r["pmw"]), statistics.median(r["draco"])
        ratio = ours / draco
        rows.append([r["name"], f"{r['vertices']:,}", len(r["pmw"]), ms(ours), ms(draco),
                     f"**{ratio:.1f}x** ({'met' if ratio <= 3 else 'miss'})",
                     f"{r['pmw_bytes']:,} / {r['drc_bytes']:,}"])
    runs = "; ".join(f"{r['name']}: decodePmw {[round(t, 4) for t in r['pmw']]}, draco3d {[round(t, 4) for t in r['draco']]}"
                     for r in results)
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    dirty = subprocess.run(["git", "status", "--porcelain", "js/src"], capture_output=True, text=True, cwd=ROOT).stdout.strip()
    node = results[0]["node"] if results else "?"
    return "\n".join([
        f"Command (from the repository root): `{command}`",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, Node {node}; load average "
        f"at start {load:.2f}. Decoder: commit {commit or '?'}{' with uncommitted js/src changes' if dirty else ''}. The machine is shared (the load average says how busy it was): "
        "compare the ratio within a row, not absolute times.",
        "",
        "What is timed (medians; one warm-up run each first, module instantiation not timed): "
        f"`decodePmw(bytes)` of the whole grid-14 .pmw (chunk payload version {payload_version}) in memory (js/: GLB "
        "plan, Draco base through draco3d, BLAKE2b digests, "
        f"{'zstd' if payload_version == 1 else 'the range-coded chunks'}, every split) vs draco3d's `DecodeBufferToMesh` of "
        "`DracoPy.encode(points, faces, quantization_bits=14, compression_level=7)` of the full mesh, positions "
        "and indices copied out. Done-when 3 of issue 15 asks for at most 3x.",
        "",
        table(["mesh", "vertices", "repeats", "JS decodePmw", "draco3d decode", "ratio (target <= 3x)",
               ".pmw / .drc bytes"], rows),
        "",
        f"All runs (seconds): {runs}",
        "",
        "Stages of the JS decode (`node js/bench/stages.mjs FILE.pmw REPEATS --cpu`: medians of this process's "
        "CPU time per stage over the same number of runs after one warm-up; the stage rows are timed in one "
        "loop that does what PmwDecoder does, `decode` and `snapshot` through PmwDecoder itself):",
        "",
        render_stages(results),
    ])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--corpus", default=str(ROOT.parent / "shared" / "corpus"))
    ap.add_argument("--big", action="store_true", help="also the bunny subdivided twice (556k vertices)")
    ap.add_argument("--huge", action="store_true",
                    help="also two copies of the subdivided bunny side by side (1.11M vertices; implies --big)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--payload-version", type=int, choices=(1, 2), default=2,
                    help="chunk payload version of the encoded .pmw (spec/bitstream.md §6 or §8; default 2, what "
                         "pmw encode writes)")
    ap.add_argument("--write", metavar="PATH", help="replace this payload version's section of this Markdown file "
                                                    f"({' / '.join(repr(s) for s in SECTIONS.values())})")
    args = ap.parse_args()
    args.big = args.big or args.huge
    command = "python tools/bench_js.py" + (" --huge" if args.huge else " --big" if args.big else "") + (
        f" --repeats {args.repeats}") + f" --payload-version {args.payload_version}" + (
        f" --write {args.write}" if args.write else "")
    load = os.getloadavg()[0]
    print(f"load average at start: {load:.2f}", file=sys.stderr)
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, mesh in load_meshes(args.corpus, args.big, args.huge):
            results.append(run_mesh(name, mesh, args.repeats if mesh.vertex_count < 200_000 else 3, Path(tmp),
                                    args.payload_version))
    publish(render(results, command, load, args.payload_version), args.write, SECTIONS[args.payload_version],
            lambda msg: print(msg, file=sys.stderr))


if __name__ == "__main__":
    main()
