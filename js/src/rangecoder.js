/**
 * The adaptive binary range decoder of chunk payload version 2 and its integer binarisations
 * (spec/bitstream.md §8.1-§8.2), LZMA style. Probabilities are 11-bit values in a Uint16Array
 * table that the caller keeps per primitive (it carries from chunk to chunk). No allocation per
 * decoded symbol.
 */
import { FormatError } from './errors.js';

/**
 * §8.1 constants. Not exported: V8 folds a module's own constants into its optimised code, but
 * loads an exported (or imported) one from its cell at every use, which cost the loops here a
 * fifth of their time on the Stanford bunny (shifts by a loaded count, comparisons in floating
 * point).
 */
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
 * operation of a conforming decoder wraps. UInt / SInt copy `range`, `code` and `pos` into locals
 * and store them back when done.
 */
export class RangeDecoder {
  constructor(buf, probs) {
    this.buf = buf;
    this.probs = probs;
    this.length = buf.length;
    this.pos = 0;
    this.range = -1; // 0xFFFFFFFF
    let code = 0;
    for (let i = 0; i < 4; i++) code = (code << 8) | this.#next();
    this.code = code;
  }

  /** NextByte: buf[pos], or 0 past the end (the stream is then overrun); pos += 1. */
  #next() {
    const pos = this.pos++;
    return pos < this.length ? this.buf[pos] : 0;
  }

  /** Whether a byte past the end was read: pos counts every NextByte, so pos > length. */
  get overrun() {
    return this.pos > this.length;
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

  /**
   * UInt / SInt (§8.2) with the coder's state in locals: the 6-bit bucket tree, then (signed,
   * b >= 1) the sign, then the mantissa (two adaptive bits, the rest direct). Step 0..5 decodes
   * tree node `node`, step 6 the sign, steps 7 and 8 the adaptive mantissa bits. Returns the
   * value; FormatError for a bucket above 32.
   */
  #int(base, what, signed) {
    const { probs, buf, length } = this;
    let { range, code, pos } = this;
    let node = 1;
    let b = 0;
    let neg = 0;
    let m = 0;
    for (let step = 0, i = base + 1; ;) {
      const p = probs[i];
      const bound = Math.imul(range >>> PROB_BITS, p); // DecodeBit, as bit()
      let bit = 0;
      if ((code >>> 0) < (bound >>> 0)) {
        range = bound;
        probs[i] = p + ((PROB_ONE - p) >> ADAPT_SHIFT);
      } else {
        code = (code - bound) | 0;
        range = (range - bound) | 0;
        probs[i] = p - (p >> ADAPT_SHIFT);
        bit = 1;
      }
      while ((range >>> 0) < TOP) {
        range <<= 8;
        code = (code << 8) | (pos < length ? buf[pos] : 0);
        pos++;
      }
      if (step < 5) {
        node = 2 * node + bit;
        i = base + node;
      } else if (step === 5) {
        b = 2 * node + bit - (1 << BUCKET_BITS);
        if (b > MAX_BUCKET) {
          this.pos = pos; // the state as it is: the caller throws away the chunk
          throw new FormatError(`chunk payload: ${what} has an invalid bucket ${b}`);
        }
        if (b === 0 || (b === 1 && !signed)) break;
        if (signed) {
          i = base + INT_SIGN + b;
        } else {
          step = 6;
          i = base + INT_MANTISSA + 3 * b;
        }
      } else if (step === 6) {
        neg = bit;
        if (b === 1) break;
        i = base + INT_MANTISSA + 3 * b;
      } else if (step === 7) {
        m = bit;
        if (b === 2) break;
        i = base + INT_MANTISSA + 3 * b + 1 + bit;
      } else {
        m = 2 * m + bit;
        break;
      }
      step++;
    }
    for (let r = b - 3; r > 0; r--) { // DecodeDirect, as direct()
      range >>>= 1;
      let bit = 0;
      if ((code >>> 0) >= range) {
        code = (code - range) | 0;
        bit = 1;
      }
      m = 2 * m + bit;
      while ((range >>> 0) < TOP) {
        range <<= 8;
        code = (code << 8) | (pos < length ? buf[pos] : 0);
        pos++;
      }
    }
    this.range = range;
    this.code = code;
    this.pos = pos;
    const a = b < 2 ? b : POW2[b - 1] + m;
    return neg ? -a : a;
  }

  /** UInt(base): an unsigned integer below 2^32. */
  uint(base, what) {
    return this.#int(base, what, false);
  }

  /** SInt(base): a signed integer of magnitude below 2^32. */
  sint(base, what) {
    return this.#int(base, what, true);
  }

  /** Termination (§8.1): FormatError unless exactly the stored bytes were read, without overrun. */
  finish() {
    if (this.pos !== this.length) this.#endedElsewhere(); // also an overrun: pos > length
  }

  /**
   * finish()'s FormatError as soon as a byte past the end was read (§8.1: a stream that overruns never
   * terminates validly; decoding on would only spend time and memory on zeros).
   */
  checkOverrun() {
    if (this.overrun) this.#endedElsewhere();
  }

  #endedElsewhere() {
    throw new FormatError(`chunk payload: the coded stream does not end at the end of the payload (${this.pos} bytes read of ${this.length})`);
  }
}
