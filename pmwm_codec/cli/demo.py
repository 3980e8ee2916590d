"""``pmw demo [--out DIR]``: build a mesh and a watermark, encode, cut, verify, draw pictures."""

from __future__ import annotations

import argparse
import os
import time

import pmwm_codec
from pmwm_codec.atomic import directory_made, write_atomic
from pmwm_codec.figures import write_figures
from pmwm_codec.shapes import demo_mesh
from pmwm_codec.verify import verify_stream
from pmwm_codec.watermark import make_text_watermark, save_png

from .common import Progress, UsageError, check_output_path, fmt_float, nonblank_path, stage_progress

CUT_FRACTION = 1 / 3


def add_parser(sub):
    p = sub.add_parser("demo", help="encode, cut and verify a generated mesh; write pictures",
                       description="Needs no input: builds a mesh and a text watermark, encodes them into a .pmw, "
                                   "cuts the file at a third of its bytes, verifies the cut and the whole file, and "
                                   "writes pictures of the mesh refining and the watermark sharpening.")
    p.add_argument("--out", default="pmw-demo", type=nonblank_path("--out", "directory"), metavar="DIR",
                   help="output directory (default ./pmw-demo)")
    p.add_argument("--resolution", type=int, default=180, help=argparse.SUPPRESS)
    p.set_defaults(run=run)


def run(args) -> int:
    out = args.out
    if out == "-":  # as verify --frames -: a folder named '-' in the current one is never what was meant
        raise UsageError("-: --out writes files into a directory, not to standard output; give a directory name")
    if os.path.exists(out) and not os.path.isdir(out):
        raise UsageError(f"{out}: exists and is not a directory")
    mark_path, pmw, cut = (os.path.join(out, name) for name in ("watermark.png", "demo.pmw", "demo-cut.pmw"))
    if os.path.isdir(out):  # every name the demo writes, checked before the first is written
        for path in (mark_path, pmw, cut):
            check_output_path(path, "demo file")
        for sub in ("cut", "whole"):
            if os.path.lexists(os.path.join(out, sub)) and not os.path.isdir(os.path.join(out, sub)):
                raise UsageError(f"{os.path.join(out, sub)}: exists and is not a directory (the demo writes its "
                                 "pictures there)")
    with directory_made(out):  # a failure, a Ctrl-C or a SIGTERM leaves no folder made for nothing
        return _run(args, out, mark_path, pmw, cut)


def _run(args, out: str, mark_path: str, pmw: str, cut: str) -> int:
    """The demo's steps, writing into the folder ``out`` (made): ``mark_path``, ``pmw``, ``cut`` and the pictures."""
    t0 = time.perf_counter()
    say = print
    mesh = demo_mesh(args.resolution)
    mark = make_text_watermark("PMWM", 64)
    say(f"1. built a mesh ({mesh.vertex_count:,} vertices, {mesh.face_count:,} faces) and a 64x64 watermark")

    progress = Progress(True)
    try:
        r = pmwm_codec.encode(mesh, pmw, watermark=mark, progress=stage_progress(progress))
    finally:
        progress.done()
    save_png(mark_path, mark)  # after the encode, which refuses a key of another image before writing anything
    d = r["distortion"]
    say(f"2. encoded {pmw}: {r['bytes']:,} bytes, base {r['base_vertices']:,} vertices + {r['vsplits']:,} splits "
        f"in {r['chunks']} chunks; mesh PSNR {fmt_float(d['psnr_db'], 1, ' dB')}; key {r['key_path']}; "
        f"watermark {mark_path}")

    with open(pmw, "rb") as fh:
        data = fh.read()
    write_atomic(cut, [data[: int(len(data) * CUT_FRACTION)]])  # whole or not at all, as every output
    say(f"3. cut the file at a third: {cut} ({int(len(data) * CUT_FRACTION):,} of {len(data):,} bytes)")

    for step, (label, path, sub) in enumerate((("cut", cut, "cut"), ("whole", pmw, "whole")), start=4):
        o = verify_stream(path, r["key_path"], keep_meshes=True)
        last = o.results[-1]
        pics = write_figures(o.results, os.path.join(out, sub),
                             title=f"demo: {label} file, {o.verdict}", total_bytes=o.total_length,
                             bytes_received=o.end.bytes_read)
        state = "truncated" if o.end.truncated else "complete"
        say(f"{step}. verified the {label} file ({state}): base + {last.chunk} of {last.chunks_total} chunks, "
            f"{last.vertices:,} vertices; watermark NC {fmt_float(last.nc, 3)}, PSNR {fmt_float(last.psnr_db, 1, ' dB')}; "
            f"{o.codes_matched:,} of {o.codes_read:,} codes match -> {o.verdict}")
        say(f"   pictures: {pics['overview']}, {pics['plot']}, {len(pics['frames'])} frames in {os.path.join(out, sub)}")
    say(f"done in {time.perf_counter() - t0:.1f} s. Try:  pmw info {cut}   pmw verify {cut} --key {r['key_path']}")
    return 0
