/**
 * The JS decoder reproduces the Python decoder exactly on spec/conformance: at every chunk
 * boundary the same bytes read, vertex and face counts (per part), and the same positions, faces
 * and quantized attributes (SHA-256 of the level recorded by tests/test_golden.py), and the same
 * final arrays in full.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { PmwDecoder, decodePmw } from '../src/index.js';
import { readNpz } from './lib/npz.js';
import { CONFORMANCE, attributesInt, conformanceFiles, levelDigest } from './lib/helpers.js';

const asNumbers = (a) => Array.from(a, Number);

for (const file of conformanceFiles()) {
  test(`${file} decodes to its expected level at every chunk boundary`, async () => {
    const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, file)));
    const want = readNpz(new Uint8Array(readFileSync(join(CONFORMANCE, file.replace(/\.pmw$/, '.expected.npz')))));
    const decoder = new PmwDecoder({ snapshots: true });
    const results = await decoder.feed(bytes);
    assert.equal(decoder.close().complete, true);
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

test('decodePmw stops after the requested chunk count and says the file is not complete', async () => {
  const file = conformanceFiles()[0];
  const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, file)));
  const want = readNpz(new Uint8Array(readFileSync(join(CONFORMANCE, file.replace(/\.pmw$/, '.expected.npz')))));
  const counts = asNumbers(want.counts.data);
  const base = await decodePmw(bytes, { chunks: 0 });
  assert.equal(base.chunksApplied, 0);
  assert.equal(base.complete, false);
  assert.equal(base.positions.length, counts[0] * 3);
  assert.equal(base.indices.length, counts[1] * 3);
  const full = await decodePmw(bytes);
  assert.equal(full.complete, true);
  assert.equal(full.positions.length, counts[counts.length - 2] * 3);
  assert.ok(full.positions instanceof Float32Array && full.indices instanceof Uint32Array);
});
