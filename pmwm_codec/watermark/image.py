"""Watermark images in and out: a square ``2^k x 2^k`` uint8 grayscale array.

:func:`load_watermark` accepts a path or an array and always returns
``(image (s, s) uint8, notices)``.  It never changes an image silently: each
conversion adds a one-line notice the tool prints.

* colour or palette images -> grayscale (ITU-R 601 luma, Pillow's ``"L"``); transparent
  pixels are composited over white first;
* 16-bit / float images -> scaled to 0..255;
* images larger than ``max_size`` on either side -> downscaled (Lanczos, aspect kept) so
  that the side fits ``max_size`` (a power of two, default 256);
* then, when not a ``2^k`` square, **padded** (never stretched) to the next ``2^k`` square,
  the image centred, the border filled with the median of the image's outer pixels (its
  background, usually), so the original pixels survive unchanged.

Bad input (missing file, directory, not an image, zero-size image) is an
:class:`~pmwm_codec.errors.InputFormatError` with a one-line message.
"""

from __future__ import annotations

import io
import os

import numpy as np
from PIL import Image, ImageDraw, ImageFont, UnidentifiedImageError

from ..constants import MAX_WATERMARK_PIXELS
from ..errors import InputFormatError, OptionError
from ..sources import check_input_path

__all__ = ["load_watermark", "save_png", "make_text_watermark", "DEFAULT_MAX_SIZE"]

#: Largest side kept as is by :func:`load_watermark` (a power of two).
DEFAULT_MAX_SIZE = 256


def _next_pow2(n: int) -> int:
    return 1 << max(0, int(n - 1).bit_length())


def _open(path) -> tuple[Image.Image, str]:
    path = os.fspath(path)
    name = check_input_path(path, "an image")
    try:
        img = Image.open(path)
        check_image_size(img, name)
        img.load()
    except UnidentifiedImageError:
        raise InputFormatError(f"{name}: not an image Pillow can read") from None
    except Image.DecompressionBombError:  # Pillow's own, larger limit, checked by Image.open
        raise InputFormatError(f"{name}: image is larger than the limit of {MAX_WATERMARK_PIXELS:,} pixels") from None
    except (OSError, ValueError, SyntaxError) as exc:
        raise InputFormatError(f"{name}: cannot read image ({exc})") from None
    return img, name


def check_image_size(img: Image.Image, name: str) -> None:
    """Refuse an opened (not yet decoded) image whose header declares more than
    :data:`MAX_WATERMARK_PIXELS` pixels: Pillow reads the size from the header, so
    nothing has been decoded yet."""
    if img.width * img.height > MAX_WATERMARK_PIXELS:
        raise InputFormatError(f"{name}: image is {img.width}x{img.height}, more than the limit of "
                               f"{MAX_WATERMARK_PIXELS:,} pixels")


def _to_gray(img: Image.Image, notices: list[str]) -> np.ndarray:
    """PIL image of any mode -> (h, w) float64 in 0..255."""
    mode = img.mode
    if mode in ("1", "L"):
        return np.asarray(img.convert("L"), dtype=np.float64)
    if mode.startswith("I") or mode == "F":
        a = np.asarray(img, dtype=np.float64)
        top = 65535.0 if mode.startswith("I;16") else max(float(a.max()), 255.0)
        if top != 255.0:
            notices.append(f"{mode} image scaled from 0..{top:g} to 0..255")
        return a * (255.0 / top)
    if "A" in mode or "transparency" in img.info:
        rgba = img.convert("RGBA")
        bg = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        img = Image.alpha_composite(bg, rgba)
        notices.append("transparent pixels composited over white")
    notices.append(f"{mode} image converted to grayscale")
    return np.asarray(img.convert("L"), dtype=np.float64)


def _array_to_gray(arr, notices: list[str]) -> np.ndarray:
    """(h, w) or (h, w, 1|3|4) array -> (h, w) float64 in 0..255."""
    a = np.asarray(arr)
    if not (a.dtype == bool or np.issubdtype(a.dtype, np.number)) or np.iscomplexobj(a):
        raise InputFormatError(f"watermark array has unsupported dtype {a.dtype}")
    if a.size == 0:
        raise InputFormatError("watermark image is empty")
    f = a.astype(np.float64) * (255.0 if a.dtype == bool else 1.0)
    if not np.isfinite(f).all():
        raise InputFormatError("watermark array holds NaN or infinite values")
    if np.issubdtype(a.dtype, np.floating) and f.min() >= 0.0 and f.max() <= 1.0:
        f *= 255.0
        notices.append("float image in 0..1 scaled to 0..255")
    if f.ndim == 3 and f.shape[2] == 1:
        f = f[:, :, 0]
    elif f.ndim == 3 and f.shape[2] in (3, 4):
        rgb = f[:, :, :3]
        if f.shape[2] == 4:
            alpha = np.clip(f[:, :, 3:] / 255.0, 0.0, 1.0)
            rgb = rgb * alpha + 255.0 * (1.0 - alpha)
            notices.append("transparent pixels composited over white")
        f = rgb @ np.array([0.299, 0.587, 0.114])
        notices.append("colour array converted to grayscale")
    if f.ndim != 2:
        raise InputFormatError(f"watermark array must be (h, w) or (h, w, 3|4), got {a.shape}")
    if f.min() < 0 or f.max() > 255:
        notices.append(f"values {f.min():g}..{f.max():g} clipped to 0..255")
    return f


def load_watermark(path_or_array, max_size: int | None = DEFAULT_MAX_SIZE):
    """Load a watermark as a ``2^k`` square grayscale image.

    Parameters
    ----------
    path_or_array : str, os.PathLike, PIL.Image.Image or array_like
        An image file, or an (h, w) / (h, w, 3|4) array (integers 0..255, or floats in 0..1).
    max_size : int or None
        Downscale (aspect kept) when a side exceeds this power of two; None keeps any size.

    Returns
    -------
    image : (s, s) uint8 with s = 2^k
    notices : list[str]
        One line per change made to the input (empty when it was used as is).
    """
    image, notices, _ = load_watermark_given(path_or_array, max_size)
    return image, notices


def load_watermark_given(path_or_array, max_size: int | None = DEFAULT_MAX_SIZE) -> tuple:
    """``(image (s, s) uint8, notices, (width, height))``: :func:`load_watermark`'s image and notices, and the size
    of the image as given, before it was made a square (a :class:`~pmwm_codec.watermark.codec.CapacityError`
    names it so: :meth:`~pmwm_codec.watermark.codec.CapacityError.as_given`)."""
    gray, notices = read_watermark(path_or_array)
    image, made = square_watermark(gray, max_size)
    return image, notices + made, gray.shape[::-1]


def read_watermark(path_or_array) -> tuple:
    """``(gray (h, w) uint8, notices)``: the image :func:`load_watermark` takes, as given (grayscale, 0..255),
    before it is made a ``2^k`` square (:func:`square_watermark`)."""
    notices: list[str] = []
    if isinstance(path_or_array, Image.Image):
        gray = _to_gray(path_or_array, notices)
    elif isinstance(path_or_array, (str, bytes, os.PathLike)):
        img, name = _open(path_or_array)
        if img.width == 0 or img.height == 0:
            raise InputFormatError(f"{name}: image is empty")
        gray = _to_gray(img, notices)
    else:
        gray = _array_to_gray(path_or_array, notices)
    if gray.size == 0:
        raise InputFormatError("watermark image is empty")
    return np.clip(np.rint(gray), 0, 255).astype(np.uint8), notices


def square_watermark(gray: np.ndarray, max_size: int | None = DEFAULT_MAX_SIZE) -> tuple:
    """``(image (s, s) uint8, notices)``: ``gray`` (h, w) uint8 downscaled (aspect kept) when a side exceeds
    ``max_size``, then padded to the next ``2^k`` square (module docstring), one notice per change."""
    notices: list[str] = []
    h, w = gray.shape
    if max_size is not None:
        if max_size < 1 or max_size & (max_size - 1):
            raise ValueError(f"max_size must be a power of two, got {max_size}")
        if max(h, w) > max_size:
            f = max_size / max(h, w)
            nw, nh = max(1, round(w * f)), max(1, round(h * f))
            gray = np.asarray(Image.fromarray(gray).resize((nw, nh), Image.LANCZOS))
            notices.append(f"watermark {w}x{h} downscaled to {nw}x{nh} (max side {max_size})")
            h, w = nh, nw

    s = _next_pow2(max(h, w))
    if (h, w) != (s, s):
        border = np.concatenate([gray[0], gray[-1], gray[:, 0], gray[:, -1]])
        value = int(np.median(border))
        out = np.full((s, s), value, dtype=np.uint8)
        top, left = (s - h) // 2, (s - w) // 2
        out[top : top + h, left : left + w] = gray
        notices.append(f"watermark {w}x{h} padded to {s}x{s} (centred, border value {value})")
        gray = out
    return np.ascontiguousarray(gray), notices


def gray_image(image) -> Image.Image:
    """A Pillow grayscale image of an (h, w) uint8 (or 0..255 numeric, clipped) array."""
    a = np.asarray(image)
    if a.ndim != 2 or a.size == 0:
        raise ValueError(f"expected a non-empty 2-D image, got shape {a.shape}")
    if a.dtype != np.uint8:
        a = np.clip(np.rint(a.astype(np.float64)), 0, 255).astype(np.uint8)
    return Image.fromarray(a, mode="L")


def save_png(path, image) -> None:
    """Write an (h, w) uint8 (or 0..255 numeric, clipped) image as a grayscale PNG."""
    write_image(path, gray_image(image))


def png_bytes(image: Image.Image) -> bytes:
    """A Pillow ``image`` encoded as PNG."""
    buf = io.BytesIO()
    image.save(buf, format="PNG")
    return buf.getvalue()


def write_image(path, image: Image.Image) -> None:
    """Write a Pillow ``image`` as a PNG at ``path``, whole or not at all (an interrupted run leaves no cut file);
    OptionError naming ``path`` when it cannot be written."""
    from ..atomic import write_atomic

    try:
        write_atomic(os.fspath(path), [png_bytes(image)])
    except OSError as exc:
        raise OptionError(f"{os.fspath(path)}: cannot write PNG ({exc.strerror or exc})") from None


def make_text_watermark(text: str, size: int = 64) -> np.ndarray:
    """Dark ``text`` on a white square, as large as fits: (size, size) uint8.

    Uses Pillow's default font; lines split on ``\\n``.  ``size`` must be a power of two.
    """
    if size < 8 or size & (size - 1):
        raise ValueError(f"size must be a power of two >= 8, got {size}")
    font = ImageFont.load_default()
    probe = ImageDraw.Draw(Image.new("L", (1, 1)))
    left, top, right, bottom = probe.multiline_textbbox((0, 0), text or " ", font=font)
    tw, th = max(1, right - left), max(1, bottom - top)
    glyphs = Image.new("L", (tw + 2, th + 2), 255)
    ImageDraw.Draw(glyphs).multiline_text((1 - left, 1 - top), text, fill=0, font=font)
    margin = max(2, size // 16)
    f = min((size - 2 * margin) / glyphs.width, (size - 2 * margin) / glyphs.height)
    nw, nh = max(1, int(glyphs.width * f)), max(1, int(glyphs.height * f))
    glyphs = glyphs.resize((nw, nh), Image.LANCZOS)
    canvas = Image.new("L", (size, size), 255)
    canvas.paste(glyphs, ((size - nw) // 2, (size - nh) // 2))
    return np.asarray(canvas, dtype=np.uint8).copy()
