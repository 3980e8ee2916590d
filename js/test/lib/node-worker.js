// A Web Worker for Node tests (Node has no `Worker` global): runs a module worker script written for the web
// (`self.onmessage`, `self.postMessage(data, transfer)`) in a worker_threads Worker, behind the interface
// worker-decoder.js uses (`new Worker(url, {type: 'module'})`, postMessage with a transfer list, onmessage,
// onerror, terminate). Transfers detach as in browsers. `withNodeWorker(fn)` runs fn with it as globalThis.Worker.
import { Worker } from 'node:worker_threads';

const BOOT = `import { parentPort, workerData } from 'node:worker_threads';
globalThis.self = globalThis;
globalThis.postMessage = (data, transfer) => parentPort.postMessage(data, transfer);
parentPort.on('message', (data) => globalThis.onmessage?.({ data }));
await import(workerData);`;

export class NodeWebWorker {
  constructor(url) {
    this.worker = new Worker(new URL(`data:text/javascript,${encodeURIComponent(BOOT)}`), { workerData: String(url) });
    this.worker.on('message', (data) => this.onmessage?.({ data }));
    this.worker.on('error', (e) => this.onerror?.(e));
  }

  postMessage(data, transfer) { this.worker.postMessage(data, transfer); }

  terminate() { this.worker.terminate(); }
}

export async function withNodeWorker(fn) {
  const had = Object.getOwnPropertyDescriptor(globalThis, 'Worker');
  globalThis.Worker = NodeWebWorker;
  try {
    return await fn();
  } finally {
    if (had) Object.defineProperty(globalThis, 'Worker', had);
    else delete globalThis.Worker;
  }
}
