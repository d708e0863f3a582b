// The 3D viewer's API (clients/web/API.md "The 3D viewer") in headless
// Chromium, offline: loadPly of ASCII and binary PLY (cloud, mesh), the
// errors for malformed input (a rejected promise with a clear message,
// shown in the container), setData's checks, setMode, stats, dispose.
//
//   node tests/browser/viewer_api.mjs [--bundle build/clients/web/assets/viewer.bundle.js]
import fs from 'node:fs';
import path from 'node:path';
import { pathToFileURL } from 'node:url';

import { check, runBrowserTest, sourceDir } from './lib.mjs';

function option(name, fallback) {
  const at = process.argv.indexOf(name);
  return at > 0 ? process.argv[at + 1] : fallback;
}

const bundlePath = option('--bundle', process.env.CRAFTSCAN_VIEWER_BUNDLE ||
  path.join(sourceDir, 'build', 'clients', 'web', 'assets', 'viewer.bundle.js'));

// As the station writes them (pipeline/common/ply.h): mm, +Z up, uchar colours.
const asciiCloud = `ply
format ascii 1.0
comment craftscan point cloud, units mm
element vertex 4
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
end_header
0 0 0 255 0 0
40 0 0 0 255 0
0 40 0 0 0 255
0 0 40 255 255 255
`;

function binaryMesh() {
  const header = Buffer.from(`ply
format binary_little_endian 1.0
comment craftscan mesh, units mm
element vertex 4
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element face 4
property list uchar int vertex_indices
end_header
`, 'latin1');
  const vertices = [[0, 0, 0], [40, 0, 0], [0, 40, 0], [0, 0, 40]];
  const faces = [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
  const body = Buffer.alloc(4 * 15 + 4 * 13);
  let at = 0;
  for (const v of vertices) {
    for (const c of v) at = body.writeFloatLE(c, at);
    for (const c of [200, 120, 60]) at = body.writeUInt8(c, at);
  }
  for (const f of faces) {
    at = body.writeUInt8(3, at);
    for (const i of f) at = body.writeInt32LE(i, at);
  }
  return Buffer.concat([header, body]);
}

runBrowserTest('viewer_api', async (t) => {
  check(fs.existsSync(bundlePath), `no bundle at ${bundlePath} (build craftscan_viewer_bundle, or --bundle)`);
  const html = path.join(t.artifacts, 'viewer_api.html');
  fs.writeFileSync(html, `<!DOCTYPE html><html><body style="margin:0">
    <div id="box" style="width:640px;height:400px"></div>
    <script src="${pathToFileURL(bundlePath).href}"></script></body></html>`);
  const page = await t.offlinePage({ width: 640, height: 400 });
  await page.goto(pathToFileURL(html).href, { waitUntil: 'load' });
  check(await page.evaluate(() => typeof CraftscanViewer.create === 'function'), 'no CraftscanViewer.create');

  const mesh = binaryMesh();
  const result = await page.evaluate(async (asciiCloud, meshBytes) => {
    const out = {};
    const bytes = (text) => new TextEncoder().encode(text).buffer;
    const errorOf = async (f) => {
      try {
        await f();
        return 'no error';
      } catch (e) {
        return e.message;
      }
    };
    const v = CraftscanViewer.create(document.getElementById('box'), { background: '#102030' });
    window.viewerUnderTest = v;
    out.cloud = await v.loadPly(bytes(asciiCloud));
    out.mesh = await v.loadPly(new Uint8Array(meshBytes).buffer);
    out.statsBoth = v.stats();
    out.garbage = await errorOf(() => v.loadPly(bytes('this is not a model')));
    out.shown = document.getElementById('box').textContent;
    const truncated = new Uint8Array(meshBytes).slice(0, meshBytes.length - 20).buffer;
    out.truncated = await errorOf(() => v.loadPly(truncated));
    out.noVertices = await errorOf(() => v.loadPly(bytes('ply\nformat ascii 1.0\nelement face 0\nend_header\n')));
    out.shortAscii = await errorOf(() => v.loadPly(bytes(asciiCloud.split('\n').slice(0, 14).join('\n'))));
    out.badIndex = await errorOf(() => v.setData({ mesh: { positions: new Float32Array(9), colors: null,
                                                          indices: new Uint32Array([0, 1, 3]) } }));
    out.badColors = await errorOf(() => v.setData({ cloud: { positions: new Float32Array(9), colors: new Uint8Array(3) } }));
    out.badMode = await errorOf(() => v.setMode('wireframe'));
    out.statsAfterErrors = v.stats();  // the failed calls changed nothing
    out.set = v.setData({ cloud: { positions: new Float32Array([0, 0, 0, 10, 0, 0, 0, 10, 5]), colors: null } });
    v.setMode('cloud');
    v.resetView();
    return out;
  }, asciiCloud, [...mesh]);
  t.log(JSON.stringify(result));

  check(result.cloud.points === 4 && result.cloud.triangles === 0, `ASCII cloud: ${JSON.stringify(result.cloud)}`);
  check(result.mesh.points === 4 && result.mesh.triangles === 4, `binary mesh: ${JSON.stringify(result.mesh)}`);
  check(result.statsBoth.points === 4 && result.statsBoth.triangles === 4, `stats: ${JSON.stringify(result.statsBoth)}`);
  check(/cannot load PLY data: not a PLY file/.test(result.garbage), `garbage: ${result.garbage}`);
  check(result.shown.includes('not a PLY file'), `the container does not show the error: '${result.shown}'`);
  check(/truncated/.test(result.truncated), `truncated: ${result.truncated}`);
  check(/no vertex element/.test(result.noVertices), `no vertices: ${result.noVertices}`);
  check(/readable vertices|not a finite/.test(result.shortAscii), `short ASCII body: ${result.shortAscii}`);
  check(/out of range/.test(result.badIndex), `bad index: ${result.badIndex}`);
  check(/colors has 1 entries for 3 points/.test(result.badColors), `bad colours: ${result.badColors}`);
  check(/not cloud, mesh or both/.test(result.badMode), `bad mode: ${result.badMode}`);
  check(result.statsAfterErrors.points === 4 && result.statsAfterErrors.triangles === 4,
        `failed calls changed the model: ${JSON.stringify(result.statsAfterErrors)}`);
  check(result.set.points === 3 && result.set.triangles === 0, `setData: ${JSON.stringify(result.set)}`);

  await page.waitForFunction(() => window.viewerUnderTest.stats().frames > 0, { timeout: 5000 });
  await t.screenshot(page, 'three_points', '#box');
  const disposed = await page.evaluate(() => {
    window.viewerUnderTest.dispose();
    return document.querySelectorAll('#box canvas').length;
  });
  check(disposed === 0, 'dispose() left the canvas');
  check(page.errors.length === 0, `page errors: ${page.errors.join('; ')}`);
  check(page.refused.length === 0, `the page asked for the network: ${page.refused.join(', ')}`);
});
