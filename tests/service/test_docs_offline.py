"""``/docs`` works offline: Swagger UI is served from the service's own files
(``service/static/docs/``, copied from the pinned swagger-ui-dist by ``make viewer``), never
from a CDN.

Against a real server: the page names no other host and every file it loads answers 200; then
headless Chromium (playwright-core from ``viewer/node_modules``, the system's Chromium) opens
``/docs`` with every request to another host refused, and the API's operations must render.
Needs the built assets (and node + Chromium for the browser test): skipped with the reason
when they are missing, except under ``CI=true``, where it fails (``make test`` builds them,
``.ci/run`` installs Chromium).
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path
from urllib.parse import urlsplit

import httpx
import pytest

from service import app as app_module

REPO = Path(__file__).resolve().parents[2]
CHROMIUM = os.environ.get("LITEGE_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
IN_CI = os.environ.get("CI", "").lower() in ("1", "true", "yes")

BROWSER_SCRIPT = r"""
import { createRequire } from 'node:module';
const [url, chromiumPath, packageJson] = process.argv.slice(1);
const { chromium } = createRequire(packageJson)('playwright-core');
const browser = await chromium.launch({
  executablePath: chromiumPath,
  headless: true,
  args: ['--no-sandbox', '--disable-background-networking', '--disable-component-update',
         '--no-first-run', '--disable-sync', '--disable-quic'],
});
const result = { served: [], refused: [], errors: [] };
try {
  const page = await browser.newPage();
  const origin = new URL(url).origin;
  await page.route('**/*', (route) => {
    const asked = route.request().url();
    if (asked.startsWith(`${origin}/`)) {
      result.served.push(asked.slice(origin.length));
      return route.continue();
    }
    result.refused.push(asked);
    return route.abort('internetdisconnected');
  });
  page.on('pageerror', (error) => result.errors.push(String(error)));
  await page.goto(`${url}/docs`);
  await page.waitForSelector('.swagger-ui .info .title', { timeout: 30000 });
  await page.waitForSelector('.opblock-summary-path', { timeout: 30000 });
  result.title = (await page.textContent('.swagger-ui .info .title')).trim();
  result.paths = await page.$$eval('.opblock-summary-path', (nodes) =>
    nodes.map((node) => node.getAttribute('data-path') || node.textContent.trim()));
} finally {
  await browser.close();
}
console.log(JSON.stringify(result));
"""


def _need(missing: list[str], what: str) -> None:
    if missing:
        reason = f"{what} needs: " + "; ".join(missing)
        if IN_CI:
            pytest.fail(reason, pytrace=False)
        pytest.skip(reason)


@pytest.fixture(scope="module")
def docs_built() -> None:
    if not (app_module.DOCS_DIR / "swagger-ui-bundle.js").is_file():
        _need(["Swagger UI's files in service/static/docs/ (run: make viewer)"], "/docs")


@pytest.fixture(scope="module")
def base_url(live_service_factory, docs_built) -> str:
    return live_service_factory().base_url


def _references(html: str) -> list[str]:
    """Every URL the page loads: src/href attributes and Swagger UI's ``url:`` option."""
    found = re.findall(r"""(?:src|href)\s*=\s*["']([^"']+)["']""", html)
    found += re.findall(r"""\burl\s*:\s*["']([^"']+)["']""", html)
    return found


def test_docs_page_names_no_other_host(base_url):
    response = httpx.get(f"{base_url}/docs", timeout=30)
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/html")
    html = response.text
    assert "SwaggerUIBundle" in html
    assert not re.search(r"(?i)(https?:)?//[a-z0-9.-]+\.[a-z]{2,}", html), "an external URL"
    references = _references(html)
    assert len(references) >= 4  # stylesheet, favicon, script, OpenAPI document
    for reference in references:
        parts = urlsplit(reference)
        assert not parts.scheme and not parts.netloc and reference.startswith("/"), reference


def test_every_file_the_page_loads_answers(base_url):
    html = httpx.get(f"{base_url}/docs", timeout=30).text
    expected_types = {".js": "javascript", ".css": "text/css", ".png": "image/png"}
    for reference in _references(html):
        response = httpx.get(f"{base_url}{reference}", timeout=30)
        assert response.status_code == 200, reference
        suffix = Path(urlsplit(reference).path).suffix
        if suffix in expected_types:
            assert expected_types[suffix] in response.headers["content-type"], reference
            assert len(response.content) > 100, reference
    bundle = httpx.get(f"{base_url}/docs/assets/swagger-ui-bundle.js", timeout=30).text
    assert "SwaggerUIBundle" in bundle
    schema = httpx.get(f"{base_url}/openapi.json", timeout=30).json()
    assert schema["info"]["title"] == "LiteGE" and "/geodesic" in schema["paths"]
    assert "/docs" not in schema["paths"]  # the page is not an API operation


def test_the_pinned_version_and_its_licence_ship_with_it(base_url):
    package = json.loads((REPO / "viewer" / "package.json").read_text())
    pinned = package["devDependencies"]["swagger-ui-dist"]
    assert re.fullmatch(r"\d+\.\d+\.\d+", pinned), "swagger-ui-dist must be pinned exactly"
    version = httpx.get(f"{base_url}/docs/assets/VERSION.txt", timeout=30)
    assert version.text.strip() == f"swagger-ui-dist {pinned}"
    licence = httpx.get(f"{base_url}/docs/assets/LICENSE.txt", timeout=30)
    assert licence.status_code == 200 and "Apache License" in licence.text


@pytest.mark.parametrize(
    "path",
    [
        "/redoc",  # off: it would load its script and fonts from CDNs
        "/docs/oauth2-redirect",
        "/docs/assets/index.html",
        "/docs/assets/swagger-ui-bundle.js.map",
        "/docs/assets/..%2Fapp.py",
        "/docs/assets/%2E%2E%2F%2E%2E%2Fapp.py",
    ],
)
def test_nothing_else_is_served(base_url, path):
    response = httpx.get(f"{base_url}{path}", timeout=30)
    assert response.status_code == 404, (path, response.status_code)


def test_a_missing_build_says_how_to_make_it(base_url, monkeypatch, tmp_path):
    monkeypatch.setattr(app_module, "DOCS_DIR", tmp_path)
    response = httpx.get(f"{base_url}/docs", timeout=30)
    assert response.status_code == 503
    assert "make viewer" in response.text and 'href="/openapi.json"' in response.text
    assert httpx.get(f"{base_url}/docs/assets/swagger-ui.css", timeout=30).status_code == 404


def test_swagger_ui_renders_with_every_other_host_refused(base_url):
    missing = []
    if shutil.which("node") is None:
        missing.append("node (Node.js) is not installed")
    if not os.access(CHROMIUM, os.X_OK):
        missing.append(f"Chromium is not installed at {CHROMIUM} (apt-get install -y chromium)")
    if not (REPO / "viewer" / "node_modules" / "playwright-core").is_dir():
        missing.append("viewer/node_modules is missing (run: make viewer)")
    _need(missing, "the /docs browser test")
    command = ["node", "--input-type=module", "-e", BROWSER_SCRIPT, base_url, CHROMIUM]
    command.append(str(REPO / "viewer" / "package.json"))
    done = subprocess.run(command, capture_output=True, text=True, timeout=150, check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    result = json.loads(done.stdout.strip().splitlines()[-1])
    assert result["refused"] == [], result
    assert result["errors"] == [], result
    assert result["title"].startswith("LiteGE"), result
    assert {"/shapes", "/geodesic", "/paths", "/correspondences"} <= set(result["paths"]), result
    assert "/docs/assets/swagger-ui-bundle.js" in result["served"], result
