"""Adaptive sampling (issue #26 item 1): render seconds to a relative MSE of 1e-2 in
progressive frames with it (``on``, and ``auto`` as the default decides) and without (``off``),
side by side, against each scene's shared reference (``cli/accuracy_reference.py``).

Every scene is rendered at the accuracy study's size (about ``--pixels`` pixels) with the
scene's settings, as ``tilerender render --target-error`` renders it, but in this process:
each wave's parts through ``tracer.render.render_pixels`` on ``--threads`` threads, the spot
checks through ``tracer.accuracy.spot_check``. After each wave the frame's true relative MSE
(less the reference's noise floor) is measured, off the clock; the time to 1e-2 is read off the
log-log line between the waves around it. The contenders run interleaved (off, on, auto, off,
...) for ``--repeats`` rounds, each round on a seed of its own shared by the three; the table
gives medians and the median of the per-round ratios off / on.
"""

import argparse
import math
import statistics
import time
from pathlib import Path

from adaptive_figures import spp_map_figure
from common import (
    REPO_ROOT,
    machine_info,
    print_machine,
    print_table,
    styled_verdict,
    verdict,
    write_results,
)

from cli.accuracy import StudyOptions, study_size
from cli.accuracy_reference import independent_reference, own_reference, reference_settings
from cluster.progressive import Goal, ProgressiveFrame, SpotCheck
from tracer.accuracy.error_estimate import noise_floor, rel_mse, rel_mse_terms
from tracer.accuracy.spot_check import render_spot_checks
from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import effect_plan
from tracer.render import render_pixels
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

SCENES = ("veach-mis", "cornell-spheres", "many-lights")
TARGET = 1e-2
"""The relative MSE the time is measured to."""
MODES = ("off", "on", "auto")
SPEEDUP = 2.0
"""Target: time to 1e-2 without adaptive sampling over the time with it, at least."""
SLOWDOWN = 1.05
"""No scene slower than this with ``auto`` (the default)."""


def study_arguments(description: str, scenes: tuple[str, ...], repeats: int):
    """The options of a time-to-quality benchmark: scenes, rounds, size, threads, spp cap."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--scenes", nargs="+", default=list(scenes), metavar="NAME")
    parser.add_argument("--repeats", type=int, default=repeats, help=f"rounds (default {repeats})")
    parser.add_argument("--pixels", type=int, default=128 * 96, help="about this many pixels")
    parser.add_argument("--threads", type=int, default=None, help="render threads (all)")
    parser.add_argument("--max-spp", type=int, default=1 << 14, help="cap per frame")
    return parser


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = study_arguments(__doc__.split("\n\n")[0], SCENES, 5)
    parser.add_argument(
        "--figures",
        type=str,
        default=None,
        metavar="DIR",
        help="write adaptive-spp-SCENE.png there: the first round's adaptive frame at the target, "
        "its samples per pixel, the uniform frame's error per pixel (docs/accuracy/ for the docs)",
    )
    return parser.parse_args(argv)


def setup(name: str, pixels: int, threads: int | None, reference_spp: int | None = None):
    """The scene compiled, its camera at the study's size, settings, reference and floor; the
    reference is the scene's independent one, else our own of ``reference_spp`` (default: the
    accuracy study's)."""
    path = REPO_ROOT / "scenes" / name / "scene.json"
    state = load_scene(path)
    scene = compile_scene(state)
    width, height = study_size(scene.camera.width, scene.camera.height, pixels)
    camera = fmt.override(scene.camera, width=width, height=height)
    options = StudyOptions(scenes=())
    base = fmt.override(scene.render, seed=options.seed, aovs=False, denoise="off")
    ref, _ = independent_reference(path.parent, width, height, base)
    if ref is None:
        ref = own_reference(
            scene,
            path.parent,
            camera,
            reference_settings(base, options.seed),
            reference_spp or options.reference_factor * 1024,
            options.reference_passes,
            options.cache_dir,
            threads,
        )
    return scene, camera, ref.settings, ref, noise_floor(ref.mean, ref.var_of_mean)


def frame_run(
    scene, camera, settings, ref, floor, mode, max_spp, threads, snapshot: dict | None = None
) -> list[dict]:
    """One progressive frame until its true relative MSE is below half the target: after
    each wave, its render seconds (waves, spot checks and the frame's arithmetic; the spot
    checks' alone), mean spp,
    the samples its parts took (counted off the parts rendered), true relative MSE and the
    estimate's square. ``snapshot``, if given, is filled at the first wave at or below the
    target (``bench/adaptive_figures.py``: image, samples per pixel, error per pixel)."""
    plan = effect_plan(scene, settings)
    pixels = camera.width * camera.height
    clock = [0.0]
    progress = ProgressiveFrame(
        camera.width, camera.height, Goal(max_spp=max_spp), lambda: clock[0], adaptive=mode
    )
    records, samples, checking = [], 0, 0.0
    while True:
        start = time.perf_counter()
        step = progress.next_part()
        if step is None:
            break
        if isinstance(step, SpotCheck):
            parts, work = render_spot_checks(
                scene, step.pixels, step.part_spp, step.part_start, camera, settings, 0, threads,
                plan,
            )  # fmt: skip
            progress.add_spot_checks(step.pixels, parts, 0.0, work)
            checking += time.perf_counter() - start
        else:
            part = fmt.override(settings, spp=step.spp)
            run = render_pixels(
                scene, 0, pixels, camera, part, 0, step.sample_start, threads, plan, step.counts
            )
            rgb = run.rgb.reshape(camera.height, camera.width, 3)
            progress.add_part(rgb, 0.0, float(run.cost.sum()))
            samples += pixels * step.spp if step.counts is None else int(step.counts.sum())
        waves = len(progress.waves)
        clock[0] += time.perf_counter() - start
        if waves > len(records):
            error = rel_mse(progress.image, ref.mean) - floor
            wave = progress.waves[-1]
            records.append(
                {
                    "seconds": clock[0],
                    "check_seconds": checking,
                    "spp": wave.spp,
                    "mean_spp": wave.mean_spp,
                    "samples": samples,
                    "rel_mse": error,
                    "estimate": None if wave.error is None else wave.error**2,
                    "adaptive": wave.adaptive,
                }
            )
            if snapshot is not None and not snapshot and error <= TARGET:
                terms = rel_mse_terms(progress.image, ref.mean).mean(axis=2)
                snapshot.update(image=progress.image, pixel_spp=progress.pixel_spp, terms=terms,
                                rel_mse=error, mean_spp=wave.mean_spp)  # fmt: skip
            if error < TARGET / 2:
                break
    return records


def time_to(records: list[dict], target: float, key: str = "seconds") -> float | None:
    """``key`` (seconds or mean_spp) where the relative MSE first falls to ``target``, on the
    log-log line between the waves around it (None if never)."""
    for before, after in zip([None, *records], records, strict=False):
        if after["rel_mse"] > target:
            continue
        if before is None or before["rel_mse"] <= 0.0 or after["rel_mse"] <= 0.0:
            return after[key]
        slope = math.log(after[key] / before[key]) / math.log(after["rel_mse"] / before["rel_mse"])
        return before[key] * (target / before["rel_mse"]) ** slope
    return None


def at_target(records: list[dict]) -> dict | None:
    """The first wave at or below the target."""
    return next((r for r in records if r["rel_mse"] <= TARGET), None)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    info = machine_info()
    print_machine(info)
    results = {}
    for name in args.scenes:
        scene, camera, settings, ref, floor = setup(name, args.pixels, args.threads)
        frame_run(scene, camera, fmt.override(settings, spp=1), ref, floor, "off", 8, 1)  # warm
        runs = {mode: [] for mode in MODES}
        snapshots = {mode: {} for mode in MODES}
        for round_index in range(args.repeats):
            seeded = fmt.override(settings, seed=settings.seed + 7919 * round_index)
            for mode in MODES:
                keep = snapshots[mode] if round_index == 0 else None
                runs[mode].append(
                    frame_run(
                        scene, camera, seeded, ref, floor, mode, args.max_spp, args.threads, keep
                    )
                )
        results[name] = summarise(runs, camera, floor)
        if args.figures is not None and snapshots["on"]:
            Path(args.figures).mkdir(parents=True, exist_ok=True)
            path = Path(args.figures) / f"adaptive-spp-{name}.png"
            spp_map_figure(name, TARGET, snapshots["on"], snapshots["off"] or None, path)
    report(results)
    write_results("adaptive", {"options": vars(args), "scenes": results}, info)
    return 0


def summarise(runs: dict[str, list], camera, floor: float) -> dict:
    """Per mode: times and mean spp to the target per round, their medians, the estimate over
    the true relative MSE at the first wave past the target; the paired ratios off / mode."""
    out = {"size": [camera.width, camera.height], "noise_floor": floor, "modes": {}}
    for mode, frames in runs.items():
        seconds = [time_to(r, TARGET) for r in frames]
        spp = [time_to(r, TARGET, "mean_spp") for r in frames]
        hits = [at_target(r) for r in frames]
        calibration = [h["estimate"] / h["rel_mse"] for h in hits if h and h["estimate"]]
        out["modes"][mode] = {
            "seconds": seconds,
            "mean_spp": spp,
            "median_seconds": _median(seconds),
            "median_spp": _median(spp),
            "estimate_over_true": calibration,
            "adaptive_waves": [sum(w["adaptive"] for w in r) for r in frames],
            "records": frames,
        }
    off = out["modes"]["off"]["seconds"]
    for mode in ("on", "auto"):
        mine = out["modes"][mode]["seconds"]
        paired = [a / b for a, b in zip(off, mine, strict=True) if a and b]
        out["modes"][mode]["speedup_paired_median"] = _median(paired)
    return out


def _median(values: list) -> float | None:
    known = [v for v in values if v is not None]
    return statistics.median(known) if known else None


def report(results: dict) -> None:
    rows = []
    for name, result in results.items():
        modes = result["modes"]
        on, auto = modes["on"]["speedup_paired_median"], modes["auto"]["speedup_paired_median"]
        calib = [_fmt(_median(modes[m]["estimate_over_true"]), 2) for m in ("off", "on")]
        rows.append(
            [
                name,
                "x".join(map(str, result["size"])),
                *(_fmt(modes[m]["median_seconds"], 3) for m in MODES),
                *(_fmt(modes[m]["median_spp"], 0) for m in MODES),
                _fmt(on, 2),
                _fmt(auto, 2),
                *calib,
                styled_verdict(verdict(on or 0.0, SPEEDUP)),
                styled_verdict(verdict(auto or 0.0, 1 / SLOWDOWN)),
            ]
        )
    print_table(
        f"Render seconds to relMSE {TARGET:g}, progressive frames",
        [
            "scene", "size", "s off", "s on", "s auto", "spp off", "spp on", "spp auto",
            "off/on", "off/auto", "est/true off", "est/true on", f"on >= {SPEEDUP:g}x",
            f"auto >= 1/{SLOWDOWN:g}",
        ],
        rows,
        caption="seconds and mean spp: medians over the rounds; off/on, off/auto: median of the "
        "per-round ratios; est/true: the estimated over the true relative MSE at the first "
        "wave past the target, median over the rounds",
    )  # fmt: skip


def _fmt(value: float | None, digits: int) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


if __name__ == "__main__":
    raise SystemExit(main())
