/**
 * The push API: bytes fed in pieces give the same levels as the whole file; a cut file is
 * progress (every chunk wholly received is applied), a file cut before its base is truncated,
 * and a chunk whose bytes differ from its digest is a named error that names the chunk.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { CorruptChunkError, DracoError, FormatError, PmwDecoder, TruncatedError, decodePmw } from '../src/index.js';
import { CONFORMANCE, conformanceFiles, seededRandom, levelDigest } from './lib/helpers.js';

const load = (f) => new Uint8Array(readFileSync(join(CONFORMANCE, f)));


async function levels(bytes, pieces) {
  const d = new PmwDecoder({ snapshots: true });
  const out = [];
  for (const piece of pieces(bytes)) out.push(...await d.feed(piece));
  return { out, end: await d.close() };
}

for (const file of conformanceFiles()) {
  test(`${file}: fed in random pieces, the same levels as fed whole`, async () => {
    const bytes = load(file);
    const whole = await levels(bytes, (b) => [b]);
    const rand = seededRandom(7);
    const pieces = (b) => {
      const out = [];
      for (let at = 0; at < b.length;) {
        const n = 1 + Math.floor(rand() * 700);
        out.push(b.subarray(at, at + n));
        at += n;
      }
      return out;
    };
    const split = await levels(bytes, pieces);
    assert.deepEqual(split.out.map((r) => [r.chunk, r.bytesRead, levelDigest(r.mesh)]),
      whole.out.map((r) => [r.chunk, r.bytesRead, levelDigest(r.mesh)]));
    assert.equal(split.end.complete, true);
  });
}

test('a file cut anywhere after its base gives the level of the last whole chunk', async () => {
  const bytes = load(conformanceFiles().find((f) => f.startsWith('sphere-attributes')));
  const { out } = await levels(bytes, (b) => [b]);
  for (let i = 0; i < out.length; i++) {
    const cutAt = i + 1 < out.length ? out[i + 1].bytesRead - 1 : bytes.length;
    const cut = await decodePmw(bytes.subarray(0, cutAt));
    assert.equal(cut.chunksApplied, out[i].chunk);
    assert.equal(cut.complete, cutAt === bytes.length);
    assert.equal(levelDigest(cut), levelDigest(out[i].mesh));
  }
});

test('a file cut before its base mesh is complete is reported truncated with bytes received and needed', async () => {
  const bytes = load(conformanceFiles()[0]);
  const { out } = await levels(bytes, (b) => [b]);
  for (const cutAt of [0, 7, 20, 500, out[0].bytesRead - 1]) {
    const d = new PmwDecoder();
    assert.deepEqual(await d.feed(bytes.subarray(0, cutAt)), []);
    await assert.rejects(d.close(), (e) => e instanceof TruncatedError && e.bytesReceived === cutAt);
  }
});

test('a chunk whose stored bytes change is corrupt, named, and neither it nor later chunks apply', async () => {
  const bytes = load(conformanceFiles()[0]).slice();
  const { out } = await levels(bytes, (b) => [b]);
  bytes[out[1].bytesRead - 3] ^= 0x10; // inside the first chunk (chunk 1: level 1)
  const d = new PmwDecoder();
  // the base came in the same feed: it is delivered, and the error comes from the next call
  assert.deepEqual((await d.feed(bytes)).map((r) => r.chunk), [0]);
  assert.ok(d.error instanceof CorruptChunkError && d.error.chunk === 1);
  assert.equal(d.chunksApplied, 0);
  await assert.rejects(d.feed(new Uint8Array(0)), (e) => e instanceof CorruptChunkError && e.chunk === 1);
  await assert.rejects(d.close(), CorruptChunkError);
  // the base alone first: the feed that brings the bad chunk (and no good level) rejects at once
  const e = new PmwDecoder();
  assert.equal((await e.feed(bytes.subarray(0, out[0].bytesRead))).length, 1);
  await assert.rejects(e.feed(bytes.subarray(out[0].bytesRead)), (x) => x instanceof CorruptChunkError && x.chunk === 1);
});

test('bytes beyond the GLB length are a format error', async () => {
  const bytes = load(conformanceFiles()[0]);
  const longer = new Uint8Array(bytes.length + 4);
  longer.set(bytes);
  await assert.rejects(decodePmw(longer), FormatError);
});

test('a JSON chunk holding a number that overflows a double is a format error naming the member', async () => {
  const bytes = load(conformanceFiles()[0]);
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jsonLength = dv.getUint32(12, true);
  const text = new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)).trimEnd();
  let json = text.replace('"nodes":[{', '"nodes":[{"translation":[1e999,0,0],');
  assert.notEqual(json, text);
  while (json.length % 4) json += ' ';
  const head = new TextEncoder().encode(json);
  const bin = bytes.subarray(20 + jsonLength);
  const out = new Uint8Array(20 + head.length + bin.length);
  out.set(bytes.subarray(0, 20));
  out.set(head, 20);
  out.set(bin, 20 + head.length);
  const odv = new DataView(out.buffer);
  odv.setUint32(8, out.length, true);
  odv.setUint32(12, head.length, true);
  await assert.rejects(decodePmw(out), (e) => e instanceof FormatError && /"0" holds a number that is not finite/.test(e.message));
});

test('a preamble declaring a JSON chunk over the limit is refused from its first 20 bytes, before any JSON is buffered', async () => {
  const { LimitError, MAX_JSON_BYTES } = await import('../src/index.js');
  const head = new Uint8Array(20);
  const dv = new DataView(head.buffer);
  dv.setUint32(0, 0x46546c67, true); // 'glTF'
  dv.setUint32(4, 2, true);
  dv.setUint32(8, 0xfffffff0, true);
  dv.setUint32(12, MAX_JSON_BYTES + 4, true);
  dv.setUint32(16, 0x4e4f534a, true); // 'JSON'
  const d = new PmwDecoder();
  await assert.rejects(d.feed(head), LimitError);
  await assert.rejects(d.feed(new Uint8Array(1024)), LimitError); // and stays failed: nothing more is taken
});

test('a chunk count that is not a whole number >= 0 is refused, not rounded or taken as none', async () => {
  const bytes = load(conformanceFiles()[0]);
  for (const chunks of [-1, NaN, 2.5, '2']) {
    await assert.rejects(decodePmw(bytes, { chunks }), RangeError, String(chunks));
  }
  assert.equal((await decodePmw(bytes, { chunks: 0 })).chunksApplied, 0);
  assert.equal((await decodePmw(bytes, { chunks: undefined })).complete, true);
});

test('decodePmw and feed take an ArrayBuffer or any typed array as bytes, and refuse what is not bytes with a TypeError', async () => {
  const bytes = load(conformanceFiles()[0]);
  const whole = await decodePmw(bytes);
  const buffer = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.length); // as response.arrayBuffer() gives
  for (const input of [buffer, new DataView(buffer), new Uint16Array(buffer)]) { // a GLB's length is a multiple of 4
    const got = await decodePmw(input);
    assert.equal(levelDigest(got), levelDigest(whole), input.constructor.name);
  }
  const d = new PmwDecoder();
  await d.feed(new Uint16Array(buffer, 0, 10)); // the first 20 bytes, by their bytes
  for (const wrong of ['glTF', [103, 108, 84, 70], null, 7]) await assert.rejects(d.feed(wrong), TypeError);
  await d.feed(new Uint8Array(buffer, 20)); // the refusals left the decoder as it was
  assert.equal((await d.close()).complete, true);
});

test('a Draco decoder of the caller\'s that fails or gives no mesh ends in a DracoError', async () => {
  const bytes = load(conformanceFiles().find((f) => f.includes('.draco.')));
  const decoders = [
    { decode: async () => { throw new Error('the DRACOLoader worker crashed'); } },
    { decode: async () => undefined },
    { decode: async () => ({ positions: new Float32Array(3) }) },
  ];
  for (const draco of decoders) await assert.rejects(decodePmw(bytes, { draco }), DracoError);
});

test('an error crossing from the decode worker keeps its class and fields, a base mesh\'s chunk null included', async () => {
  const { reviveError, serializeError } = await import('../src/worker-decoder.js');
  for (const sent of [new CorruptChunkError('chunk 3: BLAKE2b digest differs', 2),
    new CorruptChunkError('base mesh: baseDigest mismatch', null), new TruncatedError('cut', 10, 20)]) {
    const got = reviveError(JSON.parse(JSON.stringify(serializeError(sent))));
    assert.ok(got instanceof sent.constructor && got.message === sent.message, got.name);
    assert.deepEqual({ ...got }, { ...sent });
  }
});
