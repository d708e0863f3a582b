// Helpers for craftscan's browser tests (tests/browser/CMakeLists.txt):
// headless Chromium via puppeteer-core with SwiftShader's software WebGL,
// pages that may load file:// URLs only, screenshots kept as artifacts, a
// hard timeout per test, and a PNG decoder for pixel checks.
//
//   import { runBrowserTest, check } from './lib.mjs';
//   runBrowserTest('my_test', async (t) => {
//     const page = await t.offlinePage({ width: 1000, height: 700 });
//     await page.goto(pathToFileURL(file).href);
//     const png = await t.screenshot(page, 'loaded', '#thing');
//     check(png.width > 0, 'screenshot is empty');
//   });
//
// Environment: CRAFTSCAN_BROWSER_ARTIFACTS (screenshots; default
// <source>/build/tests/browser/artifacts), CRAFTSCAN_CHROMIUM (default
// /usr/bin/chromium), NODE_PATH (clients/web/node_modules; found from the
// source tree when unset).
import { createRequire } from 'node:module';
import fs from 'node:fs';
import path from 'node:path';
import { fileURLToPath } from 'node:url';
import zlib from 'node:zlib';

const here = path.dirname(fileURLToPath(import.meta.url));
export const sourceDir = path.resolve(here, '..', '..');

// puppeteer-core from NODE_PATH (require honours it, import does not), else
// from the source tree's clients/web.
function loadPuppeteer() {
  try {
    return createRequire(import.meta.url)('puppeteer-core');
  } catch {
    return createRequire(path.join(sourceDir, 'clients', 'web', 'package.json'))('puppeteer-core');
  }
}

export function artifactsDir(name) {
  const root = process.env.CRAFTSCAN_BROWSER_ARTIFACTS ||
    path.join(sourceDir, 'build', 'tests', 'browser', 'artifacts');
  const dir = name ? path.join(root, name) : root;
  fs.mkdirSync(dir, { recursive: true });
  return dir;
}

export class CheckError extends Error {}

/** Throws (failing the test) with `message` unless `condition`. */
export function check(condition, message) {
  if (!condition) throw new CheckError(message);
}

export const chromiumArgs = [
  '--headless=new',
  '--no-sandbox',
  '--use-gl=swiftshader',
  '--use-angle=swiftshader',
  '--enable-unsafe-swiftshader',
  '--ignore-gpu-blocklist',
  '--disable-gpu-vsync',  // frame rates not capped by a display that is not there
  '--no-first-run',
  '--no-default-browser-check',
  '--disable-background-networking',
  '--disable-component-update',
  '--disable-features=Translate,MediaRouter,OptimizationHints',
  '--mute-audio',
];

export async function launchBrowser(extraArgs = []) {
  const puppeteer = loadPuppeteer();
  return puppeteer.launch({
    executablePath: process.env.CRAFTSCAN_CHROMIUM || '/usr/bin/chromium',
    headless: true,
    args: [...chromiumArgs, ...extraArgs],
    protocolTimeout: 20000,
  });
}

// A page that may load file: URLs only (data:, blob: and about: are
// in-page, not network). Every other request is refused and listed in
// page.refused; uncaught page errors in page.errors, console errors in
// page.consoleErrors.
export async function offlinePage(browser, { width = 1024, height = 768 } = {}) {
  const page = await browser.newPage();
  page.refused = [];
  page.errors = [];
  page.consoleErrors = [];
  await page.setViewport({ width, height, deviceScaleFactor: 1 });
  await page.setRequestInterception(true);
  page.on('request', (request) => {
    const url = request.url();
    if (/^(file|data|blob|about):/.test(url)) {
      request.continue();
    } else {
      page.refused.push(url);
      request.abort('internetdisconnected');
    }
  });
  page.on('pageerror', (error) => page.errors.push(String(error && error.message ? error.message : error)));
  page.on('console', (message) => {
    if (message.type() === 'error') page.consoleErrors.push(message.text());
  });
  return page;
}

/**
 * Runs `body(t)` with a fresh headless Chromium; exits the process 0 when it
 * resolves, 1 when it throws or takes longer than timeoutMs (the browser is
 * killed). t: {name, browser, artifacts, offlinePage(opts), screenshot(page, label, selector), log}.
 */
export function runBrowserTest(name, body, { timeoutMs = 25000, launchArgs = [] } = {}) {
  const started = Date.now();
  const log = (...parts) => console.log(`[${name} ${((Date.now() - started) / 1000).toFixed(1)}s]`, ...parts);
  let browser = null;
  const kill = () => {
    try {
      const child = browser && browser.process();
      if (child && child.exitCode === null) child.kill('SIGKILL');
    } catch {
      // already gone
    }
  };
  const timer = setTimeout(() => {
    console.error(`${name}: FAILED: took longer than ${timeoutMs} ms (hard timeout)`);
    kill();
    process.exit(1);
  }, timeoutMs);
  const run = async () => {
    browser = await launchBrowser(launchArgs);
    log('browser', await browser.version());
    const artifacts = artifactsDir(name);
    const t = {
      name,
      browser,
      artifacts,
      log,
      offlinePage: (options) => offlinePage(browser, options),
      // PNG of `selector` (or the viewport) saved as <artifacts>/<label>.png; returns it decoded.
      screenshot: async (page, label, selector) => {
        const target = selector ? await page.$(selector) : page;
        check(target, `screenshot ${label}: no element matches ${selector}`);
        const bytes = Buffer.from(await target.screenshot({ type: 'png' }));
        const file = path.join(artifacts, `${label}.png`);
        fs.writeFileSync(file, bytes);
        log('screenshot', file);
        return decodePng(bytes);
      },
    };
    await body(t);
  };
  run()
    .then(async () => {
      clearTimeout(timer);
      await browser.close().catch(kill);
      log('PASSED');
      process.exit(0);
    })
    .catch(async (error) => {
      clearTimeout(timer);
      console.error(`${name}: FAILED: ${error instanceof CheckError ? error.message : error && error.stack ? error.stack : error}`);
      if (browser) await browser.close().catch(kill);
      process.exit(1);
    });
}

// --- pixels -----------------------------------------------------------------

/** Decodes an 8-bit RGB or RGBA, non-interlaced PNG (what Chromium writes) → {width, height, data: RGBA}. */
export function decodePng(bytes) {
  check(bytes.subarray(0, 8).equals(Buffer.from([137, 80, 78, 71, 13, 10, 26, 10])), 'not a PNG');
  let width = 0;
  let height = 0;
  let colorType = 0;
  const idat = [];
  for (let at = 8; at < bytes.length;) {
    const length = bytes.readUInt32BE(at);
    const type = bytes.toString('latin1', at + 4, at + 8);
    const data = bytes.subarray(at + 8, at + 8 + length);
    if (type === 'IHDR') {
      width = data.readUInt32BE(0);
      height = data.readUInt32BE(4);
      check(data[8] === 8 && data[12] === 0, 'PNG: only 8-bit, non-interlaced');
      colorType = data[9];
      check(colorType === 2 || colorType === 6, `PNG: colour type ${colorType} unsupported`);
    } else if (type === 'IDAT') {
      idat.push(data);
    }
    at += 12 + length;
  }
  const channels = colorType === 6 ? 4 : 3;
  const raw = zlib.inflateSync(Buffer.concat(idat));
  const stride = width * channels;
  const out = Buffer.alloc(width * height * 4);
  let previous = Buffer.alloc(stride);
  for (let y = 0; y < height; y++) {
    const filter = raw[y * (stride + 1)];
    const line = Buffer.from(raw.subarray(y * (stride + 1) + 1, (y + 1) * (stride + 1)));
    for (let i = 0; i < stride; i++) {
      const a = i >= channels ? line[i - channels] : 0;
      const b = previous[i];
      const c = i >= channels ? previous[i - channels] : 0;
      let add = 0;
      if (filter === 1) add = a;
      else if (filter === 2) add = b;
      else if (filter === 3) add = (a + b) >> 1;
      else if (filter === 4) {
        const p = a + b - c;
        const pa = Math.abs(p - a);
        const pb = Math.abs(p - b);
        const pc = Math.abs(p - c);
        add = pa <= pb && pa <= pc ? a : pb <= pc ? b : c;
      }
      line[i] = (line[i] + add) & 255;
    }
    for (let x = 0; x < width; x++) {
      for (let k = 0; k < 3; k++) out[4 * (y * width + x) + k] = line[x * channels + k];
      out[4 * (y * width + x) + 3] = channels === 4 ? line[x * channels + 3] : 255;
    }
    previous = line;
  }
  return { width, height, data: out };
}

/** "#rrggbb" → [r, g, b] */
export function hexRgb(hex) {
  const v = parseInt(hex.replace('#', ''), 16);
  return [(v >> 16) & 255, (v >> 8) & 255, v & 255];
}

/** Fraction of pixels whose colour is more than `tolerance` (any channel) from rgb. */
export function fractionNot(image, rgb, tolerance = 24) {
  let n = 0;
  const d = image.data;
  for (let i = 0; i < d.length; i += 4) {
    if (Math.abs(d[i] - rgb[0]) > tolerance || Math.abs(d[i + 1] - rgb[1]) > tolerance ||
        Math.abs(d[i + 2] - rgb[2]) > tolerance) n++;
  }
  return n / (image.width * image.height);
}

/** Fraction of pixels that differ by more than `tolerance` (any channel) between two same-size images. */
export function fractionChanged(a, b, tolerance = 24) {
  check(a.width === b.width && a.height === b.height, 'images differ in size');
  let n = 0;
  for (let i = 0; i < a.data.length; i += 4) {
    if (Math.abs(a.data[i] - b.data[i]) > tolerance || Math.abs(a.data[i + 1] - b.data[i + 1]) > tolerance ||
        Math.abs(a.data[i + 2] - b.data[i + 2]) > tolerance) n++;
  }
  return n / (a.width * a.height);
}

/** Drags with the left button from (x0, y0) by (dx, dy) px in `steps` moves. */
export async function drag(page, x0, y0, dx, dy, steps = 20) {
  await page.mouse.move(x0, y0);
  await page.mouse.down();
  for (let k = 1; k <= steps; k++) await page.mouse.move(x0 + (dx * k) / steps, y0 + (dy * k) / steps);
  await page.mouse.up();
}
