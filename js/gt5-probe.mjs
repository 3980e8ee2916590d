import { NodeIO } from '@gltf-transform/core';
import { PMWMProgressiveMesh } from './src/gltf-transform.js';
import { parseGlb } from './src/header.js';
import fs from 'node:fs';
const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
function rebuild(bytes, edit) {
  const h = parseGlb(bytes); const g = structuredClone(h.gltf); edit(g);
  let js = new TextEncoder().encode(JSON.stringify(g)); const pad = (4 - js.length % 4) % 4;
  js = new Uint8Array([...js, ...new Array(pad).fill(32)]);
  const bin = bytes.subarray(h.binStart - 8);
  const out = new Uint8Array(20 + js.length + bin.length); const dv = new DataView(out.buffer);
  dv.setUint32(0, 0x46546c67, true); dv.setUint32(4, 2, true); dv.setUint32(8, out.length, true); dv.setUint32(12, js.length, true); dv.setUint32(16, 0x4e4f534a, true);
  out.set(js, 20); out.set(bin, 20 + js.length); return out;
}
const v1 = new Uint8Array(fs.readFileSync('../spec/conformance/grid-hole.plain.v1.pmw'));
const v2 = new Uint8Array(fs.readFileSync('../spec/conformance/grid-hole.plain.packed.v2.pmw'));
const ext = (g) => g.meshes[0].primitives[0].extensions.PMWM_progressive_mesh;
const cases = {
  'v1 chunk bufferView 999': [v1, (g) => { ext(g).chunks[0].bufferView = 999; }],
  'v1 chunk bufferView "a"': [v1, (g) => { ext(g).chunks[0].bufferView = 'a'; }],
  'v1 chunk byteLength huge': [v1, (g) => { ext(g).chunks[0].byteLength = 1e6; }],
  'v1 chunks null entry': [v1, (g) => { ext(g).chunks[1] = null; }],
  'v1 chunks not array': [v1, (g) => { ext(g).chunks = 5; }],
  'v2 table bufferView 999': [v2, (g) => { ext(g).chunks.bufferView = 999; }],
  'v2 byteOffsets past': [v2, (g) => { ext(g).chunks.byteOffsets = ext(g).chunks.count ? Array(ext(g).chunks.count).fill(1e6) : []; }],
  'ext not object': [v2, (g) => { g.meshes[0].primitives[0].extensions.PMWM_progressive_mesh = 3; }],
  'version 2': [v2, (g) => { ext(g).version = 2; }],
  'payload v3': [v2, (g) => { ext(g).payload = { codec: 'pmwm-vsplit', version: 3 }; }],
};
for (const [what, [src, edit]] of Object.entries(cases)) {
  try { const doc = await io.readBinary(rebuild(src, edit)); const out = await io.writeBinary(doc); console.log(what, '-> read+write ok', out.length); }
  catch (e) { console.log(what, '->', e.name, e.message.slice(0, 150)); }
}
