"""Candidate canonical frames scored by the UDF-PCA reconstruction residual (issue 14, step 2).

The PC pipeline's PCA frame (reference-spec §1.5) fixes each axis sign by the median of the
projections; on real poses the median is close to zero for some axes and the sign flips between
poses of one animal (the paper admits the ambiguity). Here every shape gets a few candidate
frames — the proper rotations among the PCA axis sign flips, optionally axis swaps where two
eigenvalues are close — and the one whose UDF the bundle's PCA basis reconstructs best (lowest
residual, i.e. the most "training-like" frame) is kept::

    choice = select_frame(points, bundle.basis, "cpu", candidates="signs")
    choice.transform, choice.residual, choice.descriptor, choice.scores

All candidates of all shapes are scored in **one** batched
:meth:`~litege_core.descriptor.DescriptorEngine.describe_with_residual` call. A candidate is a
proper rotation ``M`` applied *after* the default transform: its canonical points are
``q' = M q`` (centre and bounding-box scale are unchanged: the box area is invariant under
axis sign flips and permutations). Candidate 0 is always the identity, so ``candidates="pca"``
reproduces the default frame exactly, and ties go to the default frame.

``margin`` keeps the default frame unless another candidate's residual is lower by more than
that fraction (``best < (1 − margin) · default``).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.canonical import Transform, canonicalize_bbox
from litege_core.descriptor import DescriptorEngine, UdfPcaBasis
from litege_core.errors import InputError

FRAME_CANDIDATES = ("pca", "signs", "swaps", "all")
"""Candidate sets: ``pca`` — the default frame only; ``signs`` — the 4 proper sign flips of
the PCA axes; ``swaps`` — ``signs`` plus, for each pair of adjacent axes whose eigenvalue ratio
``λ_{i+1}/λ_i`` exceeds ``swap_ratio``, the 4 proper signed swaps of that pair; ``all`` — the
24 proper signed permutations."""

DEFAULT_SWAP_RATIO = 0.7
"""Eigenvalue ratio above which two adjacent PCA axes count as ambiguous (``swaps``)."""

_SIGN_FLIPS = tuple(
    np.diag(np.asarray(s, dtype=np.float64))
    for s in ((1, 1, 1), (-1, -1, 1), (-1, 1, -1), (1, -1, -1))
)


def _signed_permutations(perm: Sequence[int]) -> list[NDArray]:
    """The 4 proper rotations ``diag(s) · P`` for the permutation matrix ``P`` of ``perm``."""
    base = np.eye(3)[list(perm)]
    out = []
    for signs in itertools.product((1.0, -1.0), repeat=3):
        matrix = np.diag(signs) @ base
        if np.linalg.det(matrix) > 0:
            out.append(matrix)
    return out


def candidate_rotations(
    candidates: str = "signs",
    eigenvalues: ArrayLike | None = None,
    swap_ratio: float = DEFAULT_SWAP_RATIO,
) -> list[NDArray]:
    """Proper rotations ``M (3, 3)`` applied in the canonical frame (``q' = M q``).

    The identity comes first. ``eigenvalues`` (descending, of the canonical samples) are
    needed by ``swaps`` only.
    """
    if candidates not in FRAME_CANDIDATES:
        raise InputError(f"unknown frame candidates {candidates!r}; expected {FRAME_CANDIDATES}")
    if candidates == "pca":
        return [np.eye(3)]
    if candidates == "signs":
        return [m.copy() for m in _SIGN_FLIPS]
    if candidates == "all":
        out = []
        for perm in itertools.permutations(range(3)):
            out += _signed_permutations(perm)
        return out  # identity permutation with signs (+,+,+) first
    out = [m.copy() for m in _SIGN_FLIPS]
    if eigenvalues is None:
        raise InputError("frame candidates 'swaps' need the PCA eigenvalues")
    lam = np.asarray(eigenvalues, dtype=np.float64)
    for i in (0, 1):
        if lam[i] > 0 and lam[i + 1] / lam[i] > swap_ratio:
            swapped = [0, 1, 2]
            swapped[i], swapped[i + 1] = swapped[i + 1], swapped[i]
            out += _signed_permutations(swapped)
    return out


@dataclass(frozen=True, eq=False)
class FrameChoice:
    """The selected frame of one shape.

    Attributes:
        transform: user frame → selected canonical frame.
        residual: UDF-PCA reconstruction residual in that frame.
        descriptor: ``(k,)`` float32 descriptor in that frame.
        scores: ``(C,)`` residuals of every candidate (candidate 0 = default PCA frame).
        index: index of the selected candidate.
        rotations: ``(C, 3, 3)`` the candidates ``M`` (canonical-frame rotations).
        samples: ``(P, 3)`` the descriptor's samples in the selected canonical frame.
    """

    transform: Transform
    residual: float
    descriptor: NDArray
    scores: NDArray
    index: int
    rotations: NDArray
    samples: NDArray

    def __iter__(self):
        """``transform, residual, descriptor, scores = choice``."""
        return iter((self.transform, self.residual, self.descriptor, self.scores))


def _engine(basis: UdfPcaBasis | DescriptorEngine, device) -> DescriptorEngine:
    if isinstance(basis, DescriptorEngine):
        return basis
    return basis.engine(device)


def _described(
    canonical: Sequence[NDArray], engine: DescriptorEngine, rotations: Sequence[NDArray]
) -> tuple[list[NDArray], NDArray, NDArray]:
    """Each shape's canonical cloud ``(P_b, 3)`` turned by each of its rotations ``(C_b, 3,
    3)``, described in one UDF call: the ``ΣC_b`` turned clouds, their residuals ``(ΣC_b,)``
    float64 and descriptors ``(ΣC_b, k)`` float32."""
    clouds = [cloud @ m.T for cloud, mats in zip(canonical, rotations, strict=True) for m in mats]
    result = engine.describe_with_residual(clouds)
    residuals = result.residual.detach().cpu().numpy().astype(np.float64)
    codes = result.descriptors.detach().cpu().numpy().astype(np.float32)
    return clouds, residuals, codes


def turned_frames(
    points: ArrayLike,
    basis: UdfPcaBasis | DescriptorEngine,
    rotations: ArrayLike,
    device: str | torch.device = "cpu",
) -> list[FrameChoice]:
    """The PCA frame of one shape turned by each of ``rotations`` ``(C, 3, 3)`` (e.g. small
    turns, for test-time augmentation or a frame-sensitivity probe), every one described; no
    selection: choice ``i`` is the frame ``rotations[i] @ R_pca``."""
    mats = np.asarray(rotations, dtype=np.float64)
    if mats.ndim != 3 or mats.shape[1:] != (3, 3) or mats.shape[0] < 1:
        raise InputError(f"rotations must have shape (C, 3, 3), got {mats.shape}")
    transform = canonicalize_bbox(points)
    clouds, residuals, codes = _described([transform.apply(points)], _engine(basis, device), [mats])
    mats.setflags(write=False)
    scores = residuals.copy()
    scores.setflags(write=False)
    return [
        FrameChoice(
            transform=Transform(m @ transform.rotation, transform.center, transform.scale),
            residual=float(residuals[i]),
            descriptor=codes[i].copy(),
            scores=scores,
            index=i,
            rotations=mats,
            samples=clouds[i],
        )
        for i, m in enumerate(mats)
    ]


def select_frames(
    samples: Sequence[ArrayLike],
    basis: UdfPcaBasis | DescriptorEngine,
    device: str | torch.device = "cpu",
    *,
    candidates: str = "signs",
    margin: float = 0.0,
    swap_ratio: float = DEFAULT_SWAP_RATIO,
) -> list[FrameChoice]:
    """Select the lowest-residual candidate frame for each of several shapes.

    Args:
        samples: ``B`` arrays ``(P_b, 3)``: the points the descriptor is computed from, in the
            user's frame (what :func:`~litege_core.learned.describe.shape_samples` returns).
        basis: the bundle's basis, or an engine already placed on a device.
        device: where the UDF runs (ignored when ``basis`` is an engine).
        candidates: one of :data:`FRAME_CANDIDATES`.
        margin: keep the default frame unless the best residual is below
            ``(1 − margin) ×`` the default's.
        swap_ratio: eigenvalue ratio for ``swaps``.

    Returns:
        ``B`` :class:`FrameChoice`, each the same as :func:`select_frame` of that shape.
    """
    if not 0.0 <= margin < 1.0:
        raise InputError(f"margin must be in [0, 1), got {margin!r}")
    engine = _engine(basis, device)
    transforms, canonical, rotations = [], [], []
    for points in samples:
        transform = canonicalize_bbox(points)
        cloud = transform.apply(points)
        eigenvalues = None
        if candidates == "swaps":
            centred = cloud - cloud.mean(axis=0)
            eigenvalues = np.sort(np.linalg.eigvalsh(centred.T @ centred))[::-1]
        transforms.append(transform)
        canonical.append(cloud)
        rotations.append(np.stack(candidate_rotations(candidates, eigenvalues, swap_ratio)))
    clouds, residuals, codes = _described(canonical, engine, rotations)
    choices, start = [], 0
    for transform, mats in zip(transforms, rotations, strict=True):
        scores = residuals[start : start + len(mats)]
        best = int(np.argmin(scores))
        if not scores[best] < (1.0 - margin) * scores[0]:
            best = 0
        selected = transform
        if best != 0:
            selected = Transform(mats[best] @ transform.rotation, transform.center, transform.scale)
        scores = scores.copy()
        scores.setflags(write=False)
        mats.setflags(write=False)
        choices.append(
            FrameChoice(
                transform=selected,
                residual=float(scores[best]),
                descriptor=codes[start + best].copy(),
                scores=scores,
                index=best,
                rotations=mats,
                samples=clouds[start + best],
            )
        )
        start += len(mats)
    return choices


def select_frame(
    points: ArrayLike,
    basis: UdfPcaBasis | DescriptorEngine,
    device: str | torch.device = "cpu",
    candidates: str = "signs",
    *,
    margin: float = 0.0,
    swap_ratio: float = DEFAULT_SWAP_RATIO,
) -> FrameChoice:
    """:func:`select_frames` for one shape: ``transform, residual, descriptor, scores``."""
    return select_frames(
        [points], basis, device, candidates=candidates, margin=margin, swap_ratio=swap_ratio
    )[0]


__all__ = [
    "DEFAULT_SWAP_RATIO",
    "FRAME_CANDIDATES",
    "FrameChoice",
    "candidate_rotations",
    "select_frame",
    "select_frames",
    "turned_frames",
]
