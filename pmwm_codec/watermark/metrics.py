"""Watermark similarity measures.

Watermark (arrays of any equal shape, compared as float64):

* :func:`psnr` — ``10 log10(peak^2 / MSE)``, ``inf`` for identical inputs;
* :func:`nc` — the paper's Hsu-Wu normalised correlation ``sum(w w') / sum(w^2)``; 1 for a
  perfect match, but high even for unrelated positive images;
* :func:`centered_nc` — mean-removed (Pearson) correlation in ``[-1, 1]``, 0 when either
  input is constant; the honest number next to :func:`nc`;
* :func:`ber` — fraction of differing bits.

Mesh distortion (RMS, PSNR, Hausdorff) lives in :mod:`pmwm_codec.distortion`.
"""

from __future__ import annotations

import numpy as np

__all__ = ["psnr", "nc", "centered_nc", "ber"]


def _pair(a, b) -> tuple[np.ndarray, np.ndarray]:
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        raise ValueError(f"shapes differ: {a.shape} vs {b.shape}")
    return a, b


def psnr(a, b, peak: float = 255.0) -> float:
    """PSNR in dB of ``b`` against ``a``; ``inf`` when identical."""
    a, b = _pair(a, b)
    mse = float(np.mean((a - b) ** 2)) if a.size else 0.0
    return float("inf") if mse == 0.0 else float(10.0 * np.log10(peak * peak / mse))


def nc(w, w2) -> float:
    """Hsu-Wu normalised correlation ``sum(w * w2) / sum(w ** 2)`` (w the original).

    When ``w`` is all zero: 1.0 if ``w2`` is too, else 0.0.
    """
    w, w2 = _pair(w, w2)
    den = float(np.sum(w * w))
    if den == 0.0:
        return 1.0 if not np.any(w2) else 0.0
    return float(np.sum(w * w2) / den)


def centered_nc(w, w2) -> float:
    """Mean-removed correlation (Pearson) in [-1, 1]; 0.0 if either input is constant."""
    w, w2 = _pair(w, w2)
    x, y = w - w.mean() if w.size else w, w2 - w2.mean() if w2.size else w2
    den = float(np.sqrt(np.sum(x * x) * np.sum(y * y)))
    if den == 0.0:
        return 0.0
    return float(np.clip(np.sum(x * y) / den, -1.0, 1.0))


def ber(bits_a, bits_b) -> float:
    """Bit error rate: fraction of positions where the bit arrays differ (0.0 if empty)."""
    a, b = np.asarray(bits_a), np.asarray(bits_b)
    if a.shape != b.shape:
        raise ValueError(f"shapes differ: {a.shape} vs {b.shape}")
    return float(np.mean(a.astype(bool) != b.astype(bool))) if a.size else 0.0
