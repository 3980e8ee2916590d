"""Names and hard limits defined once for the whole package.

Every byte layout lives in :mod:`pmwm_codec.format.layout`; every name a file
carries (extension name, format version) and every limit a reader enforces before
it allocates lives here, so the spec, the writer and the reader cannot drift.
"""

#: The glTF extension carried by a ``.pmw`` file's mesh primitive.  Vendor-style
#: uppercase prefix (``PMWM``), never ``KHR_``/``EXT_``.
EXTENSION_NAME = "PMWM_progressive_mesh"

#: Version of the chunk payload format and of the extension JSON.  Bumped on any
#: incompatible change; golden files carry it in their names.
FORMAT_VERSION = 1

#: Default integer grid for positions (bits per axis over the largest bbox extent).
DEFAULT_GRID_BITS = 16
MIN_GRID_BITS = 8
MAX_GRID_BITS = 30

# --- hard limits checked before anything is allocated --------------------------
MAX_VERTICES = 1 << 26  # 67M vertices
MAX_FACES = 1 << 27  # 134M faces
MAX_CHUNKS = 1 << 16
MAX_JSON_BYTES = 64 << 20
MAX_CHUNK_BYTES = 1 << 30  # one compressed chunk
MAX_DECOMPRESSED_CHUNK_BYTES = 1 << 28  # 256 MiB: a 1M-vertex batch needs ~2 MB
