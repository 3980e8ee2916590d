"""The ``PMWM_progressive_mesh`` extension object: schema check and digests.

The normative schemas live in ``spec/schema/``; this package ships byte-identical
copies in ``pmwm_codec/format/schema/`` (``tests/test_spec_sync.py`` keeps them
equal) so an installed package can validate without the source tree.

:func:`check_extension` is the gate every extension object passes before a reader
uses it: an unknown newer ``version`` is :class:`UnsupportedVersionError`, anything
the schema rejects is a one-line :class:`FormatError`.
"""

from __future__ import annotations

import functools
import hashlib
import json
from pathlib import Path

from ..constants import EXTENSION_NAME, FORMAT_VERSION
from ..errors import FormatError, UnsupportedVersionError
from .layout import DIGEST_SIZE

SCHEMA_DIR = Path(__file__).with_name("schema")
#: Schema of the object on the mesh primitive.
PRIMITIVE_SCHEMA = f"mesh.primitive.{EXTENSION_NAME}.schema.json"
#: Extension fields the writer sets itself; callers must not pass them.
RESERVED_FIELDS = ("version", "chunks")
#: Extension fields the writer derives and drops from the caller's (a copied ``baseMac`` would not match).
DERIVED_FIELDS = ("baseMac",)
#: Per-chunk fields the caller supplies (``chunk_meta``).
CHUNK_META_FIELDS = ("splits", "vertexCount", "faceCount", "geometricError")
#: Chunk payload codec id and the versions this reader knows (bitstream.md §6 and §8).
PAYLOAD_CODEC = "pmwm-vsplit"
PAYLOAD_VERSIONS = (1, 2)
#: Version written unless the caller asks for another.
DEFAULT_PAYLOAD_VERSION = 1


def digest(data) -> str:
    """BLAKE2b-128 of ``data`` as 32 lowercase hex digits (the chunk ``digest`` field)."""
    return hashlib.blake2b(data, digest_size=DIGEST_SIZE).hexdigest()


def payload_version(ext: dict) -> int:
    """The chunk payload version of an extension object (1 when it names none); FormatError for
    a codec or version this reader does not know.  The one place readers dispatch on it."""
    payload = ext.get("payload", {"codec": PAYLOAD_CODEC, "version": 1})
    if not isinstance(payload, dict) or payload.get("codec") != PAYLOAD_CODEC or payload.get("version") not in PAYLOAD_VERSIONS \
            or isinstance(payload.get("version"), bool):
        raise FormatError(f"unknown chunk payload codec {str(payload)[:60]}")
    return payload["version"]


@functools.lru_cache(maxsize=None)
def _validator():
    import jsonschema
    from referencing import Registry, Resource

    schemas = {p.name: json.loads(p.read_text()) for p in SCHEMA_DIR.glob("*.schema.json")}
    registry = Registry().with_resources((name, Resource.from_contents(s)) for name, s in schemas.items())
    schema = schemas[PRIMITIVE_SCHEMA]
    cls = jsonschema.validators.validator_for(schema)
    return cls(schema, registry=registry)


def check_extension(ext) -> dict:
    """Check an extension object; return it unchanged.

    Raises
    ------
    UnsupportedVersionError
        ``version`` is an integer newer than :data:`FORMAT_VERSION`.
    FormatError
        Not an object, or the schema rejects it (message names the JSON path).
    """
    if not isinstance(ext, dict):
        raise FormatError(f"{EXTENSION_NAME}: extension must be a JSON object")
    version = ext.get("version")
    if isinstance(version, int) and not isinstance(version, bool) and version > FORMAT_VERSION:
        raise UnsupportedVersionError(
            f"{EXTENSION_NAME}: version {version} is newer than this reader (version {FORMAT_VERSION})"
        )
    error = next(iter(sorted(_validator().iter_errors(ext), key=lambda e: list(e.absolute_path))), None)
    if error is not None:
        where = "/".join(str(p) for p in error.absolute_path) or "(root)"
        message = error.message.replace("\n", " ")
        if len(message) > 160:
            message = message[:157] + "..."
        raise FormatError(f"{EXTENSION_NAME}: {where}: {message}")
    if version != FORMAT_VERSION:
        raise UnsupportedVersionError(f"{EXTENSION_NAME}: version {version} is not supported (this reader knows {FORMAT_VERSION})")
    return ext
