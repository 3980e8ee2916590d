#!/usr/bin/env node
/**
 * Per-stage times of the JS full decode of one .pmw (medians over REPEATS runs after one warm-up):
 * GLB + JSON plan, Draco base (draco3d), and over all chunks: BLAKE2b digest (hash-wasm), zstd frame
 * walk + decompression with its XXH64 content checksum (zstddec: libzstd in WebAssembly), payload unpack,
 * split application (payload version 1), or `rangecoded`: the whole range-coded chunk decode, splits
 * included (payload version 2); then the final snapshot. Prints JSON {stage: seconds}.
 *
 *   node js/bench/stages.mjs FILE.pmw [REPEATS] [--cpu]
 */
import { readFileSync } from 'node:fs';
import { performance } from 'node:perf_hooks';
import { decodeBase } from '../src/base.js';
import { digestMatches, frameLayout, inflate, initChunkFrames } from '../src/chunkframe.js';
import { PmwDecoder } from '../src/decoder.js';
import { parseGlb, planDocument } from '../src/header.js';
import { ChunkDecoderV2 } from '../src/payload-v2.js';
import { MeshState, unpackPayload } from '../src/vsplit.js';

const [path, repeatsArg] = process.argv.slice(2).filter((a) => a !== '--cpu');
const repeats = Number(repeatsArg ?? 5);
const bytes = new Uint8Array(readFileSync(path));
/** Milliseconds: wall clock, or with --cpu this process's CPU time (steadier on a loaded machine). */
const clock = process.argv.includes('--cpu') ? () => { const u = process.cpuUsage(); return (u.user + u.system) / 1000; }
  : () => performance.now();
// zstd only when a chunk is a zstd frame, as PmwDecoder does: instantiating it grows a WebAssembly memory,
// which detaches an ArrayBuffer and drops V8's ArrayBufferDetaching protector for good: the typed-array
// accesses compiled after it check for a detached buffer, and the range-coded stage of a version 2 file
// measured a slower decoder than decodePmw runs
const glb = parseGlb(bytes);
const { stream } = planDocument(glb.gltf, glb.binLength);
await initChunkFrames({ zstd: stream.some((c) => c.payloadVersion !== 2) });

/** One decode, stage by stage, as PmwDecoder does it; returns {stage: seconds}. */
async function stages() {
  const t = {};
  let t0 = clock();
  const lap = (name) => {
    const now = clock();
    t[name] = (t[name] ?? 0) + (now - t0) / 1000;
    t0 = now;
  };
  const header = parseGlb(bytes);
  const plan = planDocument(header.gltf, header.binLength);
  const bin = bytes.subarray(header.binStart);
  lap('plan');
  const states = [];
  for (const prim of plan.primitives) {
    const b = await decodeBase(bin, prim);
    states.push(new MeshState(b.values, b.faces, b.n, b.m, b.D, prim.vertexCount, prim.faceCount));
  }
  const coders = plan.primitives.map((p, i) => (p.payloadVersion === 2 ? new ChunkDecoderV2(states[i]) : null));
  lap('base');
  plan.stream.forEach((c) => {
    const stored = bin.subarray(c.offset, c.offset + c.length);
    t0 = clock();
    if (!digestMatches(stored, c.digest)) throw new Error('digest');
    lap('blake2b');
    if (c.payloadVersion === 2) {
      coders[c.primitive].decodeChunk(stored, c);
      lap('rangecoded');
      return;
    }
    frameLayout(stored, 'chunk');
    const out = inflate(stored, c.uncompressedLength, 'chunk');
    lap('zstd');
    const state = states[c.primitive];
    const records = unpackPayload(out, state.D, state.capN);
    lap('unpack');
    state.applyPayload(records);
    lap('splits');
  });
  return t;
}

async function full() {
  const t = clock();
  const d = new PmwDecoder();
  await d.feed(bytes);
  await d.close();
  const t1 = clock();
  d.snapshot();
  return { decode: (t1 - t) / 1000, snapshot: (clock() - t1) / 1000 };
}

const median = (xs) => xs.slice().sort((a, b) => a - b)[Math.floor(xs.length / 2)];
await stages();
await full();
const runs = [];
for (let i = 0; i < repeats; i++) runs.push({ ...(await stages()), ...(await full()) });
const out = {};
for (const k of Object.keys(runs[0])) out[k] = Number(median(runs.map((r) => r[k])).toFixed(5));
out.chunks = stream.length;
process.stdout.write(`${JSON.stringify(out)}\n`);
