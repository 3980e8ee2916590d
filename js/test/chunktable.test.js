/**
 * The packed chunk table (spec/bitstream.md §6.2): the spec's worked example reads back to its values
 * and packs to its bytes, a packed conformance file and its array-form twin give entries of the same
 * shape, and every malformation is a one-line FormatError before anything sized by it is allocated.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { packChunkTable, unpackChunkTable } from '../src/chunktable.js';
import { chunkEntries, parseGlb } from '../src/header.js';
import { FormatError } from '../src/errors.js';
import { CONFORMANCE } from './lib/helpers.js';
import { TREE } from './lib/python.js';

const spec = readFileSync(join(TREE, 'spec', 'bitstream.md'), 'utf8');
const example = spec.slice(spec.indexOf('*Worked example* (two chunks, no MACs'));
const table = JSON.parse(/the table is `(\{.*?\})`/.exec(example)[1].replace('…', '3'));
const entriesOf = (c) => c.byteLength.map((byteLength, k) => ({
  byteLength, vertexCount: c.vertexCount[k], faceCount: c.faceCount[k], geometricError: c.geometricError[k],
  digest: c.digest[k], ...(c.mac ? { mac: c.mac[k] } : {}),
}));

test('the worked example of bitstream.md §6.2 unpacks to its values and packs back to its text', () => {
  const c = unpackChunkTable(table.count, table.packed);
  assert.deepEqual(c.byteLength, [300, 129]);
  assert.deepEqual(c.vertexCount, [120, 250]);
  assert.deepEqual(c.faceCount, [236, 496]);
  assert.deepEqual(c.geometricError, [Math.fround(0.0125), 0]);
  assert.ok(example.includes(String(Math.fround(0.0125))), 'the spec quotes the float32 widened to a double');
  assert.deepEqual(c.digest, ['0123456789abcdef', 'fedcba9876543210']);
  assert.deepEqual(packChunkTable(entriesOf(c)), { count: table.count, packed: table.packed });
  const entries = chunkEntries({ chunks: table }, 2, 0);
  assert.deepEqual(entries.map((e) => [e.byteOffset, e.splits]), [[0, 120], [300, 130]]);
});

test('a keyed packed table carries one MAC per chunk and reads back to the same values', () => {
  const entries = entriesOf(unpackChunkTable(table.count, table.packed)).map((e, k) => ({ ...e, mac: `${k}`.repeat(32) }));
  const packed = packChunkTable(entries);
  assert.deepEqual(entriesOf(unpackChunkTable(packed.count, packed.packed)), entries);
});

/** The extension object of the first progressive primitive of a conformance file. */
function extensionOf(file) {
  const { gltf } = parseGlb(new Uint8Array(readFileSync(join(CONFORMANCE, file))));
  const prim = gltf.meshes[0].primitives[0];
  return { ext: prim.extensions.PMWM_progressive_mesh, base: gltf.accessors[prim.attributes.POSITION].count };
}

test('a packed conformance file and an array-form one expand to entries of the same shape', () => {
  const packed = extensionOf('sphere.exact-watermark.packed.v2.pmw');
  const arrays = extensionOf('sphere.exact-watermark.v2.pmw');
  assert.ok('packed' in packed.ext.chunks && 'byteLengths' in arrays.ext.chunks);
  const a = chunkEntries(packed.ext, 2, packed.base);
  const b = chunkEntries(arrays.ext, 2, arrays.base);
  assert.deepEqual(Object.keys(a[0]).sort(), Object.keys(b[0]).sort());
  assert.ok(a.every((e) => /^[0-9a-f]{16}$/.test(e.digest) && /^[0-9a-f]{32}$/.test(e.mac) && e.splits >= 0));
});

const bytesOf = (t) => Uint8Array.from(atob(t.packed), (ch) => ch.charCodeAt(0));
const withBytes = (t, bytes) => ({ ...t, packed: btoa(String.fromCharCode(...bytes)) });
const MALFORMED = {
  'count one more': (t) => ({ ...t, count: t.count + 1 }),
  'count one less': (t) => ({ ...t, count: t.count - 1 }),
  'count past the limit': (t) => ({ ...t, count: 1 << 20 }),
  'a byte missing': (t) => withBytes(t, bytesOf(t).subarray(0, -1)),
  'a byte too many': (t) => withBytes(t, [...bytesOf(t), 0]),
  'a reserved flag bit': (t) => withBytes(t, [2, ...bytesOf(t).subarray(1)]),
  'an overlong varint': (t) => withBytes(t, [...bytesOf(t).subarray(0, -1), 0x80, 0x80, 0x80, 0x80, 0x80, 0]),
  'a NaN geometric error': (t) => { const b = bytesOf(t); b.set([0, 0, 0xc0, 0x7f], 1 + 8 * t.count); return withBytes(t, b); },
  'not base64': (t) => ({ ...t, packed: `${t.packed.slice(0, -4)}!!!=` }),
  'a text longer than the count allows': (t) => ({ ...t, packed: 'A'.repeat(4000) }),
  'a JSON array beside it': (t) => ({ ...t, byteLengths: [1] }),
};

for (const [name, damage] of Object.entries(MALFORMED)) {
  test(`a packed chunk table with ${name} is a one-line FormatError`, () => {
    assert.throws(() => chunkEntries({ chunks: damage(table) }, 2, 0), (e) => e instanceof FormatError && !e.message.includes('\n'));
  });
}
