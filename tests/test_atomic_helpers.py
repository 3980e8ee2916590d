"""Helpers of ``pmwm_codec.atomic``: ``directory_made`` (the folders a command makes for its outputs are gone again
when it fails before writing one, ``pmw demo --out``, ``verify --frames``, and nothing of the user's is removed), and
``write_stream`` / ``write_atomic`` given their parts as a generator (text written a block at a time)."""

import io
import os
import signal

import pytest

from pmwm_codec import atomic
from pmwm_codec.atomic import directory_made, fault_point, missing_directories, write_atomic, write_stream


class Stop(Exception):
    pass


def test_a_block_that_fails_leaves_none_of_the_folders_it_made(tmp_path):
    target = tmp_path / "a" / "b" / "c"
    with pytest.raises(Stop):
        with directory_made(target):
            assert target.is_dir()
            raise Stop
    assert os.listdir(tmp_path) == []


def test_a_block_that_succeeds_keeps_its_folders(tmp_path):
    target = tmp_path / "a" / "b"
    with directory_made(target):
        pass
    assert target.is_dir()


def test_a_folder_holding_a_file_and_the_folders_that_were_there_stay(tmp_path):
    (tmp_path / "a").mkdir()
    target = tmp_path / "a" / "b" / "c"
    with pytest.raises(KeyboardInterrupt):
        with directory_made(target):
            (tmp_path / "a" / "b" / "kept.txt").write_text("a whole output")
            raise KeyboardInterrupt
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["b"]
    assert os.listdir(tmp_path / "a" / "b") == ["kept.txt"]


def test_missing_directories_lists_the_ones_makedirs_would_make_deepest_first(tmp_path):
    target = tmp_path / "x" / "y"
    assert missing_directories(target) == [str(target), str(tmp_path / "x")]
    assert missing_directories(tmp_path) == []


def test_parts_given_as_a_generator_are_written_whole_and_counted_once(tmp_path):
    """The text writers (OBJ, OFF) hand their blocks over as a generator, read once: write_stream counted its parts
    in one pass and wrote them in a second, so a generator's bytes were counted and never written."""
    blocks = [b"v 0 0 0\n", b"v 1 0 0\n", b"f 1 2 3\n"]
    out = io.BytesIO()
    assert write_stream(out, (b for b in blocks)) == sum(map(len, blocks))
    assert out.getvalue() == b"".join(blocks)
    assert write_atomic(tmp_path / "m.obj", (b for b in blocks)) == sum(map(len, blocks))
    assert (tmp_path / "m.obj").read_bytes() == b"".join(blocks)


@pytest.mark.parametrize("spec, fired", [("here:USR1", [1, 2, 3, 4, 5]), ("here@3:USR1", [3]), ("here@9:USR1", []),
                                         ("elsewhere@1:USR1", []), ("", [])])
def test_a_fault_point_named_with_a_count_signals_only_the_nth_time_it_is_reached(monkeypatch, spec, fired):
    """``PMWM_FAULT=point@N:SIGNAL`` fixes a moment by the order of events (``batch-row-taken@3:STOP``: the run's
    third result); without ``@N`` every time; an unset or other point never."""
    monkeypatch.setattr(atomic, "_fault_counts", {})
    monkeypatch.setenv("PMWM_FAULT", spec)
    reached, got = [0], []
    previous = signal.signal(signal.SIGUSR1, lambda signum, frame: got.append(reached[0]))
    try:
        for _ in range(5):
            reached[0] += 1
            fault_point("here")
    finally:
        signal.signal(signal.SIGUSR1, previous)
    assert got == fired
