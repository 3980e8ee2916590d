"""Skins and animations the Khronos glTF validator calls errors are refused by name, not copied through.

``pmw encode`` copies a document's skins and animations into the ``.pmw`` (and ``decode`` into the asset it
writes) as they are, so an invalid one came out as invalid as it went in, without a word: inverse bind matrices
fewer than the joints (INVALID_IBM_ACCESSOR_COUNT), a ``weights`` channel on a mesh without morph targets
(ANIMATION_CHANNEL_TARGET_NODE_WEIGHTS_NO_MORPHS), an output holding another number of values than its
keyframes (ANIMATION_SAMPLER_OUTPUT_ACCESSOR_INVALID_COUNT) ...  Each is now one ``pmw: error:`` line naming
it, exit 2, nothing written (:func:`pmwm_codec.format.document.check_document`, which encode and decode both
run); a valid rigged, animated asset still encodes, its skins and animations kept.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.errors import FormatError, InputFormatError
from pmwm_codec.format.document import sniff_json
from pmwm_codec.stream.asset import decode_asset, encode_asset

from test_asset import DocBuilder
from test_hostile_inputs import assert_refused, run_encode

FLOAT, UNSIGNED_BYTE, UNSIGNED_SHORT = 5126, 5121, 5123
DTYPES = {FLOAT: np.float32, UNSIGNED_BYTE: np.uint8, UNSIGNED_SHORT: np.uint16}


def rigged(morph_targets: int = 0) -> DocBuilder:
    """A sphere skinned to joints j0 (root) > j1, j2, animated LINEAR (rotation of j1), STEP (translation of j2)
    and CUBICSPLINE (scale of j0) over 3 keyframes; beside it, node 4 draws a small plain mesh with
    ``morph_targets`` morph targets (and then a LINEAR and a CUBICSPLINE ``weights`` animation of them).
    Valid: the glTF validator reports no error on it."""
    b = DocBuilder()
    sphere = shapes.icosphere(2, 1.0, noise=0.02, seed=4)
    t = ((sphere.positions[:, 2] + 1) / 2).clip(0, 1)
    joints = np.zeros((sphere.vertex_count, 4), np.uint8)
    joints[:, 1] = 1 + (t > 0.5)
    weights = np.zeros((sphere.vertex_count, 4), np.float32)
    weights[:, 1] = t
    weights[:, 0] = (1 - weights[:, 1].astype(np.float64)).astype(np.float32)
    prim = b.triangles(sphere)
    prim["attributes"].update(JOINTS_0=b.accessor(joints, UNSIGNED_BYTE, "VEC4", 34962),
                              WEIGHTS_0=b.accessor(weights, FLOAT, "VEC4", 34962))
    ibm = b.accessor(np.tile(np.eye(4, dtype=np.float32).ravel(), (3, 1)), FLOAT, "MAT4")
    ball = shapes.icosphere(1, 0.3)
    plain = b.triangles(ball)
    if morph_targets:
        plain["targets"] = [{"POSITION": b.accessor((ball.positions * 0.1 * (k + 1)).astype(np.float32), FLOAT,
                                                    "VEC3", 34962, True)} for k in range(morph_targets)]
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0, 1, 4]}],
        "nodes": [{"mesh": 0, "skin": 0}, {"name": "j0", "children": [2, 3]},
                  {"name": "j1", "translation": [0, 0, 1.0]}, {"name": "j2", "translation": [0, 0, -1.0]},
                  {"name": "plain", "mesh": 1, "translation": [3, 0, 0]}],
        "skins": [{"joints": [1, 2, 3], "inverseBindMatrices": ibm, "skeleton": 1}],
        "meshes": [{"primitives": [prim]}, {"primitives": [plain]}],
    })
    times = keyframes(b, [0, 0.5, 1])
    rotation = np.array([[0, 0, 0, 1], [0, 0, 0.38268343, 0.92387953], [0, 0, 0, 1]], np.float32)
    scale = np.zeros((9, 3), np.float32)
    scale[1::3] = 1  # in-tangent, value, out-tangent per keyframe
    samplers = [{"input": times, "output": b.accessor(rotation, FLOAT, "VEC4"), "interpolation": "LINEAR"},
                {"input": times, "output": values(b, [[0, 0, 1], [0, 0.2, 1], [0, 0, 1]], "VEC3"),
                 "interpolation": "STEP"},
                {"input": times, "output": b.accessor(scale, FLOAT, "VEC3"), "interpolation": "CUBICSPLINE"}]
    channels = [{"sampler": 0, "target": {"node": 2, "path": "rotation"}},
                {"sampler": 1, "target": {"node": 3, "path": "translation"}},
                {"sampler": 2, "target": {"node": 1, "path": "scale"}}]
    b.doc["animations"] = [{"samplers": samplers, "channels": channels}]
    if morph_targets:
        linear = np.linspace(0, 1, 3 * morph_targets)
        cubic = np.zeros((3, 3, morph_targets))
        cubic[:, 1] = linear.reshape(3, -1)
        b.doc["animations"] += [
            {"samplers": [{"input": times, "output": values(b, linear, "SCALAR")}],
             "channels": [{"sampler": 0, "target": {"node": 4, "path": "weights"}}]},
            {"samplers": [{"input": times, "output": values(b, cubic.ravel(), "SCALAR"),
                           "interpolation": "CUBICSPLINE"}],
             "channels": [{"sampler": 0, "target": {"node": 4, "path": "weights"}}]}]
    return b


def keyframes(b: DocBuilder, times) -> int:
    """A FLOAT SCALAR accessor of keyframe ``times`` with its min / max; its index."""
    index = values(b, times, "SCALAR")
    b.doc["accessors"][index].update(min=[float(min(times))], max=[float(max(times))])
    return index


def values(b: DocBuilder, array, kind: str, component: int = FLOAT) -> int:
    """An accessor of ``array`` as ``kind`` elements of ``component``; its index."""
    return b.accessor(np.asarray(array, DTYPES[component]), component, kind)


def sampler(b: DocBuilder, j: int) -> dict:
    return b.doc["animations"][0]["samplers"][j]


def refused(capsys, tmp_path, b: DocBuilder, *words, edit=None):
    """The GLB of ``b`` (after ``edit(b)``) is refused by ``pmw encode`` (one line holding ``words``, exit 2,
    nothing written)."""
    if edit is not None:
        edit(b)
    src = tmp_path / "rig.glb"
    src.write_bytes(b.glb())
    assert_refused(*run_encode(capsys, tmp_path, src), "rig.glb", *words)


def _ibm(b: DocBuilder) -> dict:
    return b.doc["accessors"][b.doc["skins"][0]["inverseBindMatrices"]]


def _strided(b: DocBuilder, acc: dict, stride: int) -> None:
    b.doc["bufferViews"][acc["bufferView"]]["byteStride"] = stride


#: An edit of :func:`rigged` -> the words the refusal says.
SKIN_ERRORS = {
    "inverse bind matrices fewer than the joints": (
        lambda b: _ibm(b).update(count=2), ["skins[0].inverseBindMatrices", "2 matrices for 3 joints"]),
    "inverse bind matrices not a float mat4": (
        lambda b: b.doc["skins"][0].update(inverseBindMatrices=values(b, np.tile(np.eye(4), (3, 1)), "VEC4")),
        ["skins[0].inverseBindMatrices", "a VEC4 of FLOAT", "FLOAT MAT4"]),
    "inverse bind matrices with a byte stride": (
        lambda b: _strided(b, _ibm(b), 64), ["skins[0].inverseBindMatrices", "byteStride"]),
    "a skin without joints": (lambda b: b.doc["skins"][0].update(joints=[]), ["skins[0].joints is empty"]),
    "a joint named twice": (lambda b: b.doc["skins"][0].update(joints=[1, 2, 2]), ["skins[0].joints", "nodes[2] twice"]),
    "joints without a common root": (
        lambda b: (b.doc["nodes"][1].update(children=[2]), b.doc["scenes"][0]["nodes"].append(3)),
        ["skins[0].joints have no common root", "nodes[3]"]),
    "a skeleton that is not a common root": (
        lambda b: b.doc["skins"][0].update(skeleton=2), ["skins[0].skeleton = 2 is not a common root"]),
    "a skin on a node without a mesh": (
        lambda b: b.doc["nodes"][1].update(skin=0), ["nodes[1] has a skin but no mesh"]),
    "a skin on a mesh without joints and weights": (
        lambda b: b.doc["nodes"][4].update(skin=0), ["nodes[4] has a skin", "mesh 1 has no JOINTS_0 and WEIGHTS_0"]),
    "a skinned node shown without its joints": (
        lambda b: (b.doc["scenes"].append({"nodes": [0]}), b.doc["scenes"][0]["nodes"].remove(0)),
        ["scenes[1] shows nodes[0]", "not the joints of its skin 0"]),
    "more joints sets than weights sets": (
        lambda b: b.doc["meshes"][0]["primitives"][0]["attributes"].update(
            JOINTS_1=b.doc["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"]),
        ["meshes[0].primitives[0] has 2 JOINTS_n and 1 WEIGHTS_n"]),
}


@pytest.mark.parametrize("case", list(SKIN_ERRORS))
def test_a_skin_the_validator_calls_an_error_is_refused_by_name(capsys, tmp_path, case):
    edit, words = SKIN_ERRORS[case]
    refused(capsys, tmp_path, rigged(), *words, edit=edit)


def _skin_data(edit, component: int = FLOAT):
    """An edit giving the skinned sphere of :func:`rigged` the joints and weights ``edit(joints, weights)`` makes
    of its own ((n, 4) uint8 joints, (n, 4) float64 weights; its weights ``component``: FLOAT, or UNSIGNED_BYTE
    normalized)."""
    def apply(b: DocBuilder) -> None:
        attrs = b.doc["meshes"][0]["primitives"][0]["attributes"]
        joints = _data(b, attrs["JOINTS_0"]).astype(np.uint8)
        weights = _data(b, attrs["WEIGHTS_0"]).astype(np.float64)
        edit(joints, weights)
        attrs["JOINTS_0"] = b.accessor(joints, UNSIGNED_BYTE, "VEC4", 34962)
        if component == FLOAT:
            attrs["WEIGHTS_0"] = b.accessor(weights.astype(np.float32), FLOAT, "VEC4", 34962)
        else:
            q = np.round(weights * 255)
            whole = np.abs(weights.sum(axis=1) - 1) < 1e-6  # rounded to bytes summing to 255, as exporters do
            q[whole, np.argmax(q[whole], axis=1)] += 255 - q[whole].sum(axis=1)
            attrs["WEIGHTS_0"] = b.accessor(q.astype(np.uint8), UNSIGNED_BYTE, "VEC4", 34962)
            b.doc["accessors"][attrs["WEIGHTS_0"]]["normalized"] = True
    return apply


def _data(b: DocBuilder, index: int) -> np.ndarray:
    """The elements of accessor ``index`` of ``b`` (tightly packed, as DocBuilder writes them)."""
    acc = b.doc["accessors"][index]
    view = b.doc["bufferViews"][acc["bufferView"]]
    raw = b"".join(b.parts)[view.get("byteOffset", 0):][:view["byteLength"]]
    return np.frombuffer(raw, DTYPES[acc["componentType"]]).reshape(acc["count"], 4)


def _set(row: int, joints=None, weights=None):
    def edit(j, w):
        if joints is not None:
            j[row] = joints
        if weights is not None:
            w[row] = weights
    return edit


#: Skin data the validator calls errors -> the words of the refusal.
SKIN_DATA_ERRORS = {
    "a joint index past the skin's joints": (
        _skin_data(_set(5, joints=[0, 7, 0, 0])),
        ["meshes[0].primitives[0].attributes.JOINTS_0", "vertex 5 names joint 7", "has 3 joints (0..2)"]),
    "a negative weight": (
        _skin_data(_set(9, weights=[1.25, -0.25, 0, 0])),
        ["attributes.WEIGHTS_0", "vertex 9 has weight -0.25", "not negative"]),
    "a joint named twice": (
        _skin_data(_set(3, joints=[2, 2, 0, 0], weights=[0.5, 0.5, 0, 0])),
        ["meshes[0].primitives[0]", "vertex 3 names joint 2 twice"]),
    "weights that do not sum to 1": (
        _skin_data(_set(4, weights=[0.5, 0.25, 0, 0])), ["the skin weights of vertex 4 sum to 0.75", "sum to 1"]),
    "integer weights that do not sum to 255": (
        _skin_data(_set(4, weights=[100 / 255, 100 / 255, 0, 0]), UNSIGNED_BYTE),
        ["the skin weights of vertex 4 sum to 0.7843137"]),
}


@pytest.mark.parametrize("case", list(SKIN_DATA_ERRORS))
def test_skin_data_the_validator_calls_an_error_is_refused_by_name(capsys, tmp_path, case):
    """Copied through before: a joint index past the skin made three.js fail to load the decoded asset ("Cannot
    read properties of undefined (reading 'matrixWorld')")."""
    edit, words = SKIN_DATA_ERRORS[case]
    refused(capsys, tmp_path, rigged(), *words, edit=edit)


def test_skin_data_the_validator_only_warns_of_still_encodes(capsys, tmp_path):
    """A joint with zero weight (ACCESSOR_JOINTS_USED_ZERO_WEIGHT, a warning), a joint repeated with zero weight,
    weights spread over three joints in float32 rounding, and normalized bytes summing to 255: encoded."""
    def edit(j, w):
        j[2], w[2] = [0, 1, 2, 0], [0.5, 0.5, 0, 0]
        j[3], w[3] = [1, 1, 1, 2], [1, 0, 0, 0]
        j[6], w[6] = [0, 1, 2, 0], np.float32([0.1, 0.2, 0.7, 0])
    for component in (FLOAT, UNSIGNED_BYTE):
        b = rigged()
        _skin_data(edit, component)(b)
        src = tmp_path / "rig.glb"
        src.write_bytes(b.glb())
        status, err, path = run_encode(capsys, tmp_path, src)
        assert status == 0, err
        path.unlink()


def _channel(b: DocBuilder, **channel) -> None:
    b.doc["animations"][0]["channels"].append(channel)


def _one_keyframe_cubic(b: DocBuilder) -> None:
    sampler(b, 2).update(input=keyframes(b, [0.0]), output=values(b, np.ones((3, 3)), "VEC3"))


def _matrix_on_j2(b: DocBuilder) -> None:
    del b.doc["nodes"][3]["translation"]
    b.doc["nodes"][3]["matrix"] = [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, -1, 1]


def _output(j: int, shape: tuple, kind: str, component: int = FLOAT):
    """An edit giving sampler ``j`` of animation 0 an output of zeros of ``shape`` as ``kind`` of ``component``."""
    return lambda b: sampler(b, j).update(output=values(b, np.zeros(shape), kind, component))


ANIMATION_ERRORS = {
    "an animation without channels": (
        lambda b: b.doc["animations"][0].update(channels=[]), ["animations[0].channels is empty"]),
    "an animation without samplers": (
        lambda b: b.doc["animations"].append({"samplers": [], "channels": []}), ["animations[1].samplers is empty"]),
    "keyframe times without min and max": (
        lambda b: [b.doc["accessors"][sampler(b, 0)["input"]].pop(key) for key in ("min", "max")],
        ["animations[0].samplers[0].input", "no min / max"]),
    "a rotation output that is a vec3": (
        _output(0, (3, 3), "VEC3"),
        ["animations[0].channels[0]", "a VEC3 of FLOAT", "rotation is a FLOAT VEC4 or a normalized integer one"]),
    "a rotation output of integers not normalized": (
        _output(0, (3, 4), "VEC4", UNSIGNED_BYTE),
        ["animations[0].channels[0]", "a VEC4 of UNSIGNED_BYTE", "normalized integer"]),
    "a translation output that is a vec4": (
        _output(1, (3, 4), "VEC4"),
        ["animations[0].channels[1]", "a VEC4 of FLOAT", "translation is a FLOAT VEC3"]),
    "a translation output of integers": (
        _output(1, (3, 3), "VEC3", UNSIGNED_SHORT),
        ["animations[0].channels[1]", "a VEC3 of UNSIGNED_SHORT", "translation is a FLOAT VEC3"]),
    "an output with fewer values than keyframes": (
        _output(1, (2, 3), "VEC3"),
        ["animations[0].channels[1]", "holds 2 values for 3 keyframes", "needs 3"]),
    "a cubicspline output without tangents": (
        _output(2, (3, 3), "VEC3"),
        ["animations[0].channels[2]", "holds 3 values for 3 keyframes x 3 values", "needs 9"]),
    "a cubicspline sampler with one keyframe": (
        _one_keyframe_cubic, ["animations[0].samplers[2]", "CUBICSPLINE sampler with 1 keyframe"]),
    "animation data with a byte stride": (
        lambda b: _strided(b, b.doc["accessors"][sampler(b, 1)["output"]], 12),
        ["animations[0].samplers[1].output", "byteStride"]),
    "a weights channel on a mesh without morph targets": (
        lambda b: _channel(b, sampler=0, target={"node": 4, "path": "weights"}),
        ["animations[0].channels[3] animates the morph weights of nodes[4]", "no mesh with morph targets"]),
    "a weights channel on a node without a mesh": (
        lambda b: _channel(b, sampler=0, target={"node": 1, "path": "weights"}),
        ["animations[0].channels[3] animates the morph weights of nodes[1]"]),
    "a channel on the translation of a node with a matrix": (
        _matrix_on_j2, ["animations[0].channels[1] animates the translation of nodes[3], which has a matrix"]),
    "two channels on one target": (
        lambda b: _channel(b, sampler=1, target={"node": 3, "path": "translation"}),
        ["animations[0].channels[3] animates the translation of nodes[3], as animations[0].channels[1] does"]),
}


@pytest.mark.parametrize("case", list(ANIMATION_ERRORS))
def test_an_animation_the_validator_calls_an_error_is_refused_by_name(capsys, tmp_path, case):
    edit, words = ANIMATION_ERRORS[case]
    refused(capsys, tmp_path, rigged(), *words, edit=edit)


def _times(b: DocBuilder, times) -> None:
    """Sampler 0 of animation 0 keyed at ``times`` (3 of them, min / max declared as they are)."""
    sampler(b, 0)["input"] = keyframes(b, times)


def test_keyframe_times_that_do_not_strictly_increase_are_refused(capsys, tmp_path):
    refused(capsys, tmp_path, rigged(), "animations[0].samplers[0].input",
            "keyframe 2 at 0.5 s is not after keyframe 1 at 1 s", edit=lambda b: _times(b, [0, 1, 0.5]))


def test_a_keyframe_time_repeated_is_refused(capsys, tmp_path):
    refused(capsys, tmp_path, rigged(), "keyframe 1 at 0 s is not after keyframe 0 at 0 s",
            edit=lambda b: _times(b, [0, 0, 1]))


def test_negative_keyframe_times_are_refused(capsys, tmp_path):
    refused(capsys, tmp_path, rigged(), "animations[0].samplers[0].input", "keyframe 0 is at -1 s",
            edit=lambda b: _times(b, [-1, 0.5, 1]))


def test_a_rotation_keyframe_that_is_not_a_unit_quaternion_is_refused(capsys, tmp_path):
    """The validator's ACCESSOR_ANIMATION_SAMPLER_OUTPUT_NON_NORMALIZED_QUATERNION (a viewer slerps it as it is)."""
    refused(capsys, tmp_path, rigged(), "animations[0].samplers[0].output", "rotation of keyframe 0 is of length 2",
            "unit quaternions", edit=lambda b: sampler(b, 0).update(output=values(b, np.ones((3, 4)), "VEC4")))


def test_an_in_memory_document_with_keyframe_times_out_of_order_is_refused(tmp_path):
    """``encode_asset((gltf, buffers), ...)`` reads the times as a file's are read."""
    b = rigged()
    _times(b, [0, 1, 0.5])
    b.doc["buffers"] = [{"byteLength": b.offset}]
    with pytest.raises(InputFormatError, match="the asset: animations.0..samplers.0..input.*not after keyframe 1"):
        encode_asset((b.doc, [b"".join(b.parts)]), tmp_path / "out.pmw", measure=False)
    assert not (tmp_path / "out.pmw").exists()


def test_a_weights_output_not_one_value_per_keyframe_and_target_is_refused(capsys, tmp_path):
    b = rigged(morph_targets=2)
    b.doc["animations"][1]["samplers"][0]["output"] = values(b, np.zeros(3), "SCALAR")
    refused(capsys, tmp_path, b, "animations[1].channels[0]", "holds 3 values for 3 keyframes x 2 values", "needs 6")


def test_a_valid_rigged_asset_animated_every_way_still_encodes_with_its_skin_and_animations(capsys, tmp_path):
    """Every interpolation, morph weights (LINEAR and CUBICSPLINE), a normalized integer rotation output, a
    CUBICSPLINE rotation (its tangents not unit quaternions), a sampler no channel uses (valid glTF): encoded,
    its skin and animations kept as they were."""
    b = rigged(morph_targets=2)
    b.doc["animations"][0]["samplers"].append(dict(sampler(b, 1)))  # used by no channel
    q = np.round(np.array([[0, 0, 0, 1], [0, 0, 0.38268343, 0.92387953], [0, 0, 0, 1]]) * 32767).astype(np.int16)
    out = b.accessor(q.astype(np.uint16), UNSIGNED_SHORT, "VEC4")  # (SHORT bits; read back not needed)
    b.doc["accessors"][out].update(componentType=5122, normalized=True)
    b.doc["animations"].append({"samplers": [{"input": sampler(b, 0)["input"], "output": out}],
                                "channels": [{"sampler": 0, "target": {"node": 3, "path": "rotation"}}]})
    cubic = np.zeros((3, 3, 4), np.float32)  # tangents free (zero), values unit quaternions
    cubic[:, 1] = [[0, 0, 0, 1], [0, 0.6, 0, 0.8], [0, 0, 0, 1]]
    b.doc["animations"].append({"samplers": [{"input": sampler(b, 0)["input"], "interpolation": "CUBICSPLINE",
                                              "output": values(b, cubic.reshape(9, 4), "VEC4")}],
                                "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}]})
    src = tmp_path / "rig.glb"
    src.write_bytes(b.glb())
    status, err, path = run_encode(capsys, tmp_path, src)
    assert status == 0, err
    doc = sniff_json(path)
    assert doc["skins"][0]["joints"] == [1, 2, 3]
    assert [[c["target"] for c in a["channels"]] for a in doc["animations"]] == \
        [[c["target"] for c in a["channels"]] for a in b.doc["animations"]]
    assert [[s.get("interpolation") for s in a["samplers"]] for a in doc["animations"]] == \
        [[s.get("interpolation") for s in a["samplers"]] for a in b.doc["animations"]]


def _edit_document(src, dst, edit) -> None:
    """Write to ``dst`` the ``.pmw`` ``src`` with its glTF JSON chunk after ``edit(doc)``."""
    data = bytearray(src.read_bytes())
    length = struct.unpack("<I", data[12:16])[0]
    doc = json.loads(data[20:20 + length])
    edit(doc)
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    out = data[:12] + struct.pack("<II", len(text), 0x4E4F534A) + text + data[20 + length:]
    out[8:12] = struct.pack("<I", len(out))
    dst.write_bytes(bytes(out))


def test_a_pmw_carrying_fewer_inverse_bind_matrices_than_joints_is_refused_by_decode(capsys, tmp_path):
    """The same check reads a ``.pmw``'s document: decode never writes out an asset the validator refuses."""
    src = tmp_path / "rig.glb"
    src.write_bytes(rigged().glb())
    status, err, path = run_encode(capsys, tmp_path, src)
    assert status == 0, err
    _edit_document(path, tmp_path / "edited.pmw",
                   lambda doc: doc["accessors"][doc["skins"][0]["inverseBindMatrices"]].update(count=2))
    with pytest.raises(FormatError, match="its glTF document: skins.0..inverseBindMatrices.*2 matrices for 3 joints"):
        decode_asset(tmp_path / "edited.pmw")


def test_a_pmw_whose_skin_lost_a_joint_its_stream_names_is_refused_by_decode(capsys, tmp_path):
    """The joints a decoded level's vertices name come from the stream: a ``.pmw`` whose skin names fewer joints
    than they use is refused, not written out as an asset three.js fails to load."""
    src = tmp_path / "rig.glb"
    src.write_bytes(rigged().glb())
    status, err, path = run_encode(capsys, tmp_path, src)
    assert status == 0, err
    _edit_document(path, tmp_path / "edited.pmw", lambda doc: doc["skins"][0].update(joints=[1, 2]))
    with pytest.raises(FormatError, match=r"its glTF document: meshes.0..primitives.0..attributes.JOINTS_0: "
                                          r"vertex \d+ names joint 2, but the skin of nodes.0. has 2 joints"):
        decode_asset(tmp_path / "edited.pmw")
