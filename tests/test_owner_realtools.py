"""The owner layer read back after the real gltf-transform and gltfpack (tools/owner_realtools.py), when installed."""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

from pmwm_codec import shapes

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "tools"))
import owner_realtools as R  # noqa: E402

CHOSEN = [p for p in R.PIPELINES if p[0].startswith(("gltf-transform quantize", "gltfpack (defaults", "gltfpack -cc"))]


@pytest.mark.skipif(not all(os.path.exists(R.TOOLS[t]) for t in ("gltf-transform", "gltfpack")),
                    reason="gltf-transform / gltfpack not installed (npm ci --prefix js; npm ci --prefix tools/js)")
def test_the_owner_layer_reads_present_after_gltf_transform_quantize_and_gltfpack_with_and_without_meshopt(tmp_path):
    m = shapes.icosphere(5, 1.0, noise=0.03, seed=3)
    src = tmp_path / "blob.obj"
    with open(src, "w") as fh:
        fh.writelines(f"v {x:.17g} {y:.17g} {z:.17g}\n" for x, y, z in m.positions * np.array([1.0, 0.7, 0.5]))
        fh.writelines(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in m.faces)
    result = R.measure(str(src), 1, lambda msg: None, CHOSEN)
    assert len(CHOSEN) == 3
    for name, _, _ in CHOSEN:
        row = result["rows"][name]
        assert row["failed"] is None, row["failed"]
        assert row["present"] == 1 and row["errors"][0] <= 6
        assert row["unmarked_reads"] == row["absent_unmarked"] == 1  # the unmarked mesh through the same tool
    md = R.render([result], 1, "python tools/owner_realtools.py", {"cpu": "x", "cores": 2, "python": "3", "numpy": "2",
                                                                  "git": "HEAD", "load": (0.0, 0.0, 0.0)}, CHOSEN)
    assert md.count("\n| ") == 1 + len(CHOSEN)  # the header and one row per pipeline
