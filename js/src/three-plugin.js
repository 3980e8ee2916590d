/**
 * three.js GLTFLoader plugin for PMWM_progressive_mesh: the base shows at once, chunks refine it in place.
 *
 *   loader.register((parser) => new PMWMProgressivePlugin(parser, { url, onChunk }));
 *   const gltf = await loader.loadAsync(url);       // or: await loadProgressive(loader, url, options)
 *   await gltf.userData.pmwm.done;                   // {complete, chunksApplied, bytesFetched, ...}
 *
 * three.js reads the base mesh itself (the extension is optional). When three.js holds the whole file
 * (GLTFLoader.load downloads it whole, or parse() was given it), the plugin decodes the stream from those bytes
 * (three.js' JSON text and BIN chunk: heldFile), fetching nothing. Else it reads the stream
 * from `options.url` (default: the URL the loader was given, when `loadProgressive` is used):
 * by HTTP `Range` requests when the server honours them (preamble, JSON, base, then one request per
 * chunk in stream order, nothing after the last chunk it needs), else as one `fetch` stream. Each
 * applied chunk rewrites the primitive's BufferGeometry (arrays grown by doubling with the levels,
 * at most to the full resolution; draw range grown) and calls `onChunk`. Stops: `maxChunks`, `maxGeometricError`
 * (the first chunk whose geometricError is at most this), `byteBudget` (no byte past it is used, but the
 * base is: below it, the base is the level shown). A stop, a stop condition or a failure cancels the rest of a
 * streamed GET; `stop()` (or `options.signal` aborting) aborts the request in flight at once. A Range answer
 * shorter than asked is followed by a request for the rest. A request that brings nothing (head, or next body
 * bytes) for `stallTimeout` ms (default 30 s, STALL_TIMEOUT_MS; 0: no limit) is aborted: a FetchError. The levels
 * decoded before a failure stay drawn; `done` rejects with it (HTTP and network failures, stalls: FetchError).
 * The stream must be the document three.js parsed (its PMWM_progressive_mesh objects), else StreamMismatchError
 * before anything is drawn. What onBase,
 * onChunk, onDone throw goes to onCallbackError (else console.error), never failing the load.
 * `loadProgressive(loader, url)` fetches only the bytes up to the base first, so the base is shown
 * before any chunk is downloaded. Decoding (`worker`): in a module Worker (decode-worker.js) when the
 * header's full vertex count exceeds `workerThreshold` (default 100,000) or `worker: true`; on the main
 * thread when `worker: false`, below the threshold, or when no worker starts (Node: no Worker global);
 * the same levels, arrays and named errors either way (worker-decoder.js).
 */
import { Box3, BufferAttribute, LoaderUtils, Sphere } from 'three';
import { reportCallbackError } from './decoder.js';
import { FetchError, FormatError, PmwError, StreamMismatchError, TruncatedError } from './errors.js';
import { checkPreamble, glbHead, parseGlb, planDocument, preambleLength } from './header.js';
import { createDecoder, threeName } from './worker-decoder.js';

export const EXTENSION_NAME = 'PMWM_progressive_mesh';

export class PMWMProgressivePlugin {
  /**
   * @param {object} parser the GLTFParser
   * @param {{url?: string, range?: boolean, maxChunks?: number, maxGeometricError?: number,
   *   byteBudget?: number, onBase?: Function, onChunk?: Function, onDone?: Function, onCallbackError?: Function,
   *   fetch?: Function, signal?: AbortSignal, stallTimeout?: number, prefix?: Uint8Array, reader?: object,
   *   worker?: 'auto'|boolean, workerThreshold?: number, workerUrl?: string|URL}} options
   *   onChunk({chunk, chunksTotal, vertexCount, faceCount, bytesRead, bytesFetched, requests})
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
    const held = this.options.prefix || this.options.reader ? null : heldFile(this.parser);
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
  constructor(targets, options, json = null) {
    this.targets = targets;
    this.options = options;
    this.json = json;
    this.checked = false;
    this.levels = [];
    this.bytesFetched = 0;
    this.requests = 0;
    this.stopped = false;
    // aborts the request in flight on stop(); loadProgressive's own (its streamed GET's body) when it made one
    this.controller = options.controller ?? new AbortController();
    this.net = network(this.controller, options.stallTimeout);
    const { maxChunks = Infinity, worker = 'auto', workerThreshold, workerUrl, signal } = options;
    this.decoder = createDecoder({ bases: threeDracoBases(targets), maxChunks, worker, workerThreshold, workerUrl });
    if (signal?.aborted) this.stop();
    else if (signal) {
      const onAbort = () => this.stop();
      signal.addEventListener('abort', onAbort, { once: true });
      this.unlink = () => signal.removeEventListener('abort', onAbort);
    }
  }

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
   * The bytes this run may feed: up to the end of the last chunk wanted (maxChunks, maxGeometricError)
   * and `byteBudget`, but never fewer than the bytes before the first chunk (preamble, JSON, base: what
   * three.js shows), so a budget below the base gives that base as level 0. A chunk past them is never
   * fed (never applied, nor its digest checked), whatever pieces a streamed GET brings.
   */
  byteLimit() {
    const budget = this.options.byteBudget ?? Infinity;
    const { plan, header, received } = this.decoder;
    if (!plan) return received < 20 ? 20 : headerEndOf(this); // the header first: then the limit is known
    const { stream } = plan;
    const base = header.binStart + (stream.length ? stream[0].offset : plan.baseEnd);
    if (this.stopped) return Math.max(base, received); // stopped: the base (when held) and no chunk more
    const want = this.chunksWanted();
    const last = stream[want - 1];
    const wanted = want === stream.length ? Infinity : last ? header.binStart + last.offset + last.length : base;
    return Math.max(Math.min(budget, wanted), base);
  }

  async start() {
    const o = this.options;
    const fetchFn = o.fetch ?? globalThis.fetch.bind(globalThis);
    const source = o.reader ? continueReader(o.prefix, o.reader, this, o.url)
      : o.held ? heldPieces(o.held, this)
        : readStream(o.url, fetchFn, o.range ?? true, this, o.prefix);
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
    if (shown !== undefined && shown < end.chunksApplied) end = { ...end, complete: false, chunksApplied: shown };
    const outcome = { ...end, bytesFetched: this.bytesFetched, requests: this.requests, levels: this.levels.length,
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
    this.options = { ...this.options, prefix: undefined, reader: undefined, controller: undefined, held: undefined };
    this.json = null;
  }

  /** The number of chunks worth reading, once the header is known (geometric error, maxChunks). */
  chunksWanted() {
    const plan = this.decoder.plan;
    let want = Math.min(plan.stream.length, this.options.maxChunks ?? Infinity);
    const target = this.options.maxGeometricError;
    if (target !== undefined) {
      // a primitive without chunks is as fine as this stream makes it: it never holds the stop back
      const current = plan.primitives.map((p) => (p.chunks.length ? Infinity : 0));
      for (let k = 0; k < plan.stream.length; k++) {
        current[plan.stream[k].primitive] = plan.stream[k].geometricError;
        if (Math.max(...current) <= target) { want = Math.min(want, k + 1); break; }
      }
    }
    return want;
  }

  #enough() {
    const plan = this.decoder.plan;
    if (!plan || !this.levels.length) return false;
    const want = this.chunksWanted();
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
        [k, { values: Float32Array.from(a.array), components: a.itemSize }])) };
  });
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
    throw new RangeError(`stallTimeout must be a number of milliseconds >= 0 (0: no limit), not ${stallTimeout}`);
  }
  return { signal: controller.signal, stallTimeout, abort: (reason) => controller.abort(reason) };
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
 * The body of the answer `res`, read piece by piece (each read one wait: the stall timeout bounds the time between
 * bytes, not the whole body), at most `limit` bytes (more is cancelled, unread); STOPPED when aborted meanwhile.
 */
async function readBody(res, net, url, limit) {
  if (!res.body?.getReader) { // a fetch of the caller's whose answers have no body stream: one wait
    const body = await guard(res.arrayBuffer(), net, url);
    return body === STOPPED ? body : new Uint8Array(body, 0, Math.min(body.byteLength, limit));
  }
  const reader = res.body.getReader();
  const pieces = [];
  let length = 0;
  let done = false;
  try {
    while (length <= limit) { // the read after `limit` bytes ends the body, or brings bytes not asked for
      const next = await guard(reader.read(), net, url);
      if (next === STOPPED) return STOPPED;
      if (next.done) {
        done = true;
        break;
      }
      pieces.push(next.value);
      length += next.value.length;
    }
  } finally {
    if (!done) reader.cancel().catch(() => {});
  }
  if (pieces.length === 1 && length <= limit) return pieces[0];
  const body = new Uint8Array(Math.min(length, limit));
  let at = 0;
  for (const piece of pieces) {
    body.set(piece.subarray(0, body.length - at), at);
    at += Math.min(piece.length, body.length - at);
  }
  return body;
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

/** {first, last, size} of an answer's Content-Range (size undefined for `*`), null when absent or not readable (CORS). */
function contentRange(res) {
  const m = /^\s*bytes\s+(\d+)-(\d+)\/(\d+|\*)\s*$/i.exec(res.headers?.get?.('Content-Range') ?? '');
  return m && { first: Number(m[1]), last: Number(m[2]), size: m[3] === '*' ? undefined : Number(m[3]) };
}

/**
 * The bytes [start, stop) of `url` by Range requests, block by block as the answers come: a server may answer
 * with fewer bytes than asked (RFC 9110 §14.4), and the rest is then asked for, so the blocks fall short of
 * `stop` only when the file ends first (a 416, an empty answer, or the size its Content-Range gives). `first`:
 * the answer to a request for [start, stop) already made. Ends quietly when `net.signal` aborts; an answer other than
 * 206/416, a Content-Range starting elsewhere, or a failed request is a FetchError. `count.requests` counts the
 * requests made here.
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
    const block = await readBody(res, net, url, stop - at);
    if (block === STOPPED) return;
    if (!block.length) return; // nothing past `at`: the file ends there
    at += block.length;
    yield block;
    if (span?.size !== undefined && at >= span.size) return; // the file ends here
  }
}

/** Bytes already read (`prefix`) then the rest of a ReadableStream reader, within the run's byte limit. */
async function* continueReader(prefix, reader, run, url) {
  let done = false;
  try {
    if (prefix?.length) yield* withinLimit(prefix, run);
    while (!run.stopped && run.decoder.received < run.byteLimit()) {
      const next = await guard(reader.read(), run.net, url);
      if (next === STOPPED) return;
      if (next.done) { done = true; return; }
      run.bytesFetched += next.value.length;
      yield* withinLimit(next.value, run);
    }
  } finally {
    // stopped, at the limit, enough chunks, or a failure: the rest of the body is not downloaded
    if (!done) reader.cancel().catch(() => {});
  }
}

/** `piece` up to the run's byte limit, in parts where the limit grows as the header is read. */
function* withinLimit(piece, run) {
  for (let rest = piece; rest.length;) {
    const room = run.byteLimit() - run.decoder.received;
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

/**
 * The file three.js holds (heldFile) in the pieces Range requests would bring: the head in two (the preamble,
 * then the rest), the base, each chunk, within the run's byte limit. No copy: views of the head and of three.js'
 * BIN (the decoder copies what it is fed).
 */
function* heldPieces({ head, bin }, run) {
  const total = head.length + bin.length;
  let start = 0;
  for (const end of rangeEnds(run, head.length)) {
    while (start < Math.min(end, total)) {
      const stop = Math.min(end, total, run.byteLimit());
      if (run.stopped || stop <= start) return;
      const piece = start < head.length ? head.subarray(start, Math.min(stop, head.length))
        : bin.subarray(start - head.length, stop - head.length);
      start += piece.length;
      yield piece;
    }
  }
}

/** The file at `url`: by Range requests (when allowed and honoured), else one streamed GET. */
async function* readStream(url, fetchFn, range, run, prefix) {
  if (!url) throw new TypeError('PMWMProgressivePlugin: no url to read the stream from (options.url)');
  const { net } = run;
  let start = 0;
  if (prefix?.length) {
    yield* withinLimit(prefix, run);
    start = prefix.length;
  } else {
    if (run.stopped) return;
    const { signal } = net;
    const first = await guard(fetchFn(url, range ? { headers: { Range: 'bytes=0-19' }, signal } : { signal }), net, url);
    if (first === STOPPED) return;
    run.requests++;
    if (!first.ok) throw httpError(url, first);
    if (first.status !== 206) {
      yield* continueReader(null, first.body.getReader(), run, url);
      return;
    }
    for await (const block of rangeBlocks(fetchFn, url, 0, 20, net, run, first)) {
      const got = block.length;
      run.bytesFetched += got;
      start += got;
      yield block;
    }
    if (start < 20) return; // the file ends within its preamble
  }
  for (const end of rangeEnds(run, preambleLength(prefix ?? new Uint8Array(0)))) {
    if (run.stopped) return;
    if (end <= start) continue;
    const stop = Math.min(end, run.byteLimit());
    if (stop <= start) return;
    for await (const block of rangeBlocks(fetchFn, url, start, stop, net, run)) {
      const got = block.length;
      run.bytesFetched += got;
      start += got;
      yield block;
    }
    if (start < stop || stop < end) return; // the file ended, or the byte limit
  }
}

/** Absolute end offsets to request: the header, then (once it is parsed) the base, each chunk, the tail. */
function* rangeEnds(run, knownHeaderEnd) {
  yield run.decoder.header ? 0 : knownHeaderEnd > 20 ? knownHeaderEnd : headerEndOf(run);
  const { plan, header } = run.decoder;
  if (!plan) return;
  const { stream } = plan;
  const bin = header.binStart;
  if (stream.length) yield bin + stream[0].offset;
  const want = run.chunksWanted();
  for (let k = 0; k < want; k++) yield bin + stream[k].offset + stream[k].length;
  if (want === stream.length) yield header.length;
}

function headerEndOf(run) {
  return preambleLength(run.decoder.buf.subarray(0, run.decoder.received));
}

/**
 * Loads `url` with `loader`, reading only the bytes before the first chunk (the base and what it uses)
 * first: by Range requests, or the start of one fetch stream. three.js shows that base; a
 * PMWMProgressivePlugin registered for this load only then refines it from the rest (not fetched twice).
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
  const onAbort = () => controller.abort(signal.reason);
  signal?.addEventListener('abort', onAbort, { once: true });
  const baseFetch = options.fetch ?? globalThis.fetch.bind(globalThis);
  const fetchFn = (target, init = {}) => baseFetch(target, { ...init, headers: { ...loader.requestHeader, ...init.headers },
    ...(loader.withCredentials ? { credentials: 'include' } : {}), signal: init.signal ?? controller.signal });
  const stats = { bytesFetched: 0, requests: 0 };
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
    stats.bytesFetched += b.length;
  };
  // the bytes three.js needs: the preamble, the JSON, then everything before the first chunk (a GLB
  // without the extension: all of it, loaded as it is); known once the JSON is in (parsed once)
  let known;
  const needed = () => {
    if (known !== undefined) return known;
    if (prefix.length >= 20) checkPreamble(prefix); // a JSON chunk over the limit: refused before it is fetched
    if (prefix.length < 20 || prefix.length < preambleLength(prefix)) return preambleLength(prefix);
    const header = parseGlb(prefix);
    if (!header.gltf.extensionsUsed?.includes?.(EXTENSION_NAME)) return (known = header.length);
    const { stream } = planDocument(header.gltf, header.binLength);
    return (known = stream.length ? header.binStart + stream[0].offset : header.length);
  };
  /** Range requests for the bytes up to `end` (short answers: the rest asked for), while the file lasts. */
  const getRange = async (end, first) => {
    for await (const block of rangeBlocks(fetchFn, url, prefix.length, end, net, stats, first)) append(block);
  };
  let reader = null;
  let gltf;
  try {
    const res = await guard(fetchFn(url, options.range === false ? {} : { headers: { Range: 'bytes=0-19' } }), net, url);
    if (res === STOPPED) throw signal.reason;
    stats.requests++;
    if (!res.ok) throw httpError(url, res);
    if (res.status === 206) {
      await getRange(20, res);
      if (prefix.length === 20) await getRange(needed());
      if (prefix.length === preambleLength(prefix)) await getRange(needed());
    } else {
      reader = res.body.getReader();
      while (prefix.length < needed()) {
        const next = await guard(reader.read(), net, url);
        if (next === STOPPED || next.done) break;
        append(next.value);
      }
    }
    signal?.throwIfAborted();
    if (prefix.length < needed()) {
      throw new TruncatedError(`${url}: the file ended after ${prefix.length} bytes, before its base mesh and what `
        + `comes before the first chunk (${needed()} bytes)`, prefix.length, needed());
    }
    const factory = (parser) => new PMWMProgressivePlugin(parser, { ...options, url, prefix, reader, fetch: fetchFn,
      controller });
    loader.register(factory);
    try {
      gltf = await loader.parseAsync(baseGlb(prefix).buffer, resourcePath);
    } finally {
      loader.unregister(factory);
    }
  } catch (e) {
    signal?.removeEventListener('abort', onAbort);
    reader?.cancel().catch(() => {}); // a failed load reads no more of a streamed GET
    if (signal?.aborted) throw signal.reason; // aborted: the reason, whatever the request in flight threw
    throw e;
  }
  signal?.removeEventListener('abort', onAbort); // from here the run follows the signal (it aborts `controller`)
  if (!gltf.userData?.pmwm) reader?.cancel().catch(() => {}); // no stream to refine: nothing more is read
  const run = gltf.userData?.pmwm;
  if (run) {
    run.bytesFetched += stats.bytesFetched;
    run.requests += stats.requests;
  }
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
