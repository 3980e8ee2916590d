"""The watermark key: storage, fingerprint and keyed mappings."""

import json
import os
import stat

import numpy as np
import pytest

from pmwm_codec.errors import WatermarkKeyError
from pmwm_codec.watermark.key import WatermarkKey

SECRET = bytes(range(32))


@pytest.fixture
def key():
    ref = (np.arange(16 * 16) % 256).astype(np.uint8).reshape(16, 16)
    return WatermarkKey(SECRET, {"bits": 12, "levels": 4}, ref, "file-1234")


def test_generate_is_random_unless_seeded():
    a, b = WatermarkKey.generate(), WatermarkKey.generate()
    assert a.secret != b.secret and len(a.secret) == 32 and len(a.secret_hex) == 64
    r1 = WatermarkKey.generate(rng=np.random.default_rng(7))
    r2 = WatermarkKey.generate(rng=np.random.default_rng(7))
    assert r1 == r2


def test_permutation_is_deterministic_and_pinned():
    k = WatermarkKey(SECRET)
    p = k.permutation(5, 1000)
    assert p.dtype == np.int64 and p.shape == (1000,)
    assert np.array_equal(np.sort(p), np.arange(1000))
    assert np.array_equal(p, WatermarkKey(SECRET).permutation(5, 1000))
    # pinned values: the mapping is part of the format and must never drift
    assert k.permutation(0, 8).tolist() == PINNED_PERMUTATION
    assert k.bits(0, 16).tolist() == PINNED_BITS
    assert k.fingerprint() == PINNED_FINGERPRINT


def test_permutations_differ_by_secret_and_stream():
    a, b = WatermarkKey(SECRET), WatermarkKey(bytes(32))
    assert not np.array_equal(a.permutation(0, 100), b.permutation(0, 100))
    assert not np.array_equal(a.permutation(0, 100), a.permutation(1, 100))
    assert a.permutation(0, 0).shape == (0,) and a.permutation(0, 1).tolist() == [0]


def test_bits_are_balanced_and_keyed():
    k = WatermarkKey(SECRET)
    bits = k.bits(3, 10_000)
    assert bits.dtype == np.uint8 and set(np.unique(bits)) == {0, 1}
    assert 0.47 < bits.mean() < 0.53
    assert np.array_equal(bits[:100], k.bits(3, 100))  # prefix-stable
    assert not np.array_equal(bits[:100], k.bits(4, 100))
    assert not np.array_equal(bits[:100], WatermarkKey(bytes(32)).bits(3, 100))


def test_json_round_trip(tmp_path, key):
    path = tmp_path / "k.key"
    key.save(path)
    assert stat.S_IMODE(os.stat(path).st_mode) == 0o600
    back = WatermarkKey.load(path)
    assert back == key and back.file_id == "file-1234" and back.params == {"bits": 12, "levels": 4}
    assert np.array_equal(back.reference, key.reference)
    assert np.array_equal(back.permutation(2, 50), key.permutation(2, 50))
    doc = json.loads(path.read_text())
    assert doc["secret"] == SECRET.hex() and doc["fingerprint"] == key.fingerprint()


def test_numpy_params_are_saved(tmp_path):
    k = WatermarkKey(SECRET, {"bits": np.int64(8), "widths": np.arange(3)})
    k.save(tmp_path / "k.key")
    assert WatermarkKey.load(tmp_path / "k.key").params == {"bits": 8, "widths": [0, 1, 2]}


def test_fingerprint_is_stable_and_hides_the_secret(key):
    fp = key.fingerprint()
    assert fp == WatermarkKey(SECRET).fingerprint() and len(fp) == 16
    assert SECRET.hex()[:16] not in fp
    assert fp != WatermarkKey(bytes(32)).fingerprint()
    assert SECRET.hex() not in repr(key)


def test_check_binds_to_a_file(key):
    key.check(file_id="file-1234", fingerprint=key.fingerprint())
    with pytest.raises(WatermarkKeyError, match="another file"):
        key.check(fingerprint=WatermarkKey(bytes(32)).fingerprint())
    with pytest.raises(WatermarkKeyError, match="file-1234"):
        key.check(file_id="other")


@pytest.mark.parametrize(
    "content, message",
    [
        (b"\x00\xff garbage", "not JSON"),
        (b"[1, 2]", "a JSON object expected, got list"),
        (b'{"format": "pmwm-key", "version": 99, "secret": ""}', "version"),
        (b'{"format": "pmwm-key", "version": 1, "secret": "zz"}', "hexadecimal"),
        (b'{"format": "pmwm-key", "version": 1, "secret": "abcd"}', "bytes"),
        (('{"format": "pmwm-key", "version": 1, "secret": "%s", "fingerprint": "00"}'
          % SECRET.hex()).encode(), "fingerprint"),
        (('{"format": "pmwm-key", "version": 1, "secret": "%s", "reference": {"png": "@@"}}'
          % SECRET.hex()).encode(), "reference"),
    ],
)
def test_bad_key_files(tmp_path, content, message):
    path = tmp_path / "bad.key"
    path.write_bytes(content)
    with pytest.raises(WatermarkKeyError, match=message) as info:
        WatermarkKey.load(path)
    assert "\n" not in str(info.value)


def _png(image) -> str:
    import base64
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


@pytest.mark.parametrize("edit", ["owner_id", "params", "file_id", "reference pixel", "reference removed",
                                  "checksum", "checksum not text"])
def test_a_key_file_edited_after_it_was_written_is_refused(tmp_path, key, edit):
    """A hand-edited owner ID used to be accepted: the image verified ``authentic``, the owner ``absent``."""
    key.owner_id = 0x1234
    path = tmp_path / "k.key.json"
    key.save(path)
    doc = json.loads(path.read_text())
    if edit == "owner_id":
        doc["owner_id"] = "0000000000000001"
    elif edit == "params":
        doc["params"]["bits"] = 9
    elif edit == "file_id":
        doc["file_id"] = "file-5678"
    elif edit == "reference pixel":
        changed = key.reference.copy()
        changed[0, 0] ^= 0xFF
        doc["reference"]["png"] = _png(changed)
    elif edit == "reference removed":
        del doc["reference"]
    elif edit == "checksum":
        doc["checksum"] = "0" * 32
    else:
        doc["checksum"] = 5
    path.write_text(json.dumps(doc))
    with pytest.raises(WatermarkKeyError, match="checksum") as info:
        WatermarkKey.load(path)
    assert str(info.value).startswith(f"{path}: not a valid watermark key") and "\n" not in str(info.value)


def test_a_key_written_before_the_checksum_still_loads(tmp_path, key):
    path = tmp_path / "k.key.json"
    doc = key.to_json()
    del doc["checksum"]
    path.write_text(json.dumps(doc))
    assert WatermarkKey.load(path) == key
    key.save(path)
    assert json.loads(path.read_text())["checksum"] == key.checksum() and WatermarkKey.load(path) == key


@pytest.mark.parametrize("member, value, message", [
    ("owner_id", 1234, '"owner_id" must be a string'),  # read as the hex digits "1234", the checksum matching
    ("version", True, "unsupported key version True"),
    ("version", 1.0, "unsupported key version 1.0"),
    ("width", 16.0, "must be integers"),
    ("height", "16", "must be integers"),
])
@pytest.mark.parametrize("checksum", [True, False])
def test_a_key_file_member_of_the_wrong_type_is_refused_not_read_as_another_value(tmp_path, key, member, value,
                                                                                   message, checksum):
    """A number where the key writes text was taken for it: an owner ID written 1234 was read as the hex digits
    0x1234 (with or without the checksum: it covers the ID read), a width of 16.0 or "16" as 16, a version true
    as 1; a key file is read as written or refused, with one line."""
    key.owner_id = 0x1234
    doc = key.to_json()
    if not checksum:
        del doc["checksum"]
    (doc["reference"] if member in ("width", "height") else doc)[member] = value
    path = tmp_path / "k.key.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(WatermarkKeyError, match=message) as info:
        WatermarkKey.load(path)
    assert str(info.value).startswith(f"{path}: not a valid watermark key") and "\n" not in str(info.value)


@pytest.mark.parametrize("reference, message", [
    ({"width": 16, "height": 16, "png": "AAAA"}, 'reference watermark unreadable: "png" is not an image'),
    ({"width": 16, "height": 16, "png": "@@"}, "must be integers and \"png\" base64 text"),
    ({"width": 16, "height": 16}, "reference watermark has no 'png'"),
    ({"width": "x", "height": 16, "png": "AAAA"}, "must be integers"),
    ([1, 2], "reference watermark is not an object"),
    ({"width": 8, "height": 16, "png": None}, "base64 text"),
])
def test_an_unreadable_reference_is_named_without_python_internals(tmp_path, reference, message):
    path = tmp_path / "k.key.json"
    path.write_text(json.dumps({"format": "pmwm-key", "version": 1, "secret": SECRET.hex(), "reference": reference}))
    with pytest.raises(WatermarkKeyError) as info:
        WatermarkKey.load(path)
    text = str(info.value)
    assert message in text and "object at 0x" not in text and "BytesIO" not in text, text


def test_a_reference_of_another_size_than_declared_is_named_in_pixels(tmp_path, key):
    doc = key.to_json()
    doc["reference"]["width"] = 8
    del doc["checksum"]
    path = tmp_path / "k.key.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(WatermarkKeyError, match="reference watermark is 16x16, declared 8x16"):
        WatermarkKey.load(path)


def test_missing_key_file(tmp_path):
    with pytest.raises(WatermarkKeyError, match="no such key file"):
        WatermarkKey.load(tmp_path / "nope.key")


def test_bad_secret_length():
    with pytest.raises(WatermarkKeyError):
        WatermarkKey(b"short")


# Values from the definition in the module docstring (checked by the pure-Python
# re-implementation below); changing them breaks every existing key.
PINNED_PERMUTATION = [6, 0, 7, 2, 3, 4, 1, 5]
PINNED_BITS = [1, 0, 1, 0, 0, 0, 1, 1, 0, 1, 1, 0, 0, 0, 1, 1]
PINNED_FINGERPRINT = "353a57dc0819a9b6"


def test_mappings_follow_the_written_definition():
    """A second implementation, from the docstring alone (hashlib + struct, no numpy)."""
    import hashlib
    import hmac
    import struct

    def stream(label, sid, nbytes):
        h = hashlib.shake_256(b"pmwm/" + label + b"/v1\0" + SECRET + struct.pack("<Q", sid))
        return h.digest(nbytes)

    k = WatermarkKey(SECRET)
    for sid, n in [(0, 8), (9, 333)]:
        words = struct.unpack(f"<{n}Q", stream(b"permutation", sid, 8 * n))
        assert k.permutation(sid, n).tolist() == sorted(range(n), key=lambda i: (words[i], i))
        raw = stream(b"bits", sid, (n + 7) // 8)
        assert k.bits(sid, n).tolist() == [(raw[i // 8] >> (i % 8)) & 1 for i in range(n)]
    fp = hmac.new(SECRET, b"pmwm/fingerprint/v1", hashlib.sha256).hexdigest()[:16]
    assert k.fingerprint() == fp


def test_same_path_answers_for_a_path_holding_a_nul_instead_of_raising():
    """os.stat raises ValueError, not OSError, on a NUL in a path: same_path let it out of every caller."""
    from pmwm_codec.watermark.key import same_path

    assert same_path("out\0.pmw", "./out\0.pmw") and not same_path("out\0.pmw", "out.pmw")
    assert same_path(b"k\0.json", b"k\0.json")
