"""Embedding and extraction: bit-exact recovery, paper mode, progressive quality, invariance, wrong keys."""

from __future__ import annotations

import io

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec.errors import FormatError
from pmwm_codec import shapes
from pmwm_codec.stream import StreamDecoder, encode_mesh
from pmwm_codec.verify.mesh import Reference, read_given
from pmwm_codec.watermark import codec as wm
from pmwm_codec.watermark.key import WatermarkKey
from pmwm_codec.watermark.verify import verdict

from conftest import corpus_path, watermark_path


def gradient_watermark(size=32):
    """A smooth, non-constant test image with a few shapes."""
    y, x = np.mgrid[0:size, 0:size]
    img = 40 + 150 * (x / size) + 40 * np.sin(y / 3.0)
    img[size // 4 : size // 2, size // 4 : 3 * size // 4] = 230
    return np.clip(img, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def marked():
    mesh = shapes.icosphere(5, 1.0, noise=0.01)  # ~10k vertices
    key = WatermarkKey.generate(rng=np.random.default_rng(7))
    image = gradient_watermark(32)
    buf = io.BytesIO()
    encoded = encode_mesh(mesh, buf, watermark=image, key=key, measure=True)
    key, report = encoded.key, encoded.as_json()  # the key of the file (params, reference)
    return mesh, image, key, buf.getvalue(), report


def decode_all(data, key, reference=None, check_key=True):
    dec = StreamDecoder(key, reference, check_key=check_key, copy=False)
    results = dec.feed(data)
    dec.close()
    return results, dec


def test_exact_mode_recovers_the_watermark_bit_exactly_after_the_file_round_trip(marked):
    mesh, image, key, data, report = marked
    results, dec = decode_all(data, key)
    assert np.array_equal(results[-1].watermark, image)
    assert results[-1].psnr_db == np.inf and results[-1].nc == pytest.approx(1.0)
    assert dec.verifier.verdict() == "authentic"
    assert report["watermark"]["embedded"] == report["watermark"]["carriers"]


def test_the_partial_watermark_never_gets_worse_from_one_chunk_to_the_next(marked):
    _, image, key, data, _ = marked
    results, _ = decode_all(data, key)
    psnrs = [r.psnr_db for r in results]
    assert all(b >= a - 1e-9 for a, b in zip(psnrs, psnrs[1:]))
    coeffs = [r.coefficients for r in results]
    assert coeffs == sorted(coeffs) and coeffs[-1] == image.size


def test_paper_mode_carries_one_code_per_split_and_reads_them_back(marked):
    mesh, image, key, _, _ = marked
    buf = io.BytesIO()
    report = encode_mesh(mesh, buf, watermark=image, key=key, mode="paper", bits=12, measure=False).as_json()
    results, dec = decode_all(buf.getvalue(), key)
    assert report["watermark"]["mode"] == "paper" and report["watermark"]["bits"] == 12
    assert results[-1].psnr_db > 40.0
    assert dec.verifier.verdict() == "authentic"


def test_a_similarity_transform_of_the_decoded_mesh_yields_the_same_codes(marked):
    _, image, key, data, _ = marked
    decoded = pmwm_codec.decode(data).positions
    rng = np.random.default_rng(3)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    moved = 3.7 * decoded @ q.T + np.array([10.0, -4.0, 2.5])
    plain = read_given(Reference.read(data), decoded, key)
    transformed = read_given(Reference.read(data), moved, key)
    assert np.array_equal(plain.extractor.received, transformed.extractor.received)
    assert transformed.verdict() == "authentic"
    img, _ = transformed.extractor.image()
    assert np.array_equal(img, image)
    # float32 storage does not disturb it either, even placed a few times its size away, where float32
    # rounding (~0.05 grid steps) moves some ring descriptor values across a bin boundary: those are
    # read both ways (the binding's ambiguous readings), so every carrier reads its code among its
    # readings, and the verdict and the image (which take the agreeing reading) stay
    far = moved + np.array([30.0, -12.0, 7.5])
    for placed in (moved, far):
        stored = read_given(Reference.read(data), placed.astype(np.float32), key)
        readings = stored.extractor.alternates
        assert (readings == plain.extractor.received[:, None]).any(axis=1).all()
        assert stored.verdict() == "authentic"
        assert stored.estimate().bit_exact


def test_wrong_keys_are_not_authentic_and_correlate_near_zero(marked):
    _, image, key, data, _ = marked
    verdicts, cnc = [], []
    for seed in range(60):
        other = WatermarkKey.generate(rng=np.random.default_rng(1000 + seed))
        results, dec = decode_all(data, other, reference=image, check_key=False)
        verdicts.append(dec.verifier.verdict())
        cnc.append(results[-1].centered_nc)
    assert verdicts.count("authentic") == 0
    # a wrong key decodes noise whose few low-frequency coefficients dominate the picture, so single
    # correlations spread widely (about +-0.3); their mean over 60 keys must sit near zero
    assert abs(float(np.mean(cnc))) < 0.15


def test_an_unmarked_mesh_is_not_authentic(marked):
    mesh, image, key, data, _ = marked
    unmarked = io.BytesIO()
    encode_mesh(mesh, unmarked, measure=False)
    plain = pmwm_codec.decode(unmarked.getvalue()).positions
    # read the unmarked geometry through the marked file's connectivity and parameters
    marked_positions = pmwm_codec.decode(data).positions
    # the two decodes share vertex order only if the streams agree; map by position instead
    order = np.lexsort(marked_positions.T[::-1])
    order_plain = np.lexsort(plain.T[::-1])
    assert len(order) == len(order_plain)
    candidate = np.empty_like(plain)
    candidate[order] = plain[order_plain]
    v = read_given(Reference.read(data), candidate, key)
    assert v.verdict() != "authentic"


def test_the_verdict_rule_on_hand_counts():
    assert verdict(100, 100, 5) == "authentic"
    assert verdict(3, 100, 5) == "not-authentic"
    assert verdict(10, 10, 5) == "inconclusive"  # too few codes
    assert verdict(50, 100, 5) == "tampered"  # the mark is there, half of it no longer reads
    assert verdict(100, 100, 5, mismatched=1) == "tampered"  # one carrier inconsistent under every ring reading
    assert verdict(100, 100, 5, foreign=True) == "tampered"  # a graft: vertices the reference does not explain
    assert verdict(100, 100, 5, bound=False) == "inconclusive"  # a legacy mark can be transplanted: never authentic


def test_a_key_of_another_file_is_refused(marked):
    _, _, _, data, _ = marked
    from pmwm_codec.errors import WatermarkKeyError

    with pytest.raises(WatermarkKeyError):
        decode_all(data, WatermarkKey.generate(rng=np.random.default_rng(99)))


def test_capacity_error_names_the_sizes():
    key = WatermarkKey.generate(rng=np.random.default_rng(1))
    with pytest.raises(wm.CapacityError, match="vertex splits"):
        wm.plan(gradient_watermark(64), key, carriers=100)


def test_codes_land_in_their_bins_on_the_grid():
    rng = np.random.default_rng(5)
    centroid = rng.uniform(-50, 50, (500, 3))
    target = np.rint(centroid + rng.normal(0, 30, (500, 3))).astype(np.int64)
    codes = rng.integers(0, 32, 500)
    pts, ok = wm.place_codes(target, centroid, codes, nbar=40.0, scale=20.0, bits=5)
    assert ok.all()
    assert np.array_equal(wm.read_codes(pts, centroid, 40.0, 20.0, 5), codes)


@pytest.mark.corpus
def test_bunny_carries_the_camera_watermark_bit_exactly_at_70_db():
    bunny = corpus_path("stanford-bunny.obj")
    camera = watermark_path("camera128.png")
    buf = io.BytesIO()
    key = WatermarkKey.generate(rng=np.random.default_rng(11))
    report = pmwm_codec.encode(bunny, buf, watermark=camera, key=key)
    assert report["distortion"]["psnr_db"] >= 70.0
    results = list(pmwm_codec.iter_decode(buf.getvalue(), key=key, watermark=camera))
    assert results[-1].psnr_db == np.inf
    half = len(buf.getvalue()) / 2
    assert [r for r in results if r.bytes_read >= half][0].psnr_db >= 25.0


@pytest.mark.parametrize("field, value", [("scale", 10**400), ("scale", "x"), ("height", 10**400),
                                          ("width", float("inf")), ("bits", None)])
def test_watermark_parameters_no_number_can_hold_are_a_format_error(field, value):
    image = np.random.default_rng(0).integers(0, 256, (8, 8)).astype(np.uint8)
    params, _ = wm.plan(image, WatermarkKey.generate(rng=np.random.default_rng(1)), 500)
    with pytest.raises(FormatError):
        wm.WatermarkParams.from_config({**params.get_config(), field: value})


def test_an_all_black_watermark_verifies_authentic_with_its_own_key(tmp_path):
    """An image of zeros packs to a message of one bit; before, it packed to none and the file
    written was refused by its own verify ("bit layout ... does not match")."""
    out = tmp_path / "black.pmw"
    pmwm_codec.encode(shapes.icosphere(4, 1.0, noise=0.05), out, watermark=np.zeros((16, 16), np.uint8))
    result = pmwm_codec.verify_stream(out, str(out) + ".key.json")
    assert result.verdict == "authentic"
    assert not result.results[-1].watermark.any()
