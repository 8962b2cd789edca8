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

With a dynamic tail (``cost-aware-tail``, :mod:`cluster.balancing.tail_plan`) step 1 sends
each tracer its head and one chunk of the tail, and step 2 sends a tracer another chunk
whenever one of its results arrives, so a call is always queued behind the one it renders;
the balancer then observes every accepted range. ``Frame.idle_percent`` counts a tracer's
waits between its ranges as idle (:func:`cluster.frame.gap_idle_percent`; Table 16's measure
with one range per tracer).

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

The coordinator is a front over its parts: :mod:`cluster.fleet` (the tracers),
:mod:`cluster.scene_sync` (what each tracer holds, and what it is sent), :mod:`cluster.pools`
(the shared pools), :mod:`cluster.frame_run` with :mod:`cluster.stragglers` (a frame's run) and
:mod:`cluster.frame` (the finished frame). It is not thread-safe: one caller drives it.
"""

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import replace
from typing import Any

import numpy as np
import ray

from cluster.balancing import DEFAULT_BALANCER, Balancer, make_balancer
from cluster.connect import connect
from cluster.fleet import Fleet, TracerSlot, first_line, log
from cluster.frame import Frame
from cluster.frame_job import FrameJob, Limits
from cluster.frame_run import FrameRunner
from cluster.pools import SharedPools
from cluster.scene_graph import SceneGraph
from cluster.scene_sync import SceneSync
from tracer.accuracy.error_estimate import PARTS
from tracer.accuracy.spot_check import SpotCheck
from tracer.request import FrameRequest
from worker.envelope import SceneEnvelope
from worker.replica import KEEP_VERSIONS
from worker.tracer_actor import TracerInfo

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


class Coordinator:
    """Tracer actors on Ray and the frames they render. See the module docstring.

    ``tracers``: how many tracer actors (default: one per Ray node with CPUs, each using all
    of its node's CPUs). ``cpus_per_tracer``: CPUs each reserves and renders with (default: all
    of its node's, or the cluster's CPUs divided by ``tracers``; fractions are allowed, a
    tracer renders with ``max(1, floor(cpus))`` threads). ``balancer``: a name in
    ``cluster.balancing.BALANCERS``. ``delays``: test-only, seconds each tracer (by index)
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
        self.balancer: Balancer = make_balancer(balancer)
        self.graph = graph
        self.stall_timeout = stall_timeout
        self.line_pool = line_pool
        """Whether a frame's dynamic tail may go to a shared pool."""
        if not ray.is_initialized():
            connect()
        if ray.util.client.ray.is_connected():  # Ray Client: this process is on no Ray node
            self.line_pool = False
        node = ray.get_runtime_context().get_node_id()
        self._sync = SceneSync()
        self._pools = SharedPools(node, self.line_pool)
        self._fleet = Fleet(graph, self._sync, tracers, cpus_per_tracer, start_timeout, delays)
        limits = Limits(straggler_factor, straggler_floor, max_attempts, stall_timeout)
        self._frames = FrameRunner(self._fleet, self._sync, self._pools, limits)

    @property
    def balancer_name(self) -> str:
        return self.balancer.name

    @property
    def stats(self) -> dict[str, int]:
        """Totals over the coordinator's life: frames, tracer failures, reassignments,
        duplicates, resyncs, late answers discarded."""
        totals = self._frames.totals
        return {
            "frames": totals["frames"],
            "failures": sum(s.failures for s in self._fleet.slots),
            **{k: totals[k] for k in ("reassigned", "duplicates", "resyncs", "stale_discarded")},
        }

    def use_balancer(self, name: str) -> None:
        """Switch to a fresh balancer (from the next frame scheduled)."""
        self.balancer = make_balancer(name)

    # Tracers ---------------------------------------------------------------------------------

    def place_new_nodes(self) -> list[str]:
        """In one-tracer-per-node mode (``tracers`` not given), start a tracer on every live
        Ray node with CPUs that has none yet (a node that joined after the start, or came
        back); they get work from the next frame once ready. Returns their ids (none in the
        other mode)."""
        return self._fleet.place_new_nodes()

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
        return self._fleet.add(n, cpus, wait, delay, options or {})

    def remove_tracer(self, tracer_id: str, decline_node: bool = True) -> None:
        """Stop a tracer for good; units it still owes are handed to the others. With
        ``decline_node``, ``place_new_nodes`` leaves its node alone from now on."""
        self._fleet.remove(tracer_id, decline_node)

    def tracer_handle(self, tracer_id: str):
        """The Ray actor handle of a tracer (for tests and tools)."""
        return self._fleet.slot(tracer_id).handle

    def tracers(self) -> list[dict]:
        """Every tracer the coordinator started: id, state, CPUs, synced version, pid, node,
        failures seen."""
        return self._fleet.tracers()

    def info(self, tracer_id: str, timeout: float = 30.0) -> TracerInfo:
        """Ask a tracer about itself (its process, node, CPUs, versions held)."""
        return self._fleet.info(tracer_id, timeout)

    @property
    def ready(self) -> list[str]:
        self._fleet.poll()
        return [s.id for s in self._fleet.ready()]

    def close(self) -> None:
        """Stop every tracer (Ray itself stays up)."""
        self._fleet.close()
        self._frames.orphans.clear()
        self._pools.close()
        self._sync.clear()

    def __enter__(self) -> "Coordinator":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # Frames ----------------------------------------------------------------------------------

    def submit_frame(
        self, request: FrameRequest | None = None, graph: SceneGraph | None = None
    ) -> FrameJob:
        """Schedule ``request`` (default frame 0 as the scene sees it) at the current version
        of ``graph`` (default the coordinator's own) and send every tracer its range (with its
        commit buffer); returns at once. The request's open camera and settings are the
        scene's at that version."""
        request = request or FrameRequest()
        return self._frames.submit(request, graph or self.graph, self.balancer, self.line_pool)

    def wait_frame(self, job: FrameJob) -> Frame:
        """Collect ``job``'s units, surviving lost tracers and stragglers; returns the frame."""
        return self._frames.wait(job, self.balancer)

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
                    self._frames.wait_dispatched(in_flight[-1])
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
                self._frames.abandon(job)

    # Queries and spot checks -----------------------------------------------------------------

    def _schedulable(self) -> list[TracerSlot]:
        busy = {c.slot.id for c in self._frames.orphans.values()}
        return self._fleet.schedulable(busy)

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

        def call(envelope: SceneEnvelope):
            return slot.handle.query.remote(origins, directions, envelope, t_max)

        out = self._sync.run(graph, state, [(slot, call)], timeout)[0]
        if isinstance(out, BaseException):
            raise out
        return state.version, out

    def render_spot_checks(
        self,
        checks: SpotCheck,
        request: FrameRequest | None = None,
        graph: SceneGraph | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A progressive frame's spot checks (``tracer.accuracy.spot_check``) of ``request`` at
        the current version of ``graph``, shared out over the ready tracers. Returns
        ``(pixels, parts, work)``: the pixels checked, their (PARTS, P', 3) parts and (P',)
        work. A tracer that fails its share, or has not answered after ``stall_timeout``,
        drops those pixels (the estimate then reads them from the render's own parts) rather
        than the frame."""
        graph = graph or self.graph
        state = graph.state
        request = (request or FrameRequest()).resolved(state)
        slots = self._schedulable()
        shares = [(s, np.arange(k, len(checks.pixels), len(slots))) for k, s in enumerate(slots)]
        shares = [(s, rows) for s, rows in shares if len(rows)]

        def checker(slot: TracerSlot, rows: np.ndarray):
            def call(envelope: SceneEnvelope):
                return slot.handle.spot_check.remote(
                    envelope,
                    request,
                    checks.pixels[rows],
                    checks.part_spp[rows],
                    checks.part_start[rows],
                )

            return call

        calls = [(s, checker(s, rows)) for s, rows in shares]
        outs = self._sync.run(graph, state, calls, self.stall_timeout)
        kept, parts = [np.zeros((0, 2), np.int64)], [np.zeros((PARTS, 0, 3))]
        work = [np.zeros(0, np.int64)]
        for (slot, rows), out in zip(shares, outs, strict=True):
            if isinstance(out, BaseException):
                log.warning("spot checks on %s failed: %s", slot.id, first_line(out))
                continue
            kept.append(checks.pixels[rows])
            parts.append(out[0])
            work.append(out[1])
        return np.concatenate(kept), np.concatenate(parts, axis=1), np.concatenate(work)
