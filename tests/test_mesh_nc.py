"""The paper's mesh NC (:func:`pmwm_codec.distortion.mesh_nc`)."""

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.distortion import mesh_nc
from pmwm_codec.errors import MeshError


def test_identical_meshes_correlate_to_one():
    m = shapes.icosphere(3, 1.0, noise=0.02)
    assert mesh_nc(m, m) == pytest.approx(1.0, abs=1e-15)


def test_nc_falls_with_the_noise_as_half_the_squared_relative_error():
    m = shapes.icosphere(3, 1.0, noise=0.02)
    rng = np.random.default_rng(0)
    p = m.positions - m.positions.mean(0)
    radius = np.sqrt(np.mean(np.sum(p**2, axis=1)))
    values = []
    for sigma in (1e-4, 1e-3, 1e-2):
        noisy = m.positions + rng.normal(0.0, sigma, m.positions.shape)
        values.append(mesh_nc(m, noisy))
        # noise of variance sigma^2 per coordinate: |error|^2 / |a|^2 ~ 3 sigma^2 / radius^2, nearly all orthogonal to a
        assert 1 - values[-1] == pytest.approx(1.5 * sigma**2 / radius**2, rel=0.2)
    assert values[0] > values[1] > values[2]


def test_nc_ignores_a_shared_translation_but_not_a_shift_of_one_mesh():
    m = shapes.icosphere(3, 1.0)
    assert mesh_nc(m.positions + 5.0, m.positions + 5.0) == pytest.approx(1.0)
    assert mesh_nc(m.positions, m.positions + 0.5) < 0.9


def test_nc_needs_the_same_vertices():
    with pytest.raises(MeshError):
        mesh_nc(np.zeros((4, 3)), np.zeros((5, 3)))
