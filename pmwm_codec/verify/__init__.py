"""Verifying watermarks: a ``.pmw`` stream chunk by chunk (:mod:`.stream`).

:func:`verify_stream` ``(source, key, watermark=None) -> StreamVerification``.
"""

from .stream import StreamVerification, verify_stream

__all__ = ["StreamVerification", "verify_stream"]
