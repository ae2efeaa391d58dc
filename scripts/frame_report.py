"""Frame failures of a matching model: T-Net frame against judged frames (issue 15, step 1).

Usage:
    python scripts/frame_report.py quadrupeds [--procedural 60] [--eval-data ../shared/eval-data] \
        [--steep 40] [--per-shape]

Each shape is randomly rotated (seeded) and prepared with ``frames="tnet"`` and
``frames="judged"``; the error of a frame is the angle (rad) between the rotation it applies
and the true one; a failure is an angle above 0.66 rad (the reference's T-Net rejection filter).

* **procedural**: held-out test-split shapes (seeds 2,000,100 + k, families cycled, the pose
  mode each seed draws), whose true frame is the generator's (for ``lying`` animals that is the
  ground frame, the body rolled ~83° on its side: a body-upright frame counts as a failure);
* **steep** (``--steep N``, a quadruped model): the same seeds posed rearing, leaping,
  sitting up or lying on the belly (``litege_core.synth.poses.QUADRUPED_STEEP_MODES``,
  families cycled, then the modes), the trunk steep, stretched or low, in the ground frame as
  real animals are;
* **TOSCA** (read from ``--eval-data`` when present): the 31 ``tosca_5k`` poses and the 4
  high-resolution ``tosca_landmarks`` rest poses. TOSCA files share one frame (x: the animal's
  left-right axis, z: up, −y: forward), so the true canonical rotation of every file is the
  fixed ``C`` below (the T-Net gets cat0, dog0, horse0 within 0.2 rad of it). A rearing or
  sitting pose has no unambiguous upright frame, so part of these failures is ill-posed;
  **agreement** (convention-free) is the share of same-class pose pairs whose two frames,
  expressed in the file frame, differ by at most 0.66 rad.
* **rigged animals** (a ``quadruped`` model, ``--rigged N``, default 40): the posed CC0 animals of
  ``../shared/train-data`` (``litege_core.train.tnet.collection_shape_set``, val seeds: never
  in a T-Net's training split), randomly rotated; their true frame is the template's. Not a dev
  set: what frame settings are chosen on besides the procedural shapes;
* **FAUST** (a ``biped`` model): the 20 ``faust_5k`` humans, which share one file frame too.
  Our biped canonical frame is not tied to that convention, so the reference is the
  **consensus** of the 20 frames (the rotation nearest their mean, in the file frame): a failure
  is a frame more than 0.66 rad from it, and agreement is over all 190 pairs.

With ``--oracle`` the rigged and TOSCA tables (and the per-shape table) gain the best of the
candidate frames a judged frame is chosen from (the T-Net's and the 24 principal-axis frames, for
shapes whose turned T-Net runs split; the T-Net's alone where they agree): the floor any score of
those candidates could reach. ``--sagittal`` adds candidates that owe nothing to the principal
axes: an animal is mirror-symmetric about its sagittal plane up to its pose, so the normals of
the shape's best mirror-symmetry planes (:func:`symmetry_normals`) are candidate left-right axes,
each with 48 frames about it (:func:`sagittal_rotations`); the tables gain their best
(``sagittal oracle``), the frame the judge keeps among them (``judged over sagittal``) and
the T-Net's frame laid on the nearest of those planes (``tnet snapped``, :func:`snapped`).
``--intrinsic`` adds frames that owe nothing to the pose
(:mod:`litege_core.matching.intrinsic`, ``frames="intrinsic"``): each
reference animal mapped onto the mesh by a wave-kernel functional map, and the rotation that
best fits its canonical points to their matches; TOSCA gains the frame of the lowest fit
residual (``intrinsic``), the best reference's (``intrinsic oracle``, TOSCA), and three ways of
choosing between them and the T-Net's frame (:data:`INTRINSIC_CHOICES`).

Prints a markdown block; every number comes from this script.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import re
from collections.abc import Iterable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from scipy.spatial.transform import Rotation

from litege_core.io import load_shape
from litege_core.matching import MatchingModel
from litege_core.matching.intrinsic import intrinsic_frames
from litege_core.matching.judge import FrameJudge
from litege_core.shape import Shape
from litege_core.synth import families, generate_shape
from litege_core.synth.poses import EXTRA_MODES
from litege_core.variants import random_rotation

FAILURE = 0.66
TOSCA_TO_CANONICAL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
"""Rows: canonical x, y, z in TOSCA file coordinates (``q = C f``)."""


def angle(a: np.ndarray, b: np.ndarray) -> float:
    """Geodesic angle (rad) between two rotations."""
    return float(np.arccos(np.clip((np.trace(a.T @ b) - 1.0) / 2.0, -1.0, 1.0)))


class Found(NamedTuple):
    """A shape's frame prepared with one ``frames`` mode."""

    rotation: np.ndarray
    name: str  # MatchingShape.frame
    check: str  # MatchingShape.frame_check


def frames_of(model: MatchingModel, shapes: list[Shape], mode: str) -> list[Found]:
    """The frame of each shape prepared with ``frames=mode``."""
    out = []
    for shape in shapes:
        prepared = model.prepare(shape, frames=mode)
        rotation = np.asarray(prepared.transform.rotation)
        out.append(Found(rotation, prepared.frame, prepared.frame_check))
    return out


def tnet_frame(prepared) -> tuple:
    """``(transform, cloud, scaling)`` of a shape prepared with ``frames="tnet"``: its entry of
    ``align_shapes``, what :func:`~litege_core.matching.frame.candidate_turns` reads."""
    return (prepared.transform, np.asarray(prepared._lazy["cloud"], np.float64), prepared.scaling)


def candidate_rotations(model: MatchingModel, prepared) -> list[np.ndarray]:
    """The frames (``Transform.rotation`` of each) judged frames choose from for a shape
    prepared with ``frames="tnet"``: the T-Net's, and where its turned runs split also the 24
    principal-axis frames (seed 0, as ``MatchingModel.prepare``)."""
    from litege_core.matching.frame import candidate_turns, turned

    frame = tnet_frame(prepared)
    turns = candidate_turns(model.bundle.tnet, [frame], model.pipeline.n_tnet_points, 0)[0]
    if turns is None:
        return [np.asarray(prepared.transform.rotation)]
    return [turned(prepared.transform, turn).rotation for turn in turns]


SAGITTAL_DIRECTIONS = 600
"""Directions (a Fibonacci sphere, upper half kept) tried as normals of the symmetry plane."""
SAGITTAL_PLANES = 3
"""Symmetry planes kept per shape (local minima at least 0.5 rad apart)."""
SAGITTAL_TURNS = 24
"""Frames per plane normal and sign: turns of the other two axes about it (15° apart)."""
SYMMETRY_TRIM = 0.8
"""Share of the mirrored points (the nearest) whose distances make a plane's residual: a
pose's lifted leg or turned head should not hide the body's symmetry."""


def hemisphere(count: int) -> np.ndarray:
    """Unit directions ``(≈count/2, 3)`` of a Fibonacci sphere with ``z ≥ 0``."""
    i = np.arange(count) + 0.5
    polar, azimuth = np.arccos(1.0 - 2.0 * i / count), np.pi * (1.0 + 5**0.5) * i
    directions = np.stack(
        [np.cos(azimuth) * np.sin(polar), np.sin(azimuth) * np.sin(polar), np.cos(polar)], axis=1
    )
    return directions[directions[:, 2] >= 0.0]


def mirror_residuals(points: np.ndarray, tree, normals: np.ndarray) -> np.ndarray:
    """Trimmed mean distance ``(N,)`` from each mirror image of ``points`` ``(P, 3)`` (centred)
    across the plane through the origin with normal ``normals[n]`` to ``points`` (``tree``)."""
    mirrored = points[None] - 2.0 * (points @ normals.T).T[:, :, None] * normals[:, None, :]
    distances = tree.query(mirrored.reshape(-1, 3))[0].reshape(len(normals), -1)
    kept = int(SYMMETRY_TRIM * points.shape[0])
    return np.sort(distances, axis=1)[:, :kept].mean(axis=1)


def symmetry_normals(points: np.ndarray, count: int = SAGITTAL_PLANES) -> np.ndarray:
    """Normals ``(count, 3)`` of the ``count`` best mirror-symmetry planes of a cloud ``(P, 3)``
    through its centroid: the lowest :func:`mirror_residuals` over :func:`hemisphere`
    directions at least 0.5 rad apart, each refined by a shrinking-step descent."""
    from scipy.spatial import cKDTree

    points = points - points.mean(axis=0)
    tree = cKDTree(points)
    directions = hemisphere(SAGITTAL_DIRECTIONS)
    residuals = mirror_residuals(points, tree, directions)
    starts: list[np.ndarray] = []
    for index in np.argsort(residuals):
        if all(abs(directions[index] @ kept) < np.cos(0.5) for kept in starts):
            starts.append(directions[index])
        if len(starts) == count:
            break
    normals = []
    for normal in starts:
        best, step = mirror_residuals(points, tree, normal[None])[0], 0.1
        while step > 0.01:
            helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
            t1 = np.cross(normal, helper)
            t1 /= np.linalg.norm(t1)
            moves = np.array(
                [normal + step * sign * t for t in (t1, np.cross(normal, t1)) for sign in (1, -1)]
            )
            moves /= np.linalg.norm(moves, axis=1, keepdims=True)
            scores = mirror_residuals(points, tree, moves)
            if scores.min() < best:
                normal, best = moves[int(np.argmin(scores))], float(scores.min())
            else:
                step /= 2.0
        normals.append(normal)
    return np.array(normals)


def sagittal_rotations(normal: np.ndarray, turns: int = SAGITTAL_TURNS) -> np.ndarray:
    """Rotations ``(2·turns, 3, 3)`` whose first row (the canonical left-right axis) is
    ``±normal``, the other two turned about it in ``turns`` equal steps."""
    out = []
    for lateral in (normal, -normal):
        helper = np.eye(3)[int(np.argmin(np.abs(lateral)))]
        u = np.cross(lateral, helper)
        u /= np.linalg.norm(u)
        v = np.cross(lateral, u)
        for theta in np.arange(turns) * 2.0 * np.pi / turns:
            up = np.cos(theta) * u + np.sin(theta) * v
            out.append(np.stack([lateral, up, np.cross(lateral, up)]))
    return np.array(out)


def plane_normals(prepared) -> np.ndarray:
    """:func:`symmetry_normals` ``(3, 3)`` of a shape prepared with ``frames="tnet"`` (2,000 of
    its descriptor cloud's points, in the shape's input coordinates)."""
    from litege_core.matching.frame import subsample

    transform, cloud, _ = tnet_frame(prepared)
    return symmetry_normals(subsample(cloud @ transform.rotation, 2000, 0))


def sagittal_candidates(prepared, normals: np.ndarray) -> list[np.ndarray]:
    """The T-Net's frame and the frames of :func:`sagittal_rotations` about each of the
    ``normals`` (:func:`plane_normals`) of a shape prepared with ``frames="tnet"``
    (``Transform.rotation`` of each)."""
    rotations = [np.asarray(prepared.transform.rotation)]
    for normal in normals:
        rotations += list(sagittal_rotations(normal))
    return rotations


def snapped(rotation: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """``rotation`` (rows: the canonical axes in shape coordinates) turned by the smallest
    rotation that lays its left-right axis (row 0) on the nearest of ``normals`` ``(K, 3)`` (up
    to sign): the frame's heading and up kept as far as the symmetry plane allows."""
    lateral = rotation[0]
    normal = normals[int(np.argmax(np.abs(normals @ lateral)))]
    normal = normal * np.sign(normal @ lateral)
    axis = np.cross(lateral, normal)
    sine, cosine = np.linalg.norm(axis), float(lateral @ normal)
    if sine < 1e-12:
        return rotation
    turn = Rotation.from_rotvec(axis / sine * np.arctan2(sine, cosine)).as_matrix()
    return rotation @ turn.T


def judge_over(
    model: MatchingModel, shape: Shape, prepared, rotations: list[np.ndarray]
) -> np.ndarray:
    """The rotation the frame judge keeps among ``rotations`` (the T-Net's frame first, with the
    default margin) for ``shape`` prepared with ``frames="tnet"``, as judged frames keep one
    among theirs."""
    from litege_core.matching.judge import choose

    turns = np.array([r @ prepared.transform.rotation.T for r in rotations])
    scores = model._judge_scores([(shape, tnet_frame(prepared))], [turns])[0]
    return rotations[choose(scores)]


def alternative_errors(
    model: MatchingModel,
    shapes: list[Shape],
    rotations: list[np.ndarray],
    target: np.ndarray,
    sagittal: bool,
) -> dict[str, list[float]]:
    """Per shape, the angle (rad) from its true frame (``r @ rotation`` against ``target``) of:
    ``oracle``, the best of the judged candidates (:func:`candidate_rotations`); with
    ``sagittal`` also ``sagittal oracle``, the best of :func:`sagittal_candidates`, and
    ``judged over sagittal``, the frame the judge keeps among those (both the T-Net's frame
    alone where its turned runs agree, as judged frames), and ``tnet snapped``, the T-Net's
    frame laid on the nearest symmetry plane (:func:`snapped`)."""
    out: dict[str, list[float]] = {"oracle": []}
    if sagittal:
        out.update({"sagittal oracle": [], "judged over sagittal": [], "tnet snapped": []})
    for shape, rotation in zip(shapes, rotations, strict=True):
        prepared = model.prepare(shape, frames="tnet")
        judged = candidate_rotations(model, prepared)
        out["oracle"].append(min(angle(r @ rotation, target) for r in judged))
        if sagittal:
            split = len(judged) > 1  # its turned T-Net runs split: judged frames judge it
            normals = plane_normals(prepared)
            candidates = sagittal_candidates(prepared, normals) if split else judged
            out["sagittal oracle"].append(min(angle(r @ rotation, target) for r in candidates))
            kept = judge_over(model, shape, prepared, candidates) if split else judged[0]
            out["judged over sagittal"].append(angle(kept @ rotation, target))
            tnet_snapped = snapped(np.asarray(prepared.transform.rotation), normals)
            out["tnet snapped"].append(angle(tnet_snapped @ rotation, target))
    return out


INTRINSIC_CHOICES = (
    "intrinsic",
    "intrinsic where split",
    "judged over intrinsic",
    "judged over intrinsic where split",
)
"""Frames ``--intrinsic`` reports (:func:`intrinsic_choices`)."""


def intrinsic_choices(
    model: MatchingModel, shapes: list[Shape], to_file: list[np.ndarray]
) -> tuple[dict[str, list[np.ndarray]], list[np.ndarray], list[str]]:
    """Per shape, in file coordinates (``frame @ to_file``, the shape's input rotation; the
    identity is the true frame of a generated or rigged shape), the
    frames of :data:`INTRINSIC_CHOICES`: the intrinsic frame of the lowest residual
    (:func:`~litege_core.matching.intrinsic.intrinsic_frames`), the same only where the
    T-Net's turned runs split (else the T-Net's frame, as judged frames do), the frame the
    judge keeps among the T-Net's and every reference's intrinsic frame (:func:`judge_over`),
    and the same only where the runs split. Also every reference's frame ``(R, 3, 3)`` per
    shape and the family of the lowest residual."""
    chosen: dict[str, list[np.ndarray]] = {name: [] for name in INTRINSIC_CHOICES}
    every, names = [], []
    for shape, rotation in zip(shapes, to_file, strict=True):
        assert shape.faces is not None  # rigged animals, TOSCA and FAUST are meshes
        frames = intrinsic_frames(shape.vertices, shape.faces, model.category)
        best = min(frames, key=lambda frame: frame.residual)
        prepared = model.prepare(shape, frames="tnet")
        tnet = np.asarray(prepared.transform.rotation)
        split = len(candidate_rotations(model, prepared)) > 1
        judged = judge_over(model, shape, prepared, [tnet] + [f.rotation for f in frames])
        picks = (best.rotation, best.rotation if split else tnet, judged, judged if split else tnet)
        for name, frame in zip(INTRINSIC_CHOICES, picks, strict=True):
            chosen[name].append(frame @ rotation)
        every.append(np.array([frame.rotation @ rotation for frame in frames]))
        names.append(best.family)
    return chosen, every, names


def consensus(rotations: list[np.ndarray]) -> np.ndarray:
    """The rotation nearest (Frobenius) the mean of ``rotations``."""
    u, _, vt = np.linalg.svd(np.mean(rotations, axis=0))
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def rotated(
    meshes: Iterable[tuple[np.ndarray, np.ndarray | None]], seed: int, salt: int
) -> tuple[list[Shape], list[np.ndarray]]:
    """Each ``(vertices, faces)`` as a shape randomly rotated (seeded by ``seed``, ``salt`` and
    its position), and those rotations."""
    shapes, rotations = [], []
    for k, (vertices, faces) in enumerate(meshes):
        rotation = random_rotation(np.random.default_rng([seed, salt, k]))
        shapes.append(Shape.from_arrays(np.asarray(vertices) @ rotation.T, faces))
        rotations.append(rotation)
    return shapes, rotations


def rotated_files(files: list[Path], seed: int, salt: int) -> tuple[list[Shape], list[np.ndarray]]:
    """The files' shapes, each randomly rotated (seeded), and those rotations."""
    loaded = (load_shape(path) for path in files)
    return rotated(((shape.vertices, shape.faces) for shape in loaded), seed, salt)


def errors_to_truth(found: list[Found], truths: list[np.ndarray]) -> list[float]:
    """Angle (rad) of each found frame from the true one (the inverse of the input rotation)."""
    return [angle(f.rotation @ t, np.eye(3)) for f, t in zip(found, truths, strict=True)]


def mode_errors(
    model: MatchingModel, shapes: list[Shape], truths: list[np.ndarray]
) -> dict[str, tuple[list[float], list[Found]]]:
    """Per frame mode (``tnet``, ``judged``): :func:`errors_to_truth` of the shapes' frames and
    the frames."""
    out = {}
    for mode in ("tnet", "judged"):
        found = frames_of(model, shapes, mode)
        out[mode] = (errors_to_truth(found, truths), found)
    return out


def switched_count(found: list[Found]) -> int:
    """How many frames are not the T-Net's."""
    return sum(f.name != "tnet" for f in found)


def check_rows(label: str, mode: str, errors: list[float], found: list[Found]) -> list[str]:
    """Rows of the frames by their frame check (``MatchingShape.frame_check``: what a user is
    told of each prepared shape), for a mode that checks them."""
    rows = []
    for check in ("agreed", "split"):
        chosen = [e for e, f in zip(errors, found, strict=True) if f.check == check]
        if chosen:
            rows.append(f"| {label}, T-Net runs {check} | {mode} | {summary(chosen)} |")
    return rows


def summary(errors: list[float]) -> str:
    values = np.asarray(errors)
    return (
        f"{values.size} | {np.median(values):.2f} | {values.mean():.2f} | "
        f"{100 * (values > FAILURE).mean():.1f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("model", nargs="?", default="quadrupeds")
    parser.add_argument("--procedural", type=int, default=60)
    parser.add_argument("--eval-data", default="../shared/eval-data")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--rigged", type=int, default=40, help="posed rigged animals (0: none)")
    parser.add_argument(
        "--steep",
        type=int,
        default=0,
        help="procedural animals in the steep modes (rearing, leaping, sitting up, couchant; "
        "0: none)",
    )
    parser.add_argument("--cache", default="out/frame-report-shapes", help="rigged shape cache")
    parser.add_argument(
        "--oracle",
        action="store_true",
        help="also the best judged candidate frames (rigged and TOSCA rows, per-shape column)",
    )
    parser.add_argument(
        "--sagittal",
        action="store_true",
        help="with --oracle: also frames about symmetry-plane normals (their best, the judge's)",
    )
    parser.add_argument(
        "--reference-poses",
        default="",
        help="comma-separated pose modes of extra reference animals for the judge "
        "(e.g. sitting_upright,rearing,couchant; default: rest-pose references only)",
    )
    parser.add_argument(
        "--intrinsic",
        action="store_true",
        help="also intrinsic frames (rigged, TOSCA and FAUST meshes; needs pyFM; seconds per "
        "shape): "
        "reference animals mapped by wave-kernel functional maps, then a robust rotation fit",
    )
    parser.add_argument(
        "--per-shape",
        action="store_true",
        help="also list every real shape: the frame each mode kept and its angle (rad)",
    )
    args = parser.parse_args()
    torch.set_num_threads(1)
    model = MatchingModel.load(args.model)
    reference_poses = tuple(p for p in args.reference_poses.split(",") if p)
    if reference_poses and (judge := model.frame_judge) is not None:
        model.frame_judge = FrameJudge(
            judge.folded,
            judge.networks,
            model.bundle.basis,
            model.category,
            model.device,
            reference_poses=reference_poses,
        )
    names = families(model.category)
    rows: list[str] = []
    switched: dict[str, int] = {}
    per_shape: dict[str, dict[str, tuple[str, float]]] = {}  # shape → mode → (frame, angle)

    # ------------------------------------------------------------------ procedural
    generated = [
        generate_shape(model.category, names[k % len(names)], 2_000_100 + k)
        for k in range(args.procedural)
    ]
    shapes, truths = rotated(((g.vertices, g.faces) for g in generated), args.seed, 17)
    poses = [g.pose for g in generated]
    for mode, (errors, found) in mode_errors(model, shapes, truths).items():
        rows.append(f"| procedural (test seeds), all poses | {mode} | {summary(errors)} |")
        upright = [e for e, p in zip(errors, poses, strict=True) if p != "lying"]
        rows.append(f"| procedural, poses other than lying | {mode} | {summary(upright)} |")
        switched[f"procedural {mode}"] = switched_count(found)

    # ------------------------------------------------------------------ steep poses
    steep_modes = EXTRA_MODES[model.category]
    if args.steep and steep_modes:
        generated = [
            generate_shape(
                model.category,
                names[k % len(names)],
                2_000_100 + k,
                steep_modes[(k // len(names)) % len(steep_modes)],
            )
            for k in range(args.steep)
        ]
        shapes, truths = rotated(((g.vertices, g.faces) for g in generated), args.seed, 19)
        for mode, (errors, found) in mode_errors(model, shapes, truths).items():
            rows.append(f"| procedural (test seeds), steep modes | {mode} | {summary(errors)} |")
            rows += check_rows("procedural, steep modes", mode, errors, found)
            switched[f"steep {mode}"] = switched_count(found)

    # ------------------------------------------------------------------ rigged animals
    if args.rigged and model.category == "quadruped":
        from litege_core.datasets.factories import train_data_root
        from litege_core.train.tnet.shapes import collection_shape_set

        if Path(train_data_root(None)).is_dir():
            rigged = collection_shape_set("rigged", "val", args.rigged, None, args.cache)
            meshes = zip(rigged.vertices, rigged.faces, strict=True)
            shapes, truths = rotated(meshes, args.seed, 31)
            for mode, (errors, found) in mode_errors(model, shapes, truths).items():
                rows.append(f"| rigged animals (val seeds) | {mode} | {summary(errors)} |")
                rows += check_rows("rigged animals", mode, errors, found)
                switched[f"rigged {mode}"] = switched_count(found)
            if args.oracle:
                found_errors = alternative_errors(model, shapes, truths, np.eye(3), args.sagittal)
                for name, errors in found_errors.items():
                    rows.append(f"| rigged animals (val seeds) | {name} | {summary(errors)} |")
            if args.intrinsic:
                chosen, every, _ = intrinsic_choices(model, shapes, truths)
                found_errors = {
                    name: [angle(f, np.eye(3)) for f in frames] for name, frames in chosen.items()
                }
                found_errors["intrinsic oracle"] = [
                    min(angle(f, np.eye(3)) for f in frames) for frames in every
                ]
                for name, errors in found_errors.items():
                    rows.append(f"| rigged animals (val seeds) | {name} | {summary(errors)} |")

    # ------------------------------------------------------------------ TOSCA
    root = Path(args.eval_data)
    files = sorted((root / "tosca_5k").glob("*.off")) + sorted(
        (root / "tosca_landmarks" / "meshes").glob("*.off")
    )
    if files and model.category == "quadruped":
        real, rotations = rotated_files(files, args.seed, 23)
        labels = [("L" if "landmarks" in str(path) else "") + path.stem for path in files]
        for mode in ("tnet", "judged"):
            found = frames_of(model, real, mode)
            in_file = [f.rotation @ t for f, t in zip(found, rotations, strict=True)]
            errors = [angle(f, TOSCA_TO_CANONICAL) for f in in_file]
            for label, frame, error in zip(labels, found, errors, strict=True):
                per_shape.setdefault(f"TOSCA {label}", {})[mode] = (frame.name, error)
            rows.append(
                f"| TOSCA ({len(real)} shapes) vs file convention | {mode} | {summary(errors)} |"
            )
            rows += check_rows("TOSCA", mode, errors, found)
            pose_index = [i for i, label in enumerate(labels) if not label.startswith("L")]
            pairs = [
                (i, j)
                for i, j in itertools.combinations(pose_index, 2)
                if re.sub(r"\d+$", "", labels[i]) == re.sub(r"\d+$", "", labels[j])
            ]
            agree = [angle(in_file[i], in_file[j]) <= FAILURE for i, j in pairs]
            rows.append(
                f"| TOSCA same-class pose pairs ({len(pairs)}): frames agree ≤ 0.66 rad, % | "
                f"{mode} | {len(pairs)} | — | — | {100 * np.mean(agree):.1f} |"
            )
            switched[f"TOSCA {mode}"] = switched_count(found)
        if args.intrinsic:
            chosen, every, families_kept = intrinsic_choices(model, real, rotations)
            found_errors = {
                name: [angle(f, TOSCA_TO_CANONICAL) for f in frames]
                for name, frames in chosen.items()
            }
            found_errors["intrinsic oracle"] = [
                min(angle(f, TOSCA_TO_CANONICAL) for f in frames) for frames in every
            ]
            for name, errors in found_errors.items():
                rows.append(
                    f"| TOSCA ({len(real)} shapes) vs file convention | {name} | "
                    f"{summary(errors)} |"
                )
                for label, family, error in zip(labels, families_kept, errors, strict=True):
                    per_shape[f"TOSCA {label}"][name] = (family, error)
        if args.oracle:
            found_errors = alternative_errors(
                model, real, rotations, TOSCA_TO_CANONICAL, args.sagittal
            )
            for name, errors in found_errors.items():
                rows.append(
                    f"| TOSCA ({len(real)} shapes) vs file convention | {name} | "
                    f"{summary(errors)} |"
                )
                for label, error in zip(labels, errors, strict=True):
                    per_shape[f"TOSCA {label}"][name] = (name, error)

    # ------------------------------------------------------------------ FAUST
    files = sorted((root / "faust_5k").glob("*.off"))
    if files and model.category == "biped":
        real, rotations = rotated_files(files, args.seed, 29)
        intrinsic: dict[str, list[np.ndarray]] = {}
        if args.intrinsic:
            intrinsic, _, families_kept = intrinsic_choices(model, real, rotations)
        for mode in ("tnet", "judged", *intrinsic):
            if mode in intrinsic:
                in_file = intrinsic[mode]
                found = [
                    Found(r, family, "unchecked")
                    for r, family in zip(in_file, families_kept, strict=True)
                ]
            else:
                found = frames_of(model, real, mode)
                in_file = [f.rotation @ t for f, t in zip(found, rotations, strict=True)]
            reference = consensus(in_file)
            errors = [angle(f, reference) for f in in_file]
            for path, frame, error in zip(files, found, errors, strict=True):
                per_shape.setdefault(f"FAUST {path.stem}", {})[mode] = (frame.name, error)
            rows.append(
                f"| FAUST ({len(real)} shapes) vs their consensus frame | {mode} | "
                f"{summary(errors)} |"
            )
            rows += check_rows("FAUST", mode, errors, found)
            pairs = list(itertools.combinations(range(len(real)), 2))
            agree = [angle(in_file[i], in_file[j]) <= FAILURE for i, j in pairs]
            rows.append(
                f"| FAUST pairs ({len(pairs)}): frames agree ≤ 0.66 rad, % | {mode} | "
                f"{len(pairs)} | — | — | {100 * np.mean(agree):.1f} |"
            )
            if mode not in intrinsic:
                switched[f"FAUST {mode}"] = switched_count(found)

    date = datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d")
    print(f"### Frame failures (> {FAILURE} rad): `{args.model}` matching model\n")
    print(
        f"- date {date}; command `python scripts/frame_report.py {args.model} "
        f"--procedural {args.procedural} --rigged {args.rigged}"
        f"{f' --steep {args.steep}' if args.steep else ''}"
        f"{' --per-shape' if args.per_shape else ''}{' --oracle' if args.oracle else ''}"
        f"{' --sagittal' if args.sagittal else ''}{' --intrinsic' if args.intrinsic else ''}"
        f"{f' --reference-poses {args.reference_poses}' if reference_poses else ''}`; "
        f"frames changed by the judge: {switched}\n"
    )
    print("| shapes | frames | n | median rad | mean rad | failures % |")
    print("|---|---|---:|---:|---:|---:|")
    print("\n".join(rows))
    if args.per_shape and per_shape:
        extra = [
            m
            for m in (
                "oracle",
                "sagittal oracle",
                "judged over sagittal",
                "tnet snapped",
                *INTRINSIC_CHOICES,
                "intrinsic oracle",
            )
            if m in next(iter(per_shape.values()))
        ]
        titles = {
            "oracle": "best candidate",
            "sagittal oracle": "best sagittal candidate",
            "intrinsic": "intrinsic (lowest residual)",
            "intrinsic oracle": "best intrinsic",
            "intrinsic where split": "intrinsic where runs split",
            "judged over intrinsic": "judged over T-Net + intrinsic",
            "judged over intrinsic where split": "the same where runs split",
        }
        print(
            "\n| real shape | T-Net frame, rad | judged: frame kept, rad |"
            + "".join(f" {titles.get(m, m)}, rad |" for m in extra)
            + "\n|---|---:|---|"
            + "---:|" * len(extra)
        )
        for label, modes in per_shape.items():
            cells = {
                m: f"{modes[m][1]:.2f}" + (" **fail**" if modes[m][1] > FAILURE else "")
                for m in ("tnet", "judged", *extra)
            }
            print(
                f"| {label} | {cells['tnet']} | {modes['judged'][0]}: {cells['judged']} |"
                + "".join(f" {cells[m]} |" for m in extra)
            )


if __name__ == "__main__":
    main()
