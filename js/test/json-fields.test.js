/**
 * The JSON fields of a .pmw that both readers check: one field of a conformance file changed at a
 * time (the BIN kept) is a FormatError of this decoder, and the Python reference reader refuses the
 * same file (when a Python with pmwm_codec is found), so the two agree on what a valid file is
 * (spec/README.md and its schema).
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError } from '../src/index.js';
import { CONFORMANCE, failure } from './lib/helpers.js';
import { decodeFiles, python } from './lib/python.js';
import { withJson } from './lib/rewrite.js';

const load = (f) => new Uint8Array(readFileSync(join(CONFORMANCE, f)));
const EXT = 'PMWM_progressive_mesh';
const prim0 = (gltf) => gltf.meshes[0].primitives[0];

/**
 * Every case [label, file, mutate(gltf, prim, ext), message pattern] is a FormatError matching its
 * pattern here and an error of the reference reader; the unchanged files decode in both.
 */
async function bothRefuse(cases) {
  const files = [...new Set(cases.map(([, file]) => file))];
  const edited = cases.map(([label, file, mutate]) => withJson(load(file), (gltf) => mutate(gltf, prim0(gltf), prim0(gltf).extensions[EXT])));
  for (const [i, [label, , , pattern]] of cases.entries()) {
    const e = await failure(edited[i]);
    assert.ok(e instanceof FormatError && pattern.test(e.message), `${label}: ${e?.name}: ${e?.message}`);
  }
  for (const file of files) assert.equal(await failure(load(file)), null, `${file} decodes`);
  if (!python()) return;
  const dir = mkdtempSync(join(tmpdir(), 'pmwm-json-fields-'));
  try {
    const paths = edited.map((bytes, i) => { const p = join(dir, `${i}.pmw`); writeFileSync(p, bytes); return p; });
    decodeFiles(paths).forEach((r, i) => assert.ok(r.error, `${cases[i][0]}: the reference reader decodes it`));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
}

test('a Draco base\'s accessors declare what the Draco data decodes to: indices required, counts and types checked', async () => {
  const file = 'sphere-pillows.draco.v1.pmw';
  const acc = (gltf, prim, key) => gltf.accessors[key === 'indices' ? prim.indices : prim.attributes.POSITION];
  await bothRefuse([
    ['no indices', file, (g, p) => { delete p.indices; }, /indices: accessor undefined does not exist/],
    ['indices out of range', file, (g, p) => { p.indices = 999; }, /accessor 999 does not exist/],
    ['indices a string', file, (g, p) => { p.indices = '1'; }, /does not exist/],
    ['indices the POSITION accessor', file, (g, p) => { p.indices = p.attributes.POSITION; }, /indices: accessor \d+ has the wrong type/],
    ['indices VEC3', file, (g, p) => { acc(g, p, 'indices').type = 'VEC3'; }, /wrong type/],
    ['indices FLOAT', file, (g, p) => { acc(g, p, 'indices').componentType = 5126; }, /wrong type/],
    ['index count not a multiple of 3', file, (g, p) => { acc(g, p, 'indices').count += 1; }, /not a multiple of 3/],
    ['index count 3 more than decoded', file, (g, p) => { acc(g, p, 'indices').count += 3; }, /Draco decoded .* accessors declare/],
    ['index count missing', file, (g, p) => { delete acc(g, p, 'indices').count; }, /count/],
    ['POSITION count 1 more than decoded', file, (g, p) => { acc(g, p, 'POSITION').count += 1; }, /Draco decoded .* accessors declare/],
    ['POSITION UNSIGNED_SHORT', file, (g, p) => { acc(g, p, 'POSITION').componentType = 5123; }, /POSITION: accessor \d+ has the wrong type/],
    ['POSITION VEC4', file, (g, p) => { acc(g, p, 'POSITION').type = 'VEC4'; }, /wrong type/],
    ['POSITION index a string', file, (g, p) => { p.attributes.POSITION = String(p.attributes.POSITION); }, /does not exist/],
  ]);
});

test('a welded base\'s weld attribute (_PMWM_WELD) is an unnormalized UNSIGNED_BYTE or UNSIGNED_SHORT SCALAR of every stored vertex, with baseVertexCount', async () => {
  const file = 'kissing.welded-draco.packed.v2.pmw';
  const weld = (gltf, prim) => gltf.accessors[prim.attributes._PMWM_WELD];
  await bothRefuse([
    ['without baseVertexCount', file, (g, p, e) => { delete e.baseVertexCount; }, /_PMWM_WELD without baseVertexCount/],
    ['VEC2', file, (g, p) => { weld(g, p).type = 'VEC2'; }, /_PMWM_WELD: accessor \d+ has the wrong type/],
    ['FLOAT', file, (g, p) => { weld(g, p).componentType = 5126; }, /wrong type/],
    ['normalized', file, (g, p) => { weld(g, p).normalized = true; }, /_PMWM_WELD: normalized/],
    ['one value more than the stored vertices', file, (g, p) => { weld(g, p).count += 1; }, /values for \d+ stored vertices/],
    ['dropped: the distinct vertices on one point weld into one', file, (g, p) => { delete p.attributes._PMWM_WELD; },
      /welding gives \d+ vertices, baseVertexCount says/],
    ['no Draco id', file, (g, p) => { delete p.extensions.KHR_draco_mesh_compression.attributes._PMWM_WELD; }, /Draco attribute ids missing/],
  ]);
});

test('the copies a weld joins carry the same attribute values: a Draco base with attributes whose weld attribute is dropped is refused', async () => {
  const file = 'uv-torus-attributes.welded-draco.packed.v2.pmw';
  const drop = (g, p) => { delete p.attributes._PMWM_WELD; delete p.extensions.KHR_draco_mesh_compression.attributes._PMWM_WELD; };
  await bothRefuse([
    // welded by position alone, the seams' copies (other texture coordinates, other colours) would join
    ['weld attribute dropped', file, drop, /copies the weld joins carry different attribute values/],
    ['a Draco attribute id missing', file, (g, p) => { delete p.extensions.KHR_draco_mesh_compression.attributes.COLOR_0; },
      /Draco attribute ids missing/],
  ]);
});

test('a Draco base\'s attribute accessors are checked as a plain base\'s, and name the type of the Draco data', async () => {
  const file = 'uv-torus-attributes.welded-draco.packed.v2.pmw';
  const acc = (g, p, semantic) => g.accessors[p.attributes[semantic]];
  await bothRefuse([
    ['TEXCOORD_0 VEC3', file, (g, p) => { acc(g, p, 'TEXCOORD_0').type = 'VEC3'; }, /TEXCOORD_0: accessor \d+ has the wrong type/],
    ['TEXCOORD_0 one value more', file, (g, p) => { acc(g, p, 'TEXCOORD_0').count += 1; }, /TEXCOORD_0: \d+ values for \d+ stored vertices/],
    ['TEXCOORD_0 normalized', file, (g, p) => { acc(g, p, 'TEXCOORD_0').normalized = true; }, /must not be normalized/],
    // FLOAT is a type a plain base may store it with; the Draco data holds unsigned shorts
    ['_FEATURE_ID_0 FLOAT over unsigned shorts', file, (g, p) => { acc(g, p, '_FEATURE_ID_0').componentType = 5126; },
      /the Draco _FEATURE_ID_0 holds data of componentType 5123, its accessor says 5126/],
    ['_PMWM_WELD UNSIGNED_SHORT over bytes', file, (g, p) => { acc(g, p, '_PMWM_WELD').componentType = 5123; },
      /the Draco _PMWM_WELD holds data of componentType 5121, its accessor says 5123/],
  ]);
});

test('an attribute\'s prediction is "plane", and with chunk payload version 2 only', async () => {
  const file = 'uv-torus-plane.welded-draco.packed.v2.pmw';
  const v1 = 'uv-torus-attributes.welded-draco.v1.pmw';
  await bothRefuse([
    ['another prediction', file, (g, p, e) => { e.attributes[0].prediction = 'mean'; }, /prediction must be 'plane'/],
    ['a prediction that is not a string', file, (g, p, e) => { e.attributes[0].prediction = 1; }, /prediction must be 'plane'/],
    ['plane with payload version 1', v1, (g, p, e) => { e.attributes[0].prediction = 'plane'; }, /prediction with chunk payload version 1/],
  ]);
});

test('the extension\'s fields this decoder does not otherwise read have the form the schema gives them', async () => {
  const v1 = 'sphere.exact-watermark.v1.pmw';
  const arrays = 'sphere.exact-watermark.v2.pmw';
  const packed = 'grid-hole.plain.packed.v2.pmw';
  const wm = (key, value) => (g, p, e) => { if (value === undefined) delete e.watermark[key]; else e.watermark[key] = value; };
  await bothRefuse([
    ['baseMac a number', v1, (g, p, e) => { e.baseMac = 7; }, /baseMac must be 32 lowercase hex digits/],
    ['baseMac upper case', v1, (g, p, e) => { e.baseMac = 'A'.repeat(32); }, /baseMac must be/],
    ['baseMac 31 digits', packed, (g, p, e) => { e.baseMac = 'a'.repeat(31); }, /baseMac must be/],
    ['baseMac null', packed, (g, p, e) => { e.baseMac = null; }, /baseMac must be/],
    ['sceneMac a number', v1, (g, p, e) => { e.sceneMac = 7; }, /sceneMac must be 32 lowercase hex digits/],
    ['sceneMac 31 digits', packed, (g, p, e) => { e.sceneMac = 'a'.repeat(31); }, /sceneMac must be/],
    ['baseDigest a number', packed, (g, p, e) => { e.baseDigest = 7; }, /baseDigest must be 16 lowercase hex digits/],
    ['baseDigest upper case', packed, (g, p, e) => { e.baseDigest = 'A'.repeat(16); }, /baseDigest must be/],
    ['baseDigest 32 digits', v1, (g, p, e) => { e.baseDigest = 'a'.repeat(32); }, /baseDigest must be/],
    ['baseDigest null', packed, (g, p, e) => { e.baseDigest = null; }, /baseDigest must be/],
    ['chunk mac upper case', v1, (g, p, e) => { e.chunks[0].mac = 'A'.repeat(32); }, /chunks\[0\]: mac must be/],
    ['chunk mac a number', v1, (g, p, e) => { e.chunks[1].mac = 0; }, /chunks\[1\]: mac must be/],
    ['table macs upper case', arrays, (g, p, e) => { e.chunks.macs = e.chunks.macs.toUpperCase(); }, /chunks: macs must be/],
    ['batches 0', v1, (g, p, e) => { e.chunks[0].batches = 0; }, /batches must be an integer >= 1/],
    ['batches a string', v1, (g, p, e) => { e.chunks[0].batches = '1'; }, /batches must be/],
    ['fileId a number', packed, (g, p, e) => { e.fileId = 1; }, /fileId must be a string/],
    ['extensions an array', packed, (g, p, e) => { e.extensions = []; }, /extensions must be an object/],
    ['grid extensions a string', packed, (g, p, e) => { e.grid.extensions = 'x'; }, /grid: extensions must be an object/],
    ['table extensions null', packed, (g, p, e) => { e.chunks.extensions = null; }, /chunks: extensions must be an object/],
    ['watermark an array', packed, (g, p, e) => { e.watermark = []; }, /watermark must be an object/],
    ['watermark without mode', v1, wm('mode'), /watermark: mode must be/],
    ['watermark mode other', v1, wm('mode', 'other'), /watermark: mode must be/],
    ['watermark bits 17', v1, wm('bits', 17), /watermark: bits must be/],
    ['watermark scale 0', v1, wm('scale', 0), /watermark: scale must be/],
    ['watermark width 1.5', v1, wm('width', 1.5), /watermark: width must be/],
    ['watermark without height', v1, wm('height'), /watermark: height must be/],
    ['watermark levels -1', v1, wm('levels', -1), /watermark: levels must be/],
    ['watermark codes a string', v1, wm('codes', '8'), /watermark: codes must be/],
    ['watermark carriers over MAX_VERTICES (a LimitError)', v1, wm('carriers', 2 ** 40), /watermark: carriers \d+ is over the limit/],
    ['watermark embedFrom -1', v1, wm('embedFrom', -1), /watermark: embedFrom must be/],
    ['watermark binding other', v1, wm('binding', 'ring-v3'), /watermark: binding must be/],
    ['watermark keyFingerprint a number', v1, wm('keyFingerprint', 1), /watermark: keyFingerprint must be/],
    ['watermark layout a string', v1, wm('layout', 'x'), /watermark: layout must be/],
  ]);
});

test('a JSON null is no value of an optional member: not its default but an error, as for the reference reader', async () => {
  const plain = 'grid-hole.plain.packed.v2.pmw';
  const attributes = 'sphere-attributes.plain.packed.v2.pmw';
  await bothRefuse([
    ['primitive mode null', plain, (g, p) => { p.mode = null; }, /mode is not TRIANGLES/],
    ['bufferView byteOffset null', plain, (g) => { g.bufferViews[0].byteOffset = null; }, /bufferView 0 lies outside buffer 0/],
    ['bufferView buffer null', plain, (g) => { g.bufferViews[1].buffer = null; }, /bufferView 1 lies outside buffer 0/],
    ['accessor byteOffset null', plain, (g, p) => { g.accessors[p.indices].byteOffset = null; }, /does not fit its bufferView/],
    ['chunk table byteOffsets null', plain, (g, p, e) => { e.chunks.byteOffsets = null; }, /do not all describe/],
    ['attributes null', plain, (g, p, e) => { e.attributes = null; }, /attributes is not an array/],
    ['payload null', attributes, (g, p, e) => { e.payload = null; }, /payload is not an object/],
  ]);
});

test('the extension must be listed in extensionsUsed (spec/README.md)', async () => {
  const file = 'grid-hole.plain.packed.v2.pmw';
  await bothRefuse([
    ['extensionsUsed missing', file, (g) => { delete g.extensionsUsed; }, /is not listed in extensionsUsed/],
    ['extensionsUsed without it', file, (g) => { g.extensionsUsed = g.extensionsUsed.filter((x) => x !== EXT); }, /is not listed in extensionsUsed/],
    ['extensionsUsed a string', file, (g) => { g.extensionsUsed = EXT; }, /is not listed in extensionsUsed/],
  ]);
});

test('a JSON chunk that begins with a byte order mark is a FormatError (spec/README.md, Conformance)', async () => {
  const bytes = load('grid-hole.plain.packed.v2.pmw');
  const J = new DataView(bytes.buffer, bytes.byteOffset).getUint32(12, true);
  const text = new Uint8Array([0xef, 0xbb, 0xbf, ...bytes.subarray(20, 20 + J)]);
  const json = new Uint8Array((text.length + 3) & ~3).fill(0x20);
  json.set(text);
  const marked = new Uint8Array(bytes.length - J + json.length);
  marked.set(bytes.subarray(0, 20));
  marked.set(json, 20);
  marked.set(bytes.subarray(20 + J), 20 + json.length);
  const dv = new DataView(marked.buffer);
  dv.setUint32(8, marked.length, true);
  dv.setUint32(12, json.length, true);
  const e = await failure(marked);
  assert.ok(e instanceof FormatError && /not valid UTF-8 JSON/.test(e.message), String(e));
  if (python()) {
    const dir = mkdtempSync(join(tmpdir(), 'pmwm-json-fields-'));
    try {
      writeFileSync(join(dir, 'bom.pmw'), marked);
      assert.ok(decodeFiles([join(dir, 'bom.pmw')])[0].error, 'the reference reader refuses it');
    } finally {
      rmSync(dir, { recursive: true, force: true });
    }
  }
});

test('a bufferView\'s byteStride, where given, is a multiple of 4 in 4..252 (the glTF schema), on a chunk\'s view too', async () => {
  const file = 'sphere-pillows.draco.v1.pmw';
  const chunkView = (g, p, e) => g.bufferViews[e.chunks[0].bufferView];
  await bothRefuse([
    ['a chunk view with byteStride 2', file, (g, p, e) => { chunkView(g, p, e).byteStride = 2; }, /invalid byteStride/],
    ['a chunk view with byteStride 6', file, (g, p, e) => { chunkView(g, p, e).byteStride = 6; }, /invalid byteStride/],
    ['a chunk view with byteStride 256', file, (g, p, e) => { chunkView(g, p, e).byteStride = 256; }, /invalid byteStride/],
    ['a chunk view with byteStride "4"', file, (g, p, e) => { chunkView(g, p, e).byteStride = '4'; }, /invalid byteStride/],
  ]);
});

test('a base accessor whose bufferView\'s byteStride is shorter than its element (or strides indices) is refused, not read overlapping', async () => {
  const file = 'sphere-attributes.plain.packed.v2.pmw';
  const strideOf = (semantic, stride) => (g, p) => { g.bufferViews[g.accessors[semantic ? p.attributes[semantic] : p.indices].bufferView].byteStride = stride; };
  await bothRefuse([
    ['TEXCOORD_0 with byteStride 4', file, strideOf('TEXCOORD_0', 4), /byteStride 4 for 8-byte elements/],
    ['NORMAL with byteStride 8', file, strideOf('NORMAL', 8), /byteStride 8 for 12-byte elements/],
    ['indices with byteStride 8', file, strideOf(null, 8), /byteStride 8 for 2-byte elements/],
  ]);
});

test('the extension\'s vertexCount / faceCount are the counts its last chunk reaches: inflated ones are refused, not allocated', async () => {
  const file = 'sphere-pillows.draco.packed.v2.pmw';
  await bothRefuse([
    ['vertexCount 4,000,000', file, (g, p, e) => { e.vertexCount = 4000000; }, /differ from the \d+ \/ \d+ its last chunk reaches/],
    ['faceCount one more', file, (g, p, e) => { e.faceCount += 1; }, /differ from the \d+ \/ \d+ its last chunk reaches/],
  ]);
});
