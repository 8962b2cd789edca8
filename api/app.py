"""The FastAPI application: ``create_app(settings)``.

The lifespan opens the database, the scene repository and the render service (whose thread
connects to Ray and starts the tracers in the background: ``/readyz`` says when they are up),
and closes them in reverse order. Nothing connects at import.
"""

import asyncio
import logging
from contextlib import asynccontextmanager
from pathlib import Path

from fastapi import APIRouter, Depends, FastAPI
from fastapi.middleware.cors import CORSMiddleware
from fastapi.responses import FileResponse
from fastapi.staticfiles import StaticFiles

from api import errors
from api.deps import Context, require_token
from api.events import EventHub
from api.metrics import Metrics
from api.middleware import BodyLimit, RequestMetrics, Timeout
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

    v1 = APIRouter(prefix="/v1", dependencies=[Depends(require_token)])
    for module in (scenes, jobs, sessions, cluster):
        v1.include_router(module.router)
    app.include_router(v1)
    app.include_router(health.router)

    @app.get("/", include_in_schema=False)
    async def viewer() -> FileResponse:
        return FileResponse(STATIC / "index.html", media_type="text/html")

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    # Outermost last: metrics see every answer, the body limit runs before any parsing.
    app.add_middleware(Timeout, seconds=settings.request_timeout)
    app.add_middleware(BodyLimit, settings=settings)
    if settings.cors_origins:
        app.add_middleware(
            CORSMiddleware,
            allow_origins=settings.cors_origins,
            allow_methods=["*"],
            allow_headers=["Authorization", "Content-Type"],
        )
    app.add_middleware(RequestMetrics, metrics=metrics)
    return app
