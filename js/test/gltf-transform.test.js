/**
 * PMWMProgressiveMesh keeps a .pmw's progressive stream through glTF-Transform read() + write():
 * the extension object and every chunk's stored bytes survive, the chunks are written after all
 * other bufferViews, 4-aligned, in stream order, and our decoder gives the same mesh at every level.
 * A changed base mesh (or a Draco base about to be re-encoded) makes the write throw.
 */
import assert from 'node:assert/strict';
import { existsSync, mkdtempSync, readdirSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { spawnSync } from 'node:child_process';
import { after, test } from 'node:test';
import { Extension, NodeIO } from '@gltf-transform/core';
import { KHRDracoMeshCompression } from '@gltf-transform/extensions';
import draco3d from 'draco3d';
import { PMWMProgressiveMesh, BaseMeshChangedError, checkPmwHeader } from 'pmwm-progressive/gltf-transform';
import { writePmwAsGlb } from 'pmwm-progressive/gltf-transform.config.mjs';
import { FormatError, LimitError, MAX_JSON_DEPTH, PmwDecoder, TruncatedError, UnsupportedError } from '../src/index.js';
import { chunkEntries, parseGlb } from '../src/header.js';
import { CONFORMANCE, conformanceFiles, levelDigest } from './lib/helpers.js';
import { withJson } from './lib/rewrite.js';
import { decodeFiles, python, ROOT } from './lib/python.js';

const NAME = 'PMWM_progressive_mesh';
const CHECK_GLTF = join(ROOT, 'tools', 'js', 'check_gltf.mjs');
const VALIDATOR = join(ROOT, 'tools', 'js', 'node_modules', 'gltf-validator');

const load = (file) => new Uint8Array(readFileSync(join(CONFORMANCE, file)));

/** The GLB's JSON and BIN payload. */
function glbParts(bytes) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jsonLength = view.getUint32(12, true);
  const json = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  return { json, bin: bytes.subarray(28 + jsonLength) };
}

/** [{meshIndex, primitiveIndex, ext, chunks: Uint8Array[]}] of every progressive primitive; `ext.chunks`
 * as per-chunk entries (a payload version 2 chunk table expanded, spec/bitstream.md §6.2). */
function streams(bytes) {
  const { json, bin } = glbParts(bytes);
  return json.meshes.flatMap((mesh, meshIndex) => mesh.primitives.flatMap((p, primitiveIndex) => {
    const stored = p.extensions?.[NAME];
    if (!stored) return [];
    const entries = chunkEntries(stored, stored.payload?.version ?? 1, json.accessors[p.attributes.POSITION].count);
    const ext = { ...stored, chunks: entries };
    const chunks = ext.chunks.map((c) => {
      const start = (json.bufferViews[c.bufferView].byteOffset ?? 0) + (c.byteOffset ?? 0);
      return bin.subarray(start, start + c.byteLength);
    });
    return [{ meshIndex, primitiveIndex, ext, chunks }];
  }));
}

/** Per progressive primitive: 'entries' (payload version 1), 'packed' or 'arrays' (version 2 tables, spec/bitstream.md §6.2). */
const tableForms = (bytes) => glbParts(bytes).json.meshes.flatMap((m) => m.primitives.map((p) => p.extensions?.[NAME]?.chunks))
  .filter(Boolean).map((c) => (Array.isArray(c) ? 'entries' : 'packed' in c ? 'packed' : 'arrays'));

const withoutViews = (ext) => ({ ...ext, chunks: ext.chunks.map(({ bufferView, byteOffset, ...entry }) => entry) });

async function levels(bytes) {
  const decoder = new PmwDecoder({ snapshots: true });
  const results = await decoder.feed(bytes);
  assert.equal((await decoder.close()).complete, true);
  return results.map((r) => ({ vertices: r.vertexCount, faces: r.faceCount, digest: levelDigest(r.mesh) }));
}

/** The rewrite keeps the stream: same objects, same chunk bytes, chunks last, same decoded levels. */
async function assertStreamKept(original, rewritten) {
  const before = streams(original), after = streams(rewritten);
  assert.deepEqual(after.map((s) => withoutViews(s.ext)), before.map((s) => withoutViews(s.ext)));
  assert.deepEqual(tableForms(rewritten), tableForms(original), 'each chunk table keeps its form (packed or arrays)');
  after.forEach((s, i) => s.chunks.forEach((bytes, k) => assert.deepEqual(bytes, before[i].chunks[k], `chunk ${k}`)));
  const { json } = glbParts(rewritten);
  const chunkViews = new Set(after.flatMap((s) => s.ext.chunks.map((c) => c.bufferView)));
  const ends = json.bufferViews.filter((_, i) => !chunkViews.has(i)).map((v) => (v.byteOffset ?? 0) + v.byteLength);
  const offsetOf = (s, k) => json.bufferViews[s.ext.chunks[k].bufferView].byteOffset + (s.ext.chunks[k].byteOffset ?? 0);
  const stream = after.flatMap((s) => s.chunks.map((_, k) => offsetOf(s, k))).sort((a, b) => a - b);
  assert.ok(stream[0] >= Math.max(...ends), 'chunks come after every other bufferView');
  for (const i of chunkViews) assert.equal(json.bufferViews[i].byteOffset % 4, 0, 'chunk bufferViews start at a multiple of 4');
  assert.deepEqual(json.extensionsUsed.includes(NAME), true);
  assert.equal((json.extensionsRequired ?? []).includes(NAME), false);
  assert.deepEqual(await levels(rewritten), await levels(original));
}

for (const file of ['sphere-attributes.plain.v1.pmw', 'grid-hole.plain.v1.pmw']) {
  test(`${file}: read + write through glTF-Transform keeps the stream and decodes to the same levels`, async () => {
    const original = load(file);
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    const rewritten = await io.writeBinary(await io.readBinary(original));
    await assertStreamKept(original, rewritten);
    // and a second round trip is a fixed point
    assert.deepEqual(await io.writeBinary(await io.readBinary(rewritten)), rewritten);
  });
}

test('a rewritten base is tightly packed (one bufferView per vertex attribute) and the reference decoder gives the same levels',
  async () => {
    const original = load('sphere-attributes.plain.v1.pmw'); // POSITION, NORMAL, TEXCOORD_0: interleaved by default
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    const rewritten = await io.writeBinary(await io.readBinary(original));
    const { json } = glbParts(rewritten);
    const SIZES = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };
    for (const [semantic, index] of Object.entries(json.meshes[0].primitives[0].attributes)) {
      const accessor = json.accessors[index];
      const stride = json.bufferViews[accessor.bufferView].byteStride;
      assert.ok(stride === undefined || stride === 4 * SIZES[accessor.type], `${semantic}: byteStride ${stride}`);
    }
    if (!python()) return; // pmwm_codec refuses an interleaved base accessor
    const dir = mkdtempSync(join(tmpdir(), 'pmw-gltf-transform-'));
    try {
      writeFileSync(join(dir, 'out.pmw'), rewritten);
      const [reference] = decodeFiles([join(dir, 'out.pmw')]);
      assert.equal(reference.error, undefined);
      assert.deepEqual(reference.levels.map((l) => l.sha256), (await levels(original)).map((l) => l.digest));
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
  });

test('the Khronos validator finds no error in a rewritten file (skipped without tools/js/node_modules)',
  { skip: !existsSync(VALIDATOR) && 'gltf-validator not installed in tools/js' }, async () => {
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    const rewritten = await io.writeBinary(await io.readBinary(load('sphere-attributes.plain.v1.pmw')));
    const dir = mkdtempSync(join(tmpdir(), 'pmw-gltf-transform-'));
    try {
      writeFileSync(join(dir, 'out.pmw'), rewritten);
      const run = spawnSync(process.execPath, [CHECK_GLTF, join(dir, 'out.pmw')], { encoding: 'utf8' });
      assert.equal(run.status, 0, run.stderr);
      assert.equal(JSON.parse(run.stdout).validator.errors, 0, run.stdout);
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
  });

test('a transform that changes a progressive base mesh makes write() throw BaseMeshChangedError', async () => {
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const doc = await io.readBinary(load('sphere-attributes.plain.v1.pmw'));
  const indices = doc.getRoot().listMeshes()[0].listPrimitives()[0].getIndices();
  const swapped = indices.getArray().slice();
  [swapped[0], swapped[1]] = [swapped[1], swapped[0]];   // one flipped triangle: counts unchanged
  indices.setArray(swapped);
  await assert.rejects(io.writeBinary(doc), (e) => e instanceof BaseMeshChangedError && e.mesh === 0 && e.primitive === 0);
  // without the extension on the primitive the document writes as a plain glTF
  doc.getRoot().listMeshes()[0].listPrimitives()[0].setExtension(NAME, null);
  const plain = glbParts(await io.writeBinary(doc)).json;
  assert.equal(plain.bufferViews.length, 2);
  assert.equal(JSON.stringify(plain.meshes).includes(NAME), false);
});

test('an attribute added to a progressive base (the stream has no value of it for a new vertex) makes write() throw BaseMeshChangedError',
  async () => {
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    const doc = await io.readBinary(load('sphere-attributes.plain.v1.pmw'));
    const primitive = doc.getRoot().listMeshes()[0].listPrimitives()[0];
    const count = primitive.getAttribute('POSITION').getCount();
    primitive.setAttribute('TANGENT', doc.createAccessor().setType('VEC4').setArray(new Float32Array(4 * count))
      .setBuffer(doc.getRoot().listBuffers()[0]));
    await assert.rejects(io.writeBinary(doc), BaseMeshChangedError);
  });

// bowtie.welded-draco: a Draco base stored with copies of its non-manifold vertices; written plain, the
// copies stay and readers still weld them (spec/README.md "Welded base"); kissing.welded-draco: its weld
// attribute (_PMWM_WELD) is written plain too, and still keeps the distinct vertices on one point apart
// uv-torus-*.welded-draco: a Draco base carrying attributes (TEXCOORD_0, COLOR_0, _FEATURE_ID_0) and its weld
// attribute, written plain: a welded plain base with attributes (the second with plane prediction, §8.4.3)
for (const file of ['two-primitives.draco.v1.pmw', 'bowtie.welded-draco.packed.v2.pmw', 'kissing.welded-draco.packed.v2.pmw',
  'uv-torus-attributes.welded-draco.packed.v2.pmw', 'uv-torus-plane.welded-draco.packed.v2.pmw']) test(`${file}: re-encoding the Draco base is refused, a plain base keeps the stream`, async () => {
  const original = load(file);
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh, KHRDracoMeshCompression])
    .registerDependencies({
      'draco3d.decoder': await draco3d.createDecoderModule(), 'draco3d.encoder': await draco3d.createEncoderModule(),
    });
  const doc = await io.readBinary(original);
  await assert.rejects(io.writeBinary(doc), BaseMeshChangedError);
  doc.getRoot().listExtensionsUsed().find((e) => e.extensionName === 'KHR_draco_mesh_compression').dispose();
  const rewritten = await io.writeBinary(doc);
  assert.equal(glbParts(rewritten).json.extensionsUsed.includes('KHR_draco_mesh_compression'), false);
  await assertStreamKept(original, rewritten);
});

// The real glTF-Transform command line (node_modules/.bin/gltf-transform, a pinned devDependency) with
// the package's configuration file (gltf-transform.config.mjs): `copy` keeps every chunk of the stream.
const PACKAGE = join(ROOT, 'js');
const CLI = join(PACKAGE, 'node_modules', '.bin', 'gltf-transform');
const CONFIG = join(PACKAGE, 'gltf-transform.config.mjs');

/** Runs `gltf-transform ARGS --config gltf-transform.config.mjs`: {status, stdout, stderr}. */
const gltfTransform = (...args) => spawnSync(CLI, [...args, '--config', CONFIG], { encoding: 'utf8', timeout: 120000 });

// payload version 2 files too (chunks stored raw, spec/bitstream.md §8; chunk tables packed and in arrays, §6.2)
const COPIED = ['sphere-attributes.plain.v1.pmw', 'two-primitives.draco.v1.pmw', 'bowtie.welded-draco.packed.v2.pmw',
  'kissing.welded-draco.packed.v2.pmw', 'uv-torus-plane.welded-draco.packed.v2.pmw',
  ...conformanceFiles(2).filter((f) => f.startsWith('two-primitives'))];
const copies = mkdtempSync(join(tmpdir(), 'pmw-gltf-transform-cli-'));
after(() => rmSync(copies, { recursive: true, force: true }));

test('gltf-transform copy in.pmw out.pmw (CLI, our config) writes one GLB holding every chunk byte for byte, in order', async () => {
  for (const file of COPIED) {
    const run = gltfTransform('copy', join(CONFORMANCE, file), join(copies, file));
    assert.equal(run.status, 0, run.stdout + run.stderr);
    assert.deepEqual(readdirSync(copies).filter((f) => !f.endsWith('.pmw')), [], 'one GLB, no separate .bin');
    await assertStreamKept(load(file), new Uint8Array(readFileSync(join(copies, file))));
  }
});

test('the Khronos validator reports 0 errors / 0 warnings on what gltf-transform copy wrote (skipped without tools/js/node_modules)',
  { skip: !existsSync(VALIDATOR) && 'gltf-validator not installed in tools/js' }, () => {
    const outputs = COPIED.map((file) => join(copies, file));
    for (const [i, out] of outputs.entries()) {
      if (!existsSync(out)) assert.equal(gltfTransform('copy', join(CONFORMANCE, COPIED[i]), out).status, 0);
    }
    const check = spawnSync(process.execPath, [CHECK_GLTF, ...outputs], { encoding: 'utf8' });
    assert.equal(check.status, 0, check.stderr);
    const reports = check.stdout.trim().split('\n').map((line) => JSON.parse(line));
    assert.equal(reports.length, outputs.length);
    for (const { file, validator } of reports) {
      assert.deepEqual([validator.errors, validator.warnings], [0, 0], `${file}: ${JSON.stringify(validator.messages)}`);
    }
  });

test('gltf-transform weld of a .pmw (CLI, our config) fails with BaseMeshChangedError and writes nothing', () => {
  const dir = mkdtempSync(join(tmpdir(), 'pmw-gltf-transform-cli-'));
  try {
    const run = gltfTransform('weld', join(CONFORMANCE, 'sphere-attributes.plain.v1.pmw'), join(dir, 'out.pmw'));
    assert.notEqual(run.status, 0);
    assert.match(run.stdout + run.stderr, /base mesh of a PMWM_progressive_mesh primitive changed/);  // the CLI logs to stdout
    assert.deepEqual(readdirSync(dir), []);
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

for (const file of ['grid-hole.plain.v1.pmw', 'sphere-attributes.plain.packed.v2.pmw']) {
  test(`${file}: a progressive primitive two meshes share (mesh.clone()) is written with chunks of its own in each`, async () => {
    const original = load(file);
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    const document = await io.readBinary(original);
    const copy = document.getRoot().listMeshes()[0].clone(); // shares its primitives
    document.getRoot().listScenes()[0].addChild(document.createNode('copy').setMesh(copy));
    const decoder = new PmwDecoder();
    await decoder.feed(await io.writeBinary(document)); // was: 'chunks overlap each other or the base meshes'
    assert.equal((await decoder.close()).complete, true);
    const [full] = (await levels(original)).slice(-1);
    const { parts } = decoder.snapshot();
    assert.equal(parts.length, 2);
    for (const part of parts) assert.equal(levelDigest({ ...part, parts: [part] }), full.digest);
  });
}

test('reading a stream the decoder refuses fails with the decoder\'s named error (never a chunk read short or a TypeError)', async () => {
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const v1 = load('grid-hole.plain.v1.pmw');
  const v2 = load('grid-hole.plain.packed.v2.pmw');
  const ext = (gltf) => gltf.meshes[0].primitives[0].extensions[NAME];
  const cases = [
    ['a chunk in no bufferView', v1, (g) => { ext(g).chunks[0].bufferView = 999; }, FormatError],
    ['a chunk longer than its bufferView', v1, (g) => { ext(g).chunks[0].byteLength += 1000; }, FormatError],
    ['a chunk entry that is null', v1, (g) => { ext(g).chunks[1] = null; }, FormatError],
    ['a chunk table in no bufferView', v2, (g) => { ext(g).chunks.bufferView = 999; }, FormatError],
    ['chunks past the end of their bufferView', v2, (g) => { ext(g).chunks.byteOffsets = Array(ext(g).chunks.count).fill(1e6); }, FormatError],
    ['a newer extension version', v2, (g) => { ext(g).version = 2; }, UnsupportedError],
    ['an unknown payload version', v2, (g) => { ext(g).payload.version = 3; }, UnsupportedError],
  ];
  for (const [what, source, edit, Kind] of cases) {
    const bytes = withJson(source, edit);
    const decoder = new PmwDecoder();
    await assert.rejects(decoder.feed(bytes), Kind, `decoder: ${what}`);
    await assert.rejects(io.readBinary(bytes), Kind, what);
  }
});

test('a stream dropped from every primitive is written as a plain glTF that read() takes back', async () => {
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const document = await io.readBinary(load('grid-hole.plain.v1.pmw'));
  for (const mesh of document.getRoot().listMeshes()) for (const p of mesh.listPrimitives()) p.setExtension(NAME, null);
  const plain = await io.writeBinary(document);
  assert.equal((glbParts(plain).json.extensionsUsed ?? []).includes(NAME), false);
  await io.readBinary(plain);
});

test('writing with a meshopt compression extension in the document throws BaseMeshChangedError (a compressed base reads nowhere)', async () => {
  // EXT_meshopt_compression as the document sees it (the real one also needs meshoptimizer's encoder)
  class Meshopt extends Extension { static EXTENSION_NAME = 'EXT_meshopt_compression'; extensionName = 'EXT_meshopt_compression'; read() { return this; } write() { return this; } }
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh, Meshopt]);
  const document = await io.readBinary(load('grid-hole.plain.v1.pmw'));
  document.createExtension(Meshopt).setRequired(true);
  await assert.rejects(io.writeBinary(document), (e) => e instanceof BaseMeshChangedError && /EXT_meshopt_compression/.test(e.message));
});

test('writing a progressive document as JSON + .bin (a .gltf) is a FormatError: the stream lives in a GLB\'s BIN chunk', async () => {
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const document = await io.readBinary(load('grid-hole.plain.v1.pmw'));
  await assert.rejects(io.writeJSON(document), (e) => e instanceof FormatError && /GLB/.test(e.message));
  for (const mesh of document.getRoot().listMeshes()) for (const p of mesh.listPrimitives()) p.setExtension(NAME, null);
  await io.writeJSON(document); // without the stream: a plain .gltf
});

test('the README\'s round trip writes a .pmw; io.write(\'out.pmw\') (NodeIO: JSON + .bin for any name but .glb) is refused, writing nothing, unless writePmwAsGlb', async () => {
  const dir = mkdtempSync(join(tmpdir(), 'pmw-gltf-transform-'));
  try {
    writeFileSync(join(dir, 'in.pmw'), load('grid-hole.plain.v1.pmw'));
    const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
    writeFileSync(join(dir, 'out.pmw'), await io.writeBinary(await io.read(join(dir, 'in.pmw')))); // the README's example
    assert.deepEqual(await levels(readFileSync(join(dir, 'out.pmw'))), await levels(load('grid-hole.plain.v1.pmw')));
    await assert.rejects(io.write(join(dir, 'json.pmw'), await io.read(join(dir, 'in.pmw'))), FormatError);
    assert.deepEqual(readdirSync(dir).sort(), ['in.pmw', 'out.pmw']);
    await writePmwAsGlb(io).write(join(dir, 'glb.pmw'), await io.read(join(dir, 'in.pmw')));
    assert.deepEqual(await levels(readFileSync(join(dir, 'glb.pmw'))), await levels(load('grid-hole.plain.v1.pmw')));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
});

test('read() refuses, with the decoder\'s named error, what it can see of the JSON checks and a bad base view before glTF-Transform reads it; checkPmwHeader refuses the rest on the bytes', async () => {
  const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
  const v1 = load('grid-hole.plain.v1.pmw');
  const text = (bytes, edit) => { // the JSON text edited as text (JSON.stringify writes neither 1e999 nor a BOM)
    const h = parseGlb(bytes);
    const json = edit(new TextEncoder().encode(JSON.stringify(h.gltf)));
    const padded = new Uint8Array((json.length + 3) & ~3).fill(0x20);
    padded.set(json);
    const bin = bytes.subarray(h.binStart - 8);
    const out = new Uint8Array(20 + padded.length + bin.length);
    out.set(bytes.subarray(0, 20));
    out.set(padded, 20);
    out.set(bin, 20 + padded.length);
    new DataView(out.buffer).setUint32(8, out.length, true);
    new DataView(out.buffer).setUint32(12, padded.length, true);
    return out;
  };
  const replace = (from, to) => (json) => new TextEncoder().encode(new TextDecoder().decode(json).replace(from, to));
  const position = (g) => g.accessors[g.meshes[0].primitives[0].attributes.POSITION];
  const seen = [ // [what, bytes, the decoder's error], refused by read() too
    ['1e999', text(v1, replace('"mesh":0', '"mesh":0,"extras":1e999')), FormatError],
    ['JSON nested 65 deep', text(v1, replace('"mesh":0', `"mesh":0,"extras":${'['.repeat(MAX_JSON_DEPTH - 2)}${']'.repeat(MAX_JSON_DEPTH - 2)}`)), LimitError],
    ['POSITION in buffer 1 (glTF-Transform: TypeError)', withJson(v1, (g) => { g.bufferViews[position(g).bufferView].buffer = 1; }), FormatError],
    ['POSITION stride 16, past its view (glTF-Transform: RangeError)', withJson(v1, (g) => { g.bufferViews[position(g).bufferView].byteStride = 16; }), FormatError],
  ];
  for (const [what, bytes, Kind] of seen) {
    await assert.rejects(new PmwDecoder().feed(bytes), Kind, `decoder: ${what}`);
    assert.throws(() => checkPmwHeader(bytes), Kind, `checkPmwHeader: ${what}`);
    await assert.rejects(io.readBinary(bytes), (e) => e instanceof Kind && e.constructor === Kind, what);
  }
  const unseen = [ // glTF-Transform's TextDecoder drops a BOM and replaces invalid UTF-8: read() never sees them (js/README.md)
    ['a byte order mark', text(v1, (json) => new Uint8Array([0xef, 0xbb, 0xbf, ...json]))],
    ['invalid UTF-8 in a string', text(v1, (json) => { const at = new TextDecoder().decode(json).indexOf('"pmwm_codec"') + 1; const out = json.slice(); out[at] = 0xff; return out; })],
  ];
  for (const [what, bytes] of unseen) {
    await assert.rejects(new PmwDecoder().feed(bytes), FormatError, `decoder: ${what}`);
    assert.throws(() => checkPmwHeader(bytes), FormatError, `checkPmwHeader: ${what}`);
    await io.readBinary(bytes); // the limit js/README.md states
  }
  checkPmwHeader(v1); // a valid file passes
});

test('checkPmwHeader refuses bytes that end before the JSON and BIN chunk headers with a TruncatedError, as the decoder does', async () => {
  const v1 = load(conformanceFiles().find((f) => f.endsWith('.v1.pmw')));
  const jsonEnd = 28 + new DataView(v1.buffer, v1.byteOffset).getUint32(12, true);
  for (const n of [0, 10, 19, 20, 30, jsonEnd - 1]) {
    const prefix = v1.slice(0, n);
    const decoder = new PmwDecoder();
    await decoder.feed(prefix);
    await assert.rejects(decoder.close(), TruncatedError); // the decoder's kind for a stream this short
    assert.throws(() => checkPmwHeader(prefix), (e) => e instanceof TruncatedError && e.bytesReceived === n
      && e.bytesNeeded === (n < 20 ? 20 : jsonEnd), `checkPmwHeader: ${n} bytes`);
  }
  const bad = v1.slice(0, 24);
  bad[0] = 0; // the preamble's own checks still come first
  assert.throws(() => checkPmwHeader(bad), FormatError);
});
