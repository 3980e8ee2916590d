/**
 * The JS decoder reproduces the Python decoder exactly on spec/conformance: at every chunk
 * boundary the same bytes read, vertex and face counts (per part), and the same positions, faces
 * and quantized attributes (SHA-256 of the level recorded by tests/test_golden.py), and the same
 * final arrays in full.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { test } from 'node:test';
import { PmwDecoder, decodePmw } from '../src/index.js';
import { readNpz } from './lib/npz.js';
import { CONFORMANCE, attributesInt, conformanceFiles, levelDigest } from './lib/helpers.js';
import { decodeToGlb, python } from './lib/python.js';

const asNumbers = (a) => Array.from(a, Number);

for (const file of conformanceFiles()) {
  test(`${file} decodes to its expected level at every chunk boundary`, async () => {
    const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, file)));
    const want = readNpz(new Uint8Array(readFileSync(join(CONFORMANCE, file.replace(/\.pmw$/, '.expected.npz')))));
    const decoder = new PmwDecoder({ snapshots: true });
    const results = await decoder.feed(bytes);
    assert.equal((await decoder.close()).complete, true);
    assert.deepEqual(results.map((r) => r.bytesRead), asNumbers(want.chunk_bytes.data));
    assert.deepEqual(results.flatMap((r) => [r.vertexCount, r.faceCount]), asNumbers(want.counts.data));
    if (want.part_counts) {
      assert.deepEqual(results.flatMap((r) => r.parts.flatMap((p) => [p.vertexCount, p.faceCount])),
        asNumbers(want.part_counts.data));
    }
    assert.deepEqual(results.map((r) => levelDigest(r.mesh)), want.level_sha256.data);
    const last = results[results.length - 1].mesh;
    assert.deepEqual(asNumbers(last.positionsInt), asNumbers(want.final_positions.data));
    assert.deepEqual(asNumbers(last.indices), asNumbers(want.final_faces.data));
    if (want.final_attributes) assert.deepEqual(asNumbers(attributesInt(last)), asNumbers(want.final_attributes.data));
  });
}

test('a chunk limit stops decodePmw at the chunk count and says the file is whole (chunksApplied < chunkCount)', async () => {
  const file = conformanceFiles()[0];
  const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, file)));
  const want = readNpz(new Uint8Array(readFileSync(join(CONFORMANCE, file.replace(/\.pmw$/, '.expected.npz')))));
  const counts = asNumbers(want.counts.data);
  const base = await decodePmw(bytes, { chunks: 0 });
  assert.equal(base.chunksApplied, 0);
  assert.ok(base.chunkCount > 0);
  assert.equal(base.complete, true, 'complete: the input file is whole, as pmw decode --chunks N --json says');
  const cut = await decodePmw(bytes.subarray(0, bytes.length - 1), { chunks: 0 });
  assert.equal(cut.chunksApplied, 0);
  assert.equal(cut.complete, false, 'the same chunk limit on a cut file: not complete');
  assert.equal(base.positions.length, counts[0] * 3);
  assert.equal(base.indices.length, counts[1] * 3);
  const full = await decodePmw(bytes);
  assert.equal(full.complete, true);
  assert.equal(full.positions.length, counts[counts.length - 2] * 3);
  assert.ok(full.positions instanceof Float32Array && full.indices instanceof Uint32Array);
});

/** The float arrays of mesh `m` primitive `p` of a GLB written by `pmw decode`: {semantic: Float32Array}. */
function glbAttributes(bytes, m = 0, p = 0) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jsonLength = view.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  const bin = bytes.slice(28 + jsonLength);
  const K = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };
  return Object.fromEntries(Object.entries(gltf.meshes[m].primitives[p].attributes).map(([semantic, index]) => {
    const acc = gltf.accessors[index];
    const start = (gltf.bufferViews[acc.bufferView].byteOffset ?? 0) + (acc.byteOffset ?? 0);
    return [semantic, new Float32Array(bin.buffer, start, acc.count * K[acc.type])];
  }));
}

test('positions and attributes (NORMAL renormalized) are pmw decode\'s floats bit for bit at every level',
  { skip: python() ? false : 'no Python that imports pmwm_codec (set PYTHON)' }, async () => {
    const file = join(CONFORMANCE, 'sphere-attributes.plain.packed.v2.pmw'); // NORMAL and TEXCOORD_0
    const bytes = new Uint8Array(readFileSync(file));
    const dir = mkdtempSync(join(tmpdir(), 'pmw-floats-'));
    try {
      for (let k = 0; k <= (await decodePmw(bytes)).chunkCount; k++) {
        decodeToGlb(file, k, join(dir, `${k}.glb`));
        const reference = glbAttributes(new Uint8Array(readFileSync(join(dir, `${k}.glb`))));
        const [part] = (await decodePmw(bytes, { chunks: k })).parts;
        assert.deepEqual(part.positions, reference.POSITION, `level ${k} POSITION`);
        for (const [semantic, values] of Object.entries(part.attributes)) assert.deepEqual(values, reference[semantic], `level ${k} ${semantic}`);
      }
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
  });
