"""Owner layer on meshes from outside: what ``pmw encode --owner-id`` does with each, and whether it tells the truth.

For up to ``--limit`` mesh files under ``DIR`` (``.obj``, ``.stl``, ``.ply``: their geometry, as ``read_mesh``
reads it; ``.glb``, ``.gltf``: the asset, textures and scene kept), those of ``--min-vertices`` to
``--max-vertices`` vertices, in an order shuffled by ``--seed``, each is encoded as the command line encodes
it with an owner ID (``pmwm_codec.encode(..., owner_id=...)``, a key of its own), and the file is sorted
into one of three outcomes:

* ``refused``: the encoder said the layer cannot be read back from this mesh (nothing written);
* ``noted``: written, with the notice that the layer may not survive re-compression;
* ``clean``: written without a word about the layer.

Then the full decode of every written file (an asset's: the GLB ``pmw decode`` writes, taken as ``pmw
verify`` takes it, :func:`pmwm_codec.verify.owner.owner_view`) goes through the transports of issue 14's cell 2 (float32; a
similarity, a re-ordering and float32; Draco q14 and q11 through DracoPy; 16- and 14-bit quantization on one
cubic grid with re-ordering, as ``tools/owner_attacks.py`` runs them), and the ID is read blind
(:func:`pmwm_codec.verify.owner.owner_of_mesh`, as ``pmw verify MESH`` reads it).  What it proves: a
``clean`` file whose ID reads anything but ``present`` after one of them is a silent wrong answer (the
table's last column); a ``noted`` one that reads ``present`` after all of them was a false alarm.

    python tools/owner_sweep.py DIR [--limit 40] [--seed 7] [--out rows.jsonl]

``tools/pybullet_meshes.py`` fetches pybullet's 1,203 meshes (robot parts, CAD, procedurally built shapes)
for it.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import sys
import time
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tools"))

from owner_attacks import cells  # noqa: E402

import pmwm_codec  # noqa: E402
from pmwm_codec.errors import OwnerLayerError, PmwError  # noqa: E402
from pmwm_codec.mesh import Mesh  # noqa: E402
from pmwm_codec.stream.asset import decode_asset  # noqa: E402
from pmwm_codec.verify.owner import owner_of_mesh, owner_view  # noqa: E402
from pmwm_codec.watermark.key import WatermarkKey  # noqa: E402

#: Issue 14's cell 2, as tools/owner_attacks.py runs each.
TRANSPORTS = [(name, attack) for name, attack in cells() if name in (
    "float32", "similarity + re-order + float32", "Draco q14", "Draco q11", "16-bit quantization + re-order",
    "14-bit quantization + re-order")]
NOTICE = "the owner layer may not survive re-compression"


ASSETS = (".glb", ".gltf")


def mesh_files(root: str) -> list:
    out = []
    for dirpath, _, names in os.walk(root):
        out += [os.path.join(dirpath, n) for n in sorted(names)
                if n.lower().endswith((".obj", ".stl", ".ply", *ASSETS))]
    return sorted(out)


def probe(path: str, work: str) -> dict:
    """One mesh file: its outcome, notices and the transports' reads (see the module's docstring)."""
    asset = path.lower().endswith(ASSETS)
    src = path if asset else pmwm_codec.read_mesh(path)
    row = {"vertices": int(owner_view(path).vertex_count if asset else src.vertex_count)}
    key = WatermarkKey.generate(rng=np.random.default_rng(zlib.crc32(path.encode())))
    dst = os.path.join(work, "out.pmw")
    try:
        report = pmwm_codec.encode(src, dst, key=key, owner_id=key.owner_id, measure="none")
    except OwnerLayerError as exc:
        row["outcome"], row["why"] = "refused", str(exc)[:300]
        return row
    notes = [n for n in report.get("notices") or [] if n.startswith(NOTICE)]
    row["outcome"] = "noted" if notes else "clean"
    row["notice"] = notes[0][:300] if notes else None
    if asset:
        glb = os.path.join(work, "out.glb")
        with open(glb, "wb") as fh:
            fh.write(decode_asset(dst)[0])
        decoded = owner_view(glb)
    else:
        decoded = pmwm_codec.decode(dst)
    V, F = np.asarray(decoded.positions, np.float64), np.asarray(decoded.faces, np.int64)
    row["reads"] = {}
    for name, attack in TRANSPORTS:
        V2, F2 = attack(V, F, np.random.default_rng(100))
        read = owner_of_mesh(Mesh(V2, F2), key)
        row["reads"][name] = [int(read.bit_errors), read.verdict]
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir")
    ap.add_argument("--limit", type=int, default=40)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--min-vertices", type=int, default=1000)
    ap.add_argument("--max-vertices", type=int, default=80_000)
    ap.add_argument("--out", help="one JSON line per mesh (appended)")
    args = ap.parse_args(argv)
    files = mesh_files(args.dir)
    np.random.default_rng(args.seed).shuffle(files)
    rows, t0 = [], time.perf_counter()
    import tempfile

    with tempfile.TemporaryDirectory() as work:
        for path in files:
            if len(rows) >= args.limit:
                break
            try:
                count = (owner_view(path) if path.lower().endswith(ASSETS) else pmwm_codec.read_mesh(path)).vertex_count
            except PmwError:
                continue
            if not args.min_vertices <= count <= args.max_vertices:
                continue
            try:
                row = probe(path, work)
            except PmwError as exc:  # a mesh the encoder refuses for another reason: not in the table
                print(f"skipped {os.path.relpath(path, args.dir)}: {exc}", file=sys.stderr)
                continue
            row["file"] = os.path.relpath(path, args.dir)
            rows.append(row)
            wrong = {k: v for k, v in (row.get("reads") or {}).items() if v[1] != "present"}
            print(f"{len(rows):3d} {row['outcome']:8s} {row['vertices']:6d} {row['file']} {wrong or ''}", flush=True)
            if args.out:
                with open(args.out, "a") as fh:
                    fh.write(json.dumps(row) + "\n")
    print(summary(rows, time.perf_counter() - t0))
    return 0


def summary(rows: list, seconds: float) -> str:
    """The markdown table of the outcomes and the reads after each transport."""
    out = io.StringIO()
    out.write(f"{len(rows)} meshes of {min((r['vertices'] for r in rows), default=0):,}-"
              f"{max((r['vertices'] for r in rows), default=0):,} vertices, {seconds:.0f} s\n\n")
    out.write("| outcome | meshes | " + " | ".join(f"`present` after {n}" for n, _ in TRANSPORTS)
              + " | `present` after every one |\n")
    out.write("|---|---|" + "---|" * (len(TRANSPORTS) + 1) + "\n")
    for outcome in ("refused", "noted", "clean"):
        mine = [r for r in rows if r["outcome"] == outcome]
        if outcome == "refused":
            out.write(f"| refused (nothing written) | {len(mine)} |" + " |" * (len(TRANSPORTS) + 1) + "\n")
            continue
        cells = [sum(r["reads"][n][1] == "present" for r in mine) for n, _ in TRANSPORTS]
        every = sum(all(v[1] == "present" for v in r["reads"].values()) for r in mine)
        out.write(f"| {outcome} | {len(mine)} | " + " | ".join(f"{c} of {len(mine)}" for c in cells)
                  + f" | {every} of {len(mine)} |\n")
    return out.getvalue()


if __name__ == "__main__":
    sys.exit(main())
