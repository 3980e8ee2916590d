"""tools/probe_meshes.py reads back the OBJ files `pmw decode` writes, textured ones too."""

from __future__ import annotations

import numpy as np

from tools.probe_meshes import read_obj


def test_the_probe_reads_a_decoded_textured_obj_by_its_position_indices(tmp_path):
    path = tmp_path / "m.obj"
    path.write_text("o m\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\nvt 1 1\nvn 0 0 1\n"
                    "f 1/1 2/2 3/3\nf 2/2/1 4/4/1 3/3/1\n")
    positions, faces = read_obj(str(path))
    assert positions.shape == (4, 3)
    assert np.array_equal(faces, [[0, 1, 2], [1, 3, 2]])
