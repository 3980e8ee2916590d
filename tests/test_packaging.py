"""The wheel ships exactly one top-level package, ``pmwm_codec``, with the ``pmw`` command inside it.

Builds the wheel from a copy of the sources (so no ``build/`` or ``*.egg-info`` lands in the
repository, and no stale ``build/lib`` leaks into the wheel) with the running interpreter's pip and
setuptools (no build isolation, no network); skipped when they are missing or the build cannot run.
"""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory):
    if importlib.util.find_spec("setuptools") is None or importlib.util.find_spec("wheel") is None:
        pytest.skip("setuptools and wheel are needed to build the wheel")
    out = tmp_path_factory.mktemp("wheel")
    src = tmp_path_factory.mktemp("src")
    skip = shutil.ignore_patterns("__pycache__", "node_modules", "build", "*.egg-info")
    for tree in ("pmwm_codec", "tools"):
        shutil.copytree(ROOT / tree, src / tree, ignore=skip)
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, src / name)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
         "-w", str(out), str(src)],
        cwd=src, capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        pytest.skip(f"cannot build the wheel here: {done.stderr.strip().splitlines()[-1:]}")
    wheels = list(out.glob("pmwm_codec-*.whl"))
    assert len(wheels) == 1, done.stdout
    return wheels[0]


def test_the_wheel_holds_only_pmwm_codec(wheel):
    with zipfile.ZipFile(wheel) as zf:
        names = zf.namelist()
        top = {name.split("/", 1)[0] for name in names}
        dist_info = [t for t in top if t.endswith(".dist-info")]
        assert top - set(dist_info) == {"pmwm_codec"}
        assert len(dist_info) == 1
        assert zf.read(f"{dist_info[0]}/top_level.txt").decode().split() == ["pmwm_codec"]
        entry_points = zf.read(f"{dist_info[0]}/entry_points.txt").decode()
    assert "pmw = pmwm_codec.cli:main" in entry_points
    for module in ("cli/__init__.py", "cli/__main__.py", "cli/common.py", "__main__.py", "meshio.py",
                   "verify/__init__.py", "verify/stream.py", "format/inspect.py", "format/schema/"):
        assert any(name.startswith(f"pmwm_codec/{module}") for name in names), module
    assert not any(name.startswith("tools/") or "/bench" in name for name in names)
