"""Grid and AttributeGrid: one validator, exact float32 round trips, checked reads."""

from __future__ import annotations

import numpy as np
import pytest

from pmwm_codec.errors import FormatError
from pmwm_codec.progressive.grid import AttributeGrid, Grid

GOOD = {"bits": 16, "origin": [0.5, -1.0, 2.0], "step": 0.001}


def test_grid_config_round_trips():
    grid = Grid.from_config(GOOD)
    assert grid == Grid(16, (0.5, -1.0, 2.0), 0.001)
    assert Grid.from_config(grid.get_config()) == grid


@pytest.mark.parametrize("config, match", [
    ({**GOOD, "bits": "16"}, "bits must be an integer"),
    ({**GOOD, "bits": 16.0}, "bits must be an integer"),
    ({**GOOD, "bits": True}, "bits must be an integer"),
    ({**GOOD, "bits": 99}, "bits must be an integer"),
    ({**GOOD, "origin": [0, 0]}, "origin must be 3 finite numbers"),
    ({**GOOD, "origin": ["0", 0, 0]}, "origin must be finite numbers"),
    ({**GOOD, "origin": [float("nan"), 0, 0]}, "origin must be finite numbers"),
    ({**GOOD, "origin": [10**400, 0, 0]}, "origin must be finite numbers"),  # a JSON integer no float holds
    ({**GOOD, "step": 0}, "step must be positive"),
    ({**GOOD, "step": 10**400}, "step must be positive"),
    ({**GOOD, "step": "0.5"}, "step must be positive"),
    ({"bits": 16, "origin": [0, 0, 0]}, "needs bits, origin and step"),
])
def test_grid_from_config_is_strict(config, match):
    with pytest.raises(FormatError, match=match):
        Grid.from_config(config)


def test_grid_float32_round_trip_is_exact_and_checked():
    grid = Grid.from_config(GOOD)
    q = np.array([[0, 1, 2], [65535, 3, 40000]], np.int64)
    stored = grid.to_float32(q)
    assert stored.dtype == np.float32
    back = grid.from_float32(stored)
    assert back.dtype == np.int64 and np.array_equal(back, q)
    with pytest.raises(FormatError, match="base mesh: positions lie outside the 16-bit grid"):
        grid.from_float32(grid.to_float32(q) - 1.0)
    with pytest.raises(FormatError, match="positions are not finite"):
        grid.from_float32(np.full((1, 3), np.nan))


def test_attribute_grid_fits_round_trips_and_checks():
    values = np.array([[0.0, 1.0], [0.5, 1.0], [1.0, 1.0]])
    grid = AttributeGrid.fit(values, 10)
    assert grid.width == 2 and grid.step[1] == 1.0  # constant column
    config = {"semantic": "TEXCOORD_0", **grid.get_config()}
    assert AttributeGrid.from_config(config) == grid
    q = grid.from_float32(values, "TEXCOORD_0")
    assert q.dtype == np.int64 and q.shape == (3, 2)
    assert np.array_equal(grid.from_float32(grid.to_float32(q), "TEXCOORD_0"), q)
    with pytest.raises(FormatError, match="TEXCOORD_0 values lie outside their 10-bit grid"):
        grid.from_float32(values + 5.0, "TEXCOORD_0")
    with pytest.raises(FormatError, match="2 origins and 1 steps"):
        AttributeGrid.from_config({**config, "step": [1.0]})
