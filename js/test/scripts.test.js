/** The package's scripts as a user runs them: without their arguments they say how to call them. */
import assert from 'node:assert/strict';
import { spawnSync } from 'node:child_process';
import { dirname, join } from 'node:path';
import { test } from 'node:test';
import { fileURLToPath } from 'node:url';

const BENCH = join(dirname(fileURLToPath(import.meta.url)), '..', 'bench', 'bench.mjs');

test('npm run bench without its files prints its usage and exits 2 (no stack trace)', () => {
  const run = spawnSync(process.execPath, [BENCH], { encoding: 'utf8' });
  assert.equal(run.status, 2);
  assert.match(run.stderr, /^usage: node bench\/bench\.mjs FILE\.pmw FILE\.drc/);
});
