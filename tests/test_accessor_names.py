"""Accessor names of progressive primitives (outside probe 2, F8): the ``.pmw``'s base accessors and a
decoded level's accessors keep the input accessors' ``name`` (they were made fresh, without one)."""

from __future__ import annotations

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.format.document import load_document
from pmwm_codec.stream.asset import decode_asset, encode_asset

from test_asset import DocBuilder


def _named_asset(path):
    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    p = mesh.positions
    uv = np.stack([np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5, p[:, 2] / 2 + 0.5], 1)
    b = DocBuilder()

    def add(array, component, type_, target, name=None):
        index = b.accessor(array, component, type_, target, minmax=type_ == "VEC3" and component == 5126)
        if name:
            b.doc["accessors"][index]["name"] = name
        return index

    prim = {"attributes": {"POSITION": add(p.astype(np.float32), 5126, "VEC3", 34962, "ball positions"),
                           "NORMAL": add((p / np.linalg.norm(p, axis=1, keepdims=True)).astype(np.float32), 5126,
                                         "VEC3", 34962),
                           "TEXCOORD_0": add(uv.astype(np.float32), 5126, "VEC2", 34962, "uv1acc")},
            "indices": add(mesh.faces.astype(np.uint32).ravel(), 5125, "SCALAR", 34963, "ball indices")}
    b.doc.update(scene=0, scenes=[{"nodes": [0]}], nodes=[{"mesh": 0}], meshes=[{"primitives": [prim]}])
    path.write_bytes(b.glb())


def _names(path) -> dict:
    doc, _ = load_document(path)
    prim = doc["meshes"][0]["primitives"][0]
    used = {**prim["attributes"], "indices": prim["indices"]}
    return {what: doc["accessors"][i].get("name") for what, i in used.items()}


def test_the_pmw_and_every_decoded_level_keep_the_accessor_names(tmp_path):
    _named_asset(tmp_path / "in.glb")
    want = {"POSITION": "ball positions", "NORMAL": None, "TEXCOORD_0": "uv1acc", "indices": "ball indices"}
    assert _names(tmp_path / "in.glb") == want
    for codec in ("plain", "draco"):
        encode_asset(tmp_path / "in.glb", tmp_path / "out.pmw", base_codec=codec, measure=False)
        assert _names(tmp_path / "out.pmw") == want, codec
        for chunks in (0, None):
            glb, _, _ = decode_asset(tmp_path / "out.pmw", chunks)
            (tmp_path / "dec.glb").write_bytes(glb)
            assert _names(tmp_path / "dec.glb") == want, (codec, chunks)
