// A static file server on 127.0.0.1 (free port) with single-range Range support, for the tests.
// Counts body bytes sent (`stats.bytes`) and requests; `ranges: false` answers every GET whole (200);
// `delayMs` waits before each response (a throttled network); `mounts` serves more directories under
// URL prefixes ({'/data/': dir}: /data/x is dir/x). Per request, query parameters of a .pmw's URL:
// `cap=N` answers a Range request with at most N bytes (a short 206, as RFC 9110 allows), `fail=K` answers
// the K-th request for that URL (path and query) with HTTP 500, `cut=N` drops the connection after N bytes
// of a whole (200) answer, `stall=N` sends N bytes of a whole answer (at most all but one) and then nothing more (never ends),
// and of a Range answer reaching past byte N of the file, both send the bytes before byte N, then drop the connection
// (cut) or send nothing more (stall); `drip=MS`
// sends the body in pieces of 1,000 bytes, MS ms apart (`stats.sending`: the bodies being sent; `stats.dropped`: those
// whose connection the client closed before their end).
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';

const TYPES = { '.html': 'text/html', '.js': 'text/javascript', '.mjs': 'text/javascript', '.wasm': 'application/wasm',
  '.pmw': 'model/gltf-binary', '.json': 'application/json' };

export async function startServer(root, { ranges = true, delayMs = 0, mounts = {} } = {}) {
  const stats = { bytes: 0, requests: 0, log: [], asked: {}, sending: 0, dropped: 0 };
  const server = http.createServer(async (req, res) => {
    stats.requests++;
    const query = new URL(req.url, 'http://x').searchParams;
    const asked = (stats.asked[req.url] = (stats.asked[req.url] ?? 0) + 1);
    let rel = decodeURIComponent(new URL(req.url, 'http://x').pathname);
    const mount = Object.keys(mounts).find((prefix) => rel.startsWith(prefix));
    const base = mount ? mounts[mount] : root;
    if (mount) rel = rel.slice(mount.length - 1);
    const file = path.join(base, path.normalize(rel).replace(/^(\.\.[/\\])+/, ''));
    if (!file.startsWith(base) || !fs.existsSync(file) || !fs.statSync(file).isFile()) {
      res.writeHead(404, { 'Content-Length': 0 }); res.end(); return;
    }
    if (delayMs && file.endsWith('.pmw')) await new Promise((r) => setTimeout(r, delayMs));
    if (query.get('fail') && Number(query.get('fail')) === asked) {
      res.writeHead(500, { 'Content-Length': 0 }); res.end(); return;
    }
    const data = fs.readFileSync(file);
    const type = TYPES[path.extname(file)] ?? 'application/octet-stream';
    const m = ranges && /^bytes=(\d*)-(\d*)$/.exec(req.headers.range ?? '');
    let body = data;
    let from = 0; // the offset in the file of the body's first byte
    if (m && (m[1] || m[2])) {
      let start = m[1] === '' ? Math.max(0, data.length - Number(m[2])) : Number(m[1]);
      let end = m[1] === '' || m[2] === '' ? data.length : Math.min(Number(m[2]) + 1, data.length);
      if (query.get('cap')) end = Math.min(end, start + Number(query.get('cap')));
      if (start >= data.length || end <= start) {
        res.writeHead(416, { 'Content-Range': `bytes */${data.length}`, 'Content-Length': 0 }); res.end(); return;
      }
      body = data.subarray(start, end);
      from = start;
      res.writeHead(206, { 'Content-Type': type, 'Content-Length': body.length, 'Accept-Ranges': 'bytes',
        'Content-Range': `bytes ${start}-${end - 1}/${data.length}`, 'Cache-Control': 'no-store' });
    } else {
      res.writeHead(200, { 'Content-Type': type, 'Content-Length': body.length, 'Cache-Control': 'no-store' });
    }
    if (file.endsWith('.pmw')) { stats.bytes += body.length; stats.log.push(req.headers.range ?? 'whole'); }
    const stop = query.get('cut') ?? query.get('stall');
    let only = body === data ? stop : null; // a whole answer, cut or stalled
    if (only !== null) only = Math.min(Number(only), body.length - 1); // never the whole body: it never ends
    else if (stop !== null && from + body.length > Number(stop)) only = Math.max(0, Number(stop) - from); // a Range answer
    if (only !== null) {
      res.write(body.subarray(0, only));
      if (query.get('cut')) setTimeout(() => res.socket?.destroy(), 20); // else: stalls until closed
      return;
    }
    const drip = Number(query.get('drip') ?? 0);
    if (drip) {
      stats.sending++;
      let closed = false;
      res.on('close', () => { closed = true; });
      for (let at = 0; at < body.length && !closed; at += 1000) {
        res.write(body.subarray(at, at + 1000));
        await new Promise((r) => setTimeout(r, drip));
      }
      stats.sending--;
      if (closed) stats.dropped++;
    }
    res.end(drip ? undefined : body);
  });
  await new Promise((resolve) => server.listen(0, '127.0.0.1', resolve));
  const url = `http://127.0.0.1:${server.address().port}/`;
  const close = () => new Promise((resolve) => { server.closeAllConnections?.(); server.close(resolve); });
  return { url, stats, close };
}
