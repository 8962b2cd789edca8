"""What the two front doors (``tilerender render`` and the service's jobs) share about a job:
the rule that applies their overrides to a scene, the progressive goal of a job by quality,
and the CPUs an embedded Ray needs for its tracers."""

import dataclasses

import pydantic

from cluster.progressive import Goal
from tracer.errors import SceneError, format_validation_error
from tracer.kernel.threads import default_threads
from tracer.post.guides import resolve_prefilter
from tracer.scene import format as fmt
from tracer.scene.model import SceneState


def with_overrides(
    state: SceneState,
    *,
    width: int | None = None,
    height: int | None = None,
    spp: int | None = None,
    seed: int | None = None,
    max_depth: int | None = None,
    integrator: str | None = None,
    kernel: str | None = None,
    light_sampler: str | None = None,
    aovs: bool | None = None,
    denoise: str | None = None,
    denoise_prefilter: str | None = None,
    adaptive: str | bool | None = None,
) -> SceneState:
    """``state`` with its camera's size and its render settings overridden (None keeps the
    scene's value), and ``denoise_prefilter`` ``auto`` resolved for its materials and camera
    (``tracer.post.guides``); SceneError names a value a scene file could not hold either."""
    try:
        camera = fmt.override(state.camera, width=width, height=height)
        render = fmt.override(
            state.render,
            spp=spp,
            seed=seed,
            max_depth=max_depth,
            integrator=integrator,
            kernel=kernel,
            light_sampler=light_sampler,
            aovs=aovs,
            denoise=denoise,
            denoise_prefilter=denoise_prefilter,
            adaptive=adaptive,
        )
    except pydantic.ValidationError as exc:
        raise SceneError(format_validation_error(exc)) from None
    render = resolve_prefilter(render, state.materials.values(), camera)
    return dataclasses.replace(state, camera=camera, render=render)


def quality_goal(
    target_error: float | None, time_budget: float | None, max_spp: int, frames: int = 1
) -> Goal | None:
    """The progressive goal of a job by target error or time budget (None for neither); the
    budget is shared evenly by its ``frames``."""
    if target_error is None and time_budget is None:
        return None
    budget = None if time_budget is None else time_budget / max(1, frames)
    return Goal(target_error=target_error, time_budget=budget, max_spp=max_spp)


def embedded_ray_cpus(
    ray_address: str | None, tracers: int | None, threads: int | None
) -> int | None:
    """Logical CPUs for an embedded Ray whose tracers each take ``threads`` CPUs: enough for
    every tracer to fit (one that does not would wait for CPUs forever); None leaves Ray its
    default (all), and a cluster address has its own CPUs."""
    if ray_address is not None or not threads:
        return None
    return max(default_threads(), (tracers or 1) * threads)
