/**
 * Chunk payloads (spec/bitstream.md §6): the batch table, the byte-plane columns, and the
 * application of a batch of vertex splits to a mesh held in typed arrays that grow with it (up to
 * the extension's full-resolution counts).
 */
import { FormatError, LimitError } from './errors.js';
import { MAX_BATCHES_PER_CHUNK, MAX_VERTICES } from './constants.js';

const TWO32 = 4294967296;
/** (125*3) packed symbol value x -> its three symbols at 3x..3x+2, least significant first. */
const TRIPLES = Uint8Array.from({ length: 375 }, (_, j) => Math.floor(Math.floor(j / 3) / 5 ** (j % 3)) % 5);
/** Symbol (0..4) -> 1 when it creates the left / the right new face (spec §6.1 step 2). */
const LEFT = Uint8Array.of(0, 0, 1, 0, 1);
const RIGHT = Uint8Array.of(0, 0, 0, 1, 1);

/**
 * The column at `at` (spec §6: a width byte, then `count` values as byte planes): its width, the
 * offset of its first plane and the offset after it. Checks the layout only, not the values.
 */
function column(p, at, count, name) {
  if (at >= p.length) throw new FormatError(`chunk payload: column ${name} is missing`);
  const width = p[at];
  if (width !== 1 && width !== 2 && width !== 4 && width !== 8) {
    throw new FormatError(`chunk payload: column ${name} has invalid width ${width}`);
  }
  const end = at + 1 + width * count;
  if (end > p.length) throw new FormatError(`chunk payload: column ${name} is cut short`);
  return { width, start: at + 1, end };
}

/**
 * A column's `count` values (byte plane j of value i is at start + j*count + i): for width 1 the
 * payload's own bytes (a view, no copy), for widths 2 and 4 a Uint32Array, for width 8 a
 * Float64Array (exact below 2^53; larger values only matter to be rejected).
 */
function columnValues(p, { width, start: s }, count) {
  if (width === 1) return p.subarray(s, s + count);
  if (width === 2) {
    const out = new Uint32Array(count);
    for (let i = 0; i < count; i++) out[i] = p[s + i] | (p[s + count + i] << 8);
    return out;
  }
  const out = width === 4 ? new Uint32Array(count) : new Float64Array(count);
  for (let i = 0, c = count; i < count; i++) {
    out[i] = (p[s + i] | (p[s + c + i] << 8) | (p[s + 2 * c + i] << 16) | (p[s + 3 * c + i] << 24)) >>> 0;
  }
  for (let plane = 4; plane < width; plane++) { // width 8: bytes 4..7 only need to be seen as "large"
    const src = s + plane * count;
    const scale = TWO32 * 2 ** (8 * plane - 32);
    for (let i = 0; i < count; i++) out[i] += p[src + i] * scale;
  }
  return out;
}

/**
 * Writes the zigzag-decoded values of residual column `col` (K values) into column d of
 * `residuals` (K*D row-major). Widths 1-4 hold values below 2^32, decoded in 32-bit integers;
 * width 8 goes through doubles and rejects a value above 2^32 (spec §6).
 */
function unzigzagInto(p, col, K, D, d, residuals) {
  const s = col.start;
  if (col.width === 8) {
    const z = columnValues(p, col, K);
    for (let i = 0; i < K; i++) {
      if (z[i] > TWO32) throw new FormatError(`chunk payload: residual ${d} out of range`);
      const half = Math.floor(z[i] / 2); // zigzag: 2r for r >= 0, -2r - 1 for r < 0
      residuals[i * D + d] = z[i] === 2 * half ? half : -half - 1;
    }
    return;
  }
  for (let i = 0, o = d; i < K; i++, o += D) {
    let z = p[s + i];
    if (col.width >= 2) z |= p[s + K + i] << 8;
    if (col.width === 4) z = (z | (p[s + 2 * K + i] << 16) | (p[s + 3 * K + i] << 24)) >>> 0;
    residuals[o] = (z >>> 1) ^ -(z & 1); // zigzag: 2r for r >= 0, -2r - 1 for r < 0
  }
}

/**
 * Parses a chunk payload against D values per vertex and at most `maxSplits` splits.
 * @returns {{batches: {k:number, I:number}[], v: Int32Array, symbols: Uint8Array, residuals: Int32Array|Float64Array}}
 *   v: (K) split vertices (batch-relative gaps resolved); symbols: (I); residuals: (K*D) row-major per split,
 *   an Int32Array unless a residual column has width 8.
 */
export function unpackPayload(p, D, maxSplits) {
  if (p.length < 4) throw new FormatError('chunk payload: shorter than its header');
  const dv = new DataView(p.buffer, p.byteOffset, p.byteLength);
  const batchCount = dv.getUint32(0, true);
  if (batchCount < 1 || batchCount > MAX_BATCHES_PER_CHUNK) {
    throw new LimitError(`chunk payload: batch count ${batchCount} outside 1..${MAX_BATCHES_PER_CHUNK}`);
  }
  if (4 + 8 * batchCount > p.length) throw new FormatError('chunk payload: batch table is cut short');
  const batches = [];
  let K = 0;
  let I = 0;
  for (let j = 0; j < batchCount; j++) {
    const k = dv.getUint32(4 + 8 * j, true);
    const inc = dv.getUint32(8 + 8 * j, true);
    if (k < 1) throw new LimitError(`chunk payload: batch ${j} has no splits`);
    batches.push({ k, I: inc });
    K += k;
    I += inc;
  }
  if (K > maxSplits) throw new LimitError(`chunk payload: ${K} splits, more than the limit ${maxSplits}`);
  const packedCount = Math.ceil(I / 3);
  if (K * (D + 1) + packedCount > p.length) throw new FormatError('chunk payload: declared counts exceed the payload size');
  const gapColumn = column(p, 4 + 8 * batchCount, K, 'gaps');
  const symbolColumn = column(p, gapColumn.end, packedCount, 'symbols');
  let at = symbolColumn.end;
  const residualColumns = [];
  for (let d = 0; d < D; d++) {
    residualColumns.push(column(p, at, K, d < 3 ? `residual_${'xyz'[d]}` : `attribute_${d - 3}`));
    at = residualColumns[d].end;
  }
  if (at !== p.length) throw new FormatError(`chunk payload: ${p.length - at} trailing bytes`);
  const symbols = new Uint8Array(packedCount * 3);
  const packed = columnValues(p, symbolColumn, packedCount);
  for (let t = 0; t < packedCount; t++) {
    const x = packed[t];
    if (x >= 125) throw new FormatError('chunk payload: unknown incidence symbol');
    symbols[3 * t] = TRIPLES[3 * x];
    symbols[3 * t + 1] = TRIPLES[3 * x + 1];
    symbols[3 * t + 2] = TRIPLES[3 * x + 2];
  }
  const gaps = columnValues(p, gapColumn, K);
  const v = new Int32Array(K);
  let s = 0;
  for (const { k } of batches) {
    let prev = -1;
    for (let i = 0; i < k; i++) {
      const g = gaps[s + i];
      if (g > MAX_VERTICES) throw new FormatError('chunk payload: split vertex gap out of range');
      prev += g + 1;
      // a vertex past MAX_VERTICES can be no vertex of the mesh (spec: it MUST be < n <= MAX_VERTICES)
      if (prev >= MAX_VERTICES) throw new FormatError('chunk payload: split vertex out of range');
      v[s + i] = prev;
    }
    s += k;
  }
  // widths 1-4 give residuals within int32; only a width-8 column (valid streams have none) needs doubles
  const residuals = residualColumns.some((c) => c.width === 8) ? new Float64Array(K * D) : new Int32Array(K * D);
  for (let d = 0; d < D; d++) unzigzagInto(p, residualColumns[d], K, D, d, residuals);
  return { batches, v, symbols: symbols.subarray(0, I), residuals };
}

/**
 * Adds to `sums` (k*D) the a and b corners of every moved face r < moved of a batch: a moved face
 * gives a + b to the ring of its new vertex, a left new face v + a, a right one v + b (v is added
 * per split by the caller). owner/after/before (moved) Int32Array, sym (moved) Uint8Array.
 */
function ringSums(D, moved, owner, after, before, sym, values, sums) {
  for (let r = 0; r < moved; r++) {
    const s = sym[r];
    const wa = 1 + LEFT[s];
    const wb = 1 + RIGHT[s];
    const a = after[r] * D;
    const b = before[r] * D;
    const o = owner[r] * D;
    for (let d = 0; d < D; d++) sums[o + d] += wa * values[a + d] + wb * values[b + d];
  }
}

/** ringSums for D = 3 (positions only), unrolled. */
function ringSums3(moved, owner, after, before, sym, values, sums) {
  for (let r = 0; r < moved; r++) {
    const s = sym[r];
    const wa = 1 + LEFT[s];
    const wb = 1 + RIGHT[s];
    const a = 3 * after[r];
    const b = 3 * before[r];
    const o = 3 * owner[r];
    sums[o] += wa * values[a] + wb * values[b];
    sums[o + 1] += wa * values[a + 1] + wb * values[b + 1];
    sums[o + 2] += wa * values[a + 2] + wb * values[b + 2];
  }
}

/**
 * A primitive's mesh as it grows, in typed arrays whose capacity follows what is decoded: they
 * start at the base mesh's size and grow geometrically (reserve, called once a batch or face chunk
 * knows how much it can add), never past the extension's full-resolution counts capN / capM, which
 * are only upper bounds: a file that declares far more than its chunks decode costs no memory for it
 * (spec/README.md "Conformance").
 *
 *   values (N*D) Int32Array       row-major: vertex i's D integer values at [i*D, i*D+D) -- grid
 *                                 x, y, z, then attribute components. Valid values are < 2^30; a
 *                                 hostile stream whose value leaves the int32 range turns the array
 *                                 into a Float64Array (exact, as the reference decoder's int64)
 *   faces  (M*3) Uint32Array      face f's vertex ids at corners 3f, 3f+1, 3f+2
 *   slot   (N)   Int32Array       -1 for every vertex, except during a batch, where slot[v[i]] = i
 *                                 for the batch's split vertices
 *   mark   (N)   Uint8Array       0 for every vertex, except 1 for the split vertices during a batch
 *                                 (what the corner scan reads: a quarter of slot's bytes)
 *
 * N = vertexCapacity (n <= N <= capN), M = faceCapacity (m <= M <= capM). `n`, `m`: vertices and
 * faces in use. No per-vertex incidence lists: a batch scans the corners of its m faces once, in
 * order (spec §6.1 step 1), which costs less than keeping lists up to date. Per-batch scratch arrays
 * (see #scratch) are kept between batches and grown geometrically.
 */
export class MeshState {
  constructor(values, faces, n, m, D, capN, capM) {
    if (n > capN || m > capM) throw new FormatError('declared full-resolution counts are smaller than the base mesh');
    this.D = D;
    this.capN = capN;
    this.capM = capM;
    this.values = new Int32Array(0); // 4 bytes a value: the ring sums' scattered reads cost less
    this.faces = new Uint32Array(0);
    this.slot = new Int32Array(0);
    this.mark = new Uint8Array(0);
    this.vertexCapacity = 0;
    this.faceCapacity = 0;
    this.n = 0;
    this.m = 0;
    this.reserve(n, m);
    this.values.set(values.subarray(0, n * D));
    this.faces.set(faces.subarray(0, m * 3));
    this.n = n;
    this.m = m;
    this.perIncidence = { size: 0 };
    this.perSplit = { size: 0 };
  }

  /**
   * Room for `vertices` vertices and `faces` faces: an array too small is replaced by one of twice
   * its capacity (or the size asked, when more), at most capN / capM, its contents kept (all of them:
   * a chunk may have written past n / m already; slot's new entries -1, mark's 0). FormatError when
   * the size asked is past capN / capM; LimitError when the memory cannot be had.
   */
  reserve(vertices, faces) {
    if (vertices > this.capN) throw new FormatError('splits exceed the declared vertex count');
    if (faces > this.capM) throw new FormatError('splits exceed the declared face count');
    const grown = (need, have, cap) => Math.min(Math.max(need, 2 * have), cap);
    try {
      if (vertices > this.vertexCapacity) {
        const N = grown(vertices, this.vertexCapacity, this.capN);
        const { D } = this;
        const values = new this.values.constructor(N * D);
        values.set(this.values);
        const slot = new Int32Array(N).fill(-1);
        slot.set(this.slot);
        const mark = new Uint8Array(N);
        mark.set(this.mark);
        this.values = values;
        this.slot = slot;
        this.mark = mark;
        this.vertexCapacity = N;
      }
      if (faces > this.faceCapacity) {
        const M = grown(faces, this.faceCapacity, this.capM);
        const arr = new Uint32Array(M * 3);
        arr.set(this.faces);
        this.faces = arr;
        this.faceCapacity = M;
      }
    } catch (e) {
      if (!(e instanceof RangeError)) throw e;
      throw new LimitError(`cannot allocate ${vertices} vertices and ${faces} faces (${e.message})`);
    }
  }

  /** Moves the values to a Float64Array (exact integers up to 2^53) and returns it. */
  #widen() {
    if (!(this.values instanceof Float64Array)) this.values = Float64Array.from(this.values);
    return this.values;
  }

  /**
   * Scratch arrays of a batch with I incidences and k splits, reused from batch to batch:
   * inc (I+1) Int32Array incidence corners; per moved face (at most I): owner, after, before
   * Int32Array and sym Uint8Array; per split: sums (k*D) Float64Array, ring and wings (k)
   * Int32Array, all three zeroed.
   */
  #scratch(I, k) {
    const D = this.D;
    if (this.perIncidence.size < I + 1) {
      const size = Math.max(I + 1, 2 * this.perIncidence.size);
      this.perIncidence = {
        size, inc: new Int32Array(size), owner: new Int32Array(size), after: new Int32Array(size),
        before: new Int32Array(size), sym: new Uint8Array(size),
      };
    }
    if (this.perSplit.size < k) {
      const size = Math.max(k, 2 * this.perSplit.size);
      this.perSplit = { size, sums: new Float64Array(size * D), ring: new Int32Array(size), wings: new Int32Array(size) };
    }
    const { sums, ring, wings } = this.perSplit;
    sums.fill(0, 0, k * D);
    ring.fill(0, 0, k);
    wings.fill(0, 0, k);
    return { ...this.perIncidence, sums, ring, wings };
  }

  /**
   * Applies one batch (spec/bitstream.md §6.1) in place. On a FormatError the mesh may be left
   * half changed (the decoder then refuses to show it).
   * @param {Int32Array} v (k) split vertices; symbols (I) Uint8Array; residuals (k*D) Int32Array or Float64Array
   */
  applyBatch(v, symbols, residuals) {
    const { D } = this;
    const k = v.length;
    const n = this.n;
    if (n + k > this.capN) throw new FormatError('splits exceed the declared vertex count');
    for (let i = 0; i < k; i++) {
      if (v[i] >= n || (i > 0 && v[i] <= v[i - 1])) throw new FormatError('split vertex ids out of range or not increasing');
    }
    this.reserve(n + k, Math.min(this.m + 2 * k, this.capM)); // k new vertices, one or two new faces a split
    let { values } = this;
    const work = this.#scratch(symbols.length, k);
    const { sums, ring, wings } = work; // (k*D) ring sums of u_i row-major; (k) ring corners, new faces
    const mNew = this.#split(v, symbols, work);
    for (let i = 0; i < k; i++) {
      if (wings[i] < 1 || wings[i] > 2) throw new FormatError('a split names no new face or more than two');
      const r = ring[i];
      for (let d = 0, o = i * D; d < D; d++, o++) {
        const x = Math.floor(sums[o] / r) + residuals[o];
        if (x !== (x | 0)) values = this.#widen(); // outside int32: never in a valid stream
        values[n * D + o] = x;
      }
    }
    this.n = n + k;
    this.m = mNew;
  }

  /**
   * Steps 1-3 of spec §6.1. A scan of the corners of faces 0..m-1 lists the incidences in order
   * (branch-free: every corner is written, the count advances on a split vertex); then each
   * incidence t takes symbol t, its corner is rewritten (to u_i >= n, never a split vertex) and
   * new faces are appended after face m-1. Each moved face is recorded (owner i, corners a and b,
   * symbol) and the ring sums are added from those records in a loop without branches, whose
   * scattered reads of `values` the CPU can overlap. Fills sums, ring and wings; returns the new
   * face count.
   */
  #split(v, symbols, { inc, owner, after, before, sym, sums, ring, wings }) {
    const { D, values, slot, mark, capM, n, m } = this;
    let { faces, faceCapacity } = this; // grown here only by a hostile stream (more than two new faces a split)
    const k = v.length;
    const I = symbols.length;
    const end = 3 * m;
    // inc: incidence corners in ascending order; per moved face: owner (split index),
    // after / before (the corners after / before v), sym (its symbol)
    let moved = 0;
    let count = 0;
    let mNew = m;
    for (let i = 0; i < k; i++) {
      slot[v[i]] = i;
      mark[v[i]] = 1;
    }
    try {
      for (let c = 0; c < end; c += 3) { // one face per step
        inc[count] = c; // inc holds >= I + 1; a write past its end is dropped (count > I only fails)
        count += mark[faces[c]];
        inc[count] = c + 1;
        count += mark[faces[c + 1]];
        inc[count] = c + 2;
        count += mark[faces[c + 2]];
      }
      if (count !== I) throw new FormatError(`batch has ${I} incidence symbols, the mesh has ${count} incidences`);
      for (let t = 0; t < I; t++) {
        const s = symbols[t];
        if (s === 0) continue;
        const c = inc[t];
        const i = slot[faces[c]];
        const f = c - (c % 3);
        const a = faces[f + ((c + 1) % 3)]; // corner after v
        const b = faces[f + ((c + 2) % 3)]; // corner before v
        const u = n + i;
        const vi = v[i];
        faces[c] = u;
        const left = LEFT[s];
        const right = RIGHT[s];
        if (left + right + mNew > faceCapacity) {
          if (left + right + mNew > capM) throw new FormatError('splits exceed the declared face count');
          this.reserve(0, mNew + left + right);
          ({ faces, faceCapacity } = this);
        }
        if (left) {
          faces[3 * mNew] = u; faces[3 * mNew + 1] = vi; faces[3 * mNew + 2] = a; mNew++;
        }
        if (right) {
          faces[3 * mNew] = vi; faces[3 * mNew + 1] = u; faces[3 * mNew + 2] = b; mNew++;
        }
        ring[i] += 2 + 2 * (left + right);
        wings[i] += left + right;
        owner[moved] = i;
        after[moved] = a;
        before[moved] = b;
        sym[moved++] = s;
      }
    } finally {
      for (let i = 0; i < k; i++) {
        slot[v[i]] = -1;
        mark[v[i]] = 0;
      }
    }
    if (D === 3) ringSums3(moved, owner, after, before, sym, values, sums);
    else ringSums(D, moved, owner, after, before, sym, values, sums);
    for (let i = 0; i < k; i++) { // v once per new face, read in vertex order
      const w = wings[i];
      const x = v[i] * D;
      const o = i * D;
      for (let d = 0; d < D; d++) sums[o + d] += w * values[x + d];
    }
    return mNew;
  }

  /** Applies a whole unpacked chunk payload (see unpackPayload), batch after batch. */
  applyPayload({ batches, v, symbols, residuals }) {
    let s = 0;
    let t = 0;
    for (const { k, I } of batches) {
      this.applyBatch(v.subarray(s, s + k), symbols.subarray(t, t + I), residuals.subarray(s * this.D, (s + k) * this.D));
      s += k;
      t += I;
    }
  }
}
