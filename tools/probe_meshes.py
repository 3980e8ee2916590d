"""Robustness probe: every mesh file under a folder through the ``pmw`` command and the library, one JSON line each.

``python tools/probe_meshes.py DIR [--out results.jsonl] [--timeout 120] [--mark-every 12] [--limit N]``
takes every ``.obj``, ``.stl``, ``.ply``, ``.off``, ``.gltf`` and ``.glb`` file under ``DIR`` (any case),
smallest first, and probes each in a fresh process (``--worker``, killed with its children after ``--timeout``
seconds), in a temporary directory of its own.  The process runs the command line as
``python -m pmwm_codec`` of the tree this file lives in (``sys.executable``, ``PYTHONPATH`` set
to the repository root) and the library from that tree, so it probes this checkout.  Each file
gets one JSON line in ``--out`` (its ``outcome``: ``ok``, ``refused``, ``error``,
``decode-failed``, ``timeout``, ``worker-died``, ``probe-crash``; its ``findings``, each a
``kind`` and a ``detail``); a second run skips the files already there, so an interrupted run
resumes.  The outcome table is printed at the end; ``--summary`` prints it from ``--out`` alone.
``tools/pybullet_meshes.py`` fetches 1,203 third-party meshes for it (``~/.cache/pmwm_codec/
pybullet/pybullet_data``), ``tools/gltf_meshes.py`` 135 glTF / GLB assets and 42 more meshes
(``~/.cache/pmwm_codec/gltf``).

What each check proves (a finding names the one that failed):

* ``encode`` (``pmw encode --json``): arbitrary input is encoded (exit 0, JSON on stdout) or
  refused in one line (exit 2, one ``pmw: error`` line); never a traceback, an "unexpected" bug
  report or another exit status (``bad-exit``, ``traceback``, ``unexpected``,
  ``refusal-not-one-line``, ``bad-json``); a file made without any vertex split says why in its
  notices (``no-splits-silent``).
* ``decode`` to OBJ and ``info --json`` of the whole file succeed, and for a glTF / GLB input
  ``decode`` to GLB (else outcome ``decode-failed``).
* Round trip on the grid (OBJ, STL, PLY inputs): the decoded mesh has the vertex and face counts the encoder reported
  (``count-mismatch``) and those of the input (``roundtrip-counts``); its positions lie on the
  file's grid (``off-grid``; far from the origin, to within half a float32 spacing, which a file
  stores) within half a step (plus that) of the input's, or, for near-copies the encoder
  snaps together, of the nearest input vertex (``roundtrip-positions``; ``snapped-copies`` notes
  the snapped ones); its faces are the input's, as oriented triples of grid points
  (``roundtrip-faces``).
* Round trip of a glTF / GLB input (:meth:`Probe.compare_asset` says what each proves): every
  primitive still there in its mode, one passed through (skinned, morph, not triangles) with its
  input positions bit for bit and its morph targets, a progressive one with every attribute name but
  flat normals the encoder says it dropped (``primitive-lost``, ``passthrough-differs``, ``attributes-lost``); the progressive primitives hold
  the counts the encoder reported (``count-mismatch``); the scene as the decoded OBJ shows it has
  the counts of ``read_mesh`` of the input (``roundtrip-counts``) and its positions within a bound
  derived from each primitive's grid step and its nodes' transforms (``roundtrip-positions``).
  Where that scene check is not sound it is skipped, the reason in ``roundtrip_skipped``.
* Third parties (glTF / GLB inputs, when ``tools/js/node_modules`` exists): the Khronos validator
  finds no error in the ``.pmw`` nor in the decoded GLB (``validator-error``) and three.js loads
  both (``three-load``; ``validator-failed`` when ``check_gltf.mjs`` itself fails); the input's
  validator errors and codes are kept in ``input_validator`` (information, not a finding), and an
  error of a code the input's errors have too (``validator-error-as-input``), or a three.js failure
  with the input's own message (``three-load-as-input``), is garbage in, carried over: told apart
  from a fault, still listed.
* ``cut --chunks K`` (half the chunks) writes a file whose ``decode`` equals ``decode(chunks=K)``
  of the whole one (for an asset, the OBJ of ``pmw decode --chunks K`` of the whole one) (``cut-differs``,
  ``cut-failed``).
* Every level (``iter_decode``) decodes (``iter-decode``); when the full mesh is watertight (every
  boundary half-edge, by position, has its reverse; for an asset, the last level, since its OBJ
  also holds the primitives no level carries), so is every coarser level: no cracks (``cracks``).
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
import re
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
ASSETS = (".gltf", ".glb")
MESHES = (".obj", ".stl", ".ply", ".off") + ASSETS
DRACO = "KHR_draco_mesh_compression"
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
        asset = self.path.lower().endswith(ASSETS)
        # an OBJ / PLY / OFF with texture coordinates, colours or materials is encoded as the glTF document it
        # describes: its glTF vertices (seam copies) are what the encoder counts, its OBJ holds the positions
        appearance = not asset and carries_appearance(self.path)
        rc, dec, _ = self.pmw("decode", "decode", base + ".pmw", "-o", base + ".obj", "--json")
        rc_info, info, _ = self.pmw("info", "info", base + ".pmw", "--json")
        rc_glb = self.pmw("decode-glb", "decode", base + ".pmw", "-o", base + ".glb", "--json")[0] if asset else 0
        if rc != 0 or rc_info != 0 or info is None or rc_glb != 0:
            self.res["outcome"] = "decode-failed"
            return
        positions, faces = read_obj(base + ".obj")
        try:
            if asset:
                self.compare_asset(positions, faces, rep, base, (dec or {}).get("notices") or [])
            elif appearance:
                grids = [p["grid"] for p in info.get("primitives") or [] if p.get("grid")] or [info["grid"]]
                self.compare_points(pmwm_codec.read_mesh(self.path), positions, faces, grids)
            else:
                self.compare(pmwm_codec.read_mesh(self.path), positions, faces, info["grid"], rep)
        except Exception:  # noqa: BLE001 -- a probe bug is reported, not fatal
            self.finding("probe-error", traceback.format_exc()[-400:])
        if asset:
            self.validated(base)
        self.cut(base, int(rep["chunks"]) // 2, asset or appearance)
        with open(base + ".pmw", "rb") as f:
            data = f.read()
        # an asset's OBJ also holds the primitives passed through, which no level carries: its last level decides
        self.levels(data, watertight=None if asset else unpartnered_edges(positions.astype(np.float32), faces) == 0)
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
        # a file stores float32: far from the origin a grid point is off by up to half a float32 spacing
        # (the encoder guarantees the grid index comes back, not the grid point: Grid.carries_float32)
        from pmwm_codec.progressive.grid import float32_spacing
        f32 = float32_spacing(np.abs(dec_pos).max(axis=0, initial=0)) / (2 * step)
        off = (np.abs(qd_float - qd) - f32).max(initial=0)
        self.res["float32_steps"] = float(f32.max(initial=0))
        if off > 0.01:
            self.finding("off-grid", f"decoded positions off the grid by {off:.3g} steps more than float32 explains")
        a, b = qi[np.lexsort(qi.T[::-1])], qd[np.lexsort(qd.T[::-1])]
        if a.shape == b.shape and not np.array_equal(a, b):
            # near-copies (within 1/16 step) share one grid point: measure against the nearest input vertex
            from scipy.spatial import cKDTree
            dist = cKDTree(inp.positions).query(dec_pos, p=np.inf)[0].max() / step
            self.res["max_err_steps"] = float(dist)
            moved = int((np.abs(a - b).max(axis=1) > 0).sum())
            if dist > 0.5 + 1 / 16 + 0.01 + f32.max(initial=0):
                self.finding("roundtrip-positions", f"{moved} sorted grid rows differ; nearest input vertex "
                             f"up to {dist:.3f} steps away")
            else:
                self.finding("snapped-copies", f"{moved} grid rows moved by a step (within {dist:.3f})")
        elif a.shape == b.shape:
            err = np.abs(np.sort(dec_pos, axis=0) - np.sort(inp.positions, axis=0)).max(initial=0) / step
            self.res["max_err_steps"] = float(err)
            if err > 0.51 + f32.max(initial=0):
                self.finding("roundtrip-positions", f"max error {err:.3f} grid steps")
        rows, pid = np.unique(np.concatenate([qi, qd]), axis=0, return_inverse=True)
        pid = pid.reshape(-1)
        fi, fd = _oriented(pid[:len(qi)][inp.faces]), _oriented(pid[len(qi):][dec_faces])
        if fi.shape != fd.shape or not np.array_equal(fi, fd):
            si, sd = set(map(tuple, fi.tolist())), set(map(tuple, fd.tolist()))
            missing, extra = sorted(si - sd), sorted(sd - si)
            snapped = "snapped-copies" in {f["kind"] for f in self.res["findings"]}
            if snapped and len(missing) == len(extra) and snapped_faces(rows, missing, extra):
                self.finding("snapped-copies", f"{len(missing)} faces have corners on copies moved by a step")
            else:
                self.finding("roundtrip-faces", f"{len(missing)} input faces missing, {len(extra)} extra "
                             f"(as position triples; {len(fi)} vs {len(fd)} rows)")

    def compare_points(self, inp, dec_pos, dec_faces, grids) -> None:
        """The round trip of a mesh encoded with its appearance (the OBJ writes a position once per primitive,
        its texture coordinates and colours beside; a primitive per material, each on its grid, ``grids`` the
        primitives' ``grid`` objects): every input vertex the faces use is within half a step of the coarsest
        grid (plus 1/16 for near copies the encoder snaps together, plus float32 far from the origin) of a
        decoded position and every decoded position of an input vertex (``roundtrip-positions``); there are no
        more distinct decoded positions than input positions, and with one primitive no two decoded vertices
        on one grid point (``roundtrip-counts``); the faces are the input's, each vertex taken as its position
        (an input vertex as its nearest decoded one; ``roundtrip-faces``)."""
        from scipy.spatial import cKDTree

        from pmwm_codec.progressive.grid import float32_spacing

        step = max(float(g["step"]) for g in grids)
        used = np.unique(inp.faces) if len(inp.faces) else np.zeros(0, np.int64)
        self.res["input_vertices"], self.res["input_faces"] = inp.vertex_count, inp.face_count
        points, at = np.unique(dec_pos, axis=0, return_inverse=True)
        at = at.reshape(-1)
        distinct_in = len(np.unique(inp.positions[used], axis=0))
        one_grid = len(grids) == 1 and len(np.unique(np.rint((dec_pos - np.asarray(grids[0]["origin"], np.float64))
                                                               / step), axis=0)) == len(dec_pos)
        if len(points) > distinct_in or len(dec_faces) != inp.face_count or (len(grids) == 1 and not one_grid):
            self.finding("roundtrip-counts", f"input {distinct_in} positions / {inp.face_count} f, decoded "
                         f"{len(dec_pos)} v ({len(points)} positions) / {len(dec_faces)} f")
            return
        slack = 0.5 + 1 / 16 + 0.01 + (float32_spacing(np.abs(dec_pos).max(axis=0, initial=0)) / (2 * step)).max()
        there, nearest = cKDTree(points).query(inp.positions[used], p=np.inf)
        back = cKDTree(inp.positions[used]).query(points, p=np.inf)[0]
        far = max(there.max(initial=0), back.max(initial=0)) / step
        self.res["max_err_steps"] = float(far)
        if far > slack:
            self.finding("roundtrip-positions", f"a position {far:.3f} steps of the coarsest grid from the nearest "
                         "on the other side")
        to_point = np.full(inp.vertex_count, -1, np.int64)
        to_point[used] = nearest
        ti = {tuple(sorted(f)) for f in to_point[inp.faces].tolist()}
        td = {tuple(sorted(f)) for f in at[np.asarray(dec_faces, np.int64)].tolist()}
        if ti != td:
            self.finding("roundtrip-faces", f"{len(ti - td)} input faces missing, {len(td - ti)} extra (each vertex "
                         "as its position, an input vertex as the nearest decoded one)")

    def cut(self, base: str, k: int, asset: bool = False) -> None:
        """``pmw cut --chunks k`` then ``pmw decode`` equals the library's ``decode(chunks=k)`` (an asset's:
        ``pmw decode --chunks k`` of the whole file, whose OBJ also holds the primitives passed through)."""
        import pmwm_codec

        rc, _, _ = self.pmw("cut", "cut", base + ".pmw", "-o", base + "-cut.pmw", "--chunks", str(k), "--json")
        if rc != 0:
            self.finding("cut-failed", f"cut --chunks {k} rc={rc}")
            return
        rc, _, _ = self.pmw("decode-cut", "decode", base + "-cut.pmw", "-o", base + "-cut.obj", "--json")
        if rc != 0:
            return
        positions, faces = read_obj(base + "-cut.obj")
        if asset:
            rc, _, _ = self.pmw("decode-k", "decode", base + ".pmw", "-o", base + "-k.obj", "--chunks", str(k),
                                "--json")
            if rc != 0:
                self.finding("cut-failed", f"decode --chunks {k} of the whole file rc={rc}")
                return
            ref = pmwm_codec.mesh.Mesh(*read_obj(base + "-k.obj"))
        else:
            ref = pmwm_codec.decode(base + ".pmw", chunks=k)
        if not (np.array_equal(positions.astype(np.float32), np.asarray(ref.positions, np.float32))
                and np.array_equal(faces, ref.faces)):
            self.finding("cut-differs", f"cut at {k} decodes differently from decode --chunks {k}")

    def levels(self, data: bytes, watertight: bool | None) -> None:
        """Every level decodes; a watertight full mesh has no crack at any coarser level (``watertight``
        None: the last level decided, every level's unpartnered edges counted on the way)."""
        import pmwm_codec

        cracks, count, last = [], 0, 0
        try:
            for step in pmwm_codec.iter_decode(data):
                count += 1
                if watertight is not False:
                    last = unpartnered_edges(np.asarray(step.mesh.positions, np.float32), np.asarray(step.mesh.faces))
                    if last:
                        cracks.append((step.chunk, last))
        except Exception:  # noqa: BLE001 -- any failure is the finding
            self.finding("iter-decode", traceback.format_exc()[-400:])
        if watertight is None:
            watertight = count > 0 and last == 0
            cracks = cracks if watertight else []
        self.res["watertight"] = bool(watertight)
        self.res["levels"] = count
        if cracks:
            self.finding("cracks", f"levels with unpartnered edges (chunk, count): {cracks[:8]} of {count}")

    def compare_asset(self, dec_pos, dec_faces, report, base: str, notices: list) -> None:
        """An asset's round trip: its primitives, the counts the encoder reported, and the scene as shown.

        * Primitives (``primitive-lost``, ``passthrough-differs``, ``attributes-lost``): the decoded GLB
          has the input's meshes, each with its primitives in their modes (a strip or fan made progressive:
          TRIANGLES, the triangles it draws; input read by the library's ``load_document``); a primitive the encoder passed through (no extension in the ``.pmw``) has
          the input's POSITION values, bit for bit, and its morph targets; a progressive one keeps
          every attribute name.
        * ``count-mismatch``: the progressive primitives of the decoded GLB hold the vertex and face
          counts the encoder reported.
        * The scene (``roundtrip-counts``, ``roundtrip-positions``): ``pmwm_codec.read_mesh`` of the
          input (the default scene's triangle primitives placed by their nodes, one mesh) against the
          decoded OBJ (the scene as ``pmw decode`` shows it).  Counts: the faces not
          degenerate by index and the vertices they use are equal (at most the input's when the
          encoder welded a soup's duplicates, a notice).  Positions: every decoded vertex lies within
          ``tol`` (max norm) of some input vertex and every input vertex within ``tol`` of some decoded
          one.  A progressive primitive's vertex is within ``(1/2 + 1/16) step`` per axis of its input
          (half a step of rounding; near-copies within 1/16 step snap together), ``step`` its
          ``grid.step``; a node's linear part ``L`` maps that box into one of ``|L|_inf`` (largest row
          sum of absolute values) times as wide, so ``tol`` is the largest such bound over the
          progressive primitives and their showings (the matrices are the library's
          ``placements_by_mesh``: only the bound depends on them), plus float32 rounding of the grid
          points (4 ulp of the grid's extent, scaled by ``|L|_inf``) and the OBJ's 9 digits.  This proves each side is within ``tol`` of the other as
          point sets (a vertex moved further, dropped or added is found; a face's corners swapped among
          nearby vertices is not).  Not sound, so skipped with the reason in ``roundtrip_skipped``
          (not a finding): a Draco strip or fan, morph targets with rest weights, GPU
          instancing or placements that do not read (the OBJ holds the parts as stored, a notice),
          and inputs ``read_mesh`` refuses.
        """
        import pmwm_codec
        from pmwm_codec.constants import EXTENSION_NAME
        from pmwm_codec.format.document import load_document, read_accessor
        from pmwm_codec.format.glb import split_glb
        from pmwm_codec.format.gltf import find_extension_primitives, placements_by_mesh

        with open(base + ".pmw", "rb") as f:
            pmw_doc = split_glb(f.read(), "the .pmw")[0]
        with open(base + ".glb", "rb") as f:
            out_doc, out_bin = split_glb(f.read(), "the decoded GLB")
        found = {(mi, pi): prim["extensions"][EXTENSION_NAME]
                 for mi, pi, prim in find_extension_primitives(pmw_doc, EXTENSION_NAME)}
        in_doc, in_buffers = load_document(self.path)

        def accessor(doc, buffers, index):
            return read_accessor(doc, buffers, index)

        # the primitives, each still there
        in_meshes, out_meshes = in_doc.get("meshes", []), out_doc.get("meshes", [])
        if len(in_meshes) != len(out_meshes):
            self.finding("primitive-lost", f"input {len(in_meshes)} meshes, decoded GLB {len(out_meshes)}")
        vertices = faces = 0
        for mi, (m_in, m_out) in enumerate(zip(in_meshes, out_meshes)):
            p_in, p_out = m_in.get("primitives", []), m_out.get("primitives", [])
            if len(p_in) != len(p_out):
                self.finding("primitive-lost", f"mesh {mi}: input {len(p_in)} primitives, decoded {len(p_out)}")
            for pi, (a, b) in enumerate(zip(p_in, p_out)):
                where = f"mesh {mi} primitive {pi}"
                drawn = 4 if (mi, pi) in found and a.get("mode", 4) in (5, 6) else a.get("mode", 4)
                if drawn != b.get("mode", 4):  # a progressive strip or fan is the list of triangles it draws
                    self.finding("primitive-lost", f"{where}: mode {a.get('mode', 4)} decoded as {b.get('mode', 4)}")
                lost = set(a.get("attributes", {})) - set(b.get("attributes", {}))
                # flat normals are dropped on purpose, with a notice naming the primitive (viewers compute them)
                named = re.compile(rf"mesh {mi}( \(.*?\))? primitive {pi}\b")
                said = [n for n in report.get("notices") or [] if "NORMAL dropped" in n and named.search(n)]
                lost -= {"NORMAL"} if said else set()
                if lost:
                    self.finding("attributes-lost", f"{where}: {sorted(lost)} missing in the decoded GLB")
                if (mi, pi) in found:
                    vertices += out_doc["accessors"][b["attributes"]["POSITION"]]["count"]
                    faces += out_doc["accessors"][b.get("indices", b["attributes"]["POSITION"])]["count"] // 3
                    continue
                if len(a.get("targets") or []) != len(b.get("targets") or []):
                    self.finding("passthrough-differs", f"{where}: {len(a.get('targets') or [])} morph targets "
                                 f"decoded as {len(b.get('targets') or [])}")
                if "POSITION" in a.get("attributes", {}) and "POSITION" in b.get("attributes", {}):
                    try:
                        want = accessor(in_doc, in_buffers, a["attributes"]["POSITION"])
                    except Exception:  # noqa: BLE001 -- data the library's reader refuses: nothing to compare
                        continue
                    got = accessor(out_doc, [out_bin], b["attributes"]["POSITION"])
                    if want.shape != got.shape or not np.array_equal(want, got):
                        self.finding("passthrough-differs", f"{where}: POSITION {want.shape} decoded as {got.shape}, "
                                     "not the same values")
        if (vertices, faces) != (report["vertices"], report["faces"]):
            self.finding("count-mismatch", f"decoded GLB's progressive primitives {vertices} v / {faces} f, "
                         f"encoder reported {report['vertices']} v / {report['faces']} f")

        # the scene as shown, against the library's own reader of the input
        prims = [p for m in in_meshes for p in m.get("primitives", [])]
        why = None
        if any(DRACO in (p.get("extensions") or {}) and p.get("mode", 4) != 4 for p in prims):
            why = "the input has a Draco-compressed strip or fan, which read_mesh does not read"
        elif any(p.get("targets") for p in prims) and any(w for holder in in_meshes + in_doc.get("nodes", [])
                                                            for w in (holder.get("weights") or [])):
            why = ("the input's morph targets have rest weights (read_mesh poses them, decode's OBJ keeps the stored "
                   "positions)")
        elif any("not placed by the scene's nodes" in n for n in notices):
            why = "the decoded OBJ holds the primitives as stored (decode's notice)"
        if why is None:
            try:
                inp = pmwm_codec.read_mesh(self.path)
            except pmwm_codec.errors.PmwError as exc:
                why = f"read_mesh refuses the input: {str(exc)[:200]}"
        if why is not None:
            self.res["roundtrip_skipped"] = why
            return
        self.res["input_vertices"], self.res["input_faces"] = inp.vertex_count, inp.face_count
        shown = placements_by_mesh(pmw_doc) if pmw_doc.get("nodes") else {}
        tol = 0.0
        for (mi, _), ext in found.items():
            grid = ext["grid"]
            step = float(grid["step"])
            extent = float(np.abs(grid["origin"]).max()) + 2.0 ** int(grid.get("bits", 24)) * step
            for matrix in shown.get(mi, [np.eye(4)]) if pmw_doc.get("nodes") else [np.eye(4)]:
                scale = float(np.abs(np.asarray(matrix)[:3, :3]).sum(axis=1).max()) if matrix is not None else 1.0
                tol = max(tol, scale * ((0.5 + 1 / 16) * step + 4 * 2.0 ** -24 * extent))
        if len(dec_pos) == 0 or inp.vertex_count == 0:
            return
        tol += 1e-8 * float(np.abs(inp.positions).max())
        # the OBJ writes a position once, its texture coordinates and normals beside (``f a/t/n``): what a
        # round trip keeps is the faces not degenerate by position and the distinct positions they use; near
        # copies may share a grid point (fewer positions, each within tol of the input's, checked below),
        # and a face whose corners lie within 2 tol of each other may land on one point
        keep = _proper(dec_pos, dec_faces)
        used = np.unique(dec_faces[keep])
        used_positions = len(np.unique(dec_pos[used], axis=0))
        in_keep, in_firm = _proper(inp.positions, inp.faces), _proper(inp.positions, inp.faces, 2 * tol)
        input_used = len(np.unique(inp.positions[np.unique(inp.faces[in_keep])], axis=0))
        welded = any("duplicate vertices (same position and attributes) welded" in n
                     for n in report.get("notices") or [])
        counts = (used_positions, int(keep.sum()))
        if counts[0] > input_used or counts[1] > int(in_keep.sum()) or (not welded and counts[1] < int(in_firm.sum())):
            self.finding("roundtrip-counts", f"input scene {input_used} positions / {int(in_keep.sum())} f "
                         f"({int(in_firm.sum())} with no two corners within {2 * tol:.3g}), decoded OBJ {counts[0]} "
                         f"positions / {counts[1]} f (used, not degenerate){' after a weld' if welded else ''}")
        from scipy.spatial import cKDTree
        there = cKDTree(inp.positions).query(dec_pos[used], p=np.inf)[0].max()
        back = cKDTree(dec_pos[used]).query(inp.positions, p=np.inf)[0].max()
        self.res["max_err_tol"] = float(max(there, back) / tol) if tol > 0 else None
        if max(there, back) > tol:
            self.finding("roundtrip-positions", f"decoded vertex up to {there:.4g} from the input, input vertex up to "
                         f"{back:.4g} from the decoded; bound {tol:.4g}")

    def validated(self, base: str) -> None:
        """Third parties read what ``pmw`` writes: the Khronos glTF validator reports no error and three.js
        loads (``tools/js/check_gltf.mjs``) the ``.pmw`` and the decoded GLB (``validator-error``,
        ``three-load``; ``-as-input`` when the input has the same error); the input's validator errors are
        kept as information (``input_validator``), so a finding can be told from garbage in.  Skipped
        without ``tools/js/node_modules``."""
        if not os.path.isdir(os.path.join(HERE, "js", "node_modules")) or shutil.which("node") is None:
            self.res["validated"] = False
            return
        files = [base + ".pmw", base + ".glb", self.path]
        p = subprocess.run(["node", os.path.join(HERE, "js", "check_gltf.mjs"), *files], capture_output=True,
                           text=True, cwd=self.work)
        lines = [json.loads(line) for line in p.stdout.splitlines() if line.startswith("{")]
        if p.returncode != 0 or len(lines) != len(files):
            self.finding("validator-failed", f"check_gltf.mjs rc={p.returncode}: {p.stderr.strip()[-300:]}")
            return
        self.res["validated"] = True
        v, three = lines[2]["validator"], lines[2]["three"]
        self.res["input_validator"] = {"errors": v["errors"], "codes": {c: n for c, n in v["codes"].items()},
                                       "three_ok": three["ok"]}
        given = {m["code"] for m in v["messages"] if m["severity"] == 0}
        for name, line in zip(("pmw", "glb"), lines):
            v = line["validator"]
            if v["errors"]:
                errors = [m for m in v["messages"] if m["severity"] == 0]
                first = "; ".join(f"{m['code']} {m.get('pointer') or ''} {m['message'][:80]}" for m in errors)[:300]
                # every error listed (the first 20 messages) of a kind the input has too: garbage in, carried over
                inherited = len(errors) == v["errors"] and {m["code"] for m in errors} <= given
                self.finding("validator-error-as-input" if inherited else "validator-error",
                             f"{name}: {v['errors']} errors {v['codes']}: {first}")
            if not line["three"]["ok"]:
                same = not three["ok"] and three.get("error") == line["three"].get("error")
                self.finding("three-load-as-input" if same else "three-load",
                             f"{name}: {line['three'].get('error', '')[:300]}")

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
    """Positions and triangles of an OBJ that ``pmw decode`` wrote (``v x y z`` and ``f a b c`` lines; a corner
    ``a/t`` or ``a/t/n`` of a textured or shaded mesh counts by its position ``a``, a coloured vertex's
    ``v x y z r g b`` by its position)."""
    v, f = [], []
    with open(path) as fh:
        for line in fh:
            if line.startswith("v "):
                v.append(" ".join(line[2:].split()[:3]))  # x y z (a coloured vertex adds r g b)
            elif line.startswith("f "):
                f.append(" ".join(corner.split("/", 1)[0] for corner in line[2:].split()))
    positions = np.loadtxt(v, ndmin=2) if v else np.zeros((0, 3))
    faces = (np.loadtxt(f, dtype=np.int64, ndmin=2) - 1) if f else np.zeros((0, 3), np.int64)
    return positions, faces


def _oriented(faces: np.ndarray) -> np.ndarray:
    """(m, 3) int64 rows, sorted: each face of ``faces`` (m, 3) int64 (ids of grid points) as its canonical
    oriented triple; a face with two corners on one grid point has no orientation, and is its sorted triple."""
    from pmwm_codec.progressive.topology import face_keys

    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    flat = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 0] == faces[:, 2])
    rows = face_keys(faces)
    rows[flat] = np.sort(faces[flat], axis=1)
    return rows[np.lexsort(rows.T[::-1])]


def _proper(positions: np.ndarray, faces: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """(m,) bool: the faces whose three corners are more than ``tol`` apart (max norm) from each other; with
    ``tol`` 0, three different positions."""
    c = np.asarray(positions, np.float64)[np.asarray(faces, np.int64)]

    def apart(i, j):
        return np.abs(c[:, i] - c[:, j]).max(axis=1) > tol

    return apart(0, 1) & apart(1, 2) & apart(0, 2)


def carries_appearance(path: str) -> bool:
    """Whether the encoder reads the OBJ / PLY / OFF at ``path`` as a glTF document (texture coordinates,
    colours, materials: :func:`pmwm_codec.meshdoc.read_appearance`)."""
    from pmwm_codec.meshdoc import read_appearance

    if not path.lower().endswith((".obj", ".ply", ".off")):
        return False
    try:
        return read_appearance(path)[0] is not None
    except Exception:  # noqa: BLE001 -- a file the encoder refuses: not read as a document
        return False


def snapped_faces(rows: np.ndarray, missing: list, extra: list, limit: int = 512) -> bool:
    """Whether the input faces ``missing`` and the decoded faces ``extra`` (triples of ids into the grid
    ``rows`` (r, 3) int64) pair up one to one, each pair's corners (same orientation, any rotation)
    at most one grid step apart on every axis: the faces of near-copies the encoder put on one grid
    point.  False beyond ``limit`` faces (not checked: the pairing is quadratic)."""
    if len(missing) > limit:
        return False
    left = [rows[list(t)] for t in extra]
    for t in missing:
        face = rows[list(t)]
        match = next((i for i, other in enumerate(left)
                      if any(np.abs(face - np.roll(other, s, axis=0)).max() <= 1 for s in range(3))), None)
        if match is None:
            return False
        left.pop(match)
    return True


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
    root = os.path.abspath(root)  # the workers run in directories of their own
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
    skipped = collections.Counter(r["roundtrip_skipped"].split(":")[0] for r in ok if r.get("roundtrip_skipped"))
    lines.append(f"assets: {sum(r['file'].lower().endswith(ASSETS) for r in rows)} files, "
                 f"{sum('max_err_tol' in r for r in ok)} scene round trips checked, skipped: {dict(skipped)}; "
                 f"{sum(bool(r.get('validated')) for r in ok)} validated, "
                 f"{sum(bool((r.get('input_validator') or {}).get('errors')) for r in ok)} inputs with validator "
                 "errors")
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
