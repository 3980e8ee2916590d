"""Embedding start (``embed_from`` / ``--embed-from`` / ``embedFrom`` in the file).

The files are written with a start and read with nothing but the key and the bytes: the start
comes from the file's public watermark parameters.
"""

from __future__ import annotations

import io
import json
import os
import re

import numpy as np
import pytest
from PIL import Image

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.cli import main
from pmwm_codec.meshio import write_mesh
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.verify.mesh import verify_mesh
from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.key import WatermarkKey

MESH = shapes.icosphere(4, 1.2, noise=0.02)  # 2,498 vertex splits


def _image(size=16, seed=3):
    return np.random.default_rng(seed).integers(0, 256, (size, size)).astype(np.uint8)


def _secret(seed):
    """A key with the secret only: no parameters, no reference, no start."""
    return WatermarkKey.generate(rng=np.random.default_rng(seed))


def _encode(embed_from=0, watermark=None, seed=5, **options):
    buf = io.BytesIO()
    report = encode_mesh(MESH, buf, watermark=watermark, key=None if watermark is None else _secret(seed),
                         embed_from=embed_from, min_chunk_splits=60, measure=False, **options)
    return buf.getvalue(), report


def _decode(data, key=None, reference=None):
    dec = StreamDecoder(key, reference)
    results = dec.feed(data)
    dec.close()
    return results


@pytest.mark.parametrize("mode", ["exact", "paper"])
def test_file_with_a_start_decodes_with_only_the_secret_key(mode):
    img = _image()
    data, report = _encode(0.3, img, mode=mode)
    assert report.key.params["embedFrom"] == int(0.3 * report.vsplits)
    final = _decode(data, _secret(5), img)[-1]  # the reader is told nothing about the start
    assert final.estimate.verdict == "authentic"
    assert final.code_match == 1.0
    if mode == "exact":
        assert np.array_equal(final.watermark, img)
    else:
        assert final.nc >= 0.998


def test_verify_mesh_reads_a_start_from_the_reference_file():
    img = _image()
    data, report = _encode(1000, img)
    decoded = pmwm_codec.decode(data)
    v = verify_mesh(decoded, data, _secret(5), img)
    assert v.verdict == "authentic"
    assert v.bit_exact


def test_splits_before_the_start_keep_the_unmarked_geometry():
    img = _image()
    unmarked = _decode(_encode()[0])
    for start, before_untouched in ((1200, True), (0, False)):
        marked = _decode(_encode(start, img)[0])
        assert [r.vertices for r in marked] == [r.vertices for r in unmarked]
        splits_done = [r.vertices - marked[0].vertices for r in marked]
        before = [i for i, done in enumerate(splits_done) if 0 < done <= start]
        if before_untouched:
            assert before, "the test needs a chunk that ends before the start"
            for i in before:
                assert np.array_equal(marked[i].positions_int, unmarked[i].positions_int)
            moved = np.any(marked[-1].positions_int != unmarked[-1].positions_int, axis=1)
            assert 0 < moved.sum() <= marked[-1].vertices - marked[0].vertices - start
        else:
            assert not np.array_equal(marked[1].positions_int, unmarked[1].positions_int)


def test_fraction_and_index_forms_write_the_same_file():
    img = _image()
    by_fraction, report = _encode(0.25, img)
    by_index, _ = _encode(int(np.floor(0.25 * report.vsplits)), img)
    assert by_fraction == by_index
    assert by_fraction != _encode(0, img)[0]


def test_start_zero_writes_no_embed_from_field():
    img = _image()
    data, report = _encode(0, img)
    assert "embedFrom" not in report.key.params
    assert b"embedFrom" not in data


def test_a_start_leaving_too_few_splits_is_refused_with_the_numbers():
    img = _image(32)  # paper mode: 1,024 coefficients, one split each
    with pytest.raises(wm.CapacityError, match=r"leaves 998 of 2,498 splits; a 32x32 watermark needs 1,024"):
        _encode(1500, img, mode="paper")
    _encode(1474, img, mode="paper")  # exactly enough
    with pytest.raises(wm.CapacityError, match=r"leaves \d+ of 2,498 splits; a 32x32 watermark needs"):
        _encode(0.99, img)


def test_a_split_index_past_the_stream_is_a_capacity_error_and_writes_nothing(tmp_path):
    """An embed_from index past the splits the mesh simplifies to (known only then: checked_options takes any
    index >= 0) raised a bare ValueError out of pmwm_codec.encode, which no ``except PmwError`` caught."""
    out = tmp_path / "m.pmw"
    with pytest.raises(wm.CapacityError, match=r"embed_from 1,000,000 is outside the stream's 2,498 vertex splits: "
                                               r"start earlier") as info:
        pmwm_codec.encode(MESH, out, watermark=_image(8), embed_from=10 ** 6, measure="none")
    assert isinstance(info.value, pmwm_codec.PmwError)
    assert list(tmp_path.iterdir()) == []


def test_start_index_accepts_indices_and_fractions_only():
    assert wm.start_index(0.5, 101) == 50
    assert wm.start_index(7, 10) == 7
    for bad in (11, -1, 1.0, -0.1, True, "x", float("nan")):
        with pytest.raises(ValueError):
            wm.start_index(bad, 10)


def test_params_with_a_start_past_the_vertex_limit_are_refused():
    from pmwm_codec.errors import FormatError

    cfg = {"mode": "paper", "bits": 12, "scale": 1.0, "width": 4, "height": 4, "levels": 2, "codes": 16,
           "carriers": 100, "embedFrom": -1}
    with pytest.raises(FormatError):
        wm.WatermarkParams.from_config(cfg)
    cfg["embedFrom"] = 5
    assert wm.WatermarkParams.from_config(cfg).get_config()["embedFrom"] == 5


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("embed-from")
    write_mesh(d / "sphere.obj", MESH)
    Image.fromarray(_image(32)).save(d / "mark.png")
    return d


def _run(capsys, *argv):
    code = main([os.fspath(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_cli_refuses_a_late_start_in_one_line_with_the_numbers(files, capsys):
    out = files / "late.pmw"
    code, _, err = _run(capsys, "encode", files / "sphere.obj", "-o", out, "--watermark", files / "mark.png",
                        "--mode", "paper", "--embed-from", "2000")
    assert code == 2
    assert err.count("\n") == 1 and err.startswith("pmw: error: ")
    assert "leaves 498 of 2,498 splits" in err and "needs 1,024" in err
    assert not out.exists() and not (files / "late.pmw.key.json").exists()


@pytest.mark.parametrize("text", ["1.5", "-3", "abc", "nan", "99999"])
def test_cli_refuses_a_malformed_start(files, capsys, text):
    code, _, err = _run(capsys, "encode", files / "sphere.obj", "-o", files / "bad.pmw",
                        "--watermark", files / "mark.png", "--embed-from", text)
    assert code == 2
    assert err.startswith("pmw: error: ") or "usage" in err
    assert "Traceback" not in err


def test_cli_file_with_a_start_verifies_with_no_option(files, capsys):
    out = files / "quarter.pmw"
    code, _, err = _run(capsys, "encode", files / "sphere.obj", "-o", out, "--watermark", files / "mark.png",
                        "--embed-from", "0.25", "--quiet")
    assert code == 0, err
    code, stdout, err = _run(capsys, "verify", out, "--key", f"{out}.key.json", "--watermark", files / "mark.png")
    assert code == 0, err


def test_fit_shrinks_a_watermark_to_what_the_splits_after_the_start_carry(tmp_path, capsys):
    """``--fit`` with ``--embed-from``: the capacity error named no size, so ``--fit`` did nothing; it
    now names the largest image the splits after the start carry, and ``--fit`` encodes it."""
    src = tmp_path / "m.ply"
    write_mesh(src, MESH)
    img = tmp_path / "w.png"
    Image.fromarray(_image(64)).save(img)
    out = tmp_path / "m.pmw"
    argv = ["encode", str(src), "-o", str(out), "--watermark", str(img), "--embed-from", "0.5", "-q"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    named = re.search(r"the largest that fits from there is (\d+)x\1", err)
    assert "embedding from vertex split" in err and named and int(named.group(1)) < 64
    assert not out.exists()
    assert main(argv + ["--fit", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["watermark"]["width"] == int(named.group(1)) and any("--fit" in n for n in report["notices"])
    assert main(["verify", str(out), "--key", str(out) + ".key.json", "-q"]) == 0
