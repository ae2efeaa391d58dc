"""Non-isometric shape matching: prepare each shape once, then match many queries.

:class:`MatchingModel` wraps a matching bundle (T-Net, basis, matching network(s)):

* :meth:`MatchingModel.prepare` puts a shape into the aligned unit-area frame (spec §1.3–1.6),
  computes its UDF-PCA descriptor and the multi-tier NN cache of its points (spec §5.2) →
  :class:`MatchingShape` (small, pickle-free ``to_arrays`` for a cache). With
  ``frames="judged"`` (the default for quadrupeds, opt-in for bipeds) a shape whose T-Net runs
  on turned principal-axis frames disagree gets the frame, of the T-Net's and the 24
  principal-axis ones, that the matching network finds most like canonical reference animals
  (:mod:`litege_core.matching.frame`, :mod:`litege_core.matching.judge`, issue 15 step 1), or,
  in a bundle that carries one, that its :class:`~litege_core.nets.orientation.OrientationNet`
  finds most likely canonical (an ablation: BENCHMARKS.md ``orientation-net``);
* :meth:`MatchingModel.match` finds, for query points of X, the point of Y minimizing the
  predicted cross-shape geodesic, coarse to fine over Y's cache, all queries at once
  (spec §5.3, :func:`~litege_core.matching.search.coarse_to_fine_search`). Options:
  ``side="network"`` also matches on Y's mirror image and keeps the side with the lower mean
  predicted distance (issue 15 step 2; an ablation: the score cannot see a reflection, see
  :meth:`MatchingModel.match`); ``refine="zoomout"`` refines the matches of two meshes with
  ZoomOut started from LiteGE's map (:mod:`litege_core.matching.refine`, step 5).

The network is ``head(f(x | z_X) − f(y | z_Y))`` with per-point features ``f`` (see
:class:`~litege_core.nets.FoldedGeodesicNet`), so features of every point of a shape are
computed once per shape and a search step is the head alone on feature differences.
"""

from __future__ import annotations

import os
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from litege_core.arrays import frozen
from litege_core.canonical import Transform
from litege_core.device import resolve_device
from litege_core.errors import (
    ArtifactError,
    InputError,
)
from litege_core.matching.bundle import (
    MatchingBundle,
    SearchSettings,
    load_matching_bundle,
    resolve_matching_bundle,
)
from litege_core.matching.cache import NNCache
from litege_core.matching.frame import (
    FRAME_MODES,
    MIRROR,
    MatchingPipeline,
    align_shapes,
    candidate_turns,
    subsample,
    turned,
)
from litege_core.matching.intrinsic import intrinsic_frame
from litege_core.matching.judge import DEFAULT_MARGIN, JUDGED_BY_DEFAULT, FrameJudge, choose
from litege_core.matching.refine import (
    REFINE_METHODS,
    RefinedMap,
    Spectrum,
    ZoomOutSettings,
    heat_engine,
    refined_map,
    spectrum,
)
from litege_core.matching.search import (
    ScoreFn,
    coarse_to_fine_search,
    exhaustive_search,
    max_evaluations,
)
from litege_core.nets import FoldedGeodesicNet
from litege_core.nets.folded import resolve_precision
from litege_core.nets.orientation import OrientationNet
from litege_core.projection import CloudProjector, MeshProjector, Projector, snap
from litege_core.query import QueryLike, check_points, parse_indices, parse_query
from litege_core.sampling import isolated_points
from litege_core.shape import Shape

SIDES: tuple[str, ...] = ("frame", "network")
"""``side`` values of :meth:`MatchingModel.match`: ``frame`` — the frames decide left and right
(proper rotations keep each shape's handedness); ``network`` — match on Y and on its mirror image
and keep the lower mean predicted distance."""

PREPARATION_VERSION = 3
"""Version of what :meth:`MatchingModel.prepare` computes from a shape and a bundle (frame,
descriptor, cache): a stored prepared shape of another version is stale, so caches key on it
besides the bundle's hash. 2 (2026-11-28): ``judged`` frames consult the judge only where the
T-Net's turned runs disagree, over the principal-axis frames (1: the T-Net frame's half turns).
3 (2026-12-02): the prepared shape records :attr:`MatchingShape.frame_check`."""
FRAME_CHECKS: tuple[str, ...] = ("agreed", "split", "unchecked")
"""Values of :attr:`MatchingShape.frame_check`: the T-Net's turned runs (:func:`~litege_core.
matching.frame.runs_agree`) agreed on its frame, or split (the frame was then chosen among
candidates: about half such frames of real animals are wrong, BENCHMARKS.md
``frame-check``), or were not run (``frames="tnet"``, and point clouds under
``frames="intrinsic"``)."""
MAX_PAIRS_PER_CALL = 16_384
"""(query, candidate) pairs per head call: bounds the ``pairs × 2n`` scratch memory."""
REFINED_MAPS_PER_SHAPE = 8
"""Refined functional maps (``refine`` other than ``"none"``) kept per source shape, one per
target (and side, refinement and settings), newest last."""
_EMBED_ROWS = 8192


def _text(value: str) -> NDArray:
    return np.frombuffer(value.encode("utf-8"), dtype=np.uint8).copy()


def _untext(array: ArrayLike) -> str:
    return bytes(np.asarray(array, dtype=np.uint8)).decode("utf-8")


def _lazy_nbytes(value: Any) -> int:
    """Bytes of one computed attachment of a prepared shape: a feature table, a spectrum, the
    kept refined maps (other attachments, e.g. a projector, count 0)."""
    if isinstance(value, torch.Tensor):
        return value.element_size() * value.nelement()
    if isinstance(value, OrderedDict):
        return sum(_lazy_nbytes(item) for item in value.values())
    if isinstance(value, (np.ndarray, Spectrum, RefinedMap)):
        return int(value.nbytes)
    return 0


@dataclass(frozen=True, eq=False)
class MatchingShape:
    """A shape prepared for matching by one bundle.

    Attributes:
        shape_id: content hash of the shape.
        bundle_hash: content hash of the matching bundle.
        kind: ``"mesh"`` or ``"point_cloud"``.
        scaling: how it was scaled (``unit_area``, ``broken_mesh``, ``cloud_8k``, ``cloud_500``).
        transform: input units → aligned unit-area frame.
        aligned: ``(P, 3)`` float32 candidate points (mesh vertices or cloud points, input
            indexing) in the aligned frame (read-only).
        descriptor: ``(E,)`` float32 UDF-PCA descriptor (read-only).
        residual: PCA reconstruction residual of the descriptor (out-of-distribution signal).
        cache: the multi-tier NN cache of ``aligned``.
        seed: seed of every random draw of the preparation.
        faces: ``(F, 3)`` int64 triangles of a mesh (read-only; xyz queries are snapped onto
            them), ``None`` for point clouds.
        frame: how the frame was chosen: ``"tnet"`` (the T-Net's frame), ``"pcaK"`` (the
            judge's choice, principal-axis frame ``K`` of
            :func:`~litege_core.matching.frame.pca_candidates`), ``"mirror"`` (an internal
            mirror-image twin).
        frame_check: whether the frame was checked and held (:data:`FRAME_CHECKS`):
            ``"agreed"``, ``"split"`` (an uncertain frame) or ``"unchecked"``.
    """

    shape_id: str
    bundle_hash: str
    kind: str
    scaling: str
    transform: Transform
    aligned: NDArray
    descriptor: NDArray
    residual: float
    cache: NNCache
    seed: int
    faces: NDArray | None = field(default=None, repr=False)
    frame: str = "tnet"
    frame_check: str = "unchecked"
    _lazy: dict[str, Any] = field(default_factory=dict, repr=False)

    @property
    def n_points(self) -> int:
        return int(self.aligned.shape[0])

    @property
    def is_mesh(self) -> bool:
        return self.kind == "mesh"

    @property
    def nbytes(self) -> int:
        """Bytes of the arrays and of what was computed later: feature tables, spectra and
        kept refined maps."""
        own = sum(a.nbytes for a in self.to_arrays().values())
        return int(own + sum(_lazy_nbytes(value) for value in self._lazy.values()))

    @property
    def projector(self) -> Projector:
        """Surface projector in the aligned frame (built on first use): where xyz queries are
        snapped, by the rule of :func:`litege_core.projection.snap`."""
        projector = self._lazy.get("projector")
        if projector is None:
            points = np.asarray(self.aligned, dtype=np.float64)
            if self.faces is not None:
                projector = MeshProjector(points, self.faces)
            else:
                projector = CloudProjector(points)
            self._lazy["projector"] = projector
        return projector

    def to_arrays(self) -> dict[str, NDArray]:
        """Plain numpy arrays, no pickle (the NN cache's arrays are prefixed ``cache.``)."""
        arrays = {
            "shape_id": _text(self.shape_id),
            "bundle_hash": _text(self.bundle_hash),
            "kind": _text(self.kind),
            "scaling": _text(self.scaling),
            "rotation": np.asarray(self.transform.rotation, dtype=np.float64),
            "center": np.asarray(self.transform.center, dtype=np.float64),
            "scale": np.array([self.transform.scale], dtype=np.float64),
            "aligned": np.asarray(self.aligned, dtype=np.float32),
            "descriptor": np.asarray(self.descriptor, dtype=np.float32),
            "residual": np.array([self.residual], dtype=np.float64),
            "seed": np.array([self.seed], dtype=np.int64),
            "frame": _text(self.frame),
            "frame_check": _text(self.frame_check),
        }
        if self.faces is not None:
            arrays["faces"] = np.asarray(self.faces, dtype=np.int64)
        arrays.update({f"cache.{k}": v for k, v in self.cache.to_arrays().items()})
        return arrays

    @classmethod
    def from_arrays(cls, arrays: dict[str, NDArray]) -> MatchingShape:
        """Inverse of :meth:`to_arrays`.

        Raises:
            ArtifactError: missing keys, wrong shapes or non-finite values.
        """
        try:
            aligned = np.asarray(arrays["aligned"], dtype=np.float32)
            descriptor = np.asarray(arrays["descriptor"], dtype=np.float32)
            cache = NNCache.from_arrays(
                {k[len("cache.") :]: v for k, v in arrays.items() if k.startswith("cache.")}
            )
            prepared = cls(
                shape_id=_untext(arrays["shape_id"]),
                bundle_hash=_untext(arrays["bundle_hash"]),
                kind=_untext(arrays["kind"]),
                scaling=_untext(arrays["scaling"]),
                transform=Transform(
                    arrays["rotation"], arrays["center"], float(arrays["scale"].reshape(-1)[0])
                ),
                aligned=frozen(aligned),
                descriptor=frozen(descriptor),
                residual=float(arrays["residual"].reshape(-1)[0]),
                cache=cache,
                seed=int(arrays["seed"].reshape(-1)[0]),
                faces=_optional_faces(arrays.get("faces"), aligned.shape[0]),
                frame=_untext(arrays["frame"]) if "frame" in arrays else "tnet",
                frame_check=(
                    _untext(arrays["frame_check"]) if "frame_check" in arrays else "unchecked"
                ),
            )
        except (KeyError, IndexError, ValueError, TypeError, UnicodeDecodeError) as exc:
            raise ArtifactError(f"malformed matching shape: {exc}") from exc
        except InputError as exc:
            raise ArtifactError(f"malformed matching shape: {exc}") from exc
        if aligned.ndim != 2 or aligned.shape[1] != 3 or not np.isfinite(aligned).all():
            raise ArtifactError("malformed matching shape: aligned must be finite (P, 3)")
        if descriptor.ndim != 1 or not np.isfinite(descriptor).all():
            raise ArtifactError("malformed matching shape: descriptor must be a finite vector")
        if cache.n_points != aligned.shape[0]:
            raise ArtifactError("malformed matching shape: cache and points disagree")
        return prepared


def _optional_faces(faces: ArrayLike | None, n_points: int) -> NDArray | None:
    """Stored faces of a prepared mesh (absent for clouds and for older entries)."""
    if faces is None:
        return None
    array = np.asarray(faces, dtype=np.int64)
    if array.ndim != 2 or array.shape[1] != 3 or array.min() < 0 or array.max() >= n_points:
        raise ArtifactError("malformed matching shape: faces must index the points")
    return frozen(array)


@dataclass(frozen=True)
class MatchResult:
    """Matches of ``N`` queries of X on Y.

    Attributes:
        indices: ``(N,)`` int64 matched points of Y (Y's input indexing).
        distance: ``(N,)`` float32 predicted cross-shape geodesic at the match (unit-area units).
        evaluations: network pair evaluations used.
        refinement: how the matches were refined: ``"none"``, ``"zoomout"``, or for
            ``zoomout-hybrid`` the start of the kept map, ``"zoomout:litege"`` or
            ``"zoomout:descriptors"``.
    """

    indices: NDArray
    distance: NDArray
    evaluations: int
    refinement: str = "none"


class MatchingModel:
    """A loaded matching bundle, ready to prepare shapes and match them.

    Args:
        bundle: a :class:`MatchingBundle` (see :meth:`load`).
        device: where the networks run (default: the bundle's device).
        precision: arithmetic of the search's per-pair head product
            (:func:`~litege_core.nets.folded.resolve_precision`): ``"float32"`` (default),
            ``"bfloat16"``, ``"int8"`` or ``"auto"`` (bfloat16 where it is fast). The frame
            judge always scores in float32, so frames do not depend on it.
    """

    def __init__(
        self,
        bundle: MatchingBundle,
        device: str | torch.device | None = None,
        precision: str = "float32",
    ) -> None:
        self.bundle = bundle
        self.device = torch.device(device) if device is not None else bundle.device
        self.precision = resolve_precision(precision, self.device)
        for net in bundle.networks:
            net.to(self.device).eval()
        bundle.tnet.to(self.device).eval()
        if bundle.orientation is not None:
            bundle.orientation.to(self.device).eval()
        self._folded = [
            FoldedGeodesicNet(net, self.device, precision=self.precision) for net in bundle.networks
        ]
        self._engine = bundle.basis.engine(self.device)
        self._judge: FrameJudge | None = None

    @classmethod
    def load(
        cls,
        name_or_path: str | os.PathLike = "quadrupeds",
        device: str | torch.device = "cpu",
        precision: str = "float32",
    ) -> MatchingModel:
        """Load a shipped matching model by name, or a bundle directory (``precision``: as
        the class's argument)."""
        resolved = resolve_device(device)
        bundle = load_matching_bundle(resolve_matching_bundle(name_or_path), resolved)
        return cls(bundle, precision=precision)

    @classmethod
    def tiny_random(cls, seed: int = 0) -> MatchingModel:
        """An untrained miniature model (random weights, small basis) for fast plumbing
        tests: deterministic for ``seed``, meaningless matches."""
        from litege_core.matching.testing import tiny_matching_bundle

        return cls(tiny_matching_bundle(seed))

    # ------------------------------------------------------------------ properties

    @property
    def name(self) -> str:
        return self.bundle.name

    @property
    def category(self) -> str:
        return self.bundle.category

    @property
    def content_hash(self) -> str:
        return self.bundle.content_hash

    @property
    def pipeline(self) -> MatchingPipeline:
        return self.bundle.pipeline

    @property
    def search(self) -> SearchSettings:
        return self.bundle.search

    def __repr__(self) -> str:
        nets = len(self.bundle.networks)
        return f"MatchingModel({self.name!r}, networks={nets}, device={self.device})"

    @property
    def frame_judge(self) -> FrameJudge | None:
        """The judge of candidate frames (reference animals of the model's category), or
        ``None`` for a category without procedural reference animals."""
        if self._judge is None:
            from litege_core.synth import CATEGORIES

            if self.category not in CATEGORIES:
                return None
            networks = self.bundle.frame_judge_networks
            folded = (  # the matching networks' folded forms unless the judge has its own
                [FoldedGeodesicNet(net, self.device) for net in networks]
                if self.bundle.judge_networks or self.precision != "float32"
                else self._folded
            )
            self._judge = FrameJudge(
                folded,
                list(networks),
                self.bundle.basis,
                self.category,
                self.device,
            )
        return self._judge

    @frame_judge.setter
    def frame_judge(self, judge: FrameJudge | None) -> None:
        self._judge = judge

    def resolve_frames(self, frames: str) -> str:
        """``auto`` → ``judged`` when the model has a frame judge and its category is one the
        judge is validated on (:data:`~litege_core.matching.judge.JUDGED_BY_DEFAULT`), else
        ``tnet``.

        Raises:
            InputError: an unknown mode, ``judged`` without a judge, or ``intrinsic`` for a
                category without reference animals.
        """
        if frames not in FRAME_MODES:
            raise InputError(f"frames must be one of {list(FRAME_MODES)}, got {frames!r}")
        has_judge = self.bundle.orientation is not None or self.frame_judge is not None
        if frames == "auto":
            return "judged" if has_judge and self.category in JUDGED_BY_DEFAULT else "tnet"
        if frames == "judged" and not has_judge:
            raise InputError(
                f"frames='judged' needs reference animals; none for category {self.category!r}"
            )
        from litege_core.synth import CATEGORIES

        if frames == "intrinsic" and self.category not in CATEGORIES:
            raise InputError(
                f"frames='intrinsic' needs reference animals; none for category {self.category!r}"
            )
        return frames

    # ------------------------------------------------------------------ preparation

    def prepare(
        self,
        shape: Shape,
        *,
        seed: int = 0,
        scaling: str = "auto",
        frames: str = "auto",
        frame_margin: float = DEFAULT_MARGIN,
    ) -> MatchingShape:
        """Prepare one shape (see :meth:`prepare_many`)."""
        return self.prepare_many(
            [shape], seed=seed, scaling=scaling, frames=frames, frame_margin=frame_margin
        )[0]

    def prepare_many(
        self,
        shapes: list[Shape],
        *,
        seed: int = 0,
        scaling: str = "auto",
        frames: str = "auto",
        frame_margin: float = DEFAULT_MARGIN,
    ) -> list[MatchingShape]:
        """Align, describe and cache several shapes (one T-Net call per point count, one
        judge call, one descriptor call).

        Args:
            shapes: meshes or point clouds (validated :class:`Shape` objects).
            seed: seed of the surface samples and Poisson subsets.
            scaling: ``"auto"`` or a fixed scaling (see :mod:`litege_core.matching.frame`).
            frames: ``"tnet"`` (the T-Net's frame), ``"judged"`` (the T-Net's frame where its
                turned runs agree, else the T-Net's or a principal-axis frame, chosen by
                :attr:`frame_judge`), ``"intrinsic"`` (the T-Net's frame where its turned
                runs agree, else for a mesh its frame from functional maps of reference
                animals, :mod:`~litege_core.matching.intrinsic`) or ``"auto"`` (``judged``
                for the categories of
                :data:`~litege_core.matching.judge.JUDGED_BY_DEFAULT`).
            frame_margin: another frame replaces the T-Net's only when its judge score is
                lower by more than this fraction.
        """
        shapes = list(shapes)
        for i, shape in enumerate(shapes):
            if not isinstance(shape, Shape):
                raise InputError(f"shapes[{i}] is a {type(shape).__name__}, not a Shape")
        if not shapes:
            return []
        mode = self.resolve_frames(frames)
        # a scan's stray points are never matched (the network scores off-surface points as
        # near anything: 5 % strays drew 71 % of FAUST matches, BENCHMARKS "outliers") and
        # they pull no frame: one check serves both
        isolated = [isolated_points(s.vertices) if s.faces is None else None for s in shapes]
        on_surface = [
            shape
            if strays is None or not strays.any()
            else Shape.from_arrays(shape.vertices[~strays])
            for shape, strays in zip(shapes, isolated, strict=True)
        ]
        aligned_frames = align_shapes(
            on_surface, self.bundle.tnet, self.pipeline, scaling=scaling, seed=int(seed)
        )
        names, checks = ["tnet"] * len(shapes), ["unchecked"] * len(shapes)
        if mode == "judged":
            aligned_frames, names, checks = self._judged_frames(
                on_surface, aligned_frames, frame_margin, int(seed)
            )
        elif mode == "intrinsic":
            aligned_frames, names, checks = self._intrinsic_frames(
                on_surface, aligned_frames, int(seed)
            )
        described = self._engine.describe_with_residual(
            [cloud.astype(np.float32) for _, cloud, _ in aligned_frames]
        )
        descriptors = described.descriptors.detach().cpu().numpy().astype(np.float32)
        residuals = described.residual.detach().cpu().numpy().astype(np.float64)
        search = self.search
        prepared = []
        for b, (shape, strays, (transform, cloud, chosen)) in enumerate(
            zip(shapes, isolated, aligned_frames, strict=True)
        ):
            aligned = transform.apply(shape.vertices)
            cache = NNCache.build(
                aligned,
                tier_sizes=search.tier_sizes,
                neighbours=search.neighbours,
                strategy=search.strategy,  # type: ignore[arg-type]
                seed=int(seed),
                candidates=np.flatnonzero(~strays) if strays is not None else None,
            )
            prepared.append(
                MatchingShape(
                    shape_id=shape.content_hash,
                    bundle_hash=self.content_hash,
                    kind=shape.kind,
                    scaling=chosen,
                    transform=transform,
                    aligned=frozen(aligned, np.float32),
                    descriptor=frozen(descriptors[b]),
                    residual=float(residuals[b]),
                    cache=cache,
                    seed=int(seed),
                    faces=shape.faces,
                    frame=names[b],
                    frame_check=checks[b],
                    _lazy={"cloud": frozen(cloud, np.float32)},
                )
            )
        return prepared

    def _judged_frames(
        self,
        shapes: list[Shape],
        frames: list[tuple[Transform, NDArray, str]],
        margin: float,
        seed: int,
    ) -> tuple[list[tuple[Transform, NDArray, str]], list[str], list[str]]:
        """The T-Net frame of each shape whose turned T-Net runs agree; for the others, the
        T-Net frame or one of the 24 principal-axis frames, whichever scores best: by the
        bundle's :class:`~litege_core.nets.orientation.OrientationNet` where it has one (the
        lowest ``−log p(canonical)``), else by the frame judge (one call for all shapes).
        Returns the frames, their names and their :data:`FRAME_CHECKS`."""
        candidates = candidate_turns(self.bundle.tnet, frames, self.pipeline.n_tnet_points, seed)
        split = [i for i, turns in enumerate(candidates) if turns is not None]
        out, names = list(frames), ["tnet"] * len(frames)
        checks = ["split" if turns is not None else "agreed" for turns in candidates]
        if not split:
            return out, names, checks
        turns = [t for t in candidates if t is not None]
        orientation = self.bundle.orientation
        if orientation is not None:
            scores = np.stack(
                [
                    self._orientation_scores(orientation, frames[i][1], shape_turns, seed)
                    for i, shape_turns in zip(split, turns, strict=True)
                ]
            )
        else:
            scores = self._judge_scores([(shapes[i], frames[i]) for i in split], turns)
        for i, shape_turns, row in zip(split, turns, scores, strict=True):
            best = choose(row, margin)
            transform, cloud, chosen = frames[i]
            out[i] = (turned(transform, shape_turns[best]), cloud @ shape_turns[best].T, chosen)
            names[i] = "tnet" if best == 0 else f"pca{best - 1}"
        return out, names, checks

    def _intrinsic_frames(
        self, shapes: list[Shape], frames: list[tuple[Transform, NDArray, str]], seed: int
    ) -> tuple[list[tuple[Transform, NDArray, str]], list[str], list[str]]:
        """The T-Net frame of each shape whose turned T-Net runs agree (as judged frames) and
        of each point cloud; each other mesh in its intrinsic frame
        (:func:`~litege_core.matching.intrinsic.intrinsic_frame`), named
        ``intrinsic:<family>`` after the reference animal that gave it. Returns the frames,
        their names and their :data:`FRAME_CHECKS` (point clouds: ``"unchecked"``)."""
        out, names = list(frames), ["tnet"] * len(frames)
        checks = ["unchecked"] * len(frames)
        meshes = [i for i, shape in enumerate(shapes) if shape.faces is not None]
        if not meshes:
            return out, names, checks
        turns = candidate_turns(
            self.bundle.tnet, [frames[i] for i in meshes], self.pipeline.n_tnet_points, seed
        )
        for i, shape_turns in zip(meshes, turns, strict=True):
            shape = shapes[i]
            checks[i] = "agreed" if shape_turns is None else "split"
            if shape_turns is None or shape.faces is None:  # the T-Net's runs agree
                continue
            found = intrinsic_frame(shape.vertices, shape.faces, self.category)
            transform, cloud, chosen = frames[i]
            turn = found.rotation @ np.asarray(transform.rotation).T  # T-Net → intrinsic frame
            out[i] = (turned(transform, turn), cloud @ turn.T, chosen)
            names[i] = f"intrinsic:{found.family}"
        return out, names, checks

    def _orientation_scores(
        self, orientation: OrientationNet, cloud: NDArray, shape_turns: NDArray, seed: int
    ) -> NDArray:
        """``−log p(canonical)`` ``(C,)`` of a T-Net-aligned cloud ``(P, 3)`` under each of
        ``C`` turns ``(C, 3, 3)``."""
        points = subsample(cloud, self.pipeline.n_tnet_points, seed)
        batch = torch.from_numpy(np.stack([points @ turn.T for turn in shape_turns]))
        log_p = orientation.canonical_log_probability(batch.to(self.device, torch.float32))
        return -log_p.double().cpu().numpy()

    def _judge_scores(
        self, members: list[tuple[Shape, tuple[Transform, NDArray, str]]], turns: list[NDArray]
    ) -> NDArray:
        """Frame-judge scores ``(S, C)`` of ``S`` shapes (with their T-Net frames) under
        their ``C`` turns each (one judge call)."""
        judge = self.frame_judge
        assert judge is not None
        clouds, points = [], []
        for (shape, (transform, cloud, _)), shape_turns in zip(members, turns, strict=True):
            base = judge.target_points(transform.apply(shape.vertices))
            clouds += [cloud @ turn.T for turn in shape_turns]
            points += [base @ turn.T for turn in shape_turns]
        return judge.scores(clouds, points).reshape(len(members), -1)

    # ------------------------------------------------------------------ features

    def _check(self, prepared: MatchingShape, what: str) -> None:
        if not isinstance(prepared, MatchingShape):
            raise InputError(f"{what} must be a MatchingShape from MatchingModel.prepare")
        if prepared.bundle_hash != self.content_hash:
            raise InputError(f"{what} was prepared with another matching model; prepare it again")

    def _biases(self, prepared: MatchingShape) -> list[torch.Tensor]:
        desc = torch.tensor(prepared.descriptor[None], device=self.device)
        with torch.no_grad():
            return [
                f.shape_bias(net.shape_embedding(desc))[0]
                for f, net in zip(self._folded, self.bundle.networks, strict=True)
            ]

    def _point_features(
        self, points: torch.Tensor, biases: list[torch.Tensor]
    ) -> list[torch.Tensor]:
        """``(R, 3)`` aligned points → per network ``(R, 2n)`` head features."""
        out = []
        with torch.no_grad():
            for folded, bias in zip(self._folded, biases, strict=True):
                chunks = [
                    folded.features(folded.embed(points[i : i + _EMBED_ROWS], bias))
                    for i in range(0, max(points.shape[0], 1), _EMBED_ROWS)
                ]
                out.append(torch.cat(chunks))
        return out

    def features(self, prepared: MatchingShape) -> list[torch.Tensor]:
        """Head features of every point of a prepared shape, per network (memoized)."""
        self._check(prepared, "shape")
        key = f"features:{self.device}"
        cached = prepared._lazy.get(key)
        if cached is None:
            points = torch.tensor(prepared.aligned, device=self.device)
            cached = torch.stack(self._point_features(points, self._biases(prepared)))
            prepared._lazy[key] = cached
        return list(cached)

    def _query_features(self, source: MatchingShape, queries: QueryLike) -> list[torch.Tensor]:
        """Head features (one table per network) of the query points of ``source``: every
        point, indices, or xyz points in X's input units snapped onto X's surface."""
        query = parse_query(queries, "queries").check(source.n_points, "queries")
        if query.points is not None:
            snapped = snap(source.projector, source.transform.apply(query.points))
            if snapped.indices is None:
                aligned = torch.from_numpy(snapped.points.astype(np.float32)).to(self.device)
                return self._point_features(aligned, self._biases(source))
            rows = snapped.indices
        elif query.indices is not None:
            rows = query.indices
        else:
            return self.features(source)
        index = torch.from_numpy(rows).to(self.device)
        return [t.index_select(0, index) for t in self.features(source)]

    # ------------------------------------------------------------------ matching

    def _score_fn(self, query: list[torch.Tensor], target: list[torch.Tensor]) -> ScoreFn:
        return ensemble_score_fn(self._folded, query, target)

    def _query_vertex_rows(self, source: MatchingShape, queries: QueryLike) -> NDArray:
        """``(N,)`` vertex rows of X for the queries (an xyz query snapped inside a triangle
        takes the nearest vertex of the snapped point): what a vertex-to-vertex refinement
        maps."""
        query = parse_query(queries, "queries").check(source.n_points, "queries")
        if query.points is not None:
            snapped = snap(source.projector, source.transform.apply(query.points))
            if snapped.indices is not None:
                return np.asarray(snapped.indices, dtype=np.int64)
            from scipy.spatial import cKDTree

            tree = cKDTree(np.asarray(source.aligned, dtype=np.float64))
            return tree.query(snapped.points)[1].astype(np.int64)
        if query.indices is not None:
            return np.asarray(query.indices, dtype=np.int64)
        return np.arange(source.n_points, dtype=np.int64)

    def mirrored(self, prepared: MatchingShape) -> MatchingShape:
        """The mirror image of a prepared shape (``x → −x`` in its aligned frame): its own
        descriptor, the same NN cache (a reflection keeps every neighbourhood) and the same
        point indexing; memoized on ``prepared``. Used as a matching target only."""
        self._check(prepared, "shape")
        cached = prepared._lazy.get("mirror")
        if cached is None:
            cloud = prepared._lazy.get("cloud")
            if cloud is None:  # restored from a cache: the aligned points stand in for it
                cloud = np.asarray(prepared.aligned, dtype=np.float32)
            described = self._engine.describe_with_residual(
                [np.asarray(cloud, dtype=np.float32) @ MIRROR.T.astype(np.float32)]
            )
            cached = MatchingShape(
                shape_id=prepared.shape_id,
                bundle_hash=prepared.bundle_hash,
                kind=prepared.kind,
                scaling=prepared.scaling,
                transform=prepared.transform,
                aligned=frozen(np.asarray(prepared.aligned) @ MIRROR.T, np.float32),
                descriptor=frozen(described.descriptors[0].cpu().numpy(), np.float32),
                residual=float(described.residual[0]),
                cache=prepared.cache,
                seed=prepared.seed,
                faces=prepared.faces,
                frame="mirror",
                frame_check=prepared.frame_check,
            )
            prepared._lazy["mirror"] = cached
        return cached

    def _search(
        self,
        query: list[torch.Tensor],
        target: MatchingShape,
        beams: int | None,
        exhaustive: bool,
    ) -> tuple[NDArray, NDArray, int]:
        """``(indices (N,) int64, network values (N,), evaluations)`` on ``target``."""
        n_queries = int(query[0].shape[0])
        score = self._score_fn(query, self.features(target))
        if exhaustive:
            found, value = exhaustive_search(
                score, n_queries, target.n_points, device=self.device, max_pairs=MAX_PAIRS_PER_CALL
            )
            evaluations = n_queries * target.n_points
        else:
            width = self.search.beams if beams is None else beams
            found, value = coarse_to_fine_search(
                target.cache,
                score,
                n_queries,
                beams=width,
                device=self.device,
                max_pairs=MAX_PAIRS_PER_CALL,
            )
            evaluations = n_queries * max_evaluations(target.cache, width)
        return (
            found.cpu().numpy().astype(np.int64),
            value.float().cpu().numpy(),
            int(evaluations),
        )

    @torch.no_grad()
    def match(
        self,
        source: MatchingShape,
        target: MatchingShape,
        queries: QueryLike = None,
        *,
        query_points: ArrayLike | None = None,
        beams: int | None = None,
        exhaustive: bool = False,
        side: str = "frame",
        refine: str = "none",
        zoomout: ZoomOutSettings | None = None,
    ) -> MatchResult:
        """Match query points of ``source`` (X) on ``target`` (Y).

        Args:
            source, target: prepared shapes (same model).
            queries: anything :func:`litege_core.query.parse_query` takes: ``(N,)`` point
                indices of X, ``(N, 3)`` xyz points in X's input units (snapped onto X's
                surface, :func:`litege_core.projection.snap`), or ``None`` / ``"all"`` for
                every point of X.
            query_points: ``(N, 3)`` xyz points, the same as passing them as ``queries``.
            beams: candidates kept per coarse tier (default: the bundle's search setting).
            exhaustive: score every point of Y (the slow reference of the search).
            side: ``"frame"`` (default): the frames decide left and right; ``"network"``:
                also match on Y's mirror image (:meth:`mirrored`) and keep the side whose
                matches have the lower mean predicted distance (twice the search). Measured
                as an ablation (``litege eval matching``): on bilaterally symmetric animals
                both sides score alike, so this does not find the side.
            refine: ``"none"``; ``"zoomout"``: refine the matches of two meshes with ZoomOut
                started from LiteGE's map; ``"zoomout-hybrid"``: that, or ZoomOut started from
                a wave-kernel-signature map, whichever preserves geodesic distances better
                (:mod:`litege_core.matching.refine`; needs pyFM; seconds per pair).
                ``distance`` is then the network's prediction at the refined match.
            zoomout: settings of the refinement (default :class:`ZoomOutSettings`; an unset
                ``distortion_tolerance`` takes the model category's default).

        Raises:
            IndexOutOfRangeError, ArrayShapeError, NonFiniteError: bad queries.
            InputError: unknown ``side`` or ``refine``, ``refine="zoomout"`` with a cloud.
            MissingDependencyError: ``refine="zoomout"`` without pyFM.
        """
        self._check(target, "target")
        if side not in SIDES:
            raise InputError(f"side must be one of {list(SIDES)}, got {side!r}")
        if refine not in REFINE_METHODS:
            raise InputError(f"refine must be one of {list(REFINE_METHODS)}, got {refine!r}")
        if refine != "none" and (source.faces is None or target.faces is None):
            raise InputError(f"refine={refine!r} needs two meshes; got a point cloud")
        if query_points is not None:
            if queries is not None:
                raise InputError("give queries or query_points, not both")
            queries = check_points(query_points, "query_points")
        query = self._query_features(source, queries)
        found, value, evaluations = self._search(query, target, beams, exhaustive)
        chosen = target
        if side == "network":
            mirror = self.mirrored(target)
            found_m, value_m, extra = self._search(query, mirror, beams, exhaustive)
            evaluations += extra
            if float(value_m.mean()) < float(value.mean()):
                found, value, chosen = found_m, value_m, mirror
        refinement = "none"
        if refine != "none":
            settings = (zoomout or ZoomOutSettings()).for_category(self.category)
            source_spectrum = spectrum(source, settings)
            target_spectrum = spectrum(target, settings)
            refined, spent = self._refined_map(
                source, target, chosen, refine, settings, beams, exhaustive
            )
            rows = self._query_vertex_rows(source, queries)
            found = refined.matches(source_spectrum, target_spectrum, rows)
            refinement = refined.refinement
            cols = torch.from_numpy(found).to(self.device)
            score = self._score_fn(query, self.features(chosen))
            index = torch.arange(cols.shape[0], device=self.device)
            value = score(index, cols[:, None])[:, 0].float().cpu().numpy()
            evaluations += spent + int(cols.shape[0])
        distance = value / self.pipeline.target_scale
        return MatchResult(
            indices=found,
            distance=distance.astype(np.float32),
            evaluations=int(evaluations),
            refinement=refinement,
        )

    def _refined_map(
        self,
        source: MatchingShape,
        target: MatchingShape,
        chosen: MatchingShape,
        refine: str,
        settings: ZoomOutSettings,
        beams: int | None,
        exhaustive: bool,
    ) -> tuple[RefinedMap, int]:
        """``(map, evaluations)``: the refined map of ``source`` → ``chosen`` (``target`` or
        its mirror image) and the network evaluations spent on it (0 when it was kept).

        The map is computed once and kept on ``source`` (its last
        :data:`REFINED_MAPS_PER_SHAPE` pairs), so every batch of a refined correspondence
        stream reuses it: its seed map is the search of the spectrum's samples, which does not
        depend on a batch's queries."""
        kept: OrderedDict = source._lazy.setdefault("refined", OrderedDict())
        mirrored = chosen is not target
        key = (target.shape_id, target.bundle_hash, mirrored, refine, settings, beams, exhaustive)
        refined = kept.get(key)
        if refined is not None:
            kept.move_to_end(key)
            return refined, 0
        source_spectrum = spectrum(source, settings)
        target_spectrum = spectrum(target, settings)
        seed_rows = torch.from_numpy(source_spectrum.samples).to(self.device)
        seed_query = [t.index_select(0, seed_rows) for t in self.features(source)]
        seed_map, _, spent = self._search(seed_query, chosen, beams, exhaustive)
        hybrid = refine == "zoomout-hybrid"
        refined = refined_map(
            refine,
            seed_map,
            source_spectrum,
            target_spectrum,
            settings,
            heat_engine(source) if hybrid else None,
            heat_engine(target) if hybrid else None,
            np.asarray(source.aligned, dtype=np.float64) if hybrid else None,
        )
        kept[key] = refined
        while len(kept) > REFINED_MAPS_PER_SHAPE:
            kept.popitem(last=False)
        return refined, spent

    @torch.no_grad()
    def cross_distances(
        self,
        source: MatchingShape,
        target: MatchingShape,
        queries: ArrayLike,
        candidates: ArrayLike,
    ) -> NDArray:
        """Predicted cross-shape geodesics ``(N, M)`` (unit-area units) between query points
        of X and candidate points of Y (the matrix the search minimizes over)."""
        self._check(target, "target")
        query = self._query_features(source, parse_query(queries, "queries", allow_all=False))
        cols = parse_indices(candidates, target.n_points, "candidates")
        rows = torch.arange(query[0].shape[0], device=self.device)
        cand = torch.from_numpy(cols).to(self.device).expand(rows.shape[0], cols.size)
        out = self._score_fn(query, self.features(target))(rows, cand)
        return out.cpu().numpy() / self.pipeline.target_scale


def ensemble_score_fn(
    networks: list[FoldedGeodesicNet], query: list[torch.Tensor], target: list[torch.Tensor]
) -> ScoreFn:
    """The search's score: network outputs on head-feature differences, averaged over the
    networks.

    Args:
        networks: folded networks (one, or an ensemble).
        query: per network ``(Q, 2n)`` head features of the query points of X.
        target: per network ``(P, 2n)`` head features of the points of Y.
    """
    scale = 1.0 / len(networks)

    def score(rows: torch.Tensor, cand: torch.Tensor) -> torch.Tensor:
        m, c = cand.shape
        total: torch.Tensor | None = None
        for net, q, t in zip(networks, query, target, strict=True):
            diff = q.index_select(0, rows)[:, None, :] - t[cand]
            out = net.head(diff.reshape(m * c, -1), inplace=True).reshape(m, c)
            total = out if total is None else total + out
        assert total is not None  # an ensemble has at least one network
        return total * scale

    return score


__all__ = [
    "FRAME_CHECKS",
    "MAX_PAIRS_PER_CALL",
    "MatchResult",
    "MatchingModel",
    "MatchingShape",
    "ensemble_score_fn",
]
