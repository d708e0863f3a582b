// The progress of a job: the latest stage (name, bar, message) and one row
// per stage seen, as the WebSocket's progress messages report them.

import { h, replace, show } from './dom.js';
import { fmtTime, stageLabel } from './format.js';

const STAGE_ORDER = ['starting', 'capture', 'match', 'register', 'join', 'write', 'report', 'calibrate'];

// ids: {stage, bar, message} data-testid values for the headline parts.
export function createProgress({ stage: stageId, bar: barId, message: messageId, title = 'Progress' }) {
  const stageEl = h('span', { class: 'progress-stage', testid: stageId });
  const countEl = h('span', { class: 'progress-count' });
  const bar = h('progress', { class: 'progress-main', testid: barId, max: '1', value: '0', 'aria-label': title });
  const messageEl = h('p', { class: 'progress-message', testid: messageId, role: 'status', 'aria-live': 'polite' });
  const list = h('ol', { class: 'stage-list', 'aria-label': 'Stages' });
  const finalEl = h('p', { class: 'progress-final', role: 'alert', hidden: true });
  const el = h('div', { class: 'progress-box' },
    h('div', { class: 'progress-head' }, stageEl, countEl), bar, messageEl, list, finalEl);

  // t: a job track (jobs.js) or null.
  function update(t) {
    const idle = !t || (!t.running && !t.final);
    el.dataset.state = idle ? 'idle' : t.running ? 'running' : t.final.state;
    if (idle) {
      stageEl.textContent = 'No job running';
      stageEl.dataset.stage = '';
      countEl.textContent = '';
      bar.value = 0;
      bar.max = 1;
      messageEl.textContent = '';
      replace(list);
      show(finalEl, false);
      return;
    }
    const latest = t.latest;
    if (t.final) {
      stageEl.textContent = stageLabel(t.final.state);
      stageEl.dataset.stage = t.final.state;
      countEl.textContent = t.endedAt ? `at ${fmtTime(t.endedAt)}` : '';
      bar.max = 1;
      bar.value = t.final.state === 'done' ? 1 : latest && latest.total > 0 ? latest.current / latest.total : 0;
    } else if (latest) {
      stageEl.textContent = stageLabel(latest.name);
      stageEl.dataset.stage = latest.name;
      countEl.textContent = latest.total > 0 ? `${latest.current} of ${latest.total}` : '';
      if (latest.total > 0) {
        bar.max = latest.total;
        bar.value = Math.min(latest.current, latest.total);
      } else {
        bar.removeAttribute('value'); // indeterminate
      }
    } else {
      stageEl.textContent = 'Starting';
      stageEl.dataset.stage = 'starting';
      countEl.textContent = '';
      bar.removeAttribute('value');
    }
    messageEl.textContent = t.final ? '' : latest?.message ?? '';

    const rows = [...t.stages].sort((a, b) => {
      const ia = STAGE_ORDER.indexOf(a.name);
      const ib = STAGE_ORDER.indexOf(b.name);
      return (ia < 0 ? 99 : ia) - (ib < 0 ? 99 : ib);
    }).filter((s) => s.name !== 'starting' || t.stages.length === 1);
    const lastIndex = rows.length - 1;
    replace(list, rows.map((s, i) => {
      const complete = t.final?.state === 'done' || (s.total > 0 && s.current >= s.total) || (i < lastIndex && !t.final && s.total === 0);
      const current = !t.final && latest && s.name === latest.name;
      const p = h('progress', { max: String(s.total > 0 ? s.total : 1), 'aria-label': stageLabel(s.name) });
      if (s.total > 0) p.value = Math.min(s.current, s.total);
      else if (complete) p.value = 1;
      else if (!t.running) p.value = 0;
      return h('li', {
        class: `stage-row${complete ? ' complete' : ''}${current ? ' current' : ''}`,
        dataset: { stage: s.name },
      },
      h('span', { class: 'stage-name' }, complete ? '✓ ' : '', stageLabel(s.name)),
      p,
      h('span', { class: 'stage-count' }, s.total > 0 ? `${s.current}/${s.total}` : ''),
      h('span', { class: 'stage-message' }, s.message));
    }));

    if (t.final) {
      finalEl.textContent = t.final.message || stageLabel(t.final.state);
      finalEl.className = `progress-final final-${t.final.state}`;
      show(finalEl, true);
    } else show(finalEl, false);
  }

  update(null);
  return { el, update };
}
