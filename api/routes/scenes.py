"""Scenes: upload, list, inspect, delete, commit operations, ray queries."""

import logging
import math
import shutil
from pathlib import Path, PurePosixPath

import numpy as np
from anyio import to_thread
from fastapi import APIRouter, Request, Response
from ray.exceptions import RayError
from starlette.datastructures import UploadFile

from api.deps import Ctx, ThreadedBodyRoute
from api.errors import ApiError
from api.models import (
    CommitPublic,
    CommitRequest,
    QueryHit,
    QueryRequest,
    SceneDetail,
    ScenePublic,
    ScenesPublic,
    errors,
)
from api.scenes import SceneEntry, extract_bundle, find_entry, safe_relative
from tracer.errors import SceneError
from tracer.maths import portable
from tracer.scene import format as fmt
from tracer.scene.loader import MESH_SUFFIXES

log = logging.getLogger("tilerender.api")
router = APIRouter(prefix="/scenes", tags=["scenes"], route_class=ThreadedBodyRoute)

UPLOAD_SCHEMA = {
    "requestBody": {
        "required": True,
        "content": {
            "multipart/form-data": {
                "schema": {
                    "type": "object",
                    "properties": {
                        "scene": {
                            "type": "string",
                            "format": "binary",
                            "description": "a tilerender/1 JSON scene",
                        },
                        "files": {
                            "type": "array",
                            "items": {"type": "string", "format": "binary"},
                            "description": "files the scene references, named by their "
                            "relative paths",
                        },
                        "bundle": {
                            "type": "string",
                            "format": "binary",
                            "description": "a zip of scene.json and its files",
                        },
                        "mesh": {
                            "type": "string",
                            "format": "binary",
                            "description": "one .gltf/.glb/.obj/.ply/.stl file",
                        },
                        "name": {"type": "string", "maxLength": 200},
                    },
                }
            },
            "application/json": {"schema": {"type": "object", "description": "a JSON scene"}},
            "application/zip": {"schema": {"type": "string", "format": "binary"}},
        },
    }
}


def _public(record: dict) -> ScenePublic:
    return ScenePublic(**{k: record[k] for k in ScenePublic.model_fields})


async def _save_upload(upload: UploadFile, target: Path) -> None:
    def copy() -> None:
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
        except OSError:  # an uploaded file is where this one needs a folder
            message = f"{target.name}: another file is in its way"
            raise ApiError(422, message, "bad_upload") from None
        try:
            with open(target, "xb") as out:
                upload.file.seek(0)
                shutil.copyfileobj(upload.file, out, 1 << 16)
        except FileExistsError:
            raise ApiError(422, f"{target.name}: uploaded twice", "duplicate_file") from None

    await to_thread.run_sync(copy)


async def _stage(request: Request, ctx: Ctx, staged: Path) -> tuple[PurePosixPath, str, str]:
    """Write the upload into ``staged/files``; returns (scene entry, name, source kind)."""
    files = staged / "files"
    files.mkdir()
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype == "multipart/form-data":
        limit = ctx.settings.max_upload_bytes
        form = await request.form(
            max_files=ctx.settings.max_bundle_files + 2, max_fields=8, max_part_size=limit
        )
        try:
            known = {"scene", "files", "bundle", "mesh", "name"}
            unknown = sorted(set(form.keys()) - known)
            if unknown:
                raise ApiError(
                    422, f"unknown form field {unknown[0]!r} (use scene, files, bundle, mesh, name)"
                )
            name = scene_name(form.get("name"))
            scene, bundle, mesh = form.get("scene"), form.get("bundle"), form.get("mesh")
            extra = form.getlist("files")
            given = [
                k
                for k, v in (("scene", scene), ("bundle", bundle), ("mesh", mesh))
                if v is not None
            ]
            if len(given) != 1:
                raise ApiError(422, "give exactly one of the fields scene, bundle and mesh")
            for k in ("scene", "bundle", "mesh"):
                if len(form.getlist(k)) > 1:
                    raise ApiError(422, f"the field {k} appears more than once")
            if extra and scene is None:
                raise ApiError(422, "files go with a JSON scene (the field scene)")
            if scene is not None:
                entry = PurePosixPath("scene.json")
                if isinstance(scene, UploadFile):
                    await _save_upload(scene, files / "scene.json")
                    name = name or _stem(scene.filename) or "scene"
                else:
                    (files / "scene.json").write_text(scene, encoding="utf-8")
                    name = name or "scene"
                for item in extra:
                    if not isinstance(item, UploadFile):
                        raise ApiError(422, "files: each item must be a file with a file name")
                    relative = safe_relative(item.filename or "", "files")
                    if str(relative) == "scene.json":
                        raise ApiError(
                            422, "files: scene.json is the scene itself", "duplicate_file"
                        )
                    await _save_upload(item, files / Path(*relative.parts))
                return entry, name, "json"
            if bundle is not None:
                if not isinstance(bundle, UploadFile):
                    raise ApiError(422, "bundle: must be a file (a zip)")
                archive = staged / "bundle.zip"
                await _save_upload(bundle, archive)
                names = await to_thread.run_sync(extract_bundle, archive, files, ctx.settings)
                archive.unlink()
                return (
                    find_entry(files, names),
                    name or _stem(bundle.filename) or "bundle",
                    "bundle",
                )
            if not isinstance(mesh, UploadFile):
                raise ApiError(422, "mesh: must be a file")
            relative = safe_relative(mesh.filename or "", "mesh")
            suffix = relative.suffix.lower()
            if suffix not in MESH_SUFFIXES:
                known = ", ".join(sorted(MESH_SUFFIXES))
                raise ApiError(
                    422,
                    f"mesh: unknown mesh type {suffix or '(none)'!r} (use one of {known})",
                    "unsupported_type",
                )
            target = PurePosixPath(relative.name)
            await _save_upload(mesh, files / target.name)
            return target, name or relative.stem, "mesh"
        finally:
            await form.close()
    name = scene_name(request.query_params.get("name"))  # a raw body's name is in the query
    if ctype == "application/json":
        body = await request.body()
        if not body:
            raise ApiError(422, "the request body is empty")
        (files / "scene.json").write_bytes(body)
        return PurePosixPath("scene.json"), name or "scene", "json"
    if ctype in ("application/zip", "application/x-zip-compressed"):
        archive = staged / "bundle.zip"
        with open(archive, "wb") as out:
            async for chunk in request.stream():
                out.write(chunk)
        names = await to_thread.run_sync(extract_bundle, archive, files, ctx.settings)
        archive.unlink()
        return find_entry(files, names), name or "bundle", "bundle"
    raise ApiError(
        415,
        f"unsupported content type {ctype or '(none)'!r}: use multipart/form-data, "
        "application/json or application/zip",
    )


def scene_name(raw) -> str | None:
    """An upload's ``name`` (a form field, or the query of a raw body): at most 200 characters
    (422 beyond, never cut), None when absent or blank."""
    if raw is None:
        return None
    if not isinstance(raw, str) or len(raw) > 200:
        raise ApiError(422, "name: a text of at most 200 characters")
    return raw.strip() or None


def _stem(filename: str | None) -> str | None:
    if not filename:
        return None
    return PurePosixPath(filename.replace("\\", "/")).stem[:200] or None


@router.post(
    "",
    status_code=201,
    response_model=SceneDetail,
    openapi_extra=UPLOAD_SCHEMA,
    responses=errors(400, 413, 415),
)
async def upload_scene(request: Request, ctx: Ctx, response: Response) -> SceneDetail:
    """Upload a scene: a JSON scene with its files, a zip bundle, or one mesh file."""
    upload = await to_thread.run_sync(ctx.scenes.staging)
    try:  # all or nothing: a request that fails or times out at any point keeps no scene
        entry_path, name, source = await _stage(request, ctx, upload.staged)
        entry = await to_thread.run_sync(ctx.scenes.create, upload, entry_path, name[:200], source)
        response.headers["Location"] = f"/v1/scenes/{entry.id}"
        return await _detail(ctx, entry)
    except (ApiError, SceneError) as exc:  # named with the upload's own paths, no server path
        await to_thread.run_sync(ctx.scenes.abandon, upload)
        raise ctx.scenes.client_error(exc, upload) from None
    except BaseException:
        await to_thread.run_sync(ctx.scenes.abandon, upload)
        raise


async def _detail(ctx: Ctx, entry: SceneEntry) -> SceneDetail:
    record = ctx.store.scene(entry.id)
    if record is None:
        raise ApiError(404, f"no scene {entry.id!r}", "not_found")
    summary = await to_thread.run_sync(ctx.scenes.summary, entry)
    return SceneDetail(**{**record, **summary})


async def get_entry(ctx: Ctx, scene_id: str) -> SceneEntry:
    return await to_thread.run_sync(ctx.scenes.get, scene_id)


@router.get("", response_model=ScenesPublic, responses=errors())
async def list_scenes(ctx: Ctx) -> ScenesPublic:
    """List the scenes."""
    records = ctx.scenes.list()
    return ScenesPublic(data=[_public(r) for r in records], count=len(records))


@router.get("/{scene_id}", response_model=SceneDetail, responses=errors())
async def inspect_scene(scene_id: str, ctx: Ctx) -> SceneDetail:
    """Inspect a scene: triangles, bounds, effects, version, camera, nodes."""
    return await _detail(ctx, await get_entry(ctx, scene_id))


@router.delete("/{scene_id}", status_code=204, responses=errors())
async def delete_scene(scene_id: str, ctx: Ctx) -> Response:
    """Delete a scene (its sessions close; jobs keep their own copy and their results)."""
    await to_thread.run_sync(ctx.scenes.delete, scene_id)
    ctx.service.close_scene_sessions(scene_id)
    return Response(status_code=204)


async def _commit(scene_id: str, body: CommitRequest, ctx: Ctx) -> CommitPublic:
    entry = await get_entry(ctx, scene_id)
    version = await to_thread.run_sync(ctx.scenes.commit, entry, body.ops)
    return CommitPublic(scene_id=scene_id, version=version)


@router.post("/{scene_id}/commits", response_model=CommitPublic, responses=errors(400))
async def commit_ops(scene_id: str, body: CommitRequest, ctx: Ctx) -> CommitPublic:
    """Apply operations as one commit (all or nothing); returns the new version."""
    return await _commit(scene_id, body, ctx)


@router.patch("/{scene_id}", response_model=CommitPublic, responses=errors(400))
async def patch_scene(scene_id: str, body: CommitRequest, ctx: Ctx) -> CommitPublic:
    """Same as POST /scenes/{id}/commits."""
    return await _commit(scene_id, body, ctx)


def pixel_ray(camera: fmt.Camera, x: float, y: float, width: int, height: int):
    """The primary ray through film position (x, y) (pixels from the top-left corner), the
    way tracer.shading.camera builds it."""
    position = np.asarray(camera.position, np.float64)
    forward = np.asarray(camera.look_at, np.float64) - position
    forward /= portable.norm(forward)
    right = portable.normalized(portable.cross(forward, np.asarray(camera.up, np.float64)))
    up = portable.cross(right, forward)
    tan_half = math.tan(math.radians(camera.vfov_deg) * 0.5)
    sx = (2.0 * x / width - 1.0) * tan_half * (width / height)
    sy = (1.0 - 2.0 * y / height) * tan_half
    direction = forward + sx * right + sy * up
    return position, portable.normalized(direction)


def tracer_failure(error: RayError) -> ApiError:
    """A clean answer for a tracer call that failed: the tracer's own one-line reason when it
    refused the scene (a SceneError), 504 for a call that timed out, else 503. Ray's text (the
    actor's id, pid and node IP) goes to the server's log only."""
    if isinstance(error, TimeoutError):
        return ApiError(504, "the cluster did not answer in time; try again", "timeout")
    cause = getattr(error, "cause", None)
    if isinstance(cause, SceneError):
        reason = str(cause).splitlines()[0] if str(cause) else "invalid scene"
        return ApiError(422, f"the tracer cannot render this scene: {reason}", "invalid_scene")
    log.warning("a tracer call failed: %s", error)
    return ApiError(503, "the cluster could not answer: a tracer failed", "unavailable")


@router.post("/{scene_id}/query", response_model=QueryHit, responses=errors(400, 503, 504))
async def query_scene(scene_id: str, body: QueryRequest, ctx: Ctx) -> QueryHit:
    """Trace one ray (or the ray through a pixel) at the scene's current version (picking)."""
    entry = await get_entry(ctx, scene_id)
    if body.origin is not None:
        origin = np.asarray(body.origin, np.float64)
        direction = np.asarray(body.direction, np.float64)
        norm = portable.norm(direction)
        if not (norm > 0 and math.isfinite(norm)):
            raise ApiError(422, "direction: must be a finite, non-zero vector")
        direction = direction / norm
    else:
        camera = entry.graph.state.camera
        width, height = body.width or camera.width, body.height or camera.height
        if body.x > width or body.y > height:
            raise ApiError(422, f"pixel ({body.x}, {body.y}) is outside the {width}x{height} image")
        origin, direction = pixel_ray(camera, body.x, body.y, width, height)
    if not ctx.service.ready:
        raise ApiError(503, ctx.service.error or "the cluster is starting", "unavailable")
    try:
        version, hits = await ctx.service.call_async(
            ctx.service.query_call(entry, origin, direction), timeout=ctx.settings.request_timeout
        )
    except RayError as exc:  # checked first: Ray's errors may also derive from their cause's type
        raise tracer_failure(exc) from None
    except RuntimeError as exc:  # ClusterError: no tracer could answer
        raise ApiError(503, f"the cluster could not answer: {exc}", "unavailable") from None
    out = QueryHit(
        hit=bool(hits.node[0] >= 0) if len(hits.node) else False,
        origin=[float(v) for v in origin],
        direction=[float(v) for v in direction],
        version=version,
    )
    if out.hit:
        node = int(hits.node[0])
        state = entry.graph.state
        out.node = node
        out.node_name = state.nodes[node].name if node in state.nodes else None
        out.triangle = int(hits.triangle[0])
        out.distance = float(hits.t[0])
        out.point = [float(v) for v in hits.point[0]]
        out.normal = [float(v) for v in hits.normal[0]]
        out.material = hits.material[0]
    return out
