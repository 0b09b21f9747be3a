// Build the dashboard into app/static/dashboard/: index.html, assets/dashboard.js and assets/dashboard.css
// (our source with Leaflet and Chart.js bundled and minified), assets/LICENSES.txt (the bundled libraries'
// licence notices) and assets/build.json (a digest of the inputs: tests/unit/test_dashboard_build.py fails
// when the sources change without a rebuild). Run `npm ci && npm run build` here, or `make dashboard`.

import { createHash } from "node:crypto";
import { copyFile, mkdir, readFile, readdir, rm, writeFile } from "node:fs/promises";
import { fileURLToPath } from "node:url";
import { build } from "esbuild";

const here = (p) => fileURLToPath(new URL(p, import.meta.url));
const out = here("../app/static/dashboard/");

await rm(out, { recursive: true, force: true });
await mkdir(`${out}assets`, { recursive: true });
await build({
  entryPoints: { dashboard: here("src/main.js") },
  bundle: true,
  minify: true,
  format: "iife",
  target: ["es2020"],
  outdir: `${out}assets`,
  loader: { ".png": "dataurl", ".svg": "dataurl" },
  legalComments: "none", // the notices go to LICENSES.txt, whole
  logLevel: "info",
});
await copyFile(here("index.html"), `${out}index.html`);

const notices = ["leaflet/LICENSE", "chart.js/LICENSE.md", "@kurkle/color/LICENSE.md"];
const parts = [];
for (const path of notices) {
  const pkg = JSON.parse(await readFile(here(`node_modules/${path.split("/").slice(0, -1).join("/")}/package.json`), "utf8"));
  parts.push(`${pkg.name} ${pkg.version} (${pkg.license})\n\n${(await readFile(here(`node_modules/${path}`), "utf8")).trim()}\n`);
}
await writeFile(`${out}assets/LICENSES.txt`, `Libraries bundled into dashboard.js and dashboard.css\n\n${parts.join("\n---\n\n")}`);

// The digest of every input, in a fixed order: sha256 over "path\0content\0" of each file.
const inputs = ["build.mjs", "index.html", "package.json", "package-lock.json"];
for (const name of (await readdir(here("src"))).sort()) inputs.push(`src/${name}`);
const digest = createHash("sha256");
for (const path of inputs) digest.update(`${path}\0`).update(await readFile(here(path))).update("\0");
await writeFile(`${out}assets/build.json`, `${JSON.stringify({ inputs, sha256: digest.digest("hex") }, null, 2)}\n`);
