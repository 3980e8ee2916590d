// How the three.js plugin reads a .pmw by Range requests: three of them whatever the number of chunks (the preamble,
// the JSON with the BIN chunk header, then all it wants after them in one streamed answer), each chunk applied as soon
// as its own bytes are in, a stop in the middle of that answer aborting it, short answers followed by requests for
// the rest, and the same requests as the Python reader's (pmwm_codec.http.plan_ranges) for the same file.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { parseGlb, planDocument } from '../src/header.js';
import { decodePmw } from '../src/index.js';
import * as plugin from '../src/three-plugin.js';
import { encodeCase, python, readUrl } from './lib/python.js';
import { startServer } from './lib/server.js';

const skip = python() ? false : 'no Python that imports pmwm_codec (set PYTHON)';
const NAME = 'many.pmw';
let tmp; let server; let bytes; let binStart; let plan; let stream; let K;
/** The file offset where chunk k (1-based) ends; chunk 0: the base. */
const chunkEnd = (k) => binStart + (k ? stream[k - 1].offset + stream[k - 1].length : stream[0].offset);

before(() => {
  if (skip) return;
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'pmwm-ranges-'));
  encodeCase('many-primitives.plain', 2, path.join(tmp, NAME)); // 12 primitives, 68 chunks
  bytes = new Uint8Array(fs.readFileSync(path.join(tmp, NAME)));
  const header = parseGlb(bytes);
  binStart = header.binStart;
  plan = planDocument(header.gltf, header.binLength);
  stream = plan.stream;
  K = stream.length;
});
before(async () => { if (!skip) server = await startServer(tmp); });
after(async () => {
  await server?.close();
  if (tmp) fs.rmSync(tmp, { recursive: true, force: true });
});

/** The server's log and request count from here on. */
function watch() {
  const [from, requests] = [server.stats.log.length, server.stats.requests];
  return () => ({ log: server.stats.log.slice(from), requests: server.stats.requests - requests });
}

test('a file of many chunks is read in three Range requests, each chunk applied in turn, nothing past the last one wanted',
  { skip }, async () => {
    assert.ok(K >= 60, `${K} chunks`);
    const error = stream[40].geometricError;
    const cases = [[{}, () => K], [{ maxChunks: 10 }, () => 10],
      [{ byteBudget: Math.floor((chunkEnd(20) + chunkEnd(21)) / 2) }, () => 20],
      [{ maxGeometricError: error }, () => plugin.chunksWanted(plan, binStart, { maxGeometricError: error })]];
    for (const [options, wanted] of cases) {
      const want = wanted();
      const what = JSON.stringify(options);
      const seen = watch();
      const chunks = [];
      const gltf = await plugin.loadProgressive(new GLTFLoader(), server.url + NAME, { ...options, onChunk: (e) => chunks.push(e.chunk) });
      const outcome = await gltf.userData.pmwm.done;
      const end = want === K ? bytes.length : chunkEnd(want);
      assert.deepEqual(seen().log, ['bytes=0-19', `bytes=20-${binStart - 1}`, `bytes=${binStart}-${end - 1}`], what);
      assert.equal(outcome.requests, 3, what);
      assert.equal(outcome.bytesFetched, end, what);
      assert.deepEqual(chunks, [...Array(want)].map((_, i) => i + 1), what);
      assert.equal(outcome.chunksApplied, want, what);
    }
  });

test('each chunk is applied as soon as its own bytes are in: levels are drawn while the answer is still being sent',
  { skip }, async () => {
    const sent = [];
    const gltf = await plugin.loadProgressive(new GLTFLoader(), `${server.url}${NAME}?drip=5`, // 1,000 bytes every 5 ms
      { onChunk: () => sent.push(server.stats.sending) });
    const outcome = await gltf.userData.pmwm.done;
    assert.equal(outcome.complete, true);
    assert.equal(outcome.requests, 3);
    assert.equal(sent.length, K);
    assert.ok(sent.filter((n) => n > 0).length >= K / 2, `only ${sent.filter((n) => n > 0).length} of ${K} levels drawn `
      + 'before the answer ended');
    assert.equal(sent[0], 1, 'the first level came after the whole answer');
  });

test('stop() or an abort from onChunk in the middle of the answer aborts it at once: no later level is drawn', { skip }, async () => {
  const at = 5;
  const level = await decodePmw(bytes, { chunks: at });
  for (const how of ['stop', 'signal']) {
    const dropped = server.stats.dropped;
    const controller = new AbortController();
    const events = [];
    let run;
    let stoppedAt;
    const gltf = await plugin.loadProgressive(new GLTFLoader(), `${server.url}${NAME}?drip=20`, { signal: controller.signal,
      onChunk: (e) => {
        events.push(e.chunk);
        if (e.chunk !== at) return;
        stoppedAt = Date.now();
        if (how === 'stop') run.stop(); else controller.abort();
      } });
    run = gltf.userData.pmwm;
    const outcome = await run.done;
    assert.ok(Date.now() - stoppedAt < 500, `${how}: done ${Date.now() - stoppedAt} ms after the stop`);
    assert.deepEqual(events, [1, 2, 3, 4, 5], how);
    assert.deepEqual([outcome.stopped, outcome.complete, outcome.chunksApplied, outcome.levels], [true, false, at, at + 1], how);
    assert.ok(outcome.bytesFetched < bytes.length, how);
    let g = null;
    gltf.scene.traverse((o) => { if (o.isMesh && !g) g = o.geometry; });
    assert.deepEqual(g.getAttribute('position').array.subarray(0, level.parts[0].positions.length), level.parts[0].positions, how);
    for (let t = 0; server.stats.dropped === dropped && t < 100; t++) await new Promise((r) => setTimeout(r, 20));
    assert.equal(server.stats.dropped, dropped + 1, `${how}: the server saw the answer's connection closed`);
  }
});

test('a server that caps its answers is asked for the rest of each planned request until every byte is in', { skip }, async () => {
  for (const cap of [1000, 7000]) {
    const seen = watch();
    const chunks = [];
    const gltf = await plugin.loadProgressive(new GLTFLoader(), `${server.url}${NAME}?cap=${cap}`, { onChunk: (e) => chunks.push(e.chunk) });
    const outcome = await gltf.userData.pmwm.done;
    const answers = (from, to) => Math.ceil((to - from) / cap);
    const { log, requests } = seen();
    assert.equal(requests, answers(0, 20) + answers(20, binStart) + answers(binStart, bytes.length), `cap ${cap}`);
    assert.equal(outcome.requests, requests);
    assert.deepEqual([outcome.complete, outcome.chunksApplied, outcome.bytesFetched], [true, K, bytes.length], `cap ${cap}`);
    assert.deepEqual(chunks, [...Array(K)].map((_, i) => i + 1));
    // each request asks from where the last answer ended to the end of its planned request
    let at = 0;
    for (const range of log) {
      const [first, last] = /^bytes=(\d+)-(\d+)$/.exec(range).slice(1).map(Number);
      assert.equal(first, at, range);
      assert.ok([19, binStart - 1, bytes.length - 1].includes(last), range);
      at = Math.min(last + 1, first + cap);
    }
  }
});

test('the Python reader (pmwm_codec.http) makes the same Range requests as the plugin for the same file and chunks', { skip }, async () => {
  const base = plugin.baseGlb(bytes.subarray(0, chunkEnd(0))); // what three.js holds when the plugin reads the stream itself
  for (const maxChunks of [undefined, 0, 1, 17, K]) {
    let seen = watch();
    await readUrl(server.url + NAME, maxChunks);
    const py = seen().log;
    seen = watch();
    await (await plugin.loadProgressive(new GLTFLoader(), server.url + NAME, { maxChunks })).userData.pmwm.done;
    assert.deepEqual(seen().log, py, `loadProgressive, maxChunks ${maxChunks}`);
    seen = watch();
    const loader = new GLTFLoader();
    loader.register((parser) => new plugin.PMWMProgressivePlugin(parser, { url: server.url + NAME, maxChunks }));
    await (await loader.parseAsync(base.slice().buffer, '')).userData.pmwm.done;
    assert.deepEqual(seen().log, py, `a registered plugin, maxChunks ${maxChunks}`);
    assert.equal(py.length, 3);
  }
});
