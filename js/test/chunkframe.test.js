/**
 * Stored chunk checks (spec/bitstream.md §5) of src/chunkframe.js on frames with valid digests:
 * zstddec (libzstd) must refuse a frame whose content checksum or data differs (the decoder has no
 * XXH64 of its own), and a raw-block frame (test/lib/rewrite.js) must give its payload back exactly.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { createBLAKE2b } from 'hash-wasm';
import { initChunkFrames, openChunk } from '../src/chunkframe.js';
import { FormatError } from '../src/errors.js';
import { CONFORMANCE } from './lib/helpers.js';
import { chunkPayloads, rawFrame } from './lib/rewrite.js';

await initChunkFrames();
const blake = await createBLAKE2b(128);
const entry = (frame, length) => ({ digest: blake.init().update(frame).digest('hex'), uncompressedLength: length });
const payloads = chunkPayloads(new Uint8Array(readFileSync(join(CONFORMANCE, 'sphere-attributes.plain.v1.pmw'))));

test('a raw-block frame of every conformance payload decompresses to that payload', () => {
  for (const { payload } of payloads) {
    const frame = rawFrame(payload);
    assert.deepEqual(openChunk(frame, entry(frame, payload.length), 0), payload);
  }
});

test('a frame whose content checksum differs ends in a FormatError, also for an empty payload', () => {
  for (const payload of [payloads[0].payload, new Uint8Array(0)]) {
    const frame = rawFrame(payload);
    frame[frame.length - 1] ^= 0x40;
    assert.throws(() => openChunk(frame, entry(frame, payload.length), 3), (e) => e instanceof FormatError
      && /chunk 4: zstd (frame does not decode or its checksum differs|content checksum differs)/.test(e.message));
  }
});

test('a frame whose data differs under a matching digest ends in a FormatError', () => {
  const { payload } = payloads[0];
  const frame = rawFrame(payload);
  frame[20] ^= 0x01; // inside the first raw block: the checksum no longer matches the content
  assert.throws(() => openChunk(frame, entry(frame, payload.length), 0), FormatError);
});
