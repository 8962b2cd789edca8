"""The integrators by name, as pbrt's ``Integrator::Create``: each name's kernel, the builder of
its arguments, and what the effect plan needs to know of it.

``path``, ``direct`` (a path of two vertices), ``whitted`` and ``cost`` (the path kernel's work
as a heat map, ``tracer.io.heatmap``) run ``tracer.integrators.path`` or, path for path the
same, ``tracer.integrators.stream``; ``ao``, ``albedo``,
``normal`` and ``depth`` run ``tracer.integrators.surface``. The names are the scene format's
(``tracer.integrators.names.INTEGRATORS``; a test keeps them equal).
"""

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tracer import config
from tracer.compiled.arrays import SceneArrays
from tracer.compiled.light_tree import light_tree_of
from tracer.compiled.scene import CompiledScene
from tracer.integrators import path, stream, surface, vertex
from tracer.integrators.flags import (
    ALPHA_TEST,
    INDIRECT,
    LIGHT_TREE,
    NORMAL_MAPS,
    SHADING_NORMALS,
    TEXTURES,
    light_kinds,
)
from tracer.integrators.pixels import PixelRun
from tracer.maths import portable
from tracer.shading.lights import light_arrays, scene_fields

Arguments = Callable[[CompiledScene, PixelRun], tuple]
"""Builds a kernel's leading arguments (all but the part, the stacks and the outputs)."""


@dataclass(frozen=True)
class Integrator:
    """An integrator: its kernel for a plan's flags, its arguments, and its traits."""

    name: str
    kernels: dict[str, Callable[[int], Callable[..., None]]]
    """Kernel name (``single``, ``stream``) -> the jitted kernel for a plan's flags
    (``tracer.integrators.pixels.trace_run`` calls it); ``single`` always exists."""
    arguments: Arguments
    samples_lights: bool
    """Whether it samples lights (next-event estimation)."""
    indirect: bool
    """Whether its paths go past two vertices (the plan's ``INDIRECT``)."""
    reads_colour: bool
    """Whether it reads base colours (the plan's ``TEXTURES``)."""
    heat_map: bool = False
    """Whether its image is the work per pixel as a heat map, not the kernel's ``rgb``."""
    reads_normals: bool = True
    """Whether it shades with normals (the plan's ``SHADING_NORMALS``)."""
    tests_alpha: bool = True
    """Whether its kernels test base-colour alpha (the plan's ``ALPHA_TEST``): the path
    kernels; the surface kernel's outputs see every surface opaque."""


def arrays_for_plan(scene: CompiledScene, flags: int) -> SceneArrays:
    """The scene's arrays with only the lights a plan's flags keep (the same arrays when they
    keep every light the scene has), the light tree when the plan samples with it, and the
    materials' alpha when it tests alpha."""
    kinds = light_kinds(flags)
    present = {int(k) for k in scene.lights.kind[scene.lights.weight > 0.0]}
    arrays = scene.arrays
    if not present <= kinds:
        arrays = arrays._replace(**scene_fields(light_arrays(scene.lights, kinds)))
    if flags & LIGHT_TREE:
        arrays = arrays._replace(**light_tree_of(scene)._asdict())
    if flags & ALPHA_TEST:
        arrays = arrays._replace(mat_alpha=scene.textures.alpha)
    return arrays


def scene_diagonal(scene: CompiledScene) -> float:
    """Length of the diagonal of the scene's bounding box (world units)."""
    return portable.norm(np.subtract(scene.stats.bounds_max, scene.stats.bounds_min))


def _path(name: str, mode: int, indirect: bool, heat_map: bool = False) -> Integrator:
    """A path-kernel integrator in ``mode`` (``vertex.PATH`` or ``vertex.WHITTED``); a ``PATH``
    mode without ``indirect`` (or without the plan's ``INDIRECT``) stops at two vertices."""

    def arguments(scene: CompiledScene, run: PixelRun) -> tuple:
        settings = run.settings
        max_depth = settings.max_depth
        if mode == vertex.PATH and not (indirect and run.flags & INDIRECT):
            max_depth = min(max_depth, 2)
        return (
            arrays_for_plan(scene, run.flags),
            run.camera,
            run.width,
            run.height,
            run.p0,
            run.p1,
            run.sample_start,
            settings.spp,
            run.counts,
            max_depth,
            settings.rr_depth,
            settings.seed,
            run.frame,
            1.0 - config.SHADOW_EPSILON,
            mode,
            run.flags,
        )

    kernels = {"single": path.kernel_for, "stream": stream.kernel_for}
    return Integrator(name, kernels, arguments, True, indirect, True, heat_map)


def _surface(name: str, output: int) -> Integrator:
    """A surface-kernel integrator for ``output`` (``surface.AO``, ``ALBEDO``, ...)."""

    def arguments(scene: CompiledScene, run: PixelRun) -> tuple:
        settings = run.settings
        return (
            scene.arrays,
            run.camera,
            run.width,
            run.height,
            run.p0,
            run.p1,
            run.sample_start,
            settings.spp,
            run.counts,
            settings.seed,
            run.frame,
            output,
            settings.ao_samples,
            settings.ao_distance * scene_diagonal(scene),
            bool(run.flags & TEXTURES),
            run.flags & (SHADING_NORMALS | NORMAL_MAPS),
        )

    def kernel(flags: int) -> Callable[..., None]:
        return surface.render_surface

    reads_normals = output in (surface.AO, surface.NORMAL)
    return Integrator(
        name, {"single": kernel}, arguments, False, False, output == surface.ALBEDO,
        reads_normals=reads_normals, tests_alpha=False,
    )  # fmt: skip


REGISTRY: dict[str, Integrator] = {
    i.name: i
    for i in (
        _path("path", vertex.PATH, indirect=True),
        _path("direct", vertex.PATH, indirect=False),
        _path("whitted", vertex.WHITTED, indirect=False),
        _surface("ao", surface.AO),
        _surface("albedo", surface.ALBEDO),
        _surface("normal", surface.NORMAL),
        _surface("depth", surface.DEPTH),
        _path("cost", vertex.PATH, indirect=True, heat_map=True),
    )
}
"""Every integrator, by name, in the scene format's order."""

NAMES: tuple[str, ...] = tuple(REGISTRY)
"""The integrators' names (``tracer.integrators.names.INTEGRATORS``)."""
