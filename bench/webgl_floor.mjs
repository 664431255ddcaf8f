// What a headless browser's WebGL costs before any surface of ours is in it: a three.js sphere of
// growing size drawn in Debian's chromium (SwiftShader, the viewer's canvas size), timed from the
// draw call to its fence signalling, as the viewer's page waits for it (web/viewer.js, gpuDone).
// The floor of the viewer's drag rate on a CPU-only machine: a fence takes this long to signal
// however fast the server answers.
//
// Usage: node bench/webgl_floor.mjs [--reps N]   (prints one JSON object; medians in ms)
import { createServer } from 'node:http';
import { readFileSync } from 'node:fs';
import { createRequire } from 'node:module';
import { dirname, join, normalize } from 'node:path';
import { fileURLToPath } from 'node:url';

const args = process.argv.slice(2);
const reps = Number(args.includes('--reps') ? args[args.indexOf('--reps') + 1] : 9);
const web = join(dirname(fileURLToPath(import.meta.url)), '..', 'web');
const { chromium } = createRequire(join(web, 'package.json'))('playwright-core');

// The page: the viewer's renderer settings for software rendering (no antialiasing, the drawing
// buffer preserved) and its material (Lambert, both sides).
const page = `<!doctype html><html><body style="margin:0"><canvas id="c" style="width:100vw;height:100vh;display:block"></canvas>
<script type="importmap">{"imports":{"three":"./node_modules/three/build/three.module.js"}}</script>
<script type="module">
import * as THREE from 'three';
const canvas = document.getElementById('c');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
renderer.setSize(window.innerWidth, window.innerHeight, false);
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(40, window.innerWidth / window.innerHeight, 0.01, 100);
camera.position.set(0, 0, 3);
scene.add(new THREE.HemisphereLight(0xffffff, 0x303040, 0.9));
const mesh = new THREE.Mesh(new THREE.BufferGeometry(), new THREE.MeshLambertMaterial({ color: 0xd9b38c, side: THREE.DoubleSide }));
scene.add(mesh);
const gl = renderer.getContext();
const fence = () => {
  const sync = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
  gl.flush();
  return new Promise((ok) => {
    const poll = () => { if (gl.getSyncParameter(sync, gl.SYNC_STATUS) === gl.SIGNALED) { gl.deleteSync(sync); ok(); } else setTimeout(poll, 2); };
    poll();
  });
};
window.draw = async (segments, reps) => {
  const times = [];
  for (let r = 0; r < reps; r++) {
    mesh.geometry.dispose();
    mesh.geometry = new THREE.SphereGeometry(1, segments, segments);
    const t0 = performance.now();
    renderer.render(scene, camera);
    await fence();
    times.push(performance.now() - t0);
  }
  times.sort((a, b) => a - b);
  return { triangles: mesh.geometry.index.count / 3, fence_ms: times[times.length >> 1] };
};
window.ready = true;
</script></body></html>`;

const server = createServer((req, res) => {
  const path = decodeURIComponent(req.url.split('?')[0]);
  if (path.startsWith('/node_modules/') && path.endsWith('.js')) {
    res.setHeader('Content-Type', 'text/javascript');
    res.end(readFileSync(join(web, normalize(path).replace(/^(\.\.[/\\])+/, ''))));
  } else {
    res.setHeader('Content-Type', 'text/html');
    res.end(page);
  }
}).listen(0, '127.0.0.1');
await new Promise((ok) => server.on('listening', ok));
const browser = await chromium.launch({ executablePath: process.env.CHROMIUM || '/usr/bin/chromium', headless: true,
  args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'] });
try {
  const tab = await browser.newPage({ viewport: { width: 1000, height: 700 } });
  await tab.goto(`http://127.0.0.1:${server.address().port}/`);
  await tab.waitForFunction(() => window.ready);
  const rows = [];
  for (const segments of [10, 40, 80, 160, 400]) rows.push(await tab.evaluate(([s, n]) => window.draw(s, n), [segments, reps]));
  console.log(JSON.stringify({ canvas: [1000, 700], reps, rows }));
} finally {
  await browser.close();
  server.close();
}
