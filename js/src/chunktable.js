/**
 * The packed chunk table of payload version 2 (spec/bitstream.md §6.2): the per-chunk values of a
 * primitive's index as little-endian bytes in one base64 string, `{count, packed}`.
 *
 * Bytes: a flags byte (bit 0: MACs present; the other bits 0), `count` 8-byte digests, `count`
 * 16-byte MACs when flagged, `count` float32 geometric errors, then `3 * count` unsigned LEB128
 * varints (at most 5 bytes, below 2^32): byte lengths, vertex count steps, face count steps.
 * The same layout as `unpack_chunk_table` / `pack_chunk_table` in pmwm_codec/format/extension.py.
 */
import { FormatError, LimitError } from './errors.js';
import { MAX_CHUNKS } from './constants.js';

const DIGEST = 8;
const MAC = 16;
const ERROR = 4;
const VARINT_MAX = 5;
const BASE64 = /^(?:[A-Za-z0-9+/]{4})*(?:[A-Za-z0-9+/]{2}==|[A-Za-z0-9+/]{3}=)?$/;

const hex = (bytes) => Array.from(bytes, (b) => b.toString(16).padStart(2, '0')).join('');

/**
 * The values of a packed table by entry field: byteLength, vertexCount, faceCount, geometricError
 * (the float32 as a number), digest and, when flagged, mac (hex strings); arrays of length `count`.
 * `count` and the text's length are checked before anything is decoded; any malformation is a FormatError.
 * @param {number} count @param {string} packed @param {string} what names the primitive in messages
 */
export function unpackChunkTable(count, packed, what = 'chunks') {
  const bad = (why) => new FormatError(`${what}: packed chunk table: ${why}`);
  if (!Number.isInteger(count) || count < 0) throw bad('count is not a non-negative integer');
  if (count > MAX_CHUNKS) throw new LimitError(`${what}: more than ${MAX_CHUNKS} chunks`);
  const longest = 1 + count * (DIGEST + MAC + ERROR + 3 * VARINT_MAX);
  if (typeof packed !== 'string' || packed.length > 4 * Math.ceil(longest / 3)) throw bad(`longer than ${count} chunks can need`);
  if (!BASE64.test(packed)) throw bad('not valid base64');
  const text = atob(packed);
  const data = new Uint8Array(text.length);
  for (let i = 0; i < text.length; i++) data[i] = text.charCodeAt(i);
  if (data.length === 0 || (data[0] & ~1) !== 0) throw bad('missing or reserved flag bits');
  const macs = data[0] === 1;
  let at = 1 + count * (DIGEST + ERROR + (macs ? MAC : 0));
  if (data.length < at + 3 * count) throw bad(`${data.length} bytes are too few for ${count} chunks`);
  const out = { digest: [], byteLength: [], vertexCount: [], faceCount: [], geometricError: [] };
  for (let k = 0; k < count; k++) out.digest.push(hex(data.subarray(1 + DIGEST * k, 1 + DIGEST * (k + 1))));
  if (macs) {
    const start = 1 + DIGEST * count;
    out.mac = [];
    for (let k = 0; k < count; k++) out.mac.push(hex(data.subarray(start + MAC * k, start + MAC * (k + 1))));
  }
  const dv = new DataView(data.buffer, data.byteOffset, data.byteLength);
  for (let k = 0; k < count; k++) {
    const e = dv.getFloat32(at - ERROR * (count - k), true);
    if (!Number.isFinite(e) || e < 0) throw bad('a geometric error is negative or not finite');
    out.geometricError.push(e);
  }
  const sums = [0, 0, 0];
  for (let i = 0; i < 3 * count; i++) {
    let value = 0;
    for (let j = 0; ; j++) {
      if (j === VARINT_MAX) throw bad(`a varint longer than ${VARINT_MAX} bytes`);
      if (at >= data.length) throw bad(`the varints are not exactly ${3 * count} values`);
      const b = data[at++];
      value += (b & 0x7f) * 2 ** (7 * j);
      if (b < 0x80) break;
    }
    if (value >= 2 ** 32) throw bad('a varint over 32 bits');
    const column = Math.floor(i / count);
    if (column === 0) {
      if (value < 1) throw bad('a chunk has byteLength 0');
      out.byteLength.push(value);
    } else {
      sums[column] += value;
      out[column === 1 ? 'vertexCount' : 'faceCount'].push(sums[column]);
    }
  }
  if (at !== data.length) throw bad(`the varints are not exactly ${3 * count} values`);
  return out;
}

function leb128(values) {
  const out = [];
  for (let v of values) {
    if (!Number.isSafeInteger(v) || v < 0 || v >= 2 ** 32) throw new RangeError(`chunk table: ${v} does not fit in 32 bits`);
    while (v >= 0x80) {
      out.push((v % 0x80) | 0x80);
      v = Math.floor(v / 0x80);
    }
    out.push(v);
  }
  return out;
}

/**
 * `{count, packed}` of per-chunk entries (byteLength, vertexCount, faceCount, geometricError that is
 * a float32 value, digest of 16 hex digits, mac on every entry or none). RangeError when a value
 * would not read back the same.
 */
export function packChunkTable(entries) {
  const macs = entries.filter((e) => e.mac !== undefined).length;
  if (macs && macs !== entries.length) throw new RangeError('chunk table: a MAC on some chunks but not on all');
  const steps = (field) => entries.map((e, k) => e[field] - (k ? entries[k - 1][field] : 0));
  const varints = leb128([...entries.map((e) => e.byteLength), ...steps('vertexCount'), ...steps('faceCount')]);
  const bytes = new Uint8Array(1 + entries.length * (DIGEST + ERROR + (macs ? MAC : 0)) + varints.length);
  const dv = new DataView(bytes.buffer);
  bytes[0] = macs ? 1 : 0;
  let at = 1;
  const putHex = (h, n) => {
    if (typeof h !== 'string' || !new RegExp(`^[0-9a-f]{${2 * n}}$`).test(h)) throw new RangeError('chunk table: a digest or MAC is not lowercase hex');
    for (let i = 0; i < n; i++) bytes[at++] = parseInt(h.slice(2 * i, 2 * i + 2), 16);
  };
  for (const e of entries) putHex(e.digest, DIGEST);
  if (macs) for (const e of entries) putHex(e.mac, MAC);
  for (const e of entries) {
    if (Math.fround(e.geometricError) !== e.geometricError) throw new RangeError('chunk table: a geometric error is not a float32 value');
    dv.setFloat32(at, e.geometricError, true);
    at += ERROR;
  }
  bytes.set(varints, at);
  let text = '';
  for (let i = 0; i < bytes.length; i += 0x8000) text += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return { count: entries.length, packed: btoa(text) };
}
