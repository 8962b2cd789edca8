"""Jobs: submit stills and animations, status and progress, cancel, results, events."""

import asyncio
from typing import Annotated, Literal

import pydantic
from anyio import to_thread
from fastapi import APIRouter, Query, Request, Response
from fastapi import Path as PathParam
from fastapi.responses import FileResponse, StreamingResponse

from api.deps import Ctx, ThreadedBodyRoute
from api.errors import ApiError
from api.events import TERMINAL_EVENTS, sse
from api.job_run import job_dir, job_frames, job_state
from api.models import FramePublic, JobCreate, JobPublic, JobsPublic, Progress, errors
from api.scenes import new_id
from api.store import TERMINAL, QueueFull
from cluster.progressive import PARTS
from tracer.errors import SceneError, format_validation_error
from tracer.integrators.names import OUTPUT_LAYERS
from tracer.io.images import read_image, write_image
from tracer.io.layers import layer_as_rgb, read_layers, write_layers
from tracer.post.denoise import DenoiserUnavailable, require_denoiser
from tracer.scene.model import SceneState

router = APIRouter(prefix="/jobs", tags=["jobs"], route_class=ThreadedBodyRoute)

FORMATS = {
    "png": "image/png",
    "exr": "image/x-exr",
    "npy": "application/octet-stream",
    "npz": "application/octet-stream",
}
KEEPALIVE_SECONDS = 15.0


def _frame_urls(job_id: str, frame: int) -> dict[str, str]:
    return {f: f"/v1/jobs/{job_id}/frames/{frame}?format={f}" for f in FORMATS}


def job_public(ctx: Ctx, record: dict, with_frames: bool = False) -> JobPublic:
    """A job as the API shows it: its record, its live progress while it runs (else what its
    finished frames add up to), its place in the queue while queued."""
    live = ctx.service.jobs.progress(record["id"])
    wanted = with_frames or (live is None and record["frames_done"] > 0)
    finished = ctx.store.frames(record["id"]) if wanted else []
    if live is not None:
        progress = Progress(**live)
    else:
        done = record["status"] == "done"
        progress = Progress(
            frames_done=record["frames_done"],
            frames_total=record["frames_total"],
            lines_total=record["height"],
            lines_done=record["height"] if done else 0,
            samples_done=sum(f["spp"] for f in finished) * record["width"] * record["height"],
            eta_seconds=0.0 if done else None,
        )
    frames = None
    if with_frames:
        frames = [
            FramePublic(
                frame=f["frame"],
                position=f["position"],
                spp=f["spp"],
                seconds=f["seconds"],
                error_estimate=f["error_estimate"],
                urls=_frame_urls(record["id"], f["frame"]),
            )
            for f in finished
        ]
    fields = {k: record[k] for k in JobPublic.model_fields if k in record}
    if record["status"] == "queued":
        fields["queue_position"] = ctx.service.jobs.queue_position(record["id"])
    return JobPublic(**fields, progress=progress, frames=frames)


def _job(ctx: Ctx, job_id: str) -> dict:
    record = ctx.store.job(job_id) if len(job_id) <= 64 else None
    if record is None:
        raise ApiError(404, f"no job {job_id!r}", "not_found")
    return record


def _requested_frames(body: JobCreate, state: SceneState) -> int:
    """How many frames ``body`` asks for, counted without building any of them."""
    if body.kind == "still":
        return 1
    if body.camera_path is not None:
        return len(body.camera_path)
    if body.frames is not None:
        return len(body.frames)
    return state.animation.frames if state.animation is not None else 1


def _plan(ctx: Ctx, body: JobCreate, state: SceneState) -> tuple[dict, SceneState, list]:
    """The job's request, its scene with the overrides and its frames, or the ApiError of
    the first limit ``body`` is over. The cheap checks (counts, numbers) come first, so a
    request over a limit is refused before any camera is built; run in a worker thread."""
    s = ctx.settings
    if body.spp is not None and body.spp > s.max_spp:
        raise ApiError(422, f"spp: at most {s.max_spp}", "limit")
    if body.max_spp is not None and body.max_spp > s.max_spp:
        raise ApiError(422, f"max_spp: at most {s.max_spp}", "limit")
    progressive = body.target_error is not None or body.time_budget is not None
    if progressive and s.max_spp < PARTS:
        raise ApiError(
            422,
            f"this server caps spp at {s.max_spp}: a job by target error or time budget needs "
            f"at least one wave of {PARTS}",
            "limit",
        )
    if body.time_budget is not None and body.time_budget > s.max_time_budget:
        raise ApiError(422, f"time_budget: at most {s.max_time_budget:g} s", "limit")
    if body.kind == "animation" and body.camera_path is None:
        animation = state.animation
        if animation is None:
            raise ApiError(
                422, "the scene has no animation: give a camera_path, or kind still", "no_animation"
            )
        if body.frames is not None and max(body.frames) >= animation.frames:
            raise ApiError(
                422, f"frames: the scene's animation has frames 0-{animation.frames - 1}", "limit"
            )
    count = _requested_frames(body, state)
    if count > s.max_frames:
        raise ApiError(422, f"{count} frames: at most {s.max_frames}", "limit")
    request = body.model_dump(exclude_none=True)
    try:
        posed = job_state(state, request)
    except SceneError as exc:
        raise ApiError(422, str(exc)) from None
    if posed.render.denoise != "off":
        try:
            require_denoiser()
        except DenoiserUnavailable as exc:
            raise ApiError(503, f"this server cannot denoise: {exc}", "unavailable") from None
    if posed.camera.width > s.max_width or posed.camera.height > s.max_height:
        raise ApiError(
            422,
            f"resolution {posed.camera.width}x{posed.camera.height} is over the limit of "
            f"{s.max_width}x{s.max_height}",
            "limit",
        )
    if body.spp is None and body.target_error is None and body.time_budget is None:
        if posed.render.spp > s.max_spp:
            raise ApiError(
                422,
                f"the scene's spp ({posed.render.spp}) is over the limit of {s.max_spp}; give spp",
                "limit",
            )
    try:
        frames = job_frames(posed, request)
    except pydantic.ValidationError as exc:
        raise ApiError(422, "camera: " + format_validation_error(exc)) from None
    return request, posed, frames


@router.post("", status_code=202, response_model=JobPublic, responses=errors(400, 429, 503))
async def submit_job(body: JobCreate, ctx: Ctx, response: Response) -> JobPublic:
    """Submit a still or an animation render."""
    entry = await to_thread.run_sync(ctx.scenes.get, body.scene_id)
    state = entry.graph.state
    request, posed, frames = await to_thread.run_sync(_plan, ctx, body, state)
    job_id = new_id("j")
    await to_thread.run_sync(ctx.service.jobs.save_state, job_id, state)
    try:
        record = ctx.store.add_job(
            job_id,
            body.scene_id,
            request,
            len(frames),
            state.version,
            posed.camera.width,
            posed.camera.height,
            max_active=ctx.settings.max_queue,
        )
    except QueueFull as full:
        await to_thread.run_sync(ctx.service.jobs.drop_state, job_id)
        raise ApiError(
            429,
            f"the job queue is full ({full.active} jobs queued or running); try again later",
            "queue_full",
            {"Retry-After": "10"},
        ) from None
    ctx.metrics.jobs_submitted.inc()
    ctx.service.jobs.submit(job_id)
    response.headers["Location"] = f"/v1/jobs/{job_id}"
    return job_public(ctx, record)


@router.get("", response_model=JobsPublic, responses=errors())
async def list_jobs(
    ctx: Ctx,
    status: Literal["queued", "running", "done", "failed", "cancelled"] | None = None,
    limit: Annotated[int, Query(ge=1, le=500)] = 100,
    offset: Annotated[int, Query(ge=0, le=1_000_000)] = 0,
) -> JobsPublic:
    """List jobs, newest first."""
    records = ctx.store.jobs(status, limit, offset)
    return JobsPublic(data=[job_public(ctx, r) for r in records], count=len(records))


@router.get("/{job_id}", response_model=JobPublic, responses=errors())
async def job_status(job_id: str, ctx: Ctx) -> JobPublic:
    """A job's status, progress (frames, lines, samples, ETA) and finished frames."""
    return job_public(ctx, _job(ctx, job_id), with_frames=True)


@router.post("/{job_id}/cancel", response_model=JobPublic, responses=errors(409))
async def cancel_job(job_id: str, ctx: Ctx) -> JobPublic:
    """Cancel a queued or running job (frames already finished stay downloadable)."""
    record = _job(ctx, job_id)
    if record["status"] in TERMINAL:
        raise ApiError(409, f"job {job_id} is already {record['status']}", "conflict")
    if ctx.store.finish_job(job_id, "cancelled", "cancelled on request"):
        ctx.service.jobs.cancel(job_id)
        ctx.metrics.jobs.labels("cancelled").inc()
        ctx.events.publish(job_id, "cancelled", {"job": job_id, "status": "cancelled"})
    return job_public(ctx, _job(ctx, job_id), with_frames=True)


async def _frame_file(
    ctx: Ctx, job_id: str, frame: int | None, fmt_name: str, layer: str | None = None
) -> FileResponse:
    record = _job(ctx, job_id)
    frames = ctx.store.frames(job_id)
    if frame is None:
        if not frames:
            raise ApiError(
                404, f"job {job_id} ({record['status']}) has no finished frame yet", "not_ready"
            )
        row = frames[0]
    else:
        row = next((f for f in frames if f["frame"] == frame), None)
        if row is None:
            raise ApiError(
                404, f"job {job_id} has no finished frame {frame} ({record['status']})", "not_ready"
            )
    directory = job_dir(ctx.settings, job_id)
    source = directory / row["path"]
    if not source.is_file():
        raise ApiError(410, f"the result file of frame {row['frame']} is gone", "gone")
    bundle = source.suffix == ".npz"  # every layer; a frame of the beauty alone is a .npy
    if not bundle and layer not in (None, "beauty"):
        raise ApiError(
            404,
            f"frame {row['frame']} of job {job_id} has no {layer} layer (it has beauty; aovs "
            "and denoise in the job request add layers)",
            "not_found",
        )
    every_layer = fmt_name == "npz" or (fmt_name == "exr" and layer is None)
    if bundle and fmt_name == "npz":
        target = source
    elif bundle:
        shown = "layers" if every_layer else layer or "default"
        target = source.with_suffix(f".{shown}.{fmt_name}")
    else:
        target = source.with_suffix("." + fmt_name)
    if not target.is_file():

        def convert() -> None:
            metadata = {
                "renderer": "tilerender",
                "job": job_id,
                "frame": row["frame"],
                "spp": row["spp"],
            }
            layers, made = read_layers(source) if bundle else ({"beauty": read_image(source)}, {})
            metadata.update(made)
            if (every_layer and len(layers) > 1) or fmt_name == "npz":
                write_layers(target, layers, metadata)
                return
            name = layer or ("denoised" if "denoised" in layers else "beauty")
            if name not in layers:
                raise ApiError(
                    404,
                    f"frame {row['frame']} of job {job_id} has no {name} layer (it has "
                    f"{', '.join(layers)}; aovs and denoise in the job request add layers)",
                    "not_found",
                )
            write_image(target, layer_as_rgb(layers, name, view=fmt_name == "png"), metadata)

        await to_thread.run_sync(convert)
    filename = f"{job_id}_{row['frame']:04d}.{fmt_name}"
    return FileResponse(target, media_type=FORMATS[fmt_name], filename=filename)


Format = Annotated[
    Literal["png", "exr", "npy", "npz"],
    Query(description="image format (npz: every layer of the frame as a NumPy bundle)"),
]
Layer = Annotated[
    Literal[OUTPUT_LAYERS] | None,
    Query(
        description="the layer to show (png, npy, exr; default: denoised when the job denoises, "
        "else beauty); an exr without it holds every layer of the frame"
    ),
]


@router.get(
    "/{job_id}/frames/{frame}",
    response_class=FileResponse,
    responses={**errors(410), 200: {"content": {t: {} for t in FORMATS.values()}}},
)
async def job_frame(
    job_id: str,
    frame: Annotated[int, PathParam(ge=0, le=10**9)],
    ctx: Ctx,
    format: Format = "png",
    layer: Layer = None,
):
    """One finished frame as PNG (sRGB 8 bit), EXR or NPY (float32 linear), or all its layers
    as a multilayer EXR or an NPZ bundle."""
    return await _frame_file(ctx, job_id, frame, format, layer)


@router.get(
    "/{job_id}/result",
    response_class=FileResponse,
    responses={**errors(410), 200: {"content": {t: {} for t in FORMATS.values()}}},
)
async def job_result(
    job_id: str,
    ctx: Ctx,
    format: Format = "png",
    frame: Annotated[int | None, Query(ge=0, le=10**9)] = None,
    layer: Layer = None,
):
    """The result (a still's image, or one frame of an animation: the first by default)."""
    return await _frame_file(ctx, job_id, frame, format, layer)


@router.get(
    "/{job_id}/events",
    response_class=StreamingResponse,
    responses={**errors(), 200: {"content": {"text/event-stream": {}}}},
)
async def job_events(job_id: str, ctx: Ctx, request: Request):
    """Server-Sent Events: status, progress, frame (a frame is done), done, error, cancelled."""
    _job(ctx, job_id)
    queue = ctx.events.subscribe(job_id)
    record = _job(ctx, job_id)

    async def stream():
        try:
            yield sse("status", job_public(ctx, record).model_dump(mode="json"))
            if record["status"] in TERMINAL:
                kind = {"done": "done", "failed": "error", "cancelled": "cancelled"}[
                    record["status"]
                ]
                yield sse(
                    kind, {"job": job_id, "status": record["status"], "message": record["error"]}
                )
                return
            while True:
                try:
                    event = await asyncio.wait_for(queue.get(), KEEPALIVE_SECONDS)
                except TimeoutError:
                    yield b": keep-alive\n\n"
                    continue
                yield sse(event["event"], event["data"], event["id"])
                if event["event"] in TERMINAL_EVENTS:
                    return
        finally:
            ctx.events.unsubscribe(job_id, queue)

    return StreamingResponse(
        stream(),
        media_type="text/event-stream",
        headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"},
    )
