"""Verification: from codes read at each chunk boundary to NC, PSNR and a verdict.

The verdict is a hypothesis test on the *codes*, not on the picture.  With the
key and the reference watermark the verifier knows the code every carrier
should hold.  If the mesh does not carry this mark (another key, an unmarked
mesh, a mesh from elsewhere), each code read matches by chance with
probability ``p0 = 2**-bits`` (codes are whitened by the key in exact mode and
the bins are uniform).  The number of matches among ``n`` carriers read is then
Binomial(n, p0).  The verdict:

* ``authentic`` — at least :data:`MATCH_RATE` of the codes match *and* the
  chance of that many matches under the null is below :data:`ALPHA`;
* ``inconclusive`` — fewer than :data:`MIN_CARRIERS` codes read, or more
  matches than chance explains but fewer than :data:`MATCH_RATE` (a damaged mark);
* ``not-authentic`` — otherwise, and whenever the reference image cannot be the
  embedded one (another size, or coefficients that do not fit the file's public
  bit layout).

``ALPHA`` bounds the false-positive probability of an ``authentic`` verdict
per verification; ``tools/bench_watermark.py`` measures the rate over many
wrong keys and unmarked meshes (see BENCHMARKS.md).
"""

from __future__ import annotations

import numpy as np
from scipy.stats import binom

from . import codec as wm
from . import haar
from .metrics import centered_nc, nc, psnr
from .payload import BitLayout, pack, repeat_to_capacity, symbols

MATCH_RATE = 0.8
ALPHA = 1e-9
MIN_CARRIERS = 32
VERDICTS = ("authentic", "not-authentic", "inconclusive")


def verdict(matches: int, read: int, bits: int) -> str:
    """``authentic`` | ``not-authentic`` | ``inconclusive`` for ``matches`` of ``read`` codes."""
    if read < MIN_CARRIERS:
        return "inconclusive"
    p0 = 2.0 ** -bits
    tail = float(binom.sf(matches - 1, read, p0))
    if tail < ALPHA and matches >= MATCH_RATE * read:
        return "authentic"
    if tail < ALPHA:
        return "inconclusive"
    return "not-authentic"


class Verifier:
    """Collects codes batch by batch (an :class:`~.codec.Extractor`) and scores them.

    ``reference`` (s, s) uint8 is the original watermark (None: no scores).
    """

    def __init__(self, params: wm.WatermarkParams, key, nbar: float, reference=None):
        self.params = params
        self.extractor = wm.Extractor(params, key, nbar)
        self.reference = None if reference is None else np.asarray(reference, np.uint8)
        self.expected = None
        #: True when the reference cannot be what the file carries (other size or bit layout)
        self.mismatch = False
        if self.reference is not None:
            self.expected = expected_codes(self.reference, key, params)
            self.mismatch = self.expected is None

    def add(self, batch_index: int, points: np.ndarray, centroid: np.ndarray, nbar=None, scale=None) -> None:
        self.extractor.add(batch_index, np.asarray(points, np.float64), centroid, nbar, scale)

    def matches(self) -> tuple[int, int]:
        """``(codes matching the reference, codes read)`` so far."""
        got = self.extractor.received >= 0
        read = int(got.sum())
        if self.expected is None:
            return 0, read
        return int(np.count_nonzero(self.extractor.received[got] == self.expected[got])), read

    def verdict(self) -> str:
        if self.mismatch:
            return "not-authentic"
        if self.expected is None:
            return "inconclusive"
        m, n = self.matches()
        return verdict(m, n, self.params.bits)

    def fill(self, result) -> None:
        """Put the partial watermark and its scores into a PartialResult."""
        img, count = self.extractor.image()
        result.watermark = img
        result.coefficients = int(count)
        m, n = self.matches()
        result.carriers_read = n
        if self.reference is not None and self.reference.shape == img.shape:
            result.nc = float(nc(self.reference.astype(np.float64), img.astype(np.float64)))
            result.psnr_db = float(psnr(self.reference, img))
            result.centered_nc = float(centered_nc(self.reference.astype(np.float64), img.astype(np.float64)))
            result.code_match = (m / n) if n else None


def expected_codes(reference: np.ndarray, key, params: wm.WatermarkParams):
    """(carriers,) int64 codes the carriers hold if ``reference`` was embedded with ``key``; None if impossible."""
    if reference.shape != (params.size, params.size):
        return None
    try:
        p2, codes = wm.plan(reference, key, params.carriers, mode=params.mode, bits=params.bits)
    except (wm.CapacityError, ValueError):
        return None
    if params.mode == "exact" and p2.layout != params.layout:
        # pack the reference with the file's own layout; if it does not fit, it is not the mark
        layout = BitLayout.from_config(params.layout)
        stream = haar.to_stream(haar.forward_int(reference, params.levels), params.levels)
        try:
            message = pack(stream, layout)
        except ValueError:
            return None
        cycled = repeat_to_capacity(message, params.bits * params.carriers) ^ key.bits(0, params.bits * params.carriers)
        codes = symbols(cycled, params.bits)
    return codes
