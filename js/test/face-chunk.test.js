/**
 * Face chunks of chunk payload version 2 (spec/bitstream.md §8.6): the chunks of a primitive from
 * its extension's `firstFaceChunk` on append faces, and new vertices only those faces name (fresh, with values predicted
 * from their earlier corners), under a probability table of their own.
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
 * - New vertices (flaps): numbered n, n+1, ... as the faces name them, ranked in Near(a, b) when b
 *   is new (Near = Up(a)), their values floor(S / c) over the earlier corners of the faces naming
 *   them (a reverse face counted again; a new vertex before u counted with its decoded values) plus
 *   a residual under block 5 + min(q, 3), for every value column (attributes too); in a whole file
 *   they reach the snapshot's positions and counts.
 * - `firstFaceChunk` is read from the extension: which chunks are face chunks (entry.faces; none
 *   when absent, none either when past the last chunk, as in a cut file), and a FormatError when
 *   negative, not an integer, above 65536, or present with payload 1.
 * - Hostile face chunks end in a FormatError saying what is wrong, before any write out of
 *   bounds: cut short or too long, a rank beyond Up(a) or Near(a, b), a vertex at or beyond n,
 *   a face repeating a vertex, more faces than the entry adds (G, or a reverse face past it), an
 *   invalid bucket, more or fewer new vertices than the entry adds or than the declared count, a
 *   value with |x| >= 2^31; in whole files too, where the JS and Python decoders refuse the same
 *   damaged face chunks and agree on the others.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, test } from 'node:test';
import { NodeIO } from '@gltf-transform/core';
import { PMWMProgressiveMesh } from 'pmwm-progressive/gltf-transform';
import { FormatError, PmwDecoder, PmwError } from '../src/index.js';
import { chunkEntries, parseGlb, planDocument } from '../src/header.js';
import { ChunkDecoderV2, FACE_PROBS } from '../src/payload-v2.js';
import { MeshState } from '../src/vsplit.js';
import { CONFORMANCE, conformanceFiles, failure, jsLevels, levelDigest, seededRandom } from './lib/helpers.js';
import { TREE, decodeFiles, encodeCase, faceChunks, pythonHasPayloadV2 } from './lib/python.js';
import { FACE_TABLE, RangeEncoder, faceChunkBytes } from './lib/rangeencoder.js';
import { chunkPayloads, setTableCounts, withJson, withPayload } from './lib/rewrite.js';

const skip = !pythonHasPayloadV2() && 'no Python importing a pmwm_codec that writes payload version 2 ($PYTHON, $PMW_PYTHONPATH)';
const PILLOWS = ['pillows.plain', 'pillows-shared.draco', 'flaps.plain', 'flaps-shared.draco', 'flaps-attributes.plain'];
const FLAPS = PILLOWS.filter((name) => name.startsWith('flaps'));
const dir = mkdtempSync(join(tmpdir(), 'pmw-faces-'));
after(() => rmSync(dir, { recursive: true, force: true }));

const TETRAHEDRON = [0, 1, 2, 0, 2, 3, 0, 3, 1, 1, 3, 2];
/** The spec's example: G = 1, gap 0, b by rank 0 in Up(0), c by rank 1 in Near(0, 1), twin. */
const EXAMPLE = [{ gap: 0, b: { rank: 0 }, c: { rank: 1 }, twin: 1 }];
const hex = (bytes) => Buffer.from(bytes).toString('hex');

/**
 * A primitive's decoder over the mesh (faces flat, n vertices of D values, zero unless `values`),
 * room for capN vertices and capM faces.
 */
function meshDecoder(faces, n, { capM = faces.length / 3 + 16, capN = n + 8, D = 3, values = new Int32Array(D * n) } = {}) {
  const state = new MeshState(Int32Array.from(values), Uint32Array.from(faces), n, faces.length / 3, D, capN, capM);
  return { state, decoder: new ChunkDecoderV2(state) };
}

/** A face chunk's normalised entry (header.js) after a mesh of n vertices and m faces: t new vertices, s faces. */
const faceEntry = (n, m, t, s) => ({ faces: true, splits: t, vertexCount: n + t, faceCount: m + s });

/**
 * Decodes `bytes` as a face chunk over the tetrahedron (n vertices: 4, or more as isolated ones;
 * `fresh` new vertices, `step` faces); returns the appended faces.
 */
function tetrahedronChunk(bytes, { n = 4, step = 2, fresh = 0, capM, capN, values } = {}) {
  const { state, decoder } = meshDecoder(TETRAHEDRON, n, { capM, capN, values });
  decoder.decodeChunk(bytes, faceEntry(n, 4, fresh, step));
  return Array.from(state.faces.subarray(12, 3 * state.m));
}

test('the spec\'s example: a face chunk over the tetrahedron appends (0,1,3) and (0,3,1)', () => {
  const bytes = faceChunkBytes(EXAMPLE);
  assert.deepEqual(tetrahedronChunk(bytes), [0, 1, 3, 0, 3, 1]);
  const { state, decoder } = meshDecoder(TETRAHEDRON, 4);
  const table = decoder.probs.slice();
  decoder.decodeChunk(bytes, faceEntry(4, 4, 0, 2));
  assert.deepEqual(decoder.probs, table, 'the primitive\'s split table is neither read nor changed');
  assert.equal(state.n, 4);
  assert.equal(FACE_PROBS, 32 + 9 * 256);
  assert.equal(FACE_TABLE, FACE_PROBS);
});

test('the spec\'s example bytes (spec/bitstream.md <!-- face-chunk-example -->) are those decisions and decode to its faces', () => {
  const printed = specBytes('face-chunk-example');
  assert.equal(printed, hex(faceChunkBytes(EXAMPLE)));
  assert.deepEqual(tetrahedronChunk(Uint8Array.from(Buffer.from(printed, 'hex'))), [0, 1, 3, 0, 3, 1]);
});

test('the spec\'s examples from the reference encoder: the same bytes, the same faces and new vertex', { skip }, () => {
  const { chunk, flap } = faceChunks('tetrahedron');
  assert.equal(chunk, hex(faceChunkBytes(EXAMPLE)));
  assert.deepEqual(tetrahedronChunk(Uint8Array.from(Buffer.from(chunk, 'hex'))), [0, 1, 3, 0, 3, 1]);
  assert.equal(flap, hex(faceChunkBytes([{ gap: 0, b: { rank: 0 }, c: { fresh: true }, twin: 1 }], 1, [[-8, -16, -24]])));
  const { state, decoder } = meshDecoder(TETRAHEDRON, 4, { values: [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110] });
  decoder.decodeChunk(Uint8Array.from(Buffer.from(flap, 'hex')), faceEntry(4, 4, 1, 2));
  assert.deepEqual(Array.from(state.values.subarray(12, 15)), [7, 9, 11]);
});

test('a conformance file ends in a face chunk that adds vertices (conformance.test.js checks its levels, fuzz.test.js damages it)', () => {
  const files = conformanceFiles(2).filter((f) => /pillows/.test(f));
  assert.ok(files.length > 0, 'spec/conformance has a *pillows*.v2.pmw');
  for (const f of files) {
    const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, f)));
    const stream = entries(bytes);
    const h = parseGlb(bytes);
    const ext = h.gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
    assert.equal(ext.firstFaceChunk, stream.length - 1, `${f}: firstFaceChunk`);
    assert.deepEqual(stream.map((c) => c.faces), stream.map((_, k) => k === stream.length - 1), `${f}: its last chunk is a face chunk`);
    assert.ok(stream[stream.length - 1].splits > 0, `${f}: its face chunk adds vertices (flaps)`);
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


/** The (first) progressive primitive's extension object. */
const extensionOf = (bytes) => parseGlb(bytes).gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;

/** The stream's chunk entries (splits, vertexCount, faceCount, faces) in order. */
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
  test(`${name}: pillows (and flaps' tips) come in a face chunk that decodes to the Python decoder's level at every chunk boundary`, { skip }, async () => {
    const { bytes, want } = encodedCase(name);
    const stream = entries(bytes);
    const last = stream[stream.length - 1];
    const before = stream[stream.length - 2];
    assert.equal(extensionOf(bytes).firstFaceChunk, stream.length - 1);
    assert.ok(last.faces, 'the last chunk is a face chunk');
    assert.ok(stream.slice(0, -1).every((c) => !c.faces && c.splits > 0), 'every other chunk splits');
    if (FLAPS.includes(name)) assert.ok(last.splits > 0, `the face chunk adds the flaps' tips (${last.splits})`);
    else assert.equal(last.vertexCount, before.vertexCount, 'glued pillows only: no new vertex');
    const { levels, end, last: mesh } = await jsLevels(bytes);
    assert.deepEqual(levels, want.levels); // positions, faces and quantized attributes (sha256), counts, bytes read
    assert.equal(end.complete, true);
    const added = last.faceCount - before.faceCount;
    assert.ok(added >= 8, `${added} faces in the face chunk`);
    const appended = mesh.indices.subarray(3 * before.faceCount);
    assert.equal(twinFaces(appended), added, 'the face chunk appends pillows');
    const named = new Set(Array.from(appended).filter((x) => x >= before.vertexCount));
    assert.equal(named.size, last.splits, 'its faces name every new vertex');
    assert.ok(Array.from(mesh.indices.subarray(0, 3 * before.faceCount)).every((x) => x < before.vertexCount),
      'no face before it names a new vertex');
  });
}

test('specks.draco: specks come in the face chunk as faces of new vertices only, each new part predicted from the vertex before it; the Python decoder\'s levels', { skip }, async () => {
  const { bytes, want } = encodedCase('specks.draco');
  const stream = entries(bytes);
  const last = stream[stream.length - 1];
  const before = stream[stream.length - 2];
  assert.ok(last.faces, 'the last chunk is a face chunk');
  assert.equal(last.splits, 9, 'three specks of three new vertices');
  assert.equal(last.faceCount - before.faceCount, 4, 'two lone faces and a face with its reverse');
  const { levels, end, last: mesh } = await jsLevels(bytes);
  assert.deepEqual(levels, want.levels);
  assert.equal(end.complete, true);
  const appended = Array.from(mesh.indices.subarray(3 * before.faceCount));
  assert.ok(appended.every((x) => x >= before.vertexCount), 'every appended face names new vertices only');
});

for (const name of ['pillows.plain', 'flaps.plain']) {
  test(`${name}: read + write through glTF-Transform keeps firstFaceChunk and the face chunk's entry, the same levels`, { skip }, async () => {
    const { bytes, want } = encodedCase(name);
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    const rewritten = await io.writeBinary(await io.readBinary(bytes));
    assert.equal(extensionOf(rewritten).firstFaceChunk, entries(bytes).length - 1);
    assert.deepEqual(entries(rewritten).map((c) => [c.faces, c.splits, c.vertexCount, c.faceCount]),
      entries(bytes).map((c) => [c.faces, c.splits, c.vertexCount, c.faceCount]));
    const strip = (levels) => levels.map(({ bytesRead, ...level }) => level);
    assert.deepEqual(strip((await jsLevels(rewritten)).levels), strip(want.levels));
  });
}

test('every prefix of a file ending in a face chunk with new vertices gives the levels of its whole chunks', { skip }, async () => {
  const { bytes, want } = encodedCase('flaps.plain');
  const from = want.levels[want.levels.length - 2].bytesRead;
  for (let cut = from - 1; cut <= bytes.length; cut++) {
    const d = new PmwDecoder();
    const shown = (await d.feed(bytes.subarray(0, cut))).map((r) => r.bytesRead);
    assert.deepEqual(shown, want.levels.filter((l) => l.bytesRead <= cut).map((l) => l.bytesRead), `cut ${cut}`);
    assert.equal((await d.close()).complete, cut === bytes.length);
    assert.equal(levelDigest(d.snapshot()), want.levels[shown.length - 1].sha256, `cut ${cut}`);
  }
});

test('face chunks between chunks that split: each chunk gives the reference decoder\'s mesh', { skip }, () => {
  const { D, capN, capM, base, chunks } = faceChunks('sequence');
  assert.ok(chunks.some((c, k) => c.face && c.splits > 0 && chunks[k + 1]?.face === false), 'a split chunk follows a face chunk with new vertices');
  assert.ok(chunks.some((c, k) => c.face && chunks[k + 1]?.face), 'two face chunks in a row');
  const values = Int32Array.from(base.values);
  const faces = Uint32Array.from(base.faces);
  const state = new MeshState(values, faces, values.length / D, faces.length / 3, D, capN, capM);
  const decoder = new ChunkDecoderV2(state);
  for (const [k, c] of chunks.entries()) {
    const table = decoder.probs.slice();
    decoder.decodeChunk(Uint8Array.from(Buffer.from(c.chunk, 'hex')), { faces: c.face, vertexCount: c.vertexCount, faceCount: c.faceCount });
    if (c.face) assert.deepEqual(decoder.probs, table, `chunk ${k}: the split table is untouched`);
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
    ['a = 4 with n = 4: a new first vertex the entry does not add', faceChunkBytes([face(4, raw(0), raw(1))]), {}, /more new vertices than the 0/],
    ['a = 5 with n = 4: past the next new vertex', faceChunkBytes([face(5, raw(0), raw(1))]), {}, /vertex 5 beyond/],
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

/** Values of the tetrahedron's vertices 0..3 (D = 3) for the tests of new vertices. */
const TETRA_VALUES = [10, 0, -7, 3, 5, -2, 1, 1, 1, -4, 8, 6];
const rank = (r) => ({ rank: r });
const raw = (r) => ({ raw: r });
const FRESH = { fresh: true };
const face = (gap, b, c, twin = 0) => ({ gap, b, c, twin });

/**
 * Decodes a face chunk over the tetrahedron (values TETRA_VALUES unless given, D columns); returns
 * {faces: the appended faces, values: the new vertices' values, n, m}.
 */
function flapChunk(bytes, { fresh, step, D = 3, values = TETRA_VALUES, capN } = {}) {
  const { state, decoder } = meshDecoder(TETRAHEDRON, 4, { D, values, capN, capM: 4 + step });
  decoder.decodeChunk(bytes, faceEntry(4, 4, fresh, step));
  return {
    faces: Array.from(state.faces.subarray(12, 3 * state.m)),
    values: Array.from(state.values.subarray(4 * D, state.n * D)), n: state.n, m: state.m,
  };
}

test('new vertices of a face chunk: numbered as the faces name them, valued floor(S / c) + residual over their earlier corners', () => {
  // (0,1,4)+(0,4,1): b rank 0 in Up(0), c fresh; (0,5,3): b fresh, c rank 2 in Near(0, 5) = Up(0) = (1, 2, 3);
  // (1,6,7)+(1,7,6): both fresh, so 7 is predicted from 1 and the new vertex 6
  const faces = [face(0, rank(0), FRESH, 1), face(0, FRESH, rank(2)), face(1, FRESH, FRESH, 1)];
  const residuals = [[1, -1, 0], [0, 0, 0], [-3, 2, 1], [0, 0, 5]];
  const got = flapChunk(faceChunkBytes(faces, 3, residuals), { fresh: 4, step: 5 });
  assert.deepEqual(got.faces, [0, 1, 4, 0, 4, 1, 0, 5, 3, 1, 6, 7, 1, 7, 6]);
  assert.deepEqual([got.n, got.m], [8, 9]);
  assert.deepEqual(got.values, [
    7, 1, -5, // u = 4: corners 0, 1 of two faces, c = 4: floor((26, 10, -18) / 4) = (6, 2, -5), + (1, -1, 0)
    3, 4, -1, // u = 5: corners 0, 3, c = 2: floor((6, 8, -1) / 2) = (3, 4, -1)
    0, 7, -1, // u = 6: corner 1 of two faces (7 comes after 6), c = 2: (3, 5, -2), + (-3, 2, 1)
    1, 6, 3, // u = 7: corners 1 and 6 of two faces, c = 4: floor((6, 24, -6) / 4) = (1, 6, -2), + (0, 0, 5)
  ]);
  // the same faces with the residuals of another vertex order: the values follow the numbering, not the coding
  const swapped = flapChunk(faceChunkBytes(faces, 3, [residuals[1], residuals[0], residuals[2], residuals[3]]), { fresh: 4, step: 5 });
  assert.deepEqual(swapped.values.slice(0, 6), [6, 2, -5, 4, 3, -1]);
});

const VALUES6 = Array.from({ length: 24 }, (_, i) => (Math.floor(i / 6) + 1) * (i % 2 ? -3 : 5) + (i % 6));

test('a new vertex named again by a raw id (it is already named): every face naming it counts in its prediction', () => {
  // (0,1,4)+(0,4,1), then (1,4,5): 4 is coded raw (1 + 1 + 2), 5 fresh
  const residuals = [[0, 0, 0], [2, -2, 0]];
  const got = flapChunk(faceChunkBytes([face(0, rank(0), FRESH, 1), face(1, raw(2), FRESH)], 2, residuals), { fresh: 2, step: 3 });
  assert.deepEqual(got.faces, [0, 1, 4, 0, 4, 1, 1, 4, 5]);
  // u = 4: corners 0, 1, 0, 1 and 1 of (1,4,5) (5 comes after): c = 5, floor((29, 15, -20) / 5) = (5, 3, -4)
  // u = 5: corners 1 and 4: c = 2, floor((8, 8, -6) / 2) = (4, 4, -3), + (2, -2, 0)
  assert.deepEqual(got.values, [5, 3, -4, 6, 2, -3]);
});

/** The spec's example bytes printed after <!-- `marker` --> in spec/bitstream.md. */
function specBytes(marker) {
  const text = readFileSync(join(TREE, 'spec', 'bitstream.md'), 'utf8');
  const block = text.split(`<!-- ${marker} -->`)[1]?.match(/```\n([^`]*)```/);
  assert.ok(block, `the spec prints the bytes of ${marker}`);
  return block[1].replace(/\s+/g, '');
}

test('the spec\'s flap example: bytes, decisions and the new vertex (7, 9, 11)', () => {
  const values = [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110];
  const bytes = faceChunkBytes([face(0, rank(0), FRESH, 1)], 1, [[-8, -16, -24]]);
  assert.equal(specBytes('face-chunk-flap-example'), hex(bytes));
  const got = flapChunk(Uint8Array.from(Buffer.from(specBytes('face-chunk-flap-example'), 'hex')), { fresh: 1, step: 2, values });
  assert.deepEqual(got.faces, [0, 1, 4, 0, 4, 1]);
  assert.deepEqual(got.values, [7, 9, 11]);
});

test('the spec\'s speck example: a face of new vertices only, its first vertex predicted by the vertex before it', () => {
  const values = [0, 10, 20, 30, 40, 50, 60, 70, 80, 90, 100, 110];
  const bytes = faceChunkBytes([face(4, FRESH, FRESH)], 1, [[1, 1, 1], [0, 0, 0], [1, 0, 0]]);
  assert.equal(specBytes('face-chunk-speck-example'), hex(bytes));
  const got = flapChunk(Uint8Array.from(Buffer.from(specBytes('face-chunk-speck-example'), 'hex')), { fresh: 3, step: 1, values });
  assert.deepEqual(got.faces, [4, 5, 6]);
  assert.deepEqual(got.values, [91, 101, 111, 91, 101, 111, 92, 101, 111]);
  // a second part of new vertices: its first vertex is predicted by the last of the first part
  const two = faceChunkBytes([face(4, FRESH, FRESH), face(3, FRESH, FRESH)], 2, [[1, 1, 1], [0, 0, 0], [1, 0, 0], [-2, 0, 0], [0, 0, 0], [0, 0, 0]]);
  const parts = flapChunk(two, { fresh: 6, step: 2, values });
  assert.deepEqual(parts.faces, [4, 5, 6, 7, 8, 9]);
  assert.deepEqual(parts.values.slice(9), [90, 101, 111, 90, 101, 111, 90, 101, 111]);
});

test('new vertices\' attributes: every value column, residual q under block 5 + min(q, 3)', () => {
  const D = 6; // x, y, z, then three attribute columns (all under block 8)
  const values = VALUES6;
  const faces = [face(0, rank(0), FRESH, 1), face(1, FRESH, rank(1), 1), face(0, raw(2), FRESH)];
  const residuals = [[1, 2, 3, 4, 5, 6], [-1, 0, 7, -8, 0, 9], [30, -2, 0, 0, 1, 100]];
  const bytes = faceChunkBytes([faces[0], faces[2], faces[1]], 3, residuals);
  const got = flapChunk(bytes, { D, values, fresh: 3, step: 5 });
  assert.deepEqual(got.faces, [0, 1, 4, 0, 4, 1, 0, 3, 5, 1, 6, 3, 1, 3, 6]);
  const want = [];
  const at = (v, q) => (v < 4 ? values[v * D + q] : want[(v - 4) * D + q]);
  for (const [u, corners] of [[4, [0, 1, 0, 1]], [5, [0, 3]], [6, [1, 3, 1, 3]]]) {
    for (let q = 0; q < D; q++) {
      const S = corners.reduce((sum, p) => sum + at(p, q), 0);
      want.push(Math.floor(S / corners.length) + residuals[u - 4][q]);
    }
  }
  assert.deepEqual(got.values, want);
  // coded under other blocks, the same residuals no longer decode to them (or not at all): the decoder
  // reads block 5 + min(q, 3), not one block for all columns, nor block 5 + q
  for (const [what, valueBlock] of [['block 5 + q', (q) => 5 + q], ['one block', () => 5], ['blocks 5..7 only', (q) => 5 + Math.min(q, 2)]]) {
    const wrong = faceChunkBytes([faces[0], faces[2], faces[1]], 3, residuals, valueBlock);
    let values = null;
    try {
      values = flapChunk(wrong, { D, values: VALUES6, fresh: 3, step: 5 }).values;
    } catch (err) {
      assert.ok(err instanceof FormatError, String(err));
    }
    assert.notDeepEqual(values, want, what);
  }
});

test('hostile new vertices: more or fewer than the entry adds or the mesh may hold, raw ids past n, values out of range', () => {
  const flap = [face(0, rank(0), FRESH, 1)];
  const big = 2 ** 31 - 1;
  const cases = [
    ['a fresh vertex with t = 0', faceChunkBytes(flap, 1, [[0, 0, 0]]), { fresh: 0, step: 2 }, /more new vertices than the 0/],
    ['two fresh vertices with t = 1', faceChunkBytes([face(0, FRESH, FRESH, 1)], 1, [[0, 0, 0], [0, 0, 0]]), { fresh: 1, step: 2 }, /more new vertices than the 1/],
    ['one fresh vertex with t = 2', faceChunkBytes(flap, 1, [[0, 0, 0]]), { fresh: 2, step: 2 }, /1 new vertices, fewer than the 2/],
    ['no fresh vertex with t = 1', faceChunkBytes(EXAMPLE), { fresh: 1, step: 2 }, /0 new vertices, fewer than the 1/],
    ['an entry with fewer vertices than the mesh', faceChunkBytes(EXAMPLE), { fresh: -1, step: 2 }, /fewer than the mesh's 4/],
    ['t = 1 past the declared vertex count', faceChunkBytes(flap, 1, [[0, 0, 0]]), { fresh: 1, step: 2, capN: 4 }, /more new vertices than the 0/],
    ['a raw id of a new vertex not yet named', faceChunkBytes([face(3, raw(0), FRESH)], 1, [[0, 0, 0]]), { fresh: 1, step: 1 }, /vertex 4 beyond the mesh's 4 and the 0 new/],
    ['a raw id past the new vertices named', faceChunkBytes([face(0, rank(0), FRESH, 1), face(1, raw(3), FRESH)], 2, [[0, 0, 0], [0, 0, 0]]),
      { fresh: 2, step: 3 }, /vertex 5 beyond the mesh's 4 and the 1 new/],
    ['rank 3 in Near(0, 4) = Up(0) = (1, 2, 3), 4 new', faceChunkBytes([face(0, FRESH, rank(3))], 1, [[0, 0, 0]]), { fresh: 1, step: 1 }, /rank 3 beyond Near\(0, 4\)/],
    ['the residuals missing', faceChunkBytes(flap), { fresh: 1, step: 2 }, /does not end at the end/],
    ['x = 2^31', faceChunkBytes(flap, 1, [[1, 0, 0]]), { fresh: 1, step: 2, values: [big, 0, 0, big, 0, 0, 0, 0, 0, 0, 0, 0] }, /out of range/],
    ['x = -2^31', faceChunkBytes(flap, 1, [[0, 0, -1]]), { fresh: 1, step: 2, values: [0, 0, -big, 0, 0, -big, 0, 0, 0, 0, 0, 0] }, /out of range/],
    ['a residual of 2^32 - 1', faceChunkBytes(flap, 1, [[0, 2 ** 32 - 1, 0]]), { fresh: 1, step: 2 }, /out of range/],
  ];
  for (const [what, bytes, options, pattern] of cases) formatError(() => flapChunk(bytes, options), pattern, what);
  // the boundaries themselves are valid: 2^31 - 1 and -(2^31 - 1)
  assert.deepEqual(flapChunk(faceChunkBytes(flap, 1, [[0, 0, 0]]), { fresh: 1, step: 2, values: [big, 0, -big, big, 0, -big, 0, 0, 0, 0, 0, 0] }).values,
    [big, 0, -big]);
  assert.deepEqual(flapChunk(faceChunkBytes(flap, 1, [[-big, big, 0]]), { fresh: 1, step: 2, values: TETRA_VALUES.map(() => 0) }).values,
    [-big, big, 0]);
});

test('a new vertex\'s prediction is floor(S / c) of the exact integer sum, also past 2^53 (a hostile valence)', () => {
  // 2^20 + 2^10 coded faces (0, 1, 4) + (0, 4, 1), repeats valid: c = 4G corners, all of value v, S = 4G v > 2^53
  const G = 2 ** 20 + 2 ** 10;
  const v = 2 ** 31 - 3;
  const faces = [face(0, rank(0), FRESH, 1)];
  for (let i = 1; i < G; i++) faces.push(face(0, rank(0), raw(3), 1));
  let float = 0;
  for (let i = 0; i < 4 * G; i++) float += v;
  assert.ok(float >= 2 ** 53 && Math.floor(float / (4 * G)) === v - 1, 'a float64 sum would predict v - 1');
  const got = flapChunk(faceChunkBytes(faces, G, [[0, 1, -1]]), { fresh: 1, step: 2 * G, values: Array(12).fill(v), capN: 5 });
  assert.equal(got.m, 4 + 2 * G);
  assert.deepEqual(got.values, [v, v + 1, v - 1]);
});

/** The bytes of conformance file `name`. */
const conformance = (name) => new Uint8Array(readFileSync(join(CONFORMANCE, name)));
/** `bytes` with the first progressive primitive's extension given the fields of `patch` (undefined deletes). */
const withExtension = (bytes, patch) => withJson(bytes, (gltf) => {
  const ext = gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
  for (const [key, value] of Object.entries(patch)) {
    if (value === undefined) delete ext[key];
    else ext[key] = value;
  }
});

test('firstFaceChunk marks the chunks from it on as face chunks; invalid values are FormatErrors wherever the extension is read', async () => {
  const v2 = conformance('grid-hole.plain.packed.v2.pmw');
  const K = entries(v2).length;
  const faces = (bytes) => entries(bytes).map((c) => c.faces);
  assert.deepEqual(faces(v2), Array(K).fill(false), 'absent: no face chunk');
  assert.deepEqual(faces(withExtension(v2, { firstFaceChunk: K - 2 })), Array.from({ length: K }, (_, k) => k >= K - 2));
  assert.deepEqual(faces(withExtension(v2, { firstFaceChunk: 0 })), Array(K).fill(true));
  assert.deepEqual(faces(withExtension(v2, { firstFaceChunk: K })), Array(K).fill(false), 'past the last chunk (a cut file): none');
  assert.deepEqual(faces(withExtension(v2, { firstFaceChunk: 65536 })), Array(K).fill(false));
  // the array form of the table too (chunkEntries directly)
  const arrays = parseGlb(conformance('grid-hole.plain.v2.pmw')).gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
  const count = arrays.chunks.byteLengths.length;
  assert.deepEqual(chunkEntries({ ...arrays, firstFaceChunk: count - 1 }, 2, 0).map((e) => e.faces).slice(-2), [false, true]);
  const v1 = conformance('grid-hole.plain.v1.pmw');
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const hostile = [
    [v2, -1, /firstFaceChunk is not an integer in 0\.\.65536/],
    [v2, 1.5, /firstFaceChunk is not an integer/],
    [v2, '1', /firstFaceChunk is not an integer/],
    [v2, true, /firstFaceChunk is not an integer/],
    [v2, null, /firstFaceChunk is not an integer/],
    [v2, 65537, /firstFaceChunk is not an integer/],
    [v1, 1, /firstFaceChunk needs chunk payload version 2/],
    [v1, 0, /firstFaceChunk needs chunk payload version 2/],
  ];
  for (const [file, value, pattern] of hostile) {
    const bytes = withExtension(file, { firstFaceChunk: value });
    const what = `firstFaceChunk ${JSON.stringify(value)}`;
    formatError(() => entries(bytes), pattern, `${what}: planDocument`);
    const e = await failure(bytes);
    assert.ok(e instanceof FormatError && pattern.test(e.message), `${what}: PmwDecoder: ${e}`);
    await assert.rejects(io.readBinary(bytes), (err) => err instanceof FormatError && pattern.test(err.message), `${what}: glTF-Transform`);
  }
});

test('a whole file whose last chunk is a face chunk with new vertices: they reach the snapshot with their attributes', async () => {
  const bytes = conformance('sphere-attributes.plain.packed.v2.pmw');
  const stream = entries(bytes);
  const K = stream.length;
  const prefix = new PmwDecoder({ maxChunks: K - 1 });
  await prefix.feed(bytes);
  const before = prefix.snapshot();
  const n = stream[K - 2].vertexCount;
  const m = stream[K - 2].faceCount;
  const a = before.parts[0].attributesInt.length / n;
  const D = 3 + a;
  const value = (v, q) => (q < 3 ? before.positionsInt[3 * v + q] : before.parts[0].attributesInt[a * v + q - 3]);
  let b = Infinity; // Up(0)[0]: the smallest neighbour of vertex 0
  for (let f = 0; f < before.indices.length; f += 3) {
    const tri = Array.from(before.indices.subarray(f, f + 3));
    if (tri.includes(0)) for (const x of tri) if (x > 0) b = Math.min(b, x);
  }
  // (0, b, n) + (0, n, b), then (0, n+1, n+2) + (0, n+2, n+1)
  const residuals = Array.from({ length: 3 }, (_, i) => Array.from({ length: D }, (_, q) => ((i + 1) * (q + 2)) % 7 - 3));
  const payload = faceChunkBytes([face(0, rank(0), FRESH, 1), face(0, FRESH, FRESH, 1)], 2, residuals);
  const patched = withJson(withPayload(bytes, K - 1, payload), (gltf) => {
    const ext = gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
    ext.firstFaceChunk = K - 1;
    ext.vertexCount = n + 3;
    ext.faceCount = m + 4;
    setTableCounts(ext.chunks, K - 1, n + 3, m + 4);
  });
  assert.deepEqual(entries(patched).slice(-2).map((c) => [c.faces, c.splits]), [[false, stream[K - 2].splits], [true, 3]]);
  const d = new PmwDecoder({ snapshots: true });
  const levels = await d.feed(patched);
  assert.equal((await d.close()).complete, true);
  const mesh = levels[levels.length - 1].mesh;
  assert.deepEqual([levels[levels.length - 1].vertexCount, levels[levels.length - 1].faceCount], [n + 3, m + 4]);
  assert.deepEqual(Array.from(mesh.indices.subarray(0, 3 * m)), Array.from(before.indices));
  assert.deepEqual(Array.from(mesh.indices.subarray(3 * m)), [0, b, n, 0, n, b, 0, n + 1, n + 2, 0, n + 2, n + 1]);
  const want = [];
  const at = (v, q) => (v < n ? value(v, q) : want[(v - n) * D + q]);
  for (const [i, corners] of [[0, [0, b, 0, b]], [1, [0, 0]], [2, [0, n + 1, 0, n + 1]]]) {
    for (let q = 0; q < D; q++) want.push(Math.floor(corners.reduce((sum, p) => sum + at(p, q), 0) / corners.length) + residuals[i][q]);
  }
  const got = [];
  for (let v = n; v < n + 3; v++) {
    for (let q = 0; q < D; q++) got.push(q < 3 ? mesh.positionsInt[3 * v + q] : mesh.parts[0].attributesInt[a * v + q - 3]);
  }
  assert.deepEqual(got, want);
  assert.ok(a > 0 && Object.values(mesh.parts[0].attributes).every((x) => x.length % (n + 3) === 0), 'attributes dequantized for every vertex');
});

test('Near(a, b) lists b\'s neighbours above a, then the rest of Up(a): ranks over an open fan', () => {
  const fan = [0, 1, 2, 0, 2, 3, 0, 3, 4]; // around 0: Up(0) = (1, 2, 3, 4), Up(1) = (2)
  const decode = (faces, step = 2) => {
    const { state, decoder } = meshDecoder(fan, 5);
    decoder.decodeChunk(faceChunkBytes(faces), faceEntry(5, 3, 0, step));
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

test('hostile face chunks in a file are FormatErrors of their chunk; a damaged face chunk is refused by both decoders or by neither', { skip }, async () => {
  const { bytes } = encodedCase('flaps-shared.draco');
  const chunks = chunkPayloads(bytes);
  const k = chunks.length - 1;
  const p = chunks[k].payload;
  const hostile = [p.subarray(0, p.length - 1), Uint8Array.of(...p, 0), chunks[k - 1].payload,
    faceChunkBytes([], 2 ** 20), faceChunkBytes([{ gap: 0, b: { rank: 50 }, c: { rank: 0 }, twin: 0 }]),
    faceChunkBytes([{ gap: 1e6, b: { raw: 0 }, c: { raw: 1 }, twin: 0 }])];
  for (const [i, payload] of hostile.entries()) {
    const e = await failure(withPayload(bytes, k, payload));
    assert.ok(e instanceof FormatError, `${i}: ${e}`);
    assert.match(e.message, new RegExp(`^chunk ${k + 1}: `), `${i}`);
  }
  assert.equal(await failure(withPayload(bytes, k, p)), null, 'the rewrite itself keeps the file valid');
  // the right bytes under a wrong firstFaceChunk or a wrong vertex count: refused by both decoders
  const ext = (gltf) => gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
  const { vertexCount, faceCount } = entries(bytes)[k];
  const wrong = {
    'firstFaceChunk absent': withExtension(bytes, { firstFaceChunk: undefined }),
    'firstFaceChunk past the face chunk': withExtension(bytes, { firstFaceChunk: k + 1 }),
    'firstFaceChunk on the last split chunk': withExtension(bytes, { firstFaceChunk: k - 1 }),
    'one more new vertex': withJson(bytes, (gltf) => {
      ext(gltf).vertexCount = vertexCount + 1;
      setTableCounts(ext(gltf).chunks, k, vertexCount + 1, faceCount);
    }),
    'one new vertex fewer': withJson(bytes, (gltf) => {
      ext(gltf).vertexCount = vertexCount - 1;
      setTableCounts(ext(gltf).chunks, k, vertexCount - 1, faceCount);
    }),
  };
  const wrongFiles = Object.entries(wrong).map(([what, damaged]) => {
    const file = join(dir, `${what.replace(/\W+/g, '-')}.pmw`);
    writeFileSync(file, damaged);
    return file;
  });
  const python = decodeFiles(wrongFiles);
  for (const [i, [what, damaged]] of Object.entries(wrong).entries()) {
    const e = await failure(damaged);
    assert.ok(e instanceof FormatError, `${what}: JS ${e}`);
    assert.ok(python[i].error !== undefined, `${what}: Python decodes it`);
  }
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
