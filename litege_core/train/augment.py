"""Views of a training shape: the clean mesh and augmented inputs like those users send.

A *view* is what a user could send for one shape (a point cloud in the user's frame) together
with the rigid motion that relates the user's frame to the dataset's raw frame. The targets
live on the clean mesh: its vertices are moved by the same motion and then canonicalized with
the view's transform, so the network learns distances on the mesh *as seen through the view's
canonical frame* (spec §1.2, §3.3, §7.2).

* view 0 (``clean``): ``clean_samples`` area-weighted samples of the mesh, no rotation — what
  :func:`litege_core.learned.describe.describe_shape` does with a mesh;
* augmented views: ``n`` area-weighted samples (``log n`` uniform in ``[min_points,
  max_points]``), optionally a part cut away by two planes, optionally Gaussian noise of
  ``σ·√area`` (σ in unit-area units), optionally a uniform random rotation of everything.
  Corruptions are applied to the cloud before canonicalization and before the UDF. With
  ``frame_jitter_degrees`` the view also carries a small rotation that turns its canonical
  frame (:attr:`View.frame`, applied by :func:`litege_core.train.data.build_view_tables`);
  with ``axis_turn_probability`` that frame is also turned by a multiple of a quarter turn
  about the first canonical axis (:func:`axis_turn`).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray

from litege_core.sampling import sample_surface
from litege_core.train.config import AugmentConfig
from litege_core.variants import add_noise, cut_by_planes, random_rotation, small_rotation

CLEAN = 0
AUGMENTED = 1


class View(NamedTuple):
    """One input view of a shape.

    Attributes:
        points: ``(P, 3)`` float64 cloud in the user's frame (raw shape units).
        rotation: ``(3, 3)`` proper rotation taking raw coordinates to the user's frame
            (``p_user = R p_raw``); the identity for un-rotated views.
        kind: :data:`CLEAN` or :data:`AUGMENTED`.
        noise_sigma: the noise actually added, raw units (0 for none).
        cut_fraction: the fraction cut away (0 for none).
        frame: ``(3, 3)`` rotation applied after canonicalization (``p_canonical ↦ J
            p_canonical``; frame jitter and axis turns), ``None`` for none.
    """

    points: NDArray
    rotation: NDArray
    kind: int
    noise_sigma: float
    cut_fraction: float
    frame: NDArray | None = None


def axis_turn(quarters: int) -> NDArray:
    """``(3, 3)`` rotation by ``quarters`` quarter turns about the first axis (exact
    integers): ``(x, y, z) ↦ (x, y cos θ − z sin θ, y sin θ + z cos θ)``, ``θ = quarters·90°``."""
    cos, sin = ((1, 0), (0, 1), (-1, 0), (0, -1))[quarters % 4]
    return np.array([[1.0, 0.0, 0.0], [0.0, cos, -sin], [0.0, sin, cos]])


def clean_view(vertices: NDArray, faces: NDArray, n_samples: int, rng: np.random.Generator) -> View:
    """The clean view: ``n_samples`` area-weighted samples, raw frame."""
    points = sample_surface(vertices, faces, n_samples, rng).points
    return View(points, np.eye(3), CLEAN, 0.0, 0.0)


def augmented_view(
    vertices: NDArray,
    faces: NDArray,
    area: float,
    settings: AugmentConfig,
    rng: np.random.Generator,
) -> View:
    """An augmented view (see the module docstring).

    Args:
        vertices: ``(V, 3)`` raw mesh vertices.
        faces: ``(F, 3)`` triangles.
        area: surface area of the mesh, raw units² (sets the noise scale ``σ·√area``).
        settings: the ``[augment]`` table.
        rng: the view's random stream (every draw comes from it, in a fixed order).
    """
    log_n = rng.uniform(math.log(settings.min_points), math.log(settings.max_points))
    n_points = round(math.exp(log_n))
    points = sample_surface(vertices, faces, n_points, rng).points
    cut = 0.0
    if rng.random() < settings.cut_probability:
        cut = float(rng.uniform(settings.cut_min, settings.cut_max))
        kept = points[cut_by_planes(points, cut, rng)]
        points = kept if kept.shape[0] >= 4 else points
    sigma = 0.0
    if rng.random() < settings.noise_probability and settings.noise_sigma > 0:
        sigma = settings.noise_sigma * math.sqrt(area)
        points = add_noise(points, sigma, rng)
    rotation = random_rotation(rng) if settings.rotate else np.eye(3)
    frame = None  # drawn last: views without jitter keep their streams
    if settings.frame_jitter_degrees > 0:
        frame = small_rotation(math.radians(settings.frame_jitter_degrees), rng)
    if settings.axis_turn_probability > 0 and rng.random() < settings.axis_turn_probability:
        turn = axis_turn(int(rng.integers(1, 4)))
        frame = turn if frame is None else turn @ frame
    return View(points @ rotation.T, rotation, AUGMENTED, sigma, cut, frame)


__all__ = ["AUGMENTED", "CLEAN", "View", "augmented_view", "axis_turn", "clean_view"]
