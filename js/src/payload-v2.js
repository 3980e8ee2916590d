/**
 * Chunk payload version 2 (spec/bitstream.md §8): one range-coded stream per chunk that codes the
 * batches of vertex splits of version 1 with models reading the mesh the chunk applies to: a
 * selection mask (§8.4.1), each split's moved faces as an arc of its fan with a ranked start or an
 * escape to plain symbols (§8.4.2), and the new vertices' values against a prediction in the frame
 * of their ring (§8.4.3). The topology of a batch is that of §6.1.
 *
 * A ChunkDecoderV2 belongs to one primitive: it holds the probability table its chunks continue
 * (§8.1) and typed scratch arrays grown geometrically, and decodes each chunk straight into the
 * primitive's MeshState (values, faces, n, m). No allocation per vertex, split or symbol.
 *
 * The decoder keeps every vertex's corners as an ascending linked list (head / nxt / tail, as the
 * reference decoder's CornerLists) and every vertex's valence (§8.4.1) from batch to batch, so
 * that a batch costs its mask bits plus the work of its splits, not a pass over the mesh (#lists
 * builds them on a primitive's first chunk and after a face chunk). Per batch:
 * - #mask decodes one bit per vertex; each marked vertex lists its incidences (its corner list,
 *   in face-slot order: corner, a, b) and adds itself to its neighbours' counts (#gather);
 * - #splits then takes the splits one by one while their incidences are at hand: the symbols
 *   (#fanOf, arcStart), the moved corners and the relisting of v and u, the ring sums and normal
 *   that §8.4.3 reads (#ring: only values of the mesh before the batch), and the valences (the
 *   arc of a closed fan in O(1), #revalueArc; else from the incidences, #revalueSplit; recounted
 *   by #recount after a batch whose splits touch each other's moved faces);
 * - #newFaces appends the new faces (in the order of the corners that create them, read from a
 *   bitmap over the corners) and lists them;
 * - #values decodes the new values against the kept rings.
 * Hot loops read only constants of this module (see rangecoder.js: imported ones are not folded).
 *
 * The primitive's chunks from `firstFaceChunk` on are face chunks (§8.6): faces coded against Up(a) /
 * Near(a, b) of the mesh before them, or naming new vertices (fresh, numbered in the order the
 * faces first name them, their values predicted by the mean of their earlier corners), under a
 * table of its own (FACE_PROBS, fresh per face chunk). It reads the same corner lists and leaves
 * them (and the valences) to be rebuilt by the next batch that splits.
 */
import { FormatError, LimitError } from './errors.js';
import { MAX_BATCHES_PER_CHUNK } from './constants.js';
import { INT_BLOCK as IMPORTED_INT_BLOCK, RangeDecoder, newProbabilities } from './rangecoder.js';

/** Integer context block size (§8.2), as a constant of this module (see rangecoder.js). */
const INT_BLOCK = IMPORTED_INT_BLOCK;

// probability table layout (spec §8.3)
const P_MASK = 0; // 7 * nb + vc
const P_ESCAPE = 21;
const P_WING = 22; // + 0 left, + 1 right
const P_SYMBOL = 24; // Tree(24, 3)
const P_INT = 32;
const B_BATCHES = 0;
const B_LENGTH = 1; // + min(d, 16) - 1
const B_RANK = 17; // + min(c, 16) - 1
const B_GEOMETRY = 33; // + 3 * cls + role
const B_ATTRIBUTE = 129; // + min(j, 7)
/** Attributes predicted on the ring's plane (§8.4.3): + 16 * min(j, 7) + the ring's spread class 0 .. 15. */
const B_PLANE = 137;
const PLANE_CLASSES = 16;
/** Below this fraction of the product of its diagonal, the plane fit's determinant is singular (§8.4.3). */
const PLANE_SINGULAR = 2 ** -20;
const GEOMETRY_CLASSES = 32;
/** Size of a primitive's probability table: 32 single probabilities, 265 integer blocks. */
export const N_PROBS = P_INT + (B_PLANE + 8 * PLANE_CLASSES) * INT_BLOCK;
/** The bit of a split vertex in the mask's counts (cnt, which count marks up to 2). */
const SPLIT = 4;
/** Fans of more faces are never simple (their symbols are coded one by one). */
const MAX_ARC_FAN = 32;
/** The hash of a fan's corners: 2^FAN_BITS slots (at most half full), multiplicative hashing. */
const FAN_BITS = 6;
const FAN_SLOTS = 1 << FAN_BITS;
const FAN_SHIFT = 32 - FAN_BITS;
const HASH_MUL = 0x9e3779b1 | 0;
/** Decoded values must satisfy |x| < 2^31. */
const MAX_VALUE = 2147483648;
const TWO32 = 4294967296;

const block = (b) => P_INT + INT_BLOCK * b;

// face chunk table layout (spec §8.6): single probabilities 0..3, integer blocks 0..8 (at block(B) too)
const F_NEAR_B = 0; // b by its rank in Up(a), else Fresh / a + 1 + UInt
const F_NEAR_C = 1; // c by its rank in Near(a, b), else Fresh / a + 1 + UInt
const F_TWIN = 2; // the reverse face (a, c, b) follows
const F_FRESH = 3; // a vertex not from a list is the next new vertex, else a + 1 + UInt(block 4)
const FB_COUNT = 0; // coded faces minus one
const FB_GAP = 1; // a minus the previous face's a
const FB_RANK_B = 2; // rank in Up(a)
const FB_RANK_C = 3; // rank in Near(a, b)
const FB_RAW = 4; // x - a - 1 of a vertex coded without a list (existing, or a new one already named)
const FB_VALUE = 5; // + min(q, 3): residual of a new vertex's value q
/** Size of a face chunk's own probability table: 32 single probabilities, 9 integer blocks. */
export const FACE_PROBS = P_INT + 9 * INT_BLOCK;
const TWO53 = 2 ** 53;
/**
 * The corners after and before corner c in its face are c + AFTER[c % 3] and c + BEFORE[c % 3] (a
 * table, not a branch: the face loads of a corner walk do not wait on a guessed branch).
 */
const AFTER = Int8Array.of(1, 1, -2);
const BEFORE = Int8Array.of(2, -1, -1);
/** Neighbour lists up to this long are sorted in place by insertion, longer ones by TypedArray sort. */
const SHORT_LIST = 32;

/** Bits of the non-negative integer x (0 for 0), for any x below 2^53. */
function bitLength(x) {
  let b = 0;
  while (x >= TWO32) {
    x = Math.floor(x / TWO32);
    b += 32;
  }
  return b + 32 - Math.clz32(x);
}

/**
 * Sorts list[0 .. k) ascending in place: by insertion when short, else by TypedArray sort
 * (numeric; a vertex of huge valence stays O(k log k)).
 */
function sortList(list, k) {
  if (k > SHORT_LIST) {
    list.subarray(0, k).sort();
    return;
  }
  for (let t = 1; t < k; t++) {
    const x = list[t];
    let s = t;
    for (; s > 0 && list[s - 1] > x; s--) list[s] = list[s - 1];
    list[s] = x;
  }
}

/** floor(x + 0.5): the rounding of the frame predictions. */
const round = (x) => Math.floor(x + 0.5);

/**
 * The candidate start of rank r of an arc of L faces in a fan of d (spec §8.4.2 "Start rank"):
 * lens[t] (t < d) the length from v to the corner a of fan[t] (#fanLengths), lens[32 + c] the
 * score of start c.
 */
function arcStart(r, d, ncand, L, lens) {
  for (let c = 0; c < ncand; c++) {
    let sc = 0.0;
    for (let j = 1, t = c + 1 === d ? 0 : c + 1; j < L; j++, t = t + 1 === d ? 0 : t + 1) sc += lens[t]; // t = (c + j) mod d
    lens[MAX_ARC_FAN + c] = sc;
  }
  // rank order: score descending, then index ascending; rank r is found in r + 1 passes (r is
  // mostly 0 or 1), each taking the first candidate of highest score after the one before
  let best = -1;
  let bestScore = Infinity;
  for (let q = 0; q <= r; q++) {
    const prev = best;
    const prevScore = bestScore;
    best = -1;
    for (let c = 0; c < ncand; c++) {
      const sc = lens[MAX_ARC_FAN + c];
      if ((sc < prevScore || (sc === prevScore && c > prev)) && (best < 0 || sc > bestScore)) {
        best = c;
        bestScore = sc;
      }
    }
  }
  return best;
}

/**
 * Per value column (3 positions, then each attribute's components), 1 where the attribute is predicted on the
 * ring's plane (its extension entry's "prediction": "plane", §8.4.3); null when none is.
 * @param {{origin: number[], prediction?: string}[]} grids the primitive's attribute grids, in extension order
 */
export function planeColumns(grids) {
  const flags = [0, 0, 0];
  for (const g of grids) for (let c = 0; c < g.origin.length; c++) flags.push(g.prediction === 'plane' ? 1 : 0);
  return flags.some((f) => f === 1) ? Uint8Array.from(flags) : null;
}

export class ChunkDecoderV2 {
  /**
   * @param {import('./vsplit.js').MeshState} state the primitive's mesh, decoded into in place
   * @param {Uint8Array|null} plane per value column, 1 where the attribute is predicted on the ring's plane
   *   (its extension entry's "prediction": "plane", §8.4.3; see planeColumns), or null for none
   */
  constructor(state, plane = null) {
    this.state = state;
    this.plane = plane;
    this.probs = newProbabilities(N_PROBS);
    this.fan = new Int32Array(MAX_ARC_FAN);
    this.succ = new Int32Array(MAX_ARC_FAN); // the successor of each incidence of a fan, -1 for none
    this.hasPred = new Uint8Array(MAX_ARC_FAN);
    this.slotKey = new Int32Array(FAN_SLOTS); // the hash of a fan's corners a (see #fanOf)
    this.slotOf = new Int32Array(FAN_SLOTS);
    this.slotEpoch = new Int32Array(FAN_SLOTS);
    this.lens = new Float64Array(2 * MAX_ARC_FAN); // lengths, then scores
    this.sums = new Float64Array(state.D);
    this.frame = new Float64Array(6);
    /** The mesh (vertices, faces) that the corner lists and valences describe (-1: none, build them). */
    this.listsN = -1;
    this.listsM = -1;
    this.epoch = 0;
    this.spread = 0; // the spread #planePrediction found last
    this.arcFirst = 0; // the arc #symbols decoded last
    this.arcLength = 0;
    // scratch arrays (see #grow), declared here so that the object keeps one shape
    for (const name of ['head', 'tail', 'nxt', 'val', 'stamp', 'stamp2', 'v', 'gstart', 'inc', 'a', 'b', 'creatorOf',
      'created', 'wings', 'ringCount', 'ringClass', 'up', 'near', 'fstart', 'fnames']) this[name] = new Int32Array(0);
    this.ringSums = new Float64Array(0);
    this.ringNormals = new Float64Array(0);
    this.fresh = 0; // new vertices named so far by the face chunk being decoded
    this.vc = new Uint8Array(0);
    this.cnt = new Uint8Array(0);
    this.sym = new Uint8Array(0);
  }

  /**
   * Scratch array `name` with at least `size` (<= max) elements, grown geometrically up to `max`,
   * or to `max` at once when an eighth of it is asked (contents kept when `keep`, zeros otherwise).
   */
  #grow(name, size, Type, max, keep = false) {
    let arr = this[name];
    if (arr.length < size) {
      // (every call here runs on every growth: a call first made in optimised code deoptimises it)
      const room = Math.max(size, max);
      const cap = size > max / 8 ? room : Math.min(Math.max(size, 2 * arr.length), room);
      const old = arr;
      try {
        arr = new Type(cap);
      } catch (e) {
        if (!(e instanceof RangeError)) throw e;
        throw new LimitError(`cannot allocate ${cap} scratch entries (${e.message})`);
      }
      if (keep) arr.set(old);
      this[name] = arr;
    }
    return arr;
  }

  /**
   * Decodes one chunk's stored stream `buf` (Uint8Array) into the mesh, then checks its
   * termination: batch after batch of splits, or, when its normalised index entry `entry` is
   * marked `faces` (chunk k >= the primitive's `firstFaceChunk`, header.js), the faces and new
   * vertices of a face chunk (§8.6; no entry: a chunk that splits). FormatError / LimitError on
   * any invalid code, count or termination (the mesh may then be half changed: the decoder
   * refuses to show it).
   * @param {Uint8Array} buf @param {{faces?: boolean, vertexCount: number, faceCount: number}} [entry]
   */
  decodeChunk(buf, entry) {
    if (entry !== undefined && entry.faces === true) {
      this.#faceChunk(buf, entry.vertexCount, entry.faceCount);
      return;
    }
    const rc = new RangeDecoder(buf, this.probs);
    const batches = rc.uint(block(B_BATCHES), 'the batch count') + 1;
    if (batches > MAX_BATCHES_PER_CHUNK) {
      throw new LimitError(`chunk payload: batch count ${batches} outside 1..${MAX_BATCHES_PER_CHUNK}`);
    }
    for (let j = 0; j < batches; j++) this.#batch(rc);
    rc.finish();
  }

  /**
   * §8.6: a face chunk appending its faces to the mesh (n vertices, m faces) until the entry's
   * `faceCount`, and the t = `vertexCount` - n new vertices they name (fresh, numbered n, n+1, ...
   * as the faces first name them), then those vertices' values. Up(a) is kept for the faces of
   * one a (a never decreases, and both lists read the mesh before the chunk, which the appended
   * faces do not change; a new vertex has no neighbours there).
   */
  #faceChunk(buf, vertexCount, faceCount) {
    const st = this.state;
    const { n, m, capN, capM } = st;
    let { faces } = st; // grown (st.reserve) as the chunk's faces come: its entry's counts are only bounds
    this.#lists(n, m);
    this.listsN = -1; // the chunk's faces are not listed: the next batch rebuilds the lists
    this.#grow('up', n, Int32Array, capN); // distinct neighbours of a vertex
    this.#grow('near', n, Int32Array, capN);
    const rc = new RangeDecoder(buf, newProbabilities(FACE_PROBS)); // a fresh table for every face chunk
    const t = vertexCount - n;
    if (!(t >= 0)) throw new FormatError(`face chunk: its index entry's ${vertexCount} vertices are fewer than the mesh's ${n}`);
    const room = Math.min(faceCount, capM) - m; // the entry's face step (never past the declared count)
    const vroom = Math.min(t, capN - n); // the new vertices the chunk may add (never past the declared count)
    const G = rc.uint(block(FB_COUNT), 'the face count') + 1;
    if (G > room) throw new FormatError(`face chunk: ${G} coded faces, more than the ${Math.max(room, 0)} its index entry adds`);
    const end = 3 * (m + room);
    let f = 3 * m;
    let a = 0;
    let upFor = -1;
    let k = 0;
    this.fresh = 0;
    for (let i = 0; i < G; i++) {
      a += rc.uint(block(FB_GAP), 'a face gap');
      if (a > n + this.fresh) throw new FormatError(`face chunk: vertex ${a} beyond the mesh's ${n} and the ${this.fresh} new ones named`);
      if (a === n + this.fresh) { // the next new vertex: the first of a face of new vertices only
        if (this.fresh >= vroom) throw new FormatError(`face chunk: more new vertices than the ${vroom} its index entry adds`);
        this.fresh++;
      }
      if (a !== upFor) {
        k = a < n ? this.#upList(a) : 0; // a new vertex has no neighbour in the mesh before the chunk
        upFor = a;
      }
      let b;
      if (rc.bit(F_NEAR_B)) {
        const r = rc.uint(block(FB_RANK_B), 'a face rank');
        if (r >= k) throw new FormatError(`face chunk: rank ${r} in Up(${a}) of ${k} vertices`);
        b = this.up[r];
      } else {
        b = this.#unlisted(rc, a, n, vroom);
      }
      let c;
      if (rc.bit(F_NEAR_C)) {
        const r = rc.uint(block(FB_RANK_C), 'a face rank');
        c = this.#nearAt(a, b, k, r, n);
        if (c < 0) throw new FormatError(`face chunk: rank ${r} beyond Near(${a}, ${b})`);
      } else {
        c = this.#unlisted(rc, a, n, vroom);
      }
      if (b === c) throw new FormatError(`face chunk: face (${a}, ${b}, ${c}) repeats a vertex`);
      const twin = rc.bit(F_TWIN);
      if (f + 3 + 3 * twin > end) throw new FormatError(`face chunk: more faces than the ${room} its index entry adds`);
      if (f + 3 + 3 * twin > faces.length) {
        rc.checkOverrun(); // room only for faces that bytes stand behind
        st.reserve(0, (f + 3 + 3 * twin) / 3);
        faces = st.faces;
      }
      faces[f] = a; faces[f + 1] = b; faces[f + 2] = c; f += 3;
      if (twin) {
        faces[f] = a; faces[f + 1] = c; faces[f + 2] = b; f += 3;
      }
    }
    if (this.fresh !== t) {
      throw new FormatError(`face chunk: ${this.fresh} new vertices, fewer than the ${t} its index entry adds`);
    }
    st.reserve(n + t, 0); // the t new vertices the faces named
    if (t > 0) this.#freshValues(rc, n, t, 3 * m, f);
    rc.finish();
    st.m = f / 3;
    st.n = n + t;
  }

  /**
   * A face vertex not taken from a list (§8.6 Vertex): the next new vertex n + fresh (bit 3 set;
   * FormatError past `vroom` new vertices), else a + 1 + UInt(block 4): an existing vertex or a new
   * one already named (as the reference decoder reads it), FormatError unless below n + fresh.
   */
  #unlisted(rc, a, n, vroom) {
    if (rc.bit(F_FRESH)) {
      if (this.fresh >= vroom) throw new FormatError(`face chunk: more new vertices than the ${vroom} its index entry adds`);
      return n + this.fresh++;
    }
    const x = a + 1 + rc.uint(block(FB_RAW), 'a face vertex');
    if (x >= n + this.fresh) throw new FormatError(`face chunk: vertex ${x} beyond the mesh's ${n} and the ${this.fresh} new ones named`);
    return x;
  }

  /**
   * §8.6 "Values": the D values of the new vertices u = n .. n+t-1 in order, each q predicted by
   * floor(S[q] / c) over the corners p < u of the chunk's faces (corners f0 .. f1 of faces) that
   * name u, once per naming. The faces naming each u are listed first (fstart / fnames, one
   * scatter), so that every sum reads values already decoded.
   */
  #freshValues(rc, n, t, f0, f1) {
    const { faces, values, D, capN, capM } = this.state;
    const fstart = this.#grow('fstart', t + 1, Int32Array, capN + 1);
    const fnames = this.#grow('fnames', f1 - f0, Int32Array, 3 * capM); // a face may name three new vertices
    fstart.fill(0, 0, t + 1);
    for (let x = f0; x < f1; x++) if (faces[x] >= n) fstart[faces[x] - n + 1]++;
    for (let i = 0; i < t; i++) fstart[i + 1] += fstart[i];
    for (let x = f0; x < f1; x++) if (faces[x] >= n) fnames[fstart[faces[x] - n]++] = x - (x % 3); // the face's first corner
    for (let i = t; i > 0; i--) fstart[i] = fstart[i - 1]; // back to the starts
    fstart[0] = 0;
    const S = this.sums;
    for (let i = 0; i < t; i++) {
      const u = n + i;
      S.fill(0);
      let c = 0;
      for (let g = fstart[i]; g < fstart[i + 1]; g++) {
        const h = fnames[g];
        for (let j = 0; j < 3; j++) {
          const p = faces[h + j];
          if (p >= u) continue; // u itself, or a new vertex after it
          const pp = p * D;
          for (let q = 0; q < D; q++) S[q] += values[pp + q];
          c++;
        }
      }
      if (c === 0) { // the first vertex of a face of new vertices only: predicted by the vertex before it
        for (let q = 0; q < D; q++) S[q] = values[(u - 1) * D + q];
        c = 1;
      }
      for (let q = 0; q < D; q++) {
        const pred = Math.abs(S[q]) < TWO53 ? Math.floor(S[q] / c) : this.#wideMean(fstart[i], fstart[i + 1], u, q, c);
        this.#put(rc, u * D + q, pred, block(FB_VALUE + Math.min(q, 3)));
      }
    }
  }

  /**
   * floor(S[q] / c) with the exact integer sum S[q] (BigInt) of the corners p < u of the faces
   * fnames[g0 .. g1): only when the float64 sum reached 2^53 (a hostile stream's values and valence).
   */
  #wideMean(g0, g1, u, q, c) {
    const { faces, values, D } = this.state;
    let s = 0n;
    for (let g = g0; g < g1; g++) {
      for (let j = 0; j < 3; j++) {
        const p = faces[this.fnames[g] + j];
        if (p < u) s += BigInt(values[p * D + q]);
      }
    }
    const C = BigInt(c);
    let r = s / C; // truncates toward zero
    if (s % C !== 0n && s < 0n) r -= 1n;
    return Number(r);
  }

  /**
   * Up(a) of §8.6 into this.up, ascending: the distinct vertices x > a sharing a face with a (mesh
   * before the chunk, from a's corner list). Returns their number.
   */
  #upList(a) {
    const { head, nxt, stamp, up } = this;
    const { faces } = this.state;
    const e = this.#nextEpoch();
    let k = 0;
    for (let c = head[a]; c >= 0; c = nxt[c]) {
      for (let j = c - (c % 3), end = j + 3; j < end; j++) {
        const x = faces[j];
        if (x > a && stamp[x] !== e) {
          stamp[x] = e;
          up[k++] = x;
        }
      }
    }
    sortList(up, k);
    return k;
  }

  /**
   * Element r of Near(a, b) (§8.6), -1 when the list is shorter: first the distinct vertices
   * x > a, x != b sharing a face with b, ascending (sorted into this.near only when r falls among
   * them), then those of Up(a) (this.up, k) other than b sharing no face with b, in Up's order.
   */
  #nearAt(a, b, k, r, n) {
    const { head, nxt, stamp, up, near } = this;
    const { faces } = this.state;
    if (b >= n) return r < k ? up[r] : -1; // a new vertex: no neighbours, and not in Up(a)
    const e = this.#nextEpoch();
    stamp[b] = e;
    let count = 0;
    for (let c = head[b]; c >= 0; c = nxt[c]) {
      for (let j = c - (c % 3), end = j + 3; j < end; j++) {
        const x = faces[j];
        if (stamp[x] !== e) {
          stamp[x] = e;
          if (x > a) near[count++] = x;
        }
      }
    }
    if (r < count) {
      sortList(near, count);
      return near[r];
    }
    r -= count;
    for (let t = 0; t < k; t++) {
      const x = up[t];
      if (stamp[x] !== e && r-- === 0) return x;
    }
    return -1;
  }

  #batch(rc) {
    const st = this.state;
    const n = st.n;
    this.#lists(n, st.m);
    this.listsN = -1; // until the batch has updated them
    const k = this.#mask(rc, n);
    if (k === 0) throw new FormatError('chunk payload: a batch marks no split vertex');
    if (n + k > st.capN) throw new FormatError('splits exceed the declared vertex count');
    rc.checkOverrun(); // a batch read past the payload's end: refused now, not after decoding zeros
    st.reserve(n + k, 0); // the k new vertices (#newFaces makes room for the new faces)
    const touching = this.#splits(rc, n, k);
    this.#newFaces(n, k);
    if (touching) this.#recount(n, k);
    this.#values(rc, n, k);
    st.n = n + k;
    this.listsN = st.n;
    this.listsM = st.m;
  }

  /**
   * The corner lists of the mesh (n vertices, m faces) and every vertex's valence, built in one
   * pass over the faces unless they describe that mesh already (kept from batch to batch, built
   * on a primitive's first chunk and after a face chunk). Vertex w's corners, ascending (face-slot
   * order), are head[w], nxt[head[w]], ... until -1; tail[w] is the last (head (n), tail (n),
   * nxt (3m) Int32Array).
   */
  #lists(n, m) {
    if (this.listsN === n && this.listsM === m) return;
    const { faces, capN, capM } = this.state;
    const head = this.#grow('head', n, Int32Array, capN);
    this.#grow('tail', n, Int32Array, capN);
    this.#grow('nxt', 3 * m, Int32Array, 3 * capM);
    head.fill(-1, 0, n);
    for (let c = 0; c < 3 * m; c++) this.#append(faces[c], c);
    this.#grow('val', n, Int32Array, capN);
    this.#grow('vc', n, Uint8Array, capN);
    this.#grow('stamp', n, Int32Array, capN, true);
    this.#grow('stamp2', n, Int32Array, capN, true);
    for (let w = 0; w < n; w++) this.#setValence(w, this.#valence(w));
    this.listsN = n;
    this.listsM = m;
  }

  /** Appends corner c (above every corner listed for w) to w's corner list. */
  #append(w, c) {
    const { head, tail } = this;
    this.nxt[c] = -1;
    if (head[w] < 0) head[w] = c;
    else this.nxt[tail[w]] = c;
    tail[w] = c;
  }

  /** A fresh stamp value (stamp, stamp2 and slotEpoch hold values below it). */
  #nextEpoch() {
    if (this.epoch >= 0x3fffffff) {
      this.stamp.fill(0);
      this.stamp2.fill(0);
      this.slotEpoch.fill(0);
      this.epoch = 0;
    }
    return ++this.epoch;
  }

  /** |N(w)| of §8.4.1: the distinct vertices other than w that share a face with w (from its corner list). */
  #valence(w) {
    const { head, nxt, stamp } = this;
    const { faces } = this.state;
    const e = this.#nextEpoch();
    let valence = 0;
    for (let c = head[w]; c >= 0; c = nxt[c]) {
      for (let j = c - (c % 3), end = j + 3; j < end; j++) {
        const x = faces[j];
        if (x !== w && stamp[x] !== e) {
          stamp[x] = e;
          valence++;
        }
      }
    }
    return valence;
  }

  /**
   * Split vertex w's incidences from g on (§6.1 step 1, as §8.4.2 needs them: its corner list in
   * face-slot order): corner inc[g], the corners after / before it a[g], b[g]; and cnt[x] += 1
   * (saturating at 2) for every distinct neighbour x > w of w. Returns the next g.
   */
  #gather(w, g) {
    const { head, nxt, inc, a, b, stamp, cnt } = this;
    const { faces } = this.state;
    const e = this.#nextEpoch();
    for (let c = head[w]; c >= 0; c = nxt[c], g++) {
      const r = c % 3;
      const x = faces[c + AFTER[r]];
      const y = faces[c + BEFORE[r]];
      inc[g] = c;
      a[g] = x;
      b[g] = y;
      // counted when above w (not decided yet: no SPLIT bit) and met first here; no branch on either
      // (a vertex below w, whose count is no longer read, keeps its cnt: x > w is 0)
      const cx = cnt[x];
      cnt[x] = cx + ((x > w) & (stamp[x] !== e) & (cx < 2));
      stamp[x] = e;
      const cy = cnt[y];
      cnt[y] = cy + ((y > w) & (stamp[y] !== e) & (cy < 2));
      stamp[y] = e;
    }
    return g;
  }

  /**
   * §8.4.1: one bit per vertex w < n under the context 7 nb + vc, vc kept per vertex, nb = cnt[w]
   * (marked distinct neighbours below w, counted up to 2 as the marks are decoded). Leaves the
   * split vertices in v and their incidences grouped per split (#gather; split i's are
   * gstart[i] .. gstart[i+1]-1); returns k.
   */
  #mask(rc, n) {
    const { capN, capM, m } = this.state;
    const v = this.#grow('v', n, Int32Array, capN);
    const gstart = this.#grow('gstart', n + 1, Int32Array, capN + 1);
    for (const name of ['inc', 'a', 'b']) this.#grow(name, 3 * m, Int32Array, 3 * capM);
    this.#grow('sym', 3 * m, Uint8Array, 3 * capM);
    const cnt = this.#grow('cnt', n, Uint8Array, capN);
    const { vc } = this;
    cnt.fill(0, 0, n);
    let k = 0;
    let g = 0;
    for (let w = 0; w < n; w++) {
      if (rc.bit(7 * cnt[w] + vc[w]) === 1) {
        cnt[w] |= SPLIT; // read by #splits; the contexts of the vertices after w never read it
        gstart[k] = g;
        v[k++] = w;
        g = this.#gather(w, g);
      }
    }
    gstart[k] = g;
    return k;
  }

  /**
   * Orders split i's incidences g0 .. g0+d-1 into this.fan (spec §8.4.2 "Fan"). Returns 1 closed,
   * 2 open, 0 not simple. The a are hashed (FAN_SLOTS slots, linear probing, slots of this fan
   * marked by an epoch): a repeated a fails at once, and the successor of t is the t2 whose a is
   * b[t]. With distinct a, a successor named twice means two equal b; any other repeated b (with no
   * successor) leaves two ends to the walk, which then fails: so the spec's conditions hold
   * exactly when these checks and the walk pass.
   */
  #fanOf(g0, d) {
    const { a, b, fan, succ, hasPred, slotKey, slotOf, slotEpoch } = this;
    const e = this.#nextEpoch();
    for (let t = 0; t < d; t++) {
      const x = a[g0 + t];
      let h = Math.imul(x, HASH_MUL) >>> FAN_SHIFT;
      for (; slotEpoch[h] === e; h = (h + 1) & (FAN_SLOTS - 1)) if (slotKey[h] === x) return 0;
      slotEpoch[h] = e;
      slotKey[h] = x;
      slotOf[h] = t;
      hasPred[t] = 0;
    }
    for (let t = 0; t < d; t++) { // t2 follows t: its a is the b of t
      const y = b[g0 + t];
      let next = -1;
      for (let h = Math.imul(y, HASH_MUL) >>> FAN_SHIFT; slotEpoch[h] === e; h = (h + 1) & (FAN_SLOTS - 1)) {
        if (slotKey[h] === y) {
          next = slotOf[h];
          if (hasPred[next] !== 0) return 0;
          hasPred[next] = 1;
          break;
        }
      }
      succ[t] = next;
    }
    let first = -1;
    let starts = 0;
    for (let t = 0; t < d; t++) { // t starts the walk when no b equals its a
      if (hasPred[t] === 0) {
        starts++;
        if (first < 0) first = t;
      }
    }
    if (starts > 1) return 0;
    const kind = starts === 0 ? 1 : 2;
    if (starts === 0) first = 0;
    for (let s = 0, t = first; s < d; s++) {
      fan[s] = g0 + t;
      const next = succ[t];
      if (s < d - 1) {
        if (next < 0 || next === first) return 0;
        t = next;
      } else if ((kind === 1 && next !== first) || (kind === 2 && next >= 0)) {
        return 0;
      }
    }
    return kind;
  }


  /**
   * The batch's splits in order (split i's incidences g = gstart[i] .. gstart[i+1]-1: corner
   * inc[g], corners a[g], b[g] of the mesh before the batch), each while its incidences are at
   * hand: its symbols (§8.4.2, #symbols); §6.1 step 2, the moved corners to u = n + i, with v's and
   * u's corner lists relisted; what §8.4.3 reads of its ring (#ring); its valences (#revalueSplit).
   * Returns whether a moved face holds another split vertex (no batch of independent splits
   * does): the valences are then recounted once the batch is applied (#recount).
   */
  #splits(rc, n, k) {
    const { faces, capN, D } = this.state;
    const { inc, a, b, sym, v, gstart } = this;
    const head = this.#grow('head', n + k, Int32Array, capN, true);
    this.#grow('tail', n + k, Int32Array, capN, true);
    this.#grow('val', n + k, Int32Array, capN, true);
    this.#grow('vc', n + k, Uint8Array, capN, true);
    this.#grow('stamp', n + k, Int32Array, capN, true);
    this.#grow('stamp2', n + k, Int32Array, capN, true);
    this.#grow('ringSums', k * D, Float64Array, capN * D);
    this.#grow('ringNormals', 3 * k, Float64Array, 3 * capN);
    this.#grow('ringCount', k, Int32Array, capN);
    this.#grow('ringClass', k, Int32Array, capN);
    const { cnt } = this; // cnt[x] & SPLIT: x is a split vertex of the batch (#mask)
    let touching = false;
    for (let i = 0; i < k; i++) {
      const g0 = gstart[i];
      const g1 = gstart[i + 1];
      const vi = v[i];
      const kind = this.#symbols(rc, vi, g0, g1 - g0);
      const u = n + i;
      head[u] = -1;
      head[vi] = -1;
      for (let g = g0; g < g1; g++) {
        const c = inc[g];
        if (sym[g] === 0) {
          this.#append(vi, c);
          continue;
        }
        if (((cnt[a[g]] | cnt[b[g]]) & SPLIT) !== 0) touching = true;
        faces[c] = u;
        this.#append(u, c);
      }
      this.#ring(i, g0, g1);
      if (!touching && !(kind === 1 && this.#revalueArc(i, u, g0, g1 - g0))) this.#revalueSplit(i, u);
    }
    return touching;
  }

  /**
   * §8.4.2: the symbols sym[g0 .. g0+d) of the incidences of a split of vertex vi. Returns the
   * fan's kind (1 closed, 2 open) when they are an arc (its start in this.fan at arcFirst, its
   * length arcLength), else 0.
   */
  #symbols(rc, vi, g0, d) {
    const { sym, fan } = this;
    const kind = d >= 1 && d <= MAX_ARC_FAN ? this.#fanOf(g0, d) : 0;
    if (kind === 0 || rc.bit(P_ESCAPE)) {
      for (let t = 0; t < d; t++) {
        const x = rc.tree(P_SYMBOL, 3);
        if (x >= 5) throw new FormatError('chunk payload: unknown incidence symbol');
        sym[g0 + t] = x;
      }
      return 0;
    }
    const L = rc.uint(block(B_LENGTH + Math.min(d, 16) - 1), 'an arc length') + 1;
    if (L > d) throw new FormatError('chunk payload: an arc is longer than its fan');
    const ncand = kind === 1 ? d : d - L + 1;
    const r = rc.uint(block(B_RANK + Math.min(ncand, 16) - 1), 'an arc start rank');
    if (r >= ncand) throw new FormatError('chunk payload: an arc start rank is out of range');
    const s = arcStart(r, d, ncand, L, this.#fanLengths(vi, d));
    const left = kind === 2 && s === 0 ? rc.bit(P_WING) : 1;
    const right = kind === 2 && s + L === d ? rc.bit(P_WING + 1) : 1;
    for (let t = 0; t < d; t++) {
      const q = t >= s ? t - s : t - s + d; // (t - s) mod d
      sym[fan[t]] = q >= L ? 0 : 1 + (q === 0 ? left : 0) + 2 * (q === L - 1 ? right : 0);
    }
    this.arcFirst = s;
    this.arcLength = L;
    return kind;
  }

  /**
   * §8.4.2 "Start rank": lens[t] = the length from split vertex vi to the corner a of fan[t], t < d
   * (the values of the mesh before the batch). Returns lens.
   */
  #fanLengths(vi, d) {
    const { values, D } = this.state;
    const { a, fan, lens } = this;
    const pv = vi * D;
    for (let t = 0; t < d; t++) {
      const px = a[fan[t]] * D;
      const dx = values[px] - values[pv];
      const dy = values[px + 1] - values[pv + 1];
      const dz = values[px + 2] - values[pv + 2];
      lens[t] = Math.sqrt((dx * dx + dy * dy) + dz * dz);
    }
    return lens;
  }

  /**
   * §6.1 step 3 once every split is decoded: the new faces ((u, v, a) left, (v, u, b) right) are
   * appended in the face-slot order of the incidences that create them, their corners listed
   * (above every listed corner); FormatError when they exceed the declared face count or a split
   * creates no new face or more than two. The creating corners are put in order by a bitmap over
   * the corners (one bit a corner: a 32nd of a pass over the faces, less than the mask's).
   */
  #newFaces(n, k) {
    const st = this.state;
    const { capM, capN } = st;
    const { inc, a, b, sym, v, gstart } = this;
    const wings = this.#grow('wings', k, Int32Array, capN);
    const creatorOf = this.#grow('creatorOf', 3 * st.m, Int32Array, 3 * capM); // the incidence of a creating corner
    const words = (3 * st.m + 31) >>> 5;
    const created = this.#grow('created', words, Int32Array, (3 * capM + 31) >>> 5).fill(0, 0, words);
    let added = 0;
    for (let i = 0; i < k; i++) {
      let w = 0;
      for (let g = gstart[i]; g < gstart[i + 1]; g++) {
        const s = sym[g];
        if (s < 2) continue;
        w += s === 4 ? 2 : 1;
        creatorOf[inc[g]] = g;
        created[inc[g] >>> 5] |= 1 << (inc[g] & 31);
      }
      wings[i] = w;
      added += w;
    }
    if (st.m + added > capM) throw new FormatError('splits exceed the declared face count');
    for (let i = 0; i < k; i++) {
      if (wings[i] < 1 || wings[i] > 2) throw new FormatError('a split names no new face or more than two');
    }
    st.reserve(0, st.m + added);
    const { faces } = st;
    this.#grow('nxt', 3 * (st.m + added), Int32Array, 3 * capM, true);
    let f = 3 * st.m;
    for (let word = 0; word < words; word++) {
      for (let bits = created[word]; bits !== 0; bits &= bits - 1) {
        const c = 32 * word + 31 - Math.clz32(bits & -bits); // the corners in order
        const i = faces[c] - n; // a creating corner is a moved one: it now holds u_i
        const g = creatorOf[c];
        const s = sym[g];
        if (s === 2 || s === 4) f = this.#newFace(f, n + i, v[i], a[g]);
        if (s === 3 || s === 4) f = this.#newFace(f, v[i], n + i, b[g]);
      }
    }
    st.m += added;
  }

  /** Writes the face (x, y, z) at corner f and lists its corners; returns the next face's corner. */
  #newFace(f, x, y, z) {
    const { faces } = this.state;
    faces[f] = x; faces[f + 1] = y; faces[f + 2] = z;
    this.#append(x, f);
    this.#append(y, f + 1);
    this.#append(z, f + 2);
    return f + 3;
  }

  /**
   * The valences after a batch (n vertices before it, k splits) whose splits touch each other's
   * moved faces: every vertex whose faces changed (the split vertices, the new ones, the corners
   * a, b of their incidences) recounted from its corner list.
   */
  #recount(n, k) {
    const { v, a, b, gstart } = this;
    for (let g = 0; g < gstart[k]; g++) {
      this.#setValence(a[g], this.#valence(a[g]));
      this.#setValence(b[g], this.#valence(b[g]));
    }
    for (let i = 0; i < k; i++) {
      this.#setValence(v[i], this.#valence(v[i]));
      this.#setValence(n + i, this.#valence(n + i));
    }
  }

  /**
   * The valences after split i of a batch whose moved faces hold no split vertex but their own.
   * Then v's faces are its unmoved ones and the new ones, so its neighbours N'(v) are read from
   * the incidences (marked in stamp2): a and b of an unmoved face, a of a left new face, b of a
   * right one, and u. u's neighbours are the distinct corners x of its moved faces, and v; each
   * such x gains u and loses v unless x is in N'(v). A vertex x in the moved faces of several
   * splits gets each split's change in turn.
   */
  #revalueSplit(i, u) {
    const { v, a, b, sym, gstart, stamp, stamp2, val } = this;
    const vi = v[i];
    const g0 = gstart[i];
    const g1 = gstart[i + 1];
    const e1 = this.#nextEpoch();
    let cv = 1; // u
    for (let g = g0; g < g1; g++) {
      const s = sym[g];
      const x = a[g];
      if ((s === 0 || s === 2 || s === 4) && x !== vi && stamp2[x] !== e1) {
        stamp2[x] = e1;
        cv++;
      }
      const y = b[g];
      if ((s === 0 || s === 3 || s === 4) && y !== vi && stamp2[y] !== e1) {
        stamp2[y] = e1;
        cv++;
      }
    }
    this.#setValence(vi, cv);
    const e2 = this.#nextEpoch();
    let cu = 1; // v
    for (let g = g0; g < g1; g++) {
      if (sym[g] === 0) continue;
      for (let x = a[g], j = 0; j < 2; j++, x = b[g]) {
        if (stamp[x] === e2) continue;
        stamp[x] = e2;
        cu++;
        this.#setValence(x, val[x] + (stamp2[x] === e1 ? 1 : 0));
      }
    }
    this.#setValence(u, cu);
  }

  /**
   * #revalueSplit for the arc of a closed fan of d faces (the ring vertices r_t = a of fan[t], all
   * distinct; b of fan[t] is r_(t+1)) whose moved faces r_s .. r_(s+L) hold no split vertex: u's
   * neighbours are those L + 1 (L < d) or d (L = d) vertices and v; v keeps r_(s+L) .. r_s and
   * gains u; r_s and r_(s+L) gain u, the others between them swap v for u. False (nothing
   * changed) when a ring vertex is v itself: #revalueSplit then counts.
   */
  #revalueArc(i, u, g0, d) {
    const { a, v, fan, val } = this;
    const vi = v[i];
    for (let g = g0; g < g0 + d; g++) if (a[g] === vi) return false;
    const s = this.arcFirst;
    const L = this.arcLength;
    const rs = a[fan[s]];
    this.#setValence(rs, val[rs] + 1);
    if (L < d) {
      const re = a[fan[s + L < d ? s + L : s + L - d]];
      this.#setValence(re, val[re] + 1);
    }
    this.#setValence(vi, L < d ? d - L + 2 : 2);
    this.#setValence(u, L < d ? L + 2 : d + 1);
    return true;
  }

  /** val[w] = valence and vc[w] its class min(max(valence, 3), 9) - 3 (§8.4.1). */
  #setValence(w, valence) {
    this.val[w] = valence;
    this.vc[w] = valence < 3 ? 0 : valence > 9 ? 6 : valence - 3;
  }

  /**
   * What §8.4.3 reads of split i's ring (incidences g0 .. g1-1 with their symbols): over the moved
   * faces and the new ones, S (ringSums[D i ..]), their number c (ringCount[i]), the length class
   * of the ring (ringClass[i]) and the normal (ringNormals[3 i ..]), from the values of the mesh
   * before the batch, which the batch leaves as they are.
   */
  #ring(i, g0, g1) {
    const { values, D } = this.state;
    const { sym, a, b, v, ringSums: S } = this;
    const pv = v[i] * D;
    const vx = values[pv];
    const vy = values[pv + 1];
    const vz = values[pv + 2];
    let sx = 0;
    let sy = 0;
    let sz = 0;
    let c = 0;
    let ell = 0;
    let nx = 0.0;
    let ny = 0.0;
    let nz = 0.0;
    for (let j = g0; j < g1; j++) {
      const s = sym[j];
      if (s === 0) continue;
      const pa = a[j] * D;
      const pb = b[j] * D;
      const ax = values[pa];
      const ay = values[pa + 1];
      const az = values[pa + 2];
      const bx = values[pb];
      const by = values[pb + 1];
      const bz = values[pb + 2];
      sx += ax + bx;
      sy += ay + by;
      sz += az + bz;
      c++;
      ell += Math.abs(ax - bx) + Math.abs(ay - by) + Math.abs(az - bz);
      const e1x = ax - vx;
      const e1y = ay - vy;
      const e1z = az - vz;
      const e2x = bx - vx;
      const e2y = by - vy;
      const e2z = bz - vz;
      nx += e1y * e2z - e1z * e2y;
      ny += e1z * e2x - e1x * e2z;
      nz += e1x * e2y - e1y * e2x;
      if (s >= 2) { // the new faces: (u, v, a) left for symbols 2 and 4, (v, u, b) right for 3 and 4
        const left = s === 3 ? 0 : 1;
        const right = s === 2 ? 0 : 1;
        sx += (left + right) * vx + left * ax + right * bx;
        sy += (left + right) * vy + left * ay + right * by;
        sz += (left + right) * vz + left * az + right * bz;
        c += left + right;
        ell += left * (Math.abs(vx - ax) + Math.abs(vy - ay) + Math.abs(vz - az))
          + right * (Math.abs(vx - bx) + Math.abs(vy - by) + Math.abs(vz - bz));
      }
    }
    const o = i * D;
    S[o] = sx;
    S[o + 1] = sy;
    S[o + 2] = sz;
    if (D > 3) this.#ringAttributes(i, g0, g1);
    this.ringCount[i] = c;
    this.ringClass[i] = Math.min(bitLength(Math.floor(ell / c)), GEOMETRY_CLASSES - 1);
    this.ringNormals[3 * i] = nx;
    this.ringNormals[3 * i + 1] = ny;
    this.ringNormals[3 * i + 2] = nz;
  }

  /** #ring's sums S[q] of the attribute values q = 3 .. D-1. */
  #ringAttributes(i, g0, g1) {
    const { values, D } = this.state;
    const { sym, a, b, v, ringSums: S } = this;
    const pv = v[i] * D;
    const o = i * D;
    for (let q = 3; q < D; q++) {
      let sq = 0;
      for (let j = g0; j < g1; j++) {
        const s = sym[j];
        if (s === 0) continue;
        const xa = values[a[j] * D + q];
        const xb = values[b[j] * D + q];
        sq += xa + xb;
        if (s >= 2) sq += (s === 4 ? 2 : 1) * values[pv + q] + (s === 3 ? 0 : xa) + (s === 2 ? 0 : xb);
      }
      S[o + q] = sq;
    }
  }

  /**
   * §8.4.3: the D values of each new vertex u = n + i, split by split, from its ring (#ring): the
   * frame prediction (float64, in the spec's order), the two non-dominant axes, the dominant one
   * against the ring plane, then attributes.
   */
  #values(rc, n, k) {
    const { values, D } = this.state;
    const { v, ringSums: S, ringNormals, ringCount, ringClass } = this;
    const ph = this.frame; // ph[0..3), then the normal at [3..6)
    for (let i = 0; i < k; i++) {
      const pu = (n + i) * D;
      const pv = v[i] * D;
      const o = i * D;
      const nx = ringNormals[3 * i];
      const ny = ringNormals[3 * i + 1];
      const nz = ringNormals[3 * i + 2];
      const two = 2 * ringCount[i];
      const m0 = S[o] / two;
      const m1 = S[o + 1] / two;
      const m2 = S[o + 2] / two;
      const nn = (nx * nx + ny * ny) + nz * nz;
      let p0 = m0;
      let p1 = m1;
      let p2 = m2;
      let dom = 2;
      if (nn > 0) {
        const h = (((values[pv] - m0) * nx + (values[pv + 1] - m1) * ny) + (values[pv + 2] - m2) * nz) / nn;
        p0 = m0 + h * nx;
        p1 = m1 + h * ny;
        p2 = m2 + h * nz;
        const ax = Math.abs(nx);
        const ay = Math.abs(ny);
        const az = Math.abs(nz);
        dom = ax >= ay && ax >= az ? 0 : ay >= az ? 1 : 2;
      }
      const i0 = dom === 0 ? 1 : 0;
      const i1 = dom === 2 ? 1 : 2;
      ph[0] = p0; ph[1] = p1; ph[2] = p2; ph[3] = nx; ph[4] = ny; ph[5] = nz;
      const base = block(B_GEOMETRY + 3 * ringClass[i]);
      const x0 = this.#put(rc, pu + i0, round(ph[i0]), base);
      const x1 = this.#put(rc, pu + i1, round(ph[i1]), base + INT_BLOCK);
      const pk = nn > 0 ? ph[dom] - ((x0 - ph[i0]) * ph[3 + i0] + (x1 - ph[i1]) * ph[3 + i1]) / ph[3 + dom] : ph[dom];
      this.#put(rc, pu + dom, round(pk), base + 2 * INT_BLOCK);
      for (let q = 3; q < D; q++) {
        const mean = Math.floor(S[o + q] / two);
        if (this.plane !== null && this.plane[q] === 1) {
          const pred = this.#planePrediction(i, q, i0, i1, pu, pv, mean);
          const cls = Math.min(bitLength(Math.floor(this.spread / two)), PLANE_CLASSES - 1);
          this.#put(rc, pu + q, pred, block(B_PLANE + Math.min(q - 3, 7) * PLANE_CLASSES + cls));
        } else {
          this.#put(rc, pu + q, mean, block(B_ATTRIBUTE + Math.min(q - 3, 7)));
        }
      }
    }
  }

  /**
   * §8.4.3, plane prediction: value q of the new vertex (values at pu) of split i (kept vertex at pv), the
   * affine function of the non-dominant axes i0, i1 fitted by least squares to the ring's corners (a, b of
   * each face; v, a of a left face; v, b of a right face), at the new vertex, rounded and kept within the
   * corners' and v's range widened by its span; `mean` when the fit is singular. Sets this.spread (the sum
   * of |corner value - v's value|).
   */
  #planePrediction(i, q, i0, i1, pu, pv, mean) {
    const { values, D } = this.state;
    const { sym, a, b, gstart } = this;
    const vq = values[pv + q];
    const v0 = values[pv + i0];
    const v1 = values[pv + i1];
    let a00 = 0; let a01 = 0; let a11 = 0; let a0 = 0; let a1 = 0; let nn = 0;
    let b0 = 0; let b1 = 0; let bw = 0;
    let spread = 0; let lo = vq; let hi = vq;
    for (let j = gstart[i]; j < gstart[i + 1]; j++) {
      const s = sym[j];
      if (s === 0) continue;
      for (let t = 0; t < 6; t++) { // a, b; v, a for a left face (2, 4); v, b for a right face (3, 4)
        if (((t === 2 || t === 3) && s !== 2 && s !== 4) || (t >= 4 && s !== 3 && s !== 4)) continue;
        const k = (t === 0 || t === 3 ? a[j] : t === 1 || t === 5 ? b[j] : this.v[i]) * D;
        const d0 = values[k + i0] - v0;
        const d1 = values[k + i1] - v1;
        const w = values[k + q] - vq;
        a00 += d0 * d0;
        a01 += d0 * d1;
        a11 += d1 * d1;
        a0 += d0;
        a1 += d1;
        nn += 1;
        b0 += d0 * w;
        b1 += d1 * w;
        bw += w;
        spread += Math.abs(w);
        lo = Math.min(lo, values[k + q]);
        hi = Math.max(hi, values[k + q]);
      }
    }
    this.spread = spread;
    const m00 = a11 * nn - a1 * a1;
    const m01 = a01 * nn - a1 * a0;
    const m02 = a01 * a1 - a11 * a0;
    const det = (a00 * m00 - a01 * m01) + a0 * m02;
    if (!(det > PLANE_SINGULAR * ((a00 * a11) * nn))) return mean;
    const alpha = ((b0 * m00 - a01 * (b1 * nn - a1 * bw)) + a0 * (b1 * a1 - a11 * bw)) / det;
    const beta = ((a00 * (b1 * nn - a1 * bw) - b0 * m01) + a0 * (a01 * bw - b1 * a0)) / det;
    const gamma = ((a00 * (a11 * bw - a1 * b1) - a01 * (a01 * bw - b1 * a0)) + b0 * m02) / det;
    const t0 = values[pu + i0] - v0;
    const t1 = values[pu + i1] - v1;
    const span = hi - lo; // the fit kept within the range widened by its span, before rounding (integer bounds)
    return vq + round(Math.min(Math.max((alpha * t0 + beta * t1) + gamma, lo - span - vq), hi + span - vq));
  }

  /** values[at] = pred + SInt(ctx), checked |x| < 2^31; returns it. */
  #put(rc, at, pred, ctx) {
    const x = pred + rc.sint(ctx, 'a residual');
    if (!(x < MAX_VALUE && x > -MAX_VALUE)) throw new FormatError('chunk payload: a decoded value is out of range');
    this.state.values[at] = x;
    return x;
  }
}
