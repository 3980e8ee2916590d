/**
 * Push decoder of a .pmw stream, mirroring pmwm_codec.StreamDecoder: `await feed(bytes)` returns
 * what became available (one result when every base mesh is in, then one per applied chunk, in
 * stream order), `close()` says whether the stream was complete or cut.
 */
import { decodeBase } from './base.js';
import { SRGB8_TO_LINEAR } from './constants.js';
import { initChunkFrames, openChunk } from './chunkframe.js';
import { FormatError, LimitError, TruncatedError } from './errors.js';
import { checkPreamble, parseGlb, planDocument, preambleLength } from './header.js';
import { ChunkDecoderV2, planeColumns } from './payload-v2.js';
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

/** `value` as an error message shows what the caller gave: a string in quotes ('2' as "2"), a number as it is (NaN, -1). */
export function shown(value) {
  if (typeof value === 'string') return JSON.stringify(value);
  if (value === null || typeof value !== 'object') return String(value);
  try {
    return JSON.stringify(value) ?? String(value);
  } catch {
    return String(value);
  }
}

/**
 * The number of chunks `options` lets apply: its `maxChunks` or its `chunks` (PmwDecoder's and decodePmw's names,
 * each accepted by both and by the three.js plugin: the same option), Infinity when neither is given. A RangeError
 * naming the option the caller used unless it is a whole number >= 0 or Infinity, or when both are given and differ.
 * @param {{maxChunks?: number, chunks?: number}} options
 * @returns {number}
 */
export function chunkLimit(options) {
  const { maxChunks, chunks } = options;
  if (maxChunks !== undefined && chunks !== undefined && !Object.is(maxChunks, chunks)) {
    throw new RangeError(`maxChunks ${shown(maxChunks)} and chunks ${shown(chunks)} differ: they are one option, give one`);
  }
  const name = maxChunks !== undefined ? 'maxChunks' : 'chunks';
  const value = options[name] === undefined ? Infinity : options[name];
  if (value !== Infinity && !(Number.isSafeInteger(value) && value >= 0)) {
    throw new RangeError(`${name} must be a whole number >= 0 (or Infinity), not ${shown(value)}`);
  }
  return value;
}

export class PmwDecoder {
  /**
   * @param {{draco?: DracoDecoder, maxChunks?: number, snapshots?: boolean|'changed', onLevel?: Function,
   *   onCallbackError?: Function}} options
   *   maxChunks (or `chunks`, decodePmw's name: the same option, see chunkLimit): apply no chunk after this many; snapshots: attach `mesh` (see snapshot()) to every result;
   *   'changed': `mesh: {parts}` with parts[p] as snapshot()'s only for the primitive the level changed (the base:
   *   every one), null for the others (a copy of every part per level costs levels x mesh size on many primitives);
   *   onLevel(result, decoder): called as each level is reached, before the next chunk is applied;
   *   onCallbackError(error): given what onLevel throws (default: console.error); the decode goes on
   */
  constructor(options = {}) {
    const { draco, snapshots = false, onLevel, onCallbackError } = options;
    this.onLevel = onLevel;
    this.onCallbackError = onCallbackError;
    this.draco = draco;
    this.maxChunks = chunkLimit(options);
    this.snapshots = snapshots;
    this.buf = new Uint8Array(0);
    this.received = 0;
    this.header = null;
    this.plan = null;
    this.states = null;
    this.coders = null;
    this.bases = null; // the decoded base meshes, kept to rebuild the last good level after a chunk failed half applied
    this.chunksApplied = 0;
    this.closed = false;
    this.failed = null;
    this.overflow = 0; // bytes past the GLB length in the feed that brought the header
    this.broken = false; // a chunk failed after it began to change the mesh: snapshot() rebuilds the last good level
    this.pending = 0;
    this.queue = Promise.resolve();
    this.end = null;
  }

  /** The error that broke the stream (every later feed() and close() rejects with it), else null. */
  get error() { return this.failed; }

  /**
   * Appends `bytes` (a Uint8Array, an ArrayBuffer as `await response.arrayBuffer()` gives, or any
   * typed array or DataView: its bytes); resolves to the results that became available (possibly
   * none). The bytes are copied before feed() returns: the caller may reuse its buffer at once.
   * Anything else rejects with a TypeError and leaves the decoder as it was; so does a feed() after
   * close(). When a chunk fails after others of the same feed() were applied, it resolves to those
   * levels (every complete chunk before the bad one is delivered) and the failure comes from the next
   * feed() or close() (and `error` holds it); a failure with no level before it rejects at once.
   */
  feed(bytes) {
    let piece;
    try {
      piece = asBytes(bytes);
      if (this.closed) throw new TypeError('PmwDecoder.feed() after close(): the decoder is single-use');
    } catch (e) {
      return Promise.reject(e);
    }
    // nothing queued: run now (the bytes are appended before this returns); else queue a copy
    const run = this.pending ? (() => { const copy = piece.slice(); return this.queue.then(() => this.#feed(copy)); })()
      : this.#feed(piece);
    this.pending++;
    const settled = () => { this.pending--; };
    this.queue = run.then(settled, settled);
    return run;
  }

  async #feed(bytes) {
    if (this.failed) throw this.failed;
    const out = [];
    try {
      // bytes past the GLB length are refused, after the levels the bytes before it complete (spec/README.md,
      // Partial files): those are read as usual, the rest never
      const room = this.header ? this.header.length - this.received : Infinity;
      this.#append(bytes.length > room ? bytes.subarray(0, room) : bytes);
      await this.#advance(out);
      const past = Math.max(0, bytes.length - room) + this.overflow;
      if (past) throw new FormatError(`GLB: ${past} bytes after the declared file length ${this.header.length}`);
    } catch (e) {
      this.failed = e;
      if (!out.length) throw e;
    }
    return out; // after a failure, the levels this feed reached before it: the next call throws
  }

  #append(bytes) {
    const need = this.received + bytes.length;
    if (need > this.buf.length) {
      const cap = Math.min(Math.max(need, 2 * this.buf.length, 1024), this.header ? this.header.length : Infinity);
      const grown = new Uint8Array(cap);
      grown.set(this.buf.subarray(0, this.received));
      this.buf = grown;
    }
    this.buf.set(bytes, this.received);
    this.received = need;
  }

  /** Decodes what the bytes received allow, pushing each level's result to `out` as it is reached. */
  async #advance(out) {
    const data = this.buf.subarray(0, this.received);
    if (!this.header) {
      if (this.received < 20) return;
      checkPreamble(data); // a JSON chunk over the limit is refused before it is buffered
      if (this.received < preambleLength(data)) return;
      this.header = parseGlb(data);
      if (this.received > this.header.length) { // the bytes past it are let go; this feed fails after its levels
        this.overflow = this.received - this.header.length;
        this.received = this.header.length;
      }
      this.plan = planDocument(this.header.gltf, this.header.binLength);
      // zstd only for payload version 1 chunks (a version 2 stream's first decode does not load it)
      await initChunkFrames({ zstd: this.plan.stream.some((c) => c.payloadVersion !== 2) });
    }
    const { binStart } = this.header;
    const bin = () => this.buf.subarray(binStart, this.received);
    if (!this.states) {
      if (this.received < binStart + this.plan.baseEnd) return;
      const bases = [];
      for (const prim of this.plan.primitives) bases.push(await decodeBase(bin(), prim, this.draco));
      [this.states, this.coders] = this.#start(bases);
      this.bases = bases;
      out.push(this.#result(binStart + this.plan.baseEnd));
    }
    const { stream } = this.plan;
    while (this.chunksApplied < stream.length && this.chunksApplied < this.maxChunks) {
      const c = stream[this.chunksApplied];
      const end = binStart + c.offset + c.length;
      if (this.received < end) break;
      this.#apply(this.states, this.coders, this.chunksApplied, this.buf.subarray(binStart + c.offset, end), true);
      this.chunksApplied++;
      out.push(this.#result(end));
    }
  }

  /** Fresh mesh states (and payload version 2 coders) holding the decoded base meshes. */
  #start(bases) {
    const states = bases.map((b, i) => {
      const prim = this.plan.primitives[i];
      return new MeshState(b.values, b.faces, b.n, b.m, b.D, prim.vertexCount, prim.faceCount);
    });
    // payload version 2: per primitive, the probability table its chunks carry on (spec §8.1)
    const coders = this.plan.primitives.map((p, i) => (p.payloadVersion === 2
      ? new ChunkDecoderV2(states[i], planeColumns(p.base.grids)) : null));
    return [states, coders];
  }

  /** Applies chunk `index` (its stored bytes) to `states`; `live`: a failure past the chunk's checks marks them broken. */
  #apply(states, coders, index, stored, live) {
    const c = this.plan.stream[index];
    const state = states[c.primitive];
    const payload = openChunk(stored, c, index); // digest and frame: nothing changed yet when they fail
    const before = state.n;
    if (live) this.broken = true;
    try {
      if (c.payloadVersion === 2) coders[c.primitive].decodeChunk(payload, c); // splits, or a face chunk (c.faces)
      else state.applyPayload(unpackPayload(payload, state.D, state.capN));
    } catch (e) {
      if (e instanceof FormatError) e.message = `chunk ${index + 1}: ${e.message}`;
      throw e;
    }
    if (state.n !== c.vertexCount || state.m !== c.faceCount) {
      throw new FormatError(`chunk ${index + 1}: vertex/face counts differ from its index entry`);
    }
    try {
      checkSrgb8(state, before, this.plan.primitives[c.primitive].base.grids);
    } catch (e) {
      e.message = `chunk ${index + 1}: ${e.message}`;
      throw e;
    }
    if (live) this.broken = false;
  }

  /**
   * A chunk failed half applied: the states of the last good level, rebuilt from the base meshes and
   * the chunks applied before it (the bytes are all still here). Runs once, only after such a failure.
   */
  #repair() {
    const [states, coders] = this.#start(this.bases);
    const { binStart } = this.header;
    for (let k = 0; k < this.chunksApplied; k++) {
      const c = this.plan.stream[k];
      this.#apply(states, coders, k, this.buf.subarray(binStart + c.offset, binStart + c.offset + c.length), false);
    }
    this.states = states;
    this.coders = coders;
    this.broken = false;
  }

  #result(bytesRead) {
    const parts = this.states.map((s) => ({ vertexCount: s.n, faceCount: s.m }));
    const r = {
      chunk: this.chunksApplied, chunksTotal: this.plan.stream.length, bytesRead,
      vertexCount: parts.reduce((a, p) => a + p.vertexCount, 0),
      faceCount: parts.reduce((a, p) => a + p.faceCount, 0),
      parts,
    };
    if (this.snapshots === 'changed') {
      const changed = this.chunksApplied ? this.plan.stream[this.chunksApplied - 1].primitive : -1;
      const { primitives } = this.plan;
      r.mesh = { parts: this.states.map((s, p) => (changed < 0 || p === changed ? partSnapshot(s, primitives[p]) : null)) };
    } else if (this.snapshots) r.mesh = this.snapshot();
    if (this.onLevel) {
      try {
        this.onLevel(r, this);
      } catch (e) { // the caller's bug is not the stream's failure: reported, and the decode goes on
        reportCallbackError(this.onCallbackError, e);
      }
    }
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
   * After a failure, the last good level (the one the last result reported): a chunk that failed is
   * never shown, even half applied.
   */
  snapshot() {
    if (this.broken) this.#repair();
    if (!this.states && this.failed) throw this.failed; // the stream broke before its base mesh
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
   * Ends the stream, once the feeds queued before it are done (it needs no await of them). Resolves to
   * {complete: boolean, bytesReceived: number, totalLength: number, chunksApplied: number, chunkCount: number}:
   * `complete` says whether the input is whole (every byte up to the GLB length received: a whole file decoded with
   * maxChunks 2 is complete, with chunksApplied 2 of chunkCount), as pmwm_codec.StreamDecoder's StreamEnd.complete.
   * Rejects with the error that broke the stream, or a TruncatedError when no base mesh arrived. A later feed() is a
   * TypeError; a second close() settles as the first.
   */
  close() {
    this.closed = true;
    this.end ??= this.queue.then(() => this.#close());
    return this.end;
  }

  #close() {
    if (this.failed) throw this.failed;
    if (!this.states) {
      // before the header is in, a lower bound: where the BIN data starts (spec/README.md, Partial files)
      throw new TruncatedError(`stream ended after ${this.received} bytes, before the base mesh (${this.header ? '' : 'at least '}`
        + `${this.#baseBytes()} bytes)`,
        this.received, this.#baseBytes());
    }
    const chunkCount = this.plan.stream.length;
    return {
      complete: this.received === this.header.length,
      bytesReceived: this.received, totalLength: this.header.length, chunksApplied: this.chunksApplied, chunkCount,
    };
  }
}

/** Hands what a caller's callback threw to `handler` (itself guarded), else to console.error. */
export function reportCallbackError(handler, error) {
  try {
    if (handler) {
      handler(error);
      return;
    }
  } catch (e) {
    error = e;
  }
  console.error('pmwm-progressive: a callback threw (the decode goes on):', error);
}

/** The bytes of `data` (ArrayBuffer, typed array or DataView) as a Uint8Array view; TypeError for anything else. */
export function asBytes(data) {
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
  if (g.transfer === 'srgb8') return dequantizeSrgb8(attributesInt, n, a, col, g);
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

/**
 * FormatError unless every byte origin + i of the "srgb8" attributes (spec/README.md, attributes: transfer) of
 * `state`'s vertices from..n lies in 0..255: a chunk's new vertices, checked as it is applied.
 */
function checkSrgb8(state, from, grids) {
  const { values, D, n } = state;
  let col = 3;
  for (const g of grids) {
    const k = g.origin.length;
    if (g.transfer === 'srgb8') {
      for (let i = from; i < n; i++) {
        for (let c = 0; c < k; c++) {
          const b = g.origin[c] + values[i * D + col + c];
          if (!(b >= 0 && b <= 255)) throw new FormatError(`${g.semantic}: sRGB byte ${b} lies outside 0..255`);
        }
      }
    }
    col += k;
  }
}

/**
 * dequantize for a "srgb8" grid (spec/README.md, attributes: transfer): byte b = origin + i, 0..255 (a base
 * or a chunk with a byte outside was refused as it was read); red, green and blue SRGB8_TO_LINEAR[b], alpha b / 255 rounded to float32.
 */
function dequantizeSrgb8(attributesInt, n, a, col, g) {
  const k = g.origin.length;
  const out = new Float32Array(n * k);
  for (let i = 0, o = 0; i < n; i++, o += k) {
    for (let c = 0; c < k; c++) {
      const b = g.origin[c] + attributesInt[i * a + col + c]; // 0..255: checkSrgb8 / the base's srgb8Into
      out[o + c] = c < 3 ? SRGB8_TO_LINEAR[b] : b / 255;
    }
  }
  return out;
}
