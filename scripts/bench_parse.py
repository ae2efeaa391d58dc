"""Memory and time of parsing shape files (issue 13, item 3), before and after.

For each format a file is written from a subdivided icosphere (``--subdivisions``, default 6:
40,962 vertices, 81,920 triangles) and loaded with :func:`litege_core.io.load_shape` from its
bytes. Measured per file:

* peak traced memory (``tracemalloc``: Python objects and numpy buffers) while loading, in MB
  and per MB of file;
* growth of the peak resident set size while loading (Linux ``VmHWM``, reset just before the
  load through ``/proc/self/clear_refs``), in a fresh process per file and implementation,
  imports and the file's bytes already in memory: what a server pays, allocator overhead
  included;
* wall time (best of ``--runs``, tracemalloc off), in ms and per MB of file.

Hostile files show what the header-first checks buy: an ASCII PLY whose header declares more
vertices than the limit (1.2 M, the limit is 250 K; the data is there), an ``.npy`` header
declaring ``(10^12, 3)``, and a GLB of ``--glb-nodes`` nodes each instancing one triangle.
Their rows give the error the loader ends with.

"before" is ``litege_core/io.py`` of git revision ``--before`` (default: the commit before the
typed readers, ``893cd97~1``), imported
as a separate module from ``git show``; "after" is the working tree. ``same`` says whether both
gave identical vertices and faces. Prints a markdown table with the machine and the date.

Usage:
    python scripts/bench_parse.py [--before REV] [--subdivisions 6] [--runs 3]
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import platform
import struct
import subprocess
import sys
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from datetime import date
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import trimesh

import litege_core.io as after_io
from litege_core.errors import LiteGEError

ROOT = Path(__file__).resolve().parents[1]


def machine() -> str:
    """CPU model (Linux) or the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def module_at(revision: str) -> ModuleType:
    """``litege_core/io.py`` of a git revision, imported as ``litege_io_<revision>``."""
    source = subprocess.run(
        ["git", "show", f"{revision}:litege_core/io.py"],
        cwd=ROOT,
        check=True,
        capture_output=True,
    ).stdout
    path = Path(tempfile.mkdtemp()) / "io_before.py"
    path.write_bytes(source)
    spec = importlib.util.spec_from_file_location("litege_io_before", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["litege_io_before"] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def text(data: str | bytes) -> bytes:
    return data.encode() if isinstance(data, str) else data


def files(subdivisions: int, glb_nodes: int) -> dict[str, tuple[str, bytes]]:
    """``{label: (format, bytes)}`` of the measured files."""
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    vertices = np.asarray(sphere.vertices)
    mesh = trimesh.Trimesh(vertices, sphere.faces, process=False)
    out: dict[str, tuple[str, bytes]] = {
        "OBJ": ("obj", text(mesh.export(file_type="obj", digits=17))),
        "OFF": ("off", text(mesh.export(file_type="off", digits=17))),
        "PLY ascii": ("ply", text(mesh.export(file_type="ply", encoding="ascii"))),
        "PLY binary": ("ply", text(mesh.export(file_type="ply"))),
        "STL binary": ("stl", text(mesh.export(file_type="stl"))),
        "GLB": ("glb", text(mesh.export(file_type="glb"))),
        "PLY ascii cloud": (
            "ply",
            text(trimesh.PointCloud(vertices).export(file_type="ply", encoding="ascii")),
        ),
    }
    buffer = io.BytesIO()
    np.savetxt(buffer, vertices, fmt="%.17g")
    out["XYZ (17 digits)"] = ("xyz", buffer.getvalue())
    buffer = io.BytesIO()
    np.savetxt(buffer, vertices, fmt="%.6f")
    out["XYZ (%.6f)"] = ("xyz", buffer.getvalue())
    buffer = io.BytesIO()
    np.save(buffer, vertices)
    out["NPY"] = ("npy", buffer.getvalue())
    # hostile files
    rng = np.random.default_rng(0)
    big = rng.normal(size=(1_200_000, 3)).astype(np.float32)
    buffer = io.BytesIO()
    np.savetxt(buffer, big, fmt="%.5f")
    header = (
        "ply\nformat ascii 1.0\nelement vertex 1200000\n"
        "property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    out["hostile: PLY ascii, 1.2 M vertices"] = ("ply", header.encode() + buffer.getvalue())
    npy_header = "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 3), }"
    npy_header += " " * (63 - (len(npy_header) + 10) % 64) + "\n"
    out["hostile: NPY header (10^12, 3)"] = (
        "npy",
        b"\x93NUMPY\x01\x00" + struct.pack("<H", len(npy_header)) + npy_header.encode() + b"0" * 64,
    )
    out[f"hostile: GLB, {glb_nodes} nodes"] = ("glb", many_node_glb(glb_nodes))
    return out


def many_node_glb(n_nodes: int) -> bytes:
    """A GLB whose ``n_nodes`` nodes all instance one triangle."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], dtype=np.float32).tobytes()
    document = {
        "asset": {"version": "2.0"},
        "buffers": [{"byteLength": len(positions)}],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(positions)}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [1, 1, 0],
            }
        ],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0, "translation": [float(i), 0.0, 0.0]} for i in range(n_nodes)],
        "scenes": [{"nodes": list(range(n_nodes))}],
        "scene": 0,
    }
    chunk = json.dumps(document).encode()
    chunk += b" " * (-len(chunk) % 4)
    binary = positions + b"\x00" * (-len(positions) % 4)
    body = (
        struct.pack("<II", len(chunk), 0x4E4F534A)
        + chunk
        + struct.pack("<II", len(binary), 0x004E4942)
        + binary
    )
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


RSS_PROBE = """
import gc, importlib.util, resource, sys
path, fmt, module_path = sys.argv[1:4]
spec = importlib.util.spec_from_file_location("probe_io", module_path)
module = importlib.util.module_from_spec(spec)
sys.modules["probe_io"] = module  # dataclasses look their module up
spec.loader.exec_module(module)
import trimesh  # noqa
data = open(path, "rb").read()


def status(key):
    for line in open("/proc/self/status"):
        if line.startswith(key):
            return int(line.split()[1])


try:
    module.load_shape(b"v 0 0 0\\nv 1 0 0\\nv 0 1 0\\nf 1 2 3\\n", file_format="obj")
except Exception:
    pass
gc.collect()
with open("/proc/self/clear_refs", "w") as handle:
    handle.write("5")  # peak RSS (VmHWM) := current RSS
start = status("VmRSS:")
try:
    module.load_shape(data, file_format=fmt)
except Exception:
    pass
print(status("VmHWM:") - start)
"""


def rss_growth(module: ModuleType, data: bytes, fmt: str) -> float:
    """Peak RSS growth (MB) of loading ``data`` with ``module`` in a fresh process."""
    with tempfile.NamedTemporaryFile(suffix=f".{fmt}") as handle:
        handle.write(data)
        handle.flush()
        done = subprocess.run(
            [sys.executable, "-c", RSS_PROBE, handle.name, fmt, str(module.__file__)],
            cwd=ROOT,
            check=True,
            capture_output=True,
            text=True,
        )
    return int(done.stdout.split()[-1]) / 1024.0  # /proc/self/status counts KiB


def measure(load: Callable[[], Any], runs: int) -> tuple[float, float, Any]:
    """``(peak traced MB, best seconds, result or the LiteGEError raised)``."""

    def once() -> Any:
        try:
            return load()
        except Exception as exc:  # the row reports whatever the loader raised
            return exc

    tracemalloc.start()
    result = once()
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    best = float("inf")
    for _ in range(runs):
        started = time.perf_counter()
        once()
        best = min(best, time.perf_counter() - started)
    return peak / 1e6, best, result


def outcome(result: Any) -> str:
    if isinstance(result, Exception):
        kind = type(result).__name__
        return kind if isinstance(result, LiteGEError) else f"{kind} (not a LiteGEError: 500)"
    faces = "" if result.faces is None else f", {result.n_faces} F"
    return f"{result.n_points} V{faces}"


def same(a: Any, b: Any) -> str:
    if isinstance(a, Exception) or isinstance(b, Exception):
        return "yes" if type(a) is type(b) else "no"
    if not np.array_equal(a.vertices, b.vertices):
        return "no"
    if (a.faces is None) != (b.faces is None):
        return "no"
    return "yes" if a.faces is None or np.array_equal(a.faces, b.faces) else "no"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument(
        "--before",
        default="893cd97~1",
        help="git revision of 'before' (default: the commit "
        "before the typed readers and header-first checks)",
    )
    parser.add_argument("--subdivisions", type=int, default=6)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--glb-nodes", type=int, default=20_000)
    args = parser.parse_args()
    before_io = module_at(args.before)
    print(
        f"# Parsing memory and time — {date.today()}, {machine()}, Python {sys.version.split()[0]}"
    )
    print(f"numpy {np.__version__}, trimesh {trimesh.__version__}; before = {args.before}\n")
    print(
        "| file | MB | before: traced peak MB (per MB) | after: traced peak MB (per MB) "
        "| before: RSS +MB (per MB) | after: RSS +MB (per MB) "
        "| before: ms (per MB) | after: ms (per MB) | before → after | same |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, (fmt, data) in files(args.subdivisions, args.glb_nodes).items():
        size = len(data) / 1e6
        rows = []
        for module in (before_io, after_io):
            load = lambda m=module, d=data, f=fmt: m.load_shape(d, file_format=f)  # noqa: E731
            rows.append(measure(load, args.runs))
        (peak_b, time_b, res_b), (peak_a, time_a, res_a) = rows
        rss_b, rss_a = (rss_growth(m, data, fmt) for m in (before_io, after_io))
        print(
            f"| {label} | {size:.2f} | {peak_b:.0f} ({peak_b / size:.1f}) "
            f"| {peak_a:.0f} ({peak_a / size:.1f}) "
            f"| {rss_b:.0f} ({rss_b / size:.1f}) | {rss_a:.0f} ({rss_a / size:.1f}) "
            f"| {time_b * 1e3:.0f} ({time_b * 1e3 / size:.0f}) "
            f"| {time_a * 1e3:.0f} ({time_a * 1e3 / size:.0f}) "
            f"| {outcome(res_b)} → {outcome(res_a)} | {same(res_b, res_a)} |",
            flush=True,
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
