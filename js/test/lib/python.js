/**
 * The tests' way to the Python side: finds a Python that imports pmwm_codec from the repository
 * (PYTHONPATH = repository root) and encodes test meshes with `python -m pmwm_codec encode`.
 *
 * The interpreter: $PYTHON when set, else the repository's `.venv` (the one .ci/run makes), `python`,
 * then `python3`. `python()` is null when none can import pmwm_codec; callers skip then.
 * $PMW_PYTHONPATH names another checkout of the repository to test against instead of this one:
 * its pmwm_codec package and its spec/conformance files (TREE).
 */
import { execFile, spawnSync } from 'node:child_process';
import { existsSync } from 'node:fs';
import { dirname, join, resolve } from 'node:path';
import { fileURLToPath } from 'node:url';

export const ROOT = resolve(dirname(fileURLToPath(import.meta.url)), '..', '..', '..');
export const CORPUS = resolve(ROOT, '..', 'shared', 'corpus');
/** The repository tree whose Python package and conformance files the tests use. */
export const TREE = process.env.PMW_PYTHONPATH ? resolve(process.env.PMW_PYTHONPATH) : ROOT;

const env = () => ({ ...process.env, PYTHONPATH: [TREE, process.env.PYTHONPATH].filter(Boolean).join(':') });

let found;
/** The first interpreter that imports pmwm_codec's command line, or null. */
export function python() {
  if (found !== undefined) return found;
  const candidates = process.env.PYTHON ? [process.env.PYTHON] : [join(ROOT, '.venv', 'bin', 'python'), 'python', 'python3'];
  found = candidates.find((exe) => spawnSync(exe, ['-c', 'import pmwm_codec.cli'], { env: env(), stdio: 'ignore' }).status === 0) ?? null;
  return found;
}

const LEVELS = join(dirname(fileURLToPath(import.meta.url)), 'levels.py');

let v2;
/** Whether python() encodes chunk payload version 2 (spec/bitstream.md §8). */
export function pythonHasPayloadV2() {
  if (v2 === undefined) {
    v2 = python() !== null && spawnSync(python(), ['-c',
      'from pmwm_codec.format.extension import PAYLOAD_VERSIONS\nraise SystemExit(0 if 2 in PAYLOAD_VERSIONS else 1)'],
    { env: env(), stdio: 'ignore' }).status === 0;
  }
  return v2;
}

/**
 * Writes `file`: generated case `name` of test/lib/levels.py encoded with chunk payload `version`;
 * returns the reference decoder's levels: {levels: [{bytesRead, vertexCount, faceCount, parts, sha256}], complete}.
 */
export function encodeCase(name, version, file) {
  return JSON.parse(run([LEVELS, 'encode', name, String(version), file]));
}

/** The reference decoder's levels of each file ({levels, complete} as encodeCase), or {error: class name}. */
export function decodeFiles(files) {
  return JSON.parse(run([LEVELS, 'decode', ...files]));
}

/** Writes `out` (.glb): `pmw decode FILE --chunks N`, the reference decoder's level N as an ordinary GLB. */
export function decodeToGlb(file, chunks, out) {
  run(['-m', 'pmwm_codec', 'decode', file, '--chunks', String(chunks), '-o', out, '-q']);
}

/**
 * Reads the .pmw at `url` with the reference reader's UrlSource (pmwm_codec.http) up to `maxChunks` chunks (every one
 * when undefined), in a child process that leaves this one's event loop free (a server of the test's may answer it).
 */
export function readUrl(url, maxChunks) {
  const code = 'import sys\nfrom pmwm_codec.http import UrlSource\n'
    + 'for _ in UrlSource(sys.argv[1], max_chunks=int(sys.argv[2]) if sys.argv[2] else None): pass';
  return new Promise((resolve, reject) => {
    execFile(python(), ['-c', code, url, String(maxChunks ?? '')], { env: env() }, (error, stdout, stderr) => {
      if (error) reject(new Error(`reading ${url} with pmwm_codec.http failed: ${stderr || error}`));
      else resolve();
    });
  });
}

function run(args) {
  const out = spawnSync(python(), args, { env: env(), encoding: 'utf8', maxBuffer: 1 << 24 });
  if (out.status !== 0) throw new Error(`python ${args.join(' ')} failed (${out.status}): ${out.stderr || out.error}`);
  return out.stdout;
}

/**
 * A version 2 chunk of two batches whose first splits two adjacent vertices, each moving a face
 * that holds the other (lib/dependent_batches.py): {D, capN, capM, base: {values, faces}, chunk
 * (hex), final: {values, faces}}, final as the reference decoder gives it.
 */
export function dependentBatches() {
  return JSON.parse(run([join(dirname(fileURLToPath(import.meta.url)), 'dependent_batches.py')]));
}

/**
 * Face chunks written by the reference encoder (lib/face_chunks.py): `tetrahedron` gives {chunk,
 * flap (hex)}, the spec's examples (spec/bitstream.md §8.6); `sequence` gives {D, capN, capM, base:
 * {values, faces}, chunks: [{chunk (hex), face, splits, vertexCount, faceCount, values, faces}]}, one
 * primitive's chunks with face chunks (some adding vertices) between chunks that split, each with
 * the mesh after it as the reference decoder gives it.
 */
export function faceChunks(command) {
  return JSON.parse(run([join(dirname(fileURLToPath(import.meta.url)), 'face_chunks.py'), command]));
}

/**
 * Writes `<dir>/bunny.pmw`: the shared corpus' Stanford bunny encoded by `pmw encode` (Draco base,
 * default settings), or when ../shared is absent a generated mesh of similar size
 * (`shapes.icosphere(6)`, 40,962 vertices). Returns {file, source, report} where report is the
 * encoder's --json line (vertices, faces, chunks, bytes...).
 */
export function encodeBunny(dir) {
  let source = join(CORPUS, 'stanford-bunny.obj');
  if (!existsSync(source)) {
    source = join(dir, 'icosphere6.obj');
    run(['-c', 'import sys\nfrom pmwm_codec import meshio, shapes\nmeshio.write_mesh(sys.argv[1], shapes.icosphere(6))', source]);
  }
  const file = join(dir, 'bunny.pmw');
  const report = JSON.parse(run(['-m', 'pmwm_codec', 'encode', source, '-o', file, '--measure', 'none', '--json', '-q']));
  return { file, source, report };
}
