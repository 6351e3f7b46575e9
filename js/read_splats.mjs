// Reads a .spz (or SuperSplat .compressed.ply) with npm spz-js, an implementation independent of
// go-pipeline's writers, and dumps what it decoded: OUT.json (numPoints, shDegree, antialiased, the arrays'
// lengths) and OUT.f32 (float32 little-endian: positions xyz, scales (log), rotations xyzw, alphas (logit),
// colors (SH DC), sh (coefficient-major, channel inner), one after the other).
//     node js/read_splats.mjs model.spz /tmp/readback
import { readFileSync, writeFileSync } from "node:fs";
import { loadCompressedPly, loadSpz } from "spz-js";

const [file, out] = process.argv.slice(2);
const bytes = new Uint8Array(readFileSync(file));
const cloud = file.endsWith(".ply")
  ? await loadCompressedPly(new Blob([bytes]).stream())
  : await loadSpz(bytes);
const names = ["positions", "scales", "rotations", "alphas", "colors", "sh"];
const arrays = names.map((n) => cloud[n]);
const lengths = Object.fromEntries(names.map((n, i) => [n, arrays[i].length]));
const total = arrays.reduce((s, a) => s + a.length, 0);
const flat = new Float32Array(total);
let at = 0;
for (const a of arrays) {
  flat.set(a, at);
  at += a.length;
}
writeFileSync(`${out}.f32`, Buffer.from(flat.buffer));
const meta = { numPoints: cloud.numPoints, shDegree: cloud.shDegree, antialiased: cloud.antialiased, lengths };
writeFileSync(`${out}.json`, JSON.stringify(meta));
console.log(JSON.stringify(meta));
