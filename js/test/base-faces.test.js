/**
 * A base face that repeats a vertex is refused (spec/README.md, base mesh): a split of a vertex held
 * twice by one face has no defined result, and the Python reader refuses it the same way.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError, decodePmw } from '../src/index.js';
import { CONFORMANCE } from './lib/helpers.js';

const COMPONENT = { 5121: Uint8Array, 5123: Uint16Array, 5125: Uint32Array };

test('a plain base whose first face repeats a vertex is a FormatError', async () => {
  const bytes = new Uint8Array(readFileSync(join(CONFORMANCE, 'grid-hole.plain.v1.pmw')));
  const view = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const jsonLength = view.getUint32(12, true);
  const gltf = JSON.parse(new TextDecoder().decode(bytes.subarray(20, 20 + jsonLength)));
  const prim = gltf.meshes[0].primitives[0];
  const acc = gltf.accessors[prim.indices];
  const bv = gltf.bufferViews[acc.bufferView];
  const start = 28 + jsonLength + (bv.byteOffset ?? 0) + (acc.byteOffset ?? 0);
  const Type = COMPONENT[acc.componentType];
  const indices = new Type(bytes.buffer.slice(bytes.byteOffset + start, bytes.byteOffset + start + 3 * Type.BYTES_PER_ELEMENT));
  assert.notEqual(indices[0], indices[1]);
  const damaged = bytes.slice();
  const first = new DataView(damaged.buffer);
  if (Type === Uint8Array) first.setUint8(start + 1, indices[0]);
  else if (Type === Uint16Array) first.setUint16(start + 2, indices[0], true);
  else first.setUint32(start + 4, indices[0], true);
  await assert.rejects(decodePmw(damaged), (e) => e instanceof FormatError && /repeats a vertex/.test(e.message));
  await decodePmw(bytes);  // the undamaged file decodes
});
