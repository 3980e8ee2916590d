"""Verification: from codes read at each chunk boundary to NC, PSNR, a verdict and a tamper map.

With the key and the reference watermark the verifier knows the code every
carrier should hold: its message symbol plus, for a bound mark (``binding``
``ring-v2``), a keyed pseudo-random offset of its stream slot and of the
quantized shape of its ring (:func:`~.codec.binding_offsets`).  A code read is
*consistent* when it equals the expected code under the ring as read or one of
its ambiguous readings (a descriptor value within :data:`~.codec.RING_EPS` of a
bin boundary).  Two counts decide:

* ``matches``: codes equal to the expected code under the ring *as read*.  If
  the mesh does not carry this mark (another key, an unmarked mesh, a mesh from
  elsewhere), each matches by chance with probability ``p0 = 2**-bits`` (codes
  are whitened by the key, the bins are uniform), so ``matches`` is then
  Binomial(n, p0) over the ``n`` carriers read;
* ``mismatched``: carriers read whose code is consistent with no reading of the ring.

The verdict:

* ``inconclusive`` -- fewer than :data:`MIN_CARRIERS` codes read (even one-bit
  codes then pass the test below only when all of them match: ``2**-32 < ALPHA``);
* ``not-authentic`` -- ``matches`` within chance (binomial tail ``>= ALPHA``), or
  the reference image cannot be the embedded one (another size than the file's
  mark, or coefficients that do not fit the file's public bit layout);
* ``tampered`` -- the mark is there (tail ``< ALPHA``) but at least one carrier
  is inconsistent, or the mesh holds vertices the reference does not explain
  (``foreign``, a graft);
* ``authentic`` -- the mark is there and every carrier read is consistent (no
  tolerance: our transport keeps every code bit-exactly, and float32 storage or a
  similarity moves a ring value only across a boundary it lies within
  ``RING_EPS`` of) and the mark is bound; a legacy file (no ``binding``) is
  ``inconclusive`` instead, since its codes can be transplanted without the key.

``ALPHA`` bounds the false-positive probability of a ``tampered`` or ``authentic``
verdict per verification; ``tools/bench_watermark.py`` measures the rate over
many wrong keys and unmarked meshes (see BENCHMARKS.md).  :meth:`Verifier.tamper`
maps the inconsistent carriers to vertices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import codec as wm
from . import haar
from .metrics import centered_nc, nc, psnr
from .payload import BitLayout, bits_from_symbols, pack, repeat_to_capacity, symbols

ALPHA = 1e-9
MIN_CARRIERS = 32
#: tamper map: share of a vertex's carriers that must fail (own code failing / at least two failing)
FLAG_OWN = 0.25
FLAG_SHARED = 0.3
VERDICTS = ("authentic", "tampered", "not-authentic", "inconclusive")


def chance_tail(matches: int, read: int, bits: int) -> float:
    """P(at least ``matches`` of ``read`` codes of ``bits`` bits match by chance): the binomial tail
    with success probability 2**-bits: ``scipy.special.bdtrc``, imported on first use (``pmw encode`` does
    not load it; ``scipy.stats``, whose ``binom.sf`` computes the same tail, took ~1.1 s to import)."""
    if matches <= 0:
        return 1.0
    if matches > read:
        return 0.0
    from scipy.special import bdtrc

    return float(bdtrc(matches - 1, read, 2.0**-bits))


def verdict(matches: int, read: int, bits: int, *, mismatched: int | None = None, foreign: bool = False,
            bound: bool = True) -> str:
    """One of :data:`VERDICTS` (module docstring) for ``matches`` of ``read`` codes.

    ``mismatched``: carriers consistent with no reading of their ring (default
    ``read - matches``); ``foreign``: the mesh holds vertices the reference does not
    explain; ``bound``: the mark has a keyed binding (False: a legacy mark).
    """
    if read < MIN_CARRIERS:
        return "inconclusive"
    if chance_tail(matches, read, bits) >= ALPHA:
        return "not-authentic"
    if (read - matches if mismatched is None else mismatched) > 0 or foreign:
        return "tampered"
    return "authentic" if bound else "inconclusive"


class Verifier:
    """Collects codes batch by batch (an :class:`~.codec.Extractor`) and scores them.

    ``reference`` (s, s) uint8 is the original watermark (None: no scores); one of another size than the
    key's own image is refused (OptionError, :meth:`~.key.WatermarkKey.check_reference`);
    ``nbar`` the default reference length of :meth:`add` (None when every batch
    brings its own, as :meth:`add_carriers` does).  ``foreign`` (set by the caller):
    the checked mesh holds vertices the reference does not explain.
    """

    def __init__(self, params: wm.WatermarkParams, key, nbar: float | None, reference=None):
        self.params = params
        self.extractor = wm.Extractor(params, key, nbar)
        self.reference = None if reference is None else np.asarray(reference, np.uint8)
        self.expected = None
        self.foreign = False
        #: per batch read: (primitive, code slots (r,), new vertex ids (r,), ring descriptor, batch rows (r,))
        self.support: list = []
        #: True when the reference cannot be what the file carries (other size or bit layout)
        self.mismatch = False
        if self.reference is not None:
            key.check_reference(self.reference)  # an image of another size than the key's: OptionError
            self.expected = expected_codes(self.reference, key, params)
            self.mismatch = self.expected is None
        self.tally = Tally(params, key, self.expected)
        self._last_image = None  # (agreeing, known bits, image, count) of the last exact-mode estimate

    def add(self, batch_index: int, points: np.ndarray, centroid: np.ndarray, nbar=None, scale=None,
            known=None, descriptor=None, twin=None):
        """Read the codes of one batch (see :meth:`.codec.Extractor.add`)."""
        return self.extractor.add(batch_index, np.asarray(points, np.float64), centroid, nbar, scale, known,
                                  descriptor, twin)

    def add_carriers(self, carriers) -> None:
        """Read one :class:`~pmwm_codec.stream.replay.Carriers` batch."""
        desc = carriers.descriptor if self.params.binding else None
        slots, rows = self.add(carriers.batch, carriers.points, carriers.centroid, carriers.nbar, carriers.scale,
                               carriers.known, desc, carriers.twin)
        if carriers.vertices is not None:
            self.support.append((carriers.primitive, slots, carriers.vertices[rows], desc, rows))

    def counted(self) -> "Tally":
        """The :class:`Tally`, brought up to date with the codes read since it was last asked for."""
        self.tally.update(self.extractor.take_written(), self.extractor.alternates)
        return self.tally

    def matches(self) -> tuple[int, int]:
        """``(codes matching the reference under their ring as read, codes read)`` so far."""
        t = self.counted()
        return t.matches, t.read

    def inconsistent(self) -> np.ndarray:
        """(carriers,) bool: read, and consistent with no reading of the ring (False without a reference)."""
        alt = self.extractor.alternates
        if self.expected is None:
            return np.zeros(len(alt), bool)
        ok = (alt == self.expected[:, None]).any(axis=1)
        return (alt[:, 0] >= 0) & ~ok

    def verdict(self) -> str:
        if self.mismatch:
            return "not-authentic"
        if self.expected is None:
            return "inconclusive"
        t = self.counted()
        return verdict(t.matches, t.read, self.params.bits, mismatched=t.inconsistent, foreign=self.foreign,
                       bound=bool(self.params.binding))

    def tamper(self, offsets=None) -> np.ndarray:
        """Sorted (f,) int64 ids of the vertices whose carrier codes no longer read.

        A vertex is read by its own carrier (if it is one) and by every carrier whose ring
        holds it.  It is flagged when its own code fails and at least :data:`FLAG_OWN` of
        the carriers reading it fail, or when at least two fail and they are at least
        :data:`FLAG_SHARED` of them: a moved vertex fails each carrier reading it with
        probability ``1 - 2**-bits``, an untouched neighbour of an edit only those that
        also read a moved vertex.  ``offsets`` (per primitive) turns primitive-local ids
        into ids of the concatenated mesh.
        """
        bad = self.inconsistent()
        ids, fails, own = [], [], []
        for primitive, slots, vertices, desc, rows in self.support:
            shift = 0 if offsets is None else int(offsets[primitive])
            hit = bad[slots]
            ids.append(vertices + shift)
            fails.append(hit)
            own.append(np.ones(len(rows), bool))
            if desc is not None and len(rows):
                first, size = desc.starts[rows] + 1, desc.starts[rows + 1] - desc.starts[rows] - 1
                at = np.repeat(first - np.cumsum(size) + size, size) + np.arange(int(size.sum()))
                ids.append(desc.vertex[at] + shift)
                fails.append(np.repeat(hit, size))
                own.append(np.zeros(len(at), bool))
        if not ids:
            return np.zeros(0, np.int64)
        ids, fails, own = np.concatenate(ids), np.concatenate(fails), np.concatenate(own)
        n = int(ids.max()) + 1 if len(ids) else 0
        read = np.bincount(ids, minlength=n)
        failed = np.bincount(ids, weights=fails, minlength=n)
        own_failed = np.bincount(ids[own & fails], minlength=n) > 0
        flag = (own_failed & (failed >= FLAG_OWN * read)) | ((failed >= 2) & (failed >= FLAG_SHARED * read))
        return np.flatnonzero(flag).astype(np.int64)

    def estimate(self) -> "WatermarkEstimate":
        """The partial watermark so far, scored against the reference (one scoring for every reader).

        Its cost follows the codes read since the last estimate (:class:`Tally`), not every code read, so that a
        stream's estimate at each of its chunk boundaries does not grow with the file; the image is rebuilt
        only when the voted message it comes from changed (paper mode: from every code, each time)."""
        t = self.counted()
        m, n = t.matches, t.read
        # the mark is there: a ring value on a boundary takes the reading the expected code agrees with.  Only
        # then -- a wrong key or an unmarked mesh would otherwise be pulled toward the reference image through
        # its ambiguous carriers.
        agreeing = self.expected is not None and n > 0 and chance_tail(m, n, self.params.bits) < ALPHA
        if self.params.mode == "exact":
            img, count = self._exact_image(t, agreeing)
        else:
            received = self.extractor.received
            if agreeing:
                received = np.where(t.agree, self.expected, received)
            img, count = self.extractor.image(received)
        out = WatermarkEstimate(img, int(count), n, self.verdict(), self.params.carriers)
        if self.reference is not None and self.reference.shape == img.shape:
            r, x = self.reference.astype(np.float64), img.astype(np.float64)
            out.nc = float(nc(r, x))
            out.psnr_db = float(psnr(self.reference, img))
            out.centered_nc = float(centered_nc(r, x))
            out.bit_exact = bool(np.array_equal(img, self.reference))
        if self.expected is not None:
            out.code_match = (m / n) if n else None
            out.ber = (t.errors_disagreeing if agreeing else t.errors) / (self.params.bits * n) if n else None
            out.inconsistent = t.inconsistent
        return out

    def _exact_image(self, t: "Tally", agreeing: bool) -> tuple[np.ndarray, int]:
        """The exact mode's ``(image, coefficients)`` from the tally's votes (``agreeing``: the votes with
        every carrier that agrees with its expected code counted as that code), the last image again when
        the known part of the voted message is what it was (a copy: each estimate owns its image)."""
        bits, known = t.voted(agreeing)
        prefix = wm.known_prefix(known)
        last = self._last_image
        if last is not None and last[0] == agreeing and np.array_equal(last[1], bits[:prefix]):
            return last[2].copy(), last[3]
        values, count = wm.voted_prefix(bits, known, self.extractor.layout)
        img = self.extractor.image_of(values)
        self._last_image = (agreeing, bits[:prefix].copy(), img, count)
        return img, count


class Tally:
    """Running counts over the code slots read, kept up to date slot by slot (:meth:`update` with the slots
    written since the last update), so that what a :class:`Verifier` reports at a stream's every chunk boundary
    costs what the boundary brought rather than every carrier again (a 445-chunk asset read each of its
    31,118 carriers at each boundary).

    Per slot (``(carriers,)`` arrays, as last counted): ``got`` bool read; ``match`` bool its code equals the
    expected one under its ring as read; ``agree`` bool some reading of its ring gives the expected code;
    ``err`` uint8 bits in which its code differs from the expected one.  Totals over the slots read:
    ``read``, ``matches``, ``inconsistent`` (read and agreeing under no reading), ``errors`` and
    ``errors_disagreeing`` (the bit errors of the slots that do not agree).  Exact mode also keeps the
    majority votes of the message bits (:func:`~.payload.vote`'s counts), with the codes as read and with every
    agreeing slot's code taken as the expected one (:meth:`voted`).  Without an expected code (no reference)
    only ``got`` and ``read`` mean anything.
    """

    def __init__(self, params: wm.WatermarkParams, key, expected: np.ndarray | None):
        c, self.bits = int(params.carriers), int(params.bits)
        self.expected = expected
        self.got, self.match, self.agree = (np.zeros(c, bool) for _ in range(3))
        self.err = np.zeros(c, np.uint8)  # at most ``bits`` (<= 16)
        self.read = self.matches = self.inconsistent = self.errors = self.errors_disagreeing = 0
        self.codes = int(params.codes) if params.mode == "exact" else 0
        if self.codes:
            self.whitening = key.bits(0, self.bits * c).reshape(c, self.bits)  # (carriers, bits) uint8
            self.votes = np.zeros((2, 2, self.codes), np.int64)  # [as read | agreeing as expected][zeros | ones]
            self.counted = np.full((2, c), -1, np.int32)  # the codes the votes hold for each slot (-1: none)

    def update(self, slots: np.ndarray, alternates: np.ndarray) -> None:
        """Count the slots ``slots`` (w,) int64 (distinct) again from ``alternates`` (carriers, A) int64
        (:class:`~.codec.Extractor`'s: column 0 the code as read, -1 unread)."""
        if len(slots) == 0:
            return
        self._count(slots, -1)
        code = alternates[slots, 0]
        got = code >= 0
        self.got[slots] = got
        if self.expected is not None:
            expected = self.expected[slots]
            self.match[slots] = got & (code == expected)
            self.agree[slots] = got & (alternates[slots] == expected[:, None]).any(axis=1)
            self.err[slots] = bit_errors(np.where(got, code, expected), expected, self.bits)
        if self.codes:
            agreeing = np.where(self.agree[slots], self.expected[slots], code) if self.expected is not None else code
            self.counted[:, slots] = np.where(got, np.stack([code, agreeing]), -1)
        self._count(slots, 1)

    def _count(self, slots: np.ndarray, sign: int) -> None:
        """Add (``sign`` 1) or take away (-1) the slots' part of every total, as last counted."""
        got = slots[self.got[slots]]
        disagree = got[~self.agree[got]]
        self.read += sign * len(got)
        if self.expected is not None:
            self.matches += sign * int(np.count_nonzero(self.match[got]))
            self.inconsistent += sign * len(disagree)
            self.errors += sign * int(self.err[got].sum(dtype=np.int64))
            self.errors_disagreeing += sign * int(self.err[disagree].sum(dtype=np.int64))
        if self.codes:
            b = self.bits
            position = (b * got[:, None] + np.arange(b)) % self.codes  # the message bit each code bit carries
            for variant in (0, 1):
                bits = bits_from_symbols(self.counted[variant, got], b, b * len(got)).reshape(-1, b) ^ self.whitening[got]
                np.add.at(self.votes[variant], (bits.ravel(), position.ravel()), sign)

    def voted(self, agreeing: bool) -> tuple[np.ndarray, np.ndarray]:
        """The voted message, :func:`~.payload.vote`'s ``(bits (codes,) uint8, known (codes,) bool)``, from the
        codes as read or (``agreeing``) with every agreeing slot's code taken as the expected one."""
        zeros, ones = self.votes[int(agreeing)]
        return (ones > zeros).astype(np.uint8), ones != zeros


@dataclass
class WatermarkEstimate:
    """The watermark as read so far.

    ``watermark`` (s, s) uint8 the partial image; ``coefficients`` how many
    stream coefficients it used; ``carriers_read`` of ``carriers_total``;
    ``verdict`` (see :func:`verdict`); with a reference image: ``nc``,
    ``psnr_db`` (inf when bit-exact), ``centered_nc``, ``bit_exact``; with the
    codes the reference implies: ``code_match`` (fraction of codes read that
    match), ``ber`` (bit error rate of the codes read, a ring on a boundary taking its agreeing
    reading when the mark is there, as for the image) and ``inconsistent`` (carriers
    whose code reads under no reading of their ring).
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
    inconsistent: int = 0


def image_note(verdict: str, bit_exact: bool, failing: int = 0, why: str = "") -> str | None:
    """The line that keeps the figures of a bit-exact image (NC 1, PSNR infinite) from reading as a match the
    ``verdict`` does not make (README, "NC and PSNR beside the verdict"); None when the verdict is
    ``authentic`` or the image is not bit-exact.

    The figures are of the image extracted, each message bit voted over its copies: ``failing`` codes that no
    longer read (the tamper map's carriers) are outvoted where a bit's other copies read, which many copies
    of 1-bit codes (a two-tone image's) always do, so a ``tampered`` mesh can still give the image whole.
    ``why``: what else keeps the verdict from ``authentic`` (the scene, bytes the key holder did not write)."""
    if verdict == "authentic" or not bit_exact:
        return None
    reasons = [f"{failing:,} code{'s' if failing != 1 else ''} that no longer read, outvoted by the other copies of "
               "their bits"] if failing else []
    reasons += [why] if why else []
    return (f"the image extracted is bit-exact (NC 1, PSNR inf) but the verdict is {verdict}"
            + (f" ({'; '.join(reasons)})" if reasons else "")
            + ": the figures describe the image read, not a match the verdict vouches for")


def code_ber(received: np.ndarray, expected: np.ndarray, bits: int) -> float | None:
    """Bit error rate of the codes read (``received >= 0``) against ``expected``; None if none read."""
    got = received >= 0
    if expected is None or not got.any():
        return None
    return int(bit_errors(received[got], expected[got], bits).sum()) / (bits * int(got.sum()))


def bit_errors(codes: np.ndarray, expected: np.ndarray, bits: int) -> np.ndarray:
    """(k,) uint8: in how many of their ``bits`` low bits the codes (k,) int64 (each read, >= 0) differ from
    ``expected`` (k,) int64."""
    diff = codes ^ expected
    return sum(((diff >> b) & 1).astype(np.uint8) for b in range(bits)) if bits else np.zeros(len(diff), np.uint8)


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
