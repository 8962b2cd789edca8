"""Helpers shared by the benchmarks: timing statistics, side-by-side runs, tables, result files.

Every benchmark measures its contenders in one process run, interleaved (A, B, C, A, B, C, ...),
so that slow drifts of a shared, noisy machine hit all of them alike; it reports the median and
the best of the repeats, and ratios of those. Results go to ``bench/results/NAME.json``
together with a description of the machine.
"""

import datetime as dt
import json
import os
import platform
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from rich.console import Console
from rich.table import Table

BENCH_DIR = Path(__file__).resolve().parent
REPO_ROOT = BENCH_DIR.parent
RESULTS_DIR = BENCH_DIR / "results"

# The packages come first, before bench/ itself (which `python bench/NAME.py` puts first): else
# bench/cluster.py would shadow the cluster package whenever the root is on the path too (for
# example through PYTHONPATH).
if str(REPO_ROOT) in sys.path:
    sys.path.remove(str(REPO_ROOT))
sys.path.insert(0, str(REPO_ROOT))

console = Console(
    highlight=False, width=None if sys.stdout.isatty() or "COLUMNS" in os.environ else 160
)
"""The benchmarks' console; wide when writing to a file or pipe (``COLUMNS=240`` for wider),
so tables keep one line a row."""


# --- machine -----------------------------------------------------------------------------------


def cpu_model() -> str:
    """The CPU's model name from /proc/cpuinfo (or what ``platform`` knows elsewhere)."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def usable_cores() -> int:
    """CPUs this process may run on (its affinity mask), the default thread count everywhere."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def package_version(name: str) -> str | None:
    """Installed version of a distribution, or None if it is not installed."""
    from importlib import metadata

    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


def git_revision() -> str | None:
    """``HEAD``'s commit, with ``+dirty`` when the working tree has changes (None outside git)."""
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short=12", "HEAD"],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=REPO_ROOT,
            capture_output=True,
            text=True,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return None
    return head + ("+dirty" if dirty else "")


def machine_info() -> dict[str, Any]:
    """What a result depends on besides the code: CPU, cores, load and library versions."""
    return {
        "cpu_model": cpu_model(),
        "logical_cpus": os.cpu_count(),
        "usable_cores": usable_cores(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": package_version("numpy"),
        "numba": package_version("numba"),
        "git": git_revision(),
    }


# --- timing ------------------------------------------------------------------------------------


def time_call(fn: Callable[[], Any]) -> tuple[float, Any]:
    """Wall-clock seconds of one call of ``fn`` and its result."""
    start = time.perf_counter()
    result = fn()
    return time.perf_counter() - start, result


@dataclass
class Series:
    """Repeated measurements of one contender: ``seconds`` per run and ``work`` units per run
    (samples, rays, ...), so ``rates`` are work per second."""

    name: str
    work: float
    seconds: list[float] = field(default_factory=list)

    @property
    def rates(self) -> list[float]:
        return [self.work / s for s in self.seconds]

    @property
    def median_rate(self) -> float:
        return statistics.median(self.rates)

    @property
    def best_rate(self) -> float:
        return max(self.rates)

    @property
    def median_seconds(self) -> float:
        return statistics.median(self.seconds)

    @property
    def best_seconds(self) -> float:
        return min(self.seconds)

    def summary(self, scale: float = 1.0) -> dict[str, Any]:
        """Seconds and rates (divided by ``scale``, e.g. 1e6 for millions) for the JSON file."""
        return {
            "work": self.work,
            "seconds": self.seconds,
            "median_seconds": self.median_seconds,
            "best_seconds": self.best_seconds,
            "rate_scale": scale,
            "median_rate": self.median_rate / scale,
            "best_rate": self.best_rate / scale,
        }


@dataclass
class Contender:
    """One side of a comparison: ``run(round)`` is timed; ``prepare()``, if given, runs untimed
    just before it (e.g. to switch a library into the right mode)."""

    run: Callable[[int], Any]
    prepare: Callable[[], None] | None = None


def interleaved(
    contenders: Mapping[str, Contender],
    work: Mapping[str, float],
    repeats: int,
    on_result: Callable[[str, int, Any], None] | None = None,
) -> dict[str, Series]:
    """Run every contender once per round, in order, for ``repeats`` rounds; time each run.

    ``on_result(name, round, value)`` sees what each run returned (for validation).
    """
    series = {name: Series(name, work[name]) for name in contenders}
    for round_index in range(repeats):
        for name, contender in contenders.items():
            if contender.prepare is not None:
                contender.prepare()
            seconds, value = time_call(lambda c=contender, r=round_index: c.run(r))
            series[name].seconds.append(seconds)
            if on_result is not None:
                on_result(name, round_index, value)
    return series


def ratios(ours: Series, theirs: Series) -> dict[str, float]:
    """Throughput ratios ours/theirs: of the medians, of the bests, and the median of the
    per-round ratios (each round's runs were adjacent in time)."""
    paired = [a / b for a, b in zip(ours.rates, theirs.rates, strict=True)]
    return {
        "median": ours.median_rate / theirs.median_rate,
        "best": ours.best_rate / theirs.best_rate,
        "paired_median": statistics.median(paired),
    }


# --- reporting ---------------------------------------------------------------------------------


def verdict(value: float, target: float, at_most: bool = False) -> str:
    """``PASS`` if ``value`` meets ``target`` (>= by default, <= with ``at_most``), else MISS."""
    ok = value <= target if at_most else value >= target
    return "PASS" if ok else "MISS"


def styled_verdict(text: str) -> str:
    """A PASS/MISS verdict coloured for the terminal."""
    colour = {"PASS": "green", "MISS": "red"}.get(text, "yellow")
    return f"[bold {colour}]{text}[/]"


def print_table(
    title: str,
    columns: Sequence[str],
    rows: Iterable[Sequence[Any]],
    caption: str | None = None,
) -> None:
    """Print a rich table; the first column is left-aligned, the others right-aligned."""
    table = Table(title=title, caption=caption, title_justify="left", caption_justify="left")
    for i, column in enumerate(columns):
        table.add_column(column, justify="left" if i == 0 else "right", no_wrap=True)
    for row in rows:
        table.add_row(*(str(cell) for cell in row))
    console.print(table)


def print_machine(info: Mapping[str, Any]) -> None:
    """One line about the machine a benchmark ran on."""
    load = info.get("load_average")
    load_text = f", load {load[0]:.2f}" if load else ""
    console.print(
        f"[dim]{info['cpu_model']}, {info['usable_cores']} usable cores{load_text}; "
        f"python {info['python']}, numba {info['numba']}, numpy {info['numpy']}; "
        f"git {info['git']}[/]"
    )


def note(message: str) -> None:
    """A side remark (a skipped contender, a warm-up time) on the console."""
    console.print(f"[yellow]note:[/] {message}")


def write_results(name: str, payload: Mapping[str, Any], machine: Mapping[str, Any]) -> Path:
    """Write ``bench/results/NAME.json`` (payload plus machine and time) and return its path."""
    RESULTS_DIR.mkdir(parents=True, exist_ok=True)
    path = RESULTS_DIR / f"{name}.json"
    document = {
        "benchmark": name,
        "time": dt.datetime.now(dt.UTC).isoformat(timespec="seconds"),
        "command": [Path(sys.argv[0]).name, *sys.argv[1:]],
        "machine": dict(machine),
        **payload,
    }
    path.write_text(json.dumps(document, indent=2, default=_json_default) + "\n")
    console.print(f"[dim]results written to {path.relative_to(REPO_ROOT)}[/]")
    return path


def _json_default(value: Any) -> Any:
    """numpy scalars and arrays in JSON."""
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


def fmt_float(value: float | None, digits: int = 2) -> str:
    """A number for a table cell (``-`` for None)."""
    return "-" if value is None else f"{value:.{digits}f}"


class TreeWorker:
    """A warm worker process running ``script`` (``python -c``) with ``args`` against the
    source tree ``tree`` and its own kernel cache: it answers each request line with one JSON
    line, and its first line says it is ready (kernels loaded). ``compare_trees`` and
    ``compare_raycast`` time two trees side by side with two of these."""

    def __init__(self, script: str, args: Sequence[str], tree: str, cache: str) -> None:
        env = {**os.environ, "PYTHONPATH": tree, "TILERENDER_NUMBA_CACHE": cache}
        self.process = subprocess.Popen(
            [sys.executable, "-c", script, *args],
            cwd=tree,
            env=env,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.read()  # warmed up

    def read(self) -> dict:
        line = self.process.stdout.readline()
        if not line:
            raise RuntimeError("a worker process died (see its error output above)")
        return json.loads(line)

    def ask(self, request: str) -> dict:
        """Send one request line; return the JSON answer."""
        self.process.stdin.write(request + "\n")
        self.process.stdin.flush()
        return self.read()

    def close(self) -> None:
        self.process.stdin.close()
        self.process.wait()


def pyplot():
    """matplotlib's pyplot on the Agg backend, or None (with a note) when matplotlib is not
    installed (it comes with the ``study`` extra)."""
    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        note("matplotlib is not installed (pip install -e '.[study]'): no plot written")
        return None
    return plt
