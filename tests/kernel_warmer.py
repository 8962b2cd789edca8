"""Compile the kernel builds the test suite needs in a process of its own, while the first tests
run: the suite's time is mostly first compiles, and a compile uses one core of the two. It runs
at a lower priority than the tests, so it takes a core only where they leave one idle.

``tests/conftest.py`` starts it for runs of many tests and stops it when they end. A test that
needs a build before it is warm compiles it itself, as without the warmer; either way the build
lands once in the shared kernel cache. The first tests compile the Cornell box's lean build at
once, so the warmer leaves that one to them, takes the single-ray kernel's other builds first
and then the stream kernel's, which only the tests of their bit-identity need, and the surface
integrators' last.

    python -m tests.kernel_warmer
"""

import os

from tests.helpers import SCENES
from tracer.integrators.path import kernel_for
from tracer.warm import Build, builds


def warm_order() -> list[Build]:
    """The builds to warm, in the order they are compiled."""
    found = builds(SCENES, (("path", "single"), ("path", "stream"), ("ao", "auto")))
    lean = kernel_for(0)  # the first tests' own
    single = [b for b in found if b.settings.kernel == "single" and b.kernel is not lean]
    stream = [b for b in found if b.settings.kernel == "stream"]
    surface = [b for b in found if b.settings.integrator == "ao"]
    return single + stream + surface


def main() -> None:
    os.nice(10)
    for build in warm_order():
        build.compile()


if __name__ == "__main__":
    main()
