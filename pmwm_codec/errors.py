"""The package's named errors.

Everything a reader or the tools raise for bad input is a :class:`PmwError`, so
callers (and the ``pmw`` tool, which maps them to exit status 2) can catch one
type; each refusal is raised as the subclass naming its kind (a mesh it cannot use,
an input of the wrong kind, a ``.pmw`` that breaks the format, a key, an option or an
output), never as the base class itself.  Truncation is *not* an error of the file: a
cut stream yields every complete chunk; :class:`TruncatedError` is raised only when not
even the base mesh is complete.
"""


class PmwError(Exception):
    """Base class for every error the package raises on bad input."""


class MeshError(PmwError, ValueError):
    """A mesh that cannot be used: empty, NaN/inf coordinates, bad face indices, coordinates or attribute
    values float32 cannot carry on the grid asked for, an asset with no triangle primitive to encode."""


class DegenerateMeshError(MeshError):
    """A well-formed mesh with nothing to encode: every triangle is degenerate.

    Bad input for a mesh file; a glTF asset passes such a primitive through unchanged.
    """


class InputFormatError(PmwError, ValueError):
    """An input file that is not a readable mesh or image, or not of the kind the call needs (a
    ``--reference`` ``.pmw`` that cannot be read or carries no watermark)."""


class FormatError(PmwError, ValueError):
    """A ``.pmw`` stream that breaks the container or chunk layout."""


class UnsupportedVersionError(FormatError):
    """A ``.pmw`` in a version this reader does not implement: a newer extension ``version``, a chunk
    ``payload`` codec or version it does not know, a GLB container version other than 2 (spec README,
    *Kinds of refusal*)."""


class LimitError(FormatError):
    """Declared counts or sizes exceed the reader's hard limits."""


class ChecksumError(FormatError):
    """A chunk whose digest does not match: corruption, not truncation.

    ``chunk`` is the chunk's number in stream order, from 1 as in the message, ``pmw verify``,
    ``pmw info`` and the levels (level k is reached by chunk k; 0 is the base mesh), and as
    JavaScript's ``CorruptChunkError.chunk``; None for a base mesh whose ``baseDigest`` differs.
    """

    def __init__(self, message, chunk=None):
        super().__init__(message)
        self.chunk = chunk


class TruncatedError(FormatError):
    """The stream ended before its base mesh was complete.  ``bytes_read``: the bytes it holds; ``bytes_needed``: the
    bytes it needs (a lower bound while the JSON is not in, spec README *Partial files*), None when not said."""

    def __init__(self, message, bytes_read=0, bytes_needed=None):
        super().__init__(message)
        self.bytes_read = bytes_read
        self.bytes_needed = bytes_needed


class WatermarkKeyError(PmwError, ValueError):
    """A key file that is unreadable or belongs to another file."""


class OwnerLayerError(PmwError, ValueError):
    """An owner layer asked for (an explicit owner ID) that could not be read back from the
    mesh as it would be stored; nothing is written."""


class OptionError(PmwError, ValueError):
    """An option of :func:`pmwm_codec.encode` that is unknown or out of its range, or a ``src`` / ``dst``
    it cannot take (an output that would replace an input, ``"-"``, a GLB named as another format, an output
    file or picture that cannot be written); a reader's source or data of a kind it cannot read (an int, a
    ``str`` from a file opened in text mode)."""
