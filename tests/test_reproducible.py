"""The encoder is deterministic: the same input, key and options give the same bytes.

Also pins the bytes of one small encode, so that an accidental change of the encoder's
output (format, chunking, watermark embedding, zstd framing) fails here by name.
"""

from __future__ import annotations

import copy
import hashlib
import io
import json

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.format import read_header
from pmwm_codec.mesh import Mesh
from pmwm_codec.stream.asset import encode_asset
from pmwm_codec.stream.encoder import PrimitiveJob, encode_document, encode_mesh
from pmwm_codec.watermark.key import WatermarkKey

from test_asset import DocBuilder

#: sha256 of the ``.pmw`` of :func:`_pinned_encode`.
PINNED_SHA256 = "17c56d4c82a07115c584c69c33bcc4dda62ca73e21307e9a02735f886dc13ab4"


def _key(seed: int = 3) -> WatermarkKey:
    return WatermarkKey.generate(rng=np.random.default_rng(seed))


def _image(size: int = 16, seed: int = 3) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (size, size)).astype(np.uint8)


def _mesh_bytes(mesh, **options) -> bytes:
    buf = io.BytesIO()
    encode_mesh(mesh, buf, measure=False, **options)
    return buf.getvalue()


def _with_normals() -> Mesh:
    m = shapes.icosphere(3, 1.0, noise=0.02)
    return Mesh(m.positions, m.faces, {"NORMAL": m.positions / np.linalg.norm(m.positions, axis=1, keepdims=True)})


def _asset() -> bytes:
    """A GLB: a sphere with NORMAL and TEXCOORD_0 and a torus, two materials."""
    b = DocBuilder()
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0, 1]}], "nodes": [{"mesh": 0}, {"mesh": 1, "translation": [3.0, 0, 0]}],
        "meshes": [{"primitives": [{**b.triangles(shapes.icosphere(3, 1.0, noise=0.02)), "material": 0}]},
                   {"primitives": [{**b.triangles(shapes.torus(30, 15)), "material": 1}]}],
        "materials": [{"name": "red"}, {"name": "blue"}],
    })
    return b.glb()


@pytest.mark.parametrize("case", ["plain", "draco", "watermark", "paper"])
def test_two_encodes_of_a_mesh_give_the_same_bytes(case):
    mesh = shapes.icosphere(3, 1.3, noise=0.02)
    options = {
        "plain": dict(base_codec="plain"),
        "draco": dict(base_codec="draco"),
        "watermark": dict(watermark=_image(), key=_key()),
        "paper": dict(watermark=_image(), key=_key(), mode="paper", bits=12),
    }[case]
    first = _mesh_bytes(mesh, **copy.deepcopy(options))
    second = _mesh_bytes(mesh, **copy.deepcopy(options))
    assert first == second


def test_two_encodes_of_a_gltf_asset_with_attributes_give_the_same_bytes(tmp_path):
    src = tmp_path / "scene.glb"
    src.write_bytes(_asset())
    outs = []
    for name in ("a.pmw", "b.pmw"):
        encode_asset(src, tmp_path / name, watermark=_image(), key=_key(), measure=False)
        outs.append((tmp_path / name).read_bytes())
    assert outs[0] == outs[1]
    header = read_header(outs[0])
    assert any("attributes" in ext for ext in header.extensions)


def test_two_encodes_of_a_document_with_two_primitives_give_the_same_bytes():
    doc = {"scene": 0, "scenes": [{"nodes": [0, 1]}], "nodes": [{"mesh": 0}, {"mesh": 1}],
           "meshes": [{"primitives": [{}]}, {"primitives": [{}]}]}
    outs = []
    for _ in range(2):
        buf = io.BytesIO()
        jobs = [PrimitiveJob(_with_normals(), 0, 0), PrimitiveJob(shapes.torus(30, 15), 1, 0)]
        encode_document(copy.deepcopy(doc), b"", jobs, buf, watermark=_image(), key=_key(), measure=False)
        outs.append(buf.getvalue())
    assert outs[0] == outs[1]


def test_the_file_id_depends_on_the_content_and_the_key():
    mesh = shapes.icosphere(2, 1.0, noise=0.02)

    def file_id(data):
        return read_header(data).extensions[0]["fileId"]

    plain = file_id(_mesh_bytes(mesh, base_codec="plain"))
    assert plain == file_id(_mesh_bytes(mesh, base_codec="plain"))
    assert plain != file_id(_mesh_bytes(shapes.icosphere(2, 1.0, noise=0.03), base_codec="plain"))
    marked = file_id(_mesh_bytes(mesh, base_codec="plain", watermark=_image(8), key=_key(1)))
    assert marked != file_id(_mesh_bytes(mesh, base_codec="plain", watermark=_image(8), key=_key(2)))


def test_the_encoder_does_not_modify_the_callers_key_or_document():
    key, image = _key(), _image(8)
    before = copy.deepcopy(key)
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}], "meshes": [{"primitives": [{}]}]}
    doc_before = json.dumps(doc, sort_keys=True)
    report = encode_document(doc, b"", [PrimitiveJob(shapes.icosphere(2))], io.BytesIO(),
                             watermark=image, key=key, measure=False)
    assert key == before and key.params == {} and key.reference is None and key.file_id is None
    assert json.dumps(doc, sort_keys=True) == doc_before
    assert report.key is not key and report.key.secret == key.secret
    assert np.array_equal(report.key.reference, image) and report.key.params and report.key.file_id


def _pinned_encode() -> bytes:
    """A small generated mesh, a fixed key and watermark, a plain base, the default zstd level."""
    return _mesh_bytes(shapes.icosphere(2, 1.0, noise=0.02), base_codec="plain",
                       watermark=_image(8, seed=1), key=_key(1))


def test_the_encoder_output_is_pinned():
    got = hashlib.sha256(_pinned_encode()).hexdigest()
    assert got == PINNED_SHA256, (
        f"the encoder's output changed (sha256 {got}, pinned {PINNED_SHA256}). If the change "
        "is intended (format, chunking, watermark embedding, or a new zstandard release), "
        f"set PINNED_SHA256 in tests/test_reproducible.py to {got!r} and say why in the commit; "
        "otherwise an encoder change altered the bytes by accident."
    )

