/**
 * The adaptive binary range decoder of chunk payload version 2 and its integer binarisations
 * (spec/bitstream.md §8.1-§8.2), LZMA style. Probabilities are 11-bit values in a Uint16Array
 * table that the caller keeps per primitive (it carries from chunk to chunk). No allocation per
 * decoded symbol.
 */
import { FormatError } from './errors.js';

const PROB_BITS = 11;
const PROB_ONE = 1 << PROB_BITS;
const ADAPT_SHIFT = 4;
const TOP = 1 << 24;
/** Integer context block: bucket tree nodes [1, 64), mantissa nodes at 64 + 3b + t, sign at 192 + b. */
export const INT_BLOCK = 256;
const INT_MANTISSA = 64;
const INT_SIGN = 192;
const BUCKET_BITS = 6;
/** Largest bucket (bit length) of a coded magnitude: values below 2^32. */
const MAX_BUCKET = 32;

/** 2^b for b = 0 .. 32. */
const POW2 = Float64Array.from({ length: MAX_BUCKET + 1 }, (_, b) => 2 ** b);

/** A probability table of `size` entries, every one 1024 (probability 1/2): a primitive's first chunk. */
export function newProbabilities(size) {
  return new Uint16Array(size).fill(PROB_ONE >> 1);
}

/**
 * Decoding state over one chunk's stored bytes `buf` (Uint8Array), adapting `probs` (Uint16Array) in
 * place. `range` and `code` are held as int32 bit patterns of the unsigned 32-bit values (compared
 * after `>>> 0`), which V8 keeps unboxed: the same arithmetic as §8.1 modulo 2^32, where no
 * operation of a conforming decoder wraps.
 */
export class RangeDecoder {
  constructor(buf, probs) {
    this.buf = buf;
    this.probs = probs;
    this.length = buf.length;
    this.overrun = false;
    this.pos = 0;
    this.range = -1; // 0xFFFFFFFF
    let code = 0;
    for (let i = 0; i < 4; i++) code = (code << 8) | this.#next();
    this.code = code;
  }

  /** NextByte: buf[pos], or 0 past the end (the stream is then overrun). */
  #next() {
    const pos = this.pos++;
    if (pos < this.length) return this.buf[pos];
    this.overrun = true;
    return 0;
  }

  /** Normalize: while range < 2^24, shift a byte in. */
  #normalize() {
    while ((this.range >>> 0) < TOP) {
      this.range <<= 8;
      this.code = (this.code << 8) | this.#next(); // (code * 256 + byte) mod 2^32
    }
  }

  /** DecodeBit(i): one bit under the adaptive probability probs[i]. */
  bit(i) {
    const { probs } = this;
    const p = probs[i];
    const bound = Math.imul(this.range >>> PROB_BITS, p); // < 2^32: exact
    let bit;
    if ((this.code >>> 0) < (bound >>> 0)) {
      this.range = bound;
      probs[i] = p + ((PROB_ONE - p) >> ADAPT_SHIFT);
      bit = 0;
    } else {
      this.code = (this.code - bound) | 0;
      this.range = (this.range - bound) | 0;
      probs[i] = p - (p >> ADAPT_SHIFT);
      bit = 1;
    }
    if ((this.range >>> 0) < TOP) this.#normalize();
    return bit;
  }

  /** DecodeDirect: one bit of probability 1/2, no model. */
  direct() {
    this.range >>>= 1;
    let bit = 0;
    if ((this.code >>> 0) >= this.range) {
      this.code = (this.code - this.range) | 0;
      bit = 1;
    }
    this.#normalize();
    return bit;
  }

  /** Tree(base, nbits): nbits bits, most significant first, node `node` under probs[base + node]. */
  tree(base, nbits) {
    let node = 1;
    for (let t = 0; t < nbits; t++) node = 2 * node + this.bit(base + node);
    return node - (1 << nbits);
  }

  /** The b - 1 bits below the leading one of a bucket-b magnitude: two adaptive, the rest direct. */
  #mantissa(base, b) {
    let m = 0;
    let first = 0;
    for (let pos = 0; pos < b - 1; pos++) {
      let bit;
      if (pos === 0) first = bit = this.bit(base + INT_MANTISSA + 3 * b);
      else if (pos === 1) bit = this.bit(base + INT_MANTISSA + 3 * b + 1 + first);
      else bit = this.direct();
      m = 2 * m + bit;
    }
    return m;
  }

  /** The bucket of an integer under the block at `base`; FormatError above 32. */
  #bucket(base, what) {
    const b = this.tree(base, BUCKET_BITS);
    if (b > MAX_BUCKET) throw new FormatError(`chunk payload: ${what} has an invalid bucket ${b}`);
    return b;
  }

  /** UInt(base): an unsigned integer below 2^32. */
  uint(base, what) {
    const b = this.#bucket(base, what);
    if (b < 2) return b;
    return POW2[b - 1] + this.#mantissa(base, b);
  }

  /** SInt(base): a signed integer of magnitude below 2^32. */
  sint(base, what) {
    const b = this.#bucket(base, what);
    if (b === 0) return 0;
    const neg = this.bit(base + INT_SIGN + b);
    const a = b === 1 ? 1 : POW2[b - 1] + this.#mantissa(base, b);
    return neg ? -a : a;
  }

  /** Termination (§8.1): FormatError unless exactly the stored bytes were read, without overrun. */
  finish() {
    if (this.overrun || this.pos !== this.length) {
      throw new FormatError(`chunk payload: the coded stream does not end at the end of the payload (${this.pos} bytes read of ${this.length})`);
    }
  }
}
