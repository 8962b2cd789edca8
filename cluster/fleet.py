"""The tracer fleet: starting tracer actors where they belong, knowing when each is ready,
and restarting, adding and removing them.

By default one tracer runs per Ray node with CPUs, using all of that node's CPUs
(``place_new_nodes`` starts one on each node that joined since); with a tracer count they
are spread. A tracer is ready once it answered its probe, a snapshot of the coordinator's own
graph queued on it when it starts or restarts (Ray restarts a dead actor, ``max_restarts=-1``);
one placed on a new node then loads its kernels (``warm_up``) before it gets work.

A tracer whose process dies while it has no call in flight is noticed without a render: the
view of the fleet (:meth:`Fleet.tracers`) asks Ray's GCS, at most every ``LIVENESS_INTERVAL``
seconds, which actors are not alive or were restarted since they were seen ready, and treats
those as a failed call would (``recovering`` until its probe answers).
"""

import itertools
import logging
import math
import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import ray
from ray._private import state as ray_state
from ray.exceptions import ActorDiedError, RayError
from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

from cluster.errors import ClusterError
from cluster.scene_graph import SceneGraph
from cluster.scene_sync import SceneSync, hold
from worker.tracer_actor import TracerInfo, remote_tracer

log = logging.getLogger("tilerender.cluster")

PROBE_INTERVAL = 1.0
"""Least seconds between two liveness probes of a tracer that is down."""
LIVENESS_INTERVAL = 0.5
"""Least seconds between two looks at the GCS's actor table for tracers that died idle."""
COMING = ("starting", "warming", "recovering")
"""States of a tracer that will be ready without being asked."""


@dataclass(eq=False)
class TracerSlot:
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
    seen: tuple[int, str] | None = None
    """(pid, node) of the process that answered last (warm-up or a result)."""
    warm: dict | None = None
    home: str | None = None
    """The Ray node the tracer was placed on in one-tracer-per-node mode (None: spread)."""
    warming: Any = None
    """The pending ``warm_up`` call of a tracer placed on a new node."""
    pool_blind: bool = False
    """It could not open a shared pool file (until it is seen on another node)."""
    restarts: int | None = None
    """How often Ray had restarted the actor when it was first seen ready (None: not yet)."""

    @property
    def pid(self) -> int | None:
        return None if self.seen is None else self.seen[0]

    @property
    def node(self) -> str | None:
        return None if self.seen is None else self.seen[1]


class Fleet:
    """The tracers of one coordinator, probed with snapshots of ``graph``."""

    def __init__(
        self,
        graph: SceneGraph,
        sync: SceneSync,
        tracers: int | None,
        cpus_per_tracer: float | None,
        start_timeout: float,
        delays: Sequence[float] | None,
    ) -> None:
        self.graph = graph
        self.sync = sync
        self.start_timeout = start_timeout
        self.slots: list[TracerSlot] = []
        self._numbers = itertools.count()
        self._per_node = tracers is None
        self._declined: set[str] = set()
        self._cpus_per_tracer = cpus_per_tracer
        self._liveness_at = -math.inf
        placements = self._placements(tracers, cpus_per_tracer)
        self._default_cpus = placements[-1][0]
        delays = list(delays or [])
        try:
            slots = [
                self._start(cpus, options, delays[k] if k < len(delays) else 0.0, home)
                for k, (cpus, options, home) in enumerate(placements)
            ]
            self.wait_started(slots, require_all=False)
        except BaseException:
            self.close()
            raise

    # Placement -------------------------------------------------------------------------------

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
        """Start a tracer on every live CPU node without one (one-tracer-per-node mode)."""
        if not self._per_node:
            return []
        nodes = self._cpu_nodes()
        alive = {n["NodeID"] for n in nodes}
        for slot in self.slots:  # Ray would restart these on whichever node frees up
            if slot.state in ("starting", "recovering") and slot.home not in alive:
                log.info("tracer %s: its node %s is gone; retiring it", slot.id, slot.home)
                self.remove(slot.id, decline_node=False)
        live = ("starting", "warming", "ready", "recovering")
        homes = {s.home for s in self.slots if s.state in live} | self._declined
        started = []
        for node in nodes:
            if node["NodeID"] not in homes:
                cpus, options, home = self._node_placement(node, self._cpus_per_tracer)
                slot = self._start(cpus, options, home=home)
                slot.warming = slot.handle.warm_up.remote()  # runs after its snapshot
                log.info("tracer %s placed on new node %s", slot.id, home)
                started.append(slot.id)
        return started

    def add(self, n: int, cpus: float | None, wait: bool, delay: float, options: dict) -> list[str]:
        """Start ``n`` more tracers (``cpus`` each, default as the last one started)."""
        cpus = cpus or self._default_cpus
        options = {"scheduling_strategy": "SPREAD", **options}
        slots = [self._start(cpus, options, delay) for _ in range(n)]
        if wait:
            self.wait_started(slots, require_all=True)
        return [s.id for s in slots]

    def remove(self, tracer_id: str, decline_node: bool = True) -> None:
        """Stop a tracer for good; with ``decline_node`` its node gets no new one."""
        slot = self.slot(tracer_id)
        slot.state = "retired"
        if decline_node and slot.home is not None:
            self._declined.add(slot.home)
        _kill(slot.handle)

    def _start(
        self, cpus: float, options: dict, delay: float = 0.0, home: str | None = None
    ) -> TracerSlot:
        tracer_id = f"t{next(self._numbers)}"
        handle = remote_tracer(cpus, **options).remote(tracer_id, cpus, delay)
        slot = TracerSlot(tracer_id, handle, cpus, home=home)
        self.slots.append(slot)
        self._send_probe(slot, time.perf_counter())
        return slot

    # Liveness --------------------------------------------------------------------------------

    def _send_probe(self, slot: TracerSlot, now: float) -> None:
        """Queue a snapshot of the own graph's current version on the tracer: it runs as soon
        as the actor is up, and its answer says the tracer is ready."""
        envelope = self.sync.snapshot(self.graph, self.graph.state)
        slot.probe = slot.handle.sync_snapshot.remote(envelope.snapshot, envelope.scene)
        slot.probe_at = now

    def wait_started(self, slots: list[TracerSlot], require_all: bool) -> None:
        """Wait until ``slots`` answered their first snapshot (and loaded the render kernel)."""
        timeout = self.start_timeout
        deadline = time.perf_counter() + timeout
        while True:
            self.poll()
            waiting = [s for s in slots if s.state in ("starting", "recovering")]
            if not waiting:
                break
            if time.perf_counter() > deadline:
                if require_all or not any(s.state == "ready" for s in self.slots):
                    names = ", ".join(s.id for s in waiting)
                    raise ClusterError(
                        f"tracers {names} did not start within {timeout:g} s "
                        "(not enough free CPUs in the Ray cluster?)"
                    )
                break
            self._wait_probes(waiting)
        warm = {s.id: s.handle.warm_up.remote() for s in slots if s.state == "ready"}
        for slot in slots:
            if slot.id in warm:
                try:
                    left = max(1.0, deadline - time.perf_counter())
                    self._warmed(slot, ray.get(warm[slot.id], timeout=left))
                except (RayError, TimeoutError) as error:  # it will be handled when it renders
                    log.warning("tracer %s: warm-up failed: %s", slot.id, error)

    @staticmethod
    def _warmed(slot: TracerSlot, warm: dict) -> None:
        slot.warm = warm
        slot.seen = (warm["pid"], warm["node"])

    def _wait_probes(self, slots: list[TracerSlot]) -> None:
        """Wait a moment for one of ``slots``' probes to answer."""
        probes = [s.probe for s in slots if s.probe is not None]
        if probes:
            ray.wait(probes, num_returns=1, timeout=0.2)
        else:
            time.sleep(0.05)

    def poll(self) -> None:
        """Tracers that are starting or recovering become ready once their probe answers."""
        now = time.perf_counter()
        for slot in self.slots:
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
                    log.warning("tracer %s is dead: %s", slot.id, first_line(error))
                continue
            except RayError as error:  # still restarting, or cannot be placed yet
                log.info("tracer %s not back yet: %s", slot.id, first_line(error))
                continue
            slot.state = "warming" if slot.warming is not None else "ready"
            hold(slot, self.graph.key, version)
            slot.died_probes = 0
            slot.last_done = now

    def _poll_warm_up(self, slot: TracerSlot, now: float) -> None:
        """A tracer placed on a new node becomes ready once its kernels are loaded, so its
        first range is not timed with the load (nor taken for a straggler)."""
        ready, _ = ray.wait([slot.warming], timeout=0)
        if not ready:
            return
        ref, slot.warming = slot.warming, None
        try:
            self._warmed(slot, ray.get(ref))
        except RayError as error:  # it will be handled when it renders
            log.warning("tracer %s: warm-up failed: %s", slot.id, first_line(error))
        slot.state = "ready"
        slot.last_done = now

    def check_liveness(self) -> list[str]:
        """Mark lost the ready tracers Ray reports not alive or restarted since they were
        first seen ready (one query of the GCS's actor table, at most every
        ``LIVENESS_INTERVAL`` s); returns their ids."""
        now = time.perf_counter()
        watched = [s for s in self.slots if s.state in ("ready", "warming")]
        if not watched or now - self._liveness_at < LIVENESS_INTERVAL:
            return []
        self._liveness_at = now
        try:
            table = ray_state.actors()
        except Exception as error:  # the GCS briefly unreachable: the next look will tell
            log.info("cannot read the actor table: %s", first_line(error))
            return []
        lost = []
        for slot in watched:
            actor = table.get(slot.handle._actor_id.hex())
            if actor is None:
                continue
            restarts = int(actor.get("NumRestarts", 0))
            if slot.restarts is None:
                slot.restarts = restarts
            if actor.get("State") != "ALIVE" or restarts > slot.restarts:
                self.failed(slot, ClusterError(f"Ray reports the actor {actor.get('State')}"))
                lost.append(slot.id)
        return lost

    def failed(self, slot: TracerSlot, error: Exception) -> None:
        """A call failed because the tracer's process died: Ray restarts it; queue a snapshot so
        it is resynced (and known to be back) as soon as it is up."""
        if slot.state in ("retired", "dead"):
            return
        now = time.perf_counter()
        log.warning("tracer %s lost: %s", slot.id, first_line(error))
        slot.state = "recovering"
        slot.synced.clear()
        slot.failed_at = now
        slot.failures += 1
        slot.restarts = None
        self._send_probe(slot, now)

    # Views -----------------------------------------------------------------------------------

    def slot(self, tracer_id: str) -> TracerSlot:
        for slot in self.slots:
            if slot.id == tracer_id:
                return slot
        raise KeyError(f"no tracer {tracer_id!r}")

    def ready(self) -> list[TracerSlot]:
        return [s for s in self.slots if s.state == "ready"]

    def coming(self) -> list[TracerSlot]:
        """Tracers that are not ready yet but will be."""
        return [s for s in self.slots if s.state in COMING]

    def schedulable(self, busy: set[str]) -> list[TracerSlot]:
        """Ready tracers, waiting for one if there is none yet; tracers still ``busy`` with
        results nobody needs (a straggler's stale range) sit this frame out if others can."""
        deadline = time.perf_counter() + self.start_timeout
        while True:
            ready = self.ready()
            if ready:
                return [s for s in ready if s.id not in busy] or ready
            if not self.coming():
                raise ClusterError("no tracer is left to render with")
            if time.perf_counter() > deadline:
                raise ClusterError(f"no tracer became ready within {self.start_timeout:g} s")
            self._wait_probes(self.slots)
            self.poll()

    def tracers(self) -> list[dict]:
        """Every tracer started: id, state, CPUs, synced version, pid, node, failures seen (a
        tracer that died idle shows within ``LIVENESS_INTERVAL`` s)."""
        self.poll()
        self.check_liveness()
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
            for s in self.slots
        ]

    def info(self, tracer_id: str, timeout: float) -> TracerInfo:
        return ray.get(self.slot(tracer_id).handle.info.remote(), timeout=timeout)

    def close(self) -> None:
        """Stop every tracer (Ray itself stays up)."""
        for slot in self.slots:
            if slot.state != "retired":
                slot.state = "retired"
                _kill(slot.handle)


def _kill(handle) -> None:
    try:
        ray.kill(handle, no_restart=True)
    except RayError:  # pragma: no cover - already gone
        pass


def first_line(error: BaseException) -> str:
    """The first line of an error's message (its type's name when it has none)."""
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__
