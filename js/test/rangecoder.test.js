/**
 * The range decoder of chunk payload version 2 against the worked example of
 * spec/bitstream.md §8.5 (bytes, decisions and probabilities), and its termination and bucket checks.
 */
import assert from 'node:assert/strict';
import { test } from 'node:test';
import { FormatError } from '../src/errors.js';
import { RangeDecoder, newProbabilities } from '../src/rangecoder.js';
import { N_PROBS } from '../src/payload-v2.js';

const EXAMPLE = Uint8Array.of(0x71, 0xb5, 0x88, 0x25, 0x00, 0x00);

/** The §8.5 decisions from `bytes` under a table of 16 + 256 probabilities: [values, prob[0] trace, decoder]. */
function decodeExample(bytes) {
  const probs = newProbabilities(16 + 256);
  const rc = new RangeDecoder(bytes, probs);
  const trace = [probs[0]];
  const bits = [];
  for (let i = 0; i < 3; i++) {
    bits.push(rc.bit(0));
    trace.push(probs[0]);
  }
  bits.push(rc.direct());
  return { values: [...bits, rc.uint(16, 'x'), rc.sint(16, 'y')], trace, rc, probs };
}

test('the worked example of spec §8.5 decodes to its decisions and probabilities, ending exactly at its 6 bytes', () => {
  const { values, trace, rc, probs } = decodeExample(EXAMPLE);
  assert.deepEqual(values, [0, 1, 1, 1, 5, -3]);
  assert.deepEqual(trace, [1024, 1088, 1020, 957]);
  assert.ok(probs[16 + 192 + 2] < 1024, 'the sign of bucket 2 adapted towards 1');
  assert.equal(rc.pos, 6);
  rc.finish();
});

test('a coded stream with a byte more, or a byte less, than it reads fails its termination check', () => {
  const longer = decodeExample(Uint8Array.of(...EXAMPLE, 0)).rc;
  assert.throws(() => longer.finish(), FormatError);
  const shorter = decodeExample(EXAMPLE.subarray(0, 5)).rc;
  assert.equal(shorter.overrun, true);
  assert.throws(() => shorter.finish(), FormatError);
});

test('an integer bucket above 32 is a FormatError, for UInt and SInt', () => {
  // probabilities of a 0 bit at their minimum and a code of all ones: every tree bit is 1, bucket 63
  for (const read of [(rc) => rc.uint(0, 'x'), (rc) => rc.sint(0, 'x')]) {
    const rc = new RangeDecoder(new Uint8Array(8).fill(0xff), newProbabilities(256).fill(1));
    assert.throws(() => read(rc), (e) => e instanceof FormatError && /invalid bucket 63/.test(e.message));
  }
});

test('a primitive\'s table has the 67872 probabilities of spec §8.3, every one 1024', () => {
  assert.equal(N_PROBS, 32 + 265 * 256);
  const probs = newProbabilities(N_PROBS);
  assert.equal(probs.length, 67872);
  assert.ok(probs.every((p) => p === 1024));
});
