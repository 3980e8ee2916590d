/** Limits of spec/README.md "Limits" (values of pmwm_codec/constants.py) and format constants. */
export const MAX_VERTICES = 67108864;
export const MAX_FACES = 134217728;
export const MAX_CHUNKS = 65536;
export const MAX_JSON_BYTES = 67108864;
export const MAX_CHUNK_BYTES = 1073741824;
export const MAX_DECOMPRESSED_CHUNK_BYTES = 268435456;
/** Deepest nesting of arrays and objects in the JSON chunk, the outermost value being level 1. */
export const MAX_JSON_DEPTH = 64;
export const MAX_BATCHES_PER_CHUNK = 4096;
/** Most progressive `attributes` of a primitive: the extension schema's `maxItems`. */
export const MAX_ATTRIBUTES = 16;
export const FORMAT_VERSION = 1;
export const EXTENSION = 'PMWM_progressive_mesh';
export const DRACO_EXTENSION = 'KHR_draco_mesh_compression';
export const PAYLOAD_CODEC = 'pmwm-vsplit';
/** Chunk payload versions this decoder reads: 1 (zstd, byte-plane columns) and 2 (range-coded stream). */
export const PAYLOAD_VERSIONS = [1, 2];
