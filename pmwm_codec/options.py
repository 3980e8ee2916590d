"""The checks :func:`pmwm_codec.encode` runs on what it is given before any work: the options by name,
type and range, ``src`` / ``dst`` by kind, and output names (one home for the rules ``pmw encode``
applies to its arguments, so the Python API refuses what the command line refuses).

Every refusal is an :class:`~pmwm_codec.errors.OptionError` (a :class:`~pmwm_codec.errors.PmwError`)
naming the option and the value: never a ``KeyError`` or ``TypeError`` from deep inside.
"""

from __future__ import annotations

import errno
import math
import numbers
import os

from .constants import MAX_GRID_BITS, MIN_GRID_BITS
from .errors import OptionError

__all__ = ["checked_options", "check_source", "check_destination", "check_output_path", "checked_chunks",
           "refuse_mesh_suffix", "IMAGE_OPTIONS", "image_options_given", "ignored_without_image"]

#: The :func:`pmwm_codec.encode` options that shape only the watermark image's mark, each with the value it has
#: when not given: an encode without a watermark writes the same file whatever they are, and says so
#: (:func:`ignored_without_image`).
IMAGE_OPTIONS = {"mode": "exact", "bits": None, "embed_from": None, "step_units": None}


def _int(name, lo, hi=None):
    def check(value):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < lo or (hi is not None and value > hi):
            bound = f"an integer in {lo}..{hi}" if hi is not None else f"an integer >= {lo}"
            raise OptionError(f"{name} must be {bound}, got {value!r}")
        return int(value)
    return check


def _choice(name, choices):
    def check(value):
        if not isinstance(value, str) or value not in choices:
            raise OptionError(f"{name} must be one of {', '.join(map(repr, choices))}, got {value!r}")
        return value
    return check


def _positive(name):
    def check(value):
        if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value <= 0:
            raise OptionError(f"{name} must be a positive finite number, got {value!r}")
        return float(value)
    return check


def _embed_from(value):
    """A split index (int >= 0) or a fraction of the splits in [0, 1)."""
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise OptionError(f"embed_from must be a split index >= 0 or a fraction in [0, 1), got {value!r}")
    if isinstance(value, numbers.Integral):
        if value < 0:
            raise OptionError(f"embed_from must be a split index >= 0 or a fraction in [0, 1), got {value!r}")
        return int(value)
    if not (math.isfinite(value) and 0 <= value < 1):
        raise OptionError(f"embed_from must be a split index >= 0 or a fraction in [0, 1), got {value!r}")
    return float(value)


def _owner_id(value):
    """None, False (no owner layer), an int in [0, 2**64) or 1-16 hex digits."""
    from .watermark.key import parse_owner_id

    if value is None or value is False:
        return value
    if isinstance(value, str):
        try:
            return parse_owner_id(value)
        except ValueError as exc:
            raise OptionError(f"owner_id: {exc}") from None
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 0 <= value < 1 << 64:
        raise OptionError(f"owner_id must be an integer in [0, 2**64) or 1-16 hex digits, got {value!r}")
    return int(value)


def _measure(value):
    from .distortion import MEASURES

    if value is None or isinstance(value, bool):
        return value
    return _choice("measure", MEASURES)(value)


def _flag(name):
    def check(value):
        if not isinstance(value, bool):
            raise OptionError(f"{name} must be True or False, got {value!r}")
        return value
    return check


def _callable(name):
    def check(value):
        if not callable(value):
            raise OptionError(f"{name} must be callable, got {value!r}")
        return value
    return check


def _options() -> dict:
    """The check of each option :func:`pmwm_codec.encode` takes (see its docstring), by name."""
    from .format.extension import PAYLOAD_VERSIONS
    from .watermark.codec import MAX_BITS, MODES

    return {
        "mode": _choice("mode", MODES),
        "bits": _int("bits", 1, MAX_BITS),
        "grid_bits": _int("grid_bits", MIN_GRID_BITS, MAX_GRID_BITS),
        "base_codec": _choice("base_codec", ("draco", "plain")),
        "base_vertices": _int("base_vertices", 4),
        "step_units": _positive("step_units"),
        "embed_from": _embed_from,
        "owner_id": _owner_id,
        "owner_strength": _positive("owner_strength"),
        "min_chunk_splits": _int("min_chunk_splits", 1),
        "zstd_level": _int("zstd_level", 1, 22),
        "payload_version": _int("payload_version", min(PAYLOAD_VERSIONS), max(PAYLOAD_VERSIONS)),
        "measure": _measure,
        "strip_image_profiles": _flag("strip_image_profiles"),
        "keep_flat_normals": _flag("keep_flat_normals"),
        "geometry_only": _flag("geometry_only"),
        "progress": _callable("progress"),
    }


def checked_options(options: dict) -> dict:
    """``options`` with every value checked (None: the default, for those that have one) and numbers
    made plain ints / floats; OptionError for an unknown name or a value out of range."""
    checks = _options()
    out = {}
    for name, value in options.items():
        if name not in checks:
            raise OptionError(f"unknown option {name!r} (one of {', '.join(checks)})")
        nullable = name not in ("mode", "base_codec", "zstd_level", "payload_version", "strip_image_profiles",
                                "keep_flat_normals", "geometry_only")
        out[name] = value if value is None and nullable else checks[name](value)
    if out.get("mode") == "paper" and out.get("bits") is not None and out["bits"] < 2:
        raise OptionError(f"bits must be at least 2 in paper mode, got {out['bits']}")
    return out


def image_options_given(options: dict) -> list:
    """The :data:`IMAGE_OPTIONS` of ``options`` (:func:`checked_options`) given another value than their default,
    spelled as Python gives them (``bits``, ``mode='paper'``), in :data:`IMAGE_OPTIONS` order."""
    return [f"{name}={options[name]!r}" if name == "mode" else name
            for name, default in IMAGE_OPTIONS.items() if options.get(name, default) != default]


def ignored_without_image(names, image: str = "watermark") -> list:
    """The notice of each option of ``names`` (as the caller spells them: ``bits``; ``pmw encode``: ``--bits``)
    that an encode without a watermark image ignores, ``image`` naming that argument as the caller does
    (``--watermark``): ``"bits ignored: no watermark"``.  The one wording of the library and the command line."""
    return [f"{name} ignored: no {image}" for name in names]


def _is_path(x) -> bool:
    return isinstance(x, (str, os.PathLike))


def check_source(src) -> None:
    """OptionError unless ``src`` is a :class:`~pmwm_codec.mesh.Mesh`, a path, or an in-memory glTF
    ``(gltf dict, buffers)``."""
    from .mesh import Mesh

    if isinstance(src, Mesh) or _is_path(src):
        return
    if isinstance(src, tuple) and len(src) == 2 and isinstance(src[0], dict):
        return
    arrays = ("vertices", "faces") if hasattr(src, "vertices") else ("positions", "faces")
    hint = ""  # a mesh of another library (trimesh's .vertices), arrays given as a pair: the Mesh that takes them
    if all(hasattr(src, name) for name in arrays):
        hint = f": give pmwm_codec.Mesh(src.{arrays[0]}, src.{arrays[1]})"
    elif isinstance(src, (tuple, list)) and len(src) == 2 and not isinstance(src[0], dict):
        hint = ": give pmwm_codec.Mesh(positions, faces) for a pair of arrays"
    raise OptionError(f"src must be a Mesh, a path or a (gltf dict, buffers) pair, got {type(src).__name__}{hint}")


def check_destination(dst, inputs=()) -> None:
    """OptionError unless ``dst`` is a path or a binary file object a ``.pmw`` can be written to whole.

    A path goes through :func:`check_output_path` (not ``"-"``, a directory, a device, a missing
    directory, one of the ``inputs`` paths or a key file) and must not carry another mesh format's
    suffix (a ``.pmw`` is a GLB); a file object through
    :func:`~pmwm_codec.sources.check_file_object` (open, binary, writable, blocking).
    """
    from .sources import check_file_object

    if not _is_path(dst):
        if not callable(getattr(dst, "write", None)):
            raise OptionError(f"dst must be a path or a binary file open for writing, got {type(dst).__name__}")
        check_file_object(dst, "dst", "write")
        return
    path = check_output_path(dst, ".pmw", inputs=inputs)
    refuse_mesh_suffix(path)


def check_output_path(path, what: str, inputs=(), key: bool = False) -> str:
    """``path`` (a ``str``, ``bytes`` or ``os.PathLike`` naming an output, a ``what``: ".pmw", "mesh", "key")
    as a ``str`` once it is known that a file can be published there, checked before any work.

    Raises OptionError when it is not a path, is empty (an unset variable), ``-`` (nothing goes to
    standard output), ends with a separator or is a directory, is a device, FIFO or socket
    (:func:`~pmwm_codec.atomic.check_replaceable`), cannot be a file name (too long, a file as a
    directory), when its directory is missing or not writable, or when it is one of the ``inputs``
    paths; WatermarkKeyError when, unless it is itself a ``key``, it names a key file
    (:func:`~pmwm_codec.watermark.key.refuse_key_target`).  The messages are those of ``pmw``.
    """
    from .atomic import check_replaceable
    from .sources import path_argument, shown_path
    from .watermark.key import refuse_key_target, same_path

    path = path_argument(path, f"the {what} path")
    shown = shown_path(path)
    if path == "":
        raise OptionError(f"the {what} path is empty (an unset variable?): give a file name")
    if path == "-":
        raise OptionError(f"-: the {what} is written to a file, not to standard output; give a file name")
    if "\0" in path:  # os.lstat & co. raise ValueError, no OSError
        raise OptionError(f"{shown}: cannot write {what} (embedded null byte)")
    if _descriptor_link(path):  # /dev/stdout: the rename would replace the link itself
        raise OptionError(f"{shown}: a link to an open file descriptor (standard output or error), which an "
                          f"output never replaces; the {what} is written to a file, not to standard output: "
                          "give a file name")
    if not key:
        refuse_key_target(path, what)
    if os.path.isdir(path):
        raise OptionError(f"{shown}: is a directory; give a file name for the {what}")
    if path.endswith(os.sep) or (os.altsep and path.endswith(os.altsep)):
        raise OptionError(f"{shown}: ends with '{path[-1]}', so it names a directory; give a file name for the {what}")
    try:
        check_replaceable(path)
    except OSError as exc:
        why = exc.strerror if exc.errno == errno.EEXIST else f"{shown}: cannot write {what} ({exc.strerror or exc})"
        raise OptionError(why) from None
    directory = os.path.dirname(os.path.abspath(path)) or "."
    if not os.path.isdir(directory):
        raise OptionError(f"{shown}: cannot write {what}: directory {directory} does not exist")
    if not os.access(directory, os.W_OK):
        raise OptionError(f"{shown}: cannot write {what}: directory {directory} is not writable")
    for source in inputs:  # a name with a NUL names no file (its reader says so), so not this one
        if _is_path(source) and "\0" not in os.fsdecode(os.fspath(source)) and same_path(source, path):
            raise OptionError(f"{shown}: is also the input {shown_path(source)}; give the {what} another name "
                              "(writing it would replace the input)")
    return path


def _descriptor_link(path: str) -> bool:
    """Whether ``path`` is a symbolic link to a process's open file descriptor, as ``/dev/stdout`` is (to
    ``/proc/self/fd/1``; ``/dev/fd/1`` on macOS).  An output is published by a rename, which replaces a link
    rather than writing through it: ``-o /dev/stdout`` would put the file in place of the system's link."""
    try:
        target = os.readlink(path)
    except (OSError, ValueError):
        return False
    target = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)), target))
    return target.startswith(("/proc/", "/dev/fd/"))


def refuse_mesh_suffix(path) -> None:
    """OptionError when the ``.pmw`` path ``path`` carries another mesh format's suffix (``.obj``, ``.ply``,
    ``.stl``, ``.gltf``): a .pmw is a GLB, and a mesh of that name would be replaced by one."""
    from .mesh import MESH_SUFFIXES
    from .sources import shown_path

    suffix = os.path.splitext(os.fspath(path))[1]
    if suffix.lower() in MESH_SUFFIXES and suffix.lower() != ".glb":
        raise OptionError(f"{shown_path(path)}: a .pmw is a GLB file; name it .pmw (or .glb), not {suffix}")


def checked_chunks(chunks):
    """``chunks`` of ``decode`` / ``cut`` / ``decode_asset``: None (every chunk that arrived) or an int >= 0;
    OptionError otherwise (``-1`` read as the base alone, ``nan`` as every chunk, ``2.5`` as 3)."""
    if chunks is None:
        return None
    if isinstance(chunks, bool) or not isinstance(chunks, numbers.Integral) or chunks < 0:
        raise OptionError(f"chunks must be None or an integer >= 0, got {chunks!r}")
    return int(chunks)
