/**
 * three.js GLTFLoader plugin for PMWM_progressive_mesh: the base shows at once, chunks refine it in place.
 *
 *   loader.register((parser) => new PMWMProgressivePlugin(parser, { url, onChunk }));
 *   const gltf = await loader.loadAsync(url);       // or: await loadProgressive(loader, url, options)
 *   await gltf.userData.pmwm.done;                   // {complete, chunksApplied, bytesFetched, ...}
 *   (the outcome's complete: the whole file read and every chunk drawn; the decoder's: its input was whole)
 *
 * three.js reads the base mesh itself (the extension is optional). When three.js holds the whole file
 * (GLTFLoader.load downloads it whole, or parse() was given it), the plugin decodes the stream from those bytes
 * (three.js' JSON text and BIN chunk: heldFile), fetching nothing. Else it reads the stream
 * from `options.url` (default: the URL the loader was given, when `loadProgressive` is used):
 * by HTTP `Range` requests when the server honours them, three whatever the number of chunks (requestEnd; the
 * Python reader, pmwm_codec.http.plan_ranges, makes the same): the preamble, the JSON with the BIN chunk header, then
 * all it needs after them in one answer, the base and the chunks in stream order up to the end of the last chunk it
 * needs (nothing after it is requested: readEnd), else as one `fetch` stream. Either way the answer's body is fed to
 * the decoder as it arrives, so each chunk is applied as soon as its own bytes are in. Each
 * applied chunk rewrites the primitive's BufferGeometry (arrays grown by doubling with the levels,
 * at most to the full resolution; draw range grown) and calls `onChunk`. Stops: `maxChunks`, `maxGeometricError`
 * (the first chunk whose geometricError is at most this), `byteBudget` (the chunks that end within it: no byte past
 * it is used, but the base is: below it, the base is the level shown). A stop, a stop condition or a failure cancels
 * the rest of the answer being read; `stop()` (or `options.signal` aborting) aborts the request in flight at once. A
 * Range answer shorter than asked is followed by a request for the rest. A request that brings nothing (head, or next
 * body bytes) for `stallTimeout` ms (default 30 s, STALL_TIMEOUT_MS; 0: no limit) is aborted: a FetchError. The levels
 * decoded before a failure stay drawn; `done` rejects with it (HTTP and network failures, stalls: FetchError).
 * The stream must be the document three.js parsed (its PMWM_progressive_mesh objects), else StreamMismatchError
 * before anything is drawn. What onBase,
 * onChunk, onDone throw goes to onCallbackError (else console.error), never failing the load.
 * `loadProgressive(loader, url)` reads the bytes up to the base first and has three.js show that base before any
 * chunk is read; the plugin then reads on from the same answer (its chunks already on their way). Decoding
 * (`worker`): in a module Worker (decode-worker.js) when the header's full vertex count exceeds `workerThreshold`
 * (default 100,000) or `worker: true`; on the main thread when `worker: false`, below the threshold, or when no
 * worker starts (Node: no Worker global); the same levels, arrays and named errors either way (worker-decoder.js).
 */
import { Box3, BufferAttribute, LoaderUtils, Sphere } from 'three';
import { chunkLimit, reportCallbackError, shown } from './decoder.js';
import { FetchError, FormatError, PmwError, StreamMismatchError, TruncatedError } from './errors.js';
import { checkPreamble, glbHead, parseGlb, planDocument, preambleLength } from './header.js';
import { createDecoder, threeName } from './worker-decoder.js';

export const EXTENSION_NAME = 'PMWM_progressive_mesh';

export class PMWMProgressivePlugin {
  /**
   * @param {object} parser the GLTFParser
   * @param {{url?: string, range?: boolean, maxChunks?: number, maxGeometricError?: number,
   *   byteBudget?: number, onBase?: Function, onChunk?: Function, onDone?: Function, onCallbackError?: Function,
   *   fetch?: Function, signal?: AbortSignal, stallTimeout?: number, prefix?: Uint8Array, rest?: AsyncIterator,
   *   count?: object, worker?: 'auto'|boolean, workerThreshold?: number, workerUrl?: string|URL}} options
   *   onChunk({chunk, chunksTotal, vertexCount, faceCount, bytesRead, bytesFetched, requests})
   *   prefix, rest, count: loadProgressive's (the bytes it read, the body it reads on from, its counts)
   *   worker: 'auto' (default: a worker above workerThreshold vertices), true, false (main thread);
   *   workerUrl: the decode-worker.js to start (default: next to this module)
   */
  constructor(parser, options = {}) {
    this.parser = parser;
    this.name = EXTENSION_NAME;
    this.options = options;
  }

  async afterRoot(gltf) {
    const targets = await progressiveTargets(this.parser, gltf);
    if (!targets.length) return;
    // the whole file three.js read (GLTFLoader.load, or parse() of it): the stream is there, not fetched again
    const held = this.options.rest ? null : heldFile(this.parser);
    const run = new ProgressiveRun(targets, held ? { ...this.options, held } : this.options, this.parser.json);
    gltf.userData = gltf.userData ?? {};
    gltf.userData.pmwm = run;
    run.done = run.start();
    run.done.catch(() => {}); // the caller awaits run.done for the outcome; never an unhandled rejection
  }
}

/**
 * [{mesh: index, primitive: index, prim, objects: [three.Mesh]}] of every progressive primitive, in
 * mesh/primitive order (the decoder's primitive order): the meshes of every scene, and those of no scene
 * loaded here (the stream holds their chunks: their bases decode, their geometries refine unseen).
 */
async function progressiveTargets(parser, gltf) {
  const byKey = new Map();
  const add = (object) => {
    let assoc = parser.associations.get(object);
    if (assoc?.meshes === undefined) assoc = instancedAssociation(parser, object) ?? assoc;
    if (!object.isMesh || !assoc || assoc.meshes === undefined) return;
    const prim = parser.json.meshes?.[assoc.meshes]?.primitives?.[assoc.primitives ?? 0];
    if (!prim?.extensions?.[EXTENSION_NAME]) return;
    const key = `${assoc.meshes}/${assoc.primitives ?? 0}`;
    if (!byKey.has(key)) byKey.set(key, { mesh: assoc.meshes, primitive: assoc.primitives ?? 0, prim, objects: [] });
    byKey.get(key).objects.push(object);
  };
  for (const scene of gltf.scenes ?? [gltf.scene]) scene.traverse(add);
  const unseen = new Set();
  (parser.json.meshes ?? []).forEach((mesh, m) => mesh?.primitives?.forEach((prim, p) => {
    if (prim?.extensions?.[EXTENSION_NAME] && !byKey.has(`${m}/${p}`)) unseen.add(m);
  }));
  for (const m of unseen) (await parser.getDependency('mesh', m)).traverse(add);
  return [...byKey.values()].sort((a, b) => a.mesh - b.mesh || a.primitive - b.primitive);
}

/**
 * {meshes, primitives} of an InstancedMesh three.js built for a node with EXT_mesh_gpu_instancing, else undefined. Its
 * GLTFMeshGpuInstancing makes new objects, associated with the node only ({nodes}: the node's object, when its mesh
 * has one primitive) or not at all (the children of the node's Group, one per primitive in order), and the
 * associations of the meshes they replace are dropped once the scene is loaded.
 */
function instancedAssociation(parser, object) {
  if (!object.isInstancedMesh) return undefined;
  const own = parser.associations.get(object)?.nodes !== undefined;
  const node = parser.associations.get(own ? object : object.parent)?.nodes;
  const def = parser.json.nodes?.[node];
  if (def?.mesh === undefined || !def.extensions?.EXT_mesh_gpu_instancing) return undefined;
  return { meshes: def.mesh, primitives: own ? 0 : object.parent.children.indexOf(object) };
}

/**
 * One progressive load: reads the stream, feeds a decoder (PmwDecoder or WorkerDecoder), refreshes the geometries.
 * `json`: the document three.js parsed (parser.json); the stream must hold the same PMWM_progressive_mesh objects.
 */
export class ProgressiveRun {
  #wants = null;

  constructor(targets, options, json = null) {
    this.targets = targets;
    this.options = options;
    this.json = json;
    this.checked = false;
    this.levels = [];
    // {bytesFetched, requests}: loadProgressive's own, which counts the requests it made for the base too
    this.count = options.count ?? { bytesFetched: 0, requests: 0 };
    this.stopped = false;
    // aborts the request in flight on stop(); loadProgressive's own (its streamed GET's body) when it made one
    this.controller = options.controller ?? new AbortController();
    this.net = network(this.controller, options.stallTimeout);
    const maxChunks = checkStops(options);
    const { worker = 'auto', workerThreshold, workerUrl, signal } = options;
    this.decoder = createDecoder({ bases: threeDracoBases(targets), maxChunks, worker, workerThreshold, workerUrl });
    if (signal?.aborted) this.stop();
    else if (signal) {
      const onAbort = () => this.stop();
      signal.addEventListener('abort', onAbort, { once: true });
      this.unlink = () => signal.removeEventListener('abort', onAbort);
    }
  }

  /** The body bytes received so far, those loadProgressive read for the base included. */
  get bytesFetched() { return this.count.bytesFetched; }

  /** The HTTP requests made so far, loadProgressive's included. */
  get requests() { return this.count.requests; }

  /**
   * Stops: the request in flight is aborted at once (no more bytes are awaited), no chunk after the level
   * shown is applied, and `done` resolves with the outcome (`stopped: true`). The base that loadProgressive
   * already holds is still made level 0.
   */
  stop() {
    if (this.stopped) return;
    this.stopped = true;
    this.controller.abort();
  }

  /**
   * The bytes this run may feed: up to readEnd (the end of the last chunk wanted), which is never before the
   * first chunk (preamble, JSON, base: what three.js shows), so a budget below the base gives that base as level 0.
   * A chunk past them is never fed (never applied, nor its digest checked), whatever pieces a streamed GET brings.
   */
  byteLimit() {
    const { plan, header, received } = this.decoder;
    if (!plan) return preambleLength(receivedBytes(this)); // the header first: then the limit is known
    if (this.stopped) return Math.max(baseEnd(header, plan), received); // stopped: the base (held) and no chunk more
    return this.#wanted().end;
  }

  /**
   * {chunks, end}: the number of chunks this run reads (chunksWanted) and where their bytes end (readEnd), once the
   * header is parsed; found once (the options and the plan stay), as the parts are fed one by one.
   */
  #wanted() {
    const { header, plan } = this.decoder;
    const { options } = this;
    this.#wants ??= { chunks: chunksWanted(plan, header.binStart, options), end: readEnd(header, plan, options) };
    return this.#wants;
  }

  async start() {
    const o = this.options;
    const fetchFn = o.fetch ?? globalThis.fetch.bind(globalThis);
    const source = o.rest ? continueReader(o.prefix, o.rest, this)
      : o.held ? heldPieces(o.held, this)
        : readStream(o.url, fetchFn, o.range ?? true, this);
    let end;
    try {
      for await (const piece of source) {
        if (this.stopped && this.levels.length) break; // the prefix loadProgressive holds still makes the base
        const results = await this.decoder.feed(piece);
        if (!this.checked && this.decoder.header) this.#checkDocument(); // before any base is decoded
        for (const r of results) { // a chunk failed after them: those levels still show
          // stopped meanwhile (by onChunk of an earlier level of this piece, or during the feed): none after the level drawn
          if (this.stopped && this.levels.length) break;
          this.#level(r);
        }
        if (this.decoder.error || this.#enough()) break;
      }
      end = await this.decoder.close().catch((e) => {
        // stopped before the base reached the decoder (a plugin of the caller's): three.js' base stays
        if (this.stopped && !this.levels.length && !this.decoder.error && e instanceof TruncatedError) {
          const { header, plan, received } = this.decoder;
          return { complete: false, bytesReceived: received, totalLength: header?.length ?? null, chunksApplied: 0,
            chunkCount: plan?.stream.length ?? null };
        }
        throw e;
      });
    } finally {
      this.unlink?.();
      this.decoder.dispose?.();
      this.#release();
    }
    // stopped with levels of the last piece decoded but not drawn: the outcome is the level drawn
    const shown = this.levels.at(-1)?.chunk;
    if (shown !== undefined && shown < end.chunksApplied) end = { ...end, chunksApplied: shown };
    // the decoder's complete says the bytes fed are the whole file; the outcome's, that the model is the full one
    const full = end.complete && end.chunksApplied === end.chunkCount;
    const outcome = { ...end, complete: full, bytesFetched: this.bytesFetched, requests: this.requests, levels: this.levels.length,
      workerLevels: this.decoder.workerLevels ?? 0, stopped: this.stopped };
    this.#call(o.onDone, outcome);
    return outcome;
  }

  /** Calls a callback of the caller's: what it throws is reported (onCallbackError, else console.error), not the run's failure. */
  #call(callback, event) {
    if (!callback) return;
    try {
      callback(event);
    } catch (e) {
      reportCallbackError(this.options.onCallbackError, e);
    }
  }

  /**
   * The stream's header is in: its PMWM_progressive_mesh objects (each primitive's, with their fileId, baseDigest
   * and chunk digests) must be those of the document three.js parsed, else StreamMismatchError (nothing drawn).
   */
  #checkDocument() {
    this.checked = true;
    if (!this.json) return;
    if (progressiveObjects(this.decoder.header.gltf) !== progressiveObjects(this.json)) {
      throw new StreamMismatchError(`${this.options.url}: the stream there is not the document three.js parsed (their `
        + `${EXTENSION_NAME} objects differ): the model is left as three.js loaded it`, this.options.url);
    }
  }

  /**
   * The stream ended: the run (gltf.userData.pmwm, kept as long as the gltf) keeps only the decoder's
   * header, plan and counts; its bytes and arrays (several times the geometry's size) and the prefix go.
   */
  #release() {
    const { header, plan, received, chunksApplied, workerLevels } = this.decoder;
    this.decoder = { header, plan, received, chunksApplied, workerLevels };
    this.options = { ...this.options, prefix: undefined, rest: undefined, controller: undefined, held: undefined };
    this.json = null;
  }

  #enough() {
    const plan = this.decoder.plan;
    if (!plan || !this.levels.length) return false;
    const want = this.#wanted().chunks;
    return want < plan.stream.length && this.decoder.chunksApplied >= want; // all of them: read on to the end
  }

  /**
   * Draws level `r` and reports it. Its `mesh.parts[p]`: primitive p's arrays at that level when the level changed it
   * (the base: every primitive), else null: that geometry is left as it is (no copy, no upload), as on many
   * primitives a level refines one.
   */
  #level(r) {
    const { mesh } = r;
    const { primitives } = this.decoder.plan;
    for (const t of this.targets) {
      const p = primitives.findIndex((q) => q.mesh === t.mesh && q.primitive === t.primitive);
      if (!mesh.parts[p]) continue;
      const geometries = new Set(t.objects.map((o) => o.geometry));
      for (const g of geometries) refreshGeometry(g, mesh.parts[p], primitives[p].vertexCount, primitives[p].faceCount);
      for (const o of t.objects) { // an InstancedMesh keeps bounds of its own, computed once: computed again from the level
        if (o.isInstancedMesh) o.boundingSphere = o.boundingBox = null;
      }
    }
    const event = { ...r, bytesFetched: this.bytesFetched, requests: this.requests };
    delete event.mesh;
    this.levels.push(event);
    this.#call(r.chunk === 0 ? this.options.onBase : this.options.onChunk, event);
  }
}

/** The PMWM_progressive_mesh objects of a glTF document, where they are, as one string (the same JSON: the same string). */
function progressiveObjects(json) {
  const found = [json?.extensions?.[EXTENSION_NAME] ?? null];
  (json?.meshes ?? []).forEach((mesh, m) => mesh?.primitives?.forEach((prim, p) => {
    const ext = prim?.extensions?.[EXTENSION_NAME];
    if (ext) found.push([m, p, ext]);
  }));
  return JSON.stringify(found);
}

/**
 * Writes one level into `geometry`: draw range = the faces now, in arrays that hold at least the
 * level. They start at the first level's size and, when a level outgrows them, are replaced by ones
 * of twice the capacity (or the level's size, when more), at most the full mesh's capV vertices /
 * capF faces: memory and GPU buffers follow the levels decoded, not the counts a file declares (a
 * file may declare far more than its chunks reach; it is refused only at the chunk that fails to
 * reach them). A replacement disposes of the geometry first, which frees the GPU buffers of the
 * arrays it replaces (the first one: three.js' base arrays); the next render uploads the new ones.
 * Doubling keeps the replacements few (log2 of full / base size) and each upload at most twice the
 * level's size (three.js uploads a whole attribute when it changes).
 */
export function refreshGeometry(geometry, part, capV, capF) {
  const n = part.positions.length / 3;
  const faces = part.indices.length / 3;
  const had = geometry.userData.pmwmCapacity;
  if (!had || n > had.vertices || faces > had.faces) {
    const grown = (need, have, cap) => (need <= have ? have : Math.min(Math.max(need, 2 * have), Math.max(need, cap)));
    const vertices = grown(n, had?.vertices ?? 0, capV);
    const faceCapacity = grown(faces, had?.faces ?? 0, capF);
    geometry.dispose(); // frees the GPU buffers of the arrays replaced here, if drawn; the next render uploads these
    if (!had) {
      // an attribute the stream does not carry has no value for a new vertex: dropped, as the reference
      // writer drops it from a level (normals are recomputed below)
      const carried = new Set(['position', 'normal', ...Object.keys(part.attributes).map(threeName)]);
      for (const [name, attribute] of Object.entries(geometry.attributes)) {
        if (!carried.has(name) && !attribute.isInstancedBufferAttribute) geometry.deleteAttribute(name); // per instance: kept
      }
    }
    if (!had || vertices !== had.vertices) {
      geometry.setAttribute('position', new BufferAttribute(new Float32Array(vertices * 3), 3));
      for (const [semantic, values] of Object.entries(part.attributes)) {
        const k = values.length / n || 1;
        geometry.setAttribute(threeName(semantic), new BufferAttribute(new Float32Array(vertices * k), k));
      }
      const normal = geometry.getAttribute('normal');
      if (!part.attributes.NORMAL && normal && normal.count !== vertices) { // three.js' base normals, recomputed per level
        geometry.setAttribute('normal', new BufferAttribute(new Float32Array(vertices * 3), 3));
      }
    }
    if (!had || faceCapacity !== had.faces) geometry.setIndex(new BufferAttribute(new Uint32Array(faceCapacity * 3), 1));
    geometry.userData.pmwmCapacity = { vertices, faces: faceCapacity };
  }
  const write = (attr, values) => { attr.array.set(values); attr.needsUpdate = true; };
  write(geometry.getAttribute('position'), part.positions);
  write(geometry.index, part.indices);
  for (const [semantic, values] of Object.entries(part.attributes)) {
    write(geometry.getAttribute(threeName(semantic)), values);
  }
  geometry.setDrawRange(0, part.indices.length);
  if (!part.attributes.NORMAL && geometry.getAttribute('normal')) geometry.computeVertexNormals();
  boundLevel(geometry, part.positions);
  geometry.userData.pmwmLevel = { vertices: n, faces: part.indices.length / 3 };
}

/**
 * The bounding box and sphere of a level's `positions` (n*3): three.js' computeBounding* would read the
 * whole attribute, whose unused capacity (zeros) pulls the volumes to the origin.
 */
function boundLevel(geometry, positions) {
  const box = (geometry.boundingBox ??= new Box3()).setFromArray(positions);
  const sphere = geometry.boundingSphere ??= new Sphere();
  const { x, y, z } = box.getCenter(sphere.center);
  let far = 0;
  for (let i = 0; i < positions.length; i += 3) {
    far = Math.max(far, (positions[i] - x) ** 2 + (positions[i + 1] - y) ** 2 + (positions[i + 2] - z) ** 2);
  }
  sphere.radius = Math.sqrt(far);
}

/** The Draco base meshes three.js decoded (copies, in plan order), for dracoFromBases. */
function threeDracoBases(targets) {
  return targets.filter((t) => t.prim.extensions?.KHR_draco_mesh_compression).map((t) => {
    const { geometry } = t.objects[0];
    return { ids: t.prim.extensions.KHR_draco_mesh_compression.attributes, indices: Uint32Array.from(geometry.index.array),
      attrs: Object.fromEntries(Object.entries(geometry.attributes).map(([k, a]) =>
        [k, { values: attributeValues(a), components: a.itemSize }])) };
  });
}

/**
 * The values of a three.js attribute (count*itemSize), read through its stride: DRACOLoader stores an
 * attribute of 1- or 2-byte components (the weld attribute, _PMWM_WELD) interleaved, 4 bytes a vertex.
 */
function attributeValues(a) {
  if (!a.isInterleavedBufferAttribute) return Float32Array.from(a.array);
  const { array, stride } = a.data;
  const k = a.itemSize;
  const out = new Float32Array(a.count * k);
  for (let i = 0; i < a.count; i++) {
    for (let c = 0; c < k; c++) out[i * k + c] = array[i * stride + a.offset + c];
  }
  return out;
}

/** What a network wait gives when the run (or load) was stopped or aborted meanwhile: the caller ends quietly. */
const STOPPED = Symbol('stopped');

/** Milliseconds a request may go without bringing anything (its answer's head, or the next bytes of its body) by default. */
export const STALL_TIMEOUT_MS = 30000;

/**
 * What the network waits of one load share: `signal`, whose abort ends them quietly (STOPPED), and `stallTimeout`
 * (ms; 0 or Infinity: none), past which a wait aborts `controller` (the request, its body) and fails with a FetchError.
 */
function network(controller, stallTimeout = STALL_TIMEOUT_MS) {
  if (typeof stallTimeout !== 'number' || !(stallTimeout >= 0)) {
    throw new RangeError(`stallTimeout must be a number of milliseconds >= 0 (0: no limit), not ${shown(stallTimeout)}`);
  }
  return { signal: controller.signal, stallTimeout, abort: (reason) => controller.abort(reason) };
}

/**
 * The chunk limit of `options` (chunkLimit: `maxChunks`, or `chunks`), once its stops are checked: a RangeError
 * naming the first that is not what it says: the chunk limit a whole number >= 0, `byteBudget` a number of bytes
 * >= 0 and `maxGeometricError` a number >= 0 (Infinity allowed, or absent). Called before anything is fetched (a
 * budget of 'abc' made every later offset NaN, and the load showed the base as if stopped there; a maxChunks of -1
 * was refused only by the decoder, after the requests for the base, and 1.5 crashed on a chunk index).
 */
function checkStops(options) {
  const maxChunks = chunkLimit(options);
  const { byteBudget, maxGeometricError } = options;
  for (const [name, value, unit] of [['byteBudget', byteBudget, 'a number of bytes'], ['maxGeometricError', maxGeometricError, 'a number']]) {
    if (value !== undefined && (typeof value !== 'number' || !(value >= 0))) {
      throw new RangeError(`${name} must be ${unit} >= 0 (or Infinity), not ${shown(value)}`);
    }
  }
  return maxChunks;
}

/**
 * `promise`'s value (one wait for the network: a fetch's answer, one read of a body), or STOPPED as soon as
 * `net.signal` aborts (the promise is left to settle unseen: a fetch or read that ignores the signal is not waited
 * for). A rejection is the network's failure: a FetchError (`.cause` the fetch API's error), or STOPPED when the
 * signal aborted. A wait longer than `net.stallTimeout` is a stall: the request is aborted, a FetchError.
 */
function guard(promise, net, url) {
  const { signal, stallTimeout: ms } = net;
  return new Promise((resolve, reject) => {
    if (signal.aborted) {
      promise.catch(() => {});
      resolve(STOPPED);
      return;
    }
    let timer = null;
    const settled = () => {
      clearTimeout(timer); // also when aborted: a promise that ignores the signal may never settle
      signal.removeEventListener('abort', onAbort);
    };
    const onAbort = () => {
      settled();
      resolve(STOPPED);
    };
    signal.addEventListener('abort', onAbort, { once: true });
    if (ms > 0 && ms < 2 ** 31) {
      timer = setTimeout(() => {
        const stalled = new FetchError(`${url}: no bytes came for ${ms / 1000} s (stallTimeout): the request was aborted`,
          { url });
        reject(stalled); // before the abort, whose STOPPED comes too late
        net.abort(stalled);
      }, ms);
    }
    promise.then(resolve, (e) => (signal.aborted ? resolve(STOPPED) : reject(networkError(url, e)))).finally(settled);
  });
}

/**
 * The body of the answer `res`, piece by piece as it arrives (each read one wait: the stall timeout bounds the time
 * between pieces, not the whole body), at most `limit` bytes (more is cancelled, unread), each piece's bytes counted in
 * `count.bytesFetched`. Ends quietly when `net.signal` aborts; ending the iteration early cancels the rest of the body.
 */
async function* bodyPieces(res, net, url, limit, count) {
  if (!res.body?.getReader) { // a fetch of the caller's whose answers have no body stream: one wait
    const body = await guard(res.arrayBuffer(), net, url);
    if (body === STOPPED) return;
    const piece = new Uint8Array(body, 0, Math.min(body.byteLength, limit));
    count.bytesFetched += piece.length;
    yield piece;
    return;
  }
  const reader = res.body.getReader();
  let done = false;
  try {
    for (let left = limit; ;) {
      // (a read after `limit` bytes: the body's end, the connection kept for the next request, or bytes not asked for)
      const next = await guard(reader.read(), net, url);
      if (next === STOPPED) return;
      if (next.done) {
        done = true;
        return;
      }
      if (!left) return;
      const piece = next.value.length > left ? next.value.subarray(0, left) : next.value;
      left -= piece.length;
      count.bytesFetched += piece.length;
      yield piece;
    }
  } finally {
    if (!done) reader.cancel().catch(() => {});
  }
}

/** A failure of fetch() or of reading a body (TypeError: terminated, network error...) as a FetchError. */
function networkError(url, e) {
  if (e instanceof PmwError) return e;
  return new FetchError(`${url}: the request failed (${e?.message ?? e})`, { url, cause: e });
}

/** An answer whose status is no answer to the request: a FetchError with its status (its body is not read). */
function httpError(url, res, what = '') {
  res.body?.cancel().catch(() => {});
  return new FetchError(`${url}: HTTP ${res.status}${what}`, { url, status: res.status });
}

/** The Content-Length of a whole-file answer `res` whose body is the file as stored (no Content-Encoding), else undefined. */
function answerLength(res) {
  const encoding = (res.headers?.get?.('Content-Encoding') ?? 'identity').trim().toLowerCase();
  const length = res.headers?.get?.('Content-Length');
  return encoding === 'identity' && /^\s*\d+\s*$/.test(length ?? '') ? Number(length) : undefined;
}

/** {first, last, size} of an answer's Content-Range (size undefined for `*`), null when absent or not readable (CORS). */
function contentRange(res) {
  const m = /^\s*bytes\s+(\d+)-(\d+)\/(\d+|\*)\s*$/i.exec(res.headers?.get?.('Content-Range') ?? '');
  return m && { first: Number(m[1]), last: Number(m[2]), size: m[3] === '*' ? undefined : Number(m[3]) };
}

/**
 * The bytes [start, stop) of `url` by Range requests, piece by piece as the answers' bodies bring them (bodyPieces): a
 * server may answer with fewer bytes than asked (RFC 9110 §14.4), and the rest is then asked for, so the pieces fall
 * short of `stop` only when the file ends first (a 416, an empty answer, or the size its Content-Range gives). `first`:
 * the answer to a request for [start, stop) already made. Ends quietly when `net.signal` aborts; an answer other than
 * 206/416, a Content-Range starting elsewhere, or a failed request is a FetchError. `count` counts the requests made
 * here and the bytes received.
 */
async function* rangeBlocks(fetchFn, url, start, stop, net, count, first) {
  let at = start;
  while (at < stop) {
    let res = first;
    first = undefined;
    if (!res) {
      res = await guard(fetchFn(url, { headers: { Range: `bytes=${at}-${stop - 1}` }, signal: net.signal }), net, url);
      if (res === STOPPED) return;
      count.requests++;
    }
    if (res.status === 416) { // the file ends before `at`
      res.body?.cancel().catch(() => {});
      return;
    }
    if (res.status !== 206) throw httpError(url, res, ` to a Range request (bytes ${at}-${stop - 1})`);
    const span = contentRange(res);
    if (span && span.first !== at) {
      throw httpError(url, res, `: its Content-Range (${res.headers.get('Content-Range')}) does not answer bytes ${at}-${stop - 1}`);
    }
    const from = at;
    for await (const piece of bodyPieces(res, net, url, stop - at, count)) {
      at += piece.length;
      yield piece;
    }
    if (net.signal.aborted || at === from) return; // stopped, or nothing past `at`: the file ends there
    if (span?.size !== undefined && at >= span.size) return; // the file ends here
  }
}

/**
 * Bytes already read (`prefix`), then the pieces of `rest` (an async iterator of the file's next bytes: the body
 * being read, rangeStream or bodyPieces), within the run's byte limit. Stopped, at the limit, enough chunks, or a
 * failure: `rest` is ended, which cancels the rest of its body (not downloaded).
 */
async function* continueReader(prefix, rest, run) {
  try {
    if (prefix?.length) yield* withinLimit(prefix, run);
    while (!run.stopped && run.decoder.received < run.byteLimit()) {
      const next = await rest.next();
      if (next.done) return;
      yield* withinLimit(next.value, run);
    }
  } finally {
    rest.return().catch(() => {});
  }
}

/**
 * `piece` up to the run's byte limit, in parts that end where a part of the file ends (partEnd: the preamble, the
 * JSON, the base, each chunk), so that each level is drawn and reported as soon as its chunk is decoded, before the
 * next chunk the piece holds is (and the limit, which grows as the header is read, is known for each part).
 */
function* withinLimit(piece, run) {
  for (let rest = piece; rest.length;) {
    const room = Math.min(run.byteLimit(), partEnd(run)) - run.decoder.received;
    if (room <= 0) return;
    const part = rest.subarray(0, room);
    rest = rest.subarray(part.length);
    yield part;
  }
}

/**
 * The whole .pmw three.js parsed, when it holds it (GLTFLoader.load downloaded it, or parse() was given it): its
 * JSON text and BIN chunk, which three.js keeps (parser.extensions.KHR_binary_glTF; the file's own bytes are not
 * kept). {head, bin}: the bytes before the BIN data, rebuilt (the JSON text encoded again, a byte order mark its
 * TextDecoder dropped put back), and the BIN data: the file's bytes, as the head has the length the file's header
 * leaves the JSON. null when three.js holds less than the stream: no BIN, a BIN short of the buffer the JSON
 * declares (a base cut before the chunks, as loadProgressive's), or JSON text that does not encode back to its
 * chunk's bytes for sure (of another length, or holding U+FFFD); the plugin then reads the stream from its url.
 */
function heldFile(parser) {
  const glb = parser.extensions?.KHR_binary_glTF;
  if (!(glb?.body instanceof ArrayBuffer) || typeof glb.content !== 'string' || glb.header?.version !== 2) return null;
  const bin = new Uint8Array(glb.body);
  if (!(bin.length >= parser.json.buffers?.[0]?.byteLength)) return null;
  // U+FFFD: maybe invalid UTF-8 three.js' TextDecoder replaced (a format error the stream read again refuses)
  if (glb.content.includes('\uFFFD')) return null;
  const jsonLength = glb.header.length - 28 - bin.length;
  let json = new TextEncoder().encode(glb.content);
  if (json.length + 3 === jsonLength) {
    const marked = new Uint8Array(jsonLength);
    marked.set([0xef, 0xbb, 0xbf]);
    marked.set(json, 3);
    json = marked;
  }
  return json.length === jsonLength ? { head: glbHead(json, bin.length, glb.header.version), bin } : null;
}

/** The file three.js holds (heldFile), fed in parts (withinLimit). No copy: views of the head and of three.js' BIN. */
function* heldPieces({ head, bin }, run) {
  for (const bytes of [head, bin]) {
    for (const part of withinLimit(bytes, run)) {
      if (run.stopped) return;
      yield part;
    }
  }
}

/**
 * The file offset where the part of the file the run's decoder is in ends: the preamble, the JSON with the BIN chunk
 * header, the base (all before the first chunk), a chunk, the tail.
 */
function partEnd(run) {
  const { plan, header, received } = run.decoder;
  if (!plan) return preambleLength(receivedBytes(run));
  const base = baseEnd(header, plan);
  if (received < base) return base;
  const { stream } = plan;
  const end = (k) => header.binStart + stream[k].offset + stream[k].length;
  let [lo, hi] = [0, stream.length]; // the first chunk that ends after `received`
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (end(mid) <= received) lo = mid + 1; else hi = mid;
  }
  return lo < stream.length ? end(lo) : header.length;
}

/** The file at `url`: by Range requests (when allowed and honoured: rangeStream), else one streamed GET. */
async function* readStream(url, fetchFn, range, run) {
  if (!url) throw new TypeError('PMWMProgressivePlugin: no url to read the stream from (options.url)');
  if (run.stopped) return;
  const { net, count } = run;
  const first = await guard(fetchFn(url, range ? { headers: { Range: 'bytes=0-19' }, signal: net.signal }
    : { signal: net.signal }), net, url);
  if (first === STOPPED) return;
  count.requests++;
  if (!first.ok) throw httpError(url, first);
  const wanted = () => run.byteLimit(); // the decoder has parsed the header
  yield* continueReader(null, first.status === 206
    ? rangeStream(fetchFn, url, net, count, first, () => requestEnd(receivedBytes(run), wanted))
    : bodyPieces(first, net, url, Infinity, count), run);
}

/**
 * The file at `url` from its start by Range requests, piece by piece as the answers' bodies bring them (rangeBlocks):
 * `first` is the answer to the request for the preamble, already made; then a request up to each end `nextEnd()`
 * gives (requestEnd), asked once the bytes before it have been taken. Ends when the file ends first, or when
 * `nextEnd()` gives no more than the bytes read.
 */
async function* rangeStream(fetchFn, url, net, count, first, nextEnd) {
  let start = 0;
  for (let end = 20, answer = first; end > start; end = nextEnd(), answer = undefined) {
    for await (const piece of rangeBlocks(fetchFn, url, start, end, net, count, answer)) {
      start += piece.length;
      yield piece;
    }
    if (start < end) return; // the file ended, or the read was stopped
  }
}

/**
 * The end of the next Range request of a read from the file's start, `head` being the bytes read so far: the requests
 * are the preamble (20 bytes), the JSON with the BIN chunk header, then everything wanted after them in one request
 * (the base and the chunks, streamed: each chunk is applied as soon as its own bytes are in), up to `wanted()`
 * (readEnd). Three requests, however many chunks: pmwm_codec.http.plan_ranges plans the same.
 */
function requestEnd(head, wanted) {
  const headerEnd = preambleLength(head); // 20 while the preamble is not in
  return head.length < headerEnd ? headerEnd : wanted();
}

/** The file offset of the first chunk (the end of the base and all before it); with no chunk, of the base's end. */
function baseEnd(header, plan) {
  return header.binStart + (plan.stream.length ? plan.stream[0].offset : plan.baseEnd);
}

/**
 * The number of chunks a load reads, from the stream's `plan` (planDocument) and the stops of `options`: at most
 * `maxChunks` (or `chunks`: chunkLimit); up to the first chunk at which every primitive is within `maxGeometricError` (a primitive without
 * chunks is as fine as this stream makes it: it never holds the stop back); those that end within `byteBudget`
 * bytes of the file (`binStart`: the file offset of the BIN data).
 */
export function chunksWanted(plan, binStart, options) {
  const { stream } = plan;
  let want = Math.min(stream.length, chunkLimit(options));
  const target = options.maxGeometricError;
  if (target !== undefined) {
    const current = plan.primitives.map((p) => (p.chunks.length ? Infinity : 0));
    for (let k = 0; k < want; k++) {
      current[stream[k].primitive] = stream[k].geometricError;
      if (Math.max(...current) <= target) { want = k + 1; break; }
    }
  }
  const budget = options.byteBudget ?? Infinity;
  while (want > 0 && binStart + stream[want - 1].offset + stream[want - 1].length > budget) want--;
  return want;
}

/**
 * The end (a file offset) of the bytes a load reads: the end of the last chunk wanted (chunksWanted), or when every
 * chunk is wanted the file's end (within `byteBudget`); never before the first chunk (baseEnd: three.js shows that
 * base, so a budget below it still gives it as level 0). Nothing after it is requested.
 */
export function readEnd(header, plan, options) {
  const want = chunksWanted(plan, header.binStart, options);
  const last = plan.stream[want - 1];
  const end = want === plan.stream.length ? Math.min(header.length, options.byteBudget ?? Infinity)
    : last ? header.binStart + last.offset + last.length : 0;
  return Math.max(end, baseEnd(header, plan));
}

/** The bytes the run's decoder has been fed. */
function receivedBytes(run) {
  return run.decoder.buf.subarray(0, run.decoder.received);
}

/**
 * Loads `url` with `loader`, reading only the bytes before the first chunk (the base and what it uses)
 * first: by Range requests (requestEnd), or the start of one fetch stream. three.js shows that base; a
 * PMWMProgressivePlugin registered for this load only then refines it from the rest of the same answer (not
 * fetched twice, no request more).
 * Do not also register the plugin on `loader` yourself. Options as PMWMProgressivePlugin's. A GLB
 * without the extension loads whole, as it is; a file that ends before those bytes is a TruncatedError;
 * an HTTP error, a failed or stalled request (`options.stallTimeout`) a FetchError. `options.signal` (an AbortSignal): aborted before this
 * resolves, it rejects with `signal.reason` (as fetch() does; an AbortError DOMException unless the caller
 * gave another reason); aborted later, it stops the run as `gltf.userData.pmwm.stop()` does.
 * @param {string|URL} href the .pmw's URL
 * @returns {Promise<object>} the gltf; `gltf.userData.pmwm.done` resolves when the stream ends
 */
export async function loadProgressive(loader, href, options = {}) {
  const { signal } = options;
  signal?.throwIfAborted();
  const given = String(href); // a URL object as well (new URL('./model.pmw', import.meta.url))
  // as GLTFLoader.load: the loader's path and its manager's URL modifier, its request headers and credentials
  const url = loader.manager?.resolveURL?.((loader.path ?? '') + given) ?? given;
  const resourcePath = options.path ?? (loader.resourcePath || (loader.path
    ? LoaderUtils.resolveURL(LoaderUtils.extractUrlBase(given), loader.path) : LoaderUtils.extractUrlBase(given)));
  // aborts every request of this load, those of its run included (the run's stop() aborts it too)
  const controller = new AbortController();
  const net = network(controller, options.stallTimeout);
  checkStops(options);
  const onAbort = () => controller.abort(signal.reason);
  signal?.addEventListener('abort', onAbort, { once: true });
  const baseFetch = options.fetch ?? globalThis.fetch.bind(globalThis);
  const fetchFn = (target, init = {}) => baseFetch(target, { ...init, headers: { ...loader.requestHeader, ...init.headers },
    ...(loader.withCredentials ? { credentials: 'include' } : {}), signal: init.signal ?? controller.signal });
  const count = { bytesFetched: 0, requests: 0 }; // the run's counts (it counts on)
  let prefix = new Uint8Array(0); // a view of `kept`, whose capacity doubles: appending stays linear
  let kept = prefix;
  const append = (b) => {
    if (prefix.length + b.length > kept.length) {
      const grown = new Uint8Array(Math.max(prefix.length + b.length, 2 * kept.length));
      grown.set(prefix);
      kept = grown;
    }
    kept.set(b, prefix.length);
    prefix = kept.subarray(0, prefix.length + b.length);
  };
  // the bytes three.js needs (`base`: the preamble, the JSON, then the base and the document's data; a GLB
  // without the extension: all of it, loaded as it is) and those the load reads (`end`: readEnd); known once the
  // JSON is in (parsed once)
  let known;
  let size; // the file's size as the first answer gives it (Content-Range, or an unencoded answer's Content-Length)
  const needed = () => {
    if (known !== undefined) return known.base;
    if (prefix.length >= 20) checkPreamble(prefix); // a JSON chunk over the limit: refused before it is fetched
    if (prefix.length < 20 || prefix.length < preambleLength(prefix)) return preambleLength(prefix);
    const header = parseGlb(prefix);
    if (size > header.length) { // spec/README.md, Partial files: refused (a reader told the size MAY refuse at once)
      throw new FormatError(`${url}: GLB: ${size - header.length} bytes after the declared file length ${header.length}`);
    }
    if (!header.gltf.extensionsUsed?.includes?.(EXTENSION_NAME)) known = { base: header.length, end: header.length };
    else {
      const plan = planDocument(header.gltf, header.binLength);
      // the base three.js shows and the data it uses (D of spec/bitstream.md §4), not the padding after them: the
      // prefix that gives decodePmw its level 0 (the base's end) gives this load its base when nothing follows it
      const base = header.binStart + plan.dataEnd;
      known = { base, end: Math.max(base, readEnd(header, plan, options)) };
    }
    return known.base;
  };
  // the file's bytes as they come (Range requests: rangeStream, else one streamed GET); the plugin reads on from it
  let rest = null;
  let gltf;
  try {
    const res = await guard(fetchFn(url, options.range === false ? {} : { headers: { Range: 'bytes=0-19' } }), net, url);
    if (res === STOPPED) throw signal.reason;
    count.requests++;
    if (!res.ok) throw httpError(url, res);
    size = res.status === 206 ? contentRange(res)?.size : answerLength(res);
    const wanted = () => { needed(); return known.end; }; // the JSON is in
    rest = res.status === 206 ? rangeStream(fetchFn, url, net, count, res, () => requestEnd(prefix, wanted))
      : bodyPieces(res, net, url, Infinity, count);
    while (prefix.length < needed()) {
      const next = await rest.next();
      if (next.done) break;
      append(next.value);
    }
    signal?.throwIfAborted();
    if (prefix.length < needed()) {
      throw new TruncatedError(`${url}: the file ended after ${prefix.length} bytes, before its base mesh and the `
        + `data it uses (${needed()} bytes)`, prefix.length, needed());
    }
    const factory = (parser) => new PMWMProgressivePlugin(parser, { ...options, url, prefix, rest, fetch: fetchFn,
      controller, count });
    loader.register(factory);
    try {
      gltf = await loader.parseAsync(baseGlb(prefix.subarray(0, needed())).buffer, resourcePath);
    } finally {
      loader.unregister(factory);
    }
  } catch (e) {
    signal?.removeEventListener('abort', onAbort);
    rest?.return().catch(() => {}); // a failed load reads no more of the body in flight
    if (signal?.aborted) throw signal.reason; // aborted: the reason, whatever the request in flight threw
    throw e;
  }
  signal?.removeEventListener('abort', onAbort); // from here the run follows the signal (it aborts `controller`)
  if (!gltf.userData?.pmwm) rest.return().catch(() => {}); // no stream to refine: nothing more is read
  const run = gltf.userData?.pmwm;
  if (signal?.aborted) { // aborted while three.js parsed the base: the run is stopped (it follows the signal)
    run?.stop();
    throw signal.reason;
  }
  return gltf;
}

/** A prefix of a .pmw as a GLB three.js accepts: the GLB and BIN lengths cut to the bytes present. */
export function baseGlb(prefix) {
  const out = prefix.slice();
  const view = new DataView(out.buffer);
  const jsonLength = view.getUint32(12, true);
  const binHeader = 20 + jsonLength;
  view.setUint32(8, out.length, true);
  if (out.length >= binHeader + 8) view.setUint32(binHeader, out.length - binHeader - 8, true);
  return out;
}
