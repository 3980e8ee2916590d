"""Big text meshes: peak memory and time of reading and writing a big torus as OBJ / PLY, and of `pmw encode` /
`pmw decode` of it.

Makes, in a temporary folder (or ``--dir``), a torus of ``--vertices`` positions (default 1,000,000) with normals
and texture coordinates: an OBJ of ``v`` / ``vt`` / ``vn`` records and ``f a/b/c`` corners (a scanned heritage
asset's layout), an ASCII PLY (``x y z nx ny nz s t``), a binary one, and ``big.pmw`` encoded from the binary PLY.
Then runs each operation in a fresh Python process, ``--repeats`` times (default 3), and reports the median of its
peak resident memory (``os.wait4``'s ru_maxrss) and of its wall time: ``read_mesh`` and ``meshdoc.read_source``
(the encoder's reader) of each file, ``pmw encode`` of the OBJ, ``pmw decode big.pmw -o out.{glb,ply,obj}``; and
the SHA-256 of what the commands write, so that two runs tell whether the bytes changed.

    python tools/bench_textmesh.py [--vertices N] [--repeats R] [--code-root DIR] [--dir DIR] [--write BENCHMARKS.md]

``--code-root``: the checkout whose ``pmwm_codec`` the operations import (default this one): run it with two
roots, over one ``--dir``, to compare two versions of the code on the same files.  ``--write`` replaces the
section ``SECTION`` of that Markdown file.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tools"))

from bench import git_state, machine, publish, run_header, table  # noqa: E402

SECTION = "Reading and writing big text meshes"


def torus(vertices: int) -> tuple:
    """``(positions (n, 3), normals (n, 3), uv (n, 2) float64, triangles (2n, 3) int64)`` of a torus of about
    ``vertices`` positions (rings x sides, rings = 2 sides), each position its own normal and texture
    coordinate."""
    sides = max(3, int(round((vertices / 2) ** 0.5)))
    rings = max(3, vertices // sides)
    u, w = np.meshgrid(np.arange(rings) * 2 * np.pi / rings, np.arange(sides) * 2 * np.pi / sides, indexing="ij")
    u, w = u.reshape(-1), w.reshape(-1)
    normals = np.stack([np.cos(w) * np.cos(u), np.cos(w) * np.sin(u), np.sin(w)], 1)
    positions = normals + np.stack([2 * np.cos(u), 2 * np.sin(u), np.zeros_like(u)], 1)
    uv = np.stack([u / (2 * np.pi), w / (2 * np.pi)], 1)
    i, j = np.meshgrid(np.arange(rings), np.arange(sides), indexing="ij")
    a, b = (i * sides + j).reshape(-1), (((i + 1) % rings) * sides + j).reshape(-1)
    c, d = (((i + 1) % rings) * sides + (j + 1) % sides).reshape(-1), (i * sides + (j + 1) % sides).reshape(-1)
    return positions, normals, uv, np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])


def write_obj(path, positions, normals, uv, triangles) -> None:
    """An OBJ of ``v`` / ``vt`` / ``vn`` records and ``f a/a/a`` corners (a scanned asset's layout) at ``path``:
    ``positions``, ``normals`` (n, 3), ``uv`` (n, 2) float64, ``triangles`` (m, 3) int64, 0-based."""
    with open(path, "w") as fh:
        np.savetxt(fh, positions, "v %.6f %.6f %.6f")
        np.savetxt(fh, uv, "vt %.6f %.6f")
        np.savetxt(fh, normals, "vn %.6f %.6f %.6f")
        np.savetxt(fh, np.repeat(triangles + 1, 3, axis=1), "f %d/%d/%d %d/%d/%d %d/%d/%d")


def write_meshes(folder: Path, vertices: int, code_root: Path) -> dict:
    """Write the test files into ``folder`` (those already there are kept) and return {label: path}."""
    files = {k: folder / f for k, f in (("OBJ", "big.obj"), ("ASCII PLY", "big_ascii.ply"),
                                         ("binary PLY", "big_binary.ply"), ("pmw", "big.pmw"))}
    if all(p.exists() for p in files.values()):
        return files
    pos, nrm, uv, tri = torus(vertices)
    n, m = len(pos), len(tri)
    write_obj(files["OBJ"], pos, nrm, uv, tri)
    head = ["ply", "format {} 1.0", f"element vertex {n}"] + [f"property float {p}" for p in
                                                              ("x", "y", "z", "nx", "ny", "nz", "s", "t")]
    head += [f"element face {m}", "property list uchar int vertex_indices", "end_header", ""]
    rows = np.concatenate([pos, nrm, uv], 1)
    with open(files["ASCII PLY"], "w") as fh:
        fh.write("\n".join(head).format("ascii"))
        np.savetxt(fh, rows, "%.6f")
        np.savetxt(fh, tri, "3 %d %d %d")
    face = np.zeros(m, [("n", "u1"), ("i", "<i4", 3)])
    face["n"], face["i"] = 3, tri
    with open(files["binary PLY"], "wb") as fh:
        fh.write("\n".join(head).format("binary_little_endian").encode())
        fh.write(rows.astype("<f4").tobytes() + face.tobytes())
    subprocess.run(command("encode", str(files["binary PLY"]), "-o", str(files["pmw"]), "-q"), check=True,
                   env=environment(code_root), cwd=code_root)
    return files


def environment(code_root: Path) -> dict:
    """The environment of a measured process: ``code_root``'s package first (its working folder too, which
    ``python -m`` / ``-c`` put first on the path)."""
    return {**os.environ, "PYTHONPATH": str(code_root)}


def command(*args: str) -> list:
    """The ``pmw`` command line of ``args`` (run with :func:`environment`)."""
    return [sys.executable, "-m", "pmwm_codec.cli", *args]


def call(function: str, path: Path) -> list:
    """A Python command line calling ``pmwm_codec.<function>(path)``."""
    module, name = function.rsplit(".", 1)
    return [sys.executable, "-c", f"import sys; from pmwm_codec.{module} import {name}; {name}(sys.argv[1])", str(path)]


def measure(argv: list, code_root: Path) -> tuple:
    """``(peak resident MB, wall seconds)`` of a fresh process running ``argv``; exits on its failure."""
    with tempfile.TemporaryFile() as stderr:  # (a pipe read only after the exit would hold a chatty process)
        start = time.perf_counter()
        proc = subprocess.Popen(argv, env=environment(code_root), cwd=code_root, stdout=subprocess.DEVNULL,
                                stderr=stderr)
        _, status, usage = os.wait4(proc.pid, 0)
        seconds = time.perf_counter() - start
        proc.returncode = os.waitstatus_to_exitcode(status)
        stderr.seek(0)
        err = stderr.read().decode(errors="replace")
    if proc.returncode:
        sys.exit(f"{' '.join(argv)} failed ({proc.returncode}): {err.strip()[-400:]}")
    return usage.ru_maxrss / 1024, seconds


def digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()[:12]


def operations(files: dict, out: Path) -> list:
    """``[(label, argv, output or None)]``: what is measured."""
    ops = [(f"`read_mesh` {k} ({files[k].stat().st_size / 1e6:,.0f} MB)", call("mesh.read_mesh", files[k]),
            None) for k in ("OBJ", "ASCII PLY", "binary PLY")]
    ops += [(f"`read_source` {k} (encode's reader)", call("meshdoc.read_source", files[k]), None)
            for k in ("OBJ", "ASCII PLY", "binary PLY")]
    ops.append(("`pmw encode` OBJ", command("encode", str(files["OBJ"]), "-o", str(out / "enc.pmw"), "-q"),
                out / "enc.pmw"))
    ops += [(f"`pmw decode -o .{s}`", command("decode", str(files["pmw"]), "-o", str(out / f"out.{s}"),
                                              "-q"), out / f"out.{s}") for s in ("glb", "ply", "obj")]
    return ops


def render(rows: list, info: dict, command_line: str, vertices: int, repeats: int) -> str:
    lines = run_header(command_line, info)
    lines += [f"A torus of {vertices:,} vertices with normals and texture coordinates (`torus()` of this tool); peak "
              f"resident memory of a fresh process (`os.wait4` ru_maxrss) and wall time, medians of {repeats}; "
              "`sha256` the first 12 hex digits of what a command writes (the same digits, the same bytes).", ""]
    body = [(label, f"{peak:,.0f} MB", f"{secs:,.1f} s", sha or "") for label, peak, secs, sha in rows]
    return "\n".join(lines) + "\n" + table(("operation", "peak", "time", "sha256"), body)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--vertices", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--code-root", type=Path, default=ROOT, help="the checkout whose pmwm_codec is measured")
    ap.add_argument("--dir", type=Path, help="where the test files are made (kept; reused when there)")
    ap.add_argument("--only", help="measure only the operations whose label holds this text")
    ap.add_argument("--write", metavar="MARKDOWN", help="replace this tool's section of that file")
    args = ap.parse_args()
    code_root = args.code_root.resolve()
    folder = (args.dir or Path(tempfile.mkdtemp(prefix="bench_textmesh_"))).resolve()
    folder.mkdir(parents=True, exist_ok=True)
    files = write_meshes(folder, args.vertices, code_root)
    out = Path(tempfile.mkdtemp(prefix="out_", dir=folder))
    info = machine()
    info["git"] = git_state() if code_root == ROOT else f"{code_root} ({_head(code_root)})"
    rows = []
    for label, argv, output in operations(files, out):
        if args.only and args.only not in label:
            continue
        runs = [measure(argv, code_root) for _ in range(args.repeats)]
        rows.append((label, statistics.median(r[0] for r in runs), statistics.median(r[1] for r in runs),
                     digest(output) if output else None))
        print(f"{label}: {rows[-1][1]:,.0f} MB, {rows[-1][2]:.1f} s", file=sys.stderr, flush=True)
    command_line = "python tools/bench_textmesh.py " + " ".join(sys.argv[1:])
    publish(render(rows, info, command_line.strip(), args.vertices, args.repeats), args.write, SECTION,
            lambda msg: print(msg, file=sys.stderr))


def _head(code_root: Path) -> str:
    return subprocess.run(["git", "-C", str(code_root), "rev-parse", "--short", "HEAD"], capture_output=True,
                          text=True).stdout.strip()


if __name__ == "__main__":
    main()
