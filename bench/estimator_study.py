"""The online error estimate (``tracer.accuracy.error_estimate``) against the true error, on
development renders that are not the accuracy study's.

``render``: every sample scene at the study's size with its reference's settings (so a render
is unbiased against the study's reference, ``cli.accuracy_reference``) and seed 101 (the
study's calibration uses seed 1), as ``--batches`` independent batches of ``--batch-spp``
samples over disjoint sample ranges. Each batch keeps its running mean at 1, 2, 4, ...
``--batch-spp`` samples, so a level of N spp split into K parts takes K batches' means at N/K
samples each (or the means of several whole batches past ``--batch-spp``), and the batches give
``batches * batch_spp / N`` independent repeats of the level (at most ``batches / K``: with the
defaults 8 up to 256 spp, 4 at 512 and 2 at 1024). Cached in ``bench/results/estimator-dev/``.

``evaluate``: at every level from 4 to 1024 spp and every repeat, each estimator of
:data:`ESTIMATORS` (from the parts alone) and the current one with the repeat's spot checks
(``tracer.accuracy.spot_check``, rendered on the development seed's checks stream and cached beside
the batches) against the true relative error of the parts' mean (the reference's noise floor
subtracted, as the study does). A level counts as *within* when the estimate of the first
repeat is within +-30% of its true error (one render, as the study's calibration measures it);
the repeats give the same over every render, and the *expected* error (the root of the mean
true relative MSE over the repeats).

``validate``: the study's own calibration (``cli.accuracy.calibration``: the study's seed,
references and sizes) of the current estimator, every scene.

Our own references come from the study's cache (``bench/results/accuracy-cache/``, rendered by
``tilerender bench accuracy`` when missing; see :func:`study_setup`).

    python bench/estimator_study.py render      # 2,048 spp per scene, cached
    python bench/estimator_study.py evaluate    # a minute, from the cache; -v: every level
    python bench/estimator_study.py validate    # 1,024 spp per scene

Measured on a shared 2-core machine: ``render`` took 3.1 CPU minutes (4.2 minutes of
wall-clock time; the first run took 13, most of them for six of the study's references that
were missing from its cache, 16,384 spp each), ``validate`` 1.5 CPU minutes.
"""

import argparse
import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from common import REPO_ROOT, RESULTS_DIR, console, machine_info, print_table, write_results

from cli.accuracy import StudyOptions, calibration, scene_name, study_size
from cli.accuracy_reference import (
    Reference,
    independent_reference,
    own_reference,
    reference_settings,
)
from cli.accuracy_sweep import spp_levels
from cli.commands.samples import sample_scene_files
from tracer.accuracy import error_estimate as ee
from tracer.accuracy.spot_check import SpotCheckLedger, render_spot_checks
from tracer.compiled.scene import CompiledScene, compile_scene
from tracer.kernel.threads import default_threads
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

DEV_DIR = RESULTS_DIR / "estimator-dev"
DEV_SEED = 101
BAND = 0.3


# --- the development renders ---------------------------------------------------------------


@dataclass
class Setup:
    """A scene as the study sets it up: its size, reference and the reference's noise floor."""

    name: str
    scene: CompiledScene
    camera: fmt.Camera
    ref: Reference
    floor: float


def study_setup(path: Path, options: StudyOptions, reuse: bool = False) -> Setup:
    """The scene, camera and reference exactly as ``cli.accuracy.study_scene`` makes them.

    With ``reuse`` (``--reuse-references``), our own reference is read from the study's cache
    even when the cache key misses, if a reference of the scene at this size is there (the
    newest one): the key hashes every ``tracer/*.py``, so an edit of
    ``tracer/accuracy/error_estimate.py`` alone, which renders nothing, would otherwise render every
    reference again (16,384 spp each). After a kernel change that reference may be stale, so
    this is the caller's call."""
    scene = compile_scene(load_scene(path))
    width, height = study_size(scene.camera.width, scene.camera.height, options.pixels)
    camera = fmt.override(scene.camera, width=width, height=height)
    base = fmt.override(scene.render, seed=options.seed)
    ref, _ = independent_reference(path.parent, width, height, base)
    settings = reference_settings(base, options.seed)
    if ref is None and reuse:
        ref = cached_reference(path.parent.name, camera, settings, options)
    if ref is None:
        ref = own_reference(
            scene,
            path.parent,
            camera,
            settings,
            options.reference_factor * options.max_spp,
            options.reference_passes,
            options.cache_dir,
            options.threads,
        )
    return Setup(scene_name(path), scene, camera, ref, ee.noise_floor(ref.mean, ref.var_of_mean))


def cached_reference(
    name: str, camera: fmt.Camera, settings: fmt.RenderSettings, options: StudyOptions
) -> Reference | None:
    """The newest reference of scene ``name`` at the camera's size in the study's cache."""
    found = sorted(
        options.cache_dir.glob(f"{name}-{camera.width}x{camera.height}-*.npz"),
        key=lambda p: p.stat().st_mtime,
    )
    if not found:
        return None
    with np.load(found[-1]) as cached:
        mean, var = cached["mean"], cached["var_of_mean"]
    spp = options.reference_factor * options.max_spp
    detail = f"tilerender, path, max_depth {settings.max_depth}, {spp} spp ({found[-1].name})"
    return Reference(mean, var, "tilerender", settings, spp, 0.0, detail)


def dev_file(setup: Setup, batches: int, batch_spp: int) -> Path:
    cam = setup.camera
    return DEV_DIR / f"{setup.name}-{cam.width}x{cam.height}-s{DEV_SEED}-{batches}x{batch_spp}.npz"


def render_batches(setup: Setup, batches: int, batch_spp: int, threads: int | None) -> np.ndarray:
    """(levels, batches, H, W, 3) float32: each batch's running mean at 1, 2, 4, ...
    ``batch_spp`` samples; batch b takes samples ``[b * batch_spp, (b + 1) * batch_spp)``."""
    settings = fmt.override(setup.ref.settings, seed=DEV_SEED)
    levels = spp_levels(batch_spp)
    cam = setup.camera
    out = np.zeros((len(levels), batches, cam.height, cam.width, 3), np.float32)
    for b in range(batches):
        total = np.zeros((cam.height, cam.width, 3))
        done = 0
        for j, level in enumerate(levels):
            n = level - done
            rgb, _ = render_image(
                setup.scene,
                cam,
                fmt.override(settings, spp=n),
                sample_start=b * batch_spp + done,
                threads=threads,
            )
            total += rgb.astype(np.float64) * n
            done = level
            out[j, b] = total / level
    return out


def load_or_render(setup: Setup, batches: int, batch_spp: int, threads: int | None) -> np.ndarray:
    path = dev_file(setup, batches, batch_spp)
    if path.is_file():
        with np.load(path) as cached:
            return cached["means"]
    means = render_batches(setup, batches, batch_spp, threads)
    DEV_DIR.mkdir(parents=True, exist_ok=True)
    np.savez(path, means=means)
    return means


def level_parts(means: np.ndarray, spp: int, parts: int) -> list[np.ndarray]:
    """The independent repeats of a level of ``spp`` total samples in ``parts`` parts: each a
    (parts, H, W, 3) float64 array (empty when the batches hold too few samples)."""
    batch_levels = means.shape[0]
    batch_spp = 1 << (batch_levels - 1)
    batches = means.shape[1]
    per_part = spp // parts
    if per_part < 1:
        return []
    if per_part <= batch_spp:
        j = per_part.bit_length() - 1
        count = batches // parts
        return [means[j, r * parts : (r + 1) * parts].astype(np.float64) for r in range(count)]
    whole = per_part // batch_spp
    count = batches // (parts * whole)
    out = []
    for r in range(count):
        block = means[-1, r * parts * whole : (r + 1) * parts * whole].astype(np.float64)
        out.append(block.reshape(parts, whole, *block.shape[1:]).mean(axis=1))
    return out


# --- estimators ----------------------------------------------------------------------------

Estimator = Callable[[np.ndarray], float | None]
"""An estimate from a render's parts alone."""


def _readings(stack: np.ndarray, eps: float = ee.REL_EPSILON):
    mean = stack.mean(axis=0)
    variance = stack.var(axis=0, ddof=1) / stack.shape[0]
    centre = np.median(stack, axis=0)
    mu = np.maximum(centre, np.minimum(mean, 0.5 * ee.max_filter3(centre)))
    return mean, variance, mu


def median_reading(stack: np.ndarray, eps: float = ee.REL_EPSILON) -> float:
    """Four parts, median denominator with the 3x3 floor, never None."""
    _, variance, mu = _readings(stack, eps)
    return float(np.mean(variance / (mu * mu + eps)))


def mean_reading(stack: np.ndarray, eps: float = ee.REL_EPSILON) -> float:
    """The same with ``max(D, M)``: every outlier is the pixel's value."""
    mean, variance, mu = _readings(stack, eps)
    return float(np.mean(variance / (np.maximum(mu, mean) ** 2 + eps)))


def ambiguity_rule(limit: float) -> Estimator:
    def estimate(stack: np.ndarray) -> float | None:
        rare, carried = median_reading(stack), mean_reading(stack)
        return None if rare > limit**2 * carried else rare

    return estimate


def _excess(stack: np.ndarray, eps: float = ee.REL_EPSILON):
    """Per pixel, how much more the median reading counts than the mean reading; and the
    median reading's total (sums over pixels and channels)."""
    mean, variance, mu = _readings(stack, eps)
    med = variance / (mu * mu + eps)
    alt = variance / (np.maximum(mu, mean) ** 2 + eps)
    return (med - alt).sum(axis=2), float(med.sum())


def window_rule(size: int, limit: float = 1.5) -> Estimator:
    """Median reading; None when reading the most ambiguous ``size x size`` window of pixels
    the other way changes the relative error by more than ``limit``."""

    def estimate(stack: np.ndarray) -> float | None:
        excess, total = _excess(stack)
        padded = np.pad(excess, size - 1)
        c = padded.cumsum(0).cumsum(1)
        c = np.pad(c, ((1, 0), (1, 0)))
        boxes = c[size:, size:] - c[:-size, size:] - c[size:, :-size] + c[:-size, :-size]
        if total - boxes.max() < total / limit**2:
            return None
        return total / excess.size / 3

    return estimate


def corroborated(
    fraction: float, top: int | None, limit: float = 1.5, outlier: float = 2.0
) -> Estimator:
    """Median reading, but an outlier pixel (mean above twice the median reading's centre)
    whose mean a neighbour's mean corroborates (at least ``fraction`` of it: a light's
    neighbouring pixels) takes the mean reading; None when reading the ``top`` pixels of
    largest excess (median reading over mean reading) the other way changes the relative error
    by more than ``limit``."""

    def estimate(stack: np.ndarray, eps: float = ee.REL_EPSILON) -> float | None:
        mean, variance, mu = _readings(stack, eps)
        lit = (mean > outlier * mu) & (ee.max_neighbour(mean) >= fraction * mean)
        d = np.where(lit, np.maximum(mu, mean), mu)
        med = variance / (d * d + eps)
        alt = variance / (np.maximum(mu, mean) ** 2 + eps)
        total = float(med.sum())
        if top is not None:
            excess = np.sort((med - alt).sum(axis=2).ravel())[-top:].sum()
            if total - excess < total / limit**2:
                return None
        return total / med.size

    return estimate


ESTIMATORS: dict[str, Estimator] = {
    "median reading, never None": median_reading,
    "mean reading, never None": mean_reading,
    "whole-image ambiguity 1.5 (before)": ambiguity_rule(1.5),
    "median reading, None by the 2x2 window": window_rule(2),
    "outliers above 2x corroborated, never None": corroborated(0.5, None),
    "outliers above 2x corroborated, None by top 1": corroborated(0.5, 1),
    "outliers above 2x corroborated, None by top 2": corroborated(0.5, 2),
    "outliers above 2x corroborated, None by top 3": corroborated(0.5, 3),
    "the same, corroborated at 0.25, top 2": corroborated(0.25, 2),
    "outliers above 3x corroborated, None by top 2": corroborated(0.5, 2, outlier=3.0),
    "outliers above 4x corroborated, None by top 2": corroborated(0.5, 2, outlier=4.0),
    "tracer.accuracy.error_estimate without spot checks": ee.estimate_rel_mse,
}
WITH_CHECKS = "tracer.accuracy.error_estimate with spot checks (current code)"
"""The estimator that also takes the render's spot checks (``tracer.accuracy.spot_check``)."""
NAMES = (*ESTIMATORS, WITH_CHECKS)


# --- evaluation ----------------------------------------------------------------------------


def evaluate_scene(setup: Setup, means: np.ndarray, max_spp: int) -> list[dict]:
    """Per level: true relative MSE of every repeat and every estimator's estimates."""
    checks = SpotCheckCache(setup)
    records = []
    for spp in spp_levels(max_spp):
        if spp < ee.PARTS:
            continue
        repeats = level_parts(means, spp, ee.PARTS)
        true = [ee.rel_mse(p.mean(axis=0), setup.ref.mean) - setup.floor for p in repeats]
        estimates = {name: [f(p) for p in repeats] for name, f in ESTIMATORS.items()}
        estimates[WITH_CHECKS] = [
            ee.estimate_rel_mse(p, checks=checks.get(spp, r, p)) for r, p in enumerate(repeats)
        ]
        records.append({"spp": spp, "true": true, "estimates": estimates})
    checks.save()
    return records


class SpotCheckCache:
    """The spot checks of a scene's development renders (``tracer.accuracy.spot_check``, planned for
    each render on its own as the first wave to reach its spp would, priced in samples (the
    batches keep no work counts), on a checks stream of its own per repeat: the development
    seed plus the repeat), cached in ``DEV_DIR`` per level and repeat with the pixels they
    checked (rendered again when the pixels chosen differ).
    Delete the file after a change to the tracer's rendering."""

    def __init__(self, setup: Setup) -> None:
        self.setup = setup
        cam = setup.camera
        name = f"{setup.name}-{cam.width}x{cam.height}-s{DEV_SEED}-checks-per-part-streams.npz"
        self.path = DEV_DIR / name
        self.entries: dict[str, np.ndarray] = {}
        if self.path.is_file():
            with np.load(self.path) as cached:
                self.entries = {key: cached[key] for key in cached.files}
        self.changed = False

    def get(self, spp: int, repeat: int, parts: np.ndarray) -> ee.SpotChecks | None:
        ledger = SpotCheckLedger(self.setup.camera.width * self.setup.camera.height)
        request = ledger.plan(parts, spp)
        if request is None:
            return None
        key = f"{spp}-{repeat}"
        cached = self.entries.get(f"{key}-pixels")
        if cached is None or not np.array_equal(cached, request.pixels):
            settings = fmt.override(self.setup.ref.settings, seed=DEV_SEED + repeat)
            self.entries[f"{key}-pixels"] = request.pixels
            self.entries[f"{key}-parts"] = render_spot_checks(
                self.setup.scene,
                request.pixels,
                request.part_spp,
                request.part_start,
                self.setup.camera,
                settings,
            )[0]
            self.changed = True
        ledger.add(request, request.pixels, self.entries[f"{key}-parts"])
        return ledger.checks()

    def save(self) -> None:
        if self.changed:
            DEV_DIR.mkdir(parents=True, exist_ok=True)
            np.savez(self.path, **self.entries)


def ratio(estimate: float | None, true_mse: float) -> float | None:
    if estimate is None:
        return None
    return math.sqrt(max(estimate, 0.0)) / math.sqrt(max(true_mse, 1e-30))


def summarise(results: dict[str, list[dict]]) -> list[dict]:
    rows = []
    for name in NAMES:
        first, every, expected, nones = [], [], [], 0
        none_levels = []
        for scene, records in results.items():
            for rec in records:
                est = rec["estimates"][name]
                r0 = ratio(est[0], rec["true"][0])
                if r0 is None:
                    nones += 1
                    none_levels.append(f"{scene}@{rec['spp']}")
                else:
                    first.append(r0)
                every += [ratio(e, t) for e, t in zip(est, rec["true"], strict=True)]
                given = [e for e in est if e is not None]
                if given:
                    expected.append(
                        math.sqrt(np.mean(given)) / math.sqrt(max(np.mean(rec["true"]), 1e-30))
                    )
        given_every = [r for r in every if r is not None]
        rows.append(
            {
                "estimator": name,
                "within": sum(abs(r - 1) <= BAND for r in first),
                "given": len(first),
                "levels": len(first) + nones,
                "ratio_min": min(first, default=float("nan")),
                "ratio_max": max(first, default=float("nan")),
                "within_every": sum(abs(r - 1) <= BAND for r in given_every),
                "given_every": len(given_every),
                "renders": len(every),
                "expected_within": sum(abs(r - 1) <= BAND for r in expected),
                "expected_levels": len(expected),
                "none_levels": none_levels,
            }
        )
    return rows


def print_summary(rows: list[dict]) -> None:
    print_table(
        "estimators on the development renders (first repeat = one render per level)",
        [
            "estimator",
            "within +-30%",
            "ratio range",
            "None",
            "every repeat within / given / renders",
            "mean estimate vs expected error",
        ],
        [
            [
                r["estimator"],
                f"{r['within']} of {r['given']}",
                f"{r['ratio_min']:.2f}-{r['ratio_max']:.2f}",
                str(r["levels"] - r["given"]),
                f"{r['within_every']} / {r['given_every']} / {r['renders']}",
                f"{r['expected_within']} of {r['expected_levels']}",
            ]
            for r in rows
        ],
    )


# --- commands ------------------------------------------------------------------------------


def scene_paths(names: list[str] | None) -> list[Path]:
    available = {p.parent.name: p for p in sample_scene_files(REPO_ROOT / "scenes")}
    unknown = sorted(set(names or []) - set(available))
    if unknown:
        raise SystemExit(f"error: no sample scene {', '.join(unknown)}")
    return [available[n] for n in (names or sorted(available))]


def cmd_render(args) -> dict:
    options = StudyOptions(scenes=(), threads=args.threads or default_threads())
    seconds = {}
    for path in scene_paths(args.scenes):
        start = time.perf_counter()
        setup = study_setup(path, options, args.reuse_references)
        load_or_render(setup, args.batches, args.batch_spp, options.threads)
        seconds[setup.name] = time.perf_counter() - start
        console.print(f"{setup.name}: {seconds[setup.name]:.1f} s")
    return {"render_seconds": seconds}


def cmd_evaluate(args) -> dict:
    options = StudyOptions(scenes=(), threads=args.threads)
    results = {}
    for path in scene_paths(args.scenes):
        setup = study_setup(path, options, args.reuse_references)
        means = load_or_render(setup, args.batches, args.batch_spp, args.threads)
        results[setup.name] = evaluate_scene(setup, means, args.max_spp)
    rows = summarise(results)
    print_summary(rows)
    stops = target_stops(results)
    print_stops(stops)
    if args.verbose:
        print_levels(results)
    return {"summary": rows, "target_stops": stops, "levels": results}


TARGETS = (0.3, 0.1, 0.05)
"""Relative errors of the simulated renders to a target (``target_stops``)."""
TARGET_ESTIMATORS = ("tracer.accuracy.error_estimate without spot checks", WITH_CHECKS)


def target_stops(results: dict[str, list[dict]]) -> list[dict]:
    """Renders to a target error, simulated on the levels: for every scene, every repeat that
    reaches the last level (two with the defaults) and every target of ``TARGETS``, the first
    level whose estimate is at most the target (where a progressive render would stop), and the
    true error there; None when no level up to the last one stops it (``--max-spp``)."""
    out = []
    for name in TARGET_ESTIMATORS:
        for scene, records in results.items():
            for rep in range(len(records[-1]["true"])):
                for target in TARGETS:
                    stop = next(
                        (
                            rec
                            for rec in records
                            if rec["estimates"][name][rep] is not None
                            and math.sqrt(rec["estimates"][name][rep]) <= target
                        ),
                        None,
                    )
                    out.append(
                        {
                            "estimator": name,
                            "scene": scene,
                            "repeat": rep,
                            "target": target,
                            "spp": None if stop is None else stop["spp"],
                            "true": None
                            if stop is None
                            else math.sqrt(max(stop["true"][rep], 0.0)),
                        }
                    )
    return out


def print_stops(stops: list[dict]) -> None:
    rows = []
    for name in TARGET_ESTIMATORS:
        mine = [s for s in stops if s["estimator"] == name]
        stopped = [s for s in mine if s["spp"] is not None]
        rows.append(
            [
                name,
                f"{len(stopped)} of {len(mine)}",
                f"{sum(s['true'] <= (1 + BAND) * s['target'] for s in stopped)} of {len(stopped)}",
                ", ".join(
                    sorted({f"{s['scene']}@{s['target']:g}" for s in mine if s["spp"] is None})
                )
                or "-",
            ]
        )
    print_table(
        f"renders to a target error {', '.join(f'{t:g}' for t in TARGETS)}, simulated on the "
        "levels",
        ["estimator", "stopped by the target", "true error within +30% of it", "ran to the end"],
        rows,
    )


def print_levels(results: dict[str, list[dict]]) -> None:
    """The first repeat's estimated / true relative error at every level, one column per
    estimator (numbered as listed first)."""
    for index, name in enumerate(NAMES, 1):
        console.print(f"{index:2d}: {name}")
    for scene, records in results.items():
        for rec in records:
            cells = [f"{scene:16s} {rec['spp']:5d} true {math.sqrt(max(rec['true'][0], 0)):.3f}"]
            for est in rec["estimates"].values():
                r = ratio(est[0], rec["true"][0])
                cells.append("  None" if r is None else f"{r:6.2f}")
            console.print(" ".join(cells))


def cmd_validate(args) -> dict:
    options = StudyOptions(scenes=(), threads=args.threads or default_threads())
    out = {}
    rows = []
    for path in scene_paths(args.scenes):
        setup = study_setup(path, options, args.reuse_references)
        records = calibration(
            setup.scene, setup.camera, setup.ref, setup.floor, options, lambda n: None
        )
        out[setup.name] = records
        given = [r for r in records if r["estimated"] is not None]
        ratios = [r["estimated"] / r["true"] for r in given if r["true"] > 0]
        rows.append(
            [
                setup.name,
                f"{sum(abs(r - 1) <= BAND for r in ratios)} of {len(given)}",
                f"{min(ratios):.2f}-{max(ratios):.2f}" if ratios else "-",
                ", ".join(str(r["spp"]) for r in records if r["estimated"] is None) or "-",
            ]
        )
        console.print(" | ".join(rows[-1]))
    print_table(
        "the study's calibration (seed 1)", ["scene", "within +-30%", "ratios", "None at"], rows
    )
    return {"calibration": out}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("command", choices=("render", "evaluate", "validate"))
    parser.add_argument("--scenes", nargs="+", metavar="NAME", help="(default: every one)")
    parser.add_argument("--batches", type=int, default=32, help="(default 32)")
    parser.add_argument("--batch-spp", type=int, default=64, help="a power of two (default 64)")
    parser.add_argument("--max-spp", type=int, default=1024, help="largest level (default 1024)")
    parser.add_argument("--threads", type=int, help="render threads (default: all)")
    parser.add_argument("-v", "--verbose", action="store_true", help="every level's ratios")
    parser.add_argument(
        "--reuse-references",
        action="store_true",
        help="use the newest cached reference of a scene even if the tracer's code changed "
        "since it was rendered (only safe when the change renders nothing differently)",
    )
    args = parser.parse_args(argv)
    if args.batch_spp < 1 or args.batch_spp & (args.batch_spp - 1):
        parser.error("--batch-spp must be a power of two")
    commands = {"render": cmd_render, "evaluate": cmd_evaluate, "validate": cmd_validate}
    payload = commands[args.command](args)
    payload["options"] = {k: v for k, v in vars(args).items()}
    write_results(f"estimator_study-{args.command}", payload, machine_info())
    return 0


if __name__ == "__main__":
    sys.exit(main())
