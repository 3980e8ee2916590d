/**
 * The Draco step in Node, through the `draco3d` npm package (its WebAssembly decoder).
 * Any object with the same `decode` method can stand in (e.g. one built on three.js' DRACOLoader
 * worker in a browser): see `DracoDecoder` in decoder.js.
 */
import { createRequire } from 'node:module';
import { DracoError, FormatError } from './errors.js';

/**
 * draco3d's decoder module factory, required alone: `import draco3d from 'draco3d'` loads the package's
 * main file, which requires the encoder's Emscripten glue too, through Node's CommonJS-from-ESM path
 * (its export scan of the source): about 4 ms more of a first decode that never encodes.
 */
const createDecoderModule = createRequire(import.meta.url)('draco3d/draco_decoder_nodejs.js');

let modulePromise = null;

/** Draco's integer data types: the DT_ constant's name, the heap view that reads it, its glTF componentType. */
const INTEGER_TYPES = [['DT_INT8', 'HEAP8', 5120], ['DT_UINT8', 'HEAPU8', 5121], ['DT_INT16', 'HEAP16', 5122],
  ['DT_UINT16', 'HEAPU16', 5123], ['DT_INT32', 'HEAP32', null], ['DT_UINT32', 'HEAPU32', 5125]];

/**
 * One attribute's values for all points: an integer attribute as its integers (read in its own type, never
 * normalized, as DracoPy reads them), anything else converted to float32; `dataType` the glTF componentType its
 * data has (5126 for float32), or null for another type (which no base accessor names).
 */
function copyAttribute(m, decoder, mesh, id, what) {
  const attr = decoder.GetAttributeByUniqueId(mesh, id);
  if (!attr || attr.ptr === 0) throw new DracoError(`Draco base mesh has no attribute with unique id ${id} (${what})`);
  const k = attr.num_components();
  const count = mesh.num_points() * k;
  const type = attr.data_type();
  const integer = INTEGER_TYPES.find(([dt]) => m[dt] === type);
  const heap = integer ? m[integer[1]] : m.HEAPF32;
  const bytes = count * heap.BYTES_PER_ELEMENT;
  const ptr = m._malloc(bytes);
  try {
    if (!decoder.GetAttributeDataArrayForAllPoints(mesh, attr, integer ? type : m.DT_FLOAT32, bytes, ptr)) {
      throw new DracoError(`Draco attribute ${id} (${what}) does not convert to its values`);
    }
    const view = new heap.constructor(heap.buffer, ptr, count);
    return { values: integer ? Float64Array.from(view) : view.slice(), components: k,
      dataType: integer ? integer[2] : type === m.DT_FLOAT32 ? 5126 : null };
  } finally {
    m._free(ptr);
  }
}

/** A Draco decoder on `draco3d`: decode(bytes, {positionId, attributeIds}) -> {positions, attributes, indices}. */
export function createNodeDracoDecoder() {
  return {
    async decode(bytes, { positionId, attributeIds = [] }) {
      modulePromise ??= createDecoderModule({});
      const m = await modulePromise;
      const decoder = new m.Decoder();
      const buffer = new m.DecoderBuffer();
      const mesh = new m.Mesh();
      try {
        buffer.Init(new Int8Array(bytes.buffer, bytes.byteOffset, bytes.byteLength), bytes.byteLength);
        if (decoder.GetEncodedGeometryType(buffer) !== m.TRIANGULAR_MESH) throw new DracoError('Draco data is not a triangle mesh');
        const status = decoder.DecodeBufferToMesh(buffer, mesh);
        if (!status.ok()) throw new DracoError(`Draco decoding failed: ${status.error_msg()}`);
        const faces = mesh.num_faces();
        const ptr = m._malloc(faces * 12);
        let indices;
        try {
          decoder.GetTrianglesUInt32Array(mesh, faces * 12, ptr);
          indices = new Uint32Array(m.HEAPU32.buffer, ptr, faces * 3).slice();
        } finally {
          m._free(ptr);
        }
        const position = copyAttribute(m, decoder, mesh, positionId, 'POSITION');
        if (position.components !== 3) throw new DracoError('Draco POSITION does not have 3 components');
        if (position.dataType !== 5126) throw new FormatError('base mesh: the Draco POSITION is not a float attribute');
        const attributes = attributeIds.map((id) => copyAttribute(m, decoder, mesh, id, `attribute ${id}`));
        return { positions: position.values, attributes, indices };
      } catch (e) {
        if (e instanceof DracoError) throw e;
        throw new DracoError(`Draco decoding failed (${e?.message ?? e})`);
      } finally {
        m.destroy(mesh);
        m.destroy(buffer);
        m.destroy(decoder);
      }
    },
  };
}
