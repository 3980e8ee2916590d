/**
 * The JSON chunk as both readers read it (spec/README.md, Conformance; the reference reader's twin tests
 * are tests/test_format_json.py): its nesting depth, integer members written as floats, and the named
 * error of each refusal. Every case is a conformance file with its JSON text edited; this decoder and the
 * reference reader (when a Python with pmwm_codec is found) must give the same outcome: the same
 * levels, or an error of the same kind.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError, MAX_JSON_DEPTH, PmwDecoder, PmwError } from '../src/index.js';
import { MAX_ATTRIBUTES } from '../src/constants.js';
import { jsonTooDeep } from '../src/header.js';
import { CONFORMANCE, jsOutcome } from './lib/helpers.js';
import { decodeFiles, python } from './lib/python.js';

const load = (f) => new Uint8Array(readFileSync(join(CONFORMANCE, f)));

/** The reference reader's error classes by the kind this decoder names them (src/errors.js). */
const KIND = { FormatError: 'FormatError', LimitError: 'LimitError', UnsupportedVersionError: 'UnsupportedError',
  ChecksumError: 'CorruptChunkError', TruncatedError: 'TruncatedError' };

/** `bytes` (a GLB) with its JSON text replaced by `edit(text)`, text being the compact JSON of its document. */
function withText(bytes, edit) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const J = dv.getUint32(12, true);
  const text = edit(JSON.stringify(JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + J)))));
  const json = new TextEncoder().encode(text);
  const padded = new Uint8Array((json.length + 3) & ~3).fill(0x20);
  padded.set(json);
  const bin = bytes.subarray(28 + J);
  const out = new Uint8Array(28 + padded.length + bin.length);
  out.set(bytes.subarray(0, 20));
  out.set(padded, 20);
  out.set(bytes.subarray(20 + J, 28 + J), 20 + padded.length);
  out.set(bin, 28 + padded.length);
  const odv = new DataView(out.buffer);
  odv.setUint32(8, out.length, true);
  odv.setUint32(12, padded.length, true);
  return out;
}

/** `bytes` with `nodes[0].extras` nested so that the document is `depth` levels deep (document 1, nodes 2, node 3). */
const nested = (bytes, depth) => withText(bytes, (t) => {
  const g = JSON.parse(t);
  g.nodes[0].extras = '@extras@';
  return JSON.stringify(g).replace('"@extras@"', '['.repeat(depth - 3) + ']'.repeat(depth - 3));
});

/** What a decoder made of a file, comparable across the two: an error kind, or the levels' digests. */
const jsView = (o) => (o instanceof PmwError ? o.name : o.levels.map((l) => l.sha256));
const pyView = (o) => (o.error ? (KIND[o.error] ?? `python ${o.error}`) : o.levels.map((l) => l.sha256));

/**
 * Every case [label, bytes, want] gives `want` here and in the reference reader: an error kind
 * ('LimitError', ...) or, for 'decodes', the levels of `original`.
 */
async function bothGive(original, cases) {
  const same = jsView(await jsOutcome(original));
  const wanted = cases.map(([, , want]) => (want === 'decodes' ? same : want));
  for (const [i, [label, bytes]] of cases.entries()) {
    assert.deepEqual(jsView(await jsOutcome(bytes)), wanted[i], `${label}: this decoder`);
  }
  if (!python()) return;
  const dir = mkdtempSync(join(tmpdir(), 'pmwm-json-chunk-'));
  try {
    const paths = cases.map(([, bytes], i) => { const p = join(dir, `${i}.pmw`); writeFileSync(p, bytes); return p; });
    decodeFiles(paths).forEach((r, i) => assert.deepEqual(pyView(r), wanted[i], `${cases[i][0]}: the reference reader`));
  } finally {
    rmSync(dir, { recursive: true, force: true });
  }
}

test('a JSON chunk nested deeper than MAX_JSON_DEPTH is a LimitError naming it, in both readers; to the limit it decodes', async () => {
  const file = load('grid-hole.plain.v2.pmw');
  const deep = await jsOutcome(nested(file, 3000));
  assert.equal(deep.name, 'LimitError');
  assert.match(deep.message, new RegExp(`more than ${MAX_JSON_DEPTH} levels deep \\(MAX_JSON_DEPTH\\)`));
  const open = '['.repeat(MAX_JSON_DEPTH);
  const close = ']'.repeat(MAX_JSON_DEPTH);
  const extras = (json) => (t) => `${t.slice(0, -1)},"extras":${json}}`;
  await bothGive(file, [
    ['nested 65 deep', nested(file, MAX_JSON_DEPTH + 1), 'LimitError'],
    ['nested 3000 deep (the reviver overflowed the stack)', nested(file, 3000), 'LimitError'],
    ['nested 100000 deep', nested(file, 100000), 'LimitError'],
    ['nested 64 deep', nested(file, MAX_JSON_DEPTH), 'decodes'],
    ['brackets in a string', withText(file, extras(`{"a":"${open}"}`)), 'decodes'],
    ['brackets after an escaped quote', withText(file, extras(`{"a":"\\"${open}"}`)), 'decodes'],
    ['brackets after an escaped backslash', withText(file, extras(`{"a":"\\\\","b":${open}${close}}`)), 'LimitError'],
  ]);
});

test('the depth scan: strings skipped as JSON has them, the outermost value level 1', () => {
  const scan = (text, limit) => jsonTooDeep(new TextEncoder().encode(text), limit);
  assert.equal(scan('[[]]', 2), false);
  assert.equal(scan('[[[]]]', 2), true);
  assert.equal(scan('{"a":[{}]}', 3), false);
  assert.equal(scan('{"a":[{"b":[]}]}', 3), true);
  assert.equal(scan('["[[[["]', 1), false);
  assert.equal(scan('["\\"[[[["]', 1), false);
  assert.equal(scan('["\\\\",[[[]]]]', 1), true);
  assert.equal(scan('[]]]][[', 1), false); // closers first: the running depth, as the reference scan has it
});

/** A number written as an integral float: `@float(16)` in an edited document becomes `16.0` in its text. */
const float = (n) => `@float:${n}`;
/** `bytes` with `change(gltf, primitive, extension)` applied to its document, `float(n)` values written `n.0`. */
const withFloats = (bytes, change) => withText(bytes, (t) => {
  const g = JSON.parse(t);
  const p = g.meshes[0].primitives[0];
  change(g, p, p.extensions.PMWM_progressive_mesh);
  return JSON.stringify(g).replace(/"@float:(-?\d+)"/g, '$1.0');
});
const floats = (obj, keys) => { for (const k of keys) if (obj[k] !== undefined) obj[k] = Array.isArray(obj[k]) ? obj[k].map(float) : float(obj[k]); };

test('an integer member written as an integral float (16.0, 1.6e1) is that integer in both readers (spec/README.md "JSON numbers")', async () => {
  const grid = load('grid-hole.plain.v2.pmw');
  const pillows = load('sphere-pillows.draco.packed.v2.pmw');
  const welded = load('bowtie.welded-draco.v1.pmw');
  const attributes = load('sphere-attributes.plain.v2.pmw');
  await bothGive(grid, [
    ['grid bits 16.0', withFloats(grid, (g, p, e) => floats(e.grid, ['bits'])), 'decodes'],
    ['version, payload version, counts', withFloats(grid, (g, p, e) => { floats(e, ['version', 'vertexCount', 'faceCount']); floats(e.payload, ['version']); }), 'decodes'],
    ['chunk table arrays', withFloats(grid, (g, p, e) => floats(e.chunks, ['bufferView', 'byteLengths', 'vertexCounts', 'faceCounts'])), 'decodes'],
    ['chunk table byteOffsets', withFloats(grid, (g, p, e) => {
      let at = 0;
      e.chunks.byteOffsets = e.chunks.byteLengths.map((n) => { const o = at; at += n; return float(o); });
    }), 'decodes'],
    ['scene and node mesh', withFloats(grid, (g) => { g.scene = float(g.scene ?? 0); for (const n of g.nodes) floats(n, ['mesh']); }), 'decodes'],
    ['grid bits 1.6e1, version 1e0', withText(grid, (t) => t.replace('"bits":16,', '"bits":1.6e1,').replace('"version":1,', '"version":1e0,')), 'decodes'],
    ['grid bits 16.5', withFloats(grid, (g, p, e) => { e.grid.bits = 16.5; }), 'FormatError'],
  ]);
  await bothGive(pillows, [
    ['packed count, firstFaceChunk', withFloats(pillows, (g, p, e) => { floats(e.chunks, ['count']); floats(e, ['firstFaceChunk']); }), 'decodes'],
    ['Draco attribute id and bufferView', withFloats(pillows, (g, p) => {
      const draco = p.extensions.KHR_draco_mesh_compression;
      floats(draco, ['bufferView']);
      floats(draco.attributes, ['POSITION']);
    }), 'decodes'],
    ['packed count 10.5', withFloats(pillows, (g, p, e) => { e.chunks.count += 0.5; }), 'FormatError'],
  ]);
  await bothGive(welded, [
    ['baseVertexCount, v1 chunk entries', withFloats(welded, (g, p, e) => {
      floats(e, ['baseVertexCount']);
      for (const c of e.chunks) floats(c, ['bufferView', 'byteLength', 'uncompressedLength', 'splits', 'vertexCount', 'faceCount']);
    }), 'decodes'],
  ]);
  await bothGive(attributes, [
    ['attribute bits', withFloats(attributes, (g, p, e) => { for (const a of e.attributes) floats(a, ['bits']); }), 'decodes'],
    ['primitive attributes, indices, mode', withFloats(attributes, (g, p) => { floats(p.attributes, Object.keys(p.attributes)); floats(p, ['indices', 'mode']); }), 'decodes'],
    ['accessors, bufferViews, buffer', withFloats(attributes, (g) => {
      for (const a of g.accessors) floats(a, ['bufferView', 'byteOffset', 'componentType', 'count']);
      for (const v of g.bufferViews) floats(v, ['buffer', 'byteOffset', 'byteLength', 'target']);
      floats(g.buffers[0], ['byteLength']);
    }), 'decodes'],
    ['POSITION index 0.5', withFloats(attributes, (g, p) => { p.attributes.POSITION += 0.5; }), 'FormatError'],
  ]);
});

test('a "faces" member on a version 1 chunk entry means nothing: face chunks are payload version 2\'s (spec/bitstream.md §8.6)', async () => {
  const v1 = load('grid-hole.plain.v1.pmw');
  await bothGive(v1, [
    ['faces: true on every v1 entry', withFloats(v1, (g, p, e) => { for (const c of e.chunks) c.faces = true; }), 'decodes'],
  ]);
});

test('at most MAX_ATTRIBUTES (the schema\'s maxItems) progressive attributes: 17 are a FormatError in both readers, 16 decode', async () => {
  const schema = JSON.parse(readFileSync(join(CONFORMANCE, '..', 'schema', 'mesh.primitive.PMWM_progressive_mesh.schema.json'), 'utf8'));
  assert.equal(schema.properties.attributes.maxItems, MAX_ATTRIBUTES);
  const file = load('sphere-attributes.plain.v2.pmw');
  /** The base alone (no chunk: a split would carry other columns), its TEXCOORD_0 entry repeated to `n` entries. */
  const repeated = (n) => withFloats(file, (g, p, e) => {
    e.chunks = { byteLengths: [], vertexCounts: [], faceCounts: [], geometricErrors: [], digests: '' };
    e.vertexCount = g.accessors[p.attributes.POSITION].count;
    e.faceCount = g.accessors[p.indices].count / 3;
    delete e.baseDigest; // it covers the attribute columns
    const uv = e.attributes.find((a) => a.semantic === 'TEXCOORD_0');
    e.attributes = Array.from({ length: n }, () => ({ ...uv }));
  });
  const sixteen = repeated(MAX_ATTRIBUTES);
  await bothGive(sixteen, [
    ['16 attributes', sixteen, 'decodes'],
    ['17 attributes', repeated(MAX_ATTRIBUTES + 1), 'FormatError'],
  ]);
  assert.equal((await jsOutcome(sixteen)).levels.length, 1);
});

test('each refusal has the kind spec/README.md "Kinds of refusal" gives it, in both readers, before any level', async () => {
  const v1 = load('grid-hole.plain.v1.pmw');
  const v2 = load('grid-hole.plain.v2.pmw');
  const packed = load('grid-hole.plain.packed.v2.pmw');
  const marked = load('sphere.exact-watermark.v1.pmw');
  const edit = (bytes, change) => withFloats(bytes, change);
  const glbVersion = (bytes, version) => { const out = bytes.slice(); new DataView(out.buffer).setUint32(4, version, true); return out; };
  const position = (g, p) => g.accessors[p.attributes.POSITION];
  const cases = [
    [v2, 'vertexCount null', edit(v2, (g, p, e) => { e.vertexCount = null; }), 'FormatError'],
    [v2, 'vertexCount true', edit(v2, (g, p, e) => { e.vertexCount = true; }), 'FormatError'],
    [v2, 'vertexCount "1"', edit(v2, (g, p, e) => { e.vertexCount = '1'; }), 'FormatError'],
    [v2, 'vertexCount 1.5', edit(v2, (g, p, e) => { e.vertexCount = 1.5; }), 'FormatError'],
    [v2, 'faceCount -1', edit(v2, (g, p, e) => { e.faceCount = -1; }), 'FormatError'],
    [v2, 'vertexCount 2^27', edit(v2, (g, p, e) => { e.vertexCount = 2 ** 27; }), 'LimitError'],
    [v2, 'vertexCount 1e300', edit(v2, (g, p, e) => { e.vertexCount = 1e300; }), 'LimitError'],
    [v2, 'version 2^60', withText(v2, (t) => t.replace('"version":1,', '"version":1152921504606846976,')), 'UnsupportedError'],
    [v2, 'payload codec pmwm-vsplitx', edit(v2, (g, p, e) => { e.payload.codec = 'pmwm-vsplitx'; }), 'UnsupportedError'],
    [v2, 'payload version 3', edit(v2, (g, p, e) => { e.payload.version = 3; }), 'UnsupportedError'],
    [v1, 'payload version 3 on a v1 file', edit(v1, (g, p, e) => { e.payload = { codec: 'pmwm-vsplit', version: 3 }; }), 'UnsupportedError'],
    [v2, 'payload null', edit(v2, (g, p, e) => { e.payload = null; }), 'FormatError'],
    [v2, 'payload {}', edit(v2, (g, p, e) => { e.payload = {}; }), 'FormatError'],
    [v2, 'payload version "2"', edit(v2, (g, p, e) => { e.payload.version = '2'; }), 'FormatError'],
    [v2, 'GLB container version 514', glbVersion(v2, 514), 'UnsupportedError'],
    [v2, 'GLB container version 1', glbVersion(v2, 1), 'UnsupportedError'],
    [marked, 'watermark carriers 2^27', edit(marked, (g, p, e) => { e.watermark.carriers = 2 ** 27; }), 'LimitError'],
    [marked, 'watermark carriers -1', edit(marked, (g, p, e) => { e.watermark.carriers = -1; }), 'FormatError'],
    [v2, 'array table byteLengths[0] 0', edit(v2, (g, p, e) => { e.chunks.byteLengths[0] = 0; }), 'FormatError'],
    [v1, 'chunk byteLength 0', edit(v1, (g, p, e) => { e.chunks[0].byteLength = 0; }), 'FormatError'],
    [v1, 'chunk byteLength null', edit(v1, (g, p, e) => { e.chunks[0].byteLength = null; }), 'FormatError'],
    [v1, 'chunk uncompressedLength -1', edit(v1, (g, p, e) => { e.chunks[0].uncompressedLength = -1; }), 'FormatError'],
    [v1, 'chunk vertexCount 2^27', edit(v1, (g, p, e) => { e.chunks[0].vertexCount = 2 ** 27; }), 'LimitError'],
    [packed, 'packed count 65537', edit(packed, (g, p, e) => { e.chunks.count = 65537; }), 'LimitError'],
    [packed, 'packed count 1e300', edit(packed, (g, p, e) => { e.chunks.count = 1e300; }), 'LimitError'],
    [v1, 'POSITION count -1', edit(v1, (g, p) => { position(g, p).count = -1; }), 'FormatError'],
    [v1, 'POSITION count 2^27', edit(v1, (g, p) => { position(g, p).count = 2 ** 27; }), 'LimitError'],
  ];
  for (const file of [v1, v2, packed, marked]) {
    await bothGive(file, cases.filter(([f]) => f === file).map(([, label, bytes, kind]) => [label, bytes, kind]));
  }
  const levels = [];
  const d = new PmwDecoder({ onLevel: (r) => levels.push(r.chunk) });
  await assert.rejects(d.feed(edit(v2, (g, p, e) => { e.chunks.byteLengths[0] = 0; })), FormatError);
  assert.deepEqual(levels, [], 'no level is shown before the table\'s refusal (it showed the base, then a digest error)');
});
