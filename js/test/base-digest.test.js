/**
 * The keyless base digest (spec/bitstream.md §6.4): every base the Python encoder writes (plain and
 * Draco, attributes, two primitives, welded) decodes here to integers and faces whose digest is the
 * file's `baseDigest`; a base with a flipped bit that still decodes is refused as the Python decoder
 * refuses it (CorruptChunkError, chunk null), and both decoders agree on every flip. Skipped when no
 * Python imports a pmwm_codec that writes payload version 2; the spec's worked values (§6.4) are checked without one.
 */
import assert from 'node:assert/strict';
import { mkdtempSync, readFileSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { after, test } from 'node:test';
import { CorruptChunkError, PmwError, decodePmw } from '../src/index.js';
import { baseDigest } from '../src/base.js';
import { initChunkFrames } from '../src/chunkframe.js';
import { parseGlb, planDocument } from '../src/header.js';
import { jsLevels, jsOutcome, seededRandom } from './lib/helpers.js';
import { TREE, decodeFiles, encodeCase, pythonHasPayloadV2 } from './lib/python.js';

const skip = !pythonHasPayloadV2() && 'no Python importing a pmwm_codec that writes payload version 2 ($PYTHON, $PMW_PYTHONPATH)';
const dir = mkdtempSync(join(tmpdir(), 'pmw-base-digest-'));
after(() => rmSync(dir, { recursive: true, force: true }));

/** Case `name` encoded (payload version 2): {bytes, want, plan}. */
function encoded(name) {
  const file = join(dir, `${name}.pmw`);
  const want = encodeCase(name, 2, file);
  const bytes = new Uint8Array(readFileSync(file));
  const h = parseGlb(bytes);
  return { bytes, want, plan: planDocument(h.gltf, h.binLength), binStart: h.binStart };
}

const CASES = ['closed-sphere.draco', 'attributes.plain', 'two-primitives.draco', 'welded.draco'];

for (const name of CASES) {
  test(`${name}: every base carries a baseDigest, and it checks out here as in the Python decoder`, { skip }, async () => {
    const { bytes, want, plan } = encoded(name);
    for (const p of plan.primitives) assert.match(p.ext.baseDigest, /^[0-9a-f]{16}$/);
    const got = await jsLevels(bytes);
    assert.deepEqual(got.levels, want.levels);
  });
}

test('a base with flipped bits: both decoders refuse the same files, by the digest where the codec decodes, and agree on the others', { skip }, async () => {
  const sources = ['closed-sphere.draco', 'attributes.plain', 'two-primitives.draco'].map(encoded);
  const r = seededRandom(11);
  const files = [];
  const js = [];
  for (let i = 0; i < 72; i++) {
    const { bytes, plan, binStart } = sources[i % sources.length];
    const views = plan.primitives.flatMap((p) => p.base.views);
    const view = views[Math.floor(r() * views.length)];
    const hostile = bytes.slice();
    hostile[binStart + view.offset + Math.floor(r() * view.length)] ^= 1 << Math.floor(r() * 8);
    const file = join(dir, `flipped-${i}.pmw`);
    writeFileSync(file, hostile);
    files.push(file);
    js.push(await jsOutcome(hostile));
  }
  const py = decodeFiles(files);
  let byDigest = 0;
  for (const [i, want] of py.entries()) {
    const got = js[i];
    if (want.error !== undefined) {
      assert.ok(got instanceof PmwError, `${files[i]}: Python refuses it (${want.error}), JS decodes it`);
      if (want.error === 'ChecksumError') {
        assert.ok(got instanceof CorruptChunkError && got.chunk === null && /baseDigest mismatch/.test(got.message),
          `${files[i]}: ${got.name}: ${got.message}`);
        byDigest++;
      }
    } else {
      assert.ok(!(got instanceof PmwError), `${files[i]}: Python decodes it, JS refuses it (${got?.name}: ${got?.message})`);
      assert.deepEqual(got.levels, want.levels, files[i]);
      assert.deepEqual(want.levels, sources[i % sources.length].want.levels, `${files[i]}: a flip nobody reads changes nothing`);
    }
  }
  assert.ok(byDigest > 0, 'some flips decode and are caught by the digest alone');
});

test('two primitives: the error names the one whose base is damaged', { skip }, async () => {
  const { bytes, plan } = encoded('two-primitives.draco');
  const digest = plan.primitives[1].ext.baseDigest;
  const text = new TextDecoder().decode(bytes);
  const at = text.indexOf(digest);
  assert.ok(at > 0 && text.indexOf(digest, at + 1) < 0);
  const hostile = bytes.slice();
  hostile.set(new TextEncoder().encode('0'.repeat(16)), at);
  await assert.rejects(decodePmw(hostile), (e) => e instanceof CorruptChunkError && e.chunk === null
    && /^base mesh of progressive primitive 2: baseDigest mismatch/.test(e.message));
});

test('the worked values of bitstream.md §6.4 are what this decoder computes', async () => {
  await initChunkFrames();
  const spec = readFileSync(join(TREE, 'spec', 'bitstream.md'), 'utf8');
  const section = spec.slice(spec.indexOf('### 6.4 Base digest'), spec.indexOf('## 7. Watermark'));
  const plain = section.match(/`baseDigest` = `([0-9a-f]{16})`/)[1];
  const withAttribute = section.match(/values `7, 8, 9`: `([0-9a-f]{16})`/)[1];
  const faces = Uint32Array.from([0, 1, 2]);
  assert.equal(baseDigest(Float64Array.from([0, 0, 0, 1, 0, 0, 0, 1, 0]), faces, 3, 3), plain);
  assert.equal(baseDigest(Float64Array.from([0, 0, 0, 7, 1, 0, 0, 8, 0, 1, 0, 9]), faces, 3, 4), withAttribute);
});
