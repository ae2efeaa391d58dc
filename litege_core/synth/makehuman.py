"""Posed human bodies from the CC0 MakeHuman base mesh, macro targets and default rig.

Files (the ``makehuman/`` folder of the train-data directory)::

    base.obj                    hm08 base mesh; group ``body`` is the watertight skin (quads)
    targets/*.target            sparse offsets "index dx dy dz" on the base mesh's vertices
    rigs/default.mhskel         JSON: bones (head/tail joint names, parent); joints (name →
                                base-mesh vertex indices whose mean is the joint position)
    rigs/default_weights.mhw    JSON: bone → [[vertex, weight], ...] skinning weights

A shape is a pure function of ``seed``:

1. **Body shape** (MakeHuman's macro scheme, young caucasian): gender ``g``, muscle ``m`` and
   weight ``w`` uniform in [0, 1]; offsets ``(1−g)·female + g·male`` plus, for each gender
   (factor ``1−g`` / ``g``), the universal muscle × weight targets interpolated bilinearly on
   MakeHuman's 3 × 3 grid {min, average, max}² at ``(2m, 2w)``. Only the four corner targets
   are available: the centre (average muscle and weight) is the base mesh (zero offset) and
   the edge midpoints are the means of their two corners.
2. **Skeleton**: joint positions are the means of their vertex groups on the shaped mesh.
3. **Pose** (random but plausible, degrees, relative to the A-pose rest): spine bend forward
   −10…30, sideways ±15 and twist ±20 spread over four spine bones; neck forward −15…30 and
   twist ±35; each arm raised −30…75 (−30 is down along the body) and swung forward −25…50,
   elbow bent −30…40 more (the rest elbow is bent ~50°); each leg spread −5…25 and swung
   forward −20…45, knee bent 0…70, foot ±15. Bone ``b`` gets the rest-space rotation ``R_b``
   about its head ``h_b``; the bone matrices compose down the hierarchy,
   ``M_b = M_parent · T(h_b) R_b T(−h_b)``, and the body is posed by linear blend skinning
   with the rig's weights. A seed posed in a steep mode (arms overhead, a knee past 90°, the
   one-legged balance, the forward bend: :func:`steep_angles`) overrides some of these angles.
4. The posed body is scaled along x/y/z by factors in ``body_range``, remeshed isotropically
   to ``vertex_range`` vertices, slivers collapsed, and checked to be a closed manifold (a
   failing draw is retried with the next sub-seed).
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.spatial.transform import Rotation

from litege_core.errors import ComputationError, InputError, ShapeFileError
from litege_core.synth.meshops import (
    collapse_slivers,
    manifold_report,
    remesh,
    unit_area_scale,
)
from litege_core.synth.poses import MAKEHUMAN_STEEP_MODES, steep_pose

MAKEHUMAN_VERSION = "makehuman-1"
SIDES = (".L", ".R")
FORWARD = np.array([0.0, 0.0, 1.0])
"""MakeHuman's base mesh is y-up, facing +z, with the ``.L`` side at +x."""
TARGETS = (
    "caucasian-female-young",
    "caucasian-male-young",
    "universal-female-young-maxmuscle-maxweight",
    "universal-female-young-maxmuscle-minweight",
    "universal-female-young-minmuscle-maxweight",
    "universal-female-young-minmuscle-minweight",
    "universal-male-young-maxmuscle-maxweight",
    "universal-male-young-maxmuscle-minweight",
    "universal-male-young-minmuscle-maxweight",
    "universal-male-young-minmuscle-minweight",
)


@dataclass(frozen=True)
class HumanSettings:
    """Ranges of the random bodies (see the module docstring)."""

    body_range: tuple[float, float] = (0.93, 1.07)
    vertex_range: tuple[int, int] = (4500, 5500)
    attempts: int = 6


@dataclass
class MakeHumanModel:
    """The loaded MakeHuman assets.

    Attributes:
        base: ``(N, 3)`` base-mesh vertices (all groups; joints use helper vertices).
        body: ``(Vb,)`` sorted indices of the ``body`` group's vertices in ``base``.
        faces: ``(F, 3)`` triangles of the body, indices into ``body``.
        targets: name → ``(indices (k,), offsets (k, 3))``.
        bones: bone names in hierarchy order (parents first).
        parents: ``(B,)`` parent bone index (-1 for the root).
        heads / tails: joint-group names of each bone's head and tail.
        joints: joint-group name → base-mesh vertex indices.
        weights: ``(Vb, B)`` CSR skinning weights, rows summing to 1.
    """

    base: NDArray
    body: NDArray
    faces: NDArray
    targets: dict[str, tuple[NDArray, NDArray]]
    bones: tuple[str, ...]
    parents: NDArray
    heads: tuple[str, ...]
    tails: tuple[str, ...]
    joints: dict[str, NDArray]
    weights: sparse.csr_matrix

    def bone(self, name: str) -> int:
        return self.bones.index(name)


def _read_obj_body(path: Path) -> tuple[NDArray, NDArray]:
    """All ``v`` positions and the ``body`` group's faces (fan-triangulated, 0-based)."""
    vertices: list[list[float]] = []
    faces: list[list[int]] = []
    group: str | None = None
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise ShapeFileError(f"cannot read {path}: {exc.strerror}") from exc
    for line in lines:
        if line.startswith("v "):
            vertices.append([float(x) for x in line.split()[1:4]])
        elif line.startswith("g "):
            group = line.split(maxsplit=1)[1].strip()
        elif line.startswith("f ") and group == "body":
            corners = [int(item.split("/")[0]) - 1 for item in line.split()[1:]]
            faces.extend(
                [corners[0], corners[i], corners[i + 1]] for i in range(1, len(corners) - 1)
            )
    if not faces:
        raise ShapeFileError(f"{path} has no faces in group 'body'")
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def _read_target(path: Path) -> tuple[NDArray, NDArray]:
    try:
        data = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise ShapeFileError(f"cannot read target {path}: {exc}") from exc
    return data[:, 0].astype(np.int64), data[:, 1:4].astype(np.float64)


def load_makehuman(directory: str | Path) -> MakeHumanModel:
    """Load the MakeHuman assets from ``directory`` (the train-data ``makehuman/`` folder).

    Raises:
        ShapeFileError: a file is missing or malformed.
    """
    directory = Path(directory)
    base, all_faces = _read_obj_body(directory / "base.obj")
    body = np.unique(all_faces)
    remap = np.full(base.shape[0], -1, dtype=np.int64)
    remap[body] = np.arange(body.size)
    faces = remap[all_faces]
    targets = {name: _read_target(directory / "targets" / f"{name}.target") for name in TARGETS}
    try:
        skeleton = json.loads((directory / "rigs" / "default.mhskel").read_text())
        weight_file = json.loads((directory / "rigs" / "default_weights.mhw").read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ShapeFileError(f"cannot read the MakeHuman rig in {directory}: {exc}") from exc
    bones_json = skeleton["bones"]
    order: list[str] = []
    placed: set[str] = set()
    pending = sorted(bones_json)
    while pending:
        progress = [
            b
            for b in pending
            if bones_json[b]["parent"] in placed or bones_json[b]["parent"] is None
        ]
        if not progress:
            raise ShapeFileError("the MakeHuman skeleton's hierarchy is not a tree")
        order.extend(progress)
        placed.update(progress)
        pending = [b for b in pending if b not in placed]
    index = {name: i for i, name in enumerate(order)}
    parents = np.array(
        [-1 if bones_json[b]["parent"] is None else index[bones_json[b]["parent"]] for b in order],
        dtype=np.int64,
    )
    rows, cols, vals = [], [], []
    for bone, pairs in weight_file["weights"].items():
        if bone not in index or not pairs:
            continue
        pairs_array = np.asarray(pairs, dtype=np.float64)
        vertex = pairs_array[:, 0].astype(np.int64)
        keep = remap[vertex] >= 0
        rows.append(remap[vertex[keep]])
        cols.append(np.full(int(keep.sum()), index[bone]))
        vals.append(pairs_array[keep, 1])
    weights = sparse.coo_matrix(
        (np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
        shape=(body.size, len(order)),
    ).tocsr()
    total = np.asarray(weights.sum(axis=1)).ravel()
    if (total <= 0).any():
        raise ShapeFileError("some body vertices have no skinning weight")
    weights = sparse.diags(1.0 / total) @ weights
    return MakeHumanModel(
        base=base,
        body=body,
        faces=faces,
        targets=targets,
        bones=tuple(order),
        parents=parents,
        heads=tuple(bones_json[b]["head"] for b in order),
        tails=tuple(bones_json[b]["tail"] for b in order),
        joints={k: np.asarray(v, dtype=np.int64) for k, v in skeleton["joints"].items()},
        weights=weights.tocsr(),
    )


@functools.lru_cache(maxsize=2)
def cached_makehuman(directory: str) -> MakeHumanModel:
    """:func:`load_makehuman`, memoized per process."""
    return load_makehuman(directory)


def corner_factors(muscle: float, weight: float) -> dict[tuple[str, str], float]:
    """Factors of the four corner targets ``(min|max muscle, min|max weight)`` for
    ``(muscle, weight) ∈ [0, 1]²``: bilinear interpolation on the 3 × 3 grid whose centre is
    zero and whose edge midpoints are the means of their corners (module docstring)."""
    u, v = 2.0 * float(np.clip(muscle, 0, 1)), 2.0 * float(np.clip(weight, 0, 1))
    i0, j0 = min(int(u), 1), min(int(v), 1)
    fu, fv = u - i0, v - j0
    along = {0: (1.0, 0.0), 1: (0.5, 0.5), 2: (0.0, 1.0)}  # grid node → (min, max) factors
    out = {(m, w): 0.0 for m in ("min", "max") for w in ("min", "max")}
    for i, wi in ((i0, 1.0 - fu), (i0 + 1, fu)):
        for j, wj in ((j0, 1.0 - fv), (j0 + 1, fv)):
            if (i, j) == (1, 1) or wi * wj == 0.0:
                continue
            for a, m in enumerate(("min", "max")):
                for b, w in enumerate(("min", "max")):
                    out[(m, w)] += wi * wj * along[i][a] * along[j][b]
    return out


def body_shape(model: MakeHumanModel, gender: float, muscle: float, weight: float) -> NDArray:
    """``(N, 3)`` base-mesh vertices with the macro targets of (gender, muscle, weight) ∈ [0, 1]³
    applied (module docstring, step 1)."""
    vertices = model.base.copy()
    genders = {"female": 1.0 - gender, "male": gender}
    corners = corner_factors(muscle, weight)
    factors = {f"caucasian-{g}-young": gw for g, gw in genders.items()}
    for g, gw in genders.items():
        for (m, w), factor in corners.items():
            factors[f"universal-{g}-young-{m}muscle-{w}weight"] = gw * factor
    for name, factor in factors.items():
        if factor > 0:
            indices, offsets = model.targets[name]
            np.add.at(vertices, indices, factor * offsets)
    return vertices


def joint_positions(model: MakeHumanModel, vertices: NDArray) -> tuple[NDArray, NDArray]:
    """``(heads (B, 3), tails (B, 3))`` of the bones on the (shaped) base-mesh ``vertices``."""
    heads = np.stack([vertices[model.joints[name]].mean(axis=0) for name in model.heads])
    tails = np.stack([vertices[model.joints[name]].mean(axis=0) for name in model.tails])
    return heads, tails


def bone_matrices(model: MakeHumanModel, heads: NDArray, rotations: dict[str, NDArray]) -> NDArray:
    """``(B, 4, 4)`` skinning matrices ``M_b = M_parent · T(h_b) R_b T(−h_b)`` for rest-space
    rotations ``R_b`` (``(3, 3)``; identity for bones not in ``rotations``)."""
    n = len(model.bones)
    out = np.empty((n, 4, 4))
    for b in range(n):
        local = np.eye(4)
        rotation = rotations.get(model.bones[b])
        if rotation is not None:
            local[:3, :3] = rotation
            local[:3, 3] = heads[b] - rotation @ heads[b]
        parent = model.parents[b]
        out[b] = local if parent < 0 else out[parent] @ local
    return out


def skin(model: MakeHumanModel, body_vertices: NDArray, matrices: NDArray) -> NDArray:
    """``(Vb, 3)`` linear-blend-skinned body: ``Σ_b w[v, b] · M_b · v``."""
    blended = (model.weights @ matrices.reshape(len(model.bones), 16)).reshape(-1, 4, 4)
    return np.einsum("vij,vj->vi", blended[:, :3, :3], body_vertices) + blended[:, :3, 3]


def _rot(axis: NDArray, degrees: float) -> NDArray:
    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * np.radians(degrees)).as_matrix()


@dataclass(frozen=True)
class HumanDraw:
    """The random choices of one human (for reports and tests)."""

    gender: float
    muscle: float
    weight: float
    angles: dict[str, float]
    body_scale: tuple[float, float, float]
    target_vertices: int
    mode: str | None = None
    """The steep pose (:func:`steep_angles`), ``None`` for a drawn one."""


def draw_angles(rng: np.random.Generator) -> dict[str, float]:
    """The drawn pose angles in degrees (module docstring, step 3), keyed ``spine_forward``,
    ``spine_side``, ``spine_twist``, ``neck_forward``, ``neck_twist`` and, per side ``.L`` /
    ``.R``, ``arm_raise``, ``arm_swing``, ``elbow``, ``leg_spread``, ``leg_swing``, ``knee``,
    ``foot``."""
    angles: dict[str, float] = {
        "spine_forward": rng.uniform(-10, 30),
        "spine_side": rng.uniform(-15, 15),
        "spine_twist": rng.uniform(-20, 20),
        "neck_forward": rng.uniform(-15, 30),
        "neck_twist": rng.uniform(-35, 35),
    }
    for side in SIDES:
        for name, low, high in (
            ("arm_raise", -30, 75),
            ("arm_swing", -25, 50),
            ("elbow", -30, 40),
            ("leg_spread", -5, 25),
            ("leg_swing", -20, 45),
            ("knee", 0, 70),
            ("foot", -15, 15),
        ):
            angles[f"{name}{side}"] = rng.uniform(low, high)
    return {k: float(v) for k, v in angles.items()}


def steep_angles(mode: str, rng: np.random.Generator) -> dict[str, float]:
    """The angles (degrees, :func:`draw_angles` keys) that pose a body in a steep ``mode`` of
    :data:`~litege_core.synth.poses.MAKEHUMAN_STEEP_MODES`; the others keep their drawn values.

    * ``arms_overhead``: both arms raised 120–160° (hands above the head), elbows −50…0 (−50
      straightens the rest pose's bent elbow);
    * ``leg_lifted``: one leg's knee bent 90–135°, the thigh swung −35…50 (foot lifted
      behind or knee raised in front);
    * ``one_leg_balance``: one thigh spread 35–70° and swung 10–45, knee 105–145 (the foot
      against the other leg), arms overhead half the time;
    * ``bending_forward``: both thighs swung 55–95 (hip flexion), spine forward 15–40, knees
      0–25, arms raised 35–70 and swung 60–110 (reaching towards the feet).

    Raises:
        InputError: ``mode`` is not a MakeHuman steep mode.
    """
    if mode not in MAKEHUMAN_STEEP_MODES:
        raise InputError(f"unknown MakeHuman steep mode {mode!r}: {MAKEHUMAN_STEEP_MODES}")
    out: dict[str, float] = {}

    def arms_overhead() -> None:
        for side in SIDES:
            out[f"arm_raise{side}"] = rng.uniform(120, 160)
            out[f"arm_swing{side}"] = rng.uniform(-15, 25)
            out[f"elbow{side}"] = rng.uniform(-50, 0)

    if mode == "arms_overhead":
        arms_overhead()
    elif mode == "leg_lifted":
        side = SIDES[int(rng.integers(2))]
        out[f"knee{side}"] = rng.uniform(90, 135)
        out[f"leg_swing{side}"] = rng.uniform(-35, 50)
    elif mode == "one_leg_balance":
        side = SIDES[int(rng.integers(2))]
        out[f"leg_spread{side}"] = rng.uniform(35, 70)
        out[f"leg_swing{side}"] = rng.uniform(10, 45)
        out[f"knee{side}"] = rng.uniform(105, 145)
        if rng.random() < 0.5:
            arms_overhead()
    else:  # bending_forward
        out["spine_forward"] = rng.uniform(15, 40)
        for side in SIDES:
            out[f"leg_swing{side}"] = rng.uniform(55, 95)
            out[f"knee{side}"] = rng.uniform(0, 25)
            out[f"arm_raise{side}"] = rng.uniform(35, 70)
            out[f"arm_swing{side}"] = rng.uniform(60, 110)
    return {k: float(v) for k, v in out.items()}


def pose_rotations(
    model: MakeHumanModel, heads: NDArray, tails: NDArray, angles: dict[str, float]
) -> dict[str, NDArray]:
    """Rest-space bone rotations ``(3, 3)`` of the pose ``angles`` (:func:`draw_angles` keys,
    degrees) on a skeleton with joint ``heads`` / ``tails`` ``(B, 3)``."""
    x, y, z = np.eye(3)
    rotations: dict[str, NDArray] = {}
    for bone in ("spine04", "spine03", "spine02", "spine01"):
        rotations[bone] = (
            _rot(y, angles["spine_twist"] / 4)
            @ _rot(z, angles["spine_side"] / 4)
            @ _rot(x, angles["spine_forward"] / 4)
        )
    rotations["neck01"] = _rot(y, angles["neck_twist"]) @ _rot(x, angles["neck_forward"])

    def direction(bone: str) -> NDArray:
        b = model.bone(bone)
        d = tails[b] - heads[b]
        return d / np.linalg.norm(d)

    for side, sign in zip(SIDES, (1.0, -1.0), strict=True):
        upper = direction(f"upperarm01{side}")
        fore = direction(f"lowerarm01{side}")
        rotations[f"upperarm01{side}"] = _rot(z, sign * angles[f"arm_raise{side}"]) @ _rot(
            np.cross(upper, FORWARD), angles[f"arm_swing{side}"]
        )
        hinge = np.cross(upper, fore)
        if np.linalg.norm(hinge) > 1e-6:
            rotations[f"lowerarm01{side}"] = _rot(hinge, angles[f"elbow{side}"])
        rotations[f"upperleg01{side}"] = _rot(z, sign * angles[f"leg_spread{side}"]) @ _rot(
            x, -angles[f"leg_swing{side}"]
        )
        rotations[f"lowerleg01{side}"] = _rot(x, angles[f"knee{side}"])
        rotations[f"foot{side}"] = _rot(x, angles[f"foot{side}"])
    return rotations


def random_pose(
    model: MakeHumanModel,
    heads: NDArray,
    tails: NDArray,
    rng: np.random.Generator,
    mode: str | None = None,
) -> tuple[dict[str, NDArray], dict[str, float]]:
    """Random rest-space bone rotations (module docstring, step 3) and the drawn angles; a
    steep ``mode`` (:func:`steep_angles`) overrides some of the drawn angles."""
    angles = draw_angles(rng)
    if mode is not None:
        angles.update(steep_angles(mode, rng))
    return pose_rotations(model, heads, tails, angles), angles


def pose_human(
    model: MakeHumanModel,
    rng: np.random.Generator,
    settings: HumanSettings,
    mode: str | None = None,
) -> tuple[NDArray, HumanDraw]:
    """A shaped, posed body ``(Vb, 3)`` on ``model.faces`` (unit-area scale, centred) and the
    draw (module docstring, steps 1–3 and the scale of step 4); ``mode``: a steep pose
    (:func:`steep_angles`) or ``None`` for the drawn one."""
    gender, muscle, weight = (float(v) for v in rng.uniform(0.0, 1.0, size=3))
    shaped = body_shape(model, gender, muscle, weight)
    heads, tails = joint_positions(model, shaped)
    rotations, angles = random_pose(model, heads, tails, rng, mode)
    body = rng.uniform(*settings.body_range, size=3)
    n_target = int(rng.integers(settings.vertex_range[0], settings.vertex_range[1] + 1))
    rest = shaped[model.body]
    posed = skin(model, rest, bone_matrices(model, heads, rotations))
    posed = (posed - posed.mean(axis=0)) * unit_area_scale(rest, model.faces) * body
    draw = HumanDraw(
        gender,
        muscle,
        weight,
        angles,
        (float(body[0]), float(body[1]), float(body[2])),
        n_target,
        mode,
    )
    return posed, draw


def posed_human(
    model: MakeHumanModel,
    seed: int,
    settings: HumanSettings = HumanSettings(),
    steep_share: float = 0.0,
) -> tuple[NDArray, NDArray, HumanDraw]:
    """The remeshed human ``(vertices (V, 3), faces (F, 3), draw)`` of ``seed``; attempt ``k``
    draws from ``default_rng([seed, k])``. A ``steep_share`` of the seeds is posed in a steep
    mode (:func:`~litege_core.synth.poses.steep_pose`); the other seeds keep their bodies.

    Raises:
        ComputationError: no attempt gave a clean closed manifold.
    """
    mode = steep_pose("makehuman", seed, steep_share)
    last: Exception | None = None
    for attempt in range(settings.attempts):
        rng = np.random.default_rng([seed, attempt])
        posed, draw = pose_human(model, rng, settings, mode)
        try:
            vertices, faces = remesh(posed, model.faces, draw.target_vertices, tolerance=0.05)
            vertices, faces = collapse_slivers(vertices, faces, min_angle=2.0)
            report = manifold_report(vertices, faces)
            if not report.ok:
                raise ComputationError(f"remeshed human is not a clean closed manifold: {report}")
        except ComputationError as exc:
            last = exc
            continue
        return vertices, faces, draw
    raise ComputationError(f"makehuman seed {seed}: no clean remeshed pose ({last})")


__all__ = [
    "MAKEHUMAN_VERSION",
    "SIDES",
    "TARGETS",
    "HumanDraw",
    "HumanSettings",
    "MakeHumanModel",
    "body_shape",
    "bone_matrices",
    "cached_makehuman",
    "corner_factors",
    "draw_angles",
    "joint_positions",
    "load_makehuman",
    "pose_human",
    "pose_rotations",
    "posed_human",
    "random_pose",
    "skin",
    "steep_angles",
]
