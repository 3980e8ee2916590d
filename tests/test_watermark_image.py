"""Loading, normalising and writing watermark images."""

import numpy as np
import pytest
from PIL import Image

from pmwm_codec.errors import InputFormatError, PmwError
from pmwm_codec.watermark.image import load_watermark, make_text_watermark, save_png


def test_square_power_of_two_gray_is_untouched(tmp_path):
    img = np.arange(64 * 64, dtype=np.uint32).reshape(64, 64) % 256
    path = tmp_path / "w.png"
    Image.fromarray(img.astype(np.uint8)).save(path)
    out, notices = load_watermark(path)
    assert out.dtype == np.uint8 and out.shape == (64, 64)
    assert np.array_equal(out, img) and notices == []


def test_colour_is_converted_with_a_notice(tmp_path):
    rgb = np.zeros((32, 32, 3), np.uint8)
    rgb[..., 0] = 255
    path = tmp_path / "red.png"
    Image.fromarray(rgb).save(path)
    out, notices = load_watermark(path)
    assert out.shape == (32, 32) and abs(int(out[0, 0]) - 76) <= 1  # 0.299 * 255
    assert any("grayscale" in n for n in notices)


def test_transparent_pixels_become_white(tmp_path):
    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[:4, :, 3] = 255  # top half opaque black, bottom transparent
    path = tmp_path / "a.png"
    Image.fromarray(rgba, "RGBA").save(path)
    out, notices = load_watermark(path)
    assert (out[:4] == 0).all() and (out[4:] == 255).all()
    assert any("transparent" in n for n in notices)


def test_non_square_is_padded_centred():
    img = np.full((20, 40), 255, np.uint8)
    img[5:15, 10:30] = 0
    out, notices = load_watermark(img)
    assert out.shape == (64, 64)
    assert any("padded to 64x64" in n for n in notices)
    assert np.array_equal(out[22:42, 12:52], img)  # original pixels unchanged
    assert (out[:22] == 255).all()  # border value = background


def test_non_power_of_two_square_is_padded():
    out, notices = load_watermark(np.zeros((100, 100), np.uint8))
    assert out.shape == (128, 128) and len(notices) == 1


def test_large_images_are_downscaled_then_padded():
    out, notices = load_watermark(np.zeros((600, 300), np.uint8), max_size=128)
    assert out.shape == (128, 128)
    assert any("downscaled" in n for n in notices) and any("padded" in n for n in notices)
    out, _ = load_watermark(np.zeros((600, 300), np.uint8), max_size=None)
    assert out.shape == (1024, 1024)


def test_float_arrays_in_unit_range_are_scaled():
    out, notices = load_watermark(np.full((4, 4), 0.5))
    assert (out == 128).all() and notices


def test_sixteen_bit_png(tmp_path):
    a = np.full((16, 16), 65535, np.uint16)
    a[0, 0] = 0
    path = tmp_path / "w16.png"
    Image.fromarray(a).save(path)
    out, _ = load_watermark(path)
    assert out[0, 0] == 0 and out[1, 1] == 255


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda d: d / "missing.png", "no such file"),
        (lambda d: d, "directory"),
        (lambda d: (d / "x.png").write_bytes(b"not an image") and d / "x.png", "not an image"),
    ],
)
def test_bad_files_are_input_format_errors(tmp_path, make, message):
    with pytest.raises(InputFormatError, match=message):
        load_watermark(make(tmp_path))


def test_truncated_png_is_an_input_format_error(tmp_path):
    path = tmp_path / "w.png"
    Image.fromarray(np.random.default_rng(0).integers(0, 255, (64, 64), dtype=np.uint8)).save(path)
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputFormatError):
        load_watermark(path)


@pytest.mark.parametrize("arr", [np.zeros((0, 5)), np.zeros((4, 4, 2)), np.array(["a"]),
                                 np.array([[np.nan]])])
def test_bad_arrays(arr):
    with pytest.raises(InputFormatError):
        load_watermark(arr)


def test_save_png_round_trip(tmp_path):
    img = np.random.default_rng(1).integers(0, 256, (16, 16), dtype=np.uint8)
    save_png(tmp_path / "o.png", img)
    back, notices = load_watermark(tmp_path / "o.png")
    assert np.array_equal(back, img) and notices == []
    with pytest.raises(PmwError):
        save_png(tmp_path / "no" / "dir" / "o.png", img)


def test_text_watermark():
    w = make_text_watermark("PMW", 64)
    assert w.shape == (64, 64) and w.dtype == np.uint8
    assert w.min() < 64 and w.max() == 255  # dark text on white
    assert (w[0] == 255).all() and (w[:, 0] == 255).all()  # margin
    assert 0.05 < (w < 128).mean() < 0.6
    assert not np.array_equal(w, make_text_watermark("XYZ", 64))
    assert make_text_watermark("", 32).shape == (32, 32)
