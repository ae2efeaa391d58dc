"""Service-level errors, in the same hierarchy as the core's (:class:`LiteGEError`).

::

    LiteGEError
    ├── InputError (core)           bad shapes, arrays, indices ...
    │   ├── RequestError            a request the service cannot take as sent
    │   │   ├── UnknownModelError
    │   │   ├── TooManyQueriesError
    │   │   ├── PayloadTooLargeError
    │   │   └── UnsupportedMediaTypeError
    ├── ServiceError
    │   ├── ShapeNotFoundError
    │   ├── AuthenticationError
    │   ├── RetryLaterError         a transient lack of capacity (carries ``retry_after_s``)
    │   │   ├── OverloadedError     queue full / too many concurrent requests
    │   │   └── OutOfMemoryError    the device (or host) ran out of memory for this request
    │   ├── DeadlineExceededError
    │   ├── RequestTimeoutError     the client did not send its body in time
    │   └── NotReadyError
    ├── ArtifactError (core), ComputationError (core), MissingDependencyError (core)

:mod:`service.problems` maps every class to one HTTP status, RFC 9457 ``type`` and gRPC code.
"""

from __future__ import annotations

from litege_core.errors import InputError, LiteGEError


class RequestError(InputError):
    """A well-formed request the service will not run as sent."""

    code = "invalid-request"


class UnknownModelError(RequestError):
    code = "unknown-model"


class TooManyQueriesError(RequestError):
    code = "too-many-queries"


class PayloadTooLargeError(RequestError):
    code = "payload-too-large"


class UnsupportedMediaTypeError(RequestError):
    code = "unsupported-media-type"


class ServiceError(LiteGEError):
    """The service's own conditions (not the caller's input)."""

    code = "service-error"


class ShapeNotFoundError(ServiceError):
    code = "shape-not-found"


class AuthenticationError(ServiceError):
    code = "unauthorized"


class RetryLaterError(ServiceError):
    """Capacity the request needs is missing now; retry after ``retry_after_s`` seconds."""

    code = "retry-later"

    def __init__(self, message: str, *, retry_after_s: float = 1.0) -> None:
        super().__init__(message)
        self.retry_after_s = retry_after_s


class OverloadedError(RetryLaterError):
    """The work queue or the concurrency limit is full (``status`` 503 or 429)."""

    code = "overloaded"

    def __init__(self, message: str, *, retry_after_s: float = 1.0, status: int = 503) -> None:
        super().__init__(message, retry_after_s=retry_after_s)
        self.status = status


class OutOfMemoryError(RetryLaterError):
    """The device (CUDA out of memory) or the host ran out of memory for this request; the
    other requests of its batch are answered normally."""

    code = "out-of-memory"


class DeadlineExceededError(ServiceError):
    code = "deadline-exceeded"


class RequestTimeoutError(ServiceError):
    """The client did not send its request body within ``LITEGE_BODY_READ_TIMEOUT_S``."""

    code = "request-timeout"


class NotReadyError(ServiceError):
    code = "not-ready"
