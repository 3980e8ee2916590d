"""``pmw cut IN.pmw|URL|- --chunks N -o OUT.pmw``: any prefix of a ``.pmw`` as a valid, smaller ``.pmw``.

Thin over :func:`pmwm_codec.stream.cut.cut_file`; the output is written atomically
(:func:`pmwm_codec.format.glb.write_parts`).  A URL is read by ranges: the base, the
first N chunks, and the document's other data (images) only where it lies past them.
"""

from __future__ import annotations

from pmwm_codec.format.glb import write_parts
from pmwm_codec.http import as_source, is_url
from pmwm_codec.sources import shown_path
from pmwm_codec.stream.cut import cut_file

from .common import UsageError, check_input_file, check_pmw_output, naming, notice, print_json


def add_parser(sub):
    p = sub.add_parser(
        "cut", help=".pmw (whole, cut, a URL or on stdin) -> valid smaller .pmw",
        description="Write a complete, valid .pmw holding the base mesh and the first N vertex-split chunks "
                    "of IN (whole, truncated, an http(s) URL, or '-' for standard input): GLB length, JSON "
                    "chunk index and BIN agree, so strict glTF tools accept it. It decodes to the same mesh as "
                    "'pmw decode IN --chunks N' and verifies with IN's key.")
    p.add_argument("input", metavar="IN.pmw", help="the .pmw, an http(s) URL (read by ranges: nothing of the "
                                                 "chunks after N is fetched), or - for standard input")
    p.add_argument("-o", "--output", required=True, metavar="OUT.pmw", help="the .pmw to write")
    p.add_argument("--chunks", type=int, metavar="N",
                   help="keep the base mesh and N chunks (default: every chunk that arrived whole)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    p.set_defaults(run=run)


def run(args) -> int:
    if args.chunks is not None and args.chunks < 0:
        raise UsageError(f"--chunks must be >= 0, got {args.chunks}")
    url = is_url(args.input)
    if not url:
        check_input_file(args.input, ".pmw file", stdin=True)
    check_pmw_output(args.output, inputs=() if url else (args.input,))
    with naming(args.input):
        result = cut_file(as_source(args.input, args.chunks, whole_document=True), args.chunks)
    _refuse_orphaned_key(args.output, result.data)
    write_parts(args.output, [result.data])
    notices = []
    if args.chunks is not None and args.chunks > result.chunks:
        notices.append(f"--chunks {args.chunks}: the input holds {result.chunks_available} whole chunks "
                       f"(of {result.chunks_total}); kept {result.chunks}")
    out = {"output": args.output, "bytes": len(result.data), "chunks": result.chunks,
           "chunks_available": result.chunks_available, "chunks_total": result.chunks_total,
           "input_complete": result.source_complete, "notices": notices}
    if args.json:
        print_json(out)
        return 0
    for note in notices:
        notice(note)
    if not args.quiet:
        print(f"{shown_path(args.output)}: {out['bytes']:,} bytes, base + {result.chunks} of {result.chunks_total} chunks")
    return 0


def _refuse_orphaned_key(output, data: bytes) -> None:
    """Refused (:func:`~pmwm_codec.watermark.key.refuse_orphaned_beside`, as ``pmw encode`` refuses it) when a key
    file lies beside ``output`` (``OUT.pmw.key.json``) and the cut ``data`` does not carry that key's mark: replacing
    the file would leave the key beside a file it does not verify.  A cut of the key's own file is taken: a file
    with a watermark image names its key's fingerprint; one with the owner layer alone names none, and is taken
    when the key beside reads its owner ID ``present`` in the cut's last level (:func:`_owner_read_beside`)."""
    import os

    from pmwm_codec.format.reader import read_header
    from pmwm_codec.watermark.key import KEY_SUFFIX, refuse_orphaned_beside

    key_path = os.fspath(output) + KEY_SUFFIX
    marks = (read_header(data).extension.get("watermark") or {}).get("keyFingerprint")
    states = ("carries no watermark", "is marked with another key")
    if marks is None:
        read = _owner_read_beside(key_path, data)
        if read == "present":
            return
        if read is not None:
            states = (f"does not read as the key's owner ID (it carries no watermark image, and its owner layer "
                      f"reads {read})", states[1])
    refuse_orphaned_beside(key_path, output, marks is not None, fingerprint=marks, writer="the cut file", states=states)


def _owner_read_beside(key_path: str, data: bytes) -> str | None:
    """The owner verdict (``present`` | ``absent`` | ``inconclusive``) that the key at ``key_path`` reads in the last
    level of the ``.pmw`` ``data``; None when no readable key with an owner ID lies there."""
    import os

    from pmwm_codec.errors import PmwError
    from pmwm_codec.verify.owner import owner_of_stream
    from pmwm_codec.watermark.key import WatermarkKey

    if not os.path.isfile(key_path):
        return None
    try:
        key = WatermarkKey.load(key_path)
    except PmwError:
        return None  # refused as any key beside a file it does not verify
    if key.owner_id is None:
        return None
    return owner_of_stream(data, key, last_only=True)[-1].owner.verdict
