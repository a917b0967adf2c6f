// Bundle src/main.ts (with uPlot and three.js) into dist/: content-hashed assets and an
// index.html that names them. Usage: node build.mjs [--dev] (--dev: no minification).
import { execFileSync } from "node:child_process";
import { build } from "esbuild";
import { cpSync, existsSync, mkdirSync, readFileSync, rmSync, writeFileSync } from "node:fs";
import { basename, dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

const root = dirname(fileURLToPath(import.meta.url));
const dist = join(root, "dist");
const dev = process.argv.includes("--dev");

rmSync(dist, { recursive: true, force: true });
mkdirSync(join(dist, "assets"), { recursive: true });

const result = await build({
  entryPoints: [join(root, "src", "main.ts")],
  bundle: true,
  format: "esm",
  target: "es2022",
  minify: !dev,
  sourcemap: true,
  outdir: join(dist, "assets"),
  entryNames: "[name]-[hash]",
  metafile: true,
  logLevel: "warning",
  legalComments: "linked",
});

const outputs = Object.keys(result.metafile.outputs).map((p) => basename(p));
const js = outputs.find((p) => p.endsWith(".js"));
const css = outputs.find((p) => p.endsWith(".css"));
if (!js || !css) throw new Error(`build produced no js/css: ${outputs.join(", ")}`);

const html = readFileSync(join(root, "index.html"), "utf8")
  .replace("%APP_JS%", `/assets/${js}`)
  .replace("%APP_CSS%", `/assets/${css}`);
writeFileSync(join(dist, "index.html"), html);
if (existsSync(join(root, "public"))) cpSync(join(root, "public"), dist, { recursive: true });
// The API's documentation page (/docs) loads Swagger UI from here, never from a CDN, so that
// it works offline as the rest does (swagger-ui-dist, pinned in package.json).
const swagger = join(root, "node_modules", "swagger-ui-dist");
mkdirSync(join(dist, "swagger"), { recursive: true });
for (const name of ["swagger-ui-bundle.js", "swagger-ui.css", "favicon-32x32.png", "LICENSE"]) {
  cpSync(join(swagger, name), join(dist, "swagger", name === "LICENSE" ? "LICENSE.txt" : name));
}
// The model for the 3D view, exported by the project's own command when it is installed
// (scripts/setup.sh installs it before building); without it the console says the 3D view
// is not available.
const hikoboshi = join(root, "..", ".venv", "bin", "hikoboshi");
if (existsSync(hikoboshi)) {
  try {
    mkdirSync(join(dist, "model"), { recursive: true });
    writeFileSync(join(dist, "model", "ets7.urdf"), execFileSync(hikoboshi, ["model", "urdf"]));
  } catch (err) {
    console.warn(`no model for the 3D view: ${err.message}`);
  }
} else {
  console.warn(`no model for the 3D view: ${hikoboshi} is not installed`);
}
console.log(`console built: dist/index.html, dist/assets/${js}, dist/assets/${css}`);
