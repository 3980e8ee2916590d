"""The frame a ``.pmw`` states for its owner layer (``ownerFrame``, spec README; spec/watermark.md §7): the
encoder writes the frame its mark reads in from the full decode, and a read of a stream's level takes it in
place of the level's own estimate, which on a coarse level lies up to a shell width off."""

from __future__ import annotations

import io

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec.constants import EXTENSION_NAME
from pmwm_codec.errors import FormatError
from pmwm_codec.format.glb import glb_parts, split_glb
from pmwm_codec.shapes import icosphere
from pmwm_codec.stream import StreamDecoder
from pmwm_codec.verify import owner as verify_owner
from pmwm_codec.verify.owner import owner_of_stream
from pmwm_codec.watermark import owner
from pmwm_codec.watermark.key import WatermarkKey


@pytest.fixture(scope="module")
def marked():
    """``(mesh, key, .pmw bytes)``: a noisy sphere of 10,242 vertices with the owner layer alone (its levels'
    own estimates lie far from the full mesh's frame until most of the stream has come)."""
    mesh = icosphere(5, noise=0.02, seed=1)
    key = WatermarkKey.generate(rng=np.random.default_rng(0))
    buf = io.BytesIO()
    pmwm_codec.encode(mesh, buf, key=key, owner_id=key.owner_id)
    return mesh, key, buf.getvalue()


def _extension(data: bytes) -> dict:
    gltf, _ = split_glb(data)
    return gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]


def _rewrite(data: bytes, change) -> bytes:
    gltf, binary = split_glb(data)
    change(gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME])
    return b"".join(glb_parts(gltf, [binary], len(binary)))


def _first_present(boundaries: list) -> int:
    """The first boundary from which on every one reads ``present`` (len(boundaries): none)."""
    first = len(boundaries)
    while first > 0 and boundaries[first - 1].owner.verdict == "present":
        first -= 1
    return first


def test_the_file_states_the_frame_its_mark_reads_in_without_an_error(marked):
    _, key, data = marked
    stated = owner.frame_of_json(_extension(data)["ownerFrame"])
    full = pmwm_codec.decode(data)
    points, faces = owner.distinct_mesh(full.positions, full.faces)
    s, mass = owner._frame_scores(points, stated)
    assert owner._bit_errors(owner._soft_rows((s[None], mass[None]), key)[0], key) == 0
    again = owner.stated_frame(full.positions, full.faces, key)  # (the decode's float32 positions: not exactly)
    assert np.allclose(np.r_[again[0], again[1:]], np.r_[stated[0], stated[1:]], rtol=1e-6, atol=0)
    assert owner.frame_json(stated) == _extension(data)["ownerFrame"]  # JSON numbers read back exactly


def test_a_file_without_the_owner_layer_states_no_frame():
    buf = io.BytesIO()
    pmwm_codec.encode(icosphere(3), buf)
    assert "ownerFrame" not in _extension(buf.getvalue())


def test_the_levels_of_a_stream_read_the_mark_from_far_fewer_vertices_in_the_stated_frame(marked, monkeypatch):
    _, key, data = marked
    stated = owner_of_stream(data, key, every=True)
    monkeypatch.setattr(verify_owner, "_stated_frame", lambda gltf: None)  # each level in its own estimate
    estimated = owner_of_stream(data, key, every=True)
    assert [b.vertices for b in stated] == [b.vertices for b in estimated]
    a, b = _first_present(stated), _first_present(estimated)
    assert a < len(stated) and b < len(estimated)
    assert 2 * stated[a].vertices < estimated[b].vertices
    assert stated[-1].owner.bit_errors == 0


def test_a_cut_file_keeps_the_stated_frame_and_reads_present_where_the_whole_file_does(marked):
    _, key, data = marked
    k = _first_present(owner_of_stream(data, key, every=True))
    cut = pmwm_codec.cut(data, chunks=k)
    assert _extension(cut)["ownerFrame"] == _extension(data)["ownerFrame"]
    assert owner_of_stream(cut, key)[-1].owner.verdict == "present"


@pytest.mark.parametrize("shift", [(5.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.5), (0.0, 0.0, 0.0, 7.3)])
def test_a_stated_frame_changed_by_hand_leaves_the_full_stream_present(marked, shift):
    """A frame that does not read (moved by whole or half shells) costs the coarse levels their early read,
    not the verdict on the full stream: its un-smoothed views are read in their own estimates."""
    _, key, data = marked

    def change(ext):
        frame = ext["ownerFrame"]
        frame["center"] = [c + d * frame["width"] for c, d in zip(frame["center"], shift[:3])]
        frame["inner"] += shift[3] * frame["width"]

    boundaries = owner_of_stream(_rewrite(data, change), key)
    assert boundaries[-1].owner.verdict == "present"


def test_no_wrong_key_reads_a_level_present_in_the_stated_frame(marked):
    """The stated frame depends on the mesh, not on a key's mappings: wrong keys read fair coins in it at every
    level (the bound of :func:`~pmwm_codec.watermark.owner.false_alarm_probability` is unchanged)."""
    _, key, data = marked
    stated = owner.frame_of_json(_extension(data)["ownerFrame"])
    wrong = [WatermarkKey.generate(rng=np.random.default_rng(100 + i)) for i in range(40)]
    errors = []
    for r in pmwm_codec.iter_decode(data):
        points, faces = owner.distinct_mesh(r.mesh.positions, r.mesh.faces)
        if len(points) < 1000:
            continue
        scores = owner.mesh_scores(points, faces, stated)  # the views do not depend on the key
        for k in wrong:
            read = owner.detect(points, faces, k, scores=scores)
            assert read.verdict != "present"
            errors.append(read.bit_errors)
    assert len(errors) >= 5 * len(wrong)
    assert 20 < np.mean(errors) < 32  # about half of 64 bits, the best of 192 codings a little lower


@pytest.mark.parametrize("value, what", [
    ({"center": [0.0, 0.0], "inner": 1.0, "width": 0.1}, "center"),
    ({"center": [0.0, 0.0, 0.0], "inner": 1.0, "width": 0.0}, "width"),
    ({"center": [0.0, 0.0, 0.0], "inner": "1", "width": 0.1}, "inner"),
    ({"center": [0.0, 0.0, 0.0], "width": 0.1}, "inner"),
    ([0.0, 0.0, 0.0, 1.0, 0.1], "ownerFrame"),
])
def test_a_malformed_stated_frame_is_a_format_error(marked, value, what):
    _, _, data = marked

    def change(ext):
        ext["ownerFrame"] = value

    dec = StreamDecoder()
    with pytest.raises(FormatError, match=what):
        dec.feed(_rewrite(data, change))
        dec.close()


def test_a_stated_frame_of_absurd_numbers_costs_that_view_only_without_a_word_on_stderr(marked, recwarn):
    """Any finite numbers pass the schema; norms from a centre at 1e308 overflow, and the read treated them as
    shells of garbage with numpy's RuntimeWarnings on stderr.  Now every point is outside that view's shells."""
    _, key, data = marked

    def change(ext):
        ext["ownerFrame"] = {"center": [1e308, -1e308, 0.0], "inner": 1e308, "width": 1e-320}

    assert owner_of_stream(_rewrite(data, change), key)[-1].owner.verdict == "present"
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]
