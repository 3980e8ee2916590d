"""What ``pmw batch encode SRC`` works on: SRC expanded to assets with their output paths.

SRC is one of

* a folder: every ``.obj .ply .stl .glb .gltf`` file below it (recursively, sorted; files
  under OUT_DIR are left out when OUT_DIR lies inside SRC; symlinked folders are not entered);
* a glob (``lib/**/*.glb``; ``**`` recurses): the matching mesh files;

  in both, a file whose real path (symlinks resolved) lies outside the folder SRC names
  is refused, a failed row of the ledger that says so: a symlink planted in a library
  never makes a run read a file the user did not name (name it in a manifest instead);
* a manifest: a text file naming one input per line (blank lines and ``#`` comments
  skipped; relative paths are relative to the manifest's folder).  Its entries are taken
  as named, so an unreadable one becomes a failed asset in the ledger, not a usage error.

Each asset's output mirrors its path relative to the root of SRC (the folder, or the
folder a glob starts from, or the deepest folder common to the manifest's entries)::

    OUT_DIR/<relative path>.pmw            e.g. chairs/oak.obj -> OUT_DIR/chairs/oak.obj.pmw

The suffix is kept so that ``oak.obj`` and ``oak.ply`` never collide.  Every output
lies inside OUT_DIR by construction (relative paths never start with ``..``).
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass

from pmwm_codec.mesh import MESH_SUFFIXES
from pmwm_codec.watermark.key import KEY_SUFFIX

__all__ = ["Asset", "expand_sources", "outside_root", "ENCODE_REMEDY", "KEY_SUFFIX", "PMW_SUFFIX"]

PMW_SUFFIX = ".pmw"
_MAGIC = set("*?[")


@dataclass(frozen=True)
class Asset:
    """One input mesh and where its ``.pmw`` goes (absolute paths; ``relative`` is POSIX-style)."""

    input: str
    relative: str
    output: str
    root: str | None = None
    """The folder a folder or glob SRC names: the input's real path must stay inside it (None: named as is)."""


def expand_sources(src, out_dir) -> list[Asset]:
    """The assets of ``src`` (folder, glob or manifest) with outputs under ``out_dir``.

    Raises ValueError with a one-line message when ``src`` names nothing usable.
    """
    src = os.fspath(src)
    out_dir = os.path.abspath(os.fspath(out_dir))
    confine = True
    if os.path.isdir(src):
        root = os.path.abspath(src)
        inputs = _walk(root, out_dir)
    elif os.path.isfile(src) and os.path.splitext(src)[1].lower() in MESH_SUFFIXES:
        inputs = [os.path.abspath(src)]
        root, confine = os.path.dirname(inputs[0]), False
    elif os.path.isfile(src):
        inputs = _manifest(src)
        root, confine = _common_root(inputs), False
    elif _MAGIC & set(src):
        inputs = sorted({os.path.abspath(p) for p in glob.glob(src, recursive=True)
                         if os.path.isfile(p) and _is_mesh(p)})
        root = _glob_root(src)
    else:
        raise ValueError(f"{src}: no such folder, file or glob match")
    if not inputs:
        raise ValueError(f"{src}: no mesh files ({', '.join(MESH_SUFFIXES)}) found")
    return [_asset(path, root, out_dir, root if confine else None) for path in inputs]


#: What an ``outside_root`` refusal suggests for an input of ``pmw batch encode``.
ENCODE_REMEDY = "name the file itself, or list it in a manifest, to encode it"


def outside_root(path: str, root: str | None, remedy: str = ENCODE_REMEDY) -> str | None:
    """Why the file ``path`` must not be read (its real path leaves ``root``, the folder the user
    named: SRC for ``batch encode``, OUT_DIR or ``--keys-dir`` for ``batch verify``), or None.

    Checked by the worker just before it reads the file, so a symlink planted after the
    folder was listed is refused too.  ``remedy``: how to read such a file anyway (naming it)."""
    if root is None:
        return None
    real = os.path.realpath(path)
    if _inside(real, os.path.realpath(root)):
        return None
    return f"{path}: resolves through a symlink to {real}, outside {root}; refused ({remedy})"


def _is_mesh(path: str) -> bool:
    return os.path.splitext(path)[1].lower() in MESH_SUFFIXES


def _inside(path: str, folder: str) -> bool:
    return os.path.commonpath([path, folder]) == folder


def _walk(root: str, out_dir: str) -> list[str]:
    """The mesh files below ``root``, but for those under ``out_dir`` when it is a folder inside ``root``
    (an ``out_dir`` that is ``root`` or holds it leaves out nothing: every folder below ``root`` is under it)."""
    skip = out_dir if out_dir != root and _inside(out_dir, root) else None
    found = []
    for here, dirs, files in os.walk(root):
        dirs[:] = sorted(d for d in dirs if skip is None or not _inside(os.path.join(here, d), skip))
        found.extend(os.path.join(here, f) for f in files if _is_mesh(f))
    return sorted(found)


#: The largest manifest read (characters): far more paths than a run takes; a longer one is refused, never cut.
MAX_MANIFEST_CHARS = 1 << 26


def _manifest(path: str) -> list[str]:
    base = os.path.dirname(os.path.abspath(path))
    with open(path, encoding="utf-8") as fh:
        try:
            text = fh.read(MAX_MANIFEST_CHARS + 1)
        except UnicodeDecodeError:
            raise ValueError(f"{path}: not a mesh file and not a manifest (one path a line, UTF-8)") from None
    if len(text) > MAX_MANIFEST_CHARS:
        raise ValueError(f"{path}: a manifest of more than {MAX_MANIFEST_CHARS:,} characters (one path a line)")
    lines = text.splitlines()
    entries = [line.strip() for line in lines]
    named = [os.path.abspath(os.path.join(base, e)) for e in entries if e and not e.startswith("#")]
    return list(dict.fromkeys(named))  # duplicates once, order kept


def _glob_root(pattern: str) -> str:
    """The folder a glob starts from: its leading components without ``* ? [``."""
    parts = pattern.split(os.sep)
    fixed = []
    for part in parts[:-1]:
        if _MAGIC & set(part):
            break
        fixed.append(part)
    return os.path.abspath(os.sep.join(fixed) or ("/" if pattern.startswith(os.sep) else "."))


def _common_root(inputs: list[str]) -> str:
    if not inputs:
        return os.getcwd()
    return os.path.commonpath([os.path.dirname(p) for p in inputs])


def _asset(path: str, root: str, out_dir: str, confine: str | None) -> Asset:
    relative = os.path.relpath(path, root)
    output = os.path.join(out_dir, relative + PMW_SUFFIX)
    if not _inside(os.path.abspath(output), out_dir):  # cannot happen: root is a parent of path
        raise ValueError(f"{path}: its output would leave {out_dir}")
    return Asset(path, relative.replace(os.sep, "/"), output, confine)
