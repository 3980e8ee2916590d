"""The progressive mesh engine: exact round trips, valid levels, coarse bases, vectorised == reference."""

from __future__ import annotations

import numpy as np
import pytest

from pmwm_codec.mesh import read_mesh
from pmwm_codec.progressive.build import build_progressive
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.progressive.simplify import simplify
from pmwm_codec.progressive.topology import edge_table, face_keys
from pmwm_codec.progressive.vsplit import MOVE_BOTH, MOVE_LEFT, MOVE_RIGHT, STAY, MeshState, apply_batch
from pmwm_codec import shapes

from conftest import CORPUS_MESHES, corpus_path


def progressive_of(mesh, bits=16, target=0):
    grid = Grid.fit(mesh.positions, bits)
    q = grid.quantize(mesh.positions)
    log = simplify(q, mesh.faces, target_vertices=target)
    return build_progressive(log, q, grid), q


def decode_levels(pm):
    """Yield (positions, faces) copies after the base and after every batch."""
    state = pm.new_state()
    yield state.current_positions().copy(), state.current_faces().copy()
    for batch in pm.batches:
        apply_batch(state, batch)
        yield state.current_positions().copy(), state.current_faces().copy()


def assert_same_mesh(pm, q, faces, positions, decoded_faces):
    """Decoded == input up to vertex renumbering: identical oriented faces, identical grid positions."""
    assert np.array_equal(positions[pm.vertex_order], q)
    inverse = np.empty_like(pm.vertex_order)
    inverse[pm.vertex_order] = np.arange(len(inverse))
    got = face_keys(inverse[decoded_faces])
    want = face_keys(faces[pm.face_order])
    assert np.array_equal(got, want)


def duplicate_count(faces):
    return len(faces) - len(np.unique(np.sort(faces, axis=1), axis=0))


def assert_valid_level(positions, faces, input_had_nonmanifold_edges, input_duplicates=0):
    n = len(positions)
    # no degenerate faces
    assert np.all((faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2]))
    # no duplicate faces (either orientation)
    assert duplicate_count(faces) <= input_duplicates
    et = edge_table(faces, n)
    if not input_had_nonmanifold_edges:
        assert et.count.max() <= 2
    # consistent orientation: the two half-edges of an interior edge run opposite ways
    two = et.count == 2
    src = faces.reshape(-1)
    assert np.all(src[et.he0[two]] != src[et.he1[two]])


def test_generated_meshes_round_trip_exactly(generated_mesh):
    name, mesh = generated_mesh
    pm, q = progressive_of(mesh)
    *_, (positions, faces) = decode_levels(pm)
    assert_same_mesh(pm, q, mesh.faces, positions, faces)


def test_every_level_of_generated_meshes_is_valid(generated_mesh):
    name, mesh = generated_mesh
    had_fin = edge_table(mesh.faces, mesh.vertex_count).count.max() > 2
    pm, _ = progressive_of(mesh)
    for positions, faces in decode_levels(pm):
        assert_valid_level(positions, faces, had_fin, duplicate_count(mesh.faces))


@pytest.mark.parametrize("maker", [lambda: shapes.icosphere(4, 2.0, noise=0.01), lambda: shapes.torus(80, 40, twist=0.1)])
def test_closed_meshes_coarsen_below_two_percent_or_200(maker):
    mesh = maker()
    pm, _ = progressive_of(mesh, target=0)
    assert len(pm.base_positions) <= max(0.02 * mesh.vertex_count, 200)


def test_non_manifold_parts_stay_in_the_base():
    mesh = shapes.bowtie()
    pm, q = progressive_of(mesh)
    # the pinch vertex and the fin's three vertices are base vertices (ids < n0)
    et = edge_table(mesh.faces, mesh.vertex_count)
    fin = np.flatnonzero(et.count > 2)
    fin_vertices = np.unique(np.concatenate([et.lo[fin], et.hi[fin]]))
    n0 = len(pm.base_positions)
    assert np.all(pm.vertex_order[fin_vertices] < n0)


def test_twin_faces_are_opposite_pairs_alone_on_their_three_vertices():
    from pmwm_codec.progressive.simplify import twin_faces

    faces = np.array([[0, 1, 2], [2, 1, 0],  # a pillow
                      [3, 4, 5], [3, 4, 5],  # the same face twice, facing the same way
                      [6, 7, 8], [8, 7, 6], [7, 6, 8],  # three faces on one vertex triple
                      [0, 2, 9], [1, 0, 9]], np.int64)
    assert twin_faces(faces).tolist() == [True, True] + [False] * 7
    assert twin_faces(np.array([[1, 0, 2], [0, 1, 2]])).tolist() == [True, True]  # rotations do not matter
    assert twin_faces(np.array([[1, 0, 2], [2, 1, 0]])).tolist() == [False, False]  # 1 0 2 is 2 1 0 rotated


def test_flaps_do_not_lock_the_surface_edge_they_are_glued_on():
    """A doubled triangle glued onto a surface edge ab (the VRIP dragons carry hundreds) makes ab a
    four-face edge and gives a and b two faces more than their disk: such vertices collapse like any
    other (the flap moves with them), only the flaps' tips stay in the base (undoing their collapse
    would grow a face from nothing)."""
    from pmwm_codec.progressive.simplify import twin_faces

    mesh = shapes.flaps()
    twin = twin_faces(mesh.faces)
    flaps = mesh.faces[twin][0::2]  # (a, b, tip) of each flap
    pm, q = progressive_of(mesh, target=0)
    n0 = len(pm.base_positions)
    glued = np.unique(flaps[:, :2])
    assert np.all(pm.vertex_order[flaps[:, 2]] < n0)  # the tips stay
    assert np.mean(pm.vertex_order[glued] < n0) < 0.25  # the glued ends mostly go (before: all stayed)
    assert n0 <= len(flaps) + max(0.02 * mesh.vertex_count, 20)
    *_, (positions, faces) = decode_levels(pm)
    assert_same_mesh(pm, q, mesh.faces, positions, faces)


@pytest.mark.parametrize("use_numba", [False, True], ids=["numpy", "compiled"])
def test_a_collapse_may_delete_a_face_beside_the_edge_a_flap_hangs_from(monkeypatch, use_numba):
    """Collapsing a -> y deletes the surface face (a, b, y) whose other edge at a, ab, carries a flap
    (four faces): the split that undoes it names the face from the first moved face on ab that can
    (the surface's or the flap's), so the collapse is legal; with the flap's edges unmarked it is not."""
    from pmwm_codec.progressive import simplify as S
    from pmwm_codec.progressive import topology
    from pmwm_codec.progressive.livemesh import live_mesh
    from pmwm_codec.progressive.topology import half_edges

    monkeypatch.setattr(topology, "USE_NUMBA", use_numba and topology.USE_NUMBA)
    mesh = shapes.flaps()
    P = Grid.fit(mesh.positions, 16).quantize(mesh.positions).astype(np.float64)
    live = live_mesh(mesh.faces.copy(), np.ones(mesh.face_count, bool), np.ones(mesh.vertex_count, bool))
    F, et = live.F, live.et
    src, _, opp = half_edges(F)
    twin_edge, _ = S._twin_counts(et, F[S.twin_faces(F)], len(P))
    cu, cv = [], []
    for a, b, _tip in F[S.twin_faces(F)][0::2]:
        for f in F[(F == a).any(1) & (F == b).any(1) & ~S.twin_faces(F)]:
            cu.append(a)
            cv.append(int(np.setdiff1d(f, [a, b])[0]))  # the surface face's third vertex
    cu, cv = np.array(cu), np.array(cv)
    ce = et.find(cu, cv)
    legal = [S._legal(cu, cv, ce, (et, F, P[live.vids], opp, live.fcount, live.vv, live.vf, live.vv_edge, marks))
             for marks in (twin_edge, np.zeros_like(twin_edge))]
    assert len(cu) >= 20 and legal[0].mean() > 0.5
    assert not legal[1].any()


def test_collapses_of_a_batch_never_interact():
    """Removed vertices pairwise non-adjacent, kept vertices distinct, no kept vertex next to another's removed one."""
    mesh = shapes.icosphere(3, 1.0, noise=0.03)
    grid = Grid.fit(mesh.positions, 16)
    q = grid.quantize(mesh.positions)
    log = simplify(q, mesh.faces)
    faces = mesh.faces.copy()
    alive = np.ones(len(faces), bool)
    for batch in log.batches:
        live = faces[alive]
        et = edge_table(live, mesh.vertex_count)
        adj = {}
        for a, b in zip(et.lo, et.hi):
            adj.setdefault(int(a), set()).add(int(b))
            adj.setdefault(int(b), set()).add(int(a))
        removed = set(int(u) for u in batch.u)
        kept = [int(v) for v in batch.v]
        assert len(set(kept)) == len(kept)
        for u, v in zip(batch.u, batch.v):
            assert not (adj[int(u)] & removed)  # no other removed vertex next to u
            assert v in adj[int(u)]
            assert not ((adj[int(v)] & removed) - {int(u)})  # v next to no other removed vertex
        # advance the reference mesh
        dead = np.concatenate([batch.del_left[batch.del_left >= 0], batch.del_right[batch.del_right >= 0]])
        alive[dead] = False
        sub = faces[batch.moved_face]
        faces[batch.moved_face] = np.where(sub == batch.u[batch.moved_by][:, None], batch.v[batch.moved_by][:, None], sub)


def reference_apply(state: MeshState, batch):
    """Slow per-split reference decoder: one split at a time, by definition of the symbols."""
    n0, m0 = state.n, state.m
    faces = state.faces
    inc = [c for c in range(3 * m0) if faces.flat[c] in set(batch.v.tolist())]
    assert len(inc) == len(batch.symbols)
    index_of = {int(v): i for i, v in enumerate(batch.v)}
    new_faces = []
    ring = {i: [] for i in range(len(batch.v))}
    for corner, sym in zip(inc, batch.symbols):
        f, c = divmod(corner, 3)
        v = int(faces[f, c])
        i = index_of[v]
        u = n0 + i
        a, b = int(faces[f, (c + 1) % 3]), int(faces[f, (c + 2) % 3])
        if sym == STAY:
            continue
        ring[i] += [a, b]
        if sym in (MOVE_LEFT, MOVE_BOTH):
            new_faces.append((u, v, a))
            ring[i] += [v, a]
        if sym in (MOVE_RIGHT, MOVE_BOTH):
            new_faces.append((v, u, b))
            ring[i] += [v, b]
        faces[f, c] = u
    for i in range(len(batch.v)):
        pts = state.positions[ring[i]]
        state.positions[n0 + i] = pts.sum(0) // len(ring[i]) + batch.residual[i]
    state.faces[m0 : m0 + len(new_faces)] = new_faces
    state.n = n0 + len(batch.v)
    state.m = m0 + len(new_faces)


def test_vectorised_batch_apply_equals_the_per_split_reference():
    mesh = shapes.components(shapes.icosphere(2, 1.0, noise=0.05), shapes.grid(12, 12, hole=True))
    pm, _ = progressive_of(mesh)
    fast = pm.new_state()
    slow = pm.new_state()
    for batch in pm.batches:
        apply_batch(fast, batch)
        reference_apply(slow, batch)
        assert fast.n == slow.n and fast.m == slow.m
        assert np.array_equal(fast.current_faces(), slow.current_faces())
        assert np.array_equal(fast.current_positions(), slow.current_positions())


def test_the_builders_full_values_are_those_a_replay_of_its_batches_decodes():
    """decoded_positions reads the builder's last state (pm.full_values): the same as replaying the records,
    also when the embed hook moves the new vertices (a watermark)."""
    import dataclasses

    from pmwm_codec.distortion import decoded_positions

    mesh = shapes.components(shapes.icosphere(2, 1.0, noise=0.05), shapes.grid(12, 12, hole=True))
    grid = Grid.fit(mesh.positions, 16)
    q = grid.quantize(mesh.positions)

    def embed(j, topo, values, state):
        return values + np.array([1 + j % 3, -1, 0])

    pm = build_progressive(simplify(q, mesh.faces), q, grid, embed=embed)
    assert pm.full_values is not None
    got = decoded_positions(pm, grid)
    want = decoded_positions(dataclasses.replace(pm, full_values=None), grid)
    assert np.array_equal(got, want)
    assert not np.array_equal(got, grid.dequantize(q))  # the hook moved vertices


@pytest.mark.corpus
@pytest.mark.parametrize("name", CORPUS_MESHES)
def test_corpus_meshes_round_trip_and_every_level_is_valid(name):
    mesh = read_mesh(corpus_path(f"{name}.obj"))
    had_fin = edge_table(mesh.faces, mesh.vertex_count).count.max() > 2
    target = max(mesh.vertex_count // 100, 100)
    pm, q = progressive_of(mesh, target=target)
    last = None
    for positions, faces in decode_levels(pm):
        assert_valid_level(positions, faces, had_fin, duplicate_count(mesh.faces))
        last = positions, faces
    assert_same_mesh(pm, q, mesh.faces, *last)
    if name in ("cow", "fandisk"):
        assert len(pm.base_positions) <= max(0.02 * mesh.vertex_count, 200)


def _candidates_of(mesh):
    """The local mesh of ``mesh`` on a 16-bit grid and its first batch's candidate collapses."""
    from pmwm_codec.progressive import simplify as S
    from pmwm_codec.progressive.livemesh import live_mesh
    from pmwm_codec.progressive.topology import half_edges

    P = Grid.fit(mesh.positions, 16).quantize(mesh.positions).astype(np.float64)
    live = live_mesh(mesh.faces.copy(), np.ones(mesh.face_count, bool), np.ones(mesh.vertex_count, bool))
    src, _, opp = half_edges(live.F)
    local = (live.et, live.F, P[live.vids], opp, live.fcount, live.vv, live.vf, live.vv_edge,
             np.zeros(len(live.et.keys), bool))
    Q = S.face_quadrics(P, mesh.faces, mesh.vertex_count)[live.vids]
    return local, S._candidates(local, (live.boundary, live.edge_flags), Q, src, np.zeros(len(live.vids), bool)), len(live.vids)


@pytest.mark.parametrize("name", ["grid_with_hole", "bowtie", "doubled_faces"])
def test_a_stalled_batch_is_chosen_again_among_the_legal_candidates_only(name):
    """Few winners: every candidate is tested and only the legal ones offer again; enough winners: untouched."""
    from conftest import GENERATED
    from pmwm_codec.progressive import simplify as S

    mesh, cand, n = _candidates_of(GENERATED[name]())
    legal = S._legal(*cand[:3], mesh)
    assert 0 < legal.sum() < len(legal)  # the meshes have illegal cheap collapses to filter
    again = S._unstalled(cand, np.zeros(0, np.int64), mesh, n)
    for got, want in zip(again, cand):
        assert np.array_equal(got, want[legal])
    offering = len(np.unique(cand[0]))
    enough = np.arange(int(np.ceil(S.STALL_FRACTION * offering)))
    assert S._unstalled(cand, enough, mesh, n) is cand


def test_after_a_stalled_batch_every_later_one_selects_among_the_legal_candidates_from_the_start(monkeypatch):
    """The batch that stalls (here: made to, the third) is chosen again among the legal candidates; every batch
    after it is given ``legal_only`` and selects once, among those only; the ones before are not."""
    from pmwm_codec.progressive import simplify as S

    mesh = shapes.icosphere(4, 1.0, noise=0.05)
    q = Grid.fit(mesh.positions, 14).quantize(mesh.positions)
    calls, selections = [], []
    one_batch, unstalled, winners = S._one_batch, S._unstalled, S._ordinary_winners

    def recorded(*args):
        calls.append(args[9])
        return one_batch(*args)

    def stalls_third(cand, win, mesh, n):
        return S._legal_only(cand, mesh) if len(calls) == 3 else unstalled(cand, win, mesh, n)

    def counted(cand, mesh, n):
        selections.append(len(calls))
        if len(calls) > 3:  # after the stall: only legal candidates are offered
            assert S._legal(*cand[:3], mesh).all()
        return winners(cand, mesh, n)

    monkeypatch.setattr(S, "_one_batch", recorded)
    monkeypatch.setattr(S, "_unstalled", stalls_third)
    monkeypatch.setattr(S, "_ordinary_winners", counted)
    log = S.simplify(q, mesh.faces, target_vertices=64)
    assert calls[:3] == [False, False, False] and all(calls[3:]) and len(calls) > 5
    # the stalled batch selected twice (its legal candidates are a strict subset here), each later one once
    assert selections.count(3) == 2 and all(selections.count(b) == 1 for b in range(4, len(calls) + 1))
    assert len(log.base_vertices) <= 64
    for batch in log.batches[3:]:
        assert len(batch.u) and np.all(batch.cost >= 0)


def test_the_cow_coarsens_to_its_base_target_at_grid_14():
    """The cow stalled at 72 base vertices at grid 14 (target 64) before stalled batches were chosen again."""
    from pmwm_codec.stream.chunking import default_base_target

    mesh = read_mesh(corpus_path("cow.obj"))
    target = default_base_target(mesh.vertex_count)
    pm, _ = progressive_of(mesh, bits=14, target=target)
    assert len(pm.base_positions) == target


def test_faces_without_area_on_the_grid_do_not_stall_the_simplifier():
    """A strip finer than its grid (14,520 faces without area at 8 bits) coarsens in about as many
    batches as on a grid fine enough for every face: a moved face that had no area may keep none."""
    mesh = shapes.grid(400, 60, hole=False, bump=0.3)
    batches = {}
    for bits in (8, 16):
        q = Grid.fit(mesh.positions, bits).quantize(mesh.positions)
        log = simplify(q, mesh.faces, target_vertices=mesh.vertex_count // 100)
        assert len(log.base_vertices) == mesh.vertex_count // 100
        batches[bits] = len(log.batches)
    assert batches[8] <= 1.25 * batches[16]
