/**
 * The decode worker (a module Worker started by worker-decoder.js): runs a PmwDecoder off the main thread.
 *
 * Messages in: {type: 'start', maxChunks, bases} (the Draco bases three.js decoded, see dracoFromBases),
 * {type: 'feed', id, bytes: Uint8Array}, {type: 'close', id}. Out: {type: 'ready'} once loaded;
 * {id, results} per feed (with `error` too when a chunk failed after
 * the levels it holds: every later request fails), each result with `mesh.parts[p]` {positions, indices, attributes} (buffers
 * transferred) for the primitive its level changed, null for the others; {id, end, levels} for close (levels: how many levels this worker decoded); {id, error}
 * (serializeError) for any failure.
 */
import { PmwDecoder } from './decoder.js';
import { dracoFromBases, serializeError } from './worker-decoder.js';

let decoder = null;
let levels = 0;

/** A result with only the arrays the plugin draws, and the ArrayBuffers to transfer (each once). */
function packLevel(r, buffers) {
  const parts = r.mesh.parts.map((part) => {
    if (!part) return null; // a primitive this level left as it was
    const { positions, indices, attributes } = part;
    buffers.add(positions.buffer);
    buffers.add(indices.buffer);
    for (const values of Object.values(attributes)) buffers.add(values.buffer);
    return { positions, indices, attributes };
  });
  return { ...r, mesh: { parts } };
}

async function handle(msg) {
  if (msg.type === 'start') {
    decoder = new PmwDecoder({ draco: dracoFromBases(msg.bases), maxChunks: msg.maxChunks, snapshots: 'changed' });
  } else if (msg.type === 'feed') {
    const buffers = new Set();
    const results = (await decoder.feed(msg.bytes)).map((r) => packLevel(r, buffers));
    levels += results.length;
    // a chunk that failed after others of this piece: their levels, and the error (every later call fails)
    const failed = decoder.error ? { error: serializeError(decoder.error) } : {};
    self.postMessage({ id: msg.id, results, ...failed }, [...buffers]);
  } else if (msg.type === 'close') {
    self.postMessage({ id: msg.id, end: await decoder.close(), levels });
  }
}

self.onmessage = ({ data: msg }) => handle(msg).catch((e) => self.postMessage({ id: msg.id, error: serializeError(e) }));
self.postMessage({ type: 'ready' });
