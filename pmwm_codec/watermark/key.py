"""The watermark key: a secret, the public parameters, and the keyed mappings.

A :class:`WatermarkKey` holds

* ``secret`` — 32 random bytes; never written into a ``.pmw``;
* ``params`` — JSON-able public parameters (bits, levels, bit layout ...), as a dict;
* ``reference`` — optional (s, s) uint8 watermark, so ``verify`` needs no image;
* ``file_id`` — optional string: the ``.pmw`` the key was made for;
* ``owner_id`` — the 64-bit owner ID of the owner layer (:mod:`.owner`), an int; random
  in :meth:`WatermarkKey.generate`, None in keys written before the owner layer.

``params`` and ``file_id`` describe the first file a key file marked; they are
informational (verification takes the parameters and the public fingerprint from the
file), so a key reused for more assets (:class:`KeySlot`) is never rewritten.

It is stored as a JSON file (``save``/``load``), written atomically with mode 0600 and
never through a symbolic link::

    {"format": "pmwm-key", "version": 1, "secret": "<64 hex>", "fingerprint": "<16 hex>",
     "checksum": "<32 hex>", "file_id": "...", "owner_id": "<16 hex>", "params": {...},
     "reference": {"width": s, "height": s, "png": "<base64 PNG>"}}

A file may carry :meth:`WatermarkKey.fingerprint` publicly: it identifies the key
(HMAC-SHA256 of a fixed label) without revealing the secret, so a reader can tell
"key of another file" from "watermark absent".  Both ``fingerprint`` and ``checksum`` are
checked when present (keys written before the checksum have none and load as before):

* ``fingerprint`` covers the secret: an edited secret is refused;
* ``checksum`` (:meth:`WatermarkKey.checksum`) covers the rest: the first 32 hex digits of
  HMAC-SHA256(secret, ``"pmwm/key-checksum/v1\\0"`` + the compact, key-sorted JSON of
  ``{"file_id", "owner_id" (16 hex or null), "params", "reference": [height, width, SHA-256 hex of
  the pixels, row by row] or null}``).  A hand-edited owner ID would otherwise verify the image
  ``authentic`` beside an owner ``absent``, and an edited reference image would blame the file.
  It detects edits and corruption; it is no protection against whoever holds the secret.

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
* :meth:`mac_key` ``()``: ``stream(b"mac", 0, 32)``, the key of the chunk MACs
  (:mod:`pmwm_codec.format.mac`); a label of its own, so a MAC reveals nothing of the
  other mappings.
* :meth:`derived_key` ``(label)``: ``stream(b"key/" + label, 0, 32)``, a 32-byte key for a
  keyed PRF/MAC that never exposes the secret itself (e.g. the ring binding, SipHash-2-4 keyed
  with its first 16 bytes under the label ``ring-binding/v2``).
"""

from __future__ import annotations

import base64
import binascii
import codecs
import hashlib
import hmac
import io
import json
import os
import re
import secrets
import stat
from dataclasses import dataclass, field

import numpy as np

from ..constants import MAX_KEY_FILE_BYTES
from ..errors import WatermarkKeyError
from ..sources import bom_codec, read_regular_file, shown_path

__all__ = ["WatermarkKey", "KeySlot", "KEY_FORMAT", "KEY_VERSION", "KEY_FILE_MODE", "KEY_SUFFIX", "refuse_symlink",
           "refuse_key_target", "refuse_orphaned_beside", "same_path", "checked_key_path"]

KEY_FORMAT = "pmwm-key"
KEY_VERSION = 1
#: The members a key file of :data:`KEY_VERSION` may hold (:meth:`WatermarkKey.to_json`), and those of its
#: ``reference`` object: any other is refused by name, never read as if understood (a typo such as
#: ``owner_idd``, or a member of a later version, which raises the ``version`` with it).
KEY_MEMBERS = ("format", "version", "secret", "fingerprint", "checksum", "file_id", "owner_id", "params", "reference")
REFERENCE_MEMBERS = ("width", "height", "png")
SECRET_BYTES = 32
#: Mode of every key file written, whatever the umask or an older file's mode.
KEY_FILE_MODE = 0o600

#: The key of ``OUT.pmw`` is ``OUT.pmw.key.json`` (``pmw encode``'s default); ``pmw serve`` never serves these.
KEY_SUFFIX = ".key.json"
_FINGERPRINT_LABEL = b"pmwm/fingerprint/v1"
_CHECKSUM_LABEL = b"pmwm/key-checksum/v1\0"


def _png_b64(image: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.asarray(image, dtype=np.uint8), mode="L").save(buf, format="PNG")
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _reference_from_json(ref) -> np.ndarray:
    """The (h, w) uint8 image of a key file's ``reference`` object; ValueError saying what is wrong with it
    (worded to follow "reference watermark ")."""
    from PIL import Image, UnidentifiedImageError

    from .image import check_image_size

    if not isinstance(ref, dict):
        raise ValueError("is not an object")
    unknown = _unknown_member(ref, REFERENCE_MEMBERS, "key's reference")
    if unknown:
        raise ValueError(f"has {unknown}")
    try:
        if not (_is_int(ref["height"]) and _is_int(ref["width"])):
            raise TypeError
        shape = (ref["height"], ref["width"])
        data = base64.b64decode(ref["png"], validate=True)
    except KeyError as exc:
        raise ValueError(f"has no {exc.args[0]!r}") from None
    except (TypeError, ValueError, binascii.Error):
        raise ValueError('unreadable: "width" and "height" must be integers and "png" base64 text') from None
    try:
        with Image.open(io.BytesIO(data)) as img:
            check_image_size(img, "image")
            image = np.asarray(img.convert("L"), dtype=np.uint8).copy()
    except UnidentifiedImageError:  # its message shows the buffer object's repr: never echoed
        raise ValueError('unreadable: "png" is not an image') from None
    except (OSError, ValueError, SyntaxError, Image.DecompressionBombError) as exc:
        raise ValueError(f"unreadable ({exc})") from None
    if image.shape != shape:
        raise ValueError(f"is {image.shape[1]}x{image.shape[0]}, declared {shape[1]}x{shape[0]}")
    return image


def _unknown_member(doc: dict, members: tuple, what: str = "key") -> str | None:
    """``unknown member "owner_idd": a version 1 key holds format, ...`` for the first member of ``doc`` not
    in ``members`` (its name as JSON text, at most 40 characters of it; ``what``: what holds them); None when
    every one is known."""
    for name in doc:
        if name not in members:
            shown = json.dumps(name)
            shown = shown if len(shown) <= 40 else shown[:36] + '..."'
            return f"unknown member {shown}: a version {KEY_VERSION} {what} holds {', '.join(members)}"
    return None


def _is_int(value) -> bool:
    """Whether a JSON value is an integer (``16``; not ``16.0``, ``"16"`` or ``true``)."""
    return isinstance(value, int) and not isinstance(value, bool)


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
    owner_id: int | None = None

    def __post_init__(self):
        if not isinstance(self.secret, (bytes, bytearray)) or len(self.secret) != SECRET_BYTES:
            raise WatermarkKeyError(f"a key secret must be {SECRET_BYTES} bytes")
        self.secret = bytes(self.secret)
        if self.reference is not None:
            ref = np.asarray(self.reference)
            if ref.ndim != 2 or ref.size == 0:
                raise WatermarkKeyError(f"reference watermark must be 2-D, got shape {ref.shape}")
            self.reference = ref.astype(np.uint8)
        if self.owner_id is not None:
            if isinstance(self.owner_id, bool) or not isinstance(self.owner_id, (int, np.integer)) \
                    or not 0 <= int(self.owner_id) < 1 << 64:
                raise WatermarkKeyError("an owner id must be an integer of at most 64 bits")
            self.owner_id = int(self.owner_id)

    # --- construction and storage ---------------------------------------------------------

    @classmethod
    def generate(cls, rng=None, params=None, reference=None, file_id=None, owner_id=None) -> "WatermarkKey":
        """A new key with a random 256-bit secret and (unless given) a random 64-bit owner id.

        rng : numpy Generator, optional — only for reproducible tests; the default draws
        from the operating system (``secrets``).
        """
        secret = secrets.token_bytes(SECRET_BYTES) if rng is None else rng.bytes(SECRET_BYTES)
        if owner_id is None:
            owner_id = int.from_bytes(secrets.token_bytes(8) if rng is None else rng.bytes(8), "big")
        return cls(secret, dict(params or {}), reference, file_id, owner_id)

    @property
    def owner_hex(self) -> str | None:
        """The owner id as 16 hex digits (None when the key has none)."""
        return None if self.owner_id is None else f"{self.owner_id:016x}"

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
            "checksum": self.checksum(),
            "file_id": self.file_id,
            "owner_id": self.owner_hex,
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

        from ..format.document import check_json_depth

        check_json_depth(doc, source, error=WatermarkKeyError)
        if not isinstance(doc, dict):  # a key file holding a list, or the key's text given for its object
            text = isinstance(doc, (str, bytes))
            hint = ": give json.loads(text), or WatermarkKey.load(path) for a file" if text else ""
            raise bad(f"a JSON object expected, got {type(doc).__name__}{hint}")
        if doc.get("format") != KEY_FORMAT:
            raise bad(f'"format" is not "{KEY_FORMAT}"')
        if not _is_int(doc.get("version")) or doc["version"] != KEY_VERSION:
            raise bad(f"unsupported key version {doc.get('version')!r}")
        unknown = _unknown_member(doc, KEY_MEMBERS)
        if unknown:
            raise bad(unknown)
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
            try:
                reference = _reference_from_json(doc["reference"])
            except ValueError as exc:
                raise bad(f"reference watermark {exc}") from None
        owner_id = doc.get("owner_id")
        if owner_id is not None and not isinstance(owner_id, str):  # a number's digits are not its hex digits
            raise bad(f'"owner_id" must be a string of hexadecimal digits or null, not {type(owner_id).__name__}')
        if owner_id is not None:
            try:
                owner_id = parse_owner_id(owner_id)
            except ValueError as exc:
                raise bad(str(exc)) from None
        key = cls(secret, params, reference, file_id, owner_id)
        if "fingerprint" in doc and doc["fingerprint"] != key.fingerprint():
            raise bad("fingerprint does not match the secret")
        if "checksum" in doc and not (isinstance(doc["checksum"], str)
                                      and hmac.compare_digest(doc["checksum"], key.checksum())):
            raise bad("its owner_id, reference, params or file_id changed after it was written: they do not "
                      "match its checksum")
        return key

    def save(self, path) -> None:
        """Write the key file atomically, mode 0600 (it holds the secret), never through a symlink.

        WatermarkKeyError when ``path`` is a symbolic link (the link is left alone).
        """
        from ..atomic import write_atomic

        path = refuse_symlink(path)
        write_atomic(path, [self.to_text()], KEY_FILE_MODE)

    def to_text(self) -> bytes:
        """The key file's bytes: :meth:`to_json` as indented UTF-8 JSON."""
        return (json.dumps(self.to_json(), indent=2, default=_jsonable) + "\n").encode("utf-8")

    @classmethod
    def load(cls, path) -> "WatermarkKey":
        """Read a key file; any problem is a one-line :class:`WatermarkKeyError`."""
        path = checked_key_path(path)
        shown = shown_path(path)  # a key's JSON given as its path is never echoed (the secret)
        if not os.path.lexists(path):
            raise WatermarkKeyError(f"{shown}: no such key file")
        raw = read_regular_file(path, MAX_KEY_FILE_BYTES, WatermarkKeyError, f"{shown}: cannot read key file")
        try:
            doc = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError):
            raise WatermarkKeyError(f"{shown}: not a watermark key (not JSON)") from None
        except RecursionError:
            raise WatermarkKeyError(f"{shown}: not a watermark key (JSON nested too deeply)") from None
        return cls.from_json(doc, source=path)

    # --- public identity ----------------------------------------------------------------

    def fingerprint(self) -> str:
        """16 hex digits identifying the key, safe to publish (HMAC of a fixed label)."""
        return hmac.new(self.secret, _FINGERPRINT_LABEL, hashlib.sha256).hexdigest()[:16]

    def checksum(self) -> str:
        """32 hex digits over everything the key file states besides the secret (module docstring), keyed
        by the secret: a key file whose owner ID, reference image, params or file id was edited is refused."""
        ref = None if self.reference is None else [*self.reference.shape,
                                                   hashlib.sha256(self.reference.tobytes()).hexdigest()]
        body = json.dumps({"file_id": self.file_id, "owner_id": self.owner_hex, "params": self.params,
                           "reference": ref}, sort_keys=True, separators=(",", ":"), default=_jsonable)
        return hmac.new(self.secret, _CHECKSUM_LABEL + body.encode("utf-8"), hashlib.sha256).hexdigest()[:32]

    def check_reference(self, image, source=None) -> None:
        """OptionError when the reference watermark ``image`` (h, w), given to score a read against, is not
        the size of this key's own: a key marks with one image (:class:`KeySlot`), so an image of another
        size is never its mark and NC / PSNR against it mean nothing.  ``source``: the image as the caller
        gave it (a path is named in the message).  Nothing to check without a key image or an ``image``."""
        if self.reference is None or image is None or np.shape(image) == self.reference.shape:
            return
        from ..errors import OptionError

        (h, w), (kh, kw) = np.shape(image), self.reference.shape
        name = f" {shown_path(source)}" if isinstance(source, (str, bytes, os.PathLike)) else ""
        raise OptionError(f"the reference watermark{name} is {w}x{h}, the key's is {kw}x{kh}: a key marks with one "
                          "image, so one of another size is never its mark (give the image the file was marked "
                          "with, or none to use the key's)")

    def owns(self, fingerprint: str | None) -> bool:
        """Whether a file carrying the public ``fingerprint`` can hold this key's mark
        (True when the file states none)."""
        return not fingerprint or hmac.compare_digest(fingerprint, self.fingerprint())

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
            and self.owner_id == other.owner_id
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

    def mac_key(self) -> bytes:
        """32 bytes keying the chunk and base MACs (BLAKE2b), derived under the label ``mac``."""
        return self._stream(b"mac", 0, 32)

    def derived_key(self, label: bytes) -> bytes:
        """32 bytes derived from the secret for the keyed PRF/MAC named ``label`` (module docstring)."""
        return self._stream(b"key/" + bytes(label), 0, 32)


#: ``KeySlot.open(..., owner_id=FROM_KEY)``: mark the key file's owner ID (random for a new key).
FROM_KEY = "from-key"


def random_owner_id() -> int:
    """A random 64-bit owner ID (from the operating system's generator)."""
    return int.from_bytes(secrets.token_bytes(8), "big")


def parse_owner_id(text) -> int:
    """An owner id from 1-16 hexadecimal digits (``0x`` allowed); ValueError otherwise."""
    s = str(text).strip().lower()
    s = s[2:] if s.startswith("0x") else s
    if not 1 <= len(s) <= 16 or any(ch not in "0123456789abcdef" for ch in s):
        raise ValueError(f"owner id {text!r} is not 1 to 16 hexadecimal digits")
    return int(s, 16)


def as_key(key) -> WatermarkKey | None:
    """A :class:`WatermarkKey` from a key object or a key file path (None stays None)."""
    if key is None or isinstance(key, WatermarkKey):
        return key
    if not isinstance(key, (str, bytes, os.PathLike)):
        raise WatermarkKeyError(f"a key must be a WatermarkKey, a key file path or None, got {type(key).__name__}")
    return WatermarkKey.load(key)


def checked_key_path(path) -> str:
    """``path`` as a string; WatermarkKeyError when it is empty or only white space (an unset variable in
    ``--key $KEY``), before any work: otherwise only publishing the key would fail, naming a temporary file."""
    path = os.fspath(path)
    if not (path if isinstance(path, str) else os.fsdecode(path)).strip():
        raise WatermarkKeyError(f"an empty key path ({path!r}) names no key file (an unset variable?): give the "
                                "key file's name")
    return path


def refuse_symlink(path) -> str:
    """``path`` as a string; WatermarkKeyError if it is empty (:func:`checked_key_path`) or a symbolic link
    (a key is never written through one)."""
    path = checked_key_path(path)
    if os.path.islink(path):
        raise WatermarkKeyError(f"{path}: is a symbolic link; a key file is never written through one "
                                "(name the real file with --key)")
    return path


#: Bytes of a file's head (after its blanks) in which :func:`is_key_file` takes ``"format": "pmwm-key"`` for a key
#: whatever follows, and bytes it reads at a time past them.
_KEY_HEAD_BYTES = 4096
_KEY_SCAN_BYTES = 1 << 20
_KEY_FORMAT_NAMED = re.compile(rb'"format"\s*:\s*"' + re.escape(KEY_FORMAT.encode()) + b'"')
#: The JSON string ``"pmwm-key"`` as it may be spelled: each character as it is or as a ``\uXXXX`` escape (hex in
#: either case).  A file without it holds no ``"format": "pmwm-key"``, whatever else it holds.
_KEY_FORMAT_VALUE = re.compile(('"' + "".join(
    f"(?:{re.escape(c)}|" + r"\\u" + "".join(f"[{h}{h.upper()}]" if h.isalpha() else h for h in f"{ord(c):04x}") + ")"
    for c in KEY_FORMAT) + '"').encode())
_KEY_SPELLING_BYTES = 2 + 6 * len(KEY_FORMAT)  # the longest match: every character escaped


def is_key_file(path, fd: int | None = None) -> bool:
    """Whether ``path`` names a key file: a name ending :data:`KEY_SUFFIX` (any case), or an existing
    regular file that holds a key (``fd``: that file, already open; its content is read from its start and its
    offset left anywhere).

    A file holds a key when :meth:`WatermarkKey.load` would take it for one: JSON of at most
    :data:`~pmwm_codec.constants.MAX_KEY_FILE_BYTES` whose value is an object with ``"format": "pmwm-key"``, read
    as the loader reads it (escapes such as ``"pmwm\\u002dkey"``, blanks before the object, the members in any
    order), and so does the same text in another Unicode encoding (UTF-16 or UTF-32, big- or little-endian, with a
    byte order mark or without: RFC 4627 §3), or after a UTF-8 byte order mark: the loader refuses those, but they
    hold the secret all the same.  A file whose head (its first 4096 bytes from the ``{`` that opens it) names the
    format (``"format": "pmwm-key"``) counts too, whatever follows: the check refuses at least what it always
    refused.

    A file that cannot be a key is never held whole: one whose first character (after blanks) is not ``{`` is read
    no further than its first block (a ``.pmw``, an image); a JSON object is read a block at a time for the format's
    value as a JSON string (``"pmwm-key"``, each character as it is or escaped), which every key holds, and read
    whole and parsed only when that string is in it (a 60 MB ``.gltf`` whose buffer is a ``data:`` URI: about
    40 ms and 2 MB, where parsing it took up to a second and 400 MB)."""
    path = os.fspath(path)
    if path.lower().endswith(KEY_SUFFIX):
        return True
    if fd is not None:
        return _holds_key(fd)
    try:
        if not os.path.isfile(path):
            return False
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except (OSError, ValueError):
        return False
    try:
        return _holds_key(fd)
    finally:
        os.close(fd)


def _holds_key(fd: int) -> bool:
    """Whether the file open at ``fd`` holds a key (:func:`is_key_file`); False for anything but a regular file
    (a FIFO is never read: it blocks) and for a file that cannot be read."""
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode):
            return False
        os.set_blocking(fd, True)
        os.lseek(fd, 0, os.SEEK_SET)
        with open(fd, "rb", closefd=False) as fh:
            head = fh.read(_KEY_HEAD_BYTES)
            codec = _json_codec(head)
            tail, opened = b"", False
            for block in _utf8_blocks(fh, head, codec):
                if not opened:
                    block = block.lstrip(b" \t\r\n")  # the blanks JSON allows before a value
                    if block[:1] not in (b"{", b""):
                        return False  # not an object: no key
                    opened = bool(block)
                    if opened and _KEY_FORMAT_NAMED.search(block, 0, _KEY_HEAD_BYTES):
                        return True
                if _KEY_FORMAT_VALUE.search(tail + block[:_KEY_SPELLING_BYTES]) or _KEY_FORMAT_VALUE.search(block):
                    break  # (the first search: a spelling across the border of two blocks)
                tail = block[-_KEY_SPELLING_BYTES:]
            else:
                return False  # the format's value is nowhere: no loader takes it for a key
            if info.st_size > MAX_KEY_FILE_BYTES:
                return False  # the loader reads no such file
            fh.seek(0)
            raw = fh.read(MAX_KEY_FILE_BYTES + 1)
    except OSError:
        return False
    try:
        doc = json.loads(raw.decode(codec))
    except (UnicodeDecodeError, ValueError, RecursionError):  # the loader takes none of these for a key
        return False
    return isinstance(doc, dict) and doc.get("format") == KEY_FORMAT


def _utf8_blocks(fh, head: bytes, codec: str):
    """The file open as ``fh`` from its start (``head``: its first bytes, already read; ``codec``: its encoding) as
    blocks of UTF-8, its byte order mark dropped: as they are when it is UTF-8 (an ASCII character, all that JSON's
    syntax and the key's format are made of, is the same byte there, never part of another character), else decoded
    and encoded again."""
    decoder = None if codec.startswith("utf-8") else codecs.getincrementaldecoder(codec)(errors="replace")
    block = head.removeprefix(codecs.BOM_UTF8) if decoder is None else head
    while block:
        yield block if decoder is None else decoder.decode(block).encode("utf-8")
        block = fh.read(_KEY_SCAN_BYTES)


def _json_codec(head: bytes) -> str:
    """The codec of JSON text that starts with ``head``: by its byte order mark, else by where the NUL bytes of its
    first four bytes fall (RFC 4627 §3: its first two characters are ASCII); UTF-8 when neither says."""
    marked = bom_codec(head)
    if marked is not None:
        return marked
    nuls = tuple(byte == 0 for byte in head[:4])
    return {(True, True, True, False): "utf-32-be", (False, True, True, True): "utf-32-le",
            (True, False, True, False): "utf-16-be", (False, True, False, True): "utf-16-le"}.get(nuls, "utf-8")


def refuse_key_target(path, what: str) -> None:
    """WatermarkKeyError when the output ``path`` (a ``what``: ".pmw", "mesh") would replace a key file or
    take a key file's name (:func:`is_key_file`): a key file is never rewritten, by anything."""
    if is_key_file(path):
        raise WatermarkKeyError(f"{os.fspath(path)}: names a watermark key file; a {what} never replaces a key "
                                "(a key file is never rewritten): give the output another name")


def refuse_orphaned_beside(key_path, dst, marked: bool, key: "WatermarkKey | None" = None, *,
                           fingerprint: str | None = None, writer: str = "this encode",
                           states: tuple = ("writes no mark", "marks it with another key")) -> None:
    """WatermarkKeyError when writing the ``.pmw`` ``dst`` would leave ``key_path`` (its default key
    file, ``OUT.pmw.key.json``, when it exists) beside a file it no longer verifies: the file written carries no
    mark (``marked`` false), or another key's than that file's: ``key``, the key it marks with (None: a new one),
    as an encode with another image would (:class:`KeySlot` refuses that one), or ``fingerprint``, the key
    fingerprint the file written names (``pmw cut``).  A key of the same secret (a copy of the key file), or of
    that fingerprint, still verifies: not refused.  ``writer`` / ``states``: what writes the file and what its
    file then does (no mark, another key's), as the message says them."""
    if key_path is None or not os.path.lexists(key_path):
        return
    if marked and (key is not None or fingerprint is not None):
        try:
            beside = WatermarkKey.load(key_path)
            if (key is not None and beside.secret == key.secret) or \
                    (fingerprint is not None and beside.fingerprint() == fingerprint):
                return
        except WatermarkKeyError:
            pass
    what = states[1] if marked else states[0]
    raise WatermarkKeyError(f"{os.fspath(key_path)}: a watermark key lies beside {os.fspath(dst)}, and {writer} "
                            f"{what}: the file would no longer verify with it; the key and the "
                            "file are left untouched (write the output under another name, or move the key "
                            "away first to replace the marked file)")


def same_path(a, b) -> bool:
    """Whether the paths ``a`` and ``b`` name one file: the same existing file (links included), or
    the same place once symbolic links and ``..`` are resolved (for names not written yet)."""
    a, b = os.fspath(a), os.fspath(b)
    if any((b"\0" if isinstance(x, bytes) else "\0") in x for x in (a, b)):  # names no file (os.stat would
        # raise ValueError): compared as written
        return os.path.normpath(os.path.abspath(a)) == os.path.normpath(os.path.abspath(b))
    try:
        if os.path.samefile(a, b):
            return True
    except OSError:
        pass
    return os.path.realpath(a) == os.path.realpath(b)


@dataclass
class KeySlot:
    """The key file an encode marks with: its path and what it held when the encode began.

    Policy: a key file is never rewritten.  An existing key is reused as it is (same
    secret, its file untouched) when its reference watermark is the image being embedded,
    so one owner's key marks any number of assets with one logo, and every file it marked
    keeps verifying; a key for another image (or with none) is refused, untouched.  A
    missing key file is created (0600) in the same step that publishes the ``.pmw``.

    ``path`` str; ``existing`` the key loaded from it, or None when there was none;
    ``owner_id`` the owner ID the encode marks (None: no owner layer).  A key is reused
    only when it holds the same image and the same owner ID (or none for both).
    """

    path: str
    existing: WatermarkKey | None
    owner_id: int | None = None

    @classmethod
    def open(cls, path, image, owner_id=None) -> "KeySlot":
        """Check ``path`` for an encode that embeds ``image`` (s, s) uint8 (None: the owner layer
        alone) and the owner ID ``owner_id`` (None: no owner layer; :data:`FROM_KEY`: the key
        file's own owner ID, a random one when the file is new, none for a key written before
        the owner layer); WatermarkKeyError if refused.  The owner ID resolved is ``owner_id``."""
        path = refuse_symlink(path)
        if not os.path.lexists(path):
            return cls(path, None, random_owner_id() if owner_id == FROM_KEY else owner_id)
        existing = WatermarkKey.load(path)
        if owner_id == FROM_KEY:
            owner_id = existing.owner_id
        _check_reusable(path, existing, image, owner_id)
        return cls(path, existing, owner_id)

    def pending(self, key: WatermarkKey) -> bytes | None:
        """The bytes to write for ``key`` (None: reuse the file as it is).

        Called while the writer holds the directory lock: WatermarkKeyError when the file
        changed since :meth:`open` (another encode wrote a key there meanwhile).
        """
        refuse_symlink(self.path)
        now = WatermarkKey.load(self.path) if os.path.lexists(self.path) else None
        if self.existing is None:
            if now is not None:
                raise WatermarkKeyError(f"{self.path}: a key file appeared during the encode (another encode?); "
                                        "it is left untouched and nothing was written")
            return key.to_text()
        if now is None or now.secret != self.existing.secret or not _same_marks(now, key):
            raise WatermarkKeyError(f"{self.path}: the key file changed during the encode; "
                                    "it is left untouched and nothing was written")
        _make_private(self.path)
        return None


def _make_private(path: str) -> None:
    """Tighten a reused key file: clear its group and other permission bits (an older file may be 0644:
    it becomes 0600), never adding one (a key its owner made 0400 stays 0400); never follows a link."""
    fd = os.open(path, os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0))
    try:
        mode = stat.S_IMODE(os.fstat(fd).st_mode)
        if mode & 0o077:
            os.fchmod(fd, mode & ~0o077)
    finally:
        os.close(fd)


def _same_image(a, b) -> bool:
    return a is not None and b is not None and a.shape == b.shape and np.array_equal(a, b)


def _same_marks(a: WatermarkKey, b: WatermarkKey) -> bool:
    """The two keys mark alike: the same reference image (or none for both) and the same owner ID."""
    images = (a.reference is None and b.reference is None) or _same_image(a.reference, b.reference)
    return images and a.owner_id == b.owner_id


def check_key_object(key: WatermarkKey, image, owner_id: int | None) -> None:
    """WatermarkKeyError when a key object given to an encode holds another reference watermark than
    ``image`` (s, s) uint8 (None: the owner layer alone), or another owner ID than ``owner_id``: the file
    would not verify with it.  A key holding neither (a fresh :meth:`WatermarkKey.generate`) marks anything."""
    if key.reference is not None and image is not None and not _same_image(key.reference, np.asarray(image, np.uint8)):
        h, w = key.reference.shape
        raise WatermarkKeyError(f"the key object holds another watermark ({w}x{h}); the file would not verify "
                                "with it (a key marks with one image: use a new key)")
    if key.owner_id is not None and owner_id is not None and key.owner_id != owner_id:
        raise WatermarkKeyError(f"the key object names owner id {key.owner_hex}, not {owner_id:016x}; the owner "
                                "layer would not read with it (use a new key, or leave owner_id out)")


def _check_reusable(path: str, key: WatermarkKey, image, owner_id: int | None = None) -> None:
    if key.owner_id != owner_id:
        what = "names no owner id" if key.owner_id is None else (
            "names an owner id, and this encode writes no owner layer" if owner_id is None else "names another owner id")
        raise WatermarkKeyError(f"{path}: this key {what}; it is left untouched (name a new --key file)")
    if image is None:
        if key.reference is not None:
            raise WatermarkKeyError(f"{path}: this key holds a watermark image; an owner-only encode cannot "
                                    "reuse it (name a new --key file)")
        return
    if key.reference is None:
        raise WatermarkKeyError(f"{path}: this key holds no reference watermark, so it cannot be reused; "
                                "it is left untouched (name a new --key file)")
    if not _same_image(key.reference, np.asarray(image, np.uint8)):
        h, w = key.reference.shape
        raise WatermarkKeyError(f"{path}: this key holds another watermark ({w}x{h}); it is left untouched "
                                "(a key marks with one image: name a new --key file, or remove this one)")