// REST client of the viewer: every call is timed, logged, and errors carry the RFC 9457
// problem details (type, title, status, detail, code) the service returns.

export class ApiError extends Error {
  constructor(method, path, status, problem) {
    const title = problem.title || (status ? `HTTP ${status}` : 'Network error');
    const detail = problem.detail || '';
    super(`${method} ${path} failed: ${status || ''} ${title}${detail && detail !== title ? ` — ${detail}` : ''}`.replace('  ', ' '));
    this.method = method;
    this.path = path;
    this.status = status;
    this.problem = problem;
    this.code = problem.code || null;
  }
}

const listeners = [];

/** Register ``fn({method, path, status, ms, ok})``, called after every request. */
export function onRequest(fn) {
  listeners.push(fn);
}

function apiKey() {
  try {
    return sessionStorage.getItem('litege-api-key') || '';
  } catch {
    return '';
  }
}

export function setApiKey(key) {
  try {
    if (key) sessionStorage.setItem('litege-api-key', key);
    else sessionStorage.removeItem('litege-api-key');
  } catch {
    // storage unavailable (private mode): the key is simply not kept
  }
}

export function getApiKey() {
  return apiKey();
}

async function readProblem(response) {
  const type = response.headers.get('content-type') || '';
  try {
    if (type.includes('json')) return await response.json();
    const text = await response.text();
    return { title: response.statusText, detail: text.slice(0, 500) };
  } catch {
    return { title: response.statusText };
  }
}

/**
 * Call the service. ``json``: a body sent as JSON; ``form``: a FormData; ``binary``: read the
 * answer as an ArrayBuffer (else JSON). Resolves ``{data, response, ms}``; rejects ApiError.
 */
export async function api(method, path, { json, form, binary = false, accept } = {}) {
  const headers = {};
  const key = apiKey();
  if (key) headers['X-API-Key'] = key;
  let body;
  if (json !== undefined) {
    headers['Content-Type'] = 'application/json';
    body = JSON.stringify(json);
  } else if (form) {
    body = form;
  }
  if (accept) headers.Accept = accept;
  const started = performance.now();
  const logPath = path.split('?')[0];
  let response;
  try {
    response = await fetch(path, { method, headers, body });
  } catch (error) {
    const ms = performance.now() - started;
    listeners.forEach((fn) => fn({ method, path: logPath, status: 0, ms, ok: false }));
    throw new ApiError(method, logPath, 0, { title: 'Network error', detail: String(error.message || error) });
  }
  if (!response.ok) {
    const problem = await readProblem(response);
    const ms = performance.now() - started;
    listeners.forEach((fn) => fn({ method, path: logPath, status: response.status, ms, ok: false }));
    throw new ApiError(method, logPath, response.status, problem);
  }
  const data = binary ? await response.arrayBuffer() : await response.json();
  const ms = performance.now() - started;
  listeners.forEach((fn) => fn({ method, path: logPath, status: response.status, ms, ok: true }));
  return { data, response, ms };
}
