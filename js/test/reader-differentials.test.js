/**
 * Bytes the Python reader (pmwm_codec) and this one read differently, found by a differential run of both over
 * mutated files (helper-126): each case here was accepted by this reader and refused by the reference one. The
 * Python side's cases are in tests/test_reader_differentials.py. The sources are conformance files.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError, PmwDecoder, decodePmw } from '../src/index.js';
import { parseGlb } from '../src/header.js';
import { CONFORMANCE, jsLevels, levelDigest } from './lib/helpers.js';
import { decodeFiles, python } from './lib/python.js';
import { chunkPayloads, withPayload } from './lib/rewrite.js';

/** The file `name` with change(gltf) applied to its JSON (the BIN kept as it is). */
function rewrite(name, change) {
  const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, name)));
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jsonLength = view.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  const bin = bytes.subarray(20 + jsonLength);  // BIN chunk header and payload
  change(gltf);
  const json = new TextEncoder().encode(JSON.stringify(gltf));
  const padded = new Uint8Array(json.length + ((4 - (json.length % 4)) % 4)).fill(0x20);
  padded.set(json);
  const out = new Uint8Array(20 + padded.length + bin.length);
  const dv = new DataView(out.buffer);
  out.set(bytes.subarray(0, 12)); dv.setUint32(8, out.length, true);
  dv.setUint32(12, padded.length, true); out.set(bytes.subarray(16, 20), 16);
  out.set(padded, 20); out.set(bin, 20 + padded.length);
  return out;
}

const PLAIN = 'sphere-attributes.plain.v1.pmw';               // plain base: NORMAL, TEXCOORD_0
const DRACO = 'uv-torus-attributes.welded-draco.v1.pmw';      // Draco base: COLOR_0, TEXCOORD_0, _FEATURE_ID_0, weld

test('the sources and their rewrites without a change decode', async () => {
  for (const name of [PLAIN, DRACO]) await decodePmw(rewrite(name, () => {}));
});

/**
 * A base accessor's componentType or type that is no JSON number / string but names one as an object key does:
 * "5123" and [5123] (a one-element array's key is its element) were looked up in the reader's tables of types
 * and found, so a file the Python reader refuses decoded here (spec/README.md, Kinds of refusal: a member of
 * the wrong JSON type is a format error).
 */
test('a base accessor componentType or type given as a string or a one-element array is a FormatError', async () => {
  const cases = [];
  for (const name of [PLAIN, DRACO]) {
    for (const which of ['POSITION', 'indices', 'TEXCOORD_0']) {
      for (const field of ['componentType', 'type']) {
        for (const wrap of [(v) => String(v), (v) => [v]]) {
          if (field === 'type' && typeof wrap('x') === 'string') continue; // "VEC3" is the valid form
          cases.push({ name, which, field, wrap });
        }
      }
    }
  }
  for (const { name, which, field, wrap } of cases) {
    const changed = rewrite(name, (gltf) => {
      const prim = gltf.meshes[0].primitives[0];
      const acc = gltf.accessors[which === 'indices' ? prim.indices : prim.attributes[which]];
      acc[field] = wrap(acc[field]);
    });
    await assert.rejects(decodePmw(changed), FormatError, `${name} ${which} ${field}`);
  }
});

// --- bytes after the GLB's declared length (spec/README.md, Partial files): the cases of
// tests/test_reader_differentials.py::test_bytes_after_the_declared_length_come_after_every_level_and_are_refused_once

const load = (name) => new Uint8Array(readFileSync(join(CONFORMANCE, name)));
const concat = (...parts) => {
  const out = new Uint8Array(parts.reduce((a, p) => a + p.length, 0));
  let at = 0;
  for (const p of parts) { out.set(p, at); at += p.length; }
  return out;
};
const pieces = (bytes, size) => {
  const out = [];
  for (let i = 0; i < bytes.length; i += size) out.push(bytes.subarray(i, i + size));
  return out;
};
/** What a level is, independent of how the bytes were split. */
const level = (r) => [r.chunk, r.bytesRead, r.vertexCount, r.faceCount, levelDigest(r.mesh)].join(' ');

/** [how, pieces] of clean + extra, split in every way the spec names (as _splits in the Python test). */
function splits(clean, extra, lastChunkEnd) {
  const data = concat(clean, extra);
  const out = [['whole', [data]]];
  for (const size of [1, 3, 7, 64, 509, 4096]) out.push([`pieces of ${size}`, pieces(data, size)]);
  const start = lastChunkEnd - 5; // the last chunk's end and the extra bytes together
  out.push(['with the last chunk', [data.subarray(0, start), data.subarray(start)]]);
  out.push(['later', [clean, extra]]);
  out.push(['later, split', [clean, ...pieces(extra, 2)]]);
  out.push(['later, after an empty feed', [clean, new Uint8Array(0), extra]]);
  return out;
}

test('bytes after the declared length come after every level and are refused once, however the bytes are split', async () => {
  const extras = { zeros: new Uint8Array(4), text: new TextEncoder().encode('JUNKJUNKJUNK'), glb: load(PLAIN).subarray(0, 24) };
  for (const name of [PLAIN, DRACO, 'sphere-attributes.plain.v2.pmw', 'bowtie.welded-draco.packed.v2.pmw']) {
    const clean = load(name);
    const total = clean.length;
    const reference = new PmwDecoder({ snapshots: true });
    const expected = (await reference.feed(clean)).map(level);
    assert.ok((await reference.close()).complete);
    const lastChunkEnd = Number(expected.at(-1).split(' ')[1]);
    for (const [kind, extra] of Object.entries(extras)) {
      for (const [how, parts] of splits(clean, extra, lastChunkEnd)) {
        const what = `${name} ${kind} ${how}`;
        const d = new PmwDecoder({ snapshots: true });
        const levels = [];
        let error = null;
        let at = -1;
        let received = 0;
        let over = null;
        for (let i = 0; i <= parts.length; i++) { // i === parts.length: close()
          received += i < parts.length ? parts[i].length : 0;
          if (over === null && received > total) over = [i, received - total];
          try {
            if (i < parts.length) levels.push(...(await d.feed(parts[i])));
            else await d.close();
          } catch (e) {
            error = e;
            at = i;
            break;
          }
        }
        assert.ok(error instanceof FormatError && over !== null, what);
        assert.deepEqual(levels.map(level), expected, what);
        assert.ok(at === over[0] || at === over[0] + 1, `${what}: refused by the feed that brought them, or the next call`);
        assert.equal(error.message, `GLB: ${over[1]} bytes after the declared file length ${total}`, what);
        assert.equal(d.error, error, what);
        if (at < parts.length) await assert.rejects(d.feed(new Uint8Array(0)), (e) => e === error, what);
        await assert.rejects(d.close(), (e) => e === error, what);
      }
    }
  }
});

/**
 * Version 1 chunk `payload` whose first split's first attribute residual (column attribute_0: the Draco source's
 * COLOR_0 red, an srgb8 byte) moves 256 away from zero (zigzag + 512), the column rewritten 4 bytes a value: the
 * new vertex's byte, its prediction (0..255) plus the residual, lies outside 0..255. `D`: residual columns.
 */
function colourPushedOut(payload, D) {
  const dv = new DataView(payload.buffer, payload.byteOffset, payload.byteLength);
  const B = dv.getUint32(0, true);
  let K = 0;
  let I = 0;
  for (let j = 0; j < B; j++) { K += dv.getUint32(4 + 8 * j, true); I += dv.getUint32(8 + 8 * j, true); }
  let at = 4 + 8 * B;
  const skip = (count) => { const start = at; at += 1 + payload[at] * count; return start; };
  skip(K); skip(Math.ceil(I / 3));
  for (let d = 0; d < 3; d++) skip(K);
  const start = skip(K); // attribute_0
  const w = payload[start];
  const values = Array.from({ length: K }, (_, i) => {
    let z = 0;
    for (let b = 0; b < w; b++) z += payload[start + 1 + b * K + i] * 2 ** (8 * b);
    return z;
  });
  values[0] += 512;
  const column = new Uint8Array(1 + 4 * K);
  column[0] = 4;
  for (let i = 0; i < K; i++) for (let b = 0; b < 4; b++) column[1 + b * K + i] = Math.floor(values[i] / 2 ** (8 * b)) & 255;
  assert.equal(D, 3 + 6, 'the source keeps its attributes');
  return new Uint8Array([...payload.subarray(0, start), ...column, ...payload.subarray(at)]);
}

/**
 * A chunk whose payload (behind a valid digest) gives a new vertex an srgb8 colour byte outside 0..255 (spec/README.md,
 * attributes: transfer): this reader applied it and every chunk after it, and only a snapshot refused the byte
 * ("COLOR_0: a colour's sRGB byte lies outside 0..255", without the chunk; with no snapshot the file decoded). Now
 * the chunk is refused as it is applied, as any chunk whose payload is invalid: the levels before it delivered,
 * the chunk undone (a snapshot after the failure is the last good level), one FormatError naming the chunk and the
 * attribute; the reference reader gives the same levels and the same error.
 */
test('an srgb8 byte outside 0..255 refuses the chunk that brings it, after the levels before it, as the reference reader', async () => {
  const CHUNK = 3;
  const clean = new Uint8Array(readFileSync(join(CONFORMANCE, DRACO)));
  const { payload } = chunkPayloads(clean)[CHUNK - 1];
  const bad = withPayload(clean, CHUNK - 1, colourPushedOut(payload, 9));
  const want = (await jsLevels(clean)).levels.slice(0, CHUNK).map((l) => l.sha256);
  const message = new RegExp(`^chunk ${CHUNK}: COLOR_0: sRGB byte -?\\d+ lies outside 0\\.\\.255$`);
  for (const snapshots of [true, false]) {
    for (const size of [bad.length, 509, 64]) {
      const d = new PmwDecoder({ snapshots });
      const levels = [];
      let error = null;
      try {
        for (let at = 0; at < bad.length; at += size) levels.push(...await d.feed(bad.subarray(at, at + size)));
        await d.close();
      } catch (e) {
        error = e;
      }
      assert.ok(error instanceof FormatError && message.test(error.message), `${size}: ${error}`);
      assert.equal(levels.length, CHUNK, `${size}`);
      if (snapshots) assert.deepEqual(levels.map((r) => levelDigest(r.mesh)), want, `${size}`);
      assert.equal(levelDigest(d.snapshot()), want[CHUNK - 1], `${size}: the chunk is undone`);
    }
  }
  if (!python()) return;
  const dir = mkdtempSync(join(tmpdir(), 'pmw-srgb8-'));
  try {
    const file = join(dir, 'bad.pmw');
    writeFileSync(file, bad);
    const [py] = decodeFiles([file]);
    assert.equal(py.error, 'FormatError');
    assert.match(py.message, message);
    assert.deepEqual(py.levels.map((l) => l.sha256), want);
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

// --- chunk bytes that other data shares (spec/bitstream.md §4): the cases of tests/test_chunk_bytes_unshared.py

const EXT = 'PMWM_progressive_mesh';
/** The bufferView of the last chunk of the first progressive primitive. */
const chunkView = (gltf) => {
  const { chunks } = gltf.meshes[0].primitives[0].extensions[EXT];
  return Array.isArray(chunks) ? chunks[chunks.length - 1].bufferView : chunks.bufferView;
};
/** Appends a 100-byte bufferView over the last 200 to 100 bytes of the chunk bufferView; returns its index. */
const viewInsideTheChunks = (gltf) => {
  const view = gltf.bufferViews[chunkView(gltf)];
  gltf.bufferViews.push({ buffer: 0, byteOffset: (view.byteOffset ?? 0) + view.byteLength - 200, byteLength: 100 });
  return gltf.bufferViews.length - 1;
};
const SHARED = {
  'another bufferView': [(gltf) => { viewInsideTheChunks(gltf); }, /bufferViews\[\d+\] shares bytes with bufferView \d+, which holds chunks/],
  "an image's bufferView": [(gltf) => { gltf.images = [{ bufferView: viewInsideTheChunks(gltf), mimeType: 'image/png' }]; },
    /bufferViews\[\d+\] shares bytes with bufferView \d+, which holds chunks/],
  'an image': [(gltf) => { gltf.images = [{ bufferView: chunkView(gltf), mimeType: 'image/png' }]; },
    /images\[0\] reads bufferView \d+, which holds chunks/],
  'an accessor': [(gltf) => { gltf.accessors.push({ bufferView: chunkView(gltf), componentType: 5126, count: 4, type: 'SCALAR' }); },
    /accessors\[\d+\] reads bufferView \d+, which holds chunks/],
  'sparse values': [(gltf) => {
    gltf.accessors.push({ componentType: 5126, count: 4, type: 'SCALAR', sparse: { count: 1,
      indices: { bufferView: 0, componentType: 5123 }, values: { bufferView: chunkView(gltf) } } });
  }, /accessors\[\d+\]\.sparse\.values reads bufferView \d+, which holds chunks/],
};

/**
 * Both readers accepted a file whose chunk bytes another bufferView (an image's, an accessor's ...) shares, and
 * `pmw cut` then zeroed those bytes of the chunks it dropped: the other data silently changed. A FormatError in
 * both readers now; the chunk table bufferView two primitives share stays valid.
 */
test('chunk bytes that other data shares are a FormatError in both readers', async () => {
  const names = ['sphere-attributes.plain.v1.pmw', 'sphere-attributes.plain.v2.pmw', 'sphere-attributes.plain.packed.v2.pmw',
    'sphere-pillows.draco.packed.v2.pmw'];
  const files = [];
  for (const name of names) {
    for (const [label, [change, message]] of Object.entries(SHARED)) {
      const bytes = rewrite(name, change);
      await assert.rejects(decodePmw(bytes), (e) => e instanceof FormatError && message.test(e.message), `${name}: ${label}`);
      files.push(bytes);
    }
  }
  for (const name of ['two-primitives.draco.packed.v2.pmw', 'two-primitives.draco.v2.pmw']) {
    const { gltf } = parseGlb(load(name));
    assert.equal(new Set(gltf.meshes[0].primitives.map((p) => p.extensions[EXT].chunks.bufferView)).size, 1, name);
    assert.ok((await decodePmw(load(name))).chunksApplied > 0, name);
  }
  if (!python()) return;
  const dir = mkdtempSync(join(tmpdir(), 'pmwm-shared-chunks-'));
  try {
    const paths = files.map((bytes, i) => { const p = join(dir, `${i}.pmw`); writeFileSync(p, bytes); return p; });
    decodeFiles(paths).forEach((r, i) => assert.equal(r.error, 'FormatError', `${paths[i]}: the reference reader (${r.message})`));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

/**
 * Cut inside the JSON, the reference reader named the JSON's end (20 + J) as the bytes needed, this one 28 + J
 * (where the BIN data, and the base in it, starts): two lower bounds, two numbers. Both name the same now
 * (spec/README.md, Partial files): 20 in the preamble, 28 + J up to the BIN data, then the base meshes' end.
 */
test('a stream cut before its base mesh names the same bytes needed in both readers', async () => {
  const bytes = load('sphere-pillows.draco.packed.v2.pmw');
  const J = new DataView(bytes.buffer, bytes.byteOffset).getUint32(12, true);
  const { levels } = await jsLevels(bytes);
  const baseEnd = levels[0].bytesRead;
  const cuts = [[0, 20], [10, 20], [19, 20], [20, 28 + J], [21, 28 + J], [19 + J, 28 + J], [20 + J, 28 + J],
    [27 + J, 28 + J], [28 + J, baseEnd], [baseEnd - 1, baseEnd]];
  for (const [n, needed] of cuts) {
    const d = new PmwDecoder();
    await d.feed(bytes.subarray(0, n));
    await assert.rejects(d.close(), (e) => e.name === 'TruncatedError' && e.bytesReceived === n && e.bytesNeeded === needed,
      `cut at ${n}: this reader`);
  }
  if (!python()) return;
  const dir = mkdtempSync(join(tmpdir(), 'pmwm-needed-'));
  try {
    const paths = cuts.map(([n]) => { const p = join(dir, `${n}.pmw`); writeFileSync(p, bytes.subarray(0, n)); return p; });
    decodeFiles(paths).forEach((r, i) => assert.deepEqual([r.error, r.bytesNeeded], ['TruncatedError', cuts[i][1]],
      `cut at ${cuts[i][0]}: the reference reader (${r.message})`));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

/**
 * `ownerFrame` (spec/README.md, Properties; the owner layer's stated frame): this reader does not use it, but
 * checks its form as the Python reader's schema does, so that both refuse the same files.
 */
test('a malformed ownerFrame is a FormatError, a well-formed one decodes', async () => {
  const good = { center: [0.5, -1, 2], inner: 0.25, width: 0.01 };
  await decodePmw(rewrite(PLAIN, (gltf) => { gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh.ownerFrame = good; }));
  const bad = [
    [{ center: [0, 0], inner: 1, width: 0.1 }, /center/], [{ center: [0, 0, 0], inner: 1, width: 0 }, /width/],
    [{ center: [0, 0, 0], inner: '1', width: 0.1 }, /inner/], [{ center: [0, 0, 0], width: 0.1 }, /inner/],
    [[0, 0, 0, 1, 0.1], /ownerFrame/],
  ];
  for (const [value, what] of bad) {
    const changed = rewrite(PLAIN, (gltf) => { gltf.meshes[0].primitives[0].extensions.PMWM_progressive_mesh.ownerFrame = value; });
    await assert.rejects(decodePmw(changed), (e) => e instanceof FormatError && what.test(e.message), JSON.stringify(value));
  }
});
