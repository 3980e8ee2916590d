#!/usr/bin/env node
// Third-party checks of .pmw / .glb files: prints ONE JSON line per file argument.
//
//   node tools/js/check_gltf.mjs FILE...
//
// Each line: {"file", "bytes",
//   "validator": {"errors", "warnings", "infos", "hints", "codes": {CODE: count}, "messages": [...]},
//   "three": {"ok", "meshes", "vertices", "triangles", "radius", "center", "draco", "textures", "mapped",
//             "primitives": [{"mode", "vertices", "indices", "morphTargets",
//                             "attributes": {NAME: [itemSize, normalized, arrayType]}, "box": [min, max],
//                             "flatShading"}],
//             "error"}}
//   (primitives: one entry per THREE.Mesh/Line/Points in traversal order, attribute names as
//   three.js renamed them (position, normal, uv, color, skinIndex, ...; unknown ones keep the
//   glTF name), box: the geometry's own bounding box, in mesh space, from the loaded values,
//   flatShading: its material shades each face flat, as GLTFLoader makes it for a primitive without NORMAL)
//
// validator: Khronos glTF-Validator (npm gltf-validator) on the file bytes (bytes it cannot read as
//            glTF at all, which it throws on: one error, code NOT_GLTF, with its message).
// three:     three.js GLTFLoader.parse() in plain Node on the GLB ArrayBuffer.  The real
//            DRACOLoader needs Web Workers and fetch(), which Node lacks; for
//            KHR_draco_mesh_compression we register a stand-in that has the DRACOLoader
//            interface GLTFLoader calls (preload, decodeDracoFile) and decodes with the
//            Draco decoder three.js ships (examples/jsm/libs/draco/draco_decoder.js),
//            looking attributes up by their unique ids exactly as DRACOLoader's worker does.
//            GLTFLoader itself still builds the id map from the file.
// Exit status: 0 when every file was checked (whatever it contained), 2 on usage errors.

import fs from 'node:fs';
import path from 'node:path';
import vm from 'node:vm';
import { fileURLToPath } from 'node:url';
import { createRequire } from 'node:module';
import validator from 'gltf-validator';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
import { MeshoptDecoder } from 'three/examples/jsm/libs/meshopt_decoder.module.js';

const here = path.dirname(fileURLToPath(import.meta.url));

// A .gltf's data: URI buffers go through three.js's FileLoader (fetch, which Node has), whose
// progress callback builds a ProgressEvent (a DOM class Node lacks): a minimal one.
if (typeof globalThis.ProgressEvent === 'undefined') {
	globalThis.ProgressEvent = class ProgressEvent extends Event {
		constructor(type, { lengthComputable = false, loaded = 0, total = 0 } = {}) {
			super(type);
			Object.assign(this, { lengthComputable, loaded, total });
		}
	};
}

function loadDracoModule() {
	const file = path.join(here, 'node_modules/three/examples/jsm/libs/draco/draco_decoder.js');
	const module = { exports: {} };
	const wrapper = vm.runInThisContext(`(function (module, exports, require, __filename, __dirname) {\n${fs.readFileSync(file, 'utf8')}\n})`);
	wrapper(module, module.exports, createRequire(file), file, path.dirname(file));
	return module.exports();  // a Promise-like resolving to the decoder module
}

// The DRACOLoader methods GLTFLoader uses, running in-process instead of in a worker.
class NodeDracoLoader {
	constructor() { this.draco = null; this.used = false; }
	preload() { return this; }
	async decodeDracoFile(buffer, callback, attributeIDs, attributeTypes, _colorSpace, onError = () => {}) {
		try {
			this.used = true;
			if (!this.draco) this.draco = await loadDracoModule();
			callback(this.decode(new Int8Array(buffer), attributeIDs, attributeTypes));
		} catch (error) {
			onError(error);
		}
	}
	decode(array, attributeIDs, attributeTypes) {
		const draco = this.draco;
		const decoder = new draco.Decoder();
		const mesh = new draco.Mesh();
		try {
			const status = decoder.DecodeArrayToMesh(array, array.byteLength, mesh);
			if (!status.ok() || mesh.ptr === 0) throw new Error('Draco decoding failed: ' + status.error_msg());
			const geometry = new THREE.BufferGeometry();
			const count = mesh.num_points();
			for (const name in attributeIDs) {
				const attribute = decoder.GetAttributeByUniqueId(mesh, attributeIDs[name]);
				if (!attribute || attribute.ptr === 0) throw new Error(`no Draco attribute with unique id ${attributeIDs[name]}`);
				// the typed array GLTFLoader asks for (the accessor's componentType), as DRACOLoader reads it
				const TypedArray = globalThis[attributeTypes[name]];
				const type = { Float32Array: draco.DT_FLOAT32, Int8Array: draco.DT_INT8, Int16Array: draco.DT_INT16,
					Int32Array: draco.DT_INT32, Uint8Array: draco.DT_UINT8, Uint16Array: draco.DT_UINT16, Uint32Array: draco.DT_UINT32 }[attributeTypes[name]];
				if (type === undefined) throw new Error(`attribute type ${attributeTypes[name]} not handled`);
				const size = attribute.num_components();
				const bytes = count * size * TypedArray.BYTES_PER_ELEMENT;
				const ptr = draco._malloc(bytes);
				decoder.GetAttributeDataArrayForAllPoints(mesh, attribute, type, bytes, ptr);
				const data = new TypedArray(draco.HEAPF32.buffer, ptr, count * size).slice();
				draco._free(ptr);
				geometry.setAttribute(name, new THREE.BufferAttribute(data, size));
			}
			const indices = mesh.num_faces() * 3;
			const ptr = draco._malloc(indices * 4);
			decoder.GetTrianglesUInt32Array(mesh, indices * 4, ptr);
			geometry.setIndex(new THREE.BufferAttribute(new Uint32Array(draco.HEAPF32.buffer, ptr, indices).slice(), 1));
			draco._free(ptr);
			return geometry;
		} finally {
			draco.destroy(mesh);
			draco.destroy(decoder);
		}
	}
}

async function validate(bytes) {
	let report;
	try {
		report = await validator.validateBytes(new Uint8Array(bytes), { maxIssues: 1000, externalResourceFunction: () => Promise.reject(new Error('no external resources')) });
	} catch (error) {  // bytes that are neither GLB nor JSON glTF: the validator throws instead of reporting
		return { errors: 1, warnings: 0, infos: 0, hints: 0, codes: { NOT_GLTF: 1 },
			messages: [{ code: 'NOT_GLTF', severity: 0, message: String(error && error.message || error) }] };
	}
	const codes = {};
	for (const m of report.issues.messages) codes[m.code] = (codes[m.code] || 0) + 1;
	return {
		errors: report.issues.numErrors, warnings: report.issues.numWarnings,
		infos: report.issues.numInfos, hints: report.issues.numHints, codes,
		messages: report.issues.messages.slice(0, 20).map((m) => ({ code: m.code, severity: m.severity, message: m.message, pointer: m.pointer, offset: m.offset })),
	};
}

async function loadThree(bytes) {
	const loader = new GLTFLoader();
	const draco = new NodeDracoLoader();
	loader.setDRACOLoader(draco);
	loader.setMeshoptDecoder(MeshoptDecoder);  // EXT/KHR_meshopt_compression (WebAssembly, runs in Node)
	// Node has no image decoder (TextureLoader/ImageBitmapLoader need a DOM): a plugin hands
	// GLTFLoader an empty THREE.Texture per texture index, so materials still resolve their maps.
	let textures = 0;
	loader.register(() => ({ name: 'node_stub_textures', loadTexture: () => { textures += 1; return Promise.resolve(new THREE.Texture()); } }));
	const buffer = bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength);
	const warnings = [];
	const warn = console.warn;
	console.warn = (...args) => warnings.push(args.join(' '));
	try {
		const gltf = await new Promise((resolve, reject) => loader.parse(buffer, '', resolve, reject));
		let meshes = 0, vertices = 0, triangles = 0;
		const box = new THREE.Box3();
		gltf.scene.updateMatrixWorld(true);
		gltf.scene.traverse((object) => {
			if (!object.isMesh) return;
			meshes += 1;
			const g = object.geometry;
			const n = g.attributes.position ? g.attributes.position.count : 0;
			vertices += n;
			triangles += (g.index ? g.index.count : n) / 3;
			box.expandByObject(object);
		});
		const sphere = box.getBoundingSphere(new THREE.Sphere());
		let radius = 0;
		gltf.scene.traverse((object) => {
			if (!object.isMesh || !object.geometry.attributes.position) return;
			const p = object.geometry.attributes.position, v = new THREE.Vector3();
			for (let i = 0; i < p.count; i++) radius = Math.max(radius, v.fromBufferAttribute(p, i).applyMatrix4(object.matrixWorld).distanceTo(sphere.center));
		});
		const primitives = [];
		gltf.scene.traverse((object) => {
			if (!(object.isMesh || object.isLine || object.isPoints)) return;
			const g = object.geometry, attributes = {};
			for (const [name, a] of Object.entries(g.attributes)) attributes[name] = [a.itemSize, a.normalized, a.array.constructor.name];
			g.computeBoundingBox();
			const box = g.attributes.position ? [g.boundingBox.min.toArray(), g.boundingBox.max.toArray()] : null;
			primitives.push({ mode: object.type, vertices: g.attributes.position ? g.attributes.position.count : 0,
				indices: g.index ? g.index.count : null, morphTargets: Object.keys(g.morphAttributes).length ? (g.morphAttributes.position || []).length : 0,
				attributes, box, flatShading: Boolean(object.material && !Array.isArray(object.material) && object.material.flatShading) });
		});
		let mapped = 0;
		gltf.scene.traverse((object) => { if (object.isMesh && object.material && object.material.map) mapped += 1; });
		return { ok: true, meshes, vertices, triangles, radius, center: sphere.center.toArray(), draco: draco.used, textures, mapped, primitives, warnings };
	} catch (error) {
		return { ok: false, error: String(error && error.message || error), draco: draco.used, warnings };
	} finally {
		console.warn = warn;
	}
}

const files = process.argv.slice(2);
if (files.length === 0) {
	process.stderr.write('usage: node check_gltf.mjs FILE...\n');
	process.exit(2);
}
for (const file of files) {
	const bytes = fs.readFileSync(file);
	const result = { file, bytes: bytes.length, validator: await validate(bytes), three: await loadThree(bytes) };
	process.stdout.write(JSON.stringify(result) + '\n');
}
