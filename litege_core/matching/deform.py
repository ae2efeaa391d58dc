"""A refined map smoothed by a deformation of X (issue 15, step 5).

ZoomOut's pointwise map is read vertex by vertex from the spectral embedding, so neighbouring
points of X land on Y with independent errors of a vertex or two, while the true map of two
bodies of one kind (two poses, two builds of one template) moves neighbouring points alike.
So :func:`smooth_displacement` fits a smooth displacement field ``D = Φ C`` of X, in X's
Laplace–Beltrami eigenbasis ``Φ`` (``(V, K)``, mass-orthonormal, eigenvalues ``λ_k``), to the
map at ``S`` sample points of X:

    minimize  (A / S) Σ_s w_s |x_s + D(x_s) − y_m(s)|²  +  μ · ∫ |Δ D|²
            = (A / S) Σ_s w_s |Φ_s C − o_s|²            +  μ · Σ_k λ_k² |C_k|²

(``A`` X's area, ``o_s`` the sample's offset to its image; ``μ`` has units of area², so it
means the same on any triangulation). A constant ``Φ_0`` makes translations free. Each vertex
is then displaced by ``Φ_v C`` and maps to the Y vertex nearest its new position. The samples
are reweighted over a few rounds by a Cauchy weight ``w_s = 1 / (1 + (r_s / (c · median r))²)``
of their residual ``r_s``, so matches that landed on another part do not drag their
neighbours along. A ``K × K`` solve per round: milliseconds, whatever the mesh size.

:func:`smooth_displacement_reference` solves the same least-squares problem by ``lstsq`` on its
stacked rows (the slow reference).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError


def _robust_weights(residuals: NDArray, scale: float) -> NDArray:
    """Cauchy weights ``(S,)`` of residuals ``(S,)`` at ``scale`` × their median."""
    spread = scale * float(np.median(residuals)) + 1e-12
    return 1.0 / (1.0 + (residuals / spread) ** 2)


def _checked(
    basis: NDArray, eigenvalues: NDArray, offsets: NDArray, smoothing: float, rounds: int
) -> tuple[NDArray, NDArray, NDArray]:
    basis = np.asarray(basis, dtype=np.float64)
    eigenvalues = np.asarray(eigenvalues, dtype=np.float64)
    offsets = np.asarray(offsets, dtype=np.float64)
    if basis.ndim != 2 or eigenvalues.shape != (basis.shape[1],):
        raise InputError(
            f"need a (S, K) basis and (K,) eigenvalues, got {basis.shape}, {eigenvalues.shape}"
        )
    if offsets.shape != (basis.shape[0], 3):
        raise InputError(f"offsets must be ({basis.shape[0]}, 3), got {offsets.shape}")
    if smoothing <= 0 or rounds < 1:
        raise InputError("the smoothing weight and the rounds must be positive")
    return basis, eigenvalues, offsets


def smooth_displacement(
    basis: NDArray,
    eigenvalues: NDArray,
    offsets: NDArray,
    area: float,
    smoothing: float,
    rounds: int = 4,
    scale: float = 3.0,
) -> NDArray:
    """The smooth displacement of X that best fits a map at its samples.

    Args:
        basis: ``(S, K)`` X's eigenbasis at the samples (rows of ``Φ``).
        eigenvalues: ``(K,)`` its Laplace–Beltrami eigenvalues ``λ_k`` (≥ 0).
        offsets: ``(S, 3)`` each sample's image minus its position (unit-area frame).
        area: X's area (1 in the unit-area frame).
        smoothing: μ, the weight of ``∫ |Δ D|²`` (area² units).
        rounds: solves, each reweighting the samples by their residual.
        scale: Cauchy scale of the reweighting, in medians of the residuals.

    Returns:
        ``(K, 3)`` float64 coefficients ``C``: vertex ``v`` moves by ``Φ_v C``.
    """
    basis, eigenvalues, offsets = _checked(basis, eigenvalues, offsets, smoothing, rounds)
    sample_area = area / basis.shape[0]
    penalty = np.diag(smoothing * eigenvalues**2)
    weights = np.ones(basis.shape[0])
    coefficients = np.zeros((basis.shape[1], 3))
    for _ in range(rounds):
        weighted = basis * (weights * sample_area)[:, None]
        coefficients = np.linalg.solve(weighted.T @ basis + penalty, weighted.T @ offsets)
        weights = _robust_weights(np.linalg.norm(basis @ coefficients - offsets, axis=1), scale)
    return coefficients


def smooth_displacement_reference(
    basis: NDArray,
    eigenvalues: NDArray,
    offsets: NDArray,
    area: float,
    smoothing: float,
    rounds: int = 4,
    scale: float = 3.0,
) -> NDArray:
    """:func:`smooth_displacement` by ``numpy.linalg.lstsq`` on the stacked rows
    ``[√(w_s A / S) Φ_s ; √μ λ_k e_k]`` (the slow reference)."""
    basis, eigenvalues, offsets = _checked(basis, eigenvalues, offsets, smoothing, rounds)
    n_samples, size = basis.shape
    weights = np.ones(n_samples)
    coefficients = np.zeros((size, 3))
    for _ in range(rounds):
        root = np.sqrt(weights * area / n_samples)
        rows = np.vstack([basis * root[:, None], np.diag(np.sqrt(smoothing) * eigenvalues)])
        rhs = np.vstack([offsets * root[:, None], np.zeros((size, 3))])
        coefficients = np.linalg.lstsq(rows, rhs, rcond=None)[0]
        residuals = np.array(
            [np.linalg.norm(basis[s] @ coefficients - offsets[s]) for s in range(n_samples)]
        )
        weights = _robust_weights(residuals, scale)
    return coefficients


__all__ = ["smooth_displacement", "smooth_displacement_reference"]
