// report.html's 3D view from file:// without network (daemon/report,
// clients/web/API.md "The 3D viewer"): the inline viewer starts, draws the
// model (the canvas is not just background), turns when dragged (the
// picture changes), and the page makes no request. With --no-webgl (a
// browser without WebGL) the view says so and the pictures remain.
//
//   node tests/browser/report_viewer.mjs --report-demo build/tests/browser/craftscan_browser_report_demo [--no-webgl]
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import path from 'node:path';
import { pathToFileURL } from 'node:url';

import { check, drag, fractionChanged, fractionNot, hexRgb, runBrowserTest } from './lib.mjs';

const BACKGROUND = '#1d2125';  // the report's viewer background
const POINTS = 60000;

function option(name) {
  const at = process.argv.indexOf(name);
  return at > 0 ? process.argv[at + 1] : undefined;
}

function writeReport(t) {
  const demo = option('--report-demo');
  check(demo && fs.existsSync(demo), `--report-demo: '${demo}' is not the report demo program`);
  const session = path.join(t.artifacts, 'session');
  fs.rmSync(session, { recursive: true, force: true });
  t.log(execFileSync(demo, ['--out', session, '--points', String(POINTS)], { encoding: 'utf8' }).trim());
  return path.join(session, 'report.html');
}

if (process.argv.includes('--no-webgl')) {
  runBrowserTest('report_viewer_no_webgl', async (t) => {
    const report = writeReport(t);
    const page = await t.offlinePage({ width: 1100, height: 900 });
    await page.goto(pathToFileURL(report).href, { waitUntil: 'load', timeout: 15000 });
    const view = await page.$eval('#craftscan-viewer', (e) => ({ failed: e.classList.contains('failed'), text: e.textContent }));
    t.log('view:', view.text);
    check(view.failed && /not available in this browser.*WebGL/.test(view.text),
          `without WebGL the view should say it is unavailable: ${JSON.stringify(view)}`);
    const pictures = await page.$$eval('#cloud img, #mesh img', (images) => images.length);
    check(pictures === 10, `${pictures} preview pictures, expected 5 cloud + 5 mesh`);
    check(page.errors.length === 0, `page errors: ${page.errors.join('; ')}`);
    check(page.refused.length === 0, `the page asked for the network: ${page.refused.join(', ')}`);
    await page.$eval('#model', (e) => e.scrollIntoView());
    await t.screenshot(page, 'fallback');
  }, { launchArgs: ['--disable-3d-apis', '--disable-webgl'] });
} else {
  runBrowserTest('report_viewer', async (t) => {
    const report = writeReport(t);

    const page = await t.offlinePage({ width: 1100, height: 900 });
    await page.goto(pathToFileURL(report).href, { waitUntil: 'load', timeout: 15000 });
    await page.waitForFunction(
      () => (window.craftscanViewer && window.craftscanViewer.stats().frames > 0) ||
            document.querySelector('#craftscan-viewer.failed'),
      { timeout: 10000 });
    const failed = await page.$eval('#craftscan-viewer', (e) => (e.classList.contains('failed') ? e.textContent : ''));
    check(!failed, `the viewer did not start: ${failed}`);
    await page.$eval('#craftscan-viewer', (e) => e.scrollIntoView({ block: 'center' }));

    const stats = await page.evaluate(() => window.craftscanViewer.stats());
    t.log('stats', JSON.stringify(stats));
    check(stats.points === POINTS, `viewer has ${stats.points} points, the report ${POINTS}`);
    check(stats.triangles === 19200, `viewer has ${stats.triangles} triangles, the mesh 19200`);

    const canvas = '#craftscan-viewer canvas';
    const waitForRest = () => page.waitForFunction(() => !window.craftscanViewer.stats().moving, { timeout: 8000 });
    await waitForRest();
    const before = await t.screenshot(page, 'mesh_front', canvas);
    const drawn = fractionNot(before, hexRgb(BACKGROUND));
    t.log(`model covers ${(100 * drawn).toFixed(1)} % of the ${before.width}x${before.height} canvas`);
    check(drawn > 0.08, `the canvas is background but for ${(100 * drawn).toFixed(2)} %: no model drawn`);

    // Drag a third of the width: a turn of about 120° about the up axis.
    const box = await (await page.$(canvas)).boundingBox();
    await drag(page, box.x + box.width / 2, box.y + box.height / 2, box.width / 3, 0, 15);
    await waitForRest();
    const after = await t.screenshot(page, 'mesh_turned', canvas);
    const changed = fractionChanged(before, after);
    t.log(`dragging changed ${(100 * changed).toFixed(1)} % of the pixels`);
    check(changed > 0.03, `dragging changed only ${(100 * changed).toFixed(2)} % of the pixels`);

    // The cloud alone, through the viewer's buttons.
    await page.evaluate(() => window.craftscanViewer.setMode('cloud'));
    await waitForRest();
    await page.waitForFunction(() => window.craftscanViewer.stats().drawnPoints > 0, { timeout: 5000 });
    const cloud = await t.screenshot(page, 'cloud_turned', canvas);
    check(fractionNot(cloud, hexRgb(BACKGROUND)) > 0.05, 'the cloud is not drawn');
    const cloudStats = await page.evaluate(() => window.craftscanViewer.stats());
    check(cloudStats.drawnPoints === POINTS, `at rest ${cloudStats.drawnPoints} of ${POINTS} points drawn`);

    check(page.errors.length === 0, `page errors: ${page.errors.join('; ')}`);
    check(page.refused.length === 0, `the page asked for the network: ${page.refused.join(', ')}`);
    if (page.consoleErrors.length) t.log('console errors:', page.consoleErrors.join('; '));
    await t.screenshot(page, 'page');
  });
}
