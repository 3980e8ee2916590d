"""Reading a ``.pmw`` over HTTP (``pmwm_codec.http``) and ``pmw serve``'s Range handler.

Every server here listens on 127.0.0.1 on a free port, runs in a thread and is shut
down by its fixture; one honours ``Range``, one ignores it (plain 200 answers).
"""

from __future__ import annotations

import contextlib
import io
import json
import re
import threading
from pathlib import Path
import urllib.request
from http.server import SimpleHTTPRequestHandler

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.cli.serve import RangeRequestHandler, make_server, parse_range
from pmwm_codec.errors import FormatError, InputFormatError, PmwError
from pmwm_codec.format.inspect import inspect
from pmwm_codec.http import UrlSource, is_url

from conftest import refusing_port


class IgnoringRange(RangeRequestHandler):
    """A server that answers every GET with the whole file (200), as if Range did not exist."""

    def send_head(self):
        self._span = None
        return SimpleHTTPRequestHandler.send_head(self)

    def end_headers(self):
        SimpleHTTPRequestHandler.end_headers(self)


class Capping(RangeRequestHandler):
    """A server that answers a Range request with at most ``cap`` bytes; its ``Content-Range`` says which, and the
    file's whole size (RFC 9110 lets a server send fewer bytes than asked)."""

    cap = 300

    def send_head(self):
        match = re.match(r"bytes=(\d+)-(\d+)$", self.headers.get("Range", ""))
        if match:
            del self.headers["Range"]
            self.headers["Range"] = f"bytes={match[1]}-{min(int(match[2]), int(match[1]) + self.cap - 1)}"
        return super().send_head()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """A directory with ``x.pmw`` (icosphere(3), watermarked, several chunks) and its key file."""
    d = tmp_path_factory.mktemp("site")
    image = np.random.default_rng(3).integers(0, 256, (16, 16)).astype(np.uint8)
    pmwm_codec.encode(shapes.icosphere(3), d / "x.pmw", watermark=image)
    return d


def _serve(directory, handler):
    server = make_server(directory, "127.0.0.1", 0, handler)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    return server, thread


@contextlib.contextmanager
def _served(directory, handler):
    """``directory`` served by ``handler`` on a free port of the loopback: yields the URL of its ``x.pmw``."""
    srv, thread = _serve(directory, handler)
    try:
        yield f"http://127.0.0.1:{srv.server_address[1]}/x.pmw"
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def _decode_stalls(url: str, match: str, timeout: float = 1) -> UrlSource:
    """``pmwm_codec.decode`` of ``url`` (with ``timeout``) is the stall error ``match``: the source.  (No bound on the
    time it takes: each server here ends its answer, or is stopped, long after the reader's rule cuts it off, with
    another outcome than a stall; a bound of a few seconds failed on a loaded machine.)"""
    source = UrlSource(url, timeout=timeout)
    with pytest.raises(InputFormatError, match=match):
        pmwm_codec.decode(source)
    return source


@pytest.fixture(params=["ranges", "no-ranges"])
def server(request, site):
    """A running server over ``site`` (both kinds); stopped after the test."""
    handler = RangeRequestHandler if request.param == "ranges" else IgnoringRange
    srv, thread = _serve(site, handler)
    srv.ranges = request.param == "ranges"
    srv.url = f"http://127.0.0.1:{srv.server_address[1]}/"
    yield srv
    srv.shutdown()
    srv.server_close()
    thread.join(5)


def _pmw(capsys, *argv):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_is_url_accepts_only_http_and_https():
    assert is_url("http://127.0.0.1/x.pmw") and is_url("HTTPS://example.org/x.pmw")
    for other in ("file:///etc/passwd", "ftp://h/x.pmw", "x.pmw", "/tmp/http://x", b"http://x", None):
        assert not is_url(other)
    with pytest.raises(InputFormatError):
        UrlSource("file:///etc/passwd")


@pytest.mark.parametrize("header,expected", [
    ("bytes=0-19", (0, 20)), ("bytes=10-", (10, 100)), ("bytes=-30", (70, 100)), ("bytes=90-500", (90, 100)),
    ("bytes=100-", (100, 100)), ("bytes=5-2", None), ("bytes=0-1,5-6", None), ("items=0-1", None), (None, None),
    # thousands of digits: int() raised (a traceback on the server, the connection dropped without an answer)
    ("bytes=" + "9" * 5000 + "-", (100, 100)), ("bytes=0-" + "9" * 5000, (0, 100)), ("bytes=-" + "9" * 5000, (0, 100)),
    ("bytes=" + "9" * 5000 + "-1", None),
])
def test_parse_range_reads_single_byte_ranges(header, expected):
    assert parse_range(header, 100) == expected


def test_verify_url_gives_the_local_verdict_and_json(server, site, capsys):
    key = site / "x.pmw.key.json"
    code_file, out_file, _ = _pmw(capsys, "verify", site / "x.pmw", "--key", key, "--json")
    code_url, out_url, err = _pmw(capsys, "verify", server.url + "x.pmw", "--key", key, "--json")
    assert code_url == code_file == 0, err
    assert json.loads(out_url) == json.loads(out_file)
    assert json.loads(out_url)["verdict"] == "authentic"


def test_iter_decode_url_matches_the_file_at_every_boundary(server, site):
    local = list(pmwm_codec.iter_decode(site / "x.pmw"))
    remote = list(pmwm_codec.iter_decode(server.url + "x.pmw"))
    assert [r.bytes_read for r in remote] == [r.bytes_read for r in local]
    for a, b in zip(local, remote):
        assert np.array_equal(a.positions_int, b.positions_int) and np.array_equal(a.faces, b.faces)


def test_decode_url_with_chunks_fetches_only_the_bytes_it_needs_by_ranges(server, site):
    info = inspect(site / "x.pmw")
    assert info["chunks_total"] >= 3
    size = (site / "x.pmw").stat().st_size
    for n in (0, 2):
        server.bytes_sent = 0
        source = UrlSource(server.url + "x.pmw", max_chunks=n)
        mesh = pmwm_codec.decode(source, chunks=n)
        local = pmwm_codec.decode(site / "x.pmw", chunks=n)
        assert np.array_equal(mesh.faces, local.faces) and np.allclose(mesh.positions, local.positions)
        if server.ranges:
            # exactly the prefix up to the end of chunk n: nothing after it was sent
            assert server.bytes_sent == source.bytes_fetched == _prefix_end(site / "x.pmw", n) < size
            assert source.ranged and source.requests == 3  # the preamble, the JSON, then the rest up to chunk n
        else:
            assert not source.ranged and source.requests == 1
            assert source.bytes_fetched >= _prefix_end(site / "x.pmw", n)


@pytest.fixture(scope="module")
def many(tmp_path_factory):
    """A directory with ``x.pmw``: 12 primitives, 68 chunks (as js/test/lib/levels.py's ``many-primitives.plain``)."""
    from pmwm_codec.stream.encoder import PrimitiveJob, encode_document

    d = tmp_path_factory.mktemp("many")
    meshes = [shapes.torus(24, 12, twist=0.1 * k) for k in range(12)]
    doc = {"scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{} for _ in meshes]}]}
    jobs = [PrimitiveJob(m, 0, i) for i, m in enumerate(meshes)]
    encode_document(doc, b"", jobs, d / "x.pmw", base_codec="plain", min_chunk_splits=30, measure="none")
    return d


def test_a_file_of_many_chunks_is_read_in_three_range_requests(many):
    """The preamble, the JSON with the BIN header, then everything wanted after them in one answer: three requests
    whatever the number of chunks (there was one per chunk: 70 for these 68, each a round trip)."""
    path = many / "x.pmw"
    assert inspect(path)["chunks_total"] >= 60
    with _served(many, RangeRequestHandler) as url:
        for n in (None, 0, 10):
            source = UrlSource(url, max_chunks=n)
            assert pmwm_codec.decode(source, chunks=n) == pmwm_codec.decode(path, chunks=n)
            assert source.requests == 3
            assert source.bytes_fetched == (path.stat().st_size if n is None else _prefix_end(path, n))


class Holding(RangeRequestHandler):
    """A Range server that sends the bytes of an answer before the file offset ``server.hold``, then waits until
    ``server.release`` is set (10 s at most) to send the rest; ``server.held`` says whether an answer waited."""

    def copyfile(self, source, outputfile):
        body = source.read(self._length)
        cut = min(max(self.server.hold - (source.tell() - len(body)), 0), len(body))
        if cut < len(body):  # said before the bytes go: the reader may decode level k before this thread runs on
            self.server.held = True
        outputfile.write(body[:cut])
        outputfile.flush()
        if cut < len(body):
            self.server.release.wait(10)
        outputfile.write(body[cut:])


def test_each_chunk_reaches_the_reader_as_its_bytes_arrive_not_when_its_answer_ends(many):
    """All the chunks come in one answer, which is handed to the decoder as it arrives: level k is decoded while the
    server still holds the bytes after chunk k back (a reader that waited for the whole answer would wait 10 s)."""
    k = 5
    path = many / "x.pmw"
    srv, thread = _serve(many, Holding)
    srv.hold, srv.release, srv.held = _prefix_end(path, k), threading.Event(), False
    try:
        source = UrlSource(f"http://127.0.0.1:{srv.server_address[1]}/x.pmw")
        chunks = []
        for result in pmwm_codec.iter_decode(source):
            chunks.append(result.chunk)
            if result.chunk == k:
                assert srv.held and not srv.release.is_set(), "level k came only after its answer ended"
                srv.release.set()
        assert chunks == list(range(inspect(path)["chunks_total"] + 1))
        assert source.requests == 3
    finally:
        srv.release.set()
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def test_decode_url_string_reads_the_whole_stream(server, site):
    mesh = pmwm_codec.decode(server.url + "x.pmw")
    local = pmwm_codec.decode(site / "x.pmw")
    assert np.array_equal(mesh.faces, local.faces)
    assert server.bytes_sent == (site / "x.pmw").stat().st_size


def test_a_cut_file_over_http_reads_like_the_cut_file(server, site, capsys):
    data = (site / "x.pmw").read_bytes()
    (site / "cut.pmw").write_bytes(data[: len(data) * 2 // 3])
    key = site / "x.pmw.key.json"
    _, out_file, _ = _pmw(capsys, "verify", site / "cut.pmw", "--key", key, "--json")
    code, out_url, err = _pmw(capsys, "verify", server.url + "cut.pmw", "--key", key, "--json")
    assert json.loads(out_url) == json.loads(out_file), err
    assert json.loads(out_url)["truncated"] is True


def test_verify_url_errors_are_one_line_exit_2(server, site, capsys):
    key = site / "x.pmw.key.json"
    code, out, err = _pmw(capsys, "verify", server.url + "missing.pmw", "--key", key)
    assert code == 2 and err.startswith("pmw: error: ") and "404" in err and len(err.splitlines()) == 1
    with refusing_port() as port:  # connection refused
        code, out, err = _pmw(capsys, "verify", f"http://127.0.0.1:{port}/x.pmw", "--key", key)
    assert code == 2 and "cannot read" in err and "Connection refused" in err and len(err.splitlines()) == 1, err


def test_range_server_answers_206_with_content_range(site):
    srv, thread = _serve(site, RangeRequestHandler)
    try:
        url = f"http://127.0.0.1:{srv.server_address[1]}/x.pmw"
        size = (site / "x.pmw").stat().st_size
        with urllib.request.urlopen(urllib.request.Request(url, headers={"Range": "bytes=4-11"}), timeout=10) as r:
            assert r.status == 206 and r.headers["Content-Range"] == f"bytes 4-11/{size}"
            assert r.read() == (site / "x.pmw").read_bytes()[4:12]
        with pytest.raises(urllib.error.HTTPError) as info:
            urllib.request.urlopen(urllib.request.Request(url, headers={"Range": f"bytes={size}-"}), timeout=10)
        assert info.value.code == 416
        info.value.close()
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


class NoDelayNoted(RangeRequestHandler):
    """Notes whether each connection it answers has TCP_NODELAY set."""

    seen: list = []

    def handle(self):
        import socket

        self.seen.append(self.connection.getsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY) != 0)
        super().handle()


def test_serve_sends_its_answers_without_waiting_for_the_clients_acknowledgement(site):
    """TCP_NODELAY on every connection: with Nagle's rule the second answer on a kept-alive connection waited for the
    client's delayed acknowledgement of the first (Node's fetch and Chromium: ~22 ms a request against pmw serve)."""
    import http.client

    NoDelayNoted.seen = []
    srv, thread = _serve(site, NoDelayNoted)
    try:
        conn = http.client.HTTPConnection("127.0.0.1", srv.server_address[1], timeout=10)
        for start in (0, 20):  # two answers on one kept-alive connection
            conn.request("GET", "/x.pmw", headers={"Range": f"bytes={start}-{start + 9}"})
            answer = conn.getresponse()
            assert answer.status == 206 and len(answer.read()) == 10
        conn.close()
        assert NoDelayNoted.seen == [True]
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def test_serve_answers_only_for_files_inside_its_directory_and_never_with_a_key(tmp_path):
    """A symbolic link out of the directory, a key file (``pmw encode`` writes the secret key beside the
    ``.pmw``), a FIFO, a directory listing and a NUL byte all get 404, with or without ``Range``; a link that stays
    inside is served."""
    import os

    site, outside = tmp_path / "site", tmp_path / "outside"
    site.mkdir()
    outside.mkdir()
    (outside / "secret.txt").write_text("not yours")
    (site / "a.txt").write_text("ok")
    (site / "a.pmw.key.json").write_text('{"secret": "00"}')
    (site / "sub").mkdir()
    os.symlink(outside / "secret.txt", site / "out.txt")
    os.symlink(outside, site / "outdir")
    os.symlink(site / "a.txt", site / "in.txt")
    os.symlink(site / "a.pmw.key.json", site / "key-link.txt")
    os.mkfifo(site / "pipe.pmw")  # opening it blocked the answer (and a server thread) forever
    image = np.random.default_rng(0).integers(0, 256, (8, 8)).astype(np.uint8)
    # a key under another name (pmw encode --key site/sub/k.json) and a key name in other case were served
    pmwm_codec.encode(shapes.icosphere(3), tmp_path / "b.pmw", watermark=image, key=site / "sub" / "k.json",
                      measure="none")
    (site / "c.pmw.Key.Json").write_text('{"secret": "00"}')
    srv, thread = _serve(site, RangeRequestHandler)
    base = f"http://127.0.0.1:{srv.server_address[1]}/"

    def get(path, ranged):
        headers = {"Range": "bytes=0-1"} if ranged else {}
        try:
            with urllib.request.urlopen(urllib.request.Request(base + path, headers=headers), timeout=10) as r:
                return r.status, r.read()
        except urllib.error.HTTPError as exc:
            exc.close()
            return exc.code, b""

    try:
        for ranged in (False, True):
            assert get("a.txt", ranged)[1] == b"ok"  # bytes 0-1 are the whole file
            assert get("in.txt", ranged)[0] in (200, 206)
            for refused in ("out.txt", "outdir/secret.txt", "a.pmw.key.json", "key-link.txt", "", "sub/",
                            "sub/k.json", "c.pmw.Key.Json", "pipe.pmw",
                            "a.txt%00.pmw", "..%2Foutside%2Fsecret.txt"):
                status, body = get(refused, ranged)
                assert status == 404 and b"not yours" not in body and b"secret" not in body, refused
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


class Planting(RangeRequestHandler):
    """A handler that calls ``server.plant(False)`` before it translates (and, before the fix, checked) the path
    asked for and ``server.plant(True)`` after: what stands there is swapped between the check and the open, every
    time, as a process racing the server would do at the worst moment."""

    def translate_path(self, path):
        self.server.plant(False)
        local = super().translate_path(path)
        self.server.plant(True)
        return local


def test_serve_checks_the_file_it_opened_not_the_path_it_checked(tmp_path):
    """``pmw serve`` checked a path (its real location inside the directory, not a key, a regular file), then opened
    it by name: a name swapped meanwhile for a link out of the directory (or a folder on the way for one), for a key
    file or for a FIFO was served (the FIFO held the answer forever).  The file is now opened one component at a
    time without following links, and the checks are made on what was opened: 404 for each, nothing of it sent."""
    import os
    import shutil

    from pmwm_codec.watermark.key import WatermarkKey

    site, outside = tmp_path / "site", tmp_path / "outside"
    site.mkdir()
    outside.mkdir()
    (outside / "secret.txt").write_text("not yours")
    key = WatermarkKey.generate(rng=np.random.default_rng(9))

    def swap(path, good, planted):
        """``plant(bad)``: ``planted(path)`` where ``path`` stands when ``bad``, else ``good(path)``."""

        def plant(bad):
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path)
            elif os.path.lexists(path):
                path.unlink()
            (planted if bad else good)(path)

        return plant

    def ok(path):
        path.write_text("ok")

    cases = {  # what is asked for: what stands there at the check, and at the open
        "a.txt": swap(site / "a.txt", ok, lambda path: path.symlink_to(outside / "secret.txt")),
        "sub/secret.txt": swap(site / "sub", lambda path: path.mkdir(), lambda path: path.symlink_to(outside)),
        "k.txt": swap(site / "k.txt", ok, lambda path: path.write_bytes(key.to_text())),
        "p.txt": swap(site / "p.txt", ok, lambda path: os.mkfifo(path)),
    }
    srv, thread = _serve(site, Planting)
    base = f"http://127.0.0.1:{srv.server_address[1]}/"
    try:
        for asked, plant in cases.items():
            srv.plant = plant
            for headers in ({}, {"Range": "bytes=0-"}):
                status, _, body = _get(base + asked, headers)
                assert status == 404 and b"not yours" not in body and key.secret_hex.encode() not in body, asked
        cases["a.txt"](False)
        srv.plant = lambda bad: None  # nothing swapped: "ok" is served
        assert _get(base + "a.txt")[2] == b"ok"
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def _prefix_end(path, n: int) -> int:
    """Bytes of ``path`` up to the end of chunk ``n`` (0: the end of the data before the first chunk)."""
    from pmwm_codec.http import plan_ranges

    return plan_ranges(path.read_bytes(), n)[-1]


def test_pmw_serve_refuses_a_missing_directory(tmp_path, capsys):
    code, _, err = _pmw(capsys, "serve", tmp_path / "nope")
    assert code == 2 and err.startswith("pmw: error: ") and len(err.splitlines()) == 1


def test_pmw_serve_serves_ranges_until_stopped(site):
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "pmwm_codec", "serve", str(site), "--port", "0"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            cwd=Path(__file__).resolve().parents[1])
    try:
        line = proc.stdout.readline()
        assert line.startswith("serving ") and "http://127.0.0.1:" in line
        url = line.split(" at ")[1].split()[0] + "x.pmw"
        source = UrlSource(url, max_chunks=1)
        assert pmwm_codec.decode(source, chunks=1).faces.shape[0] > 0 and source.ranged
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stdout.close()


def test_pmw_info_and_decode_take_a_url_as_verify_does(server, site, tmp_path, capsys):
    """``pmw info URL`` (the header only) and ``pmw decode URL`` (by ranges: nothing after chunk N) give what
    they give for the file."""
    size = (site / "x.pmw").stat().st_size
    code, out_url, err = _pmw(capsys, "info", server.url + "x.pmw", "--json")
    assert code == 0, err
    code, out_file, _ = _pmw(capsys, "info", site / "x.pmw", "--json")
    remote, local = json.loads(out_url), json.loads(out_file)
    assert remote["file"] == server.url + "x.pmw" and remote["bytes"] is None  # the size is not fetched
    assert {k: v for k, v in remote.items() if k not in ("file", "bytes", "complete", "truncated", "chunks_present",
                                                         "chunks")} == \
        {k: v for k, v in local.items() if k not in ("file", "bytes", "complete", "truncated", "chunks_present", "chunks")}
    for suffix, n in ((".obj", 2), (".glb", 1), (".ply", None)):
        server.bytes_sent = 0
        extra = [] if n is None else ["--chunks", str(n)]
        out, ref = tmp_path / f"remote{suffix}", tmp_path / f"local{suffix}"
        code, _, err = _pmw(capsys, "decode", server.url + "x.pmw", "-o", out, *extra, "--json")
        assert code == 0, err
        _pmw(capsys, "decode", site / "x.pmw", "-o", ref, *extra)
        assert out.read_bytes() == ref.read_bytes()
        if server.ranges and suffix == ".obj":
            assert server.bytes_sent == _prefix_end(site / "x.pmw", n) < size
    code, _, err = _pmw(capsys, "decode", server.url + "missing.pmw", "-o", tmp_path / "m.obj")
    assert code == 2 and "404" in err and len(err.splitlines()) == 1 and not (tmp_path / "m.obj").exists()


def test_pmw_cut_takes_a_url_and_fetches_only_the_chunks_it_keeps(server, site, tmp_path, capsys):
    """``pmw cut URL --chunks N`` gives the bytes ``pmw cut FILE --chunks N`` gives, and by ranges fetches
    nothing after chunk N (this file's data all lies before its chunks); a missing URL is one line, exit 2."""
    size = (site / "x.pmw").stat().st_size
    for n in (0, 2, None):
        server.bytes_sent = 0
        extra = [] if n is None else ["--chunks", str(n)]
        remote, local = tmp_path / f"remote{n}.pmw", tmp_path / f"local{n}.pmw"
        code, out, err = _pmw(capsys, "cut", server.url + "x.pmw", "-o", remote, *extra, "--json")
        assert code == 0, err
        assert _pmw(capsys, "cut", site / "x.pmw", "-o", local, *extra)[0] == 0
        assert remote.read_bytes() == local.read_bytes()
        if server.ranges and n is not None:  # (a plain answer's first block may hold the whole small file)
            assert server.bytes_sent == _prefix_end(site / "x.pmw", n) < size
            assert json.loads(out)["input_complete"] is False
    code, _, err = _pmw(capsys, "cut", server.url + "missing.pmw", "-o", tmp_path / "m.pmw")
    assert code == 2 and "404" in err and len(err.splitlines()) == 1 and not (tmp_path / "m.pmw").exists()


def test_a_url_cut_fetches_the_document_data_another_writer_put_after_the_chunks(site, tmp_path, capsys):
    """A bufferView that holds no chunk (an image, say) stored after the chunks: by ranges, ``whole_document``
    goes on to the end of the file, so the cut keeps it; the other readers still stop after chunk N."""
    import struct

    from pmwm_codec.format.glb import glb_parts
    from pmwm_codec.format.reader import read_header

    data = (site / "x.pmw").read_bytes()
    header = read_header(data)
    gltf = json.loads(json.dumps(header.gltf_json))
    bin_data = data[header.bin_offset:]
    extra = bytes(range(16))
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(bin_data), "byteLength": len(extra)})
    gltf["buffers"][0]["byteLength"] = len(bin_data) + len(extra)
    gltf.setdefault("extras", {})["tail"] = len(gltf["bufferViews"]) - 1  # unreferenced: kept as stored
    late = tmp_path / "late"
    late.mkdir()
    (late / "y.pmw").write_bytes(b"".join(glb_parts(gltf, [bin_data, extra], len(bin_data) + len(extra))))
    assert struct.unpack_from("<I", (late / "y.pmw").read_bytes(), 8)[0] == (late / "y.pmw").stat().st_size
    srv, thread = _serve(late, RangeRequestHandler)
    try:
        url = f"http://127.0.0.1:{srv.server_address[1]}/y.pmw"
        code, _, err = _pmw(capsys, "cut", url, "-o", tmp_path / "r.pmw", "--chunks", "1")
        assert code == 0, err
        assert _pmw(capsys, "cut", late / "y.pmw", "-o", tmp_path / "l.pmw", "--chunks", "1")[0] == 0
        cut = (tmp_path / "r.pmw").read_bytes()
        assert cut == (tmp_path / "l.pmw").read_bytes() and cut.endswith(extra)
        srv.bytes_sent = 0
        pmwm_codec.decode(UrlSource(url, max_chunks=1), chunks=1)
        assert srv.bytes_sent == _prefix_end(late / "y.pmw", 1)
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


class Gzipping(IgnoringRange):
    """A server that ignores ``Range`` and gzips every answer (``Content-Encoding: gzip``) although asked for
    identity."""

    def send_head(self):
        import gzip
        import io

        self._span = None
        path = self.translate_path(self.path)
        body = gzip.compress(Path(path).read_bytes())
        self.send_response(200)
        self.send_header("Content-Encoding", "gzip")
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        return io.BytesIO(body)


class GzipRanges(RangeRequestHandler):
    """A server whose Range answers say ``Content-Encoding: gzip``: ranges of the encoded bytes."""

    def send_header(self, keyword, value):
        super().send_header(keyword, value)
        if keyword == "Content-Range":
            super().send_header("Content-Encoding", "gzip")


def test_a_gzipped_plain_answer_is_decoded_and_a_gzipped_range_answer_refused(site, tmp_path):
    """Both ended as ``GLB header: bad magic b'\\x1f\\x8b...'``, which does not say what the server did."""
    want = pmwm_codec.decode(site / "x.pmw", chunks=2)
    for handler in (Gzipping, GzipRanges):
        srv, thread = _serve(site, handler)
        url = f"http://127.0.0.1:{srv.server_address[1]}/x.pmw"
        try:
            if handler is Gzipping:
                assert pmwm_codec.decode(url, chunks=2) == want and pmwm_codec.decode(url) == pmwm_codec.decode(site / "x.pmw")
            else:
                with pytest.raises(InputFormatError, match="gzip-encoded.*in a Range answer"):
                    pmwm_codec.decode(url)
        finally:
            srv.shutdown()
            srv.server_close()
            thread.join(5)


def _replaced_after(requests: int, path: str, handler=RangeRequestHandler):
    """A Range ``handler`` that serves the file asked for ``requests`` times, then the one at ``path`` in its place
    (the server counts its requests in ``requests``)."""

    class Replaced(handler):
        def translate_path(self, asked):
            self.server.requests = getattr(self.server, "requests", 0) + 1
            return super().translate_path(asked if self.server.requests <= requests else path)

    return Replaced


def test_a_file_replaced_by_one_of_the_same_size_between_range_requests_is_refused(tmp_path):
    """Only the size was compared: a file replaced by another of the same size (here two base vertices swapped,
    which no digest covered when this was found; ``baseDigest`` does now) decoded to a mesh neither file holds,
    silently.  ``pmw serve`` now sends ``ETag``
    and ``Last-Modified`` with its Range answers and the reader compares them."""
    import os

    from pmwm_codec.format.reader import read_header

    site = tmp_path / "site"
    site.mkdir()
    pmwm_codec.encode(shapes.icosphere(3), site / "a.pmw", base_codec="plain", measure="none")
    data = bytearray((site / "a.pmw").read_bytes())
    header = read_header(bytes(data))
    views = header.gltf_json["bufferViews"]
    position = header.gltf_json["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    start = header.bin_offset + views[header.gltf_json["accessors"][position]["bufferView"]].get("byteOffset", 0)
    data[start : start + 24] = data[start + 12 : start + 24] + data[start : start + 12]  # two base vertices swapped
    (site / "b.pmw").write_bytes(bytes(data))
    os.utime(site / "b.pmw", ns=(1, 1))

    srv, thread = _serve(site, _replaced_after(2, "/b.pmw"))  # after the preamble and the JSON
    try:
        with pytest.raises(InputFormatError, match="the file changed while it was read"):
            pmwm_codec.decode(f"http://127.0.0.1:{srv.server_address[1]}/a.pmw", chunks=0)  # the base only
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


class Unversioned(RangeRequestHandler):
    """A Range server that sends neither ``ETag`` nor ``Last-Modified`` (nothing obliges a server to): only the size in
    its ``Content-Range`` tells a reader that the file changed."""

    def send_header(self, keyword, value):
        if keyword.lower() not in ("etag", "last-modified"):
            super().send_header(keyword, value)


@pytest.mark.parametrize("handler", [Unversioned, RangeRequestHandler])
def test_a_file_replaced_by_one_of_the_same_size_is_refused_with_or_without_validators(tmp_path, capsys, handler):
    """``pmw decode URL`` and ``pmw verify URL`` of a file replaced, between two Range requests, by another of the same
    size: its base (two vertices swapped) after the JSON, or its chunk 2 (a byte changed) after the JSON or, by a
    server that answers with 2,000 bytes at most, after chunk 1.  A server without ``ETag`` and ``Last-Modified``
    cannot say so, but the bytes of the other file fail the digests of the first one's index (``baseDigest``, each
    chunk's): exit 2, one line, nothing written, never a mix of the two files read as one.  With validators the
    change is named as such."""
    import os

    from pmwm_codec.format.reader import read_header
    from pmwm_codec.http import plan_ranges

    site = tmp_path / "site"
    site.mkdir()
    image = np.random.default_rng(3).integers(0, 256, (16, 16)).astype(np.uint8)
    pmwm_codec.encode(shapes.icosphere(3), site / "a.pmw", watermark=image, base_codec="plain", measure="none")
    data = (site / "a.pmw").read_bytes()
    header = read_header(data)
    position = header.gltf_json["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
    view = header.gltf_json["bufferViews"][header.gltf_json["accessors"][position]["bufferView"]]
    start = header.bin_offset + view.get("byteOffset", 0)
    swapped = data[:start] + data[start + 12 : start + 24] + data[start : start + 12] + data[start + 24 :]
    chunk_1_end, chunk_2_end = plan_ranges(data, 1)[0], plan_ranges(data, 2)[0]
    (site / "base.pmw").write_bytes(swapped)
    (site / "chunk.pmw").write_bytes(data[: chunk_2_end - 1] + bytes([data[chunk_2_end - 1] ^ 0xFF]) + data[chunk_2_end:])
    for name in ("base.pmw", "chunk.pmw"):
        os.utime(site / name, ns=(1, 1))  # another ETag and Last-Modified than a.pmw's, where they are sent
    key = site / "a.pmw.key.json"
    capped = type("Capped", (Capping, handler), {"cap": 2000})
    after_chunk_1 = 2 + -(-(chunk_1_end - header.bin_offset) // 2000)  # the preamble, the JSON, the answers to chunk 1
    assert header.bin_offset + 2000 * (after_chunk_1 - 2) < chunk_2_end  # the next answer holds chunk 2's last byte
    # after the preamble and the JSON: the base, or chunk 2; by short answers, after chunk 1: chunk 2
    for other, requests, serving, refusal in (("base.pmw", 2, handler, "base mesh: baseDigest mismatch"),
                                              ("chunk.pmw", 2, handler, "chunk 2: digest mismatch"),
                                              ("chunk.pmw", after_chunk_1, capped, "chunk 2: digest mismatch")):
        for command, argv in (("decode", ["-o", tmp_path / "a.obj"]), ("verify", ["--key", key, "--json"])):
            srv, thread = _serve(site, _replaced_after(requests, "/" + other, serving))
            try:
                code, out, err = _pmw(capsys, command, f"http://127.0.0.1:{srv.server_address[1]}/a.pmw", *argv)
            finally:
                srv.shutdown()
                srv.server_close()
                thread.join(5)
            if handler is RangeRequestHandler:
                refusal = "the file changed while it was read"
            assert code == 2 and refusal in err and len(err.splitlines()) == 1 and out == "", (other, command, err)
            assert not (tmp_path / "a.obj").exists()


def test_a_file_replaced_by_a_shorter_one_between_range_requests_is_refused_not_read_as_cut(site, tmp_path, capsys):
    """After the base and chunk 1 (the answer of a server that cut it there), ``x.pmw`` is replaced by a file that ends
    there: ``pmw serve`` answers the request for the rest with 416 (and the new size and ETag).  The reader took that
    416 for the end of a cut download and verified the prefix ``authentic``, exit 0, although the server had said the
    file holds those bytes."""
    import os
    import shutil

    from pmwm_codec.format.reader import read_header

    served = tmp_path / "site"
    served.mkdir()
    shutil.copy(site / "x.pmw", served / "x.pmw")
    chunk_1_end = _prefix_end(site / "x.pmw", 1)
    (served / "short.pmw").write_bytes((site / "x.pmw").read_bytes()[:chunk_1_end])
    os.utime(served / "short.pmw", ns=(1, 1))
    capped = type("Capped", (Capping,), {"cap": chunk_1_end - read_header((site / "x.pmw").read_bytes()).bin_offset})

    srv, thread = _serve(served, _replaced_after(3, "/short.pmw", capped))  # the preamble, the JSON, up to chunk 1
    try:
        code, out, err = _pmw(capsys, "verify", f"http://127.0.0.1:{srv.server_address[1]}/x.pmw",
                              "--key", site / "x.pmw.key.json")
        assert srv.requests == 4
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)
    assert code == 2 and err.startswith("pmw: error: ") and len(err.splitlines()) == 1, (code, err)
    assert "the file changed while it was read" in err and "verdict" not in out


@pytest.mark.parametrize("handler", [RangeRequestHandler, IgnoringRange])
def test_a_file_longer_than_its_glb_header_declares_is_refused_over_http_as_on_disk(site, tmp_path, capsys, handler):
    """A file with bytes after its declared GLB length is refused on disk and on standard input, whole or up to
    chunk 2; served by ranges it verified ``authentic`` (its size, in every Content-Range, never compared), and
    with ``--chunks 2`` or plainly (its Content-Length) it decoded: one file, two answers."""
    served = tmp_path / "site"
    served.mkdir()
    (served / "j.pmw").write_bytes((site / "x.pmw").read_bytes() + b"JUNKJUNK")
    srv, thread = _serve(served, handler)
    try:
        url = f"http://127.0.0.1:{srv.server_address[1]}/j.pmw"
        for argv in (["verify", url, "--key", site / "x.pmw.key.json"], ["info", url],
                     ["decode", url, "--chunks", 2, "-o", tmp_path / "j.obj"]):
            for where in (served / "j.pmw", url):
                code, out, err = _pmw(capsys, *[where if a == url else a for a in argv])
                assert code == 2 and len(err.splitlines()) == 1, (argv, where, err)
                assert "8 bytes after the declared file length" in err, err
        with pytest.raises(FormatError, match="after the declared file length"):
            pmwm_codec.decode(url, chunks=2)
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)
    assert not (tmp_path / "j.obj").exists()


def test_every_reader_of_the_library_takes_a_url_as_its_command_does(server, site):
    """``decode_asset``, ``cut``, ``inspect`` and ``verify_stream`` took a URL for a file name (``...: no such
    file``), though ``pmw decode``, ``pmw cut``, ``pmw info`` and ``pmw verify`` take one."""
    url, path = server.url + "x.pmw", site / "x.pmw"
    for n in (0, 2, None):
        assert pmwm_codec.decode_asset(url, chunks=n) == pmwm_codec.decode_asset(path, chunks=n)
        assert pmwm_codec.cut(url, chunks=n) == pmwm_codec.cut(path, chunks=n)
    remote, local = pmwm_codec.inspect(url), pmwm_codec.inspect(path)
    assert remote["file"] == url and remote["chunks_total"] == local["chunks_total"]
    key = site / "x.pmw.key.json"
    assert pmwm_codec.verify_stream(url, key).verdict == pmwm_codec.verify_stream(path, key).verdict == "authentic"


def test_pmw_decode_of_a_url_up_to_chunk_n_says_the_file_is_complete_as_for_the_file(server, site, tmp_path, capsys):
    """``pmw decode URL --chunks N -o x.obj --json`` said ``complete: false, truncated: true`` of a whole file
    (what it did not fetch, on purpose, is not missing); a cut file on the server still says truncated."""
    from pmwm_codec.http import plan_ranges

    data = (site / "x.pmw").read_bytes()
    (site / "cut-x.pmw").write_bytes(data[: plan_ranges(data, 3)[-1]])
    for name, complete in (("x.pmw", True), ("cut-x.pmw", False)):
        for suffix in (".obj", ".glb"):
            for n in (0, 2):
                code, out, err = _pmw(capsys, "decode", server.url + name, "-o", tmp_path / f"o{suffix}",
                                      "--chunks", n, "--json")
                assert code == 0, err
                _, local, _ = _pmw(capsys, "decode", site / name, "-o", tmp_path / f"l{suffix}", "--chunks", n,
                                   "--json")
                got, want = json.loads(out), json.loads(local)
                assert got["complete"] is complete and got["truncated"] is not complete, (name, suffix, n, got)
                assert {k: v for k, v in got.items() if k not in ("output", "files")} == \
                    {k: v for k, v in want.items() if k not in ("output", "files")}


@pytest.mark.parametrize("url, words", [
    ("http://[::1/x.pmw", "not a valid URL"), ("http://127.0.0.1:99999/x.pmw", "not a valid URL"),
    ("http://127.0.0.1:1/a b.pmw", "not a valid URL"), ("http://127.0.0.1:1/x.pmw\r\nX-Injected: 1", "not a valid URL"),
    ("http://me:hunter2@127.0.0.1:1/x.pmw", "user name or password in the URL is not supported"),
    # a password beside a port out of range or a host that does not parse: echoed whole
    ("http://me:hunter2@127.0.0.1:99999/x.pmw", "user name or password in the URL is not supported"),
    ("http://me:hunter2@[::1/x.pmw", "user name or password in the URL is not supported"),
])
def test_a_url_that_cannot_be_fetched_is_named_without_its_password(tmp_path, capsys, url, words):
    """Each ended as ``unexpected ValueError / InvalidURL (a bug of pmw)``, or for a URL with a password as a
    name lookup of ``me:hunter2@127.0.0.1`` that echoed the password; a password beside a port out of range or a
    host that does not parse was echoed in the error line."""
    code, out, err = _pmw(capsys, "decode", url, "-o", tmp_path / "x.obj")
    assert code == 2 and len(err.splitlines()) == 1 and words in err and "bug of pmw" not in err, err
    assert "hunter2" not in err and not (tmp_path / "x.obj").exists()


class Redirecting(RangeRequestHandler):
    """A server that answers every request with a redirect to ``location`` (``{port}``: its own port)."""

    location = ""

    def send_head(self):
        self.send_response(302)
        self.send_header("Location", self.location.format(port=self.server.server_address[1]))
        self.send_header("Content-Length", "0")
        self.end_headers()
        return None


@pytest.mark.parametrize("location", [
    "ftp://user:s3cret@files.example/x.pmw?token=t0ken",
    "https://user:s3cret@127.0.0.1:1/x.pmw?X-Amz-Signature=t0ken",
    "http://user:s3cret@127.0.0.1:{port}/x.pmw",
])
def test_a_refused_redirect_is_named_without_the_servers_credentials(site, tmp_path, capsys, location):
    """The refusal of a redirect to another scheme echoed the server's ``Location`` whole, password and token
    included; a redirect to an http(s) URL with a user name and password was followed, the credentials taken for
    part of the host name (``cannot read (Name or service not known)``).  Both are refused, in one line that
    names the target without them."""
    handler = type("Redirected", (Redirecting,), {"location": location})
    with _served(site, handler) as url:
        for argv in (["decode", url, "-o", tmp_path / "x.obj"], ["verify", url, "--key", site / "x.pmw.key.json"]):
            code, out, err = _pmw(capsys, *argv)
            assert code == 2 and err.startswith(f"pmw: error: {url}: redirected to ") and "verdict" not in out, err
            assert len(err.splitlines()) == 1 and "...@" in err and "s3cret" not in err and "t0ken" not in err, err
    assert not (tmp_path / "x.obj").exists()


def test_a_server_that_does_not_speak_http_is_a_named_error(tmp_path, capsys):
    """A status line that is not HTTP raised ``http.client.BadStatusLine``: ``unexpected ... (a bug of pmw)``."""
    import socket

    listener = socket.create_server(("127.0.0.1", 0))

    def answer():
        conn, _ = listener.accept()
        with conn:
            conn.recv(65536)
            conn.sendall(b"SSH-2.0-OpenSSH_9.0\r\n\r\n")

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        url = f"http://127.0.0.1:{listener.getsockname()[1]}/x.pmw"
        code, _, err = _pmw(capsys, "decode", url, "-o", tmp_path / "x.obj")
        assert code == 2 and "cannot read (BadStatusLine" in err and "bug of pmw" not in err, err
    finally:
        listener.close()
        thread.join(5)


class Trickling(RangeRequestHandler):
    """A server that sends a byte every 0.1 s (never silent long enough for a socket timeout), for 8 s at most."""

    def copyfile(self, source, outputfile):
        import time

        stop = time.monotonic() + 8
        while time.monotonic() < stop:
            block = source.read(1)
            if not block:
                return
            outputfile.write(block)
            outputfile.flush()
            time.sleep(0.1)


def test_a_server_that_trickles_is_a_named_error_not_a_read_of_hours(site):
    """A byte every 0.1 s never trips the socket timeout: a .pmw of a few KB took hours, a large one days."""
    with _served(site, Trickling) as url:
        _decode_stalls(url, "the server stalls")


def test_serve_answers_say_accept_ranges_once_and_name_the_files_version(tmp_path):
    """A 206 carried ``Accept-Ranges`` twice and neither answer an ``ETag``: a reader by ranges could not tell a
    file replaced between its requests by one of the same size."""
    import os

    (tmp_path / "a.bin").write_bytes(b"x" * 100)
    srv, thread = _serve(tmp_path, RangeRequestHandler)
    url = f"http://127.0.0.1:{srv.server_address[1]}/a.bin"
    try:
        tags = []
        for headers in ({}, {"Range": "bytes=0-9"}, {"Range": "bytes=0-9"}):
            with urllib.request.urlopen(urllib.request.Request(url, headers=headers), timeout=10) as r:
                assert r.headers.get_all("Accept-Ranges") == ["bytes"] and r.headers["Last-Modified"]
                tags.append(r.headers["ETag"])
            (tmp_path / "a.bin").write_bytes(b"y" * 100)
            os.utime(tmp_path / "a.bin", ns=(len(tags), len(tags)))
        assert None not in tags and len(set(tags)) == 3
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def test_serve_closes_the_connection_when_the_file_shrank_under_its_answer(tmp_path):
    """A file cut shorter (copied over by a writer that is not atomic) after its headers announced the old length:
    the server sent fewer bytes and kept the connection open, so a keep-alive client waited for the rest until
    its timeout (30 s by default; a browser longer)."""
    import http.client

    class Shrinking(RangeRequestHandler):
        def send_head(self):
            f = super().send_head()
            (tmp_path / "x.pmw").write_bytes(b"glTF")  # truncated in place, the same inode
            return f

    srv, thread = _serve(tmp_path, Shrinking)
    try:
        for ranged in (True, False):
            (tmp_path / "x.pmw").write_bytes(b"glTF" + bytes(4000))
            headers = {"Range": "bytes=0-999"} if ranged else {}
            # a keep-alive client, as a browser is (urllib asks for Connection: close); a connection left open would
            # end in its timeout (TimeoutError, not IncompleteRead: no bound on the time taken, which load can outrun)
            connection = http.client.HTTPConnection("127.0.0.1", srv.server_address[1], timeout=10)
            try:
                connection.request("GET", "/x.pmw", headers=headers)
                with pytest.raises(http.client.IncompleteRead):  # told the body ended early
                    connection.getresponse().read()
            finally:
                connection.close()
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def test_an_empty_file_over_http_is_a_stream_cut_before_its_header(tmp_path, capsys):
    """Its first Range request is unsatisfiable (416): that was ``HTTP 416 Requested Range Not Satisfiable``,
    where the same empty file on disk says how many bytes the stream had."""
    (tmp_path / "empty.pmw").write_bytes(b"")
    srv, thread = _serve(tmp_path, RangeRequestHandler)
    try:
        code, _, err = _pmw(capsys, "decode", f"http://127.0.0.1:{srv.server_address[1]}/empty.pmw", "-o",
                            tmp_path / "x.obj")
        assert code == 2 and "truncated: stream ended after 0 bytes" in err and len(err.splitlines()) == 1, err
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def _get(url, headers=None):
    """``(status, headers, body)`` of a GET (an error status too)."""
    try:
        with urllib.request.urlopen(urllib.request.Request(url, headers=headers or {}), timeout=10) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as exc:
        with exc:
            return exc.code, exc.headers, exc.read()


def test_serve_checks_a_folders_index_file_as_any_file(tmp_path):
    """``GET /a/`` served ``a/index.html`` (or ``index.htm``) as the standard library picked it, without the checks
    of ``translate_path``: a link out of the directory and a key file leaked (with or without ``Range``).  An index
    file is still served when it passes them; a folder without one is 404 (no listing), without a final ``/``
    a redirect."""
    import os

    site, outside = tmp_path / "site", tmp_path / "outside"
    for d in (site / "a", site / "b", site / "c", site / "d", site / "e", outside):
        d.mkdir(parents=True)
    (outside / "secret.txt").write_text("not yours")
    from pmwm_codec.watermark.key import WatermarkKey

    key = WatermarkKey.generate(rng=np.random.default_rng(1))
    key.save(outside / "owner.key.json")
    os.symlink(outside / "secret.txt", site / "a" / "index.html")  # out of the directory
    (site / "b" / "index.html").write_bytes(key.to_text())  # a key by its content
    os.symlink(outside / "owner.key.json", site / "c" / "index.htm")  # a key by its name, out of the directory
    (site / "d" / "index.html").write_text("<p>demo</p>")
    (site / "index.html").write_bytes(key.to_text())
    srv, thread = _serve(site, RangeRequestHandler)
    base = f"http://127.0.0.1:{srv.server_address[1]}/"
    try:
        for headers in ({}, {"Range": "bytes=0-5"}):
            for path in ("", "a/", "b/", "c/", "e/", "a/index.html", "b/index.html"):
                status, _, body = _get(base + path, headers)
                assert status == 404 and b"not yours" not in body and key.secret_hex.encode() not in body, (path, body)
            status, _, body = _get(base + "d/", headers)
            assert status in (200, 206) and b"<p>demo</p>".startswith(body), (status, body)
        status, got, _ = _get(base + "d", {})  # a redirect (followed by urllib) to d/
        assert status == 200
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def _key_variants(key) -> dict:
    """The same key file written as the key loader reads it and a byte pattern on its head does not."""
    text = key.to_text().decode()
    doc = json.loads(text)
    order = ["reference", "params", "secret", "fingerprint", "file_id", "owner_id", "version", "format"]
    return {
        "escaped_value.json": text.replace('"pmwm-key"', '"pmwm\\u002dkey"'),
        "escaped_name.json": text.replace('"format"', '"\\u0066ormat"'),
        "padded.json": " " * 5000 + text,
        "reordered.json": json.dumps({k: doc[k] for k in order if k in doc}, indent=2),  # format after 5 KB
        "compact.txt": json.dumps(doc, separators=(",", ":")),
    }


def test_serve_refuses_every_key_the_key_loader_reads_whatever_its_spelling(tmp_path):
    """A key file written with a JSON escape in ``format`` or its value, after 5000 blanks, or with ``format`` after
    a large ``reference`` was served whole, secret included (``is_key_file`` tested a byte pattern on the first
    4096 bytes); ``pmw verify --key`` reads each as the key.  Other JSON files are still served."""
    from pmwm_codec.watermark.key import WatermarkKey, is_key_file

    image = np.random.default_rng(2).integers(0, 256, (64, 64)).astype(np.uint8)  # a PNG of about 5 KB
    key = WatermarkKey.generate(rng=np.random.default_rng(2), reference=image)
    site = tmp_path / "site"
    site.mkdir()
    for name, text in _key_variants(key).items():
        (site / name).write_text(text)
        assert WatermarkKey.load(site / name) == key and is_key_file(site / name), name
    (site / "scene.gltf").write_text(json.dumps({"asset": {"version": "2.0"}, "format": "pmwm-key-not"}))
    (site / "escaped.json").write_text('{"name": "caf\\u00e9", "format": "other"}')
    (site / "notes.json").write_text(" " * 5000 + '{"format": "pmwm-key-list"}')
    _check_served_keys(site, key, served=("scene.gltf", "escaped.json", "notes.json"))


def _check_served_keys(site, key, encoding="utf-8", served=()):
    """``site`` served: each file of ``_key_variants(key)`` (written there in ``encoding``) is 404 with or without
    ``Range``, the secret nowhere in the answer; each file named in ``served`` is no key, and served."""
    from pmwm_codec.watermark.key import is_key_file

    srv, thread = _serve(site, RangeRequestHandler)
    base = f"http://127.0.0.1:{srv.server_address[1]}/"
    try:
        for name in _key_variants(key):
            for headers in ({}, {"Range": "bytes=0-"}):
                status, _, body = _get(base + name, headers)
                assert status == 404 and key.secret_hex.encode(encoding) not in body, name
        for name in served:
            assert not is_key_file(site / name) and _get(base + name)[0] == 200, name
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def test_serve_never_sends_a_key_saved_with_a_byte_order_mark(tmp_path):
    """A key file re-saved by an editor that puts a UTF-8 BOM first (the key loader then refuses it, but the secret
    is all there) was served whole under another name, and an output could replace it."""
    from pmwm_codec.watermark.key import WatermarkKey, is_key_file

    key = WatermarkKey.generate(rng=np.random.default_rng(5))
    site = tmp_path / "site"
    site.mkdir()
    for name, text in _key_variants(key).items():
        (site / name).write_bytes(b"\xef\xbb\xbf" + text.encode())
        assert is_key_file(site / name), name
    _check_served_keys(site, key)


@pytest.mark.parametrize("encoding", ["utf-16-le", "utf-16-be", "utf-32-le", "utf-32-be"])
@pytest.mark.parametrize("bom", [False, True])
def test_serve_never_sends_a_key_in_another_unicode_encoding(tmp_path, encoding, bom):
    """A key file re-saved as UTF-16 (an editor's "Unicode") or UTF-32, with a byte order mark or without, was served
    whole: the loader cannot read it, but it holds the secret all the same.  Other JSON in those encodings, and
    files that only look like them, are still served."""
    import codecs

    from pmwm_codec.watermark.key import WatermarkKey, is_key_file

    key = WatermarkKey.generate(rng=np.random.default_rng(6))
    mark = {"utf-16-le": codecs.BOM_UTF16_LE, "utf-16-be": codecs.BOM_UTF16_BE, "utf-32-le": codecs.BOM_UTF32_LE,
            "utf-32-be": codecs.BOM_UTF32_BE}[encoding] if bom else b""
    site = tmp_path / "site"
    site.mkdir()
    for name, text in _key_variants(key).items():
        (site / name).write_bytes(mark + text.encode(encoding))
        assert is_key_file(site / name), name
    (site / "scene.gltf").write_bytes(mark + json.dumps({"asset": {"version": "2.0"}}).encode(encoding))
    (site / "data.bin").write_bytes(b"{\0\0\0" + bytes(range(256)))  # the NULs of UTF-32: not a key all the same
    _check_served_keys(site, key, encoding, served=("scene.gltf", "data.bin"))


def test_is_key_file_reads_a_large_file_that_is_no_key_in_blocks_and_a_large_key_whole(tmp_path):
    """Any JSON object up to 64 MiB was read whole, and parsed when it held a backslash or ``pmwm-key`` anywhere (a
    .gltf whose buffer is a ``data:`` URI with its ``/`` escaped, a list that names ``pmwm-key-list``): ``pmw serve``
    did so for every request of such a file (a 60 MB .gltf: 0.4-1.4 s and 450 MB a request).  Such a file is now
    read a block at a time, for the format's value as a JSON string, and no more is held; a key is still a key with
    its format after a reference image of 1.4 MB, in UTF-8 or UTF-16."""
    import base64
    import tracemalloc

    from pmwm_codec.watermark.key import WatermarkKey, is_key_file

    data = base64.b64encode(np.random.default_rng(7).integers(0, 256, 9_000_000, dtype=np.uint8).tobytes()).decode()
    (tmp_path / "scene.gltf").write_text(json.dumps(  # 12 MB, and a backslash in every block
        {"asset": {"version": "2.0"}, "buffers": [{"uri": "data:application/octet-stream;base64," + data}]}
    ).replace("/", "\\/"))
    (tmp_path / "list.json").write_text(json.dumps({"items": list(range(1_500_000)), "format": "pmwm-key-list"}))
    for name in ("scene.gltf", "list.json"):
        tracemalloc.start()
        try:
            assert not is_key_file(tmp_path / name), name
            peak = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        assert peak < 6 << 20, (name, peak)
    image = np.random.default_rng(8).integers(0, 256, (1024, 1024)).astype(np.uint8)
    key = WatermarkKey.generate(rng=np.random.default_rng(8), reference=image)
    doc = key.to_json()
    text = json.dumps({"reference": doc.pop("reference"), **doc})  # the format 1.4 MB in
    (tmp_path / "k.json").write_text(text)
    assert WatermarkKey.load(tmp_path / "k.json") == key and is_key_file(tmp_path / "k.json")
    (tmp_path / "k.json").write_bytes(text.encode("utf-16"))
    assert is_key_file(tmp_path / "k.json")


def test_is_key_file_refuses_at_least_what_it_refused(tmp_path):
    """The check guards output paths too (a key file is never rewritten): every file the byte pattern on the
    head named a key still is one, the loader's reading added to it."""
    from pmwm_codec.watermark.key import is_key_file

    cases = {
        "nested.json": '{"x": {"format": "pmwm-key"}}',  # a key format named on the head, not at the top
        "broken.json": '{"format": "pmwm-key", "secret": ',  # not JSON at all
        "tail.json": '{"format" : "pmwm-key"}' + "x" * 70_000_000,  # over the key file size limit
    }
    for name, text in cases.items():
        (tmp_path / name).write_text(text)
        assert is_key_file(tmp_path / name), name
    (tmp_path / "deep.json").write_text('{"a": ' * 100_000 + "1" + "}" * 100_000)
    (tmp_path / "blank.json").write_text(" " * 10_000)
    (tmp_path / "x.key.json").write_text("")  # by its name
    assert not is_key_file(tmp_path / "deep.json") and not is_key_file(tmp_path / "blank.json")
    assert is_key_file(tmp_path / "x.key.json") and is_key_file(tmp_path / "missing.KEY.json")
    assert not is_key_file(tmp_path / "missing.json") and not is_key_file(tmp_path)


def test_serve_answers_a_range_with_a_stale_if_range_with_the_whole_file(tmp_path):
    """``If-Range`` was ignored: a client resuming with the validator of a replaced file got a 206 slice of the new
    file, which it would splice onto the old one (RFC 9110 §13.1.5: the whole file, 200)."""
    import os

    (tmp_path / "a.bin").write_bytes(b"x" * 100)
    os.utime(tmp_path / "a.bin", (1_000_000_000, 1_000_000_000))
    srv, thread = _serve(tmp_path, RangeRequestHandler)
    url = f"http://127.0.0.1:{srv.server_address[1]}/a.bin"
    try:
        status, headers, _ = _get(url)
        old_tag, old_date = headers["ETag"], headers["Last-Modified"]
        for validator in (old_tag, old_date):
            status, headers, body = _get(url, {"Range": "bytes=90-", "If-Range": validator})
            assert status == 206 and body == b"x" * 10 and headers["Content-Range"] == "bytes 90-99/100"
        (tmp_path / "a.bin").write_bytes(b"y" * 200)
        os.utime(tmp_path / "a.bin", (1_000_000_100, 1_000_000_100))
        for validator in (old_tag, old_date, "W/" + old_tag, "Thu, 01 Jan 1970 00:00:00 GMT", "not a date"):
            status, headers, body = _get(url, {"Range": "bytes=90-", "If-Range": validator})
            assert status == 200 and body == b"y" * 200 and "Content-Range" not in headers, validator
        status, headers, body = _get(url, {"Range": "bytes=190-", "If-Range": _get(url)[1]["ETag"]})
        assert status == 206 and body == b"y" * 10
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


@pytest.mark.parametrize("host", ["", " "])
def test_pmw_serve_refuses_an_empty_host(tmp_path, capsys, monkeypatch, host):
    """``--host ""`` bound every interface (0.0.0.0) without a word."""
    from pmwm_codec.cli import serve

    def bound(*args, **kwargs):
        raise AssertionError("a server was made")

    monkeypatch.setattr(serve, "make_server", bound)
    code, _, err = _pmw(capsys, "serve", tmp_path, "--host", host, "--port", "0")
    assert code == 2 and err.startswith("pmw: error: --host") and len(err.splitlines()) == 1, err


def test_pmw_serve_names_a_host_it_cannot_listen_on(tmp_path, capsys):
    """``--host 999.1.1.1`` said ``Name or service not known``, naming neither the option nor the host."""
    code, _, err = _pmw(capsys, "serve", tmp_path, "--host", "999.1.1.1", "--port", "0")
    assert code == 2 and "999.1.1.1" in err and len(err.splitlines()) == 1, err


def _ipv6_loopback() -> bool:
    """Whether this machine can listen on ``::1``."""
    import socket

    try:
        with socket.socket(socket.AF_INET6) as probe:
            probe.bind(("::1", 0))
    except OSError:
        return False
    return True


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback on this machine")
def test_pmw_serve_listens_on_an_ipv6_address_and_names_it_in_brackets(site):
    """``pmw serve --host ::1`` (or ``::``) was ``cannot listen there (Address family for hostname not supported)``:
    the server was IPv4 only.  It listens, prints its URL with the address in brackets, and the reader reads it."""
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "pmwm_codec", "serve", str(site), "--port", "0", "--host", "::1"],
                            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
                            cwd=Path(__file__).resolve().parents[1])
    try:
        line = proc.stdout.readline()
        assert re.fullmatch(r"serving .* at http://\[::1\]:\d+/ \(Ctrl-C to stop\)\n", line), line
        source = UrlSource(line.split(" at ")[1].split()[0] + "x.pmw", max_chunks=1)
        assert pmwm_codec.decode(source, chunks=1) == pmwm_codec.decode(site / "x.pmw", chunks=1) and source.ranged
    finally:
        proc.terminate()
        proc.wait(10)
        proc.stdout.close()
    from pmwm_codec.cli.serve import server_url

    for host, shown in (("[::1]", "[::1]"), ("::", "[::]")):
        srv = make_server(site, host, 0)
        thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
        thread.start()
        try:
            url = server_url(srv)
            assert re.fullmatch(rf"http://{re.escape(shown)}:\d+/", url), url
            assert pmwm_codec.decode(url.replace("[::]", "[::1]") + "x.pmw") == pmwm_codec.decode(site / "x.pmw")
        finally:
            srv.shutdown()
            srv.server_close()
            thread.join(5)


def test_a_url_with_non_ascii_characters_is_sent_percent_encoded_as_a_browser_does(site, tmp_path, capsys):
    """``http://host/café.pmw`` raised a bare ``UnicodeEncodeError`` (the command: "unexpected ... a bug of pmw");
    the path is now sent as UTF-8 percent-encoded (``caf%C3%A9.pmw``), a host name in IDNA, and a host name that
    has no IDNA form is a named error."""
    import shutil

    shutil.copy(site / "x.pmw", site / "café.pmw")
    srv, thread = _serve(site, RangeRequestHandler)
    base = f"http://127.0.0.1:{srv.server_address[1]}/"
    try:
        assert pmwm_codec.decode(base + "café.pmw") == pmwm_codec.decode(site / "x.pmw")
        code, out, err = _pmw(capsys, "info", base + "café.pmw?v=é#à", "--json")
        assert code == 0 and json.loads(out)["chunks_total"] == inspect(site / "x.pmw")["chunks_total"], err
        code, _, err = _pmw(capsys, "decode", base + "nowhere-é.pmw", "-o", tmp_path / "x.obj")
        assert code == 2 and "404" in err and "bug of pmw" not in err and len(err.splitlines()) == 1, err
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)
    with pytest.raises(InputFormatError, match="not a valid URL"):
        pmwm_codec.decode("http://" + "é" * 70 + ".example/x.pmw")
    code, _, err = _pmw(capsys, "verify", "http://" + "é" * 70 + ".example/x.pmw", "--key", site / "x.pmw.key.json")
    assert code == 2 and "not a valid URL" in err and len(err.splitlines()) == 1, err


@pytest.mark.parametrize("cap", [7, 300])
def test_a_server_that_sends_shorter_ranges_than_asked_is_asked_for_the_rest(site, tmp_path, capsys, cap):
    """An answer shorter than asked was taken for the end of the file, though its Content-Range said the file went
    on: ``pmw decode URL`` exited 0 with the base mesh of a complete file, ``pmw cut URL`` kept 2 of its chunks,
    ``pmw verify URL`` said truncated; a cap under the base mesh's size made each say "truncated" of a complete
    file.  The reader now asks for the rest of each range."""
    from pmwm_codec.format.reader import read_header

    handler = type("Capped", (Capping,), {"cap": cap})
    srv, thread = _serve(site, handler)
    url = f"http://127.0.0.1:{srv.server_address[1]}/x.pmw"
    key = site / "x.pmw.key.json"
    try:
        source = UrlSource(url)
        assert pmwm_codec.decode(source) == pmwm_codec.decode(site / "x.pmw")
        size, header_end = (site / "x.pmw").stat().st_size, read_header((site / "x.pmw").read_bytes()).bin_offset
        assert source.ranged and source.bytes_fetched == size

        def answers(start, end):
            return -(-(end - start) // cap)

        # the three requests planned (the preamble, the JSON, the rest), and one for the rest of each short answer
        assert source.requests == answers(0, 20) + answers(20, header_end) + answers(header_end, size)
        for command in (["decode", "-o", tmp_path / "{}.obj", "--json"], ["cut", "-o", tmp_path / "{}.pmw", "--json"],
                        ["verify", "--key", key, "--json"]):
            argv = [str(a).format("remote") for a in command[1:]]
            code, out, err = _pmw(capsys, command[0], url, *argv)
            assert code == 0, err
            argv = [str(a).format("local") for a in command[1:]]
            _, local, _ = _pmw(capsys, command[0], site / "x.pmw", *argv)
            got, want = json.loads(out), json.loads(local)
            assert {k: v for k, v in got.items() if k not in ("output", "input", "files")} == \
                {k: v for k, v in want.items() if k not in ("output", "input", "files")}, command[0]
            assert got.get("complete", True) and not got.get("truncated")
        assert (tmp_path / "remote.pmw").read_bytes() == (tmp_path / "local.pmw").read_bytes()
        assert (tmp_path / "remote.obj").read_bytes() == (tmp_path / "local.obj").read_bytes()
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


class HugeContentRange(RangeRequestHandler):
    """A ``Content-Range`` with 5000-digit numbers (``int()`` of so many digits raises ``ValueError``)."""

    def send_header(self, keyword, value):
        if keyword == "Content-Range":
            value = "bytes 0-" + "9" * 5000 + "/" + "9" * 5000
        super().send_header(keyword, value)


def test_a_content_range_of_thousands_of_digits_is_a_named_error(site):
    srv, thread = _serve(site, HugeContentRange)
    try:
        with pytest.raises(InputFormatError, match="does not answer bytes 0-19"):
            pmwm_codec.decode(f"http://127.0.0.1:{srv.server_address[1]}/x.pmw")
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


TAIL = 256 << 20  # zeros after the file: more than any reader may hold for a 10 KB file


@pytest.fixture(scope="module")
def owner_site(tmp_path_factory):
    """A directory with ``x.pmw`` whose key has an owner ID (the owner layer reads a stream twice)."""
    from pmwm_codec.watermark.key import WatermarkKey

    d = tmp_path_factory.mktemp("owner-site")
    image = np.random.default_rng(3).integers(0, 256, (16, 16)).astype(np.uint8)
    pmwm_codec.encode(shapes.icosphere(3, noise=0.05), d / "x.pmw", watermark=image, measure="none")
    assert WatermarkKey.load(d / "x.pmw.key.json").owner_id is not None
    return d


class Padded(IgnoringRange):
    """A server that ignores ``Range`` and sends the file followed by :data:`TAIL` zero bytes (``Content-Length``
    says so); ``gzip``: all of it gzip-encoded (a 256 KB answer that decodes to 256 MB)."""

    gzip = False

    def send_head(self):
        import zlib

        self._span = None
        data = Path(self.translate_path(self.path)).read_bytes()
        if self.gzip:
            packer = zlib.compressobj(9, zlib.DEFLATED, 16 + zlib.MAX_WBITS)
            zeros = bytes(1 << 20)
            self._parts = [packer.compress(data)] + [packer.compress(zeros) for _ in range(TAIL >> 20)]
            self._parts.append(packer.flush())
        else:
            self._parts = None
        size = sum(map(len, self._parts)) if self.gzip else len(data) + TAIL
        self.send_response(200)
        if self.gzip:
            self.send_header("Content-Encoding", "gzip")
        self.send_header("Content-Length", str(size))
        self.end_headers()
        self._data = data
        return io.BytesIO(b"")

    def copyfile(self, source, outputfile):
        parts = self._parts or [self._data] + [bytes(1 << 20)] * (TAIL >> 20)
        for part in parts:
            _count_sent(self.server, len(part))
            outputfile.write(part)


def _count_sent(server, n):
    with server.count_lock:
        server.bytes_sent += n


class Endless(io.RawIOBase):
    """Standard input of a ``.pmw`` followed by :data:`TAIL` zero bytes; ``given`` counts the bytes read."""

    def __init__(self, data: bytes):
        self.data, self.given = data, 0

    def readable(self):
        return True

    def readinto(self, buffer):
        n = min(len(buffer), len(self.data) + TAIL - self.given)
        head = self.data[self.given : self.given + n]
        buffer[: len(head)] = head
        buffer[len(head) : n] = bytes(n - len(head))
        self.given += n
        return n


@pytest.mark.parametrize("gzip", [False, True])
def test_verify_url_reads_no_more_than_the_file_declares(owner_site, capsys, gzip):
    """``pmw verify URL`` with a key that has an owner ID read the whole body into memory before parsing it: a server
    that sends the file then 1 GiB of zeros (or a gzip bomb) took it to 2.1 GB, a ``Content-Length`` of 10^12 to
    15.7 GB.  The reader stops at the GLB header's declared length and refuses a body that goes on."""
    site = owner_site
    key = site / "x.pmw.key.json"
    srv, thread = _serve(site, type("P", (Padded,), {"gzip": gzip}))
    url = f"http://127.0.0.1:{srv.server_address[1]}/x.pmw"
    size = (site / "x.pmw").stat().st_size
    try:
        # a plain body's Content-Length that says the file goes on past its GLB length is refused before the
        # bytes past it are read (as a file with bytes after its GLB length is on disk, even up to chunk 2)
        refusal = "more than the {size:,} bytes the file's GLB header declares" if gzip else \
            "TAIL bytes after the declared file length {size}"
        refusal = refusal.format(size=size).replace("TAIL", str(TAIL))
        code, _, err = _pmw(capsys, "verify", url, "--key", key)
        assert code == 2 and refusal in err, err
        assert len(err.splitlines()) == 1
        from pmwm_codec.http import read_declared

        source = UrlSource(url)
        with pytest.raises(PmwError, match=re.escape(refusal)):
            read_declared(source)
        assert source.bytes_fetched <= size + (1 << 16) + 1  # the file, then one byte (compressed: fewer)
        srv.bytes_sent = 0
        if gzip:  # its decoded length is not known before it is read: stopped early, no refusal
            mesh = pmwm_codec.decode(UrlSource(url, max_chunks=2), chunks=2)
            assert mesh == pmwm_codec.decode(site / "x.pmw", chunks=2)
        else:
            with pytest.raises(FormatError, match=re.escape(refusal)):
                pmwm_codec.decode(UrlSource(url, max_chunks=2), chunks=2)
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)
    assert srv.bytes_sent < TAIL // 4  # the zeros were not all sent: the reader went away


@pytest.mark.parametrize("command", ["verify", "decode"])
def test_a_stream_on_standard_input_is_read_no_further_than_its_declared_length(owner_site, tmp_path, capsys,
                                                                                 monkeypatch, command):
    """``pmw verify -`` (a key with an owner ID) and ``pmw decode - -o x.glb`` read all of standard input into memory
    before parsing it: a .pmw followed by 1 GiB of zeros took 2.1 GB."""
    import sys

    site = owner_site
    data = (site / "x.pmw").read_bytes()
    stdin = Endless(data)
    monkeypatch.setattr(sys, "stdin", io.TextIOWrapper(io.BufferedReader(stdin)))
    argv = ["--key", site / "x.pmw.key.json"] if command == "verify" else ["-o", tmp_path / "x.glb"]
    code, _, err = _pmw(capsys, command, "-", *argv)
    assert code == 2 and f"after the declared file length {len(data)}" in err and len(err.splitlines()) == 1, err
    assert stdin.given < len(data) + (4 << 20), stdin.given
    assert not (tmp_path / "x.glb").exists()


class Dripping(Capping):
    """A server that spreads every answer (of 300 bytes at most: many of them) over 0.5 s, whatever its size: each ends
    well within any timeout."""

    def copyfile(self, source, outputfile):
        import time

        data = source.read(self._length)
        for i in range(5):
            outputfile.write(data[i * len(data) // 5 : (i + 1) * len(data) // 5])
            outputfile.flush()
            time.sleep(0.1)


def test_a_server_that_drips_every_range_answer_is_a_stall_of_the_whole_transfer(site, monkeypatch):
    """The pace was judged per answer: a server that sent each of the many Range answers slowly, but within the
    timeout, held ``pmw verify URL`` for the number of requests times the timeout (65,536 chunks x 30 s).  The
    transfer as a whole must now average ``MIN_RATE`` past its first ``timeout`` seconds of network time."""
    from pmwm_codec import http

    monkeypatch.setattr(http, "MIN_RATE", 20_000)  # so that a 0.5 s answer of 300 bytes is too slow
    with _served(site, Dripping) as url:  # a 2 s timeout: no single 0.5 s answer nears it, even on a loaded machine
        source = _decode_stalls(url, r"the server stalls: [\d,]+ bytes in \d+ s, under 20,000 bytes/s", timeout=2)
        assert source.requests <= 10


def test_a_server_that_drips_its_answers_head_is_cut_off_after_the_timeout(tmp_path, capsys):
    """A status line and headers sent a byte every 0.2 s never trip a socket timeout: the read of one answer's head
    took as long as the server liked (here 8 s, then "cannot read (RemoteDisconnected ...)").  This server drips
    until the reader has given up, a minute at most (a guard against a hang): the reader must give up while the
    server is still dripping, whatever the machine's load, not notice the stall once the head has come."""
    import socket

    listener = socket.create_server(("127.0.0.1", 0))
    done = threading.Event()
    dripped_to_the_end = []

    def answer():
        conn, _ = listener.accept()
        with conn:
            conn.recv(65536)
            for byte in b"HTTP/1.1 200 OK\r\nX-Slow: " + b"x" * 300:
                if done.wait(0.2):
                    return
                try:
                    conn.sendall(bytes([byte]))
                except OSError:
                    return
            dripped_to_the_end.append(True)

    thread = threading.Thread(target=answer, daemon=True)
    thread.start()
    try:
        _decode_stalls(f"http://127.0.0.1:{listener.getsockname()[1]}/x.pmw",
                       r"the server stalls: 0 bytes in \d+ s, under 64 bytes/s after the first 1 s\)$")
    finally:
        done.set()
        listener.close()
        thread.join(10)
    assert not dripped_to_the_end


class Steady(RangeRequestHandler):
    """A slow link: every answer sent at ``rate`` bytes a second, a tenth of that every 0.1 s."""

    rate = 800

    def copyfile(self, source, outputfile):
        import time

        left = self._length
        while left:
            block = source.read(min(left, self.rate // 10))
            if not block:
                return
            outputfile.write(block)
            outputfile.flush()
            left -= len(block)
            time.sleep(0.1)


def test_a_slow_link_that_keeps_bringing_bytes_is_read_to_the_end(site):
    """A link at 800 bytes/s failed as ``the server stalls: 820 bytes in 1 s, under 1,024 bytes/s`` once past the
    timeout, though bytes kept coming (the JavaScript reader, which cuts off only a server that sends nothing for
    ``stallTimeout``, read it): the floor is now ``MIN_RATE``, 64 bytes/s, and a trickle under it still stalls."""
    with _served(site, Steady) as url:
        source = UrlSource(url, max_chunks=0, timeout=1)  # ~2.5 KB: ~3 s
        assert pmwm_codec.decode(source, chunks=0) == pmwm_codec.decode(site / "x.pmw", chunks=0)
        assert source.bytes_fetched == _prefix_end(site / "x.pmw", 0)
    with _served(site, type("Trickle", (Steady,), {"rate": 20})) as url:  # 2 bytes every 0.1 s
        _decode_stalls(url, r"the server stalls: \d+ bytes in \d+ s, under 64 bytes/s after the first 1 s")


def test_a_host_name_lookup_that_stalls_is_cut_off_after_the_timeout(site, monkeypatch):
    """``getaddrinfo`` blocks for as long as the resolver takes, and the watchdog had no connection to cut off: a
    lookup that never answered held the reader for ever.  It is now given the step's time and named."""
    import socket

    lookup = socket.getaddrinfo
    answer = threading.Event()  # the slow lookup answers once the reader has given up (a minute at most)

    def resolver(host, *args, **kwargs):
        if host == "slow.example":
            answer.wait(60)
        return lookup("127.0.0.1" if host.endswith(".example") else host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", resolver)
    with _served(site, RangeRequestHandler) as url:
        quick = UrlSource(url.replace("127.0.0.1", "quick.example"), timeout=1)  # the addresses it gives are used
        assert pmwm_codec.decode(quick) == pmwm_codec.decode(site / "x.pmw") and quick.ranged
        try:
            with pytest.raises(InputFormatError) as info:
                pmwm_codec.decode(UrlSource(url.replace("127.0.0.1", "slow.example"), timeout=1))
        finally:
            answer.set()
    assert re.fullmatch(r"http://slow\.example:\d+/x\.pmw: cannot read \(the name lookup \(DNS\) of slow\.example gave "
                        r"no answer in [01]\.\d s\)", str(info.value)), info.value


def test_an_ipv6_address_is_connected_to_with_its_scope_id(monkeypatch, capsys, tmp_path):
    """The connection was made by ``create_connection(sockaddr[:2])``: a second lookup of the bare address, which
    lost an IPv6 address's scope id, so a link-local server (``fe80::``, no address without its interface) could
    not be reached.  The address ``getaddrinfo`` gives goes to ``connect`` whole, and a URL's zone (RFC 6874:
    ``%25eth7``) goes to ``getaddrinfo`` as ``%eth7``."""
    import socket

    lookup, asked, connected = socket.getaddrinfo, [], []
    scoped = [(socket.AF_INET6, socket.SOCK_STREAM, 6, "", ("fe80::1", 8000, 0, 7))]

    def resolver(host, *args, **kwargs):  # this machine's getaddrinfo, with an interface 7 named eth7
        asked.append(host)
        return scoped if host in ("linklocal.example", "fe80::1%eth7") else lookup(host, *args, **kwargs)

    def connect(sock, address):
        connected.append((sock.family, address))
        raise ConnectionRefusedError("refused here")

    monkeypatch.setattr(socket, "getaddrinfo", resolver)
    monkeypatch.setattr(socket.socket, "connect", connect)
    for url, host in (("http://linklocal.example:8000/x.pmw", "linklocal.example"),
                      ("http://[fe80::1%25eth7]:8000/x.pmw", "fe80::1%eth7")):
        asked.clear()
        connected.clear()
        code, _, err = _pmw(capsys, "decode", url, "-o", tmp_path / "x.obj")
        assert asked == [host] and connected == [(socket.AF_INET6, ("fe80::1", 8000, 0, 7))], (asked, connected)
        assert code == 2 and err == f"pmw: error: {url}: cannot read (refused here)\n", err
    assert not (tmp_path / "x.obj").exists()


class HostNoting(RangeRequestHandler):
    """Notes the ``Host`` header of every request in ``hosts``."""

    hosts = []

    def parse_request(self):
        ok = super().parse_request()
        if ok:
            self.hosts.append(self.headers["Host"])
        return ok


@pytest.mark.skipif(not _ipv6_loopback(), reason="no IPv6 loopback on this machine")
def test_a_url_on_the_ipv6_loopback_is_still_read(site):
    """The connection made from the address ``getaddrinfo`` gives, not by ``create_connection``: ``[::1]`` reads
    as it did, its ``Host`` header as the URL writes it."""
    handler = type("Noting", (HostNoting,), {"hosts": []})
    srv = make_server(site, "::1", 0, handler)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        source = UrlSource(f"http://[::1]:{srv.server_address[1]}/x.pmw")
        assert pmwm_codec.decode(source) == pmwm_codec.decode(site / "x.pmw") and source.ranged
        assert set(handler.hosts) == {f"[::1]:{srv.server_address[1]}"}
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)


def _link_local() -> tuple | None:
    """``(address, interface name, interface index)`` of a link-local IPv6 address of this machine (Linux), or None."""
    try:
        with open("/proc/net/if_inet6") as rows:
            for hexed, index, _, scope, _, name in (row.split() for row in rows):
                if scope == "20":  # link scope
                    return ":".join(hexed[i:i + 4] for i in range(0, 32, 4)), name, int(index, 16)
    except (OSError, ValueError):
        pass
    return None


@pytest.mark.skipif(_link_local() is None, reason="no link-local IPv6 address on this machine")
def test_a_link_local_url_with_its_zone_is_read_and_a_zone_of_no_interface_named(site, tmp_path, capsys):
    """``http://[fe80::...%25eth0]:port/x.pmw`` (RFC 6874) was ``cannot read ([Errno -2] Name or service not
    known)``: the zone reached ``getaddrinfo`` as ``25eth0``, and the scope id it gives was dropped.  It reads,
    the ``Host`` header without the zone (the client's business, as curl sends it); a zone that names no interface,
    or none at all, is one line naming what is missing."""
    import socket
    from functools import partial

    from pmwm_codec.cli.serve import _Server6

    address, name, index = _link_local()
    handler = type("Noting", (HostNoting,), {"hosts": []})
    srv = _Server6((address, 0, 0, index), partial(handler, directory=str(site)))
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    shown = socket.getnameinfo((address, 0, 0, index), socket.NI_NUMERICHOST)[0].partition("%")[0]
    port = srv.server_address[1]
    try:
        source = UrlSource(f"http://[{shown}%25{name}]:{port}/x.pmw")
        assert pmwm_codec.decode(source) == pmwm_codec.decode(site / "x.pmw") and source.ranged
        assert set(handler.hosts) == {f"[{shown}]:{port}"}
        for zone, words in (("%25nosuch0", f"no network interface 'nosuch0' on this machine (the zone of {shown})"),
                            ("", f"{shown} is a link-local address: the URL names its network interface after it")):
            url = f"http://[{shown}{zone}]:{port}/x.pmw"
            code, _, err = _pmw(capsys, "decode", url, "-o", tmp_path / "x.obj")
            assert code == 2 and err.startswith(f"pmw: error: {url}: cannot read ({words}") and \
                len(err.splitlines()) == 1, err
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)
    assert not (tmp_path / "x.obj").exists()


@pytest.mark.skipif(_link_local() is None, reason="no link-local IPv6 address on this machine")
def test_pmw_serve_listens_on_a_link_local_address_with_its_zone_and_prints_a_url_that_reads(site):
    """``pmw serve --host fe80::...%eth0`` was ``cannot listen there (Invalid argument)``: the zone's scope id was
    dropped at bind, as the reader dropped it at connect.  It listens, its URL names the zone (``%25eth0``, RFC 6874),
    and that URL reads; a zone of no interface is still one line, exit 2."""
    import socket
    import subprocess
    import sys

    address, name, _ = _link_local()
    shown = socket.getnameinfo((address, 0), socket.NI_NUMERICHOST)[0].partition("%")[0]
    from pmwm_codec.cli.serve import server_url

    srv = make_server(site, f"{shown}%{name}", 0)
    thread = threading.Thread(target=srv.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    try:
        url = server_url(srv)
        assert re.fullmatch(rf"http://\[{re.escape(shown)}%25{re.escape(name)}\]:\d+/", url), url
        assert pmwm_codec.decode(url + "x.pmw") == pmwm_codec.decode(site / "x.pmw")
    finally:
        srv.shutdown()
        srv.server_close()
        thread.join(5)
    done = subprocess.run([sys.executable, "-m", "pmwm_codec", "serve", str(site), "--port", "0",
                           "--host", f"{shown}%nosuch0"], capture_output=True, text=True, timeout=60,
                          cwd=Path(__file__).resolve().parents[1])
    assert done.returncode == 2 and done.stderr.startswith(f"pmw: error: --host {shown}%nosuch0 --port 0: cannot "
                                                           "listen there (") and len(done.stderr.splitlines()) == 1
