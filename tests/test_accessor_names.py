"""Accessor names of progressive primitives (outside probe 2, F8): the ``.pmw``'s base accessors and a
decoded level's accessors keep the input accessors' ``name`` (they were made fresh, without one)."""

from __future__ import annotations

import numpy as np

from pmwm_codec import shapes
from pmwm_codec.format.document import load_document
from pmwm_codec.format.glb import glb_parts
from pmwm_codec.format.layout import padded
from pmwm_codec.stream.asset import decode_asset, encode_asset


def _named_asset(path):
    mesh = shapes.icosphere(3, 1.0, noise=0.02)
    p = mesh.positions
    uv = np.stack([np.arctan2(p[:, 1], p[:, 0]) / (2 * np.pi) + 0.5, p[:, 2] / 2 + 0.5], 1)
    views, accessors, parts = [], [], []

    def add(array, component, type_, target, name=None):
        raw = np.ascontiguousarray(array).tobytes()
        views.append({"buffer": 0, "byteOffset": sum(len(x) for x in parts), "byteLength": len(raw), "target": target})
        parts.append(raw + bytes(padded(len(raw)) - len(raw)))
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": len(array), "type": type_}
        if type_ == "VEC3" and component == 5126:
            acc.update(min=array.min(0).tolist(), max=array.max(0).tolist())
        if name:
            acc["name"] = name
        accessors.append(acc)
        return len(accessors) - 1

    prim = {"attributes": {"POSITION": add(p.astype(np.float32), 5126, "VEC3", 34962, "ball positions"),
                           "NORMAL": add((p / np.linalg.norm(p, axis=1, keepdims=True)).astype(np.float32), 5126,
                                         "VEC3", 34962),
                           "TEXCOORD_0": add(uv.astype(np.float32), 5126, "VEC2", 34962, "uv1acc")},
            "indices": add(mesh.faces.astype(np.uint32).ravel(), 5125, "SCALAR", 34963, "ball indices")}
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [prim]}], "accessors": accessors, "bufferViews": views}
    length = sum(len(x) for x in parts)
    doc["buffers"] = [{"byteLength": length}]
    path.write_bytes(b"".join(glb_parts(doc, parts, length)))


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
