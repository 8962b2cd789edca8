"""Liveness, readiness and metrics (outside /v1, never behind the token)."""

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response

from api.deps import Ctx
from api.metrics import CONTENT_TYPE

router = APIRouter(tags=["health"])


@router.get("/healthz")
async def healthz() -> dict:
    """The process answers."""
    return {"status": "ok"}


@router.get("/readyz", responses={503: {"description": "not ready"}})
async def readyz(ctx: Ctx):
    """200 when the cluster is up and the service takes work, else 503 with the reason."""
    service = ctx.service
    if service.ready:
        ready = [t for t in service.cluster_info.get("tracers", []) if t["state"] == "ready"]
        return {"status": "ready", "tracers": len(ready)}
    reason = service.error or "the cluster is starting"
    return JSONResponse(
        {"status": "starting" if service.error is None else "failed", "message": reason}, 503
    )


@router.get("/metrics", response_class=Response)
async def metrics(ctx: Ctx) -> Response:
    """Prometheus metrics."""
    m = ctx.metrics
    service = ctx.service
    m.queue.set(service.jobs.queue_length())
    m.sessions.set(len(service.live_sessions()))
    m.ready.set(1 if service.ready else 0)
    m.tracers.set(sum(1 for t in service.cluster_info.get("tracers", []) if t["state"] == "ready"))
    return Response(m.render(), media_type=CONTENT_TYPE)
