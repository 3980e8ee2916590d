/**
 * Hostile input ends in a named error (a PmwError subclass) or a valid partial result, never a
 * hang or another exception: seeded random cuts, bit flips anywhere, bit flips and overwrites of
 * decompressed chunk payloads re-wrapped with valid frames and digests, the same on the range-coded
 * streams of payload version 2 (stored raw, with valid digests), and JSON edits. The conformance
 * files of both payload versions are the sources.
 * Bounded: FUZZ_CASES (default 200) cases per kind; every case runs under a time bound.
 */
import assert from 'node:assert/strict';
import { readFileSync } from 'node:fs';
import { join } from 'node:path';
import { test } from 'node:test';
import { PmwDecoder, PmwError } from '../src/index.js';
import { CONFORMANCE, conformanceFiles, seededRandom } from './lib/helpers.js';
import { chunkPayloads, withPayload } from './lib/rewrite.js';

const CASES = Number(process.env.FUZZ_CASES ?? 200);
const files = conformanceFiles().map((f) => new Uint8Array(readFileSync(join(CONFORMANCE, f))));


/** Decodes `bytes`: 'ok' (possibly partial) or the error's class name; fails on a non-PmwError. */
async function outcome(bytes, what) {
  const d = new PmwDecoder();
  const timer = new Promise((_, reject) => setTimeout(() => reject(new Error(`${what}: decode did not end in 5 s`)), 5000).unref());
  try {
    await Promise.race([d.feed(bytes), timer]);
    await d.close();
    return 'ok';
  } catch (e) {
    if (!(e instanceof PmwError)) assert.fail(`${what}: ${e?.name}: ${e?.message}\n${e?.stack}`);
    return e.name;
  }
}

test('random cuts and bit flips anywhere in the file end in named errors', { timeout: 300000 }, async () => {
  const r = seededRandom(1);
  const seen = new Set();
  for (let i = 0; i < CASES; i++) {
    const src = files[i % files.length];
    const bytes = src.slice(0, 1 + Math.floor(r() * src.length));
    for (let f = Math.floor(r() * 4); f > 0; f--) bytes[Math.floor(r() * bytes.length)] ^= 1 << Math.floor(r() * 8);
    seen.add(await outcome(bytes, `case ${i}`));
  }
  assert.ok(seen.size > 1, [...seen].join());
});

/**
 * `payload` (a copy) damaged by kind: 0 cut short, then 1-3 flips of a bit (kind 1), random bytes
 * (2) or 4 bytes of 0xff (3) at random places; 4 noise of the same length.
 */
function damaged(r, payload, kind) {
  const out = kind === 0 ? payload.subarray(0, Math.floor(r() * payload.length)) : payload.slice();
  if (kind === 4) return out.map(() => Math.floor(r() * 256));
  for (let f = 1 + Math.floor(r() * 3); f > 0 && out.length; f--) {
    const at = Math.floor(r() * out.length);
    if (kind === 1) out[at] ^= 1 << Math.floor(r() * 8);
    else if (kind === 2) out[at] = Math.floor(r() * 256);
    else if (kind === 3) out.fill(0xff, at, at + 4);
  }
  return out;
}

test('hostile chunk payloads behind valid frames and digests end in named errors', { timeout: 300000 }, async () => {
  const r = seededRandom(2);
  const sources = files.map((bytes) => ({ bytes, chunks: chunkPayloads(bytes) }));
  const seen = new Set();
  for (let i = 0; i < CASES; i++) {
    const { bytes, chunks } = sources[i % sources.length];
    const index = Math.floor(r() * chunks.length);
    const kind = i % 4;
    const payload = damaged(r, chunks[index].payload, kind);
    seen.add(await outcome(withPayload(bytes, index, payload), `payload case ${i} (kind ${kind})`));
  }
  if (process.env.FUZZ_VERBOSE) console.log([...seen]);
  assert.ok(seen.has('FormatError') || seen.has('LimitError'), [...seen].join());
});

const v2Files = conformanceFiles(2).map((f) => new Uint8Array(readFileSync(join(CONFORMANCE, f))));

test('hostile range-coded streams of payload version 2 behind valid digests end in named errors',
  { timeout: 300000, skip: v2Files.length === 0 && 'no *.v2.pmw in spec/conformance' }, async () => {
    const r = seededRandom(4);
    const sources = v2Files.map((bytes) => ({ bytes, chunks: chunkPayloads(bytes) }));
    const seen = new Map();
    for (let i = 0; i < CASES; i++) {
      const { bytes, chunks } = sources[i % sources.length];
      const index = Math.floor(r() * chunks.length);
      const kind = i % 5;
      const payload = damaged(r, chunks[index].payload, kind);
      const name = await outcome(withPayload(bytes, index, payload), `v2 payload case ${i} (kind ${kind})`);
      seen.set(name, (seen.get(name) ?? 0) + 1);
    }
    if (process.env.FUZZ_VERBOSE) console.log(seen);
    assert.ok(seen.has('FormatError') || seen.has('LimitError'), [...seen.keys()].join());
  });

test('edits of the JSON counts and offsets end in named errors', { timeout: 300000 }, async () => {
  const r = seededRandom(3);
  const edits = [
    (x) => x.replace(/"vertexCount":\s*(\d+)/, (_, n) => `"vertexCount":${Number(n) * 1000}`),
    (x) => x.replace(/"faceCount":\s*(\d+)/, '"faceCount":1'),
    (x) => x.replace(/"byteOffset":\s*(\d+)/g, (m, n) => (r() < 0.3 ? `"byteOffset":${Number(n) + 4}` : m)),
    (x) => x.replace(/"uncompressedLength":\s*(\d+)/, '"uncompressedLength":268435456'),
    (x) => x.replace(/"bits":\s*(\d+)/, '"bits":31'),
    (x) => x.replace(/"version":\s*1/, '"version":2'),
    (x) => x.replace(/"count":\s*(\d+)/, '"count":4000000000'),
  ];
  for (let i = 0; i < Math.min(CASES, 200); i++) {
    const src = files[i % files.length];
    const J = new DataView(src.buffer, src.byteOffset).getUint32(12, true);
    const text = new TextDecoder().decode(src.subarray(20, 20 + J));
    const edited = new TextEncoder().encode(edits[i % edits.length](text));
    if (edited.length > J) continue;
    const bytes = src.slice();
    bytes.fill(0x20, 20, 20 + J);
    bytes.set(edited, 20);
    await outcome(bytes, `json case ${i}`);
  }
});
