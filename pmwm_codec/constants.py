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
#: Deepest nesting of arrays / objects in JSON, the outermost value being level 1: a reader refuses a
#: ``.pmw`` JSON chunk nested deeper, and the encoder input JSON (glTF, key files) nested deeper.  The
#: encoder writes the input's own members (``extras``, extensions it carries) at the depth they had and
#: its own at most 11 deep, so every file it writes is within the readers' limit.
MAX_JSON_DEPTH = 64
#: Most JSON values the keyed ``sceneMac`` reads (spec/bitstream.md §6.3): the glTF JSON without ``buffers``
#: and ``bufferViews``, every object, array, string, number, literal and the document itself counted once.  Its
#: canonical form is copied and hashed whole (a few seconds at this limit): a legal 64 MiB of ``extras`` (30M
#: values) cost a verify 280 s and 5 GB.  A writer refuses a document over it; a verifier reads a scene over it as
#: not the key holder's (a mismatch), without copying it.
MAX_SCENE_VALUES = 1 << 22

# --- limits of the encoder side, checked before its inputs are read into memory ---
#: Largest mesh the encoder takes: it needs about 1.9 KB per vertex (measured on a
#: subdivided bunny, ../shared/research-notes/security-audit.md), so 4M vertices
#: is about 8 GB.  Counted over all progressive primitives of one input.
MAX_ENCODE_VERTICES = 1 << 22
MAX_ENCODE_FACES = 1 << 23
#: Largest resource a ``.gltf`` may bring in through a ``uri`` (a buffer or an image
#: file inside the asset's folder, or a ``data:`` URI after decoding); larger is refused
#: and never read past this many bytes.
MAX_RESOURCE_BYTES = 1 << 30
#: At most this many textures are written beside a decoded OBJ / PLY (:mod:`pmwm_codec.meshexport`): an input
#: never makes ``pmw decode`` fill a folder with files; the rest are left out with a notice.
MAX_WRITTEN_IMAGES = 256
#: Largest input mesh / glTF / key file read whole into memory.
MAX_INPUT_FILE_BYTES = 2 << 30
MAX_KEY_FILE_BYTES = 64 << 20
#: Largest watermark image decoded (pixels, read from the header first): 4096 x 4096.
#: It is downscaled to at most 256 x 256 anyway.
MAX_WATERMARK_PIXELS = 1 << 24
