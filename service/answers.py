"""What the service answers: a registered shape, who answered a geodesic request, a path, a
correspondence, and the readiness of the process (the types REST and gRPC translate)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from litege_core.engines import ClassicalPath
from litege_core.learned import GeodesicPath
from service.repository import Registered

NO_REFINEMENT = "none"
"""The default ``refine`` of a correspondence: LiteGE's matches as they are."""
LEARNED = "learned"
"""The default ``method``: the model's prediction (engine ``"learned"``)."""


@dataclass(frozen=True)
class ShapeInfo:
    """What the API returns about a registered shape."""

    shape_id: str
    kind: str
    n_points: int
    n_faces: int
    model: str
    bundle_hash: str
    ood_score: float
    ood_calibrated: bool
    out_of_distribution: bool | None
    created: bool
    model_scores: dict[str, float] | None = None
    """Every loaded model's OOD score of the shape when ``model`` was chosen automatically
    (``auto``: the lowest wins); ``None`` when a model was named."""

    @classmethod
    def of(cls, registered: Registered) -> ShapeInfo:
        state = registered.state
        scores = registered.scores
        return cls(
            shape_id=state.shape_id,
            kind=state.kind.value,
            n_points=state.n_points,
            n_faces=0 if state.faces is None else int(state.faces.shape[0]),
            model=registered.model,
            bundle_hash=state.bundle_hash,
            ood_score=float(state.ood_score),
            ood_calibrated=state.ood_calibrated,
            out_of_distribution=state.is_out_of_distribution,
            created=registered.created,
            model_scores=None if scores is None else dict(scores),
        )


@dataclass(frozen=True)
class GeodesicAnswer:
    """Who answered a geodesic request.

    Attributes:
        shape_id: the shape.
        method: the requested method (``learned``, ``heat``, ``exact``, ``graph``).
        engine: what ran: ``learned``, or the classical engine (``heat``,
            ``pointcloud-heat``, ``exact-mmp``, ``knn-graph``).
        info: the shape's registration under the model that answered (``learned``);
            ``None`` for classical methods (no model involved).
    """

    shape_id: str
    method: str
    engine: str
    info: ShapeInfo | None = None

    @property
    def model(self) -> str | None:
        return None if self.info is None else self.info.model


@dataclass(frozen=True)
class PathResult:
    """A geodesic path, from source to target.

    Attributes:
        points: ``(L, 3)`` float64 polyline in the user's frame, ``points[0]`` the source.
        length: polyline length (user units).
        method: the requested method; ``engine``: what ran (see :class:`GeodesicAnswer`).
        distance: the method's distance between the end points (user units): the model's
            answer (``learned``: as :meth:`~service.runtime.Runtime.geodesic` gives it, fused
            where the model fuses) or the engine's distance (exact: the exact geodesic).
        segments: ``(start_index, how)`` per part of the polyline, in order (which method
            produced which part: ``learned``, ``edge-flip``, ``mesh-edges``, ``knn-graph``,
            ``straight``, ``heat-descent``, ``exact-mmp``).
        model: the model that answered (``learned``), else ``None``.
        predicted_distance: the network's distance of a learned path, else ``None``.
        n_steps: accepted gradient steps of a learned walk (0: a surface route), else ``None``.
        converged: whether a learned walk reached the source (a surface route: whether it
            joins the two points), else ``None``.
    """

    points: np.ndarray
    length: float
    method: str
    engine: str
    distance: float
    segments: tuple[tuple[int, str], ...]
    model: str | None = None
    predicted_distance: float | None = None
    n_steps: int | None = None
    converged: bool | None = None

    @classmethod
    def of(cls, path: GeodesicPath, model: str, distance: float) -> PathResult:
        """A learned path; ``distance``: the model's answer for its end points."""
        return cls(
            points=np.ascontiguousarray(path.points),  # the library gives source → target
            length=float(path.length),
            method=LEARNED,
            engine=LEARNED,
            distance=float(distance),
            segments=tuple((int(i), str(how)) for i, how in path.segments),
            model=model,
            predicted_distance=float(path.predicted_distance),
            n_steps=int(path.n_steps),
            converged=bool(path.converged),
        )

    @classmethod
    def of_classical(cls, path: ClassicalPath, method: str) -> PathResult:
        return cls(
            points=np.ascontiguousarray(path.points),
            length=float(path.length),
            method=method,
            engine=path.engine,
            distance=float(path.distance),
            segments=tuple((int(i), str(how)) for i, how in path.segments),
        )


@dataclass(frozen=True)
class Readiness:
    ready: bool
    degraded: bool
    detail: dict[str, Any]


@dataclass(frozen=True)
class FrameInfo:
    """How the canonical frame of a shape prepared for matching was chosen.

    Attributes:
        frame: :attr:`MatchingShape.frame <litege_core.matching.model.MatchingShape>`:
            ``"tnet"``, ``"pcaK"`` or ``"intrinsic:<family>"``.
        check: :attr:`MatchingShape.frame_check <litege_core.matching.model.MatchingShape>`:
            ``"agreed"`` (the T-Net's turned runs agreed), ``"split"`` (they did not: an
            uncertain frame, chosen among candidates) or ``"unchecked"``.
    """

    frame: str
    check: str

    def to_dict(self) -> dict[str, str]:
        return {"frame": self.frame, "check": self.check}


UNCHECKED_FRAME = FrameInfo("tnet", "unchecked")


@dataclass(frozen=True)
class Correspondence:
    """Matches of query points of a source shape on a target shape.

    Attributes:
        source_shape_id, target_shape_id: the two shapes.
        model: the matching model that answered.
        matches: ``(K,)`` int64 matched target vertex / point indices.
        distances: ``(K,)`` float32 predicted cross-shape geodesic at each match in the
            target's input units (``distances_unit_area`` scaled back by the target's
            unit-area scale).
        distances_unit_area: ``(K,)`` float32 the same in unit-area units (both shapes
            scaled to unit surface area): what the matching network predicts.
        evaluations: network pair evaluations used.
        refinement: how the matches were refined (:attr:`MatchResult.refinement
            <litege_core.matching.model.MatchResult>`): ``"none"``, ``"zoomout"``, or
            ``"zoomout:<seed>"`` for ``refine="zoomout-hybrid"`` (the start of the kept map).
        source_frame, target_frame: how each shape's frame was chosen (a ``"split"`` check
            warns that the matches may be turned or mirrored).
    """

    source_shape_id: str
    target_shape_id: str
    model: str
    matches: np.ndarray
    distances: np.ndarray
    distances_unit_area: np.ndarray
    evaluations: int
    refinement: str = NO_REFINEMENT
    source_frame: FrameInfo = UNCHECKED_FRAME
    target_frame: FrameInfo = UNCHECKED_FRAME

    @property
    def n_queries(self) -> int:
        return int(self.matches.shape[0])
