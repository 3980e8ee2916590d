"""What a glTF viewer shows of a marked file is what ``pmw verify`` checked: constructs a viewer reads
differently from the readers of this extension, outside the MACs (the base accessors are ``null`` in the
``sceneMac``'s document, bufferViews are not in it at all), are refused by the reader, so that no edit of
them, made without the key, verifies ``authentic`` (spec README, *Base mesh*)."""

from __future__ import annotations

import numpy as np
import pytest

from pmwm_codec.cli import main
from pmwm_codec.format.glb import glb_parts, split_glb

from conftest import marked_sphere


@pytest.fixture(scope="module")
def plain():
    """A marked icosphere with a plain base: ``(pmw bytes, key)``."""
    data, key, _ = marked_sphere(5, base_codec="plain")
    return data, key


def _rewrite(data: bytes, change) -> bytes:
    gltf, binary = split_glb(data)
    binary = bytearray(binary)
    change(gltf, binary)
    gltf["buffers"][0]["byteLength"] = len(binary)
    return b"".join(glb_parts(gltf, [bytes(binary)], len(binary)))


def _append_view(gltf, binary, raw: bytes) -> int:
    binary += bytes(-len(binary) % 4)
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary), "byteLength": len(raw)})
    binary += raw
    return len(gltf["bufferViews"]) - 1


def _verify(capsys, tmp_path, data: bytes, key) -> tuple:
    path, key_path = tmp_path / "x.pmw", tmp_path / "x.key.json"
    path.write_bytes(data)
    key.save(key_path)
    capsys.readouterr()
    status = main(["verify", str(path), "--key", str(key_path)])
    captured = capsys.readouterr()
    return status, captured.out + captured.err


def _position_accessor(gltf) -> dict:
    return gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]


def test_the_plain_file_itself_is_authentic(capsys, tmp_path, plain):
    status, out = _verify(capsys, tmp_path, *plain)
    assert status == 0 and "authentic" in out


def _sparse_positions(gltf, binary):
    """Every other base vertex moved to (0, 30, 0) by a sparse substitution, which every glTF viewer applies."""
    acc = _position_accessor(gltf)
    idx = np.arange(0, acc["count"], 2, dtype="<u2")
    values = np.tile(np.array([[0, 30, 0]], "<f4"), (len(idx), 1))
    acc["sparse"] = {"count": len(idx), "indices": {"bufferView": _append_view(gltf, binary, idx.tobytes()),
                                                    "componentType": 5123},
                     "values": {"bufferView": _append_view(gltf, binary, values.tobytes())}}


def _sparse_indices(gltf, binary):
    """The base's first triangle rewired by a sparse substitution of its indices."""
    acc = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["indices"]]
    dtype = "<u2" if acc["componentType"] == 5123 else "<u4"
    acc["sparse"] = {"count": 1, "indices": {"bufferView": _append_view(gltf, binary, np.array([0], "<u2").tobytes()),
                                             "componentType": 5123},
                     "values": {"bufferView": _append_view(gltf, binary, np.array([7], dtype).tobytes())}}


def _meshopt_position_view(gltf, binary):
    """EXT_meshopt_compression on the base POSITION's bufferView, its stream elsewhere in the buffer (three.js decodes
    it, once a viewer set a meshopt decoder, even without the extension in extensionsUsed); the view's own bytes, the
    key holder's, left as they are."""
    acc = _position_accessor(gltf)
    view = gltf["bufferViews"][acc["bufferView"]]
    stream = _append_view(gltf, binary, b"\xa0" + bytes(40))
    at = gltf["bufferViews"].pop(stream)
    view["extensions"] = {"EXT_meshopt_compression": {"buffer": 0, "byteOffset": at["byteOffset"], "byteLength": at["byteLength"],
                                                      "byteStride": 12, "count": acc["count"], "mode": "ATTRIBUTES"}}


def _meshopt_other_view(gltf, binary):
    """The same on a bufferView that no accessor or image uses (the chunks' own view)."""
    gltf["bufferViews"][-1]["extensions"] = {"KHR_meshopt_compression": {"buffer": 0, "byteLength": 4, "byteStride": 4,
                                                                         "count": 1, "mode": "ATTRIBUTES"}}


def _far_bounds(gltf, binary):
    """POSITION min / max moved far off: three.js takes the bounding sphere from them and culls the mesh."""
    acc = _position_accessor(gltf)
    acc["min"], acc["max"] = [1000.0, 1000.0, 1000.0], [1000.001, 1000.001, 1000.001]


def _bounds_one_off(gltf, binary):
    acc = _position_accessor(gltf)
    acc["max"] = [acc["max"][0] * 2, *acc["max"][1:]]


@pytest.mark.parametrize("edit, words", [
    (_sparse_positions, "sparse"), (_sparse_indices, "sparse"),  # a sparse substitution on a base accessor
    (_meshopt_position_view, "meshopt_compression"), (_meshopt_other_view, "meshopt_compression"),  # a view's extension
    (_far_bounds, "is not the bound of its values"), (_bounds_one_off, "is not the bound of its values"),  # min / max
])
def test_what_a_viewer_would_show_otherwise_than_the_readers_is_refused_not_authentic(capsys, tmp_path, plain, edit,
                                                                                      words):
    """A sparse base accessor, an extension on a bufferView and POSITION bounds other than the stored positions'
    change what a glTF viewer shows, outside every MAC: the readers refuse them (exit 2), never ``authentic``."""
    data, key = plain
    status, out = _verify(capsys, tmp_path, _rewrite(data, edit), key)
    assert status == 2 and words in out and "authentic" not in out


def test_position_bounds_of_a_draco_base_are_checked_too(capsys, tmp_path):
    data, key, _ = marked_sphere(6)
    gltf, _ = split_glb(data)
    assert "bufferView" not in _position_accessor(gltf)  # a Draco base
    status, out = _verify(capsys, tmp_path, _rewrite(data, _far_bounds), key)
    assert status == 2 and "is not the bound of its values" in out


@pytest.mark.parametrize("value", [1e39, -3.5e38, 1e308])
def test_a_position_bound_past_float32_is_refused_in_one_line_without_a_warning(capsys, tmp_path, plain, recwarn,
                                                                                 value):
    """A hand-edited POSITION ``min`` of 1e39 was refused (exit 2) after numpy's ``RuntimeWarning: overflow
    encountered in cast`` and its source line (pmw info, decode, verify: three lines on stderr where the rule is
    one); tests/test_fuzz.py::test_crafted_json met it too."""
    data, key = plain

    def edit(gltf, binary):
        _position_accessor(gltf)["min"][0] = value

    status, out = _verify(capsys, tmp_path, _rewrite(data, edit), key)
    assert status == 2 and "is not the bound of its values" in out
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def _huge_integer_bound(gltf, binary):
    _position_accessor(gltf)["min"][0] = 10**400


def _huge_integer_frame(gltf, binary):
    ext = gltf["meshes"][0]["primitives"][0]["extensions"]["PMWM_progressive_mesh"]
    ext["ownerFrame"] = {"center": [0, 0, -10**400], "inner": 0, "width": 1}


@pytest.mark.parametrize("edit, member", [(_huge_integer_bound, "min[0]"), (_huge_integer_frame, "center[2]")])
def test_an_integer_past_a_doubles_range_is_refused_naming_it_as_the_javascript_reader_does(capsys, tmp_path, plain,
                                                                                            edit, member):
    """A JSON integer literal of 401 digits is Infinity to every reader of doubles (the JavaScript reader refuses
    it: "holds a number that is not finite"); Python's JSON reader keeps it an int, and pmw info / verify ended in
    "unexpected OverflowError: int too large to convert to float (a bug of pmw ...)" for a POSITION min, pmw verify
    alone for an ownerFrame (info and decode took it)."""
    data, key = plain
    status, out = _verify(capsys, tmp_path, _rewrite(data, edit), key)
    assert status == 2 and member in out and "which JSON does not allow" in out and "unexpected" not in out
