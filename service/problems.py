"""The one table that maps LiteGE errors to HTTP statuses, RFC 9457 types and gRPC codes."""

from __future__ import annotations

from dataclasses import dataclass

import grpc

from litege_core import errors as core
from service import errors as svc

PROBLEM_BASE_URI = "https://litege.dev/problems/"
MAX_DETAIL_CHARS = 500
"""Longest problem detail (and gRPC metadata value) sent: messages may quote request strings
of any length, and gRPC refuses metadata over 16 KiB with a transport error."""


@dataclass(frozen=True)
class ProblemKind:
    """How one error class is reported: ``type`` = :data:`PROBLEM_BASE_URI` + ``code``."""

    code: str
    http_status: int
    grpc_status: grpc.StatusCode
    title: str

    @property
    def type_uri(self) -> str:
        return PROBLEM_BASE_URI + self.code


_TABLE: dict[type[core.LiteGEError], tuple[int, grpc.StatusCode, str]] = {
    core.LiteGEError: (500, grpc.StatusCode.INTERNAL, "Internal error"),
    core.InputError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Invalid input"),
    core.ShapeFileError: (400, grpc.StatusCode.INVALID_ARGUMENT, "Malformed shape file"),
    core.UnsupportedFormatError: (
        415,
        grpc.StatusCode.INVALID_ARGUMENT,
        "Unsupported shape format",
    ),
    core.EmptyShapeError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Empty shape"),
    core.NonFiniteError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Non-finite coordinates"),
    core.CoordinateRangeError: (
        422,
        grpc.StatusCode.INVALID_ARGUMENT,
        "Coordinates out of range",
    ),
    core.ArrayShapeError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Badly shaped array"),
    core.FaceIndexError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Face index out of range"),
    core.NonTriangularFacesError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Faces not triangles"),
    core.DegenerateShapeError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Degenerate shape"),
    core.ShapeTooLargeError: (413, grpc.StatusCode.INVALID_ARGUMENT, "Shape too large"),
    core.IndexOutOfRangeError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Index out of range"),
    core.MethodNotApplicableError: (
        422,
        grpc.StatusCode.INVALID_ARGUMENT,
        "Method not applicable to this shape",
    ),
    core.MethodSizeLimitError: (
        422,
        grpc.StatusCode.INVALID_ARGUMENT,
        "Shape too large for this method",
    ),
    core.ArtifactError: (500, grpc.StatusCode.INTERNAL, "Corrupt model or cache artifact"),
    core.ComputationError: (500, grpc.StatusCode.INTERNAL, "Computation failed"),
    core.MissingDependencyError: (501, grpc.StatusCode.UNIMPLEMENTED, "Missing dependency"),
    svc.RequestError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Invalid request"),
    svc.UnknownModelError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Unknown model"),
    svc.TooManyQueriesError: (422, grpc.StatusCode.INVALID_ARGUMENT, "Too many queries"),
    svc.PayloadTooLargeError: (413, grpc.StatusCode.RESOURCE_EXHAUSTED, "Payload too large"),
    svc.UnsupportedMediaTypeError: (
        415,
        grpc.StatusCode.INVALID_ARGUMENT,
        "Unsupported media type",
    ),
    svc.ServiceError: (500, grpc.StatusCode.INTERNAL, "Service error"),
    svc.ShapeNotFoundError: (404, grpc.StatusCode.NOT_FOUND, "Shape not found"),
    svc.AuthenticationError: (401, grpc.StatusCode.UNAUTHENTICATED, "Missing or wrong API key"),
    svc.RetryLaterError: (503, grpc.StatusCode.RESOURCE_EXHAUSTED, "Retry later"),
    svc.OverloadedError: (503, grpc.StatusCode.RESOURCE_EXHAUSTED, "Service overloaded"),
    svc.OutOfMemoryError: (503, grpc.StatusCode.RESOURCE_EXHAUSTED, "Out of memory"),
    svc.DeadlineExceededError: (504, grpc.StatusCode.DEADLINE_EXCEEDED, "Deadline exceeded"),
    svc.RequestTimeoutError: (408, grpc.StatusCode.DEADLINE_EXCEEDED, "Request body timeout"),
    svc.NotReadyError: (503, grpc.StatusCode.UNAVAILABLE, "Service not ready"),
}


def bounded(text: str, limit: int = MAX_DETAIL_CHARS) -> str:
    """``text`` cut to ``limit`` characters, saying how many were left out."""
    if len(text) <= limit:
        return text
    return f"{text[:limit]}… ({len(text) - limit} more characters)"


def problem_detail(exc: core.LiteGEError) -> str:
    """The detail sent for ``exc`` (REST ``detail``, gRPC status details): its message,
    :func:`bounded`."""
    return bounded(str(exc))


def problem_for(exc: core.LiteGEError) -> ProblemKind:
    """The table entry of the most specific class of ``exc`` (walks its MRO)."""
    for cls in type(exc).__mro__:
        entry = _TABLE.get(cls)
        if entry is not None:
            status, grpc_status, title = entry
            if isinstance(exc, svc.OverloadedError):
                status = exc.status
            return ProblemKind(cls.code, status, grpc_status, title)  # type: ignore[attr-defined]
    raise TypeError(f"{type(exc).__name__} is not a LiteGEError")
