"""The software renderer and the figures built on it."""

from __future__ import annotations

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.figures import _ticks, metrics_plot, overview, pick_levels, write_figures
from pmwm_codec.render import BACKGROUND, Camera, rasterize, render
from pmwm_codec.stream.decoder import Part, PartialResult
from pmwm_codec.progressive.grid import Grid


def test_render_shape_background_and_surface():
    m = shapes.icosphere(3)
    img = render(m.positions, m.faces, width=120, height=90)
    assert img.shape == (90, 120, 3) and img.dtype == np.uint8
    assert tuple(img[0, 0]) == BACKGROUND and tuple(img[-1, -1]) == BACKGROUND
    centre = img[45, 60].astype(int)
    assert (centre != BACKGROUND).any()
    covered = (img != BACKGROUND).any(axis=2).mean()
    assert 0.3 < covered < 0.8  # a sphere fills a disc, not the frame


def test_render_is_shaded_not_flat_colour():
    m = shapes.icosphere(3)
    img = render(m.positions, m.faces, width=100, height=100, supersample=1)
    mask = (img != BACKGROUND).any(axis=2)
    assert len(np.unique(img[mask].reshape(-1, 3), axis=0)) > 20


def test_one_camera_lines_frames_up():
    fine = shapes.icosphere(4)
    coarse = shapes.icosphere(1)
    cam = Camera.fit(fine.positions, 80, 80)
    a = (render(fine.positions, fine.faces, cam) != BACKGROUND).any(axis=2)
    b = (render(coarse.positions, coarse.faces, cam) != BACKGROUND).any(axis=2)
    iou = (a & b).sum() / (a | b).sum()
    assert iou > 0.85


def test_rasterize_triangle_area_and_zbuffer():
    # a right triangle covering half of a 40x40 square, and a nearer one over its corner
    screen = np.array([[0, 0, 0], [40, 0, 0], [0, 40, 0], [0, 0, 1], [10, 0, 1], [0, 10, 1]], dtype=float)
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    fbuf = rasterize(screen, faces, 40, 40)
    assert abs((fbuf >= 0).sum() - 800) < 45
    assert fbuf[2, 2] == 1 and fbuf[20, 5] == 0 and fbuf[39, 39] == -1
    fbuf = rasterize(screen[[0, 1, 2, 3, 4, 5]] * [1, 1, -1], faces, 40, 40)  # now the big one is nearer
    assert fbuf[2, 2] == 0


def test_render_no_faces_is_background():
    img = render(np.zeros((3, 3)) + np.eye(3), np.zeros((0, 3), int), width=10, height=10)
    assert (img == BACKGROUND).all()


def test_pick_levels():
    assert pick_levels([10, 20, 30]) == [0, 1, 2]
    picked = pick_levels(np.geomspace(100, 100000, 40).astype(int), 5)
    assert picked[0] == 0 and picked[-1] == 39 and len(picked) == 5
    assert np.all(np.diff(picked) > 5)  # spread out on a log scale


def test_ticks_are_round_numbers():
    t = _ticks(0, 213)
    assert t[0] == 0 and np.all(np.diff(t) == 50)


def _results():
    grid = Grid.fit(np.array([[-1.0, -1, -1], [1, 1, 1]]), 12)
    out = []
    for i, k in enumerate((1, 2, 3)):
        m = shapes.icosphere(k)
        mark = np.full((16, 16), 40 * i, np.uint8)
        psnr = float("inf") if i == 2 else 10.0 + 5 * i
        part = Part(grid.quantize(m.positions), m.faces, np.zeros((m.vertex_count, 0), np.int64), grid)
        out.append(PartialResult(i, 2, 1000 * (i + 1), m.vertex_count, m.face_count, grid,
                                 [part], mark, 10 * i, 0.5 + 0.25 * i, psnr))
    return out


def test_overview_and_plot_images():
    rs = _results()
    img = overview(rs, k=5, title="t", total_bytes=5000)
    assert img.mode == "RGB" and img.width > 3 * 200
    plot = metrics_plot(rs, title="t", total_bytes=5000, bytes_received=3500)
    assert plot.size == (760, 460)
    a = np.asarray(plot)
    assert (a != 255).any(axis=2).mean() > 0.02  # axes, ticks and lines were drawn


def test_write_figures(tmp_path):
    paths = write_figures(_results(), tmp_path / "f", title="x")
    assert [p.rsplit("/", 1)[1] for p in paths["frames"]] == ["frame_000.png", "frame_001.png", "frame_002.png"]
    assert (tmp_path / "f" / "overview.png").exists() and (tmp_path / "f" / "metrics.png").exists()


@pytest.mark.parametrize("k", [1, 3])
def test_overview_with_few_results(k):
    assert overview(_results()[:k]).width > 0
