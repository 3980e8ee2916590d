"""The ``pmw`` command: ``encode``, ``decode``, ``verify``, ``info``, ``demo``, ``batch`` (DESIGN.md §5).

Thin over the library: each subcommand lives in ``pmwm_codec/cli/<name>.py`` as
``add_parser(subparsers)`` + ``run(args) -> int``; ``python -m pmwm_codec`` runs it too.  :func:`main` is the console
script and the function tests call: ``main(["verify", "x.pmw", "--key", "k"])``.

Exit status: 0 success (verify: authentic); 1 verify ran and the mark is absent,
wrong or inconclusive; 2 bad input or usage, with one line on stderr.
"""

from __future__ import annotations

import contextlib
import os
import sys

from pmwm_codec import __version__
from pmwm_codec.errors import PmwError

from . import batch, decode, demo, encode, info, verify
from .common import EXIT_BAD_INPUT, PROG, ArgumentParser, UsageError, error_line, os_error_message

COMMANDS = (encode, decode, verify, info, demo, batch)


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
    try:
        return int(args.run(args))
    except BrokenPipeError:  # `pmw info x.pmw | head`: the reader left; not an error of ours
        with contextlib.suppress(OSError):
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except (PmwError, UsageError) as exc:
        sys.stderr.write(error_line(exc) + "\n")
    except OSError as exc:
        sys.stderr.write(error_line(os_error_message(exc)) + "\n")
    except KeyboardInterrupt:
        sys.stderr.write(error_line("interrupted") + "\n")
        return 130
    return EXIT_BAD_INPUT
