/**
 * Decoding off the main thread: `createDecoder()` gives the three.js plugin a PmwDecoder, or a
 * `WorkerDecoder` that runs one in a module Worker (`decode-worker.js`) for large meshes.
 *
 * A WorkerDecoder keeps the bytes until the GLB header is in, parses it (the same parseGlb /
 * planDocument as PmwDecoder) and decides: a worker when `worker` is true, or when it is 'auto' and the
 * header's full vertex count (all progressive primitives) exceeds `workerThreshold`; else, or when no
 * worker starts (no `Worker` global as in Node, a blocked or missing script), a PmwDecoder on the main
 * thread: the same results either way. feed() copies its bytes before it returns, as PmwDecoder.feed does (the
 * caller may reuse its buffer at once); with a worker, that copy is posted (its ArrayBuffer transferred, never the
 * caller's) and each level comes back as `result.mesh.parts[p]`
 * `{positions (n*3) Float32Array, indices (m*3) Uint32Array, attributes {semantic: Float32Array}}`
 * (copied, not transferred: decode-worker.js) for the primitive the level changed (the base: every one), null for the others; a failure comes back as the same named error (errors.js class, message, fields).
 *
 * Starting the worker: first `new Worker(url, {type: 'module'})` (bundlers rewrite this form, and it
 * is all a page needs once import maps reach workers); Chromium does not apply the page's import map
 * inside workers, so when that worker fails to load, its module graph is loaded again as blob: URLs
 * with bare names ('hash-wasm', 'zstddec') resolved by the page (`import.meta.resolve`).
 */
import { asBytes, PmwDecoder } from './decoder.js';
import * as errors from './errors.js';
import { FormatError } from './errors.js';
import { checkPreamble, parseGlb, planDocument, preambleLength } from './header.js';

/** Full vertex count above which `worker: 'auto'` decodes in a worker. */
export const WORKER_THRESHOLD = 100000;

/** glTF attribute semantic -> three.js attribute name, as GLTFLoader's ATTRIBUTES table has them. */
const THREE_NAMES = { POSITION: 'position', NORMAL: 'normal', TANGENT: 'tangent', TEXCOORD_0: 'uv',
  TEXCOORD_1: 'uv1', TEXCOORD_2: 'uv2', TEXCOORD_3: 'uv3', COLOR_0: 'color', WEIGHTS_0: 'skinWeight', JOINTS_0: 'skinIndex' };

/** The name GLTFLoader gives attribute `semantic` (its table, else the semantic lowercased: `_CUSTOM` -> `_custom`). */
export function threeName(semantic) {
  return THREE_NAMES[semantic] ?? semantic.toLowerCase();
}

/**
 * A Draco "decoder" answering, in stream order, from base meshes another decoder (three.js) decoded.
 * @param {{ids: object, attrs: object, indices: Uint32Array}[]} bases per Draco base: ids
 *   {semantic: Draco attribute id}, attrs {threeName: {values: Float32Array, components}}, indices (m*3)
 */
export function dracoFromBases(bases) {
  const queue = [...bases];
  return {
    async decode(_bytes, { attributeIds }) {
      const b = queue.shift();
      if (!b) throw new FormatError('three.js decoded fewer Draco base meshes than the stream holds');
      const byId = Object.fromEntries(Object.entries(b.ids).map(([semantic, id]) => [id, semantic]));
      return {
        positions: b.attrs.position.values, indices: b.indices,
        attributes: attributeIds.map((id) => b.attrs[threeName(byId[id])]),
      };
    },
  };
}

/**
 * A PmwDecoder (snapshots 'changed': every result carries the parts its level changed, `mesh.parts`) or, unless `worker` is false or
 * there is no Worker, a WorkerDecoder.
 * @param {{bases: object[], maxChunks?: number, worker?: 'auto'|boolean, workerThreshold?: number,
 *   workerUrl?: string|URL}} options
 */
export function createDecoder(options) {
  if (options.worker === false || typeof globalThis.Worker !== 'function') return localDecoder(options);
  return new WorkerDecoder(options);
}

function localDecoder({ bases, maxChunks = Infinity }) {
  return new PmwDecoder({ draco: dracoFromBases(bases), maxChunks, snapshots: 'changed' });
}

/** PmwDecoder's push interface (feed, close, header, plan, received, chunksApplied) over a worker. */
export class WorkerDecoder {
  #header = null;
  #plan = null;
  #received = 0;
  #chunksApplied = 0;

  constructor(options) {
    this.options = options;
    this.local = null;
    this.worker = null;
    this.workerLevels = 0;
    this.failed = null;
    this.buf = new Uint8Array(0);
    this.pending = new Map();
    this.nextId = 0;
    this.queue = Promise.resolve();
    this.closed = false;
    this.end = null;
  }

  get header() { return this.local ? this.local.header : this.#header; }
  get plan() { return this.local ? this.local.plan : this.#plan; }
  get received() { return this.local ? this.local.received : this.#received; }
  get chunksApplied() { return this.local ? this.local.chunksApplied : this.#chunksApplied; }
  /** The error that broke the stream (as PmwDecoder's `error`), else null. */
  get error() { return this.local ? this.local.error : this.failed; }
  /** Whether decoding runs in a worker (false until the header decided it). */
  get inWorker() { return this.worker !== null; }

  /**
   * Appends `bytes` (as PmwDecoder.feed: a Uint8Array, ArrayBuffer, typed array or DataView, copied before this
   * returns, so the caller may reuse its buffer at once; else a TypeError); resolves to the results that became
   * available.
   */
  feed(bytes) {
    let piece;
    try {
      piece = asBytes(bytes).slice(); // the feeds queue: the caller's bytes may have changed by the time this one runs
      if (this.closed) throw new TypeError('WorkerDecoder.feed() after close(): the decoder is single-use');
    } catch (e) {
      return Promise.reject(e);
    }
    const run = this.queue.then(() => this.#feed(piece));
    this.queue = run.catch(() => {});
    return run;
  }

  /** `bytes`: feed()'s own copy (its buffer is transferred to the worker). */
  async #feed(bytes) {
    if (this.local) return this.local.feed(bytes);
    if (this.failed) throw this.failed;
    if (this.worker) {
      this.#received += bytes.length;
      return this.#post({ type: 'feed', bytes }, [bytes.buffer]);
    }
    const data = this.#append(bytes);
    if (data.length >= 20) checkPreamble(data); // as PmwDecoder: a JSON chunk over the limit is refused before it is buffered
    if (data.length < 20 || data.length < preambleLength(data)) return [];
    await this.#choose(data);
    if (this.local) return this.local.feed(data);
    const copy = data.slice();
    this.buf = new Uint8Array(0);
    return this.#post({ type: 'feed', bytes: copy }, [copy.buffer]);
  }

  /** Keeps bytes while the header is incomplete (capacity doubled as needed); returns a view of all kept so far. */
  #append(bytes) {
    const need = this.#received + bytes.length;
    if (need > this.buf.length) {
      const grown = new Uint8Array(Math.max(need, 2 * this.buf.length, 1024));
      grown.set(this.buf.subarray(0, this.#received));
      this.buf = grown;
    }
    this.buf.set(bytes, this.#received);
    this.#received = need;
    return this.buf.subarray(0, need);
  }

  /** The header is in: a worker (started here) or the main thread. Unparseable: the main thread says why. */
  async #choose(data) {
    const { worker = 'auto', workerThreshold = WORKER_THRESHOLD } = this.options;
    let header; let plan;
    try {
      header = parseGlb(data);
      plan = planDocument(header.gltf, header.binLength);
    } catch {
      this.local = localDecoder(this.options);
      return;
    }
    const vertices = plan.primitives.reduce((a, p) => a + p.vertexCount, 0);
    const wanted = worker === true || (worker === 'auto' && vertices > workerThreshold);
    this.worker = wanted ? await startWorker(this.options.workerUrl) : null;
    if (!this.worker) {
      this.local = localDecoder(this.options);
      return;
    }
    this.#header = header;
    this.#plan = plan;
    this.worker.onmessage = ({ data: msg }) => this.#reply(msg);
    this.worker.onerror = (e) => this.#fail(new Error(`the decode worker failed: ${e.message ?? 'no message'}`));
    const bases = this.options.bases;
    this.worker.postMessage({ type: 'start', maxChunks: this.options.maxChunks ?? Infinity, bases }, baseBuffers(bases));
  }

  #post(msg, transfer) {
    return new Promise((resolve, reject) => {
      const id = ++this.nextId;
      this.pending.set(id, { resolve, reject });
      this.worker.postMessage({ ...msg, id }, transfer);
    });
  }

  #reply(msg) {
    if (msg.error && !msg.results) {
      this.#fail(reviveError(msg.error)); // rejects the request it answers with the rest
      return;
    }
    const waiting = this.pending.get(msg.id);
    this.pending.delete(msg.id);
    if (msg.results?.length) this.#chunksApplied = msg.results[msg.results.length - 1].chunk;
    if (msg.levels !== undefined) this.workerLevels = msg.levels;
    waiting?.resolve(msg.results ?? msg.end);
    // a chunk failed after the levels of this piece: those are delivered, every later call fails
    if (msg.error) this.#fail(reviveError(msg.error));
  }

  /** Rejects every pending request with `error` (and every later call), ends the worker. */
  #fail(error) {
    this.failed ??= error;
    for (const { reject } of this.pending.values()) reject(this.failed);
    this.pending.clear();
    this.worker?.terminate();
  }

  /** Ends the worker, if any (after close() or a failure it already ended). */
  dispose() { this.worker?.terminate(); }

  /**
   * Ends the stream (as PmwDecoder.close, but async): {complete, chunksApplied, ...} or the named error. From the
   * call on, a feed() is a TypeError; a second close() settles as the first.
   */
  close() {
    this.closed = true;
    this.end ??= this.#close();
    return this.end;
  }

  async #close() {
    await this.queue;
    if (this.failed) throw this.failed;
    if (this.worker) {
      const end = await this.#post({ type: 'close' }, []);
      this.worker.terminate();
      return end;
    }
    if (!this.local) { // less than a header arrived: the main-thread decoder reports it
      this.local = localDecoder(this.options);
      await this.local.feed(this.buf.subarray(0, this.#received)).catch(() => {}); // close() says why
    }
    return this.local.close();
  }
}

/** The ArrayBuffers of the base arrays (each once). */
function baseBuffers(bases) {
  const buffers = new Set();
  for (const b of bases) {
    buffers.add(b.indices.buffer);
    for (const a of Object.values(b.attrs)) buffers.add(a.values.buffer);
  }
  return [...buffers];
}

/** Milliseconds a starting worker has to post 'ready' (a script that is not the decode worker never does). */
export const WORKER_START_MS = 10000;

/** A started module worker (it posted 'ready'), or null when none starts. */
async function startWorker(workerUrl) {
  // resolves to the worker, null when it failed to load, 'late' when it loaded but never said 'ready'
  const attempt = (create) => new Promise((resolve) => {
    let worker;
    try {
      worker = create();
    } catch {
      resolve(null);
      return;
    }
    const timer = setTimeout(() => { worker.terminate(); resolve('late'); }, WORKER_START_MS);
    const settle = (value) => { clearTimeout(timer); resolve(value); };
    worker.onmessage = ({ data }) => settle(data?.type === 'ready' ? worker : (worker.terminate(), null));
    worker.onerror = (e) => { e.preventDefault?.(); worker.terminate(); settle(null); };
  });
  const url = new URL(workerUrl ?? new URL('./decode-worker.js', import.meta.url), globalThis.location?.href).href;
  if (!needsBlob.has(url)) {
    const worker = await attempt(() => workerUrl ? new Worker(workerUrl, { type: 'module' })
      : new Worker(new URL('./decode-worker.js', import.meta.url), { type: 'module' }));
    if (worker === 'late') return null; // it loaded: loading it again as blobs would not make it answer
    if (worker || typeof import.meta.resolve !== 'function') return worker;
    needsBlob.add(url);
  }
  let blob;
  try {
    blob = await blobModule(url, blobModules);
  } catch {
    blobModules.clear(); // a failed fetch is not kept: the next load tries again
    return null;
  }
  const worker = await attempt(() => new Worker(blob, { type: 'module' }));
  return worker === 'late' ? null : worker;
}

/** Worker URLs whose plain module worker failed to load (tried as blob graphs from then on). */
const needsBlob = new Set();
/** Module URL -> Promise of its rewritten blob: URL, kept for the page's life (one per module). */
const blobModules = new Map();

const STATIC_IMPORT = /^(\s*(?:import|export)\b[^'"]*?\bfrom\s*)(['"])([^'"]+)\2/gm;
const DYNAMIC_IMPORT = /(\bimport\(\s*)(['"])(\.{1,2}\/[^'"]+)\2/g;

/**
 * A blob: URL of the module at `url` whose static imports are blob: URLs of its (likewise rewritten)
 * dependencies, bare names resolved by this page's import map (left bare when it has none), and
 * relative dynamic imports made absolute. `done`: url -> Promise of its blob URL.
 */
function blobModule(url, done) {
  if (!done.has(url)) {
    done.set(url, (async () => {
      const res = await fetch(url);
      if (!res.ok) throw new Error(`${url}: HTTP ${res.status}`);
      const source = await res.text();
      const targets = new Map();
      for (const [, , , spec] of source.matchAll(STATIC_IMPORT)) {
        if (targets.has(spec)) continue;
        targets.set(spec, /^\.{0,2}\//.test(spec) ? await blobModule(new URL(spec, url).href, done) : resolveBare(spec));
      }
      const rewritten = source
        .replace(STATIC_IMPORT, (_, head, q, spec) => head + q + targets.get(spec) + q)
        .replace(DYNAMIC_IMPORT, (_, head, q, spec) => head + q + new URL(spec, url).href + q);
      return URL.createObjectURL(new Blob([rewritten], { type: 'text/javascript' }));
    })());
  }
  return done.get(url);
}

function resolveBare(spec) {
  try {
    return import.meta.resolve(spec);
  } catch {
    return spec;
  }
}

/** An error as a message: {name, message, stack, fields} (its own number/string/boolean/null fields: chunk, bytesReceived...;
 * a CorruptChunkError of the base mesh has chunk null). */
export function serializeError(e) {
  const fields = Object.fromEntries(Object.entries(e ?? {})
    .filter(([, v]) => v === null || ['number', 'string', 'boolean'].includes(typeof v)));
  return { name: e?.name ?? 'Error', message: e?.message ?? String(e), stack: e?.stack, fields };
}

/** The error `serializeError` describes, as the errors.js class of that name (else Error, TypeError...). */
export function reviveError({ name, message, stack, fields }) {
  const Kind = Object.hasOwn(errors, name) ? errors[name]
    : globalThis[name]?.prototype instanceof Error ? globalThis[name] : Error;
  const e = new Kind(message);
  Object.assign(e, fields);
  if (e.name !== name) e.name = name;
  if (stack) e.stack = stack;
  return e;
}
