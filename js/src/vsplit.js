/**
 * Chunk payloads (spec/bitstream.md §6): the batch table, the byte-plane columns, and the
 * application of a batch of vertex splits to a mesh held in typed arrays preallocated from the
 * extension's full-resolution counts.
 */
import { FormatError, LimitError } from './errors.js';
import { MAX_BATCHES_PER_CHUNK, MAX_VERTICES } from './constants.js';

const TWO32 = 4294967296;
/** Packed symbol value (0..124) -> its three symbols, least significant first. */
const TRIPLES = Array.from({ length: 125 }, (_, x) => Uint8Array.of(x % 5, Math.floor(x / 5) % 5, Math.floor(x / 25)));

/**
 * One column at `at`: its `count` values as a Float64Array (exact below 2^53; larger ones only
 * matter to be rejected) and the offset after it.
 */
function readColumn(p, at, count, name) {
  if (at >= p.length) throw new FormatError(`chunk payload: column ${name} is missing`);
  const width = p[at];
  if (width !== 1 && width !== 2 && width !== 4 && width !== 8) {
    throw new FormatError(`chunk payload: column ${name} has invalid width ${width}`);
  }
  const end = at + 1 + width * count;
  if (end > p.length) throw new FormatError(`chunk payload: column ${name} is cut short`);
  const out = new Float64Array(count);
  if (width === 1) {
    out.set(p.subarray(at + 1, end));
    return { values: out, end };
  }
  const lowPlanes = Math.min(width, 4);
  for (let plane = 0; plane < lowPlanes; plane++) {
    const src = at + 1 + plane * count;
    const scale = 2 ** (8 * plane);
    for (let i = 0; i < count; i++) out[i] += p[src + i] * scale;
  }
  for (let plane = 4; plane < width; plane++) { // width 8: bytes 4..7 only need to be seen as "large"
    const src = at + 1 + plane * count;
    const scale = TWO32 * 2 ** (8 * (plane - 4));
    for (let i = 0; i < count; i++) out[i] += p[src + i] * scale;
  }
  return { values: out, end };
}

/**
 * Parses a chunk payload against D values per vertex and at most `maxSplits` splits.
 * @returns {{batches: {k:number, I:number}[], v: Int32Array, symbols: Uint8Array, residuals: Float64Array}}
 *   v: (K) split vertices (batch-relative gaps resolved); symbols: (I); residuals: (K*D) row-major per split.
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
  let at = 4 + 8 * batchCount;
  const gaps = readColumn(p, at, K, 'gaps');
  const packed = readColumn(p, gaps.end, packedCount, 'symbols');
  at = packed.end;
  const columns = [];
  for (let d = 0; d < D; d++) {
    const col = readColumn(p, at, K, d < 3 ? `residual_${'xyz'[d]}` : `attribute_${d - 3}`);
    columns.push(col.values);
    at = col.end;
  }
  if (at !== p.length) throw new FormatError(`chunk payload: ${p.length - at} trailing bytes`);
  const symbols = new Uint8Array(packedCount * 3);
  for (let t = 0; t < packedCount; t++) {
    const x = packed.values[t];
    if (x >= 125) throw new FormatError('chunk payload: unknown incidence symbol');
    symbols.set(TRIPLES[x], 3 * t);
  }
  const v = new Int32Array(K);
  let s = 0;
  for (const { k } of batches) {
    let prev = -1;
    for (let i = 0; i < k; i++) {
      const g = gaps.values[s + i];
      if (g > MAX_VERTICES) throw new FormatError('chunk payload: split vertex gap out of range');
      prev += g + 1;
      // a vertex past MAX_VERTICES can be no vertex of the mesh (spec: it MUST be < n <= MAX_VERTICES)
      if (prev >= MAX_VERTICES) throw new FormatError('chunk payload: split vertex out of range');
      v[s + i] = prev;
    }
    s += k;
  }
  const residuals = new Float64Array(K * D);
  for (let d = 0; d < D; d++) {
    const col = columns[d];
    for (let i = 0; i < K; i++) {
      const z = col[i];
      if (z > TWO32) throw new FormatError(`chunk payload: residual ${d} out of range`);
      residuals[i * D + d] = z % 2 === 0 ? z / 2 : -(z + 1) / 2;
    }
  }
  return { batches, v, symbols: symbols.subarray(0, I), residuals };
}

/**
 * A primitive's mesh as it grows: `values` (capN*D) Float64Array of integer values per vertex
 * (grid x, y, z, then attribute components), `faces` (capM*3) Uint32Array, `n`/`m` in use, and
 * for every vertex the list of corners holding it (`head` (capN), `next` (capM*3) Int32Array,
 * -1 ends a list), so a batch finds its incidences without scanning every face.
 */
export class MeshState {
  constructor(values, faces, n, m, D, capN, capM) {
    if (n > capN || m > capM) throw new FormatError('declared full-resolution counts are smaller than the base mesh');
    this.D = D;
    this.capN = capN;
    this.capM = capM;
    try {
      this.values = new Float64Array(capN * D);
      this.faces = new Uint32Array(capM * 3);
      this.head = new Int32Array(capN).fill(-1);
      this.slot = new Int32Array(capN).fill(-1);
      this.next = new Int32Array(capM * 3);
    } catch (e) {
      if (!(e instanceof RangeError)) throw e;
      throw new LimitError(`cannot allocate ${capN} vertices and ${capM} faces (${e.message})`);
    }
    this.values.set(values.subarray(0, n * D));
    this.faces.set(faces.subarray(0, m * 3));
    for (let c = 3 * m - 1; c >= 0; c--) this.#link(c);
    this.n = n;
    this.m = m;
  }

  /** Puts corner c at the head of the list of the vertex it holds. */
  #link(c) {
    const x = this.faces[c];
    this.next[c] = this.head[x];
    this.head[x] = c;
  }

  /** The corners holding v[0..k) in ascending order (the face-slot order of spec §6.1 step 1). */
  #incidences(v, I) {
    const { head, next } = this;
    let count = 0;
    for (let i = 0; i < v.length; i++) {
      for (let c = head[v[i]]; c >= 0; c = next[c]) {
        if (++count > I) throw new FormatError(`batch has ${I} incidence symbols, the mesh has more incidences`);
      }
    }
    if (count !== I) throw new FormatError(`batch has ${I} incidence symbols, the mesh has ${count} incidences`);
    const inc = new Int32Array(count);
    let at = 0;
    for (let i = 0; i < v.length; i++) for (let c = head[v[i]]; c >= 0; c = next[c]) inc[at++] = c;
    return inc.sort();
  }

  /**
   * Applies one batch (spec/bitstream.md §6.1) in place.
   * @param {Int32Array} v (k) split vertices; symbols (I) Uint8Array; residuals (k*D) Float64Array
   */
  applyBatch(v, symbols, residuals) {
    const { D, faces, values } = this;
    const k = v.length;
    const n = this.n;
    const m = this.m;
    if (n + k > this.capN) throw new FormatError('splits exceed the declared vertex count');
    for (let i = 0; i < k; i++) {
      if (v[i] >= n || (i > 0 && v[i] <= v[i - 1])) throw new FormatError('split vertex ids out of range or not increasing');
    }
    const inc = this.#incidences(v, symbols.length);
    const { sums, ring, wings, mNew } = this.#split(v, symbols, inc, n, m);
    for (let i = 0; i < k; i++) {
      if (wings[i] < 1 || wings[i] > 2) throw new FormatError('a split names no new face or more than two');
      for (let d = 0; d < D; d++) {
        values[(n + i) * D + d] = Math.floor(sums[i * D + d] / ring[i]) + residuals[i * D + d];
      }
    }
    for (let i = 0; i < k; i++) this.head[v[i]] = -1;
    for (let t = inc.length - 1; t >= 0; t--) this.#link(inc[t]); // each to v[i] or its new vertex
    for (let c = 3 * mNew - 1; c >= 3 * m; c--) this.#link(c);
    this.n = n + k;
    this.m = mNew;
  }

  /** Steps 1-3 of spec §6.1 over the incidences `inc` in order: corners rewritten, faces appended. */
  #split(v, symbols, inc, n, m) {
    const { D, faces, values, slot, capM } = this;
    const k = v.length;
    const sums = new Float64Array(k * D);
    const wings = new Int32Array(k);
    const ring = new Int32Array(k);
    for (let i = 0; i < k; i++) slot[v[i]] = i;
    let mNew = m;
    try {
      for (let t = 0; t < inc.length; t++) {
        const s = symbols[t];
        if (s === 0) continue;
        const c = inc[t];
        const i = slot[faces[c]];
        const f = c - (c % 3);
        const a = faces[f + ((c + 1) % 3)];
        const b = faces[f + ((c + 2) % 3)];
        const u = n + i;
        const vi = v[i];
        faces[c] = u;
        const left = s === 2 || s === 4;
        const right = s === 3 || s === 4;
        if ((left ? 1 : 0) + (right ? 1 : 0) + mNew > capM) throw new FormatError('splits exceed the declared face count');
        if (left) {
          faces[3 * mNew] = u; faces[3 * mNew + 1] = vi; faces[3 * mNew + 2] = a; mNew++;
        }
        if (right) {
          faces[3 * mNew] = vi; faces[3 * mNew + 1] = u; faces[3 * mNew + 2] = b; mNew++;
        }
        const wa = 1 + (left ? 1 : 0); // weights of a, b and v in the ring sum of u
        const wb = 1 + (right ? 1 : 0);
        const wv = (left ? 1 : 0) + (right ? 1 : 0);
        const o = i * D;
        for (let d = 0; d < D; d++) sums[o + d] += wa * values[a * D + d] + wb * values[b * D + d] + wv * values[vi * D + d];
        ring[i] += 2 + 2 * wv;
        wings[i] += wv;
      }
    } finally {
      for (let i = 0; i < k; i++) slot[v[i]] = -1;
    }
    return { sums, ring, wings, mNew };
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
