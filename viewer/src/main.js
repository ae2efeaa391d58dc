// LiteGE web viewer: upload or open a shape, click for a geodesic distance heatmap,
// shift-click for a geodesic path, load a second shape for the correspondence view.
// Everything goes through the service's REST API; see service/viewer.py for the routes that
// serve this page.
import * as THREE from 'three';
import { api, getApiKey, onRequest, setApiKey } from './api.js';
import { coordinateColors, fmt, niceStep, niceTicks, viridisBytes } from './colors.js';
import { ShapeView, Viewer3D } from './scene.js';

const $ = (id) => document.getElementById(id);
const OTHER = { x: 'y', y: 'x' };

const state = {
  mode: 'distances',
  shapes: { x: null, y: null }, // {info, name, view, colors, attribution}
  models: [],
  defaultModel: null,
  examples: [],
  source: null,
  target: null,
  field: null, // {values, max, step}
  transfer: null, // {key, matches}
  lines: 0,
  isolines: true,
  busy: 0,
};
let viewer = null;

// ------------------------------------------------------------------ small UI helpers

function flag(name, value) {
  document.body.dataset[name] = value;
}

function setBusy(delta) {
  state.busy = Math.max(0, state.busy + delta);
  $('busy').hidden = state.busy === 0;
  document.body.setAttribute('aria-busy', state.busy ? 'true' : 'false');
}

function clearMessages() {
  $('messages').replaceChildren();
}

function showError(error) {
  const box = $('messages');
  const p = document.createElement('p');
  const problem = error.problem || {};
  const code = problem.code ? ` [${problem.code}]` : '';
  p.textContent = `${error.message}${code}`;
  p.className = 'error-message';
  const dismiss = document.createElement('button');
  dismiss.type = 'button';
  dismiss.className = 'dismiss';
  dismiss.textContent = '×';
  dismiss.setAttribute('aria-label', 'Dismiss this message');
  dismiss.addEventListener('click', () => p.remove());
  p.prepend(dismiss);
  box.append(p);
}

function status(text) {
  $('action-status').textContent = text;
}

function corrStatus(text) {
  $('corr-status').textContent = text;
}

// A warning for the status line when a shape's frame is uncertain (its T-Net runs split),
// '' otherwise: the matches may then be turned or mirrored.
function uncertainFrames(answer, sourceName, targetName) {
  const names = [];
  if (answer.source_frame?.check === 'split') names.push(sourceName);
  if (answer.target_frame?.check === 'split') names.push(targetName);
  if (!names.length) return '';
  return ` Warning: the frame of ${names.join(' and ')} is uncertain (turned copies disagreed), so matches may be turned or mirrored.`;
}

function logRequest({ method, path, status: code, ms, ok }) {
  const li = document.createElement('li');
  const what = document.createElement('span');
  what.textContent = `${method} ${path}`;
  what.title = `${method} ${path}`;
  const st = document.createElement('span');
  st.textContent = code || 'ERR';
  if (!ok) st.className = 'bad';
  const t = document.createElement('span');
  t.textContent = `${ms.toFixed(1)} ms`;
  li.append(what, st, t);
  const log = $('request-log');
  log.prepend(li);
  while (log.children.length > 15) log.lastChild.remove();
}

function dd(list, term, value, cls) {
  const dt = document.createElement('dt');
  dt.textContent = term;
  const d = document.createElement('dd');
  if (value instanceof Node) d.append(value);
  else d.textContent = value;
  if (cls) d.className = cls;
  list.append(dt, d);
}

function renderInfo(slot) {
  const list = $(`info-${slot}`);
  list.replaceChildren();
  const shape = state.shapes[slot];
  if (!shape) return;
  const { info } = shape;
  dd(list, 'file', shape.name);
  const id = document.createElement('code');
  id.textContent = info.shape_id;
  id.title = info.shape_id;
  dd(list, 'shape id', id);
  dd(list, 'kind', info.kind === 'mesh' ? `mesh, ${info.n_points} vertices, ${info.n_faces} faces` : `point cloud, ${info.n_points} points`);
  dd(list, 'model', info.model);
  const score = fmt(info.ood_score);
  if (info.out_of_distribution === true) {
    dd(list, 'OOD', `⚠ out of distribution (score ${score}): predictions may be unreliable`, 'warn');
  } else if (info.out_of_distribution === false) {
    dd(list, 'OOD', `in distribution (score ${score})`, 'ok');
  } else {
    dd(list, 'OOD', `score ${score} (model not calibrated)`);
  }
  dd(list, 'upload', `${info.created ? 'registered' : 'already registered'} in ${fmt(shape.uploadMs)} ms`);
  updateAttribution();
}

function updateAttribution() {
  const notes = ['x', 'y']
    .map((slot) => state.shapes[slot])
    .filter((shape) => shape && shape.attribution)
    .map((shape) => `${shape.name}: ${shape.attribution}`);
  $('attribution').textContent = [...new Set(notes)].join(' ');
}

// ------------------------------------------------------------------ colour bar

function drawColorbar(max, step) {
  const canvas = $('colorbar-canvas');
  const ctx = canvas.getContext('2d');
  const bytes = viridisBytes();
  const image = ctx.createImageData(canvas.width, canvas.height);
  for (let y = 0; y < canvas.height; y++) {
    const k = Math.round(((canvas.height - 1 - y) / (canvas.height - 1)) * 255);
    for (let x = 0; x < canvas.width; x++) {
      const o = (y * canvas.width + x) * 4;
      image.data.set(bytes.subarray(k * 4, k * 4 + 4), o);
    }
  }
  ctx.putImageData(image, 0, 0);
  if (state.isolines && step > 0) {
    ctx.fillStyle = 'rgba(0,0,0,0.8)';
    for (let level = step; level < max; level += step) {
      const y = Math.round((1 - level / max) * (canvas.height - 1));
      ctx.fillRect(0, y, 6, 1);
    }
  }
  const ticks = $('colorbar-ticks');
  ticks.replaceChildren();
  for (const t of niceTicks(0, max, 5)) {
    const span = document.createElement('span');
    span.style.top = `${(1 - t / max) * 100}%`;
    span.textContent = fmt(t);
    ticks.append(span);
  }
  $('colorbar-caption').textContent = 'geodesic distance';
  $('colorbar-units').textContent = `in input units (the shape's own)${state.isolines && step > 0 ? `; isolines every ${fmt(step)}` : ''}`;
  $('colorbar').hidden = false;
}

// ------------------------------------------------------------------ shapes

async function loadShape(slot, blob, filename, { modelHint = null, attribution = null } = {}) {
  clearMessages();
  const flagName = `shape${slot.toUpperCase()}`;
  flag(flagName, 'loading');
  setBusy(1);
  status(`Uploading ${filename}…`);
  try {
    const form = new FormData();
    form.append('file', blob, filename);
    const chosen = $('model').value || (modelHint && state.models.includes(modelHint) ? modelHint : '');
    if (chosen) form.append('model', chosen);
    const { data: info, ms } = await api('POST', '/shapes', { form });
    const geometryPath = `/viewer/shapes/${encodeURIComponent(info.shape_id)}/geometry?model=${encodeURIComponent(info.model)}`;
    const { data: buffer, response } = await api('GET', geometryPath, { binary: true });
    const n = Number(response.headers.get('X-N-Points'));
    const f = Number(response.headers.get('X-N-Faces'));
    const positions = new Float32Array(buffer, 0, n * 3);
    const index = f > 0 ? new Uint32Array(buffer, n * 12, f * 3) : null;
    const view = new ShapeView(positions, index);
    view.setIsolines(state.isolines);
    state.shapes[slot] = { info, name: filename, view, colors: null, attribution, uploadMs: ms };
    viewer.setShape(slot, view);
    state.lines = 0;
    state.transfer = null;
    if (slot === 'x') {
      state.source = null;
      state.target = null;
      state.field = null;
      $('path-info').textContent = '';
    }
    renderInfo(slot);
    $('view-hint').textContent = 'Click a point: distances. Shift-click: path. Drag: orbit; wheel: zoom; right-drag: pan.';
    status(`Opened ${filename} (${info.n_points} points) in ${fmt(ms)} ms.`);
    flag(flagName, 'ready');
    if (slot === 'y') await setMode('correspondence');
    else await setMode(state.mode);
  } catch (error) {
    showError(error);
    status('');
    flag(flagName, 'error');
  } finally {
    setBusy(-1);
  }
}

async function openExample(slot) {
  const name = $(`example-${slot}`).value;
  const example = state.examples.find((e) => e.name === name);
  if (!example) return;
  clearMessages();
  setBusy(1);
  try {
    const started = performance.now();
    const response = await fetch(`/viewer/examples/${encodeURIComponent(name)}.obj`);
    logRequest({ method: 'GET', path: `/viewer/examples/${name}.obj`, status: response.status, ms: performance.now() - started, ok: response.ok });
    if (!response.ok) {
      const problem = await response.json().catch(() => ({}));
      throw Object.assign(new Error(`GET /viewer/examples/${name}.obj failed: ${response.status} ${problem.detail || ''}`), { problem });
    }
    const blob = await response.blob();
    await loadShape(slot, blob, `${name}.obj`, { modelHint: example.model, attribution: example.attribution });
  } catch (error) {
    showError(error);
  } finally {
    setBusy(-1);
  }
}

// ------------------------------------------------------------------ modes

async function setMode(mode) {
  state.mode = mode;
  for (const radio of document.querySelectorAll('input[name="mode"]')) radio.checked = radio.value === mode;
  $('distances-panel').hidden = mode !== 'distances';
  const x = state.shapes.x;
  viewer.clearLines();
  state.lines = 0;
  viewer.layout(mode === 'correspondence');
  if (mode === 'distances') {
    $('colorbar').hidden = !state.field;
    if (x) {
      x.view.clearOverlays();
      if (state.field) {
        x.view.setField(state.field.values, state.field.max, state.field.step);
        if (state.source !== null) x.view.addMarker(state.source, 0xffffff);
      } else {
        x.view.setNeutral();
      }
    }
    viewer.render();
    return;
  }
  $('colorbar').hidden = true;
  await applyCorrespondence();
}

async function applyCorrespondence() {
  const x = state.shapes.x;
  const y = state.shapes.y;
  if (!x) {
    corrStatus('Open shape X first.');
    return;
  }
  x.view.clearOverlays();
  x.colors = x.colors || coordinateColors(x.view.geometry.attributes.position.array);
  x.view.setColors(x.colors);
  if (!y) {
    corrStatus('Open a second shape (Y) to see the correspondence.');
    flag('correspondence', 'waiting');
    viewer.render();
    return;
  }
  y.view.clearOverlays();
  const model = $('model').value || null;
  const key = `${x.info.shape_id}|${y.info.shape_id}|${model}`;
  try {
    if (!state.transfer || state.transfer.key !== key) {
      y.view.setNeutral();
      viewer.render();
      flag('correspondence', 'loading');
      corrStatus('Matching Y to X…');
      setBusy(1);
      try {
        const { data, ms } = await api('POST', '/correspondences', {
          json: {
            source_shape_id: y.info.shape_id,
            target_shape_id: x.info.shape_id,
            queries: 'all',
            return_distance: false,
            model,
          },
        });
        if (!Array.isArray(data.matches) || data.matches.length !== y.view.n) {
          throw new Error(`POST /correspondences answered ${data.matches?.length} matches for ${y.view.n} points`);
        }
        state.transfer = {
          key,
          matches: Int32Array.from(data.matches),
          model: data.model,
          ms,
          uncertain: uncertainFrames(data, 'Y', 'X'),
        };
      } finally {
        setBusy(-1);
      }
    }
    if (state.mode !== 'correspondence' || state.shapes.y !== y) return;
    const { matches } = state.transfer;
    const colors = new Float32Array(y.view.n * 3);
    for (let j = 0; j < y.view.n; j++) {
      const k = matches[j];
      colors[j * 3] = x.colors[k * 3];
      colors[j * 3 + 1] = x.colors[k * 3 + 1];
      colors[j * 3 + 2] = x.colors[k * 3 + 2];
    }
    y.view.setColors(colors);
    corrStatus(`Colours of X carried to Y through ${matches.length} predicted matches (model ${state.transfer.model}, ${fmt(state.transfer.ms)} ms). Click a point on either shape for its match.${state.transfer.uncertain}`);
    flag('correspondence', 'ready');
  } catch (error) {
    showError(error);
    y.view.setNeutral();
    corrStatus(`Colour transfer unavailable: ${error.problem?.detail || error.message}`);
    flag('correspondence', 'error');
  }
  viewer.render();
}

// ------------------------------------------------------------------ queries

function checkIndex(slot, i) {
  const shape = state.shapes[slot];
  if (!shape) throw new Error('Open a shape first (file, drop, or example).');
  if (!Number.isInteger(i) || i < 0 || i >= shape.view.n) {
    throw new Error(`Vertex index must be an integer from 0 to ${shape.view.n - 1}.`);
  }
  return shape;
}

async function showDistances(i) {
  clearMessages();
  let x;
  try {
    x = checkIndex('x', i);
  } catch (error) {
    showError(error);
    return;
  }
  if (state.mode !== 'distances') await setMode('distances');
  flag('heatmap', 'loading');
  setBusy(1);
  try {
    const { data, ms } = await api('POST', '/geodesic', {
      json: { shape_id: x.info.shape_id, sources: [i], targets: 'all', model: x.info.model },
      binary: true,
      accept: 'application/octet-stream',
    });
    const values = new Float32Array(data);
    let max = 0;
    for (const v of values) if (Number.isFinite(v) && v > max) max = v;
    const step = niceStep(max, 10);
    state.field = { values, max, step };
    state.source = i;
    state.target = null;
    x.view.clearOverlays();
    x.view.setField(values, max, step);
    x.view.addMarker(i, 0xffffff);
    drawColorbar(max, step);
    $('source-index').value = String(i);
    $('path-info').textContent = '';
    status(`Distances from vertex ${i} to all ${values.length} points in ${fmt(ms)} ms (max ${fmt(max)}).`);
    viewer.render();
    flag('heatmap', 'ready');
  } catch (error) {
    showError(error);
    flag('heatmap', 'error');
  } finally {
    setBusy(-1);
  }
}

async function showPath(j) {
  clearMessages();
  let x;
  try {
    x = checkIndex('x', j);
    if (state.source === null) throw new Error('Pick a source first: click a point (or type its index).');
  } catch (error) {
    showError(error);
    return;
  }
  flag('path', 'loading');
  setBusy(1);
  try {
    const source = state.source;
    const { data, ms } = await api('POST', '/paths', {
      json: { shape_id: x.info.shape_id, source, target: j, model: x.info.model },
    });
    state.target = j;
    x.view.clearOverlays();
    x.view.addMarker(source, 0xffffff);
    x.view.addMarker(j, 0xe5291f);
    x.view.setPath(data.points);
    $('target-index').value = String(j);
    const converged = data.converged ? '' : '; the walk did not converge';
    $('path-info').textContent = `Path ${source} → ${j}: length ${fmt(data.length)} input units `
      + `(predicted distance ${fmt(data.predicted_distance)}; ${data.n_steps} steps${converged}) · ${fmt(ms)} ms`;
    status(`Geodesic path from ${source} to ${j} in ${fmt(ms)} ms.`);
    viewer.render();
    flag('path', 'ready');
  } catch (error) {
    showError(error);
    flag('path', 'error');
  } finally {
    setBusy(-1);
  }
}

async function matchLine(slot, vertex) {
  clearMessages();
  const source = state.shapes[slot];
  const target = state.shapes[OTHER[slot]];
  if (!source || !target) {
    corrStatus('Open both shapes to draw matches.');
    return;
  }
  flag('lines', 'loading');
  setBusy(1);
  try {
    const { data, ms } = await api('POST', '/correspondences', {
      json: {
        source_shape_id: source.info.shape_id,
        target_shape_id: target.info.shape_id,
        queries: [vertex],
        return_distance: true,
        model: $('model').value || null,
      },
    });
    const k = data.matches[0];
    const xIndex = slot === 'x' ? vertex : k;
    const colors = state.shapes.x.colors;
    const color = colors
      ? new THREE.Color(colors[xIndex * 3], colors[xIndex * 3 + 1], colors[xIndex * 3 + 2])
      : new THREE.Color(0xe5291f);
    viewer.addLine(source.view.vertexWorld(vertex), target.view.vertexWorld(k), color);
    state.lines += 1;
    const distance = data.distances ? `, predicted distance ${fmt(data.distances[0])}` : '';
    corrStatus(`${slot.toUpperCase()} vertex ${vertex} → ${OTHER[slot].toUpperCase()} vertex ${k}${distance} · ${fmt(ms)} ms`);
    viewer.render();
    flag('lines', String(state.lines));
  } catch (error) {
    showError(error);
    flag('lines', 'error');
  } finally {
    setBusy(-1);
  }
}

function clearPicks() {
  if (state.mode === 'correspondence') {
    viewer.clearLines();
    state.lines = 0;
    corrStatus('');
  } else if (state.shapes.x) {
    state.field = null;
    state.source = null;
    state.target = null;
    state.shapes.x.view.clearOverlays();
    state.shapes.x.view.setNeutral();
    $('colorbar').hidden = true;
    $('path-info').textContent = '';
  }
  status('Cleared.');
  viewer.render();
}

function onPick({ slot, vertex, shift }) {
  if (state.mode === 'correspondence') {
    matchLine(slot, vertex);
  } else if (slot === 'x') {
    if (shift && state.source !== null) showPath(vertex);
    else showDistances(vertex);
  }
}

// ------------------------------------------------------------------ wiring

function wireFiles() {
  for (const slot of ['x', 'y']) {
    $(`file-${slot}`).addEventListener('change', (event) => {
      const file = event.target.files[0];
      if (file) loadShape(slot, file, file.name);
      event.target.value = '';
    });
    $(`open-example-${slot}`).addEventListener('click', () => openExample(slot));
  }
  const view = $('view');
  const overlay = $('drop-overlay');
  let half = 'x';
  const slotAt = (event) => {
    if (!state.shapes.x) return 'x';
    const rect = view.getBoundingClientRect();
    return event.clientX - rect.left > rect.width / 2 ? 'y' : 'x';
  };
  view.addEventListener('dragover', (event) => {
    if (!event.dataTransfer || ![...event.dataTransfer.types].includes('Files')) return;
    event.preventDefault();
    overlay.hidden = false;
    overlay.classList.toggle('single', !state.shapes.x);
    half = slotAt(event);
    for (const el of overlay.children) el.classList.toggle('active', el.dataset.slot === half);
  });
  view.addEventListener('dragleave', (event) => {
    if (!view.contains(event.relatedTarget)) overlay.hidden = true;
  });
  view.addEventListener('drop', (event) => {
    event.preventDefault();
    overlay.hidden = true;
    const file = event.dataTransfer.files[0];
    if (file) loadShape(slotAt(event), file, file.name);
  });
}

function wireControls() {
  for (const radio of document.querySelectorAll('input[name="mode"]')) {
    radio.addEventListener('change', () => radio.checked && setMode(radio.value));
  }
  $('reset-view').addEventListener('click', () => viewer.resetView());
  $('clear').addEventListener('click', clearPicks);
  $('show-distances').addEventListener('click', () => showDistances(Number($('source-index').value)));
  $('show-path').addEventListener('click', () => showPath(Number($('target-index').value)));
  $('source-index').addEventListener('keydown', (e) => e.key === 'Enter' && showDistances(Number(e.target.value)));
  $('target-index').addEventListener('keydown', (e) => e.key === 'Enter' && showPath(Number(e.target.value)));
  $('isolines').addEventListener('change', (event) => setIsolines(event.target.checked));
  $('swap').addEventListener('click', async () => {
    if (!state.shapes.x || !state.shapes.y) return;
    clearMessages();
    [state.shapes.x, state.shapes.y] = [state.shapes.y, state.shapes.x];
    for (const s of Object.values(state.shapes)) s.colors = null;
    state.field = null;
    state.source = null;
    state.transfer = null;
    viewer.swap();
    renderInfo('x');
    renderInfo('y');
    await setMode(state.mode);
  });
  $('api-key').value = getApiKey();
  $('api-key').addEventListener('change', (event) => setApiKey(event.target.value.trim()));
  $('model').addEventListener('change', () => {
    state.transfer = null;
  });
  const help = $('help');
  const toggleHelp = (show = help.hidden) => {
    help.hidden = !show;
    $('help-button').setAttribute('aria-expanded', String(show));
  };
  $('help-button').addEventListener('click', () => toggleHelp());
  document.addEventListener('keydown', (event) => {
    if (event.ctrlKey || event.metaKey || event.altKey) return;
    const tag = event.target.tagName;
    if (tag === 'INPUT' || tag === 'SELECT' || tag === 'TEXTAREA') return;
    switch (event.key) {
      case 'r':
      case 'R':
        viewer.resetView();
        break;
      case 'm':
      case 'M':
        setMode(state.mode === 'distances' ? 'correspondence' : 'distances');
        break;
      case 'i':
      case 'I':
        $('isolines').checked = !state.isolines;
        setIsolines(!state.isolines);
        break;
      case 'c':
      case 'C':
        clearPicks();
        break;
      case '?':
        toggleHelp();
        break;
      case 'Escape':
        toggleHelp(false);
        break;
      default:
        return;
    }
    event.preventDefault();
  });
}

function setIsolines(on) {
  state.isolines = on;
  for (const shape of Object.values(state.shapes)) shape?.view.setIsolines(on);
  if (state.field && state.mode === 'distances') drawColorbar(state.field.max, state.field.step);
  viewer.render();
}

function fillSelect(select, options) {
  select.replaceChildren(...options.map(([value, text]) => {
    const option = document.createElement('option');
    option.value = value;
    option.textContent = text;
    return option;
  }));
}

async function loadCatalogue() {
  const [version, examples] = await Promise.allSettled([
    api('GET', '/version'),
    api('GET', '/viewer/examples'),
  ]);
  if (version.status === 'fulfilled') {
    const { data } = version.value;
    state.models = data.models || [];
    state.defaultModel = data.settings?.default_model || state.models[0] || null;
    const current = $('model').value;
    fillSelect($('model'), [['', `service default${state.defaultModel ? ` (${state.defaultModel})` : ''}`], ...state.models.map((m) => [m, m])]);
    $('model').value = state.models.includes(current) ? current : '';
    $('server-status').textContent = `LiteGE ${data.version} · models: ${state.models.join(', ')}`;
  } else {
    $('server-status').textContent = 'service unreachable';
    showError(version.reason);
  }
  if (examples.status === 'fulfilled') {
    state.examples = examples.value.data.examples || [];
    const options = state.examples.map((e) => [e.name, e.label]);
    fillSelect($('example-x'), options);
    fillSelect($('example-y'), options);
    if (state.examples.length > 1) $('example-y').selectedIndex = 1;
  } else {
    showError(examples.reason);
  }
  flag('catalogue', 'ready');
}

async function init() {
  const started = performance.now();
  viewer = new Viewer3D($('canvas'), { onPick });
  window.litegeViewer.webglInitMs = performance.now() - started; // context + first frame
  onRequest(logRequest);
  wireFiles();
  wireControls();
  await setMode('distances');
  // usable now (upload, drop); the model and example lists follow
  window.litegeViewer.readyMs = performance.now();
  flag('ready', 'true');
  await loadCatalogue();
}

window.litegeViewer = {
  state,
  get viewer() {
    return viewer;
  },
  screenOf: (slot, vertex) => viewer.screenOf(slot, vertex),
  isVisible: (slot, vertex) => viewer.isVisible(slot, vertex),
  pixelAt: (x, y) => viewer.pixelAt(x, y),
  canvasStats: () => viewer.canvasStats(),
  /** Visible vertices of a slot's shape with their field value and pixel colour. */
  probe(slot = 'x', count = 300) {
    const shape = state.shapes[slot];
    const out = [];
    if (!shape) return out;
    const rect = $('canvas').getBoundingClientRect();
    const stride = Math.max(1, Math.floor(shape.view.n / count));
    for (let i = 0; i < shape.view.n; i += stride) {
      const { x, y } = viewer.screenOf(slot, i);
      if (x < rect.left + 2 || y < rect.top + 2 || x > rect.right - 2 || y > rect.bottom - 2) continue;
      if (!viewer.isVisible(slot, i)) continue;
      out.push({ vertex: i, value: state.field ? state.field.values[i] : null, x, y, rgb: viewer.pixelAt(x, y) });
    }
    return out;
  },
};

init().catch((error) => {
  showError(error);
  flag('ready', 'error');
});
