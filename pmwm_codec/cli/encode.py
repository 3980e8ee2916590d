"""``pmw encode INPUT -o OUT.pmw``: a mesh (and optionally a watermark image) to a ``.pmw``."""

from __future__ import annotations

import argparse
import os

import numpy as np

import pmwm_codec
from pmwm_codec.constants import MAX_GRID_BITS, MIN_GRID_BITS
from pmwm_codec.distortion import MEASURES
from pmwm_codec.format.extension import DEFAULT_PAYLOAD_VERSION, PAYLOAD_VERSIONS
from pmwm_codec.options import IMAGE_OPTIONS, ignored_without_image
from pmwm_codec.sources import shown_path
from pmwm_codec.watermark.codec import MAX_BITS, MODES, CapacityError, shrink_watermark, watermark_words
from pmwm_codec.watermark.image import load_watermark
from pmwm_codec.watermark.key import KEY_SUFFIX

from .common import (Progress, UsageError, check_input_file, check_output_path, check_pmw_output, fmt_float,
                     nonblank_path, notice, print_json, stage_progress)


def _int_in(lo, hi, what):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} must be an integer, got {text!r}") from None
        if not lo <= value <= (hi if hi is not None else value):
            bound = f"{lo}..{hi}" if hi is not None else f">= {lo}"
            raise argparse.ArgumentTypeError(f"{what} must be {bound}, got {value}")
        return value
    return parse


def _start(text):
    """``--embed-from``: a split index (``2031``) or a fraction of the splits (``0.066``)."""
    try:
        value = float(text) if any(c in text for c in ".eE") else int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"--embed-from must be a split index or a fraction, got {text!r}") from None
    if not (0 <= value < (1 if isinstance(value, float) else value + 1)):
        raise argparse.ArgumentTypeError(f"--embed-from must be an index >= 0 or a fraction in [0, 1), got {text}")
    return value


def owner_id_arg(text):
    from pmwm_codec.watermark.key import parse_owner_id

    try:
        return parse_owner_id(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None  # argparse names the option


def add_parser(sub):
    p = sub.add_parser(
        "encode", help="mesh (+ watermark) -> progressive .pmw",
        description="Encode a mesh (OBJ, PLY, STL, OFF) or a glTF asset (GLB/glTF: every triangle primitive becomes "
                    "progressive, materials, textures and nodes are kept) into a progressive .pmw; with --watermark, "
                    "hide the image in the vertex splits and write the secret key beside the output.")
    p.add_argument("input", help="mesh file")
    p.add_argument("-o", "--output", required=True, metavar="OUT.pmw", help="the .pmw to write")
    p.add_argument("--watermark", metavar="IMG", help="grayscale watermark image (made square, 2^k)")
    p.add_argument("--owner-id", type=owner_id_arg, metavar="HEX",
                   help="the 64-bit owner ID (1-16 hex digits, a 0x before them allowed) of the owner layer, which survives transport and "
                        "processing and is read blind by 'pmw verify MESH --key KEY' (default with --watermark: the "
                        "key's, random for a new key, left out with a note where it would not read back); alone, "
                        "without --watermark, it is the only mark.  Refused (nothing written) where the layer would "
                        "not read back from the file: a mesh whose vertex norms span too narrow a range (a sphere) "
                        "or take too few values")
    p.add_argument("--no-owner", action="store_true",
                   help="with --watermark: write the exact layer only, no owner layer")
    p.add_argument("--key", type=nonblank_path("--key", "key file"), metavar="KEY", help="key file to use (if it exists) or to write (default: OUT.pmw.key.json). Without --watermark an existing key marks with what it holds: its own watermark image (one key marks every asset alike) or, holding none, its owner ID alone; a key that does not exist then needs --owner-id")
    add_stream_options(p)
    p.add_argument("--fit", action="store_true",
                   help="shrink a watermark that does not fit to the largest size that does (with a notice)")
    p.add_argument("--measure", choices=MEASURES, default="vertices",
                   help="distortion: vertices (default: exact RMS/PSNR, Hausdorff bounded by the largest vertex "
                        "displacement), sampled (Metro-style surface Hausdorff, slower) or none")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success (notes still go to stderr)")
    p.set_defaults(run=run)


#: The defaults of :func:`add_stream_options` that are not None.
STREAM_DEFAULTS = {"mode": "exact", "base_codec": "draco", "payload_version": DEFAULT_PAYLOAD_VERSION}


def add_stream_options(p) -> None:
    """The options that decide how a mesh becomes a stream (``pmw encode`` and ``pmw batch encode``)."""
    p.add_argument("--mode", choices=MODES, default=STREAM_DEFAULTS["mode"], help="exact (default: bit-exact watermark) or paper (Eq. 4)")
    p.add_argument("--bits", type=_int_in(1, MAX_BITS, "--bits"), metavar="B", help="bits per code (default: automatic)")
    p.add_argument("--embed-from", type=_start, metavar="N",
                   help="first vertex split that carries a code, counted from the base mesh over the stream "
                        "(an index, or a fraction of the splits such as 0.25; default 0); stored in the file")
    p.add_argument("--grid-bits", type=_int_in(MIN_GRID_BITS, MAX_GRID_BITS, "--grid-bits"), metavar="Q",
                   help="position grid resolution in bits (default 16; paper mode 22).  The vertex attributes of "
                        "glTF assets have grids of their own, over each component's range: NORMAL and TANGENT 14 "
                        "bits, COLOR_n 12 (8-bit colours exact, on their own 8-bit lattice), other float attributes 14; TEXCOORD_n a step of at most 1/8192 of the "
                        "texture (error under 1/16384: a quarter texel at 4096x4096) whatever the range, up to 30 "
                        "bits; integer attributes (feature IDs) exact")
    p.add_argument("--base-codec", choices=("draco", "plain"), default=STREAM_DEFAULTS["base_codec"],
                   help="how the base mesh is stored")
    p.add_argument("--payload-version", type=int, choices=PAYLOAD_VERSIONS, default=STREAM_DEFAULTS["payload_version"],
                   help="chunk payload format: 2 (range-coded, compact chunk index; default) or 1 (zstd "
                        "columns, one index entry per chunk: the format of files written before)")
    p.add_argument("--base-vertices", type=_int_in(4, None, "--base-vertices"), metavar="N",
                   help="target base mesh size (default 1%% of the vertices, at least 64)")
    p.add_argument("--strip-image-profiles", action="store_true",
                   help="glTF assets: drop colour-profile chunks from PNG textures (same pixels; "
                        "the glTF validator warns on them)")
    p.add_argument("--keep-flat-normals", action="store_true",
                   help="glTF assets: keep a flat-shaded primitive's NORMAL (by default dropped, as viewers "
                        "compute the same flat normals, so that it streams; kept, it stays in the base)")
    p.add_argument("--geometry-only", action="store_true",
                   help="carry the input's positions and faces alone: an OBJ's or PLY's texture coordinates, "
                        "colours and materials, and a glTF asset's document (its triangle primitives merged as "
                        "its default scene places them), are not carried")


def stream_options(args, *, defaults: bool = True) -> dict:
    """The :func:`pmwm_codec.encode` options of :func:`add_stream_options`: those given, and with
    ``defaults`` the :data:`STREAM_DEFAULTS` of those not given."""
    options = {name: getattr(args, name) for name in STREAM_DEFAULTS
               if defaults or getattr(args, name) != STREAM_DEFAULTS[name]}
    for name in ("bits", "grid_bits", "base_vertices", "embed_from"):
        if getattr(args, name) is not None:
            options[name] = getattr(args, name)
    if args.strip_image_profiles:
        options["strip_image_profiles"] = True
    if args.keep_flat_normals:
        options["keep_flat_normals"] = True
    if args.geometry_only:
        options["geometry_only"] = True
    return options


def run(args) -> int:
    check_input_file(args.input, "mesh file")
    if args.watermark is not None:
        check_input_file(args.watermark, "watermark image")
    check_pmw_output(args.output, inputs=(args.input, args.watermark))  # --key = -o: the library names it
    if args.key is not None and not os.path.exists(args.key):
        check_output_path(args.key, "key", inputs=(args.input, args.watermark), key=True)
    # an encode without a mark beside a key it would orphan: refused by the library before any work
    progress = Progress(not (args.json or args.quiet))
    options = {**stream_options(args), "measure": args.measure, "progress": stage_progress(progress)}
    if args.owner_id is not None:
        options["owner_id"] = args.owner_id
    if args.no_owner and args.owner_id is not None:
        raise UsageError("--no-owner and --owner-id exclude each other")
    extra = []
    image = args.watermark is not None or _key_image(args)  # an image to mark with: given, or the key's own
    if args.no_owner:
        options["owner_id"] = False
        if not image:
            extra.append("--no-owner ignored: no --watermark, so the file carries no mark")  # with --key: refused
    if not image:  # the image's options: none of them changes a file without an image
        given = {"--embed-from": args.embed_from is not None, "--bits": args.bits is not None,
                 f"--mode {args.mode}": args.mode != STREAM_DEFAULTS["mode"], "--fit": args.fit}
        extra += ignored_without_image([name for name, on in given.items() if on], "--watermark")
        options = {name: value for name, value in options.items() if name not in IMAGE_OPTIONS}  # said above
    try:
        report = _encode_fitting(args, options, extra)
    except ValueError as exc:
        if isinstance(exc, pmwm_codec.PmwError):
            raise
        raise UsageError(str(exc)) from None  # an option the library refused (e.g. --bits for --mode paper)
    finally:
        progress.done()
    report["notices"] = list(report.get("notices") or []) + extra
    if args.json:
        print_json(report)
        return 0
    # the notes (what was adjusted, left out or shrunk) go to stderr, as decode's and cut's, with or without -q:
    # stdout holds the summary alone
    for note in report["notices"]:
        notice(note)
    if not args.quiet:
        print(summary(args.input, args.output, report))
    return 0


def _key_image(args) -> bool:
    """Whether the existing ``--key`` holds a watermark image, which an encode without ``--watermark`` marks
    with (the library's rule: one key marks every asset alike); a key file that cannot be read is the
    library's to refuse (one line, exit 2)."""
    if args.key is None or not os.path.isfile(args.key):
        return False
    try:
        return pmwm_codec.load_key(args.key).reference is not None
    except pmwm_codec.PmwError:
        return False


def _encode_fitting(args, options: dict, notices: list) -> dict:
    """Encode; with ``--fit``, a watermark too large for the mesh is shrunk to the largest
    size that fits (the library's CapacityError names it) and the encode runs again.  An existing
    key that holds this very image as ``--fit`` shrank it is reused with that image (:func:`_fitted_by_key`)."""
    watermark = _fitted_by_key(args, notices)
    if watermark is None:
        watermark = args.watermark
    try:
        return pmwm_codec.encode(args.input, args.output, watermark=watermark, key=args.key, **options)
    except CapacityError as exc:
        if not args.fit or not exc.largest_size or args.watermark is None:
            raise
        image, _ = load_watermark(args.watermark)
        size = exc.largest_size
        notices.append(f"--fit: {watermark_words(exc.size, exc.given)} shrunk to {size}x{size}, "
                       "the largest size this mesh carries")
        return pmwm_codec.encode(args.input, args.output, watermark=shrink_watermark(image, size), key=args.key,
                                 **options)


def _fitted_by_key(args, notices: list):
    """With ``--fit``, the image the existing key (``--key``, else ``OUT.pmw.key.json``) holds when it is
    ``--watermark`` as ``--fit`` shrank it on an earlier run, with a note; else None.  Without this the same
    command run again (or for the next asset of one collection key) was refused: the key holds the shrunk
    image, which is not the image named, though it is the one ``--fit`` marks with."""
    if not args.fit or args.watermark is None:
        return None
    path = args.key if args.key is not None else os.fspath(args.output) + KEY_SUFFIX
    if not os.path.isfile(path):
        return None
    try:
        reference = pmwm_codec.load_key(path).reference
    except pmwm_codec.PmwError:
        return None  # the library names what is wrong with it
    if reference is None or reference.ndim != 2 or reference.shape[0] != reference.shape[1]:
        return None
    image, _ = load_watermark(args.watermark)
    size = int(reference.shape[0])
    if size >= image.shape[0] or not np.array_equal(shrink_watermark(image, size), reference):
        return None
    notices.append(f"--fit: {watermark_words(image.shape[0], None)} shrunk to {size}x{size}, as the key {path} "
                   "holds it")
    return reference


def summary(src, dst, r) -> str:
    """The human summary of an encode report."""
    d = r["distortion"] or {}
    lines = [f"{shown_path(os.path.basename(os.fspath(src)))} -> {shown_path(dst)}  ({r['bytes']:,} bytes, {r['seconds']:.1f} s)",
             f"  mesh        {r['vertices']:,} vertices, {r['faces']:,} faces",
             f"  base        {r['base_vertices']:,} vertices, {r['base_faces']:,} faces ({r.get('base_codec', '?')})",
             f"  stream      {r['vsplits']:,} vertex splits in {r['chunks']} chunks"]
    if d.get("rms") is not None:
        diag = d.get("bbox_diagonal") or 0.0
        haus = d.get("hausdorff")
        lines.append(f"  distortion  RMS {d['rms']:.3g} (diagonal {diag:.3g}), PSNR {fmt_float(d.get('psnr_db'), 1, ' dB')}"
                     + ("" if haus is None else f", Hausdorff {'<= ' if d.get('measure') == 'vertices' else ''}"
                                                f"{100 * haus:.3g}% of the diagonal"))
    w = r.get("watermark")
    if w:
        # ``codes`` (the --json field): exact mode, the bits of one copy of the message; paper, its coefficients
        held = f"{w['codes']:,} message bits" if w["mode"] == "exact" else f"{w['codes']:,} coefficients"
        lines.append(f"  watermark   {w['width']}x{w['height']}, {w['mode']} mode, {w['bits']} bits per code, "
                     f"{held} on {w['embedded']:,} carriers")
        if r.get("key_path"):
            lines.append(f"  key         {shown_path(r['key_path'])}  (secret: verify needs it)")
    else:
        lines.append("  watermark   none")
    if r.get("owner_id"):
        lines.append(f"  owner       {r['owner_id']} (64-bit owner layer)"
                     + (f", key {r['key_path']}" if r.get("key_path") and not w else ""))
    return "\n".join(lines)
