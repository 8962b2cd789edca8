"""The integrator registry (``tracer.integrators.registry``): its names are the scene format's,
and the format does not import the kernels."""

import subprocess
import sys
import typing

from tracer.integrators import registry
from tracer.scene import format as fmt


def test_registry_names_are_the_formats():
    assert registry.NAMES == fmt.INTEGRATORS
    field = fmt.RenderSettings.model_fields["integrator"].annotation
    assert typing.get_args(field) == registry.NAMES


def test_every_integrator_has_a_kernel_for_every_build():
    for integrator in registry.REGISTRY.values():
        for flags in (0, -1):
            assert callable(integrator.kernel(flags))


def test_the_format_imports_no_kernel():
    code = (
        "import sys, tracer.scene.format\n"
        "print(any(m.startswith('tracer.integrators') for m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
