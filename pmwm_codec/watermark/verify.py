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

from dataclasses import dataclass

import numpy as np
from scipy.stats import binom

from . import codec as wm
from . import haar
from .metrics import centered_nc, nc, psnr
from .payload import BitLayout, pack, repeat_to_capacity, symbols

MATCH_RATE = 0.8
ALPHA = 1e-9
MIN_CARRIERS = 32


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

    ``reference`` (s, s) uint8 is the original watermark (None: no scores);
    ``nbar`` the default reference length of :meth:`add` (None when every batch
    brings its own, as :meth:`add_carriers` does).
    """

    def __init__(self, params: wm.WatermarkParams, key, nbar: float | None, reference=None):
        self.params = params
        self.extractor = wm.Extractor(params, key, nbar)
        self.reference = None if reference is None else np.asarray(reference, np.uint8)
        self.expected = None
        #: True when the reference cannot be what the file carries (other size or bit layout)
        self.mismatch = False
        if self.reference is not None:
            self.expected = expected_codes(self.reference, key, params)
            self.mismatch = self.expected is None

    def add(self, batch_index: int, points: np.ndarray, centroid: np.ndarray, nbar=None, scale=None,
            known=None) -> None:
        """Read the codes of one batch (see :meth:`.codec.Extractor.add`)."""
        self.extractor.add(batch_index, np.asarray(points, np.float64), centroid, nbar, scale, known)

    def add_carriers(self, carriers) -> None:
        """Read one :class:`~pmwm_codec.stream.replay.Carriers` batch."""
        self.add(carriers.batch, carriers.points, carriers.centroid, carriers.nbar, carriers.scale, carriers.known)

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

    def estimate(self) -> "WatermarkEstimate":
        """The partial watermark so far, scored against the reference (one scoring for every reader)."""
        img, count = self.extractor.image()
        m, n = self.matches()
        out = WatermarkEstimate(img, int(count), n, self.verdict(), self.params.carriers)
        if self.reference is not None and self.reference.shape == img.shape:
            r, x = self.reference.astype(np.float64), img.astype(np.float64)
            out.nc = float(nc(r, x))
            out.psnr_db = float(psnr(self.reference, img))
            out.centered_nc = float(centered_nc(r, x))
            out.bit_exact = bool(np.array_equal(img, self.reference))
        if self.expected is not None:
            out.code_match = (m / n) if n else None
            out.ber = code_ber(self.extractor.received, self.expected, self.params.bits)
        return out


@dataclass
class WatermarkEstimate:
    """The watermark as read so far.

    ``watermark`` (s, s) uint8 the partial image; ``coefficients`` how many
    stream coefficients it used; ``carriers_read`` of ``carriers_total``;
    ``verdict`` (see :func:`verdict`); with a reference image: ``nc``,
    ``psnr_db`` (inf when bit-exact), ``centered_nc``, ``bit_exact``; with the
    codes the reference implies: ``code_match`` (fraction of codes read that
    match) and ``ber`` (bit error rate of the codes read).
    """

    watermark: np.ndarray
    coefficients: int
    carriers_read: int
    verdict: str
    carriers_total: int
    nc: float | None = None
    psnr_db: float | None = None
    centered_nc: float | None = None
    bit_exact: bool = False
    code_match: float | None = None
    ber: float | None = None


def code_ber(received: np.ndarray, expected: np.ndarray, bits: int) -> float | None:
    """Bit error rate of the codes read (``received >= 0``) against ``expected``; None if none read."""
    got = received >= 0
    if expected is None or not got.any():
        return None
    diff = (received[got] ^ expected[got]).astype(np.uint64)
    errors = sum(int(np.count_nonzero((diff >> np.uint64(b)) & np.uint64(1))) for b in range(bits))
    return errors / (bits * int(got.sum()))


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
