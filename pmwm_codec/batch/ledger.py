"""The batch ledger ``OUT_DIR/pmw-batch.jsonl``: one JSON line per asset and attempt.

Each line::

    {"input": "/abs/in.obj", "input_sha256": "<64 hex>" | null, "output": "/abs/out/in.obj.pmw",
     "status": "ok" | "failed" | "skipped" | "timeout", "error": "<one line>" | null,
     "seconds": 1.25, "bytes": 10724 | null, "vertices": 800 | null, "settings_sha256": "<64 hex>",
     "output_sha256": "<64 hex>" | null}

``bytes`` and ``output_sha256`` are the output's size and SHA-256 as the row found it (ok: as written;
skipped: as checked): a re-run skips an asset only while its output still has them, so an output
truncated or damaged since (a partial copy or sync) is redone.  A row of an older run has no
``output_sha256``; its size alone is compared.

``settings_sha256`` names what the output was made with besides the input (see
:func:`settings_sha256`): a re-run with another watermark or key redoes the asset.

Only the client appends, one whole line per finished attempt, flushed at once; a run
killed mid-write leaves at most a cut last line, which :func:`read_ledger` ignores and the
next :class:`LedgerWriter` terminates before appending.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import json
import os

__all__ = ["LEDGER_NAME", "FIELDS", "STATUSES", "read_ledger", "last_rows", "LedgerWriter", "sha256_file", "input_sha256",
           "settings_sha256"]

LEDGER_NAME = "pmw-batch.jsonl"
FIELDS = ("input", "input_sha256", "output", "status", "error", "seconds", "bytes", "vertices", "settings_sha256",
          "output_sha256")
STATUSES = ("ok", "failed", "skipped", "timeout")


def sha256_file(path, block: int = 1 << 20) -> str:
    """Hex SHA-256 of a regular file, read in ``block``-byte pieces; InputFormatError for anything else (a
    FIFO or ``/dev/zero`` in a library or a manifest would never end)."""
    from pmwm_codec.sources import open_regular_file

    h = hashlib.sha256()
    with open_regular_file(path) as fh:
        for piece in iter(lambda: fh.read(block), b""):
            h.update(piece)
    return h.hexdigest()


def input_sha256(path) -> str:
    """Hex SHA-256 of an input as the encode reads it: the file's own (:func:`sha256_file`) when it names no other
    file, else one over it and every file it names (a ``.gltf``'s buffers and images, an OBJ's MTL files and
    their textures, a PLY's textures: :func:`pmwm_codec.meshdoc.named_files`), with their paths relative to the
    input's folder -- so a re-run redoes an asset whose texture changed, or moved, as it does one whose own
    bytes did.  InputFormatError / OSError as :func:`sha256_file` for the input itself."""
    from pmwm_codec.meshdoc import named_files

    own = sha256_file(path)
    named = named_files(path)
    if not named:
        return own
    folder = os.path.dirname(os.path.realpath(path))
    files = [[os.path.relpath(f, folder), sha256_file(f)] for f in named]
    return hashlib.sha256(json.dumps({"input": own, "files": files}).encode()).hexdigest()


def settings_sha256(image, key_mode: str, key_fingerprint: str | None, options: dict | None = None) -> str:
    """Hex SHA-256 of everything but the input that decides an output's bytes and its key.

    image: (s, s) uint8 watermark or None; key_mode: ``collection`` | ``beside`` | ``keys-dir``;
    key_fingerprint: the collection key's fingerprint (None otherwise); options: the encode
    options (JSON-able; none or empty: the defaults, hashed as before options existed, so a
    ledger of an older run still skips).  The package's container version is in it too, so
    that a newer format redoes old outputs.
    """
    from pmwm_codec.constants import FORMAT_VERSION

    fields = {"format": FORMAT_VERSION, "key": key_mode, "fingerprint": key_fingerprint,
              "image": None if image is None else list(image.shape)}
    if options:
        fields["options"] = options
    h = hashlib.sha256(json.dumps(fields, sort_keys=bool(options)).encode())
    if image is not None:
        h.update(image.astype("uint8").tobytes())
    return h.hexdigest()


#: The type each field of a well-formed row has (or None): a row edited by hand into another shape is not one.
_FIELD_TYPES = {"input": str, "input_sha256": str, "output": str, "status": str, "error": str,
                "seconds": (int, float), "bytes": int, "vertices": int, "settings_sha256": str, "output_sha256": str}


def _no_constant(name):
    raise ValueError(f"{name} is not JSON")  # NaN, Infinity: a row that could never be written back


def _well_formed(row) -> bool:
    if not isinstance(row, dict) or row.get("status") not in STATUSES or not isinstance(row.get("input"), str):
        return False
    return all(row.get(name) is None or (isinstance(row[name], kind) and not isinstance(row[name], bool))
               for name, kind in _FIELD_TYPES.items())


def _open_ledger(path):
    """The ledger at ``path`` opened for reading, or None when there is none.  A symbolic link, a FIFO, a device
    or a folder in its place is an OSError naming it, before anything is read (a FIFO never blocks the run, a
    link to ``/dev/zero`` is never read without end): the run appends to this file in place."""
    import stat

    path = os.fspath(path)
    if os.path.islink(path):
        raise OSError(errno.ELOOP, "is a symbolic link: the ledger is appended in place, never through a link "
                      "(remove the link)", path)
    flags = os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0)
    try:
        fd = os.open(path, flags)
    except FileNotFoundError:
        return None
    try:
        mode = os.fstat(fd).st_mode
        if not stat.S_ISREG(mode):
            what = "a folder" if stat.S_ISDIR(mode) else "not a regular file (a FIFO, a device or a socket)"
            raise OSError(errno.EINVAL, f"is {what}: the ledger is a file the run appends to (move it away)", path)
        os.set_blocking(fd, True)
        return os.fdopen(fd, "r", encoding="utf-8", errors="replace")
    except BaseException:
        os.close(fd)
        raise


def read_ledger(path) -> list[dict]:
    """Every well-formed row of the ledger at ``path`` (none when it does not exist).

    A line that is not a JSON object of the row's fields with their types (cut by a killed run, or edited by
    hand: a ``NaN``, a count written as text) is left out: its asset is done again.  OSError, before anything
    is read, when the ledger is a symbolic link or not a regular file (:func:`_open_ledger`)."""
    rows = []
    fh = _open_ledger(path)
    if fh is None:
        return rows
    with fh:
        for line in fh:
            try:
                row = json.loads(line, parse_constant=_no_constant)
            except (ValueError, RecursionError):
                continue  # a line cut by a killed run, or not a row
            if _well_formed(row):
                rows.append(row)
    return rows


def last_rows(rows) -> dict:
    """The latest row per input path: ``{input: row}``."""
    return {row["input"]: row for row in rows}


def unshare(path: str) -> None:
    """Give the file at ``path`` a copy of its own when it is one of several names of a file (a hard link: a
    ``cp -al`` or ``rsync --link-dest`` snapshot of OUT_DIR shares it), published by a rename, so that what is
    appended next goes into this ledger only, never into the snapshot's.  Any other file is left as it is."""
    import shutil
    import stat
    import uuid

    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return
    if not stat.S_ISREG(st.st_mode) or st.st_nlink < 2:
        return
    folder, name = os.path.split(os.path.abspath(path))
    temp = os.path.join(folder, f".{name}.{uuid.uuid4().hex[:12]}.tmp")
    try:
        shutil.copyfile(path, temp)
        os.chmod(temp, stat.S_IMODE(st.st_mode))
        with open(temp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.replace(temp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise OSError(exc.errno, f"{exc.strerror or exc} (copying the ledger, a hard link, to a file of its own)",
                      path) from None


class LedgerWriter:
    """Append rows to the ledger; a context manager (the file stays open for the run).

    Each row is one ``write`` of its whole line, unbuffered; a row that cannot be written whole (a full
    disk) is taken back (the file cut to where it was, when it can be) and the OSError names the ledger and
    the row's input: that asset has no row, and the next run does it again.  A ledger that is a hard link is
    given a file of its own first (:func:`unshare`): rows are never appended to another tree's ledger; one that
    is a symbolic link is refused (OSError): it could make the run append to any file the link names.
    """

    def __init__(self, path):
        self.path = os.fspath(path)
        self._fd = None

    def __enter__(self):
        if os.path.islink(self.path):  # appended in place: through a link it could be any file of the user's
            raise OSError(errno.ELOOP, "is a symbolic link: the ledger is appended in place, never through a link "
                          "(remove the link)", self.path)
        unshare(self.path)
        cut = False
        if os.path.exists(self.path) and os.path.getsize(self.path):
            with open(self.path, "rb") as fh:
                fh.seek(-1, os.SEEK_END)
                cut = fh.read(1) != b"\n"
        self._fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT | getattr(os, "O_NOFOLLOW", 0), 0o666)
        try:
            if cut:
                self._append(b"\n")
        except OSError as exc:
            self.__exit__()
            raise OSError(exc.errno, exc.strerror or str(exc), self.path) from None
        return self

    def _append(self, data: bytes) -> None:
        try:
            size = os.fstat(self._fd).st_size
        except OSError:
            size = None
        view = memoryview(data)
        try:
            while view:
                view = view[os.write(self._fd, view):]
        except OSError:
            if size is not None:
                with contextlib.suppress(OSError):
                    os.ftruncate(self._fd, size)  # no cut line left behind
            raise

    def write(self, row: dict) -> None:
        line = json.dumps({name: row.get(name) for name in FIELDS}, allow_nan=False) + "\n"
        try:
            self._append(line.encode("utf-8"))
        except OSError as exc:
            raise OSError(exc.errno, f"{exc.strerror or exc} (the row of {row.get('input')} was not written)",
                          self.path) from None

    def __exit__(self, *exc):
        if self._fd is not None:
            fd, self._fd = self._fd, None
            os.close(fd)
        return False
