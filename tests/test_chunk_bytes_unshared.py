"""A bufferView that holds chunks holds nothing else (bitstream.md §4): no other bufferView shares its bytes, and no
accessor, image or Draco object reads it.  Both readers accepted such a file, and ``pmw cut`` then zeroed (or cut off)
the bytes of the chunks it dropped under the other bufferView: its output silently held other data there than its
input.  The JavaScript side's cases are in ``js/test/reader-differentials.test.js``.  The sources are conformance
files; ``two-primitives`` shares one chunk table bufferView between its primitives, which stays valid."""

from __future__ import annotations

from pathlib import Path

import pytest

from pmwm_codec.cli import main
from pmwm_codec.errors import FormatError
from pmwm_codec.format.extension import unpack_chunk_table
from pmwm_codec.format.glb import glb_parts, split_glb
from pmwm_codec.stream import StreamDecoder
from pmwm_codec.stream.cut import cut

CONFORMANCE = Path(__file__).resolve().parents[1] / "spec" / "conformance"
EXT = "PMWM_progressive_mesh"
SOURCES = ["sphere-attributes.plain.v1.pmw", "sphere-attributes.plain.v2.pmw", "sphere-attributes.plain.packed.v2.pmw",
           "sphere-pillows.draco.packed.v2.pmw"]
MARKED = "sphere.exact-watermark.packed.v2"  # with its key: pmw verify reads it


def _decode(data: bytes) -> list:
    dec = StreamDecoder()
    levels = dec.feed(data)
    dec.close()
    return levels


def _rewrite(name: str, change) -> bytes:
    gltf, binary = split_glb((CONFORMANCE / name).read_bytes())
    change(gltf)
    return b"".join(glb_parts(gltf, [binary], len(binary)))


def _chunk_view(gltf) -> int:
    """The bufferView of the last chunk of the first progressive primitive."""
    chunks = gltf["meshes"][0]["primitives"][0]["extensions"][EXT]["chunks"]
    return chunks["bufferView"] if isinstance(chunks, dict) else chunks[-1]["bufferView"]


def _new_view_inside_the_chunks(gltf) -> int:
    """Append a 100-byte bufferView over the last 200 to 100 bytes of the chunk bufferView; its index."""
    view = gltf["bufferViews"][_chunk_view(gltf)]
    gltf["bufferViews"].append({"buffer": 0, "byteOffset": view.get("byteOffset", 0) + view["byteLength"] - 200,
                                "byteLength": 100})
    return len(gltf["bufferViews"]) - 1


def _image_inside_the_chunks(gltf) -> None:
    gltf["images"] = [{"bufferView": _new_view_inside_the_chunks(gltf), "mimeType": "image/png"}]


def _image_of_the_chunk_view(gltf) -> None:
    gltf["images"] = [{"bufferView": _chunk_view(gltf), "mimeType": "image/png"}]


def _accessor_of_the_chunk_view(gltf) -> None:
    gltf["accessors"].append({"bufferView": _chunk_view(gltf), "componentType": 5126, "count": 4, "type": "SCALAR"})


def _sparse_values_in_the_chunk_view(gltf) -> None:
    gltf["accessors"].append({"componentType": 5126, "count": 4, "type": "SCALAR", "sparse": {
        "count": 1, "indices": {"bufferView": 0, "componentType": 5123}, "values": {"bufferView": _chunk_view(gltf)}}})


def _table_view_over_the_base(gltf) -> None:
    """The chunk table's bufferView stretched back over the base mesh (Draco's bufferView), its chunks left where
    they are by ``byteOffsets``: the chunk ranges still follow the base, the bufferViews share its bytes."""
    table = gltf["meshes"][0]["primitives"][0]["extensions"][EXT]["chunks"]
    view = gltf["bufferViews"][table["bufferView"]]
    start = view["byteOffset"]
    offsets = [start]
    for length in unpack_chunk_table(table["count"], table["packed"])["byteLength"][:-1]:
        offsets.append(offsets[-1] + length)
    table["byteOffsets"] = offsets
    view["byteOffset"], view["byteLength"] = 0, start + view["byteLength"]


SHARES = r"bufferViews\[\d+\] shares bytes with bufferView \d+, which holds chunks"
CHANGES = {
    "another bufferView": (_new_view_inside_the_chunks, SHARES),
    "an image's bufferView": (_image_inside_the_chunks, SHARES),
    "an image": (_image_of_the_chunk_view, r"images\[0\] reads bufferView \d+, which holds chunks"),
    "an accessor": (_accessor_of_the_chunk_view, r"accessors\[\d+\] reads bufferView \d+, which holds chunks"),
    "sparse values": (_sparse_values_in_the_chunk_view,
                      r"accessors\[\d+\]\.sparse\.values reads bufferView \d+, which holds chunks"),
}


@pytest.mark.parametrize("name", SOURCES)
@pytest.mark.parametrize("change", list(CHANGES))
def test_chunk_bytes_that_other_data_shares_are_a_format_error(name, change):
    edit, message = CHANGES[change]
    data = _rewrite(name, edit)
    with pytest.raises(FormatError, match=message):
        _decode(data)
    with pytest.raises(FormatError, match=message):  # and cut writes nothing that differs from its input
        cut(data, 1)


def test_a_chunk_table_bufferview_over_the_draco_base_is_a_format_error():
    data = _rewrite("sphere-pillows.draco.packed.v2.pmw", _table_view_over_the_base)
    with pytest.raises(FormatError, match=r"bufferViews\[0\] shares bytes with bufferView 1, which holds chunks"):
        _decode(data)


@pytest.mark.parametrize("name", ["two-primitives.draco.packed.v2.pmw", "two-primitives.draco.v2.pmw"])
def test_primitives_that_share_one_chunk_table_bufferview_decode(name):
    data = (CONFORMANCE / name).read_bytes()
    gltf, _ = split_glb(data)
    assert len({p["extensions"][EXT]["chunks"]["bufferView"] for p in gltf["meshes"][0]["primitives"]}) == 1
    assert len(_decode(data)) > 1


@pytest.mark.parametrize("command", ["info", "decode", "verify", "cut"])
def test_every_command_refuses_chunk_bytes_an_image_shares_in_one_line_and_writes_nothing(command, tmp_path, capsys):
    """Before, ``pmw cut --chunks 2`` of this file wrote a .pmw whose image held zero bytes where the input's held
    the bytes of the chunks it dropped."""
    source = tmp_path / "shared.pmw"
    source.write_bytes(_rewrite(f"{MARKED}.pmw", _image_inside_the_chunks))
    out = tmp_path / "out"
    argv = {"info": ["info", str(source)], "decode": ["decode", str(source), "-o", f"{out}.obj"],
            "verify": ["verify", str(source), "--key", str(CONFORMANCE / f"{MARKED}.key.json")],
            "cut": ["cut", str(source), "--chunks", "2", "-o", f"{out}.pmw"]}[command]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "shares bytes with bufferView" in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shared.pmw"]
