"""Bytes the JavaScript reader (js/src) and this one read differently, found by a differential run of both
over mutated files (helper-126): each case here was accepted by one reader and refused by the other, or
refused by this one with an exception that is no :class:`~pmwm_codec.errors.PmwError`.  The JavaScript
side's cases are in ``js/test/reader-differentials.test.js``.  The sources are conformance files."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest

from pmwm_codec.errors import FormatError, LimitError
from pmwm_codec.format.glb import glb_parts, split_glb
from pmwm_codec.stream import StreamDecoder

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"
DRACO = "uv-torus-attributes.welded-draco.v1.pmw"  # Draco base, welded, COLOR_0 / TEXCOORD_0 / _FEATURE_ID_0
PLAIN = "sphere-attributes.plain.v1.pmw"  # plain base, NORMAL / TEXCOORD_0


def _decode(data: bytes) -> None:
    dec = StreamDecoder()
    dec.feed(data)
    dec.close()


def _rewrite(name: str, change) -> bytes:
    gltf, binary = split_glb((CONFORMANCE / name).read_bytes())
    change(gltf)
    return b"".join(glb_parts(gltf, [binary], len(binary)))


def _prim(gltf) -> dict:
    return gltf["meshes"][0]["primitives"][0]


@pytest.mark.parametrize("name", [DRACO, PLAIN])
def test_the_sources_decode(name):
    _decode((CONFORMANCE / name).read_bytes())
    _decode(_rewrite(name, lambda gltf: None))


@pytest.mark.parametrize("extra", [1, 2, 3])
def test_a_bin_chunk_whose_length_is_no_multiple_of_4_is_a_format_error(extra):
    """bitstream.md §3: a chunk's length is a multiple of 4. The JavaScript reader refused such a BIN chunk,
    this one decoded the file (bytes appended to the BIN, the GLB and BIN lengths raised to match)."""
    data = bytearray((CONFORMANCE / PLAIN).read_bytes() + bytes(extra))
    json_length = struct.unpack_from("<I", data, 12)[0]
    struct.pack_into("<I", data, 8, len(data))
    bin_length = struct.unpack_from("<I", data, 20 + json_length)[0]
    struct.pack_into("<I", data, 20 + json_length, bin_length + extra)
    with pytest.raises(FormatError, match="not a multiple of 4"):
        _decode(bytes(data))


def test_a_progressive_attribute_a_draco_base_primitive_lacks_is_a_format_error():
    """An extension attribute whose semantic is not in the primitive's attributes: a KeyError here on a
    Draco base (a plain base already refused it), a FormatError in JavaScript."""
    def change(gltf):
        _prim(gltf)["extensions"]["PMWM_progressive_mesh"]["attributes"][1]["semantic"] = "TEXCOORD_7"

    with pytest.raises(FormatError, match="'TEXCOORD_7' is not an attribute of the primitive"):
        _decode(_rewrite(DRACO, change))


@pytest.mark.parametrize("name, semantic", [(DRACO, "TEXCOORD_0"), (DRACO, "_PMWM_WELD"), (PLAIN, "NORMAL")])
@pytest.mark.parametrize("field, wrap", [("componentType", lambda v: [v]), ("componentType", lambda v: {str(v): 1}),
                                         ("type", lambda v: [v]), ("type", lambda v: {v: 1})])
def test_an_attribute_accessor_type_that_is_no_json_scalar_is_a_format_error(name, semantic, field, wrap):
    """``componentType: [5126]`` or ``type: ["VEC2"]`` on a progressive attribute's (or the weld's) accessor:
    a TypeError here (unhashable), a FormatError in JavaScript."""
    def change(gltf):
        acc = gltf["accessors"][_prim(gltf)["attributes"][semantic]]
        acc[field] = wrap(acc[field])

    with pytest.raises(FormatError):
        _decode(_rewrite(name, change))


@pytest.mark.parametrize("value", [True, False, -1, 65536, "1", None])
def test_a_draco_attribute_id_that_is_no_integer_of_its_range_is_a_format_error(value):
    """``KHR_draco_mesh_compression.attributes.COLOR_0: true``: this reader took it for unique id 1 (COLOR_0's
    own id in this file, so the file decoded); JavaScript refuses an id that is not an integer 0..65535."""
    def change(gltf):
        _prim(gltf)["extensions"]["KHR_draco_mesh_compression"]["attributes"]["COLOR_0"] = value

    with pytest.raises(FormatError):
        _decode(_rewrite(DRACO, change))


@pytest.mark.parametrize("name, which, count", [
    (PLAIN, "indices", 2**31), (PLAIN, "indices", 3 * 134217728 + 1), (DRACO, "indices", 2**32),
    (PLAIN, "TEXCOORD_0", 67108865), (PLAIN, "NORMAL", 2**32), (DRACO, "TEXCOORD_0", 2**64), (DRACO, "_PMWM_WELD", 2**31)])
def test_a_base_accessor_count_over_its_limit_is_a_limit_error(name, which, count):
    """spec README, Kinds of refusal: an accessor's count over a limit is a LimitError. This reader named an
    index count over ``3 * MAX_FACES`` that is no multiple of 3, and an attribute accessor's count over
    ``MAX_VERTICES`` (unequal to the POSITION count), format errors; JavaScript checks the limit first."""
    def change(gltf):
        prim = _prim(gltf)
        gltf["accessors"][prim["indices"] if which == "indices" else prim["attributes"][which]]["count"] = count

    with pytest.raises(LimitError):
        _decode(_rewrite(name, change))


@pytest.mark.parametrize("k", [0, 1, 2])
@pytest.mark.parametrize("count", [2**31, 67108865])
def test_a_chunk_table_vertex_count_over_the_limit_is_a_limit_error_before_the_next_counts_order(k, count):
    """A version 2 chunk table (array form) whose ``vertexCounts[k]`` is over ``MAX_VERTICES`` (2^31: its splits
    too): a LimitError in JavaScript, which checks chunk by chunk; this reader first saw ``vertexCounts[k + 1]``
    smaller than it and said FormatError."""
    def change(gltf):
        _prim(gltf)["extensions"]["PMWM_progressive_mesh"]["chunks"]["vertexCounts"][k] = count

    with pytest.raises(LimitError, match="exceeds the limit"):
        _decode(_rewrite("sphere-attributes.plain.v2.pmw", change))


# --- bytes after the GLB's declared length (spec README, Partial files) ------------------------------------------

TRAILING = [b"\0\0\0\0", b"JUNKJUNKJUNK", (CONFORMANCE / PLAIN).read_bytes()[:24]]  # zeros, text, a second GLB's start


def _level(r) -> tuple:
    """What a level is, independent of how the bytes were split."""
    return (r.chunk, r.bytes_read, r.vertices, r.faces_count, r.positions_int.tobytes(), r.faces.tobytes(),
            b"".join(p.attributes_int.tobytes() for p in r.parts))


def _pieces(data: bytes, size: int) -> list:
    return [data[i:i + size] for i in range(0, len(data), size)]


def _splits(clean: bytes, extra: bytes):
    """``(name, pieces)``: ``clean + extra`` split in every way the spec names: at once, in pieces of several sizes
    (the extra bytes split across feeds when a piece is shorter), the extra bytes in the piece that brings the last
    chunk, in a later piece, or in several later pieces."""
    data = clean + extra
    yield "whole", [data]
    for size in (1, 3, 7, 64, 509, 4096):
        yield f"pieces of {size}", _pieces(data, size)
    last_chunk = _decoded(clean)[-1][1]
    start = last_chunk - 5  # the last chunk's end and the extra bytes together
    yield "with the last chunk", [clean[:start], data[start:]]
    yield "later", [clean, extra]
    yield "later, split", [clean, *_pieces(extra, 2)]
    yield "later, after an empty feed", [clean, b"", extra]


def _decoded(data: bytes) -> list:
    dec = StreamDecoder()
    levels = [_level(r) for r in dec.feed(data)]
    assert dec.close().complete
    return levels


@pytest.mark.parametrize("name", [PLAIN, DRACO, "sphere-attributes.plain.v2.pmw", "bowtie.welded-draco.packed.v2.pmw"])
@pytest.mark.parametrize("extra", TRAILING, ids=["zeros", "text", "glb"])
def test_bytes_after_the_declared_length_come_after_every_level_and_are_refused_once(name, extra):
    """Every level the bytes inside the GLB's length complete is delivered, in order and as the clean file's, then
    one FormatError names the bytes after that length: from the feed that brought them when it completed no level,
    else from the next call (``feed`` or ``close``), and again from every call after it. The reader refused the
    feed that brought the extra bytes without reading the file's bytes in it (a whole file: no level at all),
    where the JavaScript reader delivered them: the two readers showed different levels of the same bytes."""
    clean = (CONFORMANCE / name).read_bytes()
    total = len(clean)
    expected = _decoded(clean)
    for how, pieces in _splits(clean, extra):
        dec, levels, error, at, received, over = StreamDecoder(), [], None, None, 0, None
        for i, piece in enumerate([*pieces, None]):  # None: close()
            received += len(piece or b"")
            if over is None and received > total:
                over = (i, received - total)
            try:
                levels += dec.feed(piece) if piece is not None else [dec.close()]
            except FormatError as exc:
                error, at = exc, i
                break
        assert error is not None and over is not None, how
        assert [_level(r) for r in levels] == expected, how
        assert at in (over[0], over[0] + 1), how  # refused by the feed that brought them, or by the next call
        assert str(error) == f"GLB: {over[1]} bytes after the declared file length {total}", how
        for again in (dec.close,) if at == len(pieces) else (lambda: dec.feed(b""), dec.close):
            with pytest.raises(FormatError) as exc:
                again()
            assert exc.value is error, how


def test_the_pull_readers_give_every_level_then_refuse_bytes_after_the_declared_length(tmp_path):
    """``iter_decode`` (a path, bytes) yields the clean file's levels, then raises; ``decode`` and ``pmw decode``
    refuse (exit 2, one line, no file written), as for a corrupt last chunk."""
    import pmwm_codec
    from pmwm_codec.cli import main

    clean = (CONFORMANCE / PLAIN).read_bytes()
    longer = tmp_path / "longer.pmw"
    longer.write_bytes(clean + b"JUNK")
    expected = _decoded(clean)
    for source in (longer, clean + b"JUNK"):
        levels = []
        with pytest.raises(FormatError, match=f"^GLB: 4 bytes after the declared file length {len(clean)}$"):
            for r in pmwm_codec.iter_decode(source):
                levels.append(_level(r))
        assert levels == expected
        with pytest.raises(FormatError, match="after the declared file length"):
            pmwm_codec.decode(source)
    assert main(["decode", str(longer), "-o", str(tmp_path / "out.obj")]) == 2
    assert not (tmp_path / "out.obj").exists()


@pytest.mark.parametrize("chunks", [0, 1, None])
def test_cut_refuses_bytes_after_the_declared_length_that_arrive_after_the_chunks_it_keeps(chunks):
    """``pmw cut --chunks N`` stops parsing once chunk N is in: bytes after the declared length in a later block
    (a file of more than 64 KiB, read in blocks) were never seen and the cut was written, exit 0; in the same block
    they were refused."""
    import pmwm_codec

    clean = (CONFORMANCE / PLAIN).read_bytes()
    for blocks in ([clean, b"JUNK"], [clean + b"JUNK"], [*_pieces(clean, 4096), b"JU", b"NK"]):
        with pytest.raises(FormatError, match=f"^GLB: [24] bytes after the declared file length {len(clean)}$"):
            pmwm_codec.cut(iter(blocks), chunks=chunks)


def test_a_chunk_that_fails_as_it_is_applied_comes_after_the_levels_of_the_same_feed():
    """A last chunk whose counts differ from its index entry (digest intact: it fails as it is applied): the
    feed that brought it with the chunks before it raised at once and returned none of their levels (fed chunk by
    chunk, they were delivered); the JavaScript reader returns them and refuses from the next call, as the spec's
    Integrity section asks (the levels before stay valid). Now the same levels whatever the split."""
    def change(gltf):
        ext = _prim(gltf)["extensions"]["PMWM_progressive_mesh"]
        ext["chunks"][-1]["faceCount"] += 2
        ext["faceCount"] += 2

    data = _rewrite(PLAIN, change)
    expected = [level[:1] + level[2:] for level in _decoded((CONFORMANCE / PLAIN).read_bytes())[:-1]]
    for size in (len(data), 4096, 1):
        dec, levels = StreamDecoder(), []
        with pytest.raises(FormatError, match=f"^chunk {len(expected)}: vertex/face counts differ") as exc:
            for piece in _pieces(data, size):
                levels += dec.feed(piece)
            dec.close()
        assert [level[:1] + level[2:] for level in map(_level, levels)] == expected, size
        with pytest.raises(FormatError) as again:
            dec.close()
        assert again.value is exc.value


@pytest.mark.parametrize("name, which", [(PLAIN, "POSITION"), (PLAIN, "indices"), (PLAIN, "chunks"), (DRACO, "chunks"),
                                         ("sphere-attributes.plain.packed.v2.pmw", "POSITION"),
                                         ("sphere-attributes.plain.packed.v2.pmw", "chunks")])
def test_a_buffer_view_whose_buffer_is_false_is_a_format_error(name, which):
    """``"buffer": false`` on the bufferView of a base accessor or of a chunk (helper-136's differential run: 102
    of 2,102 integer members set to a boolean): ``False != 0`` is false in Python, so this reader took the view as
    buffer 0's and decoded every level, the JavaScript one refused it (a Draco base's bufferView was already refused) (spec/README.md, Kinds of refusal: a member of
    the wrong JSON type is a format error; glTF types ``buffer`` integer)."""
    def change(gltf):
        prim = _prim(gltf)
        if which == "chunks":
            chunks = prim["extensions"]["PMWM_progressive_mesh"]["chunks"]
            view = chunks["bufferView"] if isinstance(chunks, dict) else chunks[0]["bufferView"]
        elif which == "indices":
            view = gltf["accessors"][prim["indices"]]["bufferView"]
        else:
            view = gltf["accessors"][prim["attributes"]["POSITION"]]["bufferView"]
        gltf["bufferViews"][view]["buffer"] = False

    with pytest.raises(FormatError, match="buffer must be a non-negative integer, got False"):
        _decode(_rewrite(name, change))


# --- an srgb8 colour byte outside 0..255 (spec/README.md, attributes: transfer) -----------------------------------

def colour_pushed_out(payload: bytes) -> bytes:
    """A version 1 chunk payload whose first split's first attribute residual (the Draco source's COLOR_0 red, an
    ``srgb8`` byte) moves 256 away from zero: its byte, the prediction (0..255) plus it, lies outside 0..255."""
    from pmwm_codec.format.records import pack_batches, unpack_batches

    batches = unpack_batches(payload, width=3 + 3 + 2 + 1)  # positions, COLOR_0, TEXCOORD_0, _FEATURE_ID_0
    r = batches[0].residual
    r[0, 3] += 256 if r[0, 3] >= 0 else -256
    return pack_batches(batches)


SRGB8_CHUNK = 3  # the chunk (1-based) whose new vertex gets the byte


def test_an_srgb8_byte_outside_0_255_refuses_the_chunk_that_brings_it_after_the_levels_before_it(tmp_path):
    """A chunk whose payload (behind a valid digest) gives a new vertex an srgb8 colour byte outside 0..255: the
    reader applied it and every chunk after it, and only turning the integers into floats refused the byte ("a
    colour's sRGB byte lies outside 0..255", naming neither the chunk nor the attribute; ``decode``, geometry only,
    never noticed and returned the whole mesh). Now the chunk is refused as it is applied, as any chunk whose
    payload is invalid: the levels before it delivered, then one FormatError naming the chunk and the attribute."""
    import pmwm_codec
    from pmwm_codec.cli import main
    from samples import rewrite_chunk

    clean = (CONFORMANCE / DRACO).read_bytes()
    data = rewrite_chunk(clean, SRGB8_CHUNK - 1, colour_pushed_out)
    expected = [level[:1] + level[2:] for level in _decoded(clean)[:SRGB8_CHUNK]]
    message = rf"^chunk {SRGB8_CHUNK}: COLOR_0: sRGB byte -?\d+ lies outside 0\.\.255$"
    for size in (len(data), 4096, 1):
        dec, levels = StreamDecoder(), []
        with pytest.raises(FormatError, match=message):
            for piece in _pieces(data, size):
                levels += dec.feed(piece)
            dec.close()
        assert [level[:1] + level[2:] for level in map(_level, levels)] == expected, size
        for r in levels:
            r.parts[0].attribute_values()  # every level delivered holds only bytes of 0..255
    with pytest.raises(FormatError, match=message):
        pmwm_codec.decode(data)
    assert len(pmwm_codec.decode(data, chunks=SRGB8_CHUNK - 1).positions) == expected[-1][1]
    bad = tmp_path / "bad.pmw"
    bad.write_bytes(data)
    assert main(["decode", str(bad), "-o", str(tmp_path / "out.glb")]) == 2
    assert not (tmp_path / "out.glb").exists()


def test_both_decoders_refuse_an_srgb8_byte_outside_0_255_at_the_chunk_that_brings_it(tmp_path, capsys):
    """tools/decoder_diff.py on that file: the JavaScript reader delivers the same levels and refuses at the same
    chunk with the same kind (both decoded every chunk and refused the byte only when dequantizing a level)."""
    import shutil

    from samples import rewrite_chunk
    from tools import decoder_diff

    if shutil.which("node") is None or not (CONFORMANCE.parents[1] / "js" / "node_modules" / "zstddec").exists():
        pytest.skip("node or js/node_modules absent")
    bad = tmp_path / "bad.pmw"
    bad.write_bytes(rewrite_chunk((CONFORMANCE / DRACO).read_bytes(), SRGB8_CHUNK - 1, colour_pushed_out))
    py = decoder_diff.python_run(str(bad))
    assert len(py["levels"]) == SRGB8_CHUNK and py["outcome"].startswith(f"FormatError: chunk {SRGB8_CHUNK}: COLOR_0:")
    for split in (0, 7):
        assert decoder_diff.main([str(bad), "--split", str(split)]) == 0
        assert "1 files: 1 agreed" in capsys.readouterr().out
