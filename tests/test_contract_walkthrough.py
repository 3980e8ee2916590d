"""Command-line behaviours a contract walkthrough (README, DESIGN.md §5) found apart from the README.

* ``pmw demo --out -`` made a folder named ``-`` in the current one and wrote the demo there, exit 0; the
  README's outputs are "never ``-`` (no output goes to standard output; nor is ``--frames -``)", and
  ``verify --frames -`` is refused.  It is now refused the same way: exit 2, one line, nothing made.
* ``pmw encode IN -o /dev/stdout`` (and ``cut``, and ``pmwm_codec.encode(mesh, "/dev/stdout")``) exited 0 and,
  run as root, replaced the system's ``/dev/stdout`` link with a regular file holding the ``.pmw``: an output
  is published by a rename, which replaces a symbolic link rather than writing through it, and a link to a
  file descriptor is neither a device nor a FIFO.  Every later ``> /dev/stdout`` in that container then
  wrote to that file.  An output that is a link to an open file descriptor is now refused (exit 2, one line,
  the link untouched).  The tests use a link of their own to ``/proc/self/fd/1``, as ``/dev/stdout`` is.
* ``pmw verify X.pmw --key K --frames DIR`` removes the pictures an earlier run left that this one does not
  write (later frames ...), "not links, not the command's inputs, nothing else": a key file under such a name
  (``frame_030.png`` holding a key) was removed with them, its secret lost, while writing a picture over the
  same file is refused ("a key file is never rewritten").  Key files are now left, as links and inputs are.
* ``pmw encode scene.gltf`` read a buffer or image ``uri`` that names a watermark key file beside the asset
  (``other.pmw.key.json``, or a key under any name) like any other file inside the asset's folder, and wrote
  its bytes, the secret among them, into the ``.pmw`` meant for publishing: exit 0.  Such a uri is now refused
  by name (exit 2, one line, nothing written), as an output never replaces a key.
* ``pmw decode - -o x.obj <&-`` (a process started with standard input closed, as some daemons and job runners
  start it) said ``unexpected AttributeError: 'NoneType' object has no attribute 'buffer' (a bug of pmw ...)``;
  it now says that standard input is closed (exit 2, one line), and ``pmwm_codec.decode("-")`` raises an
  OptionError saying so.
* ``pmw verify - --reference X.pmw --key K`` (a mesh piped in) said ``stdin: -: no such file``; it now says
  that this form reads the mesh from a file, not standard input (exit 2, one line).
"""

from __future__ import annotations

import io
import os

import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.errors import OptionError
from pmwm_codec.meshio import write_mesh
from pmwm_codec.watermark import WatermarkKey, make_text_watermark, save_png


def test_demo_refuses_out_dash_and_makes_no_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo", "--out", "-"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: -: ") and "standard output" in err and err.count("\n") == 1
    assert os.listdir(tmp_path) == []


needs_proc_fd = pytest.mark.skipif(not os.path.isdir("/proc/self/fd"), reason="no /proc/self/fd here")


@needs_proc_fd
@pytest.mark.parametrize("command", ["encode", "cut"])
def test_an_output_linked_to_standard_output_is_refused_and_the_link_kept(tmp_path, capsys, command):
    mesh = tmp_path / "m.obj"
    write_mesh(mesh, shapes.demo_mesh(12))
    source = mesh
    if command == "cut":
        source = tmp_path / "m.pmw"
        assert main(["encode", str(mesh), "-o", str(source), "-q", "--measure", "none"]) == 0
    link = tmp_path / "stdout"  # as /dev/stdout is
    os.symlink("/proc/self/fd/1", link)
    capsys.readouterr()
    assert main([command, str(source), "-o", str(link), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"pmw: error: {link}: ") and "standard output" in err and err.count("\n") == 1
    assert os.path.islink(link) and os.readlink(link) == "/proc/self/fd/1"


@needs_proc_fd
def test_the_library_refuses_an_output_linked_to_a_descriptor(tmp_path):
    link = tmp_path / "out.pmw"
    os.symlink("/proc/self/fd/2", link)
    with pytest.raises(OptionError, match="file descriptor"):
        pmwm_codec.encode(shapes.demo_mesh(12), str(link), measure="none")
    assert os.path.islink(link)
    pmwm_codec.encode(shapes.demo_mesh(12), io.BytesIO(), measure="none")  # a file object is still taken


def test_frames_never_remove_a_key_file_named_as_a_stale_picture(tmp_path, capsys):
    mesh = tmp_path / "m.obj"
    write_mesh(mesh, shapes.demo_mesh(40))
    image = tmp_path / "mark.png"
    save_png(image, make_text_watermark("P", 16))
    pmw, key = tmp_path / "m.pmw", tmp_path / "m.pmw.key.json"
    assert main(["encode", str(mesh), "-o", str(pmw), "--watermark", str(image), "-q", "--measure", "none"]) == 0
    frames = tmp_path / "frames"
    frames.mkdir()
    other = frames / "frame_999.png"  # a key under a picture's name, of a frame this run does not write
    other.write_bytes(key.read_bytes())
    stale = frames / "frame_998.png"  # a picture an earlier run left: still removed
    stale.write_bytes(b"\x89PNG\r\n\x1a\n")
    capsys.readouterr()
    assert main(["verify", str(pmw), "--key", str(key), "--frames", str(frames), "-q"]) == 0
    assert (frames / "overview.png").exists() and not stale.exists()
    assert other.read_bytes() == key.read_bytes()
    assert WatermarkKey.load(other).secret == WatermarkKey.load(key).secret


def _gltf_naming(uri: str, as_image: bool) -> dict:
    """A one-quad glTF whose buffer 0 is ``x.bin``; ``uri`` is an image's (``as_image``) or a second buffer's,
    which an image's bufferView reads."""
    doc = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0}],
           "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1, "material": 0}]}],
           "materials": [{"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}}],
           "textures": [{"source": 0}],
           "buffers": [{"byteLength": 60, "uri": "x.bin"}],
           "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                           {"buffer": 0, "byteOffset": 48, "byteLength": 12}],
           "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                          "min": [0, 0, 0], "max": [1, 1, 0]},
                         {"bufferView": 1, "componentType": 5123, "count": 6, "type": "SCALAR"}]}
    if as_image:
        doc["images"] = [{"uri": uri, "mimeType": "image/png"}]
    else:
        doc["buffers"].append({"uri": uri, "byteLength": 64})
        doc["bufferViews"].append({"buffer": 1, "byteOffset": 0, "byteLength": 64})
        doc["images"] = [{"bufferView": 2, "mimeType": "image/png"}]
    return doc


@pytest.mark.parametrize("name", ["other.pmw.key.json", "texture.png"])
@pytest.mark.parametrize("as_image", [True, False])
def test_a_gltf_uri_naming_a_key_file_is_refused_and_the_secret_never_written(tmp_path, capsys, name, as_image):
    import json

    import numpy as np

    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], np.float32)
    (tmp_path / "x.bin").write_bytes(positions.tobytes() + np.array([0, 1, 2, 1, 3, 2], np.uint16).tobytes())
    WatermarkKey.generate(owner_id=0x5EED).save(tmp_path / name)
    secret_hex = json.loads((tmp_path / name).read_text())["secret"]
    (tmp_path / "scene.gltf").write_text(json.dumps(_gltf_naming(name, as_image)))
    out = tmp_path / "scene.pmw"
    capsys.readouterr()
    assert main(["encode", str(tmp_path / "scene.gltf"), "-o", str(out), "-q"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: scene.gltf: ") and "key file" in err and err.count("\n") == 1
    assert not out.exists() and secret_hex not in err


@pytest.mark.parametrize("argv", [["decode", "-", "-o", "x.obj"], ["cut", "-", "-o", "x.pmw"], ["info", "-"],
                                  ["verify", "-", "--key", "k.key.json"]])
def test_a_closed_standard_input_is_named_not_a_bug(tmp_path, capsys, monkeypatch, argv):
    monkeypatch.chdir(tmp_path)
    WatermarkKey.generate(owner_id=1).save(tmp_path / "k.key.json")
    monkeypatch.setattr("sys.stdin", None)  # what Python makes of a closed descriptor 0
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: ") and "standard input is closed" in err and err.count("\n") == 1
    assert "unexpected" not in err and sorted(os.listdir(tmp_path)) == ["k.key.json"]
    with pytest.raises(OptionError, match="standard input is closed"):
        pmwm_codec.decode("-")


def test_verify_reference_names_a_mesh_on_standard_input_as_unsupported(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    WatermarkKey.generate(owner_id=1).save(tmp_path / "k.key.json")
    (tmp_path / "r.pmw").write_bytes(b"glTF")
    assert main(["verify", "-", "--reference", "r.pmw", "--key", "k.key.json"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("pmw: error: -: ") and "standard input" in err and "no such file" not in err
    assert err.count("\n") == 1
