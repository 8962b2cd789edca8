"""A finished frame and how it was made: its image, the ranges that made it, their timings."""

import itertools
from dataclasses import dataclass

import numpy as np

from tracer.scene import format as fmt
from worker.work_units import WorkUnits


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
    """float32 (H, W, 3), linear radiance, of the request's view (a region's lines, or its
    run as one line)."""
    cost: np.ndarray
    """int64 (H,): work per line of the view."""
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
    aov: np.ndarray | None = None
    """float32 (H, W, ``tracer.integrators.aov.CHANNELS``): the view's AOVs, when the settings
    render them (``tracer.integrators.aov``)."""


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
