/**
 * Bytes the Python reader (pmwm_codec) and this one read differently, found by a differential run of both over
 * mutated files (helper-126): each case here was accepted by this reader and refused by the reference one. The
 * Python side's cases are in tests/test_reader_differentials.py. The sources are conformance files.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { FormatError, decodePmw } from '../src/index.js';
import { CONFORMANCE } from './lib/helpers.js';

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
