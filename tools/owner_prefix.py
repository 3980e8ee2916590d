"""The owner layer from a stream's prefix: the full decode's frames against each level's own estimate.

Per mesh and key (``--keys``, keys from seeds 0, 1, ...): an owner-only encode (``stream.encode_mesh(mesh,
BytesIO(), key=<key>, owner_id=...)``, default grid) read at every chunk boundary with
:func:`pmwm_codec.watermark.owner.detect` twice, on the same levels: in the frames of the full decode
(``given=owner.full_frames(...)`` of the last level: what ``pmw verify FILE.pmw`` reads of a whole file) and in
each level's own frames (``given=None``: what it reads of a stream cut short, and read before the full
decode's frames).  Reported: the first boundary from which every later one reads ``present``, as a share of
the file's bytes and in vertices (issue 14, done-when 5: at most 25 %).  Then ``--wrong-keys`` keys that did
not mark the file read every level of at least ``--min-vertices`` vertices in the full decode's frames (the
views computed once per level: :func:`~pmwm_codec.watermark.owner.mesh_scores`): how many read ``present``
(the bound says fewer than 1e-9 a read), and the share with at most :data:`TAIL_AT` errors against the
bound's ``false_alarm_probability(TAIL_AT)``.

Run from the repository root::

    python tools/heldout.py                                   # the held-out meshes, once
    python tools/owner_prefix.py --meshes /tmp/heldout/chinesedragon10k.obj --keys 3 --wrong-keys 100
"""

from __future__ import annotations

import argparse
import io
import os
import shlex
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))

import pmwm_codec  # noqa: E402
from pmwm_codec.mesh import read_mesh  # noqa: E402
from pmwm_codec.stream import encode_mesh  # noqa: E402
from pmwm_codec.watermark import owner  # noqa: E402
from pmwm_codec.watermark.key import WatermarkKey  # noqa: E402

from bench import machine, publish, table  # noqa: E402

SECTION = "Owner layer from a stream's prefix (tools/owner_prefix.py)"
#: Wrong keys' reads with at most this many errors are counted against the bound at this count.
TAIL_AT = 16
OWNER_ID = 0x0123456789ABCDEF


def first_present(reads: list) -> int:
    """The first index from which every read of ``reads`` (verdicts) is ``present``; len(reads): none."""
    first = len(reads)
    while first > 0 and reads[first - 1] == "present":
        first -= 1
    return first


def levels(data: bytes) -> list:
    """``[(bytes read, distinct points (k, 3), faces (m, 3))]`` at every chunk boundary of a one-primitive
    ``.pmw``, base first."""
    return [(int(r.bytes_read), *owner.distinct_mesh(r.mesh.positions, r.mesh.faces))
            for r in pmwm_codec.iter_decode(data)]


def run_mesh(path: str, keys: int, wrong: int, min_vertices: int, log) -> dict:
    mesh = read_mesh(path)
    out = {"name": os.path.basename(path), "vertices": mesh.vertex_count, "full": [], "estimate": [],
           "wrong": [], "reads": 0}
    wrong_rng = np.random.default_rng(12345)
    for seed in range(keys):
        key = WatermarkKey.generate(rng=np.random.default_rng(seed))
        buf = io.BytesIO()
        key = encode_mesh(mesh, buf, key=key, owner_id=OWNER_ID + seed).key
        data = buf.getvalue()
        steps = levels(data)
        full = owner.full_frames(steps[-1][1], steps[-1][2])  # the full decode's frames, from the decoded mesh
        for label, frames in (("full", full), ("estimate", None)):
            verdicts = [owner.detect(p, f, key, given=frames).verdict for _, p, f in steps]
            i = first_present(verdicts)
            out[label].append((steps[i][0] / len(data), len(steps[i][1])) if i < len(steps) else (float("nan"), 0))
        for _, p, f in steps:
            if len(p) < min_vertices:
                continue
            scores = owner.mesh_scores(p, f, full)
            for _ in range(max(1, wrong // keys)):
                r = owner.detect(p, f, WatermarkKey.generate(rng=wrong_rng), scores=scores)
                out["wrong"].append((r.bit_errors, r.verdict))
        log(f"  {out['name']} key {seed}: full decode's frames {out['full'][-1]}, estimate {out['estimate'][-1]}")
    return out


def render(rows: list, info: dict, command: str) -> str:
    def share(pairs):
        shares = [s for s, _ in pairs]
        if any(np.isnan(shares)):
            return "never (some key)"
        j = int(np.argsort(shares)[len(shares) // 2])
        return (f"**{100 * shares[j]:.1f}%** ({100 * min(shares):.1f}-{100 * max(shares):.1f}%), "
                f"{pairs[j][1]:,} V")

    body = []
    for r in rows:
        e = np.array([err for err, _ in r["wrong"]])
        present = sum(v == "present" for _, v in r["wrong"])
        bound = owner.false_alarm_probability(TAIL_AT)
        body.append((r["name"], f"{r['vertices']:,}", share(r["full"]), share(r["estimate"]),
                     f"{present} of {len(e)}", f"{np.mean(e <= TAIL_AT):.4f} / {bound:.4f}" if len(e) else "-"))
    head = ["mesh", "vertices", "`present` from, the full decode's frames (median of keys, range; vertices there)",
            "the same levels, each in its own estimate", "wrong keys `present` (every level read)",
            f"wrong keys with <= {TAIL_AT} errors: measured / bound"]
    return "\n".join([f"Command (from the repository root): `{command}`", "",
                      f"Machine: {info['cpu']}, {info['cores']} cores, Python {info['python']}; load average at "
                      f"start {info['load'][0]:.2f}. Library: commit {info['git']}.", "", table(head, body)])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--meshes", nargs="+", required=True, help="OBJ/PLY/... files")
    ap.add_argument("--keys", type=int, default=3)
    ap.add_argument("--wrong-keys", type=int, default=100, help="wrong keys per mesh, each read at every level")
    ap.add_argument("--min-vertices", type=int, default=500, help="wrong keys read levels of at least this many")
    ap.add_argument("--write", metavar="MARKDOWN", help=f"replace the '{SECTION}' section of this file")
    args = ap.parse_args(argv)
    info = machine()
    command = "python tools/owner_prefix.py " + shlex.join(sys.argv[1:] if argv is None else argv)

    def log(msg):
        print(msg, file=sys.stderr, flush=True)

    rows = [run_mesh(p, args.keys, args.wrong_keys, args.min_vertices, log) for p in args.meshes]
    publish(render(rows, info, command.strip()), args.write, SECTION, log)
    return 0


if __name__ == "__main__":
    sys.exit(main())
