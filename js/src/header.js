/**
 * GLB preamble and JSON chunk of a .pmw file (spec/bitstream.md §1-4, spec/README.md):
 * the document, its progressive primitives and the byte range of every base mesh and chunk.
 * Everything here is checked before any BIN byte is read or any array is allocated.
 */
import { FormatError, LimitError, UnsupportedError } from './errors.js';
import { unpackChunkTable } from './chunktable.js';
import {
  DRACO_EXTENSION, EXTENSION, FORMAT_VERSION, MAX_ATTRIBUTES, MAX_CHUNK_BYTES, MAX_CHUNKS,
  MAX_DECOMPRESSED_CHUNK_BYTES, MAX_FACES, MAX_JSON_BYTES, MAX_JSON_DEPTH, MAX_VERTICES, PAYLOAD_CODEC, PAYLOAD_VERSIONS,
} from './constants.js';

const GLB_MAGIC = 0x46546c67; // 'glTF'
const JSON_TYPE = 0x4e4f534a;
const BIN_TYPE = 0x004e4942;
const MIN_GRID_BITS = 8;
const MAX_GRID_BITS = 30;
const COMPONENTS = { SCALAR: 1, VEC2: 2, VEC3: 3, VEC4: 4 };
const INDEX_TYPES = { 5123: 2, 5125: 4 };
const FLOAT = 5126;

const isInt = (x, lo, hi) => Number.isSafeInteger(x) && x >= lo && x <= hi;
const isNum = (x) => typeof x === 'number' && Number.isFinite(x);
const isObj = (x) => x !== null && typeof x === 'object' && !Array.isArray(x);
/** A member's value, or `absent` when the member is missing: a JSON null is a value (never a valid one here), not absence. */
const given = (x, absent) => (x === undefined ? absent : x);
/** A JSON Schema integer >= lo of any size (1e300 is one), as the schema check of the reference reader has it. */
const isWhole = (lo) => (x) => Number.isInteger(x) && x >= lo;
/**
 * A count or size member, returned: a FormatError unless it is an integer >= lo (null, true, -1 and 1.5
 * are no count), a LimitError over `max` (spec/README.md "Kinds of refusal"), as the reference reader has it.
 */
function checkCount(x, lo, max, what) {
  if (!Number.isInteger(x) || x < lo) throw new FormatError(`${what} is not an integer >= ${lo}`);
  if (x > max) throw new LimitError(`${what} ${x} is over the limit ${max}`);
  return x;
}
/** A string of whole `digits`-digit groups of lowercase hex (exactly one group when `one`). */
const isHex = (digits, one = true) => (x) => typeof x === 'string' && (one ? x.length === digits : x.length % digits === 0)
  && /^[0-9a-f]*$/.test(x);

/**
 * Fields of the extension's objects this decoder does not otherwise read, by object: [test, what the
 * value must be, required], as spec/schema has them. Their form is checked by every reader (a MAC's
 * value only by a verifier holding the key), so both readers refuse the same files.
 */
const SCHEMA_FIELDS = {
  extension: {
    baseMac: [isHex(32), '32 lowercase hex digits'], sceneMac: [isHex(32), '32 lowercase hex digits'], baseDigest: [isHex(16), '16 lowercase hex digits'], fileId: [(x) => typeof x === 'string', 'a string'],
    watermark: [isObj, 'an object'], ownerFrame: [isObj, 'an object'], extensions: [isObj, 'an object'],
  },
  grid: { extensions: [isObj, 'an object'] },
  ownerFrame: {
    center: [(x) => Array.isArray(x) && x.length === 3 && x.every(isNum), 'an array of 3 numbers', true],
    inner: [isNum, 'a number', true], width: [(x) => isNum(x) && x > 0, 'a number > 0', true],
  },
  chunk: { mac: [isHex(32), '32 lowercase hex digits'], batches: [isWhole(1), 'an integer >= 1'], extensions: [isObj, 'an object'] },
  chunkTable: {
    digests: [isHex(16, false), 'groups of 16 lowercase hex digits'], macs: [isHex(32, false), 'groups of 32 lowercase hex digits'],
    extensions: [isObj, 'an object'],
  },
  watermark: {
    mode: [(x) => x === 'exact' || x === 'paper', '"exact" or "paper"', true], bits: [(x) => isInt(x, 1, 16), 'an integer in 1..16', true],
    scale: [(x) => isNum(x) && x > 0, 'a number > 0', true], width: [isWhole(1), 'an integer >= 1', true],
    height: [isWhole(1), 'an integer >= 1', true], levels: [isWhole(0), 'an integer >= 0', true],
    codes: [isWhole(0), 'an integer >= 0', true], carriers: [isWhole(0), 'an integer >= 0', true], // over MAX_VERTICES: checkExtension
    embedFrom: [isWhole(0), 'an integer >= 0'], binding: [(x) => x === 'ring-v2', '"ring-v2"'],
    keyFingerprint: [(x) => typeof x === 'string', 'a string'], layout: [isObj, 'an object'], extensions: [isObj, 'an object'],
  },
};

/** FormatError unless object `obj` has the fields SCHEMA_FIELDS[kind] asks for. */
function checkFields(obj, kind, what) {
  for (const [key, [ok, must, required]] of Object.entries(SCHEMA_FIELDS[kind])) {
    if (key in obj ? !ok(obj[key]) : required) throw new FormatError(`${what}: ${key} must be ${must}`);
  }
}

/**
 * Whether JSON text `bytes` nests more than `limit` arrays and objects deep (the outermost value is
 * level 1), found by one scan of the bytes before they are parsed (spec/README.md, Conformance): a `"`
 * after an even run of backslashes (none included) begins or ends a string; outside a string `[` / `{`
 * open a level and `]` / `}` close one. The reference reader's `check_json_text_depth`
 * (pmwm_codec/format/gltf.py) scans the same way, so both refuse the same bytes; JSON.parse's reviver
 * then never recurses deeper than the limit.
 */
export function jsonTooDeep(bytes, limit = MAX_JSON_DEPTH) {
  let depth = 0;
  let inString = false;
  let odd = false; // after an odd run of backslashes
  for (let i = 0; i < bytes.length; i++) {
    const b = bytes[i];
    if (b === 0x5c) { odd = !odd; continue; }
    if (b === 0x22) {
      if (!odd) inString = !inString;
    } else if (!inString) {
      if (b === 0x5b || b === 0x7b) {
        if (++depth > limit) return true;
      } else if (b === 0x5d || b === 0x7d) depth--;
    }
    odd = false;
  }
  return false;
}

/**
 * The checks of parseGlb that a parsed JSON value still shows, for a caller that has no JSON bytes (the
 * glTF-Transform extension: its reader parses the text itself): a number that is not finite (1e999 parses
 * to Infinity) is a FormatError, nesting deeper than MAX_JSON_DEPTH a LimitError. Walked without recursion.
 */
export function checkJsonTree(value, what = 'JSON chunk') {
  const stack = [[value, 1]];
  while (stack.length) {
    const [v, depth] = stack.pop();
    if (typeof v === 'number' && !Number.isFinite(v)) throw new FormatError(`${what}: holds a number that is not finite`);
    if (v === null || typeof v !== 'object') continue;
    if (depth > MAX_JSON_DEPTH) throw new LimitError(`${what}: JSON nested more than ${MAX_JSON_DEPTH} levels deep (MAX_JSON_DEPTH)`);
    for (const child of Array.isArray(v) ? v : Object.values(v)) stack.push([child, depth + 1]);
  }
}

/** Bytes needed before the JSON can be parsed: 20 (preamble), then 20 + J + 8 (BIN header). */
export function preambleLength(bytes) {
  if (bytes.length < 20) return 20;
  return 28 + new DataView(bytes.buffer, bytes.byteOffset, 20).getUint32(12, true);
}

/**
 * Parse the preamble and JSON of a GLB prefix holding at least preambleLength(bytes) bytes.
 * @returns {{length:number, binStart:number, binLength:number, gltf:object}} binStart: file offset of BIN byte 0
 */
/** JSON.parse reviver: a number that overflows a double (1e999) is a format error (spec README). */
function finiteNumbers(key, value) {
  if (typeof value === 'number' && !Number.isFinite(value)) {
    throw new FormatError(`JSON chunk: member ${JSON.stringify(key)} holds a number that is not finite`);
  }
  return value;
}

/**
 * Check the 20-byte preamble (GLB header and JSON chunk header) of a prefix holding at least 20 bytes,
 * as soon as it is in: a streaming reader refuses a JSON chunk over the limit before buffering it.
 * @returns {{length:number, jsonLength:number}}
 */
export function checkPreamble(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  if (dv.getUint32(0, true) !== GLB_MAGIC) throw new FormatError('not a GLB file (bad magic)');
  if (dv.getUint32(4, true) !== 2) throw new UnsupportedError(`GLB version ${dv.getUint32(4, true)}, expected 2`);
  const length = dv.getUint32(8, true);
  const jsonLength = dv.getUint32(12, true);
  if (dv.getUint32(16, true) !== JSON_TYPE) throw new FormatError('first GLB chunk is not JSON');
  if (jsonLength % 4 !== 0) throw new FormatError('JSON chunk length is not a multiple of 4');
  if (jsonLength > MAX_JSON_BYTES) throw new LimitError(`JSON chunk of ${jsonLength} bytes is over the limit`);
  if (28 + jsonLength > length) throw new FormatError('GLB length leaves no room for the BIN chunk');
  return { length, jsonLength };
}

/**
 * The bytes of a GLB before its BIN chunk's data: the 12-byte header, the JSON chunk (`json`: its bytes, padding
 * included) and the BIN chunk's 8-byte header, for a BIN chunk of `binLength` bytes ending the file.
 */
export function glbHead(json, binLength, version = 2) {
  const head = new Uint8Array(28 + json.length);
  const dv = new DataView(head.buffer);
  dv.setUint32(0, GLB_MAGIC, true);
  dv.setUint32(4, version, true);
  dv.setUint32(8, head.length + binLength, true);
  dv.setUint32(12, json.length, true);
  dv.setUint32(16, JSON_TYPE, true);
  head.set(json, 20);
  dv.setUint32(20 + json.length, binLength, true);
  dv.setUint32(24 + json.length, BIN_TYPE, true);
  return head;
}

export function parseGlb(bytes) {
  const dv = new DataView(bytes.buffer, bytes.byteOffset, bytes.byteLength);
  const { length, jsonLength } = checkPreamble(bytes);
  const binLength = dv.getUint32(20 + jsonLength, true);
  if (dv.getUint32(24 + jsonLength, true) !== BIN_TYPE) throw new FormatError('second GLB chunk is not BIN');
  if (binLength % 4 !== 0 || 28 + jsonLength + binLength !== length) {
    throw new FormatError('BIN chunk does not end at the GLB length');
  }
  let gltf;
  try {
    // ignoreBOM keeps a byte order mark in the text, where JSON.parse refuses it (spec README, Conformance)
    const json = bytes.subarray(20, 20 + jsonLength);
    const text = new TextDecoder('utf-8', { fatal: true, ignoreBOM: true }).decode(json);
    if (jsonTooDeep(json)) throw new LimitError(`JSON chunk: JSON nested more than ${MAX_JSON_DEPTH} levels deep (MAX_JSON_DEPTH)`);
    gltf = JSON.parse(text, finiteNumbers);
  } catch (e) {
    if (e instanceof FormatError) throw e;
    throw new FormatError(`JSON chunk is not valid UTF-8 JSON (${e.message})`);
  }
  if (!isObj(gltf)) throw new FormatError('JSON chunk is not an object');
  return { length, binStart: 28 + jsonLength, binLength, gltf };
}

function checkGrid(grid, what, components) {
  if (!isObj(grid) || !isInt(grid.bits, MIN_GRID_BITS, MAX_GRID_BITS)) {
    throw new FormatError(`${what}: bits must be an integer in [${MIN_GRID_BITS}, ${MAX_GRID_BITS}]`);
  }
  const origin = grid.origin;
  const step = components === 3 ? [grid.step, grid.step, grid.step] : grid.step;
  if (!Array.isArray(origin) || !origin.every(isNum) || (components === 3 && origin.length !== 3)
      || origin.length < 1 || origin.length > 4) {
    throw new FormatError(`${what}: origin must be finite numbers`);
  }
  if (!Array.isArray(step) || step.length !== origin.length || !step.every((s) => isNum(s) && s > 0)) {
    throw new FormatError(`${what}: step must be positive finite numbers`);
  }
  return { bits: grid.bits, origin: origin.slice(), step: step.slice() };
}

/**
 * An attribute's `transfer` (spec/README.md, attributes): absent, or "srgb8" on a COLOR_n of 3 or 4
 * components with whole-number origins in 0..255 and steps of 1 (each component a byte: red, green and blue
 * sRGB-encoded, written as SRGB8_TO_LINEAR[byte]; alpha written as byte / 255).
 */
function checkTransfer(a, what) {
  if (a.transfer === undefined) return {};
  const where = `${what}: ${a.semantic} grid`;
  if (a.transfer !== 'srgb8') throw new FormatError(`${where}: transfer must be 'srgb8'`);
  if (!a.semantic.startsWith('COLOR_') || ![3, 4].includes(a.origin.length)) {
    throw new FormatError(`${where}: transfer 'srgb8' is for a COLOR_n of 3 or 4 components`);
  }
  if (!a.step.every((x) => x === 1) || !a.origin.every((x) => Number.isInteger(x) && x >= 0 && x <= 255)) {
    throw new FormatError(`${where}: transfer 'srgb8' needs whole-number origins in 0..255 and steps of 1`);
  }
  return { transfer: 'srgb8' };
}

/**
 * An attribute's `prediction` (spec/README.md, attributes): absent (the ring mean), or "plane" (payload version 2
 * only, spec/bitstream.md §8.4.3; checked against the payload version in checkExtension).
 */
function checkPrediction(a, what) {
  if (a.prediction === undefined) return {};
  if (a.prediction !== 'plane') throw new FormatError(`${what}: ${a.semantic} prediction must be 'plane'`);
  return { prediction: 'plane' };
}

/** A bufferView of buffer 0 by index, with its range checked against the buffer. */
function bufferView(gltf, index, bufferLength, what) {
  const views = Array.isArray(gltf.bufferViews) ? gltf.bufferViews : [];
  const view = isInt(index, 0, views.length - 1) ? views[index] : undefined;
  if (!isObj(view)) throw new FormatError(`${what}: bufferView ${index} does not exist`);
  const offset = given(view.byteOffset, 0);
  if (given(view.buffer, 0) !== 0 || !isInt(offset, 0, bufferLength) || !isInt(view.byteLength, 0, bufferLength - offset)) {
    throw new FormatError(`${what}: bufferView ${index} lies outside buffer 0`);
  }
  if (view.byteStride !== undefined && !(isInt(view.byteStride, 4, 252) && view.byteStride % 4 === 0)) {
    throw new FormatError(`${what}: bufferView ${index} has an invalid byteStride`);
  }
  return { index, offset, length: view.byteLength, stride: view.byteStride };
}

/**
 * A base accessor by index, its type and count checked (a Draco base's accessors too: they declare
 * the counts the Draco data must decode to, KHR_draco_mesh_compression).
 */
function baseAccessor(gltf, index, what, { types, components, max }) {
  const accessors = Array.isArray(gltf.accessors) ? gltf.accessors : [];
  const acc = isInt(index, 0, accessors.length - 1) ? accessors[index] : undefined;
  if (!isObj(acc)) throw new FormatError(`${what}: accessor ${index} does not exist`);
  // spec/README.md, Base mesh: a viewer applies a sparse substitution, the readers decode the stored values
  if (acc.sparse !== undefined) throw new FormatError(`${what}: accessor ${index} is sparse; a base accessor holds its values as stored`);
  // an integer: `types` is an object, whose key "5123" a string or a one-element array [5123] would also find
  const size = Number.isInteger(acc.componentType) ? types[acc.componentType] : undefined;
  const k = typeof acc.type === 'string' && Object.hasOwn(COMPONENTS, acc.type) ? COMPONENTS[acc.type] : undefined; // not ["VEC3"]
  if (!size || k !== components) throw new FormatError(`${what}: accessor ${index} has the wrong type`);
  checkCount(acc.count, 0, max, `${what}: accessor ${index}'s count`);
  return { acc, size, k };
}

/** An accessor read plan {view, offset, stride, count, components, componentType}, every byte in range. */
function accessorPlan(gltf, index, bufferLength, what, { types, components, max }) {
  const { acc, size, k } = baseAccessor(gltf, index, what, { types, components, max });
  const view = bufferView(gltf, acc.bufferView, bufferLength, what);
  const offset = given(acc.byteOffset, 0);
  const stride = view.stride ?? size * k;
  // glTF: a vertex attribute's stride is at least its element; indices are tightly packed
  if (stride < size * k || (types === INDEX_TYPES && stride !== size * k)) {
    throw new FormatError(`${what}: accessor ${index}'s bufferView has byteStride ${stride} for ${size * k}-byte elements`);
  }
  if (!isInt(offset, 0, view.length) || offset % size !== 0 || stride % size !== 0
      || (acc.count > 0 && offset + stride * (acc.count - 1) + size * k > view.length)) {
    throw new FormatError(`${what}: accessor ${index} does not fit its bufferView`);
  }
  return { view, offset, stride, count: acc.count, components: k, componentType: acc.componentType };
}

/** Hex digits of a chunk digest per payload version (spec/bitstream.md §6.2): BLAKE2b-128, its first 64 bits. */
const DIGEST_HEX = { 1: 32, 2: 16 };
const TABLE_ARRAYS = [['byteLengths', 'byteLength'], ['vertexCounts', 'vertexCount'], ['faceCounts', 'faceCount'],
  ['geometricErrors', 'geometricError']];

/**
 * The per-chunk index entries of an extension object: its `chunks` array (payload version 1), or its
 * chunk table (version 2, spec/bitstream.md §6.2: packed, or JSON arrays) expanded to entries with `bufferView`,
 * `byteOffset` (inside it), `byteLength`, `digest`, counts, `geometricError`, `mac` (when the table
 * has MACs) and the derived `splits`, `uncompressedLength` (= byteLength) and `faces` (true for a
 * face chunk: chunk k >= the extension's `firstFaceChunk`, spec/bitstream.md §8.6). FormatError when
 * `firstFaceChunk` is present and not an integer in 0..MAX_CHUNKS, or present with payload version 1
 * (beyond the chunk count it is valid: a cut file may keep no face chunk).
 * @param {object} ext @param {number} version payload version @param {number} baseVertices the base's vertex count
 */
export function chunkEntries(ext, version, baseVertices, what = 'chunks') {
  const table = ext.chunks;
  const firstFace = ext.firstFaceChunk; // absent: no face chunk (null is no integer: the schema)
  if (firstFace !== undefined && !isInt(firstFace, 0, MAX_CHUNKS)) {
    throw new FormatError(`${what}: firstFaceChunk is not an integer in 0..${MAX_CHUNKS}`);
  }
  if (version !== 2) {
    if (firstFace !== undefined) throw new FormatError(`${what}: firstFaceChunk needs chunk payload version 2`);
    if (!Array.isArray(table)) throw new FormatError(`${what}: chunks is not an array`);
    return table;
  }
  if (!isObj(table)) throw new FormatError(`${what}: chunks is not a chunk table`);
  checkFields(table, 'chunkTable', `${what}: chunks`);
  const columns = 'packed' in table || 'count' in table ? packedColumns(table, what) : arrayColumns(table, what);
  const count = columns.byteLength.length;
  let sum = 0;
  const offsets = given(table.byteOffsets, columns.byteLength.map((n) => { const at = sum; sum += n; return at; }));
  if (!Array.isArray(offsets) || offsets.length !== count) {
    throw new FormatError(`${what}: the chunk table's arrays do not all describe ${count} chunks`);
  }
  let previous = baseVertices;
  return columns.byteLength.map((_, k) => {
    const entry = { bufferView: table.bufferView, byteOffset: offsets[k], digest: columns.digest[k] };
    for (const [, field] of TABLE_ARRAYS) entry[field] = columns[field][k];
    if (columns.mac) entry.mac = columns.mac[k];
    entry.splits = entry.vertexCount - previous;
    previous = entry.vertexCount;
    entry.uncompressedLength = entry.byteLength;
    entry.faces = firstFace !== undefined && k >= firstFace;
    return entry;
  });
}

/** The packed form's values by entry field (src/chunktable.js); never mixed with the array form. */
function packedColumns(table, what) {
  if (TABLE_ARRAYS.some(([name]) => name in table) || 'digests' in table || 'macs' in table) {
    throw new FormatError(`${what}: a chunk table is packed or in arrays, not both`);
  }
  return unpackChunkTable(table.count, table.packed, what);
}

/** The array form's values by entry field, every array checked to describe the same number of chunks. */
function arrayColumns(table, what) {
  if (!Array.isArray(table.byteLengths)) throw new FormatError(`${what}: chunks is not a chunk table`);
  const count = table.byteLengths.length;
  if (count > MAX_CHUNKS) throw new LimitError(`${what}: more than ${MAX_CHUNKS} chunks`);
  const macs = table.macs;
  if (!TABLE_ARRAYS.every(([name]) => Array.isArray(table[name]) && table[name].length === count)
      || typeof table.digests !== 'string' || table.digests.length !== count * 16
      || (macs !== undefined && (typeof macs !== 'string' || macs.length !== count * 32))) {
    throw new FormatError(`${what}: the chunk table's arrays do not all describe ${count} chunks`);
  }
  const columns = Object.fromEntries(TABLE_ARRAYS.map(([name, field]) => [field, table[name]]));
  columns.digest = table.byteLengths.map((_, k) => table.digests.slice(16 * k, 16 * k + 16));
  if (macs !== undefined) columns.mac = table.byteLengths.map((_, k) => macs.slice(32 * k, 32 * k + 32));
  return columns;
}

function checkChunk(gltf, c, j, bufferLength, what, version = 1) {
  if (!isObj(c)) throw new FormatError(`${what} chunks[${j}]: not an object`);
  checkFields(c, 'chunk', `${what} chunks[${j}]`);
  // the schema's minimums: a chunk holds a byte, and a mesh after it a vertex
  checkCount(c.byteLength, 1, MAX_CHUNK_BYTES, `${what} chunks[${j}]: byteLength`);
  checkCount(c.uncompressedLength, 0, MAX_DECOMPRESSED_CHUNK_BYTES, `${what} chunks[${j}]: uncompressedLength`);
  checkCount(c.splits, 0, MAX_VERTICES, `${what} chunks[${j}]: splits`);
  checkCount(c.vertexCount, 1, MAX_VERTICES, `${what} chunks[${j}]: vertexCount`);
  checkCount(c.faceCount, 0, MAX_FACES, `${what} chunks[${j}]: faceCount`);
  if (typeof c.geometricError !== 'number' || !(c.geometricError >= 0)) { // required by the chunk schema
    throw new FormatError(`${what} chunks[${j}]: geometricError is not a number >= 0`);
  }
  const hex = DIGEST_HEX[version];
  if (typeof c.digest !== 'string' || c.digest.length !== hex || !/^[0-9a-f]*$/.test(c.digest)) {
    throw new FormatError(`${what} chunks[${j}]: digest is not ${hex} lowercase hex digits`);
  }
  const view = bufferView(gltf, c.bufferView, bufferLength, `${what} chunks[${j}]`);
  let offset = view.offset;
  if (version === 2) {
    if (!isInt(c.byteOffset, 0, view.length) || c.byteOffset + c.byteLength > view.length) {
      throw new FormatError(`${what} chunks[${j}]: lies past the end of its bufferView`);
    }
    offset += c.byteOffset;
  } else if (view.length !== c.byteLength) throw new FormatError(`${what} chunks[${j}]: byteLength differs from its bufferView`);
  return {
    view, offset, length: c.byteLength, digest: c.digest, uncompressedLength: c.uncompressedLength,
    splits: c.splits, vertexCount: c.vertexCount, faceCount: c.faceCount, geometricError: c.geometricError,
    faces: version === 2 && c.faces === true, // a face chunk (spec/bitstream.md §8.6)
  };
}

/**
 * The vertex count of a base primitive as its chunks see it: its POSITION accessor's count (Draco
 * bases too), or, for a welded base (spec/README.md "Welded base"), the extension's baseVertexCount.
 */
export function baseVertexCount(gltf, prim, ext, what) {
  const index = isObj(prim.attributes) ? prim.attributes.POSITION : undefined;
  const acc = Array.isArray(gltf.accessors) && isInt(index, 0, gltf.accessors.length - 1) ? gltf.accessors[index] : undefined;
  if (!isObj(acc)) throw new FormatError('base mesh: no POSITION accessor');
  checkCount(acc.count, 0, MAX_VERTICES, 'base mesh: POSITION accessor count');
  if (ext.baseVertexCount === undefined) return acc.count;
  if (!isInt(ext.baseVertexCount, 1, acc.count)) {
    throw new FormatError(`${what}: baseVertexCount is not an integer in 1..${acc.count} (the stored vertices)`);
  }
  return ext.baseVertexCount;
}

/** The base accessors' kinds: their component types and counts, and the limit of their element count. */
const POSITION = { types: { [FLOAT]: 4 }, components: 3, max: MAX_VERTICES };
/** The base attribute that tells a welded base's distinct vertices on one grid point apart (spec/README.md "Welded base"). */
export const WELD_ATTRIBUTE = '_PMWM_WELD';
const WELD = { types: { 5121: 1, 5123: 2 }, components: 1, max: MAX_VERTICES };
const INDICES = { types: INDEX_TYPES, components: 1, max: 3 * MAX_FACES };

/** DataView getter and element size of each componentType an accessor read here may have. */
const READERS = { 5120: ['getInt8', 1], 5121: ['getUint8', 1], 5122: ['getInt16', 2], 5123: ['getUint16', 2],
  5125: ['getUint32', 4], [FLOAT]: ['getFloat32', 4] };

/** Element size of an integer componentType a plain base may store a progressive attribute with: the one its
 * `componentType` names (UNSIGNED_INT, 5125, is stored as FLOAT; spec/README.md, attributes), else undefined. */
const storedIntegerSize = (type) => (Number.isInteger(type) && type !== 5125 && type !== FLOAT
  ? READERS[type]?.[1] : undefined);

/** The componentTypes (with their sizes) a base may store the progressive attribute `a` with: FLOAT, or the integer
 * componentType the attribute names (spec/README.md, attributes: JOINTS_n). */
function attributeTypesOf(a) {
  const named = storedIntegerSize(a.componentType);
  return named ? { [FLOAT]: 4, [a.componentType]: named } : { [FLOAT]: 4 };
}

/** A base attribute's accessor must not be normalized (an integer attribute's values are the integers themselves;
 * glTF allows no normalized FLOAT), as the reference reader requires. */
function checkAttributeNormalized(acc, where) {
  if (acc.normalized === true) throw new FormatError(`${where}: a base attribute must not be normalized`);
}

/** The base mesh plan of one primitive: Draco bufferView or plain accessors, and its attribute grids. */
function basePlan(gltf, prim, ext, bufferLength, what) {
  const attributes = given(ext.attributes, []);
  if (!Array.isArray(attributes)) throw new FormatError(`${what}: attributes is not an array`);
  if (attributes.length > MAX_ATTRIBUTES) throw new FormatError(`${what}: more than ${MAX_ATTRIBUTES} attributes (the schema's maxItems)`);
  const grids = attributes.map((a, i) => {
    if (!isObj(a) || typeof a.semantic !== 'string' || a.semantic === 'POSITION') {
      throw new FormatError(`${what}: attribute ${i} has no valid semantic`);
    }
    return { semantic: a.semantic, ...checkGrid(a, `${what}: ${a.semantic} grid`, 0), ...checkTransfer(a, what),
      ...checkPrediction(a, what) };
  });
  if (!isObj(prim.attributes)) throw new FormatError(`${what}: primitive has no attributes`);
  if (given(prim.mode, 4) !== 4) throw new FormatError(`${what}: primitive mode is not TRIANGLES`);
  const draco = isObj(prim.extensions) ? prim.extensions[DRACO_EXTENSION] : undefined;
  // the weld attribute: only on a welded base, one value per stored vertex
  const welds = prim.attributes[WELD_ATTRIBUTE] !== undefined;
  if (welds && ext.baseVertexCount === undefined) {
    throw new FormatError(`${what}: ${WELD_ATTRIBUTE} without baseVertexCount (it serves the weld only)`);
  }
  const weldWhat = `${what} ${WELD_ATTRIBUTE}`;
  const checkWeldCount = (count, vertices) => {
    if (count !== vertices) throw new FormatError(`${weldWhat}: ${count} values for ${vertices} stored vertices`);
    if (gltf.accessors[prim.attributes[WELD_ATTRIBUTE]].normalized === true) throw new FormatError(`${weldWhat}: normalized`);
  };
  if (draco !== undefined) {
    if (!isObj(draco) || !isObj(draco.attributes)) throw new FormatError(`${what}: invalid ${DRACO_EXTENSION}`);
    const ids = ['POSITION', ...grids.map((g) => g.semantic), ...(welds ? [WELD_ATTRIBUTE] : [])].map((s) => draco.attributes[s]);
    if (!ids.every((id) => isInt(id, 0, 0xffff))) throw new FormatError(`${what}: Draco attribute ids missing`);
    const view = bufferView(gltf, draco.bufferView, bufferLength, what);
    const vertices = baseAccessor(gltf, prim.attributes.POSITION, `${what} POSITION`, POSITION).acc.count;
    const corners = baseAccessor(gltf, prim.indices, `${what} indices`, INDICES).acc.count;
    if (corners % 3 !== 0) throw new FormatError(`${what}: index count ${corners} is not a multiple of 3`);
    if (welds) checkWeldCount(baseAccessor(gltf, prim.attributes[WELD_ATTRIBUTE], weldWhat, WELD).acc.count, vertices);
    const attributeTypes = grids.map((g, i) => { // the accessors of the Draco attributes, as a plain base's
      const where = `${what} ${g.semantic}`;
      const { acc } = baseAccessor(gltf, prim.attributes[g.semantic], where,
        { types: attributeTypesOf(attributes[i]), components: g.origin.length, max: MAX_VERTICES });
      checkAttributeNormalized(acc, where);
      if (acc.count !== vertices) throw new FormatError(`${where}: ${acc.count} values for ${vertices} stored vertices`);
      return acc.componentType;
    });
    const weldType = welds ? gltf.accessors[prim.attributes[WELD_ATTRIBUTE]].componentType : null;
    const attributeIds = ids.slice(1, 1 + grids.length);
    // the data type each Draco attribute must have: the one its accessor names (spec/README.md "Base mesh")
    const dataTypes = [FLOAT, ...attributeTypes, ...(welds ? [weldType] : [])];
    return { draco: { view, positionId: ids[0], attributeIds, weldId: welds ? ids[ids.length - 1] : null, vertices,
      faces: corners / 3, dataTypes }, grids, views: [view], bounds: positionBounds(gltf, prim, what) };
  }
  const position = accessorPlan(gltf, prim.attributes.POSITION, bufferLength, `${what} POSITION`, POSITION);
  const indices = accessorPlan(gltf, prim.indices, bufferLength, `${what} indices`, INDICES);
  const weld = welds ? accessorPlan(gltf, prim.attributes[WELD_ATTRIBUTE], bufferLength, weldWhat, WELD) : null;
  if (weld) checkWeldCount(weld.count, position.count);
  const attrs = grids.map((g, i) => {
    const where = `${what} ${g.semantic}`;
    const plan = accessorPlan(gltf, prim.attributes[g.semantic], bufferLength, where,
      { types: attributeTypesOf(attributes[i]), components: g.origin.length, max: MAX_VERTICES });
    checkAttributeNormalized(gltf.accessors[prim.attributes[g.semantic]], where);
    return plan;
  });
  const views = [position, indices, ...attrs, ...(weld ? [weld] : [])].map((a) => a.view);
  return { plain: { position, indices, attributes: attrs, weld }, grids, views, bounds: positionBounds(gltf, prim, what) };
}

/**
 * The POSITION accessor's {min, max} (null members when absent), each three numbers (spec/README.md, Base mesh:
 * decodeBase checks them against the stored positions; three.js culls by them, and no MAC covers them).
 */
function positionBounds(gltf, prim, what) {
  const acc = gltf.accessors[prim.attributes.POSITION];
  const out = {};
  for (const name of ['min', 'max']) {
    const v = acc[name];
    if (v !== undefined && !(Array.isArray(v) && v.length === 3 && v.every((x) => typeof x === 'number'))) {
      throw new FormatError(`${what}: POSITION ${name} is not three numbers`);
    }
    out[name] = v ?? null;
  }
  return out;
}

/** Checks a primitive's extension object; returns its chunk payload version (1 or 2). */
function checkExtension(ext, what) {
  if (!isObj(ext)) throw new FormatError(`${what}: extension is not an object`);
  if (!Number.isInteger(ext.version)) throw new FormatError(`${what}: version is not an integer`);
  // any integer above this reader's: 2^60 too (above 2^53 a JSON integer reads inexactly, but it is still newer)
  if (ext.version > FORMAT_VERSION) throw new UnsupportedError(`${what}: version ${ext.version} is newer than ${FORMAT_VERSION}`);
  if (ext.version < 1) throw new FormatError(`${what}: version ${ext.version}`);
  checkFields(ext, 'extension', what);
  if (ext.watermark !== undefined) {
    checkFields(ext.watermark, 'watermark', `${what}: watermark`);
    // a cut keeps the carriers of the whole stream (spec/README.md "Cutting a file"): bounded by the limit only
    if (ext.watermark.carriers > MAX_VERTICES) {
      throw new LimitError(`${what}: watermark: carriers ${ext.watermark.carriers} is over the limit ${MAX_VERTICES}`);
    }
  }
  if (isObj(ext.grid)) checkFields(ext.grid, 'grid', `${what}: grid`);
  if (ext.ownerFrame !== undefined) checkFields(ext.ownerFrame, 'ownerFrame', `${what}: ownerFrame`);
  const payload = given(ext.payload, { codec: PAYLOAD_CODEC, version: 1 });
  if (!isObj(payload) || typeof payload.codec !== 'string' || !Number.isInteger(payload.version)) {
    throw new FormatError(`${what}: payload is not an object with a string codec and an integer version`);
  }
  if (payload.codec !== PAYLOAD_CODEC || !PAYLOAD_VERSIONS.includes(payload.version)) { // as a newer version is
    throw new UnsupportedError(`${what}: chunk payload ${JSON.stringify(payload.codec).slice(0, 40)} version ${payload.version} is not supported`);
  }
  checkCount(ext.vertexCount, 1, MAX_VERTICES, `${what}: vertexCount`);
  checkCount(ext.faceCount, 0, MAX_FACES, `${what}: faceCount`);
  if (Array.isArray(ext.chunks) && ext.chunks.length > MAX_CHUNKS) throw new LimitError(`${what}: more than ${MAX_CHUNKS} chunks`);
  if (payload.version !== 2 && Array.isArray(ext.attributes) && ext.attributes.some((a) => isObj(a) && a.prediction !== undefined)) {
    throw new FormatError(`${what}: an attribute's prediction with chunk payload version ${payload.version} (version 2 only)`);
  }
  return payload.version;
}

/**
 * The extension's vertexCount / faceCount are the counts after all chunks of the file (spec/README.md): its last
 * chunk's, or its base mesh's when it has none. They bound what a reader's arrays grow to (they are not allocated
 * up front: MeshState grows with the decode); a file declaring millions it never reaches would otherwise decode
 * as complete to fewer.
 */
function checkFinalCounts(ext, entries, baseVertices, baseFaces, what) {
  const last = entries.length ? entries[entries.length - 1] : { vertexCount: baseVertices, faceCount: baseFaces };
  if (last.vertexCount !== ext.vertexCount || last.faceCount !== ext.faceCount) {
    throw new FormatError(`${what}: vertexCount / faceCount ${ext.vertexCount} / ${ext.faceCount} differ from the `
      + `${last.vertexCount} / ${last.faceCount} ${entries.length ? 'its last chunk reaches' : 'of its base mesh'}`);
  }
}

/**
 * The progressive primitives of a parsed document and the chunk stream.
 * @returns {{primitives: object[], stream: object[], baseEnd: number, dataEnd: number}} baseEnd: BIN offset where every
 *   base is in; dataEnd: where every bufferView that holds no chunk ends (D of spec/bitstream.md §4, at least baseEnd);
 *   stream: chunks of all primitives ordered by byte offset, each {primitive, chunk, offset, length,
 *   payloadVersion, ...}; a primitive's payloadVersion is 1 or 2 (spec/bitstream.md §6, §8).
 */
export function planDocument(gltf, binLength) {
  if (!Array.isArray(gltf.extensionsUsed) || !gltf.extensionsUsed.includes(EXTENSION)) {
    throw new FormatError(`${EXTENSION} is not listed in extensionsUsed`); // spec/README.md: it MUST be
  }
  const buffers = Array.isArray(gltf.buffers) ? gltf.buffers : [];
  if (!isObj(buffers[0]) || buffers[0].uri !== undefined || !isInt(buffers[0].byteLength, 0, binLength)) {
    throw new FormatError('buffers[0] must be the GLB BIN chunk, at most its length');
  }
  // spec/README.md, Base mesh: EXT_meshopt_compression on a view would make a viewer decode other bytes than the stored ones
  (Array.isArray(gltf.bufferViews) ? gltf.bufferViews : []).forEach((view, i) => {
    if (isObj(view) && view.extensions !== undefined && !(isObj(view.extensions) && Object.keys(view.extensions).length === 0)) {
      throw new FormatError(`bufferViews[${i}] carries extensions; a .pmw's bufferViews hold their bytes as stored`);
    }
  });
  const bufferLength = buffers[0].byteLength;
  const primitives = [];
  const counted = []; // checkFinalCounts' arguments, checked once the stream's order is (its errors come first)
  const meshes = Array.isArray(gltf.meshes) ? gltf.meshes : [];
  meshes.forEach((mesh, mi) => {
    const prims = isObj(mesh) && Array.isArray(mesh.primitives) ? mesh.primitives : [];
    prims.forEach((prim, pi) => {
      const ext = isObj(prim) && isObj(prim.extensions) ? prim.extensions[EXTENSION] : undefined;
      if (ext === undefined) return;
      const what = `mesh ${mi} primitive ${pi}`;
      const payloadVersion = checkExtension(ext, what);
      const grid = checkGrid(ext.grid, `${what}: grid`, 3);
      const base = basePlan(gltf, prim, ext, bufferLength, what);
      const baseCount = baseVertexCount(gltf, prim, ext, what);
      base.welded = ext.baseVertexCount === undefined ? null : baseCount; // decodeBase welds to this count
      const entries = chunkEntries(ext, payloadVersion, baseCount, what);
      const chunks = entries.map((c, j) => checkChunk(gltf, c, j, bufferLength, what, payloadVersion));
      counted.push([ext, entries, baseCount, base.draco ? base.draco.faces : base.plain.indices.count / 3, what]);
      const baseEnd = Math.max(0, ...base.views.map((v) => v.offset + v.length));
      primitives.push({ index: primitives.length, mesh: mi, primitive: pi, ext, grid, base, chunks, baseEnd,
        vertexCount: ext.vertexCount, faceCount: ext.faceCount, payloadVersion });
    });
  });
  if (primitives.length === 0) throw new FormatError(`no primitive carries ${EXTENSION}`);
  for (const p of primitives) p.several = primitives.length > 1; // errors name the primitive only then
  const stream = primitives.flatMap((p) => p.chunks.map((c, j) => ({
    ...c, primitive: p.index, chunk: j, payloadVersion: p.payloadVersion,
  })));
  if (stream.length > MAX_CHUNKS) throw new LimitError(`more than ${MAX_CHUNKS} chunks`);
  stream.sort((a, b) => a.offset - b.offset || a.primitive - b.primitive || a.chunk - b.chunk);
  const baseEnd = Math.max(...primitives.map((p) => p.baseEnd));
  let end = baseEnd;
  const next = primitives.map(() => 0);
  for (const c of stream) {
    if (c.offset < end) throw new FormatError('chunks overlap each other or the base meshes');
    if (c.chunk !== next[c.primitive]++) throw new FormatError('a primitive\'s chunks are not in stream order');
    end = c.offset + c.length;
  }
  const dataEnd = checkChunkViews(gltf, primitives);
  for (const args of counted) checkFinalCounts(...args);
  return { primitives, stream, baseEnd, dataEnd: Math.max(baseEnd, dataEnd) };
}

/** [where, index] of every bufferView reference of the document: an accessor's, its sparse parts', an image's, a Draco
 * object's. */
function viewReferences(gltf) {
  const objects = (x) => (Array.isArray(x) ? x.map((o) => (isObj(o) ? o : {})) : []);
  const found = [];
  const add = (where, holder) => {
    if (isObj(holder) && holder.bufferView !== undefined) found.push([where, holder.bufferView]);
  };
  objects(gltf.accessors).forEach((acc, i) => {
    add(`accessors[${i}]`, acc);
    if (isObj(acc.sparse)) for (const part of ['indices', 'values']) add(`accessors[${i}].sparse.${part}`, acc.sparse[part]);
  });
  objects(gltf.images).forEach((image, i) => add(`images[${i}]`, image));
  objects(gltf.meshes).forEach((mesh, mi) => objects(mesh.primitives).forEach((prim, pi) => {
    const draco = isObj(prim.extensions) ? prim.extensions[DRACO_EXTENSION] : undefined;
    add(`meshes[${mi}].primitives[${pi}].extensions.${DRACO_EXTENSION}`, draco);
  }));
  return found;
}

/**
 * spec/bitstream.md §4: a bufferView that holds chunks (a version 1 chunk's, a chunk table's) shares no byte with
 * any other bufferView of buffer 0 (the base meshes', the document's data), and no accessor, image or Draco object
 * reads it (a cut shortens or drops it and zeroes the chunks it drops); the chunk bufferViews may overlap one
 * another. A FormatError otherwise. Returns D of §4: the largest end of the bufferViews of buffer 0 that hold no chunk
 * (those no reader reads bytes through, with a byteOffset or byteLength that is no integer in range, left out).
 */
function checkChunkViews(gltf, primitives) {
  const chunkViews = new Map(primitives.flatMap((p) => p.chunks.map((c) => [c.view.index, c.view])));
  const shared = ' (a chunk\'s bytes are no other data\'s)';
  for (const [where, index] of viewReferences(gltf)) {
    if (chunkViews.has(index)) throw new FormatError(`${where} reads bufferView ${index}, which holds chunks${shared}`);
  }
  const spans = [...chunkViews.values()].sort((a, b) => a.offset - b.offset);
  const furthest = []; // furthest[k]: the furthest end of spans[0..k]
  spans.forEach((v, k) => furthest.push(Math.max(k ? furthest[k - 1] : 0, v.offset + v.length)));
  let dataEnd = 0;
  (Array.isArray(gltf.bufferViews) ? gltf.bufferViews : []).forEach((view, i) => {
    if (chunkViews.has(i) || !isObj(view)) return;
    const start = given(view.byteOffset, 0);
    if (given(view.buffer, 0) !== 0 || !isInt(start, 0, Number.MAX_SAFE_INTEGER)
      || !isInt(view.byteLength, 1, Number.MAX_SAFE_INTEGER)) return;
    const end = start + view.byteLength;
    dataEnd = Math.max(dataEnd, end);
    let before = 0; // the chunk views that start before this one ends
    for (let step = 1 << 30; step; step >>= 1) {
      if (before + step <= spans.length && spans[before + step - 1].offset < end) before += step;
    }
    if (before && furthest[before - 1] > start) {
      const chunkView = spans.slice(0, before).find((v) => v.offset + v.length > start);
      throw new FormatError(`bufferViews[${i}] shares bytes with bufferView ${chunkView.index}, which holds chunks${shared}`);
    }
  });
  return dataEnd;
}

/**
 * Reads an accessor into a new typed array (count*k): Float32Array for FLOAT and for a vertex attribute's
 * integers (`attribute` true: their values, exact), Uint32Array for indices.
 */
export function readAccessor(bin, plan, attribute = false) {
  const { count, components: k, stride, componentType } = plan;
  const start = plan.view.offset + plan.offset;
  const dv = new DataView(bin.buffer, bin.byteOffset + start, Math.max(0, bin.byteLength - start));
  const out = componentType === FLOAT || attribute ? new Float32Array(count * k) : new Uint32Array(count * k);
  const [get, size] = READERS[componentType];
  for (let i = 0; i < count; i++) {
    for (let c = 0; c < k; c++) out[i * k + c] = dv[get](i * stride + c * size, true);
  }
  return out;
}
