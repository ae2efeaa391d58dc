"""Posed real animals from rigged, animated glTF models (Quaternius UAA, the Khronos fox).

A *family* is one model file; a shape is a pure function of ``(family, seed)``:

1. the model is loaded once per process: the skinned mesh of the largest skinned node, welded
   by position (glTF splits vertices at UV/material seams; each welded vertex keeps the skin
   weights of one raw vertex), reduced to its largest connected component (the body: horns,
   antlers and eye slivers are separate shells and are dropped), and scaled so that its
   skinned rest pose has unit area;
2. a clip is drawn uniformly among the model's animations and a time uniformly in it; the node
   TRS are sampled there (linear/slerp); the rotation of every *free* joint (one with no leg
   joint in its subtree: neck, head, ears, tail) is perturbed by a random rotation of angle
   ``~N(0, perturb_degrees)`` (capped at 2.5 σ), and the mesh is posed by linear blend
   skinning. Leg joints (rest position in the lower ``LEG_FRACTION`` of the height) and their
   ancestors keep the clip's pose: the Quaternius feet hang on IK bones parented to the
   armature root, so any rotation of the leg chain or a spine joint above it would tear the
   hooves off the legs;
   With ``bend.probability > 0`` (:class:`~litege_core.synth.bend.BendSettings`) the posed
   surface is then bent along the body's forward axis (a curl, a head turned back, an arch;
   :mod:`litege_core.synth.bend`): poses real animals take that no clip holds, and that a
   spine rotation cannot make on these rigs;
3. the posed body is scaled along its three axes by factors in ``body_range`` (longer/taller/
   wider), Loop-subdivided once (smooths the low-poly facets) and remeshed isotropically to
   ``target_vertices`` (drawn in ``vertex_range``); the few slivers left on thin, nearly
   flat parts (tail fins, hooves) are collapsed;
4. the result is checked to be a closed, oriented manifold (no pinched vertex, no repeated
   face) in one component without slivers (exact MMP geodesics need it); a failing draw is
   retried with the next sub-seed.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.errors import ComputationError, InputError
from litege_core.synth import gltf
from litege_core.synth.bend import Bend, BendSettings, body_axes, random_bend
from litege_core.synth.meshops import (
    collapse_slivers,
    largest_body,
    manifold_report,
    remesh,
    subdivide_loop,
    unit_area_scale,
    weld,
)
from litege_core.synth.shape_space import GIRTH_STREAM, draw_girth

RIGGED_VERSION = "rigged-2"
KEEP_GIRTH = ("head", "ear", "jaw", "eye")
"""Joints (by a part of their lower-case name) whose vertices a build leaves as they are."""
LEG_FRACTION = 0.45
"""Joints whose rest position lies in the lower 45 % of the rest height count as leg joints."""

QUATERNIUS = (
    "Alpaca",
    "Bull",
    "Cow",
    "Deer",
    "Donkey",
    "Fox",
    "Horse",
    "Husky",
    "ShibaInu",
    "Stag",
    "Wolf",
)
KHRONOS_FOX = "KhronosFox"
ANIMALS = (*QUATERNIUS, KHRONOS_FOX)
"""The families of the rigged quadruped source (11 Quaternius animals + the Khronos fox)."""


def animal_path(root: str | Path, family: str) -> Path:
    """The glTF file of ``family`` under the train-data directory ``root``."""
    root = Path(root)
    if family == KHRONOS_FOX:
        return root / "khronos-fox" / "Fox.glb"
    if family in QUATERNIUS:
        return root / "quaternius-uaa" / f"{family}.gltf"
    raise InputError(f"unknown rigged animal {family!r}; expected one of {ANIMALS}")


@dataclass(frozen=True)
class PoseSettings:
    """Random pose and proportion ranges of rigged shapes (see the module docstring)."""

    perturb_degrees: float = 6.0
    body_range: tuple[float, float] = (0.88, 1.12)
    vertex_range: tuple[int, int] = (4000, 5000)
    subdivide: bool = True
    attempts: int = 6
    bend: BendSettings = field(default_factory=BendSettings)
    girth_std: float = 0.0
    """Log std of a lean-to-stocky build (:meth:`RiggedModel.with_build`): each shape's
    trunk, limbs, neck and tail girths × :func:`~litege_core.synth.shape_space.draw_girth`,
    drawn from a stream of its own (the pose does not change); 0: none."""

    def describe(self) -> str:
        """A compact, stable description (part of a dataset factory's version)."""
        girth = f",girth{self.girth_std:g}" if self.girth_std else ""
        return (
            f"pose({self.perturb_degrees:g},{self.body_range[0]:g}-{self.body_range[1]:g},"
            f"{self.vertex_range[0]}-{self.vertex_range[1]},{int(self.subdivide)},"
            f"{self.attempts},{self.bend.describe()}{girth})"
        )


def bent_pose_settings(share: float) -> PoseSettings | None:
    """The default pose ranges with a ``share`` of the animals bent along the body
    (``litege data build --bend``); ``None`` (the defaults) when ``share`` is 0."""
    if not share:
        return None
    return PoseSettings(bend=BendSettings(probability=share))


@dataclass
class RiggedModel:
    """A loaded rigged model, welded and reduced to its body.

    Attributes:
        name: family name.
        tree: node hierarchy.
        mesh: the body's skinned mesh (``vertices (V, 3)`` bind positions, welded).
        clips: animations (at least one).
        scale: factor giving the skinned rest pose unit area.
        leg_joints: ``(J,)`` bool, skin joints counted as legs.
        free_joints: ``(J,)`` bool, skin joints whose subtree has no leg joint (perturbed).
    """

    name: str
    tree: gltf.NodeTree
    mesh: gltf.SkinnedMesh
    clips: list[gltf.Clip]
    scale: float
    leg_joints: NDArray
    free_joints: NDArray

    @functools.cached_property
    def body_axes(self) -> NDArray:
        """``(3, 3)`` rows ``(forward, lateral, up)`` of the rest pose (y up)."""
        return body_axes(self.rest_vertices())

    @functools.cached_property
    def radial_offsets(self) -> NDArray:
        """``(V, 3)`` bind-space offsets of each vertex from its bones' axes, blended by its
        skin weights; zero for the head, ears, jaw and eyes (:data:`KEEP_GIRTH`).

        A bone's axis runs from its joint to the mean of its child joints, or, for a joint
        without children, on along its parent's direction as far as the vertices it holds
        reach. Moving each vertex along this offset thins (or thickens) the limbs and the
        trunk around the skeleton without moving a joint."""
        mesh = self.mesh
        joints_at = np.linalg.inv(mesh.inverse_bind)[:, :3, 3]  # (J, 3) bind positions
        slot = {int(node): j for j, node in enumerate(mesh.joint_nodes)}
        parent = np.full(len(joints_at), -1)
        for j, node in enumerate(mesh.joint_nodes):
            up = int(self.tree.parents[node])
            while up >= 0 and up not in slot:
                up = int(self.tree.parents[up])
            parent[j] = slot.get(up, -1)
        dominant = mesh.joints[np.arange(len(mesh.vertices)), mesh.weights.argmax(axis=1)]
        ends = joints_at.copy()
        for j in range(len(joints_at)):
            children = np.flatnonzero(parent == j)
            if children.size:
                ends[j] = joints_at[children].mean(axis=0)
            elif parent[j] >= 0:
                direction = joints_at[j] - joints_at[parent[j]]
                direction /= max(float(np.linalg.norm(direction)), 1e-12)
                held = mesh.vertices[dominant == j] - joints_at[j]
                reach = float((held @ direction).max()) if held.size else 0.0
                ends[j] = joints_at[j] + max(reach, 0.0) * direction
        keep = np.array(
            [
                any(word in self.tree.names[node].lower() for word in KEEP_GIRTH)
                for node in mesh.joint_nodes
            ]
        )
        start, end = joints_at[mesh.joints], ends[mesh.joints]  # (V, K, 3)
        axis = end - start
        length2 = np.maximum(np.einsum("vkd,vkd->vk", axis, axis), 1e-18)
        along = np.clip(
            np.einsum("vkd,vkd->vk", mesh.vertices[:, None] - start, axis) / length2, 0.0, 1.0
        )
        offsets = mesh.vertices[:, None] - (start + along[..., None] * axis)
        weights = np.where(keep[mesh.joints], 0.0, mesh.weights)
        return np.einsum("vk,vkd->vd", weights, offsets)

    def with_build(self, girth: float) -> NDArray:
        """``(V, 3)`` bind vertices of a build ``girth`` (< 1 lean, > 1 stocky)."""
        return self.mesh.vertices + (girth - 1.0) * self.radial_offsets

    def rest_vertices(self) -> NDArray:
        """``(V, 3)`` skinned positions in the rest pose of the node tree (scaled)."""
        matrices = gltf.skin_matrices(self.tree, self.mesh, self.tree.local_matrices())
        return self.scale * gltf.linear_blend_skinning(
            self.mesh.vertices, self.mesh.joints, self.mesh.weights, matrices
        )


def load_rigged(path: str | Path, name: str | None = None) -> RiggedModel:
    """Load, weld and reduce a rigged glTF model (see the module docstring, step 1).

    Raises:
        ShapeFileError: unreadable file or no skinned mesh; InputError: no animation.
    """
    path = Path(path)
    doc = gltf.read_gltf(path)
    tree = gltf.node_tree(doc)
    raw = gltf.skinned_mesh(doc)
    clips = [c for c in gltf.clips(doc) if c.channels and c.duration >= 0.0]
    if not clips:
        raise InputError(f"{path} has no animation to sample poses from")
    welded = weld(raw.vertices, raw.faces)
    kept, faces = largest_body(welded.vertices, welded.faces)
    source = welded.representative[kept]
    mesh = gltf.SkinnedMesh(
        vertices=welded.vertices[kept],
        faces=faces,
        joints=raw.joints[source],
        weights=raw.weights[source],
        joint_nodes=raw.joint_nodes,
        inverse_bind=raw.inverse_bind,
    )
    local = tree.local_matrices()
    world = tree.global_matrices(local)
    rest = gltf.linear_blend_skinning(
        mesh.vertices, mesh.joints, mesh.weights, world[mesh.joint_nodes] @ mesh.inverse_bind
    )
    joint_y = world[mesh.joint_nodes][:, 1, 3]
    low, high = rest[:, 1].min(), rest[:, 1].max()
    leg_joints = joint_y < low + LEG_FRACTION * (high - low)
    holds_leg = np.zeros(tree.parents.size, dtype=bool)
    for node in mesh.joint_nodes[leg_joints]:
        while node >= 0 and not holds_leg[node]:
            holds_leg[node] = True
            node = tree.parents[node]
    return RiggedModel(
        name=name or path.stem,
        tree=tree,
        mesh=mesh,
        clips=clips,
        scale=unit_area_scale(rest, mesh.faces),
        leg_joints=leg_joints,
        free_joints=~holds_leg[mesh.joint_nodes],
    )


@functools.lru_cache(maxsize=32)
def cached_model(path: str, name: str) -> RiggedModel:
    """:func:`load_rigged`, memoized per process (models are small)."""
    return load_rigged(path, name)


def _random_rotations(rng: np.random.Generator, n: int, sigma_degrees: float) -> NDArray:
    """``(n, 4)`` quaternions (x, y, z, w) about random axes, angles ~N(0, σ) capped at 2.5σ."""
    axis = rng.normal(size=(n, 3))
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    sigma = np.radians(sigma_degrees)
    angle = np.clip(rng.normal(0.0, sigma, size=n), -2.5 * sigma, 2.5 * sigma)
    return np.concatenate([axis * np.sin(angle / 2)[:, None], np.cos(angle / 2)[:, None]], axis=1)


def quaternion_multiply(a: NDArray, b: NDArray) -> NDArray:
    """Hamilton products ``a ⊗ b`` of ``(..., 4)`` quaternions in (x, y, z, w) order."""
    ax, ay, az, aw = np.moveaxis(a, -1, 0)
    bx, by, bz, bw = np.moveaxis(b, -1, 0)
    return np.stack(
        [
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz,
        ],
        axis=-1,
    )


@dataclass(frozen=True)
class PoseDraw:
    """The random choices of one posed shape (for reports and tests)."""

    clip: str
    time: float
    body_scale: tuple[float, float, float]
    target_vertices: int
    bend: Bend | None = None
    girth: float = 1.0


def pose_model(
    model: RiggedModel, rng: np.random.Generator, settings: PoseSettings, girth: float = 1.0
) -> tuple[NDArray, PoseDraw]:
    """Posed body vertices ``(V, 3)`` (on ``model.mesh.faces``, unit-area scale) and the draw
    (steps 2–3 of the module docstring, before remeshing), of build ``girth``
    (:meth:`RiggedModel.with_build`; 1: the model's own)."""
    clip = model.clips[int(rng.integers(len(model.clips)))]
    t = float(rng.uniform(0.0, clip.duration)) if clip.duration > 0 else 0.0
    translation, rotation, scale = gltf.sample_pose(model.tree, clip, t)
    nodes = model.mesh.joint_nodes[model.free_joints]
    noise = _random_rotations(rng, nodes.size, settings.perturb_degrees)
    rotation[nodes] = quaternion_multiply(rotation[nodes], noise)
    body = rng.uniform(*settings.body_range, size=3)
    n_target = int(rng.integers(settings.vertex_range[0], settings.vertex_range[1] + 1))
    local = model.tree.local_matrices(translation, rotation, scale)
    matrices = gltf.skin_matrices(model.tree, model.mesh, local)
    bind = model.mesh.vertices if girth == 1.0 else model.with_build(girth)
    posed = gltf.linear_blend_skinning(bind, model.mesh.joints, model.mesh.weights, matrices)
    posed, bend = random_bend(rng, posed, model.body_axes, settings.bend)
    posed = (posed - posed.mean(axis=0)) * model.scale * body
    draw = PoseDraw(
        clip.name, t, (float(body[0]), float(body[1]), float(body[2])), n_target, bend, girth
    )
    return posed, draw


def finish_mesh(
    vertices: NDArray, faces: NDArray, target_vertices: int, subdivide: bool
) -> tuple[NDArray, NDArray]:
    """Optionally Loop-subdivide, remesh to ``target_vertices``, collapse slivers (smallest
    angle < 2°) and check the topology.

    Raises:
        ComputationError: the result is not a closed, oriented, single-component manifold
            without slivers.
    """
    if subdivide:
        vertices, faces = subdivide_loop(vertices, faces)
    vertices, faces = remesh(vertices, faces, target_vertices, tolerance=0.05)
    vertices, faces = collapse_slivers(vertices, faces, min_angle=2.0)
    report = manifold_report(vertices, faces)
    if not report.ok:
        raise ComputationError(f"remeshed shape is not a clean closed manifold: {report}")
    return vertices, faces


def posed_animal(
    model: RiggedModel, seed: int, settings: PoseSettings = PoseSettings()
) -> tuple[NDArray, NDArray, PoseDraw]:
    """The remeshed, posed shape ``(vertices (V, 3), faces (F, 3), draw)`` of ``seed``.

    Attempt ``k`` draws from ``default_rng([seed, k])``; the first draw whose remeshed
    surface passes the manifold check is returned.

    Raises:
        ComputationError: no attempt gave a clean manifold.
    """
    last: Exception | None = None
    girth = 1.0
    if settings.girth_std:
        girth = draw_girth(np.random.default_rng([seed, GIRTH_STREAM]), settings.girth_std)
    for attempt in range(settings.attempts):
        rng = np.random.default_rng([seed, attempt])
        posed, draw = pose_model(model, rng, settings, girth)
        try:
            vertices, faces = finish_mesh(
                posed, model.mesh.faces, draw.target_vertices, settings.subdivide
            )
        except ComputationError as exc:
            last = exc
            continue
        return vertices, faces, draw
    raise ComputationError(f"{model.name} seed {seed}: no clean remeshed pose ({last})")


__all__ = [
    "ANIMALS",
    "KHRONOS_FOX",
    "QUATERNIUS",
    "RIGGED_VERSION",
    "PoseDraw",
    "PoseSettings",
    "RiggedModel",
    "animal_path",
    "bent_pose_settings",
    "cached_model",
    "finish_mesh",
    "load_rigged",
    "pose_model",
    "posed_animal",
    "quaternion_multiply",
]
