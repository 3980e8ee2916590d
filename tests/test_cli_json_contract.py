"""The ``pmw`` command against its written contract (DESIGN.md §5, README "The pmw command"), as seen from outside;
each test says what an audit found apart from it."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh


def _image(size: int) -> np.ndarray:
    y, x = np.mgrid[:size, :size]
    return (((x // 4 + y // 4) % 2) * 200 + 20 + (x * 3 + y) % 30).astype(np.uint8)


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A mesh file, a watermark image, and a .pmw marked with that image but no owner layer, with its key."""
    d = tmp_path_factory.mktemp("contract")
    mesh = shapes.demo_mesh(40)
    write_mesh(d / "m.obj", mesh)
    Image.fromarray(_image(16)).save(d / "logo.png")
    pmwm_codec.encode(mesh, d / "m.pmw", watermark=d / "logo.png", key=d / "m.key.json", owner_id=False,
                      measure="none")
    return d


def test_a_file_cut_inside_its_json_is_named_alike_by_every_command(files, tmp_path, capsys):
    """Cut inside the JSON, the same file was "inside the GLB header or JSON (needs 2544)" for info and decode but
    "before the base mesh was complete (needs 2544 bytes)" for verify and cut -- a count that read as the base's
    end, which lies further on.  Every command now says where it ended and that the count is a least one."""
    data = (files / "m.pmw").read_bytes()
    cut = tmp_path / "early.pmw"
    cut.write_bytes(data[:100])
    key = str(files / "m.key.json")
    said = set()
    for argv in (["info", str(cut)], ["decode", str(cut), "-o", str(tmp_path / "o.obj")],
                 ["verify", str(cut), "--key", key], ["cut", str(cut), "-o", str(tmp_path / "c.pmw")]):
        assert main(argv) == 2, argv
        said.add(capsys.readouterr().err)
    assert len(said) == 1, said
    line = said.pop()
    assert "stream ended after 100 bytes, inside the GLB header or JSON, before the base mesh was complete " \
           "(needs at least " in line, line
    assert not list(tmp_path.glob("o.*")) and not (tmp_path / "c.pmw").exists()
