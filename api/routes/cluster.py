"""The cluster: tracers, their speed and idle time, the balancer."""

from fastapi import APIRouter

from api.deps import Ctx, ThreadedBodyRoute
from api.errors import ApiError
from api.models import BalancerUpdate, ClusterPublic, TracerPublic, errors

router = APIRouter(prefix="/cluster", tags=["cluster"], route_class=ThreadedBodyRoute)


def cluster_public(ctx: Ctx) -> ClusterPublic:
    from cluster.balancing import BALANCERS

    service = ctx.service
    info = service.cluster_info
    last = info.get("last_frame") or {}
    per = last.get("tracers", {})
    tracers = []
    for t in info.get("tracers", []):
        mine = per.get(t["id"], {})
        tracers.append(
            TracerPublic(
                id=t["id"],
                state=t["state"],
                node=t.get("node"),
                pid=t.get("pid"),
                cpus=t["cpus"],
                threads=t["threads"],
                failures=t.get("failures", 0),
                lines_last_frame=mine.get("lines"),
                lines_per_second=mine.get("lines_per_second"),
                idle_percent=mine.get("idle_percent"),
            )
        )
    return ClusterPublic(
        ready=service.ready,
        error=service.error,
        balancer=info.get("balancer"),
        balancers=sorted(BALANCERS),
        tracers=tracers,
        last_frame=info.get("last_frame"),
        queue_length=service.jobs.queue_length(),
        sessions=len(service.live_sessions()),
        frames_rendered=service.frames_rendered,
    )


@router.get("", response_model=ClusterPublic, responses=errors())
async def cluster_status(ctx: Ctx) -> ClusterPublic:
    """Tracers (id, node, speed, lines in the last frame, idle %) and the balancer."""
    return cluster_public(ctx)


@router.put("/balancer", response_model=ClusterPublic, responses=errors(400, 503, 504))
async def set_balancer(body: BalancerUpdate, ctx: Ctx) -> ClusterPublic:
    """Choose the balancer (from the next frame on)."""
    from cluster.balancing import BALANCERS

    if body.name not in BALANCERS:
        raise ApiError(
            422, f"unknown balancer {body.name!r} (known: {', '.join(sorted(BALANCERS))})"
        )
    if not ctx.service.ready:
        raise ApiError(503, ctx.service.error or "the cluster is starting", "unavailable")

    def switch(coordinator) -> None:
        coordinator.use_balancer(body.name)
        ctx.service.cluster_info["balancer"] = body.name

    try:
        await ctx.service.call_async(switch, timeout=ctx.settings.request_timeout)
    except TimeoutError:
        raise ApiError(504, "the render thread is busy; try again", "timeout") from None
    return cluster_public(ctx)
