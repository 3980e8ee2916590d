"""The Python API refuses what the command line refuses, with a PmwError naming the problem, before any
work and without writing anything (an outside-in probe of the API found each case below raising a bare
KeyError / TypeError, hanging, or writing a file that could never be verified)."""

from __future__ import annotations

import io
import json
import math
import os

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.errors import InputFormatError, OptionError, PmwError, WatermarkKeyError
from samples import closed_file

MESH = shapes.demo_mesh(60)


def _image(seed):
    return np.random.default_rng(seed).integers(0, 256, (8, 8)).astype(np.uint8)


@pytest.fixture(scope="module")
def stream():
    buf = io.BytesIO()
    pmwm_codec.encode(MESH, buf, measure="none")
    return buf.getvalue()


@pytest.mark.parametrize("options", [
    {"mode": "x"}, {"mode": None}, {"grid_bits": 7}, {"grid_bits": 31}, {"grid_bits": 16.0}, {"grid_bits": "16"},
    {"embed_from": 1.0}, {"embed_from": -1}, {"embed_from": math.nan}, {"bits": 0}, {"bits": 17},
    {"bits": 1, "mode": "paper"}, {"bits": 3.5}, {"payload_version": 3}, {"payload_version": "2"},
    {"measure": "x"}, {"zstd_level": 23}, {"zstd_level": 3.5}, {"owner_id": "abc!"}, {"owner_id": -1},
    {"owner_id": 1 << 64}, {"owner_id": 1.5}, {"owner_id": True}, {"base_vertices": -5}, {"base_vertices": "10"},
    {"gridbits": 12},
])
def test_a_bad_option_is_an_option_error_naming_it_and_writes_nothing(tmp_path, options):
    out = tmp_path / "m.pmw"
    with pytest.raises(OptionError) as info:
        pmwm_codec.encode(MESH, out, **options)
    assert next(iter(options)) in str(info.value)
    assert list(tmp_path.iterdir()) == []


def test_owner_id_takes_hex_digits_as_the_command_line_does(tmp_path):
    report = pmwm_codec.encode(MESH, tmp_path / "m.pmw", owner_id="ff", measure="none")
    assert report["owner_id"] == "00000000000000ff"


@pytest.mark.parametrize("dst, words", [("-", "standard output"), ("x.obj", "a .pmw is a GLB file"),
                                        ("x.gltf", "a .pmw is a GLB file"), (None, "dst must be")])
def test_an_output_the_command_line_refuses_is_refused(tmp_path, monkeypatch, dst, words):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OptionError, match=words):
        pmwm_codec.encode(MESH, dst)
    assert list(tmp_path.iterdir()) == []


def test_encode_never_replaces_its_input(tmp_path):
    src = tmp_path / "m.glb"
    pmwm_codec.write_mesh(src, MESH)
    before = src.read_bytes()
    with pytest.raises(OptionError, match="is also the input"):
        pmwm_codec.encode(str(src), str(tmp_path / "." / "m.glb"))
    assert src.read_bytes() == before


def test_a_key_object_for_another_image_or_owner_is_refused(tmp_path):
    pmwm_codec.encode(MESH, tmp_path / "a.pmw", watermark=_image(0), measure="none")
    key = pmwm_codec.load_key(tmp_path / "a.pmw.key.json")
    with pytest.raises(WatermarkKeyError, match="another watermark"):
        pmwm_codec.encode(MESH, tmp_path / "b.pmw", watermark=_image(1), key=key)
    with pytest.raises(WatermarkKeyError, match="owner id"):
        pmwm_codec.encode(MESH, tmp_path / "b.pmw", watermark=_image(0), key=key, owner_id=7)
    assert not (tmp_path / "b.pmw").exists()
    pmwm_codec.encode(MESH, tmp_path / "b.pmw", watermark=_image(0), key=key, measure="none")  # its own image
    assert pmwm_codec.verify_stream(tmp_path / "b.pmw", key).verdict == "authentic"
    with pytest.raises(OptionError, match="key must be"):
        pmwm_codec.encode(MESH, tmp_path / "c.pmw", watermark=_image(0), key=True)


def test_a_mark_written_to_a_file_object_needs_a_key_it_would_otherwise_lose():
    with pytest.raises(OptionError, match="needs key="):
        pmwm_codec.encode(MESH, io.BytesIO(), watermark=_image(0))
    with pytest.raises(OptionError, match="needs key="):
        pmwm_codec.encode(MESH, io.BytesIO(), owner_id=5)


def test_pmw_paths_that_name_no_regular_file_are_input_errors_never_hangs(tmp_path):
    os.mkfifo(tmp_path / "fifo")
    (tmp_path / "dir").mkdir()
    for name, words in (("fifo", "not a regular file"), ("missing.pmw", "no such file"), ("dir", "is a directory")):
        for read in (pmwm_codec.decode, pmwm_codec.cut, pmwm_codec.decode_asset, pmwm_codec.inspect,
                     lambda src: list(pmwm_codec.iter_decode(src))):
            with pytest.raises(InputFormatError, match=words):
                read(str(tmp_path / name))


def test_a_files_content_given_as_its_path_is_never_echoed(tmp_path):
    """A key's JSON passed to load_key put its secret into the message (and into logs)."""
    pmwm_codec.encode(MESH, tmp_path / "a.pmw", watermark=_image(0), measure="none")
    text = (tmp_path / "a.pmw.key.json").read_text()
    with pytest.raises(WatermarkKeyError) as info:
        pmwm_codec.load_key(text)
    assert "secret" not in str(info.value) and len(str(info.value)) < 200
    with pytest.raises(PmwError) as info:
        pmwm_codec.encode("v 0 0 0\n" * 100, tmp_path / "x.pmw")
    assert len(str(info.value)) < 200


@pytest.mark.parametrize("chunks", [-1, math.nan, 2.5, "3", True])
def test_chunks_is_none_or_a_non_negative_int_everywhere(stream, chunks):
    for read in (pmwm_codec.decode, pmwm_codec.cut, pmwm_codec.decode_asset):
        with pytest.raises(OptionError, match="chunks"):
            read(stream, chunks)


def test_meshes_compare_by_their_arrays(stream):
    whole, again, level = pmwm_codec.decode(stream), pmwm_codec.decode(stream), pmwm_codec.decode(stream, chunks=2)
    assert whole == again and whole != level and (whole == 1) is False


def test_an_in_memory_document_brings_its_images_not_references_to_files(tmp_path):
    """A file on disk naming ``/etc/hostname`` is refused; the same document in memory was encoded with
    the reference carried into the .pmw."""
    from pmwm_codec.format.document import load_document

    src = tmp_path / "m.glb"
    pmwm_codec.write_mesh(src, MESH)
    gltf, buffers = load_document(src)
    for uri in ("/etc/hostname", "../x.png", "http://127.0.0.1:9/x.png", "x.png"):
        doc = {**gltf, "images": [{"uri": uri}]}
        with pytest.raises(InputFormatError, match="names a file"):
            pmwm_codec.encode((doc, buffers), tmp_path / "o.pmw")
    assert not (tmp_path / "o.pmw").exists()


@pytest.mark.parametrize("damage", ["node cycle", "meshes not an array", "bufferView out of range"])
def test_an_in_memory_document_gets_the_checks_a_file_gets(tmp_path, damage):
    """``encode((gltf, buffers))`` skipped the document checks a file passes through: a node that is its own
    child was encoded into an invalid .pmw, and ``"meshes": "no"`` raised AttributeError (a traceback)."""
    from pmwm_codec.format.document import load_document

    src = tmp_path / "m.glb"
    pmwm_codec.write_mesh(src, MESH)
    gltf, buffers = load_document(src)
    doc = json.loads(json.dumps(gltf))
    if damage == "node cycle":
        doc["nodes"][0]["children"] = [0]
    elif damage == "meshes not an array":
        doc["meshes"] = "no"
    else:
        doc["accessors"][0]["bufferView"] = len(doc["bufferViews"])
    (tmp_path / "bad.gltf").write_text(json.dumps(doc))
    with pytest.raises(InputFormatError) as on_disk:
        load_document(tmp_path / "bad.gltf")
    with pytest.raises(InputFormatError) as in_memory:
        pmwm_codec.encode((doc, buffers), tmp_path / "o.pmw")
    assert str(in_memory.value).split(": ", 1)[1] == str(on_disk.value).split(": ", 1)[1]
    assert not (tmp_path / "o.pmw").exists()


def test_verify_mesh_names_an_empty_mesh(tmp_path):
    from pmwm_codec.errors import MeshError
    from pmwm_codec.verify.mesh import verify_mesh

    pmwm_codec.encode(MESH, tmp_path / "a.pmw", watermark=_image(0), measure="none")
    empty = pmwm_codec.Mesh(np.zeros((0, 3)), np.zeros((0, 3), np.int64))
    with pytest.raises(MeshError, match="no vertices"):
        verify_mesh(empty, tmp_path / "a.pmw", tmp_path / "a.pmw.key.json")


@pytest.mark.parametrize("positions, faces, words", [
    (np.zeros((3, 2)), [[0, 1, 2]], "positions must be (n, 3)"),
    (np.zeros((1, 3, 3)), [[0, 1, 2]], "positions must be (n, 3)"),
    (np.eye(3), np.array([["0", "1", "2"]]), "not numbers"),
])
def test_a_mesh_of_the_wrong_shape_or_kind_is_named_so(positions, faces, words):
    from pmwm_codec.errors import MeshError
    from pmwm_codec.mesh import checked_mesh

    with pytest.raises(MeshError) as info:
        checked_mesh(positions, faces)
    assert words in str(info.value)


@pytest.mark.parametrize("key", [5, 1.5, ["k.json"]])
def test_a_key_that_is_neither_a_key_nor_a_path_is_named_by_every_reader(stream, key):
    """``verify_stream(src, 5)`` raised a bare TypeError from ``os.fspath``."""
    for read in (lambda: pmwm_codec.verify_stream(stream, key), lambda: list(pmwm_codec.iter_decode(stream, key=key)),
                 lambda: pmwm_codec.load_key(key)):
        with pytest.raises(WatermarkKeyError, match="a key must be a WatermarkKey, a key file path or None, got"):
            read()


PUBLIC_FUNCTIONS = ("encode", "decode", "iter_decode", "decode_asset", "cut", "load_key", "read_mesh", "write_mesh",
                    "inspect", "verify_stream")


@pytest.mark.parametrize("name", PUBLIC_FUNCTIONS)
def test_every_public_function_is_annotated_for_type_checkers(name):
    """The package says it is typed (``py.typed``): a type checker then trusts these signatures, so every
    parameter and the return value carry a type."""
    import inspect as pyinspect

    signature = pyinspect.signature(getattr(pmwm_codec, name))
    bare = [p.name for p in signature.parameters.values() if p.annotation is pyinspect.Parameter.empty]
    assert not bare, f"{name}: parameters without a type: {bare}"
    assert signature.return_annotation is not pyinspect.Signature.empty, f"{name}: no return type"


def test_the_typed_marker_ships_with_the_package():
    """``py.typed`` sits in the package and the build takes it into the wheel (package data)."""
    import importlib.resources
    import tomllib
    from pathlib import Path

    assert importlib.resources.files("pmwm_codec").joinpath("py.typed").is_file()
    pyproject = tomllib.loads((Path(pmwm_codec.__file__).parent.parent / "pyproject.toml").read_text())
    assert "py.typed" in pyproject["tool"]["setuptools"]["package-data"]["pmwm_codec"]


@pytest.fixture(scope="module")
def marked_16(tmp_path_factory):
    """A .pmw marked with a 16x16 image, and its key file."""
    d = tmp_path_factory.mktemp("marked16")
    image = np.random.default_rng(3).integers(0, 256, (16, 16)).astype(np.uint8)
    pmwm_codec.encode(shapes.icosphere(4, noise=0.01), d / "m.pmw", watermark=image, measure="none")
    return d / "m.pmw", d / "m.pmw.key.json", image


@pytest.mark.parametrize("size", [8, 32])
def test_a_reference_watermark_of_another_size_than_the_keys_is_refused_before_any_result(tmp_path, marked_16, size):
    """It gave nc and psnr_db None at every step, silently."""
    from pmwm_codec.verify import verify_stream

    pmw, key, image = marked_16
    other = np.random.default_rng(4).integers(0, 256, (size, size)).astype(np.uint8)
    steps = pmwm_codec.iter_decode(pmw, key=key, watermark=other)
    with pytest.raises(OptionError, match=f"reference watermark is {size}x{size}, the key's is 16x16"):
        next(steps)
    read = []

    def blocks():  # verify_stream refuses before it reads a byte
        read.append(True)
        yield pmw.read_bytes()
    from PIL import Image

    png = tmp_path / "other.png"
    Image.fromarray(other).save(png)
    with pytest.raises(OptionError, match=f"reference watermark {png} is {size}x{size}"):
        verify_stream(blocks(), key, png)
    assert read == []
    assert list(pmwm_codec.iter_decode(pmw, key=key, watermark=image))[-1].nc == 1.0


# --- outputs: a destination is checked before any work, and a file object gets every byte ---------------------


@pytest.fixture
def no_work(monkeypatch):
    """Fails the test if the encode gets as far as reading the mesh: a refusal must come before any work."""
    def read(src):
        raise AssertionError("the encode started its work before refusing its destination")
    monkeypatch.setattr(pmwm_codec, "_as_mesh", read)


def _text_file(tmp_path):
    return open(tmp_path / "text.pmw", "w")


@pytest.mark.parametrize("dst, words", [
    ("adir", "adir: is a directory; give a file name for the .pmw"),
    ("slash.pmw/", "slash.pmw/: ends with '/'"),
    ("nodir/x.pmw", "directory .*nodir does not exist"),
    ("/dev/null", "/dev/null: is not a regular file"),
    ("", "the .pmw path is empty"),
    (_text_file, "text mode.*open the file in binary mode"),
    (lambda tmp_path: io.StringIO(), "text mode"),
    (lambda tmp_path: closed_file(tmp_path / "closed.pmw", "wb"), "is closed"),
    (lambda tmp_path: open(tmp_path / "adir" / "r.pmw", "rb"), "not open for writing"),
])
def test_a_destination_that_cannot_take_the_pmw_is_refused_before_any_work(tmp_path, monkeypatch, no_work, dst,
                                                                            words):
    """Each was a bare OSError or TypeError raised after the whole encode (simplify, embed, measure), and
    ``slash.pmw/`` named a hidden temporary file."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "adir").mkdir()
    (tmp_path / "adir" / "r.pmw").write_bytes(b"")
    target = dst(tmp_path) if callable(dst) else dst
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    with pytest.raises(OptionError, match=words) as info:
        pmwm_codec.encode(MESH, target)
    assert ".tmp" not in str(info.value)
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", *before] and os.listdir(tmp_path / "adir") == ["r.pmw"]
    if hasattr(target, "close"):
        target.close()


class _ShortWrites(io.RawIOBase):
    """A raw file whose ``write()`` takes at most ``most`` bytes a call (legal: it returns the count), and after
    ``stall_after`` bytes returns ``stall`` (None: a non-blocking file that is not ready)."""

    def __init__(self, most=100, stall_after=None, stall=None):
        self.data, self.most, self.stall_after, self.stall = bytearray(), most, stall_after, stall

    def writable(self):
        return True

    def write(self, b):
        if self.stall_after is not None and len(self.data) >= self.stall_after:
            return self.stall
        b = bytes(b)[: self.most]
        self.data += b
        return len(b)


def test_a_raw_file_objects_short_writes_are_written_again_until_the_whole_pmw_is_out(tmp_path):
    """``encode`` ignored the count ``write()`` returned: it reported success with 2,229 of 14,904 bytes in
    the file object, a valid prefix that decodes to a coarser mesh, and published the new key."""
    out = _ShortWrites()
    report = pmwm_codec.encode(MESH, out, watermark=_image(0), key=tmp_path / "k.key.json", measure="none")
    assert report["bytes"] == len(out.data)
    assert pmwm_codec.decode(bytes(out.data)).vertex_count == MESH.vertex_count
    assert pmwm_codec.verify_stream(bytes(out.data), tmp_path / "k.key.json").verdict == "authentic"


@pytest.mark.parametrize("stall, words", [(None, "gave None"), (0, "wrote nothing")])
def test_a_file_object_that_stops_taking_bytes_is_an_error_and_the_new_key_is_not_kept(tmp_path, stall, words):
    out = _ShortWrites(stall_after=300, stall=stall)
    with pytest.raises(OptionError, match=f"write\\(\\) {words}.* after [0-9,]+ of [0-9,]+ bytes: the output is incomplete"):
        pmwm_codec.encode(MESH, out, watermark=_image(0), key=tmp_path / "k.key.json", measure="none")
    assert list(tmp_path.iterdir()) == []  # the key of a file that was not written whole is not published


def test_a_non_blocking_file_object_is_refused_before_any_work(tmp_path, no_work):
    """A non-blocking pipe took 4,024 of 14,856 bytes (the rest: ``write()`` returned None) and encode said OK."""
    r, w = os.pipe()
    os.set_blocking(w, False)
    with os.fdopen(r, "rb") as reader, os.fdopen(w, "wb", buffering=0) as dst:
        with pytest.raises(OptionError, match="non-blocking mode"):
            pmwm_codec.encode(MESH, dst, watermark=_image(0), key=tmp_path / "k.key.json")
        dst.close()
        assert reader.read() == b""
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("key, words", [("", "the key path is empty"), ("nodir/k.key.json", "nodir does not exist"),
                                        ("kdir/", "ends with '/'"), ("x" * 300 + ".key.json", "File name too long")])
def test_a_key_path_no_key_can_be_written_at_is_refused_before_any_work(tmp_path, monkeypatch, no_work, key, words):
    """``key=''`` (an unset variable) was taken until the publish step, which raised FileNotFoundError naming a
    hidden temporary file in the parent directory."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(OptionError, match=words) as info:
        pmwm_codec.encode(MESH, "m.pmw", watermark=_image(0), key=key)
    assert ".tmp" not in str(info.value)
    assert list(tmp_path.iterdir()) == [] and not any(".tmp" in p.name for p in tmp_path.parent.iterdir())


# --- read_mesh / write_mesh: the arguments, and a key file is never a mesh's target ---------------------------


@pytest.mark.parametrize("name", ["secret.obj", "secret.ply", "secret.stl", "secret.glb", "secret.gltf", "m.key.json"])
def test_write_mesh_never_replaces_a_key_file_as_pmw_decode_does_not(tmp_path, name):
    """``write_mesh('secret.ply', mesh)`` wrote the mesh over a key saved under that name (``pmw decode`` refused)."""
    pmwm_codec.encode(MESH, tmp_path / "a.pmw", watermark=_image(0), measure="none")
    key = (tmp_path / "a.pmw.key.json").read_bytes()
    (tmp_path / name).write_bytes(key)
    with pytest.raises(WatermarkKeyError, match="names a watermark key file; a mesh never replaces a key"):
        pmwm_codec.write_mesh(tmp_path / name, MESH)
    assert (tmp_path / name).read_bytes() == key


def test_write_mesh_never_replaces_a_key_file_beside_a_gltf_as_its_buffer(tmp_path):
    pmwm_codec.encode(MESH, tmp_path / "a.pmw", watermark=_image(0), measure="none")
    key = (tmp_path / "a.pmw.key.json").read_bytes()
    (tmp_path / "m.bin").write_bytes(key)
    pmwm_codec.write_mesh(tmp_path / "m.gltf", MESH)  # self-contained: the .bin beside it is not its buffer
    assert (tmp_path / "m.bin").read_bytes() == key and (tmp_path / "m.gltf").exists()


@pytest.mark.parametrize("path, mesh, error, words", [
    ("w.pmw", MESH, OptionError, "unknown output format '.pmw'"),
    ("-", MESH, OptionError, "not to standard output"),
    ("adir.obj", MESH, OptionError, "is a directory"),
    ("nodir/w.obj", MESH, OptionError, "nodir does not exist"),
    (io.BytesIO(), MESH, OptionError, "must be a file name .*got BytesIO"),
    (5, MESH, OptionError, "must be a file name .*got int"),
    ("w.obj", None, OptionError, "mesh must be a Mesh, got NoneType"),
    ("w.obj", (MESH.positions, MESH.faces), OptionError, "mesh must be a Mesh, got tuple"),
    ("w.obj", pmwm_codec.Mesh(MESH.positions, MESH.faces[:, :2]), pmwm_codec.errors.MeshError, "must be triangles"),
    ("w.obj", pmwm_codec.Mesh(MESH.positions, MESH.faces + 10 ** 6), pmwm_codec.errors.MeshError, "out of range"),
    # a complex position lost its imaginary part and a bool index named vertex 0 or 1 (a numpy warning at most);
    # a coordinate past float32's range was written as infinite
    ("w.obj", pmwm_codec.Mesh(MESH.positions + 1j, MESH.faces), pmwm_codec.errors.MeshError,
     "positions must be real numbers, got dtype complex128"),
    ("w.obj", pmwm_codec.Mesh(MESH.positions, MESH.faces.astype(bool)), pmwm_codec.errors.MeshError,
     r"face indices are not numbers \(dtype bool\)"),
    ("w.ply", pmwm_codec.Mesh(MESH.positions * 1e300, MESH.faces), pmwm_codec.errors.MeshError,
     "a coordinate of .*e\\+300 overflows the float32 every format stores"),
])
def test_write_mesh_names_a_wrong_argument_with_a_pmw_error_and_writes_nothing(tmp_path, monkeypatch, path, mesh,
                                                                               error, words):
    """Each raised ValueError, TypeError (``os.fspath``), AttributeError (``.positions``) or OSError."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "adir.obj").mkdir()
    with pytest.raises(error, match=words):
        pmwm_codec.write_mesh(path, mesh)
    assert [p.name for p in tmp_path.iterdir()] == ["adir.obj"]


@pytest.mark.parametrize("mesh, words", [
    (pmwm_codec.Mesh(MESH.positions + 1j, MESH.faces), "positions must be real numbers, got dtype complex128"),
    (pmwm_codec.Mesh(MESH.positions, MESH.faces.astype(bool)), r"face indices are not numbers \(dtype bool\)"),
])
def test_encode_refuses_complex_positions_and_bool_faces_and_writes_nothing(tmp_path, mesh, words):
    """encode() took a complex position as its real part and a bool face index as vertex 0 or 1."""
    with pytest.raises(pmwm_codec.errors.MeshError, match=words):
        pmwm_codec.encode(mesh, tmp_path / "m.pmw", measure="none")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("call, error, words", [
    (lambda: pmwm_codec.encode("a\0b.obj", "m.pmw"), pmwm_codec.errors.InputFormatError, "no such file"),
    (lambda: pmwm_codec.encode(MESH, "a\0b.pmw"), OptionError, r"cannot write \.pmw \(embedded null byte\)"),
    (lambda: pmwm_codec.encode(MESH, "m.pmw", watermark="a\0b.png"), pmwm_codec.errors.InputFormatError,
     "no such file"),
    (lambda: pmwm_codec.encode(MESH, "m.pmw", watermark=_image(0), key="a\0b.json"), OptionError,
     r"cannot write key \(embedded null byte\)"),
    (lambda: pmwm_codec.write_mesh("a\0b.obj", MESH), OptionError, r"cannot write mesh \(embedded null byte\)"),
])
def test_a_path_with_a_nul_is_a_pmw_error_and_writes_nothing(tmp_path, monkeypatch, call, error, words):
    """A NUL in a path made os.lstat / os.path.samefile raise a bare ValueError out of encode and write_mesh
    (the readers already said "no such file"); the string is never copied into the message."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(error, match=words) as caught:
        call()
    assert "\0" not in str(caught.value) and "not a file name" in str(caught.value)
    assert list(tmp_path.iterdir()) == []


def test_read_mesh_takes_a_file_name_and_names_anything_else(tmp_path):
    """``read_mesh(b"/path/cow.obj")`` said "no such file" for an existing file; a file object, an int or None
    raised TypeError from ``os.fspath``."""
    src = tmp_path / "m.obj"
    pmwm_codec.write_mesh(src, MESH)
    assert pmwm_codec.read_mesh(os.fsencode(src)) == pmwm_codec.read_mesh(src)
    with open(src, "rb") as fh:
        for wrong in (fh, 5, None):
            with pytest.raises(OptionError, match=f"the mesh path must be a file name .*got {type(wrong).__name__}"):
                pmwm_codec.read_mesh(wrong)


def test_a_file_whose_name_holds_a_line_break_is_read_and_named_escaped(tmp_path, monkeypatch):
    """An existing ``a<LF>b.obj`` was refused as "no such file" (a line break marked a file's content given as
    its path); a name no file has, with a line break, is still never copied into a message."""
    from pmwm_codec.meshio import write_mesh
    from pmwm_codec.sources import shown_path

    monkeypatch.chdir(tmp_path)
    write_mesh("a\nb.obj", MESH)
    pmwm_codec.encode("a\nb.obj", "m.pmw", measure="none")
    assert pmwm_codec.decode("m.pmw").vertex_count == MESH.vertex_count
    assert shown_path("a\nb.obj") == "a\\nb.obj" and shown_path("tab\there") == "tab\\there"
    with pytest.raises(pmwm_codec.errors.InputFormatError, match="not a file name") as caught:
        pmwm_codec.encode("secret\nkey.obj", "n.pmw")
    assert "secret" not in str(caught.value)
    assert not os.path.exists("n.pmw")


@pytest.mark.parametrize("given", ['{"format": "pmwm-key", "secret": "00ff"}', '{"secret":\n"00ff"}'])
def test_a_keys_json_given_as_its_path_is_never_echoed_by_the_command_line(tmp_path, monkeypatch, capsys, given):
    """``pmw verify F --key "$(cat k.json)"``: the command line's own check printed the key's JSON (its secret) in
    ``no such key file``; a name no file has that starts with ``{`` is taken for a file's content, as one with a
    line break is."""
    from pmwm_codec.cli import main

    monkeypatch.chdir(tmp_path)
    pmwm_codec.encode(MESH, "m.pmw", measure="none")
    assert main(["verify", "m.pmw", "--key", given]) == 2
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and "no such key file" in err and "not a file name" in err, err
    assert "00ff" not in err + out


def test_decode_to_takes_a_bytes_file_name_as_write_mesh_does(tmp_path, stream):
    """``decode_to(src, b"x.obj")`` was refused as "unknown output format b'.obj'"."""
    src = tmp_path / "s.pmw"
    src.write_bytes(stream)
    result = pmwm_codec.decode_to(str(src), os.fsencode(tmp_path / "x.obj"), chunks=1)
    assert result["output"] == str(tmp_path / "x.obj") and (tmp_path / "x.obj").is_file()


@pytest.mark.parametrize("dst", [io.BytesIO(), 5, None])
def test_decode_to_names_a_destination_that_is_no_file_name_with_an_option_error(tmp_path, stream, dst):
    """A file object, an int or None as ``dst`` raised a bare TypeError from os.fspath, not a PmwError."""
    src = tmp_path / "s.pmw"
    src.write_bytes(stream)
    with pytest.raises(OptionError, match="must be a file name"):
        pmwm_codec.decode_to(str(src), dst)
    assert os.listdir(tmp_path) == ["s.pmw"]


@pytest.mark.parametrize("bits, noted", [(None, False), (6, False), (7, True), (16, True)])
def test_exact_mode_past_six_bits_per_code_is_noted(tmp_path, bits, noted):
    """``--bits 16`` in exact mode moved the cow to 2.3 dB mesh PSNR without a word (the bits are the user's to
    choose, past the 6 the mode is made for; now a note says what they cost)."""
    report = pmwm_codec.encode(MESH, tmp_path / "m.pmw", watermark=_image(0), bits=bits, measure="none",
                               owner_id=False)
    assert any("bits per code: past the 6" in n for n in report["notices"]) == noted, report["notices"]


def test_verify_stream_without_a_key_is_refused_not_judged_not_authentic(stream):
    """``verify_stream(src, None)`` answered ``not-authentic``, the verdict of a forged file, for any file: a
    script that lost its key read its own files as forgeries (outside probe of the API).  ``pmw verify`` without
    ``--key`` is a usage error; the API now refuses it too."""
    with pytest.raises(WatermarkKeyError, match="needs the key"):
        pmwm_codec.verify_stream(stream, None)  # type: ignore[arg-type]


def test_iter_decode_refuses_a_watermark_without_a_key(stream):
    """``iter_decode(src, watermark=img)`` with no key decoded as if no image were given: no partial image, no
    score, no word (outside probe of the API).  The image is read with the key, so the call names what is missing."""
    with pytest.raises(OptionError, match="watermark needs a key"):
        pmwm_codec.iter_decode(stream, watermark=_image(1))
