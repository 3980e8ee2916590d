// The three.js plugin in Node: GLTFLoader shows the base, the plugin refines it over HTTP (Range or one stream).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { fileURLToPath } from 'node:url';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { decodePmw } from '../src/index.js';
import { loadProgressive } from '../src/three-plugin.js';
import { startServer } from './lib/server.js';

const conformance = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../../spec/conformance');
const NAME = 'sphere-attributes.plain.v1.pmw'; // plain base (no Draco), attributes, 10 chunks
const bytes = new Uint8Array(fs.readFileSync(path.join(conformance, NAME)));
const servers = {};

before(async () => {
  servers.ranges = await startServer(conformance);
  servers.plain = await startServer(conformance, { ranges: false });
});
after(async () => { await servers.ranges.close(); await servers.plain.close(); });

function theMesh(gltf) {
  let mesh = null;
  gltf.scene.traverse((o) => { if (o.isMesh) mesh = o; });
  return mesh;
}

for (const kind of ['ranges', 'plain']) {
  test(`loadProgressive (${kind}) refines the base in place to the full mesh, level by level`, async () => {
    const server = servers[kind];
    server.stats.bytes = 0;
    const full = await decodePmw(bytes);
    const events = [];
    const gltf = await loadProgressive(new GLTFLoader(), server.url + NAME, { onChunk: (e) => events.push(e) });
    const mesh = theMesh(gltf);
    const outcome = await gltf.userData.pmwm.done;
    assert.equal(outcome.complete, true);
    assert.equal(events.length, full.chunkCount);
    assert.deepEqual(events.map((e) => e.chunk), [...Array(full.chunkCount)].map((_, i) => i + 1));
    const g = mesh.geometry;
    assert.equal(g.userData.pmwmLevel.vertices, full.positions.length / 3);
    assert.equal(g.drawRange.count, full.indices.length);
    assert.deepEqual(g.index.array.subarray(0, full.indices.length), full.indices);
    assert.deepEqual(g.getAttribute('position').array.subarray(0, full.positions.length), full.positions);
    assert.equal(server.stats.bytes, bytes.length);
    for (let i = 1; i < events.length; i++) assert.ok(events[i].vertexCount > events[i - 1].vertexCount);
  });
}

test('a Range load stopped at chunk 2 fetches only the bytes up to its end', async () => {
  const server = servers.ranges;
  server.stats.bytes = 0;
  const two = await decodePmw(bytes, { chunks: 2 });
  const gltf = await loadProgressive(new GLTFLoader(), server.url + NAME, { maxChunks: 2 });
  const outcome = await gltf.userData.pmwm.done;
  assert.equal(outcome.chunksApplied, 2);
  assert.equal(theMesh(gltf).geometry.userData.pmwmLevel.vertices, two.positions.length / 3);
  assert.equal(server.stats.bytes, two.bytesRead);
  assert.equal(outcome.bytesFetched, two.bytesRead);
  assert.ok(two.bytesRead < bytes.length);
});

test('a byte budget shows the level of the cut file', async () => {
  for (const kind of ['ranges', 'plain']) {
    const [three, four] = [await decodePmw(bytes, { chunks: 3 }), await decodePmw(bytes, { chunks: 4 })];
    const budget = Math.floor((three.bytesRead + four.bytesRead) / 2);
    const cut = await decodePmw(bytes.subarray(0, budget));
    const gltf = await loadProgressive(new GLTFLoader(), servers[kind].url + NAME, { byteBudget: budget });
    const outcome = await gltf.userData.pmwm.done;
    assert.equal(outcome.chunksApplied, 3, kind);
    assert.equal(cut.chunksApplied, 3, kind);
    assert.equal(theMesh(gltf).geometry.userData.pmwmLevel.vertices, cut.positions.length / 3, kind);
  }
});
