// The map: road network (canvas, thousands of lines), grid cells coloured by Lambda, the latest epoch's
// routes and the POI tasks (SVG: few elements, each one inspectable). No tile layer: the network is the
// base map, drawn from graph.geojson.

import L from "leaflet";

/** ColorBrewer YlOrRd (7 classes): Lambda 1 is the first colour, the interval's maximum the last. */
export const HEAT = ["#ffffb2", "#fed976", "#feb24c", "#fd8d3c", "#fc4e2a", "#e31a1c", "#b10026"];

export const ROUTE_COLOURS = { 1: "#1b7837", 2: "#762a83", 3: "#2166ac" };
export const TASK_COLOURS = { pending: "#f4a582", assigned: "#4393c3", completed: "#1a9850" };

/** The heat colour of `lambda` when the largest count shown is `max` (null for Lambda 0). */
export function heatColour(lambda, max) {
  if (lambda <= 0) return null;
  if (max <= 1) return HEAT[HEAT.length - 1];
  const i = Math.round(((lambda - 1) / (max - 1)) * (HEAT.length - 1));
  return HEAT[Math.min(HEAT.length - 1, Math.max(0, i))];
}

export function createMap(element) {
  const map = L.map(element, { zoomSnap: 0.25, preferCanvas: false });
  const canvas = L.canvas({ padding: 0.2 });
  const panes = ["cells", "network", "routes", "tasks"];
  panes.forEach((name, i) => {
    map.createPane(name).style.zIndex = String(410 + i * 10);
  });
  map.getPane("network").style.pointerEvents = "none";

  let network = null;
  let cells = null;
  let routes = null;
  let tasks = null;
  let attribution = null;

  function replace(old, layer) {
    if (old) map.removeLayer(old);
    layer.addTo(map);
    return layer;
  }

  return {
    leaflet: map,

    /** Remove the cells, routes and tasks (another city is coming). */
    clear() {
      for (const layer of [cells, routes, tasks]) if (layer) map.removeLayer(layer);
      cells = routes = tasks = null;
    },

    /** The road network of a city and its attribution; fits the view to the network. */
    setNetwork(geojson, source) {
      network = replace(
        network,
        L.geoJSON(geojson, {
          pane: "network",
          renderer: canvas,
          interactive: false,
          style: { color: "#4d4d4d", weight: 1, opacity: 0.55 },
        }),
      );
      if (attribution) map.attributionControl.removeAttribution(attribution);
      attribution = source;
      if (source) map.attributionControl.addAttribution(source);
      const [w, s, e, n] = geojson.bbox;
      map.fitBounds([[s, w], [n, e]], { padding: [10, 10] });
    },

    /** Grid cells: coloured by Lambda where it is positive, a faint outline where the network runs. */
    setCells(geojson) {
      const max = Math.max(0, ...geojson.features.map((f) => f.properties.lambda));
      cells = replace(
        cells,
        L.geoJSON(geojson, {
          pane: "cells",
          filter: (f) => f.properties.sensed || f.properties.weight > 0,
          style: (f) => {
            const fill = heatColour(f.properties.lambda, max);
            return {
              className: fill ? "cell sensed" : "cell",
              color: "#9e9e9e",
              weight: 0.5,
              opacity: 0.6,
              fillColor: fill ?? "#ffffff",
              fillOpacity: fill ? 0.75 : 0,
            };
          },
          onEachFeature: (f, layer) => {
            const p = f.properties;
            layer.bindTooltip(`cell (${p.col}, ${p.row}): Λ = ${p.lambda}`, { sticky: true });
          },
        }),
      );
      return max;
    },

    /** The rider paths and POI routes of one epoch (the task Points of the document are drawn by setTasks). */
    setRoutes(geojson) {
      const lines = { ...geojson, features: geojson.features.filter((f) => f.properties.kind !== "task") };
      routes = replace(
        routes,
        L.geoJSON(lines, {
          pane: "routes",
          style: (f) => ({
            className: `route route-${f.properties.kind} step-${f.properties.step}`,
            color: ROUTE_COLOURS[f.properties.step],
            weight: f.properties.kind === "poi" ? 4 : 3,
            opacity: 0.9,
            dashArray: f.properties.kind === "poi" ? "8 5" : null,
          }),
          pointToLayer: (f, latlng) =>
            L.circleMarker(latlng, { radius: 4, className: `route route-${f.properties.kind}` }),
          onEachFeature: (f, layer) => {
            const p = f.properties;
            const who = p.kind === "poi" ? `task ${p.task_id}` : `rider ${p.rider_id}`;
            layer.bindTooltip(`step ${p.step}: taxi ${p.taxi_id} → ${who}, gain ${p.sensing_gain?.toFixed(3)}`);
          },
        }),
      );
    },

    /** POI tasks as circles coloured by status, at their node (`where(node)` gives [lat, lon]). */
    setTasks(list, where) {
      const markers = [];
      for (const t of list) {
        const at = where(t.node);
        if (!at) continue;
        markers.push(
          L.circleMarker(at, {
            pane: "tasks",
            radius: 6,
            className: `task task-${t.status}`,
            color: "#252525",
            weight: 1,
            fillColor: TASK_COLOURS[t.status],
            fillOpacity: 0.95,
          }).bindTooltip(`task ${t.id}: ${t.status}${t.taxi_id ? ` (taxi ${t.taxi_id})` : ""}`),
        );
      }
      tasks = replace(tasks, L.layerGroup(markers));
    },
  };
}

/** [lat, lon] of every node id named by the network's edges (tail and head of each LineString). */
export function nodePositions(graph) {
  const at = new Map();
  for (const f of graph.features) {
    const [a, b] = f.geometry.coordinates;
    at.set(f.properties.u, [a[1], a[0]]);
    at.set(f.properties.v, [b[1], b[0]]);
  }
  return at;
}
