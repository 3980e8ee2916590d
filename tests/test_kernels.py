"""The compiled kernels (numba, when installed) and their numpy twins compute the same thing.

Every kernel in :mod:`pmwm_codec.progressive` has a numpy path used when numba is absent;
these tests run both on the same inputs and require identical results, so the path CI runs
(numba, a dependency) and the fallback cannot drift apart.
"""

from __future__ import annotations

import importlib.util
import io
import os

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.errors import FormatError
from pmwm_codec.mesh import Mesh
from pmwm_codec.progressive import topology
from pmwm_codec.progressive.vsplit import MeshState, find_incidences, split_topology

NUMBA = importlib.util.find_spec("numba") is not None


@pytest.fixture(params=[True, False], ids=["compiled", "numpy"])
def kernels(request, monkeypatch):
    """Run a test once with the compiled kernels (when numba is installed) and once without."""
    if request.param and not NUMBA:
        pytest.skip("numba is not installed")
    monkeypatch.setattr(topology, "USE_NUMBA", request.param)
    return request.param


def test_group_order_is_a_stable_argsort(kernels):
    rng = np.random.default_rng(5)
    for c, n in ((10, 3), (1000, 7), (5000, 4000)):
        keys = rng.integers(0, n, c)
        assert np.array_equal(topology.group_order(keys, n), np.argsort(keys, kind="stable"))


def test_edge_ids_and_face_corner_tests_are_the_same_on_both_paths(monkeypatch):
    """topology.edge_ids (its key_ids compiled: a hash table, numbered by first row; numpy: np.unique, by sorted key) numbers
    the undirected edges one to one, with their row counts; any_corner and two_alike_at are numpy's
    expressions, on both paths."""
    rng = np.random.default_rng(3)
    for n, m in ((3, 1), (40, 300), (5000, 20000)):
        faces = rng.integers(0, n, (m, 3))
        flags = rng.random(n) < 0.1
        point = np.arange(n) % 7
        a, b = faces.reshape(-1), faces[:, [1, 2, 0]].reshape(-1)
        keys = np.minimum(a, b) * n + np.maximum(a, b)
        _, key_id, key_count = np.unique(keys, return_inverse=True, return_counts=True)
        for use in (False, NUMBA):
            monkeypatch.setattr(topology, "USE_NUMBA", use)
            ids, counts = topology.edge_ids(a, b, n)
            assert ids.dtype == counts.dtype == np.int64 and len(counts) == len(key_count)
            assert len(np.unique(key_id * len(counts) + ids)) == len(counts)  # one number per edge, one edge per number
            assert np.array_equal(counts[ids], key_count[key_id])
            assert np.array_equal(topology.any_corner(flags, faces), flags[faces].any(axis=1))
            assert np.array_equal(topology.two_alike_at(point, faces), topology.two_alike(point[faces]))


def test_the_first_edges_of_the_extent_check_are_the_same_on_both_paths(monkeypatch):
    """mesh._first_edges (the extent check's sample): compiled and numpy, every face and a stride, zero-length
    edges left out; a mesh below SMALL_JOB_VERTICES never asks for the kernel (reading it loads no numba)."""
    from pmwm_codec import mesh as mesh_module

    big = shapes.torus(80, 30)
    pos = np.asarray(big.positions, np.float64).copy()
    tri = np.asarray(big.faces, np.int64)
    pos[tri[::5, 1]] = pos[tri[::5, 0]]  # some first edges of length zero
    assert len(pos) >= topology.SMALL_JOB_VERTICES
    out = []
    for use in (False, NUMBA):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append([mesh_module._first_edges(pos, tri, stride) for stride in (1, 3)])
    for a, b in zip(*out):
        assert a.dtype == b.dtype and np.array_equal(a, b) and len(a) and (a > 0).all()
    asked = []
    monkeypatch.setattr(topology, "USE_NUMBA", NUMBA)
    monkeypatch.setattr(mesh_module, "compiled", lambda fn: asked.append(fn))
    small = shapes.icosphere(2)
    mesh_module._first_edges(np.asarray(small.positions, np.float64), np.asarray(small.faces, np.int64), 1)
    assert not asked


def test_the_splits_order_is_the_same_on_both_paths(monkeypatch):
    """build._split_order (compiled: a bitmap read word by word; numpy: argsort) of distinct keys: none, one,
    keys on a word's edges (0, 63, 64, n - 1), dense and sparse batches."""
    from pmwm_codec.progressive import build

    rng = np.random.default_rng(9)
    cases = [(np.zeros(0, np.int64), 5), (np.array([0], np.int64), 1), (np.array([64, 63, 0, 129, 127], np.int64), 130)]
    cases += [(rng.choice(n, k, replace=False).astype(np.int64), n) for n, k in ((64, 64), (1000, 7), (5000, 4000))]
    for vf, n in cases:
        out = []
        for use in (False, NUMBA):
            monkeypatch.setattr(topology, "USE_NUMBA", use)
            out.append(build._split_order(vf, n))
        order = np.argsort(vf, kind="stable")
        for got in out:
            assert np.array_equal(got[0], order) and np.array_equal(got[2], vf[order])
            assert np.array_equal(got[1][order], np.arange(len(vf)))


def test_edge_table_is_the_same_on_both_paths(monkeypatch):
    mesh = shapes.torus(30, 12)
    tables = []
    for use in (False, NUMBA):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        tables.append(topology.edge_table(np.asarray(mesh.faces, np.int64), mesh.vertex_count))
    for name in ("keys", "lo", "hi", "count", "he0", "he1"):
        assert np.array_equal(getattr(tables[0], name), getattr(tables[1], name)), name


def _encoded(mesh, bits=16) -> bytes:
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, measure=False, grid_bits=bits)
    return buf.getvalue()


@pytest.mark.parametrize("make, bits", [(lambda: shapes.icosphere(3, 1.0, noise=0.02), 16), (shapes.doubled_faces, 16),
                                        (shapes.flaps, 16), (lambda: shapes.grid(400, 8, hole=False, bump=0.3), 8),
                                        (lambda: shapes.uv_torus(32, 16), 16)],
                         ids=["sphere", "doubled faces", "flaps", "faces without area on the grid", "seams"])
def test_encode_bytes_do_not_depend_on_the_kernels(monkeypatch, make, bits):
    mesh = make()
    monkeypatch.setattr(topology, "USE_NUMBA", False)
    plain = _encoded(mesh, bits)
    monkeypatch.setattr(topology, "USE_NUMBA", NUMBA)
    assert _encoded(mesh, bits) == plain


def test_split_topology_matches_bit_for_bit(monkeypatch):
    """Faces, face order and the float ring sums (the watermark's centroids) agree exactly."""
    mesh = shapes.icosphere(3, 1.0, noise=0.05)
    pm = _progressive(mesh)
    out = []
    for use in (False, NUMBA):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        pos = np.random.default_rng(2).normal(size=(pm.vertex_count, 3))  # floats: summation order shows
        state = MeshState(pos[: len(pm.base_positions)], pm.base_faces, pm.vertex_count, pm.face_count,
                          dtype=np.float64)
        state.positions[:] = pos
        sums = [split_topology(state, b.v, b.symbols).ring_sum for b in pm.batches]
        out.append((state.current_faces().copy(), sums))
    assert np.array_equal(out[0][0], out[1][0])
    for a, b in zip(out[0][1], out[1][1]):
        assert np.array_equal(a, b)


def _progressive(mesh):
    """The encoder's ProgressiveMesh for ``mesh`` (captured from a real encode)."""
    from pmwm_codec.stream import encoder

    got = {}
    orig = encoder.build_progressive

    def capture(*a, **k):
        got["pm"] = orig(*a, **k)
        return got["pm"]

    encoder.build_progressive = capture
    try:
        _encoded(mesh)
    finally:
        encoder.build_progressive = orig
    return got["pm"]


@pytest.mark.parametrize("bad", ["no_face", "three_faces"])
def test_split_topology_refuses_bad_wing_counts_on_both_paths(kernels, bad):
    pm = _progressive(shapes.icosphere(2, 1.0, noise=0.02))
    b = pm.batches[0]
    sym = b.symbols.copy()
    state = pm.new_state()
    inc, owner = find_incidences(state, b.v)
    mine = np.flatnonzero(owner == 0)
    sym[mine] = 1 if bad == "no_face" else 4  # split 0 names none / one per moved face (>= 3)
    faces_before = state.current_faces().copy()
    with pytest.raises(FormatError):
        split_topology(state, b.v, sym)
    assert state.n == len(pm.base_positions) and np.array_equal(state.current_faces(), faces_before)


def test_a_kernel_helper_whose_name_another_definition_took_is_named_when_numba_loads(monkeypatch):
    """A helper's module global becomes its dispatcher when numba loads; a later ``def`` of the same name in the
    module (a quickselect helper named ``_select`` beside the simplifier's ``_select``) had the helper swapped
    in where the other was called ("too many arguments"), and only where numba loaded after the import."""
    pytest.importorskip("numba")

    def helper(a):
        return a

    def other(a, b):
        return a + b

    module = {"helper": other}  # the helper's name, then bound to another function
    monkeypatch.setattr(topology, "_HELPERS", topology._HELPERS + [(module, "helper", helper, {})])
    monkeypatch.setattr(topology, "_numba", None)
    with pytest.raises(RuntimeError, match="kernel helper .*helper is no longer its module's 'helper'"):
        topology._load_numba()
    assert module["helper"] is other


def test_kernels_compile_without_a_writable_cache(monkeypatch):
    """numba refuses ``cache=True`` when no cache dir is writable; the kernel then compiles uncached."""
    numba = pytest.importorskip("numba")
    topology._load_numba()
    real = numba.njit

    def njit(*a, cache=False, **k):
        if cache:
            raise RuntimeError("cannot cache function: no locator available")
        return real(*a, cache=cache, **k)

    monkeypatch.setattr(numba, "njit", njit)
    kernel = topology._jit(topology._counting_order_py)
    keys = np.array([3, 1, 3, 0, 1], np.int64)
    assert np.array_equal(kernel(keys, 4), np.argsort(keys, kind="stable"))


def test_commands_that_run_no_kernel_do_not_import_numba():
    """numba loads on the first kernel call: reading a header stays as quick to start as before."""
    import subprocess
    import sys

    code = ("import sys, pmwm_codec.progressive.simplify, pmwm_codec.progressive.vsplit, pmwm_codec.format; "
            "print('numba' in sys.modules)")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=root)
    assert out.stdout.strip() == "False"


def test_the_compiled_split_lists_the_same_ring_as_numpy(monkeypatch):
    """The ring binding reads the ring of every split: both paths must list it alike."""
    from pmwm_codec.progressive import topology, vsplit
    from pmwm_codec.progressive.build import build_progressive
    from pmwm_codec.progressive.simplify import simplify
    from pmwm_codec.progressive.grid import Grid

    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    grid = Grid.fit(mesh.positions, 14)
    q = grid.quantize(mesh.positions)
    pm = build_progressive(simplify(q, mesh.faces, target_vertices=40), q, grid)

    def rings(use_kernel):
        monkeypatch.setattr(topology, "compiled", topology.compiled if use_kernel else (lambda fn: None))
        monkeypatch.setattr(vsplit, "compiled", topology.compiled if use_kernel else (lambda fn: None))
        state, out = pm.new_state(), []
        for batch in pm.batches:
            topo = vsplit.apply_batch(state, batch)
            out.append((topo.ring_owner.tolist(), topo.ring_a.tolist(), topo.ring_b.tolist()))
        return out

    assert rings(True) == rings(False)


def _live_both_ways(monkeypatch, mesh, face_alive):
    """The :class:`LiveMesh` of ``mesh`` with ``face_alive`` built without and with the kernels."""
    from pmwm_codec.progressive.livemesh import live_mesh

    faces = np.asarray(mesh.faces, np.int64)
    vert_alive = np.zeros(mesh.vertex_count, bool)
    vert_alive[faces[face_alive].ravel()] = True
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(live_mesh(faces, face_alive, vert_alive))
    return out


_ODD_MESHES = {  # boundaries, holes, a non-manifold vertex, several components
    "grid with a hole": shapes.grid(12, 9, hole=True, bump=0.0),
    "bowtie": shapes.bowtie(),
    "doubled faces": shapes.doubled_faces(),
    "flaps": shapes.flaps(),
    "sphere and grid": shapes.components(shapes.icosphere(1, 1.0), shapes.grid(5, 5)),
    # every edge a boundary edge: twice a closed mesh's edges (the compiled edge arrays grow while built)
    "triangle soup": Mesh(np.random.default_rng(3).normal(size=(600, 3)), np.arange(600, dtype=np.int64).reshape(-1, 3)),
}


def _with_degenerate_faces(mesh):
    """``mesh`` plus faces that repeat a corner (self-loop edges, an edge twice in one face)."""
    extra = np.array([[0, 0, 1], [2, 2, 2], [3, 4, 3], [1, 5, 5]], np.int64)
    return Mesh(mesh.positions, np.vstack([np.asarray(mesh.faces, np.int64), extra]))


@pytest.mark.parametrize("name", sorted(_ODD_MESHES))
def test_the_live_mesh_is_the_same_on_both_paths_with_degenerate_faces(monkeypatch, name):
    pytest.importorskip("numba")
    mesh = _with_degenerate_faces(_ODD_MESHES[name])
    plain, fast = _live_both_ways(monkeypatch, mesh, np.ones(mesh.face_count, bool))
    for field in ("keys", "lo", "hi", "count", "he0", "he1"):
        assert np.array_equal(getattr(plain.et, field), getattr(fast.et, field)), field
    assert (plain.et.lo == plain.et.hi).any()  # the self-loops are there
    for a, b in zip(plain.vv + plain.vf + (plain.vv_edge, plain.fcount, plain.boundary, plain.edge_flags, plain.opp),
                    fast.vv + fast.vf + (fast.vv_edge, fast.fcount, fast.boundary, fast.edge_flags, fast.opp)):
        assert np.array_equal(a, b)
    assert plain.edge_flags.any()  # an edge of three faces (a degenerate face's self-loop) marks its vertex


@pytest.mark.parametrize("name", sorted(_ODD_MESHES))
def test_the_live_mesh_is_the_same_on_both_paths(monkeypatch, name):
    pytest.importorskip("numba")
    mesh = _ODD_MESHES[name]
    face_alive = np.random.default_rng(1).random(mesh.face_count) < 0.8  # some faces dead, some vertices too
    plain, fast = _live_both_ways(monkeypatch, mesh, face_alive)
    for field in ("vids", "fids", "loc", "F", "vv_edge", "fcount", "boundary", "edge_flags", "opp"):
        assert np.array_equal(getattr(plain, field), getattr(fast, field)), field
    for field in ("keys", "lo", "hi", "count", "he0", "he1"):
        assert np.array_equal(getattr(plain.et, field), getattr(fast.et, field)), field
    for a, b in zip(plain.vv + plain.vf, fast.vv + fast.vf):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("name", sorted(_ODD_MESHES))
@pytest.mark.parametrize("use", [False, True], ids=["numpy", "compiled"])
def test_the_live_mesh_from_the_previous_one_is_the_fresh_one(monkeypatch, name, use):
    """``live_mesh(..., prev)`` (the simplifier's batches: ids filtered, ``loc`` updated in place) gives the
    arrays a fresh build gives, after faces and vertices die."""
    from pmwm_codec.progressive.livemesh import live_mesh

    if use:
        pytest.importorskip("numba")
    monkeypatch.setattr(topology, "USE_NUMBA", use)
    mesh = _ODD_MESHES[name]
    faces = np.asarray(mesh.faces, np.int64)
    face_alive = np.ones(mesh.face_count, bool)
    rng = np.random.default_rng(2)
    prev = None
    for _ in range(3):
        vert_alive = np.zeros(mesh.vertex_count, bool)
        vert_alive[faces[face_alive].ravel()] = True
        chained = live_mesh(faces, face_alive, vert_alive, prev)
        fresh = live_mesh(faces, face_alive, vert_alive)
        for field in ("vids", "fids", "loc", "F", "vv_edge", "fcount", "boundary", "edge_flags", "opp"):
            assert np.array_equal(getattr(chained, field), getattr(fresh, field)), field
        for a, b in zip(chained.vv + chained.vf, fresh.vv + fresh.vf):
            assert np.array_equal(a, b)
        prev = chained.vids, chained.fids, chained.loc
        face_alive &= rng.random(mesh.face_count) < 0.8


@pytest.mark.parametrize("name", sorted(_ODD_MESHES))
def test_the_candidate_collapses_are_the_same_on_both_paths(monkeypatch, name):
    """Same candidates in the same order, ties (small integer quadrics) and NaN costs included."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import simplify

    mesh = _ODD_MESHES[name]
    lives = _live_both_ways(monkeypatch, mesh, np.ones(mesh.face_count, bool))
    out = []
    for use, live in zip((False, True), lives):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        k = len(live.vids)
        rng = np.random.default_rng(3)
        Q = rng.integers(0, 3, (k, 10)).astype(np.float64)
        Q[::7, 9] = np.nan
        Q[3::11, 9] = np.inf  # infinite costs, ranked between the finite ones and NaN
        Q[5::13] = -0.0  # zero quadrics: costs of -0.0 and 0.0, which tie
        frozen = rng.random(k) < 0.1
        P = np.asarray(mesh.positions, np.float64)[live.vids]
        src, _, opp = topology.half_edges(live.F)
        local = (live.et, live.F, P, opp, live.fcount, live.vv, live.vf, live.vv_edge, np.zeros(len(live.et.keys), bool))
        out.append(simplify._candidates(local, (live.boundary, live.edge_flags), Q, src, frozen))
        few = frozen | (rng.random(k) < 0.7)  # a few vertices left free, visited alone by the compiled kernel
        out.append(simplify._candidates(local, (live.boundary, live.edge_flags), Q, src, few, rows=np.flatnonzero(~few)))
    assert out[0] is not None and len(out[0][0]) > 0 and out[1] is not None
    for a, b in zip(out[0] + out[1], out[2] + out[3]):
        assert np.array_equal(a, b, equal_nan=True)



@pytest.mark.parametrize("name", sorted(_ODD_MESHES))
def test_face_quadrics_are_the_same_bits_on_both_paths(monkeypatch, name):
    """Face planes summed at the corners and boundary planes at the edge ends, in the same order."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import simplify

    mesh = _ODD_MESHES[name]
    pos = np.asarray(mesh.positions, np.float64) + np.random.default_rng(2).normal(0, 0.01, (mesh.vertex_count, 3))
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(simplify.face_quadrics(pos, np.asarray(mesh.faces, np.int64), mesh.vertex_count))
    assert out[0].tobytes() == out[1].tobytes()


def _run_pmw(args, root):
    """``pmw ARGS`` as its own process (``main()`` reading ``sys.argv``, as the console script does);
    returns whether numba was imported, after checking the exit status."""
    import subprocess
    import sys

    code = "import sys; from pmwm_codec.cli import main; rc = main(); print('numba' in sys.modules); sys.exit(rc)"
    out = subprocess.run([sys.executable, "-c", code, *args], capture_output=True, text=True, cwd=root)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1] == "True"


@pytest.mark.skipif(not NUMBA, reason="numba is not installed")
def test_a_small_mesh_on_the_command_line_skips_numba_and_writes_the_same_bytes(tmp_path):
    """``pmw encode`` / ``decode`` of a mesh below SMALL_JOB_VERTICES run the numpy twins in their own
    process (numba's start-up is not paid) and give the bytes the compiled kernels give."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    mesh = shapes.icosphere(3, 1.0, noise=0.02)  # 642 vertices
    assert mesh.vertex_count < topology.SMALL_JOB_VERTICES
    src = tmp_path / "sphere.obj"
    pmwm_codec.write_mesh(str(src), mesh)
    assert not _run_pmw(["encode", str(src), "-o", str(tmp_path / "cli.pmw"), "-q"], root)
    assert not _run_pmw(["decode", str(tmp_path / "cli.pmw"), "-o", str(tmp_path / "cli.obj")], root)
    from pmwm_codec.cli import main

    assert main(["encode", str(src), "-o", str(tmp_path / "lib.pmw"), "-q"]) == 0  # in process: numba as always
    assert main(["decode", str(tmp_path / "lib.pmw"), "-o", str(tmp_path / "lib.obj")]) == 0
    assert topology._one_shot is False  # an in-process call never turns the policy on
    assert (tmp_path / "cli.pmw").read_bytes() == (tmp_path / "lib.pmw").read_bytes()
    assert (tmp_path / "cli.obj").read_bytes() == (tmp_path / "lib.obj").read_bytes()


@pytest.mark.skipif(not NUMBA, reason="numba is not installed")
def test_only_a_one_shot_process_with_numba_unloaded_keeps_a_small_job_off_numba(monkeypatch):
    monkeypatch.setattr(topology, "_plain_job", False)
    monkeypatch.setattr(topology, "_one_shot", False)
    monkeypatch.setattr(topology, "_numba", None)
    topology.job_vertices(10)  # a long-running process: no change
    assert topology.compiled(topology._counting_order_py) is not None
    monkeypatch.setattr(topology, "_one_shot", True)
    monkeypatch.setattr(topology, "_numba", None)
    topology.job_vertices(topology.SMALL_JOB_VERTICES - 1)
    assert topology.compiled(topology._counting_order_py) is None
    topology.job_vertices(topology.SMALL_JOB_VERTICES)  # a big job: numba again
    assert topology.compiled(topology._counting_order_py) is not None
    topology.job_vertices(10)  # numba is loaded now: it stays in use
    assert topology.compiled(topology._counting_order_py) is not None


def test_point_faces_are_the_same_on_both_paths(monkeypatch):
    """Faces whose three corners share one grid point (specks' first test), compiled and numpy."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import simplify

    rng = np.random.default_rng(5)
    values = rng.integers(0, 3, (400, 5))[:, :3]  # a strided view, as the encoder passes its values
    faces = rng.integers(0, 400, (3000, 3))
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(simplify._point_faces(values, faces))
    assert out[0].dtype == out[1].dtype == bool and 0 < out[0].sum() < len(faces)
    assert np.array_equal(out[0], out[1])


def test_repeated_hashes_are_the_same_on_both_paths(monkeypatch):
    """The rows whose hash repeats (weld_groups' candidates): one hash table compiled, one sort in numpy;
    hashes whose low bits are all zero (round floats) and collisions of the table's top-bit slots too."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import seams

    rng = np.random.default_rng(7)
    h = rng.integers(0, 1 << 12, 5000).astype(np.uint64) << np.uint64(52)  # top bits only: many repeats
    h[::3] = rng.integers(0, np.iinfo(np.int64).max, len(h[::3])).astype(np.uint64)
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(seams._repeated_hashes(h))
        assert len(seams._repeated_hashes(np.arange(10, dtype=np.uint64))) == 0
    assert 0 < len(out[0]) < len(h)
    assert np.array_equal(out[0], out[1])


def test_first_incidence_per_split_is_the_same_on_both_paths(monkeypatch):
    """build._first_per_split: the mask kept at each split's first incidence, compiled and numpy."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import build

    rng = np.random.default_rng(11)
    owner = np.sort(rng.integers(0, 300, 2000))[rng.permutation(2000)]
    mask = rng.random(2000) < 0.3
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(build._first_per_split(mask, owner, 300))
    assert out[0].dtype == out[1].dtype == bool and 0 < out[0].sum() < mask.sum()
    assert np.array_equal(out[0], out[1])


def test_reverse_pairs_are_the_same_on_both_paths(monkeypatch):
    """_reverse_pairs (pillows, twin faces): one hash table compiled, one sort in numpy, on faces drawn from
    few vertices (triples of many faces, both orientations, rotations, repeated ids)."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import simplify

    rng = np.random.default_rng(13)
    faces = rng.integers(0, 9, (4000, 3))
    faces[::5] = rng.integers(0, 5000, (800, 3))
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(simplify._reverse_pairs(faces))
    assert 0 < out[0][0].sum() < len(faces) and out[0][1].max() > 2
    for a, b in zip(*out):
        assert a.dtype == b.dtype and np.array_equal(a, b)


def test_the_owner_layers_relaxed_surface_and_areas_are_the_same_bits_on_both_paths(monkeypatch):
    """owner._relaxed / _vertex_areas: compiled loops and numpy sums, bit for bit, on a noisy sphere with a
    degenerate face, a repeated corner and a point on no face."""
    pytest.importorskip("numba")
    from pmwm_codec.watermark import owner

    mesh = shapes.icosphere(3, 1.0, noise=0.05)
    points = np.vstack([mesh.positions, [[3.0, 0.0, 0.0]]]).astype(np.float64)
    faces = np.vstack([mesh.faces, [[0, 0, 1], [2, 2, 2]]]).astype(np.int64)
    assert len(faces) >= owner._COMPILED_FACES
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append((owner._relaxed(points, faces), owner._vertex_areas(points, faces)))
    assert np.array_equal(out[0][1][-1:], [0.0]) and np.array_equal(out[0][0][-1], points[-1])
    for a, b in zip(*out):
        assert np.array_equal(a, b)


def test_an_owner_marked_encode_writes_the_same_bytes_on_both_paths(monkeypatch):
    pytest.importorskip("numba")
    from pmwm_codec.watermark.key import WatermarkKey

    mesh = shapes.icosphere(4, 1.0, noise=0.02)
    key = WatermarkKey.generate(rng=np.random.default_rng(3), owner_id=0x0123456789ABCDEF)
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        buf = io.BytesIO()
        pmwm_codec.encode(mesh, buf, key=key, owner_id=key.owner_id, measure=False)
        out.append(buf.getvalue())
    assert out[0] == out[1]


def test_the_affordable_candidates_and_offer_ranks_are_the_same_on_both_paths(monkeypatch):
    """_affordable (the quantile of the groups' first costs: odd and even group counts, ties, NaN) and
    _offer_ranks (cost buckets, shuffled ties; a NaN cost last), compiled and numpy."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import simplify

    rng = np.random.default_rng(17)
    for trial in range(40):
        c = int(rng.integers(1, 300))
        cu = np.sort(rng.integers(0, max(1, c // 2), c))
        cost = rng.choice([0.0, -0.0, 1.0, 1e-13, 2.5, 7.0], c) if trial % 2 else rng.random(c) * 10.0 ** (trial % 7)
        if trial % 10 == 3:
            cost[rng.integers(c)] = np.nan
        if trial % 10 == 5:  # a quadric error rounded below zero ranks with the zero costs
            cost[rng.integers(c)] = -1e-9
        cols = (cu, cu + 1, np.arange(c), cost)
        out = []
        for use in (False, True):
            monkeypatch.setattr(topology, "USE_NUMBA", use)
            out.append((simplify._affordable(*cols, simplify.BATCH_QUANTILE), simplify._offer_ranks(cu, cost)))
        (aff0, rank0), (aff1, rank1) = out
        assert all(a.dtype == b.dtype and np.array_equal(a, b, equal_nan=True) for a, b in zip(aff0, aff1))
        assert rank0.dtype == rank1.dtype and np.array_equal(rank0, rank1)
        if np.isnan(cost).any():  # ranks last on every CPU (a cast of NaN to int64 gave x86's smallest integer)
            assert rank0[np.isnan(cost)].min() > rank0[~np.isnan(cost)].max(initial=-1)
        if (cost < 0).any():
            first = np.argsort(rank0)[: int(np.count_nonzero(cost <= 1e-13))]
            assert (cost[first] <= 1e-13).all()


def test_the_compiled_permutation_draws_numpys_stream():
    """pcg64.permutation (SeedSequence, PCG64 and Generator.permutation redone in a kernel) gives
    ``np.random.default_rng(seed).permutation(c)`` and pcg64.integers_63 its ``integers(0, 2**63, n)``: seeds
    of one and two 32-bit words (0, 2**32 - 1,
    2**32, ...), c from 0 past 2**16 (the masks of every width), the candidate counts _offer_ranks seeds with."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import pcg64

    perm = topology.compiled(pcg64.permutation)
    seeds = (0, 1, 2, 3, 17, 1000, 65536, 2**31, 2**32 - 1, 2**32, 2**32 + 7, 2**40 + 3, 2**63 - 1)
    for seed in seeds:
        for c in (0, 1, 2, 3, 10, 257, 5000):
            assert np.array_equal(perm(seed, c), np.random.default_rng(seed).permutation(c)), (seed, c)
    for c in (*range(0, 600, 7), 70001):
        assert np.array_equal(perm(c, c), np.random.default_rng(c).permutation(c)), c
    integers = topology.compiled(pcg64.integers_63)  # seams._rim's weights
    for seed in (0, 1, 0x5EA3, 2**40 + 3):
        for n in (0, 1, 2, 1000, 100001):
            assert np.array_equal(integers(seed, n), np.random.default_rng(seed).integers(0, 2**63, n, dtype=np.int64))


def test_faces_touching_others_are_the_same_on_both_paths(monkeypatch):
    """_touch_others (deferred pillows, specks): compiled and numpy, on random faces and choices (none, some,
    all chosen; repeated vertices)."""
    from pmwm_codec.progressive import simplify

    rng = np.random.default_rng(41)
    for trial in range(60):
        n = int(rng.integers(3, 200))
        faces = rng.integers(0, n, (int(rng.integers(1, 300)), 3))
        chosen = rng.random(len(faces)) < [0.0, 0.1, 0.5, 0.95, 1.0][trial % 5]
        out = []
        for use in (False, NUMBA):
            monkeypatch.setattr(topology, "USE_NUMBA", use)
            out.append(simplify._touch_others(faces, chosen, n))
        assert out[0].dtype == out[1].dtype == bool and np.array_equal(out[0], out[1]), trial


def test_fin_vertices_are_the_same_on_both_paths(monkeypatch):
    """_fin_vertices (the ends of edges of more than two faces): compiled and numpy, on random faces."""
    from pmwm_codec.progressive import simplify

    rng = np.random.default_rng(43)
    for trial in range(40):
        n = int(rng.integers(3, 100))
        et = topology.edge_table(rng.integers(0, n, (int(rng.integers(1, 200)), 3)), n)
        out = []
        for use in (False, NUMBA):
            monkeypatch.setattr(topology, "USE_NUMBA", use)
            out.append(simplify._fin_vertices(et, n))
        assert out[0].dtype == out[1].dtype == bool and np.array_equal(out[0], out[1]), trial


def test_the_compiled_quantile_is_numpys_on_ties_sorted_and_reversed_input():
    """_quantile_kernel's own selection (quickselect, from 2,048 values after a radix pass; not numpy's partition)
    gives np.quantile's value, bit for bit: random, few distinct values, all equal, sorted and reversed (a
    quickselect's hard cases), one value."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import simplify

    kernel = topology.compiled(simplify._quantile_kernel)
    rng = np.random.default_rng(29)
    for trial in range(400):
        g = int(rng.integers(1, 40)) if trial % 2 else int(rng.integers(1, 20000))
        x = [rng.random(g) * 10.0 ** (trial % 9 - 4), rng.integers(0, 4, g).astype(np.float64), np.full(g, 0.5),
             np.sort(rng.random(g)), np.sort(rng.random(g))[::-1].copy()][trial % 5]
        for q in (0.0, 0.3, 0.5, 0.75, 0.999):
            got = kernel(x.copy(), q)
            assert got == np.quantile(x, q) and np.signbit(got) == np.signbit(np.quantile(x, q)), (trial, g, q)
    # the radix pass's key order at the edges of the floats: negatives, both zeros, infinities, subnormals (the
    # value numpy's; a zero's sign is whichever the selection meets first, which no <= test sees)
    edges = np.array([-np.inf, -1e300, -2.5, -5e-324, -0.0, 0.0, 5e-324, 1e-310, 3.0, 1e300, np.inf])
    for trial in range(60):
        g = int(rng.integers(2048, 6000))
        x = rng.choice(edges, g) if trial % 2 else np.concatenate([rng.choice(edges, g // 2), rng.normal(size=g - g // 2)])
        for q in (0.0, 0.3, 0.5, 0.75, 0.999):
            with np.errstate(invalid="ignore"):  # numpy's inf - inf between the two order statistics: NaN
                got, want = kernel(x.copy(), q), np.quantile(x, q)
            assert got == want or (np.isnan(got) and np.isnan(want)), (trial, g, q, got, want)
            if got != 0.0 and not np.isnan(got):
                assert np.signbit(got) == np.signbit(want), (trial, g, q)


def test_grouped_symbols_match_the_argsort(kernels):
    """The payload encoder's symbols moved from face-slot order to the grouped order of distinct corners."""
    from pmwm_codec.format.records_v2 import _grouped_symbols

    rng = np.random.default_rng(11)
    for k, cap in ((0, 5), (1, 1), (7, 9), (3000, 20000), (5000, 1 << 30)):
        inc = rng.choice(cap, k, replace=False).astype(np.int64)
        symbols = rng.integers(0, 5, k).astype(np.uint8)
        want = np.empty(k, np.uint8)
        want[np.argsort(inc)] = symbols
        assert np.array_equal(_grouped_symbols(inc, symbols), want)


@pytest.mark.parametrize("make", [shapes.flaps, shapes.doubled_faces])
def test_twin_counts_are_the_same_on_both_paths(monkeypatch, make):
    from pmwm_codec.progressive import simplify as S
    from pmwm_codec.progressive.livemesh import live_mesh

    mesh = make()
    live = live_mesh(mesh.faces.copy(), np.ones(mesh.face_count, bool), np.ones(mesh.vertex_count, bool))
    twin = S.twin_faces(live.F)
    out = []
    for use in (False, NUMBA):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(S._twin_counts(live.et, live.F[twin], len(live.vids)))
    assert twin.any() and out[0][0].any()
    for a, b in zip(*out):
        assert a.dtype == b.dtype and np.array_equal(a, b)


def test_a_face_turned_over_marks_its_edges_ends_on_both_paths(monkeypatch):
    """An edge whose two faces run it the same way (one face turned over) marks both its ends (bit 1 of
    ``edge_flags``), the same with and without the kernels; boundary counts agree too."""
    pytest.importorskip("numba")
    grid = shapes.grid(6, 6, hole=False, bump=0.0)
    faces = np.asarray(grid.faces, np.int64).copy()
    faces[3] = faces[3][::-1]
    plain, fast = _live_both_ways(monkeypatch, Mesh(grid.positions, faces), np.ones(len(faces), bool))
    assert np.array_equal(plain.boundary, fast.boundary) and np.array_equal(plain.edge_flags, fast.edge_flags)
    turned = np.zeros(plain.vv[0].shape[0] - 1, bool)
    turned[np.unique(faces[3])] = True  # its interior edges' ends are among its corners
    assert (plain.edge_flags & 1).any() and not (plain.edge_flags[~turned] & 1).any()


def test_a_prefetch_hint_compiles_for_rows_and_items_and_changes_nothing(kernels):
    from pmwm_codec.format import records_v2

    rows, items, index = np.arange(30).reshape(10, 3), np.arange(10), np.array([9, 0, 4])
    before = rows.copy(), items.copy()

    def hint_all(rows, items, index):
        records_v2._prefetch_rows(rows, index, 0, len(index))
        records_v2._prefetch_rows(items, index, 0, len(index))
        return rows[index[0], 2] + items[index[2]]

    kernel = topology.compiled(hint_all) if kernels else hint_all
    assert kernel(rows, items, index) == 29 + 4
    assert np.array_equal(rows, before[0]) and np.array_equal(items, before[1])


@pytest.mark.parametrize("seed", range(6))
def test_seam_pairs_chosen_are_the_same_on_both_paths(monkeypatch, seed):
    """seams.choose_pairs: Luby rounds over (n,) arrays in numpy, over the pairs only compiled; random pairs of
    half collapses on a real neighbour CSR (many conflicts, tied costs, a vertex in several pairs)."""
    pytest.importorskip("numba")
    from pmwm_codec.progressive import seams
    from pmwm_codec.progressive.livemesh import live_mesh

    rng = np.random.default_rng(seed)
    mesh = shapes.icosphere(3, 1.0)
    faces = np.asarray(mesh.faces, np.int64)
    n = mesh.vertex_count
    live = live_mesh(faces, np.ones(len(faces), bool), np.ones(n, bool))
    h = 400
    e = rng.integers(0, len(live.et.lo), h)
    flip = rng.random(h) < 0.5
    hu = np.where(flip, live.et.lo[e], live.et.hi[e])
    hv = np.where(flip, live.et.hi[e], live.et.lo[e])
    p = 150
    i, j = rng.integers(0, h, p), rng.integers(0, h, p)
    cost = rng.integers(0, 20, p).astype(np.float64)  # ties
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(seams.choose_pairs(hu, hv, i, j, cost, live.vv, n, rounds=3 + seed))
    assert 0 < len(out[0]) < p
    assert out[0].dtype == out[1].dtype and np.array_equal(out[0], out[1])


def test_siphash_is_the_same_on_both_paths(monkeypatch):
    """codec.siphash24: lanes sorted and hashed block by block in numpy, lane by lane compiled; random keys and
    messages of every length up to 40 bytes, and none."""
    pytest.importorskip("numba")
    from pmwm_codec.watermark import codec

    rng = np.random.default_rng(17)
    nbytes = rng.integers(0, 41, 300)
    message = np.zeros((300, 48), np.uint8)
    for i, n in enumerate(nbytes):
        message[i, :n] = rng.integers(0, 256, n)
    key = rng.integers(0, 256, 16).astype(np.uint8).tobytes()
    out = []
    for use in (False, True):
        monkeypatch.setattr(topology, "USE_NUMBA", use)
        out.append(codec.siphash24(key, message, nbytes))
        assert len(codec.siphash24(key, np.zeros((0, 8), np.uint8), np.zeros(0, np.int64))) == 0
    distinct = {message[i, :n].tobytes() for i, n in enumerate(nbytes)}
    assert out[0].dtype == out[1].dtype == np.uint64 and len(np.unique(out[0])) == len(distinct)
    assert np.array_equal(out[0], out[1])


def test_the_extent_checks_median_is_numpys():
    """mesh._median (one partition) gives float(np.median(x)) bit for bit: odd and even lengths, ties, one value."""
    from pmwm_codec import mesh as meshmod

    rng = np.random.default_rng(23)
    for trial in range(500):
        k = int(rng.integers(1, 60))
        x = rng.random(k) * 10.0 ** int(rng.integers(-8, 8)) if trial % 3 else rng.integers(1, 4, k).astype(np.float64)
        got, want = meshmod._median(x), float(np.median(x))
        assert got == want and np.signbit(got) == np.signbit(want), (x, got, want)
