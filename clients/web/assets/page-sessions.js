// The Sessions page: every session with its state, resume for interrupted
// ones, and one opened below the table (3D view, measurements, downloads).

import { h, replace, show } from './dom.js';
import { fmtDate, stageLabel } from './format.js';
import { createSessionPanel } from './report.js';

const RESUMABLE = new Set(['interrupted', 'failed']);
const REFRESH_MS = 15000;

export function mountSessions(root, ctx, param) {
  const { jobs } = ctx;
  const operator = ctx.can('operator');
  const admin = ctx.can('admin');
  const cleanups = [];
  let sessions = [];
  let openId = '';
  let panel = null;
  let loading = false;

  const refreshBtn = h('button', { type: 'button', class: 'btn btn-secondary', testid: 'sessions-refresh' }, 'Refresh');
  const listStatus = h('p', { class: 'muted', role: 'status', 'aria-live': 'polite' });
  const tbody = h('tbody');
  const table = h('table', { class: 'table sessions-table', testid: 'sessions-table' },
    h('caption', { class: 'visually-hidden' }, 'Scanning sessions, newest first'),
    h('thead', null, h('tr', null,
      h('th', { scope: 'col' }, 'Session'),
      h('th', { scope: 'col' }, 'Object'),
      h('th', { scope: 'col' }, 'State'),
      h('th', { scope: 'col', class: 'num' }, 'Views'),
      h('th', { scope: 'col' }, 'Created'),
      h('th', { scope: 'col', class: 'col-updated' }, 'Updated'),
      h('th', { scope: 'col' }, h('span', { class: 'visually-hidden' }, 'Actions')))),
    tbody);
  const jobLine = h('p', { class: 'job-line', testid: 'sessions-job', role: 'status', hidden: true });
  const detail = h('div', { class: 'session-detail', testid: 'session-detail' });

  root.append(
    h('div', { class: 'page-head' },
      h('h1', { class: 'page-title', tabindex: '-1' }, 'Sessions'),
      refreshBtn),
    jobLine,
    h('section', { class: 'card' }, h('div', { class: 'table-scroll' }, table), listStatus),
    detail);

  async function resume(id, button) {
    button.disabled = true;
    const reply = await ctx.command('resume', { session: id });
    if (reply && reply.result && typeof reply.result === 'object' && reply.result.id) {
      jobs.trackJob(reply.result.verb || 'resume', { session: id, ...reply.result });
    }
    if (!reply || reply.code !== 0) button.disabled = false;
    refresh();
  }

  // Admins: the session moved to the station's trash (never unlinked).
  // Two clicks: the first asks, the second (within 5 s) does it.
  function deleteButton(s) {
    if (!admin) return null;
    const b = h('button', {
      type: 'button', class: 'btn btn-small btn-danger', testid: 'session-delete',
      'aria-label': `Move session ${s.id} to the trash`,
    }, 'Delete');
    let armed = null;
    b.addEventListener('click', async () => {
      if (!armed) {
        b.textContent = 'Move to trash?';
        b.dataset.confirm = '1';
        armed = setTimeout(() => {
          armed = null;
          b.textContent = 'Delete';
          delete b.dataset.confirm;
        }, 5000);
        return;
      }
      clearTimeout(armed);
      armed = null;
      b.disabled = true;
      const reply = await ctx.command('delete', { session: s.id });
      if (!reply || reply.code !== 0) {
        b.disabled = false;
        b.textContent = 'Delete';
        delete b.dataset.confirm;
      }
      if (openId === s.id && reply && reply.code === 0) location.hash = '#/sessions';
      refresh();
    });
    return b;
  }

  function resumeButton(s) {
    if (!operator || !RESUMABLE.has(s.state)) return null;
    const running = jobs.tracks.scan.running && jobs.tracks.scan.session === s.id;
    const b = h('button', {
      type: 'button', class: 'btn btn-small btn-primary', testid: 'session-resume',
      'aria-label': `Resume session ${s.id}`, disabled: running,
    }, running ? 'Resuming…' : 'Resume');
    b.addEventListener('click', () => resume(s.id, b));
    return b;
  }

  // Operators: another turn of a finished scan, the object laid in another
  // pose (on its side), joined onto its first turn so the model has the
  // base (the daemon's scan with add_to). Not once a turn is joined.
  function addTurnButton(s) {
    const turns = Array.isArray(s.turns) ? s.turns : [];
    if (!operator || s.job !== 'scan' || s.state !== 'done' ||
        turns.some((t) => t.state === 'joined')) return null;
    const b = h('button', {
      type: 'button', class: 'btn btn-small btn-secondary', testid: 'session-add-turn',
      title: 'Lay the object in another pose (on its side) on the platter first',
      'aria-label': `Add a turn to session ${s.id}`, disabled: jobs.tracks.scan.running,
    }, 'Add turn');
    b.addEventListener('click', async () => {
      b.disabled = true;
      const reply = await ctx.command('scan', { add_to: s.id });
      if (reply && reply.result && typeof reply.result === 'object' && reply.result.id) {
        jobs.trackJob('scan', { session: s.id, ...reply.result });
      }
      if (!reply || reply.code !== 0) b.disabled = false;
      refresh();
    });
    return b;
  }

  // "turn 1: done · turn 2: joined (fit 72.6 %, …)" under the state.
  function turnsLine(s) {
    if (!Array.isArray(s.turns) || s.turns.length < 2) return null;
    return h('div', { class: 'row-turns muted', testid: 'session-turns' },
      s.turns.map((t) => `turn ${t.turn}: ${t.state}${t.join && t.state !== 'done' ? ` — ${t.join}` : ''}`)
        .join(' · '));
  }

  function row(s) {
    const open = h('a', {
      class: 'btn btn-small btn-secondary', testid: 'session-open',
      href: `#/sessions/${encodeURIComponent(s.id)}`, 'aria-label': `Open session ${s.id}`,
    }, 'Open');
    const views = typeof s.views_captured === 'number' ? String(s.views_captured) : '—';
    const problem = s.problem ? h('div', { class: 'row-problem' }, s.problem) : null;
    return h('tr', {
      dataset: { session: s.id, state: s.state ?? '' },
      class: s.id === openId ? 'selected' : null,
    },
    h('td', { class: 'mono' }, s.id),
    h('td', null, s.object || '—', s.job && s.job !== 'scan' ? h('span', { class: 'muted' }, ` (${s.job})`) : null),
    h('td', null, h('span', { class: `badge state-${s.state}` }, s.state || 'unknown'), problem, turnsLine(s)),
    h('td', { class: 'num' }, views),
    h('td', { title: s.created ?? '' }, fmtDate(s.created)),
    h('td', { class: 'col-updated', title: s.updated ?? '' }, fmtDate(s.updated)),
    h('td', { class: 'actions' }, open, ' ', resumeButton(s), ' ', addTurnButton(s), ' ', deleteButton(s)));
  }

  function renderTable() {
    replace(tbody, sessions.map(row));
    if (!sessions.length && !loading) {
      tbody.append(h('tr', null, h('td', { colspan: '7', class: 'empty' },
        'No sessions yet. ', operator ? h('a', { href: '#/scan' }, 'Start a scan.') : null)));
    }
  }

  async function refresh() {
    if (loading) return;
    loading = true;
    listStatus.textContent = sessions.length ? 'Updating…' : 'Loading the sessions…';
    try {
      const data = await ctx.api.sessions();
      sessions = (Array.isArray(data?.sessions) ? data.sessions : [])
        .slice()
        .sort((a, b) => String(b.created ?? '').localeCompare(String(a.created ?? '')));
      listStatus.textContent = `${sessions.length} session${sessions.length === 1 ? '' : 's'}.`;
    } catch (e) {
      listStatus.textContent = `Could not load the sessions: ${e.message}`;
    } finally {
      loading = false;
    }
    renderTable();
  }

  function openSession(id) {
    if (id === openId) return;
    panel?.dispose();
    panel = null;
    openId = id;
    for (const tr of tbody.querySelectorAll('tr[data-session]')) tr.classList.toggle('selected', tr.dataset.session === id);
    if (!id) {
      replace(detail);
      return;
    }
    panel = createSessionPanel(id, {
      extra: (manifest) => {
        const s = sessions.find((x) => x.id === id) ?? { id, state: manifest?.state };
        return resumeButton(s);
      },
    });
    replace(detail, panel.el);
    panel.el.scrollIntoView({ behavior: 'smooth', block: 'start' });
  }

  function updateJobLine() {
    const t = jobs.tracks.scan;
    if (t.running) {
      const latest = t.latest;
      jobLine.textContent = `${t.verb === 'resume' ? 'Resuming' : 'Scanning'}${t.session ? ` ${t.session}` : ''}: ` +
        `${latest ? stageLabel(latest.name) : 'starting'}${latest && latest.total ? ` ${latest.current} of ${latest.total}` : ''}` +
        `${latest?.message ? ` — ${latest.message}` : ''}`;
      jobLine.append(' ', h('a', { href: '#/scan' }, 'Follow it on the Scan page'));
      show(jobLine, true);
    } else show(jobLine, false);
  }

  refreshBtn.addEventListener('click', refresh);
  const timer = setInterval(() => {
    if (!document.hidden) refresh();
  }, REFRESH_MS);
  cleanups.push(
    () => clearInterval(timer),
    ctx.on('job', (t) => {
      if (t?.kind === 'scan') updateJobLine();
    }),
    ctx.on('job-final', () => {
      refresh();
      if (openId) {
        const id = openId;
        openId = '';
        openSession(id); // its outputs may have changed
      }
    }),
    ctx.on('live', () => {
      if (ctx.store.live === 'up') refresh();
    }),
  );

  renderTable();
  refresh();
  updateJobLine();
  if (param) openSession(param);

  return {
    update(newParam) {
      openSession(newParam || '');
    },
    unmount() {
      for (const off of cleanups) off();
      panel?.dispose();
    },
  };
}
