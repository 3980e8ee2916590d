"""Watermark side of the codec: image -> Haar stream -> bits -> symbols, keys, metrics.

* :mod:`.haar` — integer (lifting) and float Haar, the low-to-high band stream;
* :mod:`.image` — loading/normalising watermark images, PNG output, a text watermark;
* :mod:`.payload` — bit layout, packing, symbols, repetition and voting;
* :mod:`.key` — the secret key and its keyed permutations / whitening bits;
* :mod:`.metrics` — PSNR, NC, BER (mesh distortion: :mod:`pmwm_codec.distortion`).
"""

from .haar import (
    Band,
    band_order,
    bands,
    forward_float,
    forward_int,
    from_stream,
    inverse_float,
    inverse_int,
    reconstruct_prefix,
    to_stream,
)
from .image import load_watermark, make_text_watermark, save_png
from .key import WatermarkKey
from .metrics import ber, centered_nc, nc, psnr
from .payload import BitLayout, bits_from_symbols, pack, repeat_to_capacity, symbols, unpack, vote

__all__ = [
    "Band",
    "band_order",
    "bands",
    "forward_float",
    "forward_int",
    "from_stream",
    "inverse_float",
    "inverse_int",
    "reconstruct_prefix",
    "to_stream",
    "load_watermark",
    "make_text_watermark",
    "save_png",
    "WatermarkKey",
    "ber",
    "centered_nc",
    "nc",
    "psnr",
    "BitLayout",
    "bits_from_symbols",
    "pack",
    "repeat_to_capacity",
    "symbols",
    "unpack",
    "vote",
]
