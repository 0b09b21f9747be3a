// The fleet recommendation's two charts (Chart.js on a 2D canvas): the total cost per hour against the instrumented
// fleet size (sample mean and worst case), and the chosen sizes over the history of solves.

import {
  CategoryScale,
  Chart,
  Legend,
  LinearScale,
  LineController,
  LineElement,
  PointElement,
  ScatterController,
  Tooltip,
} from "chart.js";

Chart.register(CategoryScale, Legend, LinearScale, LineController, LineElement, PointElement, ScatterController, Tooltip);

const BASE = {
  animation: false,
  responsive: true,
  maintainAspectRatio: false,
  plugins: { legend: { position: "bottom", labels: { boxWidth: 12 } } },
};

/** Total platform cost per hour against size: the sample mean (Deterministic), its worst case over the
 * ambiguity ball (DRO), the paper's box LP bound, the coming hour's worst case (DRO_RH), and each choice. */
export function kpiChart(canvas) {
  const chart = new Chart(canvas, {
    type: "line",
    data: { datasets: [] },
    options: {
      ...BASE,
      parsing: false,
      scales: {
        x: { type: "linear", title: { display: true, text: "instrumented taxis N1" } },
        y: { title: { display: true, text: "total cost, CNY per hour" } },
      },
    },
  });
  return {
    update(rec) {
      const pts = (rows, key) => rows.filter((r) => r[key] !== null).map((r) => ({ x: r.size, y: r[key] }));
      const chosen = (size, rows, key, label, colour) => ({
        type: "scatter",
        label,
        data: pts(rows.filter((r) => r.size === size), key),
        pointRadius: 7,
        pointStyle: "rectRot",
        backgroundColor: colour,
        borderColor: colour,
      });
      const day = rec.candidates;
      const hour = rec.dro_rh.candidates;
      chart.data.datasets = [
        { label: "mean", data: pts(day, "mean_cost_cny_per_h"), borderColor: "#878787", backgroundColor: "#878787" },
        { label: "worst case", data: pts(day, "worst_case_cost_cny_per_h"), borderColor: "#d6604d", backgroundColor: "#d6604d" },
        { label: "box LP bound", data: pts(day, "box_lp_worst_case_cny_per_h"), borderColor: "#f4a582", backgroundColor: "#f4a582", borderDash: [2, 3] },
        { label: `hour ${rec.interval.slice(11)} worst case`, data: pts(hour, "worst_case_cost_cny_per_h"), borderColor: "#2166ac", backgroundColor: "#2166ac", borderDash: [6, 4] },
        chosen(rec.chosen.dro, day, "worst_case_cost_cny_per_h", "DRO choice", "#b2182b"),
        chosen(rec.chosen.dro_rh, hour, "worst_case_cost_cny_per_h", "DRO_RH choice", "#053061"),
      ];
      chart.update();
    },
    clear() {
      chart.data.datasets = [];
      chart.update();
    },
  };
}

/** Chosen sizes per solve, oldest first; a failed solve is a gap. */
export function historyChart(canvas) {
  const chart = new Chart(canvas, {
    type: "line",
    data: { labels: [], datasets: [] },
    options: {
      ...BASE,
      spanGaps: false,
      scales: {
        x: { ticks: { maxRotation: 0, autoSkip: true } },
        y: { title: { display: true, text: "chosen N1" }, beginAtZero: true },
      },
    },
  });
  return {
    update(entries) {
      const old = [...entries].reverse();
      const size = (key) => old.map((e) => (e.recommendation ? e.recommendation.chosen[key] : null));
      chart.data.labels = old.map((e) => `${e.interval.slice(5, 10)} ${e.interval.slice(11)}`);
      chart.data.datasets = [
        { label: "DRO_RH", data: size("dro_rh"), borderColor: "#053061", backgroundColor: "#053061", stepped: true },
        { label: "DRO", data: size("dro"), borderColor: "#b2182b", backgroundColor: "#b2182b", stepped: true },
        { label: "Deterministic", data: size("deterministic"), borderColor: "#878787", backgroundColor: "#878787", stepped: true },
      ];
      chart.update();
    },
  };
}

/** The chosen size at each subsidy of the recommendation's sweep (same samples), a step per method, and the
 * configured ζ marked: what a different setting would recommend. */
export function sweepChart(canvas) {
  const chart = new Chart(canvas, {
    type: "line",
    data: { datasets: [] },
    options: {
      ...BASE,
      parsing: false,
      scales: {
        x: { type: "linear", title: { display: true, text: "ζ, CNY per instrumented vehicle-hour" } },
        y: { title: { display: true, text: "chosen N1" }, beginAtZero: true },
      },
    },
  });
  return {
    update(rec) {
      const pts = (key) => rec.subsidy_sweep.map((p) => ({ x: p.subsidy_cny_per_vehicle_hour, y: p[key] }));
      const here = rec.subsidy_sweep.filter((p) => p.subsidy_cny_per_vehicle_hour === rec.subsidy_cny_per_vehicle_hour);
      chart.data.datasets = [
        { label: "DRO", data: pts("dro"), borderColor: "#b2182b", backgroundColor: "#b2182b", stepped: "before" },
        { label: `DRO_RH ${rec.interval.slice(11)}`, data: pts("dro_rh"), borderColor: "#053061", backgroundColor: "#053061", stepped: "before", borderDash: [6, 4] },
        { label: "Deterministic", data: pts("deterministic"), borderColor: "#878787", backgroundColor: "#878787", stepped: "before" },
        {
          type: "scatter",
          label: `ζ = ${rec.subsidy_cny_per_vehicle_hour} (set)`,
          data: here.map((p) => ({ x: p.subsidy_cny_per_vehicle_hour, y: p.dro })),
          pointRadius: 7,
          pointStyle: "rectRot",
          backgroundColor: "#f4a582",
          borderColor: "#b2182b",
        },
      ];
      chart.update();
    },
    clear() {
      chart.data.datasets = [];
      chart.update();
    },
  };
}
