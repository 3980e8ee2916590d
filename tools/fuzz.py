"""Hostile-file fuzzer for the ``.pmw`` readers.

Every generated file is decoded by :class:`pmwm_codec.stream.StreamDecoder`
(with the watermark key, fed in random block sizes) and by
:func:`pmwm_codec.iter_decode`.  The only acceptable outcomes are a decode (a
mutation can be harmless) or a :class:`pmwm_codec.errors.PmwError` subclass;
anything else -- an ``IndexError``/``ValueError`` from numpy, a
``MemoryError``, a hang, a huge allocation -- is a finding, printed with a
reproducer (the seed and kind; ``--save DIR`` writes the file).

Kinds of cases (``KINDS``):

``flip``     1..8 random bytes replaced
``truncate`` the file cut at a random length
``insert``   random bytes inserted, or a slice deleted
``splice``   a slice of the file copied over another place
``payload``  a chunk's *raw* payload mutated (bytes, counts, truncation), then
             re-framed with zstd and a valid digest by ``build_pmw`` -- reaches
             the records parser and the vertex-split code
``records``  semantically crafted split batches (vertex ids out of range or
             repeated, bad symbols, huge residuals, wrong counts), packed by
             ``pack_batches`` and rebuilt into a valid container
``json``     one value of the glTF JSON (extension, chunk index, bufferViews,
             accessors, watermark parameters) replaced by a hostile value
             (huge or negative counts, offsets, overlapping views, lying
             digests, wrong types), re-framed as a GLB
``zstd``     a chunk replaced by a zstd frame that claims gigabytes (content
             size field), with a valid digest and a matching or lying
             ``uncompressedLength``
``claims``   one chunk's index entry claiming up to millions more vertices and faces than
             its records hold, every later entry and the extension's counts raised to
             agree (the header's consistency checks pass; only decoding finds the lie),
             sometimes with that chunk's payload cut short: memory must follow what
             is decoded, not the claim

Run::

    python tools/fuzz.py --cases 100000            # prints counts per outcome
    python tools/fuzz.py --seconds 600 --save /tmp/fuzz-findings
"""

from __future__ import annotations

import argparse
import copy
import io
import json
import os
import resource
import signal
import sys
import time
import traceback
import tracemalloc
from collections import Counter
from pathlib import Path

import numpy as np

from pmwm_codec.constants import EXTENSION_NAME
from pmwm_codec.errors import PmwError

KINDS = ("flip", "truncate", "insert", "splice", "payload", "records", "json", "zstd", "claims")


# ------------------------------------------------------------------ the sample


class Sample:
    """A small marked ``.pmw`` and everything needed to rebuild variants of it."""

    def __init__(self, subdivisions: int = 3, size: int = 16, seed: int = 0):
        from pmwm_codec.format import BaseEvent, ChunkEvent, HeaderEvent, encode_base, iter_events
        from pmwm_codec.format.records import unpack_batches
        from pmwm_codec.shapes import icosphere
        from pmwm_codec.stream.encoder import encode_mesh
        from pmwm_codec.watermark.key import WatermarkKey

        rng = np.random.default_rng(seed)
        self.image = rng.integers(0, 256, (size, size)).astype(np.uint8)
        self.key = WatermarkKey.generate(rng=rng)
        buf = io.BytesIO()
        # payload version 1: the mutators rewrite its zstd frames, records and per-chunk entries
        encode_mesh(icosphere(subdivisions), buf, watermark=self.image, key=self.key, base_codec="plain",
                    payload_version=1)
        self.data = buf.getvalue()
        self.payloads = []
        for event in iter_events(self.data):
            if isinstance(event, HeaderEvent):
                ext = event.extension
            elif isinstance(event, BaseEvent):
                base_pos, base_faces = event.positions_int, event.faces
            elif isinstance(event, ChunkEvent):
                self.payloads.append(event.payload)
        self.extension = {k: copy.deepcopy(v) for k, v in ext.items() if k not in ("version", "chunks")}
        self.meta = [{k: v for k, v in c.items() if k in ("splits", "vertexCount", "faceCount", "geometricError", "batches")}
                     for c in ext["chunks"]]
        self.base = encode_base(base_pos, base_faces, ext["grid"], codec="plain")
        self.batches = [unpack_batches(p) for p in self.payloads]
        json_length = int.from_bytes(self.data[12:16], "little")
        self.gltf = json.loads(self.data[20: 20 + json_length])
        self.bin = bytes(self.data[20 + json_length + 8:])
        assert self.rebuild() is not None

    def rebuild(self, payloads=None, meta=None, extension=None) -> bytes:
        """A valid container (digests, zstd frames) around ``payloads`` (raw bytes)."""
        from pmwm_codec.format import build_pmw

        return build_pmw(base=self.base, chunks=self.payloads if payloads is None else payloads,
                         chunk_meta=self.meta if meta is None else meta,
                         extension=self.extension if extension is None else extension, zstd_level=1)


def join_glb(gltf: dict, bin_payload: bytes) -> bytes:
    """Re-frame a (possibly hostile) glTF JSON and BIN payload as a GLB."""
    from pmwm_codec.format.glb import join_glb as join

    return join(gltf, bin_payload)


# ------------------------------------------------------------------ mutators

HOSTILE = [-1, 0, 1, 3, 7, 2**31 - 1, 2**31, 2**32, 2**40, 2**63 - 1, 2**64, -2**63, 1e300, -0.5, 0.5,
           float("inf"), None, True, "x", "", [], {}, [0, 1], {"a": 1}]


def _bytes_flip(data: bytes, rng) -> bytes:
    b = bytearray(data)
    for _ in range(int(rng.integers(1, 9))):
        b[int(rng.integers(len(b)))] = int(rng.integers(256))
    return bytes(b)


def _bytes_insert(data: bytes, rng) -> bytes:
    i = int(rng.integers(len(data) + 1))
    if rng.random() < 0.5:
        return data[:i] + rng.bytes(int(rng.integers(1, 64))) + data[i:]
    j = min(len(data), i + int(rng.integers(1, 64)))
    return data[:i] + data[j:]


def _bytes_splice(data: bytes, rng) -> bytes:
    n = len(data)
    i, j = (int(x) for x in rng.integers(0, n, 2))
    k = int(rng.integers(1, 256))
    piece = data[i: i + k]
    return data[:j] + piece + data[j + len(piece):]


def _mutate_payload(p: bytes, rng) -> bytes:
    r = rng.random()
    if r < 0.35:
        return _bytes_flip(p, rng)
    if r < 0.5:
        return p[: int(rng.integers(len(p) + 1))]
    if r < 0.6:
        return _bytes_insert(p, rng)
    b = bytearray(p)
    # crafted header / batch table values
    field = int(rng.integers(0, min(len(b) // 4, 8))) * 4 if len(b) >= 4 else 0
    value = int(rng.choice([0, 1, 2, 255, 256, 4096, 4097, 2**16, 2**24, 2**31, 2**32 - 1]))
    b[field: field + 4] = value.to_bytes(4, "little")
    if rng.random() < 0.3 and len(b) > 20:  # a column width byte
        b[int(rng.integers(4, len(b)))] = int(rng.choice([0, 3, 8, 9, 255]))
    return bytes(b)


def _craft_batches(sample: Sample, rng):
    from pmwm_codec.progressive.vsplit import SplitBatch

    chunks = [list(bs) for bs in sample.batches]
    c = int(rng.integers(len(chunks)))
    j = int(rng.integers(len(chunks[c])))
    b = chunks[c][j]
    v, s, res = b.v.copy(), b.symbols.copy(), b.residual.copy()
    what = int(rng.integers(0, 9))
    if what == 0 and len(v):
        v[int(rng.integers(len(v)))] = int(rng.choice([0, v[-1] + 1, 10**6, 2**40]))
        v.sort()
    elif what == 1 and len(v) > 1:
        v[1] = v[0]  # repeated id
    elif what == 2 and len(s):
        s[int(rng.integers(len(s)))] = int(rng.integers(0, 5))
    elif what == 3:
        s = s[: int(rng.integers(len(s) + 1))]
    elif what == 4:
        s = np.concatenate([s, rng.integers(0, 5, int(rng.integers(1, 10))).astype(np.uint8)])
    elif what == 5:
        res[int(rng.integers(len(res)))] = rng.choice([2**62, -2**62, 2**40, -(2**31)], 3)
    elif what == 6:
        s = np.zeros_like(s)  # no split names a new face
    elif what == 7:
        chunks[c] = chunks[c][:j] + chunks[c][j + 1:] or chunks[c]  # a batch missing
    else:
        s = rng.permutation(s)
    if what != 7:
        chunks[c][j] = SplitBatch(v, s, res)
    return c, chunks[c]


def make_case(sample: Sample, kind: str, rng, *, json_scope: str = "all") -> bytes:
    """One hostile file of ``kind`` (see module docstring).

    ``json_scope`` (kind ``json``): ``all``; ``container`` (everything but the
    extension's ``watermark`` and ``payload`` objects); ``watermark`` (only those).
    """
    from pmwm_codec.format.extension import digest
    from pmwm_codec.format.records import pack_batches

    data = sample.data
    if kind == "flip":
        return _bytes_flip(data, rng)
    if kind == "truncate":
        return data[: int(rng.integers(len(data)))]
    if kind == "insert":
        return _bytes_insert(data, rng)
    if kind == "splice":
        return _bytes_splice(data, rng)
    if kind == "payload":
        payloads = list(sample.payloads)
        k = int(rng.integers(len(payloads)))
        payloads[k] = _mutate_payload(payloads[k], rng)
        return sample.rebuild(payloads)
    if kind == "records":
        c, batches = _craft_batches(sample, rng)
        payloads = list(sample.payloads)
        try:
            payloads[c] = pack_batches(batches)
        except (ValueError, OverflowError):
            return data
        return sample.rebuild(payloads)
    if kind == "json":
        gltf = copy.deepcopy(sample.gltf)
        ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
        targets = []

        def walk(obj, path):
            if isinstance(obj, dict):
                for k, v in obj.items():
                    walk(v, path + [k])
            elif isinstance(obj, list):
                for i, v in enumerate(obj):
                    walk(v, path + [i])
            else:
                targets.append(path)

        walk(ext, ["ext"])
        walk(gltf["bufferViews"], ["bufferViews"])
        walk(gltf["accessors"], ["accessors"])
        walk(gltf["buffers"], ["buffers"])
        wm_paths = [t for t in targets if t[0] == "ext" and len(t) > 1 and t[1] in ("watermark", "payload")]
        if json_scope == "container":
            targets = [t for t in targets if t not in wm_paths]
        elif json_scope == "watermark":
            targets = wm_paths
        for _ in range(int(rng.integers(1, 4))):
            path = targets[int(rng.integers(len(targets)))]
            obj = ext if path[0] == "ext" else gltf[path[0]]
            for p in path[1:-1]:
                obj = obj[p]
            r = rng.random()
            is_int = isinstance(obj[path[-1]], int) and not isinstance(obj[path[-1]], bool)  # not yet replaced
            if r < 0.15 and path[0] == "bufferViews" and path[-1] == "byteOffset" and is_int:
                obj[path[-1]] = max(0, obj[path[-1]] - int(rng.integers(1, 400)))  # overlap
            elif r < 0.25 and path[-1] == "digest":
                obj[path[-1]] = digest(rng.bytes(8))  # lying digest
            elif r < 0.45 and is_int:
                obj[path[-1]] = int(obj[path[-1]]) + int(rng.integers(-3, 4))
            else:
                obj[path[-1]] = HOSTILE[int(rng.integers(len(HOSTILE)))]
        try:
            return join_glb(gltf, sample.bin)
        except (ValueError, OverflowError):
            return data
    if kind == "zstd":
        claim = int(rng.choice([2**30, 2**31 - 1, 2**33, 2**40, 2**62]))
        frame = (b"\x28\xb5\x2f\xfd" + bytes([0xE4]) + claim.to_bytes(8, "little")
                 + (1 | (0 << 1) | (3 << 3)).to_bytes(3, "little") + b"abc" + rng.bytes(4))
        if rng.random() < 0.3:
            import zstandard

            frame = zstandard.ZstdCompressor(level=1, write_checksum=True).compress(bytes(int(rng.integers(1, 2**16))))
            claim = int(rng.choice([len(frame), 2**30]))
        gltf = copy.deepcopy(sample.gltf)
        ext = gltf["meshes"][0]["primitives"][0]["extensions"][EXTENSION_NAME]
        k = int(rng.integers(len(ext["chunks"])))
        chunk = ext["chunks"][k]
        view = gltf["bufferViews"][chunk["bufferView"]]
        start, old = view["byteOffset"], view["byteLength"]
        if len(frame) > old:
            frame = frame[:old]
        body = bytearray(sample.bin)
        body[start: start + old] = frame + bytes(old - len(frame))
        view["byteLength"] = chunk["byteLength"] = len(frame)
        chunk["digest"] = digest(frame)
        chunk["uncompressedLength"] = claim if rng.random() < 0.7 else int(rng.integers(1, 4096))
        return join_glb(gltf, bytes(body))
    if kind == "claims":
        from pmwm_codec.constants import MAX_VERTICES

        k = int(rng.integers(len(sample.meta)))
        extra = int(rng.choice([1, 1000, 10**5, 10**7, MAX_VERTICES // 2]))
        meta = copy.deepcopy(sample.meta)
        for j in range(k, len(meta)):
            meta[j]["vertexCount"] += extra
            meta[j]["faceCount"] += 2 * extra
        meta[k]["splits"] += extra
        extension = {**sample.extension, "vertexCount": meta[-1]["vertexCount"], "faceCount": meta[-1]["faceCount"]}
        payloads = list(sample.payloads)
        if rng.random() < 0.3:
            payloads[k] = payloads[k][: int(rng.integers(len(payloads[k])))]
        return sample.rebuild(payloads, meta, extension)
    raise ValueError(f"unknown kind {kind!r}")


# ------------------------------------------------------------------ the oracle


def decode_case(data: bytes, key, rng=None) -> str:
    """Decode ``data`` both ways; return the outcome name ('ok' or a PmwError class name).

    Raises whatever non-PmwError the library raised (a finding).
    """
    import pmwm_codec
    from pmwm_codec.stream import StreamDecoder

    outcome = "ok"
    dec = StreamDecoder(key, check_key=False)
    try:
        if rng is None:
            dec.feed(data)
        else:
            i = 0
            while i < len(data):
                step = int(rng.integers(1, 4096))
                dec.feed(data[i: i + step])
                i += step
        dec.close()
    except PmwError as exc:
        outcome = type(exc).__name__
    try:
        for _ in pmwm_codec.iter_decode(data):
            pass
    except PmwError as exc:
        outcome2 = type(exc).__name__
        if outcome == "ok":
            outcome = outcome2
    return outcome


def limit_memory(max_bytes: int | None):
    """Cap the address space (RLIMIT_AS): a huge allocation becomes a MemoryError (a finding)
    instead of the kernel's OOM killer.  Returns the previous limits (for :func:`restore_memory`)."""
    old = resource.getrlimit(resource.RLIMIT_AS)
    if max_bytes is not None:
        hard = old[1]
        soft = max_bytes if hard == resource.RLIM_INFINITY else min(max_bytes, hard)
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))
    return old


def restore_memory(old) -> None:
    resource.setrlimit(resource.RLIMIT_AS, old)


class Timeout(Exception):
    pass


def _alarm(signum, frame):
    raise Timeout()


def run(cases: int, seed: int = 0, seconds: float | None = None, save: str | None = None,
        per_case_timeout: int = 10, trace_every: int = 200, progress: bool = True, kinds=KINDS,
        max_memory: int | None = 4 << 30):
    """Run the fuzzer; returns ``(counts per kind and outcome, findings, stats)``."""
    sample = Sample()
    limit_memory(max_memory)
    rng = np.random.default_rng(seed)
    counts = Counter()
    findings = []
    worst_alloc = (0, None)
    slowest = (0.0, None)
    signal.signal(signal.SIGALRM, _alarm)
    t_start = time.perf_counter()
    done = 0
    for i in range(cases):
        if seconds is not None and time.perf_counter() - t_start > seconds:
            break
        kind = kinds[i % len(kinds)]
        case_seed = int(rng.integers(2**63))
        crng = np.random.default_rng(case_seed)
        data = make_case(sample, kind, crng)
        traced = trace_every and i % trace_every == 0
        if traced:
            tracemalloc.start()
        t0 = time.perf_counter()
        signal.alarm(per_case_timeout)
        try:
            outcome = decode_case(data, sample.key, crng)
        except Timeout:
            outcome = "HANG"
            findings.append((kind, case_seed, "hang", data))
        except BaseException as exc:  # noqa: BLE001 - every other exception is a finding
            if isinstance(exc, KeyboardInterrupt):
                raise
            outcome = "CRASH:" + type(exc).__name__
            findings.append((kind, case_seed, traceback.format_exc(limit=6), data))
        finally:
            signal.alarm(0)
        dt = time.perf_counter() - t0
        if traced:
            _, peak = tracemalloc.get_traced_memory()
            tracemalloc.stop()
            if peak > worst_alloc[0]:
                worst_alloc = (peak, (kind, case_seed))
        if dt > slowest[0]:
            slowest = (dt, (kind, case_seed))
        counts[(kind, outcome)] += 1
        done += 1
        if progress and done % 5000 == 0:
            el = time.perf_counter() - t_start
            print(f"  {done} cases, {el:.0f} s, {len(findings)} findings, max RSS "
                  f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB", flush=True)
    if save and findings:
        os.makedirs(save, exist_ok=True)
        for n, (kind, s, _, data) in enumerate(findings):
            Path(save, f"finding-{n:03d}-{kind}-{s}.pmw").write_bytes(data)
    stats = {
        "cases": done,
        "seconds": time.perf_counter() - t_start,
        "max_rss_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "peak_traced_alloc_mib": worst_alloc[0] / 2**20,
        "peak_traced_case": worst_alloc[1],
        "slowest_case_s": slowest[0],
        "slowest_case": slowest[1],
        "sample_bytes": len(sample.data),
    }
    return counts, findings, stats


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Fuzz the .pmw readers with hostile files.")
    ap.add_argument("--cases", type=int, default=10000)
    ap.add_argument("--seconds", type=float, default=None, help="stop after this many seconds")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--save", type=str, default=None, help="write the files of findings here")
    ap.add_argument("--max-memory-mib", type=int, default=4096,
                    help="address-space cap; a bigger allocation is a MemoryError finding (0: no cap)")
    ap.add_argument("--kinds", type=str, default=",".join(KINDS), help="comma-separated kinds to run")
    ap.add_argument("--kind", choices=KINDS, default=None, help="reproduce one case: with --case-seed")
    ap.add_argument("--case-seed", type=int, default=None)
    args = ap.parse_args(argv)
    if args.kind is not None:
        sample = Sample()
        limit_memory((args.max_memory_mib << 20) or None)
        data = make_case(sample, args.kind, np.random.default_rng(args.case_seed))
        print(decode_case(data, sample.key, np.random.default_rng(args.case_seed)))
        return 0
    counts, findings, stats = run(args.cases, args.seed, args.seconds, args.save, kinds=tuple(args.kinds.split(",")),
                                  max_memory=(args.max_memory_mib << 20) or None)
    outcomes = Counter()
    for (kind, outcome), n in counts.items():
        outcomes[outcome] += n
    print(f"\n{stats['cases']} cases in {stats['seconds']:.0f} s ({stats['cases'] / stats['seconds']:.0f}/s), "
          f"sample file {stats['sample_bytes']} bytes")
    print(f"max RSS {stats['max_rss_mib']:.0f} MiB; peak traced allocation {stats['peak_traced_alloc_mib']:.1f} MiB "
          f"(every 200th case traced; worst {stats['peak_traced_case']}); slowest case {stats['slowest_case_s']:.2f} s "
          f"{stats['slowest_case']}")
    print("\n| outcome | cases |\n|---|---|")
    for outcome, n in outcomes.most_common():
        print(f"| {outcome} | {n} |")
    print("\n| kind | " + " | ".join(sorted(outcomes)) + " |")
    print("|---|" + "---|" * len(outcomes))
    for kind in args.kinds.split(","):
        print(f"| {kind} | " + " | ".join(str(counts.get((kind, o), 0)) for o in sorted(outcomes)) + " |")
    if findings:
        print(f"\n{len(findings)} FINDINGS (non-PmwError, hang):")
        seen = set()
        for kind, s, tb, _ in findings:
            sig = tb.strip().splitlines()[-1]
            if sig in seen:
                continue
            seen.add(sig)
            print(f"--- kind={kind} case_seed={s}  (reproduce: python tools/fuzz.py --kind {kind} --case-seed {s})\n{tb}")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
