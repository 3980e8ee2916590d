/**
 * The decoder's int32 -> float64 widening path (src/vsplit.js MeshState.values): a hostile stream
 * whose residuals push grid values outside the int32 range (allowed by the payload format: a stored
 * residual may reach |r| = 2^31) still decodes to the exact integers of the reference decoder's
 * int64 arithmetic. Subjects: conformance files with one chunk payload rewritten (test/lib/rewrite.js)
 * so that one split's residual is huge; stored as a width-4 or a width-8 column.
 */
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { test } from 'node:test';
import { decodePmw } from '../src/index.js';
import { parseGlb, planDocument } from '../src/header.js';
import { CONFORMANCE, levelDigest } from './lib/helpers.js';
import { python, ROOT } from './lib/python.js';
import { chunkPayloads, withPayload } from './lib/rewrite.js';

const INT32_MAX = 2 ** 31 - 1;

/** Byte offsets of a payload's residual columns: [{width, start}] per value d (spec/bitstream.md §6). */
function residualColumns(payload, D) {
  const dv = new DataView(payload.buffer, payload.byteOffset, payload.byteLength);
  const batchCount = dv.getUint32(0, true);
  let K = 0;
  let I = 0;
  for (let j = 0; j < batchCount; j++) {
    K += dv.getUint32(4 + 8 * j, true);
    I += dv.getUint32(8 + 8 * j, true);
  }
  let at = 4 + 8 * batchCount;
  at += 1 + payload[at] * K; // gaps
  at += 1 + payload[at] * Math.ceil(I / 3); // packed symbols
  const columns = [];
  for (let d = 0; d < D; d++) {
    columns.push({ width: payload[at], start: at + 1 });
    at += 1 + payload[at] * K;
  }
  return { K, columns, end: at };
}

/**
 * `payload` with residual `d` of split `i` replaced: that column re-stored with `width` byte planes,
 * split i's value set to `residual` (the others kept). @returns {{payload: Uint8Array, old: number}}
 */
function withResidual(payload, D, i, d, residual, width) {
  const { K, columns } = residualColumns(payload, D);
  const col = columns[d];
  const zig = new Array(K);
  for (let s = 0; s < K; s++) {
    let z = 0;
    for (let b = col.width - 1; b >= 0; b--) z = z * 256 + payload[col.start + b * K + s];
    zig[s] = z;
  }
  const old = zig[i] % 2 === 0 ? zig[i] / 2 : -(zig[i] + 1) / 2;
  zig[i] = residual >= 0 ? 2 * residual : -2 * residual - 1;
  const column = new Uint8Array(1 + width * K);
  column[0] = width;
  for (let s = 0; s < K; s++) {
    let z = zig[s];
    for (let b = 0; b < width; b++, z = Math.floor(z / 256)) column[1 + b * K + s] = z % 256;
  }
  const before = payload.subarray(0, col.start - 1);
  const after = payload.subarray(col.start + col.width * K);
  const out = new Uint8Array(before.length + column.length + after.length);
  out.set(before);
  out.set(column, before.length);
  out.set(after, before.length + column.length);
  return { payload: out, old };
}

function load(name) {
  const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, name)));
  const { gltf, binLength } = parseGlb(bytes);
  return { bytes, plan: planDocument(gltf, binLength), chunks: chunkPayloads(bytes) };
}

/** The first or last chunk of the first primitive: {index, D, K, payload}. */
function chunkOf({ plan, chunks }, last) {
  const index = last ? plan.stream.findLastIndex((c) => c.primitive === 0) : plan.stream.findIndex((c) => c.primitive === 0);
  const D = 3 + plan.primitives[0].base.grids.reduce((a, g) => a + g.origin.length, 0);
  const { payload } = chunks[index];
  return { index, D, K: residualColumns(payload, D).K, payload };
}

for (const width of [4, 8]) {
  test(`a last split whose x leaves int32 (width-${width} residual column) decodes to the exact integer, the rest unchanged`, async () => {
    const src = load('sphere-attributes.plain.v1.pmw');
    const { index, D, K, payload } = chunkOf(src, true);
    const residual = width === 4 ? INT32_MAX : 2 ** 31; // the largest each width stores (z <= 2^32)
    const edit = withResidual(payload, D, K - 1, 0, residual, width);
    const ref = await decodePmw(src.bytes);
    const out = await decodePmw(withPayload(src.bytes, index, edit.payload));
    const u = ref.positionsInt.length / 3 - 1; // the last split of the last chunk adds the last vertex
    const x = ref.positionsInt[3 * u] + (residual - edit.old);
    assert.ok(x > INT32_MAX, `x = ${x} stays in int32: the test does not reach the widening path`);
    assert.ok(out.positionsInt instanceof Float64Array);
    assert.equal(out.positionsInt[3 * u], x);
    const expected = Float64Array.from(ref.positionsInt);
    expected[3 * u] = x;
    assert.deepEqual(out.positionsInt, expected);
    const { origin, step } = src.plan.primitives[0].grid;
    assert.equal(out.positions[3 * u], Math.fround(origin[0] + x * step[0]));
    assert.deepEqual(out.positions.subarray(0, 3 * u), ref.positions.subarray(0, 3 * u));
    assert.deepEqual(out.indices, ref.indices);
    assert.deepEqual(Array.from(out.parts[0].attributesInt), Array.from(ref.parts[0].attributesInt));
  });
}

test('a wide value in the first chunk feeds later predictions exactly as the Python reference decoder (int64)',
  { skip: python() ? false : 'no Python that imports pmwm_codec (set PYTHON)' }, async () => {
    let moved = 0; // values other than the edited one that differ from the untouched decode
    for (const name of ['sphere-attributes.plain.v1.pmw', 'two-parts.draco.v1.pmw']) {
      const src = load(name);
      const ref = await decodePmw(src.bytes);
      const { index, D, payload } = chunkOf(src, false);
      // split 0 of the first chunk: later splits predict from the wide value
      const hostile = withPayload(src.bytes, index, withResidual(payload, D, 0, 0, INT32_MAX, 4).payload);
      const out = await decodePmw(hostile);
      assert.ok(out.parts[0].positionsInt instanceof Float64Array, `${name}: the widening path was not reached`);
      moved += out.positionsInt.filter((x, i) => x !== ref.positionsInt[i]).length - 1;
      const dir = mkdtempSync(join(tmpdir(), 'pmwm-wide-'));
      try {
        writeFileSync(join(dir, 'hostile.pmw'), hostile);
        assert.equal(levelDigest(out), referenceDigest(join(dir, 'hostile.pmw')), name);
      } finally {
        rmSync(dir, { recursive: true, force: true });
      }
    }
    assert.ok(moved > 0, 'no later prediction read the wide value');
  });

/** tests/test_js_decoder.py's level digest of the Python StreamDecoder's last level of `file`. */
function referenceDigest(file) {
  const code = `import hashlib, sys
import numpy as np
from pmwm_codec.stream import StreamDecoder
dec = StreamDecoder()
r = dec.feed(open(sys.argv[1], 'rb').read())[-1]
h = hashlib.sha256()
attributes = np.concatenate([p.attributes_int for p in r.parts])
for a in (r.positions_int, r.faces, attributes) if attributes.size else (r.positions_int, r.faces):
    h.update(np.ascontiguousarray(a, dtype='<i8').tobytes())
print(h.hexdigest())`;
  const env = { ...process.env, PYTHONPATH: [ROOT, process.env.PYTHONPATH].filter(Boolean).join(':') };
  const res = spawnSync(python(), ['-c', code, file], { env, encoding: 'utf8' });
  assert.equal(res.status, 0, res.stderr);
  return res.stdout.trim();
}
