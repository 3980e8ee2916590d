/**
 * A tiny reader of numpy .npz files (a zip of .npy arrays, stored or deflated) for the tests:
 * readNpz(bytes) -> {name: {dtype, shape, data}} with data a BigInt64Array ('<i8'), Uint8Array
 * ('|u1') or an array of strings ('<U*').
 */
import { inflateRawSync } from 'node:zlib';

function entries(buf) {
  const dv = new DataView(buf.buffer, buf.byteOffset, buf.byteLength);
  let eocd = buf.length - 22;
  while (eocd >= 0 && dv.getUint32(eocd, true) !== 0x06054b50) eocd--;
  if (eocd < 0) throw new Error('npz: no end of central directory');
  const count = dv.getUint16(eocd + 10, true);
  let at = dv.getUint32(eocd + 16, true);
  const out = [];
  for (let i = 0; i < count; i++) {
    const method = dv.getUint16(at + 10, true);
    const size = dv.getUint32(at + 20, true);
    const nameLen = dv.getUint16(at + 28, true);
    const extraLen = dv.getUint16(at + 30, true);
    const commentLen = dv.getUint16(at + 32, true);
    const local = dv.getUint32(at + 42, true);
    const name = new TextDecoder().decode(buf.subarray(at + 46, at + 46 + nameLen));
    const start = local + 30 + dv.getUint16(local + 26, true) + dv.getUint16(local + 28, true);
    const raw = buf.subarray(start, start + size);
    out.push({ name, data: method === 8 ? new Uint8Array(inflateRawSync(raw)) : raw });
    at += 46 + nameLen + extraLen + commentLen;
  }
  return out;
}

function readNpy(b) {
  const dv = new DataView(b.buffer, b.byteOffset, b.byteLength);
  const major = b[6];
  const headerLen = major === 1 ? dv.getUint16(8, true) : dv.getUint32(8, true);
  const start = major === 1 ? 10 : 12;
  const header = new TextDecoder().decode(b.subarray(start, start + headerLen));
  const descr = /'descr':\s*'([^']+)'/.exec(header)[1];
  const shape = /'shape':\s*\(([^)]*)\)/.exec(header)[1].split(',').filter((s) => s.trim()).map(Number);
  if (/'fortran_order':\s*True/.test(header)) throw new Error('npz: fortran order not supported');
  const body = b.slice(start + headerLen);
  const count = shape.reduce((a, x) => a * x, 1);
  let data;
  if (descr === '<i8') data = new BigInt64Array(body.buffer, 0, count);
  else if (descr === '|u1') data = body.subarray(0, count);
  else if (descr.startsWith('<U')) {
    const w = Number(descr.slice(2));
    const u32 = new Uint32Array(body.buffer, 0, count * w);
    data = Array.from({ length: count }, (_, i) => String.fromCodePoint(...u32.subarray(i * w, (i + 1) * w)).replace(/\0+$/, ''));
  } else throw new Error(`npz: dtype ${descr} not supported`);
  return { dtype: descr, shape, data };
}

export function readNpz(bytes) {
  const out = {};
  for (const { name, data } of entries(bytes)) out[name.replace(/\.npy$/, '')] = readNpy(data);
  return out;
}
