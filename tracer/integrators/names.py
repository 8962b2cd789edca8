"""The integrators' and kernels' names: the one list the scene format, the registry and the CLI
use.

Kept apart from the kernels so that the format and the command line's parser read it without
importing them (``tracer.integrators.registry`` holds an entry for each name, in this order).
"""

INTEGRATORS = ("path", "direct", "whitted", "ao", "albedo", "normal", "depth", "cost")

KERNELS = ("auto", "single", "stream")
"""``render.kernel``'s choices: a kernel by name (``tracer.integrators.registry``), or ``auto``
for the measured rule (``tracer.integrators.kernel_choice``)."""

AOV_INTEGRATORS = ("path", "direct", "whitted", "cost")
"""The integrators whose paths give AOVs (``tracer.integrators.aov``): the path kernel's."""

DENOISE = ("off", "fast", "balanced", "high")
"""``render.denoise``'s choices: off, or an Open Image Denoise quality
(``tracer.post.denoise``)."""

DENOISE_PREFILTER = ("auto", "on", "off", "albedo")
"""``render.denoise_prefilter``'s choices: prefilter the denoiser's guides where they are noisy
(``tracer.post.guides``), always, never, or the albedo only (the normal counted clean)."""

ADAPTIVE = ("auto", "on", "off")
"""``render.adaptive``'s choices: adaptive sampling in progressive renders where it is predicted
to win (``cluster.adaptive``), in every wave once the frame has a few samples, or never."""

LIGHT_SAMPLERS = ("auto", "power", "tree")
"""``render.light_sampler``'s choices: how next-event estimation picks emissive triangles, by
the rule the effect plan measured (``tracer.integrators.effects``), by power, or with the light
tree (``tracer.shading.light_tree``)."""

OUTPUT_LAYERS = (
    "beauty",
    "denoised",
    "albedo",
    "normal",
    "depth",
    "position",
    "alpha",
    "object_id",
    "material_id",
)
"""A frame's layers (``tracer.post.frame_layers``), in the order files hold them: the beauty,
the denoised beauty and the AOVs (``tracer.integrators.aov``)."""
