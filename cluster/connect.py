"""Joining a Ray cluster, or starting an embedded one for this process.

``connect()`` with no address starts a private local Ray (``ray.init(address="local")``: it
never attaches to some other cluster found on the machine) with the dashboard off and the
workers' output kept out of the caller's terminal. Its node address is 127.0.0.1, so its GCS,
raylet, agents and workers listen on the loopback interface only: nothing off the machine can
reach (or join) the embedded Ray, whatever host the service itself listens on. ``"auto"``
joins the cluster ``ray start`` left on this machine; ``"host:port"`` (or ``"ray://host:port"``
for Ray Client) joins that one. Before handing an address to Ray, we check that something
answering like a gRPC server listens there (a TCP connect and an HTTP/2 handshake, a few
seconds at most): Ray itself keeps retrying an unreachable address for many minutes. Joining
``host:port`` also needs a Ray node (a raylet) on this machine, which ``ray start --address``
provides: without one, Ray waits a minute or two before it fails, so we check for a raylet
process first and say what to do.

If Ray is already initialised in this process, ``connect()`` uses that session (an explicit
``host:port`` is still checked to be reachable) and says so in the returned
:class:`Connection` (``started=False``), so a caller that did not start Ray does not stop it.
"""

import logging
import os
import socket
from dataclasses import dataclass
from unittest import mock

import psutil
import ray

from cluster.errors import ClusterUnreachable

LOOPBACK = "127.0.0.1"
"""The embedded Ray's node address: its servers listen on this interface only."""
PROBE_TIMEOUT = 5.0
"""Seconds allowed for the TCP connect and handshake with a cluster's address."""

_HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + b"\x00\x00\x00\x04\x00\x00\x00\x00\x00"
_SETTINGS = 0x4


@dataclass(frozen=True)
class Connection:
    address: str
    """The cluster's GCS address (``host:port``)."""
    started: bool
    """True if this call started an embedded Ray (which ``disconnect`` then stops)."""
    nodes: int
    cpus: float


def connect(
    address: str | None = None, num_cpus: int | None = None, quiet: bool = True
) -> Connection:
    """Connect this process to Ray: an embedded local instance (``address`` None or
    ``"local"``, with ``num_cpus`` logical CPUs, default all), the machine's ``ray start``
    cluster (``"auto"``), or the one at ``"host:port"``.

    Raises :class:`ClusterUnreachable` (a ``ConnectionError``) when the address cannot be
    reached, and ValueError for ``num_cpus`` with an address (a cluster has its own CPUs).
    ``quiet`` keeps Ray's informational logging and the workers' output off the terminal.
    """
    joining = address not in (None, "local")
    if num_cpus is not None and joining:
        raise ValueError("num_cpus applies to an embedded Ray only, not to a cluster address")
    if ray.is_initialized():
        if joining and address != "auto":
            probe(_resolve(address), tls=_tls())
        return _current(started=False)
    options = {
        "include_dashboard": False,
        "log_to_driver": not quiet,
        "logging_level": logging.ERROR if quiet else logging.INFO,
    }
    if not joining:
        _init_on_loopback(num_cpus=num_cpus, **options)
        return _current(started=True)
    probe(_resolve(address), tls=_tls())
    if not address.startswith("ray://") and address != "auto" and not local_raylet_running():
        raise ClusterUnreachable(
            f"the Ray cluster at {address} answers, but no Ray node runs on this machine, and a "
            f"Ray driver needs one: start it first with `ray start --address {address} "
            "--num-cpus 0` (docs/deploy.md), or join through Ray Client (ray://HOST:10001)"
        )
    try:
        ray.init(address=address, **options)
    except (ConnectionError, RuntimeError, TimeoutError) as error:
        raise ClusterUnreachable(
            f"cannot join the Ray cluster at {address}: {str(error).splitlines()[0]}"
        ) from None
    return _current(started=False)


def _init_on_loopback(**options) -> None:
    """``ray.init`` of a local Ray whose node address is 127.0.0.1. Ray's servers bind to the
    node address, or to every interface when it is not loopback; ``ray.init`` turns a loopback
    ``_node_ip_address`` into the machine's outward address (``resolve_ip_for_localhost``), so
    that rewrite is switched off while the node starts."""
    from ray._private import services

    with mock.patch.object(services, "resolve_ip_for_localhost", lambda host: host):
        ray.init(address="local", _node_ip_address=LOOPBACK, **options)


def local_raylet_running() -> bool:
    """Whether a Ray node's raylet process runs on this machine (True when processes cannot
    be listed: then Ray is left to find out)."""
    try:
        return any(p.info["name"] == "raylet" for p in psutil.process_iter(["name"]))
    except psutil.Error:  # pragma: no cover - a restricted /proc
        return True


def _tls() -> bool:
    return os.environ.get("RAY_USE_TLS", "0").lower() in ("1", "true")


def disconnect() -> None:
    """Leave Ray (stopping the embedded instance if this process started one)."""
    if ray.is_initialized():
        ray.shutdown()


def _current(started: bool) -> Connection:
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    cpus = sum(float(n.get("Resources", {}).get("CPU", 0.0)) for n in nodes)
    address = ray.get_runtime_context().gcs_address
    return Connection(address=address, started=started, nodes=len(nodes), cpus=cpus)


def _resolve(address: str) -> str:
    """``host:port`` of ``address`` (``"auto"`` is looked up the way Ray does)."""
    if address == "auto":
        try:
            from ray._private.services import canonicalize_bootstrap_address_or_die

            return canonicalize_bootstrap_address_or_die("auto")
        except ConnectionError as error:
            found = "several" if "multiple" in str(error).lower() else "none"
            raise ClusterUnreachable(
                f"'auto' finds no single Ray cluster to join on this machine ({found} started "
                "with `ray start`); give the head's host:port"
            ) from None
        except ImportError:  # pragma: no cover - Ray moved its private helpers
            return address
    return address.removeprefix("ray://")


def parse_address(address: str) -> tuple[str, int]:
    """``(host, port)`` of ``"host:port"`` or ``"[v6]:port"``; ClusterUnreachable if malformed."""
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ClusterUnreachable(f"{address!r} is not a Ray address (expected host:port)")
    return host.strip("[]"), int(port)


def probe(address: str, timeout: float = PROBE_TIMEOUT, tls: bool = False) -> None:
    """Check that a gRPC server (a Ray GCS or Ray Client server) listens at ``address``:
    connect over TCP and, unless ``tls``, exchange HTTP/2 SETTINGS frames. Raises
    :class:`ClusterUnreachable` with the reason otherwise."""
    if address == "auto":
        return
    host, port = parse_address(address)
    try:
        with socket.create_connection((host, port), timeout=timeout) as conn:
            if tls:
                return
            conn.settimeout(timeout)
            conn.sendall(_HTTP2_PREFACE)
            header = _read(conn, 9)
    except socket.gaierror as error:
        raise ClusterUnreachable(f"cannot reach Ray at {address}: unknown host ({error})") from None
    except TimeoutError:
        raise ClusterUnreachable(
            f"cannot reach Ray at {address}: no answer within {timeout:g} s"
        ) from None
    except OSError as error:
        reason = error.strerror or str(error)
        raise ClusterUnreachable(f"cannot reach Ray at {address}: {reason}") from None
    if len(header) < 9 or header[3] != _SETTINGS:
        raise ClusterUnreachable(
            f"cannot reach Ray at {address}: something listens there, but it is not Ray "
            "(no gRPC handshake)"
        )


def _read(conn: socket.socket, size: int) -> bytes:
    data = b""
    while len(data) < size:
        chunk = conn.recv(size - len(data))
        if not chunk:
            break
        data += chunk
    return data
