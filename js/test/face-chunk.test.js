/**
 * Face chunks of chunk payload version 2 (spec/bitstream.md §8.6): a chunk whose entry adds no
 * vertex appends faces between existing vertices, under a probability table of its own.
 *
 * - The spec's example (the tetrahedron) decodes to its two faces, from the decisions the spec
 *   lists (written by test/lib/rangeencoder.js), from the bytes the spec prints and from the
 *   reference encoder's bytes (all the same); the conformance file with pillows ends in a face chunk.
 * - Files with glued pillows, encoded by the Python package (which sends them in a face chunk at
 *   the end), decode here to the reference decoder's level at every chunk boundary (counts, bytes
 *   read, positions and faces), every prefix to the levels of its whole chunks, and to the same
 *   levels after a read + write through glTF-Transform (the face chunk's entry kept).
 * - Face chunks between chunks that split: each chunk gives the reference decoder's mesh, so the
 *   splits after a face chunk read the mesh it left (valences and corner lists recounted), and the
 *   primitive's split table is neither read nor changed by a face chunk.
 * - Hostile face chunks end in a FormatError saying what is wrong, before any write out of
 *   bounds: cut short or too long, a rank beyond Up(a) or Near(a, b), a vertex at or beyond n,
 *   a face repeating a vertex, more faces than the entry adds (G, or a reverse face past it), an
 *   invalid bucket; in whole files too, where the JS and Python decoders refuse the same damaged
 *   face chunks and agree on the others.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, test } from 'node:test';
import { NodeIO } from '@gltf-transform/core';
import { PMWMProgressiveMesh } from 'pmwm-progressive/gltf-transform';
import { FormatError, PmwDecoder, PmwError } from '../src/index.js';
import { parseGlb, planDocument } from '../src/header.js';
import { ChunkDecoderV2, FACE_PROBS } from '../src/payload-v2.js';
import { MeshState } from '../src/vsplit.js';
import { CONFORMANCE, conformanceFiles, levelDigest, seededRandom } from './lib/helpers.js';
import { TREE, decodeFiles, encodeCase, faceChunks, pythonHasPayloadV2 } from './lib/python.js';
import { RangeEncoder, faceChunkBytes } from './lib/rangeencoder.js';
import { chunkPayloads, withPayload } from './lib/rewrite.js';

const skip = !pythonHasPayloadV2() && 'no Python importing a pmwm_codec that writes payload version 2 ($PYTHON, $PMW_PYTHONPATH)';
const PILLOWS = ['pillows.plain', 'pillows-shared.draco'];
const dir = mkdtempSync(join(tmpdir(), 'pmw-faces-'));
after(() => rmSync(dir, { recursive: true, force: true }));

const TETRAHEDRON = [0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2];
/** The spec's example: G = 1, gap 0, b by rank 0 in Up(0), c by rank 1 in Near(0, 1), twin. */
const EXAMPLE = [{ gap: 0, b: { rank: 0 }, c: { rank: 1 }, twin: 1 }];
const hex = (bytes) => Buffer.from(bytes).toString('hex');

/** A primitive's decoder over the mesh (faces flat, n vertices of D = 3 zero values), room for capM faces. */
function meshDecoder(faces, n, capM = faces.length / 3 + 16, values = new Int32Array(3 * n)) {
  const state = new MeshState(Int32Array.from(values), Uint32Array.from(faces), n, faces.length / 3, 3, n, capM);
  return { state, decoder: new ChunkDecoderV2(state) };
}

/** Decodes `bytes` as a face chunk over the tetrahedron (n vertices: 4, or more as isolated ones). */
function tetrahedronChunk(bytes, { n = 4, step = 2, capM } = {}) {
  const { state, decoder } = meshDecoder(TETRAHEDRON, n, capM);
  decoder.decodeChunk(bytes, { splits: 0, faceCount: 4 + step });
  return Array.from(state.faces.subarray(12, 3 * state.m));
}

test('the spec\'s example: a face chunk over the tetrahedron appends (0,1,3) and (0,3,1)', () => {
  const bytes = faceChunkBytes(EXAMPLE);
  assert.deepEqual(tetrahedronChunk(bytes), [0, 1, 3, 0, 3, 1]);
  const { state, decoder } = meshDecoder(TETRAHEDRON, 4);
  const table = decoder.probs.slice();
  decoder.decodeChunk(bytes, { splits: 0, faceCount: 6 });
  assert.deepEqual(decoder.probs, table, 'the primitive\'s split table is neither read nor changed');
  assert.equal(state.n, 4);
  assert.equal(FACE_PROBS, 32 + 5 * 256);
});

test('the spec\'s example bytes (spec/bitstream.md <!-- face-chunk-example -->) are those decisions and decode to its faces', () => {
  const text = readFileSync(join(TREE, 'spec', 'bitstream.md'), 'utf8');
  const block = text.split('<!-- face-chunk-example -->')[1]?.match(/```\n([^`]*)```/);
  assert.ok(block, 'the spec prints the example\'s bytes');
  const printed = block[1].replace(/\s+/g, '');
  assert.equal(printed, hex(faceChunkBytes(EXAMPLE)));
  assert.deepEqual(tetrahedronChunk(Uint8Array.from(Buffer.from(printed, 'hex'))), [0, 1, 3, 0, 3, 1]);
});

test('the spec\'s example from the reference encoder: the same bytes, the same faces', { skip }, () => {
  const { chunk } = faceChunks('tetrahedron');
  assert.equal(chunk, hex(faceChunkBytes(EXAMPLE)));
  assert.deepEqual(tetrahedronChunk(Uint8Array.from(Buffer.from(chunk, 'hex'))), [0, 1, 3, 0, 3, 1]);
});

test('a conformance file ends in a face chunk (conformance.test.js checks its levels, fuzz.test.js damages it)', () => {
  const files = conformanceFiles(2).filter((f) => /pillows/.test(f));
  assert.ok(files.length > 0, 'spec/conformance has a *pillows*.v2.pmw');
  for (const f of files) {
    const stream = entries(new Uint8Array(readFileSync(join(CONFORMANCE, f))));
    assert.equal(stream[stream.length - 1].splits, 0, `${f}: its last chunk is a face chunk`);
  }
});

test('the test encoder reproduces the coder example of spec §8.5', () => {
  const e = new RangeEncoder(16 + 256);
  for (const b of [0, 1, 1]) e.bit(0, b);
  e.direct(1);
  e.uint(16, 5);
  e.sint(16, -3);
  assert.equal(hex(e.finish()), '71b588250000');
});

const encoded = new Map();
/** Case `name` of lib/levels.py encoded with payload version 2: {bytes, want} (the Python decoder's levels). */
function encodedCase(name) {
  if (!encoded.has(name)) {
    const file = join(dir, `${name}.pmw`);
    const want = encodeCase(name, 2, file);
    encoded.set(name, { file, bytes: new Uint8Array(readFileSync(file)), want });
  }
  return encoded.get(name);
}

/** Every level the JS decoder gives for `bytes` fed whole, as levels.py prints them, and close(). */
async function jsLevels(bytes) {
  const d = new PmwDecoder({ snapshots: true });
  const results = await d.feed(bytes);
  const levels = results.map((r) => ({
    bytesRead: r.bytesRead, vertexCount: r.vertexCount, faceCount: r.faceCount,
    parts: r.parts.map((p) => [p.vertexCount, p.faceCount]), sha256: levelDigest(r.mesh),
  }));
  return { levels, end: d.close(), last: results[results.length - 1].mesh };
}

/** The stream's chunk entries (splits, vertexCount, faceCount) in order. */
const entries = (bytes) => {
  const h = parseGlb(bytes);
  return planDocument(h.gltf, h.binLength).stream;
};

/** Faces of `indices` (flat) whose reverse is also among them: the pillows' faces. */
function twinFaces(indices) {
  const key = (a, b, c) => { // rotation with the smallest first
    const m = Math.min(a, b, c);
    return m === a ? `${a},${b},${c}` : m === b ? `${b},${c},${a}` : `${c},${a},${b}`;
  };
  const all = new Set();
  for (let f = 0; f < indices.length; f += 3) all.add(key(indices[f], indices[f + 1], indices[f + 2]));
  let twins = 0;
  for (let f = 0; f < indices.length; f += 3) if (all.has(key(indices[f], indices[f + 2], indices[f + 1]))) twins++;
  return twins;
}

for (const name of PILLOWS) {
  test(`${name}: glued pillows come in a face chunk that decodes to the Python decoder's level at every chunk boundary`, { skip }, async () => {
    const { bytes, want } = encodedCase(name);
    const stream = entries(bytes);
    const last = stream[stream.length - 1];
    const before = stream[stream.length - 2];
    assert.equal(last.splits, 0, 'the last chunk is a face chunk');
    assert.equal(last.vertexCount, before.vertexCount);
    assert.ok(stream.slice(0, -1).every((c) => c.splits > 0), 'every other chunk splits');
    const { levels, end, last: mesh } = await jsLevels(bytes);
    assert.deepEqual(levels, want.levels);
    assert.equal(end.complete, true);
    const added = last.faceCount - before.faceCount;
    assert.ok(added >= 8, `${added} faces in the face chunk`);
    assert.equal(twinFaces(mesh.indices.subarray(3 * before.faceCount)), added, 'the face chunk appends pillows');
  });
}

test('read + write through glTF-Transform keeps a face chunk: its entry still adds no vertex, the same levels', { skip }, async () => {
  const { bytes, want } = encodedCase('pillows.plain');
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const rewritten = await io.writeBinary(await io.readBinary(bytes));
  assert.deepEqual(entries(rewritten).map((c) => [c.splits, c.vertexCount, c.faceCount]),
    entries(bytes).map((c) => [c.splits, c.vertexCount, c.faceCount]));
  const strip = (levels) => levels.map(({ bytesRead, ...level }) => level);
  assert.deepEqual(strip((await jsLevels(rewritten)).levels), strip(want.levels));
});

test('every prefix of a file ending in a face chunk gives the levels of its whole chunks', { skip }, async () => {
  const { bytes, want } = encodedCase('pillows.plain');
  const from = want.levels[want.levels.length - 2].bytesRead;
  for (let cut = from - 1; cut <= bytes.length; cut++) {
    const d = new PmwDecoder();
    const shown = (await d.feed(bytes.subarray(0, cut))).map((r) => r.bytesRead);
    assert.deepEqual(shown, want.levels.filter((l) => l.bytesRead <= cut).map((l) => l.bytesRead), `cut ${cut}`);
    assert.equal(d.close().complete, cut === bytes.length);
    assert.equal(levelDigest(d.snapshot()), want.levels[shown.length - 1].sha256, `cut ${cut}`);
  }
});

test('face chunks between chunks that split: each chunk gives the reference decoder\'s mesh', { skip }, () => {
  const { D, capN, capM, base, chunks } = faceChunks('sequence');
  assert.ok(chunks.some((c, k) => c.splits === 0 && chunks[k + 1]?.splits > 0), 'a split chunk follows a face chunk');
  const values = Int32Array.from(base.values);
  const faces = Uint32Array.from(base.faces);
  const state = new MeshState(values, faces, values.length / D, faces.length / 3, D, capN, capM);
  const decoder = new ChunkDecoderV2(state);
  for (const [k, c] of chunks.entries()) {
    const table = decoder.probs.slice();
    decoder.decodeChunk(Uint8Array.from(Buffer.from(c.chunk, 'hex')), c);
    if (c.splits === 0) assert.deepEqual(decoder.probs, table, `chunk ${k}: the split table is untouched`);
    assert.deepEqual([state.n, state.m], [c.values.length / D, c.faces.length / 3], `chunk ${k}`);
    assert.deepEqual([...state.values.subarray(0, state.n * D)], c.values, `chunk ${k}`);
    assert.deepEqual([...state.faces.subarray(0, state.m * 3)], c.faces, `chunk ${k}`);
  }
});

/** The FormatError that `fn` throws (asserted to be one, with a message matching `pattern`). */
function formatError(fn, pattern, what) {
  try {
    fn();
  } catch (e) {
    assert.ok(e instanceof FormatError, `${what}: ${e?.name}: ${e?.message}`);
    assert.match(e.message, pattern, what);
    return e;
  }
  return assert.fail(`${what}: decoded`);
}

test('hostile face chunks over the tetrahedron are FormatErrors that say what is wrong', () => {
  const rank = (r) => ({ rank: r });
  const raw = (r) => ({ raw: r });
  const face = (gap, b, c, twin = 0) => ({ gap, b, c, twin });
  const good = faceChunkBytes(EXAMPLE);
  const cases = [
    ['cut short', good.subarray(0, good.length - 1), {}, /does not end at the end/],
    ['a byte too many', Uint8Array.of(...good, 0), {}, /does not end at the end/],
    ['empty', new Uint8Array(0), {}, /./],
    ['rank 3 in Up(0) = (1, 2, 3)', faceChunkBytes([face(0, rank(3), rank(0))]), {}, /rank 3 in Up\(0\)/],
    ['rank 2 in Near(0, 1) = (2, 3)', faceChunkBytes([face(0, rank(0), rank(2))]), {}, /rank 2 beyond Near\(0, 1\)/],
    ['a rank in Up(3), which is empty', faceChunkBytes([face(3, rank(0), rank(0))]), {}, /rank 0 in Up\(3\) of 0/],
    ['a rank in Up(4) of an isolated vertex', faceChunkBytes([face(4, rank(0), rank(0))]), { n: 5 }, /Up\(4\) of 0/],
    ['a = 4 with n = 4', faceChunkBytes([face(4, raw(0), raw(1))]), {}, /vertex 4 beyond/],
    ['a huge gap', faceChunkBytes([face(2 ** 32 - 1, raw(0), raw(1))]), {}, /beyond/],
    ['raw b = 4', faceChunkBytes([face(0, raw(3), rank(0))]), {}, /vertex 4 beyond/],
    ['raw c = 5', faceChunkBytes([face(0, rank(0), raw(4))]), {}, /vertex 5 beyond/],
    ['b = c', faceChunkBytes([face(0, raw(1), raw(1))]), {}, /repeats a vertex/],
    ['b = c from Up(0) and raw', faceChunkBytes([face(0, rank(1), raw(1))]), {}, /repeats a vertex/],
    ['G = 3 over a step of 2', faceChunkBytes([], 3), {}, /3 coded faces, more than the 2/],
    ['G = 2^32 over a step of 2', faceChunkBytes([], 2 ** 32), {}, /more than the 2/],
    ['a reverse face past a step of 1', faceChunkBytes([face(0, rank(0), rank(1), 1)]), { step: 1 }, /more faces than the 1/],
    ['an entry whose count is below the mesh', faceChunkBytes([face(0, rank(0), rank(1))]), { step: -1 }, /more than the 0/],
    ['a step past the declared face count', faceChunkBytes([face(0, rank(0), rank(1), 1)]), { step: 2, capM: 5 }, /more faces than the 1/],
  ];
  for (const [what, bytes, options, pattern] of cases) formatError(() => tetrahedronChunk(bytes, options), pattern, what);
  const e = new RangeEncoder(FACE_PROBS);
  e.uint(32, 0, 40); // G with bucket 40
  formatError(() => tetrahedronChunk(e.finish()), /invalid bucket 40/, 'an invalid bucket');
  // the same decisions but valid: every refusal above is the case's own
  assert.deepEqual(tetrahedronChunk(faceChunkBytes([face(0, rank(2), rank(1)), face(1, raw(1), rank(0), 1)]), { step: 3 }),
    [0, 3, 2, 1, 3, 2, 1, 2, 3]);
});

test('Near(a, b) lists b\'s neighbours above a, then the rest of Up(a): ranks over an open fan', () => {
  const fan = [0, 1, 2, 0, 2, 3, 0, 3, 4]; // around 0: Up(0) = (1, 2, 3, 4), Up(1) = (2)
  const decode = (faces, step = 2) => {
    const { state, decoder } = meshDecoder(fan, 5);
    decoder.decodeChunk(faceChunkBytes(faces), { splits: 0, faceCount: 3 + step });
    return Array.from(state.faces.subarray(9, 3 * state.m));
  };
  // Near(0, 1) = (2 | 3, 4): b's neighbour 2, then Up(0) without 1 and 2
  for (const [r, c] of [[0, 2], [1, 3], [2, 4]]) {
    assert.deepEqual(decode([{ gap: 0, b: { rank: 0 }, c: { rank: r }, twin: 0 }], 1), [0, 1, c], `rank ${r}`);
  }
  formatError(() => decode([{ gap: 0, b: { rank: 0 }, c: { rank: 3 }, twin: 0 }], 1), /rank 3 beyond Near\(0, 1\)/, 'rank 3');
  // Near(1, 3) = (2, 4 |): 3's neighbours above 1 (4 is not in Up(1)), then nothing of Up(1) = (2)
  assert.deepEqual(decode([{ gap: 1, b: { raw: 1 }, c: { rank: 1 }, twin: 1 }]), [1, 3, 4, 1, 4, 3]);
  formatError(() => decode([{ gap: 1, b: { raw: 1 }, c: { rank: 2 }, twin: 0 }], 1), /rank 2 beyond Near\(1, 3\)/, 'rank 2');
  // Up(a) is kept for faces of the same a: two faces of a = 0, then a = 2 (Up(2) = (3))
  assert.deepEqual(decode([{ gap: 0, b: { rank: 3 }, c: { rank: 0 }, twin: 0 }, { gap: 0, b: { rank: 1 }, c: { raw: 3 }, twin: 0 },
    { gap: 2, b: { rank: 0 }, c: { rank: 0 }, twin: 0 }], 3), [0, 4, 3, 0, 2, 4, 2, 3, 4]);
});

/** Decodes `bytes` whole: the error thrown (a PmwError), or null. */
async function failure(bytes) {
  try {
    const d = new PmwDecoder();
    await d.feed(bytes);
    d.close();
    return null;
  } catch (e) {
    if (!(e instanceof PmwError)) throw e;
    return e;
  }
}

test('hostile face chunks in a file are FormatErrors of their chunk; a damaged face chunk is refused by both decoders or by neither', { skip }, async () => {
  const { bytes } = encodedCase('pillows-shared.draco');
  const chunks = chunkPayloads(bytes);
  const k = chunks.length - 1;
  const p = chunks[k].payload;
  const hostile = [p.subarray(0, p.length - 1), Uint8Array.of(...p, 0), chunks[k - 1].payload,
    faceChunkBytes([], 2 ** 20), faceChunkBytes([{ gap: 0, b: { rank: 50 }, c: { rank: 0 }, twin: 0 }]),
    faceChunkBytes([{ gap: 1e6, b: { raw: 0 }, c: { raw: 1 }, twin: 0 }])];
  for (const [i, payload] of hostile.entries()) {
    const e = await failure(withPayload(bytes, k, payload));
    assert.ok(e instanceof FormatError, `${i}: ${e}`);
    assert.match(e.message, new RegExp(`^chunk ${k}: `), `${i}`);
  }
  assert.equal(await failure(withPayload(bytes, k, p)), null, 'the rewrite itself keeps the file valid');
  const r = seededRandom(9);
  const files = [];
  const js = [];
  for (let i = 0; i < 60; i++) {
    const payload = p.slice();
    const span = i % 2 ? payload.length : 4; // anywhere, or in the coder's flush
    for (let f = 1 + Math.floor(r() * 2); f > 0; f--) payload[payload.length - 1 - Math.floor(r() * span)] ^= 1 << Math.floor(r() * 8);
    const file = join(dir, `flipped-${i}.pmw`);
    const damaged = withPayload(bytes, k, payload);
    writeFileSync(file, damaged);
    files.push(file);
    const e = await failure(damaged);
    js.push(e === null ? (await jsLevels(damaged)).levels : e);
  }
  let refused = 0;
  for (const [i, want] of decodeFiles(files).entries()) {
    if (want.error !== undefined) {
      refused++;
      assert.ok(js[i] instanceof FormatError, `${files[i]}: Python refuses it (${want.error}), JS: ${js[i]}`);
    } else {
      assert.ok(!(js[i] instanceof PmwError), `${files[i]}: Python decodes it, JS refuses it (${js[i]?.message})`);
      assert.deepEqual(js[i], want.levels, files[i]);
    }
  }
  assert.ok(refused > 0 && refused < files.length, `${refused} of ${files.length} refused: both outcomes compared`);
});
