// Drives the web viewer in headless Chromium (playwright-core from viewer/node_modules, the
// system's Chromium; no browser download) and prints what it measured as one JSON object.
// Run by tests/service/test_viewer_e2e.py:
//   node tests/service/viewer_e2e.mjs --url http://127.0.0.1:PORT --x X.obj --y Y.obj --out DIR
import { createRequire } from 'node:module';
import { mkdirSync } from 'node:fs';

const require = createRequire(new URL('../../viewer/package.json', import.meta.url));
const { chromium } = require('playwright-core');

const args = {};
for (let i = 2; i < process.argv.length; i += 2) args[process.argv[i].replace(/^--/, '')] = process.argv[i + 1];
const out = args.out || 'tests/artifacts';
mkdirSync(out, { recursive: true });
const timeout = 20000;
const result = { steps: [], consoleErrors: [] };
const step = (name) => {
  result.steps.push(name);
};

const browser = await chromium.launch({
  executablePath: args.chromium || process.env.LITEGE_CHROMIUM || '/usr/bin/chromium',
  headless: true,
  args: [
    '--no-sandbox',
    '--use-angle=swiftshader',
    '--enable-unsafe-swiftshader',
    '--ignore-gpu-blocklist',
    '--disable-quic',
    '--no-first-run',
    '--disable-background-networking',
    '--disable-component-update',
    '--disable-sync',
  ],
});
try {
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on('console', (m) => {
    if (m.type() === 'error') result.consoleErrors.push(m.text());
  });
  page.on('pageerror', (e) => result.consoleErrors.push(String(e)));
  const viewer = () => page.evaluate(() => window.litegeViewer);

  // ---- load
  const started = Date.now();
  await page.goto(`${args.url}/viewer`);
  await page.waitForSelector('body[data-ready="true"]', { timeout });
  result.loadWallMs = Date.now() - started;
  result.loadMs = await page.evaluate(() => window.litegeViewer.readyMs);
  result.webglInitMs = await page.evaluate(() => window.litegeViewer.webglInitMs);
  result.assets = await page.evaluate(() => performance.getEntriesByType('resource')
    .filter((r) => r.name.includes('/viewer/assets/'))
    .map((r) => ({ name: r.name.split('/').pop(), ms: r.responseEnd - r.startTime, bytes: r.encodedBodySize })));
  await page.waitForSelector('body[data-catalogue="ready"]', { timeout });
  result.webgl = await page.evaluate(() => {
    const gl = window.litegeViewer.viewer.renderer.getContext();
    return gl.getParameter(gl.VERSION);
  });
  result.exampleCount = await page.locator('#example-x option').count();
  step('loaded');

  // ---- keyboard: the controls and the canvas are reachable with Tab, and have names
  await page.keyboard.press('Tab'); // skip link
  await page.keyboard.press('Tab');
  result.secondTabStop = await page.evaluate(() => document.activeElement?.id || document.activeElement?.tagName);
  result.canvasLabel = await page.getAttribute('#canvas', 'aria-label');
  result.canvasTabIndex = await page.getAttribute('#canvas', 'tabindex');

  // ---- upload X, click a vertex, wait for the heatmap
  await page.setInputFiles('#file-x', args.x);
  await page.waitForSelector('body[data-shape-x="ready"], body[data-shape-x="error"]', { timeout });
  result.shapeX = await page.evaluate(() => document.body.dataset.shapeX);
  result.infoX = await page.textContent('#info-x');
  step('uploaded X');
  const before = await page.evaluate(() => window.litegeViewer.canvasStats());
  result.statsNeutral = before;
  const candidates = await page.evaluate(() => window.litegeViewer.probe('x', 300));
  candidates.sort((a, b) => a.x - b.x);
  const target = candidates[Math.floor(candidates.length * 0.15)];
  result.clicked = target.vertex;
  await page.mouse.click(target.x, target.y);
  await page.waitForSelector('body[data-heatmap="ready"], body[data-heatmap="error"]', { timeout });
  result.heatmap = await page.evaluate(() => document.body.dataset.heatmap);
  result.source = await page.evaluate(() => window.litegeViewer.state.source);
  result.statsHeatmap = await page.evaluate(() => window.litegeViewer.canvasStats());
  result.probe = (await page.evaluate(() => window.litegeViewer.probe('x', 400))).map((p) => ({ value: p.value, rgb: p.rgb }));
  result.colorbarVisible = await page.isVisible('#colorbar');
  result.colorbarText = await page.textContent('#colorbar');
  result.requestLog = await page.textContent('#request-log');
  await page.screenshot({ path: `${out}/viewer-heatmap.png` });
  step('heatmap');

  // ---- shift-click the farthest visible vertex: geodesic path
  const probe = await page.evaluate(() => window.litegeViewer.probe('x', 400));
  probe.sort((a, b) => b.value - a.value);
  const far = probe[0];
  await page.keyboard.down('Shift');
  await page.mouse.click(far.x, far.y);
  await page.keyboard.up('Shift');
  await page.waitForSelector('body[data-path="ready"], body[data-path="error"]', { timeout });
  result.path = await page.evaluate(() => document.body.dataset.path);
  result.pathInfo = await page.textContent('#path-info');
  await page.screenshot({ path: `${out}/viewer-path.png` });
  step('path');

  // ---- keyboard shortcuts: I toggles isolines, R resets the view
  await page.focus('#canvas');
  await page.keyboard.press('i');
  result.isolinesAfterI = await page.isChecked('#isolines');
  await page.keyboard.press('i');
  await page.keyboard.press('ArrowLeft');
  await page.keyboard.press('r');
  step('keys');

  // ---- bad input: a client-side check, and a problem+json answer of the service
  await page.fill('#source-index', '999999999');
  await page.click('#show-distances');
  await page.waitForSelector('#messages p', { timeout });
  result.badIndexMessage = await page.textContent('#messages');
  await page.setInputFiles('#file-y', { name: 'broken.obj', mimeType: 'text/plain', buffer: Buffer.from('v 0 0 0\nf 1 2 3\n') });
  await page.waitForSelector('body[data-shape-y="error"]', { timeout });
  result.badUploadMessage = await page.textContent('#messages');
  step('error messages');

  // ---- second shape: correspondence view (or its clean error while the endpoint is missing)
  await page.evaluate(() => {
    document.body.dataset.shapeY = 'idle';
  });
  await page.setInputFiles('#file-y', args.y);
  await page.waitForSelector('body[data-shape-y="ready"], body[data-shape-y="error"]', { timeout });
  result.shapeY = await page.evaluate(() => document.body.dataset.shapeY);
  await page.waitForFunction(() => ['ready', 'error'].includes(document.body.dataset.correspondence), null, { timeout: 45000 });
  result.correspondence = await page.evaluate(() => document.body.dataset.correspondence);
  result.mode = await page.evaluate(() => window.litegeViewer.state.mode);
  result.messages = await page.textContent('#messages');
  result.corrStatus = await page.textContent('#corr-status');
  result.statsCorrespondence = await page.evaluate(() => window.litegeViewer.canvasStats());
  result.probeY = (await page.evaluate(() => window.litegeViewer.probe('y', 200))).map((p) => p.rgb);
  await page.screenshot({ path: `${out}/viewer-correspondence.png` });
  const tail = await page.evaluate(() => window.litegeViewer.probe('y', 200));
  if (tail.length) {
    await page.mouse.click(tail[0].x, tail[0].y);
    await page.waitForSelector('body[data-lines="1"], body[data-lines="error"]', { timeout });
    result.lines = await page.evaluate(() => document.body.dataset.lines);
    result.lineStatus = await page.textContent('#corr-status');
  }
  step('correspondence');

  // ---- a service without POST /correspondences: the problem is shown, nothing breaks
  await page.route('**/correspondences', (route) => route.fulfill({
    status: 404,
    contentType: 'application/problem+json',
    body: JSON.stringify({ type: 'https://litege.dev/problems/not-found', title: 'Not Found', status: 404, detail: 'Not Found', code: 'not-found' }),
  }));
  await page.click('#swap');
  await page.waitForSelector('body[data-correspondence="error"]', { timeout });
  result.missingEndpointMessage = await page.textContent('#messages');
  result.missingEndpointStatus = await page.textContent('#corr-status');
  result.statsMissingEndpoint = await page.evaluate(() => window.litegeViewer.canvasStats());
  await page.screenshot({ path: `${out}/viewer-correspondence-missing.png` });
  await page.unroute('**/correspondences');
  step('missing endpoint');

  // ---- drag and drop a file (a bundled example) on the left half: it replaces X
  await page.evaluate(() => {
    document.body.dataset.shapeX = 'idle';
  });
  await page.evaluate(async () => {
    const blob = await (await fetch('/viewer/examples/cow.obj')).blob();
    const transfer = new DataTransfer();
    transfer.items.add(new File([blob], 'cow.obj', { type: 'text/plain' }));
    const view = document.getElementById('view');
    const rect = view.getBoundingClientRect();
    const init = { dataTransfer: transfer, bubbles: true, cancelable: true, clientX: rect.left + rect.width * 0.25, clientY: rect.top + rect.height / 2 };
    view.dispatchEvent(new DragEvent('dragover', init));
    view.dispatchEvent(new DragEvent('drop', init));
  });
  await page.waitForSelector('body[data-shape-x="ready"], body[data-shape-x="error"]', { timeout });
  result.dropped = await page.evaluate(() => [document.body.dataset.shapeX, window.litegeViewer.state.shapes.x?.name]);
  step('drop');

  // ---- laptop-sized and narrow windows keep the view and the controls usable
  await page.setViewportSize({ width: 800, height: 700 });
  await page.waitForTimeout(200);
  result.narrow = await page.evaluate(() => {
    const c = document.getElementById('canvas').getBoundingClientRect();
    const p = document.getElementById('panel').getBoundingClientRect();
    return { canvasWidth: c.width, canvasHeight: c.height, panelWidth: p.width };
  });
  await page.screenshot({ path: `${out}/viewer-narrow.png` });
  step('narrow');
} catch (error) {
  result.error = String(error && error.stack ? error.stack : error);
  try {
    const page = browser.contexts()[0]?.pages()[0];
    if (page) {
      result.flagsAtError = await page.evaluate(() => ({ ...document.body.dataset }));
      result.messagesAtError = await page.textContent('#messages');
      await page.screenshot({ path: `${out}/viewer-error.png` });
    }
  } catch {
    // the page is gone: nothing more to record
  }
} finally {
  await browser.close();
}
process.stdout.write(`${JSON.stringify(result)}\n`);
