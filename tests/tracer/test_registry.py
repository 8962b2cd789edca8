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


def test_the_format_and_the_cli_parser_import_no_kernel():
    """Only the list of names, never the kernels, is loaded to validate a scene or parse a
    command line."""
    for module in ("tracer.scene.format", "cli.main"):
        code = (
            f"import sys, {module}\n"
            "print(sorted(m for m in sys.modules if m.startswith('tracer.integrators')))"
        )
        run = subprocess.run(
            [sys.executable, "-c", code], capture_output=True, text=True, check=True
        )
        assert run.stdout.strip() == "['tracer.integrators', 'tracer.integrators.names']", module
