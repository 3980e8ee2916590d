"""Differential run of the two ``.pmw`` decoders (``pmwm_codec.stream.StreamDecoder`` and the JavaScript
``PmwDecoder`` of js/) over the same files: per file, the levels each delivers (chunk, vertices, faces and
tests/samples.py's level digest, which js/test/lib/helpers.js' ``levelDigest`` computes alike) and how the
decode ended ("complete", "truncated" or the error's kind).  Error kinds are compared as spec/README.md "Kinds of
refusal" names them (``ChecksumError`` is JavaScript's ``CorruptChunkError``, ``UnsupportedVersionError`` its
``UnsupportedError``, a ``DracoError`` a format error); messages are not compared.

    python tools/decoder_diff.py [--split SEED] [--max-chunks N] [--show K] FILE.pmw ... | @LIST

Prints the counts (agreed: both delivered the same levels and ended alike; disagreed, by class) and up to
``--show`` files of each class.  Exit status 1 when any file disagrees.  The mutated files helper-136 fed it
(truncations, byte flips, length fields, chunk swaps, JSON values, payloads with valid digests) were made by
scratch scripts; any .pmw files will do.
"""

from __future__ import annotations

import argparse
import collections
import importlib.util
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from pmwm_codec.errors import PmwError
from pmwm_codec.stream import StreamDecoder

ROOT = Path(__file__).resolve().parents[1]
#: Python error class -> the kind both decoders share (spec/README.md, Kinds of refusal)
KINDS = {"ChecksumError": "CorruptChunkError", "UnsupportedVersionError": "UnsupportedError", "DracoError": "FormatError"}


def _level_digest():
    """tests/samples.py's ``level_digest`` (the conformance files' level digest)."""
    spec = importlib.util.spec_from_file_location("_pmw_test_samples", ROOT / "tests" / "samples.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.level_digest


def python_run(path: str, split: int = 0, max_chunks=None, digest=None) -> dict:
    """What StreamDecoder makes of the file at ``path`` (as tools/decoder_diff.mjs prints it for PmwDecoder)."""
    digest = digest or _level_digest()
    data = Path(path).read_bytes()
    dec = StreamDecoder(max_chunks=max_chunks)
    levels = []

    def level(r) -> list:
        try:
            for p in r.parts:
                p.attribute_values()  # what JavaScript's snapshot() dequantizes (an srgb8 byte out of range: refused at its chunk)
            h = digest(r)
        except PmwError as exc:
            h = f"SNAP:{KINDS.get(type(exc).__name__, type(exc).__name__)}"
        return [r.chunk, r.vertices, r.faces_count, h]

    rng = np.random.default_rng(split)
    try:
        at = 0
        while at < len(data):
            n = 1 + int(rng.random() * rng.random() * 5000) if split else len(data)
            levels += [level(r) for r in dec.feed(data[at: at + n])]
            at += n
        outcome = "complete" if dec.close().complete else "truncated"
    except PmwError as exc:
        outcome = f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # noqa: BLE001 - a bug of the reader: reported as a disagreement of its own
        outcome = f"NOT-PMW:{type(exc).__name__}: {exc}"
    return {"path": path, "levels": levels, "outcome": outcome}


def kind(outcome: str) -> str:
    name = outcome.split(":")[0]
    return KINDS.get(name, name)


def compare(py: dict, js: dict):
    """None when the two runs agree, else the class of their disagreement (a short string)."""
    if py["levels"] == js["levels"] and kind(py["outcome"]) == kind(js["outcome"]):
        return None
    a, b = py["levels"], js["levels"]
    n = min(len(a), len(b))
    what = "geometry differs" if a[:n] != b[:n] else f"levels python={len(a)} js={len(b)}"
    return f"{what}; python {kind(py['outcome'])}, js {kind(js['outcome'])}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("files", nargs="+", help=".pmw files, or @LIST: a file of paths, one a line")
    ap.add_argument("--split", type=int, default=0, help="feed in pieces of 1..5000 bytes (a seed); 0: whole")
    ap.add_argument("--max-chunks", type=int, default=None)
    ap.add_argument("--show", type=int, default=3)
    args = ap.parse_args(argv)
    files = [p for f in args.files for p in (Path(f[1:]).read_text().split() if f.startswith("@") else [f])]
    with tempfile.NamedTemporaryFile("w", suffix=".list") as listing:
        listing.write("\n".join(str(Path(f).resolve()) for f in files) + "\n")
        listing.flush()
        extra = [str(args.split)] + ([str(args.max_chunks)] if args.max_chunks is not None else [])
        out = subprocess.run(["node", str(ROOT / "tools" / "decoder_diff.mjs"), listing.name, *extra],
                             capture_output=True, text=True, check=True)
    js = [json.loads(line) for line in out.stdout.splitlines()]
    digest = _level_digest()
    counts, shown = collections.Counter(), collections.defaultdict(list)
    for path, j in zip(files, js):
        p = python_run(str(Path(path).resolve()), args.split, args.max_chunks, digest)
        cls = compare(p, j)
        counts["agreed" if cls is None else cls] += 1
        if cls is not None and len(shown[cls]) < args.show:
            shown[cls].append(f"{path}\n      python: {p['outcome'][:160]}\n      js:     {j['outcome'][:160]}")
    print(f"{len(files)} files: {counts.pop('agreed', 0)} agreed")
    for cls, n in counts.most_common():
        print(f"{n} disagreed: {cls}")
        for line in shown[cls]:
            print(f"    {line}")
    return 1 if counts else 0


if __name__ == "__main__":
    sys.exit(main())
