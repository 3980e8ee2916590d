/**
 * Push decoder of a .pmw stream, mirroring pmwm_codec.StreamDecoder: `await feed(bytes)` returns
 * what became available (one result when every base mesh is in, then one per applied chunk, in
 * stream order), `close()` says whether the stream was complete or cut.
 */
import { decodeBase } from './base.js';
import { initChunkFrames, openChunk } from './chunkframe.js';
import { FormatError, LimitError, TruncatedError } from './errors.js';
import { checkPreamble, parseGlb, planDocument, preambleLength } from './header.js';
import { ChunkDecoderV2 } from './payload-v2.js';
import { MeshState, unpackPayload } from './vsplit.js';

/**
 * @typedef {object} DracoDecoder
 * @property {(bytes: Uint8Array, ids: {positionId: number, attributeIds: number[]}) =>
 *   Promise<{positions: Float32Array, attributes: (Float32Array|{values: Float32Array, components: number})[],
 *   indices: Uint32Array}>} decode  the mesh in Draco's decoded vertex order
 */

const NORMALIZED = { NORMAL: 3, TANGENT: 3 };
/** 1e-30 as float32: the least length a NORMAL/TANGENT is divided by. */
const TINY = Math.fround(1e-30);

export class PmwDecoder {
  /**
   * @param {{draco?: DracoDecoder, maxChunks?: number, snapshots?: boolean, onLevel?: Function}} options
   *   maxChunks: apply no chunk after this many; snapshots: attach `mesh` (see snapshot()) to every result;
   *   onLevel(result, decoder): called as each level is reached, before the next chunk is applied
   */
  constructor({ draco, maxChunks = Infinity, snapshots = false, onLevel } = {}) {
    this.onLevel = onLevel;
    this.draco = draco;
    if (maxChunks !== Infinity && !(Number.isSafeInteger(maxChunks) && maxChunks >= 0)) {
      throw new RangeError(`maxChunks must be a whole number >= 0 (or Infinity), not ${maxChunks}`);
    }
    this.maxChunks = maxChunks;
    this.snapshots = snapshots;
    this.buf = new Uint8Array(0);
    this.received = 0;
    this.header = null;
    this.plan = null;
    this.states = null;
    this.coders = null;
    this.chunksApplied = 0;
    this.closed = false;
    this.failed = null;
    this.queue = Promise.resolve();
  }

  /**
   * Appends `bytes` (a Uint8Array, an ArrayBuffer as `await response.arrayBuffer()` gives, or any
   * typed array or DataView: its bytes); resolves to the results that became available (possibly
   * none). Anything else rejects with a TypeError and leaves the decoder as it was.
   */
  feed(bytes) {
    let piece;
    try {
      piece = asBytes(bytes);
    } catch (e) {
      return Promise.reject(e);
    }
    const run = this.queue.then(() => this.#feed(piece));
    this.queue = run.catch(() => {});
    return run;
  }

  async #feed(bytes) {
    if (this.closed) throw new FormatError('the decoder was already closed');
    if (this.failed) throw this.failed;
    try {
      this.#append(bytes);
      return await this.#advance();
    } catch (e) {
      this.failed = e;
      throw e;
    }
  }

  #append(bytes) {
    const need = this.received + bytes.length;
    if (this.header && need > this.header.length) throw new FormatError('more bytes than the GLB length');
    if (need > this.buf.length) {
      const cap = Math.min(Math.max(need, 2 * this.buf.length, 1024), this.header ? this.header.length : Infinity);
      const grown = new Uint8Array(cap);
      grown.set(this.buf.subarray(0, this.received));
      this.buf = grown;
    }
    this.buf.set(bytes, this.received);
    this.received = need;
  }

  async #advance() {
    const out = [];
    const data = this.buf.subarray(0, this.received);
    if (!this.header) {
      if (this.received < 20) return out;
      checkPreamble(data); // a JSON chunk over the limit is refused before it is buffered
      if (this.received < preambleLength(data)) return out;
      this.header = parseGlb(data);
      if (this.received > this.header.length) throw new FormatError('more bytes than the GLB length');
      this.plan = planDocument(this.header.gltf, this.header.binLength);
      await initChunkFrames();
    }
    const { binStart } = this.header;
    const bin = () => this.buf.subarray(binStart, this.received);
    if (!this.states) {
      if (this.received < binStart + this.plan.baseEnd) return out;
      const states = [];
      for (const prim of this.plan.primitives) {
        const b = await decodeBase(bin(), prim, this.draco);
        states.push(new MeshState(b.values, b.faces, b.n, b.m, b.D, prim.vertexCount, prim.faceCount));
      }
      // payload version 2: per primitive, the probability table its chunks carry on (spec §8.1)
      this.coders = this.plan.primitives.map((p, i) => (p.payloadVersion === 2 ? new ChunkDecoderV2(states[i]) : null));
      this.states = states;
      out.push(this.#result(binStart + this.plan.baseEnd));
    }
    const { stream } = this.plan;
    while (this.chunksApplied < stream.length && this.chunksApplied < this.maxChunks) {
      const c = stream[this.chunksApplied];
      const end = binStart + c.offset + c.length;
      if (this.received < end) break;
      this.#apply(c, this.buf.subarray(binStart + c.offset, end));
      this.chunksApplied++;
      out.push(this.#result(end));
    }
    return out;
  }

  #apply(c, stored) {
    const index = this.chunksApplied;
    const state = this.states[c.primitive];
    const payload = openChunk(stored, c, index);
    try {
      if (c.payloadVersion === 2) this.coders[c.primitive].decodeChunk(payload, c); // splits, or a face chunk (c.faces)
      else state.applyPayload(unpackPayload(payload, state.D, state.capN));
    } catch (e) {
      if (e instanceof FormatError) e.message = `chunk ${index + 1}: ${e.message}`;
      throw e;
    }
    if (state.n !== c.vertexCount || state.m !== c.faceCount) {
      throw new FormatError(`chunk ${index + 1}: vertex/face counts differ from its index entry`);
    }
  }

  #result(bytesRead) {
    const parts = this.states.map((s) => ({ vertexCount: s.n, faceCount: s.m }));
    const r = {
      chunk: this.chunksApplied, chunksTotal: this.plan.stream.length, bytesRead,
      vertexCount: parts.reduce((a, p) => a + p.vertexCount, 0),
      faceCount: parts.reduce((a, p) => a + p.faceCount, 0),
      parts,
    };
    if (this.snapshots) r.mesh = this.snapshot();
    this.onLevel?.(r, this);
    return r;
  }

  /**
   * The mesh now (fresh arrays, not views of the decoder's state), all progressive primitives
   * concatenated in mesh/primitive order: positions (N*3) Float32Array (origin + q*step), positionsInt
   * (N*3) Int32Array grid integers, indices (M*3) Uint32Array (offset per part), parts: per primitive
   * {positions, positionsInt, indices, attributesInt (n*a) Int32Array, attributes {semantic: Float32Array}}.
   * A hostile stream whose values leave the int32 range gets its integer arrays as Float64Array
   * (exact, as the reference decoder's int64; never for a valid stream, whose values are < 2^30).
   * With one progressive primitive, positions, positionsInt and indices ARE parts[0]'s arrays (the
   * same objects, not copies): writing to one shows in the other.
   */
  snapshot() {
    if (this.failed) throw this.failed; // a chunk may be half applied: never shown as a level
    if (!this.states) throw new TruncatedError('no base mesh yet', this.received, this.#baseBytes());
    const parts = this.states.map((s, p) => partSnapshot(s, this.plan.primitives[p]));
    if (parts.length === 1) {
      const [p] = parts; // one primitive: the top level shares its arrays (nothing to concatenate)
      return { positions: p.positions, positionsInt: p.positionsInt, indices: p.indices, parts };
    }
    const N = parts.reduce((a, p) => a + p.positionsInt.length / 3, 0);
    const M = parts.reduce((a, p) => a + p.indices.length / 3, 0);
    const positions = new Float32Array(N * 3);
    const positionsInt = new (parts.some((p) => p.positionsInt instanceof Float64Array) ? Float64Array : Int32Array)(N * 3);
    const indices = new Uint32Array(M * 3);
    let v = 0;
    let f = 0;
    for (const p of parts) {
      positions.set(p.positions, v * 3);
      positionsInt.set(p.positionsInt, v * 3);
      if (v === 0) indices.set(p.indices, f * 3);
      else for (let i = 0; i < p.indices.length; i++) indices[f * 3 + i] = p.indices[i] + v;
      v += p.positionsInt.length / 3;
      f += p.indices.length / 3;
    }
    return { positions, positionsInt, indices, parts };
  }

  #baseBytes() {
    return this.header ? this.header.binStart + this.plan.baseEnd : preambleLength(this.buf.subarray(0, this.received));
  }

  /**
   * Ends the stream. @returns {{complete: boolean, bytesReceived: number, totalLength: number,
   * chunksApplied: number, chunkCount: number}}; TruncatedError when no base mesh arrived.
   */
  close() {
    if (this.failed) throw this.failed;
    this.closed = true;
    if (!this.states) {
      throw new TruncatedError(`stream ended after ${this.received} bytes, before the base mesh (${this.#baseBytes()} bytes)`,
        this.received, this.#baseBytes());
    }
    const chunkCount = this.plan.stream.length;
    return {
      complete: this.received === this.header.length && this.chunksApplied === chunkCount,
      bytesReceived: this.received, totalLength: this.header.length, chunksApplied: this.chunksApplied, chunkCount,
    };
  }
}

/** The bytes of `data` (ArrayBuffer, typed array or DataView) as a Uint8Array view; TypeError for anything else. */
function asBytes(data) {
  if (data instanceof Uint8Array) return data;
  if (ArrayBuffer.isView(data)) return new Uint8Array(data.buffer, data.byteOffset, data.byteLength);
  if (data instanceof ArrayBuffer || (typeof SharedArrayBuffer === 'function' && data instanceof SharedArrayBuffer)) {
    return new Uint8Array(data);
  }
  throw new TypeError(`expected bytes (a Uint8Array, ArrayBuffer or typed array), not ${data === null ? 'null' : typeof data}`
    + (data?.constructor?.name ? ` (${data.constructor.name})` : ''));
}

/**
 * One primitive's arrays now (copies); attributes dequantized, NORMAL/TANGENT xyz renormalized.
 * positionsInt / attributesInt are Int32Array, or Float64Array (exact integers) when a hostile stream
 * put a value outside the int32 range (see MeshState.values).
 */
function partSnapshot(s, prim) {
  const { D, n, m, values } = s;
  const Ints = values instanceof Float64Array && !fitsInt32(values, n * D) ? Float64Array : Int32Array;
  const positionsInt = new Ints(n * 3);
  const positions = new Float32Array(n * 3);
  const a = D - 3;
  const attributesInt = new Ints(n * a);
  const [ox, oy, oz] = prim.grid.origin;
  const [sx, sy, sz] = prim.grid.step;
  for (let i = 0, r = 0, o = 0; i < n; i++, r += D, o += 3) {
    const x = values[r];
    const y = values[r + 1];
    const z = values[r + 2];
    positionsInt[o] = x;
    positionsInt[o + 1] = y;
    positionsInt[o + 2] = z;
    positions[o] = ox + x * sx;
    positions[o + 1] = oy + y * sy;
    positions[o + 2] = oz + z * sz;
    for (let d = 0; d < a; d++) attributesInt[i * a + d] = values[r + 3 + d];
  }
  const attributes = {};
  let col = 0;
  for (const g of prim.base.grids) {
    attributes[g.semantic] = dequantize(attributesInt, n, a, col, g);
    col += g.origin.length;
  }
  return { positions, positionsInt, indices: s.faces.slice(0, m * 3), attributesInt, attributes };
}

/** Whether values[0..count) all lie in the int32 range. */
function fitsInt32(values, count) {
  for (let i = 0; i < count; i++) if (values[i] !== (values[i] | 0)) return false;
  return true;
}

/**
 * One attribute's floats: columns col..col+k of `attributesInt` (n*a) on grid `g` (k components),
 * as (n*k) Float32Array: origin + i*step in double precision, rounded to float32 (as positions);
 * NORMAL/TANGENT xyz then scaled to unit length in float32 arithmetic, as the reference writes a level
 * (spec/README.md "Seams and attributes"): every product, sum (x² + y², then + z²), the square root and
 * the quotient by max(length, 1e-30) rounded to float32; a zero vector stays zero.
 */
function dequantize(attributesInt, n, a, col, g) {
  const f = Math.fround; // float32 rounding of a double result: exact float32 arithmetic for + * / sqrt
  const k = g.origin.length;
  const out = new Float32Array(n * k);
  const nk = NORMALIZED[g.semantic] ? Math.min(3, k) : 0;
  for (let i = 0, o = 0; i < n; i++, o += k) {
    for (let c = 0; c < k; c++) out[o + c] = g.origin[c] + attributesInt[i * a + col + c] * g.step[c];
    if (!nk) continue;
    let squares = 0;
    for (let c = 0; c < nk; c++) squares = f(squares + f(out[o + c] * out[o + c]));
    const length = f(Math.sqrt(squares));
    if (length > 0) for (let c = 0; c < nk; c++) out[o + c] = out[o + c] / Math.max(length, TINY);
  }
  return out;
}
