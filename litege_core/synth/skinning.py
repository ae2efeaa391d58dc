"""Skinning weights (bone heat) and linear blend skinning with per-bone scale and rotation.

Weights follow Baran and Popović (2007): for each joint ``j`` solve ``(−Δ + H) w_j = H p_j``
on the template, where ``Δ`` is the cotangent Laplacian, ``H_ii = 1 / d_i²`` with ``d_i`` the
distance from vertex ``i`` to the bone segment it is attached to, and ``p_j`` the indicator of
the vertices attached to joint ``j``. Attachment is semantic instead of Pinocchio's visibility
test: the body part whose primitive dominates the implicit field at a vertex picks the group,
and the nearest bone of that group wins. Weights are symmetrized with the mirror map, cut to
the ``max_influences`` largest per vertex and renormalized.

Deformation: each joint's bone has a rest frame (axis along the bone, a lateral axis, a
depth axis). A shape sample scales each bone along its axis and across it; the new joint
positions follow down the chain, and vertices move by the weight-blended affine maps. A pose
then rotates each joint about its (new) position, composed down the chain, also blended by
the weights (linear blend skinning).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.sparse.linalg import splu

from litege_core.errors import ComputationError
from litege_core.synth.skeleton import Skeleton, point_segment_distance


def cotangent_laplacian(vertices: NDArray, faces: NDArray) -> tuple[sparse.csc_matrix, NDArray]:
    """Cotangent stiffness ``K`` (``(V, V)``, positive semi-definite) and lumped
    (barycentric) vertex areas ``(V,)``."""
    n = len(vertices)
    p = vertices[faces]
    rows, cols, vals = [], [], []
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        u = p[:, j] - p[:, i]
        w = p[:, k] - p[:, i]
        cross = np.linalg.norm(np.cross(u, w), axis=1)
        cot = np.einsum("ij,ij->i", u, w) / np.maximum(cross, 1e-15)
        rows += [faces[:, j], faces[:, k]]
        cols += [faces[:, k], faces[:, j]]
        vals += [-0.5 * cot, -0.5 * cot]
    off = sparse.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n, n)
    ).tocsr()
    stiffness = off - sparse.diags(np.asarray(off.sum(axis=1)).ravel())
    area = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)
    mass = np.bincount(faces.ravel(), np.repeat(area / 3.0, 3), minlength=n)
    return stiffness.tocsc(), mass


def attach_to_bones(vertices: NDArray, groups: list[str], skeleton: Skeleton) -> NDArray:
    """``(V,)`` joint index per vertex: the nearest bone segment within the vertex's group."""
    dist = point_segment_distance(vertices, skeleton.positions, skeleton.tips)
    member = np.array([[g == jg for jg in skeleton.groups] for g in groups], dtype=bool)
    if not member.any(axis=1).all():
        raise ComputationError("a body part has no bone in the skeleton")
    return np.argmin(np.where(member, dist, np.inf), axis=1)


def bone_heat_weights(
    vertices: NDArray,
    faces: NDArray,
    skeleton: Skeleton,
    attachment: NDArray,
    symmetry: NDArray,
    heat_scale: float = 1.0,
) -> NDArray:
    """``(V, J)`` dense bone-heat weights: non-negative, rows sum to 1, mirror-symmetric
    (``W[sym][:, mirror] == W``).

    ``heat_scale`` multiplies ``H``: smaller values diffuse further (wider joint blends);
    1 is Baran and Popović's choice.
    """
    n, n_joints = len(vertices), skeleton.n_joints
    dist = point_segment_distance(vertices, skeleton.positions, skeleton.tips)
    d = np.maximum(dist[np.arange(n), attachment], 1e-2)
    heat = heat_scale / (d * d)
    stiffness, mass = cotangent_laplacian(vertices, faces)
    system = (stiffness + sparse.diags(mass * heat)).tocsc()
    rhs = np.zeros((n, n_joints))
    rhs[np.arange(n), attachment] = mass * heat
    weights = splu(system).solve(rhs)
    weights = 0.5 * (weights + weights[symmetry][:, skeleton.mirror])
    weights = np.clip(weights, 0.0, None)
    return weights / weights.sum(axis=1, keepdims=True)


def sparsify(weights: NDArray, max_influences: int, min_weight: float) -> NDArray:
    """Keep at most ``max_influences`` weights per row, continuously.

    Plain top-k truncation jumps where the k-th and (k+1)-th weights swap, which shows as
    creases once posed. Here every weight is lowered by ``max(w_(k+1), min_weight)`` (the
    largest dropped weight, or the floor) and clipped at 0, then rows are renormalized: at a
    swap both weights are equal and both become 0, so the result is continuous in the input.
    """
    w = np.clip(weights, 0.0, None)
    w /= np.maximum(w.sum(axis=1, keepdims=True), 1e-300)
    ordered = -np.sort(-w, axis=1)
    cut = ordered[:, max_influences] if w.shape[1] > max_influences else np.zeros(len(w))
    floor = np.maximum(cut, min_weight)[:, None]
    floor = np.minimum(floor, 0.5 * ordered[:, :1])  # never drop a row's largest weight
    w = np.clip(w - floor, 0.0, None)
    # Rows whose (k+1)-th weight exceeds half their largest (rare): drop every weight not
    # above the (k+1)-th largest (ties go together, which keeps mirror symmetry).
    kth = -np.sort(-w, axis=1)[:, max_influences] if w.shape[1] > max_influences else None
    if kth is not None:
        w[w <= kth[:, None]] = 0.0
    return w / w.sum(axis=1, keepdims=True)


def bone_frames(skeleton: Skeleton) -> NDArray:
    """``(J, 3, 3)`` rest frames; columns: bone axis, lateral (width) axis, depth axis."""
    axis = skeleton.tips - skeleton.positions
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    lateral = np.array([1.0, 0.0, 0.0]) - axis[:, :1] * axis
    degenerate = np.linalg.norm(lateral, axis=1) < 0.3
    lateral[degenerate] = np.array([0.0, 0.0, 1.0]) - axis[degenerate, 2:3] * axis[degenerate]
    lateral /= np.linalg.norm(lateral, axis=1, keepdims=True)
    depth = np.cross(axis, lateral)
    return np.stack([axis, lateral, depth], axis=2)


def scale_maps(skeleton: Skeleton, scales: NDArray) -> tuple[NDArray, NDArray]:
    """Per-bone affine maps for a shape sample.

    Args:
        scales: ``(J, 3)`` positive factors per bone: length (along the bone), width
            (lateral) and depth.

    Returns:
        ``A (J, 3, 3)`` linear parts and ``positions (J, 3)`` of the new joints; a point
        ``v`` rigidly attached to bone ``j`` maps to ``positions[j] + A[j] (v − rest_j)``.
    """
    frames = bone_frames(skeleton)
    A = np.einsum("jab,jb,jcb->jac", frames, scales, frames)
    new = skeleton.positions.copy()
    for j in range(1, skeleton.n_joints):
        p = skeleton.parents[j]
        new[j] = new[p] + A[p] @ (skeleton.positions[j] - skeleton.positions[p])
    return A, new


def pose_maps(
    parents: NDArray, positions: NDArray, local_rotations: NDArray, root_translation: NDArray
) -> tuple[NDArray, NDArray]:
    """Forward kinematics.

    Args:
        parents: ``(J,)``; positions: ``(J, 3)`` rest (shaped) joint positions.
        local_rotations: ``(J, 3, 3)`` rotation of each joint relative to its parent, in the
            rest frame's world axes.
        root_translation: ``(3,)``.

    Returns:
        ``R (J, 3, 3)`` world rotations and ``q (J, 3)`` posed joint positions; a point
        attached to joint ``j`` maps to ``q[j] + R[j] (v − positions[j])``.
    """
    n = len(parents)
    R = np.empty((n, 3, 3))
    q = np.empty((n, 3))
    R[0] = local_rotations[0]
    q[0] = positions[0] + root_translation
    for j in range(1, n):
        p = parents[j]
        R[j] = R[p] @ local_rotations[j]
        q[j] = q[p] + R[p] @ (positions[j] - positions[p])
    return R, q


def blend(
    vertices: NDArray, weights: NDArray, linear: NDArray, rest: NDArray, new: NDArray
) -> NDArray:
    """Linear blend skinning: ``v' = Σ_j w_j (new_j + linear_j (v − rest_j))``.

    Args:
        vertices: ``(V, 3)``; weights: ``(V, J)``; linear: ``(J, 3, 3)``;
        rest, new: ``(J, 3)`` joint positions before and after.
    """
    local = vertices[:, None, :] - rest[None]  # (V, J, 3)
    moved = np.einsum("jab,vjb->vja", linear, local) + new[None]
    return np.einsum("vj,vja->va", weights, moved)


def axis_angle_to_matrix(rotvec: NDArray) -> NDArray:
    """``(..., 3)`` axis-angle vectors (radians) to ``(..., 3, 3)`` rotation matrices."""
    theta = np.linalg.norm(rotvec, axis=-1, keepdims=True)
    axis = rotvec / np.maximum(theta, 1e-12)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    zero = np.zeros_like(x)
    K = np.stack([zero, -z, y, z, zero, -x, -y, x, zero], axis=-1).reshape(*x.shape, 3, 3)
    s = np.sin(theta)[..., None]
    c = np.cos(theta)[..., None]
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + s * K + (1.0 - c) * (K @ K)


__all__ = [
    "attach_to_bones",
    "axis_angle_to_matrix",
    "blend",
    "bone_frames",
    "bone_heat_weights",
    "cotangent_laplacian",
    "pose_maps",
    "scale_maps",
    "sparsify",
]
