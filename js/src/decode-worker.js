/**
 * The decode worker (a module Worker started by worker-decoder.js): runs a PmwDecoder off the main thread.
 *
 * Messages in: {type: 'start', maxChunks, bases} (the Draco bases three.js decoded, see dracoFromBases),
 * {type: 'feed', id, bytes: Uint8Array}, {type: 'close', id}. Out: {type: 'ready'} once loaded;
 * {id, results} per feed (with `error` too when a chunk failed after
 * the levels it holds: every later request fails), each result with `mesh.parts[p]` {positions, indices, attributes} (copied
 * by postMessage, not transferred: see handle) for the primitive its level changed, null for the others; {id, end, levels} for close (levels: how many levels this worker decoded); {id, error}
 * (serializeError) for any failure.
 */
import { PmwDecoder } from './decoder.js';
import { dracoFromBases, serializeError } from './worker-decoder.js';

let decoder = null;
let levels = 0;

/** A result with only the arrays the plugin draws. */
function packLevel(r) {
  const parts = r.mesh.parts.map((part) => {
    if (!part) return null; // a primitive this level left as it was
    const { positions, indices, attributes } = part;
    return { positions, indices, attributes };
  });
  return { ...r, mesh: { parts } };
}

async function handle(msg) {
  if (msg.type === 'start') {
    decoder = new PmwDecoder({ draco: dracoFromBases(msg.bases), maxChunks: msg.maxChunks, snapshots: 'changed' });
  } else if (msg.type === 'feed') {
    const results = (await decoder.feed(msg.bytes)).map(packLevel);
    levels += results.length;
    // a chunk that failed after others of this piece: their levels, and the error (every later call fails)
    const failed = decoder.error ? { error: serializeError(decoder.error) } : {};
    // copied, not transferred: a transfer detaches the arrays' ArrayBuffers, and the first detached buffer of an
    // isolate drops V8's ArrayBufferDetaching protector for good: code that relied on it is deoptimised and the
    // typed-array accesses compiled after it check for a detached buffer, which slowed every later chunk's
    // decode far more than these copies cost
    self.postMessage({ id: msg.id, results, ...failed });
  } else if (msg.type === 'close') {
    self.postMessage({ id: msg.id, end: await decoder.close(), levels });
  }
}

self.onmessage = ({ data: msg }) => handle(msg).catch((e) => self.postMessage({ id: msg.id, error: serializeError(e) }));
self.postMessage({ type: 'ready' });
