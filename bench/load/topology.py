"""The compose topology without Docker: ``ray start`` head and worker processes and the API
process on this machine, started with the same entry points as the compose services.

    ray start --head --port=PORT --num-cpus=N --block      (the head)
    ray start --address=HEAD:PORT --num-cpus=N --block     (each worker)
    tilerender serve --host 127.0.0.1 --port 0 --ray-address HEAD:PORT

Every process runs in its own session (process group). ``Topology.close()`` stops them all:
the API with SIGINT (its clean shutdown), each Ray node with SIGKILL of its process group and
of every descendant (Ray's worker processes, the tracers among them, call ``setsid`` and live
in groups of their own). ``ray stop`` is never used: it would stop every Ray on the machine,
other people's included.

Additions to the compose command lines, all for running several nodes on one machine next to
other users: a short ``--temp-dir`` of our own (Unix socket paths under it must stay below 108
bytes, so a pytest ``tmp_path`` is too long), free ports for the head's Ray client server and
each node's dashboard agent (and the head's dashboard, which Ray starts in a minimal mode even
with ``--include-dashboard=false``), ``--include-dashboard=false`` and
``--disable-usage-stats``.

Ray token authentication is set explicitly (``RAY_AUTH_MODE=token`` and a random
``RAY_AUTH_TOKEN`` for every process): with the mode unset, Ray >= 2.59's ``ray start --head``
turns it on whenever ``~/.ray/auth_token`` exists (any earlier embedded ``ray.init()`` writes
one), while a driver given an explicit address never does, and is then refused by the GCS.
"""

import contextlib
import os
import secrets
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import psutil

REPO_ROOT = Path(__file__).resolve().parents[2]
BIN = Path(sys.executable).parent
RAY = BIN / "ray"
TILERENDER = BIN / "tilerender"
LOOPBACK = "127.0.0.1"
READY_TIMEOUT = 300.0


def free_port() -> int:
    """A TCP port nobody listens on right now (on the loopback)."""
    with socket.socket() as sock:
        sock.bind((LOOPBACK, 0))
        return sock.getsockname()[1]


def kill_tree(process: subprocess.Popen, sig: int = signal.SIGKILL) -> None:
    """Send ``sig`` to ``process``, its process group and every descendant, then reap it."""
    try:
        descendants = psutil.Process(process.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        descendants = []
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(process.pid, sig)
    for child in descendants:
        with contextlib.suppress(psutil.NoSuchProcess):
            child.send_signal(sig)
    with contextlib.suppress(subprocess.TimeoutExpired):
        process.wait(10)
    psutil.wait_procs(descendants, timeout=10)


@dataclass
class RayNode:
    """One ``ray start --block`` process (a head or a worker)."""

    role: str
    process: subprocess.Popen
    log: Path

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def kill(self) -> None:
        """The node disappears at once: SIGKILL to its raylet, its workers and the rest."""
        kill_tree(self.process)

    def pids(self) -> set[int]:
        """The node's processes (ray start and every descendant)."""
        try:
            root = psutil.Process(self.process.pid)
            return {root.pid} | {p.pid for p in root.children(recursive=True)}
        except psutil.NoSuchProcess:
            return set()


@dataclass
class Api:
    """A ``tilerender serve`` process and its URL."""

    process: subprocess.Popen
    url: str
    data_dir: Path
    log: Path

    def stop(self, timeout: float = 30.0) -> int | None:
        """SIGINT (a clean shutdown), SIGKILL after ``timeout``; then SIGKILL to whatever
        it started that is still there (an embedded Ray's processes)."""
        if self.process.poll() is None:
            try:
                descendants = psutil.Process(self.process.pid).children(recursive=True)
            except psutil.NoSuchProcess:
                descendants = []
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout)
            except subprocess.TimeoutExpired:
                kill_tree(self.process)
            _, alive = psutil.wait_procs(descendants, timeout=10)
            for process in alive:
                with contextlib.suppress(psutil.NoSuchProcess):
                    process.kill()
        return self.process.returncode

    def log_tail(self, chars: int = 3000) -> str:
        return self.log.read_text(errors="replace")[-chars:] if self.log.exists() else ""


@dataclass
class Topology:
    """A head, workers and an API on this machine; use as a context manager (stops all)."""

    workdir: Path
    temp_dir: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="trl-")))
    head: RayNode | None = None
    workers: list[RayNode] = field(default_factory=list)
    apis: list[Api] = field(default_factory=list)
    port: int = 0
    token: str = field(default_factory=lambda: secrets.token_hex(32))
    env: dict[str, str] = field(default_factory=dict)
    """Extra environment of every process (e.g. PYTHONPATH)."""

    @property
    def ray_env(self) -> dict[str, str]:
        """Environment of every process: token authentication on, with our own token."""
        return {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": self.token}

    @property
    def address(self) -> str:
        return f"{LOOPBACK}:{self.port}"

    def _spawn(self, args: list[str], log_name: str, env: dict | None = None):
        log = self.workdir / log_name
        log.parent.mkdir(parents=True, exist_ok=True)
        environ = {**os.environ, **self.ray_env, **self.env, **(env or {})}
        with open(log, "wb") as out:
            process = subprocess.Popen(
                args,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=out,
                env=environ,
                cwd=REPO_ROOT,
                start_new_session=True,
            )
        return process, log

    def start_head(self, num_cpus: int) -> RayNode:
        self.port = free_port()
        args = [
            str(RAY), "start", "--head", f"--port={self.port}", f"--num-cpus={num_cpus}",
            "--block",
            *self._local_flags(),
            f"--ray-client-server-port={free_port()}",
            f"--dashboard-port={free_port()}",
            "--include-dashboard=false",
        ]  # fmt: skip
        process, log = self._spawn(args, "ray-head.log")
        self.head = RayNode("head", process, log)
        self._wait_started(self.head)
        return self.head

    def add_worker(self, num_cpus: int) -> RayNode:
        assert self.head is not None, "start the head first"
        args = [
            str(RAY), "start", f"--address={self.address}", f"--num-cpus={num_cpus}", "--block",
            *self._local_flags(),
        ]  # fmt: skip
        process, log = self._spawn(args, f"ray-worker-{len(self.workers)}.log")
        node = RayNode(f"worker-{len(self.workers)}", process, log)
        self.workers.append(node)
        self._wait_started(node)
        return node

    def _local_flags(self) -> list[str]:
        return [
            f"--temp-dir={self.temp_dir}",
            f"--dashboard-agent-listen-port={free_port()}",
            "--disable-usage-stats",
        ]

    @staticmethod
    def _wait_started(node: RayNode, timeout: float = 180.0) -> None:
        """Until ``ray start`` says the node runs (it has registered with the head's GCS)."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            log = node.log.read_text(errors="replace")
            if "Ray runtime started" in log:
                return
            if not node.alive:
                raise RuntimeError(f"ray {node.role} exited: {log[-2000:]}")
            time.sleep(0.2)
        raise TimeoutError(f"ray {node.role} did not start: {node.log.read_text()[-2000:]}")

    def start_api(self, data_dir: Path, *extra: str, env: dict | None = None) -> Api:
        """``tilerender serve`` joined to the head; waits for /readyz."""
        port = free_port()
        args = [
            str(TILERENDER), "serve", "--host", LOOPBACK, "--port", str(port),
            "--ray-address", self.address, "--data-dir", str(data_dir), *extra,
        ]  # fmt: skip
        process, log = self._spawn(args, f"api-{len(self.apis)}.log", env)
        api = Api(process, f"http://{LOOPBACK}:{port}", data_dir, log)
        self.apis.append(api)
        wait_ready(api)
        return api

    def close(self) -> None:
        for api in self.apis:
            api.stop()
        for node in [*self.workers, self.head]:
            if node is not None:
                node.kill()
        shutil.rmtree(self.temp_dir, ignore_errors=True)

    def __enter__(self) -> "Topology":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def wait_ready(api: Api, timeout: float = READY_TIMEOUT) -> None:
    """Poll /readyz until 200; raise with the API's log if it fails or exits."""
    import httpx

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if api.process.poll() is not None:
            raise RuntimeError(f"serve exited: {api.log_tail()}")
        try:
            r = httpx.get(api.url + "/readyz", timeout=5)
            if r.status_code == 200:
                return
            if r.json().get("status") == "failed":
                raise RuntimeError(f"cluster failed: {r.json().get('message')}")
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"the API did not become ready: {api.log_tail()}")


def serve_embedded(workdir: Path, data_dir: Path, *extra: str, env: dict | None = None) -> Api:
    """``tilerender serve`` on 127.0.0.1 with its own embedded Ray (what ``./dev run``
    starts); waits for /readyz. Stop it with ``Api.stop()``."""
    port = free_port()
    log = workdir / "api.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    args = [
        str(TILERENDER), "serve", "--host", LOOPBACK, "--port", str(port),
        "--data-dir", str(data_dir), *extra,
    ]  # fmt: skip
    with open(log, "wb") as out:
        process = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=out,
            env={**os.environ, **(env or {})},
            cwd=REPO_ROOT,
            start_new_session=True,
        )
    api = Api(process, f"http://{LOOPBACK}:{port}", data_dir, log)
    try:
        wait_ready(api)
    except BaseException:
        kill_tree(process)
        raise
    return api
