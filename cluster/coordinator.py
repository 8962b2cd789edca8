"""The Brigade core (Bikker 7.3.1-7.3.4): tracer actors, frame scheduling, assembly, failures.

A :class:`Coordinator` starts tracer actors (:mod:`worker.tracer_actor`) on Ray, by default one
per node using all of that node's CPUs, and renders frames of a :class:`SceneGraph` (its own
``graph``, or any other passed per call: tracers keep replicas of a few graphs, each under the
graph's ``key``, so a service renders many scenes in turns without resending them):

1. **Schedule** (``submit_frame``): the frame is pinned to the graph's current version ``v``
   (and the state at ``v`` is kept). The frame is cut into work units (:mod:`worker.work_units`:
   whole lines, or equal spans of them when there are many tracers, so that every tracer's
   share is hundreds of units) and the balancer splits the units among the ready tracers.
   Each tracer gets one remote ``render`` call carrying the commit buffer that takes it from
   the version it will hold after its earlier calls to ``v``; a tracer with no usable scene (new,
   restarted, or further behind than the graph's log) gets the snapshot at ``v`` instead,
   ``ray.put`` once per version and shared by every tracer through the object store.
2. **Collect** (``wait_frame``): results are written into an :class:`Assembler` that accepts
   only the frame, version and ranges it assigned; the frame is done when every unit is.
   Meanwhile failures are handled (below).
3. **Learn**: the balancer observes each tracer's range, render seconds and per-unit cost.

With a dynamic tail (``cost-aware-tail``, :mod:`cluster.tail`) step 1 sends each tracer its
head and one chunk of the tail, and step 2 sends a tracer another chunk whenever one of its
results arrives, so a call is always queued behind the one it renders; the balancer then
observes every accepted range. ``Frame.idle_percent`` counts a tracer's waits between its
ranges as idle (:func:`gap_idle_percent`; Table 16's measure with one range per tracer).

With a pool the tail does not go out in calls: step 1 writes all of it into a shared pool and
every tracer's one call names the pool, so a tracer renders its head and then claims chunks
itself until none is left; its result carries the chunks (``UnitsResult.more``). When every
tracer of the frame runs on the coordinator's own Ray node the pool is a small file in shared
memory (:mod:`worker.line_pool`, claims microseconds apart; ``cost-aware``, the default, keeps
a tail only there); otherwise (or where file locks are missing), for ``cost-aware-tail``, a Ray
actor on the coordinator's node holds it (:mod:`worker.remote_pool`: a claim is one actor call,
sent while the chunk before it renders). Every claim records its owner, so the units a lost or
stalled tracer held are known. ``cost-aware-tail`` hands its tail out in calls where no pool is
allowed (``line_pool=False``, Ray Client).

``render_animation`` pipelines frames (Bikker's double buffering, 7.3.4): frame N+1's pose is
committed to the graph and its render calls are submitted while frame N renders, so each
tracer applies N+1's commits and starts N+1 as soon as it finishes N (Ray runs an actor's calls
in submission order). At most ``KEEP_VERSIONS`` (2) frames are in flight: the replicas keep
exactly the versions those frames need. The split of frame N+1 is chosen before frame N's
timings are known, so the balancers learn with one frame of lag. With a dynamic tail, N+1 is
submitted once N's tail is all handed out, so its calls queue behind N's last chunks.

Failures:

- **Lost tracer.** A call that fails because its actor died (``RayActorError``) hands the
  range's unfinished units (and the pool chunks it had claimed), split evenly, to the
  surviving ready tracers (preferring ones with
  nothing left to do in that frame). Ray restarts the actor (``max_restarts=-1``); the
  coordinator immediately queues a ``sync_snapshot`` call on it, which runs when the new process
  is up. When it answers, the tracer is ready again and gets work from the next scheduled frame.
- **Straggler.** When some ready tracer has nothing left to do in a frame while a range is still
  running, and that range has run longer than ``straggler_factor`` x its predicted time plus
  ``straggler_floor`` seconds, its unfinished units are duplicated to an idle tracer; whichever
  copy arrives first is used (the other is ignored when it arrives). The prediction is the
  frame's own measurement: median apply seconds plus units x render seconds per unit (a ratio of
  sums) of
  the ranges already finished in this frame.
- **Out of sync.** A tracer that cannot reach the frame's version answers ``OutOfSync`` with
  the version it holds; the range is resent with the commits from there, or a snapshot.
- **Stale results.** Late answers (the losing copy of a duplicate, anything of a finished
  frame) are collected and discarded; the assembler refuses results of another frame, version
  or range.
- Tracers may join (``add_tracers``; ``place_new_nodes`` starts one on each Ray node that
  joined since, in the default one-per-node mode) or leave (``remove_tracer``) between frames.

The coordinator is not thread-safe: one caller drives it.
"""

import itertools
import logging
import math
import time
from collections import OrderedDict
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import ray
from ray.exceptions import (
    ActorDiedError,
    GetTimeoutError,
    RayActorError,
    RayError,
    RayTaskError,
)
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from cluster.assembler import Assembler, runs
from cluster.balancing import DEFAULT_BALANCER, TracerReport, even_split, make_balancer
from cluster.connect import connect
from cluster.scene_graph import SceneGraph
from cluster.balancing.tail_plan import TailPlan
from tracer.accuracy.error_estimate import PARTS
from tracer.accuracy.spot_check import SpotCheck
from tracer.errors import TilerenderError
from tracer.request import FrameRequest
from tracer.scene import format as fmt
from tracer.scene.codec import encode_commit, encode_state
from tracer.scene.model import SceneState
from worker.line_pool import LinePool
from worker.line_pool import supported as line_pool_supported
from worker.line_pool import sweep as line_pool_sweep
from worker.remote_pool import REMOTE_CLAIM_SECONDS, PoolLost, RemotePool, remote_tables
from worker.replica import KEEP_VERSIONS
from worker.tracer_actor import MAX_SCENES, OutOfSync, TracerInfo, UnitsResult, remote_tracer
from worker.work_units import WorkUnits

log = logging.getLogger("tilerender.cluster")

STRAGGLER_FACTOR = 2.0
"""A range is a straggler after this many times its predicted time ..."""
STRAGGLER_FLOOR = 0.5
"""... plus this many seconds (Ray call latency and timing jitter of tiny frames)."""
MAX_ATTEMPTS = 8
"""Times a unit range may be handed out (failures, resyncs) before the frame is given up."""
START_TIMEOUT = 300.0
"""Seconds ``Coordinator()`` waits for its tracers to come up (first start may compile)."""
STALL_TIMEOUT = 600.0
"""Seconds a frame may go without any result arriving before it is given up."""
POLL_SECONDS = 0.02
PROBE_INTERVAL = 1.0
"""Least seconds between two liveness probes of a tracer that is down."""
SNAPSHOTS_KEPT = 4
COMMITS_KEPT = 4096
INLINE_COMMITS = 64 * 1024
"""Commit buffers larger than this many bytes go through the object store (put once, shared
by every tracer that needs the same buffer) instead of inside each render call."""
BUFFERS_KEPT = 8


class ClusterError(TilerenderError, RuntimeError):
    """A frame cannot be completed (no tracer left, a range failing again and again), or no
    tracer would start; ``str()`` says which."""


@dataclass(frozen=True)
class RangeReport:
    """One accepted result of a frame."""

    tracer: str
    u0: int
    u1: int
    seconds: float
    apply_seconds: float
    kind: str
    """``split`` (the balancer's; a head with a dynamic tail), ``tail`` (a chunk of the dynamic
    tail), ``reassigned`` (from a lost tracer), ``duplicate`` (of a straggler) or a resent one
    (after ``OutOfSync``), named like the range it replaced."""
    pid: int
    node: str


@dataclass
class Frame:
    """A finished frame and how it was made."""

    frame: int
    version: int
    rgb: np.ndarray
    """float32 (H, W, 3), linear radiance."""
    cost: np.ndarray
    """int64 (H,): work per line."""
    units: WorkUnits
    """How the frame was cut into work units; ``split`` and ``ranges`` count in units."""
    unit_cost: np.ndarray
    """int64 (units,): work per unit (what the balancer learns from)."""
    camera: fmt.Camera
    settings: fmt.RenderSettings
    split: list[tuple[str, int, int]]
    """The balancer's assignment: (tracer, u0, u1) in tracer order."""
    ranges: list[RangeReport]
    tracer_seconds: dict[str, float]
    """Busy seconds (applying commits plus rendering) of each tracer that delivered units."""
    idle_percent: float
    """Bikker's Table 16 measure over ``tracer_seconds``: time tracers waited for the slowest."""
    wall_seconds: float
    """From the moment the frame could start (submitted, and the previous frame done) to its
    last unit."""
    overhead_seconds: float
    """``wall_seconds`` minus the slowest tracer's busy seconds: scheduling, transfer, waits."""
    span_idle_percent: float = 0.0
    """Idle % over the wall time: ``sum_i (wall - t_i) / (T wall)`` (latency counts too)."""
    calls: int = 0
    """Render calls whose units were used (one per tracer without a dynamic tail)."""
    pooled: bool = False
    """The dynamic tail went to a shared pool (every ``tail`` range was claimed by a
    tracer within one of its calls) rather than out in calls of its own."""
    failures: int = 0
    reassigned: int = 0
    duplicates: int = 0
    resyncs: int = 0
    effects: dict | None = None
    """The effect plan the frame was rendered with (every tracer derives the same one)."""
    rays: np.ndarray | None = None
    """int64 (H,): rays traced per line (camera, continuation, shadow and occlusion)."""


@dataclass(eq=False)
class _Slot:
    """The coordinator's view of one tracer actor."""

    id: str
    handle: Any
    cpus: float
    state: str = "starting"
    """``starting``, ``warming`` (answered its snapshot, loading its kernels: a tracer placed
    on a new node), ``ready``, ``recovering`` (died; Ray restarts it), ``dead`` or
    ``retired``."""
    synced: OrderedDict[str, int] = field(default_factory=OrderedDict)
    """Per scene key, the version the tracer will hold once its submitted calls ran (the
    tracer's replicas, least recently used first, as it keeps them)."""
    probe: Any = None
    probe_at: float = 0.0
    died_probes: int = 0
    failed_at: float = -math.inf
    failures: int = 0
    last_done: float = 0.0
    """When its latest result arrived: a later call of it started no earlier."""
    pid: int | None = None
    node: str | None = None
    incarnation: str | None = None
    warm: dict | None = None
    home: str | None = None
    """The Ray node the tracer was placed on in one-tracer-per-node mode (None: spread)."""
    warming: Any = None
    """The pending ``warm_up`` call of a tracer placed on a new node."""
    pool_blind: bool = False
    """It could not open a shared pool file (until it is seen on another node)."""


@dataclass(eq=False)
class _Task:
    slot: _Slot
    u0: int
    u1: int
    kind: str
    attempt: int
    submitted: float
    duplicated: bool = False
    resent: bool = False
    """Sent again after OutOfSync (a second OutOfSync gets a snapshot)."""
    owner: int | None = None
    """The tracer's id in the frame's shared pool (None: the call takes no chunks)."""


@dataclass(eq=False)
class FrameJob:
    """A frame in flight; ``Coordinator.wait_frame`` turns it into a :class:`Frame`."""

    frame: int
    graph: SceneGraph
    state: SceneState
    camera: fmt.Camera
    settings: fmt.RenderSettings
    sample_start: int
    units: WorkUnits
    assembler: Assembler
    submitted: float
    split: list[tuple[str, int, int]] = field(default_factory=list)
    pending: dict = field(default_factory=dict)
    ranges: list[RangeReport] = field(default_factory=list)
    busy: dict[str, float] = field(default_factory=dict)
    primary: dict[str, UnitsResult] = field(default_factory=dict)
    tail: TailPlan | None = None
    """The dynamic tail's units not handed out yet (``cost-aware-tail``)."""
    pool: LinePool | RemotePool | None = None
    """The dynamic tail as a shared pool: a file when every tracer shares this machine."""
    pool_chunks: list[tuple[int, int]] = field(default_factory=list)
    """The pool's chunks, as written into it."""
    arrivals: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    """Per tracer, (arrival time, busy seconds) of each accepted result, in arrival order."""
    late_heads: dict[str, float] = field(default_factory=dict)
    """Render seconds of heads whose units a copy had delivered first (stragglers)."""
    result: Frame | None = None
    calls: int = 0
    failures: int = 0
    reassigned: int = 0
    duplicates: int = 0
    resyncs: int = 0

    @property
    def version(self) -> int:
        return self.state.version


def _held(slot: _Slot, scene: str) -> int | None:
    """The version of ``scene`` the coordinator believes ``slot`` holds (None: none)."""
    return slot.synced.get(scene)


def _hold(slot: _Slot, scene: str, version: int | None) -> None:
    """Record that ``slot`` holds ``version`` of ``scene`` (None: nothing), mirroring the
    tracer's most-recently-used order and its limit of ``MAX_SCENES``."""
    slot.synced.pop(scene, None)
    if version is not None:
        slot.synced[scene] = version
        while len(slot.synced) > MAX_SCENES:
            slot.synced.popitem(last=False)


class Coordinator:
    """Tracer actors on Ray and the frames they render. See the module docstring.

    ``tracers``: how many tracer actors (default: one per Ray node with CPUs, each using all
    of its node's CPUs). ``cpus_per_tracer``: CPUs each reserves and renders with (default: all
    of its node's, or the cluster's CPUs divided by ``tracers``; fractions are allowed, a
    tracer renders with ``max(1, floor(cpus))`` threads). ``balancer``: a name in
    ``cluster.balance.BALANCERS``. ``delays``: test-only, seconds each tracer (by index)
    sleeps before every render, to simulate slow tracers. Connects to Ray (an embedded local
    instance) if this process is not connected yet.
    """

    def __init__(
        self,
        graph: SceneGraph,
        tracers: int | None = None,
        cpus_per_tracer: float | None = None,
        balancer: str = DEFAULT_BALANCER,
        *,
        straggler_factor: float = STRAGGLER_FACTOR,
        straggler_floor: float = STRAGGLER_FLOOR,
        max_attempts: int = MAX_ATTEMPTS,
        start_timeout: float = START_TIMEOUT,
        stall_timeout: float = STALL_TIMEOUT,
        delays: Sequence[float] | None = None,
        line_pool: bool = True,
    ) -> None:
        if tracers is not None and tracers < 1:
            raise ValueError(f"tracers must be at least 1, not {tracers}")
        if cpus_per_tracer is not None and not cpus_per_tracer > 0:
            raise ValueError(f"cpus_per_tracer must be positive, not {cpus_per_tracer}")
        if straggler_factor < 1.0 or straggler_floor < 0.0:
            raise ValueError("straggler_factor must be >= 1 and straggler_floor >= 0")
        self.balancer = make_balancer(balancer)
        self.balancer_name = balancer
        self.graph = graph
        self.straggler_factor = straggler_factor
        self.straggler_floor = straggler_floor
        self.max_attempts = max_attempts
        self.start_timeout = start_timeout
        self.stall_timeout = stall_timeout
        self.line_pool = line_pool
        self.stats = {
            "frames": 0,
            "failures": 0,
            "reassigned": 0,
            "duplicates": 0,
            "resyncs": 0,
            "stale_discarded": 0,
        }
        self._slots: list[_Slot] = []
        self._numbers = itertools.count()
        self._snapshots: OrderedDict[tuple[str, int], Any] = OrderedDict()
        self._commit_blobs: OrderedDict[tuple[str, int], bytes] = OrderedDict()
        self._buffers: OrderedDict[tuple[str, int, int], Any] = OrderedDict()
        self._orphans: dict = {}
        self._last_done = 0.0
        self._pools: set[LinePool | RemotePool] = set()
        self._pool_tables = None  # the actor holding remote pools, made when first needed
        self._pool_keys = itertools.count()
        if not ray.is_initialized():
            connect()
        self._node = ray.get_runtime_context().get_node_id()
        if ray.util.client.ray.is_connected():  # Ray Client: this process is on no Ray node
            self.line_pool = False
        if self.line_pool and line_pool_supported():
            line_pool_sweep()
        self._per_node = tracers is None
        self._declined: set[str] = set()
        self._cpus_per_tracer = cpus_per_tracer
        placements = self._placements(tracers, cpus_per_tracer)
        self._default_cpus = placements[-1][0]
        delays = list(delays or [])
        try:
            slots = [
                self._start(cpus, options, delays[k] if k < len(delays) else 0.0, home)
                for k, (cpus, options, home) in enumerate(placements)
            ]
            self._wait_started(slots, self.start_timeout, require_all=False)
        except BaseException:
            self.close()
            raise

    def use_balancer(self, name: str) -> None:
        """Switch to a fresh balancer (from the next frame scheduled)."""
        self.balancer = make_balancer(name)
        self.balancer_name = name

    # Tracers ---------------------------------------------------------------------------------

    @staticmethod
    def _cpu_nodes() -> list[dict]:
        return [n for n in ray.nodes() if n.get("Alive") and n["Resources"].get("CPU", 0) > 0]

    @staticmethod
    def _node_placement(node: dict, cpus: float | None) -> tuple[float, dict, str]:
        """One tracer on ``node`` using ``cpus`` of its CPUs (default all)."""
        total, home = node["Resources"]["CPU"], node["NodeID"]
        strategy = NodeAffinitySchedulingStrategy(home, soft=True)
        return min(cpus, total) if cpus else total, {"scheduling_strategy": strategy}, home

    def _placements(
        self, tracers: int | None, cpus: float | None
    ) -> list[tuple[float, dict, str | None]]:
        """(CPUs, actor options, home node) of each tracer to start."""
        nodes = self._cpu_nodes()
        if not nodes:
            raise ClusterError("the Ray cluster has no node with CPUs")
        if tracers is None:
            return [self._node_placement(n, cpus) for n in nodes]
        if cpus is None:
            total = sum(n["Resources"]["CPU"] for n in nodes)
            cpus = max(0.01, math.floor(100 * total / tracers) / 100)
        return [(cpus, {"scheduling_strategy": "SPREAD"}, None)] * tracers

    def place_new_nodes(self) -> list[str]:
        """In one-tracer-per-node mode (``tracers`` not given), start a tracer on every live
        Ray node with CPUs that has none yet (a node that joined after the start, or came
        back); they get work from the next frame once ready. Returns their ids (none in the
        other mode)."""
        if not self._per_node:
            return []
        nodes = self._cpu_nodes()
        alive = {n["NodeID"] for n in nodes}
        for slot in self._slots:  # Ray would restart these on whichever node frees up
            if slot.state in ("starting", "recovering") and slot.home not in alive:
                log.info("tracer %s: its node %s is gone; retiring it", slot.id, slot.home)
                self.remove_tracer(slot.id, decline_node=False)
        live = ("starting", "warming", "ready", "recovering")
        homes = {s.home for s in self._slots if s.state in live} | self._declined
        started = []
        for node in nodes:
            if node["NodeID"] not in homes:
                cpus, options, home = self._node_placement(node, self._cpus_per_tracer)
                slot = self._start(cpus, options, home=home)
                slot.warming = slot.handle.warm_up.remote()  # runs after its snapshot
                log.info("tracer %s placed on new node %s", slot.id, home)
                started.append(slot.id)
        return started

    def _start(
        self, cpus: float, options: dict, delay: float = 0.0, home: str | None = None
    ) -> _Slot:
        tracer_id = f"t{next(self._numbers)}"
        handle = remote_tracer(cpus, **options).remote(tracer_id, cpus, delay)
        slot = _Slot(tracer_id, handle, cpus, home=home)
        self._slots.append(slot)
        self._send_probe(slot, time.perf_counter())
        return slot

    def _send_probe(self, slot: _Slot, now: float) -> None:
        """Queue a snapshot of the own graph's current version on the tracer: it runs as soon
        as the actor is up, and its answer says the tracer is ready."""
        state = self.graph.state
        slot.probe = slot.handle.sync_snapshot.remote(
            self._snapshot_ref(self.graph.key, state), self.graph.key
        )
        slot.probe_at = now

    def _wait_started(self, slots: list[_Slot], timeout: float, require_all: bool) -> None:
        """Wait until ``slots`` answered their first snapshot (and loaded the render kernel)."""
        deadline = time.perf_counter() + timeout
        while True:
            self._poll_slots()
            waiting = [s for s in slots if s.state in ("starting", "recovering")]
            if not waiting:
                break
            if time.perf_counter() > deadline:
                if require_all or not any(s.state == "ready" for s in self._slots):
                    names = ", ".join(s.id for s in waiting)
                    raise ClusterError(
                        f"tracers {names} did not start within {timeout:g} s "
                        "(not enough free CPUs in the Ray cluster?)"
                    )
                break
            probes = [s.probe for s in waiting if s.probe is not None]
            if probes:
                ray.wait(probes, num_returns=1, timeout=0.2)
            else:
                time.sleep(0.05)
        warm = {s.id: s.handle.warm_up.remote() for s in slots if s.state == "ready"}
        for slot in slots:
            if slot.id in warm:
                try:
                    slot.warm = ray.get(
                        warm[slot.id], timeout=max(1.0, deadline - time.perf_counter())
                    )
                    slot.pid, slot.node = slot.warm["pid"], slot.warm["node"]
                except (RayError, TimeoutError) as error:  # it will be handled when it renders
                    log.warning("tracer %s: warm-up failed: %s", slot.id, error)

    def _poll_slots(self) -> None:
        """Tracers that are starting or recovering become ready once their probe answers."""
        now = time.perf_counter()
        for slot in self._slots:
            if slot.state == "warming":
                self._poll_warm_up(slot, now)
                continue
            if slot.state not in ("starting", "recovering"):
                continue
            if slot.probe is None:
                if now - slot.probe_at >= PROBE_INTERVAL:
                    self._send_probe(slot, now)
                continue
            ready, _ = ray.wait([slot.probe], timeout=0)
            if not ready:
                continue
            probe, slot.probe = slot.probe, None
            try:
                version = ray.get(probe)
            except ActorDiedError as error:
                slot.died_probes += 1
                if slot.died_probes >= 3:
                    slot.state = "dead"
                    log.warning("tracer %s is dead: %s", slot.id, _first_line(error))
                continue
            except RayError as error:  # still restarting, or cannot be placed yet
                log.info("tracer %s not back yet: %s", slot.id, _first_line(error))
                continue
            slot.state = "warming" if slot.warming is not None else "ready"
            _hold(slot, self.graph.key, version)
            slot.died_probes = 0
            slot.last_done = now

    def _poll_warm_up(self, slot: _Slot, now: float) -> None:
        """A tracer placed on a new node becomes ready once its kernels are loaded, so its
        first range is not timed with the load (nor taken for a straggler)."""
        ready, _ = ray.wait([slot.warming], timeout=0)
        if not ready:
            return
        ref, slot.warming = slot.warming, None
        try:
            slot.warm = ray.get(ref)
            slot.pid, slot.node = slot.warm["pid"], slot.warm["node"]
        except RayError as error:  # it will be handled when it renders
            log.warning("tracer %s: warm-up failed: %s", slot.id, _first_line(error))
        slot.state = "ready"
        slot.last_done = now

    def add_tracers(
        self,
        n: int = 1,
        cpus: float | None = None,
        wait: bool = True,
        delay: float = 0.0,
        *,
        options: dict | None = None,
    ) -> list[str]:
        """Start ``n`` more tracers (``cpus`` each, default as the last one started); they get
        work from the next frame scheduled after they answer. ``wait``: return only once they
        are ready. ``delay`` is the test-only render delay. ``options``: more Ray actor options
        for these tracers (e.g. a ``runtime_env``), over ``scheduling_strategy="SPREAD"``."""
        cpus = cpus or self._default_cpus
        options = {"scheduling_strategy": "SPREAD", **(options or {})}
        slots = [self._start(cpus, options, delay) for _ in range(n)]
        if wait:
            self._wait_started(slots, self.start_timeout, require_all=True)
        return [s.id for s in slots]

    def remove_tracer(self, tracer_id: str, decline_node: bool = True) -> None:
        """Stop a tracer for good; units it still owes are handed to the others. With
        ``decline_node``, ``place_new_nodes`` leaves its node alone from now on."""
        slot = self._slot(tracer_id)
        slot.state = "retired"
        if decline_node and slot.home is not None:
            self._declined.add(slot.home)
        try:
            ray.kill(slot.handle, no_restart=True)
        except RayError:  # pragma: no cover - already gone
            pass

    def tracer_handle(self, tracer_id: str):
        """The Ray actor handle of a tracer (for tests and tools)."""
        return self._slot(tracer_id).handle

    def _slot(self, tracer_id: str) -> _Slot:
        for slot in self._slots:
            if slot.id == tracer_id:
                return slot
        raise KeyError(f"no tracer {tracer_id!r}")

    def tracers(self) -> list[dict]:
        """Every tracer the coordinator started: id, state, CPUs, synced version, pid, node,
        failures seen."""
        self._poll_slots()
        return [
            {
                "id": s.id,
                "state": s.state,
                "cpus": s.cpus,
                "threads": max(1, int(s.cpus)),
                "synced": s.synced.get(self.graph.key),
                "scenes": len(s.synced),
                "pid": s.pid,
                "node": s.node,
                "failures": s.failures,
                "warm_up": s.warm,
            }
            for s in self._slots
        ]

    def info(self, tracer_id: str, timeout: float = 30.0) -> TracerInfo:
        """Ask a tracer about itself (its process, node, CPUs, versions held)."""
        return ray.get(self._slot(tracer_id).handle.info.remote(), timeout=timeout)

    @property
    def ready(self) -> list[str]:
        self._poll_slots()
        return [s.id for s in self._slots if s.state == "ready"]

    def close(self) -> None:
        """Stop every tracer (Ray itself stays up)."""
        for slot in self._slots:
            if slot.state != "retired":
                slot.state = "retired"
                try:
                    ray.kill(slot.handle, no_restart=True)
                except RayError:  # pragma: no cover - already gone
                    pass
        self._orphans.clear()
        for pool in self._pools:
            try:
                pool.unlink()
            except RayError:  # pragma: no cover - Ray is already down
                pass
        self._pools.clear()
        if self._pool_tables is not None:
            try:
                ray.kill(self._pool_tables)
            except RayError:  # pragma: no cover - already gone
                pass
            self._pool_tables = None
        self._snapshots.clear()
        self._buffers.clear()

    def __enter__(self) -> "Coordinator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # Scene data for tracers ------------------------------------------------------------------

    def _snapshot_ref(self, scene: str, state: SceneState):
        """The encoded snapshot of ``state`` in the object store (put once per scene and
        version)."""
        key = (scene, state.version)
        ref = self._snapshots.get(key)
        if ref is None:
            ref = self._snapshots[key] = ray.put(encode_state(state))
            while len(self._snapshots) > SNAPSHOTS_KEPT:
                self._snapshots.popitem(last=False)
        return ref

    def _commits(self, graph: SceneGraph, since: int, version: int) -> list[bytes] | None:
        """Encoded commits taking a replica of ``graph`` from ``since`` to ``version``; None if
        the graph's log does not reach back that far."""
        commits = graph.commits_since(since)
        if commits is None:
            return None
        blobs = []
        for commit in commits:
            if commit.version > version:
                break
            key = (graph.key, commit.version)
            blob = self._commit_blobs.get(key)
            if blob is None:
                blob = self._commit_blobs[key] = encode_commit(commit)
                while len(self._commit_blobs) > COMMITS_KEPT:
                    self._commit_blobs.popitem(last=False)
            blobs.append(blob)
        return blobs

    def _sync_for(self, have: int | None, graph: SceneGraph, state: SceneState) -> tuple[Any, Any]:
        """(commit buffer, snapshot ref or None) for a tracer holding ``have`` of ``graph`` to
        reach ``state``. The buffer is a list of encoded commits, or the object-store reference
        of one when it is large (Ray resolves either argument to the list in the tracer)."""
        version = state.version
        if have is not None and have >= version:
            return [], None  # it should still hold the version; if not it says OutOfSync
        commits = None if have is None else self._commits(graph, have, version)
        if commits is None:
            return [], self._snapshot_ref(graph.key, state)
        if sum(len(c) for c in commits) <= INLINE_COMMITS:
            return commits, None
        key = (graph.key, have, version)
        ref = self._buffers.get(key)
        if ref is None:
            ref = self._buffers[key] = ray.put(commits)
            while len(self._buffers) > BUFFERS_KEPT:
                self._buffers.popitem(last=False)
        return ref, None

    # Scheduling ------------------------------------------------------------------------------

    def submit_frame(
        self, request: FrameRequest | None = None, graph: SceneGraph | None = None
    ) -> FrameJob:
        """Schedule ``request`` (default frame 0 as the scene sees it) at the current version
        of ``graph`` (default the coordinator's own) and send every tracer its range (with its
        commit buffer); returns at once. The request's open camera and settings are the
        scene's at that version."""
        self._drain_orphans()
        self._poll_slots()
        graph = graph or self.graph
        state = graph.state
        request = (request or FrameRequest()).resolved(state)
        frame, camera, settings = request.frame, request.camera, request.settings
        sample_start = request.sample_start
        slots = self._schedulable()
        now = time.perf_counter()
        units = WorkUnits.for_tracers(camera.width, camera.height, len(slots))
        job = FrameJob(
            frame=frame,
            graph=graph,
            state=state,
            camera=camera,
            settings=settings,
            sample_start=sample_start,
            units=units,
            assembler=Assembler(frame, state.version, units),
            submitted=now,
        )
        ids = [s.id for s in slots]
        plan = getattr(self.balancer, "plan", None)
        if plan is not None:
            local = line_pool_supported() and all(
                s.node == self._node and not s.pool_blind for s in slots
            )
            remote = getattr(self.balancer, "remote_pool", False)
            pooled = self.line_pool and len(slots) > 1 and (local or remote)
            claim = 0.0 if local else REMOTE_CLAIM_SECONDS
            job.tail = plan(units.count, ids, pooled=pooled, spans=units.spans, claim_seconds=claim)
            ranges = job.tail.heads
            if pooled and not job.tail.empty:
                self._open_pool(job, local)
        else:
            ranges = self.balancer.split(units.count, ids, spans=units.spans)
        try:
            for owner, (slot, (u0, u1)) in enumerate(zip(slots, ranges, strict=True)):
                job.split.append((slot.id, u0, u1))
                if job.pool is not None:  # every tracer claims chunks, with or without a head
                    self._submit(job, slot, u0, u1, "split", 1, owner=owner)
                elif u1 > u0:
                    self._submit(job, slot, u0, u1, "split", 1)
            for slot in slots:  # one chunk queued behind every head
                self._feed(job, slot)
        except BaseException:
            self._abandon(job)
            raise
        return job

    def _open_pool(self, job: FrameJob, local: bool) -> None:
        """Move ``job``'s whole tail into a shared pool its tracers claim from: a file when
        they all share this machine (``local``), else a table in the pool actor."""
        chunks = job.pool_chunks = job.tail.take_all()
        if local:
            job.pool = LinePool.create(chunks)
        else:
            if self._pool_tables is None:
                self._pool_tables = remote_tables(self._node)
                ray.get(self._pool_tables.rows.remote(-1))  # up before tracers claim from it
            job.pool = RemotePool.create(self._pool_tables, chunks, next(self._pool_keys))
        self._pools.add(job.pool)
        for u0, u1 in chunks:
            job.assembler.assign(u0, u1)

    def _close_pool(self, job: FrameJob) -> None:
        if job.pool is not None:
            job.pool.unlink()
            self._pools.discard(job.pool)

    def _release_pool(self, job: FrameJob) -> None:
        """When no pooled call is left to claim them (a tracer could not open the pool, or died
        before it was empty, or the pool actor was lost), hand the pool's units that nothing
        delivered or owes out in calls of their own (without asking the pool: every chunk is
        claimed or unclaimed by now, and the answer would be an actor call)."""
        if job.pool is None or any(t.owner is not None for t in job.pending.values()):
            return
        owed = np.zeros(job.units.count, bool)
        for task in job.pending.values():
            owed[task.u0 : task.u1] = True
        left = [
            run
            for u0, u1 in job.pool_chunks
            for a, b in job.assembler.missing(u0, u1)
            for run in runs(~owed[a:b], offset=a)
        ]
        if left:  # not the normal end of a frame: is the pool still there?
            try:
                job.pool.unclaimed()
            except PoolLost as error:
                self._lose_pool(error)
        for u0, u1 in left:
            self._reassign(job, u0, u1, None, 1)

    def _owed(self, job: FrameJob, task: _Task) -> list[tuple[int, int]]:
        """The unit ranges ``task`` may deliver: its own range and the pool chunks it claimed
        (none known when the pool actor is lost: ``_release_pool`` hands those out)."""
        own = [(task.u0, task.u1)] if task.u1 > task.u0 else []
        if task.owner is None or job.pool is None:
            return own
        try:
            return own + job.pool.claimed(task.owner)
        except PoolLost as error:
            self._lose_pool(error)
            return own

    def _lose_pool(self, error: Exception) -> None:
        """The pool actor is gone (its node's memory monitor, say): the next pooled frame
        starts a new one."""
        log.warning("the pool actor is lost: %s", _first_line(error))
        self._pool_tables = None

    def _feed(self, job: FrameJob, slot: _Slot) -> None:
        """Send ``slot`` the next chunk of ``job``'s dynamic tail, if any is left."""
        if job.tail is None or job.tail.empty or slot.state != "ready":
            return
        chunk = job.tail.next_chunk(slot.id)
        if chunk is not None:
            self._submit(job, slot, *chunk, "tail", 1)

    def _feed_idle(self, job: FrameJob) -> None:
        """Ready tracers with nothing left in ``job`` (back from a failure, or whose calls
        failed) take chunks of its tail."""
        if job.tail is None or job.tail.empty:
            return
        busy = {t.slot.id for t in (*job.pending.values(), *self._orphans.values())}
        for slot in self._slots:
            if slot.state == "ready" and slot.id not in busy:
                self._feed(job, slot)
                self._feed(job, slot)  # and one queued behind it

    def _schedulable(self) -> list[_Slot]:
        """Ready tracers, waiting for one if there is none yet; tracers still busy with
        results nobody needs (a straggler's stale range) sit this frame out if others can."""
        deadline = time.perf_counter() + self.start_timeout
        while True:
            ready = [s for s in self._slots if s.state == "ready"]
            if ready:
                busy = {task.slot.id for task in self._orphans.values()}
                free = [s for s in ready if s.id not in busy]
                return free or ready
            if not any(s.state in ("starting", "warming", "recovering") for s in self._slots):
                raise ClusterError("no tracer is left to render with")
            if time.perf_counter() > deadline:
                raise ClusterError(f"no tracer became ready within {self.start_timeout:g} s")
            probes = [s.probe for s in self._slots if s.probe is not None]
            if probes:
                ray.wait(probes, num_returns=1, timeout=0.2)
            else:
                time.sleep(0.05)
            self._poll_slots()

    def _submit(
        self,
        job: FrameJob,
        slot: _Slot,
        u0: int,
        u1: int,
        kind: str,
        attempt: int,
        sync: tuple[Any, Any] | None = None,
        owner: int | None = None,
    ) -> _Task:
        scene = job.graph.key
        have = _held(slot, scene)
        commits, snapshot = sync if sync is not None else self._sync_for(have, job.graph, job.state)
        ref = slot.handle.render.remote(
            job.frame,
            job.version,
            commits,
            job.camera,
            job.settings,
            u0,
            u1,
            job.sample_start,
            snapshot,
            scene,
            pool=None if owner is None else (job.pool.ticket, owner),
            spans=job.units.spans,
        )
        if snapshot is not None:
            _hold(slot, scene, job.version)
        elif have is not None:  # the commits (if any) take it to the version
            _hold(slot, scene, max(have, job.version))
        if u1 > u0:
            job.assembler.assign(u0, u1)
        task = job.pending[ref] = _Task(slot, u0, u1, kind, attempt, time.perf_counter())
        task.owner = owner
        return task

    # Collecting ------------------------------------------------------------------------------

    def wait_frame(self, job: FrameJob) -> Frame:
        """Collect ``job``'s units, surviving lost tracers and stragglers; returns the frame."""
        if job.result is not None:
            return job.result
        try:
            self._collect(job)
        except BaseException:
            self._abandon(job)
            raise
        return self._finish(job)

    def _collect(self, job: FrameJob) -> None:
        last_progress = time.perf_counter()
        while not job.assembler.complete:
            self._feed_idle(job)
            if not job.pending:
                if job.tail is not None:
                    job.tail.drain()  # nobody can take chunks: the units are reassigned
                for u0, u1 in job.assembler.missing():  # defensive: nothing owes these units
                    self._reassign(job, u0, u1, None, self.max_attempts)
            refs = list(job.pending)
            ready, _ = ray.wait(refs, num_returns=1, timeout=POLL_SECONDS)
            if ready:
                ready, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
                for ref in ready:
                    self._handle(job, ref)
                last_progress = time.perf_counter()
            elif time.perf_counter() - last_progress > self.stall_timeout:
                raise ClusterError(
                    f"frame {job.frame}: no tracer answered for {self.stall_timeout:g} s"
                )
            self._poll_slots()
            if not job.assembler.complete:
                self._check_stragglers(job)

    def _abandon(self, job: FrameJob) -> None:
        """Give ``job`` up (an error, or its caller stopped): its late answers are discarded
        on arrival and its pool is removed."""
        self._orphans.update(job.pending)
        job.pending.clear()
        self._close_pool(job)

    def render_frame(
        self, request: FrameRequest | None = None, graph: SceneGraph | None = None
    ) -> Frame:
        """Render one frame at the current version of ``graph`` (default the own graph)."""
        return self.wait_frame(self.submit_frame(request, graph))

    def render_animation(
        self,
        frames: Iterable[int] | None = None,
        request: FrameRequest | None = None,
        pipeline: int = KEEP_VERSIONS,
    ) -> Iterator[Frame]:
        """Yield the frames of the scene's animation (default all of them), in order, each as
        ``request`` with its frame number (default the scene's camera and settings). Before
        frame N is scheduled its pose is committed (``SceneGraph.frame_commit``); up to
        ``pipeline`` frames are in flight (at most ``KEEP_VERSIONS``), so frame N+1's commits
        reach the tracers while frame N renders."""
        if frames is None:
            animation = self.graph.state.animation
            frames = range(animation.frames if animation is not None else 1)
        depth = max(1, min(pipeline, KEEP_VERSIONS))
        request = request or FrameRequest()
        upcoming = iter(frames)
        in_flight: list[FrameJob] = []

        def schedule_next() -> None:
            number = next(upcoming, None)
            if number is not None:
                self.graph.frame_commit(number)
                in_flight.append(self.submit_frame(replace(request, frame=number)))

        def top_up() -> None:
            """Submit frames until ``depth`` are in flight (each after the one before it has
            handed out its whole dynamic tail, so its calls queue behind that tail)."""
            while len(in_flight) < depth:
                if in_flight:
                    self._wait_dispatched(in_flight[-1])
                before = len(in_flight)
                schedule_next()
                if len(in_flight) == before:
                    return  # no frames left

        try:
            top_up()
            while in_flight:
                done = self.wait_frame(in_flight.pop(0))
                top_up()  # N+2 is submitted before N is handed to the caller
                yield done
        finally:  # an error, or the caller stopped early: frames still in flight are dropped
            for job in in_flight:
                self._abandon(job)

    def _wait_dispatched(self, job: FrameJob) -> None:
        """Collect ``job``'s results until its dynamic tail is all handed out (at once without
        a tail), so the next frame's calls queue behind its last chunks rather than before
        them (Ray runs an actor's calls in order)."""
        last_progress = time.perf_counter()
        while job.tail is not None and not job.tail.empty and not job.assembler.complete:
            refs = list(job.pending)
            if not refs:
                return  # wait_frame hands the units out
            ready, _ = ray.wait(refs, num_returns=1, timeout=POLL_SECONDS)
            for ref in ready:
                self._handle(job, ref)
                last_progress = time.perf_counter()
            if time.perf_counter() - last_progress > self.stall_timeout:
                return  # wait_frame reports the stall
            self._poll_slots()
            self._feed_idle(job)

    def _handle(self, job: FrameJob, ref) -> None:
        task = job.pending.pop(ref)
        slot = task.slot
        try:
            out = ray.get(ref)
        except RayTaskError as error:  # an exception inside the tracer: try elsewhere
            # (first: an error the tracer met, e.g. from another actor, is a RayTaskError that
            # is also a RayActorError, and the tracer itself is alive)
            log.warning("tracer %s failed on frame %d: %s", slot.id, job.frame, _first_line(error))
            job.failures += 1
            self._recover(job, task, error)
            return
        except RayActorError as error:
            if task.submitted >= slot.failed_at:
                self._tracer_failed(slot, error)
            job.failures += 1
            self._recover(job, task, error)
            return
        now = time.perf_counter()
        slot.last_done = now
        if isinstance(out, OutOfSync):
            _hold(slot, out.scene, out.have)
            slot.incarnation = out.incarnation
            job.resyncs += 1
            if task.attempt >= self.max_attempts:
                raise ClusterError(
                    f"tracer {slot.id} cannot reach version {job.version}: {out.reason}"
                )
            if task.owner is None and not job.assembler.missing(task.u0, task.u1):
                return
            if out.have is None or out.have >= job.version or task.resent:
                # it cannot get there by commits
                sync = ([], self._snapshot_ref(job.graph.key, job.state))
            else:
                sync = self._sync_for(out.have, job.graph, job.state)
            again = self._submit(
                job, slot, task.u0, task.u1, task.kind, task.attempt + 1, sync, task.owner
            )
            again.resent = True
            return
        if out.node != slot.node:
            slot.pool_blind = False
        slot.pid, slot.node, slot.incarnation = out.pid, out.node, out.incarnation
        # The next chunk queues while this tracer works on its last (after an OutOfSync answer
        # the resend above keeps it busy, and the chunk waits until the tracer is in sync).
        self._feed(job, slot)
        if task.owner is not None and out.more is None:
            log.warning("tracer %s cannot open the frame's pool file", slot.id)
            slot.pool_blind = True
        busy = 0.0
        for part, kind in [(out, task.kind), *((chunk, "tail") for chunk in out.more or ())]:
            if part.u1 == part.u0:  # a pooled call without a range of its own
                busy += part.seconds + part.apply_seconds
                continue
            if job.assembler.accept(part) <= 0:  # refused (-1), or units another copy delivered
                if kind == "split" and part.frame == job.frame:
                    job.late_heads[slot.id] = part.seconds
                continue
            job.ranges.append(
                RangeReport(
                    slot.id,
                    part.u0,
                    part.u1,
                    part.seconds,
                    part.apply_seconds,
                    kind,
                    part.pid,
                    part.node,
                )
            )
            busy += part.seconds + part.apply_seconds
            if kind == "split":
                job.primary[slot.id] = part
        self._release_pool(job)
        if busy > 0.0:
            job.calls += 1
            job.busy[slot.id] = job.busy.get(slot.id, 0.0) + busy
            job.arrivals.setdefault(slot.id, []).append((now, busy))

    def _tracer_failed(self, slot: _Slot, error: Exception) -> None:
        """A call failed because the tracer's process died: Ray restarts it; queue a snapshot so
        it is resynced (and known to be back) as soon as it is up."""
        if slot.state in ("retired", "dead"):
            return
        now = time.perf_counter()
        log.warning("tracer %s lost: %s", slot.id, _first_line(error))
        slot.state = "recovering"
        slot.synced.clear()
        slot.failed_at = now
        slot.failures += 1
        self.stats["failures"] += 1
        self._send_probe(slot, now)

    def _recover(self, job: FrameJob, task: _Task, error: Exception) -> None:
        """Hand the failed task's unfinished units, not owed by another call, to others."""
        owed = np.zeros(job.units.count, bool)
        for other in job.pending.values():
            for u0, u1 in self._owed(job, other):
                owed[u0:u1] = True
        if job.pool is not None and any(t.owner is not None for t in job.pending.values()):
            try:
                unclaimed = job.pool.unclaimed()  # a pooled call still running claims them
            except PoolLost as error:
                self._lose_pool(error)
                unclaimed = []
            for u0, u1 in unclaimed:
                owed[u0:u1] = True
        mine = np.zeros(job.units.count, bool)
        for u0, u1 in self._owed(job, task):
            mine[u0:u1] = True
        todo = mine & ~job.assembler.done & ~owed
        for u0, u1 in runs(todo):
            if task.attempt >= self.max_attempts:
                raise ClusterError(
                    f"frame {job.frame}: units [{u0}, {u1}) failed {task.attempt} times; last: "
                    f"{_first_line(error)}"
                )
            self._reassign(job, u0, u1, task.slot, task.attempt)
        self._release_pool(job)

    def _reassign(
        self, job: FrameJob, u0: int, u1: int, failed: _Slot | None, attempt: int
    ) -> None:
        """Split units [u0, u1) evenly among the tracers that can take them."""
        self._poll_slots()
        ready = [s for s in self._slots if s.state == "ready" and s is not failed]
        busy = {t.slot.id for t in job.pending.values()}
        targets = [s for s in ready if s.id not in busy] or ready
        if not targets:  # nobody ready: queue on tracers that are coming back
            targets = [s for s in self._slots if s.state in ("starting", "warming", "recovering")]
        if not targets:
            raise ClusterError(f"frame {job.frame}: no tracer is left to render with")
        pieces = even_split(u1 - u0, min(len(targets), u1 - u0))
        for slot, (a, b) in zip(targets, pieces, strict=False):
            if b > a:
                self._submit(job, slot, u0 + a, u0 + b, "reassigned", attempt + 1)
        job.reassigned += 1

    def _check_stragglers(self, job: FrameJob) -> None:
        """Duplicate a range that runs far longer than predicted to a tracer that is idle."""
        if not job.ranges:
            return
        busy = {t.slot.id for t in job.pending.values()}
        idle = [s for s in self._slots if s.state == "ready" and s.id not in busy]
        if not idle:
            return
        # Seconds per unit over everything delivered (a ratio of sums: chunks of the tail are
        # cheap units, heads dear ones), apply seconds of calls (chunks apply nothing).
        per_unit = sum(r.seconds for r in job.ranges) / sum(r.u1 - r.u0 for r in job.ranges)
        calls = [r.apply_seconds for r in job.ranges if r.kind != "tail"]
        apply = float(np.median(calls)) if calls else 0.0
        now = time.perf_counter()
        running: set[str] = set()  # tracers whose first pending call (the one running) is seen
        stuck: set[str] = set()  # tracers whose running call is a straggler
        for task in list(job.pending.values()):  # in submission order
            if not idle:
                break
            tracer, queued = task.slot.id, task.slot.id in running
            running.add(tracer)
            if queued and tracer not in stuck:
                continue  # behind a call that is on time: it has not started yet
            if task.duplicated or task.kind == "duplicate":
                if task.duplicated:
                    stuck.add(tracer)
                continue
            started = max(task.submitted, task.slot.last_done)
            owed = None  # asked of a remote pool only when needed: it is an actor call
            if task.owner is not None and job.busy:  # pooled calls end together
                predicted = max(job.busy.values())
            else:
                owed = self._owed(job, task)
                predicted = apply + per_unit * sum(u1 - u0 for u0, u1 in owed)
            late = now - started > self.straggler_factor * predicted + self.straggler_floor
            if not (queued or late):  # a call queued behind a straggler waits as long as it
                continue
            stuck.add(tracer)
            owed = self._owed(job, task) if owed is None else owed
            missing = [run for u0, u1 in owed for run in job.assembler.missing(u0, u1)]
            if not missing:
                continue
            target = idle.pop(0)
            log.info(
                "frame %d: tracer %s ran units [%d, %d) for %.2f s (predicted %.2f s): "
                "duplicating to %s",
                job.frame, task.slot.id, task.u0, task.u1, now - started, predicted, target.id,
            )  # fmt: skip
            for u0, u1 in missing:
                self._submit(job, target, u0, u1, "duplicate", task.attempt)
            task.duplicated = True
            job.duplicates += 1

    def _finish(self, job: FrameJob) -> Frame:
        now = time.perf_counter()
        self._abandon(job)  # losing copies and the like: discarded on arrival
        start = max(job.submitted, self._last_done)
        self._last_done = now
        busy = job.busy
        slowest = max(busy.values(), default=0.0)
        wall = now - start
        span = [max(0.0, wall - min(t, wall)) for t in busy.values()]
        frame = Frame(
            frame=job.frame,
            version=job.version,
            rgb=job.assembler.rgb,
            cost=job.assembler.line_cost(),
            units=job.units,
            unit_cost=job.assembler.cost,
            rays=job.assembler.line_rays(),
            camera=job.camera,
            settings=job.settings,
            split=list(job.split),
            ranges=sorted(job.ranges, key=lambda r: r.u0),
            tracer_seconds=dict(busy),
            idle_percent=gap_idle_percent(job.arrivals),
            wall_seconds=wall,
            overhead_seconds=max(0.0, wall - slowest),
            span_idle_percent=100 * sum(span) / (len(span) * wall) if span and wall > 0 else 0.0,
            calls=job.calls,
            pooled=job.pool is not None,
            failures=job.failures,
            reassigned=job.reassigned,
            duplicates=job.duplicates,
            resyncs=job.resyncs,
            effects=next((r.effects for r in job.primary.values()), None),
        )
        self._observe(job, now)
        job.result = frame
        self.stats["frames"] += 1
        for key in ("reassigned", "duplicates", "resyncs"):
            self.stats[key] += getattr(job, key)
        return frame

    def _observe(self, job: FrameJob, now: float) -> None:
        """Tell the balancer what each tracer of the split did (the balancer's lines are the
        frame's work units). A straggler whose units came from a duplicate reports the time it
        had run (a lower bound); a lost tracer reports nothing (the balancer keeps its
        prediction for those units)."""
        if job.tail is not None:
            self._observe_tail(job, now)
            return
        reports = []
        for tracer_id, u0, u1 in job.split:
            result = job.primary.get(tracer_id)
            if u1 == u0:
                reports.append(TracerReport(tracer_id, u0, u1, 0.0, np.zeros(0, np.int64)))
            elif result is not None:
                reports.append(TracerReport(tracer_id, u0, u1, result.seconds, result.cost))
        reports += self._stalled_reports(job, now)
        if reports:
            self.balancer.observe(job.units.count, reports, spans=job.units.spans)

    def _observe_tail(self, job: FrameJob, now: float) -> None:
        """Tell a dynamic-tail balancer every accepted range: heads and chunks with their
        render seconds, units of copies and reassignments with none (NaN: cost only). A
        straggler whose head came from a copy reports the time it had run on it (a lower
        bound), as without a tail."""
        reports = [
            TracerReport(
                r.tracer,
                r.u0,
                r.u1,
                r.seconds if r.kind in ("split", "tail") else math.nan,
                job.assembler.cost[r.u0 : r.u1].copy(),
            )
            for r in job.ranges
        ]
        reports += self._stalled_reports(job, now)
        if reports:
            self.balancer.observe(job.units.count, reports, spans=job.units.spans)

    def _stalled_reports(self, job: FrameJob, now: float) -> list[TracerReport]:
        """Stragglers of ``job``'s split whose units a copy delivered, each with the time it
        had run (a lower bound); a lost tracer reports nothing."""
        by_id = {s.id: s for s in self._slots}
        reports = []
        for tracer_id, u0, u1 in job.split:
            slot = by_id.get(tracer_id)
            if u1 > u0 and tracer_id not in job.primary and slot and slot.state == "ready":
                seconds = job.late_heads.get(tracer_id)
                if seconds is None:  # still running: the time it has run so far
                    seconds = now - max(job.submitted, slot.last_done)
                reports.append(
                    TracerReport(tracer_id, u0, u1, seconds, job.assembler.cost[u0:u1].copy())
                )
        return reports

    def _drain_orphans(self) -> None:
        """Collect late answers of finished frames and discard them (failures still count)."""
        if not self._orphans:
            return
        refs = list(self._orphans)
        ready, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
        for ref in ready:
            task = self._orphans.pop(ref)
            try:
                ray.get(ref)
            except RayTaskError:
                continue
            except RayActorError as error:
                if task.submitted >= task.slot.failed_at:
                    self._tracer_failed(task.slot, error)
                continue
            task.slot.last_done = time.perf_counter()
            self.stats["stale_discarded"] += 1

    # Queries ---------------------------------------------------------------------------------

    def query(
        self,
        origins,
        directions,
        t_max: float | None = None,
        graph: SceneGraph | None = None,
        timeout: float = 60.0,
    ) -> tuple[int, Any]:
        """Ray queries (Bikker 7.3.6) at the current version of ``graph`` (default the own
        graph) on a ready tracer, which first reaches that version like a render call. Returns
        ``(version, tracer.geometry.query.SceneHits)``."""
        graph = graph or self.graph
        state = graph.state
        origins, directions = np.asarray(origins, float), np.asarray(directions, float)
        slot = self._schedulable()[0]

        def call(commits, snapshot):
            return slot.handle.query.remote(
                origins, directions, state.version, t_max, graph.key, commits, snapshot
            )

        out = self._synced_calls(graph, state, [(slot, call)], timeout)[0]
        if isinstance(out, BaseException):
            raise out
        return state.version, out

    def render_spot_checks(
        self,
        checks: SpotCheck,
        request: FrameRequest | None = None,
        graph: SceneGraph | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A progressive frame's spot checks (``tracer.accuracy.spot_check``) of ``request`` at the
        current version of ``graph``, shared out over the ready tracers. Returns ``(pixels,
        parts, work)``: the pixels checked, their (PARTS, P', 3) parts and (P',) work. A
        tracer that fails its share, or has not answered after ``stall_timeout``, drops those
        pixels (the estimate then reads them from the render's own parts) rather than the
        frame."""
        graph = graph or self.graph
        state = graph.state
        request = (request or FrameRequest()).resolved(state)
        frame, camera, settings = request.frame, request.camera, request.settings
        slots = self._schedulable()
        shares = [(s, np.arange(k, len(checks.pixels), len(slots))) for k, s in enumerate(slots)]
        shares = [(s, rows) for s, rows in shares if len(rows)]

        def checker(slot: _Slot, rows: np.ndarray):
            def call(commits, snapshot):
                return slot.handle.spot_check.remote(
                    frame,
                    state.version,
                    commits,
                    camera,
                    settings,
                    checks.pixels[rows],
                    checks.part_spp[rows],
                    checks.part_start[rows],
                    snapshot,
                    graph.key,
                )

            return call

        calls = [(s, checker(s, rows)) for s, rows in shares]
        outs = self._synced_calls(graph, state, calls, self.stall_timeout)
        kept, parts = [np.zeros((0, 2), np.int64)], [np.zeros((PARTS, 0, 3))]
        work = [np.zeros(0, np.int64)]
        for (slot, rows), out in zip(shares, outs, strict=True):
            if isinstance(out, BaseException):
                log.warning("spot checks on %s failed: %s", slot.id, _first_line(out))
                continue
            kept.append(checks.pixels[rows])
            parts.append(out[0])
            work.append(out[1])
        return np.concatenate(kept), np.concatenate(parts, axis=1), np.concatenate(work)

    def _synced_calls(
        self, graph: SceneGraph, state: SceneState, calls: list, timeout: float
    ) -> list[Any]:
        """Run ``(slot, call)`` pairs, all in flight at once: ``call(commits, snapshot)`` is an
        actor call that first reaches ``state`` of ``graph``; a tracer that answers
        :class:`OutOfSync` is asked once more with a snapshot. Within ``timeout`` seconds for
        them all, retries included; a call not done by then is cancelled (if still queued: a
        running one finishes, and its result is dropped). Per call, its result, or the error
        (a ``ClusterError`` or Ray's) that ended it."""
        deadline = time.perf_counter() + timeout
        pending = []
        for slot, call in calls:
            have = _held(slot, graph.key)
            commits, snapshot = self._sync_for(have, graph, state)
            pending.append((slot, call, have, call(commits, snapshot)))
        results = []
        for slot, call, have, ref in pending:
            try:
                out = _get_by(ref, deadline)
                if isinstance(out, OutOfSync):
                    _hold(slot, graph.key, out.have)
                    ref = call([], self._snapshot_ref(graph.key, state))
                    out = _get_by(ref, deadline)
                if isinstance(out, OutOfSync):
                    _hold(slot, graph.key, out.have)
                    raise ClusterError(
                        f"tracer {slot.id} cannot reach version {state.version}: {out.reason}"
                    )
                _hold(slot, graph.key, max(have or 0, state.version))
            except (ClusterError, RayError) as error:
                out = error
            results.append(out)
        return results


def _get_by(ref, deadline: float) -> Any:
    """``ray.get`` of ``ref`` by ``deadline`` (a ``perf_counter`` time); a call not done by
    then is cancelled (Ray drops it if still queued) and raises ``GetTimeoutError``."""
    try:
        return ray.get(ref, timeout=max(0.0, deadline - time.perf_counter()))
    except GetTimeoutError:
        ray.cancel(ref)
        raise


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def gap_idle_percent(arrivals: dict[str, list[tuple[float, float]]]) -> float:
    """Table 16's idle % with several ranges per tracer: a tracer's window runs from the start
    of its first range to the end of its last, and waiting between its ranges counts as idle.
    ``arrivals`` holds, per tracer, (arrival time, busy seconds) of its results in arrival
    order; the gap before a range is its arrival minus the previous arrival minus its busy
    seconds (the return latency cancels). With one range per tracer this is exactly
    ``idle_percent`` of the busy seconds."""
    if not arrivals:
        return 0.0
    busy, windows = [], []
    for results in arrivals.values():
        total = sum(seconds for _, seconds in results)
        gaps = sum(
            max(0.0, (at - before) - seconds)
            for (before, _), (at, seconds) in itertools.pairwise(results)
        )
        busy.append(total)
        windows.append(total + gaps)
    longest = max(windows)
    if longest <= 0.0:
        return 0.0
    return 100.0 * sum(longest - b for b in busy) / (len(busy) * longest)
