"""The watermark key: a secret, the public parameters, and the keyed mappings.

A :class:`WatermarkKey` holds

* ``secret`` — 32 random bytes; never written into a ``.pmw``;
* ``params`` — JSON-able public parameters (bits, levels, bit layout ...), as a dict;
* ``reference`` — optional (s, s) uint8 watermark, so ``verify`` needs no image;
* ``file_id`` — optional string binding the key to one ``.pmw``.

It is stored as a JSON file (``save``/``load``), written with mode 0600::

    {"format": "pmwm-key", "version": 1, "secret": "<64 hex>", "file_id": "...",
     "params": {...}, "reference": {"width": s, "height": s, "png": "<base64 PNG>"}}

A file may carry :meth:`WatermarkKey.fingerprint` publicly: it identifies the key
(HMAC-SHA256 of a fixed label) without revealing the secret, so a reader can tell
"key of another file" from "watermark absent".

**Keyed mappings** are defined by SHAKE-256 over the secret, so that any implementation
(and any numpy version) reproduces them bit for bit — ``numpy.random.Generator`` methods
carry no such promise across numpy releases::

    stream(label, id, nbytes) = SHAKE256(b"pmwm/" + label + b"/v1\\0" + secret
                                         + uint64_le(id)).digest(nbytes)

* :meth:`permutation` ``(id, n)``: the stable argsort of the n little-endian uint64 words
  of ``stream(b"permutation", id, 8 n)`` — a uniformly random permutation (ties, with
  probability ~n^2/2^65, resolve by index);
* :meth:`bits` ``(id, n)``: the first n bits (little-endian bit order within each byte)
  of ``stream(b"bits", id, ceil(n / 8))``;
* :meth:`derived_key` ``(label)``: ``stream(b"key/" + label, 0, 32)``, a 32-byte key for a
  keyed PRF/MAC (BLAKE2b) that never exposes the secret itself (e.g. the ring binding).
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import io
import json
import os
import secrets
from dataclasses import dataclass, field

import numpy as np

from ..errors import WatermarkKeyError

__all__ = ["WatermarkKey", "KEY_FORMAT", "KEY_VERSION"]

KEY_FORMAT = "pmwm-key"
KEY_VERSION = 1
SECRET_BYTES = 32
_FINGERPRINT_LABEL = b"pmwm/fingerprint/v1"


def _png_b64(image: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8), mode="L").save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _png_unb64(text: str) -> np.ndarray:
    from PIL import Image

    with Image.open(io.BytesIO(base64.b64decode(text, validate=True))) as img:
        return np.asarray(img.convert("L"), dtype=np.uint8).copy()


def _jsonable(obj):
    """numpy scalars and arrays in ``params`` -> plain JSON values."""
    if isinstance(obj, (np.generic, np.ndarray)):
        return obj.tolist()
    raise TypeError(f"{type(obj).__name__} in key params is not JSON-serialisable")


@dataclass(eq=False)
class WatermarkKey:
    """Secret + public parameters + optional reference watermark + owning file id."""

    secret: bytes
    params: dict = field(default_factory=dict)
    reference: np.ndarray | None = None
    file_id: str | None = None

    def __post_init__(self):
        if not isinstance(self.secret, (bytes, bytearray)) or len(self.secret) != SECRET_BYTES:
            raise WatermarkKeyError(f"a key secret must be {SECRET_BYTES} bytes")
        self.secret = bytes(self.secret)
        if self.reference is not None:
            ref = np.asarray(self.reference)
            if ref.ndim != 2 or ref.size == 0:
                raise WatermarkKeyError(f"reference watermark must be 2-D, got shape {ref.shape}")
            self.reference = ref.astype(np.uint8)

    # --- construction and storage ---------------------------------------------------------

    @classmethod
    def generate(cls, rng=None, params=None, reference=None, file_id=None) -> "WatermarkKey":
        """A new key with a random 256-bit secret.

        rng : numpy Generator, optional — only for reproducible tests; the default draws
        from the operating system (``secrets``).
        """
        secret = secrets.token_bytes(SECRET_BYTES) if rng is None else rng.bytes(SECRET_BYTES)
        return cls(secret, dict(params or {}), reference, file_id)

    @property
    def secret_hex(self) -> str:
        return self.secret.hex()

    def to_json(self) -> dict:
        """The JSON object of the key file (holds the secret)."""
        doc = {
            "format": KEY_FORMAT,
            "version": KEY_VERSION,
            "secret": self.secret.hex(),
            "fingerprint": self.fingerprint(),
            "file_id": self.file_id,
            "params": self.params,
        }
        if self.reference is not None:
            h, w = self.reference.shape
            doc["reference"] = {"width": w, "height": h, "png": _png_b64(self.reference)}
        return doc

    @classmethod
    def from_json(cls, doc, source: str = "key") -> "WatermarkKey":
        """Rebuild from :meth:`to_json`'s object; WatermarkKeyError on anything wrong."""

        def bad(why):
            return WatermarkKeyError(f"{source}: not a valid watermark key ({why})")

        if not isinstance(doc, dict) or doc.get("format") != KEY_FORMAT:
            raise bad(f'"format" is not "{KEY_FORMAT}"')
        if doc.get("version") != KEY_VERSION:
            raise bad(f"unsupported key version {doc.get('version')!r}")
        try:
            secret = bytes.fromhex(doc["secret"])
        except (KeyError, TypeError, ValueError):
            raise bad("secret missing or not hexadecimal") from None
        if len(secret) != SECRET_BYTES:
            raise bad(f"secret has {len(secret)} bytes, expected {SECRET_BYTES}")
        params = doc.get("params") or {}
        file_id = doc.get("file_id")
        if not isinstance(params, dict) or not (file_id is None or isinstance(file_id, str)):
            raise bad('"params" must be an object and "file_id" a string')
        reference = None
        if doc.get("reference") is not None:
            ref = doc["reference"]
            try:
                reference = _png_unb64(ref["png"])
                shape = (int(ref["height"]), int(ref["width"]))
            except (KeyError, TypeError, ValueError, OSError, binascii.Error) as exc:
                raise bad(f"reference watermark unreadable: {exc}") from None
            if reference.shape != shape:
                raise bad(f"reference watermark is {reference.shape}, declared {shape}")
        key = cls(secret, params, reference, file_id)
        if "fingerprint" in doc and doc["fingerprint"] != key.fingerprint():
            raise bad("fingerprint does not match the secret")
        return key

    def save(self, path) -> None:
        """Write the key file as JSON (mode 0600: it holds the secret)."""
        path = os.fspath(path)
        text = json.dumps(self.to_json(), indent=2, default=_jsonable) + "\n"
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)

    @classmethod
    def load(cls, path) -> "WatermarkKey":
        """Read a key file; any problem is a one-line :class:`WatermarkKeyError`."""
        path = os.fspath(path)
        try:
            with open(path, "rb") as fh:
                raw = fh.read(1 << 26)
        except FileNotFoundError:
            raise WatermarkKeyError(f"{path}: no such key file") from None
        except OSError as exc:
            raise WatermarkKeyError(f"{path}: cannot read key file ({exc.strerror})") from None
        try:
            doc = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            raise WatermarkKeyError(f"{path}: not a watermark key (not JSON)") from None
        return cls.from_json(doc, source=path)

    # --- public identity ----------------------------------------------------------------

    def fingerprint(self) -> str:
        """16 hex digits identifying the key, safe to publish (HMAC of a fixed label)."""
        return hmac.new(self.secret, _FINGERPRINT_LABEL, hashlib.sha256).hexdigest()[:16]

    def check(self, file_id: str | None = None, fingerprint: str | None = None) -> None:
        """Raise WatermarkKeyError if the key does not belong to the given file."""
        if fingerprint is not None and fingerprint != self.fingerprint():
            raise WatermarkKeyError("the key belongs to another file (fingerprint differs)")
        if file_id is not None and self.file_id is not None and file_id != self.file_id:
            raise WatermarkKeyError(
                f"the key belongs to file {self.file_id}, not to file {file_id}"
            )

    def __eq__(self, other) -> bool:
        if not isinstance(other, WatermarkKey):
            return NotImplemented
        same_ref = (self.reference is None and other.reference is None) or (
            self.reference is not None
            and other.reference is not None
            and np.array_equal(self.reference, other.reference)
        )
        return (
            hmac.compare_digest(self.secret, other.secret)
            and self.params == other.params
            and self.file_id == other.file_id
            and same_ref
        )

    def __repr__(self) -> str:  # never print the secret
        ref = "none" if self.reference is None else "x".join(map(str, self.reference.shape[::-1]))
        fp, fid = self.fingerprint(), self.file_id
        return f"WatermarkKey(fingerprint={fp}, file_id={fid!r}, reference={ref})"

    # --- keyed mappings -----------------------------------------------------------------

    def _stream(self, label: bytes, stream_id: int, nbytes: int) -> bytes:
        stream_id = int(stream_id)
        if not 0 <= stream_id < 1 << 64:
            raise ValueError(f"stream_id must fit in 64 bits, got {stream_id}")
        h = hashlib.shake_256(b"pmwm/" + label + b"/v1\0" + self.secret)
        h.update(stream_id.to_bytes(8, "little"))
        return h.digest(nbytes) if nbytes else b""

    def permutation(self, stream_id: int, n: int) -> np.ndarray:
        """Secret permutation of n slots for stream/chunk ``stream_id``: (n,) int64."""
        n = int(n)
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        words = np.frombuffer(self._stream(b"permutation", stream_id, 8 * n), dtype="<u8")
        return np.argsort(words, kind="stable").astype(np.int64)

    def bits(self, stream_id: int, n: int) -> np.ndarray:
        """Keyed pseudo-random bits for whitening: (n,) uint8 of 0/1."""
        n = int(n)
        if n < 0:
            raise ValueError(f"n must be >= 0, got {n}")
        raw = np.frombuffer(self._stream(b"bits", stream_id, (n + 7) // 8), dtype=np.uint8)
        return np.unpackbits(raw, bitorder="little")[:n]


    def derived_key(self, label: bytes) -> bytes:
        """32 bytes derived from the secret for the keyed PRF/MAC named ``label`` (module docstring)."""
        return self._stream(b"key/" + bytes(label), 0, 32)


def as_key(key) -> WatermarkKey | None:
    """A :class:`WatermarkKey` from a key object or a key file path (None stays None)."""
    if key is None or isinstance(key, WatermarkKey):
        return key
    return WatermarkKey.load(key)
