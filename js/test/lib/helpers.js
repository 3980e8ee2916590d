/** Shared test helpers: conformance file paths and the level digest of tests/samples.py. */
import { createHash } from 'node:crypto';
import { readdirSync } from 'node:fs';
import { join } from 'node:path';
import { PmwDecoder, PmwError } from '../../src/index.js';
import { TREE } from './python.js';

/** spec/conformance of the repository under test (TREE: this one, or $PMW_PYTHONPATH's). */
export const CONFORMANCE = join(TREE, 'spec', 'conformance');

/**
 * Names of the conformance files: `<name>.v1.pmw` (chunk payload version 1) and `<name>.v2.pmw`
 * (the same cases with payload version 2, spec/bitstream.md §8; `<name>.packed.v2.pmw` with the packed
 * chunk table of §6.2, `<name>.v2.pmw` with its older JSON arrays), or only those of `version`.
 */
export function conformanceFiles(version) {
  const suffixes = version === undefined ? ['.v1.pmw', '.v2.pmw'] : [`.v${version}.pmw`];
  return readdirSync(CONFORMANCE).filter((f) => suffixes.some((s) => f.endsWith(s))).sort();
}

/** Any integer typed array as little-endian int64 bytes (numpy '<i8'). */
export function asInt64Bytes(arr) {
  const out = new BigInt64Array(arr.length);
  for (let i = 0; i < arr.length; i++) out[i] = BigInt(arr[i]);
  return new Uint8Array(out.buffer);
}

/** Parts' quantized attributes stacked (n, a) as one flat array, like tests/test_golden.py. */
export function attributesInt(mesh) {
  const total = mesh.parts.reduce((a, p) => a + p.attributesInt.length, 0);
  const out = new Int32Array(total);
  let at = 0;
  for (const p of mesh.parts) { out.set(p.attributesInt, at); at += p.attributesInt.length; }
  return out;
}

/** SHA-256 of positions, faces and (when any) quantized attributes as <i8: tests/samples.py level_digest. */
export function levelDigest(mesh) {
  const h = createHash('sha256');
  h.update(asInt64Bytes(mesh.positionsInt));
  h.update(asInt64Bytes(mesh.indices));
  const a = attributesInt(mesh);
  if (a.length) h.update(asInt64Bytes(a));
  return h.digest('hex');
}

/** A seeded uniform [0, 1) generator (mulberry32): the tests' only randomness. */
export function seededRandom(seed) {
  return () => {
    seed = (seed + 0x6d2b79f5) | 0;
    let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

/** Decodes `bytes` whole: the error thrown (a PmwError), or null. */
export async function failure(bytes) {
  try {
    const d = new PmwDecoder();
    await d.feed(bytes);
    await d.close();
    return null;
  } catch (e) {
    if (!(e instanceof PmwError)) throw e;
    return e;
  }
}

/**
 * Every level the JS decoder gives for `bytes` fed whole, as levels.py prints them:
 * {levels, end (close()'s result), last (the last level's mesh)}.
 */
export async function jsLevels(bytes) {
  const d = new PmwDecoder({ snapshots: true });
  const results = await d.feed(bytes);
  const levels = results.map((r) => ({
    bytesRead: r.bytesRead, vertexCount: r.vertexCount, faceCount: r.faceCount,
    parts: r.parts.map((p) => [p.vertexCount, p.faceCount]), sha256: levelDigest(r.mesh),
  }));
  return { levels, end: await d.close(), last: results[results.length - 1].mesh };
}

/** What this decoder makes of `bytes`: its PmwError, or jsLevels(bytes) when it decodes them. */
export async function jsOutcome(bytes) {
  const e = await failure(bytes);
  return e === null ? jsLevels(bytes) : e;
}
