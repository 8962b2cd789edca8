"""A frame's run through the tracers: submit, feed the dynamic tail, collect, recover from
lost tracers, duplicate stragglers, finish (``docs/cluster.md``).

:meth:`FrameRunner.submit` pins the frame's request to the graph's current version, cuts the
frame into work units and sends every tracer its share (the balancer's split, or its plan's
heads, with one chunk of the tail queued behind, or the whole tail in a shared pool);
:meth:`FrameRunner.wait` collects results into the frame's :class:`Assembler` while handling
failures, then tells the balancer what each tracer did.
"""

import math
import time
from collections import Counter

import numpy as np
import ray
from ray.exceptions import RayActorError, RayTaskError

from cluster.assembler import Assembler, runs
from cluster.balancing import Balancer, TracerReport, even_split
from cluster.errors import ClusterError
from cluster.fleet import Fleet, TracerSlot, first_line, log
from cluster.frame import Frame, RangeReport, gap_idle_percent
from cluster.frame_job import Call, FrameJob, Limits
from cluster.pools import SharedPools
from cluster.scene_graph import SceneGraph
from cluster.scene_sync import SceneSync, held
from cluster.stragglers import stragglers
from tracer.request import FrameRequest
from worker.envelope import SceneEnvelope
from worker.remote_pool import PoolLost
from worker.tracer_actor import OutOfSync
from worker.work_units import WorkUnits

POLL_SECONDS = 0.02


class FrameRunner:
    """Runs frames on ``fleet``'s tracers, keeping the totals behind ``Coordinator.stats``."""

    def __init__(self, fleet: Fleet, sync: SceneSync, pools: SharedPools, limits: Limits) -> None:
        self.fleet = fleet
        self.sync = sync
        self.pools = pools
        self.limits = limits
        self.totals = Counter(frames=0, reassigned=0, duplicates=0, resyncs=0, stale_discarded=0)
        """Over every frame finished: frames, reassignments, duplicates, resyncs, and late
        answers discarded."""
        self.orphans: dict = {}
        """Calls of frames given up or finished, whose late answers are discarded."""
        self._last_done = 0.0

    # Submitting ------------------------------------------------------------------------------

    def submit(
        self, request: FrameRequest, graph: SceneGraph, balancer: Balancer, pooling: bool
    ) -> FrameJob:
        """Schedule ``request`` at the current version of ``graph``; returns at once."""
        self.drain_orphans()
        self.fleet.poll()
        state = graph.state
        request = request.resolved(state)
        slots = self.fleet.schedulable({c.slot.id for c in self.orphans.values()})
        units = WorkUnits.for_tracers(*request.view(), len(slots))
        job = FrameJob(
            request=request,
            graph=graph,
            state=state,
            units=units,
            assembler=Assembler(request.frame, state.version, units, request.settings.renders_aovs),
            submitted=time.perf_counter(),
        )
        ids = [s.id for s in slots]
        local = self.pools.shares_file(slots)
        pooled = pooling and len(slots) > 1 and (local or balancer.remote_pool)
        claim = self.pools.claim_seconds(local)
        job.tail = balancer.plan(
            units.count, ids, pooled=pooled, spans=units.spans, claim_seconds=claim
        )
        if job.tail is not None:
            ranges = job.tail.heads
            if pooled and not job.tail.empty:
                self._open_pool(job, local)
        else:
            ranges = balancer.split(units.count, ids, spans=units.spans)
        try:
            for owner, (slot, (u0, u1)) in enumerate(zip(slots, ranges, strict=True)):
                job.split.append((slot.id, u0, u1))
                if job.pool is not None:  # every tracer claims chunks, with or without a head
                    self._send(job, slot, u0, u1, "split", 1, owner=owner)
                elif u1 > u0:
                    self._send(job, slot, u0, u1, "split", 1)
            for slot in slots:  # one chunk queued behind every head
                self._feed(job, slot)
        except BaseException:
            self.abandon(job)
            raise
        return job

    def _open_pool(self, job: FrameJob, local: bool) -> None:
        """Move ``job``'s whole tail into a shared pool its tracers claim from: a file when
        they all share this machine (``local``), else a table in the pool actor."""
        chunks = job.pool_chunks = job.tail.take_all()
        job.pool = self.pools.create(chunks, local)
        for u0, u1 in chunks:
            job.assembler.assign(u0, u1)

    def _send(
        self,
        job: FrameJob,
        slot: TracerSlot,
        u0: int,
        u1: int,
        kind: str,
        attempt: int,
        envelope: SceneEnvelope | None = None,
        owner: int | None = None,
    ) -> Call:
        """One render call of units [u0, u1) to ``slot`` (with the envelope reaching the
        frame's version from what it holds, unless given)."""
        have = held(slot, job.graph.key)
        envelope = envelope or self.sync.envelope(slot, job.graph, job.state)
        ref = slot.handle.render.remote(
            envelope,
            job.request.for_units(u0, u1),
            spans=job.units.spans,
            pool=None if owner is None else (job.pool.ticket, owner),
        )
        self.sync.sent(slot, envelope, have)
        if u1 > u0:
            job.assembler.assign(u0, u1)
        call = job.pending[ref] = Call(slot, u0, u1, kind, attempt, time.perf_counter())
        call.owner = owner
        return call

    def _feed(self, job: FrameJob, slot: TracerSlot) -> None:
        """Send ``slot`` the next chunk of ``job``'s dynamic tail, if any is left."""
        if job.tail is None or job.tail.empty or slot.state != "ready":
            return
        chunk = job.tail.next_chunk(slot.id)
        if chunk is not None:
            self._send(job, slot, *chunk, "tail", 1)

    def _feed_idle(self, job: FrameJob) -> None:
        """Ready tracers with nothing left in ``job`` (back from a failure, or whose calls
        failed) take chunks of its tail."""
        if job.tail is None or job.tail.empty:
            return
        busy = {c.slot.id for c in (*job.pending.values(), *self.orphans.values())}
        for slot in self.fleet.ready():
            if slot.id not in busy:
                self._feed(job, slot)
                self._feed(job, slot)  # and one queued behind it

    # Collecting ------------------------------------------------------------------------------

    def wait(self, job: FrameJob, balancer: Balancer) -> Frame:
        """Collect ``job``'s units, surviving lost tracers and stragglers; returns the frame
        once ``balancer`` has observed it."""
        if job.result is not None:
            return job.result
        try:
            self._collect(job)
        except BaseException:
            self.abandon(job)
            raise
        return self._finish(job, balancer)

    def _collect(self, job: FrameJob) -> None:
        last_progress = time.perf_counter()
        while not job.assembler.complete:
            self._feed_idle(job)
            if not job.pending:
                if job.tail is not None:
                    job.tail.drain()  # nobody can take chunks: the units are reassigned
                for u0, u1 in job.assembler.missing():  # defensive: nothing owes these units
                    self._reassign(job, u0, u1, None, self.limits.max_attempts)
            refs = list(job.pending)
            ready, _ = ray.wait(refs, num_returns=1, timeout=POLL_SECONDS)
            if ready:
                ready, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
                for ref in ready:
                    self._handle(job, ref)
                last_progress = time.perf_counter()
            elif time.perf_counter() - last_progress > self.limits.stall_timeout:
                raise ClusterError(
                    f"frame {job.frame}: no tracer answered for {self.limits.stall_timeout:g} s"
                )
            self.fleet.poll()
            if not job.assembler.complete:
                self._duplicate_stragglers(job)

    def _duplicate_stragglers(self, job: FrameJob) -> None:
        """Duplicate calls that run far longer than predicted to tracers that are idle."""
        busy = {c.slot.id for c in job.pending.values()}
        idle = [s for s in self.fleet.ready() if s.id not in busy]
        for call, target, missing in stragglers(job, idle, self.limits, self.owed):
            for u0, u1 in missing:
                self._send(job, target, u0, u1, "duplicate", call.attempt)
            call.duplicated = True
            job.duplicates += 1

    def wait_dispatched(self, job: FrameJob) -> None:
        """Collect ``job``'s results until its dynamic tail is all handed out (at once without
        a tail), so the next frame's calls queue behind its last chunks rather than before
        them (Ray runs an actor's calls in order)."""
        last_progress = time.perf_counter()
        while job.tail is not None and not job.tail.empty and not job.assembler.complete:
            refs = list(job.pending)
            if not refs:
                return  # wait hands the units out
            ready, _ = ray.wait(refs, num_returns=1, timeout=POLL_SECONDS)
            for ref in ready:
                self._handle(job, ref)
                last_progress = time.perf_counter()
            if time.perf_counter() - last_progress > self.limits.stall_timeout:
                return  # wait reports the stall
            self.fleet.poll()
            self._feed_idle(job)

    def abandon(self, job: FrameJob) -> None:
        """Give ``job`` up (an error, or its caller stopped): its late answers are discarded
        on arrival and its pool is removed."""
        self.orphans.update(job.pending)
        job.pending.clear()
        self.pools.remove(job.pool)

    def _handle(self, job: FrameJob, ref) -> None:
        call = job.pending.pop(ref)
        slot = call.slot
        try:
            out = ray.get(ref)
        except RayTaskError as error:  # an exception inside the tracer: try elsewhere
            # (first: an error the tracer met, e.g. from another actor, is a RayTaskError that
            # is also a RayActorError, and the tracer itself is alive)
            log.warning("tracer %s failed on frame %d: %s", slot.id, job.frame, first_line(error))
            job.failures += 1
            self._recover(job, call, error)
            return
        except RayActorError as error:
            if call.submitted >= slot.failed_at:
                self.fleet.failed(slot, error)
            job.failures += 1
            self._recover(job, call, error)
            return
        now = time.perf_counter()
        slot.last_done = now
        if isinstance(out, OutOfSync):
            self._resend(job, call, out)
            return
        if out.node != slot.node:
            slot.pool_blind = False
        slot.seen = (out.pid, out.node)
        # The next chunk queues while this tracer works on its last (after an OutOfSync answer
        # the resend keeps it busy, and the chunk waits until the tracer is in sync).
        self._feed(job, slot)
        if call.owner is not None and out.more is None:
            log.warning("tracer %s cannot open the frame's pool file", slot.id)
            slot.pool_blind = True
        busy = 0.0
        for part, kind in [(out, call.kind), *((chunk, "tail") for chunk in out.more or ())]:
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

    def _resend(self, job: FrameJob, call: Call, out: OutOfSync) -> None:
        """``call``'s tracer could not reach the frame's version: send the range again with
        what the resync rule says (unless the units are delivered by now)."""
        envelope = self.sync.resync(call.slot, out, job.graph, job.state, last=call.resent)
        job.resyncs += 1
        if call.attempt >= self.limits.max_attempts:
            raise ClusterError(
                f"tracer {call.slot.id} cannot reach version {job.version}: {out.reason}"
            )
        if call.owner is None and not job.assembler.missing(call.u0, call.u1):
            return
        again = self._send(
            job, call.slot, call.u0, call.u1, call.kind, call.attempt + 1, envelope, call.owner
        )
        again.resent = True

    # Failures --------------------------------------------------------------------------------

    def owed(self, job: FrameJob, call: Call) -> list[tuple[int, int]]:
        """The unit ranges ``call`` may deliver: its own range and the pool chunks it claimed
        (none known when the pool actor is lost: ``_release_pool`` hands those out)."""
        own = [(call.u0, call.u1)] if call.u1 > call.u0 else []
        if call.owner is None or job.pool is None:
            return own
        try:
            return own + job.pool.claimed(call.owner)
        except PoolLost as error:
            self.pools.lose(error)
            return own

    def _release_pool(self, job: FrameJob) -> None:
        """When no pooled call is left to claim them (a tracer could not open the pool, or died
        before it was empty, or the pool actor was lost), hand the pool's units that nothing
        delivered or owes out in calls of their own (without asking the pool: every chunk is
        claimed or unclaimed by now, and the answer would be an actor call)."""
        if job.pool is None or any(c.owner is not None for c in job.pending.values()):
            return
        owed = np.zeros(job.units.count, bool)
        for call in job.pending.values():
            owed[call.u0 : call.u1] = True
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
                self.pools.lose(error)
        for u0, u1 in left:
            self._reassign(job, u0, u1, None, 1)

    def _recover(self, job: FrameJob, call: Call, error: Exception) -> None:
        """Hand the failed call's unfinished units, not owed by another call, to others."""
        owed = np.zeros(job.units.count, bool)
        for other in job.pending.values():
            for u0, u1 in self.owed(job, other):
                owed[u0:u1] = True
        if job.pool is not None and any(c.owner is not None for c in job.pending.values()):
            try:
                unclaimed = job.pool.unclaimed()  # a pooled call still running claims them
            except PoolLost as lost:
                self.pools.lose(lost)
                unclaimed = []
            for u0, u1 in unclaimed:
                owed[u0:u1] = True
        mine = np.zeros(job.units.count, bool)
        for u0, u1 in self.owed(job, call):
            mine[u0:u1] = True
        todo = mine & ~job.assembler.done & ~owed
        for u0, u1 in runs(todo):
            if call.attempt >= self.limits.max_attempts:
                raise ClusterError(
                    f"frame {job.frame}: units [{u0}, {u1}) failed {call.attempt} times; last: "
                    f"{first_line(error)}"
                )
            self._reassign(job, u0, u1, call.slot, call.attempt)
        self._release_pool(job)

    def _reassign(
        self, job: FrameJob, u0: int, u1: int, failed: TracerSlot | None, attempt: int
    ) -> None:
        """Split units [u0, u1) evenly among the tracers that can take them."""
        self.fleet.poll()
        ready = [s for s in self.fleet.ready() if s is not failed]
        busy = {c.slot.id for c in job.pending.values()}
        targets = [s for s in ready if s.id not in busy] or ready
        if not targets:  # nobody ready: queue on tracers that are coming back
            targets = self.fleet.coming()
        if not targets:
            raise ClusterError(f"frame {job.frame}: no tracer is left to render with")
        pieces = even_split(u1 - u0, min(len(targets), u1 - u0))
        for slot, (a, b) in zip(targets, pieces, strict=False):
            if b > a:
                self._send(job, slot, u0 + a, u0 + b, "reassigned", attempt + 1)
        job.reassigned += 1

    def drain_orphans(self) -> None:
        """Collect late answers of finished frames and discard them (failures still count)."""
        if not self.orphans:
            return
        refs = list(self.orphans)
        ready, _ = ray.wait(refs, num_returns=len(refs), timeout=0)
        for ref in ready:
            call = self.orphans.pop(ref)
            try:
                ray.get(ref)
            except RayTaskError:
                continue
            except RayActorError as error:
                if call.submitted >= call.slot.failed_at:
                    self.fleet.failed(call.slot, error)
                continue
            call.slot.last_done = time.perf_counter()
            self.totals["stale_discarded"] += 1

    # Finishing -------------------------------------------------------------------------------

    def _finish(self, job: FrameJob, balancer: Balancer) -> Frame:
        now = time.perf_counter()
        self.abandon(job)  # losing copies and the like: discarded on arrival
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
            aov=job.assembler.aov,
            camera=job.request.camera,
            settings=job.request.settings,
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
        reports = self.reports(job, now)
        if reports:
            balancer.observe(job.units.count, reports, spans=job.units.spans)
        job.result = frame
        self.totals["frames"] += 1
        for key in ("reassigned", "duplicates", "resyncs"):
            self.totals[key] += getattr(job, key)
        return frame

    def reports(self, job: FrameJob, now: float) -> list[TracerReport]:
        """What the balancer learns from ``job`` (the balancer's units are the frame's work
        units). Without a dynamic tail, each tracer's range of the split with its seconds;
        with one, every accepted range: heads and chunks with their render seconds, units of
        copies and reassignments with none (NaN: cost only). A straggler whose units came
        from a copy reports the time it had run (a lower bound); a lost tracer reports
        nothing (the balancer keeps its prediction for those units)."""
        if job.tail is not None:
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
        else:
            reports = []
            for tracer_id, u0, u1 in job.split:
                result = job.primary.get(tracer_id)
                if u1 == u0:
                    reports.append(TracerReport(tracer_id, u0, u1, 0.0, np.zeros(0, np.int64)))
                elif result is not None:
                    reports.append(TracerReport(tracer_id, u0, u1, result.seconds, result.cost))
        return reports + self._stalled_reports(job, now)

    def _stalled_reports(self, job: FrameJob, now: float) -> list[TracerReport]:
        """Stragglers of ``job``'s split whose units a copy delivered, each with the time it
        had run (a lower bound); a lost tracer reports nothing."""
        by_id = {s.id: s for s in self.fleet.slots}
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
