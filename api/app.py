"""The FastAPI application: ``create_app(settings)``.

The lifespan opens the database, the scene repository and the render service (whose thread
connects to Ray and starts the tracers in the background: ``/readyz`` says when they are up),
and closes them in reverse order. Nothing connects at import.
"""

import asyncio
import copy
import logging
from collections.abc import Callable
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from api import errors
from api.deps import Context
from api.events import EventHub
from api.metrics import Metrics
from api.middleware import BearerAuth, BodyLimit, JSONCORSMiddleware, RequestMetrics, Timeout
from api.routes import cluster, health, jobs, scenes, sessions
from api.scenes import SceneRepository
from api.service import RenderService
from api.settings import Settings
from api.store import Store

STATIC = Path(__file__).parent / "static"
DESCRIPTION = """\
tilerender's cloud rendering service: upload scenes, change them with commits, render stills
and animations as jobs, and watch interactive sessions live. See docs/api.md.

Errors are JSON: `{"error": {"status": 422, "code": "invalid", "message": "..."}}`.
With a token configured, every `/v1` request needs `Authorization: Bearer <token>`.
"""

log = logging.getLogger("tilerender.api")

SECURITY_SCHEMES = {
    "bearer": {"type": "http", "scheme": "bearer", "description": "the service's token"},
    "access_token": {
        "type": "apiKey",
        "in": "query",
        "name": "access_token",
        "description": "the token as a query parameter (for an <img> or EventSource)",
    },
}


def openapi_with_security(app: FastAPI, settings: Settings) -> Callable[[], dict]:
    """``app.openapi`` that declares the bearer token on the /v1 operations only while the
    service has a token (the settings are read at each call; the base document is cached)."""
    base = app.openapi

    def openapi() -> dict:
        doc = base()
        if not settings.token:
            return doc
        doc = copy.deepcopy(doc)
        doc.setdefault("components", {})["securitySchemes"] = SECURITY_SCHEMES
        for path, operations in doc["paths"].items():
            if path.startswith("/v1/") or path == "/v1":
                for operation in operations.values():
                    operation["security"] = [{name: []} for name in SECURITY_SCHEMES]
        return doc

    return openapi


def create_app(settings: Settings | None = None, session_factory=None) -> FastAPI:
    """The service for ``settings`` (default: from ``TILERENDER_*`` environment variables).
    ``session_factory``: returns the interactive-session class (default
    ``cluster.session.InteractiveSession``); tests swap it."""
    settings = settings or Settings.from_env()
    metrics = Metrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        settings.data_dir.mkdir(parents=True, exist_ok=True)
        store = Store(settings.database)
        repository = SceneRepository(settings, store)
        events = EventHub()
        events.bind(asyncio.get_running_loop())
        service = RenderService(settings, store, repository, events, metrics, session_factory)
        service.start(asyncio.get_running_loop())
        app.state.ctx = Context(settings, store, repository, service, events, metrics)
        try:
            yield
        finally:
            await asyncio.to_thread(service.stop)
            store.close()

    app = FastAPI(
        title="tilerender",
        version="1",
        description=DESCRIPTION,
        lifespan=lifespan,
        docs_url="/docs",
        openapi_url="/openapi.json",
    )
    app.state.settings = settings
    errors.install(app)

    app.openapi = openapi_with_security(app, settings)

    v1 = APIRouter(prefix="/v1")
    for module in (scenes, jobs, sessions, cluster):
        v1.include_router(module.router)
    app.include_router(v1)
    app.include_router(health.router)

    @app.get("/", include_in_schema=False)
    async def viewer() -> FileResponse:
        return FileResponse(STATIC / "index.html", media_type="text/html")

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    # Outermost last: metrics see every answer, CORS answers preflights, the token is checked
    # before anything reads the body, the body limit runs before any parsing.
    app.add_middleware(Timeout, settings=settings)
    app.add_middleware(BodyLimit, settings=settings)
    app.add_middleware(BearerAuth, settings=settings)
    if settings.cors_origins:
        app.add_middleware(
            JSONCORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["*"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(RequestMetrics, metrics=metrics)
    return app
