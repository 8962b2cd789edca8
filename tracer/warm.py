"""Compiling kernels ahead of the renders that need them: every distinct kernel build the sample
scenes need, each compiled by rendering one pixel, so it lands in numba's kernel cache
(``tracer.kernel.numba_cache``). The Docker image's build (``docker/warm_kernels.py``) and the test
suite (``tests/kernel_warmer.py``) use it."""

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

from tracer.compiled.scene import CompiledScene, compile_scene
from tracer.integrators.effects import EffectPlan, effect_plan
from tracer.integrators.kernel_choice import chosen_kernel
from tracer.render import render_lines
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene


@dataclass(frozen=True)
class Build:
    """A compiled kernel a render needs, and the render that compiles it."""

    kernel: Callable[..., None]
    label: str
    scene: CompiledScene
    settings: fmt.RenderSettings
    plan: EffectPlan

    def compile(self) -> float:
        """Render one pixel with it; returns the seconds taken (mostly its compile)."""
        start = time.perf_counter()
        tiny = fmt.override(self.scene.camera, width=1, height=1)
        render_lines(self.scene, 0, 1, tiny, self.settings, threads=1, plan=self.plan)
        return time.perf_counter() - start


def builds(scenes: Path, renders: Iterable[tuple[str, str]] = (("path", "auto"),)) -> list[Build]:
    """Every distinct kernel the sample scenes under ``scenes`` need, rendered by each of
    ``renders`` (an integrator and a ``render.kernel`` value), in scene order; each scene is
    loaded and compiled once."""
    renders = tuple(renders)
    found: dict[int, Build] = {}
    for path in sorted(scenes.glob("*/scene.json")):
        scene = compile_scene(load_scene(path))
        for integrator, kernel_name in renders:
            settings = fmt.override(scene.render, spp=1, integrator=integrator, kernel=kernel_name)
            plan = effect_plan(scene, settings)
            kernel = chosen_kernel(settings, plan.flags)
            label = f"{path.parent.name} ({integrator}, {kernel_name})"
            found.setdefault(id(kernel), Build(kernel, label, scene, settings, plan))
    return list(found.values())
