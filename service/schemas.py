"""Request and response bodies of the REST API (separate request/response models)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

Point = Annotated[list[float], Field(min_length=3, max_length=3, description="[x, y, z]")]
Triangle = Annotated[list[int], Field(min_length=3, max_length=3)]
VertexIndex = Annotated[int, Field(ge=0)]
Indices = Annotated[list[VertexIndex], Field(min_length=1, description="vertex/point indices")]
Points = Annotated[
    list[Point], Field(min_length=1, description="xyz points in the shape's frame and units")
]
ShapeKindName = Literal["mesh", "point_cloud"]


class _Request(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ShapeArraysRequest(_Request):
    """A shape sent as JSON arrays (``POST /shapes`` with ``application/json``)."""

    vertices: Annotated[list[Point], Field(min_length=1)]
    faces: list[Triangle] | None = None
    kind: ShapeKindName | None = None
    model: str | None = Field(None, description="model bundle (default: the service default)")


class GeodesicRequest(_Request):
    shape_id: str = Field(min_length=1, max_length=128)
    model: str | None = None
    sources: Indices | Points
    targets: Indices | Points | Literal["all"] = "all"


class PathRequest(_Request):
    shape_id: str = Field(min_length=1, max_length=128)
    model: str | None = None
    source: VertexIndex | Point
    target: VertexIndex | Point


class CorrespondenceRequest(_Request):
    """Match query points of the source shape on the target shape (both registered first
    with ``POST /shapes``; their ids are the content hashes)."""

    source_shape_id: str = Field(min_length=1, max_length=128)
    target_shape_id: str = Field(min_length=1, max_length=128)
    queries: Indices | Points | Literal["all"] = Field(
        "all",
        description="source vertex/point indices, xyz points in the source's frame and units, "
        "or 'all' (every source vertex/point)",
    )
    return_distance: bool = Field(False, description="also return the distance at each match")
    model: str | None = Field(None, description="matching model (default: the service's)")


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


class GeodesicResponse(BaseModel):
    shape_id: str
    model: str
    rows: int
    cols: int
    units: Literal["input"] = "input"
    distances: list[list[float]] = Field(description="rows × cols, row-major, in input units")


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
        description="per query, the predicted cross-shape geodesic distance at the match, in "
        "unit-area units (both shapes scaled to unit surface area), NOT the shapes' input "
        "units; null unless return_distance was true",
    )


class PathResponse(BaseModel):
    shape_id: str
    points: list[Point] = Field(description="polyline from source to target")
    length: float
    predicted_distance: float
    n_steps: int
    converged: bool


class Problem(BaseModel):
    """RFC 9457 problem details."""

    type: str
    title: str
    status: int
    detail: str
    instance: str | None = None
    code: str
