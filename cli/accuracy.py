"""The accuracy study behind ``tilerender bench accuracy``: what accuracy costs in time.

Every scene is rendered small (about ``pixels`` pixels, a whole fraction of its own size) in
this process, and every image is compared with the scene's one reference
(:mod:`cli.accuracy_reference`), so bias shows as error:

1. **Sweep** (:mod:`cli.accuracy_sweep`). Each configuration (integrators, depths, Russian
   roulette and the effect plan on and off, denoising) takes samples 1, 2, 4, ... ``max_spp``
   in doubling waves over disjoint sample ranges; the configurations take turns wave by wave
   (slow drifts of a shared machine hit them alike). After each wave the mean so far is
   measured: relative MSE, RMSE, PSNR, SSIM and FLIP (``cli.accuracy_metrics.measure``),
   against the seconds spent, the rays traced and the kernel's work (BVH node visits plus
   triangle tests). A denoised configuration renders nothing of its own: after each wave it
   denoises its source's mean so far (which records the albedo and normal AOVs), and its
   seconds are the source's plus that one denoising's (a render denoises once, at the end).
2. **Effect costs** after Reiter's eq. 5.1 (:func:`effect_costs`).
3. **Time to quality**: seconds to reach a relative MSE (``cli.accuracy_metrics.time_to``).
4. **Calibration** of the online error estimate against the true error (:func:`calibration`).

:func:`run_study` returns everything as JSON-ready data plus the images the report shows;
:mod:`cli.accuracy_report` writes the report.
"""

import math
import os
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cli.accuracy_reference import (
    Reference,
    independent_reference,
    own_reference,
    reference_settings,
)
from cli.accuracy_sweep import (
    DEFAULT_CONFIG,
    DENOISED_STRIP,
    Config,
    RenderClock,
    configurations,
    render_counted,
    spp_levels,
    sweep,
)
from tracer.accuracy.denoised_error import denoise_and_estimate
from tracer.accuracy.error_estimate import (
    PARTS,
    estimate_rel_error,
    noise_floor,
    rel_mse,
)
from tracer.accuracy.spot_check import SpotCheckLedger, render_spot_checks
from tracer.compiled.scene import CompiledScene, compile_scene
from tracer.integrators.aov import CHANNELS, aov_layers
from tracer.integrators.effects import effect_plan
from tracer.integrators.flags import MATERIAL_BUILD, MATERIAL_EFFECTS, SHADOWS
from tracer.kernel.threads import default_threads
from tracer.post.guides import noisy_guides
from tracer.render import render_image
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene

REPO_ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CACHE = REPO_ROOT / "bench" / "results" / "accuracy-cache"


@dataclass(frozen=True)
class StudyOptions:
    scenes: tuple[Path, ...]
    """Scene files (a folder's scene.json or its glTF file)."""
    pixels: int = 128 * 96
    """About this many pixels per image (see :func:`study_size`)."""
    max_spp: int = 1024
    reference_factor: int = 16
    """Our own references take ``reference_factor x max_spp`` samples per pixel."""
    reference_passes: int = 16
    effect_spp: int = 32
    """Samples per pixel of one timed render of the effect-cost table."""
    repeats: int = 7
    """Rounds of the effect-cost table (the median is reported)."""
    seed: int = 0
    threads: int | None = None
    cache_dir: Path = DEFAULT_CACHE
    flip_every: int = 2
    """FLIP (the slowest metric) at every ``flip_every``-th sweep level and the last."""

    def __post_init__(self) -> None:
        if self.max_spp < PARTS or self.max_spp & (self.max_spp - 1):
            raise ValueError(f"max_spp must be a power of two >= {PARTS}, got {self.max_spp}")
        if self.pixels < 64:
            raise ValueError(f"pixels must be at least 64, got {self.pixels}")
        for name in ("reference_factor", "reference_passes", "effect_spp", "repeats"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be at least 1")


def study_size(width: int, height: int, pixels: int) -> tuple[int, int]:
    """The scene's image size divided by the whole factor ``k`` that brings it closest to
    ``pixels`` (an independent reference at the scene's size then averages ``k x k`` blocks);
    the size scaled to ``pixels`` when no factor divides both sides within 2x of it."""
    best = None
    for k in range(1, min(width, height) + 1):
        if width % k or height % k:
            continue
        miss = abs(math.log(width * height / (k * k) / pixels))
        if best is None or miss < best[0]:
            best = (miss, k)
    if best is not None and best[0] <= math.log(2.0):
        return width // best[1], height // best[1]
    scale = math.sqrt(pixels / (width * height))
    return max(1, round(width * scale)), max(1, round(height * scale))


# --- the parts of a scene's study --------------------------------------------------------------


EFFECT_STAGES = (
    ("diffuse", "whitted", SHADOWS | MATERIAL_EFFECTS, False),
    ("diffuse, material build", "whitted", SHADOWS | MATERIAL_EFFECTS, True),
    ("diffuse + shadows", "whitted", MATERIAL_EFFECTS, True),
    ("diffuse + reflection, refraction", "whitted", SHADOWS, True),
    ("diffuse + shadows + reflection, refraction", "whitted", 0, True),
    ("all effects", "path", 0, True),
)
"""Reiter's eq. 5.1 stages: (name, integrator, effects dropped from the plan the integrator
gets, whether it runs in the scene's build of the kernel). The ``whitted`` stages are Reiter's
own ray tracer (direct light, recursion through mirrors and glass); without material effects
every surface is Lambertian. ``all effects`` is the path tracer, so the indirect part is what
path tracing adds to Whitted's with every effect. A scene with material effects runs in the
kernel build with the material dispatch (``tracer.integrators.path.kernel_for``), where every step
costs more than in the build without it; Reiter's renderer switched effects at run time, in
one build, so every stage but ``diffuse`` runs in the scene's build
(``tracer.integrators.flags.MATERIAL_BUILD``), and the build's own cost is a part of its own."""


def effect_parts(median: dict[str, float]) -> dict[str, float]:
    """Reiter's eq. 5.1 from the stages' median seconds: the scene's kernel build, shadows and
    reflection/refraction each added to diffuse alone in that build, and indirect light added
    to Whitted with every effect."""
    d = median["diffuse, material build"]
    return {
        "diffuse": median["diffuse"],
        "material build": d - median["diffuse"],
        "shadows": median["diffuse + shadows"] - d,
        "reflection, refraction": median["diffuse + reflection, refraction"] - d,
        "indirect": median["all effects"] - median["diffuse + shadows + reflection, refraction"],
    }


def effect_costs(
    scene: CompiledScene,
    camera: fmt.Camera,
    base: fmt.RenderSettings,
    ref: Reference,
    floor: float,
    options: StudyOptions,
    on_samples: Callable[[int], None],
) -> dict:
    """Time the stages side by side (``repeats`` interleaved rounds of ``effect_spp`` samples,
    after one untimed warm-up each; :class:`RenderClock` seconds), split the time into parts by
    eq. 5.1 and compare their sum with the measured time of all effects. Each stage's image
    (all rounds' samples) is also measured against the reference: what an effect adds to
    accuracy."""
    threads = options.threads or default_threads()
    stages = []
    scene_plan = effect_plan(scene, base)
    build = MATERIAL_BUILD if scene_plan.flags & MATERIAL_EFFECTS else 0
    for name, integrator, drop, scene_build in EFFECT_STAGES:
        settings = fmt.override(base, integrator=integrator, spp=options.effect_spp)
        plan = Config(name, name, drop=drop, add=build if scene_build else 0).plan(scene, settings)
        tiny = fmt.override(camera, width=1, height=1)
        render_image(scene, tiny, fmt.override(settings, spp=1), plan=plan, threads=threads)
        stages.append((name, settings, plan, np.zeros((camera.height, camera.width, 3)), []))
    work = dict.fromkeys((name for name, *_ in stages), 0)
    rays = dict.fromkeys(work, 0)
    for round_index in range(options.repeats):
        for name, settings, plan, total, seconds in stages:
            with RenderClock(threads) as clock:
                rgb, stage_rays, stage_work, _ = render_counted(
                    scene, camera, settings, round_index * options.effect_spp, threads, plan
                )
            seconds.append(clock.seconds)
            rays[name] += stage_rays
            work[name] += stage_work
            total += rgb
            on_samples(options.effect_spp)
    median = {name: float(np.median(seconds)) for name, _, _, _, seconds in stages}
    parts = effect_parts(median)
    total_seconds = median["all effects"]
    return {
        "spp": options.effect_spp,
        "repeats": options.repeats,
        "stages": [
            {
                "name": name,
                "integrator": settings.integrator,
                "effects": plan.names(),
                "seconds": seconds,
                "median_seconds": median[name],
                "rays": rays[name] / options.repeats,
                "work": work[name] / options.repeats,
                "rel_mse": rel_mse(total / options.repeats, ref.mean) - floor,
            }
            for name, settings, plan, total, seconds in stages
        ],
        "parts": parts,
        "sum_of_parts": sum(parts.values()),
        "total": total_seconds,
        "ratio": sum(parts.values()) / total_seconds,
    }


def calibration(
    scene: CompiledScene,
    camera: fmt.Camera,
    ref: Reference,
    floor: float,
    options: StudyOptions,
    on_samples: Callable[[int], None],
    prefilter: tuple[str, ...] = (),
) -> list[dict]:
    """The online estimate against the true error: the reference's own settings (so the
    render is unbiased against it) with another seed, ``PARTS`` independent parts that double
    together, as a progressive render's waves do; at each total spp the estimate from the parts
    and their spot checks, topped up level by level as a progressive render's are
    (``tracer.accuracy.spot_check``; None where it says the error is not estimable yet), the pixels
    checked, and the true relative error of their mean (the
    reference's noise floor subtracted); with the render seconds of the parts so far and of
    the level's spot checks (:class:`RenderClock`). And for the mean denoised (``high``, the
    AOVs guiding, those ``prefilter`` names prefiltered): the estimate of its error
    (``tracer.accuracy.denoised_error``; None where not given), its true error and the seconds
    that took (one denoising, and a second for the estimate where it is given; OIDN's start-up
    is paid before, untimed)."""
    settings = fmt.override(ref.settings, seed=options.seed + 1, aovs=True)
    plan = effect_plan(scene, settings)
    threads = options.threads or default_threads()
    sums = np.zeros((PARTS, camera.height, camera.width, 3))
    aov_sums = np.zeros((camera.height, camera.width, CHANNELS))
    per_part = 0
    seconds, work = 0.0, 0.0
    ledger = SpotCheckLedger(camera.width * camera.height)
    records = []
    warm_up = np.ones((camera.height, camera.width, 3), np.float32)
    denoise_and_estimate(np.stack([warm_up] * PARTS), 1, None, None, "high", prefilter, 0)
    for level in spp_levels(options.max_spp):
        if level < PARTS:
            continue
        n = level // PARTS - per_part
        for k in range(PARTS):
            with RenderClock(threads) as clock:
                rgb, _, part_work, aov = render_counted(
                    scene,
                    camera,
                    fmt.override(settings, spp=n),
                    PARTS * per_part + k * n,
                    threads,
                    plan,
                )
            seconds += clock.seconds
            work += float(part_work)
            sums[k] += rgb.astype(np.float64) * n
            aov_sums += aov.astype(np.float64) * n
            on_samples(n)
        per_part += n
        parts = sums / per_part
        request = ledger.plan(parts, level, work)
        check_seconds = 0.0
        if request is not None:
            with RenderClock(threads) as clock:
                checked, check_work = render_spot_checks(
                    scene,
                    request.pixels,
                    request.part_spp,
                    request.part_start,
                    camera,
                    settings,
                    threads=threads,
                )
            ledger.add(request, request.pixels, checked, check_work)
            check_seconds = clock.seconds
        checks = ledger.checks()
        true_mse = rel_mse(parts.mean(axis=0), ref.mean) - floor
        guides = aov_layers((aov_sums / level).astype(np.float32))
        with RenderClock(threads) as clock:
            denoised, denoised_estimate = denoise_and_estimate(
                parts, per_part, guides["albedo"], guides["normal"], "high", prefilter, level
            )
        denoised_mse = rel_mse(denoised, ref.mean) - floor
        records.append(
            {
                "spp": level,
                "estimated": estimate_rel_error(parts, checks=checks),
                "true": math.sqrt(max(true_mse, 0.0)),
                "checked": 0 if checks is None else len(checks.pixels),
                "seconds": seconds,
                "check_seconds": check_seconds,
                "denoised": {
                    "estimated": denoised_estimate,
                    "true": math.sqrt(max(denoised_mse, 0.0)),
                    "seconds": clock.seconds,
                },
            }
        )
    return records


# --- one scene, and the whole study ------------------------------------------------------------


def scene_name(path: Path) -> str:
    """A scene's name: its folder's."""
    return path.parent.name


def planned_spp(options: StudyOptions, configs: int, own_reference_needed: bool) -> int:
    """Samples per pixel a scene's study renders (the progress bar's total)."""
    reference = options.reference_factor * options.max_spp if own_reference_needed else 0
    effect = len(EFFECT_STAGES) * options.repeats * options.effect_spp
    return reference + configs * options.max_spp + effect + options.max_spp


def rendering_configs(configs: list[Config]) -> int:
    """How many of ``configs`` render samples (the denoised ones take their sources')."""
    return sum(1 for config in configs if config.source is None)


def study_scene(
    path: Path,
    options: StudyOptions,
    on_start: Callable[[str, int], None],
    on_samples: Callable[[int], None],
    on_phase: Callable[[str], None],
) -> tuple[dict, dict]:
    """The whole study of one scene: ``(results, images)``; ``images`` holds the reference and
    the strip images. ``on_start(name, total_spp)`` opens its progress, ``on_phase`` names
    each part as it starts."""
    name = scene_name(path)
    state = load_scene(path)
    scene = compile_scene(state)
    width, height = study_size(scene.camera.width, scene.camera.height, options.pixels)
    camera = fmt.override(scene.camera, width=width, height=height)
    base = fmt.override(scene.render, seed=options.seed, aovs=False, denoise="off")
    ref, note = independent_reference(path.parent, width, height, base)
    configs = configurations(base)
    on_start(name, planned_spp(options, rendering_configs(configs), ref is None))
    if ref is None:
        on_phase("reference")
        ref = own_reference(
            scene,
            path.parent,
            camera,
            reference_settings(base, options.seed),
            options.reference_factor * options.max_spp,
            options.reference_passes,
            options.cache_dir,
            options.threads,
            on_samples,
        )
    floor = noise_floor(ref.mean, ref.var_of_mean)
    on_phase("sweep")
    prefilter = noisy_guides(state.materials.values(), camera)  # what auto prefilters
    threads = options.threads or default_threads()
    configs_result, strips = sweep(
        scene,
        camera,
        base,
        ref,
        floor,
        options.max_spp,
        threads,
        on_samples,
        prefilter=prefilter,
        flip_every=options.flip_every,
    )
    on_phase("effect costs")
    costs = effect_costs(scene, camera, base, ref, floor, options, on_samples)
    on_phase("calibration")
    calib = calibration(scene, camera, ref, floor, options, on_samples, prefilter=prefilter)
    result = {
        "scene": str(path.relative_to(REPO_ROOT)) if path.is_relative_to(REPO_ROOT) else str(path),
        "size": [width, height],
        "triangles": scene.stats.triangles,
        "reference": {
            "source": ref.source,
            "detail": ref.detail,
            "spp": ref.spp,
            "max_depth": ref.settings.max_depth,
            "seconds": ref.seconds,
            "noise_floor": floor,
            "note": note,
        },
        "configs": configs_result,
        "effects": costs,
        "calibration": calib,
    }
    images = {
        "reference": ref.mean.astype(np.float32),
        "strips": strips[DEFAULT_CONFIG],
        "denoised_strips": strips[DENOISED_STRIP],
    }
    return result, images


def machine() -> dict:
    """What the timings depend on besides the code."""
    from importlib.metadata import version

    return {
        "cpus": len(os.sched_getaffinity(0))
        if hasattr(os, "sched_getaffinity")
        else os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numba": version("numba"),
    }


def run_study(
    options: StudyOptions,
    on_start: Callable[[str, int], None] = lambda name, total: None,
    on_samples: Callable[[int], None] = lambda n: None,
    on_phase: Callable[[str], None] = lambda phase: None,
) -> tuple[dict, dict]:
    """Study every scene of ``options``; returns ``(results, images by scene)``."""
    started = time.perf_counter()
    results = {"options": options_json(options), "machine": machine(), "scenes": {}}
    images = {}
    for path in options.scenes:
        result, scene_images = study_scene(path, options, on_start, on_samples, on_phase)
        results["scenes"][scene_name(path)] = result
        images[scene_name(path)] = scene_images
    results["machine"]["load_average_end"] = machine()["load_average"]
    results["seconds"] = time.perf_counter() - started
    return results, images


def options_json(options: StudyOptions) -> dict:
    return {
        "scenes": [str(p) for p in options.scenes],
        "pixels": options.pixels,
        "max_spp": options.max_spp,
        "reference_factor": options.reference_factor,
        "reference_passes": options.reference_passes,
        "effect_spp": options.effect_spp,
        "repeats": options.repeats,
        "seed": options.seed,
        "threads": options.threads,
    }
