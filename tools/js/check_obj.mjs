#!/usr/bin/env node
// three.js's own readers on the OBJ / MTL / PLY files `pmw decode` writes: prints ONE JSON line per file argument.
//
//   node tools/js/check_obj.mjs FILE...
//
// .obj: OBJLoader.parse() of its text and MTLLoader.parse() of each MTL its mtllib records name (looked up beside
//       it; the textures are not loaded: Node has no image decoder, the file names they give are reported):
//   {"file", "ok", "meshes": [{"name", "corners", "position": [...], "uv": [...] | null, "normal": [...] | null,
//     "color": [...] | null, "groups": [{"start", "count", "material"}]}],
//    "materials": {NAME: {"color": [r, g, b], "opacity", "map": FILE | null, "bump": FILE | null,
//      "emissive": [r, g, b] | null, "emissiveMap": FILE | null}}, "error"}
//   (color, emissive: the MTL's Kd, Ke as written; MTLLoader takes them as sRGB when it makes the material)
//   (position / uv / normal / color: the flat arrays OBJLoader builds, a value per corner, as three.js draws them;
//    colours are the linear values three.js decodes the file's sRGB ones to)
// .ply: PLYLoader.parse() of its bytes:
//   {"file", "ok", "vertices", "indices", "attributes": {NAME: itemSize}, "uv": [...] | null,
//    "color": [...] | null, "error"}   (color: linear, in [0, 1], as the shader reads it: PLYLoader decodes the
//    file's sRGB colours and keeps 8-bit ones as linear bytes)
// Exit status: 0 when every file was read (whatever it held), 2 on usage errors.

import fs from 'node:fs';
import path from 'node:path';
import { OBJLoader } from 'three/examples/jsm/loaders/OBJLoader.js';
import { MTLLoader } from 'three/examples/jsm/loaders/MTLLoader.js';
import { PLYLoader } from 'three/examples/jsm/loaders/PLYLoader.js';

// An attribute's values as floats: a normalized integer one (PLYLoader keeps 8-bit colours as bytes, decoded to
// linear) over its type's largest value, as a shader reads it.
function flat(attribute) {
	if (!attribute) return null;
	const values = Array.from(attribute.array);
	if (!attribute.normalized) return values;
	const max = attribute.array instanceof Uint8Array ? 255 : attribute.array instanceof Uint16Array ? 65535 : 1;
	return values.map((v) => v / max);
}

function checkObj(file) {
	const text = fs.readFileSync(file, 'utf8');
	const materials = {};
	for (const line of text.split('\n')) {
		const m = /^mtllib\s+(.+?)\s*$/.exec(line);
		if (!m) continue;
		const mtl = path.join(path.dirname(file), m[1]);
		const creator = new MTLLoader().parse(fs.readFileSync(mtl, 'utf8'), path.dirname(mtl) + '/');
		for (const [name, info] of Object.entries(creator.materialsInfo)) {
			materials[name] = {
				color: info.kd ?? null, opacity: info.d !== undefined ? Number(info.d) : null,
				map: info.map_kd ?? null, bump: info.map_bump ?? info.bump ?? null,
				emissive: info.ke ?? null, emissiveMap: info.map_ke ?? null,
			};
		}
	}
	const group = new OBJLoader().parse(text);
	const meshes = [];
	group.traverse((object) => {
		if (!object.isMesh) return;
		const g = object.geometry;
		const names = Array.isArray(object.material) ? object.material.map((m) => m.name) : [object.material.name];
		meshes.push({
			name: object.name, corners: g.attributes.position.count,
			position: flat(g.attributes.position), uv: flat(g.attributes.uv),
			normal: flat(g.attributes.normal), color: flat(g.attributes.color),
			groups: g.groups.length ? g.groups.map((x) => ({ start: x.start, count: x.count, material: names[x.materialIndex] }))
				: [{ start: 0, count: g.attributes.position.count, material: names[0] }],
		});
	});
	return { meshes, materials };
}

function checkPly(file) {
	const data = fs.readFileSync(file);
	const g = new PLYLoader().parse(data.buffer.slice(data.byteOffset, data.byteOffset + data.byteLength));
	const attributes = {};
	for (const [name, a] of Object.entries(g.attributes)) attributes[name] = a.itemSize;
	return {
		vertices: g.attributes.position.count, indices: g.index ? g.index.count : null, attributes,
		uv: flat(g.attributes.uv), color: flat(g.attributes.color),
	};
}

const files = process.argv.slice(2);
if (!files.length) {
	console.error('usage: node check_obj.mjs FILE...');
	process.exit(2);
}
for (const file of files) {
	let out;
	try {
		out = { file, ok: true, ...(file.toLowerCase().endsWith('.ply') ? checkPly(file) : checkObj(file)) };
	} catch (error) {
		out = { file, ok: false, error: String(error && error.message || error) };
	}
	console.log(JSON.stringify(out));
}
