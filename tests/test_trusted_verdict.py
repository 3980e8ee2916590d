"""Attacks on the verdict: keyless forgery, local edits, grafts, noise -- and what must stay authentic.

The forgery is the recipe of ``../shared/security/forge_example.py`` (audit probe 4) on the
current module paths: read every carrier's code from a marked file (public: scale, bits,
hierarchy, nbar) and place the same codes on a deformed copy, then write it as a ``.pmw`` or
check it as a mesh with the original as reference.  Without the keyed ring binding that was
``authentic``; with it, a carrier whose ring changed needs a code only the key holder knows.
"""

from __future__ import annotations

import io

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.format import BaseEvent, ChunkEvent, HeaderEvent, build_pmw, encode_base, iter_events
from pmwm_codec.format.records import pack_batches, unpack_batches
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.progressive.topology import mean_edge_length, unique_edges
from pmwm_codec.progressive.vsplit import MeshState, SplitBatch, split_topology
from pmwm_codec.stream import encode_mesh
from pmwm_codec.verify import verify_mesh, verify_stream
from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.key import WatermarkKey
from tools import attacks


def _marked(mesh, seed=0):
    rng = np.random.default_rng(seed)
    img = rng.integers(0, 256, (16, 16)).astype(np.uint8)
    buf = io.BytesIO()
    # payload version 1: the forgeries below unpack and repack its records
    key = encode_mesh(mesh, buf, watermark=img, key=WatermarkKey.generate(rng=rng), payload_version=1).key
    return buf.getvalue(), key, img


@pytest.fixture(scope="module")
def marked():
    """A noisy icosphere(4) (2,562 vertices), marked: ``(pmw bytes, key, image, full decode)``."""
    data, key, img = _marked(shapes.icosphere(4, noise=0.01, seed=3))
    return data, key, img, pmwm_codec.decode(data)


def _diagonal(positions) -> float:
    return float(np.linalg.norm(positions.max(axis=0) - positions.min(axis=0)))


def smooth_warp(amplitude: float):
    """A smooth deformation moving no point by more than ``amplitude`` times the diagonal."""

    def deform(p):
        p = np.asarray(p, np.float64)
        lo, diag = p.min(axis=0), _diagonal(p)
        x = 2 * np.pi * (p - lo) / (diag / 2)
        return p + amplitude * diag / np.sqrt(3) * np.sin(x[:, [1, 2, 0]])

    return deform


# ------------------------------------------------------------------- the forgery


def _hierarchy(data):
    ext = base = None
    chunks = []
    for ev in iter_events(data):
        if isinstance(ev, HeaderEvent):
            ext = ev.extension
        elif isinstance(ev, BaseEvent):
            base = (np.asarray(ev.positions_int), np.asarray(ev.faces))
        elif isinstance(ev, ChunkEvent):
            chunks.append(unpack_batches(ev.payload))
    return ext, base, chunks


def forge(data, amplitude):
    """Codes of ``data`` transplanted onto its copy warped by ``amplitude`` of the diagonal, keylessly.

    Returns ``(ext, forged base (ints, faces), forged chunks, forged full positions (n, 3) int64,
    codes that found no grid point)``.  Every carrier goes to the grid point nearest its warped
    position that holds its original code relative to the *forged* ring mean (``place_codes``),
    as in the audit's script.
    """
    ext, (b_pos, b_faces), chunks = _hierarchy(data)
    p = wm.WatermarkParams.from_config(ext["watermark"])
    n, m = int(ext["vertexCount"]), int(ext["faceCount"])
    so = MeshState(b_pos, b_faces, n, m)
    for batches in chunks:  # the original's full-resolution grid positions, to warp them
        for b in batches:
            to = split_topology(so, b.v, b.symbols)
            so.positions[to.u] = to.prediction() + b.residual
    top = (1 << Grid.from_config(ext["grid"]).bits) - 1  # the forgery stays on the file's grid
    warped = np.clip(np.rint(smooth_warp(amplitude)(so.positions[:n])), 0, top).astype(np.int64)
    so = MeshState(b_pos, b_faces, n, m)
    sf = MeshState(warped[: len(b_pos)], b_faces, n, m)
    nbar_o = mean_edge_length(b_pos, b_faces)
    nbar_f = mean_edge_length(warped[: len(b_pos)], b_faces)
    out_chunks, failed = [], 0
    for batches in chunks:
        nb = []
        for b in batches:
            to = split_topology(so, b.v, b.symbols)
            so.positions[to.u] = to.prediction() + b.residual
            code = wm.read_codes(so.positions[to.u], to.centroid(), nbar_o, p.scale, p.bits)
            tf = split_topology(sf, b.v, b.symbols)
            pts, ok = wm.place_codes(warped[to.u], tf.centroid(), code, nbar_f, p.scale, p.bits)
            failed += int((~ok).sum())
            pts = np.clip(pts, 0, top)
            sf.positions[tf.u] = pts
            nb.append(SplitBatch(b.v, b.symbols, pts - tf.prediction()))
        out_chunks.append(nb)
    return ext, (sf.positions[: len(b_pos)].copy(), b_faces), out_chunks, sf.positions[:n].copy(), failed


def write_forged_pmw(ext, base, chunks) -> bytes:
    """A fresh ``.pmw`` (plain base) with the original's public extension fields (fileId, watermark)."""
    b_pos, b_faces = base
    eb = encode_base(np.asarray(b_pos, np.int64), np.asarray(b_faces, np.int64), ext["grid"], codec="plain")
    nv, nf = len(b_pos), len(b_faces)
    payloads, meta = [], []
    for batches, c in zip(chunks, ext["chunks"]):
        payloads.append(pack_batches(batches))
        nv += sum(b.size for b in batches)
        nf += sum(b.new_face_count() for b in batches)
        meta.append({"splits": c["splits"], "vertexCount": nv, "faceCount": nf,
                     "geometricError": c["geometricError"], "batches": len(batches)})
    extension = {k: v for k, v in ext.items() if k not in ("version", "chunks")}
    return build_pmw(base=eb, chunks=payloads, chunk_meta=meta, extension=extension)


@pytest.mark.parametrize("amplitude", [0.001, 0.01, 0.1])
def test_codes_transplanted_onto_a_warped_copy_never_verify(marked, amplitude):
    data, key, _img, _ref = marked
    ext, base, chunks, forged_ints, _ = forge(data, amplitude)
    forged = write_forged_pmw(ext, base, chunks)
    as_stream = verify_stream(forged, key)
    assert as_stream.verdict in ("not-authentic", "tampered"), as_stream.as_json()
    positions = Grid.from_config(ext["grid"]).dequantize(forged_ints)
    as_mesh = verify_mesh((positions, _ref.faces), data, key)
    assert as_mesh.verdict in ("not-authentic", "tampered"), as_mesh.as_json()


def test_the_forgery_recipe_transplants_every_code(marked):
    """The attack itself works -- every public code lands on the warped copy, which moved by the
    amount asked for -- so the test above fails for the right reason (the binding), not a broken forge."""
    data, _key, _img, ref = marked
    ext, base, chunks, _ints, failed = forge(data, 0.001)
    forged = pmwm_codec.decode(write_forged_pmw(ext, base, chunks))
    assert failed == 0
    moved = np.linalg.norm(forged.positions - ref.positions, axis=1).max() / _diagonal(ref.positions)
    assert 2e-4 < moved < 2e-3


# ------------------------------------------------------------------- local edits


def _ring_distance(faces, n, sources) -> np.ndarray:
    """(n,) graph distance (in edges) of every vertex to the set ``sources``; large where unreachable."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import dijkstra

    e = unique_edges(faces)
    g = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(n, n)).tocsr()
    d = dijkstra(g, directed=False, indices=np.asarray(sources), unweighted=True, min_only=True)
    return np.where(np.isfinite(d), d, 1e9)


def _local_edit(positions, fraction, amplitude, seed):
    """Move the ``fraction`` of vertices nearest a random vertex, each by ``amplitude`` of the diagonal
    in its own random direction.  Returns ``(edited positions, moved ids)``."""
    rng = np.random.default_rng(seed)
    centre = positions[rng.integers(len(positions))]
    count = max(1, int(round(fraction * len(positions))))
    moved = np.argsort(np.linalg.norm(positions - centre, axis=1))[:count]
    step = rng.normal(size=(count, 3))
    step *= amplitude * _diagonal(positions) / np.linalg.norm(step, axis=1, keepdims=True)
    out = positions.copy()
    out[moved] += step
    return out, moved


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("fraction", [0.01, 0.05])
def test_a_local_edit_is_tampered_and_mapped_where_it_happened(marked, seed, fraction):
    data, key, _img, ref = marked
    edited, moved = _local_edit(ref.positions, fraction, 0.001, seed)
    r = verify_mesh((edited, ref.faces), data, key)
    assert r.verdict == "tampered", r.as_json()
    flagged = np.asarray(r.tamper()["flagged"], np.int64)
    assert np.isin(moved, flagged).mean() >= 0.5
    near = _ring_distance(ref.faces, len(ref.positions), moved)[flagged] <= 2
    assert near.mean() >= 0.8


@pytest.mark.parametrize("amplitude", [1e-5, 1e-4])
def test_noise_at_the_grid_step_is_never_authentic(marked, amplitude):
    data, key, _img, ref = marked
    rng = np.random.default_rng(7)
    noisy = ref.positions + rng.normal(size=ref.positions.shape) * amplitude * _diagonal(ref.positions)
    r = verify_mesh((noisy, ref.faces), data, key)
    assert r.verdict != "authentic", r.as_json()
    assert r.tamper()["flagged"]


def test_a_crop_grafted_onto_another_mesh_is_never_authentic(marked):
    data, key, _img, ref = marked
    keep = np.argsort(ref.positions[:, 2])[-len(ref.positions) // 5 :]  # the top fifth of the sphere
    sub_faces = ref.faces[np.isin(ref.faces, keep).all(axis=1)]
    used = np.unique(sub_faces)
    remap = np.full(len(ref.positions), -1)
    remap[used] = np.arange(len(used))
    other = shapes.torus(24, 12)
    host = np.asarray(other.positions, np.float64) * 0.3 + ref.positions.mean(axis=0)
    positions = np.concatenate([ref.positions[used], host])
    faces = np.concatenate([remap[sub_faces], np.asarray(other.faces) + len(used)])
    r = verify_mesh((positions, faces), data, key)
    assert r.verdict != "authentic", r.as_json()


def test_a_graft_beside_the_whole_marked_mesh_is_tampered_and_its_vertices_are_the_ones_flagged(marked):
    """Every code still reads (the marked mesh is whole), so the failing carriers flag nothing: the tamper
    map must name the grafted vertices themselves (it was empty beside ``tampered``: outside probe)."""
    data, key, _img, ref = marked
    other = shapes.torus(12, 6)
    size = _diagonal(ref.positions)
    host = np.asarray(other.positions, np.float64) * 0.1 * size + ref.positions.max(axis=0) + 0.2 * size
    positions = np.concatenate([ref.positions, host])
    faces = np.concatenate([ref.faces, np.asarray(other.faces) + len(ref.positions)])
    r = verify_mesh((positions, faces), data, key)
    assert r.verdict == "tampered" and r.foreign, r.as_json()
    assert r.tamper()["flagged"] == list(range(len(ref.positions), len(positions)))


def _flip_edges(faces: np.ndarray, count: int, rng) -> tuple:
    """``faces`` (m, 3) with ``count`` interior edges flipped (the two faces of each edge rewired across its other
    diagonal: the same vertices, other triangles); returns (faces, the vertices of the changed faces)."""
    faces = faces.copy()
    changed, used = [], set()
    edge_faces: dict = {}
    for f, tri in enumerate(faces):
        for a, b in ((tri[0], tri[1]), (tri[1], tri[2]), (tri[2], tri[0])):
            edge_faces.setdefault((min(a, b), max(a, b)), []).append(f)
    for (a, b) in rng.permutation(np.array(sorted(edge_faces)))[:, :].tolist():
        pair = edge_faces[(a, b)]
        if len(pair) != 2 or used & set(pair):
            continue
        f, g = pair
        c = int(next(x for x in faces[f] if x not in (a, b)))
        d = int(next(x for x in faces[g] if x not in (a, b)))
        fa = list(faces[f]).index(a)
        first = [a, faces[f][(fa + 1) % 3], faces[f][(fa + 2) % 3]]  # a, then f's winding
        if first[1] == b:  # f = (a, b, c): flipped to (a, d, c) and (d, b, c)
            faces[f], faces[g] = (a, d, c), (d, b, c)
        else:  # f = (a, c, b)
            faces[f], faces[g] = (a, c, d), (d, c, b)
        used |= {f, g}
        changed += [a, b, c, d]
        if len(used) >= 2 * count:
            break
    return faces, np.unique(changed)


def test_faces_rewired_over_the_same_vertices_are_tampered_and_flagged_where(marked):
    """The codes are read from the positions alone: a mesh with every vertex where the reference has it but
    other faces (edges flipped, or faces made anew) read ``authentic``, nothing flagged (outside probe)."""
    data, key, _img, ref = marked
    faces, corners = _flip_edges(np.asarray(ref.faces), 5, np.random.default_rng(4))
    r = verify_mesh((ref.positions, faces), data, key)
    assert r.verdict == "tampered" and r.bit_exact, r.as_json()
    assert r.tamper()["flagged"] == corners.tolist()
    scrambled = np.random.default_rng(5).integers(0, len(ref.positions), ref.faces.shape)
    assert verify_mesh((ref.positions, scrambled), data, key).verdict == "tampered"


def test_a_face_removed_is_tampered_and_its_corners_flagged(marked):
    data, key, _img, ref = marked
    r = verify_mesh((ref.positions, np.delete(ref.faces, 7, axis=0)), data, key)
    assert r.verdict == "tampered", r.as_json()
    assert r.tamper()["flagged"] == sorted(ref.faces[7].tolist())


@pytest.mark.parametrize("winding", [1, -1], ids=["as-is", "reversed"])
def test_a_face_added_twice_is_tampered_and_its_corners_flagged(marked, winding):
    """Faces were compared as sets: a copy of a face the reference has (a double-sided patch, either winding) read
    ``authentic`` (helper-150)."""
    data, key, _img, ref = marked
    faces = np.concatenate([ref.faces, ref.faces[7:8, ::winding]])
    r = verify_mesh((ref.positions, faces), data, key)
    assert r.verdict == "tampered", r.as_json()
    assert r.tamper()["flagged"] == sorted(ref.faces[7].tolist())


# ------------------------------------------------------------------- what must stay authentic


LOSSLESS = {
    "untouched": lambda V, F, rng: (V, F),
    "float32": attacks.float32,
    "similarity": attacks.similarity,
    "reorder": attacks.reorder,
    "all three": attacks.chain(attacks.similarity, attacks.reorder, attacks.float32),
    "winding flipped": lambda V, F, rng: (V, F[:, ::-1]),  # as a mirroring exporter writes them: not compared
    "winding flipped, re-ordered": lambda V, F, rng: attacks.reorder(V, F[:, ::-1], rng),
    # unwelded, every corner its own vertex (a triangle soup): the correspondence names one copy of each vertex,
    # the faces on the others were left out of the comparison and every reference face read missing (tampered)
    "unwelded": lambda V, F, rng: (V[F].reshape(-1, 3), np.arange(F.size).reshape(-1, 3)),
}


@pytest.mark.parametrize("name", sorted(LOSSLESS))
def test_lossless_copies_stay_authentic_with_nothing_flagged(marked, name):
    data, key, img, ref = marked
    V, F = LOSSLESS[name](ref.positions.copy(), ref.faces.copy(), np.random.default_rng(5))
    r = verify_mesh((V, F), data, key)
    assert r.verdict == "authentic", r.as_json()
    assert r.tamper() == {"flagged": [], "fraction": 0.0}
    assert r.bit_exact and r.carriers_read == r.carriers_total


def test_the_untouched_stream_is_authentic_with_nothing_flagged(marked):
    data, key, _img, _ref = marked
    v = verify_stream(data, key)
    assert v.verdict == "authentic"
    assert v.as_json()["tamper"] == {"flagged": [], "fraction": 0.0}
    assert v.as_json()["binding"] == "ring-v2"


def test_a_legacy_mark_without_binding_is_never_authentic(marked):
    """A file marked before the binding (no ``binding`` field) reads its image but cannot prove itself."""
    data, key, img, ref = marked
    legacy = wm.WatermarkParams.from_config({**wm.WatermarkParams.from_config(
        next(iter_events(data)).extension["watermark"]).get_config(), "binding": ""})
    from pmwm_codec.watermark.verify import verdict

    assert not legacy.binding
    assert verdict(500, 500, legacy.bits, bound=bool(legacy.binding)) == "inconclusive"


@pytest.mark.corpus
def test_the_bunny_forgery_fails_and_its_copy_stays_authentic(tmp_path):
    from conftest import corpus_path

    mesh = pmwm_codec.read_mesh(corpus_path("stanford-bunny.obj"))
    data, key, _img = _marked(mesh)
    ext, base, chunks, _forged, _ = forge(data, 0.001)
    assert verify_stream(write_forged_pmw(ext, base, chunks), key).verdict in ("not-authentic", "tampered")
    ref = pmwm_codec.decode(data)
    V, F = attacks.similarity(ref.positions.astype(np.float32).astype(np.float64), ref.faces,
                              np.random.default_rng(0))
    assert verify_mesh((V, F), data, key).verdict == "authentic"
    edited, moved = _local_edit(ref.positions, 0.01, 0.001, 0)
    r = verify_mesh((edited, ref.faces), data, key)
    flagged = np.asarray(r.tamper()["flagged"], np.int64)
    assert r.verdict == "tampered" and np.isin(moved, flagged).mean() >= 0.5
    assert (_ring_distance(ref.faces, len(ref.positions), moved)[flagged] <= 2).mean() >= 0.8


def test_pmw_verify_says_tampered_with_exit_1_and_draws_the_map(marked, tmp_path, capsys):
    import json

    from pmwm_codec.cli import main

    data, key, _img, ref = marked
    (tmp_path / "m.pmw").write_bytes(data)
    key.save(tmp_path / "m.key.json")
    edited, _moved = _local_edit(ref.positions, 0.01, 0.001, 0)
    pmwm_codec.write_mesh(tmp_path / "e.obj", pmwm_codec.Mesh(edited, ref.faces))
    argv = ["verify", str(tmp_path / "e.obj"), "--reference", str(tmp_path / "m.pmw"), "--key",
            str(tmp_path / "m.key.json"), "--json", "--frames", str(tmp_path / "frames")]
    capsys.readouterr()
    assert main(argv) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "tampered" and doc["tamper"]["flagged"] and 0 < doc["tamper"]["fraction"] < 1
    assert (tmp_path / "frames" / "tamper.png").stat().st_size > 0
    assert main(["verify", str(tmp_path / "m.pmw"), "--key", str(tmp_path / "m.key.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "authentic" and doc["tamper"] == {"flagged": [], "fraction": 0.0}


def test_a_legacy_golden_file_still_reads_its_image_but_is_never_authentic():
    """spec/conformance holds files marked before the binding: their image still reads bit-exactly,
    never ``authentic`` (a legacy mark can be transplanted without the key, and it has no chunk MACs)."""
    from pathlib import Path

    base = Path(__file__).resolve().parent.parent / "spec" / "conformance" / "sphere.exact-watermark.v1"
    key = WatermarkKey.load(f"{base}.key.json")
    v = verify_stream(f"{base}.pmw", key)
    assert v.binding == "" and v.as_json()["binding"] is None
    assert np.array_equal(v.results[-1].watermark, key.reference)
    assert v.verdict == "not-authentic" and v.mac["missing"] and any("no MAC" in n for n in v.mac_notes())


@pytest.mark.parametrize("matches, read, bits", [(0, 40, 5), (1, 40, 5), (3, 40, 5), (12, 40, 5), (40, 40, 5),
                                                 (41, 40, 5), (7, 1000, 1), (520, 1000, 1), (160, 3000, 5),
                                                 (3000, 3000, 5), (60, 2000, 6)])
def test_the_chance_tail_is_the_binomial_upper_tail(matches, read, bits):
    """P(at least ``matches`` of ``read`` codes match by chance), against the tail summed exactly
    in rationals: the verdict's threshold (1e-9) is crossed where the exact tail crosses it."""
    from fractions import Fraction
    from math import comb

    from pmwm_codec.watermark.verify import chance_tail

    q = 2**bits - 1  # P(one code matches) = 1 / 2**bits
    exact = float(Fraction(sum(comb(read, i) * q ** (read - i) for i in range(max(matches, 0), read + 1)),
                           2 ** (bits * read)))
    got = chance_tail(matches, read, bits)
    assert got == pytest.approx(exact, rel=1e-9, abs=1e-300)
