"""A ``data:`` URI or file a ``.gltf`` names must hold what it claims (security review, audit-sec).

A base64 data URI with characters outside the base64 alphabet used to decode by dropping them
(``base64.b64decode`` without ``validate``): ``data:image/png;base64,@@@@`` became an empty image,
encoded with exit 0 into a zero-length bufferView (glTF requires ``byteLength >= 1``), and ``pmw
decode -o x.obj`` then wrote a 0-byte ``x_0.png``.  Such a URI, and any resource of no bytes, is
refused by name (exit 2, one line, nothing written); base64 broken by white space still decodes.
"""

from __future__ import annotations

import base64

import pytest

from pmwm_codec import shapes

from test_gltf_input_refusals import encoded, refused
from test_hostile_inputs import TINY_PNG, gltf_doc


@pytest.fixture
def mesh():
    return shapes.icosphere(1)


@pytest.mark.parametrize("payload", ["@@@@", base64.b64encode(TINY_PNG).decode()[:8] + "!*" +
                                     base64.b64encode(TINY_PNG).decode()[8:], "A"])
def test_a_base64_data_uri_with_bytes_outside_the_alphabet_is_refused(capsys, tmp_path, mesh, payload):
    doc = gltf_doc(mesh, images=["data:image/png;base64," + payload])
    refused(capsys, tmp_path, doc, "data URI", "does not decode")


@pytest.mark.parametrize("how", ["data URI", "file"])
def test_an_image_of_no_bytes_is_refused_not_written_as_an_empty_buffer_view(capsys, tmp_path, mesh, how):
    uri = {"data URI": "data:image/png;base64,", "file": "empty.png"}[how]
    doc = gltf_doc(mesh, images=[uri])
    doc["images"][0]["mimeType"] = "image/png"
    refused(capsys, tmp_path, doc, "no bytes", files={"empty.png": b""})


def test_base64_broken_over_lines_still_decodes(capsys, tmp_path, mesh):
    text = base64.b64encode(TINY_PNG).decode()
    doc = gltf_doc(mesh, images=["data:image/png;base64," + text[:12] + "\n" + text[12:]])
    gltf = encoded(capsys, tmp_path, doc)
    assert [image["mimeType"] for image in gltf["images"]] == ["image/png"]
