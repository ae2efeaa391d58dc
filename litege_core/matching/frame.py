"""The matching pipeline's canonical frame (reference-spec §1.3, §1.4, §1.6).

Every shape is centred and scaled to unit-area units, then rotated by the T-Net:

* watertight-ish mesh → unit area (centre: mean of area-weighted samples, ``s = 1/√area``);
* mesh with many boundary edges (a broken scan) → Poisson-disk spacing of the mesh's samples;
* point cloud → Poisson-disk spacing of the cloud (the 500-point setting for small clouds).

The T-Net sees at most ``n_tnet_points`` points of the scaled cloud (the authors feed 8000 at
test time but trained on 2000, spec §1.6 🐞); its rotation ``R_pred`` right-multiplies the
points, so the frame's :class:`~litege_core.canonical.Transform` has rotation ``R_predᵀ``.

**Candidate frames** (issue 15, step 1). On real animals the T-Net fails in ways its own
inputs reveal: run on the cloud's principal-axis frame turned by each of the 24 cube rotations
(:func:`tnet_turn_runs`, every axis order and sign it was trained to accept), a T-Net that reads
the shape gives one frame 24 times; where it hesitates (a curled cat, a rearing horse) the runs
split. :func:`runs_agree` is that test: the runs split on every T-Net failure of 40 posed
rigged animals, on 12 of the 14 of TOSCA, and on none of 60 held-out procedural quadrupeds
(their only failures, lying animals framed upright, agree and stay). Where the runs split, the
T-Net's frame competes with the 24 principal-axis frames (:func:`pca_candidates`), and
:class:`~litege_core.matching.judge.FrameJudge` (the matching network itself, against canonical
reference animals) keeps one (BENCHMARKS.md ``frame-gate``). Candidates are expressed as turns
``M`` of the T-Net's frame (``q' = M q``); :func:`turned` applies one.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any, Literal

import numpy as np
import torch
from numpy.typing import NDArray

from litege_core.canonical import (
    PoissonScaleSetting,
    Transform,
    canonicalize_unit_area,
    poisson_frame,
)
from litege_core.errors import InputError
from litege_core.nets import TNet
from litege_core.sampling import random_generator, sample_surface
from litege_core.seams import boundary_edge_fraction
from litege_core.shape import Shape

Scaling = Literal["auto", "unit_area", "broken_mesh", "cloud_8k", "cloud_500"]
SCALINGS: tuple[str, ...] = ("auto", "unit_area", "broken_mesh", "cloud_8k", "cloud_500")

FrameMode = Literal["auto", "tnet", "judged", "intrinsic"]
FRAME_MODES: tuple[str, ...] = ("auto", "tnet", "judged", "intrinsic")
"""``tnet``: the T-Net's frame as is (the reference); ``judged``: the T-Net's frame where its
turned runs agree (:func:`runs_agree`), else the one of it and the 24 principal-axis frames that
the matching network finds most like the canonical reference animals
(:class:`~litege_core.matching.judge.FrameJudge`); ``intrinsic``: the T-Net's frame where its
turned runs agree, else for a mesh the frame of the reference animals' functional maps onto it
(:mod:`litege_core.matching.intrinsic`; seconds per shape, needs pyFM), for a point cloud the
T-Net's; ``auto``: ``judged`` for the categories the judge is validated on, else ``tnet``."""

TURN_RUN_POINTS = 500
"""Points each turned T-Net run sees (a subset of the T-Net's input; it was trained on 500 to
2000): the same frame failures as 2000 on the procedural, rigged and TOSCA frame reports, at a
quarter of the cost."""
AGREEMENT_ANGLE = 0.66
"""rad: turned T-Net runs agree when each is within this angle of the plain run (the failure
threshold of the frame reports and of spec §1.6)."""

MIRROR = np.diag([-1.0, 1.0, 1.0])
"""Reflection across the canonical sagittal plane (``x → −x``; x is the animal's left-right
axis): maps an animal onto its mirror image, left and right swapped."""


@dataclass(frozen=True)
class MatchingPipeline:
    """Constants of the matching pipeline a bundle was trained with (stored in its manifest).

    Attributes:
        n_center_samples: area-weighted samples whose mean centres a unit-area mesh.
        n_tnet_points: points the T-Net sees.
        n_descriptor_samples: area-weighted samples of a mesh for its UDF descriptor (a cloud
            uses its own points).
        cloud_8k_target, cloud_500_target, broken_target: mean 1-NN spacing of Poisson-disk
            subsets of unit-area meshes (spec §1.4), calibrated with our sampler.
        small_cloud_points: clouds with at most this many points use the 500-point setting.
        broken_boundary_fraction: meshes whose boundary edges exceed this fraction of all
            edges are scaled as broken meshes.
        target_scale: network outputs are ``target_scale ×`` unit-area geodesics (1.42).
    """

    n_center_samples: int = 8000
    n_tnet_points: int = 2000
    n_descriptor_samples: int = 2000
    cloud_8k_target: float = 0.03835
    cloud_500_target: float = 0.12121
    broken_target: float = 0.01181
    small_cloud_points: int = 1500
    broken_boundary_fraction: float = 0.02
    target_scale: float = 1.42

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> MatchingPipeline:
        return cls(**data)

    def poisson_setting(self, scaling: str) -> PoissonScaleSetting:
        """The §1.4 row of a Poisson scaling, with this pipeline's calibrated target."""
        if scaling == "cloud_8k":
            return PoissonScaleSetting("cloud_8k", 8000, 500, self.cloud_8k_target)
        if scaling == "cloud_500":
            return PoissonScaleSetting("cloud_500", 500, 50, self.cloud_500_target)
        if scaling == "broken_mesh":
            return PoissonScaleSetting("broken_mesh", 56_000, 7000, self.broken_target, True)
        raise InputError(f"{scaling!r} is not a Poisson scaling")


def choose_scaling(shape: Shape, pipeline: MatchingPipeline, scaling: str = "auto") -> str:
    """Resolve ``"auto"`` to a concrete scaling for ``shape`` (see the module docstring)."""
    if scaling not in SCALINGS:
        raise InputError(f"scaling must be one of {list(SCALINGS)}, got {scaling!r}")
    if shape.faces is None:
        if scaling in ("unit_area", "broken_mesh"):
            raise InputError(f"scaling {scaling!r} needs a mesh; got a point cloud")
        if scaling == "auto":
            small = shape.n_points <= pipeline.small_cloud_points
            return "cloud_500" if small else "cloud_8k"
        return scaling
    if scaling != "auto":
        return scaling
    welded_boundary = boundary_edge_fraction(shape.faces, shape.vertices)  # a soup is whole
    broken = welded_boundary > pipeline.broken_boundary_fraction
    return "broken_mesh" if broken else "unit_area"


def scale_frame(
    shape: Shape, pipeline: MatchingPipeline, scaling: str, seed: int
) -> tuple[Transform, NDArray]:
    """Centre and scale ``shape`` (no rotation yet).

    Returns:
        ``(transform, cloud)``: the unrotated unit-area transform and the ``(P, 3)`` point
        cloud (input units) the T-Net and the descriptor are computed from.
    """
    if scaling == "unit_area":
        assert shape.faces is not None, "unit-area scaling is chosen for meshes only"
        rng = random_generator(seed)
        transform = canonicalize_unit_area(
            shape.vertices, shape.faces, pipeline.n_center_samples, rng
        )
        cloud = sample_surface(shape.vertices, shape.faces, pipeline.n_descriptor_samples, rng)
        return transform, cloud.points
    return poisson_frame(shape, pipeline.poisson_setting(scaling), seed)


def subsample(points: NDArray, n_max: int, seed: int) -> NDArray:
    """At most ``n_max`` rows of ``points``, drawn without replacement (deterministic)."""
    if points.shape[0] <= n_max:
        return points
    keep = random_generator(seed).choice(points.shape[0], n_max, replace=False)
    return points[np.sort(keep)]


@torch.no_grad()
def tnet_rotations(tnet: TNet, clouds: list[NDArray]) -> NDArray:
    """``R_pred`` of each centred, scaled cloud: ``(B, 3, 3)`` float64.

    Clouds of equal size run as one batch; the T-Net is in eval mode.
    """
    device = next(tnet.parameters()).device
    out = np.empty((len(clouds), 3, 3))
    sizes: dict[int, list[int]] = {}
    for i, cloud in enumerate(clouds):
        sizes.setdefault(cloud.shape[0], []).append(i)
    for members in sizes.values():
        batch = torch.from_numpy(np.stack([clouds[i] for i in members])).to(device, torch.float32)
        out[members] = tnet.rotation(batch).double().cpu().numpy()
    return out


def align_shapes(
    shapes: list[Shape],
    tnet: TNet,
    pipeline: MatchingPipeline,
    *,
    scaling: str = "auto",
    seed: int = 0,
) -> list[tuple[Transform, NDArray, str]]:
    """Canonical matching frames of several shapes.

    Returns:
        per shape ``(transform, cloud, scaling)``: the full transform (input → aligned
        unit-area frame, rotation ``R_predᵀ``), the descriptor cloud in the aligned frame
        ``(P, 3)`` float64 and the scaling used.
    """
    scaled = []
    for shape in shapes:
        chosen = choose_scaling(shape, pipeline, scaling)
        transform, cloud = scale_frame(shape, pipeline, chosen, seed)
        scaled.append((transform, transform.apply(cloud), chosen))
    rotations = tnet_rotations(
        tnet, [subsample(c, pipeline.n_tnet_points, seed) for _, c, _ in scaled]
    )
    frames = []
    for (transform, cloud, chosen), rotation in zip(scaled, rotations, strict=True):
        rotation = _orthonormal(rotation)
        full = Transform(rotation.T, transform.center, transform.scale)
        frames.append((full, cloud @ rotation, chosen))
    return frames


def cube_rotations() -> NDArray:
    """The 24 proper signed permutation matrices ``(24, 3, 3)`` float64, the identity first."""
    from litege_core.nets.tnet import CUBE_ROTATIONS

    return CUBE_ROTATIONS.numpy()


@torch.no_grad()
def tnet_turn_runs(tnet: TNet, clouds: list[NDArray]) -> NDArray:
    """``R_pred`` ``(B, 24, 3, 3)`` float64 of the T-Net run 24 times on each centred, scaled
    cloud: on its principal-axis frame turned by each cube rotation ``K`` (a pre-aligned T-Net,
    ``frames = Q K``), or on the cloud turned by ``K`` (``R = K R'``) without pre-alignment.
    Run 0 is the plain run of :func:`tnet_rotations`. One T-Net call per cloud."""
    from litege_core.nets.tnet import pca_frames

    device = next(tnet.parameters()).device
    cube = torch.from_numpy(cube_rotations()).to(device, torch.float32)  # (24, 3, 3)
    out = np.empty((len(clouds), len(cube), 3, 3))
    for i, cloud in enumerate(clouds):
        batch = torch.from_numpy(cloud).to(device, torch.float32)[None].expand(len(cube), -1, -1)
        if tnet.prealign == "pca":
            frames = pca_frames(batch[:1]) @ cube
            rotations = tnet.rotation(batch.contiguous(), frames=frames)
        else:
            rotations = cube @ tnet.rotation(batch @ cube)
        out[i] = rotations.double().cpu().numpy()
    return out


def runs_agree(runs: NDArray, threshold: float = AGREEMENT_ANGLE) -> bool:
    """Whether every run of ``runs`` ``(K, 3, 3)`` is within ``threshold`` rad of run 0."""
    cosines = (np.einsum("kij,ij->k", runs, runs[0]) - 1.0) / 2.0
    return bool(np.all(np.arccos(np.clip(cosines, -1.0, 1.0)) <= threshold))


def pca_candidates(cloud: NDArray) -> NDArray:
    """The 24 principal-axis frames of a centred, scaled cloud as rotations ``R`` ``(24, 3, 3)``
    float64 (``cloud @ R`` is the cloud in that frame, the convention of ``R_pred``):
    ``Q K`` for :func:`~litege_core.nets.tnet.pca_frames` ``Q`` and each cube rotation ``K``."""
    from litege_core.nets.tnet import pca_frames

    frame = pca_frames(torch.from_numpy(np.asarray(cloud, np.float64))[None])[0].numpy()
    return frame @ cube_rotations()


def candidate_turns(
    tnet: TNet,
    frames: list[tuple[Transform, NDArray, str]],
    n_tnet_points: int,
    seed: int,
) -> list[NDArray | None]:
    """The frames a judged frame chooses from, per shape of :func:`align_shapes`' ``frames``.

    Returns:
        per shape ``None`` where its turned T-Net runs agree (the T-Net's frame stands), else
        ``(25, 3, 3)`` float64 turns ``M`` of its T-Net frame (apply with :func:`turned`): the
        identity (the T-Net's frame), then the 24 principal-axis frames of what the T-Net saw.
    """
    inputs = [  # the T-Net's inputs: the unrotated clouds' subsets of align_shapes
        subsample(cloud @ transform.rotation, n_tnet_points, seed) for transform, cloud, _ in frames
    ]
    runs = tnet_turn_runs(tnet, [subsample(c, TURN_RUN_POINTS, seed) for c in inputs])
    out: list[NDArray | None] = []
    for (transform, _, _), seen, run in zip(frames, inputs, runs, strict=True):
        if runs_agree(run):
            out.append(None)
            continue
        tnet_rotation = transform.rotation.T  # R_pred: cloud = unrotated @ R_pred
        candidates = np.concatenate([tnet_rotation[None], pca_candidates(seen)])
        out.append(np.transpose(candidates, (0, 2, 1)) @ tnet_rotation)  # R_cᵀ R_pred
    return out


def turned(transform: Transform, turn: NDArray) -> Transform:
    """``transform`` followed by the canonical-frame rotation ``turn`` (``q' = turn · q``)."""
    return Transform(np.asarray(turn) @ transform.rotation, transform.center, transform.scale)


def _orthonormal(matrix: NDArray) -> NDArray:
    """The nearest proper rotation (float32 Gram–Schmidt output drifts by ~1e-7)."""
    u, _, vt = np.linalg.svd(matrix)
    rotation = u @ vt
    if np.linalg.det(rotation) < 0:
        u[:, -1] *= -1
        rotation = u @ vt
    if not math.isclose(abs(np.linalg.det(rotation)), 1.0, abs_tol=1e-6):
        raise InputError("the T-Net produced a degenerate rotation")
    return rotation


__all__ = [
    "AGREEMENT_ANGLE",
    "FRAME_MODES",
    "MIRROR",
    "SCALINGS",
    "TURN_RUN_POINTS",
    "FrameMode",
    "MatchingPipeline",
    "Scaling",
    "align_shapes",
    "candidate_turns",
    "choose_scaling",
    "cube_rotations",
    "pca_candidates",
    "runs_agree",
    "scale_frame",
    "subsample",
    "tnet_rotations",
    "tnet_turn_runs",
    "turned",
]
