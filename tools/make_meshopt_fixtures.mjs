// Writes tests/data/meshopt/streams.json (+ streams.bin.gz, the bytes it points at): inputs and
// meshoptimizer-encoded streams for every mode, filter, stride, index size and attribute stream
// version of EXT_/KHR_meshopt_compression, for tests/test_meshopt.py (our decoder must give back
// the encoder's input bytes; for filtered views and rotated triangles, the bytes of
// meshoptimizer's own decoder).
//
// It also makes torus.glb (a generated torus: positions, normals, texture coordinates, 16-bit
// indices; in a temporary folder, not committed) and runs gltfpack 1.3 (npm package "gltfpack",
// WASM; path in $GLTFPACK, default `gltfpack` on PATH) on it, writing into tests/data/meshopt/:
//
//     gltfpack -i torus.glb -o torus_plain.glb
//     gltfpack -i torus.glb -o torus_c.glb -c
//     gltfpack -i torus.glb -o torus_cc.glb -cc
//     gltfpack -i torus.glb -o torus_cc_khr.glb -cc -ce khr
//     gltfpack -i torus.glb -o torus_cf.glb -cf     (also writes torus_cf.fallback.bin)
//
// Run from the repository root, with js/node_modules holding meshoptimizer 1.2 (a dependency of
// the js/ package's dev tools: `cd js && npm ci`):
//
//     GLTFPACK=/path/to/gltfpack node tools/make_meshopt_fixtures.mjs
//
// Everything is generated from a fixed-seed PRNG: rerunning gives the same files.

import { writeFileSync, mkdirSync, mkdtempSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { join } from 'node:path';
import { execFileSync } from 'node:child_process';
import { gzipSync } from 'node:zlib';
import { MeshoptEncoder, MeshoptDecoder } from '../js/node_modules/meshoptimizer/index.js';

await MeshoptEncoder.ready;
await MeshoptDecoder.ready;

let seed = 0x2545f491;
function rand() {
	// mulberry32
	seed = (seed + 0x6d2b79f5) | 0;
	let t = seed;
	t = Math.imul(t ^ (t >>> 15), t | 1);
	t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
	return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
}

// every byte string goes once into one binary blob; the JSON names it by [offset, length]
const blob = [];
let blobLength = 0;
const b64 = (u8) => {
	const at = [blobLength, u8.byteLength];
	blob.push(Buffer.from(u8.buffer, u8.byteOffset, u8.byteLength));
	blobLength += u8.byteLength;
	return at;
};
const cases = [];
const inputs = {}; // shared raw inputs by key
function keep(key, u8) {
	inputs[key] = b64(u8);
	return key;
}

// ---- attributes: rows mixing the kinds of columns real vertex data has ----
function vertexData(count, stride) {
	const out = new Uint8Array(count * stride);
	const dv = new DataView(out.buffer);
	for (let c = 0; c < stride / 4; c++) {
		const kind = c % 12 === 2 ? 2 : [0, 1, 3, 4, 5][c % 5];
		let acc = rand() * 1000;
		for (let i = 0; i < count; i++) {
			const o = i * stride + c * 4;
			if (kind === 0) {
				// smooth 16-bit quantized coordinates (2-byte deltas)
				dv.setUint16(o, (30000 + Math.round(3000 * Math.sin(i * 0.05 + c))) & 0xffff, true);
				dv.setUint16(o + 2, (i * 7 + c) & 0xffff, true);
			} else if (kind === 1) {
				// smooth float32 (XOR deltas)
				acc += Math.round((rand() - 0.5) * 64) / 256; // few mantissa bits: XOR deltas stay small
				dv.setFloat32(o, acc, true);
			} else if (kind === 2) {
				// random bytes (literal groups)
				dv.setUint32(o, (rand() * 4294967296) >>> 0, true);
			} else if (kind === 3) {
				// constant (zero deltas)
				dv.setUint32(o, 0x3f800000, true);
			} else if (kind === 4) {
				// small noise around a value (1-/2-bit deltas)
				for (let k = 0; k < 4; k++) out[o + k] = 100 + Math.floor(rand() * (k + 1));
			} else {
				// sparse jumps (sentinels)
				for (let k = 0; k < 4; k++) out[o + k] = rand() < 0.1 ? Math.floor(rand() * 256) : k * 10;
			}
		}
	}
	return out;
}

const strides = [
	[4, 300],
	[8, 300],
	[12, 270],
	[16, 260],
	[24, 100],
	[32, 100],
	[64, 130],
	[256, 34],
];
for (const [stride, count] of strides) {
	const raw = vertexData(count, stride);
	const key = keep(`attr_s${stride}`, raw);
	const versions = [
		[0, 2],
		[1, 2],
	];
	if (stride === 8) versions.push([1, 0], [1, 1], [1, 3], [0, 3]);
	if (stride === 16) versions.push([1, 3]);
	for (const [version, level] of versions) {
		const enc = MeshoptEncoder.encodeVertexBufferLevel(raw, count, stride, level, version);
		cases.push({ name: `attr_s${stride}_v${version}_l${level}`, mode: 'ATTRIBUTES', filter: 'NONE', version, count, stride, input: key, encoded: b64(enc), expected: 'input' });
	}
}
for (const count of [0, 1, 15, 16, 17]) {
	const raw = vertexData(count, 12);
	const key = keep(`attr_n${count}`, raw);
	for (const version of [0, 1]) {
		const enc = MeshoptEncoder.encodeVertexBufferLevel(raw, count, 12, 2, version);
		cases.push({ name: `attr_n${count}_v${version}`, mode: 'ATTRIBUTES', filter: 'NONE', version, count, stride: 12, input: key, encoded: b64(enc), expected: 'input' });
	}
}

// ---- triangles and index sequences ----
function grid(n) {
	const idx = [];
	for (let y = 0; y < n; y++)
		for (let x = 0; x < n; x++) {
			const a = y * (n + 1) + x;
			idx.push(a, a + 1, a + n + 2, a, a + n + 2, a + n + 1);
		}
	return new Uint32Array(idx);
}
function shuffledTriangles(idx) {
	const tris = [];
	for (let i = 0; i < idx.length; i += 3) {
		const r = Math.floor(rand() * 3);
		const t = [idx[i], idx[i + 1], idx[i + 2]];
		tris.push([t[r], t[(r + 1) % 3], t[(r + 2) % 3]]);
	}
	for (let i = tris.length - 1; i > 0; i--) {
		const j = Math.floor(rand() * (i + 1));
		[tris[i], tris[j]] = [tris[j], tris[i]];
	}
	return new Uint32Array(tris.flat());
}
function optimized(idx, optsize) {
	const copy = new Uint32Array(idx);
	MeshoptEncoder.reorderMesh(copy, true, optsize); // reorders and renumbers in place
	return copy;
}
function as(idx, size) {
	return size === 2 ? new Uint8Array(new Uint16Array(idx).buffer) : new Uint8Array(new Uint32Array(idx).buffer);
}
const g = grid(12);
const triSets = {
	optimized: optimized(g, true),
	cache: optimized(grid(10), false),
	shuffled: shuffledTriangles(g),
	large: shuffledTriangles(grid(8)).map((v) => v * 1000 + 70000),
	concatenated: new Uint32Array([...optimized(grid(6), true), ...optimized(grid(5), true)]),
	degenerate: new Uint32Array(Array.from({ length: 300 }, () => Math.floor(rand() * 40))),
};
for (const [name, idx] of Object.entries(triSets)) {
	for (const size of [2, 4]) {
		if (size === 2 && Math.max(...idx) > 0xffff) continue;
		const raw = as(idx, size);
		const enc = MeshoptEncoder.encodeIndexBuffer(raw, idx.length, size);
		// the encoder may rotate a triangle's corners (and keeps the triangle order): the expected
		// bytes are meshoptimizer's decoder's; the test checks they are the input up to rotations
		const out = new Uint8Array(idx.length * size);
		MeshoptDecoder.decodeIndexBuffer(out, idx.length, size, enc);
		const same = Buffer.compare(Buffer.from(out), Buffer.from(raw)) === 0;
		cases.push({ name: `tri_${name}_${size}`, mode: 'TRIANGLES', filter: 'NONE', version: 0, count: idx.length, stride: size, input: keep(`tri_${name}_${size}`, raw), encoded: b64(enc), expected: same ? 'input' : b64(out) });
	}
}
const lines = [];
for (let i = 0; i < g.length; i += 3) lines.push(g[i], g[i + 1], g[i + 1], g[i + 2]);
const strip = [];
for (let i = 0; i < 600; i++) strip.push((i >> 1) + (i & 1) * 40);
const seqSets = {
	lines: new Uint32Array(lines),
	strip: new Uint32Array(strip),
	random: new Uint32Array(Array.from({ length: 300 }, () => Math.floor(rand() * 65536))),
	large: new Uint32Array(Array.from({ length: 300 }, () => (rand() * 2 ** 29) >>> 0)), // deltas within the codec's +-2^30, 5-byte varints
	empty: new Uint32Array(0),
};
for (const [name, idx] of Object.entries(seqSets)) {
	for (const size of [2, 4]) {
		if (size === 2 && idx.some((v) => v > 0xffff)) continue;
		const raw = as(idx, size);
		const enc = MeshoptEncoder.encodeIndexSequence(raw, idx.length, size);
		cases.push({ name: `seq_${name}_${size}`, mode: 'INDICES', filter: 'NONE', version: 0, count: idx.length, stride: size, input: keep(`seq_${name}_${size}`, raw), encoded: b64(enc), expected: 'input' });
	}
}

// ---- filters: the filter encoder's output is the codec input; meshoptimizer's decoder gives the expected bytes ----
function unitVectors(count, comps) {
	const f = new Float32Array(count * comps);
	for (let i = 0; i < count; i++) {
		let v = Array.from({ length: comps }, () => rand() * 2 - 1);
		if (i % 50 === 0) v = v.map((_, k) => (k === i % comps ? (i % 100 ? 1 : -1) : 0)); // axis-aligned
		const len = Math.hypot(...v) || 1;
		for (let k = 0; k < comps; k++) f[i * comps + k] = v[k] / len;
	}
	return f;
}
function filterCase(name, filter, count, stride, ints) {
	const key = keep(name, ints);
	for (const version of filter === 'COLOR' ? [1] : [0, 1]) {
		const enc = MeshoptEncoder.encodeVertexBufferLevel(ints, count, stride, 2, version);
		const out = new Uint8Array(count * stride);
		MeshoptDecoder.decodeVertexBuffer(out, count, stride, enc, filter);
		cases.push({ name: `${name}_v${version}`, mode: 'ATTRIBUTES', filter, version, count, stride, input: key, encoded: b64(enc), expected: b64(out) });
	}
}
const N = 100;
{
	const nrm = unitVectors(N, 4).map((v, i) => (i % 4 === 3 ? (i & 4 ? 1 : -1) : v));
	const n3 = new Float32Array(N * 4);
	for (let i = 0; i < N; i++) {
		const x = nrm[i * 4], y = nrm[i * 4 + 1], z = nrm[i * 4 + 2];
		const l = Math.hypot(x, y, z) || 1;
		n3.set([x / l, y / l, z / l, nrm[i * 4 + 3]], i * 4);
	}
	filterCase('oct_s4_b8', 'OCTAHEDRAL', N, 4, MeshoptEncoder.encodeFilterOct(n3, N, 4, 8));
	filterCase('oct_s4_b5', 'OCTAHEDRAL', N, 4, MeshoptEncoder.encodeFilterOct(n3, N, 4, 5));
	filterCase('oct_s8_b12', 'OCTAHEDRAL', N, 8, MeshoptEncoder.encodeFilterOct(n3, N, 8, 12));
	filterCase('oct_s8_b16', 'OCTAHEDRAL', N, 8, MeshoptEncoder.encodeFilterOct(n3, N, 8, 16));
}
{
	const q = unitVectors(N, 4);
	filterCase('quat_b12', 'QUATERNION', N, 8, MeshoptEncoder.encodeFilterQuat(q, N, 8, 12));
	filterCase('quat_b16', 'QUATERNION', N, 8, MeshoptEncoder.encodeFilterQuat(q, N, 8, 16));
	filterCase('quat_b4', 'QUATERNION', N, 8, MeshoptEncoder.encodeFilterQuat(q, N, 8, 4));
}
{
	const N = 100;
	const f = new Float32Array(N * 3).map((_, i) => (rand() - 0.5) * Math.pow(10, (i % 9) - 4));
	filterCase('exp_s12_b15_sharedvector', 'EXPONENTIAL', N, 12, MeshoptEncoder.encodeFilterExp(f, N, 12, 15, 'SharedVector'));
	filterCase('exp_s12_b23_separate', 'EXPONENTIAL', N, 12, MeshoptEncoder.encodeFilterExp(f, N, 12, 23, 'Separate'));
	filterCase('exp_s4_b10_sharedcomponent', 'EXPONENTIAL', N * 3, 4, MeshoptEncoder.encodeFilterExp(f, N * 3, 4, 10, 'SharedComponent'));
	filterCase('exp_s12_b16_clamped', 'EXPONENTIAL', N, 12, MeshoptEncoder.encodeFilterExp(f, N, 12, 16, 'Clamped'));
}
{
	const col = new Float32Array(N * 4).map(() => rand());
	filterCase('color_s4_b8', 'COLOR', N, 4, MeshoptEncoder.encodeFilterColor(col, N, 4, 8));
	filterCase('color_s4_b5', 'COLOR', N, 4, MeshoptEncoder.encodeFilterColor(col, N, 4, 5));
	filterCase('color_s8_b12', 'COLOR', N, 8, MeshoptEncoder.encodeFilterColor(col, N, 8, 12));
	filterCase('color_s8_b16', 'COLOR', N, 8, MeshoptEncoder.encodeFilterColor(col, N, 8, 16));
}

mkdirSync('tests/data/meshopt', { recursive: true });
const json = JSON.stringify({ encoder: 'meshoptimizer 1.2.0 (npm)', blob: 'streams.bin.gz', inputs, cases }, null, 0);
writeFileSync('tests/data/meshopt/streams.json', json + '\n');
writeFileSync('tests/data/meshopt/streams.bin.gz', gzipSync(Buffer.concat(blob), { level: 9 }));
console.log(`${cases.length} cases, ${blobLength} bytes of streams`);

// ---- a torus GLB and gltfpack's outputs ----
function torusGlb(R, r, nu, nv) {
	const pos = [], nrm = [], uv = [], idx = [];
	for (let i = 0; i <= nu; i++)
		for (let j = 0; j <= nv; j++) {
			const u = (i / nu) * 2 * Math.PI, v = (j / nv) * 2 * Math.PI;
			const cx = Math.cos(u), sx = Math.sin(u), cv = Math.cos(v), sv = Math.sin(v);
			pos.push((R + r * cv) * cx, (R + r * cv) * sx, r * sv);
			nrm.push(cv * cx, cv * sx, sv);
			uv.push(i / nu, j / nv);
		}
	for (let i = 0; i < nu; i++)
		for (let j = 0; j < nv; j++) {
			const a = i * (nv + 1) + j, b = a + nv + 1;
			idx.push(a, b, a + 1, a + 1, b, b + 1);
		}
	const P = new Float32Array(pos), N3 = new Float32Array(nrm), T = new Float32Array(uv), I = new Uint16Array(idx);
	const parts = [P, N3, T, I].map((a) => Buffer.from(a.buffer));
	const views = [], offsets = [];
	let at = 0;
	for (const p of parts) {
		offsets.push(at);
		at += (p.length + 3) & ~3;
	}
	parts.forEach((p, k) => views.push({ buffer: 0, byteOffset: offsets[k], byteLength: p.length, target: k < 3 ? 34962 : 34963 }));
	const lo = [0, 1, 2].map((k) => Math.min(...pos.filter((_, q) => q % 3 === k)));
	const hi = [0, 1, 2].map((k) => Math.max(...pos.filter((_, q) => q % 3 === k)));
	const vcount = P.length / 3;
	const doc = {
		asset: { version: '2.0', generator: 'pmwm_codec tools/make_meshopt_fixtures.mjs' },
		scene: 0,
		scenes: [{ nodes: [0] }],
		nodes: [{ mesh: 0 }],
		meshes: [{ primitives: [{ attributes: { POSITION: 0, NORMAL: 1, TEXCOORD_0: 2 }, indices: 3 }] }],
		accessors: [
			{ bufferView: 0, componentType: 5126, count: vcount, type: 'VEC3', min: lo.map(Math.fround), max: hi.map(Math.fround) },
			{ bufferView: 1, componentType: 5126, count: vcount, type: 'VEC3' },
			{ bufferView: 2, componentType: 5126, count: vcount, type: 'VEC2' },
			{ bufferView: 3, componentType: 5123, count: I.length, type: 'SCALAR' },
		],
		bufferViews: views,
		buffers: [{ byteLength: at }],
	};
	const bin = Buffer.alloc(at);
	parts.forEach((p, k) => p.copy(bin, offsets[k]));
	let json = Buffer.from(JSON.stringify(doc));
	json = Buffer.concat([json, Buffer.alloc((4 - (json.length % 4)) % 4, 0x20)]);
	const head = Buffer.alloc(12);
	head.writeUInt32LE(0x46546c67, 0);
	head.writeUInt32LE(2, 4);
	head.writeUInt32LE(12 + 8 + json.length + 8 + bin.length, 8);
	const chunk = (len, type) => {
		const h = Buffer.alloc(8);
		h.writeUInt32LE(len, 0);
		h.writeUInt32LE(type, 4);
		return h;
	};
	return Buffer.concat([head, chunk(json.length, 0x4e4f534a), json, chunk(bin.length, 0x004e4942), bin]);
}
const dir = 'tests/data/meshopt';
const tmp = mkdtempSync(join(tmpdir(), 'meshopt-'));
writeFileSync(join(tmp, 'torus.glb'), torusGlb(1.0, 0.35, 32, 16));
const gltfpack = process.env.GLTFPACK || 'gltfpack';
for (const [out, args] of [
	['torus_plain.glb', []],
	['torus_c.glb', ['-c']],
	['torus_cc.glb', ['-cc']],
	['torus_cc_khr.glb', ['-cc', '-ce', 'khr']],
	['torus_cf.glb', ['-cf']],
]) {
	execFileSync(gltfpack, ['-i', join(tmp, 'torus.glb'), '-o', `${dir}/${out}`, ...args], { stdio: 'inherit' });
}
rmSync(tmp, { recursive: true });
