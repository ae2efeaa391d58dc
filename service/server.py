"""The HTTP service as it stands in this milestone.

What exists: ``/healthz`` and ``/version`` (library version and the capabilities the core
provides). The geodesic, path and correspondence endpoints arrive with the service issue; until
then the server says so at start-up and in ``/version`` rather than pretending.
"""

from __future__ import annotations

import fastapi

from litege_core import __version__

ROUTES_SERVED = ("/healthz", "/version", "/docs")
NOT_YET_SERVED = ("/shapes", "/geodesic", "/paths", "/correspondences")


def create_app() -> fastapi.FastAPI:
    app = fastapi.FastAPI(title="LiteGE", version=__version__)

    @app.get("/healthz")
    def healthz() -> dict[str, str]:
        return {"status": "ok"}

    @app.get("/version")
    def version() -> dict[str, object]:
        return {
            "version": __version__,
            "serves": list(ROUTES_SERVED),
            "not_yet_served": list(NOT_YET_SERVED),
        }

    return app


def run(host: str = "127.0.0.1", port: int = 8000) -> None:
    import uvicorn

    print(
        f"LiteGE {__version__} serving {', '.join(ROUTES_SERVED)} on http://{host}:{port}\n"
        f"Not yet served (service milestone pending): {', '.join(NOT_YET_SERVED)}",
        flush=True,
    )
    uvicorn.run(create_app(), host=host, port=port, log_level="info")
