/**
 * three.js GLTFLoader plugin for PMWM_progressive_mesh: the base shows at once, chunks refine it in place.
 *
 *   loader.register((parser) => new PMWMProgressivePlugin(parser, { url, onChunk }));
 *   const gltf = await loader.loadAsync(url);       // or: await loadProgressive(loader, url, options)
 *   await gltf.userData.pmwm.done;                   // {complete, chunksApplied, bytesFetched, ...}
 *
 * three.js reads the base mesh itself (the extension is optional). The plugin then reads the stream
 * from `options.url` (default: the URL the loader was given, when `loadProgressive` is used):
 * by HTTP `Range` requests when the server honours them (preamble, JSON, base, then one request per
 * chunk in stream order, nothing after the last chunk it needs), else as one `fetch` stream. Each
 * applied chunk rewrites the primitive's BufferGeometry (arrays grown by doubling with the levels,
 * at most to the full resolution; draw range grown) and calls `onChunk`. Stops: `maxChunks`, `maxGeometricError`
 * (the first chunk whose geometricError is at most this), `byteBudget` (no byte past it is used, but the
 * base is: below it, the base is the level shown). A stop, a stop condition or a failure cancels the rest of a
 * streamed GET.
 * `loadProgressive(loader, url)` fetches only the bytes up to the base first, so the base is shown
 * before any chunk is downloaded. Decoding (`worker`): in a module Worker (decode-worker.js) when the
 * header's full vertex count exceeds `workerThreshold` (default 100,000) or `worker: true`; on the main
 * thread when `worker: false`, below the threshold, or when no worker starts (Node: no Worker global);
 * the same levels, arrays and named errors either way (worker-decoder.js).
 */
import { Box3, BufferAttribute, LoaderUtils, Sphere } from 'three';
import { FormatError, TruncatedError } from './errors.js';
import { checkPreamble, parseGlb, planDocument, preambleLength } from './header.js';
import { createDecoder, threeName } from './worker-decoder.js';

export const EXTENSION_NAME = 'PMWM_progressive_mesh';

export class PMWMProgressivePlugin {
  /**
   * @param {object} parser the GLTFParser
   * @param {{url?: string, range?: boolean, maxChunks?: number, maxGeometricError?: number,
   *   byteBudget?: number, onBase?: Function, onChunk?: Function, onDone?: Function, fetch?: Function,
   *   prefix?: Uint8Array, reader?: object, worker?: 'auto'|boolean, workerThreshold?: number,
   *   workerUrl?: string|URL}} options
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
    const run = new ProgressiveRun(targets, this.options);
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
    const assoc = parser.associations.get(object);
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

/** One progressive load: reads the stream, feeds a decoder (PmwDecoder or WorkerDecoder), refreshes the geometries. */
export class ProgressiveRun {
  constructor(targets, options) {
    this.targets = targets;
    this.options = options;
    this.levels = [];
    this.bytesFetched = 0;
    this.requests = 0;
    this.stopped = false;
    const { maxChunks = Infinity, worker = 'auto', workerThreshold, workerUrl } = options;
    this.decoder = createDecoder({ bases: threeDracoBases(targets), maxChunks, worker, workerThreshold, workerUrl,
      keep: [options.prefix?.buffer] });
  }

  /** Stops reading after the chunk being read. */
  stop() { this.stopped = true; }

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
    const want = this.chunksWanted();
    const last = stream[want - 1];
    const wanted = want === stream.length ? Infinity : last ? header.binStart + last.offset + last.length : base;
    return Math.max(Math.min(budget, wanted), base);
  }

  async start() {
    const o = this.options;
    const fetchFn = o.fetch ?? globalThis.fetch.bind(globalThis);
    const source = o.reader ? continueReader(o.prefix, o.reader, this)
      : readStream(o.url, fetchFn, o.range ?? true, this, o.prefix);
    let end;
    try {
      for await (const piece of source) {
        if (this.stopped) break;
        const results = await this.decoder.feed(piece);
        for (const r of results) this.#level(r);
        if (this.#enough()) break;
      }
      end = await this.decoder.close();
    } finally {
      this.decoder.dispose?.();
      this.#release();
    }
    const outcome = { ...end, bytesFetched: this.bytesFetched, requests: this.requests, levels: this.levels.length,
      workerLevels: this.decoder.workerLevels ?? 0 };
    o.onDone?.(outcome);
    return outcome;
  }

  /**
   * The stream ended: the run (gltf.userData.pmwm, kept as long as the gltf) keeps only the decoder's
   * header, plan and counts; its bytes and arrays (several times the geometry's size) and the prefix go.
   */
  #release() {
    const { header, plan, received, chunksApplied, workerLevels } = this.decoder;
    this.decoder = { header, plan, received, chunksApplied, workerLevels };
    this.options = { ...this.options, prefix: undefined, reader: undefined };
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

  /** Draws level `r` (its `mesh`: the decoder's snapshot at that level) and reports it. */
  #level(r) {
    const { mesh } = r;
    const { primitives } = this.decoder.plan;
    for (const t of this.targets) {
      const p = primitives.findIndex((q) => q.mesh === t.mesh && q.primitive === t.primitive);
      const geometries = new Set(t.objects.map((o) => o.geometry));
      for (const g of geometries) refreshGeometry(g, mesh.parts[p], primitives[p].vertexCount, primitives[p].faceCount);
    }
    const event = { ...r, bytesFetched: this.bytesFetched, requests: this.requests };
    delete event.mesh;
    this.levels.push(event);
    if (r.chunk === 0) this.options.onBase?.(event);
    else this.options.onChunk?.(event);
  }
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
      for (const name of Object.keys(geometry.attributes)) if (!carried.has(name)) geometry.deleteAttribute(name);
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

/** Bytes already read (`prefix`) then the rest of a ReadableStream reader, within the run's byte limit. */
async function* continueReader(prefix, reader, run) {
  let done = false;
  try {
    if (prefix?.length) yield* withinLimit(prefix, run);
    while (!run.stopped && run.decoder.received < run.byteLimit()) {
      const next = await reader.read();
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
    rest = rest.subarray(part.length); // before the yield: a part fed to a worker may take its buffer with it
    yield part;
  }
}

/** The file at `url`: by Range requests (when allowed and honoured), else one streamed GET. */
async function* readStream(url, fetchFn, range, run, prefix) {
  if (!url) throw new FormatError('PMWMProgressivePlugin: no url to read the stream from (options.url)');
  let start = 0;
  if (prefix?.length) {
    yield* withinLimit(prefix, run);
    start = prefix.length;
  } else {
    const first = await fetchFn(url, range ? { headers: { Range: 'bytes=0-19' } } : {});
    run.requests++;
    if (!first.ok) throw new FormatError(`${url}: HTTP ${first.status}`);
    if (first.status !== 206) {
      yield* continueReader(null, first.body.getReader(), run);
      return;
    }
    const head = new Uint8Array(await first.arrayBuffer());
    const got = head.length; // a piece yielded may be transferred to the decode worker (then empty here)
    run.bytesFetched += got;
    yield head;
    if (got < 20) return;
    start = 20;
  }
  for (const end of rangeEnds(run, preambleLength(prefix ?? new Uint8Array(0)))) {
    if (run.stopped) return;
    if (end <= start) continue;
    const stop = Math.min(end, run.byteLimit());
    if (stop <= start) return;
    const res = await fetchFn(url, { headers: { Range: `bytes=${start}-${stop - 1}` } });
    run.requests++;
    if (res.status === 416) return;
    if (res.status !== 206) throw new FormatError(`${url}: HTTP ${res.status} to a Range request`);
    const block = new Uint8Array(await res.arrayBuffer());
    const got = block.length;
    run.bytesFetched += got;
    yield block;
    if (got < stop - start || stop < end) return;
    start = end;
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
 * without the extension loads whole, as it is; a file that ends before those bytes is a TruncatedError.
 * @param {string|URL} href the .pmw's URL
 * @returns {Promise<object>} the gltf; `gltf.userData.pmwm.done` resolves when the stream ends
 */
export async function loadProgressive(loader, href, options = {}) {
  const given = String(href); // a URL object as well (new URL('./model.pmw', import.meta.url))
  // as GLTFLoader.load: the loader's path and its manager's URL modifier, its request headers and credentials
  const url = loader.manager?.resolveURL?.((loader.path ?? '') + given) ?? given;
  const resourcePath = options.path ?? (loader.resourcePath || (loader.path
    ? LoaderUtils.resolveURL(LoaderUtils.extractUrlBase(given), loader.path) : LoaderUtils.extractUrlBase(given)));
  const baseFetch = options.fetch ?? globalThis.fetch.bind(globalThis);
  const fetchFn = (target, init = {}) => baseFetch(target, { ...init, headers: { ...loader.requestHeader, ...init.headers },
    ...(loader.withCredentials ? { credentials: 'include' } : {}) });
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
  const res = await fetchFn(url, options.range === false ? {} : { headers: { Range: 'bytes=0-19' } });
  stats.requests++;
  if (!res.ok) throw new FormatError(`${url}: HTTP ${res.status}`);
  let reader = null;
  let gltf;
  try {
    if (res.status === 206) {
      append(new Uint8Array(await res.arrayBuffer()));
      if (prefix.length === 20) await getRange(fetchFn, url, 20, needed(), append, stats);
      if (prefix.length === preambleLength(prefix)) await getRange(fetchFn, url, prefix.length, needed(), append, stats);
    } else {
      reader = res.body.getReader();
      while (prefix.length < needed()) {
        const { value, done } = await reader.read();
        if (done) break;
        append(value);
      }
    }
    if (prefix.length < needed()) {
      throw new TruncatedError(`${url}: the file ended after ${prefix.length} bytes, before its base mesh and what `
        + `comes before the first chunk (${needed()} bytes)`, prefix.length, needed());
    }
    const factory = (parser) => new PMWMProgressivePlugin(parser, { ...options, url, prefix, reader, fetch: fetchFn });
    loader.register(factory);
    try {
      gltf = await loader.parseAsync(baseGlb(prefix).buffer, resourcePath);
    } finally {
      loader.unregister(factory);
    }
  } catch (e) {
    reader?.cancel().catch(() => {}); // a failed load reads no more of a streamed GET
    throw e;
  }
  if (!gltf.userData?.pmwm) reader?.cancel().catch(() => {}); // no stream to refine: nothing more is read
  const run = gltf.userData?.pmwm;
  if (run) {
    run.bytesFetched += stats.bytesFetched;
    run.requests += stats.requests;
  }
  return gltf;
}

async function getRange(fetchFn, url, start, end, append, stats) {
  if (end <= start) return;
  const res = await fetchFn(url, { headers: { Range: `bytes=${start}-${end - 1}` } });
  stats.requests++;
  if (res.status === 416) return; // the file ends before `start`: the caller finds it short
  if (res.status !== 206) throw new FormatError(`${url}: HTTP ${res.status} to a Range request`);
  append(new Uint8Array(await res.arrayBuffer()));
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
