"""Decoding a ``.pmw`` to an OBJ or PLY that keeps its appearance needs not much more memory than decoding it to
GLB: the decoder's state of the level and the decoded GLB's bytes are let go once the scene is read from them, and
an OBJ's (an OFF's) faces are made a block of records at a time."""

from __future__ import annotations

import tracemalloc

import pytest

import pmwm_codec
from pmwm_codec import meshio
from pmwm_codec.meshdoc import Part
from pmwm_codec.meshexport import Scene, Showing, write_scene
from pmwm_codec.stream.export import decode_to
from tools.bench_textmesh import torus, write_obj


@pytest.fixture(scope="module")
def torus_pmw(tmp_path_factory):
    """A ``.pmw`` of a 20,000-vertex torus with normals and texture coordinates."""
    folder = tmp_path_factory.mktemp("torus")
    write_obj(str(folder / "torus.obj"), *torus(20_000))
    pmwm_codec.encode(str(folder / "torus.obj"), str(folder / "torus.pmw"))
    return folder / "torus.pmw"


def _peak(src, dst) -> int:
    """The most memory Python held while ``decode_to`` wrote ``dst`` (tracemalloc: numpy's arrays count)."""
    tracemalloc.start()
    try:
        decode_to(str(src), str(dst))
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def test_a_decode_to_ply_holds_not_much_more_than_a_decode_to_glb(torus_pmw, tmp_path):
    """The PLY's peak was ~1.3x the GLB's (741 against 574 MB resident for a 1M-vertex torus): the scene's
    arrays and the file's records were made while the decoder's replay state and the GLB's bytes were held.
    (An OBJ of so small a mesh is one block of :func:`~pmwm_codec.meshio.text_rows`' text: not measured here.)"""
    decode_to(str(torus_pmw), str(tmp_path / "warm.glb"))  # what a first decode loads once is not counted
    glb = _peak(torus_pmw, tmp_path / "out.glb")
    assert _peak(torus_pmw, tmp_path / "out.ply") < 1.1 * glb


@pytest.mark.parametrize("suffix", [".obj", ".off"])
def test_an_obj_or_off_of_a_scene_holds_not_much_more_than_its_ply(tmp_path, monkeypatch, suffix):
    """The OBJ writer held an (m, 3) int64 array of its faces' rows per form (position, texture coordinate, normal)
    beside the welded map's own (2.1x the PLY's peak for a torus with normals and texture coordinates; 923 MB
    resident decoding a 1M-vertex torus to OBJ, against 570 MB to PLY), the OFF writer one more; the corners are
    looked up a block of records at a time now.  Small blocks of text, so that the text is not what is measured."""
    monkeypatch.setattr(meshio, "TEXT_ROWS_BLOCK", 1024)
    positions, normals, uv, triangles = torus(50_000)
    scene = Scene([Showing("torus", [Part(positions, triangles, {"NORMAL": normals, "TEXCOORD_0": uv}, None)])],
                  [], [], [])
    ply = _written_peak(scene, tmp_path / "out.ply")
    assert _written_peak(scene, tmp_path / f"out{suffix}") < 1.3 * ply


def _written_peak(scene, path) -> int:
    """The most memory Python held while ``write_scene`` wrote ``scene`` to ``path`` (tracemalloc)."""
    tracemalloc.start()
    try:
        write_scene(str(path), scene)
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
