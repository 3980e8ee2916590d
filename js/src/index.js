/**
 * pmwm-progressive: decoder of PMWM_progressive_mesh (.pmw) files, written from spec/.
 *
 *   const { positions, indices, chunksApplied, complete } = await decodePmw(bytes);
 *
 * In Node, Draco base meshes decode through the `draco3d` package; in a browser pass
 * `{draco: {decode(bytes, {positionId, attributeIds})}}` (e.g. built on three.js' DRACOLoader).
 */
import { PmwDecoder } from './decoder.js';

export { PmwDecoder } from './decoder.js';
export * from './errors.js';
export {
  MAX_VERTICES, MAX_FACES, MAX_CHUNKS, MAX_JSON_BYTES, MAX_JSON_DEPTH, MAX_CHUNK_BYTES, MAX_DECOMPRESSED_CHUNK_BYTES,
} from './constants.js';

/**
 * Decodes a whole (or cut) .pmw file.
 * @param {Uint8Array|ArrayBuffer|ArrayBufferView} bytes the file, or a prefix of it holding at least the base meshes
 * @param {{chunks?: number, maxChunks?: number, draco?: object}} options chunks (or maxChunks, PmwDecoder's name: the
 *   same option): apply at most this many chunks of the stream
 * @returns {Promise<{positions: Float32Array, indices: Uint32Array, positionsInt: Int32Array, parts: object[],
 *   chunksApplied: number, chunkCount: number, complete: boolean, bytesRead: number}>}
 *   positions (3 per vertex), indices (3 per face) of every progressive primitive, concatenated; complete: the
 *   input is whole (every byte up to the GLB length given), however many chunks `chunks` let apply (a whole file
 *   with {chunks: 2} is complete, chunksApplied 2 of chunkCount); as pmw decode's --json `complete`;
 *   the arrays of PmwDecoder.snapshot() (shared with parts[0] for one primitive; positionsInt a
 *   Float64Array only for a hostile stream whose values leave the int32 range)
 */
export async function decodePmw(bytes, { chunks, maxChunks, draco } = {}) {
  const decoder = new PmwDecoder({ draco, chunks, maxChunks });
  const results = await decoder.feed(bytes);
  const end = await decoder.close();
  const mesh = decoder.snapshot();
  return {
    ...mesh, chunksApplied: end.chunksApplied, chunkCount: end.chunkCount, complete: end.complete,
    bytesRead: results.length ? results[results.length - 1].bytesRead : 0,
  };
}
