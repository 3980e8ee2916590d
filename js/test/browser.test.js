// The three.js plugin in headless Chromium (Debian's /usr/bin/chromium through playwright-core): a page on
// 127.0.0.1 loads a .pmw through loadProgressive. Skipped when Chromium is absent (CI installs it).
import assert from 'node:assert/strict';
import fs from 'node:fs';
import os from 'node:os';
import path from 'node:path';
import { after, before, test } from 'node:test';
import { fileURLToPath } from 'node:url';
import { decodePmw } from '../src/index.js';
import { startServer } from './lib/server.js';

const CHROMIUM = process.env.CHROMIUM ?? '/usr/bin/chromium';
const skip = fs.existsSync(CHROMIUM) ? false : `no Chromium at ${CHROMIUM}`;
const root = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '../..');
const NAME = 'spec/conformance/sphere-attributes.plain.v1.pmw';
const bytes = new Uint8Array(fs.readFileSync(path.join(root, NAME)));
let browser; let profile; const servers = {};

before(async () => {
  if (skip) return;
  const { chromium } = await import('playwright-core');
  profile = fs.mkdtempSync(path.join(os.tmpdir(), 'pmwm-chromium-'));
  // a fresh profile directory (playwright passes it as --user-data-dir)
  browser = await chromium.launchPersistentContext(profile, { executablePath: CHROMIUM, headless: true,
    args: ['--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
      '--disable-background-networking', '--disable-component-update', '--disable-sync', '--enable-unsafe-swiftshader'] });
  servers.fast = await startServer(root);
  servers.slow = await startServer(root, { delayMs: 60 });
  servers.plain = await startServer(root, { ranges: false });
});
after(async () => {
  await browser?.close();
  for (const s of Object.values(servers)) await s.close();
  if (profile) fs.rmSync(profile, { recursive: true, force: true });
});

async function load(server, query) {
  const page = await browser.newPage();
  try {
    await page.goto(`${server.url}js/test/browser/index.html?src=/${NAME}&${query}`);
    await page.waitForFunction(() => window.result !== undefined, null, { timeout: 60000 });
    const out = await page.evaluate(() => ({ result: window.result, levels: window.levels }));
    assert.equal(out.result.error, undefined, out.result.error);
    return out;
  } finally {
    await page.close();
  }
}

test('a throttled Range load reaches the full vertex count through at least three distinct rendered levels', { skip }, async () => {
  const full = await decodePmw(bytes);
  const { result, levels } = await load(servers.slow, '');
  assert.equal(result.complete, true);
  assert.equal(result.vertices, full.positions.length / 3);
  assert.ok(new Set(levels.map((l) => l.image)).size >= 3, `${levels.length} levels`);
  assert.ok(new Set(levels.map((l) => l.vertexCount)).size >= 3);
});

test('a plain (no Range) load reaches the full vertex count', { skip }, async () => {
  const full = await decodePmw(bytes);
  const { result } = await load(servers.plain, 'range=0');
  assert.equal(result.complete, true);
  assert.equal(result.vertices, full.positions.length / 3);
});

test('a load stopped after a byte budget shows the level of the cut file', { skip }, async () => {
  const [three, four] = [await decodePmw(bytes, { chunks: 3 }), await decodePmw(bytes, { chunks: 4 })];
  const budget = Math.floor((three.bytesRead + four.bytesRead) / 2);
  const { result } = await load(servers.fast, `budget=${budget}`);
  assert.equal(result.chunksApplied, 3);
  assert.equal(result.vertices, three.positions.length / 3);
});

test('a Range load of two chunks fetches only the bytes it needs (counted at the server)', { skip }, async () => {
  const two = await decodePmw(bytes, { chunks: 2 });
  servers.fast.stats.bytes = 0;
  const { result } = await load(servers.fast, 'chunks=2');
  assert.equal(result.chunksApplied, 2);
  assert.equal(servers.fast.stats.bytes, two.bytesRead);
  assert.ok(two.bytesRead < bytes.length);
});
