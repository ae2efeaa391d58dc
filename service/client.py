"""A small synchronous Python client of the REST API (used by the tests and benchmarks).

::

    with LiteGEClient("http://127.0.0.1:8000") as client:
        info = client.register_file("dog.obj")
        d = client.geodesic(info["shape_id"], [0, 10], "all")     # (2, N) float32
        d = client.geodesic(info["shape_id"], [0], method="exact")  # exact MMP (meshes)
        path = client.path(info["shape_id"], 0, 4242)             # dict, points (L, 3)
        m = client.correspondences(source_id, target_id, "all")   # m["matches"]: (N,) int64
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import httpx
import msgpack
import numpy as np
from numpy.typing import ArrayLike, NDArray


class ProblemError(Exception):
    """An RFC 9457 problem answered by the service (``status``, ``code``, ``problem``)."""

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status = status
        self.problem = problem
        self.code = str(problem.get("code", ""))
        super().__init__(f"{status} {self.code}: {problem.get('detail', '')}")


def _query(value: ArrayLike | str) -> Any:
    if isinstance(value, str):
        return value
    return np.asarray(value).tolist()


class LiteGEClient:
    """REST client. ``binary=True`` fetches distance matrices as raw float32 bytes."""

    def __init__(
        self,
        base_url: str,
        *,
        api_key: str | None = None,
        timeout_s: float = 60.0,
        binary: bool = True,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        headers = {"X-API-Key": api_key} if api_key else {}
        self.binary = binary
        self._http = httpx.Client(
            base_url=base_url, headers=headers, timeout=timeout_s, transport=transport
        )

    def __enter__(self) -> LiteGEClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        self._http.close()

    def _check(self, response: httpx.Response) -> httpx.Response:
        if response.status_code >= 400:
            try:
                problem = response.json()
            except ValueError:
                problem = {"detail": response.text}
            raise ProblemError(response.status_code, problem)
        return response

    # ------------------------------------------------------------------ shapes

    def register_file(
        self,
        source: str | os.PathLike | bytes,
        *,
        file_format: str | None = None,
        kind: str | None = None,
        model: str | None = None,
    ) -> dict[str, Any]:
        """Upload a file (path or bytes; bytes need ``file_format``)."""
        if isinstance(source, bytes | bytearray):
            if file_format is None:
                raise ValueError("file_format is required when uploading bytes")
            name, data = f"upload.{file_format}", bytes(source)
        else:
            name, data = Path(source).name, Path(source).read_bytes()
        fields = {k: v for k, v in (("format", file_format), ("kind", kind), ("model", model)) if v}
        response = self._http.post("/shapes", files={"file": (name, data)}, data=fields)
        return self._check(response).json()

    def register_arrays(
        self,
        vertices: ArrayLike,
        faces: ArrayLike | None = None,
        *,
        kind: str | None = None,
        model: str | None = None,
    ) -> dict[str, Any]:
        body: dict[str, Any] = {"vertices": np.asarray(vertices, dtype=np.float64).tolist()}
        if faces is not None:
            body["faces"] = np.asarray(faces, dtype=np.int64).tolist()
        if kind:
            body["kind"] = kind
        if model:
            body["model"] = model
        return self._check(self._http.post("/shapes", json=body)).json()

    def get_shape(self, shape_id: str, model: str | None = None) -> dict[str, Any]:
        params = {"model": model} if model else None
        return self._check(self._http.get(f"/shapes/{shape_id}", params=params)).json()

    def delete_shape(self, shape_id: str) -> None:
        self._check(self._http.delete(f"/shapes/{shape_id}"))

    # ------------------------------------------------------------------ queries

    def geodesic(
        self,
        shape_id: str,
        sources: ArrayLike,
        targets: ArrayLike | str = "all",
        *,
        model: str | None = None,
        method: str | None = None,
    ) -> NDArray[np.float32]:
        """``(S, T)`` float32 distances in the shape's input units (``method``: ``learned``,
        the default, ``heat``, ``exact`` or ``graph``)."""
        body: dict[str, Any] = {
            "shape_id": shape_id,
            "sources": _query(sources),
            "targets": _query(targets),
        }
        if model:
            body["model"] = model
        if method:
            body["method"] = method
        accept = "application/octet-stream" if self.binary else "application/json"
        response = self._check(self._http.post("/geodesic", json=body, headers={"Accept": accept}))
        if response.headers.get("content-type", "").startswith("application/octet-stream"):
            rows, cols = (int(x) for x in response.headers["X-Array-Shape"].split(","))
            return np.frombuffer(response.content, dtype="<f4").reshape(rows, cols)
        if "msgpack" in response.headers.get("content-type", ""):
            payload = msgpack.unpackb(response.content)
            return np.frombuffer(payload["data"], dtype=payload["dtype"]).reshape(payload["shape"])
        data = response.json()
        table = [[np.inf if d is None else d for d in row] for row in data["distances"]]
        return np.asarray(table, dtype=np.float32).reshape(data["rows"], data["cols"])

    def path(
        self,
        shape_id: str,
        source: int | ArrayLike,
        target: int | ArrayLike,
        *,
        model: str | None = None,
        method: str | None = None,
    ) -> dict[str, Any]:
        """A path dict; ``points`` is an ``(L, 3)`` float64 array from source to target, with
        ``method``, ``engine``, ``length``, ``distance`` and ``segments``."""
        body: dict[str, Any] = {
            "shape_id": shape_id,
            "source": _query(source),
            "target": _query(target),
        }
        if model:
            body["model"] = model
        if method:
            body["method"] = method
        result = self._check(self._http.post("/paths", json=body)).json()
        result["points"] = np.asarray(result["points"], dtype=np.float64)
        return result

    def correspondences(
        self,
        source_shape_id: str,
        target_shape_id: str,
        queries: ArrayLike | str = "all",
        *,
        return_distance: bool = False,
        model: str | None = None,
        refine: str | None = None,
    ) -> dict[str, Any]:
        """Matches of source queries (indices, ``(K, 3)`` points or ``"all"``) on the target:
        the response dict with ``matches`` a ``(K,)`` int64 array, and ``distances`` (the
        target's input units) and ``distances_unit_area`` ``(K,)`` float32 arrays (``None``
        unless ``return_distance``), ``refinement``, and ``source_frame`` and ``target_frame``
        (``{"frame", "check"}``; check ``"split"``: an uncertain frame). ``refine``:
        ``"zoomout"`` or ``"zoomout-hybrid"`` refines the matches of two meshes (seconds per
        request)."""
        body: dict[str, Any] = {
            "source_shape_id": source_shape_id,
            "target_shape_id": target_shape_id,
            "queries": _query(queries),
            "return_distance": return_distance,
        }
        if model:
            body["model"] = model
        if refine is not None:
            body["refine"] = refine
        result = self._check(self._http.post("/correspondences", json=body)).json()
        result["matches"] = np.asarray(result["matches"], dtype=np.int64)
        for name in ("distances", "distances_unit_area"):
            if result.get(name) is not None:
                result[name] = np.asarray(result[name], dtype=np.float32)
        return result

    # ------------------------------------------------------------------ probes

    def ready(self) -> dict[str, Any]:
        return self._check(self._http.get("/readyz")).json()

    def metrics(self) -> str:
        return self._check(self._http.get("/metrics")).text
