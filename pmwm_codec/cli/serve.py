"""``pmw serve DIR [--port P] [--host 127.0.0.1]``: a small static server with Range support, for local demos.

The standard library's ``http.server`` plus single-range ``Range: bytes=a-b`` requests
(``206 Partial Content``, ``416`` when unsatisfiable), so that ``pmw verify URL``, the
three.js plugin and the demo page can read a ``.pmw`` chunk by chunk.  Only files under
``DIR`` are served: the standard library's path translation, then the file is opened one
component at a time below ``DIR`` without following symbolic links (one is followed only
when its target lies inside ``DIR``: :func:`open_inside`), and the checks are made on the
file opened, so a name swapped for a link, a key or a FIFO between a check and the open
serves nothing.  Key files (``*.key.json`` in any case: ``pmw encode`` writes the secret key
beside the ``.pmw``; or a key under any other name, ``--key site/k.json``) are never served,
and directories are not listed (a folder's ``index.html``, or ``index.htm``, is served for
``GET /folder/`` after the same checks as any file).  A ``Range`` with an ``If-Range`` whose validator is not the file's current one gets the whole file
(200, RFC 9110 §13.1.5).  It binds to 127.0.0.1 unless ``--host`` says otherwise (never to every
interface for an empty ``--host``), or an IPv6 address (``::1``, ``::``; its URL in brackets).  Not a production
server.
"""

from __future__ import annotations

import contextlib
import datetime
import email.utils
import errno
import os
import re
import socket
import stat
import threading
import time
import urllib.parse
from functools import partial
from http import HTTPStatus
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer

from pmwm_codec.watermark.key import KEY_SUFFIX, is_key_file  # never served: the secret key files, by name or content

from .common import UsageError

_RANGE = re.compile(r"bytes=(\d*)-(\d*)\s*$")
#: Symbolic links :func:`open_inside` follows in one path at most (the kernel's own limit, ELOOP).
_MAX_LINKS = 40
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)


def add_parser(sub):
    p = sub.add_parser("serve", help="serve a directory over HTTP with Range support (local demos)",
                       description="Serve the files of DIR over HTTP, with single-range Range requests, for local "
                                   "demos of progressive loading (pmw verify URL, the three.js plugin). Ctrl-C stops it.")
    p.add_argument("directory", metavar="DIR", help="the directory to serve")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default 8000; 0: any free port)")
    p.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1: this machine only); an "
                                                       "IPv6 address too, ::1 or :: (every interface)")
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
    #: TCP_NODELAY: a kept-alive connection's next answer is not held back until the client acknowledges the
    #: last one (the headers and body of an answer are separate writes; with Nagle's rule and the client's
    #: delayed acknowledgement each request on a kept-alive connection waited ~20-40 ms)
    disable_nagle_algorithm = True

    def send_head(self):
        """The answer's status and headers; the file to send (None: nothing more to send).

        The file the standard library's translation names is opened by :func:`open_inside` and checked as
        opened (``fstat``, its content): a folder asked with a final ``/`` is its ``index.html`` (else
        ``index.htm``), without one 404 (no listing), asked without it a redirect to it; anything but a regular
        file (a FIFO: reading it would block the answer forever), a key file (:func:`is_key_file`: by the name
        asked for or the real one, or by its content) and a name no file can have (a NUL byte) is 404.  Then
        a usable single ``Range`` (:func:`parse_range`) whose ``If-Range`` holds gets 206 (416 past the end),
        anything else the whole file: 200, or 304 for an ``If-Modified-Since`` the file has not changed since."""
        self._etag = self._length = None
        local = self.translate_path(self.path)
        opened = self._open(local)
        if opened is not None and stat.S_ISDIR(os.fstat(opened[0]).st_mode):
            os.close(opened[0])
            parts = urllib.parse.urlsplit(self.path)
            if not parts.path.endswith("/"):  # a redirect to the folder, as the standard library answers
                self.send_response(HTTPStatus.MOVED_PERMANENTLY)
                self.send_header("Location", urllib.parse.urlunsplit(parts._replace(path=parts.path + "/")))
                self.send_header("Content-Length", "0")
                self.end_headers()
                return None
            local, opened = self._index(local)
        if opened is None:
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        fd, real = opened
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or local.lower().endswith(KEY_SUFFIX) or is_key_file(real, fd):
            os.close(fd)
            self.send_error(HTTPStatus.NOT_FOUND, "File not found")
            return None
        os.set_blocking(fd, True)
        f = os.fdopen(fd, "rb")
        try:
            return self._answer(f, info, local)
        except BaseException:
            f.close()
            raise

    def _open(self, local: str):
        """``(fd, real path)`` of ``local`` (a path :meth:`translate_path` gave) opened by :func:`open_inside`
        below the served directory; None when there is no such file there, or it cannot be served from there."""
        directory = os.path.join(self.directory, "")
        if not local.startswith(directory):
            return None
        try:
            return open_inside(self.directory, local[len(directory):])
        except (OSError, ValueError):  # missing, outside, unreadable; a NUL byte
            return None

    def _index(self, folder: str) -> tuple:
        """``(path, opened)`` of the folder's ``index.html``, else ``index.htm``: the first that is a regular file
        (:meth:`_open`); ``(folder, None)`` when neither is."""
        for name in ("index.html", "index.htm"):
            path = os.path.join(folder, name)
            opened = self._open(path)
            if opened is not None:
                if stat.S_ISREG(os.fstat(opened[0]).st_mode):
                    return path, opened
                os.close(opened[0])
        return folder, None

    def _answer(self, f, info: os.stat_result, local: str):
        """The status and headers for the regular file open as ``f`` (``info``: its ``fstat``), named ``local``."""
        size, self._etag = info.st_size, etag(info)
        span = parse_range(self.headers["Range"], size) if "Range" in self.headers else None
        if span is None or not self._if_range_holds(info):
            if self._not_modified(info):
                f.close()
                self.send_response(HTTPStatus.NOT_MODIFIED)
                self.end_headers()
                return None
            self.send_response(HTTPStatus.OK)
            span = (0, size)
        elif span[0] >= size:
            f.close()
            self.send_response(HTTPStatus.REQUESTED_RANGE_NOT_SATISFIABLE)
            self.send_header("Content-Range", f"bytes */{size}")
            self.send_header("Content-Length", "0")
            self.end_headers()
            return None
        else:
            self.send_response(HTTPStatus.PARTIAL_CONTENT)
            self.send_header("Content-Range", f"bytes {span[0]}-{span[1] - 1}/{size}")
        self.send_header("Content-Type", self.guess_type(local))
        self.send_header("Content-Length", str(span[1] - span[0]))
        self.send_header("Last-Modified", self.date_time_string(info.st_mtime))
        self.end_headers()
        f.seek(span[0])
        return f

    def _not_modified(self, info: os.stat_result) -> bool:
        """Whether a whole-file request's ``If-Modified-Since`` (without ``If-None-Match``) is not older than the
        file's last modification, to the second (304, as the standard library answers)."""
        if "If-Modified-Since" not in self.headers or "If-None-Match" in self.headers:
            return False
        try:
            since = email.utils.parsedate_to_datetime(self.headers["If-Modified-Since"])
        except (TypeError, ValueError, IndexError, OverflowError):
            return False
        if since.tzinfo is None:
            since = since.replace(tzinfo=datetime.timezone.utc)
        return since.tzinfo is datetime.timezone.utc and int(info.st_mtime) <= since.timestamp()

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


def open_inside(root, relative: str) -> tuple:
    """``(fd, real)``: the file or folder the path ``relative`` names below ``root``, opened read-only
    without blocking (a FIFO opens at once: the caller looks at it with ``fstat`` first), and its real path.

    Each component is opened relative to the folder opened before it (``dir_fd``) with ``O_NOFOLLOW``: what it
    opens is what is there at that moment, never what a path pointed to when it was checked.  A symbolic link met
    on the way (``readlink``) is followed only when its target, resolved, lies inside ``root``: the walk starts
    again from ``root`` along that target, so a link inside the tree is served and one out of it (or swapped in
    meanwhile) is not.  OSError when the file is not there, a link leads out of ``root`` (``EACCES``) or there are
    more than :data:`_MAX_LINKS` of them; ValueError for a name with a NUL byte."""
    root = os.path.realpath(root)
    parts, links = relative.split(os.sep), 0
    if ".." in parts:
        raise OSError(errno.EACCES, "outside the served directory")
    while True:
        parts = [part for part in parts if part not in ("", ".")]
        fd = os.open(root, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | _CLOEXEC)
        try:
            for i, part in enumerate(parts):
                last = i == len(parts) - 1
                flags = os.O_RDONLY | os.O_NOFOLLOW | _CLOEXEC | (os.O_NONBLOCK if last else os.O_DIRECTORY)
                try:
                    opened = os.open(part, flags, dir_fd=fd)
                except OSError as exc:
                    try:
                        target = os.readlink(part, dir_fd=fd)
                    except OSError:
                        raise exc from None  # not a link: missing, not a folder ...
                    break
                os.close(fd)
                fd = opened
            else:
                return fd, os.path.join(root, *parts)
        except BaseException:
            os.close(fd)
            raise
        os.close(fd)
        links += 1
        resolved = os.path.realpath(os.path.join(root, *parts[:i], target))
        if links > _MAX_LINKS or os.path.commonpath([resolved, root]) != root:
            raise OSError(errno.EACCES if links <= _MAX_LINKS else errno.ELOOP, "outside the served directory")
        parts = os.path.relpath(resolved, root).split(os.sep) + parts[i + 1:]


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


class _Server6(_Server):
    """:class:`_Server` on an IPv6 address; on ``::`` (every interface) it takes IPv4 clients too where the system
    lets it, as ``python -m http.server --bind ::`` does."""

    address_family = socket.AF_INET6

    def server_bind(self):
        with contextlib.suppress(AttributeError, OSError):
            self.socket.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 0)
        super().server_bind()


def make_server(directory, host: str = "127.0.0.1", port: int = 0, handler=RangeRequestHandler):
    """A ``ThreadingHTTPServer`` serving ``directory`` with ``handler``; not started.

    ``host``: a name or an IPv4 address, or an IPv6 address (``::1``; in brackets too, ``[::1]``; a link-local one
    with its zone, ``fe80::1%eth0``).  It counts body
    bytes in ``bytes_sent`` (under ``count_lock``).
    """
    if host.startswith("[") and host.endswith("]"):
        host = host[1:-1]
    address = (host, port)
    if ":" in host:  # an IPv6 address; with its zone (fe80::1%eth0), the interface's scope id binds with it
        address = socket.getaddrinfo(host, port, socket.AF_INET6, socket.SOCK_STREAM)[0][4]
    server_class = _Server6 if ":" in host else _Server  # (a name or an IPv4 address has no colon)
    server = server_class(address, partial(handler, directory=os.fspath(directory)))
    server.bytes_sent = 0
    server.count_lock = threading.Lock()
    server.daemon_threads = True
    return server


def server_url(server) -> str:
    """The URL of the root of what ``server`` serves: an IPv6 address in brackets (``http://[::1]:8000/``, a zone's
    ``%`` as ``%25``, RFC 6874)."""
    host, port = server.server_address[:2]
    scope = server.server_address[3] if len(server.server_address) > 3 else 0
    if scope and "%" not in host:  # a link-local address: the URL names its interface (getsockname gives its index)
        with contextlib.suppress(OSError):
            host += "%" + socket.if_indextoname(scope)
    return f"http://[{host.replace('%', '%25')}]:{port}/" if ":" in host else f"http://{host}:{port}/"


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
    print(f"serving {os.path.abspath(args.directory)} at {server_url(server)} (Ctrl-C to stop)", flush=True)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
    return 0

