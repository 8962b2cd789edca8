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
    """Every integrator has the single-ray kernel; the path integrators also the stream kernel,
    a distinct build for each plan."""
    for integrator in registry.REGISTRY.values():
        assert "single" in integrator.kernels
        for flags in (0, -1):
            built = {name: kernel(flags) for name, kernel in integrator.kernels.items()}
            assert all(callable(k) for k in built.values())
            assert len({id(k) for k in built.values()}) == len(built)
    assert set(registry.REGISTRY["path"].kernels) == {"single", "stream"}
    assert set(registry.REGISTRY["ao"].kernels) == {"single"}


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
