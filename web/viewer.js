// adaptiso viewer page: talks to `adaptiso view` (docs/API.md), draws with three.js.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { MeshoptDecoder } from 'meshoptimizer/decoder';

const $ = (id) => document.getElementById(id);
const client = Math.random().toString(36).slice(2, 12);  // this page's sweep state on the server
const params = new URLSearchParams(location.search);
// On a bisection grid the page asks for surfaces within a distance of the grid's own (voxels):
// the one chosen at rest (?distance=D), a coarser one while the iso slider is dragged: at least
// ?drag-distance=D (default 2), more where the surface is intricate, so that a dragged surface
// keeps near ?drag-triangles=N (default 20,000; see nextDragDistance). On a Delaunay grid the
// server picks, while dragging, the level of detail that fits this many triangles (?budget=N),
// and the surface at the chosen error follows when the slider rests.
const budget = Number(params.get('budget')) || 150000;
const startDistance = params.has('distance') ? Number(params.get('distance')) : NaN;
// The error levels even on a bisection grid: ?levels=1, or an error given (?error=E: the paper's
// figures, scripts/figures.sh).
const useLevels = params.get('levels') === '1' || params.has('error');
const dragDistance = Number(params.get('drag-distance')) || 2;
const dragTriangles = Number(params.get('drag-triangles')) || 20000;
// ?collapse=R: rounds of edge collapses after each distance query the page draws. 0 by default:
// on the CT bunny's noisy mid-range surface two rounds took 866 k → 531 k triangles within 0.5
// voxels but added 0.5 s to the server's 0.6 s, more than SwiftShader's drawing saved (0.5 → 0.32
// s), and slowed dragging from 9.5 to 7-8 surfaces a second. Exports keep the server's default
// (the command line's surface) unless ?collapse= is given.
const collapseGiven = params.has('collapse') ? `&collapse=${encodeURIComponent(params.get('collapse'))}` : '';
const collapse = collapseGiven || '&collapse=0';
// While the iso slider is held still this long during a drag (ms), the page asks for the surface
// at rest without waiting for the release (?rest-after=MS; 0: at the release only), and a release
// at that iso-value then asks for nothing more. A drag that resumes overtakes it: the page aborts
// the request and the server cancels the query (docs/API.md), so the dragged surfaces keep coming.
// On a bisection grid (surfaces within a distance) only.
const restAfter = params.has('rest-after') ? Number(params.get('rest-after')) : 300;
// The page's starting state can come from the address too (scripts/figures.sh draws the paper's
// figures this way): ?iso=V (data units), &error=E (data units, at rest), &show=surface,points,
// tets,reference, &reference=side|overlay, &camera=X,Y,Z (direction from the centre to the eye),
// &up=X,Y,Z (the screen's up, default +z), &panel=hide. Once the first surface and every layer
// asked for are drawn, <body data-ready="1">.
const startIso = params.has('iso') ? Number(params.get('iso')) : NaN;
const startError = params.has('error') ? Number(params.get('error')) : NaN;
const startShow = params.has('show') ? params.get('show').split(',') : null;
const startCamera = (params.get('camera') || '').split(',').map(Number);
const startUp = (params.get('up') || '').split(',').map(Number);
const givenVector = (v) => v.length === 3 && v.every(Number.isFinite) && v.some((c) => c !== 0);
// Every surface shown, with its timings, for scripts and the browser benchmark.
const record = (window.adaptisoSurfaces = []);
const canvas = $('view');
// Software rasterisers (SwiftShader, llvmpipe: headless browsers, virtual machines, remote
// desktops) resolve 4-sample antialiasing on the CPU: the bunny's 8 M triangles at rest took
// 9.7-10.0 s to draw with it and 2.4-3.5 s without (bench/viewer_bench.mjs). GPUs keep it.
function softwareRendering() {
  const gl = document.createElement('canvas').getContext('webgl2');
  if (!gl) return false;
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const name = String(gl.getParameter(info ? info.UNMASKED_RENDERER_WEBGL : gl.RENDERER));
  gl.getExtension('WEBGL_lose_context')?.loseContext();
  return /swiftshader|llvmpipe|softpipe|software/i.test(name);
}
const software = softwareRendering();
const renderer = new THREE.WebGLRenderer({ canvas, antialias: !software, preserveDrawingBuffer: true });
renderer.setPixelRatio(window.devicePixelRatio);
// A software rasteriser's time follows the pixels too: a dragged surface of the bunny (20,000
// triangles) took 181 ms from hand-over to drawn on a 1000×700 page and 74 ms on a 500×350 one
// (bench/viewer_bench.mjs), the server's query 80 ms. So there the surfaces drawn while the iso
// slider is dragged are drawn at ?drag-scale=S of the canvas's resolution (0.5 by default with
// software rendering, 1 with a GPU) and the surface at rest at full resolution, as ParaView's
// image reduction factor does during interaction. On the 1000×700 page the bunny's drag went from
// 6.8–7.6 to 9.3–10.4 surfaces a second (steady rate, 4 alternated pairs); the browser still
// composites the page at full size, which is most of what is left. The 512×512×120 MR head's drag,
// held by the server's 130 ms a surface, stayed at 6.6 a second.
const dragScaleGiven = Number(params.get('drag-scale'));
const dragScale = params.has('drag-scale') && dragScaleGiven > 0 && dragScaleGiven <= 1 ? dragScaleGiven : software ? 0.5 : 1;
let drawScale = 1;
function setDrawScale(scale) {
  if (scale === drawScale) return;
  drawScale = scale;
  renderer.setPixelRatio(window.devicePixelRatio * scale);
  renderer.setSize(window.innerWidth, window.innerHeight, false);
}
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x15171c);
const camera = new THREE.PerspectiveCamera(40, 1, 0.01, 1e6);
const controls = new OrbitControls(camera, canvas);
scene.add(new THREE.HemisphereLight(0xffffff, 0x303040, 0.9));
const headlight = new THREE.DirectionalLight(0xffffff, 1.6);
camera.add(headlight);
scene.add(camera);

// Gouraud shading with the interpolated vertex gradients as normals (MeshLambertMaterial lights per vertex).
const surfaceMaterial = new THREE.MeshLambertMaterial({ color: 0xd9b38c, side: THREE.DoubleSide });
const referenceMaterial = new THREE.MeshLambertMaterial({ color: 0x6fa8dc, side: THREE.DoubleSide, transparent: true, opacity: 0.55 });
const surface = new THREE.Mesh(new THREE.BufferGeometry(), surfaceMaterial);
const reference = new THREE.Mesh(new THREE.BufferGeometry(), referenceMaterial);
const points = new THREE.Points(new THREE.BufferGeometry(), new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true }));
const tets = new THREE.LineSegments(new THREE.BufferGeometry(), new THREE.LineBasicMaterial({ color: 0x88ccff, transparent: true, opacity: 0.35 }));
scene.add(surface, reference, points, tets);

let info = null;
const stats = { extract: 0, encode: 0, wait: 0, transfer: 0, decode: 0, bytes: 0, triangles: 0, vertices: 0, active: 0, incremental: false, inRange: true,
                refTriangles: null, error: 0, guaranteed: true, level: 0, coarse: false, distance: null, rank: 0 };

function resize() {
  const w = window.innerWidth, h = window.innerHeight;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  requestRender();
}
window.addEventListener('resize', resize);

// Drawn on demand (the camera moved, a layer, the surface or the window changed), not at every
// animation frame: with software rendering (SwiftShader here) redrawing a still bunny surface of
// 8 M triangles kept a core busy, which the server on the same machine lost (its encoding of the
// MR head's surface at rest took 2.2-2.8 s in the browser benchmark against 0.4 s alone), and
// on a laptop's GPU it is battery.
let renderQueued = false, renderWanted = false;
function renderNow() {
  renderWanted = false;
  renderer.render(scene, camera);
}

// Resolves when the GPU has finished everything drawn so far (a WebGL2 fence, polled between
// tasks; at once without WebGL2). Drawing calls return as soon as they are queued: a page that
// sends the next surface before the GPU has drawn the last piles frames up, and with software
// rendering the queue then blocked the page's thread for up to 5.0 s at a time while the slider
// was dragged over the bunny (10 long tasks inside renderNow in a 4 s drag).
function gpuDone() {
  const gl = renderer.getContext();
  if (typeof gl.fenceSync !== 'function') return Promise.resolve();
  const sync = gl.fenceSync(gl.SYNC_GPU_COMMANDS_COMPLETE, 0);
  gl.flush();
  return new Promise((resolve) => {
    const poll = () => {
      if (gl.isContextLost() || gl.getSyncParameter(sync, gl.SYNC_STATUS) === gl.SIGNALED) {
        gl.deleteSync(sync);
        resolve();
      } else setTimeout(poll, 2);
    };
    poll();
  });
}
function requestRender() {
  renderWanted = true;
  if (renderQueued) return;
  renderQueued = true;
  requestAnimationFrame(() => {
    renderQueued = false;
    if (renderWanted) renderNow();  // unless drawn meanwhile (a new surface is drawn at once)
  });
}
controls.addEventListener('change', requestRender);

function showStatus(text) { $('status').textContent = text; }

function updateStats() {
  if (!info) return;
  const lines = [
    stats.distance !== null
      ? `within about ${stats.distance} voxels of the grid's surface${stats.coarse ? ', coarse while dragging' : ''}` +
          ` (its error ${stats.guaranteed ? '≤' : 'measured'} ${Number(stats.error).toPrecision(4)})`
      : `error: ${stats.guaranteed ? '≤' : 'measured'} ${Number(stats.error).toPrecision(4)}` +
          ` (${(100 * stats.error / ((info.max - info.min) || 1)).toPrecision(3)} % of the range)${stats.coarse ? ', coarse while dragging' : ''}`,
    `kept vertices: ${info.kept}`,
    `tetrahedra: ${info.tetrahedra}`,
    `triangles: ${stats.triangles}`,
    `vertices: ${stats.vertices}`,
    `active tetrahedra: ${stats.active}`,
    `extraction: ${(stats.extract * 1000).toFixed(1)} ms${stats.incremental ? ' (incremental)' : ''}` +
      `${info.ranks > 1 && stats.distance !== null ? `, by rank ${stats.rank} of ${info.ranks}` : ''}`,
    `encoding: ${stats.encode.toFixed(1)} ms${stats.wait >= 1 ? `, after waiting ${stats.wait.toFixed(0)} ms for the background extraction` : ''}`,
    `transfer: ${stats.transfer.toFixed(1)} ms, ${(stats.bytes / Math.max(stats.triangles, 1)).toFixed(1)} bytes/triangle`,
    `decode: ${stats.decode.toFixed(1)} ms`,
  ];
  if (!stats.inRange) lines.push('iso-value outside the value range: empty surface');
  if (stats.refTriangles !== null) lines.push(`reference triangles: ${stats.refTriangles}`);
  $('stats').textContent = lines.join('\n');
  $('stats').dataset.iso = String(shownIso);  // the exact iso-value shown, for scripts and tests
  $('stats').dataset.error = String(stats.error);  // the error of the surface shown (data units)
  $('stats').dataset.level = String(stats.level);
  $('stats').dataset.distance = stats.distance === null ? '' : String(stats.distance);  // voxels, on a bisection grid
}

// Binary mesh: u32 V, u32 T, f32 positions[3V], f32 normals[3V], u32 indices[3T].
function decodeMesh(buffer) {
  const head = new Uint32Array(buffer, 0, 2);
  const V = head[0], T = head[1];
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(buffer, 8, 3 * V), 3));
  g.setAttribute('normal', new THREE.BufferAttribute(new Float32Array(buffer, 8 + 12 * V, 3 * V), 3));
  g.setIndex(new THREE.BufferAttribute(new Uint32Array(buffer, 8 + 24 * V, 3 * T), 1));
  return g;
}

// The unit normal of each of the 65,536 octahedral byte pairs (mesh_codec.hpp), looked up instead
// of unfolded per vertex: the loop over a bunny surface's 1.9 M vertices took 160 ms unfolding
// (Math.hypot dominating) and 60–95 ms looking up, in node.
let normalTable = null;
function octahedralNormals() {
  if (normalTable) return normalTable;
  normalTable = new Float32Array(3 * 65536);
  for (let i = 0; i < 65536; i++) {
    let x = ((i >> 8) << 24 >> 24) / 127, y = ((i & 255) << 24 >> 24) / 127;  // the two bytes as int8
    const z = 1 - Math.abs(x) - Math.abs(y);
    if (z < 0) { const fx = (1 - Math.abs(y)) * (x >= 0 ? 1 : -1), fy = (1 - Math.abs(x)) * (y >= 0 ? 1 : -1); x = fx; y = fy; }
    const len = Math.hypot(x, y, z) || 1;
    normalTable[3 * i] = x / len; normalTable[3 * i + 1] = y / len; normalTable[3 * i + 2] = z / len;
  }
  return normalTable;
}

// Compact mesh (mesh_codec.hpp): "ADM2", u32 V, u32 T, f32 origin[3], f32 step[3], u32 vertex bytes,
// meshopt vertex stream of 8-byte vertices (u16 x, y, z; i8 octahedral normal), u32 K, K × (u32
// triangles, u32 base, u32 bytes), then K meshopt index streams of up to 2^20 triangles each,
// encoded side by side on the server; a stream's indices are rotated down by its base (mod V).
function decodeCompact(buffer) {
  const view = new DataView(buffer);
  const V = view.getUint32(4, true), T = view.getUint32(8, true);
  const origin = [0, 1, 2].map((a) => view.getFloat32(12 + 4 * a, true)), step = [0, 1, 2].map((a) => view.getFloat32(24 + 4 * a, true));
  const vbytes = view.getUint32(36, true);
  const packed = new Uint8Array(8 * V);
  MeshoptDecoder.decodeVertexBuffer(packed, V, 8, new Uint8Array(buffer, 40, vbytes));
  const K = view.getUint32(40 + vbytes, true);
  const indices = new Uint32Array(3 * T);
  let at = 44 + vbytes + 12 * K, first = 0;
  for (let k = 0; k < K; k++) {
    const entry = 44 + vbytes + 12 * k;
    const count = 3 * view.getUint32(entry, true), base = view.getUint32(entry + 4, true), bytes = view.getUint32(entry + 8, true);
    const chunk = indices.subarray(first, first + count);
    MeshoptDecoder.decodeIndexBuffer(new Uint8Array(indices.buffer, 4 * first, 4 * count), count, 4, new Uint8Array(buffer, at, bytes));
    if (base) {
      const wrap = V - base;
      for (let i = 0; i < count; i++) { const x = chunk[i]; chunk[i] = x < wrap ? x + base : x - wrap; }
    }
    at += bytes;
    first += count;
  }
  const q = new Uint16Array(packed.buffer), u = new Uint8Array(packed.buffer), table = octahedralNormals();
  const pos = new Float32Array(3 * V), nrm = new Float32Array(3 * V);
  const [ox, oy, oz] = origin, [sx, sy, sz] = step;
  for (let v = 0, p = 0; v < V; v++, p += 3) {
    pos[p] = ox + sx * q[4 * v]; pos[p + 1] = oy + sy * q[4 * v + 1]; pos[p + 2] = oz + sz * q[4 * v + 2];
    const n = 3 * ((u[8 * v + 6] << 8) | u[8 * v + 7]);
    nrm[p] = table[n]; nrm[p + 1] = table[n + 1]; nrm[p + 2] = table[n + 2];
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  g.setAttribute('normal', new THREE.BufferAttribute(nrm, 3));
  g.setIndex(new THREE.BufferAttribute(indices, 1));
  return g;
}

// The page's decoding, for tests: positions, normals and indices of a compact answer.
window.adaptisoDecodeCompact = async (buffer) => {
  await MeshoptDecoder.ready;
  const g = decodeCompact(buffer);
  return { positions: g.attributes.position.array, normals: g.attributes.normal.array, indices: g.index.array };
};

function replaceGeometry(object, geometry) {
  object.geometry.dispose();
  object.geometry = geometry;
  requestRender();
}

function isoFromSlider() {
  const s = $('iso');
  return info.min + (info.max - info.min) * (Number(s.value) / Number(s.max));
}

// The error asked for at rest: the slider runs on a log scale from the prepared bound to the
// value range (data units); its left end is the prepared surface.
function errorFromSlider() {
  const e = $('error'), lo = info.error_bound, hi = info.max - info.min;
  if (!(lo > 0) || !(hi > lo)) return lo || 0;
  return lo * Math.pow(hi / lo, Number(e.value) / Number(e.max));
}
// The distance asked for at rest (voxels): the slider runs on a log scale from 0.25 to 16, its
// left end the grid's own surface (0).
function distanceFromSlider() {
  const v = Number($('distance').value) / Number($('distance').max);
  return v === 0 ? 0 : Number((0.25 * Math.pow(64, v)).toPrecision(2));
}
function showDistance() { $('distance-value').textContent = `${distanceFromSlider()} voxels`; }
function showError() {
  const e = errorFromSlider();
  $('error-value').textContent = `≤ ${e.toPrecision(3)} (${(100 * e / ((info.max - info.min) || 1)).toPrecision(2)} %)`;
}

// The distance of the next dragged surface, from the last surface's distance and triangles. A
// fixed drag distance cannot hold a rate: on the CT bunny at iso 1000 the surface within 2 voxels
// has 1.18 M triangles and takes 0.94 s (within 16: 63 k; within 64: 15 k), at iso 1600.5 within
// 2 voxels 110 k. Triangles fall about as 1/D on intricate or noisy surfaces and 1/D² on smooth
// ones; a step of (n / target)^(2/3) settles on either without overshooting far. Never finer than
// ?drag-distance, never coarser than 64 voxels unless that is (a shape, not a blob, on a 512-voxel
// scan).
let dragDistanceNow = dragDistance;
function nextDragDistance(d, triangles) {
  if (!(d > 0)) return dragDistance;
  const next = d * Math.pow(Math.max(triangles, 1) / dragTriangles, 2 / 3);
  return Math.min(Math.max(64, dragDistance), Math.max(dragDistance, Number(next.toPrecision(2))));
}

// At most one surface request in flight; while it runs only the latest wanted request is kept, so
// requests never go stale and dragging updates the surface as fast as the server answers. A
// request while dragging (coarse) asks for the triangle budget; a request at rest for the error.
let wanted = null, inFlight = false, shownIso = null;
// The surface at rest last asked for, in flight or drawn ({ url, controller }; controller: its
// fetch's, while a drag may abort it); null once a dragged surface replaces it.
let restRequest = null;
const drawing = [];  // fences of the surfaces handed to the GPU and not yet drawn, oldest first
const kQueuedTriangles = 100000;
let statusBeforeBusy = null;  // the status line a "server busy" message replaced
function surfaceRequest(iso, coarse) {
  let url = `api/surface?iso=${encodeURIComponent(iso)}&client=${client}&format=compact`;
  const distance = info.distance ? (coarse ? Math.max(dragDistanceNow, distanceFromSlider()) : distanceFromSlider()) : null;
  if (info.distance) {
    url += `&distance=${distance}${collapse}`;
  } else {
    if (info.levels.length > 1) url += `&error=${errorFromSlider()}`;
    if (coarse) url += `&budget=${budget}`;
  }
  return { url, distance };
}
function requestSurface(iso, coarse = false) {
  coarse = coarse && $('lod').checked;
  // Held still, then released: the surface at rest is on its way or drawn already.
  if (!coarse && wanted === null && restRequest !== null && restRequest.url === surfaceRequest(iso, false).url) return;
  wanted = { iso, coarse, input: performance.now() };
  if (coarse && inFlight && restRequest?.controller) restRequest.controller.abort();  // the drag resumed
  if (!inFlight) pump();
}
async function pump() {
  if (wanted === null) return;
  const { iso, coarse, input } = wanted;
  wanted = null;
  inFlight = true;
  try {
    const t0 = performance.now();
    const { url, distance } = surfaceRequest(iso, coarse);
    const controller = !coarse && info.distance ? new AbortController() : null;
    restRequest = coarse ? null : { url, controller };
    const r = await fetch(url, controller ? { signal: controller.signal } : {});
    if (r.status === 503) {  // the server's memory budget is taken for now: ask again (the latest wanted) when it says
      const after = Math.min(10, Number(r.headers.get('Retry-After')) || 1);
      if (statusBeforeBusy === null) statusBeforeBusy = $('status').textContent;
      showStatus(`server busy: ${(await r.text()).trim()} (retrying in ${after} s)`);
      if (wanted === null) wanted = { iso, coarse, input };
      await new Promise((ok) => setTimeout(ok, 1000 * after));
      return;
    }
    if (!r.ok) throw new Error(await r.text());
    if (statusBeforeBusy !== null) {
      showStatus(statusBeforeBusy);
      statusBeforeBusy = null;
    }
    const buffer = await r.arrayBuffer();
    if (restRequest?.url === url) restRequest.controller = null;  // arrived: drawn whatever comes next
    const t1 = performance.now();
    await MeshoptDecoder.ready;
    const geometry = decodeCompact(buffer);
    const t2 = performance.now();
    stats.extract = Number(r.headers.get('X-Extract-Seconds'));
    stats.encode = 1000 * Number(r.headers.get('X-Encode-Seconds'));
    stats.wait = 1000 * Number(r.headers.get('X-Wait-Seconds'));
    stats.transfer = t1 - t0 - 1000 * stats.extract - stats.encode - stats.wait;
    stats.decode = t2 - t1;
    stats.bytes = buffer.byteLength;
    stats.triangles = Number(r.headers.get('X-Triangles'));
    stats.vertices = Number(r.headers.get('X-Vertices'));
    stats.active = Number(r.headers.get('X-Active-Tetrahedra'));
    stats.incremental = r.headers.get('X-Incremental') === '1';
    stats.inRange = r.headers.get('X-In-Range') === '1';
    stats.error = Number(r.headers.get('X-Error-Bound'));
    stats.guaranteed = r.headers.get('X-Error-Guaranteed') === '1';
    stats.level = Number(r.headers.get('X-Level'));
    stats.distance = r.headers.has('X-Distance') ? Number(r.headers.get('X-Distance')) : null;
    stats.rank = Number(r.headers.get('X-Rank') || 0);
    stats.coarse = coarse;
    // Every surface within a distance tells the next drag how far to go (at rest too: the first
    // drag then starts near its target).
    if (info.distance) dragDistanceNow = nextDragDistance(distance, stats.triangles);
    // A surface while dragging is drawn while the next is requested, and a small one may wait
    // behind the one being drawn (no more: a queue of frames blocked the page, gpuDone). A fence
    // takes its time to signal, 24 ms for 180 triangles and 37 ms for 12,640 in an idle SwiftShader
    // (bench/webgl_floor.mjs), and more while the server works: waiting for each before handing
    // over the next held the bunny's drag at 6.5-9.9 surfaces/s, one queued raised it to 8.4-12.0
    // in the same runs (bench/viewer_bench.mjs). A surface at rest waits for all, and is drawn
    // before the page says it is ready.
    while (drawing.length >= (coarse && stats.triangles <= kQueuedTriangles ? 2 : 1)) await drawing[0];
    const t2b = performance.now();
    replaceGeometry(surface, geometry);  // uploaded when first drawn, now
    setDrawScale(coarse ? dragScale : 1);
    renderNow();
    const shown = gpuDone();
    drawing.push(shown);
    shown.then(() => drawing.splice(drawing.indexOf(shown), 1));
    shownIso = iso;
    // Timings (SwiftShader's drawing is CPU work, reported with the upload as draw), taken now:
    // the next request rewrites stats before a dragged surface is drawn.
    const entry = { iso, coarse, level: stats.level, error: stats.error, distance: stats.distance, triangles: stats.triangles, bytes: stats.bytes,
                    request: t1 - t0, server: 1000 * stats.extract, wait: stats.wait, encode: stats.encode, decode: t2 - t1,
                    gpuWait: t2b - t2, fromInput: t2 - input, fromInputUploaded: t2b - input,
                    pixels: [renderer.domElement.width, renderer.domElement.height] };
    const note = () => {
      const t3 = performance.now();
      record.push({ ...entry, draw: t3 - t2b, fromInputDrawn: t3 - input, at: t3 });
    };
    if (coarse) shown.then(note);
    else note(await shown);
    updateStats();  // after a surface at rest is recorded: tests read the record once the panel shows it
    const layers = [];
    if ($('show-tets').checked) layers.push(loadTetrahedra(iso));
    if ($('show-reference').checked) layers.push(loadReference(iso));
    await Promise.all(layers);
    document.body.dataset.ready = '1';
  } catch (e) {
    restRequest = null;  // asked for again at the release
    if (e.name !== 'AbortError') showStatus(`error: ${e.message}`);  // aborted: a drag overtook the surface at rest
  } finally {
    inFlight = false;
    if (wanted !== null) pump();
  }
}

async function loadPoints() {
  const r = await fetch('api/points');
  const buffer = await r.arrayBuffer();
  const N = new Uint32Array(buffer, 0, 1)[0];
  const pos = new Float32Array(buffer, 4, 3 * N), val = new Float32Array(buffer, 4 + 12 * N, N);
  const colors = new Float32Array(3 * N);
  for (let i = 0; i < N; i++) {
    const t = info.max > info.min ? (val[i] - info.min) / (info.max - info.min) : 0.5;
    colors[3 * i] = 0.2 + 0.8 * t; colors[3 * i + 1] = 0.4 + 0.4 * (1 - Math.abs(2 * t - 1)); colors[3 * i + 2] = 1 - 0.8 * t;
  }
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(pos, 3));
  g.setAttribute('color', new THREE.BufferAttribute(colors, 3));
  replaceGeometry(points, g);
}

async function loadTetrahedra(iso) {
  const r = await fetch(`api/tetrahedra?iso=${encodeURIComponent(iso)}`);
  if (!r.ok) { showStatus(await r.text()); return; }
  const buffer = await r.arrayBuffer();
  const [V, E] = new Uint32Array(buffer, 0, 2);
  const g = new THREE.BufferGeometry();
  g.setAttribute('position', new THREE.BufferAttribute(new Float32Array(buffer, 8, 3 * V), 3));
  g.setIndex(new THREE.BufferAttribute(new Uint32Array(buffer, 8 + 12 * V, 2 * E), 1));
  replaceGeometry(tets, g);
}

let sideOffset = 0;
async function loadReference(iso) {
  const r = await fetch(`api/reference?iso=${encodeURIComponent(iso)}`);
  if (!r.ok) { showStatus(await r.text()); stats.refTriangles = null; return; }
  replaceGeometry(reference, decodeMesh(await r.arrayBuffer()));
  stats.refTriangles = Number(r.headers.get('X-Triangles'));
  updateStats();
}

function applyVisibility() {
  surface.visible = $('show-surface').checked;
  points.visible = $('show-points').checked;
  tets.visible = $('show-tets').checked;
  reference.visible = $('show-reference').checked;
  const side = $('reference-mode').value === 'side';
  reference.position.set(side ? sideOffset : 0, 0, 0);
  // Overlaid on the surface it is see-through; beside it, or alone, it is solid.
  const solid = side || !surface.visible;
  referenceMaterial.opacity = solid ? 1 : 0.55;
  referenceMaterial.transparent = !solid;
  requestRender();
}

function drawHistogram(h) {
  const c = $('histogram'), ctx = c.getContext('2d');
  ctx.clearRect(0, 0, c.width, c.height);
  const logs = h.counts.map((n) => Math.log1p(n)), top = Math.max(...logs, 1);
  const w = c.width / logs.length;
  ctx.fillStyle = 'rgba(140, 160, 190, 0.55)';
  logs.forEach((v, i) => { const bh = (v / top) * (c.height - 14); ctx.fillRect(i * w, c.height - 14 - bh, Math.max(w - 0.5, 0.5), bh); });
}

function frame(box) {
  const center = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3()).length();
  controls.target.copy(center);
  const eye = givenVector(startCamera) ? new THREE.Vector3(...startCamera) : new THREE.Vector3(0.6, -0.9, 0.7);
  camera.position.copy(center).add(eye.normalize().multiplyScalar(size * 1.3));
  camera.up.copy(givenVector(startUp) ? new THREE.Vector3(...startUp).normalize() : new THREE.Vector3(0, 0, 1));
  camera.near = size / 1000; camera.far = size * 100;
  camera.updateProjectionMatrix();
  controls.update();
  sideOffset = box.getSize(new THREE.Vector3()).x * 1.15;
  requestRender();
}

async function start() {
  resize();
  for (;;) {  // the server may still be preparing the grid
    try {
      const r = await fetch('api/info');
      info = await r.json();
    } catch (e) { showStatus('server unreachable, retrying…'); }
    if (info && info.state === 'ready') break;
    if (info && info.state === 'failed') { showStatus(`preparation failed: ${info.error}`); return; }
    if (info) showStatus(`preparing: ${info.stage} ${(100 * info.progress).toFixed(0)} %`);
    await new Promise((ok) => setTimeout(ok, 300));
  }
  if (useLevels) info.distance = false;
  const d = info.dims, s = info.spacing;
  const grid = info.facts.grid === 'bisection' ? 'bisection grid' : `Delaunay grid (${info.reduction.method})`;
  showStatus(`${d.join('×')} voxels, values ${info.min} … ${info.max}; ${grid}, ` +
             `error ${info.error_guaranteed ? '≤' : 'measured'} ${Number(info.error_bound).toPrecision(4)}`);
  const box = new THREE.Box3();
  const corner = (i, j, k) => {  // world = origin + direction · (spacing ⊙ index)
    const g = [i * s[0], j * s[1], k * s[2]], D = info.direction, o = info.origin;
    return new THREE.Vector3(o[0] + D[0] * g[0] + D[1] * g[1] + D[2] * g[2], o[1] + D[3] * g[0] + D[4] * g[1] + D[5] * g[2],
                             o[2] + D[6] * g[0] + D[7] * g[1] + D[8] * g[2]);
  };
  for (const i of [0, d[0] - 1]) for (const j of [0, d[1] - 1]) for (const k of [0, d[2] - 1]) box.expandByPoint(corner(i, j, k));
  frame(box);
  drawHistogram(info.histogram);
  $('show-reference').disabled = !info.reference;
  const slider = $('iso'), field = $('iso-value');
  slider.disabled = field.disabled = false;
  field.step = String((info.max - info.min) / 1000 || 1);
  const initial = Number.isFinite(startIso) ? startIso : info.min + 0.5 * (info.max - info.min);
  slider.value = String(Math.round(Number(slider.max) * (initial - info.min) / ((info.max - info.min) || 1)));
  field.value = String(initial);
  // Dragging sends input events (coarse surfaces within the budget); releasing sends change (the
  // surface at the chosen error).
  let restTimer = null;
  slider.addEventListener('input', () => {
    const v = isoFromSlider();
    field.value = String(Number(v.toPrecision(6)));
    requestSurface(v, true);
    clearTimeout(restTimer);
    if (info.distance && restAfter > 0) restTimer = setTimeout(() => requestSurface(isoFromSlider(), false), restAfter);
  });
  slider.addEventListener('change', () => { clearTimeout(restTimer); requestSurface(isoFromSlider(), false); });
  const distanceSlider = $('distance');
  if (info.distance) {  // a bisection grid: the surface within a distance, not an error level
    $('distance-box').hidden = false;
    $('error-box').hidden = true;
    distanceSlider.disabled = false;
    if (Number.isFinite(startDistance) && startDistance >= 0)
      distanceSlider.value = String(startDistance < 0.25 ? 0 : Math.round(Number(distanceSlider.max) * Math.min(1, Math.log(startDistance / 0.25) / Math.log(64))));
    showDistance();
    distanceSlider.addEventListener('input', () => { showDistance(); if (shownIso !== null) requestSurface(shownIso, false); });
  }
  const errorSlider = $('error');
  errorSlider.disabled = !(info.levels.length > 1) || info.distance;
  const lo = info.error_bound, hi = info.max - info.min;
  if (Number.isFinite(startError) && !errorSlider.disabled && startError > lo && hi > lo) {
    errorSlider.value = String(Math.round(Number(errorSlider.max) * Math.min(1, Math.log(startError / lo) / Math.log(hi / lo))));
  }
  showError();
  errorSlider.addEventListener('input', () => { showError(); if (shownIso !== null) requestSurface(shownIso, false); });
  field.addEventListener('change', () => {
    const v = Number(field.value);
    if (!Number.isFinite(v)) return;
    slider.value = String(Math.round(Number(slider.max) * (v - info.min) / ((info.max - info.min) || 1)));
    requestSurface(v);
  });
  for (const id of ['show-surface', 'show-points', 'show-tets', 'show-reference', 'reference-mode'])
    $(id).addEventListener('change', () => {
      applyVisibility();
      if (id === 'show-points' && $(id).checked && !points.geometry.attributes.position) loadPoints();
      if (id === 'show-tets' && $(id).checked && shownIso !== null) loadTetrahedra(shownIso);
      if (id === 'show-reference' && $(id).checked && shownIso !== null) loadReference(shownIso);
    });
  // Export: the surface at rest (the iso-value and error shown), simplified on the server.
  const exportButton = $('export');
  exportButton.disabled = false;
  exportButton.addEventListener('click', () => {
    if (shownIso === null) return;
    const distance = Math.max(0, Number($('export-distance').value) || 0);
    let url = `api/export?iso=${encodeURIComponent(shownIso)}&client=${client}&simplify=${distance}&format=${$('export-format').value}`;
    if (info.distance) url += `&distance=${distanceFromSlider()}${collapseGiven}`;
    else if (info.levels.length > 1) url += `&error=${errorFromSlider()}`;
    const a = document.createElement('a');
    a.href = url;
    a.download = '';
    document.body.appendChild(a);
    a.click();
    a.remove();
  });
  if (startShow)
    for (const layer of ['surface', 'points', 'tets', 'reference'])
      $(`show-${layer}`).checked = startShow.includes(layer) && !$(`show-${layer}`).disabled;
  if (params.get('reference') === 'side' || params.get('reference') === 'overlay') $('reference-mode').value = params.get('reference');
  if (params.get('panel') === 'hide') $('panel').style.display = 'none';
  if ($('show-reference').checked && $('reference-mode').value === 'side') {
    // Frame both: the surface and the reference beside it.
    const offset = sideOffset;
    frame(box.clone().union(box.clone().translate(new THREE.Vector3(offset, 0, 0))));
    sideOffset = offset;
  }
  applyVisibility();
  if ($('show-points').checked) await loadPoints().catch((e) => showStatus(`kept vertices: ${e.message}`));
  requestSurface(initial);
}

start();
