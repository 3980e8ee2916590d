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
