"""Which kernel traces a render's paths: the single-ray kernel or the stream kernel.

Both give the same pixels bit for bit (``tracer.integrators.stream``), so the choice is about
speed only. ``render.kernel`` names one; ``auto`` (the default) applies the rule measured by
``bench/renderer_mrays.py`` (``docs/performance.md``, "Single-ray and stream kernels").
"""

from collections.abc import Callable
from dataclasses import dataclass

from tracer.integrators import flags
from tracer.integrators.effects import EffectPlan
from tracer.integrators.registry import REGISTRY
from tracer.scene import format as fmt

SINGLE = "single"
STREAM = "stream"


@dataclass(frozen=True)
class KernelChoice:
    """The kernel a render runs, and the rule that chose it."""

    name: str
    reason: str

    def to_json(self) -> dict:
        """What render metadata and ``tilerender plan`` show."""
        return {"kernel": self.name, "kernel_reason": self.reason}


def choose_kernel(settings: fmt.RenderSettings, plan_flags: int) -> KernelChoice:
    """The kernel for ``settings.integrator`` under a plan's flags: ``settings.kernel`` when it
    names one the integrator has, else the measured rule."""
    kernels = REGISTRY[settings.integrator].kernels
    if len(kernels) == 1:
        return KernelChoice(SINGLE, f"the {settings.integrator} integrator has one kernel")
    if settings.kernel != "auto":
        return KernelChoice(settings.kernel, "set in render.kernel")
    if plan_flags & flags.MATERIAL_EFFECTS:
        return KernelChoice(
            STREAM, "material effects: shading in runs of one material pays for the stream"
        )
    return KernelChoice(SINGLE, "Lambertian surfaces only: the stream's bookkeeping costs more")


def plan_report(plan: EffectPlan, settings: fmt.RenderSettings) -> dict:
    """The effect plan's JSON with the kernel choice beside it (render metadata, ``tilerender
    plan``, the service's scene summary and frame metadata)."""
    return {**plan.to_json(), **choose_kernel(settings, plan.flags).to_json()}


def chosen_kernel(settings: fmt.RenderSettings, plan_flags: int) -> Callable[..., None]:
    """The jitted kernel a render with ``settings`` and a plan's flags runs."""
    kernels = REGISTRY[settings.integrator].kernels
    return kernels[choose_kernel(settings, plan_flags).name](plan_flags)
