// A guided camera calibration on the Calibrate page in headless Chromium,
// against the real craftscand on the sim with its simulated technician
// (console_station with --sim-extra ", technician: 1, technician_fps: 4,
// supersampling: 1" and --calibration "{guided: true, views: 10,
// guided_max_s: 300}"): the technician moves the board, holds it, blurs it,
// takes it out of view and too close; the daemon takes views only when it is
// held still in a new pose and says what to do.
//   - an admin opens the Calibrate page and starts the calibration with its
//     button;
//   - the live pictures carry the guide's overlay: the board's corners drawn
//     over both cameras (<svg data-corners> > 0, the corners' colours in the
//     picture's pixels), and the pictures change from frame to frame;
//   - the coverage grid fills (and its pixels change), the variety bars rise
//     and the advice text changes as views are taken; the page shows the
//     states moving and holding, and the views kept;
//   - every overlay the page receives (its WebSocket frames, read through
//     the DevTools protocol): the states searching, moving, holding and
//     captured all occur, the corners lie within the preview picture, 10
//     views are accepted within 180 s of the technician's (frame) time, and
//     the reasons views were refused are logged;
//   - the verdict: the page shows the calibration done and accepted with an
//     RMS of at most 0.25 px; the job's result (status verb, from the page)
//     agrees and the guide covered at least 75 % of the image;
//   - then the turntable axis from the same page: the technician lays the
//     board on the platter, the page tells them how ("Lay the board", "Let
//     go", "Hands off") and shows the six angles measured; the axis is
//     accepted with a residual under 0.5 mm.
// Screenshots mid-calibration and of the verdict in the artifacts folder
// (calibrate/).
//
//   node calibrate.mjs --station-harness PATH --assets DIR
import { runBrowserTest, check, fractionChanged } from './lib.mjs';
import { consolePage, harnessArgs, pageFetch, sel, signIn, startStation } from './station.mjs';

const harness = harnessArgs('calibrate.mjs');
// Views the guide asks for: the fewest the verdict accepts (10); the picture
// is covered (11 of its 12 cells) by the sixth.
const VIEWS = 10;
const COVERAGE_GRID = `${sel('calib-coverage')} .coverage-grid`;
const TONES = [[0x2f, 0xd1, 0x5f], [0xff, 0xb0, 0x20], [0xff, 0x4a, 0x3d]]; // style.css corner tones

// What the guide panel shows now.
async function guideState(page) {
  return page.evaluate(() => {
    const q = (id) => document.querySelector(`[data-testid="${id}"]`);
    const guide = q('calib-guide');
    const corners = q('calib-corners');
    const layers = corners ? [...corners.querySelectorAll('svg.corner-layer')] : [];
    return {
      visible: !!guide && !guide.hidden,
      state: guide?.dataset.state ?? '',
      running: guide?.dataset.running === 'true',
      advice: q('calib-advice')?.hidden === false ? q('calib-advice').textContent.trim() : '',
      rejected: q('calib-rejected')?.hidden === false ? q('calib-rejected').textContent.trim() : '',
      accepted: Number(q('calib-counts')?.dataset.accepted || 0),
      needed: Number(q('calib-counts')?.dataset.needed || 0),
      covered: Number(q('calib-coverage')?.dataset.covered || 0),
      cells: Number(q('calib-coverage')?.dataset.cells || 0),
      diversity: Object.fromEntries([...document.querySelectorAll('[data-testid="calib-diversity"] [data-axis]')]
        .map((r) => [r.dataset.axis, Number(r.dataset.value)])),
      frame: corners && !corners.hidden ? corners.dataset.frame ?? '' : '',
      corners: layers.map((l) => Number(l.dataset.corners || 0)),
    };
  });
}

// Pixels of a screenshot near one of the corner colours.
function tonedPixels(image) {
  let n = 0;
  const d = image.data;
  for (let i = 0; i < d.length; i += 4) {
    if (TONES.some((c) => Math.abs(d[i] - c[0]) + Math.abs(d[i + 1] - c[1]) + Math.abs(d[i + 2] - c[2]) < 60)) n++;
  }
  return n;
}

runBrowserTest('calibrate', async (t) => {
  const station = await startStation({
    ...harness,
    simExtra: ', technician: 1, technician_fps: 4, supersampling: 1',
    calibration: `{guided: true, views: ${VIEWS}, guided_max_s: 300}`,
  });
  const { info } = station;
  t.log('station', info.station, 'at', info.url);
  try {
    const page = await consolePage(t.browser, info.url, { width: 1280, height: 1000 });
    // Every message the page receives over its WebSocket.
    const overlays = [];
    const finals = new Map(); // job id → {stage, message}
    const cdp = await page.createCDPSession();
    await cdp.send('Network.enable');
    cdp.on('Network.webSocketFrameReceived', ({ response }) => {
      let m;
      try {
        m = JSON.parse(response.payloadData);
      } catch {
        return;
      }
      if (m.type === 'preview' && m.overlay && m.overlay.kind === 'calibration') {
        overlays.push({ job: m.job_id, stamp: Number(m.stamp_ns), width: m.width, height: m.height, o: m.overlay });
      } else if (m.type === 'progress' && ['done', 'failed', 'cancelled'].includes(m.stage)) {
        finals.set(m.job_id, { stage: m.stage, message: m.message });
      }
    });

    await page.goto(info.url, { waitUntil: 'load' });
    await signIn(page, info, info.admin);
    await page.waitForFunction((s) => document.querySelector(s)?.dataset.state === 'idle',
                               { timeout: 15000 }, sel('station-state'));
    await page.click(sel('nav-calibrate'));
    await page.waitForSelector(sel('calibrate-start'), { visible: true });
    await page.click(sel('calibrate-start'));
    await page.waitForFunction((s) => {
      const e = document.querySelector(s);
      return e && !e.hidden && e.dataset.running === 'true';
    }, { timeout: 30000 }, sel('calib-guide'));
    const started = Date.now();
    t.log('the guide is shown');

    // Follow the page until the verdict: what it shows, and the pictures of
    // two frames with corners.
    const seen = { states: new Set(), advice: new Set(), rejected: new Set(), diversity: new Set() };
    let first = null;
    let last = null;
    let coverageBefore = null;
    let coverageLate = null;
    const cornerShots = [];
    let midShot = false;
    let tonedWithout = null; // corner-coloured pixels in a frame without corners
    for (;;) {
      const verdict = await page.$eval(sel('calibrate-result'), (e) => (e.hidden ? '' : e.dataset.state ?? ''));
      if (verdict) break;
      check(Date.now() - started < 200000, 'no verdict within 200 s');
      const s = await guideState(page);
      if (s.visible && s.running) {
        first ??= s;
        last = s;
        seen.states.add(s.state);
        if (s.advice) seen.advice.add(s.advice);
        if (s.rejected) seen.rejected.add(s.rejected);
        seen.diversity.add(JSON.stringify(s.diversity));
        if (!coverageBefore && s.cells > 0) coverageBefore = await t.screenshot(page, '01-coverage-first', COVERAGE_GRID);
        const withCorners = s.frame && s.corners.length === 2 && s.corners.every((n) => n > 0);
        if (withCorners && cornerShots.length < 2 && (!cornerShots.length || cornerShots[0].frame !== s.frame) &&
            (!cornerShots.length || s.accepted > cornerShots[0].accepted)) {
          const image = await t.screenshot(page, `02-corners-${cornerShots.length + 1}`, sel('calib-corners'));
          cornerShots.push({ frame: s.frame, accepted: s.accepted, corners: s.corners, image, toned: tonedPixels(image) });
        } else if (s.frame && s.corners.every((n) => n === 0) && tonedWithout === null) {
          tonedWithout = tonedPixels(await t.screenshot(page, '02-corners-none', sel('calib-corners')));
        }
        if (!coverageLate && s.needed > 0 && s.accepted >= s.needed - 2) {
          coverageLate = await t.screenshot(page, '05-coverage-late', COVERAGE_GRID);
        }
        if (!midShot && s.accepted >= 6) {
          midShot = true;
          await t.screenshot(page, '03-mid-calibration');
          t.log(`mid-calibration: ${s.accepted} of ${s.needed} views, ${s.covered} of ${s.cells} cells, advice "${s.advice}"`);
        }
      }
      await new Promise((r) => setTimeout(r, 250));
    }
    t.log(`verdict after ${((Date.now() - started) / 1000).toFixed(1)} s`);
    await t.screenshot(page, '04-verdict');

    // The page along the way.
    t.log('page states:', [...seen.states].join(' '));
    for (const a of seen.advice) t.log('  advice:', a);
    for (const r of seen.rejected) t.log('  ', r);
    check(first && last, 'the guide never showed a running calibration');
    for (const state of ['moving', 'holding']) check(seen.states.has(state), `the page never showed "${state}"`);
    check(seen.advice.size >= 3, `the advice changed ${seen.advice.size - 1} times`);
    check(seen.diversity.size >= 3, `the variety bars changed ${seen.diversity.size - 1} times`);
    const axes = Object.keys(last.diversity);
    check(axes.length === 4, `variety bars: ${axes.join(', ')}`);
    check(axes.some((k) => last.diversity[k] > (first.diversity[k] ?? 0)), 'no variety bar rose');
    check(last.cells > 0 && last.covered > first.covered, `coverage ${first.covered} → ${last.covered} of ${last.cells} cells`);
    const end = await guideState(page); // what the views covered stays beside the verdict
    check(end.visible && !end.running && end.accepted >= VIEWS && end.needed === VIEWS,
          `after the verdict the guide shows ${end.accepted} of ${end.needed} views`);

    // The overlay drawn: corners in both pictures, in their colours, and the
    // pictures moving on.
    check(cornerShots.length === 2, `${cornerShots.length} frames with the board's corners shown`);
    const [a, b] = cornerShots;
    const moved = fractionChanged(a.image, b.image);
    t.log(`corner frames ${a.frame} (${a.corners}) and ${b.frame} (${b.corners}): ${(100 * moved).toFixed(1)} % of the pixels changed; ` +
          `${a.toned} and ${b.toned} pixels in the corners' colours (${tonedWithout ?? 'no frame'} without corners)`);
    check(moved > 0.01, 'the live pictures did not change between frames');
    check(a.toned > 100 && b.toned > 100, 'the corners are not drawn over the pictures');
    if (tonedWithout !== null) {
      check(Math.min(a.toned, b.toned) > 2 * tonedWithout + 100, 'the corners\' colours are as common without corners');
    }
    check(coverageBefore && coverageLate, 'no coverage grid shown while the calibration ran');
    const filled = fractionChanged(coverageBefore, coverageLate);
    t.log(`coverage grid: ${(100 * filled).toFixed(1)} % of its pixels changed`);
    check(filled > 0.05, 'the coverage grid did not fill');

    // Every overlay the page was sent.
    check(overlays.length > 0, 'no calibration overlay reached the page');
    const job = overlays[0].job;
    const mine = overlays.filter((m) => m.job === job);
    const states = new Set(mine.map((m) => m.o.state));
    const rejections = new Set(mine.map((m) => m.o.rejected).filter(Boolean));
    const technicianS = (mine[mine.length - 1].stamp - mine[0].stamp) * 1e-9;
    const maxViews = Math.max(...mine.map((m) => Number(m.o.views_accepted) || 0));
    t.log(`${mine.length} overlays over ${technicianS.toFixed(0)} s of technician time; states: ${[...states].join(' ')}; ` +
          `rejected: ${[...rejections].map((r) => `'${r}'`).join(' ')}`);
    for (const state of ['searching', 'moving', 'holding', 'captured']) check(states.has(state), `never ${state}`);
    check(maxViews >= VIEWS, `${maxViews} views accepted`);
    check(technicianS <= 180, `accepted after ${technicianS.toFixed(0)} s of the technician's time (> 3 minutes)`);
    for (const m of mine) {
      for (const side of ['left', 'right']) {
        for (const p of m.o.board?.[side] ?? []) {
          check(p[0] >= -1 && p[0] <= m.width + 1 && p[1] >= -1 && p[1] <= m.height + 1,
                `a ${side} corner (${p}) outside the ${m.width}x${m.height} preview`);
        }
      }
    }
    const final = finals.get(job);
    check(final && final.stage === 'done', `the job ended ${JSON.stringify(final)}`);
    t.log('final:', final.message);

    // The verdict on the page, and the job's result.
    const verdict = await page.$eval(sel('calibrate-result'), (e) => ({
      state: e.dataset.state,
      text: e.textContent.trim(),
      fields: Object.fromEntries([...e.querySelectorAll('dd[data-key]')].map((d) => [d.dataset.key, d.textContent.trim()])),
    }));
    t.log('verdict:', verdict.text.replace(/\s+/g, ' ').slice(0, 200));
    check(verdict.state === 'done', `verdict ${verdict.state}`);
    check(verdict.fields.accepted === 'yes', `accepted: ${verdict.fields.accepted}`);
    const rms = parseFloat(verdict.fields.rms_stereo_px);
    check(rms > 0 && rms <= 0.25, `the page shows an RMS of ${verdict.fields.rms_stereo_px}`);
    const status = await pageFetch(page, '/api/command', {
      method: 'POST',
      headers: { 'Content-Type': 'application/json', 'X-Craftscan-Request': '1' },
      body: JSON.stringify({ verb: 'status' }),
    });
    const result = status.body?.result?.job?.result ?? {};
    t.log(`rms ${result.rms_stereo_px} px, epipolar ${result.epipolar_mean_px} px, coverage ${result.guided?.coverage}`);
    check(result.accepted === true, `the job's result: ${JSON.stringify(result)}`);
    check(result.rms_stereo_px <= 0.25 && Math.abs(result.rms_stereo_px - rms) < 0.01, `RMS ${result.rms_stereo_px} px`);
    check(result.guided?.coverage >= 0.75, `the guide covered ${result.guided?.coverage}`);

    // The turntable axis, guided the same way: the technician lays the board
    // on the platter; the page shows the angles as they are measured.
    await page.waitForFunction((s) => !document.querySelector(s)?.disabled, { timeout: 15000 },
                               sel('calibrate-turntable-start'));
    await page.click(sel('calibrate-turntable-start'));
    const tableStarted = Date.now();
    const tableSeen = { advice: new Set(), found: 0 };
    for (;;) {
      const v = await page.$eval(sel('calibrate-result'), (e) =>
        (e.hidden || !e.textContent.includes('Turntable') ? '' : e.dataset.state ?? ''));
      const a = await page.$eval(sel('calib-angles'), (e) => ({
        visible: !e.hidden, found: Number(e.dataset.found) || 0,
        advice: document.querySelector('[data-testid="calib-advice"]')?.textContent ?? '',
      }));
      if (a.visible) tableSeen.found = Math.max(tableSeen.found, a.found);
      if (a.advice) tableSeen.advice.add(a.advice);
      if (v && a.found >= 6) break;
      if (v === 'failed' || v === 'cancelled') break;
      check(Date.now() - tableStarted < 90000, 'no turntable verdict within 90 s');
      if (a.found === 3 && !tableSeen.shot) {
        tableSeen.shot = true;
        await t.screenshot(page, '07-turntable-turning');
      }
      await new Promise((r) => setTimeout(r, 150));
    }
    await t.screenshot(page, '08-turntable-verdict');
    const table = await page.$eval(sel('calibrate-result'), (e) => ({
      state: e.dataset.state,
      fields: Object.fromEntries([...e.querySelectorAll('dd[data-key]')].map((d) => [d.dataset.key, d.textContent.trim()])),
    }));
    t.log(`turntable: ${table.state}, ${JSON.stringify(table.fields)}; advice seen: ${[...tableSeen.advice].join(' | ')}`);
    check(table.state === 'done', `the turntable calibration ended ${table.state}`);
    check(tableSeen.found === 6, `${tableSeen.found} of 6 angles shown measured`);
    check([...tableSeen.advice].some((x) => /Lay the board|Let go|Hands off/.test(x)),
          'the page never told the person how to lay the board');
    const residual = parseFloat(table.fields.residual_mm);
    check(residual >= 0 && residual < 0.5, `turntable residual ${table.fields.residual_mm} mm`);

    check(page.refused.length === 0, `requests outside the console: ${page.refused.join(', ')}`);
    check(page.errors.length === 0, `page errors: ${page.errors.join(' | ')}`);
  } finally {
    await station.stop();
  }
}, { timeoutMs: 230000 });
