"""Interactive sessions: a live MJPEG stream, camera updates, stats.

Scene updates reach a session through the scene's commits (``POST /v1/scenes/{id}/commits``):
the session renders the scene's current version every frame.
"""

import asyncio
import math

import pydantic
from anyio import to_thread
from fastapi import APIRouter, Request, Response
from fastapi.responses import StreamingResponse

from api.deps import Ctx, ThreadedBodyRoute
from api.errors import ApiError
from api.live_session import LiveSession, set_camera_now
from api.models import (
    CameraPose,
    SessionCreate,
    SessionPublic,
    SessionsPublic,
    SessionUpdate,
    errors,
)
from api.scenes import new_id
from tracer.errors import format_validation_error
from tracer.post.denoise import DenoiserUnavailable, require_denoiser
from tracer.scene import format as fmt

router = APIRouter(prefix="/sessions", tags=["sessions"], route_class=ThreadedBodyRoute)

BOUNDARY = "frame"
FIRST_FRAME_WAIT = 10.0


def _public(live: LiveSession) -> SessionPublic:
    return SessionPublic(
        id=live.id,
        scene_id=live.scene_id,
        width=live.width,
        height=live.height,
        denoise=live.denoise,
        camera=None if live.camera is None else live.camera.model_dump(),
        created=live.created,
        stream_url=f"/v1/sessions/{live.id}/stream",
        frame_url=f"/v1/sessions/{live.id}/frame.jpg",
        stats=live.stats(),
    )


def _live(ctx: Ctx, session_id: str) -> LiveSession:
    live = ctx.service.sessions.get(session_id)
    if live is None or live.closed:
        raise ApiError(404, f"no session {session_id!r} (closed or expired?)", "not_found")
    return live


async def _check_denoiser(quality: str) -> None:
    """A 503 now when the session is to denoise and this server cannot (the check imports
    pyoidn, off the event loop)."""
    if quality != "off":
        try:
            await to_thread.run_sync(require_denoiser)
        except DenoiserUnavailable as exc:
            raise ApiError(503, f"this server cannot denoise: {exc}", "unavailable") from None


def _example_size(pixels: int) -> str:
    """The largest 16:9 size of at most ``pixels`` pixels, as ``WxH``."""
    height = math.isqrt(pixels * 9 // 16)
    return f"{height * 16 // 9}x{height}"


def _camera(base: fmt.Camera, pose: CameraPose | None, width: int, height: int) -> fmt.Camera:
    changes = {} if pose is None else pose.model_dump(exclude_none=True)
    try:
        return fmt.override(base, width=width, height=height, **changes)
    except pydantic.ValidationError as exc:
        raise ApiError(422, "camera: " + format_validation_error(exc)) from None


@router.post(
    "", status_code=201, response_model=SessionPublic, responses=errors(400, 429, 503, 504)
)
async def open_session(body: SessionCreate, ctx: Ctx, response: Response) -> SessionPublic:
    """Open an interactive session on a scene."""
    s = ctx.settings
    entry = await to_thread.run_sync(ctx.scenes.get, body.scene_id)
    width = body.width or s.session_default_width
    height = body.height or s.session_default_height
    if width > s.max_width or height > s.max_height:
        raise ApiError(
            422,
            f"resolution {width}x{height} is over the limit of {s.max_width}x{s.max_height}",
            "limit",
        )
    if width * height > s.max_session_pixels:
        raise ApiError(
            422,
            f"a session of {width}x{height} has {width * height} pixels, more than the limit of "
            f"{s.max_session_pixels} ({_example_size(s.max_session_pixels)} at 16:9)",
            "limit",
        )
    if not ctx.service.ready:
        raise ApiError(503, ctx.service.error or "the cluster is starting", "unavailable")
    await _check_denoiser(body.denoise)
    camera = _camera(entry.graph.state.camera, body.camera, width, height)
    try:
        ctx.service.session_factory()
    except (ImportError, AttributeError):
        raise ApiError(
            503,
            f"interactive sessions are not available ({s.session_class} cannot be imported)",
            "unavailable",
        ) from None
    live = LiveSession(new_id("v"), entry, width, height, asyncio.get_running_loop())
    live.camera = camera
    live.denoise = body.denoise
    try:
        await ctx.service.call_async(
            ctx.service.open_session(live, camera, body.target_fps, body.min_blend),
            timeout=s.request_timeout,
        )
    except TimeoutError:
        raise ApiError(504, "the cluster did not open the session in time", "timeout") from None
    response.headers["Location"] = f"/v1/sessions/{live.id}"
    return _public(live)


@router.get("", response_model=SessionsPublic, responses=errors())
async def list_sessions(ctx: Ctx) -> SessionsPublic:
    """List open sessions."""
    lives = ctx.service.live_sessions()
    return SessionsPublic(data=[_public(live) for live in lives], count=len(lives))


@router.get("/{session_id}", response_model=SessionPublic, responses=errors())
async def session_status(session_id: str, ctx: Ctx) -> SessionPublic:
    """A session's stats: fps, spp, blend factor, latency of camera updates."""
    live = _live(ctx, session_id)
    live.touch()
    return _public(live)


@router.delete("/{session_id}", status_code=204, responses=errors())
async def close_session(session_id: str, ctx: Ctx) -> Response:
    """Close a session."""
    _live(ctx, session_id)
    ctx.service.close_session(session_id)
    return Response(status_code=204)


@router.patch("/{session_id}", response_model=SessionPublic, responses=errors(400, 404, 503))
async def update_session(session_id: str, body: SessionUpdate, ctx: Ctx) -> SessionPublic:
    """Change how the session shows its frames: ``denoise`` (the viewer's toggle)."""
    live = _live(ctx, session_id)
    await _check_denoiser(body.denoise)
    if not hasattr(live.session, "set_denoise"):
        raise ApiError(503, f"{ctx.settings.session_class} sessions cannot denoise", "unavailable")
    live.session.set_denoise(body.denoise)
    live.denoise = body.denoise
    live.denoise_error = None
    live.touch()
    return _public(live)


@router.put("/{session_id}/camera", response_model=SessionPublic, responses=errors(400))
async def update_camera(session_id: str, pose: CameraPose, ctx: Ctx) -> SessionPublic:
    """Move the session's camera (the next frame shows it; convergence starts over)."""
    live = _live(ctx, session_id)
    camera = _camera(live.camera, pose, live.width, live.height)
    live.camera = camera
    set_camera_now(live, camera)
    return _public(live)


@router.get(
    "/{session_id}/frame.jpg",
    response_class=Response,
    responses={**errors(504), 200: {"content": {"image/jpeg": {}}}},
)
async def latest_frame(session_id: str, ctx: Ctx, after: int = 0) -> Response:
    """The latest frame as a JPEG (waits for one newer than ``after``, if given)."""
    live = _live(ctx, session_id)
    live.touch()
    loop = asyncio.get_running_loop()
    deadline = loop.time() + FIRST_FRAME_WAIT
    while (live.jpeg is None or live.seq <= after) and not live.closed:
        remaining = deadline - loop.time()
        if remaining <= 0:
            raise ApiError(504, "no new frame yet", "timeout")
        try:
            await asyncio.wait_for(live.event.wait(), remaining)
        except TimeoutError:
            pass
        live.touch()
    if live.jpeg is None:
        raise ApiError(404, f"session {session_id} closed before its first frame", "not_found")
    headers = {
        "Cache-Control": "no-store",
        "X-Frame-Seq": str(live.seq),
        "X-Frame-Version": str(live.meta.get("version")),
    }
    return Response(live.jpeg, media_type="image/jpeg", headers=headers)


@router.get(
    "/{session_id}/stream",
    response_class=StreamingResponse,
    responses={
        **errors(),
        200: {"content": {f"multipart/x-mixed-replace; boundary={BOUNDARY}": {}}},
    },
)
async def stream(session_id: str, ctx: Ctx, request: Request) -> StreamingResponse:
    """The live stream: ``multipart/x-mixed-replace`` JPEG frames for an ``<img>``."""
    live = _live(ctx, session_id)

    async def frames():
        live.clients += 1
        live.touch()
        last = 0
        try:
            while not live.closed:
                if live.jpeg is not None and live.seq > last:
                    last = live.seq
                    jpeg = live.jpeg
                    head = (
                        f"--{BOUNDARY}\r\nContent-Type: image/jpeg\r\n"
                        f"Content-Length: {len(jpeg)}\r\nX-Frame-Seq: {last}\r\n"
                        f"X-Frame-Version: {live.meta.get('version')}\r\n\r\n"
                    ).encode()
                    yield head + jpeg + b"\r\n"
                    continue
                try:
                    await asyncio.wait_for(live.event.wait(), 5.0)
                except TimeoutError:
                    if await request.is_disconnected():
                        return
        finally:
            live.clients -= 1
            live.touch()

    return StreamingResponse(
        frames(),
        media_type=f"multipart/x-mixed-replace; boundary={BOUNDARY}",
        headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"},
    )
