"""The owner layer: embed/detect round trip, keys, attacks, false alarms (generated meshes)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.mesh import Mesh
from pmwm_codec.watermark import owner
from pmwm_codec.watermark.key import WatermarkKey, parse_owner_id


@pytest.fixture(scope="module")
def blob():
    """An irregular closed mesh of ~10k vertices (a noisy, stretched icosphere)."""
    m = shapes.icosphere(5, 1.0, noise=0.03, seed=3)
    return Mesh(m.positions * np.array([1.0, 0.7, 0.5]), m.faces)


@pytest.fixture(scope="module")
def marked(blob):
    key = WatermarkKey.generate(rng=np.random.default_rng(7))
    return key, owner.embed(blob.positions, blob.faces, key)


def _rms_of_diagonal(a, b):
    diag = np.linalg.norm(a.max(0) - a.min(0))
    return float(np.sqrt(np.mean(np.sum((a - b) ** 2, axis=1))) / diag)


def test_round_trip_reads_the_keys_owner_id_with_no_errors_within_the_distortion_budget(blob, marked):
    key, pos = marked
    r = owner.detect(pos, blob.faces, key)
    assert r.id == key.owner_hex and r.bit_errors == 0 and r.verdict == "present"
    assert r.false_alarm_probability == pytest.approx(owner.HYPOTHESES * 2.0**-64)
    assert _rms_of_diagonal(blob.positions, pos) < 0.0002  # the issue's budget: 0.02% of the diagonal


def _grid_quantize(pos, bits, rng):
    """Uniform quantization on a cubic grid of 2**bits - 1 steps over the largest extent, rotated."""
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    p = pos @ q.T
    step = (p.max(0) - p.min(0)).max() / (2**bits - 1)
    return np.round((p - p.min(0)) / step) * step


def test_transport_leaves_no_bit_error(blob, marked):
    """float32, Draco q11 and q14, and 11/14/16-bit grids in other poses: every bit survives."""
    import DracoPy

    key, pos = marked
    rng = np.random.default_rng(9)
    for bits in (11, 14, 16):
        assert owner.detect(_grid_quantize(pos, bits, rng), blob.faces, key).bit_errors == 0
    assert owner.detect(pos.astype(np.float32), blob.faces, key).bit_errors == 0
    for bits in (11, 14):
        d = DracoPy.decode(DracoPy.encode(pos.astype(np.float32), blob.faces.astype(np.uint32), quantization_bits=bits))
        assert owner.detect(np.asarray(d.points, np.float64), np.asarray(d.faces).reshape(-1, 3), key).bit_errors == 0


def _ellipsoid_with_a_gap(subdivisions, start, stop, outward=None):
    """An ellipsoid (an icosphere of ``subdivisions``) whose vertices with norms from ``start`` to ``stop`` shells
    of its estimated frame are moved radially to the nearer of those bounds (``outward``: to ``stop``)."""
    m = shapes.icosphere(subdivisions)
    pos, faces = m.positions * np.array([1.0, 0.7, 0.45]), m.faces
    points, inverse = owner._distinct_index(pos)
    c, lo, w = owner._frame(points, inverse[faces])
    d = pos - c
    r = np.linalg.norm(d, axis=1)
    a, b = lo + start * w, lo + stop * w
    gap = (r > a) & (r < b)
    to = b if outward else np.where(r - a < b - r, a, b)
    return Mesh(np.where(gap[:, None], c + d * (to / r)[:, None], pos), faces)


def _gapped_ellipsoid():
    """An ellipsoid whose norms leave most of one shell of its estimated frame empty (the vertices of that
    shell's middle 85% moved radially to the nearer of its bounds: a gap, as between a teapot's body and lid)."""
    return _ellipsoid_with_a_gap(4, 32.075, 32.925)


def test_a_small_shell_that_can_be_marked_one_way_only_reads_no_bit_wrong_unattacked(monkeypatch):
    """A small shell whose vertices all lie in the quarter next to its inner edge (an outer shell of an ellipsoid
    of ~10k vertices keeping its inner fifth, a few dozen vertices against a median of ~140; CGAL's 17.5k-vertex
    man has one, 27 against 197) cannot be marked as a 1: the flow takes its vertices to that edge, never past
    its middle.  The coding the budget prices lowest may ask it so (a small shell costs little even at full
    amplitude), and marked in the estimate (as where no point of the search grid reaches
    ``REACH_FACTOR * strength`` in every shell: the man) the bit read wrong on the marked mesh itself, or was
    erased, for about half of all keys, the verdict ``present`` all the same.  Every key's mark must read its
    ID with no error, within the layer's RMS."""
    mesh = _ellipsoid_with_a_gap(5, 56.2, 57.5, outward=True)
    points, faces = owner.distinct_mesh(mesh.positions, mesh.faces)
    assert owner._reach(points, owner._frame(points, faces)).min() < 0  # one side reads wrong at any amplitude
    monkeypatch.setattr(owner, "_embedding_frame", lambda p, f, s: (owner._frame(p, f), None))
    rng = np.random.default_rng(5)
    for _ in range(6):
        key = WatermarkKey.generate(rng=rng)
        pos = owner.embed(mesh.positions, mesh.faces, key)
        r = owner.detect(pos, mesh.faces, key)
        assert (r.bit_errors, r.erased, r.verdict) == (0, 0, "present")
        assert _rms_of_diagonal(mesh.positions, pos) <= owner.MAX_RMS * (1 + 1e-9)


def test_a_mark_that_reads_every_bit_unattacked_is_made_once(blob, monkeypatch):
    """The encoder makes a mark again only where it reads a bit wrong on the marked mesh: a good one stays
    exactly as it was (the bytes of the files it marked)."""
    calls = []
    real = owner._mark
    monkeypatch.setattr(owner, "_mark", lambda *a, **kw: calls.append(1) or real(*a, **kw))
    key = WatermarkKey.generate(rng=np.random.default_rng(7))
    pos = owner.embed(blob.positions, blob.faces, key)
    assert owner.detect(pos, blob.faces, key).bit_errors == 0 and len(calls) == 1


def test_a_gap_in_the_norms_is_marked_in_a_frame_the_read_finds_so_no_bit_is_lost():
    mesh = _gapped_ellipsoid()
    points, inverse = owner._distinct_index(mesh.positions)
    faces = inverse[mesh.faces]
    assert owner._reach(points, owner._frame(points, faces)).min() < owner.DEFAULT_STRENGTH  # a shell short
    frame, offset = owner._embedding_frame(points, faces, owner.DEFAULT_STRENGTH)
    assert offset is not None and owner._reach(points, frame).min() >= owner.REACH_FACTOR * owner.DEFAULT_STRENGTH
    rng = np.random.default_rng(5)
    estimate_errors = []
    for _ in range(4):
        key = WatermarkKey.generate(rng=rng)
        pos = owner.embed(mesh.positions, mesh.faces, key)
        for p in (pos, pos.astype(np.float32).astype(np.float64), _grid_quantize(pos, 14, np.random.default_rng(3))):
            r = owner.detect(p, mesh.faces, key)
            assert r.bit_errors == 0 and r.verdict == "present"
        assert _rms_of_diagonal(mesh.positions, pos) < 0.0002
        with pytest.MonkeyPatch.context() as mp:  # the same keys marked in the estimate lose bits
            mp.setattr(owner, "_embedding_frame", lambda p, f, s: (owner._frame(p, f), None))
            estimate_errors.append(owner.detect(owner.embed(mesh.positions, mesh.faces, key), mesh.faces, key).bit_errors)
    assert sum(e > 0 for e in estimate_errors) >= 2


def test_a_mark_in_the_searched_grid_is_kept_unless_one_in_the_estimate_reads_better(monkeypatch):
    mesh = _gapped_ellipsoid()
    key = WatermarkKey.generate(rng=np.random.default_rng(5))
    reads = []
    real = owner._read_errors

    def counted(points, faces, k):
        reads.append(real(points, faces, k))
        return reads[-1]

    monkeypatch.setattr(owner, "_read_errors", counted)
    pos = owner.embed(mesh.positions, mesh.faces, key)
    assert len(reads) == 2 and reads[0] < reads[1]  # the offset frame's mark read better: kept
    assert owner.detect(pos, mesh.faces, key).bit_errors == reads[0]
    # the estimate's mark reads a bit wrong here; that its coding is then chosen again is tested apart
    monkeypatch.setattr(owner, "_errors_read", lambda points, faces, k: 0)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(owner, "_embedding_frame", lambda p, f, s: (owner._frame(p, f), None))
        plain = owner.embed(mesh.positions, mesh.faces, key)
    monkeypatch.setattr(owner, "_read_errors", lambda points, faces, k: 5)  # a tie: the offset frame's mark
    assert np.array_equal(owner.embed(mesh.positions, mesh.faces, key), pos)
    scores = iter([6, 5])  # the estimate's reads better: its mark
    monkeypatch.setattr(owner, "_read_errors", lambda points, faces, k: next(scores))
    assert np.array_equal(owner.embed(mesh.positions, mesh.faces, key), plain)


def test_a_mesh_whose_every_shell_can_be_marked_is_marked_in_its_estimated_frame(blob):
    points, inverse = owner._distinct_index(blob.positions)
    faces = inverse[blob.faces]
    frame, offset = owner._embedding_frame(points, faces, owner.DEFAULT_STRENGTH)
    assert offset is None and all(np.array_equal(x, y) for x, y in zip(frame, owner._frame(points, faces)))


def test_the_encoders_read_back_counts_the_pieces_a_mesh_file_is_read_in(monkeypatch):
    """6 errors read ``present`` from one read (8.7e-10) and not from the best of two (1.7e-9): the encoder's
    check must read as ``pmw verify MESH`` does, whole and piece by piece, or it lets through a layer the
    decoded mesh reads ``inconclusive`` (a sphere beside a second large piece)."""
    from pmwm_codec.stream import encoder
    from pmwm_codec.verify import owner as verify_owner

    def six_errors(positions, faces, key, scores=None, reads=1):
        p, verdict = owner.judge(6, 0, reads)
        return owner.OwnerResult(key.owner_hex, 6, 0, p, verdict)

    monkeypatch.setattr(verify_owner, "detect", six_errors)
    key = WatermarkKey.generate(rng=np.random.default_rng(3))
    one = shapes.icosphere(3)  # 642 vertices: a piece of its own beside another
    two = Mesh(np.concatenate([one.positions, one.positions * 0.5 + 3.0]), np.concatenate([one.faces, one.faces + 642]))
    assert owner.judge(6, 0, 1)[1] == "present" and owner.judge(6, 0, 2)[1] != "present"
    assert encoder._owner_check([one.positions], [one.faces], key, [[np.eye(4)]]) is None
    why = encoder._owner_check([two.positions], [two.faces], key, [[np.eye(4)]])
    assert why is not None and "6 of its 64 bits" in why


def test_duplicated_vertices_do_not_change_what_is_read(blob, marked):
    """Seam duplicates (and the vertices Draco splits at them) count once: the soft values are equal."""
    key, pos = marked
    dup = np.random.default_rng(4).choice(len(pos), len(pos) // 3, replace=False)
    soft = owner.read_soft(pos, blob.faces, key)
    assert np.array_equal(owner.read_soft(np.vstack([pos, pos[dup]]), blob.faces, key), soft)


def test_embedding_moves_vertices_radially_and_keeps_coincident_ones_together(blob):
    key = WatermarkKey.generate(rng=np.random.default_rng(8))
    pos = np.vstack([blob.positions, blob.positions[:500]])
    out = owner.embed(pos, blob.faces, key, rms_budget=None)
    assert np.array_equal(out[-500:], out[:500])
    c = np.unique(pos, axis=0).mean(0)
    d0, d1 = pos - c, out - c
    cos = np.sum(d0 * d1, 1) / np.linalg.norm(d0, axis=1) / np.linalg.norm(d1, axis=1)
    assert cos.min() > 1 - 1e-6  # the centroid moves a little with the marking; the rays barely do


def _least_margin(soft, key):
    """The smallest of soft values (64,) times the side its bit is coded to, under the alternative coding that
    reads the key's ID best."""
    coded = owner._coded(key, key.owner_id)[np.argmin(owner._errors_each(soft, key))]
    return float((np.where(coded == 1, 1.0, -1.0) * soft).min())


def test_the_layer_never_costs_more_than_the_issues_rms_whatever_the_strength_asks():
    """Margins that the simulated transport keeps asking for can take the displacement past the budget (the
    beetle: 0.0201% for one key of five); it is scaled back to 0.02% of the diagonal, and still reads."""
    m = shapes.icosphere(4, 1.0, noise=0.03, seed=3)
    pos = m.positions * np.array([1.0, 0.7, 0.5])
    key = WatermarkKey.generate(rng=np.random.default_rng(7))
    marked = owner.embed(pos, m.faces, key, strength=0.3)  # uncapped: 0.0218%
    assert _rms_of_diagonal(pos, marked) <= owner.MAX_RMS * (1 + 1e-9)
    assert _rms_of_diagonal(pos, marked) > 0.99 * owner.MAX_RMS
    assert owner.detect(marked, m.faces, key).bit_errors == 0
    moved = owner._capped(pos, pos + np.array([[3.0, 0, 0]] * len(pos)), np.ones(len(pos)), 0.5)
    assert np.allclose(moved - pos, [0.5, 0, 0])  # scaled along the displacement itself


def test_rms_budget_raises_every_margin_and_stays_within_the_budget(blob, marked):
    key, pos = marked
    bare = owner.embed(blob.positions, blob.faces, key, rms_budget=None)
    margin_bare = _least_margin(owner.read_soft(bare, blob.faces, key), key)
    margin = _least_margin(owner.read_soft(pos, blob.faces, key), key)
    assert owner.DEFAULT_STRENGTH <= margin_bare < margin
    assert _rms_of_diagonal(blob.positions, bare) < _rms_of_diagonal(blob.positions, pos) <= owner.DEFAULT_RMS_BUDGET


@pytest.mark.parametrize("row", [0, 5, owner.ALTERNATIVES - 1])
def test_a_mark_under_any_alternative_coding_reads_the_keys_id_exactly(blob, monkeypatch, row):
    """Whichever coding the encoder takes, the read finds it and reports the key's ID itself; row 0 is the
    coding of marks made before there was a choice, so they still read."""
    key = WatermarkKey.generate(rng=np.random.default_rng(11))
    monkeypatch.setattr(owner, "_chosen_sides", lambda points, count, faces, sides, *a, **kw: sides[row])
    pos = owner.embed(blob.positions, blob.faces, key)
    assert not np.all(owner._alternatives(key)[row] == 0) or row == 0
    r = owner.detect(pos, blob.faces, key)
    assert (r.id, r.bit_errors, r.verdict) == (key.owner_hex, 0, "present")
    errors = owner._errors_each(owner.read_soft(pos, blob.faces, key), key)
    assert errors[row] == 0 and np.all(np.delete(errors, row) > 14)  # the other codings read the ID as noise


def test_choosing_the_coding_the_mesh_leans_to_raises_the_margins_on_a_coarse_mesh(monkeypatch):
    """On a mesh of ~40 vertices a shell an unmarked shell's score is as large as the margin the budget buys;
    the encoder takes the coding whose shells lean its way (cow and spot, 2.9k vertices: the margin level
    +19-36%; BENCHMARKS.md "Owner layer"): here the median margin read, averaged over 4 keys, is at least 3%
    higher (measured: 8%), within the same RMS budget."""
    m = shapes.icosphere(4, 1.0, noise=0.03, seed=5)
    pos, faces = m.positions * np.array([1.0, 0.7, 0.5]), m.faces
    chosen, first = [], []
    pick = owner._chosen_sides
    for k in range(4):
        key = WatermarkKey.generate(rng=np.random.default_rng(30 + k))
        for out, how in ((chosen, pick), (first, lambda points, count, faces, sides, *a, **kw: sides[0])):
            monkeypatch.setattr(owner, "_chosen_sides", how)
            marked = owner.embed(pos, faces, key)
            assert _rms_of_diagonal(pos, marked) <= owner.DEFAULT_RMS_BUDGET * (1 + 1e-9)
            soft = owner.read_soft(marked, faces, key)
            coded = owner._coded(key, key.owner_id)[np.argmin(owner._errors_each(soft, key))]
            out.append(float(np.median(np.where(coded == 1, 1.0, -1.0) * soft)))
    assert np.mean(chosen) > 1.03 * np.mean(first)


def test_shell_score_is_zero_at_shell_edges_and_peaks_at_a_quarter_and_three_quarters():
    """A vertex that noise carries across a shell edge changes the scores continuously (g(0) = g(1) = 0)."""
    t = np.array([0.0, 1e-4, 1 - 1e-4, 1.0, 1 / 4, 3 / 4])
    g = owner.g_of_t(t)
    assert np.all(np.abs(g[:4]) < 1e-3)
    assert g[4] == pytest.approx(-1.0) and g[5] == pytest.approx(1.0)
    assert np.all(np.abs(owner.g_of_t(np.linspace(0, 1, 1001))) <= 1 + 1e-12)


def test_the_search_statistic_is_the_shell_score_to_within_a_billionth():
    """The frame search's polynomial g agrees with -sin(2 pi t) everywhere in [0, 1), edges and folds included."""
    t = np.concatenate([np.linspace(0.0, 1.0, 200001)[:-1], [0.25, 0.5, 0.75, np.nextafter(1.0, 0.0), 1e-300]])
    assert np.abs(owner._g_poly(t) - owner.g_of_t(t)).max() < 1e-9


@pytest.mark.parametrize("use", [False, True], ids=["numpy", "compiled"])
def test_the_frame_search_objective_is_the_same_bits_compiled_and_in_numpy(use, monkeypatch):
    """sum_k |S_k| of many frame offsets, on strided views as the coarse search takes them: the compiled loop
    and the numpy path agree bit for bit, and both agree with the objective taken with numpy's sine."""
    from pmwm_codec.progressive import topology

    if use and not topology.USE_NUMBA:
        pytest.skip("numba is not installed")
    rng = np.random.default_rng(11)
    d = rng.normal(size=(30000, 3))
    rho = np.linalg.norm(d, axis=1) + rng.random(30000)
    n = d / np.linalg.norm(d, axis=1)[:, None]
    lo, width = float(rho.min()) + 0.1, float(rho.max() - rho.min()) / (owner.BINS + 2)
    offsets = rng.uniform(-0.4, 0.4, (40, 5))
    values = []
    for flag in (False, use):
        monkeypatch.setattr(topology, "USE_NUMBA", flag)
        values.append([owner._search_objective(n[::m], rho[::m], lo, width, x) for m, x in zip([1, 3] * 20, offsets)])
    assert values[0] == values[1]
    for (m, x), value in zip(zip([1, 3] * 20, offsets), values[0]):
        u = (rho[::m] - n[::m] @ (x[:3] * width) - lo - x[3] * width) / (width * (1.0 + (x[4] - x[3]) / owner.BINS))
        u = u[(u >= 0.0) & (u < owner.BINS)]
        s = u.astype(np.int64)
        tot = np.bincount(s, weights=owner.g_of_t(u - s), minlength=owner.BINS)
        assert value == pytest.approx(np.abs(tot / np.maximum(np.bincount(s, minlength=owner.BINS), 1)).sum(),
                                      rel=1e-9)


def test_embedding_flow_keeps_every_vertex_in_its_shell_and_in_order():
    """The flow's profile is 0 and flat at both edges, so each tabled flow maps [0, 1] onto itself, increasing."""
    assert owner._h_of_t(np.array([0.0, 1.0])) == pytest.approx([0.0, 0.0])
    assert abs(owner._h_of_t(np.array([1e-4]))[0]) < 1e-4
    table = owner._flow_table()
    assert np.all(np.diff(table, axis=2) >= 0)
    assert np.all(table[:, :, 0] == 0.0) and np.all(table[:, :, -1] == 1.0)
    mid = table[:, -1, (owner._FLOW_T - 1) // 2]  # t = 1/2 flows toward 1/4 (side 0) and 3/4 (side 1)
    assert mid[0] < 0.3 and mid[1] > 0.7


def test_wrong_key_and_unmarked_mesh_are_absent(blob, marked):
    key, pos = marked
    rng = np.random.default_rng(11)
    for _ in range(5):
        assert owner.detect(pos, blob.faces, WatermarkKey.generate(rng=rng)).verdict != "present"
    assert owner.detect(blob.positions, blob.faces, key).verdict != "present"


def test_same_secret_other_owner_id_is_not_present(blob, marked):
    key, pos = marked
    other = WatermarkKey(key.secret, owner_id=key.owner_id ^ 0xFFFF_FFFF_0000_0000)
    r = owner.detect(pos, blob.faces, other)
    # 32 bits differ from the ID marked; under the best of the 32 codings and 6 views the other ID reads
    # about as a wrong key does (~21 errors, 21 here): absent, never nearly everywhere
    assert r.bit_errors >= 15 and r.verdict == "absent"


def test_survives_similarity_reorder_float32_and_small_noise(blob, marked):
    key, pos = marked
    rng = np.random.default_rng(5)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = (pos @ q.T * 3.7 + [5.0, -2.0, 1.0]).astype(np.float32).astype(np.float64)
    perm = rng.permutation(len(pos))
    inv = np.argsort(perm)
    r = owner.detect(moved[perm], inv[blob.faces][rng.permutation(len(blob.faces))], key)
    assert r.bit_errors == 0 and r.verdict == "present"
    d = np.linalg.norm(pos - pos.mean(0), axis=1).mean()
    noisy = pos + rng.uniform(-1, 1, pos.shape) * 0.0005 * d
    assert owner.detect(noisy, blob.faces, key).verdict == "present"


def test_owner_id_wider_than_64_bits_is_refused(blob):
    key = WatermarkKey.generate(rng=np.random.default_rng(1))
    with pytest.raises(ValueError):
        owner.embed(blob.positions, blob.faces, key, owner_id=1 << 64)


def _tail(e):
    """P(at most e of 64 fair coins come up wrong), exactly."""
    return sum(math.comb(64, i) for i in range(e + 1)) / 2**64


def _expected_least(n):
    """The expected fewest errors among n independent reads of 64 fair coins."""
    return sum((1.0 - _tail(e)) ** n for e in range(64))


def test_false_alarm_probability_is_the_union_bound_of_the_binomial_tail_over_the_codings_read():
    assert owner.HYPOTHESES == owner.FRAMES * owner.ALTERNATIVES == 192
    assert owner.false_alarm_probability(0, frames=1) == 2.0**-64
    assert owner.false_alarm_probability(8) == pytest.approx(owner.HYPOTHESES * _tail(8))
    assert owner.false_alarm_probability(6) < owner.PRESENT_BELOW < owner.false_alarm_probability(7)  # spec: <= 6
    assert owner.false_alarm_probability(14) < owner.ABSENT_FROM <= owner.false_alarm_probability(15)  # spec: >= 15
    assert owner.false_alarm_probability(64) == 1.0 and owner.false_alarm_probability(40) == 1.0


def test_wrong_key_errors_stay_within_the_stated_false_alarm_bound(blob, marked):
    """Over 200 wrong keys none is present and the best-of-frames error counts are no more often low
    than the stated bound allows (1,000 keys: tools/owner_attacks.py)."""
    _, pos = marked
    rng = np.random.default_rng(2)
    errors = []
    scores = owner.mesh_scores(pos, blob.faces)  # the frames do not depend on the key
    for _ in range(200):
        k = WatermarkKey.generate(rng=rng)
        r = owner.detect(pos, blob.faces, k, scores=scores)
        assert r.verdict != "present"
        errors.append(r.bit_errors)
    errors = np.array(errors)
    for e in (14, 16, 18):  # bound 0.0007, 0.007, 0.06; the fraction's sd over 200 keys is <= 0.02
        assert np.mean(errors <= e) <= owner.false_alarm_probability(e) + 0.03
    # each key's best of its codings: no better than HYPOTHESES independent fair reads would give (the bound's
    # model), no worse than ALTERNATIVES of them (one view); the mean's sd over 200 keys is ~0.15
    assert _expected_least(owner.HYPOTHESES) - 0.6 <= errors.mean() <= _expected_least(owner.ALTERNATIVES) + 0.6


def test_key_serialises_the_owner_id(tmp_path):
    key = WatermarkKey.generate(owner_id=0xABCDEF)
    key.save(tmp_path / "k.json")
    doc = json.loads((tmp_path / "k.json").read_text())
    assert doc["owner_id"] == "0000000000abcdef"
    assert WatermarkKey.load(tmp_path / "k.json") == key
    assert parse_owner_id("0x00FF") == 255
    with pytest.raises(ValueError):
        parse_owner_id("xyz")


def test_cli_owner_only_encode_then_blind_verify_of_the_decoded_mesh(tmp_path, blob, capsys):

    src = tmp_path / "blob.obj"
    with open(src, "w") as fh:
        fh.writelines(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in blob.positions)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in blob.faces)
    out = tmp_path / "b.pmw"
    assert main(["encode", str(src), "-o", str(out), "--owner-id", "00c0ffee00c0ffee", "-q"]) == 0
    key = tmp_path / "b.pmw.key.json"
    assert WatermarkKey.load(key).owner_hex == "00c0ffee00c0ffee"
    assert main(["decode", str(out), "-o", str(tmp_path / "d.ply")]) == 0
    capsys.readouterr()
    assert main(["verify", str(tmp_path / "d.ply"), "--key", str(key), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)  # the CLI's key is random: a few bit errors may occur
    assert doc["owner"]["verdict"] == "present" and doc["owner"]["bits"] == 64
    assert bin(int(doc["owner"]["id"], 16) ^ 0x00C0FFEE00C0FFEE).count("1") == doc["owner"]["bit_errors"] <= 6
    assert main(["verify", str(src), "--key", str(key), "-q"]) == 1  # the unmarked original
    assert main(["verify", str(out), "--key", str(key), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["owner"]["verdict"] == "present" and all("owner" in c for c in doc["chunks"])
    other = tmp_path / "other.json"  # another owner's key: the text names the key's ID, never the bits read as one
    WatermarkKey.generate(owner_id=0x1234, rng=np.random.default_rng(3)).save(other)
    assert main(["verify", str(out), "--key", str(other)]) == 1
    last = capsys.readouterr().out.splitlines()[-1]
    assert last.startswith("owner 0000000000001234: absent (read as ") and "bits differ" in last, last
    # the text of an owner-only file: no image rows (no boundary reads a code), and the verdict line says
    # that the owner layer decides the exit status (it said "not-authentic (the file carries no watermark)"
    # over a table of zero coefficients, then exited 0)
    assert main(["verify", str(out), "--key", str(key)]) == 0
    text = capsys.readouterr().out
    assert "coeffs" not in text and "PSNR" not in text
    assert "the file carries no watermark image; its owner layer, below, decides the exit status" in text
    assert text.splitlines()[-1].startswith("owner 00c0ffee00c0ffee: present")


def test_a_pmw_renamed_glb_is_verified_as_the_stream_and_refused_as_a_plain_mesh(tmp_path, blob, capsys):
    """A glTF reader sees only a .pmw's base mesh: under a .glb name the file is still verified as the stream
    (every chunk boundary, the full mesh), and encoding or reading it as a mesh is refused by name."""
    import pmwm_codec
    from pmwm_codec.errors import InputFormatError

    src = tmp_path / "blob.obj"
    _write_obj(src, blob)
    out, key = tmp_path / "b.pmw", tmp_path / "b.key.json"
    assert main(["encode", str(src), "-o", str(out), "--owner-id", "00c0ffee00c0ffee", "--key", str(key), "-q"]) == 0
    renamed = tmp_path / "b.glb"
    renamed.write_bytes(out.read_bytes())
    capsys.readouterr()
    assert main(["verify", str(out), "--key", str(key), "--json"]) == 0
    as_pmw = json.loads(capsys.readouterr().out)
    assert main(["verify", str(renamed), "--key", str(key), "--json"]) == 0
    as_glb = json.loads(capsys.readouterr().out)
    assert as_glb["owner"] == as_pmw["owner"] and len(as_glb["chunks"]) == len(as_pmw["chunks"]) > 1
    assert main(["encode", str(renamed), "-o", str(tmp_path / "again.pmw")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "PMWM_progressive_mesh" in err and "pmw decode" in err
    assert not (tmp_path / "again.pmw").exists()
    with pytest.raises(InputFormatError, match="progressive .pmw stream"):
        pmwm_codec.read_mesh(renamed)


def _write_obj(path, mesh):
    with open(path, "w") as fh:
        fh.writelines(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in mesh.positions)
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in mesh.faces)


def _watermark_png(path):
    from PIL import Image

    Image.fromarray((np.arange(16 * 16).reshape(16, 16) % 2 * 255).astype(np.uint8)).save(path)


def test_watermark_encode_marks_a_random_owner_id_by_default_and_no_owner_opts_out(tmp_path, blob, capsys):
    src, img = tmp_path / "blob.obj", tmp_path / "w.png"
    _write_obj(src, blob)
    _watermark_png(img)
    ids = []
    for name in ("a", "b"):
        assert main(["encode", str(src), "-o", str(tmp_path / f"{name}.pmw"), "--watermark", str(img), "--json"]) == 0
        doc = json.loads(capsys.readouterr().out)
        key = WatermarkKey.load(tmp_path / f"{name}.pmw.key.json")
        assert key.owner_hex == doc["owner_id"]
        ids.append(key.owner_id)
        assert main(["verify", str(tmp_path / f"{name}.pmw"), "--key", str(tmp_path / f"{name}.pmw.key.json"),
                     "--json"]) == 0
        out = json.loads(capsys.readouterr().out)
        assert out["verdict"] == "authentic" and out["owner"]["verdict"] == "present"
    assert ids[0] != ids[1]  # random per new key
    # reusing key a for the same image marks key a's owner id again
    assert main(["encode", str(src), "-o", str(tmp_path / "c.pmw"), "--watermark", str(img),
                 "--key", str(tmp_path / "a.pmw.key.json"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["owner_id"] == f"{ids[0]:016x}"
    # --no-owner: the exact layer only, and the new key names no owner id
    assert main(["encode", str(src), "-o", str(tmp_path / "n.pmw"), "--watermark", str(img), "--no-owner", "-q"]) == 0
    assert WatermarkKey.load(tmp_path / "n.pmw.key.json").owner_id is None
    # a key with an owner id is not reused by an encode without the layer
    assert main(["encode", str(src), "-o", str(tmp_path / "d.pmw"), "--watermark", str(img), "--no-owner",
                 "--key", str(tmp_path / "a.pmw.key.json")]) == 2
    assert "names an owner id" in capsys.readouterr().err
    assert main(["encode", str(src), "-o", str(tmp_path / "e.pmw"), "--no-owner", "--owner-id", "ff"]) == 2


def test_a_key_written_before_the_owner_layer_still_marks_and_verifies_the_image(tmp_path, blob, capsys):
    src, img = tmp_path / "blob.obj", tmp_path / "w.png"
    _write_obj(src, blob)
    _watermark_png(img)
    assert main(["encode", str(src), "-o", str(tmp_path / "a.pmw"), "--watermark", str(img), "-q"]) == 0
    old = tmp_path / "old.key.json"
    doc = json.loads((tmp_path / "a.pmw.key.json").read_text())
    doc.pop("owner_id")  # as an older version wrote it: without the owner ID, nor the checksum over it
    doc.pop("checksum")
    old.write_text(json.dumps(doc))
    assert main(["encode", str(src), "-o", str(tmp_path / "b.pmw"), "--watermark", str(img), "--key", str(old),
                 "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert "owner_id" not in report and any("no owner id" in n for n in report["notices"])
    assert main(["verify", str(tmp_path / "b.pmw"), "--key", str(old), "-q"]) == 0


def test_scores_read_once_give_every_key_the_same_answer_as_detect(blob, marked):
    """``detect`` reads its views one at a time and stops at the first without an error; from every
    view's scores at once (``mesh_scores``) it picks the same view: clean, noisy and smoothed."""
    key, pos = marked
    rng = np.random.default_rng(12)
    diag = np.linalg.norm(pos.max(0) - pos.min(0))
    noisy = pos + rng.normal(size=pos.shape) * 0.003 * diag / math.sqrt(3)
    smooth = _laplacian_smoothing(pos, blob.faces, 30)
    keys = [key] + [WatermarkKey.generate(rng=rng) for _ in range(3)]
    for p in (pos, noisy, smooth):
        scores = owner.mesh_scores(p, blob.faces)
        for k in keys:
            assert owner.detect(p, blob.faces, k, scores=scores) == owner.detect(p, blob.faces, k)


def _offset_frame(frame_of, dc, dlo, dhi):
    """A frame estimator that errs by ``dc`` (3,) / ``dlo`` / ``dhi`` shell widths."""
    def wrong(points, faces, areas=None):
        c, lo, w = frame_of(points, faces, areas)
        return c + np.asarray(dc) * w, lo + dlo * w, w * (1.0 + (dhi - dlo) / owner.BINS)
    return wrong


def test_frame_search_reads_through_an_estimate_a_fifth_of_a_shell_off(blob, marked, monkeypatch):
    """Smoothing and coarse quantization move the estimated frame by tenths of a shell (bunny,
    smoothing 30: ~0.2); the read searches the frame that maximises sum |S_k| around the estimate."""
    key, pos = marked
    monkeypatch.setattr(owner, "_frame", _offset_frame(owner._frame, [0.15, 0.1, 0.0], 0.2, 0.2))
    points, inverse = owner._distinct_index(pos)
    shell, t, _, _ = owner._shells(points, owner._frame(points, inverse[blob.faces]))
    soft = np.zeros(owner.BINS)
    inside = shell >= 0
    soft[owner._layout(key)[0]] = np.bincount(shell[inside], owner.g_of_t(t[inside]), owner.BINS)
    assert owner._bit_errors(soft, key) > 8  # the offset frame alone fails, under every alternative coding
    r = owner.detect(pos, blob.faces, key)
    assert r.bit_errors == 0 and r.verdict == "present"


def test_the_estimate_is_always_read_whatever_the_search_finds(blob, marked, monkeypatch):
    """The first frame a read tries is the estimate itself: on the marked mesh and after transport
    it is the frame the encoder measured, so a search lured elsewhere (here: every climb ends
    0.4 widths off) costs nothing."""
    key, pos = marked
    points, inverse = owner._distinct_index(pos)
    faces = inverse[blob.faces]
    frame = owner._frame(points, faces)
    monkeypatch.setattr(owner, "_ascend", lambda objectives, x, center: center + np.array([0.3, 0.0, 0.0, 0.1, 0.1]))
    frames = owner._searched_frames(points, faces)
    assert len(frames) == 4 and len(owner._read_frames(points, faces)) == owner.FRAMES
    assert np.array_equal(frames[0][0], frame[0]) and frames[0][1:] == frame[1:]
    assert not np.array_equal(frames[1][0], frame[0])
    r = owner.detect(pos, blob.faces, key)
    assert r.bit_errors == 0 and r.verdict == "present"


def test_frame_search_climbs_from_several_grid_points(blob, monkeypatch):
    """The best grid point can sit in a lesser basin (a smoothed 23k-vertex dragon: 2 of 3 keys):
    the search climbs from the SEARCH_STARTS best grid points and keeps the highest maximum."""
    high, low = np.array([0.1, 0.1, 0.0, 0.1, 0.1]), np.array([-0.2, -0.2, 0.0, 0.0, 0.0])

    def objective(n, rho, lo, width, x):  # a narrow high peak near the grid's centre, a lower one on a grid point
        return float(np.exp(-np.sum((x - high) ** 2) / 0.02) + 0.6 * np.exp(-np.sum((x - low) ** 2) / 0.1))

    monkeypatch.setattr(owner, "_search_objective", objective)
    points, inverse = owner._distinct_index(blob.positions)
    faces = inverse[blob.faces]
    centroid, lo, width = owner._frame(points, faces)
    searched = owner._searched_frames(points, faces)[1]
    assert np.allclose(searched[0], centroid + high[:3] * width) and searched[1] == pytest.approx(lo + 0.1 * width)
    monkeypatch.setattr(owner, "SEARCH_STARTS", 1)  # one climb, from the best grid point: the lesser peak
    searched = owner._searched_frames(points, faces)[1]
    assert np.allclose(searched[0], centroid + low[:3] * width)


def test_sparser_shells_get_larger_margins(blob, marked):
    """Equal signal-to-noise: a shell's margin grows as its vertex count falls (sqrt(median / mass))."""
    key, pos = marked
    s, mass = owner.mesh_scores(pos, blob.faces)
    s, mass = s[0], mass[0]  # the estimated frame (the marked mesh reads there)
    order = np.argsort(mass)
    assert mass[order[0]] < mass[order[-1]]
    assert np.abs(s[order[:16]]).mean() > 1.2 * np.abs(s[order[-16:]]).mean()


# -- the encoder writes the owner layer only where it reads back ---------------------------------

def _files(path):
    return sorted(p.name for p in path.iterdir())


def test_unreadable_flags_a_sphere_and_a_regular_torus_before_any_embedding(blob):
    """A sphere's norms differ by rounding only (shells a tiny fraction of a grid step wide); a torus of
    64 sides has 33 distinct norms, so most shells hold no vertex.  Meshes that carry the layer pass."""
    from pmwm_codec.progressive.grid import Grid

    def why(mesh, bits=16):
        return owner.unreadable(mesh.positions, mesh.faces, Grid.fit(mesh.positions, bits).step)

    assert "too narrow a range" in why(shapes.icosphere(4))
    assert "too narrow a range" in why(shapes.icosphere(2, 1.0, noise=1e-7))  # rounding-level bumps
    assert "too few distinct values" in why(shapes.torus(160, 64))
    assert why(blob) is None and why(shapes.demo_mesh()) is None and why(shapes.icosphere(3, 1.3, noise=0.02)) is None
    # the test is against the grid the positions are stored on: 0.0007 of radial noise is under half a
    # step of an 8-bit grid but several steps of a 16-bit one
    bumpy = shapes.icosphere(4, 1.0, noise=0.0007, seed=1)
    assert why(bumpy, 16) is None and "too narrow a range" in why(bumpy, 8)


def test_unreadable_says_so_when_the_shells_lie_where_few_vertices_are(blob):
    """A detailed object standing on a vast ground plane of 36 vertices: the plane is nearly all of the
    surface's area, so the area-placed shells span the plane, where a few dozen of its thousands of vertices lie. The
    refusal named "too few distinct values", which the object's norms are not; it now says where the shells
    lie and why."""
    from pmwm_codec.progressive.grid import Grid

    ground = shapes.grid(6, 6, hole=False, bump=0.0)  # 36 vertices, 50 faces: a flat square in z = 0
    xy = ground.positions[:, :2] - ground.positions[:, :2].mean(0)
    ground = Mesh(np.column_stack([200 * xy[:, 0] / np.ptp(xy[:, 0]), np.full(len(xy), -1.5),
                                   200 * xy[:, 1] / np.ptp(xy[:, 1])]), ground.faces)
    obj = blob
    scene = Mesh(np.vstack([obj.positions, ground.positions]),
                 np.vstack([obj.faces, ground.faces + obj.vertex_count]))
    why = owner.unreadable(scene.positions, scene.faces, Grid.fit(scene.positions, 16).step)
    assert why is not None and "too few distinct values" not in why, why
    assert "shells lie where most of its surface's area is" in why and f"of its {obj.vertex_count + 36:,} distinct" in why
    assert ground.vertex_count == 36
    assert owner.unreadable(obj.positions, obj.faces, Grid.fit(obj.positions, 16).step) is None  # the object alone


def test_an_explicit_owner_id_the_mesh_cannot_carry_is_refused_and_nothing_is_written(tmp_path, capsys):
    import pmwm_codec
    from pmwm_codec.errors import OwnerLayerError

    src, img = tmp_path / "in" / "ball.obj", tmp_path / "in" / "w.png"
    src.parent.mkdir()
    _write_obj(src, shapes.icosphere(4))
    _watermark_png(img)
    out = tmp_path / "out"
    out.mkdir()
    with pytest.raises(OwnerLayerError, match="cannot be read back from this mesh .*too narrow a range"):
        pmwm_codec.encode(src, out / "a.pmw", owner_id=0xDEADBEEF01234567)
    for extra in ([], ["--watermark", str(img)]):
        code = main(["encode", str(src), "-o", str(out / "b.pmw"), "--owner-id", "deadbeef01234567", *extra])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1
        assert err.startswith("pmw: error: the owner layer cannot be read back from this mesh (its vertex norms span "
                              "too narrow a range") and err.rstrip().endswith("encode without --owner-id")
    torus = tmp_path / "in" / "torus.obj"
    _write_obj(torus, shapes.torus(160, 64))
    assert main(["encode", str(torus), "-o", str(out / "t.pmw"), "--owner-id", "ff", "-q"]) == 2
    assert "too few distinct values" in capsys.readouterr().err
    assert _files(out) == []  # no .pmw, no key


def _empty_shells(mesh) -> int:
    points, inverse = owner._distinct_index(mesh.positions)
    return owner._empty_shells(owner._shells(points, owner._frame(points, inverse[mesh.faces]))[0])


def _two_shells():
    """A noisy sphere inside a noisy ellipsoid (two pieces): vertex norms in two lumps, 9 of the estimated
    frame's 64 shells between them empty (few enough for the read-back to decide, as on CAD parts)."""
    a, b = shapes.icosphere(4, 0.7, noise=0.04, seed=1), shapes.icosphere(4, 1.0, noise=0.04, seed=2)
    return Mesh(np.vstack([a.positions, b.positions * np.array([1.0, 0.9, 0.8])]),
                np.vstack([a.faces, b.faces + len(a.positions)]))


def test_bits_no_vertex_carries_count_as_errors_but_not_against_the_verdict():
    """Of 64 bits with 11 erased, the verdict weighs the 53 read: P = HYPOTHESES * T_53(wrong read)."""
    p, verdict = owner.judge(11, 11)
    assert verdict == "present" and p == pytest.approx(owner.HYPOTHESES * 2.0**-53)
    assert owner.judge(11 + 3, 11)[1] == "present" and owner.judge(11 + 4, 11)[1] != "present"
    assert owner.judge(14, 11)[0] == pytest.approx(owner.false_alarm_probability(3, bits=53))
    assert owner.judge(6, 0) == (owner.false_alarm_probability(6), "present")  # nothing erased: as before
    for errors, erased in ((6, 2), (10, 5), (20, 10)):  # never larger than counting the erased as wrong
        assert owner.judge(errors, erased)[0] <= owner.false_alarm_probability(errors)
    assert owner.judge(17, 17)[1] == "inconclusive"  # fewer than MIN_BITS_READ bits read


def test_a_mesh_whose_norms_leave_shells_empty_reads_present_on_the_bits_it_carries(tmp_path, capsys):
    mesh = _two_shells()
    empty = _empty_shells(mesh)
    assert 0 < empty <= owner.OWNER_BITS - owner.MIN_BITS_READ  # erased bits, few enough for a verdict
    key = WatermarkKey.generate(rng=np.random.default_rng(4))
    marked = owner.embed(mesh.positions, mesh.faces, key)
    for pos in (marked, _grid_quantize(marked, 14, np.random.default_rng(2))):
        r = owner.detect(pos, mesh.faces, key)
        assert r.verdict == "present" and r.erased == empty == r.bit_errors  # every bit read is right
        assert r.as_json()["erased"] == empty
    src = tmp_path / "two.obj"
    _write_obj(src, Mesh(marked, mesh.faces))
    key.save(tmp_path / "k.json")
    assert main(["verify", str(src), "--key", str(tmp_path / "k.json")]) == 0
    out = capsys.readouterr().out
    assert f"{empty}/64 bits differ from the key's {key.owner_hex}, {empty} of them in shells no vertex falls in (not read)" in out


def test_a_refusal_says_how_many_of_the_bits_read_wrong_no_vertex_carries(blob, monkeypatch):
    """The read-back's refusal counts the erased bits among the wrong ones, as ``pmw verify`` does."""
    import pmwm_codec.verify.owner as verify_owner
    from pmwm_codec.stream.encoder import _owner_check

    key = WatermarkKey.generate(rng=np.random.default_rng(3))
    eye = [[np.eye(4)]]
    for erased, said in ((9, "20 of its 64 bits wrong from the file, 9 of them in shells no vertex falls in: absent"),
                         (0, "20 of its 64 bits wrong from the file: absent")):
        monkeypatch.setattr(verify_owner, "owner_of_mesh",
                            lambda mesh, key, erased=erased: owner.OwnerResult("0" * 16, 20, erased, 1.0, "absent"))
        assert _owner_check([blob.positions], [blob.faces], key, eye).endswith(said)


def test_a_mesh_too_large_for_float32_is_refused_in_one_line_with_the_owner_layer_asked(tmp_path, capsys):
    import warnings

    src = tmp_path / "big.obj"  # a diagonal whose square is past float64: no overflow warning before the refusal
    src.write_text("v 0 0 0\nv 1e160 0 0\nv 0 1e160 0\nf 1 2 3\n")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code = main(["encode", str(src), "-o", str(tmp_path / "b.pmw"), "--owner-id", "1"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "float32" in err
    assert [str(w.message) for w in caught] == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["big.obj"]


def test_the_default_owner_layer_is_left_out_with_a_notice_where_it_cannot_be_read_back(tmp_path, capsys):
    src, img = tmp_path / "ball.obj", tmp_path / "w.png"
    _write_obj(src, shapes.icosphere(4))
    _watermark_png(img)
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert main(["encode", str(src), "-o", str(out), "--watermark", str(img), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "owner_id" not in doc
    notes = [n for n in doc["notices"] if "owner layer" in n]
    assert len(notes) == 1 and notes[0].startswith("the owner layer cannot be read back from this mesh (its vertex "
                                                   "norms span too narrow a range")
    assert notes[0].endswith("the file carries the image watermark only, and its key names no owner id")
    assert WatermarkKey.load(key).owner_id is None  # as --no-owner writes it
    assert json.loads(key.read_text())["owner_id"] is None
    assert main(["verify", str(out), "--key", str(key), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "authentic" and doc["owner"] is None  # the exact layer; no owner claim at all
    assert main(["encode", str(src), "-o", str(tmp_path / "b.pmw"), "--watermark", str(img)]) == 0
    printed, said = capsys.readouterr()
    assert "pmw: note: the owner layer cannot be read back" in said and "owner   " not in printed


def test_a_reused_key_naming_an_owner_id_marks_a_mesh_without_the_layer_and_stays_as_it_is(tmp_path, blob, capsys):
    """One key for many assets: a mesh that cannot carry the layer gets the image watermark only, the key
    file is reused untouched (it names the owner id of the files that carry it) and the notice says so."""
    ball, lumpy, img = tmp_path / "ball.obj", tmp_path / "blob.obj", tmp_path / "w.png"
    _write_obj(ball, shapes.icosphere(4))
    _write_obj(lumpy, blob)
    _watermark_png(img)
    key = tmp_path / "a.pmw.key.json"
    assert main(["encode", str(lumpy), "-o", str(tmp_path / "a.pmw"), "--watermark", str(img), "-q"]) == 0
    before = key.read_bytes()
    assert main(["encode", str(ball), "-o", str(tmp_path / "b.pmw"), "--watermark", str(img), "--key", str(key),
                 "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert "owner_id" not in doc and key.read_bytes() == before
    assert any("cannot be read back" in n and "reused as it is, names an owner id this file does not carry" in n
               for n in doc["notices"])
    assert main(["verify", str(tmp_path / "b.pmw"), "--key", str(key), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "authentic" and doc["owner"]["verdict"] != "present"
    assert main(["verify", str(tmp_path / "a.pmw"), "--key", str(key), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["owner"]["verdict"] == "present"


def test_a_layer_the_watermark_leaves_unreadable_is_caught_on_the_full_decode(tmp_path, blob, monkeypatch):
    """Under a watermark the layer is read back from the full decode (the exact layer moves vertices too):
    where that read fails the stages run again without the layer (default) or the encode is refused."""
    import pmwm_codec
    from pmwm_codec.errors import OwnerLayerError
    from pmwm_codec.stream import encoder

    reads = []
    real = encoder._owner_check

    def failing_on_the_decode(positions, faces, key, frames, notices=None):
        reads.append(real(positions, faces, key, frames, notices))
        return "forced" if len(reads) == 2 else reads[-1]

    monkeypatch.setattr(encoder, "_owner_check", failing_on_the_decode)
    src, img = tmp_path / "blob.obj", tmp_path / "w.png"
    _write_obj(src, blob)
    _watermark_png(img)
    report = pmwm_codec.encode(src, tmp_path / "a.pmw", watermark=img)
    assert reads == [None, None]  # read back after marking, then from the full decode (present both times)
    assert "owner_id" not in report and any("(forced)" in n for n in report["notices"])
    key = WatermarkKey.load(tmp_path / "a.pmw.key.json")
    assert key.owner_id is None
    result = pmwm_codec.verify_stream(str(tmp_path / "a.pmw"), key)
    assert result.verdict == "authentic"
    # the file is the one an encode without the layer writes (same key: same bytes)
    pmwm_codec.encode(src, tmp_path / "n.pmw", watermark=img, key=key, owner_id=False)
    assert (tmp_path / "a.pmw").read_bytes() == (tmp_path / "n.pmw").read_bytes()
    reads.clear()
    with pytest.raises(OwnerLayerError, match=r"\(forced\); encode without --owner-id"):
        pmwm_codec.encode(src, tmp_path / "b.pmw", watermark=img, owner_id=0x1234)
    assert not (tmp_path / "b.pmw").exists() and not (tmp_path / "b.pmw.key.json").exists()


def test_without_a_watermark_the_read_back_sees_exactly_the_full_decode(blob):
    """An owner-only encode reads the layer back from the marked positions on the grid the encoder fits,
    before simplifying: those are the positions of the full decode, so no second read is needed."""
    import io

    import pmwm_codec
    from pmwm_codec.progressive.grid import Grid
    from pmwm_codec.stream.encoder import encode_mesh

    key = WatermarkKey.generate(rng=np.random.default_rng(21))
    buf = io.BytesIO()
    report = encode_mesh(blob, buf, key=key, owner_id=0x5EED, measure=False)
    assert report.key.owner_id == 0x5EED and report.notices == []
    marked = owner.embed(blob.positions, blob.faces, report.key)
    grid = Grid.fit(marked, 16)
    decoded = pmwm_codec.decode(buf.getvalue())
    assert np.array_equal(np.unique(decoded.positions, axis=0), np.unique(grid.dequantize(grid.quantize(marked)), axis=0))
    assert owner.detect(decoded.positions, decoded.faces, report.key).verdict == "present"


def _cut(mesh, cuts) -> list:
    """``mesh`` cut into parts at the face-centre x quantiles ``cuts``; a vertex on a cut belongs to both sides."""
    x = mesh.positions[mesh.faces].mean(1)[:, 0]
    part = np.searchsorted(np.quantile(x, cuts), x, side="right")
    out = []
    for k in range(len(cuts) + 1):
        used, inverse = np.unique(mesh.faces[part == k], return_inverse=True)
        out.append(Mesh(mesh.positions[used], inverse.reshape(-1, 3)))
    return out


def _asset_of_parts(path, mesh, parts, nodes: list, one_mesh: bool):
    """A GLB of ``mesh`` cut into ``parts`` primitives by face-centre x (an int: equal face counts; a list:
    the quantiles to cut at), one glTF mesh holding them all or one mesh each, two materials, ``nodes`` as
    the scene's node list (node 0 the scene's root)."""
    from test_asset import DocBuilder

    cuts = list(parts) if not isinstance(parts, int) else [k / parts for k in range(1, parts)]
    b = DocBuilder()
    prims = [{**b.triangles(piece, uv=False), "material": i % 2} for i, piece in enumerate(_cut(mesh, cuts))]
    meshes = [{"primitives": prims}] if one_mesh else [{"primitives": [p]} for p in prims]
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=nodes, meshes=meshes,
                 materials=[{"name": "a"}, {"name": "b"}])
    path.write_bytes(b.glb())
    return path


#: node 0 rotates and scales (a similarity), node 1 translates; both place every mesh alike
_SHARED_ROOT = [{"children": [1], "rotation": [0.0, 0.38268343, 0.0, 0.92387953], "scale": [2.0, 2.0, 2.0]},
                {"mesh": 0, "translation": [1.0, 2.0, 3.0]}]


@pytest.mark.parametrize("one_mesh", [True, False], ids=["one-mesh-three-primitives", "three-meshes-one-root"])
def test_a_multi_primitive_asset_carries_one_owner_layer_read_from_the_pmw_and_the_decoded_asset(tmp_path, blob,
                                                                                                    one_mesh):
    """The primitives are marked as the one mesh both reads see: the stream's parts taken together, and the
    decoded GLB's triangle primitives placed by its nodes (a rotation and scale shared by every mesh)."""
    from pmwm_codec.stream.asset import decode_asset, encode_asset
    from pmwm_codec.format.document import load_document, read_accessor
    from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream

    nodes = _SHARED_ROOT if one_mesh else [{**_SHARED_ROOT[0], "children": [1, 2, 3]}] + [{"mesh": i} for i in range(3)]
    src = _asset_of_parts(tmp_path / "parts.glb", blob, 3, nodes, one_mesh)
    key = WatermarkKey.generate(rng=np.random.default_rng(11))
    report = encode_asset(src, tmp_path / "parts.pmw", key=key, owner_id=0x0123456789ABCDEF, measure=False)
    assert report.key.owner_id == 0x0123456789ABCDEF and not any("owner" in n for n in report.notices)
    last = owner_of_stream(tmp_path / "parts.pmw", report.key)[-1]
    assert last.owner.verdict == "present" and last.owner.bit_errors == 0
    glb, _, _ = decode_asset(tmp_path / "parts.pmw")
    (tmp_path / "out.glb").write_bytes(glb)
    read = owner_of_mesh(tmp_path / "out.glb", report.key)  # trimesh: nodes applied
    assert read.verdict == "present" and read.bit_errors == 0
    # the frame the file states (on its first progressive primitive only) is the scene's, as both reads place it
    from pmwm_codec.format.glb import split_glb
    from pmwm_codec.verify.owner import owner_view
    from pmwm_codec.watermark import owner

    gltf = split_glb((tmp_path / "parts.pmw").read_bytes())[0]
    stated = [p["extensions"]["PMWM_progressive_mesh"].get("ownerFrame") for m in gltf["meshes"] for p in m["primitives"]]
    assert stated[0] is not None and stated[1:] == [None] * (len(stated) - 1)
    view = owner_view(tmp_path / "out.glb")
    points, _ = owner.distinct_mesh(view.positions, view.faces)
    s, mass = owner._frame_scores(points, owner.frame_of_json(stated[0]))
    assert owner._bit_errors(owner._soft_rows((s[None], mass[None]), report.key)[0], report.key) == 0
    # one budget for the whole asset: the layer's RMS over every vertex, against the asset's diagonal (each
    # input vertex against the nearest decoded vertex of its primitive: the layer moves a vertex by ~0.02%
    # of the diagonal, far less than the spacing of this mesh's vertices)
    from scipy.spatial import cKDTree

    doc, buffers = load_document(src)
    out, out_buffers = load_document(tmp_path / "out.glb")
    before, gaps = [], []
    for m_in, m_out in zip(doc["meshes"], out["meshes"]):
        for p_in, p_out in zip(m_in["primitives"], m_out["primitives"]):
            x = read_accessor(doc, buffers, p_in["attributes"]["POSITION"]).astype(np.float64)
            y = read_accessor(out, out_buffers, p_out["attributes"]["POSITION"]).astype(np.float64)
            assert len(x) == len(y)
            before.append(x)
            gaps.append(cKDTree(y).query(x)[0])
    before, gaps = np.concatenate(before), np.concatenate(gaps)
    diagonal = np.linalg.norm(before.max(0) - before.min(0))
    assert 0.005 / 100 < np.sqrt(np.mean(gaps**2)) / diagonal < 0.025 / 100


def test_a_small_surface_cut_off_centre_into_primitives_carries_the_owner_layer(tmp_path):
    """A 2.5k-vertex surface cut into two primitives at 80% of its length: the cut border's vertices are in both.
    On a grid of their own each, the two copies of a border vertex decoded a grid step apart: the layer's read
    counts them as two positions on two open borders, whose surface, relaxed, loses a strip along the cut, moving
    the area centroid by most of a shell width (0 of 4 keys read back; the cow cut in two, 0 of 4).  Sharing one
    grid, they decode to one position and the layer reads as on the uncut surface."""
    from pmwm_codec.stream.asset import decode_asset, encode_asset
    from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream

    m = shapes.icosphere(4, 1.0, noise=0.03, seed=3)
    small = Mesh(m.positions * np.array([1.0, 0.7, 0.5]), m.faces)
    src = _asset_of_parts(tmp_path / "cut.glb", small, [0.8], [{"mesh": 0}], one_mesh=True)
    for seed in range(2):
        key = WatermarkKey.generate(rng=np.random.default_rng(seed))
        report = encode_asset(src, tmp_path / "cut.pmw", key=key, owner_id=0x0123456789ABCDEF, measure=False)
        assert owner_of_stream(tmp_path / "cut.pmw", report.key)[-1].owner.bit_errors == 0
        (tmp_path / "cut.glb.out.glb").write_bytes(decode_asset(tmp_path / "cut.pmw")[0])
        assert owner_of_mesh(tmp_path / "cut.glb.out.glb", report.key).verdict == "present"


#: three meshes, each under its own node: apart, turned differently, one stretched along z, one mirrored
_APART = [{"children": [1, 2, 3]},
          {"mesh": 0, "translation": [3.0, 0.0, 0.0], "rotation": [0.0, 0.0, 0.38268343, 0.92387953]},
          {"mesh": 1, "scale": [1.0, 1.0, 3.0], "translation": [0.0, -2.0, 1.0]},
          {"mesh": 2, "matrix": [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 4, 1]}]


def test_an_asset_whose_meshes_nodes_place_apart_carries_one_owner_layer_in_the_scene(tmp_path, blob):
    """Meshes placed by different node transforms (one not a similarity, one a reflection): the layer is
    marked into the scene as shown, each vertex's move taken back into its own mesh's coordinates, so the
    ``.pmw``'s read (its parts placed by the nodes) and the decoded asset's (trimesh) both read it."""
    from pmwm_codec.stream.asset import decode_asset, encode_asset
    from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream

    src = _asset_of_parts(tmp_path / "apart.glb", blob, 3, _APART, one_mesh=False)
    key = WatermarkKey.generate(rng=np.random.default_rng(5))
    report = encode_asset(src, tmp_path / "apart.pmw", key=key, owner_id=0xFEEDFACE, measure=False)
    assert report.key.owner_id == 0xFEEDFACE and not any("owner" in n for n in report.notices)
    last = owner_of_stream(tmp_path / "apart.pmw", report.key)[-1]
    assert last.owner.verdict == "present" and last.owner.bit_errors == 0
    (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "apart.pmw")[0])
    read = owner_of_mesh(tmp_path / "out.glb", report.key)
    assert read.verdict == "present" and read.bit_errors == 0
    # the stored meshes taken together, as an OBJ decode writes them, are not the scene: no false present
    import pmwm_codec

    stored = pmwm_codec.decode(tmp_path / "apart.pmw")
    assert owner_of_mesh(stored, report.key).verdict != "present"


def test_halves_stored_in_other_frames_and_put_back_to_meet_carry_the_owner_layer(tmp_path):
    """Their border coincides in the scene only; each half keeps a grid of its own, which rounds the border's
    two copies apart there. Marked as the read sees them (on their grids), the layer reads back from the
    ``.pmw`` and the decoded asset (marked on the exact positions, the read's frame moved: 20-26 of 64 bits
    wrong on the cow's halves, refused)."""
    from test_asset import DocBuilder

    from pmwm_codec.format.gltf import place
    from pmwm_codec.stream.asset import decode_asset, encode_asset
    from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream

    m = shapes.icosphere(4, 1.0, noise=0.03, seed=0)
    blob = Mesh(m.positions * np.array([1.0, 0.7, 0.5]), m.faces)  # 2.5k vertices: the frame matters
    x = blob.positions[blob.faces].mean(1)[:, 0]
    x = x - np.quantile(x, 0.3) + 0.1  # cut at the 30% quantile (the mirror's case failed there, 0 of 2 keys)
    moves = [np.diag([-1.0, 1.0, 1.0, 1.0]), np.array([[1.0, 0, 0, 4.0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]])]
    for turn in moves:
        b = DocBuilder()
        prims = []
        for k, rows in enumerate((x < 0.1, x >= 0.1)):
            used, inverse = np.unique(blob.faces[rows], return_inverse=True)
            stored = blob.positions[used] if k == 0 else place(blob.positions[used], np.linalg.inv(turn))
            prims.append(b.triangles(Mesh(stored, inverse.reshape(-1, 3)), uv=False))
        b.doc.update(scene=0, scenes=[{"nodes": [0, 1]}], meshes=[{"primitives": [p]} for p in prims],
                     nodes=[{"mesh": 0}, {"mesh": 1, "matrix": turn.T.ravel().tolist()}])
        (tmp_path / "halves.glb").write_bytes(b.glb())
        key = WatermarkKey.generate(rng=np.random.default_rng(3))
        report = encode_asset(tmp_path / "halves.glb", tmp_path / "halves.pmw", key=key, owner_id=0xC0FFEE,
                              measure=False)
        assert owner_of_stream(tmp_path / "halves.pmw", report.key)[-1].owner.verdict == "present"
        (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "halves.pmw")[0])
        assert owner_of_mesh(tmp_path / "out.glb", report.key).verdict == "present"


def test_a_mesh_shown_twice_beside_one_shown_once_leaves_its_copies_and_the_other_carries_the_layer(tmp_path, blob):
    """Nodes that share a mesh (a wheel shown four times, say) show copies that one move of the stored mesh
    cannot mark alike: they stay where they are and count in the read's statistics, and the mesh shown once
    carries the layer, read from the ``.pmw`` (every showing placed) and from the decoded asset.  (Shells that
    only such copies reach cannot be marked: here they sit within the other mesh's range of norms.)"""
    from pmwm_codec.format.document import load_document, read_accessor
    from pmwm_codec.stream.asset import decode_asset, encode_asset
    from pmwm_codec.stream.encoder import _WEAK_NOTICE
    from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream

    small = shapes.icosphere(3, 0.3, noise=0.02, seed=5)
    nodes = [{"children": [1, 2, 3]}, {"mesh": 0},
             {"mesh": 1, "translation": [0.6, 0.0, 0.0]}, {"mesh": 1, "translation": [-0.6, 0.1, 0.0]}]
    from test_asset import DocBuilder

    b = DocBuilder()
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=nodes,
                 meshes=[{"primitives": [b.triangles(blob, uv=False)]}, {"primitives": [b.triangles(small, uv=False)]}])
    (tmp_path / "wheels.glb").write_bytes(b.glb())
    key = WatermarkKey.generate(rng=np.random.default_rng(8))
    report = encode_asset(tmp_path / "wheels.glb", tmp_path / "wheels.pmw", key=key, owner_id=0xBEEF, measure=False)
    # no refusal, nor fear for re-compression; the shells the copies hold leave bits wrong, and a note says how many
    assert not any("owner" in n and not n.startswith(_WEAK_NOTICE) for n in report.notices)
    assert owner_of_stream(tmp_path / "wheels.pmw", report.key)[-1].owner.verdict == "present"
    (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "wheels.pmw")[0])
    assert owner_of_mesh(tmp_path / "out.glb", report.key).verdict == "present"
    doc, buffers = load_document(tmp_path / "out.glb")
    shared = read_accessor(doc, buffers, doc["meshes"][1]["primitives"][0]["attributes"]["POSITION"])
    step = 2 * np.ptp(small.positions, axis=0).max() / 2**16  # the 16-bit grid's step is about half that
    assert np.abs(np.sort(shared, axis=0) - np.sort(small.positions, axis=0)).max() <= step  # not moved


def _instanced(b, mesh_index: int, offsets) -> dict:
    """A node drawing mesh ``mesh_index`` once per row of ``offsets`` (k, 3) by ``EXT_mesh_gpu_instancing``."""
    tr = b.accessor(np.asarray(offsets, np.float32), 5126, "VEC3")
    b.doc.setdefault("extensionsUsed", []).append("EXT_mesh_gpu_instancing")
    return {"mesh": mesh_index, "extensions": {"EXT_mesh_gpu_instancing": {"attributes": {"TRANSLATION": tr}}}}


_STORED_VIEWS = {
    # every mesh shown twice: one mesh of two primitives under two nodes (a wheel of two parts, shown twice)
    "every-mesh-twice": [{"children": [1, 2]}, {"mesh": 0}, {"mesh": 0, "translation": [0.0, 4.0, 0.0],
                                                             "rotation": [0.0, 0.0, 0.38268343, 0.92387953]}],
    # flattened by a scale of zero: no inverse to take a move in the scene back through
    "flat": [{"children": [1], "scale": [0.0, 0.0, 0.0]}, {"mesh": 0}],
    # GPU instancing: where the instances are drawn the accessors say, which the reads do not place
    "gpu-instanced": None,
}


@pytest.mark.parametrize("case", sorted(_STORED_VIEWS))
def test_an_asset_with_no_mesh_shown_once_carries_the_owner_layer_in_its_stored_meshes(tmp_path, blob, case):
    """Nodes that all share their meshes (instances), GPU instancing, or a scale of zero: no one move of the
    stored positions marks the scene, so the layer is marked in the meshes' own coordinates, each mesh once
    (:func:`~pmwm_codec.format.gltf.owner_placements`), and read there from the ``.pmw`` at every boundary and
    from the decoded GLB; the GLB's scene flattened (as an OBJ of it is written) is not that view, and reads
    no false ``present``.  (These assets were refused before: ``every mesh is shown more than once``.)"""
    from test_asset import DocBuilder

    from pmwm_codec.stream.asset import decode_asset, encode_asset
    from pmwm_codec.verify.owner import owner_of_mesh, owner_of_stream, owner_view

    b = DocBuilder()
    prims = [b.triangles(piece, uv=False) for piece in _cut(blob, [0.5])]
    nodes = _STORED_VIEWS[case]
    if nodes is None:
        nodes = [{"children": [1]}, _instanced(b, 0, [[0.0, 0.0, 0.0], [3.0, 0.0, 0.0], [0.0, 3.0, 0.0]])]
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=nodes, meshes=[{"primitives": prims}])
    (tmp_path / "in.glb").write_bytes(b.glb())
    key = WatermarkKey.generate(rng=np.random.default_rng(11))
    report = encode_asset(tmp_path / "in.glb", tmp_path / "in.pmw", key=key, owner_id=0x5EED0F0123456789,
                          measure=False)
    assert report.key.owner_id == 0x5EED0F0123456789 and not any("owner" in n for n in report.notices)
    reads = owner_of_stream(tmp_path / "in.pmw", report.key)
    assert reads[-1].owner.verdict == "present" and reads[-1].owner.bit_errors == 0
    (tmp_path / "out.glb").write_bytes(decode_asset(tmp_path / "in.pmw")[0])
    view = owner_view(tmp_path / "out.glb")
    assert view.vertex_count == sum(len(np.unique(p.faces)) for p in _cut(blob, [0.5]))  # each stored once
    read = owner_of_mesh(tmp_path / "out.glb", report.key)
    assert read.verdict == "present" and read.bit_errors == 0
    if case == "every-mesh-twice":  # the scene flattened (as an OBJ of it is written): two copies apart,
        import pmwm_codec  # each a piece read on its own; the two are copies, so one is read

        flat = pmwm_codec.read_mesh(tmp_path / "out.glb")
        from_copies = owner_of_mesh(flat, report.key)
        assert from_copies.verdict == "present" and from_copies.bit_errors == 0
        assert from_copies.false_alarm_probability == pytest.approx(2 * owner.false_alarm_probability(0))


def test_a_marked_mesh_beside_another_object_or_shown_twice_in_one_mesh_file_reads_present(blob, marked):
    """An OBJ of a scene that shows the marked object twice, or that puts it beside an object of its own
    (here a torus of 15% of the vertices; one of 1% did as much), read whole gave 25-50 bit errors: the
    layer's frame is the marked object's, not the file's.  Each separate piece is now read too, and the false-alarm bound covers every read made."""
    from pmwm_codec.verify.owner import owner_of_mesh, pieces

    key, pos = marked
    q, _ = np.linalg.qr(np.random.default_rng(4).normal(size=(3, 3)))
    size = np.ptp(pos, axis=0).max()
    other = shapes.torus(60, 30)
    for second, faces2 in ((pos @ q.T * 2.0 + 3 * size, blob.faces),  # a copy, turned, scaled, moved apart
                           (other.positions * size + [0.0, 0.0, 3 * size], other.faces)):  # another object
        both = np.concatenate([pos, second])
        faces = np.concatenate([blob.faces, faces2 + len(pos)])
        parts = pieces(Mesh(both, faces))
        assert len(parts) == (1 if faces2 is blob.faces else 2)  # copies are read once; else each object
        assert owner.detect(both, faces, key).verdict != "present"  # the whole, as before
        r = owner_of_mesh(Mesh(both, faces), key)
        assert r.verdict == "present" and r.bit_errors == 0 and r.id == key.owner_hex
        assert r.false_alarm_probability == pytest.approx((1 + len(parts)) * owner.false_alarm_probability(0))
        rng = np.random.default_rng(12)
        for _ in range(20):  # wrong keys: the extra reads give no false present
            assert owner_of_mesh(Mesh(both, faces), WatermarkKey.generate(rng=rng)).verdict != "present"
    assert pieces(blob) == [] and pieces(Mesh(pos, blob.faces)) == []  # one piece: read whole, as before


def _laplacian_smoothing(positions, faces, iterations, lam=0.03):
    """The benchmark's smoothing attack (MEPP's LaplacianSmoothing: Jacobi, uniform weights), written
    out here with a loop over the edges, independent of the reader's umbrella operator."""
    n = len(positions)
    nbrs = [set() for _ in range(n)]
    for a, b, c in np.asarray(faces):
        nbrs[a] |= {b, c}
        nbrs[b] |= {a, c}
        nbrs[c] |= {a, b}
    idx = [np.fromiter(s, np.int64) for s in nbrs]
    x = np.array(positions, np.float64)
    for _ in range(iterations):
        x = x + lam * (np.array([x[i].mean(0) if len(i) else x[j] for j, i in enumerate(idx)]) - x)
    return x


def test_the_umbrella_operator_is_the_mean_of_the_neighbours_minus_the_point():
    """A neighbour counts once per face it shares (twice for every neighbour inside a closed surface);
    a point on no face gets 0."""
    pos = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0], [5, 5, 5]], np.float64)
    faces = np.array([[0, 1, 2], [1, 3, 2]])
    u = owner._umbrella(pos, faces)
    expect = np.array([[0.5, 0.5, 0], [-0.75, 0.75, 0], [0.75, -0.75, 0], [-0.5, -0.5, 0], [0, 0, 0]])
    assert np.allclose(u, expect)
    closed = shapes.icosphere(2, 1.0)
    u = owner._umbrella(closed.positions, closed.faces)
    for v in (0, 17, 100):
        ring = np.unique(closed.faces[(closed.faces == v).any(1)])
        ring = ring[ring != v]
        assert np.allclose(u[v], closed.positions[ring].mean(0) - closed.positions[v])


def test_the_un_smoothed_view_is_three_explicit_steps_back_along_the_umbrella(blob):
    """``_unsmoothed_view`` of the umbrella's powers is ``Q`` steps of ``a / Q``, each with the umbrella of the
    positions the step before left (the operator is linear in the positions, so its powers serve every ``a``)."""
    points, inverse = owner._distinct_index(blob.positions)
    faces = inverse[blob.faces]
    powers = owner._umbrella_powers(points, faces)
    assert len(powers) == owner.UNSMOOTH_STEPS + 1 == 4
    for a in (0.0, 0.3, 1.7, 4.0):
        p = points
        for _ in range(owner.UNSMOOTH_STEPS):
            p = p - a / owner.UNSMOOTH_STEPS * owner._umbrella(p, faces)
        assert np.allclose(owner._unsmoothed_view(powers, a), p, rtol=0, atol=1e-12 * np.abs(points).max())


@pytest.mark.parametrize("iterations", [10, 30])
def test_a_smoothed_mesh_reads_present_through_steps_back(blob, marked, monkeypatch, iterations):
    """Laplacian smoothing shrinks the surface unevenly by tenths of a shell: read as it is, the marked mesh
    after 10 or 30 iterations is absent; the read's un-smoothed view reads it present."""
    key, pos = marked
    smoothed = _laplacian_smoothing(pos, blob.faces, iterations)
    r = owner.detect(smoothed, blob.faces, key)
    assert r.verdict == "present" and r.bit_errors <= 3
    monkeypatch.setattr(owner, "UNSMOOTH", (0.0,))  # the un-smoothed view is the mesh as it is
    assert owner.detect(smoothed, blob.faces, key).verdict == "absent"


def test_on_a_coarse_mesh_three_steps_back_read_what_one_step_misses(monkeypatch):
    """On ~40 vertices a shell the neighbours lie shells apart, and 30 smoothing iterations are far from the
    first-order reach of one step back: with one step 4 keys read 3-7 errors, with three none."""
    m = shapes.icosphere(4, 1.0, noise=0.03, seed=5)
    pos, faces = m.positions * np.array([1.0, 0.7, 0.5]), m.faces
    errors = {}
    for steps in (1, owner.UNSMOOTH_STEPS):
        monkeypatch.setattr(owner, "UNSMOOTH_STEPS", steps)
        errors[steps] = []
        for k in range(4):
            key = WatermarkKey.generate(rng=np.random.default_rng(40 + k))
            smoothed = _laplacian_smoothing(owner.embed(pos, faces, key), faces, 30)
            errors[steps].append(owner.detect(smoothed, faces, key).bit_errors)
    assert errors[owner.UNSMOOTH_STEPS] == [0, 0, 0, 0] and sum(errors[1]) > 8


def test_the_un_smoothing_step_is_chosen_by_the_mesh_alone(blob, marked):
    """The step comes from sum |S_k| in the estimated frame, not from any key: the more iterations of
    smoothing, the larger the step back."""
    _, pos = marked

    def step(positions):
        p, inverse = owner._distinct_index(positions)
        faces = inverse[blob.faces]
        view, powers = owner._unsmoothed(p, faces), owner._umbrella_powers(p, faces)
        return min(owner.UNSMOOTH, key=lambda a: np.abs(view - owner._unsmoothed_view(powers, a)).max())

    steps = [step(_laplacian_smoothing(pos, blob.faces, it)) for it in (5, 20, 30)]
    assert steps[0] < steps[1] < steps[2]


def test_the_un_smoothed_views_are_read_unless_the_mesh_as_it_is_reads_without_an_error(blob, marked, monkeypatch):
    """A transported mesh reads every bit as it is and never pays for un-smoothing; a smoothed one reads the
    same answer directly and from scores read once for every key."""
    key, pos = marked
    smoothed = _laplacian_smoothing(pos, blob.faces, 30)
    scores = owner.mesh_scores(smoothed, blob.faces)
    assert len(scores[0]) == owner.FRAMES
    assert owner.detect(smoothed, blob.faces, key) == owner.detect(smoothed, blob.faces, key, scores=scores)

    def refuse(points, faces):
        raise AssertionError("un-smoothed a mesh that reads present as it is")

    monkeypatch.setattr(owner, "_unsmoothed", refuse)
    assert owner.detect(pos.astype(np.float32), blob.faces, key).bit_errors == 0
    with pytest.raises(AssertionError, match="un-smoothed"):
        owner.detect(smoothed, blob.faces, key)


def test_the_spec_states_the_piece_rule_with_the_readers_numbers():
    """spec/watermark.md §7 "Pieces" is what a second reader implements: its numbers are the code's."""
    from pathlib import Path

    from pmwm_codec.verify import owner as reader

    text = " ".join((Path(__file__).resolve().parents[1] / "spec" / "watermark.md").read_text().split())
    assert f"the {reader.MAX_GROUPED} largest are also grouped" in text
    assert f"at least {reader.MIN_PIECE_VERTICES} distinct positions" in text
    assert f"at most {reader.MAX_PIECES} are kept" in text
    assert f"`{owner.HYPOTHESES} (1 + P)`" in text
    assert f"{owner.ALTERNATIVES} **alternative codings**" in text and "row 0, which is all zero" in text
    assert owner.ALT_STREAM_ID == int.from_bytes(b"owneralt", "big") and 'int.from_bytes(b"owneralt", "big")' in text
    assert f"the {owner.FRAMES} x {owner.ALTERNATIVES} = {owner.HYPOTHESES} codings read" in text


def test_a_stream_of_many_small_chunks_is_read_where_its_level_has_grown_and_at_its_end(tmp_path, blob, monkeypatch,
                                                                                      capsys):
    """A multi-primitive asset streams in hundreds of small chunks (assimp's 2CylinderEngine: 442), and the owner
    was read at every one: 190 s of ``pmw verify`` (0.42 s a read).  It is now read at the base, wherever the
    level has REREAD_GROWTH more vertices than at the last read, and at the last boundary; a boundary between
    carries the last read, naming it (``read_at_chunk``).  Reading every boundary gives the same final answer."""
    from pmwm_codec.verify import owner as verify_owner
    from pmwm_codec.watermark import owner as layer

    src = tmp_path / "blob.obj"
    _write_obj(src, blob)
    out, key = tmp_path / "b.pmw", tmp_path / "b.key.json"
    assert main(["encode", str(src), "-o", str(out), "--owner-id", "00c0ffee00c0ffee", "--key", str(key), "-q"]) == 0
    every = verify_owner.owner_of_stream(out, key, every=True)
    calls = []
    monkeypatch.setattr(verify_owner, "detect", lambda p, f, k, **kw: calls.append(len(p)) or layer.detect(p, f, k, **kw))
    monkeypatch.setattr(verify_owner, "REREAD_GROWTH", 0.5)  # coarse, so that this small stream skips some
    some = verify_owner.owner_of_stream(out, key)
    assert len(some) == len(every) and 2 < len(calls) < len(every)
    assert some[-1] == every[-1] and some[-1].read_at == some[-1].chunk  # the last boundary is read, always
    last_read = None
    for b, e in zip(some, every):
        if b.read_at == b.chunk:
            assert b.owner == e.owner  # a boundary read is the same read
            assert last_read is None or b.vertices >= last_read.vertices * 1.5 or b is some[-1]
            last_read = b
        else:  # between reads: the last read, named
            assert b.read_at == last_read.chunk and b.owner == last_read.owner and b.vertices < last_read.vertices * 1.5
    capsys.readouterr()
    assert main(["verify", str(out), "--key", str(key), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert [c["owner"]["read_at_chunk"] for c in doc["chunks"]] == [b.read_at for b in some]


def test_the_encoder_checks_the_layer_after_the_quantization_re_compression_applies(blob, marked):
    """None when the layer reads present after 11- and 14-bit quantization (coincident positions merged, as
    in the file Draco or gltfpack writes); a notice naming both read-backs when it does not (here: another
    key, whose layer the mesh does not carry)."""
    from pmwm_codec.stream.encoder import _transport_check

    key, pos = marked
    assert _transport_check(pos, blob.faces, key) is None
    said = _transport_check(pos, blob.faces, WatermarkKey.generate(rng=np.random.default_rng(11)))
    assert said is not None and "after 11-bit quantization" in said and "after 14-bit quantization" in said
    assert said.startswith("the owner layer may not survive re-compression of this mesh")


def test_a_layer_that_would_not_survive_re_compression_is_written_with_a_notice(tmp_path, blob, capsys, monkeypatch):
    import pmwm_codec.stream.encoder as encoder

    seen = []

    def fragile(points, faces, key):
        seen.append(len(points))
        return f"{encoder._TRANSPORT_NOTICE}: (simulated)"

    monkeypatch.setattr(encoder, "_transport_check", fragile)
    src = tmp_path / "blob.obj"
    _write_obj(src, blob)
    out = tmp_path / "b.pmw"
    assert main(["encode", str(src), "-o", str(out), "--owner-id", "00c0ffee00c0ffee", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert seen == [blob.vertex_count] and f"{encoder._TRANSPORT_NOTICE}: (simulated)" in doc["notices"]
    assert main(["verify", str(out), "--key", str(tmp_path / "b.pmw.key.json"), "--json"]) == 0  # the layer is there
    assert json.loads(capsys.readouterr().out)["owner"]["verdict"] == "present"


def test_a_mark_that_reads_a_bit_wrong_as_written_is_written_with_a_notice_saying_how_many(tmp_path, blob, capsys):
    """A mark that reads ``present`` from the file it was written to, but with bits wrong or erased (here: a mesh
    whose norms leave shells empty), has that many fewer to lose to an attack: one notice says how many, as
    ``pmw verify`` counts them; a mark that reads every bit gets none.  Under a watermark the count is the full
    decode's (the exact layer moves vertices too), said once."""
    from pmwm_codec.stream.encoder import _WEAK_NOTICE

    img = tmp_path / "w.png"
    _watermark_png(img)
    for name, mesh, image in (("gapped", _two_shells(), None), ("blob", blob, None), ("imaged", _two_shells(), img)):
        src, out, key = tmp_path / f"{name}.obj", tmp_path / f"{name}.pmw", tmp_path / f"{name}.pmw.key.json"
        _write_obj(src, mesh)
        if image is None:  # the owner layer alone, of a key made before; else a new key with a random owner ID
            WatermarkKey.generate(rng=np.random.default_rng(4)).save(key)
        image = [] if image is None else ["--watermark", str(image)]
        assert main(["encode", str(src), "-o", str(out), "--json", *image] + (["--key", str(key)] * key.exists())) == 0
        said = [n for n in json.loads(capsys.readouterr().out)["notices"] if n.startswith(_WEAK_NOTICE)]
        assert main(["verify", str(out), "--key", str(key), "--json"]) == 0
        read = json.loads(capsys.readouterr().out)["owner"]
        assert read["verdict"] == "present" and (read["bit_errors"] > 0) == (name != "blob")
        if name == "blob":
            assert said == []
            continue
        assert len(said) == 1 and f"pmw verify reads {read['bit_errors']} of its 64 bits wrong" in said[0]
        assert f", {read['erased']} of them in shells no vertex falls in" in said[0] and read["erased"] > 0
        assert main(["encode", str(src), "-o", str(tmp_path / f"{name}-2.pmw"), "--key", str(key), *image]) == 0
        assert f"pmw: note: {said[0]}\n" in capsys.readouterr().err  # the same line in the text form


def test_a_layer_that_reads_from_the_file_but_not_once_rounded_to_float32_is_refused(blob, monkeypatch):
    """A decoded GLB, or a re-saved copy, holds the scene a few float32 steps away: the read-back reads that too."""
    import pmwm_codec.verify.owner as verify_owner
    from pmwm_codec.stream.encoder import _owner_check

    key = WatermarkKey.generate(rng=np.random.default_rng(3))
    seen = []

    def read(mesh, key):
        seen.append(mesh.positions.copy())
        return owner.OwnerResult("0" * 16, 0, 0, 1e-20, "present") if len(seen) == 1 else \
            owner.OwnerResult("0" * 16, 20, 5, 1.0, "absent")

    monkeypatch.setattr(verify_owner, "owner_of_mesh", read)
    said = _owner_check([blob.positions], [blob.faces], key, [[np.eye(4)]])
    assert said.endswith("20 of its 64 bits wrong from the file's positions rounded to float32, as a decoded or "
                         "re-saved copy holds them, 5 of them in shells no vertex falls in: absent")
    assert np.array_equal(seen[1], seen[0].astype(np.float32)) and not np.array_equal(seen[1], seen[0])
