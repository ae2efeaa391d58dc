"""Figures from the rasterizer: a shaded surface with a colour field (scalar through viridis
with isolines, or per-vertex colours), path and marker overlays, a colour bar, titles, and
the side-by-side correspondence figure. Returns Pillow images (``image.save("out.png")``)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from litege_core.errors import MissingDependencyError

try:
    from PIL import Image, ImageDraw, ImageFont
except ImportError as exc:
    raise MissingDependencyError(
        "PNG figures need Pillow: pip install 'litege[render]'", module="PIL"
    ) from exc

from litege_core.render.colormap import isoline_mask, nice_step, nice_ticks, viridis
from litege_core.render.raster import (
    Camera,
    dilate,
    disk_mask,
    fit_camera,
    lambert,
    polyline_masks,
    rasterize_mesh,
    rasterize_points,
)
from litege_core.seams import vertex_normals

BACKGROUND = (1.0, 1.0, 1.0)
NEUTRAL = (0.78, 0.74, 0.68)
PATH_COLOR = (0.90, 0.16, 0.12)
TEXT = (30, 30, 30)


@dataclass(frozen=True)
class Overlay:
    """Polylines and markers drawn over a surface (3D, in the shape's frame).

    Attributes:
        paths: ``(L, 3)`` polylines, each with an RGB colour in [0, 1].
        markers: points, each with an RGB colour in [0, 1].
    """

    paths: Sequence[tuple[NDArray, tuple[float, float, float]]] = field(default_factory=tuple)
    markers: Sequence[tuple[NDArray, tuple[float, float, float]]] = field(default_factory=tuple)


def font(size: int = 14) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's bundled font at ``size`` pixels (no system fonts needed)."""
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: fixed-size bitmap font
        return ImageFont.load_default()


def _point_radius(camera: Camera, points: NDArray) -> float:
    """Splat radius (pixels of ``camera``) from the median nearest-neighbour spacing."""
    from scipy.spatial import cKDTree

    rng = np.random.default_rng(0)
    sample = points if points.shape[0] <= 4000 else points[rng.choice(points.shape[0], 4000)]
    distances, _ = cKDTree(points).query(sample, k=2)
    spacing = float(np.median(distances[:, 1]))
    return float(np.clip(0.75 * spacing * camera.scale, 1.0, 0.02 * camera.width))


def render_surface(
    vertices: ArrayLike,
    faces: ArrayLike | None = None,
    *,
    scalar: ArrayLike | None = None,
    colors: ArrayLike | None = None,
    vmin: float | None = None,
    vmax: float | None = None,
    isoline_step: float | None = None,
    overlay: Overlay | None = None,
    size: tuple[int, int] = (640, 480),
    view: str | ArrayLike = "three_quarter",
    camera: Camera | None = None,
    ssaa: int = 2,
    background: tuple[float, float, float] = BACKGROUND,
    up_axis: int | None = None,
) -> Image.Image:
    """A shaded rendering of a mesh (``faces`` given) or point cloud.

    Args:
        vertices: ``(N, 3)`` points.
        faces: ``(F, 3)`` triangles, or ``None`` for a point cloud (drawn as splats).
        scalar: ``(N,)`` field coloured with viridis over ``[vmin, vmax]`` (default: its
            range), with isolines every ``isoline_step`` (default: ~10 per range; 0: none).
        colors: ``(N, 3)`` RGB in [0, 1] per vertex (ignored when ``scalar`` is given).
        overlay: paths and markers.
        size: ``(W, H)`` of the image; ``view``: a name of
            :data:`~litege_core.render.raster.VIEWS` or a direction towards the viewer;
            ``camera``: an explicit camera of that size (overrides ``view``).
        ssaa: supersampling factor (anti-aliasing).
        up_axis: the shape's up axis (0 = x, 1 = y, 2 = z) the named views turn with;
            default :func:`~litege_core.render.raster.detect_up_axis` (y-up and z-up files).
    """
    points = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    ssaa = max(int(ssaa), 1)
    base_camera = camera or fit_camera(points, size, view, up_axis=up_axis)
    cam = base_camera.scaled(ssaa)
    if faces is not None:
        tris = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        frags = rasterize_mesh(cam, points, tris)
        normals = frags.interpolate(vertex_normals(points, tris), fill=0.0)
    else:
        frags = rasterize_points(cam, points, _point_radius(cam, points))
        assert frags.normals is not None  # point splats always carry normals
        normals = frags.normals
    mask = frags.mask
    diagonal = float(np.linalg.norm(np.ptp(points, axis=0))) or 1.0

    iso = np.zeros(mask.shape, dtype=bool)
    if scalar is not None:
        field_values = np.asarray(scalar, dtype=np.float64).reshape(-1)
        finite = field_values[np.isfinite(field_values)]
        lo = vmin if vmin is not None else (float(finite.min()) if finite.size else 0.0)
        hi = vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0)
        image_values = frags.interpolate(field_values)
        base = viridis(image_values, lo, hi)
        step = nice_step(hi - lo, 10) if isoline_step is None else float(isoline_step)
        if step > 0:
            iso = isoline_mask(
                image_values, step, mask, depth=frags.depth, max_depth_jump=0.03 * diagonal
            )
            iso = dilate(iso, ssaa // 2)
    elif colors is not None:
        base = np.clip(frags.interpolate(np.asarray(colors, dtype=np.float64)), 0.0, 1.0)
    else:
        base = np.broadcast_to(np.asarray(NEUTRAL), (*mask.shape, 3))

    shade = lambert(normals, cam)
    rgb = np.where(mask[..., None], np.nan_to_num(base) * shade[..., None], background)
    rgb = np.where(iso[..., None], rgb * 0.25, rgb)

    overlay = overlay or Overlay()
    for points_3d, color in overlay.paths:
        visible, hidden = polyline_masks(
            cam, frags, points_3d, 3.0 * ssaa, depth_tolerance=0.015 * diagonal
        )
        edge = dilate(visible, max(ssaa // 2, 1)) & ~visible
        rgb = np.where(edge[..., None], np.asarray(color) * 0.35, rgb)
        rgb = np.where(visible[..., None], color, rgb)
        rgb = np.where(hidden[..., None], 0.6 * rgb + 0.4 * np.asarray(color), rgb)
    for point, color in overlay.markers:
        ring = disk_mask(cam, point, 6.0 * ssaa)
        dot = disk_mask(cam, point, 4.0 * ssaa)
        rgb = np.where(ring[..., None], (1.0, 1.0, 1.0), rgb)
        rgb = np.where(dot[..., None], color, rgb)

    image = Image.fromarray(np.clip(rgb * 255.0 + 0.5, 0, 255).astype(np.uint8), "RGB")
    return image.reduce(ssaa) if ssaa > 1 else image


def colorbar(
    height: int,
    vmin: float,
    vmax: float,
    label: str,
    *,
    isoline_step: float | None = None,
    width: int = 96,
) -> Image.Image:
    """A vertical viridis colour bar (``vmin`` at the bottom) with ticks and a label."""
    image = Image.new("RGB", (width, height), (255, 255, 255))
    draw = ImageDraw.Draw(image)
    small = font(12)
    top, bottom, left, bar_w = 28, height - 16, 8, 16
    span = max(bottom - top, 1)
    t = np.linspace(1.0, 0.0, span)
    strip = (viridis(t, 0.0, 1.0) * 255).astype(np.uint8)
    image.paste(Image.fromarray(np.repeat(strip[:, None, :], bar_w, axis=1), "RGB"), (left, top))
    draw.rectangle((left - 1, top - 1, left + bar_w, bottom), outline=(60, 60, 60))
    draw.text((left, 6), label, fill=TEXT, font=small)
    if not vmax > vmin:
        return image
    step = nice_step(vmax - vmin, 10) if isoline_step is None else isoline_step
    if step and step > 0:  # isoline marks
        for level in np.arange(np.ceil(vmin / step) * step, vmax, step):
            y = bottom - (level - vmin) / (vmax - vmin) * span
            draw.line((left, y, left + 4, y), fill=(20, 20, 20))
    for tick in nice_ticks(vmin, vmax, 5):
        y = bottom - (tick - vmin) / (vmax - vmin) * span
        draw.line((left + bar_w, y, left + bar_w + 4, y), fill=(40, 40, 40))
        draw.text((left + bar_w + 7, y - 7), f"{tick:.4g}", fill=TEXT, font=small)
    return image


def titled(image: Image.Image, title: str, subtitle: str = "") -> Image.Image:
    """``image`` with a title band (and an optional smaller subtitle) above it."""
    band = 26 if not subtitle else 44
    out = Image.new("RGB", (image.width, image.height + band), (255, 255, 255))
    out.paste(image, (0, band))
    draw = ImageDraw.Draw(out)
    draw.text((8, 5), title, fill=TEXT, font=font(15))
    if subtitle:
        draw.text((8, 25), subtitle, fill=(90, 90, 90), font=font(12))
    return out


def side_by_side(images: Sequence[Image.Image], gap: int = 8) -> Image.Image:
    """Images in one row on white, top-aligned."""
    width = sum(im.width for im in images) + gap * (len(images) - 1)
    height = max(im.height for im in images)
    out = Image.new("RGB", (width, height), (255, 255, 255))
    x = 0
    for im in images:
        out.paste(im, (x, 0))
        x += im.width + gap
    return out


def heatmap_figure(
    vertices: ArrayLike,
    faces: ArrayLike | None,
    distances: ArrayLike,
    *,
    source_point: ArrayLike | None = None,
    path: ArrayLike | None = None,
    title: str = "",
    subtitle: str = "",
    units: str = "input units",
    size: tuple[int, int] = (640, 480),
    view: str | ArrayLike = "three_quarter",
    ssaa: int = 2,
    up_axis: int | None = None,
) -> Image.Image:
    """Geodesic distance heatmap with isolines, optional source marker and path, and a
    colour bar labelled with ``units``; ``up_axis`` as in :func:`render_surface`."""
    values = np.asarray(distances, dtype=np.float64).reshape(-1)
    finite = values[np.isfinite(values)]
    vmin = 0.0
    vmax = float(finite.max()) if finite.size else 1.0
    step = nice_step(vmax - vmin, 10)
    markers = []
    paths = []
    if path is not None:
        polyline = np.asarray(path, dtype=np.float64).reshape(-1, 3)
        paths.append((polyline, PATH_COLOR))
        markers.append((polyline[0], PATH_COLOR))
        markers.append((polyline[-1], PATH_COLOR))
    if source_point is not None:
        markers.append((np.asarray(source_point, dtype=np.float64), (1.0, 1.0, 1.0)))
    surface = render_surface(
        vertices,
        faces,
        scalar=values,
        vmin=vmin,
        vmax=vmax,
        isoline_step=step,
        overlay=Overlay(paths=paths, markers=markers),
        size=size,
        view=view,
        ssaa=ssaa,
        up_axis=up_axis,
    )
    bar = colorbar(surface.height, vmin, vmax, f"distance ({units})", isoline_step=step, width=130)
    figure = side_by_side([surface, bar], gap=0)
    return titled(figure, title, subtitle) if title else figure


def match_figure(
    x_vertices: ArrayLike,
    x_faces: ArrayLike | None,
    x_colors: ArrayLike,
    y_vertices: ArrayLike,
    y_faces: ArrayLike | None,
    y_colors: ArrayLike,
    *,
    x_title: str = "X",
    y_title: str = "Y",
    title: str = "",
    subtitle: str = "",
    size: tuple[int, int] = (480, 400),
    view: str | ArrayLike = "three_quarter",
    ssaa: int = 2,
    up_axis: int | None = None,
) -> Image.Image:
    """Two shapes side by side, each with its per-vertex colours (colour transfer); each
    shape's up axis is detected on its own unless ``up_axis`` is given."""
    left = render_surface(
        x_vertices, x_faces, colors=x_colors, size=size, view=view, ssaa=ssaa, up_axis=up_axis
    )
    right = render_surface(
        y_vertices, y_faces, colors=y_colors, size=size, view=view, ssaa=ssaa, up_axis=up_axis
    )
    figure = side_by_side([titled(left, x_title), titled(right, y_title)], gap=12)
    return titled(figure, title, subtitle) if title else figure


def parse_size(text: str) -> tuple[int, int]:
    """``"640x480"`` → ``(640, 480)``."""
    try:
        width, height = (int(part) for part in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"size must look like 640x480, got {text!r}") from None
    if not (16 <= width <= 8192 and 16 <= height <= 8192):
        raise ValueError(f"size must be between 16 and 8192 pixels a side, got {text!r}")
    return width, height


__all__ = [
    "BACKGROUND",
    "NEUTRAL",
    "PATH_COLOR",
    "TEXT",
    "Overlay",
    "colorbar",
    "font",
    "heatmap_figure",
    "match_figure",
    "parse_size",
    "render_surface",
    "side_by_side",
    "titled",
]
