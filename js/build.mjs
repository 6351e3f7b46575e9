// Bundles src/viewer.js (three.js + Spark, exact versions from package-lock.json) into one minified IIFE:
// ../go_pipeline/_resources/viewer/viewer.min.js, with the licences beside it and viewer.json (versions,
// size, SHA-256). Run: `npm ci && npm run build` in js/.
import { createHash } from "node:crypto";
import { copyFileSync, mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { build } from "esbuild";

process.chdir(new URL(".", import.meta.url).pathname); // paths below are relative to js/

const out = new URL("../go_pipeline/_resources/viewer/", import.meta.url);
mkdirSync(out, { recursive: true });
await build({
  absWorkingDir: process.cwd(),
  entryPoints: ["src/viewer.js"],
  bundle: true,
  minify: true,
  format: "iife",
  target: "es2020",
  legalComments: "eof",
  outfile: new URL("viewer.min.js", out).pathname,
});
const bundle = readFileSync(new URL("viewer.min.js", out));
const version = (name) => JSON.parse(readFileSync(`node_modules/${name}/package.json`)).version;
const info = {
  file: "viewer.min.js",
  bytes: bundle.length,
  sha256: createHash("sha256").update(bundle).digest("hex"),
  packages: Object.fromEntries(["three", "@sparkjsdev/spark", "esbuild"].map((n) => [n, version(n)])),
  licenses: { three: "MIT", "@sparkjsdev/spark": "MIT" },
  rebuild: "cd js && npm ci && npm run build",
};
writeFileSync(new URL("viewer.json", out), JSON.stringify(info, null, 2) + "\n");
copyFileSync("node_modules/three/LICENSE", new URL("LICENSE.three", out).pathname);
copyFileSync("node_modules/@sparkjsdev/spark/LICENSE", new URL("LICENSE.spark", out).pathname);
console.log(JSON.stringify(info));
