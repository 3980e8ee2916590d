"""A watermark is only written where it can verify: ``pmw verify`` calls a mark with fewer than
``MIN_CARRIERS`` codes ``inconclusive`` (exit 1), so an encode that leaves fewer carriers (a mesh
barely larger than its base, such as the convex-hull parts of robot URDFs, or ``embed_from`` near
the end) would write a file its own key never verifies.  Such an encode is refused instead, with
one line naming the numbers, and ``--fit`` does not shrink the image into it."""

from __future__ import annotations

import io

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.key import WatermarkKey
from pmwm_codec.watermark.verify import MIN_CARRIERS

IMAGE = (np.arange(4, dtype=np.uint8).reshape(2, 2) * 60)


def _key():
    return WatermarkKey.generate(rng=np.random.default_rng(1))


def _verdict(data: bytes, key) -> str:
    dec = StreamDecoder(key, IMAGE)
    results = dec.feed(data)
    dec.close()
    return results[-1].estimate.verdict


@pytest.mark.parametrize("mesh, options", [
    (shapes.grid(9, 9, hole=False), {}),                                 # 81 vertices: 17 splits past a 64-vertex base
    (shapes.icosphere(4, noise=0.02), {"embed_from": 0.99}),             # 2,498 splits, the last 25 marked
], ids=["few-splits", "late-start"])
def test_a_mark_with_fewer_carriers_than_verify_reads_is_refused(mesh, options):
    with pytest.raises(wm.CapacityError, match=f"needs {MIN_CARRIERS} to verify") as info:
        encode_mesh(mesh, io.BytesIO(), watermark=IMAGE, key=_key(), measure=False, **options)
    assert info.value.largest_size is None  # --fit has nothing to shrink to
    assert "\n" not in str(info.value)


def test_a_mark_with_enough_carriers_still_verifies_authentic():
    buf = io.BytesIO()
    report = encode_mesh(shapes.grid(10, 10, hole=False), buf, watermark=IMAGE, key=_key(), measure=False)
    assert MIN_CARRIERS <= report.as_json()["watermark"]["embedded"] < 64
    assert _verdict(buf.getvalue(), report.key) == "authentic"


def test_pmw_encode_fit_on_a_tiny_mesh_is_one_line_and_no_file(tmp_path, capsys):
    from PIL import Image

    src, out, image = tmp_path / "part.obj", tmp_path / "part.pmw", tmp_path / "logo.png"
    write_mesh(str(src), shapes.grid(9, 9, hole=False))
    Image.fromarray(np.random.default_rng(0).integers(0, 256, (32, 32)).astype(np.uint8)).save(image)
    code = main(["encode", str(src), "-o", str(out), "--watermark", str(image), "--fit"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and err.startswith("pmw: error:") and "to verify" in err
    assert not out.exists() and not (tmp_path / "part.pmw.key.json").exists()
