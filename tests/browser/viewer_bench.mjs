// The 3D viewer's frame rates (not a test; prints figures): a synthetic
// cloud of 1 M coloured points in headless Chromium with SwiftShader
// (software WebGL on the CPU: a lower bound for a machine with a GPU),
// measured by the viewer's own stats().fps (frames drawn in the last second):
//   interacting  — a mouse drag for a few seconds (levels of detail: at most
//                  300 000 points drawn, fewer when frames are slow), and
//                  the same with levels of detail off;
//   resting      — every frame drawn whole (the viewer's `continuous` option;
//                  by default a resting viewer draws nothing);
// each with the viewer's default (no multisampling on a software renderer)
// and with multisampling forced on.
//
//   node tests/browser/viewer_bench.mjs [--bundle build/clients/web/assets/viewer.bundle.js]
//        [--points 1000000] [--seconds 4] [--size 1280x720]
import fs from 'node:fs';
import path from 'node:path';

import { check, runBrowserTest, sourceDir } from './lib.mjs';

function option(name, fallback) {
  const at = process.argv.indexOf(name);
  return at > 0 ? process.argv[at + 1] : fallback;
}

const bundlePath = option('--bundle', process.env.CRAFTSCAN_VIEWER_BUNDLE ||
  path.join(sourceDir, 'build', 'clients', 'web', 'assets', 'viewer.bundle.js'));
const POINTS = Number(option('--points', 1000000));
const SECONDS = Number(option('--seconds', 4));
const [WIDTH, HEIGHT] = option('--size', '1280x720').split('x').map(Number);

// A torus knot tube with noise, coloured along it: a surface that fills
// the view from every side.
function makeCloud(n) {
  const positions = new Float32Array(3 * n);
  const colors = new Uint8Array(3 * n);
  let s = 0x2545f491;
  const rand = () => {  // xorshift32
    s ^= s << 13;
    s ^= s >>> 17;
    s ^= s << 5;
    return (s >>> 0) / 4294967296;
  };
  for (let i = 0; i < n; i++) {
    const t = rand() * Math.PI * 2;
    const a = rand() * Math.PI * 2;
    const p = 2, q = 3, R = 40, r = 14, tube = 7;
    const cx = (R + r * Math.cos(q * t)) * Math.cos(p * t);
    const cy = (R + r * Math.cos(q * t)) * Math.sin(p * t);
    const cz = r * Math.sin(q * t);
    const radius = tube + (rand() - 0.5) * 0.3;
    positions[3 * i] = cx + radius * Math.cos(a) * Math.cos(p * t);
    positions[3 * i + 1] = cy + radius * Math.cos(a) * Math.sin(p * t);
    positions[3 * i + 2] = cz + 30 + radius * Math.sin(a);
    colors[3 * i] = 128 + 120 * Math.cos(t);
    colors[3 * i + 1] = 128 + 120 * Math.sin(2 * t);
    colors[3 * i + 2] = 160 + 80 * Math.sin(a);
  }
  return { positions, colors };
}

runBrowserTest('viewer_bench', async (t) => {
  check(fs.existsSync(bundlePath), `no bundle at ${bundlePath} (build craftscan_viewer_bundle, or --bundle)`);
  const bundle = fs.readFileSync(bundlePath, 'utf8');
  const page = await t.offlinePage({ width: WIDTH, height: HEIGHT });
  await page.setContent(`<!DOCTYPE html><html><body style="margin:0">
    <div id="v" style="width:${WIDTH}px;height:${HEIGHT}px"></div>
    <script>${bundle}</script>
    <script>window.makeCloud = ${makeCloud.toString()};</script></body></html>`);

  const setup = async (options) => page.evaluate((points, options) => {
    if (window.viewer) window.viewer.dispose();
    const started = performance.now();
    const cloud = window.makeCloud(points);
    window.viewer = CraftscanViewer.create(document.getElementById('v'), options);
    window.viewer.setData({ cloud });
    return performance.now() - started;
  }, POINTS, options);

  const settle = (ms) => new Promise((resolve) => setTimeout(resolve, ms));
  const stats = () => page.evaluate(() => window.viewer.stats());

  // Dragging in circles for SECONDS; fps sampled once a second after the first.
  const interact = async () => {
    const cx = WIDTH / 2, cy = HEIGHT / 2;
    await page.mouse.move(cx, cy);
    await page.mouse.down();
    const samples = [];
    let drawn = 0;
    const start = Date.now();
    let k = 0;
    let nextSample = start + 1000;
    while (Date.now() - start < SECONDS * 1000) {
      k++;
      await page.mouse.move(cx + 150 * Math.cos(k / 10), cy + 60 * Math.sin(k / 10));
      await settle(16);
      if (Date.now() >= nextSample) {
        const s = await stats();
        samples.push(s.fps);
        drawn = s.drawnPoints;
        nextSample += 1000;
      }
    }
    await page.mouse.up();
    return { fps: median(samples), samples, drawn };
  };
  const rest = async () => {
    await settle(1500);
    const samples = [];
    for (let i = 0; i < SECONDS - 1; i++) {
      await settle(1000);
      samples.push((await stats()).fps);
    }
    const s = await stats();
    return { fps: median(samples), samples, drawn: s.drawnPoints };
  };

  const results = [];
  // The viewer's default turns MSAA off on a software renderer; forced on for comparison.
  for (const antialias of [true, undefined]) {
    const aa = antialias ? 'MSAA on ' : 'default ';
    const ms = await setup({ antialias });
    t.log(`${aa}: ${POINTS} points set (generated, shuffled, uploaded) in ${ms.toFixed(0)} ms`);
    await settle(1000);
    results.push([`${aa}  interacting, levels of detail`, await interact()]);
    results.push([`${aa}  resting, on demand (draws nothing)`, await rest()]);
    await setup({ antialias, continuous: true });
    results.push([`${aa}  resting, every frame drawn whole`, await rest()]);
    await setup({ antialias, lodPoints: 1e9 });
    await settle(1000);
    results.push([`${aa}  interacting, levels of detail off`, await interact()]);
  }

  await t.screenshot(page, 'bench_cloud', '#v');
  console.log(`\nviewer_bench: ${POINTS} points, ${WIDTH}x${HEIGHT}, ${await t.browser.version()}, SwiftShader`);
  for (const [label, r] of results) {
    console.log(`  ${label.padEnd(48)} ${String(r.fps).padStart(4)} fps  (drawn ${r.drawn} points; per second: ${r.samples.join(' ')})`);
  }
}, { timeoutMs: 300000 });

function median(values) {
  if (!values.length) return 0;
  const sorted = [...values].sort((a, b) => a - b);
  return sorted[Math.floor(sorted.length / 2)];
}
