"""The keyless ``baseDigest`` (bitstream.md §6.4): a base mesh damaged so that it still decodes is
refused by name, never shown as other geometry with exit status 0."""

from __future__ import annotations

import json

import numpy as np
import pytest

from pmwm_codec import cli, constants
from pmwm_codec.errors import ChecksumError, PmwError
from pmwm_codec.format import BaseEvent, ContainerParser
from pmwm_codec.format.extension import base_digest
from pmwm_codec.format.mac import base_mac
from pmwm_codec.watermark.key import WatermarkKey
from test_golden import CASES, _encode

NAME = constants.EXTENSION_NAME


def _split(data: bytes):
    """``(gltf dict, offset of the BIN payload)`` of a GLB."""
    json_length = int.from_bytes(data[12:16], "little")
    return json.loads(data[20 : 20 + json_length]), 20 + json_length + 8


def _bases(data: bytes) -> list:
    """The BaseEvents of ``data`` (the parser stops after the bases)."""
    parser = ContainerParser(max_chunks=0)
    events = [e for e in parser.feed(data) if isinstance(e, BaseEvent)]
    parser.close()
    return events


def _extensions(data: bytes) -> list:
    gltf, _ = _split(data)
    return [p["extensions"][NAME] for m in gltf["meshes"] for p in m["primitives"] if NAME in p.get("extensions", {})]


@pytest.fixture(scope="module", params=["grid-hole.plain", "sphere-attributes.plain", "two-primitives.draco",
                                        "bowtie.welded-draco", "sphere.exact-watermark"])
def written(request):
    case = CASES[request.param]()
    data, key = _encode(case.pop("mesh"), **case)
    return request.param, data, key


def test_every_written_base_carries_the_digest_of_the_mesh_it_decodes_to(written):
    """Plain and Draco bases, with attributes, welded, several primitives: the field is written and
    is the digest of what a reader decodes (grid integers, faces, attributes), not of the stored bytes."""
    name, data, _ = written
    exts, bases = _extensions(data), _bases(data)
    assert len(exts) == len(bases) >= 1
    for ext, base in zip(exts, bases):
        assert ext["baseDigest"] == base_digest(base.positions_int, base.faces, base.attributes_int), name
    assert len({e["baseDigest"] for e in exts}) == len(exts)  # distinct bases, distinct digests


def test_the_mac_covers_the_base_but_not_its_digest_field():
    """A verifier with the key recomputes ``baseMac`` over the extension without ``baseDigest``: the
    writer's MAC matches, and it is the MAC a file without the field would carry."""
    case = CASES["sphere.exact-watermark"]()
    data, key = _encode(case.pop("mesh"), **case)
    (ext,), (base,) = _extensions(data), _bases(data)
    found = base_mac(key.mac_key(), 0, ext, base.positions_int, base.faces, base.attributes_int)
    assert found == ext["baseMac"] and "baseDigest" in ext
    without = {k: v for k, v in ext.items() if k != "baseDigest"}
    assert base_mac(key.mac_key(), 0, without, base.positions_int, base.faces, base.attributes_int) == found


def test_the_digest_sees_every_part_of_the_base():
    """One changed integer in positions, faces or attributes, or one face more, changes it."""
    rng = np.random.default_rng(5)
    positions = rng.integers(0, 1 << 14, (40, 3))
    faces = rng.integers(0, 40, (60, 3))
    attributes = rng.integers(0, 1 << 10, (40, 5))
    reference = base_digest(positions, faces, attributes)
    assert len(reference) == 16 and int(reference, 16) >= 0
    for array in (positions, faces, attributes):
        changed = array.copy()
        changed[rng.integers(len(array)), rng.integers(array.shape[1])] ^= 1
        parts = [changed if a is array else a for a in (positions, faces, attributes)]
        assert base_digest(*parts) != reference
    assert base_digest(positions, faces[:-1], attributes) != reference
    assert base_digest(positions, faces, None) != reference
    assert base_digest(positions, faces, attributes[:, :0]) == base_digest(positions, faces, None)


def _draco_ranges(data: bytes) -> list:
    """Absolute byte ranges of the Draco bufferViews of the bases."""
    gltf, bin_start = _split(data)
    out = []
    for mesh in gltf["meshes"]:
        for prim in mesh["primitives"]:
            draco = prim.get("extensions", {}).get("KHR_draco_mesh_compression")
            if draco is not None:
                view = gltf["bufferViews"][draco["bufferView"]]
                start = bin_start + view.get("byteOffset", 0)
                out.append((start, start + view["byteLength"]))
    return out


def test_a_flipped_bit_anywhere_in_a_draco_base_never_decodes_to_other_geometry():
    """Every byte of a Draco base, one bit flipped: the reader either refuses the file with a named
    error or (a bit Draco never reads) gives back exactly the base that was written.  Before the
    digest, flips that Draco decodes without complaint gave a different mesh and exit status 0."""
    case = CASES["two-parts.draco"]()
    data, _ = _encode(case.pop("mesh"), **case)
    written = _bases(data)
    (start, end), = _draco_ranges(data)
    outcomes = {"refused by digest": 0, "refused otherwise": 0, "unchanged": 0}
    for offset in range(start, end):
        damaged = bytearray(data)
        damaged[offset] ^= 1 << (offset % 8)
        try:
            bases = _bases(bytes(damaged))
        except ChecksumError as exc:
            assert str(exc).startswith("base mesh: baseDigest mismatch")
            outcomes["refused by digest"] += 1
            continue
        except PmwError:
            outcomes["refused otherwise"] += 1
            continue
        assert all(np.array_equal(a.positions_int, b.positions_int) and np.array_equal(a.faces, b.faces)
                   for a, b in zip(bases, written)), f"byte {offset - start} of the Draco base: other geometry, no error"
        outcomes["unchanged"] += 1
    assert outcomes["refused by digest"] > 0, outcomes  # the case the digest exists for does occur


def test_several_primitives_name_the_damaged_one():
    case = CASES["two-primitives.draco"]()
    data, _ = _encode(case.pop("mesh"), **case)
    gltf, bin_start = _split(data)
    exts = _extensions(data)
    damaged = data.replace(exts[1]["baseDigest"].encode(), b"0" * 16, 1)
    with pytest.raises(ChecksumError, match=r"^base mesh of progressive primitive 2: baseDigest mismatch"):
        _bases(damaged)


def test_files_without_the_field_still_decode():
    """Files written before the field existed (every conformance file) are not checked: the field is
    optional, and a file with it blanked out decodes to the same base."""
    case = CASES["grid-hole.plain"]()
    data, _ = _encode(case.pop("mesh"), **case)
    text = f',"baseDigest":"{_extensions(data)[0]["baseDigest"]}"'.encode()
    assert data.count(text) == 1
    stripped = data.replace(text, b" " * len(text))  # same length: every offset stays right
    assert "baseDigest" not in _extensions(stripped)[0]
    (a,), (b,) = _bases(data), _bases(stripped)
    assert np.array_equal(a.positions_int, b.positions_int) and np.array_equal(a.faces, b.faces)


def test_the_command_line_refuses_a_damaged_base_in_one_line_and_writes_nothing(tmp_path, capsys):
    case = CASES["two-parts.draco"]()
    data, _ = _encode(case.pop("mesh"), **case)
    written = _bases(data)
    (start, end), = _draco_ranges(data)
    for offset in range(start, end):  # the first flip Draco decodes to other geometry
        damaged = bytearray(data)
        damaged[offset] ^= 1 << (offset % 8)
        try:
            _bases(bytes(damaged))
        except ChecksumError:
            break
        except PmwError:
            continue
    else:
        pytest.fail("no flip decodes to other geometry")
    src = tmp_path / "damaged.pmw"
    src.write_bytes(bytes(damaged))
    for argv in (["decode", src, "-o", tmp_path / "out.obj"], ["verify", src, "--key", _key_file(tmp_path)]):
        code = cli.main([str(a) for a in argv])
        out, err = capsys.readouterr()
        assert code == 2, (argv, out, err)
        assert err.count("\n") == 1 and "base mesh: baseDigest mismatch" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged.pmw", "key.json"]
    assert written  # the intact file's bases decode


def _key_file(tmp_path):
    path = tmp_path / "key.json"
    if not path.exists():
        WatermarkKey.generate(rng=np.random.default_rng(1)).save(path)
    return path
