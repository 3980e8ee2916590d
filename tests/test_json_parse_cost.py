"""What ``pmw verify`` spends on a large glTF JSON before any geometry (a 64 MiB JSON took ~13 s): the parsed
document was walked once more in Python to find a NaN or infinite number, although the JSON parser reads every
number itself (32M integers: 3.5 s of the 13), and Python's garbage collector walked the millions of arrays and
objects such a document holds again and again while the parser and the scene MAC's copy made them (16M empty
arrays: 5.5 s of parsing, 0.8 s with the collector held off).  Both are gone; the refusal of a non-finite number,
named by its JSON path, is unchanged."""

from __future__ import annotations

import gc
import json

import pytest

from pmwm_codec.errors import FormatError
from pmwm_codec.format import gltf, parser
from pmwm_codec.format.glb import frame_glb, split_glb
from pmwm_codec.verify import verify_stream

from conftest import marked_sphere


@pytest.fixture(scope="module")
def sphere():
    data, key, _ = marked_sphere(13)
    return data, key


def _with_extras(data: bytes, extras, literal: str = "") -> bytes:
    """The file with its first node's ``extras``; a ``"@x@"`` in them written as the JSON text ``literal``."""
    doc, binary = split_glb(data)
    doc["nodes"][0]["extras"] = extras
    text = json.dumps(doc).replace('"@x@"', literal)
    return b"".join(frame_glb(text.encode(), [bytes(binary)], len(binary)))


def test_a_document_without_a_non_finite_number_is_not_walked_for_one(monkeypatch, sphere):
    walks = []

    def walk(doc, name, error):
        walks.append(name)

    monkeypatch.setattr(gltf, "check_finite_numbers", walk)
    monkeypatch.setattr(parser, "check_finite_numbers", walk, raising=False)
    data, key = sphere
    assert verify_stream(_with_extras(data, list(range(100_000))), key).verdict == "tampered"  # the extras: sceneMac
    assert walks == []


@pytest.mark.parametrize("value, shown", [("NaN", "NaN"), ("-Infinity", "-Infinity"), ("1e999", "Infinity"),
                                          ("-1e400", "-Infinity")])
def test_a_non_finite_number_is_still_refused_by_its_path(sphere, value, shown):
    data, key = sphere
    marked = _with_extras(data, [1, 2.5, "@x@"], value)
    with pytest.raises(FormatError, match=rf"GLB JSON chunk: nodes\[0\]\.extras\[2\] is {shown}, which JSON does not"):
        verify_stream(marked, key)


def test_the_collector_does_not_walk_a_large_document_while_it_is_built(sphere):
    """300,000 empty arrays in ``extras``: ~2,000 collections during a verify, now a handful."""
    data, key = sphere
    wide = _with_extras(data, [[] for _ in range(300_000)])
    starts = []

    def count(phase, info):
        if phase == "start":
            starts.append(info["generation"])

    gc.callbacks.append(count)
    try:
        verdict = verify_stream(wide, key).verdict
    finally:
        gc.callbacks.remove(count)
    assert verdict == "tampered" and len(starts) < 100, len(starts)
    assert gc.isenabled()


def test_verify_reads_the_image_and_the_owner_layer_in_one_pass_after_the_full_decodes_frames(monkeypatch, tmp_path,
                                                                                            capsys):
    """A key with an owner ID (every key ``pmw encode --watermark`` writes) made ``pmw verify`` decode the
    stream twice, its JSON parsed twice: once for the image, once for the owner layer.  The image and the owner
    layer are read in one pass; a file's levels are read in the frames of its full decode
    (``verify.owner.full_decode_frames``), which one decode-only pass before it takes: two parses, not three."""
    import numpy as np

    import pmwm_codec
    from pmwm_codec import shapes
    from pmwm_codec.cli import main

    out = tmp_path / "m.pmw"
    image = np.random.default_rng(6).integers(0, 256, (8, 8)).astype(np.uint8)
    report = pmwm_codec.encode(shapes.icosphere(4, noise=0.01), out, watermark=image, measure="none")
    assert report.get("owner_id")
    parsed = []
    load = parser._load_json
    monkeypatch.setattr(parser, "_load_json", lambda text: parsed.append(1) or load(text))
    assert main(["verify", str(out), "--key", report["key_path"], "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["verdict"] == "authentic" and doc["owner"]["verdict"] == "present"
    assert all(row["owner"]["verdict"] in ("present", "absent", "inconclusive") for row in doc["chunks"])
    assert len(parsed) == 2  # the frames' pass and the read's
