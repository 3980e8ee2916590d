"""Robustness probe: every mesh file under a folder through the ``pmw`` command and the library, one JSON line each.

``python tools/probe_meshes.py DIR [--out results.jsonl] [--timeout 120] [--mark-every 12] [--limit N]``
takes every ``.obj``, ``.stl`` and ``.ply`` file under ``DIR`` (any case), smallest first, and
probes each in a fresh process (``--worker``, killed with its children after ``--timeout``
seconds), in a temporary directory of its own.  The process runs the command line as
``python -m pmwm_codec`` of the tree this file lives in (``sys.executable``, ``PYTHONPATH`` set
to the repository root) and the library from that tree, so it probes this checkout.  Each file
gets one JSON line in ``--out`` (its ``outcome``: ``ok``, ``refused``, ``error``,
``decode-failed``, ``timeout``, ``worker-died``, ``probe-crash``; its ``findings``, each a
``kind`` and a ``detail``); a second run skips the files already there, so an interrupted run
resumes.  The outcome table is printed at the end; ``--summary`` prints it from ``--out`` alone.
``tools/pybullet_meshes.py`` fetches 1,203 third-party meshes for it (``~/.cache/pmwm_codec/
pybullet/pybullet_data``).

What each check proves (a finding names the one that failed):

* ``encode`` (``pmw encode --json``): arbitrary input is encoded (exit 0, JSON on stdout) or
  refused in one line (exit 2, one ``pmw: error`` line); never a traceback, an "unexpected" bug
  report or another exit status (``bad-exit``, ``traceback``, ``unexpected``,
  ``refusal-not-one-line``, ``bad-json``); a file made without any vertex split says why in its
  notices (``no-splits-silent``).
* ``decode`` to OBJ and ``info --json`` of the whole file succeed (else outcome ``decode-failed``).
* Round trip on the grid: the decoded mesh has the vertex and face counts the encoder reported
  (``count-mismatch``) and those of the input (``roundtrip-counts``); its positions lie on the
  file's grid (``off-grid``) within half a step of the input's, or, for near-copies the encoder
  snaps together, of the nearest input vertex (``roundtrip-positions``; ``snapped-copies`` notes
  the snapped ones); its faces are the input's, as oriented triples of grid points
  (``roundtrip-faces``).
* ``cut --chunks K`` (half the chunks) writes a file whose ``decode`` equals ``decode(chunks=K)``
  of the whole one (``cut-differs``, ``cut-failed``).
* Every level (``iter_decode``) decodes (``iter-decode``); when the full mesh is watertight (every
  boundary half-edge, by position, has its reverse), so is every coarser level: no cracks
  (``cracks``).
* Six random byte prefixes decode or raise a one-line ``PmwError``, nothing else
  (``prefix-decode``, ``prefix-multiline``).
* Every ``--mark-every``-th file (by rank, smallest first): a 32x32 watermark (``--fit``) and an
  owner ID are embedded and ``pmw verify --key`` finds each (exit 0; ``verify-failed``).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import traceback

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
MESHES = (".obj", ".stl", ".ply")
OWNER_ID = "1234abcd"
PREFIXES = 6


def tree_env() -> dict:
    """The environment in which ``python`` imports ``pmwm_codec`` from this checkout."""
    env = dict(os.environ)
    env["PYTHONPATH"] = ROOT + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    return env


# ---------------------------------------------------------------- the per-file worker (a fresh process)

class Probe:
    """The checks on one mesh file; ``res`` is its JSON line."""

    def __init__(self, path: str, work: str):
        self.path, self.work = path, work
        self.res = {"findings": [], "cmds": {}}

    def finding(self, kind: str, detail) -> None:
        self.res["findings"].append({"kind": kind, "detail": str(detail)[:400]})

    def pmw(self, name: str, *argv: str, ok=(0, 2)):
        """Run ``python -m pmwm_codec ARGV``; (exit status, its JSON on exit 0 or None, stderr).
        Checks what every command owes: an exit status in ``ok``, no traceback, one line per refusal."""
        t = time.perf_counter()
        p = subprocess.run([sys.executable, "-m", "pmwm_codec", *argv], capture_output=True, text=True,
                           env=tree_env(), cwd=self.work)
        err = p.stderr
        self.res["cmds"][name] = {"rc": p.returncode, "s": round(time.perf_counter() - t, 3), "stderr": err[-600:]}
        if p.returncode not in ok:
            self.finding("bad-exit", f"{name}: rc={p.returncode} {err[-400:]}")
        if "Traceback" in err:
            self.finding("traceback", f"{name}: {err[-400:]}")
        if "unexpected" in err and "a bug of pmw" in err:
            self.finding("unexpected", f"{name}: {err.strip()}")
        if p.returncode == 2 and sum(line.startswith("pmw: error") for line in err.splitlines()) != 1:
            self.finding("refusal-not-one-line", f"{name}: {err[-400:]}")
        js = None
        if p.returncode == 0 and "--json" in argv:
            try:
                js = json.loads(p.stdout)
            except ValueError as exc:
                self.finding("bad-json", f"{name}: {exc}: {p.stdout[:200]}")
        return p.returncode, js, err

    def run(self, mark: bool) -> None:
        import pmwm_codec

        base = os.path.join(self.work, "out")
        rc, rep, err = self.pmw("encode", "encode", self.path, "-o", base + ".pmw", "--json")
        if rc != 0:
            self.res["outcome"] = "refused" if rc == 2 else "error"
            self.res["refusal"] = err.strip()[-300:]
            return
        if rep is None:
            self.res["outcome"] = "error"
            return
        self.res["report"] = {k: rep.get(k) for k in ("vertices", "faces", "base_vertices", "base_faces", "vsplits",
                                                       "chunks", "bytes", "seconds", "notices")}
        if rep.get("vsplits", 0) == 0 and not rep.get("notices"):
            self.finding("no-splits-silent", "encode made no vertex split and said nothing")
        rc, _, _ = self.pmw("decode", "decode", base + ".pmw", "-o", base + ".obj", "--json")
        rc_info, info, _ = self.pmw("info", "info", base + ".pmw", "--json")
        if rc != 0 or rc_info != 0 or info is None:
            self.res["outcome"] = "decode-failed"
            return
        positions, faces = read_obj(base + ".obj")
        try:
            self.compare(pmwm_codec.read_mesh(self.path), positions, faces, info["grid"], rep)
        except Exception:  # noqa: BLE001 -- a probe bug is reported, not fatal
            self.finding("probe-error", traceback.format_exc()[-400:])
        self.cut(base, int(rep["chunks"]) // 2)
        with open(base + ".pmw", "rb") as f:
            data = f.read()
        self.levels(data, watertight=unpartnered_edges(positions.astype(np.float32), faces) == 0)
        self.prefixes(data)
        if mark:
            self.marked(base)
        self.res["outcome"] = "ok"

    def compare(self, inp, dec_pos, dec_faces, grid, report) -> None:
        """The round trip on the grid: counts, positions within half a step (or snapped), faces."""
        origin, step = np.asarray(grid["origin"], np.float64), float(grid["step"])
        if len(dec_pos) != report["vertices"] or len(dec_faces) != report["faces"]:
            self.finding("count-mismatch", f"decoded {len(dec_pos)} v / {len(dec_faces)} f, "
                         f"encoder reported {report['vertices']} v / {report['faces']} f")
        self.res["input_vertices"], self.res["input_faces"] = inp.vertex_count, inp.face_count
        if len(dec_pos) != inp.vertex_count or len(dec_faces) != inp.face_count:
            self.finding("roundtrip-counts", f"input {inp.vertex_count} v / {inp.face_count} f, "
                         f"decoded {len(dec_pos)} v / {len(dec_faces)} f")
        qi = np.rint((inp.positions - origin) / step).astype(np.int64)
        qd_float = (dec_pos - origin) / step
        qd = np.rint(qd_float).astype(np.int64)
        off = np.abs(qd_float - qd).max(initial=0)
        if off > 0.01:
            self.finding("off-grid", f"decoded positions off the grid by {off:.3g} steps")
        a, b = qi[np.lexsort(qi.T[::-1])], qd[np.lexsort(qd.T[::-1])]
        if a.shape == b.shape and not np.array_equal(a, b):
            # near-copies (within 1/16 step) share one grid point: measure against the nearest input vertex
            from scipy.spatial import cKDTree
            dist = cKDTree(inp.positions).query(dec_pos, p=np.inf)[0].max() / step
            self.res["max_err_steps"] = float(dist)
            moved = int((np.abs(a - b).max(axis=1) > 0).sum())
            if dist > 0.5 + 1 / 16 + 0.01:
                self.finding("roundtrip-positions", f"{moved} sorted grid rows differ; nearest input vertex "
                             f"up to {dist:.3f} steps away")
            else:
                self.finding("snapped-copies", f"{moved} grid rows moved by a step (within {dist:.3f})")
        elif a.shape == b.shape:
            err = np.abs(np.sort(dec_pos, axis=0) - np.sort(inp.positions, axis=0)).max(initial=0) / step
            self.res["max_err_steps"] = float(err)
            if err > 0.51:
                self.finding("roundtrip-positions", f"max error {err:.3f} grid steps")
        pid = np.unique(np.concatenate([qi, qd]), axis=0, return_inverse=True)[1].reshape(-1)
        fi, fd = canonical_faces(pid[:len(qi)][inp.faces]), canonical_faces(pid[len(qi):][dec_faces])
        if fi.shape != fd.shape or not np.array_equal(fi, fd):
            si, sd = set(map(tuple, fi.tolist())), set(map(tuple, fd.tolist()))
            self.finding("roundtrip-faces", f"{len(si - sd)} input faces missing, {len(sd - si)} extra "
                         f"(as position triples; {len(fi)} vs {len(fd)} rows)")

    def cut(self, base: str, k: int) -> None:
        """``pmw cut --chunks k`` then ``pmw decode`` equals the library's ``decode(chunks=k)``."""
        import pmwm_codec

        rc, _, _ = self.pmw("cut", "cut", base + ".pmw", "-o", base + "-cut.pmw", "--chunks", str(k), "--json")
        if rc != 0:
            self.finding("cut-failed", f"cut --chunks {k} rc={rc}")
            return
        rc, _, _ = self.pmw("decode-cut", "decode", base + "-cut.pmw", "-o", base + "-cut.obj", "--json")
        if rc != 0:
            return
        positions, faces = read_obj(base + "-cut.obj")
        ref = pmwm_codec.decode(base + ".pmw", chunks=k)
        if not (np.array_equal(positions.astype(np.float32), np.asarray(ref.positions, np.float32))
                and np.array_equal(faces, ref.faces)):
            self.finding("cut-differs", f"cut at {k} decodes differently from decode --chunks {k}")

    def levels(self, data: bytes, watertight: bool) -> None:
        """Every level decodes; a watertight full mesh has no crack at any coarser level."""
        import pmwm_codec

        self.res["watertight"] = bool(watertight)
        cracks, count = [], 0
        try:
            for step in pmwm_codec.iter_decode(data):
                count += 1
                if watertight:
                    c = unpartnered_edges(np.asarray(step.mesh.positions, np.float32), np.asarray(step.mesh.faces))
                    if c:
                        cracks.append((step.chunk, c))
        except Exception:  # noqa: BLE001 -- any failure is the finding
            self.finding("iter-decode", traceback.format_exc()[-400:])
        self.res["levels"] = count
        if cracks:
            self.finding("cracks", f"levels with unpartnered edges (chunk, count): {cracks[:8]} of {count}")

    def prefixes(self, data: bytes) -> None:
        """Random byte prefixes (a download that stopped) decode or raise a one-line PmwError."""
        import pmwm_codec

        rng = np.random.default_rng(len(data))
        for cutoff in sorted(set(rng.integers(1, len(data), PREFIXES).tolist())):
            try:
                pmwm_codec.decode(data[:cutoff])
            except pmwm_codec.errors.PmwError as exc:
                if "\n" in str(exc):
                    self.finding("prefix-multiline", f"{cutoff}: {str(exc)[:200]}")
            except Exception:  # noqa: BLE001 -- any other exception is the finding
                self.finding("prefix-decode", f"{cutoff}/{len(data)}: {traceback.format_exc()[-300:]}")

    def marked(self, base: str) -> None:
        """A watermark image and an owner ID, each embedded and found again by ``pmw verify --key``."""
        from PIL import Image

        wm = os.path.join(self.work, "wm32.png")
        y, x = np.mgrid[0:32, 0:32]
        Image.fromarray(((x * 8) ^ (y * 8)).astype(np.uint8)).save(wm)
        for label, extra in (("wm", ["--watermark", wm, "--fit"]), ("owner", ["--owner-id", OWNER_ID])):
            out = f"{base}-{label}.pmw"
            rc, _, err = self.pmw(f"encode-{label}", "encode", self.path, "-o", out, *extra, "--json")
            self.res[f"{label}_encode"] = rc if rc == 0 else err.strip()[-200:]
            if rc != 0:
                continue
            rc, vj, err = self.pmw(f"verify-{label}", "verify", out, "--key", out + ".key.json", "--json", ok=(0, 1, 2))
            verdicts = vj and (vj.get("verdict"), (vj.get("owner") or {}).get("verdict"))
            self.res[f"{label}_verify"] = [rc, verdicts]
            if rc != 0:
                self.finding("verify-failed", f"{label}: rc={rc} verdicts={verdicts} {err.strip()[-200:]}")


def read_obj(path: str):
    """Positions and triangles of an OBJ that ``pmw decode`` wrote (``v x y z`` and ``f a b c`` lines)."""
    v, f = [], []
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                v.append(line[2:])
            elif line.startswith("f "):
                f.append(line[2:])
    positions = np.loadtxt(v, ndmin=2) if v else np.zeros((0, 3))
    faces = (np.loadtxt(f, dtype=np.int64, ndmin=2) - 1) if f else np.zeros((0, 3), np.int64)
    return positions, faces


def canonical_faces(faces: np.ndarray) -> np.ndarray:
    """Each triangle rotated to start at its smallest index (orientation kept), rows sorted."""
    if len(faces) == 0:
        return faces
    rots = [faces[:, [(s + j) % 3 for j in range(3)]] for s in range(3)]
    best = rots[0]
    for r in rots[1:]:
        less = (r[:, 0] < best[:, 0]) | ((r[:, 0] == best[:, 0]) & ((r[:, 1] < best[:, 1])
                                                                   | ((r[:, 1] == best[:, 1]) & (r[:, 2] < best[:, 2]))))
        best = np.where(less[:, None], r, best)
    return best[np.lexsort(best.T[::-1])]


def unpartnered_edges(pts: np.ndarray, faces: np.ndarray) -> int:
    """Boundary half-edges (by index) whose reverse (by exact position) is not a boundary half-edge:
    a crack; zero-length edges (both ends on one point) are ignored.  0 for a watertight mesh."""
    if len(faces) == 0:
        return 0
    pid = np.unique(pts, axis=0, return_inverse=True)[1].reshape(-1)
    a, b = faces.reshape(-1), faces[:, [1, 2, 0]].reshape(-1)
    n = len(pts)
    edge, count = np.unique(np.minimum(a, b) * n + np.maximum(a, b), return_inverse=True, return_counts=True)[1:]
    boundary = (count[edge.reshape(-1)] == 1) & (pid[a] != pid[b])
    fwd = pid[a[boundary]] * n + pid[b[boundary]]
    back = pid[b[boundary]] * n + pid[a[boundary]]
    return int(np.count_nonzero(~np.isin(back, fwd)))


def worker(path: str, work: str, mark: bool) -> int:
    """Probe one file; its JSON line is the last line of stdout."""
    probe = Probe(path, work)
    t = time.perf_counter()
    try:
        probe.run(mark)
    except BaseException:  # noqa: BLE001 -- the crash is the finding
        probe.finding("probe-crash", traceback.format_exc()[-600:])
        probe.res.setdefault("outcome", "probe-crash")
    probe.res["seconds_total"] = round(time.perf_counter() - t, 2)
    probe.res["maxrss_mb"] = round(max(resource.getrusage(who).ru_maxrss for who in
                                       (resource.RUSAGE_SELF, resource.RUSAGE_CHILDREN)) / 1024, 1)
    print("\n" + json.dumps(probe.res, default=str))
    return 0


# ---------------------------------------------------------------- the driver

def mesh_files(root: str) -> list:
    """Every mesh file under ``root``, as (size, path relative to root), smallest first."""
    found = []
    for d, _, names in os.walk(root):
        for name in names:
            if name.lower().endswith(MESHES):
                p = os.path.join(d, name)
                found.append((os.path.getsize(p), os.path.relpath(p, root)))
    return sorted(found)


def read_results(path: str) -> list:
    if not os.path.exists(path):
        return []
    with open(path) as f:
        return [json.loads(line) for line in f if line.strip()]


def probe_file(path: str, mark: bool, timeout: float) -> dict:
    """One file in a fresh worker process and temporary directory, killed with its children on timeout."""
    work = tempfile.mkdtemp(prefix="pmw-probe-")
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", path, work] + (["--mark"] if mark else [])
    p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=tree_env(),
                         start_new_session=True)
    try:
        out, err = p.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.communicate()
        return {"outcome": "timeout", "findings": [{"kind": "timeout", "detail": f"{timeout:g} s"}]}
    finally:
        shutil.rmtree(work, ignore_errors=True)
    lines = out.strip().splitlines()
    try:
        res = json.loads(lines[-1])
    except (IndexError, ValueError):
        return {"outcome": "worker-died", "findings": [{"kind": "worker-died", "detail": f"rc={p.returncode} {err[-500:]}"}]}
    if err.strip():
        res["findings"].append({"kind": "stderr-noise", "detail": err[-300:]})
    return res


def run(root: str, out: str, timeout: float, mark_every: int, limit: int | None) -> list:
    files = mesh_files(root)[:limit]
    done = {r["file"] for r in read_results(out)}
    for i, (size, rel) in enumerate(files):
        if rel in done:
            continue
        mark = mark_every > 0 and i % mark_every == 0
        t = time.perf_counter()
        res = {"file": rel, **probe_file(os.path.join(root, rel), mark, timeout)}
        res.update(wall=round(time.perf_counter() - t, 2), size=size, mark=mark)
        with open(out, "a") as f:
            f.write(json.dumps(res) + "\n")
        print(f"{i + 1}/{len(files)} {res['outcome']} {res['wall']:.1f} s {rel} "
              f"{[f['kind'] for f in res['findings']]}", flush=True)
    return read_results(out)


def summary(rows: list) -> str:
    """The outcome table, the slowest files, the largest size ratios and base shares, the refusals."""
    table = collections.Counter((r.get("outcome"), tuple(sorted({f["kind"] for f in r.get("findings", [])})))
                                for r in rows)
    lines = [f"{len(rows)} files", "| outcome | findings | files |", "|---|---|---|"]
    lines += [f"| {o} | {', '.join(k) or '-'} | {n} |" for (o, k), n in sorted(table.items(), key=lambda x: -x[1])]
    ok = [r for r in rows if r.get("report")]
    lines.append("\nslowest (wall s, encode s, maxrss MB, vertices):")
    for r in sorted(rows, key=lambda r: -r["wall"])[:8]:
        lines.append(f"  {r['wall']:7.1f} {r.get('cmds', {}).get('encode', {}).get('s', '-'):>7} "
                     f"{r.get('maxrss_mb', 0):7.0f} {(r.get('report') or {}).get('vertices', '-'):>8} {r['file']}")
    lines.append("largest size ratio (pmw bytes / input bytes):")
    for r in sorted(ok, key=lambda r: -r["report"]["bytes"] / max(r["size"], 1))[:6]:
        lines.append(f"  {r['report']['bytes'] / max(r['size'], 1):.2f} {r['report']['bytes']} / {r['size']} {r['file']}")
    lines.append("largest base share (base vertices / vertices), meshes of 500 vertices or more:")
    big = [r for r in ok if r["report"]["vertices"] >= 500]
    for r in sorted(big, key=lambda r: -r["report"]["base_vertices"] / r["report"]["vertices"])[:10]:
        rep = r["report"]
        lines.append(f"  {100 * rep['base_vertices'] / rep['vertices']:5.1f}% {rep['base_vertices']}/{rep['vertices']} "
                     f"{r['file']} {rep['notices']}")
    marked = [r for r in ok if r.get("mark")]
    for label in ("wm", "owner"):
        given = [r for r in marked if f"{label}_encode" in r]
        verified = sum((r.get(f"{label}_verify") or [None])[0] == 0 for r in given)
        refused = sum(r[f"{label}_encode"] != 0 for r in given)
        lines.append(f"{label} marks: {len(given)} files sampled, {verified} verified, {refused} refused at encode")
    lines.append("not ok:")
    lines += [f"  {r.get('outcome')} {r['file']} {(r.get('refusal') or str(r.get('findings')))[:250]}"
              for r in rows if r.get("outcome") != "ok"]
    return "\n".join(lines)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--worker"]:  # internal: python probe_meshes.py --worker FILE WORKDIR [--mark]
        sys.path.insert(0, ROOT)
        return worker(argv[1], argv[2], "--mark" in argv[3:])
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", nargs="?", help="the folder of mesh files (searched recursively)")
    ap.add_argument("--out", default="probe-results.jsonl", help="the results, one JSON line per file (appended; resumed)")
    ap.add_argument("--timeout", type=float, default=120, help="seconds per file before its worker is killed (default 120)")
    ap.add_argument("--mark-every", type=int, default=12, help="embed and verify a watermark and an owner ID in every "
                    "N-th file (default 12; 0: none)")
    ap.add_argument("--limit", type=int, help="only the N smallest files")
    ap.add_argument("--summary", action="store_true", help="print the table of --out and run nothing")
    args = ap.parse_args(argv)
    if args.summary:
        rows = read_results(args.out)
    elif args.dir is None or not os.path.isdir(args.dir):
        ap.error(f"not a folder: {args.dir}")
    else:
        os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
        rows = run(args.dir, args.out, args.timeout, args.mark_every, args.limit)
    print(summary(rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
