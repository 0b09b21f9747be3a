// The operator dashboard: asks for a read token, then for one city shows the road network, Lambda per grid
// cell for an interval chosen on a slider over the day (with the coverage rate and Gamma), the POI tasks by
// status with the latest epoch's routes, and the fleet-size recommendation with its history, polling the API.

import "leaflet/dist/leaflet.css";
import "./style.css";

import { ApiError, apiClient, orNoData } from "./api.js";
import { historyChart, kpiChart, sweepChart } from "./charts.js";
import { dayIntervals, dayIntervalsOn, spanText } from "./horizon.js";
import { HEAT, ROUTE_COLOURS, TASK_COLOURS, createMap, nodePositions } from "./map.js";

const params = new URLSearchParams(location.search);
const POLL_S = Math.max(2, Number(params.get("poll")) || 10);
const TOKEN_KEY = "sensedispatch.token";

const $ = (id) => document.getElementById(id);
const text = (id, value) => {
  $(id).textContent = value;
};
const pct = (x) => `${(100 * x).toFixed(1)} %`;
const num = (x, digits = 4) => (x === null || x === undefined ? "–" : Number(x).toFixed(digits));

const state = {
  api: null,
  cities: new Map(), // name -> CityOut
  city: null,
  graph: null, // the network of `city` and its node positions
  nodes: null,
  epochId: null,
  epoch: null,
  intervals: [], // the slider's day
  follow: true, // the slider follows the latest epoch's interval
  timer: null,
  busy: false,
  again: false,
};

const map = createMap($("map"));
const kpi = kpiChart($("kpi-chart"));
const history = historyChart($("history-chart"));
const sweep = sweepChart($("sweep-chart"));

// ----------------------------------------------------------------------------------------------- status

function showError(err) {
  const box = $("error");
  if (!err) {
    box.hidden = true;
    box.textContent = "";
    return;
  }
  box.hidden = false;
  box.textContent = err instanceof ApiError ? `${err.detail} (${err.status} ${err.kind})` : String(err.message ?? err);
}

function showUpdated() {
  const now = new Date();
  text("updated", `updated at ${now.toLocaleTimeString([], { hour12: false })} · polling every ${POLL_S} s`);
  $("updated").dateTime = now.toISOString();
}

// ------------------------------------------------------------------------------------------------ login

async function connect(token) {
  const api = apiClient(token);
  const { cities } = await api.cities();
  state.api = api;
  state.cities = new Map(cities.map((c) => [c.name, c]));
  sessionStorage.setItem(TOKEN_KEY, token);
  const select = $("city");
  select.replaceChildren(...cities.map((c) => new Option(c.name, c.name)));
  const wanted = params.get("city");
  select.value = state.cities.has(wanted) ? wanted : cities[0]?.name;
  $("login").hidden = true;
  $("session").hidden = false;
  document.body.classList.add("connected");
  await openCity(select.value);
}

function disconnect(err) {
  clearInterval(state.timer);
  state.api = null;
  sessionStorage.removeItem(TOKEN_KEY);
  $("login").hidden = false;
  $("session").hidden = true;
  document.body.classList.remove("connected");
  showError(err ?? null);
}

$("login").addEventListener("submit", async (event) => {
  event.preventDefault();
  const token = $("token").value.trim();
  if (!token) return;
  $("connect").disabled = true;
  try {
    showError(null);
    await connect(token);
  } catch (err) {
    disconnect(err);
  } finally {
    $("connect").disabled = false;
  }
});

$("logout").addEventListener("click", () => disconnect());
$("city").addEventListener("change", (e) => openCity(e.target.value));

// ----------------------------------------------------------------------------------------------- a city

async function openCity(name) {
  clearInterval(state.timer);
  Object.assign(state, { city: name, epochId: null, epoch: null, follow: true, intervals: [] });
  $("follow").checked = true;
  map.clear();
  showEpoch(null, null);
  const city = state.cities.get(name);
  text("city-source", city.source);
  state.graph = await state.api.graph(name);
  state.nodes = nodePositions(state.graph);
  map.setNetwork(state.graph, city.source);
  text("network-size", `${city.network.nodes} nodes · ${city.network.edges} edges · ${city.network.road_km} km`);
  await refresh();
  state.timer = setInterval(refresh, POLL_S * 1000);
}

function todayIn(timezone) {
  return new Intl.DateTimeFormat("en-CA", { timeZone: timezone }).format(new Date());
}

/** Put the slider on the day of interval `label` (key `key`), or on today's horizon when there is none. */
function setDay(horizon, label, key) {
  state.intervals = label ? dayIntervals(horizon, label, key) : dayIntervalsOn(horizon, todayIn(horizon.timezone));
  const slider = $("interval");
  slider.max = String(state.intervals.length - 1);
  const i = label ? state.intervals.findIndex((iv) => iv.label === label) : 0;
  if (state.follow || Number(slider.value) > state.intervals.length - 1) slider.value = String(Math.max(0, i));
  $("horizon-mark").style.width = `${(100 * horizon.n_intervals) / state.intervals.length}%`;
  showSliderLabel();
}

function selectedInterval() {
  return state.intervals[Number($("interval").value)];
}

function showSliderLabel() {
  const iv = selectedInterval();
  if (!iv) return;
  const horizon = state.cities.get(state.city).horizon;
  text("interval-label", `${iv.label.slice(0, 10)} ${spanText(horizon, iv.label)}${iv.inHorizon ? "" : " (outside the horizon)"}`);
}

$("interval").addEventListener("input", () => {
  state.follow = false;
  $("follow").checked = false;
  showSliderLabel();
});
$("interval").addEventListener("change", () => run(refreshCoverage));
$("follow").addEventListener("change", (e) => {
  state.follow = e.target.checked;
  if (state.follow) run(refresh);
});

async function run(step) {
  try {
    await step();
    showError(null);
    showUpdated();
  } catch (err) {
    if (err instanceof ApiError && (err.status === 401 || err.status === 403)) disconnect(err);
    else showError(err);
  }
}

// ------------------------------------------------------------------------------------------ refreshing

async function refresh() {
  if (!state.api) return;
  if (state.busy) {
    state.again = true; // asked while a round runs (a city just chosen, say): run another after it
    return;
  }
  state.busy = true;
  try {
    do {
      state.again = false;
      await refreshOnce();
    } while (state.again);
  } finally {
    state.busy = false;
  }
}

/** One round of read calls: the epoch log (and the latest epoch, when new), coverage, tasks, fleet. */
async function refreshOnce() {
  await run(async () => {
    const name = state.city;
    const log = await state.api.epochLog(name);
    if (log.last && log.last.epoch_id !== state.epochId) {
      const [epoch, routes] = await Promise.all([
        state.api.epoch(name, log.last.epoch_id),
        state.api.routes(name, log.last.epoch_id),
      ]);
      if (name !== state.city) return; // the city changed meanwhile
      Object.assign(state, { epochId: log.last.epoch_id, epoch });
      map.setRoutes(routes);
      showEpoch(epoch, routes);
    } else if (!log.last) {
      showEpoch(null, null);
    }
    text("epoch-count", String(log.committed));
    const horizon = state.cities.get(name).horizon;
    if (state.follow || !state.intervals.length) {
      setDay(horizon, state.epoch?.stats.interval ?? null, state.epoch?.stats.interval_key ?? 0);
    }
    await Promise.all([refreshCoverage(), refreshTasks(), refreshFleet()]);
  });
}

async function refreshCoverage() {
  const iv = selectedInterval();
  if (!iv) return;
  const name = state.city;
  const [cells, cov] = await Promise.all([
    state.api.coverageCells(name, iv.label),
    state.api.coverage(name, iv.label),
  ]);
  if (name !== state.city) return;
  const max = map.setCells(cells);
  text("coverage-interval", `${iv.label.slice(0, 10)} ${spanText(state.cities.get(name).horizon, iv.label)}`);
  text("coverage-rate", pct(cov.coverage_rate));
  text("gamma", num(cov.gamma_so_far));
  text("cells-sensed", `${cov.n_cells_covered} of ${cov.n_cells_touched}`);
  text("lambda-max", String(max));
  text("heat-max", max > 1 ? String(max) : "");
}

function showEpoch(epoch, routes) {
  if (!epoch) {
    for (const id of ["epoch-id", "epoch-time", "route-count", "rider-routes", "poi-routes", "epoch-gamma"]) text(id, "–");
    return;
  }
  const kinds = { rider: 0, poi: 0 };
  for (const f of routes.features) if (f.properties.kind in kinds) kinds[f.properties.kind] += 1;
  const s = epoch.stats;
  text("epoch-id", epoch.epoch_id);
  text("epoch-time", epoch.time.replace("T", " "));
  text("route-count", String(kinds.rider + kinds.poi));
  text("rider-routes", `${kinds.rider} (step 1: ${s.step1_matches}, step 2: ${s.step2_matches})`);
  text("poi-routes", String(kinds.poi));
  text("epoch-gamma", `${num(s.gamma)} (+${num(s.gamma_gain)})`);
}

async function refreshTasks() {
  const name = state.city;
  const { tasks } = await state.api.tasks(name);
  if (name !== state.city) return;
  map.setTasks(tasks, (node) => state.nodes.get(node));
  const by = { pending: 0, assigned: 0, completed: 0 };
  for (const t of tasks) by[t.status] += 1;
  for (const [status, n] of Object.entries(by)) text(`tasks-${status}`, String(n));
}

const ago = (s) => (s < 90 ? `${Math.round(s)} s` : s < 5400 ? `${Math.round(s / 60)} min` : `${(s / 3600).toFixed(1)} h`);
const hhmm = (rfc) => rfc.slice(11, 16);

/** The worker line, the solve in progress with its runs, from GET .../fleet/status. */
function showWorker(st) {
  const w = st.worker;
  const line = $("fleet-worker");
  line.classList.toggle("gone", !w.seen);
  if (w.seen) {
    const where = w.workers[0]?.embedded ? " (inside the service)" : ` (${w.workers[0]?.host})`;
    const parts = [`worker: last heartbeat ${ago(w.heartbeat_age_s)} ago${where}`];
    if (st.pending_request) parts.push("a solve request is queued");
    if (st.next_scheduled) parts.push(`next scheduled solve: hour ${st.next_scheduled.interval.replace("T", " ")} at ${hhmm(st.next_scheduled.due_at)}`);
    line.textContent = parts.join(" · ");
  } else {
    const last = w.heartbeat_age_s === null ? "never seen" : `last heartbeat ${ago(w.heartbeat_age_s)} ago`;
    line.textContent = `no fleet worker (${last}): a solve request would wait for nobody; ${w.hint}`;
  }
  const h = st.history;
  const history = $("fleet-history");
  const waiting = st.waiting ? ` · not sized now: ${st.waiting.reason}` : "";
  history.hidden = h.enough && !st.waiting;
  history.classList.toggle("gone", !h.enough && h.until_then === "none");
  history.textContent = h.enough
    ? waiting.slice(3)
    : `${h.text}${h.until_then === "synthetic" ? "; until then sized on the seeded synthetic history (a demo city)" : ""}${waiting}`;
  const s = st.solving;
  $("fleet-solving").hidden = !s;
  if (s) {
    const why = s.trigger === "request" ? "requested" : "scheduled";
    text("fleet-solving-text", `solving: ${s.runs_done} of ${s.runs_total || "?"} runs (hour ${s.interval.slice(11)}, ${why}, ${ago(s.elapsed_s)})`);
    $("fleet-progress").max = Math.max(1, s.runs_total);
    $("fleet-progress").value = s.runs_done;
  }
}

$("solve-now").addEventListener("click", async () => {
  const name = state.city;
  const button = $("solve-now");
  button.disabled = true;
  try {
    const r = await state.api.solve(name);
    text("solve-answer", `${r.status.replace("_", " ")} (request ${r.request_id.slice(0, 8)}…)`);
  } catch (err) {
    text("solve-answer", err instanceof ApiError ? `${err.detail} (${err.status} ${err.kind})` : String(err.message ?? err));
  } finally {
    button.disabled = false;
  }
  run(refreshFleet);
});

async function refreshFleet() {
  const name = state.city;
  const [rec, hist, st] = await Promise.all([
    orNoData(state.api.recommendation(name)),
    state.api.history(name, 48),
    state.api.fleetStatus(name),
  ]);
  if (name !== state.city) return;
  showWorker(st);
  $("fleet-none").hidden = Boolean(rec);
  $("fleet-body").hidden = !rec;
  if (rec) {
    text("fleet-hour", `${rec.interval.slice(0, 10)} ${rec.interval.slice(11)}`);
    text("fleet-deterministic", String(rec.chosen.deterministic));
    text("fleet-dro", String(rec.chosen.dro));
    text("fleet-dro-rh", String(rec.chosen.dro_rh));
    text("fleet-target", rec.completion_target === null ? "none" : String(rec.completion_target));
    text("fleet-method", `${rec.divergence}, α = ${rec.alpha}, ${rec.data_window.n_days} ${rec.data_window.source} days`);
    text("fleet-version", `version ${rec.version}, computed ${rec.computed_at.slice(0, 19).replace("T", " ")} in ${rec.solve.wall_s.toFixed(0)} s (${rec.solve.runs} runs, ${rec.solve.cached_runs} cached)`);
    text("fleet-window", `history: ${rec.data_window.source} — ${rec.data_window.note}`);
    text("fleet-subsidy", rec.subsidy_note);
    kpi.update(rec);
    sweep.update(rec);
  } else {
    kpi.clear();
    sweep.clear();
  }
  history.update(hist.entries);
  const rows = hist.entries.slice(0, 6).map((e) => {
    const tr = document.createElement("tr");
    tr.className = `solve-${e.status}`;
    const sizes = e.recommendation ? `${e.recommendation.chosen.dro_rh} / ${e.recommendation.chosen.dro} / ${e.recommendation.chosen.deterministic}` : e.reason;
    for (const cell of [e.computed_at.slice(5, 16).replace("T", " "), e.status, sizes]) {
      const td = document.createElement("td");
      td.textContent = cell;
      tr.append(td);
    }
    return tr;
  });
  $("history-rows").replaceChildren(...rows);
  text("history-count", String(hist.entries.length));
}

// --------------------------------------------------------------------------------------------- legends

function swatch(colour, label, cls = "swatch") {
  const li = document.createElement("li");
  const box = document.createElement("span");
  box.className = cls;
  box.style.background = colour;
  li.append(box, label);
  return li;
}

const heat = HEAT.map((c, i) => swatch(c, i === 0 ? "1" : ""));
heat.at(-1).append(Object.assign(document.createElement("span"), { id: "heat-max", textContent: "max" }));
$("heat-legend").replaceChildren(...heat);
$("route-legend").replaceChildren(
  swatch(ROUTE_COLOURS[1], "step 1: instrumented taxi → rider", "line"),
  swatch(ROUTE_COLOURS[2], "step 2: regular taxi → rider", "line"),
  swatch(ROUTE_COLOURS[3], "step 3: route to a POI", "line dashed"),
);
$("task-legend").replaceChildren(
  ...Object.entries(TASK_COLOURS).map(([status, c]) => {
    const li = swatch(c, `${status}: `, "dot");
    const n = document.createElement("strong");
    n.id = `tasks-${status}`;
    n.textContent = "–";
    li.append(n);
    return li;
  }),
);

// ------------------------------------------------------------------------------------------------ start

const saved = sessionStorage.getItem(TOKEN_KEY);
if (saved) connect(saved).catch((err) => disconnect(err));
