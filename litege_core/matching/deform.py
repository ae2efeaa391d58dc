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

The spectral map is the most isometric map, and two bodies of one kind built in different
proportions are not isometric: its images of neighbouring samples share a bias of a few edges
that no smoothing removes. :func:`register_displacement` then lets go of them and registers the
displaced samples to Y's surface (non-rigid ICP in the eigenbasis, point-to-plane):

    minimize  (A / S) Σ_s [((x_s + Φ_s C − y_c(s)) · n_c(s))²  +  α w_s |Φ_s C − o_s|²]
              +  μ_r · Σ_k λ_k² |C_k|²

with ``y_c(s)`` the Y vertex nearest the displaced sample and ``n_c(s)`` its normal, recomputed
each round, and ``μ_r`` annealed geometrically from a stiff to a soft deformation. Sliding along
Y's surface costs nothing in the first term, so the tangential part of the map is set by the
smoothness, the start (the fitted displacement) and a weak, robustly weighted tie ``α`` to the
spectral map: without the tie the least-bent deformation also slides off the right map of two
poses (near-isometric pairs, where the spectral map has no bias to remove). A ``3K × 3K`` solve
per round.

:func:`smooth_displacement_reference` and :func:`register_displacement_reference` solve the same
least-squares problems by ``lstsq`` on their stacked rows (the slow references).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import InputError

if TYPE_CHECKING:  # scipy loads when a displacement is registered
    from scipy.spatial import cKDTree


def _robust_weights(residuals: NDArray, scale: float) -> NDArray:
    """Cauchy weights ``(S,)`` of residuals ``(S,)`` at ``scale`` × their median."""
    spread = scale * float(np.median(residuals)) + 1e-12
    return 1.0 / (1.0 + (residuals / spread) ** 2)


def _unit_rows(vectors: NDArray) -> NDArray:
    """``(T, 3)`` rows scaled to unit length; zero rows stay zero."""
    lengths = np.linalg.norm(vectors, axis=1, keepdims=True)
    return vectors / np.maximum(lengths, 1e-300)


def _registration_inputs(
    basis: NDArray,
    eigenvalues: NDArray,
    points: NDArray,
    offsets: NDArray,
    coefficients: NDArray,
    target: NDArray,
    target_normals: NDArray,
    smoothing: tuple[float, float],
    rounds: int,
    anchor: float,
) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, NDArray, NDArray]:
    """The arguments of :func:`register_displacement` checked and as float64 arrays (a copy of
    ``coefficients``; the normals scaled to unit rows, zero rows kept).

    Raises:
        InputError: shapes that do not fit together, a smoothing weight not positive, or
            negative rounds or anchor.
    """
    basis, eigenvalues, offsets = _checked(basis, eigenvalues, offsets, min(smoothing), 1)
    points = np.asarray(points, dtype=np.float64)
    coefficients = np.array(coefficients, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    target_normals = np.asarray(target_normals, dtype=np.float64)
    n_samples, size = basis.shape
    if points.shape != offsets.shape or coefficients.shape != (size, 3):
        raise InputError(
            f"need ({n_samples}, 3) points and ({size}, 3) coefficients, got {points.shape}, "
            f"{coefficients.shape}"
        )
    if target.ndim != 2 or target.shape[1] != 3 or target_normals.shape != target.shape:
        raise InputError(
            f"need (T, 3) target vertices and normals, got {target.shape}, {target_normals.shape}"
        )
    if rounds < 0 or anchor < 0:
        raise InputError(f"rounds and anchor must be >= 0, got {rounds}, {anchor}")
    normals = _unit_rows(target_normals)
    return basis, eigenvalues, points, offsets, coefficients, target, normals


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


def register_displacement(
    basis: NDArray,
    eigenvalues: NDArray,
    points: NDArray,
    offsets: NDArray,
    coefficients: NDArray,
    target: NDArray,
    target_normals: NDArray,
    area: float,
    smoothing: tuple[float, float],
    rounds: int = 8,
    anchor: float = 0.01,
    scale: float = 3.0,
    target_tree: cKDTree | None = None,
) -> NDArray:
    """A displacement of X refined by registering its samples to Y's surface (point-to-plane
    non-rigid ICP with an annealed smoothness weight, loosely tied to the map; the module doc).

    Args:
        basis: ``(S, K)`` X's eigenbasis at the samples (rows of ``Φ``).
        eigenvalues: ``(K,)`` its Laplace–Beltrami eigenvalues ``λ_k`` (≥ 0).
        points: ``(S, 3)`` the samples' positions (unit-area frame).
        offsets: ``(S, 3)`` each sample's image under the map minus its position (the tie).
        coefficients: ``(K, 3)`` the starting displacement ``C`` (of
            :func:`smooth_displacement`).
        target: ``(T, 3)`` Y's vertices, in the same frame.
        target_normals: ``(T, 3)`` their normals (any length, any sign; a zero row, as an
            unreferenced vertex has, gives a sample nearest that vertex no surface term).
        area: X's area (1 in the unit-area frame).
        smoothing: ``(μ_first, μ_last)``, the weight of ``∫ |Δ D|²`` at the first and the last
            round (area² units), geometric in between.
        rounds: closest-point rounds (0 returns ``coefficients``).
        anchor: α, the weight of the tie to the map relative to the surface term (0: none).
        scale: Cauchy scale of the tie's reweighting, in medians of its residuals.
        target_tree: a k-d tree of ``target`` (built when not given).

    Returns:
        ``(K, 3)`` float64 coefficients: vertex ``v`` moves by ``Φ_v C``.
    """
    basis, eigenvalues, points, offsets, coefficients, target, normals = _registration_inputs(
        basis,
        eigenvalues,
        points,
        offsets,
        coefficients,
        target,
        target_normals,
        smoothing,
        rounds,
        anchor,
    )
    if not rounds:
        return coefficients
    if target_tree is None:
        from scipy.spatial import cKDTree

        target_tree = cKDTree(target)
    n_samples, size = basis.shape
    sample_area = area / n_samples
    for weight in np.geomspace(smoothing[0], smoothing[1], rounds):
        fitted = basis @ coefficients
        _, nearest = target_tree.query(points + fitted)
        normal = normals[nearest]
        # row s of the linearised surface residual: Σ_kj Φ_sk n_sj C_kj − (y_c(s) − x_s) · n_s
        rows = (basis[:, :, None] * normal[:, None, :]).reshape(n_samples, 3 * size)
        gap = np.einsum("ij,ij->i", target[nearest] - points, normal)
        system = rows.T @ rows + np.diag(np.repeat(weight / sample_area * eigenvalues**2, 3))
        rhs = rows.T @ gap
        if anchor:
            tie = anchor * _robust_weights(np.linalg.norm(fitted - offsets, axis=1), scale)
            tied = basis * tie[:, None]
            system += np.kron(tied.T @ basis, np.eye(3))
            rhs += (tied.T @ offsets).ravel()
        coefficients = np.linalg.solve(system, rhs).reshape(size, 3)
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


def register_displacement_reference(
    basis: NDArray,
    eigenvalues: NDArray,
    points: NDArray,
    offsets: NDArray,
    coefficients: NDArray,
    target: NDArray,
    target_normals: NDArray,
    area: float,
    smoothing: tuple[float, float],
    rounds: int = 8,
    anchor: float = 0.01,
    scale: float = 3.0,
) -> NDArray:
    """:func:`register_displacement` by ``numpy.linalg.lstsq`` on each round's stacked rows,
    the unknowns ``C`` flattened ``(k, j)``: per sample ``s`` one surface row
    ``Φ_sk n_sj`` (right side ``(y_c(s) − x_s) · n_s``), per sample and axis ``j`` one tie row
    ``√(α w_s) Φ_sk`` (right side ``√(α w_s) o_sj``), and per unknown one smoothness row
    ``√(μ_r S / A) λ_k`` (the slow reference, nearest vertices by brute force)."""
    basis, eigenvalues, points, offsets, coefficients, target, normals = _registration_inputs(
        basis,
        eigenvalues,
        points,
        offsets,
        coefficients,
        target,
        target_normals,
        smoothing,
        rounds,
        anchor,
    )
    n_samples, size = basis.shape
    eye = np.eye(3)
    for weight in np.geomspace(smoothing[0], smoothing[1], rounds):
        fitted = basis @ coefficients
        moved = points + fitted
        nearest = np.argmin(((moved[:, None, :] - target[None, :, :]) ** 2).sum(-1), axis=1)
        normal = normals[nearest]
        surface = np.stack([np.outer(basis[s], normal[s]).ravel() for s in range(n_samples)])
        gap = np.einsum("ij,ij->i", target[nearest] - points, normal)
        penalty = np.diag(np.repeat(np.sqrt(weight * n_samples / area) * eigenvalues, 3))
        blocks, rhs = [surface, penalty], [gap, np.zeros(3 * size)]
        if anchor:
            residuals = np.linalg.norm(fitted - offsets, axis=1)
            root = np.sqrt(anchor * _robust_weights(residuals, scale))
            for j in range(3):  # unknown (k, j) sits at column 3 k + j
                blocks.append(np.kron(basis * root[:, None], eye[j]))
                rhs.append(root * offsets[:, j])
        solution = np.linalg.lstsq(np.vstack(blocks), np.concatenate(rhs), rcond=None)[0]
        coefficients = solution.reshape(size, 3)
    return coefficients


__all__ = [
    "register_displacement",
    "register_displacement_reference",
    "smooth_displacement",
    "smooth_displacement_reference",
]
