"""A frame in flight: its job state, its render calls, and the limits its run keeps to."""

from dataclasses import dataclass, field

from cluster.assembler import Assembler
from cluster.balancing.tail_plan import TailPlan
from cluster.fleet import TracerSlot
from cluster.frame import Frame, RangeReport
from cluster.scene_graph import SceneGraph
from tracer.request import FrameRequest
from tracer.scene.model import SceneState
from worker.line_pool import LinePool
from worker.remote_pool import RemotePool
from worker.tracer_actor import UnitsResult
from worker.work_units import WorkUnits


@dataclass(frozen=True)
class Limits:
    """How long a frame may take and how often a range may be handed out."""

    straggler_factor: float
    """A range is a straggler after this many times its predicted time ..."""
    straggler_floor: float
    """... plus this many seconds (Ray call latency and timing jitter of tiny frames)."""
    max_attempts: int
    """Times a unit range may be handed out (failures, resyncs) before the frame is given up."""
    stall_timeout: float
    """Seconds a frame may go without any result arriving before it is given up."""


@dataclass(eq=False)
class Call:
    """One render call of a frame in flight."""

    slot: TracerSlot
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

    request: FrameRequest
    """The frame's request, resolved at the version it is pinned to."""
    graph: SceneGraph
    state: SceneState
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
    def frame(self) -> int:
        return self.request.frame

    @property
    def version(self) -> int:
        return self.state.version
