// What the console knows of the station's jobs, fed by command replies,
// status and the WebSocket's progress / capture / disparity / cloud /
// preview messages.
//
// One track per kind of job, each the latest job of that kind:
//   scan       scan, resume, capture   (stages, thumbnails and disparity
//              pictures of the views, the session)
//   calibrate  calibrate, calibrate-turntable   (stages, guidance from the
//              preview overlays, result)
//   device     turntable, camera
// A job's end is its progress message whose stage is "done", "failed" or
// "cancelled". A track the station stops reporting (the daemon restarted) is
// ended "interrupted" once a status shows another job or none.
//
// The live preview is a job on the daemon too (verb "preview"), but not one
// a person waits for: it has no track, never makes the station "busy" for
// the console (stationBusy) and gives way to any other job on the daemon.
// Its jobs are only remembered (isPreviewJob) so that their progress is not
// taken for a scan's; the frames themselves are live-preview.js's.

import { api } from './api.js';
import { emit } from './store.js';

export const FINAL_STAGES = new Set(['done', 'failed', 'cancelled']);

const KIND_OF_VERB = {
  scan: 'scan',
  resume: 'scan',
  capture: 'scan',
  calibrate: 'calibrate',
  'calibrate-turntable': 'calibrate',
  turntable: 'device',
  camera: 'device',
  preview: 'preview', // no track: see above
};

export function kindOfVerb(verb) {
  const v = String(verb ?? '');
  return KIND_OF_VERB[v] ?? (v.startsWith('calibrat') ? 'calibrate' : 'scan');
}

function newTrack(kind) {
  return {
    kind,
    id: '', // job id ("job-3")
    verb: '',
    session: '', // the session the job works on, once known
    running: false,
    startedAt: 0,
    endedAt: 0,
    stages: [], // [{name, current, total, message}] in the order first seen
    latest: null, // the last progress: {name, current, total, message}
    final: null, // {state: "done"|"failed"|"cancelled"|"interrupted", message}
    thumbs: new Map(), // view index → {index, angle, left, right}
    disparities: new Map(), // view index → {index, image, valid, width, height, scaleMin, scaleMax}
    viewPoints: new Map(), // view index → points of its cloud
    fusedPoints: 0,
    guide: null, // the guided calibration's latest overlay (calib-guide.js), or null
    guideFrame: null, // the preview message that carried it (the pictures)
    result: null, // the job's result from the daemon, when fetched
    resultSession: '', // the session to show when the job is over
    resolving: false,
    resolveError: '',
  };
}

export const tracks = {
  scan: newTrack('scan'),
  calibrate: newTrack('calibrate'),
  device: newTrack('device'),
};
const verbOfJob = new Map(); // job id → verb
const previewJobs = new Set(); // ids of the daemon's preview jobs
let lastStatus = null;
let expected = null; // {verb, at}: a job command sent whose reply has not come yet

// Called before sending a command that starts a job, so that progress
// arriving before its reply is filed under the right kind.
export function expectJob(verb) {
  expected = verb in KIND_OF_VERB ? { verb, at: Date.now() } : null;
}

export function resetJobs() {
  for (const kind of Object.keys(tracks)) tracks[kind] = newTrack(kind);
  verbOfJob.clear();
  previewJobs.clear();
  lastStatus = null;
  expected = null;
}

// Whether `jobId` is (known to be) one of the daemon's live-preview jobs.
export function isPreviewJob(jobId) {
  return !!jobId && (previewJobs.has(jobId) || verbOfJob.get(jobId) === 'preview');
}

// Whether the station is busy with a job that keeps others from starting
// (the live preview does not: the daemon stops it for any job).
export function stationBusy(s) {
  return !!s && s.state === 'busy' && s.job_verb !== 'preview';
}

// Notes `jobId` as a preview job unless something says it is another
// (a calibrate job's frames may come without an overlay).
function notePreviewJob(jobId) {
  if (!jobId || previewJobs.has(jobId) || findTrack(jobId)) return;
  const verb = verbOfJob.get(jobId) ?? (lastStatus?.job_id === jobId ? lastStatus.job_verb : '');
  if (!verb || verb === 'preview') previewJobs.add(jobId);
}

function findTrack(jobId) {
  return Object.values(tracks).find((t) => t.id && t.id === jobId) ?? null;
}

function kindOfJob(jobId, stage) {
  let verb = verbOfJob.get(jobId);
  if (!verb && lastStatus && lastStatus.job_id === jobId && lastStatus.job_verb) verb = lastStatus.job_verb;
  if (verb) return kindOfVerb(verb);
  const known = findTrack(jobId);
  if (known) return known.kind;
  if (expected && Date.now() - expected.at < 15000) return kindOfVerb(expected.verb);
  return String(stage ?? '').startsWith('calibrat') ? 'calibrate' : 'scan';
}

function startTrack(kind, id, verb) {
  const t = newTrack(kind);
  t.id = id || '';
  t.verb = verb || '';
  t.running = true;
  t.startedAt = Date.now();
  tracks[kind] = t;
  return t;
}

// A job the console started or was told of: `job` is the daemon's JobJson
// ({id, verb, state, session, stage, progress, message, result}).
export function trackJob(verb, job) {
  expected = null;
  const kind = kindOfVerb(job?.verb || verb);
  const id = job?.id ?? '';
  if (id) verbOfJob.set(id, job?.verb || verb);
  if (kind === 'preview') {
    if (id) previewJobs.add(id);
    return null;
  }
  let t = id ? findTrack(id) : null;
  if (t && t.kind !== kind) {
    // Progress arrived before the reply and was filed under a guessed kind.
    tracks[t.kind] = newTrack(t.kind);
    t.kind = kind;
    tracks[kind] = t;
  }
  if (!t) t = startTrack(kind, id, job?.verb || verb);
  t.verb = job?.verb || verb;
  if (job?.session) t.session = job.session;
  emit('job', t);
  return t;
}

export function onProgress(m) {
  if (!m || !m.job_id) return;
  const stage = String(m.stage ?? '');
  if (stage === 'preview') previewJobs.add(m.job_id);
  const kind = isPreviewJob(m.job_id) ? 'preview' : kindOfJob(m.job_id, stage);
  if (kind === 'preview') {
    previewJobs.add(m.job_id);
    if (FINAL_STAGES.has(stage)) emit('preview-job', { id: m.job_id, state: stage, message: String(m.message ?? '') });
    return;
  }
  let t = tracks[kind];
  if (t.id !== m.job_id) {
    const elsewhere = findTrack(m.job_id);
    if (elsewhere) {
      tracks[elsewhere.kind] = newTrack(elsewhere.kind);
      elsewhere.kind = kind;
      tracks[kind] = t = elsewhere;
    } else {
      t = startTrack(kind, m.job_id, verbOfJob.get(m.job_id) ?? '');
    }
  }
  if (FINAL_STAGES.has(stage)) {
    finishJob(t, stage, String(m.message ?? ''));
    return;
  }
  if (!t.running) return; // a late message of a job already over
  const row = {
    name: stage,
    current: Number(m.current) || 0,
    total: Number(m.total) || 0,
    message: String(m.message ?? ''),
  };
  const i = t.stages.findIndex((s) => s.name === stage);
  if (i >= 0) t.stages[i] = row;
  else t.stages.push(row);
  t.latest = row;
  emit('job', t);
}

// A preview message whose overlay is the guided calibration's feedback
// ({kind: "calibration", ...}): filed on the calibrate track of its job;
// emits 'guide' (the track). Other preview messages are not jobs' business.
export function onPreview(m) {
  const overlay = m?.overlay;
  if (!overlay || typeof overlay !== 'object' || overlay.kind !== 'calibration') {
    if (!m?.overlay) notePreviewJob(m?.job_id);
    return;
  }
  let t = tracks.calibrate;
  if (m.job_id && t.id !== m.job_id) {
    const elsewhere = findTrack(m.job_id);
    if (elsewhere) {
      // Progress came first and was filed under a guessed kind.
      tracks[elsewhere.kind] = newTrack(elsewhere.kind);
      elsewhere.kind = 'calibrate';
      tracks.calibrate = t = elsewhere;
    } else if (t.running && !t.id) {
      t.id = m.job_id;
    } else {
      t = startTrack('calibrate', m.job_id, verbOfJob.get(m.job_id) || 'calibrate');
      emit('job', t);
    }
  }
  if (!t.running) return; // a late frame of a job already over
  t.guide = overlay;
  t.guideFrame = m;
  emit('guide', t);
}

export function finishJob(t, state, message) {
  if (t.final) {
    // Ended already (a status said so first): keep the daemon's own words.
    if (message && !t.final.message && t.final.state === state) {
      t.final.message = message;
      emit('job', t);
    }
    return;
  }
  t.running = false;
  t.final = { state, message };
  t.endedAt = Date.now();
  emit('job', t);
  emit('job-final', t);
  if (t.kind === 'scan') resolveSession(t);
  if (t.kind === 'calibrate' && state === 'done') fetchResult(t);
}

// The daemon's JobJson of job `id` from the status verb, or null.
async function jobInfo(id) {
  try {
    const reply = await api.command('status');
    const job = reply && reply.code === 0 && reply.result ? reply.result.job : null;
    return job && job.id === id ? job : null;
  } catch {
    return null;
  }
}

// The session of a scan job that ended: the reply's, the capture messages',
// the daemon's job record, or — for a finished one — the newest done session.
async function resolveSession(t) {
  t.resolving = true;
  emit('job', t);
  let id = t.session;
  if (!id && t.id) {
    const job = await jobInfo(t.id);
    if (job) {
      id = job.session || job.result?.session || '';
      if (job.result) t.result = job.result;
    }
  }
  if (!id && t.final.state === 'done') {
    try {
      const list = (await api.sessions())?.sessions ?? [];
      const newest = list
        .filter((s) => s.state === 'done')
        .sort((a, b) => String(b.updated || b.created).localeCompare(String(a.updated || a.created)))[0];
      id = newest?.id ?? '';
    } catch {
      /* shown below */
    }
  }
  t.resolving = false;
  t.session = t.session || id;
  t.resultSession = id;
  t.resolveError = id ? '' : 'The console could not tell which session this job made; open it from the Sessions page.';
  emit('job', t);
}

async function fetchResult(t) {
  const job = t.id ? await jobInfo(t.id) : null;
  if (job && job.result && typeof job.result === 'object') {
    t.result = job.result;
    emit('job', t);
  }
}

export function onStatus(s) {
  if (!s) return;
  lastStatus = s;
  if (s.job_id && s.job_verb) verbOfJob.set(s.job_id, s.job_verb);
  if (s.online === false) return; // stale: decide nothing until it is heard again
  if (s.job_id && s.job_verb === 'preview') previewJobs.add(s.job_id);
  const active = s.state === 'busy' && s.job_id && s.job_verb !== 'preview' &&
    (s.job_state === 'running' || s.job_state === 'queued' || !s.job_state);
  if (active) {
    const kind = kindOfVerb(s.job_verb);
    if (tracks[kind].id !== s.job_id && !findTrack(s.job_id)) {
      emit('job', startTrack(kind, s.job_id, s.job_verb));
    }
  }
  for (const t of Object.values(tracks)) {
    if (!t.running || !t.id || Date.now() - t.startedAt < 5000) continue;
    if (s.job_id === t.id && FINAL_STAGES.has(s.job_state)) {
      finishJob(t, s.job_state, s.job_state === 'failed' ? String(s.last_error ?? '') : '');
    } else if (s.job_id !== t.id) {
      finishJob(t, 'interrupted', t.kind === 'scan'
        ? 'The station stopped this job without finishing it (it may have restarted). ' +
          'The session is kept: resume it from the Sessions page.'
        : 'The station stopped this job without finishing it (it may have restarted).');
    }
  }
}

// The scan track, its views' pictures cleared when `session` is another
// session than the one they show.
function scanTrackOf(session) {
  const t = tracks.scan;
  if (session && t.session !== session) {
    if (t.session) {
      t.thumbs.clear();
      t.disparities.clear();
    }
    t.session = session;
  }
  return t;
}

export function onCapture(m) {
  if (!m || typeof m.view_index !== 'number') return;
  const t = scanTrackOf(m.session);
  t.thumbs.set(m.view_index, {
    index: m.view_index,
    angle: typeof m.angle_deg === 'number' ? m.angle_deg : null,
    left: typeof m.left === 'string' ? m.left : '',
    right: typeof m.right === 'string' ? m.right : '',
  });
  emit('thumb', m.view_index);
}

// A view's disparity picture (message "disparity"): kept beside the view's
// thumbnail; emits 'thumb' (the view index) like a capture.
export function onDisparity(m) {
  if (!m || typeof m.view_index !== 'number' || typeof m.image !== 'string' || !m.image) return;
  const t = scanTrackOf(m.session);
  const num = (v) => (typeof v === 'number' && Number.isFinite(v) ? v : null);
  t.disparities.set(m.view_index, {
    index: m.view_index,
    image: m.image,
    valid: Math.min(1, Math.max(0, num(m.valid_fraction) ?? 0)),
    width: num(m.width),
    height: num(m.height),
    scaleMin: num(m.scale_min),
    scaleMax: num(m.scale_max),
  });
  emit('thumb', m.view_index);
}

export function onCloud(m) {
  if (!m) return;
  const t = tracks.scan;
  if (m.session && t.session && m.session !== t.session) return;
  if (m.kind === 'fused') t.fusedPoints = Number(m.points) || 0;
  else if (typeof m.view_index === 'number') t.viewPoints.set(m.view_index, Number(m.points) || 0);
  emit('cloud', m);
}
