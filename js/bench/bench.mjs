#!/usr/bin/env node
/**
 * Times the JS full decode of a .pmw (decodePmw: GLB plan, Draco base via draco3d, digests, zstd,
 * every split) against draco3d's decode of the same full mesh Draco-encoded (DecodeBufferToMesh,
 * then positions and indices copied out, as three.js' DRACOLoader does). One warm-up run each
 * (module instantiation is not timed), then REPEATS runs each, alternating. Prints JSON:
 * {vertices, faces, pmw: [seconds], draco: [seconds], node}.
 *
 *   node js/bench/bench.mjs FILE.pmw FILE.drc [REPEATS]
 */
import { readFileSync } from 'node:fs';
import { performance } from 'node:perf_hooks';
import draco3d from 'draco3d';
import { decodePmw } from '../src/index.js';

const [pmwPath, drcPath, repeatsArg] = process.argv.slice(2);
if (!pmwPath || !drcPath) {
  console.error('usage: node bench/bench.mjs FILE.pmw FILE.drc [REPEATS]   (python tools/bench_js.py makes both)');
  process.exit(2);
}
const repeats = Number(repeatsArg ?? 5);
const pmw = new Uint8Array(readFileSync(pmwPath));
const drc = new Uint8Array(readFileSync(drcPath));
const m = await draco3d.createDecoderModule({});

function dracoDecode(bytes) {
  const decoder = new m.Decoder();
  const buffer = new m.DecoderBuffer();
  const mesh = new m.Mesh();
  buffer.Init(new Int8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength), bytes.byteLength);
  const status = decoder.DecodeBufferToMesh(buffer, mesh);
  if (!status.ok()) throw new Error(status.error_msg());
  const n = mesh.num_points();
  const f = mesh.num_faces();
  const attr = decoder.GetAttribute(mesh, decoder.GetAttributeId(mesh, m.POSITION));
  const pp = m._malloc(n * 12);
  decoder.GetAttributeDataArrayForAllPoints(mesh, attr, m.DT_FLOAT32, n * 12, pp);
  const positions = new Float32Array(m.HEAPF32.buffer, pp, n * 3).slice();
  const ip = m._malloc(f * 12);
  decoder.GetTrianglesUInt32Array(mesh, f * 12, ip);
  const indices = new Uint32Array(m.HEAPU32.buffer, ip, f * 3).slice();
  m._free(pp); m._free(ip);
  m.destroy(mesh); m.destroy(buffer); m.destroy(decoder);
  return { positions, indices };
}

async function time(fn) {
  const t = performance.now();
  const out = await fn();
  return [(performance.now() - t) / 1000, out];
}

const [, full] = await time(() => decodePmw(pmw));
const [, ref] = await time(() => dracoDecode(drc));
if (!full.complete) throw new Error('the .pmw did not decode completely');
const out = { vertices: full.positions.length / 3, faces: full.indices.length / 3,
  dracoVertices: ref.positions.length / 3, pmw: [], draco: [], node: process.version };
for (let i = 0; i < repeats; i++) {
  out.pmw.push((await time(() => decodePmw(pmw)))[0]);
  out.draco.push((await time(() => dracoDecode(drc)))[0]);
}
process.stdout.write(`${JSON.stringify(out)}\n`);
