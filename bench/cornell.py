"""Cornell box: tilerender against Mitsuba 3 (scalar_rgb and llvm_ad_rgb) on the same workload.

The workload is Mitsuba's own ``cornell_box()`` (which ``scenes/cornell-box`` reproduces), a
path tracer with ``max_depth`` 8, 256x256 pixels, 64 samples per pixel, on every core. All
renderers run in this process, interleaved round by round after a warm-up render each, and the
script reports samples per second (pixels * spp / seconds) with the throughput ratios
tilerender/Mitsuba, plus each renderer's mean RGB next to the reference mean as a sanity check.

Mitsuba is optional (``pip install mitsuba``); its LLVM variant needs a libLLVM that can select
``fminimum`` (LLVM >= 15; the system's may abort): ``bench/get_libllvm.sh`` fetches one into
``.cache/llvm``, or set ``DRJIT_LIBLLVM_PATH``.
"""

import argparse
import importlib.util
import os
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np
from common import (
    REPO_ROOT,
    Contender,
    Series,
    console,
    fmt_float,
    interleaved,
    machine_info,
    note,
    package_version,
    print_machine,
    print_table,
    ratios,
    styled_verdict,
    time_call,
    usable_cores,
    verdict,
    write_results,
)

SCENE = REPO_ROOT / "scenes" / "cornell-box" / "scene.json"
REFERENCE_MEAN = REPO_ROOT / "scenes" / "cornell-box" / "reference_mean.npy"
REFERENCE_VAR = REPO_ROOT / "scenes" / "cornell-box" / "reference_var_of_mean.npy"
REFERENCE_SPP = 8192
LLVM_CACHE = REPO_ROOT / ".cache" / "llvm"
OURS = "tilerender"
VARIANTS = ("scalar_rgb", "llvm_ad_rgb")
TARGETS = {"scalar_rgb": 1.5, "llvm_ad_rgb": 0.5}
"""Least acceptable throughput ratio tilerender / Mitsuba variant."""


@dataclass(frozen=True)
class Workload:
    width: int
    height: int
    spp: int
    max_depth: int
    threads: int

    @property
    def samples(self) -> int:
        return self.width * self.height * self.spp


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        description="Cornell box samples/s: tilerender vs Mitsuba 3 scalar_rgb and llvm_ad_rgb, "
        "interleaved in one run. Writes bench/results/cornell.json.",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument("--width", type=int, default=256, help="image width")
    parser.add_argument("--height", type=int, default=256, help="image height")
    parser.add_argument("--spp", type=int, default=64, help="samples per pixel")
    parser.add_argument("--max-depth", type=int, default=8, help="longest path (both renderers)")
    parser.add_argument(
        "--threads", type=int, default=usable_cores(), help="render threads for every renderer"
    )
    parser.add_argument("--repeats", type=int, default=5, help="timed rounds of every renderer")
    parser.add_argument(
        "--variants",
        default=",".join(VARIANTS),
        help="comma-separated Mitsuba variants to compare against ('' for none)",
    )
    args = parser.parse_args(argv)
    for name in ("width", "height", "spp", "max_depth", "threads", "repeats"):
        if getattr(args, name) < 1:
            parser.error(f"--{name.replace('_', '-')} must be at least 1")
    args.variants = [v for v in args.variants.split(",") if v]
    return args


# --- tilerender ------------------------------------------------------------------------------


def tilerender_contender(workload: Workload) -> Contender:
    """Render the repo's Cornell box scene; round ``r`` uses seed ``r``."""
    # Imported here, after Mitsuba: Dr.Jit then loads its libLLVM before numba's llvmlite does
    # (the order this benchmark is tested in).
    from tracer.compiled.scene import compile_scene
    from tracer.render import render_image
    from tracer.scene import format as fmt
    from tracer.scene.loader import load_scene

    scene = compile_scene(load_scene(SCENE))
    camera = fmt.override(scene.camera, width=workload.width, height=workload.height)

    def run(round_index: int) -> np.ndarray:
        settings = fmt.override(
            scene.render, spp=workload.spp, max_depth=workload.max_depth, seed=round_index
        )
        rgb, _ = render_image(scene, camera, settings, threads=workload.threads)
        return rgb

    return Contender(run)


# --- Mitsuba ---------------------------------------------------------------------------------


def find_libllvm() -> Path | None:
    """``DRJIT_LIBLLVM_PATH`` if set, else the newest libLLVM that get_libllvm.sh unpacked."""
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    if configured:
        return Path(configured) if Path(configured).is_file() else None
    found = sorted(LLVM_CACHE.glob("root/usr/lib/*/libLLVM.so.*"))
    return found[-1] if found else None


PROBE = """
import numpy as np, mitsuba as mi
mi.set_variant("llvm_ad_rgb")
scene = mi.cornell_box()
scene["sensor"]["film"]["width"] = scene["sensor"]["film"]["height"] = 8
np.array(mi.render(mi.load_dict(scene), spp=1))
"""


def llvm_problem(libllvm: Path) -> str | None:
    """Why Mitsuba's LLVM variants cannot run with ``libllvm`` (None if a tiny render works).

    The probe runs in a subprocess because an unsuitable libLLVM aborts the process.
    """
    env = dict(os.environ, DRJIT_LIBLLVM_PATH=str(libllvm))
    try:
        probe = subprocess.run(
            [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, timeout=600
        )
    except subprocess.TimeoutExpired:
        return "a test render did not finish in 10 minutes"
    if probe.returncode == 0:
        return None
    lines = probe.stderr.strip().splitlines()
    errors = [line for line in lines if "ERROR" in line or "Error" in line]
    detail = (errors or lines or [""])[-1 if not errors else 0].strip()
    return f"a test render failed (exit code {probe.returncode}): {detail}"


def usable_variants(variants: list[str]) -> tuple[ModuleType | None, list[str]]:
    """Import Mitsuba and keep the variants that can run here, explaining each one skipped.

    Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` when it is imported, so the LLVM check comes first.
    """
    if not variants:
        return None, []
    if importlib.util.find_spec("mitsuba") is None:
        note("Mitsuba 3 is not installed (pip install mitsuba); comparing against nothing")
        return None, []
    wanted = [v for v in variants if not v.startswith("llvm_") or llvm_ready(v)]
    import mitsuba as mi

    usable = []
    for variant in wanted:
        if variant in mi.variants():
            usable.append(variant)
        else:
            note(f"Mitsuba has no variant {variant!r}; skipped")
    return mi, usable


def llvm_ready(variant: str) -> bool:
    """Point Dr.Jit at a suitable libLLVM, or explain why ``variant`` is skipped."""
    libllvm = find_libllvm()
    configured = os.environ.get("DRJIT_LIBLLVM_PATH")
    if libllvm is None and configured:
        note(f"{variant} skipped: DRJIT_LIBLLVM_PATH={configured} is not a file")
        return False
    if libllvm is None:
        note(
            f"{variant} skipped: no libLLVM found (run bench/get_libllvm.sh, or set "
            "DRJIT_LIBLLVM_PATH to a libLLVM >= 15 that can select fminimum)"
        )
        return False
    problem = llvm_problem(libllvm)
    if problem is not None:
        note(f"{variant} skipped with {libllvm}: {problem}")
        return False
    os.environ["DRJIT_LIBLLVM_PATH"] = str(libllvm)  # read when the LLVM backend starts
    return True


def mitsuba_contender(mi: ModuleType, variant: str, workload: Workload) -> Contender:
    """Mitsuba's ``cornell_box()`` with a path tracer of the same depth; round ``r`` uses seed r.

    ``np.array`` forces the (lazily evaluated) LLVM variant to finish the image.
    """
    import drjit as dr

    mi.set_variant(variant)
    dr.set_thread_count(workload.threads)
    description = mi.cornell_box()
    description["integrator"] = {"type": "path", "max_depth": workload.max_depth}
    description["sensor"]["film"]["width"] = workload.width
    description["sensor"]["film"]["height"] = workload.height
    scene = mi.load_dict(description)

    def run(round_index: int) -> np.ndarray:
        return np.array(mi.render(scene, spp=workload.spp, seed=round_index))

    return Contender(run, prepare=lambda: mi.set_variant(variant))


# --- measuring and reporting -----------------------------------------------------------------


def warm_up(contenders: dict[str, Contender], seed: int) -> dict[str, float]:
    """One untimed-for-the-ratios render of each contender (compiles kernels); its seconds."""
    seconds = {}
    for name, contender in contenders.items():
        with console.status(f"warm-up render: {name}"):
            if contender.prepare is not None:
                contender.prepare()
            seconds[name], _ = time_call(lambda c=contender: c.run(seed))
    return seconds


def mean_collector(means: dict[str, list[np.ndarray]]) -> Callable[[str, int, object], None]:
    """An ``on_result`` hook that records each image's mean RGB."""

    def record(name: str, _round: int, image: object) -> None:
        means.setdefault(name, []).append(np.asarray(image, np.float64).mean(axis=(0, 1)))

    return record


def format_rgb(rgb: np.ndarray) -> str:
    return " ".join(f"{c:.4f}" for c in rgb)


@dataclass(frozen=True)
class Reference:
    """The Cornell box reference (Mitsuba 3, 8192 spp): the image mean per channel, and the
    pixels' mean per-sample variance (to judge how far a renderer's image mean may stray)."""

    mean: np.ndarray
    sample_variance: np.ndarray
    mean_variance: np.ndarray

    @classmethod
    def load(cls) -> "Reference":
        mean = np.load(REFERENCE_MEAN).astype(np.float64).reshape(-1, 3)
        var_of_mean = np.load(REFERENCE_VAR).astype(np.float64).reshape(-1, 3)
        return cls(
            mean.mean(axis=0),
            var_of_mean.mean(axis=0) * REFERENCE_SPP,
            var_of_mean.sum(axis=0) / var_of_mean.shape[0] ** 2,
        )

    def z_scores(self, image_mean: np.ndarray, samples: int) -> np.ndarray:
        """Approximate z-score per channel of an image mean over ``samples`` samples in all.

        The renderer's variance is estimated from the reference's per-sample variance, so this
        is a sanity check (|z| below about 4), not a test.
        """
        variance = self.sample_variance / samples + self.mean_variance
        return (image_mean - self.mean) / np.sqrt(variance)


def speed_table(
    workload: Workload,
    series: dict[str, Series],
    warmup: dict[str, float],
    means: dict[str, np.ndarray],
    z: dict[str, np.ndarray],
    reference: Reference,
) -> None:
    """Samples/s of every renderer, with its mean RGB next to the reference's."""
    rows = [
        [
            name,
            fmt_float(s.median_rate / 1e6, 3),
            fmt_float(s.best_rate / 1e6, 3),
            fmt_float(s.median_seconds, 3),
            fmt_float(warmup[name], 2),
            format_rgb(means[name]),
            f"{100 * np.max(np.abs(means[name] / reference.mean - 1.0)):.2f}%",
            fmt_float(np.max(np.abs(z[name])), 1),
        ]
        for name, s in series.items()
    ]
    rows.append(["reference (8192 spp)", "", "", "", "", format_rgb(reference.mean), "", ""])
    print_table(
        f"Cornell box {workload.width}x{workload.height}, {workload.spp} spp, "
        f"max_depth {workload.max_depth}, {workload.threads} threads",
        [
            "renderer",
            "Msamples/s median",
            "best",
            "median s",
            "warm-up s",
            "mean RGB",
            "max dev",
            "max |z|",
        ],
        rows,
        caption="mean RGB: image mean over the timed renders; max dev: largest relative "
        "difference of a channel from the reference; |z|: that difference in (approximate) "
        "standard errors, expect < 4 (the reference is 256x256: at other sizes the image edges "
        "weigh differently and the means may shift a little)",
    )


def ratio_table(series: dict[str, Series]) -> dict[str, dict]:
    """Print the ratios tilerender / each Mitsuba variant with verdicts; return them."""
    results, rows = {}, []
    for variant in (v for v in series if v != OURS):
        r = ratios(series[OURS], series[variant])
        target = TARGETS.get(variant)
        outcome = verdict(r["median"], target) if target else "-"
        results[f"{OURS}/{variant}"] = {**r, "target_at_least": target, "verdict": outcome}
        rows.append(
            [
                f"{OURS} / {variant}",
                fmt_float(r["median"]),
                fmt_float(r["best"]),
                fmt_float(r["paired_median"]),
                f">= {target}" if target else "-",
                styled_verdict(outcome),
            ]
        )
    if rows:
        print_table(
            "Throughput ratios (verdict on the ratio of medians)",
            ["ratio", "of medians", "of bests", "paired median", "target", "verdict"],
            rows,
            caption="paired median: median over rounds of the ratio within each round",
        )
    return results


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    workload = Workload(args.width, args.height, args.spp, args.max_depth, args.threads)
    machine = machine_info()
    print_machine(machine)
    mi, variants = usable_variants(args.variants)

    contenders = {OURS: tilerender_contender(workload)}
    for variant in variants:
        contenders[variant] = mitsuba_contender(mi, variant, workload)
    warmup = warm_up(contenders, seed=args.repeats)  # a seed no timed round uses

    means: dict[str, list[np.ndarray]] = {}
    with console.status(f"{args.repeats} interleaved rounds of {', '.join(contenders)}"):
        series = interleaved(
            contenders,
            {name: workload.samples for name in contenders},
            args.repeats,
            on_result=mean_collector(means),
        )
    reference = Reference.load()
    mean_rgb = {name: np.mean(values, axis=0) for name, values in means.items()}
    z = {
        name: reference.z_scores(mean_rgb[name], workload.samples * len(means[name]))
        for name in mean_rgb
    }
    speed_table(workload, series, warmup, mean_rgb, z, reference)
    renderers = {
        name: {
            **s.summary(scale=1e6),
            "warmup_seconds": warmup[name],
            "mean_rgb": mean_rgb[name],
            "z_scores": z[name],
        }
        for name, s in series.items()
    }
    results = {
        "renderers": renderers,
        "ratios": ratio_table(series),
        "reference_mean_rgb": reference.mean,
    }
    machine["mitsuba"] = package_version("mitsuba")
    machine["drjit_libllvm"] = os.environ.get("DRJIT_LIBLLVM_PATH")
    write_results(
        "cornell",
        {"workload": vars(args) | {"samples_per_render": workload.samples}, **results},
        machine,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
