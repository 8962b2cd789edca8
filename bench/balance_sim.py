"""Replay recorded cost traces through the workload balancers and measure idle time.

Set-up (every balancer sees exactly the same frames, speeds and noise):

- **Trace.** ``bench/traces/<orbit>.npz`` (``bench/record_cost_traces.py``): the real cost of
  every line, and of every span of a line, of 128 frames of an orbiting camera. ``slow``/
  ``fast`` have 96 lines (128x96, 16 spans recorded), ``slow-hd``/``fast-hd`` 480 lines
  (640x480, 64 spans).
- **Work units.** The balancers split a row of work units, as the coordinator does
  (``worker.work_units``): each line cut into ``--spans`` equal spans, unit ``u`` span
  ``u % spans`` of line ``u // spans``. ``auto`` (the default) takes the coordinator's choice
  for each scenario, ``WorkUnits.for_tracers(W, H, T)`` (whole lines for two tracers at
  640x480, 64 spans of 10 pixels for 128); an integer (a power of two, at most the recorded
  spans) fixes it, 1 being whole lines. A unit's cost is the sum of its recorded spans.
- **Tracers.** T tracers with relative speeds drawn log-uniform in ``[0.5, 2]`` from
  ``numpy.random.default_rng(seed + T)`` (the *equal* rows give every tracer speed 1, Bikker's
  Table 16 set-up with two identical GPUs). Speeds are scaled so a perfectly balanced frame
  takes ``--frame-ms`` (the cluster is sized for its frame rate).
- **A frame.** ``split`` gives ranges of units; tracer i spends
  ``sum(cost[u0:u1]) / speed_i * jitter + overhead`` seconds, where ``jitter`` is lognormal
  (median 1, sigma ``--jitter``), drawn per frame and tracer from a generator seeded by
  ``--seed`` (identical for every balancer), and ``overhead`` (``--overhead-ms``) is paid by
  every tracer with a non-empty range. Tracers with empty ranges are not called and spend 0 s.
  Then ``observe`` gets each tracer's range, seconds and unit costs.
- **Metric.** Idle % of each frame, ``100 * sum_i (t_max - t_i) / (T * t_max)`` (Table 16),
  averaged over all frames (the cold start included: frame 0 is an even split for everyone),
  over frames 8 and later ("steady"), and its 95th percentile and maximum (the spikes of
  Bikker's figure 48).
- **Oracle.** Not a balancer: the min-max partition of each frame's *true* costs with the
  *true* speeds. What remains is the floor set by jitter and by whole-unit granularity.
- **Noise floor.** The idle of the jitter alone: every tracer given exactly its share of
  infinitely divisible work, so tracer i takes ``T0 * jitter_i + overhead``. In expectation no
  split of whole units, known in advance, does better.

Writes ``bench/results/balance_sim.json`` and, when matplotlib is installed (the ``study``
extra), ``bench/results/balance_sim.png`` (idle % per frame, after Bikker's figure 48).
"""

import argparse
import heapq
import itertools
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import numpy as np
from common import (
    REPO_ROOT,
    RESULTS_DIR,
    console,
    machine_info,
    print_machine,
    print_table,
    pyplot,
    styled_verdict,
    verdict,
    write_results,
)

from cluster.balancing import (
    BALANCERS,
    CostAware,
    CostAwareTail,
    PerfectSmooth,
    RobinHood,
    TracerReport,
    idle_percent,
    make_balancer,
    min_max_cuts,
)
from worker.remote_pool import REMOTE_CLAIM_SECONDS
from worker.work_units import WorkUnits

TRACE_DIR = REPO_ROOT / "bench" / "traces"
ORACLE = "oracle"
STEADY_FROM = 8
"""Frames before this one count in the "all" mean only: the balancers' cold start."""

# Targets from the issue, for the cost-aware balancer: (orbit, scenario) -> mean idle % at most.
# Two tracers on both resolutions of both orbits (and the equal-speed pair); 8-128 tracers on
# the fast orbit at 640x480 (128x96 has too few pixels to share among 32 or 128 tracers).
TARGETS = {
    ("slow", "2"): 1.0,
    ("slow", "2eq"): 1.0,
    ("slow-hd", "2"): 1.0,
    ("slow-hd", "2eq"): 1.0,
    ("fast", "2"): 2.0,
    ("fast", "2eq"): 2.0,
    ("fast-hd", "2"): 2.0,
    ("fast-hd", "2eq"): 2.0,
    ("fast-hd", "8"): 3.0,
    ("fast-hd", "32"): 3.0,
    ("fast-hd", "128"): 3.0,
}


def trace_path(name: str) -> Path:
    """``bench/traces/<name>.npz``; exits with a message when it is missing."""
    path = TRACE_DIR / f"{name}.npz"
    if not path.exists():
        raise SystemExit(f"{path} is missing: run bench/record_cost_traces.py first")
    return path


@cache
def trace_size(name: str) -> tuple[int, int]:
    """The frame size ``(width, height)`` of trace ``name``."""
    with np.load(trace_path(name)) as data:
        return int(data["width"]), int(data["height"])


@cache
def load_trace(name: str, spans: int = 1) -> np.ndarray:
    """The cost of every work unit, ``spans`` per line, of every frame of trace ``name``:
    float64 (frames, height * spans), units in row-major order. Groups of recorded spans are
    summed (a span of ``WorkUnits`` is exactly a group of finer spans when spans divide).
    ValueError when the trace was not recorded at a multiple of ``spans``."""
    path = trace_path(name)
    with np.load(path) as data:
        if spans == 1:
            return data["cost"].astype(np.float64)
        if "span_cost" not in data:
            raise ValueError(
                f"{path} has per-line costs only (recorded before spans): --spans 1 replays it, "
                "bench/record_cost_traces.py records it again with spans"
            )
        span_cost = data["span_cost"]
    frames, height, recorded = span_cost.shape
    if recorded % spans:
        raise ValueError(
            f"{path} has {recorded} spans a line: --spans must be a power of two up to "
            f"{recorded}, not {spans}"
        )
    grouped = span_cost.reshape(frames, height, spans, recorded // spans)
    return grouped.sum(axis=3, dtype=np.int64).reshape(frames, height * spans).astype(np.float64)


def spans_for(args, orbit: str, tracers: int) -> int:
    """Spans per line for ``tracers`` on ``orbit``: ``--spans``, or the coordinator's choice."""
    if args.spans != "auto":
        return args.spans
    return WorkUnits.for_tracers(*trace_size(orbit), tracers).spans


def check_spans(args) -> str | None:
    """Why some orbit of ``args`` cannot be replayed at its spans, or None (loads the traces)."""
    try:
        for orbit in args.orbits:
            for _, count, _ in scenarios(args.tracers, not args.no_equal):
                load_trace(orbit, spans_for(args, orbit, count))
    except ValueError as error:
        return str(error)
    return None


def spans_option(text: str) -> int | str:
    """``--spans``: ``auto`` or a power of two."""
    if text == "auto":
        return text
    try:
        spans = int(text)
    except ValueError:
        spans = 0
    if spans < 1 or spans & (spans - 1):
        raise argparse.ArgumentTypeError(f"'auto' or a power of two (1, 2, 4, ...), not {text!r}")
    return spans


def tracer_speeds(count: int, equal: bool, seed: int, low: float, high: float) -> np.ndarray:
    """Relative speeds: all 1 when ``equal``, else log-uniform in [low, high]."""
    if equal:
        return np.ones(count)
    rng = np.random.default_rng(seed + count)
    return np.exp(rng.uniform(math.log(low), math.log(high), count))


def simulate(
    balancer,
    cost: np.ndarray,
    speeds: np.ndarray,
    jitter: np.ndarray,
    overhead: float,
    lag: int = 0,
    spans: int = 1,
) -> np.ndarray:
    """Idle % of every frame of ``cost`` (frames, units; ``spans`` units per line) for
    ``balancer`` (or ``ORACLE``) and tracers of absolute ``speeds`` (cost units per second),
    ``jitter`` (frames, T). With ``lag`` k, frame f is split before frames f-k..f-1 are
    observed (a pipelined coordinator: k = 1)."""
    frames, height = cost.shape
    ids = [f"t{i:03d}" for i in range(speeds.size)]
    idle = np.empty(frames)
    pending: list[list[TracerReport]] = []
    for f in range(frames):
        unit_cost = cost[f]
        if balancer == ORACLE:
            floor = CostAware.FLOOR * max(unit_cost.mean(), 1e-300)
            edges = min_max_cuts(np.maximum(unit_cost, floor), speeds)
            ranges = list(itertools.pairwise(edges))
        else:
            ranges = balancer.split(height, ids, spans=spans)
        seconds = np.zeros(speeds.size)
        reports = []
        for i, (y0, y1) in enumerate(ranges):
            if y1 > y0:
                seconds[i] = unit_cost[y0:y1].sum() / speeds[i] * jitter[f, i] + overhead
            reports.append(
                TracerReport(ids[i], y0, y1, float(seconds[i]), unit_cost[y0:y1].astype(np.int64))
            )
        if balancer != ORACLE:
            pending.append(reports)
            while len(pending) > lag:
                balancer.observe(height, pending.pop(0), spans=spans)
        idle[f] = idle_percent(seconds)
    return idle


def simulate_calls(
    balancer,
    cost: np.ndarray,
    speeds: np.ndarray,
    jitter: np.ndarray,
    overhead: float,
    latency: float,
    gap: float,
    lag: int = 0,
    claim: float | None = None,
    spans: int = 1,
    remote: bool = False,
) -> dict[str, np.ndarray]:
    """Every frame of ``cost`` (``spans`` units per line) as the coordinator runs it, call by
    call (:func:`frame_calls`), or with ``claim`` (seconds per chunk) as tracers claiming from
    a shared pool run it (:func:`frame_pool`). ``remote``: the tracers are on several
    machines, so the pool is the actor pool (only for balancers that use it, ``remote_pool``;
    the others run call by call): claims answered ``REMOTE_CLAIM_SECONDS`` after they are
    sent, each sent while the chunk before renders (``claim`` is what it costs the tracer),
    chunks planned as the coordinator plans them.
    Returns per frame: ``idle`` (Table 16's measure with the gaps between a tracer's calls
    counted as idle: every tracer's window runs from its first render to the latest end of
    any), ``span_idle`` (from the first send to the last result: latency included), ``wall``
    (that span, seconds) and ``calls``."""
    frames, height = cost.shape
    ids = [f"t{i:03d}" for i in range(speeds.size)]
    out = {k: np.empty(frames) for k in ("idle", "span_idle", "wall", "calls")}
    pending: list[list[TracerReport]] = []
    pooled = claim is not None and (not remote or getattr(balancer, "remote_pool", False))
    for f in range(frames):
        if hasattr(balancer, "plan"):
            # as the coordinator plans: chunks sized for the actor pool's round trip, the
            # file pool's own least chunk
            claim_seconds = REMOTE_CLAIM_SECONDS if pooled and remote else 0.0
            plan = balancer.plan(
                height, ids, pooled=pooled, spans=spans, claim_seconds=claim_seconds
            )
            heads = plan.heads
        else:
            plan, heads = None, balancer.split(height, ids, spans=spans)
        times = speeds / jitter[f]  # this frame's speeds
        if pooled and plan is not None:
            chunks = plan.take_all()
            trip = REMOTE_CLAIM_SECONDS if remote else 0.0
            measures, reports = frame_pool(cost[f], times, ids, heads, chunks, latency, claim, trip)
        else:
            measures, reports = frame_calls(
                cost[f], times, ids, heads, plan, overhead, latency, gap
            )
        for key, value in measures.items():
            out[key][f] = value
        pending.append(reports)
        while len(pending) > lag:
            balancer.observe(height, pending.pop(0), spans=spans)
    return out


def frame_calls(
    unit_cost: np.ndarray,
    speeds: np.ndarray,
    ids: list[str],
    heads: list[tuple[int, int]],
    plan,
    overhead: float,
    latency: float,
    gap: float,
) -> tuple[dict[str, float], list[TracerReport]]:
    """One frame, call by call: a call reaches its tracer ``latency`` seconds after it is
    sent, waits for the tracer's earlier calls (Ray runs an actor's calls in order), starts
    ``gap`` seconds after the tracer is free (the call's cost outside rendering), renders
    ``cost / speed + overhead`` seconds, and its result is back ``latency`` seconds later.
    Every tracer gets its head at once; with a ``plan`` (the dynamic tail) also one chunk
    queued behind it, and another whenever one of its results comes back."""
    count = speeds.size
    free = np.zeros(count)  # when each tracer is done with the calls it got so far
    first = np.full(count, np.inf)
    busy = np.zeros(count)
    events: list[tuple[float, int]] = []
    reports: list[TracerReport] = []

    def send(i: int, y0: int, y1: int, now: float) -> None:
        start = max(now + latency, free[i]) + gap
        seconds = unit_cost[y0:y1].sum() / speeds[i] + overhead
        free[i] = start + seconds
        first[i] = min(first[i], start)
        busy[i] += seconds
        heapq.heappush(events, (free[i] + latency, i))
        reports.append(
            TracerReport(ids[i], y0, y1, float(seconds), unit_cost[y0:y1].astype(np.int64))
        )

    for i, (y0, y1) in enumerate(heads):
        if y1 > y0:
            send(i, y0, y1, 0.0)
    for i in range(count if plan is not None else 0):
        chunk = plan.next_chunk(ids[i])
        if chunk is not None:
            send(i, *chunk, 0.0)
    end = 0.0
    while events:
        end, i = heapq.heappop(events)
        chunk = plan.next_chunk(ids[i]) if plan is not None else None
        if chunk is not None:
            send(i, *chunk, end)
    worked = np.isfinite(first)
    window = float(np.max(free[worked] - first[worked])) if worked.any() else 0.0
    measures = {
        "idle": 100 * float(np.sum(window - busy)) / (count * window) if window else 0.0,
        "span_idle": 100 * float(np.sum(end - busy)) / (count * end) if end else 0.0,
        "wall": end,
        "calls": float(len(reports)),
    }
    return measures, reports


def frame_pool(
    unit_cost: np.ndarray,
    speeds: np.ndarray,
    ids: list[str],
    heads: list[tuple[int, int]],
    chunks: list[tuple[int, int]],
    latency: float,
    claim: float,
    round_trip: float = 0.0,
) -> tuple[dict[str, float], list[TracerReport]]:
    """One frame with the tail in a shared unit pool: every tracer gets one call (``latency``
    seconds each way), renders its head (``cost / speed``), then claims chunks in order, each
    ``claim`` seconds plus its render, the tracer free first claiming first, until none is
    left. A call's fixed cost is the latency alone (one call per tracer, as in the cluster).
    With a ``round_trip`` (the actor pool) claims are answered that long after they are sent,
    in the order they reach the pool, and each is sent when the chunk before it starts
    (:func:`frame_pool_ahead`)."""
    if round_trip > 0.0:
        return frame_pool_ahead(unit_cost, speeds, ids, heads, chunks, latency, claim, round_trip)
    tracers = _PoolTracers(unit_cost, speeds, ids, latency, heads)
    ready = [(tracers.free[i], i) for i in range(speeds.size)]
    heapq.heapify(ready)
    for y0, y1 in chunks:
        _, i = heapq.heappop(ready)
        tracers.render(i, y0, y1, claim)
        heapq.heappush(ready, (tracers.free[i], i))
    return tracers.measures(), tracers.reports


def frame_pool_ahead(
    unit_cost: np.ndarray,
    speeds: np.ndarray,
    ids: list[str],
    heads: list[tuple[int, int]],
    chunks: list[tuple[int, int]],
    latency: float,
    claim: float,
    round_trip: float,
) -> tuple[dict[str, float], list[TracerReport]]:
    """:func:`frame_pool` for the actor pool: a tracer sends its first claim when its head is
    done and each later one when it starts the chunk before (so it holds the next chunk while
    rendering); the pool answers claims in the order they arrive, half a ``round_trip`` after
    they are sent, and the answer is back half a round trip later. A chunk starts when the
    tracer is free and its answer is back; a wait for an answer counts in the chunk's seconds
    (as the tracers report them), the wait for the last, empty answer in no one's."""
    tracers = _PoolTracers(unit_cost, speeds, ids, latency, heads)
    arrivals = [(tracers.free[i] + round_trip / 2, i) for i in range(speeds.size)]
    heapq.heapify(arrivals)
    waiting = list(chunks)[::-1]
    while arrivals:
        arrived, i = heapq.heappop(arrivals)
        answer = arrived + round_trip / 2
        if not waiting:
            tracers.free[i] = max(tracers.free[i], answer)
            continue
        start = max(tracers.free[i], answer)
        tracers.render(i, *waiting.pop(), (start - tracers.free[i]) + claim)
        heapq.heappush(arrivals, (start + round_trip / 2, i))
    return tracers.measures(), tracers.reports


class _PoolTracers:
    """The tracers of one pooled frame: when each is free, its busy seconds and its reports;
    every tracer got one call (``latency`` each way) and renders its head first."""

    def __init__(self, unit_cost, speeds, ids, latency: float, heads) -> None:
        self.unit_cost, self.speeds, self.ids, self.latency = unit_cost, speeds, ids, latency
        self.free = np.full(speeds.size, latency)
        self.busy = np.zeros(speeds.size)
        self.reports: list[TracerReport] = []
        for i, (y0, y1) in enumerate(heads):
            if y1 > y0:
                self.render(i, y0, y1, 0.0)

    def render(self, i: int, y0: int, y1: int, extra: float) -> None:
        """Tracer ``i`` renders units [y0, y1) and spends ``extra`` seconds beside."""
        seconds = self.unit_cost[y0:y1].sum() / self.speeds[i] + extra
        self.free[i] += seconds
        self.busy[i] += seconds
        cost = self.unit_cost[y0:y1].astype(np.int64)
        self.reports.append(TracerReport(self.ids[i], y0, y1, float(seconds), cost))

    def measures(self) -> dict[str, float]:
        count = self.speeds.size
        window = float(self.free.max() - self.latency)
        end = float(self.free.max() + self.latency)
        busy = self.busy
        return {
            "idle": 100 * float(np.sum(window - busy)) / (count * window) if window else 0.0,
            "span_idle": 100 * float(np.sum(end - busy)) / (count * end) if end else 0.0,
            "wall": end,
            "calls": float(count),
        }


def summarise(idle: np.ndarray) -> dict[str, float]:
    """Mean over all frames; mean, 95th percentile and maximum over the steady frames."""
    steady = idle[STEADY_FROM:] if idle.size > STEADY_FROM else idle
    return {
        "mean": float(idle.mean()),
        "steady": float(steady.mean()),
        "p95": float(np.percentile(steady, 95)),
        "max": float(steady.max()),
    }


def result_key(sigma: float, lag: int) -> str:
    return f"jitter {sigma:g}, lag {lag}"


def scenarios(counts: list[int], equal_pair: bool) -> list[tuple[str, int, bool]]:
    """(label, tracers, equal speeds): the equal pair first, then each count."""
    out = [("2eq", 2, True)] if equal_pair else []
    return out + [(str(t), t, False) for t in counts]


@dataclass
class Scenario:
    """One orbit's trace with one set of simulated tracers and their jitter."""

    orbit: str
    label: str
    count: int
    equal: bool
    spans: int
    cost: np.ndarray
    relative_speeds: np.ndarray
    speeds: np.ndarray
    jitter: np.ndarray
    noise_floor: float


def orbit_scenarios(args, jitter_sigma: float) -> Iterator[Scenario]:
    """Every orbit with every tracer count of ``args``, its frames cut into units
    (:func:`spans_for`): speeds scaled so a balanced frame takes ``--frame-ms``, jitter drawn
    from a seed of its own, and the noise floor."""
    for orbit in args.orbits:
        for label, count, equal in scenarios(args.tracers, not args.no_equal):
            spans = spans_for(args, orbit, count)
            cost = load_trace(orbit, spans)[: args.frames]
            frames = cost.shape[0]
            mean_frame_cost = float(cost.sum(axis=1).mean())
            rel = tracer_speeds(count, equal, args.seed, *args.speed_range)
            speeds = rel * mean_frame_cost / (rel.sum() * args.frame_ms * 1e-3)
            rng = np.random.default_rng([args.seed, count, int(equal)])
            jitter = np.exp(jitter_sigma * rng.standard_normal((frames, count)))
            floor = float(
                np.mean([idle_percent(args.frame_ms * j + args.overhead_ms) for j in jitter])
            )
            yield Scenario(orbit, label, count, equal, spans, cost, rel, speeds, jitter, floor)


def run(args, factories: dict, jitter_sigma: float, lag: int, keep_frames: bool) -> dict:
    """Every balancer on every orbit and scenario at one jitter level and lag; returns
    ``{orbit: {scenario: {..., "balancers": {name: summary}}}}``."""
    results: dict = {}
    for sc in orbit_scenarios(args, jitter_sigma):
        frames, units = sc.cost.shape
        entry = {
            "tracers": sc.count,
            "equal_speeds": sc.equal,
            "relative_speeds": np.round(sc.relative_speeds, 4),
            "lines": units // sc.spans,
            "spans": sc.spans,
            "units": units,
            "frames": frames,
            "noise_floor": sc.noise_floor,
            "balancers": {},
        }
        for name, factory in factories.items():
            balancer = ORACLE if factory == ORACLE else factory()
            overhead = args.overhead_ms * 1e-3
            idle = simulate(balancer, sc.cost, sc.speeds, sc.jitter, overhead, lag, sc.spans)
            entry["balancers"][name] = summarise(idle)
            if keep_frames:
                entry["balancers"][name]["per_frame"] = np.round(idle, 2)
        results.setdefault(sc.orbit, {})[sc.label] = entry
    return results


def run_calls(args, factories: dict, jitter_sigma: float, lag: int) -> dict:
    """Every balancer of ``factories`` through :func:`simulate_calls` on every orbit and
    tracer count; ``{orbit: {T: {"noise_floor": ..., "balancers": {name: summary}}}}`` where a
    summary holds the means over all frames of idle, span idle, wall (ms) and calls."""
    results: dict = {}
    for sc in orbit_scenarios(args, jitter_sigma):
        entry = {
            "tracers": sc.count,
            "spans": sc.spans,
            "units": sc.cost.shape[1],
            "noise_floor": sc.noise_floor,
            "balancers": {},
        }
        for name, factory in factories.items():
            out = simulate_calls(
                factory(),
                sc.cost,
                sc.speeds,
                sc.jitter,
                args.overhead_ms * 1e-3,
                args.latency_ms * 1e-3,
                args.call_gap_ms * 1e-3,
                lag,
                None if args.pool_claim_ms is None else args.pool_claim_ms * 1e-3,
                sc.spans,
                args.remote_pool,
            )
            entry["balancers"][name] = {
                "idle": float(out["idle"].mean()),
                "idle_steady": float(out["idle"][STEADY_FROM:].mean()),
                "span_idle": float(out["span_idle"].mean()),
                "wall_ms": float(1e3 * out["wall"].mean()),
                "calls_per_tracer": float(out["calls"].mean() / sc.count),
            }
        results.setdefault(sc.orbit, {})[sc.label] = entry
    return results


def spans_text(spans: int) -> str:
    """``1 span``, ``4 spans``."""
    return f"{spans} span{'' if spans == 1 else 's'}"


def spans_headers(results: dict) -> tuple[list[str], bool]:
    """Column headers ``T=<label> (<spans> spans)`` of ``{orbit: {label: entry}}``, and whether
    every column's spans are the same on every orbit (else the tables show a row of them per
    orbit and the headers leave them out)."""
    labels = list(next(iter(results.values())))
    spans = {k: {by_label[k]["spans"] for by_label in results.values()} for k in labels}
    uniform = all(len(s) == 1 for s in spans.values())
    if not uniform:
        return [f"T={k}" for k in labels], False
    return [f"T={k} ({spans_text(next(iter(spans[k])))})" for k in labels], True


def spans_row(orbit: str, by_label: dict) -> list[str]:
    """A table row with the spans per line and the units of each scenario of ``orbit``."""
    cells = [f"{spans_text(e['spans'])}, {e['units']} units" for e in by_label.values()]
    return [f"{orbit} spans a line", *cells]


def print_calls(results: dict, title: str) -> None:
    """A row per orbit and balancer, a column per tracer count: ``idle / span idle / wall ms /
    calls per tracer``; the noise floor on its own row (and the spans, see
    :func:`spans_headers`)."""
    headers, uniform = spans_headers(results)
    rows = []
    for orbit, by_label in results.items():
        labels = list(by_label)
        names = list(by_label[labels[0]]["balancers"])
        if not uniform:
            rows.append(spans_row(orbit, by_label))
        floors = (f"{by_label[k]['noise_floor']:5.2f}" for k in labels)
        rows.append([f"{orbit} noise floor", *floors])
        for name in names:
            cells = []
            for label in labels:
                d = by_label[label]["balancers"][name]
                cells.append(
                    f"{d['idle']:5.2f} /{d['span_idle']:5.2f} /{d['wall_ms']:6.1f} /"
                    f"{d['calls_per_tracer']:4.1f}"
                )
            rows.append([f"{orbit} {name}", *cells])
    print_table(title, ["orbit, balancer", *headers], rows)


def tail_variants() -> dict:
    """The static split and the dynamic tail with one constant changed at a time."""
    variants: dict = {"cost-aware": CostAware, "tail (defaults)": CostAwareTail}
    for fraction in (0.8, 0.9, 0.95, 0.97):
        variants[f"tail fraction={fraction}"] = lambda x=fraction: CostAwareTail(fraction=x)
    for divisor in (1.0, 1.5, 3.0, 4.0):
        variants[f"tail divisor={divisor}"] = lambda x=divisor: CostAwareTail(divisor=x)
    for least in (0.0, 0.01, 0.04, 0.08):
        variants[f"tail min_chunk={least}"] = lambda x=least: CostAwareTail(min_chunk=x)
    for seconds in (0.0, 0.0025, 0.01, 0.02):
        variants[f"tail min_seconds={seconds}"] = lambda x=seconds: CostAwareTail(min_seconds=x)
    for z in (1.0, 2.0, 3.0):
        variants[f"tail z={z}"] = lambda x=z: CostAwareTail(z=x)
    for worth in (0.0, 2.0, 8.0):
        variants[f"tail calls_worth={worth}"] = lambda x=worth: CostAwareTail(calls_worth=x)
    return variants


def print_results(results: dict, title: str) -> None:
    """One table: a row per orbit and balancer, a column per scenario, cells
    ``mean / steady / p95`` (and the spans, see :func:`spans_headers`)."""
    orbits = list(results)
    labels = list(results[orbits[0]])
    headers, uniform = spans_headers(results)
    rows = []
    for orbit in orbits:
        names = list(results[orbit][labels[0]]["balancers"])
        if not uniform:
            rows.append(spans_row(orbit, results[orbit]))
        for name in names:
            cells = []
            for label in labels:
                d = results[orbit][label]["balancers"][name]
                cells.append(f"{d['mean']:5.2f} /{d['steady']:5.2f} /{d['p95']:5.1f}")
            rows.append([f"{orbit} {name}", *cells])
    print_table(title, ["orbit, balancer", *headers], rows)


TARGET_COLUMNS = (
    "run orbit T spans target all steady perfect-smooth oracle noise-floor reachable verdict steady"
)
TARGET_COLUMNS = TARGET_COLUMNS.split()


def check_targets(all_results: dict, model: str, name: str = "cost-aware") -> list[dict]:
    """The issue's targets for the balancer ``name`` at every jitter level, on the mean over
    all frames and over the steady frames; ``model`` names what the runs replayed."""
    checks = []
    for run_key, results in all_results.items():
        for (orbit, label), target in TARGETS.items():
            entry = results.get(orbit, {}).get(label)
            if entry is None or name not in entry["balancers"]:
                continue
            ours = entry["balancers"][name]
            # split-level summaries have mean / steady, call-level ones idle / idle_steady
            mean = ours.get("mean", ours.get("idle"))
            steady = ours.get("steady", ours.get("idle_steady"))
            oracle = entry["balancers"].get(ORACLE)
            smooth = entry["balancers"].get("perfect-smooth")
            checks.append(
                {
                    "run": run_key,
                    "orbit": orbit,
                    "tracers": label,
                    "spans": entry["spans"],
                    "target": target,
                    "mean": mean,
                    "steady": steady,
                    "perfect_smooth_mean": None if smooth is None else smooth["mean"],
                    "oracle_mean": None if oracle is None else oracle["mean"],
                    "noise_floor": entry["noise_floor"],
                    "reachable": None if oracle is None else bool(oracle["mean"] <= target),
                    "verdict_mean": verdict(mean, target, at_most=True),
                    "verdict_steady": verdict(steady, target, at_most=True),
                }
            )
    if checks:

        def cell(value):
            return "-" if value is None else f"{value:.2f}"

        print_table(
            f"targets: {name} idle % ({model}; mean over all frames, over frames 8+); the "
            "oracle's mean is the floor that jitter and whole units leave to a split made "
            "before the frame, the noise floor what jitter alone leaves such a split even with "
            "infinitely divisible work",
            TARGET_COLUMNS,
            [
                [
                    c["run"],
                    c["orbit"],
                    c["tracers"],
                    str(c["spans"]),
                    f"<= {c['target']:.1f}",
                    cell(c["mean"]),
                    cell(c["steady"]),
                    cell(c["perfect_smooth_mean"]),
                    cell(c["oracle_mean"]),
                    cell(c["noise_floor"]),
                    {None: "-", True: "yes", False: "no"}[c["reachable"]],
                    styled_verdict(c["verdict_mean"]),
                    styled_verdict(c["verdict_steady"]),
                ]
                for c in checks
            ],
        )
    return checks


def sweep_variants() -> dict:
    """Variants of the balancers' constants, one changed at a time from the defaults."""
    variants: dict = {}
    variants["robin-hood step=1% of H"] = RobinHood
    for unit in (1, 2, 4, 8):
        variants[f"robin-hood step={unit}"] = lambda u=unit: RobinHood(step=u)
    for alpha in (0.2, 0.3, 0.4, 0.5, 0.6, 0.8, 1.0):
        variants[f"perfect-smooth alpha={alpha}"] = lambda a=alpha: PerfectSmooth(alpha=a)
    variants["cost-aware (defaults)"] = CostAware
    for abp in CostAware.PREDICTORS:
        variants["cost-aware only a={} b={} phi={}".format(*abp)] = lambda p=abp: CostAware(
            predictors=[p]
        )
    for blur in (0, 2, 4):
        variants[f"cost-aware blur={blur}"] = lambda r=blur: CostAware(blur=r)
    for gamma in (0.1, 0.2, 0.5, 1.0):
        variants[f"cost-aware speed_alpha={gamma}"] = lambda g=gamma: CostAware(speed_alpha=g)
    for w in (0.05, 0.3, 1.0):
        variants[f"cost-aware error_alpha={w}"] = lambda w=w: CostAware(error_alpha=w)
    return variants


def plot(results: dict, path: Path, jitter: str) -> bool:
    """Idle % per frame, one panel per orbit and scenario (figure 48's layout)."""
    plt = pyplot()
    if plt is None:
        return False
    panels = [(o, s) for o, by in results.items() for s in by]
    cols = len(results)
    rows = max(len(by) for by in results.values())
    fig, axes = plt.subplots(
        rows, cols, figsize=(4.2 * cols, 2.4 * rows), squeeze=False, sharex=True
    )
    for c, (orbit, by_label) in enumerate(results.items()):
        for r, (label, entry) in enumerate(by_label.items()):
            ax = axes[r][c]
            for name, data in entry["balancers"].items():
                style = {"linestyle": ":", "color": "grey"} if name == ORACLE else {}
                ax.plot(data["per_frame"], label=name, linewidth=0.8, **style)
            ax.set_yscale("symlog", linthresh=1.0)
            ax.set_ylim(0, 100)
            size = f"{entry['lines']} lines x {spans_text(entry['spans'])}"
            ax.set_title(f"{orbit}, T={label} ({size}; {jitter})", fontsize=9)
            ax.tick_params(labelsize=7)
            if c == 0:
                ax.set_ylabel("idle %", fontsize=8)
    for c in range(cols):
        axes[-1][c].set_xlabel("frame", fontsize=8)
    for r in range(rows):
        for c in range(cols):
            if r >= len(list(results.values())[c]):
                axes[r][c].axis("off")
    handles, names = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, names, loc="upper center", ncol=len(names), fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(path, dpi=72)
    plt.close(fig)
    console.print(f"[dim]plot written to {path.relative_to(REPO_ROOT)} ({len(panels)} panels)[/]")
    return True


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0],
        epilog=__doc__.split("\n\n", 1)[1],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--orbits",
        nargs="+",
        default=["slow", "fast", "slow-hd", "fast-hd"],
        help="traces in bench/traces/ to replay (default: %(default)s)",
    )
    parser.add_argument(
        "--tracers",
        nargs="+",
        type=int,
        default=[2, 3, 8, 32, 128],
        help="tracer counts with unequal speeds (default: %(default)s)",
    )
    parser.add_argument(
        "--no-equal",
        action="store_true",
        help="leave out the 2-tracer equal-speed scenario (Table 16's set-up)",
    )
    parser.add_argument(
        "--balancers",
        nargs="+",
        default=None,
        choices=[*BALANCERS, ORACLE],
        help="balancers to run (default: all but cost-aware-static, cost-aware-tail and the "
        "oracle's; with --calls: cost-aware and cost-aware-tail). cost-aware and "
        "cost-aware-tail hand units out within the frame, which only the --calls model "
        "replays: without --calls both are cost-aware-static",
    )
    parser.add_argument("--frames", type=int, default=128, help="frames to replay (default 128)")
    parser.add_argument(
        "--spans",
        type=spans_option,
        default="auto",
        help="spans per line, the work units every model balances: 'auto' for the "
        "coordinator's choice per orbit and tracer count (WorkUnits.for_tracers), or a power "
        "of two up to the trace's recorded spans (1: whole lines; traces recorded without "
        "spans allow only 1) (default: %(default)s)",
    )
    parser.add_argument(
        "--jitter",
        nargs="+",
        type=float,
        default=[0.05, 0.01, 0.0],
        help="sigmas of the lognormal timing noise, one full run each (default: %(default)s)",
    )
    parser.add_argument(
        "--overhead-ms",
        type=float,
        default=0.5,
        help="fixed cost of every non-empty range (default %(default)s ms)",
    )
    parser.add_argument(
        "--frame-ms",
        type=float,
        default=50.0,
        help="a perfectly balanced frame's time (default %(default)s ms)",
    )
    parser.add_argument(
        "--speed-range",
        nargs=2,
        type=float,
        default=[0.5, 2.0],
        metavar=("LOW", "HIGH"),
        help="relative tracer speeds, log-uniform (default 0.5 2)",
    )
    parser.add_argument("--seed", type=int, default=1, help="seed of speeds and jitter (1)")
    parser.add_argument(
        "--lag",
        nargs="+",
        type=int,
        default=[0, 1],
        help="frames split before the previous frame is observed, one full run each: 0 as in "
        "Brigade, 1 for cluster.coordinator's two-frame pipeline (default: %(default)s); the "
        "first is plotted",
    )
    parser.add_argument(
        "--sweep",
        action="store_true",
        help="instead of the balancers: variants of their constants (robin-hood's unit, "
        "perfect-smooth's alpha, cost-aware's forecasters, blur and smoothing weights)",
    )
    parser.add_argument(
        "--name",
        default=None,
        help="results files bench/results/NAME.json and NAME.png (default balance_sim; with "
        "--sweep no file is written unless a name is given)",
    )
    parser.add_argument(
        "--plot-jitter",
        type=float,
        default=0.01,
        help="jitter level to plot, at the first lag (default %(default)s; the first of "
        "--jitter if not run)",
    )
    parser.add_argument("--no-plot", action="store_true", help="do not write the PNG plot")
    parser.add_argument(
        "--calls",
        action="store_true",
        help="instead of the tables above: the call-level model (latency, the gap between a "
        "tracer's calls) for the balancers given with --balancers (default cost-aware and "
        "cost-aware-tail), with idle, span idle, wall time and calls per tracer",
    )
    parser.add_argument(
        "--pool",
        dest="pool_claim_ms",
        type=float,
        nargs="?",
        const=0.05,
        default=None,
        metavar="CLAIM_MS",
        help="with --calls: the tail goes to a shared pool the tracers claim chunks from, "
        "CLAIM_MS per claim (default %(const)s ms: the file pool of tracers sharing one "
        "machine, a file lock, a kernel launch and the chunk's result), instead of Ray calls",
    )
    parser.add_argument(
        "--remote-pool",
        action="store_true",
        help="with --calls: tracers on several machines, so only cost-aware-tail pools its "
        "tail, in the actor pool (worker.remote_pool): each claim is sent while the chunk "
        "before it renders and costs a tracer 0.15 ms (unless --pool sets it), chunks at "
        "least twice the pool's round trip (worker.remote_pool.REMOTE_CLAIM_SECONDS); "
        "cost-aware keeps no tail there",
    )
    parser.add_argument(
        "--tail-sweep",
        action="store_true",
        help="with --calls: the dynamic tail's constants, one changed at a time",
    )
    parser.add_argument(
        "--latency-ms",
        type=float,
        default=0.6,
        help="--calls: one-way coordinator-tracer latency (default %(default)s ms: half the "
        "1.15 ms a 1-line render call's round trip exceeds its render time, measured by "
        "bench/cluster.py --skip scaling idle recovery --orbit-size 640 480)",
    )
    parser.add_argument(
        "--call-gap-ms",
        type=float,
        default=0.9,
        help="--calls: a tracer's time outside rendering per call when calls are queued "
        "back to back (default %(default)s ms: 0.86 ms measured by the same command)",
    )
    args = parser.parse_args(argv)
    if args.frames < 1 or min(args.tracers) < 1 or min(args.jitter) < 0 or args.overhead_ms < 0:
        parser.error("--frames and --tracers must be positive, --jitter and --overhead-ms >= 0")
    if min(args.lag) < 0:
        parser.error("--lag must be >= 0")
    if args.calls and args.sweep:
        parser.error("--sweep runs the split-level model; with --calls use --tail-sweep")
    if not args.calls and (args.tail_sweep or args.pool_claim_ms is not None or args.remote_pool):
        parser.error(
            "--tail-sweep, --pool and --remote-pool belong to the call-level model: add --calls"
        )
    if args.remote_pool and args.pool_claim_ms is None:
        args.pool_claim_ms = 0.15
    if args.pool_claim_ms is not None and args.pool_claim_ms < 0:
        parser.error("--pool's claim time must be >= 0 ms")
    if args.name is not None and not args.name.replace("_", "").replace("-", "").isalnum():
        parser.error("--name is a file name without a directory: letters, digits, - and _")
    if not 0 < args.speed_range[0] <= args.speed_range[1]:
        parser.error("--speed-range needs 0 < LOW <= HIGH")
    if problem := check_spans(args):
        parser.error(problem)

    machine = machine_info()
    print_machine(machine)
    start = time.perf_counter()
    options = dict(vars(args))
    if args.calls:
        return main_calls(args, options, machine)
    if args.balancers is None:
        # Without --calls the cost-aware balancers are their static split: one row of them.
        static = ("cost-aware-static", "cost-aware-tail")
        args.balancers = [*(b for b in BALANCERS if b not in static), ORACLE]
    if args.sweep:
        factories = sweep_variants()
    else:
        factories = {
            name: (ORACLE if name == ORACLE else (lambda n=name: make_balancer(n)))
            for name in args.balancers
        }
    all_results = {}
    shown = args.plot_jitter if args.plot_jitter in args.jitter else args.jitter[0]
    for lag in args.lag:
        for sigma in args.jitter:
            key = result_key(sigma, lag)
            plotted = sigma == shown and lag == args.lag[0] and not args.sweep
            all_results[key] = run(args, factories, sigma, lag, keep_frames=plotted)
            print_results(
                all_results[key],
                f"{'sweep: ' if args.sweep else ''}idle %, mean over all {args.frames} frames / "
                f"over frames {STEADY_FROM}+ / 95th percentile over frames {STEADY_FROM}+; "
                f"{key}",
            )
    console.print(
        f"[dim]overhead {args.overhead_ms:g} ms per range, balanced frame {args.frame_ms:g} "
        f"ms, speeds log-uniform in {args.speed_range} (seed {args.seed}); "
        f"{time.perf_counter() - start:.1f} s[/]"
    )
    if args.sweep:
        if args.name:
            write_results(args.name, {"options": options, "results": all_results}, machine)
        return 0
    args.name = args.name or "balance_sim"
    checks = check_targets(
        all_results,
        "its static split, as across machines; the pooled tail of tracers sharing a machine "
        "is replayed with --calls --pool",
    )
    payload = {"options": options, "targets": checks, "results": all_results}
    write_results(args.name, payload, machine)
    if not args.no_plot:
        RESULTS_DIR.mkdir(parents=True, exist_ok=True)
        key = result_key(shown, args.lag[0])
        plot(all_results[key], RESULTS_DIR / f"{args.name}.png", key)
    return 0


def main_calls(args, options: dict, machine: dict) -> int:
    """The call-level comparison (``--calls``): tables per jitter and lag, JSON results."""
    if args.tail_sweep:
        factories = tail_variants()
    else:
        names = [n for n in args.balancers or ["cost-aware", "cost-aware-tail"] if n != ORACLE]
        factories = {name: (lambda n=name: make_balancer(n)) for name in names}
    start = time.perf_counter()
    all_results = {}
    for lag in args.lag:
        for sigma in args.jitter:
            key = result_key(sigma, lag)
            all_results[key] = run_calls(args, factories, sigma, lag)
            print_calls(
                all_results[key],
                f"{'tail sweep: ' if args.tail_sweep else ''}"
                f"{'shared unit pool: ' if args.pool_claim_ms is not None else ''}"
                f"{'actor pool (claims sent ahead): ' if args.remote_pool else ''}"
                f"calls: idle % (gaps count) / span "
                f"idle % (latency counts) / wall ms / calls per tracer, means over "
                f"{args.frames} frames; {key}",
            )
    console.print(
        f"[dim]latency {args.latency_ms:g} ms each way, {args.call_gap_ms:g} ms per call "
        f"outside rendering, {args.overhead_ms:g} ms per call inside, balanced frame "
        f"{args.frame_ms:g} ms; {time.perf_counter() - start:.1f} s[/]"
    )
    pooled = args.pool_claim_ms is not None
    pool = "balance_pool_remote" if args.remote_pool else "balance_pool"
    name = args.name or (
        "balance_tail_sweep" if args.tail_sweep else pool if pooled else "balance_tail"
    )
    checks = []
    if pooled and not args.tail_sweep:
        if args.remote_pool:
            checks = check_targets(all_results, "tracers on several machines", "cost-aware-tail")
        else:
            checks = check_targets(all_results, "as the coordinator runs it: a file pool")
    payload = {"options": options, "targets": checks, "results": all_results}
    write_results(name, payload, machine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
