"""Request and response bodies of the REST API (separate request/response models).

Query fields (``sources``, ``targets``, ``source``, ``target``, ``queries``) are taken as the
JSON they are and parsed by the one rule of :func:`litege_core.query.parse_query` (in
:class:`service.runtime.Runtime`), exactly as gRPC's; their JSON schema documents that rule.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, WithJsonSchema

from litege_core.matching.refine import REFINE_METHODS
from service.errors import RequestError

SHAPE_ID_MAX_LENGTH = 128
"""Longest shape id a request may name (ids are hex content hashes, far shorter)."""


def check_shape_id(shape_id: str, field: str = "shape_id") -> str:
    """``shape_id`` stripped, as the REST bodies' ``Field(min_length=1,
    max_length=SHAPE_ID_MAX_LENGTH)`` accept it (the gRPC server's check).

    Raises:
        RequestError: an empty or overlong id.
    """
    shape_id = shape_id.strip()
    if not shape_id:
        raise RequestError(f"{field} is required")
    if len(shape_id) > SHAPE_ID_MAX_LENGTH:
        raise RequestError(
            f"{field} is {len(shape_id)} characters long; shape ids have at most "
            f"{SHAPE_ID_MAX_LENGTH}"
        )
    return shape_id


Point = Annotated[list[float], Field(min_length=3, max_length=3, description="[x, y, z]")]
Triangle = Annotated[list[int], Field(min_length=3, max_length=3)]
ShapeKindName = Literal["mesh", "point_cloud"]
MethodName = Literal["learned", "heat", "exact", "graph"]
EngineName = Literal["learned", "heat", "pointcloud-heat", "exact-mmp", "knn-graph"]

_MODEL_DESCRIPTION = (
    "geodesic model bundle, or 'auto': the loaded model with the lowest out-of-distribution "
    "score, weighed with its network-to-graph agreement, for this shape (default: the "
    "service's LITEGE_DEFAULT_MODEL, 'auto' unless set)"
)
_METHODS_TEXT = (
    "'learned' (default: the model's prediction, blended with its calibrated graph "
    "Dijkstra where the model ships one and LITEGE_GEODESIC_FUSION is 'auto', the default, or "
    "'graph'; paths follow the network), 'heat' (meshes: robust intrinsic heat "
    "method; point clouds: point-cloud heat method, more than 30 distinct points), 'exact' "
    "(meshes only: exact polyhedral "
    "geodesics, MMP; refused above LITEGE_MAX_EXACT_VERTICES vertices{extra}) or 'graph' "
    "(Dijkstra on the k-nearest-neighbour graph). Same units (the shape's input units) and "
    "query types for all; 'model' only matters for 'learned'"
)
_GEODESIC_METHOD = _METHODS_TEXT.format(extra=" and above LITEGE_MAX_EXACT_SOURCES sources")
_PATH_METHOD = _METHODS_TEXT.format(extra="; its paths are exact geodesics")

_INDICES_SCHEMA = {
    "type": "array",
    "items": {"type": "integer", "minimum": 0},
    "minItems": 1,
    "description": "vertex/point indices",
}
_POINTS_SCHEMA = {
    "type": "array",
    "items": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
    "minItems": 1,
    "description": "xyz points in the shape's frame and units (snapped onto the surface)",
}
_POINT_SCHEMA = {
    "type": "array",
    "items": {"type": "number"},
    "minItems": 3,
    "maxItems": 3,
    "description": "[x, y, z]",
}
_ALL_SCHEMA = {"type": "string", "enum": ["all"], "description": "every vertex/point"}

Query = Annotated[Any, WithJsonSchema({"anyOf": [_INDICES_SCHEMA, _POINTS_SCHEMA]})]
"""Indices or xyz points (``"all"`` is refused where one must name points)."""
QueryOrAll = Annotated[
    Any, WithJsonSchema({"anyOf": [_INDICES_SCHEMA, _POINTS_SCHEMA, _ALL_SCHEMA]})
]
"""Indices, xyz points or ``"all"``."""
SinglePoint = Annotated[
    Any,
    WithJsonSchema(
        {
            "anyOf": [
                {"type": "integer", "minimum": 0, "description": "a vertex/point index"},
                _POINT_SCHEMA,
            ]
        }
    ),
]
"""One index or one ``[x, y, z]`` point."""


def _refine_method(value: str) -> str:
    if value not in REFINE_METHODS:
        raise ValueError(f"refine must be one of {list(REFINE_METHODS)}, got {value!r}")
    return value


RefineName = Annotated[
    str,
    AfterValidator(_refine_method),
    WithJsonSchema({"type": "string", "enum": list(REFINE_METHODS)}),
]
"""One of the library's ``REFINE_METHODS`` (:mod:`litege_core.matching.refine`)."""


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ShapeArraysRequest(_Request):
    """A shape sent as JSON arrays (``POST /shapes`` with ``application/json``)."""

    vertices: Annotated[list[Point], Field(min_length=1)]
    faces: list[Triangle] | None = None
    kind: ShapeKindName | None = None
    model: str | None = Field(None, description=_MODEL_DESCRIPTION)


class GeodesicRequest(_Request):
    shape_id: str = Field(min_length=1, max_length=SHAPE_ID_MAX_LENGTH)
    model: str | None = Field(None, description=_MODEL_DESCRIPTION)
    method: MethodName = Field("learned", description=_GEODESIC_METHOD)
    sources: Query = Field(description="vertex/point indices or xyz points")
    targets: QueryOrAll = Field("all", description="indices, xyz points or 'all'")


class PathRequest(_Request):
    shape_id: str = Field(min_length=1, max_length=SHAPE_ID_MAX_LENGTH)
    model: str | None = Field(None, description=_MODEL_DESCRIPTION)
    method: MethodName = Field("learned", description=_PATH_METHOD)
    source: SinglePoint = Field(description="one vertex/point index or one [x, y, z] point")
    target: SinglePoint = Field(description="one vertex/point index or one [x, y, z] point")


class CorrespondenceRequest(_Request):
    """Match query points of the source shape on the target shape (both registered first
    with ``POST /shapes``; their ids are the content hashes)."""

    source_shape_id: str = Field(min_length=1, max_length=SHAPE_ID_MAX_LENGTH)
    target_shape_id: str = Field(min_length=1, max_length=SHAPE_ID_MAX_LENGTH)
    queries: QueryOrAll = Field(
        "all",
        description="source vertex/point indices, xyz points in the source's frame and units, "
        "or 'all' (every source vertex/point)",
    )
    return_distance: bool = Field(False, description="also return the distance at each match")
    model: str | None = Field(
        None,
        description="matching model (default: the model of the source shape's category: the "
        "service's category router's where it is confident, else that of the model 'auto' "
        "registers the shape with; else the service's first)",
    )
    refine: RefineName = Field(
        "none",
        description="'none' (default): the learned matches; 'zoomout': refine them with ZoomOut "
        "(functional maps started from the learned map); 'zoomout-hybrid': that, or ZoomOut "
        "started from a wave-kernel-signature map, whichever preserves geodesic distances "
        "better. Meshes only (a point cloud: 422 method-not-applicable); seconds per pair, "
        "and the request runs as one compute job; needs pyFM on the server (else 501 "
        "missing-dependency)",
    )


class ShapeInfoResponse(BaseModel):
    shape_id: str
    kind: ShapeKindName
    n_points: int
    n_faces: int
    model: str
    bundle_hash: str
    ood_score: float
    ood_calibrated: bool
    out_of_distribution: bool | None
    created: bool
    model_scores: dict[str, float] | None = Field(
        None,
        description="when the model was chosen automatically ('auto'): every loaded model's "
        "out-of-distribution score for this shape (z-score when calibrated; 'model' is the "
        "lowest); null when a model was named",
    )


class GeodesicResponse(BaseModel):
    shape_id: str
    model: str | None = Field(
        description="the model that answered ('learned'); null for classical methods"
    )
    method: MethodName = Field(description="the method asked for")
    engine: EngineName = Field(
        description="what ran: 'learned', or the classical engine ('heat', 'pointcloud-heat', "
        "'exact-mmp', 'knn-graph')"
    )
    rows: int
    cols: int
    units: Literal["input"] = "input"
    distances: list[list[float | None]] = Field(
        description="rows × cols, row-major, in input units; null where a classical engine "
        "finds no surface path (points on different connected components: +inf in the "
        "binary and msgpack formats)"
    )


class FrameInfoModel(BaseModel):
    """How a shape's canonical frame was chosen for matching."""

    frame: str = Field(
        description="'tnet' (the T-Net's frame), 'pcaK' (principal-axis frame K, chosen by "
        "the frame judge) or 'intrinsic:<family>' (frames='intrinsic')"
    )
    check: Literal["agreed", "split", "unchecked"] = Field(
        description="'agreed': the T-Net's frame held on turned copies of the shape; 'split': "
        "it did not, and the frame was chosen among candidates: an uncertain frame (on the "
        "real dev animals about half of these are wrong), so the matches may be turned or "
        "mirrored; 'unchecked': no check ran (frames='tnet')"
    )


class CorrespondenceResponse(BaseModel):
    source_shape_id: str
    target_shape_id: str
    model: str = Field(description="the matching model that answered")
    n_queries: int
    matches: list[int] = Field(
        description="per query, the matched target vertex/point index (target's indexing)"
    )
    distances: list[float] | None = Field(
        None,
        description="per query, the predicted cross-shape geodesic distance at the match in "
        "the TARGET shape's input units (distances_unit_area scaled by the target's own "
        "unit-area scale); null unless return_distance was true",
    )
    distances_unit_area: list[float] | None = Field(
        None,
        description="the same distances in unit-area units (both shapes scaled to unit "
        "surface area: what the matching network predicts, comparable across shapes); null "
        "unless return_distance was true",
    )
    refinement: str = Field(
        description="how the matches were refined: 'none', 'zoomout', or for 'zoomout-hybrid' "
        "'zoomout:<seed>' naming the start of the kept map ('zoomout:litege' or "
        "'zoomout:descriptors')"
    )
    source_frame: FrameInfoModel = Field(description="how the source shape's frame was chosen")
    target_frame: FrameInfoModel = Field(description="how the target shape's frame was chosen")


class PathSegment(BaseModel):
    start: int = Field(description="index in points where this part starts")
    method: str = Field(
        description="what produced the part: 'learned' (the learned walk), 'edge-flip', "
        "'mesh-edges', 'knn-graph', 'straight' (a surface route: the whole learned path "
        "where the model fuses its distances with a graph, or the finish of a stalled "
        "learned walk), 'heat-descent', 'exact-mmp'"
    )


class PathResponse(BaseModel):
    shape_id: str
    model: str | None = Field(
        None, description="the model that answered ('learned'); null for classical methods"
    )
    method: MethodName = Field(description="the method asked for")
    engine: EngineName = Field(description="what ran (see GeodesicResponse.engine)")
    points: list[Point] = Field(description="polyline from source to target")
    length: float = Field(description="polyline length, input units")
    distance: float = Field(
        description="the method's distance between source and target, input units (learned: "
        "the model's, as /geodesic answers it, fused where the model fuses; exact: the exact "
        "geodesic, equal to length to rounding)"
    )
    segments: list[PathSegment] = Field(
        description="the parts of the polyline in order; part k runs from points[start_k] to "
        "the next part's start (the last one to the end)"
    )
    predicted_distance: float | None = Field(
        None, description="learned paths: the network's distance; null otherwise"
    )
    n_steps: int | None = Field(
        None, description="learned paths: accepted gradient steps (0 for a surface route)"
    )
    converged: bool | None = Field(
        None,
        description="learned paths: whether the learned walk reached the source (else an "
        "on-surface route finished it, see segments), or for a surface route whether it joins "
        "the two points on the surface; null for classical methods",
    )


class Problem(BaseModel):
    """RFC 9457 problem details."""

    type: str
    title: str
    status: int
    detail: str
    instance: str | None = None
    code: str
