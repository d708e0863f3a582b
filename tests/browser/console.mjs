// The console in headless Chromium against the real craftscand on the sim
// (console_station: the daemon plus craftscan-web's server):
//   - the page loads from the console alone (every other URL refused);
//   - an operator signs in and sees the station idle with its role;
//   - a 4-view scan starts from the scan page, its thumbnails arrive live,
//     each view's disparity under its picture once matched (a false-colour
//     picture, decoded in the page: coloured where valid, not one colour,
//     its caption's "% valid" the share of coloured pixels);
//   - the daemon is killed mid-scan: the page says the station is gone; the
//     scan page, left and opened again, still shows the views' pictures and
//     disparities;
//     started again, the session shows as interrupted, Resume completes it;
//   - the finished session opens in the 3D viewer, which draws the model
//     (pixels differ from the background) and turns under the mouse;
//   - an observer sees no scan button, and a forged scan from its page is
//     refused by the daemon (forbidden), one without the console's header
//     by the server (403).
// Screenshots of each page in the artifacts folder.
//
//   node console.mjs --station-harness PATH --assets DIR
import { runBrowserTest, check, drag, fractionChanged } from './lib.mjs';
import {
  consolePage, harnessArgs, pageFetch, sel, signIn, startStation, textOf, waitUntil,
} from './station.mjs';

const harness = harnessArgs('console.mjs');

// The Scan page's disparity pictures, decoded through a canvas in the page:
// [{view, src, valid (data-valid), caption, hasPicture (the camera's
// thumbnail too), width, height, coloured (share of pixels not black),
// colours (occupied bins of 8 levels per channel), topShare (the most common
// bin's share, black counted as one)}].
async function disparityPictures(page) {
  return page.$$eval(`${sel('thumbs')} figure[data-view]`, async (figures) => {
    const out = [];
    for (const figure of figures) {
      const img = figure.querySelector('[data-testid="thumb-disparity"]');
      if (!img) continue;
      const picture = new Image();
      picture.src = img.src;
      await picture.decode();
      const canvas = document.createElement('canvas');
      canvas.width = picture.naturalWidth;
      canvas.height = picture.naturalHeight;
      const g = canvas.getContext('2d');
      g.drawImage(picture, 0, 0);
      const d = g.getImageData(0, 0, canvas.width, canvas.height).data;
      const bins = new Map();
      let black = 0;
      for (let i = 0; i < d.length; i += 4) {
        if (d[i] + d[i + 1] + d[i + 2] < 60) {
          black++;
          continue;
        }
        const key = ((d[i] >> 5) << 6) | ((d[i + 1] >> 5) << 3) | (d[i + 2] >> 5);
        bins.set(key, (bins.get(key) || 0) + 1);
      }
      const pixels = canvas.width * canvas.height;
      out.push({
        view: Number(figure.dataset.view),
        src: img.src,
        valid: Number(img.dataset.valid),
        caption: figure.querySelector('[data-testid="thumb-disparity-caption"]')?.textContent.trim() ?? '',
        hasPicture: !!figure.querySelector('.thumb-button img'),
        width: canvas.width,
        height: canvas.height,
        coloured: (pixels - black) / pixels,
        colours: bins.size,
        topShare: Math.max(black, ...bins.values()) / pixels,
      });
    }
    return out;
  });
}

runBrowserTest('console', async (t) => {
  const station = await startStation(harness);
  const { info } = station;
  t.log('station', info.station, 'at', info.url);
  try {
    const page = await consolePage(t.browser, info.url);
    const loadStart = Date.now();
    await page.goto(info.url, { waitUntil: 'load' });
    await page.waitForSelector(sel('login-token'), { visible: true });
    t.log(`console loaded in ${Date.now() - loadStart} ms`);
    await t.screenshot(page, '01-sign-in');

    // A wrong token: the station's refusal is shown.
    await page.$eval(sel('login-station'), (e, v) => { e.value = v; }, info.station);
    await page.type(sel('login-token'), 'not-a-token-0123456789');
    await page.click(sel('login-submit'));
    await page.waitForFunction((s) => {
      const e = document.querySelector(s);
      return e && e.textContent.trim().length > 0 && e.offsetParent !== null;
    }, { timeout: 15000 }, sel('login-error'));
    const refusal = await textOf(page, 'login-error');
    check(/refused|token/i.test(refusal), `login-error says "${refusal}"`);
    await page.$eval(sel('login-token'), (e) => { e.value = ''; });

    // The operator.
    await signIn(page, info, info.operator);
    check((await textOf(page, 'role')).includes('operator'), `role shows "${await textOf(page, 'role')}"`);
    await page.waitForFunction((s) => document.querySelector(s)?.dataset.state === 'idle',
                               { timeout: 15000 }, sel('station-state'));
    check(!(await page.$(sel('nav-calibrate'))), 'an operator sees no calibration page (admin only)');
    await page.click(sel('nav-scan'));
    await page.waitForSelector(sel('scan-start'), { visible: true });
    await page.$eval(sel('scan-object'), (e) => { e.value = ''; });
    await page.type(sel('scan-object'), 'box');
    await page.$eval(sel('scan-views'), (e) => { e.value = ''; });
    await page.type(sel('scan-views'), '4');
    await page.$eval(sel('scan-step'), (e) => { e.value = ''; });
    await page.type(sel('scan-step'), '90');
    await page.click(sel('scan-start'));
    await page.waitForSelector(`${sel('thumbs')} figure img`, { timeout: 60000 });
    // The views' disparities, as they are matched.
    await page.waitForFunction((s) => document.querySelectorAll(s).length >= 2, { timeout: 60000 },
                               `${sel('thumbs')} ${sel('thumb-disparity')}`);
    const shown = await disparityPictures(page);
    await t.screenshot(page, '02-scan-live');
    await t.screenshot(page, '02-scan-live-views', sel('thumbs'));
    for (const p of shown) {
      t.log(`view ${p.view}: ${p.caption}; ${p.width}x${p.height}, ${(100 * p.coloured).toFixed(1)} % coloured, ` +
            `${p.colours} colours, the commonest ${(100 * p.topShare).toFixed(1)} %`);
      check(p.hasPicture, `view ${p.view}: a disparity without the camera's picture`);
      check(p.width > 0 && p.width <= 320, `view ${p.view}: disparity picture ${p.width} px wide`);
      check(p.valid > 0.05 && p.valid <= 1, `view ${p.view}: valid fraction ${p.valid}`);
      check(p.caption === `disparity, ${Math.round(100 * p.valid)} % valid`, `view ${p.view}: caption "${p.caption}"`);
      check(Math.abs(p.coloured - p.valid) < 0.1,
            `view ${p.view}: ${(100 * p.coloured).toFixed(1)} % of the picture coloured, ${(100 * p.valid).toFixed(1)} % valid`);
      check(p.colours >= 4 && p.topShare < 0.9, `view ${p.view}: the disparity picture is (nearly) one colour`);
    }

    // The daemon dies mid-scan.
    check((await station.send('kill')) === 'ok', 'killing the daemon');
    await page.waitForSelector(sel('banner-gone'), { visible: true, timeout: 15000 });
    await t.screenshot(page, '03-station-gone');
    // The scan page left and opened again: its views' pictures and
    // disparities are still there (from the console's memory: the station
    // is gone).
    await page.click(sel('nav-sessions'));
    await page.waitForSelector(sel('sessions-refresh'), { visible: true });
    await page.click(sel('nav-scan'));
    await page.waitForSelector(`${sel('thumbs')} ${sel('thumb-disparity')}`, { timeout: 5000 });
    const again = await disparityPictures(page);
    for (const p of shown) {
      check(again.some((q) => q.view === p.view && q.src === p.src && q.hasPicture),
            `view ${p.view}: its disparity is gone after the scan page was opened again`);
    }
    check((await station.send('start')) === 'ok', 'starting the daemon again');
    await page.waitForSelector(sel('banner-gone'), { hidden: true, timeout: 30000 });

    // The interrupted session, resumed from the sessions page.
    await page.click(sel('nav-sessions'));
    const interrupted = `${sel('sessions-table')} [data-state="interrupted"]`;
    await waitUntil('the interrupted session', async () => {
      if (await page.$(interrupted)) return true;
      const refresh = await page.$(sel('sessions-refresh'));
      if (refresh) await refresh.click();
      return false;
    }, 30000);
    const session = await page.$eval(interrupted, (e) => e.dataset.session ||
                                     e.closest('[data-session]').dataset.session);
    await t.screenshot(page, '04-sessions-interrupted');
    // Until the page has seen the station without that scan, the button says
    // the scan runs; then it offers Resume.
    const resumeButton = `${sel('sessions-table')} [data-session="${session}"] ${sel('session-resume')}`;
    await page.waitForSelector(`${resumeButton}:not([disabled])`, { timeout: 20000 });
    await page.click(resumeButton);
    await page.waitForFunction((s) => /resume/i.test(document.querySelector(s)?.textContent || ''),
                               { timeout: 15000 }, sel('status-line'));
    const resumed = await page.$eval(sel('status-line'), (e) => [e.dataset.code, e.textContent.trim()]);
    t.log('resume:', resumed.join(' — '));
    check(resumed[0] === 'ok', `resume refused: ${resumed[1]}`);
    await waitUntil(`session ${session} done`, async () => {
      const r = await pageFetch(page, '/api/sessions', {});
      const s = (r.body && r.body.sessions || []).find((x) => x.id === session);
      return s && s.state === 'done';
    }, 180000);
    t.log(`session ${session} resumed to done`);
    // A finished scan offers another turn (the object laid in another pose:
    // the daemon's scan with add_to).
    await page.click(sel('sessions-refresh'));
    await page.waitForSelector(`${sel('sessions-table')} [data-session="${session}"] ${sel('session-add-turn')}`,
                               { timeout: 20000 });

    // Its model in the viewer.
    await page.goto(`${info.url}#/sessions/${session}`, { waitUntil: 'load' });
    await page.waitForFunction((s) => document.querySelector(s)?.dataset.state === 'ready',
                               { timeout: 60000 }, sel('viewer'));
    await new Promise((r) => setTimeout(r, 500));
    const before = await t.screenshot(page, '05-session-viewer', sel('viewer'));
    // The background is the viewer's most common colour.
    const d = before.data;
    const counts = new Map();
    for (let i = 0; i < d.length; i += 4) {
      const key = ((d[i] >> 3) << 10) | ((d[i + 1] >> 3) << 5) | (d[i + 2] >> 3);
      counts.set(key, (counts.get(key) || 0) + 1);
    }
    const mode = [...counts.entries()].sort((a, b) => b[1] - a[1])[0][0];
    const bg = [((mode >> 10) & 31) * 8 + 4, ((mode >> 5) & 31) * 8 + 4, (mode & 31) * 8 + 4];
    let differ = 0;
    for (let i = 0; i < d.length; i += 4) {
      if (Math.abs(d[i] - bg[0]) + Math.abs(d[i + 1] - bg[1]) + Math.abs(d[i + 2] - bg[2]) > 48) differ++;
    }
    const drawn = differ / (before.width * before.height);
    t.log(`viewer: ${(100 * drawn).toFixed(1)} % of its pixels differ from the background`);
    check(drawn > 0.02, `the viewer shows nothing (${(100 * drawn).toFixed(2)} % drawn)`);
    const box = await (await page.$(sel('viewer'))).boundingBox();
    await drag(page, box.x + box.width / 2, box.y + box.height / 2, 160, 40);
    await new Promise((r) => setTimeout(r, 500));
    const after = await t.screenshot(page, '06-session-viewer-turned', sel('viewer'));
    check(fractionChanged(before, after) > 0.01, 'dragging did not turn the model');
    await page.waitForFunction((s) => (document.querySelector(s)?.textContent || '').trim().length > 0,
                               { timeout: 20000 }, sel('measurements'))
      .catch(() => {});
    const measured = await textOf(page, 'measurements');
    check(measured.length > 0, 'no measurements shown');
    t.log('measurements:', measured.replace(/\s+/g, ' ').slice(0, 160));

    // The observer: no scan button; forged requests refused.
    const context = await t.browser.createBrowserContext();
    const observer = await consolePage(context, info.url);
    await observer.goto(info.url, { waitUntil: 'load' });
    await signIn(observer, info, info.observer);
    await observer.click(sel('nav-scan'));
    await new Promise((r) => setTimeout(r, 500));
    check(!(await observer.$(sel('scan-start'))), 'an observer sees a scan button');
    await t.screenshot(observer, '07-observer-scan-page');
    const json = { 'Content-Type': 'application/json' };
    const forged = await pageFetch(observer, '/api/command', {
      method: 'POST', headers: { ...json, 'X-Craftscan-Request': '1' },
      body: JSON.stringify({ verb: 'scan', args: { object: 'x', views: 4 } }),
    });
    check(forged.status === 200 && forged.body.code_name === 'forbidden',
          `a forged scan: ${JSON.stringify(forged)}`);
    const noHeader = await pageFetch(observer, '/api/command', {
      method: 'POST', headers: json, body: JSON.stringify({ verb: 'status' }),
    });
    check(noHeader.status === 403, `without X-Craftscan-Request: ${noHeader.status}`);

    // An admin moves the session to the trash (two clicks).
    const adminContext = await t.browser.createBrowserContext();
    const admin = await consolePage(adminContext, info.url);
    await admin.goto(`${info.url}#/sessions`, { waitUntil: 'load' });
    await signIn(admin, info, info.admin);
    await admin.click(sel('nav-sessions'));
    const deleteButton = `${sel('sessions-table')} [data-session="${session}"] ${sel('session-delete')}`;
    await admin.waitForSelector(deleteButton, { visible: true, timeout: 15000 });
    await admin.click(deleteButton);
    await admin.waitForSelector(`${deleteButton}[data-confirm]`, { timeout: 5000 });
    await t.screenshot(admin, '08-admin-delete-confirm');
    await admin.click(deleteButton);
    await admin.waitForFunction((s) => !document.querySelector(s), { timeout: 15000 },
                                `${sel('sessions-table')} [data-session="${session}"]`);
    check(!(await observer.$(sel('session-delete'))), 'an observer sees a delete button');

    check(page.refused.length === 0 && observer.refused.length === 0,
          `requests outside the console: ${[...page.refused, ...observer.refused].join(', ')}`);
    check(page.errors.length === 0, `page errors: ${page.errors.join(' | ')}`);
  } finally {
    await station.stop();
  }
}, { timeoutMs: 240000 });
