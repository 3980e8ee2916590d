"""A decoded asset's vertex colours keep their alpha where the output format holds one: an OFF's ``COFF`` records
(``r g b a``) carry COLOR_0's alpha (they had been written ``1`` whatever it was, a translucent mesh shown opaque), a
PLY's ``alpha``; an OBJ's ``v x y z r g b`` cannot, and the decode says so rather than drop it without a word.
"""

from __future__ import annotations

import numpy as np

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.format.document import load_document, read_accessor

from test_ply_appearance import corners, ply_bytes, xyz


def _translucent(tmp_path):
    """``.pmw`` of a sphere PLY with RGBA colours whose alpha varies over the surface (some opaque)."""
    mesh = shapes.icosphere(2)
    p = mesh.positions
    rgba = np.concatenate([np.rint((p - p.min(0)) / np.ptp(p, 0) * 255),
                           np.rint(np.clip(p[:, 2:] + 1.0, 0.0, 1.0) * 255)], 1).astype(np.uint8)
    vertex = xyz(p) + [(c, "uchar", rgba[:, k]) for k, c in enumerate(("red", "green", "blue", "alpha"))]
    (tmp_path / "s.ply").write_bytes(ply_bytes("binary_little_endian", vertex, corners(mesh.faces)))
    pmwm_codec.encode(str(tmp_path / "s.ply"), str(tmp_path / "s.pmw"))
    return tmp_path / "s.pmw"


def _glb_corners(pmw, tmp_path) -> np.ndarray:
    """(3m, 7) float64: each decoded corner's position and linear RGBA, of the one primitive."""
    (tmp_path / "ref.glb").write_bytes(pmwm_codec.decode_asset(str(pmw)))
    gltf, buffers = load_document(str(tmp_path / "ref.glb"))
    (prim,) = gltf["meshes"][0]["primitives"]
    faces = read_accessor(gltf, buffers, prim["indices"]).reshape(-1)
    colour = read_accessor(gltf, buffers, prim["attributes"]["COLOR_0"]).astype(np.float64)
    assert colour.shape[1] == 4
    pos = read_accessor(gltf, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
    return np.hstack([pos[faces], colour[faces]])


def _sorted(rows):
    tri = rows.reshape(-1, 3 * rows.shape[1])
    return tri[np.lexsort(tri.T[::-1])].reshape(-1, rows.shape[1])


def test_an_off_holds_each_vertex_colour_s_alpha(tmp_path):
    src = _translucent(tmp_path)
    want = _glb_corners(src, tmp_path)
    assert want[:, 6].min() < 0.2 and want[:, 6].max() == 1.0  # translucent and opaque vertices both
    out = tmp_path / "back.off"
    result = pmwm_codec.decode_to(str(src), str(out))
    lines = out.read_text().splitlines()
    assert lines[0] == "COFF"
    nv, nf, _ = map(int, lines[1].split())
    table = np.array([line.split() for line in lines[2:2 + nv]], np.float64)
    faces = np.array([line.split() for line in lines[2 + nv:2 + nv + nf]], np.int64)
    assert table.shape[1] == 7 and (faces[:, 0] == 3).all()
    got = table[faces[:, 1:].reshape(-1)]
    got[:, :3] = got[:, :3].astype(np.float32)  # 9 digits: each float32 back
    got, want = _sorted(got), _sorted(want)
    assert np.array_equal(got[:, :3], want[:, :3])  # positions exact, faces and winding kept
    assert np.abs(got[:, 6] - want[:, 6]).max() <= 5e-7 + 1e-9  # the alpha, six decimals
    assert not any("alpha" in n for n in result["notices"])


def test_a_ply_holds_the_alpha_and_an_obj_says_it_leaves_it_out(tmp_path):
    src = _translucent(tmp_path)
    assert not any("alpha" in n for n in pmwm_codec.decode_to(str(src), str(tmp_path / "b.ply"))["notices"])
    notices = pmwm_codec.decode_to(str(src), str(tmp_path / "b.obj"))["notices"]
    assert any("the vertex colours' alpha is left out" in n for n in notices), notices
    # an opaque asset's OBJ has nothing left out
    mesh = shapes.icosphere(2)
    vertex = xyz(mesh.positions) + [(c, "uchar", np.full(len(mesh.positions), 90)) for c in ("red", "green", "blue")]
    (tmp_path / "o.ply").write_bytes(ply_bytes("binary_little_endian", vertex, corners(mesh.faces)))
    pmwm_codec.encode(str(tmp_path / "o.ply"), str(tmp_path / "o.pmw"))
    assert not any("alpha" in n for n in pmwm_codec.decode_to(str(tmp_path / "o.pmw"), str(tmp_path / "o.obj"))["notices"])


def _masked(tmp_path, alpha: float, cutoff=None):
    """``.pmw`` of the textured torus OBJ with its material made ``alphaMode: MASK`` of base colour alpha ``alpha``."""
    from pmwm_codec import meshdoc

    from test_obj_appearance import _png, _torus_obj

    path, *_ = _torus_obj(str(tmp_path))
    _png(tmp_path / "skin.png")
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\n")
    (doc, buffers), _ = meshdoc.read_source(path)
    material = doc["materials"][0]
    material["alphaMode"] = "MASK"
    material["pbrMetallicRoughness"]["baseColorFactor"] = [1.0, 1.0, 1.0, alpha]
    if cutoff is not None:
        material["alphaCutoff"] = cutoff
    src = tmp_path / f"mask{alpha}.pmw"
    pmwm_codec.encode((doc, buffers), str(src))
    return src


def _mtl_opacity(path) -> float:
    (value,) = [float(line.split()[1]) for line in path.read_text().splitlines() if line.startswith("d ")]
    return value


def test_a_masked_material_is_opaque_where_drawn_and_absent_where_cut_not_translucent(tmp_path):
    """glTF draws an ``alphaMode: MASK`` material opaque where its alpha reaches ``alphaCutoff`` (0.5 by default)
    and not at all below: its MTL ``d`` is 1 or 0 (``d 0.8`` had shown it 80 % translucent in three.js and Blender),
    and the texture's alpha, which would cut it out, is said to be left out."""
    result = pmwm_codec.decode_to(str(_masked(tmp_path, 0.8)), str(tmp_path / "kept.obj"))
    assert _mtl_opacity(tmp_path / "kept.mtl") == 1.0
    assert any("alpha mask (alphaMode MASK) is left out" in n for n in result["notices"]), result["notices"]
    result = pmwm_codec.decode_to(str(_masked(tmp_path, 0.8, cutoff=0.9)), str(tmp_path / "cut.obj"))
    assert _mtl_opacity(tmp_path / "cut.mtl") == 0.0
    assert not any("alpha mask" in n for n in result["notices"])
