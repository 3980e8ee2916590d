"""Vectorised connectivity queries shared by the simplifier and the tests.

All functions take ``faces`` (m, 3) int64 with vertex ids in ``[0, n)`` and
return flat numpy arrays; nothing here loops over vertices or faces in Python.
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass

import numpy as np

#: Use the numba kernels when numba is installed (tests flip this to check the numpy twins).
#: numba itself is imported on the first kernel call, not here: commands that run no kernel
#: (``pmw info``, ...) do not pay its import time.
USE_NUMBA = importlib.util.find_spec("numba") is not None
_numba = None  # the numba module, once loaded
#: A one-shot process (:func:`one_shot_process`: the ``pmw`` command line) runs a job of fewer
#: vertices than this on the numpy / Python twins of the kernels when numba is not loaded yet:
#: numba's start-up in a fresh process (its import, its target context, the cached kernels) costs
#: more than its kernels save on a small mesh (BENCHMARKS.md, "Small meshes on the command line").
#: The twins give the same bytes.  A long-running process (the library, ``pmw batch``'s workers,
#: ``pmw serve``) pays the start-up once and always uses numba.
SMALL_JOB_VERTICES = 2000
_one_shot = False
_plain_job = False
#: Set by :mod:`pmwm_codec.compile_ahead`'s helper process while it runs the kernels as plain Python to note
#: their argument types: :func:`compiled` then gives ``_capture.recorder(fn)`` (the plain function, noting the
#: arguments of its first call) instead of None or the dispatcher.
_capture = None


@dataclass
class EdgeTable:
    """Undirected edges of a triangle mesh and the half-edges on them.

    Attributes
    ----------
    keys : (e,) int64, sorted
        ``lo * n + hi`` for every undirected edge, ascending (for searchsorted).
    lo, hi : (e,) int64
        Edge end points, ``lo < hi``.
    count : (e,) int64
        Number of faces on the edge (1 boundary, 2 interior, >2 non-manifold).
    he0, he1 : (e,) int64
        First and second half-edge on the edge (``he1 == -1`` when count == 1).
        Half-edge ``h`` is corner ``h % 3`` of face ``h // 3`` and runs from
        that corner to the next one.
    """

    n: int
    keys: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    count: np.ndarray
    he0: np.ndarray
    he1: np.ndarray

    def find(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Edge ids of the pairs ``(a, b)`` (any order); -1 where no such edge."""
        a = np.asarray(a, np.int64)
        b = np.asarray(b, np.int64)
        q = np.minimum(a, b) * self.n + np.maximum(a, b)
        pos = np.searchsorted(self.keys, q)
        pos_c = np.minimum(pos, len(self.keys) - 1)
        hit = self.keys[pos_c] == q
        return np.where(hit, pos_c, -1)


def _counting_order_py(keys, n):
    """Kernel of :func:`group_order`: keys (c,) int64 in [0, n) -> (c,) int64 stable order."""
    count = np.zeros(n + 1, dtype=np.int64)
    for k in keys:
        count[k + 1] += 1
    for i in range(n):
        count[i + 1] += count[i]
    out = np.empty(len(keys), dtype=np.int64)
    for j in range(len(keys)):
        k = keys[j]
        out[count[k]] = j
        count[k] += 1
    return out


_COMPILED: dict = {}  # plain function -> its dispatcher
_HELPERS: list = []  # (module globals, name, plain function, flags) of every kernel_helper


def compiled(fn):
    """The numba-compiled twin of the plain-Python kernel ``fn`` (disk-cached), or None.

    None when numba is absent or :data:`USE_NUMBA` is off; callers then run their numpy
    version, which computes the same result.
    """
    if _capture is not None:
        return _capture.recorder(fn)
    if not USE_NUMBA or _plain_job:
        return None
    jit = _COMPILED.get(fn) if _numba is not None else None  # the common case: a kernel already called
    if jit is None:
        _load_numba()
        fn = getattr(fn, "py_func", fn)  # a kernel_helper that is also called as a kernel
        jit = _COMPILED.get(fn)
        if jit is None:
            jit = _COMPILED[fn] = _jit(fn)
    return jit


def one_shot_process() -> None:
    """Declare this process one job long (the command line): :func:`job_vertices` may then keep
    a small job off numba."""
    global _one_shot
    _one_shot = True


def job_vertices(count: int) -> None:
    """The size of the job at hand, in vertices (an encode's input, a decode's declared counts).
    In a one-shot process that has not loaded numba, a job below :data:`SMALL_JOB_VERTICES` runs
    the kernels' numpy / Python twins (:func:`compiled` gives None); elsewhere nothing changes."""
    global _plain_job
    if _one_shot and _numba is None:
        _plain_job = count < SMALL_JOB_VERTICES


def _load_numba():
    """Import numba once; swap every :func:`kernel_helper` for its dispatcher in its module and
    :func:`prefetch` for its compiled form."""
    global _numba, prefetch
    if _numba is None:
        import numba

        _numba = numba
        for g, name, fn, flags in _HELPERS:
            here = g.get(name)
            if here is not fn and here is not _COMPILED.get(fn):  # another definition took the helper's name in
                # its module (numba loaded again finds the helper's own dispatcher there): swapping
                # the global would put the helper where the other is called (a bug, named here)
                raise RuntimeError(f"kernel helper {fn.__module__}.{name} is no longer its module's {name!r}")
            g[name] = _COMPILED.setdefault(fn, _jit(fn, **flags))
        prefetch = _prefetch_intrinsic()
        if _first_compile:
            _listen_for_compiles()


_first_compile: list = []  # callbacks of :func:`on_first_compile` not called yet


def on_first_compile(callback) -> None:
    """Call ``callback()`` (no arguments) once, when a kernel first compiles in this process, i.e. is not
    found in numba's disk cache: on a machine's first runs (the first encode compiles for about a minute);
    never when numba is absent or every kernel loads from the cache.  The command line tells a user at a
    terminal why it is slow (:func:`pmwm_codec.cli.main`)."""
    _first_compile.append(callback)
    if _numba is not None and len(_first_compile) == 1:
        _listen_for_compiles()


def _listen_for_compiles() -> None:
    """Register a listener for numba's ``numba:compile`` event (numba's event API: it starts only on a
    cache miss) that calls the :func:`on_first_compile` callbacks at the first one (afterwards it has
    none to call)."""
    from numba.core import event

    class FirstCompile(event.Listener):
        def on_start(self, ev):
            callbacks = list(_first_compile)
            _first_compile.clear()
            for callback in callbacks:
                callback()

        def on_end(self, ev):
            pass

    event.register("numba:compile", FirstCompile())


def prefetch(array, i):
    """A hint for compiled kernels: start loading the cache line of ``array[i]`` (of ``array[i, 0]`` for
    a 2-D array; ``0 <= i < len(array)``) and go on at once, so that loads whose addresses are known
    early overlap the work before them.  Changes no result; in plain Python it does nothing.  Kernels
    call it as ``topology.prefetch`` (the module attribute, swapped by :func:`_load_numba`)."""


def _prefetch_intrinsic():
    """:func:`prefetch` compiled: LLVM's ``llvm.prefetch`` (write, high locality, data cache)."""
    from llvmlite import ir
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def compiled_prefetch(typingctx, array, i):
        def codegen(context, builder, signature, args):
            aryty = signature.args[0]
            ary = context.make_array(aryty)(context, builder, args[0])
            index = [args[1]] + [context.get_constant(_numba.types.intp, 0)] * (aryty.ndim - 1)
            ptr = cgutils.get_item_pointer(context, builder, aryty, ary, index, wraparound=False)
            i8p, i32 = ir.IntType(8).as_pointer(), ir.IntType(32)
            fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(ir.VoidType(), [i8p, i32, i32, i32]),
                                                "llvm.prefetch.p0i8")
            builder.call(fn, [builder.bitcast(ptr, i8p), ir.Constant(i32, 1), ir.Constant(i32, 3), ir.Constant(i32, 1)])
            return context.get_dummy_value()

        return _numba.types.void(array, _numba.types.intp), codegen

    return compiled_prefetch


def _jit(fn, **flags):
    """``numba.njit`` with the on-disk cache (next to the module, else numba's user cache dir);
    without the cache when no cache dir is writable (numba refuses ``cache=True`` then)."""
    try:
        return _numba.njit(cache=True, nogil=True, **flags)(fn)
    except RuntimeError:  # "cannot cache function ...: no locator available"
        return _numba.njit(cache=False, nogil=True, **flags)(fn)


def kernel_helper(fn=None, *, allocates: bool = False, inline: bool = False):
    """Decorator for plain-Python functions that compiled kernels call: numba needs them compiled
    too.  The module global becomes the dispatcher when numba loads (:func:`_load_numba`).

    A helper that makes no array (no ``np.empty``, no slice, no sort: ``allocates`` False) is
    compiled without numba's reference counting: with it, every call counts each array argument
    up on entry and down on return with atomic instructions, which took a third of a decode's
    time (helpers are called per coded decision and per corner).  ``@kernel_helper(allocates=True)``
    keeps it for the helpers that need it.  ``inline`` has numba inline the helper into its
    callers (``inline="always"``): for small helpers returning tuples of state that must stay in
    registers rather than go through memory at every call.

    A helper is compiled for the argument types of its first call from each kind of site, and a
    constant there is a *literal* type of its own (``Literal[int](0)``): a helper first called as
    ``f(x, 0)`` and then as ``f(x, i)`` is compiled twice.  Call sites pass constants as
    ``np.int64(0)`` where the helper is also called with a variable, so that a machine's first runs
    compile each helper once.  Array arguments likewise: a readonly array is another type than a
    writable one (:class:`~pmwm_codec.format.rangecoder.Decoder` copies its bytes into a writable
    array so that decoding shares the payload kernels the encoder compiled: a machine's first
    decode after its first encode took 22.5 s, now 4.5).
    """
    if fn is None:
        return lambda f: kernel_helper(f, allocates=allocates, inline=inline)
    flags = {} if allocates else {"_nrt": False}
    if inline:
        flags["inline"] = "always"
    if _numba is not None:
        return _COMPILED.setdefault(fn, _jit(fn, **flags))
    _HELPERS.append((fn.__globals__, fn.__name__, fn, flags))
    return fn


def group_order(keys: np.ndarray, n: int) -> np.ndarray:
    """Stable order of ``keys`` (c,) int in ``[0, n)``: (c,) int64, equal to ``argsort(kind="stable")``.

    A counting sort (O(c + n)) when numba is available, numpy's stable argsort otherwise.
    """
    keys = np.asarray(keys, dtype=np.int64)
    kernel = compiled(_counting_order_py) if len(keys) >= 64 else None
    if kernel is None:
        return np.argsort(keys, kind="stable")
    return kernel(keys, int(n))


def half_edges(faces: np.ndarray, with_dst: bool = True):
    """Half-edge end points: ``(src, dst, opposite)`` each (3m,) int64, face-major (``src`` a view of
    ``faces``); ``dst`` None unless ``with_dst`` (a copy the caller may not need)."""
    faces = np.ascontiguousarray(faces)
    kernel = compiled(_rotated_kernel)
    if kernel is not None:
        return faces.reshape(-1), kernel(faces, 1) if with_dst else None, kernel(faces, 2)
    dst = None
    if with_dst:
        dst = np.empty_like(faces)  # faces[:, [1, 2, 0]] by slices: contiguous, no gather
        dst[:, :2] = faces[:, 1:]
        dst[:, 2] = faces[:, 0]
    opp = np.empty_like(faces)  # faces[:, [2, 0, 1]]
    opp[:, 0] = faces[:, 2]
    opp[:, 1:] = faces[:, :2]
    return faces.reshape(-1), None if dst is None else dst.reshape(-1), opp.reshape(-1)


def _rotated_kernel(faces, shift):
    """Compiled half of :func:`half_edges`: (3m,) the corner ``(c + shift) % 3`` of every corner ``c`` of
    ``faces`` (m, 3), face-major (``dst``: shift 1, ``opp``: shift 2)."""
    out = np.empty(3 * len(faces), faces.dtype)
    for f in range(len(faces)):
        for c in range(3):
            out[3 * f + c] = faces[f, (c + shift) % 3]
    return out


def edge_table(faces: np.ndarray, n: int) -> EdgeTable:
    """Build the :class:`EdgeTable` of ``faces`` (m, 3) over ``n`` vertices."""
    src, dst, _ = half_edges(faces)
    lo = np.minimum(src, dst)
    hi = np.maximum(src, dst)
    key = lo * n + hi
    by_hi = group_order(hi, n)
    order = by_hi[group_order(lo[by_hi], n)]
    ks = key[order]
    first = np.empty(len(ks), dtype=bool)
    first[0] = True
    np.not_equal(ks[1:], ks[:-1], out=first[1:])
    starts = np.flatnonzero(first)
    count = np.diff(np.append(starts, len(ks)))
    he0 = order[starts]
    second = np.minimum(starts + 1, len(ks) - 1)
    he1 = np.where(count >= 2, order[second], -1)
    return EdgeTable(n, ks[starts], lo[he0], hi[he0], count, he0, he1)


def edge_ids(a: np.ndarray, b: np.ndarray, n: int) -> tuple:
    """A number for each undirected edge ``(a, b)`` ((k,) int64 vertex ids in ``[0, n)``): :func:`key_ids` of
    the keys ``min * n + max``."""
    return key_ids(np.minimum(a, b) * n + np.maximum(a, b))


def key_ids(keys: np.ndarray) -> tuple:
    """A number for each of the ``keys`` ((k,) int64, >= 0): ``(ids (k,), counts (e,))`` int64, ``ids`` equal
    exactly when the keys are, ``counts[ids[i]]`` the key's rows.  The numbering is only an identity: numpy's
    is the sorted keys' (``np.unique``), the compiled one's the keys' first rows' (an open-addressing table,
    no sort: :func:`_key_ids_kernel`)."""
    kernel = compiled(_key_ids_kernel)
    if kernel is not None:
        return kernel(np.asarray(keys, np.int64))
    _, ids, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return ids.reshape(-1), counts


def _key_ids_kernel(keys):
    """Compiled :func:`key_ids`: each key looked up in a table of at least twice as many slots (linear probing
    from a Fibonacci hash: the top bits of the key times 2**64 / golden ratio); a new key gets the next number."""
    k = len(keys)
    bits = 1
    while (1 << bits) < 2 * k:
        bits += 1
    table = np.full(1 << bits, -1, np.int64)
    num = np.empty(1 << bits, np.int64)
    ids = np.empty(k, np.int64)
    counts = np.zeros(k, np.int64)
    e = 0
    for i in range(k):
        key = keys[i]
        j = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(64 - bits))
        while table[j] >= 0 and table[j] != key:
            j = (j + 1) & ((1 << bits) - 1)
        if table[j] < 0:
            table[j] = key
            num[j] = e
            e += 1
        ids[i] = num[j]
        counts[num[j]] += 1
    return ids, counts[:e]


def csr(groups: np.ndarray, values: np.ndarray, n: int):
    """Group ``values`` by ``groups`` (ids in [0, n)): returns ``(start (n+1,), values sorted)``."""
    order = group_order(groups, n)
    start = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(np.bincount(groups, minlength=n), out=start[1:])
    return start, values[order]


def expand(start: np.ndarray, rows: np.ndarray):
    """For CSR ``start`` and query ``rows`` (k,), the flat positions of every entry.

    Returns ``(owner (t,), pos (t,))``: ``owner[j]`` is the index into ``rows`` that
    entry ``pos[j]`` belongs to.  Vectorised ``[range(start[r], start[r+1]) for r in rows]``.
    """
    lengths = start[rows + 1] - start[rows]
    owner = np.repeat(np.arange(len(rows)), lengths)
    offsets = np.cumsum(lengths) - lengths
    pos = np.arange(int(lengths.sum())) - np.repeat(offsets, lengths) + np.repeat(start[rows], lengths)
    return owner, pos


def face_keys(faces: np.ndarray):
    """Rotation-invariant, orientation-keeping keys of faces: (m, 3) int64 rows.

    Each face is rotated so its smallest vertex id comes first; two faces are the
    same oriented triangle iff their rows are equal.
    """
    k = np.argmin(faces, axis=1)
    idx = (k[:, None] + np.arange(3)[None, :]) % 3
    return np.take_along_axis(faces, idx, axis=1)


def any_corner(flags: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: the faces of ``faces`` (m, 3) int with a corner whose vertex has ``flags`` (n,) bool;
    ``flags[faces].any(axis=1)``, the three columns or-ed (numpy's ``any`` along a row of three is
    ~10x the time on a scan's faces); compiled, one pass (:func:`_any_corner_kernel`)."""
    kernel = compiled(_any_corner_kernel) if faces.dtype == np.int64 and flags.dtype == np.bool_ else None
    if kernel is not None:
        return kernel(flags, np.ascontiguousarray(faces))
    return flags[faces[:, 0]] | flags[faces[:, 1]] | flags[faces[:, 2]]


def _any_corner_kernel(flags, faces):
    """Compiled :func:`any_corner`."""
    out = np.empty(len(faces), np.bool_)
    for f in range(len(faces)):
        out[f] = flags[faces[f, 0]] | flags[faces[f, 1]] | flags[faces[f, 2]]
    return out


def two_alike(keys: np.ndarray) -> np.ndarray:
    """(m,) bool: the rows of ``keys`` (m, 3) (a value per face corner: a grid point, a seam group) with two
    equal values; a face whose corners ``keys`` tells apart has none."""
    a, b, c = keys[:, 0], keys[:, 1], keys[:, 2]
    return (a == b) | (b == c) | (c == a)


def two_alike_at(values: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) bool: ``two_alike(values[faces])`` for ``values`` (n,) int64 and ``faces`` (m, 3) int64, compiled
    without the (m, 3) gather (:func:`_two_alike_at_kernel`)."""
    kernel = compiled(_two_alike_at_kernel) if faces.dtype == np.int64 and values.dtype == np.int64 else None
    if kernel is not None:
        return kernel(values, np.ascontiguousarray(faces))
    return two_alike(values[faces])


def _two_alike_at_kernel(values, faces):
    """Compiled :func:`two_alike_at`."""
    out = np.empty(len(faces), np.bool_)
    for f in range(len(faces)):
        a, b, c = values[faces[f, 0]], values[faces[f, 1]], values[faces[f, 2]]
        out[f] = (a == b) | (b == c) | (c == a)
    return out


def unique_edges(faces: np.ndarray) -> np.ndarray:
    """Undirected edges of ``faces`` (m, 3) int: (e, 2) int64 rows ``(lo, hi)``, ``lo < hi``.

    Every edge once, rows in ascending lexicographic order; (0, 2) without faces.
    """
    f = np.asarray(faces, np.int64).reshape(-1, 3)
    e = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]])
    if len(e) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    return np.unique(np.sort(e, axis=1), axis=0)


def mean_edge_length(positions: np.ndarray, faces: np.ndarray) -> float:
    """Mean length of the undirected edges: ``positions`` (n, 3) float, ``faces`` (m, 3) int.

    Each edge counts once however many faces share it; 0.0 (no warning) without faces.
    """
    e = unique_edges(faces)
    if len(e) == 0:
        return 0.0
    p = np.asarray(positions, np.float64)
    return float(np.linalg.norm(p[e[:, 0]] - p[e[:, 1]], axis=1).mean())


def canonical_faces(faces: np.ndarray) -> np.ndarray:
    """Faces in a canonical order: (m, 3) int64.

    Every face is rotated so its smallest vertex id comes first (orientation kept,
    see :func:`face_keys`), and the rows are sorted lexicographically, so two face
    arrays hold the same oriented triangles iff their canonical forms are equal.
    """
    g = face_keys(np.asarray(faces, np.int64).reshape(-1, 3))
    return g[np.lexsort((g[:, 2], g[:, 1], g[:, 0]))]


def same_face_set(a: np.ndarray, b: np.ndarray) -> bool:
    """True when the (m, 3) int face arrays ``a`` and ``b`` hold the same oriented triangles.

    Compared as multisets: any face order, any rotation within a face; a flipped
    face (other orientation) differs.
    """
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        return False
    return bool(np.array_equal(canonical_faces(a), canonical_faces(b)))
