import { NodeIO } from '@gltf-transform/core';
import { prune, dedup } from '@gltf-transform/functions';
import { PMWMProgressiveMesh } from './src/gltf-transform.js';
import { jsLevels } from './test/lib/helpers.js';
import fs from 'node:fs';
const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
const bytes = new Uint8Array(fs.readFileSync(process.argv[2]));
async function attempt(what, edit) {
  const doc = await io.readBinary(bytes);
  try {
    await edit(doc);
    const out = await io.writeBinary(doc);
    const r = await jsLevels(out).catch((e) => ({ err: `${e.name}: ${e.message}` }));
    console.log(what, '-> wrote', out.length, r.err ?? `${r.levels.length} levels, complete ${r.end.complete}, parts ${r.levels.at(-1).parts}`);
  } catch (e) { console.log(what, '-> THROWS', e.name, e.message.slice(0, 160)); }
}
await attempt('clone mesh into a 2nd node', (doc) => {
  const mesh = doc.getRoot().listMeshes()[0];
  const copy = mesh.clone();
  doc.getRoot().listScenes()[0].addChild(doc.createNode('copy').setMesh(copy));
});
await attempt('same mesh on 2 nodes', (doc) => {
  const mesh = doc.getRoot().listMeshes()[0];
  doc.getRoot().listScenes()[0].addChild(doc.createNode('copy').setMesh(mesh));
});
await attempt('remove the progressive mesh', (doc) => { doc.getRoot().listMeshes()[0].dispose(); });
await attempt('dispose extension', (doc) => { doc.getRoot().listExtensionsUsed().find((e) => e.extensionName === 'PMWM_progressive_mesh').dispose(); });
await attempt('prune', (doc) => doc.transform(prune()));
await attempt('dedup', (doc) => doc.transform(dedup()));
await attempt('setExtension null', (doc) => { for (const m of doc.getRoot().listMeshes()) for (const p of m.listPrimitives()) p.setExtension('PMWM_progressive_mesh', null); });
await attempt('write gltf (json)', async (doc) => { const { json, resources } = await io.writeJSON(doc); console.log('   json buffers', JSON.stringify(json.buffers), Object.keys(resources)); });
