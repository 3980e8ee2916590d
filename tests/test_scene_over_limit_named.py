"""The scene MAC at its limit (spec/bitstream.md §6.3, ``MAX_SCENE_VALUES``): ``pmw verify`` built the scene
document twice (once for where its data ends, once for its MAC), doubling the cost near the limit, and a scene
over the limit printed the usual "sceneMac mismatch" line without naming the limit.  The scene is now built once
per verify, and a scene over the limit says so, with the number, on the line and in ``--json``
(``mac.scene_error``; ``reference_mac.scene_error`` for ``verify MESH --reference``)."""

from __future__ import annotations

import json

import pytest

import pmwm_codec
from pmwm_codec.cli import main
from pmwm_codec.format import mac
from pmwm_codec.verify import verify_mesh, verify_stream

from conftest import marked_sphere


@pytest.fixture(scope="module")
def sphere():
    data, key, _ = marked_sphere(12)
    return data, key


@pytest.fixture
def files(tmp_path, sphere):
    data, key = sphere
    (tmp_path / "x.pmw").write_bytes(data)
    key.save(tmp_path / "x.key.json")
    return tmp_path / "x.pmw", tmp_path / "x.key.json"


def test_a_verify_builds_the_scene_document_once(monkeypatch, sphere):
    calls = []
    built = mac.scene_document

    def counted(gltf):
        calls.append(1)
        return built(gltf)

    monkeypatch.setattr(mac, "scene_document", counted)
    data, key = sphere
    assert verify_stream(data, key).verdict == "authentic"
    assert len(calls) == 1
    calls.clear()
    assert verify_stream([data[i : i + 997] for i in range(0, len(data), 997)], key).verdict == "authentic"
    assert len(calls) == 1  # fed in blocks: built when the JSON is in, checked with the same copy


def test_a_scene_over_the_limit_is_named_on_the_line_and_in_the_json(monkeypatch, files, capsys):
    monkeypatch.setattr(mac, "MAX_SCENE_VALUES", 60)  # the key holder's sphere: a scene of more values
    path, key = files
    assert main(["verify", str(path), "--key", str(key)]) == 1
    out = capsys.readouterr().out
    assert "verdict: tampered" in out
    assert ("the scene (nodes, materials, other meshes) is not the key holder's: the scene holds more than 60 JSON "
            "values (MAX_SCENE_VALUES, spec/bitstream.md §6.3): too many for its sceneMac") in out.splitlines(), out
    assert "sceneMac mismatch" not in out
    assert main(["verify", str(path), "--key", str(key), "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "tampered" and doc["mac"]["scene"] is False
    assert "more than 60 JSON values (MAX_SCENE_VALUES" in doc["mac"]["scene_error"]


def test_a_scene_that_matches_has_no_scene_error(files, capsys):
    path, key = files
    assert main(["verify", str(path), "--key", str(key), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["mac"]["scene"] is True and doc["mac"]["scene_error"] is None


def test_a_reference_over_the_limit_is_named_too(monkeypatch, sphere):
    data, key = sphere
    mesh = pmwm_codec.decode(data)
    monkeypatch.setattr(mac, "MAX_SCENE_VALUES", 60)
    v = verify_mesh((mesh.positions, mesh.faces), data, key)
    assert v.verdict == "not-authentic" and v.reference_mac["scene"] is False
    assert "more than 60 JSON values (MAX_SCENE_VALUES" in v.reference_mac["scene_error"]
    assert "more than 60 JSON values" in v.reference_note()
