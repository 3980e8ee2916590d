// The three.js plugin in headless Chromium (Debian's /usr/bin/chromium through playwright-core): the demo
// page (js/demo/index.html), served from 127.0.0.1, loads a .pmw through loadProgressive and DRACOLoader.
// Subjects: bunny.pmw, encoded in setup by `python -m pmwm_codec encode` from ../shared's Stanford bunny
// (a generated icosphere of similar size when ../shared is absent; Draco base, the encoder's defaults),
// and a conformance file with a plain base and attributes. Skipped when Chromium is absent (CI installs
// it); the bunny's tests skip when no Python imports pmwm_codec (set PYTHON).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { after, before, describe, test } from 'node:test';
import { parseGlb, planDocument } from '../src/header.js';
import { decodePmw } from '../src/index.js';
import { encodeBunny, python, ROOT } from './lib/python.js';
import { startServer } from './lib/server.js';

const CHROMIUM = process.env.CHROMIUM ?? '/usr/bin/chromium';
const skip = fs.existsSync(CHROMIUM) ? false : `no Chromium at ${CHROMIUM}`;
const skipBunny = skip || (python() ? false : 'no Python that imports pmwm_codec (set PYTHON)');
let browser; let tmp; let bunny; const servers = {};

before(async () => {
  if (skip) return;
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'pmwm-browser-'));
  if (!skipBunny) bunny = encodeBunny(tmp);
  const { chromium } = await import('playwright-core');
  // a fresh profile directory (playwright passes it as --user-data-dir)
  browser = await chromium.launchPersistentContext(path.join(tmp, 'profile'), { executablePath: CHROMIUM, headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync', '--enable-unsafe-swiftshader'] });
  const mounts = { '/data/': tmp };
  servers.fast = await startServer(ROOT, { mounts });
  servers.slow = await startServer(ROOT, { mounts, delayMs: 40 });
  servers.plain = await startServer(ROOT, { mounts, ranges: false });
});
after(async () => {
  await browser?.close();
  for (const s of Object.values(servers)) await s.close();
  if (tmp) fs.rmSync(tmp, { recursive: true, force: true });
});

/**
 * The demo page's outcome for `src` with `query`: {result, levels: [{chunk, vertexCount, image}], arrays}.
 * arrays (with `arrays: true`): the refined geometry's drawn positions, indices and normals as plain arrays.
 * `failing: true` expects the load to end in an error (result.errorName, result.errorMessage).
 */
async function load(server, src, query, { arrays = false, failing = false } = {}) {
  const page = await browser.newPage();
  const errors = [];
  page.on('pageerror', (e) => errors.push(String(e)));
  try {
    await page.goto(`${server.url}js/demo/index.html?src=${src}&size=256&record=1&${query}`);
    await page.waitForFunction(() => window.result !== undefined, null, { timeout: 60000 });
    const out = await page.evaluate((withArrays) => {
      const g = withArrays && window.mesh.geometry;
      const drawn = (attr, n) => Array.from(attr.array.subarray(0, n * attr.itemSize));
      return { result: window.result, levels: window.levels, arrays: g && { indices: drawn(g.index, g.drawRange.count),
        positions: drawn(g.getAttribute('position'), g.userData.pmwmLevel.vertices),
        normals: g.getAttribute('normal') ? drawn(g.getAttribute('normal'), g.userData.pmwmLevel.vertices) : null } };
    }, arrays);
    if (failing) assert.ok(out.result.errorName, 'the load should have failed');
    else assert.equal(out.result.error, undefined, out.result.error);
    assert.deepEqual(errors, []);
    return out;
  } finally {
    await page.close();
  }
}

const SUBJECTS = [
  { title: 'bunny.pmw (Draco base)', src: '/data/bunny.pmw', skip: () => skipBunny, bytes: () => fs.readFileSync(bunny.file) },
  { title: 'sphere-attributes (plain base, attributes)', src: '/spec/conformance/sphere-attributes.plain.v1.pmw', skip: () => skip,
    bytes: () => fs.readFileSync(path.join(ROOT, 'spec/conformance/sphere-attributes.plain.v1.pmw')) },
  // three.js decodes the Draco base with its copies of non-manifold vertices; our decoder welds them
  { title: 'bowtie.welded-draco (welded Draco base)', src: '/spec/conformance/bowtie.welded-draco.packed.v2.pmw', skip: () => skip,
    bytes: () => fs.readFileSync(path.join(ROOT, 'spec/conformance/bowtie.welded-draco.packed.v2.pmw')) },
  // three.js decodes the weld attribute (_PMWM_WELD) as an attribute of its own; our decoder welds by it
  { title: 'kissing.welded-draco (weld attribute)', src: '/spec/conformance/kissing.welded-draco.packed.v2.pmw', skip: () => skip,
    bytes: () => fs.readFileSync(path.join(ROOT, 'spec/conformance/kissing.welded-draco.packed.v2.pmw')) },
  // three.js decodes TEXCOORD_0, COLOR_0 and _FEATURE_ID_0 from the Draco base; our decoder welds its seam copies
  { title: 'uv-torus-attributes.welded-draco (Draco base with attributes)',
    src: '/spec/conformance/uv-torus-attributes.welded-draco.packed.v2.pmw', skip: () => skip,
    bytes: () => fs.readFileSync(path.join(ROOT, 'spec/conformance/uv-torus-attributes.welded-draco.packed.v2.pmw')) },
];

for (const subject of SUBJECTS) {
  describe(subject.title, () => {
    let bytes; let full;
    before(async () => {
      if (subject.skip()) return;
      bytes = new Uint8Array(subject.bytes());
      full = await decodePmw(bytes);
    });
    const opts = () => ({ skip: subject.skip() });

    test('a throttled Range load reaches the full vertex count through at least three pixel-different levels', opts(), async () => {
      const { result, levels } = await load(servers.slow, subject.src, '');
      assert.equal(result.complete, true);
      assert.equal(result.vertices, full.positions.length / 3);
      if (subject.src.includes('bunny')) assert.equal(result.vertices, bunny.report.vertices);
      assert.equal(levels.length, full.chunkCount + 1, 'the base and one rendered level per chunk');
      assert.ok(new Set(levels.map((l) => l.image)).size >= 3, `${levels.length} levels`);
      assert.ok(new Set(levels.map((l) => l.vertexCount)).size >= 3);
    });

    test('a plain (no Range) load reaches the full vertex count', opts(), async () => {
      servers.plain.stats.bytes = 0;
      const { result } = await load(servers.plain, subject.src, 'range=0');
      assert.equal(result.complete, true);
      assert.equal(result.vertices, full.positions.length / 3);
      assert.equal(servers.plain.stats.bytes, bytes.length);
    });

    test('a load stopped after a byte budget shows the level the decoder gives for that byte prefix', opts(), async () => {
      const k = Math.min(3, full.chunkCount - 1);
      const [lo, hi] = [await decodePmw(bytes, { chunks: k }), await decodePmw(bytes, { chunks: k + 1 })];
      const budget = Math.floor((lo.bytesRead + hi.bytesRead) / 2);
      const prefix = await decodePmw(bytes.subarray(0, budget));
      assert.equal(prefix.chunksApplied, k);
      servers.fast.stats.bytes = 0;
      const { result } = await load(servers.fast, subject.src, `budget=${budget}`);
      assert.equal(result.chunksApplied, k);
      assert.equal(result.complete, false);
      assert.equal(result.vertices, prefix.positions.length / 3);
      assert.ok(result.vertices < full.positions.length / 3);
      assert.ok(servers.fast.stats.bytes <= budget, `${servers.fast.stats.bytes} bytes served, budget ${budget}`);
    });

    test('a Range load of two chunks fetches only the bytes it needs (counted at the server)', opts(), async () => {
      const two = await decodePmw(bytes, { chunks: 2 });
      servers.fast.stats.bytes = 0;
      const { result } = await load(servers.fast, subject.src, 'chunks=2');
      assert.equal(result.chunksApplied, 2);
      assert.equal(result.vertices, two.positions.length / 3);
      assert.equal(servers.fast.stats.bytes, two.bytesRead);
      assert.ok(two.bytesRead < bytes.length);
    });

    test('worker=1 decodes in the Web Worker to the same levels and arrays as the main thread (worker=0)', opts(), async () => {
      const main = await load(servers.fast, subject.src, 'worker=0', { arrays: true });
      const inWorker = await load(servers.fast, subject.src, 'worker=1', { arrays: true });
      assert.equal(main.result.workerLevels, 0, 'worker=0 decoded in a worker');
      assert.equal(inWorker.result.workerLevels, full.chunkCount + 1, 'the worker decoded the base and every chunk');
      assert.equal(inWorker.result.complete, true);
      const counts = (out) => out.levels.map((l) => [l.chunk, l.vertexCount]);
      assert.equal(inWorker.levels.length, full.chunkCount + 1);
      assert.deepEqual(counts(inWorker), counts(main));
      assert.deepEqual(inWorker.arrays, main.arrays);
      assert.deepEqual(inWorker.arrays.positions, Array.from(full.positions));
      assert.deepEqual(inWorker.arrays.indices, Array.from(full.indices));
    });

    test('worker auto decodes in the worker only when the full vertex count exceeds the threshold', opts(), async () => {
      const vertices = full.positions.length / 3;
      const below = await load(servers.fast, subject.src, `worker-threshold=${vertices - 1}`);
      const at = await load(servers.fast, subject.src, `worker-threshold=${vertices}`);
      assert.equal(below.result.workerLevels, full.chunkCount + 1);
      assert.equal(at.result.workerLevels, 0);
      assert.equal(below.result.vertices, vertices);
      assert.equal(at.result.vertices, vertices);
    });

    test('a worker that cannot start falls back to the main thread with the same result', opts(), async () => {
      const { result } = await load(servers.fast, subject.src, 'worker=1&worker-url=/no-such-worker.js');
      assert.equal(result.workerLevels, 0);
      assert.equal(result.complete, true);
      assert.equal(result.vertices, full.positions.length / 3);
    });

    test('a corrupt chunk fails with the same named error in the worker as on the main thread', opts(), async () => {
      const header = parseGlb(bytes);
      const chunk = planDocument(header.gltf, header.binLength).stream[1];
      const corrupt = bytes.slice();
      corrupt[header.binStart + chunk.offset + chunk.length - 1] ^= 0x40; // a stored byte: the digest differs
      const name = `corrupt-${path.basename(subject.src)}`;
      fs.writeFileSync(path.join(tmp, name), corrupt);
      const main = await load(servers.fast, `/data/${name}`, 'worker=0', { failing: true });
      const inWorker = await load(servers.fast, `/data/${name}`, 'worker=1', { failing: true });
      assert.equal(main.result.errorName, 'CorruptChunkError');
      assert.deepEqual([inWorker.result.errorName, inWorker.result.errorMessage],
        [main.result.errorName, main.result.errorMessage]);
    });

    test('a corrupt last chunk leaves the last good level drawn and reported, by Range and by one streamed GET, in the worker and on the main thread',
      opts(), async () => {
        const header = parseGlb(bytes);
        const { stream } = planDocument(header.gltf, header.binLength);
        const K = stream.length;
        const corrupt = bytes.slice();
        corrupt[header.binStart + stream[K - 1].offset + stream[K - 1].length - 1] ^= 0x40;
        const name = `corrupt-last-${path.basename(subject.src)}`;
        fs.writeFileSync(path.join(tmp, name), corrupt);
        const good = await decodePmw(bytes, { chunks: K - 1 });
        for (const [server, query] of [[servers.fast, 'worker=0'], [servers.fast, 'worker=1'],
          [servers.plain, 'worker=0&range=0'], [servers.plain, 'worker=1&range=0']]) {
          const { result, levels, arrays } = await load(server, `/data/${name}`, query, { failing: true, arrays: true });
          assert.equal(result.errorName, 'CorruptChunkError', query);
          // the page records the base once loaded, then each onChunk
          assert.deepEqual(levels.map((l) => l.chunk), [...Array(K).keys()], `${query}: onChunk of every good chunk`);
          assert.deepEqual(arrays.positions, Array.from(good.positions), query);
          assert.deepEqual(arrays.indices, Array.from(good.indices), query);
        }
      });
  });
}

test('a worker script that loads but never says ready (a wrong workerUrl) falls back to the main thread, no hang',
  { skip, timeout: 60000 }, async () => {
    const src = '/spec/conformance/sphere-attributes.plain.v1.pmw';
    const full = await decodePmw(new Uint8Array(fs.readFileSync(path.join(ROOT, src))));
    const { result } = await load(servers.fast, src, 'worker=1&worker-url=/js/src/errors.js'); // a module, not the worker
    assert.equal(result.workerLevels, 0);
    assert.equal(result.complete, true);
    assert.equal(result.vertices, full.positions.length / 3);
  });
