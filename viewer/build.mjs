// Bundle the viewer into service/static/viewer/ (generated, not committed): index.html and
// assets/viewer.{js,css}. Run by `make viewer` (npm ci && npm run build).
import { build } from 'esbuild';
import { copyFile, mkdir, rm } from 'node:fs/promises';
import { fileURLToPath } from 'node:url';

const here = (path) => fileURLToPath(new URL(path, import.meta.url));
const out = here('../service/static/viewer/');
const assets = `${out}assets/`;

await rm(out, { recursive: true, force: true });
await mkdir(assets, { recursive: true });
await build({
  entryPoints: [here('src/main.js')],
  bundle: true,
  minify: true,
  format: 'esm',
  target: ['es2020'],
  outfile: `${assets}viewer.js`,
  legalComments: 'eof',
  logLevel: 'warning',
});
await copyFile(here('src/style.css'), `${assets}viewer.css`);
await copyFile(here('src/index.html'), `${out}index.html`);
console.log(`viewer built into ${out}`);
