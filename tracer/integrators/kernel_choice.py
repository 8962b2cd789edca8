"""Which kernel traces a render's paths: the single-ray kernel or the stream kernel.

Both give the same pixels bit for bit (``tracer.integrators.stream``), so the choice is about
speed only. ``render.kernel`` names one; ``auto`` (the default) applies the rule measured by
``bench/renderer_mrays.py`` (``docs/performance.md``, "Single-ray and stream kernels").
"""

from collections.abc import Callable
from dataclasses import dataclass

from tracer.integrators.effects import EffectPlan
from tracer.integrators.registry import REGISTRY
from tracer.scene import format as fmt

SINGLE = "single"
MEASURED = (
    "measured: the stream kernel is 0.86-0.97x the single-ray kernel on every sample scene and "
    "on 1.31M triangles (bench/renderer_mrays.py)"
)


@dataclass(frozen=True)
class KernelChoice:
    """The kernel a render runs, and the rule that chose it."""

    name: str
    reason: str

    def to_json(self) -> dict:
        """What render metadata and ``tilerender plan`` show."""
        return {"kernel": self.name, "kernel_reason": self.reason}


def choose_kernel(settings: fmt.RenderSettings) -> KernelChoice:
    """The kernel for ``settings.integrator``: ``settings.kernel`` when the integrator has a
    choice and the render records no AOVs, else the measured rule (today the single-ray
    kernel, whatever the plan)."""
    kernels = REGISTRY[settings.integrator].kernels
    if len(kernels) == 1:
        return KernelChoice(SINGLE, f"the {settings.integrator} integrator has one kernel")
    if settings.renders_aovs:  # the format refuses an explicit stream kernel with them
        return KernelChoice(SINGLE, "AOVs come from the single-ray kernel only")
    if settings.kernel != "auto":
        return KernelChoice(settings.kernel, "set in render.kernel")
    return KernelChoice(SINGLE, MEASURED)


def plan_report(plan: EffectPlan, settings: fmt.RenderSettings) -> dict:
    """The effect plan's JSON with the kernel choice beside it (render metadata, ``tilerender
    plan``, the service's scene summary and frame metadata)."""
    return {**plan.to_json(), **choose_kernel(settings).to_json()}


def chosen_kernel(settings: fmt.RenderSettings, plan_flags: int) -> Callable[..., None]:
    """The jitted kernel a render with ``settings`` and a plan's flags runs."""
    kernels = REGISTRY[settings.integrator].kernels
    return kernels[choose_kernel(settings).name](plan_flags)
