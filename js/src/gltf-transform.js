/**
 * PMWM_progressive_mesh for glTF-Transform (@gltf-transform/core, an optional peer dependency):
 * a document read with this extension registered keeps every progressive primitive's stream, so
 * `read()` then `write()` of a .pmw gives a .pmw again instead of a plain GLB of the base meshes.
 *
 *   import { NodeIO } from '@gltf-transform/core';
 *   import { PMWMProgressiveMesh } from 'pmwm-progressive/gltf-transform';
 *   const io = new NodeIO().registerExtensions([PMWMProgressiveMesh]);
 *   await writeFile('out.pmw', await io.writeBinary(await io.read('in.pmw')));   // NodeIO.write: GLB for .glb only
 *
 * Read: each progressive primitive gets a `ProgressiveMesh` extension property holding the
 * extension object without the chunks' `bufferView` indices (`getInfo()`: every other property,
 * `firstFaceChunk` among them, kept as read and written back; the chunk entries as header.js's
 * chunkEntries normalises them, `faces` marking face chunks), the stored chunk bytes
 * as read (`getChunks()`: Uint8Array[], one zstd frame each), each chunk's place in the stream
 * (`getStreamOffsets()`: its BIN byte offset in the file read) and a fingerprint of the base mesh.
 *
 * Write: the chunks of all progressive primitives are written as one stream, in the order they had
 * in the file read, as bufferViews placed after every other bufferView of the buffer (glTF-Transform
 * writes accessors, then images, then extension bufferViews: base, document data, chunks, as
 * spec/bitstream.md §4 asks), each starting at a multiple of 4 with zero gaps; the chunk index's
 * `bufferView` entries are rewritten. The payload bytes are never touched.
 *
 * A vertex split names base vertices by index, so the stream is only valid on the exact base mesh it
 * was encoded against. Before writing, the base mesh (POSITION, indices and the attributes the
 * stream carries, values and order) is compared with its fingerprint taken on read; a transform
 * that welded, reordered, simplified, quantized or otherwise changed it makes the write throw
 * `BaseMeshChangedError`. A Draco base (KHR_draco_mesh_compression registered on read) can be written
 * back only as plain accessors: re-encoding it renumbers the vertices, so writing with the Draco
 * extension still in the document throws `BaseMeshChangedError` as well.
 */
import { Extension, ExtensionProperty, Format, PropertyType, VertexLayout } from '@gltf-transform/core';
import { createBLAKE2b } from 'hash-wasm';
import { FormatError, PmwError, TruncatedError } from './errors.js';
import {
  WELD_ATTRIBUTE, baseVertexCount, checkJsonTree, checkPreamble, chunkEntries, parseGlb, planDocument, preambleLength,
} from './header.js';
import { packChunkTable } from './chunktable.js';

/** BLAKE2b-128 (hash-wasm; WebAssembly compiles asynchronously, once, at import). */
const blake = await createBLAKE2b(128);

const NAME = 'PMWM_progressive_mesh';
const DRACO = 'KHR_draco_mesh_compression';
/** Extensions that write bufferViews compressed (a base must be plain bufferViews or Draco). */
const MESHOPT = ['EXT_meshopt_compression', 'KHR_meshopt_compression'];
/** The resource key glTF-Transform gives a GLB's BIN chunk. */
const GLB_BUFFER = '@glb.bin';

/** Writing would break a progressive stream: its base mesh changed since it was read. */
export class BaseMeshChangedError extends PmwError {
  /** @param {string} message @param {{mesh: number, primitive: number}} where */
  constructor(message, where) {
    super(message);
    this.mesh = where.mesh;
    this.primitive = where.primitive;
  }
}

/** The PMWM_progressive_mesh object of one primitive: the stream, kept as read. */
export class ProgressiveMesh extends ExtensionProperty {
  static EXTENSION_NAME = NAME;

  init() {
    this.extensionName = NAME;
    this.propertyType = 'ProgressiveMesh';
    this.parentTypes = [PropertyType.PRIMITIVE];
  }

  getDefaults() {
    return Object.assign(super.getDefaults(), {
      info: null, chunks: [], streamOffsets: [], fingerprint: '', dracoBase: false, packedTable: true,
    });
  }

  /** @returns {object} the extension object, `chunks[k]` without `bufferView` */
  getInfo() { return this.get('info'); }
  setInfo(info) { return this.set('info', info); }
  /** @returns {Uint8Array[]} stored chunk bytes, in this primitive's chunk order */
  getChunks() { return this.get('chunks'); }
  setChunks(chunks) { return this.set('chunks', chunks); }
  /** @returns {number[]} each chunk's BIN byte offset in the file read: its place in the stream */
  getStreamOffsets() { return this.get('streamOffsets'); }
  setStreamOffsets(offsets) { return this.set('streamOffsets', offsets); }
  /** @returns {string} hex BLAKE2b-128 of the base mesh as read (baseFingerprint) */
  getFingerprint() { return this.get('fingerprint'); }
  setFingerprint(fingerprint) { return this.set('fingerprint', fingerprint); }
  /** @returns {boolean} whether the base was stored with KHR_draco_mesh_compression */
  getDracoBase() { return this.get('dracoBase'); }
  setDracoBase(draco) { return this.set('dracoBase', draco); }
  /** @returns {boolean} whether a payload version 2 chunk table is written packed (false: as the JSON arrays it was read in) */
  getPackedTable() { return this.get('packedTable'); }
  setPackedTable(packed) { return this.set('packedTable', packed); }
}

/**
 * Fingerprint of a primitive's base mesh: counts, the names of its attributes, POSITION bytes, indices
 * as uint32 values and the bytes of every attribute the stream carries, in order.
 * @param {import('@gltf-transform/core').Primitive} primitive
 * @param {object} info the extension object (its `attributes[].semantic` are hashed)
 * @returns {{hex: string, vertices: number, faces: number}}
 */
export function baseFingerprint(primitive, info) {
  const position = primitive.getAttribute('POSITION');
  const indices = primitive.getIndices();
  const vertices = position ? position.getCount() : 0;
  const faces = indices ? indices.getCount() / 3 : 0;
  const hash = blake.init();
  const section = (label, array) => {
    const bytes = array ? new Uint8Array(array.buffer, array.byteOffset, array.byteLength) : new Uint8Array(0);
    hash.update(new TextEncoder().encode(`${label}:${bytes.length};`));
    hash.update(bytes);
  };
  // the attribute names too: one added to a progressive base (tangents()) would have no value for a new vertex
  section(`mode ${primitive.getMode()} vertices ${vertices} faces ${faces} attributes ${primitive.listSemantics().sort()} POSITION`,
    position?.getArray());
  section('indices', indices ? Uint32Array.from(indices.getArray()) : null);
  for (const { semantic } of info.attributes ?? []) section(semantic, primitive.getAttribute(semantic)?.getArray());
  // a welded base's weld attribute: changed, the weld would give other vertices than the stream names
  if (primitive.getAttribute(WELD_ATTRIBUTE)) section(WELD_ATTRIBUTE, primitive.getAttribute(WELD_ATTRIBUTE).getArray());
  const hex = hash.digest('hex');
  return { hex, vertices, faces };
}

/** Every progressive primitive of a document: [{mesh, primitive, meshIndex, primitiveIndex, stream}]. */
function progressivePrimitives(document) {
  const out = [];
  document.getRoot().listMeshes().forEach((mesh, meshIndex) => {
    mesh.listPrimitives().forEach((primitive, primitiveIndex) => {
      const stream = primitive.getExtension(NAME);
      if (stream) out.push({ mesh, primitive, meshIndex, primitiveIndex, stream });
    });
  });
  return out;
}

/** Whether a parsed glTF document has a primitive carrying the extension. */
const carriesStream = (json) => (json.meshes ?? []).some((m) => m?.primitives?.some?.((p) => p?.extensions?.[NAME] !== undefined));

/**
 * The decoder's checks of a document glTF-Transform has parsed (src/header.js): the JSON values (checkJsonTree)
 * and every progressive primitive (planDocument: extension objects, chunk tables, every base and chunk range).
 * @returns the plan, or null when no primitive carries the extension
 */
function checkedPlan(context) {
  const json = context.jsonDoc.json;
  if (!carriesStream(json)) return null;
  checkJsonTree(json);
  return planDocument(json, context.jsonDoc.resources[GLB_BUFFER]?.byteLength ?? 0);
}

/**
 * Runs every check the decoder makes of a .pmw's header on its raw bytes (src/header.js parseGlb and
 * planDocument: the GLB framing, the JSON chunk's UTF-8, byte order mark, non-finite numbers and depth, every
 * progressive primitive) and throws the decoder's named error; `PMWMProgressiveMesh.read()` cannot make those
 * glTF-Transform's reader takes before any extension runs (js/README.md). Call it before `io.readBinary(bytes)`
 * to accept exactly the files the decoder accepts. A GLB without the extension passes.
 * @param {Uint8Array} bytes a whole GLB
 */
export function checkPmwHeader(bytes) {
  // bytes that end before the BIN chunk's header: the decoder's TruncatedError (after the preamble's own checks),
  // not the RangeError of a DataView read past them
  if (bytes.length >= 20) checkPreamble(bytes);
  if (bytes.length < preambleLength(bytes)) {
    throw new TruncatedError(`the GLB ended after ${bytes.length} bytes, before its JSON and BIN chunk headers `
      + `(${preambleLength(bytes)} bytes)`, bytes.length, preambleLength(bytes));
  }
  const { gltf, binLength } = parseGlb(bytes);
  if (carriesStream(gltf)) planDocument(gltf, binLength);
}

export class PMWMProgressiveMesh extends Extension {
  static EXTENSION_NAME = NAME;
  extensionName = NAME;
  prereadTypes = [PropertyType.BUFFER];
  prewriteTypes = [PropertyType.BUFFER];

  /**
   * Before glTF-Transform reads the buffers, bufferViews and accessors: the document is checked as the decoder
   * checks it (checkedPlan), so a stream the decoder refuses is refused with its named error, not with the
   * TypeError or RangeError glTF-Transform's own reading of a bad base bufferView or stride would throw.
   * @param {import('@gltf-transform/core').ReaderContext} context
   */
  preread(context, propertyType) {
    if (propertyType === PropertyType.BUFFER) checkedPlan(context);
    return this;
  }

  /** @returns {ProgressiveMesh} a new, empty extension property */
  createProgressiveMesh() {
    return new ProgressiveMesh(this.document.getGraph());
  }

  /**
   * Reads every progressive primitive's stream. The document is first checked as the decoder checks it
   * (checkedPlan, as in preread), so a stream the decoder would refuse is refused here with the same named
   * error, never read short.
   * @param {import('@gltf-transform/core').ReaderContext} context
   */
  read(context) {
    const json = context.jsonDoc.json;
    const plan = checkedPlan(context);
    if (plan === null) return this;
    const bin = context.jsonDoc.resources[GLB_BUFFER];
    for (const { mesh, primitive: index, ext, chunks: placed, payloadVersion, base } of plan.primitives) {
      const primitive = context.meshes[mesh].listPrimitives()[index];
      const entries = chunkEntries(ext, payloadVersion,
        baseVertexCount(json, json.meshes[mesh].primitives[index], ext, `mesh ${mesh} primitive ${index}`));
      const info = { ...ext, chunks: entries.map(({ bufferView, byteOffset, ...entry }) => entry) };
      primitive.setExtension(NAME, this.createProgressiveMesh()
        .setInfo(info).setChunks(placed.map((c) => bin.slice(c.offset, c.offset + c.length)))
        .setStreamOffsets(placed.map((c) => c.offset))
        .setFingerprint(baseFingerprint(primitive, info).hex)
        .setDracoBase(Boolean(base.draco))
        .setPackedTable(!Array.isArray(ext.chunks) && !('byteLengths' in ext.chunks)));
    }
    return this;
  }

  /** Checks every base, then queues the chunks (whole stream, in stream order) as bufferViews. */
  prewrite(context, propertyType) {
    if (propertyType !== PropertyType.BUFFER) return this;
    const root = this.document.getRoot();
    const draco = root.listExtensionsUsed().some((e) => e.extensionName === DRACO);
    const meshopt = root.listExtensionsUsed().find((e) => MESHOPT.includes(e.extensionName))?.extensionName;
    const queued = [];
    const progressive = progressivePrimitives(this.document);
    if (progressive.length && context.options.format !== Format.GLB) {
      throw new FormatError(`${NAME} lives in a GLB's BIN chunk (spec/README.md "Dependencies"), and this write is JSON `
        + `+ .bin (NodeIO.write writes a GLB only for a .glb name): write the bytes of io.writeBinary(doc) to the .pmw, `
        + `or remove the extension (primitive.setExtension('${NAME}', null)) to write a plain .gltf`);
    }
    for (const [owner, { primitive, meshIndex, primitiveIndex, stream }] of progressive.entries()) {
      const where = { mesh: meshIndex, primitive: primitiveIndex };
      const label = `mesh ${meshIndex} primitive ${primitiveIndex}`;
      const now = baseFingerprint(primitive, stream.getInfo());
      if (now.hex !== stream.getFingerprint()) {
        throw new BaseMeshChangedError(`${label}: the base mesh of a ${NAME} primitive changed since it was read `
          + `(now ${now.vertices} vertices, ${now.faces} faces); its vertex splits name base vertices by index, `
          + `so the stream would no longer decode. Transform before encoding, or remove the extension `
          + `(primitive.setExtension('${NAME}', null)) to write a plain glTF.`, where);
      }
      if (stream.getDracoBase() && draco) {
        throw new BaseMeshChangedError(`${label}: the base was read from ${DRACO}; re-encoding it renumbers `
          + `its vertices, which the ${NAME} stream refers to by index. Dispose the ${DRACO} extension `
          + `to write the base as plain accessors.`, where);
      }
      if (meshopt) {
        throw new BaseMeshChangedError(`${label}: ${meshopt} would store the base's bufferViews compressed, and a `
          + `${NAME} base is plain bufferViews or ${DRACO} (spec/README.md "Base mesh"): no reader would read it. `
          + `Dispose the ${meshopt} extension to write the stream.`, where);
      }
      const buffer = primitive.getAttribute('POSITION')?.getBuffer() ?? root.listBuffers()[0];
      // owner: the primitive's place in the document; a primitive two meshes share (mesh.clone()) is written
      // twice, each time with chunks of its own (chunks never overlap)
      stream.getChunks().forEach((bytes, k) => queued.push({ buffer, stream, owner, k, order: stream.getStreamOffsets()[k],
        view: bytes.subarray(0) }));
    }
    queued.sort((a, b) => a.order - b.order);
    // every vertex attribute in a bufferView of its own, tightly packed: the reference reader
    // (pmwm_codec) refuses an interleaved base accessor (byteStride larger than its element)
    if (progressive.length) context.options.vertexLayout = VertexLayout.SEPARATE;
    shareVersion2Views(queued);
    this._queued = queued;
    for (const view of new Set(queued.map((q) => q.view))) {
      const buffer = queued.find((q) => q.view === view).buffer;
      if (!context.otherBufferViews.has(buffer)) context.otherBufferViews.set(buffer, []);
      context.otherBufferViews.get(buffer).push(view);
    }
    return this;
  }

  /** @param {import('@gltf-transform/core').WriterContext} context */
  write(context) {
    const queued = this._queued ?? [];
    this._queued = null;
    const json = context.jsonDoc.json;
    const views = new Map(queued.map((q) => [q, context.otherBufferViewsIndexMap.get(q.view)]));
    for (const buffer of new Set(queued.map((q) => q.buffer))) {
      alignTail(context, context.bufferIndexMap.get(buffer), [...new Set(queued.filter((q) => q.buffer === buffer).map((q) => views.get(q)))]);
    }
    const progressive = progressivePrimitives(this.document);
    if (!progressive.length) json.extensionsUsed = json.extensionsUsed.filter((name) => name !== NAME); // a plain glTF
    for (const [owner, { mesh, primitiveIndex, stream }] of progressive.entries()) {
      const meshDef = json.meshes[context.meshIndexMap.get(mesh)];
      const primitiveDef = meshDef.primitives[primitiveIndex];
      const info = stream.getInfo();
      const placed = info.chunks.map((entry, k) => queued.find((q) => q.owner === owner && q.k === k));
      const chunks = (info.payload?.version ?? 1) === 2
        ? compactChunks(info.chunks.map((entry, k) => ({ ...entry, bufferView: views.get(placed[k]), byteOffset: placed[k].at })),
          stream.getPackedTable())
        : info.chunks.map((entry, k) => ({ bufferView: views.get(placed[k]), ...entry }));
      primitiveDef.extensions = { ...primitiveDef.extensions, [NAME]: { ...info, chunks } };
    }
    return this;
  }
}

/**
 * Payload version 2 chunks lie back to back in one bufferView per buffer (spec/bitstream.md §6.2):
 * gives every queued version 2 chunk (in stream order) the shared view and its offset `at` in it.
 */
function shareVersion2Views(queued) {
  for (const buffer of new Set(queued.map((q) => q.buffer))) {
    const mine = queued.filter((q) => q.buffer === buffer && (q.stream.getInfo().payload?.version ?? 1) === 2);
    const view = new Uint8Array(mine.reduce((n, q) => n + q.view.length, 0));
    let at = 0;
    for (const q of mine) {
      const bytes = q.view;
      view.set(bytes, at);
      Object.assign(q, { view, at });
      at += bytes.length;
    }
  }
}

/**
 * The chunk table (spec/bitstream.md §6.2) of per-chunk entries in one bufferView: packed, or as the
 * JSON arrays when the table was read in that form (its values, hence its MACs, kept as they were).
 */
function compactChunks(entries, packed = true) {
  const table = entries.length ? { bufferView: entries[0].bufferView } : {};
  let sum = 0;
  if (!entries.every((e) => { const ok = e.byteOffset === sum; sum += e.byteLength; return ok; })) {
    table.byteOffsets = entries.map((e) => e.byteOffset);
  }
  if (packed) return Object.assign(table, packChunkTable(entries));
  table.byteLengths = entries.map((e) => e.byteLength);
  table.vertexCounts = entries.map((e) => e.vertexCount);
  table.faceCounts = entries.map((e) => e.faceCount);
  table.geometricErrors = entries.map((e) => e.geometricError);
  table.digests = entries.map((e) => e.digest).join('');
  if (entries.some((e) => e.mac !== undefined)) table.macs = entries.map((e) => e.mac).join('');
  return table;
}

/**
 * Moves the bufferViews from the first chunk's onward (the tail glTF-Transform writes extension
 * bufferViews into, unpadded) so each starts at a multiple of 4, zero-filling the gaps, and fixes
 * the buffer's byteLength and bytes.
 * @param {import('@gltf-transform/core').WriterContext} context
 * @param {number} bufferIndex @param {number[]} chunkViews bufferView indices of the chunks
 */
function alignTail(context, bufferIndex, chunkViews) {
  const json = context.jsonDoc.json;
  const bufferDef = json.buffers[bufferIndex];
  const key = bufferDef.uri ?? '@glb.bin';
  const old = context.jsonDoc.resources[key];
  const start = Math.min(...chunkViews.map((i) => json.bufferViews[i].byteOffset));
  const tail = json.bufferViews.filter((v) => v.buffer === bufferIndex && (v.byteOffset ?? 0) >= start)
    .sort((a, b) => a.byteOffset - b.byteOffset);
  const align = (n) => Math.ceil(n / 4) * 4;
  let end = align(start);
  const placed = tail.map((view) => {
    const at = end;
    end = align(at + view.byteLength);
    return { view, at };
  });
  const bytes = new Uint8Array(end);
  bytes.set(old.subarray(0, start));
  for (const { view, at } of placed) {
    bytes.set(old.subarray(view.byteOffset, view.byteOffset + view.byteLength), at);
    view.byteOffset = at;
  }
  context.jsonDoc.resources[key] = bytes;
  bufferDef.byteLength = end;
}
