"""`pmw cut`: any prefix of a .pmw becomes a valid, smaller .pmw; textured assets are laid out base first."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from PIL import Image

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.errors import TruncatedError
from pmwm_codec.format import read_header
from pmwm_codec.format.layout import CHUNK_HEADER_SIZE, GLB_HEADER_SIZE, PREAMBLE_SIZE, ChunkHeader, GlbHeader
from pmwm_codec.format.glb import glb_parts
from pmwm_codec.format.parser import parse_preamble
from pmwm_codec.stream.asset import decode_asset, encode_asset
from pmwm_codec.stream.cut import cut, cut_file
from pmwm_codec.stream.decoder import StreamDecoder
from pmwm_codec.stream.reader import decode_stream

from conftest import corpus_path, marked_sphere
from test_asset import DocBuilder, check, two_mesh_asset


def _png(size: int = 32) -> bytes:
    """A small grayscale PNG without colour-profile chunks."""
    buf = io.BytesIO()
    Image.fromarray((np.indices((size, size)).sum(0) * 7 % 256).astype(np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _textured_asset() -> bytes:
    """A GLB: a UV-mapped sphere whose material samples an embedded PNG (stored before the mesh)."""
    b = DocBuilder()
    png = _png()
    b.doc["bufferViews"].append({"buffer": 0, "byteOffset": 0, "byteLength": len(png)})
    b.parts.append(png + bytes(-len(png) % 4))
    b.offset = len(png) + (-len(png) % 4)
    b.doc.update({
        "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{**b.triangles(shapes.icosphere(3, 1.0, noise=0.02)), "material": 0}]}],
        "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
        "textures": [{"source": 0, "sampler": 0}], "samplers": [{}],
        "images": [{"bufferView": 0, "mimeType": "image/png"}],
    })
    return b.glb()


def _json_and_bin(data: bytes) -> tuple:
    _, json_length = parse_preamble(data[:PREAMBLE_SIZE])
    gltf = json.loads(data[PREAMBLE_SIZE : PREAMBLE_SIZE + json_length])
    return gltf, PREAMBLE_SIZE + json_length + CHUNK_HEADER_SIZE


def _chunk_views(gltf) -> set:
    """The bufferViews holding chunks: one per chunk entry (payload version 1) or the one a
    version 2 chunk table names."""
    views = set()
    for m in gltf["meshes"]:
        for p in m["primitives"]:
            chunks = (p.get("extensions") or {}).get("PMWM_progressive_mesh", {}).get("chunks", [])
            if isinstance(chunks, dict):
                views |= {chunks["bufferView"]} if "bufferView" in chunks else set()
            else:
                views |= {c["bufferView"] for c in chunks}
    return views


@pytest.fixture
def textured_pmw(tmp_path):
    src = tmp_path / "tex.glb"
    src.write_bytes(_textured_asset())
    out = tmp_path / "tex.pmw"
    encode_asset(src, out, measure=False)
    return out.read_bytes()


def test_a_textured_asset_stores_its_base_then_its_image_then_the_chunks(textured_pmw):
    gltf, _ = _json_and_bin(textured_pmw)
    views = gltf["bufferViews"]
    prim = gltf["meshes"][0]["primitives"][0]
    draco = (prim.get("extensions") or {}).get("KHR_draco_mesh_compression")
    base_views = ({draco["bufferView"]} if draco else
                  {gltf["accessors"][a]["bufferView"] for a in [*prim["attributes"].values(), prim["indices"]]})
    image_view = gltf["images"][0]["bufferView"]
    end = lambda i: views[i].get("byteOffset", 0) + views[i]["byteLength"]  # noqa: E731
    assert max(end(i) for i in base_views) <= views[image_view]["byteOffset"]
    assert end(image_view) <= min(views[i]["byteOffset"] for i in _chunk_views(gltf))


def test_the_textured_base_decodes_from_the_bytes_of_the_base_and_its_image(textured_pmw):
    gltf, bin_start = _json_and_bin(textured_pmw)
    views = gltf["bufferViews"]
    needed = bin_start + max(v.get("byteOffset", 0) + v["byteLength"] for i, v in enumerate(views) if i not in _chunk_views(gltf))
    glb, end, _ = decode_asset(textured_pmw[:needed])
    assert end.chunks_applied == 0
    full, _, _ = decode_asset(textured_pmw)
    image = lambda data: Image.open(io.BytesIO(_image_bytes(data))).tobytes()  # noqa: E731
    assert image(glb) == image(full) == Image.open(io.BytesIO(_png())).tobytes()


def _image_bytes(glb: bytes) -> bytes:
    gltf, bin_start = _json_and_bin(glb)
    view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    return glb[bin_start + view.get("byteOffset", 0) : bin_start + view.get("byteOffset", 0) + view["byteLength"]]


def _same_levels(source: bytes, cut_bytes: bytes, chunks: int) -> None:
    a, _ = decode_stream(source, chunks=chunks)
    b, end = decode_stream(cut_bytes)
    assert end.complete and end.chunks_applied == min(chunks, a.chunks_total)
    assert np.array_equal(a.positions_int, b.positions_int) and np.array_equal(a.faces, b.faces)


def test_a_cut_file_decodes_to_the_same_mesh_as_the_source_with_as_many_chunks():
    data, key, _ = marked_sphere(4)
    total = read_header(data).chunk_count
    for n in range(total + 2):
        small = cut(data, n)
        _same_levels(data, small, n)
        assert len(small) <= len(data)


def test_a_cut_file_verifies_with_the_key_of_its_source():
    data, key, img = marked_sphere(5)
    for n in (2, read_header(data).chunk_count):
        ours = StreamDecoder(key, reference=img).feed(cut(data, n))[-1].estimate
        theirs = StreamDecoder(key, reference=img, max_chunks=n).feed(data)[-1].estimate
        assert np.array_equal(ours.watermark, theirs.watermark)
        assert (ours.verdict, ours.carriers_read, ours.code_match) == (theirs.verdict, theirs.carriers_read, theirs.code_match)
    assert ours.verdict == "authentic" and ours.bit_exact


def test_the_glb_lengths_of_a_cut_file_agree():
    data, _, _ = marked_sphere(6)
    small = cut(data[: len(data) * 3 // 4], 2)
    header = GlbHeader.parse(small[:GLB_HEADER_SIZE])
    gltf, bin_start = _json_and_bin(small)
    bin_header = ChunkHeader.parse(small[bin_start - CHUNK_HEADER_SIZE : bin_start])
    assert header.length == len(small) == bin_start + bin_header.length
    assert gltf["buffers"][0]["byteLength"] == bin_header.length
    ext = read_header(small).extension  # the chunk table expanded to per-chunk entries
    assert len(ext["chunks"]) == 2
    assert (ext["vertexCount"], ext["faceCount"]) == (ext["chunks"][-1]["vertexCount"], ext["chunks"][-1]["faceCount"])


def test_cutting_a_byte_prefix_keeps_the_chunks_that_arrived_whole():
    data, _, _ = marked_sphere(7)
    prefix = data[: len(data) * 2 // 3]
    arrived = decode_stream(prefix)[1].chunks_applied
    result = cut_file(prefix, None)
    assert result.chunks == result.chunks_available == arrived and not result.source_complete
    _same_levels(data, result.data, arrived)
    assert cut(result.data, None) == result.data  # cutting a cut file again changes nothing


def test_cutting_a_whole_file_with_all_chunks_gives_the_same_bytes():
    data, _, _ = marked_sphere(8)
    assert cut(data) == data


def test_a_prefix_without_the_whole_base_cannot_be_cut():
    data, _, _ = marked_sphere(9)
    with pytest.raises(TruncatedError):
        cut(data[:200], 0)


def test_a_multi_mesh_asset_cuts_every_primitive_to_the_level_reached(tmp_path):
    src = two_mesh_asset(tmp_path)
    encode_asset(src, tmp_path / "s.pmw", measure=False)
    data = (tmp_path / "s.pmw").read_bytes()
    for n in (0, 3, 7):
        small = cut(data, n)
        a, _ = decode_stream(data, chunks=n)
        b, _ = decode_stream(small)
        for pa, pb in zip(a.parts, b.parts):
            assert np.array_equal(pa.positions_int, pb.positions_int) and np.array_equal(pa.faces, pb.faces)
        gltf, _ = _json_and_bin(small)
        kept = min(n, read_header(data).chunk_count)
        assert read_header(small).chunk_count == kept
        assert len(_chunk_views(gltf)) == (1 if kept else 0)  # payload version 2: one shared bufferView


def test_every_cut_of_a_textured_asset_passes_the_khronos_validator(tmp_path, textured_pmw):
    total = read_header(textured_pmw).chunk_count
    for n in range(total + 1):
        path = tmp_path / f"cut{n}.pmw"
        path.write_bytes(cut(textured_pmw, n))
        result = check(path)
        assert result["validator"]["errors"] == 0 and result["validator"]["warnings"] == 0, (n, result["validator"])
        assert result["three"]["ok"]


def test_pmw_cut_reads_stdin_and_says_when_fewer_chunks_arrived(tmp_path, capsys, monkeypatch):
    data, _, _ = marked_sphere(10)
    prefix = data[: len(data) // 2 + 2000]
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(prefix)))
    out = tmp_path / "c.pmw"
    assert main(["cut", "-", "--chunks", "99", "-o", str(out), "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    arrived = decode_stream(prefix)[1].chunks_applied
    assert report["chunks"] == report["chunks_available"] == arrived and not report["input_complete"]
    assert "99" in report["notices"][0]
    assert out.read_bytes() == cut(prefix, 99)
    monkeypatch.setattr("sys.stdin", io.TextIOWrapper(io.BytesIO(prefix)))
    assert main(["cut", "-", "--chunks", "99", "-o", str(out), "-q"]) == 0
    assert "note:" in capsys.readouterr().err


def test_pmw_cut_of_a_file_without_its_base_fails_in_one_line_and_writes_nothing(tmp_path, capsys):
    data, _, _ = marked_sphere(11)
    src = tmp_path / "short.pmw"
    src.write_bytes(data[:300])
    assert main(["cut", str(src), "--chunks", "1", "-o", str(tmp_path / "o.pmw")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: ") and err.count("\n") == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == ["short.pmw"]
    assert main(["cut", str(src), "--chunks", "-1", "-o", str(tmp_path / "o.pmw")]) == 2


def _old_order(data: bytes) -> bytes:
    """The same file with the layout of files written before the base-first order: the
    document's own bufferViews (the image) first, then the base mesh, then the chunks."""
    gltf, bin_start = _json_and_bin(data)
    views, chunk_views = gltf["bufferViews"], _chunk_views(gltf)
    doc_views = [image["bufferView"] for image in gltf["images"]]
    lo = min(views[i]["byteOffset"] for i in doc_views)
    hi = max(views[i]["byteOffset"] + views[i]["byteLength"] for i in doc_views)
    payload = data[bin_start:]
    for i, view in enumerate(views):
        if i in doc_views:
            view["byteOffset"] -= lo
        elif i not in chunk_views:
            view["byteOffset"] = view.get("byteOffset", 0) + hi - lo
    moved = payload[lo:hi] + payload[:lo] + payload[hi:]
    return b"".join(glb_parts(gltf, [moved], len(moved)))


def test_files_with_the_old_order_still_decode_and_cut(textured_pmw):
    old = _old_order(textured_pmw)
    assert old != textured_pmw
    for n in (0, 2, None):
        a, _ = decode_stream(textured_pmw, chunks=n)
        b, _ = decode_stream(old, chunks=n)
        assert np.array_equal(a.positions_int, b.positions_int) and np.array_equal(a.faces, b.faces)
        _same_levels(old, cut(old, n), 99 if n is None else n)
    assert _image_bytes(decode_asset(old)[0]) == _image_bytes(decode_asset(textured_pmw)[0])


def _image_last(data: bytes) -> bytes:
    """The same file with the document's own bufferViews (the image) after the chunks (bitstream.md §4 lets a
    file place them anywhere outside the chunk ranges); where they were, zero bytes."""
    gltf, bin_start = _json_and_bin(data)
    views, payload = gltf["bufferViews"], bytearray(data[bin_start:])
    end = len(payload)
    for i in (image["bufferView"] for image in gltf["images"]):
        start, length = views[i]["byteOffset"], views[i]["byteLength"]
        payload += payload[start : start + length] + bytes(-length % 4)
        payload[start : start + length] = bytes(length)
        views[i]["byteOffset"], end = end, len(payload)
    return b"".join(glb_parts(gltf, [bytes(payload)], len(payload)))


def test_a_cut_carries_no_byte_of_the_chunks_it_drops(textured_pmw):
    """With the document's data after the chunks, ``pmw cut`` kept the dropped chunks' bytes as the gap before it
    (19,290 bytes of finer levels in a cut of spot), detail the user meant to cut away (outside probe): they are
    zero bytes now, as every gap is, and the cut decodes and shows its image as before."""
    moved = _image_last(textured_pmw)
    gltf, bin_start = _json_and_bin(moved)
    entries = read_header(moved).extensions[0]["chunks"]  # expanded: each chunk's bufferView and byteOffset in it
    for n in (0, 2):
        out = cut(moved, n)
        _same_levels(moved, out, n)
        assert _image_bytes(decode_asset(out)[0]) == _image_bytes(decode_asset(textured_pmw)[0])
        _, out_bin = _json_and_bin(out)
        for c in entries[n:]:
            start = gltf["bufferViews"][c["bufferView"]].get("byteOffset", 0) + c.get("byteOffset", 0)
            stored = moved[bin_start + start : bin_start + start + c["byteLength"]]
            assert stored not in out, (n, c)
            assert out[out_bin + start : out_bin + start + c["byteLength"]] == bytes(c["byteLength"])


@pytest.mark.corpus
def test_every_cut_of_spot_passes_the_khronos_validator(tmp_path):
    src = corpus_path("spot.glb")
    out = tmp_path / "spot.pmw"
    encode_asset(src, out, strip_image_profiles=True, measure=False)
    data = out.read_bytes()
    for n in range(read_header(data).chunk_count + 1):
        path = tmp_path / f"spot{n}.pmw"
        path.write_bytes(cut(data, n))
        result = check(path)
        assert result["validator"]["errors"] == 0 and result["validator"]["warnings"] == 0, (n, result["validator"])
        _same_levels(data, path.read_bytes(), n)


def test_a_prefix_ending_inside_the_texture_decodes_to_a_valid_glb_without_it(tmp_path, textured_pmw, capsys):
    gltf, bin_start = _json_and_bin(textured_pmw)
    image_view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    prefix = textured_pmw[: bin_start + image_view["byteOffset"] + image_view["byteLength"] // 2]
    glb, end, decoder = decode_asset(prefix)
    doc, _ = _json_and_bin(glb)
    assert end.truncated and "images" not in doc and "textures" not in doc
    assert not any("Texture" in key for m in doc.get("materials", []) for key in _keys(m))
    assert decoder.notices == ["image 0 has not arrived yet: the level is written without it"]
    src = tmp_path / "prefix.pmw"
    src.write_bytes(prefix)
    assert main(["decode", str(src), "-o", str(tmp_path / "level.glb"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["notices"] == decoder.notices
    result = check(tmp_path / "level.glb")
    assert result["validator"]["errors"] == 0 and result["validator"]["warnings"] == 0, result["validator"]
    assert result["three"]["ok"]


def _keys(node):
    if isinstance(node, dict):
        for key, value in node.items():
            yield key
            yield from _keys(value)
    elif isinstance(node, list):
        for item in node:
            yield from _keys(item)


def test_pmw_cut_never_leaves_a_key_beside_a_file_it_does_not_verify(tmp_path, capsys):
    """``pmw cut other.pmw -o b.pmw`` replaced ``b.pmw`` while ``b.pmw.key.json`` stayed beside it: the key no longer
    verified the file there (``pmw encode`` refuses that).  A cut of the key's own file still replaces it."""
    mine, my_key, _ = marked_sphere(6)
    other, _, _ = marked_sphere(7)
    unmarked = io.BytesIO()
    from pmwm_codec.stream import encode_mesh

    encode_mesh(shapes.icosphere(3), unmarked)
    src = {"mine": tmp_path / "mine.pmw", "other": tmp_path / "other.pmw", "unmarked": tmp_path / "unmarked.pmw"}
    src["mine"].write_bytes(mine)
    src["other"].write_bytes(other)
    src["unmarked"].write_bytes(unmarked.getvalue())
    out = tmp_path / "b.pmw"
    out.write_bytes(mine)
    my_key.save(str(out) + ".key.json")
    for name, why in (("other", "is marked with another key"), ("unmarked", "carries no watermark")):
        assert main(["cut", str(src[name]), "-o", str(out), "--chunks", "1"]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and f"{out}.key.json: a watermark key lies beside {out}, and the cut file {why}" in err
        assert out.read_bytes() == mine
    assert main(["cut", str(src["mine"]), "-o", str(out), "--chunks", "1", "-q"]) == 0
    assert out.read_bytes() == cut(mine, 1)


def test_a_cut_of_a_file_with_the_owner_layer_alone_is_taken_exactly_when_the_key_beside_reads_it(tmp_path, capsys):
    """Such a file names no key fingerprint: the cut was refused beside its own key ("carries no watermark") though
    ``pmw verify`` of the cut with that key said ``present``.  Now the key beside is read in the cut: taken when its
    owner ID reads ``present``, refused (naming the owner read) when not: another key's file, a prefix too short."""
    import shutil

    from pmwm_codec.meshio import write_mesh

    write_mesh(str(tmp_path / "m.obj"), shapes.demo_mesh())
    src, other, out = tmp_path / "src.pmw", tmp_path / "other.pmw", tmp_path / "b.pmw"
    for path in (src, other):  # the same ID under two keys (each encode makes its own secret)
        assert main(["encode", str(tmp_path / "m.obj"), "-o", str(path), "--owner-id", "abc", "-q"]) == 0
    shutil.copy(src, out)
    shutil.copy(f"{src}.key.json", f"{out}.key.json")
    capsys.readouterr()
    assert main(["cut", str(src), "-o", str(out), "-q"]) == 0 and out.read_bytes() == src.read_bytes()
    seen = set()
    for source, chunks in ((other, None), (src, 0), (src, 1), (src, 3), (src, None)):
        argv = ["cut", str(source), "-o", str(out)] + ([] if chunks is None else ["--chunks", str(chunks)])
        assert main([*argv[:3], str(tmp_path / "probe.pmw"), "-q", *argv[4:]]) == 0  # the same cut, nothing beside
        verified = main(["verify", str(tmp_path / "probe.pmw"), "--key", f"{out}.key.json", "-q"]) == 0
        seen.add(verified)
        capsys.readouterr()
        before = out.read_bytes()
        assert main([*argv, "-q"]) == (0 if verified else 2)
        err = capsys.readouterr().err
        if verified:
            assert out.read_bytes() == (tmp_path / "probe.pmw").read_bytes()
        else:
            assert err.count("\n") == 1 and "does not read as the key's owner ID" in err and out.read_bytes() == before
        (tmp_path / "probe.pmw").unlink()
    assert seen == {True, False}  # both answers were put to the test
