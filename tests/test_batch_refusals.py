"""``pmw batch``: what a batch refuses up front (a key or keys folder where an input or an output is) and what
``pmw batch verify`` never reads (a file whose real path leaves the folder it names)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

import pmwm_codec
from pmwm_codec import shapes
from pmwm_codec.meshio import write_mesh

pytest.importorskip("distributed")

from pmwm_codec.batch import LEDGER_NAME, encode_batch, verify_batch  # noqa: E402
from pmwm_codec.batch.run import dask_client  # noqa: E402
from pmwm_codec.batch.tasks import verify_task  # noqa: E402
from pmwm_codec.cli import main  # noqa: E402

IMAGE = (np.indices((8, 8)).sum(0) % 2 * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def client():
    """One local Dask worker for the in-process runs of this module (a refused run never uses it)."""
    with dask_client(workers=1) as c:
        yield c


@pytest.fixture
def lib(tmp_path):
    """``tmp/lib/a.obj`` and ``tmp/wm.png``; returns ``tmp``."""
    from PIL import Image

    (tmp_path / "lib").mkdir()
    write_mesh(tmp_path / "lib" / "a.obj", shapes.icosphere(3, noise=0.01, seed=1))
    Image.fromarray(IMAGE).save(tmp_path / "wm.png")
    return tmp_path


def _tree(root: Path) -> dict:
    """Every path under ``root`` with its bytes (None for a folder): what a refused run must leave as it was."""
    return {p: (None if p.is_dir() else p.read_bytes()) for p in sorted(root.rglob("*"))}


def _one_line(capsys, *words) -> None:
    """One ``pmw: error:`` line on stderr naming ``words``, and nothing on stdout (not even with --json)."""
    out, err = capsys.readouterr()
    assert err.count("\n") == 1 and err.startswith("pmw: error:"), err
    for word in words:
        assert word in err, err
    assert out == "", out


# --- 09: a key or keys folder where an input or an output is: bad usage, nothing written --------------------------


def test_a_collection_key_named_as_an_output_is_refused_before_anything_is_written(lib, capsys):
    """``--key out/a.obj.pmw`` (the probe's 09): the run wrote a new collection key at the name of an output,
    then the asset failed (the .pmw would replace the key), exit 1.  ``pmw encode`` refuses the same clash up
    front; so does the batch now: exit 2, one line, no key, no OUT_DIR."""
    before = _tree(lib)
    out = lib / "out"
    assert main(["batch", "encode", str(lib / "lib"), "-o", str(out), "--workers", "1", "--watermark",
                 str(lib / "wm.png"), "--key", str(out / "a.obj.pmw"), "-q"]) == 2
    _one_line(capsys, str(out / "a.obj.pmw"), "output")
    assert not out.exists() and _tree(lib) == before


def test_a_keys_dir_that_is_an_existing_file_is_bad_usage_not_a_failed_asset(lib, capsys):
    """``--keys-dir lib/a.obj`` (an input, a file): every asset failed with ``File exists``, exit 1."""
    before = _tree(lib)
    out = lib / "out"
    assert main(["batch", "encode", str(lib / "lib"), "-o", str(out), "--workers", "1", "--watermark",
                 str(lib / "wm.png"), "--keys-dir", str(lib / "lib" / "a.obj"), "--json"]) == 2
    _one_line(capsys, str(lib / "lib" / "a.obj"), "not a folder")
    assert not out.exists() and _tree(lib) == before


@pytest.mark.parametrize("where, words", [
    ("out/a.obj.pmw", "output"),  # a key at an output's name: the .pmw would replace it (or it the .pmw)
    ("out/" + LEDGER_NAME, "ledger"),  # the ledger appended to a key file
    ("out/a.obj.pmw/k.key.json", "output"),  # inside a path that will be a .pmw, not a folder
    ("lib/a.obj", "input"),  # an input (refused before, but as "not a watermark key": now it says why)
    ("alias.key.json", "input"),  # a symlink to an input
])
def test_a_collection_key_at_an_input_an_output_or_the_ledger_is_refused_and_nothing_is_written(lib, client, where,
                                                                                                  words):
    os.symlink(lib / "lib" / "a.obj", lib / "alias.key.json")
    _refused_and_untouched(lib, client, words, key=lib / where)


@pytest.mark.parametrize("where, words", [
    ("lib/a.obj", "not a folder"),  # an existing file
    ("lib/a.obj/keys", "not a folder"),  # below an existing file: never made
    ("out/a.obj.pmw", "output"),  # the keys folder made where an output goes
    ("out/a.obj.pmw/keys", "output"),  # ... or below it
    ("out/" + LEDGER_NAME, "ledger"),
])
def test_a_keys_dir_that_is_a_file_or_lies_where_an_output_goes_is_refused_and_nothing_is_written(lib, client, where,
                                                                                                    words):
    _refused_and_untouched(lib, client, words, keys_dir=lib / where)


def _refused_and_untouched(lib, client, words, **place):
    """``encode_batch`` of ``lib`` with the key option ``place`` (``key=`` or ``keys_dir=``) is refused in one
    line naming the path and ``words``, and nothing on disk changed (no OUT_DIR, no key)."""
    (path,) = place.values()
    before = _tree(lib)
    with pytest.raises(pmwm_codec.PmwError) as caught:
        encode_batch(lib / "lib", lib / "out", watermark=lib / "wm.png", client=client, **place)
    message = str(caught.value)
    assert "\n" not in message and str(path) in message and words in message, message
    assert not (lib / "out").exists() and _tree(lib) == before


def test_a_new_collection_key_or_the_keys_inside_out_dir_are_still_fine(lib, client):
    """The refusals above leave the documented places alone: a new collection key inside OUT_DIR (made with
    it), and ``--keys-dir OUT_DIR`` (each key beside its output, as without it)."""
    out = lib / "out"
    assert encode_batch(lib / "lib", out, watermark=lib / "wm.png", key=out / "c.key.json", client=client)["ok"] == 1
    assert verify_batch(out, key=out / "c.key.json", client=client)["authentic"] == 1
    out2 = lib / "out2"
    assert encode_batch(lib / "lib", out2, watermark=lib / "wm.png", keys_dir=out2, client=client)["ok"] == 1
    assert (out2 / "a.obj.pmw.key.json").is_file()
    assert verify_batch(out2, client=client)["authentic"] == 1


def test_a_key_whose_folder_does_not_exist_leaves_no_output_folder(lib, capsys):
    """The key's folder missing: exit 2 in one line as before, and no longer an empty OUT_DIR left behind."""
    out = lib / "out"
    assert main(["batch", "encode", str(lib / "lib"), "-o", str(out), "--workers", "1", "--watermark",
                 str(lib / "wm.png"), "--key", str(out / "nosub" / "k.key.json")]) == 2
    _one_line(capsys, "nosub")
    assert not out.exists()


# --- 10: batch verify never reads a file whose real path leaves the folder it names -----------------------------


@pytest.fixture
def published(tmp_path):
    """``published/`` holding a good file, an alias inside it, and links planted to a file outside it."""
    mesh = tmp_path / "m.obj"
    write_mesh(mesh, shapes.icosphere(3, noise=0.01, seed=2))
    elsewhere, pub = tmp_path / "elsewhere", tmp_path / "published"
    elsewhere.mkdir()
    pub.mkdir()
    pmwm_codec.encode(mesh, elsewhere / "real.pmw", watermark=IMAGE, measure="none")
    pmwm_codec.encode(mesh, pub / "good.pmw", watermark=IMAGE, measure="none")
    (pub / "planted.pmw").symlink_to("../elsewhere/real.pmw")  # the probe's 10: both the file and its key
    (pub / "planted.pmw.key.json").symlink_to("../elsewhere/real.pmw.key.json")
    (pub / "own.pmw").write_bytes((elsewhere / "real.pmw").read_bytes())  # the file inside, its key outside
    (pub / "own.pmw.key.json").symlink_to("../elsewhere/real.pmw.key.json")
    (pub / "alias.pmw").symlink_to("good.pmw")  # links that stay inside: verified
    (pub / "alias.pmw.key.json").symlink_to("good.pmw.key.json")
    (pub / "linked").symlink_to("../elsewhere", target_is_directory=True)  # a symlinked folder: not entered
    return tmp_path


def test_batch_verify_refuses_a_file_or_key_whose_real_path_leaves_the_folder(published, capsys):
    """``pmw batch verify published/`` followed ``planted.pmw -> ../elsewhere/real.pmw`` (and its key) and
    answered ``authentic``, exit 0: a verdict on a file outside the folder named.  Now each such file is an
    ``error`` result that says its real path leaves the folder, exit 1; links inside the folder still verify."""
    pub = published / "published"
    assert main(["batch", "verify", str(pub), "--workers", "1", "--json"]) == 1
    doc = json.loads(capsys.readouterr().out)
    results = {Path(r["file"]).name: r for r in doc["results"]}
    assert sorted(results) == ["alias.pmw", "good.pmw", "own.pmw", "planted.pmw"]  # not linked/real.pmw
    assert results["good.pmw"]["verdict"] == results["alias.pmw"]["verdict"] == "authentic"
    for name, target in (("planted.pmw", "real.pmw"), ("own.pmw", "real.pmw.key.json")):
        r = results[name]
        assert r["verdict"] == "error" and "outside" in r["error"] and str(pub) in r["error"], r
        assert str(published / "elsewhere" / target) in r["error"], r
    assert doc["authentic"] == 2 and doc["files"] == 4


def test_batch_verify_refuses_a_key_under_keys_dir_whose_real_path_leaves_it(published, client):
    """``--keys-dir`` names a folder too: a key there that is a link out of it is not read; ``--key`` names
    one file, which is followed as named (as a manifest's entries are for encode)."""
    pub, keys = published / "published", published / "keys"
    keys.mkdir()
    (keys / "good.pmw.key.json").symlink_to(pub / "good.pmw.key.json")  # outside keys/: refused
    (pub / "planted.pmw").unlink()
    (pub / "own.pmw").unlink()
    (pub / "alias.pmw").unlink()
    doc = verify_batch(pub, keys_dir=keys, client=client)
    (r,) = doc["results"]
    assert r["verdict"] == "error" and "outside" in r["error"] and str(keys) in r["error"], r
    link = published / "collection.key.json"
    link.symlink_to(pub / "good.pmw.key.json")
    assert verify_batch(pub, key=link, client=client)["authentic"] == 1


def test_the_verify_task_checks_the_real_paths_itself_so_a_link_planted_after_listing_is_refused(published):
    pub = published / "published"
    r = verify_task(str(pub / "planted.pmw"), str(pub / "planted.pmw.key.json"), None, str(pub))
    assert r["verdict"] == "error" and "outside" in r["error"]
    alias = verify_task(str(pub / "alias.pmw"), str(pub / "alias.pmw.key.json"), None, str(pub))
    assert alias["verdict"] == "authentic"


# --- an OUT_DIR that is not a folder: named as such (it was named as its ledger's path, "Not a directory") -------


@pytest.mark.parametrize("where", ["file", "below a file", "device"])
def test_an_out_dir_that_is_not_a_folder_is_named_as_such_and_nothing_is_made(lib, capsys, where):
    mesh = lib / "lib" / "a.obj"
    out = {"file": mesh, "below a file": mesh / "out", "device": Path("/dev/null")}[where]
    before = _tree(lib)
    status = main(["batch", "encode", str(lib / "lib"), "-o", str(out), "--watermark", str(lib / "wm.png"),
                   "--workers", "1", "-q"])
    assert status == 2
    if where == "below a file":
        _one_line(capsys, f"pmw: error: {out}: cannot be made: {mesh} is not a folder")
    else:
        _one_line(capsys, f"pmw: error: {out}: exists and is not a folder; -o names the folder the outputs go in")
    assert _tree(lib) == before


@pytest.mark.parametrize("command", ["encode", "verify"])
def test_an_empty_out_dir_is_refused_not_taken_for_the_current_folder(lib, capsys, monkeypatch, command):
    """``-o ''`` (an unset variable in ``-o $OUT``) was the current folder: the outputs, keys and ledger went there."""
    monkeypatch.chdir(lib)
    before = _tree(lib)
    argv = ["batch", "encode", "lib", "-o", "", "--watermark", "wm.png", "--workers", "1", "-q"] \
        if command == "encode" else ["batch", "verify", " ", "--workers", "1", "-q"]
    assert main(argv) == 2
    _one_line(capsys, "an empty path", "names no folder")
    assert _tree(lib) == before


def test_an_empty_src_is_named_as_empty(lib, capsys, monkeypatch):
    monkeypatch.chdir(lib)
    before = _tree(lib)
    assert main(["batch", "encode", "", "-o", "out", "--workers", "1", "-q"]) == 2
    _one_line(capsys, "pmw: error: an empty SRC ('') names no folder, file or glob (an unset variable?)")
    assert _tree(lib) == before


# --- batch verify: an expected watermark image or a --keys-dir that cannot be used is bad usage --------------------


@pytest.mark.parametrize("option", ["--watermark", "--keys-dir"])
def test_batch_verify_with_a_watermark_or_keys_dir_that_does_not_exist_is_one_line_exit_2(published, capsys, option):
    """``pmw batch verify OUT --watermark nosuch.png`` (or ``--keys-dir nosuch``) started the cluster and gave one
    ``error`` result per file, exit 1; ``pmw verify FILE --watermark nosuch.png`` says it once, exit 2."""
    pub = published / "published"
    for name in ("planted.pmw", "own.pmw", "alias.pmw"):
        (pub / name).unlink()
    missing = published / ("nosuch.png" if option == "--watermark" else "nosuch")
    assert main(["batch", "verify", str(pub), option, str(missing), "--workers", "1", "--json"]) == 2
    _one_line(capsys, str(missing), "no such")
