"""Prometheus metrics of one app (its own registry, so several apps can live in one process)."""

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, generate_latest

CONTENT_TYPE = "text/plain; version=0.0.4; charset=utf-8"


class Metrics:
    def __init__(self) -> None:
        self.registry = CollectorRegistry()
        r = self.registry
        self.requests = Counter(
            "tilerender_http_requests", "HTTP requests", ["method", "route", "status"], registry=r
        )
        self.request_seconds = Histogram(
            "tilerender_http_request_seconds",
            "Time to the response's first byte",
            ["route"],
            buckets=(0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30),
            registry=r,
        )
        self.jobs = Counter("tilerender_jobs", "Jobs that ended, by status", ["status"], registry=r)
        self.jobs_submitted = Counter("tilerender_jobs_submitted", "Jobs submitted", registry=r)
        self.frames = Counter(
            "tilerender_frames",
            "Coordinator frames rendered (a session's frame, or one turn of a job)",
            ["kind"],
            registry=r,
        )
        self.frame_seconds = Histogram(
            "tilerender_frame_seconds",
            "Wall time of a coordinator frame (a session's frame, or one turn of a job)",
            ["kind"],
            buckets=(0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60, 300),
            registry=r,
        )
        self.rays = Counter(
            "tilerender_rays",
            "Rays traced (camera, continuation, shadow and occlusion), by frame kind",
            ["kind"],
            registry=r,
        )
        self.sessions = Gauge("tilerender_sessions", "Open interactive sessions", registry=r)
        self.queue = Gauge("tilerender_job_queue", "Queued and running jobs", registry=r)
        self.tracers = Gauge("tilerender_tracers_ready", "Tracers ready to render", registry=r)
        self.idle = Gauge(
            "tilerender_idle_percent", "Idle % of the tracers in the latest frame", registry=r
        )
        self.ready = Gauge("tilerender_ready", "1 when the cluster is up", registry=r)

    def render(self) -> bytes:
        return generate_latest(self.registry)
