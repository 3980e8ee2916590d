"""Reading a ``.pmw`` over HTTP: a byte source for a URL the user named.

:class:`UrlSource` is an iterable of byte blocks (a *source* in the sense of
:mod:`pmwm_codec.sources`), so every reader takes it as it takes a file.  It asks for
the first bytes with a ``Range`` request:

* the server honours it (``206``): three requests (:func:`plan_ranges`), the GLB
  preamble (20 bytes), the JSON with the BIN chunk header, then everything the reader
  needs after them in one: the base mesh and the chunks in stream order, up to the file
  length, or with ``max_chunks=N`` up to the end of the N-th chunk (nothing after it is
  requested).  Its body is handed on as it arrives, so each chunk reaches the decoder
  as soon as its own bytes are in; a server that answers with fewer bytes than asked
  is asked for the rest, as often as it takes.
* the server ignores it (``200``): the body is read as one plain streamed GET, in
  blocks, up to the file length the GLB header declares (a body that goes on is
  refused), stopped after the N-th chunk when ``max_chunks`` is given; a gzip or deflate
  ``Content-Encoding`` is undone as it is read (a ranged answer in one is refused).

A connection that ends early is a cut stream, read with the same semantics as a cut
file (every complete chunk is delivered).  A server that sends nothing for ``timeout``
seconds stalls, and the whole transfer is bounded too, not per request, a host name's
lookup included (:meth:`UrlSource._step`).  Only ``http://`` and ``https://`` URLs are
accepted, and only where the caller passed one (:func:`is_url`): nothing read from a
file ever makes us fetch anything; a redirect to another scheme, or to a URL with a user
name or password, is refused.  Network failures and inconsistent servers raise
:class:`~pmwm_codec.errors.InputFormatError` naming the URL (a redirect's target as
:func:`shown_url` shows it: never its password or query), and so does a file that
changes between the requests (its size, ``ETag`` or ``Last-Modified``).
:func:`read_declared` reads a stream whole (a URL, standard input) no further than its
declared length.
"""

from __future__ import annotations

import bisect
import contextlib
import http.client
import ipaddress
import os
import re
import socket
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
import zlib

from .constants import MAX_INPUT_FILE_BYTES
from .errors import FormatError, InputFormatError, LimitError
from .format import ContainerParser, HeaderEvent
from .format.extension import chunk_start
from .format.layout import CHUNK_HEADER_SIZE, PREAMBLE_SIZE
from .format.parser import parse_preamble, trailing_bytes
from .sources import DEFAULT_BLOCK_SIZE, iter_blocks, read_all, resolve_stdin

#: Seconds one network step may take (a host name's lookup, a request up to its answer's head, one read of a
#: body: a server that sends nothing that long stalls), and the network time a transfer has before its pace counts.
DEFAULT_TIMEOUT = 30.0
#: Bytes per second a transfer must average past its first ``timeout`` seconds of network time
#: (:meth:`UrlSource._step`): a floor under any link HTTP runs on (512 bit/s), so that only a server that holds
#: the reader with a trickle is refused, not a slow link.
MIN_RATE = 64
_CONTENT_RANGE = re.compile(r"bytes\s+(\d{1,19})-(\d{1,19})/(\d{1,19}|\*)\s*$")  # (int() of 5000 digits raises)


def is_url(source) -> bool:
    """True for a ``str`` starting with ``http://`` or ``https://`` (any case)."""
    return isinstance(source, str) and source[:8].lower().startswith(("http://", "https://"))


def as_source(source, max_chunks: int | None = None, whole_document: bool = False):
    """A :class:`UrlSource` for a URL string (reading up to ``max_chunks`` chunks; ``whole_document``: and
    the document's other data, see :func:`plan_ranges`), any other source unchanged."""
    return UrlSource(source, max_chunks=max_chunks, whole_document=whole_document) if is_url(source) else source


def stream_end(source, end):
    """``end`` (a :class:`~pmwm_codec.stream.StreamEnd` of a read of ``source``) as the file is: a
    :class:`UrlSource` that stopped after the chunks asked for fetched no more, and the file on the server
    is complete when its size is its GLB length (it is not a cut file because we did not fetch the rest)."""
    if isinstance(source, UrlSource) and source.stopped and not end.complete and source.file_size is not None:
        from dataclasses import replace

        return replace(end, complete=source.file_size == end.total_length)
    return end


def _split(url: str) -> tuple:
    """``(start, netloc, tail)`` of a URL: ``scheme://`` (empty when there is none), the authority up to the
    first ``/``, ``?`` or ``#`` (a user name and password, the host, the port) and the path, query and fragment."""
    scheme, sep, rest = url.partition("://")
    if not sep:
        return "", "", url
    end = min((i for i in map(rest.find, "/?#") if i >= 0), default=len(rest))
    return scheme + sep, rest[:end], rest[end:]


def shown_url(url: str) -> str:
    """``url`` (a server's, or one refused for its password) as a message names it: without a user name and
    password (``...@``) or a query and fragment (``?...``), where a redirect to a signed link carries its
    credentials (``?X-Amz-Signature=``, ``?token=``), which must not be copied into a terminal or a log; the
    scheme, host, port and path say which file it is.  The URL the caller named is named as it was given
    (refused at once if it holds a password): its query is the caller's own, already on the command line."""
    start, netloc, tail = _split(url)
    at = "...@" if "@" in netloc else ""
    path = re.split(r"[?#]", tail, maxsplit=1)
    return start + at + netloc.rpartition("@")[2] + path[0] + ("?..." if len(path) > 1 else "")


def _request_url(url: str) -> str:
    """``url`` in ASCII, as a browser sends it (RFC 3987 §3.1): a non-ASCII host name in IDNA (``xn--``),
    any other non-ASCII character percent-encoded as UTF-8 (``café.pmw``: ``caf%C3%A9.pmw``);
    :class:`~pmwm_codec.errors.InputFormatError` when it cannot be (a host name label over 63 characters)."""
    if url.isascii():
        return url
    start, netloc, tail = _split(url)
    try:
        if not netloc.isascii():  # a host name and a port (a user name is refused before, an IPv6 address is ASCII)
            host, colon, port = netloc.rpartition(":")
            if not colon or port and not port.isdigit():
                host, colon, port = netloc, "", ""
            netloc = host.encode("idna").decode("ascii") + colon + port
        tail = re.sub(r"[^\x00-\x7f]+", lambda m: urllib.parse.quote(m[0], safe="", errors="surrogateescape"), tail)
    except UnicodeError as exc:
        raise InputFormatError(f"{url}: not a valid URL ({exc})") from None
    return f"{start}{netloc}{tail}"


class _HttpOnlyRedirects(urllib.request.HTTPRedirectHandler):
    """Follow redirects to ``http(s)://`` URLs without a user name or password only (never ``file:`` or
    ``ftp:``; credentials from a server would go where the caller sent none); ``url``: the URL the caller named,
    which the refusal names first."""

    def __init__(self, url: str):
        self.url = url

    def redirect_request(self, req, fp, code, msg, headers, newurl):
        why = "not an http(s) URL" if not is_url(newurl) else \
            "a URL with a user name or password (not supported)" if "@" in _split(newurl)[1] else None
        if why:
            raise InputFormatError(f"{self.url}: redirected to {shown_url(newurl)}, {why}")
        return super().redirect_request(req, fp, code, msg, headers, newurl)


class UrlSource:
    """The bytes of the ``.pmw`` at ``url``, as blocks, fetched as they are iterated.

    ``max_chunks``: stop after the base mesh and this many chunks (stream order);
    ``whole_document``: and after the document's other data (:func:`plan_ranges`).
    After (or during) an iteration ``requests`` counts the HTTP requests made,
    ``bytes_fetched`` the body bytes received and ``ranged`` says whether the server
    honoured ``Range``; ``stopped`` whether it ended after the chunks asked for, leaving the
    rest of the file unfetched, and ``file_size`` the file's size as the server gave it
    (None: not said).  Each iteration fetches afresh.
    """

    def __init__(self, url: str, *, max_chunks: int | None = None, whole_document: bool = False,
                 timeout: float = DEFAULT_TIMEOUT, block_size: int = DEFAULT_BLOCK_SIZE):
        if not is_url(url):
            raise InputFormatError(f"{shown_url(str(url))}: not an http:// or https:// URL")
        if "@" in _split(url)[1]:  # before any other check, whose message would show it: never echoed, a password
            raise InputFormatError(f"{shown_url(url)}: a user name or password in the URL is not supported")
        try:
            urllib.parse.urlsplit(url).port  # noqa: B018 - a port out of range or not a number raises here
        except ValueError as exc:
            raise InputFormatError(f"{url}: not a valid URL ({exc})") from None
        self.url = url
        self._target = _request_url(url)
        netloc = _split(self._target)[1]  # the Host header without an IPv6 literal's zone, which is the client's
        self._host = re.sub(r"%[^\]]*\]", "]", netloc) if netloc.startswith("[") and "%" in netloc else None
        self.max_chunks = max_chunks
        self.whole_document = whole_document
        self.timeout = timeout
        self.block_size = block_size
        self.requests = 0
        self.bytes_fetched = 0
        self.ranged = None
        self.stopped = False
        self.file_size = None
        self._watch = _Watchdog()
        self._waited = 0.0
        self._opener = urllib.request.build_opener(_HttpOnlyRedirects(self.url), *self._watch.handlers())

    def __repr__(self):
        return f"UrlSource({self.url!r})"

    def __iter__(self):
        self.requests = self.bytes_fetched = 0
        self._waited = 0.0
        self._size = self._validators = self.file_size = None
        self.stopped = False
        response = self._open(0, PREAMBLE_SIZE, past_end_ok=True)
        with response:
            if response.status == 416:  # an empty file: a stream of no bytes (the reader says it is cut)
                self.ranged = True
                return
            self.ranged = response.status == 206
            self._check_encoding(response)
            if not self.ranged:
                yield from self._plain(response)
                return
            head = self._fetch(0, PREAMBLE_SIZE, response)
        yield head
        if len(head) < PREAMBLE_SIZE:
            return
        yield from self._ranges(head)

    # -- Range mode --------------------------------------------------------------

    def _ranges(self, preamble: bytes):
        """After the preamble: the JSON + BIN header, then the rest :func:`plan_ranges` plans, as it arrives, in blocks
        cut where the base and each chunk end (:func:`_cut`; a file longer than its GLB header declares is refused:
        :meth:`_check_length`)."""
        total, json_length = parse_preamble(preamble)
        self._check_length(total)
        header_end = PREAMBLE_SIZE + json_length + CHUNK_HEADER_SIZE
        rest = self._fetch(PREAMBLE_SIZE, header_end)
        yield rest
        if len(rest) < header_end - PREAMBLE_SIZE:
            return
        header = _header(preamble + rest)
        (stop,) = _plan(header, self.max_chunks, self.whole_document)
        at = header_end
        for block in _cut(self._blocks(at, stop), at, _part_ends(header)):
            at += len(block)
            yield block
        self.stopped = at == stop < total  # (fewer bytes: the server stopped, a cut stream)

    def _check_length(self, total: int) -> None:
        """FormatError when the file's size as the server gave it is more than ``total``, the length its GLB
        header declares: every reader refuses the bytes after it (a file on disk, standard input), and so does
        a read that stops before them (``max_chunks``)."""
        if self.file_size is not None and self.file_size > total:
            raise trailing_bytes(self.file_size, total)

    def _fetch(self, start: int, end: int, response=None) -> bytes:
        """Bytes ``[start, end)`` at once (:meth:`_blocks` joined)."""
        return b"".join(self._blocks(start, end, response))

    def _blocks(self, start: int, end: int, response=None):
        """Bytes ``[start, end)`` by Range requests (``response``: the first one's answer, already open), yielded
        block by block as they arrive (:meth:`_read`), so that a reader decodes each chunk as soon as its bytes
        are in; closing the generator closes the answer being read.

        A server may answer with fewer bytes than asked (RFC 9110 §14.4: it caps the size of its
        answers, say): the rest is asked for, until the range is complete.  Fewer bytes come (or
        none) only when the file ends first, or an answer's body ends before the bytes its
        ``Content-Range`` announced (a cut stream).
        """
        at = start
        while at < end:
            with response or self._open(at, end, past_end_ok=True) as answer:
                response = None
                if answer.status == 416:  # the served file ends before ``at``: a cut stream, unless it said it did not
                    self._check_unsatisfiable(answer, at)
                    return
                if answer.status != 206:
                    raise InputFormatError(f"{self.url}: the server answered a Range request with status "
                                           f"{answer.status} after honouring one")
                self._check_encoding(answer)
                last = self._answered(answer, at, end)
                while at < last:
                    block = self._read(answer, min(self.block_size, last - at))
                    if not block:
                        return  # the connection ended early: a cut stream
                    at += len(block)
                    yield block
            if self.file_size is not None and at >= self.file_size:
                return  # the file ends here

    def _check_encoding(self, response) -> None:
        """Refuse a ranged answer in a content coding (gzip ...): its byte ranges are not the file's.
        A plain answer's is undone as it is read (:meth:`_plain`)."""
        coding = _coding(response)
        if coding is not None and (response.status == 206 or coding not in _DECODERS):
            raise InputFormatError(f"{self.url}: the server sent the file {coding}-encoded (Content-Encoding) although "
                                   "asked for identity" + (" in a Range answer" if response.status == 206 else ""))

    def _answered(self, response, start: int, end: int) -> int:
        """The end of the bytes a 206 answer for ``[start, end)`` holds, ``[start, last)``, as its ``Content-Range``
        says: ``last <= end`` (the server may send fewer bytes than asked).

        The file's size, ``ETag`` and ``Last-Modified`` must stay the ones the first answer gave (a file
        replaced while it is read is refused, even by one of the same size).
        """
        given = response.headers.get("Content-Range", "")
        match = _CONTENT_RANGE.match(given)
        if match is None or int(match[1]) != start or not start <= int(match[2]) < end \
                or match[3] != "*" and int(match[2]) >= int(match[3]):
            raise InputFormatError(f"{self.url}: Content-Range {given!r} does not answer bytes {start}-{end - 1}")
        if self._size is None:
            self._size, self._validators = match[3], self._validators_of(response)
            self.file_size = int(match[3]) if match[3].isdigit() else None
        else:
            self._check_same_file(response, match[3])
        return int(match[2]) + 1

    @staticmethod
    def _validators_of(response) -> dict:
        return {name: response.headers.get(name) for name in ("ETag", "Last-Modified")}

    def _check_same_file(self, response, size: str | None) -> None:
        """InputFormatError when ``response`` (a later answer) shows another file than the first answer did:
        another size (``size``, from its ``Content-Range``; None: not said), ``ETag`` or ``Last-Modified``."""
        if size is not None and size != self._size:
            raise InputFormatError(f"{self.url}: the file changed while it was read (size {self._size}, now {size})")
        for name, now in self._validators_of(response).items():
            first = self._validators[name]
            if first is not None and now is not None and now != first:
                raise InputFormatError(f"{self.url}: the file changed while it was read ({name} {first}, now {now})")

    def _check_unsatisfiable(self, response, at: int) -> None:
        """A 416 for bytes from ``at`` on, after earlier answers: a cut stream when the file ends before ``at``
        (its size not known, or known and at most ``at``); when ``at`` is inside the size the server gave, the file
        shrank or was replaced (InputFormatError, never a cut stream)."""
        if self.file_size is None or at >= self.file_size:
            return
        match = re.match(r"bytes\s+\*/(\d{1,19})\s*$", response.headers.get("Content-Range") or "")
        self._check_same_file(response, match and match[1])
        raise InputFormatError(f"{self.url}: the file changed while it was read (the server has no bytes from "
                               f"{at:,} on, in a file of {self.file_size:,} bytes)")

    # -- plain mode ---------------------------------------------------------------

    def _plain(self, response):
        """The body of a plain GET, in blocks, up to the file length its GLB header declares, or to the end
        of chunk ``max_chunks``: nothing past it is read.  A body that goes on after that length (more bytes
        than the file holds, or a compressed body that decodes to more) is refused once the file's bytes
        are given."""
        if response.status != 200:
            raise InputFormatError(f"{self.url}: HTTP status {response.status}")
        coding = _coding(response)
        undo = None if coding is None else _DECODERS[coding]()
        length = response.headers.get("Content-Length", "")
        self.file_size = int(length) if coding is None and length.isdigit() and len(length) < 20 else None
        head, stop, offset, over = bytearray(), None, 0, False
        while stop is None or offset < stop:
            want = self.block_size if stop is None else min(self.block_size, stop - offset)
            block = self._read(response, want) if undo is None else self._undo(response, undo, want)
            if not block:
                return
            if stop is None:
                head += block
                stop = _plain_stop(head, self.max_chunks, self.whole_document)
                if stop is not None:
                    self._check_length(parse_preamble(head)[0])
                if stop is not None and offset + len(block) > stop:
                    block, over = block[: stop - offset], True
            offset += len(block)
            yield block
        total = parse_preamble(head)[0]
        self.stopped = stop < total
        if not self.stopped and (over or (self._read(response, 1) if undo is None else self._undo(response, undo, 1))):
            raise InputFormatError(f"{self.url}: the server sends more than the {total:,} bytes the file's GLB "
                                   "header declares")

    # -- HTTP ---------------------------------------------------------------------

    def _open(self, start: int, end: int, past_end_ok: bool = False):
        request = urllib.request.Request(self._target, headers={"Range": f"bytes={start}-{end - 1}",
                                                           "Accept-Encoding": "identity"})
        if self._host:  # (its own request's only: a redirect's is its target's)
            request.add_unredirected_header("Host", self._host)
        self.requests += 1
        self._watch.fd = None  # until this request connects
        try:
            with self._step():
                return self._opener.open(request, timeout=self.timeout)
        except urllib.error.HTTPError as exc:
            if past_end_ok and exc.code == 416:
                return exc  # a response object too (status 416, empty body)
            exc.close()
            raise InputFormatError(f"{self.url}: HTTP {exc.code} {exc.reason}") from None
        except (urllib.error.URLError, OSError) as exc:
            reason = getattr(exc, "reason", None) or exc
            raise InputFormatError(f"{self.url}: cannot read ({reason})") from None
        except http.client.InvalidURL as exc:  # a space or a control character in the URL
            raise InputFormatError(f"{self.url}: not a valid URL ({exc})") from None
        except http.client.HTTPException as exc:  # not an HTTP answer (BadStatusLine ...)
            raise InputFormatError(f"{self.url}: cannot read ({type(exc).__name__}: {exc})") from None

    def _undo(self, response, undo, size: int) -> bytes:
        """Up to ``size`` bytes of a body in a content coding, decoded (``b""`` at its end)."""
        while True:
            if undo.unconsumed_tail:
                data = undo.unconsumed_tail
            elif undo.eof:
                return b""
            else:
                data = self._read(response, self.block_size)
                if not data:
                    return undo.flush()
            try:
                block = undo.decompress(data, size)
            except zlib.error as exc:
                raise InputFormatError(f"{self.url}: the server's compressed answer does not decode ({exc})") from None
            if block:
                return block

    def _read(self, response, size: int) -> bytes:
        """Up to ``size`` bytes of the body as they come (``b""`` at its end), in one :meth:`_step`."""
        with self._step():
            try:
                block = response.read1(size)
            except (OSError, ValueError, http.client.HTTPException) as exc:  # reset, timeout, broken chunked encoding
                raise InputFormatError(f"{self.url}: cannot read ({exc})") from None
            self.bytes_fetched += len(block)
        return block

    @contextlib.contextmanager
    def _step(self):
        """One network step (a host name's lookup with the connection, a request up to its answer's head, or one
        read of a body: it ends as soon as any byte arrives), timed.

        The rule: one step takes at most ``timeout`` seconds (a server that sends nothing that long stalls, as the
        JavaScript reader's ``stallTimeout`` says), and all the steps of an iteration at most
        ``timeout + bytes_fetched / MIN_RATE`` seconds: past its first ``timeout`` seconds the transfer averages
        :data:`MIN_RATE`, over all its requests (a server that trickles every answer of a thousand ranges fails
        as one that trickles one answer).  Each byte received buys ``1 / MIN_RATE`` s, so a slow link that keeps
        bringing bytes is never cut off, while a server that holds the reader with a trickle is, within about
        ``timeout + size / MIN_RATE`` seconds, ``size`` the bytes it sends (not the size it declares, which is the
        server's to choose).  The time the reader spends between steps (decoding what arrived) is not counted.
        A step that outlives its share is cut off by :class:`_Watchdog` (a socket timeout bounds each wait for a
        byte, not a step: a status line or a body sent a byte every few seconds never trips it).
        """
        allowed = min(self.timeout, self._budget() - self._waited)
        if allowed <= 0:
            raise self._stalled()
        started = time.monotonic()
        self._watch.start(allowed)
        try:
            yield
        except BaseException as exc:
            cut = self._watch.stop()
            self._waited += time.monotonic() - started
            if cut and isinstance(exc, Exception):  # the error of a connection cut off: say why it was
                raise self._stalled() from None
            raise
        cut = self._watch.stop()
        self._waited += time.monotonic() - started
        if cut or self._waited > self._budget():
            raise self._stalled()

    def _budget(self) -> float:
        """The seconds of network time the transfer may have taken so far (:meth:`_step`)."""
        return self.timeout + self.bytes_fetched / MIN_RATE

    def _stalled(self) -> InputFormatError:
        """The error of a transfer that broke the rule of :meth:`_step`."""
        if self._waited > self._budget():
            why = (f"{self.bytes_fetched:,} bytes in {self._waited:.0f} s, under {MIN_RATE:,} bytes/s after the "
                   f"first {self.timeout:g} s")
        else:
            why = f"no answer or read done in {self.timeout:g} s"
        return InputFormatError(f"{self.url}: cannot read (the server stalls: {why})")


class _Watchdog:
    """Shuts down the connection of a network step that outlives its time (:meth:`UrlSource._step`), so the
    read blocked on it returns.  The HTTP handlers it makes note the socket of each connection as it is
    made (its file descriptor: a TLS socket wraps the same one) in ``fd``, and look its host name up within
    the step's time (:meth:`connection`)."""

    def __init__(self):
        self.fd = None
        self._lock = threading.Lock()
        self._step = 0  # which step is timed (a timer of an earlier one does nothing)
        self._cut = False
        self._timer = None
        self._deadline = None  # when the timed step's time is up (time.monotonic()); None: no step is timed

    def handlers(self) -> tuple:
        """An HTTP and an HTTPS handler for ``urllib.request.build_opener`` whose connections note their socket."""
        watch = self

        class Noted(http.client.HTTPConnection):
            def connect(self):
                self._create_connection = watch.connection
                super().connect()
                watch.fd = self.sock.fileno()

        class NotedTls(http.client.HTTPSConnection, Noted):  # Noted.connect runs before the TLS handshake
            pass

        class Http(urllib.request.HTTPHandler):
            def do_open(self, http_class, req, **kwargs):
                return super().do_open(Noted, req, **kwargs)

        class Https(urllib.request.HTTPSHandler):
            def do_open(self, http_class, req, **kwargs):
                return super().do_open(NotedTls, req, **kwargs)

        return Http(), Https()

    def connection(self, address: tuple, timeout, source_address=None) -> socket.socket:
        """``socket.create_connection(address, ...)`` with the host name looked up within the timed step's time.

        ``getaddrinfo`` cannot be cut off (a resolver that does not answer blocks it for as long as it likes,
        and there is no socket yet to shut down): it runs in a daemon thread, left to end on its own when the
        time is up, and the step fails then with an OSError naming the host.  The connection is made to the
        addresses it gave, in its order, each as it gave it: an IPv6 address with its flow info and scope id
        (a link-local address is no address without its zone, and a second lookup of the bare address, as
        ``create_connection`` makes, loses it).  An IPv6 literal's zone comes as the URL writes it, ``%25``
        (RFC 6874: ``[fe80::1%25eth0]``), and goes to ``getaddrinfo`` as ``%`` (``fe80::1%eth0``)."""
        host, port = address
        zone = ""
        if ":" in host and "%" in host:  # an IPv6 literal with a zone
            host = urllib.parse.unquote(host)
            zone = host.partition("%")[2]
        found = {}

        def look_up():
            try:
                found["addresses"] = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
            except OSError as exc:
                found["error"] = exc

        seconds = None if self._deadline is None else max(0.0, self._deadline - time.monotonic())
        lookup = threading.Thread(target=look_up, name=f"pmw-resolve-{host}", daemon=True)
        lookup.start()
        lookup.join(seconds)
        if lookup.is_alive():
            raise TimeoutError(f"the name lookup (DNS) of {host} gave no answer in {seconds:.1f} s")
        if "error" in found:
            if zone and not _is_interface(zone):
                raise OSError(f"no network interface {zone!r} on this machine (the zone of "
                              f"{host.partition('%')[0]})") from None
            raise found["error"]
        error = OSError(f"no address for the host name {host}")
        for family, kind, proto, _, sockaddr in found["addresses"]:
            sock = None
            try:
                sock = socket.socket(family, kind, proto)
                if timeout is not socket._GLOBAL_DEFAULT_TIMEOUT:  # (create_connection's default: leave it)
                    sock.settimeout(timeout)
                if source_address:
                    sock.bind(source_address)
                sock.connect(sockaddr)
                return sock
            except OSError as exc:
                error = exc
                if sock is not None:
                    sock.close()
                if family == socket.AF_INET6 and not sockaddr[3] and ipaddress.ip_address(sockaddr[0]).is_link_local:
                    error = OSError(f"{sockaddr[0]} is a link-local address: the URL names its network interface "
                                    f"after it, [{sockaddr[0]}%25eth0] ({exc.strerror or exc})")
        raise error

    def start(self, seconds: float) -> None:
        """Time a step: its connection is shut down in ``seconds`` unless :meth:`stop` comes first."""
        with self._lock:
            self._step += 1
            self._cut = False
            self._deadline = time.monotonic() + seconds
            self._timer = threading.Timer(seconds, self._fire, (self._step,))
        self._timer.daemon = True
        self._timer.start()

    def stop(self) -> bool:
        """End the step's timing; whether its connection was cut off."""
        with self._lock:
            self._step += 1
            self._deadline = None
            if self._timer is not None:
                self._timer.cancel()
                self._timer = None
            return self._cut

    def _fire(self, step: int) -> None:
        with self._lock:
            if step != self._step or self.fd is None:
                return
            self._cut = True
            try:
                sock = socket.socket(fileno=self.fd)
            except OSError:
                return
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
            finally:
                sock.detach()  # the descriptor stays the connection's, closed with it


def _is_interface(zone: str) -> bool:
    """Whether ``zone`` (an IPv6 address's zone: an interface's name or index) names a network interface here."""
    if zone.isdigit():
        return True  # an index: getaddrinfo takes any
    try:
        socket.if_nametoindex(zone)
    except (OSError, ValueError):
        return False
    return True


#: Content codings a plain answer may come in, undone as it is read (gzip with its header, deflate as zlib).
_DECODERS = {"gzip": lambda: zlib.decompressobj(16 + zlib.MAX_WBITS),
             "x-gzip": lambda: zlib.decompressobj(16 + zlib.MAX_WBITS),
             "deflate": lambda: zlib.decompressobj(zlib.MAX_WBITS)}


def _coding(response):
    """The answer's content coding (lower case), None for none or ``identity``."""
    coding = (response.headers.get("Content-Encoding") or "").strip().lower()
    return None if coding in ("", "identity") else coding


def _plain_stop(head, max_chunks: int | None, whole_document: bool = False):
    """Where a plain read stops (the file's declared length, or the end of chunk ``max_chunks``), once
    ``head`` (bytes-like) holds the preamble (with ``max_chunks``: the JSON and the BIN header); else None."""
    if len(head) < PREAMBLE_SIZE:
        return None
    total, json_length = parse_preamble(head)
    if max_chunks is None:
        return total
    if len(head) < PREAMBLE_SIZE + json_length + CHUNK_HEADER_SIZE:
        return None
    return plan_ranges(head[:total], max_chunks, whole_document)[-1]  # (bytes past the file: not the parser's)


def read_declared(source) -> bytes:
    """All bytes of the ``.pmw`` ``source`` (a URL, ``"-"``, any source :mod:`pmwm_codec.sources` takes),
    for a reader that needs them at once: of a stream, never more than its GLB header declares.

    A stream (a URL, standard input, a file object, an iterable) that goes on past that length is
    refused as soon as it does (FormatError: nothing past that block is read), and so is a declared
    length over the input limit (:data:`~pmwm_codec.constants.MAX_INPUT_FILE_BYTES`, LimitError); one
    that ends first gives the bytes it had (a cut file).  A path or bytes are read whole, as they are
    (what the file holds: the reader then names the bytes after its length).
    """
    source = resolve_stdin(as_source(source))
    if isinstance(source, (str, os.PathLike, bytes, bytearray, memoryview)):
        return read_all(source)
    parts, size, total = [], 0, None
    for block in iter_blocks(source, DEFAULT_BLOCK_SIZE):
        parts.append(bytes(block))
        size += len(block)
        if total is None and size >= PREAMBLE_SIZE:
            total = parse_preamble(b"".join(parts)[:PREAMBLE_SIZE])[0]
            if total > MAX_INPUT_FILE_BYTES:
                raise LimitError(f"GLB header: a file of {total:,} bytes, more than the limit of "
                                 f"{MAX_INPUT_FILE_BYTES:,} for a stream read whole")
        if total is not None and size > total:
            raise FormatError(f"GLB: more bytes after the declared file length {total} (a stream: not read further)")
    return b"".join(parts)


def plan_ranges(head: bytes, max_chunks: int | None = None, whole_document: bool = False) -> list:
    """The Range requests after the header, as their absolute end offsets: one, ``[stop]``.

    ``head``: at least the preamble, the JSON and the BIN chunk header, checked here by the container
    parser (structure, limits, chunk ranges).  The request goes from the end of the BIN chunk header to
    ``stop``: the base meshes (everything before the first chunk), then the chunks in stream order, up to
    the file length; with ``max_chunks`` up to the end of that chunk instead (gaps before a chunk go with
    it), unless ``whole_document`` asks for the document's other data too (images, plain meshes: every
    bufferView that holds no chunk) and some of it lies past that chunk: then up to the file length.

    One streamed request, not one per chunk: a chunk comes no later for being in a long answer (its bytes
    are handed on as they arrive), and every request more would cost a round trip (the JavaScript reader,
    js/src/three-plugin.js ``requestEnd``, plans the same requests).
    """
    return _plan(_header(head), max_chunks, whole_document)


def _header(head: bytes) -> HeaderEvent:
    """The header of ``head`` (at least the preamble, the JSON and the BIN chunk header), checked by the container
    parser (structure, limits, chunk ranges)."""
    parser = ContainerParser()
    header = next((e for e in parser.feed(head) if isinstance(e, HeaderEvent)), None)
    if header is None:  # pragma: no cover - the caller passes the whole header
        raise InputFormatError("the glTF JSON did not arrive whole")
    return header


def _chunk_ranges(header: HeaderEvent) -> list:
    """``[(start, end)]``: the absolute byte range of each chunk, in stream order."""
    views = header.gltf_json["bufferViews"]
    starts = sorted((header.bin_offset + chunk_start(views, c), int(c["byteLength"]))
                    for ext in header.extensions for c in ext["chunks"])
    return [(start, start + length) for start, length in starts]


def _plan(header: HeaderEvent, max_chunks: int | None, whole_document: bool) -> list:
    """:func:`plan_ranges` of a parsed header."""
    chunks = _chunk_ranges(header)
    if max_chunks is not None and max_chunks < len(chunks):
        stop = chunks[max_chunks - 1][1] if max_chunks else chunks[0][0]  # the end of that chunk, or of the base
        if not (whole_document and _data_end(header) > stop):
            return [stop]
    return [header.total_length]


def _part_ends(header: HeaderEvent) -> list:
    """The absolute offsets where the parts of the file after its header end, in order: the base (all before the first
    chunk), each chunk."""
    chunks = _chunk_ranges(header)
    return [start for start, _ in chunks[:1]] + [end for _, end in chunks]


def _cut(blocks, start: int, ends: list):
    """``blocks`` (the file's bytes from offset ``start`` on) cut at each offset of ``ends`` (sorted), as byte views, so
    that a block holds at most the end of one part of the file: a reader then decodes, and yields, each chunk as soon
    as its bytes are in, before the next chunk that came in the same block (a block of the network holds many small
    chunks)."""
    k = bisect.bisect_right(ends, start)
    for block in blocks:
        view = memoryview(block)  # (its parts: views, not copies)
        while view:
            while k < len(ends) and ends[k] <= start:
                k += 1
            size = len(view) if k == len(ends) else min(len(view), ends[k] - start)
            start += size
            yield view[:size]
            view = view[size:]


def _data_end(header) -> int:
    """Absolute end of the last bufferView of the BIN that holds no chunk (0: none)."""
    views = header.gltf_json["bufferViews"]
    chunk_views = {int(c["bufferView"]) for ext in header.extensions for c in ext["chunks"]}
    return max((header.bin_offset + int(v.get("byteOffset", 0)) + int(v["byteLength"])
                for i, v in enumerate(views) if i not in chunk_views and v.get("buffer") == 0), default=0)
