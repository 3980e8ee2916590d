"""The public API called as its users call it, with the arguments they get wrong: each refusal is a
:class:`~pmwm_codec.errors.PmwError` of its documented kind, named clearly, and nothing is written."""

from __future__ import annotations

import io

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.errors import MeshError

MESH = shapes.torus(24, 12)


def _image(seed):
    return np.random.default_rng(seed).integers(0, 256, (8, 8)).astype(np.uint8)


@pytest.mark.parametrize("attributes, words", [
    ([1, 2], "attributes must be a dict of .* got list"),
    ({"normal": 5}, "attribute normal has no rows \\(a scalar\\) for"),
    ({"normal": None}, "attribute normal has no rows \\(a scalar\\) for"),
])
def test_mesh_attributes_that_are_no_dict_of_rows_are_a_mesh_error_and_nothing_is_written(tmp_path, attributes,
                                                                                          words):
    """A list raised AttributeError ('list' object has no attribute 'items') out of encode, a scalar or None
    an IndexError (tuple index out of range)."""
    with pytest.raises(MeshError, match=words):
        pmwm_codec.encode(pmwm_codec.Mesh(MESH.positions, MESH.faces, attributes), tmp_path / "m.pmw")
    assert list(tmp_path.iterdir()) == []


def test_a_uint64_face_index_past_int64_is_named_as_given(tmp_path):
    """2**63 + 5 was named as face index -9223372036854775803: cast to int64 before the range was checked."""
    faces = MESH.faces.astype(np.uint64)
    faces[0, 0] = 2 ** 63 + 5
    with pytest.raises(MeshError, match=f"face index {2 ** 63 + 5} out of range"):
        pmwm_codec.encode(pmwm_codec.Mesh(MESH.positions, faces), tmp_path / "m.pmw")
    assert list(tmp_path.iterdir()) == []


def test_a_watermark_image_named_by_a_bytes_path_is_read(tmp_path):
    """The image reader takes ``str``, ``bytes`` or ``os.PathLike``; a bytes path raised a bare TypeError
    (a bytes-like object is required, not 'str') from the check that the file exists."""
    from pmwm_codec.watermark.image import save_png

    png = tmp_path / "mark.png"
    save_png(png, _image(1))
    key = pmwm_codec.watermark.key.WatermarkKey.generate(rng=np.random.default_rng(2))
    by_bytes, by_str = io.BytesIO(), io.BytesIO()
    pmwm_codec.encode(MESH, by_bytes, watermark=bytes(png), key=key, measure="none")
    pmwm_codec.encode(MESH, by_str, watermark=str(png), key=key, measure="none")
    assert by_bytes.getvalue() == by_str.getvalue()


@pytest.mark.parametrize("arguments, error, words", [
    ({"key": 123}, pmwm_codec.errors.WatermarkKeyError, "a key must be a WatermarkKey"),
    ({"key": "no-such-key.json"}, pmwm_codec.errors.WatermarkKeyError, "no such key file"),
    ({"watermark": np.zeros((8, 8), complex)}, pmwm_codec.errors.InputFormatError, "unsupported dtype"),
    ({"src": 3}, pmwm_codec.errors.OptionError, "the source must be a path"),
    ({"src": io.StringIO("glTF")}, pmwm_codec.errors.OptionError, "text mode"),
])
def test_iter_decode_refuses_its_arguments_when_called_not_at_the_first_result(tmp_path, monkeypatch, arguments,
                                                                                 error, words):
    """iter_decode was a generator function: a mistyped key path or a source no reader takes was said only at
    the first next(), far from the call that named it (a consumer that never pulled a result heard nothing)."""
    monkeypatch.chdir(tmp_path)
    arguments = {"src": b"glTF", **arguments}
    with pytest.raises(error, match=words):
        pmwm_codec.iter_decode(**arguments)


def test_iter_decode_stopped_early_closes_its_source():
    """Closing the iterator after the first result closes the caller's generator of blocks (its ``finally``
    runs) and leaves no thread behind."""
    import threading

    data = io.BytesIO()
    pmwm_codec.encode(MESH, data, measure="none")
    closed = []

    def blocks():
        try:
            for i in range(0, len(data.getvalue()), 97):
                yield data.getvalue()[i:i + 97]
        finally:
            closed.append(True)

    threads = threading.active_count()
    steps = pmwm_codec.iter_decode(blocks())
    assert next(steps).chunk == 0
    steps.close()
    assert closed == [True] and threading.active_count() == threads


@pytest.mark.parametrize("source", [{}, {b"glTF": 1}, set(), frozenset({b"glTF"})])
def test_a_dict_or_a_set_is_no_source_of_blocks(source):
    """An empty dict was read as a file of 0 bytes ("truncated: stream ended after 0 bytes"), a dict's keys or a
    set's members as blocks in an order nobody chose."""
    with pytest.raises(pmwm_codec.errors.OptionError, match=f"the source must be a path.*got {type(source).__name__}"):
        pmwm_codec.decode(source)


@pytest.mark.parametrize("name", [b"/tmp/model.pmw", b"model.pmw", b"C:\\assets\\m.glb", bytearray(b"scans/a")])
def test_a_file_name_given_as_bytes_to_a_reader_is_said_to_be_read_as_the_file_s_content(tmp_path, name):
    """decode(b"/tmp/x.pmw") said only "bad magic b'/tmp'": the reader takes bytes as a .pmw's content."""
    for read in (pmwm_codec.decode, pmwm_codec.inspect, lambda src: list(pmwm_codec.iter_decode(src))):
        with pytest.raises(pmwm_codec.errors.FormatError, match="look like a file name.*give a name as a str") as exc:
            read(name)
        assert bytes(name).decode() not in str(exc.value)  # (the text itself is not repeated)
    with pytest.raises(pmwm_codec.errors.FormatError, match="bad magic"):  # text that names no file: as before
        pmwm_codec.decode(b"hello")


def test_a_mesh_of_another_library_or_a_pair_of_arrays_is_refused_with_the_mesh_that_takes_them(tmp_path):
    """encode() of a trimesh.Trimesh or of (positions, faces) said only "got Trimesh" / "got tuple"."""
    class OtherMesh:  # what trimesh.Trimesh offers
        vertices, faces = MESH.positions, MESH.faces

    with pytest.raises(pmwm_codec.errors.OptionError, match=r"got OtherMesh: give pmwm_codec.Mesh\(src.vertices, "
                                                            r"src.faces\)"):
        pmwm_codec.encode(OtherMesh(), tmp_path / "m.pmw")
    with pytest.raises(pmwm_codec.errors.OptionError, match=r"got tuple: give pmwm_codec.Mesh\(positions, faces\)"):
        pmwm_codec.encode((MESH.positions, MESH.faces), tmp_path / "m.pmw")
    assert list(tmp_path.iterdir()) == []


def test_encode_takes_its_paths_as_bytes_as_read_mesh_and_load_key_do(tmp_path):
    """encode() refused a bytes file name for ``src`` and ``dst`` ("src must be a Mesh, a path ..., got bytes") and
    for ``key`` ("key must be a WatermarkKey, a key file path or None, got bytes"), which read_mesh, write_mesh,
    decode_to and load_key take."""
    obj = tmp_path / "m.obj"
    pmwm_codec.write_mesh(obj, MESH)
    as_bytes = pmwm_codec.encode(bytes(obj), bytes(tmp_path / "b.pmw"), watermark=_image(3),
                                 key=bytes(tmp_path / "b.key.json"), measure="none")
    assert as_bytes["key_path"] == str(tmp_path / "b.key.json")
    key = pmwm_codec.load_key(tmp_path / "b.key.json")
    again = io.BytesIO()
    pmwm_codec.encode(str(obj), again, watermark=_image(3), key=key, measure="none")
    assert (tmp_path / "b.pmw").read_bytes() == again.getvalue()


@pytest.mark.parametrize("alias", ["MeshSource", "Destination", "WatermarkImage", "KeyLike"])
def test_the_type_aliases_of_encodes_paths_name_bytes(alias):
    """encode (and load_key, iter_decode's key, the image reader) take a file name as bytes: a type checker reading
    the aliases flagged such a call as an error."""
    import typing

    assert bytes in typing.get_args(getattr(pmwm_codec, alias))


def test_a_mesh_made_of_lists_counts_and_shows_itself():
    """Mesh(list, list) was taken by encode but its vertex_count, face_count, repr and bbox_diagonal raised
    AttributeError ('list' object has no attribute 'shape')."""
    mesh = pmwm_codec.Mesh(MESH.positions.tolist(), MESH.faces.tolist())
    assert (mesh.vertex_count, mesh.face_count) == (MESH.vertex_count, MESH.face_count)
    assert repr(mesh) == repr(MESH) and mesh == MESH
    assert mesh.bbox_diagonal() == MESH.bbox_diagonal()
    with pytest.raises(MeshError, match="vertex or face data is not numeric"):
        pmwm_codec.Mesh([[0, 0, 0], [1, 0]], [[0, 1, 2]])


@pytest.mark.parametrize("arguments, error, words", [
    ({"positions": MESH.positions * np.nan}, MeshError, "NaN or infinite coordinates"),
    ({"faces": MESH.faces + MESH.vertex_count}, MeshError, "face index .* out of range"),
    ({"positions": MESH.positions[:, :2]}, MeshError, r"positions must be \(n, 3\)"),
    ({"positions": np.zeros((0, 3)), "faces": np.zeros((0, 3), int)}, MeshError, "n >= 1 without a camera"),
    ({"width": 0}, pmwm_codec.errors.OptionError, r"width must be an integer 1\.\.8192 \(pixels\), got 0"),
    ({"height": -5}, pmwm_codec.errors.OptionError, r"height must be an integer 1\.\.8192 \(pixels\), got -5"),
    ({"width": 10**6, "height": 10**6}, pmwm_codec.errors.OptionError, "width must be an integer 1..8192"),  # MemoryError
    ({"width": 8192, "height": 8192}, pmwm_codec.errors.OptionError, "more than 67,108,864 pixels"),  # 16384^2 buffer
    ({"supersample": 0}, pmwm_codec.errors.OptionError, "supersample must be an integer 1..8, got 0"),  # drew at 1
    ({"supersample": 2.5}, pmwm_codec.errors.OptionError, "supersample must be an integer 1..8, got 2.5"),
    ({"color": "red"}, pmwm_codec.errors.OptionError, "color must be an RGB triple"),
    ({"background": (1, 2)}, pmwm_codec.errors.OptionError, "background must be an RGB triple"),
    ({"camera": 5}, pmwm_codec.errors.OptionError, "camera must be a Camera or None, got int"),
])
def test_render_names_a_wrong_argument_with_a_pmw_error(arguments, error, words):
    """render (README: pictures without the command line) raised IndexError (a face index out of range, (n, 2)
    positions), ValueError from numpy or Pillow (no vertices, width 0 or negative, a colour of two numbers or a
    name), AttributeError (a camera that is none), and drew NaN positions as garbage with RuntimeWarnings."""
    from pmwm_codec.render import render

    arguments = {"positions": MESH.positions, "faces": MESH.faces, **arguments}
    with pytest.raises(error, match=words):
        render(arguments.pop("positions"), arguments.pop("faces"), **arguments)


@pytest.mark.parametrize("fields, words", [
    ({"rotation": np.eye(2)}, r"rotation must be a finite \(3, 3\) array, got shape \(2, 2\)"),  # numpy ValueError
    ({"center": [0.0, np.nan, 0.0]}, "center must be a finite .* not all finite"),
    ({"scale": float("nan")}, "scale must be a finite number > 0, got nan"),  # drew garbage, RuntimeWarnings
    ({"scale": 0.0}, "scale must be a finite number > 0"),
    ({"width": 0}, "width must be an integer 1..8192"),
])
def test_a_camera_that_cannot_draw_is_refused_by_name(fields, words):
    """A Camera built by hand (README: frames that line up) was taken as given: a (2, 2) rotation raised
    numpy's ValueError inside render, a NaN scale drew an empty picture with RuntimeWarnings (outside probe)."""
    from pmwm_codec.render import Camera

    base = {"rotation": np.eye(3), "center": np.zeros(3), "scale": 1.0, "width": 8, "height": 8}
    with pytest.raises(pmwm_codec.errors.OptionError, match=words):
        Camera(**{**base, **fields})
    with pytest.raises(MeshError, match="Camera.fit: positions must be"):  # numpy's ValueError on an empty array
        Camera.fit(np.zeros((0, 3)))


def test_render_of_no_faces_is_the_background():
    from pmwm_codec.render import BACKGROUND, render

    image = render(MESH.positions, np.zeros((0, 3), np.int64), width=8, height=8)
    assert image.shape == (8, 8, 3) and (image == BACKGROUND).all()


@pytest.fixture(scope="module")
def results():
    data = io.BytesIO()
    pmwm_codec.encode(MESH, data, measure="none")
    return list(pmwm_codec.iter_decode(data.getvalue()))


@pytest.mark.parametrize("arguments, words", [
    ({"results": []}, "nothing to draw"),
    ({"results": [1, 2]}, "each must be a PartialResult of pmwm_codec.iter_decode, got int"),
    ({"k": 0}, r"k \(how many levels the overview shows\) must be an integer >= 1, got 0"),
    ({"tamper": [10 ** 9]}, r"tamper: vertex indices \(f,\) of the last result's mesh"),
    ({"title": 5}, "title must be a str or None, got int"),  # AttributeError from Pillow's text layout
])
def test_write_figures_names_a_wrong_argument_with_an_option_error_and_writes_nothing(tmp_path, results, arguments,
                                                                                      words):
    """Each raised ValueError ('no results to draw'), AttributeError, IndexError (k=0, a flagged vertex past
    the mesh) from inside the drawing."""
    from pmwm_codec.figures import write_figures

    arguments = {"results": results, **arguments}
    with pytest.raises(pmwm_codec.errors.OptionError, match=words):
        write_figures(arguments.pop("results"), tmp_path / "pictures", **arguments)
    assert list(tmp_path.iterdir()) == []


def test_write_figures_of_results_kept_without_meshes_says_how_to_keep_them(tmp_path):
    """verify_stream's results hold no meshes unless keep_meshes=True: write_figures raised numpy's ValueError
    ('need at least one array to concatenate')."""
    from pmwm_codec.figures import write_figures

    data = io.BytesIO()
    pmwm_codec.encode(MESH, data, watermark=_image(4), key=tmp_path / "k.key.json", measure="none")
    verified = pmwm_codec.verify_stream(data.getvalue(), tmp_path / "k.key.json")
    with pytest.raises(pmwm_codec.errors.OptionError, match="keep_meshes=True"):
        write_figures(verified.results, tmp_path / "pictures")
    assert not (tmp_path / "pictures").exists()


def test_decode_and_encode_in_several_threads_give_what_one_thread_gives(tmp_path):
    """README: the library keeps no state between calls, so calls may run in threads at once (each on its own
    arguments): the same bytes decoded in 3 threads, 3 encodes with one key object, as one thread does them."""
    from concurrent.futures import ThreadPoolExecutor

    from pmwm_codec.watermark.key import WatermarkKey

    key = WatermarkKey.generate(rng=np.random.default_rng(5))

    def encoded(_):
        out = io.BytesIO()
        pmwm_codec.encode(MESH, out, watermark=_image(5), key=key, measure="none")
        return out.getvalue()

    alone = encoded(None)
    with ThreadPoolExecutor(3) as pool:
        assert list(pool.map(encoded, range(3))) == [alone] * 3
        meshes = list(pool.map(lambda _: pmwm_codec.decode(alone), range(3)))
    assert all(m == pmwm_codec.decode(alone) for m in meshes)


def test_a_key_that_is_no_json_object_is_named_as_what_it_is(tmp_path):
    """WatermarkKey.from_json of the key's text (a str), and a key file holding a JSON list, were refused as
    '"format" is not "pmwm-key"', which sent the user looking at a member the key has."""
    from pmwm_codec.errors import WatermarkKeyError
    from pmwm_codec.watermark.key import WatermarkKey

    text = WatermarkKey.generate(rng=np.random.default_rng(6)).to_text().decode()
    with pytest.raises(WatermarkKeyError, match=r"a JSON object expected, got str: give json.loads\(text\)"):
        WatermarkKey.from_json(text)
    (tmp_path / "list.json").write_text("[1, 2]")
    with pytest.raises(WatermarkKeyError, match="list.json: not a valid watermark key .a JSON object expected, "
                                                 "got list"):
        pmwm_codec.load_key(tmp_path / "list.json")


def test_a_stream_decoder_takes_a_key_file_path_and_names_wrong_arguments_with_pmw_errors(tmp_path):
    """StreamDecoder(key) raised AttributeError ('str' object has no attribute 'mac_key') for a key file path, which
    iter_decode and load_key take, and for an int; max_chunks=-1 or '2' was taken; a feed() after close() raised a
    bare ValueError."""
    from pmwm_codec.errors import OptionError, WatermarkKeyError
    from pmwm_codec.stream import StreamDecoder

    data = io.BytesIO()
    pmwm_codec.encode(MESH, data, watermark=_image(7), key=tmp_path / "k.key.json", measure="none")
    by_path = StreamDecoder(tmp_path / "k.key.json")
    by_object = StreamDecoder(pmwm_codec.load_key(tmp_path / "k.key.json"))
    assert [r.nc for r in by_path.feed(data.getvalue())] == [r.nc for r in by_object.feed(data.getvalue())]
    with pytest.raises(WatermarkKeyError, match="a key must be a WatermarkKey, a key file path or None, got int"):
        StreamDecoder(5)
    for wrong in (-1, "2"):
        with pytest.raises(OptionError, match="must be None or an integer >= 0"):
            StreamDecoder(max_chunks=wrong)
    by_path.close()
    with pytest.raises(OptionError, match="single-use: it was already closed"):
        by_path.feed(b"")


def test_a_stream_decoder_reads_its_reference_image_when_made(tmp_path):
    """StreamDecoder(reference="x.png") raised a bare ValueError ("invalid literal for int()") from inside the first
    feed(); the reference is read as iter_decode reads its watermark: a path, or an array, checked when made."""
    from pmwm_codec.errors import InputFormatError
    from pmwm_codec.stream import StreamDecoder

    data = io.BytesIO()
    pmwm_codec.encode(MESH, data, watermark=_image(7), key=tmp_path / "k.key.json", measure="none")
    with pytest.raises(InputFormatError, match="no such file"):
        StreamDecoder(tmp_path / "k.key.json", reference=str(tmp_path / "missing.png"))
    with pytest.raises(InputFormatError, match="watermark array"):
        StreamDecoder(tmp_path / "k.key.json", reference=5)
    image = pmwm_codec.load_key(tmp_path / "k.key.json").reference
    from PIL import Image

    Image.fromarray(image).save(tmp_path / "mark.png")
    by_file = StreamDecoder(tmp_path / "k.key.json", reference=str(tmp_path / "mark.png")).feed(data.getvalue())
    assert by_file[-1].nc == pytest.approx(1.0)
