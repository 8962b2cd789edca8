"""The integrators' and kernels' names: the one list the scene format, the registry and the CLI
use.

Kept apart from the kernels so that the format and the command line's parser read it without
importing them (``tracer.integrators.registry`` holds an entry for each name, in this order).
"""

INTEGRATORS = ("path", "direct", "whitted", "ao", "albedo", "normal", "depth", "cost")

KERNELS = ("auto", "single", "stream")
"""``render.kernel``'s choices: a kernel by name (``tracer.integrators.registry``), or ``auto``
for the measured rule (``tracer.integrators.kernel_choice``)."""
