"""The service's settings: one typed model, read from ``TILERENDER_*`` environment variables.

Every field has a safe default; :meth:`Settings.from_env` reads ``TILERENDER_<FIELD>`` (upper
case) for each, e.g. ``TILERENDER_DATA_DIR``, ``TILERENDER_TOKEN``,
``TILERENDER_CORS_ORIGINS=http://a.example,http://b.example``. ``tilerender serve`` builds the
same model from its flags. Unknown fields and unsafe values (a non-positive limit, a balancer
that does not exist) are refused when the model is built, before anything starts.
"""

import os
from pathlib import Path

from pydantic import BaseModel, ConfigDict, Field, field_validator

from api.models import MAX_COMMIT_OPS, MAX_JOB_FRAMES
from cluster.balancing import DEFAULT_BALANCER

ENV_PREFIX = "TILERENDER_"
MiB = 1024 * 1024


def default_data_dir() -> Path:
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "tilerender"


class Settings(BaseModel):
    """What the service needs to run: where it keeps data, how it reaches the cluster, who may
    use it, and its limits."""

    model_config = ConfigDict(extra="forbid", validate_assignment=True)

    # Storage -------------------------------------------------------------------------------
    data_dir: Path = Field(default_factory=default_data_dir, description="scenes, jobs, results")
    db_path: Path | None = Field(default=None, description="SQLite file (default data_dir/db)")
    resume_jobs: bool = Field(
        default=True,
        description="after a restart, resume unfinished jobs from their last completed frame "
        "(False: mark them failed with the reason)",
    )

    # Cluster -------------------------------------------------------------------------------
    ray_address: str | None = Field(default=None, description="None: an embedded local Ray")
    tracers: int | None = Field(default=None, ge=1, le=1024)
    threads: float | None = Field(default=None, gt=0, description="CPUs per tracer")
    num_cpus: int | None = Field(default=None, ge=1, description="CPUs of the embedded Ray")
    balancer: str = DEFAULT_BALANCER
    tracer_nice: int = Field(
        default=10,
        ge=0,
        le=19,
        description="niceness given to tracer processes on this machine, so the HTTP side "
        "stays responsive while they use every core (0: leave them alone)",
    )

    # Access --------------------------------------------------------------------------------
    token: str | None = Field(default=None, description="bearer token; None: no auth")
    cors_origins: list[str] = Field(default_factory=list)

    # Limits --------------------------------------------------------------------------------
    max_upload_bytes: int = Field(default=64 * MiB, ge=1024, description="uploads, commits")
    max_json_bytes: int = Field(
        default=4 * MiB, ge=1024, description="the body of any other request (jobs, sessions)"
    )
    max_unpacked_bytes: int = Field(default=256 * MiB, ge=1024)
    max_bundle_files: int = Field(default=256, ge=1)
    max_compression_ratio: float = Field(default=100.0, gt=1.0)
    max_triangles: int = Field(default=2_000_000, ge=1)
    max_width: int = Field(default=3840, ge=1, le=16384)
    max_height: int = Field(default=2160, ge=1, le=16384)
    max_spp: int = Field(default=4096, ge=1)
    max_frames: int = Field(default=1000, ge=1, le=MAX_JOB_FRAMES)
    max_time_budget: float = Field(default=3600.0, gt=0)
    max_queue: int = Field(default=16, ge=1, description="queued and running jobs")
    max_sessions: int = Field(default=4, ge=1)
    max_session_pixels: int = Field(
        default=1280 * 720,
        ge=64,
        description="width x height of one interactive session at most (every frame of a "
        "session renders, blends and encodes at its full size, on the one render thread)",
    )
    max_ops: int = Field(
        default=1000, ge=1, le=MAX_COMMIT_OPS, description="operations in one commit"
    )
    request_timeout: float = Field(default=30.0, gt=0, description="seconds; not for streams")
    upload_timeout: float = Field(
        default=300.0, gt=0, description="seconds for a scene upload (loading and compiling)"
    )
    job_turn_seconds: float = Field(
        default=0.5,
        gt=0,
        le=10,
        description="seconds of work in one turn of a job (calls, cancels and sessions wait "
        "at most about one)",
    )

    # Sessions ------------------------------------------------------------------------------
    session_idle_seconds: float = Field(default=60.0, gt=0)
    session_default_width: int = Field(default=320, ge=1)
    session_default_height: int = Field(default=180, ge=1)
    jpeg_quality: int = Field(default=85, ge=10, le=100)
    session_class: str = Field(
        default="cluster.session:InteractiveSession",
        description="module:Class of the interactive sessions (tests plug in another)",
        pattern=r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$",
    )

    @field_validator("balancer")
    @classmethod
    def _known_balancer(cls, value: str) -> str:
        from cluster.balancing import BALANCERS

        if value not in BALANCERS:
            raise ValueError(f"unknown balancer {value!r} (known: {', '.join(sorted(BALANCERS))})")
        return value

    @field_validator("cors_origins", mode="before")
    @classmethod
    def _split_origins(cls, value):
        if isinstance(value, str):
            return [o.strip() for o in value.split(",") if o.strip()]
        return value

    @field_validator("token")
    @classmethod
    def _token(cls, value: str | None) -> str | None:
        if value is not None and not value.strip():
            return None
        if value is not None and len(value) < 8:
            raise ValueError("a bearer token needs at least 8 characters")
        return value

    @property
    def database(self) -> Path:
        return self.db_path or self.data_dir / "tilerender.db"

    @classmethod
    def from_env(cls, environ: dict[str, str] | None = None, **overrides) -> "Settings":
        """Settings from ``TILERENDER_*`` variables, then ``overrides`` (None values ignored)."""
        environ = os.environ if environ is None else environ
        values: dict = {}
        for name in cls.model_fields:
            raw = environ.get(ENV_PREFIX + name.upper())
            if raw is not None and raw != "":
                values[name] = raw
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**values)
