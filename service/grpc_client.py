"""A small synchronous Python client of the gRPC API (``litege.v1.LiteGE``).

::

    from service.grpc_client import GrpcClient

    with GrpcClient("127.0.0.1:50051", api_key=None) as client:
        info = client.register_file("dog.obj")                  # dict, info["shape_id"]
        d = client.geodesic(info["shape_id"], [0, 17, 42])      # (3, N) float32
        d = client.geodesic(info["shape_id"], [0], method="heat")  # a classical engine
        path = client.path(info["shape_id"], 0, 4242)           # path["points"]: (L, 3)
        for answer in client.correspond(source_id, target_id, [[0, 1], "all"]):
            answer["matches"]                                   # (K,) int64, per batch


A failed call raises :class:`GrpcCallError` with the gRPC status code, the server's message and
the RFC 9457 problem type URI the server sent in its trailing metadata (and, for ``Correspond``,
the id of the batch that failed).
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import grpc
import numpy as np
from numpy.typing import ArrayLike, NDArray

from service.grpc_stubs import load_stubs

API_KEY_HEADER = "x-api-key"
PROBLEM_TYPE_KEY = "litege-problem-type"
RETRY_AFTER_KEY = "retry-after-ms"
BATCH_ID_KEY = "litege-batch-id"
DEFAULT_MAX_MESSAGE_BYTES = 65 << 20
"""The server's default upload limit (64 MiB) plus its framing headroom."""
DEFAULT_CHUNK_BYTES = 1 << 20


class GrpcCallError(Exception):
    """A gRPC call that did not succeed.

    Attributes:
        code: the :class:`grpc.StatusCode`.
        message: the server's (or the channel's) description.
        problem_type: RFC 9457 ``type`` URI from the ``litege-problem-type`` trailing metadata,
            ``None`` when the server sent none (e.g. a transport error or a client deadline).
        retry_after_ms: from ``retry-after-ms`` (overloaded server), else ``None``.
        batch_id: from ``litege-batch-id`` (the ``Correspond`` batch that failed), else
            ``None``.
    """

    def __init__(
        self,
        code: grpc.StatusCode,
        message: str,
        problem_type: str | None = None,
        retry_after_ms: int | None = None,
        batch_id: int | None = None,
    ) -> None:
        super().__init__(f"{code.name}: {message}")
        self.code = code
        self.message = message
        self.problem_type = problem_type
        self.retry_after_ms = retry_after_ms
        self.batch_id = batch_id

    @classmethod
    def of(cls, error: grpc.RpcError) -> GrpcCallError:
        """Translate the exception a gRPC stub raised."""
        code = error.code() if hasattr(error, "code") else grpc.StatusCode.UNKNOWN
        details = error.details() if hasattr(error, "details") else str(error)
        trailing = (
            dict(error.trailing_metadata() or ()) if hasattr(error, "trailing_metadata") else {}
        )
        retry = trailing.get(RETRY_AFTER_KEY)
        batch = trailing.get(BATCH_ID_KEY)
        return cls(
            code or grpc.StatusCode.UNKNOWN,
            details or "",
            trailing.get(PROBLEM_TYPE_KEY),
            int(retry) if retry and str(retry).isdigit() else None,
            int(batch) if batch and str(batch).isdigit() else None,
        )


def _frame_info(message: Any) -> dict[str, str]:
    """A ``FrameInfo`` message as ``{"frame", "check"}``."""
    return {"frame": message.frame, "check": message.check}


def _indices_or_points(value: ArrayLike, what: str) -> tuple[str, NDArray]:
    """``("indices", (K,) int64)`` or ``("points", (K, 3) float64)`` from user input."""
    array = np.asarray(value)
    if array.dtype.kind in "iu" and array.ndim <= 1:
        return "indices", array.astype(np.int64).reshape(-1)
    if array.dtype.kind == "f" and array.shape[-1:] == (3,) and array.ndim in (1, 2):
        return "points", array.astype(np.float64).reshape(-1, 3)
    raise ValueError(
        f"{what} must be integer indices (K,) or float xyz points (K, 3); "
        f"got dtype {array.dtype} and shape {array.shape}"
    )


class GrpcClient:
    """Synchronous client over an insecure channel (see the module docstring).

    Args:
        target: ``host:port`` of the server.
        api_key: sent as ``x-api-key`` metadata with every LiteGE call.
        timeout_s: default deadline of each call (methods take ``timeout_s`` to override).
        max_message_bytes: largest message sent or received.
    """

    def __init__(
        self,
        target: str,
        *,
        api_key: str | None = None,
        timeout_s: float = 30,
        max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
    ) -> None:
        self.pb2, pb2_grpc = load_stubs()
        self.target = target
        self.timeout_s = timeout_s
        self._metadata = ((API_KEY_HEADER, api_key),) if api_key else ()
        self._channel = grpc.insecure_channel(
            target,
            options=[
                ("grpc.max_send_message_length", max_message_bytes),
                ("grpc.max_receive_message_length", max_message_bytes),
            ],
        )
        self._stub = pb2_grpc.LiteGEStub(self._channel)

    # ------------------------------------------------------------------ plumbing

    def close(self) -> None:
        self._channel.close()

    def __enter__(self) -> GrpcClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _call(self, method: str, request: Any, timeout_s: float | None) -> Any:
        try:
            return getattr(self._stub, method)(
                request,
                timeout=self.timeout_s if timeout_s is None else timeout_s,
                metadata=self._metadata,
            )
        except grpc.RpcError as exc:
            raise GrpcCallError.of(exc) from None

    @staticmethod
    def _info(message: Any) -> dict[str, Any]:
        """``litege.v1.ShapeInfo`` → dict (``out_of_distribution`` ``None`` when unset)."""
        return {
            "shape_id": message.shape_id,
            "kind": message.kind,
            "n_points": int(message.n_points),
            "n_faces": int(message.n_faces),
            "model": message.model,
            "bundle_hash": message.bundle_hash,
            "ood_score": float(message.ood_score),
            "ood_calibrated": bool(message.ood_calibrated),
            "out_of_distribution": (
                bool(message.out_of_distribution)
                if message.HasField("out_of_distribution")
                else None
            ),
            "created": bool(message.created),
            "model_scores": dict(message.model_scores) or None,
        }

    def _header(self, file_format: str, kind: str | None, model: str | None, **fields: Any) -> Any:
        header = self.pb2.ShapeHeader(file_format=file_format, **fields)
        if kind is not None:
            header.kind = kind
        if model is not None:
            header.model = model
        return self.pb2.RegisterShapeRequest(header=header)

    def _chunks(self, data: bytes, chunk_bytes: int) -> Iterator[Any]:
        if chunk_bytes < 1:
            raise ValueError("chunk_bytes must be positive")
        view = memoryview(data)
        for start in range(0, len(view), chunk_bytes):
            yield self.pb2.RegisterShapeRequest(chunk=bytes(view[start : start + chunk_bytes]))

    # ------------------------------------------------------------------ shapes

    def register_file(
        self,
        path_or_bytes: str | os.PathLike[str] | bytes,
        file_format: str | None = None,
        kind: str | None = None,
        model: str | None = None,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        *,
        timeout_s: float | None = None,
    ) -> dict[str, Any]:
        """Upload a shape file (streamed in ``chunk_bytes`` pieces) and register it.

        ``file_format`` defaults to the path's extension; it is required for bytes.
        Returns the shape info as a dict (``shape_id``, ``created``, ...).
        """
        if isinstance(path_or_bytes, bytes | bytearray | memoryview):
            if file_format is None:
                raise ValueError("file_format is required when uploading bytes")
            data = bytes(path_or_bytes)
        else:
            path = Path(path_or_bytes)
            file_format = file_format or path.suffix.lstrip(".").lower()
            data = path.read_bytes()

        def requests() -> Iterator[Any]:
            yield self._header(file_format, kind, model)
            yield from self._chunks(data, chunk_bytes)

        return self._info(self._call("RegisterShape", requests(), timeout_s))

    def register_arrays(
        self,
        vertices: ArrayLike,
        faces: ArrayLike | None = None,
        kind: str | None = None,
        model: str | None = None,
        *,
        chunk_bytes: int = DEFAULT_CHUNK_BYTES,
        timeout_s: float | None = None,
    ) -> dict[str, Any]:
        """Register ``(N, 3)`` vertices and optional ``(F, 3)`` triangles (raw-chunk encoding:
        little-endian float64 vertices, then int64 faces)."""
        v = np.ascontiguousarray(vertices, dtype="<f8")
        if v.ndim != 2 or v.shape[1] != 3:
            raise ValueError(f"vertices must have shape (N, 3), got {v.shape}")
        f = np.zeros((0, 3), dtype="<i8")
        if faces is not None:
            f = np.asarray(faces)
            if f.size and f.dtype.kind not in "iu":
                raise ValueError(f"faces must be integer indices, got dtype {f.dtype}")
            f = np.ascontiguousarray(f, dtype="<i8")
            if f.ndim != 2 or f.shape[1] != 3:
                raise ValueError(f"faces must have shape (F, 3), got {f.shape}")
        data = v.tobytes() + f.tobytes()

        def requests() -> Iterator[Any]:
            yield self._header("arrays", kind, model, n_vertices=len(v), n_faces=len(f))
            yield from self._chunks(data, chunk_bytes)

        return self._info(self._call("RegisterShape", requests(), timeout_s))

    def get_shape(
        self, shape_id: str, model: str | None = None, *, timeout_s: float | None = None
    ) -> dict[str, Any]:
        """The shape's info (``created`` is ``False``)."""
        request = self.pb2.ShapeRef(shape_id=shape_id)
        if model is not None:
            request.model = model
        return self._info(self._call("GetShape", request, timeout_s))

    def delete_shape(self, shape_id: str, *, timeout_s: float | None = None) -> dict[str, Any]:
        """Forget the shape: ``{"shape_id": ..., "deleted": True}`` (NOT_FOUND when unknown)."""
        response = self._call("DeleteShape", self.pb2.ShapeRef(shape_id=shape_id), timeout_s)
        return {"shape_id": response.shape_id, "deleted": bool(response.deleted)}

    # ------------------------------------------------------------------ queries

    def geodesic(
        self,
        shape_id: str,
        sources: ArrayLike,
        targets: ArrayLike | str | None = "all",
        model: str | None = None,
        *,
        method: str | None = None,
        timeout_s: float | None = None,
    ) -> NDArray[np.float32]:
        """Geodesic distances ``(S, T)`` float32 in the shape's units.

        Args:
            sources: ``(S,)`` integer indices or ``(S, 3)`` float xyz points.
            targets: ``(T,)`` indices, ``(T, 3)`` points, or ``"all"`` / ``None`` (``T = N``).
            method: ``learned`` (default), ``heat``, ``exact`` or ``graph``.
        """
        request = self.pb2.GeodesicRequest(shape_id=shape_id)
        if model is not None:
            request.model = model
        if method is not None:
            request.method = method
        what, array = _indices_or_points(sources, "sources")
        if what == "indices":
            request.source_indices.values.extend(array.tolist())
        else:
            request.source_points.xyz.extend(array.ravel().tolist())
        if targets is None or (isinstance(targets, str) and targets == "all"):
            request.all_targets = True
        else:
            what, array = _indices_or_points(targets, "targets")
            if what == "indices":
                request.target_indices.values.extend(array.tolist())
            else:
                request.target_points.xyz.extend(array.ravel().tolist())
        response = self._call("Geodesic", request, timeout_s)
        return np.array(response.distances, dtype=np.float32).reshape(response.rows, response.cols)

    def _query_point(self, value: int | ArrayLike, what: str) -> Any:
        array = np.asarray(value)
        if array.ndim == 0 and array.dtype.kind in "iu":
            return self.pb2.QueryPoint(index=int(array))
        if array.shape == (3,) and array.dtype.kind in "iuf":
            x, y, z = (float(c) for c in array)
            return self.pb2.QueryPoint(xyz=self.pb2.Point(x=x, y=y, z=z))
        raise ValueError(f"{what} must be one vertex index or one (3,) xyz point")

    def path(
        self,
        shape_id: str,
        source: int | ArrayLike,
        target: int | ArrayLike,
        model: str | None = None,
        *,
        method: str | None = None,
        timeout_s: float | None = None,
    ) -> dict[str, Any]:
        """A geodesic path; ``points`` is ``(L, 3)`` float64 from source to target, with
        ``method``, ``engine``, ``model``, ``length``, ``distance``, ``segments`` (a list of
        ``(start, method)``) and, for learned paths, ``predicted_distance``, ``n_steps`` and
        ``converged`` (``None`` for classical methods)."""
        request = self.pb2.PathRequest(
            shape_id=shape_id,
            source=self._query_point(source, "source"),
            target=self._query_point(target, "target"),
        )
        if model is not None:
            request.model = model
        if method is not None:
            request.method = method
        response = self._call("Path", request, timeout_s)

        def learned(name: str, kind: type) -> Any:
            return kind(getattr(response, name)) if response.HasField(name) else None

        return {
            "points": np.array(response.points, dtype=np.float64).reshape(-1, 3),
            "length": float(response.length),
            "method": response.method,
            "engine": response.engine,
            "model": response.model or None,
            "distance": float(response.distance),
            "segments": [(int(s.start), s.method) for s in response.segments],
            "predicted_distance": learned("predicted_distance", float),
            "n_steps": learned("n_steps", int),
            "converged": learned("converged", bool),
        }

    def correspond(
        self,
        source_shape_id: str,
        target_shape_id: str,
        batches: Iterable[ArrayLike | str],
        model: str | None = None,
        *,
        return_distance: bool = False,
        deadline_ms: int | None = None,
        timeout_s: float | None = None,
        refine: str | None = None,
    ) -> Iterator[dict[str, Any]]:
        """Stream batches of source queries through one ``Correspond`` call; yields one dict
        per batch, in order: ``batch_id`` (the batch's position), ``n_queries``, ``matches``
        (``(K,)`` int64 target indices), ``distances`` (``(K,)`` float32 in the target's input
        units) and ``distances_unit_area`` (the same in unit-area units; both ``None`` unless
        ``return_distance``), ``model``, ``refinement`` (``"none"``, ``"zoomout"``,
        ``"zoomout:<seed>"``), ``source_frame`` and ``target_frame`` (``{"frame", "check"}``:
        how each shape's frame was chosen; check ``"split"``: an uncertain frame).

        Args:
            batches: each ``(K,)`` integer indices, ``(K, 3)`` float xyz points in the source's
                units, or ``"all"``; consumed lazily, as gRPC's flow control allows.
            deadline_ms: deadline of each batch, from its arrival at the server.
            timeout_s: deadline of the whole stream (default: the client's).
            refine: ``"none"`` (the server's default), ``"zoomout"`` or ``"zoomout-hybrid"``:
                refine the matches of two meshes with ZoomOut (seconds per batch).

        Closing the returned iterator early (``break``, ``close()``) cancels the call: the
        server computes no further batch. A failed batch raises :class:`GrpcCallError` (with
        its ``batch_id``) after the answers of the batches before it.
        """
        pb2 = self.pb2

        def requests() -> Iterator[Any]:
            for position, queries in enumerate(batches):
                request = pb2.CorrespondRequest(batch_id=position, return_distance=return_distance)
                if position == 0:
                    request.source_shape_id = source_shape_id
                    request.target_shape_id = target_shape_id
                    if model is not None:
                        request.model = model
                    if refine is not None:
                        request.refine = refine
                if deadline_ms is not None:
                    request.deadline_ms = int(deadline_ms)
                if isinstance(queries, str) and queries == "all":
                    request.all_queries = True
                else:
                    what, array = _indices_or_points(queries, "queries")
                    if what == "indices":
                        request.query_indices.values.extend(array.tolist())
                    else:
                        request.query_points.xyz.extend(array.ravel().tolist())
                yield request

        call = self._stub.Correspond(
            requests(),
            timeout=self.timeout_s if timeout_s is None else timeout_s,
            metadata=self._metadata,
        )
        try:
            for response in call:
                yield {
                    "batch_id": int(response.batch_id),
                    "source_shape_id": response.source_shape_id,
                    "target_shape_id": response.target_shape_id,
                    "model": response.model,
                    "refinement": response.refinement,
                    "source_frame": _frame_info(response.source_frame),
                    "target_frame": _frame_info(response.target_frame),
                    "n_queries": int(response.n_queries),
                    "matches": np.array(response.matches, dtype=np.int64),
                    "distances": (
                        np.array(response.distances, dtype=np.float32) if return_distance else None
                    ),
                    "distances_unit_area": (
                        np.array(response.distances_unit_area, dtype=np.float32)
                        if return_distance
                        else None
                    ),
                }
        except grpc.RpcError as exc:
            raise GrpcCallError.of(exc) from None
        finally:
            call.cancel()  # no-op after the end of the stream; stops it when closed early

    # ------------------------------------------------------------------ health

    def health(self, service: str = "", *, timeout_s: float | None = None) -> str:
        """``grpc.health.v1`` status name of ``service`` ("" = the whole server), e.g.
        ``"SERVING"``."""
        from grpc_health.v1 import health_pb2, health_pb2_grpc

        stub = health_pb2_grpc.HealthStub(self._channel)
        try:
            response = stub.Check(
                health_pb2.HealthCheckRequest(service=service),
                timeout=self.timeout_s if timeout_s is None else timeout_s,
            )
        except grpc.RpcError as exc:
            raise GrpcCallError.of(exc) from None
        return health_pb2.HealthCheckResponse.ServingStatus.Name(response.status)
