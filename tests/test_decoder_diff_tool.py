"""tools/decoder_diff.py: the two decoders agree on the conformance files fed whole and in pieces, and a file
they read differently (a bufferView whose ``buffer`` is ``false``, before 665837e) is reported as such."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tools import decoder_diff

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted(str(p) for p in (ROOT / "spec" / "conformance").glob("*.v1.pmw"))[:3]


@pytest.fixture(autouse=True)
def _node():
    if shutil.which("node") is None or not (ROOT / "js" / "node_modules" / "zstddec").exists():
        pytest.skip("node or js/node_modules absent")


@pytest.mark.parametrize("split", [0, 5])
def test_the_decoders_agree_on_conformance_files(split, capsys):
    assert decoder_diff.main([*FILES, "--split", str(split)]) == 0
    assert f"{len(FILES)} files: {len(FILES)} agreed" in capsys.readouterr().out


def test_the_decoders_agree_that_a_whole_file_decoded_with_a_chunk_limit_is_complete(capsys):
    """--max-chunks 1: both decoders stop after one chunk and both say the (whole) input is complete; before, the
    JavaScript decoder's complete also required every chunk applied ("python complete, js truncated")."""
    assert decoder_diff.main([*FILES, "--max-chunks", "1"]) == 0
    assert f"{len(FILES)} files: {len(FILES)} agreed" in capsys.readouterr().out
    assert decoder_diff.python_run(FILES[0], max_chunks=1)["outcome"] == "complete"


def test_levels_one_decoder_delivers_and_the_other_refuses_are_a_disagreement():
    py = decoder_diff.python_run(FILES[0])
    js = {**py, "levels": [], "outcome": "FormatError: bufferView 1 lies outside buffer 0"}
    assert decoder_diff.compare(py, py) is None
    assert decoder_diff.compare(py, js) == f"levels python={len(py['levels'])} js=0; python complete, js FormatError"
    assert decoder_diff.compare({**py, "outcome": "ChecksumError: x"}, {**py, "outcome": "CorruptChunkError: y"}) is None
