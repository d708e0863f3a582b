// Formatting for people: numbers, sizes, dates, field names from the
// station's JSON ("median_to_mesh_mm" → "Median to mesh", unit "mm").

const UNITS = [
  ['_mm', 'mm'],
  ['_px', 'px'],
  ['_deg', '°'],
  ['_pct', '%'],
  ['_ms', 'ms'],
  ['_us', 'µs'],
  ['_db', 'dB'],
  ['_s', 's'],
];

const WORDS = {
  rms: 'RMS',
  id: 'ID',
  obj: 'OBJ',
  ply: 'PLY',
  p95: '95th percentile',
  x: 'X',
  y: 'Y',
  z: 'Z',
};

// The unit a key's suffix names, and the key without it.
export function splitUnit(key) {
  for (const [suffix, unit] of UNITS) {
    if (key.endsWith(suffix) && key.length > suffix.length) {
      return { base: key.slice(0, -suffix.length), unit };
    }
  }
  return { base: key, unit: '' };
}

export function humanize(key) {
  const { base } = splitUnit(String(key));
  const words = base.split(/[_\-\s.]+/).filter(Boolean).map((w) => WORDS[w.toLowerCase()] ?? w);
  if (words.length === 0) return String(key);
  const first = words[0];
  words[0] = first === first.toUpperCase() ? first : first[0].toUpperCase() + first.slice(1);
  return words.join(' ');
}

const nf = new Map();
function formatter(digits) {
  if (!nf.has(digits)) {
    nf.set(digits, new Intl.NumberFormat(undefined, {
      maximumFractionDigits: digits,
      minimumFractionDigits: 0,
    }));
  }
  return nf.get(digits);
}

// A number with a sensible precision: integers as they are (grouped), others
// with 1–3 decimals depending on size.
export function fmtNumber(n, digits) {
  if (typeof n !== 'number' || !Number.isFinite(n)) return n === null || n === undefined ? '—' : String(n);
  if (digits === undefined) {
    if (Number.isInteger(n)) digits = 0;
    else if (Math.abs(n) >= 100) digits = 1;
    else if (Math.abs(n) >= 1) digits = 2;
    else digits = 3;
  }
  return formatter(digits).format(n);
}

// A value for a key: "12.3 mm", "yes", "1 234", "a, b, c".
export function fmtValue(key, value) {
  const { unit } = splitUnit(String(key));
  if (typeof value === 'boolean') return value ? 'yes' : 'no';
  if (value === null || value === undefined || value === '') return '—';
  if (Array.isArray(value)) {
    const list = value.map((v) => fmtValue('', v)).join(', ');
    if (!unit) return list;
    return unit === '°' || unit === '%' ? `${list} (${unit})` : `${list} ${unit}`;
  }
  if (typeof value === 'number') {
    if (unit === 'ms' && Math.abs(value) >= 1000) return `${fmtNumber(value / 1000, 1)} s`;
    const text = fmtNumber(value);
    if (!unit) return text;
    return unit === '°' || unit === '%' ? `${text}${unit}` : `${text} ${unit}`;
  }
  return String(value);
}

export function fmtBytes(n) {
  if (typeof n !== 'number' || !Number.isFinite(n)) return '';
  if (n < 1024) return `${n} B`;
  const units = ['KB', 'MB', 'GB', 'TB'];
  let v = n / 1024;
  let i = 0;
  while (v >= 1024 && i < units.length - 1) {
    v /= 1024;
    i++;
  }
  return `${fmtNumber(v, v >= 100 ? 0 : 1)} ${units[i]}`;
}

// "2024-05-01T09:30:00.000Z" → local "1 May 2024, 11:30" (the input when unparsable).
export function fmtDate(iso) {
  if (!iso) return '—';
  const d = new Date(iso);
  if (Number.isNaN(d.getTime())) return String(iso);
  return d.toLocaleString(undefined, {
    year: 'numeric',
    month: 'short',
    day: 'numeric',
    hour: '2-digit',
    minute: '2-digit',
  });
}

export function fmtTime(ms) {
  const d = new Date(ms);
  if (Number.isNaN(d.getTime())) return '';
  return d.toLocaleTimeString(undefined, { hour: '2-digit', minute: '2-digit', second: '2-digit' });
}

// Words for the station's and jobs' stage names.
const STAGES = {
  starting: 'Starting',
  capture: 'Capturing views',
  match: 'Matching the camera pairs',
  register: 'Aligning the views',
  join: 'Joining the turns',
  write: 'Building the model',
  report: 'Writing the report',
  calibrate: 'Computing the calibration',
  done: 'Finished',
  failed: 'Failed',
  cancelled: 'Cancelled',
  interrupted: 'Interrupted',
};
export function stageLabel(stage) {
  if (!stage) return '';
  return STAGES[stage] ?? humanize(stage);
}
