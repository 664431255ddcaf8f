// Draws the paper's figures (Lürig & Ertl 1998) with adaptiso alone: for each figure it starts
// `adaptiso view` on the volume with the figure's options, opens the viewer page in Debian's
// headless chromium (WebGL through SwiftShader) with the figure's state in the address, waits until
// the page reports every layer drawn, and saves the canvas as PNG. The numbers of each figure come
// from the same server (/api/info, the surface's headers) and go to FIGURES.md beside the images.
// Usage: node scripts/figures.mjs ADAPTISO_CLI OUT_DIR DATA_DIR   (run by scripts/figures.sh)
import { spawn, execFileSync } from 'node:child_process';
import { createRequire } from 'node:module';
import { existsSync, mkdirSync, mkdtempSync, renameSync, rmSync, writeFileSync } from 'node:fs';
import { tmpdir } from 'node:os';
import { dirname, join } from 'node:path';
import { fileURLToPath } from 'node:url';

const [cli, out, data] = process.argv.slice(2);
if (!cli || !out || !data) {
  console.error('usage: node scripts/figures.mjs ADAPTISO_CLI OUT_DIR DATA_DIR');
  process.exit(2);
}
const web = join(dirname(fileURLToPath(import.meta.url)), '..', 'web');
const { chromium } = createRequire(join(web, 'package.json'))('playwright-core');
const tmp = mkdtempSync(join(tmpdir(), 'adaptiso-figures-'));
mkdirSync(out, { recursive: true });

// The paper's sphere: `adaptiso generate sphere --size 50` (values 295 … 1000, iso 0.7 of the range).
const sphere = join(tmp, 'sphere50.nrrd');
execFileSync(cli, ['generate', 'sphere', '--size', '50', '--quiet', '-o', sphere]);
const head = join(data, 'ct_head_headsq_quarter', 'quarter.nhdr');

const delaunay = (...a) => ['--grid', 'delaunay', ...a];
const figures = [
  { file: 'fig01_structural_vertices.png', volume: sphere, args: delaunay('--method', 'structural'), iso: 0.7, show: 'points',
    title: 'Figure 1: vertices kept by the structural analysis (central differences, no threshold)',
    paper: 'the vertices kept where the gradient changes (structural analysis, §2.1)' },
  { file: 'fig03_reconstruction_vertices.png', volume: sphere, args: delaunay('--relative', '--max-error', '0.05'), iso: 0.7, show: 'points',
    title: 'Figure 3: vertices kept by the reconstruction analysis at error 0.05 of the range',
    paper: 'the vertices kept by the reconstruction analysis; asymmetric because the paper extends the volume to a power-of-two cube' },
  { file: 'fig05_delaunay_structural.png', volume: sphere, args: delaunay('--method', 'structural'), iso: 0.7, show: 'surface,tets',
    title: 'Figure 5: Delaunay tetrahedrization of the structural vertices; the tetrahedra cut by the iso-surface at 0.7' },
  { file: 'fig06_delaunay_reconstruction.png', volume: sphere, args: delaunay('--relative', '--max-error', '0.05'), iso: 0.7, show: 'surface,tets',
    title: 'Figure 6: Delaunay tetrahedrization of the reconstruction vertices (error 0.05); the tetrahedra cut at 0.7' },
  { file: 'fig06b_bisection.png', volume: sphere, args: ['--relative', '--max-error', '0.05'], iso: 0.7, show: 'surface,tets',
    title: 'Figure 6, bisection grid: the tetrahedra of the longest-edge bisection grid (error ≤ 0.05, guaranteed) cut at 0.7' },
  { file: 'fig08_sphere_delaunay.png', volume: sphere, args: delaunay('--relative', '--max-error', '0.15'), iso: 0.7, show: 'surface',
    title: 'Figure 8: the reduced sphere\'s iso-surface at 0.7, Delaunay grid at error 0.15', paperNumbers: '198 vertices, 542 triangles' },
  { file: 'fig08b_sphere_bisection.png', volume: sphere, args: ['--relative', '--max-error', '0.15'], iso: 0.7, show: 'surface',
    title: 'Figure 8, bisection grid: the same surface from the bisection grid at error ≤ 0.15 (guaranteed)', paperNumbers: '198 vertices, 542 triangles' },
  { file: 'fig09_ct_full_resolution.png', volume: head, args: [], isoData: 500, show: 'reference', camera: '0,-1,-0.25', up: '0,0,-1',
    title: 'Figure 9: CT head (headsq, 64×64×93) at iso 500 (skin), full-resolution marching cubes',
    paperNumbers: '128³ CT: 323,822 triangles' },
  { file: 'fig10_ct_reduced.png', volume: head, args: delaunay('--relative', '--max-error', '0.05'), isoData: 500, show: 'surface', camera: '0,-1,-0.25', up: '0,0,-1',
    title: 'Figure 10: the same CT from the paper\'s grid (reconstruction analysis, Delaunay) at error 0.05 of the range',
    paperNumbers: '128³ CT reduced: 18,456 vertices (99.12 % fewer), 71,872 triangles' },
  { file: 'fig10b_ct_bisection.png', volume: head, args: [], isoData: 500, show: 'surface', camera: '0,-1,-0.25', up: '0,0,-1',
    title: 'Figure 10, bisection grid: the same CT from the bisection grid at the default error (0.02 of the range, guaranteed)',
    paperNumbers: '128³ CT reduced: 18,456 vertices (99.12 % fewer), 71,872 triangles' },
];

let browser;
const servers = [];
function cleanup() {
  for (const s of servers) s.kill('SIGTERM');
  rmSync(tmp, { recursive: true, force: true });
}
process.on('exit', cleanup);
const fail = (msg) => { console.error(`figures: ${msg}`); process.exit(1); };

async function serve(volume, args) {
  const server = spawn(cli, ['view', volume, ...args, '--port', '0', '--web', web, '--quiet'], { stdio: ['ignore', 'pipe', 'inherit'] });
  servers.push(server);
  const url = await new Promise((ok, bad) => {
    let text = '';
    server.stdout.on('data', (d) => { text += d; const m = text.match(/http:\/\/[^\s]+\//); if (m) ok(m[0]); });
    server.on('exit', (code) => bad(new Error(`adaptiso view exited with ${code}`)));
  });
  for (;;) {  // the server prepares the grid in the background
    const info = await (await fetch(`${url}api/info`)).json();
    if (info.state === 'ready') return { server, url, info };
    if (info.state === 'failed') throw new Error(`preparing ${volume} failed: ${info.error}`);
    await new Promise((ok) => setTimeout(ok, 200));
  }
}

const fmt = (n) => Number(n).toLocaleString('en-US');
const rows = [];
try {
  if (!existsSync(head)) console.log(`figures: ${head} absent (ADAPTISO_DATA); Figures 9 and 10 are skipped`);
  browser = await chromium.launch({ executablePath: process.env.CHROMIUM || '/usr/bin/chromium', headless: true,
    args: ['--no-sandbox', '--use-angle=swiftshader', '--enable-unsafe-swiftshader', '--ignore-gpu-blocklist'] });
  for (const f of figures) {
    if (!existsSync(f.volume)) continue;
    const { server, url, info } = await serve(f.volume, f.args);
    const iso = f.isoData ?? info.min + f.iso * (info.max - info.min);
    const page = await browser.newPage({ viewport: { width: 640, height: 512 } });
    // levels=1: the grid's own surface (the paper's), not one within a distance of it.
    const query = new URLSearchParams({ iso: String(iso), show: f.show, panel: 'hide', camera: f.camera || '0.6,-0.9,0.7', up: f.up || '0,0,1', levels: '1' });
    await page.goto(`${url}?${query}`);
    await page.waitForSelector('body[data-ready="1"]', { timeout: 120000 });
    // Two frames so the last layer is on the canvas, not only uploaded.
    await page.evaluate(() => new Promise((ok) => requestAnimationFrame(() => requestAnimationFrame(ok))));
    const shown = await page.evaluate(() => ({ surface: window.adaptisoSurfaces.at(-1), stats: document.getElementById('stats').textContent }));
    const png = join(out, f.file);
    await page.locator('#view').screenshot({ path: `${png}.tmp.png` });
    renameSync(`${png}.tmp.png`, png);
    await page.close();
    server.kill('SIGTERM');
    const active = /active tetrahedra: (\d+)/.exec(shown.stats)?.[1];
    const reference = /reference triangles: (\d+)/.exec(shown.stats)?.[1];
    const grid = f.show === 'reference' ? [] : [
      `${info.facts.grid === 'bisection' ? 'bisection grid' : `Delaunay grid (${info.reduction.method})`}`,
      `${fmt(info.kept)} kept vertices (${(100 * (1 - info.kept / info.dims.reduce((a, b) => a * b))).toFixed(2)} % fewer than voxels)`,
      `${fmt(info.tetrahedra)} tetrahedra`,
      `error ${info.error_guaranteed ? '≤' : 'measured'} ${Number(info.error_bound).toPrecision(4)} (${(100 * info.error_bound / (info.max - info.min)).toPrecision(3)} % of the range)`,
    ];
    const numbers = [
      `${info.dims.join('×')} voxels`,
      ...grid,
      `iso ${Number(iso.toPrecision(6))}`,
      f.show.includes('surface') ? `${fmt(shown.surface.triangles)} triangles` : null,
      f.show.includes('tets') && active ? `${fmt(active)} active tetrahedra` : null,
      reference ? `${fmt(reference)} triangles by marching cubes` : null,
    ].filter(Boolean).join(', ');
    rows.push({ ...f, numbers });
    console.log(`${f.file}: ${numbers}`);
  }
} catch (e) {
  fail(e.message);
} finally {
  if (browser) await browser.close();
}

const md = ['# The paper\'s figures, drawn by adaptiso', '',
  'Written by `scripts/figures.sh` (the viewer page in headless chromium); do not edit by hand.', ''];
for (const r of rows) {
  md.push(`## ${r.title}`, '', `![${r.title}](${r.file})`, '', `adaptiso: ${r.numbers}.`);
  if (r.paperNumbers) md.push(`Paper: ${r.paperNumbers}.`);
  else if (r.paper) md.push(`Paper: ${r.paper}.`);
  md.push('');
}
writeFileSync(join(out, 'FIGURES.md.tmp'), md.join('\n'));
renameSync(join(out, 'FIGURES.md.tmp'), join(out, 'FIGURES.md'));
console.log(`figures: ${rows.length} images and FIGURES.md in ${out}`);
process.exit(0);
