"""The owner layer through the real tools assets go through: gltf-transform and gltfpack, run as users run them.

``tools/owner_attacks.py`` simulates transport (quantization grids, Draco through DracoPy, re-ordering); this
benchmark runs the tools themselves on the GLB that ``pmw decode`` writes, and reads the result back with the
command line only, as a user would:

    pmw encode MESH -o m.pmw --owner-id HEX --key k.json      (no watermark: the owner layer alone)
    pmw decode m.pmw -o m.glb
    <tool> m.glb out.glb                                     (each pipeline of :data:`PIPELINES`)
    pmw verify out.glb --key k.json --json                    (the owner's bit errors and verdict)

The same pipelines run on the unmarked mesh (its GLB written by trimesh) and are read with each key: every
such read must say ``absent`` (a false ``present`` would be a false alarm).  gltf-transform comes from
``js/`` (``npm ci --prefix js``), gltfpack from ``tools/js`` (``npm ci --prefix tools/js``); a pipeline whose
tool is not installed is reported as skipped.

    python tools/owner_realtools.py [--meshes A.obj ...] [--heldout DIR] [--keys 3] [--write BENCHMARKS.md]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
HERE = os.path.dirname(os.path.abspath(__file__))
for path in (ROOT, HERE):
    if path not in sys.path:
        sys.path.insert(0, path)

from pmwm_codec.cli import main as pmw  # noqa: E402

from bench import DEFAULT_CORPUS, machine, publish, run_header, table  # noqa: E402

SECTION = "Owner layer through real tools (gltf-transform, gltfpack)"
TOOLS = {
    "gltf-transform": os.path.join(ROOT, "js", "node_modules", ".bin", "gltf-transform"),
    "gltfpack": os.path.join(ROOT, "tools", "js", "node_modules", ".bin", "gltfpack"),
}
#: (name, tool, arguments between the input and the output; ``{i}`` / ``{o}`` the files).
PIPELINES = (
    ("gltf-transform draco (defaults)", "gltf-transform", "draco {i} {o}"),
    ("gltf-transform quantize (defaults: 14-bit positions)", "gltf-transform", "quantize {i} {o}"),
    ("gltf-transform weld + reorder", "gltf-transform", "weld {i} {t} && reorder {t} {o}"),
    ("gltf-transform simplify --ratio 0.5 --error 0.01", "gltf-transform", "simplify {i} {o} --ratio 0.5 --error 0.01"),
    ("gltf-transform simplify --ratio 0.25 --error 0.01", "gltf-transform", "simplify {i} {o} --ratio 0.25 --error 0.01"),
    ("gltf-transform optimize --compress draco", "gltf-transform", "optimize {i} {o} --compress draco"),
    ("gltf-transform optimize --compress quantize", "gltf-transform", "optimize {i} {o} --compress quantize"),
    ("gltf-transform meshopt (EXT_meshopt_compression)", "gltf-transform", "meshopt {i} {o}"),
    ("gltfpack (defaults: 14-bit positions, re-ordered)", "gltfpack", "-i {i} -o {o}"),
    ("gltfpack -vp 10 (10-bit positions)", "gltfpack", "-i {i} -o {o} -vp 10"),
    ("gltfpack -vp 8 (8-bit positions)", "gltfpack", "-i {i} -o {o} -vp 8"),
    ("gltfpack -si 0.5 (simplified to half)", "gltfpack", "-i {i} -o {o} -si 0.5"),
    ("gltfpack -si 0.3", "gltfpack", "-i {i} -o {o} -si 0.3"),
    ("gltfpack -si 0.1", "gltfpack", "-i {i} -o {o} -si 0.1"),
    ("gltfpack -cc (meshopt compression)", "gltfpack", "-i {i} -o {o} -cc"),
)


def run_tool(tool: str, args: str, src: str, dst: str, tmp: str) -> str | None:
    """Run one pipeline (steps joined by ``&&``); None on success, else the failing step's last line of output."""
    steps = args.format(i=shlex.quote(src), o=shlex.quote(dst), t=shlex.quote(os.path.join(tmp, "step.glb")))
    for step in steps.split(" && "):
        done = subprocess.run([TOOLS[tool], *shlex.split(step)], capture_output=True, text=True, timeout=600)
        if done.returncode != 0:
            lines = (done.stderr or done.stdout).strip().splitlines()
            return lines[-1] if lines else f"exit {done.returncode}"
    return None if os.path.exists(dst) else "wrote no output"


def pmw_json(*argv) -> tuple:
    """``(exit status, JSON document or None, stderr's last line)`` of ``pmw *argv`` run in this process."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = pmw(list(argv))
        except SystemExit as exc:
            code = exc.code
    try:
        doc = json.loads(out.getvalue())
    except ValueError:
        doc = None
    lines = err.getvalue().strip().splitlines()
    return code, doc, lines[-1] if lines else ""


def write_plain_glb(mesh_path: str, dst: str) -> None:
    import trimesh

    m = trimesh.load(mesh_path, force="mesh", process=False)
    m.export(dst)


def measure(mesh_path: str, keys: int, log, pipelines=PIPELINES) -> dict:
    """``{"name", "rows": {pipeline name: {"errors": [bit errors per key], "present", "vertices", "failed",
    "absent_unmarked", "unmarked_reads", "unmarked_fewest"}}}`` of ``pipelines`` on the mesh file."""
    name = os.path.splitext(os.path.basename(mesh_path))[0]
    rows = {p[0]: {"errors": [], "present": 0, "vertices": [], "failed": None, "absent_unmarked": 0,
                   "unmarked_reads": 0, "unmarked_fewest": None} for p in pipelines}
    rng = np.random.default_rng(20261203)
    with tempfile.TemporaryDirectory() as tmp:
        plain = os.path.join(tmp, "unmarked.glb")
        write_plain_glb(mesh_path, plain)
        for k in range(keys):
            owner_hex = f"{int(rng.integers(0, 2**63)):016x}"
            pmw_file, key, glb = (os.path.join(tmp, f) for f in (f"m{k}.pmw", f"k{k}.json", f"m{k}.glb"))
            code, _, err = pmw_json("encode", mesh_path, "-o", pmw_file, "--owner-id", owner_hex, "--key", key, "-q")
            if code != 0:
                raise SystemExit(f"{name}: encode failed: {err}")
            code, _, err = pmw_json("decode", pmw_file, "-o", glb, "-q")
            if code != 0:
                raise SystemExit(f"{name}: decode failed: {err}")
            for pname, tool, args in pipelines:
                row = rows[pname]
                if not os.path.exists(TOOLS[tool]):
                    row["failed"] = f"{tool} not installed"
                    continue
                for src, marked in ((glb, True), (plain, False)):
                    out = os.path.join(tmp, "out.glb")
                    if os.path.exists(out):
                        os.remove(out)
                    why = run_tool(tool, args, src, out, tmp)
                    if why is not None:
                        row["failed"] = f"{tool}: {why}"
                        continue
                    code, doc, err = pmw_json("verify", out, "--key", key, "--json")
                    if doc is None or "owner" not in doc:
                        row["failed"] = f"pmw verify: {err or f'exit {code}'}"
                        continue
                    o = doc["owner"]
                    if marked:
                        row["errors"].append(o["bit_errors"])
                        row["present"] += o["verdict"] == "present"
                        row["vertices"].append(doc["vertices"])
                    else:
                        row["unmarked_reads"] += 1
                        row["absent_unmarked"] += o["verdict"] == "absent"
                        fewest = row["unmarked_fewest"]
                        row["unmarked_fewest"] = o["bit_errors"] if fewest is None else min(fewest, o["bit_errors"])
            log(f"[{name}] key {k + 1}/{keys} done")
    return {"name": name, "rows": rows}


def render(results, keys: int, command: str, info: dict, pipelines=PIPELINES) -> str:
    lines = run_header(command, info) + [
             "Each mesh is encoded with the owner layer alone (`pmw encode MESH --owner-id HEX`, a new random ID and "
             f"key each time; keys: {keys}), decoded to GLB (`pmw decode`), passed through the tool as a user runs "
             "it, and read back with `pmw verify OUT.glb --key K --json`. Cells: BER over the keys (bit errors / 64, "
             "mean), `present` count, vertices read. The unmarked mesh goes through the same pipeline and is read "
             "with every key: the last column counts `absent` verdicts and the fewest bit errors seen.", ""]
    header = ["pipeline"] + [f"{r['name']}: BER (present), vertices" for r in results] + ["unmarked: absent, fewest errors"]
    body = []
    for pname, _, _ in pipelines:
        cells, ua, ur, fewest, failed = [], 0, 0, [], None
        for r in results:
            row = r["rows"][pname]
            failed = failed or row["failed"]
            if row["errors"]:
                cells.append(f"{np.mean(row['errors']) / 64:.3f} ({row['present']}/{len(row['errors'])}), "
                             f"{int(np.median(row['vertices'])):,} V")
            else:
                cells.append(f"not read: {row['failed']}")
            ua += row["absent_unmarked"]
            ur += row["unmarked_reads"]
            if row["unmarked_fewest"] is not None:
                fewest.append(row["unmarked_fewest"])
        body.append([pname] + cells + [f"{ua}/{ur}, {min(fewest) if fewest else '-'}"])
    lines.append(table(header, body))
    return "\n".join(lines) + "\n"


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--meshes", nargs="*", default=[os.path.join(DEFAULT_CORPUS, "stanford-bunny.obj")])
    ap.add_argument("--heldout", help="a folder with snowden.obj, dragon23k.obj, dragon100k.obj (tools/heldout.py)")
    ap.add_argument("--keys", type=int, default=3)
    ap.add_argument("--write", metavar="BENCHMARKS.md")
    args = ap.parse_args(argv)
    meshes = list(args.meshes)
    if args.heldout:
        meshes += [os.path.join(args.heldout, f) for f in ("snowden.obj", "dragon23k.obj", "dragon100k.obj")]

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    t0 = time.perf_counter()
    results = [measure(m, args.keys, log) for m in meshes]
    command = "python tools/owner_realtools.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    md = render(results, args.keys, command.strip(), machine())
    log(f"{time.perf_counter() - t0:.0f} s")
    publish(md, args.write, SECTION, log)


if __name__ == "__main__":
    main()
