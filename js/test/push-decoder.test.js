// The push decoder's contract around failures and misuse: every complete chunk before a bad one is
// delivered (the error comes from the next call, as pmwm_codec.StreamDecoder does), snapshot() gives the
// last good level, a throwing onLevel is not the decode's failure, the bytes are taken before feed()
// returns, close() waits for the feeds before it, and a feed() after close() is a TypeError.
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { readFileSync, writeFileSync, mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { test } from 'node:test';
import { parseGlb, planDocument } from '../src/header.js';
import { CorruptChunkError, decodePmw, FormatError, PmwDecoder } from '../src/index.js';
import { CONFORMANCE, levelDigest } from './lib/helpers.js';
import { python, TREE } from './lib/python.js';
import { withJson } from './lib/rewrite.js';

const NAME = 'sphere-attributes.plain.v1.pmw'; // plain base, attributes, payload version 1
const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, NAME)));
const { binStart, binLength, gltf } = parseGlb(bytes);
const stream = planDocument(gltf, binLength).stream;
const K = stream.length;

/** `bytes` with one stored byte of chunk `k` (0-based) flipped: its digest no longer matches. */
function corruptChunk(k) {
  const out = bytes.slice();
  out[binStart + stream[k].offset + stream[k].length - 1] ^= 0x40;
  return out;
}

const counts = (results) => results.map((r) => [r.chunk, r.vertexCount, r.faceCount, r.bytesRead]);

test('a corrupt chunk after others in the same feed: feed resolves to every good level, the next call fails', async () => {
  const bad = corruptChunk(K - 1);
  const good = await decodePmw(bytes, { chunks: K - 1 });
  const d = new PmwDecoder();
  const results = await d.feed(bad);
  assert.deepEqual(results.map((r) => r.chunk), [...Array(K).keys()], 'the base and every chunk before the bad one');
  assert.ok(d.error instanceof CorruptChunkError && d.error.chunk === K);
  assert.equal(d.chunksApplied, K - 1);
  assert.equal(levelDigest(d.snapshot()), levelDigest(good), 'snapshot() is the last good level');
  await assert.rejects(d.feed(new Uint8Array(0)), (e) => e === d.error);
  await assert.rejects(d.close(), (e) => e === d.error);
  assert.equal(levelDigest(d.snapshot()), levelDigest(good));
  await assert.rejects(decodePmw(bad), CorruptChunkError); // the whole-file call still fails
});

test('the levels delivered before a corrupt chunk do not depend on how the bytes were split', async () => {
  const bad = corruptChunk(3);
  const whole = new PmwDecoder();
  const expected = counts(await whole.feed(bad));
  assert.equal(expected.length, 4);
  for (const size of [1, 7, 100, 1000]) {
    const d = new PmwDecoder();
    const got = [];
    for (let at = 0; at < bad.length && !d.error; at += size) {
      got.push(...await d.feed(bad.subarray(at, at + size)).catch(() => [])); // a piece with no good level rejects
    }
    assert.deepEqual(counts(got), expected, `pieces of ${size}`);
    assert.ok(d.error instanceof CorruptChunkError, `pieces of ${size}`);
    assert.equal(levelDigest(d.snapshot()), levelDigest(whole.snapshot()), `pieces of ${size}`);
  }
});

test('a chunk that fails half applied is never shown: snapshot() rebuilds the last good level', async () => {
  // the last chunk's index entry claims other counts: the chunk is refused after its splits changed the mesh
  const edited = withJson(bytes, (json) => {
    const ext = json.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
    Object.assign(ext.chunks[K - 1], { vertexCount: ext.vertexCount + 1, faceCount: ext.faceCount + 2 });
    Object.assign(ext, { vertexCount: ext.vertexCount + 1, faceCount: ext.faceCount + 2 });
  });
  const good = await decodePmw(bytes, { chunks: K - 1 });
  for (const snapshots of [false, true]) {
    const d = new PmwDecoder({ snapshots });
    const results = await d.feed(edited);
    assert.equal(results.length, K, 'the base and the K - 1 good chunks');
    assert.ok(d.error instanceof FormatError);
    assert.match(d.error.message, new RegExp(`^chunk ${K}: vertex/face counts differ`));
    assert.equal(levelDigest(d.snapshot()), levelDigest(good));
    if (snapshots) assert.equal(levelDigest(results.at(-1).mesh), levelDigest(good));
    await assert.rejects(d.close(), FormatError);
  }
});

test('bytes past the GLB length in the piece that brings the last chunks: those chunks are delivered, then the refusal', async () => {
  const longer = new Uint8Array(bytes.length + 4);
  longer.set(bytes);
  const d = new PmwDecoder();
  const results = await d.feed(longer);
  assert.equal(results.length, K + 1);
  assert.ok(d.error instanceof FormatError && /GLB: 4 bytes after the declared file length/.test(d.error.message));
  assert.equal(levelDigest(d.snapshot()), levelDigest(await decodePmw(bytes)));
  await assert.rejects(d.close(), FormatError);
  await assert.rejects(decodePmw(longer), FormatError);
});

test('an onLevel that throws is reported (onCallbackError) and the decode goes on to the full mesh', async () => {
  const reported = [];
  const seen = [];
  const d = new PmwDecoder({
    onLevel: (r) => { seen.push(r.chunk); if (r.chunk === 3) throw new Error('bug in the caller'); },
    onCallbackError: (e) => reported.push(e.message),
  });
  const results = await d.feed(bytes);
  assert.equal(results.length, K + 1);
  assert.deepEqual(seen, [...Array(K + 1).keys()]);
  assert.deepEqual(reported, ['bug in the caller']);
  assert.equal(d.error, null);
  assert.equal((await d.close()).complete, true);
  assert.equal(levelDigest(d.snapshot()), levelDigest(await decodePmw(bytes)));
});

test('without onCallbackError, what onLevel throws goes to console.error', async (t) => {
  const logged = [];
  t.mock.method(console, 'error', (...args) => logged.push(args));
  const d = new PmwDecoder({ onLevel: (r) => { if (r.chunk === 1) throw new Error('bug'); } });
  assert.equal((await d.feed(bytes)).length, K + 1);
  assert.equal(logged.length, 1);
  assert.ok(logged[0].some((a) => a instanceof Error && a.message === 'bug'));
});

test('feed() takes the bytes before it returns: the caller may reuse its buffer at once, queued or not', async () => {
  const full = levelDigest(await decodePmw(bytes));
  // one feed, buffer cleared before it settles
  const d = new PmwDecoder();
  const buf = bytes.slice();
  const p = d.feed(buf);
  buf.fill(0);
  assert.equal((await p).length, K + 1);
  assert.equal(levelDigest(d.snapshot()), full);
  // many feeds queued through one reused buffer (as a BYOB reader does), none awaited before the next
  const e = new PmwDecoder();
  const scratch = new Uint8Array(97);
  const pending = [];
  for (let at = 0; at < bytes.length; at += scratch.length) {
    const n = Math.min(scratch.length, bytes.length - at);
    scratch.set(bytes.subarray(at, at + n));
    pending.push(e.feed(scratch.subarray(0, n)));
    scratch.fill(0xee);
  }
  assert.equal((await Promise.all(pending)).flat().length, K + 1);
  assert.equal(levelDigest(e.snapshot()), full);
});

test('close() waits for the feeds queued before it', async () => {
  const d = new PmwDecoder();
  d.feed(bytes.subarray(0, 5000));
  d.feed(bytes.subarray(5000));
  const end = await d.close();
  assert.equal(end.complete, true);
  assert.equal(end.chunksApplied, K);
  assert.deepEqual(await d.close(), end, 'a second close() gives the same end');
});

test('feed() after close() is a TypeError (misuse), not a FormatError', async () => {
  const d = new PmwDecoder();
  await d.feed(bytes);
  await d.close();
  await assert.rejects(d.feed(new Uint8Array(0)), (e) => e instanceof TypeError && /after close\(\)/.test(e.message));
  const e = new PmwDecoder();
  const closing = e.close(); // refused from the call on, before the close settles
  await assert.rejects(e.feed(bytes), TypeError);
  await assert.rejects(closing, { name: 'TruncatedError' });
});

test('a corrupt chunk\'s CorruptChunkError.chunk is the number its message gives, one past the last level, as Python\'s', async () => {
  const dir = mkdtempSync(join(tmpdir(), 'pmwm-chunk-number-'));
  try {
    for (const k of [0, 2, K - 1]) { // 0-based stream index of the chunk made corrupt
      const levels = [];
      const d = new PmwDecoder({ onLevel: (r) => levels.push(r.chunk) });
      await d.feed(corruptChunk(k));
      const { error } = d;
      assert.ok(error instanceof CorruptChunkError, String(error));
      assert.equal(error.chunk, Number(/^chunk (\d+):/.exec(error.message)?.[1]), error.message);
      assert.equal(error.chunk, levels.at(-1) + 1, 'the chunk after the last level delivered');
      if (python() === null) continue;
      const file = join(dir, `corrupt-${k}.pmw`);
      writeFileSync(file, corruptChunk(k));
      const py = spawnSync(python(), ['-c', `import sys
from pmwm_codec.errors import ChecksumError
from pmwm_codec.stream.reader import decode_stream
try:
    decode_stream(open(sys.argv[1], "rb").read())
except ChecksumError as e:
    print(e.chunk)`, file], { env: { ...process.env, PYTHONPATH: TREE }, encoding: 'utf8' });
      assert.equal(py.stdout.trim(), String(error.chunk), `pmwm_codec's ChecksumError.chunk ${py.stderr}`);
    }
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

test('decodePmw and PmwDecoder take either name of the chunk limit, chunks or maxChunks; both given must agree', async () => {
  for (const options of [{ chunks: 2 }, { maxChunks: 2 }, { chunks: 2, maxChunks: 2 }]) {
    assert.equal((await decodePmw(bytes, options)).chunksApplied, 2, JSON.stringify(options));
    const d = new PmwDecoder(options);
    await d.feed(bytes);
    assert.equal((await d.close()).chunksApplied, 2, JSON.stringify(options));
  }
  for (const options of [{ chunks: 2, maxChunks: 3 }, { chunks: 2, maxChunks: Infinity }]) {
    await assert.rejects(decodePmw(bytes, options), { name: 'RangeError', message: /maxChunks .* and chunks 2 differ/ });
    assert.throws(() => new PmwDecoder(options), { name: 'RangeError', message: /maxChunks .* and chunks 2 differ/ });
  }
});

test('a bad chunk limit is refused naming the option the caller used and showing its value as given', async () => {
  for (const name of ['chunks', 'maxChunks']) {
    for (const [value, text] of [[-1, '-1'], [1.5, '1.5'], [NaN, 'NaN'], ['2', '"2"'], [null, 'null']]) {
      const message = `${name} must be a whole number >= 0 (or Infinity), not ${text}`;
      await assert.rejects(decodePmw(bytes, { [name]: value }), { name: 'RangeError', message });
      assert.throws(() => new PmwDecoder({ [name]: value }), { name: 'RangeError', message });
    }
  }
});
