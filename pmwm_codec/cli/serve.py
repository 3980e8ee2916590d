"""``pmw serve DIR [--port P] [--host 127.0.0.1]``: a small static server with Range support, for local demos.

The standard library's ``http.server`` plus single-range ``Range: bytes=a-b`` requests
(``206 Partial Content``, ``416`` when unsatisfiable), so that ``pmw verify URL``, the
three.js plugin and the demo page can read a ``.pmw`` chunk by chunk.  Only files under
``DIR`` are served: the standard library's path translation, then the path's real location
(symbolic links followed) must be inside ``DIR``'s.  Key files (``*.key.json`` in any case: ``pmw encode``
writes the secret key beside the ``.pmw``; or a key under any other name, ``--key site/k.json``) are never served, and directories are not listed
(a folder's ``index.html``, or ``index.htm``, is served for ``GET /folder/`` after the same checks as any
file).  A ``Range`` with an ``If-Range`` whose validator is not the file's current one gets the whole file
(200, RFC 9110 §13.1.5).  It binds to 127.0.0.1 unless ``--host`` says otherwise (never to every
interface for an empty ``--host``).  Not a production server.
"""

from __future__ import annotations

import datetime
import email.utils
import os
import re
import threading
import time
from functools import partial
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

from pmwm_codec.watermark.key import is_key_file  # never served: the secret key files, by name or by content

from .common import UsageError

_RANGE = re.compile(r"bytes=(\d*)-(\d*)\s*$")
#: What :meth:`RangeRequestHandler.translate_path` gives for a path it refuses: no file can be there.
_NOWHERE = os.path.join(os.devnull, "refused")


def add_parser(sub):
    p = sub.add_parser("serve", help="serve a directory over HTTP with Range support (local demos)",
                       description="Serve the files of DIR over HTTP, with single-range Range requests, for local "
                                   "demos of progressive loading (pmw verify URL, the three.js plugin). Ctrl-C stops it.")
    p.add_argument("directory", metavar="DIR", help="the directory to serve")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only)")
    p.set_defaults(run=run)


def parse_range(header: str | None, size: int):
    """``(start, end)`` (end exclusive) of a single ``bytes=`` range of a ``size``-byte file.

    None when there is no usable single range (absent, several ranges, another unit, a last
    byte before the first: RFC 9110 §14.1.1 calls that invalid, to be ignored: the whole file
    is sent); ``(size, size)`` when it cannot be satisfied (416).
    """
    match = _RANGE.match(header or "")
    if match is None or match[1] == match[2] == "":
        return None
    first, last = (_offset(m) for m in (match[1], match[2]))
    if first is not None and last is not None and last < first:
        return None
    if first is None:  # suffix: the last n bytes
        return (max(0, size - last), size) if last else (size, size)
    start = first
    end = size if last is None else min(last + 1, size)
    if start >= size or end <= start:
        return (size, size)
    return start, end


def _offset(digits: str):
    """A byte offset of a Range header (None for none); past any file at 19 digits and more (``int()`` of
    thousands of digits raises, and is slow before that)."""
    if digits == "":
        return None
    return int(digits) if len(digits) < 19 else 1 << 63


class RangeRequestHandler(SimpleHTTPRequestHandler):
    """``SimpleHTTPRequestHandler`` answering single-range requests with 206.

    ``server.bytes_sent`` (when the server has it) counts the body bytes sent.
    """

    protocol_version = "HTTP/1.1"

    def translate_path(self, path):
        """The standard library's translation, refused (a path where no file can be: 404) when the
        file's real location is outside the served directory (a symbolic link out of it), when it is a
        key file (:func:`~pmwm_codec.watermark.key.is_key_file`: by its name, or by its content), when it
        is neither a regular file nor a folder (a FIFO: opening it blocks the answer forever), or when the
        name cannot be a file name (a NUL byte).  A folder asked with a final ``/`` is its ``index.html``
        (else ``index.htm``), through the same checks, and refused when it has none: given the folder, the
        standard library's ``send_head`` would pick that file itself, unchecked."""
        local = self._checked(super().translate_path(path))
        if local.endswith("/") and os.path.isdir(local):
            for name in ("index.html", "index.htm"):
                index = os.path.join(local, name)
                if os.path.isfile(index):
                    return self._checked(index)
            return _NOWHERE  # no listing either
        return local

    def _checked(self, local: str) -> str:
        """``local`` when it may be served (:meth:`translate_path`), else :data:`_NOWHERE`."""
        try:
            real, root = os.path.realpath(local), os.path.realpath(self.directory)
        except (ValueError, OSError):
            return _NOWHERE
        if os.path.commonpath([real, root]) != root or is_key_file(real) or is_key_file(local):
            return _NOWHERE
        if os.path.exists(real) and not (os.path.isfile(real) or os.path.isdir(real)):
            return _NOWHERE
        return local

    def list_directory(self, path):
        """No listings: the names in a folder are not the client's business (a key file's among them)."""
        self.send_error(HTTPStatus.NOT_FOUND, "No directory listing")
        return None

    def send_head(self):
        self._etag = self._length = None
        path = self.translate_path(self.path)
        if os.path.isfile(path):
            self._etag = etag(os.stat(path))
        if "Range" not in self.headers or not os.path.isfile(path):
            return super().send_head()
        try:
            f = open(path, "rb")
        except OSError:
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        info = os.fstat(f.fileno())
        size, self._etag = info.st_size, etag(info)
        span = parse_range(self.headers["Range"], size)
        if span is None or not self._if_range_holds(info):
            f.close()
            return super().send_head()
        if span[0] >= size:
            f.close()
            self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        self.send_response(HTTPStatus.PARTIAL_CONTENT)
        self.send_header("Content-Type", self.guess_type(path))
        self.send_header("Content-Range", f"bytes {span[0]}-{span[1] - 1}/{size}")
        self.send_header("Content-Length", str(span[1] - span[0]))
        self.send_header("Last-Modified", self.date_time_string(info.st_mtime))
        self.end_headers()
        f.seek(span[0])
        return f

    def _if_range_holds(self, info: os.stat_result) -> bool:
        """Whether a Range request's ``If-Range`` (RFC 9110 §13.1.5) lets the range be sent: no ``If-Range``,
        or its validator is the file's current one, the strong :func:`etag` exactly, or the ``Last-Modified``
        date exactly when that date is a strong validator (the file unchanged for a second since, §8.8.2.2).
        Any other (a weak or old tag, another date, a date that does not parse): the whole file is sent."""
        given = self.headers.get("If-Range")
        if given is None:
            return True
        given = given.strip()
        if given.startswith(('"', "W/")):
            return given == etag(info)
        try:
            date = email.utils.parsedate_to_datetime(given)
        except (TypeError, ValueError, IndexError, OverflowError):
            return False
        if date.tzinfo is None:
            date = date.replace(tzinfo=datetime.timezone.utc)
        return int(date.timestamp()) == int(info.st_mtime) and time.time() - info.st_mtime >= 1

    def send_header(self, keyword, value):
        if keyword.lower() == "content-length":
            self._length = int(value)
        super().send_header(keyword, value)

    def copyfile(self, source, outputfile):
        """The body: the ``Content-Length`` announced, or less when the file shrank meanwhile (copied over by a
        writer that is not atomic); the connection is then closed, which tells the client the body ended early
        (kept open, the client would wait for the missing bytes)."""
        left = getattr(self, "_length", None)
        while left is None or left > 0:
            block = source.read(1 << 16 if left is None else min(1 << 16, left))
            if not block:
                break
            _count(self.server, len(block))  # before the write: a client never sees bytes not yet counted
            outputfile.write(block)
            if left is not None:
                left -= len(block)
        if left:
            self.close_connection = True

    def end_headers(self):
        self.send_header("Accept-Ranges", "bytes")
        if getattr(self, "_etag", None) is not None:  # a reader by ranges tells a file replaced meanwhile
            self.send_header("ETag", self._etag)
        super().end_headers()

    def log_message(self, format, *args):  # noqa: A002 - the standard library's name
        if getattr(self.server, "verbose", False):
            super().log_message(format, *args)


def etag(info: os.stat_result) -> str:
    """A strong ``ETag`` of a file from its ``stat``: size and modification time (nanoseconds)."""
    return f'"{info.st_size:x}-{info.st_mtime_ns:x}"'


def _count(server, n: int) -> None:
    lock = getattr(server, "count_lock", None)
    if lock is not None:
        with lock:
            server.bytes_sent += n


class _Server(ThreadingHTTPServer):
    """A client that goes away mid-answer is its own business: no traceback for it."""

    def handle_error(self, request, client_address):
        import sys

        if not isinstance(sys.exc_info()[1], ConnectionError):
            super().handle_error(request, client_address)


def make_server(directory, host: str = "127.0.0.1", port: int = 0, handler=RangeRequestHandler):
    """A ``ThreadingHTTPServer`` serving ``directory`` with ``handler``; not started.

    It counts body bytes in ``bytes_sent`` (under ``count_lock``).
    """
    server = _Server((host, port), partial(handler, directory=os.fspath(directory)))
    server.bytes_sent = 0
    server.count_lock = threading.Lock()
    server.daemon_threads = True
    return server


def run(args) -> int:
    if not os.path.isdir(args.directory):
        raise UsageError(f"{args.directory}: not a directory")
    if not 0 <= args.port <= 65535:
        raise UsageError(f"--port {args.port}: not a TCP port (0..65535)")
    if not args.host.strip():
        raise UsageError(f"--host {args.host!r}: no address (an empty one binds every interface); give one, "
                         "127.0.0.1 for this machine only or 0.0.0.0 for every interface")
    try:
        server = make_server(args.directory, args.host, args.port)
    except OSError as exc:  # a name that does not resolve, an address not of this machine, a port in use
        raise UsageError(f"--host {args.host} --port {args.port}: cannot listen there "
                         f"({exc.strerror or exc})") from None
    server.verbose = True
    host, port = server.server_address[:2]
    print(f"serving {os.path.abspath(args.directory)} at http://{host}:{port}/ (Ctrl-C to stop)", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0

