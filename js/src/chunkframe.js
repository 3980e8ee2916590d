/**
 * A stored chunk (spec/bitstream.md §5): BLAKE2b-128 digest, then one zstd frame with its content
 * size and checksum, decompressed into exactly `uncompressedLength` bytes (payload version 1; a
 * version 2 chunk is its coded stream itself, §8).
 *
 * Digest: BLAKE2b (RFC 7693, 16-byte output, no key) from hash-wasm. Decompression: zstddec, the
 * reference libzstd compiled to WebAssembly; its one-shot ZSTD_decompress also verifies the frame's
 * content checksum (XXH64, low 32 bits) and fails the frame when it differs, so a wrong checksum ends in
 * the same FormatError as any other undecodable frame. Chunks are whole frames, so one-shot decoding per
 * chunk keeps the push decoder incremental. The WebAssembly memory grows to the largest chunk seen
 * (stored + decompressed bytes: at most 1.25 GiB under spec/README.md "Limits", within its 2000 MiB).
 */
import { createBLAKE2b } from 'hash-wasm';
import { ZSTDDecoder } from 'zstddec';
import { CorruptChunkError, FormatError } from './errors.js';

const MAX_BLOCK = 131072;
/** Low 32 bits of XXH64 (seed 0) of no bytes: the content checksum of an empty frame. */
const XXH64_EMPTY_LOW32 = 0x51d8e999;
let blake = null;
let zstd = null;

/**
 * Loads the BLAKE2b and (unless `zstd` is false) the zstd WebAssembly modules once (async: browsers
 * compile wasm asynchronously). Only payload version 1 chunks are zstd frames: a stream of version 2
 * chunks only needs BLAKE2b, and skipping zstd takes its load off a first decode (in Node, zstddec
 * fetches its embedded module as a data: URL, which loads Node's fetch implementation first:
 * about 40 ms of a cold process's decode of the Stanford bunny, more than its BLAKE2b and Draco).
 * @param {{zstd?: boolean}} [options]
 */
export async function initChunkFrames({ zstd: withZstd = true } = {}) {
  if (blake && (zstd || !withZstd)) return;
  const decoder = withZstd && !zstd ? new ZSTDDecoder() : null;
  const [hasher] = await Promise.all([blake ?? createBLAKE2b(128), decoder?.init()]);
  blake ??= hasher;
  zstd ??= decoder;
}

function ready(needZstd = false) {
  if (blake === null || (needZstd && zstd === null)) {
    throw new Error(`initChunkFrames(${needZstd ? '' : '{zstd: false}'}) was not awaited`);
  }
}

/** True when BLAKE2b-128 of `stored` equals the 32-digit lowercase hex `digest`, or begins with the
 * 16-digit `digest` of a payload version 2 chunk table (spec/bitstream.md §6.2). */
export function digestMatches(stored, digest) {
  ready();
  if (typeof digest !== 'string' || (digest.length !== 32 && digest.length !== 16)) return false;
  return blake.init().update(stored).digest('hex').slice(0, digest.length) === digest;
}

/**
 * Unkeyed BLAKE2b-128 over `fields` framed as spec/bitstream.md §6.3 has it (each field preceded by
 * its length as a uint64 little-endian), as 32 lowercase hex digits.
 * @param {Uint8Array[]} fields
 */
export function framedDigest(fields) {
  ready();
  const hasher = blake.init();
  const length = new DataView(new ArrayBuffer(8));
  for (const f of fields) {
    length.setBigUint64(0, BigInt(f.length), true);
    hasher.update(new Uint8Array(length.buffer)).update(f);
  }
  return hasher.digest('hex');
}

/**
 * The frame header and block layout of one zstd frame (RFC 8878 §3.1.1), walked without decoding.
 * @returns {{contentSize:number, checksum:number}} FormatError unless the frame declares its content size,
 *   has a checksum, no dictionary, and ends exactly at the end of `frame`.
 */
export function frameLayout(frame, what) {
  const fail = (why) => { throw new FormatError(`${what}: ${why}`); };
  if (frame.length < 6 || frame[0] !== 0x28 || frame[1] !== 0xb5 || frame[2] !== 0x2f || frame[3] !== 0xfd) {
    fail('not a zstd frame');
  }
  const fhd = frame[4];
  const fcsFlag = fhd >> 6;
  const single = (fhd >> 5) & 1;
  if (fhd & 8) fail('zstd frame header has its reserved bit set');
  if (!((fhd >> 2) & 1)) fail('zstd frame has no content checksum');
  if (fhd & 3) fail('zstd frame names a dictionary');
  const fcsSize = fcsFlag === 0 ? single : 1 << fcsFlag;
  if (fcsSize === 0) fail('zstd frame does not declare its content size');
  let at = 5 + (single ? 0 : 1);
  if (at + fcsSize > frame.length) fail('zstd frame header is cut short');
  let contentSize = 0;
  for (let i = fcsSize - 1; i >= 0; i--) contentSize = contentSize * 256 + frame[at + i];
  if (fcsSize === 2) contentSize += 256;
  at += fcsSize;
  for (let last = 0; !last;) {
    if (at + 3 > frame.length) fail('zstd frame is cut short');
    const h = frame[at] | (frame[at + 1] << 8) | (frame[at + 2] << 16);
    last = h & 1;
    const type = (h >> 1) & 3;
    const size = h >>> 3;
    if (type === 3 || size > MAX_BLOCK) fail('zstd frame has an invalid block');
    at += 3 + (type === 1 ? 1 : size);
  }
  if (at + 4 !== frame.length) fail(at + 4 > frame.length ? 'zstd frame is cut short' : 'bytes after the zstd frame');
  const checksum = (frame[at] | (frame[at + 1] << 8) | (frame[at + 2] << 16) | (frame[at + 3] << 24)) >>> 0;
  return { contentSize, checksum };
}

/**
 * Checks and decompresses chunk `index` (0-based) of the stream (spec/bitstream.md §5, checks 2-4). A chunk
 * of payload version 2 (§8) is stored as it is: digest, then `uncompressedLength` equal to its length.
 * @param {Uint8Array} stored the chunk's bufferView bytes
 * @param {{digest:string, uncompressedLength:number, payloadVersion?:number}} chunk its index entry
 * @returns {Uint8Array} the payload, exactly `uncompressedLength` bytes (version 2: `stored` itself)
 */
export function openChunk(stored, chunk, index) {
  const number = index + 1; // numbered from 1, as the Python reader does (0 is the base mesh)
  const what = `chunk ${number}`;
  if (!digestMatches(stored, chunk.digest)) throw new CorruptChunkError(`${what}: BLAKE2b digest differs`, number);
  if (chunk.payloadVersion === 2) {
    if (chunk.uncompressedLength !== stored.length) {
      throw new FormatError(`${what}: uncompressedLength ${chunk.uncompressedLength} differs from byteLength ${stored.length} (payload version 2)`);
    }
    return stored;
  }
  const { contentSize, checksum } = frameLayout(stored, what);
  if (contentSize !== chunk.uncompressedLength) throw new FormatError(`${what}: zstd content size differs`);
  if (contentSize === 0) {
    // zstddec cannot tell an empty result from an error, so check the checksum here (an empty payload
    // then fails the payload parser: spec/bitstream.md §6 starts it with a header)
    if (checksum !== XXH64_EMPTY_LOW32) throw new FormatError(`${what}: zstd content checksum differs`);
    return new Uint8Array(0);
  }
  return inflate(stored, contentSize, what);
}

/**
 * One zstd frame decompressed into exactly `contentSize` (> 0) bytes; libzstd checks the content checksum.
 * @returns {Uint8Array} a fresh array, not a view of the WebAssembly memory
 */
export function inflate(frame, contentSize, what) {
  ready(true);
  const out = zstd.decode(frame, contentSize);
  // zstddec returns the bytes ZSTD_decompress wrote: none (an error code) unless the frame decoded
  // and its checksum matched
  if (out.length !== contentSize) throw new FormatError(`${what}: zstd frame does not decode or its checksum differs`);
  return out;
}
