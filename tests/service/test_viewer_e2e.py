"""The web viewer end to end in headless Chromium, against a real server.

``viewer_e2e.mjs`` (node + playwright-core from ``viewer/node_modules``, the system's Chromium,
no browser download) opens ``/viewer``, uploads a shape, clicks a vertex, reads the heatmap's
pixels, shift-clicks for a path, tries bad input, loads a second shape for the correspondence
view (served by a tiny matching model), then replays it against a missing endpoint, and
prints what it measured. Screenshots land in ``tests/artifacts/`` (not committed).

Skips with its reason when node, Chromium or the built viewer are missing, except under
``CI=true``, where it fails instead (``make`` builds the viewer, ``.ci/run`` installs Chromium).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh

from litege_core.matching import MatchingModel
from litege_core.synth import generate_shape
from service.viewer import STATIC_DIR

REPO = Path(__file__).resolve().parents[2]
SCRIPT = Path(__file__).with_name("viewer_e2e.mjs")
ARTIFACTS = REPO / "tests" / "artifacts"
CHROMIUM = os.environ.get("LITEGE_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"


def _missing() -> list[str]:
    missing = []
    if shutil.which("node") is None:
        missing.append("node (Node.js) is not installed")
    if not os.access(CHROMIUM, os.X_OK):
        missing.append(f"Chromium is not installed at {CHROMIUM} (apt-get install -y chromium)")
    if not (REPO / "viewer" / "node_modules" / "playwright-core").is_dir():
        missing.append("viewer/node_modules is missing (run: make viewer)")
    if not (STATIC_DIR / "index.html").is_file():
        missing.append("the viewer is not built (run: make viewer)")
    return missing


@pytest.fixture(scope="module")
def browser_tools() -> None:
    missing = _missing()
    if missing:
        reason = "the viewer end-to-end test needs: " + "; ".join(missing)
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(reason, pytrace=False)
        pytest.skip(reason)


def _write_obj(path: Path, family: str) -> Path:
    shape = generate_shape("quadruped", family, 7)
    trimesh.Trimesh(shape.vertices, shape.faces, process=False).export(path)
    return path


def _run(service_url: str, x: Path, y: Path) -> dict:
    ARTIFACTS.mkdir(parents=True, exist_ok=True)
    command = ["node", str(SCRIPT), "--url", service_url, "--x", str(x), "--y", str(y)]
    command += ["--out", str(ARTIFACTS), "--chromium", CHROMIUM]
    done = subprocess.run(
        command, cwd=REPO, capture_output=True, text=True, timeout=150, check=False
    )
    assert done.returncode == 0, done.stderr[-3000:]
    lines = [line for line in done.stdout.splitlines() if line.startswith("{")]
    assert lines, f"no result from the browser script: {done.stdout[-2000:]} {done.stderr[-2000:]}"
    result = json.loads(lines[-1])
    (ARTIFACTS / "viewer-e2e.json").write_text(json.dumps(result, indent=2))
    return result


def _luma(rgb) -> float:
    return float(np.asarray(rgb, dtype=float) @ [0.2126, 0.7152, 0.0722])


def test_viewer_end_to_end(browser_tools, live_service_factory, tmp_path):
    started = time.monotonic()
    service = live_service_factory(matching=MatchingModel.tiny_random(0))
    x = _write_obj(tmp_path / "dog.obj", "dog")
    y = _write_obj(tmp_path / "cat.obj", "cat")
    result = _run(service.base_url, x, y)
    assert "error" not in result, result["error"]
    assert result["steps"][-1] == "narrow", result["steps"]

    # loads fast: the assets and the app are quick; software WebGL (SwiftShader in headless
    # Chromium) spends its own time creating the context, which a GPU browser does not
    assert result["webgl"].startswith("WebGL")
    app_ms = result["loadMs"] - result["webglInitMs"]
    assert app_ms < 1000, result
    assert all(asset["ms"] < 1000 for asset in result["assets"]), result["assets"]
    assert result["exampleCount"] >= 9  # one example per procedural family

    # keyboard: controls come first in tab order, the 3D view is focusable and labelled
    assert result["secondTabStop"] == "help-button"
    assert result["canvasTabIndex"] == "0" and "Arrow keys" in result["canvasLabel"]
    assert result["isolinesAfterI"] is False

    # upload → info panel with the shape id, model and OOD status
    assert result["shapeX"] == "ready"
    assert "shape id" in result["infoX"] and "quadrupeds" in result["infoX"]
    assert "distribution" in result["infoX"]

    # click → heatmap: the clicked vertex is the source, the canvas shows a field
    assert result["heatmap"] == "ready" and result["source"] == result["clicked"]
    assert result["statsHeatmap"]["covered"] > 0.02
    assert result["statsHeatmap"]["distinctColours"] > 3 * result["statsNeutral"]["distinctColours"]
    assert result["colorbarVisible"] and "input units" in result["colorbarText"]

    # colours vary from near to far as viridis does: blue/purple near (b > g), green/yellow
    # far (g > b); shading scales the channels together, so the ratio survives it
    probe = [p for p in result["probe"] if p["value"] is not None and _luma(p["rgb"]) > 25]
    assert len(probe) > 40, len(probe)
    values = np.array([p["value"] for p in probe])
    rgb = np.array([p["rgb"] for p in probe], dtype=float)
    near = rgb[values <= np.quantile(values, 0.2)]
    far = rgb[values >= np.quantile(values, 0.8)]
    assert np.mean(near[:, 2] > near[:, 1]) > 0.7, near
    assert np.mean(far[:, 1] > far[:, 2]) > 0.7, far
    ratio = rgb[:, 1] / (rgb[:, 2] + 1.0)
    assert np.corrcoef(values, ratio)[0, 1] > 0.6

    # shift-click → path drawn, its length reported
    assert result["path"] == "ready" and "length" in result["pathInfo"]

    # errors: a client-side check and the service's problem detail are both shown
    assert "Vertex index must be" in result["badIndexMessage"]
    assert "POST /shapes failed" in result["badUploadMessage"]
    assert "[face-index-out-of-range]" in result["badUploadMessage"]

    # second shape → correspondence view with colours carried to Y, and a match line
    assert result["shapeY"] == "ready" and result["mode"] == "correspondence"
    assert result["correspondence"] == "ready", result["messages"]
    assert "predicted matches" in result["corrStatus"]
    y_colours = {tuple(np.asarray(c) // 16) for c in result["probeY"]}
    assert len(y_colours) > 5  # coloured by the transfer, not the neutral grey
    assert result["lines"] == "1" and "vertex" in result["lineStatus"]

    # a service without POST /correspondences: its problem (404) is shown cleanly
    assert result["missingEndpointMessage"].startswith("×POST /correspondences failed: 404")
    assert "unavailable" in result["missingEndpointStatus"]
    assert result["statsMissingEndpoint"]["covered"] > 0.02  # both shapes still drawn

    # a file dropped on the left half of the view replaces X
    assert result["dropped"] == ["ready", "cow.obj"]

    # narrow window: view and controls stack, both usable
    assert result["narrow"]["canvasWidth"] >= 600 and result["narrow"]["canvasHeight"] >= 300

    # no script errors: only the failed requests the test made on purpose
    unexpected = [e for e in result["consoleErrors"] if "Failed to load resource" not in e]
    assert not unexpected, unexpected
    for name in ("heatmap", "path", "correspondence", "correspondence-missing", "narrow"):
        assert (ARTIFACTS / f"viewer-{name}.png").stat().st_size > 10_000
    assert time.monotonic() - started < 120
