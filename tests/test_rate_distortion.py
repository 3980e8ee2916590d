"""The simplifier's order at equal vertex counts, and the rate-distortion bench (tools/bench_rd.py)."""

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.distortion import rms_surface_distance
from pmwm_codec.progressive import simplify as simplify_mod
from pmwm_codec.progressive.simplify import _affordable, simplify
from tools import bench_rd


def test_affordable_keeps_the_candidates_no_dearer_than_the_quantile_of_each_vertexs_cheapest():
    # three vertices' candidates, grouped by removed vertex, cheapest first
    cu = np.array([0, 0, 1, 1, 2], np.int64)
    cost = np.array([1.0, 5.0, 2.0, 3.0, 9.0])
    cv, ce = np.arange(5) + 10, np.arange(5) + 20
    kept = _affordable(cu, cv, ce, cost, 0.5)  # the median of (1, 2, 9) is 2
    assert kept[0].tolist() == [0, 1] and kept[3].tolist() == [1.0, 2.0]
    assert kept[1].tolist() == [10, 12] and kept[2].tolist() == [20, 22]
    assert all(np.array_equal(a, b) for a, b in zip(_affordable(cu, cv, ce, cost, 1.0), (cu, cv, ce, cost)))


def test_level_at_gives_exactly_the_asked_vertex_count_on_the_input_positions():
    mesh = shapes.torus(32, 16)
    log = simplify(mesh.positions, mesh.faces, target_vertices=40)
    for count in (40, 100, 333, mesh.vertex_count):
        level = bench_rd.level_at(mesh, log, count)
        assert level.vertex_count == count
        assert len(np.unique(level.faces)) == count
        # half-edge collapses never move a vertex: every level vertex is an input vertex
        assert {tuple(p) for p in level.positions} <= {tuple(p) for p in mesh.positions}
    full = bench_rd.level_at(mesh, log, mesh.vertex_count)
    assert rms_surface_distance(mesh, full, samples=2000) < 1e-12


@pytest.mark.parametrize("mesh", [shapes.grid(40, 40, hole=False, bump=0.4), shapes.torus(48, 24, twist=0.3)],
                         ids=["bumpy-grid", "twisted-torus"])
def test_cost_capped_batches_give_closer_levels_at_the_same_vertex_count(mesh, monkeypatch):
    def errors(quantile):
        monkeypatch.setattr(simplify_mod, "BATCH_QUANTILE", quantile)
        log = simplify(mesh.positions, mesh.faces, target_vertices=mesh.vertex_count // 20)
        return [rms_surface_distance(mesh, bench_rd.level_at(mesh, log, k), samples=20_000)
                for k in (mesh.vertex_count // 10, mesh.vertex_count // 4)]

    default = simplify_mod.BATCH_QUANTILE
    assert default < 1.0
    every_winner, capped = errors(1.0), errors(default)
    assert all(c < e for c, e in zip(capped, every_winner))


def test_cost_capped_batches_still_reach_the_base_target():
    mesh = shapes.icosphere(4, noise=0.02)
    log = simplify(mesh.positions, mesh.faces, target_vertices=64)
    assert len(log.base_vertices) == 64


def test_bench_rd_measures_every_boundary_and_fits_prefixes_in_the_lod_bytes():
    mesh = shapes.torus(64, 32, twist=0.2)
    res = bench_rd.measure("torus", mesh, 14, 3000, lambda s: None)
    sizes = [c[0] for c in res["curve"]]
    assert sizes == sorted(sizes) and sizes[-1] <= res["bytes"]
    assert res["curve"][-1][1] == mesh.vertex_count
    assert res["curve"][-1][2] < res["curve"][0][2]  # the full mesh is closer than the base
    assert [x["fraction"] for x in res["lods"]] == list(bench_rd.FRACTIONS)
    for x in res["lods"]:
        assert x["ours_k_vertices"] == max(x["lod_vertices"], res["curve"][0][1])  # never below our base
        if x["prefix"] is not None:
            assert x["prefix"][0] <= x["lod_bytes"]
            later = [c for c in res["curve"] if c[0] > x["prefix"][0]]
            assert not later or later[0][0] > x["lod_bytes"]  # the longest prefix that fits
    md = bench_rd.render([{**res, "samples": 3000}], {"cpu": "x", "cores": 2, "load": (0, 0, 0), "python": "3",
                                                      "numpy": "2", "DracoPy": "2", "fast_simplification": "0",
                                                      "git": "abc"}, "python tools/bench_rd.py", None)
    assert md.count("| torus | 14 |") == 2 * len(bench_rd.FRACTIONS) + 1  # same bytes, placement, the stream


def test_bench_rd_same_bytes_only_gives_the_full_runs_same_bytes_cells_and_skips_the_diagnostics():
    mesh = shapes.torus(64, 32, twist=0.2)
    full = bench_rd.measure("torus", mesh, 14, 3000, lambda s: None)
    quick = bench_rd.measure("torus", mesh, 14, 3000, lambda s: None, same_bytes_only=True)
    assert [c[:2] for c in quick["curve"]] == [c[:2] for c in full["curve"]]
    assert quick["curve"][0] == full["curve"][0]  # the base is always measured
    for a, b in zip(full["lods"], quick["lods"]):
        for key in ("lod_bytes", "lod_error", "prefix", "prefix_chunks", "prefix_no_json"):
            assert a[key] == b[key], key
        assert b["ours_k_error"] is None and b["placed_error"] is None and b["snapped_error"] is None
    skipped = [c for c in quick["curve"] if c[2] is None]
    assert skipped, "a prefix that no LOD picks is not measured"
    md = bench_rd.render([{**quick, "samples": 3000}], {"cpu": "x", "cores": 2, "load": (0, 0, 0), "python": "3",
                                                        "numpy": "2", "DracoPy": "2", "fast_simplification": "0",
                                                        "git": "abc"}, "python tools/bench_rd.py", None)
    assert md.count("| torus | 14 |") == len(bench_rd.FRACTIONS) + 1 and "not measured" in md


def test_level_clusters_send_every_vertex_to_a_vertex_of_the_level():
    mesh = shapes.torus(32, 16)
    log = simplify(mesh.positions, mesh.faces, target_vertices=40)
    for count in (40, 100, 333):
        _, faces, rep = bench_rd.level_clusters(mesh, log, count)
        level = np.unique(faces)
        assert len(level) == count
        assert np.array_equal(np.unique(rep), level)  # every cluster is headed by a level vertex
        assert np.array_equal(rep[level], level)


def test_quadric_placement_moves_only_the_vertices_that_absorbed_others_and_undoes_noise():
    # a noisy sphere: half-edge collapses keep noisy input vertices, the cluster's quadric minimum averages them
    mesh = shapes.icosphere(4, noise=0.01)
    log = simplify(mesh.positions, mesh.faces, target_vertices=64)
    core, faces, rep = bench_rd.level_clusters(mesh, log, 1500)  # of 2,562: some absorbed nobody
    kept = bench_rd.compact(core.positions, faces)
    placed = bench_rd.placed_level(core, faces, rep)
    assert np.array_equal(placed.faces, kept.faces)
    alone = np.bincount(rep, minlength=core.vertex_count)[np.unique(faces)] == 1
    assert alone.any() and np.array_equal(placed.positions[alone], kept.positions[alone])
    assert not np.array_equal(placed.positions[~alone], kept.positions[~alone])
    assert rms_surface_distance(mesh, placed, samples=20_000) < rms_surface_distance(mesh, kept, samples=20_000)


def test_snapping_a_lod_puts_every_vertex_on_an_input_vertex():
    mesh = shapes.icosphere(3, noise=0.01)
    lod = bench_rd.compact(mesh.positions[::3] * 1.001, mesh.faces[: len(mesh.faces) // 4] // 3)
    snapped = bench_rd.snapped(mesh, lod)
    assert np.array_equal(snapped.faces, lod.faces)
    assert {tuple(p) for p in snapped.positions} <= {tuple(p) for p in mesh.positions}
