"""Third-party glTF / GLB assets for the robustness probe: an npm package and a Debian package, both pinned.

Two sources nobody wrote for this codec, from registries every machine here reaches:

* npm ``@webxr-input-profiles/assets@1.0.20``: 82 ``.glb`` models of real VR controllers and
  hands (``package/dist/profiles/**``): textured, many meshes and nodes each, skinned hands.
  The registry tarball is fetched with ``npm pack`` and its sha512 checked against the
  integrity string pinned here (the one ``npm view ... dist.integrity`` gives).
* Debian ``assimp-testmodels`` ``5.2.5~ds0-1`` (assimp's test models): its ``glTF/`` (glTF 1.0)
  and ``glTF2/`` folders, edge cases on purpose (wrong JSON types, indices out of range,
  infinities, strips and fans, a missing ``.bin``, Draco input, morphs, skins, cameras,
  texture transforms), and the ``.obj .stl .ply`` files of its ``OBJ/``, ``PLY/``, ``STL/`` and
  ``invalid/`` folders (empty and malformed ones among them).  The ``.deb`` is fetched with
  ``apt-get download`` (no root needed), its SHA-256 checked, and unpacked with ``dpkg-deb -x``.

``python tools/gltf_meshes.py [--dir DIR] [--tarball PATH] [--deb PATH]`` extracts only the mesh
files (``.gltf .glb .obj .stl .ply``, any case) and the files each ``.gltf`` names by a relative
``uri`` (its buffers, images and, in glTF 1.0, shaders: ``.bin .png .jpg ...``), at their relative
paths, under ``DIR/webxr-input-profiles/`` and ``DIR/assimp-testmodels/`` (default ``DIR``
``~/.cache/pmwm_codec/gltf``).  A ``uri`` naming a file the package lacks (assimp's
``MissingBin`` case) is skipped: the probe sees the asset as shipped.  The downloads (~94 MB
and ~21 MB) go to a temporary directory and are deleted; ``--tarball PATH`` / ``--deb PATH``
read copies already on disk instead.  The files are third-party data, under their authors'
terms: they are never copied into the repository.  ``tools/probe_meshes.py DIR`` runs the
codec over them.
"""

from __future__ import annotations

import argparse
import base64
import hashlib
import json
import os
import posixpath
import shutil
import subprocess
import sys
import tarfile
import tempfile
import urllib.parse

NPM_PACKAGE = "@webxr-input-profiles/assets"
NPM_VERSION = "1.0.20"
TARBALL = f"webxr-input-profiles-assets-{NPM_VERSION}.tgz"
TARBALL_SHA512 = "V/8NB4Ywgm//TBVMgo0TgJ9DtxsBoo0iiaF8AdfiP0F0cgbwkuQycEZAIOsplyd/iZ8L3mrFYNJBC6rzQb4tJA=="
TARBALL_FOLDERS = ("package/dist/profiles/",)
DEB_PACKAGE = "assimp-testmodels"
DEB_VERSION = "5.2.5~ds0-1"
DEB = f"{DEB_PACKAGE}_{DEB_VERSION}_all.deb"
DEB_SHA256 = "526f326186000cd6f631ea806128548a7d3d391abd8149fddc5c4c8513e80b8a"
DEB_ROOT = "usr/share/assimp/models/"
DEB_FOLDERS = tuple(DEB_ROOT + f + "/" for f in ("glTF", "glTF2", "OBJ", "PLY", "STL", "invalid"))
MESHES = (".gltf", ".glb", ".obj", ".stl", ".ply")
DEFAULT_DIR = os.path.join(os.path.expanduser("~"), ".cache", "pmwm_codec", "gltf")


class FetchError(Exception):
    """A package cannot be fetched, is not the pinned one or cannot be unpacked: one line."""


def run(cmd: list, what: str, cwd: str | None = None) -> None:
    """Run ``cmd``; FetchError "``what`` failed: <its last stderr line>" when it cannot start or exits non-zero."""
    try:
        subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=cwd)
    except subprocess.CalledProcessError as exc:
        why = ((exc.stderr or "").strip().splitlines() or [f"exit status {exc.returncode}"])[-1]
        raise FetchError(f"{what} failed: {why}") from None
    except OSError as exc:
        raise FetchError(f"{what} failed: {exc}") from None


def npm_pack(into: str) -> str:
    """``npm pack`` the pinned package into ``into`` (the registry tarball, not built); its path."""
    run(["npm", "pack", f"{NPM_PACKAGE}@{NPM_VERSION}", "--pack-destination", into, "--silent"],
        f"npm pack {NPM_PACKAGE}@{NPM_VERSION}", cwd=into)
    return found(into, TARBALL, "npm pack")


def apt_download(into: str, package: str = DEB_PACKAGE, version: str = DEB_VERSION) -> str:
    """``apt-get download`` the pinned ``.deb`` (``package`` at ``version``, an architecture-independent
    one) into ``into`` (no root needed); its path."""
    run(["apt-get", "download", "-q", f"{package}={version}"], f"apt-get download {package}={version}", cwd=into)
    # apt-get writes the epoch-less version with ':' as '%3a'; these versions have none
    return found(into, f"{package}_{version}_all.deb", "apt-get download")


def found(folder: str, name: str, by: str) -> str:
    path = os.path.join(folder, name)
    if not os.path.isfile(path):
        raise FetchError(f"{by} wrote no {name} (found: {', '.join(sorted(os.listdir(folder))) or 'nothing'})")
    return path


def digest(path: str, algorithm: str) -> bytes:
    h = hashlib.new(algorithm)
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.digest()


def check_tarball(path: str) -> None:
    """FetchError unless ``path`` is the pinned npm tarball, byte for byte (its sha512 integrity)."""
    got = base64.b64encode(digest(path, "sha512")).decode()
    if got != TARBALL_SHA512:
        raise FetchError(f"{path} is not {TARBALL} (sha512-{got}, expected sha512-{TARBALL_SHA512})")


def check_deb(path: str, sha256: str = DEB_SHA256, name: str = DEB) -> None:
    """FetchError unless ``path`` is the pinned ``.deb`` ``name`` (SHA-256 ``sha256``, hex), byte for byte."""
    got = digest(path, "sha256").hex()
    if got != sha256:
        raise FetchError(f"{path} is not {name} (SHA-256 {got}, expected {sha256})")


def unpack_tarball(path: str, into: str) -> None:
    """The tarball's members under ``into`` (the ``data`` filter: no absolute paths, links out, devices)."""
    try:
        with tarfile.open(path) as tf:
            tf.extractall(into, filter="data")
    except (tarfile.TarError, OSError) as exc:
        raise FetchError(f"cannot unpack {path}: {exc}") from None


def unpack_deb(path: str, into: str) -> None:
    """The ``.deb``'s data under ``into`` (``dpkg-deb -x``, which refuses paths out of ``into``)."""
    run(["dpkg-deb", "-x", path, into], f"dpkg-deb -x {path}")


def gltf_uris(text: bytes) -> list:
    """The relative ``uri`` strings of a ``.gltf``'s buffers, images and shaders (arrays in glTF 2.0,
    objects keyed by id in 1.0), percent-decoded; ``data:`` URIs and absolute ones left out.  A file
    that is not JSON names nothing (the probe sees it as it is)."""
    try:
        doc = json.loads(text)
    except (ValueError, UnicodeDecodeError, RecursionError):
        return []
    if not isinstance(doc, dict):
        return []
    uris = []
    for key in ("buffers", "images", "shaders"):
        items = doc.get(key)
        items = list(items.values()) if isinstance(items, dict) else items if isinstance(items, list) else []
        for item in items:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:") and "://" not in uri:
                uris.append(urllib.parse.unquote(uri))
    return uris


def wanted(root: str, folders: tuple) -> tuple:
    """(mesh files, files the ``.gltf`` among them name) under ``folders`` of the unpacked ``root``,
    as ``/``-separated paths relative to ``root``; a named file must lie under the same folder."""
    meshes = []
    for folder in folders:
        top = os.path.join(root, *folder.split("/"))
        for d, _, names in os.walk(top):
            for name in names:
                if name.lower().endswith(MESHES) and _regular(os.path.join(d, name)):
                    meshes.append(os.path.relpath(os.path.join(d, name), root).replace(os.sep, "/"))
    others = set()
    for mesh in meshes:
        if not mesh.lower().endswith(".gltf"):
            continue
        folder = next(f for f in folders if mesh.startswith(f))
        with open(os.path.join(root, *mesh.split("/")), "rb") as f:
            uris = gltf_uris(f.read())
        for uri in uris:
            rel = posixpath.normpath(posixpath.join(posixpath.dirname(mesh), uri.replace("\\", "/")))
            if rel.startswith(folder) and rel not in meshes and _regular(os.path.join(root, *rel.split("/"))):
                others.add(rel)
    return sorted(meshes), sorted(others)


def _regular(path: str) -> bool:
    """A regular file, not a link (a link in a package could name a file outside it)."""
    return os.path.isfile(path) and not os.path.islink(path)


def copy_out(root: str, strip: str, members: list, out_dir: str) -> None:
    """Copy ``members`` (relative to ``root``) to ``out_dir``, each without its ``strip`` prefix."""
    for rel in members:
        target = os.path.join(out_dir, *rel[len(strip):].split("/"))
        os.makedirs(os.path.dirname(target), exist_ok=True)
        shutil.copyfile(os.path.join(root, *rel.split("/")), target)


def extract(tarball: str, deb: str, out_dir: str) -> dict:
    """Unpack both packages in a temporary folder and copy the wanted files under ``out_dir``;
    returns ``{subfolder: (mesh files, other files)}``."""
    counts = {}
    with tempfile.TemporaryDirectory() as tmp:
        for sub, path, unpack, folders, strip in (
                ("webxr-input-profiles", tarball, unpack_tarball, TARBALL_FOLDERS, TARBALL_FOLDERS[0]),
                ("assimp-testmodels", deb, unpack_deb, DEB_FOLDERS, DEB_ROOT)):
            root = os.path.join(tmp, sub)
            os.makedirs(root)
            unpack(path, root)
            meshes, others = wanted(root, folders)
            if not meshes:
                raise FetchError(f"{path} holds no mesh file under {', '.join(folders)}")
            copy_out(root, strip, meshes + others, os.path.join(out_dir, sub))
            counts[sub] = (len(meshes), len(others))
            shutil.rmtree(root)
    return counts


def fetch(out_dir: str, tarball: str | None = None, deb: str | None = None) -> dict:
    """Fetch (or take ``tarball`` / ``deb``), check and extract; returns :func:`extract`'s counts."""
    with tempfile.TemporaryDirectory() as tmp:
        tarball = tarball or npm_pack(tmp)
        check_tarball(tarball)
        deb = deb or apt_download(tmp)
        check_deb(deb)
        return extract(tarball, deb, out_dir)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", default=DEFAULT_DIR,
                    help=f"where to write the two folders (default {DEFAULT_DIR}; never inside the repository)")
    ap.add_argument("--tarball", help=f"a copy of {TARBALL} (npm {NPM_PACKAGE}@{NPM_VERSION}) on disk, instead of "
                    "downloading it")
    ap.add_argument("--deb", help=f"a copy of {DEB} on disk, instead of downloading it")
    args = ap.parse_args(argv)
    try:
        counts = fetch(args.dir, args.tarball, args.deb)
    except (FetchError, OSError) as exc:
        print(f"gltf_meshes: error: {exc}", file=sys.stderr)
        return 2
    for sub, (meshes, others) in counts.items():
        print(f"{os.path.join(args.dir, sub)}: {meshes:,} mesh files, {others:,} files they name")
    return 0


if __name__ == "__main__":
    sys.exit(main())
