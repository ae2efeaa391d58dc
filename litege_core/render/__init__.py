"""Offscreen rendering to PNG (pure numpy + Pillow, no OpenGL, no display).

* :mod:`~litege_core.render.colormap` — viridis, normalization, isoline levels and detection,
  coordinate colourings for correspondences.
* :mod:`~litege_core.render.raster` — orthographic camera, z-buffered triangle and point
  rasterization, Lambert shading, polyline overlays with a depth test.
* :mod:`~litege_core.render.figures` — heatmap (isolines, path, colour bar) and side-by-side
  correspondence figures as Pillow images.

Used by ``litege render`` and ``litege render-match``.
"""

from litege_core.render.colormap import (
    VIRIDIS,
    coordinate_colors,
    isoline_mask,
    nice_step,
    nice_ticks,
    normalize,
    viridis,
)
from litege_core.render.raster import Camera, Fragments, fit_camera, rasterize_mesh

__all__ = [
    "VIRIDIS",
    "Camera",
    "Fragments",
    "coordinate_colors",
    "fit_camera",
    "isoline_mask",
    "nice_step",
    "nice_ticks",
    "normalize",
    "rasterize_mesh",
    "viridis",
]
