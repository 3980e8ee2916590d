"""The whole pipeline: encode -> .pmw -> push/pull decode, whole, cut, fed in any blocks."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.errors import ChecksumError, FormatError, OptionError, TruncatedError
from pmwm_codec.progressive.grid import Grid
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.progressive.topology import face_keys
from samples import closed_file


def small_mesh():
    return shapes.components(shapes.icosphere(3, 1.0, noise=0.04), shapes.grid(14, 12, hole=True))


@pytest.fixture(scope="module", params=["draco", "plain"])
def encoded(request):
    mesh = small_mesh()
    buf = io.BytesIO()
    report = encode_mesh(mesh, buf, base_codec=request.param, min_chunk_splits=40, measure=False)
    return mesh, buf.getvalue(), report


def all_results(data, **kw):
    dec = StreamDecoder(**kw)
    out = dec.feed(data)
    end = dec.close()
    return out, end


def same_mesh_up_to_renumbering(a_pos, a_faces, b_pos, b_faces):
    """Equal oriented faces and positions after matching vertices by position."""
    ka = np.lexsort(a_pos.T[::-1])
    kb = np.lexsort(b_pos.T[::-1])
    if not np.allclose(a_pos[ka], b_pos[kb]):
        return False
    ra = np.empty(len(ka), np.int64)
    ra[ka] = np.arange(len(ka))
    rb = np.empty(len(kb), np.int64)
    rb[kb] = np.arange(len(kb))
    fa = face_keys(ra[a_faces])
    fb = face_keys(rb[b_faces])
    fa = fa[np.lexsort(fa.T[::-1])]
    fb = fb[np.lexsort(fb.T[::-1])]
    return np.array_equal(fa, fb)


def test_decoding_the_whole_file_gives_the_input_mesh_within_one_grid_step(encoded):
    mesh, data, _ = encoded
    out = pmwm_codec.decode(data)
    assert out.vertex_count == mesh.vertex_count and out.face_count == mesh.face_count
    grid = Grid.fit(mesh.positions, 16)
    # positions: every input vertex has a decoded vertex within half a grid step per axis
    q_in = grid.quantize(mesh.positions)
    q_out = grid.quantize(out.positions)
    assert same_mesh_up_to_renumbering(q_in.astype(float), mesh.faces, q_out.astype(float), out.faces)
    assert np.abs(grid.dequantize(q_in) - mesh.positions).max() <= grid.step


def test_results_arrive_base_first_then_one_per_chunk_in_order(encoded):
    _, data, report = encoded
    results, end = all_results(data)
    assert [r.chunk for r in results] == list(range(report.chunks + 1))
    assert end.complete and not end.truncated
    assert results[-1].vertices == report.vertices
    assert all(a.bytes_read < b.bytes_read for a, b in zip(results, results[1:]))


def test_every_cut_yields_exactly_the_chunks_inside_it(encoded):
    _, data, _ = encoded
    full, _ = all_results(data)
    ends = [r.bytes_read for r in full]
    cuts = sorted(set(range(0, len(data) + 1, 97)) | {e + d for e in ends for d in (-1, 0, 1)} | {len(data)})
    for cut in cuts:
        if cut < 0 or cut > len(data):
            continue
        dec = StreamDecoder()
        if cut < ends[0]:
            dec.feed(data[:cut])
            with pytest.raises(TruncatedError):
                dec.close()
            continue
        got = dec.feed(data[:cut])
        end = dec.close()
        want = [r for r in full if r.bytes_read <= cut]
        assert [r.chunk for r in got] == [r.chunk for r in want]
        assert end.truncated == (cut < len(data))
        for g, w in zip(got, want):
            assert np.array_equal(g.positions_int, w.positions_int) and np.array_equal(g.faces, w.faces)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 4000), min_size=1, max_size=40))
def test_any_block_sizes_give_the_same_results(sizes):
    data = _cached_small_file()
    full, _ = all_results(data)
    dec = StreamDecoder()
    got, pos, i = [], 0, 0
    while pos < len(data):
        step = sizes[i % len(sizes)]
        got += dec.feed(data[pos : pos + step])
        pos += step
        i += 1
    assert dec.close().complete
    assert [r.chunk for r in got] == [r.chunk for r in full]
    assert all(np.array_equal(a.faces, b.faces) for a, b in zip(got, full))


_SMALL = {}


def _cached_small_file():
    if "data" not in _SMALL:
        buf = io.BytesIO()
        encode_mesh(small_mesh(), buf, min_chunk_splits=40, measure=False)
        _SMALL["data"] = buf.getvalue()
    return _SMALL["data"]


def test_pull_wrappers_agree_with_the_push_decoder(encoded, tmp_path):
    _, data, _ = encoded
    path = tmp_path / "m.pmw"
    path.write_bytes(data)
    full, _ = all_results(data)
    for source in (str(path), data, io.BytesIO(data), [data[i : i + 333] for i in range(0, len(data), 333)]):
        got = list(pmwm_codec.iter_decode(source))
        assert [r.chunk for r in got] == [r.chunk for r in full]
        assert np.array_equal(got[-1].faces, full[-1].faces)


def test_a_flipped_bit_in_a_chunk_is_reported_as_corruption_of_that_chunk(encoded):
    _, data, _ = encoded
    full, _ = all_results(data)
    # flip a bit in the middle of chunk 2's bytes
    start, stop = full[1].bytes_read, full[2].bytes_read
    bad = bytearray(data)
    bad[(start + stop) // 2] ^= 0x10
    dec = StreamDecoder()
    with pytest.raises(ChecksumError) as err:
        dec.feed(bytes(bad))
        dec.close()
    assert "2" in str(err.value)


def test_decode_chunks_stops_after_n_chunks(encoded):
    _, data, _ = encoded
    full, _ = all_results(data)
    m = pmwm_codec.decode(data, chunks=2)
    assert m.vertex_count == full[2].vertices and m.face_count == full[2].faces_count


def test_a_second_close_is_harmless_and_a_broken_stream_keeps_saying_why():
    """A second ``close()`` raised a bare RuntimeError from the container parser; after an error, later
    calls did too (``feed() after an error``) instead of naming what broke the stream."""
    data = _cached_small_file()
    dec = StreamDecoder()
    dec.feed(data)
    end = dec.close()
    assert dec.close() == end and end.complete
    with pytest.raises(ValueError, match="single-use"):
        dec.feed(b"")
    cut = StreamDecoder()
    cut.feed(data[:10])
    for _ in range(2):
        with pytest.raises(TruncatedError, match="before the base mesh"):
            cut.close()
    bad = StreamDecoder()
    with pytest.raises(FormatError, match="bad magic"):
        bad.feed(b"glTX" + data[4:])
    for call in (lambda: bad.feed(data), bad.close, bad.close):
        with pytest.raises(FormatError, match="bad magic"):
            call()


@pytest.mark.parametrize("data", ["glTF", 5, None, [b"glTF"]])
def test_feeding_anything_but_bytes_is_an_option_error_that_leaves_the_decoder_usable(data):
    """``feed(str)`` raised a bare TypeError from ``memoryview``."""
    dec = StreamDecoder()
    with pytest.raises(OptionError, match="StreamDecoder.feed.*bytes-like.*got " + type(data).__name__):
        dec.feed(data)
    assert dec.feed(_cached_small_file()) and dec.close().complete


@pytest.mark.parametrize("source, words", [
    (5, "the source must be a path.*got int"), (None, "got NoneType"),
    (io.StringIO("glTF"), "text mode.*open the file in binary mode"),
    (["glTF"], "a block of the source.*got str"), ([b"glTF", 7], "a block of the source.*got int"),
])
def test_every_reader_names_a_source_it_cannot_read(source, words):
    """Each raised a bare TypeError (``'int' object is not iterable``, ``can't concat str to bytearray``)."""
    for read in (pmwm_codec.decode, pmwm_codec.decode_asset, pmwm_codec.cut, pmwm_codec.inspect,
                 lambda src: list(pmwm_codec.iter_decode(src))):
        if hasattr(source, "seek"):
            source.seek(0)
        with pytest.raises(OptionError, match=words):
            read(source)


_READERS = {"decode": lambda s: pmwm_codec.decode(s).face_count, "iter_decode": lambda s: len(list(pmwm_codec.iter_decode(s))),
            "decode_asset": pmwm_codec.decode_asset, "cut": pmwm_codec.cut,
            "inspect": lambda s: {k: v for k, v in pmwm_codec.inspect(s).items() if k != "file"}}


def _strided(data: bytes) -> memoryview:
    """A non-contiguous memoryview whose bytes are ``data``: every other byte of a twice-as-long buffer."""
    buf = np.zeros(2 * len(data), np.uint8)
    buf[::2] = np.frombuffer(data, np.uint8)
    return memoryview(buf)[::2]


@pytest.mark.parametrize("kind", ["numpy uint8 array", "numpy (n, 4) array", "non-contiguous memoryview",
                                  "blocks of numpy arrays"])
def test_every_reader_reads_any_bytes_like_source_as_its_bytes(kind):
    """A numpy array was read as zeros by decode_asset (``bytes(np.uint8(71))`` is 71 zero bytes), as nothing by
    cut and raised IndexError in inspect; a strided memoryview was refused by decode ("expected (... memoryview),
    got memoryview") and raised TypeError in cut."""
    data = _cached_small_file()
    data = data + b"\0" * (-len(data) % 4)  # a GLB is 4-byte aligned already; the (n, 4) view needs it
    blocks = [data[i:i + 999] for i in range(0, len(data), 999)]
    source, same = {"numpy uint8 array": (lambda: np.frombuffer(data, np.uint8), data),
                    "numpy (n, 4) array": (lambda: np.frombuffer(data, np.uint8).reshape(-1, 4), data),
                    "non-contiguous memoryview": (lambda: _strided(data), data),
                    "blocks of numpy arrays": (lambda: [np.frombuffer(b, np.uint8) for b in blocks], blocks)}[kind]
    for name, read in _READERS.items():
        assert read(source()) == read(same), name


@pytest.mark.parametrize("kind, words", [
    ("closed file", "the file object \\(BufferedReader\\) is closed"),
    ("file open for writing", "not open for reading"),
    ("non-blocking pipe", "non-blocking mode"),
    ("read() gives None", "read\\(\\) gave None"),
])
def test_every_reader_refuses_a_file_object_it_cannot_read_whole_with_one_named_error(tmp_path, kind, words):
    """A closed file raised ValueError ("read of closed file"); a non-blocking file whose read() gives None (no
    data ready) was read as ending there: a silently shorter file."""
    import os

    path = tmp_path / "m.pmw"
    path.write_bytes(_cached_small_file())

    class NoDataYet(io.RawIOBase):
        def readable(self):
            return True

        def readinto(self, b):
            return None

    def non_blocking_pipe():
        r, w = os.pipe()
        os.write(w, _cached_small_file()[:1000])
        os.set_blocking(r, False)
        return os.fdopen(r, "rb", buffering=0)

    make = {"closed file": lambda: closed_file(path), "file open for writing": lambda: open(tmp_path / "w", "wb"),
            "non-blocking pipe": non_blocking_pipe, "read() gives None": NoDataYet}[kind]
    for name, read in _READERS.items():
        source = make()
        try:
            with pytest.raises(OptionError, match=words):
                read(source)
        finally:
            source.close()
