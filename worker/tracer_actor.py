"""A Brigade tracer (Bikker 7.3.1-7.3.4) as a Ray actor.

:class:`Tracer` is a plain class that owns a :class:`~worker.replica.SceneReplica` and renders
ranges of a frame's work units (:mod:`worker.work_units`: whole lines, or spans of them) with
:func:`tracer.render.render_pixels`; :func:`remote_tracer` makes the
Ray actor class from it (one process per tracer, restarted by Ray when it dies). Keeping the
class plain lets the tests drive it in-process, without Ray.

A tracer may hold several scenes at once (a service renders jobs and sessions of different
scenes in turns): each is a replica under the key of its scene graph, the
``MAX_SCENES`` most recently used are kept, and every call names its scene.

Every call on a scene (``render``, ``spot_check``, ``query``) carries a
:class:`~worker.envelope.SceneEnvelope`, everything the tracer needs to reach the version the
call is for: the commit buffer since the version the coordinator believes the tracer holds
(encoded commits, applied in order and idempotently), or a snapshot when the coordinator knows
it has none; ``reach`` applies it. If the replica still cannot produce the version (a
restarted process, a gap in the commits, or a version it no longer keeps) the call returns
:class:`OutOfSync` instead of its answer, saying which version it holds, and the coordinator
resends it with the right commits or a snapshot. A frame's calls carry the frame's
:class:`~tracer.request.FrameRequest` with the tracer's share of its work units.

Rendering uses as many threads as the CPUs the actor reserved (at least one), so tracers never
oversubscribe the cores Ray gave them.
"""

import os
import time
import uuid
from collections import OrderedDict
from dataclasses import dataclass, field, replace

import numpy as np

from tracer.accuracy.spot_check import render_spot_checks
from tracer.errors import SceneError
from tracer.geometry.query import SceneHits
from tracer.integrators.effects import effect_plan
from tracer.integrators.kernel_choice import chosen_kernel, plan_report
from tracer.kernel import numba_cache
from tracer.kernel.threads import default_threads
from tracer.render import render_lines, render_pixels
from tracer.request import FrameRequest
from tracer.scene import format as fmt
from worker.envelope import DEFAULT_SCENE, SceneEnvelope
from worker.line_pool import LinePool
from worker.remote_pool import PoolLost, RemotePool
from worker.replica import SceneReplica
from worker.work_units import WorkUnits

MAX_SCENES = 4
"""Scenes a tracer keeps compiled; the least recently used beyond this is dropped (a call
for it later answers :class:`OutOfSync` and is resent with a snapshot)."""


@dataclass
class UnitsResult:
    """Work units [u0, u1) of ``frame`` (``spans`` units per line) rendered at scene
    ``version`` by one tracer."""

    tracer: str
    frame: int
    version: int
    u0: int
    u1: int
    rgb: np.ndarray
    """float32 (pixels, 3), linear radiance of the units' pixel run, in row-major order."""
    cost: np.ndarray
    """int64 (u1 - u0,): work per unit (BVH node visits plus triangle tests)."""
    seconds: float
    """Rendering (including a test-only ``delay``), not applying commits."""
    apply_seconds: float
    """Applying the commit buffer or snapshot that came with the call (BVH refit/rebuild)."""
    pid: int
    node: str
    incarnation: str
    """Changes when Ray restarts the actor (a new process with an empty replica)."""
    effects: dict | None = None
    """The effect plan the units were rendered with
    (``tracer.integrators.effects.EffectPlan.to_json``)."""
    rays: np.ndarray | None = None
    """int64 (u1 - u0,): rays traced per unit (camera, continuation, shadow and occlusion)."""
    aov: np.ndarray | None = None
    """float32 (pixels, ``tracer.integrators.aov.CHANNELS``): the AOVs of the pixel run, when
    the settings render them."""
    spans: int = 1
    """Units per line of the frame (:class:`worker.work_units.WorkUnits`)."""
    more: list["UnitsResult"] | None = field(default_factory=list)
    """Chunks of the frame's shared pool this call rendered after its own range, in the
    order claimed (:mod:`worker.line_pool`); None when the call named a pool this tracer could
    not open (another machine, or the frame already finished)."""


@dataclass(frozen=True)
class OutOfSync:
    """The tracer could not reach ``version`` of ``scene``: it holds ``have`` of it (None:
    nothing of that scene)."""

    tracer: str
    frame: int
    version: int
    have: int | None
    reason: str
    incarnation: str
    scene: str = DEFAULT_SCENE


@dataclass(frozen=True)
class TracerInfo:
    id: str
    node: str
    pid: int
    incarnation: str
    cpus: float
    threads: int
    version: int | None
    """Newest version of the most recently used scene (None: no scene yet)."""
    versions: tuple[int, ...]
    scenes: dict[str, tuple[int, ...]]
    """Versions held per scene key, least recently used first."""
    cache_dir: str
    """numba's kernel cache directory in this process (shared by every tracer of a machine)."""


def _node_id() -> str:
    """The Ray node this process runs on, or the host name outside Ray."""
    try:
        import ray

        if ray.is_initialized():
            return ray.get_runtime_context().get_node_id()
    except Exception:  # pragma: no cover - Ray missing or not in a worker
        pass
    return os.uname().nodename


class Tracer:
    """One tracer: a scene replica and a renderer of work-unit ranges. Not thread-safe; a Ray actor
    runs one call at a time, in submission order.

    ``cpus`` is what the actor reserved; it renders with ``max(1, floor(cpus))`` threads.
    ``delay`` is a test-only option: seconds to sleep at the start of every render (a slow or
    stalled tracer, or one to kill mid-render); it counts as render time.
    """

    def __init__(self, tracer_id: str, cpus: float | None = None, delay: float = 0.0):
        self.id = tracer_id
        self.cpus = float(cpus) if cpus else float(default_threads())
        self.threads = max(1, int(self.cpus))
        self.delay = float(delay)
        self.replicas: OrderedDict[str, SceneReplica] = OrderedDict()
        self.incarnation = uuid.uuid4().hex[:12]
        self.pid = os.getpid()
        self.node = _node_id()

    # Scene synchronisation -------------------------------------------------------------------

    def replica(self, scene: str = DEFAULT_SCENE) -> SceneReplica | None:
        """The replica of ``scene`` (marked most recently used), or None."""
        replica = self.replicas.get(scene)
        if replica is not None:
            self.replicas.move_to_end(scene)
        return replica

    def sync_snapshot(self, blob: bytes, scene: str = DEFAULT_SCENE) -> int:
        """Start ``scene`` over from an encoded snapshot (``tracer.scene.codec.encode_state``);
        returns the version now held."""
        replica = self.replica(scene)
        if replica is None:
            replica = self.replicas[scene] = SceneReplica(blob)
            while len(self.replicas) > MAX_SCENES:
                self.replicas.popitem(last=False)
        else:
            replica.reset(blob)
        return replica.version

    def version(self, scene: str = DEFAULT_SCENE) -> int | None:
        """The newest version of ``scene`` held (None: none)."""
        replica = self.replicas.get(scene)
        return None if replica is None else replica.version

    def reach(self, envelope: SceneEnvelope, frame: int = -1) -> tuple[OutOfSync | None, float]:
        """Bring the replica of ``envelope.scene`` to hold ``envelope.version``: (None, or the
        :class:`OutOfSync` answer for ``frame`` saying why not; seconds spent applying)."""
        envelope = envelope.fetched()
        start = time.perf_counter()
        problem = self._apply(envelope)
        seconds = time.perf_counter() - start
        if problem is None:
            return None, seconds
        scene, version = envelope.scene, envelope.version
        have = self.version(scene)
        return OutOfSync(self.id, frame, version, have, problem, self.incarnation, scene), seconds

    def _apply(self, envelope: SceneEnvelope) -> str | None:
        """Apply ``envelope``'s snapshot or commits; None on success, else why it failed."""
        scene, version, snapshot = envelope.scene, envelope.version, envelope.snapshot
        replica = self.replica(scene)
        if snapshot is not None and (replica is None or version not in replica.versions):
            self.sync_snapshot(snapshot, scene)
            replica = self.replicas[scene]
        if replica is None:
            return "no replica of this scene (new or restarted tracer, or dropped)"
        if version in replica.versions:
            return None
        try:
            replica.apply(list(envelope.commits))
        except SceneError as error:  # a gap (CommitGap) or a commit that does not apply here
            return str(error).splitlines()[0]
        if version not in replica.versions:
            return f"holds versions {replica.versions}, not {version}"
        return None

    # Rendering -------------------------------------------------------------------------------

    def render(
        self,
        envelope: SceneEnvelope,
        request: FrameRequest,
        spans: int = 1,
        pool: tuple[str | RemotePool, int] | None = None,
    ) -> "UnitsResult | OutOfSync":
        """Render the work units ``request.units`` (``spans`` units per line: whole lines by
        default) of ``request``'s frame exactly at the version ``envelope`` reaches.

        The request's camera and settings left None are the scene's at that version. ``pool``:
        the frame's shared pool (a :mod:`worker.line_pool` file's path, or a
        :class:`worker.remote_pool.RemotePool`) and this tracer's owner id in it; after its own
        units the tracer claims and renders the pool's chunks until none is left
        (``UnitsResult.more``). The request's units may then be empty.
        """
        frame, (u0, u1), sample_start = request.frame, request.units, request.sample_start
        out_of_sync, apply_seconds = self.reach(envelope, frame)
        applied = time.perf_counter()
        if out_of_sync is not None:
            return out_of_sync
        scene, version = envelope.scene, envelope.version
        compiled = self.replicas[scene].at(version)
        if self.delay > 0.0:
            time.sleep(self.delay)
        settings = request.settings or compiled.render
        camera = request.camera or compiled.camera
        units = WorkUnits(*replace(request, camera=camera).view(), spans)
        first = request.first_pixel
        plan = effect_plan(compiled, settings)
        effects = plan_report(plan, settings)

        def render_units(a: int, b: int, since: float, apply_seconds: float = 0.0) -> UnitsResult:
            if b > a:
                p0, p1 = units.pixels(a, b)
                out = render_pixels(
                    compiled,
                    first + p0,
                    first + p1,
                    camera,
                    settings,
                    frame,
                    sample_start,
                    self.threads,
                    plan,
                    request.counts,
                )
                rgb, aov = out.rgb, out.aov
                cost, rays = units.per_unit(a, b, out.cost), units.per_unit(a, b, out.rays)
            else:  # a tracer of a pooled frame with no range of its own
                rgb, cost, rays = np.zeros((0, 3), np.float32), np.zeros(0, np.int64), None
                aov = None
            return UnitsResult(
                tracer=self.id,
                frame=frame,
                version=version,
                u0=a,
                u1=b,
                rgb=rgb,
                cost=cost,
                seconds=time.perf_counter() - since,
                apply_seconds=apply_seconds,
                pid=self.pid,
                node=self.node,
                incarnation=self.incarnation,
                effects=effects,
                rays=rays,
                spans=spans,
                aov=aov,
            )

        result = render_units(u0, u1, applied, apply_seconds)
        if pool is not None:
            result.more = self._drain(pool, render_units)
        return result

    @staticmethod
    def _drain(pool: tuple[str | RemotePool, int], render_units) -> list[UnitsResult] | None:
        """Claim and render chunks of the shared pool until none is left (or the pool actor
        is lost: the coordinator hands out what is left); None if the pool is a file that
        cannot be opened here."""
        where, owner = pool
        since = time.perf_counter()
        try:
            shared = LinePool.open(where) if isinstance(where, str) else where
        except OSError:  # not readable here (another user, another container)
            shared = None
        if shared is None:
            return None
        chunks = []
        with shared:
            try:
                for chunk in shared.claims(owner):
                    chunks.append(render_units(*chunk, since))  # its seconds include the claim
                    since = time.perf_counter()
            except PoolLost:
                pass
        return chunks

    def spot_check(
        self,
        envelope: SceneEnvelope,
        request: FrameRequest,
        pixels: np.ndarray,
        part_spp: np.ndarray,
        part_start: np.ndarray,
    ) -> "tuple[np.ndarray, np.ndarray] | OutOfSync":
        """Spot checks of ``pixels`` ((P, 2) y, x) of ``request``'s frame at the version
        ``envelope`` reaches: samples ``[part_start, part_start + part_spp)`` of each part's
        stream, per pixel (:func:`tracer.accuracy.spot_check.render_spot_checks`: (PARTS, P, 3)
        parts and (P,) work)."""
        out_of_sync, _ = self.reach(envelope, request.frame)
        if out_of_sync is not None:
            return out_of_sync
        compiled = self.replicas[envelope.scene].at(envelope.version)
        camera = request.camera or compiled.camera
        settings = request.settings or compiled.render
        return render_spot_checks(
            compiled, pixels, part_spp, part_start, camera, settings, request.frame, self.threads
        )

    def warm_up(self) -> dict:
        """Render one pixel of the held scene at 1 spp, so the render kernel is loaded (from
        numba's on-disk cache when another process compiled it) before the first frame.
        Returns the seconds taken, numba's cache hits and misses for the kernel, the cache
        directory, and this process's pid and node."""
        if not self.replicas:
            raise SceneError("warm_up needs a scene: send a snapshot first")
        scene = next(reversed(self.replicas.values())).current
        start = time.perf_counter()
        tiny = fmt.override(scene.camera, width=1, height=1)
        settings = fmt.override(scene.render, spp=1)
        plan = effect_plan(scene, settings)
        render_lines(scene, 0, 1, tiny, settings, threads=1, plan=plan)
        stats = chosen_kernel(settings, plan.flags).stats
        return {
            "seconds": time.perf_counter() - start,
            "cache_hits": sum(stats.cache_hits.values()),
            "cache_misses": sum(stats.cache_misses.values()),
            "cache_dir": os.environ.get("NUMBA_CACHE_DIR", ""),
            "pid": self.pid,
            "node": self.node,
        }

    def query(
        self,
        origins: np.ndarray,
        directions: np.ndarray,
        envelope: SceneEnvelope | None = None,
        t_max: float | None = None,
    ) -> "SceneHits | OutOfSync":
        """Single or batched ray queries (Bikker 7.3.6) at the version ``envelope`` reaches
        (None, or its version None: the newest held of its scene)."""
        envelope = envelope or SceneEnvelope()
        if envelope.version is None:
            replica = self.replica(envelope.scene)
            if replica is None:
                raise SceneError("query needs a scene: send a snapshot first")
            return replica.query(origins, directions, None, t_max)
        out_of_sync, _ = self.reach(envelope)
        if out_of_sync is not None:
            return out_of_sync
        return self.replicas[envelope.scene].query(origins, directions, envelope.version, t_max)

    # Introspection and test hooks ------------------------------------------------------------

    def info(self) -> TracerInfo:
        replica = next(reversed(self.replicas.values()), None)
        return TracerInfo(
            id=self.id,
            node=self.node,
            pid=self.pid,
            incarnation=self.incarnation,
            cpus=self.cpus,
            threads=self.threads,
            version=None if replica is None else replica.version,
            versions=() if replica is None else tuple(replica.versions),
            scenes={key: tuple(r.versions) for key, r in self.replicas.items()},
            cache_dir=os.environ.get("NUMBA_CACHE_DIR", str(numba_cache.cache_base())),
        )

    def set_delay(self, seconds: float) -> None:
        """Test-only: sleep ``seconds`` at the start of every later render."""
        self.delay = float(seconds)


_REMOTE = None


def remote_tracer(cpus: float, **options):
    """The Ray actor class of :class:`Tracer` with its options: ``num_cpus=cpus``, restarted
    without limit when its process dies (``max_restarts=-1``), calls never retried by Ray
    (``max_task_retries=0``: the coordinator reassigns a lost range itself). ``options``
    (e.g. ``scheduling_strategy``) override or extend these. Create an actor with
    ``remote_tracer(c).remote(tracer_id, c)``."""
    import ray

    global _REMOTE
    if _REMOTE is None:
        _REMOTE = ray.remote(Tracer)
    settings = {"num_cpus": cpus, "max_restarts": -1, "max_task_retries": 0, **options}
    return _REMOTE.options(**settings)
