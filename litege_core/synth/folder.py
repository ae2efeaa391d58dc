"""Training shapes from a folder of arbitrary meshes (each with its own triangulation).

Every mesh file under a directory (any mesh format :func:`litege_core.io.load_shape` reads) is
a *family*, named by its path relative to the directory. Files are split train/val/test by
file (seeded), so no mesh of the evaluation splits is seen in training.

A shape is a pure function of ``(file, seed)``, so a small collection yields many shapes:

1. the file is loaded once per process, welded, reduced to its largest connected component,
   repaired where it is not edge-manifold (a shell that met the body at a single vertex, an
   antler on its pedicle, comes off), centred and scaled to unit area. A rigged, animated
   glTF (GLB or ``.gltf``: a skinned mesh and at least one animation; with
   ``FolderSettings.poses``, opt-in) is loaded as a rig instead
   (:func:`~litege_core.synth.rigged.load_rigged`: its skinned body, one closed manifold), and
   each shape takes a pose of its own: a clip drawn among the file's animations and a time in
   it, posed by linear blend skinning (the clip's pose as it is: no joint noise, no bend, which
   a user's rig need not tolerate). A glTF whose skin cannot be read so is used in its stored
   pose;
2. with probability ``stretch_probability`` a smooth non-rigid stretch is applied
   (:func:`~litege_core.synth.meshops.smooth_stretch`: an anisotropic scale along random axes
   plus low-frequency sine displacements, a diffeomorphism);
3. the surface is remeshed isotropically to a vertex count drawn log-uniformly in
   ``vertex_range`` (different densities and triangulations of the same surface), slivers are
   collapsed, and the result is checked to be an oriented edge-manifold single component (and
   closed when the input was). Random rotations are left to training views.

A draw whose remesh is not clean is redrawn (``attempts`` in all); when every draw fails, the
shape is the file's *reference shape* (:func:`reference_shape`: as stored, a rig in its rest
pose, unstretched, remeshed to the middle of ``vertex_range``). :func:`check_files` builds each
file's reference shape before a build starts, so a build never stops on a file that passed it.
"""

from __future__ import annotations

import functools
import hashlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from litege_core.arrays import frozen
from litege_core.errors import ComputationError, EmptyShapeError, InputError, LiteGEError
from litege_core.io import MESH_FORMATS, load_shape, self_contained_gltf
from litege_core.synth.meshops import (
    collapse_slivers,
    largest_body,
    manifold_report,
    remesh,
    smooth_stretch,
    unit_area_scale,
    weld,
)
from litege_core.synth.rigged import PoseSettings, RiggedModel, load_rigged, pose_model
from litege_core.validate import ShapeLimits

FOLDER_VERSION = "folder-2"
FOLDER_LIMITS = ShapeLimits(max_vertices=2_000_000, max_faces=4_000_000, max_file_bytes=1 << 30)
"""Size bounds of a collection's mesh files (the user's own files: wider than an upload's)."""
MESH_SUFFIXES = tuple(sorted(MESH_FORMATS))
"""Mesh formats of :data:`litege_core.io.MESH_FORMATS` (files of point-cloud-only formats,
XYZ and NPY, are skipped; a PLY without faces is listed and refused by name when loaded)."""


@dataclass(frozen=True)
class FolderSettings:
    """Augmentation ranges of folder shapes (see the module docstring)."""

    vertex_range: tuple[int, int] = (3000, 6000)
    stretch_probability: float = 0.75
    axis_range: tuple[float, float] = (0.85, 1.15)
    amplitude: float = 0.04
    attempts: int = 4
    poses: bool = False
    """Pose each rigged, animated glTF file by its own clips (step 1); ``False`` (the
    default): every file in its stored pose. Opt-in: trained from scratch on the 12 rigged
    train-data animals for 20 minutes, posed and stored-pose runs erred the same on average
    over two seeds, on held-out poses and on TOSCA (BENCHMARKS.md ``rig-poses``)."""

    def __post_init__(self) -> None:
        if not 100 <= self.vertex_range[0] <= self.vertex_range[1]:
            raise InputError("need 100 ≤ vertex_range[0] ≤ vertex_range[1]")
        if not 0.0 <= self.stretch_probability <= 1.0:
            raise InputError("stretch_probability must lie in [0, 1]")

    def describe(self) -> str:
        """A stable text of the settings (part of the factory version)."""
        return (
            f"v{self.vertex_range[0]}-{self.vertex_range[1]}"
            f",p{self.stretch_probability:g},a{self.axis_range[0]:g}-{self.axis_range[1]:g}"
            f",w{self.amplitude:g},k{self.attempts},r{int(self.poses)}"
        )


def list_meshes(directory: str | Path) -> tuple[str, ...]:
    """Sorted relative POSIX paths of the mesh files under ``directory`` (recursive).

    Raises:
        InputError: the directory does not exist or holds no mesh file.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"{directory} is not a directory")
    files = sorted(
        path.relative_to(directory).as_posix()
        for path in directory.rglob("*")
        if path.is_file() and path.suffix.lower().lstrip(".") in MESH_SUFFIXES
    )
    if not files:
        raise InputError(f"no mesh files ({', '.join(MESH_SUFFIXES)}) under {directory}")
    return tuple(files)


def check_files(
    directory: str | Path, files: tuple[str, ...], settings: FolderSettings = FolderSettings()
) -> None:
    """Build the reference shape (:func:`reference_shape`) of every file of ``files`` once,
    before any shape is built, so that a folder's unusable files are named together and at
    once, and a build that starts never stops on one of them.

    Raises:
        InputError: the files that cannot serve (unreadable, no faces, no manifold body, no
            clean remesh), each with its reason (the first ten), to remove from the folder.
    """
    failed = []
    for name in files:
        try:
            reference_shape(directory, name, settings)
        except LiteGEError as exc:
            failed.append(exc.message)
    if failed:
        more = f"; and {len(failed) - 10} more" if len(failed) > 10 else ""
        raise InputError(
            f"{len(failed)} of {len(files)} mesh files cannot be used (remove them from the "
            f"folder): {'; '.join(failed[:10])}{more}"
        )


def split_files(
    files: tuple[str, ...], seed: int, eval_fraction: float = 0.1
) -> dict[str, tuple[str, ...]]:
    """Split ``files`` into train/val/test by a seeded permutation: ``round(eval_fraction·n)``
    files each for val and test (at least one each when ``n ≥ 3``), the rest train."""
    n = len(files)
    n_eval = max(1, round(eval_fraction * n)) if n >= 3 else 0
    order = np.random.default_rng([seed, 0xF17E]).permutation(n)
    chosen = [files[i] for i in order]
    return {
        "val": tuple(sorted(chosen[:n_eval])),
        "test": tuple(sorted(chosen[n_eval : 2 * n_eval])),
        "train": tuple(sorted(chosen[2 * n_eval :])),
    }


def not_rigs(directory: str | Path, files: tuple[str, ...]) -> list[str]:
    """The files of ``files`` that are not rigged, animated glTF files (:func:`rigged_model`)."""
    return [name for name in files if rigged_model(str(Path(directory) / name)) is None]


def pose_splits(files: tuple[str, ...], seed: int) -> dict[str, tuple[str, ...]]:
    """Splits of a collection whose shapes are poses of its files: by file
    (:func:`split_files`) with three files or more, else every split holds every file and the
    splits differ by their seeds (held-out poses of the same characters)."""
    if len(files) >= 3:
        return split_files(files, seed)
    return {"train": files, "val": files, "test": files}


POSE_SPLIT_SHAPES = (120, 8)
"""Training and evaluation (val, test) shapes a collection of poses of fewer than three files
holds by default (:func:`shapes_per_file`): its files are shared by every split
(:func:`pose_splits`), so per-file defaults made for dozens of files would leave it a handful."""


def shapes_per_file(
    n_files: int,
    poses: bool,
    defaults: tuple[int, int],
    given: tuple[int | None, int | None] = (None, None),
) -> tuple[int, int]:
    """``(training, evaluation)`` shapes per file: each ``given`` count, or where it is
    ``None`` its default: ``defaults``, or for ``poses`` of fewer than three files enough to
    make :data:`POSE_SPLIT_SHAPES` in all (at least ``defaults``)."""
    if poses and n_files < 3:
        defaults = (
            max(defaults[0], math.ceil(POSE_SPLIT_SHAPES[0] / n_files)),
            max(defaults[1], math.ceil(POSE_SPLIT_SHAPES[1] / n_files)),
        )
    return (
        defaults[0] if given[0] is None else given[0],
        defaults[1] if given[1] is None else given[1],
    )


def splits_share_files(splits: Mapping[str, Sequence[str]]) -> bool:
    """Whether a file lies in more than one split (:func:`pose_splits` of fewer than three
    files: the held-out shapes are other poses of the training files)."""
    names = [name for split in splits.values() for name in split]
    return len(set(names)) < len(names)


def folder_digest(directory: str | Path, files: tuple[str, ...]) -> str:
    """SHA-256 (hex, 16 characters) over the names and bytes of ``files`` (a ``.gltf``'s with
    the buffer files it names embedded, :func:`~litege_core.io.self_contained_gltf`)."""
    digest = hashlib.sha256()
    for name in files:
        digest.update(name.encode())
        digest.update(hashlib.sha256(_content(Path(directory) / name)).digest())
    return digest.hexdigest()[:16]


def _content(path: Path) -> bytes:
    """The bytes that make the mesh file at ``path``: its own, and a ``.gltf``'s buffer files
    (its own alone where they cannot be read: loading it will say why)."""
    if path.suffix.lower() == ".gltf":
        try:
            return self_contained_gltf(path, FOLDER_LIMITS)
        except LiteGEError:
            pass
    return path.read_bytes()


@dataclass(frozen=True)
class PreparedMesh:
    """A cleaned input mesh: centred, unit area; ``closed`` when it has no boundary."""

    vertices: NDArray
    faces: NDArray
    closed: bool


@functools.lru_cache(maxsize=64)
def prepare_mesh(path: str) -> PreparedMesh:
    """Load, weld, keep the largest component, repair and normalize one file (step 1).

    Raises:
        InputError subclasses for unreadable files and for files without faces (point clouds
        saved as PLY, ...); ComputationError when no usable manifold can be made of it. Each
        message starts with ``path``.
    """
    try:
        return _prepare_mesh(path)
    except LiteGEError as exc:  # the same class (problem type), naming the file
        raise type(exc)(f"{path}: {exc.message}", **exc.details) from exc


def _prepare_mesh(path: str) -> PreparedMesh:
    shape = load_shape(path, limits=FOLDER_LIMITS)
    if shape.faces is None:
        raise EmptyShapeError(
            "the file has no faces (a point cloud): training on a folder needs triangle "
            "meshes; remove it from the folder"
        )
    welded = weld(np.asarray(shape.vertices), np.asarray(shape.faces), tolerance=1e-7)
    kept, faces = largest_body(welded.vertices, welded.faces, require_closed=False)
    vertices = welded.vertices[kept]
    report = manifold_report(vertices, faces)
    vertices = (vertices - vertices.mean(axis=0)) * unit_area_scale(vertices, faces)
    return PreparedMesh(vertices, faces, report.closed)


def folder_shape(
    directory: str | Path, name: str, seed: int, settings: FolderSettings = FolderSettings()
) -> tuple[NDArray, NDArray]:
    """The shape ``(vertices (V, 3), faces (F, 3))`` of file ``name`` and ``seed`` (a rig's
    pose, then steps 2–3); attempt ``k`` draws from ``default_rng([seed, k])``, and when no
    attempt gives a clean manifold the shape is the file's :func:`reference_shape`.

    Raises:
        LiteGEError subclasses: the file cannot be loaded, or not even its reference shape is
            a clean manifold (:func:`check_files` names such files up front).
    """
    path = str(Path(directory) / name)
    rig = rigged_model(path) if settings.poses else None
    for attempt in range(settings.attempts):
        rng = np.random.default_rng([seed, attempt])
        if rig is None:
            source = prepare_mesh(path)  # memoized: loaded once per process
        else:
            posed, _ = pose_model(rig, rng, RIG_POSES)
            source = PreparedMesh(posed, rig.mesh.faces, closed=True)
        low, high = settings.vertex_range
        n_target = round(float(np.exp(rng.uniform(np.log(low), np.log(high)))))
        vertices = source.vertices
        if rng.random() < settings.stretch_probability:
            vertices = smooth_stretch(
                vertices, rng, axis_range=settings.axis_range, amplitude=settings.amplitude
            )
        try:
            return clean_remesh(PreparedMesh(vertices, source.faces, source.closed), n_target)
        except ComputationError:
            continue
    vertices, faces = reference_shape(directory, name, settings)
    return vertices.copy(), faces.copy()


def reference_shape(
    directory: str | Path, name: str, settings: FolderSettings = FolderSettings()
) -> tuple[NDArray, NDArray]:
    """The reference shape ``(vertices (V, 3), faces (F, 3))``, read-only, of file ``name``:
    its surface as stored (with ``settings.poses``, a rig in its rest pose), unstretched,
    remeshed to the geometric middle of ``settings.vertex_range`` (memoized per process).

    Raises:
        LiteGEError subclasses naming the file: it cannot be loaded, or its remesh is not a
            clean manifold (ComputationError).
    """
    return _reference_shape(str(Path(directory) / name), settings)


@functools.lru_cache(maxsize=64)
def _reference_shape(path: str, settings: FolderSettings) -> tuple[NDArray, NDArray]:
    rig = rigged_model(path) if settings.poses else None
    if rig is None:
        source = prepare_mesh(path)
    else:
        rest = rig.rest_vertices()  # scaled to unit area
        source = PreparedMesh(rest - rest.mean(axis=0), rig.mesh.faces, closed=True)
    n_target = round(math.sqrt(settings.vertex_range[0] * settings.vertex_range[1]))
    try:
        vertices, faces = clean_remesh(source, n_target)
    except ComputationError as exc:
        raise ComputationError(f"{path}: {exc.message}") from exc
    return frozen(vertices), frozen(faces)


def clean_remesh(source: PreparedMesh, n_target: int) -> tuple[NDArray, NDArray]:
    """Step 3: ``source`` remeshed isotropically to about ``n_target`` vertices, slivers
    collapsed, checked.

    Raises:
        ComputationError: the result is not an oriented edge-manifold single component with
            no angle at or below 1°, closed when ``source`` is.
    """
    vertices, faces = remesh(source.vertices, source.faces, n_target, tolerance=0.08)
    vertices, faces = collapse_slivers(vertices, faces, min_angle=2.0)
    report = manifold_report(vertices, faces)
    clean = report.manifold and report.oriented and report.components == 1
    if not clean or report.min_angle <= 1.0 or (source.closed and not report.closed):
        raise ComputationError(f"the remeshed surface is not a clean manifold: {report}")
    return vertices, faces


RIG_POSES = PoseSettings(perturb_degrees=0.0, body_range=(1.0, 1.0))
"""How :func:`folder_shape` poses a rig: a clip and a time, nothing more (its vertex range and
subdivision are unused: the folder's own remeshing follows)."""


@functools.lru_cache(maxsize=64)
def rigged_model(path: str) -> RiggedModel | None:
    """The rig of a glTF file with a skinned mesh and an animation
    (:func:`~litege_core.synth.rigged.load_rigged`); ``None`` for other files, and for a glTF
    whose skinned body cannot be made one closed manifold (it is then used as it is stored)."""
    if Path(path).suffix.lower() not in {".glb", ".gltf"}:
        return None
    try:
        return load_rigged(path)
    except LiteGEError:
        return None


__all__ = [
    "FOLDER_LIMITS",
    "FOLDER_VERSION",
    "MESH_SUFFIXES",
    "POSE_SPLIT_SHAPES",
    "RIG_POSES",
    "FolderSettings",
    "PreparedMesh",
    "check_files",
    "clean_remesh",
    "folder_digest",
    "folder_shape",
    "list_meshes",
    "not_rigs",
    "pose_splits",
    "prepare_mesh",
    "reference_shape",
    "rigged_model",
    "shapes_per_file",
    "split_files",
    "splits_share_files",
]
