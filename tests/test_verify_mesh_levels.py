"""A mesh that is a level of the reference's stream verifies as that level.

A decode after fewer chunks (``pmw decode --chunks N``, a viewer's level), exported, has the vertices
of the stream's first N chunks and that level's faces: checked against the whole stream it read
``tampered`` with every vertex flagged, since its faces are not the full mesh's.  It is now matched to
the chunk boundary whose counts it has and read as ``verify`` reads the ``cut`` file of that level.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.verify import verify_mesh

from test_verify_mesh_assets import _encode_decode_flatten, _mark, _moved_and_reordered
from test_asset import two_mesh_asset
from test_obj_appearance import _png, _torus_obj


def marked_sphere(folder) -> tuple:
    """``(path of a marked .pmw of a 2,562-vertex sphere written in ``folder``, its key)``."""
    src = folder / "sphere.obj"
    pmwm_codec.write_mesh(src, shapes.icosphere(4, noise=0.02, seed=2))
    dst = folder / "sphere.pmw"
    pmwm_codec.encode(src, dst, watermark=_mark(), measure="none")
    return dst, pmwm_codec.load_key(folder / "sphere.pmw.key.json")


@pytest.fixture(scope="module")
def marked(tmp_path_factory):
    return marked_sphere(tmp_path_factory.mktemp("levels"))


def _levels(path) -> list:
    """The chunk counts short of the whole stream at which a decode has more vertices than the one before."""
    chunks = pmwm_codec.inspect(path)["chunks"]
    return [c["chunk"] for c in chunks[:-1]]


def test_every_level_a_decoder_shows_verifies_as_its_cut_file_does(marked, tmp_path):
    pmw, key = marked
    levels = _levels(pmw)
    assert len(levels) >= 3
    for n in [0] + levels[:: max(1, len(levels) // 4)]:
        mesh = pmwm_codec.decode(pmw, chunks=n)
        v = verify_mesh(mesh, pmw, key)
        cut = pmwm_codec.verify_stream(pmwm_codec.cut(pmw, chunks=n), key)
        assert v.level == n and v.chunks_total == len(levels) + 1
        assert v.correspondence == "identity" and v.coverage == 1.0
        assert (v.verdict, v.carriers_read) == (cut.verdict, cut.codes_read)
        assert v.reference_vertices == mesh.vertex_count
        assert len(v.flagged) == 0
    assert v.verdict == "authentic" and v.carriers_read > 0


def test_the_whole_mesh_is_checked_against_the_whole_stream(marked):
    pmw, key = marked
    v = verify_mesh(pmwm_codec.decode(pmw), pmw, key)
    assert v.level is None and v.verdict == "authentic" and v.carriers_read == v.carriers_total
    assert v.as_json()["level"] is None


def test_a_level_moved_reordered_and_saved_as_float32_verifies_as_that_level(marked):
    pmw, key = marked
    n = _levels(pmw)[len(_levels(pmw)) // 2]
    mesh = pmwm_codec.decode(pmw, chunks=n)
    positions, faces = _moved_and_reordered(mesh.positions, mesh.faces, seed=7)
    v = verify_mesh((positions.astype(np.float32).astype(np.float64), faces), pmw, key)
    assert (v.level, v.correspondence, v.verdict) == (n, "permutation", "authentic")


def test_an_edited_level_is_tampered_with_the_edit_flagged_not_every_vertex(marked):
    """The vertices the level's last chunk brought moved by a twentieth of an edge: ``tampered``, and the tamper map
    names vertices among them and their neighbours, not the whole mesh (a single vertex's 1-bit code may read
    the same after a move; these are many)."""
    pmw, key = marked
    chunks = pmwm_codec.inspect(pmw)["chunks"]
    n = chunks[-3]["chunk"]
    mesh = pmwm_codec.decode(pmw, chunks=n)
    positions = np.array(mesh.positions, np.float64)
    edges = np.linalg.norm(positions[mesh.faces[:, 0]] - positions[mesh.faces[:, 1]], axis=1).mean()
    new = np.arange(chunks[-4]["vertices"], mesh.vertex_count)
    positions[new] += 0.05 * edges
    v = verify_mesh((positions, mesh.faces), pmw, key)
    assert v.level == n and v.verdict == "tampered"
    near = np.isin(mesh.faces, new).any(axis=1)
    assert set(v.flagged.tolist()) <= set(mesh.faces[near].ravel().tolist())
    assert len(np.intersect1d(v.flagged, new)) > 0 and len(v.flagged) < mesh.vertex_count / 2


def test_a_level_of_a_two_primitive_asset_flattened_verifies_as_that_level(tmp_path):
    pmw, key, _ = _encode_decode_flatten(two_mesh_asset(tmp_path), tmp_path)
    levels = _levels(pmw)
    n = levels[len(levels) // 2]
    out = tmp_path / "level.glb"
    out.write_bytes(pmwm_codec.decode_asset(pmw, chunks=n))
    flat = pmwm_codec.read_mesh(out)  # node transforms applied, primitives concatenated
    v = verify_mesh(flat, pmw, key)
    assert (v.level, v.verdict) == (n, "authentic")
    cut = pmwm_codec.verify_stream(pmwm_codec.cut(pmw, chunks=n), key)
    assert v.carriers_read == cut.codes_read


def test_pmw_verify_names_the_level_in_its_text_and_json(marked, tmp_path, capsys):
    pmw, key = marked
    key_path = pmw.parent / "sphere.pmw.key.json"
    n = _levels(pmw)[1]
    level = tmp_path / "level.ply"
    pmwm_codec.write_mesh(level, pmwm_codec.decode(pmw, chunks=n))
    total = len(_levels(pmw)) + 1
    assert main(["verify", str(level), "--reference", str(pmw), "--key", str(key_path)]) == 0
    assert f"matched to the reference's level after {n} of {total} chunks by identity" in capsys.readouterr().out
    main(["verify", str(level), "--reference", str(pmw), "--key", str(key_path), "--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["level"] == {"chunks": n, "chunks_total": total} and out["verdict"] == "authentic"


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    """``(marked .pmw of a UV torus OBJ with a texture, its key, a level's chunk count, that level as the OBJ
    `pmw decode --chunks` writes: welded, one ``v`` per position, the seam copies one vertex)``."""
    folder = tmp_path_factory.mktemp("textured")
    path, *_ = _torus_obj(str(folder), rings=64)
    (folder / "t.mtl").write_text("newmtl skin\nmap_Kd t.png\n")
    _png(folder / "t.png")
    pmw = folder / "t.pmw"
    pmwm_codec.encode(path, pmw, watermark=_mark(), measure="none")
    n = _levels(pmw)[len(_levels(pmw)) // 2]
    out = folder / "level.obj"
    assert main(["decode", str(pmw), "--chunks", str(n), "-o", str(out), "-q"]) == 0
    return pmw, pmwm_codec.load_key(folder / "t.pmw.key.json"), n, pmwm_codec.read_mesh(out)


def test_a_level_of_a_textured_asset_written_as_an_obj_verifies_as_that_level(textured):
    """The OBJ welds the vertices the asset splits at its seams, so its vertex count is no chunk boundary's: it read
    ``tampered`` against the whole stream, every vertex flagged; it is that level, welded."""
    pmw, key, n, mesh = textured
    cut = pmwm_codec.verify_stream(pmwm_codec.cut(pmw, chunks=n), key)
    assert mesh.vertex_count < cut.results[-1].vertices  # welded
    v = verify_mesh(mesh, pmw, key)
    assert (v.level, v.correspondence, v.coverage, v.verdict) == (n, "identity", 1.0, "authentic")
    assert v.carriers_read == cut.codes_read > 0 and len(v.flagged) == 0
    positions, faces = _moved_and_reordered(mesh.positions, mesh.faces, seed=3)
    v = verify_mesh((positions.astype(np.float32).astype(np.float64), faces), pmw, key)
    assert (v.level, v.correspondence, v.verdict) == (n, "permutation", "authentic")
    stl = pmw.parent / "level.stl"  # a soup whose corners read welded
    assert main(["decode", str(pmw), "--chunks", str(n), "-o", str(stl), "-q"]) == 0
    v = verify_mesh(pmwm_codec.read_mesh(stl), pmw, key)
    assert (v.level, v.verdict, v.carriers_read) == (n, "authentic", cut.codes_read)


def test_an_edited_welded_level_is_tampered(textured):
    pmw, key, n, mesh = textured
    positions = np.array(mesh.positions, np.float64)
    edges = np.linalg.norm(positions[mesh.faces[:, 0]] - positions[mesh.faces[:, 1]], axis=1).mean()
    positions[-10:] += 0.05 * edges
    v = verify_mesh((positions, mesh.faces), pmw, key)
    assert v.level == n and v.verdict == "tampered" and 0 < len(v.flagged) < mesh.vertex_count / 2
