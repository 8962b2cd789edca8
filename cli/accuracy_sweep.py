"""The accuracy study's sweep (``cli.accuracy``, part 1): its configurations, the render of one
wave with the rays and work it took, render seconds that a busy machine does not inflate, and
the sweep that runs every configuration through the spp levels, wave by wave."""

import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from cli.accuracy_metrics import TARGETS, measure, time_to
from cli.accuracy_reference import Reference
from tracer.compiled.scene import CompiledScene
from tracer.integrators.aov import CHANNELS
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.flags import EFFECTS, LIGHT_SAMPLES, NO_MIS, SHADOWS
from tracer.post.frame_layers import denoise_with_aov
from tracer.render import render_image
from tracer.scene import format as fmt

STRIP_SPP = (1, 4, 16, 64, 256)
"""Sample counts of the default configuration shown beside the reference in image strips."""
DEFAULT_CONFIG = "path"
AOV_CONFIG = "path-aov"
"""The default configuration recording the AOVs: the denoised configurations' source."""
DENOISED_STRIP = "path-oidn-high"
"""The denoised configuration whose images the strips show under the default's."""


@dataclass(frozen=True)
class Config:
    """One configuration of the sweep: settings changes, effects dropped from the plan and
    sampling switches added to it."""

    name: str
    label: str
    changes: dict = field(default_factory=dict)
    drop: int = 0
    """Effect flags removed from the scene's plan (``tracer.integrators.flags``)."""
    add: int = 0
    """Kernel switches added to the plan (``tracer.integrators.flags.NO_MIS``)."""
    denoise: str = "off"
    """An OIDN quality: the configuration denoises the images of ``source`` (renders none)."""
    source: str | None = None

    def settings(self, base: fmt.RenderSettings) -> fmt.RenderSettings:
        return fmt.override(base, **self.changes)

    def plan(self, scene: CompiledScene, settings: fmt.RenderSettings) -> EffectPlan:
        plan = effect_plan(scene, settings)
        if not self.drop and not self.add:
            return plan
        reasons = {**plan.reasons, **{n: "dropped by the study" for n in names(self.drop)}}
        return EffectPlan(plan.flags & ~self.drop | self.add, reasons)


def names(flags: int) -> list[str]:
    """Names of the effect flags in ``flags``."""
    return [name for name, bit in EFFECTS.items() if flags & bit]


def configurations(base: fmt.RenderSettings) -> list[Config]:
    """The sweep's configurations around the scene's own settings ``base`` (the ``path``
    configuration): path tracing at depths 1 to 16, without Russian roulette, with every effect
    (no plan), with light samples but no MIS, with BSDF sampling only (no light samples, so no
    MIS); direct light; Whitted; ambient occlusion; and ``path`` recording its AOVs, denoised
    at OIDN's ``fast`` and ``high`` qualities guided by them."""
    depth = base.max_depth
    configs = [Config(DEFAULT_CONFIG, f"path, NEE + MIS, depth {depth} (the scene's)")]
    configs += [
        Config(
            f"path-d{d}", f"path, depth {d}", {"max_depth": d, "rr_depth": min(base.rr_depth, d)}
        )
        for d in (1, 2, 3, 4, 8, 16)
        if d != depth
    ]
    configs += [
        Config("path-no-rr", "path, no Russian roulette", {"rr_depth": depth}),
        Config("path-no-plan", "path, every effect (no effect plan)", {"effect_plan": False}),
        Config("path-no-mis", "path, light samples without MIS", add=NO_MIS),
        Config(
            "path-bsdf",
            "path, BSDF sampling only (no light samples, no MIS)",
            drop=LIGHT_SAMPLES | SHADOWS,
        ),
        Config("direct", "direct light (NEE + MIS, two vertices)", {"integrator": "direct"}),
        Config("whitted", "Whitted (direct light, specular recursion)", {"integrator": "whitted"}),
        Config("ao", "ambient occlusion (not radiance: all bias)", {"integrator": "ao"}),
        Config(AOV_CONFIG, "path, recording the AOVs (the denoiser's guides)", {"aovs": True}),
    ]
    configs += [
        Config(
            f"path-oidn-{quality}",
            f"path, denoised (OIDN {quality}, albedo + normal guides)",
            denoise=quality,
            source=AOV_CONFIG,
        )
        for quality in ("fast", "high")
    ]
    return configs


def spp_levels(max_spp: int) -> list[int]:
    """1, 2, 4, ..., ``max_spp``."""
    return [1 << k for k in range(max_spp.bit_length())]


def render_counted(
    scene: CompiledScene,
    camera: fmt.Camera,
    settings: fmt.RenderSettings,
    sample_start: int,
    threads: int,
    plan: EffectPlan,
) -> tuple[np.ndarray, int, int, np.ndarray | None]:
    """A frame (:func:`tracer.render.render_image`) with the rays it traced, the kernel work
    it took and its AOVs when the settings record them: ``(rgb, rays, work, aov)``."""
    rays = []
    aov = (
        np.empty((camera.height, camera.width, CHANNELS), np.float32)
        if settings.renders_aovs
        else None
    )

    def on_lines(lines) -> None:
        rays.append(int(lines.rays.sum()))
        if aov is not None:
            aov[lines.y0 : lines.y1] = lines.aov

    rgb, cost = render_image(
        scene,
        camera,
        settings,
        sample_start=sample_start,
        threads=threads,
        plan=plan,
        on_lines=on_lines,
    )
    return rgb, sum(rays), int(cost.sum()), aov


class RenderClock:
    """Render time that a busy shared machine does not inflate: the process's CPU seconds
    (every render thread's) divided by the thread count, which is the wall-clock time of the
    same render on an idle machine with balanced threads. Wall-clock seconds are kept too."""

    def __init__(self, threads: int) -> None:
        self.threads = threads

    def __enter__(self) -> "RenderClock":
        self._cpu, self._wall = time.process_time(), time.perf_counter()
        return self

    def __exit__(self, *exc) -> None:
        self.seconds = (time.process_time() - self._cpu) / self.threads
        self.wall_seconds = time.perf_counter() - self._wall


@dataclass
class _Run:
    """A configuration's running sums during the sweep."""

    config: Config
    settings: fmt.RenderSettings
    plan: EffectPlan
    total: np.ndarray
    aov_total: np.ndarray | None = None
    spp: int = 0
    seconds: float = 0.0
    wall_seconds: float = 0.0
    rays: int = 0
    work: int = 0
    levels: list = field(default_factory=list)


def sweep(
    scene: CompiledScene,
    camera: fmt.Camera,
    base: fmt.RenderSettings,
    ref: Reference,
    floor: float,
    max_spp: int,
    threads: int,
    on_samples: Callable[[int], None],
    prefilter: tuple[str, ...] = (),
    flip_every: int = 2,
) -> tuple[dict, dict[str, dict[int, np.ndarray]]]:
    """Run every configuration through the spp levels 1 to ``max_spp`` on ``threads`` threads,
    interleaved wave by wave (a denoised one after its source, the guides ``prefilter`` names
    prefiltered; FLIP at every ``flip_every``-th level and the last); returns the
    per-configuration records and the images at ``STRIP_SPP`` of the default configuration and of
    ``DENOISED_STRIP``, by configuration name."""
    runs = []
    for config in configurations(base):
        settings = config.settings(base)
        plan = config.plan(scene, settings)
        if config.source is None:  # compile or load the kernel, untimed
            tiny = fmt.override(camera, width=1, height=1)
            render_image(scene, tiny, fmt.override(settings, spp=1), plan=plan, threads=threads)
        elif config.source not in (run.config.name for run in runs):
            raise ValueError(f"{config.name} denoises {config.source}, which must come first")
        else:  # create OIDN's device and load the quality's weights, untimed
            warm_up = np.ones((camera.height, camera.width, 3), np.float32)
            aov = np.zeros((camera.height, camera.width, CHANNELS), np.float32)
            denoise_with_aov(warm_up, aov, config.denoise, prefilter, threads)
        runs.append(_Run(config, settings, plan, np.zeros((camera.height, camera.width, 3))))
    by_name = {run.config.name: run for run in runs}
    strips: dict[str, dict[int, np.ndarray]] = {DEFAULT_CONFIG: {}, DENOISED_STRIP: {}}
    levels = spp_levels(max_spp)
    for index, level in enumerate(levels):
        flip = index % flip_every == 0 or index == len(levels) - 1
        for run in runs:
            if run.config.source is None:
                n = level - run.spp
                with RenderClock(threads) as clock:
                    rgb, rays, work, aov = render_counted(
                        scene, camera, fmt.override(run.settings, spp=n), run.spp, threads, run.plan
                    )
                run.seconds += clock.seconds
                run.wall_seconds += clock.wall_seconds
                run.total += rgb.astype(np.float64) * n
                if aov is not None:
                    run.aov_total = aov.astype(np.float64) * n + (
                        0.0 if run.aov_total is None else run.aov_total
                    )
                run.rays += rays
                run.work += work
                image = run.total / level
                seconds, wall_seconds = run.seconds, run.wall_seconds
                on_samples(n)
            else:  # the source rendered this level already: denoise its mean once
                source = by_name[run.config.source]
                with RenderClock(threads) as clock:
                    image = denoise_with_aov(
                        source.total / level,
                        source.aov_total / level,
                        run.config.denoise,
                        prefilter,
                        threads,
                    ).image
                seconds = source.seconds + clock.seconds
                wall_seconds = source.wall_seconds + clock.wall_seconds
                run.rays, run.work = source.rays, source.work
            run.spp = level
            record = {
                "spp": level,
                "seconds": seconds,
                "wall_seconds": wall_seconds,
                "rays": run.rays,
                "mrays_per_second": run.rays / seconds / 1e6 if seconds > 0 else None,
                "work": run.work,
            }
            run.levels.append(record | measure(image, ref, floor, flip))
            if run.config.name in strips and level in STRIP_SPP:
                strips[run.config.name][level] = image.astype(np.float32)
    results = {}
    for run in runs:
        data = {
            "label": run.config.label,
            "settings": {
                k: v
                for k, v in run.settings.model_dump(mode="json").items()
                if k in ("integrator", "max_depth", "rr_depth", "effect_plan")
            },
            "effects": run.plan.names(),
        }
        if run.config.source is not None:
            data["denoise"] = {
                "quality": run.config.denoise,
                "source": run.config.source,
                "prefiltered": bool(prefilter),
                "prefiltered_guides": list(prefilter),
            }
        data["levels"] = run.levels
        data["time_to"] = {f"{t:g}": time_to(run.levels, t) for t in TARGETS}
        results[run.config.name] = data
    return results, strips
