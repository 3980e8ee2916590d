"""Decoding a ``.pmw`` to an OBJ or PLY that keeps its appearance needs not much more memory than decoding it to
GLB: the decoder's state of the level and the decoded GLB's bytes are let go once the scene is read from them."""

from __future__ import annotations

import tracemalloc

import pytest

import pmwm_codec
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
