"""Verify time of a bound watermark: the cost of the keyed ring binding (spec/watermark.md §5).

Encodes a mesh with a watermark under a fixed key (default: stanford-bunny + camera128, exact
mode), then times, ``--runs`` times each, medians reported:

* ``verify``: :func:`pmwm_codec.verify.stream.verify_stream` of the whole file (decode + verify);
* ``verifier``: the :class:`~pmwm_codec.watermark.verify.Verifier` alone over the geometry decoded
  once (what each key of the wrong-key benchmark costs);
* ``offsets``: :func:`~pmwm_codec.watermark.codec.binding_offsets` alone, with alternatives, over
  every batch's ring descriptors.

Run from the repository root::

    python tools/bench_binding.py [--runs 7] [--keep /tmp/bunny.pmw]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(HERE), HERE]

import pmwm_codec  # noqa: E402
from pmwm_codec.verify.stream import verify_stream  # noqa: E402
from pmwm_codec.watermark import codec as wm  # noqa: E402
from pmwm_codec.watermark.image import load_watermark  # noqa: E402
from pmwm_codec.watermark.key import WatermarkKey  # noqa: E402

from bench_watermark import DEFAULT_CORPUS, DEFAULT_WATERMARKS, run_verifier, verifier_feed  # noqa: E402


def _median_seconds(fn, runs: int) -> float:
    times = []
    for _ in range(runs):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mesh", default=os.path.join(DEFAULT_CORPUS, "stanford-bunny.obj"))
    ap.add_argument("--watermark", default=os.path.join(DEFAULT_WATERMARKS, "camera128.png"))
    ap.add_argument("--runs", type=int, default=7)
    ap.add_argument("--keep", metavar="PMW", help="encode to this path (reused when it exists)")
    args = ap.parse_args(argv)
    key = WatermarkKey.generate(rng=np.random.default_rng(1))
    tmp = tempfile.mkdtemp()
    path = args.keep or os.path.join(tmp, "marked.pmw")
    if not os.path.exists(path):
        t = time.perf_counter()
        pmwm_codec.encode(args.mesh, path, watermark=args.watermark, key=key, measure=False)
        print(f"encode: {time.perf_counter() - t:.1f} s")
    reference, _ = load_watermark(args.watermark)
    blob, params, nbar, feed = verifier_feed(path)
    result = verify_stream(path, key, args.watermark)
    print(f"binding {params.binding!r}, carriers {params.carriers}, verdict {result.verdict}, "
          f"codes {result.codes_matched}/{result.codes_read}")
    descs = [(c, c.descriptor) for c in feed]

    def offsets():
        off = 0
        for j, (c, d) in enumerate(descs):
            k = len(c.points)
            wm.binding_offsets(wm.binding_key(key), wm.carrier_slots(key, j, off, k), d,
                               params.bits, alternatives=True)
            off += k

    rows = {
        "verify": _median_seconds(lambda: verify_stream(path, key, args.watermark), args.runs),
        "verifier": _median_seconds(lambda: run_verifier(params, key, nbar, reference, feed), args.runs),
        "offsets": _median_seconds(offsets, args.runs),
    }
    for name, sec in rows.items():
        print(f"{name:9s} median of {args.runs}: {sec * 1000:.1f} ms")


if __name__ == "__main__":
    main()
