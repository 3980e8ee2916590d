"""Two command-line behaviours an audit found apart from the README:

* ``pmw encode --fit`` shrinks a watermark that does not fit and the key keeps the shrunk image; the same
  command run again, or for the next asset of one collection ``--key`` ("one key marks any number of
  assets"), was refused as "another watermark".  It now marks with the image the key holds when that is
  the named image as ``--fit`` shrank it.
* ``pmw verify MESH --key KEY`` (the blind owner read) dropped ``--frames`` and ``--watermark`` in silence:
  exit 0, no picture, no word (even for an image file that does not exist).  It now refuses them, exit 2,
  one line, nothing written.
"""

from __future__ import annotations

import numpy as np
from PIL import Image

from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh
from pmwm_codec.watermark import WatermarkKey


def _pattern(size: int) -> np.ndarray:
    y, x = np.mgrid[:size, :size]
    return (((x // 4 + y // 4) % 2) * 200 + 20 + (x * 3 + y) % 30).astype(np.uint8)


def test_fit_reuses_the_key_that_holds_the_image_it_shrank(tmp_path, capsys):
    mesh_a, mesh_b = tmp_path / "a.obj", tmp_path / "b.obj"
    write_mesh(mesh_a, shapes.demo_mesh(40))
    write_mesh(mesh_b, shapes.demo_mesh(44))
    image = tmp_path / "logo.png"
    Image.fromarray(_pattern(64)).save(image)  # too large for these meshes: --fit shrinks it
    key = tmp_path / "collection.key.json"
    common = ["--watermark", str(image), "--fit", "--key", str(key), "-q", "--measure", "none"]
    assert main(["encode", str(mesh_a), "-o", str(tmp_path / "a.pmw"), *common]) == 0
    held = WatermarkKey.load(key).reference
    assert held is not None and held.shape[0] < 64
    capsys.readouterr()
    for src, out in ((mesh_b, "b.pmw"), (mesh_a, "a2.pmw")):  # the next asset; the same command again
        assert main(["encode", str(src), "-o", str(tmp_path / out), *common]) == 0, capsys.readouterr().err
        assert main(["verify", str(tmp_path / out), "--key", str(key), "-q"]) == 0
    assert np.array_equal(WatermarkKey.load(key).reference, held)  # the key as it was


def test_fit_still_refuses_a_key_of_another_image(tmp_path, capsys):
    mesh = tmp_path / "a.obj"
    write_mesh(mesh, shapes.demo_mesh(40))
    Image.fromarray(_pattern(64)).save(tmp_path / "one.png")
    Image.fromarray(255 - _pattern(64)).save(tmp_path / "two.png")
    key = tmp_path / "k.key.json"
    base = ["--fit", "--key", str(key), "-q", "--measure", "none"]
    assert main(["encode", str(mesh), "-o", str(tmp_path / "a.pmw"), "--watermark", str(tmp_path / "one.png"),
                 *base]) == 0
    capsys.readouterr()
    assert main(["encode", str(mesh), "-o", str(tmp_path / "b.pmw"), "--watermark", str(tmp_path / "two.png"),
                 *base]) == 2
    assert "another watermark" in capsys.readouterr().err
    assert not (tmp_path / "b.pmw").exists()


def test_the_blind_owner_read_refuses_options_it_cannot_honour(tmp_path, capsys):
    mesh = tmp_path / "m.obj"
    write_mesh(mesh, shapes.torus(24, 12))
    key = tmp_path / "k.key.json"
    WatermarkKey.generate(rng=np.random.default_rng(1), owner_id=0xABC).save(key)
    frames = tmp_path / "frames"
    for extra in (["--frames", str(frames)], ["--watermark", str(tmp_path / "missing.png")]):
        assert main(["verify", str(mesh), "--key", str(key), *extra]) == 2
        out, err = capsys.readouterr()
        assert out == "" and err.count("\n") == 1 and err.startswith("pmw: error: " + extra[0]), err
        assert "--reference" in err and "Traceback" not in err
    assert not frames.exists()
