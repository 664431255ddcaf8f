// The viewer in a real browser (Debian's chromium, headless, SwiftShader), driven like a user:
// `adaptiso view GRID.adg`, wait until the coarser levels are built, drag the iso slider for a few
// seconds (input events at 60 Hz), release it, and read the page's own timings
// (window.adaptisoSurfaces: request, server extraction, decode, upload + draw, from the input),
// and the page's main thread blocked (long tasks, during the measured drag). The page draws a
// surface only once the GPU has drawn the previous one, so "drawn" is on screen, not queued.
//
// Usage: node bench/viewer_bench.mjs ADAPTISO_CLI GRID.adg [--budget N | --distance D [--drag-distance D2]
//                                    [--drag-triangles T] [--collapse R] [--rest-after MS] [--drag-scale S]] [--from F --to T] [--seconds S]
//                                    [--pause MS]
// F and T are slider positions (0–1000). --budget drives the error levels (?levels=1: built first,
// waited for); --distance the surface-adaptive queries of a bisection grid (D at rest; while
// dragging at least D2, default 2, and coarser to keep near T triangles, the page's default
// 20,000; a huge T keeps D2; nothing to build; R rounds of edge collapses, the server's default
// when absent; --rest-after the page's ?rest-after, the pause in a drag after which it asks for the
// surface at rest; --drag-scale the page's ?drag-scale, the resolution dragged surfaces are drawn
// at, default 0.5 with software rendering). --pause: how long the slider is held at its last position before the release
// (default 1000 ms; 0 releases at once); with the distance mode's ?rest-after shorter than it, the
// surface at rest may be on screen before the release (ms_after_release 0, drawn_before_release).
// Prints one JSON object.
import { spawn } from 'node:child_process';
import { createRequire } from 'node:module';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const args = process.argv.slice(2);
const opt = (name, fallback) => { const i = args.indexOf(name); return i >= 0 ? args[i + 1] : fallback; };
const [cli, grid] = args;
const budget = Number(opt('--budget', 150000)), from = Number(opt('--from', 400)), to = Number(opt('--to', 600));
const seconds = Number(opt('--seconds', 4));
const distance = opt('--distance', null), dragDistance = opt('--drag-distance', '2');
const dragTriangles = opt('--drag-triangles', null), collapse = opt('--collapse', null), restAfter = opt('--rest-after', null);
const dragScale = opt('--drag-scale', null);
const pause = Number(opt('--pause', 1000));
const query = distance !== null
  ? `?distance=${distance}&drag-distance=${dragDistance}${dragTriangles ? `&drag-triangles=${dragTriangles}` : ''}${collapse !== null ? `&collapse=${collapse}` : ''}` +
    `${restAfter !== null ? `&rest-after=${restAfter}` : ''}${dragScale !== null ? `&drag-scale=${dragScale}` : ''}`
  : `?levels=1&budget=${budget}`;
const web = join(dirname(fileURLToPath(import.meta.url)), '..', 'web');
const { chromium } = createRequire(join(web, 'package.json'))('playwright-core');

const server = spawn(cli, ['view', grid, '--port', '0', '--web', web, '--quiet'], { stdio: ['ignore', 'pipe', 'inherit'] });
const url = await new Promise((ok, bad) => {
  let out = '';
  server.stdout.on('data', (d) => { out += d; const m = out.match(/http:\/\/[^\s]+\//); if (m) ok(m[0]); });
  server.on('exit', (code) => bad(new Error(`server exited with ${code}`)));
});
const browser = await chromium.launch({ executablePath: process.env.CHROMIUM || '/usr/bin/chromium', headless: true,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'] });
const median = (xs) => { const s = [...xs].sort((a, b) => a - b); return s.length ? s[Math.floor(s.length / 2)] : null; };
const p90 = (xs) => { const s = [...xs].sort((a, b) => a - b); return s.length ? s[Math.min(s.length - 1, Math.floor(0.9 * s.length))] : null; };
try {
  const page = await browser.newPage({ viewport: { width: 1000, height: 700 } });
  await page.addInitScript(() => {
    window.benchLongTasks = [];
    new PerformanceObserver((l) => { for (const e of l.getEntries()) window.benchLongTasks.push([e.startTime, e.duration]); })
      .observe({ type: 'longtask', buffered: true });
  });
  await page.goto(`${url}${query}`, { timeout: 600000 });
  await page.waitForFunction(() => (window.adaptisoSurfaces || []).length > 0, null, { timeout: 600000 });
  const t0 = Date.now();
  if (distance === null)
    await page.waitForFunction(() => fetch('api/info').then((r) => r.json()).then((j) => j.levels.every((l) => l.built)), null,
                               { timeout: 900000, polling: 500 });
  const levelsSeconds = (Date.now() - t0) / 1000;
  const info = await (await fetch(`${url}api/info`)).json();
  // Warm every level's extractor once (a first extraction on a level is a fresh march), as a user's
  // first drag would; then the measured drag.
  let firstMeasured = 0, dragStart = 0;
  for (const pass of ['warm', 'measure']) {
    if (pass === 'measure') [firstMeasured, dragStart] = await page.evaluate(() => [window.adaptisoSurfaces.length, performance.now()]);
    await page.evaluate(async ([a, b, s]) => {
      const el = document.getElementById('iso');
      const steps = Math.round(60 * s);
      for (let i = 0; i <= steps; i++) {
        el.value = String(Math.round(a + (b - a) * (i / steps)));
        el.dispatchEvent(new Event('input'));
        await new Promise((ok) => setTimeout(ok, 1000 / 60));
      }
    }, pass === 'warm' ? [from, to, 1] : [to, from, seconds]);
    if (pass === 'warm') await page.waitForTimeout(2000);
  }
  const [dragEnd, lastDrag] = await page.evaluate(() => [performance.now(), window.adaptisoSurfaces.length]);
  if (pause > 0) await page.waitForTimeout(pause);  // held at the last position
  const released = await page.evaluate(() => { document.getElementById('iso').dispatchEvent(new Event('change')); return performance.now(); });
  await page.waitForTimeout(Math.max(0, 1000 - pause));  // the last answers of the drag arrive
  const during = await page.evaluate(([n, end]) => window.adaptisoSurfaces.slice(n).filter((r) => r.coarse && r.at <= end + 1000),
                                     [firstMeasured, dragEnd]);
  const blocked = await page.evaluate(([a, b]) => window.benchLongTasks.filter(([t]) => t >= a && t <= b).map(([, d]) => d), [dragStart, dragEnd + 1000]);
  await page.waitForFunction((n) => window.adaptisoSurfaces.slice(n).some((r) => !r.coarse), lastDrag, { timeout: 120000 });
  const settled = await page.evaluate((n) => window.adaptisoSurfaces.slice(n).find((r) => !r.coarse), lastDrag);
  const measured = during.slice(Math.floor(during.length / 10));  // drop the first tenth (the drag's start)
  const span = measured.length > 1 ? (measured.at(-1).at - measured[0].at) / 1000 : 0;
  if (process.env.VIEWER_BENCH_TRACE) console.error(JSON.stringify(measured.map((r) => [Math.round(r.at), r.level, Math.round(r.request), Math.round(r.fromInput)])));
  console.log(JSON.stringify({
    grid, budget: distance === null ? budget : null, distance: distance === null ? null : Number(distance),
    drag_distance: distance === null ? null : Number(dragDistance), prepared_error: info.error_bound, levels: info.levels.length, levels_seconds: levelsSeconds,
    drag: {
      surfaces: measured.length, per_second: span > 0 ? (measured.length - 1) / span : null,
      // The steady rate, from the median interval, and the pauses (the page dropping a large mesh).
      steady_per_second: measured.length > 2 ? 1000 / median(measured.slice(1).map((r, i) => r.at - measured[i].at)) : null,
      pauses_over_1s: measured.slice(1).map((r, i) => r.at - measured[i].at).filter((g) => g > 1000).length,
      levels: [...new Set(measured.map((r) => r.level))], error_median: median(measured.map((r) => r.error)),
      triangles_median: median(measured.map((r) => r.triangles)),
      from_input_ms: { median: median(measured.map((r) => r.fromInput)), p90: p90(measured.map((r) => r.fromInput)) },
      from_input_uploaded_ms: { median: median(measured.map((r) => r.fromInputUploaded)), p90: p90(measured.map((r) => r.fromInputUploaded)) },
      from_input_drawn_ms: { median: median(measured.map((r) => r.fromInputDrawn)), p90: p90(measured.map((r) => r.fromInputDrawn)) },
      server_ms: median(measured.map((r) => r.server)), request_ms: median(measured.map((r) => r.request)),
      decode_ms: median(measured.map((r) => r.decode)), gpu_wait_ms: median(measured.map((r) => r.gpuWait)),
      draw_ms: median(measured.map((r) => r.draw)),
      // The page's thread busy for over 50 ms at a time (the slider then does not move).
      long_tasks: blocked.length, longest_task_ms: blocked.length ? Math.max(...blocked) : 0,
      bytes_per_triangle: median(measured.map((r) => r.bytes / Math.max(r.triangles, 1))),
    },
    rest: {
      ms_after_release: Math.max(0, settled.at - released), ms_after_last_input: settled.at - dragEnd,
      drawn_before_release: settled.at <= released, pause_ms: pause, error: settled.error, level: settled.level, triangles: settled.triangles,
      bytes_per_triangle: settled.bytes / Math.max(settled.triangles, 1), server_ms: settled.server, wait_ms: settled.wait,
      encode_ms: settled.encode, request_ms: settled.request,
      decode_ms: settled.decode, draw_ms: settled.draw,
    },
  }));
} finally {
  await browser.close();
  server.kill('SIGTERM');
}
