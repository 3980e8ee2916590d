"""The verifier's running counts (:class:`~pmwm_codec.watermark.verify.Tally`) give at every step what
counting every code read from scratch gives: the same matches, errors, inconsistent carriers, votes, image
and verdict, whatever order the codes come in and when a slot is read again."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.key import WatermarkKey
from pmwm_codec.watermark.payload import bits_from_symbols, vote
from pmwm_codec.watermark.verify import ALPHA, Verifier, chance_tail, code_ber, verdict


def _verifier(mode: str, seed: int, carriers: int, reference: bool) -> Verifier:
    rng = np.random.default_rng(seed)
    key = WatermarkKey.generate(rng=rng)
    image = rng.integers(0, 256, (8, 8)).astype(np.uint8)
    params, _ = wm.plan(image, key, carriers, mode=mode)
    return Verifier(params, key, 1.0, image if reference else None)


def _write(v: Verifier, slots: np.ndarray, rng: np.random.Generator, honest: float) -> None:
    """Write codes into ``slots`` as :meth:`~pmwm_codec.watermark.codec.Extractor.add` does: column 0 the code as
    read, the other columns ambiguous readings or -1; a share ``honest`` of them the expected code, in column 0 or
    among the readings, the rest random."""
    ext, b = v.extractor, v.params.bits
    rows = np.full((len(slots), ext.alternates.shape[1]), -1, np.int64)
    rows[:, 0] = rng.integers(0, 1 << b, len(slots))
    extra = rng.integers(0, 3, len(slots))  # ambiguous readings of each
    for i in range(len(slots)):
        rows[i, 1 : 1 + extra[i]] = rng.integers(0, 1 << b, extra[i])
    if v.expected is not None:
        good = rng.random(len(slots)) < honest
        where = np.where(rng.random(len(slots)) < 0.8, 0, 1 + rng.integers(0, 2, len(slots)))
        rows[good, where[good]] = v.expected[slots[good]]
    rows[rng.random(len(slots)) < 0.05] = -1  # a carrier that could not be read (written unread: no reading at all)
    ext.alternates[slots] = rows
    ext.written.append(slots)


def _from_scratch(v: Verifier) -> dict:
    """What the verifier reported before it kept counts: every number from every code read."""
    ext, expected, bits = v.extractor, v.expected, v.params.bits
    received = ext.received
    got = received >= 0
    n = int(got.sum())
    if expected is None:
        return {"read": n}
    m = int(np.count_nonzero(received[got] == expected[got]))
    agree = (ext.alternates == expected[:, None]).any(axis=1)
    bad = int((got & ~agree).sum())
    agreeing = n > 0 and chance_tail(m, n, bits) < ALPHA
    if agreeing:
        received = np.where(agree, expected, received)
    image, count = ext.image(received)
    return {"read": n, "matches": m, "inconsistent": bad, "image": image, "count": count,
            "ber": code_ber(received, expected, bits),
            "verdict": verdict(m, n, bits, mismatched=bad, bound=bool(v.params.binding))}


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**16), mode=st.sampled_from(["exact", "paper"]), honest=st.sampled_from([0.0, 0.6, 1.0]),
       steps=st.integers(1, 8), reference=st.booleans())
def test_running_counts_equal_counting_every_code_again(seed, mode, honest, steps, reference):
    carriers = 300
    v = _verifier(mode, seed, carriers, reference)
    rng = np.random.default_rng(seed + 1)
    for _ in range(steps):
        # a batch's slots, sometimes ones read before (a reader may read a slot again)
        slots = np.unique(rng.integers(0, carriers, rng.integers(1, 80)))
        _write(v, slots, rng, honest)
        want = _from_scratch(v)
        est = v.estimate()
        t = v.tally
        assert t.read == want["read"] == est.carriers_read
        if not reference:
            assert est.verdict == "inconclusive" and est.ber is None
            continue
        assert (t.matches, t.inconsistent) == (want["matches"], want["inconsistent"])
        assert np.array_equal(est.watermark, want["image"]) and est.coefficients == want["count"]
        assert est.ber == want["ber"] and est.inconsistent == want["inconsistent"] and est.verdict == want["verdict"]
        assert v.verdict() == want["verdict"] and v.matches() == (want["matches"], want["read"])


@pytest.mark.parametrize("agreeing", [False, True])
def test_the_votes_are_the_message_bits_voted_from_every_code(agreeing):
    v = _verifier("exact", 5, 300, True)
    rng = np.random.default_rng(9)
    for _ in range(4):
        _write(v, np.unique(rng.integers(0, 300, 60)), rng, 0.7)
    t = v.counted()
    ext, b, c = v.extractor, v.params.bits, v.params.carriers
    received = ext.received
    if agreeing:
        received = np.where((ext.alternates == v.expected[:, None]).any(axis=1), v.expected, received)
    raw = bits_from_symbols(np.where(received >= 0, received, 0), b, b * c) ^ v.extractor.key.bits(0, b * c)
    bits, known = vote(raw, np.repeat(received >= 0, b), v.params.codes)
    got_bits, got_known = t.voted(agreeing)
    assert np.array_equal(got_bits, bits) and np.array_equal(got_known, known)
    raw = ext.received
    assert t.errors == sum(bin(int(x)).count("1") for x in (raw ^ v.expected)[raw >= 0])


def test_a_slot_read_again_counts_once_with_its_new_code():
    v = _verifier("exact", 3, 300, True)
    slots = np.arange(50)
    ext = v.extractor
    ext.alternates[slots, 0] = v.expected[slots]
    ext.written.append(slots)
    assert v.matches() == (50, 50)
    ext.alternates[slots[:10], 0] = (v.expected[slots[:10]] + 1) % (1 << v.params.bits)
    ext.written.append(slots[:10])
    assert v.matches() == (40, 50) and v.tally.inconsistent == 10
