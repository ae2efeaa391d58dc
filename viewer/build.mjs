// Bundle the viewer into service/static/viewer/ (generated, not committed): index.html and
// assets/viewer.{js,css}. Run by `make viewer` (npm ci && npm run build).
// Also copies Swagger UI (swagger-ui-dist, pinned in package.json) into service/static/docs/,
// from where the service serves /docs without a CDN (service/app.py).
import { build } from 'esbuild';
import { copyFile, mkdir, readFile, rm, writeFile } from 'node:fs/promises';
import { fileURLToPath } from 'node:url';

const here = (path) => fileURLToPath(new URL(path, import.meta.url));
const out = here('../service/static/viewer/');
const assets = `${out}assets/`;
const docs = here('../service/static/docs/');
const swagger = here('node_modules/swagger-ui-dist/');

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

// Swagger UI for /docs: the bundle, its stylesheet and favicon, with its licence files
// (Apache-2.0). The stylesheet's source-map comment is dropped (the maps are not shipped).
await rm(docs, { recursive: true, force: true });
await mkdir(docs, { recursive: true });
await copyFile(`${swagger}swagger-ui-bundle.js`, `${docs}swagger-ui-bundle.js`);
const css = await readFile(`${swagger}swagger-ui.css`, 'utf8');
await writeFile(`${docs}swagger-ui.css`, css.replace(/\s*\/\*# sourceMappingURL=[^*]*\*\/\s*$/, '\n'));
await copyFile(`${swagger}favicon-32x32.png`, `${docs}favicon-32x32.png`);
await copyFile(`${swagger}LICENSE`, `${docs}LICENSE.txt`);
await copyFile(`${swagger}NOTICE`, `${docs}NOTICE.txt`);
await copyFile(`${swagger}swagger-ui-bundle.js.LICENSE.txt`, `${docs}swagger-ui-bundle.js.LICENSE.txt`);
const { version } = JSON.parse(await readFile(`${swagger}package.json`, 'utf8'));
await writeFile(`${docs}VERSION.txt`, `swagger-ui-dist ${version}\n`);
console.log(`Swagger UI ${version} copied into ${docs}`);
