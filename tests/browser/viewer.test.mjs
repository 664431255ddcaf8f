// End-to-end test of `adaptiso view` in a real browser: Debian's chromium, headless, driven by
// playwright-core (nothing is downloaded). Loads the page for the paper's sphere, moves the slider,
// checks the triangle count in #stats follows and matches /api/surface, checks the canvas is not
// blank, checks every file the pages load answers 200, and saves a screenshot.
// Usage: node viewer.test.mjs ADAPTISO_CLI ARTIFACT_DIR [installed]
// With `installed`, ADAPTISO_CLI is an installed program and serves the page it finds beside itself
// (no --web), and the drags at a distance (which load no file) are left to the source tree's run.
// Exit code 77 (skipped) only when node modules or chromium are missing.
import { spawn, execFileSync } from 'node:child_process';
import { createRequire } from 'node:module';
import { existsSync, mkdirSync, mkdtempSync, readFileSync, rmSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const [cli, artifacts, mode] = process.argv.slice(2);
const installed = mode === 'installed';
const here = dirname(fileURLToPath(import.meta.url));
const web = join(here, '..', '..', 'web');
const chromiumPath = process.env.CHROMIUM || '/usr/bin/chromium';
let chromium;
try {
  ({ chromium } = createRequire(join(web, 'package.json'))('playwright-core'));
} catch (e) {
  console.log(`SKIP: playwright-core is not installed in ${web}/node_modules (run scripts/deps.sh)`);
  process.exit(77);
}
if (!existsSync(chromiumPath)) {
  console.log(`SKIP: no chromium at ${chromiumPath} (apt-get install chromium)`);
  process.exit(77);
}

const fail = (msg) => { console.error(`FAIL: ${msg}`); cleanup(); process.exit(1); };
const tmp = mkdtempSync(join(tmpdir(), 'adaptiso-view-'));
let server, browser;
function cleanup() {
  if (server) server.kill('SIGTERM');
  rmSync(tmp, { recursive: true, force: true });
}
setTimeout(() => fail('timed out after 150 s'), 150000).unref();

// ADAPTISO_VIEW_VOLUME runs the same checks on another volume (e.g. a CT from ../shared/data).
let volume = process.env.ADAPTISO_VIEW_VOLUME;
if (!volume) {
  volume = join(tmp, 'sphere.nrrd');
  execFileSync(cli, ['generate', 'sphere', '--size', '50', '-o', volume]);
}
server = spawn(cli, ['view', volume, '--relative', '--max-error', process.env.ADAPTISO_VIEW_ERROR || '0.15', '--port', '0',
                    ...(installed ? [] : ['--web', web]), '--quiet'],
               { stdio: ['ignore', 'pipe', 'inherit'] });
const url = await new Promise((ok, bad) => {
  let out = '';
  server.stdout.on('data', (d) => { out += d; const m = out.match(/http:\/\/[^\s]+\//); if (m) ok(m[0]); });
  server.on('exit', (code) => bad(new Error(`server exited with ${code}`)));
}).catch((e) => fail(e.message));

// With a distance, the surface the page draws: no edge collapses unless the page was given ?collapse=.
async function apiTriangles(iso, distance = '') {
  const within = distance === '' || distance == null ? '' : `&distance=${distance}&collapse=0`;
  const r = await fetch(`${url}api/surface?iso=${encodeURIComponent(iso)}&client=test-check${within}`);
  if (!r.ok) fail(`/api/surface answered ${r.status}`);
  const buf = await r.arrayBuffer();
  const [V, T] = new Uint32Array(buf, 0, 2);
  if (Number(r.headers.get('X-Triangles')) !== T) fail('X-Triangles disagrees with the body');
  return T;
}

// The page's decoding of the compact answer against the plain one (f32 positions and normals) of
// the same surface: fresh extractions of two new clients, so the same triangles in the same order
// (the index codec may rotate a triangle's corners); positions within half a 16-bit step of the
// bounding box, normals within 1° (the octahedral bytes: about 0.6° at worst).
async function checkCompactDecoding(page, iso) {
  const r = await fetch(`${url}api/surface?iso=${encodeURIComponent(iso)}&client=test-plain`);
  const buf = await r.arrayBuffer();
  const [V, T] = new Uint32Array(buf, 0, 2);
  const pos = new Float32Array(buf, 8, 3 * V), nrm = new Float32Array(buf, 8 + 12 * V, 3 * V), idx = new Uint32Array(buf, 8 + 24 * V, 3 * T);
  const got = await page.evaluate(async (i) => {
    const b = await (await fetch(`api/surface?iso=${encodeURIComponent(i)}&client=test-compact&format=compact`)).arrayBuffer();
    const d = await window.adaptisoDecodeCompact(b);
    return { positions: Array.from(d.positions), normals: Array.from(d.normals), indices: Array.from(d.indices) };
  }, iso);
  if (got.indices.length !== 3 * T) fail(`compact decoding: ${got.indices.length / 3} triangles, plain ${T}`);
  const tol = [0, 1, 2].map((a) => {
    let lo = Infinity, hi = -Infinity;
    for (let v = 0; v < V; v++) { lo = Math.min(lo, pos[3 * v + a]); hi = Math.max(hi, pos[3 * v + a]); }
    return 0.51 * (hi - lo) / 65535 + 1e-6 * Math.max(Math.abs(lo), Math.abs(hi));
  });
  const close = (p, q) => [0, 1, 2].every((a) => Math.abs(got.positions[3 * p + a] - pos[3 * q + a]) <= tol[a]);
  const angle = (p, q) => Math.acos(Math.min(1, [0, 1, 2].reduce((s, a) => s + got.normals[3 * p + a] * nrm[3 * q + a], 0))) * 180 / Math.PI;
  for (let t = 0; t < T; t++) {
    const r0 = [0, 1, 2].find((r) => [0, 1, 2].every((c) => close(got.indices[3 * t + (c + r) % 3], idx[3 * t + c])));
    if (r0 === undefined) fail(`compact decoding: triangle ${t}'s corners are not the plain answer's`);
    for (let c = 0; c < 3; c++) {
      const a = angle(got.indices[3 * t + (c + r0) % 3], idx[3 * t + c]);
      if (!(a <= 1)) fail(`compact decoding: triangle ${t} corner ${c}: normal off by ${a}°`);
    }
  }
}

// The page's decoding of several index streams (the server sends ⌈T / 2^20⌉ of them, encoded side
// by side), against an independent construction: a compact answer's single stream decoded here
// with meshoptimizer's own decoder, cut into 3 streams, each rotated down by its base (1 + the
// largest index before it) and encoded with meshoptimizer's encoder, the buffer laid out as
// mesh_codec.hpp says. The page must give back the same triangles (corners possibly rotated).
async function checkStreamedDecoding(page, iso) {
  const { MeshoptDecoder, MeshoptEncoder } = await import(join(web, 'node_modules', 'meshoptimizer', 'index.module.js'));
  await MeshoptDecoder.ready;
  await MeshoptEncoder.ready;
  const one = new Uint8Array(await (await fetch(`${url}api/surface?iso=${encodeURIComponent(iso)}&client=test-streams&format=compact`)).arrayBuffer());
  const view = new DataView(one.buffer);
  const V = view.getUint32(4, true), T = view.getUint32(8, true), vbytes = view.getUint32(36, true);
  if (view.getUint32(40 + vbytes, true) !== 1 || T < 30) fail(`streamed decoding: expected one index stream of a few triangles, got T = ${T}`);
  const ibytes = view.getUint32(44 + vbytes + 8, true);
  const indices = new Uint32Array(3 * T);
  MeshoptDecoder.decodeIndexBuffer(new Uint8Array(indices.buffer), 3 * T, 4, one.subarray(56 + vbytes, 56 + vbytes + ibytes));
  const cuts = [0, Math.floor(T / 3), Math.floor((2 * T) / 3), T], table = [], streams = [];
  let top = -1;
  for (let k = 0; k < 3; k++) {
    const part = indices.slice(3 * cuts[k], 3 * cuts[k + 1]);
    const base = k === 0 ? 0 : top + 1;
    for (const x of part) top = Math.max(top, x);
    const rotated = part.map((x) => (x >= base ? x - base : x + (V - base)));
    const bytes = MeshoptEncoder.encodeIndexBuffer(new Uint8Array(rotated.buffer), rotated.length, 4);
    table.push(cuts[k + 1] - cuts[k], base, bytes.length);
    streams.push(bytes);
  }
  const head = one.subarray(0, 40 + vbytes);
  const out = new Uint8Array(head.length + 4 + 4 * table.length + streams.reduce((s, b) => s + b.length, 0));
  out.set(head);
  new DataView(out.buffer).setUint32(head.length, 3, true);
  table.forEach((x, i) => new DataView(out.buffer).setUint32(head.length + 4 + 4 * i, x, true));
  let at = head.length + 4 + 4 * table.length;
  for (const b of streams) { out.set(b, at); at += b.length; }
  const got = await page.evaluate(async (bytes) => Array.from((await window.adaptisoDecodeCompact(new Uint8Array(bytes).buffer)).indices),
                                  Array.from(out));
  if (got.length !== 3 * T) fail(`streamed decoding: ${got.length / 3} triangles, expected ${T}`);
  for (let t = 0; t < T; t++) {
    const same = [0, 1, 2].some((r) => [0, 1, 2].every((c) => got[3 * t + (c + r) % 3] === indices[3 * t + c]));
    if (!same) fail(`streamed decoding: triangle ${t} is [${got.slice(3 * t, 3 * t + 3)}], expected [${indices.slice(3 * t, 3 * t + 3)}]`);
  }
}

try {
  browser = await chromium.launch({ executablePath: chromiumPath, headless: true,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'] });
  // Every file a page loads from the server (the API aside, whose answers the checks below read),
  // and every request that failed outright.
  const assets = new Map(), failed = [], aborted = new Set();  // aborted: surfaces held back that the page may drop
  const watch = (p) => {
    p.on('response', (r) => {
      const u = new URL(r.url());
      if (r.url().startsWith(url) && !u.pathname.startsWith('/api/')) assets.set(u.pathname, r.status());
    });
    // A surface at rest that a resumed drag overtook is aborted by the page, on purpose.
    const overtaken = (r) => r.failure()?.errorText === 'net::ERR_ABORTED' && /\/api\/surface\?/.test(r.url()) && aborted.has(r.url());
    p.on('requestfailed', (r) => { if (r.url().startsWith(url) && !overtaken(r)) failed.push(`${r.url()}: ${r.failure()?.errorText}`); });
    return p;
  };
  const page = watch(await browser.newPage({ viewport: { width: 1000, height: 700 } }));
  const errors = [];
  page.on('pageerror', (e) => errors.push(e.message));
  await page.goto(url, { waitUntil: 'load' });
  const notServed = () => [...assets].filter(([, status]) => status !== 200);
  if (notServed().length || failed.length) fail(`files the page loads did not answer 200: ${JSON.stringify(notServed())} ${failed.join('; ')}`);
  await page.waitForFunction(() => /triangles: [1-9]/.test(document.getElementById('stats').textContent), null, { timeout: 60000 });
  // In one evaluation: the page replaces a dragged surface with the one at rest between two
  // round trips, so reading the text and the attributes one by one could pair a dragged surface's
  // count with the rest surface's distance (CI saw 336 triangles at D = 2 checked against 0.5's 708).
  const read = () => page.evaluate(() => {
    const s = document.getElementById('stats');
    return { text: s.textContent, iso: s.dataset.iso, distance: s.dataset.distance };
  });
  const first = await read();
  const t1 = Number(first.text.match(/triangles: (\d+)/)[1]);
  // A bisection grid: the page asks for surfaces within a distance (0.5 voxels at rest by default).
  if (first.distance !== '0.5') fail(`the first surface is not the one within 0.5 voxels: data-distance '${first.distance}'`);
  const api1 = await apiTriangles(first.iso, first.distance);
  if (t1 !== api1) fail(`stats say ${t1} triangles, the API ${api1} at iso ${first.iso}, distance ${first.distance}`);
  if (!(t1 < await apiTriangles(first.iso))) fail(`the surface within 0.5 voxels has no fewer triangles than the grid's (${t1})`);
  await checkCompactDecoding(page, first.iso);
  await checkStreamedDecoding(page, first.iso);
  // Drag the slider to 80 % of the range (input events, as a user's drag produces).
  await page.evaluate(() => {
    const s = document.getElementById('iso');
    for (let v = Number(s.value); v <= 800; v += 25) { s.value = String(v); s.dispatchEvent(new Event('input')); }
  });
  await page.waitForFunction((old) => document.getElementById('stats').dataset.iso !== old &&
    Math.abs(Number(document.getElementById('iso-value').value) - Number(document.getElementById('stats').dataset.iso)) <
      1e-3 * Math.abs(Number(document.getElementById('stats').dataset.iso)), first.iso, { timeout: 30000 });
  const second = await read();
  const t2 = Number(second.text.match(/triangles: (\d+)/)[1]);
  if (t2 === t1) fail(`the triangle count did not change when the slider moved (${t1})`);
  const api2 = await apiTriangles(second.iso, second.distance);
  if (t2 !== api2) fail(`after the move: stats ${t2} triangles, API ${api2} at iso ${second.iso}`);
  // The canvas shows something: the variance of its luminance is well above zero.
  await page.waitForTimeout(500);
  const variance = await page.evaluate(() => {
    const src = document.getElementById('view');
    const c = document.createElement('canvas');
    c.width = 200; c.height = 140;
    const ctx = c.getContext('2d');
    ctx.drawImage(src, 0, 0, c.width, c.height);
    const d = ctx.getImageData(0, 0, c.width, c.height).data;
    let s = 0, s2 = 0; const n = d.length / 4;
    for (let i = 0; i < d.length; i += 4) { const y = 0.3 * d[i] + 0.59 * d[i + 1] + 0.11 * d[i + 2]; s += y; s2 += y * y; }
    return s2 / n - (s / n) ** 2;
  });
  if (!(variance > 20)) fail(`the canvas looks blank (luminance variance ${variance})`);
  // The page draws on demand: turning the view with the mouse redraws it.
  const pixels = () => page.evaluate(() => {
    const src = document.getElementById('view'), c = document.createElement('canvas');
    c.width = 100; c.height = 70;
    const ctx = c.getContext('2d');
    ctx.drawImage(src, 0, 0, c.width, c.height);
    return Array.from(ctx.getImageData(0, 0, c.width, c.height).data);
  });
  const unturned = await pixels();
  await page.mouse.move(500, 350);
  await page.mouse.down();
  await page.mouse.move(650, 380, { steps: 8 });
  await page.mouse.up();
  await page.waitForTimeout(300);
  const after = await pixels();
  const changed = after.filter((v, i) => Math.abs(v - unturned[i]) > 8).length;
  if (changed < 0.01 * after.length) fail(`turning the view with the mouse did not redraw the canvas (${changed} values changed)`);
  // The installed page loads the same files as the source tree's (checked below): the drags at a
  // distance, which load none, run once, on the source tree (they are half this test's time).
  if (!installed) {
    // Distances: dragging shows surfaces within 2 voxels, releasing settles on the distance chosen
    // (?distance=1 here), each the server's surface at that distance, coarse first.
    const near = watch(await browser.newPage({ viewport: { width: 800, height: 600 } }));
    near.on('pageerror', (e) => errors.push(e.message));
    await near.goto(`${url}?distance=1`);
    await near.waitForFunction(() => (window.adaptisoSurfaces || []).length > 0, null, { timeout: 60000 });
    const nearBefore = await near.evaluate(() => window.adaptisoSurfaces.length);
    await near.evaluate(async () => {  // a drag: input events 30 ms apart, then the release
      const s = document.getElementById('iso');
      for (let v = 400; v <= 700; v += 20) { s.value = String(v); s.dispatchEvent(new Event('input')); await new Promise((ok) => setTimeout(ok, 30)); }
      s.dispatchEvent(new Event('change'));
    });
    await near.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => !r.coarse), nearBefore, { timeout: 30000 });
    const nearShown = await near.evaluate((n) => window.adaptisoSurfaces.slice(n), nearBefore);
    const drags = nearShown.filter((r) => r.coarse), rest = nearShown.filter((r) => !r.coarse);
    if (!drags.length || drags.some((r) => r.distance !== 2)) fail(`dragged surfaces are not within 2 voxels: ${JSON.stringify(drags.map((r) => r.distance))}`);
    if (rest.at(-1).distance !== 1) fail(`the surface at rest is not within the distance chosen (1): ${rest.at(-1).distance}`);
    // SwiftShader here: the dragged surfaces are drawn at half the canvas's resolution, the surface
    // at rest at full resolution (the page's 800×600).
    const software = await near.evaluate(() => /swiftshader|llvmpipe|software/i.test(String((() => {
      const gl = document.createElement('canvas').getContext('webgl2');
      const info = gl?.getExtension('WEBGL_debug_renderer_info');
      return gl ? gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER) : '';
    })())));
    const full = JSON.stringify([800, 600]), half = JSON.stringify([400, 300]);
    if (JSON.stringify(rest.at(-1).pixels) !== full) fail(`the surface at rest was drawn at ${rest.at(-1).pixels}, not ${full}`);
    if (software && drags.some((r) => JSON.stringify(r.pixels) !== half)) fail(`dragged surfaces were drawn at ${JSON.stringify(drags.map((r) => r.pixels))}, not ${half}`);
    const restIso = rest.at(-1).iso;  // the record's own, not a later read of the panel
    if (rest.at(-1).triangles !== await apiTriangles(restIso, 1)) fail(`the surface at rest has ${rest.at(-1).triangles} triangles, the API ${await apiTriangles(restIso, 1)}`);
    // Each dragged surface is the server's at its own iso-value and 2 voxels (the last drag may stop
    // short of the release's iso-value, so its count is not compared with the surface at rest's).
    const lastDrag = drags.at(-1);
    if (lastDrag.triangles !== await apiTriangles(lastDrag.iso, 2)) fail(`the last dragged surface has ${lastDrag.triangles} triangles, the API ${await apiTriangles(lastDrag.iso, 2)} at iso ${lastDrag.iso}, distance 2`);
    if ((await near.locator('#stats').getAttribute('data-distance')) !== '1') fail('#stats does not say the distance of the surface shown');
    console.log(`distance: ${drags.length} dragged surfaces within 2 voxels (${drags.at(-1).triangles} triangles, drawn at ${drags.at(-1).pixels.join('×')}), at rest within 1 voxel (${rest.at(-1).triangles} triangles, ${rest.at(-1).pixels.join('×')})`);
    await near.close();
    // Held still while dragging (?rest-after=150), the page asks for the surface at rest before the
    // release, and the release then asks for nothing more. A drag that resumes while that surface is
    // on its way overtakes it: here its answer is held back 3 s, and the dragged surfaces still come
    // meanwhile (the page aborted the request; the server cancels the query, tests/view).
    const holding = watch(await browser.newPage({ viewport: { width: 800, height: 600 } }));
    holding.on('pageerror', (e) => errors.push(e.message));
    await holding.goto(`${url}?distance=1&rest-after=150`);
    await holding.waitForFunction(() => (window.adaptisoSurfaces || []).length > 0, null, { timeout: 60000 });
    const drag = (from, to) => holding.evaluate(async ([a, b]) => {
      const s = document.getElementById('iso');
      for (let v = a; a < b ? v <= b : v >= b; v += a < b ? 20 : -20) { s.value = String(v); s.dispatchEvent(new Event('input')); await new Promise((ok) => setTimeout(ok, 30)); }
    }, [from, to]);
    const rests = async (n) => (await holding.evaluate((k) => window.adaptisoSurfaces.slice(k), n)).filter((r) => !r.coarse);
    const stillBefore = await holding.evaluate(() => window.adaptisoSurfaces.length);
    await drag(400, 600);
    await holding.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => !r.coarse), stillBefore, { timeout: 30000 });
    if ((await rests(stillBefore)).at(-1).distance !== 1) fail('the surface at rest asked for while the slider was held is not within 1 voxel');
    await holding.evaluate(() => document.getElementById('iso').dispatchEvent(new Event('change')));
    await holding.waitForTimeout(1000);
    const held = await rests(stillBefore);
    if (held.length !== 1) fail(`held still and released, the page drew ${held.length} surfaces at rest, not 1`);
    let delayed = 0;
    await holding.route(/api\/surface.*distance=1&/, async (route) => {
      ++delayed;
      aborted.add(route.request().url());
      await new Promise((ok) => setTimeout(ok, 3000));
      await route.continue().catch(() => {});  // aborted by the page meanwhile
    });
    await drag(600, 500);
    await holding.waitForTimeout(400);  // held: the surface at rest is asked for, and held back
    const resumed = await holding.evaluate(() => window.adaptisoSurfaces.length);
    const t0 = Date.now();
    await drag(500, 400);
    await holding.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => r.coarse), resumed, { timeout: 30000 });
    const waited = Date.now() - t0;
    if (!delayed) fail('holding the slider still did not ask for the surface at rest');
    if (waited > 2500) fail(`a drag that resumed waited ${waited} ms for the surface at rest it overtook`);
    await holding.unroute(/api\/surface.*distance=1&/);
    await holding.evaluate(() => document.getElementById('iso').dispatchEvent(new Event('change')));
    await holding.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => !r.coarse), resumed, { timeout: 30000 });
    if (/^error:/.test(await holding.locator('#status').textContent())) fail(`the page shows an error after a drag overtook the surface at rest: ${await holding.locator('#status').textContent()}`);
    console.log(`held still: the surface at rest drawn once before the release; a resumed drag drew its first surface ${waited} ms after it started, the surface at rest held back`);
    await holding.close();
    // An intricate surface while dragging: with a target of 300 triangles (the sphere has 1,188
    // within 2 voxels) the dragged surfaces go coarser than ?drag-distance, each stating the
    // distance it was asked at and being the server's surface at that distance.
    const lean = watch(await browser.newPage({ viewport: { width: 800, height: 600 } }));
    lean.on('pageerror', (e) => errors.push(e.message));
    await lean.goto(`${url}?distance=1&drag-triangles=300`);
    await lean.waitForFunction(() => (window.adaptisoSurfaces || []).length > 0, null, { timeout: 60000 });
    const leanBefore = await lean.evaluate(() => window.adaptisoSurfaces.length);
    await lean.evaluate(async () => {
      const s = document.getElementById('iso');
      for (let v = 400; v <= 700; v += 10) { s.value = String(v); s.dispatchEvent(new Event('input')); await new Promise((ok) => setTimeout(ok, 30)); }
      s.dispatchEvent(new Event('change'));
    });
    await lean.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => !r.coarse), leanBefore, { timeout: 30000 });
    const leanDrags = (await lean.evaluate((n) => window.adaptisoSurfaces.slice(n), leanBefore)).filter((r) => r.coarse);
    if (!leanDrags.some((r) => r.distance > 2) || leanDrags.some((r) => !(r.distance >= 2 && r.distance <= 64)))
      fail(`dragged surfaces with a 300-triangle target did not go coarser than 2 voxels (within [2, 64]): ${JSON.stringify(leanDrags.map((r) => r.distance))}`);
    const leanLast = leanDrags.at(-1);
    if (leanLast.triangles !== await apiTriangles(leanLast.iso, leanLast.distance))
      fail(`the last dragged surface has ${leanLast.triangles} triangles, the API ${await apiTriangles(leanLast.iso, leanLast.distance)} at distance ${leanLast.distance}`);
    console.log(`drag target: distances ${leanDrags.map((r) => r.distance).join(' ')}, last ${leanLast.triangles} triangles`);
    await lean.close();
  }
  // Level of detail (?levels=1, the error levels on a bisection grid too): with a small triangle
  // budget, dragging shows coarser surfaces with their (larger) guaranteed error; releasing the
  // slider settles on the prepared surface and error.
  const lod = watch(await browser.newPage({ viewport: { width: 800, height: 600 }, acceptDownloads: true }));
  lod.on('pageerror', (e) => errors.push(e.message));
  await lod.goto(`${url}?levels=1&budget=${process.env.ADAPTISO_VIEW_BUDGET || 300}`);
  await lod.waitForFunction(() => (window.adaptisoSurfaces || []).length > 0, null, { timeout: 60000 });
  const info = await (await fetch(`${url}api/info`)).json();
  if (info.levels.length < 2) fail(`no coarser levels offered (${JSON.stringify(info.levels)})`);
  await lod.waitForFunction((n) => fetch('api/info').then((r) => r.json()).then((j) => j.levels.filter((l) => l.built).length === n),
                            info.levels.length, { timeout: 60000, polling: 200 });
  const before = await lod.evaluate(() => window.adaptisoSurfaces.length);
  await lod.evaluate(async () => {  // a drag: input events 30 ms apart, then the release
    const s = document.getElementById('iso');
    for (let v = 400; v <= 700; v += 20) { s.value = String(v); s.dispatchEvent(new Event('input')); await new Promise((ok) => setTimeout(ok, 30)); }
  });
  await lod.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => r.coarse && r.level > 0), before, { timeout: 30000 });
  const dragged = await lod.evaluate((n) => window.adaptisoSurfaces.slice(n).filter((r) => r.coarse), before);
  const coarse = dragged.filter((r) => r.level > 0);
  // A level coarsened by its bound has a larger one; a floored level's surface has the error of
  // the tetrahedra it cuts, within the level's bound (measured once built), and may be as small as
  // the prepared one on a smooth field.
  const built = (await (await fetch(`${url}api/info`)).json()).levels;
  const claims = (r) => (built[r.level].cell_floor ? r.error <= built[r.level].bound * (1 + 1e-12) : r.error > info.error_bound);
  const wrong = coarse.find((r) => !claims(r));
  if (wrong) fail(`a coarse surface claims a wrong error: ${JSON.stringify(wrong)} (levels ${JSON.stringify(built)})`);
  await lod.evaluate(() => document.getElementById('iso').dispatchEvent(new Event('change')));
  await lod.waitForFunction((e) => document.getElementById('stats').dataset.level === '0' &&
    Number(document.getElementById('stats').dataset.error) === e && !/coarse while dragging/.test(document.getElementById('stats').textContent),
    info.error_bound, { timeout: 30000 });
  const settled = await lod.evaluate(() => window.adaptisoSurfaces.at(-1));
  if (settled.coarse || settled.level !== 0) fail(`the surface at rest is not the prepared one: ${JSON.stringify(settled)}`);
  // Frame pacing: no surface goes to the GPU (at - draw) before the previous one is drawn (at),
  // except a small one while dragging (at most 100,000 triangles, web/viewer.js), which may wait
  // behind the one being drawn but not behind two. In the order they went to the GPU: surfaces
  // are recorded as their fences are seen to signal, two in the same poll in either order.
  const shown = (await lod.evaluate((n) => window.adaptisoSurfaces.slice(n), before)).sort((a, b) => a.at - a.draw - (b.at - b.draw));
  const early = shown.findIndex((r, i) => {
    const behind = r.coarse && r.triangles <= 100000 ? 2 : 1;
    return i >= behind && r.at - r.draw < shown[i - behind].at - 0.5;
  });
  if (early > 0) fail(`a surface went to the GPU before the ones ahead of it were drawn: ${JSON.stringify(shown.slice(Math.max(0, early - 2), early + 1))}`);
  // A software renderer (SwiftShader here) draws without antialiasing.
  if (await lod.evaluate(() => document.getElementById('view').getContext('webgl2').getContextAttributes().antialias))
    fail('the page antialiases on a software renderer');
  console.log(`level of detail: ${coarse.length} of ${dragged.length} dragged surfaces coarse (levels ` +
              `${[...new Set(coarse.map((r) => r.level))].join(',')}, errors up to ${Math.max(...coarse.map((r) => r.error)).toPrecision(3)}), ` +
              `settled at error ${settled.error.toPrecision(4)} with ${settled.triangles} triangles, ${(settled.bytes / Math.max(settled.triangles, 1)).toFixed(2)} bytes/triangle`);
  // Export: the download button gives the surface on screen, simplified, as a .glb file.
  const [download] = await Promise.all([lod.waitForEvent('download', { timeout: 30000 }), lod.click('#export')]);
  const saved = join(tmp, 'export.glb');
  await download.saveAs(saved);
  const head = readFileSync(saved).subarray(0, 4).toString();
  if (!download.suggestedFilename().endsWith('.glb') || head !== 'glTF') fail(`export gave ${download.suggestedFilename()} starting '${head}'`);
  await lod.close();
  // State from the address (scripts/figures.sh draws the paper's figures this way): the iso-value,
  // the layers and a hidden panel, and body[data-ready] once every layer is drawn.
  const wantedIso = info.min + 0.7 * (info.max - info.min);
  const still = watch(await browser.newPage({ viewport: { width: 400, height: 300 } }));
  still.on('pageerror', (e) => errors.push(e.message));
  await still.goto(`${url}?${new URLSearchParams({ iso: String(wantedIso), show: 'surface,tets,points', panel: 'hide', camera: '1,0,0', up: '0,1,0', levels: '1' })}`);
  await still.waitForSelector('body[data-ready="1"]', { timeout: 60000 });
  const state = await still.evaluate(() => ({
    iso: Number(document.getElementById('stats').dataset.iso), panel: getComputedStyle(document.getElementById('panel')).display,
    layers: ['surface', 'points', 'tets', 'reference'].map((l) => document.getElementById(`show-${l}`).checked),
    active: Number(/active tetrahedra: (\d+)/.exec(document.getElementById('stats').textContent)[1]) }));
  if (state.iso !== wantedIso || state.panel !== 'none' || state.layers.join() !== 'true,true,true,false' || !(state.active > 0))
    fail(`the page did not take its state from the address: ${JSON.stringify(state)}`);
  await still.close();
  // Toggles: kept vertices and the full-resolution reference load without errors.
  await page.check('#show-points');
  await page.check('#show-reference');
  await page.waitForFunction(() => /reference triangles: [1-9]/.test(document.getElementById('stats').textContent), null, { timeout: 30000 });
  if (errors.length) fail(`page errors: ${errors.join('; ')}`);
  if (notServed().length || failed.length) fail(`files the page loads did not answer 200: ${JSON.stringify(notServed())} ${failed.join('; ')}`);
  for (const f of ['/', '/viewer.js', '/style.css'])
    if (!assets.has(f)) fail(`the page never loaded ${f} (loaded: ${[...assets.keys()].join(', ')})`);
  if (![...assets.keys()].some((f) => f.endsWith('three.module.js'))) fail(`the page never loaded three.js (loaded: ${[...assets.keys()].join(', ')})`);
  mkdirSync(artifacts, { recursive: true });
  await page.locator('#view').screenshot({ path: join(artifacts, 'viewer.png') });
  console.log(`PASS${installed ? ' (installed)' : ''}: ${t1} → ${t2} triangles, canvas variance ${variance.toFixed(0)}, ` +
              `${assets.size} files loaded with 200, screenshot ${join(artifacts, 'viewer.png')}`);
} catch (e) {
  fail(e.stack || String(e));
} finally {
  if (browser) await browser.close();
  cleanup();
}
process.exit(0);
