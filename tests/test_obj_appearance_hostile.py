"""Hostile OBJ appearance inputs (pmwm_codec.meshdoc): whatever an OBJ, its MTL files and their textures hold,
``encode`` either writes a ``.pmw`` that decodes or raises a PmwError of one line, writing nothing; the files an
OBJ names are read only inside its folder, only when a face uses them, under the resource budget.

Every input is made here; the fuzzed ones in temporary folders of their own (hypothesis runs each example
many times over, so no fixture folder is shared between examples).
"""

from __future__ import annotations

import io
import os
import struct
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from PIL import Image

import pmwm_codec
from pmwm_codec import meshdoc
from pmwm_codec.cli import main

#: A textured quad's records: four positions, four texture coordinates, one normal.
QUAD = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nvn 0 0 1\n"
TEXTURED = "mtllib t.mtl\n" + QUAD + "usemtl skin\nf 1/1 2/2 3/3 4/4\n"


def png_bytes(size=8, colour=(200, 40, 10)) -> bytes:
    out = io.BytesIO()
    Image.new("RGB", (size, size), colour).save(out, "PNG")
    return out.getvalue()


def encode_or_refuse(path, out) -> dict | None:
    """The report of ``encode(path, out)`` after checking that ``out`` decodes, or None after checking the
    refusal: a PmwError of one line, and no ``out`` left behind.  Any other exception fails the test."""
    try:
        report = pmwm_codec.encode(str(path), str(out))
    except pmwm_codec.PmwError as exc:
        message = str(exc)
        assert message and len(message.splitlines()) == 1 and message.isprintable(), repr(message)
        assert not os.path.exists(out) and not os.path.exists(str(out) + ".key.json")
        return None
    assert pmwm_codec.decode_asset(str(out))[:4] == b"glTF"
    return report


def write(folder, files: dict) -> None:
    for name, data in files.items():
        with open(os.path.join(folder, name), "wb") as fh:
            fh.write(data if isinstance(data, bytes) else data.encode())


# -- fuzzed OBJ and MTL text ----------------------------------------------------------------------------------

numbers = st.one_of(
    st.sampled_from(["0", "1", "-1", "0.5", "1e3", "nan", "inf", "-inf", "NaN", "1e39", "-1e308", "1e-320",
                     "0x10", "1_0", "", ".", "-", "+1", "\u0661"]),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
)
indices = st.one_of(st.integers(-6, 9).map(str),
                    st.sampled_from(["0", "99999999999999999999", "-99999999999999999999", "9223372036854775808",
                                     "", "x", "1.0", "\u0661"]))
corners = st.one_of(
    st.tuples(indices, indices, indices).map(lambda t: "/".join(t)),
    st.tuples(indices, indices).map(lambda t: "/".join(t)),
    indices,
    st.sampled_from(["1//", "/1", "1/2/3/4", "//", "/", "1/1/", "1//1"]),
)
separators = st.sampled_from([" ", "\t", "  ", " \t"])


def record(keyword, values):
    return st.tuples(separators, st.lists(values, min_size=0, max_size=8)).map(
        lambda t: keyword + t[0] + t[0].join(t[1]))


good_index = st.sampled_from(["1", "2", "3", "4", "-1", "-2", "-3", "+2"])
good_corner = st.one_of(good_index, st.tuples(good_index, good_index).map("/".join),
                        good_index.map(lambda i: i + "//1"), st.tuples(good_index, good_index).map(lambda t: "/".join(
                            (*t, "1"))))
hostile_records = st.one_of(record("v", numbers), record("vt", numbers), record("vn", numbers), record("f", corners))
good_records = st.one_of(
    st.tuples(separators, st.lists(good_corner, min_size=3, max_size=5)).map(lambda t: "f" + t[0] + t[0].join(t[1])),
    st.sampled_from(["v 0 0 0", "v 1 0 0", "v 0 1 0", "v 1 1 0 1 0 0", "vt 0 0", "vt 1 1", "vn 0 0 1",
                     "f 1/1 2/2 3/3", "f 1 2 3", "f -1/-1 -2/-2 -3/-3", "f 1//1 2//1 3//1", "f", "usemtl",
                     "usemtl skin", "usemtl other", "usemtl nope", "usemtl sk\u00efn", "mtllib t.mtl",
                     "mtllib gone.mtl t.mtl", "mtllib", "mtllib t.mtl t.mtl", "# a comment", "o thing", "g group",
                     "s off", "", "   "]),
)
#: Mostly records that read (so that many examples get to the encoder), one in eight anything at all.
obj_records = st.integers(0, 7).flatmap(lambda i: hostile_records if i == 0 else good_records)
line_ends = st.sampled_from(["\n", "\r\n", "\r"])
encodings = st.sampled_from(["utf-8", "utf-8-sig", "latin-1", "utf-16"])


def obj_bytes(records, line_end, encoding) -> bytes:
    text = line_end.join(records) + line_end
    return text.encode(encoding, errors="replace")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(records=st.lists(obj_records, min_size=1, max_size=24), base=st.booleans(), line_end=line_ends,
       encoding=encodings)
def test_fuzzed_obj_text_either_encodes_to_a_pmw_that_decodes_or_is_refused_in_one_line(records, base, line_end,
                                                                                       encoding):
    if base:
        records = QUAD.splitlines() + records
    with tempfile.TemporaryDirectory() as folder:
        write(folder, {"t.obj": obj_bytes(records, line_end, encoding),
                       "t.mtl": "newmtl skin\nKd 1 0 0\nmap_Kd skin.png\nnewmtl other\nKd 0 1 0\n",
                       "skin.png": png_bytes()})
        encode_or_refuse(os.path.join(folder, "t.obj"), os.path.join(folder, "t.pmw"))


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(records=st.lists(obj_records, min_size=1, max_size=16), quad_first=st.booleans(), line_end=line_ends)
def test_fuzzed_records_after_a_valid_textured_quad_encode_or_are_refused_in_one_line(records, quad_first, line_end):
    body = [TEXTURED.strip()] + records if quad_first else records + [TEXTURED.strip()]
    with tempfile.TemporaryDirectory() as folder:
        write(folder, {"t.obj": line_end.join(body) + line_end, "t.mtl": "newmtl skin\nmap_Kd skin.png\n",
                       "skin.png": png_bytes()})
        encode_or_refuse(os.path.join(folder, "t.obj"), os.path.join(folder, "t.pmw"))


map_options = st.sampled_from(["-s", "-o", "-t", "-bm", "-clamp", "-blendu", "-mm", "-imfchan", "-type", "-cc",
                               "-texres", "-boost"])
map_words = st.lists(st.one_of(map_options, st.sampled_from(["1", "0.5", "on", "off", "skin.png", "gone.png",
                                                             "../x.png", "/etc/hostname", "sk in.png", "\\x.png"])),
                     max_size=6)
names = st.one_of(st.sampled_from(["skin", "", "sk\u00efn", "\u6750\u8cea", "\U0001f600", "a b", "skin skin"]),
                  st.text(alphabet=st.characters(blacklist_categories=("Cs",), blacklist_characters="\n\r\0#"),
                          max_size=8))
mtl_statements = st.one_of(
    names.map(lambda n: f"newmtl {n}".rstrip()),
    st.tuples(st.sampled_from(["map_Kd", "map_Bump", "bump", "norm", "map_Ka", "map_d"]), map_words).map(
        lambda t: " ".join([t[0], *t[1]])),
    st.tuples(st.sampled_from(["Kd", "Ka", "d", "Tr", "Ns", "illum", "Ni"]), st.lists(numbers, max_size=4)).map(
        lambda t: " ".join([t[0], *t[1]])),
    st.sampled_from(["newmtl", "newmtl skin", "newmtl skin", "Kd", "map_Kd", "# map_Kd ../x.png", ""]),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(statements=st.lists(mtl_statements, max_size=12), used=names, line_end=line_ends, encoding=encodings)
def test_fuzzed_mtl_text_either_encodes_to_a_pmw_that_decodes_or_is_refused_in_one_line(statements, used, line_end,
                                                                                       encoding):
    obj = "mtllib t.mtl\n" + QUAD + f"usemtl {used}\nf 1/1 2/2 3/3 4/4\n"
    with tempfile.TemporaryDirectory() as folder:
        write(folder, {"t.obj": obj.encode("utf-8"), "skin.png": png_bytes(),
                       "t.mtl": (line_end.join(statements) + line_end).encode(encoding, errors="replace")})
        encode_or_refuse(os.path.join(folder, "t.obj"), os.path.join(folder, "t.pmw"))


# -- numbers no float32 carries -------------------------------------------------------------------------------


@pytest.mark.parametrize("vt", ["vt nan 0", "vt inf 0", "vt 0 -inf", "vt 1e308 0", "vt 0 1e39"])
def test_a_texture_coordinate_that_is_not_finite_is_refused_naming_the_vt_record(tmp_path, vt):
    (tmp_path / "t.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\n" + vt + "\nf 1/1 2/2 3/1\n")
    assert refused(tmp_path / "t.obj", "t.obj: vt record 2 ", vt).startswith("t.obj: vt record 2 ")


@pytest.mark.parametrize("v", ["v nan 0 0", "v inf 0 0", "v 0 1e39 0", "v 0 0 -1e308"])
def test_a_position_that_is_not_finite_is_refused_naming_the_v_record_not_an_accessor(tmp_path, v):
    (tmp_path / "t.obj").write_text(v + "\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 3/1\n")
    assert refused(tmp_path / "t.obj", v).startswith("t.obj: v record 1 ")


def test_a_gltf_texture_coordinate_that_is_not_finite_is_refused_not_a_traceback(tmp_path):
    uv = np.array([[0, 0], [1, 0], [0, np.inf]], np.float32)
    part = meshdoc.Part(np.eye(3, dtype=np.float32), np.array([[0, 1, 2]]), {"TEXCOORD_0": uv})
    doc = meshdoc.build_document([part], [], [], "x")
    with pytest.raises(pmwm_codec.PmwError, match="TEXCOORD_0"):
        pmwm_codec.encode(doc, str(tmp_path / "t.pmw"))
    assert not (tmp_path / "t.pmw").exists()


# -- line ends ------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("line_end", ["\r", "\r\n", "\x0c\n", "\u2028"])
def test_an_obj_of_any_line_end_read_mesh_takes_is_encoded_plain_or_textured(tmp_path, line_end):
    plain = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n".replace("\n", line_end)
    (tmp_path / "plain.obj").write_text(plain, newline="")
    assert pmwm_codec.encode(str(tmp_path / "plain.obj"), str(tmp_path / "plain.pmw"))["vertices"] == 3
    write(tmp_path, {"t.obj": TEXTURED.replace("\n", line_end), "t.mtl": "newmtl skin\nmap_Kd skin.png\n".replace(
        "\n", line_end), "skin.png": png_bytes()})
    pmwm_codec.encode(str(tmp_path / "t.obj"), str(tmp_path / "t.pmw"))
    gltf = _decoded_json(tmp_path / "t.pmw")
    assert "TEXCOORD_0" in gltf["meshes"][0]["primitives"][0]["attributes"]
    assert len(gltf["images"]) == 1 and gltf["materials"][0]["name"] == "skin"


def _decoded_json_of(obj, pmw) -> dict:
    pmwm_codec.encode(str(obj), str(pmw))
    return _decoded_json(pmw)


def _decoded_json(pmw) -> dict:
    import json

    glb = pmwm_codec.decode_asset(str(pmw))
    length = struct.unpack_from("<I", glb, 12)[0]
    return json.loads(glb[20:20 + length])


def test_a_latin1_material_name_with_byte_0x85_names_the_same_material_in_the_obj_and_the_mtl(tmp_path):
    write(tmp_path, {"t.obj": TEXTURED.replace("usemtl skin", "usemtl skin\x85").encode("latin-1"),
                     "t.mtl": "newmtl skin\x85\nKd 1 0 0\n".encode("latin-1")})
    pmwm_codec.encode(str(tmp_path / "t.obj"), str(tmp_path / "t.pmw"))
    gltf = _decoded_json(tmp_path / "t.pmw")
    material = gltf["materials"][gltf["meshes"][0]["primitives"][0]["material"]]
    assert material["pbrMetallicRoughness"]["baseColorFactor"][:3] == [1.0, 0.0, 0.0]


# -- the files an OBJ names -----------------------------------------------------------------------------------


def textured(folder, texture="skin.png", files=None, obj=TEXTURED) -> Path:
    folder = Path(folder)
    write(folder, {"t.obj": obj, "t.mtl": f"newmtl skin\nmap_Kd {texture}\n", **(files or {})})
    return folder / "t.obj"


def refused(path, *words) -> str:
    out = str(path) + ".pmw"
    with pytest.raises(pmwm_codec.PmwError) as caught:
        pmwm_codec.encode(str(path), out)
    message = str(caught.value)
    assert len(message.splitlines()) == 1 and all(w in message for w in words), message
    assert not os.path.exists(out) and not os.path.exists(out + ".key.json")
    return message


def left_out(path, *words) -> str:
    """Encode the OBJ at ``path``: it encodes, one notice names the file it did not read and why (``words``),
    and the output holds no image (what was left out was never read, so never embedded)."""
    out = str(path) + ".pmw"
    report = pmwm_codec.encode(str(path), out)
    named = [n for n in report["notices"] if all(w in n for w in words)]
    assert len(named) == 1 and named[0].endswith("left out") and "\n" not in named[0], report["notices"]
    assert "images" not in _decoded_json(out)
    return named[0]


def test_a_texture_that_is_a_fifo_is_left_out_without_blocking(tmp_path):
    os.mkfifo(tmp_path / "skin.png")
    left_out(textured(tmp_path), "'skin.png'", "not a regular file")


def test_a_texture_that_is_a_directory_is_left_out(tmp_path):
    (tmp_path / "skin.png").mkdir()
    left_out(textured(tmp_path), "'skin.png'", "not a regular file")


def test_a_texture_symlinked_to_dev_zero_is_left_out_unread(tmp_path):
    os.symlink("/dev/zero", tmp_path / "skin.png")
    left_out(textured(tmp_path), "'skin.png'", "outside the asset's folder")


def test_an_mtl_symlinked_to_dev_zero_is_left_out_unread(tmp_path):
    path = textured(tmp_path)
    os.remove(tmp_path / "t.mtl")
    os.symlink("/dev/zero", tmp_path / "t.mtl")
    left_out(path, "'t.mtl'", "outside the asset's folder")


def test_a_symlink_chain_leading_out_of_the_folder_is_left_out_unread(tmp_path):
    folder = tmp_path / "asset"
    folder.mkdir()
    (tmp_path / "secret.png").write_bytes(png_bytes())
    os.symlink(tmp_path / "secret.png", folder / "b.png")
    os.symlink("b.png", folder / "a.png")
    left_out(textured(folder, "a.png"), "'a.png'", "outside the asset's folder")


def test_a_symlink_chain_inside_the_folder_reads_the_file_once(tmp_path):
    (tmp_path / "real.png").write_bytes(png_bytes())
    os.symlink("real.png", tmp_path / "b.png")
    os.symlink("b.png", tmp_path / "skin.png")
    obj = TEXTURED + "usemtl other\nf 1/1 3/3 4/4\n"
    path = textured(tmp_path, obj=obj)
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\nnewmtl other\nmap_Kd real.png\n")
    pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert len(_decoded_json(tmp_path / "t.pmw")["images"]) == 1


def test_a_texture_over_the_resource_budget_is_left_out(tmp_path, monkeypatch):
    blob = png_bytes(64)
    monkeypatch.setattr(meshdoc, "MAX_RESOURCE_BYTES", len(blob) - 1)
    left_out(textured(tmp_path, files={"skin.png": blob}), "'skin.png'", "limit")


def test_the_budget_is_shared_by_the_mtl_and_every_texture(tmp_path, monkeypatch):
    obj = TEXTURED + "usemtl other\nf 1/1 3/3 4/4\n"
    mtl = "newmtl skin\nmap_Kd a.png\nnewmtl other\nmap_Kd b.png\n"
    a, b = png_bytes(16), png_bytes(16, (1, 2, 3))
    monkeypatch.setattr(meshdoc, "MAX_RESOURCE_BYTES", len(mtl) + len(a) + len(b) - 1)
    path = textured(tmp_path, obj=obj, files={"a.png": a, "b.png": b})
    (tmp_path / "t.mtl").write_text(mtl)
    report = pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert any("'b.png' not read" in n and n.endswith("left out") for n in report["notices"]), report["notices"]
    assert len(_decoded_json(tmp_path / "t.pmw")["images"]) == 1  # a.png, read within the budget
    monkeypatch.setattr(meshdoc, "MAX_RESOURCE_BYTES", len(mtl) + len(a) + len(b))
    assert len(_decoded_json_of(path, tmp_path / "t2.pmw")["images"]) == 2


def bmp_header(width, height) -> bytes:
    """A 24-bit BMP header declaring ``width`` x ``height`` pixels, with next to no pixel data after it."""
    row = (width * 3 + 3) & ~3
    return (b"BM" + struct.pack("<IHHI", 54 + row * height, 0, 0, 54)
            + struct.pack("<IiiHHIIiiII", 40, width, height, 1, 24, 0, row * height, 2835, 2835, 0, 0) + bytes(64))


@pytest.mark.parametrize("side", [10_000, 20_000])
def test_a_decompression_bomb_texture_is_left_out_with_a_notice_and_never_decoded(tmp_path, side):
    path = textured(tmp_path, "skin.bmp", files={"skin.bmp": bmp_header(side, side)})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a DecompressionBombWarning too
        report = pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert any("'skin.bmp'" in n and "left out" in n for n in report["notices"]), report["notices"]
    assert "images" not in _decoded_json(tmp_path / "t.pmw")


def test_a_texture_over_pillows_pixel_limit_is_left_out(tmp_path, monkeypatch):
    out = io.BytesIO()
    Image.new("RGB", (64, 64)).save(out, "BMP")
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)
    path = textured(tmp_path, "skin.bmp", files={"skin.bmp": out.getvalue()})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a DecompressionBombWarning too
        report = pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert any("'skin.bmp'" in n and "left out" in n for n in report["notices"]), report["notices"]


def test_a_truncated_png_is_left_out_with_a_notice_not_embedded(tmp_path):
    blob = png_bytes(64)
    path = textured(tmp_path, files={"skin.png": blob[: len(blob) // 2]})
    report = pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert any("'skin.png'" in n and "left out" in n for n in report["notices"]), report["notices"]
    assert "images" not in _decoded_json(tmp_path / "t.pmw")


def test_a_png_signature_followed_by_junk_is_left_out_with_a_notice(tmp_path):
    path = textured(tmp_path, files={"skin.png": b"\x89PNG\r\n\x1a\n" + b"junk" * 10})
    report = pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert any("'skin.png'" in n and "left out" in n for n in report["notices"]), report["notices"]


def test_a_percent_encoded_texture_name_is_read_literally_never_decoded(tmp_path):
    folder = tmp_path / "asset"
    (folder / "%2e%2e").mkdir(parents=True)
    (tmp_path / "skin.png").write_bytes(png_bytes(colour=(1, 1, 1)))  # what %2e%2e/ would name, decoded
    inside = png_bytes(colour=(9, 9, 9))
    (folder / "%2e%2e" / "skin.png").write_bytes(inside)
    path = textured(folder, "%2e%2e/skin.png")
    pmwm_codec.encode(str(path), str(folder / "t.pmw"))
    glb = pmwm_codec.decode_asset(str(folder / "t.pmw"))
    assert inside in glb
    os.remove(folder / "%2e%2e" / "skin.png")
    report = pmwm_codec.encode(str(path), str(folder / "u.pmw"))
    assert any("'%2e%2e/skin.png' is not beside t.obj" in n for n in report["notices"]), report["notices"]


@pytest.mark.parametrize("texture", ["..\\outside.png", "sub\\..\\..\\outside.png", "\\outside.png"])
def test_a_windows_path_out_of_the_folder_is_left_out_unread(tmp_path, texture):
    folder = tmp_path / "asset"
    (folder / "sub").mkdir(parents=True)
    (tmp_path / "outside.png").write_bytes(png_bytes())
    message = left_out(textured(folder, texture), "outside.png", "not read")
    assert "outside the asset's folder" in message or "absolute path" in message


def test_an_mtllib_of_several_names_reads_those_there_and_names_those_missing(tmp_path):
    obj = TEXTURED.replace("mtllib t.mtl", "mtllib gone.mtl t.mtl also-gone.mtl")
    report = pmwm_codec.encode(str(textured(tmp_path, obj=obj, files={"skin.png": png_bytes()})),
                               str(tmp_path / "t.pmw"))
    assert any("'gone.mtl' is not beside" in n for n in report["notices"])
    assert any("'also-gone.mtl' is not beside" in n for n in report["notices"])
    assert len(_decoded_json(tmp_path / "t.pmw")["images"]) == 1


def test_one_texture_named_two_ways_is_embedded_once(tmp_path):
    (tmp_path / "sub").mkdir()
    blob = png_bytes(32)
    obj = TEXTURED + "usemtl other\nf 1/1 3/3 4/4\n"
    path = textured(tmp_path, obj=obj, files={"skin.png": blob})
    (tmp_path / "t.mtl").write_text("newmtl skin\nmap_Kd skin.png\nnewmtl other\nmap_Kd sub/../skin.png\n"
                                    "map_Bump ./skin.png\n")
    pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    gltf = _decoded_json(tmp_path / "t.pmw")
    assert len(gltf["images"]) == 1 and len(gltf["materials"]) == 2
    assert pmwm_codec.decode_asset(str(tmp_path / "t.pmw")).count(blob) == 1


# -- materials no face uses -----------------------------------------------------------------------------------


@pytest.mark.parametrize("texture", ["gone.png", "../outside.png", "/etc/hostname", "fifo.png", "zero.png"])
def test_the_texture_of_a_material_no_face_uses_is_never_read(tmp_path, texture):
    os.mkfifo(tmp_path / "fifo.png")
    os.symlink("/dev/zero", tmp_path / "zero.png")
    path = textured(tmp_path, files={"skin.png": png_bytes()})
    (tmp_path / "t.mtl").write_text(f"newmtl unused\nmap_Kd {texture}\nmap_Bump {texture}\n"
                                    "newmtl skin\nmap_Kd skin.png\n")
    report = pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    assert not any(texture in n for n in report["notices"]), report["notices"]
    gltf = _decoded_json(tmp_path / "t.pmw")
    assert [m["name"] for m in gltf["materials"]] == ["skin"] and len(gltf["images"]) == 1


def test_a_material_defined_twice_keeps_its_first_definition_and_never_reads_the_second_texture(tmp_path):
    path = textured(tmp_path, files={"skin.png": png_bytes()})
    (tmp_path / "t.mtl").write_text("newmtl skin\nKd 1 0 0\nnewmtl skin\nKd 0 1 0\nmap_Kd ../outside.png\n")
    pmwm_codec.encode(str(path), str(tmp_path / "t.pmw"))
    gltf = _decoded_json(tmp_path / "t.pmw")
    assert gltf["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"][:3] == [1.0, 0.0, 0.0]


# -- the command ----------------------------------------------------------------------------------------------


def mark_png(path) -> str:
    y, x = np.mgrid[:32, :32]
    Image.fromarray((128 + 90 * np.sin(x / 3.0) * np.cos(y / 5.0)).astype(np.uint8)).save(path)
    return str(path)


BAD_OBJS = {
    "face": ("map_Kd skin.png", TEXTURED.replace("f 1/1 2/2 3/3 4/4", "f 1/1 2/2 9/3")),
    "corner": ("map_Kd skin.png", TEXTURED.replace("f 1/1 2/2 3/3 4/4", "f 1/1 2/2 /3")),
    "vt": ("map_Kd skin.png", TEXTURED.replace("vt 1 1", "vt nan 1")),
}


@pytest.mark.parametrize("watermark", [False, True])
@pytest.mark.parametrize("case", sorted(BAD_OBJS))
def test_pmw_encode_of_a_bad_obj_exits_2_with_one_line_and_leaves_no_pmw_and_no_key(tmp_path, capsys, case, watermark):
    statement, obj = BAD_OBJS[case]
    folder = tmp_path / "asset"
    folder.mkdir()
    (tmp_path / "outside.png").write_bytes(png_bytes())
    os.mkfifo(folder / "fifo.png")
    write(folder, {"bad.obj": obj, "t.mtl": f"newmtl skin\n{statement}\n", "skin.png": png_bytes()})
    out = folder / "out.pmw"
    argv = ["encode", str(folder / "bad.obj"), "-o", str(out)]
    if watermark:
        argv += ["--watermark", mark_png(tmp_path / "mark.png")]
    before = sorted(os.listdir(folder))
    status = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2, err
    assert len(err) == 1 and err[0].startswith("pmw: error: bad.obj") and "Traceback" not in err[0], err
    assert sorted(os.listdir(folder)) == before  # no out.pmw, no out.pmw.key.json, nothing half-written


def test_pmw_encode_of_a_bad_obj_in_a_fresh_process_prints_one_line(tmp_path):
    write(tmp_path, {"bad.obj": TEXTURED.replace("vt 1 1", "vt inf 1"), "t.mtl": "newmtl skin\n"})
    run = subprocess.run([sys.executable, "-m", "pmwm_codec", "encode", str(tmp_path / "bad.obj"), "-o",
                          str(tmp_path / "out.pmw"), "--watermark", mark_png(tmp_path / "mark.png")],
                         capture_output=True, text=True, cwd=Path(__file__).resolve().parents[1])
    assert run.returncode == 2, run.stderr
    assert len(run.stderr.strip().splitlines()) == 1 and "Traceback" not in run.stderr, run.stderr
    assert sorted(os.listdir(tmp_path)) == ["bad.obj", "mark.png", "t.mtl"]
