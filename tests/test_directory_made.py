"""``atomic.directory_made``: the folders a command makes for its outputs are gone again when it fails before
writing one (``pmw demo --out``, ``verify --frames``), and nothing of the user's is removed."""

import os

import pytest

from pmwm_codec.atomic import directory_made, missing_directories


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
