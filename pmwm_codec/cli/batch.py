"""``pmw batch encode SRC -o OUT_DIR`` / ``pmw batch verify OUT_DIR``: whole libraries on Dask.

Exit status: encode 0 when every asset is ok or skipped, 1 when some failed or timed out;
verify 0 when every file is authentic, 1 otherwise; 2 bad usage (or Dask not installed);
130 interrupted (Ctrl-C), 143 terminated (SIGTERM: stopped as a Ctrl-C stops it; :func:`.common.sigterm_stops`),
one line each.
The work is :mod:`pmwm_codec.batch`; this module parses, shows progress and reports.
"""

from __future__ import annotations


import argparse
import os

from .common import EXIT_NOT_AUTHENTIC, EXIT_OK, Progress, UsageError, nonblank_path, print_json
from .encode import add_stream_options, owner_id_arg, stream_options

INSTALL_HINT = 'pmw batch needs Dask: pip install "pmwm_codec[batch]"'


def _positive(kind, what):
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{what} must be a number, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"{what} must be > 0, got {text}")
        return value
    return parse


def _cluster_options(p) -> None:
    p.add_argument("--workers", type=_positive(int, "--workers"), metavar="N",
                   help="local Dask worker processes (default: one per CPU)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="run on an existing Dask cluster (tcp://host:8786) "
                   "whose workers have pmwm_codec installed and share the file system")
    p.add_argument("--no-worker-timeout", type=_positive(float, "--no-worker-timeout"), metavar="S",
                   help="seconds the run goes on while the cluster has no worker (all died, none joined) before it "
                        "stops, exit 2 (default 120)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument("-q", "--quiet", action="store_true", help="print nothing but errors")


def add_parser(sub):
    p = sub.add_parser("batch", help="encode or verify a whole library of meshes (Dask)",
                       description="Encode a folder, glob or manifest of meshes into a mirrored tree of .pmw "
                                   "files, or verify such a tree, on a local or remote Dask cluster.")
    cmds = p.add_subparsers(dest="batch_command", metavar="encode|verify", parser_class=type(p))
    cmds.required = True
    e = cmds.add_parser("encode", help="every mesh of SRC -> OUT_DIR/<relative path>.pmw",
                        description="Encode every mesh (OBJ, PLY, STL, OFF, glTF/GLB) of SRC — a folder (recursively), "
                                    "a glob or a manifest (one path a line) — into OUT_DIR/<relative path>.pmw. "
                                    "A ledger OUT_DIR/pmw-batch.jsonl records each attempt; a re-run skips assets "
                                    "already done with the same input and settings (watermark, key, the options "
                                    "below as 'pmw encode' takes them) whose output is still the one the ledger "
                                    "records (its size and SHA-256). "
                                    "Exit 0 all ok, 1 some failed, 2 bad usage.")
    e.add_argument("src", metavar="SRC", help="folder, glob (quote it) or manifest file")
    e.add_argument("-o", "--output", required=True, type=nonblank_path("-o", "folder"), metavar="OUT_DIR",
                   help="output folder (created)")
    e.add_argument("--watermark", metavar="IMG", help="watermark image for every asset")
    keys = e.add_mutually_exclusive_group()
    keys.add_argument("--key", type=nonblank_path("--key", "key file"), metavar="KEY", help="one collection key for every asset (loaded, or created)")
    keys.add_argument("--keys-dir", type=nonblank_path("--keys-dir", "directory"), metavar="DIR", help="write each asset's key under DIR "
                      "(default: OUT.pmw.key.json beside each output); a folder, not an input or an output")
    e.add_argument("--timeout", type=_positive(float, "--timeout"), metavar="S",
                   help="seconds per asset before its encoder is killed (default 600)")
    e.add_argument("--force", action="store_true", help="redo assets the ledger records as done")
    add_stream_options(e)
    owner = e.add_mutually_exclusive_group()
    owner.add_argument("--owner-id", type=owner_id_arg, metavar="HEX",
                       help="the 64-bit owner ID of every asset's owner layer (as 'pmw encode --owner-id'; alone, "
                            "without --watermark, the only mark); with --key: the ID of a new collection key, or "
                            "the one an existing key must name")
    owner.add_argument("--no-owner", action="store_true",
                       help="with --watermark: write the exact layer only, no owner layer")
    _cluster_options(e)
    e.set_defaults(run=run_encode)
    v = cmds.add_parser("verify", help="verify every .pmw under OUT_DIR",
                        description="Verify every .pmw under OUT_DIR with one collection key (--key), the keys "
                                    "under --keys-dir, or the key beside each file. Symlinked folders are not "
                                    "entered; a file or key whose real path leaves OUT_DIR (or --keys-dir) is not "
                                    "read and counts as an error; a file that ends before its declared length is 'truncated', not "
                                    "authentic. Exit 0 when every file is authentic (a file carrying the owner layer alone: present).")
    v.add_argument("out_dir", type=nonblank_path("OUT_DIR", "folder"), metavar="OUT_DIR")
    keys = v.add_mutually_exclusive_group()
    keys.add_argument("--key", type=nonblank_path("--key", "key file"), metavar="KEY", help="the collection key")
    keys.add_argument("--keys-dir", type=nonblank_path("--keys-dir", "directory"), metavar="DIR", help="the folder of per-asset keys")
    v.add_argument("--watermark", metavar="IMG", help="expected watermark image (default: the one in each key)")
    _cluster_options(v)
    v.set_defaults(run=run_verify)


def _library():
    try:
        import distributed  # noqa: F401  (the engine; the batch modules import it when a run starts)
    except ImportError:
        raise UsageError(INSTALL_HINT) from None
    from pmwm_codec import batch

    _quiet_client_logs()
    return batch


def _quiet_client_logs() -> None:
    """Keep what the Dask client tells its log off the command's standard error, which holds one line at most: a
    result lost with its worker before the run had it is computed again ("Couldn't gather 1 keys, rescheduling",
    a warning) and the run waits for it again (:meth:`pmwm_codec.batch.run._Submitted.run`), which leaves asyncio
    a gather's task whose exception nobody reads ("Task exception was never retrieved", printed as the process
    ends).  The run says what it has to say in its rows, its summary and its one-line errors."""
    import logging

    logging.getLogger("distributed.client").setLevel(logging.ERROR)
    logging.getLogger("asyncio").setLevel(logging.CRITICAL)


def _no_worker_timeout(args, batch) -> float:
    return args.no_worker_timeout or batch.NO_WORKER_TIMEOUT


def _bar(args) -> Progress:
    progress = Progress(not (args.json or args.quiet))

    def show(c):
        failed = c.get("failed", 0) + c.get("timeout", 0)
        rate = "" if c.get("rate") is None else f" {c['rate']:.1f}/s"
        progress(f"{c['done']}/{c['total']} f{failed} r{c.get('running', 0)}{rate}", c["done"] / max(1, c["total"]))
    show.bar = progress
    return show


def run_encode(args) -> int:
    batch = _library()
    options = stream_options(args, defaults=False)  # the ledger's settings: only what differs from the defaults
    if args.owner_id is not None:
        options["owner_id"] = args.owner_id
    if args.no_owner:
        if args.watermark is None and args.key is None:
            raise UsageError("--no-owner needs --watermark (or a collection --key): without a mark there is no owner layer")
        options["owner_id"] = False
    show = _bar(args)
    try:
        summary = batch.encode_batch(args.src, args.output, watermark=args.watermark, key=args.key,
                                     keys_dir=args.keys_dir, workers=args.workers, scheduler=args.scheduler,
                                     timeout=args.timeout or batch.DEFAULT_TIMEOUT, force=args.force, progress=show,
                                     options=options, no_worker_timeout=_no_worker_timeout(args, batch))
    finally:
        show.bar.done()
    if args.json:
        print_json(summary)
    elif not args.quiet:
        print(f"{summary['assets']} assets: {summary['ok']} ok, {summary['skipped']} skipped, "
              f"{summary['failed']} failed, {summary['timeout']} timed out in {summary['seconds']:.1f} s; "
              f"ledger {summary['ledger']}")
        for row in summary["failures"]:
            print(f"  {row['status']}: {_failure_line(row, args.src)}")
    return EXIT_OK if not summary["failures"] else EXIT_NOT_AUTHENTIC


def _failure_line(row: dict, src) -> str:
    """A failed row's error led by its input's path (relative to the ``src`` folder, or to the
    current directory for a glob or a manifest), not by its base name alone: two ``bad.obj`` in two
    folders stay apart."""
    path = row.get("input") or ""
    base = os.path.abspath(src) if os.path.isdir(src) else os.getcwd()
    shown = os.path.relpath(path, base) if path and os.path.isabs(path) else path
    error = str(row.get("error") or row["status"])
    for lead in (path, os.path.basename(path)):
        if lead and error.startswith(lead + ": "):
            error = error[len(lead) + 2:]
            break
    return f"{shown}: {error}" if shown else error


def run_verify(args) -> int:
    batch = _library()
    show = _bar(args)
    try:
        outcome = batch.verify_batch(args.out_dir, key=args.key, keys_dir=args.keys_dir, watermark=args.watermark,
                                     workers=args.workers, scheduler=args.scheduler, progress=show,
                                     no_worker_timeout=_no_worker_timeout(args, batch))
    finally:
        show.bar.done()
    if args.json:
        print_json(outcome)
    elif not args.quiet:
        for r in outcome["results"]:
            if r["verdict"] not in ("authentic", "present"):
                error = r["error"] or ""
                if error.startswith(r["file"] + ": "):  # the path once, not twice
                    error = error[len(r["file"]) + 2:]
                print(f"  {r['verdict']}: {r['file']}" + (f" ({error})" if error else ""))
        print(f"{outcome['authentic']} of {outcome['files']} files authentic" if not outcome["present"] else
              f"{outcome['authentic'] + outcome['present']} of {outcome['files']} files verified ("
              f"{outcome['present']} of the owner layer alone: present)")
    return EXIT_OK if outcome["authentic"] + outcome["present"] == outcome["files"] else EXIT_NOT_AUTHENTIC
