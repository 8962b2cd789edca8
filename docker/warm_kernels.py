"""Fill numba's kernel cache while the image is built, so no container compiles at start.

The path kernel has four builds (``tracer.integrators.path.KERNELS``: with or without the material
dispatch, with or without point/spot/sun/sky lights), and so has the stream kernel; a scene needs
the build its effect plan and kernel choice pick (``tracer.integrators.kernel_choice``).
This renders one pixel of the first sample scene that needs each build (``tracer.warm``), in this
process (no Ray), which compiles it into ``NUMBA_CACHE_DIR`` (set from ``TILERENDER_NUMBA_CACHE``
by ``tracer``). Tracers in containers of the image then load the kernels from there (numba
recompiles only on a CPU of another kind than the build machine's).

    python docker/warm_kernels.py SCENES_DIR
"""

import sys
from pathlib import Path

from tracer.kernel import numba_cache
from tracer.warm import builds


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: python docker/warm_kernels.py SCENES_DIR", file=sys.stderr)
        return 2
    done = [f"{build.label}: {build.compile():.1f} s" for build in builds(Path(argv[0]))]
    cache = numba_cache.configure()
    print(f"warmed {len(done)} kernel builds in {cache}: {', '.join(done)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
