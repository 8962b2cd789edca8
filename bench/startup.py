"""Start-up time of the command line: cold (every kernel compiles) and warm (kernels cached).

Cold: ``tilerender render`` of a 32x32, 1 spp Cornell box with ``TILERENDER_NUMBA_CACHE``
pointing at a fresh, empty directory, so numba compiles every kernel it needs. Warm: the same
command again with the same cache directory, repeated; this is "warm start to first pixel". A
still this small renders in the command's own process by default; the same command with
``--no-in-process`` (through a tracer actor on an embedded Ray) is timed beside it, as are
importing the tracer (``python -c "import tracer.render, tracer.scene.loader"``) and the bare
interpreter (``python -c pass``), interleaved with the warm runs.

``--base TREE`` times cold starts of another source tree (a checkout, run with ``PYTHONPATH``
set to it) alternating with this one's, ``--cold-repeats`` rounds, each with an empty cache of
its own: what a change did to the compile time.
"""

import argparse
import functools
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

from common import (
    REPO_ROOT,
    Contender,
    Series,
    console,
    fmt_float,
    interleaved,
    machine_info,
    print_machine,
    print_table,
    styled_verdict,
    time_call,
    verdict,
    write_results,
)

SCENE = REPO_ROOT / "scenes" / "cornell-box" / "scene.json"
COLD_TARGET = 30.0
WARM_TARGET = 3.0
"""Most seconds for a cold and a warm start."""
CLI = "tilerender render (warm)"
CLI_RAY = "tilerender render --no-in-process (warm, embedded Ray)"
IMPORT = "import tracer"
PYTHON = "python -c pass"


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Cold and warm start of `tilerender render` (32x32, 1 spp Cornell box) with "
        "a fresh numba cache, warm starts in process and through the embedded Ray, and the cost "
        "of importing the tracer. "
        "Writes bench/results/startup.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--repeats", type=int, default=5, help="warm runs (and import runs)")
    parser.add_argument("--scene", type=Path, default=SCENE, help="scene to render")
    parser.add_argument(
        "--skip-cold", action="store_true", help="reuse the user's kernel cache, no cold start"
    )
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds allowed per run")
    parser.add_argument(
        "--base", type=Path, help="another source tree whose cold starts alternate with this one's"
    )
    parser.add_argument("--cold-repeats", type=int, default=1, help="cold starts per tree")
    args = parser.parse_args(argv)
    args.scene = args.scene.resolve()
    if args.repeats < 1 or args.cold_repeats < 1:
        parser.error("--repeats and --cold-repeats must be at least 1")
    if args.base is not None and not (args.base / "cli" / "main.py").is_file():
        parser.error(f"--base {args.base}: not a tilerender source tree (no cli/main.py)")
    if args.base is not None and args.skip_cold:
        parser.error("--base compares cold starts: drop --skip-cold")
    return args


def tilerender_executable() -> list[str]:
    """The ``tilerender`` console script next to this interpreter (else ``python -m``)."""
    script = Path(sys.executable).with_name("tilerender")
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-m", "cli.main"]


def child_env(cache: Path | None) -> dict[str, str]:
    """The environment of a timed run: our kernel cache directory (or the user's default)."""
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    if cache is not None:
        env["TILERENDER_NUMBA_CACHE"] = str(cache)
    return env


def run_command(
    command: list[str], env: dict[str, str], timeout: float, cwd: Path = REPO_ROOT
) -> None:
    """Run ``command`` (from ``cwd``); raise with its stderr if it fails."""
    result = subprocess.run(
        command, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout
    )
    if result.returncode != 0:
        raise RuntimeError(
            f"{' '.join(command)} exited with {result.returncode}:\n{result.stderr.strip()}"
        )


def render_command(scene: Path, output: Path) -> list[str]:
    return [
        *tilerender_executable(),
        "render",
        str(scene),
        "-o",
        str(output),
        "--spp",
        "1",
        "--width",
        "32",
        "--height",
        "32",
        "-q",
    ]


def display_command(command: list[str], scene: Path) -> str:
    """``command`` as a user would type it (program name, relative scene, OUT.npy)."""
    shown = ["tilerender", *command[command.index("render") :]]
    shown[shown.index("-o") + 1] = "OUT.npy"
    if scene.resolve().is_relative_to(REPO_ROOT):
        shown[2] = str(scene.resolve().relative_to(REPO_ROOT))
    return " ".join(shown)


def cache_size(directory: Path) -> tuple[int, int]:
    """Number of files and bytes under ``directory``."""
    files = [p for p in directory.rglob("*") if p.is_file()]
    return len(files), sum(p.stat().st_size for p in files)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    machine = machine_info()
    print_machine(machine)
    work = Path(tempfile.mkdtemp(prefix="tilerender-startup-"))
    try:
        results = measure(args, work)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    results["verdicts"] = report(results)
    write_results(
        "startup",
        {"settings": vars(args) | {"scene": str(args.scene), "base": str(args.base)}, **results},
        machine,
    )
    return 0


def measure(args: argparse.Namespace, work: Path) -> dict:
    """Time the cold start (unless skipped), then the warm starts and imports interleaved."""
    cache = None if args.skip_cold else work / "numba-cache"
    env = child_env(cache)
    output = work / "out.npy"
    command = render_command(args.scene, output)
    results: dict = {"command": display_command(command, args.scene)}
    if cache is not None:
        cold = cold_starts(args, work, command)
        files, size = cache_size(cache)
        results["cold"] = {
            "seconds": statistics.median(cold["tree"]),
            "runs": cold["tree"],
            "cache_files": files,
            "cache_bytes": size,
        }
        if args.base is not None:
            results["cold_base"] = {
                "tree": str(args.base),
                "seconds": statistics.median(cold["base"]),
                "runs": cold["base"],
            }
    else:
        with console.status("warm-up run (compiles the kernels if the user's cache is stale)"):
            run_command(command, env, args.timeout)
    contenders = {
        CLI: Contender(lambda _: run_command(command, env, args.timeout)),
        CLI_RAY: Contender(lambda _: run_command([*command, "--no-in-process"], env, args.timeout)),
        IMPORT: Contender(
            lambda _: run_command(
                [sys.executable, "-c", "import tracer.render, tracer.scene.loader"],
                env,
                args.timeout,
            )
        ),
        PYTHON: Contender(lambda _: run_command([sys.executable, "-c", "pass"], env, args.timeout)),
    }
    with console.status(f"warm starts: {args.repeats} rounds"):
        series = interleaved(contenders, dict.fromkeys(contenders, 1.0), args.repeats)
    results["warm"] = {name: seconds_summary(s) for name, s in series.items()}
    return results


def cold_starts(args: argparse.Namespace, work: Path, command: list[str]) -> dict[str, list]:
    """Seconds of each cold start, by tree (``tree``, and ``base`` with ``--base``), taking
    turns at going first. This tree's last cold start leaves its kernels in ``numba-cache``."""
    trees = {"tree": (REPO_ROOT, command)}
    if args.base is not None:
        base = args.base.resolve()
        base_command = [sys.executable, "-m", "cli.main", *command[command.index("render") :]]
        trees["base"] = (base, base_command)
    seconds: dict[str, list] = {name: [] for name in trees}
    for round_ in range(args.cold_repeats):
        order = list(trees) if round_ % 2 == 0 else list(reversed(trees))
        for name in order:
            cwd, run = trees[name]
            cache = work / ("numba-cache" if name == "tree" else "numba-base")
            shutil.rmtree(cache, ignore_errors=True)
            cache.mkdir()
            env = child_env(cache) | ({"PYTHONPATH": str(cwd)} if name == "base" else {})
            start = functools.partial(run_command, run, env, args.timeout, cwd)
            with console.status(f"cold start {round_ + 1} of {name}: an empty kernel cache"):
                elapsed, _ = time_call(start)
            seconds[name].append(elapsed)
    return seconds


def seconds_summary(series: Series) -> dict:
    return {
        "seconds": series.seconds,
        "median_seconds": series.median_seconds,
        "best_seconds": series.best_seconds,
    }


def report(results: dict) -> dict[str, str]:
    """Print the start-up table; return the verdicts."""
    rows, verdicts = [], {}
    cold = results.get("cold")
    if cold is not None:
        mb = cold["cache_bytes"] / 1e6
        verdicts["cold"] = verdict(cold["seconds"], COLD_TARGET, at_most=True)
        rows.append(
            [
                f"tilerender render (cold: {cold['cache_files']} cache files, {mb:.1f} MB)",
                fmt_float(cold["seconds"]),
                fmt_float(min(cold["runs"])),
                f"<= {COLD_TARGET:g}",
                styled_verdict(verdicts["cold"]),
            ]
        )
    base = results.get("cold_base")
    if base is not None:
        ratio = cold["seconds"] / base["seconds"]
        rows.append(
            [
                f"the same, --base {base['tree']} (cold; this tree takes {ratio:.2f}x)",
                fmt_float(base["seconds"]),
                fmt_float(min(base["runs"])),
                "",
                "",
            ]
        )
    for name, s in results["warm"].items():
        target, outcome = "", ""
        if name == CLI:
            verdicts["warm"] = verdict(s["median_seconds"], WARM_TARGET, at_most=True)
            target, outcome = f"<= {WARM_TARGET:g}", styled_verdict(verdicts["warm"])
        rows.append(
            [name, fmt_float(s["median_seconds"]), fmt_float(s["best_seconds"]), target, outcome]
        )
    print_table(
        f"Start-up: {results['command']}",
        ["run", "median s", "best s", "target", "verdict"],
        rows,
        caption="wall time of each subprocess; cold runs (median) alternate between trees, "
        "the others are interleaved",
    )
    return verdicts


if __name__ == "__main__":
    sys.exit(main())
