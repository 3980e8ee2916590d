"""Keys, output files and failures at any moment: what the encoder leaves on disk.

The encoder runs as ``python -m pmwm_codec encode`` from the repository root; faults are
injected with the test hook ``PMWM_FAULT=<point>:<SIGNAL>`` (pmwm_codec.atomic.fault_point)
or with a file size limit (RLIMIT_FSIZE: writes fail with EFBIG, as on a full disk).
"""

from __future__ import annotations

import dataclasses
import json
import os
import resource
import signal
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.distortion import mesh_distortion, vertex_distortion
from pmwm_codec.mesh import Mesh
from pmwm_codec.meshio import write_mesh
from pmwm_codec.errors import OptionError, WatermarkKeyError
from pmwm_codec.watermark.key import WatermarkKey

ROOT = Path(__file__).resolve().parents[1]


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (16, 16)).astype(np.uint8)


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("inputs")
    write_mesh(d / "a.ply", shapes.icosphere(4, noise=0.01, seed=1))
    write_mesh(d / "b.ply", shapes.torus(60, 30))
    Image.fromarray(_image(1)).save(d / "w1.png")
    Image.fromarray(_image(2)).save(d / "w2.png")
    return d


def pmw(*args, env=None, preexec_fn=None):
    full_env = {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}
    return subprocess.run([sys.executable, "-m", "pmwm_codec", *map(str, args)], cwd=ROOT, env=full_env,
                          capture_output=True, text=True, timeout=300, preexec_fn=preexec_fn)


def encode(inputs, out, image="w1.png", *extra, **kw):
    return pmw("encode", inputs / "a.ply", "-o", out, "--watermark", inputs / image, "--quiet", *extra, **kw)


def verdict(path, key) -> tuple:
    r = pmw("verify", path, "--key", key, "--json")
    return r.returncode, (json.loads(r.stdout)["verdict"] if r.stdout else r.stderr)


def mode(path) -> int:
    return stat.S_IMODE(os.lstat(path).st_mode)


def one_error_line(r) -> bool:
    return r.returncode == 2 and r.stderr.startswith("pmw: error:") and r.stderr.count("\n") == 1


# --- keys --------------------------------------------------------------------------------


def test_new_key_is_0600_and_replaces_a_0644_file_with_a_0600_one(tmp_path):
    path = tmp_path / "k.json"
    path.write_text("old")
    os.chmod(path, 0o644)
    WatermarkKey.generate().save(path)
    assert mode(path) == 0o600 and WatermarkKey.load(path)


def test_key_save_refuses_a_symlink_and_leaves_its_target(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    (tmp_path / "k.json").symlink_to(victim)
    with pytest.raises(pmwm_codec.PmwError, match="symbolic link"):
        WatermarkKey.generate().save(tmp_path / "k.json")
    assert victim.read_text() == "precious"


@pytest.mark.parametrize("explicit", [True, False], ids=["--key", "default path"])
def test_encode_refuses_a_key_path_that_is_a_symlink(inputs, tmp_path, explicit):
    victim = tmp_path / "victim.txt"
    victim.write_text("precious")
    key = tmp_path / ("k.json" if explicit else "o.pmw.key.json")
    key.symlink_to(victim)
    r = encode(inputs, tmp_path / "o.pmw", "w1.png", *(["--key", key] if explicit else []))
    assert one_error_line(r) and "symbolic link" in r.stderr
    assert victim.read_text() == "precious" and key.is_symlink() and not (tmp_path / "o.pmw").exists()


def test_a_key_reused_for_a_second_asset_keeps_the_first_verifying(inputs, tmp_path):
    key = tmp_path / "owner.key.json"
    assert encode(inputs, tmp_path / "a.pmw", "w1.png", "--key", key).returncode == 0
    first = key.read_bytes()
    r = pmw("encode", inputs / "b.ply", "-o", tmp_path / "b.pmw", "--watermark", inputs / "w1.png", "--key", key,
            "--quiet")
    assert r.returncode == 0 and key.read_bytes() == first  # reused as it is
    assert verdict(tmp_path / "a.pmw", key) == (0, "authentic")
    assert verdict(tmp_path / "b.pmw", key) == (0, "authentic")


@pytest.mark.parametrize("explicit", [True, False], ids=["--key", "default path"])
def test_a_key_of_another_watermark_is_refused_and_left_untouched(inputs, tmp_path, explicit):
    out = tmp_path / "a.pmw"
    key = tmp_path / "k.json" if explicit else tmp_path / "a.pmw.key.json"
    args = ["--key", key] if explicit else []
    assert encode(inputs, out, "w1.png", *args).returncode == 0
    before = (out.read_bytes(), key.read_bytes())
    r = encode(inputs, out, "w2.png", *args)
    assert one_error_line(r) and "another watermark" in r.stderr
    assert (out.read_bytes(), key.read_bytes()) == before
    assert verdict(out, key) == (0, "authentic")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([out.name, key.name])


def test_a_reused_0644_key_is_tightened_to_0600(inputs, tmp_path):
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert encode(inputs, out).returncode == 0
    os.chmod(key, 0o644)
    assert encode(inputs, out).returncode == 0 and mode(key) == 0o600


@pytest.mark.parametrize("before, after", [(0o400, 0o400), (0o640, 0o600), (0o604, 0o600)])
def test_a_reused_key_is_never_loosened(inputs, tmp_path, before, after):
    """Only group/other bits are cleared: a key its owner made read-only stays read-only."""
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert encode(inputs, out).returncode == 0
    os.chmod(key, before)
    content = key.read_bytes()
    assert encode(inputs, out).returncode == 0
    assert mode(key) == after and key.read_bytes() == content
    os.chmod(key, before)
    pmwm_codec.encode(inputs / "b.ply", tmp_path / "b.pmw", watermark=inputs / "w1.png", key=key)
    assert mode(key) == after and key.read_bytes() == content


def test_a_key_named_without_a_watermark_marks_with_its_own_image_and_owner_id(capsys, inputs, tmp_path):
    """``pmw encode IN -o OUT --key K`` without ``--watermark`` wrote an unmarked file (a note said the key was
    ignored) where its user asked for their mark: one key now marks every asset alike, with the image it holds
    and its owner ID (the same bytes as naming the image), as ``pmw batch encode --key`` does."""
    key = tmp_path / "k.json"
    assert encode(inputs, tmp_path / "a.pmw", "w1.png", "--key", key).returncode == 0
    first = key.read_bytes()
    status, err = _cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "again.pmw", "-q", "--key", key)
    assert status == 0 and not [line for line in err if "ignored" in line or "error" in line], err  # -q: notes only
    assert (tmp_path / "again.pmw").read_bytes() == (tmp_path / "a.pmw").read_bytes() and key.read_bytes() == first
    r = pmw("verify", tmp_path / "again.pmw", "--key", key, "--json")
    doc = json.loads(r.stdout)
    assert r.returncode == 0 and doc["verdict"] == "authentic" and doc["owner"]["verdict"] == "present"
    report = pmwm_codec.encode(inputs / "a.ply", tmp_path / "lib.pmw", key=key, measure="none")  # the library alike
    assert report["watermark"] is not None and report["owner_id"] == WatermarkKey.load(key).owner_hex
    assert (tmp_path / "lib.pmw").read_bytes() == (tmp_path / "a.pmw").read_bytes()


def test_an_owner_key_named_alone_marks_its_owner_id(capsys, inputs, tmp_path):
    key = tmp_path / "owner.json"
    assert pmw("encode", inputs / "a.ply", "-o", tmp_path / "o.pmw", "--owner-id", "c0ffee", "--key", key,
               "-q").returncode == 0
    status, err = _cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "o2.pmw", "-q", "--key", key)
    assert status == 0 and not [line for line in err if "ignored" in line or "error" in line], err  # -q: notes only
    assert (tmp_path / "o2.pmw").read_bytes() == (tmp_path / "o.pmw").read_bytes()
    r = pmw("verify", tmp_path / "o2.pmw", "--key", key, "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["owner"]["id"] == "0000000000c0ffee"


def test_a_key_named_without_a_mark_to_make_it_with_is_refused_and_nothing_is_written(capsys, inputs, tmp_path):
    """A missing key file named without --watermark or --owner-id (a mistyped path, most likely) is refused:
    never an unmarked file, never a new random key the user did not ask for; a key holding neither an image
    nor an owner ID is refused too (nothing to mark with)."""
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "x.pmw", "--key", tmp_path / "typo.json"),
             "typo.json: no such key file", "--owner-id")
    bare = dataclasses.replace(WatermarkKey.generate(), owner_id=None)
    with pytest.raises(WatermarkKeyError, match="nothing to mark with"):
        pmwm_codec.encode(inputs / "a.ply", tmp_path / "x.pmw", key=bare, measure="none")
    assert list(tmp_path.iterdir()) == []


def test_no_owner_with_a_key_that_would_then_mark_nothing_is_refused(capsys, inputs, tmp_path):
    """``--no-owner`` with a missing key, or with a key of the owner layer alone, wrote an unmarked file (exit 0)."""
    owner = tmp_path / "owner.json"
    assert pmw("encode", inputs / "a.ply", "-o", tmp_path / "o.pmw", "--owner-id", "7", "--key", owner,
               "-q").returncode == 0
    before = sorted(p.name for p in tmp_path.iterdir())
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "x.pmw", "--no-owner", "--key",
                   tmp_path / "missing.json"), "missing.json: no such key file")
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "x.pmw", "--no-owner", "--key", owner),
             "owner.json: the key holds no watermark image", "nothing would be marked")
    with pytest.raises(WatermarkKeyError, match="no such key file"):
        pmwm_codec.encode(inputs / "a.ply", tmp_path / "x.pmw", key=tmp_path / "missing.json", owner_id=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_a_key_whose_image_does_not_fit_is_refused_and_fit_does_not_shrink_it(capsys, inputs, tmp_path):
    """--fit shrinks a watermark given as an image; the one a key holds is its mark, never another size.  The key's
    name is no format field (a name with braces crashed the message: KeyError)."""
    key = tmp_path / "k{x}.json"
    assert encode(inputs, tmp_path / "a.pmw", "w1.png", "--key", key).returncode == 0
    small = tmp_path / "small.ply"
    write_mesh(small, shapes.icosphere(2))  # 162 vertices: 98 splits, too few for a 16x16 image
    before = sorted(p.name for p in tmp_path.iterdir())
    for extra in ([], ["--fit"]):
        _refused(*_cli(capsys, "encode", small, "-o", tmp_path / "s.pmw", "--key", key, *extra), "k{x}.json: a 16x16 "
                 "watermark needs", "a key marks with its own image only, never shrunk")
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_re_encoding_with_the_default_key_gives_the_same_bytes(inputs, tmp_path):
    out = tmp_path / "a.pmw"
    assert encode(inputs, out).returncode == 0
    first = out.read_bytes()
    assert encode(inputs, out).returncode == 0 and out.read_bytes() == first


# --- wrong key -------------------------------------------------------------------------


def test_a_key_of_another_file_gives_not_authentic_and_exit_1(inputs, tmp_path):
    out = tmp_path / "a.pmw"
    assert encode(inputs, out).returncode == 0
    foreign = tmp_path / "foreign.json"
    WatermarkKey.generate(reference=_image(1)).save(foreign)
    r = pmw("verify", out, "--key", foreign, "--json")
    doc = json.loads(r.stdout)
    assert r.returncode == 1 and doc["verdict"] == "not-authentic" and doc["key_matches"] is False
    assert pmw("decode", out, "-o", tmp_path / "d.ply").returncode == 0
    r = pmw("verify", tmp_path / "d.ply", "--reference", out, "--key", foreign, "--json")
    doc = json.loads(r.stdout)
    assert r.returncode == 1 and doc["verdict"] == "not-authentic" and doc["key_matches"] is False
    r = pmw("verify", tmp_path / "d.ply", "--reference", out, "--key", tmp_path / "a.pmw.key.json", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["key_matches"] is True


# --- file modes ------------------------------------------------------------------------


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_pmw_and_decoded_files_honour_the_umask_and_keys_stay_0600(inputs, tmp_path, umask):
    out = tmp_path / "a.pmw"

    def set_umask():
        os.umask(umask)

    assert encode(inputs, out, preexec_fn=set_umask).returncode == 0
    assert mode(out) == 0o666 & ~umask and mode(tmp_path / "a.pmw.key.json") == 0o600
    for suffix in (".glb", ".obj", ".ply", ".stl"):
        assert pmw("decode", out, "-o", tmp_path / f"d{suffix}", preexec_fn=set_umask).returncode == 0
        assert mode(tmp_path / f"d{suffix}") == 0o666 & ~umask


# --- failures at any moment ----------------------------------------------------------------


def _no_temp_files(directory: Path) -> bool:
    return not [p.name for p in directory.iterdir() if p.name.startswith(".")]


def _pair_is_whole(out: Path, key: Path) -> bool:
    """A .pmw, if any, verifies with the key beside it."""
    return not out.exists() or (key.exists() and verdict(out, key) == (0, "authentic"))


@pytest.mark.parametrize("point", ["measured", "stage-written", "staged", "key-published", "published"])
def test_sigkill_at_any_point_never_leaves_a_marked_file_without_its_key(inputs, tmp_path, point):
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    r = encode(inputs, out, env={"PMWM_FAULT": f"{point}:KILL"})
    assert r.returncode == -9
    assert _no_temp_files(tmp_path) and _pair_is_whole(out, key)
    assert out.exists() == (point == "published")


@pytest.mark.parametrize("point", ["stage-written", "staged", "key-published", "published"])
def test_sigkill_during_a_re_encode_keeps_the_old_pair_or_the_new(inputs, tmp_path, point):
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert encode(inputs, out).returncode == 0
    old_key = key.read_bytes()
    r = encode(inputs, out, "w1.png", "--base-vertices", "80", env={"PMWM_FAULT": f"{point}:KILL"})
    assert r.returncode == -9 and key.read_bytes() == old_key
    assert _no_temp_files(tmp_path) and _pair_is_whole(out, key)


@pytest.mark.parametrize("sig", ["INT", "TERM"])
def test_sigint_sigterm_while_publishing_are_held_until_the_pair_is_whole(inputs, tmp_path, sig):
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    # the child starts with the signal's default disposition: a shell's background job inherits SIGINT ignored,
    # and an ignored signal rightly stays ignored (exit 0) -- the suite must not depend on how it was started
    r = encode(inputs, out, env={"PMWM_FAULT": f"staged:{sig}"},
               preexec_fn=lambda: signal.signal(getattr(signal, "SIG" + sig), signal.SIG_DFL))
    assert r.returncode != 0  # the signal arrives, after the pair is published
    assert out.exists() and key.exists() and _no_temp_files(tmp_path) and _pair_is_whole(out, key)


@pytest.mark.parametrize("point", ["measured", "stage-written", "staged"])
def test_a_sigterm_ends_an_encode_with_one_terminated_line_and_status_143(inputs, tmp_path, point):
    # `timeout`, systemd and `docker stop` send SIGTERM: it stops an encode as a Ctrl-C does (what was being
    # written discarded, or the pair published whole first), said in one line, 143 as a shell reports it
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    r = encode(inputs, out, env={"PMWM_FAULT": f"{point}:TERM"},
               preexec_fn=lambda: signal.signal(signal.SIGTERM, signal.SIG_DFL))
    assert (r.returncode, r.stderr) == (143, "pmw: error: terminated\n")
    assert _no_temp_files(tmp_path) and _pair_is_whole(out, key)
    assert out.exists() == (point != "measured")  # once staging began, held back until the pair is whole


@pytest.mark.parametrize("limit", [1_000, 8_000], ids=["key write fails", "pmw write fails"])  # key ~2 KB, .pmw ~15 KB
def test_disk_full_leaves_nothing_and_exits_2(inputs, tmp_path, limit):
    out = tmp_path / "a.pmw"

    def small_files():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    r = encode(inputs, out, preexec_fn=small_files)
    assert one_error_line(r)
    assert list(tmp_path.iterdir()) == []


def test_two_encodes_to_one_output_leave_a_matching_pair(inputs, tmp_path):
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    procs = [subprocess.Popen([sys.executable, "-m", "pmwm_codec", "encode", str(inputs / "a.ply"), "-o", str(out),
                               "--watermark", str(inputs / image), "--quiet"], cwd=ROOT, env=env,
                              stderr=subprocess.PIPE, text=True) for image in ("w1.png", "w2.png")]
    codes = sorted(p.wait(timeout=300) for p in procs)
    assert codes in ([0, 2], [0, 0])  # the second to reach the files finds another key and refuses
    assert _no_temp_files(tmp_path) and verdict(out, key) == (0, "authentic")


# --- the distortion measurement --------------------------------------------------------------


def _cylinder(n: int) -> Mesh:
    """A closed cylinder: 2n + 2 vertices, long thin side triangles and two fans."""
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    ring = np.c_[np.cos(a), np.sin(a)]
    pos = np.r_[np.c_[ring, np.zeros(n)], np.c_[ring, np.ones(n)], [[0, 0, 0], [0, 0, 1]]]
    i = np.arange(n)
    j = (i + 1) % n
    faces = np.r_[np.c_[i, j, n + j], np.c_[i, n + j, n + i], np.c_[np.full(n, 2 * n), j, i],
                  np.c_[np.full(n, 2 * n + 1), n + i, n + j]]
    return Mesh(pos, faces)


def test_vertex_measure_is_exact_rms_and_bounds_the_sampled_hausdorff():
    m = _cylinder(64)
    moved = Mesh(m.positions + 1e-3 * np.random.default_rng(3).standard_normal(m.positions.shape), m.faces)
    fast, sampled = vertex_distortion(m, moved), mesh_distortion(m, moved)
    assert fast["rms"] == pytest.approx(sampled["rms"], rel=1e-12)
    assert fast["psnr_db"] == pytest.approx(sampled["psnr_db"], rel=1e-12)
    assert sampled["hausdorff"] <= fast["hausdorff"] + 1e-15
    worst = np.linalg.norm(moved.positions - m.positions, axis=1).max()
    assert fast["hausdorff"] == pytest.approx(worst / fast["bbox_diagonal"])


CYLINDER_CHILD = """
import numpy as np, resource, sys
sys.path.insert(0, {tests!r})
from test_keys_files import _cylinder
from pmwm_codec.distortion import mesh_distortion
from pmwm_codec.mesh import Mesh
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))
m = _cylinder(200)
moved = Mesh(m.positions + 1e-4 * np.random.default_rng(0).standard_normal(m.positions.shape), m.faces)
print(mesh_distortion(m, moved)["hausdorff"])
"""


def test_sampled_measure_of_a_closed_cylinder_stays_under_3_gib():
    code = CYLINDER_CHILD.format(tests=str(Path(__file__).parent))
    r = subprocess.run([sys.executable, "-c", code], cwd=ROOT, env={**os.environ, "PYTHONPATH": str(ROOT)},
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-500:]
    assert 0 < float(r.stdout) < 1e-3


def test_encode_json_distortion_keeps_its_fields_and_names_the_measure(inputs, tmp_path):
    for measure in ("vertices", "sampled", "none"):
        r = pmw("encode", inputs / "a.ply", "-o", tmp_path / f"{measure}.pmw", "--measure", measure, "--json")
        d = json.loads(r.stdout)["distortion"]
        assert {"rms", "psnr_db", "hausdorff", "bbox_diagonal"} <= set(d) and d["measure"] == measure
        assert (d["rms"] is None) == (measure == "none")


# --- no output replaces a key file, the input, or takes a name it cannot have ------------------


def _cli(capsys, *argv) -> tuple:
    """``pmw ARGV`` in process: ``(status, stderr lines)``."""
    from pmwm_codec.cli import main

    status = main([str(a) for a in argv])
    return status, capsys.readouterr().err.strip().splitlines()


def _refused(status, err, *words):
    assert status == 2 and len(err) == 1 and err[0].startswith("pmw: error: "), err
    assert all(w in err[0] for w in words), err


def test_a_key_named_like_the_output_is_refused_before_anything_is_written(capsys, inputs, tmp_path):
    """``--key y.pmw -o y.pmw`` used to write the key, rename the .pmw over it and exit 0: a marked
    file whose key no longer existed."""
    out = tmp_path / "y.pmw"
    status, err = _cli(capsys, "encode", inputs / "a.ply", "-o", out, "--key", out, "--watermark", inputs / "w1.png")
    _refused(status, err, "the key file would be the .pmw itself")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(WatermarkKeyError):
        pmwm_codec.encode(inputs / "a.ply", out, watermark=inputs / "w1.png", key=str(tmp_path / "." / "y.pmw"))
    assert list(tmp_path.iterdir()) == []


def test_no_output_replaces_a_key_file_by_its_name_or_its_contents(capsys, inputs, tmp_path):
    """encode, cut and decode outputs onto ``*.key.json`` or onto a file holding a key (any name):
    refused, the key byte-identical and still verifying its .pmw."""
    pmw_path = tmp_path / "p.pmw"
    assert encode(inputs, pmw_path).returncode == 0
    key = Path(str(pmw_path) + ".key.json")
    renamed = tmp_path / "k.json"
    renamed.write_bytes(key.read_bytes())
    glb_named = tmp_path / "k.glb"
    glb_named.write_bytes(key.read_bytes())
    before = key.read_bytes()
    for argv in (["encode", inputs / "a.ply", "-o", key],
                 ["encode", inputs / "a.ply", "-o", renamed],
                 ["cut", pmw_path, "--chunks", "2", "-o", key],
                 ["cut", pmw_path, "--chunks", "2", "-o", renamed],
                 ["decode", pmw_path, "-o", glb_named]):
        status, err = _cli(capsys, *argv)
        _refused(status, err, "key")
    assert key.read_bytes() == before and renamed.read_bytes() == before and glb_named.read_bytes() == before
    assert verdict(pmw_path, key) == (0, "authentic")


def test_cut_never_replaces_its_input_nor_names_a_glb_as_another_mesh_format(capsys, inputs, tmp_path):
    pmw_path = tmp_path / "p.pmw"
    assert encode(inputs, pmw_path).returncode == 0
    before = pmw_path.read_bytes()
    _refused(*_cli(capsys, "cut", pmw_path, "--chunks", "2", "-o", pmw_path), "is also the input")
    assert pmw_path.read_bytes() == before
    mesh_file = tmp_path / "m.obj"
    mesh_file.write_text("v 0 0 0\n")
    for name in ("m.obj", "x.ply", "x.stl", "x.gltf"):
        _refused(*_cli(capsys, "cut", pmw_path, "-o", tmp_path / name), "a .pmw is a GLB file")
    assert mesh_file.read_text() == "v 0 0 0\n" and not (tmp_path / "x.ply").exists()


def test_an_output_named_dash_is_refused_not_written_as_a_file(capsys, inputs, tmp_path, monkeypatch):
    pmw_path = tmp_path / "p.pmw"
    assert encode(inputs, pmw_path).returncode == 0
    monkeypatch.chdir(tmp_path)
    for argv in (["encode", inputs / "a.ply", "-o", "-"], ["cut", pmw_path, "-o", "-"]):
        _refused(*_cli(capsys, *argv), "standard output")
    assert not (tmp_path / "-").exists()


def test_a_failed_temporary_file_is_reported_under_the_name_asked_for(tmp_path, monkeypatch):
    """Where no temporary file can be made beside the target, the error names the target (it named
    a hidden ``.NAME.xxxx.tmp`` that never existed)."""
    import tempfile

    from pmwm_codec import atomic

    def refuse(*args, **kwargs):
        raise FileNotFoundError(2, "No such file or directory", str(tmp_path / ".x.pmw.abc.tmp"))

    monkeypatch.delattr(atomic.os, "O_TMPFILE", raising=False)  # the named temporary file's path
    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(OSError) as info:
        atomic.write_atomic(tmp_path / "x.pmw", [b"data"])
    assert info.value.filename == str(tmp_path / "x.pmw") and ".tmp" not in str(info.value)


def test_key_matches_is_null_for_a_file_without_a_watermark_image(capsys, inputs, tmp_path):
    """An owner-only .pmw holds no key fingerprint: ``key_matches`` is null (was true for any key)."""
    owner_only = tmp_path / "o.pmw"
    assert pmw("encode", inputs / "a.ply", "-o", owner_only, "--owner-id", "0123456789abcdef", "-q").returncode == 0
    other = tmp_path / "p.pmw"
    assert encode(inputs, other).returncode == 0
    for key in (Path(str(other) + ".key.json"), Path(str(owner_only) + ".key.json")):
        r = pmw("verify", owner_only, "--key", key, "--json")
        assert json.loads(r.stdout)["key_matches"] is None


@pytest.mark.parametrize("empty", ["", "  "])
def test_an_empty_key_path_is_refused_up_front(capsys, inputs, tmp_path, monkeypatch, empty):
    """``--key "$KEY"`` with KEY unset used to run the whole encode, then fail publishing the key, naming a
    hidden temporary file of the parent directory; the API raised a FileNotFoundError."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "o.pmw"
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", out, "--watermark", inputs / "w1.png", "--key", empty),
             "--key", "empty path")
    assert list(tmp_path.iterdir()) == []
    assert encode(inputs, out).returncode == 0
    _refused(*_cli(capsys, "verify", out, "--key", empty), "--key", "empty path")
    with pytest.raises((OptionError, WatermarkKeyError), match="empty"):  # as an output path, or as a key path
        pmwm_codec.encode(inputs / "a.ply", tmp_path / "p.pmw", watermark=inputs / "w1.png", key=empty)
    with pytest.raises(WatermarkKeyError, match="empty key path"):
        next(pmwm_codec.iter_decode(out, key=empty))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o.pmw", "o.pmw.key.json"]


def test_verify_refuses_a_key_whose_owner_id_was_edited(capsys, inputs, tmp_path):
    """It used to verify ``authentic``, exit 0, with the owner layer ``absent``: the edited ID was read for."""
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert encode(inputs, out).returncode == 0
    doc = json.loads(key.read_text())
    assert doc["owner_id"] is not None
    doc["owner_id"] = f"{int(doc['owner_id'], 16) ^ 1:016x}"
    edited = tmp_path / "edited.key.json"
    edited.write_text(json.dumps(doc))
    _refused(*_cli(capsys, "verify", out, "--key", edited), "edited.key.json", "not a valid watermark key", "checksum")
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "b.pmw", "--watermark", inputs / "w1.png",
                   "--key", edited), "checksum")
    assert not (tmp_path / "b.pmw").exists()


def test_an_unmarked_encode_never_leaves_a_key_beside_a_file_it_does_not_verify(capsys, inputs, tmp_path):
    """An encode without --watermark used to replace a marked ``a.pmw`` silently, its key left beside a file
    it no longer verified (one with another image is refused: so is this one)."""
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert encode(inputs, out).returncode == 0
    before = (out.read_bytes(), key.read_bytes())
    for extra in ([], ["--no-owner"]):
        _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", out, "-q", *extra), str(key), "writes no mark")
    # a key named without a mark to make it with: refused as such (it used to be ignored: no mark)
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", out, "-q", "--key", tmp_path / "other.key.json"),
             "other.key.json: no such key file")
    assert (out.read_bytes(), key.read_bytes()) == before and verdict(out, key) == (0, "authentic")
    out.unlink()  # a key alone: an unmarked a.pmw beside it would not verify either
    _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", out, "-q"), str(key))
    assert sorted(p.name for p in tmp_path.iterdir()) == [key.name]
    key.rename(tmp_path / "kept.json")  # the ways out the message names: the key moved away, or another name
    assert _cli(capsys, "encode", inputs / "a.ply", "-o", out, "-q")[0] == 0
    assert _cli(capsys, "encode", inputs / "a.ply", "-o", tmp_path / "plain.pmw", "-q")[0] == 0


def test_the_library_refuses_an_unmarked_encode_beside_a_key_as_the_command_line_does(tmp_path):
    """``pmwm_codec.encode(mesh, "a.pmw")`` without a mark replaced a marked ``a.pmw`` silently (the
    command line refused it), its key left beside a file it no longer verified."""
    import pmwm_codec
    from pmwm_codec import shapes
    from pmwm_codec.errors import WatermarkKeyError

    mesh, out = shapes.demo_mesh(60), tmp_path / "a.pmw"
    pmwm_codec.encode(mesh, out, owner_id=0x1234, measure="none")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert sorted(before) == ["a.pmw", "a.pmw.key.json"]
    with pytest.raises(WatermarkKeyError, match="writes no mark"):
        pmwm_codec.encode(mesh, out, measure="none")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
    pmwm_codec.encode(mesh, tmp_path / "b.pmw", measure="none")  # another name: no key beside it
    assert (tmp_path / "b.pmw").exists() and not (tmp_path / "b.pmw.key.json").exists()


def test_a_marked_encode_with_another_key_never_leaves_the_key_beside_a_file_it_does_not_verify(capsys, inputs,
                                                                                                  tmp_path):
    """``--key other.json -o a.pmw`` (a new key, or another existing one) replaced a marked ``a.pmw``, exit 0,
    leaving ``a.pmw.key.json`` beside a file it no longer verified (as an unmarked encode or one of another image
    would, and those are refused).  A copy of that key (the same secret) still verifies: it is taken."""
    out, key = tmp_path / "a.pmw", tmp_path / "a.pmw.key.json"
    assert encode(inputs, out).returncode == 0
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    assert pmw("encode", inputs / "b.ply", "-o", tmp_path / "o.pmw", "--watermark", inputs / "w1.png", "-q",
               "--key", tmp_path / "other.json").returncode == 0
    before["other.json"] = (tmp_path / "other.json").read_bytes()
    (tmp_path / "o.pmw").unlink()
    for named in ("new.json", "other.json"):
        _refused(*_cli(capsys, "encode", inputs / "a.ply", "-o", out, "-q", "--watermark", inputs / "w1.png",
                       "--key", tmp_path / named), str(key), "another key")
    with pytest.raises(WatermarkKeyError, match="another key"):
        pmwm_codec.encode(inputs / "a.ply", out, watermark=inputs / "w1.png", key=WatermarkKey.generate(),
                          measure="none")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before and verdict(out, key) == (0, "authentic")
    (tmp_path / "copy.json").write_bytes(key.read_bytes())
    assert encode(inputs, out, "w1.png", "--key", tmp_path / "copy.json").returncode == 0
    assert verdict(out, key) == (0, "authentic")
