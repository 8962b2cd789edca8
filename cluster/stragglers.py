"""Stragglers: ranges that run far longer than the frame's own measurements predict, whose
units are then duplicated to an idle tracer (whichever copy arrives first is used)."""

import time
from collections.abc import Callable

import numpy as np

from cluster.fleet import TracerSlot, log
from cluster.frame_job import Call, FrameJob, Limits


def stragglers(
    job: FrameJob,
    idle: list[TracerSlot],
    limits: Limits,
    owed: Callable[[FrameJob, Call], list[tuple[int, int]]],
) -> list[tuple[Call, TracerSlot, list[tuple[int, int]]]]:
    """Calls of ``job`` to duplicate now: (the call, the ``idle`` tracer to take it, its
    units not delivered yet). A call is late after ``straggler_factor`` x its predicted time
    plus ``straggler_floor`` seconds; the prediction is the frame's median apply seconds plus
    its units x render seconds per unit (a ratio of sums over what is delivered); a pooled
    call is predicted to end with the other pooled calls; a call queued behind a straggler
    waits as long as it."""
    if not job.ranges or not idle:
        return []
    idle = list(idle)
    # Seconds per unit over everything delivered (a ratio of sums: chunks of the tail are
    # cheap units, heads dear ones), apply seconds of calls (chunks apply nothing).
    per_unit = sum(r.seconds for r in job.ranges) / sum(r.u1 - r.u0 for r in job.ranges)
    calls = [r.apply_seconds for r in job.ranges if r.kind != "tail"]
    apply = float(np.median(calls)) if calls else 0.0
    now = time.perf_counter()
    running: set[str] = set()  # tracers whose first pending call (the one running) is seen
    stuck: set[str] = set()  # tracers whose running call is a straggler
    found = []
    for call in list(job.pending.values()):  # in submission order
        if not idle:
            break
        tracer, queued = call.slot.id, call.slot.id in running
        running.add(tracer)
        if queued and tracer not in stuck:
            continue  # behind a call that is on time: it has not started yet
        if call.duplicated or call.kind == "duplicate":
            if call.duplicated:
                stuck.add(tracer)
            continue
        started = max(call.submitted, call.slot.last_done)
        units = None  # asked of a remote pool only when needed: it is an actor call
        if call.owner is not None and job.busy:  # pooled calls end together
            predicted = max(job.busy.values())
        else:
            units = owed(job, call)
            predicted = apply + per_unit * sum(u1 - u0 for u0, u1 in units)
        late = now - started > limits.straggler_factor * predicted + limits.straggler_floor
        if not (queued or late):
            continue
        stuck.add(tracer)
        units = owed(job, call) if units is None else units
        missing = [run for u0, u1 in units for run in job.assembler.missing(u0, u1)]
        if not missing:
            continue
        target = idle.pop(0)
        log.info(
            "frame %d: tracer %s ran units [%d, %d) for %.2f s (predicted %.2f s): "
            "duplicating to %s",
            job.frame, call.slot.id, call.u0, call.u1, now - started, predicted, target.id,
        )  # fmt: skip
        found.append((call, target, missing))
    return found
