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
 */
import { FormatError, LimitError } from './errors.js';
import { MAX_BATCHES_PER_CHUNK } from './constants.js';
import { INT_BLOCK, RangeDecoder, newProbabilities } from './rangecoder.js';

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
const GEOMETRY_CLASSES = 32;
/** Size of a primitive's probability table: 32 single probabilities, 137 integer blocks. */
export const N_PROBS = P_INT + (B_ATTRIBUTE + 8) * INT_BLOCK;
/** Fans of more faces are never simple (their symbols are coded one by one). */
const MAX_ARC_FAN = 32;
/** Decoded values must satisfy |x| < 2^31. */
const MAX_VALUE = 2147483648;
const TWO32 = 4294967296;

const block = (b) => P_INT + INT_BLOCK * b;

/** Bits of the non-negative integer x (0 for 0), for any x below 2^53. */
function bitLength(x) {
  let b = 0;
  while (x >= TWO32) {
    x = Math.floor(x / TWO32);
    b += 32;
  }
  return b + 32 - Math.clz32(x);
}

/** floor(x + 0.5): the rounding of the frame predictions. */
const round = (x) => Math.floor(x + 0.5);

/**
 * The candidate start of rank r of an arc of L faces in a fan of d (spec §8.4.2 "Start rank"):
 * lens[t] (t < d) the length from v to the corner a of fan[t], lens[32 + c] the score of start c.
 */
function arcStart(r, fan, d, ncand, L, a, values, D, v, lens) {
  const pv = v * D;
  for (let t = 0; t < d; t++) {
    const pa = a[fan[t]] * D;
    const dx = values[pa] - values[pv];
    const dy = values[pa + 1] - values[pv + 1];
    const dz = values[pa + 2] - values[pv + 2];
    lens[t] = Math.sqrt((dx * dx + dy * dy) + dz * dz);
  }
  for (let c = 0; c < ncand; c++) {
    let sc = 0.0;
    for (let j = 1; j < L; j++) sc += lens[(c + j) % d];
    lens[MAX_ARC_FAN + c] = sc;
  }
  for (let c = 0; c < ncand; c++) {
    const sc = lens[MAX_ARC_FAN + c];
    let rank = 0;
    for (let c2 = 0; c2 < ncand; c2++) {
      const s2 = lens[MAX_ARC_FAN + c2];
      if (s2 > sc || (s2 === sc && c2 < c)) rank++;
    }
    if (rank === r) return c;
  }
  return -1; // ranks are a permutation of 0 .. ncand-1: never reached
}

export class ChunkDecoderV2 {
  /** @param {import('./vsplit.js').MeshState} state the primitive's mesh, decoded into in place */
  constructor(state) {
    this.state = state;
    this.probs = newProbabilities(N_PROBS);
    this.fan = new Int32Array(MAX_ARC_FAN);
    this.lens = new Float64Array(2 * MAX_ARC_FAN); // lengths, then scores
    this.sums = new Float64Array(state.D);
    this.frame = new Float64Array(6);
    // scratch arrays (see #grow), declared here so that the object keeps one shape
    for (const name of ['off', 'nb', 'stamp', 'v', 'slot', 'gstart', 'gfill', 'inc', 'owner', 'a', 'b', 'gidx',
      'posA', 'posB', 'wings']) this[name] = new Int32Array(0);
    this.sel = new Uint8Array(0);
    this.sym = new Uint8Array(0);
  }

  /**
   * Scratch array `name` with at least `size` (<= max) elements, grown geometrically up to `max`
   * (contents not kept; a new array is filled with `fillValue` when given).
   */
  #grow(name, size, Type, max, fillValue) {
    let arr = this[name];
    if (arr.length < size) {
      const cap = Math.min(Math.max(size, 2 * arr.length), Math.max(size, max));
      try {
        arr = new Type(cap);
      } catch (e) {
        if (!(e instanceof RangeError)) throw e;
        throw new LimitError(`cannot allocate ${cap} scratch entries (${e.message})`);
      }
      if (fillValue !== undefined) arr.fill(fillValue);
      this[name] = arr;
    }
    return arr;
  }

  /**
   * Decodes one chunk's stored stream `buf` (Uint8Array) into the mesh, batch after batch, then
   * checks its termination. FormatError / LimitError on any invalid code, count or termination
   * (the mesh may then be half changed: the decoder refuses to show it).
   */
  decodeChunk(buf) {
    const rc = new RangeDecoder(buf, this.probs);
    const batches = rc.uint(block(B_BATCHES), 'the batch count') + 1;
    if (batches > MAX_BATCHES_PER_CHUNK) {
      throw new LimitError(`chunk payload: batch count ${batches} outside 1..${MAX_BATCHES_PER_CHUNK}`);
    }
    for (let j = 0; j < batches; j++) this.#batch(rc);
    rc.finish();
  }

  #batch(rc) {
    const st = this.state;
    const n = st.n;
    const k = this.#mask(rc, n, st.m);
    if (k === 0) throw new FormatError('chunk payload: a batch marks no split vertex');
    if (n + k > st.capN) throw new FormatError('splits exceed the declared vertex count');
    const I = this.#incidences(n, st.m, k);
    this.#connectivity(rc, k);
    this.#topology(k, I);
    this.#values(rc, n, k);
    st.n = n + k;
  }

  /**
   * §8.4.1: one bit per vertex w < n under the context of its distinct neighbours (valence class)
   * and the marked ones below w. Builds the vertex -> neighbour lists `nb` (the two other corners
   * of each of its corners, in `off[w] .. off[w+1]`; off[w+1] - off[w] is twice its corner count). Leaves sel (n) Uint8Array, and the split vertices v (k) Int32Array and
   * their slot (slot[v[i]] = i). Returns k.
   */
  #mask(rc, n, m) {
    const { faces } = this.state;
    const { capN, capM } = this.state;
    const off = this.#grow('off', n + 1, Int32Array, capN + 1);
    const nb = this.#grow('nb', 6 * m, Int32Array, 6 * capM);
    const stamp = this.#grow('stamp', n, Int32Array, capN);
    const sel = this.#grow('sel', n, Uint8Array, capN);
    off.fill(0, 0, n + 1);
    stamp.fill(-1, 0, n);
    for (let c = 0; c < 3 * m; c++) off[faces[c]] += 2;
    for (let w = 1; w < n; w++) off[w] += off[w - 1];
    off[n] = 6 * m;
    for (let f = 3 * m - 3; f >= 0; f -= 3) { // the two other corners of every corner, listed per vertex
      const x = faces[f];
      const y = faces[f + 1];
      const z = faces[f + 2];
      nb[--off[x]] = y; nb[--off[x]] = z;
      nb[--off[y]] = z; nb[--off[y]] = x;
      nb[--off[z]] = x; nb[--off[z]] = y;
    }
    let k = 0;
    for (let w = 0; w < n; w++) {
      let valence = 0;
      let below = 0;
      for (let t = off[w], end = off[w + 1]; t < end; t++) {
        const x = nb[t];
        if (x !== w && stamp[x] !== w) {
          stamp[x] = w;
          valence++;
          if (x < w) below += sel[x];
        }
      }
      const bit = rc.bit(P_MASK + 7 * (below < 2 ? below : 2) + (valence < 3 ? 0 : valence > 9 ? 6 : valence - 3));
      sel[w] = bit;
      k += bit;
    }
    const v = this.#grow('v', k, Int32Array, capN);
    const slot = this.#grow('slot', n, Int32Array, capN, -1);
    for (let w = 0, i = 0; w < n; w++) {
      if (sel[w]) {
        slot[w] = i;
        v[i++] = w;
      }
    }
    return k;
  }

  /**
   * §6.1 step 1 grouped as §8.4.2 needs them: incidences t (face-slot order) with corner inc[t],
   * split owner[t], corners after / before a[t], b[t] (mesh before the batch); split i's
   * incidences gidx[gstart[i] .. gstart[i+1]) in face-slot order. Resets slot. Returns I.
   */
  #incidences(n, m, k) {
    const { faces } = this.state;
    const { off, v, slot } = this;
    const { capN, capM } = this.state;
    const gstart = this.#grow('gstart', k + 1, Int32Array, capN + 1);
    const fill = this.#grow('gfill', k, Int32Array, capN);
    gstart[0] = 0;
    for (let i = 0; i < k; i++) {
      gstart[i + 1] = gstart[i] + ((off[v[i] + 1] - off[v[i]]) >> 1); // corners of v[i]
      fill[i] = gstart[i];
    }
    const I = gstart[k];
    const inc = this.#grow('inc', I, Int32Array, 3 * capM);
    const owner = this.#grow('owner', I, Int32Array, 3 * capM);
    const a = this.#grow('a', I, Int32Array, 3 * capM);
    const b = this.#grow('b', I, Int32Array, 3 * capM);
    const gidx = this.#grow('gidx', I, Int32Array, 3 * capM);
    this.#grow('sym', I, Uint8Array, 3 * capM);
    let t = 0;
    for (let c = 0; c < 3 * m; c += 3) {
      for (let j = 0; j < 3; j++) {
        const i = slot[faces[c + j]];
        if (i < 0) continue;
        inc[t] = c + j;
        owner[t] = i;
        a[t] = faces[c + ((j + 1) % 3)];
        b[t] = faces[c + ((j + 2) % 3)];
        gidx[fill[i]++] = t;
        t++;
      }
    }
    for (let i = 0; i < k; i++) slot[v[i]] = -1;
    return I;
  }

  /**
   * Orders split i's incidences J = gidx[g0 .. g0+d) into this.fan (spec §8.4.2 "Fan").
   * Returns 1 closed, 2 open, 0 not simple. posA / posB (n) all -1 on entry and on return.
   */
  #fanOf(g0, d) {
    const { gidx, a, b, fan, posA, posB } = this;
    let kind = 1;
    for (let t = 0; t < d; t++) {
      const j = gidx[g0 + t];
      if (posA[a[j]] >= 0 || posB[b[j]] >= 0) kind = 0;
      posA[a[j]] = t;
      posB[b[j]] = t;
    }
    if (kind !== 0) {
      let first = -1;
      let starts = 0;
      for (let t = 0; t < d; t++) {
        if (posB[a[gidx[g0 + t]]] < 0) {
          starts++;
          if (first < 0) first = t;
        }
      }
      if (starts === 0) first = 0;
      kind = starts === 0 ? 1 : starts === 1 ? 2 : 0;
      for (let s = 0, t = first; kind !== 0 && s < d; s++) {
        const j = gidx[g0 + t];
        fan[s] = j;
        const next = posA[b[j]];
        if (s < d - 1) {
          if (next < 0 || next === first) kind = 0;
          t = next;
        } else if ((kind === 1 && next !== first) || (kind === 2 && next >= 0)) {
          kind = 0;
        }
      }
    }
    for (let t = 0; t < d; t++) {
      const j = gidx[g0 + t];
      posA[a[j]] = -1;
      posB[b[j]] = -1;
    }
    return kind;
  }

  /** §8.4.2: the incidence symbols sym (I) of the batch, split by split. */
  #connectivity(rc, k) {
    const { gstart, gidx, sym, fan, v, a } = this;
    const { values, D, n, capN } = this.state;
    this.#grow('posA', n, Int32Array, capN, -1);
    this.#grow('posB', n, Int32Array, capN, -1);
    for (let i = 0; i < k; i++) {
      const g0 = gstart[i];
      const d = gstart[i + 1] - g0;
      const kind = d >= 1 && d <= MAX_ARC_FAN ? this.#fanOf(g0, d) : 0;
      if (kind === 0 || rc.bit(P_ESCAPE)) {
        for (let t = 0; t < d; t++) {
          const x = rc.tree(P_SYMBOL, 3);
          if (x >= 5) throw new FormatError('chunk payload: unknown incidence symbol');
          sym[gidx[g0 + t]] = x;
        }
        continue;
      }
      const L = rc.uint(block(B_LENGTH + Math.min(d, 16) - 1), 'an arc length') + 1;
      if (L > d) throw new FormatError('chunk payload: an arc is longer than its fan');
      const ncand = kind === 1 ? d : d - L + 1;
      const r = rc.uint(block(B_RANK + Math.min(ncand, 16) - 1), 'an arc start rank');
      if (r >= ncand) throw new FormatError('chunk payload: an arc start rank is out of range');
      const s = arcStart(r, fan, d, ncand, L, a, values, D, v[i], this.lens);
      const left = kind === 2 && s === 0 ? rc.bit(P_WING) : 1;
      const right = kind === 2 && s + L === d ? rc.bit(P_WING + 1) : 1;
      for (let t = 0; t < d; t++) {
        const q = (t - s + d) % d;
        sym[fan[t]] = q >= L ? 0 : 1 + (q === 0 ? left : 0) + 2 * (q === L - 1 ? right : 0);
      }
    }
  }

  /**
   * §6.1 steps 2-3: every moved corner becomes u_i, new faces are appended in incidence order
   * ((u, v, a) left, (v, u, b) right); FormatError when they exceed the declared face count or a
   * split creates no new face or more than two.
   */
  #topology(k, I) {
    const st = this.state;
    const { faces, capM } = st;
    const { inc, owner, a, b, sym, v } = this;
    const n = st.n;
    const wings = this.#grow('wings', k, Int32Array, st.capN);
    wings.fill(0, 0, k);
    let added = 0;
    for (let t = 0; t < I; t++) {
      const s = sym[t];
      added += (s === 2 || s === 3) ? 1 : s === 4 ? 2 : 0;
      wings[owner[t]] += (s === 2 || s === 3) ? 1 : s === 4 ? 2 : 0;
    }
    if (st.m + added > capM) throw new FormatError('splits exceed the declared face count');
    for (let i = 0; i < k; i++) {
      if (wings[i] < 1 || wings[i] > 2) throw new FormatError('a split names no new face or more than two');
    }
    let f = 3 * st.m;
    for (let t = 0; t < I; t++) {
      const s = sym[t];
      if (s === 0) continue;
      const u = n + owner[t];
      const vi = v[owner[t]];
      faces[inc[t]] = u;
      if (s === 2 || s === 4) {
        faces[f] = u; faces[f + 1] = vi; faces[f + 2] = a[t]; f += 3;
      }
      if (s === 3 || s === 4) {
        faces[f] = vi; faces[f + 1] = u; faces[f + 2] = b[t]; f += 3;
      }
    }
    st.m += added;
  }

  /** §8.4.3: the D values of each new vertex u = n + i, split by split. */
  #values(rc, n, k) {
    const { values, D } = this.state;
    const { gstart, gidx, sym, a, b, v, sums: S } = this;
    for (let i = 0; i < k; i++) {
      const pv = v[i] * D;
      S.fill(0);
      let c = 0;
      let ell = 0;
      let nx = 0.0;
      let ny = 0.0;
      let nz = 0.0;
      for (let g = gstart[i]; g < gstart[i + 1]; g++) {
        const j = gidx[g];
        const s = sym[j];
        if (s === 0) continue;
        const pa = a[j] * D;
        const pb = b[j] * D;
        for (let q = 0; q < D; q++) S[q] += values[pa + q] + values[pb + q];
        c++;
        ell += Math.abs(values[pa] - values[pb]) + Math.abs(values[pa + 1] - values[pb + 1])
          + Math.abs(values[pa + 2] - values[pb + 2]);
        const e1x = values[pa] - values[pv];
        const e1y = values[pa + 1] - values[pv + 1];
        const e1z = values[pa + 2] - values[pv + 2];
        const e2x = values[pb] - values[pv];
        const e2y = values[pb + 1] - values[pv + 1];
        const e2z = values[pb + 2] - values[pv + 2];
        nx += e1y * e2z - e1z * e2y;
        ny += e1z * e2x - e1x * e2z;
        nz += e1x * e2y - e1y * e2x;
        for (let w = 0; w < 2; w++) {
          if (w === 0 ? s !== 2 && s !== 4 : s !== 3 && s !== 4) continue;
          const po = w === 0 ? pa : pb;
          for (let q = 0; q < D; q++) S[q] += values[pv + q] + values[po + q];
          c++;
          ell += Math.abs(values[pv] - values[po]) + Math.abs(values[pv + 1] - values[po + 1])
            + Math.abs(values[pv + 2] - values[po + 2]);
        }
      }
      this.#vertex(rc, (n + i) * D, pv, c, Math.min(bitLength(Math.floor(ell / c)), GEOMETRY_CLASSES - 1), nx, ny, nz);
    }
  }

  /**
   * One new vertex at values[pu ..]: the frame prediction of §8.4.3 (float64, in the spec's
   * order), the two non-dominant axes, the dominant one against the ring plane, then attributes.
   */
  #vertex(rc, pu, pv, c, cls, nx, ny, nz) {
    const { values, D } = this.state;
    const S = this.sums;
    const two = 2 * c;
    const m0 = S[0] / two;
    const m1 = S[1] / two;
    const m2 = S[2] / two;
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
    const ph = this.frame; // ph[0..3), then the normal at [3..6)
    ph[0] = p0; ph[1] = p1; ph[2] = p2; ph[3] = nx; ph[4] = ny; ph[5] = nz;
    const base = block(B_GEOMETRY + 3 * cls);
    const x0 = this.#put(rc, pu + i0, round(ph[i0]), base);
    const x1 = this.#put(rc, pu + i1, round(ph[i1]), base + INT_BLOCK);
    const pk = nn > 0 ? ph[dom] - ((x0 - ph[i0]) * ph[3 + i0] + (x1 - ph[i1]) * ph[3 + i1]) / ph[3 + dom] : ph[dom];
    this.#put(rc, pu + dom, round(pk), base + 2 * INT_BLOCK);
    for (let q = 3; q < D; q++) {
      this.#put(rc, pu + q, Math.floor(S[q] / two), block(B_ATTRIBUTE + Math.min(q - 3, 7)));
    }
  }

  /** values[at] = pred + SInt(ctx), checked |x| < 2^31; returns it. */
  #put(rc, at, pred, ctx) {
    const x = pred + rc.sint(ctx, 'a residual');
    if (!(x < MAX_VALUE && x > -MAX_VALUE)) throw new FormatError('chunk payload: a decoded value is out of range');
    this.state.values[at] = x;
    return x;
  }
}
