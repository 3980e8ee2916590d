"""A machine's first runs: compile the numba kernels a ``pmw`` command needs later in a second process.

On a cold numba cache (a machine's first runs, or after an upgrade) ``pmw encode`` spends about half a
minute compiling kernels, one after the other, on one core: first the simplifier's, then the payload
coder's (:mod:`~pmwm_codec.format.records_v2`, the largest of them ``_batch_kernel``), while the
machine's other cores idle.  When such a one-shot command first compiles
(:func:`~pmwm_codec.progressive.topology.on_first_compile`), the command line starts one *helper*
process (:func:`arm`, :func:`start`) that compiles the kernels the command reaches *later*, which
numba writes to its disk cache; the command then loads them from there instead of compiling them.

What the helper does (:func:`child`):

1. It encodes (and decodes) a small mesh of its own with the payload kernels run as plain Python
   (numba not loaded: they are their own twins, the same results), noting the arguments of each
   kernel's first call, and of the calls those kernels make to the helpers they call directly, in
   the order of the calls (:class:`_Capture`).  The command calls them in that order too.
2. It loads numba and compiles each kernel for those arguments' types, from the last call to the
   first: the command's order reversed, so that the two processes work from opposite ends (for an
   encode: the command compiles the simplifier's kernels, then reaches the payload coder's, which
   the helper compiled first; for a decode, whose first kernels are the payload coder's, the
   helper takes the last helpers of ``_batch_kernel`` while the command compiles its first).
3. It exits.

The two processes tell each other what they compile, on the pipes between them: the helper skips a
kernel the command has started to compile, and the command, about to look a kernel up in the cache
while the helper compiles it, waits for the helper to save it rather than compile it a second time
(:meth:`Helper.wait_for`).

What it never does: change a result.  It writes nothing but numba's cache entries, and a cache entry
is the compiled form of a kernel, the same code whichever process compiled it (numba keys an entry by
the argument types, the target machine and a hash of the kernel's bytecode; an entry for types the
command never asks for is never used).  It prints nothing (its output goes to ``/dev/null``, its
messages to the command go on a pipe of their own).  It never outlives the command: it reads a pipe
from the command, which the system closes when the command exits however it exits (``kill -9``
included), and it ends at that end of file (:func:`_watch_parent`).

Where it runs: only for the one-shot commands that will run the payload coder or its decoder, run as a
process of their own (:func:`pmwm_codec.cli.ahead_plan`; not ``pmwm_codec.encode`` in a user's process,
not ``pmw batch`` / ``serve``), only when a kernel is compiled (numba in use, the cache cold: never on the
small-mesh path, which does not load numba), on a machine with two CPUs or more for this process, and not
with ``PMW_COMPILE_AHEAD=0``.
"""

from __future__ import annotations

import contextlib
import os
import sys
import threading

#: ``PMW_COMPILE_AHEAD=0`` (or ``off``, ``no``, ``false``) in the environment: never start the helper.
ENV = "PMW_COMPILE_AHEAD"
#: The steps of :func:`small_job` a helper can note the kernels of: ``"encode"`` (the payload coder's, version 2,
#: in encode mode) and ``"decode"`` (the decoder's); a command's *plan* is those it will run (see
#: :func:`pmwm_codec.cli.ahead_plan`).
STEPS = ("encode", "decode")
#: Modules whose kernels the helper runs as plain Python: theirs are their own twins (the same results,
#: slowly), where the simplifier's and the watermark's twins are numpy code that calls no kernel.
CAPTURED = frozenset({"pmwm_codec.format.records_v2", "pmwm_codec.format.rangecoder"})

_helper = None  # the Helper of this process, once started


def cpus() -> int:
    """CPUs this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def wanted() -> bool:
    """Whether a helper may start here: numba in use, two CPUs or more, file locks (POSIX), not turned off."""
    from .progressive import topology

    if os.environ.get(ENV, "").strip().lower() in ("0", "off", "no", "false"):
        return False
    try:
        import fcntl  # noqa: F401 - the cache lock (:func:`_locked`)
    except ImportError:
        return False
    return topology.USE_NUMBA and cpus() >= 2


def arm(plan) -> None:
    """In the process of a one-shot ``pmw`` command that will run the steps ``plan`` (of :data:`STEPS`): start
    the helper (:func:`start`) when a kernel first compiles, if there is a plan and a helper is :func:`wanted`."""
    if not plan or not wanted():
        return
    from .progressive.topology import on_first_compile

    on_first_compile(lambda: start(plan))


def start(plan) -> Helper | None:
    """Start this process's helper for ``plan`` (steps of :data:`STEPS`), once; None when it cannot start
    (it is only an optimisation: the command compiles what it needs itself)."""
    global _helper
    if _helper is None:
        try:
            if _batch_kernel_cached():
                return None
            _helper = Helper(plan)
        except Exception:  # noqa: BLE001 - called from numba's compile event: a failure here must not fail the compile
            return None
    return _helper


def _batch_kernel_cached() -> bool:
    """Whether numba's cache holds the payload coder's batch kernel (:func:`~pmwm_codec.format.records_v2._batch_kernel`
    and the helpers it calls: ~14 s of the ~16 s a helper would compile).  Without it a helper is worth its start
    (~1.5 s of CPU); with it the rest is small (``pmw verify`` after a first encode compiles the decoder's
    ``dec_uint`` and the owner layer's readers: 1-2 s)."""
    from .format import records_v2
    from .progressive.topology import compiled

    try:
        return bool(compiled(records_v2._batch_kernel)._cache._cache_file._load_index())  # numba's own index reader
    except Exception:  # noqa: BLE001 - numba's internals moved: start the helper, as on a cold cache
        return False


def kernel_name(fn) -> str:
    """``module.qualname`` of a kernel (or its dispatcher): the name the two processes use for it."""
    fn = getattr(fn, "py_func", fn)
    return f"{fn.__module__}.{fn.__qualname__}"


#: ``python -c`` program of the helper: imports this package from where the command imported it (not from
#: the working directory, which ``-c`` puts first on the path), then runs :func:`child`.
_BOOT = "import sys; sys.path[0] = sys.argv[1]; from pmwm_codec.compile_ahead import child; child(sys.argv[2:])"


class Helper:
    """The command's side of a running helper: its process, the kernels it is compiling (its ``+name`` and
    ``-name`` lines), and the command's own compiles told to it (:meth:`tell`)."""

    def __init__(self, plan):
        import subprocess

        import pmwm_codec

        root = os.path.dirname(os.path.dirname(os.path.abspath(pmwm_codec.__file__)))
        env = dict(os.environ)
        if env.get("NUMBA_CACHE_DIR"):  # the directory numba read at its import, were the command to change its own
            env["NUMBA_CACHE_DIR"] = os.path.abspath(env["NUMBA_CACHE_DIR"])
        self.busy: dict = {}  # kernel name -> compiles the helper has started and not saved
        self.alive = False
        self.cond = threading.Condition()
        _install_cache_hooks(before_load=self.wait_for)
        _listen(self.tell)
        self.proc = subprocess.Popen([sys.executable, "-c", _BOOT, root, *plan], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env)
        self.alive = True
        threading.Thread(target=self._read, name="pmw-compile-ahead", daemon=True).start()

    def _read(self) -> None:
        """Follow the helper's lines until it exits; then reap it and wake every waiter."""
        try:
            for line in self.proc.stdout:
                name = line[1:].decode(errors="replace").strip()
                with self.cond:
                    if line[:1] == b"+":
                        self.busy[name] = self.busy.get(name, 0) + 1
                    elif line[:1] == b"-" and self.busy.get(name, 0) > 0:
                        self.busy[name] -= 1
                    self.cond.notify_all()
        except (OSError, ValueError):
            pass
        with self.cond:
            self.alive = False
            self.busy.clear()
            self.cond.notify_all()
        with contextlib.suppress(Exception):
            self.proc.wait()

    def wait_for(self, name: str) -> None:
        """Return once the helper is not compiling ``name`` (it saved it, or it ended)."""
        with self.cond:
            while self.alive and self.busy.get(name, 0) > 0:
                self.cond.wait(0.5)

    def tell(self, name: str) -> None:
        """Tell the helper that the command compiles ``name`` (the helper skips it)."""
        if not self.alive:
            return
        try:
            self.proc.stdin.write(b"+" + name.encode() + b"\n")
            self.proc.stdin.flush()
        except (OSError, ValueError):  # the helper has ended
            pass


def _listen(started) -> None:
    """Call ``started(name)`` at the start of every numba compile in this process (numba's event API)."""
    from numba.core import event

    class Started(event.Listener):
        def on_start(self, ev):
            started(kernel_name(ev.data["dispatcher"]))

        def on_end(self, ev):
            pass

    event.register("numba:compile", Started())


# ---------------------------------------------------------------------------------------- the cache


_saving = threading.Lock()  # held while this process writes a cache entry (the helper ends between two)
_ending = False  # the helper was told to end while it wrote one (:func:`_end_soon`)


@contextlib.contextmanager
def _locked(path: str, how: int):
    """``flock`` the cache directory ``path`` (``how``: shared or exclusive); no lock where it is missing."""
    import fcntl

    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        yield
        return
    try:
        fcntl.flock(fd, how)
        yield
    finally:
        os.close(fd)  # releases the lock


def _install_cache_hooks(before_load=None, saved=None) -> None:
    """Wrap numba's cache lookups and saves (:class:`numba.core.caching.Cache`) in this process:
    ``before_load(name)`` before a lookup (the command waits there for the helper), ``saved(name)`` after
    a save, and both under a lock on the cache directory.

    Why the lock: numba writes each file of an entry (the function's index, mapping argument types to data
    file names, and the data file) to a temporary name and renames it, so a reader never sees half a file,
    and two processes saving the *same* entry write the same index and equivalent data, whichever lands
    last.  But a save reads the index, adds its key with the first free data file number and writes both:
    two processes saving *different* entries of one function at once could each take number 1, leaving an
    index whose entry names the other's data; and a reader between the index and the data file could load
    an older data file of that number (a stale cache).  Under the lock (exclusive to save, shared to load)
    the command and its helper never interleave so.
    """
    import fcntl

    from numba.core.caching import Cache

    _check_numba_cache()
    load, save = Cache.load_overload, Cache.save_overload

    def load_overload(self, sig, target_context):
        if before_load is not None:
            before_load(kernel_name(self._py_func))
        with _locked(self._cache_path, fcntl.LOCK_SH):
            return load(self, sig, target_context)

    def save_overload(self, sig, data):
        try:
            with _saving:
                with contextlib.suppress(OSError):
                    self._impl.locator.ensure_cache_path()  # numba makes it in the save; the lock needs it first
                with _locked(self._cache_path, fcntl.LOCK_EX):
                    save(self, sig, data)
            if _ending:  # a SIGTERM came during the save (:func:`_end_soon`)
                os._exit(0)
        finally:
            if saved is not None:
                saved(kernel_name(self._py_func))

    Cache.load_overload, Cache.save_overload = load_overload, save_overload


def _check_numba_cache() -> None:
    """RuntimeError unless numba's cache objects have what the hooks of :func:`_install_cache_hooks` read (numba's
    internals, as of 0.59-0.68: a cache's ``_py_func``, ``_cache_path`` and ``_impl.locator``), checked on the batch
    kernel's; a numba whose internals moved gets no hooks, hence no helper (the command compiles alone, as before),
    rather than hooks that fail inside every compile."""
    from .format import records_v2
    from .progressive.topology import compiled

    cache = compiled(records_v2._batch_kernel)._cache
    if not all(hasattr(x, a) for x, a in ((cache, "_py_func"), (cache, "_cache_path"), (cache, "_impl"))) \
            or not hasattr(cache._impl, "locator") or not callable(getattr(cache, "load_overload", None)) \
            or not callable(getattr(cache, "save_overload", None)):
        raise RuntimeError("numba's cache internals are not those compile_ahead knows")


# ---------------------------------------------------------------------------------------- the helper


def child(plan) -> None:
    """The helper process (started by :class:`Helper`): notes the kernels' arguments for ``plan``,
    compiles them in the reverse order, exits; ends at once when the command does."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # a Ctrl-C is the command's: the helper ends with it
    signal.signal(signal.SIGTERM, _end_soon)
    signal.signal(signal.SIGHUP, _end_soon)
    # Not niced: on a machine whose CPUs are all busy the command may wait for a kernel the helper is compiling,
    # which a niced helper shares with the busy processes at a lower weight (nice 10: about a tenth of theirs).
    # A first decode, two busy processes beside it: 31 and 50 s niced, 40 and 40 s not, 47 and 48 s without one.
    messages = os.fdopen(os.dup(1), "wb", buffering=0)
    quiet = os.open(os.devnull, os.O_RDWR)
    os.dup2(quiet, 1)  # nothing the helper may print reaches the command's terminal or its messages
    os.dup2(quiet, 2)
    started: set = set()  # kernels the command compiles
    threading.Thread(target=_watch_parent, args=(started,), name="pmw-parent", daemon=True).start()
    with contextlib.suppress(BaseException):
        _compile_ahead(plan, started, messages)
    _end()


def _watch_parent(started: set) -> None:
    """Note the kernels the command says it compiles; end the process when the command's pipe closes (the
    command exited, whichever way)."""
    with contextlib.suppress(Exception):
        for line in os.fdopen(0, "rb"):
            if line[:1] == b"+":
                started.add(line[1:].decode(errors="replace").strip())
    _end()


def _end() -> None:
    """Exit now (no interpreter shutdown, no output), not in the middle of writing a cache entry."""
    with _saving:
        os._exit(0)


def _end_soon(signum, frame) -> None:
    """SIGTERM, SIGHUP: exit now, or right after the cache entry being written (never leaving a part of it)."""
    global _ending
    if _saving.acquire(blocking=False):
        os._exit(0)
    _ending = True


def _compile_ahead(plan, started: set, messages) -> None:
    import numba

    from .progressive import topology

    calls = capture(plan)

    def say(sign: bytes, name: str) -> None:
        with contextlib.suppress(OSError):
            messages.write(sign + name.encode() + b"\n")

    topology._load_numba()
    inflight: list = []  # kernels this process compiles and has not saved

    def saved(name: str) -> None:
        with contextlib.suppress(ValueError):
            inflight.remove(name)
        say(b"-", name)

    _install_cache_hooks(saved=saved)
    from numba.core import event

    class Compiling(event.Listener):
        def on_start(self, ev):
            name = kernel_name(ev.data["dispatcher"])
            inflight.append(name)
            say(b"+", name)

        def on_end(self, ev):
            pass

    event.register("numba:compile", Compiling())
    for fn, args in reversed(calls):
        if kernel_name(fn) in started:
            continue
        with contextlib.suppress(Exception):
            topology.compiled(fn).compile(tuple(numba.typeof(a) for a in args))
        for name in inflight:  # a compile that failed saves nothing: the command need not wait for it
            say(b"-", name)
        inflight.clear()


class _Capture:
    """The arguments of each kernel's first call (of the :data:`CAPTURED` modules), and of the first call of
    each helper a kernel calls directly (``@kernel_helper`` not inlined), in the order of those calls;
    installed as :data:`pmwm_codec.progressive.topology._capture` while the helper runs them as plain Python."""

    def __init__(self):
        self.first: dict = {}  # plain function -> args of its first call (dicts keep the order)
        self.on = False  # note calls (only in the plan's steps)
        self.depth = 0  # kernels and helpers running

    def recorder(self, fn):
        """:func:`~pmwm_codec.progressive.topology.compiled` while capturing: ``fn`` plain, noting its calls;
        None (the numpy twin) outside :data:`CAPTURED`."""
        fn = getattr(fn, "py_func", fn)
        if fn.__module__ not in CAPTURED:
            return None
        return self._noting(fn, 0)

    def _noting(self, fn, depth: int):
        def call(*args):
            if self.on and self.depth == depth and fn not in self.first:
                self.first[fn] = args
            self.depth += 1
            try:
                return fn(*args)
            finally:
                self.depth -= 1

        call.py_func = fn  # as a dispatcher has it: compiled(), _kernel() unwrap a helper called as a kernel
        return call

    @contextlib.contextmanager
    def helpers(self):
        """For the block, every helper kernels call (module globals) plain, where numba has made them
        dispatchers (:func:`~pmwm_codec.progressive.topology._load_numba`), those not inlined noting their
        calls at depth 1; the globals as they were afterwards."""
        from .progressive import topology

        swapped = [(g, name, fn, g[name]) for g, name, fn, flags in topology._HELPERS
                   if fn.__module__ in CAPTURED and g.get(name) in (fn, topology._COMPILED.get(fn))]
        for g, name, fn, _ in swapped:
            inline = "inline" in next(f for h, n, p, f in topology._HELPERS if p is fn)
            g[name] = fn if inline else self._noting(fn, 1)
        try:
            yield
        finally:
            for g, name, _, was in swapped:
                g[name] = was


def capture(plan) -> list:
    """``[(kernel, args), ...]``: the kernels a command running the steps ``plan`` compiles, with the
    arguments of their first calls, in call order, from :func:`small_job` run with the kernels as plain Python
    (numba not loaded)."""
    from . import stream  # noqa: F401 - the kernels' modules, loaded before their helpers are swapped
    from .progressive import topology

    notes = _Capture()
    topology._capture = notes
    try:
        with notes.helpers():
            small_job(lambda step: setattr(notes, "on", step in plan))
    finally:
        topology._capture = None
    return list(notes.first.items())


def small_job(step=lambda name: None) -> None:
    """The helper's job: a small watermarked mesh encoded, then decoded, in memory; ``step("encode")`` and
    ``step("decode")`` are called before each."""
    import io

    import numpy as np

    from . import shapes
    from .stream import decode_stream, encode_mesh
    from .watermark.key import WatermarkKey

    image = (np.indices((8, 8)).sum(0) % 2 * 255).astype(np.uint8)
    key = WatermarkKey.generate(rng=np.random.default_rng(0))
    data = io.BytesIO()
    step("encode")
    encode_mesh(shapes.icosphere(3, noise=0.01, seed=1), data, watermark=image, key=key, measure="none")
    step("decode")
    decode_stream(io.BytesIO(data.getvalue()), key=key)
