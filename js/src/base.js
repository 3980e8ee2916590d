/**
 * Base meshes (spec/README.md "Base mesh"): read plain accessors or decode Draco, then map the
 * stored floats to grid integers, `rint((p - origin) / step)` in float64 with ties to even.
 */
import { framedDigest } from './chunkframe.js';
import { CorruptChunkError, DracoError, FormatError, PmwError } from './errors.js';
import { SRGB8_TO_LINEAR } from './constants.js';
import { WELD_ATTRIBUTE, readAccessor } from './header.js';

const BASE_DIGEST_LABEL = new TextEncoder().encode('pmwm/base-digest/v1');

/** Round half to even, as numpy's rint (the reference reader's rounding). */
function rint(x) {
  const r = Math.round(x);
  return r - x === 0.5 && r % 2 !== 0 ? r - 1 : r;
}

/**
 * Writes the grid integers of `floats` (count*k, k = grid.origin.length) into column `col0..col0+k`
 * of `values` (count*D row-major).
 */
function quantizeInto(values, D, col0, floats, grid, what) {
  const k = grid.origin.length;
  const count = floats.length / k;
  const limit = 2 ** grid.bits;
  if (grid.transfer === 'srgb8') {
    srgb8Into(values, D, col0, floats, grid, what);
    return;
  }
  for (let i = 0; i < count; i++) {
    for (let c = 0; c < k; c++) {
      const q = rint((floats[i * k + c] - grid.origin[c]) / grid.step[c]);
      if (!Number.isFinite(q)) throw new FormatError(`base mesh: ${what} are not finite`);
      if (q < 0 || q >= limit) throw new FormatError(`base mesh: ${what} lie outside the ${grid.bits}-bit grid`);
      values[i * D + col0 + c] = q;
    }
  }
}

/**
 * quantizeInto for a "srgb8" grid (spec/README.md, attributes: transfer): each stored float32 must be the value
 * the grid writes for a byte b (red, green, blue: SRGB8_TO_LINEAR[b], found by bisection, the table rising; alpha:
 * b / 255 rounded to float32); the integer is b - origin.
 */
function srgb8Into(values, D, col0, floats, grid, what) {
  const k = grid.origin.length;
  const count = floats.length / k;
  const limit = 2 ** grid.bits;
  for (let i = 0; i < count; i++) {
    for (let c = 0; c < k; c++) {
      const v = Math.fround(floats[i * k + c]);
      let b;
      if (c < 3) {
        let lo = 0;
        let hi = 255;
        while (lo < hi) {
          const mid = (lo + hi) >> 1;
          if (SRGB8_TO_LINEAR[mid] < v) lo = mid + 1; else hi = mid;
        }
        b = lo;
        if (SRGB8_TO_LINEAR[b] !== v) b = -1;
      } else {
        b = rint(v * 255);
        if (!(b >= 0 && b <= 255) || Math.fround(b / 255) !== v) b = -1;
      }
      if (b < 0) throw new FormatError(`base mesh: ${what} are not the 8-bit sRGB colours of their grid`);
      const q = b - grid.origin[c];
      if (q < 0 || q >= limit) throw new FormatError(`base mesh: ${what} lie outside the ${grid.bits}-bit grid`);
      values[i * D + col0 + c] = q;
    }
  }
}

let nodeDraco = null;
async function defaultDraco() {
  try {
    nodeDraco ??= (await import('./draco-node.js')).createNodeDracoDecoder();
  } catch (e) {
    throw new DracoError(`no Draco decoder: pass options.draco (draco3d not loadable: ${e.message})`);
  }
  return nodeDraco;
}

/**
 * Decodes primitive `prim`'s base mesh from the BIN payload.
 * @param {Uint8Array} bin BIN payload (at least up to the base's bufferViews)
 * @param {object} prim a primitive plan of planDocument()
 * @param {{decode: Function}|undefined} draco a Draco decoder (see draco-node.js), default draco3d in Node
 * @returns {Promise<{values: Float64Array, faces: Uint32Array, n: number, m: number, D: number}>}
 *   values: (n*D) grid x, y, z then attribute components per vertex; faces: (m*3)
 */
/** The POSITION accessor's min / max, where given, are the exact float32 bounds of the stored positions (spec/README.md, Base mesh). */
function checkBounds(positions, n, bounds) {
  if (!bounds || n === 0) return;
  for (const name of ['min', 'max']) {
    const given = bounds[name];
    if (given === null) continue;
    for (let c = 0; c < 3; c++) {
      let b = positions[c];
      for (let i = c; i < 3 * n; i += 3) b = name === 'min' ? Math.min(b, positions[i]) : Math.max(b, positions[i]);
      if (Math.fround(b) !== Math.fround(given[c])) {
        throw new FormatError(`base mesh: POSITION ${name} [${given}] is not the bound of its values`);
      }
    }
  }
}

export async function decodeBase(bin, prim, draco) {
  const { base, grid } = prim;
  let positions;
  let attributes;
  let indices;
  let ordinals = null; // the weld attribute's values, one per stored vertex
  if (base.draco) {
    const { view, positionId, attributeIds } = base.draco;
    const decoder = draco ?? await defaultDraco();
    let out;
    try {
      const ids = base.draco.weldId == null ? attributeIds : [...attributeIds, base.draco.weldId];
      out = await decoder.decode(bin.subarray(view.offset, view.offset + view.length), { positionId, attributeIds: ids });
    } catch (e) {
      if (e instanceof PmwError) throw e;
      throw new DracoError(`Draco decoding failed (${e?.message ?? e})`, { cause: e }); // a decoder of the caller's
    }
    ({ positions, attributes = [], indices } = out ?? {});
    const asked = attributeIds.length + (base.draco.weldId == null ? 0 : 1);
    if (!positions || !indices || !Array.isArray(attributes) || attributes.length !== asked) {
      throw new DracoError(`the Draco decoder gave no {positions, indices, attributes: [${asked} arrays]}`);
    }
    // a decoder that says what type each attribute's data has (draco-node.js does): the one its accessor names
    base.draco.dataTypes.slice(1).forEach((type, j) => {
      const got = attributes[j]?.dataType;
      if (got !== undefined && got !== type) {
        const name = j < base.grids.length ? base.grids[j].semantic : WELD_ATTRIBUTE;
        throw new FormatError(`base mesh: the Draco ${name} holds data of componentType ${got}, its accessor says ${type}`);
      }
    });
    if (base.draco.weldId != null) {
      const a = attributes[attributes.length - 1];
      ordinals = a?.values ?? a;
      if (!ordinals || (a.components !== undefined && a.components !== 1)) {
        throw new DracoError(`the Draco decoder gave no ${WELD_ATTRIBUTE} of one component`);
      }
      attributes = attributes.slice(0, -1);
    }
    if (positions.length !== 3 * base.draco.vertices || indices.length !== 3 * base.draco.faces) {
      throw new FormatError(`base mesh: Draco decoded ${positions.length / 3} vertices / ${indices.length / 3} faces, `
        + `accessors declare ${base.draco.vertices} / ${base.draco.faces}`);
    }
    attributes = attributes.map((a, j) => {
      const values = a?.values ?? a;
      if (!values) throw new DracoError(`the Draco decoder gave no ${base.grids[j].semantic}`);
      if (a.components !== undefined && a.components !== base.grids[j].origin.length) {
        throw new DracoError(`Draco ${base.grids[j].semantic} has ${a.components} components`);
      }
      return values;
    });
  } else {
    positions = readAccessor(bin, base.plain.position);
    indices = readAccessor(bin, base.plain.indices);
    attributes = base.plain.attributes.map((plan) => readAccessor(bin, plan, true));
    if (base.plain.weld) ordinals = readAccessor(bin, base.plain.weld, true);
  }
  const n = positions.length / 3;
  checkBounds(positions, n, base.bounds);
  const D = 3 + base.grids.reduce((s, g) => s + g.origin.length, 0);
  if (indices.length % 3 !== 0) throw new FormatError('base mesh: index count is not a multiple of 3');
  for (let i = 0; i < indices.length; i++) {
    if (indices[i] >= n) throw new FormatError('base mesh: an index is out of range');
  }
  let values = new Float64Array(n * D);
  quantizeInto(values, D, 0, positions, { ...grid }, 'positions');
  let col = 3;
  base.grids.forEach((g, j) => {
    if (attributes[j].length !== n * g.origin.length) throw new FormatError(`base mesh: ${g.semantic} count differs`);
    quantizeInto(values, D, col, attributes[j], g, `${g.semantic} values`);
    col += g.origin.length;
  });
  let faces = indices instanceof Uint32Array ? indices : Uint32Array.from(indices);
  let count = n;
  if (ordinals !== null && ordinals.length !== n) throw new FormatError(`base mesh: ${WELD_ATTRIBUTE} count differs (${ordinals.length} values, ${n} stored vertices)`);
  if (base.welded != null) {
    ({ values, faces, count } = weld(values, faces, n, D, ordinals));
    if (count !== base.welded) {
      throw new FormatError(`base mesh: welding gives ${count} vertices, baseVertexCount says ${base.welded}`);
    }
  }
  for (let f = 0; f < faces.length; f += 3) {
    const a = faces[f], b = faces[f + 1], c = faces[f + 2];
    if (a === b || b === c || a === c) throw new FormatError('base mesh: a face repeats a vertex');
  }
  if (prim.ext?.baseDigest !== undefined) checkBaseDigest(values, faces, count, D, prim);
  return { values, faces, n: count, m: faces.length / 3, D };
}

/**
 * Columns `col0 .. col0+k` of the first `rows` rows of `values` (rows*D, row-major) as little-endian
 * int64 bytes. Grid integers and face indices are in [0, 2^32), so each is its low word and a zero word.
 */
function int64Bytes(values, rows, D, col0, k) {
  const out = new DataView(new ArrayBuffer(rows * k * 8));
  for (let i = 0; i < rows; i++) {
    for (let c = 0; c < k; c++) out.setUint32((i * k + c) * 8, values[i * D + col0 + c], true);
  }
  return new Uint8Array(out.buffer);
}

/**
 * The `baseDigest` of a decoded base (spec/bitstream.md §6.4), 16 lowercase hex digits: `values` (n*D,
 * grid x, y, z then the attribute components of each vertex), `faces` (m*3). Needs initChunkFrames().
 */
export function baseDigest(values, faces, n, D) {
  const m = faces.length / 3;
  const a = D - 3;
  const counts = new DataView(new ArrayBuffer(24));
  [n, m, a].forEach((x, i) => counts.setUint32(8 * i, x, true));
  const fields = [BASE_DIGEST_LABEL, new Uint8Array(counts.buffer), int64Bytes(values, n, D, 0, 3),
    int64Bytes(faces, m, 3, 0, 3), int64Bytes(values, n, D, 3, a)];
  return framedDigest(fields).slice(0, 16);
}

/**
 * CorruptChunkError (chunk null: the base mesh) unless the decoded base gives the extension's
 * `baseDigest` (spec/bitstream.md §6.4): the first 16 hex digits of BLAKE2b-128 over the framed
 * label, counts, positions, faces and attributes, each as little-endian int64.
 */
function checkBaseDigest(values, faces, n, D, prim) {
  if (baseDigest(values, faces, n, D) !== prim.ext.baseDigest) {
    const which = prim.several ? ` of progressive primitive ${prim.index + 1}` : '';
    throw new CorruptChunkError(`base mesh${which}: baseDigest mismatch, the base mesh decodes to other geometry than was written (corrupt)`, null);
  }
}

/**
 * Welds a stored base's copies (spec/README.md "Welded base"): vertices with equal grid positions
 * (and equal values of the weld attribute, `ordinals`, when the base has it) are one vertex, the first
 * of them in stored order; kept vertices are numbered in stored order and every face corner names its
 * kept vertex. Copies MUST carry equal attribute values (FormatError otherwise). `values` (n*D), `faces` (m*3) on n vertices, `ordinals` (n) or null; returns new arrays
 * and the kept count.
 */
function weld(values, faces, n, D, ordinals) {
  const first = new Map();
  const number = new Uint32Array(n);
  const kept = [];
  for (let i = 0; i < n; i++) {
    const key = `${values[i * D]},${values[i * D + 1]},${values[i * D + 2]},${ordinals ? ordinals[i] : 0}`;
    const j = first.get(key);
    if (j === undefined) {
      first.set(key, kept.length);
      number[i] = kept.length;
      kept.push(i);
    } else {
      number[i] = j;
      for (let c = 3; c < D; c++) {
        if (values[i * D + c] !== values[kept[j] * D + c]) {
          throw new FormatError('base mesh: copies the weld joins carry different attribute values (spec README, Welded base)');
        }
      }
    }
  }
  const out = new Float64Array(kept.length * D);
  kept.forEach((i, k) => out.set(values.subarray(i * D, i * D + D), k * D));
  return { values: out, faces: faces.map((x) => number[x]), count: kept.length };
}
