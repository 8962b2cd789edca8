"""``tilerender serve``: run the HTTP service and its web viewer until Ctrl-C (or SIGTERM)."""

import argparse
import socket

import pydantic

from cli.errors import UsageError
from cli.output import stderr
from cluster.jobs import embedded_ray_cpus
from tracer.errors import format_validation_error


def serve_settings(args: argparse.Namespace):
    """The service's settings: TILERENDER_* variables, overridden by the flags given."""
    from api.settings import Settings

    try:
        return Settings.from_env(
            num_cpus=embedded_ray_cpus(args.ray_address, args.tracers, args.threads),
            data_dir=args.data_dir,
            db_path=args.db,
            token=args.token,
            cors_origins=args.cors_origin,
            ray_address=args.ray_address,
            tracers=args.tracers,
            threads=args.threads,
            balancer=args.balancer,
        )
    except pydantic.ValidationError as exc:
        raise UsageError(format_validation_error(exc)) from None


def listening_socket(host: str, port: int) -> socket.socket:
    """A TCP socket bound to ``host:port`` (UsageError if it cannot be)."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    # Accepted connections inherit this: without it a response written in two parts waits
    # for the client's delayed ACK (about 40 ms per request on keep-alive connections).
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise UsageError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None
    return sock


def run(args: argparse.Namespace) -> int:
    """Run the HTTP service until interrupted; prints the viewer's URL once listening."""
    import uvicorn

    from api.app import create_app

    settings = serve_settings(args)
    if settings.ray_address is not None:  # fail fast, before anything starts
        from cluster.connect import probe

        probe(settings.ray_address.removeprefix("ray://"))
    sock = listening_socket(args.host, args.port)
    port = sock.getsockname()[1]
    host = f"[{args.host}]" if sock.family == socket.AF_INET6 else args.host
    url = f"http://{host}:{port}/"
    cluster = settings.ray_address or "an embedded local Ray"
    fragment = f"#token={settings.token}" if settings.token else ""
    print(f"tilerender: viewer at {url}{fragment}", flush=True)
    stderr.print(
        f"serving the API at {url}v1 (docs at {url}docs) on {cluster}; data in "
        f"{settings.data_dir}; Ctrl-C stops"
    )
    config = uvicorn.Config(
        create_app(settings),
        log_level=args.log_level,
        access_log=args.log_level in ("info", "debug"),
        timeout_graceful_shutdown=5,
    )
    server = uvicorn.Server(config)
    try:
        server.run(sockets=[sock])
    except KeyboardInterrupt:  # uvicorn re-raises the signal once it has shut down cleanly
        pass
    stderr.print("tilerender: stopped")
    return 0
