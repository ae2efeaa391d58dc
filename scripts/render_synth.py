"""Render the synthetic templates and samples of every family to PNG, and print statistics.

Offscreen, dependency-free: an orthographic numpy z-buffer rasterizer with flat two-sided
shading, written to PNG with zlib. Usage::

    .venv/bin/python scripts/render_synth.py --out /tmp/synth [--samples 6] [--stats 200]

Writes ``templates.png`` (side, front and top views of both templates, skinning-weight
colours), ``<category>_<family>.png`` (a grid of random samples, side views) and
``poses_<category>.png`` (each pose mode), and prints mesh statistics.
"""

from __future__ import annotations

import argparse
import struct
import sys
import time
import zlib
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

VIEWS = {
    # name: (direction towards the viewer, up)
    "side": (np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
    "front": (np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0])),
    "top": (np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, -1.0])),
    "three_quarter": (np.array([0.8, 0.35, 0.5]), np.array([0.0, 1.0, 0.0])),
}


def rasterize(
    vertices: NDArray,
    faces: NDArray,
    view: str = "side",
    size: tuple[int, int] = (320, 240),
    colors: NDArray | None = None,
    wire: bool = False,
) -> NDArray:
    """Render a mesh to an ``(H, W, 3)`` uint8 image, fitted to the frame.

    Args:
        vertices: ``(V, 3)``; faces: ``(F, 3)``.
        view: a key of ``VIEWS``.
        size: ``(width, height)`` in pixels.
        colors: optional ``(V, 3)`` per-vertex RGB in [0, 1] (averaged per face).
        wire: darken pixels near triangle edges (shows the triangulation).
    """
    width, height = size
    towards, up = VIEWS[view]
    towards = towards / np.linalg.norm(towards)
    up = up - (up @ towards) * towards
    up /= np.linalg.norm(up)
    right = np.cross(up, towards)
    uv = np.stack([vertices @ right, vertices @ up], axis=1)
    depth = -(vertices @ towards)  # smaller is nearer
    used = np.unique(faces)
    lo, hi = uv[used].min(axis=0), uv[used].max(axis=0)
    scale = 0.92 * min(width / max(hi[0] - lo[0], 1e-9), height / max(hi[1] - lo[1], 1e-9))
    center = 0.5 * (lo + hi)
    px = (uv[:, 0] - center[0]) * scale + width / 2
    py = height / 2 - (uv[:, 1] - center[1]) * scale
    tri = vertices[faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-15)
    light = np.array([0.4, 0.7, 0.6]) * 0.5 + towards * 0.5
    light /= np.linalg.norm(light)
    shade = 0.25 + 0.75 * np.abs(normal @ light)
    base = np.full((len(faces), 3), (0.85, 0.72, 0.55)) if colors is None else colors[faces].mean(1)
    face_rgb = np.clip(base * shade[:, None], 0, 1)
    image = np.ones((height, width, 3))
    zbuf = np.full((height, width), np.inf)
    fx, fy, fz = px[faces], py[faces], depth[faces]
    x0 = np.clip(np.floor(fx.min(1)).astype(int), 0, width - 1)
    x1 = np.clip(np.ceil(fx.max(1)).astype(int), 0, width - 1)
    y0 = np.clip(np.floor(fy.min(1)).astype(int), 0, height - 1)
    y1 = np.clip(np.ceil(fy.max(1)).astype(int), 0, height - 1)
    for i in range(len(faces)):
        xs = np.arange(x0[i], x1[i] + 1) + 0.5
        ys = np.arange(y0[i], y1[i] + 1) + 0.5
        gx, gy = np.meshgrid(xs, ys)
        ax, bx, cx = fx[i]
        ay, by, cy = fy[i]
        det = (bx - ax) * (cy - ay) - (cx - ax) * (by - ay)
        if abs(det) < 1e-12:
            continue
        w1 = ((gx - ax) * (cy - ay) - (cx - ax) * (gy - ay)) / det
        w2 = ((bx - ax) * (gy - ay) - (gx - ax) * (by - ay)) / det
        w0 = 1.0 - w1 - w2
        inside = (w0 >= -1e-6) & (w1 >= -1e-6) & (w2 >= -1e-6)
        if not inside.any():
            continue
        z = w0 * fz[i, 0] + w1 * fz[i, 1] + w2 * fz[i, 2]
        sub = zbuf[y0[i] : y1[i] + 1, x0[i] : x1[i] + 1]
        win = inside & (z < sub)
        sub[win] = z[win]
        color = face_rgb[i]
        if wire:
            edge = np.minimum(np.minimum(w0, w1), w2) < 0.06
            patch = np.where(edge[..., None], color * 0.55, color)
        else:
            patch = np.broadcast_to(color, (*z.shape, 3))
        image[y0[i] : y1[i] + 1, x0[i] : x1[i] + 1][win] = patch[win]
    return (image * 255).astype(np.uint8)


def save_png(path: Path, image: NDArray) -> None:
    """Write an ``(H, W, 3)`` uint8 image as PNG."""
    height, width, _ = image.shape
    raw = b"".join(b"\x00" + image[y].tobytes() for y in range(height))

    def chunk(tag: bytes, data: bytes) -> bytes:
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    Path(path).write_bytes(png)


def tile(images: list[NDArray], columns: int) -> NDArray:
    """Arrange equally sized images in a grid with 4-pixel grey gutters."""
    h, w, _ = images[0].shape
    rows = (len(images) + columns - 1) // columns
    canvas = np.full((rows * (h + 4) + 4, columns * (w + 4) + 4, 3), 160, dtype=np.uint8)
    for k, img in enumerate(images):
        r, c = divmod(k, columns)
        canvas[4 + r * (h + 4) : 4 + r * (h + 4) + h, 4 + c * (w + 4) : 4 + c * (w + 4) + w] = img
    return canvas


def weight_colors(weights: NDArray, seed: int = 3) -> NDArray:
    """``(V, 3)`` colours blending a random colour per bone by the skinning weights."""
    rng = np.random.default_rng(seed)
    palette = 0.25 + 0.75 * rng.random((weights.shape[1], 3))
    return np.asarray(weights @ palette)


def main(argv: list[str] | None = None) -> int:
    from litege_core import synth
    from litege_core.synth import quality

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("/tmp/synth"))
    parser.add_argument("--samples", type=int, default=6, help="samples per family grid")
    parser.add_argument("--stats", type=int, default=200, help="samples for intersection stats")
    parser.add_argument("--size", type=int, default=300, help="tile width in pixels")
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    size = (args.size, int(args.size * 0.75))

    tiles = []
    for category in synth.CATEGORIES:
        tmpl = synth.template(category)
        colors = weight_colors(tmpl.weights)
        for view in ("side", "front", "top", "three_quarter"):
            tiles.append(rasterize(tmpl.vertices, tmpl.faces, view, size, colors, wire=True))
        report = quality.mesh_report(tmpl.vertices, tmpl.faces)
        print(f"template {category}: " + ", ".join(f"{k}={v}" for k, v in report.items()))
        sym_err = np.abs(tmpl.vertices[tmpl.symmetry] * (-1, 1, 1) - tmpl.vertices).max()
        print(f"  symmetry max error {sym_err:.2e}; joints {tmpl.skeleton.n_joints}")
    save_png(args.out / "templates.png", tile(tiles, 4))

    for category in synth.CATEGORIES:
        for family in synth.families(category):
            images, extents = [], []
            for seed in range(args.samples):
                shape = synth.generate_shape(category, family, seed)
                images.append(rasterize(shape.vertices, shape.faces, "side", size))
                v = quality.unit_area(shape.vertices, shape.faces)
                extents.append(v.max(0) - v.min(0))
            save_png(args.out / f"{category}_{family}.png", tile(images, 3))
            ext = np.mean(extents, axis=0)
            print(f"{category}/{family}: mean extent after unit-area scaling (x, y, z) = {ext}")
        poses = synth.pose_modes(category)
        images = []
        for mode in poses:
            for seed in range(3):
                shape = synth.generate_shape(
                    category, synth.families(category)[seed % 2], seed, pose=mode
                )
                images.append(rasterize(shape.vertices, shape.faces, "three_quarter", size))
        save_png(args.out / f"poses_{category}.png", tile(images, 3))

    for category in synth.CATEGORIES:
        start = time.perf_counter()
        raw = kept = total = redraws = 0
        per_family = max(1, args.stats // len(synth.families(category)))
        for family in synth.families(category):
            for seed in range(per_family):
                first = synth.generate_shape(category, family, 10_000 + seed, reject=False)
                raw += bool(quality.self_intersects(first.vertices, first.faces))
                shape = synth.generate_shape(category, family, 10_000 + seed)
                kept += bool(quality.self_intersects(shape.vertices, shape.faces))
                redraws += int(shape.params["pose_attempts"]) - 1
                total += 1
        elapsed = time.perf_counter() - start
        print(
            f"{category}: self-intersecting {raw}/{total} ({100.0 * raw / total:.1f} %) "
            f"before rejection, {kept}/{total} ({100.0 * kept / total:.1f} %) after "
            f"({redraws} redraws); {elapsed / total * 1000:.0f} ms per sample pair"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
