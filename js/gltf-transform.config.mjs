/**
 * A configuration for the glTF-Transform command line (@gltf-transform/cli 4) that keeps .pmw streams:
 *
 *   gltf-transform copy in.pmw out.pmw --config node_modules/pmwm-progressive/gltf-transform.config.mjs
 *
 * - Registers the CLI's usual extensions plus PMWMProgressiveMesh, so a command that reads and writes
 *   a .pmw keeps the PMWM_progressive_mesh stream (every chunk, byte for byte, in stream order)
 *   instead of dropping it. A command that changes a progressive base mesh (weld, reorder, simplify,
 *   quantize, draco, optimize...) fails with BaseMeshChangedError and writes nothing.
 * - Writes an output named `*.pmw` as a binary glTF (GLB), as it writes `*.glb`; without this the CLI
 *   writes any name other than .glb as JSON glTF plus a separate .bin, which is no longer a .pmw.
 *
 * Draco bases: the CLI decodes KHR_draco_mesh_compression on read and drops it (every command), so
 * the base is written as plain accessors: the same vertices in the same order, a larger base; the
 * stream, its MACs and every level decode the same.
 */
import { writeFile } from 'node:fs/promises';
import { ALL_EXTENSIONS } from '@gltf-transform/extensions';
import { PMWMProgressiveMesh } from './src/gltf-transform.js';

/** Makes `io.write(uri, doc)` write GLB for a `.pmw` uri (and note its size, as the CLI reports it). */
export function writePmwAsGlb(io) {
  const write = io.write.bind(io);
  io.write = async (uri, doc) => {
    if (!/\.pmw$/i.test(uri)) return write(uri, doc);
    const bytes = await io.writeBinary(doc);
    await writeFile(uri, bytes);
    io.lastWriteBytes = bytes.byteLength;
  };
  return io;
}

export default {
  extensions: [...ALL_EXTENSIONS, PMWMProgressiveMesh],
  onProgramReady: ({ io }) => { writePmwAsGlb(io); },
};
