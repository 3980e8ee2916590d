// The three.js plugin when things go wrong: a corrupt chunk (the levels before it stay drawn and reported),
// stop() and AbortSignal (prompt, the drawn level kept), short 206 answers (the rest asked for), HTTP and
// network failures (FetchError), a registered plugin whose url holds another document (StreamMismatchError, when
// three.js parsed only a base; a whole file refines from its own bytes),
// a server that stalls (stallTimeout: FetchError), and callbacks of the caller's that throw.
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { parseGlb, planDocument } from '../src/header.js';
import { CorruptChunkError, decodePmw, FetchError, FormatError, PmwError, StreamMismatchError } from '../src/index.js';
import { baseGlb, loadProgressive, PMWMProgressivePlugin, STALL_TIMEOUT_MS } from '../src/three-plugin.js';
import { CONFORMANCE } from './lib/helpers.js';
import { startServer } from './lib/server.js';

const NAME = 'sphere-attributes.plain.v1.pmw'; // plain base, attributes, 10 chunks
const OTHER = 'grid-hole.plain.v1.pmw';
const bytes = new Uint8Array(fs.readFileSync(path.join(CONFORMANCE, NAME)));
const { binStart, binLength, gltf: json } = parseGlb(bytes);
const stream = planDocument(json, binLength).stream;
const K = stream.length;
/** The length of the bytes of a .pmw before its first chunk. */
function endOfBase(file) {
  const header = parseGlb(file);
  return header.binStart + planDocument(header.gltf, header.binLength).stream[0].offset;
}
const baseEnd = endOfBase(bytes);
/** The file offset where chunk k (1-based) ends. */
const chunkEnd = (k) => binStart + stream[k - 1].offset + stream[k - 1].length;
let tmp;
const servers = {};

before(async () => {
  tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'pmwm-plugin-'));
  for (const f of [NAME, OTHER]) fs.copyFileSync(path.join(CONFORMANCE, f), path.join(tmp, f));
  const corrupt = bytes.slice();
  corrupt[binStart + stream[K - 1].offset + stream[K - 1].length - 1] ^= 0x40; // the last chunk's digest differs
  fs.writeFileSync(path.join(tmp, 'corrupt-last.pmw'), corrupt);
  fs.writeFileSync(path.join(tmp, 'trailing.pmw'), Buffer.concat([bytes, Buffer.from('JUNKJUNK')]));
  servers.ranges = await startServer(tmp);
  servers.plain = await startServer(tmp, { ranges: false });
});
after(async () => {
  await servers.ranges.close();
  await servers.plain.close();
  fs.rmSync(tmp, { recursive: true, force: true });
});

function theMesh(gltf) {
  let mesh = null;
  gltf.scene.traverse((o) => { if (o.isMesh) mesh = o; });
  return mesh;
}

/** The drawn level of `gltf`'s mesh: {vertices, positions, indices}. */
function drawn(gltf) {
  const g = theMesh(gltf).geometry;
  const level = g.userData.pmwmLevel;
  if (!level) return { vertices: g.getAttribute('position').count, base: true };
  return { vertices: level.vertices, positions: g.getAttribute('position').array.slice(0, level.vertices * 3),
    indices: g.index.array.slice(0, g.drawRange.count) };
}

const settle = (promise, ms) => Promise.race([promise.then((v) => ({ value: v }), (e) => ({ error: e })),
  new Promise((r) => setTimeout(() => r('pending'), ms))]);

for (const kind of ['ranges', 'plain']) {
  test(`a corrupt last chunk (${kind}): the last good level stays drawn, its events fired, done rejects with the error`, async () => {
    const good = await decodePmw(bytes, { chunks: K - 1 });
    const events = [];
    const gltf = await loadProgressive(new GLTFLoader(), `${servers[kind].url}corrupt-last.pmw`, {
      onBase: (e) => events.push(`B${e.chunk}`), onChunk: (e) => events.push(e.chunk), onDone: () => events.push('D') });
    await assert.rejects(gltf.userData.pmwm.done, (e) => e instanceof CorruptChunkError && e.chunk === K);
    assert.deepEqual(events, ['B0', ...Array.from({ length: K - 1 }, (_, i) => i + 1)]);
    const d = drawn(gltf);
    assert.equal(d.vertices, good.positions.length / 3);
    assert.deepEqual(d.positions, good.positions);
    assert.deepEqual(d.indices, good.indices);
  });
}

test('stop() right after loadProgressive resolves: the base stays, done resolves {complete: false, chunksApplied: 0}, onDone is called', async () => {
  const base = await decodePmw(bytes, { chunks: 0 });
  for (const [kind, query] of [['ranges', ''], ['plain', ''], ['plain', '?stall=100000']]) {
    const done = [];
    const gltf = await loadProgressive(new GLTFLoader(), `${servers[kind].url}${NAME}${query}`, { onDone: (o) => done.push(o) });
    gltf.userData.pmwm.stop();
    const outcome = await gltf.userData.pmwm.done;
    assert.equal(outcome.complete, false, kind + query);
    assert.equal(outcome.chunksApplied, 0, kind + query);
    assert.equal(outcome.levels, 1, kind + query);
    assert.equal(outcome.stopped, true, kind + query);
    assert.deepEqual(done, [outcome], kind + query);
    assert.deepEqual(drawn(gltf).positions, base.positions, kind + query);
  }
});

test('stop() aborts the request in flight: done settles at once on a stalled stream, the drawn level kept', async () => {
  const stalled = `${servers.plain.url}${NAME}?stall=${baseEnd + 200}`; // the base, then nothing more
  const gltf = await loadProgressive(new GLTFLoader(), stalled, {});
  await new Promise((r) => setTimeout(r, 100));
  const t0 = Date.now();
  gltf.userData.pmwm.stop();
  const out = await settle(gltf.userData.pmwm.done, 2000);
  assert.notEqual(out, 'pending', 'done did not settle after stop()');
  assert.ok(Date.now() - t0 < 1000);
  assert.equal(out.value.chunksApplied, 0);
  assert.equal(out.value.stopped, true);
  assert.equal(drawn(gltf).vertices, (await decodePmw(bytes, { chunks: 0 })).positions.length / 3);
});

test('an AbortSignal already aborted rejects loadProgressive at once with its reason, fetching nothing', async () => {
  const requests = servers.ranges.stats.requests;
  const controller = new AbortController();
  controller.abort();
  await assert.rejects(loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { signal: controller.signal }),
    { name: 'AbortError' });
  const reason = new Error('navigated away');
  await assert.rejects(loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { signal: AbortSignal.abort(reason) }),
    (e) => e === reason);
  assert.equal(servers.ranges.stats.requests, requests);
});

test('an AbortSignal aborted mid-stream stops the run promptly (done resolves, the level drawn kept); during the base load it rejects', async () => {
  const controller = new AbortController();
  const gltf = await loadProgressive(new GLTFLoader(), `${servers.plain.url}${NAME}?stall=${baseEnd + 200}`,
    { signal: controller.signal });
  await new Promise((r) => setTimeout(r, 100));
  controller.abort();
  const out = await settle(gltf.userData.pmwm.done, 2000);
  assert.notEqual(out, 'pending', 'done did not settle after abort()');
  assert.equal(out.value.stopped, true);
  assert.equal(out.value.complete, false);
  assert.ok(drawn(gltf).vertices > 0);
  // aborted while the bytes before the first chunk are still coming: loadProgressive rejects with the reason
  const early = new AbortController();
  const loading = loadProgressive(new GLTFLoader(), `${servers.plain.url}${NAME}?stall=100`, { signal: early.signal });
  setTimeout(() => early.abort(), 100);
  const res = await settle(loading, 2000);
  assert.notEqual(res, 'pending');
  assert.equal(res.error?.name, 'AbortError');
});

test('stop() or an abort from onChunk draws no later level, even of the same streamed piece (the level stopped at stays, done says it)',
  async () => {
    // a streamed GET brings the whole file in one or two pieces: the decoder gives every chunk of a piece at once
    const at = 2;
    const level = await decodePmw(bytes, { chunks: at });
    for (const [how, kind] of [['stop', 'plain'], ['signal', 'plain'], ['stop', 'ranges']]) {
      const what = `${how} ${kind}`;
      const controller = new AbortController();
      const events = [];
      let run;
      const gltf = await loadProgressive(new GLTFLoader(), servers[kind].url + NAME, { signal: controller.signal,
        onChunk: (e) => {
          events.push(e.chunk);
          if (e.chunk === at) (how === 'stop' ? run.stop() : controller.abort());
        } });
      run = gltf.userData.pmwm;
      const outcome = await run.done;
      assert.deepEqual(events, [1, 2], what);
      assert.equal(outcome.stopped, true, what);
      assert.equal(outcome.complete, false, what);
      assert.equal(outcome.chunksApplied, at, what);
      assert.equal(outcome.levels, at + 1, what);
      const d = drawn(gltf);
      assert.deepEqual(d.positions, level.positions, what);
      assert.deepEqual(d.indices, level.indices, what);
    }
  });

test('Range answers shorter than asked: the rest is asked for, the load completes (no false truncation)', async () => {
  const full = await decodePmw(bytes);
  for (const cap of [7, 300, 1000]) {
    const gltf = await loadProgressive(new GLTFLoader(), `${servers.ranges.url}${NAME}?cap=${cap}`);
    const outcome = await gltf.userData.pmwm.done;
    assert.equal(outcome.complete, true, `cap ${cap}`);
    assert.equal(outcome.chunksApplied, K, `cap ${cap}`);
    assert.equal(outcome.bytesFetched, bytes.length, `cap ${cap}`);
    assert.deepEqual(drawn(gltf).positions, full.positions, `cap ${cap}`);
  }
  // a registered plugin reading by Range (three.js parsed only the base: the stream is read from the url)
  const loader = new GLTFLoader();
  loader.register((parser) => new PMWMProgressivePlugin(parser, { url: `${servers.ranges.url}${NAME}?cap=500` }));
  const gltf = await loader.parseAsync(baseGlb(bytes.subarray(0, baseEnd)).buffer, '');
  const outcome = await gltf.userData.pmwm.done;
  assert.equal(outcome.chunksApplied, K);
  assert.equal(outcome.bytesFetched, bytes.length);
});

test('a file with bytes after its GLB length is refused as the server sizes it (Content-Range, Content-Length): no level', async () => {
  // spec/README.md, Partial files: a reader told the size before the bytes may refuse at once; the plugin had shown
  // the file complete, its 8 extra bytes unread (Range) or read and ignored (one GET)
  for (const server of [servers.ranges, servers.plain]) {
    await assert.rejects(loadProgressive(new GLTFLoader(), `${server.url}trailing.pmw`, { range: server === servers.ranges }),
      (e) => e instanceof FormatError && /GLB: 8 bytes after the declared file length \d+/.test(e.message));
    const gltf = await loadProgressive(new GLTFLoader(), `${server.url}${NAME}`, { range: server === servers.ranges });
    assert.equal((await gltf.userData.pmwm.done).complete, true); // (the same file without them: whole)
  }
});

test('HTTP errors and network failures are FetchError (status, url, cause), not FormatError or a raw TypeError', async () => {
  const url404 = servers.ranges.url + 'no-such.pmw';
  await assert.rejects(loadProgressive(new GLTFLoader(), url404),
    (e) => e instanceof FetchError && e instanceof PmwError && !(e instanceof FormatError) && e.status === 404 && e.url === url404);
  await assert.rejects(loadProgressive(new GLTFLoader(), `${servers.ranges.url}${NAME}?fail=1`),
    (e) => e instanceof FetchError && e.status === 500);
  // a 500 on a request for the rest of a short answer (300 bytes each), two after the base: the levels before stay
  const toBase = 1 + Math.ceil((binStart - 20) / 300) + Math.ceil((baseEnd - binStart) / 300);
  const gltf = await loadProgressive(new GLTFLoader(), `${servers.ranges.url}${NAME}?cap=300&fail=${toBase + 2}`);
  await assert.rejects(gltf.userData.pmwm.done, (e) => e instanceof FetchError && e.status === 500);
  assert.ok(drawn(gltf).vertices > 0);
  // the connection dropped mid-body: during the base load, then after it
  await assert.rejects(loadProgressive(new GLTFLoader(), `${servers.plain.url}${NAME}?cut=100`),
    (e) => e instanceof FetchError && e.status === undefined && e.cause instanceof Error);
  for (const kind of ['plain', 'ranges']) { // by Range: in the answer that holds the base and every chunk
    const chunks = [];
    const cut = await loadProgressive(new GLTFLoader(), `${servers[kind].url}${NAME}?cut=${chunkEnd(2) + 10}`,
      { onChunk: (e) => chunks.push(e.chunk) });
    await assert.rejects(cut.userData.pmwm.done, (e) => e instanceof FetchError && e.status === undefined, kind);
    assert.deepEqual(chunks, [1, 2], `${kind}: the levels before the cut drawn`);
    assert.deepEqual(drawn(cut).positions, (await decodePmw(bytes, { chunks: 2 })).positions, kind);
  }
  // a fetch that cannot connect at all
  await assert.rejects(loadProgressive(new GLTFLoader(), 'http://127.0.0.1:1/x.pmw'), FetchError);
});

test('a registered plugin with a fixed url refines a whole file from its own bytes, a base from the url if the same document', async () => {
  const url = servers.ranges.url + NAME;
  const loader = new GLTFLoader();
  loader.register((parser) => new PMWMProgressivePlugin(parser, { url }));
  const requests = servers.ranges.stats.requests;
  const first = await loader.parseAsync(bytes.slice().buffer, ''); // three.js holds the whole file
  assert.equal((await first.userData.pmwm.done).complete, true);
  const otherBytes = new Uint8Array(fs.readFileSync(path.join(tmp, OTHER)));
  const whole = await loader.parseAsync(otherBytes.slice().buffer, ''); // another whole file, the same loader
  assert.equal((await whole.userData.pmwm.done).complete, true);
  assert.deepEqual(drawn(whole).positions, (await decodePmw(otherBytes)).positions);
  assert.equal(servers.ranges.stats.requests, requests, 'the stream of a whole file is not read from the url');
  // three.js given only the other file's base: its stream is read from the url, which holds another document
  const other = await loader.parseAsync(baseGlb(otherBytes.subarray(0, endOfBase(otherBytes))).buffer, '');
  const before = theMesh(other).geometry.getAttribute('position').array.slice();
  await assert.rejects(other.userData.pmwm.done, (e) => e instanceof StreamMismatchError && e.url === url);
  const g = theMesh(other).geometry;
  assert.equal(g.userData.pmwmLevel, undefined, 'no level of the other stream was drawn');
  assert.deepEqual(g.getAttribute('position').array, before, 'left as three.js loaded it');
  assert.equal(g.getAttribute('position').count, (await decodePmw(otherBytes, { chunks: 0 })).positions.length / 3);
});

test('a server that stops sending (connection open, no bytes) fails the load after stallTimeout with a FetchError naming the URL and the seconds, the levels decoded kept',
  async () => {
    const cases = [ // [server, the file's bytes sent before the stall, the level then drawn]
      ['plain', baseEnd + 200, 0], // a streamed GET: in chunk 1
      ['ranges', chunkEnd(2) + 10, 2], // Range requests: in chunk 3, in the request for all after the JSON
    ];
    for (const [kind, stall, level] of cases) {
      const url = `${servers[kind].url}${NAME}?stall=${stall}`;
      const expected = await decodePmw(bytes, { chunks: level });
      const chunks = [];
      const gltf = await loadProgressive(new GLTFLoader(), url, { stallTimeout: 300, onChunk: (e) => chunks.push(e.chunk) });
      const t0 = Date.now();
      const out = await settle(gltf.userData.pmwm.done, 5000);
      assert.notEqual(out, 'pending', `${kind}: done did not settle on a stalled stream`);
      assert.ok(Date.now() - t0 < 3000, kind);
      const e = out.error;
      assert.ok(e instanceof FetchError && e.url === url && e.status === undefined, `${kind}: ${e}`);
      assert.ok(e.message.includes(url) && e.message.includes('0.3 s'), e.message);
      assert.deepEqual(chunks, [...Array(level)].map((_, i) => i + 1), kind);
      assert.deepEqual(drawn(gltf).positions, expected.positions, kind);
    }
    // stalled before the base is in: loadProgressive itself rejects
    const early = `${servers.plain.url}${NAME}?stall=100`;
    const res = await settle(loadProgressive(new GLTFLoader(), early, { stallTimeout: 300 }), 5000);
    assert.ok(res.error instanceof FetchError && res.error.url === early && res.error.message.includes('0.3 s'), String(res.error));
  });

test('stallTimeout defaults to 30 s, 0 waits for ever (until stop()), and anything but a number >= 0 is a RangeError', async () => {
  assert.equal(STALL_TIMEOUT_MS, 30000);
  const gltf = await loadProgressive(new GLTFLoader(), `${servers.plain.url}${NAME}?stall=${baseEnd + 200}`, { stallTimeout: 0 });
  assert.equal(await settle(gltf.userData.pmwm.done, 800), 'pending');
  gltf.userData.pmwm.stop();
  assert.equal((await gltf.userData.pmwm.done).stopped, true);
  for (const stallTimeout of [-1, NaN, '30000', null]) {
    await assert.rejects(loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { stallTimeout }), RangeError);
  }
});

test('byteBudget and maxGeometricError other than a number >= 0 are a RangeError before anything is fetched, by either way in', async () => {
  const requests = [];
  const fetch = (url, init) => { requests.push(url); return globalThis.fetch(url, init); };
  const bad = [{ byteBudget: 'abc' }, { byteBudget: NaN }, { byteBudget: -1 }, { byteBudget: '4000' }, { byteBudget: null },
    { maxGeometricError: 'x' }, { maxGeometricError: NaN }, { maxGeometricError: -0.5 }];
  for (const stops of bad) {
    await assert.rejects(loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { ...stops, fetch }), RangeError, JSON.stringify(stops));
    const loader = new GLTFLoader();
    loader.register((parser) => new PMWMProgressivePlugin(parser, { url: servers.ranges.url + NAME, ...stops, fetch }));
    await assert.rejects(loader.parseAsync(baseGlb(bytes.subarray(0, baseEnd)).buffer, ''), RangeError, JSON.stringify(stops));
  }
  assert.deepEqual(requests, []);
  // the edges are valid stops: 0 bytes gives the base, Infinity every chunk; an error of Infinity is met by chunk 1, 0 by the last
  for (const [stops, applied] of [[{ byteBudget: 0 }, 0], [{ byteBudget: Infinity }, K], [{ maxGeometricError: Infinity }, 1],
    [{ maxGeometricError: 0 }, K]]) {
    const gltf = await loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, stops);
    assert.equal((await gltf.userData.pmwm.done).chunksApplied, applied, JSON.stringify(stops));
  }
});

test('a maxChunks (or chunks) other than a whole number >= 0 is one RangeError naming it before anything is fetched, by either way in', async () => {
  const requests = [];
  const fetch = (url, init) => { requests.push(url); return globalThis.fetch(url, init); };
  const bad = [[{ maxChunks: -1 }, 'maxChunks', '-1'], [{ maxChunks: NaN }, 'maxChunks', 'NaN'], [{ maxChunks: '2' }, 'maxChunks', '"2"'],
    [{ maxChunks: 1.5 }, 'maxChunks', '1.5'], [{ chunks: -1 }, 'chunks', '-1']];
  for (const [stops, name, text] of bad) {
    const error = { name: 'RangeError', message: `${name} must be a whole number >= 0 (or Infinity), not ${text}` };
    await assert.rejects(loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { ...stops, fetch }), error);
    const loader = new GLTFLoader();
    loader.register((parser) => new PMWMProgressivePlugin(parser, { url: servers.ranges.url + NAME, ...stops, fetch }));
    await assert.rejects(loader.parseAsync(baseGlb(bytes.subarray(0, baseEnd)).buffer, ''), error);
  }
  await assert.rejects(loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { maxChunks: 2, chunks: 3, fetch }),
    { name: 'RangeError', message: /maxChunks 2 and chunks 3 differ/ });
  assert.deepEqual(requests, []);
  const gltf = await loadProgressive(new GLTFLoader(), servers.ranges.url + NAME, { chunks: 2 }); // decodePmw's name: the same stop
  assert.equal((await gltf.userData.pmwm.done).chunksApplied, 2);
});

test('a callback that throws is reported (onCallbackError) and the load goes on to the full mesh', async () => {
  const full = await decodePmw(bytes);
  for (const kind of ['ranges', 'plain']) {
    const reported = [];
    const chunks = [];
    const boom = (where) => () => { throw new Error(where); };
    const gltf = await loadProgressive(new GLTFLoader(), servers[kind].url + NAME, {
      onBase: boom('base'), onChunk: (e) => { chunks.push(e.chunk); if (e.chunk === 3) throw new Error('chunk 3'); },
      onDone: boom('done'), onCallbackError: (e) => reported.push(e.message) });
    const outcome = await gltf.userData.pmwm.done;
    assert.equal(outcome.complete, true, kind);
    assert.equal(chunks.length, K, kind);
    assert.deepEqual(reported, ['base', 'chunk 3', 'done'], kind);
    assert.deepEqual(drawn(gltf).positions, full.positions, kind);
  }
});
