#!/usr/bin/env node
/**
 * The JavaScript side of tools/decoder_diff.py: decodes each file named in LIST (one path a line) with PmwDecoder
 * and prints one JSON line per file: {path, levels: [[chunk, vertexCount, faceCount, sha256]], outcome}, sha256
 * js/test/lib/helpers.js' levelDigest of the level's snapshot ("SNAP:<error name>" when snapshot() refuses it),
 * outcome "complete", "truncated" or "<error name>: <message>". SPLIT (a seed) feeds each file in pieces of
 * 1..5000 bytes; MAXCHUNKS sets maxChunks.
 *
 *   node tools/decoder_diff.mjs LIST [SPLIT] [MAXCHUNKS]
 */
import { readFileSync } from 'node:fs';
import { PmwDecoder, PmwError } from '../js/src/index.js';
import { levelDigest, seededRandom } from '../js/test/lib/helpers.js';

const [list, split = 0, maxChunks = Infinity] = process.argv.slice(2).map((a, i) => (i ? Number(a) : a));
for (const path of readFileSync(list, 'utf8').split('\n').filter(Boolean)) {
  const bytes = new Uint8Array(readFileSync(path));
  const levels = [];
  const snapshot = (d) => { try { return levelDigest(d.snapshot()); } catch (e) { return `SNAP:${e.name}`; } };
  const dec = new PmwDecoder({ maxChunks, onLevel: (r, d) => levels.push([r.chunk, r.vertexCount, r.faceCount, snapshot(d)]) });
  let outcome;
  try {
    const r = seededRandom(split);
    for (let at = 0; at < bytes.length;) {
      const n = split ? 1 + Math.floor(r() * r() * 5000) : bytes.length;
      await dec.feed(bytes.slice(at, at + n));
      at += n;
    }
    outcome = (await dec.close()).complete ? 'complete' : 'truncated';
  } catch (e) {
    outcome = `${e instanceof PmwError ? '' : 'NOT-PMW:'}${e.name}: ${e.message}`;
  }
  process.stdout.write(`${JSON.stringify({ path, levels, outcome })}\n`);
}
