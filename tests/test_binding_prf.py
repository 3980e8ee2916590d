"""The ring binding's keyed PRF (spec/watermark.md §5, ``binding: "ring-v2"``).

* the vectorized SipHash-2-4 (:func:`codec.siphash24`) equals a plain, byte-oriented transcription
  of the SipHash paper, which itself reproduces the paper's reference vectors (key 00..0f,
  message 00, 01, ..., n-1, for n = 0..63);
* :func:`codec.binding_offsets` equals the spec's formula computed carrier by carrier, including
  the ambiguous readings;
* a reader refuses a file naming a binding it does not know, with a named error.
"""

from __future__ import annotations

import io

import numpy as np
import pytest

from pmwm_codec import shapes
from pmwm_codec.errors import FormatError
from pmwm_codec.format import iter_events
from pmwm_codec.stream.encoder import encode_mesh
from pmwm_codec.stream.replay import Replay
from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.key import WatermarkKey

M64 = (1 << 64) - 1

#: SipHash-2-4 outputs (8 bytes, as the reference implementation writes them) for key 00 01 .. 0f and
#: message 00 01 .. (n-1), n = 0 .. 63: ``vectors_sip64`` of the reference code (veorq/SipHash, vectors.h).
PAPER_VECTORS = """
310e0edd47db6f72 fd67dc93c539f874 5a4fa9d909806c0d 2d7efbd796666785 b7877127e09427cf 8da699cd64557618
cee3fe586e46c9cb 37d1018bf50002ab 6224939a79f5f593 b0e4a90bdf82009e f3b9dd94c5bb5d7a a7ad6b22462fb3f4
fbe50e86bc8f1e75 903d84c02756ea14 eef27a8e90ca23f7 e545be4961ca29a1 db9bc2577fcc2a3f 9447be2cf5e99a69
9cd38d96f0b3c14b bd6179a71dc96dbb 98eea21af25cd6be c7673b2eb0cbf2d0 883ea3e395675393 c8ce5ccd8c030ca8
94af49f6c650adb8 eab8858ade92e1bc f315bb5bb835d817 adcf6b0763612e2f a5c91da7acaa4dde 716595876650a2a6
28ef495c53a387ad 42c341d8fa92d832 ce7cf2722f512771 e37859f94623f3a7 381205bb1ab0e012 ae97a10fd434e015
b4a31508beff4d31 81396229f0907902 4d0cf49ee5d4dcca 5c73336a76d8bf9a d0a704536ba93e0e 925958fcd6420cad
a915c29bc8067318 952b79f3bc0aa6d4 f21df2e41d4535f9 87577519048f53a9 10a56cf5dfcd9adb eb75095ccd986cd0
51a9cb9ecba312e6 96afadfc2ce666c7 72fe52975a4364ee 5a1645b276d592a1 b274cb8ebf87870a 6f9bb4203de7b381
eaecb2a30b22a87f 9924a43cc1315724 bd838d3aafbf8db7 0b1a2a3265d51aea 135079a3231ce660 932b2846e4d70666
e1915f5cb1eca46c f325965ca16d629f 575ff28e60381be5 724506eb4c328a95
""".split()
PAPER_KEY = bytes(range(16))


def _rotl(x: int, r: int) -> int:
    return ((x << r) | (x >> (64 - r))) & M64


def _sipround(v: list) -> None:
    v[0] = (v[0] + v[1]) & M64; v[1] = _rotl(v[1], 13); v[1] ^= v[0]; v[0] = _rotl(v[0], 32)  # noqa: E702
    v[2] = (v[2] + v[3]) & M64; v[3] = _rotl(v[3], 16); v[3] ^= v[2]  # noqa: E702
    v[0] = (v[0] + v[3]) & M64; v[3] = _rotl(v[3], 21); v[3] ^= v[0]  # noqa: E702
    v[2] = (v[2] + v[1]) & M64; v[1] = _rotl(v[1], 17); v[1] ^= v[2]; v[2] = _rotl(v[2], 32)  # noqa: E702


def siphash24_reference(key: bytes, message: bytes) -> int:
    """SipHash-2-4 of a byte string, transcribed from the paper one byte-oriented step at a time."""
    k0, k1 = int.from_bytes(key[:8], "little"), int.from_bytes(key[8:16], "little")
    v = [k0 ^ 0x736F6D6570736575, k1 ^ 0x646F72616E646F6D, k0 ^ 0x6C7967656E657261, k1 ^ 0x7465646279746573]
    whole = len(message) - len(message) % 8
    tail = message[whole:] + bytes(7 - len(message) % 8) + bytes([len(message) & 0xFF])
    for i in range(0, whole + 8, 8):
        m = int.from_bytes((message[i:i + 8] if i < whole else tail), "little")
        v[3] ^= m
        _sipround(v)
        _sipround(v)
        v[0] ^= m
    v[2] ^= 0xFF
    for _ in range(4):
        _sipround(v)
    return v[0] ^ v[1] ^ v[2] ^ v[3]


def test_the_reference_transcription_reproduces_the_paper_vectors():
    assert len(PAPER_VECTORS) == 64
    for n, want in enumerate(PAPER_VECTORS):
        assert siphash24_reference(PAPER_KEY, bytes(range(n))).to_bytes(8, "little").hex() == want, n


def _lanes(messages: list) -> tuple[np.ndarray, np.ndarray]:
    """Byte strings as siphash24's zero-padded (w, B) uint8 matrix and (w,) lengths."""
    width = 8 * (max(len(m) for m in messages) // 8 + 1)
    out = np.zeros((len(messages), width), np.uint8)
    for i, m in enumerate(messages):
        out[i, : len(m)] = np.frombuffer(m, np.uint8)
    return out, np.array([len(m) for m in messages], np.int64)


def test_the_vectorized_siphash_reproduces_all_64_paper_vectors_in_one_call():
    """Messages of 0 .. 63 bytes as lanes of one call, shuffled (so lanes of every length interleave)."""
    lengths = np.random.default_rng(0).permutation(64)
    out = wm.siphash24(PAPER_KEY, *_lanes([bytes(range(n)) for n in lengths]))
    assert [int(h).to_bytes(8, "little").hex() for h in out] == [PAPER_VECTORS[n] for n in lengths]


def test_the_vectorized_siphash_equals_the_reference_on_random_keys_and_messages():
    rng = np.random.default_rng(5)
    key = rng.bytes(16)
    messages = [rng.bytes(int(n)) for n in rng.integers(0, 70, 300)]
    out = wm.siphash24(key, *_lanes(messages))
    assert [int(h) for h in out] == [siphash24_reference(key, m) for m in messages]
    assert len(wm.siphash24(key, np.zeros((0, 8), np.uint8), np.zeros(0, np.int64))) == 0


def _batch(seed=0):
    """The largest batch of a small bound encode: a key, its carriers' stream slots and ring descriptor."""
    key = WatermarkKey.generate(rng=np.random.default_rng(seed))
    image = np.random.default_rng(1).integers(0, 256, (8, 8)).astype(np.uint8)
    buf = io.BytesIO()
    encode_mesh(shapes.icosphere(3, 1.0, noise=0.02), buf, measure=False, watermark=image, key=key)
    replay = Replay()
    feed = [c for event in iter_events(buf.getvalue()) for c in replay.on_event(event)]
    batch = max(feed, key=lambda c: len(c.points))
    return key, wm.carrier_slots(key, batch.batch, 1000, len(batch.points)), batch.descriptor


def _spec_offset(key, slot, values, bits) -> int:
    """spec §5: SipHash-2-4 keyed with derived_key(label)[0:16] of uint64_le(slot) || int16_le(D saturated)."""
    message = int(slot).to_bytes(8, "little")
    message += b"".join(int(min(max(v, -32768), 32767)).to_bytes(2, "little", signed=True) for v in values)
    return siphash24_reference(key.derived_key(b"ring-binding/v2")[:16], message) % (1 << bits)


def test_binding_offsets_follow_the_spec_carrier_by_carrier_with_every_ambiguous_reading():
    key, slots, desc = _batch()
    # widen the boundary band so that many carriers have 1, 2, 3 or more ambiguous values
    near = np.where(desc.closeness < 0.1, np.where(desc.q % 2 == 0, -1, 1), 0)
    desc = wm.RingDescriptor(desc.q, desc.starts, desc.vertex, near, desc.closeness)
    bits = 7
    got = wm.binding_offsets(wm.binding_key(key), slots, desc, bits, alternatives=True)
    counts = set()
    for i in range(len(slots)):
        lo, hi = desc.starts[i], desc.starts[i + 1]
        q, n = desc.q[lo:hi], near[lo:hi]
        amb = np.flatnonzero(n)
        amb = amb[np.argsort(desc.closeness[lo:hi][amb], kind="stable")][: wm.MAX_AMBIGUOUS]
        counts.add(len(amb))
        for m in range(wm.ALTERNATIVES):
            if m >= 1 << len(amb):
                assert got[i, m] == -1
                continue
            alt = q.copy()
            for t in range(len(amb)):
                if m >> t & 1:
                    alt[amb[t]] += n[amb[t]]
            assert got[i, m] == _spec_offset(key, slots[i], alt, bits), (i, m)
    assert counts >= {0, 1, 2, 3}  # every shape of the lane expansion was exercised
    which = np.array([5, 1, 2])
    assert np.array_equal(wm.binding_offsets(wm.binding_key(key), slots, desc, bits, which)[:, 0], got[which, 0])


def test_the_binding_offset_depends_on_the_key_the_slot_and_every_ring_value():
    key, slots, desc = _batch()
    other, _, _ = _batch(seed=1)
    bits = 16
    base = wm.binding_offsets(wm.binding_key(key), slots, desc, bits)[:, 0]
    assert np.mean(base == wm.binding_offsets(wm.binding_key(other), slots, desc, bits)[:, 0]) < 0.01
    assert np.mean(base == wm.binding_offsets(wm.binding_key(key), slots + 1, desc, bits)[:, 0]) < 0.01
    bumped = wm.RingDescriptor(desc.q + 1, desc.starts, desc.vertex, desc.near, desc.closeness)
    assert np.mean(base == wm.binding_offsets(wm.binding_key(key), slots, bumped, bits)[:, 0]) < 0.01


def test_a_file_naming_an_unknown_binding_is_refused_with_a_named_error():
    key, _, _ = _batch()
    image = np.random.default_rng(0).integers(0, 256, (8, 8)).astype(np.uint8)
    params, _ = wm.plan(image, key, 500)
    assert params.binding == wm.BINDING == "ring-v2"
    cfg = params.get_config()
    assert wm.WatermarkParams.from_config(cfg).binding == "ring-v2"
    assert wm.WatermarkParams.from_config({**cfg, "binding": ""}).binding == ""  # legacy: readable
    for unknown in ("ring-v1", "ring-v3", 7):
        with pytest.raises(FormatError, match="unknown watermark binding"):
            wm.WatermarkParams.from_config({**cfg, "binding": unknown})
