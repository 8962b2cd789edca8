"""What /v1/cluster reports of the render thread's work: the latest frame per tracer, and
the lowered priority of the tracers on this machine."""

import logging
import os

log = logging.getLogger("tilerender.api")


def frame_report(frame, kind: str) -> dict:
    """Per-tracer lines, speed and idle time of a coordinator ``Frame`` of a job or session
    (of a job's turn: its size is the run's view)."""
    lines: dict[str, float] = {}  # in lines: a frame of many tracers hands out spans of them
    for r in frame.ranges:
        lines[r.tracer] = lines.get(r.tracer, 0.0) + frame.units.lines(r.u0, r.u1)
    busy = frame.tracer_seconds
    slowest = max(busy.values(), default=0.0)
    rays = int(frame.rays.sum()) if frame.rays is not None else 0
    per_tracer = {
        tid: {
            "lines": round(lines.get(tid, 0.0), 6),  # exact: spans are powers of two
            "seconds": round(busy.get(tid, 0.0), 6),
            "lines_per_second": round(lines.get(tid, 0) / busy[tid], 2) if busy.get(tid) else None,
            "idle_percent": round(100.0 * (slowest - busy.get(tid, 0.0)) / slowest, 2)
            if slowest > 0
            else 0.0,
        }
        for tid in set(lines) | set(busy)
    }
    return {
        "kind": kind,
        "width": frame.units.width,
        "height": frame.units.height,
        "spp": frame.settings.spp,
        "wall_seconds": round(frame.wall_seconds, 6),
        "idle_percent": round(frame.idle_percent, 3),
        "overhead_seconds": round(frame.overhead_seconds, 6),
        "calls": frame.calls,
        "pooled": frame.pooled,
        "rays": rays,
        "mrays_per_second": round(rays / frame.wall_seconds / 1e6, 3)
        if frame.wall_seconds > 0
        else None,
        "tracers": per_tracer,
    }


def renice_local_tracers(tracers: list[dict], nice: int, node: str | None, done: set[int]) -> None:
    """Lower the CPU priority of tracer processes running on ``node`` (this machine) to
    ``nice`` (every thread they have; threads they start later inherit it), so that the event
    loop, which needs little CPU but needs it at once, is not queued behind render threads on
    a machine whose every core renders. Tracers on other machines, and the pids in ``done``
    (to which each one handled is added), are left alone."""
    if nice <= 0 or not hasattr(os, "setpriority"):
        return
    for tracer in tracers:
        pid = tracer.get("pid")
        if pid is None or pid in done or tracer.get("node") != node:
            continue
        done.add(pid)
        try:
            for tid in os.listdir(f"/proc/{pid}/task"):
                os.setpriority(os.PRIO_PROCESS, int(tid), nice)
        except (OSError, ValueError) as exc:
            log.info("cannot lower the priority of tracer %s (pid %s): %s", tracer["id"], pid, exc)
