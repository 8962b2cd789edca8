"""Request and response shapes of the API (the OpenAPI document is built from these)."""

from typing import Annotated, Any, Literal

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from tracer.integrators.names import (
    ADAPTIVE,
    DENOISE,
    DENOISE_PREFILTER,
    KERNELS,
    LIGHT_SAMPLERS,
)
from tracer.scene import format as fmt

MAX_CAMERA_PATH = 10_000
"""Cameras a job's ``camera_path`` may hold whatever the settings say: the model refuses a
longer list after reading this many (each is validated), so a hostile one costs little."""
MAX_JOB_FRAMES = fmt.MAX_FRAMES
"""Entries of a job's ``frames``: no animation has more frames than the scene format allows."""
MAX_COMMIT_OPS = 10_000
"""Operations one commit may hold whatever the settings say (``max_ops`` is at most this)."""


def _three_components(value: Any) -> Any:
    """Refuse a vector of the wrong length before its items are validated (pydantic checks
    a tuple's length only after validating every item it was given)."""
    if isinstance(value, list | tuple) and len(value) != 3:
        raise ValueError(f"a vector has 3 components, not {len(value)}")
    return value


Vec3 = Annotated[fmt.Vec3, BeforeValidator(_three_components)]


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid")


class ErrorBody(BaseModel):
    status: int
    code: str
    message: str


class ErrorResponse(BaseModel):
    error: ErrorBody


ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": ErrorResponse, "description": text}
    for code, text in {
        401: "missing bearer token",
        403: "wrong bearer token",
        404: "not found",
        422: "invalid input",
    }.items()
}


def errors(*codes: int) -> dict[int | str, dict[str, Any]]:
    texts = {
        400: "a body that cannot be read (not UTF-8, too deeply nested, malformed multipart)",
        409: "conflict",
        413: "too large",
        415: "unsupported media type",
        429: "queue or session limit reached",
        503: "the cluster is not ready",
        504: "timed out",
    }
    extra = {c: {"model": ErrorResponse, "description": texts.get(c, "error")} for c in codes}
    return {**ERRORS, **extra}


# --- Scenes ------------------------------------------------------------------------------------


class Bounds(BaseModel):
    min: list[float]
    max: list[float]


class ScenePublic(BaseModel):
    id: str
    name: str
    source: str = Field(description="json, bundle or mesh")
    entry: str | None = Field(description="the scene file inside the upload")
    version: int
    triangles: int
    created: float


class SceneDetail(ScenePublic):
    nodes: int
    meshes: int
    materials: list[str]
    bounds: Bounds | None
    camera: dict
    render: dict
    sky: list[float]
    animation: dict | None
    effects: dict = Field(
        description="the effect plan the tracers render the scene with: enabled effects, "
        "skipped ones and the rule behind each (docs/effects.md)"
    )
    node_list: list[dict]
    warnings: list[str] = Field(
        default_factory=list,
        description="what loading the scene ignored or approximated of its glTF files, one "
        "line per feature and file (docs/materials.md, the glTF feature table)",
    )


class ScenesPublic(BaseModel):
    data: list[ScenePublic]
    count: int


class CommitRequest(Strict):
    ops: list[dict[str, Any]] = Field(
        min_length=1,
        max_length=MAX_COMMIT_OPS,
        description="scene operations (docs/dynamic-scenes.md), applied all or nothing",
        json_schema_extra={"examples": [[{"op": "set_sky", "radiance": [0.1, 0.1, 0.1]}]]},
    )


class CommitPublic(BaseModel):
    scene_id: str
    version: int


class QueryRequest(Strict):
    """A ray (``origin`` and ``direction``) or a pixel of the scene's current camera (``x``,
    ``y`` in pixels from the top-left corner, ``width`` and ``height`` of the image they refer
    to: the camera's by default)."""

    origin: Vec3 | None = None
    direction: Vec3 | None = None
    x: float | None = Field(default=None, ge=0, le=16384)
    y: float | None = Field(default=None, ge=0, le=16384)
    width: int | None = Field(default=None, ge=1, le=16384)
    height: int | None = Field(default=None, ge=1, le=16384)

    @model_validator(mode="after")
    def _one_kind(self) -> "QueryRequest":
        ray = self.origin is not None or self.direction is not None
        pixel = self.x is not None or self.y is not None
        if ray == pixel:
            raise ValueError("give either origin and direction, or x and y")
        if ray and (self.origin is None or self.direction is None):
            raise ValueError("a ray needs both origin and direction")
        if pixel and (self.x is None or self.y is None):
            raise ValueError("a pixel needs both x and y")
        if ray and not any(self.direction):
            raise ValueError("direction must not be zero")
        return self


class QueryHit(BaseModel):
    hit: bool
    node: int | None = None
    node_name: str | None = None
    triangle: int | None = None
    distance: float | None = None
    point: list[float] | None = None
    normal: list[float] | None = None
    material: str | None = None
    origin: list[float]
    direction: list[float]
    version: int


# --- Jobs --------------------------------------------------------------------------------------


class CameraPose(Strict):
    position: Vec3
    look_at: Vec3
    up: Vec3 | None = None
    vfov_deg: float | None = Field(default=None, gt=0, lt=180)


class JobCreate(Strict):
    """A render job: a still, or an animation (the scene's keyframes, or a camera path),
    by samples per pixel (``spp``, default the scene's), by ``target_error`` (relative RMS
    error estimate per frame) or by ``time_budget`` (seconds for the whole job)."""

    scene_id: str = Field(min_length=1, max_length=64)
    kind: Literal["still", "animation"] = "still"
    spp: int | None = Field(default=None, ge=1)
    target_error: float | None = Field(default=None, gt=0, lt=1)
    time_budget: float | None = Field(default=None, gt=0)
    max_spp: int | None = Field(
        default=None,
        ge=4,
        description="cap for the progressive modes (at least 4: a wave is four parts)",
    )
    width: int | None = Field(default=None, ge=1)
    height: int | None = Field(default=None, ge=1)
    seed: int | None = Field(default=None, ge=0, lt=2**63)
    max_depth: int | None = Field(default=None, ge=1, le=1024)
    kernel: Literal[KERNELS] | None = Field(
        default=None,
        description="how paths are traced (the scene's render.kernel by default); the same "
        "image either way",
    )
    light_sampler: Literal[LIGHT_SAMPLERS] | None = Field(
        default=None,
        description="how light samples pick emissive triangles: power, tree or auto (the "
        "scene's render.light_sampler by default); the same image in expectation",
    )
    aovs: bool | None = Field(
        default=None,
        description="also render the AOV layers albedo, normal, depth, position, alpha, "
        "object_id and material_id (the scene's render.aovs by default); frames then offer "
        "?layer= and every layer as exr or npz",
    )
    denoise: Literal[DENOISE] | None = Field(
        default=None,
        description="denoise each finished frame with Open Image Denoise at this quality "
        "(the scene's render.denoise by default); the frame's default layer is then the "
        "denoised one, the beauty stays as ?layer=beauty",
    )
    denoise_prefilter: Literal[DENOISE_PREFILTER] | None = Field(
        default=None,
        description="prefilter the denoiser's albedo and normal guides: auto where they are "
        "noisy (both with a lens aperture, a normal map or a blended surface, the albedo with "
        "textures only), on (both), off or albedo (the scene's render.denoise_prefilter by "
        "default)",
    )
    adaptive: Literal[ADAPTIVE] | bool | None = Field(
        default=None,
        description="adaptive sampling with target_error or time_budget: each wave gives "
        "pixels samples by their estimated share of the error; auto where it is predicted to "
        "win, on (true) or off (false) (the scene's render.adaptive by default)",
    )
    frames: list[Annotated[int, Field(ge=0, lt=MAX_JOB_FRAMES)]] | None = Field(
        default=None,
        max_length=MAX_JOB_FRAMES,
        description="animation frames (default all of the scene's)",
    )
    camera_path: list[CameraPose] | None = Field(
        default=None,
        max_length=MAX_CAMERA_PATH,
        description="an animation along these cameras instead of the keyframes",
    )
    camera: CameraPose | None = Field(
        default=None, description="a still from this view instead of the scene's camera"
    )

    @model_validator(mode="after")
    def _check(self) -> "JobCreate":
        modes = [m for m in (self.target_error, self.time_budget) if m is not None]
        if len(modes) > 1 or (modes and self.spp is not None):
            raise ValueError("give at most one of spp, target_error and time_budget")
        if self.adaptive is not None and not modes:
            raise ValueError("adaptive applies to jobs by target_error or time_budget")
        if self.kind == "still" and (self.frames is not None or self.camera_path is not None):
            raise ValueError("frames and camera_path are for animations (kind: animation)")
        if self.kind == "animation" and self.camera is not None:
            raise ValueError("camera is for stills; an animation takes a camera_path")
        if self.frames is not None and self.camera_path is not None:
            raise ValueError("give frames or camera_path, not both")
        if self.frames is not None:
            if not self.frames:
                raise ValueError("frames must not be empty")
            if len(set(self.frames)) != len(self.frames):
                raise ValueError("frames must not repeat")
        if self.camera_path is not None and not self.camera_path:
            raise ValueError("camera_path must not be empty")
        return self


class Progress(BaseModel):
    frames_done: int
    frames_total: int
    current_frame: int | None = None
    lines_done: int = 0
    lines_total: int = 0
    samples_done: int = 0
    spp_current_frame: int | None = None
    error_estimate: float | None = None
    error_spp: int | None = None
    """Samples per pixel the estimate was made at (the last complete wave's)."""
    eta_seconds: float | None = None
    elapsed_seconds: float | None = None


class FramePublic(BaseModel):
    frame: int
    position: int
    spp: int
    seconds: float
    error_estimate: float | None
    urls: dict[str, str]


class JobPublic(BaseModel):
    id: str
    scene_id: str
    status: Literal["queued", "running", "done", "failed", "cancelled"]
    request: dict
    created: float
    started: float | None
    finished: float | None
    scene_version: int
    width: int
    height: int
    error: str | None
    resumed: int = Field(description="times the job was resumed after a restart")
    queue_position: int | None = None
    progress: Progress
    frames: list[FramePublic] | None = None


class JobsPublic(BaseModel):
    data: list[JobPublic]
    count: int


# --- Sessions ----------------------------------------------------------------------------------


class SessionCreate(Strict):
    scene_id: str = Field(min_length=1, max_length=64)
    width: int | None = Field(default=None, ge=8)
    height: int | None = Field(default=None, ge=8)
    target_fps: float = Field(default=10.0, gt=0, le=120)
    min_blend: float = Field(default=0.1, gt=0, le=1)
    camera: CameraPose | None = None
    denoise: Literal[DENOISE] = Field(
        default="off",
        description="denoise the shown image (the converged blend, guided by its albedo and "
        "normal) with Open Image Denoise at this quality; PATCH the session to change it",
    )


class SessionUpdate(Strict):
    denoise: Literal[DENOISE] = Field(
        description="denoise the shown image at this quality from the next frame on (off: show "
        "it as it is)"
    )


class SessionPublic(BaseModel):
    id: str
    scene_id: str
    width: int
    height: int
    denoise: Literal[DENOISE]
    camera: dict | None
    created: float
    stream_url: str
    frame_url: str
    stats: dict


class SessionsPublic(BaseModel):
    data: list[SessionPublic]
    count: int


# --- Cluster -----------------------------------------------------------------------------------


class TracerPublic(BaseModel):
    id: str
    state: str
    node: str | None
    pid: int | None
    cpus: float
    threads: int
    failures: int
    lines_last_frame: float | None
    """Lines rendered in the last frame (fractional when the frame was cut into spans)."""
    lines_per_second: float | None
    idle_percent: float | None


class ClusterPublic(BaseModel):
    ready: bool
    error: str | None
    balancer: str | None
    balancers: list[str]
    tracers: list[TracerPublic]
    last_frame: dict | None
    queue_length: int
    sessions: int
    frames_rendered: int


class BalancerUpdate(Strict):
    name: str = Field(min_length=1, max_length=64)
