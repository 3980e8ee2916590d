"""Triangle strips and fans are made progressive as the triangles they draw (glTF 2.0 3.7.2.1).

A primitive of mode TRIANGLE_STRIP (5) or TRIANGLE_FAN (6) was passed through whole, and an asset of
nothing else was refused: "the asset has no triangle primitive that can be made progressive (mode 5 is
not TRIANGLES)" (assimp's glTF-Asset-Generator Mesh_PrimitiveMode_04/05/11/12).  It is now the list of
triangles it draws, each wound as the spec's formula says, a strip's restarts dropped; the ``.pmw``
stores TRIANGLES.  The expected triangles here come from the spec's formula, not from the code under test.
"""

from __future__ import annotations

import types

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec.cli import main
from pmwm_codec.format.document import sniff_json

from test_hostile_inputs import gltf_doc, write_gltf

STRIP, FAN = 5, 6


def spec_triangles(order: np.ndarray, mode: int) -> list:
    """glTF 2.0 3.7.2.1, as written there: strip p_i = {v_i, v_i+(1+i%2), v_i+(2-i%2)}, fan p_i = {v_i+1, v_i+2, v_0}."""
    tris = []
    for i in range(len(order) - 2):
        if mode == STRIP:
            tris.append((order[i], order[i + 1 + i % 2], order[i + 2 - i % 2]))
        else:
            tris.append((order[i + 1], order[i + 2], order[0]))
    return [t for t in tris if len(set(t)) == 3]


def terrain_strips(rows: int = 24, cols: int = 24) -> tuple:
    """``(positions (rows*cols, 3) float64, order)``: a wavy height field drawn as one strip per row pair,
    joined by restarts (the last index of one strip and the first of the next repeated)."""
    y, x = np.mgrid[0:rows, 0:cols].astype(np.float64)
    z = 0.3 * np.sin(x / 3.0) * np.cos(y / 4.0)
    positions = np.stack([x.ravel(), y.ravel(), z.ravel()], 1)
    order = []
    for r in range(rows - 1):
        row = np.stack([np.arange(cols) + r * cols, np.arange(cols) + (r + 1) * cols], 1).ravel().tolist()
        if order:
            order += [order[-1], row[0]]
        order += row
    return positions, np.asarray(order, np.int64)


def dome_fan(ring: int = 120) -> tuple:
    """``(positions, order)``: a cone-shaped dome drawn as one closed fan around its apex."""
    t = np.linspace(0, 2 * np.pi, ring, endpoint=False)
    radius = 1.0 + 0.1 * np.sin(5 * t)
    positions = np.concatenate([[[0.0, 0.0, 1.0]], np.stack([radius * np.cos(t), radius * np.sin(t), 0 * t], 1)])
    return positions, np.asarray([0, *range(1, ring + 1), 1], np.int64)


def doc_of(positions: np.ndarray, order: np.ndarray, mode: int | None) -> dict:
    doc = gltf_doc(types.SimpleNamespace(positions=positions, faces=order, vertex_count=len(positions)))
    doc.pop("materials")
    prim = doc["meshes"][0]["primitives"][0]
    prim.pop("material")
    if mode is not None:
        prim["mode"] = mode
    return doc


def oriented(faces) -> set:
    """Each face (vertex ids) as its rotation starting at its smallest id: the same set for the same oriented triangles."""
    out = set()
    for f in np.asarray(faces).reshape(-1, 3).tolist():
        k = f.index(min(f))
        out.add(tuple(f[k:] + f[:k]))
    return out


def input_ids(decoded: np.ndarray, positions: np.ndarray) -> np.ndarray:
    """For each decoded vertex (on the file's grid) the input vertex it decodes (the nearest, within a grid step)."""
    d = np.linalg.norm(decoded[:, None, :] - positions[None, :, :], axis=2)
    ids = d.argmin(1)
    assert d[np.arange(len(decoded)), ids].max() < 1e-3 * np.ptp(positions, axis=0).max()
    return ids


@pytest.mark.parametrize("mode, shape", [(STRIP, terrain_strips), (FAN, dome_fan)])
def test_a_strip_or_fan_encodes_progressive_as_the_triangles_it_draws(capsys, tmp_path, mode, shape):
    positions, order = shape()
    expected = spec_triangles(order.tolist(), mode)
    src = write_gltf(tmp_path / "in", doc_of(positions, order, mode))
    out = tmp_path / "out.pmw"
    assert main(["encode", str(src), "-o", str(out), "-q", "--grid", "16"]) == 0, capsys.readouterr().err
    prim = sniff_json(out)["meshes"][0]["primitives"][0]
    assert prim.get("mode", 4) == 4 and "PMWM_progressive_mesh" in prim["extensions"]
    levels = list(pmwm_codec.iter_decode(out))
    assert len(levels) > 2, "the strip/fan must refine in vertex splits, not stay whole in the base"
    assert levels[0].vertices < len(positions)
    full = levels[-1].mesh
    assert full.face_count == len(expected)
    assert oriented(input_ids(full.positions, positions)[full.faces]) == oriented(expected)


def test_a_strip_and_its_triangle_list_encode_to_the_same_triangles(tmp_path):
    """The same terrain as a strip and as the TRIANGLES list the spec's formula gives: one mesh either way."""
    positions, order = terrain_strips(12, 12)
    listed = np.asarray(spec_triangles(order.tolist(), STRIP), np.int64).ravel()
    meshes = []
    for name, doc in (("strip", doc_of(positions, order, STRIP)), ("list", doc_of(positions, listed, None))):
        out = tmp_path / f"{name}.pmw"
        pmwm_codec.encode(write_gltf(tmp_path / name, doc), out, measure="none")
        meshes.append(list(pmwm_codec.iter_decode(out))[-1].mesh)
    assert oriented(input_ids(meshes[0].positions, positions)[meshes[0].faces]) == \
        oriented(input_ids(meshes[1].positions, positions)[meshes[1].faces])


def test_a_strip_counts_against_the_face_limit_as_the_triangles_it_draws():
    """The declared-size check before any buffer is read counted TRIANGLES only: a strip declaring a billion
    indices slipped past it.  A strip of k indices draws k - 2 triangles."""
    from pmwm_codec.constants import MAX_ENCODE_FACES
    from pmwm_codec.errors import InputFormatError
    from pmwm_codec.format.document import check_document

    positions, order = terrain_strips(4, 4)
    doc = doc_of(positions, order, STRIP)
    doc["accessors"][1]["count"] = MAX_ENCODE_FACES + 3
    doc["bufferViews"][1]["byteLength"] = 4 * (MAX_ENCODE_FACES + 3)
    doc["buffers"][0]["byteLength"] = doc["bufferViews"][1]["byteOffset"] + 4 * (MAX_ENCODE_FACES + 3)
    with pytest.raises(InputFormatError, match="encoder's limit"):
        check_document(doc, "m.gltf")
