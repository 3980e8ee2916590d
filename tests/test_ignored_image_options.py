"""An option that shapes only the watermark image's mark (``bits``, ``mode``, ``embed_from``, ``step_units``)
given to an encode without a watermark changes nothing in the file: ``pmw encode`` said so in a note, while
``pmwm_codec.encode`` ignored it in silence.  Both now say it, in the report's ``notices``, worded by one
function (:func:`pmwm_codec.options.ignored_without_image`) so the two never drift."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh

MESH = shapes.torus(24, 12)


@pytest.mark.parametrize("options, note", [
    ({"bits": 3}, "bits ignored: no watermark"),
    ({"mode": "paper"}, "mode='paper' ignored: no watermark"),
    ({"embed_from": 0.25}, "embed_from ignored: no watermark"),
    ({"step_units": 1.5}, "step_units ignored: no watermark"),
])
def test_the_library_names_an_image_option_it_ignores_without_a_watermark(options, note):
    report = pmwm_codec.encode(MESH, io.BytesIO(), measure="none", **options)
    assert report["watermark"] is None and note in report["notices"], report["notices"]


def test_the_library_says_nothing_of_options_it_uses():
    image = np.random.default_rng(2).integers(0, 256, (8, 8)).astype(np.uint8)
    key = pmwm_codec.watermark.key.WatermarkKey.generate(rng=np.random.default_rng(3))
    report = pmwm_codec.encode(MESH, io.BytesIO(), watermark=image, key=key, bits=3, measure="none", owner_id=False)
    assert not any("ignored" in note for note in report["notices"]), report["notices"]
    plain = pmwm_codec.encode(MESH, io.BytesIO(), mode="exact", measure="none")  # the default: nothing to say
    assert not any("ignored" in note for note in plain["notices"]), plain["notices"]


def test_the_command_line_says_it_once_in_its_own_words(tmp_path, capsys):
    src = tmp_path / "t.obj"
    write_mesh(src, MESH)
    assert main(["encode", str(src), "-o", str(tmp_path / "t.pmw"), "--bits", "3", "--mode", "paper", "--json"]) == 0
    notices = json.loads(capsys.readouterr().out)["notices"]
    ignored = [n for n in notices if "ignored" in n]
    assert ignored == ["--bits ignored: no --watermark", "--mode paper ignored: no --watermark"], notices


def test_the_library_names_an_owner_strength_it_ignores_without_an_owner_layer():
    """``owner_strength`` shapes the owner layer alone: without an ``owner_id`` or a watermark there is none."""
    note = "owner_strength ignored: no owner layer (an owner_id, or a watermark, makes one)"
    for owner_id in (None, False):
        report = pmwm_codec.encode(MESH, io.BytesIO(), measure="none", owner_strength=0.1, owner_id=owner_id)
        assert report.get("owner_id") is None and note in report["notices"], report["notices"]
    key = pmwm_codec.watermark.key.WatermarkKey.generate(rng=np.random.default_rng(3))
    marked = pmwm_codec.encode(shapes.icosphere(4, noise=0.02), io.BytesIO(), measure="none", owner_strength=0.1,
                               owner_id=key.owner_hex, key=key)
    assert marked["owner_id"] == key.owner_hex and not any("ignored" in n for n in marked["notices"]), marked
