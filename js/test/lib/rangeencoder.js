/**
 * Test-only range encoder of chunk payload version 2 (spec/bitstream.md §8.1-§8.2): LZMA's
 * encoder (`low` 33 bits, a cache byte and carry propagation, five ShiftLow calls to flush, the
 * first output byte dropped) and the UInt binarisation, so that tests can write streams of any
 * decisions, hostile ones included, without the Python encoder. Checked against §8.5's bytes.
 */
const TOP = 2 ** 24;
const TWO32 = 2 ** 32;

export class RangeEncoder {
  /** @param {number} size the probability table's size (every entry 1024) */
  constructor(size) {
    this.probs = new Uint16Array(size).fill(1024);
    this.low = 0; // < 2^33
    this.range = 0xffffffff;
    this.cache = 0;
    this.cacheSize = 1;
    this.out = [];
  }

  #shiftLow() {
    if (this.low < 0xff000000 || this.low >= TWO32) {
      const carry = this.low >= TWO32 ? 1 : 0;
      let temp = this.cache;
      do {
        this.out.push((temp + carry) & 0xff);
        temp = 0xff;
      } while (--this.cacheSize !== 0);
      this.cache = Math.floor((this.low % TWO32) / TOP);
    }
    this.cacheSize++;
    this.low = (this.low % TOP) * 256;
  }

  #normalize() {
    while (this.range < TOP) {
      this.range = (this.range * 256) % TWO32;
      this.#shiftLow();
    }
  }

  /** EncodeBit under probs[i] (adapted as DecodeBit adapts it). */
  bit(i, bit) {
    const p = this.probs[i];
    const bound = Math.floor(this.range / 2048) * p;
    if (bit === 0) {
      this.range = bound;
      this.probs[i] = p + ((2048 - p) >> 4);
    } else {
      this.low += bound;
      this.range -= bound;
      this.probs[i] = p - (p >> 4);
    }
    this.#normalize();
  }

  /** A bit of probability 1/2 (DecodeDirect). */
  direct(bit) {
    this.range = Math.floor(this.range / 2);
    if (bit) this.low += this.range;
    this.#normalize();
  }

  /** Tree(base, nbits) of value x, most significant bit first. */
  tree(base, nbits, x) {
    let node = 1;
    for (let t = nbits - 1; t >= 0; t--) {
      const b = Math.floor(x / 2 ** t) % 2;
      this.bit(base + node, b);
      node = 2 * node + b;
    }
  }

  /** UInt(base) of x (0 <= x < 2^32); `bucket` forces the bucket (a hostile b > 32 when asked). */
  uint(base, x, bucket) {
    const b = bucket ?? (x === 0 ? 0 : Math.floor(Math.log2(x)) + 1);
    this.tree(base, 6, b);
    if (b < 2 || b > 32) return;
    const m = x - 2 ** (b - 1);
    const bitAt = (t) => Math.floor(m / 2 ** t) % 2; // bit t of the mantissa (b - 1 bits)
    const f = bitAt(b - 2);
    this.bit(base + 64 + 3 * b, f);
    if (b === 2) return;
    this.bit(base + 64 + 3 * b + 1 + f, bitAt(b - 3));
    for (let t = b - 4; t >= 0; t--) this.direct(bitAt(t));
  }

  /** SInt(base) of x. */
  sint(base, x) {
    const a = Math.abs(x);
    const b = a === 0 ? 0 : Math.floor(Math.log2(a)) + 1;
    this.tree(base, 6, b);
    if (b === 0) return;
    this.bit(base + 192 + b, x < 0 ? 1 : 0);
    if (b === 1) return;
    const m = a - 2 ** (b - 1);
    const bitAt = (t) => Math.floor(m / 2 ** t) % 2;
    const f = bitAt(b - 2);
    this.bit(base + 64 + 3 * b, f);
    if (b === 2) return;
    this.bit(base + 64 + 3 * b + 1 + f, bitAt(b - 3));
    for (let t = b - 4; t >= 0; t--) this.direct(bitAt(t));
  }

  /** The stored bytes: five ShiftLow calls, the first byte (always 0) dropped. */
  finish() {
    for (let i = 0; i < 5; i++) this.#shiftLow();
    return Uint8Array.from(this.out.slice(1));
  }
}

const block = (b) => 32 + 256 * b;

/** Size of a face chunk's probability table (spec §8.6): 32 single probabilities, 9 integer blocks. */
export const FACE_TABLE = 32 + 9 * 256;

/**
 * The stored bytes of a face chunk (spec §8.6) coding `faces`: each {gap, b, c, twin} with b / c
 * either {rank} (bit 1, the rank in Up(a) / Near(a, b)), {fresh: true} (bits 0 and 1: the next new
 * vertex) or {raw} (bits 0 and 0, x - a - 1); `count` overrides the coded G (default
 * faces.length); `residuals` (one array of D residuals per new vertex, in order) follow the faces,
 * residual q under block `valueBlock(q)` (spec: 5 + min(q, 3); another only to show that a
 * decoder tells them apart). No check: hostile streams are the point.
 */
export function faceChunkBytes(faces, count = faces.length, residuals = [], valueBlock = (q) => 5 + Math.min(q, 3)) {
  const e = new RangeEncoder(FACE_TABLE + 8 * 256); // room for a valueBlock past the table's 9 blocks
  e.uint(block(0), count - 1);
  for (const { gap, b, c, twin } of faces) {
    e.uint(block(1), gap);
    for (const [x, near, rankBlock] of [[b, 0, 2], [c, 1, 3]]) {
      e.bit(near, 'rank' in x ? 1 : 0);
      if ('rank' in x) {
        e.uint(block(rankBlock), x.rank);
        continue;
      }
      e.bit(3, x.fresh ? 1 : 0);
      if (!x.fresh) e.uint(block(4), x.raw);
    }
    e.bit(2, twin ? 1 : 0);
  }
  for (const row of residuals) row.forEach((r, q) => e.sint(block(valueBlock(q)), r));
  return e.finish();
}
