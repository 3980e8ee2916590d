#!/usr/bin/env node
/**
 * Dumps the JS decode of a .pmw at every chunk boundary as JSON lines on stdout:
 * {"chunk", "bytesRead", "vertexCount", "faceCount", "parts": [[n, m], ...], "sha256"}, sha256 being
 * tests/samples.py's level digest (positions, faces, quantized attributes as <i8).
 * Used by tests/test_js_decoder.py. Exit 2 with one line on stderr on a decode error.
 *
 *   node js/tools/dump.mjs FILE.pmw
 */
import { readFileSync } from 'node:fs';
import { PmwDecoder } from '../src/index.js';
import { levelDigest } from '../test/lib/helpers.js';

const path = process.argv[2];
try {
  const bytes = new Uint8Array(readFileSync(path));
  const write = (r, decoder) => process.stdout.write(`${JSON.stringify({
    chunk: r.chunk, bytesRead: r.bytesRead, vertexCount: r.vertexCount, faceCount: r.faceCount,
    parts: r.parts.map((p) => [p.vertexCount, p.faceCount]), sha256: levelDigest(decoder.snapshot()),
  })}\n`);
  const decoder = new PmwDecoder({ onLevel: write });
  await decoder.feed(bytes);
  const end = await decoder.close();
  process.stdout.write(`${JSON.stringify({ end })}\n`);
} catch (e) {
  process.stderr.write(`dump: error: ${e.name}: ${e.message}\n`);
  process.exit(2);
}
