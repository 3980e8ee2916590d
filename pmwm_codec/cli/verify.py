"""``pmw verify IN.pmw|URL|- --key KEY``: read the watermark at every chunk boundary and decide.

``pmw verify MESH --key KEY`` (OBJ, PLY, STL, OFF, glTF/GLB, no ``--reference``) reads the owner
layer blind.  Exit status: 0 authentic (a mesh: owner ``present``; a ``.pmw`` without an
image watermark: owner ``present`` at the end); 1 tampered, not-authentic, absent or inconclusive;
2 bad input.  A chunk whose keyed MAC fails is named on its own line ("chunk 7: not written
by the key holder (MAC mismatch)"), and so is a scene that is not the key holder's (its ``sceneMac``
fails: verdict ``tampered``), not arrived yet or not covered, and a file that holds only a prefix of
the key holder's stream ("a prefix of the key holder's stream: 746 of 2,839 carriers read").
``--frames DIR`` also draws the tamper map (``tamper.png``: flagged vertices in red).
"""

from __future__ import annotations

import os

import pmwm_codec
from pmwm_codec.http import UrlSource, is_url
from pmwm_codec.verify import StreamVerification, verify_stream

from .common import (EXIT_NOT_AUTHENTIC, EXIT_OK, Progress, UsageError, check_input_file, check_output_path,
                     fmt_float, naming, nonblank_path, print_json)


def add_parser(sub):
    p = sub.add_parser(
        "verify", help="read the watermark chunk by chunk; exit 0 if authentic",
        description="Verify the watermark of a .pmw (whole, truncated, or '-' for standard input) at every "
                    "chunk boundary. Exit status: 0 authentic, 1 tampered, not authentic or inconclusive, 2 bad input.")
    p.add_argument("input", metavar="IN.pmw|URL|MESH",
                   help="the .pmw, an http(s):// URL of one (read by Range requests when the server allows), or - for "
                        "standard input; with --reference, a mesh file that left the stream")
    p.add_argument("--key", required=True, type=nonblank_path("--key", "key file"), metavar="KEY", help="the key file written by pmw encode")
    p.add_argument("--watermark", metavar="IMG", help="expected watermark image (default: the one in the key)")
    p.add_argument("--frames", metavar="DIR", help="write the partial watermark per chunk, an overview and a plot")
    p.add_argument("--reference", metavar="ORIGINAL.pmw",
                   help="verify a mesh that left the stream (exported, moved, re-saved) against the original .pmw")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing; only the exit status")
    p.set_defaults(run=run)


def _check_common(args) -> None:
    """The key, the optional watermark image and the --frames directory, before any work."""
    check_input_file(args.key, "key file")
    if args.watermark is not None:
        check_input_file(args.watermark, "watermark image")
    if args.frames == "-":
        raise UsageError("-: --frames writes pictures into a directory, not to standard output; give a directory name")
    if args.frames is not None and os.path.exists(args.frames) and not os.path.isdir(args.frames):
        raise UsageError(f"{args.frames}: exists and is not a directory (--frames needs a directory)")


def _check_pictures(args, paths) -> None:
    """UsageError, before any picture is written, when one of ``paths`` (the files ``--frames`` will
    write) is an input of the command (the stream, the key, the watermark image, the reference, or
    the file standard input reads), a key file, or not a file that can be replaced."""
    if not os.path.isdir(args.frames):
        return  # made by the write: nothing in it yet
    inputs = [args.input, args.key, args.watermark, getattr(args, "reference", None)]
    for path in paths:
        check_output_path(path, "--frames picture", inputs=inputs)


def _is_mesh_file(path: str) -> bool:
    """A mesh file by its suffix, unless it is a GLB that is a progressive stream (a ``.pmw`` renamed
    ``.glb``: verified as the stream it is, not as its base mesh)."""
    from pmwm_codec.format.document import is_progressive_file
    from pmwm_codec.mesh import MESH_SUFFIXES

    return path != "-" and os.path.splitext(path)[1].lower() in MESH_SUFFIXES and not is_progressive_file(path)


def run(args) -> int:
    if args.reference is not None:
        return run_reference(args)
    url = is_url(args.input)
    if not url and _is_mesh_file(args.input):
        return run_owner(args)
    if not url:
        check_input_file(args.input, ".pmw file", stdin=True)
    _check_common(args)
    progress = Progress(not (args.json or args.quiet))
    source = UrlSource(args.input) if url else args.input
    try:
        with naming(args.input):
            key = pmwm_codec.load_key(args.key)
            # the owner layer read in the same pass as the image; a file's levels in the frames of its full decode
            reader = _owner_reader(key, None if url or args.input == "-" else args.input)
            outcome = verify_stream(source, key, args.watermark, keep_meshes=args.frames is not None,
                                    progress=progress, each=None if reader is None else reader.add)
            owners = [] if reader is None else reader.boundaries
    finally:
        progress.done()
    pictures = None
    if args.frames is not None:
        from pmwm_codec.figures import figure_paths, write_figures

        _check_pictures(args, figure_paths(outcome.results, args.frames, tamper=outcome.marked))
        name = "stdin" if args.input == "-" else os.path.basename(args.input.rstrip("/"))
        title = f"{name}: {outcome.verdict}" + ("" if outcome.end.complete else " (truncated)")
        pictures = write_figures(outcome.results, args.frames, title=title, total_bytes=outcome.total_length,
                                 bytes_received=outcome.end.bytes_read,
                                 tamper=outcome.flagged if outcome.marked else None,
                                 inputs=[p for p in (args.input, args.key, args.watermark) if p and p != "-"])
    if args.json:
        doc = outcome.as_json()
        # ``owner`` is a field of every verify object (DESIGN.md §5): null where the key names no owner ID
        # (written with --no-owner, or before the owner layer), so nothing is read
        for n, chunk in enumerate(doc["chunks"]):
            boundary = owners[n] if n < len(owners) else None
            chunk["owner"] = None if boundary is None else {**boundary.owner.as_json(),
                                                            "read_at_chunk": boundary.read_at}
        doc["owner"] = owners[-1].owner.as_json() if owners else None
        if pictures is not None:
            doc["pictures"] = pictures
        print_json(doc)
    elif not args.quiet:
        print(report(outcome, pictures, owner_only=bool(owners) and not outcome.marked))
        if owners:
            print(owner_report(owners, key))
    if not outcome.marked and owners:  # an owner-only file: the owner layer decides
        return EXIT_OK if owners[-1].owner.verdict == "present" else EXIT_NOT_AUTHENTIC
    return EXIT_OK if outcome.verdict == "authentic" else EXIT_NOT_AUTHENTIC


def _owner_reader(key, path=None):
    """An :class:`~pmwm_codec.verify.owner.OwnerReader` for the key's owner layer (None: the key carries no owner
    id); ``path``: a ``.pmw`` file whose levels are read in the frames of its full decode (a first pass, its
    frames computed from the decoded mesh: :func:`~pmwm_codec.verify.owner.full_decode_frames`); None (a URL or
    standard input, read as it arrives): each level in its own."""
    if key.owner_id is None:
        return None
    from pmwm_codec.verify.owner import OwnerReader, full_decode_frames

    return OwnerReader(key, frames=None if path is None else full_decode_frames(path))


def owner_report(owners, key) -> str:
    """Human lines: the owner layer at each chunk boundary it was read at (``key`` the key read with), and from
    how many bytes it is present."""
    lines = [f"{'chunk':>5} {'bytes':>11} {'vertices':>9}  owner"]
    for b in owners:  # the boundaries it was read at (one between carries the read before it)
        if b.read_at != b.chunk:
            continue
        o = b.owner
        lines.append(f"{b.chunk:>5} {b.bytes_read:>11,} {b.vertices:>9,}  {o.verdict} ({o.bit_errors}/64 bit errors, "
                     f"P_fa {o.false_alarm_probability:.1e})")
    first = next((b for b in owners if b.owner.verdict == "present"), None)
    lines.append(f"owner {_owner_line(owners[-1].owner, key)}"
                 + (f" (present from {first.bytes_read:,} bytes)" if first else ""))
    return "\n".join(lines)


def _owner_line(o, key) -> str:
    """``ID: verdict`` of an owner read, the ID always the key's (the bits read are no ID unless ``present``):
    with the bits read beside it when some differ."""
    if o.verdict == "present" and not o.bit_errors:
        return f"{key.owner_hex}: present"
    return f"{key.owner_hex}: {o.verdict} (read as {o.id}: {o.bit_errors} of {o.bits} bits differ{_erased(o)})"


def _erased(o) -> str:
    """How many of the bits that differ no vertex carried (not read: not counted against the verdict)."""
    return f", {o.erased} of them in shells no vertex falls in (not read)" if o.erased else ""


def run_owner(args) -> int:
    """``pmw verify MESH --key KEY``: the owner layer, read blind from any mesh file."""
    check_input_file(args.input, "mesh file")
    check_input_file(args.key, "key file")
    # this form reads the owner layer alone: no image is compared and no picture drawn, so an option asking for
    # either would be dropped in silence (exit 0, nothing written); said instead, before any work
    for option, given in (("--watermark", args.watermark), ("--frames", args.frames)):
        if given is not None:
            raise UsageError(f"{option}: 'pmw verify MESH --key KEY' (no --reference) reads the owner layer alone, "
                             f"which compares no image and draws no picture; add --reference ORIGINAL.pmw to check "
                             f"the image watermark (and write pictures), or leave {option} out")
    mesh, key, o = _blind_owner(args)
    if args.json:
        print_json({"input": args.input, "vertices": mesh.vertex_count, "owner": o.as_json(), "verdict": o.verdict})
    elif not args.quiet:
        print(f"{args.input}: {mesh.vertex_count:,} vertices; owner read {o.id}: {o.bit_errors}/64 bits differ "
              f"from the key's {key.owner_hex}{_erased(o)}, false-alarm probability {o.false_alarm_probability:.2e}")
        print(f"verdict: {o.verdict}")
    return EXIT_OK if o.verdict == "present" else EXIT_NOT_AUTHENTIC


def _blind_owner(args, key=None, scene=None) -> tuple:
    """``(mesh, key, owner)``: the owner layer of the mesh file ``args.input`` read blind with ``args.key`` (the
    :class:`~pmwm_codec.mesh.Mesh` read, the key, an :class:`~pmwm_codec.watermark.owner.OwnerResult`); ``key``,
    ``scene``: the key and the file's :func:`~pmwm_codec.mesh.read_mesh` mesh when already loaded."""
    from pmwm_codec.verify.owner import owner_key, owner_of_mesh, owner_view

    with naming(args.input):
        mesh = owner_view(args.input, scene)
    with naming(args.key):
        key = owner_key(args.key) if key is None else key
        return mesh, key, owner_of_mesh(mesh, key)


def run_reference(args) -> int:
    """``pmw verify MESH --reference ORIGINAL.pmw --key KEY``: one verdict for a mesh file."""
    from pmwm_codec.verify.mesh import verify_mesh  # registration (scipy): loaded only for this form
    from pmwm_codec.watermark.key import as_key

    if args.input == "-":  # read_mesh takes a file, whose suffix names its format
        raise UsageError("-: verify MESH --reference reads the mesh from a file (its suffix names its format), "
                         "not from standard input; give the mesh file's name")
    check_input_file(args.input, "mesh file")
    check_input_file(args.reference, "reference .pmw", stdin=True)
    _check_common(args)
    with naming(args.input):
        mesh = pmwm_codec.read_mesh(args.input)
    with naming(args.key):
        key = as_key(args.key)  # read once: the image's check and the owner layer's
    with naming(args.reference):
        v = verify_mesh(mesh, args.reference, key, args.watermark)
    owner = None if key.owner_id is None else _blind_owner(args, key, mesh)[1:]
    if args.frames is not None:
        from pmwm_codec.figures import TAMPER_NAME, remove_stale, tamper_figure, write_pictures
        from pmwm_codec.watermark.image import gray_image

        names = ("watermark.png", TAMPER_NAME)
        _check_pictures(args, [os.path.join(args.frames, name) for name in names])
        title = f"{os.path.basename(args.input)}: {v.verdict}"
        write_pictures(args.frames, {names[0]: gray_image(v.watermark),
                                     names[1]: tamper_figure(mesh.positions, mesh.faces, v.flagged, v.watermark,
                                                             title=title)})
        # an earlier run's frames, overview and plot: the folder shows this mesh's pictures, as the stream form's does
        remove_stale(args.frames, set(names),
                     [p for p in (args.input, args.key, args.watermark, args.reference) if p and p != "-"])
    if args.json:
        print_json({**v.as_json(), "owner": None if owner is None else owner[1].as_json()})
    elif not args.quiet:
        whom = "the reference" if v.level is None else \
            f"the reference's level after {v.level:,} of {v.chunks_total:,} chunks"
        print(f"{args.input}: {v.vertices:,} vertices matched to {whom} by {v.correspondence} "
              f"({100 * v.coverage:.1f}% of its vertices); {v.carriers_read:,} of {v.carriers_total:,} codes read")
        print(f"NC {fmt_float(v.nc, 4)}  PSNR {fmt_float(v.psnr_db, 2)} dB  BER {fmt_float(v.ber, 4)}"
              + ("  (bit-exact)" if v.bit_exact and not v.image_note else ""))
        if v.image_note:  # a bit-exact image the verdict does not vouch for: said so, not marked a match
            print(v.image_note)
        if v.reference_note():
            print(v.reference_note())
        if owner is not None:
            print(f"owner {_owner_line(owner[1], owner[0])}, false-alarm probability "
                  f"{owner[1].false_alarm_probability:.2e}")
        print(f"verdict: {v.verdict}" + _tamper_note(v.tamper(), v.binding)
              + ("" if v.key_matches else " (the reference is marked with another key: its key fingerprint differs)"))
    return EXIT_OK if v.verdict == "authentic" else EXIT_NOT_AUTHENTIC


def report(o: StreamVerification, pictures=None, owner_only: bool = False) -> str:
    """The human table: one row per chunk boundary, then the verdict.  ``owner_only``: the file carries no
    image and the key's owner layer is reported after this (:func:`owner_report`), which decides the exit
    status: no image rows (they would read no code at any boundary), and the verdict line says so."""
    lines = []
    if not owner_only:
        lines.append(f"{'chunk':>5} {'bytes':>11} {'vertices':>9} {'faces':>9} {'coeffs':>7} {'NC':>7} {'PSNR dB':>8}")
        for r in o.results:
            lines.append(f"{r.chunk:>5} {r.bytes_read:>11,} {r.vertices:>9,} {r.faces_count:>9,} "
                         f"{r.coefficients:>7,} {fmt_float(r.nc, 4):>7} {fmt_float(r.psnr_db, 2):>8}")
    applied = o.results[-1].chunk
    if o.end.complete:
        lines.append(f"complete: {o.end.bytes_read:,} bytes, base + {applied} of {o.end.chunks_total} chunks")
    else:
        lines.append(f"truncated: {o.end.bytes_read:,} of {o.total_length:,} bytes arrived, "
                     f"base + {applied} of {o.end.chunks_total} chunks")
    if not o.marked and owner_only:
        why = "the file carries no watermark image; its owner layer, below, decides the exit status"
    elif not o.marked:
        why = "the file carries no watermark"
    elif not o.key_matches:
        why = "the file is marked with another key: its key fingerprint differs"
    elif o.codes_read:
        why = f"{o.codes_matched:,} of {o.codes_read:,} codes match"
    else:
        why = "no codes read yet"
    lines.append(f"verdict: {o.verdict} ({why})" + (_tamper_note(o.tamper(), o.binding) if o.marked else ""))
    lines += o.mac_notes()
    if o.image_note():
        lines.append(o.image_note())
    if o.stream_note():
        lines.append(o.stream_note())
    if pictures:
        lines.append(f"pictures: {len(pictures['frames'])} frames, {pictures['overview']}"
                     + (f", {pictures['plot']}" if pictures.get("plot") else ""))
    return "\n".join(lines)


def _tamper_note(tamper: dict, binding: str) -> str:
    """`` ; N vertices flagged (x%)`` and the legacy-mark notice, for the verdict line."""
    note = ""
    if tamper["flagged"]:
        note += f"; {len(tamper['flagged']):,} vertices flagged ({100 * tamper['fraction']:.2f}%)"
    if not binding:
        note += "; legacy mark without keyed binding: never authentic, re-encode the original"
    return note
