// Interval labels of a city's horizon, on the local wall clock (labels are "YYYY-MM-DDTHH:MM", the local
// start of an interval, as the API writes them). Wall-clock times are held as UTC milliseconds so the
// browser's own time zone never enters.

const pad = (n) => String(n).padStart(2, "0");

function parseLabel(label) {
  const m = /^(\d{4})-(\d{2})-(\d{2})T(\d{2}):(\d{2})$/.exec(label);
  if (!m) throw new Error(`not an interval label: ${label}`);
  return Date.UTC(+m[1], +m[2] - 1, +m[3], +m[4], +m[5]);
}

function formatLabel(ms) {
  const d = new Date(ms);
  return `${d.getUTCFullYear()}-${pad(d.getUTCMonth() + 1)}-${pad(d.getUTCDate())}T${pad(d.getUTCHours())}:${pad(d.getUTCMinutes())}`;
}

/** Intervals per day (`interval_s` divides a day). */
export const perDay = (horizon) => 86400 / horizon.interval_s;

/**
 * Every interval of the day that interval `key` (labelled `label`) belongs to: `{label, position, inHorizon}`
 * for positions 0..perDay-1, position 0 starting at the horizon's start.
 */
export function dayIntervals(horizon, label, key) {
  const n = perDay(horizon);
  const position = ((key % n) + n) % n;
  const first = parseLabel(label) - position * horizon.interval_s * 1000;
  return Array.from({ length: n }, (_, i) => ({
    label: formatLabel(first + i * horizon.interval_s * 1000),
    position: i,
    inHorizon: i < horizon.n_intervals,
  }));
}

/** The day's intervals when nothing has been committed yet: the horizon's start on `date` (YYYY-MM-DD). */
export function dayIntervalsOn(horizon, date) {
  const [h, m] = horizon.start.split(":");
  return dayIntervals(horizon, `${date}T${h}:${m}`, 0);
}

/** "08:00–09:00" for an interval label. */
export function spanText(horizon, label) {
  const start = parseLabel(label);
  const end = formatLabel(start + horizon.interval_s * 1000);
  return `${label.slice(11)}–${end.slice(11)}`;
}
