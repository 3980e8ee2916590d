"""The ``pmw`` command: ``encode``, ``decode``, ``cut``, ``verify``, ``info``, ``demo``, ``batch``, ``serve`` (DESIGN.md §5).

Thin over the library: each subcommand lives in ``pmwm_codec/cli/<name>.py`` as
``add_parser(subparsers)`` + ``run(args) -> int``; ``python -m pmwm_codec`` runs it too.  :func:`main` is the console
script and the function tests call: ``main(["verify", "x.pmw", "--key", "k"])``.

Exit status: 0 success (verify: authentic); 1 verify ran and the mark is absent,
wrong or inconclusive; 2 bad input or usage, with one line on stderr; 130 interrupted
(Ctrl-C), with one line on stderr.

Nothing is imported here at module level: :func:`main` loads the subcommands (numpy, Pillow ...)
inside its guard, so a Ctrl-C while they load is the one ``interrupted`` line too, not a traceback.
"""

from __future__ import annotations

#: The subcommand modules, in the order ``pmw --help`` lists them.
COMMANDS = ("encode", "decode", "cut", "verify", "info", "demo", "batch", "serve")
#: Commands that do one job and exit: run as a process of their own (``argv`` None), a small mesh skips
#: numba's start-up (:func:`pmwm_codec.progressive.topology.job_vertices`).  ``batch`` and ``serve``
#: live on, and the tests' in-process calls keep numba.
ONE_SHOT = {"encode", "decode", "cut", "verify", "demo"}


def build_parser():
    """The ``pmw`` argument parser, every subcommand added (imports them)."""
    from importlib import import_module

    from pmwm_codec import __version__

    from .common import PROG, ArgumentParser

    parser = ArgumentParser(prog=PROG, description="Progressive, watermarked 3D meshes in glTF (.pmw).")
    parser.add_argument("--version", action="version", version=f"{PROG} {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=ArgumentParser)
    sub.required = True
    for name in COMMANDS:
        import_module(f"{__name__}.{name}").add_parser(sub)
    return parser


def _explain_first_compile() -> None:
    """At a terminal, say why a machine's first runs are slow, once, when a kernel first compiles (numba's
    disk cache has none yet: about a minute for the first encode, not again)."""
    import sys

    from .common import _isatty, notice

    if not _isatty(sys.stderr):
        return
    from pmwm_codec.progressive.topology import on_first_compile

    def say():
        sys.stderr.write("\r")  # over a progress bar's line, if one is drawn (the note is longer)
        notice(FIRST_COMPILE)
        sys.stderr.flush()

    on_first_compile(say)


def ahead_plan(args) -> tuple:
    """The steps of :data:`pmwm_codec.compile_ahead.STEPS` the command ``args`` will run, whose kernels a helper
    process may compile while the command compiles its first ones: ``"encode"``, the payload coder of version 2
    (not ``--payload-version 1``, zstd columns); ``"decode"``, its decoder (a ``.pmw`` decoded, cut, verified,
    or a ``--reference``'s; not ``verify MESH --key``, the owner layer alone).  () for none."""
    command = args.command
    if command == "encode":
        return ("encode",) if args.payload_version != 1 else ()
    if command == "demo":
        return ("encode", "decode")
    if command in ("decode", "cut"):
        return ("decode",)
    if command == "verify":
        from .verify import _is_mesh_file

        return ("decode",) if args.reference is not None or not _is_mesh_file(args.input) else ()
    return ()


#: The note :func:`_explain_first_compile` writes.
FIRST_COMPILE = ("compiling the numba kernels for this machine (once: up to a minute or two; later runs load them "
                 "from numba's cache)")


def main(argv=None) -> int:
    """Run ``pmw`` with ``argv`` (default ``sys.argv[1:]``); returns the exit status."""
    noted: list = []
    try:
        previous = _note_interrupts(noted)
        try:
            from .common import run_command

            parser = build_parser()
            try:
                args = parser.parse_args(argv)
            except SystemExit as exc:  # usage errors (2), --help / --version (0)
                return int(exc.code or 0)
        finally:
            _restore_sigint(previous)
        if noted:  # a Ctrl-C that a module's loading swallowed
            raise KeyboardInterrupt
        if argv is None and args.command in ONE_SHOT:
            from pmwm_codec.progressive.topology import one_shot_process

            one_shot_process()
            _explain_first_compile()
            from pmwm_codec.compile_ahead import arm

            arm(ahead_plan(args))  # on a cold cache a second process compiles the kernels needed later
        return run_command(args)
    except Exception as exc:  # noqa: BLE001 - only when a Ctrl-C came while the modules loaded; else raised again
        if not noted:
            raise
        from .common import interrupted

        return interrupted()
    except KeyboardInterrupt:  # while the modules load or the arguments are read (run_command answers later ones)
        from .common import interrupted

        return interrupted()


def _note_interrupts(noted: list):
    """While the modules load: a SIGINT raises KeyboardInterrupt as Python's own handler does, and is noted in
    ``noted``, because a compiled module's loading may turn it into another error (numpy's C extension, its
    import of ``datetime`` interrupted, raises an ImportError that has lost the KeyboardInterrupt).  Only where
    Python's own handler is in place, in the main thread (an ignored SIGINT stays ignored).  Where Python
    cannot raise it (a weakref callback, as importlib's module locks run) it prints no "Exception ignored"
    traceback: noted, ``main`` says it once.  Returns what :func:`_restore_sigint` puts back (the handler and
    ``sys.unraisablehook``; None: nothing changed)."""
    import signal
    import sys
    import threading

    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        return None

    def note(signum, frame):
        noted.append(signum)
        raise KeyboardInterrupt

    hook = sys.unraisablehook

    def unraisable(info):  # a KeyboardInterrupt raised in a weakref callback (importlib's module locks) is
        if not (noted and isinstance(info.exc_value, KeyboardInterrupt)):  # ignored by Python, which printed a
            hook(info)  # traceback ("Exception ignored in ..."): noted, it is said once, as "interrupted"

    sys.unraisablehook = unraisable
    return signal.signal(signal.SIGINT, note), hook


def _restore_sigint(previous) -> None:
    if previous is not None:
        import signal
        import sys

        handler, sys.unraisablehook = previous
        signal.signal(signal.SIGINT, handler)
