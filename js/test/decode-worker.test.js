// decode-worker.js run in this process under a stand-in `self` that records what the worker posts (the
// worker-decoder tests run it in a worker_threads Worker, where a transfer list cannot be seen).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { test } from 'node:test';
import { CONFORMANCE } from './lib/helpers.js';

const posted = [];
globalThis.self = { postMessage: (data, transfer) => posted.push({ data, transfer }) };
await import('../src/decode-worker.js');

/** The message the worker posts with `id`, once it has (polled, at most `ms` milliseconds). */
async function reply(id, ms = 10000) {
  for (const end = Date.now() + ms; Date.now() < end;) {
    const found = posted.find((p) => p.data.id === id);
    if (found) return found;
    await new Promise((resolve) => setTimeout(resolve, 5));
  }
  throw new Error(`the worker did not answer message ${id}`);
}

test('the decode worker posts its levels copied, transferring no ArrayBuffer: a detached buffer would drop V8\'s '
  + 'ArrayBufferDetaching protector in the worker, which throws away its compiled decoding code and checks every '
  + 'later typed-array access', async () => {
  const bytes = new Uint8Array(fs.readFileSync(path.join(CONFORMANCE, 'sphere-attributes.plain.v1.pmw')));
  assert.equal(posted[0].data.type, 'ready');
  self.onmessage({ data: { type: 'start', maxChunks: Infinity, bases: [] } });
  self.onmessage({ data: { type: 'feed', id: 1, bytes } });
  const { data, transfer } = await reply(1);
  assert.equal(data.error, undefined);
  assert.equal(data.results.length, 11, 'the base and its 10 chunks');
  const positions = data.results.at(-1).mesh.parts[0].positions;
  assert.ok(positions.length > 0 && positions.buffer.byteLength > 0, 'the last level\'s positions, not detached');
  assert.deepEqual(transfer ?? [], []);
  self.onmessage({ data: { type: 'close', id: 2 } });
  assert.equal((await reply(2)).data.end.complete, true);
});
