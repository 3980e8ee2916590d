/**
 * Memory follows what is decoded, not what a file declares (spec/README.md "Conformance"): a file
 * whose chunk table claims tens of millions of vertices and faces for its last chunks (a few KB edited
 * in the JSON of a small real file) is refused with the FormatError of the first chunk that fails to
 * reach its entry, while the decoder's arrays stay near the size of the mesh it really decoded; a
 * valid file's arrays start at its base's size and end at its full counts exactly.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError, PmwDecoder } from '../src/index.js';
import { readNpz } from './lib/npz.js';
import { CONFORMANCE, levelDigest } from './lib/helpers.js';
import { packChunkTable, unpackChunkTable } from '../src/chunktable.js';
import { chunkPayloads, withJson, withPayload } from './lib/rewrite.js';

/** Declared counts near the limits (MAX_VERTICES 2^26, MAX_FACES 2^27): gigabytes if allocated up front. */
const V = 60000000;
const F = 120000000;
const MB = 2 ** 20;

const read = (name) => new Uint8Array(readFileSync(join(CONFORMANCE, name)));

/**
 * `bytes` (one progressive primitive) with chunks `from` .. K-1 claiming V vertices and F, F+1, ...
 * faces, and the extension's final counts those of its last chunk (so the header checks pass): by
 * default `from` is the last chunk that splits (the first face chunk, if any, and those after it claim
 * too), as an attacker edits a real file's table (pmwm_codec's chunk table packing, spec/bitstream.md §6.2).
 */
function declaring(bytes, from) {
  let first;
  const out = withJson(bytes, (gltf, plan) => {
    const ext = gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
    const K = plan.primitives[0].chunks.length;
    first = from ?? (ext.firstFaceChunk ?? K) - 1;
    const t = ext.chunks;
    if (Array.isArray(t)) { // payload version 1: one entry per chunk
      for (let k = first; k < K; k++) Object.assign(t[k], { vertexCount: V, faceCount: F + k - first });
    } else if ('packed' in t) { // digests (and MACs) kept
      const cols = unpackChunkTable(t.count, t.packed);
      for (let k = first; k < K; k++) [cols.vertexCount[k], cols.faceCount[k]] = [V, F + k - first];
      Object.assign(t, packChunkTable(cols.byteLength.map((byteLength, k) => ({ byteLength, vertexCount: cols.vertexCount[k],
        faceCount: cols.faceCount[k], geometricError: cols.geometricError[k], digest: cols.digest[k], mac: cols.mac?.[k] }))));
    } else {
      for (let k = first; k < K; k++) [t.vertexCounts[k], t.faceCounts[k]] = [V, F + k - first];
    }
    ext.vertexCount = V;
    ext.faceCount = F + K - 1 - first;
  });
  return { bytes: out, first };
}

/** Bytes of the typed arrays a decoder holds for its meshes (MeshState and ChunkDecoderV2, scratch included). */
function heldBytes(decoder) {
  let total = 0;
  const add = (o) => {
    for (const [key, v] of Object.entries(o)) {
      if (ArrayBuffer.isView(v)) total += v.byteLength;
      else if (key !== 'state' && v !== null && Object.getPrototypeOf(v) === Object.prototype) add(v); // scratch groups
    }
  };
  for (const s of decoder.states) add(s);
  for (const c of decoder.coders) if (c) add(c);
  return total;
}

/** Decodes `bytes` whole: {decoder, error, grew (arrayBuffers after minus before, bytes)}. */
async function decode(bytes) {
  const decoder = new PmwDecoder();
  const before = process.memoryUsage().arrayBuffers;
  let error = null;
  try {
    await decoder.feed(bytes);
    await decoder.close();
  } catch (e) {
    error = e;
  }
  return { decoder, error, grew: process.memoryUsage().arrayBuffers - before };
}

const FILES = ['sphere-attributes.plain.v1.pmw', 'sphere-attributes.plain.v2.pmw', 'sphere-attributes.plain.packed.v2.pmw',
  'sphere-pillows.draco.packed.v2.pmw', 'grid-hole.plain.packed.v2.pmw'];

for (const name of FILES) {
  test(`${name} edited to declare ${V} vertices / ${F} faces: the same FormatError, memory near the real mesh`, async () => {
    const src = read(name);
    const normal = await decode(src);
    assert.equal(normal.error, null);
    const { bytes, first } = declaring(src);
    const bomb = await decode(bytes);
    assert.ok(bomb.error instanceof FormatError, String(bomb.error));
    assert.equal(bomb.error.message, `chunk ${first + 1}: vertex/face counts differ from its index entry`);
    assert.ok(bomb.grew < 32 * MB, `arrayBuffers grew by ${(bomb.grew / MB).toFixed(1)} MB`);
    const held = heldBytes(bomb.decoder);
    assert.ok(held <= 2 * heldBytes(normal.decoder), `${held} bytes held, ${heldBytes(normal.decoder)} for the whole mesh`);
    const [s] = bomb.decoder.states;
    assert.equal(s.capN, V); // the declared counts stay the bound ...
    assert.ok(s.vertexCapacity <= 2 * s.n && s.faceCapacity <= 4 * s.m, `${s.vertexCapacity} / ${s.faceCapacity} for ${s.n} / ${s.m}`);
  });
}

test('a payload cut to 3 bytes under a claim of millions is refused at its first batch, not decoded as zeros to the claim', async () => {
  // The range decoder reads zeros past a payload's end (spec §8.1 overrun); it said so only at the chunk's end.
  const name = 'sphere-attributes.plain.packed.v2.pmw';
  const { bytes, first } = declaring(read(name));
  const cut = withPayload(bytes, first, chunkPayloads(bytes)[first].payload.subarray(0, 3));
  const { error, grew } = await decode(cut);
  assert.ok(error instanceof FormatError, String(error));
  assert.match(error.message, new RegExp(`^chunk ${first + 1}: chunk payload: the coded stream does not end at the end of the payload`));
  assert.ok(grew < 32 * MB, `arrayBuffers grew by ${(grew / MB).toFixed(1)} MB`);
});

test('a face chunk whose entry declares millions of new vertices and faces is refused, its arrays near the real mesh', async () => {
  const name = 'sphere-pillows.draco.packed.v2.pmw'; // its last chunk is a face chunk (firstFaceChunk)
  const { bytes, first } = declaring(read(name), 11);
  const { decoder, error, grew } = await decode(bytes);
  assert.equal(decoder.plan.stream[first].faces, true);
  assert.ok(error instanceof FormatError, String(error));
  assert.match(error.message, new RegExp(`^chunk ${first + 1}: face chunk: \\d+ new vertices, fewer than the \\d+ its index entry adds$`));
  assert.ok(grew < 32 * MB, `arrayBuffers grew by ${(grew / MB).toFixed(1)} MB`);
  const [s] = decoder.states;
  assert.ok(s.vertexCapacity < 4096 && s.faceCapacity < 8192, `${s.vertexCapacity} / ${s.faceCapacity}`);
});

test('a valid file\'s arrays start at its base\'s size, stay within twice each level, end at its full counts; the levels are the expected ones', async () => {
  for (const name of FILES) {
    const capacities = [];
    const decoder = new PmwDecoder({
      snapshots: true,
      onLevel: (r, d) => {
        const [s] = d.states;
        capacities.push({ n: s.n, m: s.m, N: s.vertexCapacity, M: s.faceCapacity });
      },
    });
    const results = await decoder.feed(read(name));
    assert.equal((await decoder.close()).complete, true);
    const want = readNpz(read(name.replace(/\.pmw$/, '.expected.npz')));
    assert.deepEqual(results.map((r) => levelDigest(r.mesh)), want.level_sha256.data, name);
    const [base] = capacities;
    assert.deepEqual([base.N, base.M], [base.n, base.m], `${name}: base`);
    for (const c of capacities) assert.ok(c.n <= c.N && c.N <= 2 * c.n && c.m <= c.M && c.M <= 4 * c.m, `${name}: ${JSON.stringify(c)}`);
    const last = capacities[capacities.length - 1];
    assert.deepEqual([last.N, last.M], [last.n, last.m], `${name}: full`);
  }
});
