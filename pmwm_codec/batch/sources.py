"""What ``pmw batch encode SRC`` works on: SRC expanded to assets with their output paths.

SRC is one of

* a folder: every ``.obj .ply .stl .glb .gltf`` file below it (recursively, sorted; files
  under OUT_DIR are left out when OUT_DIR lies inside SRC; symlinked folders are not entered);
* a glob (``lib/**/*.glb``; ``**`` recurses): the matching mesh files (as for a folder: not through a
  symlinked folder below the folder the glob starts from, nor under OUT_DIR);

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
lies inside OUT_DIR by construction (relative paths never start with ``..``).  Two inputs
whose outputs differ only in letter case (``A.OBJ`` and ``a.obj``; ``Chairs/oak.obj`` and
``chairs/oak.obj``, a manifest naming one file in two spellings on macOS) would write one file on a
case-insensitive file system (macOS, Windows: OUT_DIR, or a copy of it, may well be one):
the first (in the order listed) is encoded and the other is refused, a failed row of the
ledger that names the first (:attr:`Asset.clash`).
"""

from __future__ import annotations

import fnmatch
import os
from dataclasses import dataclass, replace

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
    clash: str | None = None
    """Why the asset is not encoded: its output is an earlier asset's but for letter case (None: it is not)."""


def expand_sources(src, out_dir) -> list[Asset]:
    """The assets of ``src`` (folder, glob or manifest) with outputs under ``out_dir``.

    Raises ValueError with a one-line message when ``src`` names nothing usable.
    """
    src = os.fspath(src)
    if not src.strip():
        raise ValueError(f"an empty SRC ({src!r}) names no folder, file or glob (an unset variable?)")
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
        root = _glob_root(src)
        inputs = _globbed(src, root, out_dir)
    else:
        raise ValueError(f"{src}: no such folder, file or glob match")
    if not inputs:
        raise ValueError(f"{src}: no mesh files ({', '.join(MESH_SUFFIXES)}) found")
    return _case_clashes([_asset(path, root, out_dir, root if confine else None) for path in inputs])


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


def _case_clashes(assets: list[Asset]) -> list[Asset]:
    """``assets``, each whose output is an earlier one's but for letter case (``str.casefold``) refused in its
    :attr:`Asset.clash`: on a case-insensitive file system the two are one file, one asset's ``.pmw`` (and
    key) written over the other's."""
    first = {}
    for i, asset in enumerate(assets):
        earlier = first.setdefault(asset.output.casefold(), asset)
        if earlier is not asset:
            assets[i] = replace(asset, clash=(
                f"{asset.input}: its output {asset.relative}{PMW_SUFFIX} is {earlier.relative}{PMW_SUFFIX} (of "
                f"{earlier.input}) but for letter case, one file on a case-insensitive file system (macOS, "
                "Windows); not encoded (rename one of the two to encode both)"))
    return assets


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


def _globbed(pattern: str, root: str, out_dir: str) -> list[str]:
    """The mesh files ``pattern`` matches, listed as a folder SRC lists them: by walking ``root`` (the folder the
    pattern starts from) without entering a symlinked folder or OUT_DIR (when it lies inside ``root``), each file
    matched against the rest of the pattern as :mod:`glob` matches (``**`` any number of folders, ``*`` ``?``
    ``[...]`` within a name, a leading dot matched only by a leading dot).

    :func:`glob.glob` followed symlinked folders: a link to a folder above (``lib/a/loop -> ..``) made one file
    some forty assets, and two such links (``lib/b -> a`` besides) never ended (exponential in the links)."""
    rest = [part for part in pattern.split(os.sep)[len(_glob_fixed(pattern)):] if part not in ("", ".")]
    skip = out_dir if out_dir != root and _inside(out_dir, root) else None
    deepest = None if "**" in rest else len(rest) - 1  # folders below root a match can lie in
    found = []
    for here, dirs, files in os.walk(root):
        depth = 0 if here == root else os.path.relpath(here, root).count(os.sep) + 1
        if deepest is not None and depth >= deepest:
            dirs[:] = []
        dirs[:] = sorted(d for d in dirs if skip is None or not _inside(os.path.join(here, d), skip))
        folders = [] if here == root else os.path.relpath(here, root).split(os.sep)
        for name in files:
            path = os.path.join(here, name)
            if _is_mesh(name) and _matches(tuple(folders + [name]), tuple(rest)) and os.path.isfile(path):
                found.append(path)
    return sorted(found)


def _matches(names: tuple, parts: tuple) -> bool:
    """Whether the path components ``names`` match the glob components ``parts``."""
    from functools import lru_cache

    @lru_cache(maxsize=None)
    def match(i: int, j: int) -> bool:
        if j == len(parts):
            return i == len(names)
        if parts[j] == "**":  # nothing, or one more folder (the file too when it ends the pattern); none hidden
            more = i < len(names) - 1 or (i < len(names) and j == len(parts) - 1)
            return match(i, j + 1) or (more and not names[i].startswith(".") and match(i + 1, j))
        return i < len(names) and _name_matches(names[i], parts[j]) and match(i + 1, j + 1)

    return match(0, 0)


def _name_matches(name: str, part: str) -> bool:
    if not (_MAGIC & set(part)):
        return name == part
    if name.startswith(".") and not part.startswith("."):
        return False
    return fnmatch.fnmatchcase(name, part)


#: The largest manifest read (characters): far more paths than a run takes; a longer one is refused, never cut.
MAX_MANIFEST_CHARS = 1 << 26


def _manifest(path: str) -> list[str]:
    base = os.path.dirname(os.path.abspath(path))
    with open(path, encoding="utf-8-sig") as fh:  # a byte order mark (a Windows editor's) is not a path
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


def _glob_fixed(pattern: str) -> list[str]:
    """The leading components of a glob without ``* ? [`` (never its last one)."""
    fixed = []
    for part in pattern.split(os.sep)[:-1]:
        if _MAGIC & set(part):
            break
        fixed.append(part)
    return fixed


def _glob_root(pattern: str) -> str:
    """The folder a glob starts from: its leading components without ``* ? [``."""
    return os.path.abspath(os.sep.join(_glob_fixed(pattern)) or ("/" if pattern.startswith(os.sep) else "."))


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
