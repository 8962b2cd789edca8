"""Fill numba's kernel cache while the image is built, so no container compiles at start.

The path kernel has four builds (``tracer.integrators.path.KERNELS``: with or without the material
dispatch, with or without point/spot/sun/sky lights), and so has the stream kernel; a scene needs
the build its effect plan and kernel choice pick (``tracer.integrators.kernel_choice``).
This renders one pixel of the first sample scene that needs each build, in this process (no Ray),
which compiles it into ``NUMBA_CACHE_DIR`` (set from ``TILERENDER_NUMBA_CACHE`` by ``tracer``).
Tracers in containers of the image then load the kernels from there (numba recompiles only on a
CPU of another kind than the build machine's).

    python docker/warm_kernels.py SCENES_DIR
"""

import sys
import time
from pathlib import Path

from tracer.compiled.scene import compile_scene
from tracer.integrators.effects import effect_plan
from tracer.integrators.kernel_choice import chosen_kernel
from tracer.kernel import numba_cache
from tracer.render import render_lines
from tracer.scene import format as fmt
from tracer.scene.loader import load_scene


def warm(scenes: Path) -> list[str]:
    """Compile every kernel build some scene under ``scenes`` needs; returns what was warmed."""
    warmed: dict[int, str] = {}
    for path in sorted(scenes.glob("*/scene.json")):
        scene = compile_scene(load_scene(path))
        settings = fmt.override(scene.render, spp=1)
        plan = effect_plan(scene, settings)
        kernel = chosen_kernel(settings, plan.flags)
        if id(kernel) in warmed:
            continue
        start = time.perf_counter()
        tiny = fmt.override(scene.camera, width=1, height=1)
        render_lines(scene, 0, 1, tiny, settings, threads=1, plan=plan)
        warmed[id(kernel)] = f"{path.parent.name} ({time.perf_counter() - start:.1f} s)"
    return list(warmed.values())


def main(argv: list[str]) -> int:
    if len(argv) != 1 or not Path(argv[0]).is_dir():
        print("usage: python docker/warm_kernels.py SCENES_DIR", file=sys.stderr)
        return 2
    done = warm(Path(argv[0]))
    cache = numba_cache.configure()
    print(f"warmed {len(done)} kernel builds in {cache}: {', '.join(done)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
