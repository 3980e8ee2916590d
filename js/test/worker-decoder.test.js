// The decoder the three.js plugin uses (worker-decoder.js): a WorkerDecoder on the main thread (Node: no Worker
// global) and in a module worker (test/lib/node-worker.js runs decode-worker.js in a worker_threads Worker).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { test } from 'node:test';
import { PmwDecoder } from '../src/index.js';
import { WorkerDecoder } from '../src/worker-decoder.js';
import { CONFORMANCE } from './lib/helpers.js';
import { withNodeWorker } from './lib/node-worker.js';

const NAME = 'sphere-attributes.plain.v1.pmw'; // plain base (no Draco), attributes, 10 chunks
const bytes = new Uint8Array(fs.readFileSync(path.join(CONFORMANCE, NAME)));

/** What a decoder's results say of each level: chunk, counts, and the arrays drawn. */
const levels = (results) => results.map(({ chunk, vertexCount, faceCount, mesh }) => ({ chunk, vertexCount, faceCount,
  parts: mesh.parts.map(({ positions, indices, attributes }) => ({ positions, indices, attributes })) }));

/**
 * Feeds `data` to `decoder` in pieces of `size` bytes from one buffer the caller reuses: each piece is written
 * into it, fed, and the buffer overwritten (0xff) as soon as feed() returns; `awaitEach` false: before any feed is
 * awaited, true: each feed awaited before the next piece is written (the buffer must still be the caller's).
 */
async function feedReusingBuffer(decoder, data, size, awaitEach) {
  const buffer = new Uint8Array(size);
  const fed = [];
  for (let at = 0; at < data.length; at += size) {
    const piece = buffer.subarray(0, Math.min(size, data.length - at));
    piece.set(data.subarray(at, at + piece.length));
    fed.push(decoder.feed(piece));
    buffer.fill(0xff);
    if (awaitEach) await fed.at(-1);
    assert.equal(buffer.buffer.byteLength, size, 'the caller\'s buffer was not taken (transferred) from it');
  }
  const results = [];
  for (const f of fed) results.push(...await f);
  return { results, end: await decoder.close() };
}

test('WorkerDecoder.feed copies its input: overwriting the buffer right after feed returns changes nothing decoded', async () => {
  const expected = levels(await new PmwDecoder({ snapshots: true }).feed(bytes));
  assert.equal(expected.length, 11);
  // first in the worker: a worker that failed to start (none without the shim) makes later ones try blob: URLs
  for (const awaitEach of [false, true]) {
    await withNodeWorker(async () => {
      const inWorker = new WorkerDecoder({ bases: [], worker: true });
      const worker = await feedReusingBuffer(inWorker, bytes, 1000, awaitEach);
      assert.equal(inWorker.inWorker, true, 'decoded in the worker');
      assert.equal(inWorker.workerLevels, expected.length);
      assert.equal(worker.end.complete, true);
      assert.deepEqual(levels(worker.results), expected);
    });
  }
  for (const awaitEach of [false, true]) {
    const onMainThread = new WorkerDecoder({ bases: [], worker: true }); // no Worker global: the main thread
    const main = await feedReusingBuffer(onMainThread, bytes, 1000, awaitEach);
    assert.equal(onMainThread.inWorker, false);
    assert.equal(main.end.complete, true);
    assert.deepEqual(levels(main.results), expected);
  }
});

test('WorkerDecoder: feed() after close() is a TypeError and a second close() settles as the first, as PmwDecoder', async () => {
  const d = new WorkerDecoder({ bases: [], worker: false });
  await d.feed(bytes);
  const end = await d.close();
  assert.equal(end.complete, true);
  await assert.rejects(d.feed(new Uint8Array(0)), (e) => e instanceof TypeError && /after close\(\)/.test(e.message));
  assert.deepEqual(await d.close(), end, 'a second close() gives the same end');
  const e = new WorkerDecoder({ bases: [], worker: false });
  const closing = e.close(); // refused from the call on, before the close settles
  await assert.rejects(e.feed(bytes), TypeError);
  await assert.rejects(closing, { name: 'TruncatedError' });
});
