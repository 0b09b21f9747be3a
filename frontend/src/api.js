// The service's HTTP API as the dashboard uses it: bearer token, JSON or GeoJSON in, the one error shape out.
//
// Every call resolves relative to the page (served at /dashboard), so the dashboard keeps working behind a
// reverse proxy that mounts the service under a path prefix.

/** An error answer of the API: `{"error": kind, "detail": text, "fields": [...]}` plus the HTTP status. */
export class ApiError extends Error {
  constructor(status, kind, detail) {
    super(`${detail} (${status} ${kind})`);
    this.status = status;
    this.kind = kind;
    this.detail = detail;
  }
}

/** A client for one bearer token. `send(method, path)` resolves to the parsed body or rejects with an
 * ApiError; `get(path)` is `send("GET", path)`. */
export function apiClient(token) {
  async function send(method, path) {
    let response;
    try {
      response = await fetch(path, { method, headers: { Authorization: `Bearer ${token}` }, cache: "no-store" });
    } catch (err) {
      throw new ApiError(0, "unreachable", `the service cannot be reached: ${err.message}`);
    }
    if (response.ok) return response.json();
    let body = null;
    try {
      body = await response.json();
    } catch {
      // not the error shape (a proxy's page, say): report the status alone
    }
    throw new ApiError(response.status, body?.error ?? "http_error", body?.detail ?? response.statusText);
  }
  const get = (path) => send("GET", path);

  const city = (name) => `v1/cities/${encodeURIComponent(name)}`;
  return {
    cities: () => get("v1/cities"),
    graph: (name) => get(`${city(name)}/graph.geojson`),
    epochLog: (name) => get(`${city(name)}/epochs`),
    epoch: (name, id) => get(`${city(name)}/epochs/${encodeURIComponent(id)}`),
    routes: (name, id) => get(`${city(name)}/epochs/${encodeURIComponent(id)}/routes.geojson`),
    coverage: (name, label) => get(`${city(name)}/coverage?interval=${encodeURIComponent(label)}`),
    coverageCells: (name, label) => get(`${city(name)}/coverage.geojson?interval=${encodeURIComponent(label)}`),
    tasks: (name) => get(`${city(name)}/tasks`),
    recommendation: (name) => get(`${city(name)}/fleet/recommendation`),
    history: (name, limit) => get(`${city(name)}/fleet/recommendations?limit=${limit}`),
    fleetStatus: (name) => get(`${city(name)}/fleet/status`),
    solve: (name) => send("POST", `${city(name)}/fleet/solve`),
  };
}

/** The value of a call, or `fallback` when it answers 404 `no_data` (nothing to show yet). */
export async function orNoData(promise, fallback = null) {
  try {
    return await promise;
  } catch (err) {
    if (err instanceof ApiError && err.status === 404 && err.kind === "no_data") return fallback;
    throw err;
  }
}
