"""Every refusal of the public API is one of the named kinds of ``pmwm_codec.errors`` (README, "Python API"; spec
README, "Kinds of refusal"), never the bare base class: a caller tells a mesh it cannot use from an output it
cannot write or an input of the wrong kind by the class alone, and ``except PmwError`` still catches them all.
Each case below raised ``PmwError`` itself."""

from __future__ import annotations

import io

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.errors import InputFormatError, MeshError, OptionError, PmwError
from pmwm_codec.figures import write_pictures
from pmwm_codec.verify import verify_mesh
from pmwm_codec.watermark import save_png
from pmwm_codec.watermark.image import gray_image

from test_hostile_inputs import glb_of

MARK = np.random.default_rng(5).integers(0, 256, (8, 8)).astype(np.uint8)


def _far_out_mesh():
    """A small sphere 10,000 units from the origin: float32 cannot carry a 16-bit grid over it."""
    m = shapes.icosphere(3, 1.0, noise=0.01)
    return pmwm_codec.Mesh((m.positions + [10000.0, 0.0, 0.0]).astype(np.float32).astype(np.float64), m.faces)


def _png_in_a_file_as_directory(tmp_path):
    (tmp_path / "file").write_bytes(b"x")
    save_png(tmp_path / "file" / "mark.png", MARK)


def _pictures_under_a_file(tmp_path):
    (tmp_path / "file").write_bytes(b"x")
    write_pictures(tmp_path / "file" / "frames", {"a.png": gray_image(MARK)})


def _reference_that_cannot_be_read(tmp_path):
    def blocks():
        yield b"glTF"
        raise OSError(5, "Input/output error")

    verify_mesh(shapes.icosphere(2), blocks(), pmwm_codec.load_key(_marked(tmp_path)[1]))


def _marked(tmp_path) -> tuple:
    out = tmp_path / "m.pmw"
    pmwm_codec.encode(shapes.icosphere(3, noise=0.01), out, watermark=MARK, measure="none")
    return out, str(out) + ".key.json"


def _reference_without_a_watermark(tmp_path):
    _, key = _marked(tmp_path)
    plain = tmp_path / "plain.pmw"
    pmwm_codec.encode(shapes.icosphere(3, noise=0.01), plain, measure="none")
    verify_mesh(pmwm_codec.decode(plain), plain, key)


def _asset_without_triangles(tmp_path):
    src = tmp_path / "cloud.glb"
    src.write_bytes(glb_of([(0, np.random.default_rng(3).uniform(-1, 1, (20, 3)), None)]))
    pmwm_codec.encode(src, tmp_path / "cloud.pmw")


def _mesh_float32_cannot_carry(tmp_path):
    m = shapes.icosphere(3, 1.0, noise=0.01)  # float64 points far out: a fine grid's points are none of float32's
    pmwm_codec.encode(pmwm_codec.Mesh(m.positions + [10000.0, 0.0, 0.0], m.faces), io.BytesIO(), grid_bits=24,
                      measure="none")


def _marked_mesh_float32_cannot_carry(tmp_path):
    key = pmwm_codec.watermark.key.WatermarkKey.generate(rng=np.random.default_rng(1))
    pmwm_codec.encode(_far_out_mesh(), io.BytesIO(), watermark=MARK, key=key, measure="none")


@pytest.mark.parametrize("refusal, kind, words", [
    (_png_in_a_file_as_directory, OptionError, "cannot write PNG"),
    (_pictures_under_a_file, OptionError, "cannot write pictures"),
    (_reference_that_cannot_be_read, InputFormatError, "cannot read the reference file"),
    (_reference_without_a_watermark, InputFormatError, "the reference file carries no watermark"),
    (_asset_without_triangles, MeshError, "no triangle primitive that can be made progressive"),
    (_mesh_float32_cannot_carry, MeshError, "does not survive the float32 positions"),
    (_marked_mesh_float32_cannot_carry, MeshError, "does not survive the float32 positions"),
])
def test_a_refusal_is_raised_as_its_documented_kind(tmp_path, refusal, kind, words):
    with pytest.raises(PmwError, match=words) as info:  # the base class still catches every one
        refusal(tmp_path)
    assert type(info.value) is not PmwError and isinstance(info.value, kind), type(info.value)


def test_the_package_raises_no_bare_pmw_error():
    """A new refusal picks its kind too: no ``raise PmwError(`` is left in the package."""
    from pathlib import Path

    root = Path(pmwm_codec.__file__).parent
    bare = [f"{p.relative_to(root)}:{n}" for p in root.rglob("*.py")
            for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if "raise PmwError(" in line]
    assert bare == []
