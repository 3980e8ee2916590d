"""The ``pmw`` command: ``encode``, ``decode``, ``cut``, ``verify``, ``info``, ``demo``, ``batch``, ``serve`` (DESIGN.md §5).

Thin over the library: each subcommand lives in ``pmwm_codec/cli/<name>.py`` as
``add_parser(subparsers)`` + ``run(args) -> int``; ``python -m pmwm_codec`` runs it too.  :func:`main` is the console
script and the function tests call: ``main(["verify", "x.pmw", "--key", "k"])``.

Exit status: 0 success (verify: authentic); 1 verify ran and the mark is absent,
wrong or inconclusive; 2 bad input or usage, with one line on stderr.
"""

from __future__ import annotations

from pmwm_codec import __version__

from . import batch, cut, decode, demo, encode, info, serve, verify
from .common import PROG, ArgumentParser, run_command

COMMANDS = (encode, decode, cut, verify, info, demo, batch, serve)
#: Commands that do one job and exit: run as a process of their own (``argv`` None), a small mesh skips
#: numba's start-up (:func:`pmwm_codec.progressive.topology.job_vertices`).  ``batch`` and ``serve``
#: live on, and the tests' in-process calls keep numba.
ONE_SHOT = {"encode", "decode", "cut", "verify", "demo"}


def build_parser() -> ArgumentParser:
    parser = ArgumentParser(prog=PROG, description="Progressive, watermarked 3D meshes in glTF (.pmw).")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)
    sub.required = True
    for command in COMMANDS:
        command.add_parser(sub)
    return parser


def main(argv=None) -> int:
    """Run ``pmw`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # usage errors (2), --help / --version (0)
        return int(exc.code or 0)
    if argv is None and args.command in ONE_SHOT:
        from pmwm_codec.progressive.topology import one_shot_process

        one_shot_process()
    return run_command(args)
