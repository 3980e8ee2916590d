"""A watermark too large for the mesh is refused naming the image as the caller gave it and what fits.  A
300x200 image (downscaled to 256x171, then padded to a 256x256 square to be carried) was refused as "a 256x256
watermark needs 589783 bits": a size the user never gave."""

from __future__ import annotations

import io
import json
import re

import numpy as np
import pytest
from PIL import Image

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh
from pmwm_codec.watermark.codec import CapacityError

MESH = shapes.torus(48, 24)


@pytest.fixture
def files(tmp_path):
    write_mesh(tmp_path / "t.obj", MESH)
    pixels = np.random.default_rng(0).integers(0, 256, (200, 300)).astype(np.uint8)
    Image.fromarray(pixels).save(tmp_path / "w.png")
    return tmp_path


def test_the_command_line_names_the_image_given_and_what_fits(files, capsys):
    assert main(["encode", str(files / "t.obj"), "-o", str(files / "t.pmw"), "--watermark", str(files / "w.png")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("pmw: error: the 300x200 watermark (carried as a 256x256 square) "
                                                   "needs "), err
    fit = re.search(r"the largest that fits is (\d+)x\1 \(this image at (\d+)x(\d+), padded\)", err)
    assert fit, err
    side, width, height = map(int, fit.groups())
    assert (width, height) == (side, round(side * 200 / 300))
    assert "--fit" in err and not (files / "t.pmw").exists()


def test_fit_says_what_it_shrank_as_given(files, capsys):
    assert main(["encode", str(files / "t.obj"), "-o", str(files / "t.pmw"), "--watermark", str(files / "w.png"),
                 "--fit", "--json"]) == 0
    notices = json.loads(capsys.readouterr().out)["notices"]
    assert any(n.startswith("--fit: the 300x200 watermark (carried as a 256x256 square) shrunk to ") for n in notices), \
        notices


def test_the_library_names_it_too(files):
    with pytest.raises(CapacityError, match=r"^the 300x200 watermark \(carried as a 256x256 square\) needs [\d,]+ bits"):
        pmwm_codec.encode(MESH, io.BytesIO(), watermark=files / "w.png", key=_key(), measure="none")
    with pytest.raises(CapacityError, match=r"splits; the 300x200 watermark \(carried as a 256x256 square\) needs .*"
                                            r"from there is (\d+)x\1 \(this image at \d+x\d+, padded\)"):
        pmwm_codec.encode(MESH, io.BytesIO(), watermark=files / "w.png", key=_key(), measure="none", embed_from=0.5)


def test_a_square_image_taken_as_it_is_is_named_as_before(files):
    image = np.random.default_rng(1).integers(0, 256, (64, 64)).astype(np.uint8)
    with pytest.raises(CapacityError, match=r"^a 64x64 watermark needs [\d,]+ bits; this mesh has [\d,]+ vertex splits"
                                            r".*: the largest that fits is (\d+)x\1 \(pmw encode --fit"):
        pmwm_codec.encode(MESH, io.BytesIO(), watermark=image, key=_key(), measure="none")


def _key():
    return pmwm_codec.watermark.key.WatermarkKey.generate(rng=np.random.default_rng(4))
