/**
 * Constructs a glTF viewer reads differently from the readers of this extension, outside the MACs, are refused
 * (spec/README.md, Base mesh), as the Python reader refuses them (tests/test_viewer_differentials.py).
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError, decodePmw } from '../src/index.js';
import { CONFORMANCE } from './lib/helpers.js';

const FILE = join(CONFORMANCE, 'grid-hole.plain.packed.v2.pmw');

/** The file with change(gltf, bin) applied to its JSON and BIN (bin: an array of byte arrays, appended to). */
function rewrite(bytes, change) {
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jsonLength = view.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  const binLength = view.getUint32(20 + jsonLength, true);
  const parts = [bytes.subarray(28 + jsonLength, 28 + jsonLength + binLength)];
  const append = (raw) => {
    const at = parts.reduce((n, p) => n + p.length, 0);
    parts.push(raw, new Uint8Array((4 - (raw.length % 4)) % 4));
    gltf.bufferViews.push({ buffer: 0, byteOffset: at, byteLength: raw.length });
    return gltf.bufferViews.length - 1;
  };
  change(gltf, append);
  const bin = new Uint8Array(parts.reduce((n, p) => n + p.length, 0));
  let at = 0;
  for (const p of parts) { bin.set(p, at); at += p.length; }
  gltf.buffers[0].byteLength = bin.length;
  let text = new TextEncoder().encode(JSON.stringify(gltf));
  const padded = new Uint8Array(text.length + ((4 - (text.length % 4)) % 4)).fill(0x20);
  padded.set(text); text = padded;
  const out = new Uint8Array(28 + text.length + bin.length);
  const dv = new DataView(out.buffer);
  out.set([0x67, 0x6c, 0x54, 0x46]); dv.setUint32(4, 2, true); dv.setUint32(8, out.length, true);
  dv.setUint32(12, text.length, true); out.set([0x4a, 0x53, 0x4f, 0x4e], 16); out.set(text, 20);
  dv.setUint32(20 + text.length, bin.length, true); out.set([0x42, 0x49, 0x4e, 0], 24 + text.length);
  out.set(bin, 28 + text.length);
  return out;
}

const bytes = new Uint8Array(readFileSync(FILE));

test('the untouched file and its rewrite without a change decode', async () => {
  await decodePmw(bytes);
  await decodePmw(rewrite(bytes, () => {}));
});

test('a sparse substitution on a base accessor is a FormatError, not a base shown one way and decoded another', async () => {
  for (const which of ['POSITION', 'indices']) {
    const changed = rewrite(bytes, (gltf, append) => {
      const prim = gltf.meshes[0].primitives[0];
      const acc = gltf.accessors[which === 'POSITION' ? prim.attributes.POSITION : prim.indices];
      const values = which === 'POSITION' ? new Uint8Array(new Float32Array([0, 30, 0]).buffer)
        : new Uint8Array(acc.componentType === 5123 ? new Uint16Array([1]).buffer : new Uint32Array([1]).buffer);
      acc.sparse = { count: 1, indices: { bufferView: append(new Uint8Array(new Uint16Array([0]).buffer)), componentType: 5123 },
        values: { bufferView: append(values) } };
    });
    await assert.rejects(decodePmw(changed), (e) => e instanceof FormatError && /sparse/.test(e.message), which);
  }
});

test('a bufferView carrying an extension (EXT_meshopt_compression) is a FormatError', async () => {
  const changed = rewrite(bytes, (gltf) => {
    const prim = gltf.meshes[0].primitives[0];
    const view = gltf.bufferViews[gltf.accessors[prim.attributes.POSITION].bufferView];
    view.extensions = { EXT_meshopt_compression: { buffer: 0, byteLength: 4, byteStride: 12, count: 1, mode: 'ATTRIBUTES' } };
  });
  await assert.rejects(decodePmw(changed), (e) => e instanceof FormatError && /bufferViews\[\d+\] carries extensions/.test(e.message));
});

test('POSITION min / max other than the bounds of the stored positions are a FormatError', async () => {
  const changed = rewrite(bytes, (gltf) => {
    const acc = gltf.accessors[gltf.meshes[0].primitives[0].attributes.POSITION];
    acc.min = [1000, 1000, 1000]; acc.max = [1000.001, 1000.001, 1000.001];
  });
  await assert.rejects(decodePmw(changed), (e) => e instanceof FormatError && /is not the bound of its values/.test(e.message));
});
