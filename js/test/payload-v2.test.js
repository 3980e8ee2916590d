/**
 * Chunk payload version 2 (spec/bitstream.md §8): files encoded by the Python package with
 * `payload_version=2` decode here to the reference decoder's level at every chunk boundary (plain
 * and Draco bases, closed meshes and boundaries, attributes, two primitives, an exact watermark),
 * to the same levels as their version 1 encoding, and every prefix of one to the levels its
 * whole chunks give; a batch of dependent splits (which the decoder's kept valences cannot follow)
 * and the batch after it decode as in the reference decoder. Stored-chunk rules (digest, uncompressedLength) and hostile streams end in
 * named errors; on streams with flipped bits both decoders refuse the same files and give the
 * same levels on the others. Skipped when no Python imports a pmwm_codec that writes version 2.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, test } from 'node:test';
import { CorruptChunkError, FormatError, PmwDecoder, PmwError, TruncatedError, UnsupportedError } from '../src/index.js';
import { parseGlb, planDocument } from '../src/header.js';
import { ChunkDecoderV2 } from '../src/payload-v2.js';
import { MeshState } from '../src/vsplit.js';
import { failure, jsLevels, jsOutcome, levelDigest, seededRandom } from './lib/helpers.js';
import { decodeFiles, dependentBatches, encodeCase, pythonHasPayloadV2 } from './lib/python.js';
import { chunkPayloads, withPayload } from './lib/rewrite.js';

const skip = !pythonHasPayloadV2() && 'no Python importing a pmwm_codec that writes payload version 2 ($PYTHON, $PMW_PYTHONPATH)';
const CASES = ['closed-sphere.draco', 'boundaries.plain', 'attributes.plain', 'two-primitives.draco', 'exact-watermark.draco'];
const dir = mkdtempSync(join(tmpdir(), 'pmw-v2-'));
after(() => rmSync(dir, { recursive: true, force: true }));

const encoded = new Map();
/** Case `name` encoded with payload `version`: {bytes, want} (want: the Python decoder's levels). */
function encodedCase(name, version = 2) {
  const key = `${name}.v${version}`;
  if (!encoded.has(key)) {
    const file = join(dir, `${key}.pmw`);
    const want = encodeCase(name, version, file);
    encoded.set(key, { bytes: new Uint8Array(readFileSync(file)), want });
  }
  return encoded.get(key);
}


/** The payload versions of a file's progressive primitives. */
function payloadVersions(bytes) {
  const h = parseGlb(bytes);
  return planDocument(h.gltf, h.binLength).primitives.map((p) => p.payloadVersion);
}

for (const name of CASES) {
  test(`${name}: payload version 2 decodes to the Python decoder's level at every chunk boundary`, { skip }, async () => {
    const { bytes, want } = encodedCase(name);
    assert.ok(payloadVersions(bytes).every((v) => v === 2), 'every primitive is payload version 2');
    assert.ok(want.levels.length >= 3, `${want.levels.length} levels: base and at least two chunks`);
    const { levels, end } = await jsLevels(bytes);
    assert.deepEqual(levels, want.levels);
    assert.equal(end.complete, want.complete);
    assert.equal(end.complete, true);
  });
}

test('the version 2 and version 1 encodings of a mesh decode to the same levels', { skip }, async () => {
  for (const name of ['boundaries.plain', 'attributes.plain']) {
    const strip = (levels) => levels.map(({ bytesRead, ...level }) => level);
    const v1 = await jsLevels(encodedCase(name, 1).bytes);
    const v2 = await jsLevels(encodedCase(name, 2).bytes);
    assert.deepEqual(payloadVersions(encodedCase(name, 1).bytes), [1]);
    assert.deepEqual(strip(v2.levels), strip(v1.levels));
  }
});

test('every prefix of a version 2 file gives the levels of its whole chunks, or TruncatedError before the base', { skip }, async () => {
  const { bytes, want } = encodedCase('boundaries.plain');
  const baseEnd = want.levels[0].bytesRead;
  for (let cut = 1; cut < bytes.length; cut++) {
    const d = new PmwDecoder();
    const shown = (await d.feed(bytes.subarray(0, cut))).map((r) => r.bytesRead);
    if (cut < baseEnd) {
      assert.deepEqual(shown, [], `cut ${cut}`);
      await assert.rejects(d.close(), TruncatedError, `cut ${cut}`);
      continue;
    }
    assert.deepEqual(shown, want.levels.filter((l) => l.bytesRead <= cut).map((l) => l.bytesRead), `cut ${cut}`);
    assert.equal((await d.close()).complete, false);
    assert.equal(levelDigest(d.snapshot()), want.levels[shown.length - 1].sha256, `cut ${cut}`);
  }
});

test('a version 2 chunk is stored raw: a changed byte fails its digest, a chunk table whose arrays disagree is a FormatError', { skip }, async () => {
  const { bytes } = encodedCase('boundaries.plain');
  const chunks = chunkPayloads(bytes);
  assert.equal(chunks[1].payload.length, chunks[1].c.length, 'openChunk gives the stored bytes themselves');
  const h = parseGlb(bytes);
  const flipped = bytes.slice();
  flipped[h.binStart + chunks[1].c.offset + 2] ^= 0x10;
  const corrupt = await failure(flipped);
  assert.ok(corrupt instanceof CorruptChunkError && corrupt.chunk === 2, String(corrupt)); // chunks[1]: the second
  const lying = withPayload(bytes, 1, chunks[1].payload, { faceCounts: [] });
  const e = await failure(lying);
  assert.ok(e instanceof FormatError && /chunk table/.test(e.message), String(e));
  assert.equal(await failure(withPayload(bytes, 1, chunks[1].payload)), null, 'the rewrite itself keeps the file valid');
});

test('a payload version this decoder does not know is an UnsupportedError', { skip }, async () => {
  const { bytes } = encodedCase('boundaries.plain');
  const J = new DataView(bytes.buffer, bytes.byteOffset).getUint32(12, true);
  const text = new TextDecoder().decode(bytes.subarray(20, 20 + J)).replace('"version": 2', '"version": 3')
    .replace('"version":2', '"version":3');
  const edited = bytes.slice();
  edited.set(new TextEncoder().encode(text), 20);
  assert.ok((await failure(edited)) instanceof UnsupportedError);
});

test('a version 2 stream with a byte more or a byte less, or another chunk\'s stream, is a FormatError of its chunk', { skip }, async () => {
  const { bytes } = encodedCase('closed-sphere.draco');
  const chunks = chunkPayloads(bytes);
  const k = chunks.length - 1;
  const p = chunks[k].payload;
  for (const payload of [Uint8Array.of(...p, 0), p.subarray(0, p.length - 1), chunks[0].payload]) {
    const e = await failure(withPayload(bytes, k, payload));
    assert.ok(e instanceof FormatError, String(e));
    assert.match(e.message, new RegExp(`^chunk ${k + 1}: `));
  }
  const empty = await failure(withPayload(bytes, k, new Uint8Array(0))); // a packed table cannot even say so
  assert.ok(empty instanceof FormatError && /byteLength 0/.test(empty.message), String(empty));
});

test('on version 2 streams with flipped bits, the JS and Python decoders refuse the same files and agree on the others', { skip }, async () => {
  const sources = ['closed-sphere.draco', 'boundaries.plain', 'attributes.plain'].map((name) => {
    const { bytes } = encodedCase(name);
    return { name, bytes, chunks: chunkPayloads(bytes) };
  });
  const r = seededRandom(5);
  const files = [];
  const js = [];
  for (let i = 0; i < 90; i++) {
    const { name, bytes, chunks } = sources[i % sources.length];
    const index = Math.floor(r() * chunks.length);
    const payload = chunks[index].payload.slice();
    // anywhere, or in the last 4 bytes (the coder's flush, where a flip can leave a valid stream)
    const span = i % 2 ? payload.length : 4;
    for (let f = 1 + Math.floor(r() * 2); f > 0; f--) payload[payload.length - 1 - Math.floor(r() * span)] ^= 1 << Math.floor(r() * 8);
    const file = join(dir, `flipped-${i}.${name}.pmw`);
    const hostile = withPayload(bytes, index, payload);
    writeFileSync(file, hostile);
    files.push(file);
    js.push(await jsOutcome(hostile));
  }
  const py = decodeFiles(files);
  let refused = 0;
  for (const [i, want] of py.entries()) {
    const got = js[i];
    if (want.error !== undefined) {
      refused++;
      assert.ok(got instanceof PmwError, `${files[i]}: Python refuses it (${want.error}), JS decodes it`);
    } else {
      assert.ok(!(got instanceof PmwError), `${files[i]}: Python decodes it, JS refuses it (${got?.name}: ${got?.message})`);
      assert.deepEqual(got.levels, want.levels, files[i]);
    }
  }
  assert.ok(refused > 0 && refused < py.length, `${refused} of ${py.length} refused: both outcomes compared`);
});

test('a batch of adjacent splits whose moved faces hold each other, and the batch after it, decode as in the Python decoder', { skip }, () => {
  const { D, capN, capM, base, chunk, final } = dependentBatches();
  const values = Int32Array.from(base.values);
  const faces = Uint32Array.from(base.faces);
  const state = new MeshState(values, faces, values.length / D, faces.length / 3, D, capN, capM);
  new ChunkDecoderV2(state).decodeChunk(Uint8Array.from(Buffer.from(chunk, 'hex')));
  assert.deepEqual([state.n, state.m], [final.values.length / D, final.faces.length / 3]);
  assert.deepEqual([...state.values.subarray(0, state.n * D)], final.values);
  assert.deepEqual([...state.faces.subarray(0, state.m * 3)], final.faces);
});
