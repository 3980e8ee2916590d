#!/usr/bin/env node
/**
 * Times the JS full decode (decodePmw: GLB plan, base, every chunk) of .pmw files, for example the
 * same mesh encoded with chunk payload version 1 and version 2 (`pmw encode --payload-version N`).
 * One warm-up decode each (module instantiation not timed), then REPEATS rounds decoding every file
 * in turn. Prints one JSON line per file: {file, payloadVersions, bytes, vertices, faces,
 * seconds: [...], median}, then {ratio: median of each file / median of the first}.
 *
 *   node js/bench/versions.mjs [--repeats N] FILE.pmw [FILE.pmw ...]
 */
import { readFileSync } from 'node:fs';
import { performance } from 'node:perf_hooks';
import { decodePmw } from '../src/index.js';
import { parseGlb, planDocument } from '../src/header.js';

const args = process.argv.slice(2);
const at = args.indexOf('--repeats');
const repeats = at >= 0 ? Number(args.splice(at, 2)[1]) : 7;
const files = args.map((file) => {
  const bytes = new Uint8Array(readFileSync(file));
  const h = parseGlb(bytes);
  return { file, bytes, payloadVersions: planDocument(h.gltf, h.binLength).primitives.map((p) => p.payloadVersion), seconds: [] };
});

async function decodeOnce(f) {
  const t = performance.now();
  const out = await decodePmw(f.bytes);
  const s = (performance.now() - t) / 1000;
  if (!out.complete) throw new Error(`${f.file} did not decode completely`);
  return { s, vertices: out.positions.length / 3, faces: out.indices.length / 3 };
}

const median = (xs) => { const s = [...xs].sort((a, b) => a - b); return s[Math.floor(s.length / 2)]; };
for (const f of files) Object.assign(f, await decodeOnce(f)); // warm-up
for (let r = 0; r < repeats; r++) for (const f of files) f.seconds.push((await decodeOnce(f)).s);
for (const f of files) {
  process.stdout.write(`${JSON.stringify({ file: f.file, payloadVersions: f.payloadVersions, bytes: f.bytes.length,
    vertices: f.vertices, faces: f.faces, seconds: f.seconds.map((s) => Number(s.toFixed(4))), median: median(f.seconds) })}\n`);
}
process.stdout.write(`${JSON.stringify({ ratio: files.map((f) => Number((median(f.seconds) / median(files[0].seconds)).toFixed(3))), node: process.version })}\n`);
