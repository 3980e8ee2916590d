/**
 * Test-only writer: a .pmw with one chunk's payload replaced, stored as a zstd frame of raw
 * blocks (RFC 8878: single segment, 4-byte content size, XXH64 checksum; payload version 1) or as
 * it is (payload version 2, spec/bitstream.md §8) with a fresh BLAKE2b digest, so hostile payloads
 * reach the record parser instead of stopping at the digest.
 */
import { createBLAKE2b, createXXHash64 } from 'hash-wasm';
import { parseGlb, planDocument } from '../../src/header.js';
import { openChunk, initChunkFrames } from '../../src/chunkframe.js';
import { packChunkTable, unpackChunkTable } from '../../src/chunktable.js';

const blake = await createBLAKE2b(128);
const xxh64 = await createXXHash64();
await initChunkFrames();

export function rawFrame(payload) {
  const blocks = [];
  for (let at = 0; at < payload.length || at === 0; at += 131072) {
    const part = payload.subarray(at, at + 131072);
    const last = at + 131072 >= payload.length ? 1 : 0;
    const h = (part.length << 3) | last;
    blocks.push(Uint8Array.of(h & 255, (h >> 8) & 255, (h >> 16) & 255), part);
    if (payload.length === 0) break;
  }
  const digest = xxh64.init().update(payload).digest('binary'); // big-endian
  const sum = new DataView(digest.buffer, digest.byteOffset).getUint32(4);
  const head = Uint8Array.of(0x28, 0xb5, 0x2f, 0xfd, 0xa4, ...new Uint8Array(Uint32Array.of(payload.length).buffer));
  const tail = new Uint8Array(Uint32Array.of(sum).buffer);
  const out = new Uint8Array([...head, ...blocks.flatMap((b) => [...b]), ...tail]);
  return out;
}

/** The decompressed payloads of every chunk, in stream order: [{entry, payload}]. */
export function chunkPayloads(bytes) {
  const h = parseGlb(bytes);
  const plan = planDocument(h.gltf, h.binLength);
  return plan.stream.map((c, i) => ({ c, payload: openChunk(bytes.subarray(h.binStart + c.offset, h.binStart + c.offset + c.length), c, i) }));
}

/**
 * `bytes` with stream chunk `index` holding `payload` (bufferViews after it shifted), its index
 * entry then given the fields of `patch` (e.g. a wrong uncompressedLength). Payload version 2: the
 * chunk table's entries are updated (later chunks of the shared bufferView shift) and `patch` is
 * applied to the table itself.
 */
export function withPayload(bytes, index, payload, patch = {}) {
  const h = parseGlb(bytes);
  const gltf = structuredClone(h.gltf);
  const plan = planDocument(gltf, h.binLength);
  const c = plan.stream[index];
  const chunks = gltf.meshes[plan.primitives[c.primitive].mesh].primitives[plan.primitives[c.primitive].primitive]
    .extensions.PMWM_progressive_mesh.chunks;
  if (c.payloadVersion === 2) return withV2Payload(bytes, h, gltf, plan, c, chunks, payload, patch);
  const entry = chunks[c.chunk];
  const frame = rawFrame(payload);
  const padded = (n) => (n + 3) & ~3;
  const delta = padded(frame.length) - padded(c.length);
  for (const v of gltf.bufferViews) if ((v.byteOffset ?? 0) > c.offset) v.byteOffset += delta;
  gltf.bufferViews[entry.bufferView].byteLength = frame.length;
  Object.assign(entry, { byteLength: frame.length, uncompressedLength: payload.length, digest: blake.init().update(frame).digest('hex') }, patch);
  const oldBin = bytes.subarray(h.binStart, h.binStart + h.binLength);
  const bin = new Uint8Array(padded(h.binLength + delta));
  bin.set(oldBin.subarray(0, c.offset));
  bin.set(frame, c.offset);
  bin.set(oldBin.subarray(c.offset + padded(c.length)), c.offset + padded(frame.length));
  gltf.buffers[0].byteLength = Math.min(bin.length, gltf.buffers[0].byteLength + delta);
  return glb(gltf, bin);
}

/** withPayload for a chunk of a version 2 chunk table: the chunks lie back to back in one bufferView. */
function withV2Payload(bytes, h, gltf, plan, c, table, payload, patch) {
  const padded = (n) => (n + 3) & ~3;
  const view = gltf.bufferViews[table.bufferView];
  const viewEnd = (view.byteOffset ?? 0) + view.byteLength;
  const d = payload.length - c.length;
  const delta = padded(viewEnd + d) - padded(viewEnd);
  for (const v of gltf.bufferViews) if ((v.byteOffset ?? 0) >= padded(viewEnd) && v !== view) v.byteOffset += delta;
  view.byteLength += d;
  for (const p of plan.primitives) { // every table in this bufferView: offsets after the chunk move by d
    const t = gltf.meshes[p.mesh].primitives[p.primitive].extensions.PMWM_progressive_mesh.chunks;
    if (t.byteOffsets) t.byteOffsets = t.byteOffsets.map((o) => ((view.byteOffset ?? 0) + o > c.offset ? o + d : o));
  }
  const hex = blake.init().update(payload).digest('hex').slice(0, 16);
  if ('packed' in table) { // spec/bitstream.md §6.2: unpack, change the chunk's length and digest, pack again
    const cols = unpackChunkTable(table.count, table.packed);
    cols.byteLength[c.chunk] = payload.length;
    cols.digest[c.chunk] = hex;
    Object.assign(table, packChunkTable(cols.byteLength.map((byteLength, k) => ({
      byteLength, vertexCount: cols.vertexCount[k], faceCount: cols.faceCount[k], geometricError: cols.geometricError[k],
      digest: cols.digest[k], mac: cols.mac?.[k] }))));
  } else {
    table.byteLengths[c.chunk] = payload.length;
    table.digests = table.digests.slice(0, 16 * c.chunk) + hex + table.digests.slice(16 * c.chunk + 16);
  }
  Object.assign(table, patch);
  const oldBin = bytes.subarray(h.binStart, h.binStart + h.binLength);
  const bin = new Uint8Array(padded(h.binLength + delta));
  bin.set(oldBin.subarray(0, c.offset));
  bin.set(payload, c.offset);
  bin.set(oldBin.subarray(c.offset + c.length, viewEnd), c.offset + payload.length);
  bin.set(oldBin.subarray(padded(viewEnd)), padded(viewEnd + d));
  gltf.buffers[0].byteLength = Math.min(bin.length, gltf.buffers[0].byteLength + delta);
  return glb(gltf, bin);
}

/**
 * `bytes` with its glTF JSON changed by `mutate(gltf, plan)` (on a copy; plan: planDocument of the
 * original), the BIN kept: e.g. an extension property or a chunk table's counts (packed tables:
 * use `setTableCounts`).
 */
export function withJson(bytes, mutate) {
  const h = parseGlb(bytes);
  const gltf = structuredClone(h.gltf);
  mutate(gltf, planDocument(h.gltf, h.binLength));
  return glb(gltf, bytes.subarray(h.binStart, h.binStart + h.binLength));
}

/**
 * Sets chunk k's vertexCount / faceCount in a version 2 chunk table `table` (packed or arrays), in
 * place; its digests and MACs are kept (a MAC then fails, which tests of unkeyed files never see).
 */
export function setTableCounts(table, k, vertexCount, faceCount) {
  if (!('packed' in table)) {
    table.vertexCounts[k] = vertexCount;
    table.faceCounts[k] = faceCount;
    return;
  }
  const cols = unpackChunkTable(table.count, table.packed);
  cols.vertexCount[k] = vertexCount;
  cols.faceCount[k] = faceCount;
  Object.assign(table, packChunkTable(cols.byteLength.map((byteLength, j) => ({
    byteLength, vertexCount: cols.vertexCount[j], faceCount: cols.faceCount[j], geometricError: cols.geometricError[j],
    digest: cols.digest[j], mac: cols.mac?.[j] }))));
}

/** A GLB of a glTF JSON object and its BIN bytes (4-byte aligned). */
export function glb(gltf, bin) {
  const padded = (n) => (n + 3) & ~3;
  let json = new TextEncoder().encode(JSON.stringify(gltf));
  const jsonPadded = new Uint8Array(padded(json.length)).fill(0x20);
  jsonPadded.set(json);
  json = jsonPadded;
  const out = new Uint8Array(28 + json.length + bin.length);
  const dv = new DataView(out.buffer);
  dv.setUint32(0, 0x46546c67, true); dv.setUint32(4, 2, true); dv.setUint32(8, out.length, true);
  dv.setUint32(12, json.length, true); dv.setUint32(16, 0x4e4f534a, true);
  out.set(json, 20);
  dv.setUint32(20 + json.length, bin.length, true); dv.setUint32(24 + json.length, 0x004e4942, true);
  out.set(bin, 28 + json.length);
  return out;
}
